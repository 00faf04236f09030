//! What a run or a map will cost, estimated from its configuration before anything starts.
//!
//! A typo (`t_final = 1e9` for `1e6`, `n = 700` for `70`) can turn a run into a month of a
//! shared machine or a request for more memory than it has, found out only when the job is
//! killed. The commands refuse such a run up front with an estimate (`--force` runs it anyway).
//! The estimate is a product of sizes and one cost per orbit-step measured once on the
//! development machine (below); it only has to be right within a factor of a few, since it is
//! compared with limits (a day, the machine's memory) that real runs are far from or far above.
//!
//! Pure: the caller says how many cores and how much memory the machine has ([`Machine`];
//! `Machine::this_host` reads them from `/proc`, the one I/O here).

use chaoscope_bus as bus;

use crate::map::MapSpec;
use chaoscope_schemas::run::{Method, SystemKind};

use crate::spec::RunSpec;

/// Cost of one orbit-step (one trajectory or tangent vector advanced one ABA864 step) of the
/// one-orbit engine (`chaoscope run`/`produce`): `ENGINE_NS_BASE + ENGINE_NS_PER_DIM * 2N`
/// nanoseconds. Measured with `chaoscope produce --recorders 0` on one core (2-core Xeon,
/// AVX-512): Henon-Heiles 100 (VM) and 123 (MPM) ns; FPUT N = 101 MPM 1.35 us; FPUT N = 501
/// 5.3 (MPM) and 6.8 (VM) us per orbit-step.
pub const ENGINE_NS_BASE: f64 = 80.0;
pub const ENGINE_NS_PER_DIM: f64 = 5.0;

/// Cost of one orbit-step of the batched map kernel per phase-space dimension, in nanoseconds
/// (RESULTS-maps.md: Henon-Heiles 2.7 ns per orbit-step, FPUT N = 501 1.6 to 3.2 us).
pub const MAP_NS_PER_DIM: f64 = 1.0;

/// Longest run (wall clock) started without `--force`.
pub const MAX_SECONDS: f64 = 86_400.0;

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
}

/// Estimate of a validated run (validation draws no direction and allocates nothing in
/// proportion to the run, so this comes before any of it). Its sizes are the spec's: the
/// dimension of every kind of system, the sets, the schemes.
pub fn run(spec: &RunSpec, machine: &Machine) -> Estimate {
    let vm = spec
        .schemes()
        .iter()
        .filter(|s| s.method == Method::Vm)
        .count();
    run_estimate(
        spec.system().kind(),
        spec.total_steps() as f64,
        spec.dim(),
        spec.k(),
        spec.sets(),
        spec.schemes().len(),
        vm,
        machine,
    )
}

/// Nanoseconds of one orbit-step of the one-orbit engine for a system of `kind` and dimension
/// `dim`: the place to calibrate each kind of system. Measured for separable Hamiltonians
/// (above); flows and maps are charged the same until measured (an expression's evaluation
/// costs about what a force does, and the estimate need only be right within a factor of a
/// few).
fn engine_ns_per_orbit_step(kind: SystemKind, dim: usize) -> f64 {
    match kind {
        SystemKind::Hamiltonian | SystemKind::Flow | SystemKind::Map => {
            ENGINE_NS_BASE + ENGINE_NS_PER_DIM * dim as f64
        }
    }
}

