//! The batched kernel of a user-written potential starts on the Cranelift step kernels and
//! switches to the C ones when their background build is ready (a 1001-site chain must not wait
//! a minute for its compiler).
//!
//! - The map is the same, point for point and bit for bit, whatever call the switch happens
//!   at: all Cranelift, all C, and switches placed at several calls by the test hook
//!   `CHAOSCOPE_C_KERNELS_AFTER_CALLS`, on one and two threads, for MPM (orbit kernel) and VM
//!   (tangent kernel). Each run's JSON says how many calls each backend ran, so a run that
//!   never switched cannot pass for one that did.
//! - A C build that fails (no compiler, a compile error) is said once, in one line naming the
//!   cause, and the map goes on with the Cranelift kernels.
//! - A map that ends, or is interrupted by SIGINT, while the compiler is still running leaves
//!   no compiler process and no file behind (the build is cancelled: see `Inner::drop` in
//!   `dynamics/src/model/expression.rs` for why).

use std::collections::BTreeMap;
use std::path::Path;
use std::process::{Command, Output};
use std::time::{Duration, Instant};

use chaoscope_files::map_file::read_map_file;
use prost::Message;
use serde_json::Value;

/// Henon-Heiles written as an expression over the small map of the map tests (9 x 7 points).
fn hh_map(method: &str, indicator: &str) -> String {
    include_str!("data/hh-map-small.toml")
        .replace(
            "name = \"henon-heiles\"\n",
            "name = \"potential\"\nn = 2\npotential = \"(q1^2 + q2^2)/2 + q1^2*q2 - q2^3/3\"\n",
        )
        .replace("method = \"mpm\"", &format!("method = \"{method}\""))
        .replace(
            "indicator = \"gali-time\"",
            &format!("indicator = \"{indicator}\""),
        )
        .replace(
            "threshold = 0.05\n",
            if indicator == "gali-time" {
                "threshold = 0.05\n"
            } else {
                ""
            },
        )
}

/// The FPUT-beta chain as a lattice sum (a loop over its term).
const FPUT_LOOP: &str = "sum(i = 0..N, (q[i+1] - q[i])^2/2 + beta/4*(q[i+1] - q[i])^4)";

/// A graded FPUT-beta chain (the quartic coupling growing along it, `beta i / N`: the sum's
/// index as a number, which the loop form of lattice sums does not take, so every site's
/// derivative is unrolled and the C build of a long chain takes tens of seconds).
const FPUT_GRADED: &str = "sum(i = 0..N, (q[i+1] - q[i])^2/2 + beta*i/(4*N)*(q[i+1] - q[i])^4)";

/// The chain `potential` of `n` sites with fixed ends (lowest mode, amplitude 0.5) mapped by
/// `method` over (q1, q2) on a `grid` x `grid` grid to `t_final`.
fn fput_map(n: usize, grid: usize, t_final: f64, potential: &str, method: &str) -> String {
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
         potential = \"{potential}\"\n\
         [orbit]\nq = [{}]\np = [{p}]\n\
         [integrator]\nmethod = \"aba864\"\nh = 0.02\nt_final = {t_final}\n\
         [deviations]\nk = 2\nsets = 1\nseed = 3\n\
         [[scheme]]\nname = \"{method}\"\nmethod = \"{method}\"\nd0 = 1e-8\ntau = 1.0\n\
         [map]\nx = {{ coord = \"q1\", min = -0.1, max = 0.1, n = {grid} }}\n\
         y = {{ coord = \"q2\", min = -0.1, max = 0.1, n = {grid} }}\nindicator = \"gali\"\nk = 2\n\
         route = \"per-set\"\n",
        q.join(", ")
    )
}

/// `chaoscope map CONFIG --out OUT --json` with the given environment; the kernel cache is
/// always the test's own.
fn map_command(config: &Path, out: &Path, threads: usize, env: &[(&str, &str)]) -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_chaoscope"));
    c.args(["map", s(config), "--out", s(out), "--json", "--no-progress"])
        .args(["--threads", &threads.to_string()])
        .env_remove("CHAOSCOPE_CC")
        .env_remove("CHAOSCOPE_C_KERNELS_AFTER_CALLS");
    for (k, v) in env {
        c.env(k, v);
    }
    c
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// Runs a map to completion: its points by index (exact protobuf bytes), its JSON summary and
/// its stderr.
fn map(
    config: &Path,
    out: &Path,
    threads: usize,
    env: &[(&str, &str)],
) -> (BTreeMap<u64, Vec<u8>>, Value, String) {
    let _ = std::fs::remove_file(out);
    let o: Output = map_command(config, out, threads, env).output().unwrap();
    let stderr = String::from_utf8_lossy(&o.stderr).into_owned();
    assert!(o.status.success(), "map {env:?}: {stderr}");
    let json: Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(json["complete"], true, "{json}");
    let contents = read_map_file(out).unwrap();
    assert!(contents.damaged.is_none());
    let points = contents
        .points
        .into_iter()
        .map(|p| (p.index, p.encode_to_vec()))
        .collect();
    (points, json, stderr)
}

