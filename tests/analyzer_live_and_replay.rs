//! With real processes: the live monitor's final values equal the
//! offline analysis of the recording; a replay with other tau reproduces the recorded reference
//! orbit bit for bit and the paper's tau dependence of the MPM GALIs at t = 200; a replay with
//! other d0 copies only the MPM schemes and compares each with its original.

use std::io::{BufRead, BufReader};
use std::process::Stdio;
use std::time::Duration;

use crate::common::*;
use chaoscope_schemas::config::{DeviationsConfig, SchemeConfig, paper};
use serde_json::Value;

const LIMIT: Duration = Duration::from_secs(120);

/// The paper's chaotic Henon-Heiles run named `run`: VM and MPM at `d0`, and a QR scheme.
fn hh_run(run: &str, t_final: f64, sets: usize, d0: f64) -> String {
    let mut config = paper::henon_heiles(
        paper::HH_CHAOTIC_Q2,
        t_final,
        DeviationsConfig::random(4, sets, 4),
        vec![
            SchemeConfig::new("vm", "vm", d0, 1.0),
            SchemeConfig::new("mpm", "mpm", d0, 1.0),
            SchemeConfig::new("qr", "vm", 1.0, 1.0).with_orthonormalize("qr"),
        ],
    );
    config.run.name = Some(run.to_string());
    config.to_toml()
}

fn json_stdout(args: &[&str]) -> Value {
    let out = chaoscope(args).output().expect("run chaoscope");
    assert!(out.status.success(), "chaoscope {args:?} failed");
    let text = String::from_utf8(out.stdout).unwrap();
    serde_json::from_str(text.lines().last().expect("a line")).expect("JSON")
}

#[test]
fn monitor_json_lines_final_values_equal_offline_analyze() {
    let dir = tempfile::tempdir().unwrap();
    let run = unique_run("monitor");
    let config = dir.path().join("run.toml");
    std::fs::write(&config, hh_run(&run, 300.0, 4, 1e-8)).unwrap();
    let out = dir.path().join("run.mcap");

    // The producer waits for its recorder; the monitor attaches first so it sees every frame.
    let mut producer = Proc::spawn(chaoscope(&[
        "produce",
        config.to_str().unwrap(),
        "--no-progress",
        "--wait-timeout",
        "60",
    ]));
    let mut monitor_cmd = chaoscope(&[
        "monitor",
        &run,
        "--json-lines",
        "--interval",
        "0.1",
        "--wait-timeout",
        "60",
    ]);
    monitor_cmd.stderr(Stdio::piped());
    let mut monitor = Proc::spawn(monitor_cmd);
    let mut err = BufReader::new(monitor.0.stderr.take().unwrap());
    let mut line = String::new();
    err.read_line(&mut line).unwrap();
    assert!(line.contains("attached"), "monitor said: {line}");
    let mut recorder = Proc::spawn(record_cmd(&run, &out, &[]));
    assert!(recorder.wait(LIMIT).success());
    assert!(producer.wait(LIMIT).success());
    assert!(monitor.wait(LIMIT).success());
    let lines = monitor.stdout();
    let live: Value = serde_json::from_str(lines.lines().last().unwrap()).unwrap();
    assert_eq!(live["final"], true);
    assert_eq!(live["progress"]["status"], "completed");
    assert_eq!(live["progress"]["frames_lost"], 0, "the monitor kept up");
    assert_eq!(live["run"]["complete"], true);

    let offline = json_stdout(&["analyze", out.to_str().unwrap(), "--json"]);
    // Same code, same samples: equal to the last bit (JSON prints f64 round-trip exact).
    assert_eq!(live["run"], offline["run"]);
    assert_eq!(live["schemes"], offline["schemes"]);
    assert_eq!(offline["run"]["t"], 300.0);
    assert!(
        lines.lines().count() >= 2,
        "intermediate updates were streamed"
    );
}

