//! The bus side of `chaoscope monitor`: a subscriber on the run's lossy monitor stream.
//!
//! The monitor stream has safe overflow on: when a monitor falls behind, the oldest frames in
//! its buffer are overwritten and the producer never waits. Frame sequence numbers tell the
//! monitor what it missed (late attach, overflow), and the analysis marks its results
//! incomplete accordingly. Wakes on the producer's data-ready event, and at least every
//! `tick` for display refreshes and producer liveness checks.

use std::cell::Cell;
use std::ops::ControlFlow;
use std::time::{Duration, Instant};

use crate::convert::{self, HeaderError};
use crate::frame::FrameHeader;
use crate::{BusError, DataService, EventService, HeaderService, HeaderSubscriber, Liveness};
use chaoscope_schemas::names;
use chaoscope_schemas::proto::DataMessage;
use chaoscope_schemas::proto::RunHeader;
use iceoryx2::port::listener::Listener;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::prelude::*;
use iceoryx2::waitset::WaitSetRunResult;

#[derive(Debug, thiserror::Error)]
pub enum LiveError {
    #[error(transparent)]
    Bus(#[from] BusError),
    #[error(transparent)]
    Header(#[from] HeaderError),
    #[error("run {run:?}: no run header within {timeout:?} (is the run producing?)")]
    NoHeader { run: String, timeout: Duration },
}

/// What the monitor loop sees.
#[derive(Debug)]
pub enum LiveEvent {
    Message(DataMessage),
    /// Periodic wake-up (refresh the display).
    Tick,
}

/// Why [`LiveRun::receive`] returned.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LiveEnded {
    Stopped,
    Signal,
    ProducerGone,
}

/// A monitor's subscription to one run.
pub struct LiveRun {
    run: String,
    /// The ports live as long as their node.
    _node: Node<ipc::Service>,
    monitor: Subscriber<ipc::Service, [u64], FrameHeader>,
    _header: HeaderSubscriber,
    listener: Listener<ipc::Service>,
    _services: (DataService, HeaderService, EventService),
    /// Next frame sequence number expected.
    next_frame: Cell<Option<u64>>,
    /// Frames known to be missed while attached (gaps in the sequence, broken frames).
    frames_lost: Cell<u64>,
    /// Records the producer published before the first frame this monitor received: before it
    /// attached (or, for a monitor that attached first and read late, overwritten before its
    /// first read: the stream cannot tell the two apart). Not lost: the monitor was not there.
    frames_before_attach: Cell<u64>,
    frames_received: Cell<u64>,
}

impl LiveRun {
    /// Subscribes to `run` and waits for its header (kept as history, so it also reaches late
    /// monitors). A monitor never creates a run's services: it waits until the run's producer
    /// (or recorder) has created them, so a monitor killed at any moment cannot leave a service
    /// half-created for the run's own processes, and the monitor stream's size stays the
    /// producer's to choose. The data side is opened only after the header arrived (the
    /// producer creates every service before announcing). `Ok(None)` on a termination signal;
    /// an error when nothing arrived within `timeout`.
    pub fn connect(run: &str, timeout: Duration) -> Result<Option<(Self, RunHeader)>, LiveError> {
        let node_name = format!("chaoscope-monitor/{run}/{}", std::process::id());
        let node = crate::create_node(&node_name)?;
        let start = Instant::now();
        let Some(header_service) = wait_for(&node, run, start, timeout, &|| {
            crate::open_header_service(&node, run)
        })?
        else {
            return Ok(None);
        };
        let header = crate::header_subscriber(&header_service)?;
        let Some(run_header) = wait_header(&node, &header, run, start, timeout)? else {
            return Ok(None);
        };
        let Some(monitor_service) = wait_for(&node, run, start, timeout, &|| {
            crate::open_monitor_service(&node, run)
        })?
        else {
            return Ok(None);
        };
        let Some(event_service) = wait_for(&node, run, start, timeout, &|| {
            crate::open_data_ready_service(&node, run)
        })?
        else {
            return Ok(None);
        };
        // No buffer size given: the subscriber takes the service's, sized by the producer.
        let monitor = monitor_service
            .subscriber_builder()
            .create()
            .map_err(|e| BusError::new("create monitor subscriber", e))?;
        let listener = event_service
            .listener_builder()
            .create()
            .map_err(|e| BusError::new("create listener", e))?;
        Ok(Some((
            Self {
                run: run.to_string(),
                _node: node,
                monitor,
                _header: header,
                listener,
                _services: (monitor_service, header_service, event_service),
                next_frame: Cell::new(None),
                frames_lost: Cell::new(0),
                frames_before_attach: Cell::new(0),
                frames_received: Cell::new(0),
            },
            run_header,
        )))
    }

    pub fn run(&self) -> &str {
        &self.run
    }

    /// Frames known to be missed so far while attached (overwritten while behind, or broken);
    /// not those published before the monitor's first frame ([`Self::frames_before_attach`]).
    pub fn frames_lost(&self) -> u64 {
        self.frames_lost.get()
    }

