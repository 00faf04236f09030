//! `chaoscope bench --dkg-only`: the disordered Klein-Gordon chain of
//! `examples/models/dkg-single-site.toml` (written as an expression, disorder drawn from a seed)
//! through the whole `chaoscope run` (producer, bus, recorder: each run a process tree of its
//! own, its CPU time that of every process in it) against a hand-written scalar C of the same
//! ABA864 step and tangent map (`chains.c`, model 0, built at bench time with `-O3 -march=native
//! -ffp-contract=off`, or the `CHAOSCOPE_CC_MARCH` the run's kernels are built for, e.g.
//! `x86-64-v3` for the AVX2 path of an AVX-512 machine: [`yardstick`]), at `--dkg-sizes`.
//!
//! Both integrate one reference orbit and one VM deviation vector, renormalized every `tau` = 10
//! of the example (the run records a sample every `sample_every` = 100, the stretching factors
//! between carried with it), over the same site-steps at every size (`2 * 10^8`, so the process
//! start and the compilation weigh what they weigh in a run of that length); and both run to
//! `t = 100` once more, whose MLEs are
//! compared (the C's vector is the run's own first direction). The C's arithmetic is the
//! chain's forces in the textbook order, not chaoscope's compiled loop, so the two MLEs agree to
//! rounding amplified by the orbit's (weak) chaos, not bit for bit.

use std::process::{Command, Stdio};

use anyhow::Context;
use chaoscope_dynamics::batch::StepCoeffs;
use chaoscope_dynamics::integrator::{Splitting, SplittingScheme};
use chaoscope_dynamics::model::ExpressionModel;
use chaoscope_dynamics::spec::RunSpec;
use chaoscope_schemas::config::{ModelConfig, ParamValue, RunConfig};

/// The yardsticks' C program (`chains.c`: model 0 the DKG chain, 1 the FPUT chain).
const SOURCE: &str = include_str!("chains.c");
const EXAMPLE: &str = include_str!("../../examples/models/dkg-single-site.toml");
const H: f64 = 0.05;
/// The run's recording interval, `[run] sample_every` (the weak-chaos study's setting).
const SAMPLE_EVERY: f64 = 100.0;
/// Site-steps of each throughput run.
const SITE_STEPS: f64 = 2e8;

/// The example at `n` sites (the excitation in the middle), to `t_final`, one VM vector, a sample
/// every `SAMPLE_EVERY`.
pub(super) fn config(n: usize, t_final: f64) -> anyhow::Result<RunConfig> {
    let mut text = EXAMPLE
        .replace("n = 1000\n", &format!("n = {n}\n"))
        .replace("sites = 500,", &format!("sites = {},", n / 2))
        .replace("t_final = 5000.0", &format!("t_final = {t_final:?}"))
        .replace("k = 2\n", "k = 1\n");
    text = text.replace("name = \"dkg-single-site\"", "name = \"bench-dkg\"");
    let mut config = RunConfig::from_toml(&text)?;
    config.run.sample_every = Some(SAMPLE_EVERY);
    anyhow::ensure!(
        config.integrator.h == Some(H) && config.integrator.t_final == t_final,
        "the DKG example changed shape: the bench cannot set its size and length"
    );
    Ok(config)
}

