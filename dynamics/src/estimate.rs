//! What a run or a map will cost, estimated from its configuration before anything starts.
//!
//! A typo (`t_final = 1e9` for `1e6`, `n = 700` for `70`) can turn a run into a month of a
//! shared machine or a request for more memory than it has, found out only when the job is
//! killed. The commands refuse such a run up front with an estimate (`--force` runs it anyway).
//!
//! Memory is a product of sizes (checked first, before anything is allocated). Time is the
//! run's orbit-steps times a cost per orbit-step measured for the actual system by a short
//! calibration ([`Calibration`]): a few milliseconds stepping the validated system itself (its
//! compiled vector field, map or potential, with the deviation work of its schemes) from its
//! initial state, or, for a map, computing a batch of its own grid points cut to a few steps
//! through the map's route and kernel. Each cost is the least of several timings of the
//! calibrating thread's CPU time, so other processes on a loaded machine inflate it little: the
//! estimate is the work's time on an idle core (its CPU time), compared with limits (a day, the
//! machine's memory) that real runs are far from or far above, printed beside the time the work
//! took, and for a map that names no route it picks the cheaper of two equal routes.
//!
//! Numerics stay pure: the calibration's timings are wall-clock dependent but go only into the
//! decision to start, never into an output, and it computes on copies (the validated spec and
//! every output are untouched, so recordings and maps stay bit-identical). `Machine::this_host`
//! reads the machine's cores and memory from `/proc`, the one I/O here.

use std::time::{Duration, Instant};

use crate::batch::Isa;
use crate::integrator::Workspace;
use crate::map::{Batching, MapOptions, MapRoute, MapSpec};
use crate::model::KernelBuild;
use crate::system::DynamicalSystem;
use chaoscope_expr::potential::uncounted;
use chaoscope_schemas::run::{Method, Route};

use crate::spec::RunSpec;

/// Cost of one orbit-step of the batched map kernel per phase-space dimension, in nanoseconds
/// (RESULTS-maps.md: Henon-Heiles 2.7 ns per orbit-step, FPUT N = 501 1.6 to 3.2 us): used only
/// when the calibration finds no point of the map to time (every sampled point outside the
/// energy surface).
pub const MAP_NS_PER_DIM: f64 = 1.0;

/// The one-orbit engine's work beyond stepping (renormalization, samples, publishing), as a
/// factor on the calibrated stepping: measured with `chaoscope produce --recorders 0`
/// against the estimate (RELIABILITY.md).
pub const ENGINE_OVERHEAD: f64 = 1.25;

/// The work of one sample beyond the steps, as a fixed cost and a cost per value it carries
/// (nanoseconds of CPU): published, recorded (encoded, compressed, written) and read back by
/// the analysis. Measured with `chaoscope run` (CPU time of all its processes) of runs whose
/// every step or every few steps is a sample: the Henon map sampled at each of 10^7 steps
/// (8 values, 11.7 us per sample), FPUT-beta N = 32 (194 values, 20 us).
pub const SAMPLE_NS: f64 = 10_000.0;
pub const SAMPLE_NS_PER_VALUE: f64 = 50.0;

/// The fixed wall-clock start-up of `chaoscope run` beyond its work: the producer and recorder
/// processes started, the bus's services opened and the recorder's subscription seen before the
/// first step, the summary read back at the end. Measured on runs of one renormalization
/// (t = 1: 0.05-0.06 s of wall clock on an AMD EPYC Zen 5, 2 vCPUs; each step of the handshake
/// wakes its waiter at once or within milliseconds, `bus::Backoff`).
pub const RUN_START_SECONDS: f64 = 0.06;

/// Longest run (wall clock) started without `--force`.
pub const MAX_SECONDS: f64 = 86_400.0;

/// The calibration's timings: each cost is the least of `TIMINGS` timings of at least
/// `MIN_TIMING` each (more calls per timing until one lasts that long), within `BUDGET` of the
/// thread's CPU time per cost (a step slower than the budget is timed once, after one untimed
/// call), and at most `WALL_CAP` of wall clock (a machine so loaded that the thread runs less
/// than 1/50 of the time keeps the timings it has).
const TIMINGS: usize = 5;
const MIN_TIMING: Duration = Duration::from_millis(1);
const BUDGET: Duration = Duration::from_millis(40);
const WALL_CAP: Duration = Duration::from_secs(2);

/// What the machine offers.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Machine {
    /// Cores the work can spread over.
    pub cores: usize,
    /// Memory of the machine in bytes, if known.
    pub memory_bytes: Option<u64>,
}

impl Machine {
    /// This machine: the cores available to this process and `MemTotal` of /proc/meminfo.
    pub fn this_host() -> Self {
        let memory_bytes = std::fs::read_to_string("/proc/meminfo").ok().and_then(|m| {
            let line = m.lines().find(|l| l.starts_with("MemTotal:"))?;
            let kib: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
            kib.checked_mul(1024)
        });
        Self {
            cores: std::thread::available_parallelism().map_or(1, |n| n.get()),
            memory_bytes,
        }
    }

    /// This machine's CPU model name (`model name` of /proc/cpuinfo, `"unknown"` without it):
    /// what every speed figure of the benches is quoted beside.
    pub fn cpu_model() -> String {
        std::fs::read_to_string("/proc/cpuinfo")
            .ok()
            .and_then(|t| {
                t.lines()
                    .find(|l| l.starts_with("model name"))
                    .and_then(|l| l.split_once(':'))
                    .map(|(_, v)| v.trim().to_string())
            })
            .unwrap_or_else(|| "unknown".into())
    }
}

/// An estimate, with the keys to name when it is refused.
#[derive(Debug, Clone, PartialEq)]
pub struct Estimate {
    /// Trajectories times steps.
    pub orbit_steps: f64,
    /// Wall-clock seconds on the machine's cores.
    pub seconds: f64,
    /// Peak memory of all the processes of the run (producer, recorder, shared memory), bytes.
    pub bytes: f64,
    /// The key that sets the duration (named in the refusal), and how the work is counted.
    pub time_key: &'static str,
    pub work: String,
    /// The key that sets the memory.
    pub memory_key: &'static str,
    /// Cores the work is estimated to spread over.
    pub cores: usize,
    /// The measured costs the time comes from (`None` when memory alone refuses the run, which
    /// is then not stepped at all).
    pub calibration: Option<Calibration>,
}

