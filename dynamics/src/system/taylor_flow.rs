//! A flow `dx/dt = f(x, t)` written as expressions, advanced by Taylor's method
//! (`integrator.method = "taylor"`, [`crate::integrator::taylor`]).
//!
//! An engine step spans one interval of the time grid (multiples of `h`): the state chooses
//! its Taylor steps there from its own series and lands exactly on the grid point. The tangent
//! vectors of the variational method ride on the same series: the tape carries the
//! variational equations `dv/dt = J(x, t) v` beside the state's, so their Taylor steps are
//! the state's (the state's series never read the vectors', and the steps are chosen from the
//! state's alone: the orbit moves bit for bit as without them). The multi-particle method's
//! nearby orbits follow the reference's steps (`step_along`). A step depends only on the state
//! it starts from, so a run resumes bit for bit from a recorded sample.

use std::sync::{Arc, OnceLock};

use chaoscope_expr::VectorFunction;
use chaoscope_expr::taylor::{NativeBuild, TaylorTape};
use chaoscope_schemas::run::SystemClass;

use super::{AdaptiveSteps, BLOW_UP_GROWTH, DynamicalSystem, Time};
use crate::integrator::taylor::{Taylor, TaylorStepError};
use crate::integrator::{TangentError, Workspace};
use crate::vector_field::VectorField;

/// A tape and the background build of its compiled pass.
type BuiltTape = (Arc<TaylorTape>, Option<NativeBuild>);

/// `dx/dt = f(x, t)` by Taylor's method on the time grid of `h`.
pub struct TaylorFlow {
    /// The name recordings carry (`"ode"`, `"hamiltonian"`).
    pub name: String,
    field: Arc<dyn VectorField>,
    taylor: Taylor,
    h: f64,
    /// The tape of the state alone, and those with `k` vectors (built when first asked for),
    /// each with the background build of its compiled pass (stopped when the system is
    /// dropped).
    tapes: Vec<OnceLock<Result<BuiltTape, String>>>,
}

impl TaylorFlow {
    /// The flow of `field` (compiled from expressions) at tolerance `tol` on the grid `h`;
    /// `Err` naming the operation that has no Taylor series.
    pub fn new(name: &str, field: Arc<dyn VectorField>, tol: f64, h: f64) -> Result<Self, String> {
        let vf = field.compiled().ok_or_else(|| {
            "taylor needs a right-hand side written as expressions (rhs or H)".to_string()
        })?;
        let taylor = Taylor::new(tol);
        let dim = vf.dim();
        let tapes: Vec<_> = (0..=dim).map(|_| OnceLock::new()).collect();
        let own = vf.taylor_tape_compiled(0, taylor.order);
        if let Err(e) = tapes[0].get_or_init(|| own) {
            return Err(e.clone());
        }
        Ok(Self {
            name: name.to_string(),
            field,
            taylor,
            h,
            tapes,
        })
    }

    fn function(&self) -> &VectorFunction {
        self.field.compiled().expect("checked in new")
    }

    fn tape(&self, vectors: usize) -> Result<&Arc<TaylorTape>, String> {
        let Some(cell) = self.tapes.get(vectors) else {
            return Err(format!(
                "{vectors} tangent vectors of a {}-dimensional flow",
                self.dim()
            ));
        };
        cell.get_or_init(|| {
            self.function()
                .taylor_tape_compiled(vectors, self.taylor.order)
        })
        .as_ref()
        .map(|(tape, _)| tape)
        .map_err(Clone::clone)
    }

    /// The reference's tape (built in `new`).
    fn own_tape(&self) -> &Arc<TaylorTape> {
        self.tapes[0]
            .get()
            .and_then(|t| t.as_ref().ok())
            .map(|(tape, _)| tape)
            .expect("built in new")
    }

    #[allow(clippy::too_many_arguments)]
    fn advance(
        &self,
        tape: &TaylorTape,
        x: &mut [f64],
        w: &mut [f64],
        t: f64,
        plan: Option<&[f64]>,
        taken: Option<&mut Vec<f64>>,
        work: &mut Workspace,
    ) -> Result<(), TaylorStepError> {
        let coef = work.taylor.buffer(tape);
        self.taylor
            .advance(tape, coef, x, w, t, t + self.h, plan, taken)
    }
}

impl DynamicalSystem for TaylorFlow {
    fn name(&self) -> &str {
        &self.name
    }

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

    fn step(&self, x: &mut [f64], t: f64, work: &mut Workspace) {
        self.step_reference(x, t, &mut Vec::new(), work);
    }

