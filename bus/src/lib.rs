//! chaoscope-bus: everything chaoscope sends over iceoryx2 (shared memory), and nothing a file
//! carries (that is `chaoscope-schemas`).
//!
//! - [`frame`]: the `#[repr(C)]` user headers and the payload layout of the data frames.
//! - [`convert`]: frames to the protobuf messages a recording stores, and the run header
//!   decoder every receiver uses.
//! - this module: how every process opens the services of a run (below), the per-user domain,
//!   liveness, the idle wait; `stale`: what killed processes leave behind, removed.
//! - [`monitor`]: a monitor's subscriber on a run's lossy monitor stream.
//! - [`signals`]: the SIGINT/SIGTERM latch installed after iceoryx2's handlers.
//!
//! # Opening the services of a run
//!
//! Producer, recorders, checkers and monitors all go through these functions, so service QoS
//! (buffer sizes, overflow policy) cannot drift between them: iceoryx2 refuses to connect ports
//! whose service settings or header `type_name`s disagree.
//!
//! Delivery guarantees:
//! - `data`: safe overflow OFF. With the producer's publisher on
//!   `BackpressureStrategy::RetryUntilDelivered`, a full subscriber buffer makes the producer wait
//!   instead of dropping: recorders are lossless. (It waits asleep after a few quick retries:
//!   the producer's backpressure handler.)
//! - `monitor`: safe overflow ON, so the oldest sample is overwritten for a slow monitor and the
//!   producer never waits for it.
//! - `header`: history 1, so a subscriber that arrives late still gets the run header.
//! - map `points`: safe overflow ON (a slow watcher loses the oldest points, `chaoscope map`
//!   never waits); map `header`: history 1.

use std::os::unix::fs::{DirBuilderExt, MetadataExt, PermissionsExt};
use std::path::PathBuf;
use std::sync::OnceLock;
use std::time::Duration;

use iceoryx2::node::{DeadNodeView, NodeDetails, NodeView};
use iceoryx2::port::listener::Listener;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::prelude::*;
use iceoryx2::service::builder::event::{
    Builder as EventBuilder, EventCreateError, EventOpenError, EventOpenOrCreateError,
};
use iceoryx2::service::builder::publish_subscribe::{
    Builder as PubSubBuilder, PublishSubscribeCreateError, PublishSubscribeOpenError,
    PublishSubscribeOpenOrCreateError,
};
use iceoryx2::service::port_factory::{event, publish_subscribe};

use chaoscope_schemas::names::{self, map_stream, stream};
use chaoscope_schemas::proto::RunHeader;

use crate::convert::HeaderError;
use crate::frame::{FrameHeader, MapFrameHeader, RunAnnouncement};

pub mod convert;
pub mod frame;
pub mod monitor;
pub mod signals;
mod stale;

/// Frames a data subscriber can hold before the producer waits.
pub const DATA_BUFFER: usize = 64;
/// Payload words up to which a producer gathers records into one frame (8 KiB: a few dozen
/// samples of a small system, so the per-frame cost is shared by many; a record longer than
/// this travels in a frame of its own).
pub const FRAME_TARGET_WORDS: usize = 1024;

/// Longest frame payload of a run whose longest record has `longest_record` words.
pub fn max_frame_words(longest_record: usize) -> usize {
    longest_record.max(FRAME_TARGET_WORDS)
}
/// Fewest frames a monitor subscriber holds (older ones are overwritten); the producer sizes
/// the monitor service for whole samples with [`monitor_buffer_for`].
pub const MONITOR_BUFFER: usize = 8;
/// Shared memory the monitor stream may take (all monitors together), in bytes.
pub const MONITOR_MEMORY: usize = 64 << 20;

/// Frames a monitor buffer aims to hold when memory allows: a few hundred samples of a small
/// system, so a monitor descheduled for a moment on a busy machine still loses nothing.
pub const MONITOR_TARGET_FRAMES: usize = 4096;

/// Monitor buffer for a run whose samples take at most `frames_per_sample` frames of at most
/// `max_payload` words: at least two whole samples (the producer publishes a sample in one
/// burst) and [`MONITOR_TARGET_FRAMES`], bounded by [`MONITOR_MEMORY`] (large systems then
/// lose frames when a monitor falls behind, which monitors detect and report).
pub fn monitor_buffer_for(frames_per_sample: usize, max_payload: usize) -> usize {
    let frame_bytes = max_payload.max(1) * size_of::<u64>() + size_of::<FrameHeader>();
    let cap = MONITOR_MEMORY / (frame_bytes * MAX_MONITORS);
    (2 * frames_per_sample)
        .max(MONITOR_TARGET_FRAMES)
        .min(cap)
        .max(MONITOR_BUFFER)
}
/// Lossless subscribers (recorders, checkers) one run can have.
pub const MAX_DATA_SUBSCRIBERS: usize = 8;
/// Monitors one run can have.
pub const MAX_MONITORS: usize = 8;
/// Period at which waiting loops re-check liveness and signals.
pub const POLL_INTERVAL: Duration = Duration::from_millis(50);

