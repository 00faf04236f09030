//! The deviation methods: how a scheme's deviation vectors live between renormalizations, the
//! one definition the engine and the phase-space maps share.
//!
//! A method evolves *lanes* over any [`PointKernel`] of the system (the engine's one-orbit
//! stepping along the reference's plan, or a kind's batched form), and says what deviation a
//! lane holds and how a lane restarts from a renormalized deviation:
//! - [`Variational`] (VM): a lane is a tangent vector, advanced by the exact tangent map of the
//!   steps the reference took; the deviation is the lane itself.
//! - [`MultiParticle`] (MPM): a lane is a nearby orbit `x + d`, integrated with the full
//!   equations of motion; the deviation is its separation from the reference, as the system
//!   measures it (on the torus for angles). The rounding in `x + d` is part of the method.
//!
//! How sets of directions are formed from lanes is the route's business (per set: `k` lanes
//! each; the run's window propagator: one basis of `D` tangent vectors per scheme; the map's
//! basis: `D` lanes per point), written once per route for every method. A new method is one
//! implementation of [`DeviationMethod`] here, and its name in [`Method`].

use chaoscope_schemas::run::Method;

use crate::batch::{PointKernel, Soa};
use crate::integrator::TangentError;

/// One way of evolving deviations.
pub trait DeviationMethod: Sync {
    /// Whether the lanes are orbits of the system (stepped like the reference, which may then
    /// share their lane array) rather than tangent vectors (stepped along the reference's
    /// recorded steps, so the reference goes first: `PointKernel::reference_steps`).
    fn lanes_are_orbits(&self) -> bool;

    /// The lane holding deviation `d` (already scaled) from the reference state `x`: how a lane
    /// starts, and how it restarts after a renormalization.
    fn start(&self, x: &[f64], d: &[f64], lane: &mut [f64]);

    /// Advance every lane by `steps` steps, the first of them step number `from` of the run
    /// (see [`PointKernel`]).
    fn advance(
        &self,
        kernel: &mut dyn PointKernel,
        lanes: &mut Soa,
        from: u64,
        steps: u64,
    ) -> Result<(), TangentError>;

    /// The deviation `out` that `lane` holds from the reference state `x`.
    fn deviation(&self, kernel: &dyn PointKernel, lane: &[f64], x: &[f64], out: &mut [f64]);

    /// The norm of the basis vectors of a basis route: the tangent map is linear, so VM evolves
    /// unit vectors; MPM's nearby orbits sit at the scheme's `d0`.
    fn basis_norm(&self, d0: f64) -> f64;
}

/// The variational method.
pub struct Variational;

/// The multi-particle method.
pub struct MultiParticle;

/// The implementation of `method`.
pub fn of(method: Method) -> &'static dyn DeviationMethod {
    match method {
        Method::Vm => &Variational,
        Method::Mpm => &MultiParticle,
    }
}

impl DeviationMethod for Variational {
    fn lanes_are_orbits(&self) -> bool {
        false
    }

    fn start(&self, _x: &[f64], d: &[f64], lane: &mut [f64]) {
        lane.copy_from_slice(d);
    }

    fn advance(
        &self,
        kernel: &mut dyn PointKernel,
        lanes: &mut Soa,
        from: u64,
        steps: u64,
    ) -> Result<(), TangentError> {
        kernel.tangent_steps(lanes, from, steps)
    }

    fn deviation(&self, _kernel: &dyn PointKernel, lane: &[f64], _x: &[f64], out: &mut [f64]) {
        out.copy_from_slice(lane);
    }

    fn basis_norm(&self, _d0: f64) -> f64 {
        1.0
    }
}

impl DeviationMethod for MultiParticle {
    fn lanes_are_orbits(&self) -> bool {
        true
    }

    /// A nearby orbit carries the reference's parameters (a state's entries after its `D`
    /// coordinates, when the lane has them) unchanged.
    fn start(&self, x: &[f64], d: &[f64], lane: &mut [f64]) {
        for ((y, xi), di) in lane.iter_mut().zip(x).zip(d) {
            *y = xi + di;
        }
        let (n, len) = (d.len().min(lane.len()), lane.len());
        lane[n..].copy_from_slice(&x[n..len]);
    }

    fn advance(
        &self,
        kernel: &mut dyn PointKernel,
        lanes: &mut Soa,
        from: u64,
        steps: u64,
    ) -> Result<(), TangentError> {
        kernel.orbit_steps(lanes, from, steps);
        Ok(())
    }

    fn deviation(&self, kernel: &dyn PointKernel, lane: &[f64], x: &[f64], out: &mut [f64]) {
        kernel.separation(lane, x, out);
    }

    fn basis_norm(&self, d0: f64) -> f64 {
        d0
    }
}
