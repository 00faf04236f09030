//! The disordered discrete nonlinear Schroedinger lattice advanced by a composition of the
//! exact flows of its three parts (`integrator::composition`), with their exact tangent maps
//! for the variational method; the multi-particle method steps its nearby orbits with the same
//! composition.

use std::sync::Arc;

use chaoscope_schemas::run::SystemClass;

use super::{DynamicalSystem, ReferenceTangent, Time};
use crate::integrator::composition::{Composition, SplitFlows};
use crate::integrator::{TangentError, Workspace};
use crate::model::Ddnls;
use crate::vector_field::VectorField;

/// The DDNLS stepped by `composition` with fixed step `h`.
#[derive(Clone)]
pub struct DdnlsSystem {
    model: Arc<Ddnls>,
    composition: Composition,
    h: f64,
    /// The composition's flows times `h`, formed once.
    times: Vec<(usize, f64)>,
}

impl DdnlsSystem {
    pub fn new(model: Arc<Ddnls>, composition: Composition, h: f64) -> Self {
        let times = composition.times(h);
        Self {
            model,
            composition,
            h,
            times,
        }
    }

    pub fn model(&self) -> &Arc<Ddnls> {
        &self.model
    }

    pub fn composition(&self) -> &Composition {
        &self.composition
    }

    pub fn h(&self) -> f64 {
        self.h
    }
}

impl DynamicalSystem for DdnlsSystem {
    fn name(&self) -> &str {
        "ddnls"
    }

    fn kind(&self) -> SystemClass {
        SystemClass::Hamiltonian
    }

    fn dim(&self) -> usize {
        SplitFlows::dim(self.model.as_ref())
    }

    fn time(&self) -> Time {
        Time::Continuous { h: self.h }
    }

    #[inline]
    fn step(&self, x: &mut [f64], _t: f64, _work: &mut Workspace) {
        Composition::step(self.model.as_ref(), &self.times, x)
    }

    #[inline]
    fn step_tangent(
        &self,
        x: &mut [f64],
        w: &mut [f64],
        _t: f64,
        _work: &mut Workspace,
    ) -> Result<(), TangentError> {
        Composition::step_tangent(self.model.as_ref(), &self.times, x, w);
        Ok(())
    }

    fn no_tangent_reason(&self) -> Option<String> {
        None
    }

    /// The energy `H`; the norm, the second invariant, is [`DdnlsSystem::norm`].
    fn invariant(&self, x: &[f64]) -> Option<f64> {
        Some(self.model.energy(x))
    }

    fn divergence(&self, _x: &[f64], _t: f64) -> Option<f64> {
        None
    }

    fn vector_field(&self, x: &[f64], t: f64, out: &mut [f64]) -> bool {
        self.model.value(x, t, out);
        true
    }

    fn diagnose_non_finite(&self, x: &[f64], _t: f64) -> Option<String> {
        self.model.diagnose(x)
    }

    /// The tangent step moves the orbit with exactly the operations of `step` (the flows of
    /// `x` do not read `w`), so a set of tangent vectors may carry the reference (stepped one
    /// step at a time: no fused pass).
    fn reference_tangent(&self) -> Option<&dyn ReferenceTangent> {
        Some(self)
    }
}

impl ReferenceTangent for DdnlsSystem {}

impl DdnlsSystem {
    /// The norm `S = sum_l (q_l^2 + p_l^2)/2`, conserved beside the energy.
    pub fn norm(&self, x: &[f64]) -> f64 {
        self.model.norm(x)
    }
}
