//! What Foxglove and Lichtblick see, checked with their own TypeScript libraries under Node
//! (tests/node/: package.json and package-lock.json; `npm ci --prefix tests/node` installs them):
//! - `@mcap/core` + `@mcap/support` + `@mcap/nodejs` + `protobufjs` decode every message of every
//!   channel of a recording and of a map file from the schemas the files carry, and the
//!   recording's indicators channel equals `chaoscope analyze --json` (`check_mcap.js`);
//! - `@foxglove/ws-protocol`'s client receives a live run from `chaoscope monitor --foxglove`
//!   (`live_client.js`).

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::sync::mpsc;
use std::time::Duration;

use crate::common::*;
use chaoscope_schemas::config::{DeviationsConfig, SchemeConfig, paper};
use serde_json::Value;

const LIMIT: Duration = Duration::from_secs(120);

/// tests/node, with its packages installed; fails with the command that installs them.
fn node_dir() -> PathBuf {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/node");
    for package in [
        "@mcap/core",
        "@mcap/nodejs",
        "@mcap/support",
        "protobufjs",
        "@foxglove/ws-protocol",
        "ws",
    ] {
        assert!(
            dir.join("node_modules").join(package).is_dir(),
            "tests/node/node_modules/{package} is missing: run `npm ci --prefix tests/node` \
             (Node 20 or newer and npm) before the tests"
        );
    }
    dir
}

fn node(script: &str) -> Command {
    let mut c = Command::new("node");
    c.arg(node_dir().join(script));
    c
}

/// Runs `check_mcap.js` on `file` (with an `analyze --json` report to compare, if given) and
/// returns its counts per topic.
fn check_with_node(file: &Path, report: Option<&Path>) -> Value {
    let mut c = node("check_mcap.js");
    c.arg(file);
    if let Some(r) = report {
        c.arg(r);
    }
    let out = c.output().expect("node (Node 20 or newer) on PATH");
    assert!(
        out.status.success(),
        "Foxglove's reading stack failed on {}: {}",
        file.display(),
        String::from_utf8_lossy(&out.stderr)
    );
    let text = String::from_utf8(out.stdout).unwrap();
    serde_json::from_str(text.lines().last().expect("a line")).expect("JSON")
}

fn hh_run(run: &str, t_final: f64) -> String {
    let mut config = paper::henon_heiles(
        paper::HH_CHAOTIC_Q2,
        t_final,
        DeviationsConfig::random(3, 2, 7),
        vec![
            SchemeConfig::new("vm", "vm", 1e-8, 1.0),
            SchemeConfig::new("mpm-qr", "mpm", 1e-8, 1.0).with_orthonormalize("qr"),
        ],
    );
    config.run.name = Some(run.to_string());
    config.to_toml()
}

#[test]
fn foxglove_reading_stack_decodes_every_message_of_a_recording_and_a_map() {
    node_dir();
    let dir = tempfile::tempdir().unwrap();
    let config = write_config(dir.path(), &hh_run(&unique_run("node-read"), 30.0));
    let file = dir.path().join("run.mcap");
    let out = chaoscope(&[
        "run",
        config.to_str().unwrap(),
        "--out",
        file.to_str().unwrap(),
    ])
    .output()
    .expect("chaoscope run");
    assert!(out.status.success(), "chaoscope run failed");
    let analyzed = chaoscope(&["analyze", file.to_str().unwrap(), "--json"])
        .output()
        .expect("chaoscope analyze");
    assert!(analyzed.status.success());
    let report = dir.path().join("analyze.json");
    std::fs::write(&report, &analyzed.stdout).unwrap();

    let counts = check_with_node(&file, Some(&report));
    let rec = read_recording(&file);
    let total = 1 + rec.frames.len() + rec.indicators.len() + 1;
    assert_eq!(counts["total"].as_u64(), Some(total as u64), "{counts}");
    // 31 samples (t = 0..30, tau = 1): one indicators message per scheme and sample.
    for scheme in ["vm", "mpm-qr"] {
        let topic = format!("/chaoscope/indicators/{scheme}");
        assert_eq!(counts["topics"][&topic].as_u64(), Some(31), "{counts}");
    }

    let map = dir.path().join("map.mcap");
    let map_config = dir.path().join("map.toml");
    std::fs::write(&map_config, include_str!("data/hh-map-small.toml")).unwrap();
    let out = chaoscope(&[
        "map",
        map_config.to_str().unwrap(),
        "--out",
        map.to_str().unwrap(),
        "--no-progress",
    ])
    .output()
    .expect("chaoscope map");
    assert!(out.status.success(), "chaoscope map failed");
    let counts = check_with_node(&map, None);
    // The header and the 9 x 7 grid points.
    assert_eq!(
        counts["topics"]["/chaoscope/map/header"].as_u64(),
        Some(1),
        "{counts}"
    );
    assert_eq!(
        counts["topics"]["/chaoscope/map/points"].as_u64(),
        Some(63),
        "{counts}"
    );
}

