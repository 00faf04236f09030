//! Flows (`[model] name = "ode"`) and maps (`name = "map"`) through the whole pipeline with real
//! processes (issue "beyond Hamiltonians"): the example configs are recorded by `chaoscope run`,
//! analyzed (the report carries the kind, the mean divergence and the sum of the exponents in
//! place of the energy error), replayed with another tau on the bit-identical orbit, and mapped;
//! orbits that escape, blow up or turn NaN stop with the time or iteration named, in the report
//! and in the recording, and never put NaN into an output.

use crate::common;

use std::f64::consts::{PI, TAU};
use std::path::Path;

use chaoscope_schemas::config::{MapAxis, MapConfig, MapModelConfig, ModelConfig, RunConfig};
use serde_json::Value;

use crate::common::{chaoscope_captured as chaoscope, run_ok};

fn example(name: &str) -> RunConfig {
    let path = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("examples/models")
        .join(name);
    let text = std::fs::read_to_string(&path).unwrap();
    let mut config = RunConfig::from_file_text(&text, &path).unwrap();
    config.run.name = Some(common::unique_run(name.trim_end_matches(".toml")));
    config
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// A little-endian `f64` array in NumPy's `.npy` format (version 1.0, C order), read as the
/// format's specification says: its shape and its values.
fn read_npy(path: &Path) -> (Vec<usize>, Vec<f64>) {
    let bytes = std::fs::read(path).unwrap();
    assert_eq!(&bytes[..8], b"\x93NUMPY\x01\x00", "{}", path.display());
    let data = 10 + u16::from_le_bytes([bytes[8], bytes[9]]) as usize;
    assert_eq!(data % 64, 0, "the data is aligned");
    let header = std::str::from_utf8(&bytes[10..data]).unwrap();
    assert!(header.contains("'descr': '<f8'"), "{header}");
    assert!(header.contains("'fortran_order': False"), "{header}");
    let shape = &header[header.find("'shape': (").unwrap() + 10..];
    let shape: Vec<usize> = shape[..shape.find(')').unwrap()]
        .split(',')
        .map(str::trim)
        .filter(|d| !d.is_empty())
        .map(|d| d.parse().unwrap())
        .collect();
    let values: Vec<f64> = bytes[data..]
        .chunks_exact(8)
        .map(|b| f64::from_le_bytes(b.try_into().unwrap()))
        .collect();
    assert_eq!(values.len(), shape.iter().product::<usize>());
    (shape, values)
}

/// The `[model]` keys of a map's config.
fn map_model(config: &mut RunConfig) -> &mut MapModelConfig {
    match &mut config.model {
        ModelConfig::Map(m) => m,
        other => panic!("not a map: {}", other.name()),
    }
}

fn write(dir: &Path, name: &str, config: &RunConfig) -> std::path::PathBuf {
    let path = dir.join(name);
    std::fs::write(&path, config.to_toml()).unwrap();
    path
}

fn scheme<'a>(report: &'a Value, name: &str) -> &'a Value {
    report["schemes"]
        .as_array()
        .unwrap()
        .iter()
        .find(|s| s["name"] == name)
        .unwrap_or_else(|| panic!("scheme {name} in {report}"))
}

/// No NaN or infinity anywhere in a JSON document (serde_json writes them as null, so a null
/// where a number belongs is one too; the one field that is null by design is allowed).
fn assert_all_finite(v: &Value, path: &str) {
    match v {
        Value::Number(n) => assert!(n.as_f64().unwrap().is_finite(), "{path} = {n}"),
        // `torus_dimension` is null by design when the verdict names no torus.
        Value::Null if path.ends_with(".torus_dimension") => {}
        Value::Null => panic!("{path} is null (a NaN or infinity written as JSON)"),
        Value::Array(a) => {
            for (i, x) in a.iter().enumerate() {
                assert_all_finite(x, &format!("{path}[{i}]"));
            }
        }
        Value::Object(o) => {
            for (k, x) in o {
                assert_all_finite(x, &format!("{path}.{k}"));
            }
        }
        _ => {}
    }
}