/// Costs measured for one system on this machine, in nanoseconds.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Calibration {
    /// One orbit-step: one trajectory (the reference, or a nearby orbit of the multi-particle
    /// method) advanced one step; for a map, the average orbit-step of its batched points,
    /// deviation work included.
    pub ns_per_orbit_step: f64,
    /// One tangent vector advanced one step beside its orbit (the variational method), beyond
    /// that orbit's own step; 0 when no scheme uses it.
    pub ns_per_tangent_step: f64,
    /// One lane (the orbit's copy or a tangent vector) of a set advanced one step in the
    /// system's fused pass ([`crate::system::ReferenceTangent::steps`]), where the run's sets
    /// of tangent vectors take it and the first carries the reference: the kernels the run
    /// will have at its start (C ones in the kernel cache, else the Cranelift pass it runs
    /// while their build is under way). A run whose every task takes the pass times nothing
    /// else: its orbit-step and tangent-step costs are then this one.
    pub ns_per_fused_lane_step: Option<f64>,
    /// Wall-clock time the calibration took.
    pub seconds_spent: f64,
}

/// What the process around a run holds in flight besides the numerics (the bus of
/// `chaoscope-dynamics`, whose constants these are): part of a run's memory.
#[derive(Debug, Clone, Copy)]
pub struct Transport {
    /// Frames a recorder's buffer holds.
    pub buffered_frames: usize,
    /// Bytes the monitors' share of the frames takes.
    pub monitor_bytes: usize,
    /// Words of the frame that carries a (scheme, set)'s record of `k` vectors of dimension
    /// `dim` (arguments `k`, `dim`).
    pub frame_words: fn(usize, usize) -> usize,
}

impl Default for Transport {
    /// Nothing in flight: the numerics' memory alone.
    fn default() -> Self {
        Self {
            buffered_frames: 0,
            monitor_bytes: 0,
            frame_words: |_, _| 0,
        }
    }
}

/// Estimate of a validated run (validation draws no direction and allocates nothing in
/// proportion to the run, so this comes before any of it): memory from the spec's sizes and
/// what its `transport` holds in flight, then, if it fits, time from a calibration of the
/// spec's own system.
pub fn run(spec: &RunSpec, machine: &Machine, transport: &Transport) -> Estimate {
    let sizes = RunSizes::of(spec);
    let memory = sizes.memory(transport);
    if machine.memory_bytes.is_some_and(|m| memory.0 > m as f64) {
        return sizes.estimate(memory, None, machine);
    }
    let calibration = calibrate_run(spec, &sizes);
    sizes.estimate(memory, Some(calibration), machine)
}

/// Estimate of `section`: `orbits` reference orbits of the spec's steps each, one after the
/// other on one core (no deviation vectors), keeping up to `crossings` crossings of each (the
/// state, and the plotted pair). Memory first, from the sizes alone; then the time from a
/// calibration of the spec's own reference step.
pub fn section(spec: &RunSpec, orbits: usize, crossings: usize, machine: &Machine) -> Estimate {
    let steps = spec.total_steps() as f64;
    let dim = spec.dim();
    let (orbitsf, crossingsf) = (orbits as f64, crossings as f64);
    // Each orbit's crossings (the state) while it is drawn, and every orbit's plotted pairs.
    let bytes =
        8.0 * (crossingsf * dim as f64 + 2.0 * orbitsf * crossingsf) + 8.0 * dim as f64 * 4.0;
    let mut estimate = Estimate {
        orbit_steps: orbitsf * steps,
        seconds: 0.0,
        bytes,
        time_key: "integrator.t_final",
        work: format!(
            "{} orbits x {} steps of dimension {dim}",
            count(orbitsf),
            count(steps)
        ),
        memory_key: "--count x --crossings",
        cores: 1,
        calibration: None,
    };
    if machine.memory_bytes.is_some_and(|m| bytes > m as f64) {
        return estimate;
    }
    // The reference step alone: no scheme's vectors are stepped.
    let reference_only = RunSizes {
        steps,
        samples: 0.0,
        dim,
        k: spec.k(),
        sets: spec.sets(),
        mpm: 0,
        vm: 0,
        propagator_mpm: 0,
        propagator_vm: 0,
        carried: false,
    };
    let calibration = calibrate_run(spec, &reference_only);
    estimate.seconds = orbitsf * steps * calibration.ns_per_orbit_step * ENGINE_OVERHEAD * 1e-9;
    estimate.calibration = Some(calibration);
    estimate
}

/// The sizes of a run that its cost is a function of.
struct RunSizes {
    steps: f64,
    /// Samples the run emits (at every renormalization of a scheme, or every `sample_every`).
    samples: f64,
    dim: usize,
    k: usize,
    sets: usize,
    /// Per-set schemes by method, and window-propagator schemes (one task of `dim` lanes each).
    mpm: usize,
    vm: usize,
    propagator_mpm: usize,
    propagator_vm: usize,
    /// The per-set VM sets step in the system's fused pass, the first carrying the reference
    /// ([`crate::engine::carries_the_reference`]).
    carried: bool,
}

impl RunSizes {
    fn of(spec: &RunSpec) -> Self {
        let count = |method: Method, route: Route| {
            spec.schemes()
                .iter()
                .filter(|s| s.method == method && s.route == route)
                .count()
        };
        let total = spec.total_steps();
        let every = spec
            .sample_every_steps()
            .or_else(|| spec.schemes().iter().map(|s| s.tau_steps).min())
            .unwrap_or(total)
            .max(1);
        Self {
            steps: total as f64,
            samples: (total / every + 1) as f64,
            dim: spec.dim(),
            k: spec.k(),
            sets: spec.sets(),
            mpm: count(Method::Mpm, Route::PerSet),
            vm: count(Method::Vm, Route::PerSet),
            propagator_mpm: count(Method::Mpm, Route::WindowPropagator),
            propagator_vm: count(Method::Vm, Route::WindowPropagator),
            carried: crate::engine::carries_the_reference(spec),
        }
    }

