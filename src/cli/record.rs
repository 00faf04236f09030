//! `chaoscope record --out FILE.mcap`: record a run from the bus (the next one that appears,
//! unless `--run` names it).

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Duration;

use chaoscope_files::file::Compression;
use chaoscope_recorder::{RecordError, RecordOptions, record};

#[derive(clap::Args)]
pub struct Args {
    /// Output MCAP file.
    #[arg(long)]
    pub out: PathBuf,
    /// Run to record; default: the next run that appears on the bus.
    #[arg(long)]
    pub run: Option<String>,
    /// Replace the output file if it exists.
    #[arg(long)]
    pub force: bool,
    /// Chunk compression: zstd, lz4 or none.
    #[arg(long, default_value = "zstd")]
    pub compression: Compression,
    /// Target chunk size in bytes (uncompressed).
    #[arg(long, default_value_t = 4 << 20)]
    pub chunk_size: u64,
    /// Close the open chunk at least every this many seconds (what a crash can lose).
    #[arg(long, default_value = "1", value_parser = super::parse_seconds)]
    pub flush_interval: Duration,
    /// Give up if no run shows up within this many seconds.
    #[arg(long, value_parser = super::parse_seconds)]
    pub wait_timeout: Option<Duration>,
    /// Sleep this many milliseconds per message (simulates a slow disk; tests backpressure).
    #[arg(long, hide = true, value_parser = parse_millis)]
    pub throttle_ms: Option<Duration>,
}

fn parse_millis(s: &str) -> Result<Duration, String> {
    super::parse_seconds(s).map(|d| d / 1000)
}

pub fn main(args: Args) -> anyhow::Result<ExitCode> {
    let mut options = RecordOptions::new(args.out);
    options.run = args.run;
    options.force = args.force;
    options.file.compression = args.compression;
    options.file.chunk_size = args.chunk_size;
    options.flush_interval = args.flush_interval;
    options.wait_timeout = args.wait_timeout;
    options.throttle = args.throttle_ms.unwrap_or_default();
    chaoscope_bus::signals::install(chaoscope_os::signals::Mode::Finish);
    let outcome = match record(&options) {
        Ok(outcome) => outcome,
        // Stopped before any run started: nothing was written, nothing to say.
        Err(RecordError::InterruptedBeforeRun) => return Ok(super::exit_interrupted()),
        Err(e) => return Err(e.into()),
    };
    let s = &outcome.summary;
    chaoscope_os::errln!(
        "chaoscope record: run {} -> {} ({} frames, {} missing, finalized by {}, run {})",
        outcome.run,
        outcome.out.display(),
        s.frames_received,
        s.frames_missing,
        s.finalized_by,
        s.run_status
    );
    super::print_summary(&serde_json::json!({
        "role": "recorder",
        "run": outcome.run,
        "out": outcome.out,
        "finalized_by": s.finalized_by,
        "run_status": s.run_status,
        "frames_received": s.frames_received,
        "frames_missing": s.frames_missing,
        "invalid_frames": outcome.invalid_frames,
        "file": {
            "device": outcome.file_identity.0,
            "inode": outcome.file_identity.1,
        },
    }));
    Ok(ExitCode::SUCCESS)
}