#[test]
fn lorenz_records_analyzes_and_replays_bit_identically() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let mut config = example("lorenz.toml");
    config.integrator.t_final = 50.0;
    let cfg = write(d, "lorenz.toml", &config);
    let rec = d.join("lorenz.mcap");
    run_ok(&["run", s(&cfg), "--out", s(&rec)]);

    let report: Value = serde_json::from_str(&run_ok(&["analyze", s(&rec), "--json"])).unwrap();
    assert_all_finite(&report, "report");
    let run = &report["run"];
    assert_eq!(run["kind"], "flow");
    assert_eq!(run["time"], "continuous");
    assert_eq!(run["dim"], 3);
    assert!(
        run.get("energy_error_max").is_none(),
        "a flow has no energy: {run}"
    );
    // div f = -(sigma + 1 + beta) everywhere, so its mean is that constant to rounding.
    let divergence = -(10.0 + 1.0 + 8.0 / 3.0);
    let mean = run["mean_divergence"].as_f64().unwrap();
    assert!(
        ((mean - divergence) / divergence).abs() < 1e-12,
        "{mean} vs {divergence}"
    );
    for name in ["vm", "mpm"] {
        let sch = scheme(&report, name);
        let sum = sch["lyapunov_sum"].as_f64().unwrap();
        // VM: the QR sums telescope into ln |det| of the tangent map, exp(t div f) for the
        // exact flow and the same to the integrator's error for the step (dop853 at h = 0.01
        // to t = 50: 7e-8 relative measured, the transient's large derivatives dominating);
        // 1e-6 is the bound the guide quotes (systems.md). MPM: the nearby
        // orbits' third separation shrinks by exp(-14.57 tau) = 0.23 between renormalizations
        // and is measured against the rounding of x + d (eps |x| / d0, about 4e-7 relative),
        // a relative error of about 1e-6 per renormalization that averages down: 1e-4.
        let tol = if name == "vm" { 1e-6 } else { 1e-4 };
        assert!(
            ((sum - divergence) / divergence).abs() < tol,
            "{name}: sum {sum} vs {divergence}"
        );
        let mle = sch["mle"].as_f64().unwrap();
        // t = 50 is short: the finite-time MLE is within about 0.2 of 0.9056.
        assert!((0.6..1.2).contains(&mle), "{name}: MLE {mle}");
    }

    // Replay with another tau: the recorded orbit again, bit for bit.
    let replayed = d.join("replay.mcap");
    let out = run_ok(&[
        "replay",
        s(&rec),
        "--tau",
        "2",
        "--out",
        s(&replayed),
        "--json",
    ]);
    let outcome: Value = serde_json::from_str(out.lines().last().unwrap()).unwrap();
    let compared = outcome["reference_states_compared"].as_u64().unwrap();
    assert!(compared >= 25, "{outcome}");
    assert_eq!(
        compared,
        outcome["reference_states_identical"].as_u64().unwrap()
    );
}

#[test]
fn a_divergence_free_flow_written_with_asinh_keeps_its_volume() {
    // dx1/dt = asinh(x2), dx2/dt = -x1: Hamilton's equations of H = x1^2/2 + x2 asinh(x2) -
    // sqrt(1 + x2^2), so div f = d asinh(x2)/dx1 + d(-x1)/dx2 = 0 everywhere. The derived
    // Jacobian has those entries as exact zeros, so the mean divergence is 0 exactly; the VM
    // exponents' sum is ln |det| of the integrator's tangent map over t, 0 for the exact flow and
    // the step's error for dop853 at h = 0.01 (local error about 1e-16 per step on this smooth,
    // O(1) flow): 1e-9 leaves three orders of magnitude of margin.
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let mut config = example("lorenz.toml");
    let ModelConfig::Ode(ode) = &mut config.model else {
        panic!("lorenz.toml is a flow")
    };
    ode.rhs = Some(vec!["asinh(x2)".into(), "-x1".into()]);
    ode.params.clear();
    config.orbit.x = vec![0.5, 1.5];
    config.deviations.k = 2;
    config.integrator.t_final = 20.0;
    let cfg = write(d, "asinh-flow.toml", &config);
    let rec = d.join("asinh-flow.mcap");
    run_ok(&["run", s(&cfg), "--out", s(&rec)]);

    let report: Value = serde_json::from_str(&run_ok(&["analyze", s(&rec), "--json"])).unwrap();
    assert_all_finite(&report, "report");
    let run = &report["run"];
    assert_eq!(run["kind"], "flow");
    assert_eq!(run["dim"], 2);
    assert_eq!(run["mean_divergence"].as_f64().unwrap(), 0.0, "{run}");
    let sum = scheme(&report, "vm")["lyapunov_sum"].as_f64().unwrap();
    assert!(sum.abs() < 1e-9, "vm: sum {sum}");
}

#[test]
fn adaptive_lorenz_replays_bit_identically() {
    // Error control: the reference chooses its substeps, the deviation sets follow them, and a
    // replay with another tau chooses the very same ones (they depend on the state only).
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let mut config = example("lorenz.toml");
    config.integrator.t_final = 20.0;
    config.integrator.h = Some(0.1);
    config.integrator.rtol = Some(1e-10);
    config.integrator.atol = Some(1e-10);
    let cfg = write(d, "lorenz.toml", &config);
    let rec = d.join("lorenz.mcap");
    run_ok(&["run", s(&cfg), "--out", s(&rec)]);
    let out = run_ok(&[
        "replay",
        s(&rec),
        "--tau",
        "0.5",
        "--out",
        s(&d.join("replay.mcap")),
        "--json",
    ]);
    let outcome: Value = serde_json::from_str(out.lines().last().unwrap()).unwrap();
    let compared = outcome["reference_states_compared"].as_u64().unwrap();
    assert!(compared >= 20, "{outcome}");
    assert_eq!(
        compared,
        outcome["reference_states_identical"].as_u64().unwrap()
    );
}

