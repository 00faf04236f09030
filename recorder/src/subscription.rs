//! The bus side of a receiver: subscribe to a run, wait for its header, then receive its data
//! frames, waking on the producer's iceoryx2 events (no busy polling) and watching the
//! producer's node liveness.
//!
//! Used by the recorder and by anything else that must receive every frame (a checker).

use std::cell::{Cell, RefCell};
use std::ops::ControlFlow;
use std::time::{Duration, Instant};

use chaoscope_bus::convert::{self, FrameError, HeaderError};
use chaoscope_bus::frame::FrameHeader;
use chaoscope_bus::{
    self as bus, BusError, DataService, EventService, HeaderService, HeaderSubscriber, Liveness,
};
use chaoscope_schemas::names;
use chaoscope_schemas::proto::DataMessage;
use chaoscope_schemas::proto::RunHeader;
use iceoryx2::port::listener::Listener;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::port::update_connections::UpdateConnections;
use iceoryx2::prelude::*;
use iceoryx2::waitset::WaitSetRunResult;

/// How long a receiver that got SIGINT or SIGTERM still takes frames, waiting for the
/// producer's end-of-run record: a terminal's Ctrl+C, or `chaoscope run` passing a signal on,
/// reaches the producer at the same moment, which then stops at once and says so; a recording
/// that holds that record says how the run ended (`analyze`'s `run.end`). A producer that goes
/// on (a recorder stopped alone) costs this wait, well inside the second a signal is given.
pub const SIGNAL_GRACE: Duration = Duration::from_millis(250);

/// What a receiver sees.
#[derive(Debug)]
pub enum BusEvent {
    Message(DataMessage),
    /// A frame that breaks the layout; it is skipped (the sequence numbers show the hole).
    Invalid(FrameError),
    /// Periodic wake-up while no data flows ([`bus::POLL_INTERVAL`]).
    Tick,
}

/// Why [`RunSubscription::receive`] returned.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Ended {
    /// The callback asked to stop.
    Stopped,
    /// SIGINT or SIGTERM.
    Signal,
    /// The producer's node died or vanished; every frame it had delivered was received first.
    ProducerGone,
}

