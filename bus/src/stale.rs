//! What a process killed (SIGKILL) at the wrong moment leaves in the bus directory, and its
//! removal where iceoryx2's own dead-node cleanup does not reach.
//!
//! iceoryx2 (0.10) keeps, per node `<id>` of a domain with root `R` and prefix `P`:
//! - `R/nodes/P<id>.node_monitor` (the state file; its owner holds an fcntl write lock on it for
//!   as long as it lives), `..._owner_lock` (write-locked by whoever cleans the node up) and
//!   `..._context` (the owner's process id; mode 0200 while the node is being created);
//! - `R/nodes/<id>/`: `Pnode.details` (name, pid, and the domain's configuration), one
//!   `P<hash>.service_tag` per service the node opened and one `P<port>.port_tag` per port.
//!
//! and per service `R/services/P<hash>.service`, its static configuration, created mode 0600,
//! written, fsynced, then made 0400: while it is 0600 the service "is being created", and every
//! other process opening it waits, then gives up with `HangsInCreation`.
//!
//! Every chaoscope process cleans up dead nodes when it starts (and iceoryx2 does so in every
//! node creation and destruction), so a process is often killed *while cleaning up* or while
//! creating its node or a service. Measured by killing `chaoscope record` at random moments in
//! its first 20 ms (40 kills): 9 services left at mode 0600 (killed during the fsync), node
//! directories holding service tags but no details file, monitor files without a state file,
//! node directories without monitor files. What iceoryx2 does with each:
//! - a dead node whose details file is gone (its cleaner was killed after removing it, or the
//!   node was killed while dropping itself): listed as dead, but iceoryx2 then cleans it with
//!   the *global* configuration (`/tmp/iceoryx2`, not our domain) and never finds it;
//! - a node killed while creating its monitor files (context still 0200), or whose cleaner was
//!   killed after removing the state file: never listed, never removed;
//! - a service left at 0600 by a killed creator: the creator's cleanup finds no readable
//!   configuration and removes only its tag; the service hangs in creation forever, and the run
//!   of that name can never start again.
//!
//! - a service whose last holder was killed in its `ServiceState::drop` after deregistering
//!   from the service and removing its tag, but before its storage handles dropped (they remove
//!   the dynamic and then the static configuration): complete, held by nobody, never looked at
//!   again. Seen in the crash loop: a producer SIGKILLed during its end-of-run cleanup left
//!   `chaoscope/run/<run>/header` for good.
//!
//! [`remove_stale`] removes these, and only when the owner is gone: a node's owner is the
//! process whose pid is part of the node id (iceoryx2's `UniqueSystemId`: seconds, nanoseconds,
//! pid, counter); it is alive while `kill(pid, 0)` finds it (a zombie counts as dead), and as in
//! iceoryx2 a write lock on the state file (its owner) or on the owner lock (a cleaner at work)
//! also means "leave it". A service's creator always holds its service tag before it creates the
//! configuration file (iceoryx2 creates the tag first), so a 0600 configuration that no node of
//! a live process holds a tag for has no creator left and is removed; iceoryx2 then creates the
//! service anew.

use std::collections::BTreeSet;
use std::os::unix::fs::PermissionsExt;
use std::path::{Path, PathBuf};

/// The pid of the process that created the node with the raw id `id`: iceoryx2's node ids are
/// `UniqueSystemId`s, `#[repr(C)] { seconds: u32, nanoseconds: u32, pid: u32, counter: u32 }`
/// transmuted to a `u128` (checked against `UniqueNodeId::pid` by a test).
pub(crate) fn node_owner_pid(id: u128) -> u32 {
    let bytes = id.to_ne_bytes();
    u32::from_ne_bytes([bytes[8], bytes[9], bytes[10], bytes[11]])
}

/// Whether process `pid` still runs (conservatively: when in doubt, it does).
pub(crate) fn process_alive(pid: u32) -> bool {
    let Ok(raw) = libc::pid_t::try_from(pid) else {
        return true;
    };
    if raw <= 0 {
        return true;
    }
    // SAFETY: kill with signal 0 only checks for existence and permission.
    if unsafe { libc::kill(raw, 0) } != 0 {
        // EPERM: it exists, as someone else's process.
        return std::io::Error::last_os_error().raw_os_error() != Some(libc::ESRCH);
    }
    // A killed child its parent has not reaped yet is a zombie: gone, its locks released.
    match std::fs::read_to_string(format!("/proc/{raw}/stat")) {
        Ok(stat) => !stat
            .rsplit_once(')')
            .is_some_and(|(_, rest)| matches!(rest.trim_start().chars().next(), Some('Z' | 'X'))),
        Err(_) => true,
    }
}

