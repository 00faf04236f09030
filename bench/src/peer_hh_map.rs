//! The second workload of `chaoscope bench --peer heyoka`: the Henon-Heiles MLE map on the
//! section x = 0 at E = 1/8 (p_x > 0 solved from the energy), t = 1000, one tangent vector
//! renormalized every tau = 1, on an N x N grid over the paper's region of (y, p_y).
//!
//! chaoscope's side is the whole `chaoscope map` command (this executable, one thread, the
//! route it chooses by default), its CPU time that of the child process. The grid's initial
//! conditions are then read back from the map file it wrote and handed to the peer
//! (`benches/peer/heyoka_hh_map.py`, heyoka's `taylor_adaptive_batch` on the tangent system),
//! so both programs start from the same doubles. chaoscope's energy error is measured apart
//! from the timed command, by the one-orbit engine on each point of the map (the map file
//! holds indicators, not states).

use std::process::{Command, Stdio};

use anyhow::Context;
use chaoscope_dynamics::engine::Engine;
use chaoscope_dynamics::integrator::SplittingScheme;
use chaoscope_dynamics::model::{At, HenonHeiles, SeparableHamiltonian};
use chaoscope_dynamics::spec::RunSpec;
use chaoscope_files::map_file::read_map_file;
use chaoscope_indicators::StretchSums;
use chaoscope_schemas::config::RunConfig;
use chaoscope_schemas::proto::MapPoint;

/// The peer's side, shipped with the repository.
const HEYOKA_SCRIPT: &str = include_str!("../../benches/peer/heyoka_hh_map.py");

/// Energy of the section.
const ENERGY: f64 = 0.125;
/// Length of every orbit.
const T_FINAL: f64 = 1000.0;
/// The tangent vector both sides start from (normalized by both).
const VECTOR: [f64; 4] = [0.5, 0.5, 0.5, 0.5];
/// The default of both sides' accuracy (`--peer-map-method`, `--peer-map-h`, `--peer-map-tol`):
/// heyoka at tolerance 1e-11 keeps its largest relative energy error over the grid near 4e-12,
/// chaoscope's s17odr8 at h = 0.125 near 1.4e-12 (aba864 needs h = 0.01 for 2e-12, 2.6x the
/// time), both within the 1e-10 the workload allows with a margin of 25. heyoka at 1e-10
/// reaches 7e-11, too close to the bound on a large grid. The JSON reports each side's
/// measured error beside its setting.
pub const DEFAULT_METHOD: &str = "s17odr8";
/// What the workload asks of chaoscope: at least 1.5 times heyoka batch mode's speed per
/// thread, at the same energy error.
const TARGET_SPEEDUP: f64 = 1.5;
pub const DEFAULT_H: f64 = 0.125;
pub const DEFAULT_TOL: f64 = 1e-11;
/// The classification: chaotic when the MLE at t = 1000 is above 0.02. A regular orbit's
/// finite-time MLE decays like ln(t)/t, about 0.007 at t = 1000 (most tori of the grid give
/// 0.003-0.01), while the chaotic sea of Henon-Heiles at E = 1/8 gives 0.03-0.08 at that time;
/// on the 20 x 20 grid the histogram of the MLEs has its trough between 0.01 and 0.025 (26 of
/// 300 points), and 0.02 sits in it. Sticky orbits that linger near islands land in the
/// trough; those are the points two correct integrators may classify differently (their
/// chaotic trajectories part after a few hundred time units), which is why the count is
/// reported rather than assumed.
const CHAOTIC_MLE: f64 = 0.02;