/// `chaoscope run` of `config` in `dir`: (CPU seconds of its process tree, MLE of its scheme).
pub(super) fn chaoscope_run(
    dir: &std::path::Path,
    config: &RunConfig,
    tag: &str,
) -> anyhow::Result<(f64, f64)> {
    let exe = std::env::current_exe()?;
    let cfg = dir.join(format!("{tag}.toml"));
    let out = dir.join(format!("{tag}.mcap"));
    std::fs::write(&cfg, config.to_toml())?;
    let before = chaoscope_os::cpu_time::children_seconds();
    let status = Command::new(&exe)
        .arg("run")
        .arg(&cfg)
        .arg("--out")
        .arg(&out)
        .env("RAYON_NUM_THREADS", "1")
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .status()
        .context("starting chaoscope run")?;
    let cpu = chaoscope_os::cpu_time::children_seconds() - before;
    anyhow::ensure!(
        status.success(),
        "chaoscope run of the DKG chain failed ({status})"
    );
    let report = Command::new(&exe)
        .arg("analyze")
        .arg(&out)
        .arg("--json")
        .output()
        .context("running chaoscope analyze")?;
    anyhow::ensure!(report.status.success(), "chaoscope analyze failed");
    let json: serde_json::Value = serde_json::from_slice(&report.stdout)?;
    let mle = json["schemes"][0]["mle"]
        .as_f64()
        .context("analyze --json gave no MLE")?;
    std::fs::remove_file(&out).ok();
    Ok((cpu, mle))
}

/// The C program's input for `config` (model 0 of `chains.c`).
fn c_input(config: &RunConfig) -> anyhow::Result<String> {
    let spec = RunSpec::from_config(config)?;
    let n = spec.dim() / 2;
    // W and the disorder as the example writes them, so the C runs the run's chain.
    let (w, eps) = match &config.model {
        ModelConfig::Potential(p) => match (p.params.get("W"), p.params.get("eps")) {
            (Some(ParamValue::Scalar(w)), Some(ParamValue::Drawn(d))) => (
                *w,
                chaoscope_dynamics::spec::drawn::uniform(d.uniform[0], d.uniform[1], d.seed, n),
            ),
            _ => anyhow::bail!("the DKG example no longer has a scalar W and a drawn eps"),
        },
        _ => anyhow::bail!("the DKG example is no longer a potential model"),
    };
    let mut values = vec![0.0, n as f64, w];
    values.extend(eps);
    Ok(c_input_of(values, &spec, H))
}

/// The C program's input: the model's values `model` (its id, `N`, its parameters), then the
/// ABA864 splitting at step `h`, the renormalization windows of `spec`'s first scheme, its
/// initial state and its first set's first direction (see `chains.c`).
pub(super) fn c_input_of(model: Vec<f64>, spec: &RunSpec, h: f64) -> String {
    let n = spec.dim() / 2;
    let coeffs = StepCoeffs::new(&Splitting::new(SplittingScheme::Aba864), h);
    let tau = spec.schemes()[0].tau_steps;
    let mut values = model;
    values.push(coeffs.kicks() as f64);
    values.extend(&coeffs.drift);
    values.extend(&coeffs.kick);
    values.push(tau as f64);
    values.push((spec.total_steps() / tau) as f64);
    values.push(h);
    values.push(1.0);
    values.extend(spec.x0());
    values.extend(&spec.directions()[0].vectors[..2 * n]);
    values.iter().map(|v| format!("{v:e}\n")).collect()
}

/// The C yardstick on `input`: (CPU seconds, MLE).
pub(super) fn c_run(exe: &std::path::Path, input: &str) -> anyhow::Result<(f64, f64)> {
    let text = super::scalar_c::output_of(exe, input)?;
    let value = |key: &str| -> anyhow::Result<f64> {
        text.lines()
            .find_map(|l| l.strip_prefix(key))
            .with_context(|| format!("the C yardstick printed no {key}"))?
            .trim()
            .parse::<f64>()
            .map_err(Into::into)
    };
    Ok((value("cpu_seconds ")?, value("mle ")?))
}

/// The yardsticks' program, built: its private scratch directory (mode 0700, random name,
/// prefix `prefix`: the program built there is run), its path, and the `-march` it was built
/// for.
pub(super) struct Yardstick {
    pub scratch: tempfile::TempDir,
    pub exe: std::path::PathBuf,
    pub march: String,
}

