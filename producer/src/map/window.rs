//! What both routes of a map do with a group of points around the windows of
//! [`crate::window`]: their lanes as one lane array, a group's steps, the end of a window for a
//! point's reference (the escape test of runs) and for each set (the per-set route's
//! renormalization).

use super::indicator::PointAccumulator;
use crate::batch::{PointKernel, Soa};
use crate::method::DeviationMethod;
use crate::spec::RunSpec;
use crate::window::{self, RunError, Window};

/// A point's reference at the end of window `w`: its state `x` (read from lane `ref_lane` of
/// `soa` when it is an orbit lane, stepped in place otherwise) passes the escape test of runs
/// from `start`, its state at the end of the previous window, which becomes `x`.
pub fn end_reference(
    run: &RunSpec,
    soa: &Soa,
    ref_lane: Option<usize>,
    start: &mut [f64],
    x: &mut [f64],
    w: &Window,
) -> Result<(), RunError> {
    if let Some(r) = ref_lane {
        soa.read_lane(r, x);
    }
    window::check_reference(run, start, x, w, None)?;
    start.copy_from_slice(x);
    Ok(())
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
        self.raw.copy_from_slice(&self.separations);
        window::renormalize(
            self.run,
            0,
            set,
            &mut self.separations,
            &mut self.stretch,
            w.t,
        )?;
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
