//! The propagator route of a map (`[map] route = "propagator"`): every set's indicator from one
//! evolved basis per point instead of `sets * k` vectors (see [`crate::propagator`]).
//!
//! - VM: the `D = 2N` basis vectors are tangent vectors around the point's reference orbit (the
//!   batched tangent kernel, as per-set VM), QR-renormalized every window.
//! - MPM: `D` nearby orbits at `x + d0 q_j`, integrated with the full equations of motion like
//!   per-set MPM's, and restarted at `x + d0 q_j,new` after each window's QR of the separations:
//!   a finite-difference propagator. It differs from per-set MPM by terms of order `d0` (the
//!   nonlinear part of each window's finite difference); `spec.rs` refuses `d0` outside the
//!   range where that difference stays within the paper's MPM-VM distance.
//!
//! At a renormalization where the indicator needs the sets (every window for `gali-time` and
//! `mle`, the last one for `gali` and `sali`), each set's vectors are formed from the propagator
//! as the unit vectors `M w_a / |M w_a|` with stretching `|M(t_n) w_a| / |M(t_{n-1}) w_a|`,
//! computed in logs: exactly what per-vector rescaling holds, handed to the same
//! [`PointAccumulator`], so a point's numbers mean what they mean on the per-set route.

use super::indicator::{PointAccumulator, broke_off};
use super::point::PointResult;
use super::spec::MapSpec;
use super::window::{Window, Windows, check_escape};
use crate::batch::{Isa, PointKernel, Soa};
use crate::engine::RunError;
use crate::propagator::{Propagator, SetImage};
use crate::spec::RunSpec;

/// The sets of one point as the propagator gives them.
struct Sets {
    /// `ln |M w_a|` of every set's vectors at its last observation.
    log_norms: Vec<Vec<f64>>,
    image: SetImage,
    unit: Vec<f64>,
    stretch: Vec<f64>,
}

impl Sets {
    fn new(run: &RunSpec) -> Self {
        Self {
            log_norms: vec![vec![0.0; run.k()]; run.sets()],
            image: SetImage::default(),
            unit: vec![0.0; run.k() * run.dim()],
            stretch: vec![0.0; run.k()],
        }
    }

    /// Hands every unfinished set to `acc` at the end of window `w`, if the indicator needs it.
    fn observe(
        &mut self,
        run: &RunSpec,
        prop: &Propagator,
        acc: &mut PointAccumulator,
        w: &Window,
    ) {
        if !(w.last || acc.observes_every_window()) {
            return;
        }
        for (set, dirs) in run.directions().iter().enumerate() {
            if acc.is_stopped(set) {
                continue;
            }
            prop.image(&dirs.vectors, &mut self.image);
            prop.unit_vectors(&self.image, &mut self.unit);
            for ((s, now), before) in self
                .stretch
                .iter_mut()
                .zip(self.image.log_norms())
                .zip(self.log_norms[set].iter_mut())
            {
                *s = (now - *before).exp();
                *before = *now;
            }
            acc.observe(set, w.t, &self.unit, &self.stretch, w.last);
        }
    }
}

fn basis_error(
    run: &RunSpec,
    w: &Window,
    source: crate::renormalization::RenormalizationError,
) -> RunError {
    RunError::Renormalization {
        scheme: run.schemes()[0].name.clone(),
        // The propagator's basis is shared by every set: reported as set 0.
        set: 0,
        t: w.t,
        source,
    }
}

/// VM: the point `index`, or `None` if `stop()` (asked at every window) became true first.
pub fn compute_vm(
    spec: &MapSpec,
    isa: Isa,
    index: u64,
    stop: &dyn Fn() -> bool,
) -> Option<PointResult> {
    let mut kernel = batched(spec, isa);
    vm_with(kernel.as_mut(), spec, index, stop)
}

/// The system's batched form (validation keeps the propagator route to systems with one).
fn batched(spec: &MapSpec, isa: Isa) -> Box<dyn PointKernel + '_> {
    spec.run
        .system()
        .batched(isa)
        .expect("validation keeps the propagator route to systems with a batched form")
}

