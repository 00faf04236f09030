//! `chaoscope analyze` streams a recording, so its memory does not grow
//! with the file. Writes a ~1 GB recording (in process, through the recorder's MCAP layout),
//! analyzes it in a child process, and prints peak RSS (the child's `ru_maxrss`) and MB/s as
//! one JSON document; exits non-zero if the peak exceeds 200 MB.
//!
//! `cargo bench --bench analyze_memory` (CHAOSCOPE_BENCH_SCALE=0.1 for a ~100 MB quick run).
//! Not part of CI: it writes a gigabyte.

use std::process::{Command, Stdio};
use std::time::Instant;

use chaoscope_analyzer::write::SampleWriter;
use chaoscope_dynamics::engine::Engine;
use chaoscope_dynamics::spec::RunSpec;
use chaoscope_schemas::config::RunConfig;
use serde_json::json;

mod common;
use common::{CHAOSCOPE, scale};

/// FPUT-beta N = 31, k = 8, VM and MPM, 32 sets, renormalized every step: 64 frames of
/// 8 x 62 + 8 doubles (4 kB) per sample, ~270 kB per sample.
fn config(t_final: f64) -> String {
    format!(
        r#"
[run]
name = "analyze-memory"
[model]
name = "fput-beta"
n = 31
beta = 1.0
[orbit]
preset = "spo1"
energy = 20.0
[integrator]
method = "aba864"
h = 0.05
t_final = {t_final}
[deviations]
k = 8
sets = 32
seed = 1
[[scheme]]
name = "vm"
method = "vm"
d0 = 1e-8
tau = 0.05
[[scheme]]
name = "mpm"
method = "mpm"
d0 = 1e-8
tau = 0.05
"#
    )
}

fn max_rss_children_kb() -> i64 {
    let mut usage: libc::rusage = unsafe { std::mem::zeroed() };
    // SAFETY: getrusage fills the struct we own.
    unsafe { libc::getrusage(libc::RUSAGE_CHILDREN, &mut usage) };
    usage.ru_maxrss
}

fn main() {
    // ~1 GB at scale 1: 3700 samples x ~270 kB.
    let t_final = (190.0 * scale()).max(1.0).round();
    let dir = std::env::temp_dir().join(format!("chaoscope-analyze-memory-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("big.mcap");

    let cfg = RunConfig::from_toml(&config(t_final)).unwrap();
    let spec = RunSpec::from_config(&cfg).unwrap();
    let header = chaoscope_dynamics::header::run_header("analyze-memory", &cfg, &spec);
    let start = Instant::now();
    let mut writer = SampleWriter::create(&path, &header).unwrap();
    let mut engine = Engine::new(spec);
    while let Some(s) = engine.next_sample().unwrap() {
        writer.write(&s).unwrap();
    }
    writer.finish("benchmark").unwrap();
    let write_s = start.elapsed().as_secs_f64();
    let bytes = std::fs::metadata(&path).unwrap().len();

    let start = Instant::now();
    let out = Command::new(CHAOSCOPE)
        .args(["analyze", path.to_str().unwrap(), "--json"])
        .stderr(Stdio::inherit())
        .output()
        .unwrap();
    let secs = start.elapsed().as_secs_f64();
    assert!(out.status.success(), "analyze failed");
    let report: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let rss_mb = max_rss_children_kb() as f64 / 1024.0;
    let mb = bytes as f64 / 1e6;
    println!(
        "{}",
        serde_json::to_string_pretty(&json!({
            "bench": "analyze_memory",
            "file_mb": mb,
            "write_seconds": write_s,
            "samples": report["run"]["samples"],
            "analyze_seconds": secs,
            "analyze_mb_per_s": mb / secs,
            "analyze_peak_rss_mb": rss_mb,
            "limit_mb": 200,
        }))
        .unwrap()
    );
    let _ = std::fs::remove_dir_all(&dir);
    if rss_mb > 200.0 {
        eprintln!("peak RSS {rss_mb:.1} MB exceeds 200 MB");
        std::process::exit(1);
    }
}
