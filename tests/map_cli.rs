//! `chaoscope map` / `merge` end to end: shards merged equal the unsharded map exactly, and an
//! interrupted (or killed and truncated) map resumes to the same result.

use std::collections::BTreeMap;
use std::path::Path;
use std::process::Command;

use chaoscope_files::map_file::read_map_file;
use prost::Message;

/// A small HH map (9 x 7 points, t = 20) shared by the map tests.
const CONFIG: &str = include_str!("data/hh-map-small.toml");

fn dir() -> tempfile::TempDir {
    let d = tempfile::tempdir().unwrap();
    std::fs::write(d.path().join("map.toml"), CONFIG).unwrap();
    d
}

fn chaoscope(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_chaoscope"))
        .args(args)
        .output()
        .expect("chaoscope runs")
}

fn ok(args: &[&str]) {
    let out = chaoscope(args);
    assert!(
        out.status.success(),
        "chaoscope {args:?}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// The map's points by index, each as its exact protobuf bytes (NaN-safe equality).
fn points(path: &Path) -> BTreeMap<u64, Vec<u8>> {
    let contents = read_map_file(path).unwrap();
    assert!(contents.damaged.is_none());
    let mut map = BTreeMap::new();
    for p in contents.points {
        assert!(
            map.insert(p.index, p.encode_to_vec()).is_none(),
            "point twice"
        );
    }
    map
}

/// A small map over a parameter and a coordinate: the standard map's SALI over (K, p0) (6 x 5
/// points, 200 iterations), each point's K a lane value.
const PARAM_CONFIG: &str = r#"
[model]
name = "map"
next = ["x1 + x2 + K*sin(x1)", "x2 + K*sin(x1)"]
params = { K = 1.0 }
modulo = [6.283185307179586, 6.283185307179586]
[orbit]
x = [2.0, 0.0]
[integrator]
t_final = 200
[deviations]
k = 2
sets = 2
seed = 3
[[scheme]]
name = "mpm"
method = "mpm"
d0 = 1e-7
tau = 1
[map]
x = { param = "K", min = 0.2, max = 2.7, n = 6 }
y = { coord = "x2", min = -3.0, max = 3.0, n = 5 }
indicator = "sali"
"#;

/// A small map over a parameter of a `potential` (a coupling of Henon-Heiles) and a momentum:
/// the points' coupling a per-lane value of the compiled potential (5 x 4 points, t = 10).
const POTENTIAL_PARAM_CONFIG: &str = r#"
[model]
name = "potential"
n = 2
potential = "(q1^2 + q2^2)/2 + lam*(q1^2*q2 - q2^3/3)"
params = { lam = 1.0 }
[orbit]
q = [0.0, 0.1]
p = [0.3, 0.0]
[integrator]
method = "aba864"
h = 0.05
t_final = 10
[deviations]
k = 2
sets = 2
seed = 3
[[scheme]]
name = "vm"
method = "vm"
d0 = 1e-8
tau = 1
[map]
x = { param = "lam", min = 0.5, max = 2.5, n = 5 }
y = { coord = "p2", min = -0.2, max = 0.2, n = 4 }
indicator = "gali"
route = "per-set"
"#;

/// Shards at 1 and 2 threads merge into exactly the unsharded map's points, for a coordinate
/// map and maps over a parameter (whose header says so: `MapAxis.param`) of a discrete map and
/// of a potential.
#[test]
fn merged_shards_equal_the_unsharded_map() {
    merged_shards_equal_the_unsharded(CONFIG, 63);
    merged_shards_equal_the_unsharded(PARAM_CONFIG, 30);
    merged_shards_equal_the_unsharded(POTENTIAL_PARAM_CONFIG, 20);
    let tmp = dir();
    let (cfg, out) = (tmp.path().join("k.toml"), tmp.path().join("k.mcap"));
    std::fs::write(&cfg, PARAM_CONFIG).unwrap();
    ok(&["map", s(&cfg), "--out", s(&out), "--no-progress"]);
    let header = read_map_file(&out).unwrap().header.unwrap();
    let (x, y) = (header.x.unwrap(), header.y.unwrap());
    assert_eq!((x.param.as_str(), x.coord.as_str(), x.n), ("K", "", 6));
    assert_eq!((y.param.as_str(), y.coord.as_str()), ("", "x2"));
}

fn merged_shards_equal_the_unsharded(config: &str, grid_points: usize) {
    let tmp = dir();
    let d = tmp.path();
    let cfg = d.join("map.toml");
    std::fs::write(&cfg, config).unwrap();
    let whole = d.join("whole.mcap");
    ok(&[
        "map",
        s(&cfg),
        "--out",
        s(&whole),
        "--threads",
        "2",
        "--no-progress",
    ]);
    let mut shards = Vec::new();
    for i in 0..4 {
        let out = d.join(format!("shard{i}.mcap"));
        let threads = if i % 2 == 0 { "1" } else { "2" };
        let shard = format!("{i}/4");
        ok(&[
            "map",
            s(&cfg),
            "--out",
            s(&out),
            "--shard",
            &shard,
            "--threads",
            threads,
            "--no-progress",
        ]);
        shards.push(out);
    }
    let merged = d.join("merged.mcap");
    let png = d.join("merged.png");
    let mut args = vec!["merge", "--out", s(&merged), "--png", s(&png)];
    args.extend(shards.iter().map(|p| s(p)));
    ok(&args);
    let want = points(&whole);
    assert_eq!(want.len(), grid_points);
    assert_eq!(points(&merged), want);
    assert!(std::fs::metadata(&png).unwrap().len() > 1000);
    // A missing shard is refused.
    let out = chaoscope(&[
        "merge",
        "--out",
        s(&d.join("bad.mcap")),
        s(&shards[0]),
        s(&shards[1]),
    ]);
    assert!(!out.status.success());
}

#[test]
fn interrupted_and_killed_maps_resume() {
    let tmp = dir();
    let d = tmp.path();
    let cfg = d.join("map.toml");
    let whole = d.join("whole.mcap");
    ok(&["map", s(&cfg), "--out", s(&whole), "--no-progress"]);
    let want = points(&whole);

    // Interrupted (as by Ctrl-C) after 10 points, then resumed.
    let out = d.join("interrupted.mcap");
    let first = chaoscope(&[
        "map",
        s(&cfg),
        "--out",
        s(&out),
        "--no-progress",
        "--stop-after",
        "10",
    ]);
    assert_eq!(first.status.code(), Some(130));
    let partial = points(&out).len();
    assert!(
        (10..63).contains(&partial),
        "{partial} points after the interruption"
    );
    let second = chaoscope(&["map", s(&cfg), "--out", s(&out), "--no-progress", "--json"]);
    assert!(second.status.success());
    let summary: serde_json::Value = serde_json::from_slice(&second.stdout).unwrap();
    assert_eq!(summary["resumed"], partial as u64);
    // The estimate covers the points still to compute, not the grid.
    assert_eq!(
        summary["estimated_points"],
        summary["points_expected"].as_u64().unwrap() - partial as u64
    );
    // The route that ran: the one the config names.
    assert_eq!(summary["route"], "per-set");
    assert_eq!(points(&out), want);

    // Killed mid-write: the file is cut inside a chunk; the complete chunks are kept.
    let killed = d.join("killed.mcap");
    ok(&[
        "map",
        s(&cfg),
        "--out",
        s(&killed),
        "--no-progress",
        "--flush-interval",
        "0",
    ]);
    let bytes = std::fs::read(&killed).unwrap();
    std::fs::write(&killed, &bytes[..bytes.len() * 2 / 3]).unwrap();
    ok(&["map", s(&cfg), "--out", s(&killed), "--no-progress"]);
    assert_eq!(points(&killed), want);

    // Another configuration never silently mixes with an existing recording.
    std::fs::write(&cfg, CONFIG.replace("seed = 5", "seed = 6")).unwrap();
    let other = chaoscope(&["map", s(&cfg), "--out", s(&out), "--no-progress"]);
    assert!(!other.status.success());
    assert!(String::from_utf8_lossy(&other.stderr).contains("--restart"));
}

/// A grid axis over a coordinate the model declares periodic (`[model] modulo`) whose
/// `max - min` is one whole period repeats its first line as its last: `map` and `config` say
/// so, for the grid of a map as for those of a flow (`ode`) and of the Hamiltonians
/// (`hamiltonian`, `potential`, whose `modulo` runs over q1..qN, p1..pN). The pendulum's angle
/// is periodic, its momentum not (period 0): only the angle's axis is named, and a grid of the
/// angle ending one grid spacing short of the period (the `max` the warning proposes) is not.
#[test]
fn grids_spanning_a_declared_period_are_said_to_repeat_their_first_line() {
    let d = tempfile::tempdir().unwrap();
    const TWO_PI: &str = "6.283185307179586";
    let common = r#"
[deviations]
k = 2
sets = 1
seed = 1
[[scheme]]
name = "vm"
method = "vm"
d0 = 1e-8
tau = 1
"#;
    // (name, model table and orbit, integrator, angle, momentum)
    let models = [
        (
            "map",
            format!(
                "[model]\nname = \"map\"\nnext = [\"x1 + x2 + sin(x1)\", \"x2 + sin(x1)\"]\n\
                 modulo = [{TWO_PI}, 0]\n[orbit]\nx = [0.5, 0.0]\n"
            ),
            "[integrator]\nt_final = 10\n",
            "x1",
            "x2",
        ),
        (
            "ode",
            format!(
                "[model]\nname = \"ode\"\nrhs = [\"x2\", \"-sin(x1)\"]\nmodulo = [{TWO_PI}, 0]\n\
                 [orbit]\nx = [0.5, 0.0]\n"
            ),
            "[integrator]\nmethod = \"rk4\"\nh = 0.05\nt_final = 10\n",
            "x1",
            "x2",
        ),
        (
            "hamiltonian",
            format!(
                "[model]\nname = \"hamiltonian\"\nn = 1\nhamiltonian = \"p1^2/2 - cos(q1)\"\n\
                 modulo = [{TWO_PI}, 0]\n[orbit]\nq = [0.5]\np = [0.0]\n"
            ),
            "[integrator]\nmethod = \"gl4\"\nh = 0.05\nt_final = 10\n",
            "q1",
            "p1",
        ),
        (
            "potential",
            format!(
                "[model]\nname = \"potential\"\nn = 1\npotential = \"-cos(q1)\"\n\
                 modulo = [{TWO_PI}, 0]\n[orbit]\nq = [0.5]\np = [0.0]\n"
            ),
            "[integrator]\nmethod = \"aba864\"\nh = 0.05\nt_final = 10\n",
            "q1",
            "p1",
        ),
    ];
    let pi = std::f64::consts::PI;
    // One spacing short of the period: 5 distinct lines over [-pi, pi).
    let short = -pi + 2.0 * pi * 4.0 / 5.0;
    for (name, model, integrator, angle, momentum) in &models {
        for (max, repeats) in [(pi, true), (short, false)] {
            let text = format!(
                "{model}{integrator}{common}[map]\n\
                 x = {{ coord = \"{angle}\", min = {:?}, max = {max:?}, n = 5 }}\n\
                 y = {{ coord = \"{momentum}\", min = -2.0, max = 2.0, n = 3 }}\n\
                 indicator = \"sali\"\n",
                -pi
            );
            let path = d.path().join(format!("{name}.toml"));
            std::fs::write(&path, &text).unwrap();
            let out = chaoscope(&["config", s(&path)]);
            let stderr = String::from_utf8_lossy(&out.stderr);
            assert!(out.status.success(), "{name}: {stderr}\n{text}");
            let warned: Vec<&str> = stderr
                .lines()
                .filter(|l| l.contains("repeats the first"))
                .collect();
            if repeats {
                assert_eq!(warned.len(), 1, "{name}, max = {max}: {stderr}");
                assert!(
                    warned[0].contains(&format!("map.x: min = {} and max = {pi}", -pi))
                        && warned[0].contains(&format!("same point of {angle}")),
                    "{name}: {}",
                    warned[0]
                );
                // The max it proposes is the grid that stops short of the period.
                assert!(
                    warned[0].contains(&format!("max = {short}")),
                    "{name}: {}",
                    warned[0]
                );
            } else {
                assert!(warned.is_empty(), "{name}, max = {max}: {stderr}");
            }
        }
    }
}
