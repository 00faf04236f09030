//! Full disk and failing writes: the writer runs under `RLIMIT_FSIZE` (set in the child before
//! exec), so its output file cannot grow past a few hundred KiB, as on a full disk or a quota.
//! The recorder and `map` stop with one clear message naming the file and the cause, exit
//! non-zero, and keep every complete chunk; the producer is not left waiting for the dead
//! recorder; `recover` with an output it cannot write says so and leaves no partial file.
//!
//! `chaoscope run` starts `record` and `produce` as separate processes; the limit is put on the
//! recorder alone, since it also bounds the shared-memory files of the bus.

use crate::common;

use std::os::unix::process::CommandExt;
use std::path::Path;
use std::process::{Command, Output, Stdio};
use std::time::Duration;

use crate::common::{CHAOSCOPE, Proc, assert_bit_identical, compute, read_recording, unique_run};
use chaoscope_schemas::config::{DeviationsConfig, SchemeConfig, paper};

/// `command` with its file size limited to `bytes` (and SIGXFSZ at its default, as a user's
/// shell leaves it: chaoscope itself must ignore it to report the failed write).
fn limited(mut command: Command, bytes: u64) -> Command {
    // SAFETY: only async-signal-safe calls (setrlimit, signal) between fork and exec.
    unsafe {
        command.pre_exec(move || {
            let limit = libc::rlimit {
                rlim_cur: bytes,
                rlim_max: bytes,
            };
            if libc::setrlimit(libc::RLIMIT_FSIZE, &limit) != 0 {
                return Err(std::io::Error::last_os_error());
            }
            libc::signal(libc::SIGXFSZ, libc::SIG_DFL);
            Ok(())
        });
    }
    command
}

fn stderr_of(p: &mut Proc) -> String {
    let mut s = String::new();
    if let Some(mut e) = p.0.stderr.take() {
        std::io::Read::read_to_string(&mut e, &mut s).unwrap();
    }
    s
}

fn output(mut command: Command) -> Output {
    command.stdin(Stdio::null()).output().unwrap()
}

/// A run that writes about 100 MB (compressed, some 3 MB: ten times the recorder's 300 kB
/// limit, so the producer is still publishing when the recorder dies, however fast the
/// machine): the paper's chaotic HH orbit, 50 sets sampled every step. (At 10 MB a Zen 5
/// published the whole run before the recorder, compressing, reached its limit.)
fn big_run() -> String {
    paper::henon_heiles(
        paper::HH_CHAOTIC_Q2,
        200.0,
        DeviationsConfig::random(4, 50, 5),
        vec![SchemeConfig::new("mpm", "mpm", 1e-8, 0.01)],
    )
    .to_toml()
}