    /// (Orbits, tangent vectors) one step advances across all tasks, and the number of tasks.
    fn task_work(&self) -> (f64, f64, usize) {
        let (dimf, kf, setsf) = (self.dim as f64, self.k as f64, self.sets as f64);
        // Per step: every (scheme, set) task: k nearby orbits (MPM), or k tangent vectors and
        // the task's own copy of the orbit (VM); a propagator scheme is one task of D lanes.
        let orbits = setsf * (self.mpm as f64 * kf + self.vm as f64)
            + self.propagator_mpm as f64 * dimf
            + self.propagator_vm as f64;
        let tangents = setsf * self.vm as f64 * kf + self.propagator_vm as f64 * dimf;
        let tasks = (self.mpm + self.vm) * self.sets + self.propagator_mpm + self.propagator_vm;
        (orbits, tangents, tasks)
    }

    /// Peak bytes, and the key that sets them.
    fn memory(&self, transport: &Transport) -> (f64, &'static str) {
        let (dimf, kf, setsf) = (self.dim as f64, self.k as f64, self.sets as f64);
        let schemes = (self.mpm + self.vm + self.propagator_mpm + self.propagator_vm) as f64;
        let (orbits, tangents, _) = self.task_work();
        // Memory, in f64 values: the directions (sets x k x D), every task's vectors and orbits,
        // one sample in the producer and one in the analysis of `run` (every (scheme, set)'s k
        // separations and stretches), and the frames in flight in shared memory (a recorder's
        // buffer and the monitors' bounded share).
        let frame = kf * dimf + kf;
        // A bus frame gathers records up to a target size (small systems) or holds one.
        let bus_frame = (transport.frame_words)(self.k, self.dim) as f64;
        let per_set_tasks = schemes * setsf;
        let values = setsf * kf * dimf
            + (orbits + tangents) * dimf
            + 2.0 * per_set_tasks * frame
            + (transport.buffered_frames as f64 + 2.0) * bus_frame;
        let bytes = 8.0 * values + transport.monitor_bytes as f64;
        // The frames in flight depend on k and D alone; the rest grows with the sets.
        let key = if transport.buffered_frames as f64 * frame > setsf * (schemes + 1.0) * frame {
            "deviations.k"
        } else {
            "deviations.sets"
        };
        (bytes, key)
    }

    fn estimate(
        &self,
        (bytes, memory_key): (f64, &'static str),
        calibration: Option<Calibration>,
        machine: &Machine,
    ) -> Estimate {
        let (orbits, tangents, tasks) = self.task_work();
        let cores = machine.cores.clamp(1, tasks.max(1));
        // The reference orbit is serial; the tasks spread over the cores. Each sample is
        // published, recorded and analysed besides: the state and every (scheme, set)'s `k`
        // separations and stretches.
        let schemes = (self.mpm + self.vm + self.propagator_mpm + self.propagator_vm) as f64;
        let (dimf, kf) = (self.dim as f64, self.k as f64);
        let sample_values = dimf + schemes * self.sets as f64 * (kf * dimf + kf);
        let sample_ns = SAMPLE_NS + SAMPLE_NS_PER_VALUE * sample_values;
        let seconds = calibration.map_or(0.0, |c| {
            let task_ns = orbits * c.ns_per_orbit_step + tangents * c.ns_per_tangent_step;
            // The reference's own steps, then the tasks' over the cores; where the VM sets take
            // the fused pass, the first of them carries the reference (in place of its steps,
            // before the others) and every such set steps its orbit's copy and `k` vectors as
            // `1 + k` lanes of the pass.
            let (serial_ns, task_ns) = match c.ns_per_fused_lane_step {
                Some(lane_ns) if self.carried => {
                    let fused_sets = (self.vm * self.sets) as f64;
                    let set_ns = (1.0 + kf) * lane_ns;
                    let others =
                        task_ns - fused_sets * (c.ns_per_orbit_step + kf * c.ns_per_tangent_step);
                    (set_ns, (fused_sets - 1.0) * set_ns + others.max(0.0))
                }
                _ => (c.ns_per_orbit_step, task_ns),
            };
            (self.steps * (serial_ns + task_ns / cores as f64) * ENGINE_OVERHEAD
                + self.samples * sample_ns)
                * 1e-9
        });
        Estimate {
            orbit_steps: self.steps * (1.0 + orbits + tangents),
            seconds,
            bytes,
            time_key: "integrator.t_final",
            work: format!(
                "{} steps x {} orbits and tangent vectors of dimension {}",
                count(self.steps),
                count(1.0 + orbits + tangents),
                self.dim
            ),
            memory_key,
            cores,
            calibration,
        }
    }
}

/// A timing of work on this thread: its CPU time, or wall-clock time where there is no such
/// clock. On a loaded machine the least of several wall-clock timings moved by a factor of
/// several between two starts of the same map; the calibration's decision of a map's route
/// must not.
struct Timing {
    cpu: Option<Duration>,
    wall: Instant,
}

impl Timing {
    fn start() -> Self {
        Self {
            cpu: chaoscope_os::cpu_time::thread(),
            wall: Instant::now(),
        }
    }

