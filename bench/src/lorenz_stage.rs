//! `chaoscope bench --lorenz-stage-only`: what one stage of a dop853 step of the Lorenz system
//! with three tangent vectors costs through the real one-orbit path, beside a plain loop doing
//! the same flops.
//!
//! - `one_orbit_step_tangent`: the system a run of `examples/models/lorenz.toml` builds (the
//!   compiled right-hand side and its Jacobian-vector product, fixed h = 0.01), stepped by
//!   `AdaptiveSteps::step_tangent_along`, what the engine calls for a set of three tangent
//!   vectors (fewer than the batched kernels' lanes): the orbit's copy and its three vectors.
//! - `plain_loop`: the same step hand-written for D = 3 in this file: the Lorenz field, its
//!   Jacobian applied to each vector, and the Runge-Kutta stage combinations over the
//!   tableau's non-zero coefficients, in the order the integrator sums them, with fixed-size
//!   arrays and nothing else (no traits, no calls, no bounds the compiler cannot see).
//! - `engine`: the whole one-orbit run (the reference orbit, its VM copy with the three
//!   vectors, QR renormalization every tau = 1) per stage of a step, for scale.
//!
//! A stage here is one of the 12 stages of a step: one field evaluation and three
//! Jacobian-vector products with their stage combinations. Both sides run the same number of
//! steps from the same state in interleaved rounds (each restarting its vectors every 100
//! steps, as a renormalization would), and the JSON carries how far their final states differ
//! (the orbit bit for bit; the vectors to rounding: the compiled Jacobian-vector product may
//! group its products differently from the hand-written one).

use chaoscope_dynamics::engine::Engine;
use chaoscope_dynamics::integrator::{RungeKuttaTableau, Workspace};
use chaoscope_dynamics::spec::RunSpec;
use chaoscope_schemas::config::RunConfig;

/// Lorenz's parameters, as in `examples/models/lorenz.toml`.
const SIGMA: f64 = 10.0;
const RHO: f64 = 28.0;
const BETA: f64 = 2.6666666666666665;
const H: f64 = 0.01;
/// Steps between restarts of the tangent vectors (tau = 1 at h = 0.01).
const WINDOW: u64 = 100;
/// Interleaved rounds of (one-orbit path, plain loop).
const ROUNDS: usize = 3;

/// The run whose system is measured: `examples/models/lorenz.toml` with its VM scheme only.
fn config(t_final: f64) -> String {
    format!(
        r#"[run]
name = "lorenz"
[model]
name = "ode"
rhs = ["sigma*(x2 - x1)", "x1*(rho - x3) - x2", "x1*x2 - beta*x3"]
params = {{ sigma = {SIGMA:?}, rho = {RHO:?}, beta = {BETA:?} }}
[orbit]
x = [1.0, 1.0, 1.0]
[integrator]
method = "dop853"
h = {H:?}
t_final = {t_final:?}
[deviations]
k = 3
sets = 1
seed = 1
[[scheme]]
name = "vm"
method = "vm"
d0 = 1e-8
tau = 1.0
orthonormalize = "qr"
"#
    )
}

/// The tangent vectors every window starts from (one after the other).
const W0: [f64; 9] = [1.0, 0.0, 0.0, 0.3, 1.0, 0.0, -0.2, 0.5, 1.0];

/// The dop853 tableau's non-zero coefficients, row by row in the integrator's order.
struct Plain {
    a: Vec<Vec<(usize, f64)>>,
    b: Vec<(usize, f64)>,
}

impl Plain {
    fn new() -> Self {
        let t = RungeKuttaTableau::Dop853
            .tableau()
            .expect("dop853 is explicit");
        let nz = |row: &[f64]| -> Vec<(usize, f64)> {
            row.iter()
                .enumerate()
                .filter(|(_, a)| **a != 0.0)
                .map(|(j, &a)| (j, a))
                .collect()
        };
        Self {
            a: t.a.iter().map(|r| nz(r)).collect(),
            b: nz(t.b),
        }
    }