#[test]
fn a_recorder_hitting_a_full_disk_stops_clearly_and_keeps_its_complete_chunks() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    let config = dir.join("run.toml");
    let text = big_run();
    std::fs::write(&config, &text).unwrap();
    let out = dir.join("out.mcap");
    let run = unique_run("fulldisk");

    let mut record = Command::new(CHAOSCOPE);
    record
        .args(["record", "--run", &run, "--chunk-size", "32768", "--out"])
        .arg(&out)
        .stdout(Stdio::null())
        .stderr(Stdio::piped());
    let mut recorder = Proc::spawn(limited(record, 300_000));
    let mut produce = Command::new(CHAOSCOPE);
    produce
        .args([
            "produce",
            config.to_str().unwrap(),
            "--run",
            &run,
            "--no-progress",
        ])
        .stdout(Stdio::null())
        .stderr(Stdio::piped());
    let mut producer = Proc::spawn(produce);

    let recorder_status = recorder.wait(Duration::from_secs(60));
    let recorder_err = stderr_of(&mut recorder);
    // The producer notices the dead recorder and ends: it is not blocked forever.
    let producer_status = producer.wait(Duration::from_secs(60));
    let producer_err = stderr_of(&mut producer);
    eprintln!(
        "recorder {recorder_status}: {recorder_err}producer {producer_status}: {producer_err}"
    );
    assert!(!recorder_status.success(), "{recorder_err}");
    assert_eq!(recorder_status.code(), Some(1), "{recorder_err}");
    // One line, naming the file, the cause and where what was written is kept.
    let partial = chaoscope_os::output::partial_path(&out);
    assert_eq!(recorder_err.lines().count(), 1, "{recorder_err}");
    let line = recorder_err.lines().last().unwrap_or("");
    assert!(
        line.contains(out.to_str().unwrap())
            && line.contains("File too large")
            && line.contains(partial.to_str().unwrap()),
        "the error names neither the file nor the cause: {recorder_err}"
    );
    assert!(!recorder_err.contains("panicked"), "{recorder_err}");
    // The output's name only ever holds a finished file.
    assert!(!out.exists(), "a failed recording took the output's name");
    let size = std::fs::metadata(&partial).unwrap().len();
    assert!(size <= 300_000, "{size} bytes");
    // The producer is not left computing for nobody: it ends with one line saying why.
    assert_eq!(producer_status.code(), Some(3), "{producer_err}");
    assert_eq!(producer_err.lines().count(), 1, "{producer_err}");
    assert!(
        producer_err.contains("every recorder left before the end of the run"),
        "{producer_err}"
    );

    // Every complete chunk is kept: recover salvages them, and they are exactly the start of
    // the run.
    let fixed = dir.join("fixed.mcap");
    let r = output({
        let mut c = Command::new(CHAOSCOPE);
        c.args([
            "recover",
            partial.to_str().unwrap(),
            "--out",
            fixed.to_str().unwrap(),
        ]);
        c
    });
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    let rec = read_recording(&fixed);
    let expected = compute(&text, Some(rec.references.len() + 1));
    assert!(
        rec.references.len() >= 5,
        "{} samples kept",
        rec.references.len()
    );
    assert_bit_identical(&rec, &expected);
    eprintln!(
        "{size} bytes written, {} complete samples salvaged",
        rec.references.len()
    );
}

/// A 40 x 30 Henon-Heiles map, t = 20, a chunk closed after every point.
const MAP: &str = r#"
[model]
name = "henon-heiles"
[orbit]
q = [0.0, 0.0]
p = [0.0, 0.0]
energy = 0.125
solve_for = "p1"
[integrator]
method = "aba864"
h = 0.01
t_final = 20.0
[deviations]
k = 2
sets = 4
seed = 1
[[scheme]]
name = "mpm"
method = "mpm"
d0 = 1e-8
tau = 1.0
[map]
x = { coord = "q2", min = -0.4, max = 0.6, n = 40 }
y = { coord = "p2", min = -0.4, max = 0.4, n = 30 }
indicator = "gali"
"#;

fn map_cmd(dir: &Path, out: &str) -> Command {
    let mut c = Command::new(CHAOSCOPE);
    c.current_dir(dir)
        .args(["map", "map.toml", "--out", out, "--json", "--no-progress"])
        .args(["--threads", "1", "--flush-interval", "0"]);
    c
}

#[test]
fn a_map_hitting_a_full_disk_stops_clearly_and_resumes_to_the_same_map() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    std::fs::write(dir.join("map.toml"), MAP).unwrap();

    let full = output(limited(map_cmd(dir, "map.mcap"), 40_000));
    let err = String::from_utf8_lossy(&full.stderr);
    eprintln!("{err}");
    assert_eq!(full.status.code(), Some(1), "{err}");
    assert!(!err.contains("panicked"), "{err}");
    let line = err.lines().last().unwrap_or("");
    assert!(
        line.contains("map.mcap") && line.contains("File too large"),
        "the error names neither the file nor the cause: {err}"
    );

    // Resumed without the limit, it keeps what was written and completes the same map as an
    // uninterrupted one.
    let resumed = output(map_cmd(dir, "map.mcap"));
    assert!(
        resumed.status.success(),
        "{}",
        String::from_utf8_lossy(&resumed.stderr)
    );
    let summary: serde_json::Value = serde_json::from_slice(&resumed.stdout).unwrap();
    assert!(summary["resumed"].as_u64().unwrap() > 10, "{summary}");
    assert_eq!(summary["complete"], true);
    let fresh = output(map_cmd(dir, "fresh.mcap"));
    assert!(fresh.status.success());
    let points = |name: &str| {
        chaoscope_files::map_file::read_map_file(&dir.join(name))
            .unwrap()
            .points
            .into_iter()
            .map(|p| {
                let per_set: Vec<u64> = p.per_set.iter().map(|v| v.to_bits()).collect();
                (p.index, (p.value.to_bits(), per_set))
            })
            .collect::<std::collections::BTreeMap<_, _>>()
    };
    assert_eq!(points("map.mcap"), points("fresh.mcap"));
    eprintln!("resumed {} points", summary["resumed"]);
}

