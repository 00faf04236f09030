//! Issue #13, point 5: a recording or map file, which may come from anyone, cannot make
//! `analyze`, `replay` or `map` (resuming) write anywhere but the paths the user gave. Hostile
//! headers name schemes `../escaped`, absolute paths, `a/b`, names with newlines, duplicate
//! names; recorded configs name tables by absolute and `..` paths and runs by `../..` names.
//! Each command runs in an empty working directory beside the directories the user named, and
//! afterwards every file under the test's root and the absolute targets are accounted for.

use crate::common;

use std::collections::BTreeSet;
use std::io::Cursor;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::time::{Duration, Instant};

use crate::common::CHAOSCOPE;
use chaoscope_files::file::{Compression, FileOptions};
use chaoscope_files::map_file::MapFile;
use chaoscope_files::testing::{self, Shape};
use chaoscope_schemas::proto::{MapHeader, Scheme};

fn files_under(dir: &Path) -> BTreeSet<PathBuf> {
    fn walk(dir: &Path, out: &mut BTreeSet<PathBuf>) {
        for e in std::fs::read_dir(dir).into_iter().flatten().flatten() {
            let p = e.path();
            if e.file_type().is_ok_and(|t| t.is_dir()) {
                out.insert(p.clone());
                walk(&p, out);
            } else {
                out.insert(p);
            }
        }
    }
    let mut out = BTreeSet::new();
    walk(dir, &mut out);
    out
}

/// A place laid out like a user's: `inputs/` (the hostile files), `given/` (where the user
/// said outputs go), `cwd/` (the working directory), all under `root`.
struct Place {
    root: tempfile::TempDir,
    /// An absolute path outside `root` that hostile names aim at.
    outside: PathBuf,
}

impl Place {
    fn new() -> Self {
        let root = tempfile::tempdir().unwrap();
        for d in ["inputs", "given", "cwd"] {
            std::fs::create_dir(root.path().join(d)).unwrap();
        }
        let outside = std::env::temp_dir().join(format!("chaoscope-escape-{}", std::process::id()));
        Self { root, outside }
    }

    fn path(&self, rel: &str) -> PathBuf {
        self.root.path().join(rel)
    }

    fn run(&self, args: &[&str]) -> Output {
        Command::new(CHAOSCOPE)
            .args(args)
            .current_dir(self.path("cwd"))
            .output()
            .unwrap()
    }

    /// Runs `args`; afterwards the only new files are among `allowed`, nothing exists at the
    /// outside target. Returns the output.
    fn assert_writes_only(&self, args: &[&str], allowed: &[PathBuf]) -> Output {
        let before = files_under(self.root.path());
        let out = self.run(args);
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert_ne!(out.status.code(), Some(101), "{args:?} panicked: {stderr}");
        assert!(!stderr.contains("panicked"), "{args:?}: {stderr}");
        let after = files_under(self.root.path());
        for new in after.difference(&before) {
            assert!(
                allowed.iter().any(|a| new.starts_with(a)),
                "{args:?} wrote {} (allowed: {allowed:?})",
                new.display()
            );
        }
        assert!(
            !self.outside.exists(),
            "{args:?} wrote {}",
            self.outside.display()
        );
        let parent = self.root.path().parent().unwrap();
        for e in std::fs::read_dir(parent).unwrap().flatten() {
            let name = e.file_name().to_string_lossy().into_owned();
            assert!(
                !name.starts_with("escaped"),
                "{args:?} wrote {name} beside the root"
            );
        }
        out
    }
}

/// A change to a recording's run header.
type HeaderEdit = Box<dyn Fn(&mut chaoscope_schemas::proto::RunHeader)>;

fn recording_with(path: &Path, edit: impl FnOnce(&mut chaoscope_schemas::proto::RunHeader)) {
    let shape = Shape {
        dim: 4,
        k: 2,
        sets: 2,
        samples: 40,
    };
    let options = FileOptions {
        compression: Compression::Zstd,
        chunk_size: 4096,
    };
    let bytes = testing::write_run_with(Cursor::new(Vec::new()), &shape, &options, 3, edit)
        .unwrap()
        .into_inner();
    std::fs::write(path, bytes).unwrap();
}

fn scheme(name: &str) -> Scheme {
    Scheme {
        index: 0,
        name: name.into(),
        method: "mpm".into(),
        d0: 1e-8,
        tau: 0.01,
        tau_steps: 1,
        orthonormalize: "rescale".into(),
    }
}

