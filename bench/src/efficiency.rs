//! `chaoscope bench --efficiency-only`: the integrator efficiency table of the lattices, as
//! Danieli, Many Manda, Mithun and Skokos (Math. in Eng. 1, 447 (2019), arXiv:1812.01870)
//! measure it: for each lattice and each integrator chaoscope offers for it, over step sizes
//! `h`, the CPU time of one thread to a fixed `t` with one VM tangent vector (the tangent
//! dynamics is that paper's subject) against the maximal relative energy error (and for the
//! DDNLS the norm error); then, at a few target errors, each integrator's CPU time interpolated
//! log-log between its step sizes, and the ranking, fastest first, beside the paper's.
//!
//! Every run goes through the engine a `chaoscope run` drives (`RunSpec::from_config` of a
//! configuration as a user writes it, `Engine::new`, `next_sample`), in this process with no
//! bus or recorder, inside a rayon pool of one thread, so the CPU time of that thread is the
//! whole run's. The energy is read from each sample (`Sample::energy`, what the run's report
//! carries), the DDNLS norm from each sample's state; a sample every 10 time units (`tau`).
//!
//! The lattices: the beta-FPUT chain (built in, fixed ends, beta = 1, every site's momentum
//! `+-sqrt(0.2)` with signs drawn from seed 1: energy 0.1 per site), the disordered
//! Klein-Gordon chain of `examples/models/dkg-single-site.toml` (an expression, its C kernels
//! built into the kernel cache before the clock starts), the 1-D DDNLS of
//! `examples/models/ddnls-block.toml` (21 central sites of norm 1) and the 2-D DDNLS of
//! `examples/models/ddnls-square.toml` (a 3 x 3 central block), each at `sites` sites (the
//! square's side the integer square root) to `t_final`.

use chaoscope_dynamics::engine::Engine;
use chaoscope_dynamics::integrator::composition::{Composition, CompositionScheme};
use chaoscope_dynamics::integrator::{Splitting, SplittingScheme};
use chaoscope_dynamics::model::{Ddnls, SQUARE_LOOPS_FROM_SIDE};
use chaoscope_dynamics::spec::RunSpec;
use chaoscope_schemas::config::{ModelConfig, RunConfig};

/// Target relative errors of the table: a loose, a moderate and a tight accuracy.
pub const TARGETS: [f64; 3] = [1e-5, 1e-8, 1e-10];

/// The renormalization period of the VM vector, and the sample interval: long enough that
/// a window's fixed cost (renormalization, sample, check of the state: a few microseconds)
/// stays small beside its steps at the largest step size, short enough that the maximum of the
/// energy error over the samples is the run's (the error oscillates on the lattice's
/// time scales, of order 1 to 10).
const TAU: f64 = 10.0;

/// Step sizes per integrator: the family's largest, halved this many times at most.
const HALVINGS: u32 = 5;

/// Below this fraction of the smallest target, a smaller step size says nothing more about the
/// table (and soon reaches the rounding floor): the halving stops.
const BELOW_SMALLEST_TARGET: f64 = 1e-2;

/// One step size of one integrator: its CPU seconds and maximal relative errors, or why the
/// run stopped (a step size past the method's stability).
#[derive(Debug, Clone, PartialEq)]
pub struct Point {
    pub h: f64,
    pub cpu_seconds: f64,
    pub energy_error: f64,
    /// The maximal energy error over the whole run over that of its first half: about 1 for a
    /// bounded error (a symplectic method), about 2 for one that drifts linearly in time.
    pub energy_growth: f64,
    /// The DDNLS's maximal relative norm error; `None` for the other lattices.
    pub norm_error: Option<f64>,
    pub failed: Option<String>,
}

/// Where an integrator's CPU time at a target error lies.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Reach {
    /// Interpolated log-log between the two step sizes around the target.
    Interpolated(f64),
    /// Even the cheapest (largest) step size is below the target: at most its CPU time.
    AtMost(f64),
    /// No step size measured reaches the target.
    NotReached,
}