#[test]
fn recover_to_an_output_it_cannot_write_fails_clearly_and_leaves_nothing() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    let input = dir.join("in.mcap");
    std::fs::write(
        &input,
        chaoscope_files::testing::small_run(chaoscope_files::file::Compression::Zstd),
    )
    .unwrap();
    let recover = |out: &Path| {
        let mut c = Command::new(CHAOSCOPE);
        c.args([
            "recover",
            input.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
        ]);
        c
    };
    // A directory that does not exist.
    let missing = dir.join("no-such-dir/out.mcap");
    let r = output(recover(&missing));
    let err = String::from_utf8_lossy(&r.stderr);
    assert_eq!(r.status.code(), Some(1), "{err}");
    assert!(
        err.contains(missing.to_str().unwrap()) && err.contains("No such file"),
        "{err}"
    );
    // A disk that fills up after 1000 bytes.
    let out = dir.join("out.mcap");
    let r = output(limited(recover(&out), 1000));
    let err = String::from_utf8_lossy(&r.stderr);
    eprintln!("{err}");
    assert_eq!(r.status.code(), Some(1), "{err}");
    assert_eq!(err.lines().count(), 1, "{err}");
    assert!(
        err.contains(out.to_str().unwrap()) && err.contains("File too large"),
        "{err}"
    );
    assert!(!out.exists(), "a partial output was left behind");
    assert!(
        !chaoscope_os::output::partial_path(&out).exists(),
        "its in-progress file was left behind"
    );
}

/// `merge` whose output cannot grow past 1000 bytes (a full disk, a quota): one line naming
/// the output and the cause, exit 1, nothing left behind, and the PNG (written after the map)
/// not started (before: a bare "File too large (os error 27)", naming no file).
#[test]
fn merge_to_an_output_it_cannot_write_names_the_file() {
    use chaoscope_files::map_file::MapFile;
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    let shard = dir.join("shard.mcap");
    let (header, points) = chaoscope_files::testing::values::valid_map();
    let mut file = MapFile::create(
        std::io::Cursor::new(Vec::new()),
        &header,
        &chaoscope_files::file::FileOptions::default(),
    )
    .unwrap();
    for p in &points {
        file.write_point(p).unwrap();
    }
    let bytes = file.finish().unwrap().into_inner();
    std::fs::write(&shard, &bytes).unwrap();
    let (out, png) = (dir.join("merged.mcap"), dir.join("merged.png"));
    let merge = || {
        let mut c = Command::new(CHAOSCOPE);
        c.args([
            "merge",
            shard.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
        ]);
        c.args(["--png", png.to_str().unwrap()]);
        c
    };
    let r = output(limited(merge(), 1000));
    let err = String::from_utf8_lossy(&r.stderr);
    eprintln!("{err}");
    assert_eq!(r.status.code(), Some(1), "{err}");
    assert_eq!(err.lines().count(), 1, "{err}");
    assert!(
        err.contains(out.to_str().unwrap()) && err.contains("File too large"),
        "{err}"
    );
    assert!(!out.exists() && !png.exists(), "an output was left behind");
    assert!(
        !chaoscope_os::output::partial_path(&out).exists(),
        "its in-progress file was left behind"
    );
}