#[test]
fn a_late_monitor_loses_no_frame_and_a_stopped_one_is_not_final() {
    // A monitor attached mid-run: what the producer published before it attached is counted
    // in frames_before_attach, never as lost; stopped by SIGINT while the run goes on, its last
    // line says "interrupted", not "final".
    let dir = tempfile::tempdir().unwrap();
    let run = unique_run("late-monitor");
    let config = dir.path().join("run.toml");
    // Long enough to outlive the test (it is stopped by a signal).
    std::fs::write(&config, hh_run(&run, 1e7, 1, 1e-8)).unwrap();
    let out = dir.path().join("run.mcap");
    let mut producer = Proc::spawn(chaoscope(&[
        "produce",
        config.to_str().unwrap(),
        "--no-progress",
        "--force",
        "--wait-timeout",
        "60",
    ]));
    let mut recorder = Proc::spawn(record_cmd(&run, &out, &[]));
    // Let the run publish for a while before the monitor comes.
    std::thread::sleep(Duration::from_millis(1500));
    let mut monitor_cmd = chaoscope(&[
        "monitor",
        &run,
        "--json-lines",
        "--interval",
        "0.1",
        "--wait-timeout",
        "60",
    ]);
    monitor_cmd.stderr(Stdio::piped());
    let mut monitor = Proc::spawn(monitor_cmd);
    let mut err = BufReader::new(monitor.0.stderr.take().unwrap());
    let mut line = String::new();
    err.read_line(&mut line).unwrap();
    assert!(line.contains("attached"), "monitor said: {line}");
    let mut stdout = BufReader::new(monitor.0.stdout.take().unwrap());
    let mut first = String::new();
    stdout.read_line(&mut first).unwrap();
    let first: Value = serde_json::from_str(&first).unwrap();
    assert_eq!(first["final"], false);
    // The run published at least one frame in 1.5 s before the monitor came; just attached,
    // it has not fallen behind (a monitor's buffer holds far more than 0.1 s of this run).
    assert!(
        first["progress"]["frames_before_attach"].as_u64().unwrap() > 0,
        "{first}"
    );
    assert_eq!(first["progress"]["frames_lost"], 0, "{first}");
    monitor.signal(libc::SIGINT);
    let status = monitor.wait(LIMIT);
    assert_eq!(status.code(), Some(130));
    let mut rest = String::new();
    std::io::Read::read_to_string(&mut stdout, &mut rest).unwrap();
    let last: Value = serde_json::from_str(rest.lines().last().unwrap()).unwrap();
    assert_eq!(last["final"], false, "{last}");
    assert_eq!(last["interrupted"], true, "{last}");
    assert_eq!(last["detached"], false, "{last}");
    assert!(last["progress"]["status"].is_null(), "{last}");
    assert_eq!(
        last["run"]["complete"], false,
        "it saw only part of the run"
    );
    let mut said = String::new();
    std::io::Read::read_to_string(&mut err, &mut said).unwrap();
    assert!(said.contains("published before it attached"), "{said}");
    producer.signal(libc::SIGINT);
    producer.wait(LIMIT);
    recorder.wait(LIMIT);
}

fn gali(report: &Value, scheme: &str, j: usize) -> f64 {
    let s = report["schemes"]
        .as_array()
        .unwrap()
        .iter()
        .find(|s| s["name"] == scheme)
        .unwrap_or_else(|| panic!("scheme {scheme}"));
    s["gali"][j.to_string()]["log10_mean"].as_f64().unwrap()
}

/// Every new indicator for every scheme of a replay's `analyze --json`: FLI, OFLI (the
/// Henon-Heiles vector field rebuilt from the recording's config), MEGNO and its mean over the
/// sets; the 0-1 test where the scheme has at least 1000 renormalizations to sample the orbit
/// at (tau <= 0.2 here, t = 200), and where not, the reason. The original schemes' values equal the
/// recording's to the last bit (the same orbit and separations: replay changes none of their
/// numbers).
fn assert_every_indicator_and_the_originals_unchanged(report: &Value, recorded: &Value) {
    for s in report["schemes"].as_array().unwrap() {
        let name = s["name"].as_str().unwrap();
        for field in ["fli", "ofli", "megno", "megno_mean"] {
            assert!(s[field]["mean"].is_f64(), "{name}: {field} = {}", s[field]);
            assert!(s[field]["std"].is_f64(), "{name}: {field} = {}", s[field]);
        }
        let tau = s["tau"].as_f64().unwrap();
        if tau <= 0.2 {
            let k = s["zero_one_k"].as_f64().unwrap();
            assert!((-1.0..=1.0).contains(&k), "{name}: K = {k}");
        } else {
            assert!(
                s["zero_one_k"]["unavailable"]
                    .as_str()
                    .unwrap()
                    .contains("too short for the 0-1 test"),
                "{name}: {}",
                s["zero_one_k"]
            );
        }
        if let Some(orig) = recorded["schemes"]
            .as_array()
            .unwrap()
            .iter()
            .find(|o| o["name"] == s["name"])
        {
            for field in ["fli", "ofli", "megno", "megno_mean", "zero_one_k"] {
                assert_eq!(s[field], orig[field], "{name}: {field}");
            }
        }
    }
}