/// The map's configuration: VM with k = 1 and the MLE indicator, the grid `n` x `n` over
/// `examples/maps/hh-mle.toml`'s region.
fn map_config(n: usize, (method, h): (&str, f64)) -> String {
    format!(
        r#"[model]
name = "henon-heiles"
[orbit]
q = [0.0, 0.0]
p = [0.0, 0.0]
energy = {ENERGY:?}
solve_for = "p1"
[integrator]
method = "{method}"
h = {h:?}
t_final = {T_FINAL:?}
[deviations]
k = 1
vectors = [{VECTOR:?}]
[[scheme]]
name = "vm"
method = "vm"
d0 = 1e-8
tau = 1.0
[map]
x = {{ coord = "q2", min = -0.45, max = 0.65, n = {n} }}
y = {{ coord = "p2", min = -0.45, max = 0.45, n = {n} }}
indicator = "mle"
"#
    )
}

/// The same orbit as one run (the map point's initial condition, its tangent vector and
/// scheme), for its energy error.
fn point_config(x0: &[f64], (method, h): (&str, f64)) -> String {
    format!(
        r#"[model]
name = "henon-heiles"
[orbit]
q = [{:?}, {:?}]
p = [{:?}, {:?}]
[integrator]
method = "{method}"
h = {h:?}
t_final = {T_FINAL:?}
[deviations]
k = 1
vectors = [{VECTOR:?}]
[[scheme]]
name = "vm"
method = "vm"
d0 = 1e-8
tau = 1.0
"#,
        x0[0], x0[1], x0[2], x0[3]
    )
}

fn hh_energy(s: &[f64]) -> f64 {
    HenonHeiles.energy(s, At::T0)
}

/// Every sample of the point `x0` run alone by the one-orbit engine with `step`.
fn each_sample(
    x0: &[f64],
    step: (&str, f64),
    mut f: impl FnMut(&chaoscope_schemas::run::Sample),
) -> anyhow::Result<()> {
    let cfg = RunConfig::from_toml(&point_config(x0, step))?;
    let mut engine = Engine::new(RunSpec::from_config(&cfg)?);
    while let Some(sample) = engine.next_sample()? {
        f(&sample);
    }
    Ok(())
}

/// Largest relative energy error over every tau of every point, by the one-orbit engine.
fn chaoscope_energy_error(points: &[MapPoint], step: (&str, f64)) -> anyhow::Result<f64> {
    let mut worst = 0.0f64;
    for p in points {
        let e0 = hh_energy(&p.x0);
        each_sample(&p.x0, step, |sample| {
            worst = worst.max(((hh_energy(&sample.state) - e0) / e0).abs());
        })?;
    }
    Ok(worst)
}

/// The second integrator of the self-check on the points classified differently: the default
/// method of a run, at the step that holds the workload's energy error.
const SECOND_STEP: (&str, f64) = ("aba864", 0.01);

/// The MLE at [`T_FINAL`] of the point `x0` by the one-orbit engine with `step`: its tangent
/// vector's stretching factors over the renormalizations (those carried with each sample, then
/// its own), summed as the analysis sums them.
fn one_orbit_mle(x0: &[f64], step: (&str, f64)) -> anyhow::Result<f64> {
    let (mut sums, mut t) = (StretchSums::new(1), 0.0);
    each_sample(x0, step, |sample| {
        if sample.seq > 0 {
            let set = &sample.schemes[0];
            for stretch in set
                .earlier_stretch
                .chunks_exact(1)
                .chain([&set.stretch[..]])
            {
                sums.add(stretch);
            }
        }
        t = sample.t;
    })?;
    anyhow::ensure!(t > 0.0, "the one-orbit run of {x0:?} took no step");
    Ok(sums.mle(t))
}

