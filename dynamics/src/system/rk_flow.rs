//! A flow `dx/dt = f(x)` advanced by an explicit Runge-Kutta method.
//!
//! With a fixed step every engine step is one Runge-Kutta step of size `h`. With error control
//! (adaptive `dop853`) an engine step spans one interval of the time grid (multiples of `h`):
//! the reference orbit chooses its substeps there and lands exactly on the grid point, and the
//! deviation sets (VM's tangent vectors, MPM's nearby orbits) take the very same substeps
//! ([`AdaptiveSteps::step_along`]), so every scheme sees one trajectory, whatever `tau`.
//!
//! A field that reads the time is evaluated at each stage's time (`t + c_i h`, see
//! `integrator::runge_kutta`), the substeps of an adaptive step at the times the reference
//! gave them; its energy (a Hamiltonian `H(q, p, t)`) is not conserved, so it reports none.

use std::sync::Arc;

use chaoscope_schemas::run::SystemClass;

use chaoscope_expr::VectorFunction;

use super::{AdaptiveSteps, BLOW_UP_GROWTH, DynamicalSystem, Time};
use crate::batch::{self, FlowScratch, Isa, PointKernel, Soa};
use crate::integrator::runge_kutta::{RungeKutta, Tableau, Tolerances, substep_times};
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
    /// The substeps of a step from time `t` with their start times: a fixed-step flow's one
    /// substep `h` at `t`, or the plan's, each at `t` plus the substeps before it
    /// (`substep_times`, the times `step_adaptive` gave them).
    fn substeps<'a>(&'a self, t: f64, plan: &'a [f64]) -> impl Iterator<Item = (f64, f64)> + 'a {
        let fixed = self.tolerances.is_none().then_some((t, self.h));
        fixed.into_iter().chain(substep_times(t, plan))
    }
}

impl DynamicalSystem for RkFlow {
    fn name(&self) -> &str {
        &self.name
    }

    /// A Hamiltonian vector field is reported as a Hamiltonian (its energy error), whatever
    /// the method; any other field as a flow.
    fn kind(&self) -> SystemClass {
        self.field.class()
    }

    fn dim(&self) -> usize {
        self.field.dim()
    }

    fn time(&self) -> Time {
        Time::Continuous { h: self.h }
    }