/// Whether some process holds an fcntl lock on `path` (iceoryx2's liveness and cleaner locks).
/// Absent files are unlocked. Never called on a file of this process's own nodes: closing any
/// descriptor of a file drops this process's fcntl locks on it.
fn locked(path: &Path) -> bool {
    use std::os::fd::AsRawFd;
    // Write-only: iceoryx2 creates these files 0200 and makes them 0600 once set up, and
    // F_GETLK needs no particular access mode.
    let file = match std::fs::OpenOptions::new().write(true).open(path) {
        Ok(f) => f,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return false,
        // Cannot tell: it may be locked.
        Err(_) => return true,
    };
    // SAFETY: a zeroed flock is a valid argument; F_GETLK only fills it in.
    let mut lock: libc::flock = unsafe { std::mem::zeroed() };
    lock.l_type = libc::F_WRLCK as _;
    lock.l_whence = libc::SEEK_SET as _;
    // SAFETY: the descriptor is open for the duration of the call.
    if unsafe { libc::fcntl(file.as_raw_fd(), libc::F_GETLK, &mut lock) } == -1 {
        return true;
    }
    // The field's own type named: `as _` is ambiguous once a crate of the build (serde_json)
    // compares integers with other types.
    lock.l_type != libc::F_UNLCK as libc::c_short
}

/// The bus directory's node and service records, by file name.
pub(crate) struct Layout {
    nodes: PathBuf,
    services: PathBuf,
    /// Where POSIX shared memory lives (`shm_open` names are files there on Linux).
    shm: PathBuf,
    prefix: String,
}

const MONITOR: &str = ".node_monitor";
const MONITOR_FILES: [&str; 3] = [
    ".node_monitor",
    ".node_monitor_owner_lock",
    ".node_monitor_context",
];
const SERVICE: &str = ".service";
const SERVICE_TAG: &str = ".service_tag";
const PORT_TAG: &str = ".port_tag";
/// Mode of an iceoryx2 static storage (service configuration, node details, tags) still being
/// written (0400 once complete).
const STATIC_BEING_CREATED: u32 = 0o600;

impl Layout {
    /// The layout of the domain `config` describes.
    pub(crate) fn of(config: &iceoryx2::config::Config) -> Self {
        use iceoryx2::prelude::SemanticString;
        use std::os::unix::ffi::OsStrExt;
        let path =
            |p: iceoryx2::prelude::Path| PathBuf::from(std::ffi::OsStr::from_bytes(p.as_bytes()));
        Self {
            nodes: path(config.global.node_dir()),
            services: path(config.global.service_dir()),
            shm: PathBuf::from("/dev/shm"),
            prefix: String::from_utf8_lossy(config.global.prefix.as_bytes()).into_owned(),
        }
    }

    fn monitor_file(&self, id: u128, suffix: &str) -> PathBuf {
        self.nodes.join(format!("{}{id}{suffix}", self.prefix))
    }

    /// Ids of every node with a record: a monitor file or a details directory.
    fn node_ids(&self) -> BTreeSet<u128> {
        let mut ids = BTreeSet::new();
        for entry in std::fs::read_dir(&self.nodes)
            .into_iter()
            .flatten()
            .flatten()
        {
            let name = entry.file_name();
            let Some(name) = name.to_str() else { continue };
            let id: Option<u128> = match name.strip_prefix(self.prefix.as_str()) {
                Some(rest) => MONITOR_FILES
                    .iter()
                    .rev()
                    .find_map(|s| rest.strip_suffix(s))
                    .and_then(|n| n.parse().ok()),
                None => name.parse().ok(),
            };
            ids.extend(id);
        }
        ids
    }

    /// Files in node `id`'s details directory.
    fn node_records(&self, id: u128) -> Vec<PathBuf> {
        std::fs::read_dir(self.nodes.join(id.to_string()))
            .into_iter()
            .flatten()
            .flatten()
            .map(|e| e.path())
            .collect()
    }

    /// Whether node `id` has any record left (a live node always has its monitor files; a node
    /// that dropped itself has none).
    pub(crate) fn has_records(&self, id: u128) -> bool {
        self.nodes.join(id.to_string()).exists()
            || MONITOR_FILES
                .iter()
                .any(|s| self.monitor_file(id, s).exists())
    }