/// `chaoscope map` of the workload in `dir`: (CPU seconds of the child, its JSON summary, the
/// points it computed).
fn chaoscope_map(
    dir: &std::path::Path,
    n: usize,
    step: (&str, f64),
) -> anyhow::Result<(f64, serde_json::Value, Vec<MapPoint>)> {
    let exe = std::env::current_exe().context("this executable")?;
    let cfg = dir.join("hh-mle.toml");
    let out = dir.join("hh-mle.mcap");
    std::fs::write(&cfg, map_config(n, step))?;
    let before = chaoscope_os::cpu_time::children_seconds();
    let run = Command::new(&exe)
        .arg("map")
        .arg(&cfg)
        .arg("--out")
        .arg(&out)
        .args(["--threads", "1", "--json", "--no-progress", "--restart"])
        .env("RAYON_NUM_THREADS", "1")
        .stderr(Stdio::piped())
        .output()
        .context("starting chaoscope map")?;
    let cpu = chaoscope_os::cpu_time::children_seconds() - before;
    anyhow::ensure!(
        run.status.success(),
        "chaoscope map of the Henon-Heiles workload failed ({}): {}",
        run.status,
        String::from_utf8_lossy(&run.stderr).trim()
    );
    let summary: serde_json::Value =
        serde_json::from_slice(&run.stdout).context("chaoscope map --json printed no JSON")?;
    let contents = read_map_file(&out)?;
    let ok = chaoscope_schemas::proto::map_point::Status::Ok as i32;
    let points = contents
        .points
        .into_iter()
        .filter(|p| p.status == ok)
        .collect();
    Ok((cpu, summary, points))
}

/// The peer's JSON for `points`, or why there is none.
fn run_script(
    python: &str,
    dir: &std::path::Path,
    points: &[MapPoint],
    tol: f64,
) -> anyhow::Result<serde_json::Value> {
    let list: Vec<_> = points
        .iter()
        .map(|p| serde_json::json!({"index": p.index, "x0": p.x0}))
        .collect();
    let file = dir.join("points.json");
    std::fs::write(&file, serde_json::to_vec(&list)?)?;
    let mut args = vec![
        "--points".to_string(),
        file.display().to_string(),
        "--t-final".to_string(),
        format!("{T_FINAL:?}"),
        "--tol".to_string(),
        format!("{tol:?}"),
        "--vector".to_string(),
    ];
    args.extend(VECTOR.map(|v| format!("{v:?}")));
    super::peer::run_peer_script(
        python,
        "benches/peer/heyoka_hh_map.py",
        HEYOKA_SCRIPT,
        &args,
    )
}

/// How the two sides' MLEs compare point by point.
#[derive(Debug, Default)]
struct Agreement {
    /// Points classified the same (chaotic when the MLE exceeds [`CHAOTIC_MLE`]).
    same: usize,
    /// The largest MLE difference.
    max_diff: f64,
    /// The points classified differently: (index, initial state, chaoscope's MLE, the peer's).
    differ: Vec<(u64, Vec<f64>, f64, f64)>,
}

/// Compares `points` (chaoscope's) with the peer's MLEs by point index; points the peer did not
/// return are skipped.
fn agreement(points: &[MapPoint], theirs: &serde_json::Value) -> Agreement {
    let mut out = Agreement::default();
    for p in points {
        let Some(m) = theirs[p.index.to_string()].as_f64() else {
            continue;
        };
        if (p.value > CHAOTIC_MLE) == (m > CHAOTIC_MLE) {
            out.same += 1;
        } else {
            out.differ.push((p.index, p.x0.clone(), p.value, m));
        }
        out.max_diff = out.max_diff.max((p.value - m).abs());
    }
    out
}

