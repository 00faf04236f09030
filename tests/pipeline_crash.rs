//! Crashes and signals leave valid data; a slow recorder loses nothing.

use std::path::Path;
use std::time::{Duration, Instant};

use crate::common::*;
use chaoscope_bus::{self as bus, Liveness};
use chaoscope_schemas::config::RunConfig;
use chaoscope_schemas::names;

const LIMIT: Duration = Duration::from_secs(60);

/// Waits until the in-progress file of `out` (`out.partial`, renamed to `out` once the
/// recording is finalized) holds at least `bytes` bytes (completed chunks are on disk).
/// Waits until the in-progress file of `out` holds `bytes` (true) or `p` has exited (false).
fn wait_for_size_or_exit(out: &Path, bytes: u64, p: &mut Proc) -> bool {
    let path = &chaoscope_os::output::partial_path(out);
    let start = Instant::now();
    loop {
        if std::fs::metadata(path).map(|m| m.len()).unwrap_or(0) >= bytes {
            return true;
        }
        if p.0.try_wait().unwrap().is_some() {
            return false;
        }
        assert!(
            start.elapsed() < LIMIT,
            "{} never reached {bytes} bytes",
            path.display()
        );
        std::thread::sleep(Duration::from_millis(5));
    }
}

/// The complete samples the recording at `path` holds on disk (read up to any damage; 0 if
/// there is no such file or it holds no sample yet).
fn samples_on_disk(path: &Path) -> usize {
    let Ok(mut reader) = chaoscope_analyzer::recording::RecordingReader::open_salvaging(path)
    else {
        return 0;
    };
    let mut n = 0;
    while let Ok(Some(_)) = reader.next_sample() {
        n += 1;
    }
    n
}

fn wait_for_size(out: &Path, bytes: u64) {
    let path = &chaoscope_os::output::partial_path(out);
    let start = Instant::now();
    while std::fs::metadata(path).map(|m| m.len()).unwrap_or(0) < bytes {
        assert!(
            start.elapsed() < LIMIT,
            "{} never reached {bytes} bytes",
            path.display()
        );
        std::thread::sleep(Duration::from_millis(20));
    }
}

fn produce_cmd(run: &str, config: &Path) -> std::process::Command {
    chaoscope(&[
        "produce",
        config.to_str().unwrap(),
        "--run",
        run,
        "--no-progress",
        "--wait-timeout",
        "60",
    ])
}

#[test]
fn kill_9_of_the_recorder_keeps_every_completed_chunk_and_recover_salvages_it() {
    let dir = tempfile::tempdir().unwrap();
    let text = hh_config(1e5, 0.01).to_toml(); // far longer than the test lasts
    let config = write_config(dir.path(), &text);
    let broken = dir.path().join("broken.mcap");
    let run = unique_run("kill-recorder");
    let mut recorder = Proc::spawn(record_cmd(
        &run,
        &broken,
        &["--chunk-size", "65536", "--compression", "lz4"],
    ));
    let mut producer = Proc::spawn(produce_cmd(&run, &config));
    wait_for_size(&broken, 400_000);
    recorder.signal(libc::SIGKILL);
    recorder.wait(LIMIT);
    // A killed recorder's file never has the output's name: it stays in progress.
    assert!(!broken.exists());
    let broken = chaoscope_os::output::partial_path(&broken);

    // The producer neither hangs on its dead recorder nor computes on for nobody: once the
    // dead recorder is cleaned up it ends by itself (the run failed: its recorders left).
    assert_eq!(
        producer.wait(LIMIT).code(),
        Some(3),
        "producer should end, its recorder gone"
    );

    // The killed file has no summary; standard readers of the indexed layout reject it.
    let bytes = std::fs::read(&broken).unwrap();
    assert!(mcap::Summary::read(&bytes).is_err() || mcap::Summary::read(&bytes).unwrap().is_none());

    let fixed = dir.path().join("fixed.mcap");
    let out = std::process::Command::new(CHAOSCOPE)
        .args([
            "recover",
            broken.to_str().unwrap(),
            "--out",
            fixed.to_str().unwrap(),
        ])
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let rec = read_recording(&fixed);
    assert!(rec.header.is_some(), "the run header survives");
    assert!(
        rec.references.len() > 100,
        "only {} samples salvaged",
        rec.references.len()
    );
    assert_contiguous(&rec.frames);
    let expected = compute(&text, Some(rec.references.len() + 1));
    assert_bit_identical(&rec, &expected);
    let summary = mcap::Summary::read(&std::fs::read(&fixed).unwrap())
        .unwrap()
        .expect("indexed");
    assert!(!summary.chunk_indexes.is_empty());
}

#[test]
fn kill_9_of_the_producer_makes_the_recorder_finalize_an_interrupted_file() {
    let dir = tempfile::tempdir().unwrap();
    let text = hh_config(1e5, 0.01).to_toml();
    let config = write_config(dir.path(), &text);
    let out = dir.path().join("run.mcap");
    let run = unique_run("kill-producer");
    let mut recorder = Proc::spawn(record_cmd(&run, &out, &["--chunk-size", "65536"]));
    let mut producer = Proc::spawn(produce_cmd(&run, &config));
    wait_for_size(&out, 200_000);
    producer.signal(libc::SIGKILL);
    producer.wait(LIMIT);
    assert!(
        recorder.wait(LIMIT).success(),
        "recorder must finalize, not fail"
    );

    let rec = read_recording(&out);
    let summary = rec.recording.as_ref().expect("recording summary");
    assert_eq!(summary.finalized_by, "producer-died");
    assert_eq!(summary.run_status, "interrupted");
    assert_eq!(summary.frames_missing, 0);
    assert!(rec.end.is_none());
    assert_contiguous(&rec.frames);
    let expected = compute(&text, Some(rec.references.len() + 1));
    assert_bit_identical(&rec, &expected);
    // The dead producer's shared memory was cleaned up.
    assert_eq!(
        bus::node_liveness(&names::producer_node_name(&run)),
        Liveness::Absent
    );
}

/// `chaoscope run` of Henon-Heiles to t = 10^5 (hours) into `DIR/run.mcap`, under a unique
/// run name made from `tag`: the command, the run's name and the output.
fn long_hh_run(dir: &Path, tag: &str) -> (std::process::Command, String, std::path::PathBuf) {
    let config = write_config(dir, &hh_config(1e5, 0.01).to_toml());
    let out = dir.join("run.mcap");
    let run = unique_run(tag);
    let command = chaoscope(&[
        "run",
        config.to_str().unwrap(),
        "--run",
        &run,
        "--out",
        out.to_str().unwrap(),
    ]);
    (command, run, out)
}

#[test]
fn sigint_to_chaoscope_run_ends_both_processes_with_a_valid_file() {
    let dir = tempfile::tempdir().unwrap();
    let (command, run, out) = long_hh_run(dir.path(), "sigint");
    let mut front = Proc::spawn(command);
    wait_for_size(&out, 100_000);
    front.signal(libc::SIGINT); // to the front door only: it must forward it
    assert_eq!(front.wait(LIMIT).code(), Some(130));
    let printed = front.stdout();
    assert!(
        printed.contains("status interrupted"),
        "summary printed: {printed}"
    );

    let rec = read_recording(&out);
    let summary = rec.recording.as_ref().expect("finalized file");
    assert_eq!(summary.run_status, "interrupted");
    assert_eq!(summary.frames_missing, 0);
    // The recorder got the signal too, and waited for the producer's end-of-run record, so
    // the file says how the run ended (`analyze`'s `run.end`), not only that it was cut.
    assert_eq!(summary.finalized_by, "end-of-run");
    let end = rec.end.as_ref().expect("the producer's end-of-run record");
    assert_eq!(
        chaoscope_schemas::proto::end_of_run::Status::try_from(end.status),
        Ok(chaoscope_schemas::proto::end_of_run::Status::Interrupted)
    );
    assert_contiguous(&rec.frames);
    for name in [
        names::producer_node_name(&run),
        names::recorder_node_name(&run),
    ] {
        assert_eq!(
            bus::node_liveness(&name),
            Liveness::Absent,
            "{name} still around"
        );
    }
}

/// The producer under `chaoscope run` killed by a signal from outside (the OOM killer, a
/// stray `kill -9`): the recorder finalizes an interrupted file, and `run` exits 1 with one
/// line saying what happened and how to go on (before: exit 1 and nothing on stderr).
#[test]
fn a_killed_producer_under_run_is_said_in_one_line_naming_resume() {
    let dir = tempfile::tempdir().unwrap();
    let (mut command, _, out) = long_hh_run(dir.path(), "kill-producer-run");
    let errors = dir.path().join("stderr");
    command.stderr(std::fs::File::create(&errors).unwrap());
    let mut front = Proc::spawn(command);
    wait_for_size(&out, 100_000);
    let pid = front.pid();
    let children = std::fs::read_to_string(format!("/proc/{pid}/task/{pid}/children")).unwrap();
    let producer = children
        .split_whitespace()
        .map(|c| c.parse::<i32>().unwrap())
        .find(|c| {
            std::fs::read(format!("/proc/{c}/cmdline"))
                .is_ok_and(|a| a.split(|&b| b == 0).any(|w| w == b"produce"))
        })
        .expect("run's producer");
    // SAFETY: kill(2) of a child process of ours that is still running.
    unsafe { libc::kill(producer, libc::SIGKILL) };
    assert_eq!(front.wait(LIMIT).code(), Some(1));
    let said = std::fs::read_to_string(&errors).unwrap();
    let line = format!(
        "chaoscope: error: the producer was killed by signal 9; the recording holds the run up to \
         there (`chaoscope resume {}` continues it)",
        out.display()
    );
    assert!(said.contains(&line), "{said}");
    let summary = read_recording(&out).recording.expect("finalized file");
    assert_eq!(
        (summary.finalized_by.as_str(), summary.run_status.as_str()),
        ("producer-died", "interrupted")
    );
}