    fn elapsed(&self) -> Duration {
        match (self.cpu, chaoscope_os::cpu_time::thread()) {
            (Some(start), Some(now)) => now.saturating_sub(start),
            _ => self.wall.elapsed(),
        }
    }
}

/// Nanoseconds per call of `call`: the least of [`TIMINGS`] timings (of this thread's CPU time,
/// [`Timing`]) of at least [`MIN_TIMING`] (calls per timing doubled until one lasts that long),
/// within [`BUDGET`] of wall clock. The least, because other work on the machine (caches,
/// frequency) only ever adds to a timing.
fn ns_per_call(mut call: impl FnMut()) -> f64 {
    // Untimed: first touches of memory and caches, lazily prepared state.
    call();
    let (budget, wall) = (Timing::start(), Instant::now());
    let (mut calls, mut timings, mut least) = (1u64, 0, f64::INFINITY);
    loop {
        let t = Timing::start();
        for _ in 0..calls {
            call();
        }
        let elapsed = t.elapsed();
        let capped = wall.elapsed() >= WALL_CAP;
        if elapsed >= MIN_TIMING || capped {
            least = least.min(elapsed.as_nanos() as f64 / calls as f64);
            timings += 1;
        } else {
            calls *= 2;
        }
        if timings >= TIMINGS || (timings > 0 && budget.elapsed() >= BUDGET) || capped {
            return least;
        }
    }
}

/// Steps the run's own system from its initial state: the reference (or a nearby orbit) alone,
/// and, if a scheme uses the variational method, with tangent vectors beside it; where the VM
/// sets take the fused pass and carry the reference ([`RunSizes::carried`]), that pass, and the
/// rest only if some task steps otherwise. A state that stops being finite (an escaping orbit,
/// growing tangent vectors) starts over from `x0`.
fn calibrate_run(spec: &RunSpec, sizes: &RunSizes) -> Calibration {
    let start = Instant::now();
    let fused = if sizes.carried {
        ns_per_fused_lane_step(spec)
    } else {
        None
    };
    if let Some(lane_ns) = fused
        && sizes.mpm + sizes.propagator_mpm + sizes.propagator_vm == 0
    {
        return Calibration {
            ns_per_orbit_step: lane_ns,
            ns_per_tangent_step: lane_ns,
            ns_per_fused_lane_step: fused,
            seconds_spent: start.elapsed().as_secs_f64(),
        };
    }
    let system: &dyn DynamicalSystem = spec.system().as_ref();
    let x0 = spec.x0();
    let dim = x0.len();
    let mut work = Workspace::new();
    let (mut x, mut plan) = (x0.to_vec(), Vec::new());
    let ns_per_orbit_step = ns_per_call(|| {
        plan.clear();
        system.step_reference(&mut x, 0.0, &mut plan, &mut work);
        if !x.iter().all(|v| v.is_finite()) {
            x.copy_from_slice(x0);
        }
    });
    let ns_per_tangent_step = if sizes.vm + sizes.propagator_vm > 0 {
        // A few vectors stand for any number: their cost is linear in the count.
        let m = if sizes.propagator_vm > 0 {
            dim
        } else {
            sizes.k
        }
        .clamp(1, 4);
        let mut w = unit_vectors(m, dim);
        x.copy_from_slice(x0);
        let ns = ns_per_call(|| {
            let ok = system.step_tangent(&mut x, &mut w, 0.0, &mut work).is_ok();
            if !ok || !x.iter().chain(&w).all(|v| v.is_finite() && v.abs() < 1e100) {
                x.copy_from_slice(x0);
                w = unit_vectors(m, dim);
            }
        });
        ((ns - ns_per_orbit_step) / m as f64).max(0.0)
    } else {
        0.0
    };
    Calibration {
        ns_per_orbit_step,
        ns_per_tangent_step,
        ns_per_fused_lane_step: fused,
        seconds_spent: start.elapsed().as_secs_f64(),
    }
}

/// `m` unit vectors of dimension `dim`, one after the other (the `j`-th along axis `j`).
fn unit_vectors(m: usize, dim: usize) -> Vec<f64> {
    let mut w = vec![0.0; m * dim];
    for j in 0..m {
        w[j * dim + j % dim] = 1.0;
    }
    w
}

/// Steps of the fused pass per timed call: enough to make the call's own cost (the kernel's
/// gathers of its lanes) as small beside them as in a run's windows of many steps.
const FUSED_STEPS_PER_CALL: u64 = 64;

/// Nanoseconds per lane-step of the system's fused pass (an orbit and up to 4 tangent vectors,
/// `1 + m` lanes, stepped together) with the kernels the run will have at its start: those in
/// the kernel cache, else the pass compiled at once where the run is long enough for it, never
/// a build ([`KernelBuild::CacheOnly`]); uncounted, so the calls move no kernel switch. `None`
/// where the pass does not run now (a run too short for it).
fn ns_per_fused_lane_step(spec: &RunSpec) -> Option<f64> {
    let pass = spec.system().reference_tangent()?;
    let x0 = spec.x0();
    let dim = x0.len();
    pass.prepare(
        spec.total_steps().saturating_mul(dim as u64),
        KernelBuild::CacheOnly,
    );
    let m = spec.k().clamp(1, 4);
    let (mut x, mut v) = (x0.to_vec(), unit_vectors(m, dim));
    let steps =
        |x: &mut [f64], v: &mut [f64]| uncounted(|| pass.steps(x, v, 0, FUSED_STEPS_PER_CALL));
    if !steps(&mut x, &mut v) {
        return None;
    }
    let ns = ns_per_call(|| {
        let ok = steps(&mut x, &mut v);
        if !ok || !x.iter().chain(&v).all(|v| v.is_finite() && v.abs() < 1e100) {
            x.copy_from_slice(x0);
            v = unit_vectors(m, dim);
        }
    });
    Some(ns / (FUSED_STEPS_PER_CALL * (1 + m as u64)) as f64)
}

/// Estimate of a validated map on the instruction set the map will use: `points` grid points
/// (the shard's share), of which the share a probe of the grid finds inside the energy surface
/// ([`probe_grid`]) is integrated, each the reference orbit and every set's `k` vectors (the
/// basis route: `dim` basis vectors) to the horizon (an upper bound for points that stop early:
/// escaped, or `gali-time` below its threshold), over `threads` threads (give no more than the
/// machine's cores). Memory first; then the time from a calibration ([`calibrate_map`]).
pub fn map_on(
    spec: &MapSpec,
    points: u64,
    machine: &Machine,
    threads: usize,
    isa: Isa,
) -> Estimate {
    let run = &spec.run;
    let (dimf, setsf) = (run.dim() as f64, run.sets() as f64);
    let steps = run.total_steps() as f64;
    let pointsf = points as f64;
    // Every point's result is kept until the end (for the summary and the PNG): its per-set
    // values, its initial condition and some fixed overhead.
    let bytes = pointsf * (8.0 * (setsf + dimf) + 256.0);
    let probe = probe_grid(spec);
    let integrated = pointsf * probe.inside_share;
    let orbit_steps = integrated * route_orbits_per_point(spec, spec.route) * steps;
    let calibration = if machine.memory_bytes.is_some_and(|m| bytes > m as f64) {
        None
    } else {
        Some(
            calibrate_map(spec, isa, &probe.inside).unwrap_or(Calibration {
                ns_per_orbit_step: MAP_NS_PER_DIM * dimf,
                ns_per_tangent_step: 0.0,
                ns_per_fused_lane_step: None,
                seconds_spent: 0.0,
            }),
        )
    };
    let seconds = calibration.map_or(0.0, |c| {
        orbit_steps * c.ns_per_orbit_step * 1e-9 / threads.max(1) as f64
    });
    Estimate {
        orbit_steps,
        seconds,
        bytes,
        time_key: "integrator.t_final",
        work: format!(
            "{} points x {} orbits x {} steps of dimension {}",
            count(integrated),
            count(route_orbits_per_point(spec, spec.route)),
            count(steps),
            run.dim()
        ),
        memory_key: "map.x.n",
        cores: threads.max(1),
        calibration,
    }
}

/// How much cheaper the basis route must be estimated before a map that names no route takes
/// it. The two calibrations run back to back on one thread, each the least of several timings,
/// so load moves their ratio by tens of per cent; the route, which decides the last bits of the
/// values (equal to rounding), must not follow it. A factor 4 is twice the ratio of any example
/// that stays per-set (the Lorenz MLE map: basis 1.9x faster) and a fraction of that of the
/// maps the basis route pays most for, those of many sets (Henon-Heiles GALI_2 with 50 sets of
/// two vectors against a basis of four: 18x).
pub const ROUTE_MARGIN: f64 = 4.0;

/// The route a map that names none takes, and why: the estimate of each route.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RouteChoice {
    pub route: MapRoute,
    /// Estimated seconds of the route taken and of the other.
    pub seconds: f64,
    pub other_seconds: f64,
}

