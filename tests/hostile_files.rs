//! Every input file is hostile, end to end: `chaoscope analyze` and `chaoscope merge` on
//! damaged files exit with status 1 and an error naming the file and the damage, never a panic;
//! `chaoscope map` resumes a damaged map to the same map, and refuses one that is not its own.

use crate::common;

use std::collections::BTreeMap;
use std::path::Path;
use std::process::Command;

use crate::common::{CHAOSCOPE, chaoscope};
use chaoscope_files::file::{Compression, FileOptions};
use chaoscope_files::map_file::{MapFile, read_map_file};
use chaoscope_files::testing;
use chaoscope_schemas::proto::{MapAxis, MapHeader, MapPoint, map_point};
use prost::Message;

/// Damaged copies of `bytes` (a file of several chunks), each with what its error must say.
fn damage(bytes: &[u8]) -> Vec<(&'static str, Vec<u8>, &'static str)> {
    let third = testing::chunk_offsets(bytes)[2];
    let mut flipped = bytes.to_vec();
    flipped[third + 60] ^= 0x10;
    // A bit of the third chunk's CRC (after its opcode, length, times and uncompressed size).
    let mut crc = bytes.to_vec();
    crc[third + 9 + 24] ^= 0x10;
    let mut attachment = bytes[..third].to_vec();
    attachment.extend(testing::short_attachment());
    let mut huge = bytes.to_vec();
    huge[third + 1..third + 9].copy_from_slice(&(1u64 << 40).to_le_bytes());
    let mut zeros = bytes[..third].to_vec();
    zeros.resize(third + 4096, 0);
    vec![
        (
            "cut",
            bytes[..third + 30].to_vec(),
            "MCAP file ended in the middle",
        ),
        // A bit of its zstd data.
        ("flip", flipped, "Error during decompression"),
        ("crc", crc, "Chunk CRC failed"),
        (
            "attachment",
            attachment,
            "attachment record shorter than its own fields",
        ),
        (
            "huge",
            huge,
            "a record of 1099511627776 bytes, longer than any",
        ),
        ("zeros", zeros, "invalid opcode 0x00"),
    ]
}

/// Runs `chaoscope args`; asserts it failed with status 1, and that stderr names `file` and
/// the damage (`at byte` of the third chunk, `problem`) without panic text. Returns stderr.
fn assert_refused(args: &[&str], file: &Path, at: usize, problem: &str, what: &str) -> String {
    let out = Command::new(CHAOSCOPE).args(args).output().unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr).into_owned();
    assert_eq!(out.status.code(), Some(1), "{what}: {args:?}: {stderr}");
    assert!(!stderr.contains("panicked"), "{what}: {stderr}");
    assert!(stderr.contains(file.to_str().unwrap()), "{what}: {stderr}");
    assert!(
        stderr.contains(&format!("at byte {at}")),
        "{what}: {stderr}"
    );
    assert!(stderr.contains(problem), "{what}: {stderr}");
    stderr
}

#[test]
fn analyze_refuses_a_damaged_recording_with_a_clear_error() {
    let dir = tempfile::tempdir().unwrap();
    let bytes = testing::small_run(Compression::Zstd);
    let good = dir.path().join("good.mcap");
    std::fs::write(&good, &bytes).unwrap();
    let status = chaoscope(&["analyze", good.to_str().unwrap(), "--json"])
        .status()
        .unwrap();
    assert!(status.success());

    let at = testing::chunk_offsets(&bytes)[2];
    for (what, damaged, problem) in damage(&bytes) {
        let path = dir.path().join(format!("{what}.mcap"));
        std::fs::write(&path, damaged).unwrap();
        let file = path.to_str().unwrap();
        for args in [["analyze", file].as_slice(), &["analyze", file, "--json"]] {
            let stderr = assert_refused(args, &path, at, problem, what);
            assert!(stderr.contains("damaged or truncated"), "{what}: {stderr}");
        }
    }
}

#[test]
fn merge_refuses_a_damaged_shard_with_a_clear_error() {
    let dir = tempfile::tempdir().unwrap();
    let (bytes, _, _) = testing::small_map(40, 8, Compression::Zstd);
    let at = testing::chunk_offsets(&bytes)[2];
    let out = dir.path().join("merged.mcap");
    for (what, damaged, problem) in damage(&bytes) {
        let path = dir.path().join(format!("{what}.mcap"));
        std::fs::write(&path, damaged).unwrap();
        let args = [
            "merge",
            path.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
        ];
        let stderr = assert_refused(&args, &path, at, problem, what);
        assert!(stderr.contains("damaged or cut short"), "{what}: {stderr}");
        assert!(!out.exists(), "{what}: merged anyway");
    }
}