/// A `chaoscope run` started with SIGINT ignored (a script's background job; `nohup`-style
/// wrappers) keeps ignoring it from its first instant to its end, and so do the producer and
/// the recorder it starts: a SIGINT at once, before any handler is in place, and a Ctrl-C to the
/// whole process group once it records, stop nothing (before, the first was ignored and the
/// second stopped the run). SIGTERM then stops it as usual, with a complete file.
#[test]
fn a_run_started_with_sigint_ignored_keeps_ignoring_it_and_stops_on_sigterm() {
    use std::os::unix::process::CommandExt;
    let dir = tempfile::tempdir().unwrap();
    let (mut c, _, out) = long_hh_run(dir.path(), "sigign");
    c.process_group(0);
    // SAFETY: signal(2) between fork and exec, async-signal-safe.
    unsafe {
        c.pre_exec(|| {
            libc::signal(libc::SIGINT, libc::SIG_IGN);
            Ok(())
        });
    }
    let mut front = Proc::spawn(c);
    front.signal(libc::SIGINT);
    wait_for_size(&out, 100_000);
    // SAFETY: kill(2) on the process group our own child leads.
    unsafe { libc::kill(-front.pid(), libc::SIGINT) };
    let partial = chaoscope_os::output::partial_path(&out);
    let size_at_sigint = std::fs::metadata(&partial).unwrap().len();
    // Still recording well after the Ctrl-C: another megabyte in the in-progress file (this
    // run records several a second), the run still going.
    assert!(
        wait_for_size_or_exit(&out, size_at_sigint + 1_000_000, &mut front),
        "the run stopped on SIGINT"
    );

    front.signal(libc::SIGTERM);
    assert_eq!(front.wait(LIMIT).code(), Some(143));
    let rec = read_recording(&out);
    let summary = rec.recording.as_ref().expect("finalized file");
    assert_eq!(summary.run_status, "interrupted");
    assert_eq!(summary.frames_missing, 0);
    assert_eq!(summary.finalized_by, "end-of-run");
    assert_contiguous(&rec.frames);
}

#[test]
fn a_slow_recorder_loses_nothing_because_the_producer_waits() {
    let dir = tempfile::tempdir().unwrap();
    let text = hh_config(10.0, 0.01).to_toml(); // 1001 samples, 5005 frames
    let config = write_config(dir.path(), &text);
    let out = dir.path().join("slow.mcap");
    let run = unique_run("slow");
    // 0.3 ms per message: far slower than the producer, so its buffer is full most of the time.
    let mut recorder = Proc::spawn(record_cmd(&run, &out, &["--throttle-ms", "0.3"]));
    let mut producer = Proc::spawn(produce_cmd(&run, &config));
    assert!(producer.wait(LIMIT).success());
    assert!(recorder.wait(LIMIT).success());
    let rec = read_recording(&out);
    let expected = compute(&text, None);
    assert_eq!(rec.references.len(), expected.len());
    assert_contiguous(&rec.frames);
    assert_bit_identical(&rec, &expected);
    let summary = rec.recording.unwrap();
    assert_eq!(
        (summary.frames_missing, summary.run_status.as_str()),
        (0, "completed")
    );
}

// ---------------------------------------------------------------------------------------------
// Issue #24, signals: the kill-and-signal matrix.
//
// Every long-running command, at every moment of its life, under load: SIGINT or SIGTERM ends
// it within one second (every renormalization window of these configs is far shorter), with
// exit status 130 or 143 (0 if it had finished its work when the signal came; a process
// signalled before its own code runs dies of the signal, which a shell reports the same way),
// and leaves a valid file at the output's name or none (a command that has nothing worth
// finalizing ends at once and removes its unfinished output), never an in-progress file. The
// partner of a signalled recorder or producer ends too. Moments are events seen from outside:
// the process spawned, its program running (exec done), its in-progress file created, data in
// it (or the C compiler building a potential's step kernels), its output in place.

