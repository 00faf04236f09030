//! Dynamical systems as the engine sees them.
//!
//! The engine, the deviation dynamics (VM, MPM) and the indicators do not care what a system is
//! made of: they need a state of dimension `D`, one step of its evolution, one step of the exact
//! tangent map of that evolution (for the variational method), and whatever invariant it
//! conserves (for the report). [`DynamicalSystem`] is that interface, in the shape of
//! DynamicalSystemsBase.jl's: a continuous or discrete system advanced by `step`, around which
//! the deviation methods of this crate ([`crate::method`]: tangent vectors, nearby orbits) work
//! for *any* system, in the engine and, through the system's batched form, in the maps.
//!
//! Kinds, one file each:
//! - [`SplitHamiltonian`]: a separable Hamiltonian [`SeparableHamiltonian`](crate::model::SeparableHamiltonian) with a
//!   symplectic [`Splitting`](crate::integrator::Splitting) (built-in models and `[model] name =
//!   "potential"`);
//! - [`RkFlow`]: a vector field `dx/dt = f(x)` with a Runge-Kutta method (its tangent map is the
//!   derivative of the Runge-Kutta step, from the field's Jacobian-vector product): `[model]
//!   name = "ode"`, and any Hamiltonian `H(q, p)` (`name = "hamiltonian"`, whose field is
//!   `(dH/dp, -dH/dq)`), explicit (`rk4`, `dop853`) or implicit symplectic Gauss-Legendre
//!   (`gl4`, `gl6`);
//! - [`TaylorFlow`]: the same fields written as expressions, with Taylor's method
//!   (`integrator.method = "taylor"`): the series of the solution and of its variational
//!   equations by automatic differentiation of the expressions, order and steps from `tol`;
//! - [`DdnlsSystem`]: the disordered discrete nonlinear Schroedinger lattice (`[model] name =
//!   "ddnls"`), a Hamiltonian not separable into `T(p) + V(q)`, stepped by a composition of its
//!   three parts' exact flows (`integrator::composition`) with their exact tangent maps;
//! - [`Map`]: a discrete map `x -> F(x)` (`[model] name = "map"`, `Time::Discrete`, `tau`
//!   counted in iterations), angles taken modulo their period.
//!
//! Time: every step is given the time it starts at, `t = n h` for step `n` (computed, never
//! accumulated: [`Time::at`]), so a non-autonomous system (`t` read by a flow's `rhs`, a
//! Hamiltonian or a potential) is stepped at the right times by the engine, its deviation
//! sets and the batched kernels alike; each integrator says how the time enters its stages.
//! Runs start at `t = 0`.
//!
//! Each kind's batched form (`batched`: many orbits as lanes, for phase-space maps) is written
//! beside it, in its own file.

mod ddnls;
mod map;
mod rk_flow;
mod split_hamiltonian;
mod taylor_flow;

pub use ddnls::DdnlsSystem;
pub use map::Map;
pub use rk_flow::RkFlow;
pub use split_hamiltonian::SplitHamiltonian;
pub use taylor_flow::TaylorFlow;

use chaoscope_schemas::run::SystemClass;

use crate::batch::{Isa, PointKernel};
use crate::integrator::{TangentError, Workspace};
use crate::model::KernelBuild;

/// How much |x| must grow, from the start of a step whose adaptive substeps collapsed to the
/// last state they reached, for the collapse to be the solution's blow-up (an escape) rather
/// than the integrator's failure. A collapse takes the substep 14 decades below the step: a
/// solution blowing up like (t* - t)^-p grows by 10^(14 p) over them, a hundredfold for any
/// p above 1/7 (x' = x^2: p = 1), while one that stays within a factor 100 of where it was
/// (beyond |x| = 1: a state near 0 may grow by much and stay small) did not run away, and the
/// step failed for the field's sake (not smooth enough there, or undefined just beyond).
pub(crate) const BLOW_UP_GROWTH: f64 = 100.0;

/// How a system's time advances.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Time {
    /// A flow sampled by a fixed step `h`: step `n` is time `n h`.
    Continuous { h: f64 },
    /// A map: step `n` is iteration `n`.
    Discrete,
}

impl Time {
    /// The time of step `step`: `step * h` (an iteration count for a map), computed from the
    /// step number and never accumulated, as `RunSpec::time_of`.
    #[inline]
    pub fn at(self, step: u64) -> f64 {
        match self {
            Time::Continuous { h } => step as f64 * h,
            Time::Discrete => step as f64,
        }
    }

    /// As recordings name it (`RunHeader.time`).
    pub fn name(self) -> &'static str {
        match self {
            Time::Continuous { .. } => "continuous",
            Time::Discrete => "discrete",
        }
    }
}