fn vm_with(
    kernel: &mut dyn PointKernel,
    spec: &MapSpec,
    index: u64,
    stop: &dyn Fn() -> bool,
) -> Option<PointResult> {
    let run = &spec.run;
    let dim = run.dim();
    let (base, mut x) = match spec.start_point(index) {
        Ok(start) => start,
        Err(outside) => return Some(*outside),
    };
    let mut acc = spec.accumulator();
    let mut prop = Propagator::new(dim);
    let mut soa = Soa::new(dim, dim);
    let mut evolved = vec![0.0; dim * dim];
    let mut sets = Sets::new(run);
    let mut orbit_steps = 0;
    for w in Windows::new(run) {
        if stop() {
            return None;
        }
        for (j, q) in prop.basis().chunks_exact(dim).enumerate() {
            soa.write_lane(j, q);
        }
        orbit_steps += w.steps * (1 + dim as u64);
        kernel.reference_steps(&mut x, w.steps);
        if let Err(e) = kernel.tangent_steps(&mut soa, w.steps) {
            return Some(broke_off(base, w.t, &e.into(), orbit_steps));
        }
        if let Err(e) = check_escape(&x, w.t) {
            return Some(broke_off(base, w.t, &e, orbit_steps));
        }
        for (j, y) in evolved.chunks_exact_mut(dim).enumerate() {
            soa.read_lane(j, y);
        }
        if let Err(e) = prop.renormalize(&evolved, 1.0) {
            return Some(broke_off(base, w.t, &basis_error(run, &w, e), orbit_steps));
        }
        sets.observe(run, &prop, &mut acc, &w);
        if acc.is_done() {
            break;
        }
    }
    Some(acc.finish(base, orbit_steps))
}

/// VM, many points at once: one lane per point holding its orbit and its `D` basis vectors
/// (`PointKernel::orbit_tangent_steps`; fused into one pass for separable Hamiltonians), so the
/// reference orbits share the SIMD lanes too; the same numbers as [`compute_vm`] bit for bit
/// (the kernel repeats the reference's recorded stages and the tangent steps lane by lane).
pub fn compute_vm_batch(
    spec: &MapSpec,
    isa: Isa,
    indices: &[u64],
    stop: &dyn Fn() -> bool,
) -> Vec<PointResult> {
    let mut kernel = batched(spec, isa);
    vm_batch_with(kernel.as_mut(), spec, indices, stop)
}

struct LiveVm {
    base: PointResult,
    acc: PointAccumulator,
    prop: Propagator,
    sets: Sets,
    lane: usize,
    orbit_steps: u64,
}

fn vm_batch_with(
    kernel: &mut dyn PointKernel,
    spec: &MapSpec,
    indices: &[u64],
    stop: &dyn Fn() -> bool,
) -> Vec<PointResult> {
    let run = &spec.run;
    let dim = run.dim();
    let rows = dim * (1 + dim);
    let mut out = Vec::with_capacity(indices.len());
    let mut live = Vec::new();
    let mut columns: Vec<Vec<f64>> = Vec::new();
    for &index in indices {
        match spec.start_point(index) {
            Err(outside) => out.push(*outside),
            Ok((base, x0)) => {
                let prop = Propagator::new(dim);
                let mut column = x0.clone();
                column.extend_from_slice(prop.basis());
                live.push(LiveVm {
                    base,
                    acc: spec.accumulator(),
                    prop,
                    sets: Sets::new(run),
                    lane: columns.len(),
                    orbit_steps: 0,
                });
                columns.push(column);
            }
        }
    }
    let mut soa = Soa::new(rows, columns.len());
    for (l, c) in columns.iter().enumerate() {
        soa.write_lane(l, c);
    }
    let mut column = vec![0.0; rows];
    let mut windows = Windows::new(run);
    while !live.is_empty() {
        if stop() {
            break;
        }
        let Some(w) = windows.next() else { break };
        if let Err(e) = kernel.orbit_tangent_steps(&mut soa, w.steps) {
            let e = e.into();
            out.extend(
                live.drain(..)
                    .map(|p| broke_off(p.base, w.t, &e, p.orbit_steps)),
            );
            break;
        }
        let before = live.len();
        let mut keep = Vec::with_capacity(before);
        for mut p in live.drain(..) {
            p.orbit_steps += w.steps * (1 + dim as u64);
            soa.read_lane(p.lane, &mut column);
            let (x, evolved) = column.split_at_mut(dim);
            if let Err(e) = check_escape(x, w.t) {
                out.push(broke_off(p.base, w.t, &e, p.orbit_steps));
                continue;
            }
            if let Err(e) = p.prop.renormalize(evolved, 1.0) {
                out.push(broke_off(
                    p.base,
                    w.t,
                    &basis_error(run, &w, e),
                    p.orbit_steps,
                ));
                continue;
            }
            evolved.copy_from_slice(p.prop.basis());
            soa.write_lane(p.lane, &column);
            p.sets.observe(run, &p.prop, &mut p.acc, &w);
            if p.acc.is_done() {
                out.push(p.acc.finish(p.base, p.orbit_steps));
                continue;
            }
            keep.push(p);
        }
        if keep.len() != before {
            soa = compact(&soa, rows, 1, keep.iter_mut().map(|p| &mut p.lane));
        }
        live = keep;
    }
    out
}