/// Longest time from the signal to the command's exit: the promise.
const SIGNAL_BOUND: Duration = Duration::from_secs(1);
/// What the test allows beyond the promise for the load it makes itself. It runs four cases
/// at a time (a map with two threads, a producer beside its recorder) beside two busy threads
/// on what may be a 2-core machine shared with other tests: five to eight runnable threads per
/// core. After its signal a command still has to be scheduled and do its last work (a footer,
/// an fsync of the file and of its directory, a rename), each step waiting behind the other
/// runnable threads' time slices and the disk's queue. Measured: with a load average of 6-9
/// the worst case took 0.31-0.59 s; with 16-22 (other builds besides), 0.83 and 0.99 s. Half a
/// second more keeps a case on a machine loaded far beyond CI from failing for the machine's
/// sake, while a command that ignores its signal (which runs on for seconds or minutes, as
/// every failure this matrix found did) still fails. Cases over the promise itself are counted
/// and printed.
const LOAD_MARGIN: Duration = Duration::from_millis(500);
/// How long a moment may take to come.
const MOMENT_LIMIT: Duration = Duration::from_secs(60);

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Kind {
    Run,
    /// `record` signalled, its producer started first.
    Record,
    /// `produce` signalled, its recorder started first.
    Produce,
    /// The standard map (a discrete map, VM, batched).
    Map,
    /// A user-written potential: its C step kernels build while the map runs.
    PotentialMap,
    Replay,
    Merge,
    Recover,
    Analyze,
    Section,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Moment {
    /// At once: the child may not have executed chaoscope yet.
    Spawned,
    /// Its program runs (exec done).
    Started,
    /// Its in-progress file exists.
    Opened,
    /// The system C compiler builds the step kernels.
    Building,
    /// Data flows: its in-progress file grew past its first bytes (`analyze`, which writes at
    /// the end only: 100 ms into reading).
    Mid,
    /// Its output is in place: the work is done, the process is ending.
    End,
}

#[derive(Debug, Clone, Copy)]
struct Case {
    kind: Kind,
    threads: usize,
    moment: Moment,
    signal: i32,
}

/// Inputs shared by the cases (read only).
struct Inputs {
    dir: tempfile::TempDir,
    long_run: std::path::PathBuf,
    short_run: std::path::PathBuf,
    /// A recording that takes a while to replay, and a short one.
    long_recording: std::path::PathBuf,
    short_recording: std::path::PathBuf,
    long_map: std::path::PathBuf,
    short_map: std::path::PathBuf,
    long_potential: std::path::PathBuf,
    short_potential: std::path::PathBuf,
    shards: Vec<std::path::PathBuf>,
    section: std::path::PathBuf,
}

fn fput_potential_map(n: usize, grid: usize, t_final: f64) -> String {
    let q: Vec<String> = (1..=n)
        .map(|i| {
            format!(
                "{}",
                0.5 * (std::f64::consts::PI * i as f64 / (n + 1) as f64).sin()
            )
        })
        .collect();
    let p = vec!["0.0"; n].join(", ");
    format!(
        "[model]\nname = \"potential\"\nn = {n}\nboundary = \"fixed\"\nparams = {{ beta = 1.0 }}\n\
         potential = \"sum(i = 0..N, (q[i+1] - q[i])^2/2 + beta/4*(q[i+1] - q[i])^4)\"\n\
         [orbit]\nq = [{}]\np = [{p}]\n\
         [integrator]\nmethod = \"aba864\"\nh = 0.02\nt_final = {t_final}\n\
         [deviations]\nk = 2\nsets = 1\nseed = 3\n\
         [[scheme]]\nname = \"mpm\"\nmethod = \"mpm\"\nd0 = 1e-8\ntau = 1.0\n\
         [map]\nx = {{ coord = \"q1\", min = -0.1, max = 0.1, n = {grid} }}\n\
         y = {{ coord = \"q2\", min = -0.1, max = 0.1, n = {grid} }}\nindicator = \"gali\"\nk = 2\n",
        q.join(", ")
    )
}

fn standard_map(n: usize, t_final: u64) -> String {
    format!(
        "[model]\nname = \"map\"\nnext = [\"x1 + x2 + K*sin(x1)\", \"x2 + K*sin(x1)\"]\n\
         params = {{ K = 1.0 }}\nmodulo = [6.283185307179586, 6.283185307179586]\n\
         [orbit]\nx = [0.0, 0.0]\n[integrator]\nh = 1\nt_final = {t_final}\n\
         [deviations]\nk = 2\nsets = 1\nseed = 1\n\
         [[scheme]]\nname = \"vm\"\nmethod = \"vm\"\nd0 = 1e-8\ntau = 1\n\
         [map]\nx = {{ coord = \"x1\", min = 0.0, max = 6.283185307179586, n = {n} }}\n\
         y = {{ coord = \"x2\", min = -3.141592653589793, max = 3.141592653589793, n = {n} }}\n\
         indicator = \"sali\"\nroute = \"per-set\"\n"
    )
}

impl Inputs {
    fn new() -> Self {
        let dir = tempfile::tempdir().unwrap();
        let write = |name: &str, text: &str| {
            let p = dir.path().join(name);
            std::fs::write(&p, text).unwrap();
            p
        };
        let long_run = write("long-run.toml", &hh_config(1e6, 0.01).to_toml());
        let short_run = write("short-run.toml", &hh_config(2.0, 0.01).to_toml());
        let long_map = write("long-map.toml", &standard_map(10, 200_000));
        let short_map = write("short-map.toml", &standard_map(4, 2_000));
        let long_potential = write("long-potential.toml", &fput_potential_map(101, 4, 1000.0));
        let short_potential = write("short-potential.toml", &fput_potential_map(101, 2, 5.0));
        let section = write(
            "section.toml",
            &include_str!("data/hh-map-small.toml").replace("t_final = 20.0", "t_final = 200.0"),
        );
        let record = |config: &Path, name: &str| {
            let out = dir.path().join(name);
            run_ok(&[
                "run",
                config.to_str().unwrap(),
                "--run",
                &unique_run("matrix-input"),
                "--out",
                out.to_str().unwrap(),
            ]);
            out
        };
        // About 1.5 s of replay (more under load): 20 sets of k = 4.
        let replayed = {
            let mut c = hh_config(300.0, 0.5);
            c.deviations = chaoscope_schemas::config::DeviationsConfig::random(4, 20, 11);
            write("replayed.toml", &c.to_toml())
        };
        let long_recording = record(&replayed, "long.mcap");
        let short_recording = record(&short_run, "short.mcap");
        let map_config = write("shard-map.toml", include_str!("data/hh-map-small.toml"));
        let shards = (0..2)
            .map(|i| {
                let out = dir.path().join(format!("shard-{i}.mcap"));
                run_ok(&[
                    "map",
                    map_config.to_str().unwrap(),
                    "--out",
                    out.to_str().unwrap(),
                    "--shard",
                    &format!("{i}/2"),
                    "--no-progress",
                    "--name",
                    &unique_run("matrix-shard"),
                ]);
                out
            })
            .collect();
        Self {
            dir,
            long_run,
            short_run,
            long_recording,
            short_recording,
            long_map,
            short_map,
            long_potential,
            short_potential,
            shards,
            section,
        }
    }
}

/// Two busy threads: the load the matrix runs under (with the cases themselves, more runnable
/// threads than the machine has cores).
struct Hog {
    stop: std::sync::Arc<std::sync::atomic::AtomicBool>,
    threads: Vec<std::thread::JoinHandle<u64>>,
}

impl Hog {
    fn start(threads: usize) -> Self {
        let stop = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
        let threads = (0..threads)
            .map(|_| {
                let stop = stop.clone();
                std::thread::spawn(move || {
                    let mut x = 0u64;
                    while !stop.load(std::sync::atomic::Ordering::Relaxed) {
                        for _ in 0..10_000 {
                            x = std::hint::black_box(x.wrapping_mul(6364136223846793005) + 1);
                        }
                    }
                    x
                })
            })
            .collect();
        Self { stop, threads }
    }
}

impl Drop for Hog {
    fn drop(&mut self) {
        self.stop.store(true, std::sync::atomic::Ordering::Relaxed);
        for t in self.threads.drain(..) {
            let _ = t.join();
        }
    }
}

/// A spawned chaoscope process whose stderr goes to a file of the case.
fn spawn_in(dir: &Path, tag: &str, args: &[String], env: &[(&str, String)]) -> Proc {
    let mut c = std::process::Command::new(CHAOSCOPE);
    c.args(args)
        .stdin(std::process::Stdio::null())
        .stdout(std::process::Stdio::null())
        .stderr(std::fs::File::create(dir.join(format!("{tag}.stderr"))).unwrap());
    for (k, v) in env {
        c.env(k, v);
    }
    Proc::spawn(c)
}

/// Whether a process of `pid` runs chaoscope's own program (exec done).
fn executing_chaoscope(pid: i32) -> bool {
    std::fs::read_link(format!("/proc/{pid}/exe"))
        .is_ok_and(|exe| exe == Path::new(CHAOSCOPE) || exe.ends_with("chaoscope"))
}

/// Any process whose command line mentions `needle` (the C compiler building into a cache).
fn process_mentioning(needle: &str) -> bool {
    std::fs::read_dir("/proc").unwrap().flatten().any(|e| {
        e.file_name()
            .to_str()
            .is_some_and(|n| n.bytes().all(|b| b.is_ascii_digit()))
            && std::fs::read(e.path().join("cmdline"))
                .is_ok_and(|c| c.windows(needle.len()).any(|w| w == needle.as_bytes()))
    })
}

fn size(path: &Path) -> u64 {
    std::fs::metadata(path).map_or(0, |m| m.len())
}

/// How a case went.
struct Outcome {
    /// From the signal to the exit; `None` if the command had ended before the moment came.
    took: Option<Duration>,
    /// The whole case.
    wall: Duration,
}

fn run_case(inputs: &Inputs, case: Case, n: usize) -> Result<Outcome, String> {
    let case_start = Instant::now();
    let work = tempfile::tempdir_in(inputs.dir.path()).unwrap();
    let dir = work.path();
    let s = |p: &Path| p.to_str().unwrap().to_string();
    let long = !matches!(case.moment, Moment::End);
    let cache = dir.join("kernel-cache");
    let env = vec![("CHAOSCOPE_KERNEL_CACHE", s(&cache))];
    let run = unique_run(&format!("matrix{n}"));
    // The output (its name; a command may write several), and the partner process.
    let (out, args, partner): (std::path::PathBuf, Vec<String>, Option<Vec<String>>) =
        match case.kind {
            Kind::Run => {
                let out = dir.join("run.mcap");
                let config = if long {
                    &inputs.long_run
                } else {
                    &inputs.short_run
                };
                let args = ["run", &s(config), "--run", &run, "--out", &s(&out)];
                (out, args.map(String::from).to_vec(), None)
            }
            Kind::Record | Kind::Produce => {
                let out = dir.join("run.mcap");
                let config = if long {
                    &inputs.long_run
                } else {
                    &inputs.short_run
                };
                let produce = ["produce", &s(config), "--run", &run, "--no-progress"];
                let record = ["record", "--run", &run, "--out", &s(&out)];
                let (me, other): (Vec<String>, Vec<String>) = if case.kind == Kind::Record {
                    (
                        record.map(String::from).to_vec(),
                        produce.map(String::from).to_vec(),
                    )
                } else {
                    (
                        produce.map(String::from).to_vec(),
                        record.map(String::from).to_vec(),
                    )
                };
                (out, me, Some(other))
            }
            Kind::Map | Kind::PotentialMap => {
                let out = dir.join("map.mcap");
                let config = match (case.kind, long) {
                    (Kind::Map, true) => &inputs.long_map,
                    (Kind::Map, false) => &inputs.short_map,
                    (_, true) => &inputs.long_potential,
                    (_, false) => &inputs.short_potential,
                };
                let threads = case.threads.to_string();
                let args = [
                    "map",
                    &s(config),
                    "--out",
                    &s(&out),
                    "--threads",
                    &threads,
                    "--no-progress",
                    "--flush-interval",
                    "0.1",
                    "--name",
                    &run,
                ];
                (out, args.map(String::from).to_vec(), None)
            }
            Kind::Replay => {
                let out = dir.join("replay.mcap");
                let input = if long {
                    &inputs.long_recording
                } else {
                    &inputs.short_recording
                };
                let args = [
                    "replay",
                    &s(input),
                    "--tau",
                    "1.0",
                    "--tau",
                    "2.0",
                    "--out",
                    &s(&out),
                ];
                (out, args.map(String::from).to_vec(), None)
            }
            Kind::Merge => {
                let out = dir.join("merged.mcap");
                let mut args: Vec<String> = vec!["merge".into()];
                args.extend(inputs.shards.iter().map(|p| s(p)));
                args.extend([
                    "--out".into(),
                    s(&out),
                    "--png".into(),
                    s(&dir.join("m.png")),
                ]);
                (out, args, None)
            }
            Kind::Recover => {
                let out = dir.join("recovered.mcap");
                let args = ["recover", &s(&inputs.long_recording), "--out", &s(&out)];
                (out, args.map(String::from).to_vec(), None)
            }
            Kind::Analyze => {
                let csv = dir.join("csv");
                let args = [
                    "analyze",
                    &s(&inputs.long_recording),
                    "--csv",
                    &s(&csv),
                    "--plot",
                    &s(&dir.join("plot")),
                ];
                (csv.join("vm.csv"), args.map(String::from).to_vec(), None)
            }
            Kind::Section => {
                let out = dir.join("section.csv");
                let args = [
                    "section",
                    &s(&inputs.section),
                    "--vary",
                    "q2",
                    "--from",
                    "-0.2",
                    "--to",
                    "0.2",
                    "--count",
                    if long { "400" } else { "3" },
                    "--csv",
                    &s(&out),
                    "--plot",
                    &s(dir),
                ];
                (out, args.map(String::from).to_vec(), None)
            }
        };
    let partial = chaoscope_os::output::partial_path(&out);
    // A partner first: a recorder waits for its run, a producer for its recorder.
    let mut partner = partner.map(|a| spawn_in(dir, "partner", &a, &env));
    if case.kind == Kind::Record {
        wait_for_node(&names::producer_node_name(&run));
    }
    let mut me = spawn_in(dir, "me", &args, &env);
    let pid = me.pid();
    let mut reached = |what: &dyn Fn() -> bool| -> Result<bool, String> {
        let start = Instant::now();
        loop {
            if what() {
                return Ok(true);
            }
            if me.0.try_wait().unwrap().is_some() {
                return Ok(false);
            }
            if start.elapsed() > MOMENT_LIMIT {
                return Err(format!("{case:?}: its moment never came"));
            }
            std::thread::sleep(Duration::from_millis(2));
        }
    };
    let opened_size = std::cell::Cell::new(0);
    let came = match case.moment {
        Moment::Spawned => true,
        Moment::Started => reached(&|| executing_chaoscope(pid))?,
        Moment::Opened => reached(&|| partial.exists())?,
        Moment::Building => reached(&|| process_mentioning(&s(&cache)))?,
        Moment::Mid if case.kind == Kind::Analyze => {
            std::thread::sleep(Duration::from_millis(100));
            true
        }
        Moment::Mid => reached(&|| {
            let now = size(&partial);
            if opened_size.get() == 0 {
                opened_size.set(now);
            }
            opened_size.get() > 0 && now > opened_size.get()
        })?,
        Moment::End => reached(&|| out.exists())?,
    };
    let signalled = Instant::now();
    if came {
        me.signal(case.signal);
    }
    let status = loop {
        if let Some(status) = me.0.try_wait().unwrap() {
            break status;
        }
        if signalled.elapsed() > Duration::from_secs(30) {
            me.signal(libc::SIGKILL);
            return Err(format!("{case:?}: still running 30 s after the signal"));
        }
        std::thread::sleep(Duration::from_millis(1));
    };
    let took = came.then(|| signalled.elapsed());
    let stderr = std::fs::read_to_string(dir.join("me.stderr")).unwrap_or_default();
    if stderr.contains("panicked") {
        return Err(format!("{case:?}: panicked: {stderr}"));
    }
    if let Some(t) = took
        && t > SIGNAL_BOUND + LOAD_MARGIN
    {
        return Err(format!("{case:?}: ended {t:?} after the signal"));
    }
    // Its exit status: the signal's, or success if its work was done.
    use std::os::unix::process::ExitStatusExt;
    let by_signal = status.code()
        == Some(i32::from(chaoscope_os::signals::exit_status(case.signal)))
        || status.signal() == Some(case.signal);
    // Success is right when the work was done before the signal was seen (the output is then
    // in place, checked below).
    let ok_status = by_signal || status.success() && (!came || out.exists());
    if !ok_status {
        return Err(format!("{case:?}: exit {status}: {stderr}"));
    }
    if let Some(p) = &mut partner {
        // A partner that met the signalled process ends by itself: a producer whose recorder
        // left after taking samples, a recorder that got its run's header (the producer's end
        // or death ends it). One that never met it still waits for it, as it should (a
        // recorder that came and went before its producer looked is one the producer never
        // had); the user (here, the test) ends that one.
        let met = match case.kind {
            Kind::Record => chaoscope_analyzer::recording::analyze_file(
                &out,
                &chaoscope_analyzer::AnalysisOptions::default(),
            )
            .is_ok_and(|(a, _)| a.report().run.samples > 0),
            _ => size(&out) > 0 || size(&partial) > 0,
        };
        let start = Instant::now();
        while p.0.try_wait().unwrap().is_none() {
            if !met || start.elapsed() > Duration::from_secs(20) {
                p.signal(libc::SIGTERM);
                p.wait(Duration::from_secs(20));
                if met {
                    return Err(format!("{case:?}: its partner did not end"));
                }
                break;
            }
            std::thread::sleep(Duration::from_millis(10));
        }
    }
    // Never an in-progress file; the output valid where it is.
    for e in walk(dir) {
        if e.to_string_lossy().contains(".partial") {
            return Err(format!("{case:?}: left {e:?}"));
        }
    }
    if out.exists() {
        match case.kind {
            Kind::Run | Kind::Record | Kind::Produce | Kind::Replay | Kind::Recover => {
                chaoscope_analyzer::recording::analyze_file(
                    &out,
                    &chaoscope_analyzer::AnalysisOptions::default(),
                )
                .map_err(|e| format!("{case:?}: {out:?} unreadable: {e}"))?;
            }
            Kind::Map | Kind::PotentialMap | Kind::Merge => {
                let m = chaoscope_files::map_file::read_map_file(&out)
                    .map_err(|e| format!("{case:?}: {out:?}: {e}"))?;
                if m.damaged.is_some() || m.header.is_none() {
                    return Err(format!("{case:?}: {out:?} damaged: {:?}", m.damaged));
                }
            }
            Kind::Analyze | Kind::Section => {
                if size(&out) == 0 {
                    return Err(format!("{case:?}: {out:?} empty"));
                }
            }
        }
    } else if came
        && matches!(case.moment, Moment::Mid)
        && matches!(
            case.kind,
            Kind::Run
                | Kind::Record
                | Kind::Produce
                | Kind::Map
                | Kind::PotentialMap
                | Kind::Replay
        )
    {
        return Err(format!("{case:?}: data was written, yet no file: {stderr}"));
    }
    Ok(Outcome {
        took,
        wall: case_start.elapsed(),
    })
}

fn walk(dir: &Path) -> Vec<std::path::PathBuf> {
    let mut out = Vec::new();
    for e in std::fs::read_dir(dir).into_iter().flatten().flatten() {
        let p = e.path();
        if p.is_dir() {
            out.extend(walk(&p));
        }
        out.push(p);
    }
    out
}

#[test]
fn sigint_and_sigterm_end_every_long_command_at_every_moment_with_a_valid_file() {
    let started = Instant::now();
    let inputs = Inputs::new();
    let mut cases = Vec::new();
    use Moment::*;
    let writing = [Spawned, Started, Opened, Mid, End];
    let one_shot = [Spawned, Started, Opened, End];
    let plan: Vec<(Kind, usize, Vec<Moment>)> = vec![
        (Kind::Run, 1, writing.to_vec()),
        (Kind::Record, 1, writing.to_vec()),
        (Kind::Produce, 1, writing.to_vec()),
        (Kind::Replay, 1, writing.to_vec()),
        (Kind::Map, 1, writing.to_vec()),
        (Kind::Map, 2, writing.to_vec()),
        (
            Kind::PotentialMap,
            1,
            vec![Spawned, Started, Building, Mid, End],
        ),
        (
            Kind::PotentialMap,
            2,
            vec![Spawned, Started, Building, Mid, End],
        ),
        (Kind::Merge, 1, one_shot.to_vec()),
        (Kind::Recover, 1, one_shot.to_vec()),
        (Kind::Section, 1, one_shot.to_vec()),
        (Kind::Analyze, 1, vec![Spawned, Started, Mid, End]),
    ];
    for (kind, threads, moments) in plan {
        for moment in moments {
            for signal in [libc::SIGINT, libc::SIGTERM] {
                cases.push(Case {
                    kind,
                    threads,
                    moment,
                    signal,
                });
            }
        }
    }
    let total = cases.len();
    assert!(total >= 100, "{total} cases");
    let prepared = started.elapsed();
    let hog = Hog::start(2);
    // Four at a time: with the hog, more runnable threads than cores all along.
    let queue = std::sync::Mutex::new(cases.into_iter().enumerate().collect::<Vec<_>>());
    let results = std::sync::Mutex::new(Vec::new());
    std::thread::scope(|scope| {
        for _ in 0..4 {
            scope.spawn(|| {
                while let Some((n, case)) = queue.lock().unwrap().pop() {
                    // A case that panics (an assertion of a helper) is a failed case.
                    let r = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
                        run_case(&inputs, case, n)
                    }))
                    .unwrap_or_else(|_| Err(format!("{case:?}: panicked in the test")));
                    // Named as it happens: a matrix killed at an outer timeout (run against an
                    // older binary, tests/against-binary.sh) still tells which cases failed.
                    if let Err(e) = &r {
                        eprintln!("case {n} failed: {e}");
                    }
                    results.lock().unwrap().push((case, r));
                }
            });
        }
    });
    drop(hog);
    let results = results.into_inner().unwrap();
    let failures: Vec<&String> = results
        .iter()
        .filter_map(|(_, r)| r.as_ref().err())
        .collect();
    let took: Vec<Duration> = results
        .iter()
        .filter_map(|(_, r)| r.as_ref().ok().and_then(|o| o.took))
        .collect();
    let early = results
        .iter()
        .filter(|(_, r)| r.as_ref().is_ok_and(|o| o.took.is_none()))
        .count();
    let worst = took.iter().max().copied().unwrap_or_default();
    // The slowest answers to a signal, and how many went past the promise into the margin.
    let mut answers: Vec<(Duration, Case)> = results
        .iter()
        .filter_map(|(c, r)| r.as_ref().ok().and_then(|o| o.took).map(|t| (t, *c)))
        .collect();
    answers.sort_by_key(|a| std::cmp::Reverse(a.0));
    let over_promise = answers.iter().filter(|a| a.0 > SIGNAL_BOUND).count();
    eprintln!(
        "slowest answers to a signal: {:?}; {over_promise} over {SIGNAL_BOUND:?}",
        &answers[..answers.len().min(4)]
    );
    let mut walls: Vec<(Duration, Case)> = results
        .iter()
        .filter_map(|(c, r)| r.as_ref().ok().map(|o| (o.wall, *c)))
        .collect();
    walls.sort_by_key(|w| std::cmp::Reverse(w.0));
    eprintln!("slowest cases: {:?}", &walls[..walls.len().min(6)]);
    let mut sorted = took.clone();
    sorted.sort();
    eprintln!(
        "signal matrix: {total} cases ({} signalled, {early} had ended before their moment), \
         signal to exit: median {:?}, worst {worst:?}; inputs {:.1} s, matrix {:.1} s",
        took.len(),
        sorted.get(sorted.len() / 2).copied().unwrap_or_default(),
        prepared.as_secs_f64(),
        (started.elapsed() - prepared).as_secs_f64()
    );
    assert!(
        failures.is_empty(),
        "{} of {total} cases failed:\n{}",
        failures.len(),
        failures
            .iter()
            .map(|s| s.as_str())
            .collect::<Vec<_>>()
            .join("\n")
    );
    // The matrix proves little if most cases missed their moment.
    assert!(
        early * 10 <= total,
        "{early} of {total} cases ended before their moment"
    );
}