/// One interface for every system the engine runs.
pub trait DynamicalSystem: Send + Sync {
    /// The model's name as written in configs.
    fn name(&self) -> &str;

    fn kind(&self) -> SystemClass;

    /// Dimension `D` of the state (and of every deviation vector).
    fn dim(&self) -> usize;

    fn time(&self) -> Time;

    /// Whether the system depends on the time (a non-autonomous flow, Hamiltonian or
    /// potential): its steps depend on the `t` they are given.
    fn reads_time(&self) -> bool {
        false
    }

    /// Advance the state `x` by one step from time `t`.
    fn step(&self, x: &mut [f64], t: f64, work: &mut Workspace);

    /// Advance `x` and the deviation vectors stored one after the other in `w` by one step
    /// from time `t` of the exact tangent map of [`DynamicalSystem::step`] (so VM and MPM see
    /// the same dynamics).
    fn step_tangent(
        &self,
        x: &mut [f64],
        w: &mut [f64],
        t: f64,
        work: &mut Workspace,
    ) -> Result<(), TangentError>;

    /// Why the variational method cannot be used (a derivative the system lacks, naming the
    /// operation); `None` when it can.
    fn no_tangent_reason(&self) -> Option<String>;

    /// The conserved quantity reported beside the indicators (a Hamiltonian's energy), if any;
    /// `None` for a system that reads the time (its energy is not conserved).
    fn invariant(&self, x: &[f64]) -> Option<f64>;

    /// The local rate of phase-space volume change at `x`, whose average along the orbit the
    /// report carries beside the sum of the Lyapunov exponents: `div f(x)` (the trace of the
    /// Jacobian) for a flow, `ln |det DF(x)|` per iteration for a map. `None` for systems that
    /// conserve volume by construction (Hamiltonians). At time `t`.
    fn divergence(&self, x: &[f64], t: f64) -> Option<f64>;

    /// The vector field `out = f(x, t)`, the flow direction at `x` (the orthogonal FLI reads
    /// the deviation's component across it), and true; false for a system without one (a map:
    /// its time is discrete). Off the hot path: once per renormalization of the reference.
    fn vector_field(&self, x: &[f64], t: f64, out: &mut [f64]) -> bool {
        let _ = (x, t, out);
        false
    }

    /// What made a state non-finite when stepped from `x` (the last finite state) at time `t`,
    /// naming the operation where the system knows it. Off the hot path: called after a
    /// failure.
    fn diagnose_non_finite(&self, x: &[f64], t: f64) -> Option<String>;

    /// The system's batched form, its one extension point for it: many orbits (and tangent
    /// vectors along a recorded reference) advanced together as lanes, on the instruction set
    /// `isa` where the kind has per-ISA code; what phase-space maps run on. `None` for a system
    /// without one, whose map points run through the engine (same bits, one orbit at a time).
    fn batched(&self, isa: Isa) -> Option<Box<dyn PointKernel + '_>> {
        let _ = isa;
        None
    }

    /// Its steps' substeps, where the state chooses them (adaptive step-size control); `None`
    /// for fixed steps, whose every step is `step`.
    fn adaptive(&self) -> Option<&dyn AdaptiveSteps> {
        None
    }

    /// Its fused pass of the orbit with a small set of tangent vectors, where a set may step
    /// with its own copy of the reference and that copy serve as the reference (its tangent
    /// steps move the orbit exactly as `step` does). A run then integrates the orbit once, not
    /// once more beside such a set. `None` for a system without.
    fn reference_tangent(&self) -> Option<&dyn ReferenceTangent> {
        None
    }

    /// The separable Hamiltonian behind this system (its model, splitting and step), for what
    /// only separable Hamiltonians offer: solving the energy for a momentum (maps' grid
    /// points), Poincare sections, `N` in the run header. `None` for every other kind.
    fn separable(&self) -> Option<&SplitHamiltonian> {
        None
    }

    /// The energy of each site of the lattice Hamiltonian's state `x` (`N` values into `out`,
    /// the weights of the energy distribution): a separable Hamiltonian's model's
    /// ([`crate::model::SeparableHamiltonian::site_energies`]), a Hamiltonian written as lattice sums'
    /// ([`VectorField::site_energies`]). An error saying why for any other system.
    fn site_energies(&self, x: &[f64], out: &mut [f64]) -> Result<(), String> {
        match self.separable() {
            Some(s) => s.model().site_energies(x, out),
            None => Err(no_site_energies(self.name())),
        }
    }

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