#[test]
fn henon_map_records_and_reports_its_constant_jacobian() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let mut config = example("henon-map.toml");
    config.integrator.t_final = 20000.0;
    let cfg = write(d, "henon.toml", &config);
    let rec = d.join("henon.mcap");
    run_ok(&["run", s(&cfg), "--out", s(&rec)]);
    let report: Value = serde_json::from_str(&run_ok(&["analyze", s(&rec), "--json"])).unwrap();
    assert_all_finite(&report, "report");
    assert_eq!(report["run"]["kind"], "map");
    assert_eq!(report["run"]["time"], "discrete");
    let ln_b = 0.3f64.ln();
    // ln |det J| = ln b at every point: its mean is that constant to rounding.
    let mean = report["run"]["mean_divergence"].as_f64().unwrap();
    assert!((mean - ln_b).abs() < 1e-12, "{mean} vs {ln_b}");
    for name in ["vm", "mpm"] {
        let sch = scheme(&report, name);
        let sum = sch["lyapunov_sum"].as_f64().unwrap();
        // VM: the QR sums are ln |det| of the product of Jacobians, n ln b, to rounding. MPM:
        // the nearby orbits at d0 = 1e-8 see the map's curvature, relative 1e-8 per iteration,
        // which averages out to well below 1e-6.
        let tol = if name == "vm" { 1e-12 } else { 1e-6 };
        assert!((sum - ln_b).abs() < tol, "{name}: {sum} vs {ln_b}");
        // 2e4 iterations: the finite-time MLE is within a few 1e-3 of 0.41922.
        let mle = sch["mle"].as_f64().unwrap();
        assert!((mle - 0.41922).abs() < 0.01, "{name}: {mle}");
    }
    // The covariant Lyapunov vectors of the VM scheme (`analyze --clv`): growth rates on the
    // QR spectrum (1.6e4 iterations between the transients; boundary terms of at most
    // |ln 1e-4| / 1.6e4, app/tests/analysis/clv.rs), the angle series as CSV in time order.
    let clv: Value =
        serde_json::from_str(&run_ok(&["analyze", s(&rec), "--clv", "--json"])).unwrap();
    assert_all_finite(&clv, "clv");
    let clv = &clv["clv"];
    assert_eq!(clv["scheme"], "vm");
    assert_eq!(clv["classes"], serde_json::json!(["unstable", "stable"]));
    for j in 0..2 {
        let (a, b) = (
            clv["growth_rates"][j].as_f64(),
            clv["qr_spectrum"][j].as_f64(),
        );
        assert!((a.unwrap() - b.unwrap()).abs() < 1e-3, "{clv}");
    }
    let csv_dir = d.join("csv");
    run_ok(&["analyze", s(&rec), "--clv", "--csv", s(&csv_dir)]);
    let csv = std::fs::read_to_string(csv_dir.join("clv-angles.csv")).unwrap();
    let mut lines = csv.lines();
    assert_eq!(
        lines.next(),
        Some("t,unstable_vs_rest,expanding_vs_contracting")
    );
    let times: Vec<f64> = lines
        .map(|l| l.split(',').next().unwrap().parse().unwrap())
        .collect();
    assert_eq!(
        times.len() as u64,
        clv["renormalizations"].as_u64().unwrap()
    );
    assert!(times.windows(2).all(|w| w[0] < w[1]));
    assert_eq!(times[0], clv["t_start"].as_f64().unwrap());
    // The vectors exported as NumPy files (`--clv-vectors DIR`) and the angle histograms drawn
    // (`--plot DIR`).
    let (npy_dir, plot_dir) = (d.join("npy"), d.join("plots"));
    run_ok(&[
        "analyze",
        s(&rec),
        "--clv",
        "--clv-vectors",
        s(&npy_dir),
        "--plot",
        s(&plot_dir),
    ]);
    let (shape, vectors) = read_npy(&npy_dir.join("clv-vectors.npy"));
    assert_eq!(shape, [times.len(), 2, 2]);
    let (shape, npy_times) = read_npy(&npy_dir.join("clv-times.npy"));
    assert_eq!(shape, [times.len()]);
    // The same doubles as the CSV's times (its cells read back exactly).
    assert_eq!(npy_times, times);
    let angle_rows: Vec<Vec<f64>> = csv
        .lines()
        .skip(1)
        .map(|l| l.split(',').skip(1).map(|c| c.parse().unwrap()).collect())
        .collect();
    for (row, angles) in vectors.chunks_exact(4).zip(&angle_rows) {
        let (a, b) = (&row[0..2], &row[2..4]);
        // Unit vectors: V = Q C with Q orthonormal and C's columns normalized, each to a few
        // roundings of 1.1e-16 in a 2-term sum.
        for v in [a, b] {
            let norm = (v[0] * v[0] + v[1] * v[1]).sqrt();
            assert!((norm - 1.0).abs() < 1e-14, "|v| = {norm}");
        }
        // The angle between the two lines, computed here from sines and cosines of the
        // exported vectors, is the CSV's (the analysis goes through an orthonormalization of
        // each: the two agree to a few roundings of the angle, below pi/2).
        let sin = (a[0] * b[1] - a[1] * b[0]).abs();
        let cos = (a[0] * b[0] + a[1] * b[1]).abs();
        let angle = sin.atan2(cos);
        // Unstable against the rest and expanding against contracting are one pair here.
        for recorded in angles {
            assert!((angle - recorded).abs() < 1e-12, "{angle} vs {recorded}");
        }
    }
    for name in ["unstable_vs_rest", "expanding_vs_contracting"] {
        let png = std::fs::read(plot_dir.join(format!("clv-angle-{name}.png"))).unwrap();
        assert!(png.starts_with(b"\x89PNG\r\n\x1a\n"), "{name}: not a PNG");
        let svg = std::fs::read_to_string(plot_dir.join(format!("clv-angle-{name}.svg"))).unwrap();
        assert!(
            svg.contains("<svg") && svg.contains("</svg>"),
            "{name}: not an SVG"
        );
    }
    // A directory that is a file: one line naming it, exit status 1.
    let not_a_dir = d.join("a-file");
    std::fs::write(&not_a_dir, "x").unwrap();
    let out = chaoscope(&["analyze", s(&rec), "--clv", "--clv-vectors", s(&not_a_dir)])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(
        err.contains(&format!("{}: not a directory", s(&not_a_dir))),
        "{err}"
    );
    assert_eq!(err.trim_end().lines().count(), 1, "{err}");
    // A scheme the CLVs cannot come from: one line naming it, exit status 1.
    let out = chaoscope(&["analyze", s(&rec), "--clv", "--clv-scheme", "mpm"])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(err.contains("scheme 'mpm' is mpm with qr"), "{err}");
    assert_eq!(err.trim_end().lines().count(), 1, "{err}");
    // Replay with another tau (an integer number of iterations).
    let out = run_ok(&[
        "replay",
        s(&rec),
        "--tau",
        "10",
        "--out",
        s(&d.join("replay.mcap")),
        "--json",
    ]);
    let outcome: Value = serde_json::from_str(out.lines().last().unwrap()).unwrap();
    assert_eq!(
        outcome["reference_states_compared"],
        outcome["reference_states_identical"]
    );
}