impl Reach {
    fn seconds(self) -> Option<f64> {
        match self {
            Reach::Interpolated(s) | Reach::AtMost(s) => Some(s),
            Reach::NotReached => None,
        }
    }
}

/// The CPU time at which `points` (CPU seconds, relative error) reach the relative error
/// `target`: the cheapest point at or below the target, and if a cheaper point lies above
/// it, the straight line between the two in `(log error, log CPU)` evaluated at the target.
/// Points with a non-finite or non-positive value are left out (a failed run, an error of
/// exactly 0).
pub fn cpu_at(points: &[(f64, f64)], target: f64) -> Reach {
    let mut valid: Vec<(f64, f64)> = points
        .iter()
        .copied()
        .filter(|&(c, e)| c.is_finite() && c > 0.0 && e.is_finite() && e > 0.0)
        .collect();
    valid.sort_by(|a, b| a.0.total_cmp(&b.0));
    let Some(j) = valid.iter().position(|&(_, e)| e <= target) else {
        return Reach::NotReached;
    };
    if j == 0 {
        return Reach::AtMost(valid[0].0);
    }
    // valid[j - 1] is cheaper and above the target, valid[j] at or below it.
    let (c0, e0) = valid[j - 1];
    let (c1, e1) = valid[j];
    let f = (target.ln() - e0.ln()) / (e1.ln() - e0.ln());
    Reach::Interpolated((c0.ln() + f * (c1.ln() - c0.ln())).exp())
}

/// The integrators ordered by their CPU time at `target` (fastest first; an `AtMost` counts
/// as its bound), and apart the ones that did not reach it. `curves` are (method, points of
/// (CPU seconds, relative error)).
pub fn ranking(
    curves: &[(String, Vec<(f64, f64)>)],
    target: f64,
) -> (Vec<(String, Reach)>, Vec<String>) {
    let mut ranked = Vec::new();
    let mut not_reached = Vec::new();
    for (method, points) in curves {
        match cpu_at(points, target) {
            Reach::NotReached => not_reached.push(method.clone()),
            reach => ranked.push((method.clone(), reach)),
        }
    }
    ranked.sort_by(|a, b| {
        let (x, y) = (
            a.1.seconds().unwrap_or(f64::INFINITY),
            b.1.seconds().unwrap_or(f64::INFINITY),
        );
        x.total_cmp(&y)
    });
    (ranked, not_reached)
}

/// The step sizes of a family: `h_max`, `h_max / 2`, ... (`HALVINGS + 1` of them). Powers of
/// two times `h_max`, which is itself a power of two, so every one divides `tau = 10` and the
/// final time exactly.
pub fn step_sizes(h_max: f64) -> Vec<f64> {
    (0..=HALVINGS)
        .map(|k| h_max / f64::from(1u32 << k))
        .collect()
}

/// The 2-D disordered Klein-Gordon lattice the table runs, written as an expression.
const DKG_SQUARE: &str = include_str!("../../examples/models/dkg-square.toml");

/// A lattice of the table.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Family {
    FputBeta,
    Dkg,
    Dkg2d,
    Ddnls1d,
    Ddnls2d,
}

impl Family {
    pub const ALL: [Family; 5] = [
        Family::FputBeta,
        Family::Dkg,
        Family::Dkg2d,
        Family::Ddnls1d,
        Family::Ddnls2d,
    ];

