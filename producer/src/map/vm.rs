//! Batched variational method: one point at a time, its reference orbit integrated once (with
//! where each step's tangent map is taken recorded) and the `sets * k` tangent vectors of all
//! its sets advanced as lanes by the system's tangent kernel around it.

use super::indicator::broke_off;
use super::point::PointResult;
use super::spec::MapSpec;
use super::window::{SetRenormalization, Windows, check_escape, retain_sets};
use crate::batch::{Isa, PointKernel, Soa};

/// The point `index`, or `None` if `stop()` (asked at every window) became true first. Systems
/// without a batched form are computed by the one-orbit engine.
pub fn compute(
    spec: &MapSpec,
    isa: Isa,
    index: u64,
    stop: &dyn Fn() -> bool,
) -> Option<PointResult> {
    match spec.run.system().batched(isa) {
        Some(mut kernel) => compute_with(kernel.as_mut(), spec, index, stop),
        None => (!stop()).then(|| super::one_orbit::point(spec, index)),
    }
}

fn compute_with(
    kernel: &mut dyn PointKernel,
    spec: &MapSpec,
    index: u64,
    stop: &dyn Fn() -> bool,
) -> Option<PointResult> {
    let run = &spec.run;
    let (dim, k, d0) = (run.dim(), run.k(), run.schemes()[0].d0);
    let (base, mut x) = match spec.start_point(index) {
        Ok(start) => start,
        Err(outside) => return Some(*outside),
    };
    let mut acc = spec.accumulator();
    // Active sets: (set index, first lane of its k vectors).
    let mut sets: Vec<(usize, usize)> = (0..run.sets()).map(|s| (s, s * k)).collect();
    let mut soa = Soa::new(dim, run.sets() * k);
    for (s, dirs) in run.directions().iter().enumerate() {
        for (i, u) in dirs.vectors.chunks_exact(dim).enumerate() {
            let scaled: Vec<f64> = u.iter().map(|u| d0 * u).collect();
            soa.write_lane(s * k + i, &scaled);
        }
    }
    let mut renormalization = SetRenormalization::new(run);
    let mut orbit_steps = 0;
    for w in Windows::new(run) {
        if stop() {
            return None;
        }
        orbit_steps += w.steps * (1 + (sets.len() * k) as u64);
        kernel.reference_steps(&mut x, w.steps);
        if let Err(e) = kernel.tangent_steps(&mut soa, w.steps) {
            return Some(broke_off(base, w.t, &e.into(), orbit_steps));
        }
        if let Err(e) = check_escape(&x, w.t) {
            return Some(broke_off(base, w.t, &e, orbit_steps));
        }
        let before = sets.len();
        let stepped = retain_sets(&mut sets, |set, lane| {
            let vectors = &mut renormalization.separations;
            for i in 0..k {
                soa.read_lane(lane + i, &mut vectors[i * dim..(i + 1) * dim]);
            }
            let goes_on = renormalization.apply(&mut acc, set, &w)?;
            if goes_on {
                let vectors = &renormalization.separations;
                for i in 0..k {
                    soa.write_lane(lane + i, &vectors[i * dim..(i + 1) * dim]);
                }
            }
            Ok(goes_on)
        });
        if let Err(e) = stepped {
            return Some(broke_off(base, w.t, &e, orbit_steps));
        }
        if acc.is_done() {
            break;
        }
        if sets.len() != before {
            // Stopped sets leave: their lanes are compacted away.
            let mut packed = Soa::new(dim, sets.len() * k);
            let mut buf = vec![0.0; dim];
            for (j, (_, lane)) in sets.iter_mut().enumerate() {
                for i in 0..k {
                    soa.read_lane(*lane + i, &mut buf);
                    packed.write_lane(j * k + i, &buf);
                }
                *lane = j * k;
            }
            soa = packed;
        }
    }
    Some(acc.finish(base, orbit_steps))
}