#[allow(clippy::too_many_arguments)]
fn run_estimate(
    kind: SystemKind,
    steps: f64,
    dim: usize,
    k: usize,
    sets: usize,
    schemes: usize,
    vm_schemes: usize,
    machine: &Machine,
) -> Estimate {
    let (dimf, kf, setsf) = (dim as f64, k as f64, sets as f64);
    // Per step: the reference orbit (serial), then every (scheme, set) task in parallel: k
    // nearby orbits (MPM), or k tangent vectors and the task's own copy of the orbit (VM).
    let task_orbits = setsf * (schemes as f64 * kf + vm_schemes as f64);
    let ns = engine_ns_per_orbit_step(kind, dim);
    let cores = machine.cores.clamp(1, (schemes * sets).max(1)) as f64;
    let seconds = steps * ns * (1.0 + task_orbits / cores) * 1e-9;
    // Memory, in f64 values: the directions (sets x k x 2N), every task's vectors and orbits,
    // one sample in the producer and one in the analysis of `run` (every task's k separations
    // and stretches), and the frames in flight in shared memory (a recorder's buffer and the
    // monitors' bounded share).
    let frame = kf * dimf + kf;
    // A bus frame gathers records up to a target size (small systems) or holds one.
    let bus_frame =
        bus::max_frame_words(k * dim + k + chaoscope_bus::frame::RECORD_HEADER_WORDS) as f64;
    let tasks = schemes as f64 * setsf;
    let values = setsf * kf * dimf
        + tasks * (kf + 1.0) * dimf
        + 2.0 * tasks * frame
        + (bus::DATA_BUFFER as f64 + 2.0) * bus_frame;
    let bytes = 8.0 * values + bus::MONITOR_MEMORY as f64;
    // The frames in flight depend on k and 2N alone; the rest grows with the sets.
    let memory_key = if bus::DATA_BUFFER as f64 * frame > setsf * (schemes as f64 + 1.0) * frame {
        "deviations.k"
    } else {
        "deviations.sets"
    };
    Estimate {
        orbit_steps: steps * (1.0 + task_orbits),
        seconds,
        bytes,
        time_key: "integrator.t_final",
        work: format!(
            "{} steps x {} orbits of dimension {dim}",
            count(steps),
            count(1.0 + task_orbits)
        ),
        memory_key,
        cores: cores as usize,
    }
}

/// Estimate of a validated map: `points` grid points (the shard's share), each the reference
/// orbit and every set's `k` vectors (the basis route: `dim` basis vectors) to the horizon (an upper bound for points that stop early:
/// outside the energy surface, escaped, or `gali-time` below its threshold).
pub fn map(spec: &MapSpec, points: u64, threads: usize) -> Estimate {
    let run = &spec.run;
    let (dimf, setsf) = (run.dim() as f64, run.sets() as f64);
    let per_point = match spec.route {
        crate::map::MapRoute::PerSet => 1.0 + setsf * run.k() as f64,
        // One basis of dim tangent vectors or nearby orbits per point.
        crate::map::MapRoute::Basis => 1.0 + dimf,
    };
    let steps = run.total_steps() as f64;
    let pointsf = points as f64;
    let orbit_steps = pointsf * per_point * steps;
    let seconds = orbit_steps * MAP_NS_PER_DIM * dimf * 1e-9 / threads.max(1) as f64;
    // Every point's result is kept until the end (for the summary and the PNG): its per-set
    // values, its initial condition and some fixed overhead.
    let bytes = pointsf * (8.0 * (setsf + dimf) + 256.0);
    Estimate {
        orbit_steps,
        seconds,
        bytes,
        time_key: "integrator.t_final",
        work: format!(
            "{} points x {} orbits x {} steps of dimension {}",
            count(pointsf),
            count(per_point),
            count(steps),
            run.dim()
        ),
        memory_key: "map.x.n",
        cores: threads.max(1),
    }
}

impl Estimate {
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
    } else if s < y {
        format!("{:.0} days", s / d)
    } else if s < 1e4 * y {
        format!("{:.0} years", s / y)
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
        let e = run(&RunSpec::from_config(&cfg).unwrap(), &TWO_CORES);
        // 1e5 steps x (1 + 9 / 2) orbit-steps at 100 ns: about 0.05 s.
        assert!(e.seconds > 0.01 && e.seconds < 1.0, "{e:?}");
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
        let e = run(&RunSpec::from_config(&cfg).unwrap(), &TWO_CORES);
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
                 [integrator]\nmethod = \"rk4\"\nh = 0.01\nt_final = 1e11\n",
                3,
            ),
            (
                "[model]\nname = \"map\"\nnext = [\"x2\", \"-x1\"]\n[orbit]\nx = [0.5, 0.0]\n\
                 [integrator]\nh = 1\nt_final = 1e12\n",
                2,
            ),
        ];
        for (system, dim) in runs {
            let text = format!(
                "{system}[deviations]\nk = 2\n[[scheme]]\nname = \"v\"\nmethod = \"vm\"\n\
                 d0 = 1e-8\ntau = 1\n"
            );
            let spec = RunSpec::from_config(&RunConfig::from_toml(&text).unwrap()).unwrap();
            let e = run(&spec, &TWO_CORES);
            assert!(e.work.ends_with(&format!("of dimension {dim}")), "{e:?}");
            // 1e13 and 1e12 steps of about 100 ns, 4 orbits each (the reference, the task's copy
            // and k = 2 tangent vectors) on one core: weeks, refused.
            assert!(e.seconds > 86_400.0, "{e:?}");
            assert!(e.refusal(&TWO_CORES).is_some());
        }
    }
}
