//! The renormalization window, one definition for runs ([`crate::engine`]) and map points
//! ([`crate::map`]): when a window ends ([`Window`]), the escape test of the reference at its end
//! and the error naming the step that left ([`check_reference`]), and the renormalization of a
//! set of deviations with what is handed on (the separations before it and their stretching
//! factors: [`renormalize`], [`deviations`], [`restart`]).
//!
//! Sans-io: each function takes the state and says what happened. An escaping orbit is reported
//! the same way by a run and by a map point of the same initial condition: the same time (the
//! end of the window it was found in), the same verdict and the same message.

use crate::batch::{PointKernel, Soa};
use crate::integrator::{TangentError, Workspace};
use crate::method::DeviationMethod;
use crate::renormalization::{self, RenormalizationError};
use crate::spec::RunSpec;
use chaoscope_schemas::run::{ADAPTIVE_STEP_FAILED, IMPLICIT_NOT_CONVERGED, INTEGRATOR_FAILED};
use chaoscope_schemas::run::{REFERENCE_ESCAPED, SchemeSpec};

/// Beyond this norm a state is treated as escaped: polynomial forces overflow soon after.
pub const ESCAPE_NORM: f64 = 1e100;

/// A run (or a map point) that could not go on.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum RunError {
    // Begins with `REFERENCE_ESCAPED`, which the verdict reads back from the end-of-run reason.
    #[error("{REFERENCE_ESCAPED} by t = {t} (|x| = {norm:e}){}",
        cause.as_ref().map(|c| format!(": {c}")).unwrap_or_default())]
    Escaped {
        t: f64,
        norm: f64,
        /// The operation that produced a non-finite value, where the system knows it.
        cause: Option<String>,
    },
    // Begins with `INTEGRATOR_FAILED`, which the verdict reads back (`failed`, not `escaped`).
    #[error("{INTEGRATOR_FAILED} by t = {t}: {cause}")]
    IntegratorFailed {
        /// The time the failed step was to reach.
        t: f64,
        /// The integrator's own reason.
        cause: String,
    },
    #[error("scheme '{scheme}', set {set}, t = {t}: {source}")]
    Renormalization {
        scheme: String,
        set: u32,
        t: f64,
        source: RenormalizationError,
    },
    #[error(transparent)]
    Tangent(#[from] TangentError),
}

impl RunError {
    /// The time the run stopped at (a tangent map the system lacks stops it before it starts).
    pub fn t(&self) -> f64 {
        match self {
            RunError::Escaped { t, .. }
            | RunError::IntegratorFailed { t, .. }
            | RunError::Renormalization { t, .. } => *t,
            RunError::Tangent(_) => 0.0,
        }
    }
}

/// One window: advance `steps` steps from step number `from`, then renormalize at time `t`.
#[derive(Debug, Clone, Copy)]
pub struct Window {
    pub from: u64,
    pub steps: u64,
    pub t: f64,
    /// The run's final step.
    pub last: bool,
}

impl Window {
    /// The window from step `from`: to the next renormalization of any of the run's schemes,
    /// cut at the run's last step; `None` once the run is complete.
    pub fn after(run: &RunSpec, from: u64) -> Option<Window> {
        let total = run.total_steps();
        if from >= total {
            return None;
        }
        let end = run
            .schemes()
            .iter()
            .map(|s| (from / s.tau_steps + 1) * s.tau_steps)
            .min()
            .unwrap_or(total)
            .min(total);
        Some(Window {
            from,
            steps: end - from,
            t: run.time_of(end),
            last: end == total,
        })
    }

    /// The step the window ends at.
    pub fn end(&self) -> u64 {
        self.from + self.steps
    }

    /// Whether `scheme` renormalizes at the window's end (every `tau`, and at the run's end).
    pub fn renormalizes(&self, scheme: &SchemeSpec) -> bool {
        self.end().is_multiple_of(scheme.tau_steps) || self.last
    }
}

fn norm_of(v: &[f64]) -> f64 {
    v.iter().map(|v| v * v).sum::<f64>().sqrt()
}

/// The escape test of the reference at the end of window `w`: `x` its state there, `start` its
/// state at the window's start (where the failing step is searched from), `divergence` the
/// divergence at `x` and its integral where the caller integrates it along the orbit (else the
/// divergence at `x` is evaluated). A NaN norm counts as escaped, and so does a state whose
/// invariant or divergence is not finite (a potential or vector field undefined there: no NaN
/// may reach an output).
pub fn check_reference(
    run: &RunSpec,
    start: &[f64],
    x: &[f64],
    w: &Window,
    divergence: Option<(f64, f64)>,
) -> Result<(), RunError> {
    let system = run.system();
    let norm = norm_of(x);
    let defined = system.invariant(x).is_none_or(|e| e.is_finite())
        && match divergence {
            Some((d, integral)) => d.is_finite() && integral.is_finite(),
            None => system.divergence(x, w.t).is_none_or(|d| d.is_finite()),
        };
    if norm.is_nan() || norm >= ESCAPE_NORM || !defined {
        return Err(escape_error(run, start.to_vec(), w, norm));
    }
    Ok(())
}