#[test]
fn replay_with_other_tau_is_bit_identical_and_follows_the_paper_at_t_200() {
    let dir = tempfile::tempdir().unwrap();
    let run = unique_run("replay");
    let config = dir.path().join("run.toml");
    // The paper's Fig. 7 setting: HH chaotic orbit, h = 0.01, d0 = 1e-9, t = 200.
    std::fs::write(&config, hh_run(&run, 200.0, 40, 1e-9)).unwrap();
    let rec = dir.path().join("rec.mcap");
    let rep = dir.path().join("rep.mcap");
    let status = chaoscope(&[
        "run",
        config.to_str().unwrap(),
        "--out",
        rec.to_str().unwrap(),
    ])
    .stdout(Stdio::null())
    .status()
    .unwrap();
    assert!(status.success());

    let outcome = json_stdout(&[
        "replay",
        rec.to_str().unwrap(),
        "--tau",
        "0.1",
        "--tau",
        "1",
        "--tau",
        "10",
        "--tau",
        "100",
        "--out",
        rep.to_str().unwrap(),
        "--json",
    ]);
    // Every recorded reference state (t = 0, 1, ..., 200) and every recorded separation set.
    assert_eq!(outcome["reference_states_compared"], 201);
    assert_eq!(outcome["reference_states_identical"], 201);
    assert_eq!(outcome["reference_states_not_sampled"], 0);
    assert_eq!(outcome["separation_sets_compared"], 201 * 3 * 40);
    assert_eq!(
        outcome["separation_sets_identical"],
        outcome["separation_sets_compared"]
    );

    let report = json_stdout(&["analyze", rep.to_str().unwrap(), "--json", "--at", "200"]);
    let recorded = json_stdout(&["analyze", rec.to_str().unwrap(), "--json", "--at", "200"]);
    assert_every_indicator_and_the_originals_unchanged(&report, &recorded);
    for j in 2..=4 {
        let (m01, m1, m10, m100) = (
            gali(&report, "mpm-tau0.1", j),
            gali(&report, "mpm", j),
            gali(&report, "mpm-tau10", j),
            gali(&report, "mpm-tau100", j),
        );
        eprintln!(
            "GALI_{j} (log10 geometric mean over 40 sets) tau = 0.1: {m01:.3}, 1: {m1:.3}, \
             10: {m10:.3}, 100: {m100:.3}; VM {:.3}",
            gali(&report, "vm", j)
        );
        // VM: the tangent dynamics is linear, rescaling changes nothing but rounding.
        for t in ["vm-tau0.1", "vm-tau10", "vm-tau100"] {
            assert!(
                (gali(&report, t, j) - gali(&report, "vm", j)).abs() < 0.01,
                "{t}"
            );
        }
        // MPM, tau <= 1: flat. The same 40 direction sets are used for every tau, so the
        // difference of the means is far below the set-to-set spread (~0.5 decades).
        assert!((m01 - m1).abs() < 0.15, "GALI_{j}: tau 0.1 vs 1");
        if j >= 3 {
            // Above tau ~ 1 the values change: GALI_3 and GALI_4 sit on MPM's rounding floor
            // (numerics.md), which depends on how often the nearby orbits are reset.
            assert!(
                (m100 - m1).abs() > 3.0 * (m01 - m1).abs().max(0.1),
                "GALI_{j}: tau 100 vs 1"
            );
        }
    }

    // Another d0 on the same recording: MPM schemes are copied per d0, VM ones are not (their
    // tangent vectors evolve linearly, d0 only scales them), and the replay prints each new
    // scheme against its original.
    let rep_d0 = dir.path().join("rep-d0.mcap");
    let outcome = json_stdout(&[
        "replay",
        rec.to_str().unwrap(),
        "--d0",
        "1e-7",
        "--d0",
        "1e-11",
        "--out",
        rep_d0.to_str().unwrap(),
        "--json",
    ]);
    assert_eq!(
        outcome["schemes"],
        serde_json::json!(["vm", "mpm", "qr", "mpm-d01e-7", "mpm-d01e-11"])
    );
    assert_eq!(outcome["reference_states_identical"], 201);
    assert_eq!(
        outcome["separation_sets_identical"],
        outcome["separation_sets_compared"]
    );
    let report = json_stdout(&["analyze", rep_d0.to_str().unwrap(), "--json", "--at", "200"]);
    assert_every_indicator_and_the_originals_unchanged(&report, &recorded);
    let comparison = outcome["comparison"].as_array().unwrap();
    assert_eq!(comparison.len(), 2, "{comparison:?}");
    let mpm = report["schemes"].as_array().unwrap()[1]["mle"]
        .as_f64()
        .unwrap();
    for c in comparison {
        let name = c["scheme"].as_str().unwrap();
        assert_eq!(c["of"], "mpm", "{name}");
        let s = report["schemes"]
            .as_array()
            .unwrap()
            .iter()
            .find(|s| s["name"] == name)
            .unwrap();
        // The comparison is the analysis `analyze` runs, at the end (t = 200).
        assert_eq!(c["mle"], s["mle"], "{name}");
        let delta = c["mle_delta"].as_f64().unwrap();
        assert_eq!(delta, s["mle"].as_f64().unwrap() - mpm, "{name}");
        eprintln!("{name}: {c}");
        // MPM's nearby orbits stay in the linear regime for d0 from 1e-11 to 1e-7 (the paper's
        // Fig. 5): the finite-time MLE moves by the nonlinearity, O(d0), and by the rounding
        // floor eps / d0 ~ 1e-5 per renormalization, averaging out: far below 1 % of it.
        assert!(
            delta.abs() < 0.01 * mpm,
            "{name}: MLE delta {delta}, MLE {mpm}"
        );
    }
}

