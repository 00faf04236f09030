//! Issue #13, point 5: a recording or map file, which may come from anyone, cannot make
//! `analyze`, `replay` or `map` (resuming) write anywhere but the paths the user gave. Hostile
//! headers name schemes `../escaped`, absolute paths, `a/b`, names with newlines, duplicate
//! names; recorded configs name tables by absolute and `..` paths and runs by `../..` names.
//! Each command runs in an empty working directory beside the directories the user named, and
//! afterwards every file under the test's root and the absolute targets are accounted for.

mod common;

use std::collections::BTreeSet;
use std::io::Cursor;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use chaoscope_recorder::file::{Compression, FileOptions};
use chaoscope_recorder::map_file::MapFile;
use chaoscope_recorder::testing::{self, Shape};
use chaoscope_schemas::proto::{MapHeader, Scheme};
use common::CHAOSCOPE;

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