fn calls(json: &Value) -> (u64, u64) {
    let k = &json["expression_kernels"];
    (
        k["cranelift_calls"].as_u64().unwrap(),
        k["c_calls"].as_u64().unwrap(),
    )
}

#[test]
fn the_map_is_the_same_whatever_call_the_c_kernels_arrive_at() {
    let dir = tempfile::tempdir().unwrap();
    let cache = dir.path().join("kernels");
    let cache_env = ("CHAOSCOPE_KERNEL_CACHE", s(&cache));
    // Henon-Heiles, and an FPUT chain whose lattice sum is a loop (the lattice step kernels).
    for (method, text, grid_points) in [
        ("mpm", hh_map("mpm", "gali-time"), 63),
        ("vm", hh_map("vm", "gali"), 63),
        ("fput-loop-vm", fput_map(12, 4, 60.0, FPUT_LOOP, "vm"), 16),
    ] {
        let config = dir.path().join(format!("{method}.toml"));
        std::fs::write(&config, text).unwrap();
        let out = dir.path().join(format!("{method}.mcap"));

        // All Cranelift: the C kernels switched off.
        let (cranelift, json, _) = map(&config, &out, 2, &[cache_env, ("CHAOSCOPE_CC", "none")]);
        assert_eq!(json["expression_kernels"]["c_build"], "off");
        let (_, total) = {
            let (cl, c) = calls(&json);
            assert_eq!(c, 0, "{method}: C kernels ran although switched off");
            (cl, cl + c)
        };
        assert_eq!(
            cranelift.len(),
            grid_points,
            "{method}: every grid point recorded"
        );
        // Enough kernel calls to place switches early, in the middle and late.
        assert!(total > 100, "{method}: only {total} kernel calls");

        // All C (the first call waits for the build), then switches at chosen calls, on one
        // and two threads, and the untouched background switch.
        let runs: [(Option<u64>, usize); 6] = [
            (Some(0), 1),
            (Some(1), 2),
            (Some(total / 3), 1),
            (Some(total / 2), 2),
            (Some(total - 5), 2),
            (None, 2),
        ];
        for (after, threads) in runs {
            let after_text = after.map(|a| a.to_string());
            let mut env = vec![cache_env];
            if let Some(a) = &after_text {
                env.push(("CHAOSCOPE_C_KERNELS_AFTER_CALLS", a));
            }
            let (points, json, _) = map(&config, &out, threads, &env);
            let (cl, c) = calls(&json);
            if let Some(a) = after {
                assert_eq!(
                    (cl, c > 0),
                    (a, true),
                    "{method}, switch after {a} calls, {threads} threads: {json}"
                );
            }
            assert_eq!(cl + c, total, "{method}: the same work in every run");
            assert!(
                points == cranelift,
                "{method}: switching to C after {after:?} calls on {threads} threads changed \
                 the map"
            );
        }
    }
}

#[test]
fn a_failed_c_build_is_said_once_and_the_map_goes_on() {
    let dir = tempfile::tempdir().unwrap();
    let cache = dir.path().join("kernels");
    let config = dir.path().join("map.toml");
    std::fs::write(&config, hh_map("mpm", "gali-time")).unwrap();
    let out = dir.path().join("map.mcap");
    let cache_env = ("CHAOSCOPE_KERNEL_CACHE", s(&cache));
    let (reference, _, _) = map(&config, &out, 2, &[cache_env, ("CHAOSCOPE_CC", "none")]);

    // A compiler that answers for its target but fails on the kernels, as a compile error.
    let failing = dir.path().join("failing-cc");
    std::fs::write(
        &failing,
        "#!/bin/sh\ncase \" $* \" in *\" -shared \"*) echo 'steps.c:1:1: error: simulated' >&2; \
         exit 1;; esac\nexec cc \"$@\"\n",
    )
    .unwrap();
    {
        use std::os::unix::fs::PermissionsExt;
        std::fs::set_permissions(&failing, std::fs::Permissions::from_mode(0o755)).unwrap();
    }
    for (compiler, cause) in [
        (
            "/nonexistent/cc",
            "cannot run the C compiler '/nonexistent/cc'",
        ),
        (s(&failing), "error: simulated"),
    ] {
        // Switch after 3 calls: the map waits for the build's outcome there, so the failure
        // is met during the map rather than cancelled at its end.
        let (points, json, stderr) = map(
            &config,
            &out,
            2,
            &[
                cache_env,
                ("CHAOSCOPE_CC", compiler),
                ("CHAOSCOPE_C_KERNELS_AFTER_CALLS", "3"),
            ],
        );
        let said: Vec<&str> = stderr
            .lines()
            .filter(|l| l.contains("C step kernels"))
            .collect();
        assert_eq!(said.len(), 1, "{compiler}: said once: {stderr}");
        assert!(
            said[0].contains(cause) && said[0].contains("Cranelift"),
            "{compiler}: the line names the cause and the fallback: {}",
            said[0]
        );
        assert_eq!(json["expression_kernels"]["c_build"], "failed");
        assert_eq!(calls(&json).1, 0);
        assert!(
            points == reference,
            "{compiler}: the fallback changed the map"
        );
    }
}