/// The yardsticks' program `chains.c` built (`-O3 -march=... -ffp-contract=off`) by the C
/// compiler and for the instruction set the run's C kernels are built with (`CHAOSCOPE_CC`,
/// else `cc`; `CHAOSCOPE_CC_MARCH`, else `native`: both sides of a comparison on one
/// instruction set, checked against this CPU as the kernels' is); why not, where there is no C
/// compiler, it fails, or the instruction set is refused (the bench then says so instead of
/// failing).
pub(super) fn yardstick(prefix: &str) -> anyhow::Result<Result<Yardstick, String>> {
    let scratch = tempfile::Builder::new().prefix(prefix).tempdir()?;
    let (program, march) = match chaoscope_expr::jit::CCompiler::from_env() {
        Some(cc) if cc.march == "native" => (cc.program, "-march=native".to_owned()),
        Some(cc) => match cc.checked_march_flag(scratch.path()) {
            Ok(flag) => (cc.program, flag),
            Err(e) => return Ok(Err(e.to_string())),
        },
        None => ("cc".into(), "-march=native".to_owned()),
    };
    let src = scratch.path().join("chains.c");
    std::fs::write(&src, SOURCE)?;
    let exe = scratch.path().join("chains");
    let built = Command::new(&program)
        .args(["-O3", &march, "-ffp-contract=off", "-o"])
        .arg(&exe)
        .arg(&src)
        .arg("-lm")
        .output();
    Ok(match built {
        Ok(o) if o.status.success() => Ok(Yardstick {
            scratch,
            exe,
            march,
        }),
        Ok(o) => Err(format!(
            "{} failed: {}",
            program.display(),
            String::from_utf8_lossy(&o.stderr)
                .lines()
                .next()
                .unwrap_or("")
        )),
        Err(e) => Err(format!("no C compiler ({}): {e}", program.display())),
    })
}