/// The sleeps of a wait for a peer that usually answers within milliseconds (a recorder's
/// first look for its run's header, a producer's wait for its last reader to leave): 1 ms,
/// doubling up to [`POLL_INTERVAL`]. A fixed [`POLL_INTERVAL`] added up to that much to each
/// step of a run's handshake, most of a short run's wall-clock time; a wait that goes on costs
/// no more wake-ups than the fixed one after the first few.
#[derive(Debug, Clone)]
pub struct Backoff {
    next: Duration,
}

impl Default for Backoff {
    fn default() -> Self {
        Self {
            next: Duration::from_millis(1),
        }
    }
}

impl Backoff {
    /// The next sleep: twice the last, at most [`POLL_INTERVAL`].
    pub fn interval(&mut self) -> Duration {
        let interval = self.next;
        self.next = (interval * 2).min(POLL_INTERVAL);
        interval
    }
}

/// Sleeps one [`POLL_INTERVAL`] on `node`: [`poll_wait_for`].
pub fn poll_wait(node: &Node<ipc::Service>) -> bool {
    poll_wait_for(node, POLL_INTERVAL)
}

/// Sleeps `interval` on `node`; `false` once SIGINT or SIGTERM asked the process to end. Any
/// other interrupted sleep (SIGCONT after SIGSTOP, SIGCHLD) is not a request to end: a recorder
/// stopped and continued before its run started took it for Ctrl+C and quit, and its producer
/// waited in vain for it (found by `tests/crash_loop.rs`, seed 35). SIGINT/SIGTERM are also
/// read from `chaoscope_os::signals`, which iceoryx2 cannot lose.
pub fn poll_wait_for(node: &Node<ipc::Service>, interval: Duration) -> bool {
    !chaoscope_os::signals::requested()
        && !matches!(
            node.wait(interval),
            Err(iceoryx2::node::NodeWaitFailure::TerminationRequest)
        )
        && !chaoscope_os::signals::requested()
}

pub type DataService = publish_subscribe::PortFactory<ipc::Service, [u64], FrameHeader>;
pub type HeaderService = publish_subscribe::PortFactory<ipc::Service, [u8], RunAnnouncement>;
pub type EventService = event::PortFactory<ipc::Service>;
pub type MapService = publish_subscribe::PortFactory<ipc::Service, [u8], MapFrameHeader>;

/// Watchers one map can have.
pub const MAX_MAP_WATCHERS: usize = 4;
/// Points a map watcher holds before the oldest are overwritten.
pub const MAP_POINTS_BUFFER: usize = 1024;

/// A bus failure, with what was being done.
#[derive(Debug, thiserror::Error)]
#[error("iceoryx2: {what}: {detail}")]
pub struct BusError {
    pub what: String,
    pub detail: String,
}

impl BusError {
    pub fn new(what: impl Into<String>, detail: impl std::fmt::Debug) -> Self {
        Self {
            what: what.into(),
            detail: format!("{detail:?}"),
        }
    }

    /// The bus directory cannot be used (the message says why).
    fn directory(message: &str) -> Self {
        Self {
            what: "bus directory".into(),
            detail: message.into(),
        }
    }
}

/// Quiets iceoryx2's logger (it warns about a missing config file in every process); errors
/// still show. Call once at process start.
pub fn quiet_logging() {
    set_log_level(LogLevel::Error);
}

/// Environment variable naming the bus directory instead of `/tmp/chaoscope-bus-<uid>`.
pub const BUS_DIR_ENV: &str = "CHAOSCOPE_BUS_DIR";

/// Where and under which names this user's chaoscope processes meet on the bus.
///
/// iceoryx2's default domain (`/tmp/iceoryx2/`, shared-memory names `iox2_*`) is one for all
/// users: whoever creates `/tmp/iceoryx2` first owns it (another user can then delete or
/// replace everyone's service files, or, if it is root's, nobody else can use the bus), and two
/// users' runs of the same name collide in `/dev/shm`. chaoscope therefore gives each user a
/// domain of their own:
/// - the root directory (service and node files, event sockets) is `/tmp/chaoscope-bus-<uid>`
///   (or `$CHAOSCOPE_BUS_DIR`), created mode 0700 and refused unless it is a real directory
///   owned by this user with no group or other permissions, so nobody else can list, read,
///   create or delete anything in it;
/// - shared-memory segments are named `cs<uid>_<tag of the directory>_*` in `/dev/shm` and created by iceoryx2 mode
///   0600 (built without its `dev_permissions` feature), which the sticky bit of `/dev/shm`
///   keeps other users from deleting; the one segment iceoryx2 makes world-writable (a node
///   counter, `*.global_mgmt`) is narrowed to 0600 by [`create_node`].
///
/// Every process of the same user (producer, recorders, monitors, map watchers) computes the
/// same domain, so they still meet; a process of another user computes its own.
#[derive(Debug, Clone)]
pub struct Domain {
    /// The iceoryx2 root directory.
    pub root: PathBuf,
    /// Prefix of every file and shared-memory segment iceoryx2 creates.
    pub prefix: String,
    config: Config,
}

impl Domain {
    /// The iceoryx2 configuration with this domain's root and prefix.
    pub fn config(&self) -> &Config {
        &self.config
    }
}

