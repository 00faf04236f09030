//! The basis route of a map (`[map] route = "basis"`): every set's
//! indicator from one evolved basis per point instead of `sets * k` vectors, accumulated over
//! the whole orbit as the scaled QR propagator ([`crate::propagator`]). The basis is `D` lanes
//! of the scheme's [`DeviationMethod`], at its basis norm:
//!
//! - VM: `D` unit tangent vectors around the point's reference orbit, QR-renormalized every
//!   window.
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
use super::window::{
    Group, advance_group, compact, drive, end_reference, keep_one_lane_each, push_reference_lane,
};
use crate::batch::{Isa, PointKernel};
use crate::method::{self, DeviationMethod};
use crate::propagator::{Propagator, SetImage};
use crate::spec::RunSpec;
use crate::window::{self, RunError, Window};

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
        if acc.needs_qr() {
            // `spectrum`: the basis is itself renormalized by QR every window, so its
            // accumulated `ln R_jj` are the Benettin spectrum of the point (from the coordinate
            // axes, whatever the sets' directions: every set gets the same first k exponents,
            // to which any generic set's converge). One stretch for all, from set 0's record.
            let k = self.stretch.len();
            stretch_since(
                &mut self.stretch,
                &prop.log_scales()[..k],
                &mut self.log_norms[0],
            );
            for set in 0..run.sets() {
                acc.observe(set, w.t, &self.unit, &self.stretch, w.last);
            }
            return;
        }
        for (set, dirs) in run.directions().iter().enumerate() {
            if acc.is_stopped(set) {
                continue;
            }
            prop.image(&dirs.vectors, &mut self.image);
            prop.unit_vectors(&self.image, &mut self.unit);
            stretch_since(
                &mut self.stretch,
                self.image.log_norms(),
                &mut self.log_norms[set],
            );
            acc.observe(set, w.t, &self.unit, &self.stretch, w.last);
        }
    }
}

/// The stretching factors since the last observation, `e^(now - before)`, from logarithmic
/// norms; `before` becomes `now`.
fn stretch_since(stretch: &mut [f64], now: &[f64], before: &mut [f64]) {
    for ((s, now), before) in stretch.iter_mut().zip(now).zip(before) {
        *s = (now - *before).exp();
        *before = *now;
    }
}

/// A failed renormalization of a point's basis, shared by every set: reported as set 0.
fn basis_error(
    run: &RunSpec,
    w: &Window,
    source: crate::renormalization::RenormalizationError,
) -> RunError {
    window::renormalization_error(run, 0, 0, w.t, source)
}

/// A point being computed.
struct Live {
    base: PointResult,
    acc: PointAccumulator,
    prop: Propagator,
    sets: Sets,
    /// Its reference state: read from lane `ref_lane` when the lanes are orbits, stepped here
    /// by the kernel otherwise.
    x: Vec<f64>,
    ref_lane: Option<usize>,
    /// Its reference state at the end of the last window.
    start: Vec<f64>,
    /// The lane of its first basis vector; the `D` lanes are consecutive.
    first: usize,
    orbit_steps: u64,
}

/// The system's batched form (validation keeps the basis route to systems with one).
fn batched(spec: &MapSpec, isa: Isa) -> Box<dyn PointKernel + '_> {
    spec.run
        .system()
        .batched(isa)
        .expect("validation keeps the basis route to systems with a batched form")
}

/// Computes the points `indices` (several at once when the method's lanes are orbits); results
/// in no particular order. Once `stop()` (asked at every window) is true, returns the points
/// finished so far.
pub fn compute(
    spec: &MapSpec,
    isa: Isa,
    indices: &[u64],
    stop: &dyn Fn() -> bool,
) -> Vec<PointResult> {
    let mut kernel = batched(spec, isa);
    let kernel = kernel.as_mut();
    let method = method::of(spec.run.schemes()[0].method);
    let orbits = method.lanes_are_orbits();
    drive(
        spec,
        indices,
        (spec.lane_len(orbits), orbits),
        stop,
        |base, x0, lanes| start(spec, method, base, x0, lanes),
        |g, w| window(kernel, method, spec, g, w),
    )
}

/// A point's reference and its basis lanes `x + s q_j` (orbits) or `s q_j` (tangent vectors),
/// `s` the method's basis norm, appended to `lanes`.
fn start(
    spec: &MapSpec,
    method: &dyn DeviationMethod,
    base: PointResult,
    x0: Vec<f64>,
    lanes: &mut Vec<Vec<f64>>,
) -> Live {
    let run = &spec.run;
    let dim = run.dim();
    let prop = Propagator::new(dim);
    let ref_lane = push_reference_lane(method, lanes, &x0);
    let first = lanes.len();
    let norm = method.basis_norm(run.schemes()[0].d0);
    for q in prop.basis().chunks_exact(dim) {
        let d: Vec<f64> = q.iter().map(|q| norm * q).collect();
        let mut lane = vec![0.0; spec.lane_len(method.lanes_are_orbits())];
        method.start(&x0, &d, &mut lane);
        lanes.push(lane);
    }
    Live {
        acc: spec.accumulator(),
        sets: Sets::new(run),
        prop,
        base,
        start: x0.clone(),
        x: x0,
        ref_lane,
        first,
        orbit_steps: 0,
    }
}