    /// Whether node `id` may still be used: its owner runs, holds its state lock, or a cleaner
    /// is at work on it.
    fn in_use(&self, id: u128) -> bool {
        process_alive(node_owner_pid(id))
            || locked(&self.monitor_file(id, MONITOR))
            || locked(&self.monitor_file(id, ".node_monitor_owner_lock"))
    }

    /// Removes, in the directories of nodes whose owner is gone, the records the owner was
    /// killed while writing (still mode 0600): iceoryx2 does not list them, so its cleanup
    /// removes the node's other records, cannot remove the directory, and gives up, every time.
    /// A tag still being written was never used (iceoryx2 creates the tag before the service
    /// or port it stands for), so nothing else refers to it. Returns how many were removed.
    pub(crate) fn remove_unfinished_records(&self) -> usize {
        let mut removed = 0;
        for id in self.node_ids() {
            if self.in_use(id) {
                continue;
            }
            for record in self.node_records(id) {
                let unfinished = std::fs::symlink_metadata(&record).is_ok_and(|m| {
                    m.file_type().is_file()
                        && m.permissions().mode() & 0o777 == STATIC_BEING_CREATED
                });
                if unfinished && std::fs::remove_file(&record).is_ok() {
                    removed += 1;
                }
            }
        }
        removed
    }

    /// Removes the records of nodes whose owner is gone and that hold no service or port (what
    /// iceoryx2 cannot list or clean: a node killed while being created, or whose cleaner was
    /// killed after emptying it). A node that still holds tags is left to iceoryx2's cleanup,
    /// which also detaches it from its services. Returns how many nodes were removed.
    pub(crate) fn remove_dead_node_remnants(&self) -> usize {
        let mut removed = 0;
        for id in self.node_ids() {
            if self.in_use(id) {
                continue;
            }
            let records = self.node_records(id);
            let holds_ports = records.iter().any(|p| {
                let name = p.file_name().and_then(|n| n.to_str()).unwrap_or("");
                name.ends_with(SERVICE_TAG) || name.ends_with(PORT_TAG)
            });
            if holds_ports {
                continue;
            }
            // iceoryx2's order: details, then the directory, then the monitor files with the
            // context last (so a remnant always names its owner while anything of it is left).
            for record in records {
                let _ = std::fs::remove_file(record);
            }
            let _ = std::fs::remove_dir(self.nodes.join(id.to_string()));
            for suffix in MONITOR_FILES {
                let _ = std::fs::remove_file(self.monitor_file(id, suffix));
            }
            removed += 1;
        }
        removed
    }

