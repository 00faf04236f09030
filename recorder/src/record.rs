//! The recorder process: discover a run, subscribe, write MCAP, finalize on end-of-run, signal
//! or producer death.

use std::ops::ControlFlow;
use std::path::PathBuf;
use std::time::{Duration, Instant};

use chaoscope_bus as bus;
use chaoscope_os::output::{Leftover, Output, OutputError, OutputOptions};
use chaoscope_schemas::names;
use chaoscope_schemas::proto::DataMessage;
use chaoscope_schemas::proto::RecordingSummary;

use crate::discover::{self, Discovery};
use crate::subscription::{BusEvent, Ended, RunSubscription, SubscribeError};
use crate::write_thread::WriteThread;
use chaoscope_files::file::FileOptions;
use chaoscope_files::recording::{FinalizedBy, Recording};

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
    /// Device and inode of the file written, as it was put at `out`.
    pub file_identity: (u64, u64),
}

#[derive(Debug, thiserror::Error)]
pub enum RecordError {
    #[error(transparent)]
    Subscribe(#[from] SubscribeError),
    #[error(transparent)]
    Bus(#[from] bus::BusError),
    #[error("invalid run name: {0}")]
    RunName(String),
    /// The cause is in the message (no error source), so a chain printer does not repeat it.
    #[error("{}: {cause}", path.display())]
    Io {
        path: PathBuf,
        cause: std::io::Error,
    },
    #[error(transparent)]
    Output(#[from] OutputError),
    /// The whole cause in the message (`...: File too large`) and no error source, so that a
    /// chain printer does not repeat it.
    #[error("{}: MCAP: {}", path.display(), chaoscope_files::file::error_chain(error))]
    Mcap {
        path: PathBuf,
        error: mcap::McapError,
    },
    /// A write failed: the file written so far stays as `kept` (its complete chunks can be
    /// salvaged), never at the output's name.
    #[error(
        "{}: MCAP: {}; what was written is kept in {} (`chaoscope resume {}` continues the run \
         from its complete chunks, `chaoscope recover {} --out FILE` salvages them)",
        path.display(),
        chaoscope_files::file::error_chain(error),
        kept.display(),
        kept.display(),
        kept.display()
    )]
    WriteFailed {
        path: PathBuf,
        error: mcap::McapError,
        kept: PathBuf,
    },
    #[error("interrupted before any run started")]
    InterruptedBeforeRun,
    #[error("no run appeared within {0:?}")]
    NoRun(Duration),
}

/// The recording's output (see [`chaoscope_os::output`]): opened before anything else, so an
/// output that cannot be written (or that another live recorder writes) is refused before the
/// recorder tells a producer it is ready.
pub fn open_output(out: &std::path::Path, force: bool) -> Result<Output, RecordError> {
    let options = OutputOptions {
        replace: force,
        create_dir: true,
        inputs: Vec::new(),
        leftover: if force {
            Leftover::Discard
        } else {
            Leftover::Refuse
        },
        // A recording that stops on an error keeps its complete chunks for `recover`.
        keep_failed: true,
    };
    Output::create(out, &options)
        .map_err(|e| {
            e.with_leftover_hint(|partial| {
                format!(
                    " (a recorder that was killed: `chaoscope resume {}` continues the run from \
                     its complete chunks, `chaoscope recover {} --out FILE` salvages them)",
                    partial.display(),
                    partial.display()
                )
            })
        })
        .map_err(RecordError::from)
}

/// How long a recorder whose producer died goes on cleaning up after it.
const DEAD_PRODUCER_CLEANUP: Duration = Duration::from_secs(1);

/// Removes the dead producer of `run` from the bus: cleans up until its node is gone, for at
/// most [`DEAD_PRODUCER_CLEANUP`]. One cleanup is not always enough: another process may be
/// cleaning that node at the same moment (every process cleans up dead nodes when it starts),
/// and then ours skips it and the node is still listed, dead, when the recorder has exited.
/// A full test suite saw it once (`kill_9_of_the_producer_makes_the_recorder_finalize_an_
/// interrupted_file`).
fn remove_dead_producer(run: &str) {
    let node = names::producer_node_name(run);
    let start = Instant::now();
    let mut backoff = bus::Backoff::default();
    loop {
        bus::cleanup_dead_nodes();
        if bus::node_liveness(&node) == bus::Liveness::Absent
            || start.elapsed() >= DEAD_PRODUCER_CLEANUP
        {
            return;
        }
        std::thread::sleep(backoff.interval());
    }
}

/// Records one run to `options.out`.
pub fn record(options: &RecordOptions) -> Result<RecordOutcome, RecordError> {
    let output = open_output(&options.out, options.force)?;
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
    // Unbuffered on purpose: chunks are written whole, so a crash never leaves a half chunk
    // sitting in a user-space buffer.
    let file = output.file()?;
    let recording = Recording::start(file, &header, &options.file).map_err(mcap_err)?;
    // Encoding, compression and writing on a thread of their own (see `write_thread`).
    let mut recording = WriteThread::start(recording).map_err(|cause| RecordError::Io {
        path: path.clone(),
        cause,
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
                chaoscope_os::errln!("chaoscope record: skipping invalid frame: {e}");
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
    // On a write error this still finalizes the file as far as it goes, and returns the error;
    // the file then stays at its in-progress name.
    let summary = match recording.finish(reason) {
        Ok((_file, summary)) => summary,
        Err(error) => {
            let kept = output.keep();
            return Err(RecordError::WriteFailed { path, error, kept });
        }
    };
    let file_identity = output.identity()?;
    output.commit()?;
    if reason == FinalizedBy::ProducerDied {
        remove_dead_producer(&run);
    }
    Ok(RecordOutcome {
        run,
        out: path,
        summary,
        invalid_frames,
        file_identity,
    })
}