    /// `n` steps of the orbit `x` and the vectors `w`.
    fn steps(&self, x: &mut [f64; 3], w: &mut [[f64; 3]; 3], n: u64) {
        let mut k = [[0.0f64; 3]; 12];
        let mut xs = [[0.0f64; 3]; 12];
        let mut kt = [[[0.0f64; 3]; 12]; 3];
        for _ in 0..n {
            for i in 0..12 {
                let row = &self.a[i];
                let mut xi = [0.0; 3];
                for d in 0..3 {
                    let mut sum = 0.0;
                    for &(j, a) in row {
                        sum += a * k[j][d];
                    }
                    xi[d] = x[d] + H * sum;
                }
                k[i] = [
                    SIGMA * (xi[1] - xi[0]),
                    xi[0] * (RHO - xi[2]) - xi[1],
                    xi[0] * xi[1] - BETA * xi[2],
                ];
                xs[i] = xi;
                for (v, kv) in w.iter().zip(kt.iter_mut()) {
                    let mut wi = [0.0; 3];
                    for d in 0..3 {
                        let mut sum = 0.0;
                        for &(j, a) in row {
                            sum += a * kv[j][d];
                        }
                        wi[d] = v[d] + H * sum;
                    }
                    kv[i] = [
                        SIGMA * (wi[1] - wi[0]),
                        (RHO - xi[2]) * wi[0] - wi[1] - xi[0] * wi[2],
                        xi[1] * wi[0] + xi[0] * wi[1] - BETA * wi[2],
                    ];
                }
            }
            let combine = |y: &mut [f64; 3], k: &[[f64; 3]; 12]| {
                for d in 0..3 {
                    let mut sum = 0.0;
                    for &(i, b) in &self.b {
                        sum += b * k[i][d];
                    }
                    y[d] += H * sum;
                }
            };
            combine(x, &k);
            for (v, kv) in w.iter_mut().zip(&kt) {
                combine(v, kv);
            }
        }
    }
}

/// Flops of one step of the plain loop (multiplies and adds; the same count as the
/// integrator's, which sums the same non-zero terms).
fn flops_per_step(p: &Plain) -> u64 {
    let combos: u64 = p.a.iter().map(|r| 3 * (2 * r.len() as u64 + 2)).sum();
    let last = 3 * (2 * p.b.len() as u64 + 2);
    // The field: 2 + 3 + 3 flops; each Jacobian-vector product: 2 + 5 + 5.
    4 * (combos + last) + 12 * (8 + 3 * 12)
}

