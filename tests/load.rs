//! Issue #13, point 4: load. Four `chaoscope run`s and two `chaoscope map`s at once on a 2-core
//! machine, while monitors (`chaoscope monitor`, the lossy service) and map watchers attach and
//! detach in a loop, some detaching by SIGKILL, do not interfere: every run has its own
//! services, and every recording and map holds exactly the messages of the same run or map made
//! alone.
//!
//! Compared are the messages (topic, sequence, log time = simulation time, payload bytes), not
//! the file bytes: a recording's chunks are closed by size and by wall-clock time (at least every
//! second), and each message's MCAP `publish_time` is the wall-clock time it was written, so two
//! recordings of the same run legitimately differ in chunk boundaries and publish times only. Map
//! points are compared by grid index: the order in which points finish depends on scheduling.

mod common;

use std::collections::BTreeMap;
use std::path::Path;
use std::process::Command;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::time::{Duration, Instant};

use chaoscope_bus::BUS_DIR_ENV;
use chaoscope_files::map_file::read_map_file;
use chaoscope_schemas::names::topic;
use common::*;
use prost::Message;

const LIMIT: Duration = Duration::from_secs(120);
const MAP: &str = include_str!("data/hh-map-small.toml");

/// (topic, sequence, log time, payload) of every message but how the recording ended
/// (`/chaoscope/recording` also counts frames received, which is the same; kept), in file order.
type Messages = Vec<(String, u32, u64, Vec<u8>)>;

fn messages(path: &Path) -> Messages {
    let bytes = std::fs::read(path).unwrap();
    mcap::MessageStream::new(&bytes)
        .unwrap()
        .map(|m| {
            let m = m.unwrap();
            (
                m.channel.topic.clone(),
                m.sequence,
                m.log_time,
                m.data.into_owned(),
            )
        })
        .collect()
}

/// Map header bytes and points by grid index.
fn map_points(path: &Path) -> (Vec<u8>, BTreeMap<u64, Vec<u8>>) {
    let contents = read_map_file(path).unwrap();
    assert!(contents.damaged.is_none(), "{}: damaged", path.display());
    let header = contents.header.unwrap().encode_to_vec();
    let points = contents
        .points
        .iter()
        .map(|p| (p.index, p.encode_to_vec()))
        .collect();
    (header, points)
}

struct Job {
    name: String,
    config: std::path::PathBuf,
    map: bool,
}

fn command(job: &Job, out: &Path, bus: &Path) -> Command {
    let cfg = job.config.to_str().unwrap();
    let out = out.to_str().unwrap();
    let mut c = if job.map {
        chaoscope(&[
            "map",
            cfg,
            "--out",
            out,
            "--name",
            &job.name,
            "--threads",
            "1",
            "--no-progress",
        ])
    } else {
        chaoscope(&["run", cfg, "--run", &job.name, "--out", out])
    };
    c.env(BUS_DIR_ENV, bus);
    c
}

/// How many shared-memory segments with `prefix` exist, iceoryx2's node counter aside.
fn segments_of(prefix: &str) -> usize {
    domain_segments(prefix)
        .iter()
        .filter(|name| !is_node_counter(name))
        .count()
}