#[derive(Debug, thiserror::Error)]
pub enum SubscribeError {
    #[error(transparent)]
    Bus(#[from] BusError),
    #[error(transparent)]
    Header(#[from] HeaderError),
    #[error("run {run:?}: the producer went away before publishing its run header")]
    NoHeader { run: String },
    #[error("run {run:?}: no run header within {0:?}", .timeout)]
    HeaderTimeout { run: String, timeout: Duration },
}

/// A subscription to one run.
pub struct RunSubscription {
    run: String,
    node: Node<ipc::Service>,
    data: Subscriber<ipc::Service, [u64], FrameHeader>,
    header: HeaderSubscriber,
    listener: Listener<ipc::Service>,
    ready_service: EventService,
    /// Held once the data connection is up; tells the producer this receiver is ready.
    ready: std::cell::OnceCell<Listener<ipc::Service>>,
    _services: (DataService, HeaderService, EventService),
}

impl RunSubscription {
    /// Subscribes to `run` as the node `node_name`. Subscribe before the producer starts
    /// publishing data: a producer waits for its recorders, but frames sent before a subscriber
    /// exists are not replayed.
    pub fn open(run: &str, node_name: &str) -> Result<Self, SubscribeError> {
        let node = bus::create_node(node_name)?;
        let data_service = bus::data_service(&node, run)?;
        let header_service = bus::header_service(&node, run)?;
        let event_service = bus::data_ready_service(&node, run)?;
        // Header subscriber first: a producer starts streaming as soon as it sees the data
        // subscriber, and hands out the header history to the subscribers that exist then.
        let header = bus::header_subscriber(&header_service)?;
        let data = data_service
            .subscriber_builder()
            .buffer_size(bus::DATA_BUFFER)
            .create()
            .map_err(|e| BusError::new("create data subscriber", e))?;
        let ready_service = bus::ready_service(&node, run)?;
        let listener = event_service
            .listener_builder()
            .create()
            .map_err(|e| BusError::new("create listener", e))?;
        Ok(Self {
            run: run.to_string(),
            node,
            data,
            header,
            listener,
            ready_service,
            ready: std::cell::OnceCell::new(),
            _services: (data_service, header_service, event_service),
        })
    }

    pub fn run(&self) -> &str {
        &self.run
    }

    fn producer_liveness(&self) -> Liveness {
        bus::node_liveness(&names::producer_node_name(&self.run))
    }

    /// Waits for the run header (it is kept as history, so it also reaches late subscribers).
    /// `Ok(None)` means a termination signal arrived first.
    pub fn wait_header(
        &self,
        timeout: Option<Duration>,
    ) -> Result<Option<RunHeader>, SubscribeError> {
        let start = Instant::now();
        let mut seen_alive = false;
        let mut backoff = bus::Backoff::default();
        loop {
            if let Some(header) =
                bus::try_receive_run_header::<SubscribeError>(&self.header, &self.run)?
            {
                self.declare_ready()?;
                return Ok(Some(header));
            }
            // A producer that is not there yet may still come; one that was there and left
            // without a header never will.
            match self.producer_liveness() {
                Liveness::Alive => seen_alive = true,
                _ if seen_alive => {
                    return Err(SubscribeError::NoHeader {
                        run: self.run.clone(),
                    });
                }
                _ => {}
            }
            if let Some(timeout) = timeout
                && start.elapsed() > timeout
            {
                return Err(SubscribeError::HeaderTimeout {
                    run: self.run.clone(),
                    timeout,
                });
            }
            if !bus::poll_wait_for(&self.node, backoff.interval()) {
                return Ok(None);
            }
        }
    }

    /// Connects the receiving side of the data stream (the producer exists: it sent the
    /// header), then tells the producer so by holding a listener on the ready service.
    fn declare_ready(&self) -> Result<(), BusError> {
        self.data
            .update_connections()
            .map_err(|e| BusError::new("connect to the data stream", e))?;
        if self.ready.get().is_none() {
            let listener = self
                .ready_service
                .listener_builder()
                .create()
                .map_err(|e| BusError::new("create ready listener", e))?;
            let _ = self.ready.set(listener);
        }
        Ok(())
    }

    /// Receives up to one buffer of frames; returns how many arrived and whether `f` stopped.
    fn drain(
        &self,
        f: &mut impl FnMut(BusEvent) -> ControlFlow<()>,
    ) -> Result<(usize, bool), BusError> {
        let mut count = 0;
        let mut messages = Vec::new();
        while count < bus::DATA_BUFFER {
            let Some(sample) = self
                .data
                .receive()
                .map_err(|e| BusError::new("receive data", e))?
            else {
                break;
            };
            count += 1;
            let decoded =
                convert::decode_frame(sample.user_header(), sample.payload(), &mut messages);
            // Release the shared-memory sample before the (possibly slow) callback.
            drop(sample);
            if let Err(e) = decoded
                && f(BusEvent::Invalid(e)).is_break()
            {
                return Ok((count, true));
            }
            for m in messages.drain(..) {
                if f(BusEvent::Message(m)).is_break() {
                    return Ok((count, true));
                }
            }
        }
        Ok((count, false))
    }

    /// Delivers every data frame to `f` until `f` breaks, a signal's grace
    /// ([`SIGNAL_GRACE`]) has passed, or the producer is gone. Sleeps in a WaitSet on the
    /// producer's data-ready event and a liveness interval.
    pub fn receive(
        &self,
        mut f: impl FnMut(BusEvent) -> ControlFlow<()>,
    ) -> Result<Ended, SubscribeError> {
        // Results of the wake-up callback, read by the loop between calls.
        let ended = Cell::new(None);
        let failure = RefCell::new(None);
        // When a signal's grace ends: set when the signal is first seen.
        let grace_ends = Cell::new(None::<Instant>);
        let signal_grace_over = || {
            if !chaoscope_os::signals::requested() {
                return false;
            }
            let now = Instant::now();
            let ends = grace_ends.get().unwrap_or(now + SIGNAL_GRACE);
            grace_ends.set(Some(ends));
            now >= ends
        };
        let mut on_wake = |_id: WaitSetAttachmentId<ipc::Service>| {
            let _ = self.listener.try_wait(|_| {});
            let mut idle = true;
            loop {
                // A producer faster than this receiver keeps it draining: a signal must still
                // end it within its grace, not when the data stops.
                if signal_grace_over() {
                    ended.set(Some(Ended::Signal));
                    return CallbackProgression::Stop;
                }
                match self.drain(&mut f) {
                    Err(e) => *failure.borrow_mut() = Some(e),
                    Ok((_, true)) => ended.set(Some(Ended::Stopped)),
                    Ok((0, false)) => break,
                    Ok((_, false)) => {
                        idle = false;
                        continue;
                    }
                }
                return CallbackProgression::Stop;
            }
            if idle {
                if f(BusEvent::Tick).is_break() {
                    ended.set(Some(Ended::Stopped));
                    return CallbackProgression::Stop;
                }
                if self.producer_liveness() != Liveness::Alive {
                    // Frames it delivered before dying are still in our buffer: take them first.
                    loop {
                        match self.drain(&mut f) {
                            Err(e) => *failure.borrow_mut() = Some(e),
                            Ok((_, true)) => ended.set(Some(Ended::Stopped)),
                            Ok((0, false)) => ended.set(Some(Ended::ProducerGone)),
                            Ok((_, false)) => continue,
                        }
                        return CallbackProgression::Stop;
                    }
                }
            }
            CallbackProgression::Continue
        };
        bus::with_data_waitset(&self.listener, bus::POLL_INTERVAL, |waitset| {
            loop {
                let result = waitset
                    .wait_and_process_once(&mut on_wake)
                    .map_err(|e| BusError::new("wait", e))?;
                if let Some(e) = failure.borrow_mut().take() {
                    return Err(e.into());
                }
                if let Some(ended) = ended.get() {
                    return Ok(ended);
                }
                // `Interrupt` is any interrupted wait, also a process resumed by SIGCONT after
                // SIGSTOP (epoll returns EINTR then): waiting again is right, since a SIGINT or
                // SIGTERM is reported as `TerminationRequest` by the next wait, and latched
                // (`chaoscope_os::signals`) even when iceoryx2 lost it (a SIGCONT after it
                // overwrites iceoryx2's record of the last signal).
                if (result == WaitSetRunResult::TerminationRequest
                    || chaoscope_os::signals::requested())
                    && signal_grace_over()
                {
                    return Ok(Ended::Signal);
                }
            }
        })
    }
}
