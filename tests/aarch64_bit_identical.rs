//! The same configs give the same bits on 64-bit ARM as on x86-64: every run of
//! `examples/models` and of the paper's orbits, recorded by `produce` and `record` over the bus,
//! every phase-space map through the batched kernel, and `analyze --json` of the recordings.
//!
//! Why this holds and what it tests: the numerics use no fused multiply-add and no
//! reassociation on any path (ARCHITECTURE.md, "Bit-identical everywhere"), so the x86 kernels
//! (AVX-512 or AVX2 and the system C compiler's kernels for expression models) and the aarch64
//! ones (NEON through the portable path, Cranelift's aarch64 back end for expression models)
//! must agree to the last bit. A contraction, a vector-width-dependent reduction order or a
//! libm difference anywhere on the way from config to file shows up here as a differing message.
//!
//! The aarch64 binary runs under user-mode QEMU, so timings mean nothing here; bits do. It is
//! built by `tests/aarch64/build.sh`, so this test is ignored by a plain `cargo test`. The
//! cross-build takes too long for CI; run it by hand before a change to the numerics lands
//! (CONTRIBUTING.md):
//!
//! ```text
//! tests/aarch64/build.sh
//! cargo test --release --test aarch64_bit_identical -- --ignored
//! ```

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};

use chaoscope_schemas::config::RunConfig;
mod common;
use common::{map_points, run_command};

const TARGET: &str = "aarch64-unknown-linux-gnu";

/// One of the two machines: how to start its `chaoscope`.
#[derive(Clone, Copy)]
enum Machine {
    X86,
    Arm,
}

impl Machine {
    fn name(self) -> &'static str {
        match self {
            Machine::X86 => "x86-64",
            Machine::Arm => "aarch64",
        }
    }

    fn command(self) -> Command {
        match self {
            Machine::X86 => Command::new(env!("CARGO_BIN_EXE_chaoscope")),
            Machine::Arm => {
                let mut c = Command::new("qemu-aarch64");
                c.arg(arm_binary())
                    // The ARM C library the emulator loads (Debian's cross packages).
                    .env("QEMU_LD_PREFIX", "/usr/aarch64-linux-gnu")
                    // The host's C compiler would build x86 kernels for an ARM process; on a
                    // real ARM machine `cc` is native. Here expression models take Cranelift.
                    .env("CHAOSCOPE_CC", "none");
                c
            }
        }
    }
}

/// `<target dir>/aarch64-unknown-linux-gnu/release/chaoscope`, next to this test's own
/// `<target dir>/release/chaoscope`.
fn arm_binary() -> PathBuf {
    let x86 = Path::new(env!("CARGO_BIN_EXE_chaoscope"));
    let target_dir = x86.parent().and_then(Path::parent).unwrap();
    let bin = target_dir.join(TARGET).join("release").join("chaoscope");
    assert!(
        bin.exists(),
        "{} is missing: build it with tests/aarch64/build.sh",
        bin.display()
    );
    bin
}

/// `config` produced and recorded over the bus by `machine`'s processes into `out`.
fn record(machine: Machine, config: &Path, out: &Path, run: &str) {
    let mut recorder = machine.command();
    recorder
        // Neither waits for ever for a partner that did not start (under QEMU a start takes
        // about a second).
        .args(["record", "--wait-timeout", "120", "--run", run, "--out"])
        .arg(out)
        .stdout(Stdio::null())
        .stderr(Stdio::piped());
    let recorder = recorder.spawn().expect("the recorder starts");
    let mut producer = machine.command();
    producer.arg("produce").arg(config).args([
        "--run",
        run,
        "--no-progress",
        "--wait-timeout",
        "120",
    ]);
    run_command(producer.stdin(Stdio::null()));
    let recorded = recorder.wait_with_output().unwrap();
    assert!(
        recorded.status.success(),
        "record on {} failed: {}",
        machine.name(),
        String::from_utf8_lossy(&recorded.stderr)
    );
}

/// Every message of a recording by topic, as (sequence, log time, bytes): all but MCAP's
/// publish time, the wall-clock time of writing.
fn messages(path: &Path) -> BTreeMap<String, Vec<(u32, u64, Vec<u8>)>> {
    let bytes = std::fs::read(path).unwrap();
    let mut topics: BTreeMap<String, Vec<_>> = BTreeMap::new();
    for m in mcap::MessageStream::new(&bytes).unwrap() {
        let m = m.unwrap();
        topics.entry(m.channel.topic.clone()).or_default().push((
            m.sequence,
            m.log_time,
            m.data.into_owned(),
        ));
    }
    topics
}

