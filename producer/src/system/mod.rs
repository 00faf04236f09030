//! Dynamical systems as the engine sees them.
//!
//! The engine, the deviation dynamics (VM, MPM) and the indicators do not care what a system is
//! made of: they need a state of dimension `D`, one step of its evolution, one step of the exact
//! tangent map of that evolution (for the variational method), and whatever invariant it
//! conserves (for the report). [`DynamicalSystem`] is that interface, in the shape of
//! DynamicalSystemsBase.jl's: a continuous or discrete system advanced by `step`, around which
//! the two generic wrappers of this crate (tangent vectors, `engine`'s variational sets; nearby
//! orbits, its multi-particle sets) work for *any* system.
//!
//! Kinds, one file each:
//! - [`SplitHamiltonian`]: a separable Hamiltonian [`Model`] with a symplectic [`Splitting`]
//!   (built-in models and `[model] name = "potential"`);
//! - later, beside it: a vector field `dx/dt = f(x)` with a Runge-Kutta tableau (its tangent map
//!   is the derivative of the Runge-Kutta step, by the expression compiler's automatic
//!   derivatives), and a non-separable Hamiltonian with an implicit Gauss-Legendre method;
//! - [`Map`]: a discrete map `x -> F(x)` (`[model] name = "map"`, `Time::Discrete`, `tau`
//!   counted in iterations), angles taken modulo their period.

mod map;
mod split_hamiltonian;

pub use map::{Map, wrap_coordinate};
pub use split_hamiltonian::SplitHamiltonian;

use crate::integrator::{TangentError, Workspace};

/// How a system's time advances.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Time {
    /// A flow sampled by a fixed step `h`: step `n` is time `n h`.
    Continuous { h: f64 },
    /// A map: step `n` is iteration `n`.
    Discrete,
}

/// One interface for every system the engine runs.
pub trait DynamicalSystem: Send + Sync {
    /// The model's name as written in configs.
    fn name(&self) -> &str;

    /// Dimension `D` of the state (and of every deviation vector).
    fn dim(&self) -> usize;

    fn time(&self) -> Time;

    /// Advance the state `x` by one step.
    fn step(&self, x: &mut [f64], work: &mut Workspace);

    /// Advance `x` and the deviation vectors stored one after the other in `w` by one step of
    /// the exact tangent map of [`DynamicalSystem::step`] (so VM and MPM see the same dynamics).
    fn step_tangent(
        &self,
        x: &mut [f64],
        w: &mut [f64],
        work: &mut Workspace,
    ) -> Result<(), TangentError>;

    /// Why the variational method cannot be used (a derivative the system lacks, naming the
    /// operation); `None` when it can.
    fn no_tangent_reason(&self) -> Option<String>;

    /// The conserved quantity reported beside the indicators (a Hamiltonian's energy), if any.
    fn invariant(&self, x: &[f64]) -> Option<f64>;

    /// What made a state non-finite when stepped from `x` (the last finite state), naming the
    /// operation where the system knows it. Off the hot path: called after a failure.
    fn diagnose_non_finite(&self, x: &[f64]) -> Option<String>;

    /// The separation `out = y - x` of a nearby state `y` from the reference `x`, as the
    /// multi-particle method measures it: the plain difference, except on a system with
    /// periodic coordinates (a map's angles), whose separations are taken on the torus.
    #[inline]
    fn separation(&self, y: &[f64], x: &[f64], out: &mut [f64]) {
        for ((o, a), b) in out.iter_mut().zip(y).zip(x) {
            *o = a - b;
        }
    }
}