#[test]
fn analyze_writes_csv_and_plots_only_into_the_directories_given() {
    let place = Place::new();
    let outside = place.outside.to_str().unwrap().to_string();
    let csv = place.path("given/csv");
    let plot = place.path("given/plot");
    let allowed = [csv.clone(), plot.clone()];

    // The control: a well-named scheme's files land in the given directories, named after it.
    let good = place.path("inputs/good.mcap");
    recording_with(&good, |h| h.schemes[0].name = "mpm".into());
    let out = place.assert_writes_only(
        &[
            "analyze",
            good.to_str().unwrap(),
            "--csv",
            csv.to_str().unwrap(),
            "--plot",
            plot.to_str().unwrap(),
        ],
        &allowed,
    );
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(csv.join("mpm.csv").exists());
    assert!(plot.join("gali_mpm.png").exists() || plot.join("gali_mpm.svg").exists());
    std::fs::remove_dir_all(&csv).unwrap();
    std::fs::remove_dir_all(&plot).unwrap();

    let hostile: Vec<(&str, HeaderEdit)> = vec![
        (
            "dot-dot",
            Box::new(|h| h.schemes[0].name = "../../escaped".into()),
        ),
        ("absolute", {
            let o = outside.clone();
            Box::new(move |h| h.schemes[0].name = o.clone())
        }),
        ("slash", Box::new(|h| h.schemes[0].name = "a/b".into())),
        (
            "newline",
            Box::new(|h| h.schemes[0].name = "x\n../../escaped".into()),
        ),
        ("empty", Box::new(|h| h.schemes[0].name = String::new())),
        (
            "long",
            Box::new(|h| h.schemes[0].name = "a".repeat(100_000)),
        ),
        (
            "duplicate",
            Box::new(|h| {
                let mut second = scheme("mpm");
                second.index = 1;
                h.schemes.push(second);
            }),
        ),
    ];
    for (what, edit) in hostile {
        let file = place.path(&format!("inputs/{what}.mcap"));
        recording_with(&file, |h| edit(h));
        let out = place.assert_writes_only(
            &[
                "analyze",
                file.to_str().unwrap(),
                "--csv",
                csv.to_str().unwrap(),
                "--plot",
                plot.to_str().unwrap(),
            ],
            &allowed,
        );
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(1), "{what}: {stderr}");
        assert_eq!(stderr.trim_end().lines().count(), 1, "{what}: {stderr}");
        assert!(stderr.contains("scheme name"), "{what}: {stderr}");
        assert!(
            stderr.len() < 500,
            "{what}: {} bytes of error",
            stderr.len()
        );
        assert!(!csv.exists() && !plot.exists(), "{what}: directories made");
    }
}

#[test]
fn replay_writes_only_its_output_whatever_the_recorded_config_names() {
    let place = Place::new();
    let outside = place.outside.to_str().unwrap().to_string();
    let table = format!("{outside}/bond.csv");
    // Recorded configs naming tables outside, runs and schemes by climbing names.
    let configs = [
        format!(
            "[model]\nname = \"potential\"\nn = 2\npotential = \"U(q1)\"\ntables = {{ U = \"{table}\" }}\n"
        ),
        "[model]\nname = \"potential\"\nn = 2\npotential = \"U(q1)\"\ntables = { U = \"../../escaped.csv\" }\n".to_string(),
        format!("{}\n", common::hh_config(1.0, 0.01).to_toml()).replace("name = \"vm\"", "name = \"../../escaped\""),
        common::hh_config(1.0, 0.01).to_toml(),
    ];
    for (i, config) in configs.iter().enumerate() {
        let file = place.path(&format!("inputs/r{i}.mcap"));
        recording_with(&file, |h| {
            h.config_toml = config.clone();
            h.run_name = "../../escaped".into();
        });
        let new = place.path(&format!("given/new{i}.mcap"));
        let out = place.assert_writes_only(
            &[
                "replay",
                file.to_str().unwrap(),
                "--tau",
                "0.02",
                "--out",
                new.to_str().unwrap(),
            ],
            std::slice::from_ref(&new),
        );
        let stderr = String::from_utf8_lossy(&out.stderr);
        eprintln!("replay {i}: {:?}: {}", out.status.code(), stderr.trim());
        if i < 3 {
            assert_eq!(out.status.code(), Some(1), "replay {i}: {stderr}");
            assert!(!new.exists(), "replay {i} left {}", new.display());
        }
    }
}

#[test]
fn resuming_a_foreign_map_writes_nothing_and_leaves_it_untouched() {
    let place = Place::new();
    let outside = place.outside.to_str().unwrap().to_string();
    let config = place.path("inputs/map.toml");
    std::fs::write(&config, include_str!("data/hh-map-small.toml")).unwrap();
    let map = place.path("given/map.mcap");
    let png = place.path("given/map.png");
    for (what, recorded) in [
        (
            "table outside",
            format!(
                "[model]\nname = \"potential\"\nn = 2\npotential = \"U(q1)\"\ntables = {{ U = \"{outside}/bond.csv\" }}\n"
            ),
        ),
        (
            "climbing names",
            include_str!("data/hh-map-small.toml")
                .replace("name = \"mpm\"", "name = \"../../escaped\""),
        ),
    ] {
        let header = MapHeader {
            config_toml: recorded,
            grid_points: 63,
            shard_count: 1,
            indicator: "gali-time".into(),
            ..Default::default()
        };
        let mut file = MapFile::create(
            Cursor::new(Vec::new()),
            &header,
            &FileOptions {
                compression: Compression::Zstd,
                chunk_size: 1 << 20,
            },
        )
        .unwrap();
        file.close_chunk().unwrap();
        let bytes = file.finish().unwrap().into_inner();
        std::fs::write(&map, &bytes).unwrap();
        let out = place.assert_writes_only(
            &[
                "map",
                config.to_str().unwrap(),
                "--out",
                map.to_str().unwrap(),
                "--png",
                png.to_str().unwrap(),
                "--no-progress",
            ],
            &[],
        );
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(1), "{what}: {stderr}");
        assert_eq!(
            std::fs::read(&map).unwrap(),
            bytes,
            "{what}: the map was changed"
        );
    }
}

