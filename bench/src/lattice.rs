//! `chaoscope bench --lattice-only`: the beta-FPUT chain written as a lattice sum (`[model] name
//! = "potential"`, the sum a loop over its term) against the built-in `fput-beta` chain, same
//! run, at N = 10^3, 10^4, 10^5, and the C step kernels' build time at
//! N = 10^2 and 10^5.
//!
//! Each run is a process of its own (this executable, `bench --lattice-case`, one rayon
//! thread): its CPU time (user + system) and peak resident memory are the kernel's figures for
//! the whole process, configuration to last sample, on one thread; the process reports its
//! time from the configuration text to an engine ready to step (parse, validate, compile), in
//! wall time and in its own CPU time (on a loaded machine the wall time counts other
//! processes' turns), and to the first sample. The two models run one after the other at each
//! size (built-in first), the pair repeated `--lattice-pairs` times, first with an empty kernel
//! cache (`cold_cache`), then with the chain's C kernels built into it (the top-level figures);
//! the JSON gives every run, where its C kernels stood (`c_kernels`) and the median ratios.
//!
//! The run: fixed ends, beta = 1, the lowest normal mode at amplitude 0.5 (a regular orbit),
//! ABA864 with h = 0.02 to t = 2 * 10^5 / N (the same site-steps at every size), one VM and one
//! MPM scheme with k = 2 (tau = 1, d0 = 1e-8). The process also reports its final state's
//! digest and its schemes' MLEs, so the JSON says whether the two models gave the same bits.

use std::io::Read;
use std::process::{Command, Stdio};
use std::time::Instant;

use anyhow::Context;
use chaoscope_dynamics::engine::Engine;
use chaoscope_dynamics::indicators::StretchSums;
use chaoscope_dynamics::model::ExpressionModel;
use chaoscope_dynamics::spec::RunSpec;
use chaoscope_schemas::config::RunConfig;

const FPUT: &str = "sum(i = 0..N, (q[i+1] - q[i])^2/2 + beta/4*(q[i+1] - q[i])^4)";

/// The run's configuration: `model` is `builtin` or `expression`.
pub(super) fn config_text(model: &str, n: usize, t_final: f64) -> anyhow::Result<String> {
    let model = match model {
        "builtin" => format!("name = \"fput-beta\"\nn = {n}\nbeta = 1.0"),
        "expression" => format!(
            "name = \"potential\"\nn = {n}\nboundary = \"fixed\"\nparams = {{ beta = 1.0 }}\npotential = \"{FPUT}\""
        ),
        other => anyhow::bail!("unknown lattice bench model {other:?}"),
    };
    let q: Vec<String> = (1..=n)
        .map(|j| {
            let x = 0.5 * (std::f64::consts::PI * j as f64 / (n + 1) as f64).sin();
            format!("{x:e}")
        })
        .collect();
    Ok(format!(
        "[run]\nname = \"bench-lattice\"\n[model]\n{model}\n[orbit]\nq = [{}]\np = [{}]\n\
         [integrator]\nmethod = \"aba864\"\nh = 0.02\nt_final = {t_final}\n\
         [deviations]\nk = 2\nsets = 1\nseed = 1\n\
         [[scheme]]\nname = \"vm\"\nmethod = \"vm\"\nd0 = 1e-8\ntau = 1.0\n\
         [[scheme]]\nname = \"mpm\"\nmethod = \"mpm\"\nd0 = 1e-8\ntau = 1.0\n",
        q.join(", "),
        vec!["0.0"; n].join(", ")
    ))
}