struct Live {
    base: PointResult,
    acc: PointAccumulator,
    prop: Propagator,
    sets: Sets,
    /// The reference orbit's lane; the `D` nearby orbits follow it.
    lane: usize,
    orbit_steps: u64,
}

/// MPM: the points `indices` together (each a reference and `D` nearby orbits in one lane
/// array); results in no particular order. Once `stop()` (asked at every window) is true,
/// returns the points finished so far.
pub fn compute_mpm(
    spec: &MapSpec,
    isa: Isa,
    indices: &[u64],
    stop: &dyn Fn() -> bool,
) -> Vec<PointResult> {
    let mut kernel = batched(spec, isa);
    mpm_with(kernel.as_mut(), spec, indices, stop)
}

fn mpm_with(
    kernel: &mut dyn PointKernel,
    spec: &MapSpec,
    indices: &[u64],
    stop: &dyn Fn() -> bool,
) -> Vec<PointResult> {
    let run = &spec.run;
    let (dim, d0) = (run.dim(), run.schemes()[0].d0);
    let mut out = Vec::with_capacity(indices.len());
    let mut live = Vec::new();
    let mut lanes: Vec<Vec<f64>> = Vec::new();
    for &index in indices {
        match spec.start_point(index) {
            Err(outside) => out.push(*outside),
            Ok((base, x0)) => {
                let prop = Propagator::new(dim);
                let lane = lanes.len();
                lanes.push(x0.clone());
                for q in prop.basis().chunks_exact(dim) {
                    lanes.push(x0.iter().zip(q).map(|(x, q)| x + d0 * q).collect());
                }
                live.push(Live {
                    base,
                    acc: spec.accumulator(),
                    prop,
                    sets: Sets::new(run),
                    lane,
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
    let mut separations = vec![0.0; dim * dim];
    let mut windows = Windows::new(run);
    while !live.is_empty() {
        if stop() {
            break;
        }
        let Some(w) = windows.next() else { break };
        kernel.orbit_steps(&mut soa, w.steps);
        let before = live.len();
        let mut keep = Vec::with_capacity(before);
        for mut p in live.drain(..) {
            p.orbit_steps += w.steps * (1 + dim as u64);
            soa.read_lane(p.lane, &mut x);
            if let Err(e) = check_escape(&x, w.t) {
                out.push(broke_off(p.base, w.t, &e, p.orbit_steps));
                continue;
            }
            for (j, d) in separations.chunks_exact_mut(dim).enumerate() {
                soa.read_lane(p.lane + 1 + j, &mut y);
                kernel.separation(&y, &x, d);
            }
            if let Err(e) = p.prop.renormalize(&separations, d0) {
                out.push(broke_off(
                    p.base,
                    w.t,
                    &basis_error(run, &w, e),
                    p.orbit_steps,
                ));
                continue;
            }
            for (j, q) in p.prop.basis().chunks_exact(dim).enumerate() {
                for (yi, (xi, qi)) in y.iter_mut().zip(x.iter().zip(q)) {
                    *yi = xi + d0 * qi;
                }
                soa.write_lane(p.lane + 1 + j, &y);
            }
            p.sets.observe(run, &p.prop, &mut p.acc, &w);
            if p.acc.is_done() {
                out.push(p.acc.finish(p.base, p.orbit_steps));
                continue;
            }
            keep.push(p);
        }
        if keep.len() != before {
            soa = compact(&soa, dim, 1 + dim, keep.iter_mut().map(|p| &mut p.lane));
        }
        live = keep;
    }
    out
}

/// A new lane array (of `rows` rows) holding only the lanes of the points still live (finished
/// ones leave the batch): `per_point` lanes from each point's first lane, which is updated.
fn compact<'a>(
    old: &Soa,
    rows: usize,
    per_point: usize,
    first_lanes: impl ExactSizeIterator<Item = &'a mut usize>,
) -> Soa {
    let mut soa = Soa::new(rows, first_lanes.len() * per_point);
    let mut buf = vec![0.0; rows];
    for (i, lane) in first_lanes.enumerate() {
        let to = i * per_point;
        for j in 0..per_point {
            old.read_lane(*lane + j, &mut buf);
            soa.write_lane(to + j, &buf);
        }
        *lane = to;
    }
    soa
}