/// The measurement, as JSON: `steps` steps per side per round.
pub fn measure(steps: u64, engine_t_final: f64) -> anyhow::Result<serde_json::Value> {
    anyhow::ensure!(
        steps >= WINDOW,
        "--lorenz-stage-steps must be at least {WINDOW}"
    );
    let cfg = RunConfig::from_toml(&config(1.0))?;
    let spec = RunSpec::from_config(&cfg)?;
    let system = spec.system().clone();
    let x0: [f64; 3] = spec.x0().try_into()?;
    let plain = Plain::new();
    let stages = (12 * steps * ROUNDS as u64) as f64;

    let (mut path_cpu, mut plain_cpu) = (0.0, 0.0);
    let mut path_x = x0.to_vec();
    let mut path_w = W0.to_vec();
    let mut work = Workspace::new();
    let (mut plain_x, mut plain_w) = (x0, [[0.0; 3]; 3]);
    for _ in 0..ROUNDS {
        let start = chaoscope_os::cpu_time::thread_seconds();
        let (x, w) = (&mut path_x, &mut path_w);
        x.copy_from_slice(&x0);
        for step in 0..steps {
            if step % WINDOW == 0 {
                w.copy_from_slice(&W0);
            }
            system.step_tangent_along(x, w, step as f64 * H, &[], &mut work)?;
        }
        path_cpu += chaoscope_os::cpu_time::thread_seconds() - start;

        let start = chaoscope_os::cpu_time::thread_seconds();
        plain_x = x0;
        for window in 0..steps / WINDOW {
            for (v, w0) in plain_w.iter_mut().zip(W0.chunks_exact(3)) {
                v.copy_from_slice(w0);
            }
            let n = WINDOW.min(steps - window * WINDOW);
            plain.steps(std::hint::black_box(&mut plain_x), &mut plain_w, n);
        }
        let rest = steps % WINDOW;
        if rest > 0 {
            for (v, w0) in plain_w.iter_mut().zip(W0.chunks_exact(3)) {
                v.copy_from_slice(w0);
            }
            plain.steps(&mut plain_x, &mut plain_w, rest);
        }
        plain_cpu += chaoscope_os::cpu_time::thread_seconds() - start;
    }
    let orbit_identical = path_x
        .iter()
        .zip(&plain_x)
        .all(|(a, b)| a.to_bits() == b.to_bits());
    // Per vector: the largest component difference over the largest component.
    let vector_rel_diff = path_w
        .chunks_exact(3)
        .zip(&plain_w)
        .map(|(a, b)| {
            let diff = a
                .iter()
                .zip(b)
                .map(|(a, b)| (a - b).abs())
                .fold(0.0, f64::max);
            diff / b.iter().map(|v| v.abs()).fold(0.0, f64::max)
        })
        .fold(0.0f64, f64::max);

    // The whole one-orbit run, for scale.
    let spec = RunSpec::from_config(&RunConfig::from_toml(&config(engine_t_final))?)?;
    let start = chaoscope_os::cpu_time::thread_seconds();
    let mut engine = Engine::one_orbit(spec.clone());
    while engine.next_sample()?.is_some() {}
    let engine_cpu = chaoscope_os::cpu_time::thread_seconds() - start;
    let engine_stages = 12.0 * spec.total_steps() as f64;

    let path_ns = path_cpu * 1e9 / stages;
    let plain_ns = plain_cpu * 1e9 / stages;
    let flops = flops_per_step(&plain) as f64 / 12.0;
    Ok(serde_json::json!({
        "workload": "Lorenz (sigma 10, rho 28, beta 8/3), dop853 fixed h = 0.01, 3 tangent vectors, from (1, 1, 1)",
        "steps_per_round": steps,
        "rounds": ROUNDS,
        "flops_per_stage": flops,
        "one_orbit_step_tangent": {
            "what": "AdaptiveSteps::step_tangent_along of the compiled Lorenz field: the orbit's copy and 3 tangent vectors",
            "cpu_seconds": path_cpu,
            "ns_per_stage": path_ns,
        },
        "plain_loop": {
            "what": "the same step hand-written for D = 3 in Rust: field, Jacobian times 3 vectors, stage combinations",
            "cpu_seconds": plain_cpu,
            "ns_per_stage": plain_ns,
        },
        "one_orbit_over_plain_loop": path_ns / plain_ns,
        "orbit_bit_identical_to_plain_loop": orbit_identical,
        "vectors_max_relative_difference_to_plain_loop": vector_rel_diff,
        "engine": {
            "what": "Engine::one_orbit of the VM run (reference orbit + its VM copy with 3 vectors, QR every tau = 1)",
            "t_final": engine_t_final,
            "cpu_seconds": engine_cpu,
            "ns_per_stage": engine_cpu * 1e9 / engine_stages,
        },
    }))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The plain loop is the integrator's arithmetic: a short measurement reports the orbit
    /// bit for bit equal, and the vectors equal to rounding accumulated over one window of
    /// 100 steps of a chaotic flow (a few ulps per step, grown by at most e^(0.9 * 1)): 1e-10
    /// leaves room for that and still fails on any wrong coefficient or term.
    #[test]
    fn lorenz_stage_plain_loop_is_the_integrators_arithmetic() {
        let m = measure(WINDOW, 1.0).unwrap();
        assert_eq!(m["orbit_bit_identical_to_plain_loop"], true, "{m}");
        let diff = m["vectors_max_relative_difference_to_plain_loop"]
            .as_f64()
            .unwrap();
        assert!(diff < 1e-10, "{m}");
        assert!(m["one_orbit_over_plain_loop"].as_f64().unwrap() > 0.0);
    }
}
