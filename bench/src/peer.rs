//! `chaoscope bench --peer heyoka`: the Lorenz spectrum workload run by chaoscope and by a peer
//! program in the same run, with the same initial state and tangent directions: each side's CPU
//! time (one thread), its spectrum, its state error at t = 10 against a reference computed by
//! neither, and the ratio of the CPU times.
//!
//! The peer's side is `benches/peer/heyoka_lorenz.py` (built into this binary and fed to the
//! Python interpreter on its standard input, so it runs from any directory). It also computes
//! the reference: a multiple-precision Taylor series (mpmath) run twice at different orders and
//! precisions, whose difference it reports. Where heyoka cannot be imported the JSON says so
//! and carries chaoscope's side alone.
//!
//! The same command runs the second workload, the Henon-Heiles MLE map (`super::peer_hh_map`),
//! reported as the `hh_map` object.

use std::io::Write;
use std::process::{Command, Stdio};

use anyhow::Context;
use chaoscope_dynamics::batch::Isa;
use chaoscope_dynamics::engine::Engine;
use chaoscope_dynamics::estimate::Machine;
use chaoscope_dynamics::spec::RunSpec;
use chaoscope_schemas::config::RunConfig;

/// The peer's side, shipped with the repository.
const HEYOKA_SCRIPT: &str = include_str!("../../benches/peer/heyoka_lorenz.py");

/// When the state error is read.
const ERROR_TIME: f64 = 10.0;

/// chaoscope's integration of the Lorenz spectrum.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum FlowMethod {
    /// Taylor's method at `tol`, landing on the grid of `h`.
    Taylor { tol: f64, h: f64 },
    /// dop853 with the fixed step `h`.
    Dop853 { h: f64 },
}

impl FlowMethod {
    /// From `--peer-method`, `--peer-h` and `--peer-tol`.
    pub fn new(method: &str, h: Option<f64>, tol: f64) -> anyhow::Result<Self> {
        let m = match method {
            "taylor" => Self::Taylor {
                tol,
                h: h.unwrap_or(1.0),
            },
            "dop853" => Self::Dop853 {
                h: h.unwrap_or(0.01),
            },
            other => anyhow::bail!("--peer-method {other:?}: taylor or dop853"),
        };
        let h = m.h();
        anyhow::ensure!(
            h > 0.0 && h <= 1.0 && (1.0 / h).fract() == 0.0,
            "--peer-h {h}: a step that divides tau = 1 (1, 0.5, 0.01, 0.005, ...)"
        );
        anyhow::ensure!(
            (1e-20..0.1).contains(&tol),
            "--peer-tol {tol}: in [1e-20, 0.1)"
        );
        Ok(m)
    }

    /// The Taylor tolerance both sides use (machine epsilon beside dop853).
    pub fn tol(self) -> f64 {
        match self {
            Self::Taylor { tol, .. } => tol,
            Self::Dop853 { .. } => f64::EPSILON,
        }
    }

    fn h(self) -> f64 {
        match self {
            Self::Taylor { h, .. } | Self::Dop853 { h } => h,
        }
    }

    /// The `[integrator]` lines of the method.
    pub fn integrator(self) -> String {
        match self {
            Self::Taylor { tol, h } => format!("method = \"taylor\"\ntol = {tol:?}\nh = {h:?}"),
            Self::Dop853 { h } => format!("method = \"dop853\"\nh = {h:?}"),
        }
    }

    pub fn describe(self) -> String {
        match self {
            Self::Taylor { tol, h } => format!("taylor, tol = {tol:e}, grid h = {h}"),
            Self::Dop853 { h } => format!("dop853, fixed h = {h}"),
        }
    }
}

/// The run of chaoscope's side: `examples/models/lorenz.toml` with its VM scheme only and the
/// identity's rows as the three tangent vectors (heyoka's variational equations start from the
/// identity).
fn config(t_final: f64, method: FlowMethod) -> String {
    let integrator = method.integrator();
    format!(
        r#"[run]
name = "lorenz"
[model]
name = "ode"
rhs = ["sigma*(x2 - x1)", "x1*(rho - x3) - x2", "x1*x2 - beta*x3"]
params = {{ sigma = 10.0, rho = 28.0, beta = 2.6666666666666665 }}
[orbit]
x = [1.0, 1.0, 1.0]
[integrator]
{integrator}
t_final = {t_final:?}
[deviations]
k = 3
vectors = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
[[scheme]]
name = "vm"
method = "vm"
d0 = 1e-8
tau = 1.0
orthonormalize = "qr"
"#
    )
}

/// chaoscope's side: config to spectrum through the engine a run uses, on this thread.
fn chaoscope_side(t_final: f64, method: FlowMethod) -> anyhow::Result<serde_json::Value> {
    let mut side = spectrum_run(&config(t_final, method), ERROR_TIME)?;
    side["method"] = method.describe().into();
    side["state_t10"] = side["state_at"].take();
    Ok(side)
}

