//! `examples/slurm/map-array.sh` on a real Slurm cluster: the array tasks and the merge job run
//! under Slurm, one task is requeued mid-run (Slurm kills it and starts it again) and resumes
//! from its shard's recording, and the merged map equals the unsharded map bit for bit.
//!
//! It needs a running cluster, so it is ignored by a plain `cargo test`; CI starts a one-node
//! cluster and runs it (`.ci/run`):
//!
//! ```text
//! sudo tests/slurm/start-cluster.sh
//! cargo test --release --test slurm_cluster -- --ignored
//! ```

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::{Duration, Instant};

use chaoscope_files::map_file::read_map_file;

mod common;
use common::{map_points, run_command as run};

/// The paper's Henon-Heiles GALI_2 map at a size where each of two shards computes for about
/// ten seconds on one core of a quiet Zen 5 (t = 2000; at t = 500 a shard ended 2-3 s after
/// its first chunk, before the test could requeue it): long enough to requeue a task after its
/// first chunk is on disk (written after `--flush-interval`, 2 s).
const CONFIG: &str = r#"
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
t_final = 2000.0

[deviations]
k = 2
sets = 50
seed = 1

[[scheme]]
name = "mpm"
method = "mpm"
d0 = 1e-8
tau = 1.0

[map]
x = { coord = "q2", min = -0.45, max = 0.65, n = 24 }
y = { coord = "p2", min = -0.45, max = 0.45, n = 16 }
indicator = "gali"
k = 2
"#;

const SHARDS: usize = 2;

/// Points already on disk in a shard that is being written (complete chunks only).
fn points_on_disk(path: &Path) -> usize {
    read_map_file(path).map(|c| c.points.len()).unwrap_or(0)
}

/// `scontrol show job` fields of one job (or array task), `None` once Slurm forgot it.
fn job_fields(job: &str) -> Option<BTreeMap<String, String>> {
    let out = Command::new("scontrol")
        .args(["show", "job", "--oneliner", job])
        .output()
        .ok()?;
    if !out.status.success() {
        return None;
    }
    let text = String::from_utf8_lossy(&out.stdout);
    let fields = text
        .split_whitespace()
        .filter_map(|kv| kv.split_once('='))
        .map(|(k, v)| (k.to_string(), v.to_string()))
        .collect::<BTreeMap<_, _>>();
    (!fields.is_empty()).then_some(fields)
}

fn wait_until(what: &str, timeout: Duration, mut done: impl FnMut() -> bool) {
    let start = Instant::now();
    while !done() {
        assert!(start.elapsed() < timeout, "timed out waiting for {what}");
        std::thread::sleep(Duration::from_millis(200));
    }
}

fn state(job: &str) -> String {
    job_fields(job)
        .and_then(|f| f.get("JobState").cloned())
        .unwrap_or_default()
}

