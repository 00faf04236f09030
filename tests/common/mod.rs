//! Helpers shared by the multi-process pipeline tests: configs, child processes, reading a
//! recording back and recomputing it in process.

#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::process::{Child, Command, ExitStatus, Stdio};
use std::time::{Duration, Instant};

use chaoscope_dynamics::engine::Engine;
use chaoscope_dynamics::spec::RunSpec;
use chaoscope_schemas::config::{DeviationsConfig, RunConfig, SchemeConfig, paper};
use chaoscope_schemas::names::topic;
use chaoscope_schemas::proto::{
    EndOfRun, Indicators, RecordingSummary, ReferenceState, RunHeader, SeparationSet,
};
use chaoscope_schemas::run::Sample;
use prost::Message;

pub const CHAOSCOPE: &str = env!("CARGO_BIN_EXE_chaoscope");

/// Takes SIGINT's default action back in every test process that includes this module, before
/// the harness starts a thread.
/// The tests signal the commands they start with SIGINT, and a process started with SIGINT
/// ignored (the background job of a shell without job control: `cargo test ... &` in a script)
/// passes that on to every command it starts, which then keeps ignoring it (as it must:
/// docs/src/commands.md). Every test that interrupts a command failed so, each as "did not stop
/// on SIGINT", naming neither cause nor cure. Run from `.init_array`, as the C runtime runs
/// constructors: before `main`, so before any test.
#[used]
#[unsafe(link_section = ".init_array")]
static SIGINT_DEFAULT_BEFORE_THE_TESTS: extern "C" fn() = {
    extern "C" fn sigint_default() {
        // SAFETY: signal(2) with SIG_DFL, in the one thread the process has before `main`.
        unsafe { libc::signal(libc::SIGINT, libc::SIG_DFL) };
    }
    sigint_default
};

/// A short run on the paper's chaotic Henon-Heiles orbit: k = 3, two sets, VM and MPM with QR
/// (t_final, tau as given).
pub fn hh_config(t_final: f64, tau: f64) -> RunConfig {
    paper::henon_heiles(
        paper::HH_CHAOTIC_Q2,
        t_final,
        DeviationsConfig::random(3, 2, 11),
        vec![
            SchemeConfig::new("vm", "vm", 1e-8, tau),
            SchemeConfig::new("mpm-qr", "mpm", 1e-8, tau).with_orthonormalize("qr"),
        ],
    )
}

/// A run name no other test (or concurrent test run) uses: the process id tells concurrent
/// test binaries apart, a counter the tests of one binary (they run on parallel threads, and two
/// of them once read the same clock nanosecond and shared a run), the clock a later process that
/// reuses the id.
pub fn unique_run(tag: &str) -> String {
    static NEXT: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);
    let n = NEXT.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
    let nanos = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .unwrap()
        .subsec_nanos();
    format!("test-{tag}-{}-{n}-{nanos}", std::process::id())
}

pub fn chaoscope(args: &[&str]) -> Command {
    let mut c = Command::new(CHAOSCOPE);
    c.args(args).stdout(Stdio::piped()).stderr(Stdio::inherit());
    c
}

/// `chaoscope ARGS` with stdout and stderr captured (for `output()`).
pub fn chaoscope_captured(args: &[&str]) -> Command {
    let mut c = Command::new(CHAOSCOPE);
    c.args(args);
    c
}