/// CPU seconds (user + system) this process has used so far: on a shared machine the wall
/// time from the configuration to the first step counts other processes' turns too.
/// The child process: `MODEL:N:T_FINAL`; prints one JSON object.
pub fn case(arg: &str) -> anyhow::Result<()> {
    let parts: Vec<&str> = arg.split(':').collect();
    anyhow::ensure!(parts.len() == 3, "--lattice-case MODEL:N:T_FINAL");
    let n: usize = parts[1].parse().context("N")?;
    let t_final: f64 = parts[2].parse().context("T_FINAL")?;
    let text = config_text(parts[0], n, t_final)?;
    let cpu_started = chaoscope_os::cpu_time::process_seconds();
    let started = Instant::now();
    let config = RunConfig::from_toml(&text)?;
    let spec = RunSpec::from_config(&config)?;
    let expression = spec.system().separable().and_then(|h| {
        let any: &dyn std::any::Any = h.model().as_ref();
        any.downcast_ref::<ExpressionModel>().cloned()
    });
    let loops = expression.as_ref().map(ExpressionModel::has_loops);
    let steps = spec.total_steps();
    let mut engine = Engine::new(spec);
    let ready = started.elapsed().as_secs_f64();
    let ready_cpu = chaoscope_os::cpu_time::process_seconds() - cpu_started;
    let report = (|| -> anyhow::Result<serde_json::Value> {
        let mut first = None;
        let mut sums: Vec<StretchSums> = Vec::new();
        let mut last = None;
        while let Some(s) = engine.next_sample()? {
            if first.is_none() {
                first = Some(started.elapsed().as_secs_f64());
            }
            if sums.is_empty() {
                sums = s
                    .schemes
                    .iter()
                    .map(|d| StretchSums::new(d.stretch.len()))
                    .collect();
            }
            if s.seq > 0 {
                for (m, d) in sums.iter_mut().zip(&s.schemes) {
                    m.add(&d.stretch);
                }
            }
            last = Some((s.t, s.state));
        }
        let (t, state) = last.context("the run gave no sample")?;
        // FNV-1a over the final state's bits: equal digests, equal states.
        let digest = state.iter().fold(0xcbf2_9ce4_8422_2325u64, |h, x| {
            x.to_bits()
                .to_le_bytes()
                .iter()
                .fold(h, |h, &b| (h ^ u64::from(b)).wrapping_mul(0x0100_0000_01b3))
        });
        Ok(serde_json::json!({
            "config_to_engine_seconds": ready,
            "config_to_engine_cpu_seconds": ready_cpu,
            "config_to_first_sample_seconds": first,
            "steps": steps,
            "lattice_loops": loops,
            "final_state_digest": format!("{digest:016x}"),
            "mle": sums.iter().map(|m| m.mle(t)).collect::<Vec<_>>(),
            // Where the expression's C kernels stood at the end: `not-started` (a run too
            // short to build them, none in the cache), `loaded-from-cache`, `compiled`, ...
            "c_kernels": expression.as_ref().map(|m| m.c_step_status().state.name()),
            // Kernel calls by back end: batched calls and the fused one-orbit pass's.
            "kernel_calls": expression.as_ref().map(|m| {
                let status = m.c_step_status();
                serde_json::json!({"c": status.c_calls, "cranelift": status.cranelift_calls})
            }),
        }))
    })()?;
    chaoscope_os::outln!("{}", serde_json::to_string(&report)?)?;
    Ok(())
}

