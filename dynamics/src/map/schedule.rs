//! Rayon across points; results are handed to a sink on the calling thread as they complete.

use std::sync::mpsc;

use rayon::prelude::*;

use super::point::PointResult;
use super::spec::MapRoute;
use super::spec::MapSpec;
use super::{basis, per_set};
use crate::batch::Isa;
use crate::method;
use chaoscope_os::termination::Termination;

/// Points per batch on the basis route (and the fused one), in units of
/// [`MapOptions::mpm_points_per_batch`].
const ROUTE_BATCH_FACTOR: usize = 8;

/// Most tangent vectors a point of the per-set route carries in a fused lane. With few, a
/// point's own vectors fill no SIMD vector and a kernel call per point costs more than its
/// arithmetic; with many, the point-by-point kernel fills its lanes and forms each stage's
/// Hessian once for all of them, while a fused lane recomputes it per vector and outgrows the
/// L1 cache. Henon-Heiles GALI maps, 20 x 20 points to t = 200, one thread (AMD EPYC Zen 4,
/// AVX-512), fused against point by point: 4 vectors 0.13 s against 0.85 s, 8 vectors 0.75 s
/// against 0.86 s, 16 vectors 1.39 s against 1.11 s.
const FUSED_PER_SET_MAX_VECTORS: usize = 8;

#[derive(Debug, Clone)]
pub struct MapOptions {
    /// Worker threads (`None`: rayon's default, one per core).
    pub threads: Option<usize>,
    pub isa: Isa,
    /// MPM points integrated together in one lane array. Larger batches amortize the
    /// per-window bookkeeping; smaller ones balance the threads better.
    pub mpm_points_per_batch: usize,
    /// Checked at every renormalization window: once it is requested, points in progress are
    /// dropped (a resumed map computes them again) and `run_map` returns, so SIGINT/SIGTERM stop
    /// a map of long orbits within a window rather than after a whole batch of points.
    pub termination: Option<Termination>,
}

impl Default for MapOptions {
    fn default() -> Self {
        Self {
            threads: None,
            isa: Isa::detect(),
            mpm_points_per_batch: 8,
            termination: None,
        }
    }
}

/// Computes `points` (grid indices) and calls `sink` with each result, on this thread, in
/// completion order. Returns early (with the points finished so far delivered) when `sink`
/// returns `false`.
pub fn run_map(
    spec: &MapSpec,
    points: &[u64],
    options: &MapOptions,
    mut sink: impl FnMut(PointResult) -> bool,
) -> Result<(), rayon::ThreadPoolBuildError> {
    let mut builder = rayon::ThreadPoolBuilder::new();
    if let Some(n) = options.threads {
        builder = builder.num_threads(n);
    }
    let pool = builder.build()?;
    let batching = Batching::of(spec, options.mpm_points_per_batch);
    let (tx, rx) = mpsc::channel::<PointResult>();
    let stop = std::sync::atomic::AtomicBool::new(false);
    std::thread::scope(|scope| {
        let stop = &stop;
        let stopped = move || {
            stop.load(std::sync::atomic::Ordering::Relaxed)
                || options.termination.as_ref().is_some_and(|t| t.requested())
        };
        scope.spawn(move || {
            pool.install(|| {
                points
                    .par_chunks(batching.points)
                    .for_each_with(tx, |tx, chunk| {
                        if stopped() {
                            return;
                        }
                        let results = batching.compute(spec, options.isa, chunk, &stopped);
                        for r in results {
                            // The receiver hung up: the caller stopped.
                            if tx.send(r).is_err() {
                                return;
                            }
                        }
                    })
            });
        });
        for r in rx.iter() {
            if !sink(r) {
                stop.store(true, std::sync::atomic::Ordering::Relaxed);
                break;
            }
        }
    });
    Ok(())
}

/// How a map's points are grouped into batches of the kernel, decided once per map.
#[derive(Debug, Clone, Copy)]
pub struct Batching {
    /// Points one batch computes together.
    pub points: usize,
    /// The basis of tangent vectors of many points at once, one lane per point (its orbit and
    /// basis), where the kernel fuses them.
    fused: bool,
}

impl Batching {
    /// `mpm_points_per_batch`: see [`MapOptions`].
    pub fn of(spec: &MapSpec, mpm_points_per_batch: usize) -> Self {
        let orbits = method::of(spec.run.schemes()[0].method).lanes_are_orbits();
        // VM on a kernel that steps many points' orbits and tangent vectors in one pass: one
        // lane per point (its orbit and basis, or its orbit and its sets' vectors, where they
        // are few).
        let vectors = spec.run.sets() * spec.run.k();
        let fused = !orbits
            && match spec.route {
                MapRoute::Basis => spec.fuses_orbits_and_tangents(),
                MapRoute::PerSet => {
                    vectors <= FUSED_PER_SET_MAX_VECTORS && spec.fuses_few_vectors()
                }
            };
        let points_per_batch = mpm_points_per_batch.max(1);
        let points = if !spec.has_batched_kernel() {
            // Systems without a batched kernel: one point at a time through the one-orbit
            // engine.
            1
        } else if fused || (orbits && spec.route == MapRoute::Basis) {
            // One lane per point, or 1 + D lanes instead of 1 + sets * k: more points fill the
            // kernel's chunks as well.
            points_per_batch * ROUTE_BATCH_FACTOR
        } else if orbits {
            points_per_batch
        } else {
            // Tangent lanes follow their own point's reference: one point at a time.
            1
        };
        Self { points, fused }
    }

    /// One batch of points (grid indices) computed on this thread by the spec's route, as
    /// [`run_map`] computes each of its batches (and the estimate's calibration times one).
    pub fn compute(
        &self,
        spec: &MapSpec,
        isa: Isa,
        indices: &[u64],
        stop: &dyn Fn() -> bool,
    ) -> Vec<PointResult> {
        match spec.route {
            MapRoute::Basis if self.fused => basis::compute_fused(spec, isa, indices, stop),
            MapRoute::PerSet if self.fused => per_set::compute_fused(spec, isa, indices, stop),
            MapRoute::Basis => basis::compute(spec, isa, indices, stop),
            MapRoute::PerSet => per_set::compute(spec, isa, indices, stop),
        }
    }
}
