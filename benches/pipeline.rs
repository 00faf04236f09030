//! Must-show 5: sustained producer -> iceoryx2 -> recorder -> MCAP throughput, against the raw
//! MCAP writer alone and `dd` to the same disk. Prints one JSON document; no assertions.
//!
//! `cargo bench --bench pipeline` (set CHAOSCOPE_BENCH_SCALE=0.2 for a quick run).

use std::io::Cursor;
use std::path::Path;
use std::process::{Command, Stdio};
use std::time::Instant;

use chaoscope_recorder::file::{FileOptions, RecordingFile};
use chaoscope_schemas::config::{DeviationsConfig, SchemeConfig, paper};
use chaoscope_schemas::convert::DataMessage;
use chaoscope_schemas::proto::{ReferenceState, RunHeader, Scheme, SeparationSet};
use serde_json::{Value, json};

mod common;
use common::{CHAOSCOPE, scale};

/// FPUT-beta N = 501, k = 8, renormalized (and sampled) every step.
fn fput_config(t_final: f64) -> String {
    let n = 501;
    let q: Vec<String> = (1..=n)
        .map(|i| {
            format!(
                "{:.6}",
                0.5 * (std::f64::consts::PI * i as f64 / (n + 1) as f64).sin()
            )
        })
        .collect();
    let p = vec!["0.0"; n];
    format!(
        "[model]\nname = \"fput-beta\"\nn = {n}\nbeta = 1.0\n[orbit]\nq = [{}]\np = [{}]\n\
         [integrator]\nmethod = \"leapfrog\"\nh = 0.05\nt_final = {t_final}\n\
         [deviations]\nk = 8\nsets = 1\nseed = 3\n\
         [[scheme]]\nname = \"vm\"\nmethod = \"vm\"\nd0 = 1e-8\ntau = 0.05\n",
        q.join(", "),
        p.join(", ")
    )
}

/// The paper's HH orbit, VM and MPM, k = 4, sampled at every step (tau = h).
fn hh_config(t_final: f64) -> String {
    let tau = paper::HH_STEP;
    paper::henon_heiles(
        paper::HH_CHAOTIC_Q2,
        t_final,
        DeviationsConfig::random(4, 1, 1),
        vec![
            SchemeConfig::new("vm", "vm", 1e-8, tau),
            SchemeConfig::new("mpm", "mpm", 1e-8, tau),
        ],
    )
    .to_toml()
}

fn last_json_line(bytes: &[u8]) -> Value {
    let text = String::from_utf8_lossy(bytes);
    text.lines()
        .rev()
        .find_map(|l| serde_json::from_str(l).ok())
        .unwrap_or(Value::Null)
}

/// Producer and recorder as two processes; throughput over the producer's streaming time.
fn pipeline(name: &str, config: &str, dir: &Path) -> Value {
    let cfg = dir.join(format!("{name}.toml"));
    std::fs::write(&cfg, config).unwrap();
    let out = dir.join(format!("{name}.mcap"));
    let run = format!("bench-{name}-{}", std::process::id());
    let recorder = Command::new(CHAOSCOPE)
        .args(["record", "--run", &run, "--out", out.to_str().unwrap()])
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let start = Instant::now();
    let producer = Command::new(CHAOSCOPE)
        .args([
            "produce",
            cfg.to_str().unwrap(),
            "--run",
            &run,
            "--no-progress",
        ])
        .output()
        .unwrap();
    let recorder = recorder.wait_with_output().unwrap();
    let wall = start.elapsed().as_secs_f64();
    let p = last_json_line(&producer.stdout);
    let r = last_json_line(&recorder.stdout);
    let secs = p["seconds"].as_f64().unwrap_or(f64::NAN);
    let payload = p["payload_bytes"].as_f64().unwrap_or(0.0);
    let frames = p["frames"].as_f64().unwrap_or(0.0);
    let file = std::fs::metadata(&out).map(|m| m.len()).unwrap_or(0);
    json!({
        "case": name,
        "samples": p["samples"],
        "frames": p["frames"],
        "lost_messages": r["frames_missing"],
        "frames_recorded": r["frames_received"],
        "payload_MB": payload / 1e6,
        "file_MB": file as f64 / 1e6,
        "producer_seconds": secs,
        "wall_seconds_including_startup_and_finalize": wall,
        "payload_MB_per_s": payload / 1e6 / secs,
        "messages_per_s": frames / secs,
    })
}