/// Issue #24, paths: every command that writes a file writes it through one discipline
/// (`chaoscope_os::output`): into `NAME.partial`, created exclusively, renamed onto `NAME` when
/// complete. So, whatever sits at the output's name, and even with `--force`:
/// - a FIFO or a device is neither opened, replaced nor removed (before: `replay` opened a FIFO
///   and hung; as root `replay`/`recover --out /dev/null --force` deleted `/dev/null`; tested
///   here on a twin of `/dev/null` made with mknod when the test runs as root);
/// - a hard or symbolic link to one of the command's inputs is refused and the input kept
///   (before: `replay --out` a hard link of its input overwrote the input);
/// - a dangling symbolic link is not followed: nothing appears where it points;
/// - a directory is refused and kept;
///
/// and no in-progress file is left behind.
#[test]
fn no_writer_replaces_a_special_file_or_an_input_nor_follows_a_link() {
    let place = Place::new();
    let inputs = place.path("inputs");
    let run = inputs.join("run.mcap");
    let config = common::write_config(&inputs, &common::hh_config(2.0, 0.01).to_toml());
    let ran = common::chaoscope_captured(&[
        "run",
        config.to_str().unwrap(),
        "--run",
        &common::unique_run("paths"),
        "--out",
        run.to_str().unwrap(),
    ])
    .output()
    .unwrap();
    assert!(
        ran.status.success(),
        "{}",
        String::from_utf8_lossy(&ran.stderr)
    );
    let map_config = inputs.join("map.toml");
    std::fs::write(&map_config, include_str!("data/hh-map-small.toml")).unwrap();
    let shard = inputs.join("shard.mcap");
    common::run_ok(&[
        "map",
        map_config.to_str().unwrap(),
        "--out",
        shard.to_str().unwrap(),
        "--no-progress",
        "--name",
        &common::unique_run("paths-map"),
    ]);
    let chart = inputs.join("chart.json");
    std::fs::write(
        &chart,
        r#"{"title": "t", "x_label": "x", "y_label": "y", "lines": [{"points": [[0, 0], [1, 1]]}]}"#,
    )
    .unwrap();

    /// A command writing `target` (in `dir`), and the input a link at `target` aims at. Its
    /// arguments, split at spaces, with `{out}` for `target`, `{dir}` for `dir`, `{unique}` for a
    /// fresh run name, and `{run}`, `{shard}`, `{map}`, `{config}`, `{chart}` for the inputs.
    struct Writer {
        what: &'static str,
        argv: &'static str,
        /// The output's name within the case's directory.
        name: &'static str,
        input: PathBuf,
    }
    let s = |p: &Path| p.to_str().unwrap().to_string();
    let inputs_named = [
        ("{run}", s(&run)),
        ("{shard}", s(&shard)),
        ("{map}", s(&map_config)),
        ("{config}", s(&config)),
        ("{chart}", s(&chart)),
    ];
    let expand = |argv: &str, dir: &Path, target: &Path| -> Vec<String> {
        argv.split(' ')
            .map(|word| {
                let mut word = word
                    .replace("{out}", &s(target))
                    .replace("{dir}", &s(dir))
                    .replace("{unique}", &common::unique_run("paths"));
                for (name, path) in &inputs_named {
                    word = word.replace(name, path);
                }
                word
            })
            .collect()
    };
    let writer = |what, argv, name, input: &Path| Writer {
        what,
        argv,
        name,
        input: input.to_path_buf(),
    };
    let writers = vec![
        writer(
            "replay",
            "replay {run} --tau 0.02 --out {out} --force",
            "out.mcap",
            &run,
        ),
        writer(
            "recover",
            "recover {run} --out {out} --force",
            "out.mcap",
            &run,
        ),
        writer(
            "merge",
            "merge {shard} --out {out} --force",
            "out.mcap",
            &shard,
        ),
        writer(
            "map --out",
            "map {map} --out {out} --restart --no-progress --name {unique}",
            "out.mcap",
            &map_config,
        ),
        writer(
            "map --png",
            "map {map} --out {dir}/m.mcap --png {out} --restart --no-progress --name {unique}",
            "map.png",
            &map_config,
        ),
        writer("analyze --csv", "analyze {run} --csv {dir}", "vm.csv", &run),
        writer(
            "analyze --plot",
            "analyze {run} --plot {dir}",
            "gali_vm.png",
            &run,
        ),
        writer(
            "section --csv",
            "section {map} --vary q2 --from -0.1 --to 0.1 --count 2 --csv {out}",
            "section.csv",
            &map_config,
        ),
        writer("chart", "chart {chart} --out {dir}/c", "c.png", &chart),
        writer(
            "run",
            "run {config} --run {unique} --out {out} --force",
            "out.mcap",
            &config,
        ),
    ];

    #[derive(Debug, Clone, Copy, PartialEq)]
    enum Planted {
        Fifo,
        Device,
        HardLinkToInput,
        SymlinkToInput,
        DanglingLink,
        Directory,
    }
    // SAFETY: geteuid(2) cannot fail.
    let root = unsafe { libc::geteuid() } == 0;
    let mut planted = vec![
        Planted::Fifo,
        Planted::HardLinkToInput,
        Planted::SymlinkToInput,
        Planted::DanglingLink,
        Planted::Directory,
    ];
    if root {
        planted.push(Planted::Device);
    }
    let inputs_before: Vec<(PathBuf, Vec<u8>)> = [&run, &shard, &map_config, &config, &chart]
        .iter()
        .map(|p| (p.to_path_buf(), std::fs::read(p).unwrap()))
        .collect();
    let mut cases = 0;
    let mut failures = Vec::new();
    for (wi, w) in writers.iter().enumerate() {
        for (pi, &p) in planted.iter().enumerate() {
            let dir = place.path(&format!("given/{wi}-{pi}"));
            std::fs::create_dir_all(&dir).unwrap();
            let target = dir.join(w.name);
            let aim = place.path(&format!("given/aim-{wi}-{pi}"));
            let c = |p: &Path| std::ffi::CString::new(p.to_str().unwrap()).unwrap();
            match p {
                Planted::Fifo => {
                    // SAFETY: mkfifo(3) on a NUL-terminated path.
                    assert_eq!(unsafe { libc::mkfifo(c(&target).as_ptr(), 0o600) }, 0);
                }
                Planted::Device => {
                    // A twin of /dev/null (character device 1:3), which only root can make.
                    let dev = libc::makedev(1, 3);
                    // SAFETY: mknod(2) on a NUL-terminated path.
                    let made =
                        unsafe { libc::mknod(c(&target).as_ptr(), libc::S_IFCHR | 0o666, dev) };
                    assert_eq!(made, 0, "mknod: {}", std::io::Error::last_os_error());
                }
                Planted::HardLinkToInput => std::fs::hard_link(&w.input, &target).unwrap(),
                Planted::SymlinkToInput => std::os::unix::fs::symlink(&w.input, &target).unwrap(),
                Planted::DanglingLink => std::os::unix::fs::symlink(&aim, &target).unwrap(),
                Planted::Directory => std::fs::create_dir(&target).unwrap(),
            }
            let before = std::fs::symlink_metadata(&target).unwrap().file_type();
            let args = expand(w.argv, &dir, &target);
            let args: Vec<&str> = args.iter().map(String::as_str).collect();
            cases += 1;
            let case = format!("{} over {p:?}", w.what);
            let Some(out) = output_within(&args, Duration::from_secs(30)) else {
                failures.push(format!("{case}: did not end within 30 s (hung on it?)"));
                continue;
            };
            let stderr = String::from_utf8_lossy(&out.stderr).into_owned();
            if out.status.code() == Some(101) || stderr.contains("panicked") {
                failures.push(format!("{case}: panicked: {stderr}"));
            }
            let after = std::fs::symlink_metadata(&target).map(|m| m.file_type());
            match p {
                Planted::DanglingLink => {
                    if aim.exists() {
                        failures.push(format!("{case}: followed the link and wrote {aim:?}"));
                    }
                }
                _ => {
                    if after.as_ref().ok() != Some(&before) {
                        failures.push(format!("{case}: {before:?} became {after:?}"));
                    }
                    if out.status.success() && p != Planted::Directory {
                        failures.push(format!("{case}: succeeded: {stderr}"));
                    }
                    // One line, naming the output.
                    if !out.status.success()
                        && (stderr.trim_end().lines().count() != 1
                            || !stderr.contains(target.to_str().unwrap()))
                    {
                        failures.push(format!("{case}: error is not one line naming it: {stderr}"));
                    }
                }
            }
            let left: Vec<_> = std::fs::read_dir(&dir)
                .unwrap()
                .flatten()
                .map(|e| e.file_name().to_string_lossy().into_owned())
                .filter(|n| n.contains(".partial"))
                .collect();
            if !left.is_empty() {
                failures.push(format!("{case}: left {left:?}"));
            }
            for (path, bytes) in &inputs_before {
                if std::fs::read(path).ok().as_ref() != Some(bytes) {
                    failures.push(format!("{case}: the input {path:?} changed"));
                }
            }
        }
    }
    eprintln!(
        "{cases} cases ({} writers x {} planted files)",
        writers.len(),
        planted.len()
    );
    assert!(
        failures.is_empty(),
        "{} of {cases} cases failed:\n{}",
        failures.len(),
        failures.join("\n")
    );
}