/// Processes whose command line mentions `path` (the compiler driver, cc1, as and ld of a
/// build in that cache all do: the source, the output and `TMPDIR` are inside it).
fn processes_mentioning(path: &Path) -> Vec<String> {
    let needle = path.to_str().unwrap().as_bytes();
    let mut found = Vec::new();
    for entry in std::fs::read_dir("/proc").unwrap().flatten() {
        if !entry
            .file_name()
            .to_str()
            .is_some_and(|n| n.bytes().all(|b| b.is_ascii_digit()))
        {
            continue;
        }
        if let Ok(cmdline) = std::fs::read(entry.path().join("cmdline"))
            && cmdline.windows(needle.len()).any(|w| w == needle)
        {
            found.push(String::from_utf8_lossy(&cmdline).replace('\0', " "));
        }
    }
    found
}

/// Every file and directory under `dir` but the compiler's target records (`target-*`: a
/// finished record of what the compiler targets, written whole before any build, which every
/// later build reads instead of running the compiler to ask).
fn files_under(dir: &Path) -> Vec<String> {
    let mut files = Vec::new();
    if let Ok(entries) = std::fs::read_dir(dir) {
        for e in entries.flatten() {
            if e.file_name().to_string_lossy().starts_with("target-") {
                continue;
            }
            files.push(e.path().display().to_string());
            if e.path().is_dir() {
                files.extend(files_under(&e.path()));
            }
        }
    }
    files
}