/// This process's domain: computed (and its directory created and checked) once.
pub fn domain() -> Result<&'static Domain, BusError> {
    static DOMAIN: OnceLock<Result<Domain, String>> = OnceLock::new();
    DOMAIN
        .get_or_init(|| {
            // SAFETY: geteuid(2) cannot fail.
            let uid = unsafe { libc::geteuid() };
            let root = match std::env::var_os(BUS_DIR_ENV) {
                Some(dir) => PathBuf::from(dir),
                // Fixed, not $TMPDIR: every process of the user must find the same directory.
                None => PathBuf::from(format!("/tmp/chaoscope-bus-{uid}")),
            };
            make_domain(root)
        })
        .as_ref()
        .map_err(|e| BusError::directory(e))
}

/// The domain of the bus directory `root` (what processes started with `CHAOSCOPE_BUS_DIR=root`
/// use), its directory created and checked like [`domain`]'s.
pub fn domain_at(root: &std::path::Path) -> Result<Domain, BusError> {
    make_domain(root.to_path_buf()).map_err(|e| BusError::directory(&e))
}

fn make_domain(root: PathBuf) -> Result<Domain, String> {
    // SAFETY: geteuid(2) cannot fail.
    let uid = unsafe { libc::geteuid() };
    if !root.is_absolute() {
        return Err(format!(
            "{} = {} must be an absolute path",
            BUS_DIR_ENV,
            root.display()
        ));
    }
    // Before the directory is made: one whose sockets would not fit is refused, not created.
    // The user and the directory in every segment name: users never collide in /dev/shm, and
    // neither do two bus directories of one user (separate domains, e.g. per batch job).
    let prefix = format!(
        "cs{uid}_{:08x}_",
        fnv1a(root.as_os_str().as_encoded_bytes())
    );
    let mut config = Config::default();
    let mut root_text = root.to_string_lossy().into_owned();
    if !root_text.ends_with('/') {
        root_text.push('/');
    }
    let longest = longest_socket_path(root_text.len(), prefix.len());
    if longest > SOCKET_PATH_MAX {
        return Err(format!(
            "{} = {} is {} bytes long, too long for the bus's sockets: each listener is a unix \
             socket at DIR/{prefix}<listener id, up to {LISTENER_ID_DIGITS} digits>.event, which \
             must fit the {SOCKET_PATH_MAX} bytes of a socket path; use a directory of at most \
             {} bytes",
            BUS_DIR_ENV,
            root.display(),
            root.as_os_str().len(),
            max_bus_dir_len(prefix.len())
        ));
    }
    match std::fs::DirBuilder::new().mode(0o700).create(&root) {
        Ok(()) => {}
        Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => {}
        Err(e) => return Err(format!("creating {}: {e}", root.display())),
    }
    // lstat: a symbolic link planted by someone else is refused, not followed.
    let meta =
        std::fs::symlink_metadata(&root).map_err(|e| format!("reading {}: {e}", root.display()))?;
    if !meta.file_type().is_dir() {
        return Err(format!(
            "{} is not a directory (a link or file someone else may have planted); remove it",
            root.display()
        ));
    }
    if meta.uid() != uid {
        return Err(format!(
            "{} belongs to uid {}, not to you (uid {uid}): another user could read or change \
             your runs through it; remove it or set {BUS_DIR_ENV} to a directory of yours",
            root.display(),
            meta.uid()
        ));
    }
    if meta.permissions().mode() & 0o077 != 0 {
        // Ours, but open to others (made by hand or by an older umask): close it.
        std::fs::set_permissions(&root, std::fs::Permissions::from_mode(0o700))
            .map_err(|e| format!("making {} private: {e}", root.display()))?;
    }
    let root_path = Path::new(root_text.as_bytes())
        .map_err(|e| format!("{} as an iceoryx2 path: {e:?}", root.display()))?;
    config.global.set_root_path(&root_path);
    config.global.prefix = FileName::new(prefix.as_bytes())
        .map_err(|e| format!("{prefix} as an iceoryx2 prefix: {e:?}"))?;
    Ok(Domain {
        root,
        prefix,
        config,
    })
}

/// The longest path of a unix socket: `sun_path` is 108 bytes, its last the terminating NUL.
pub const SOCKET_PATH_MAX: usize = 107;

/// Digits of a listener's id in its socket's name: iceoryx2 names each listener's socket by its
/// `UniqueListenerId`, a u128 written in decimal (up to 39 digits, the process's id counter in
/// its top bits: a long-lived process's ids grow longer).
const LISTENER_ID_DIGITS: usize = 39;

/// What iceoryx2 appends to the event sockets' names (`Config::global.service
/// .event_connection_suffix`).
const EVENT_SUFFIX: &str = ".event";

/// The longest socket path iceoryx2 makes in a root directory written in `root_with_slash`
/// bytes (its trailing `/` included) under a prefix of `prefix` bytes: an event listener's,
/// `ROOT/PREFIX<id>.event` (`event_config` and `event_concept_name` of iceoryx2).
fn longest_socket_path(root_with_slash: usize, prefix: usize) -> usize {
    root_with_slash + prefix + LISTENER_ID_DIGITS + EVENT_SUFFIX.len()
}

/// The longest bus directory (without a trailing `/`) whose sockets fit [`SOCKET_PATH_MAX`],
/// under a prefix of `prefix` bytes (`cs<uid>_<8 hex>_`: 48 bytes for uid 0, 45 for uid 1000).
pub fn max_bus_dir_len(prefix: usize) -> usize {
    SOCKET_PATH_MAX - longest_socket_path(1, prefix)
}