    pub fn name(self) -> &'static str {
        match self {
            Family::FputBeta => "fput_beta",
            Family::Dkg => "dkg",
            Family::Dkg2d => "dkg_2d",
            Family::Ddnls1d => "ddnls_1d",
            Family::Ddnls2d => "ddnls_2d",
        }
    }

    fn is_ddnls(self) -> bool {
        matches!(self, Family::Ddnls1d | Family::Ddnls2d)
    }

    /// The largest step size, a power of two, where the cheapest methods' errors lie above the
    /// loosest target and the fastest linear frequency `omega` keeps `omega h` of order one
    /// (FPUT: `omega <= 2` plus the quartic term; DKG: `omega <= sqrt(3/2 + 4/W) ~ 1.6`, on the
    /// square `sqrt(3/2 + 2/W) ~ 1.3` at W = 10, 0.4 per excited site adding ~20 %; DDNLS
    /// chain: on-site `|eps| <= 2` and hopping 2; square: `|eps| <= 5` and hopping 4). A step
    /// past a method's stability is reported as failed, not ranked.
    fn h_max(self) -> f64 {
        match self {
            Family::FputBeta | Family::Dkg | Family::Dkg2d | Family::Ddnls1d => 0.5,
            Family::Ddnls2d => 0.25,
        }
    }

    /// The integrators chaoscope offers for the family: (config name, order, force evaluations
    /// or part flows per step).
    pub fn methods(self) -> Vec<(&'static str, u32, usize)> {
        match self {
            Family::FputBeta | Family::Dkg | Family::Dkg2d => SplittingScheme::ALL
                .iter()
                .map(|&k| (k.name(), k.order(), Splitting::new(k).kicks().len()))
                .collect(),
            Family::Ddnls1d | Family::Ddnls2d => {
                let mut m: Vec<(&'static str, u32, usize)> = CompositionScheme::ALL
                    .iter()
                    .map(|&k| (k.name(), k.order(), Composition::new(k, 3).stages().len()))
                    .collect();
                // The Runge-Kutta reference: 12 evaluations of the vector field (and of its
                // Jacobian along the tangent vector) per step.
                if self == Family::Ddnls1d {
                    m.push(("dop853", 8, 12));
                }
                m
            }
        }
    }

    /// The configuration text of a run of `sites` sites to `t_final` by `method` at step `h`.
    pub fn config(
        self,
        sites: usize,
        t_final: f64,
        method: &str,
        h: f64,
    ) -> anyhow::Result<RunConfig> {
        let common = format!(
            "[integrator]\nmethod = \"{method}\"\nh = {h:?}\nt_final = {t_final:?}\n\
             [deviations]\nk = 1\nsets = 1\nseed = 1\n\
             [[scheme]]\nname = \"vm\"\nmethod = \"vm\"\nd0 = 1e-8\ntau = {TAU:?}\n"
        );
        let text = match self {
            Family::FputBeta => format!(
                "[run]\nname = \"bench-efficiency-fput\"\n\
                 [model]\nname = \"fput-beta\"\nn = {sites}\nbeta = 1.0\n\
                 [orbit]\nexcite = {{ sites = [1, {sites}], energy = {e:?}, seed = 1 }}\n{common}",
                e = 0.1 * sites as f64
            ),
            Family::Dkg => {
                let mut config = super::dkg::config(sites, t_final)?;
                config.run.name = Some("bench-efficiency-dkg".into());
                config.run.sample_every = None;
                config.integrator.method = method.into();
                config.integrator.h = Some(h);
                for s in &mut config.schemes {
                    s.tau = TAU;
                }
                return Ok(config);
            }
            Family::Dkg2d => {
                let side = sites.isqrt().max(3);
                let mid = side.div_ceil(2);
                // The example's `[model]` table, at this side.
                let model = DKG_SQUARE
                    .find("[model]")
                    .zip(DKG_SQUARE.find("[orbit]"))
                    .map(|(from, to)| &DKG_SQUARE[from..to])
                    .filter(|m| m.contains("\nn = 21\n"))
                    .ok_or_else(|| {
                        anyhow::anyhow!(
                            "the 2-D DKG example changed shape: the bench cannot set its side"
                        )
                    })?
                    .replace("\nn = 21\n", &format!("\nn = {side}\n"));
                format!(
                    "[run]\nname = \"bench-efficiency-dkg-square\"\n{model}\
                     [orbit]\nexcite = {{ sites = [{a}, {b}], energy = 3.6, seed = 3 }}\n{common}",
                    a = mid - 1,
                    b = mid + 1
                )
            }
            Family::Ddnls1d => {
                let mid = sites.div_ceil(2);
                let (first, last) = (mid.saturating_sub(10).max(1), (mid + 10).min(sites));
                format!(
                    "[run]\nname = \"bench-efficiency-ddnls\"\n\
                     [model]\nname = \"ddnls\"\nlattice = \"chain\"\nn = {sites}\nW = 4.0\n\
                     beta = 0.72\nseed = 1\n\
                     [orbit]\nexcite = {{ sites = [{first}, {last}], norm = {norm:?}, seed = 4 }}\n\
                     {common}",
                    norm = (last - first + 1) as f64
                )
            }
            Family::Ddnls2d => {
                let side = sites.isqrt().max(3);
                let mid = side.div_ceil(2);
                format!(
                    "[run]\nname = \"bench-efficiency-ddnls-square\"\n\
                     [model]\nname = \"ddnls\"\nlattice = \"square\"\nn = {side}\nW = 10.0\n\
                     beta = 1.0\nseed = 1\n\
                     [orbit]\nexcite = {{ sites = [{a}, {b}], norm = 9.0, seed = 4 }}\n{common}",
                    a = mid - 1,
                    b = mid + 1
                )
            }
        };
        Ok(RunConfig::from_toml(&text)?)
    }
}