    /// Files in `dir` named `<prefix><stem><suffix>`, as (stem, path).
    fn named<'a>(
        &'a self,
        dir: &Path,
        suffix: &'a str,
    ) -> impl Iterator<Item = (String, PathBuf)> + 'a {
        std::fs::read_dir(dir)
            .into_iter()
            .flatten()
            .flatten()
            .filter_map(move |e| {
                let name = e.file_name().into_string().ok()?;
                let stem = name
                    .strip_prefix(self.prefix.as_str())?
                    .strip_suffix(suffix)?;
                Some((stem.to_string(), e.path()))
            })
    }

    /// Stems of the tags named `<prefix><stem><suffix>` that the nodes `counts` hold.
    fn tagged(&self, suffix: &str, counts: impl Fn(u128) -> bool) -> BTreeSet<String> {
        self.node_ids()
            .into_iter()
            .filter(|&id| counts(id))
            .flat_map(|id| {
                self.named(&self.nodes.join(id.to_string()), suffix)
                    .map(|(stem, _)| stem)
                    .collect::<Vec<_>>()
            })
            .collect()
    }

    /// This domain's shared-memory segments: (file name without the prefix, path).
    fn segments(&self) -> impl Iterator<Item = (String, PathBuf)> + '_ {
        self.named(&self.shm, "")
    }

    /// The id a segment is named after (`<hash>_<id>[__<n>].<kind>` after the prefix): a service's id
    /// for its dynamic configuration, a port's for the port's segments. Both are
    /// `UniqueSystemId`s, so they name the pid of the process that created the segment.
    fn segment_id(name: &str) -> Option<u128> {
        let stem = name.split('.').next()?.split("__").next()?;
        stem.rsplit_once('_')?.1.parse().ok()
    }

    /// Removes segments of size zero whose creator is gone: it was killed between creating the
    /// segment and sizing it. iceoryx2 waits for such a segment to get its size, with no time
    /// limit: every later cleanup of the dead node that used its service hung there, and so did
    /// every process starting on the bus (seen in the crash loop: a producer stuck in its
    /// start-up cleanup on a `.dynamic` segment of 0 bytes, mode 0200). Returns how many.
    pub(crate) fn remove_unsized_segments(&self) -> usize {
        self.segments()
            .filter(|(_, path)| std::fs::metadata(path).is_ok_and(|m| m.len() == 0))
            .filter(|(name, _)| {
                Self::segment_id(name).is_some_and(|id| !process_alive(node_owner_pid(id)))
            })
            .filter(|(_, path)| std::fs::remove_file(path).is_ok())
            .count()
    }

    /// Ids of every port some node record holds a tag for, whatever the node's state.
    fn tagged_ports(&self) -> BTreeSet<u128> {
        self.tagged(PORT_TAG, |_| true)
            .iter()
            .filter_map(|stem| stem.parse().ok())
            .collect()
    }

    /// Removes the shared memory of ports (a publisher's data segments, a listener's event
    /// segment, named `<prefix><hash>_<port id>...`) whose owner is gone and that no node
    /// holds a port tag for. iceoryx2 finds a dead process's port resources through the port
    /// tags and the service's registration; a process killed between creating a port's
    /// segment and registering the port (or a cleaner killed between removing the port tag and
    /// the segment) leaves a segment nothing points to, and a listener its wake-up socket. Seen in the crash loop as one extra
    /// `.event_mgmt` segment after a run whose processes were killed while starting. A port id
    /// is a `UniqueSystemId` like a node id, so it names its owner's pid. Returns how many.
    pub(crate) fn remove_orphaned_port_segments(&self) -> usize {
        let is_port = |name: &str| {
            name.ends_with(".event_mgmt") || name.ends_with("__mgmt.data") || {
                name.strip_suffix(".data")
                    .and_then(|n| n.rsplit_once("__"))
                    .is_some_and(|(_, segment)| segment.parse::<u64>().is_ok())
            }
        };
        // A listener's wake-up socket, `<root>/<prefix><port id>.event`, goes with its segment.
        let root = self
            .nodes
            .parent()
            .map(Path::to_path_buf)
            .unwrap_or_default();
        let sockets = self
            .named(&root, ".event")
            .filter_map(|(stem, path)| Some((stem.parse().ok()?, path)));
        let candidates: Vec<(u128, PathBuf)> = self
            .segments()
            .filter(|(name, _)| is_port(name))
            .filter_map(|(name, path)| Some((Self::segment_id(&name)?, path)))
            .chain(sockets)
            .filter(|(port, _)| !process_alive(node_owner_pid(*port)))
            .collect();
        if candidates.is_empty() {
            return 0;
        }
        let tagged = self.tagged_ports();
        candidates
            .into_iter()
            .filter(|(port, path)| !tagged.contains(port) && std::fs::remove_file(path).is_ok())
            .count()
    }

    /// Service hashes some node of a live process holds a tag for.
    fn hashes_in_use(&self) -> BTreeSet<String> {
        self.tagged_hashes(|id| self.in_use(id))
    }

    /// Service hashes some node `counts` holds a tag for.
    pub(crate) fn tagged_hashes(&self, counts: impl Fn(u128) -> bool) -> BTreeSet<String> {
        self.tagged(SERVICE_TAG, counts)
    }

    /// Removes the static configuration of every service left half-created by a creator that is
    /// gone (mode 0600 and no live node holds its tag). Returns how many were removed.
    pub(crate) fn remove_abandoned_creations(&self) -> usize {
        let being_created = |path: &Path| {
            std::fs::symlink_metadata(path).is_ok_and(|m| {
                m.file_type().is_file() && m.permissions().mode() & 0o777 == STATIC_BEING_CREATED
            })
        };
        let candidates: Vec<(String, PathBuf)> = self
            .named(&self.services, SERVICE)
            .filter(|(_, path)| being_created(path))
            .collect();
        if candidates.is_empty() {
            return 0;
        }
        // Tags are looked at after the configuration was seen half-created: a live creator made
        // its tag before the configuration, so it is seen here. A creator starting later cannot
        // create the file while this one exists.
        let in_use = self.hashes_in_use();
        let mut removed = 0;
        for (hash, path) in candidates {
            if !in_use.contains(&hash)
                && being_created(&path)
                && std::fs::remove_file(&path).is_ok()
            {
                removed += 1;
            }
        }
        removed
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate as bus;
    use crate::Domain;
    use iceoryx2::prelude::{CallbackProgression, Node, NodeBuilder, NodeState, ipc};

    /// A private bus domain in a fresh directory, removed (with its segments) on drop.
    struct TestDomain(Domain);

    impl TestDomain {
        fn new(tag: &str) -> Self {
            bus::quiet_logging();
            let nanos = std::time::SystemTime::now()
                .duration_since(std::time::UNIX_EPOCH)
                .unwrap()
                .as_nanos();
            // Short enough for the bus's sockets (`make_domain` refuses a longer directory):
            // the nanoseconds within the second tell apart the domains of one process.
            let dir = std::env::temp_dir().join(format!(
                "cs-stale-{tag}-{}-{}",
                std::process::id(),
                nanos % 1_000_000_000
            ));
            Self(bus::domain_at(&dir).unwrap())
        }

        fn layout(&self) -> Layout {
            Layout::of(self.0.config())
        }

        fn node(&self, name: &str) -> Node<ipc::Service> {
            NodeBuilder::new()
                .name(&name.try_into().unwrap())
                .config(self.0.config())
                .create::<ipc::Service>()
                .unwrap()
        }

        /// (alive, dead) node counts as iceoryx2 lists them.
        fn listed(&self) -> (usize, usize) {
            let (mut alive, mut dead) = (0, 0);
            Node::<ipc::Service>::list(self.0.config(), |state| {
                match state {
                    NodeState::Alive(_) => alive += 1,
                    NodeState::Dead(_) => dead += 1,
                    _ => {}
                }
                CallbackProgression::Continue
            })
            .unwrap();
            (alive, dead)
        }

        fn files(&self, dir: &Path) -> Vec<String> {
            let mut v: Vec<String> = std::fs::read_dir(dir)
                .into_iter()
                .flatten()
                .flatten()
                .map(|e| e.file_name().to_string_lossy().into_owned())
                .collect();
            v.sort();
            v
        }
    }

    impl Drop for TestDomain {
        fn drop(&mut self) {
            let _ = std::fs::remove_dir_all(&self.0.root);
            for e in std::fs::read_dir("/dev/shm")
                .into_iter()
                .flatten()
                .flatten()
            {
                if e.file_name().to_string_lossy().starts_with(&self.0.prefix) {
                    let _ = std::fs::remove_file(e.path());
                }
            }
        }
    }

    /// The pid of a process that has exited (and was reaped).
    fn dead_pid() -> u32 {
        let mut child = std::process::Command::new("true").spawn().unwrap();
        let pid = child.id();
        child.wait().unwrap();
        pid
    }

    /// A node id as iceoryx2 makes them (`UniqueSystemId`), owned by `pid`.
    fn node_id(pid: u32, counter: u32) -> u128 {
        let mut bytes = [0u8; 16];
        for (i, v) in [1_700_000_000u32, 12345, pid, counter]
            .into_iter()
            .enumerate()
        {
            bytes[i * 4..i * 4 + 4].copy_from_slice(&v.to_ne_bytes());
        }
        u128::from_ne_bytes(bytes)
    }

    fn write(path: &Path, bytes: &[u8], mode: u32) {
        std::fs::write(path, bytes).unwrap();
        std::fs::set_permissions(path, std::fs::Permissions::from_mode(mode)).unwrap();
    }

    #[test]
    fn the_owner_pid_is_read_from_the_node_id_as_iceoryx2_reads_it() {
        let d = TestDomain::new("pid");
        let node = d.node("pid-check");
        let id = node.id();
        assert_eq!(
            node_owner_pid(id.value()),
            id.pid::<ipc::Service>().unwrap().value() as u32
        );
        assert_eq!(node_owner_pid(id.value()), std::process::id());
        assert!(process_alive(std::process::id()));
        assert!(!process_alive(dead_pid()));
    }

    /// The records a dead node leaves when the process cleaning it up was killed after removing
    /// its details file: iceoryx2 lists it as dead, and its cleanup (with the global
    /// configuration, as iceoryx2 does for a node without details) never removed it. Seen in
    /// the crash loop (`tests/crash_loop.rs`) with a half-written tag besides.
    #[test]
    fn a_dead_node_without_details_is_removed() {
        let d = TestDomain::new("nodetails");
        let live = d.node("live");
        let l = d.layout();
        let id = node_id(dead_pid(), 7);
        // Monitor files as a finished ProcessGuard leaves them (context: the owner's unique
        // process id, mode 0400), a node directory holding a tag of a service that is gone.
        write(&l.monitor_file(id, MONITOR), b"", 0o600);
        write(&l.monitor_file(id, ".node_monitor_owner_lock"), b"", 0o600);
        write(
            &l.monitor_file(id, ".node_monitor_context"),
            &id.to_ne_bytes(),
            0o400,
        );
        let dir = l.nodes.join(id.to_string());
        std::fs::create_dir(&dir).unwrap();
        let tag = format!("{}{}{SERVICE_TAG}", d.0.prefix, "ab".repeat(20));
        write(&dir.join(&tag), b"", 0o400);
        // And a tag its owner was killed while writing (still 0600): iceoryx2 does not see it,
        // cannot remove the directory, and its cleanup fails every time.
        let unfinished = format!("{}{}{SERVICE_TAG}", d.0.prefix, "cd".repeat(20));
        write(&dir.join(&unfinished), b"", 0o600);
        assert_eq!(d.listed(), (1, 1), "iceoryx2 lists it as dead");

        assert_eq!(bus::cleanup_dead_nodes_in(d.0.config()), 1);
        assert_eq!(d.listed(), (1, 0));
        let left: Vec<String> = d
            .files(&l.nodes)
            .into_iter()
            .filter(|n| n.contains(&id.to_string()))
            .collect();
        assert!(left.is_empty(), "left: {left:?}");
        // The live node is untouched.
        assert_eq!(d.listed().0, 1);
        drop(live);
    }

    /// A node killed while creating its monitor files (context still 0200: iceoryx2 reports it
    /// as not existing) and one whose cleaner was killed after removing the state file: never
    /// listed by iceoryx2. Removed only once their owner is gone.
    #[test]
    fn unlisted_remnants_are_removed_once_their_owner_is_gone() {
        let d = TestDomain::new("remnants");
        let l = d.layout();
        let mut sleeper = std::process::Command::new("sleep")
            .arg("30")
            .spawn()
            .unwrap();
        let starting_live = node_id(sleeper.id(), 1);
        let starting_dead = node_id(dead_pid(), 2);
        let cleaned_dead = node_id(dead_pid(), 3);
        for id in [starting_live, starting_dead] {
            let dir = l.nodes.join(id.to_string());
            std::fs::create_dir_all(&dir).unwrap();
            write(
                &dir.join(format!("{}node.details", d.0.prefix)),
                b"x",
                0o400,
            );
            write(&l.monitor_file(id, ".node_monitor_context"), b"", 0o200);
        }
        write(
            &l.monitor_file(cleaned_dead, ".node_monitor_owner_lock"),
            b"",
            0o600,
        );
        write(
            &l.monitor_file(cleaned_dead, ".node_monitor_context"),
            &[0; 16],
            0o400,
        );
        assert_eq!(
            d.listed(),
            (0, 0),
            "iceoryx2 lists nodes by their state file"
        );

        bus::cleanup_dead_nodes_in(d.0.config());
        let left = d.files(&l.nodes);
        let of = |id: u128| left.iter().filter(|n| n.contains(&id.to_string())).count();
        assert_eq!(
            of(starting_live),
            2,
            "a node being created by a live process is kept"
        );
        assert_eq!((of(starting_dead), of(cleaned_dead)), (0, 0), "{left:?}");

        sleeper.kill().unwrap();
        sleeper.wait().unwrap();
        bus::cleanup_dead_nodes_in(d.0.config());
        assert!(d.files(&l.nodes).is_empty(), "{:?}", d.files(&l.nodes));
    }

    /// A service whose creator was killed while writing its configuration (left at mode 0600)
    /// hangs in creation for everyone: a run's participant removes it, once no live process
    /// holds it, and creates the service anew.
    #[test]
    fn a_service_left_half_created_by_a_dead_creator_is_created_anew() {
        let d = TestDomain::new("halfcreated");
        let l = d.layout();
        let run = "half-created";
        // The configuration file of the real service, then the service gone.
        let (name, contents) = {
            let node = d.node("creator");
            let _service = bus::data_service(&node, run).unwrap();
            let name = d.files(&l.services).pop().unwrap();
            (name.clone(), std::fs::read(l.services.join(&name)).unwrap())
        };
        assert!(d.files(&l.services).is_empty());
        // Killed during the fsync: written, still 0600.
        write(&l.services.join(&name), &contents, 0o600);
        let hash = name
            .strip_prefix(&d.0.prefix)
            .and_then(|n| n.strip_suffix(SERVICE))
            .unwrap();

        // While a live process holds its tag (it is the creator, still at work), it stays.
        let holder = d.node("holder");
        let holder_dir = l.nodes.join(holder.id().value().to_string());
        let tag = holder_dir.join(format!("{}{hash}{SERVICE_TAG}", d.0.prefix));
        write(&tag, b"", 0o400);
        assert_eq!(l.remove_abandoned_creations(), 0);
        std::fs::remove_file(&tag).unwrap();

        // Without the repair this fails after 1 s: PublishSubscribeOpenError(HangsInCreation).
        let node = d.node("next");
        let start = std::time::Instant::now();
        let service = bus::data_service(&node, run).unwrap();
        let subscriber = service.subscriber_builder().create().unwrap();
        assert!(
            start.elapsed() < CREATION_REPAIR_BOUND,
            "{:?}",
            start.elapsed()
        );
        let mode = std::fs::metadata(l.services.join(&name))
            .unwrap()
            .permissions()
            .mode();
        assert_eq!(mode & 0o777, 0o400, "created anew and complete");
        drop((subscriber, service, holder));
    }

    /// A service whose last holder was killed after removing its tag but before its storages
    /// (the last steps of iceoryx2's `ServiceState::drop`): complete, registered by nobody alive,
    /// tagged by nobody. Without the repair nothing ever removes it (seen in the crash loop).
    #[test]
    fn a_service_nobody_holds_is_removed() {
        let d = TestDomain::new("orphan");
        let l = d.layout();
        let shm = || -> BTreeSet<String> {
            d.files(Path::new("/dev/shm"))
                .into_iter()
                .filter(|f| f.starts_with(&d.0.prefix))
                .collect()
        };
        let before = shm();
        let snapshot = |dir: &Path, names: &BTreeSet<String>| -> Vec<(PathBuf, Vec<u8>, u32)> {
            names
                .iter()
                .map(|n| {
                    let path = dir.join(n);
                    let mode = std::fs::metadata(&path).unwrap().permissions().mode() & 0o777;
                    (path.clone(), std::fs::read(&path).unwrap(), mode)
                })
                .collect()
        };
        // The files of a real service, taken while its creator holds it, then the service gone.
        let files = {
            let node = d.node("creator");
            let _service = bus::data_service(&node, "orphan").unwrap();
            let statics: BTreeSet<String> = d.files(&l.services).into_iter().collect();
            // The service's dynamic configuration (the first node also made the domain's
            // management segment, which is not the service's).
            let dynamics: BTreeSet<String> = shm()
                .difference(&before)
                .filter(|f| f.ends_with(".dynamic"))
                .cloned()
                .collect();
            assert_eq!(
                (statics.len(), dynamics.len()),
                (1, 1),
                "{statics:?} {dynamics:?}"
            );
            let mut files = snapshot(&l.services, &statics);
            files.extend(snapshot(Path::new("/dev/shm"), &dynamics));
            files
        };
        assert!(d.files(&l.services).is_empty());
        let restore = || {
            for (path, bytes, mode) in &files {
                write(path, bytes, *mode);
            }
        };
        let services = || {
            let mut n = 0;
            <ipc::Service as iceoryx2::service::Service>::list(d.0.config(), |_| {
                n += 1;
                CallbackProgression::Continue
            })
            .unwrap();
            n
        };
        restore();
        assert_eq!(services(), 1, "the orphan is listed");

        // While a live node holds its tag, it stays.
        let holder = d.node("holder");
        let hash = d.files(&l.services)[0]
            .strip_prefix(&d.0.prefix)
            .and_then(|n| n.strip_suffix(SERVICE))
            .unwrap()
            .to_string();
        let tag = l
            .nodes
            .join(holder.id().value().to_string())
            .join(format!("{}{hash}{SERVICE_TAG}", d.0.prefix));
        write(&tag, b"", 0o400);
        bus::cleanup_dead_nodes_in(d.0.config());
        assert_eq!(services(), 1, "held by a live node's tag");
        std::fs::remove_file(&tag).unwrap();

        // Nobody holds it: removed, the dynamic configuration's segment with it.
        bus::cleanup_dead_nodes_in(d.0.config());
        assert_eq!(services(), 0);
        assert!(
            d.files(&l.services).is_empty(),
            "{:?}",
            d.files(&l.services)
        );
        assert!(
            !shm().contains(files[1].0.file_name().unwrap().to_str().unwrap()),
            "{:?}",
            shm()
        );

        // Only the static configuration left: removed as well, and the run's service works.
        write(&files[0].0, &files[0].1, files[0].2);
        bus::cleanup_dead_nodes_in(d.0.config());
        assert!(
            d.files(&l.services).is_empty(),
            "{:?}",
            d.files(&l.services)
        );
        let node = d.node("next");
        let service = bus::data_service(&node, "orphan").unwrap();
        let subscriber = service.subscriber_builder().create().unwrap();
        drop((subscriber, service, holder));
    }

    /// A port segment whose owner is dead and that no node tags is removed; one of a live
    /// owner, or one a node still tags (iceoryx2's dead-node cleanup finds it), stays.
    #[test]
    fn port_segments_nobody_can_find_are_removed() {
        let d = TestDomain::new("portsegments");
        let l = d.layout();
        let _live = d.node("live");
        let hash = "33c1ac61b54bf6edd0a0a8390f0c2fd7cf74d745";
        let segment =
            |port: u128, suffix: &str| l.shm.join(format!("{}{hash}_{port}{suffix}", d.0.prefix));
        let dead = dead_pid();
        let orphans = [
            segment(node_id(dead, 1), ".event_mgmt"),
            segment(node_id(dead, 2), "__0.data"),
            segment(node_id(dead, 2), "__mgmt.data"),
        ];
        let socket =
            l.nodes
                .parent()
                .unwrap()
                .join(format!("{}{}.event", d.0.prefix, node_id(dead, 1)));
        write(&socket, b"", 0o600);
        let mine = segment(node_id(std::process::id(), 3), ".event_mgmt");
        let tagged_port = node_id(dead, 4);
        let tagged = segment(tagged_port, ".event_mgmt");
        for path in orphans.iter().chain([&mine, &tagged]) {
            write(path, b"segment", 0o600);
        }
        // The tag of the last one, in a dead node's directory (left to iceoryx2's cleanup).
        let node_dir = l.nodes.join(node_id(dead, 9).to_string());
        std::fs::create_dir_all(&node_dir).unwrap();
        write(
            &node_dir.join(format!("{}{tagged_port}{PORT_TAG}", d.0.prefix)),
            b"",
            0o400,
        );
        assert_eq!(l.remove_orphaned_port_segments(), 4);
        assert!(orphans.iter().all(|p| !p.exists()) && !socket.exists());
        assert!(mine.exists() && tagged.exists());
        for path in [mine, tagged] {
            std::fs::remove_file(path).unwrap();
        }
    }

    /// A segment of size zero left by a dead creator is removed before anything opens it; one
    /// of a live creator (still sizing it), or one with contents, stays.
    #[test]
    fn unsized_segments_of_dead_creators_are_removed() {
        let d = TestDomain::new("unsized");
        let l = d.layout();
        let hash = "112437a14a36c452eeea7e2aefc2af954fc5a3f2";
        let segment = |id: u128| l.shm.join(format!("{}{hash}_{id}.dynamic", d.0.prefix));
        let dead = dead_pid();
        let (unsized_dead, unsized_mine, sized_dead) = (
            segment(node_id(dead, 1)),
            segment(node_id(std::process::id(), 2)),
            segment(node_id(dead, 3)),
        );
        write(&unsized_dead, b"", 0o200);
        write(&unsized_mine, b"", 0o200);
        write(&sized_dead, b"configuration", 0o600);
        assert_eq!(l.remove_unsized_segments(), 1);
        assert!(!unsized_dead.exists() && unsized_mine.exists() && sized_dead.exists());
        for path in [unsized_mine, sized_dead] {
            std::fs::remove_file(path).unwrap();
        }
    }

    /// iceoryx2 waits 1 s for a hanging creation before the repair runs; one repair suffices.
    const CREATION_REPAIR_BOUND: std::time::Duration = std::time::Duration::from_secs(5);
}