/// `chaoscope ARGS` with its output; `None` (after killing it) if it runs past `limit`.
fn output_within(args: &[&str], limit: Duration) -> Option<Output> {
    let mut child = Command::new(CHAOSCOPE)
        .args(args)
        .stdin(std::process::Stdio::null())
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    // Read both pipes on threads, so a chatty child cannot block on a full pipe.
    let mut stdout = child.stdout.take().unwrap();
    let mut stderr = child.stderr.take().unwrap();
    let read_out = std::thread::spawn(move || {
        let mut v = Vec::new();
        let _ = std::io::Read::read_to_end(&mut stdout, &mut v);
        v
    });
    let read_err = std::thread::spawn(move || {
        let mut v = Vec::new();
        let _ = std::io::Read::read_to_end(&mut stderr, &mut v);
        v
    });
    let start = Instant::now();
    let status = loop {
        if let Some(status) = child.try_wait().unwrap() {
            break status;
        }
        if start.elapsed() > limit {
            let _ = child.kill();
            let _ = child.wait();
            return None;
        }
        std::thread::sleep(Duration::from_millis(10));
    };
    Some(Output {
        status,
        stdout: read_out.join().unwrap(),
        stderr: read_err.join().unwrap(),
    })
}

/// Waits until the writer of `out` has begun: its in-progress file (or, for a writer that
/// writes in place, the file itself) exists (up to a minute).
fn wait_for_writer(out: &Path) {
    let partial = chaoscope_os::output::partial_path(out);
    let start = Instant::now();
    while !partial.exists() && !out.exists() {
        assert!(
            start.elapsed() < Duration::from_secs(60),
            "{out:?} never begun"
        );
        std::thread::sleep(Duration::from_millis(10));
    }
}