/// 32-bit FNV-1a: a short, stable tag of the bus directory for segment names.
fn fnv1a(bytes: &[u8]) -> u32 {
    bytes.iter().fold(0x811c_9dc5, |h, &b| {
        (h ^ u32::from(b)).wrapping_mul(0x0100_0193)
    })
}

/// Narrows this user's node-counter segments (which iceoryx2 creates world-writable) to 0600.
fn close_global_segments(domain: &Domain) {
    let Ok(entries) = std::fs::read_dir("/dev/shm") else {
        return;
    };
    // SAFETY: geteuid(2) cannot fail.
    let uid = unsafe { libc::geteuid() };
    for entry in entries.flatten() {
        let name = entry.file_name();
        let name = name.to_string_lossy();
        if !(name.starts_with(&domain.prefix) && name.ends_with(".global_mgmt")) {
            continue;
        }
        if let Ok(meta) = entry.metadata()
            && meta.uid() == uid
            && meta.permissions().mode() & 0o077 != 0
        {
            let _ = std::fs::set_permissions(entry.path(), std::fs::Permissions::from_mode(0o600));
        }
    }
}

/// Creates a node named `name` after removing stale resources left by crashed processes.
///
/// iceoryx2 handles SIGINT/SIGTERM for the node: waiting calls then report a termination
/// request, which every chaoscope loop honours.
pub fn create_node(name: &str) -> Result<Node<ipc::Service>, BusError> {
    quiet_logging();
    let domain = domain()?;
    cleanup_dead_nodes();
    let node_name: NodeName = name
        .try_into()
        .map_err(|e| BusError::new(format!("node name {name:?}"), e))?;
    let node = NodeBuilder::new()
        .name(&node_name)
        .config(domain.config())
        .create::<ipc::Service>()
        .map_err(|e| BusError::new(format!("create node {name:?}"), e))?;
    close_global_segments(domain);
    Ok(node)
}

/// Removes the shared memory and registrations of every dead node (a process killed with
/// SIGKILL cannot clean up after itself), and what iceoryx2's own cleanup leaves of processes
/// killed while they created or cleaned up nodes and services (see [`stale`]). Returns how many
/// dead nodes were removed.
pub fn cleanup_dead_nodes() -> usize {
    quiet_logging();
    let Ok(domain) = domain() else {
        return 0;
    };
    cleanup_dead_nodes_in(domain.config())
}

/// [`cleanup_dead_nodes`] in the domain of `config`.
pub fn cleanup_dead_nodes_in(config: &Config) -> usize {
    let layout = stale::Layout::of(config);
    // First what would make iceoryx2's cleanup of a dead node fail every time, or hang.
    layout.remove_unsized_segments();
    layout.remove_unfinished_records();
    let mut dead = Vec::new();
    let _ = Node::<ipc::Service>::list(config, |state| {
        if let NodeState::Dead(view) = state {
            dead.push(view);
        }
        CallbackProgression::Continue
    });
    let mut removed = dead
        .into_iter()
        .filter(|view| {
            if view.details().is_some() {
                return view.clone().try_remove_stale_resources().is_ok();
            }
            // Its details file is gone (its cleaner, or the node dropping itself, was killed
            // after removing it). iceoryx2 would then clean it up with the global configuration
            // (`/tmp/iceoryx2`), not ours, and never find it: give it our domain's. Only the
            // configuration of these details is used; the cleaner lock still refuses a node
            // whose owner is alive.
            DeadNodeView::<ipc::Service>::__internal_try_remove_stale_resources(
                *view.id(),
                NodeDetails::__internal_new(&None, config),
            )
            .is_ok()
        })
        .count();
    removed += layout.remove_dead_node_remnants();
    layout.remove_abandoned_creations();
    remove_orphaned_services(config, &layout);
    layout.remove_orphaned_port_segments();
    removed
}

/// Removes every service nobody holds (see [`stale`]): no node, alive or dead, holds a tag for
/// it, and no live process is registered in its dynamic configuration. Returns how many.
///
/// Every process that creates or opens a service makes its tag first and removes it only after
/// deregistering, so a service that some process is creating, opening or using always has a
/// tag; a dead node's tags are left to iceoryx2's dead-node cleanup (run just before). The
/// candidates are listed before the tags are read, and a creator cannot start a service whose
/// configuration still exists, so no creation that starts in between can be mistaken for one.
fn remove_orphaned_services(config: &Config, layout: &stale::Layout) -> usize {
    use iceoryx2::service::internal::ServiceInternal;
    let mut candidates = Vec::new();
    let _ = ipc::Service::list(config, |details| {
        let registered_alive = details.dynamic_details.as_ref().is_some_and(|d| {
            d.nodes.iter().any(|n| {
                let id = match n {
                    NodeState::Alive(v) => v.id(),
                    NodeState::Dead(v) => v.id(),
                    // Someone else's, or unreadable: leave it.
                    NodeState::Inaccessible(_) | NodeState::Undefined(_) => return true,
                };
                // A node of a live process that has no record left has dropped itself.
                stale::process_alive(stale::node_owner_pid(id.value()))
                    && layout.has_records(id.value())
            })
        });
        if !registered_alive {
            candidates.push(details.static_details);
        }
        CallbackProgression::Continue
    });
    if candidates.is_empty() {
        return 0;
    }
    let tagged = layout.tagged_hashes(|_| true);
    candidates
        .into_iter()
        .filter(|service| !tagged.contains(service.service_hash().as_str()))
        .filter(|service| {
            // SAFETY: no process uses the service: none holds its tag or is registered alive.
            unsafe { ipc::Service::__internal_remove_service(service, config) }.is_ok()
        })
        .count()
}