/// What one run gives: CPU seconds of its steps, the maximal relative energy error over the
/// samples and over the first half of them, and the maximal relative norm error (DDNLS).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Run {
    pub cpu_seconds: f64,
    pub energy_error: f64,
    pub energy_error_first_half: f64,
    pub norm_error: Option<f64>,
}

/// One run of `config` through the engine on one thread: the CPU time of its samples (every
/// `next_sample` with the errors' bookkeeping; the engine's construction, which loads a
/// potential's compiled kernels once per run whatever its length, apart), and its errors (with
/// `ddnls`, the norm's too).
pub fn measure(config: &RunConfig, ddnls: Option<&Ddnls>) -> anyhow::Result<Run> {
    let spec = RunSpec::from_config(config)?;
    let (e0, half) = (spec.e0(), 0.5 * spec.t_final());
    let s0 = ddnls.map(|m| m.norm(spec.x0()));
    let pool = rayon::ThreadPoolBuilder::new().num_threads(1).build()?;
    pool.install(|| -> anyhow::Result<Run> {
        let mut run = Run {
            cpu_seconds: 0.0,
            energy_error: 0.0,
            energy_error_first_half: 0.0,
            norm_error: s0.map(|_| 0.0),
        };
        let mut engine = Engine::new(spec);
        // One clock reading at each end: a reading of a thread's CPU clock is a system call
        // (about a microsecond), as much as a short sample interval's steps. The bookkeeping
        // inside is O(N) per sample against the O(N stages / h) of its steps.
        let start = chaoscope_os::cpu_time::thread_seconds();
        while let Some(sample) = engine.next_sample()? {
            let e = ((sample.energy - e0) / e0).abs();
            run.energy_error = run.energy_error.max(e);
            if sample.t <= half {
                run.energy_error_first_half = run.energy_error_first_half.max(e);
            }
            if let (Some(m), Some(s0), Some(worst)) = (ddnls, s0, run.norm_error.as_mut()) {
                *worst = worst.max(((m.norm(&sample.state) - s0) / s0).abs());
            }
        }
        run.cpu_seconds = chaoscope_os::cpu_time::thread_seconds() - start;
        Ok(run)
    })
}