/// The `hh_map` object of the report.
pub fn compare(
    n: usize,
    (method, h_step): (&str, f64),
    tol: f64,
    python: &str,
) -> anyhow::Result<serde_json::Value> {
    anyhow::ensure!(
        (2..=1000).contains(&n),
        "--peer-grid {n}: between 2 and 1000 points per axis"
    );
    anyhow::ensure!(
        SplittingScheme::from_name(method).is_some(),
        "--peer-map-method {method:?}: one of {}",
        SplittingScheme::catalogue()
    );
    anyhow::ensure!(
        h_step > 0.0 && (1.0 / h_step).fract() == 0.0 && h_step <= 0.5,
        "--peer-map-h {h_step}: a step of at most 0.5 that divides tau = 1 (0.01, 0.1, 0.125, 0.2, ...)"
    );
    anyhow::ensure!(
        (1e-16..=1e-6).contains(&tol),
        "--peer-map-tol {tol}: between 1e-16 and 1e-6"
    );
    let scratch = tempfile::Builder::new()
        .prefix("chaoscope-bench-peer-hh")
        .tempdir()?;
    let (cpu, summary, points) = chaoscope_map(scratch.path(), n, (method, h_step))?;
    let energy_error = chaoscope_energy_error(&points, (method, h_step))?;
    let peer = run_script(python, scratch.path(), &points, tol)?;
    let available = peer["heyoka_available"].as_bool() == Some(true);
    let mut chaoscope = serde_json::json!({
        "command": "chaoscope map --threads 1 (RAYON_NUM_THREADS=1), default route",
        "route": summary["route"],
        "method": format!("{method}, h = {h_step}, VM k = 1"),
        "cpu_seconds": cpu,
        "max_relative_energy_error": energy_error,
    });
    let (heyoka, ratio, same) = if available && peer["heyoka"].is_object() {
        let mut h = peer["heyoka"].clone();
        let a = agreement(&points, &h["mle"]);
        if let Some(o) = h.as_object_mut() {
            o.remove("mle");
        }
        h["max_mle_difference_to_chaoscope"] = serde_json::json!(a.max_diff);
        // Where the two disagree: a sticky orbit's finite-time MLE near the threshold, which
        // two correct integrators may put on either side (their chaotic trajectories part
        // after a few hundred time units); listed so a reader can check.
        // Each such point again by chaoscope alone, with the map's method through the
        // one-orbit engine (the map's MLE to rounding) and with a second integrator: where the
        // second puts the point on the other side of the threshold, or moves its MLE by more
        // than its distance to the threshold, chaoscope's own class of it depends on the
        // integrator, and no peer can be asked to match it.
        let mut self_split = 0;
        let mut listed = Vec::with_capacity(a.differ.len());
        for (index, x0, ours, theirs) in &a.differ {
            let same_method = one_orbit_mle(x0, (method, h_step))?;
            let second = one_orbit_mle(x0, SECOND_STEP)?;
            let splits = (second > CHAOTIC_MLE) != (*ours > CHAOTIC_MLE)
                || (second - ours).abs() > (ours - CHAOTIC_MLE).abs();
            self_split += usize::from(splits);
            listed.push(
                serde_json::json!({"index": index, "x0": x0, "chaoscope_mle": ours,
                "heyoka_mle": theirs, "chaoscope_one_orbit_mle": same_method,
                "chaoscope_second_integrator_mle": second,
                "chaoscope_second_integrator_moves_it_across_or_further_than_the_threshold":
                    splits}),
            );
        }
        h["classified_differently"] = serde_json::Value::Array(listed);
        h["second_integrator"] = serde_json::json!(format!(
            "chaoscope's one-orbit engine, {} at h = {}",
            SECOND_STEP.0, SECOND_STEP.1
        ));
        h["classified_differently_and_integrator_dependent_in_chaoscope"] =
            serde_json::json!(self_split);
        let same = a.same;
        let ratio = h["cpu_seconds"].as_f64().unwrap_or(f64::NAN) / cpu;
        (h, serde_json::json!(ratio), serde_json::json!(same))
    } else {
        (
            serde_json::Value::Null,
            serde_json::Value::Null,
            serde_json::Value::Null,
        )
    };
    chaoscope["points"] = serde_json::json!(points.len());
    Ok(serde_json::json!({
        "workload": format!(
            "Henon-Heiles MLE map, {n} x {n} grid on x = 0 (p_x > 0 from E = 1/8) over y in \
             [-0.45, 0.65], p_y in [-0.45, 0.45], t = 1000, one tangent vector renormalized \
             every tau = 1; one thread"
        ),
        "cpu": chaoscope_dynamics::estimate::Machine::cpu_model(),
        "isa": chaoscope_dynamics::batch::Isa::detect().name(),
        "grid": n,
        "points_total": n * n,
        "points_on_energy_surface": points.len(),
        "peer_available": available,
        "peer_unavailable": peer.get("heyoka_unavailable").cloned().unwrap_or(serde_json::Value::Null),
        "chaoscope": chaoscope,
        "heyoka": heyoka,
        "heyoka_cpu_over_chaoscope_cpu": ratio,
        "target_heyoka_cpu_over_chaoscope_cpu": TARGET_SPEEDUP,
        "meets_target": ratio.as_f64().map(|r| r >= TARGET_SPEEDUP),
        "classification": format!("chaotic when the MLE at t = 1000 is above {CHAOTIC_MLE}"),
        "classified_same": same,
        "classified_total": points.len(),
    }))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The map's configuration is a valid map of n x n points, and a point of its section run
    /// alone keeps the energy within the workload's 1e-10: s17odr8 at h = 0.125 is an
    /// eighth-order symplectic method whose energy error at E = 1/8 is of order 1e-12 and does
    /// not drift;
    /// a wrong initial condition (p_x not solved from E) or a wrong energy formula would be off
    /// by order 1e-2 or more.
    #[test]
    fn peer_hh_map_config_and_energy_error() {
        let cfg = RunConfig::from_toml(&map_config(5, (DEFAULT_METHOD, DEFAULT_H))).unwrap();
        let spec = chaoscope_dynamics::map::MapSpec::from_config(&cfg).unwrap();
        assert_eq!(spec.shard_points("0/1".parse().unwrap()).count(), 25);
        let (y, py) = (0.1, 0.0);
        let px = (2.0 * ENERGY - y * y - py * py + 2.0 * y * y * y / 3.0).sqrt();
        let point = MapPoint {
            x0: vec![0.0, y, px, py],
            ..Default::default()
        };
        assert!((hh_energy(&point.x0) - ENERGY).abs() < 1e-15);
        let e = chaoscope_energy_error(std::slice::from_ref(&point), (DEFAULT_METHOD, DEFAULT_H))
            .unwrap();
        assert!(e > 0.0 && e < 1e-10, "{e}");
    }

    /// The self-check's MLE: the README's chaotic orbit (y = -0.25, p_y = 0) stretches its
    /// vector at about 0.04 per time unit by t = 1000 with either integrator, a point of a torus
    /// (y = 0.1, p_y = 0) at about ln(t)/t (0.0049 by both); a sum of stretches not divided by
    /// the time, or a stretch missed per sample, would put both far off.
    #[test]
    fn the_self_checks_mle_tells_the_chaotic_orbit_from_a_torus() {
        const REGULAR_Y: f64 = 0.1;
        let at = |y: f64| {
            let px = (2.0 * ENERGY - y * y + 2.0 * y * y * y / 3.0).sqrt();
            [0.0, y, px, 0.0]
        };
        for step in [(DEFAULT_METHOD, DEFAULT_H), SECOND_STEP] {
            let chaotic = one_orbit_mle(&at(-0.25), step).unwrap();
            assert!((0.03..0.06).contains(&chaotic), "{step:?}: {chaotic}");
            let regular = one_orbit_mle(&at(REGULAR_Y), step).unwrap();
            assert!(regular > 0.0 && regular < 0.012, "{step:?}: {regular}");
        }
    }

    /// Classification counts a point the same when both MLEs fall on one side of the threshold,
    /// skips points the peer did not return, and reports the largest difference.
    #[test]
    fn peer_hh_map_agreement_counts() {
        let p = |index: u64, value: f64| MapPoint {
            index,
            value,
            ..Default::default()
        };
        let ours = [p(0, 0.005), p(1, 0.045), p(2, 0.019), p(3, 0.03)];
        let theirs = serde_json::json!({"0": 0.006, "1": 0.05, "2": 0.021});
        let a = agreement(&ours, &theirs);
        assert_eq!(a.same, 2);
        assert!((a.max_diff - 0.005).abs() < 1e-12, "{}", a.max_diff);
        let differ: Vec<u64> = a.differ.iter().map(|d| d.0).collect();
        assert_eq!(differ, [2]);
    }
}
