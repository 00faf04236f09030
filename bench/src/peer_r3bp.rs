//! The second flow of `chaoscope bench --peer heyoka`: the planar circular restricted
//! three-body problem of the Sun and Jupiter (`examples/models/restricted-three-body.toml`), a
//! chaotic orbit that starts on the circle a = 0.86 about the Sun, 198 degrees from Jupiter,
//! with its four Lyapunov exponents by the variational method (QR every tau = 1) to t = 1000,
//! run by chaoscope and by heyoka (`benches/peer/heyoka_r3bp.py`) at the same tolerance, ten
//! times each; each side's CPU time, spectrum and largest relative error of the Jacobi
//! constant (-2 H).
//!
//! Why t = 1000 ten times and not t = 10^4 once: by t ~ 500 two integrations of this chaotic
//! orbit that differ in the last bit are different orbits, and later ones meet Jupiter closer
//! than 1e-2, where the rounding of any double-precision integration in these coordinates
//! costs the Jacobi constant 1e-13 .. 1e-6 by luck of where the steps fall (seen on both
//! sides). Up to t = 1000 this orbit keeps 0.04 from Jupiter: both sides hold the Jacobi
//! constant to a few 1e-15, so the times compare the same work at the same accuracy.

use super::peer::{FlowMethod, run_peer_script, spectrum_run};
use chaoscope_dynamics::batch::Isa;
use chaoscope_dynamics::estimate::Machine;

const SCRIPT: &str = include_str!("../../benches/peer/heyoka_r3bp.py");

/// Jupiter's mass over the Sun's and Jupiter's.
const MU: f64 = 9.537e-4;
/// `(x, y, px, py)`: on the circle of radius 0.86 about the Sun at 198 degrees from Jupiter,
/// with the circular speed about the Sun (the canonical momenta of the rotating frame are the
/// inertial velocity's components).
pub const STATE: [f64; 4] = [
    -0.8188623040138321,
    -0.2657546151624547,
    0.3330626600839581,
    -1.0250614657881958,
];
const T_FINAL: f64 = 1000.0;
/// Runs of the workload on each side (their CPU times summed).
const REPEATS: usize = 10;

fn config(method: FlowMethod) -> String {
    let [x, y, px, py] = STATE;
    format!(
        r#"[run]
name = "restricted-three-body"
[model]
name = "hamiltonian"
n = 2
hamiltonian = "(p1^2 + p2^2)/2 + q2*p1 - q1*p2 - (1 - mu)/sqrt((q1 + mu)^2 + q2^2) - mu/sqrt((q1 - 1 + mu)^2 + q2^2)"
params = {{ mu = {MU:?} }}
[orbit]
q = [{x:?}, {y:?}]
p = [{px:?}, {py:?}]
[integrator]
{}
t_final = {T_FINAL:?}
[deviations]
k = 4
vectors = [[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]]
[[scheme]]
name = "vm"
method = "vm"
d0 = 1e-8
tau = 1.0
orthonormalize = "qr"
"#,
        method.integrator()
    )
}

/// Both sides, or chaoscope's alone with the reason the peer is missing.
pub fn compare(method: FlowMethod, python: &str) -> anyhow::Result<serde_json::Value> {
    let mut ours = spectrum_run(&config(method), T_FINAL)?;
    for _ in 1..REPEATS {
        let again = spectrum_run(&config(method), T_FINAL)?;
        anyhow::ensure!(
            again["spectrum"] == ours["spectrum"],
            "the repeated run gave another spectrum"
        );
        for key in [
            "compile_cpu_seconds",
            "c_compiler_cpu_seconds",
            "run_cpu_seconds",
            "cpu_seconds",
        ] {
            let sum = ours[key].as_f64().unwrap_or(0.0) + again[key].as_f64().unwrap_or(0.0);
            ours[key] = sum.into();
        }
    }
    ours["method"] = method.describe().into();
    ours["repeats"] = REPEATS.into();
    let _ = ours.as_object_mut().map(|o| o.remove("state_at"));
    let mut args = vec![
        "--t-final".to_string(),
        format!("{T_FINAL:?}"),
        "--tol".to_string(),
        format!("{:?}", method.tol()),
        "--mu".to_string(),
        format!("{MU:?}"),
        "--repeats".to_string(),
        REPEATS.to_string(),
        "--state".to_string(),
    ];
    args.extend(STATE.iter().map(|v| format!("{v:?}")));
    let peer = run_peer_script(python, "benches/peer/heyoka_r3bp.py", SCRIPT, &args)?;
    let available = peer["heyoka_available"].as_bool() == Some(true);
    let theirs = peer
        .get("heyoka")
        .cloned()
        .unwrap_or(serde_json::Value::Null);
    let ratio = |key: &str| {
        let r = theirs[key].as_f64().unwrap_or(f64::NAN) / ours[key].as_f64().unwrap_or(f64::NAN);
        if r.is_finite() {
            serde_json::json!(r)
        } else {
            serde_json::Value::Null
        }
    };
    Ok(serde_json::json!({
        "cpu": Machine::cpu_model(),
        "isa": Isa::detect().name(),
        "workload": "planar circular restricted three-body problem, Sun-Jupiter mu = 9.537e-4, rotating frame; a chaotic orbit from the circle a = 0.86 about the Sun at 198 degrees from Jupiter; 4 tangent vectors from the identity, QR every tau = 1, spectrum to t = 1000, ten runs; one thread",
        "peer_available": available,
        "peer_unavailable": peer.get("heyoka_unavailable").cloned().unwrap_or(serde_json::Value::Null),
        "chaoscope": ours,
        "heyoka": theirs,
        "heyoka_cpu_over_chaoscope_cpu": ratio("cpu_seconds"),
        "heyoka_run_cpu_over_chaoscope_run_cpu": ratio("run_cpu_seconds"),
    }))
}
