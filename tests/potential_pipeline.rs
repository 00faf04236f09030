//! User-written potentials through the whole pipeline with real processes: the Hertzian granular chain with a `[[sweep]]` over d0 is
//! recorded, analyzed (the V shape of the MPM-VM distance against d0), replayed with another
//! tau on the bit-identical orbit, and mapped; a potential with `abs` is refused for VM and runs
//! by MPM; a replay refuses a table that changed since the recording.

use crate::common;

use std::path::Path;

use crate::common::{chaoscope_captured as chaoscope, run_ok};
use chaoscope_schemas::config::{MapAxis, MapConfig, ModelConfig, RunConfig};
use serde_json::Value;

fn models_dir() -> std::path::PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("examples/models")
}

fn hertz(t_final: f64) -> RunConfig {
    let text = std::fs::read_to_string(models_dir().join("hertz-chain.toml")).unwrap();
    let mut config = RunConfig::from_toml(&text).unwrap();
    config.integrator.t_final = t_final;
    config.run.name = Some(common::unique_run("hertz"));
    config
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

#[test]
fn hertz_chain_records_analyzes_replays_and_maps() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let cfg = d.join("hertz.toml");
    std::fs::write(&cfg, hertz(200.0).to_toml()).unwrap();
    let rec = d.join("hertz.mcap");
    run_ok(&["run", s(&cfg), "--out", s(&rec)]);

    // The V shape: |log10 GALI_2(MPM) - log10 GALI_2(VM)| at t = 200 against d0. Large d0 leave
    // the linear regime (the contacts' nonlinearity), small d0 drown in the rounding of
    // x + d (about eps |x| / d0); in between the two agree closely.
    let report: Value = serde_json::from_str(&run_ok(&["analyze", s(&rec), "--json"])).unwrap();
    let mut v: Vec<(f64, f64)> = report["schemes"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|s| s["method"] == "mpm")
        .map(|s| {
            (
                s["d0"].as_f64().unwrap(),
                s["vs_vm"]["gali"]["2"]["mean_abs_delta_log10"]
                    .as_f64()
                    .unwrap(),
            )
        })
        .collect();
    v.sort_by(|a, b| a.0.total_cmp(&b.0));
    assert_eq!(v.len(), 13, "d0 = 1e-14 .. 1e-2, one per decade");
    for (d0, dist) in &v {
        eprintln!("Hertz chain, t = 200: d0 = {d0:e}: |dlog10 GALI_2| = {dist:.3e}");
    }
    let (best_d0, best) = v
        .iter()
        .copied()
        .min_by(|a, b| a.1.total_cmp(&b.1))
        .unwrap();
    assert!(
        (1e-11..=1e-5).contains(&best_d0),
        "the closest MPM is at d0 = {best_d0:e}"
    );
    assert!(v[0].1 > 10.0 * best && v[12].1 > 10.0 * best, "{v:?}");

    // Replay with another tau: the recorded orbit again, bit for bit.
    let replayed = d.join("replay.mcap");
    let out = run_ok(&[
        "replay",
        s(&rec),
        "--tau",
        "2",
        "--out",
        s(&replayed),
        "--json",
    ]);
    let outcome: Value = serde_json::from_str(out.lines().last().unwrap()).unwrap();
    assert!(outcome["reference_states_compared"].as_u64().unwrap() > 0);
    assert_eq!(
        outcome["reference_states_compared"],
        outcome["reference_states_identical"]
    );
    assert_eq!(
        outcome["separation_sets_compared"],
        outcome["separation_sets_identical"]
    );

    // A map of the chain over (q1, p1): MPM, GALI_2.
    let mut map_config = hertz(20.0);
    map_config.sweeps.clear();
    map_config.schemes[0].method = "mpm".into();
    map_config.schemes[0].name = "mpm".into();
    map_config.map = Some(MapConfig {
        k: Some(2),
        ..MapConfig::new(
            MapAxis::new("q1", -0.004, 0.004, 4),
            MapAxis::new("p1", -0.05, 0.05, 3),
            "gali",
        )
    });
    let map_cfg = d.join("map.toml");
    std::fs::write(&map_cfg, map_config.to_toml()).unwrap();
    let map = d.join("map.mcap");
    run_ok(&["map", s(&map_cfg), "--out", s(&map)]);
    let contents = chaoscope_files::map_file::read_map_file(&map).unwrap();
    assert_eq!(contents.points.len(), 12);
    assert!(contents.points.iter().all(|p| p.value.is_finite()));
}