#[test]
#[ignore = "needs a running Slurm cluster: tests/slurm/start-cluster.sh (root), then --ignored"]
fn map_array_under_slurm_requeues_a_task_resumes_it_and_merges_bit_identically() {
    let sinfo = Command::new("sinfo").arg("-h").output();
    assert!(
        matches!(&sinfo, Ok(o) if o.status.success()),
        "no Slurm cluster answers (sinfo failed); start one with tests/slurm/start-cluster.sh"
    );
    let bin = PathBuf::from(env!("CARGO_BIN_EXE_chaoscope"));
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let cfg = d.join("map.toml");
    std::fs::write(&cfg, CONFIG).unwrap();

    // The reference: the same map unsharded, outside Slurm.
    let whole = d.join("whole.mcap");
    run(Command::new(&bin)
        .args(["map", "--no-progress", "--threads", "2", "--out"])
        .arg(&whole)
        .arg(&cfg));
    let want = map_points(&whole);
    assert_eq!(want.len(), 24 * 16);

    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("examples/slurm/map-array.sh");
    let out_dir = d.join("out");
    let submitted = run(Command::new(&script)
        .arg(&cfg)
        .arg(&out_dir)
        .arg(SHARDS.to_string())
        .env("CHAOSCOPE", &bin)
        .env("CPUS_PER_TASK", "1")
        .env("MEM_PER_CPU", "200M")
        .env("TIME_LIMIT", "00:10:00"));
    let ids = submitted
        .lines()
        .find_map(|l| l.strip_prefix("array_job="))
        .expect("the script prints the job ids");
    let (array_job, merge_job) = ids
        .split_once(" merge_job=")
        .map(|(a, m)| (a.trim().to_string(), m.trim().to_string()))
        .expect("array_job=A merge_job=M");
    let task0 = format!("{array_job}_0");

    // Requeue task 0 once it has written at least one chunk and is still computing.
    // A running map writes `shard-0.mcap.partial` (renamed to `shard-0.mcap` when it ends).
    let shard0 = chaoscope_os::output::partial_path(&out_dir.join("shard-0.mcap"));
    wait_until(
        "task 0 to write its first chunk",
        Duration::from_secs(120),
        || points_on_disk(&shard0) > 0,
    );
    let before = points_on_disk(&shard0);
    assert_eq!(
        state(&task0),
        "RUNNING",
        "task 0 finished before it could be requeued: make the map larger"
    );
    assert!(before < want.len() / SHARDS, "task 0 is already done");
    run(Command::new("scontrol").args(["requeue", &task0]));
    // Slurm holds a requeued job back (its begin time moves minutes ahead, so the old
    // instance can be cleaned up); let it start again as soon as it is pending. slurmd refuses
    // a launch credential issued in the same second as the revocation of the old one, hence the
    // pause.
    wait_until(
        "task 0 to be pending again",
        Duration::from_secs(60),
        || state(&task0) == "PENDING",
    );
    std::thread::sleep(Duration::from_secs(2));
    run(Command::new("scontrol").args(["update", &format!("JobId={task0}"), "StartTime=now"]));

    // Everything finishes: both tasks, then the merge job (afterok on the whole array).
    wait_until("the merge job", Duration::from_secs(300), || {
        for i in 0..SHARDS {
            let s = state(&format!("{array_job}_{i}"));
            assert!(
                !matches!(s.as_str(), "FAILED" | "CANCELLED" | "TIMEOUT" | "NODE_FAIL"),
                "array task {i} {s}: {}",
                std::fs::read_to_string(out_dir.join(format!("logs/shard-{i}.out")))
                    .unwrap_or_default()
            );
        }
        let s = state(&merge_job);
        assert!(
            !matches!(s.as_str(), "FAILED" | "CANCELLED" | "TIMEOUT" | "NODE_FAIL"),
            "merge job {s}: {}",
            std::fs::read_to_string(out_dir.join("logs/merge.out")).unwrap_or_default()
        );
        s == "COMPLETED"
    });
    for i in 0..SHARDS {
        let task = format!("{array_job}_{i}");
        assert_eq!(state(&task), "COMPLETED", "task {i}");
    }
    let restarts = job_fields(&task0).unwrap()["Restarts"].clone();
    assert_eq!(restarts, "1", "task 0 ran twice (requeued once)");

    // The requeued task resumed from its recording instead of starting over: its second run's
    // summary (the log is rewritten by the rerun) counts the points it found on disk.
    let log0 = std::fs::read_to_string(out_dir.join("logs/shard-0.out")).unwrap();
    let summary: serde_json::Value = log0
        .lines()
        .rev()
        .find_map(|l| serde_json::from_str(l).ok())
        .unwrap_or_else(|| panic!("no JSON summary in task 0's log:\n{log0}"));
    let resumed = summary["resumed"].as_u64().expect("resumed count");
    assert!(
        resumed >= before as u64,
        "task 0 resumed {resumed} points, but {before} were on disk when it was requeued"
    );

    // The merged map is the unsharded map, bit for bit.
    assert_eq!(map_points(&out_dir.join("map.mcap")), want);
    assert!(std::fs::metadata(out_dir.join("map.png")).unwrap().len() > 1000);
}

