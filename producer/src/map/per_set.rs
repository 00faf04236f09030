//! Batched multi-particle method: the reference orbit and the `sets * k` nearby orbits of several
//! points are lanes of one [`Soa`], all advanced by the same kernel between renormalizations.
//! Sets that stop (`gali-time`) and finished points leave the batch: the lanes are compacted so
//! the kernel never integrates a finished orbit.

use super::indicator::{PointAccumulator, broke_off};
use super::point::PointResult;
use super::spec::MapSpec;
use super::window::{SetRenormalization, Windows, check_escape, retain_sets};
use crate::batch::{Isa, PointKernel, Soa};

struct Live {
    base: PointResult,
    acc: PointAccumulator,
    ref_lane: usize,
    /// Active sets: (set index, lane of its first nearby orbit; the k orbits are consecutive).
    sets: Vec<(usize, usize)>,
    orbit_steps: u64,
}

/// Computes the points `indices` together; results in no particular order. Once `stop()` (asked
/// at every window) is true, returns the points finished so far. Systems without a batched form
/// are computed one point at a time by the one-orbit engine.
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
    let (dim, k, d0) = (run.dim(), run.k(), run.schemes()[0].d0);
    let mut out = Vec::with_capacity(indices.len());
    let mut live = Vec::new();
    let mut lanes: Vec<Vec<f64>> = Vec::new();
    for &index in indices {
        match spec.start_point(index) {
            Err(outside) => out.push(*outside),
            Ok((base, x0)) => {
                let ref_lane = lanes.len();
                lanes.push(x0.clone());
                let mut sets = Vec::with_capacity(run.sets());
                for (s, dirs) in run.directions().iter().enumerate() {
                    sets.push((s, lanes.len()));
                    // As Engine::new: d = d0 * u, nearby orbit = x + d.
                    let scaled: Vec<f64> = dirs.vectors.iter().map(|u| d0 * u).collect();
                    for d in scaled.chunks_exact(dim) {
                        lanes.push(x0.iter().zip(d).map(|(x, d)| x + d).collect());
                    }
                }
                live.push(Live {
                    base,
                    acc: spec.accumulator(),
                    ref_lane,
                    sets,
                    orbit_steps: 0,
                });
            }
        }
    }
    let mut soa = Soa::new(dim, lanes.len());
    for (l, x) in lanes.iter().enumerate() {
        soa.write_lane(l, x);
    }

    let (mut x, mut y) = (vec![0.0; dim], vec![0.0; dim]);
    let mut renormalization = SetRenormalization::new(run);
    let mut windows = Windows::new(run);
    while !live.is_empty() {
        if stop() {
            break;
        }
        let Some(w) = windows.next() else { break };
        kernel.orbit_steps(&mut soa, w.steps);
        let mut changed = false;
        let mut keep = Vec::with_capacity(live.len());
        for mut p in live.drain(..) {
            p.orbit_steps += w.steps * (1 + (p.sets.len() * k) as u64);
            soa.read_lane(p.ref_lane, &mut x);
            if let Err(e) = check_escape(&x, w.t) {
                out.push(broke_off(p.base, w.t, &e, p.orbit_steps));
                changed = true;
                continue;
            }
            let before = p.sets.len();
            let stepped = retain_sets(&mut p.sets, |set, lane| {
                let separations = &mut renormalization.separations;
                for i in 0..k {
                    soa.read_lane(lane + i, &mut y);
                    kernel.separation(&y, &x, &mut separations[i * dim..(i + 1) * dim]);
                }
                let goes_on = renormalization.apply(&mut p.acc, set, &w)?;
                if goes_on {
                    for i in 0..k {
                        let d = &renormalization.separations[i * dim..(i + 1) * dim];
                        for (yi, (xi, di)) in y.iter_mut().zip(x.iter().zip(d)) {
                            *yi = xi + di;
                        }
                        soa.write_lane(lane + i, &y);
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
        live = keep;
        if changed {
            soa = compact(&soa, &mut live, k, dim);
        }
    }
    out
}

/// A new lane array holding only the lanes of `live` points and their active sets.
fn compact(old: &Soa, live: &mut [Live], k: usize, dim: usize) -> Soa {
    let total: usize = live.iter().map(|p| 1 + p.sets.len() * k).sum();
    let mut soa = Soa::new(dim, total);
    let mut buf = vec![0.0; dim];
    let mut next = 0;
    let mut mv = |from: usize, soa: &mut Soa| {
        old.read_lane(from, &mut buf);
        soa.write_lane(next, &buf);
        next += 1;
        next - 1
    };
    for p in live.iter_mut() {
        p.ref_lane = mv(p.ref_lane, &mut soa);
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