    fn step_tangent(
        &self,
        x: &mut [f64],
        w: &mut [f64],
        t: f64,
        work: &mut Workspace,
    ) -> Result<(), TangentError> {
        let tape = Arc::clone(
            self.tape(w.len() / self.dim())
                .map_err(TangentError::NoHessian)?,
        );
        if self.advance(&tape, x, w, t, None, None, work).is_err() {
            x.fill(f64::NAN);
        }
        Ok(())
    }

    fn no_tangent_reason(&self) -> Option<String> {
        self.field.no_tangent_reason()
    }

    fn invariant(&self, x: &[f64]) -> Option<f64> {
        self.field.invariant(x)
    }

    fn site_energies(&self, x: &[f64], out: &mut [f64]) -> Result<(), String> {
        self.field.site_energies(x, out, &self.name)
    }

    fn divergence(&self, x: &[f64], t: f64) -> Option<f64> {
        self.field.volume_rate(x, t)
    }

    fn vector_field(&self, x: &[f64], t: f64, out: &mut [f64]) -> bool {
        self.field.value(x, t, out);
        true
    }

    fn diagnose_non_finite(&self, x: &[f64], t: f64) -> Option<String> {
        if let Some(cause) = self.field.diagnose_non_finite(x, t) {
            return Some(cause);
        }
        let mut y = x.to_vec();
        let mut work = Workspace::new();
        let tape = Arc::clone(self.own_tape());
        let e = self
            .advance(&tape, &mut y, &mut [], t, None, None, &mut work)
            .err()?;
        // As adaptive dop853: a collapse while the state ran away is the solution's blow-up
        // (an escape); one where it stayed within a hundredfold is the method's failure.
        let norm = |v: &[f64]| v.iter().map(|a| a * a).sum::<f64>().sqrt();
        let (from, to) = (norm(x), norm(&y));
        Some(if to >= BLOW_UP_GROWTH * from.max(1.0) {
            format!(
                "{e}, |x| having grown from {from:e} to {to:e} within the step (the solution blows up)"
            )
        } else {
            format!(
                "{}: {e}, at |x| = {to:e}",
                chaoscope_schemas::run::ADAPTIVE_STEP_FAILED
            )
        })
    }

    fn adaptive(&self) -> Option<&dyn AdaptiveSteps> {
        Some(self)
    }
}

impl AdaptiveSteps for TaylorFlow {
    fn step_reference(&self, x: &mut [f64], t: f64, plan: &mut Vec<f64>, work: &mut Workspace) {
        let tape = Arc::clone(self.own_tape());
        if self
            .advance(&tape, x, &mut [], t, None, Some(plan), work)
            .is_err()
        {
            // The engine stops the run at a non-finite state and asks `diagnose_non_finite`.
            x.fill(f64::NAN);
        }
    }

    fn step_along(&self, x: &mut [f64], t: f64, plan: &[f64], work: &mut Workspace) {
        let tape = Arc::clone(self.own_tape());
        // Steps given: nothing can fail but the values, which the engine checks.
        let _ = self.advance(&tape, x, &mut [], t, Some(plan), None, work);
    }

    fn step_tangent_along(
        &self,
        x: &mut [f64],
        w: &mut [f64],
        t: f64,
        plan: &[f64],
        work: &mut Workspace,
    ) -> Result<(), TangentError> {
        let tape = Arc::clone(
            self.tape(w.len() / self.dim())
                .map_err(TangentError::NoHessian)?,
        );
        let _ = self.advance(&tape, x, w, t, Some(plan), None, work);
        Ok(())
    }

    /// The tangent tape computes the state's series anyway, and the steps are the state's:
    /// one pass gives the reference and the vectors (a separate reference pass, latency-bound,
    /// costs a third of the tangent pass of Lorenz with three vectors).
    fn steps_reference_with_tangents(&self) -> bool {
        true
    }

    fn step_reference_tangent(
        &self,
        x: &mut [f64],
        w: &mut [f64],
        t: f64,
        plan: &mut Vec<f64>,
        work: &mut Workspace,
    ) -> Result<(), TangentError> {
        let tape = Arc::clone(
            self.tape(w.len() / self.dim())
                .map_err(TangentError::NoHessian)?,
        );
        if self
            .advance(&tape, x, w, t, None, Some(plan), work)
            .is_err()
        {
            x.fill(f64::NAN);
        }
        Ok(())
    }
}