// Issue #26, resume and extend: a run killed at random moments, or interrupted, and resumed,
// and a finished run extended, give the analysis of the uninterrupted run, exactly.

/// `chaoscope analyze FILE --json` (the whole report: every indicator of every scheme at the
/// end, the curves' summary, the verdicts, the run's energy error and divergence).
fn analysis_json(path: &Path) -> String {
    run_ok(&["analyze", path.to_str().unwrap(), "--json"])
}

/// The Henon-Heiles orbit of `hh_config` with two schemes of different `tau` (resumable only
/// at their common multiples), one on the window-propagator route, VM and MPM, QR and rescale.
fn resumable_config(t_final: f64) -> String {
    let mut config = hh_config(t_final, 0.5);
    config.schemes[0].tau = 0.75;
    let mut propagator = chaoscope_schemas::config::SchemeConfig::new("vm-window", "vm", 1e-8, 1.5);
    propagator.route = Some("propagator".into());
    config.schemes.push(propagator);
    config.to_toml()
}

/// Numbers in `[lo, hi)` from a seeded generator (SplitMix64): the seed is printed, and
/// `CHAOSCOPE_RESUME_SEED` replays a failure's kills.
fn fractions(n: usize, lo: f64, hi: f64) -> Vec<f64> {
    let seed = std::env::var("CHAOSCOPE_RESUME_SEED")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or_else(|| {
            std::time::SystemTime::now()
                .duration_since(std::time::UNIX_EPOCH)
                .unwrap()
                .as_nanos() as u64
        });
    eprintln!("kills drawn from CHAOSCOPE_RESUME_SEED={seed}");
    let mut state = seed;
    (0..n)
        .map(|_| {
            state = state.wrapping_add(0x9e37_79b9_7f4a_7c15);
            let mut z = state;
            z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
            z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
            let u = (z ^ (z >> 31)) as f64 / u64::MAX as f64;
            lo + (hi - lo) * u
        })
        .collect()
}

/// `chaoscope ARGS` in a process group of its own (so a signal to the group reaches the
/// command and every process it started, as a batch system's kill does).
fn spawn_group(args: &[&str]) -> Proc {
    use std::os::unix::process::CommandExt;
    let mut c = chaoscope_captured(args);
    c.stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::null())
        .process_group(0);
    Proc::spawn(c)
}

fn signal_group(p: &Proc, signal: i32) {
    // SAFETY: kill(2) on the process group our own child leads.
    unsafe { libc::kill(-p.pid(), signal) };
}

/// Waits for the group `p` leads to be gone after a kill: its leader reaped, and none of its
/// other processes (the recorder holding the output's lock, the producer) still exiting, as a
/// batch system starts a requeued job only once the killed one's processes are gone. A dying
/// recorder's lock outlives the reaped leader by a moment, more so the more data it held.
fn wait_group_gone(p: &mut Proc) {
    p.wait(LIMIT);
    let group = p.pid().to_string();
    let start = Instant::now();
    let alive = || {
        std::fs::read_dir("/proc").unwrap().flatten().any(|e| {
            // `pid (comm) state ppid pgrp ...`; the name may hold spaces and parentheses.
            let stat = std::fs::read_to_string(e.path().join("stat")).unwrap_or_default();
            stat.rsplit_once(')').is_some_and(|(_, rest)| {
                let fields: Vec<&str> = rest.split_whitespace().take(3).collect();
                fields.len() == 3 && !matches!(fields[0], "Z" | "X") && fields[2] == group
            })
        })
    };
    while alive() {
        assert!(start.elapsed() < LIMIT, "group {group} still alive");
        std::thread::sleep(Duration::from_millis(10));
    }
}

