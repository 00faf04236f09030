//! What every route of a map does with its points around the windows of [`crate::window`]:
//! the one driver of a route's points through the windows ([`drive`], the points' lanes in lane
//! arrays), a group's steps, the end of a window for a point's reference (the escape test of
//! runs) and for each set (the per-set route's renormalization), and the lane arrays compacted
//! when points leave.

use super::indicator::PointAccumulator;
use super::point::PointResult;
use super::spec::MapSpec;
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

/// Points advanced by one kernel call, `P` a route's point: their lanes.
pub struct Group<P> {
    pub soa: Soa,
    pub points: Vec<P>,
}

/// Drives the points `indices` of a route through the run's windows, as a run's driver does:
/// each point's lanes (of `rows` entries: a state, parameters included, or a deviation vector)
/// appended by `start`, the points in one lane array when `shared` (one kernel call steps them
/// all) or one each, every group handed each window to `window`, which returns the points that
/// finished or failed there (points outside the energy surface are finished from the start).
/// Results in no particular order; once `stop()` (asked at every window) is true, the points
/// finished so far.
pub fn drive<P>(
    spec: &MapSpec,
    indices: &[u64],
    (rows, shared): (usize, bool),
    stop: &dyn Fn() -> bool,
    mut start: impl FnMut(PointResult, Vec<f64>, &mut Vec<Vec<f64>>) -> P,
    mut window: impl FnMut(&mut Group<P>, &Window) -> Vec<PointResult>,
) -> Vec<PointResult> {
    let mut out = Vec::with_capacity(indices.len());
    let mut groups = Vec::new();
    let (mut lanes, mut points) = (Vec::new(), Vec::new());
    let group = |lanes: &mut Vec<Vec<f64>>, points| {
        let mut soa = Soa::new(rows, lanes.len());
        for (l, x) in lanes.drain(..).enumerate() {
            soa.write_lane(l, &x);
        }
        Group { soa, points }
    };
    for &index in indices {
        match spec.start_point(index) {
            Err(outside) => out.push(*outside),
            Ok((base, x0)) => {
                if !shared && !points.is_empty() {
                    groups.push(group(&mut lanes, std::mem::take(&mut points)));
                }
                points.push(start(base, x0, &mut lanes));
            }
        }
    }
    if !points.is_empty() {
        groups.push(group(&mut lanes, points));
    }
    let mut step = 0;
    while !groups.is_empty() && !stop() {
        let Some(w) = Window::after(&spec.run, step) else {
            break;
        };
        step = w.end();
        for g in &mut groups {
            out.extend(window(g, &w));
        }
        groups.retain(|g| !g.points.is_empty());
    }
    out
}

/// Keeps `keep` (of the `before` points the group held at the window's start) as the group's
/// points, each one lane (`lane` of the point), the lane array compacted when some left.
pub fn keep_one_lane_each<P>(
    g: &mut Group<P>,
    mut keep: Vec<P>,
    before: usize,
    lane: fn(&mut P) -> &mut usize,
) {
    if keep.len() != before {
        let runs = keep.iter_mut().map(|p| (lane(p), 1)).collect();
        g.soa = compact(&g.soa, runs);
    }
    g.points = keep;
}

/// A new lane array holding only the runs of lanes `(first, len)` given (those of the points
/// still live), in order; each `first` becomes where its run starts now.
pub fn compact(old: &Soa, runs: Vec<(&mut usize, usize)>) -> Soa {
    let mut soa = Soa::new(old.rows(), runs.iter().map(|(_, n)| n).sum());
    let mut buf = vec![0.0; old.rows()];
    let mut next = 0;
    for (first, n) in runs {
        for j in 0..n {
            old.read_lane(*first + j, &mut buf);
            soa.write_lane(next + j, &buf);
        }
        *first = next;
        next += n;
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
