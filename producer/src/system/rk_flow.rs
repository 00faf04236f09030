//! A flow `dx/dt = f(x)` advanced by an explicit Runge-Kutta method.
//!
//! With a fixed step every engine step is one Runge-Kutta step of size `h`. With error control
//! (adaptive `dop853`) an engine step spans one interval of the time grid (multiples of `h`):
//! the reference orbit chooses its substeps there and lands exactly on the grid point, and the
//! deviation sets (VM's tangent vectors, MPM's nearby orbits) take the very same substeps
//! ([`DynamicalSystem::step_along`]), so every scheme sees one trajectory, whatever `tau`.

use std::sync::Arc;

use chaoscope_schemas::run::SystemKind;

use chaoscope_expr::VectorFunction;

use super::{DynamicalSystem, Time};
use crate::batch::{self, FlowScratch, Isa, PointKernel, Soa};
use crate::integrator::runge_kutta::{RungeKutta, Tableau, Tolerances};
use crate::integrator::{TangentError, Workspace};
use crate::vector_field::VectorField;

/// `dx/dt = f(x)` with a Runge-Kutta method of step `h` (or grid `h`, with error control).
#[derive(Clone)]
pub struct RkFlow {
    /// The name recordings carry (`"ode"`).
    pub name: String,
    pub field: Arc<dyn VectorField>,
    pub method: RungeKutta,
    pub h: f64,
    /// `Some` for adaptive steps (dop853 only).
    pub tolerances: Option<Tolerances>,
}

impl RkFlow {
    fn substeps<'a>(&'a self, plan: &'a [f64]) -> impl Iterator<Item = f64> + 'a {
        // A fixed-step flow follows no plan: its one substep is `h`.
        let fixed = self.tolerances.is_none().then_some(self.h);
        fixed.into_iter().chain(plan.iter().copied())
    }
}

impl DynamicalSystem for RkFlow {
    fn name(&self) -> &str {
        &self.name
    }

    /// A Hamiltonian vector field is reported as a Hamiltonian (its energy error), whatever
    /// the method; any other field as a flow.
    fn kind(&self) -> SystemKind {
        if self.field.is_hamiltonian() {
            SystemKind::Hamiltonian
        } else {
            SystemKind::Flow
        }
    }

    fn dim(&self) -> usize {
        self.field.dim()
    }

    fn time(&self) -> Time {
        Time::Continuous { h: self.h }
    }