/// Every leaf of two JSON values that differs, as `path`.
fn differing_paths(a: &Value, b: &Value, path: &str, out: &mut Vec<String>) {
    match (a, b) {
        (Value::Object(x), Value::Object(y)) => {
            for key in x.keys().chain(y.keys().filter(|k| !x.contains_key(*k))) {
                let (u, v) = (x.get(key), y.get(key));
                match (u, v) {
                    (Some(u), Some(v)) => differing_paths(u, v, &format!("{path}.{key}"), out),
                    _ => out.push(format!("{path}.{key}")),
                }
            }
        }
        (Value::Array(x), Value::Array(y)) if x.len() == y.len() => {
            for (i, (u, v)) in x.iter().zip(y).enumerate() {
                differing_paths(u, v, &format!("{path}[{i}]"), out);
            }
        }
        _ if a != b => out.push(path.to_string()),
        _ => {}
    }
}

/// `analyze --from T`: the finite-time exponents average the stretching
/// from T on, and nothing else in the report changes (GALI, SALI, FLI, MEGNO, the 0-1 test, the
/// verdict). The exponents from T follow from the whole run's at T and at the end:
/// `(t l(t) - T l(T)) / (t - T)`, the same sums of logarithms, to rounding.
#[test]
fn analyze_from_t_changes_the_averaged_exponents_and_nothing_else() {
    let dir = tempfile::tempdir().unwrap();
    let run = unique_run("from");
    let config = dir.path().join("run.toml");
    std::fs::write(&config, hh_run(&run, 200.0, 3, 1e-8)).unwrap();
    let rec = dir.path().join("rec.mcap");
    let status = chaoscope(&[
        "run",
        config.to_str().unwrap(),
        "--out",
        rec.to_str().unwrap(),
    ])
    .stdout(Stdio::null())
    .status()
    .unwrap();
    assert!(status.success());
    let file = rec.to_str().unwrap();
    let whole = json_stdout(&["analyze", file, "--json"]);
    let at_50 = json_stdout(&["analyze", file, "--json", "--at", "50"]);
    let from = json_stdout(&["analyze", file, "--json", "--from", "50"]);
    assert_eq!(from["run"]["exponents_from"], 50.0);
    let mut changed = Vec::new();
    differing_paths(&whole, &from, "", &mut changed);
    let exponent_field = |p: &str| {
        p == ".run.exponents_from"
            || p.ends_with(".mle")
            || p.contains(".lyapunov[")
            || p.contains(".lyapunov_std[")
            || p.ends_with(".lyapunov_sum")
            || p.ends_with(".vs_vm.mle_delta")
    };
    let others: Vec<&String> = changed.iter().filter(|p| !exponent_field(p)).collect();
    assert!(others.is_empty(), "--from changed {others:?}");
    assert!(
        changed.iter().any(|p| p.contains("schemes[2].lyapunov[3]")),
        "the QR spectrum did not change: {changed:?}"
    );
    for (si, name) in ["vm", "mpm", "qr"].iter().enumerate() {
        let l = |r: &Value, i: usize| r["schemes"][si]["lyapunov"][i].as_f64().unwrap();
        let n = whole["schemes"][si]["lyapunov"].as_array().unwrap().len();
        for i in 0..n {
            let want = (200.0 * l(&whole, i) - 50.0 * l(&at_50, i)) / 150.0;
            let got = l(&from, i);
            // Sums of ~200 logarithms of size ~0.1 each, divided and multiplied back: rounding
            // of order 1e-15 relative to the sums, so 1e-12 absolute is generous and still far
            // below any transient effect (the exponents move by ~1e-3 here).
            assert!(
                (got - want).abs() < 1e-12,
                "{name} l_{}: from 50 {got}, from the whole run's {want}",
                i + 1
            );
        }
    }
}

