//! The per-set route of a map: every set's `k` lanes (tangent vectors for VM, nearby orbits for
//! MPM: the scheme's [`DeviationMethod`]) advanced by the system's batched form and renormalized
//! vector by vector every window, as the engine does.
//!
//! Lanes that are orbits share one lane array across several points, each point's reference
//! orbit one more lane of it, all advanced by one kernel call. Tangent lanes follow their own
//! point's reference (stepped first, its steps recorded), so each point has an array of its
//! own, unless the kernel fuses orbits and tangents ([`compute_fused`]): then each point is one
//! lane holding its orbit and every set's vectors, and many points share one lane array. Sets
//! that stop (`gali-time`) and finished points leave: the lanes are compacted so the kernel
//! never integrates a finished orbit.

use super::indicator::{PointAccumulator, broke_off};
use super::point::PointResult;
use super::spec::MapSpec;
use super::window::{
    Group, SetRenormalization, advance_group, compact, drive, end_reference, keep_one_lane_each,
    push_reference_lane, retain_sets,
};
use crate::batch::{Isa, PointKernel};
use crate::method::{self, DeviationMethod};
use crate::window::{self, Window};

/// A point being computed.
struct Live {
    base: PointResult,
    acc: PointAccumulator,
    /// Its reference state: read from lane `ref_lane` when the lanes are orbits, stepped here
    /// by the kernel otherwise.
    x: Vec<f64>,
    ref_lane: Option<usize>,
    /// Its reference state at the end of the last window.
    start: Vec<f64>,
    /// Active sets: (set index, lane of its first vector; the `k` lanes are consecutive).
    sets: Vec<(usize, usize)>,
    orbit_steps: u64,
}

/// Computes the points `indices` (several at once when the method's lanes are orbits); results
/// in no particular order. Once `stop()` (asked at every window) is true, returns the points
/// finished so far. Systems without a batched form are computed one point at a time by the
/// one-orbit engine.
pub fn compute(
    spec: &MapSpec,
    isa: Isa,
    indices: &[u64],
    stop: &dyn Fn() -> bool,
) -> Vec<PointResult> {
    match spec.run.system().batched(isa) {
        Some(mut kernel) => compute_with(kernel.as_mut(), spec, indices, stop),
        None => indices
            .iter()
            .take_while(|_| !stop())
            .map(|&i| super::one_orbit::point(spec, i))
            .collect(),
    }
}

fn compute_with(
    kernel: &mut dyn PointKernel,
    spec: &MapSpec,
    indices: &[u64],
    stop: &dyn Fn() -> bool,
) -> Vec<PointResult> {
    let method = method::of(spec.run.schemes()[0].method);
    let orbits = method.lanes_are_orbits();
    let mut renormalization = SetRenormalization::new(&spec.run);
    drive(
        spec,
        indices,
        (spec.lane_len(orbits), orbits),
        stop,
        |base, x0, lanes| start(spec, method, base, x0, lanes),
        |g, w| window(kernel, method, spec, g, w, &mut renormalization),
    )
}

/// A point of the fused per-set route: one lane of `D (1 + sets k)` rows, its orbit then the
/// `k` tangent vectors of each set.
struct LiveFused {
    base: PointResult,
    acc: PointAccumulator,
    lane: usize,
    /// Its reference state at the end of the last window.
    start: Vec<f64>,
    /// Active sets: (set index, row of its first vector in the lane).
    sets: Vec<(usize, usize)>,
    orbit_steps: u64,
}

/// The VM per-set route on a kernel that advances many points' orbits and tangent vectors in
/// one pass ([`PointKernel::fuses_orbits_and_tangents`]): one lane per point, its orbit and its
/// sets' vectors, so one kernel call steps a whole batch of points. Lane by lane the kernel does
/// the bits of the reference's steps followed by the tangent steps, and every set is then
/// renormalized as [`compute`] does, so the points are [`compute`]'s bit for bit; it only
/// spares the point-by-point kernel calls, which cost several times the arithmetic for a small
/// system with one or two vectors (the Henon-Heiles MLE map).
pub fn compute_fused(
    spec: &MapSpec,
    isa: Isa,
    indices: &[u64],
    stop: &dyn Fn() -> bool,
) -> Vec<PointResult> {
    let mut kernel = spec
        .run
        .system()
        .batched(isa)
        .expect("a fused route is chosen only for systems with a batched form");
    let kernel = kernel.as_mut();
    let run = &spec.run;
    let (dim, k) = (run.dim(), run.k());
    let d0 = run.schemes()[0].d0;
    let rows = dim * (1 + run.sets() * k);
    let mut renormalization = SetRenormalization::new(run);
    let start = |base, x0: Vec<f64>, lanes: &mut Vec<Vec<f64>>| {
        let start = x0[..dim].to_vec();
        let mut column = x0;
        let mut sets = Vec::with_capacity(run.sets());
        for (s, dirs) in run.directions().iter().enumerate() {
            sets.push((s, column.len()));
            // As Engine::new: the tangent vectors start at d0 * u.
            column.extend(dirs.scaled(d0));
        }
        debug_assert_eq!(column.len(), rows);
        lanes.push(column);
        LiveFused {
            base,
            acc: spec.accumulator(),
            lane: lanes.len() - 1,
            start,
            sets,
            orbit_steps: 0,
        }
    };
    let mut column = vec![0.0; rows];
    let window = |g: &mut Group<LiveFused>, w: &Window| {
        let mut out = Vec::new();
        for p in &mut g.points {
            p.orbit_steps += w.steps * (1 + (p.sets.len() * k) as u64);
        }
        if let Err(e) = kernel.orbit_tangent_steps(&mut g.soa, w.from, w.steps) {
            let e = e.into();
            return g
                .points
                .drain(..)
                .map(|p| broke_off(p.base, w.t, &e, p.orbit_steps))
                .collect();
        }
        let before = g.points.len();
        let mut keep = Vec::with_capacity(before);
        for mut p in g.points.drain(..) {
            g.soa.read_lane(p.lane, &mut column);
            if let Err(e) = window::check_reference(run, &p.start, &column[..dim], w, None) {
                out.push(broke_off(p.base, w.t, &e, p.orbit_steps));
                continue;
            }
            p.start.copy_from_slice(&column[..dim]);
            let stepped = retain_sets(&mut p.sets, |set, first| {
                let vectors = &mut column[first..first + k * dim];
                renormalization.separations.copy_from_slice(vectors);
                let goes_on = renormalization.apply(&mut p.acc, set, w)?;
                if goes_on {
                    vectors.copy_from_slice(&renormalization.separations);
                } else {
                    // A finished set's vectors stay in the lane; zero, they stay finite.
                    vectors.fill(0.0);
                }
                Ok(goes_on)
            });
            if let Err(e) = stepped {
                out.push(broke_off(p.base, w.t, &e, p.orbit_steps));
                continue;
            }
            if p.acc.is_done() {
                out.push(p.acc.finish(p.base, p.orbit_steps));
                continue;
            }
            g.soa.write_lane(p.lane, &column);
            keep.push(p);
        }
        keep_one_lane_each(g, keep, before, |p: &mut LiveFused| &mut p.lane);
        out
    };
    drive(spec, indices, (rows, true), stop, start, window)
}