/// One child run: its report, CPU seconds and peak resident memory (MB).
fn run_child(
    model: &str,
    n: usize,
    t_final: f64,
    cache: &std::path::Path,
) -> anyhow::Result<serde_json::Value> {
    let exe = std::env::current_exe().context("this executable")?;
    let mut child = Command::new(exe)
        .args(["bench", "--lattice-case", &format!("{model}:{n}:{t_final}")])
        // One thread: the figures are per core.
        .env("RAYON_NUM_THREADS", "1")
        .env("CHAOSCOPE_KERNEL_CACHE", cache)
        .stdout(Stdio::piped())
        .stderr(Stdio::inherit())
        .spawn()
        .context("starting a lattice bench run")?;
    let mut out = String::new();
    child
        .stdout
        .take()
        .context("the child's output")?
        .read_to_string(&mut out)?;
    let mut status = 0;
    // SAFETY: a zeroed rusage is a valid value for wait4 to fill.
    let mut usage: libc::rusage = unsafe { std::mem::zeroed() };
    // SAFETY: wait4 on the pid of our own child, which nothing else reaps (the `Child` is
    // never waited for).
    let pid = unsafe { libc::wait4(child.id() as i32, &mut status, 0, &mut usage) };
    anyhow::ensure!(pid > 0, "waiting for the lattice bench run");
    anyhow::ensure!(
        libc::WIFEXITED(status) && libc::WEXITSTATUS(status) == 0,
        "the lattice bench run {model} N = {n} failed ({status})"
    );
    let seconds = |t: libc::timeval| t.tv_sec as f64 + t.tv_usec as f64 * 1e-6;
    let mut report: serde_json::Value =
        serde_json::from_str(out.trim()).context("the lattice bench run's report")?;
    if let Some(o) = report.as_object_mut() {
        o.insert(
            "cpu_seconds".into(),
            (seconds(usage.ru_utime) + seconds(usage.ru_stime)).into(),
        );
        // Linux reports kilobytes.
        o.insert(
            "peak_memory_mb".into(),
            (usage.ru_maxrss as f64 / 1024.0).into(),
        );
    }
    Ok(report)
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

/// The expression chain against the built-in one at each of `sizes`, `pairs` times, in two
/// states of the kernel cache: cold (the chain's C kernels never built on this machine: a run
/// this short builds none, so the expression steps through its Cranelift code) and warm (built
/// once before, as any long run of the chain at that size or `bench`'s own build leaves them:
/// the run loads them, running no compiler, and its small sets take the fused pass). The
/// top-level ratios are the warm runs', the steady state of a user's runs; `cold_cache` holds
/// the first run's.
pub fn compare(sizes: &[usize], pairs: usize) -> anyhow::Result<serde_json::Value> {
    let mut out = Vec::new();
    let scratch =
        std::env::temp_dir().join(format!("chaoscope-bench-lattice-{}", std::process::id()));
    for &n in sizes {
        let t_final = 2e5 / n as f64;
        let cold = scratch.join(format!("cold-{n}"));
        let warm = scratch.join(format!("warm-{n}"));
        let mut cold_runs = Vec::new();
        for _ in 0..pairs.max(1) {
            let b = run_child("builtin", n, t_final, &cold)?;
            let e = run_child("expression", n, t_final, &cold)?;
            cold_runs.push((b, e));
        }
        let build = super::dkg::warm_kernel_cache_in(
            &RunConfig::from_toml(&config_text("expression", n, 1.0)?)?,
            Some(&warm),
        )?;
        let mut runs = Vec::new();
        for _ in 0..pairs.max(1) {
            let b = run_child("builtin", n, t_final, &warm)?;
            let e = run_child("expression", n, t_final, &warm)?;
            runs.push((b, e));
        }
        let _ = std::fs::remove_dir_all(&scratch);
        let field = |v: &serde_json::Value, k: &str| v[k].as_f64().unwrap_or(f64::NAN);
        let ratio = |runs: &[(serde_json::Value, serde_json::Value)], k: &str| {
            median(
                runs.iter()
                    .map(|(b, e)| field(e, k) / field(b, k))
                    .collect(),
            )
        };
        let (b0, e0) = &runs[0];
        let mle_rel: Vec<f64> = b0["mle"]
            .as_array()
            .into_iter()
            .flatten()
            .zip(e0["mle"].as_array().into_iter().flatten())
            .map(|(x, y)| {
                let (x, y) = (
                    x.as_f64().unwrap_or(f64::NAN),
                    y.as_f64().unwrap_or(f64::NAN),
                );
                (x - y).abs() / x.abs().max(y.abs())
            })
            .collect();
        let pair_json = |runs: &[(serde_json::Value, serde_json::Value)]| {
            runs.iter()
                .map(|(b, e)| serde_json::json!({"builtin": b, "expression": e}))
                .collect::<Vec<_>>()
        };
        let cold_e0 = &cold_runs[0].1;
        out.push(serde_json::json!({
            "n": n,
            "t_final": t_final,
            "kernel_cache": "warm",
            "kernel_cache_build": build,
            "runs": pair_json(&runs),
            "cpu_expression_over_builtin": ratio(&runs, "cpu_seconds"),
            "cpu_target": 1.5,
            "memory_expression_over_builtin": ratio(&runs, "peak_memory_mb"),
            "memory_target": 2.0,
            "expression_config_to_engine_seconds": median(runs.iter().map(|(_, e)| field(e, "config_to_engine_seconds")).collect()),
            "expression_config_to_engine_cpu_seconds": median(runs.iter().map(|(_, e)| field(e, "config_to_engine_cpu_seconds")).collect()),
            "builtin_config_to_engine_cpu_seconds": median(runs.iter().map(|(b, _)| field(b, "config_to_engine_cpu_seconds")).collect()),
            "config_to_first_step_target_seconds": 1.0,
            "final_state_bit_identical": b0["final_state_digest"] == e0["final_state_digest"],
            "mle_relative_difference_vm_mpm": mle_rel,
            "cold_cache": {
                "runs": pair_json(&cold_runs),
                "cpu_expression_over_builtin": ratio(&cold_runs, "cpu_seconds"),
                "memory_expression_over_builtin": ratio(&cold_runs, "peak_memory_mb"),
                "final_state_bit_identical": cold_runs[0].0["final_state_digest"] == cold_e0["final_state_digest"],
            },
        }));
    }
    Ok(serde_json::Value::Array(out))
}

/// The C step kernels of the FPUT chain written as a lattice sum, built afresh (an empty
/// cache) at each of `sizes`: seconds each, and the time from the configuration to the
/// Cranelift kernels.
pub fn c_build(sizes: &[usize]) -> anyhow::Result<serde_json::Value> {
    let mut out = Vec::new();
    for &n in sizes {
        let text = config_text("expression", n, 1.0)?;
        let cpu_started = chaoscope_os::cpu_time::process_seconds();
        let started = Instant::now();
        let config = RunConfig::from_toml(&text)?;
        let (model, _) = chaoscope_dynamics::spec::model_from_config(&config.model)?;
        let any: &dyn std::any::Any = model.as_ref();
        let model = any
            .downcast_ref::<ExpressionModel>()
            .context("a potential compiles to an ExpressionModel")?;
        let cranelift = model
            .cranelift_step_kernels()
            .map_err(|e| anyhow::anyhow!("{e}"))?
            .compile_time()
            .as_secs_f64();
        let usable = started.elapsed().as_secs_f64();
        let usable_cpu = chaoscope_os::cpu_time::process_seconds() - cpu_started;
        let cache = std::env::temp_dir().join(format!(
            "chaoscope-bench-lattice-kernels-{}-{n}",
            std::process::id()
        ));
        let started = Instant::now();
        let built = model.build_c_step_kernels(&cache);
        let seconds = started.elapsed().as_secs_f64();
        let _ = std::fs::remove_dir_all(&cache);
        out.push(match built {
            Ok(_) => serde_json::json!({
                "n": n,
                "lattice_loops": model.has_loops(),
                "graph_nodes": model.graph_nodes(),
                "config_to_cranelift_kernels_seconds": usable,
                "config_to_cranelift_kernels_cpu_seconds": usable_cpu,
                "cranelift_step_kernels_seconds": cranelift,
                "c_build_seconds": seconds,
            }),
            Err(reason) => serde_json::json!({ "n": n, "c_unavailable": reason }),
        });
    }
    Ok(serde_json::Value::Array(out))
}
