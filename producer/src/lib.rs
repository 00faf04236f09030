//! chaoscope-producer, the producer process: validate a run configuration, integrate it with
//! the [`Engine`] of `chaoscope-dynamics`, and publish it on the iceoryx2 bus (run header, every
//! sample, end-of-run record).
//!
//! Recorders are lossless: the producer waits for them to subscribe before it starts, and waits
//! for them whenever their buffer is full. Monitors get a lossy copy and never slow it down.
//!
//! [`map`] is the live stream of `chaoscope map` (header, points, end record; lossy).

pub mod estimate;
pub mod map;
mod ports;

use std::time::{Duration, Instant};

use chaoscope_bus::frame::{
    FrameHeader, RecordBatch, reference_record_words, separations_record_words, status,
};
use chaoscope_bus::{self as bus, BusError, OpenAloneError};
use chaoscope_schemas::config::RunConfig;
use chaoscope_schemas::names;

use chaoscope_dynamics::engine::{Engine, RunError};
use chaoscope_dynamics::header::{non_finite, run_header};
use chaoscope_dynamics::spec::RunSpec;
use chaoscope_os::termination::Termination;
use chaoscope_schemas::run::Sample;

use ports::Ports;

/// How a producer runs.
#[derive(Debug, Clone)]
pub struct PublishOptions {
    /// Run name; overrides `[run] name` of the config. Generated when neither is given.
    pub run_name: Option<String>,
    /// Lossless subscribers (recorders) to wait for before publishing the first sample.
    pub recorders: usize,
    /// Give up if the recorders do not show up within this time.
    pub wait_timeout: Option<Duration>,
    /// After the end-of-run record, wait up to this long for recorders to drain and leave.
    pub linger: Duration,
    /// Draw a progress bar on stderr (only if it is a terminal).
    pub progress: bool,
    /// Called once the run's services are open (no other live producer of this run holds them)
    /// and the header is announced, before waiting for the recorders: `chaoscope run` starts
    /// its recorder only then, so a recorder never records another producer's run of the same
    /// name.
    pub on_open: Option<fn()>,
}

impl Default for PublishOptions {
    fn default() -> Self {
        Self {
            run_name: None,
            recorders: 1,
            wait_timeout: None,
            linger: Duration::from_secs(30),
            progress: true,
            on_open: None,
        }
    }
}

/// The failure of a run whose recorders all left before its end.
pub const RECORDERS_LEFT: &str = "every recorder left before the end of the run";

/// How a run ended.
#[derive(Debug, Clone, PartialEq)]
pub enum RunStatus {
    Completed,
    Interrupted,
    Failed(String),
}

#[derive(Debug, Clone)]
pub struct PublishOutcome {
    pub run: String,
    pub status: RunStatus,
    pub samples: u64,
    pub frames: u64,
    pub payload_bytes: u64,
    pub elapsed: Duration,
    /// From the recorders' readiness to their leaving after the end-of-run record (the
    /// sustained part of the run, without process start-up).
    pub streaming: Duration,
}