/// The integrator `method` of `family` over the family's step sizes, largest first, stopping
/// once the error is far below the smallest target (see [`BELOW_SMALLEST_TARGET`]).
fn curve(family: Family, sites: usize, t_final: f64, method: &str) -> anyhow::Result<Vec<Point>> {
    let mut points = Vec::new();
    for h in step_sizes(family.h_max()) {
        let config = family.config(sites, t_final, method, h)?;
        let ddnls = match &config.model {
            ModelConfig::Ddnls(m) => Some(chaoscope_dynamics::spec::ddnls_lattice(m)?),
            _ => None,
        };
        let point = match measure(&config, ddnls.as_ref()) {
            Ok(run) => Point {
                h,
                cpu_seconds: run.cpu_seconds,
                energy_error: run.energy_error,
                energy_growth: run.energy_error / run.energy_error_first_half,
                norm_error: run.norm_error,
                failed: None,
            },
            // A step past the method's stability: the state escaped or stopped being finite.
            Err(e) => Point {
                h,
                cpu_seconds: f64::NAN,
                energy_error: f64::NAN,
                energy_growth: f64::NAN,
                norm_error: None,
                failed: Some(format!("{e:#}")),
            },
        };
        let done = point.failed.is_none()
            && point.energy_error.max(point.norm_error.unwrap_or(0.0))
                < BELOW_SMALLEST_TARGET * TARGETS[TARGETS.len() - 1];
        points.push(point);
        if done {
            break;
        }
    }
    Ok(points)
}

/// The paper's ranking of `family` as its abstract states it (arXiv:1812.01870): the most
/// efficient schemes at moderate and at high accuracy. The paper treats the FPUT chain and the
/// 1-D and 2-D DDNLS; not the DKG chain.
pub fn paper_best(family: Family) -> serde_json::Value {
    let source = "Danieli, Many Manda, Mithun, Skokos, Math. in Eng. 1, 447 (2019), \
                  arXiv:1812.01870, abstract";
    match family {
        Family::FputBeta => serde_json::json!({
            "moderate_accuracy": ["aba864"],
            "high_accuracy": ["srkn14a"],
            "source": source,
        }),
        Family::Ddnls1d | Family::Ddnls2d => serde_json::json!({
            "moderate_accuracy": ["s9abc6", "s11abc6"],
            "high_accuracy": ["s17abc8", "s19abc8"],
            "source": source,
        }),
        Family::Dkg | Family::Dkg2d => serde_json::json!({
            "moderate_accuracy": null,
            "high_accuracy": null,
            "source": "not treated by the paper (its lattices are the FPUT chain and the DDNLS)",
        }),
    }
}

fn point_json(p: &Point) -> serde_json::Value {
    let finite = |x: f64| x.is_finite().then_some(x);
    serde_json::json!({
        "h": p.h,
        "cpu_seconds": finite(p.cpu_seconds),
        "max_relative_energy_error": finite(p.energy_error),
        "energy_error_over_first_half": finite(p.energy_growth),
        "max_relative_norm_error": p.norm_error.and_then(finite),
        "failed": p.failed,
    })
}

/// The rankings at every target of `curves` (method, points).
fn rankings(curves: &[(String, Vec<(f64, f64)>)]) -> Vec<serde_json::Value> {
    TARGETS
        .iter()
        .map(|&target| {
            let (ranked, not_reached) = ranking(curves, target);
            serde_json::json!({
                "target_relative_error": target,
                "ranking": ranked.iter().map(|(m, r)| match r {
                    Reach::Interpolated(s) => serde_json::json!({ "method": m, "cpu_seconds": s }),
                    Reach::AtMost(s) => serde_json::json!({ "method": m, "cpu_seconds_at_most": s }),
                    Reach::NotReached => serde_json::Value::Null,
                }).collect::<Vec<_>>(),
                "not_reached": not_reached,
            })
        })
        .collect()
}