/// The paper's chaotic Henon-Heiles orbit, VM and MPM with k = 2, long enough (about 4 s on one
/// core of a Zen 3) to be requeued after its recorder closed its first chunks (one a second).
const RUN_CONFIG: &str = r#"
[model]
name = "henon-heiles"

[orbit]
q = [0.0, -0.25]
p = [0.0, 0.0]
energy = 0.125
solve_for = "p1"

[integrator]
method = "aba864"
h = 0.01
t_final = 100000.0

[deviations]
k = 2
sets = 1
seed = 1

[[scheme]]
name = "vm"
method = "vm"
d0 = 1e-8
tau = 1.0

[[scheme]]
name = "mpm"
method = "mpm"
d0 = 1e-8
tau = 1.0
orthonormalize = "qr"
"#;

#[test]
#[ignore = "needs a running Slurm cluster: tests/slurm/start-cluster.sh (root), then --ignored"]
fn a_requeued_run_resumes_by_itself_to_the_uninterrupted_analysis() {
    let sinfo = Command::new("sinfo").arg("-h").output();
    assert!(
        matches!(&sinfo, Ok(o) if o.status.success()),
        "no Slurm cluster answers (sinfo failed); start one with tests/slurm/start-cluster.sh"
    );
    let bin = PathBuf::from(env!("CARGO_BIN_EXE_chaoscope"));
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let cfg = d.join("run.toml");
    std::fs::write(&cfg, RUN_CONFIG).unwrap();
    let analysis = |path: &Path| run(Command::new(&bin).args(["analyze", "--json"]).arg(path));

    // The reference: the same run uninterrupted, outside Slurm.
    let whole = d.join("whole.mcap");
    run(Command::new(&bin)
        .args(["run", "--run", "requeue-test", "--out"])
        .arg(&whole)
        .arg(&cfg));
    let want = analysis(&whole);

    // The job as a user writes it: `chaoscope run` with --requeue, nothing else.
    let out = d.join("run.mcap");
    let log = d.join("run.out");
    let job = run(Command::new("sbatch")
        .args(["--parsable", "--requeue", "--cpus-per-task=1", "--mem=500M"])
        .args(["--time=00:10:00", "--job-name=chaoscope-run"])
        .arg(format!("--output={}", log.display()))
        .arg(format!(
            "--wrap='{}' run '{}' --run requeue-test --out '{}'",
            bin.display(),
            cfg.display(),
            out.display()
        )));
    let job = job.trim().to_string();

    // Requeue it once its recording holds complete chunks and it is still computing. Slurm
    // stops it with SIGTERM: the recorder finalizes an interrupted file.
    let partial = chaoscope_os::output::partial_path(&out);
    wait_until("the run's first chunks", Duration::from_secs(120), || {
        std::fs::metadata(&partial).is_ok_and(|m| m.len() > 1_000_000)
    });
    assert_eq!(
        state(&job),
        "RUNNING",
        "the run finished before it could be requeued"
    );
    run(Command::new("scontrol").args(["requeue", &job]));
    wait_until(
        "the run to be pending again",
        Duration::from_secs(60),
        || state(&job) == "PENDING",
    );
    std::thread::sleep(Duration::from_secs(2));
    run(Command::new("scontrol").args(["update", &format!("JobId={job}"), "StartTime=now"]));
    wait_until("the requeued run", Duration::from_secs(300), || {
        let s = state(&job);
        assert!(
            !matches!(s.as_str(), "FAILED" | "CANCELLED" | "TIMEOUT" | "NODE_FAIL"),
            "run {s}: {}",
            std::fs::read_to_string(&log).unwrap_or_default()
        );
        s == "COMPLETED"
    });
    assert_eq!(job_fields(&job).unwrap()["Restarts"], "1", "requeued once");
    let text = std::fs::read_to_string(&log).unwrap();
    assert!(
        text.contains("requeued by Slurm: continuing") && text.contains("samples copied"),
        "the second run did not resume:\n{text}"
    );
    assert_eq!(analysis(&out), want, "the requeued run's analysis");
}