/// A complete map file whose header says `shard_index / shard_count` of `grid_points` (a grid
/// of `grid_points` x 1), holding points 0 to 3 of a 4 x 1 grid: valid values otherwise, so
/// that what is refused is the shard or the grid.
fn shard(dir: &Path, name: &str, shard_index: u32, shard_count: u32, grid_points: u64) -> String {
    let n = grid_points as u32;
    let axis = |n: u32| MapAxis {
        coord: "q2".into(),
        param: String::new(),
        min: 0.0,
        max: 3.0,
        n,
    };
    let header = MapHeader {
        config_toml: "[map]".into(),
        indicator: "gali".into(),
        k: 2,
        sets: 1,
        t_final: 1.0,
        x: Some(axis(n)),
        y: Some(axis(1)),
        grid_points,
        shard_index,
        shard_count,
        ..Default::default()
    };
    let path = dir.join(name);
    let out = std::fs::File::create(&path).unwrap();
    let mut file = MapFile::create(out, &header, &FileOptions::default()).unwrap();
    for index in 0..4 {
        let point = MapPoint {
            index,
            ix: index as u32,
            x: 3.0 * index as f64 / f64::from(n.max(2) - 1),
            status: map_point::Status::Ok as i32,
            value: -1.0,
            mean_log10: -1.0,
            per_set: vec![-1.0],
            t_end: 1.0,
            ..Default::default()
        };
        file.write_point(&point).unwrap();
    }
    file.finish().unwrap();
    path.to_str().unwrap().to_string()
}

#[test]
fn merge_refuses_impossible_shard_headers_without_panicking() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let out = d.join("merged.mcap");
    let out = out.to_str().unwrap();
    let cases = [
        vec![shard(d, "zero.mcap", 0, 0, 4)],
        vec![shard(d, "index.mcap", 3, 2, 4)],
        // Same configuration, other grids: more points than the last one's grid.
        vec![shard(d, "a.mcap", 0, 1, 4), shard(d, "b.mcap", 0, 1, 2)],
    ];
    for shards in cases {
        let mut args = vec!["merge"];
        args.extend(shards.iter().map(String::as_str));
        args.extend(["--out", out, "--force"]);
        let result = Command::new(CHAOSCOPE).args(&args).output().unwrap();
        let stderr = String::from_utf8_lossy(&result.stderr);
        assert_eq!(result.status.code(), Some(1), "{args:?}: {stderr}");
        assert!(!stderr.contains("panicked"), "{args:?}: {stderr}");
        assert!(
            stderr.contains(shards.last().unwrap()),
            "{args:?}: {stderr}"
        );
    }
}

/// A map's points by index, as their exact protobuf bytes.
fn map_points(path: &Path) -> BTreeMap<u64, Vec<u8>> {
    let contents = read_map_file(path).unwrap();
    assert!(contents.damaged.is_none(), "{:?}", contents.damaged);
    contents
        .points
        .iter()
        .map(|p| (p.index, p.encode_to_vec()))
        .collect()
}

/// A temporary directory with the small map's configuration, and that file.
fn map_dir() -> (tempfile::TempDir, std::path::PathBuf) {
    let dir = tempfile::tempdir().unwrap();
    let cfg = dir.path().join("map.toml");
    std::fs::write(&cfg, include_str!("data/hh-map-small.toml")).unwrap();
    (dir, cfg)
}

/// `chaoscope map CONFIG --out OUT`, a chunk per point, with `extra` arguments.
fn map_run(cfg: &Path, out: &Path, extra: &[&str]) -> std::process::Output {
    let args = ["map", cfg.to_str().unwrap(), "--out", out.to_str().unwrap()];
    Command::new(CHAOSCOPE)
        .args(args)
        .args(["--no-progress", "--flush-interval", "0"])
        .args(extra)
        .output()
        .unwrap()
}

#[test]
fn a_damaged_map_resumes_to_the_same_map_and_foreign_points_are_refused() {
    let (dir, cfg) = map_dir();
    let d = dir.path();
    let map = |out: &Path| map_run(&cfg, out, &[]);
    let whole = d.join("whole.mcap");
    assert!(map(&whole).status.success());
    let want = map_points(&whole);

    // A bit flipped in a middle chunk: the points before it are kept, the rest recomputed.
    let mut bytes = std::fs::read(&whole).unwrap();
    let chunks = testing::chunk_offsets(&bytes);
    assert!(chunks.len() > 4, "{} chunks", chunks.len());
    let hit = chunks[chunks.len() / 2];
    bytes[hit + 40] ^= 0x04;
    let damaged = d.join("damaged.mcap");
    std::fs::write(&damaged, &bytes).unwrap();
    let out = map(&damaged);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    assert!(
        stderr.contains("is damaged or cut short (record")
            && stderr.contains(&format!("at byte {hit}")),
        "{stderr}"
    );
    assert_eq!(map_points(&damaged), want);

    // The same map's header, with a point that is not in it.
    let header = read_map_file(&whole).unwrap().header.unwrap();
    let foreign = d.join("foreign.mcap");
    let file = std::fs::File::create(&foreign).unwrap();
    let mut file = MapFile::create(file, &header, &FileOptions::default()).unwrap();
    let point = MapPoint {
        index: header.grid_points + 5,
        ..Default::default()
    };
    file.write_point(&point).unwrap();
    file.finish().unwrap();
    let out = map(&foreign);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{stderr}");
    assert!(!stderr.contains("panicked"), "{stderr}");
    assert!(
        stderr.contains(foreign.to_str().unwrap()) && stderr.contains("not in its shard"),
        "{stderr}"
    );
}

