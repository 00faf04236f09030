//! `chaoscope recover` streams its input: memory stays at about one chunk whatever the size of
//! the file. Writes a ~1 GB recording through the recorder's own writer (FPUT N = 501 sized:
//! 1002-dimensional states, k = 4, 8 sets per sample, zstd chunks of 4 MiB), cuts it in the
//! middle of a chunk as `kill -9` would, recovers it in a child process (this binary again) and
//! prints one JSON line: input bytes, the child's peak RSS (`VmHWM` of /proc/self/status) and
//! MB/s. Exits non-zero if the peak exceeds 100 MB.
//!
//! `cargo bench -p chaoscope-recorder --bench recover_memory` (CHAOSCOPE_BENCH_SCALE=0.1 for a
//! ~100 MB quick run). Not part of CI: it writes two gigabytes.

use std::fs::File;
use std::io::{Read, Seek, SeekFrom};
use std::path::Path;
use std::process::{Command, Stdio};
use std::time::Instant;

use chaoscope_files::file::FileOptions;
use chaoscope_files::testing as synthetic;
use mcap::records::Record;
use serde_json::{Value, json};

const CHILD: &str = "--recover-child";
const LIMIT_MB: f64 = 100.0;

fn scale() -> f64 {
    std::env::var("CHAOSCOPE_BENCH_SCALE")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(1.0)
}

/// Peak resident set size of this process in kB.
fn vm_hwm_kb() -> u64 {
    let status = std::fs::read_to_string("/proc/self/status").unwrap();
    status
        .lines()
        .find_map(|l| l.strip_prefix("VmHWM:"))
        .and_then(|v| v.trim().trim_end_matches("kB").trim().parse().ok())
        .expect("VmHWM in /proc/self/status")
}

/// The child: recover and report.
fn child(input: &str, output: &str) {
    let start = Instant::now();
    let report = chaoscope_files::recover(Path::new(input), Path::new(output), true).unwrap();
    let seconds = start.elapsed().as_secs_f64();
    println!(
        "{}",
        json!({
            "seconds": seconds,
            "peak_rss_kb": vm_hwm_kb(),
            "messages": report.messages,
            "chunks": report.chunks,
            "stopped_at": report.stopped_at,
        })
    );
}

/// Start and length of every chunk, from the summary of a finished file (read from its end).
fn chunks(path: &Path) -> Vec<(u64, u64)> {
    let mut file = File::open(path).unwrap();
    let len = file.metadata().unwrap().len();
    // Footer record (opcode, length, summary start, summary offset start, CRC) and magic.
    let tail = 1 + 8 + 8 + 8 + 4 + 8;
    let mut footer = [0u8; 8];
    file.seek(SeekFrom::Start(len - tail + 9)).unwrap();
    file.read_exact(&mut footer).unwrap();
    let summary_start = u64::from_le_bytes(footer);
    let mut summary = vec![0u8; (len - tail - summary_start) as usize];
    file.seek(SeekFrom::Start(summary_start)).unwrap();
    file.read_exact(&mut summary).unwrap();
    mcap::read::LinearReader::sans_magic(&summary)
        .filter_map(|r| match r.unwrap() {
            Record::ChunkIndex(c) => Some((c.chunk_start_offset, c.chunk_length)),
            _ => None,
        })
        .collect()
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    if let Some(i) = args.iter().position(|a| a == CHILD) {
        return child(&args[i + 1], &args[i + 2]);
    }

    let dir = std::env::temp_dir().join(format!("chaoscope-recover-memory-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let broken = dir.join("broken.mcap");
    let fixed = dir.join("fixed.mcap");

    // ~264 kB per sample: ~1 GB at scale 1.
    let shape = synthetic::Shape {
        dim: 1002,
        k: 4,
        sets: 8,
        samples: ((4000.0 * scale()).round() as u64).max(40),
    };
    let start = Instant::now();
    let options = FileOptions::default();
    synthetic::write_run(File::create(&broken).unwrap(), &shape, &options, 1).unwrap();
    let write_seconds = start.elapsed().as_secs_f64();

    // Cut in the middle of the last full chunk (the very last one is what `finish` flushed):
    // the open chunk of a kill.
    let chunks = chunks(&broken);
    assert!(chunks.len() > 2, "{} chunks", chunks.len());
    let (chunk_start, chunk_len) = chunks[chunks.len() - 2];
    let cut = chunk_start + chunk_len / 2;
    File::options()
        .write(true)
        .open(&broken)
        .unwrap()
        .set_len(cut)
        .unwrap();

    let out = Command::new(std::env::current_exe().unwrap())
        .args([CHILD, broken.to_str().unwrap(), fixed.to_str().unwrap()])
        .stderr(Stdio::inherit())
        .output()
        .unwrap();
    assert!(out.status.success(), "the recovering child failed");
    let child: Value = serde_json::from_slice(&out.stdout).unwrap();
    let seconds = child["seconds"].as_f64().unwrap();
    let peak_mb = child["peak_rss_kb"].as_f64().unwrap() / 1024.0;
    let output_bytes = std::fs::metadata(&fixed).unwrap().len();
    println!(
        "{}",
        json!({
            "bench": "recover_memory",
            "input_bytes": cut,
            "chunks_in_input": chunks.iter().filter(|(s, l)| s + l <= cut).count(),
            "cut_into_chunk_bytes": cut - chunk_start,
            "chunk_bytes": chunk_len,
            "output_bytes": output_bytes,
            "messages": child["messages"],
            "stopped_at": child["stopped_at"],
            "write_seconds": write_seconds,
            "recover_seconds": seconds,
            "recover_mb_per_s": cut as f64 / 1e6 / seconds,
            "peak_rss_mb": peak_mb,
            "limit_mb": LIMIT_MB,
        })
    );
    let _ = std::fs::remove_dir_all(&dir);
    if peak_mb > LIMIT_MB {
        eprintln!("peak RSS {peak_mb:.1} MB exceeds {LIMIT_MB} MB");
        std::process::exit(1);
    }
}