/// The error for an orbit found non-finite or escaped by the end of window `w` (the time every
/// driver names): steps again from the window's start `last_good` to the first step that leaves
/// it, and names that step's time or iteration and, where the system knows it, the operation
/// that failed.
fn escape_error(run: &RunSpec, last_good: Vec<f64>, w: &Window, norm: f64) -> RunError {
    let system = run.system().as_ref();
    let mut x = last_good;
    let mut work = Workspace::new();
    let mut cause = None;
    let mut plan = Vec::new();
    for step in w.from..w.end() {
        let before = x.clone();
        let t_before = run.time_of(step);
        plan.clear();
        system.step_reference(&mut x, t_before, &mut plan, &mut work);
        let t_after = run.time_of(step + 1);
        let at = format!("in the step to t = {t_after}");
        if x.iter().any(|v| !v.is_finite()) {
            let why = system.diagnose_non_finite(&before, t_before);
            // From a finite state within the bound, a step the integrator could not take is its
            // failure, not the orbit's escape.
            if let Some(why) = &why
                && (why.contains(IMPLICIT_NOT_CONVERGED) || why.starts_with(ADAPTIVE_STEP_FAILED))
            {
                return RunError::IntegratorFailed {
                    t: t_after,
                    cause: format!("{why} {at}"),
                };
            }
            cause = Some(
                why.map_or(format!("the state became non-finite {at}"), |c| {
                    format!("{c} {at}")
                }),
            );
            break;
        }
        if system.invariant(&x).is_some_and(|e| !e.is_finite())
            || system
                .divergence(&x, t_after)
                .is_some_and(|d| !d.is_finite())
        {
            cause = Some(
                system
                    .diagnose_non_finite(&x, t_after)
                    .map_or(format!("the system is not defined {at}"), |c| {
                        format!("{c} {at}")
                    }),
            );
            break;
        }
        if norm_of(&x) >= ESCAPE_NORM {
            cause = Some(format!("|x| passed {ESCAPE_NORM:e} {at}"));
            break;
        }
    }
    RunError::Escaped {
        t: w.t,
        norm,
        cause,
    }
}

/// Renormalizes the `k` deviation vectors of set `set` of scheme `scheme` in place to the
/// scheme's `d0` (each rescaled, or by QR: its `orthonormalize`), writing their stretching
/// factors to `stretch`: the one renormalization of runs, resumed runs and map points.
pub fn renormalize(
    run: &RunSpec,
    scheme: usize,
    set: usize,
    vectors: &mut [f64],
    stretch: &mut [f64],
    t: f64,
) -> Result<(), RunError> {
    let s = &run.schemes()[scheme];
    renormalization::renormalize(vectors, run.dim(), s.d0, s.orthonormalize, stretch)
        .map_err(|source| renormalization_error(run, scheme, set, t, source))
}

/// A failed renormalization of set `set` of scheme `scheme` at time `t`.
pub fn renormalization_error(
    run: &RunSpec,
    scheme: usize,
    set: usize,
    t: f64,
    source: RenormalizationError,
) -> RunError {
    RunError::Renormalization {
        scheme: run.schemes()[scheme].name.clone(),
        set: set as u32,
        t,
        source,
    }
}

/// The deviations from the reference state `x` that the consecutive lanes of `lanes` from
/// `first` hold, one row of `out` (of `x`'s dimension `dim`) per lane; `lane` is scratch space
/// of `dim` values.
pub fn deviations(
    method: &dyn DeviationMethod,
    kernel: &dyn PointKernel,
    lanes: &Soa,
    first: usize,
    x: &[f64],
    out: &mut [f64],
    lane: &mut [f64],
) {
    for (i, d) in out.chunks_exact_mut(lane.len()).enumerate() {
        lanes.read_lane(first + i, lane);
        method.deviation(kernel, lane, x, d);
    }
}

/// Restarts the consecutive lanes of `lanes` from `first` from the deviations `d` (rows of the
/// length of `lane`, scratch space) around the reference state `x`.
pub fn restart(
    method: &dyn DeviationMethod,
    lanes: &mut Soa,
    first: usize,
    x: &[f64],
    d: &[f64],
    lane: &mut [f64],
) {
    for (i, d) in d.chunks_exact(lane.len()).enumerate() {
        method.start(x, d, lane);
        lanes.write_lane(first + i, lane);
    }
}
