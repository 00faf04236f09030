//! `chaoscope map` publishes its points live: a `chaoscope map-watch` process started before
//! the map receives the header, the points (bit-identical to the MCAP recording) and the end
//! record, with sequence numbers accounting for every point published.

use std::collections::BTreeMap;
use std::io::{BufRead, BufReader};
use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::sync::mpsc;
use std::time::{Duration, Instant};

use crate::common;

use chaoscope_bus as bus;
use chaoscope_files::map_file::read_map_file;
use chaoscope_schemas::proto::MapPoint;

const CHAOSCOPE: &str = env!("CARGO_BIN_EXE_chaoscope");

/// A small HH map (9 x 7 points, t = 20) shared by the map tests.
const CONFIG: &str = include_str!("data/hh-map-small.toml");

const GRID: u64 = 63;

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// A watcher of map `name`, started and subscribed (its stderr says so) before this returns.
struct Watcher {
    child: Child,
    stdout: std::thread::JoinHandle<Vec<serde_json::Value>>,
}

impl Watcher {
    fn start(name: &str) -> Self {
        let mut child = Command::new(CHAOSCOPE)
            .args(["map-watch", name, "--json-lines", "--wait-timeout", "60"])
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .expect("map-watch starts");
        let stdout = child.stdout.take().unwrap();
        let stdout = std::thread::spawn(move || {
            BufReader::new(stdout)
                .lines()
                .map(|l| serde_json::from_str(&l.unwrap()).expect("a JSON line"))
                .collect()
        });
        let (tx, rx) = mpsc::channel();
        let stderr = child.stderr.take().unwrap();
        std::thread::spawn(move || {
            for line in BufReader::new(stderr).lines().map_while(Result::ok) {
                eprintln!("watcher: {line}");
                if line.contains("following map") {
                    let _ = tx.send(());
                }
            }
        });
        rx.recv_timeout(Duration::from_secs(30))
            .expect("the watcher subscribes");
        Self { child, stdout }
    }

    /// The watcher's JSON lines, once it exited by itself (after the end record).
    fn finish(mut self) -> Vec<serde_json::Value> {
        let start = Instant::now();
        let status = loop {
            if let Some(status) = self.child.try_wait().unwrap() {
                break status;
            }
            if start.elapsed() > Duration::from_secs(30) {
                let _ = self.child.kill();
                panic!("the watcher did not end after the map");
            }
            std::thread::sleep(Duration::from_millis(20));
        };
        assert!(status.success(), "map-watch exited with {status}");
        self.stdout.join().unwrap()
    }
}

fn map(args: &[&str]) -> std::process::Output {
    Command::new(CHAOSCOPE)
        .arg("map")
        .args(args)
        .output()
        .expect("chaoscope map runs")
}

fn recorded(path: &Path) -> BTreeMap<u64, MapPoint> {
    let contents = read_map_file(path).unwrap();
    contents.points.into_iter().map(|p| (p.index, p)).collect()
}

/// Checks the watcher's lines against the recording; returns the end line.
fn check_stream(lines: &[serde_json::Value], file: &BTreeMap<u64, MapPoint>) -> serde_json::Value {
    assert_eq!(lines[0]["type"], "header", "first line: {}", lines[0]);
    assert_eq!(lines[0]["grid_points"], GRID);
    assert_eq!(lines[0]["indicator"], "gali-time");
    let end = lines.last().unwrap().clone();
    assert_eq!(end["type"], "end");
    let points: Vec<_> = lines.iter().filter(|l| l["type"] == "point").collect();
    assert_eq!(points.len() + 2, lines.len());
    let mut seqs = std::collections::BTreeSet::new();
    for p in &points {
        let seq = p["seq"].as_u64().unwrap();
        assert!(seqs.insert(seq), "seq {seq} twice");
        let index = p["index"].as_u64().unwrap();
        let want = file
            .get(&index)
            .unwrap_or_else(|| panic!("point {index} not in the file"));
        assert_eq!(
            p["status"],
            want.status().as_str_name().to_ascii_lowercase()
        );
        match p["value"].as_f64() {
            Some(v) => assert_eq!(v.to_bits(), want.value.to_bits(), "point {index}"),
            None => assert!(
                want.value.is_nan(),
                "point {index}: null for {}",
                want.value
            ),
        }
        assert_eq!(p["x"].as_f64().unwrap().to_bits(), want.x.to_bits());
        assert_eq!(p["y"].as_f64().unwrap().to_bits(), want.y.to_bits());
    }
    let published = end["published"].as_u64().unwrap();
    let received = end["received"].as_u64().unwrap();
    let missed = end["missed"].as_u64().unwrap();
    assert_eq!(received, points.len() as u64);
    assert_eq!(received + missed, published, "{end}");
    assert!(seqs.iter().all(|&s| s < published));
    // Lossy by design, but an idle 63-point stream into a 1024-point buffer loses little.
    assert!(received * 2 > published, "{end}");
    end
}

