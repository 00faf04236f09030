//! `chaoscope bench --lattice-only`, its second part: the beta-FPUT chain written as a lattice
//! sum and the built-in `fput-beta` chain, each through the whole `chaoscope run` (producer,
//! bus, recorder; the CPU time of its process tree), against a hand-written scalar C of the same
//! ABA864 step and tangent map (`chains.c`, built at bench time with `-O3 -march=native
//! -ffp-contract=off`), at the lattice sizes.
//!
//! The run of `lattice.rs` (fixed ends, beta = 1, the lowest normal mode at amplitude 0.5, a
//! regular orbit, h = 0.02) with one VM vector renormalized every `tau` = 1 and recorded every
//! 10 time units, over the same `2 * 10^8` site-steps at every size, the expression's C kernels
//! built into the kernel cache (or found there) first; the MLEs of the timed runs are compared
//! with the C's (the C sums the forces in the textbook order, chaoscope in the lattice sum's:
//! equal to rounding on this regular orbit).

use chaoscope_dynamics::spec::RunSpec;
use chaoscope_schemas::config::{DeviationsConfig, RunConfig, SchemeConfig};

use super::dkg::{
    Yardstick, c_input_of, c_run, chaoscope_run, t_final_of, warm_kernel_cache, yardstick,
};
const H: f64 = 0.02;
const TAU: f64 = 1.0;
const SAMPLE_EVERY: f64 = 10.0;
const SITE_STEPS: f64 = 2e8;

/// `model` (`builtin` or `expression`) at `n` sites to `t_final`: one VM vector.
fn config(model: &str, n: usize, t_final: f64) -> anyhow::Result<RunConfig> {
    let mut config = RunConfig::from_toml(&super::lattice::config_text(model, n, t_final)?)?;
    config.run.name = Some(format!("bench-fput-{model}"));
    config.run.sample_every = Some(SAMPLE_EVERY);
    config.deviations = DeviationsConfig::random(1, 1, 1);
    config.schemes = vec![SchemeConfig::new("vm", "vm", 1.0, TAU)];
    anyhow::ensure!(
        config.integrator.h == Some(H),
        "the lattice bench's run changed its step"
    );
    Ok(config)
}

/// The C program's input for `config` (model 1 of `chains.c`, beta = 1).
fn c_input(config: &RunConfig) -> anyhow::Result<String> {
    let spec = RunSpec::from_config(config)?;
    let n = spec.dim() / 2;
    Ok(c_input_of(vec![1.0, n as f64, 1.0], &spec, H))
}

pub fn compare(sizes: &[usize]) -> anyhow::Result<serde_json::Value> {
    let Yardstick { scratch, exe, .. } = match yardstick("chaoscope-bench-fput-")? {
        Ok(built) => built,
        Err(why) => return Ok(serde_json::json!({ "unavailable": why })),
    };
    let dir = scratch.path();
    let mut rows = Vec::new();
    for &n in sizes {
        anyhow::ensure!(
            n >= 4,
            "--lattice-sizes: a chain of at least 4 sites, got {n}"
        );
        let t_final = t_final_of(SITE_STEPS, n, SAMPLE_EVERY, H);
        let site_steps = n as f64 * t_final / H;
        let mut row =
            serde_json::json!({ "sites": n, "t_final": t_final, "site_steps": site_steps });
        let (c_cpu, c_mle) = c_run(&exe, &c_input(&config("expression", n, t_final)?)?)?;
        row["c"] = serde_json::json!({
            "cpu_seconds": c_cpu,
            "site_steps_per_cpu_second": site_steps / c_cpu,
            "mle": c_mle,
        });
        row["kernel_cache"] = warm_kernel_cache(&config("expression", n, SAMPLE_EVERY)?)?;
        for model in ["builtin", "expression"] {
            let (cpu, mle) =
                chaoscope_run(dir, &config(model, n, t_final)?, &format!("{model}-{n}"))?;
            row[model] = serde_json::json!({
                "cpu_seconds": cpu,
                "site_steps_per_cpu_second": site_steps / cpu,
                "over_c": c_cpu / cpu,
                "mle": mle,
                "mle_relative_difference_to_c": ((mle - c_mle) / c_mle).abs(),
            });
        }
        let e = row["expression"]["cpu_seconds"]
            .as_f64()
            .unwrap_or(f64::NAN);
        let b = row["builtin"]["cpu_seconds"].as_f64().unwrap_or(f64::NAN);
        row["expression_over_builtin_speed"] = (b / e).into();
        rows.push(row);
    }
    Ok(serde_json::json!({
        "settings": "beta-FPUT, beta = 1, fixed ends, lowest normal mode at amplitude 0.5, \
                     ABA864 h = 0.02, one VM vector renormalized every tau = 1 and recorded \
                     every 10 time units, the same 2e8 site-steps at every size; chaoscope run \
                     with one rayon thread, CPU time of its whole process tree, the \
                     expression's C kernels in the kernel cache (kernel_cache: built or loaded \
                     before, in how long); scalar C -O3 -march=native -ffp-contract=off, CPU \
                     time of its loop",
        "compiler": super::scalar_c::compiler(),
        "sizes": rows,
    }))
}