/// The table of `family` at `sites` sites to `t_final`.
fn family_table(family: Family, sites: usize, t_final: f64) -> anyhow::Result<serde_json::Value> {
    let kernel_cache = if family == Family::Dkg {
        super::dkg::warm_kernel_cache(&family.config(sites, TAU, "aba864", 0.5)?)?
    } else {
        serde_json::Value::Null
    };
    let mut integrators = Vec::new();
    let mut energy_curves = Vec::new();
    let mut norm_curves = Vec::new();
    for (method, order, stages) in family.methods() {
        let points = curve(family, sites, t_final, method)?;
        energy_curves.push((
            method.to_string(),
            points
                .iter()
                .map(|p| (p.cpu_seconds, p.energy_error))
                .collect(),
        ));
        if family.is_ddnls() {
            norm_curves.push((
                method.to_string(),
                points
                    .iter()
                    .map(|p| (p.cpu_seconds, p.norm_error.unwrap_or(f64::NAN)))
                    .collect(),
            ));
        }
        integrators.push(serde_json::json!({
            "method": method,
            "order": order,
            "stages_per_step": stages,
            "points": points.iter().map(point_json).collect::<Vec<_>>(),
        }));
    }
    let dkg_2d = format!(
        "2-D disordered Klein-Gordon lattice of examples/models/dkg-square.toml (W = 10, a 3 x 3 \
         central block sharing E = 3.6), an expression whose sums are {}",
        if sites.isqrt() >= SQUARE_LOOPS_FROM_SIDE {
            "loops along its rows"
        } else {
            "unrolled (a square of this size steps faster so)"
        }
    );
    let mut out = serde_json::json!({
        "model": match family {
            Family::FputBeta => "beta-FPUT chain, fixed ends, beta = 1, momenta +-sqrt(0.2) (signs from seed 1), energy 0.1 per site",
            Family::Dkg => "disordered Klein-Gordon chain of examples/models/dkg-single-site.toml (W = 4, single site at E = 0.4), an expression on its C kernels",
            Family::Dkg2d => &dkg_2d,
            Family::Ddnls1d => "1-D DDNLS of examples/models/ddnls-block.toml (W = 4, beta = 0.72, 21 central sites of norm 1, random phases)",
            Family::Ddnls2d => "2-D DDNLS of examples/models/ddnls-square.toml (W = 10, beta = 1, a 3 x 3 central block of norm 1 per site)",
        },
        "sites": match family {
            Family::Dkg2d | Family::Ddnls2d => sites.isqrt().max(3).pow(2),
            _ => sites,
        },
        "integrators": integrators,
        "energy": rankings(&energy_curves),
        "paper_best": paper_best(family),
    });
    if family.is_ddnls() {
        out["norm"] = rankings(&norm_curves).into();
    }
    if family == Family::Dkg {
        out["kernel_cache"] = kernel_cache;
    }
    Ok(out)
}

/// The machine's one-minute load average (Linux), what says how shared the CPU was while the
/// table was measured; `None` where it cannot be read.
fn load_average() -> Option<f64> {
    std::fs::read_to_string("/proc/loadavg")
        .ok()?
        .split_whitespace()
        .next()?
        .parse()
        .ok()
}