#[test]
fn map_refuses_and_keeps_a_file_it_cannot_read_as_its_map_unless_restarted() {
    let (dir, cfg) = map_dir();
    let d = dir.path();
    let map = |out: &Path, extra: &[&str]| map_run(&cfg, out, extra);
    let whole = d.join("whole.mcap");
    assert!(map(&whole, &[]).status.success());
    let want = map_points(&whole);

    // (a) The first chunk, which holds the header, damaged: intact later chunks must survive.
    let mut bytes = std::fs::read(&whole).unwrap();
    let chunks = testing::chunk_offsets(&bytes);
    assert!(chunks.len() > 2, "{} chunks", chunks.len());
    bytes[chunks[0] + 40] ^= 0x04;
    let headless = d.join("headless.mcap");
    std::fs::write(&headless, &bytes).unwrap();
    assert!(read_map_file(&headless).unwrap().header.is_none());
    // (b) An MCAP file that is not a map at all.
    let foreign = d.join("foreign.mcap");
    std::fs::write(&foreign, testing::small_run(Compression::Zstd)).unwrap();
    // (c) Not MCAP at all (a notes file given as --out by mistake).
    let text = d.join("notes.mcap");
    std::fs::write(&text, "my notes\n").unwrap();
    for (file, why) in [
        (&headless, "no readable map header"),
        (&foreign, "no readable map header"),
        (&text, "is not an MCAP file"),
    ] {
        let before = std::fs::read(file).unwrap();
        let out = map(file, &[]);
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(1), "{stderr}");
        assert!(
            stderr.contains(file.to_str().unwrap())
                && stderr.contains(why)
                && stderr.contains("--restart"),
            "{stderr}"
        );
        assert_eq!(
            std::fs::read(file).unwrap(),
            before,
            "{} changed",
            file.display()
        );
        let mut prev = file.as_os_str().to_owned();
        prev.push(".prev");
        assert!(!Path::new(&prev).exists());
        // --restart replaces it.
        let out = map(file, &["--restart"]);
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        assert_eq!(map_points(file), want);
    }
    // The damage of a header chunk is reported.
    std::fs::write(&headless, &bytes).unwrap();
    let stderr = String::from_utf8_lossy(&map(&headless, &[]).stderr).into_owned();
    assert!(stderr.contains("is damaged or cut short"), "{stderr}");
}

// ---- Valid files with hostile values, through every command that reads them ---------------

/// Words a non-finite number prints as.
const NON_FINITE: [&str; 6] = ["NaN", "-NaN", "inf", "-inf", "+inf", "infinity"];

/// The non-finite numbers written as words of `text` (an output of a command).
fn non_finite_words(text: &str) -> Vec<&str> {
    let word = |c: char| c.is_ascii_alphanumeric() || matches!(c, '.' | '+' | '-' | '_');
    text.split(|c: char| !word(c))
        .filter(|w| NON_FINITE.contains(w))
        .collect()
}

/// JSON nulls at keys other than those a report may leave empty (`serde_json` writes NaN and
/// infinities as null, so a null elsewhere is a non-finite number).
fn unexpected_nulls(value: &serde_json::Value, key: &str, out: &mut Vec<String>) {
    match value {
        serde_json::Value::Null if !["torus_dimension", "sali"].contains(&key) => {
            out.push(key.to_string());
        }
        serde_json::Value::Array(items) => {
            items.iter().for_each(|v| unexpected_nulls(v, key, out));
        }
        serde_json::Value::Object(map) => {
            map.iter().for_each(|(k, v)| unexpected_nulls(v, k, out));
        }
        _ => {}
    }
}

/// What one command did: its exit code (`None`: killed by a signal), stdout and stderr.
struct Ran {
    code: Option<i32>,
    stdout: String,
    stderr: String,
}

/// `chaoscope args`, killed after 30 s (a hang fails the test), with its address space limited
/// to 2 GiB (an allocation a file's claim drives beyond it aborts, which fails the test too).
fn run_bounded(args: &[&str]) -> Ran {
    use std::io::Read;
    use std::os::unix::process::CommandExt;
    let mut command = Command::new(CHAOSCOPE);
    command
        .args(args)
        .stdin(std::process::Stdio::null())
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped());
    // SAFETY: setrlimit(2) is async-signal-safe; nothing else runs between fork and exec.
    unsafe {
        command.pre_exec(|| {
            let limit = 2u64 << 30;
            let rl = libc::rlimit {
                rlim_cur: limit,
                rlim_max: limit,
            };
            libc::setrlimit(libc::RLIMIT_AS, &rl);
            Ok(())
        });
    }
    let mut child = command.spawn().unwrap();
    let (mut out, mut err) = (child.stdout.take().unwrap(), child.stderr.take().unwrap());
    let reader = std::thread::spawn(move || {
        let mut s = String::new();
        let _ = out.read_to_string(&mut s);
        s
    });
    let err_reader = std::thread::spawn(move || {
        let mut s = String::new();
        let _ = err.read_to_string(&mut s);
        s
    });
    let start = std::time::Instant::now();
    let status = loop {
        if let Some(s) = child.try_wait().unwrap() {
            break s;
        }
        if start.elapsed() > std::time::Duration::from_secs(30) {
            let _ = child.kill();
            let _ = child.wait();
            panic!("chaoscope {args:?} still running after 30 s");
        }
        std::thread::sleep(std::time::Duration::from_millis(10));
    };
    Ran {
        code: status.code(),
        stdout: reader.join().unwrap(),
        stderr: err_reader.join().unwrap(),
    }
}