/// Runs `command` (its stdout as the caller set it) to its end, or kills it after `limit`
/// (`None`).
fn output_within(mut command: Command, limit: Duration) -> Option<Output> {
    let mut child = command
        .stdin(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let start = std::time::Instant::now();
    while child.try_wait().unwrap().is_none() {
        if start.elapsed() > limit {
            let _ = child.kill();
            let _ = child.wait();
            return None;
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    Some(child.wait_with_output().unwrap())
}

/// Issue #24, failing partners: when `chaoscope run`'s recorder cannot write its output, both
/// processes end at once and the user reads one line naming the file and the cause (before:
/// two error lines, then the producer waited for its dead recorder forever). Two ways to fail:
/// a directory that cannot be made (under /proc, which root cannot write either), and an
/// in-progress name taken by something that is not chaoscope's (`run`'s own check of the
/// output passes, the recorder refuses).
#[test]
fn a_run_whose_recorder_cannot_write_ends_at_once_with_one_line() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    let config = common::write_config(dir, &common::hh_config(1e4, 0.01).to_toml());
    let taken = dir.join("taken.mcap");
    std::fs::create_dir(chaoscope_os::output::partial_path(&taken)).unwrap();
    for (out, cause) in [
        (
            Path::new("/proc/chaoscope-no-such-dir/run.mcap").to_path_buf(),
            "No such file or directory",
        ),
        (taken.clone(), "not a regular file"),
    ] {
        let mut run = Command::new(CHAOSCOPE);
        run.args([
            "run",
            config.to_str().unwrap(),
            "--run",
            &unique_run("unwritable"),
            "--out",
            out.to_str().unwrap(),
        ]);
        run.stdout(Stdio::null());
        let o = output_within(run, Duration::from_secs(30))
            .unwrap_or_else(|| panic!("run --out {out:?} did not end within 30 s"));
        let stderr = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(1), "{out:?}: {stderr}");
        assert_eq!(stderr.trim_end().lines().count(), 1, "{out:?}: {stderr}");
        let parent = out.parent().unwrap().to_str().unwrap();
        assert!(
            stderr.contains(parent) && stderr.contains(cause),
            "{out:?}: {stderr}"
        );
        assert!(!out.exists());
    }
    assert!(chaoscope_os::output::partial_path(&taken).is_dir());
}

/// Issue #24, failing writes to standard output (and error): a reader that goes away (`| head`) ends every
/// printing command quietly with 141 (what a shell shows for a filter killed by SIGPIPE), and a
/// full disk (`> /dev/full`) is one error line and a non-zero exit (before: a panic with exit
/// status 101, and `analyze --json > /dev/full` exited 0 having written nothing). Live
/// followers (`monitor --json-lines`, `map-watch --json-lines`) end too instead of following
/// on into a closed pipe.
#[test]
fn a_closed_pipe_ends_quietly_and_a_full_standard_output_is_one_error() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    let config = common::write_config(dir, &common::hh_config(2.0, 0.01).to_toml());
    let recording = dir.join("run.mcap");
    common::run_ok(&[
        "run",
        config.to_str().unwrap(),
        "--run",
        &unique_run("pipes"),
        "--out",
        recording.to_str().unwrap(),
    ]);
    let map_config = dir.join("map.toml");
    std::fs::write(&map_config, include_str!("data/hh-map-small.toml")).unwrap();
    let shard = dir.join("shard.mcap");
    common::run_ok(&[
        "map",
        map_config.to_str().unwrap(),
        "--out",
        shard.to_str().unwrap(),
        "--no-progress",
        "--name",
        &unique_run("pipes-map"),
    ]);
    // Live sources for the followers: a run producing for nobody, a map of long orbits.
    let long = dir.join("long.toml");
    std::fs::write(&long, common::hh_config(1e6, 0.01).to_toml()).unwrap();
    let live_run = unique_run("pipes-live");
    let mut producer = Proc::spawn(common::chaoscope(&[
        "produce",
        long.to_str().unwrap(),
        "--run",
        &live_run,
        "--recorders",
        "0",
        "--no-progress",
    ]));
    let s = |p: &Path| p.to_str().unwrap().to_string();
    let mut n = 0;
    let mut commands: Vec<Vec<String>> = vec![
        // The followers first, while their sources live.
        vec!["monitor".into(), live_run.clone(), "--json-lines".into()],
        // The watcher of a map started after it (below), so that it sees the map from its
        // header on.
        vec!["map-watch".into(), String::new(), "--json-lines".into()],
        vec!["analyze".into(), s(&recording)],
        vec!["analyze".into(), s(&recording), "--json".into()],
        vec!["merge".into(), s(&shard), "--json".into(), "--force".into()],
        vec![
            "map".into(),
            s(&map_config),
            "--json".into(),
            "--no-progress".into(),
        ],
        vec!["recover".into(), s(&recording), "--force".into()],
        vec![
            "replay".into(),
            s(&recording),
            "--tau".into(),
            "0.02".into(),
            "--force".into(),
        ],
        vec![
            "replay".into(),
            s(&recording),
            "--tau".into(),
            "0.02".into(),
            "--json".into(),
            "--force".into(),
        ],
    ];
    for args in &mut commands {
        // Each writes a file of its own.
        if ["merge", "map", "recover", "replay"].contains(&args[0].as_str()) {
            args.push("--out".into());
            args.push(s(&dir.join(format!("out-{}.mcap", args[0]))));
        }
        if args[0] == "map" {
            args.push("--name".into());
            args.push(unique_run("pipes-m"));
        }
    }
    for args in &commands {
        for full in [false, true] {
            n += 1;
            let mut c = Command::new(CHAOSCOPE);
            c.stdin(Stdio::null()).stderr(Stdio::piped());
            let watched = unique_run("pipes-watched");
            if args[0] == "map-watch" {
                c.args(["map-watch", &watched, "--json-lines"]);
            } else {
                c.args(args);
            }
            if full {
                c.stdout(std::fs::File::create("/dev/full").unwrap());
            } else {
                // A reader that has gone away: the pipe's read end is closed before anything
                // is written.
                let (read, write) = std::io::pipe().unwrap();
                drop(read);
                c.stdout(write);
            }
            let watcher = (args[0] == "map-watch").then(|| {
                std::thread::spawn({
                    let (config, out, watched) =
                        (map_config.clone(), dir.join("w.mcap"), watched.clone());
                    move || {
                        common::wait_for_node(&chaoscope_schemas::names::map_watcher_node_name(
                            &watched,
                        ));
                        common::run_ok(&[
                            "map",
                            config.to_str().unwrap(),
                            "--out",
                            out.to_str().unwrap(),
                            "--restart",
                            "--no-progress",
                            "--name",
                            &watched,
                        ]);
                    }
                })
            });
            let o = output_within(c, Duration::from_secs(60))
                .unwrap_or_else(|| panic!("{args:?} (full {full}) did not end within 60 s"));
            if let Some(w) = watcher {
                w.join().unwrap();
            }
            let stderr = String::from_utf8_lossy(&o.stderr);
            assert!(
                o.status.code() != Some(101) && !stderr.contains("panicked"),
                "{args:?}: {stderr}"
            );
            if full {
                assert_eq!(o.status.code(), Some(1), "{args:?} > /dev/full: {stderr}");
                let last = stderr.trim_end().lines().last().unwrap_or("");
                assert_eq!(
                    last,
                    "chaoscope: error: writing to standard output: No space left on device \
                     (os error 28)",
                    "{args:?}: {stderr}"
                );
                assert_eq!(
                    stderr.matches("chaoscope: error").count(),
                    1,
                    "{args:?}: more than one error: {stderr}"
                );
            } else {
                assert_eq!(o.status.code(), Some(141), "{args:?} | closed: {stderr}");
                assert!(!stderr.contains("error"), "{args:?} | closed: {stderr}");
            }
        }
    }
    producer.signal(libc::SIGINT);
    assert_eq!(producer.wait(Duration::from_secs(60)).code(), Some(130));
    // A full standard error loses the messages, never the work or the exit status (before: a
    // panic, 101, once `analyze --csv` had written its files).
    for (args, code) in [
        (
            vec![
                "analyze".to_string(),
                s(&recording),
                "--csv".into(),
                s(&dir.join("csv")),
            ],
            0,
        ),
        (vec!["analyze".to_string(), s(&dir.join("missing.mcap"))], 1),
    ] {
        let status = Command::new(CHAOSCOPE)
            .args(&args)
            .stdout(Stdio::null())
            .stderr(std::fs::File::create("/dev/full").unwrap())
            .status()
            .unwrap();
        assert_eq!(status.code(), Some(code), "{args:?} 2> /dev/full");
    }
    assert!(dir.join("csv/vm.csv").exists());
    eprintln!("{n} cases of closed and full standard output");
}