#[test]
fn a_run_killed_at_random_moments_and_resumed_gives_the_uninterrupted_analysis() {
    let dir = tempfile::tempdir().unwrap();
    // A run of at least WHOLE_SECONDS on this machine (about 2.6 s of computing for t = 6000
    // on one core of a Zen 3, 0.8 s on a Zen 5: the length is scaled to the machine), so that
    // kills land between the recorder's chunks (it closes one every second) and before the
    // end: the moments are drawn from the measured length.
    const WHOLE_SECONDS: f64 = 3.5;
    let run = unique_run("resume");
    let whole = dir.path().join("whole.mcap");
    let mut t_final = 6_000.0;
    let (config, took) = loop {
        let config = write_config(dir.path(), &resumable_config(t_final));
        let started = Instant::now();
        run_ok(&[
            "run",
            config.to_str().unwrap(),
            "--run",
            &run,
            "--out",
            whole.to_str().unwrap(),
        ]);
        let took = started.elapsed().as_secs_f64();
        if took >= WHOLE_SECONDS || t_final >= 48_000.0 {
            break (config, took);
        }
        std::fs::remove_file(&whole).unwrap();
        t_final *= (WHOLE_SECONDS * 1.2 / took).ceil().clamp(2.0, 8.0);
    };
    eprintln!("the uninterrupted run: t = {t_final}, {took:.2} s");
    let cfg = config.to_str().unwrap();
    let want = analysis_json(&whole);

    // Each kill lands when the in-progress file holds a drawn share of the whole recording,
    // not at a drawn time: a moment drawn from the measured length misses the run when the
    // load that slowed the measurement lifts (CI once measured 17 s under the other tests'
    // load, and then three runs each finished before their moment). The share is a moment in
    // the run's own progress, whatever the machine and its load.
    let whole_bytes = std::fs::metadata(&whole).unwrap().len();
    let mut resumed = 0;
    let mut attempts = 0;
    let shares = fractions(8, 0.05, 0.8);
    for (i, share) in shares.into_iter().enumerate() {
        // Case 2 is stopped by SIGTERM (an interrupted, finalized file), the others by SIGKILL
        // of every process (a killed recorder's in-progress file). Three kills that landed in
        // the run are enough; a kill whose run outran it is drawn again, up to eight.
        if attempts == 3 {
            break;
        }
        let out = dir.path().join(format!("killed-{i}.mcap"));
        let o = out.to_str().unwrap();
        let signal = if attempts == 2 {
            libc::SIGTERM
        } else {
            libc::SIGKILL
        };
        let mut p = spawn_group(&["run", cfg, "--run", &run, "--out", o]);
        let at = (share * whole_bytes as f64) as u64;
        let landed = wait_for_size_or_exit(&out, at, &mut p);
        signal_group(&p, signal);
        wait_group_gone(&mut p);
        if !landed && out.exists() && analysis_json(&out) == want {
            continue; // it had finished before its share was on disk: drawn again
        }
        attempts += 1;
        let resume = chaoscope_captured(&["resume", o, "--json"])
            .output()
            .unwrap();
        let stderr = String::from_utf8_lossy(&resume.stderr);
        if !resume.status.success() {
            // Killed before the first chunk reached the disk: nothing to resume, said so.
            assert!(
                stderr.contains("holds no complete sample") && signal == libc::SIGKILL,
                "case {i} (at {share:.3} of the file): {stderr}"
            );
            continue;
        }
        // Resumed in place: the in-progress file became the recording.
        assert!(!chaoscope_os::output::partial_path(&out).exists());
        assert_eq!(
            analysis_json(&out),
            want,
            "case {i}: killed at {share:.3} of the file"
        );
        resumed += 1;
    }
    assert!(
        resumed >= 1,
        "none of {attempts} kills left something to resume"
    );

    // A resume killed in turn is resumed again, to the same analysis.
    let out = dir.path().join("twice.mcap");
    let o = out.to_str().unwrap();
    // The run is killed once its in-progress file holds a sample on disk (the recorder closes
    // a chunk every second: bytes alone do not say one is complete, and a run killed before
    // then leaves nothing to resume, which the cases above accept).
    let mut p = spawn_group(&["run", cfg, "--run", &run, "--out", o]);
    let partial = chaoscope_os::output::partial_path(&out);
    wait_for_size(&out, 100_000);
    let start = Instant::now();
    while samples_on_disk(&partial) == 0 {
        assert!(
            start.elapsed() < LIMIT,
            "{} never held a sample",
            partial.display()
        );
        std::thread::sleep(Duration::from_millis(20));
    }
    signal_group(&p, libc::SIGKILL);
    wait_group_gone(&mut p);
    let held = samples_on_disk(&partial);
    let mut p = spawn_group(&["resume", o]);
    std::thread::sleep(Duration::from_millis(500));
    signal_group(&p, libc::SIGKILL);
    wait_group_gone(&mut p);
    // Whatever moment the kill hit, what the killed run held is still there to resume from.
    let left = samples_on_disk(&partial).max(samples_on_disk(&out));
    assert!(
        left >= held,
        "the killed resume lost samples: {held} on disk before it, {left} after"
    );
    // Unless the resume had finished before its kill (then the run is complete).
    let again = chaoscope_captured(&["resume", o]).output().unwrap();
    assert!(
        again.status.success()
            || String::from_utf8_lossy(&again.stderr).contains("the run is complete"),
        "{}",
        String::from_utf8_lossy(&again.stderr)
    );
    assert_eq!(analysis_json(&out), want, "a resume killed and resumed");
    // A killed resume leaves nothing behind but the recording.
    let names: Vec<String> = std::fs::read_dir(dir.path())
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|n| n.starts_with("twice"))
        .collect();
    assert_eq!(names, ["twice.mcap"]);
}

/// A recorder killed after it finished its file and before it renamed it leaves the complete
/// recording at `NAME.partial`: `resume` puts it in place as it is (it said "the run is
/// complete" and left it there, and `run` refused the leftover). And a resume stopped before it
/// computed a sample leaves a finalized recording as it was, byte for byte (it rewrote it, with
/// a complete run's file replaced by an "interrupted" one when extending).
#[test]
fn a_complete_leftover_is_put_in_place_and_a_resume_stopped_at_once_changes_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let config = write_config(dir.path(), &hh_config(200.0, 1.0).to_toml());
    let whole = dir.path().join("whole.mcap");
    run_ok(&[
        "run",
        config.to_str().unwrap(),
        "--out",
        whole.to_str().unwrap(),
    ]);
    let want = analysis_json(&whole);

    let done = dir.path().join("done.mcap");
    let leftover = chaoscope_os::output::partial_path(&done);
    std::fs::copy(&whole, &leftover).unwrap();
    let out = run_ok(&["resume", done.to_str().unwrap()]);
    assert!(
        out.contains("completed at t = 200 of t_final = 200"),
        "{out}"
    );
    assert!(!leftover.exists());
    assert_eq!(analysis_json(&done), want);
    assert_eq!(
        std::fs::read(&done).unwrap(),
        std::fs::read(&whole).unwrap()
    );

    // A shorter leftover beside the complete file (a resume of it killed while copying) is not
    // the run: the file is complete, said so, and left as it is.
    let bytes = std::fs::read(&whole).unwrap();
    let stale = dir.path().join("stale.mcap");
    std::fs::write(&stale, &bytes).unwrap();
    std::fs::write(
        chaoscope_os::output::partial_path(&stale),
        &bytes[..bytes.len() / 2],
    )
    .unwrap();
    let refused = chaoscope_captured(&["resume", stale.to_str().unwrap()])
        .output()
        .unwrap();
    assert!(!refused.status.success());
    assert!(
        String::from_utf8_lossy(&refused.stderr).contains("the run is complete"),
        "{}",
        String::from_utf8_lossy(&refused.stderr)
    );
    assert_eq!(std::fs::read(&stale).unwrap(), bytes);

    let options = chaoscope_app::resume::ResumeOptions {
        t_final: Some(400.0),
        stop: Some(std::sync::Arc::new(std::sync::atomic::AtomicBool::new(
            true,
        ))),
        ..Default::default()
    };
    let outcome = chaoscope_app::resume::resume(&whole, &options).unwrap();
    assert_eq!(
        (
            outcome.status.as_str(),
            outcome.samples_computed,
            outcome.t_reached
        ),
        ("interrupted", 0, 200.0)
    );
    assert_eq!(
        std::fs::read(&whole).unwrap(),
        bytes,
        "the recording changed"
    );
    assert!(!chaoscope_os::output::partial_path(&whole).exists());
}