/// One window of a group: advance its lanes, QR-renormalize every point's basis and restart its
/// lanes from it, observe the sets. Returns the points that finished or failed.
fn window(
    kernel: &mut dyn PointKernel,
    method: &dyn DeviationMethod,
    spec: &MapSpec,
    g: &mut Group<Live>,
    w: &Window,
) -> Vec<PointResult> {
    let run = &spec.run;
    let dim = run.dim();
    let norm = method.basis_norm(run.schemes()[0].d0);
    for p in &mut g.points {
        p.orbit_steps += w.steps * (1 + dim as u64);
    }
    let single = g.points.first_mut().map(|p| p.x.as_mut_slice());
    if let Err(e) = advance_group(kernel, method, &mut g.soa, single, w) {
        return g
            .points
            .drain(..)
            .map(|p| broke_off(p.base, w.t, &e, p.orbit_steps))
            .collect();
    }
    let mut out = Vec::new();
    let before = g.points.len();
    let mut keep = Vec::with_capacity(before);
    let mut lane = vec![0.0; dim];
    let (mut deviations, mut scaled) = (vec![0.0; dim * dim], vec![0.0; dim * dim]);
    for mut p in g.points.drain(..) {
        if let Err(e) = end_reference(run, &g.soa, p.ref_lane, &mut p.start, &mut p.x, w) {
            out.push(broke_off(p.base, w.t, &e, p.orbit_steps));
            continue;
        }
        window::deviations(
            method,
            kernel,
            &g.soa,
            p.first,
            &p.x,
            &mut deviations,
            &mut lane,
        );
        if let Err(e) = p.prop.renormalize(&deviations, norm) {
            out.push(broke_off(
                p.base,
                w.t,
                &basis_error(run, w, e),
                p.orbit_steps,
            ));
            continue;
        }
        for (dj, qj) in scaled.iter_mut().zip(p.prop.basis()) {
            *dj = norm * qj;
        }
        window::restart(method, &mut g.soa, p.first, &p.x, &scaled, &mut lane);
        p.sets.observe(run, &p.prop, &mut p.acc, w);
        if p.acc.is_done() {
            out.push(p.acc.finish(p.base, p.orbit_steps));
            continue;
        }
        keep.push(p);
    }
    if keep.len() != before && !keep.is_empty() {
        let runs = keep.iter_mut().flat_map(|p| {
            let basis = std::iter::once((&mut p.first, dim));
            p.ref_lane.iter_mut().map(|r| (r, 1)).chain(basis)
        });
        g.soa = compact(&g.soa, runs.collect());
    }
    g.points = keep;
    out
}

/// VM, many points at once: one lane per point holding its orbit and its `D` basis vectors
/// (`PointKernel::orbit_tangent_steps`; fused into one pass for separable Hamiltonians), so the
/// reference orbits share the SIMD lanes too; the same numbers as [`compute`] bit for bit
/// (the kernel repeats the reference's recorded stages and the tangent steps lane by lane).
pub fn compute_fused(
    spec: &MapSpec,
    isa: Isa,
    indices: &[u64],
    stop: &dyn Fn() -> bool,
) -> Vec<PointResult> {
    let mut kernel = batched(spec, isa);
    fused_with(kernel.as_mut(), spec, indices, stop)
}

struct LiveVm {
    base: PointResult,
    acc: PointAccumulator,
    prop: Propagator,
    sets: Sets,
    lane: usize,
    /// Its reference state at the end of the last window.
    start: Vec<f64>,
    orbit_steps: u64,
}

fn fused_with(
    kernel: &mut dyn PointKernel,
    spec: &MapSpec,
    indices: &[u64],
    stop: &dyn Fn() -> bool,
) -> Vec<PointResult> {
    let run = &spec.run;
    let dim = run.dim();
    let start = |base, x0: Vec<f64>, lanes: &mut Vec<Vec<f64>>| {
        let prop = Propagator::new(dim);
        let start = x0[..dim].to_vec();
        let mut column = x0;
        column.extend_from_slice(prop.basis());
        lanes.push(column);
        LiveVm {
            base,
            acc: spec.accumulator(),
            prop,
            sets: Sets::new(run),
            lane: lanes.len() - 1,
            start,
            orbit_steps: 0,
        }
    };
    let mut column = vec![0.0; dim * (1 + dim)];
    let window = |g: &mut Group<LiveVm>, w: &Window| {
        let mut out = Vec::new();
        if let Err(e) = kernel.orbit_tangent_steps(&mut g.soa, w.from, w.steps) {
            let e = e.into();
            out.extend(
                g.points
                    .drain(..)
                    .map(|p| broke_off(p.base, w.t, &e, p.orbit_steps)),
            );
            return out;
        }
        let before = g.points.len();
        let mut keep = Vec::with_capacity(before);
        for mut p in g.points.drain(..) {
            p.orbit_steps += w.steps * (1 + dim as u64);
            g.soa.read_lane(p.lane, &mut column);
            let (x, evolved) = column.split_at_mut(dim);
            if let Err(e) = window::check_reference(run, &p.start, x, w, None) {
                out.push(broke_off(p.base, w.t, &e, p.orbit_steps));
                continue;
            }
            p.start.copy_from_slice(x);
            if let Err(e) = p.prop.renormalize(evolved, 1.0) {
                out.push(broke_off(
                    p.base,
                    w.t,
                    &basis_error(run, w, e),
                    p.orbit_steps,
                ));
                continue;
            }
            evolved.copy_from_slice(p.prop.basis());
            g.soa.write_lane(p.lane, &column);
            p.sets.observe(run, &p.prop, &mut p.acc, w);
            if p.acc.is_done() {
                out.push(p.acc.finish(p.base, p.orbit_steps));
                continue;
            }
            keep.push(p);
        }
        keep_one_lane_each(g, keep, before, |p: &mut LiveVm| &mut p.lane);
        out
    };
    drive(spec, indices, (dim * (1 + dim), true), stop, start, window)
}