#[test]
fn abs_is_refused_for_vm_and_runs_by_mpm() {
    let dir = tempfile::tempdir().unwrap();
    let mut config = hertz(10.0);
    config.sweeps.clear();
    // A kink: no continuous first derivative where a bond length crosses zero.
    let ModelConfig::Potential(model) = &mut config.model else {
        panic!("the Hertz chain is a potential")
    };
    model.potential = Some("sum(i = 0..N, A*(q[i+1] - q[i])^2 + delta0*abs(q[i+1] - q[i]))".into());
    let cfg = dir.path().join("abs.toml");
    std::fs::write(&cfg, config.to_toml()).unwrap();
    let rec = dir.path().join("abs.mcap");
    let out = chaoscope(&["run", s(&cfg), "--out", s(&rec)])
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("'abs'") && err.contains("column"), "{err}");
    assert!(!rec.exists(), "a refused run leaves no file");

    config.schemes[0].method = "mpm".into();
    std::fs::write(&cfg, config.to_toml()).unwrap();
    run_ok(&["run", s(&cfg), "--out", s(&rec)]);
}

#[test]
fn replay_refuses_a_changed_table() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    std::fs::copy(models_dir().join("fput-bond.csv"), d.join("fput-bond.csv")).unwrap();
    let text = std::fs::read_to_string(models_dir().join("tabulated-bond.toml")).unwrap();
    let mut config = RunConfig::from_toml(&text).unwrap();
    config.integrator.t_final = 5.0;
    config.run.name = Some(common::unique_run("table"));
    let cfg = d.join("tabulated.toml");
    std::fs::write(&cfg, config.to_toml()).unwrap();
    let rec = d.join("tabulated.mcap");
    // The table's relative path is taken from the config file's directory.
    run_ok(&["run", s(&cfg), "--out", s(&rec)]);
    let replayed = d.join("replay.mcap");
    run_ok(&["replay", s(&rec), "--tau", "0.5", "--out", s(&replayed)]);

    // Change one sample: the replay must refuse, naming the table and the digests.
    let csv = d.join("fput-bond.csv");
    let changed = std::fs::read_to_string(&csv)
        .unwrap()
        .replacen("-3,24.75", "-3,24.76", 1);
    std::fs::write(&csv, changed).unwrap();
    let out = chaoscope(&[
        "replay",
        s(&rec),
        "--tau",
        "0.5",
        "--out",
        s(&d.join("again.mcap")),
    ])
    .output()
    .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("sha256") && err.contains("differs"), "{err}");
}

#[test]
fn map_resume_refuses_a_changed_table() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    std::fs::copy(models_dir().join("fput-bond.csv"), d.join("fput-bond.csv")).unwrap();
    let text = std::fs::read_to_string(models_dir().join("tabulated-bond.toml")).unwrap();
    let mut config = RunConfig::from_toml(&text).unwrap();
    config.integrator.t_final = 2.0;
    config.schemes.retain(|s| s.method == "mpm");
    config.map = Some(MapConfig {
        k: Some(2),
        ..MapConfig::new(
            MapAxis::new("q2", -0.2, 0.2, 3),
            MapAxis::new("p2", -0.2, 0.2, 2),
            "gali",
        )
    });
    let cfg = d.join("map.toml");
    std::fs::write(&cfg, config.to_toml()).unwrap();
    let map = d.join("map.mcap");
    run_ok(&["map", s(&cfg), "--out", s(&map)]);
    let before = std::fs::read(&map).unwrap();

    let csv = d.join("fput-bond.csv");
    let changed = std::fs::read_to_string(&csv)
        .unwrap()
        .replacen("-3,24.75", "-3,24.76", 1);
    std::fs::write(&csv, changed).unwrap();
    let out = chaoscope(&["map", s(&cfg), "--out", s(&map)])
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("another table") && err.contains("'U'"),
        "{err}"
    );
    assert_eq!(
        std::fs::read(&map).unwrap(),
        before,
        "the map file is left untouched"
    );
}