/// A command on a file with hostile values either succeeds or fails with status 1 and one line
/// naming `file`; never a panic, a signal or a hang. True if it succeeded.
fn succeeded_or_refused(what: &str, args: &[&str], file: &Path, ran: &Ran) -> bool {
    let lines: Vec<&str> = ran.stderr.lines().collect();
    match ran.code {
        Some(0) => true,
        Some(1) => {
            assert!(
                lines.len() == 1 && lines[0].contains(&file.display().to_string()),
                "{what}: {args:?}: the refusal is not one line naming {}: {}",
                file.display(),
                ran.stderr
            );
            false
        }
        code => panic!("{what}: {args:?} ended with {code:?}: {}", ran.stderr),
    }
}

/// Valid recordings holding hostile values (stretching factors of NaN, 0 and infinity, and the
/// rest of [`testing::values::crafted_recordings`]) through `analyze` (table, `--json`, `--csv`,
/// `--plot`) and `replay`: each is analyzed with finite numbers in every output or refused in
/// one line naming the file and the value, never a panic, a hang or a NaN (before: NaN and
/// infinities in the table and the CSV files, index out of bounds in `--plot`).
#[test]
fn valid_recordings_with_hostile_values_give_finite_outputs_or_one_line() {
    let dir = tempfile::tempdir().unwrap();
    let (mut analyzed, mut refused) = (Vec::new(), Vec::new());
    for (what, bytes) in testing::values::crafted_recordings() {
        let file = dir.path().join(format!("{}.mcap", what.replace(' ', "-")));
        std::fs::write(&file, bytes).unwrap();
        let f = file.to_str().unwrap();
        let ran = run_bounded(&["analyze", f]);
        if !succeeded_or_refused(&what, &["analyze", f], &file, &ran) {
            refused.push(format!("{what}: {}", ran.stderr.trim()));
            let out = dir.path().join("replay.mcap");
            let args = ["replay", f, "--tau", "0.2", "--out", out.to_str().unwrap()];
            let replayed = run_bounded(&args);
            assert!(!succeeded_or_refused(&what, &args, &file, &replayed));
            assert!(!out.exists(), "{what}: a failed replay left its output");
            continue;
        }
        let bad = non_finite_words(&ran.stdout);
        assert!(
            bad.is_empty(),
            "{what}: the table holds {bad:?}:\n{}",
            ran.stdout
        );
        let json = run_bounded(&["analyze", f, "--json"]);
        assert_eq!(json.code, Some(0), "{what}: {}", json.stderr);
        let mut nulls = Vec::new();
        unexpected_nulls(&serde_json::from_str(&json.stdout).unwrap(), "", &mut nulls);
        assert!(
            nulls.is_empty(),
            "{what}: non-finite JSON values at {nulls:?}"
        );
        let csv = dir.path().join(format!("csv-{}", what.replace(' ', "-")));
        let plot = dir.path().join(format!("plot-{}", what.replace(' ', "-")));
        for (flag, out) in [("--csv", &csv), ("--plot", &plot)] {
            let ran = run_bounded(&["analyze", f, flag, out.to_str().unwrap()]);
            assert_eq!(ran.code, Some(0), "{what} {flag}: {}", ran.stderr);
        }
        for entry in std::fs::read_dir(&csv)
            .unwrap()
            .chain(std::fs::read_dir(&plot).unwrap())
        {
            let path = entry.unwrap().path();
            if path.extension().is_some_and(|e| e == "png") {
                continue;
            }
            let text = std::fs::read_to_string(&path).unwrap();
            let bad = non_finite_words(&text);
            assert!(bad.is_empty(), "{what}: {} holds {bad:?}", path.display());
        }
        analyzed.push(what);
    }
    eprintln!(
        "{} crafted recordings: {} analyzed with finite outputs ({analyzed:?}), {} refused:\n{}",
        analyzed.len() + refused.len(),
        analyzed.len(),
        refused.len(),
        refused.join("\n")
    );
    // Every value no producer writes is refused; the valid edge case (rates beyond f64) is
    // analyzed, its rates reported as +-f64::MAX.
    assert_eq!(analyzed, ["rates beyond f64"]);
}