    fn reads_time(&self) -> bool {
        self.field.reads_time()
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

    fn step(&self, x: &mut [f64], t: f64, work: &mut Workspace) {
        match self.tolerances {
            None => self
                .method
                .advance(self.field.as_ref(), x, t, self.h, &mut work.rk),
            Some(_) => {
                let mut plan = Vec::new();
                self.step_reference(x, t, &mut plan, work);
            }
        }
    }

    fn step_tangent(
        &self,
        x: &mut [f64],
        w: &mut [f64],
        t: f64,
        work: &mut Workspace,
    ) -> Result<(), TangentError> {
        match self.tolerances {
            None => self
                .method
                .advance_tangent(self.field.as_ref(), x, w, t, self.h, &mut work.rk),
            Some(_) => {
                // Choose the substeps as the reference does, then follow them.
                let mut plan = Vec::new();
                let mut probe = x.to_vec();
                self.step_reference(&mut probe, t, &mut plan, work);
                self.step_tangent_along(x, w, t, &plan, work)
            }
        }
    }

    fn no_tangent_reason(&self) -> Option<String> {
        self.field.no_tangent_reason()
    }

    /// The energy of a Hamiltonian field, conserved unless `H` reads the time.
    fn invariant(&self, x: &[f64]) -> Option<f64> {
        self.field.invariant(x)
    }

    fn site_energies(&self, x: &[f64], out: &mut [f64]) -> Result<(), String> {
        self.field.site_energies(x, out, &self.name)
    }

    /// `None` for a Hamiltonian field: its flow conserves volume (`div f = 0` identically).
    fn divergence(&self, x: &[f64], t: f64) -> Option<f64> {
        self.field.volume_rate(x, t)
    }

    fn vector_field(&self, x: &[f64], t: f64, out: &mut [f64]) -> bool {
        self.field.value(x, t, out);
        true
    }

    fn diagnose_non_finite(&self, x: &[f64], t: f64) -> Option<String> {
        let field = self.field.as_ref();
        if let Some(cause) = field.diagnose_non_finite(x, t) {
            return Some(cause);
        }
        if let Some(tol) = self.tolerances {
            let mut y = x.to_vec();
            let mut scratch = Workspace::new();
            let mut plan = Vec::new();
            if let Err(e) =
                self.method
                    .step_adaptive(field, &mut y, t, self.h, tol, &mut plan, &mut scratch.rk)
            {
                // `y` is the last state the controller accepted before it gave up.
                let norm = |v: &[f64]| v.iter().map(|a| a * a).sum::<f64>().sqrt();
                let (from, to) = (norm(x), norm(&y));
                return Some(if to >= BLOW_UP_GROWTH * from.max(1.0) {
                    format!(
                        "{e}, |x| having grown from {from:e} to {to:e} within the step (the \
                         solution blows up)"
                    )
                } else {
                    format!(
                        "{}: {e}, at |x| = {to:e} (the vector field is not smooth enough there \
                         for the tolerances)",
                        chaoscope_schemas::run::ADAPTIVE_STEP_FAILED
                    )
                });
            }
        }
        if let Some(why) = self.method.implicit_step_fails(field, x, t, self.h) {
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
            let ti = t + tableau.c[i] * self.h;
            let (_, rest) = k.split_at_mut(i * dim);
            field.value(&xi, ti, &mut rest[..dim]);
            if rest[..dim].iter().any(|v| !v.is_finite()) {
                return Some(field.diagnose_non_finite(&xi, ti).unwrap_or_else(|| {
                    format!(
                        "f is not finite at the Runge-Kutta stage {} (the solution blows up)",
                        i + 1
                    )
                }));
            }
        }
        None
    }

    fn adaptive(&self) -> Option<&dyn AdaptiveSteps> {
        Some(self)
    }
}

impl AdaptiveSteps for RkFlow {
    fn step_reference(&self, x: &mut [f64], t: f64, plan: &mut Vec<f64>, work: &mut Workspace) {
        let Some(tol) = self.tolerances else {
            return self.step(x, t, work);
        };
        let field = self.field.as_ref();
        if self
            .method
            .step_adaptive(field, x, t, self.h, tol, plan, &mut work.rk)
            .is_err()
        {
            // The engine stops the run at a non-finite state and asks `diagnose_non_finite`
            // why; no state past the failure is ever published.
            x.fill(f64::NAN);
        }
    }

    fn resumable(&self) -> Result<(), String> {
        match self.tolerances {
            None => Ok(()),
            // The controller's proposal for the next substep: the one thing a sample lacks.
            Some(_) => Err(format!(
                "{} with tolerances chooses each substep from the one before, which a recording \
                 does not keep: a resumed run would take other substeps. Use a fixed step (no \
                 rtol/atol) to make runs resumable, or rerun with a longer t_final",
                self.method.kind.name()
            )),
        }
    }

    fn step_along(&self, x: &mut [f64], t: f64, plan: &[f64], work: &mut Workspace) {
        for (ts, h) in self.substeps(t, plan) {
            self.method
                .advance(self.field.as_ref(), x, ts, h, &mut work.rk);
        }
    }

    fn step_tangent_along(
        &self,
        x: &mut [f64],
        w: &mut [f64],
        t: f64,
        plan: &[f64],
        work: &mut Workspace,
    ) -> Result<(), TangentError> {
        for (ts, h) in self.substeps(t, plan) {
            self.method
                .advance_tangent(self.field.as_ref(), x, w, ts, h, &mut work.rk)?;
        }
        Ok(())
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
    fn orbit_steps(&mut self, x: &mut Soa, from: u64, steps: u64) {
        batch::flow_orbit_steps(
            self.tableau,
            self.f,
            self.h,
            x,
            from,
            steps,
            &mut self.scratch,
        );
    }

    fn reference_steps(&mut self, x: &mut [f64], from: u64, steps: u64) {
        batch::record_flow_reference(
            self.tableau,
            self.f,
            self.h,
            x,
            from,
            steps,
            &mut self.stages,
            &mut self.scratch,
        );
    }

    fn tangent_steps(&mut self, v: &mut Soa, from: u64, steps: u64) -> Result<(), TangentError> {
        if batch::flow_tangent_steps(
            self.tableau,
            self.f,
            self.h,
            &self.stages,
            v,
            from,
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