#[test]
fn four_runs_and_two_maps_at_once_with_monitors_coming_and_going_match_runs_made_alone() {
    let started = Instant::now();
    let work = tempfile::tempdir().unwrap();
    let bus = tempfile::Builder::new()
        .prefix("load-bus")
        .tempdir()
        .unwrap();
    let tag = unique_run("load");
    let mut jobs = Vec::new();
    // Four different runs (orbit length, tau, sets): distinct services, distinct data.
    for (i, (t_final, tau)) in [(30.0, 0.01), (40.0, 0.02), (25.0, 0.01), (50.0, 0.05)]
        .into_iter()
        .enumerate()
    {
        let dir = work.path().join(format!("run{i}"));
        std::fs::create_dir(&dir).unwrap();
        let mut cfg = hh_config(t_final, tau);
        cfg.deviations.seed = 100 + i as u64;
        jobs.push(Job {
            name: format!("{tag}-r{i}"),
            config: write_config(&dir, &cfg.to_toml()),
            map: false,
        });
    }
    for i in 0..2 {
        let path = work.path().join(format!("map{i}.toml"));
        std::fs::write(&path, MAP.replace("seed = 5", &format!("seed = {}", 5 + i))).unwrap();
        jobs.push(Job {
            name: format!("{tag}-m{i}"),
            config: path,
            map: true,
        });
    }

    // Alone, one after the other, nobody watching.
    let alone = work.path().join("alone");
    std::fs::create_dir(&alone).unwrap();
    let t = Instant::now();
    for job in &jobs {
        let out = alone.join(format!("{}.mcap", job.name));
        let status = command(job, &out, bus.path()).status().unwrap();
        assert!(status.success(), "{} alone: {status}", job.name);
    }
    let alone_time = t.elapsed();

    // All at once, with monitors and watchers attaching and detaching all the time.
    let together = work.path().join("together");
    std::fs::create_dir(&together).unwrap();
    let stop = Arc::new(AtomicBool::new(false));
    let attached = Arc::new(AtomicUsize::new(0));
    let watchers: Vec<_> = jobs
        .iter()
        .enumerate()
        .map(|(i, job)| {
            let (name, map) = (job.name.clone(), job.map);
            let (stop, attached) = (Arc::clone(&stop), Arc::clone(&attached));
            let bus = bus.path().to_path_buf();
            std::thread::spawn(move || {
                let mut n = 0u64;
                while !stop.load(Ordering::Relaxed) {
                    let mut c = if map {
                        chaoscope(&["map-watch", &name, "--json-lines", "--wait-timeout", "5"])
                    } else {
                        chaoscope(&["monitor", &name, "--json-lines", "--wait-timeout", "5"])
                    };
                    c.env(BUS_DIR_ENV, &bus).stderr(std::process::Stdio::null());
                    let mut watcher = Proc::spawn(c);
                    // Attached for 50..350 ms, then gone: every third one killed outright.
                    let ms = 50 + (n * 97 + i as u64 * 31) % 300;
                    std::thread::sleep(Duration::from_millis(ms));
                    let signal = if n % 3 == 2 {
                        libc::SIGKILL
                    } else {
                        libc::SIGINT
                    };
                    watcher.signal(signal);
                    let status = watcher.wait(Duration::from_secs(30));
                    assert_ne!(status.code(), Some(101), "{name}: a watcher panicked");
                    attached.fetch_add(1, Ordering::Relaxed);
                    n += 1;
                }
            })
        })
        .collect();
    let t = Instant::now();
    let mut procs: Vec<_> = jobs
        .iter()
        .map(|job| {
            let out = together.join(format!("{}.mcap", job.name));
            Proc::spawn(command(job, &out, bus.path()))
        })
        .collect();
    for (job, p) in jobs.iter().zip(&mut procs) {
        let status = p.wait(LIMIT);
        assert!(status.success(), "{} under load: {status}", job.name);
    }
    let together_time = t.elapsed();
    stop.store(true, Ordering::Relaxed);
    for w in watchers {
        w.join().expect("watcher loop");
    }

    for job in &jobs {
        let a = alone.join(format!("{}.mcap", job.name));
        let b = together.join(format!("{}.mcap", job.name));
        if job.map {
            let (ha, pa) = map_points(&a);
            let (hb, pb) = map_points(&b);
            assert_eq!(ha, hb, "{}: map header", job.name);
            assert_eq!(pa.len(), 63, "{}: grid points", job.name);
            assert!(pa == pb, "{}: points differ under load", job.name);
        } else {
            let (ma, mb) = (messages(&a), messages(&b));
            assert!(ma.len() > 1000, "{}: {} messages", job.name, ma.len());
            assert_eq!(ma.len(), mb.len(), "{}: message count", job.name);
            for (x, y) in ma.iter().zip(&mb) {
                assert!(x == y, "{}: message {:?} differs under load", job.name, x.0);
            }
            let rec = read_recording(&b);
            let s = rec.recording.unwrap();
            assert_eq!(
                (s.run_status.as_str(), s.frames_missing),
                ("completed", 0),
                "{}",
                job.name
            );
            assert!(mb.iter().any(|m| m.0 == topic::END));
        }
    }
    // Last, a watcher of a map that never comes, killed outright: nobody starts after it, so
    // its node and the services it made (a watcher started before its map makes them) stay in
    // shared memory until the next process of this domain cleans up first thing, which
    // `close_private_bus` does here. Nothing may be left then, of it or of any watcher above.
    let mut late = chaoscope(&["map-watch", &format!("{tag}-late"), "--wait-timeout", "60"]);
    late.env(BUS_DIR_ENV, bus.path());
    let mut late = Proc::spawn(late);
    let prefix = chaoscope_bus::domain_at(bus.path()).unwrap().prefix;
    let start = Instant::now();
    // Its second segment is the points service's: it has made both of its services.
    while segments_of(&prefix) < 2 {
        assert!(
            start.elapsed() < LIMIT,
            "the late watcher never made its services"
        );
        std::thread::sleep(Duration::from_millis(10));
    }
    late.signal(libc::SIGKILL);
    late.wait(LIMIT);
    assert!(
        segments_of(&prefix) >= 2,
        "the killed watcher left nothing to clean"
    );
    let left = close_private_bus(bus.path());
    assert!(left.is_empty(), "segments left after cleanup: {left:#?}");
    eprintln!(
        "load: 4 runs + 2 maps alone {:.1} s, together {:.1} s with {} monitor/watcher \
         attachments; {:.1} s wall",
        alone_time.as_secs_f64(),
        together_time.as_secs_f64(),
        attached.load(Ordering::Relaxed),
        started.elapsed().as_secs_f64()
    );
}
