//! Renormalization windows of a map point, exactly as the engine schedules them, and what the
//! routes do at the end of a window: the escape test of the reference orbit (both) and each
//! set's renormalization (the per-set route).

use super::indicator::PointAccumulator;
use crate::batch::{PointKernel, Soa};
use crate::engine::RunError;
use crate::method::DeviationMethod;

use crate::renormalization;
use crate::spec::RunSpec;

/// Beyond this norm a state counts as escaped (the engine's criterion).
const ESCAPE_NORM: f64 = 1e100;

fn norm(v: &[f64]) -> f64 {
    v.iter().map(|v| v * v).sum::<f64>().sqrt()
}

/// The engine's escape test of the reference state `x` at time `t`.
pub fn check_escape(x: &[f64], t: f64) -> Result<(), RunError> {
    let norm = norm(x);
    if norm.is_nan() || norm >= ESCAPE_NORM {
        Err(RunError::Escaped {
            t,
            norm,
            cause: None,
        })
    } else {
        Ok(())
    }
}

/// The lanes of one group of points as one lane array (`lanes` is emptied, each of `rows`
/// entries: a state, parameters included, or a deviation vector): both routes batch the lanes
/// of several points so that one kernel call steps them all.
pub fn lane_array(lanes: &mut Vec<Vec<f64>>, rows: usize) -> Soa {
    let mut soa = Soa::new(rows, lanes.len());
    for (l, x) in lanes.drain(..).enumerate() {
        soa.write_lane(l, &x);
    }
    soa
}

/// The reference orbit's lane, pushed onto `lanes`, when the method steps orbits as lanes (MPM:
/// the reference is stepped by the same call as its neighbours); `None` for the tangent method,
/// whose point keeps its reference state outside the lane array.
pub fn push_reference_lane(
    method: &dyn DeviationMethod,
    lanes: &mut Vec<Vec<f64>>,
    x0: &[f64],
) -> Option<usize> {
    method.lanes_are_orbits().then(|| {
        lanes.push(x0.to_vec());
        lanes.len() - 1
    })
}

/// Steps a group's lanes through `steps` steps. With orbit lanes one call steps references and
/// neighbours alike; otherwise the group holds one point, whose reference state `single` is
/// stepped first and its tangent lanes then follow the recorded steps. An error ends every point
/// of the group.
pub fn advance_group(
    kernel: &mut dyn PointKernel,
    method: &dyn DeviationMethod,
    soa: &mut Soa,
    single: Option<&mut [f64]>,
    w: &Window,
) -> Result<(), RunError> {
    if !method.lanes_are_orbits() {
        let x = single.expect("a tangent-method group holds one point");
        kernel.reference_steps(x, w.from, w.steps);
    }
    method
        .advance(kernel, soa, w.from, w.steps)
        .map_err(RunError::from)
}

/// One window: advance `steps` steps from step number `from` (every point starts at step 0,
/// `t = 0`), then renormalize at time `t`.
#[derive(Debug, Clone, Copy)]
pub struct Window {
    pub from: u64,
    pub steps: u64,
    pub t: f64,
    /// The run's final step.
    pub last: bool,
}

/// Windows of `tau_steps` steps, the last one cut at `total_steps` (Engine::next_stop with one
/// scheme).
pub struct Windows<'a> {
    run: &'a RunSpec,
    step: u64,
}

impl<'a> Windows<'a> {
    pub fn new(run: &'a RunSpec) -> Self {
        Self { run, step: 0 }
    }
}

impl Iterator for Windows<'_> {
    type Item = Window;
    fn next(&mut self) -> Option<Window> {
        let total = self.run.total_steps();
        if self.step >= total {
            return None;
        }
        let tau = self.run.schemes()[0].tau_steps;
        let target = ((self.step / tau + 1) * tau).min(total);
        let w = Window {
            from: self.step,
            steps: target - self.step,
            t: self.run.time_of(target),
            last: target == total,
        };
        self.step = target;
        Some(w)
    }
}

/// The renormalization of one deviation set at the end of a window, with its scratch space.
pub struct SetRenormalization<'a> {
    run: &'a RunSpec,
    /// The set's `k` separation vectors (rows of `dim`): the caller fills them before
    /// [`Self::apply`] and, if the set goes on, takes them back renormalized to `d0`.
    pub separations: Vec<f64>,
    /// The separations before renormalization (what the indicator sees).
    raw: Vec<f64>,
    stretch: Vec<f64>,
}

impl<'a> SetRenormalization<'a> {
    pub fn new(run: &'a RunSpec) -> Self {
        Self {
            run,
            separations: vec![0.0; run.k() * run.dim()],
            raw: vec![0.0; run.k() * run.dim()],
            stretch: vec![0.0; run.k()],
        }
    }

    /// Renormalizes the separation vectors of `set` to `d0` as the engine does (each rescaled,
    /// or by QR for `spectrum`: the scheme's `orthonormalize`, checked by the validation), and
    /// hands the vectors before it and their stretching factors to `acc`. `Ok(true)` when the set goes
    /// on, `Ok(false)` when it has finished.
    pub fn apply(
        &mut self,
        acc: &mut PointAccumulator,
        set: usize,
        w: &Window,
    ) -> Result<bool, RunError> {
        let scheme = &self.run.schemes()[0];
        self.raw.copy_from_slice(&self.separations);
        renormalization::renormalize(
            &mut self.separations,
            self.run.dim(),
            scheme.d0,
            scheme.orthonormalize,
            &mut self.stretch,
        )
        .map_err(|source| RunError::Renormalization {
            scheme: scheme.name.clone(),
            set: set as u32,
            t: w.t,
            source,
        })?;
        Ok(!acc.observe(set, w.t, &self.raw, &self.stretch, w.last))
    }
}

/// Keeps the active sets `(set, first lane)` for which `step` returns `Ok(true)`. The first
/// error ends the stepping (the point has failed; the sets after it are kept untouched) and is
/// returned.
pub fn retain_sets(
    sets: &mut Vec<(usize, usize)>,
    mut step: impl FnMut(usize, usize) -> Result<bool, RunError>,
) -> Result<(), RunError> {
    let mut error = None;
    sets.retain(|&(set, lane)| {
        if error.is_some() {
            return true;
        }
        step(set, lane).unwrap_or_else(|e| {
            error = Some(e);
            true
        })
    });
    error.map_or(Ok(()), Err)
}