/// `config` shortened to `t_final` (runs under emulation are about 50x slower).
fn shortened(text: &str, t_final: f64) -> String {
    let mut config = RunConfig::from_toml(text).unwrap();
    if config.integrator.t_final > t_final {
        // A whole number of the config's steps: a forced system's step divides its forcing
        // period, not `t_final` (the Duffing example's h = 2 pi / 120).
        let h = config.integrator.h.unwrap_or(1.0);
        config.integrator.t_final = (t_final / h).round() * h;
    }
    config.to_toml()
}

/// Records `config` on both machines and compares every message; returns the number compared.
fn same_recording(dir: &Path, name: &str, config: &str) -> usize {
    let cfg = dir.join(format!("{name}.toml"));
    std::fs::write(&cfg, config).unwrap();
    let (x86, arm) = (
        dir.join(format!("{name}-x86.mcap")),
        dir.join(format!("{name}-arm.mcap")),
    );
    // One run name for both (one after the other), so even the run header is the same.
    let run = format!("aarch64-{name}-{}", std::process::id());
    record(Machine::X86, &cfg, &x86, &run);
    record(Machine::Arm, &cfg, &arm, &run);
    let (want, got) = (messages(&x86), messages(&arm));
    assert_eq!(
        want.keys().collect::<Vec<_>>(),
        got.keys().collect::<Vec<_>>(),
        "{name}: the channels differ"
    );
    assert!(
        want.contains_key("/chaoscope/end") && want.keys().any(|t| t.contains("/separations/")),
        "{name}: not a whole recording"
    );
    let mut compared = 0;
    for (topic, w) in &want {
        let g = &got[topic];
        assert_eq!(w.len(), g.len(), "{name} {topic}: message counts differ");
        if let Some(i) = (0..w.len()).find(|&i| w[i] != g[i]) {
            panic!(
                "{name} {topic}: message {i} (sequence {}) differs between x86-64 and aarch64",
                w[i].0
            );
        }
        compared += w.len();
    }

    // The analysis of each machine's own file, on that machine: text for text.
    let analyze = |machine: Machine, file: &Path| {
        let mut c = machine.command();
        c.arg("analyze").arg(file).arg("--json");
        run_command(&mut c)
    };
    let (a, b) = (analyze(Machine::X86, &x86), analyze(Machine::Arm, &arm));
    assert!(a.contains("\"verdict\""), "{name}: analyze printed {a}");
    assert!(a == b, "{name}: analyze --json differs:\n{a}\n{b}");
    compared
}

#[test]
#[ignore = "needs the aarch64 binary and qemu-user: tests/aarch64/build.sh, then --ignored"]
fn every_example_model_and_paper_orbit_records_the_same_bits_on_aarch64() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut cases: Vec<(String, String)> = Vec::new();
    for entry in std::fs::read_dir(root.join("examples/models")).unwrap() {
        let path = entry.unwrap().path();
        match path.extension().and_then(|e| e.to_str()) {
            Some("toml") => {
                let text = std::fs::read_to_string(&path).unwrap();
                let is_map = RunConfig::from_toml(&text).unwrap().model.name() == "map";
                // 100 time units of a flow, 1000 iterations of a map.
                let t_final = if is_map { 1000.0 } else { 100.0 };
                let name = path.file_stem().unwrap().to_string_lossy().into_owned();
                cases.push((name, shortened(&text, t_final)));
            }
            // Tabulated potentials name their tables relative to the config.
            Some("csv") => {
                std::fs::copy(&path, dir.join(path.file_name().unwrap())).unwrap();
            }
            _ => {}
        }
    }
    assert!(
        cases.len() >= 13,
        "examples/models has {} configs",
        cases.len()
    );
    for paper in ["hh_chaotic", "hh_regular", "fput5_chaotic"] {
        let path = root.join(format!("examples/paper/configs/{paper}.toml"));
        let text = std::fs::read_to_string(&path).unwrap();
        cases.push((paper.to_string(), shortened(&text, 200.0)));
    }
    // The VM propagator route of a run (one tangent basis for all sets).
    let mut route = RunConfig::from_toml(&cases.last().unwrap().1).unwrap();
    route.schemes.retain(|s| s.method == "vm");
    for s in &mut route.schemes {
        s.route = Some("propagator".into());
    }
    cases.push(("fput5_chaotic_propagator".into(), route.to_toml()));

    let mut total = 0;
    for (name, config) in &cases {
        let n = same_recording(dir, name, config);
        eprintln!("{name}: {n} messages bit-identical on x86-64 and aarch64");
        total += n;
    }
    eprintln!("{} recordings, {total} messages", cases.len());
}