#[test]
fn a_finished_run_extended_to_twice_its_t_final_is_the_longer_run() {
    let dir = tempfile::tempdir().unwrap();
    // t_final = 250.25 ends off the schemes' common multiple of 1.5: the extension drops the
    // recording's last sample (at the old end, where every scheme renormalized only because the
    // run ended) and continues from t = 249.
    let rossler = r#"
[model]
name = "ode"
rhs = ["-x2 - x3", "x1 + a*x2", "b + x3*(x1 - c)"]
params = { a = 0.2, b = 0.2, c = 5.7 }
[orbit]
x = [1.0, 1.0, 0.0]
[integrator]
method = "dop853"
h = 0.01
t_final = T
[deviations]
k = 3
sets = 2
seed = 5
[[scheme]]
name = "vm"
method = "vm"
d0 = 1e-8
tau = 1.0
orthonormalize = "qr"
[[scheme]]
name = "mpm"
method = "mpm"
d0 = 1e-8
tau = 0.5
"#;
    let cases = [
        ("henon-heiles", resumable_config(250.25), 250.25, 500.5),
        ("rossler", rossler.replace("T", "150.25"), 150.25, 300.5),
    ];
    for (name, short, t, twice) in cases {
        let run = unique_run("extend");
        let long_cfg = write_config(
            dir.path(),
            &short.replace(&format!("t_final = {t}"), &format!("t_final = {twice}")),
        );
        let long = dir.path().join(format!("{name}-long.mcap"));
        run_ok(&[
            "run",
            long_cfg.to_str().unwrap(),
            "--run",
            &run,
            "--out",
            long.to_str().unwrap(),
        ]);
        let short_cfg = dir.path().join(format!("{name}-short.toml"));
        std::fs::write(&short_cfg, &short).unwrap();
        let finished = dir.path().join(format!("{name}.mcap"));
        let f = finished.to_str().unwrap();
        run_ok(&[
            "run",
            short_cfg.to_str().unwrap(),
            "--run",
            &run,
            "--out",
            f,
        ]);
        let before = std::fs::read(&finished).unwrap();

        // A finished run is not resumed without a later end.
        let again = chaoscope_captured(&["resume", f]).output().unwrap();
        assert!(!again.status.success());
        assert!(
            String::from_utf8_lossy(&again.stderr).contains("the run is complete at t_final"),
            "{}",
            String::from_utf8_lossy(&again.stderr)
        );
        // The flag's value is named when it is what fails: the recording's own end, and a time
        // off the step grid (before, "the recorded configuration is no longer valid").
        let off_grid = format!("{}", t + 0.005);
        for (asked, said) in [
            (t.to_string(), "ends on the recording's last step"),
            (off_grid.clone(), "is not a whole number of time steps"),
        ] {
            let out = dir.path().join(format!("{name}-flag.mcap"));
            let again = chaoscope_captured(&[
                "resume",
                f,
                "--t-final",
                &asked,
                "--out",
                out.to_str().unwrap(),
            ])
            .output()
            .unwrap();
            let err = String::from_utf8_lossy(&again.stderr);
            assert_eq!(again.status.code(), Some(1), "{err}");
            assert!(
                err.contains(&format!("--t-final {asked}")) && err.contains(said),
                "{err}"
            );
            assert!(!out.exists());
        }
        // Into another file: the recording stays as it was.
        let other = dir.path().join(format!("{name}-extended.mcap"));
        let twice_s = twice.to_string();
        run_ok(&[
            "resume",
            f,
            "--t-final",
            &twice_s,
            "--out",
            other.to_str().unwrap(),
        ]);
        assert_eq!(std::fs::read(&finished).unwrap(), before);
        let want = analysis_json(&long);
        assert_eq!(
            analysis_json(&other),
            want,
            "{name} extended into another file"
        );
        // In place.
        run_ok(&["resume", f, "--t-final", &twice_s]);
        assert_eq!(analysis_json(&finished), want, "{name} extended in place");
    }
}

#[test]
fn what_cannot_be_resumed_is_refused_naming_why() {
    let dir = tempfile::tempdir().unwrap();
    let refused = |args: &[&str], needle: &str| {
        let out = chaoscope_captured(args).output().unwrap();
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(1), "{args:?}: {stderr}");
        assert!(stderr.contains(needle), "{args:?}: {stderr}");
        assert!(!stderr.contains("panicked"), "{stderr}");
    };
    let missing = dir.path().join("none.mcap");
    refused(&["resume", missing.to_str().unwrap()], "no such recording");
    let junk = dir.path().join("junk.mcap");
    std::fs::write(&junk, b"not a recording").unwrap();
    refused(&["resume", junk.to_str().unwrap()], "not an MCAP file");

    // Adaptive step sizes carry the controller's state from step to step.
    let adaptive = std::fs::read_to_string(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("examples/models/rossler.toml"),
    )
    .unwrap()
    .replace("t_final = 10000.0", "t_final = 20.0");
    let cfg = write_config(dir.path(), &adaptive);
    let rec = dir.path().join("adaptive.mcap");
    let run = unique_run("adaptive");
    run_ok(&[
        "run",
        cfg.to_str().unwrap(),
        "--run",
        &run,
        "--out",
        rec.to_str().unwrap(),
    ]);
    refused(
        &["resume", rec.to_str().unwrap(), "--t-final", "40"],
        "dop853 with tolerances chooses each substep from the one before",
    );

    // An escaped orbit would escape again.
    let escaping = r#"
[model]
name = "potential"
n = 1
potential = "-q1^4"
[orbit]
q = [1.0]
p = [1.0]
[integrator]
method = "leapfrog"
h = 0.01
t_final = 50.0
[deviations]
k = 1
[[scheme]]
name = "vm"
method = "vm"
d0 = 1e-8
tau = 1.0
"#;
    let cfg = dir.path().join("escaping.toml");
    std::fs::write(&cfg, escaping).unwrap();
    let rec = dir.path().join("escaped.mcap");
    let run = unique_run("escaped");
    let _ = chaoscope_captured(&[
        "run",
        cfg.to_str().unwrap(),
        "--run",
        &run,
        "--out",
        rec.to_str().unwrap(),
    ])
    .output()
    .unwrap();
    refused(
        &["resume", rec.to_str().unwrap(), "--t-final", "100"],
        "a continuation would fail the same way",
    );

    // A run still being recorded is its recorder's.
    let config = write_config(dir.path(), &resumable_config(1e6));
    let live = dir.path().join("live.mcap");
    let run = unique_run("live");
    let mut p = spawn_group(&[
        "run",
        config.to_str().unwrap(),
        "--run",
        &run,
        "--out",
        live.to_str().unwrap(),
    ]);
    wait_for_size(&live, 1);
    refused(
        &["resume", live.to_str().unwrap()],
        "is being written by another live process",
    );
    refused(
        &[
            "resume",
            live.to_str().unwrap(),
            "--out",
            dir.path().join("elsewhere.mcap").to_str().unwrap(),
        ],
        "is being written by another live process",
    );
    signal_group(&p, libc::SIGINT);
    p.wait(LIMIT);
}

#[test]
fn sample_every_keeps_the_accumulated_indicators_exact_and_resumes() {
    let dir = tempfile::tempdir().unwrap();
    // Taus 0.75, 0.5 and 1.5: a sample every 4.5 is a multiple of each; t_final off that grid.
    let every = |t_final: f64| {
        let mut config = RunConfig::from_toml(&resumable_config(t_final)).unwrap();
        config.run.sample_every = Some(4.5);
        config.to_toml()
    };
    let run = unique_run("sample-every");
    let go = |name: &str, text: &str| {
        let cfg = dir.path().join(format!("{name}.toml"));
        std::fs::write(&cfg, text).unwrap();
        let out = dir.path().join(format!("{name}.mcap"));
        run_ok(&[
            "run",
            cfg.to_str().unwrap(),
            "--run",
            &run,
            "--out",
            out.to_str().unwrap(),
        ]);
        out
    };
    let all = go("all", &resumable_config(300.25));
    let thinned = go("thinned", &every(300.25));
    let report = |p: &Path| serde_json::from_str::<serde_json::Value>(&analysis_json(p)).unwrap();
    let (a, b) = (report(&all), report(&thinned));
    // 0, every 4.5 up to 297, and the end at 300.25.
    assert_eq!(b["run"]["samples"], 68);
    // The stretching factors of every renormalization reach the analysis: the exponents, FLI
    // and MEGNO are the every-renormalization run's to the bit; GALI and SALI are computed from
    // the last sample's vectors, the same in both.
    for (sa, sb) in a["schemes"]
        .as_array()
        .unwrap()
        .iter()
        .zip(b["schemes"].as_array().unwrap())
    {
        for key in [
            "t",
            "mle",
            "lyapunov",
            "fli",
            "megno",
            "megno_mean",
            "gali",
            "sali",
        ] {
            assert_eq!(sa[key], sb[key], "scheme {}: {key}", sa["name"]);
        }
    }
    let size = |p: &Path| std::fs::metadata(p).unwrap().len();
    assert!(
        size(&thinned) * 2 < size(&all),
        "{} vs {}",
        size(&thinned),
        size(&all)
    );

    // A thinned run extended: the recording's end off the sampling grid is not resumed from
    // (its renormalizations since 148.5 belong to the sample at 153).
    let half = go("half", &every(150.25));
    run_ok(&["resume", half.to_str().unwrap(), "--t-final", "300.25"]);
    assert_eq!(analysis_json(&half), analysis_json(&thinned));

    // A sampling interval that is not a multiple of every tau is refused, naming the key.
    let bad = dir.path().join("bad.toml");
    std::fs::write(
        &bad,
        every(300.25).replace("sample_every = 4.5", "sample_every = 2.0"),
    )
    .unwrap();
    let out = chaoscope_captured(&["config", bad.to_str().unwrap()])
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert!(
        stderr.contains("run.sample_every")
            && stderr.contains("not a multiple of scheme 'vm''s tau"),
        "{stderr}"
    );
}

// The compiler is optional at every step: a C compiler that never returns (a stalled licence
// server or network mount) holds no command. Its wait observes SIGINT and SIGTERM, a model
// dropped during its build cancels it (the compiler's group killed, never joined), and the
// compiler dies with its parent (the parent-death signal), even one killed outright.

/// The DKG chain of `examples/models/dkg-block.toml` at 200 sites (its block at sites 90..110)
/// to `t_final`.
fn dkg_200(t_final: f64) -> String {
    let text = include_str!("../examples/models/dkg-block.toml");
    for from in ["n = 1000\n", "sites = [490, 510]", "t_final = 5000.0\n"] {
        assert!(text.contains(from), "dkg-block.toml changed: {from}");
    }
    text.replace("n = 1000\n", "n = 200\n")
        .replace("sites = [490, 510]", "sites = [90, 110]")
        .replace("t_final = 5000.0\n", &format!("t_final = {t_final:?}\n"))
}

/// A stand-in C compiler that appends its process id to `pids` and then sleeps (as itself: the
/// process that hangs is the one chaoscope started).
fn hanging_compiler(dir: &Path, pids: &Path) -> std::path::PathBuf {
    use std::os::unix::fs::PermissionsExt;
    let path = dir.join("hanging-cc");
    std::fs::write(
        &path,
        format!(
            "#!/bin/sh\necho $$ >> '{}'\nexec sleep 1000\n",
            pids.display()
        ),
    )
    .unwrap();
    std::fs::set_permissions(&path, std::fs::Permissions::from_mode(0o755)).unwrap();
    path
}

fn pids_in(file: &Path) -> Vec<i32> {
    std::fs::read_to_string(file)
        .unwrap_or_default()
        .lines()
        .filter_map(|l| l.trim().parse().ok())
        .collect()
}