/// A point's reference and the lanes of its sets, appended to `lanes`: the reference as a lane
/// too when the lanes are orbits.
fn start(
    spec: &MapSpec,
    method: &dyn DeviationMethod,
    base: PointResult,
    x0: Vec<f64>,
    lanes: &mut Vec<Vec<f64>>,
) -> Live {
    let run = &spec.run;
    let d0 = run.schemes()[0].d0;
    let ref_lane = push_reference_lane(method, lanes, &x0);
    let mut sets = Vec::with_capacity(run.sets());
    for (s, dirs) in run.directions().iter().enumerate() {
        sets.push((s, lanes.len()));
        // As Engine::new: d = d0 * u, the lane from it.
        for d in dirs.scaled(d0).chunks_exact(run.dim()) {
            let mut lane = vec![0.0; spec.lane_len(method.lanes_are_orbits())];
            method.start(&x0, d, &mut lane);
            lanes.push(lane);
        }
    }
    Live {
        acc: spec.accumulator(),
        base,
        start: x0.clone(),
        x: x0,
        ref_lane,
        sets,
        orbit_steps: 0,
    }
}

/// One window of a group: advance its lanes, then renormalize every active set of every point.
/// Returns the points that finished or failed; the group keeps the others, its lanes compacted
/// when some left.
fn window(
    kernel: &mut dyn PointKernel,
    method: &dyn DeviationMethod,
    spec: &MapSpec,
    g: &mut Group<Live>,
    w: &Window,
    renormalization: &mut SetRenormalization,
) -> Vec<PointResult> {
    let run = &spec.run;
    let (dim, k) = (run.dim(), run.k());
    let mut out = Vec::new();
    for p in &mut g.points {
        p.orbit_steps += w.steps * (1 + (p.sets.len() * k) as u64);
    }
    let single = g.points.first_mut().map(|p| p.x.as_mut_slice());
    if let Err(e) = advance_group(kernel, method, &mut g.soa, single, w) {
        return g
            .points
            .drain(..)
            .map(|p| broke_off(p.base, w.t, &e, p.orbit_steps))
            .collect();
    }
    let mut changed = false;
    let mut keep = Vec::with_capacity(g.points.len());
    let mut lane = vec![0.0; dim];
    for mut p in g.points.drain(..) {
        if let Err(e) = end_reference(run, &g.soa, p.ref_lane, &mut p.start, &mut p.x, w) {
            out.push(broke_off(p.base, w.t, &e, p.orbit_steps));
            changed = true;
            continue;
        }
        let before = p.sets.len();
        let x = &p.x;
        let soa = &mut g.soa;
        let stepped = retain_sets(&mut p.sets, |set, first| {
            let separations = &mut renormalization.separations;
            window::deviations(method, kernel, soa, first, x, separations, &mut lane);
            let goes_on = renormalization.apply(&mut p.acc, set, w)?;
            if goes_on {
                let separations = &renormalization.separations;
                window::restart(method, soa, first, x, separations, &mut lane);
            }
            Ok(goes_on)
        });
        if let Err(e) = stepped {
            out.push(broke_off(p.base, w.t, &e, p.orbit_steps));
            changed = true;
            continue;
        }
        changed |= p.sets.len() != before;
        if p.acc.is_done() {
            out.push(p.acc.finish(p.base, p.orbit_steps));
            changed = true;
            continue;
        }
        keep.push(p);
    }
    g.points = keep;
    if changed && !g.points.is_empty() {
        let runs = g.points.iter_mut().flat_map(|p| {
            let sets = p.sets.iter_mut().map(|(_, first)| (first, k));
            p.ref_lane.iter_mut().map(|r| (r, 1)).chain(sets)
        });
        g.soa = compact(&g.soa, runs.collect());
    }
    out
}