/// Waits up to `limit` for `done`.
fn wait_for(limit: Duration, mut done: impl FnMut() -> bool) -> bool {
    let start = Instant::now();
    while start.elapsed() < limit {
        if done() {
            return true;
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    false
}

#[test]
fn a_map_ended_or_interrupted_during_the_c_build_leaves_no_compiler_and_no_files() {
    // A 1001-site chain unrolled: its C build takes tens of seconds, its Cranelift kernels a
    // fraction of one, so the map computes while the compiler runs.
    let dir = tempfile::tempdir().unwrap();
    let cache = dir.path().join("kernels");
    let cache_env = ("CHAOSCOPE_KERNEL_CACHE", s(&cache));

    // Ends first: four short orbits.
    let small = dir.path().join("small.toml");
    std::fs::write(&small, fput_map(1001, 2, 2.0, FPUT_GRADED, "mpm")).unwrap();
    let (points, json, _) = map(&small, &dir.path().join("small.mcap"), 2, &[cache_env]);
    assert_eq!(points.len(), 4);
    assert_eq!(
        json["expression_kernels"]["c_build"], "building",
        "the map must end while the compiler runs: {json}"
    );
    assert_eq!(processes_mentioning(&cache), Vec::<String>::new());
    assert_eq!(files_under(&cache), Vec::<String>::new());

    // Interrupted: SIGINT once the compiler is running.
    let large = dir.path().join("large.toml");
    std::fs::write(&large, fput_map(1001, 20, 100.0, FPUT_GRADED, "mpm")).unwrap();
    let mut child = map_command(&large, &dir.path().join("large.mcap"), 2, &[cache_env])
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let compiling = wait_for(Duration::from_secs(60), || {
        !processes_mentioning(&cache).is_empty()
    });
    // SAFETY: sends a signal to the child this test started.
    unsafe { libc::kill(child.id() as i32, libc::SIGINT) };
    assert!(compiling, "the C compiler never started");
    let exited = wait_for(Duration::from_secs(30), || {
        child.try_wait().unwrap().is_some()
    });
    if !exited {
        let _ = child.kill();
    }
    let o = child.wait_with_output().unwrap();
    assert!(exited, "the map did not stop on SIGINT");
    assert_eq!(
        o.status.code(),
        Some(130),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
    let json: Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(json["interrupted"], true);
    // The signal stops the compiler too (its wait observes it), so the build may be over,
    // cancelled, by the time the map writes its summary.
    let state = &json["expression_kernels"]["c_build"];
    assert!(state == "building" || state == "cancelled", "{json}");
    assert_eq!(processes_mentioning(&cache), Vec::<String>::new());
    assert_eq!(files_under(&cache), Vec::<String>::new());
}

/// A shared library whose constructor writes `marker` when loaded, carrying the stamp of
/// kernel `hash` (what another user would plant in a kernel cache they can write).
fn planted_library(dir: &Path, hash: &str, marker: &Path) -> Vec<u8> {
    let src = dir.join("planted.c");
    let lib = dir.join("planted.so");
    std::fs::write(
        &src,
        format!(
            "#include <stdio.h>\nconst char chaoscope_kernel_hash[] = \"{hash}\";\n\
             __attribute__((constructor)) static void planted(void) {{\n\
             FILE *f = fopen(\"{}\", \"w\"); if (f) {{ fputs(\"loaded\", f); fclose(f); }} }}\n",
            marker.display()
        ),
    )
    .unwrap();
    let status = Command::new("cc")
        .args(["-shared", "-fPIC", "-o"])
        .arg(&lib)
        .arg(&src)
        .status()
        .unwrap();
    assert!(status.success(), "cc builds the planted library");
    std::fs::read(&lib).unwrap()
}

#[test]
fn a_library_planted_in_a_shared_temporary_kernel_cache_is_never_loaded() {
    use std::os::unix::fs::PermissionsExt;
    let dir = tempfile::tempdir().unwrap();
    let config = dir.path().join("map.toml");
    std::fs::write(&config, hh_map("mpm", "gali-time")).unwrap();
    let out = dir.path().join("map.mcap");
    // The kernel's name (its hash: compiler, flags, target, source; not the directory), from
    // a build into a cache of the test's own.
    let own = dir.path().join("own");
    let (reference, json, _) = map(
        &config,
        &out,
        2,
        &[
            ("CHAOSCOPE_KERNEL_CACHE", s(&own)),
            ("CHAOSCOPE_C_KERNELS_AFTER_CALLS", "0"),
        ],
    );
    assert_eq!(json["expression_kernels"]["c_build"], "compiled");
    let name = std::fs::read_dir(&own)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .find(|n| n.ends_with(".so"))
        .expect("a library in the cache");
    let hash = &name["steps-".len()..name.len() - ".so".len()];

    // A temporary directory shared by all users (mode 1777, as /tmp), in which another user
    // made the kernel caches a user without HOME would fall back to (this one's and the
    // per-user one), writable by all, holding a planted library of that very name and its
    // matching digest.
    let tmp = dir.path().join("tmp");
    std::fs::create_dir(&tmp).unwrap();
    std::fs::set_permissions(&tmp, std::fs::Permissions::from_mode(0o1777)).unwrap();
    let marker = dir.path().join("planted-code-ran");
    let planted = planted_library(dir.path(), hash, &marker);
    // SAFETY: geteuid(2) cannot fail.
    let uid = unsafe { libc::geteuid() };
    for cache in [
        "chaoscope-kernels".to_string(),
        format!("chaoscope-kernels-{uid}"),
    ] {
        let cache = tmp.join(cache);
        std::fs::create_dir(&cache).unwrap();
        std::fs::write(cache.join(&name), &planted).unwrap();
        std::fs::write(
            cache.join(name.replace(".so", ".sha256")),
            hex_sha256(&planted),
        )
        .unwrap();
        std::fs::set_permissions(&cache, std::fs::Permissions::from_mode(0o777)).unwrap();
        if uid == 0 {
            // Root can make it another user's for real.
            for f in [
                cache.join(&name),
                cache.join(name.replace(".so", ".sha256")),
                cache,
            ] {
                std::os::unix::fs::chown(&f, Some(65534), Some(65534)).unwrap();
            }
        }
    }
    let run_without_home = |expect_build: &str| {
        let _ = std::fs::remove_file(&out);
        let o = map_command(
            &config,
            &out,
            2,
            &[("CHAOSCOPE_C_KERNELS_AFTER_CALLS", "0")],
        )
        .env_remove("CHAOSCOPE_KERNEL_CACHE")
        .env_remove("HOME")
        .env_remove("XDG_CACHE_HOME")
        .env("TMPDIR", &tmp)
        .output()
        .unwrap();
        let stderr = String::from_utf8_lossy(&o.stderr).into_owned();
        assert!(o.status.success(), "{stderr}");
        assert!(
            !marker.exists(),
            "the planted library was loaded (its constructor ran): {stderr}"
        );
        let json: Value = serde_json::from_slice(&o.stdout).unwrap();
        assert_eq!(
            json["expression_kernels"]["c_build"], expect_build,
            "{stderr}"
        );
        let points: BTreeMap<u64, Vec<u8>> = read_map_file(&out)
            .unwrap()
            .points
            .into_iter()
            .map(|p| (p.index, p.encode_to_vec()))
            .collect();
        assert!(points == reference, "the map changed");
        stderr
    };
    // Refused in one line naming the directory and why; the map is computed by Cranelift.
    let stderr = run_without_home("failed");
    let per_user = tmp.join(format!("chaoscope-kernels-{uid}"));
    let said: Vec<&str> = stderr
        .lines()
        .filter(|l| l.contains("kernel cache"))
        .collect();
    assert_eq!(said.len(), 1, "{stderr}");
    assert!(
        said[0].contains(&per_user.display().to_string())
            && (said[0].contains("belongs to uid 65534") || said[0].contains("writable by others")),
        "{}",
        said[0]
    );
    // Once that directory is gone, the user's own is made (mode 0700) and used.
    std::fs::remove_dir_all(&per_user).unwrap();
    run_without_home("compiled");
    let mode = std::fs::metadata(&per_user).unwrap().permissions().mode() & 0o777;
    assert_eq!(mode, 0o700, "the per-user cache is private");
    run_without_home("loaded-from-cache");
}

/// SHA-256 in hexadecimal (coreutils' `sha256sum`), as the kernel cache's digest files hold it.
fn hex_sha256(bytes: &[u8]) -> String {
    let out = Command::new("sha256sum")
        .stdin(std::process::Stdio::piped())
        .stdout(std::process::Stdio::piped())
        .spawn()
        .and_then(|mut child| {
            use std::io::Write;
            child.stdin.take().unwrap().write_all(bytes)?;
            child.wait_with_output()
        })
        .unwrap();
    String::from_utf8(out.stdout).unwrap()[..64].to_string()
}

/// A short run of a chain written as a lattice sum builds no C kernels (the build would cost
/// more than it saves) and so runs no compiler; once the kernels are in the cache (here built
/// by a map, as a long run builds them), a short run loads them and steps its small sets in the
/// fused pass, still running no compiler: what the compiler targets is remembered in the cache
/// under a fingerprint of the compiler's file and the CPU, and asked again, once, when the
/// compiler's file changes. The run's bits are the built-in chain's whichever kernels ran.
#[test]
fn a_short_run_loads_cached_kernels_without_running_the_compiler() {
    let dir = tempfile::tempdir().unwrap();
    let cache = dir.path().join("kernels");
    let log = dir.path().join("cc.log");
    // A compiler that logs every call, then is `cc`.
    let cc = dir.path().join("logging-cc");
    std::fs::write(
        &cc,
        format!(
            "#!/bin/sh\necho \"$*\" >> '{}'\nexec cc \"$@\"\n",
            log.display()
        ),
    )
    .unwrap();
    {
        use std::os::unix::fs::PermissionsExt;
        std::fs::set_permissions(&cc, std::fs::Permissions::from_mode(0o755)).unwrap();
    }
    let calls = || -> Vec<String> {
        std::fs::read_to_string(&log)
            .unwrap_or_default()
            .lines()
            .map(String::from)
            .collect()
    };
    // 16 sites to t = 20 (1000 steps, 3.2 * 10^4 state-value steps: far below a build's worth),
    // VM and MPM sets of two vectors.
    let short_run = |model: &str| lattice_case(&format!("{model}:16:20"), &cache, s(&cc));
    let builtin = short_run("builtin");

    let cold = short_run("expression");
    assert_eq!(cold["c_kernels"], "not-started", "{cold}");
    assert_eq!(
        calls(),
        Vec::<String>::new(),
        "a short run ran the compiler"
    );
    assert!(!cache.exists(), "a short run made the kernel cache");
    assert_eq!(cold["final_state_digest"], builtin["final_state_digest"]);

    // The same chain's kernels built by a map (which waits for them).
    let config = dir.path().join("map.toml");
    std::fs::write(&config, fput_map(16, 2, 2.0, FPUT_LOOP, "vm")).unwrap();
    let (_, json, _) = map(
        &config,
        &dir.path().join("map.mcap"),
        1,
        &[
            ("CHAOSCOPE_KERNEL_CACHE", s(&cache)),
            ("CHAOSCOPE_CC", s(&cc)),
            ("CHAOSCOPE_C_KERNELS_AFTER_CALLS", "0"),
        ],
    );
    assert_eq!(json["expression_kernels"]["c_build"], "compiled", "{json}");
    let built = calls();
    assert_eq!(
        built.len(),
        2,
        "the target asked, the kernels compiled: {built:?}"
    );
    assert!(
        built[0].contains("-dM") && built[1].contains("-shared"),
        "{built:?}"
    );

    let warm = short_run("expression");
    assert_eq!(warm["c_kernels"], "loaded-from-cache", "{warm}");
    assert_eq!(calls(), built, "a cached load ran the compiler");
    assert_eq!(warm["final_state_digest"], builtin["final_state_digest"]);
    assert_eq!(warm["mle"], cold["mle"]);

    // Another compiler file (a later modification time): a short run has no record of its
    // target and runs no compiler to ask (a compiler that hangs would hold it: a lookup that
    // only loads never waits for one), stepping the one-orbit way with the same bits; the next
    // build asks the target once and finds the kernels, the same for the same target, in the
    // cache; a short run then loads them.
    let later = std::time::SystemTime::now() + Duration::from_secs(5);
    std::fs::File::options()
        .write(true)
        .open(&cc)
        .unwrap()
        .set_modified(later)
        .unwrap();
    let changed = short_run("expression");
    assert_eq!(changed["c_kernels"], "not-started", "{changed}");
    assert_eq!(calls(), built, "a short run ran the compiler");
    assert_eq!(changed["final_state_digest"], builtin["final_state_digest"]);
    let (_, json, _) = map(
        &config,
        &dir.path().join("map.mcap"),
        1,
        &[
            ("CHAOSCOPE_KERNEL_CACHE", s(&cache)),
            ("CHAOSCOPE_CC", s(&cc)),
            ("CHAOSCOPE_C_KERNELS_AFTER_CALLS", "0"),
        ],
    );
    assert_eq!(
        json["expression_kernels"]["c_build"], "loaded-from-cache",
        "{json}"
    );
    let now = calls();
    assert_eq!(now.len(), 3, "{now:?}");
    assert!(now[2].contains("-dM"), "{now:?}");
    let reloaded = short_run("expression");
    assert_eq!(reloaded["c_kernels"], "loaded-from-cache", "{reloaded}");
    assert_eq!(calls(), now, "a cached load ran the compiler");
    assert_eq!(
        reloaded["final_state_digest"],
        builtin["final_state_digest"]
    );
}

/// Without a C compiler a run's small sets of a lattice are stepped by Cranelift's print of
/// the fused pass once the run is long enough to repay its build (5 * 10^7 state-value steps:
/// 64 sites to t = 7812.5 at h = 0.02), the one-orbit way below that; the bits are the built-in
/// chain's either way.
#[test]
fn a_run_without_a_c_compiler_steps_its_small_sets_in_cranelifts_fused_pass() {
    let dir = tempfile::tempdir().unwrap();
    let run = |model: &str, t_final: u32| {
        lattice_case(&format!("{model}:64:{t_final}"), dir.path(), "none")
    };
    for (t_final, fused) in [(7800, false), (7900, true)] {
        let expression = run("expression", t_final);
        let calls = &expression["kernel_calls"];
        assert_eq!(calls["c"], 0, "t = {t_final}: {expression}");
        assert_eq!(
            calls["cranelift"].as_u64().unwrap() > 0,
            fused,
            "t = {t_final}: {expression}"
        );
        assert_eq!(
            expression["final_state_digest"],
            run("builtin", t_final)["final_state_digest"],
            "t = {t_final}"
        );
    }
}

/// `chaoscope bench --lattice-case CASE` on one thread with the kernel cache `cache` and the
/// compiler `cc`: its JSON.
fn lattice_case(case: &str, cache: &Path, cc: &str) -> Value {
    let o = Command::new(env!("CARGO_BIN_EXE_chaoscope"))
        .args(["bench", "--lattice-case", case])
        .env("RAYON_NUM_THREADS", "1")
        .env("CHAOSCOPE_KERNEL_CACHE", cache)
        .env("CHAOSCOPE_CC", cc)
        .env_remove("CHAOSCOPE_C_KERNELS_AFTER_CALLS")
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{stderr}");
    serde_json::from_slice(&o.stdout).unwrap()
}

/// An executable shell script `name` in `dir` with the body `body` (a stand-in compiler).
fn script(dir: &Path, name: &str, body: &str) -> std::path::PathBuf {
    use std::os::unix::fs::PermissionsExt;
    let path = dir.join(name);
    std::fs::write(&path, format!("#!/bin/sh\n{body}")).unwrap();
    std::fs::set_permissions(&path, std::fs::Permissions::from_mode(0o755)).unwrap();
    path
}

/// `command`'s output, or a failure if it is still running after `limit` (it is then killed):
/// a bound only a hang reaches (a test must not wait for ever on a command that hangs).
fn output_within(mut command: Command, limit: Duration) -> Output {
    let mut child = command
        .stdin(std::process::Stdio::null())
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    // Read on threads: a full pipe must not hold the child.
    let mut stdout = child.stdout.take().unwrap();
    let mut stderr = child.stderr.take().unwrap();
    let out = std::thread::spawn(move || {
        let mut b = Vec::new();
        std::io::Read::read_to_end(&mut stdout, &mut b).unwrap();
        b
    });
    let err = std::thread::spawn(move || {
        let mut b = Vec::new();
        std::io::Read::read_to_end(&mut stderr, &mut b).unwrap();
        b
    });
    let ended = wait_for(limit, || child.try_wait().unwrap().is_some());
    if !ended {
        let _ = child.kill();
    }
    let status = child.wait().unwrap();
    let stderr = err.join().unwrap();
    assert!(
        ended,
        "still running after {limit:?} (a hang): {}",
        String::from_utf8_lossy(&stderr)
    );
    Output {
        status,
        stdout: out.join().unwrap(),
        stderr,
    }
}

/// The map of `config` into `out` with `env`, bounded by `limit`: its points, JSON and stderr.
fn map_within(
    config: &Path,
    out: &Path,
    env: &[(&str, &str)],
    limit: Duration,
) -> (BTreeMap<u64, Vec<u8>>, Value, String) {
    let _ = std::fs::remove_file(out);
    let o = output_within(map_command(config, out, 2, env), limit);
    let stderr = String::from_utf8_lossy(&o.stderr).into_owned();
    assert!(o.status.success(), "map {env:?}: {stderr}");
    let json: Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(json["complete"], true, "{json}");
    let contents = read_map_file(out).unwrap();
    assert!(contents.damaged.is_none());
    let points = contents
        .points
        .into_iter()
        .map(|p| (p.index, p.encode_to_vec()))
        .collect();
    (points, json, stderr)
}

/// The lines of `stderr` about the C kernels.
fn c_lines(stderr: &str) -> Vec<&str> {
    stderr
        .lines()
        .filter(|l| l.contains("C step kernels"))
        .collect()
}

/// A compiler is an optimization: one that hangs (on its target query or on the build), crashes
/// or lies (garbage for a library, a FIFO where the library should be) costs the map at most
/// its deadline (`CHAOSCOPE_CC_TIMEOUT`, 2 s here) and one line naming the cause, and the map
/// is the Cranelift one bit for bit. A hung compiler's process is gone when the map ends. The
/// map waits for the build's outcome after three calls (`CHAOSCOPE_C_KERNELS_AFTER_CALLS`), so
/// every failure is met during the map rather than cancelled at its end.
#[test]
fn a_compiler_that_hangs_crashes_or_lies_costs_its_deadline_and_one_line() {
    let dir = tempfile::tempdir().unwrap();
    let config = dir.path().join("map.toml");
    std::fs::write(&config, hh_map("mpm", "gali-time")).unwrap();
    let out = dir.path().join("map.mcap");
    let none_cache = dir.path().join("none-cache");
    let (reference, _, _) = map(
        &config,
        &out,
        2,
        &[
            ("CHAOSCOPE_KERNEL_CACHE", s(&none_cache)),
            ("CHAOSCOPE_CC", "none"),
        ],
    );
    let pids = dir.path().join("pids");
    let hang = format!("echo $$ >> '{}'\nexec sleep 1000\n", pids.display());
    // `-o PATH` of a build (the target query has none).
    let output_arg =
        "out=\nprev=\nfor a in \"$@\"; do [ \"$prev\" = -o ] && out=\"$a\"; prev=\"$a\"; done\n";
    let cases = [
        (
            "hang",
            hang.clone(),
            "did not finish reporting its target within 2 s",
        ),
        (
            "hang-build",
            format!("case \" $* \" in *\" -shared \"*) {hang};; esac\nexec cc \"$@\"\n"),
            "did not finish compiling the step kernels within 2 s",
        ),
        // No core file left in the test's directory.
        (
            "crash",
            "ulimit -c 0\nkill -SEGV $$\n".into(),
            "failed to report its target",
        ),
        (
            "garbage",
            format!(
                "{output_arg}if [ -n \"$out\" ]; then echo 'not a library' > \"$out\"; exit 0; fi\n\
                 echo '#define __chaoscope_garbage__ ((('\nexit 0\n"
            ),
            "cannot load the compiled kernels",
        ),
        (
            "fifo",
            format!(
                "{output_arg}if [ -n \"$out\" ]; then mkfifo \"$out\"; exit 0; fi\nexec cc \"$@\"\n"
            ),
            "a FIFO, not a regular file",
        ),
    ];
    for (name, body, cause) in cases {
        let compiler = script(dir.path(), name, &body);
        let cache = dir.path().join(format!("cache-{name}"));
        let (points, json, stderr) = map_within(
            &config,
            &out,
            &[
                ("CHAOSCOPE_KERNEL_CACHE", s(&cache)),
                ("CHAOSCOPE_CC", s(&compiler)),
                ("CHAOSCOPE_CC_TIMEOUT", "2"),
                ("CHAOSCOPE_C_KERNELS_AFTER_CALLS", "3"),
            ],
            Duration::from_secs(120),
        );
        let said = c_lines(&stderr);
        assert_eq!(said.len(), 1, "{name}: said once: {stderr}");
        assert!(
            said[0].contains(cause) && said[0].contains("Cranelift"),
            "{name}: the line names the cause and the fallback: {}",
            said[0]
        );
        assert_eq!(json["expression_kernels"]["c_build"], "failed", "{name}");
        assert_eq!(calls(&json).1, 0, "{name}");
        assert!(points == reference, "{name}: the fallback changed the map");
        assert_eq!(processes_mentioning(&cache), Vec::<String>::new());
    }
    // A deadline that is not a positive number of seconds is said in that line too (the C
    // kernels off, the map the same).
    let cache = dir.path().join("cache-bad-timeout");
    let (points, json, stderr) = map_within(
        &config,
        &out,
        &[
            ("CHAOSCOPE_KERNEL_CACHE", s(&cache)),
            ("CHAOSCOPE_CC_TIMEOUT", "-1"),
            ("CHAOSCOPE_C_KERNELS_AFTER_CALLS", "3"),
        ],
        Duration::from_secs(120),
    );
    let said = c_lines(&stderr);
    assert_eq!(said.len(), 1, "said once: {stderr}");
    assert!(
        said[0].contains("CHAOSCOPE_CC_TIMEOUT='-1' is not a positive number of seconds"),
        "{}",
        said[0]
    );
    assert_eq!(json["expression_kernels"]["c_build"], "failed");
    assert!(points == reference, "a refused deadline changed the map");
    // Every hung compiler's process ended with its build.
    let hung: Vec<String> = std::fs::read_to_string(&pids)
        .unwrap()
        .lines()
        .map(String::from)
        .collect();
    assert_eq!(hung.len(), 2, "each hanging compiler ran once: {hung:?}");
    for pid in hung {
        assert!(
            !Path::new(&format!("/proc/{pid}")).exists(),
            "the hung compiler {pid} is still there"
        );
    }
}

/// A FIFO at any entry of one's own kernel cache (the compiler's target record, a library, its
/// digest) is refused in one line naming it, without being opened for reading (whose open or
/// read would wait for a writer for ever), and the command goes on without C kernels with the
/// same bits: a map that builds, and a short run that only loads.
#[test]
fn a_fifo_in_the_kernel_cache_is_refused_in_one_line_and_the_command_goes_on() {
    let dir = tempfile::tempdir().unwrap();
    let cache = dir.path().join("kernels");
    let config = dir.path().join("map.toml");
    std::fs::write(&config, fput_map(16, 2, 2.0, FPUT_LOOP, "vm")).unwrap();
    let out = dir.path().join("map.mcap");
    let cache_env = ("CHAOSCOPE_KERNEL_CACHE", s(&cache));
    let (reference, _, _) = map(&config, &out, 2, &[cache_env, ("CHAOSCOPE_CC", "none")]);
    // The kernels and the target record in the cache, by the system compiler.
    let (_, json, _) = map(
        &config,
        &out,
        2,
        &[cache_env, ("CHAOSCOPE_C_KERNELS_AFTER_CALLS", "0")],
    );
    assert_eq!(json["expression_kernels"]["c_build"], "compiled", "{json}");
    let short_run = || {
        let o = output_within(
            {
                let mut c = Command::new(env!("CARGO_BIN_EXE_chaoscope"));
                c.args(["bench", "--lattice-case", "expression:16:20"])
                    .env("RAYON_NUM_THREADS", "1")
                    .env("CHAOSCOPE_KERNEL_CACHE", &cache)
                    .env_remove("CHAOSCOPE_CC")
                    .env_remove("CHAOSCOPE_C_KERNELS_AFTER_CALLS");
                c
            },
            Duration::from_secs(120),
        );
        let stderr = String::from_utf8_lossy(&o.stderr).into_owned();
        assert!(o.status.success(), "{stderr}");
        let json: Value = serde_json::from_slice(&o.stdout).unwrap();
        (json, stderr)
    };
    let (loaded, _) = short_run();
    assert_eq!(loaded["c_kernels"], "loaded-from-cache", "{loaded}");
    let mut entries: Vec<String> = std::fs::read_dir(&cache)
        .unwrap()
        .flatten()
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .filter(|n| n.starts_with("target-") || n.starts_with("steps-"))
        .collect();
    entries.sort();
    assert!(
        entries.iter().any(|n| n.starts_with("target-"))
            && entries.iter().any(|n| n.ends_with(".so"))
            && entries.iter().any(|n| n.ends_with(".sha256")),
        "{entries:?}"
    );
    for name in &entries {
        let path = cache.join(name);
        let aside = dir.path().join("aside");
        std::fs::rename(&path, &aside).unwrap();
        let c_path = std::ffi::CString::new(path.to_str().unwrap()).unwrap();
        // SAFETY: mkfifo(3) of a NUL-terminated path.
        assert_eq!(unsafe { libc::mkfifo(c_path.as_ptr(), 0o600) }, 0);
        let (points, json, stderr) = map_within(
            &config,
            &out,
            &[cache_env, ("CHAOSCOPE_C_KERNELS_AFTER_CALLS", "3")],
            Duration::from_secs(120),
        );
        let said = c_lines(&stderr);
        assert_eq!(said.len(), 1, "{name}: said once: {stderr}");
        assert!(
            said[0].contains(name.as_str()) && said[0].contains("a FIFO, not a regular file"),
            "{name}: {}",
            said[0]
        );
        assert_eq!(json["expression_kernels"]["c_build"], "failed", "{name}");
        assert!(points == reference, "{name}: the fallback changed the map");
        let (run, stderr) = short_run();
        assert_eq!(run["c_kernels"], "not-started", "{name}: {run}");
        assert_eq!(
            run["final_state_digest"], loaded["final_state_digest"],
            "{name}"
        );
        let said = c_lines(&stderr);
        assert_eq!(said.len(), 1, "{name}: a short run says it too: {stderr}");
        assert!(
            said[0].contains("a FIFO, not a regular file"),
            "{}",
            said[0]
        );
        std::fs::remove_file(&path).unwrap();
        std::fs::rename(&aside, &path).unwrap();
    }
}
