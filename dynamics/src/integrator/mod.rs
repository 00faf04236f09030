//! Integrators, one file each.
//!
//! One trait, [`Integrator`], generic over the system it advances: symplectic splittings
//! ([`Splitting`]) implement it for separable Hamiltonians ([`SeparableHamiltonian`]); the explicit Runge-Kutta
//! methods ([`RungeKutta`]: rk4, dop853 with or without error control) implement it for vector
//! fields ([`crate::vector_field::VectorField`]).
//! An integrator may also advance deviation vectors with its own tangent map (the variational
//! method); one that cannot says so and only the multi-particle method is offered.

pub mod composition;
pub mod gauss_legendre;
pub mod runge_kutta;
mod splitting;
pub mod taylor;

pub use runge_kutta::{RungeKutta, RungeKuttaTableau};
pub use splitting::{Splitting, SplittingScheme};

use crate::model::{At, SeparableHamiltonian};

/// Scratch buffers reused across steps so the inner loop never allocates. One per thread.
#[derive(Debug, Default, Clone)]
pub struct Workspace {
    pub(crate) force: Vec<f64>,
    /// Stages of a Runge-Kutta step and the adaptive controller's proposal.
    pub(crate) rk: runge_kutta::RkScratch,
    /// Coefficients of Taylor's method.
    pub(crate) taylor: taylor::TaylorScratch,
}

impl Workspace {
    pub fn new() -> Self {
        Self::default()
    }

    pub(crate) fn force(&mut self, n: usize) -> &mut [f64] {
        if self.force.len() < n {
            self.force.resize(n, 0.0);
        }
        &mut self.force[..n]
    }
}

/// Why a tangent-map step could not be taken.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum TangentError {
    #[error(
        "{0}: the variational method needs second derivatives; use the multi-particle method (mpm)"
    )]
    NoHessian(String),
}

/// A fixed-step integrator for systems of type `S`.
pub trait Integrator<S: ?Sized>: Send + Sync {
    /// Name as written in configs (`"aba864"`).
    fn name(&self) -> &str;

    /// Order of the global error in `h` for a general system.
    fn order(&self) -> u32;

    /// Advance the phase-space point `x` by one step `h` from time `t` (what a system that
    /// depends on the time reads at each stage; see each integrator for how).
    fn step(&self, system: &S, x: &mut [f64], t: f64, h: f64, work: &mut Workspace);

    /// Advance `x` and `k` deviation vectors stored one after the other in `w` (each of the
    /// phase-space dimension) by one step from time `t` of the integrator's own tangent map.
    fn step_tangent(
        &self,
        system: &S,
        x: &mut [f64],
        w: &mut [f64],
        t: f64,
        h: f64,
        work: &mut Workspace,
    ) -> Result<(), TangentError>;
}

/// Relative energy error `|H - H0| / |H0|` (absolute when `H0 = 0`).
pub fn relative_energy_error(model: &dyn SeparableHamiltonian, x: &[f64], e0: f64) -> f64 {
    let e = model.energy(x, At::T0);
    if e0 == 0.0 {
        (e - e0).abs()
    } else {
        ((e - e0) / e0).abs()
    }
}