/// Whether process `pid` exists and is not a zombie.
fn alive(pid: i32) -> bool {
    std::fs::read_to_string(format!("/proc/{pid}/stat")).is_ok_and(|stat| {
        stat.rsplit_once(')')
            .and_then(|(_, rest)| rest.split_whitespace().next())
            .is_some_and(|state| !matches!(state, "Z" | "X"))
    })
}

/// How long a signalled command may take to end with a compiler hanging: far beyond its own
/// answer (a poll of 10 ms, then the ends of the signal matrix above), far below the compiler's
/// default deadline (300 s), which a command that waits for the compiler would reach.
const HUNG_COMPILER_BOUND: Duration = Duration::from_secs(10);

#[test]
fn a_hanging_compiler_never_holds_a_command_past_its_signal() {
    let dir = tempfile::tempdir().unwrap();
    let s = |p: &Path| p.to_str().unwrap().to_string();
    // Long enough to build the C kernels (a run: at least 10^8 state-value steps) and to be
    // running for the whole case.
    let run_config = dir.path().join("dkg-200.toml");
    std::fs::write(&run_config, dkg_200(1e6)).unwrap();
    let map_config = dir.path().join("potential-map.toml");
    std::fs::write(&map_config, fput_potential_map(101, 4, 1000.0)).unwrap();
    #[derive(Debug, Clone, Copy, PartialEq)]
    enum Command {
        Run,
        Map,
        Produce,
    }
    let mut cases: Vec<(Command, i32)> = Vec::new();
    for command in [Command::Run, Command::Map, Command::Produce] {
        for signal in [libc::SIGINT, libc::SIGTERM] {
            cases.push((command, signal));
        }
    }
    // Killed outright: the compiler still dies with it.
    cases.push((Command::Map, libc::SIGKILL));
    cases.push((Command::Run, libc::SIGKILL));
    for (n, (command, signal)) in cases.into_iter().enumerate() {
        let case = format!("{command:?} {signal}");
        let work = dir.path().join(format!("case-{n}"));
        std::fs::create_dir(&work).unwrap();
        let pids = work.join("pids");
        let cc = hanging_compiler(&work, &pids);
        let cache = work.join("kernels");
        let out = work.join("out.mcap");
        let run = unique_run("hung-cc");
        let args: Vec<String> = match command {
            Command::Run => vec![
                "run".into(),
                s(&run_config),
                "--run".into(),
                run.clone(),
                "--out".into(),
                s(&out),
            ],
            Command::Map => vec![
                "map".into(),
                s(&map_config),
                "--out".into(),
                s(&out),
                "--threads".into(),
                "2".into(),
                "--no-progress".into(),
                "--name".into(),
                run.clone(),
            ],
            Command::Produce => vec![
                "produce".into(),
                s(&run_config),
                "--run".into(),
                run.clone(),
                "--no-progress".into(),
            ],
        };
        let spawn = |args: &[String]| {
            use std::os::unix::process::CommandExt;
            let mut c = std::process::Command::new(CHAOSCOPE);
            c.args(args)
                .env("CHAOSCOPE_CC", &cc)
                .env("CHAOSCOPE_KERNEL_CACHE", &cache)
                .env_remove("CHAOSCOPE_CC_TIMEOUT")
                .env_remove("CHAOSCOPE_C_KERNELS_AFTER_CALLS")
                .stdin(std::process::Stdio::null())
                .stdout(std::process::Stdio::null())
                .stderr(std::process::Stdio::null())
                .process_group(0);
            Proc::spawn(c)
        };
        let mut recorder = (command == Command::Produce).then(|| {
            spawn(&[
                "record".into(),
                "--run".into(),
                run.clone(),
                "--out".into(),
                s(&out),
            ])
        });
        let mut me = spawn(&args);
        let start = Instant::now();
        while pids_in(&pids).is_empty() {
            assert!(
                me.0.try_wait().unwrap().is_none(),
                "{case}: ended before its compiler ran"
            );
            assert!(
                start.elapsed() < MOMENT_LIMIT,
                "{case}: the compiler never ran"
            );
            std::thread::sleep(Duration::from_millis(10));
        }
        let compiler = pids_in(&pids)[0];
        me.signal(signal);
        let signalled = Instant::now();
        let status = me.wait(HUNG_COMPILER_BOUND + Duration::from_secs(20));
        let took = signalled.elapsed();
        assert!(
            took < HUNG_COMPILER_BOUND,
            "{case}: ended {took:?} after its signal"
        );
        use std::os::unix::process::ExitStatusExt;
        if signal == libc::SIGKILL {
            assert_eq!(status.signal(), Some(libc::SIGKILL), "{case}");
        } else {
            assert_eq!(
                status.code(),
                Some(i32::from(chaoscope_os::signals::exit_status(signal))),
                "{case}: {status}"
            );
        }
        // The compiler is gone, with the command (at once: it was killed, or died with its
        // parent), and so is everything the command started (its group: `run`'s producer and
        // recorder). A recorder partner ends by itself once its producer is gone.
        let start = Instant::now();
        while alive(compiler) {
            assert!(
                start.elapsed() < HUNG_COMPILER_BOUND,
                "{case}: the compiler {compiler} outlived its command"
            );
            std::thread::sleep(Duration::from_millis(10));
        }
        if signal == libc::SIGKILL {
            // SAFETY: kill(2) on the group our own child led (what is left of it).
            unsafe { libc::kill(-me.pid(), libc::SIGKILL) };
        }
        wait_group_gone(&mut me);
        if let Some(r) = &mut recorder {
            if size(&out) == 0 && size(&chaoscope_os::output::partial_path(&out)) == 0 {
                // It never met its producer: the user ends it.
                r.signal(libc::SIGTERM);
            }
            r.wait(LIMIT);
        }
        assert!(
            pids_in(&pids).iter().all(|&p| !alive(p)),
            "{case}: a compiler is left: {:?}",
            pids_in(&pids)
        );
    }
}

/// The bits of `chaoscope run CONFIG` as run `name` (its reference states, separations and
/// indicators, encoded), with its kernel cache in `dir`, the compiler's deadline and the C
/// switch-over at their defaults unless `env` sets them, waited for at most `bound`.
#[allow(clippy::type_complexity)]
fn recorded_bits(
    dir: &Path,
    config: &Path,
    name: &str,
    env: &[(&str, &std::ffi::OsStr)],
    bound: Duration,
) -> (Vec<Vec<u8>>, Vec<Vec<u8>>, Vec<(String, Vec<u8>)>) {
    use prost::Message;
    let out = dir.join(format!("{name}.mcap"));
    let mut c = chaoscope_captured(&[
        "run",
        config.to_str().unwrap(),
        "--run",
        &unique_run(name),
        "--out",
        out.to_str().unwrap(),
    ]);
    c.env("CHAOSCOPE_KERNEL_CACHE", dir.join("kernels"))
        .env_remove("CHAOSCOPE_C_KERNELS_AFTER_CALLS")
        .env_remove("CHAOSCOPE_CC_TIMEOUT")
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::null());
    for (k, v) in env {
        c.env(k, v);
    }
    let mut p = Proc::spawn(c);
    let status = p.wait(bound);
    assert!(status.success(), "{name}: {status}");
    let r = read_recording(&out);
    let references = r.references.iter().map(|x| x.encode_to_vec()).collect();
    let separations = r.separations.iter().map(|x| x.encode_to_vec()).collect();
    let indicators = r
        .indicators
        .iter()
        .map(|(t, x)| (t.clone(), x.encode_to_vec()))
        .collect();
    (references, separations, indicators)
}

/// A command whose compiler hangs finishes, within its deadline (`CHAOSCOPE_CC_TIMEOUT`) and
/// its own time, with the file of a run without C kernels, bit for bit: a 200-site DKG run long
/// enough to build them (the build runs beside it, the run steps the one-orbit way meanwhile).
#[test]
fn a_run_whose_compiler_hangs_finishes_with_the_bits_of_a_run_without_c_kernels() {
    let dir = tempfile::tempdir().unwrap();
    let config = dir.path().join("dkg-200.toml");
    // 3 * 10^5 steps of 400 state values: over the 10^8 that start a build.
    std::fs::write(&config, dkg_200(15000.0)).unwrap();
    let pids = dir.path().join("pids");
    let cc = hanging_compiler(dir.path(), &pids);
    let record = |name: &str, env: &[(&str, &std::ffi::OsStr)]| {
        // A bound only a hang reaches (the run takes seconds).
        recorded_bits(dir.path(), &config, name, env, Duration::from_secs(300))
    };
    let without = record("without", &[("CHAOSCOPE_CC", "none".as_ref())]);
    let hung = record(
        "hung",
        &[
            ("CHAOSCOPE_CC", cc.as_os_str()),
            ("CHAOSCOPE_CC_TIMEOUT", "2".as_ref()),
        ],
    );
    assert!(!without.0.is_empty());
    assert_eq!(pids_in(&pids).len(), 1, "the compiler ran once");
    assert!(
        without == hung,
        "a run whose compiler hung differs from one without C kernels"
    );
    assert!(pids_in(&pids).iter().all(|&p| !alive(p)));
}

/// The Lorenz example by Taylor's method to `t_final`, its VM scheme only (QR every time unit),
/// written to `dir/NAME.toml`.
fn lorenz_taylor(dir: &Path, name: &str, t_final: f64) -> std::path::PathBuf {
    let mut lorenz = RunConfig::from_toml(include_str!("../examples/models/lorenz.toml")).unwrap();
    lorenz.run.name = Some(name.into());
    lorenz.integrator.method = "taylor".into();
    lorenz.integrator.h = Some(1.0);
    lorenz.integrator.t_final = t_final;
    lorenz.schemes.retain(|s| s.method == "vm");
    let config = dir.join(format!("{name}.toml"));
    std::fs::write(&config, lorenz.to_toml()).unwrap();
    config
}

