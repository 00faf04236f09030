//! Phase-space maps of systems written as expressions (discrete maps, Runge-Kutta flows): the
//! batched kernel (the compiled lane functions) against the one-orbit engine computing the same
//! points, which it equals bit for bit (`dynamics/tests/map_batch.rs`). Prints one JSON object
//! per case: CPU seconds of each path on one thread, measured in this run, and their ratio.
//!
//! `cargo bench -p chaoscope-dynamics --bench expression_maps`

use chaoscope_dynamics::batch::Isa;
use chaoscope_dynamics::estimate::Machine;
use chaoscope_dynamics::map::{self, MapOptions, MapSpec};
use chaoscope_schemas::config::RunConfig;

const STANDARD_MAP: &str = r#"
[model]
name = "map"
next = ["x1 + x2 + K*sin(x1)", "x2 + K*sin(x1)"]
params = { K = 1.0 }
modulo = [6.283185307179586, 6.283185307179586]
[orbit]
x = [0.0, 0.0]
[integrator]
h = 1
t_final = 1000
[deviations]
k = 2
sets = 1
seed = 1
[[scheme]]
name = "vm"
method = "vm"
d0 = 1e-8
tau = 1
[map]
x = { coord = "x1", min = 0.0, max = 6.2, n = 40 }
y = { coord = "x2", min = -3.1, max = 3.1, n = 40 }
indicator = "sali"
"#;

const LORENZ: &str = r#"
[model]
name = "ode"
rhs = ["sigma*(x2 - x1)", "x1*(rho - x3) - x2", "x1*x2 - beta*x3"]
params = { sigma = 10.0, rho = 28.0, beta = 2.6666666666666665 }
[orbit]
x = [1.0, 1.0, 20.0]
[integrator]
method = "rk4"
h = 0.01
t_final = 200
[deviations]
k = 2
sets = 4
seed = 1
[[scheme]]
name = "mpm"
method = "METHOD"
d0 = 1e-8
tau = 1
[map]
x = { coord = "x1", min = -10.0, max = 10.0, n = 8 }
y = { coord = "x2", min = -10.0, max = 10.0, n = 8 }
indicator = "gali"
"#;

fn case(name: &str, text: &str) -> serde_json::Value {
    let spec = MapSpec::from_config(&RunConfig::from_toml(text).unwrap()).unwrap();
    let points: Vec<u64> = (0..spec.grid_points()).collect();
    let options = MapOptions {
        threads: Some(1),
        ..MapOptions::default()
    };
    let start = chaoscope_os::cpu_time::process_seconds();
    let mut batched = Vec::new();
    map::run_map(&spec, &points, &options, |r| {
        batched.push(r);
        true
    })
    .unwrap();
    let batched_cpu = chaoscope_os::cpu_time::process_seconds() - start;
    let start = chaoscope_os::cpu_time::process_seconds();
    let engine: Vec<_> = points
        .iter()
        .map(|&i| map::one_orbit::point(&spec, i))
        .collect();
    let engine_cpu = chaoscope_os::cpu_time::process_seconds() - start;
    batched.sort_by_key(|r| r.index);
    let identical = batched.iter().zip(&engine).all(|(a, b)| a.same_numbers(b));
    serde_json::json!({
        "case": name,
        "points": points.len(),
        "batched_kernel": spec.has_batched_kernel(),
        "batched_cpu_seconds": batched_cpu,
        "one_orbit_engine_cpu_seconds": engine_cpu,
        "engine_over_batched": engine_cpu / batched_cpu,
        "bit_identical": identical,
        "isa": Isa::detect().name(),
        "cpu": Machine::cpu_model(),
    })
}

fn main() {
    for (name, text) in [
        (
            "standard map, VM SALI, 40 x 40, n = 1000",
            STANDARD_MAP.to_string(),
        ),
        (
            "Lorenz rk4, MPM GALI_2, 4 sets, 8 x 8, t = 200",
            LORENZ.replace("METHOD", "mpm"),
        ),
        (
            "Lorenz rk4, VM GALI_2, 4 sets, 8 x 8, t = 200",
            LORENZ.replace("METHOD", "vm"),
        ),
    ] {
        println!("{}", case(name, &text));
    }
}