#[test]
fn a_watcher_follows_a_map_live() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let cfg = d.join("map.toml");
    std::fs::write(&cfg, CONFIG).unwrap();

    // A whole map: every point published once, values as in the file.
    let name = common::unique_run("map");
    let watcher = Watcher::start(&name);
    let out = d.join("whole.mcap");
    let run = map(&[
        s(&cfg),
        "--out",
        s(&out),
        "--name",
        &name,
        "--threads",
        "2",
        "--no-progress",
    ]);
    assert!(
        run.status.success(),
        "{}",
        String::from_utf8_lossy(&run.stderr)
    );
    let lines = watcher.finish();
    let file = recorded(&out);
    assert_eq!(file.len() as u64, GRID);
    let end = check_stream(&lines, &file);
    assert_eq!(end["status"], "completed");
    assert_eq!(end["published"], GRID);

    // Interrupted after 10 points, then resumed: the resumed run publishes the recorded points
    // first, then the new ones, and the union is the whole map.
    let out = d.join("resumed.mcap");
    let watcher = Watcher::start(&name);
    let first = map(&[
        s(&cfg),
        "--out",
        s(&out),
        "--name",
        &name,
        "--no-progress",
        "--stop-after",
        "10",
    ]);
    assert_eq!(first.status.code(), Some(130));
    let lines = watcher.finish();
    let partial = recorded(&out);
    let end = check_stream(&lines, &partial);
    assert_eq!(end["status"], "interrupted");
    assert_eq!(end["published"].as_u64().unwrap(), partial.len() as u64);

    let watcher = Watcher::start(&name);
    let second = map(&[s(&cfg), "--out", s(&out), "--name", &name, "--no-progress"]);
    assert!(second.status.success());
    let lines = watcher.finish();
    let end = check_stream(&lines, &recorded(&out));
    assert_eq!(end["status"], "completed");
    assert_eq!(end["published"], GRID);

    // Nothing of the map is left on the bus once its processes are gone.
    std::thread::sleep(Duration::from_millis(200));
    assert!(
        !bus::list_maps().contains(&name),
        "map services left behind: {:?}",
        bus::list_maps()
    );
}

/// Two maps of one name: both compute their map, and the one that finds the other on the bus
/// goes without a live stream, saying so with an error that names the map and the other
/// process. Started while the first is on the bus, the second is refused by the liveness
/// check; started at the same moment, both pass that check, and the one that opens the bus
/// second finds the other's publishers in place (never iceoryx2's slot error is shown).
#[test]
fn a_second_map_of_a_name_goes_without_a_live_stream_and_says_why() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    // GALI at a fixed time ("gali-time" stops every orbit of this map within milliseconds), so
    // that a map takes a while: about 0.1 s at t = 1000.
    let config = |t_final: &str| {
        let path = d.join(format!("map-{t_final}.toml"));
        let text = CONFIG
            .replace("t_final = 20.0", &format!("t_final = {t_final}"))
            .replace("indicator = \"gali-time\"", "indicator = \"gali\"")
            .replace("threshold = 0.05\n", "");
        std::fs::write(&path, text).unwrap();
        path
    };
    let start = |cfg: &Path, name: &str, out: &str| {
        Command::new(CHAOSCOPE)
            .args(["map", s(cfg), "--out", s(&d.join(out)), "--name", name])
            .args(["--threads", "1", "--no-progress"])
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap()
    };
    // Its stderr; the map itself is always computed.
    let outcome = |child: Child| {
        let out = child.wait_with_output().unwrap();
        let err = String::from_utf8_lossy(&out.stderr).into_owned();
        assert!(out.status.success(), "{err}");
        err
    };
    let refused = |err: &str, name: &str| {
        err.contains("no live stream")
            && err.contains("already being published")
            && err.contains(name)
    };

    // One after the other: the first is on the bus (a map of about 2 s).
    let name = common::unique_run("map-twice");
    let long = config("20000.0");
    let first = start(&long, &name, "first.mcap");
    common::wait_for_node(&chaoscope_schemas::names::map_node_name(&name));
    let err = outcome(start(&long, &name, "second.mcap"));
    assert!(refused(&err, &name), "{err}");
    let err = outcome(first);
    assert!(!err.contains("no live stream"), "{err}");

    // At the same moment.
    let short = config("1000.0");
    let mut met = 0;
    for i in 0..4 {
        let name = common::unique_run("map-together");
        let (a, b) = (
            start(&short, &name, &format!("a{i}.mcap")),
            start(&short, &name, &format!("b{i}.mcap")),
        );
        let errors = [outcome(a), outcome(b)];
        for err in &errors {
            assert!(
                !err.contains("no live stream") || refused(err, &name),
                "{errors:?}"
            );
        }
        met += errors.iter().filter(|e| refused(e, &name)).count();
    }
    eprintln!("{met} of 4 pairs started together met on the bus");
}