/// Reads a child's lines on a thread (so its pipe never fills) and hands them over.
fn lines(pipe: impl std::io::Read + Send + 'static) -> mpsc::Receiver<String> {
    let (tx, rx) = mpsc::channel();
    std::thread::spawn(move || {
        for line in BufReader::new(pipe).lines().map_while(Result::ok) {
            if tx.send(line).is_err() {
                break;
            }
        }
    });
    rx
}

fn wait_line(rx: &mpsc::Receiver<String>, what: &str, found: impl Fn(&str) -> bool) -> String {
    loop {
        match rx.recv_timeout(Duration::from_secs(60)) {
            Ok(line) if found(&line) => return line,
            Ok(_) => {}
            Err(e) => panic!("waiting for {what}: {e}"),
        }
    }
}

#[test]
fn foxglove_client_receives_the_run_live_from_monitor_foxglove() {
    node_dir();
    let dir = tempfile::tempdir().unwrap();
    let run = unique_run("foxglove-live");
    let config = write_config(dir.path(), &hh_run(&run, 200.0));
    let file = dir.path().join("run.mcap");

    // The producer waits for its recorder, which starts once the client has subscribed: the
    // client then sees the run from its first sample.
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
        "--plain",
        "--foxglove",
        "127.0.0.1:0",
        "--wait-timeout",
        "60",
    ]);
    monitor_cmd.stdout(Stdio::null()).stderr(Stdio::piped());
    let mut monitor = Proc::spawn(monitor_cmd);
    let monitor_err = lines(monitor.0.stderr.take().unwrap());
    let serving = wait_line(&monitor_err, "the monitor's address", |l| {
        l.contains("ws://")
    });
    let url = serving[serving.find("ws://").unwrap()..].trim().to_string();

    let topics = [
        "/chaoscope/reference",
        "/chaoscope/indicators/vm",
        "/chaoscope/indicators/mpm-qr",
    ];
    let mut client_cmd = node("live_client.js");
    client_cmd.arg(&url).args(topics).stdout(Stdio::piped());
    let mut client = Proc::spawn(client_cmd);
    let client_out = lines(client.0.stdout.take().unwrap());
    wait_line(&client_out, "the client's subscriptions", |l| {
        l.contains("subscribed") && topics.iter().all(|t| l.contains(&format!("\"{t}\"")))
    });

    let mut recorder = Proc::spawn(record_cmd(&run, &file, &[]));
    assert!(recorder.wait(LIMIT).success(), "recorder failed");
    assert!(producer.wait(LIMIT).success(), "producer failed");
    assert!(monitor.wait(LIMIT).success(), "monitor failed");
    assert!(
        client.wait(LIMIT).success(),
        "the Foxglove client failed (its stderr above)"
    );
    let last = wait_line(&client_out, "the client's report", |l| {
        l.contains("\"topics\"")
    });
    let report: Value = serde_json::from_str(&last).unwrap();
    // Live delivery is lossy by design (the monitor never slows the run), so every channel must
    // carry messages, and never more than the run has: 201 samples (t = 0..200, tau = 1).
    for topic in topics {
        let n = report["topics"][topic]["messages"].as_u64().unwrap_or(0);
        assert!((1..=201).contains(&n), "{topic}: {n} messages: {report}");
        let t = report["topics"][topic]["last"]["t"].as_f64().unwrap();
        assert!(t > 0.0 && t <= 200.0, "{topic}: last t = {t}");
    }
    let gali = &report["topics"]["/chaoscope/indicators/vm"]["last"]["gali"];
    assert_eq!(
        gali.as_array().map(Vec::len),
        Some(2),
        "GALI_2 and GALI_3: {gali}"
    );
}

#[test]
fn monitor_foxglove_says_that_any_local_user_can_read_the_run() {
    // No node needed: the warning comes when the server starts, before any run is found.
    let out = chaoscope_captured(&[
        "monitor",
        &unique_run("foxglove-nobody"),
        "--plain",
        "--foxglove",
        "127.0.0.1:0",
        "--wait-timeout",
        "0.2",
    ])
    .output()
    .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    let warnings: Vec<&str> = stderr.lines().filter(|l| l.contains("warning")).collect();
    assert_eq!(warnings.len(), 1, "{stderr}");
    assert!(
        warnings[0].contains("no access control")
            && warnings[0].contains("any user of this machine")
            && warnings[0].contains("can connect to it and read this run"),
        "{}",
        warnings[0]
    );
}