    /// The compiled right-hand side stepped by a fixed-step explicit method ([`FlowKernel`]);
    /// `None` with adaptive steps (every orbit would choose its own substeps), an implicit
    /// method (per-orbit stage iterations) or a hand-written field: their points run through
    /// the engine.
    fn batched(&self, _isa: Isa) -> Option<Box<dyn PointKernel + '_>> {
        if self.tolerances.is_some() {
            return None;
        }
        Some(Box::new(FlowKernel {
            tableau: self.method.kind.tableau()?,
            f: self.field.compiled()?,
            h: self.h,
            stages: Vec::new(),
            scratch: FlowScratch::default(),
        }))
    }

    fn step(&self, x: &mut [f64], work: &mut Workspace) {
        match self.tolerances {
            None => self
                .method
                .advance(self.field.as_ref(), x, self.h, &mut work.rk),
            Some(_) => {
                let mut plan = Vec::new();
                self.step_reference(x, &mut plan, work);
            }
        }
    }

    fn step_tangent(
        &self,
        x: &mut [f64],
        w: &mut [f64],
        work: &mut Workspace,
    ) -> Result<(), TangentError> {
        match self.tolerances {
            None => self
                .method
                .advance_tangent(self.field.as_ref(), x, w, self.h, &mut work.rk),
            Some(_) => {
                // Choose the substeps as the reference does, then follow them.
                let mut plan = Vec::new();
                let mut probe = x.to_vec();
                self.step_reference(&mut probe, &mut plan, work);
                self.step_tangent_along(x, w, &plan, work)
            }
        }
    }

    fn step_reference(&self, x: &mut [f64], plan: &mut Vec<f64>, work: &mut Workspace) {
        let Some(tol) = self.tolerances else {
            return self.step(x, work);
        };
        let field = self.field.as_ref();
        if self
            .method
            .step_adaptive(field, x, self.h, tol, plan, &mut work.rk)
            .is_err()
        {
            // The engine stops the run at a non-finite state and asks `diagnose_non_finite`
            // why; no state past the failure is ever published.
            x.fill(f64::NAN);
        }
    }

    fn step_along(&self, x: &mut [f64], plan: &[f64], work: &mut Workspace) {
        for h in self.substeps(plan) {
            self.method.advance(self.field.as_ref(), x, h, &mut work.rk);
        }
    }

    fn step_tangent_along(
        &self,
        x: &mut [f64],
        w: &mut [f64],
        plan: &[f64],
        work: &mut Workspace,
    ) -> Result<(), TangentError> {
        for h in self.substeps(plan) {
            self.method
                .advance_tangent(self.field.as_ref(), x, w, h, &mut work.rk)?;
        }
        Ok(())
    }

    fn no_tangent_reason(&self) -> Option<String> {
        self.field.no_tangent_reason()
    }

    fn invariant(&self, x: &[f64]) -> Option<f64> {
        self.field.energy(x)
    }

    /// `None` for a Hamiltonian field: its flow conserves volume (`div f = 0` identically).
    fn divergence(&self, x: &[f64]) -> Option<f64> {
        (!self.field.is_hamiltonian()).then(|| self.field.divergence(x))
    }

    fn vector_field(&self, x: &[f64], out: &mut [f64]) -> bool {
        self.field.value(x, out);
        true
    }

    fn diagnose_non_finite(&self, x: &[f64]) -> Option<String> {
        let field = self.field.as_ref();
        if let Some(cause) = field.diagnose_non_finite(x) {
            return Some(cause);
        }
        if let Some(tol) = self.tolerances {
            let mut y = x.to_vec();
            let mut scratch = Workspace::new();
            let mut plan = Vec::new();
            if let Err(e) =
                self.method
                    .step_adaptive(field, &mut y, self.h, tol, &mut plan, &mut scratch.rk)
            {
                return Some(e.to_string());
            }
        }
        if let Some(why) = self.method.implicit_step_fails(field, x, self.h) {
            return Some(format!("{why} (h = {})", self.h));
        }
        // Replay the step stage by stage: the first stage state where f is not finite.
        let tableau = self.method.kind.tableau()?;
        let dim = x.len();
        let mut k = vec![0.0; tableau.stages() * dim];
        let mut xi = vec![0.0; dim];
        for i in 0..tableau.stages() {
            for d in 0..dim {
                let sum: f64 = (0..i).map(|j| tableau.a[i][j] * k[j * dim + d]).sum();
                xi[d] = x[d] + self.h * sum;
            }
            if xi.iter().any(|v| !v.is_finite()) {
                return Some(format!(
                    "the Runge-Kutta stage {} overflowed (the solution blows up)",
                    i + 1
                ));
            }
            let (_, rest) = k.split_at_mut(i * dim);
            field.value(&xi, &mut rest[..dim]);
            if rest[..dim].iter().any(|v| !v.is_finite()) {
                return Some(field.diagnose_non_finite(&xi).unwrap_or_else(|| {
                    format!(
                        "f is not finite at the Runge-Kutta stage {} (the solution blows up)",
                        i + 1
                    )
                }));
            }
        }
        None
    }
}

/// A flow with a fixed-step explicit Runge-Kutta method and a compiled right-hand side, over
/// its lane functions.
struct FlowKernel<'a> {
    tableau: &'static Tableau,
    f: &'a VectorFunction,
    h: f64,
    /// Stage states of every step of the last reference steps.
    stages: Vec<f64>,
    scratch: FlowScratch,
}

impl PointKernel for FlowKernel<'_> {
    fn orbit_steps(&mut self, x: &mut Soa, steps: u64) {
        batch::flow_orbit_steps(self.tableau, self.f, self.h, x, steps, &mut self.scratch);
    }

    fn reference_steps(&mut self, x: &mut [f64], steps: u64) {
        batch::record_flow_reference(
            self.tableau,
            self.f,
            self.h,
            x,
            steps,
            &mut self.stages,
            &mut self.scratch,
        );
    }

    fn tangent_steps(&mut self, v: &mut Soa, steps: u64) -> Result<(), TangentError> {
        if batch::flow_tangent_steps(
            self.tableau,
            self.f,
            self.h,
            &self.stages,
            v,
            steps,
            &mut self.scratch,
        ) {
            Ok(())
        } else {
            Err(TangentError::NoHessian(
                self.f
                    .no_tangent_reason()
                    .unwrap_or_else(|| "the right-hand side's Jacobian".into()),
            ))
        }
    }
}