/// Valid map files holding hostile values (a header claiming 10^7 points per axis, axes near
/// 1e308, and the rest of [`testing::values::crafted_maps`]) through `merge --png`: each is
/// refused in one line naming the file and the field, never a panic, a hang or gigabytes
/// (before: the 10^7 header drove `merge --png` to 3.3 GB, axes near 1e308 never ended,
/// others panicked in plotting); the valid map merges and draws.
#[test]
fn valid_maps_with_hostile_values_are_refused_in_one_line() {
    let dir = tempfile::tempdir().unwrap();
    let (header, points) = testing::values::valid_map();
    let mut cases = testing::values::crafted_maps();
    let mut valid = MapFile::create(
        std::io::Cursor::new(Vec::new()),
        &header,
        &FileOptions::default(),
    )
    .unwrap();
    for p in &points {
        valid.write_point(p).unwrap();
    }
    cases.push(("valid".into(), valid.finish().unwrap().into_inner()));
    for (what, bytes) in cases {
        let file = dir.path().join(format!("{}.mcap", what.replace(' ', "-")));
        std::fs::write(&file, bytes).unwrap();
        let out = dir.path().join("merged.mcap");
        let png = dir.path().join("merged.png");
        let _ = std::fs::remove_file(&out);
        let args = [
            "merge",
            file.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
            "--png",
            png.to_str().unwrap(),
            "--allow-incomplete",
            "--force",
        ];
        let ran = run_bounded(&args);
        let merged = succeeded_or_refused(&what, &args, &file, &ran);
        assert_eq!(merged, what == "valid", "{what}: {}", ran.stderr);
        if merged {
            assert!(std::fs::metadata(&png).unwrap().len() > 1000);
        }
    }
}

/// Maps whose header and points hold values at the ends of f64 that a map file may hold (a
/// `gali-time` map of t_final near 1e308, so its colour bar spans it; values near 1e308 and
/// 1e-308 of every indicator; one value among many equal ones): `merge --png` draws each or
/// refuses it in one line naming the file, never a panic in plotting (before: a gali-time
/// map of t_final 1e308 panicked with `Option::unwrap()` on `None`, exit 101).
#[test]
fn maps_of_extreme_finite_values_draw_or_are_refused_in_one_line() {
    let dir = tempfile::tempdir().unwrap();
    type Edit = fn(&mut MapHeader, &mut Vec<MapPoint>);
    let cases: Vec<(&str, Edit)> = vec![
        ("gali-time of t_final 1e308", |h, p| {
            h.indicator = "gali-time".into();
            h.threshold = 1e-8;
            h.t_final = 1e308;
            for q in p.iter_mut() {
                q.value = 1e307;
                q.t_end = 1e308;
            }
        }),
        ("gali-time of t_final f64::MAX", |h, p| {
            h.indicator = "gali-time".into();
            h.threshold = 1e-8;
            h.t_final = f64::MAX;
            for (i, q) in p.iter_mut().enumerate() {
                q.value = f64::MAX / (1.0 + i as f64);
                q.t_end = f64::MAX;
            }
        }),
        ("gali-time of t_final 0", |h, p| {
            h.indicator = "gali-time".into();
            h.threshold = 1e-8;
            h.t_final = 0.0;
            for q in p.iter_mut() {
                q.value = 0.0;
                q.t_end = 0.0;
            }
        }),
        ("gali-time of t_final 5e-324", |h, p| {
            h.indicator = "gali-time".into();
            h.threshold = 1e-8;
            h.t_final = 5e-324;
            for q in p.iter_mut() {
                q.value = 5e-324;
                q.t_end = 5e-324;
            }
        }),
        ("gali-time threshold f64::MAX", |h, _| {
            h.indicator = "gali-time".into();
            h.threshold = f64::MAX;
        }),
        ("mle values near 1e308", |h, p| {
            h.indicator = "mle".into();
            for (i, q) in p.iter_mut().enumerate() {
                q.value = if i % 2 == 0 { f64::MAX } else { 1e-300 };
            }
        }),
        ("spectrum values at -1e308 and 1e308", |h, p| {
            h.indicator = "spectrum".into();
            h.k = 2;
            for (i, q) in p.iter_mut().enumerate() {
                q.value = if i % 2 == 0 { -f64::MAX } else { f64::MAX };
                q.spectrum = vec![q.value, -q.value];
            }
        }),
        ("fli values near 1e308", |h, p| {
            h.indicator = "fli".into();
            for (i, q) in p.iter_mut().enumerate() {
                q.value = if i % 3 == 0 { f64::MAX } else { -f64::MAX };
            }
        }),
        ("gali values of 5e-324", |_, p| {
            for q in p.iter_mut() {
                q.value = 5e-324;
            }
        }),
        ("sali values all equal", |h, p| {
            h.indicator = "sali".into();
            for q in p.iter_mut() {
                q.value = 0.5;
            }
        }),
        ("t_final f64::MAX", |h, _| h.t_final = f64::MAX),
    ];
    for (what, edit) in cases {
        let (mut header, mut points) = testing::values::valid_map();
        edit(&mut header, &mut points);
        let mut file = MapFile::create(
            std::io::Cursor::new(Vec::new()),
            &header,
            &FileOptions::default(),
        )
        .unwrap();
        for p in &points {
            file.write_point(p).unwrap();
        }
        let path = dir.path().join(format!("{}.mcap", what.replace(' ', "-")));
        std::fs::write(&path, file.finish().unwrap().into_inner()).unwrap();
        let (out, png) = (
            dir.path().join("merged.mcap"),
            dir.path().join("merged.png"),
        );
        let args = [
            "merge",
            path.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
            "--png",
            png.to_str().unwrap(),
            "--force",
        ];
        let ran = run_bounded(&args);
        if succeeded_or_refused(what, &args, &path, &ran) {
            assert!(std::fs::metadata(&png).unwrap().len() > 1000, "{what}");
        }
    }
}