/// Liveness of a node, found by name among all nodes of the machine.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Liveness {
    Alive,
    /// The process died without cleaning up (crash, `kill -9`).
    Dead,
    /// No node of that name exists (never started, exited, or already cleaned up).
    Absent,
}

/// Liveness of the node named `name`.
pub fn node_liveness(name: &str) -> Liveness {
    quiet_logging();
    let mut result = Liveness::Absent;
    let Ok(domain) = domain() else {
        return result;
    };
    let _ = Node::<ipc::Service>::list(domain.config(), |state| {
        let (liveness, details) = match &state {
            NodeState::Alive(v) => (Liveness::Alive, v.details()),
            NodeState::Dead(v) => (Liveness::Dead, v.details()),
            _ => return CallbackProgression::Continue,
        };
        if details.as_ref().is_some_and(|d| d.name().as_str() == name) {
            result = liveness;
            if liveness == Liveness::Alive {
                return CallbackProgression::Stop;
            }
        }
        CallbackProgression::Continue
    });
    result
}

/// Why [`open_alone`] opened nothing.
#[derive(Debug)]
pub enum OpenAloneError {
    /// A live node of that name holds the services.
    Held,
    Bus(BusError),
}

/// Opens with `open` the services of a process that must be alone on the bus under the node
/// name `node_name` (a run's producer, a map's publisher), unless a live node of that name
/// already holds them. Two processes started at the same moment both find no such node before
/// opening; the one that opens second fails to get the publishers (one per stream) and then
/// finds the other alive, so it too reports [`OpenAloneError::Held`] rather than the bus's
/// slot count.
pub fn open_alone<T>(
    node_name: &str,
    open: impl FnOnce() -> Result<T, BusError>,
) -> Result<T, OpenAloneError> {
    cleanup_dead_nodes();
    if node_liveness(node_name) == Liveness::Alive {
        return Err(OpenAloneError::Held);
    }
    open().map_err(|e| match node_liveness(node_name) {
        Liveness::Alive => OpenAloneError::Held,
        _ => OpenAloneError::Bus(e),
    })
}

fn service_name(run: &str, stream: &str) -> Result<ServiceName, BusError> {
    let name = names::service_name(run, stream);
    name.as_str()
        .try_into()
        .map_err(|e| BusError::new(format!("service name {name:?}"), e))
}

/// How long a run's participant keeps repairing and retrying a service that hangs in creation
/// (each attempt first waits iceoryx2's creation timeout, 1 s).
const CREATION_REPAIR_TIMEOUT: Duration = Duration::from_secs(10);

/// Opens or creates a service of a run's participant (producer, recorder; for maps also the
/// watchers, which must be subscribed before a short map's first point): the one of them that
/// comes first creates it. A process killed while creating a service leaves it "hanging in
/// creation" (iceoryx2 waits 1 s for it, then fails with `HangsInCreation`): the participant
/// then removes what dead processes left (a half-created service only once no live process
/// holds it, see [`stale`]) and tries again, for up to [`CREATION_REPAIR_TIMEOUT`].
fn open_or_create<T, E: std::fmt::Debug>(
    node: &Node<ipc::Service>,
    what: impl Fn() -> String,
    hangs: impl Fn(&E) -> bool,
    mut attempt: impl FnMut() -> Result<T, E>,
) -> Result<T, BusError> {
    let start = std::time::Instant::now();
    loop {
        match attempt() {
            Ok(service) => return Ok(service),
            Err(e) if hangs(&e) && start.elapsed() < CREATION_REPAIR_TIMEOUT => {
                cleanup_dead_nodes_in(node.config());
            }
            Err(e) => return Err(BusError::new(what(), e)),
        }
    }
}

/// Opens a service of a run for a monitor: monitors never create a run's services (the
/// producer sizes them, and a monitor killed while creating one would leave it hanging in
/// creation for the run's own processes). `Ok(None)` while the service does
/// not exist or is still being created: the caller waits and tries again.
fn open_existing<T, E: std::fmt::Debug>(
    node: &Node<ipc::Service>,
    what: impl Fn() -> String,
    absent: impl Fn(&E) -> bool,
    hangs: impl Fn(&E) -> bool,
    open: impl FnOnce() -> Result<T, E>,
) -> Result<Option<T>, BusError> {
    match open() {
        Ok(service) => Ok(Some(service)),
        Err(e) if absent(&e) => Ok(None),
        Err(e) if hangs(&e) => {
            // Its creator may have been killed: let the next attempt find it repaired.
            cleanup_dead_nodes_in(node.config());
            Ok(None)
        }
        Err(e) => Err(BusError::new(what(), e)),
    }
}

