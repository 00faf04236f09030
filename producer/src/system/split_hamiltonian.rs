//! A separable Hamiltonian advanced by a symplectic splitting.

use std::sync::Arc;

use chaoscope_schemas::run::SystemKind;

use super::{DynamicalSystem, Time};
use crate::integrator::{Integrator, Splitting, TangentError, Workspace};
use crate::model::Model;

/// `H = T(p) + V(q)` stepped by a splitting with fixed step `h`; its tangent map is the
/// splitting's own (`Splitting::step_tangent`), the variational equations of the discrete map.
#[derive(Clone)]
pub struct SplitHamiltonian {
    pub model: Arc<dyn Model>,
    pub splitting: Splitting,
    pub h: f64,
}

impl DynamicalSystem for SplitHamiltonian {
    fn name(&self) -> &str {
        self.model.name()
    }

    fn kind(&self) -> SystemKind {
        SystemKind::Hamiltonian
    }

    fn dim(&self) -> usize {
        2 * self.model.dof()
    }

    fn time(&self) -> Time {
        Time::Continuous { h: self.h }
    }

    #[inline]
    fn step(&self, x: &mut [f64], work: &mut Workspace) {
        self.splitting.step(self.model.as_ref(), x, self.h, work)
    }

    #[inline]
    fn step_tangent(
        &self,
        x: &mut [f64],
        w: &mut [f64],
        work: &mut Workspace,
    ) -> Result<(), TangentError> {
        self.splitting
            .step_tangent(self.model.as_ref(), x, w, self.h, work)
    }

    fn no_tangent_reason(&self) -> Option<String> {
        self.model.no_hessian_reason()
    }

    fn invariant(&self, x: &[f64]) -> Option<f64> {
        Some(self.model.energy(x))
    }

    fn divergence(&self, _x: &[f64]) -> Option<f64> {
        None
    }

    fn diagnose_non_finite(&self, x: &[f64]) -> Option<String> {
        let n = self.model.dof();
        // The potential itself undefined at x (the energy is what the run checks), ...
        if x.iter().all(|v| v.is_finite()) && !self.model.potential(&x[..n]).is_finite() {
            return self.model.diagnose_non_finite(&x[..n]);
        }
        // ... or the step from x: replay it stage by stage and ask the model about the first
        // position whose forces are not finite.
        let w = self.model.inverse_masses();
        let mut x = x.to_vec();
        let mut force = vec![0.0; n];
        let (drifts, kicks) = (self.splitting.drifts(), self.splitting.kicks());
        for (i, &d) in kicks.iter().enumerate() {
            Splitting::drift(&mut x, n, drifts[i] * self.h, w);
            self.model.gradient(&x[..n], &mut force);
            if force.iter().any(|f| !f.is_finite()) || x.iter().any(|v| !v.is_finite()) {
                return self.model.diagnose_non_finite(&x[..n]);
            }
            let (_, p) = x.split_at_mut(n);
            for (pi, fi) in p.iter_mut().zip(&force) {
                *pi -= d * self.h * fi;
            }
        }
        None
    }
}