/// Chart descriptions with ranges near the limits of f64 (data at +-1e308, fixed ranges of
/// infinite or zero width, reversed): drawn, or refused in one line naming the file, never a
/// hang (before: `chart` with ranges near 1e308 never ended).
#[test]
fn charts_with_extreme_ranges_end() {
    let dir = tempfile::tempdir().unwrap();
    let line = |points: &str| format!(r#"{{"lines": [{{"points": {points}, "stroke": "dots"}}]"#);
    let specs = [
        (
            "data at 1e308",
            format!("{}}}", line("[[-1e308, -1e308], [1e308, 1e308]]")),
        ),
        (
            "range of infinite width",
            format!(
                r#"{}, "x_range": [-1e308, 1e308]}}"#,
                line("[[0, 0], [1, 1]]")
            ),
        ),
        (
            "range of no width",
            format!(
                r#"{}, "y_range": [1e300, 1e300]}}"#,
                line("[[0, 0], [1, 1]]")
            ),
        ),
        (
            "reversed range",
            format!(r#"{}, "x_range": [1, 0]}}"#, line("[[0, 0], [1, 1]]")),
        ),
        (
            "data near the largest double",
            format!("{}}}", line("[[1.7976931348623157e308, 0], [1.7e308, 1]]")),
        ),
        (
            "one point far from a fixed range",
            format!(r#"{}, "x_range": [0, 1]}}"#, line("[[0, 0], [1e300, 1]]")),
        ),
    ];
    let (mut drawn, mut refused) = (0, 0);
    for (what, spec) in specs {
        let file = dir.path().join(format!("{}.json", what.replace(' ', "-")));
        std::fs::write(&file, spec).unwrap();
        let stem = dir.path().join(what.replace(' ', "-"));
        let args = [
            "chart",
            file.to_str().unwrap(),
            "--out",
            stem.to_str().unwrap(),
        ];
        let ran = run_bounded(&args);
        if succeeded_or_refused(what, &args, &file, &ran) {
            let svg = std::fs::read_to_string(stem.with_extension("svg")).unwrap();
            assert!(non_finite_words(&svg).is_empty(), "{what}");
            drawn += 1;
        } else {
            refused += 1;
        }
    }
    // The fixed ranges that cannot be drawn are refused, the data ranges drawn.
    assert_eq!((drawn, refused), (3, 3));
}

fn mkfifo(path: &Path) {
    use std::os::unix::ffi::OsStrExt;
    let c = std::ffi::CString::new(path.as_os_str().as_bytes()).unwrap();
    // SAFETY: a NUL-terminated path.
    assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o600) }, 0, "mkfifo");
}

/// `chaoscope args` refused at once: status 1 and one line naming `file` and saying it is
/// `what` ("a FIFO"), within [`run_bounded`]'s watchdog (a command that waits on the FIFO fails
/// the test instead of hanging it), leaving nothing at `outputs` (nor a `.partial` of them).
fn assert_refused_special(args: &[&str], file: &Path, what: &str, outputs: &[&Path]) {
    let ran = run_bounded(args);
    let lines: Vec<&str> = ran.stderr.lines().collect();
    assert_eq!(ran.code, Some(1), "{args:?}: {}", ran.stderr);
    assert!(
        lines.len() == 1
            && lines[0].contains(&file.display().to_string())
            && lines[0].contains(what),
        "{args:?}: not one line naming {} as {what}: {}",
        file.display(),
        ran.stderr
    );
    for out in outputs {
        let partial = format!("{}.partial", out.display());
        assert!(
            !out.exists() && !Path::new(&partial).exists(),
            "{args:?} left {} or its .partial",
            out.display()
        );
    }
}