fn pubsub_hangs(e: &PublishSubscribeOpenOrCreateError) -> bool {
    matches!(
        e,
        PublishSubscribeOpenOrCreateError::PublishSubscribeOpenError(
            PublishSubscribeOpenError::HangsInCreation
        ) | PublishSubscribeOpenOrCreateError::PublishSubscribeCreateError(
            PublishSubscribeCreateError::HangsInCreation
                | PublishSubscribeCreateError::IsBeingCreatedByAnotherInstance
        ) | PublishSubscribeOpenOrCreateError::SystemInFlux
    )
}

fn event_hangs(e: &EventOpenOrCreateError) -> bool {
    matches!(
        e,
        EventOpenOrCreateError::EventOpenError(EventOpenError::HangsInCreation)
            | EventOpenOrCreateError::EventCreateError(
                EventCreateError::IsBeingCreatedByAnotherInstance
            )
            | EventOpenOrCreateError::SystemInFlux
    )
}

fn pubsub_absent(e: &PublishSubscribeOpenError) -> bool {
    matches!(
        e,
        PublishSubscribeOpenError::DoesNotExist | PublishSubscribeOpenError::IsMarkedForDestruction
    )
}

fn pubsub_open_hangs(e: &PublishSubscribeOpenError) -> bool {
    matches!(e, PublishSubscribeOpenError::HangsInCreation)
}

fn event_absent(e: &EventOpenError) -> bool {
    matches!(
        e,
        EventOpenError::DoesNotExist | EventOpenError::IsMarkedForDestruction
    )
}

fn event_open_hangs(e: &EventOpenError) -> bool {
    matches!(e, EventOpenError::HangsInCreation)
}

type DataBuilder = PubSubBuilder<[u64], FrameHeader, ipc::Service>;
type HeaderBuilder = PubSubBuilder<[u8], RunAnnouncement, ipc::Service>;
type MapBuilder = PubSubBuilder<[u8], MapFrameHeader, ipc::Service>;

// The settings of each service, in one place: the process creating a service sets them, the
// processes opening it require them.

fn data_builder(node: &Node<ipc::Service>, name: &ServiceName) -> DataBuilder {
    node.service_builder(name)
        .publish_subscribe::<[u64]>()
        .user_header::<FrameHeader>()
        .enable_safe_overflow(false)
        .history_size(0)
        .subscriber_max_buffer_size(DATA_BUFFER)
        .max_subscribers(MAX_DATA_SUBSCRIBERS)
        .max_publishers(1)
}

fn monitor_builder(node: &Node<ipc::Service>, name: &ServiceName, buffer: usize) -> DataBuilder {
    node.service_builder(name)
        .publish_subscribe::<[u64]>()
        .user_header::<FrameHeader>()
        .enable_safe_overflow(true)
        .history_size(1)
        .subscriber_max_buffer_size(buffer.max(MONITOR_BUFFER))
        .max_subscribers(MAX_MONITORS)
        .max_publishers(1)
}

fn header_builder(node: &Node<ipc::Service>, name: &ServiceName) -> HeaderBuilder {
    node.service_builder(name)
        .publish_subscribe::<[u8]>()
        .user_header::<RunAnnouncement>()
        .enable_safe_overflow(true)
        .history_size(1)
        .subscriber_max_buffer_size(2)
        .max_subscribers(MAX_DATA_SUBSCRIBERS + MAX_MONITORS)
        .max_publishers(1)
}

fn data_ready_builder(node: &Node<ipc::Service>, name: &ServiceName) -> EventBuilder<ipc::Service> {
    node.service_builder(name)
        .event()
        .max_notifiers(2)
        .max_listeners(MAX_DATA_SUBSCRIBERS + MAX_MONITORS)
}

fn ready_builder(node: &Node<ipc::Service>, name: &ServiceName) -> EventBuilder<ipc::Service> {
    node.service_builder(name)
        .event()
        .max_notifiers(2)
        .max_listeners(MAX_DATA_SUBSCRIBERS)
}

fn map_header_builder(node: &Node<ipc::Service>, name: &ServiceName) -> MapBuilder {
    node.service_builder(name)
        .publish_subscribe::<[u8]>()
        .user_header::<MapFrameHeader>()
        .enable_safe_overflow(true)
        .history_size(1)
        .subscriber_max_buffer_size(2)
        .max_subscribers(MAX_MAP_WATCHERS)
        .max_publishers(1)
}

fn map_points_builder(node: &Node<ipc::Service>, name: &ServiceName) -> MapBuilder {
    node.service_builder(name)
        .publish_subscribe::<[u8]>()
        .user_header::<MapFrameHeader>()
        .enable_safe_overflow(true)
        .history_size(0)
        .subscriber_max_buffer_size(MAP_POINTS_BUFFER)
        .max_subscribers(MAX_MAP_WATCHERS)
        .max_publishers(1)
}

/// The lossless data stream of `run`.
pub fn data_service(node: &Node<ipc::Service>, run: &str) -> Result<DataService, BusError> {
    let name = service_name(run, stream::DATA)?;
    open_or_create(
        node,
        || format!("open data service of run {run:?}"),
        pubsub_hangs,
        || data_builder(node, &name).open_or_create(),
    )
}

/// The lossy monitor stream of `run`, for its producer, which sizes it: `buffer` frames per
/// monitor.
pub fn monitor_service(
    node: &Node<ipc::Service>,
    run: &str,
    buffer: usize,
) -> Result<DataService, BusError> {
    let name = service_name(run, stream::MONITOR)?;
    open_or_create(
        node,
        || format!("open monitor service of run {run:?}"),
        pubsub_hangs,
        || monitor_builder(node, &name, buffer).open_or_create(),
    )
}