#[test]
fn a_map_refuses_a_fractional_tau_and_a_step_other_than_one() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    // Each edit spoils the Henon map's config and gives its text.
    type Spoil = fn(RunConfig) -> String;
    let cases: [(Spoil, &str); 5] = [
        (
            |mut c| {
                c.schemes[0].tau = 2.5;
                c.to_toml()
            },
            "tau",
        ),
        (
            |mut c| {
                c.integrator.h = Some(0.5);
                c.to_toml()
            },
            "integrator.h",
        ),
        (
            |mut c| {
                c.integrator.method = "rk4".into();
                c.to_toml()
            },
            "integrator.method",
        ),
        // A flow's key in a map's table.
        (
            |c| {
                c.to_toml().replacen(
                    "name = \"map\"\n",
                    "name = \"map\"\nrhs = [\"x1\", \"x2\"]\n",
                    1,
                )
            },
            "model.rhs",
        ),
        (
            |mut c| {
                map_model(&mut c).modulo = Some(vec![1.0]);
                c.to_toml()
            },
            "model.modulo",
        ),
    ];
    for (spoil, key) in cases {
        let cfg = d.join("bad.toml");
        std::fs::write(&cfg, spoil(example("henon-map.toml"))).unwrap();
        let rec = d.join("bad.mcap");
        let out = chaoscope(&["run", s(&cfg), "--out", s(&rec)])
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(1), "{key}: {err}");
        assert_eq!(err.trim().lines().count(), 1, "{key}: {err}");
        assert!(err.contains(key), "{key}: {err}");
        assert!(!rec.exists(), "{key}: a refused run leaves no file");
    }
}

/// Runs `config`, which must stop early: exit 1, one line naming `needle` and the time, a
/// recording that ends with the failure, and an `analyze` report of what was recorded without
/// NaN.
fn assert_stops(config: &RunConfig, needle: &str, at: &str) {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let cfg = write(d, "stops.toml", config);
    let rec = d.join("stops.mcap");
    let out = chaoscope(&["run", s(&cfg), "--out", s(&rec)])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    // `run` exits with the producer's status: 3 for a run that failed.
    assert_eq!(out.status.code(), Some(3), "{err}");
    assert!(!err.contains("panicked"), "{err}");
    assert!(err.contains(needle) && err.contains(at), "{err}");
    // The recording keeps everything before the failure and says why it ended.
    let report: Value = serde_json::from_str(&run_ok(&["analyze", s(&rec), "--json"])).unwrap();
    assert_all_finite(&report, "report");
    assert!(report["run"]["samples"].as_u64().unwrap() >= 1);
    let end = &report["run"]["end"];
    assert_eq!(end["status"], "failed", "{report}");
    let reason = end["reason"].as_str().unwrap();
    assert!(reason.contains(needle) && reason.contains(at), "{reason}");
}

