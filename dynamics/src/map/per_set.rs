//! The per-set route of a map: every set's `k` lanes (tangent vectors for VM, nearby orbits for
//! MPM: the scheme's [`DeviationMethod`]) advanced by the system's batched form and renormalized
//! vector by vector every window, as the engine does.
//!
//! Lanes that are orbits share one lane array across several points, each point's reference
//! orbit one more lane of it, all advanced by one kernel call. Tangent lanes follow their own
//! point's reference (stepped first, its steps recorded), so each point has an array of its
//! own. Sets that stop (`gali-time`) and finished points leave: the lanes are compacted so the
//! kernel never integrates a finished orbit.

use super::indicator::{PointAccumulator, broke_off};
use super::point::PointResult;
use super::spec::MapSpec;
use super::window::{
    SetRenormalization, Window, Windows, advance_group, check_escape, lane_array,
    push_reference_lane, retain_sets,
};
use crate::batch::{Isa, PointKernel, Soa};
use crate::method::{self, DeviationMethod};

/// A point being computed.
struct Live {
    base: PointResult,
    acc: PointAccumulator,
    /// Its reference state: read from lane `ref_lane` when the lanes are orbits, stepped here
    /// by the kernel otherwise.
    x: Vec<f64>,
    ref_lane: Option<usize>,
    /// Active sets: (set index, lane of its first vector; the `k` lanes are consecutive).
    sets: Vec<(usize, usize)>,
    orbit_steps: u64,
}

/// Points advanced by one kernel call: their lanes.
struct Group {
    soa: Soa,
    points: Vec<Live>,
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
    let run = &spec.run;
    let method = method::of(run.schemes()[0].method);
    let orbits = method.lanes_are_orbits();
    let rows = spec.lane_len(orbits);
    let mut out = Vec::with_capacity(indices.len());
    let mut groups: Vec<Group> = Vec::new();
    let mut lanes: Vec<Vec<f64>> = Vec::new();
    let mut points = Vec::new();
    for &index in indices {
        match spec.start_point(index) {
            Err(outside) => out.push(*outside),
            Ok((base, x0)) => {
                if !orbits && !points.is_empty() {
                    groups.push(group(&mut lanes, std::mem::take(&mut points), rows));
                }
                points.push(start(spec, method, base, x0, &mut lanes));
            }
        }
    }
    if !points.is_empty() {
        groups.push(group(&mut lanes, points, rows));
    }

    let mut renormalization = SetRenormalization::new(run);
    let mut windows = Windows::new(run);
    while groups.iter().any(|g| !g.points.is_empty()) {
        if stop() {
            break;
        }
        let Some(w) = windows.next() else { break };
        for g in &mut groups {
            let finished = window(kernel, method, spec, g, &w, &mut renormalization);
            out.extend(finished);
        }
        groups.retain(|g| !g.points.is_empty());
    }
    out
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
        let scaled: Vec<f64> = dirs.vectors.iter().map(|u| d0 * u).collect();
        for d in scaled.chunks_exact(run.dim()) {
            let mut lane = vec![0.0; spec.lane_len(method.lanes_are_orbits())];
            method.start(&x0, d, &mut lane);
            lanes.push(lane);
        }
    }
    Live {
        acc: spec.accumulator(),
        base,
        x: x0,
        ref_lane,
        sets,
        orbit_steps: 0,
    }
}

/// The points whose lanes (of `rows` entries) are `lanes` (taken), as one lane array.
fn group(lanes: &mut Vec<Vec<f64>>, points: Vec<Live>, rows: usize) -> Group {
    Group {
        soa: lane_array(lanes, rows),
        points,
    }
}

/// One window of a group: advance its lanes, then renormalize every active set of every point.
/// Returns the points that finished or failed; the group keeps the others, its lanes compacted
/// when some left.
fn window(
    kernel: &mut dyn PointKernel,
    method: &dyn DeviationMethod,
    spec: &MapSpec,
    g: &mut Group,
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
        if let Some(r) = p.ref_lane {
            g.soa.read_lane(r, &mut p.x);
        }
        if let Err(e) = check_escape(&p.x, w.t) {
            out.push(broke_off(p.base, w.t, &e, p.orbit_steps));
            changed = true;
            continue;
        }
        let before = p.sets.len();
        let x = &p.x;
        let soa = &mut g.soa;
        let stepped = retain_sets(&mut p.sets, |set, first| {
            let separations = &mut renormalization.separations;
            for i in 0..k {
                soa.read_lane(first + i, &mut lane);
                method.deviation(kernel, &lane, x, &mut separations[i * dim..(i + 1) * dim]);
            }
            let goes_on = renormalization.apply(&mut p.acc, set, w)?;
            if goes_on {
                for i in 0..k {
                    let d = &renormalization.separations[i * dim..(i + 1) * dim];
                    method.start(x, d, &mut lane);
                    soa.write_lane(first + i, &lane);
                }
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
        g.soa = compact(&g.soa, &mut g.points, k);
    }
    out
}

/// A new lane array holding only the lanes of `live` points and their active sets.
fn compact(old: &Soa, live: &mut [Live], k: usize) -> Soa {
    let rows = old.rows();
    let total: usize = live
        .iter()
        .map(|p| usize::from(p.ref_lane.is_some()) + p.sets.len() * k)
        .sum();
    let mut soa = Soa::new(rows, total);
    let mut buf = vec![0.0; rows];
    let mut next = 0;
    let mut mv = |from: usize, soa: &mut Soa| {
        old.read_lane(from, &mut buf);
        soa.write_lane(next, &buf);
        next += 1;
        next - 1
    };
    for p in live.iter_mut() {
        if let Some(r) = &mut p.ref_lane {
            *r = mv(*r, &mut soa);
        }
        for (_, lane) in p.sets.iter_mut() {
            let first = mv(*lane, &mut soa);
            for i in 1..k {
                mv(*lane + i, &mut soa);
            }
            *lane = first;
        }
    }
    soa
}
