//! Issue #13, point 2: a crash loop. Over more than 50 runs, the producer, the recorder or
//! `chaoscope run` is killed with SIGKILL at a random (seeded) moment, and once the recorder is
//! stopped (SIGSTOP) for longer than a chunk period and continued. After each run every file is
//! readable or recovered by `chaoscope recover`, what it holds is exactly the start of an
//! uninterrupted run, bit for bit, and once the next run has started no dead node, no service of
//! an earlier run and no extra shared-memory segment or bus file is left.
//!
//! The whole loop runs in a bus directory of its own (`CHAOSCOPE_BUS_DIR`, so its segments are
//! `cs<uid>_<tag>_*` in /dev/shm): every file of that domain is this test's, and other tests or
//! users running at the same time cannot disturb the counts.
//!
//! `CHAOSCOPE_CRASH_SEED=<n>` replays another schedule (the seed and every kill are printed).

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::{Duration, Instant};

use crate::common::*;
use chaoscope_bus::{self as bus, BUS_DIR_ENV, Domain};
use chaoscope_schemas::names;
use iceoryx2::node::NodeView;
use iceoryx2::prelude::*;

/// Kills (the floor is 50), plus the one SIGSTOP/SIGCONT run.
const KILLS: usize = 54;
const LIMIT: Duration = Duration::from_secs(60);
/// The recorder's chunk period in this test: short runs still hold several chunks to salvage.
const FLUSH: &str = "0.1";
/// How long the recorder is stopped: several chunk periods.
const STOP_FOR: Duration = Duration::from_millis(600);

