//! The producer process: validate a run configuration, integrate it with the [`Engine`], and
//! publish it on the iceoryx2 bus (run header, every sample, end-of-run record).
//!
//! Recorders are lossless: the producer waits for them to subscribe before it starts, and waits
//! for them whenever their buffer is full. Monitors get a lossy copy and never slow it down.
//!
//! [`map`] is the live stream of `chaoscope map` (header, points, end record; lossy).

mod header;
pub mod map;
mod ports;
mod termination;

use std::time::{Duration, Instant};

use chaoscope_schemas::bus::{self, BusError, Liveness};
use chaoscope_schemas::config::RunConfig;
use chaoscope_schemas::frame::{FrameHeader, status};
use chaoscope_schemas::names;

use crate::engine::{Engine, RunError, Sample};
use crate::spec::{RunSpec, SpecError};

pub use header::run_header;
use ports::Ports;
pub use termination::Termination;

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
}

impl Default for PublishOptions {
    fn default() -> Self {
        Self {
            run_name: None,
            recorders: 1,
            wait_timeout: None,
            linger: Duration::from_secs(30),
            progress: true,
        }
    }
}

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
}

#[derive(Debug, thiserror::Error)]
pub enum PublishError {
    /// Not a `#[source]`: the message already holds it, and error chains would repeat it.
    #[error("invalid configuration: {0}")]
    Spec(SpecError),
    #[error("invalid run name: {0}")]
    RunName(String),
    #[error("run {0:?} is already being produced by a live process")]
    AlreadyRunning(String),
    #[error("no recorder subscribed to run {run:?} within {timeout:?}")]
    NoRecorder { run: String, timeout: Duration },
    #[error(transparent)]
    Bus(#[from] BusError),
}

impl From<SpecError> for PublishError {
    fn from(e: SpecError) -> Self {
        Self::Spec(e)
    }
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

/// Longest frame payload of a run (a separation set: k vectors plus k stretches).
fn max_payload(spec: &RunSpec) -> usize {
    spec.dim.max(spec.k * spec.dim + spec.k)
}

/// The first non-finite value of a sample, described (NaN never goes on the bus or into files).
pub fn non_finite(sample: &Sample) -> Option<String> {
    if !sample.state.iter().all(|v| v.is_finite()) || !sample.energy.is_finite() {
        return Some(format!("non-finite reference state at t = {}", sample.t));
    }
    sample
        .schemes
        .iter()
        .find(|s| {
            !s.separations
                .iter()
                .chain(&s.stretch)
                .all(|v| v.is_finite())
        })
        .map(|s| {
            format!(
                "non-finite deviation vectors (scheme {}, set {}) at t = {}",
                s.scheme, s.set, sample.t
            )
        })
}

/// Validates `config`, then integrates and publishes it. Returns when the run completed, was
/// interrupted (SIGINT/SIGTERM) or failed numerically; the end-of-run record says which.
pub fn publish(
    config: &RunConfig,
    options: &PublishOptions,
) -> Result<PublishOutcome, PublishError> {
    publish_spec(config, RunSpec::from_config(config)?, options)
}

/// [`publish`] for a run already validated, e.g. one with a hand-written model
/// ([`RunSpec::with_model`]); `config` is what the run header records.
pub fn publish_spec(
    config: &RunConfig,
    spec: RunSpec,
    options: &PublishOptions,
) -> Result<PublishOutcome, PublishError> {
    let run = resolve_run_name(config, options.run_name.as_deref())?;
    let node_name = names::producer_node_name(&run);
    bus::cleanup_dead_nodes();
    if bus::node_liveness(&node_name) == Liveness::Alive {
        return Err(PublishError::AlreadyRunning(run));
    }
    let header = run_header(&run, config, &spec);
    let termination = Termination::new();
    // Monitors hold two whole samples (reference + every scheme x set frame), memory permitting.
    let frames_per_sample = 1 + spec.schemes.len() * spec.sets();
    let monitor_buffer = bus::monitor_buffer_for(frames_per_sample, max_payload(&spec));
    let mut ports = Ports::open(
        &node_name,
        &run,
        max_payload(&spec),
        monitor_buffer,
        &termination,
    )?;
    ports.announce(&header)?;

    let start = Instant::now();
    let mut publisher = RunPublisher {
        ports: &mut ports,
        frame: 0,
        samples: 0,
        last_step: 0,
        last_t: 0.0,
    };
    let status = if !publisher.wait_for_recorders(options, &termination, &run)? {
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
    let (frames, samples) = (publisher.frame, publisher.samples);
    linger(&ports, options.linger, &termination);
    Ok(PublishOutcome {
        run,
        status,
        samples,
        frames,
        payload_bytes: ports.payload_bytes,
        elapsed: start.elapsed(),
    })
}

/// Waits (bounded) until every lossless subscriber has read the end-of-run record and left:
/// frames still queued for a recorder must outlive this process's publisher.
fn linger(ports: &Ports, limit: Duration, termination: &Termination) {
    let start = Instant::now();
    while ports.data_subscribers() > 0 && start.elapsed() < limit && !termination.requested() {
        bus::cleanup_dead_nodes();
        ports.refresh_connections();
        std::thread::sleep(bus::POLL_INTERVAL);
    }
}

struct RunPublisher<'p> {
    ports: &'p mut Ports,
    /// Next frame sequence number.
    frame: u64,
    samples: u64,
    last_step: u64,
    last_t: f64,
}

/// Notify subscribers at least every this many frames, so a large sample does not fill their
/// buffer before they are woken.
const NOTIFY_EVERY: u64 = (bus::DATA_BUFFER / 4) as u64;

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
                // New subscribers (monitors, late recorders) get the run header.
                self.ports.refresh_connections();
                progress.set_position(engine.current_step());
                last_refresh = Instant::now();
            }
        };
        progress.finish_and_clear();
        Ok(status)
    }

    fn send_sample(&mut self, sample: &Sample) -> Result<(), BusError> {
        let dim = sample.state.len();
        let reference = FrameHeader::reference(
            self.frame,
            sample.seq,
            sample.step,
            sample.t,
            sample.energy,
            dim,
        );
        self.ports.send(reference, &[&sample.state])?;
        self.frame += 1;
        for s in &sample.schemes {
            let k = s.stretch.len();
            let h = FrameHeader::separations(
                self.frame,
                sample.seq,
                sample.step,
                sample.t,
                s.scheme,
                s.set,
                k,
                dim,
            );
            self.ports.send(h, &[&s.separations, &s.stretch])?;
            self.frame += 1;
            if self.frame.is_multiple_of(NOTIFY_EVERY) {
                self.ports.notify();
            }
        }
        self.ports.notify();
        self.samples = sample.seq + 1;
        self.last_step = sample.step;
        self.last_t = sample.t;
        Ok(())
    }

    fn send_end(&mut self, code: u32, reason: &str) -> Result<(), BusError> {
        let h = FrameHeader::end(
            self.frame,
            self.samples,
            self.last_step,
            self.last_t,
            code,
            reason,
        );
        self.ports.send(h, &[])?;
        self.frame += 1;
        self.ports.notify();
        Ok(())
    }
}

fn describe(e: &RunError) -> String {
    e.to_string()
}