/// The monitor stream of `run` if its producer has created it (monitors get the buffer size
/// the producer chose, at least [`MONITOR_BUFFER`]).
pub fn open_monitor_service(
    node: &Node<ipc::Service>,
    run: &str,
) -> Result<Option<DataService>, BusError> {
    let name = service_name(run, stream::MONITOR)?;
    open_existing(
        node,
        || format!("open monitor service of run {run:?}"),
        pubsub_absent,
        pubsub_open_hangs,
        || monitor_builder(node, &name, MONITOR_BUFFER).open(),
    )
}

/// The run-header stream of `run` (history 1 for late subscribers).
pub fn header_service(node: &Node<ipc::Service>, run: &str) -> Result<HeaderService, BusError> {
    let name = service_name(run, stream::HEADER)?;
    open_or_create(
        node,
        || format!("open header service of run {run:?}"),
        pubsub_hangs,
        || header_builder(node, &name).open_or_create(),
    )
}

/// The run-header stream of `run` if its producer (or recorder) has created it.
pub fn open_header_service(
    node: &Node<ipc::Service>,
    run: &str,
) -> Result<Option<HeaderService>, BusError> {
    let name = service_name(run, stream::HEADER)?;
    open_existing(
        node,
        || format!("open header service of run {run:?}"),
        pubsub_absent,
        pubsub_open_hangs,
        || header_builder(node, &name).open(),
    )
}

/// The wake-up event the producer notifies after publishing data.
pub fn data_ready_service(node: &Node<ipc::Service>, run: &str) -> Result<EventService, BusError> {
    let name = service_name(run, stream::DATA_READY)?;
    open_or_create(
        node,
        || format!("open event service of run {run:?}"),
        event_hangs,
        || data_ready_builder(node, &name).open_or_create(),
    )
}

/// The data-ready event of `run` if its producer (or recorder) has created it.
pub fn open_data_ready_service(
    node: &Node<ipc::Service>,
    run: &str,
) -> Result<Option<EventService>, BusError> {
    let name = service_name(run, stream::DATA_READY)?;
    open_existing(
        node,
        || format!("open event service of run {run:?}"),
        event_absent,
        event_open_hangs,
        || data_ready_builder(node, &name).open(),
    )
}

/// The readiness service of `run` (see [`names::stream::READY`]).
pub fn ready_service(node: &Node<ipc::Service>, run: &str) -> Result<EventService, BusError> {
    let name = service_name(run, stream::READY)?;
    open_or_create(
        node,
        || format!("open ready service of run {run:?}"),
        event_hangs,
        || ready_builder(node, &name).open_or_create(),
    )
}

/// A receiver's subscription to the run-header stream.
pub type HeaderSubscriber = Subscriber<ipc::Service, [u8], RunAnnouncement>;

/// Subscribes to the run-header stream of `service`.
pub fn header_subscriber(service: &HeaderService) -> Result<HeaderSubscriber, BusError> {
    service
        .subscriber_builder()
        .create()
        .map_err(|e| BusError::new("create header subscriber", e))
}

/// The run header of `run` if it has arrived (it is kept as history, so it also reaches late
/// subscribers), its format version checked.
pub fn try_receive_run_header<E: From<BusError> + From<HeaderError>>(
    header: &HeaderSubscriber,
    run: &str,
) -> Result<Option<RunHeader>, E> {
    let received = header
        .receive()
        .map_err(|e| BusError::new("receive run header", e))?;
    let Some(sample) = received else {
        return Ok(None);
    };
    Ok(Some(crate::convert::decode_run_header(
        run,
        sample.user_header(),
        sample.payload(),
    )?))
}

/// Runs `wait_loop` with a WaitSet that wakes a receiver when the producer notifies new data on
/// `listener` (its data-ready event), and at least every `interval` (liveness checks, display
/// refreshes). The attachments last as long as the loop.
pub fn with_data_waitset<T, E: From<BusError>>(
    listener: &Listener<ipc::Service>,
    interval: Duration,
    wait_loop: impl FnOnce(&WaitSet<ipc::Service>) -> Result<T, E>,
) -> Result<T, E> {
    let waitset = WaitSetBuilder::new()
        .create::<ipc::Service>()
        .map_err(|e| BusError::new("create waitset", e))?;
    let _data_ready = waitset
        .attach_notification(listener)
        .map_err(|e| BusError::new("attach listener", e))?;
    let _interval = waitset
        .attach_interval(interval)
        .map_err(|e| BusError::new("attach interval", e))?;
    wait_loop(&waitset)
}

fn map_service_name(map: &str, stream: &str) -> Result<ServiceName, BusError> {
    let name = names::map_service_name(map, stream);
    name.as_str()
        .try_into()
        .map_err(|e| BusError::new(format!("service name {name:?}"), e))
}

/// The header stream of map `map` (history 1 for late watchers).
pub fn map_header_service(node: &Node<ipc::Service>, map: &str) -> Result<MapService, BusError> {
    let name = map_service_name(map, map_stream::HEADER)?;
    open_or_create(
        node,
        || format!("open header service of map {map:?}"),
        pubsub_hangs,
        || map_header_builder(node, &name).open_or_create(),
    )
}