/// The comparison at `sizes`, and with `ensemble` = (realizations, sites) the ensemble's
/// throughput.
pub fn compare(
    sizes: &[usize],
    pairs: usize,
    ensemble: Option<(usize, usize)>,
) -> anyhow::Result<serde_json::Value> {
    anyhow::ensure!(
        (1..=100).contains(&pairs),
        "--dkg-pairs: 1 to 100 pairs, got {pairs}"
    );
    let Yardstick {
        scratch,
        exe,
        march,
    } = match yardstick("chaoscope-bench-dkg-")? {
        Ok(built) => built,
        Err(why) => return Ok(serde_json::json!({ "unavailable": why })),
    };
    let dir = scratch.path();
    let mut rows = Vec::new();
    for &n in sizes {
        anyhow::ensure!(n >= 4, "--dkg-sizes: a chain of at least 4 sites, got {n}");
        let t_final = t_final_of(SITE_STEPS, n, SAMPLE_EVERY, H);
        // The chain's C kernels built into the kernel cache (or found there) first, as a
        // user's first long run of a chain does once for every later realization and length:
        // the timed run starts from the cache, as the C yardstick from its built program.
        let short = config(n, 100.0)?;
        let build = warm_kernel_cache(&short)?;
        let (_, run_mle) = chaoscope_run(dir, &short, &format!("short-{n}"))?;
        let (_, c_mle) = c_run(&exe, &c_input(&short)?)?;
        let long = config(n, t_final)?;
        let input = c_input(&long)?;
        // Interleaved, so a drift of the machine's speed falls on both sides of a pair alike.
        let mut timed = Vec::with_capacity(pairs);
        for _ in 0..pairs {
            let (run_cpu, _) = chaoscope_run(dir, &long, &format!("long-{n}"))?;
            let (c_cpu, _) = c_run(&exe, &input)?;
            timed.push((run_cpu, c_cpu));
        }
        let mut ratios: Vec<f64> = timed.iter().map(|(run, c)| c / run).collect();
        ratios.sort_by(f64::total_cmp);
        let ratio = ratios[ratios.len() / 2];
        let least =
            |side: fn(&(f64, f64)) -> f64| timed.iter().map(side).fold(f64::INFINITY, f64::min);
        let (run_cpu, c_cpu) = (least(|t| t.0), least(|t| t.1));
        let site_steps = n as f64 * t_final / H;
        rows.push(serde_json::json!({
            "sites": n,
            "t_final": t_final,
            "site_steps": site_steps,
            "pairs": timed.iter().map(|(run, c)| serde_json::json!({
                "run_cpu_seconds": run, "c_cpu_seconds": c, "run_over_c": c / run,
            })).collect::<Vec<_>>(),
            "run_over_c_of_least_cpu": c_cpu / run_cpu,
            "run_cpu_seconds": run_cpu,
            "kernel_cache": build,
            "c_cpu_seconds": c_cpu,
            "run_site_steps_per_cpu_second": site_steps / run_cpu,
            "c_site_steps_per_cpu_second": site_steps / c_cpu,
            "run_over_c": ratio,
            "target_run_over_c": 1.0,
            "meets_target": ratio >= 1.0,
            "mle_t100": { "run": run_mle, "c": c_mle,
                          "relative_difference": ((run_mle - c_mle) / c_mle).abs(),
                          "target_relative_difference": 1e-10 },
        }));
    }
    let ensemble = match ensemble {
        Some((realizations, n)) => ensemble_throughput(dir, realizations, n)?,
        None => serde_json::Value::Null,
    };
    Ok(serde_json::json!({
        "settings": "DKG W = 4, eps uniform in [0.5, 1.5) (seed 1), fixed ends, single site \
                     excited at E = 0.4, ABA864 h = 0.05, one VM vector renormalized every \
                     tau = 10 and recorded every 100 time units; chaoscope run with one rayon \
                     thread, CPU time of its whole process tree (process start, configuration, \
                     compilation, producer, bus, recorder, summary), the chain's C kernels in \
                     the kernel cache (kernel_cache: built or loaded before, in how long); \
                     scalar C -O3 -march (as the kernels: march) -ffp-contract=off, CPU time \
                     of its loop; \
                     --dkg-pairs interleaved (run, C) pairs per length: run_over_c is the \
                     median of the pairs' ratios, *_cpu_seconds each side's least",
        "compiler": super::scalar_c::compiler(),
        "march": march,
        "sizes": rows,
        "ensemble": ensemble,
    }))
}

/// The end of a run of about `site_steps` site-steps of an `n`-site chain at step `h`: whole
/// sampling intervals `sample_every` (at least one), so every size runs the same work.
pub(super) fn t_final_of(site_steps: f64, n: usize, sample_every: f64, h: f64) -> f64 {
    (site_steps / (n as f64 * sample_every / h))
        .round()
        .max(1.0)
        * sample_every
}