/// A VM spectrum run of `toml` (QR every tau) through the engine a run uses, on this thread:
/// its CPU time (building the system, with the C compiler's CPU when it ran, and running),
/// the spectrum, the state at `read_at` and the largest relative error of the invariant.
pub(super) fn spectrum_run(toml: &str, read_at: f64) -> anyhow::Result<serde_json::Value> {
    let (start, children) = (
        chaoscope_os::cpu_time::thread_seconds(),
        chaoscope_os::cpu_time::children_seconds(),
    );
    let cfg = RunConfig::from_toml(toml)?;
    let spec = RunSpec::from_config(&cfg)?;
    let compile_cpu = chaoscope_os::cpu_time::thread_seconds() - start;
    let mut engine = Engine::new(spec);
    let mut logs = Vec::new();
    let mut state_at = None;
    let (mut t_end, mut e0, mut worst) = (0.0, None, 0.0f64);
    while let Some(sample) = engine.next_sample()? {
        if sample.t == read_at {
            state_at = Some(sample.state.clone());
        }
        let e0 = *e0.get_or_insert(sample.energy);
        if e0 != 0.0 {
            worst = worst.max(((sample.energy - e0) / e0).abs());
        }
        t_end = sample.t;
        for s in &sample.schemes {
            logs.resize(s.stretch.len(), 0.0);
            for (l, r) in logs.iter_mut().zip(&s.stretch) {
                *l += r.ln();
            }
        }
    }
    // Dropped first: a build of the compiled pass still under way is finished there, and its
    // compiler's time belongs to this run.
    drop(engine);
    let cpu = chaoscope_os::cpu_time::thread_seconds() - start;
    // The C compiler of the Taylor pass (or of the step kernels) runs as a child process.
    let compiler_cpu = chaoscope_os::cpu_time::children_seconds() - children;
    let spectrum: Vec<f64> = logs.iter().map(|l| l / t_end).collect();
    Ok(serde_json::json!({
        "compile_cpu_seconds": compile_cpu,
        "c_compiler_cpu_seconds": compiler_cpu,
        "run_cpu_seconds": cpu - compile_cpu,
        "cpu_seconds": cpu + compiler_cpu,
        "spectrum": spectrum,
        "state_at": state_at,
        "max_relative_energy_error": (e0 != Some(0.0)).then_some(worst),
        "t_final": t_end,
    }))
}

/// Largest absolute component difference of a side's `state_t10` to the reference.
fn state_error(side: &serde_json::Value, reference: &serde_json::Value) -> serde_json::Value {
    let (Some(s), Some(r)) = (side["state_t10"].as_array(), reference.as_array()) else {
        return serde_json::Value::Null;
    };
    let e = s
        .iter()
        .zip(r)
        .map(|(a, b)| (a.as_f64().unwrap_or(f64::NAN) - b.as_f64().unwrap_or(f64::NAN)).abs())
        .fold(0.0f64, f64::max);
    serde_json::json!(e)
}

/// The peer's JSON, or why there is none (no interpreter, or heyoka not importable).
fn run_script(python: &str, t_final: f64, tol: f64) -> anyhow::Result<serde_json::Value> {
    let args = [
        "--t-final".to_string(),
        format!("{t_final:?}"),
        "--tol".to_string(),
        format!("{tol:?}"),
    ];
    run_peer_script(
        python,
        "benches/peer/heyoka_lorenz.py",
        HEYOKA_SCRIPT,
        &args,
    )
}

/// Runs the peer's Python `source` (shipped as `name`) with `args`, fed on standard input: its
/// JSON, or, when the interpreter cannot start, a JSON saying so as plainly as a missing
/// package (`heyoka_available: false`, `heyoka_unavailable`). A script that fails is an error.
pub(super) fn run_peer_script(
    python: &str,
    name: &str,
    source: &str,
    args: &[String],
) -> anyhow::Result<serde_json::Value> {
    let spawned = Command::new(python)
        .arg("-")
        .args(args)
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn();
    let mut child = match spawned {
        Ok(child) => child,
        Err(e) => {
            return Ok(serde_json::json!({
                "heyoka_available": false,
                "heyoka_unavailable": format!("cannot start the Python interpreter {python:?} ({e}); --peer-python names another"),
            }));
        }
    };
    child
        .stdin
        .take()
        .context("the interpreter's standard input")?
        .write_all(source.as_bytes())?;
    let out = child.wait_with_output()?;
    anyhow::ensure!(
        out.status.success(),
        "{name} failed ({}): {}",
        out.status,
        String::from_utf8_lossy(&out.stderr).trim()
    );
    serde_json::from_slice(&out.stdout).with_context(|| format!("{name} printed no JSON"))
}

