//! Batched multi-particle method: the reference orbit and the `sets * k` nearby orbits of several
//! points are lanes of one [`Soa`], all advanced by the same kernel between renormalizations.
//! Sets that stop (`gali-time`) and finished points leave the batch: the lanes are compacted so
//! the kernel never integrates a finished orbit.

use super::indicator::{PointAccumulator, failed};
use super::point::{PointResult, PointStatus};
use super::spec::MapSpec;
use super::window::{ESCAPE_NORM, Windows, norm};
use crate::batch::{self, Isa, LaneModel, Soa};
use crate::engine::RunError;
use crate::renormalization::{self, Orthonormalization};
use crate::with_lane_model;

struct Live {
    base: PointResult,
    acc: PointAccumulator,
    ref_lane: usize,
    /// Active sets: (set index, lane of its first nearby orbit; the k orbits are consecutive).
    sets: Vec<(usize, usize)>,
    orbit_steps: u64,
}

/// Computes the points `indices` together; results in no particular order.
pub fn compute(spec: &MapSpec, isa: Isa, indices: &[u64]) -> Vec<PointResult> {
    with_lane_model!(&spec.lanes, |m| compute_with(m, spec, isa, indices))
}

fn compute_with<M: LaneModel>(
    model: &M,
    spec: &MapSpec,
    isa: Isa,
    indices: &[u64],
) -> Vec<PointResult> {
    let run = &spec.run;
    let (dim, k, d0) = (run.dim, run.k, run.schemes[0].d0);
    let mut out = Vec::with_capacity(indices.len());
    let mut live = Vec::new();
    let mut lanes: Vec<Vec<f64>> = Vec::new();
    for &index in indices {
        let base = spec.base_result(index);
        match spec.initial_state(index) {
            Err(reason) => out.push(failed(base, PointStatus::OutsideEnergySurface, 0.0, reason)),
            Ok(x0) => {
                let ref_lane = lanes.len();
                lanes.push(x0.clone());
                let mut sets = Vec::with_capacity(run.sets());
                for (s, dirs) in run.directions.iter().enumerate() {
                    sets.push((s, lanes.len()));
                    // As Engine::new: d = d0 * u, nearby orbit = x + d.
                    let scaled: Vec<f64> = dirs.vectors.iter().map(|u| d0 * u).collect();
                    for d in scaled.chunks_exact(dim) {
                        lanes.push(x0.iter().zip(d).map(|(x, d)| x + d).collect());
                    }
                }
                live.push(Live {
                    base: PointResult { x0, ..base },
                    acc: PointAccumulator::new(spec.indicator, dim, run.sets(), run.t_final()),
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
    let mut separations = vec![0.0; k * dim];
    let mut raw = vec![0.0; k * dim];
    let mut stretch = vec![0.0; k];
    let mut windows = Windows::new(run);
    while !live.is_empty() {
        let Some(w) = windows.next() else { break };
        batch::orbit_steps(isa, model, &spec.coeffs, &mut soa, w.steps);
        let mut changed = false;
        let mut keep = Vec::with_capacity(live.len());
        for mut p in live.drain(..) {
            p.orbit_steps += w.steps * (1 + (p.sets.len() * k) as u64);
            soa.read_lane(p.ref_lane, &mut x);
            let rn = norm(&x);
            if rn.is_nan() || rn >= ESCAPE_NORM {
                let e = RunError::Escaped { t: w.t, norm: rn };
                out.push(PointResult {
                    orbit_steps: p.orbit_steps,
                    ..failed(p.base, PointStatus::Escaped, w.t, e.to_string())
                });
                changed = true;
                continue;
            }
            let mut error = None;
            let before = p.sets.len();
            p.sets.retain(|&(set, lane)| {
                if error.is_some() {
                    return true;
                }
                for i in 0..k {
                    soa.read_lane(lane + i, &mut y);
                    for ((d, a), b) in separations[i * dim..(i + 1) * dim]
                        .iter_mut()
                        .zip(&y)
                        .zip(&x)
                    {
                        *d = a - b;
                    }
                }
                raw.copy_from_slice(&separations);
                if let Err(source) = renormalization::renormalize(
                    &mut separations,
                    dim,
                    d0,
                    Orthonormalization::Rescale,
                    &mut stretch,
                ) {
                    error = Some(RunError::Renormalization {
                        scheme: run.schemes[0].name.clone(),
                        set: set as u32,
                        t: w.t,
                        source,
                    });
                    return true;
                }
                if p.acc.observe(set, w.t, &raw, &stretch, w.last) {
                    return false;
                }
                for i in 0..k {
                    let d = &separations[i * dim..(i + 1) * dim];
                    for (yi, (xi, di)) in y.iter_mut().zip(x.iter().zip(d)) {
                        *yi = xi + di;
                    }
                    soa.write_lane(lane + i, &y);
                }
                true
            });
            if let Some(e) = error {
                out.push(PointResult {
                    orbit_steps: p.orbit_steps,
                    ..failed(p.base, PointStatus::Escaped, w.t, e.to_string())
                });
                changed = true;
                continue;
            }
            changed |= p.sets.len() != before;
            if p.acc.is_done() {
                let r = p.acc.finish(p.base.clone());
                out.push(PointResult {
                    orbit_steps: p.orbit_steps,
                    ..r
                });
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