/// The lossy point stream of map `map`.
pub fn map_points_service(node: &Node<ipc::Service>, map: &str) -> Result<MapService, BusError> {
    let name = map_service_name(map, map_stream::POINTS)?;
    open_or_create(
        node,
        || format!("open point service of map {map:?}"),
        pubsub_hangs,
        || map_points_builder(node, &name).open_or_create(),
    )
}

/// Names of the maps whose header service currently exists on this machine.
pub fn list_maps() -> Vec<String> {
    quiet_logging();
    let mut maps = Vec::new();
    let Ok(domain) = domain() else {
        return maps;
    };
    let _ = ipc::Service::list(domain.config(), |details| {
        if let Some(map) = names::map_of_header_service(details.static_details.name().as_str()) {
            maps.push(map.to_string());
        }
        CallbackProgression::Continue
    });
    maps.sort();
    maps.dedup();
    maps
}

/// Names of the runs whose header service currently exists on this machine.
pub fn list_runs() -> Vec<String> {
    quiet_logging();
    let mut runs = Vec::new();
    let Ok(domain) = domain() else {
        return runs;
    };
    let _ = ipc::Service::list(domain.config(), |details| {
        if let Some(run) = names::run_of_header_service(details.static_details.name().as_str()) {
            runs.push(run.to_string());
        }
        CallbackProgression::Continue
    });
    runs.sort();
    runs.dedup();
    runs
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A handshake's sleeps start at 1 ms and double to the poll interval, never past it.
    #[test]
    fn backoff_doubles_from_a_millisecond_to_the_poll_interval() {
        let mut backoff = Backoff::default();
        let ms: Vec<u128> = (0..9).map(|_| backoff.interval().as_millis()).collect();
        assert_eq!(ms, [1, 2, 4, 8, 16, 32, 50, 50, 50]);
    }

    /// A directory under the temporary one whose path is exactly `len` bytes.
    fn dir_of_len(base: &std::path::Path, len: usize) -> PathBuf {
        let base = base.to_string_lossy().into_owned();
        assert!(base.len() + 2 <= len, "{base} is too long for {len}");
        PathBuf::from(format!("{base}/{}", "d".repeat(len - base.len() - 1)))
    }

    #[test]
    fn a_bus_directory_is_refused_up_front_when_its_sockets_would_not_fit() {
        // SAFETY: geteuid(2) cannot fail.
        let uid = unsafe { libc::geteuid() };
        let prefix = format!("cs{uid}_00000000_").len();
        let max = max_bus_dir_len(prefix);
        // sun_path holds 107 bytes and its NUL; the socket adds '/', the prefix, 39 digits
        // and ".event": 108 - 1 - 1 - prefix - 39 - 6 (48 for uid 0).
        assert_eq!(max, 108 - 1 - 1 - prefix - 39 - 6);
        let base = PathBuf::from(format!("/tmp/cbus-{}", std::process::id()));
        std::fs::create_dir_all(&base).unwrap();
        // At the limit: the domain is made, and a listener opens a socket in it.
        let at = dir_of_len(&base, max);
        let domain = domain_at(&at).unwrap();
        quiet_logging();
        let node = NodeBuilder::new()
            .config(domain.config())
            .create::<ipc::Service>()
            .unwrap();
        let service = node
            .service_builder(&"length-test".try_into().unwrap())
            .event()
            .open_or_create()
            .unwrap();
        let listener = service.listener_builder().create().unwrap();
        drop((listener, service, node));
        // One byte beyond (a trailing slash counts for nothing): refused in one line saying
        // why and how long it may be, before iceoryx2 is asked.
        let beyond = dir_of_len(&base, max + 1);
        let why = domain_at(&beyond).unwrap_err().to_string();
        assert!(
            why.contains("too long for the bus's sockets")
                && why.contains(&format!("at most {max} bytes"))
                && !why.contains('\n'),
            "{why}"
        );
        assert!(!beyond.exists(), "a refused directory was made");
        assert!(domain_at(&PathBuf::from(format!("{}/", at.display()))).is_ok());
        std::fs::remove_dir_all(&base).unwrap();
    }

    #[test]
    fn monitor_buffer_holds_whole_samples_within_the_memory_bound() {
        // Small frames: the target applies.
        assert_eq!(monitor_buffer_for(13, 20), MONITOR_TARGET_FRAMES);
        // Many sets: two whole samples.
        assert_eq!(monitor_buffer_for(5001, 20), 10_002);
        // Henon-Heiles in frames of many records: memory bounds it.
        let b = monitor_buffer_for(3, max_frame_words(28));
        assert!(b * FRAME_TARGET_WORDS * 8 * MAX_MONITORS <= MONITOR_MEMORY);
        assert!(b >= 2 * 3);
        // FPUT N = 501, k = 8: 8 kdoubles per frame; memory bounds it, never below the minimum.
        let b = monitor_buffer_for(3, 8 * 1002 + 8);
        assert!(b * (8 * 1002 + 8) * 8 * MAX_MONITORS <= MONITOR_MEMORY + (1 << 20));
        assert!(b >= MONITOR_BUFFER);
        assert_eq!(monitor_buffer_for(3, 10_000_000), MONITOR_BUFFER);
    }
}
