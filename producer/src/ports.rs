//! The producer's side of the bus: header, lossless data and lossy monitor publishers, and the
//! data-ready notifier.

use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Duration;

use chaoscope_bus::frame::{FrameHeader, RunAnnouncement};
use chaoscope_bus::{self as bus, BusError, DataService, EventService, HeaderService};
use chaoscope_schemas::proto::RunHeader;
use iceoryx2::port::notifier::Notifier;
use iceoryx2::port::publisher::Publisher;
use iceoryx2::port::update_connections::UpdateConnections;
use iceoryx2::port::{BackpressureAction, BackpressureInfo};
use iceoryx2::prelude::*;
use prost::Message;

use chaoscope_os::termination::Termination;

/// How long a blocked send keeps waiting for a slow recorder after SIGINT/SIGTERM, so the final
/// frames (and the end-of-run record) still reach it.
const DRAIN_GRACE: Duration = Duration::from_secs(3);
/// How often a blocked send checks for dead subscribers.
const DEAD_CHECK_PERIOD: Duration = Duration::from_millis(200);
/// Retries of a blocked send that only yield the core (iceoryx2's own retry loop) before the
/// producer sleeps [`RETRY_SLEEP`] between retries. Why: a recorder that is about to take a
/// frame is met at once, but one busy for longer (compressing, writing a chunk) had the
/// producer spinning beside it, yielding in a loop: with every step sampled that was most of the
/// producer's CPU time (0.6 of 0.95 CPU-s for 6e5 messages), taken from the cores the recorder
/// and everything else on the machine share. The recorder's buffer holds 64 frames, so a wait
/// of this length never lets it run dry.
const SPIN_RETRIES: u64 = 16;
const RETRY_SLEEP: Duration = Duration::from_micros(50);

pub struct Ports {
    _node: Node<ipc::Service>,
    data_service: DataService,
    monitor_service: DataService,
    _event_service: EventService,
    ready_service: EventService,
    _header_service: HeaderService,
    header: Publisher<ipc::Service, [u8], RunAnnouncement>,
    data: Publisher<ipc::Service, [u64], FrameHeader>,
    monitor: Publisher<ipc::Service, [u64], FrameHeader>,
    notifier: Notifier<ipc::Service>,
}

/// Waits on a recorder whose buffer is full, but gives up on dead ones (their stale resources
/// are removed, which disconnects them) and, after a grace period, when asked to stop.
fn backpressure_handler(
    termination: Termination,
) -> impl Fn(&BackpressureInfo) -> BackpressureAction + Send {
    let last_check_ms = Arc::new(AtomicU64::new(0));
    move |info| {
        if termination.requested() && info.elapsed_time > DRAIN_GRACE {
            return BackpressureAction::DiscardDataAndFail;
        }
        let elapsed_ms = info.elapsed_time.as_millis() as u64;
        let last = if info.retries == 0 {
            0
        } else {
            last_check_ms.load(Ordering::Relaxed)
        };
        if elapsed_ms >= last + DEAD_CHECK_PERIOD.as_millis() as u64 {
            last_check_ms.store(elapsed_ms, Ordering::Relaxed);
            // Removing a dead subscriber's resources disconnects it; the blocked send then
            // returns by itself.
            bus::cleanup_dead_nodes();
        } else if info.retries == 0 {
            last_check_ms.store(0, Ordering::Relaxed);
        }
        if info.retries >= SPIN_RETRIES {
            std::thread::sleep(RETRY_SLEEP);
        }
        BackpressureAction::Retry
    }
}