#[test]
fn escaping_blowing_up_and_nan_orbits_stop_with_their_time() {
    // A map with an unbounded orbit: x -> 2 x + 1 from 1 doubles every iteration and passes the
    // escape norm (1e100... far below f64's range) after about 330 iterations.
    let mut config = example("henon-map.toml");
    map_model(&mut config).next = Some(vec!["2*x1 + 1".into(), "x2".into()]);
    map_model(&mut config).params.clear();
    config.orbit.x = vec![1.0, 0.0];
    config.integrator.t_final = 1000.0;
    for s in &mut config.schemes {
        s.tau = 10.0;
    }
    assert_stops(&config, "escaped", "t = ");

    // A flow that blows up in finite time: dx/dt = x^2 from x = 1 reaches infinity at t = 1.
    let mut config = example("lorenz.toml");
    let ModelConfig::Ode(ode) = &mut config.model else {
        panic!("lorenz.toml is a flow")
    };
    ode.rhs = Some(vec!["x1^2".into(), "-x2".into(), "-x3".into()]);
    ode.params.clear();
    config.orbit.x = vec![1.0, 1.0, 1.0];
    config.integrator.t_final = 5.0;
    config.integrator.h = Some(0.01);
    for s in &mut config.schemes {
        s.tau = 0.1;
    }
    assert_stops(&config, "escaped", "t = ");

    // A map that produces NaN: log of a negative number once x1 < 0 (x1 -> x1 - 1 from 2.5).
    let mut config = example("henon-map.toml");
    map_model(&mut config).next = Some(vec!["x1 - 1".into(), "x2 + log(x1)".into()]);
    map_model(&mut config).params.clear();
    config.orbit.x = vec![2.5, 1.0];
    config.integrator.t_final = 100.0;
    for s in &mut config.schemes {
        s.tau = 1.0;
    }
    assert_stops(&config, "log", "t = 4");
}

#[test]
fn standard_map_sali_map_shows_islands() {
    // The SALI map of the standard map at K = 1 over a coarse grid of (theta, p): MPM's
    // separation is measured on the torus, so orbits near the seam are not taken for chaotic.
    // Points in the main island around (pi, 0) keep SALI far above the chaotic sea's.
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let mut config = example("standard-map.toml");
    config.integrator.t_final = 1000.0;
    config.schemes.truncate(1);
    config.schemes[0].orthonormalize = "rescale".into();
    config.map = Some(MapConfig::new(
        MapAxis::new("x1", 0.0, TAU, 24),
        MapAxis::new("x2", -PI, PI, 24),
        "sali",
    ));
    let cfg = write(d, "map.toml", &config);
    let map = d.join("map.mcap");
    let png = d.join("map.png");
    run_ok(&["map", s(&cfg), "--out", s(&map), "--png", s(&png)]);
    assert!(std::fs::metadata(&png).unwrap().len() > 1000);
    let contents = chaoscope_files::map_file::read_map_file(&map).unwrap();
    assert_eq!(contents.points.len(), 24 * 24);
    assert!(contents.points.iter().all(|p| p.value.is_finite()));
    let value = |theta: f64, p: f64| {
        let ix = (theta / TAU * 23.0).round() as u64;
        let iy = ((p + PI) / TAU * 23.0).round() as u64;
        contents
            .points
            .iter()
            .find(|q| q.index == iy * 24 + ix)
            .unwrap()
            .mean_log10
    };
    // Regular at the island centre: SALI of a 2D map falls as a power law, about 1/n (1e-3 at
    // n = 1000, within a decade); chaotic: exponentially, to the 1e-16 floor.
    let island = value(PI, 0.0);
    let sea = value(0.1, 0.1);
    eprintln!("standard map K = 1, n = 1000: log10 SALI island {island}, sea {sea}");
    assert!(island > -5.0, "island centre: log10 SALI = {island}");
    assert!(sea < -10.0, "chaotic sea: log10 SALI = {sea}");
}