/// Files that are not regular files wherever a command reads one: a FIFO (with no writer: a
/// blocking open never returns, and must not hang the command deaf to SIGINT and SIGTERM) as a
/// table named in a recording's embedded config (`replay`, `resume`; `analyze` goes on without
/// what it would add) or in a
/// config (`config`, `run`, `produce`, `map`, `section`), as the config itself, as the
/// recording (`analyze`, `analyze --clv`, `replay`, `resume`, `recover`), as a map shard
/// (`merge`) and as a chart description (`chart`); a character device and a directory where
/// a recording or a table belongs. Each is refused at once in one line naming the path and
/// what it is, with no output left behind.
#[test]
fn fifos_devices_and_directories_as_inputs_are_refused_at_once_in_one_line() {
    use chaoscope_schemas::config::{MapAxis, MapConfig, RunConfig};
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let s = |p: &Path| p.to_str().unwrap().to_string();
    let models = Path::new(env!("CARGO_MANIFEST_DIR")).join("examples/models");
    let csv = d.join("fput-bond.csv");
    std::fs::copy(models.join("fput-bond.csv"), &csv).unwrap();
    let text = std::fs::read_to_string(models.join("tabulated-bond.toml")).unwrap();
    let mut config = RunConfig::from_toml(&text).unwrap();
    config.integrator.t_final = 2.0;
    config.run.name = Some(common::unique_run("fifo-table"));
    let cfg = d.join("tabulated.toml");
    std::fs::write(&cfg, config.to_toml()).unwrap();
    let rec = d.join("tabulated.mcap");
    common::run_ok(&["run", &s(&cfg), "--out", &s(&rec)]);
    config.schemes.retain(|s| s.method == "mpm");
    config.map = Some(MapConfig {
        k: Some(2),
        ..MapConfig::new(
            MapAxis::new("q2", -0.2, 0.2, 3),
            MapAxis::new("p2", -0.2, 0.2, 2),
            "gali",
        )
    });
    let map_cfg = d.join("map.toml");
    std::fs::write(&map_cfg, config.to_toml()).unwrap();

    // The table the recording and the configs name becomes a FIFO no one writes.
    std::fs::remove_file(&csv).unwrap();
    mkfifo(&csv);
    let out = d.join("out.mcap");
    let o = s(&out);
    let (r, c, m) = (s(&rec), s(&cfg), s(&map_cfg));
    // `analyze` reads the table only for what it adds (flow field, site energies): without it
    // the analysis of what the recording holds goes on, at once, saying in one line what is
    // left out and why (the table, a FIFO).
    let analyze_without_table = |what: &str| {
        let ran = run_bounded(&["analyze", &r, "--json"]);
        assert_eq!(ran.code, Some(0), "analyze: {}", ran.stderr);
        let report: serde_json::Value = serde_json::from_str(ran.stdout.trim())
            .unwrap_or_else(|e| panic!("analyze --json: {e}: {}", ran.stdout));
        assert!(report["schemes"].is_array(), "{report}");
        let lines: Vec<&str> = ran.stderr.lines().collect();
        assert!(
            lines.len() == 1
                && lines[0].contains("warning")
                && lines[0].contains("no flow field and no site energies")
                && lines[0].contains(&csv.display().to_string())
                && lines[0].contains(what),
            "analyze: not one warning naming what is missing and why ({what}): {}",
            ran.stderr
        );
    };
    analyze_without_table("a FIFO");
    let table_cases: [Vec<&str>; 7] = [
        vec!["replay", &r, "--tau", "0.5", "--out", &o],
        vec!["resume", &r, "--t-final", "4", "--out", &o],
        vec!["config", &c],
        vec!["run", &c, "--out", &o],
        vec!["produce", &c],
        vec!["map", &m, "--out", &o],
        vec!["section", &c, "--surface", "q1", "--csv", &o],
    ];
    for args in &table_cases {
        assert_refused_special(args, &csv, "a FIFO", &[&out]);
    }

    // The file a command is given is a FIFO.
    let fifo_toml = d.join("config.toml");
    let fifo_mcap = d.join("recording.mcap");
    let fifo_json = d.join("chart.json");
    for f in [&fifo_toml, &fifo_mcap, &fifo_json] {
        mkfifo(f);
    }
    let (ft, fm, fj) = (s(&fifo_toml), s(&fifo_mcap), s(&fifo_json));
    for args in [
        vec!["config", &ft],
        vec!["run", &ft, "--out", &o],
        vec!["produce", &ft],
        vec!["map", &ft, "--out", &o],
        vec!["section", &ft, "--surface", "q1", "--csv", &o],
    ] {
        assert_refused_special(&args, &fifo_toml, "a FIFO", &[&out]);
    }
    for args in [
        vec!["analyze", &fm],
        vec!["analyze", &fm, "--clv"],
        vec!["replay", &fm, "--tau", "0.5", "--out", &o],
        vec!["resume", &fm, "--t-final", "4", "--out", &o],
        vec!["recover", &fm, "--out", &o],
        vec!["merge", &fm, "--out", &o],
    ] {
        assert_refused_special(&args, &fifo_mcap, "a FIFO", &[&out]);
    }
    assert_refused_special(
        &["chart", &fj, "--out", &s(&d.join("chart"))],
        &fifo_json,
        "a FIFO",
        &[&d.join("chart.png"), &d.join("chart.svg")],
    );

    // A device (which reads forever) and a directory, where a recording or a table belongs.
    let zero = Path::new("/dev/zero");
    assert_refused_special(&["analyze", "/dev/zero"], zero, "a character device", &[]);
    assert_refused_special(&["config", "/dev/zero"], zero, "a character device", &[]);
    std::fs::remove_file(&csv).unwrap();
    std::fs::create_dir(&csv).unwrap();
    analyze_without_table("a directory");
    assert_refused_special(
        &["replay", &r, "--tau", "0.5", "--out", &o],
        &csv,
        "a directory",
        &[&out],
    );
    assert_refused_special(&["config", &c], &csv, "a directory", &[]);
}