#[derive(Debug, thiserror::Error)]
pub enum PublishError {
    #[error("invalid run name: {0}")]
    RunName(String),
    #[error("run {0:?} is already being produced by a live process")]
    AlreadyRunning(String),
    #[error("no recorder subscribed to run {run:?} within {timeout:?}")]
    NoRecorder { run: String, timeout: Duration },
    #[error(transparent)]
    Bus(#[from] BusError),
}

/// The run name: explicit option, else the config's `[run] name`, else generated.
pub fn resolve_run_name(
    config: &RunConfig,
    explicit: Option<&str>,
) -> Result<String, PublishError> {
    let name = match explicit.or(config.run.name.as_deref()) {
        Some(n) => n.to_string(),
        None => {
            let secs = std::time::SystemTime::now()
                .duration_since(std::time::UNIX_EPOCH)
                .map(|d| d.as_secs())
                .unwrap_or(0);
            format!("run-{secs}-{}", std::process::id())
        }
    };
    names::validate_run_name(&name).map_err(|e| {
        let key = if explicit.is_some() {
            "--run"
        } else {
            "run.name"
        };
        PublishError::RunName(format!("{key}: {e}"))
    })?;
    Ok(name)
}

/// Longest record of a run, in words (a separation set: k vectors plus k stretches).
fn longest_record(spec: &RunSpec) -> usize {
    let earlier = spec.most_earlier_renormalizations() as usize;
    reference_record_words(spec.dim()).max(separations_record_words(spec.k(), spec.dim(), earlier))
}

/// Integrates and publishes the validated run `spec` (from `config`, or around a hand-written
/// model, [`RunSpec::with_model`]); `config` is what the run header records. Returns when the
/// run completed, was interrupted (SIGINT/SIGTERM) or failed numerically; the end-of-run record
/// says which.
pub fn publish(
    config: &RunConfig,
    spec: RunSpec,
    options: &PublishOptions,
) -> Result<PublishOutcome, PublishError> {
    let run = resolve_run_name(config, options.run_name.as_deref())?;
    let node_name = names::producer_node_name(&run);
    let header = run_header(&run, config, &spec);
    let termination = Termination::with_fallback(bus::signals::iceoryx2_termination_requested);
    // Monitors hold two whole samples (a sample's records take at most one frame each),
    // memory permitting.
    let frames_per_sample = 1 + spec.schemes().len() * spec.sets();
    let max_frame = bus::max_frame_words(longest_record(&spec));
    let monitor_buffer = bus::monitor_buffer_for(frames_per_sample, max_frame);
    let mut ports = bus::open_alone(&node_name, || {
        Ports::open(&node_name, &run, max_frame, monitor_buffer, &termination)
    })
    .map_err(|e| match e {
        OpenAloneError::Held => PublishError::AlreadyRunning(run.clone()),
        OpenAloneError::Bus(e) => PublishError::Bus(e),
    })?;
    ports.announce(&header)?;
    if let Some(on_open) = options.on_open {
        on_open();
    }

    let start = Instant::now();
    let mut publisher = RunPublisher {
        ports: &mut ports,
        batch: RecordBatch::new(0),
        batch_opened: start,
        last_sample: start,
        payload_bytes: 0,
        samples: 0,
        last_step: 0,
        last_t: 0.0,
    };
    let ready = publisher.wait_for_recorders(options, &termination, &run)?;
    let streaming_start = Instant::now();
    let status = if !ready {
        RunStatus::Interrupted
    } else {
        publisher.stream(Engine::new(spec), options, &termination)?
    };
    let (code, reason) = match &status {
        RunStatus::Completed => (status::COMPLETED, String::new()),
        RunStatus::Interrupted => (status::INTERRUPTED, "interrupted by a signal".to_string()),
        RunStatus::Failed(r) => (status::FAILED, r.clone()),
    };
    publisher.send_end(code, &reason)?;
    let (frames, samples) = (publisher.batch.next_frame(), publisher.samples);
    let payload_bytes = publisher.payload_bytes;
    linger(&ports, options.linger, &termination);
    Ok(PublishOutcome {
        run,
        status,
        samples,
        frames,
        payload_bytes,
        elapsed: start.elapsed(),
        streaming: streaming_start.elapsed(),
    })
}

/// Waits (bounded) until every lossless subscriber has read the end-of-run record and left:
/// frames still queued for a recorder must outlive this process's publisher.
fn linger(ports: &Ports, limit: Duration, termination: &Termination) {
    let start = Instant::now();
    let mut backoff = bus::Backoff::default();
    // A reader killed before it left is only seen gone once its node is cleaned up: that scan
    // of the bus is made once a poll interval, however often the count is looked at.
    let mut cleaned: Option<Instant> = None;
    while ports.data_subscribers() > 0 && start.elapsed() < limit && !termination.requested() {
        if cleaned.is_none_or(|at| at.elapsed() >= bus::POLL_INTERVAL) {
            bus::cleanup_dead_nodes();
            cleaned = Some(Instant::now());
        }
        ports.refresh_connections();
        std::thread::sleep(backoff.interval());
    }
}

struct RunPublisher<'p> {
    ports: &'p mut Ports,
    /// Records not sent yet; its next record number is the run's next `frame_seq`.
    batch: RecordBatch,
    /// When the batch's first record was added, and when the latest sample was.
    batch_opened: Instant,
    last_sample: Instant,
    /// Bytes of values (state, separations, stretches) sent on the data stream.
    payload_bytes: u64,
    samples: u64,
    last_step: u64,
    last_t: f64,
}

/// Longest a complete sample waits in a batch for more samples. Samples that come faster than
/// this share frames (a monitor sees them at most this late); a sample that took longer to
/// compute is sent as soon as it is complete, so slow runs are not delayed at all.
const MAX_BATCH_AGE: Duration = Duration::from_millis(2);

