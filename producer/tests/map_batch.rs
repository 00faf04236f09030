//! Map points from the batched kernel equal the one-orbit engine's bit for bit, for VM and MPM,
//! every indicator, every instruction set and thread count; and the map tells islands from the
//! chaotic sea.

use chaoscope_producer::batch::Isa;
use chaoscope_producer::map::{self, MapOptions, MapSpec, PointResult, PointStatus};
use chaoscope_schemas::config::RunConfig;

fn hh_map(method: &str, map: &str, t_final: f64, sets: usize) -> MapSpec {
    let text = format!(
        r#"
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
t_final = {t_final}
[deviations]
k = 2
sets = {sets}
seed = 3
[[scheme]]
name = "s"
method = "{method}"
d0 = 1e-8
tau = 1.0
[map]
{map}
"#
    );
    MapSpec::from_config(&RunConfig::from_toml(&text).unwrap()).unwrap()
}

/// A 4 x 3 grid over the section: chaotic, regular and outside-the-surface points.
const GRID: &str = r#"x = { coord = "q2", min = -0.45, max = 0.65, n = 4 }
y = { coord = "p2", min = -0.45, max = 0.45, n = 3 }"#;

fn batched(spec: &MapSpec, threads: usize, isa: Isa) -> Vec<PointResult> {
    let points: Vec<u64> = (0..spec.grid_points()).collect();
    let options = MapOptions {
        threads: Some(threads),
        isa,
        mpm_points_per_batch: 5,
    };
    let mut out = Vec::new();
    map::run_map(spec, &points, &options, |r| {
        out.push(r);
        true
    })
    .unwrap();
    out.sort_by_key(|r| r.index);
    out
}

fn check_against_engine(spec: &MapSpec) {
    let want: Vec<PointResult> = (0..spec.grid_points())
        .map(|i| map::one_orbit::point(spec, i))
        .collect();
    assert!(want.iter().any(|r| r.status == PointStatus::Ok));
    assert!(
        want.iter()
            .any(|r| r.status == PointStatus::OutsideEnergySurface)
    );
    for isa in Isa::ALL.into_iter().filter(|i| i.available()) {
        for threads in [1, 2] {
            let got = batched(spec, threads, isa);
            assert_eq!(got.len(), want.len());
            for (g, w) in got.iter().zip(&want) {
                assert!(
                    g.same_numbers(w),
                    "{} on {} with {threads} threads:\n batch  {g:?}\n engine {w:?}",
                    spec.indicator.name(),
                    isa.name()
                );
            }
        }
    }
}

#[test]
fn mpm_points_equal_the_engine() {
    check_against_engine(&hh_map(
        "mpm",
        &format!("{GRID}\nindicator = \"gali\""),
        30.0,
        3,
    ));
    check_against_engine(&hh_map(
        "mpm",
        &format!("{GRID}\nindicator = \"gali-time\"\nk = 3\nthreshold = 0.05"),
        30.0,
        3,
    ));
    check_against_engine(&hh_map(
        "mpm",
        &format!("{GRID}\nindicator = \"mle\""),
        20.0,
        2,
    ));
}

#[test]
fn vm_points_equal_the_engine() {
    check_against_engine(&hh_map(
        "vm",
        &format!("{GRID}\nindicator = \"gali\""),
        30.0,
        3,
    ));
    check_against_engine(&hh_map(
        "vm",
        &format!("{GRID}\nindicator = \"gali-time\"\nk = 3\nthreshold = 0.05"),
        30.0,
        3,
    ));
    check_against_engine(&hh_map(
        "vm",
        &format!("{GRID}\nindicator = \"mle\""),
        20.0,
        2,
    ));
}

#[test]
fn gali_time_stops_sets_early() {
    let spec = hh_map(
        "mpm",
        &format!("{GRID}\nindicator = \"gali-time\"\nk = 3\nthreshold = 0.05"),
        30.0,
        3,
    );
    let got = batched(&spec, 2, Isa::detect());
    let full = 3000 * (1 + 3 * 3);
    assert!(
        got.iter()
            .any(|r| r.status == PointStatus::Ok && r.orbit_steps < full && r.t_end < 30.0),
        "no point stopped early: {got:?}"
    );
    assert!(
        got.iter().any(|r| r.per_set.contains(&30.0)),
        "every set stopped: the test would not see censoring"
    );
}

#[test]
fn islands_and_the_chaotic_sea() {
    // The paper's regular (x2 = 0.558) and chaotic (x2 = -0.25) orbits, p2 = 0.
    let axes = r#"x = { coord = "q2", min = -0.25, max = 0.558, n = 2 }
y = { coord = "p2", min = 0.0, max = 0.0, n = 1 }"#;
    let gali = batched(
        &hh_map("mpm", &format!("{axes}\nindicator = \"gali\""), 300.0, 10),
        2,
        Isa::detect(),
    );
    let (chaotic, regular) = (&gali[0], &gali[1]);
    assert!(regular.mean_log10 > -2.0, "regular GALI_2 {regular:?}");
    assert!(chaotic.mean_log10 < -4.0, "chaotic GALI_2 {chaotic:?}");

    let mle = batched(
        &hh_map("vm", &format!("{axes}\nindicator = \"mle\""), 300.0, 4),
        2,
        Isa::detect(),
    );
    assert!(mle[0].value > 0.03, "chaotic MLE {}", mle[0].value);
    assert!(mle[1].value < 0.02, "regular MLE {}", mle[1].value);

    let time = batched(
        &hh_map(
            "mpm",
            &format!("{axes}\nindicator = \"gali-time\"\nk = 3\nthreshold = 1e-8"),
            300.0,
            10,
        ),
        2,
        Isa::detect(),
    );
    assert!(
        time[0].value < 250.0,
        "chaotic decay time {}",
        time[0].value
    );
    assert_eq!(
        time[1].value, 300.0,
        "regular orbit never decays below 1e-8"
    );
}

#[test]
fn escaping_orbits_are_marked_not_fatal() {
    // Above the escape energy 1/6 many orbits leave the potential well and blow up.
    let text = hh_map("mpm", &format!("{GRID}\nindicator = \"gali\""), 100.0, 2)
        .config_toml
        .replace("energy = 0.125", "energy = 0.3");
    let spec = MapSpec::from_config(&RunConfig::from_toml(&text).unwrap()).unwrap();
    let got = batched(&spec, 2, Isa::detect());
    let escaped: Vec<&PointResult> = got
        .iter()
        .filter(|r| r.status == PointStatus::Escaped)
        .collect();
    assert!(!escaped.is_empty(), "{got:?}");
    assert!(escaped.iter().all(|r| r.value.is_nan() && r.t_end < 100.0));
    for r in &got {
        assert!(
            r.same_numbers(&map::one_orbit::point(&spec, r.index)),
            "{r:?}"
        );
    }
}