/// `realizations` disorder realizations (seeds 1, 2, ...; the command line checked 1 to 1000 of
/// 4 sites or more) of the `n`-site chain over the same site-steps each, as many `chaoscope
/// run`s at a time as the machine has cores: the ensemble's site-steps per CPU second (the sum
/// over every process tree) and per wall second.
fn ensemble_throughput(
    dir: &std::path::Path,
    realizations: usize,
    n: usize,
) -> anyhow::Result<serde_json::Value> {
    let at_once = std::thread::available_parallelism().map_or(1, |c| c.get());
    let t_final = t_final_of(SITE_STEPS, n, SAMPLE_EVERY, H);
    let exe = std::env::current_exe()?;
    let mut configs = Vec::with_capacity(realizations);
    for r in 1..=realizations {
        let mut realization = config(n, t_final)?;
        match &mut realization.model {
            ModelConfig::Potential(p) => match p.params.get_mut("eps") {
                Some(ParamValue::Drawn(d)) => d.seed = r as u64,
                _ => anyhow::bail!("the DKG example no longer has a drawn eps"),
            },
            _ => anyhow::bail!("the DKG example is no longer a potential model"),
        }
        let path = dir.join(format!("ensemble-{r}.toml"));
        std::fs::write(&path, realization.to_toml())?;
        configs.push(path);
    }
    // The kernels of this chain in the cache before the clock starts (one realization's is
    // every realization's: array parameters are not in the kernel's source).
    let build = warm_kernel_cache(&config(n, 100.0)?)?;
    let before = chaoscope_os::cpu_time::children_seconds();
    let started = std::time::Instant::now();
    let mut running: Vec<std::process::Child> = Vec::new();
    for (r, cfg) in configs.iter().enumerate() {
        if running.len() == at_once {
            let first = running.remove(0);
            wait_ok(first)?;
        }
        running.push(
            Command::new(&exe)
                .arg("run")
                .arg(cfg)
                .arg("--run")
                .arg(format!("bench-dkg-ensemble-{}-{r}", std::process::id()))
                .arg("--out")
                .arg(dir.join(format!("ensemble-{r}.mcap")))
                .env("RAYON_NUM_THREADS", "1")
                .stdout(Stdio::null())
                .stderr(Stdio::null())
                .spawn()
                .context("starting chaoscope run")?,
        );
    }
    for child in running {
        wait_ok(child)?;
    }
    let wall = started.elapsed().as_secs_f64();
    let cpu = chaoscope_os::cpu_time::children_seconds() - before;
    for r in 0..realizations {
        std::fs::remove_file(dir.join(format!("ensemble-{r}.mcap"))).ok();
    }
    let site_steps = realizations as f64 * n as f64 * t_final / H;
    Ok(serde_json::json!({
        "sites": n,
        "realizations": realizations,
        "runs_at_once": at_once,
        "t_final": t_final,
        "site_steps": site_steps,
        "cpu_seconds": cpu,
        "wall_seconds": wall,
        "site_steps_per_cpu_second": site_steps / cpu,
        "site_steps_per_wall_second": site_steps / wall,
        "kernel_cache": build,
    }))
}

/// Builds the C kernels of `config`'s potential into the kernel cache of the environment (or
/// finds them there), waiting for them: what a run of that chain then loads. Says which, in how
/// long, or why there are none (the runs then step without the fused pass).
pub(super) fn warm_kernel_cache(config: &RunConfig) -> anyhow::Result<serde_json::Value> {
    warm_kernel_cache_in(config, None)
}

/// [`warm_kernel_cache`] into the cache directory `cache` instead of the environment's.
pub(super) fn warm_kernel_cache_in(
    config: &RunConfig,
    cache: Option<&std::path::Path>,
) -> anyhow::Result<serde_json::Value> {
    let spec = RunSpec::from_config(config)?;
    let Some(model) = spec.system().separable().map(|h| h.model().clone()) else {
        return Ok(serde_json::json!({ "unavailable": "not a potential" }));
    };
    let any: &dyn std::any::Any = model.as_ref();
    let Some(expression) = any.downcast_ref::<ExpressionModel>() else {
        return Ok(serde_json::json!({ "unavailable": "a built-in model: no C kernels" }));
    };
    let started = std::time::Instant::now();
    let built = match cache {
        None => expression
            .c_step_kernels()
            .map(|k| expression.c_step_kernels_cached(k))
            .map_err(String::from),
        Some(dir) => expression
            .build_c_step_kernels(dir)
            .map(|k| expression.c_step_kernels_cached(&k)),
    };
    Ok(match built {
        Ok(cached) => serde_json::json!({
            "loaded_from_cache": cached,
            "seconds": started.elapsed().as_secs_f64(),
        }),
        Err(why) => serde_json::json!({ "unavailable": why }),
    })
}

fn wait_ok(mut child: std::process::Child) -> anyhow::Result<()> {
    let status = child.wait()?;
    anyhow::ensure!(status.success(), "a DKG ensemble run failed ({status})");
    Ok(())
}