/// SplitMix64: the kill schedule, reproducible from the seed.
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    }

    /// Uniform in [0, 1).
    fn unit(&mut self) -> f64 {
        (self.next() >> 11) as f64 / (1u64 << 53) as f64
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
enum Victim {
    Producer,
    Recorder,
    Run,
}

/// The test's private bus: its directory, the domain processes started with it use, and the
/// shared-memory names that belong to it.
struct Bus {
    dir: tempfile::TempDir,
    domain: Domain,
}

impl Bus {
    fn new() -> Self {
        let dir = tempfile::Builder::new()
            .prefix("crash-loop-bus")
            .tempdir()
            .unwrap();
        let domain = bus::domain_at(dir.path()).unwrap();
        Self { dir, domain }
    }

    fn command(&self, args: &[&str]) -> Command {
        let mut c = chaoscope(args);
        c.env(BUS_DIR_ENV, self.dir.path());
        c
    }

    /// This domain's segments in /dev/shm, by name.
    fn segments(&self) -> Vec<String> {
        domain_segments(&self.domain.prefix)
    }

    /// Every file under the bus directory (service and node records, event sockets).
    fn files(&self) -> Vec<PathBuf> {
        fn walk(dir: &Path, out: &mut Vec<PathBuf>) {
            for e in std::fs::read_dir(dir).into_iter().flatten().flatten() {
                let p = e.path();
                if e.file_type().is_ok_and(|t| t.is_dir()) {
                    walk(&p, out);
                } else {
                    out.push(p);
                }
            }
        }
        let mut out = Vec::new();
        walk(self.dir.path(), &mut out);
        out.sort();
        out
    }

    /// (alive, dead) node names of the domain.
    fn nodes(&self) -> (Vec<String>, Vec<String>) {
        let (mut alive, mut dead) = (Vec::new(), Vec::new());
        Node::<ipc::Service>::list(self.domain.config(), |state| {
            let (list, details) = match &state {
                NodeState::Alive(v) => (&mut alive, v.details()),
                NodeState::Dead(v) => (&mut dead, v.details()),
                _ => return CallbackProgression::Continue,
            };
            let name = details.as_ref().map(|d| d.name().as_str().to_string());
            list.push(name.unwrap_or_else(|| "<no details>".into()));
            CallbackProgression::Continue
        })
        .unwrap();
        (alive, dead)
    }

    /// The node records with their modes, to show what a failure left.
    fn node_records(&self) -> Vec<String> {
        use std::os::unix::fs::PermissionsExt;
        self.files()
            .into_iter()
            .filter(|f| f.starts_with(self.dir.path().join("nodes")))
            .map(|f| {
                let mode = std::fs::metadata(&f).map_or(0, |m| m.permissions().mode() & 0o777);
                format!("{:o} {}", mode, f.display())
            })
            .collect()
    }

    fn services(&self) -> Vec<String> {
        let mut v = Vec::new();
        ipc::Service::list(self.domain.config(), |details| {
            v.push(details.static_details.name().as_str().to_string());
            CallbackProgression::Continue
        })
        .unwrap();
        v.sort();
        v
    }

    fn producer_alive(&self, run: &str) -> bool {
        let name = names::producer_node_name(run);
        self.nodes().0.contains(&name)
    }

    /// Waits until no node of `run` is alive and every process owning a node record has
    /// exited (a killed `chaoscope run`'s children finalize). iceoryx2 stops listing a node
    /// once its monitor files are gone, while its owner may still be removing the rest of its
    /// records: checking the bus then would blame a process for what it is still cleaning up.
    fn wait_nodes_gone(&self, run: &str) {
        let start = Instant::now();
        while self.nodes().0.iter().any(|n| n.contains(run))
            || self.record_owners().into_iter().any(running)
        {
            assert!(start.elapsed() < LIMIT, "nodes of {run} still alive");
            std::thread::sleep(Duration::from_millis(20));
        }
    }

    /// Pids of the owners of the domain's node records (directories and monitor files), from
    /// the node ids: iceoryx2's `UniqueSystemId` is `{ seconds, nanoseconds, pid, counter }` as
    /// four native-endian u32 in a u128.
    fn record_owners(&self) -> BTreeSet<u32> {
        std::fs::read_dir(self.dir.path().join("nodes"))
            .into_iter()
            .flatten()
            .flatten()
            .filter_map(|e| {
                let name = e.file_name().into_string().ok()?;
                let id: u128 = name.split('.').next()?.rsplit('_').next()?.parse().ok()?;
                let b = id.to_ne_bytes();
                Some(u32::from_ne_bytes([b[8], b[9], b[10], b[11]]))
            })
            .collect()
    }

    /// The producer of `run` is up and waiting for its recorder: the domain holds exactly what a
    /// fresh producer holds (`baseline`: counts of segments and bus files), no dead node and no
    /// service of any other run. Returns the counts seen.
    fn assert_only(&self, run: &str, baseline: Option<usize>) -> usize {
        // The producer creates its ports one after the other: wait until the counts settle.
        let start = Instant::now();
        let mut last = usize::MAX;
        let mut stable = 0;
        let counts = loop {
            let counts = self.segments().len();
            // A producer slow to create its ports (a loaded machine) can pause for more than
            // the settling time with fewer segments than a fresh one holds: wait for them all.
            let complete = baseline.is_none_or(|b| counts >= b);
            if counts == last && complete && self.services().len() == names_per_run() {
                stable += 1;
                if stable == 3 {
                    break counts;
                }
            } else {
                stable = 0;
            }
            last = counts;
            assert!(
                start.elapsed() < LIMIT,
                "the bus of {run} never settled: {:?}",
                self.services()
            );
            std::thread::sleep(Duration::from_millis(30));
        };
        let (alive, dead) = self.nodes();
        assert!(
            dead.is_empty(),
            "dead nodes left behind: {dead:?}\n{:#?}",
            self.node_records()
        );
        assert_eq!(alive, vec![names::producer_node_name(run)], "nodes");
        for s in self.services() {
            assert!(s.contains(run), "service {s} of another run is left");
        }
        // Bus files: the service records of this run, and the records of one node (port
        // records come and go with the ports, so they are not counted).
        let files = self.files();
        let root = self.dir.path();
        let services = files
            .iter()
            .filter(|f| f.starts_with(root.join("services")))
            .count();
        assert_eq!(services, names_per_run(), "service records: {files:#?}");
        let node_dirs: std::collections::BTreeSet<_> = files
            .iter()
            .filter_map(|f| f.strip_prefix(root.join("nodes")).ok())
            .filter(|rel| rel.components().count() > 1)
            .map(|rel| rel.components().next().unwrap().as_os_str().to_owned())
            .collect();
        assert_eq!(
            node_dirs.len(),
            1,
            "node records of more than one node: {files:#?}"
        );
        if let Some(base) = baseline {
            assert_eq!(
                counts,
                base,
                "segments of a fresh producer, {run}: left over from earlier runs?\n{:#?}",
                self.segments()
            );
        }
        counts
    }
}

/// Services a producer opens: header, data, data-ready, ready, monitor.
fn names_per_run() -> usize {
    5
}

/// Reads the recording `out`: a finalized file as it is, otherwise what `chaoscope recover`
/// salvages from the in-progress file a killed recorder left (`out.partial`; `out` itself only
/// ever holds a finalized file). `None` when there is nothing to read (the recorder died
/// before writing its first bytes).
fn read_or_recover(out: &Path, dir: &Path, i: usize) -> Option<(Recorded, bool)> {
    let partial = chaoscope_os::output::partial_path(out);
    let file = if out.exists() {
        assert!(
            !partial.exists(),
            "run {i}: both {out:?} and its in-progress file"
        );
        out
    } else {
        &partial
    };
    let Ok(meta) = std::fs::metadata(file) else {
        return None;
    };
    let bytes = std::fs::read(file).unwrap();
    if mcap::Summary::read(&bytes).is_ok_and(|s| s.is_some()) {
        return Some((read_recording(file), false));
    }
    let fixed = dir.join(format!("fixed-{i}.mcap"));
    let out = Command::new(CHAOSCOPE)
        .args(["recover", file.to_str().unwrap(), "--out"])
        .arg(&fixed)
        .output()
        .unwrap();
    if meta.len() < 8 {
        // Killed before the magic was written: recover must say so, not salvage garbage.
        assert!(
            !out.status.success(),
            "recover accepted a {}-byte file",
            meta.len()
        );
        return None;
    }
    assert!(
        out.status.success(),
        "run {i}: recover failed on {} ({} bytes): {}",
        file.display(),
        meta.len(),
        String::from_utf8_lossy(&out.stderr)
    );
    Some((read_recording(&fixed), true))
}

#[test]
fn killing_any_process_at_any_moment_loses_nothing_but_the_tail_and_leaves_no_stale_resource() {
    let started = Instant::now();
    let seed: u64 = std::env::var("CHAOSCOPE_CRASH_SEED")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(13);
    let mut rng = Rng(seed);
    eprintln!("crash loop: seed {seed} (CHAOSCOPE_CRASH_SEED replays another)");

    let work = tempfile::tempdir().unwrap();
    let bus = Bus::new();
    // 2001 samples of 5 frames (k = 3, VM and MPM-QR, 2 sets): a few tenths of a second.
    let text = hh_config(20.0, 0.01).to_toml();
    let config = write_config(work.path(), &text);
    let expected = compute(&text, None);

    let produce = |run: &str| {
        Proc::spawn(bus.command(&[
            "produce",
            config.to_str().unwrap(),
            "--run",
            run,
            "--no-progress",
            "--wait-timeout",
            "30",
        ]))
    };
    let record = |run: &str, out: &Path, flush: &str| {
        Proc::spawn(bus.command(&[
            "record",
            "--run",
            run,
            "--out",
            out.to_str().unwrap(),
            "--flush-interval",
            flush,
            "--chunk-size",
            "65536",
            "--wait-timeout",
            "30",
        ]))
    };

    // An uninterrupted run: the reference bit for bit, its duration sets the kill window, and
    // its producer, before the recorder starts, is the baseline of a clean bus.
    let run = unique_run("crash-clean");
    let out = work.path().join("clean.mcap");
    let mut producer = produce(&run);
    while !bus.producer_alive(&run) {
        std::thread::sleep(Duration::from_millis(10));
    }
    let baseline = bus.assert_only(&run, None);
    let t0 = Instant::now();
    let mut recorder = record(&run, &out, FLUSH);
    assert!(producer.wait(LIMIT).success());
    assert!(recorder.wait(LIMIT).success());
    let window = t0.elapsed();
    let clean = read_recording(&out);
    assert_eq!(clean.references.len(), expected.len());
    assert_bit_identical(&clean, &expected);
    eprintln!(
        "crash loop: clean run {:.2} s, bus of a fresh producer: {baseline} segments",
        window.as_secs_f64(),
    );

    let mut tally: BTreeMap<(Victim, &str), usize> = BTreeMap::new();
    let mut salvaged = Vec::new();
    for i in 0..=KILLS {
        let stop_run = i == KILLS / 2;
        let victim = match rng.next() % 3 {
            0 => Victim::Producer,
            1 => Victim::Recorder,
            _ => Victim::Run,
        };
        // Anywhere from the first instant (bus setup, file creation) to past the end of a run.
        let delay = window.mul_f64(1.2 * rng.unit());
        let run = unique_run(&format!("crash{i}"));
        let out = work.path().join(format!("run-{i}.mcap"));
        let mut waited_for_peer = false;

        let outcome = if stop_run {
            // SIGSTOP the recorder for several chunk periods while the producer waits on it.
            let mut producer = produce(&run);
            while !bus.producer_alive(&run) {
                std::thread::sleep(Duration::from_millis(10));
            }
            bus.assert_only(&run, Some(baseline));
            let mut recorder = record(&run, &out, FLUSH);
            std::thread::sleep(delay.min(window / 2));
            recorder.signal(libc::SIGSTOP);
            std::thread::sleep(STOP_FOR);
            recorder.signal(libc::SIGCONT);
            assert!(producer.wait(LIMIT).success(), "producer after SIGCONT");
            assert!(recorder.wait(LIMIT).success(), "recorder after SIGCONT");
            let rec = read_recording(&out);
            let summary = rec.recording.as_ref().unwrap();
            assert_eq!(
                (summary.run_status.as_str(), summary.frames_missing),
                ("completed", 0)
            );
            assert_eq!(
                rec.references.len(),
                expected.len(),
                "stopped recorder lost samples"
            );
            assert_contiguous(&rec.frames);
            assert_bit_identical(&rec, &expected);
            eprintln!("crash loop {i}: recorder stopped {STOP_FOR:?}: complete, identical");
            "stopped, complete"
        } else if victim == Victim::Run {
            let mut front = Proc::spawn(bus.command(&[
                "run",
                config.to_str().unwrap(),
                "--run",
                &run,
                "--out",
                out.to_str().unwrap(),
            ]));
            let spawned = Instant::now();
            // The check needs the producer up and no recorder yet; `run` starts the recorder
            // first, so look at what is left over only from earlier runs here.
            std::thread::sleep(delay.saturating_sub(spawned.elapsed()));
            front.signal(libc::SIGKILL);
            front.wait(LIMIT);
            // Its children were told (SIGTERM on the parent's death) and finalize. A recorder
            // leaves the bus before it has finished its file, so the file is read only once
            // every process of this run has exited.
            bus.wait_nodes_gone(&run);
            wait_processes_gone(&run);
            "killed run"
        } else {
            let producer = produce(&run);
            while !bus.producer_alive(&run) {
                std::thread::sleep(Duration::from_millis(10));
            }
            bus.assert_only(&run, Some(baseline));
            let recorder = record(&run, &out, FLUSH);
            std::thread::sleep(delay);
            let (killed, mut survivor, what) = match victim {
                Victim::Producer => (producer, recorder, "killed producer"),
                _ => (recorder, producer, "killed recorder"),
            };
            killed.signal(libc::SIGKILL);
            let mut killed = killed;
            killed.wait(LIMIT);
            // The survivor ends on its own: a recorder finalizes ("producer-died"), a producer
            // never blocks on the dead recorder (it streams on to its end, or stops once the
            // dead recorder is cleaned up: exit 3, its recorders left). Only one killed
            // before the two met (the recorder before its ready handshake, the producer before
            // its header) still waits for its peer: it must then be waiting, not streaming,
            // and stop at once on SIGINT.
            let grace = window * 2 + Duration::from_secs(2);
            let start = Instant::now();
            while survivor.0.try_wait().unwrap().is_none() && start.elapsed() < grace {
                std::thread::sleep(Duration::from_millis(20));
            }
            if survivor.0.try_wait().unwrap().is_none() {
                survivor.signal(libc::SIGINT);
                let status = survivor.wait(Duration::from_secs(10));
                assert_ne!(status.code(), Some(101), "run {i}: panic");
                waited_for_peer = true;
                "killed before the two met; the survivor waited, stopped by SIGINT"
            } else {
                let status = survivor.wait(LIMIT);
                if victim == Victim::Producer && status.code() == Some(1) {
                    // The producer died after the recorder saw it alive but before the
                    // recorder received its header (history dies with its publisher): no
                    // producer is coming back for it, and the recorder says so ("the producer
                    // went away before publishing its run header"), exit 1, with no data.
                    waited_for_peer = true;
                    "killed before the two met; the recorder reported it, exit 1"
                } else if victim == Victim::Recorder && status.code() == Some(3) {
                    // The producer found its recorder gone (once the dead node was cleaned up)
                    // and stopped rather than compute the rest of the run for nobody.
                    "killed recorder; the producer ended, its recorder gone"
                } else {
                    assert!(
                        status.success(),
                        "run {i}: the survivor of a {what}: {status}"
                    );
                    what
                }
            }
        };

        let checked = match read_or_recover(&out, work.path(), i) {
            None => {
                assert!(
                    victim != Victim::Producer || stop_run || waited_for_peer,
                    "run {i}: the recorder outlived the producer but wrote no file"
                );
                "no file"
            }
            Some((rec, recovered)) => {
                if waited_for_peer {
                    assert!(
                        rec.frames.is_empty(),
                        "run {i}: data recorded, yet a peer waited"
                    );
                }
                if victim == Victim::Producer && !stop_run && !waited_for_peer {
                    let s = rec.recording.as_ref().expect("finalized by the recorder");
                    assert!(
                        s.finalized_by == "producer-died" || s.finalized_by == "end-of-run",
                        "run {i}: finalized by {}",
                        s.finalized_by
                    );
                    assert_eq!(s.frames_missing, 0, "run {i}");
                }
                assert_contiguous(&rec.frames);
                assert_bit_identical(&rec, &expected);
                salvaged.push(rec.references.len());
                if recovered { "recovered" } else { "readable" }
            }
        };
        if !stop_run {
            eprintln!(
                "crash loop {i}: {outcome} after {:.3} s: {checked}, {} samples",
                delay.as_secs_f64(),
                salvaged
                    .last()
                    .filter(|_| checked != "no file")
                    .unwrap_or(&0)
            );
            *tally.entry((victim, checked)).or_default() += 1;
        }
    }

    // The run after the last kill starts on a clean bus, and once it is over nothing is left
    // but iceoryx2's node counter.
    let run = unique_run("crash-last");
    let out = work.path().join("last.mcap");
    let mut producer = produce(&run);
    while !bus.producer_alive(&run) {
        std::thread::sleep(Duration::from_millis(10));
    }
    bus.assert_only(&run, Some(baseline));
    let mut recorder = record(&run, &out, FLUSH);
    assert!(producer.wait(LIMIT).success());
    assert!(recorder.wait(LIMIT).success());
    assert_bit_identical(&read_recording(&out), &expected);
    let segments = bus.segments();
    assert!(
        segments.iter().all(|s| is_node_counter(s)),
        "segments left after the last run: {segments:#?}"
    );
    let files = bus.files();
    assert!(files.is_empty(), "bus files left: {files:#?}");
    assert_eq!(bus.nodes(), (vec![], vec![]));
    assert_eq!(close_private_bus(bus.dir.path()), Vec::<String>::new());

    let kills: usize = tally.values().sum();
    assert!(kills >= 50, "only {kills} kills");
    eprintln!(
        "crash loop: {kills} kills {tally:?}, 1 stop; samples kept per run: min {} max {}; \
         {:.1} s wall",
        salvaged.iter().min().unwrap_or(&0),
        salvaged.iter().max().unwrap_or(&0),
        started.elapsed().as_secs_f64()
    );
}

/// Whether process `pid` runs (a zombie does not: it holds nothing any more).
fn running(pid: u32) -> bool {
    // SAFETY: signal 0 only checks for existence.
    if unsafe { libc::kill(pid as libc::pid_t, 0) } != 0 {
        return false;
    }
    std::fs::read_to_string(format!("/proc/{pid}/stat")).is_ok_and(|stat| {
        !stat
            .rsplit_once(')')
            .is_some_and(|(_, rest)| rest.trim_start().starts_with(['Z', 'X']))
    })
}

/// Waits until no running process has `run` among its arguments (the orphaned children of a
/// killed `chaoscope run`, which finish their files after leaving the bus).
fn wait_processes_gone(run: &str) {
    let start = Instant::now();
    loop {
        let alive: Vec<u32> = std::fs::read_dir("/proc")
            .into_iter()
            .flatten()
            .flatten()
            .filter_map(|e| e.file_name().to_str()?.parse::<u32>().ok())
            .filter(|&pid| running(pid) && argv(pid).iter().any(|a| a == run))
            .collect();
        if alive.is_empty() {
            return;
        }
        assert!(
            start.elapsed() < LIMIT,
            "processes {alive:?} of {run} still alive"
        );
        std::thread::sleep(Duration::from_millis(20));
    }
}

/// The arguments of process `pid` (empty once it is gone).
fn argv(pid: u32) -> Vec<String> {
    std::fs::read(format!("/proc/{pid}/cmdline"))
        .unwrap_or_default()
        .split(|&b| b == 0)
        .filter(|a| !a.is_empty())
        .map(|a| String::from_utf8_lossy(a).into_owned())
        .collect()
}

/// The children of process `pid` (those its main thread started: `run` starts both there).
fn children(pid: u32) -> Vec<u32> {
    std::fs::read_to_string(format!("/proc/{pid}/task/{pid}/children"))
        .unwrap_or_default()
        .split_whitespace()
        .filter_map(|c| c.parse().ok())
        .collect()
}

/// `chaoscope run` SIGKILLed while its recorder is between fork and exec, at the two points
/// where the recorder's parent-death SIGTERM could go astray: before `PR_SET_PDEATHSIG` (the
/// child finds its parent gone and raises the signal itself) and after it (the kernel sends
/// it). The forked child runs `run`'s handlers until exec, which latched the signal in memory
/// the exec then dropped: the recorder started with no signal, its producer (which got its own
/// and ended) never seen alive, and waited for it for ever (once in this file's crash loop,
/// seed 13; a kill lands in this window by chance only). `CHAOSCOPE_SPAWN_PAUSE` holds the
/// child at each point so the kill lands there every time.
#[test]
fn a_run_killed_while_its_recorder_starts_leaves_no_recorder_behind() {
    let work = tempfile::tempdir().unwrap();
    let bus = Bus::new();
    let config = write_config(work.path(), &hh_config(20.0, 0.01).to_toml());
    for point in ["before-pdeathsig", "before-exec"] {
        let run = unique_run("spawn-kill");
        let out = work.path().join(format!("{point}.mcap"));
        let mut command = bus.command(&[
            "run",
            config.to_str().unwrap(),
            "--run",
            &run,
            "--out",
            out.to_str().unwrap(),
        ]);
        // Long enough for this test to see the child and kill `run` within it on a loaded
        // machine, and for the producer to be gone when a recorder that lost the signal
        // starts after it.
        command.env("CHAOSCOPE_SPAWN_PAUSE", format!("record:{point}:1500"));
        let mut front = Proc::spawn(command);
        let front_pid = front.pid() as u32;
        // The recorder's child: forked after the producer opened the run, still running
        // `run`'s image (its arguments are `run`'s until exec).
        let start = Instant::now();
        let recorder = loop {
            let kids = children(front_pid);
            let started = kids
                .iter()
                .any(|&k| argv(k).get(1).is_some_and(|a| a == "produce"));
            let forked = kids
                .iter()
                .copied()
                .find(|&k| argv(k).get(1).is_some_and(|a| a == "run"));
            if let (true, Some(recorder)) = (started, forked) {
                break recorder;
            }
            assert!(
                front.0.try_wait().unwrap().is_none(),
                "{point}: run ended before starting its recorder"
            );
            assert!(start.elapsed() < LIMIT, "{point}: no recorder started");
            std::thread::sleep(Duration::from_millis(5));
        };
        front.signal(libc::SIGKILL);
        front.wait(LIMIT);
        let start = Instant::now();
        while running(recorder) && start.elapsed() < LIMIT {
            std::thread::sleep(Duration::from_millis(20));
        }
        let left = running(recorder).then(|| argv(recorder));
        if left.is_some() {
            // SAFETY: kill(2) of the recorder this test's `run` started.
            unsafe { libc::kill(recorder as libc::pid_t, libc::SIGKILL) };
        }
        assert_eq!(
            left, None,
            "{point}: the recorder outlived its killed `run` by {LIMIT:?}"
        );
        bus.wait_nodes_gone(&run);
        // The recorder ended before it wrote anything, and the producer streamed to nobody.
        assert!(!out.exists(), "{point}: {out:?} written");
        assert!(
            !chaoscope_os::output::partial_path(&out).exists(),
            "{point}: an in-progress file left"
        );
    }
}