impl RouteChoice {
    /// `route basis (estimated 7.2x faster than per-set)`, or why the per-set route stays.
    pub fn reason(&self) -> String {
        let other = match self.route {
            MapRoute::PerSet => MapRoute::Basis,
            MapRoute::Basis => MapRoute::PerSet,
        };
        let ratio = self.other_seconds / self.seconds.max(f64::MIN_POSITIVE);
        if ratio >= 1.0 {
            format!(
                "route {} (estimated {ratio:.1}x faster than {})",
                self.route.name(),
                other.name()
            )
        } else {
            format!(
                "route {} (estimated {:.1}x slower than {}, within the margin of {ROUTE_MARGIN}x \
                 that a change of route needs)",
                self.route.name(),
                1.0 / ratio,
                other.name()
            )
        }
    }
}

/// [`map_on`], choosing the route of a map that names none: where the two routes give the same
/// numbers ([`MapSpec::routes_agree`]), both are estimated and the basis route is taken if it
/// is estimated at least [`ROUTE_MARGIN`] times faster (`spec.route` is set to it). The choice
/// (`None`: the route is the configuration's, or the only one that gives its numbers) says
/// why.
pub fn map_choosing_route(
    spec: &mut MapSpec,
    points: u64,
    machine: &Machine,
    threads: usize,
    isa: Isa,
) -> (Estimate, Option<RouteChoice>) {
    let per_set = map_on(spec, points, machine, threads, isa);
    let calibrated = |e: &Estimate| e.calibration.is_some_and(|c| c.seconds_spent > 0.0);
    if spec.route_named || !spec.routes_agree() || !calibrated(&per_set) {
        return (per_set, None);
    }
    let basis_spec = MapSpec {
        route: MapRoute::Basis,
        ..spec.clone()
    };
    let basis = map_on(&basis_spec, points, machine, threads, isa);
    if calibrated(&basis) && basis.seconds * ROUTE_MARGIN < per_set.seconds {
        spec.route = MapRoute::Basis;
        let choice = RouteChoice {
            route: MapRoute::Basis,
            seconds: basis.seconds,
            other_seconds: per_set.seconds,
        };
        return (basis, Some(choice));
    }
    let choice = RouteChoice {
        route: MapRoute::PerSet,
        seconds: per_set.seconds,
        other_seconds: basis.seconds,
    };
    (per_set, Some(choice))
}

/// Orbits and vectors a point of `route` advances each step, as its `orbit_steps` count them:
/// the reference and every set's `k` vectors, or the reference and one basis of `dim`.
fn route_orbits_per_point(spec: &MapSpec, route: MapRoute) -> f64 {
    let run = &spec.run;
    match route {
        MapRoute::PerSet => 1.0 + (run.sets() * run.k()) as f64,
        MapRoute::Basis => 1.0 + run.dim() as f64,
    }
}

/// [`map_on`] on this machine ([`Machine::this_host`]) with the instruction set it detects.
pub fn map(spec: &MapSpec, points: u64, threads: usize) -> Estimate {
    map_on(spec, points, &Machine::this_host(), threads, Isa::detect())
}

/// Grid points a probe looks at: enough for the share inside the energy surface to a few per
/// cent, and a few microseconds each (a point's initial state, its energy solved).
const PROBES: u64 = 256;

/// What a probe of the grid finds: the share of points inside the energy surface (the others
/// are recorded without a step), and the probed points inside, spread over the grid.
struct GridProbe {
    inside_share: f64,
    inside: Vec<u64>,
}

/// Probes up to [`PROBES`] points spread evenly over the grid (every point of a smaller grid).
fn probe_grid(spec: &MapSpec) -> GridProbe {
    let grid = spec.grid_points().max(1);
    let n = grid.min(PROBES);
    let inside: Vec<u64> = (0..n)
        .map(|i| i * grid / n)
        .filter(|&i| spec.start_point(i).is_ok())
        .collect();
    GridProbe {
        inside_share: inside.len() as f64 / n as f64,
        inside,
    }
}