/// The crossings a `section --surface ... --csv` wrote: (time, state) per row, after the
/// header `orbit,t,<coordinates>`.
fn read_crossings(path: &Path, coordinates: &str) -> Vec<(f64, Vec<f64>)> {
    let text = std::fs::read_to_string(path).unwrap();
    let mut lines = text.lines();
    assert_eq!(
        lines.next(),
        Some(format!("orbit,t,{coordinates}").as_str())
    );
    lines
        .map(|l| {
            let v: Vec<f64> = l.split(',').map(|x| x.parse().unwrap()).collect();
            assert_eq!(v[0], 0.0, "one orbit: {l}");
            assert!(v.iter().all(|x| x.is_finite()), "{l}");
            (v[1], v[2..].to_vec())
        })
        .collect()
}

#[test]
fn rossler_section_crossings_agree_at_a_ten_times_smaller_step() {
    // The Rossler attractor (a = b = 0.2, c = 5.7) cut by x1 = 0 upward (x1 increasing, where
    // dx1/dt = -x2 - x3 > 0: the half-plane x2 < 0 the orbit winds through, the standard
    // section), from the example's initial state, by fixed-step dop853 at h = 0.01 and at
    // h = 0.001. The crossings are located to rounding from the last step before them, so
    // they differ only by the two trajectories' errors: dop853's truncation error at h = 0.01
    // is ~h^8 = 1e-16 per unit time, so rounding (~1e-16 per step over 1.2e4 steps) dominates,
    // amplified by the largest exponent 0.07 over the t ~ 116 of 20 returns (e^8 ~ 3e3): about
    // 1e-11, measured 3e-11. The bound 1e-9 holds with a margin of 30; a crossing
    // located only to an interpolation's accuracy (cubic Hermite over h = 0.01: ~1e-9 to 1e-8
    // here) would not meet it.
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let mut crossings = Vec::new();
    for h in [0.01, 0.001] {
        let mut config = example("rossler.toml");
        config.integrator = chaoscope_schemas::config::IntegratorConfig::fixed("dop853", h, 200.0);
        let cfg = write(d, &format!("rossler-{h}.toml"), &config);
        let csv = d.join(format!("rossler-{h}.csv"));
        run_ok(&[
            "section",
            s(&cfg),
            "--surface",
            "x1",
            "--direction",
            "up",
            "--crossings",
            "20",
            "--csv",
            s(&csv),
        ]);
        crossings.push(read_crossings(&csv, "x1,x2,x3"));
    }
    let (coarse, fine) = (&crossings[0], &crossings[1]);
    assert_eq!((coarse.len(), fine.len()), (20, 20));
    let mut worst: f64 = 0.0;
    for ((t, x), (t_fine, x_fine)) in coarse.iter().zip(fine) {
        // On the surface to rounding (|x1| at the crossing is ~eps of the step's scale), on the
        // x2 < 0 side.
        assert!(
            x[0].abs() < 1e-14 && x_fine[0].abs() < 1e-14,
            "{x:?} {x_fine:?}"
        );
        assert!(x[1] < 0.0, "{x:?}");
        worst = worst.max((t - t_fine).abs());
        for (a, b) in x.iter().zip(x_fine) {
            worst = worst.max((a - b).abs());
        }
    }
    assert!(worst < 1e-9, "largest difference {worst:e}");
    eprintln!("rossler section: first 20 crossings at h and h/10 differ by at most {worst:e}");
    // A return time is about 2 pi / 1.03: 20 returns by t ~ 120.
    assert!(
        (100.0..140.0).contains(&coarse[19].0),
        "t = {}",
        coarse[19].0
    );

    // The first-return map of x2 and the section, drawn.
    let plot = d.join("plot");
    run_ok(&[
        "section",
        s(&d.join("rossler-0.01.toml")),
        "--surface",
        "x1",
        "--return-map",
        "x2",
        "--plot",
        s(&plot),
    ]);
    for f in [
        "section.png",
        "section.svg",
        "return-map.png",
        "return-map.svg",
    ] {
        assert!(plot.join(f).metadata().unwrap().len() > 1000, "{f}");
    }
}

