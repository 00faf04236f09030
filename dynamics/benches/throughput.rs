//! Integration throughput of the one-orbit engine, printed as JSON (one object per case).
//!
//! An orbit-step is one phase-space trajectory (the reference orbit, a tangent vector or a
//! nearby orbit) advanced by one full ABA864 step. Measured on one rayon thread, so the figure
//! is per core. Run: `cargo bench -p chaoscope-dynamics --bench throughput`.

use std::time::Instant;

use chaoscope_dynamics::engine::Engine;
use chaoscope_dynamics::spec::RunSpec;
use chaoscope_schemas::config::RunConfig;

fn config(model: &str, orbit: &str, k: usize, method: &str, t_final: f64) -> String {
    format!(
        r#"
{model}
{orbit}
[integrator]
method = "aba864"
h = 0.01
t_final = {t_final}
[deviations]
k = {k}
sets = 1
seed = 1
[[scheme]]
name = "s"
method = "{method}"
d0 = 1e-8
tau = 1.0
"#
    )
}

fn measure(name: &str, text: &str) -> serde_json::Value {
    let spec = RunSpec::from_config(&RunConfig::from_toml(text).unwrap()).unwrap();
    let (steps, k, n) = (spec.total_steps(), spec.k(), spec.dim() / 2);
    let method = spec.schemes()[0].method.name();
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .unwrap();
    let start = Instant::now();
    let mut samples = 0u64;
    pool.install(|| Engine::new(spec).run(|_| samples += 1))
        .unwrap();
    let secs = start.elapsed().as_secs_f64();
    let orbit_steps = steps as f64 * (k + 1) as f64;
    serde_json::json!({
        "case": name, "method": method, "dof": n, "k": k, "steps": steps, "seconds": secs,
        "orbit_steps_per_second_per_core": orbit_steps / secs,
        "run_steps_per_second_per_core": steps as f64 / secs,
        "samples": samples,
    })
}

fn main() {
    // `cargo bench` passes `--bench`; a filter argument selects cases by substring.
    let filter: Option<String> = std::env::args().skip(1).find(|a| !a.starts_with("--"));
    let hh = (
        "[model]\nname = \"henon-heiles\"",
        "[orbit]\nq = [0.0, -0.25]\np = [0.0, 0.0]\nenergy = 0.125\nsolve_for = \"p1\"",
    );
    let mut cases: Vec<(String, String)> = Vec::new();
    for method in ["vm", "mpm"] {
        cases.push((
            format!("hh-{method}"),
            config(hh.0, hh.1, 4, method, 10000.0),
        ));
        for (n, k, t) in [(5usize, 10usize, 2000.0), (101, 8, 200.0), (501, 8, 40.0)] {
            let model = format!("[model]\nname = \"fput-beta\"\nn = {n}\nbeta = 1.0");
            let orbit = "[orbit]\npreset = \"spo1\"\nenergy = 1.0".to_string();
            cases.push((
                format!("fput{n}-{method}"),
                config(&model, &orbit, k, method, t),
            ));
        }
    }
    for (name, text) in cases {
        if filter.as_deref().is_some_and(|f| !name.contains(f)) {
            continue;
        }
        println!("{}", measure(&name, &text));
    }
}