#[test]
fn replay_of_a_non_autonomous_run_is_bit_identical() {
    // The driven Duffing oscillator with `t` in its rhs (every run starts at t = 0, and a replay
    // rebuilds the system from the recorded config and steps it at the same times n h): every
    // reference state and separation set of the replay equals the recording's bit for bit.
    let dir = tempfile::tempdir().unwrap();
    let run = unique_run("replay-duffing");
    let config = dir.path().join("run.toml");
    let text = std::fs::read_to_string(
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("examples/models/duffing.toml"),
    )
    .unwrap()
    .replace("name = \"duffing\"", &format!("name = \"{run}\""))
    .replace(
        "t_final = 104719.75511965978",
        "t_final = 52.35987755982989",
    );
    std::fs::write(&config, text).unwrap();
    let rec = dir.path().join("rec.mcap");
    let rep = dir.path().join("rep.mcap");
    let status = chaoscope(&[
        "run",
        config.to_str().unwrap(),
        "--out",
        rec.to_str().unwrap(),
    ])
    .stdout(Stdio::null())
    .status()
    .unwrap();
    assert!(status.success());
    let outcome = json_stdout(&[
        "replay",
        rec.to_str().unwrap(),
        "--tau",
        "10.471975511965978",
        "--out",
        rep.to_str().unwrap(),
        "--json",
    ]);
    // 10 periods, renormalized once per period by both schemes: 11 states with t = 0.
    assert_eq!(outcome["reference_states_compared"], 11);
    assert_eq!(outcome["reference_states_identical"], 11);
    assert_eq!(outcome["separation_sets_compared"], 11 * 2);
    assert_eq!(
        outcome["separation_sets_identical"],
        outcome["separation_sets_compared"]
    );
}

/// `[analysis] zero_one_observable` travels with the recording: `analyze` of the recorded run
/// rebuilds the system from the config the file carries and observes the same expression as
/// the run computed in process (the same K to the last bit), which differs from the generic
/// observable's.
#[test]
fn the_zero_one_observable_travels_with_the_recording() {
    let dir = tempfile::tempdir().unwrap();
    // The paper's chaotic Henon-Heiles orbit to t = 1000 at tau = 1: 1001 samples, enough for K.
    let k_of = |name: &str, analysis: &str| -> (f64, f64) {
        let text = hh_run(&unique_run(name), 1000.0, 1, 1e-8) + analysis;
        let config = dir.path().join(format!("{name}.toml"));
        std::fs::write(&config, &text).unwrap();
        let rec = dir.path().join(format!("{name}.mcap"));
        let status = chaoscope(&[
            "run",
            config.to_str().unwrap(),
            "--out",
            rec.to_str().unwrap(),
        ])
        .stdout(Stdio::null())
        .status()
        .unwrap();
        assert!(status.success());
        let report = json_stdout(&["analyze", rec.to_str().unwrap(), "--json"]);
        let vm = report["schemes"]
            .as_array()
            .unwrap()
            .iter()
            .find(|s| s["name"] == "vm")
            .unwrap();
        let recorded = vm["zero_one_k"].as_f64().unwrap_or_else(|| panic!("{vm}"));
        let cfg = chaoscope_schemas::config::RunConfig::from_toml(&text).unwrap();
        let options = chaoscope_analyzer::analysis::AnalysisOptions::default();
        let a = chaoscope_app::inprocess::analyze_config(&cfg, &options, |_| {}).unwrap();
        let in_process = a
            .report()
            .scheme("vm")
            .unwrap()
            .indicators
            .value("zero_one_k")
            .unwrap();
        (recorded, in_process)
    };
    let (recorded, in_process) = k_of("zo-q2", "\n[analysis]\nzero_one_observable = \"q2\"\n");
    assert_eq!(
        recorded.to_bits(),
        in_process.to_bits(),
        "{recorded} {in_process}"
    );
    let (generic, _) = k_of("zo-generic", "");
    assert_ne!(recorded, generic, "the key changes the observable");
}