/// The whole table at `sites` sites to `t_final`.
pub fn table(sites: usize, t_final: f64) -> anyhow::Result<serde_json::Value> {
    anyhow::ensure!(
        (25..=100_000).contains(&sites),
        "--efficiency-sites: between 25 and 100000 sites, got {sites}"
    );
    anyhow::ensure!(
        t_final.is_finite() && (TAU..=1e7).contains(&t_final) && (t_final / TAU).fract() == 0.0,
        "--efficiency-t: a multiple of {TAU} time units (the renormalization period) between \
         {TAU} and 1e7, got {t_final}"
    );
    let load_before = load_average();
    let started = chaoscope_os::cpu_time::process_seconds();
    let wall = std::time::Instant::now();
    let mut families = serde_json::Map::new();
    for family in Family::ALL {
        families.insert(family.name().into(), family_table(family, sites, t_final)?);
    }
    Ok(serde_json::json!({
        "cpu": chaoscope_dynamics::estimate::Machine::cpu_model(),
        "isa": chaoscope_dynamics::batch::Isa::detect().name(),
        "settings": "one VM tangent vector (k = 1, tau = 10), the engine of chaoscope run in \
                     process on one thread; CPU time of that thread for the run's steps (every \
                     sample; the engine's construction apart); max relative energy error |E(t) - E(0)|/|E(0)| over the \
                     samples (t = 0, 10, 20, ..., t_final), for the DDNLS also the norm's; step sizes \
                     h_max / 2^k, k = 0..5, stopping once the error is below 1e-12; at each \
                     target the CPU time interpolated log-log between the two step sizes around \
                     it (cpu_seconds_at_most: the largest step size is below it already)",
        "sites": sites,
        "t_final": t_final,
        "targets": TARGETS,
        "families": families,
        "total_cpu_seconds": chaoscope_os::cpu_time::process_seconds() - started,
        "total_wall_seconds": wall.elapsed().as_secs_f64(),
        "load_average_1min": { "before": load_before, "after": load_average() },
    }))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// On a straight line in log-log (CPU = 1e-3 / error^(1/4), a fourth-order method's curve),
    /// the interpolation between any two bracketing points is exact to rounding.
    #[test]
    fn cpu_at_is_exact_on_a_power_law() {
        let cpu = |e: f64| 1e-3 * e.powf(-0.25);
        let points: Vec<(f64, f64)> = [1e-3, 1e-6, 1e-9, 1e-12]
            .iter()
            .map(|&e| (cpu(e), e))
            .collect();
        for target in [5e-4, 1e-5, 3e-8, 1e-10, 1e-12] {
            match cpu_at(&points, target) {
                Reach::Interpolated(s) => {
                    assert!((s / cpu(target) - 1.0).abs() < 1e-12, "{target}: {s}")
                }
                other => panic!("{target}: {other:?}"),
            }
        }
        // Above every error: the cheapest point bounds it; below every error: not reached.
        assert_eq!(cpu_at(&points, 1e-2), Reach::AtMost(cpu(1e-3)));
        assert_eq!(cpu_at(&points, 1e-13), Reach::NotReached);
    }

    /// The bracket is the cheapest point at or below the target and the point just cheaper:
    /// a non-monotone tail (the rounding floor, where a smaller step only costs more) and a
    /// failed step size change nothing, and the order of the points does not matter.
    #[test]
    fn cpu_at_takes_the_cheapest_bracket() {
        let points = [
            (8.0, 2e-14), // the floor: more CPU, no better
            (1.0, 1e-4),
            (f64::NAN, f64::NAN), // a failed step size
            (4.0, 1e-14),
            (2.0, 1e-6),
        ];
        // Between (1, 1e-4) and (2, 1e-6): log-midpoint at 1e-5 gives sqrt(2).
        match cpu_at(&points, 1e-5) {
            Reach::Interpolated(s) => assert!((s - 2f64.sqrt()).abs() < 1e-12, "{s}"),
            other => panic!("{other:?}"),
        }
        // Exactly on a point: that point's CPU time.
        assert_eq!(cpu_at(&points, 1e-6), Reach::Interpolated(2.0));
        assert_eq!(cpu_at(&points, 1e-15), Reach::NotReached);
    }

    /// The ranking orders by CPU time at the target, counts an at-most bound as its value, and
    /// keeps the integrators that never reach the target apart.
    #[test]
    fn ranking_orders_fastest_first() {
        let curves = vec![
            ("slow".to_string(), vec![(1.0, 1e-3), (10.0, 1e-7)]),
            ("fast".to_string(), vec![(0.5, 1e-4), (1.0, 1e-8)]),
            ("never".to_string(), vec![(0.1, 1e-2), (0.2, 1e-3)]),
            ("always".to_string(), vec![(3.0, 1e-9)]),
        ];
        let (ranked, not_reached) = ranking(&curves, 1e-5);
        let names: Vec<&str> = ranked.iter().map(|(m, _)| m.as_str()).collect();
        assert_eq!(names, ["fast", "always", "slow"]);
        assert_eq!(ranked[1].1, Reach::AtMost(3.0));
        assert_eq!(not_reached, ["never"]);
    }

    /// Hostile flags give one line naming the flag, before any run: too few sites for the
    /// DDNLS block, a final time that is not a multiple of the renormalization period, and
    /// the values that are no time at all.
    #[test]
    fn hostile_flags_are_refused_naming_them() {
        let message = |sites: usize, t: f64| format!("{:#}", table(sites, t).unwrap_err());
        assert!(message(10, 500.0).starts_with("--efficiency-sites:"));
        assert!(message(1_000_000, 500.0).starts_with("--efficiency-sites:"));
        for t in [55.0, 0.0, -10.0, f64::NAN, f64::INFINITY, 1e8] {
            let m = message(128, t);
            assert!(m.starts_with("--efficiency-t:"), "{t}: {m}");
            assert!(!m.contains('\n'), "{m}");
        }
    }

    /// Every step size is a power of two below 1, so each divides `tau = 10` and the final time
    /// exactly (the run's validation asks for whole steps).
    #[test]
    fn step_sizes_divide_the_unit() {
        for family in Family::ALL {
            for h in step_sizes(family.h_max()) {
                assert_eq!((1.0 / h).fract(), 0.0, "{h}");
            }
        }
    }

    /// The least-squares slope of `ys` against `xs`.
    fn slope(xs: &[f64], ys: &[f64]) -> f64 {
        let n = xs.len() as f64;
        let (mx, my) = (xs.iter().sum::<f64>() / n, ys.iter().sum::<f64>() / n);
        let sxy: f64 = xs.iter().zip(ys).map(|(x, y)| (x - mx) * (y - my)).sum();
        let sxx: f64 = xs.iter().map(|x| (x - mx) * (x - mx)).sum();
        sxy / sxx
    }

    /// The table's errors are right: through the very runs the table makes (`Family::config`,
    /// `measure`), on small lattices, every integrator's maximal relative energy error falls
    /// as `h^order` over two halvings of `h` in its asymptotic range (above the rounding
    /// floor of ~1e-13, below the errors of order 1e-2 where the step is no longer small).
    /// The orders offered are 2, 4, 6 and 8, two apart, so a tolerance of 0.9 on the fitted
    /// slope tells each from its neighbours: a wrong coefficient, a method run in place of
    /// another or an error read from the wrong state would fail it. The maximum over the
    /// samples of an oscillating error is a rough statistic (its phase at the samples moves
    /// with `h`), which the least-squares fit over the three step sizes smooths.
    #[test]
    fn every_integrator_shows_its_order_in_the_table_runs() {
        let mut failures = Vec::new();
        for family in Family::ALL {
            let (sites, t_final) = (32, 100.0);
            for (method, order, _) in family.methods() {
                // The asymptotic range: the higher the order the larger the step, so that the
                // smallest error stays above the rounding floor. The DDNLS: h_max / 16 for
                // order 2 to h_max / 2 for order 8; the two-part splittings: a quarter of the
                // family's largest step for orders 2 and 4, half of it for 6, all of it for 8.
                let halvings = if family.is_ddnls() {
                    5 - order / 2
                } else {
                    (4 - order / 2).min(2)
                };
                let h0 = family.h_max() / f64::from(1u32 << halvings);
                let hs = [h0, h0 / 2.0, h0 / 4.0];
                let mut errors = Vec::new();
                for &h in &hs {
                    let config = family.config(sites, t_final, method, h).expect("config");
                    let ddnls = match &config.model {
                        ModelConfig::Ddnls(m) => {
                            Some(chaoscope_dynamics::spec::ddnls_lattice(m).unwrap())
                        }
                        _ => None,
                    };
                    let run = measure(&config, ddnls.as_ref()).expect("run");
                    errors.push(run.energy_error);
                }
                let errors_text: Vec<String> = errors.iter().map(|e| format!("{e:.1e}")).collect();
                let (xs, ys): (Vec<f64>, Vec<f64>) = hs
                    .iter()
                    .zip(&errors)
                    .filter(|(_, e)| **e > 1e-13)
                    .map(|(h, e)| (h.ln(), e.ln()))
                    .unzip();
                let p = slope(&xs, &ys);
                eprintln!(
                    "{} {method}: order {order}, slope {p:.2}, errors {errors_text:?}",
                    family.name()
                );
                if xs.len() < 3 || (p - f64::from(order)).abs() > 0.9 {
                    failures.push(format!(
                        "{} {method}: slope {p:.2} of {order}",
                        family.name()
                    ));
                }
            }
        }
        assert!(failures.is_empty(), "{failures:?}");
    }
}