/// The report: both sides, or chaoscope's alone with the reason the peer is missing.
pub fn report(
    chaoscope: serde_json::Value,
    peer: serde_json::Value,
    t_final: f64,
) -> serde_json::Value {
    let reference = peer["reference_state_t10"].clone();
    let mut ours = chaoscope;
    ours["state_error_t10"] = state_error(&ours, &reference);
    let available = peer["heyoka_available"].as_bool() == Some(true);
    let (theirs, ratio) = if available && peer["heyoka"].is_object() {
        let mut theirs = peer["heyoka"].clone();
        theirs["state_error_t10"] = state_error(&theirs, &reference);
        let ratio = theirs["cpu_seconds"].as_f64().unwrap_or(f64::NAN)
            / ours["cpu_seconds"].as_f64().unwrap_or(f64::NAN);
        (theirs, serde_json::json!(ratio))
    } else {
        (serde_json::Value::Null, serde_json::Value::Null)
    };
    serde_json::json!({
        "cpu": Machine::cpu_model(),
        "isa": Isa::detect().name(),
        "workload": "Lorenz (sigma 10, rho 28, beta 8/3) from (1, 1, 1), 3 tangent vectors from the identity, QR every tau = 1, spectrum to t_final; one thread",
        "t_final": t_final,
        "peer": "heyoka",
        "peer_available": available,
        "peer_unavailable": peer.get("heyoka_unavailable").cloned().unwrap_or(serde_json::Value::Null),
        "reference": peer.get("reference").cloned().unwrap_or(serde_json::Value::Null),
        "reference_state_t10": reference,
        "reference_self_difference": peer.get("reference_self_difference").cloned().unwrap_or(serde_json::Value::Null),
        "chaoscope": ours,
        "heyoka": theirs,
        "heyoka_cpu_over_chaoscope_cpu": ratio,
    })
}

/// `chaoscope bench --peer NAME`: the Lorenz spectrum's report, with the Henon-Heiles MLE map
/// on a `grid` x `grid` grid by `step` (splitting, h) and at `map_tol` (`super::peer_hh_map`) as its `hh_map` object.
pub fn compare(
    peer: &str,
    t_final: f64,
    method: FlowMethod,
    map: (usize, (&str, f64), f64),
    python: &str,
) -> anyhow::Result<serde_json::Value> {
    anyhow::ensure!(
        peer == "heyoka",
        "--peer {peer:?}: the one peer known is \"heyoka\""
    );
    anyhow::ensure!(
        t_final.is_finite() && t_final >= ERROR_TIME && t_final.fract() == 0.0,
        "--peer-t-final {t_final}: a whole number of time units, at least {ERROR_TIME} (the \
         state error is read at t = {ERROR_TIME})"
    );
    let chaoscope = chaoscope_side(t_final, method)?;
    let peer = run_script(python, t_final, method.tol())?;
    let mut out = report(chaoscope, peer, t_final);
    let (grid, step, map_tol) = map;
    out["r3bp"] = super::peer_r3bp::compare(method, python)?;
    out["hh_map"] = super::peer_hh_map::compare(grid, step, map_tol, python)?;
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Without heyoka the report carries chaoscope's side, its error against the reference the
    /// script computed, and says the peer is missing; the ratio is absent, never made up.
    #[test]
    fn peer_report_without_heyoka_says_so() {
        let ours = chaoscope_side(10.0, FlowMethod::Dop853 { h: 0.01 }).unwrap();
        let peer = serde_json::json!({
            "reference_state_t10": [-4.902687541134648, -3.743872921802919, 24.690858102790564],
            "reference_self_difference": 3e-33,
            "heyoka_available": false,
            "heyoka_unavailable": "the Python package heyoka cannot be imported",
        });
        let r = report(ours, peer, 10.0);
        assert_eq!(r["peer_available"], false);
        assert!(r["heyoka"].is_null() && r["heyoka_cpu_over_chaoscope_cpu"].is_null());
        assert!(r["peer_unavailable"].as_str().unwrap().contains("heyoka"));
        // dop853 at h = 0.01 from (1, 1, 1) to t = 10: a global error of order 1e-10 at most
        // (8th order, |f| h of a few tenths, errors grown by about e^(0.9 * 10)); a wrong
        // state, spectrum bookkeeping or reference would be off by order 1.
        let e = r["chaoscope"]["state_error_t10"].as_f64().unwrap();
        assert!(e < 1e-8, "{r}");
        let spectrum = r["chaoscope"]["spectrum"].as_array().unwrap();
        assert_eq!(spectrum.len(), 3);
        // Over t = 10 the spectrum has not converged, but it is ordered and its sum is the mean
        // divergence -(sigma + 1 + beta) = -13.667 to rounding (QR keeps the volume).
        let sum: f64 = spectrum.iter().map(|v| v.as_f64().unwrap()).sum();
        assert!((sum + 13.0 + 2.0 / 3.0).abs() < 1e-6, "{r}");
        assert!(r["cpu"].is_string() && r["isa"].is_string());
    }
}