/// `chaoscope ARGS` run to success; its stdout (a failure panics with its stderr).
pub fn run_ok(args: &[&str]) -> String {
    let out = chaoscope_captured(args).output().expect("chaoscope runs");
    assert!(
        out.status.success(),
        "chaoscope {args:?}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8(out.stdout).unwrap()
}

/// `chaoscope record` of `run` into `out`, with `extra` arguments.
pub fn record_cmd(run: &str, out: &Path, extra: &[&str]) -> Command {
    let mut args = vec!["record", "--run", run, "--out", out.to_str().unwrap()];
    args.extend_from_slice(extra);
    chaoscope(&args)
}

/// A child process killed if the test fails before reaping it.
pub struct Proc(pub Child);

impl Proc {
    pub fn spawn(mut c: Command) -> Self {
        Self(c.spawn().expect("spawn"))
    }

    pub fn pid(&self) -> i32 {
        self.0.id() as i32
    }

    pub fn signal(&self, signal: i32) {
        // SAFETY: kill(2) on our own child.
        unsafe { libc::kill(self.pid(), signal) };
    }

    /// Waits up to `limit`; panics (after killing the child) if it does not exit.
    pub fn wait(&mut self, limit: Duration) -> ExitStatus {
        let start = Instant::now();
        loop {
            if let Some(status) = self.0.try_wait().unwrap() {
                return status;
            }
            if start.elapsed() > limit {
                let _ = self.0.kill();
                panic!("process {} did not exit within {limit:?}", self.pid());
            }
            std::thread::sleep(Duration::from_millis(20));
        }
    }

    pub fn stdout(&mut self) -> String {
        let mut s = String::new();
        if let Some(mut out) = self.0.stdout.take() {
            std::io::Read::read_to_string(&mut out, &mut s).unwrap();
        }
        s
    }
}

impl Drop for Proc {
    fn drop(&mut self) {
        if let Ok(None) = self.0.try_wait() {
            let _ = self.0.kill();
            let _ = self.0.wait();
        }
    }
}

/// Everything a recording holds, decoded.
#[derive(Debug, Default)]
pub struct Recorded {
    pub header: Option<RunHeader>,
    /// (frame, message) in file order.
    pub references: Vec<ReferenceState>,
    pub separations: Vec<SeparationSet>,
    pub end: Option<EndOfRun>,
    pub recording: Option<RecordingSummary>,
    /// (topic, message) of the indicator channels, in file order.
    pub indicators: Vec<(String, Indicators)>,
    /// Frame numbers of data messages in file order.
    pub frames: Vec<u64>,
}

/// Reads a recording; `lenient` accepts a missing end (salvage input).
pub fn read_recording(path: &Path) -> Recorded {
    let bytes = std::fs::read(path).unwrap();
    let mut r = Recorded::default();
    for m in mcap::MessageStream::new(&bytes).expect("valid MCAP") {
        let m = m.expect("readable message");
        let data = &m.data[..];
        match m.channel.topic.as_str() {
            topic::RUN => r.header = Some(RunHeader::decode(data).unwrap()),
            topic::REFERENCE => {
                let s = ReferenceState::decode(data).unwrap();
                r.frames.push(s.frame);
                r.references.push(s);
            }
            topic::END => {
                let s = EndOfRun::decode(data).unwrap();
                r.frames.push(s.frame);
                r.end = Some(s);
            }
            topic::RECORDING => r.recording = Some(RecordingSummary::decode(data).unwrap()),
            t if t.starts_with("/chaoscope/separations/") => {
                let s = SeparationSet::decode(data).unwrap();
                r.frames.push(s.frame);
                r.separations.push(s);
            }
            t if t.starts_with("/chaoscope/indicators/") => r
                .indicators
                .push((t.to_string(), Indicators::decode(data).unwrap())),
            other => panic!("unexpected topic {other}"),
        }
    }
    r
}

/// The in-process computation of `config_toml`, all samples.
pub fn compute(config_toml: &str, limit: Option<usize>) -> Vec<Sample> {
    let cfg = RunConfig::from_toml(config_toml).unwrap();
    let mut engine = Engine::new(RunSpec::from_config(&cfg).unwrap());
    let mut out = Vec::new();
    while let Some(s) = engine.next_sample().unwrap() {
        out.push(s);
        if limit.is_some_and(|l| out.len() >= l) {
            break;
        }
    }
    out
}

pub fn bits(v: &[f64]) -> Vec<u64> {
    v.iter().map(|x| x.to_bits()).collect()
}

/// Asserts that the recorded references and separation sets are exactly `expected[..n]`
/// (n = number of recorded reference states), bit for bit, each exactly once.
pub fn assert_bit_identical(rec: &Recorded, expected: &[Sample]) {
    let n = rec.references.len();
    assert!(
        n <= expected.len(),
        "more samples recorded ({n}) than computed ({})",
        expected.len()
    );
    let mut seps = rec.separations.iter();
    for (i, (got, want)) in rec.references.iter().zip(expected).enumerate() {
        assert_eq!(
            got.seq, i as u64,
            "sample {i} recorded out of order or twice"
        );
        assert_eq!(
            (got.seq, got.step, got.t.to_bits()),
            (want.seq, want.step, want.t.to_bits())
        );
        assert_eq!(bits(&got.state), bits(&want.state), "state of sample {i}");
        assert_eq!(
            got.energy.to_bits(),
            want.energy.to_bits(),
            "energy of sample {i}"
        );
        for ws in &want.schemes {
            let Some(gs) = seps.next() else {
                // A salvaged file may end inside a sample.
                return;
            };
            assert_eq!(
                (gs.seq, gs.scheme, gs.set),
                (want.seq, ws.scheme, ws.set),
                "separation order at sample {i}"
            );
            assert_eq!(
                bits(&gs.separations),
                bits(&ws.separations),
                "separations at sample {i}"
            );
            assert_eq!(
                bits(&gs.stretch),
                bits(&ws.stretch),
                "stretch at sample {i}"
            );
        }
    }
}

/// Frames are 0, 1, 2, ... with no gap and no repeat.
pub fn assert_contiguous(frames: &[u64]) {
    for (i, f) in frames.iter().enumerate() {
        assert_eq!(*f, i as u64, "frame {i} is {f}: gap or duplicate");
    }
}

pub fn write_config(dir: &Path, text: &str) -> PathBuf {
    let p = dir.join("run.toml");
    std::fs::write(&p, text).unwrap();
    p
}

/// Python checks run unless CHAOSCOPE_SKIP_PYTHON=1 (CI installs the packages).
pub fn python_checks_enabled() -> bool {
    std::env::var("CHAOSCOPE_SKIP_PYTHON")
        .map(|v| v != "1")
        .unwrap_or(true)
}

pub fn python_script(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/python")
        .join(name)
}

/// Runs an example script (path relative to the repository) in its `--reduced` mode against this
/// build of chaoscope, writing into `out`; panics with the script's name if it fails.
pub fn run_reduced_example(script: &str, out: &Path) {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join(script);
    let status = Command::new("python3")
        .arg(&path)
        .args(["--reduced", "--chaoscope", CHAOSCOPE, "--out"])
        .arg(out)
        .status()
        .unwrap_or_else(|e| {
            panic!("python3 {script}: {e} (packages: tests/python/requirements.txt)")
        });
    assert!(status.success(), "{script} --reduced failed: {status}");
}

/// A map recording's points by grid index, each as its exact protobuf bytes (a damaged file
/// fails the test).
pub fn map_points(path: &Path) -> std::collections::BTreeMap<u64, Vec<u8>> {
    let contents = chaoscope_files::map_file::read_map_file(path).unwrap();
    assert!(contents.damaged.is_none(), "{} is damaged", path.display());
    contents
        .points
        .into_iter()
        .map(|p| (p.index, p.encode_to_vec()))
        .collect()
}

/// Runs `cmd` to success and returns its stdout; a failure panics with the command and its
/// output.
pub fn run_command(cmd: &mut Command) -> String {
    let out = cmd.output().unwrap_or_else(|e| panic!("{cmd:?}: {e}"));
    assert!(
        out.status.success(),
        "{cmd:?} failed: {}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8_lossy(&out.stdout).into_owned()
}

/// Waits (at most 30 s) until a live node named `node` is on the bus, i.e. a process has got
/// as far as opening it.
pub fn wait_for_node(node: &str) {
    let start = Instant::now();
    while chaoscope_bus::node_liveness(node) != chaoscope_bus::Liveness::Alive {
        assert!(
            start.elapsed() < Duration::from_secs(30),
            "node {node} never came up"
        );
        std::thread::sleep(Duration::from_millis(5));
    }
}

/// Closes a test's private bus domain (the directory `dir` its processes were given as
/// `CHAOSCOPE_BUS_DIR`) once every process of it has ended. Removes what processes killed with
/// SIGKILL left there, as the next chaoscope process of that domain would, and returns the
/// shared-memory segments still there besides iceoryx2's node counter: a test asserts that list
/// is empty. The node counter itself (16 bytes that iceoryx2 keeps for the domain's lifetime) is
/// removed too, since nobody uses this domain any more: test runs leave nothing in /dev/shm.
pub fn close_private_bus(dir: &Path) -> Vec<String> {
    let domain = chaoscope_bus::domain_at(dir).unwrap();
    chaoscope_bus::cleanup_dead_nodes_in(domain.config());
    let (counters, left): (Vec<String>, Vec<String>) = domain_segments(&domain.prefix)
        .into_iter()
        .partition(|name| is_node_counter(name));
    for name in counters {
        let _ = std::fs::remove_file(Path::new("/dev/shm").join(name));
    }
    left
}

/// The shared-memory segments of the bus domain with segment prefix `prefix`, by name.
pub fn domain_segments(prefix: &str) -> Vec<String> {
    let mut v: Vec<String> = std::fs::read_dir("/dev/shm")
        .unwrap()
        .flatten()
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .filter(|n| n.starts_with(prefix))
        .collect();
    v.sort();
    v
}

/// Whether segment `name` is iceoryx2's node counter, which it keeps for a domain's lifetime.
pub fn is_node_counter(name: &str) -> bool {
    name.ends_with(".global_mgmt")
}