/// Steps whose substeps the state chooses: the reference records them in a plan and every
/// deviation set follows the very same substeps, so every scheme sees one trajectory.
pub trait AdaptiveSteps {
    /// Advance the reference orbit by one step from time `t`, appending to `plan` the substeps
    /// it took.
    fn step_reference(&self, x: &mut [f64], t: f64, plan: &mut Vec<f64>, work: &mut Workspace);

    /// Advance `x` by one step from time `t` along the substeps `plan` the reference took.
    fn step_along(&self, x: &mut [f64], t: f64, plan: &[f64], work: &mut Workspace);

    /// [`DynamicalSystem::step_tangent`] along the substeps `plan` the reference took.
    fn step_tangent_along(
        &self,
        x: &mut [f64],
        w: &mut [f64],
        t: f64,
        plan: &[f64],
        work: &mut Workspace,
    ) -> Result<(), TangentError>;

    /// Whether a run can be resumed from a recorded sample (`chaoscope resume`): only if a step
    /// carries nothing from the steps before it that a sample does not hold.
    fn resumable(&self) -> Result<(), String> {
        Ok(())
    }

    /// Whether [`AdaptiveSteps::step_reference_tangent`] steps the reference and a set of
    /// tangent vectors in one pass, cheaper than the two apart (a system whose tangent pass
    /// computes the orbit anyway): then a run steps its first plain VM set with the reference.
    fn steps_reference_with_tangents(&self) -> bool {
        false
    }

    /// [`AdaptiveSteps::step_reference`] of `x` and [`AdaptiveSteps::step_tangent_along`] of
    /// the vectors `w` along its substeps, in one call: bit for bit the two apart, which is
    /// what this default does.
    fn step_reference_tangent(
        &self,
        x: &mut [f64],
        w: &mut [f64],
        t: f64,
        plan: &mut Vec<f64>,
        work: &mut Workspace,
    ) -> Result<(), TangentError> {
        let mut along = x.to_vec();
        let before = plan.len();
        self.step_reference(x, t, plan, work);
        self.step_tangent_along(&mut along, w, t, &plan[before..], work)
    }
}

/// A fused pass of the orbit and a small set of tangent vectors ([`DynamicalSystem::reference_tangent`]).
pub trait ReferenceTangent {
    /// A run of `work` state-value steps (steps times the dimension) will call
    /// [`ReferenceTangent::steps`]: build what it needs, where that repays and `build` allows.
    fn prepare(&self, work: u64, build: KernelBuild) {
        let _ = (work, build);
    }

    /// `steps` steps, the first of them step number `from`, of the orbit `x` and the tangent
    /// vectors `v` around it (stored one after the other), in one fused pass: bit for bit
    /// `step` of `x` and `step_tangent` of `v` along it. False, with nothing stepped, where the
    /// system has no such kernel now (its caller steps them one step at a time).
    fn steps(&self, x: &mut [f64], v: &mut [f64], from: u64, steps: u64) -> bool {
        let _ = (x, v, from, steps);
        false
    }
}

/// What every system offers through its capabilities, with the plain steps where it has none.
impl dyn DynamicalSystem + '_ {
    /// Advance the reference orbit by one step from time `t`, appending its substeps to `plan`
    /// where the system chooses them ([`AdaptiveSteps`]).
    pub fn step_reference(&self, x: &mut [f64], t: f64, plan: &mut Vec<f64>, work: &mut Workspace) {
        match self.adaptive() {
            Some(a) => a.step_reference(x, t, plan, work),
            None => self.step(x, t, work),
        }
    }

    /// Advance `x` by one step from time `t` along the reference's substeps `plan`.
    pub fn step_along(&self, x: &mut [f64], t: f64, plan: &[f64], work: &mut Workspace) {
        match self.adaptive() {
            Some(a) => a.step_along(x, t, plan, work),
            None => self.step(x, t, work),
        }
    }

    /// [`DynamicalSystem::step_tangent`] along the reference's substeps `plan`.
    pub fn step_tangent_along(
        &self,
        x: &mut [f64],
        w: &mut [f64],
        t: f64,
        plan: &[f64],
        work: &mut Workspace,
    ) -> Result<(), TangentError> {
        match self.adaptive() {
            Some(a) => a.step_tangent_along(x, w, t, plan, work),
            None => self.step_tangent(x, w, t, work),
        }
    }
}

/// Why the system `name` has no site energies.
pub(crate) fn no_site_energies(name: &str) -> String {
    format!(
        "site energies are given for lattice Hamiltonians (fput-beta, a potential or a \
         hamiltonian written as lattice sums); '{name}' is not one"
    )
}