/// A short run on a square lattice (`chaoscope run` in a private bus domain) into `dir`:
/// `lattice = "square"` with side `n`, or the same DDNLS on a chain of `n` sites.
fn ddnls_recording(dir: &Path, lattice: &str, n: usize) -> String {
    let config = dir.join(format!("{lattice}.toml"));
    let block = if lattice == "square" {
        "[3, 4]"
    } else {
        "[4, 5]"
    };
    std::fs::write(
        &config,
        format!(
            "[run]\nname = \"plane-{lattice}\"\n[model]\nname = \"ddnls\"\nlattice = \
             \"{lattice}\"\nn = {n}\nW = 10.0\nbeta = 1.0\nseed = 3\n[orbit]\nexcite = {{ sites \
             = {block}, norm = 4.0, seed = 2 }}\n[integrator]\nmethod = \"s11abc6\"\nh = 0.05\n\
             t_final = 20.0\n[deviations]\nk = 1\nsets = 1\nseed = 5\n[[scheme]]\nname = \
             \"vm\"\nmethod = \"vm\"\nd0 = 1e-8\ntau = 1.0\n"
        ),
    )
    .unwrap();
    let out = dir.join(format!("{lattice}.mcap"));
    let bus = dir.join(format!("bus-{lattice}"));
    std::fs::create_dir_all(&bus).unwrap();
    let ran = Command::new(CHAOSCOPE)
        .args([
            "run",
            config.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
        ])
        .env("CHAOSCOPE_BUS_DIR", &bus)
        .output()
        .unwrap();
    assert!(
        ran.status.success(),
        "{}",
        String::from_utf8_lossy(&ran.stderr)
    );
    assert!(common::close_private_bus(&bus).is_empty());
    out.to_str().unwrap().to_string()
}

/// `analyze --plot` on a run over an 8 x 8 square lattice draws the norm and the DVD over the
/// plane as one PNG per time (the times asked, or by default four a decade apart ending at the
/// run's end, t_final = 20: 0.02, 0.2, 2, 20), and no space-time picture of the flattened site
/// index. Hostile `--plane-times` (after the run's end, negative, NaN, not a number, without
/// --plot, on a chain) are refused naming the problem (exit 1, or 64 for a usage error), and
/// nothing is drawn.
#[test]
fn plane_heat_maps_of_a_square_lattice_and_hostile_plane_times() {
    let dir = tempfile::tempdir().unwrap();
    let square = ddnls_recording(dir.path(), "square", 8);
    let plot = dir.path().join("plot");
    let p = plot.to_str().unwrap();
    let ran = run_bounded(&["analyze", &square, "--plot", p, "--plane-times", "0,10,20"]);
    assert_eq!(ran.code, Some(0), "{}", ran.stderr);
    for t in ["0", "10", "20"] {
        let png = std::fs::read(plot.join(format!("plane-t{t}.png"))).unwrap();
        assert_eq!(&png[..8], b"\x89PNG\r\n\x1a\n", "plane-t{t}.png");
    }
    assert!(plot.join("norm_m2.png").exists());
    assert!(!plot.join("distributions.png").exists());
    std::fs::remove_dir_all(&plot).unwrap();
    let ran = run_bounded(&["analyze", &square, "--plot", p]);
    assert_eq!(ran.code, Some(0), "{}", ran.stderr);
    for t in ["0.02", "0.2", "2", "20"] {
        assert!(
            plot.join(format!("plane-t{t}.png")).exists(),
            "plane-t{t}.png"
        );
    }
    std::fs::remove_dir_all(&plot).unwrap();

    let chain = ddnls_recording(dir.path(), "chain", 9);
    for (args, code, problem) in [
        (
            vec![&square[..], "--plot", p, "--plane-times", "30"],
            1,
            "--plane-times 30: after the run's end, t = 20",
        ),
        // Quoted as written, not as 309 digits.
        (
            vec![&square[..], "--plot", p, "--plane-times", "1e308"],
            1,
            "--plane-times 1e308: after the run's end",
        ),
        (
            vec![&square[..], "--plot", p, "--plane-times", "5,-1"],
            1,
            "--plane-times -1: a time from 0 on",
        ),
        (
            vec![&square[..], "--plot", p, "--plane-times", "NaN"],
            1,
            "--plane-times NaN: a time from 0 on",
        ),
        (
            vec![&square[..], "--plot", p, "--plane-times", "1,x"],
            64,
            "invalid value 'x'",
        ),
        (vec![&square[..], "--plane-times", "1"], 64, "--plot <DIR>"),
        // --at as --from: a NaN or negative time once reported t = 0 as if asked for.
        (
            vec![&square[..], "--at", "nan"],
            1,
            "--at NaN: a time from 0 on",
        ),
        (vec![&square[..], "--at=-1"], 1, "--at -1: a time from 0 on"),
        (
            vec![&square[..], "--at=-inf"],
            1,
            "--at -inf: a time from 0 on",
        ),
        (
            vec![&chain[..], "--plot", p, "--plane-times", "1"],
            1,
            "a chain of 9 sites",
        ),
    ] {
        let mut all = vec!["analyze"];
        all.extend(args);
        let ran = run_bounded(&all);
        assert_eq!(ran.code, Some(code), "{all:?}: {}", ran.stderr);
        assert!(ran.stderr.contains(problem), "{all:?}: {}", ran.stderr);
        assert!(!ran.stderr.contains("panicked"), "{all:?}: {}", ran.stderr);
        assert!(!plot.exists(), "{all:?} drew");
    }
    // A chain without the flag keeps its space-time picture.
    let ran = run_bounded(&["analyze", &chain, "--plot", p]);
    assert_eq!(ran.code, Some(0), "{}", ran.stderr);
    assert!(plot.join("distributions.png").exists());
    assert!(!plot.join("plane-t20.png").exists());
}