#[test]
fn section_through_a_surface_refuses_what_it_cannot_draw() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let rossler = write(d, "rossler.toml", &example("rossler.toml"));
    let map = write(d, "henon-map.toml", &example("henon-map.toml"));
    let csv = d.join("out.csv");
    let cases: [(&Path, &[&str], &str); 8] = [
        (
            &map,
            &["--surface", "x1"],
            "--surface: sections through a surface are drawn for flows",
        ),
        (
            &rossler,
            &["--surface", "x4"],
            "--surface: line 1, column 1: variable 'x4' does not exist",
        ),
        (
            &rossler,
            &["--surface", "x1 +"],
            "--surface: line 1, column 5",
        ),
        (&rossler, &["--surface", "2 * a"], "reads no coordinate"),
        // |x1| stays below about 12 on the attractor.
        (
            &rossler,
            &["--surface", "x1 - 100"],
            "no crossing of the surface x1 - 100 = 0 (up)",
        ),
        (
            &rossler,
            &["--surface", "x1", "--axes", "x1,y"],
            "--axes: 'y' is not a coordinate",
        ),
        (
            &rossler,
            &["--surface", "x1", "--axes", "x1 - x2 +, x3"],
            "--axes: 'x1 - x2 +' is not a coordinate or an expression of the state (x1..x3): \
             line 1, column 10",
        ),
        (
            &rossler,
            &["--surface", "x1", "--axes", "x1, x2, x3"],
            "--axes 'x1, x2, x3': give two expressions",
        ),
    ];
    for (config, extra, needle) in cases {
        let mut args = vec!["section", s(config), "--csv", s(&csv)];
        args.extend_from_slice(extra);
        let out = chaoscope(&args).output().unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(1), "{extra:?}: {err}");
        assert!(!err.contains("panicked"), "{err}");
        let error = err
            .lines()
            .find(|l| l.starts_with("chaoscope: error: "))
            .unwrap();
        assert!(error.contains(needle), "{extra:?}: {err}");
        // Nothing written: no CSV, no unfinished one.
        assert!(
            !csv.exists() && !d.join("out.csv.partial").exists(),
            "{extra:?}"
        );
    }
    // An orbit that escapes after some crossings: they are written (finite), the orbit's end
    // is named with its time, and the exit status says it failed. x3' = x3^2 added to a
    // rotation blows x3 up in finite time (x3 = 1 / (2 - t) from 0.5: at t = 2).
    let mut blow = example("rossler.toml");
    let ModelConfig::Ode(ode) = &mut blow.model else {
        panic!("a flow")
    };
    ode.rhs = Some(vec!["-x2".into(), "x1".into(), "x3^2".into()]);
    ode.params.clear();
    blow.orbit.x = vec![1.0, 0.0, 0.5];
    blow.integrator = chaoscope_schemas::config::IntegratorConfig::fixed("dop853", 0.001, 10.0);
    let blow = write(d, "blow.toml", &blow);
    let out = chaoscope(&["section", s(&blow), "--surface", "x1", "--csv", s(&csv)])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{err}");
    // The first step past t = 2 is where the state stops being finite.
    assert!(
        err.contains("stopped at t = 2.00") && err.contains("rhs[3]"),
        "{err}"
    );
    // x1 = cos t crosses 0 upward at 3 pi / 2 = 4.7 only: before the blow-up at t = 2 there is
    // no upward crossing, so nothing is written; downward, the one at pi / 2 is.
    assert!(!csv.exists(), "{err}");
    let out = chaoscope(&[
        "section",
        s(&blow),
        "--surface",
        "x1",
        "--direction",
        "down",
        "--csv",
        s(&csv),
    ])
    .output()
    .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(err.contains("after 1 crossings"), "{err}");
    let rows = read_crossings(&csv, "x1,x2,x3");
    assert_eq!(rows.len(), 1);
    assert!((rows[0].0 - PI / 2.0).abs() < 1e-12, "{rows:?}");
}