impl Ports {
    /// Creates the node and every service of `run`; `max_payload` is the longest frame payload
    /// in words, `monitor_buffer` the frames each monitor can hold.
    pub fn open(
        node_name: &str,
        run: &str,
        max_payload: usize,
        monitor_buffer: usize,
        termination: &Termination,
    ) -> Result<Self, BusError> {
        let node = bus::create_node(node_name)?;
        let header_service = bus::header_service(&node, run)?;
        let data_service = bus::data_service(&node, run)?;
        let monitor_service = bus::monitor_service(&node, run, monitor_buffer)?;
        let event_service = bus::data_ready_service(&node, run)?;
        let ready_service = bus::ready_service(&node, run)?;
        let header = header_service
            .publisher_builder()
            .initial_max_slice_len(4096)
            .allocation_strategy(AllocationStrategy::PowerOfTwo)
            .create()
            .map_err(|e| BusError::new("create header publisher", e))?;
        let data = data_service
            .publisher_builder()
            .initial_max_slice_len(max_payload.max(1))
            .allocation_strategy(AllocationStrategy::Static)
            .backpressure_strategy(BackpressureStrategy::RetryUntilDelivered)
            .set_backpressure_handler(backpressure_handler(termination.clone()))
            .create()
            .map_err(|e| BusError::new("create data publisher", e))?;
        let monitor = monitor_service
            .publisher_builder()
            .initial_max_slice_len(max_payload.max(1))
            .allocation_strategy(AllocationStrategy::Static)
            .backpressure_strategy(BackpressureStrategy::DiscardData)
            .create()
            .map_err(|e| BusError::new("create monitor publisher", e))?;
        let notifier = event_service
            .notifier_builder()
            .create()
            .map_err(|e| BusError::new("create notifier", e))?;
        Ok(Self {
            _node: node,
            data_service,
            monitor_service,
            _event_service: event_service,
            ready_service,
            _header_service: header_service,
            header,
            data,
            monitor,
            notifier,
        })
    }

    /// Publishes the run header; it stays as history for subscribers that come later.
    pub fn announce(&self, header: &RunHeader) -> Result<(), BusError> {
        let bytes = header.encode_to_vec();
        let mut sample = self
            .header
            .loan_slice_uninit(bytes.len())
            .map_err(|e| BusError::new("loan header sample", e))?;
        *sample.user_header_mut() = RunAnnouncement {
            producer_pid: std::process::id(),
            ..Default::default()
        };
        sample
            .write_from_slice(&bytes)
            .send()
            .map_err(|e| BusError::new("send run header", e))?;
        Ok(())
    }

    /// Hands the run header to subscribers that connected since the last call.
    pub fn refresh_connections(&self) {
        let _ = self.header.update_connections();
        let _ = self.data.update_connections();
    }

    /// Lossless receivers that declared their data connection up (see `stream::READY`).
    pub fn ready_receivers(&self) -> usize {
        self.ready_service.dynamic_config().number_of_listeners()
    }

    /// Lossless subscribers (recorders, checkers) currently connected to the data stream.
    pub fn data_subscribers(&self) -> usize {
        self.data_service.dynamic_config().number_of_subscribers()
    }

    fn monitors(&self) -> usize {
        self.monitor_service
            .dynamic_config()
            .number_of_subscribers()
    }

    /// Sends one frame, to the recorders (waiting if they are behind) and to the monitors
    /// (never waiting).
    pub fn send(&mut self, header: FrameHeader, payload: &[u64]) -> Result<(), BusError> {
        send_on(&self.data, header, payload).map_err(|e| BusError::new("send data frame", e))?;
        if self.monitors() > 0 {
            // A monitor that cannot keep up just misses frames.
            let _ = send_on(&self.monitor, header, payload);
        }
        Ok(())
    }

    /// Wakes the subscribers' WaitSets.
    pub fn notify(&self) {
        let _ = self.notifier.notify();
    }
}

fn send_on(
    publisher: &Publisher<ipc::Service, [u64], FrameHeader>,
    header: FrameHeader,
    payload: &[u64],
) -> Result<(), Box<dyn std::error::Error>> {
    let mut sample = publisher.loan_slice_uninit(payload.len())?;
    *sample.user_header_mut() = header;
    sample.write_from_slice(payload).send()?;
    Ok(())
}