    /// Frames the producer published before the first one this monitor received.
    pub fn frames_before_attach(&self) -> u64 {
        self.frames_before_attach.get()
    }

    /// Whether the samples received miss any of the run's: lost while attached, or published
    /// before (an analysis of them is then incomplete).
    pub fn missed_any(&self) -> bool {
        self.frames_lost() > 0 || self.frames_before_attach() > 0
    }

    pub fn frames_received(&self) -> u64 {
        self.frames_received.get()
    }

    fn producer_alive(&self) -> bool {
        crate::node_liveness(&names::producer_node_name(&self.run)) == Liveness::Alive
    }

    /// Takes everything buffered now; returns whether `f` asked to stop.
    fn drain(&self, f: &mut impl FnMut(LiveEvent) -> ControlFlow<()>) -> Result<bool, BusError> {
        let mut messages = Vec::new();
        loop {
            let Some(sample) = self
                .monitor
                .receive()
                .map_err(|e| BusError::new("receive monitor frame", e))?
            else {
                return Ok(false);
            };
            let h = *sample.user_header();
            // Frames and their counts come from another process: saturating arithmetic.
            match self.next_frame.get() {
                // The first frame: what came before it was published before the monitor was
                // there to receive it.
                None => self.frames_before_attach.set(h.frame_seq),
                Some(expected) if h.frame_seq > expected => {
                    self.frames_lost.set(
                        self.frames_lost
                            .get()
                            .saturating_add(h.frame_seq - expected),
                    );
                }
                Some(_) => {}
            }
            self.next_frame
                .set(Some(h.frame_seq.saturating_add(h.records)));
            let decoded = convert::decode_frame(&h, sample.payload(), &mut messages);
            drop(sample);
            // A frame that breaks the layout counts as lost, all its records.
            if decoded.is_err() {
                self.frames_lost
                    .set(self.frames_lost.get().saturating_add(h.records));
                continue;
            }
            self.frames_received
                .set(self.frames_received.get() + messages.len() as u64);
            for m in messages.drain(..) {
                if f(LiveEvent::Message(m)).is_break() {
                    return Ok(true);
                }
            }
        }
    }

    /// Delivers frames to `f` until it breaks, a signal arrives or the producer is gone.
    pub fn receive(
        &self,
        tick: Duration,
        mut f: impl FnMut(LiveEvent) -> ControlFlow<()>,
    ) -> Result<LiveEnded, LiveError> {
        crate::with_data_waitset(&self.listener, tick, |waitset| {
            let mut last_liveness = Instant::now();
            loop {
                let result = waitset
                    .wait_and_process_once(|_| CallbackProgression::Stop)
                    .map_err(|e| BusError::new("wait", e))?;
                // `Interrupt` is any interrupted wait, also a monitor resumed by SIGCONT after
                // SIGSTOP: a SIGINT or SIGTERM is reported as `TerminationRequest` next (and
                // latched by `chaoscope_os::signals` when iceoryx2 lost it).
                if result == WaitSetRunResult::TerminationRequest
                    || chaoscope_os::signals::requested()
                {
                    return Ok(LiveEnded::Signal);
                }
                let _ = self.listener.try_wait(|_| {});
                if self.drain(&mut f)? {
                    return Ok(LiveEnded::Stopped);
                }
                if f(LiveEvent::Tick).is_break() {
                    return Ok(LiveEnded::Stopped);
                }
                if last_liveness.elapsed() >= crate::POLL_INTERVAL {
                    last_liveness = Instant::now();
                    if !self.producer_alive() {
                        // What it delivered before going is still buffered: take it first.
                        if self.drain(&mut f)? {
                            return Ok(LiveEnded::Stopped);
                        }
                        return Ok(LiveEnded::ProducerGone);
                    }
                }
            }
        })
    }
}

/// Opens a service of `run` with `open` until the run has created it. `Ok(None)` on a
/// termination signal.
fn wait_for<T>(
    node: &Node<ipc::Service>,
    run: &str,
    start: Instant,
    timeout: Duration,
    open: &dyn Fn() -> Result<Option<T>, BusError>,
) -> Result<Option<T>, LiveError> {
    loop {
        if let Some(service) = open()? {
            return Ok(Some(service));
        }
        if start.elapsed() > timeout {
            return Err(LiveError::NoHeader {
                run: run.to_string(),
                timeout,
            });
        }
        if !crate::poll_wait(node) {
            return Ok(None);
        }
    }
}

/// Waits for the run header on `header`.
fn wait_header(
    node: &Node<ipc::Service>,
    header: &HeaderSubscriber,
    run: &str,
    start: Instant,
    timeout: Duration,
) -> Result<Option<RunHeader>, LiveError> {
    loop {
        if let Some(run_header) = crate::try_receive_run_header::<LiveError>(header, run)? {
            return Ok(Some(run_header));
        }
        if start.elapsed() > timeout {
            return Err(LiveError::NoHeader {
                run: run.to_string(),
                timeout,
            });
        }
        if !crate::poll_wait(node) {
            return Ok(None);
        }
    }
}