#[test]
fn sections_of_periodic_angles_span_one_period() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    // The pendulum H = p^2/2 - cos(q) rotating from q = 0, p = 2.5 (energy 2.125, above the
    // separatrix at 1), sampled every time unit for 300: unwrapped its angle reaches ~700.
    let pendulum = |modulo: &str| {
        format!(
            "[model]\nname = \"hamiltonian\"\nn = 1\nhamiltonian = \"p1^2/2 - cos(q1)\"\n\
             {modulo}[orbit]\nx = [0.0, 2.5]\n[integrator]\nmethod = \"dop853\"\nh = 0.05\n\
             t_final = 300.0\n[deviations]\nk = 1\nsets = 1\nseed = 1\n[[scheme]]\n\
             name = \"vm\"\nmethod = \"vm\"\nd0 = 1e-8\ntau = 1.0\n"
        )
    };
    let mut samples = Vec::new();
    for (name, modulo) in [
        ("raw", ""),
        ("wrapped", "modulo = [6.283185307179586, 0]\n"),
    ] {
        let config = d.join(format!("{name}.toml"));
        std::fs::write(&config, pendulum(modulo)).unwrap();
        let csv = d.join(format!("{name}.csv"));
        let plot = d.join(name);
        run_ok(&[
            "section",
            s(&config),
            "--sample-every",
            "1",
            "--crossings",
            "1000",
            "--csv",
            s(&csv),
            "--plot",
            s(&plot),
        ]);
        assert!(plot.join("section.svg").exists());
        samples.push(read_crossings(&csv, "q1,p1"));
    }
    let (raw, wrapped) = (&samples[0], &samples[1]);
    assert_eq!((raw.len(), wrapped.len()), (300, 300));
    // Unwrapped the angle spans some 70 periods and more: the angular speed p never falls
    // below sqrt(2 (2.125 - 1)) = 1.5 (at q = pi), so q(300) > 450 (measured 590).
    assert!(raw.last().unwrap().1[0] > 450.0, "{:?}", raw.last());
    for ((t, r), (t_w, w)) in raw.iter().zip(wrapped) {
        // The same orbit (the integration never wraps), its angle taken into [0, 2 pi): the
        // difference is a whole number of turns to the rounding of a remainder of q <~ 700,
        // 1e-13; the momentum is the same bits.
        assert_eq!(t, t_w);
        assert!((0.0..TAU).contains(&w[0]), "q1 = {}", w[0]);
        let turns = (r[0] - w[0]) / TAU;
        assert!((turns - turns.round()).abs() < 1e-12, "{r:?} {w:?}");
        assert_eq!(r[1], w[1]);
    }
    // Over 300 samples of a rotation with an irrational period the wrapped angle covers the
    // circle: the section spans one period, [0, 2 pi).
    let (lo, hi) = wrapped
        .iter()
        .fold((f64::MAX, f64::MIN), |(lo, hi), (_, w)| {
            (lo.min(w[0]), hi.max(w[0]))
        });
    assert!(lo < 0.1 && hi > TAU - 0.1, "{lo} {hi}");

    // The driven pendulum of Baker and Gollub (its angle x1 and the drive's phase x3 declared
    // periodic in the example), cut once per drive period by sin(x3) = 0 upward (x3 = 0 mod 2
    // pi): its chaotic orbit's angle fills the circle, written within one period.
    let config = write(d, "pendulum.toml", &example("driven-pendulum.toml"));
    let csv = d.join("pendulum.csv");
    run_ok(&[
        "section",
        s(&config),
        "--surface",
        "sin(x3)",
        "--crossings",
        "200",
        "--axes",
        "sin(x1), x2",
        "--csv",
        s(&csv),
        "--plot",
        s(&d.join("pendulum")),
    ]);
    // 200 of the 212 drive periods 2 pi / (2/3) = 9.42 in the example's t_final = 2000.
    let rows = read_crossings(&csv, "x1,x2,x3");
    assert_eq!(rows.len(), 200);
    for (_, x) in &rows {
        assert!(
            (0.0..TAU).contains(&x[0]) && (0.0..TAU).contains(&x[2]),
            "{x:?}"
        );
        // On the section: the drive's phase is 0 mod 2 pi, to the rounding of x3 ~ 2 pi k.
        assert!(x[2].sin().abs() < 1e-9, "{x:?}");
    }
    let spread = rows.iter().fold((f64::MAX, f64::MIN), |(lo, hi), (_, x)| {
        (lo.min(x[0]), hi.max(x[0]))
    });
    assert!(spread.1 - spread.0 > 5.0, "{spread:?}");
    assert!(d.join("pendulum/section.svg").exists());
}

#[test]
fn stroboscopic_section_samples_the_orbit_every_period() {
    // The Duffing example (t in its rhs) over 40 forcing periods T = 2 pi / omega, h = T / 100:
    // `--sample-every "2*pi/omega"` gives the state after every 100 steps, at the times
    // k * 100 h (= k T to rounding), and sampling every 2T gives every second of those states,
    // bit for bit: the samples are the run's own orbit, never interpolated.
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let mut duffing = example("duffing.toml");
    let period = 2.0 * PI / 1.2;
    duffing.integrator.t_final = 40.0 * period;
    let config = write(d, "duffing.toml", &duffing);
    let (one, two) = (d.join("one.csv"), d.join("two.csv"));
    for (every, csv) in [("2*pi/omega", &one), ("2 * (2*pi/omega)", &two)] {
        run_ok(&[
            "section",
            s(&config),
            "--sample-every",
            every,
            "--crossings",
            "1000",
            "--csv",
            s(csv),
        ]);
    }
    let (one, two) = (read_crossings(&one, "x1,x2"), read_crossings(&two, "x1,x2"));
    assert_eq!((one.len(), two.len()), (40, 20));
    let h = duffing.integrator.h.unwrap();
    for (k, (t, _)) in one.iter().enumerate() {
        assert_eq!(*t, ((k as u64 + 1) * 100) as f64 * h);
        assert!((t - (k + 1) as f64 * period).abs() < 1e-12 * t, "{t}");
    }
    for (k, sample) in two.iter().enumerate() {
        assert_eq!(sample, &one[2 * k + 1]);
    }
    // What it refuses, in one line naming the option, before writing anything.
    let csv = d.join("bad.csv");
    for (every, needle) in [
        (
            "1.0",
            "--sample-every: 1 is not a whole number of time steps",
        ),
        ("x1", "reads the state"),
        ("-period", "line 1"),
        ("0 * omega", "must be a positive number"),
        ("2*pi/omega +", "--sample-every: line 1, column 13"),
    ] {
        let out = chaoscope(&[
            "section",
            s(&config),
            "--sample-every",
            every,
            "--csv",
            s(&csv),
        ])
        .output()
        .unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(1), "{every}: {err}");
        assert!(err.contains(needle), "{every}: {err}");
        assert!(!csv.exists(), "{every}");
    }
}