/// The MCAP writer alone (in memory and to a file on the same disk), same message sizes.
fn raw_writer(name: &str, k: u32, dim: u32, messages: usize, dir: &Path) -> Value {
    let header = RunHeader {
        dim,
        k,
        schemes: vec![Scheme {
            name: "vm".into(),
            ..Default::default()
        }],
        ..Default::default()
    };
    let sep = |frame: u64| {
        DataMessage::Separations(SeparationSet {
            frame,
            k,
            dim,
            separations: (0..k * dim)
                .map(|i| (i as f64 * 0.618 + frame as f64).sin() * 1e-8)
                .collect(),
            stretch: vec![1.0001; k as usize],
            ..Default::default()
        })
    };
    let reference = DataMessage::Reference(ReferenceState {
        state: (0..dim).map(|i| (i as f64).cos()).collect(),
        ..Default::default()
    });
    let bytes_per_pair = ((k * dim + k + dim) * 8) as f64;
    let mut results = vec![];
    for target in ["memory", "file"] {
        let path = dir.join(format!("{name}-raw.mcap"));
        let start = Instant::now();
        let write_all = |w: &mut dyn FnMut(&DataMessage)| {
            for i in 0..messages as u64 {
                w(&reference);
                w(&sep(i));
            }
        };
        if target == "memory" {
            let mut f =
                RecordingFile::create(Cursor::new(Vec::new()), &header, &FileOptions::default())
                    .unwrap();
            write_all(&mut |m| f.write(m).unwrap());
            f.finish(&Default::default()).unwrap();
        } else {
            let file = std::fs::File::create(&path).unwrap();
            let mut f = RecordingFile::create(file, &header, &FileOptions::default()).unwrap();
            write_all(&mut |m| f.write(m).unwrap());
            f.finish(&Default::default()).unwrap().sync_all().unwrap();
        }
        let secs = start.elapsed().as_secs_f64();
        results.push(json!({
            "target": target,
            "payload_MB_per_s": bytes_per_pair * messages as f64 / 1e6 / secs,
            "messages_per_s": 2.0 * messages as f64 / secs,
        }));
    }
    json!({ "case": format!("{name} raw MCAP writer (zstd, synthetic data of the same shape)"), "results": results })
}

fn dd(dir: &Path) -> Value {
    let of = dir.join("dd.bin");
    let out = Command::new("dd")
        .args([
            "if=/dev/zero",
            &format!("of={}", of.display()),
            "bs=1M",
            "count=256",
            "conv=fdatasync",
        ])
        .output();
    let text = out
        .map(|o| String::from_utf8_lossy(&o.stderr).into_owned())
        .unwrap_or_default();
    let _ = std::fs::remove_file(&of);
    json!({ "case": "dd 256 MiB to the same disk (fdatasync)", "output": text.lines().last().unwrap_or("") })
}

fn main() {
    // `cargo bench` passes --bench; nothing else to parse.
    let dir = tempfile::tempdir_in(env!("CARGO_TARGET_TMPDIR")).unwrap();
    let s = scale();
    let fput = pipeline(
        "fput-n501-k8",
        &fput_config((50.0 * s).max(1.0)),
        dir.path(),
    );
    let hh = pipeline(
        "hh-every-step",
        &hh_config((1000.0 * s).max(10.0)),
        dir.path(),
    );
    let report = json!({
        "pipeline": [fput, hh],
        "raw_writer": [raw_writer("fput-n501-k8", 8, 1002, 2000, dir.path()), raw_writer("hh", 4, 4, 100_000, dir.path())],
        "dd": dd(dir.path()),
    });
    println!("{}", serde_json::to_string_pretty(&report).unwrap());
}