/// Henon-Heiles written as a potential (an expression model: the batched kernel runs compiled
/// step kernels) over the small map of the map tests, GALI_3 at t = 20.
fn expression_hh_map(method: &str) -> String {
    include_str!("data/hh-map-small.toml")
        .replace(
            "name = \"henon-heiles\"\n",
            "name = \"potential\"\nn = 2\npotential = \"(q1^2 + q2^2)/2 + q1^2*q2 - q2^3/3\"\n",
        )
        .replace("method = \"mpm\"", &format!("method = \"{method}\""))
        // The value itself: a time of crossing would hide a difference in the last bits.
        .replace("indicator = \"gali-time\"", "indicator = \"gali\"")
        .replace("threshold = 0.05\n", "")
}

#[test]
#[ignore = "needs the aarch64 binary and qemu-user: tests/aarch64/build.sh, then --ignored"]
fn maps_through_the_batched_kernel_are_the_same_bits_on_aarch64() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    let cache = dir.join("kernels");
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let small = |file: &str, t_final: f64, sets: usize, n: usize| {
        let text = std::fs::read_to_string(root.join("examples/maps").join(file)).unwrap();
        let mut config = RunConfig::from_toml(&text).unwrap();
        config.integrator.t_final = t_final;
        config.deviations.sets = config.deviations.sets.min(sets);
        let map = config.map.as_mut().unwrap();
        map.x.n = n;
        map.y.n = n * 3 / 4;
        config.to_toml()
    };
    let cases = [
        // The paper's MPM workload: HH kernel, per-set and by the basis route.
        ("hh-gali2", small("hh-gali2.toml", 100.0, 4, 8)),
        (
            "hh-gali2-propagator",
            small("hh-gali2-propagator.toml", 100.0, 4, 8),
        ),
        // Exponents (QR), and a map given by expressions.
        ("hh-mle", small("hh-mle.toml", 100.0, 1, 8)),
        (
            "standard-map-sali",
            small("standard-map-sali.toml", 300.0, 1, 12),
        ),
        // A potential written as an expression: on x86 the system C compiler's step kernels
        // only (the test hook below), on ARM Cranelift's.
        ("expression-hh-mpm", expression_hh_map("mpm")),
        ("expression-hh-vm", expression_hh_map("vm")),
    ];
    for (name, config) in &cases {
        let cfg = dir.join(format!("{name}.toml"));
        std::fs::write(&cfg, config).unwrap();
        let map = |machine: Machine, isa: Option<&str>| {
            let out = dir.join(format!(
                "{name}-{}-{}.mcap",
                machine.name(),
                isa.unwrap_or("")
            ));
            let mut c = machine.command();
            c.args(["map", "--no-progress", "--json", "--threads", "2", "--out"])
                .arg(&out)
                .arg(&cfg)
                .env("CHAOSCOPE_KERNEL_CACHE", &cache)
                .env("CHAOSCOPE_C_KERNELS_AFTER_CALLS", "0");
            if let Some(isa) = isa {
                c.args(["--isa", isa]);
            }
            let json = run_command(&mut c);
            let json: serde_json::Value = serde_json::from_str(json.trim()).unwrap();
            (map_points(&out), json)
        };
        let (want, json) = map(Machine::X86, None);
        assert!(!want.is_empty(), "{name}: no points");
        if name.starts_with("expression") {
            let kernels = &json["expression_kernels"];
            assert!(
                kernels["c_calls"].as_u64() > Some(0) && kernels["cranelift_calls"] == 0,
                "{name}: the x86 map did not run on the C kernels: {json}"
            );
        }
        for (label, (got, json)) in [
            ("aarch64", map(Machine::Arm, None)),
            // x86's own narrower path, for a machine without AVX-512.
            ("x86-64 --isa avx2", map(Machine::X86, Some("avx2"))),
        ] {
            assert_eq!(
                want.len(),
                got.len(),
                "{name} on {label}: point counts differ"
            );
            if let Some(i) = want.keys().find(|i| want[i] != got[i]) {
                panic!("{name}: point {i} differs on {label}");
            }
            if label == "aarch64" && name.starts_with("expression") {
                assert_eq!(
                    json["expression_kernels"]["c_calls"], 0,
                    "{name}: the ARM map ran C kernels: {json}"
                );
            }
        }
        eprintln!("{name}: {} points bit-identical", want.len());
    }
}