/// Times one batch of the map's own points inside the energy surface (`inside`, spread over the
/// grid; as many as a batch of the map holds) computed through its route and kernel on this
/// thread, with the run cut to a few steps (more until a timing lasts [`MIN_TIMING`]); the cost
/// is the time over the orbit-steps the points report. `None` if no point is inside.
fn calibrate_map(spec: &MapSpec, isa: Isa, inside: &[u64]) -> Option<Calibration> {
    let batching = Batching::of(spec, MapOptions::default().mpm_points_per_batch);
    if inside.is_empty() {
        return None;
    }
    let n = batching.points.clamp(1, inside.len());
    let indices: Vec<u64> = (0..n).map(|i| inside[i * inside.len() / n]).collect();
    let total = spec.run.total_steps();
    // Untimed, as in `ns_per_call`: the kernels compiled at their first call, first touches of
    // memory. A timing that held a compilation would be the least only if all did.
    let warm = MapSpec {
        run: spec.run.truncated(total.min(2)),
        ..spec.clone()
    };
    uncounted(|| batching.compute(&warm, isa, &indices, &|| false));
    let (start, budget) = (Instant::now(), Timing::start());
    let (mut steps, mut timings, mut least) = (total.min(8), 0, f64::INFINITY);
    loop {
        let short = MapSpec {
            run: spec.run.truncated(steps),
            ..spec.clone()
        };
        let t = Timing::start();
        // Uncounted: the map's C-kernel switch and its call counts see only the map's calls.
        let results = uncounted(|| batching.compute(&short, isa, &indices, &|| false));
        let elapsed = t.elapsed();
        let orbit_steps: u64 = results.iter().map(|r| r.orbit_steps).sum();
        if orbit_steps == 0 {
            return None;
        }
        // A timing shorter than MIN_TIMING is mostly the batch's setup (its points' states,
        // directions and lanes): it counts only where the run is no longer than that.
        let capped = start.elapsed() >= WALL_CAP;
        if elapsed >= MIN_TIMING || steps >= total || capped {
            least = least.min(elapsed.as_nanos() as f64 / orbit_steps as f64);
            timings += 1;
        } else {
            steps = (steps * 4).min(total);
        }
        if timings >= TIMINGS || (timings > 0 && budget.elapsed() >= BUDGET) || capped {
            return Some(Calibration {
                ns_per_orbit_step: least,
                ns_per_tangent_step: 0.0,
                ns_per_fused_lane_step: None,
                seconds_spent: start.elapsed().as_secs_f64(),
            });
        }
    }
}

impl Estimate {
    /// This estimate of a map's `points` narrowed to the `todo` of them a resumed map still
    /// computes (the rest are read from its earlier file): the time and the orbit-steps scale
    /// by `todo / points`, the work names both counts; the memory stays, since every point's
    /// result, resumed or computed, is held to the end. The route is chosen before, on all the
    /// points, so that it does not depend on how far the map got.
    pub fn narrowed_to(mut self, todo: u64, points: u64) -> Self {
        if todo >= points {
            return self;
        }
        let share = todo as f64 / points as f64;
        self.orbit_steps *= share;
        self.seconds *= share;
        self.work = format!(
            "{}, of which {todo} of the {points} points are still to compute",
            self.work
        );
        self
    }

    /// Why this should not start without `--force`, on one line naming the key; `None` if it
    /// fits a day and the machine's memory.
    pub fn refusal(&self, machine: &Machine) -> Option<String> {
        if let Some(memory) = machine.memory_bytes
            && self.bytes > memory as f64
        {
            return Some(format!(
                "{}: this would need about {} of memory, more than this machine's {} \
                 (estimated from the configuration: {}); pass --force to start it anyway",
                self.memory_key,
                bytes(self.bytes),
                bytes(memory as f64),
                self.work
            ));
        }
        if self.seconds > MAX_SECONDS {
            return Some(format!(
                "{}: this would take about {} on {} core{} (estimated from the configuration: \
                 {}, {:.1e} orbit-steps); shorten it, or pass --force to start it anyway",
                self.time_key,
                duration(self.seconds),
                self.cores,
                if self.cores == 1 { "" } else { "s" },
                self.work,
                self.orbit_steps
            ));
        }
        None
    }
}

/// `5000`, `2.0e10`.
fn count(n: f64) -> String {
    if n < 1e6 {
        format!("{n:.0}")
    } else {
        format!("{n:.1e}")
    }
}

/// `12.3 GiB`, `512 MiB`.
fn bytes(b: f64) -> String {
    const GIB: f64 = (1u64 << 30) as f64;
    if b >= 1024.0 * GIB {
        format!("{:.1} TiB", b / (1024.0 * GIB))
    } else if b >= GIB {
        format!("{:.1} GiB", b / GIB)
    } else {
        format!("{:.0} MiB", b / (1u64 << 20) as f64)
    }
}

