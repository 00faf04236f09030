//! Must-show 3 and 4: crashes and signals leave valid data; a slow recorder loses nothing.

mod common;

use std::path::Path;
use std::time::{Duration, Instant};

use chaoscope_bus::{self as bus, Liveness};
use chaoscope_schemas::names;
use common::*;

const LIMIT: Duration = Duration::from_secs(60);

/// Waits until `path` holds at least `bytes` bytes (completed chunks are on disk).
fn wait_for_size(path: &Path, bytes: u64) {
    let start = Instant::now();
    while std::fs::metadata(path).map(|m| m.len()).unwrap_or(0) < bytes {
        assert!(
            start.elapsed() < LIMIT,
            "{} never reached {bytes} bytes",
            path.display()
        );
        std::thread::sleep(Duration::from_millis(20));
    }
}

fn produce_cmd(run: &str, config: &Path) -> std::process::Command {
    chaoscope(&[
        "produce",
        config.to_str().unwrap(),
        "--run",
        run,
        "--no-progress",
        "--wait-timeout",
        "60",
    ])
}

#[test]
fn kill_9_of_the_recorder_keeps_every_completed_chunk_and_recover_salvages_it() {
    let dir = tempfile::tempdir().unwrap();
    let text = hh_config(1e5, 0.01).to_toml(); // far longer than the test lasts
    let config = write_config(dir.path(), &text);
    let broken = dir.path().join("broken.mcap");
    let run = unique_run("kill-recorder");
    let mut recorder = Proc::spawn(record_cmd(
        &run,
        &broken,
        &["--chunk-size", "65536", "--compression", "lz4"],
    ));
    let mut producer = Proc::spawn(produce_cmd(&run, &config));
    wait_for_size(&broken, 400_000);
    recorder.signal(libc::SIGKILL);
    recorder.wait(LIMIT);

    // The producer must not hang on its dead recorder: it still stops cleanly on SIGINT.
    std::thread::sleep(Duration::from_millis(300));
    producer.signal(libc::SIGINT);
    assert_eq!(
        producer.wait(LIMIT).code(),
        Some(130),
        "producer should report an interrupted run"
    );

    // The killed file has no summary; standard readers of the indexed layout reject it.
    let bytes = std::fs::read(&broken).unwrap();
    assert!(mcap::Summary::read(&bytes).is_err() || mcap::Summary::read(&bytes).unwrap().is_none());

    let fixed = dir.path().join("fixed.mcap");
    let out = std::process::Command::new(CHAOSCOPE)
        .args([
            "recover",
            broken.to_str().unwrap(),
            "--out",
            fixed.to_str().unwrap(),
        ])
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let rec = read_recording(&fixed);
    assert!(rec.header.is_some(), "the run header survives");
    assert!(
        rec.references.len() > 100,
        "only {} samples salvaged",
        rec.references.len()
    );
    assert_contiguous(&rec.frames);
    let expected = compute(&text, Some(rec.references.len() + 1));
    assert_bit_identical(&rec, &expected);
    let summary = mcap::Summary::read(&std::fs::read(&fixed).unwrap())
        .unwrap()
        .expect("indexed");
    assert!(!summary.chunk_indexes.is_empty());
}

#[test]
fn kill_9_of_the_producer_makes_the_recorder_finalize_an_interrupted_file() {
    let dir = tempfile::tempdir().unwrap();
    let text = hh_config(1e5, 0.01).to_toml();
    let config = write_config(dir.path(), &text);
    let out = dir.path().join("run.mcap");
    let run = unique_run("kill-producer");
    let mut recorder = Proc::spawn(record_cmd(&run, &out, &["--chunk-size", "65536"]));
    let mut producer = Proc::spawn(produce_cmd(&run, &config));
    wait_for_size(&out, 200_000);
    producer.signal(libc::SIGKILL);
    producer.wait(LIMIT);
    assert!(
        recorder.wait(LIMIT).success(),
        "recorder must finalize, not fail"
    );

    let rec = read_recording(&out);
    let summary = rec.recording.as_ref().expect("recording summary");
    assert_eq!(summary.finalized_by, "producer-died");
    assert_eq!(summary.run_status, "interrupted");
    assert_eq!(summary.frames_missing, 0);
    assert!(rec.end.is_none());
    assert_contiguous(&rec.frames);
    let expected = compute(&text, Some(rec.references.len() + 1));
    assert_bit_identical(&rec, &expected);
    // The dead producer's shared memory was cleaned up.
    assert_eq!(
        bus::node_liveness(&names::producer_node_name(&run)),
        Liveness::Absent
    );
}

#[test]
fn sigint_to_chaoscope_run_ends_both_processes_with_a_valid_file() {
    let dir = tempfile::tempdir().unwrap();
    let config = write_config(dir.path(), &hh_config(1e5, 0.01).to_toml());
    let out = dir.path().join("run.mcap");
    let run = unique_run("sigint");
    let mut front = Proc::spawn(chaoscope(&[
        "run",
        config.to_str().unwrap(),
        "--run",
        &run,
        "--out",
        out.to_str().unwrap(),
    ]));
    wait_for_size(&out, 100_000);
    front.signal(libc::SIGINT); // to the front door only: it must forward it
    assert_eq!(front.wait(LIMIT).code(), Some(130));
    let printed = front.stdout();
    assert!(
        printed.contains("status interrupted"),
        "summary printed: {printed}"
    );

    let rec = read_recording(&out);
    let summary = rec.recording.as_ref().expect("finalized file");
    assert_eq!(summary.run_status, "interrupted");
    assert_eq!(summary.frames_missing, 0);
    assert_contiguous(&rec.frames);
    for name in [
        names::producer_node_name(&run),
        names::recorder_node_name(&run),
    ] {
        assert_eq!(
            bus::node_liveness(&name),
            Liveness::Absent,
            "{name} still around"
        );
    }
}

#[test]
fn a_slow_recorder_loses_nothing_because_the_producer_waits() {
    let dir = tempfile::tempdir().unwrap();
    let text = hh_config(10.0, 0.01).to_toml(); // 1001 samples, 5005 frames
    let config = write_config(dir.path(), &text);
    let out = dir.path().join("slow.mcap");
    let run = unique_run("slow");
    // 0.3 ms per message: far slower than the producer, so its buffer is full most of the time.
    let mut recorder = Proc::spawn(record_cmd(&run, &out, &["--throttle-ms", "0.3"]));
    let mut producer = Proc::spawn(produce_cmd(&run, &config));
    assert!(producer.wait(LIMIT).success());
    assert!(recorder.wait(LIMIT).success());
    let rec = read_recording(&out);
    let expected = compute(&text, None);
    assert_eq!(rec.references.len(), expected.len());
    assert_contiguous(&rec.frames);
    assert_bit_identical(&rec, &expected);
    let summary = rec.recording.unwrap();
    assert_eq!(
        (summary.frames_missing, summary.run_status.as_str()),
        (0, "completed")
    );
}