/// Taylor's method builds its compiled pass on a thread of its own: with a compiler that hangs
/// (and no deadline short of the default 300 s) the run ends in its own time with the bits of a
/// run without a C compiler (the interpreted pass gives them), and no compiler outlives it (the
/// build is cancelled, its process group stopped, when the system is dropped).
#[test]
fn a_taylor_run_whose_compiler_hangs_ends_in_its_own_time_and_leaves_no_compiler() {
    let dir = tempfile::tempdir().unwrap();
    let config = lorenz_taylor(dir.path(), "lorenz-taylor", 300.0);
    let pids = dir.path().join("pids");
    let cc = hanging_compiler(dir.path(), &pids);
    let record = |name: &str, cc: &std::ffi::OsStr| {
        // The run takes a second; waiting on the compiler would take 300 s.
        let (references, separations, _) = recorded_bits(
            dir.path(),
            &config,
            name,
            &[("CHAOSCOPE_CC", cc)],
            Duration::from_secs(60),
        );
        (references, separations)
    };
    let without = record("taylor-without", "none".as_ref());
    let hung = record("taylor-hung", cc.as_os_str());
    assert!(!without.0.is_empty());
    assert!(!pids_in(&pids).is_empty(), "the compiler was started");
    assert!(
        without == hung,
        "a Taylor run whose compiler hung differs from one without C"
    );
    // The run waited for the build (2 s, `FINISH_GRACE`), then cancelled it within the drop's
    // grace (0.5 s) and the compiler driver's poll.
    std::thread::sleep(Duration::from_secs(1));
    assert!(
        pids_in(&pids).iter().all(|&p| !alive(p)),
        "a compiler outlived its run: {:?}",
        pids_in(&pids)
    );
}

/// A Taylor run shorter than the build of its compiled pass waits for the build (up to
/// `FINISH_GRACE`) instead of cancelling it, so the pass lands in the kernel cache and the next
/// run of the system loads it: cancelled, runs shorter than their build would interpret forever.
#[test]
fn a_taylor_run_shorter_than_its_build_leaves_the_pass_in_the_kernel_cache() {
    let dir = tempfile::tempdir().unwrap();
    let cache = dir.path().join("kernels");
    std::fs::create_dir(&cache).unwrap();
    // A few milliseconds of stepping, against a build of a few tenths of a second.
    let config = lorenz_taylor(dir.path(), "lorenz-taylor-short", 5.0);
    let libraries = || {
        std::fs::read_dir(&cache)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .filter(|n| n.ends_with(".so"))
            .collect::<Vec<_>>()
    };
    let run = |name: &str| {
        let out = dir.path().join(name);
        let status = chaoscope_captured(&[
            "run",
            config.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
        ])
        .env("CHAOSCOPE_KERNEL_CACHE", &cache)
        .env_remove("CHAOSCOPE_CC")
        .stdout(std::process::Stdio::null())
        .status()
        .unwrap();
        assert!(status.success());
        analysis_json(&out)
    };
    let first = run("first.mcap");
    // A compiler slowed past the grace by a loaded machine is given two more runs.
    for again in 0..2 {
        if !libraries().is_empty() {
            break;
        }
        run(&format!("again-{again}.mcap"));
    }
    let built = libraries();
    assert!(
        !built.is_empty(),
        "no run left the Taylor pass in the kernel cache"
    );
    // The next run loads it: nothing is built again, and the bits are the interpreted run's.
    assert_eq!(run("loaded.mcap"), first);
    assert_eq!(libraries(), built);
}

/// Whether the main thread of `pid` is blocked in read(2) on its standard input (x86-64 and
/// aarch64 number `read` 0 and 63; the first argument is the descriptor).
fn reading_stdin(pid: i32) -> bool {
    let syscall = std::fs::read_to_string(format!("/proc/{pid}/syscall")).unwrap_or_default();
    let mut fields = syscall.split_whitespace();
    let read = if cfg!(target_arch = "aarch64") {
        "63"
    } else {
        "0"
    };
    fields.next() == Some(read) && fields.next() == Some("0x0")
}

fn mkfifo(path: &Path) {
    use std::os::unix::ffi::OsStrExt;
    let c = std::ffi::CString::new(path.as_os_str().as_bytes()).unwrap();
    // SAFETY: a NUL-terminated path.
    assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o600) }, 0, "mkfifo");
}

/// The signal matrix on FIFO inputs. Standard input a pipe no writer ever closes (`-`, the
/// documented way to hand a config over standard input): every command that reads its config
/// there (`config`, `run`, `produce`, `map`, `section`), blocked in that read, ends on SIGINT
/// and on SIGTERM within the bound with 130 or 143, and leaves no process behind (before:
/// `produce -` latched the signal and went on waiting in the read, restarted after each one).
#[test]
fn sigint_and_sigterm_end_commands_waiting_on_a_standard_input_fifo() {
    use std::os::unix::process::CommandExt;
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out.mcap");
    let o = out.to_str().unwrap();
    let cases: [&[&str]; 5] = [
        &["config", "-"],
        &["run", "-", "--out", o],
        &["produce", "-"],
        &["map", "-", "--out", o],
        &["section", "-", "--surface", "x1", "--csv", o],
    ];
    for args in cases {
        for signal in [libc::SIGINT, libc::SIGTERM] {
            let mut c = chaoscope_captured(args);
            c.stdin(std::process::Stdio::piped())
                .stdout(std::process::Stdio::null())
                .stderr(std::process::Stdio::null())
                .process_group(0);
            let mut p = Proc::spawn(c);
            // The pipe's write end, held open: the read never ends by itself.
            let _writer = p.0.stdin.take().unwrap();
            let start = Instant::now();
            while !reading_stdin(p.pid()) {
                assert!(start.elapsed() < MOMENT_LIMIT, "{args:?} never read stdin");
                std::thread::sleep(Duration::from_millis(5));
            }
            signal_group(&p, signal);
            let sent = Instant::now();
            let status = p.wait(SIGNAL_BOUND + LOAD_MARGIN + LIMIT);
            let took = sent.elapsed();
            assert!(
                took <= SIGNAL_BOUND + LOAD_MARGIN,
                "{args:?} took {took:?} to end on signal {signal}"
            );
            assert_eq!(
                status.code(),
                Some(chaoscope_os::signals::exit_status(signal) as i32),
                "{args:?} on signal {signal}"
            );
            wait_group_gone(&mut p);
            assert!(!out.exists(), "{args:?} left {}", out.display());
        }
    }
}

/// Whether the main thread of `pid` is blocked in openat(2) (x86-64 and aarch64 number it 257
/// and 56): where a command that opens a FIFO without a writer waits.
fn opening(pid: i32) -> bool {
    let syscall = std::fs::read_to_string(format!("/proc/{pid}/syscall")).unwrap_or_default();
    let openat = if cfg!(target_arch = "aarch64") {
        "56"
    } else {
        "257"
    };
    syscall.split_whitespace().next() == Some(openat)
}

/// The signal matrix on FIFO inputs named in files: a recording whose embedded config names its
/// table at a FIFO (anyone can send such a file) through `analyze`, `replay` and `resume`, the
/// same with the recording itself a FIFO, and `produce` of a config with a FIFO table. Each
/// either ends by itself, refused in one line (status 1: the FIFO is never waited on) or done
/// (`analyze`, 0: the table only adds to its report), or, once seen blocked in an open, is
/// signalled (SIGINT, SIGTERM) and ends within the bound with 130 or 143; no process and no
/// output, nor its
/// `.partial` of it, left behind (before: `replay` and `resume` waited on the FIFO deaf to both
/// signals, and `resume` left `OUT.partial` when killed).
#[test]
fn sigint_and_sigterm_end_commands_given_a_fifo_in_place_of_a_file() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let s = |p: &Path| p.to_str().unwrap().to_string();
    let models = Path::new(env!("CARGO_MANIFEST_DIR")).join("examples/models");
    let csv = d.join("fput-bond.csv");
    std::fs::copy(models.join("fput-bond.csv"), &csv).unwrap();
    let text = std::fs::read_to_string(models.join("tabulated-bond.toml")).unwrap();
    let mut config = RunConfig::from_toml(&text).unwrap();
    config.integrator.t_final = 2.0;
    config.run.name = Some(unique_run("fifo-signal"));
    let cfg = d.join("tabulated.toml");
    std::fs::write(&cfg, config.to_toml()).unwrap();
    let rec = d.join("tabulated.mcap");
    run_ok(&["run", &s(&cfg), "--out", &s(&rec)]);
    std::fs::remove_file(&csv).unwrap();
    mkfifo(&csv);
    let fifo_rec = d.join("fifo.mcap");
    mkfifo(&fifo_rec);
    let out = d.join("out.mcap");
    let (r, f, c, o) = (s(&rec), s(&fifo_rec), s(&cfg), s(&out));
    let cases: [Vec<&str>; 7] = [
        vec!["analyze", &r, "--json"],
        vec!["replay", &r, "--tau", "0.5", "--out", &o],
        vec!["resume", &r, "--t-final", "4", "--out", &o],
        vec!["analyze", &f],
        vec!["replay", &f, "--tau", "0.5", "--out", &o],
        vec!["resume", &f, "--t-final", "4", "--out", &o],
        vec!["produce", &c],
    ];
    for args in &cases {
        for signal in [libc::SIGINT, libc::SIGTERM] {
            let mut p = spawn_group(args);
            let start = Instant::now();
            let ended = loop {
                if let Some(status) = p.0.try_wait().unwrap() {
                    break Some(status);
                }
                // Blocked in an open once it runs chaoscope's program (the loader's opens
                // are over by then): the wait the FIFO would make.
                if executing_chaoscope(p.pid()) && opening(p.pid()) {
                    break None;
                }
                assert!(
                    start.elapsed() < MOMENT_LIMIT,
                    "{args:?} neither ended nor opened"
                );
                std::thread::sleep(Duration::from_millis(1));
            };
            match ended {
                Some(status) => {
                    let done = status.code() == Some(0) && args[0] == "analyze";
                    assert!(
                        status.code() == Some(1) || done,
                        "{args:?} ended with {status:?}"
                    );
                }
                None => {
                    signal_group(&p, signal);
                    let sent = Instant::now();
                    let status = p.wait(SIGNAL_BOUND + LOAD_MARGIN + LIMIT);
                    let took = sent.elapsed();
                    assert!(
                        took <= SIGNAL_BOUND + LOAD_MARGIN,
                        "{args:?} took {took:?} to end on signal {signal}"
                    );
                    // A signal that came while a regular file was being opened may also find
                    // the command refusing the FIFO, or done.
                    let code = status.code();
                    assert!(
                        code == Some(chaoscope_os::signals::exit_status(signal) as i32)
                            || code == Some(1)
                            || (code == Some(0) && args[0] == "analyze"),
                        "{args:?} on signal {signal} ended with {status:?}"
                    );
                }
            }
            wait_group_gone(&mut p);
            let partial = d.join("out.mcap.partial");
            assert!(
                !out.exists() && !partial.exists(),
                "{args:?} left {} or its .partial",
                out.display()
            );
        }
    }
}