impl RunPublisher<'_> {
    /// Returns false if a signal arrived first.
    fn wait_for_recorders(
        &mut self,
        options: &PublishOptions,
        termination: &Termination,
        run: &str,
    ) -> Result<bool, PublishError> {
        let start = Instant::now();
        while self.ports.ready_receivers() < options.recorders {
            self.ports.refresh_connections();
            if termination.requested() {
                return Ok(false);
            }
            if let Some(timeout) = options.wait_timeout
                && start.elapsed() > timeout
            {
                return Err(PublishError::NoRecorder {
                    run: run.to_string(),
                    timeout,
                });
            }
            std::thread::sleep(Duration::from_millis(10));
        }
        self.ports.refresh_connections();
        Ok(true)
    }

    fn stream(
        &mut self,
        mut engine: Engine,
        options: &PublishOptions,
        termination: &Termination,
    ) -> Result<RunStatus, PublishError> {
        let progress = if options.progress {
            indicatif::ProgressBar::new(engine.total_steps())
        } else {
            indicatif::ProgressBar::hidden()
        };
        let mut last_refresh = Instant::now();
        let status = loop {
            if termination.requested() {
                break RunStatus::Interrupted;
            }
            let sample = match engine.next_sample() {
                Ok(Some(sample)) => sample,
                Ok(None) => break RunStatus::Completed,
                Err(e) => break RunStatus::Failed(describe(&e)),
            };
            if let Some(problem) = non_finite(&sample) {
                break RunStatus::Failed(problem);
            }
            if let Err(e) = self.send_sample(&sample) {
                if termination.requested() {
                    break RunStatus::Interrupted;
                }
                return Err(e.into());
            }
            if last_refresh.elapsed() > bus::POLL_INTERVAL {
                // Recorders that left before the end (a failed write, a kill once its node is
                // cleaned up) leave nobody to compute for.
                // (Recorders that finalized on the signal this process got too: interrupted.)
                if options.recorders > 0 && self.ports.data_subscribers() == 0 {
                    break if termination.requested() {
                        RunStatus::Interrupted
                    } else {
                        RunStatus::Failed(RECORDERS_LEFT.to_string())
                    };
                }
                // New subscribers (monitors, late recorders) get the run header.
                self.ports.refresh_connections();
                progress.set_position(engine.current_step());
                last_refresh = Instant::now();
            }
        };
        progress.finish_and_clear();
        Ok(status)
    }

    /// Adds a sample's records to the batch, sending frames as they fill, and the batch itself
    /// unless more samples are coming soon (see [`MAX_BATCH_AGE`]).
    fn send_sample(&mut self, sample: &Sample) -> Result<(), BusError> {
        let dim = sample.state.len();
        self.make_room(reference_record_words(dim))?;
        self.batch.push_reference(
            sample.seq,
            sample.step,
            sample.t,
            sample.energy,
            sample.mean_divergence,
            sample.divergence_sum,
            &sample.state,
        );
        for s in &sample.schemes {
            let earlier = s.earlier_stretch.len() / s.stretch.len().max(1);
            self.make_room(separations_record_words(s.stretch.len(), dim, earlier))?;
            self.batch.push_separations(
                sample.seq,
                sample.step,
                sample.t,
                s.scheme,
                s.set,
                dim,
                &s.separations,
                &s.stretch,
                &s.earlier_stretch,
            );
        }
        self.samples = sample.seq + 1;
        self.last_step = sample.step;
        self.last_t = sample.t;
        let now = Instant::now();
        let slow = now - self.last_sample >= MAX_BATCH_AGE;
        self.last_sample = now;
        if slow || now - self.batch_opened >= MAX_BATCH_AGE {
            self.flush()?;
        }
        Ok(())
    }

    /// Sends the batch first if a record of `words` would take it beyond a frame's target.
    fn make_room(&mut self, words: usize) -> Result<(), BusError> {
        if self.batch.is_empty() {
            self.batch_opened = Instant::now();
        } else if self.batch.words().len() + words > bus::FRAME_TARGET_WORDS {
            self.flush()?;
            self.batch_opened = Instant::now();
        }
        Ok(())
    }

    /// Sends the batch (if any) as one frame and wakes the subscribers.
    fn flush(&mut self) -> Result<(), BusError> {
        if self.batch.is_empty() {
            return Ok(());
        }
        self.ports.send(self.batch.header(), self.batch.words())?;
        self.payload_bytes += (self.batch.value_words() * size_of::<f64>()) as u64;
        self.ports.notify();
        self.batch.reset(self.batch.next_frame());
        Ok(())
    }

    /// Sends what is batched, then the end-of-run record. Records that cannot be sent (a
    /// recorder stuck past the drain grace of a signal) are given up, their numbers left as a
    /// gap, and the end of the run is still sent.
    fn send_end(&mut self, code: u32, reason: &str) -> Result<(), BusError> {
        let flushed = self.flush();
        if flushed.is_err() {
            self.batch.reset(self.batch.next_frame());
        }
        let h = FrameHeader::end(
            self.batch.next_frame(),
            self.samples,
            self.last_step,
            self.last_t,
            code,
            reason,
        );
        self.ports.send(h, &[])?;
        self.batch.reset(self.batch.next_frame() + 1);
        self.ports.notify();
        flushed
    }
}

fn describe(e: &RunError) -> String {
    e.to_string()
}
