//! The recorder process: discover a run, subscribe, write MCAP, finalize on end-of-run, signal
//! or producer death.

use std::fs::File;
use std::ops::ControlFlow;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use chaoscope_bus as bus;
use chaoscope_schemas::names;
use chaoscope_schemas::proto::DataMessage;
use chaoscope_schemas::proto::RecordingSummary;

use crate::discover::{self, Discovery};
use crate::file::FileOptions;
use crate::recording::{FinalizedBy, Recording};
use crate::subscription::{BusEvent, Ended, RunSubscription, SubscribeError};
use crate::write_thread::WriteThread;

#[derive(Debug, Clone)]
pub struct RecordOptions {
    /// Run to record; `None` records the next run that appears.
    pub run: Option<String>,
    pub out: PathBuf,
    /// Replace an existing output file.
    pub force: bool,
    pub file: FileOptions,
    /// Close the open chunk at least this often, bounding what a crash of the recorder loses.
    pub flush_interval: Duration,
    /// Give up if no run (or no run header) shows up within this time.
    pub wait_timeout: Option<Duration>,
    /// Artificial delay per message, to demonstrate backpressure (tests and benchmarks).
    pub throttle: Duration,
}

impl RecordOptions {
    pub fn new(out: impl Into<PathBuf>) -> Self {
        Self {
            run: None,
            out: out.into(),
            force: false,
            file: FileOptions::default(),
            flush_interval: Duration::from_secs(1),
            wait_timeout: None,
            throttle: Duration::ZERO,
        }
    }
}

#[derive(Debug, Clone)]
pub struct RecordOutcome {
    pub run: String,
    pub out: PathBuf,
    pub summary: RecordingSummary,
    /// Frames that broke the layout and were skipped.
    pub invalid_frames: u64,
}

#[derive(Debug, thiserror::Error)]
pub enum RecordError {
    #[error(transparent)]
    Subscribe(#[from] SubscribeError),
    #[error(transparent)]
    Bus(#[from] bus::BusError),
    #[error("invalid run name: {0}")]
    RunName(String),
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("{path} already exists (pass --force to replace it)")]
    Exists { path: PathBuf },
    /// The whole cause in the message (`...: File too large`) and no error source, so that a
    /// chain printer does not repeat it.
    #[error("{path}: MCAP: {}", crate::file::error_chain(error))]
    Mcap {
        path: PathBuf,
        error: mcap::McapError,
    },
    #[error("interrupted before any run started")]
    InterruptedBeforeRun,
    #[error("no run appeared within {0:?}")]
    NoRun(Duration),
}

fn create_output(path: &Path, force: bool) -> Result<File, RecordError> {
    let io = |source| RecordError::Io {
        path: path.to_path_buf(),
        source,
    };
    if path.exists() && !force {
        return Err(RecordError::Exists {
            path: path.to_path_buf(),
        });
    }
    if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).map_err(io)?;
    }
    // Unbuffered on purpose: chunks are written whole, so a crash never leaves a half chunk
    // sitting in a user-space buffer.
    File::create(path).map_err(io)
}

/// Records one run to `options.out`.
pub fn record(options: &RecordOptions) -> Result<RecordOutcome, RecordError> {
    let run = match &options.run {
        Some(run) => {
            names::validate_run_name(run).map_err(RecordError::RunName)?;
            run.clone()
        }
        None => match discover::wait_for_run(options.wait_timeout)? {
            Discovery::Found(run) => run,
            Discovery::Signal => return Err(RecordError::InterruptedBeforeRun),
            Discovery::TimedOut => {
                return Err(RecordError::NoRun(options.wait_timeout.unwrap_or_default()));
            }
        },
    };
    let subscription = RunSubscription::open(&run, &names::recorder_node_name(&run))?;
    let Some(header) = subscription.wait_header(options.wait_timeout)? else {
        return Err(RecordError::InterruptedBeforeRun);
    };

    let path = options.out.clone();
    let mcap_err = |error| RecordError::Mcap {
        path: path.clone(),
        error,
    };
    let file = create_output(&path, options.force)?;
    let recording = Recording::start(file, &header, &options.file).map_err(mcap_err)?;
    // Encoding, compression and writing on a thread of their own (see `write_thread`).
    let mut recording = WriteThread::start(recording).map_err(|source| RecordError::Io {
        path: path.clone(),
        source,
    })?;

    let mut invalid_frames = 0;
    let mut last_chunk_close = Instant::now();
    let mut writer_stopped = false;
    let ended = subscription.receive(|event| {
        let mut done = false;
        let alive = match event {
            BusEvent::Message(m) => {
                if !options.throttle.is_zero() {
                    std::thread::sleep(options.throttle);
                }
                done = matches!(m, DataMessage::End(_));
                recording.push(m) && (!done || recording.flush())
            }
            BusEvent::Invalid(e) => {
                eprintln!("chaoscope record: skipping invalid frame: {e}");
                invalid_frames += 1;
                true
            }
            // Idle: let the file catch up with the run.
            BusEvent::Tick => recording.flush(),
        };
        let alive = alive
            && (done || last_chunk_close.elapsed() < options.flush_interval || {
                last_chunk_close = Instant::now();
                recording.close_chunk()
            });
        if !alive {
            // A write failed; `finish` returns the error.
            writer_stopped = true;
        }
        if done || !alive {
            ControlFlow::Break(())
        } else {
            ControlFlow::Continue(())
        }
    })?;
    drop(subscription);
    let reason = match ended {
        _ if writer_stopped => FinalizedBy::Signal,
        Ended::Stopped => FinalizedBy::EndOfRun,
        Ended::Signal => FinalizedBy::Signal,
        Ended::ProducerGone => FinalizedBy::ProducerDied,
    };
    // On a write error this still leaves a readable file behind, and returns the error.
    let (file, summary) = recording.finish(reason).map_err(mcap_err)?;
    file.sync_all().map_err(|source| RecordError::Io {
        path: path.clone(),
        source,
    })?;
    if reason == FinalizedBy::ProducerDied {
        bus::cleanup_dead_nodes();
    }
    Ok(RecordOutcome {
        run,
        out: path,
        summary,
        invalid_frames,
    })
}