/// `3.2 hours`, `41 days`, `2.1e6 years`.
fn duration(s: f64) -> String {
    let (h, d, y) = (3600.0, 86_400.0, 365.25 * 86_400.0);
    if s < d {
        format!("{:.1} hours", s / h)
    } else if s < 1e4 * y {
        // Whole days or years, with the noun agreeing ("1 day", "1 year", "2 days").
        let (count, unit) = if s < y {
            ((s / d).round(), "day")
        } else {
            ((s / y).round(), "year")
        };
        let plural = if count == 1.0 { "" } else { "s" };
        format!("{count:.0} {unit}{plural}")
    } else {
        format!("{:.1e} years", s / y)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use chaoscope_schemas::config::{DeviationsConfig, RunConfig, SchemeConfig, paper};

    const TWO_CORES: Machine = Machine {
        cores: 2,
        memory_bytes: Some(24 << 30),
    };

    /// The bus's frames in flight as `chaoscope-dynamics` passes them (its `estimate::BUS`:
    /// 64 buffered frames, 64 MiB of monitor frames, frames of at least 1024 words and a record
    /// header of 8), so these runs are estimated as `chaoscope run` estimates them.
    const BUS: Transport = Transport {
        buffered_frames: 64,
        monitor_bytes: 64 << 20,
        frame_words: |k, dim| (k * dim + k + 8).max(1024),
    };

    #[test]
    fn the_default_run_is_seconds_and_megabytes() {
        let cfg = paper::henon_heiles(
            paper::HH_CHAOTIC_Q2,
            1000.0,
            DeviationsConfig::random(4, 1, 1),
            vec![
                SchemeConfig::new("vm", "vm", 1e-8, 1.0),
                SchemeConfig::new("mpm", "mpm", 1e-8, 1.0),
            ],
        );
        let e = run(&RunSpec::from_config(&cfg).unwrap(), &TWO_CORES, &BUS);
        // 1e5 steps x (1 + 9 / 2) orbit-steps at about 100 ns: about 0.05 s. Bounds a
        // factor of 5 and 20 away: a calibration on a loaded machine, or a slower one, stays
        // inside; a cost off by orders of magnitude (a unit, a count) does not.
        assert!(e.seconds > 0.01 && e.seconds < 1.0, "{e:?}");
        let c = e.calibration.unwrap();
        assert!(
            c.ns_per_tangent_step > 0.0 && c.seconds_spent < 1.0,
            "{c:?}"
        );
        assert!(e.bytes < 128.0 * (1 << 20) as f64, "{e:?}");
        assert_eq!(e.refusal(&TWO_CORES), None);
    }

    #[test]
    fn a_long_chain_for_a_billion_time_units_is_refused() {
        let text = r#"
[model]
name = "fput-beta"
n = 501
[orbit]
preset = "spo1"
energy = 50.0
[integrator]
method = "aba864"
h = 0.05
t_final = 1e9
[deviations]
k = 2
[[scheme]]
name = "m"
method = "mpm"
d0 = 1e-8
tau = 1.0
"#;
        let cfg = RunConfig::from_toml(text).unwrap();
        let e = run(&RunSpec::from_config(&cfg).unwrap(), &TWO_CORES, &BUS);
        let why = e.refusal(&TWO_CORES).unwrap();
        assert!(
            why.starts_with("integrator.t_final: this would take about"),
            "{why}"
        );
        assert!(why.contains("--force") && !why.contains('\n'), "{why}");
    }

    #[test]
    fn flows_and_maps_are_estimated_at_their_dimension() {
        // A flow of 3 coordinates and a map of 2: the dimension is the validated spec's, as for
        // Hamiltonians (2N), so the cost scales with each system's own size.
        let runs = [
            (
                "[model]\nname = \"ode\"\nrhs = [\"x2\", \"x3\", \"-x1\"]\n[orbit]\nx = [1.0, 0.0, 0.0]\n\
                 [integrator]\nmethod = \"rk4\"\nh = 0.01\nt_final = 1e13\n",
                3,
            ),
            (
                "[model]\nname = \"map\"\nnext = [\"x2\", \"-x1\"]\n[orbit]\nx = [0.5, 0.0]\n\
                 [integrator]\nh = 1\nt_final = 1e14\n",
                2,
            ),
        ];
        for (system, dim) in runs {
            let text = format!(
                "{system}[deviations]\nk = 2\n[[scheme]]\nname = \"v\"\nmethod = \"vm\"\n\
                 d0 = 1e-8\ntau = 1\n"
            );
            let spec = RunSpec::from_config(&RunConfig::from_toml(&text).unwrap()).unwrap();
            let e = run(&spec, &TWO_CORES, &BUS);
            assert!(e.work.ends_with(&format!("of dimension {dim}")), "{e:?}");
            // 1e15 and 1e14 steps, 4 orbits each (the reference, the task's copy and k = 2
            // tangent vectors) on one core: at a nanosecond per orbit-step (what the calibration
            // of these few-operation systems cannot undercut), 46 and 4.6 days. Refused.
            assert!(e.seconds > 86_400.0, "{e:?}");
            assert!(e.refusal(&TWO_CORES).is_some());
        }
    }

    /// The DKG chain of `examples/models` at 200 sites to t = 50000 (10^6 ABA864 steps), with
    /// `schemes` appended.
    fn dkg_chain(k: usize, schemes: &str) -> RunSpec {
        let text = include_str!("../../examples/models/dkg-single-site.toml")
            .replace("n = 1000\n", "n = 200\n")
            .replace("sites = 500,", "sites = 100,")
            .replace("t_final = 5000.0", "t_final = 50000.0")
            .replace("k = 2\n", &format!("k = {k}\n"));
        RunSpec::from_config(&RunConfig::from_toml(&format!("{text}{schemes}")).unwrap()).unwrap()
    }

    /// A lattice run whose VM set takes the fused pass and carries the reference is timed on
    /// that pass, not on separate orbit and tangent steps (about 15x slower: the estimate of
    /// this very run said 14 s for a run of 0.8 s of CPU time): its steps cost `1 + k` lanes of
    /// the pass, the reference nothing beside them. A second scheme of nearby orbits (MPM)
    /// steps one orbit at a time, so the one-orbit costs are timed too, and its orbits added.
    #[test]
    fn a_run_carried_by_the_fused_pass_is_timed_on_it() {
        let spec = dkg_chain(1, "");
        assert!(crate::engine::carries_the_reference(&spec));
        let e = run(&spec, &TWO_CORES, &BUS);
        let c = e.calibration.unwrap();
        let lane = c.ns_per_fused_lane_step.expect("the fused pass is timed");
        assert_eq!((c.ns_per_orbit_step, c.ns_per_tangent_step), (lane, lane));
        let sizes = RunSizes::of(&spec);
        let sample_ns = SAMPLE_NS + SAMPLE_NS_PER_VALUE * (400.0 + 401.0);
        let want = (1e6 * 2.0 * lane * ENGINE_OVERHEAD + sizes.samples * sample_ns) * 1e-9;
        assert!(
            (e.seconds - want).abs() < 1e-9 * want,
            "{} s, want {want} s",
            e.seconds
        );

        let mpm = "[[scheme]]\nname = \"mpm\"\nmethod = \"mpm\"\nd0 = 1e-8\ntau = 10.0\n";
        let both = dkg_chain(1, mpm);
        let e = run(&both, &TWO_CORES, &BUS);
        let c = e.calibration.unwrap();
        let lane = c.ns_per_fused_lane_step.expect("the fused pass is timed");
        assert!(
            c.ns_per_orbit_step != lane,
            "the one-orbit step is timed: {c:?}"
        );
        // The carrier first, then the MPM set's one nearby orbit on the second core.
        let sizes = RunSizes::of(&both);
        let sample_ns = SAMPLE_NS + SAMPLE_NS_PER_VALUE * (400.0 + 2.0 * 401.0);
        let want = (1e6 * (2.0 * lane + c.ns_per_orbit_step / 2.0) * ENGINE_OVERHEAD
            + sizes.samples * sample_ns)
            * 1e-9;
        assert!(
            (e.seconds - want).abs() < 1e-9 * want,
            "{} s, want {want} s",
            e.seconds
        );

        // Nearby orbits alone: nothing carries the reference.
        let text = include_str!("../../examples/models/dkg-single-site.toml")
            .replace("method = \"vm\"", "method = \"mpm\"");
        let spec = RunSpec::from_config(&RunConfig::from_toml(&text).unwrap()).unwrap();
        assert!(!crate::engine::carries_the_reference(&spec));
        let c = run(&spec, &TWO_CORES, &BUS).calibration.unwrap();
        assert_eq!(c.ns_per_fused_lane_step, None);
    }

    /// The Henon-Heiles section map of the paper (MLE, VM, k = 1, one set) on an 8 x 6 grid whose
    /// first point (q2 = p2 = -0.45) lies outside the energy surface, on `route`.
    fn hh_section_map(route: Option<&str>) -> MapSpec {
        let mut cfg = paper::henon_heiles(
            0.0,
            100.0,
            DeviationsConfig::random(1, 1, 1),
            vec![SchemeConfig::new("vm", "vm", 1e-8, 1.0)],
        );
        cfg.map = Some(chaoscope_schemas::config::MapConfig {
            route: route.map(str::to_string),
            ..paper::hh_section_map(8, 6, "mle")
        });
        MapSpec::from_config(&cfg).unwrap()
    }

    #[test]
    fn a_map_is_calibrated_on_its_points_inside_the_energy_surface() {
        let spec = hh_section_map(Some("per-set"));
        assert!(spec.start_point(0).is_err(), "the first point is outside");
        let e = map_on(&spec, spec.grid_points(), &TWO_CORES, 1, Isa::detect());
        // Timed, not the fallback of a map with no point inside (seconds_spent 0).
        let c = e.calibration.unwrap();
        assert!(c.seconds_spent > 0.0, "{c:?}");
        // Only the points inside are integrated: 10^4 steps of 2 orbits each, for fewer than
        // the 48 points and more than half of them (the section's disc covers most of the grid).
        let all = 48.0 * 2.0 * 1e4;
        assert!(e.orbit_steps < all && e.orbit_steps > 0.5 * all, "{e:?}");
    }

    #[test]
    fn a_resumed_map_is_estimated_for_its_remaining_points_and_holds_all_of_them() {
        let spec = hh_section_map(Some("per-set"));
        let whole = map_on(&spec, 48, &TWO_CORES, 1, Isa::detect());
        let rest = whole.clone().narrowed_to(12, 48);
        // A quarter of the points: a quarter of the work and of the time, the same memory.
        assert_eq!(rest.orbit_steps, whole.orbit_steps * 0.25);
        assert_eq!(rest.seconds, whole.seconds * 0.25);
        assert_eq!(rest.bytes, whole.bytes);
        assert!(
            rest.work
                .ends_with("12 of the 48 points are still to compute"),
            "{}",
            rest.work
        );
        // A map with nothing resumed is the map's own estimate, nothing said.
        assert_eq!(whole.clone().narrowed_to(48, 48).work, whole.work);
        // Nothing left: no time, and no refusal for time (the memory is checked as ever).
        let done = Estimate {
            seconds: 1e9,
            ..whole.clone()
        }
        .narrowed_to(0, 48);
        assert_eq!((done.seconds, done.orbit_steps), (0.0, 0.0));
        assert!(done.refusal(&TWO_CORES).is_none());
    }

    #[test]
    fn a_named_route_is_kept_and_an_unnamed_one_is_chosen_where_the_routes_agree() {
        for route in ["per-set", "basis"] {
            let mut spec = hh_section_map(Some(route));
            let (_, choice) = map_choosing_route(&mut spec, 48, &TWO_CORES, 1, Isa::detect());
            assert_eq!((spec.route.name(), choice), (route, None));
        }
        // Unnamed: both routes estimated, the one taken said with both estimates; which one
        // depends on the timings (the values do not: map_routes.rs).
        let mut spec = hh_section_map(None);
        let (e, choice) = map_choosing_route(&mut spec, 48, &TWO_CORES, 1, Isa::detect());
        let choice = choice.expect("chosen by cost");
        assert_eq!((choice.route, choice.seconds), (spec.route, e.seconds));
        assert!(choice.other_seconds > 0.0, "{choice:?}");
        assert!(choice.reason().starts_with("route "), "{}", choice.reason());
    }

    #[test]
    fn durations_read_as_english() {
        assert_eq!(duration(1800.0), "0.5 hours");
        assert_eq!(duration(86_400.0), "1 day");
        assert_eq!(duration(3.0 * 86_400.0), "3 days");
        assert_eq!(duration(365.25 * 86_400.0), "1 year");
        assert_eq!(duration(2.4 * 365.25 * 86_400.0), "2 years");
        assert_eq!(duration(3e4 * 365.25 * 86_400.0), "3.0e4 years");
    }

    #[test]
    fn a_section_of_many_long_orbits_is_refused_and_a_small_one_is_not() {
        let spec_to = |t_final| {
            let cfg = paper::henon_heiles(
                paper::HH_CHAOTIC_Q2,
                t_final,
                DeviationsConfig::random(4, 1, 1),
                vec![SchemeConfig::new("vm", "vm", 1e-8, 1.0)],
            );
            RunSpec::from_config(&cfg).unwrap()
        };
        // 30 orbits of 10^5 steps: well under a second per orbit.
        let small = section(&spec_to(1000.0), 30, 400, &TWO_CORES);
        assert!(small.refusal(&TWO_CORES).is_none(), "{small:?}");
        assert!(small.calibration.is_some());
        // 10^7 orbits of 10^7 steps: 10^14 steps, weeks at any speed (a step is > 10 ns).
        let many = section(&spec_to(1e5), 10_000_000, 10, &TWO_CORES);
        let why = many.refusal(&TWO_CORES).expect("refused");
        assert!(
            why.starts_with("integrator.t_final: this would take about"),
            "{why}"
        );
        // 2^40 crossings kept per orbit: terabytes, refused before any step is timed.
        let huge = section(&spec_to(1000.0), 30, 1 << 40, &TWO_CORES);
        let why = huge.refusal(&TWO_CORES).expect("refused");
        assert!(
            why.starts_with("--count x --crossings: this would need about"),
            "{why}"
        );
        assert!(huge.calibration.is_none());
    }
}