/// Issue #24, paths: one writer per output. A second `map` of one `--out` is refused with one
/// line while the first lives, and the first completes the whole map (before: the second
/// deleted the first's live file and both said `complete`). `run --force` onto the file a live
/// run writes is refused (before: the two runs mixed in one file), and a run refused as a
/// duplicate of a live run's name leaves no file (before: its recorder recorded the other run).
#[test]
fn a_second_writer_of_one_output_is_refused_while_the_first_lives() {
    let place = Place::new();
    let dir = place.path("given");
    // A map long enough to be live while the second starts. The small map's `gali-time` stops
    // most points within a few hundred steps (8 ms in all on a Zen 5 at t = 400, which the
    // second process sometimes outlived there): every point to t = 10^4 instead (`gali`),
    // 4.2e8 orbit-steps, about 1.2 s on a Zen 5 and 3-4 s on a Zen 3.
    let config = place.path("inputs/map.toml");
    std::fs::write(
        &config,
        include_str!("data/hh-map-small.toml")
            .replace("t_final = 20.0", "t_final = 10000.0")
            .replace("indicator = \"gali-time\"", "indicator = \"gali\"")
            .replace("threshold = 0.05\n", ""),
    )
    .unwrap();
    let out = dir.join("map.mcap");
    let map = |name: &str| {
        common::chaoscope_captured(&[
            "map",
            config.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
            "--no-progress",
            "--json",
            "--threads",
            "1",
            "--name",
            &common::unique_run(name),
        ])
    };
    let first = map("first")
        .stdout(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    wait_for_writer(&out);
    let second = map("second").output().unwrap();
    let stderr = String::from_utf8_lossy(&second.stderr);
    assert_eq!(second.status.code(), Some(1), "{stderr}");
    assert_eq!(stderr.trim_end().lines().count(), 1, "{stderr}");
    assert!(
        stderr.contains(out.to_str().unwrap()) && stderr.contains("another live process"),
        "{stderr}"
    );
    let done = first.wait_with_output().unwrap();
    assert!(done.status.success(), "the first map failed");
    let json: serde_json::Value = serde_json::from_slice(&done.stdout).unwrap();
    assert_eq!(json["complete"], true, "{json}");
    assert_eq!(json["computed"], 63, "{json}");
    assert_eq!(common::map_points(&out).len(), 63);

    // Two runs and one file.
    let long = common::write_config(
        &place.path("inputs"),
        &common::hh_config(1e5, 0.01).to_toml(),
    );
    let first_name = common::unique_run("first-run");
    let run_out = dir.join("run.mcap");
    let mut first = common::Proc::spawn(common::chaoscope(&[
        "run",
        long.to_str().unwrap(),
        "--run",
        &first_name,
        "--out",
        run_out.to_str().unwrap(),
    ]));
    wait_for_writer(&run_out);
    let second = common::chaoscope_captured(&[
        "run",
        long.to_str().unwrap(),
        "--run",
        &common::unique_run("second-run"),
        "--out",
        run_out.to_str().unwrap(),
        "--force",
    ])
    .output()
    .unwrap();
    let stderr = String::from_utf8_lossy(&second.stderr);
    assert_eq!(second.status.code(), Some(1), "{stderr}");
    assert_eq!(stderr.trim_end().lines().count(), 1, "{stderr}");
    assert!(stderr.contains("another live process"), "{stderr}");
    // A run of the live run's name, into a file of its own: refused, and no file.
    let duplicate_out = dir.join("duplicate.mcap");
    let duplicate = common::chaoscope_captured(&[
        "run",
        long.to_str().unwrap(),
        "--run",
        &first_name,
        "--out",
        duplicate_out.to_str().unwrap(),
    ])
    .output()
    .unwrap();
    let stderr = String::from_utf8_lossy(&duplicate.stderr);
    assert_eq!(duplicate.status.code(), Some(1), "{stderr}");
    assert_eq!(stderr.trim_end().lines().count(), 1, "{stderr}");
    assert!(stderr.contains("already being produced"), "{stderr}");
    assert!(
        !duplicate_out.exists() && !chaoscope_os::output::partial_path(&duplicate_out).exists(),
        "a refused run left a file"
    );
    first.signal(libc::SIGINT);
    assert_eq!(first.wait(Duration::from_secs(60)).code(), Some(130));
    // The first run's file holds the first run alone, every frame once.
    let rec = common::read_recording(&run_out);
    assert_eq!(rec.header.as_ref().unwrap().run_name, first_name);
    common::assert_contiguous(&rec.frames);
    assert_eq!(rec.recording.unwrap().run_status, "interrupted");
}

/// `chaoscope ARGS`, its exit code and stderr (run to its end; stdin closed).
fn attempt(args: &[String]) -> (Option<i32>, String) {
    let out = Command::new(CHAOSCOPE)
        .args(args)
        .stdin(std::process::Stdio::null())
        .output()
        .unwrap();
    (
        out.status.code(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

fn strings(args: &[&str]) -> Vec<String> {
    args.iter().map(|s| s.to_string()).collect()
}

/// The inputs the attacking writers read: a finished short recording, a map configuration and
/// a finished map, a chart description, all under `dir`.
struct Ammunition {
    recording: PathBuf,
    map_config: PathBuf,
    map: PathBuf,
    short_config: PathBuf,
}

impl Ammunition {
    fn new(dir: &Path) -> Self {
        let short_config = dir.join("short.toml");
        std::fs::write(&short_config, common::hh_config(5.0, 0.01).to_toml()).unwrap();
        let recording = dir.join("short.mcap");
        let (code, stderr) = attempt(&strings(&[
            "run",
            short_config.to_str().unwrap(),
            "--run",
            &common::unique_run("ammunition"),
            "--out",
            recording.to_str().unwrap(),
        ]));
        assert_eq!(code, Some(0), "{stderr}");
        let map_config = dir.join("map.toml");
        std::fs::write(&map_config, include_str!("data/hh-map-small.toml")).unwrap();
        let map = dir.join("map.mcap");
        let (code, stderr) = attempt(&strings(&[
            "map",
            map_config.to_str().unwrap(),
            "--out",
            map.to_str().unwrap(),
            "--no-progress",
            "--json",
        ]));
        assert_eq!(code, Some(0), "{stderr}");
        Self {
            recording,
            map_config,
            map,
            short_config,
        }
    }

    /// Every command that writes a file, aimed at `target` (with `--force` where it has one).
    fn writers(&self, target: &Path, force: bool) -> Vec<Vec<String>> {
        let t = target.to_str().unwrap();
        let rec = self.recording.to_str().unwrap();
        let mut all = vec![
            strings(&["recover", rec, "--out", t]),
            strings(&["replay", rec, "--tau", "0.02", "--out", t]),
            strings(&["resume", rec, "--t-final", "6", "--out", t]),
            strings(&[
                "map",
                self.map_config.to_str().unwrap(),
                "--out",
                t,
                "--no-progress",
                "--json",
            ]),
            strings(&[
                "merge",
                self.map.to_str().unwrap(),
                "--out",
                t,
                "--allow-incomplete",
            ]),
            strings(&[
                "record",
                "--run",
                &common::unique_run("attacker"),
                "--out",
                t,
                "--wait-timeout",
                "0.2",
            ]),
            strings(&[
                "run",
                self.short_config.to_str().unwrap(),
                "--run",
                &common::unique_run("attacker"),
                "--out",
                t,
            ]),
        ];
        if force {
            for args in &mut all {
                args.push("--force".into());
            }
        }
        all
    }
}

/// A long run (t = 10^5, hours of integration, ended by SIGINT) recording into `out`, once its
/// recorder holds `out.partial` and has written the run's header into it.
fn live_run(config: &Path, name: &str, out: &Path) -> common::Proc {
    let run = common::Proc::spawn({
        let mut c = common::chaoscope_captured(&[
            "run",
            config.to_str().unwrap(),
            "--run",
            name,
            "--out",
            out.to_str().unwrap(),
        ]);
        c.stdin(std::process::Stdio::null())
            .stdout(std::process::Stdio::null())
            .stderr(std::process::Stdio::piped());
        c
    });
    // Begun recording: the run's header is in the in-progress file.
    let partial = chaoscope_os::output::partial_path(out);
    let start = Instant::now();
    while std::fs::metadata(&partial).map_or(true, |m| m.len() == 0) {
        assert!(
            start.elapsed() < Duration::from_secs(60),
            "{out:?} never begun"
        );
        std::thread::sleep(Duration::from_millis(10));
    }
    run
}

/// Why the recording at `out` is not the run `name` of `expected` (its samples a prefix of
/// `expected`, bit for bit, every frame once, finalized with status `interrupted`), if it
/// is not.
fn not_the_live_run(
    out: &Path,
    name: &str,
    expected: &[chaoscope_schemas::run::Sample],
) -> Option<String> {
    let read = std::panic::catch_unwind(|| {
        let rec = common::read_recording(out);
        common::assert_contiguous(&rec.frames);
        common::assert_bit_identical(&rec, expected);
        rec
    });
    let Ok(rec) = read else {
        return Some(format!(
            "{out:?} is not a complete copy of the live run's samples"
        ));
    };
    let header = rec.header.as_ref().map(|h| h.run_name.clone());
    if header.as_deref() != Some(name) {
        return Some(format!("{out:?} holds run {header:?}, not {name}"));
    }
    if rec.references.is_empty() {
        return Some(format!("{out:?} holds no sample"));
    }
    match rec.recording.as_ref().map(|r| r.run_status.as_str()) {
        Some("interrupted") => None,
        other => Some(format!("{out:?} ended with status {other:?}")),
    }
}

/// How many samples the recording at `out` holds (0 if it cannot be read).
fn samples_in(out: &Path) -> usize {
    std::panic::catch_unwind(|| common::read_recording(out).references.len()).unwrap_or(0)
}

/// Stops a live run with SIGINT; its exit code and stderr.
fn stop(mut run: common::Proc) -> (Option<i32>, String) {
    run.signal(libc::SIGINT);
    let code = run.wait(Duration::from_secs(60)).code();
    let mut stderr = String::new();
    if let Some(mut e) = run.0.stderr.take() {
        std::io::Read::read_to_string(&mut e, &mut stderr).unwrap();
    }
    (code, stderr)
}

/// A live output has one owner. Every writing command aimed at a live run's in-progress file
/// `live.mcap.partial` (as an output of its own, with and without `--force`) or at a link to it
/// is refused in one line naming the live writer, and the run completes its own file (before:
/// `recover`, `replay` and `resume` with `--force` renamed their file over the live one and the
/// run reported success with their file at its name). An in-progress file replaced behind the
/// writer's back (a plain `mv` of another user program) makes the run fail loudly, naming it,
/// instead of putting the stranger's file at the run's name.
#[test]
fn no_command_replaces_a_live_in_progress_file_whatever_its_flags() {
    let place = Place::new();
    let ammo = Ammunition::new(&place.path("inputs"));
    let long_toml = common::hh_config(1e5, 0.1).to_toml();
    let long = place.path("inputs/long.toml");
    std::fs::write(&long, &long_toml).unwrap();
    let out = place.path("given/live.mcap");
    let partial = chaoscope_os::output::partial_path(&out);
    let link = place.path("given/link.mcap");
    std::os::unix::fs::symlink(&partial, &link).unwrap();
    let name = common::unique_run("live");
    let run = live_run(&long, &name, &out);
    let mut failures = Vec::new();
    for force in [false, true] {
        for args in ammo.writers(&partial, force) {
            let (code, stderr) = attempt(&args);
            let line = stderr.trim_end();
            if code != Some(1)
                || line.lines().count() != 1
                || !line.contains("another live process")
                || !line.contains(partial.to_str().unwrap())
            {
                failures.push(format!("{args:?}: exit {code:?}: {line}"));
            }
        }
    }
    // A link at the output is replaced itself, never what it points to.
    let (code, stderr) = attempt(&ammo.writers(&link, true)[0]);
    assert_eq!(code, Some(0), "{stderr}");
    assert!(std::fs::symlink_metadata(&link).unwrap().is_file());
    let (code, stderr) = stop(run);
    assert_eq!(code, Some(130), "{stderr}");
    assert!(failures.is_empty(), "{}", failures.join("\n"));
    let expected = common::compute(&long_toml, Some(samples_in(&out)));
    assert_eq!(not_the_live_run(&out, &name, &expected), None);

    // Replaced behind the writer's back: the run fails loudly and nothing is renamed.
    std::fs::remove_file(&out).unwrap();
    let name = common::unique_run("replaced");
    let run = live_run(&long, &name, &out);
    let stranger = place.path("given/stranger");
    std::fs::write(&stranger, "not the run").unwrap();
    std::fs::rename(&stranger, &partial).unwrap();
    let (code, stderr) = stop(run);
    assert_ne!(code, Some(0), "{stderr}");
    assert_ne!(code, Some(130), "{stderr}");
    assert!(
        stderr.contains("replaced or removed by another process")
            && stderr.contains(partial.to_str().unwrap()),
        "{stderr}"
    );
    assert!(
        !out.exists(),
        "the stranger's file was put at the run's name"
    );
    assert_eq!(std::fs::read(&partial).unwrap(), b"not the run");
}

/// Fifty rounds of a live run attacked by every other writing command (one command a round,
/// in turn), aimed at the run's output or at its in-progress file, with or without `--force`
/// (each command at each of the four aims at least once); and, one round in eight, `analyze --csv` aimed at a live run whose output has the
/// name of one of its tables. Each live run lives until the attacks are over (it ends by
/// SIGINT after them), so the verdict does not depend on timing: every attack is refused, and
/// the run's file is its own, every sample bit-identical to the undisturbed computation of its
/// configuration, or the run failed loudly (an exit status other than 0 and 130, with an
/// error). A silent loss (exit 130 or 0 with a file that is not the run's) fails the test.
#[test]
fn fifty_rounds_of_attacks_on_a_live_output_lose_nothing_silently() {
    let place = Place::new();
    let ammo = Ammunition::new(&place.path("inputs"));
    let long_toml = common::hh_config(1e5, 0.1).to_toml();
    let long = place.path("inputs/long.toml");
    std::fs::write(&long, &long_toml).unwrap();
    let mut expected = Vec::new();
    let commands = ammo.writers(Path::new("x"), false).len() + 1;
    let (mut silent, mut loud, mut refused) = (0, 0, 0);
    let mut failures = Vec::new();
    for round in 0..50 {
        let dir = place.path(&format!("given/round{round}"));
        std::fs::create_dir(&dir).unwrap();
        let command = round % commands;
        let analyzing = command == commands - 1;
        // `analyze --csv DIR` writes `DIR/<scheme>.csv`: the live output takes the name of
        // the short recording's first scheme's table.
        let out = dir.join(if analyzing { "vm.csv" } else { "live.mcap" });
        let partial = chaoscope_os::output::partial_path(&out);
        let name = common::unique_run(&format!("round{round}"));
        let run = live_run(&long, &name, &out);
        let mut attacks = Vec::new();
        if analyzing {
            let rec = ammo.recording.to_str().unwrap();
            attacks.push(strings(&["analyze", rec, "--csv", dir.to_str().unwrap()]));
        } else {
            // Each round one of the four aims, in turn with the commands: 50 rounds cover each
            // command at each aim at least once.
            let variant = (round / commands) % 4;
            let target = if variant.is_multiple_of(2) {
                &out
            } else {
                &partial
            };
            attacks.push(ammo.writers(target, variant >= 2).swap_remove(command));
        }
        for args in &attacks {
            let (code, stderr) = attempt(args);
            if code == Some(1) && stderr.trim_end().lines().count() == 1 {
                refused += 1;
            } else {
                failures.push(format!(
                    "round {round}: {args:?} not refused: {code:?} {stderr}"
                ));
            }
        }
        let (code, stderr) = stop(run);
        let written = samples_in(&out);
        if written > expected.len() {
            expected = common::compute(&long_toml, Some(2 * written));
        }
        match (code, not_the_live_run(&out, &name, &expected)) {
            (Some(130), None) => {}
            (Some(0 | 130), Some(why)) => {
                silent += 1;
                failures.push(format!("round {round}: silent loss: {why}"));
            }
            (_, _) if !stderr.trim().is_empty() => loud += 1,
            (code, _) => failures.push(format!("round {round}: exit {code:?} without a word")),
        }
    }
    eprintln!(
        "50 rounds: {refused} attacks refused, {loud} runs failed loudly, {silent} silent losses"
    );
    assert!(failures.is_empty(), "{}", failures.join("\n"));
    assert_eq!(silent, 0);
}

/// A failed command names every in-progress file it keeps, and the kept file never blocks the
/// next attempt without saying how to go on. A resume into `--out` that fills its file-size
/// limit (a full disk, a quota) keeps what it wrote, and its one-line error names that file
/// (before: it named only the output); the next `resume` into that output is refused with a
/// line saying which command continues the kept file, and `--force`, as that line says,
/// discards it and writes the whole resumed run (before: `--force` was refused the same way).
#[test]
fn a_failed_resume_names_what_it_keeps_and_the_next_attempt_can_go_on() {
    use std::os::unix::process::CommandExt;
    let place = Place::new();
    let ammo = Ammunition::new(&place.path("inputs"));
    let out = place.path("given/longer.mcap");
    let partial = chaoscope_os::output::partial_path(&out);
    let resume = |extra: &[&str], limit: Option<u64>| {
        let mut c = Command::new(CHAOSCOPE);
        c.args([
            "resume",
            ammo.recording.to_str().unwrap(),
            "--t-final",
            "60",
            "--out",
            out.to_str().unwrap(),
        ])
        .args(extra)
        .stdin(std::process::Stdio::null());
        if let Some(bytes) = limit {
            // SAFETY: only async-signal-safe calls (setrlimit) between fork and exec.
            unsafe {
                c.pre_exec(move || {
                    let limit = libc::rlimit {
                        rlim_cur: bytes,
                        rlim_max: bytes,
                    };
                    if libc::setrlimit(libc::RLIMIT_FSIZE, &limit) != 0 {
                        return Err(std::io::Error::last_os_error());
                    }
                    Ok(())
                });
            }
        }
        let o = c.output().unwrap();
        (
            o.status.code(),
            String::from_utf8_lossy(&o.stderr).into_owned(),
        )
    };
    // The 5-unit recording resumed to t = 60 writes some 12 times its size: past 64 KiB.
    let (code, stderr) = resume(&[], Some(64 << 10));
    assert_eq!(code, Some(1), "{stderr}");
    assert_eq!(stderr.trim_end().lines().count(), 1, "{stderr}");
    assert!(partial.exists() && !out.exists(), "{stderr}");
    assert!(
        stderr.contains(partial.to_str().unwrap()),
        "the error does not name the kept {partial:?}: {stderr}"
    );
    let (code, stderr) = resume(&[], None);
    assert_eq!(code, Some(1), "{stderr}");
    assert_eq!(stderr.trim_end().lines().count(), 1, "{stderr}");
    assert!(
        stderr.contains(partial.to_str().unwrap())
            && stderr.contains(&format!("chaoscope resume {}", out.display()))
            && stderr.contains("--force"),
        "{stderr}"
    );
    let (code, stderr) = resume(&["--force"], None);
    assert_eq!(code, Some(0), "{stderr}");
    assert!(!partial.exists());
    let rec = common::read_recording(&out);
    common::assert_contiguous(&rec.frames);
    assert_eq!(rec.recording.unwrap().run_status, "completed");
    assert_eq!(rec.header.unwrap().t_final, 60.0);
}
