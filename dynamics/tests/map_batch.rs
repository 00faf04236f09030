//! Map points from the batched kernel equal the one-orbit engine's bit for bit, for VM and MPM,
//! every indicator, every instruction set and thread count; and the map tells islands from the
//! chaotic sea.

use chaoscope_dynamics::batch::Isa;
use chaoscope_dynamics::engine::{Engine, RunError};
use chaoscope_dynamics::map::{self, MapOptions, MapSpec, PointResult, PointStatus};
use chaoscope_schemas::config::{
    DeviationsConfig, MapAxis, MapConfig, RunConfig, SchemeConfig, paper,
};
use chaoscope_schemas::run::escape_time;

/// A map of the paper's Henon-Heiles section (k = 2, one scheme of `method`).
fn hh_map(method: &str, map: MapConfig, t_final: f64, sets: usize) -> MapSpec {
    MapSpec::from_config(&hh_map_config(method, map, t_final, sets)).unwrap()
}

fn hh_map_config(method: &str, map: MapConfig, t_final: f64, sets: usize) -> RunConfig {
    // q2 and p2 come from the grid; p1 is solved per point.
    let mut config = paper::henon_heiles(
        0.0,
        t_final,
        DeviationsConfig::random(2, sets, 3),
        vec![SchemeConfig::new("s", method, 1e-8, 1.0)],
    );
    config.map = Some(map);
    config
}

/// A 4 x 3 grid over the section: chaotic, regular and outside-the-surface points.
fn grid(indicator: &str) -> MapConfig {
    paper::hh_section_map(4, 3, indicator)
}

/// `gali-time` of GALI_3 with the given threshold.
fn gali3_time(threshold: f64) -> MapConfig {
    MapConfig {
        k: Some(3),
        threshold: Some(threshold),
        ..grid("gali-time")
    }
}

fn batched(spec: &MapSpec, threads: usize, isa: Isa) -> Vec<PointResult> {
    let points: Vec<u64> = (0..spec.grid_points()).collect();
    let options = MapOptions {
        threads: Some(threads),
        isa,
        mpm_points_per_batch: 5,
        termination: None,
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
    check_against_engine(&hh_map("mpm", grid("gali"), 30.0, 3));
    check_against_engine(&hh_map("mpm", gali3_time(0.05), 30.0, 3));
    check_against_engine(&hh_map("mpm", grid("mle"), 20.0, 2));
    check_against_engine(&hh_map("mpm", grid("megno"), 20.0, 2));
    check_against_engine(&hh_map("mpm", grid("fli"), 20.0, 2));
}

#[test]
fn vm_points_equal_the_engine() {
    check_against_engine(&hh_map("vm", grid("gali"), 30.0, 3));
    check_against_engine(&hh_map("vm", gali3_time(0.05), 30.0, 3));
    check_against_engine(&hh_map("vm", grid("mle"), 20.0, 2));
    check_against_engine(&hh_map("vm", grid("fli"), 20.0, 2));
    check_against_engine(&hh_map("vm", grid("megno_mean"), 20.0, 2));
    // One set of one vector (the MLE) and of two (SALI): the fused per-set route's lanes of 8
    // and 12 rows, which Henon-Heiles steps in registers, two vectors wide on AVX-512.
    let one_set = |indicator: &str, k: usize| MapConfig {
        k: Some(k),
        ..grid(indicator)
    };
    check_against_engine(&hh_map("vm", one_set("mle", 1), 20.0, 1));
    check_against_engine(&hh_map("vm", one_set("sali", 2), 20.0, 1));
    // GALI_3 times of two sets (6 vectors, a fused lane): sets stop at their own windows.
    check_against_engine(&hh_map("vm", gali3_time(0.05), 30.0, 2));
}

#[test]
fn gali_time_stops_sets_early() {
    let spec = hh_map("mpm", gali3_time(0.05), 30.0, 3);
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
    // Two points: the paper's chaotic and regular orbits (p2 = 0).
    let orbits = |indicator: &str| {
        MapConfig::new(
            MapAxis::new("q2", paper::HH_CHAOTIC_Q2, paper::HH_REGULAR_Q2, 2),
            MapAxis::new("p2", 0.0, 0.0, 1),
            indicator,
        )
    };
    let gali = batched(&hh_map("mpm", orbits("gali"), 300.0, 10), 2, Isa::detect());
    let (chaotic, regular) = (&gali[0], &gali[1]);
    assert!(regular.mean_log10 > -2.0, "regular GALI_2 {regular:?}");
    assert!(chaotic.mean_log10 < -4.0, "chaotic GALI_2 {chaotic:?}");

    let mle = batched(&hh_map("vm", orbits("mle"), 300.0, 4), 2, Isa::detect());
    assert!(mle[0].value > 0.03, "chaotic MLE {}", mle[0].value);
    assert!(mle[1].value < 0.02, "regular MLE {}", mle[1].value);

    // MEGNO's mean and FLI through the one indicator interface (`indicator = "megno_mean"`,
    // `"fli"`), at t = 1000 (tau = 1). On the regular orbit the first vector grows linearly,
    // |w| ~ a + b t, so Y -> 2 and its mean -> 2 from below, the start weighing like
    // ln(t) / t: at t = 1000 the mean is within 0.4 of 2 (about 1.8 here; at t = 300 still
    // 1.3). On the chaotic one megno_mean ~ lambda_1 t / 2 ~ 0.04 * 500 = 20: above 10 allows
    // the finite-time exponent to be half its value, and is far from 2.
    let megno = batched(
        &hh_map("vm", orbits("megno_mean"), 1000.0, 4),
        2,
        Isa::detect(),
    );
    assert!(
        megno[0].value > 10.0,
        "chaotic megno_mean {}",
        megno[0].value
    );
    assert!(
        (megno[1].value - 2.0).abs() < 0.4,
        "regular megno_mean {}",
        megno[1].value
    );
    // FLI from t = 300 to t = 1000: on the regular orbit ln |w| = ln(a + b t) gains
    // ln(1000 / 300) = 1.20 (within 0.5: the tangent vector's oscillation about the linear
    // growth), on the chaotic one lambda_1 * 700 ~ 28 (above 14: half of it at least).
    let fli_300 = batched(&hh_map("mpm", orbits("fli"), 300.0, 4), 2, Isa::detect());
    let fli = batched(&hh_map("mpm", orbits("fli"), 1000.0, 4), 2, Isa::detect());
    let gain = |i: usize| fli[i].value - fli_300[i].value;
    assert!(
        gain(0) > 14.0,
        "chaotic FLI {} -> {}",
        fli_300[0].value,
        fli[0].value
    );
    assert!(
        (gain(1) - (1000f64 / 300.0).ln()).abs() < 0.5,
        "regular FLI {} -> {}",
        fli_300[1].value,
        fli[1].value
    );

    let time = batched(
        &hh_map(
            "mpm",
            MapConfig {
                k: Some(3),
                threshold: Some(1e-8),
                ..orbits("gali-time")
            },
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
    let mut config = hh_map_config("mpm", grid("gali"), 100.0, 2);
    config.orbit.energy = Some(0.3);
    let spec = MapSpec::from_config(&config).unwrap();
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

/// The stop of `spec`'s run from point `index`'s initial condition (the engine of `chaoscope
/// run`, its deviation sets stepped by the batched form) and of a map of that one point.
fn run_and_map_point_stop(spec: &MapSpec, index: u64) -> (RunError, PointResult) {
    let (_, x0) = spec.start_point(index).unwrap();
    let mut engine = Engine::new(spec.point_run(&x0));
    let stop = loop {
        match engine.next_sample() {
            Ok(Some(_)) => continue,
            Ok(None) => panic!("point {index} should escape"),
            Err(e) => break e,
        }
    };
    let mut point = Vec::new();
    map::run_map(spec, &[index], &MapOptions::default(), |r| {
        point.push(r);
        true
    })
    .unwrap();
    (stop, point.pop().unwrap())
}

/// An escaping orbit stops a run and a one-point map of the same initial condition alike: the
/// same time (the end of the window the escape was found in), the same verdict (`escaped`, its
/// time read back from the reason) and the same message, naming the step that left, on both map
/// routes, with either method, for a Hamiltonian flow and a discrete map.
#[test]
fn an_escaping_orbit_stops_a_run_and_its_map_point_alike() {
    let mut cases = Vec::new();
    for (method, route) in [
        ("mpm", "per-set"),
        ("vm", "per-set"),
        ("vm", "basis"),
        ("mpm", "basis"),
    ] {
        let map = MapConfig {
            route: Some(route.into()),
            ..grid("gali")
        };
        let mut config = hh_map_config(method, map, 100.0, 2);
        config.orbit.energy = Some(0.3);
        cases.push((format!("HH {method} {route}"), config));
    }
    let mut specs: Vec<(String, MapSpec)> = cases
        .iter()
        .map(|(name, c)| (name.clone(), MapSpec::from_config(c).unwrap()))
        .collect();
    for method in ["vm", "mpm"] {
        specs.push((
            format!("Henon map {method}"),
            discrete_map(method, "gali", 4, false),
        ));
    }
    for (name, spec) in &specs {
        let escaping: Vec<u64> = batched(spec, 1, Isa::detect())
            .iter()
            .filter(|r| r.status == PointStatus::Escaped)
            .map(|r| r.index)
            .collect();
        assert!(!escaping.is_empty(), "{name}: no point escapes");
        for &index in escaping.iter().take(2) {
            let (stop, point) = run_and_map_point_stop(spec, index);
            assert!(
                matches!(stop, RunError::Escaped { cause: Some(_), .. }),
                "{name}: {stop}"
            );
            // Exact: both drivers run one window test on the same bits of the same orbit.
            assert_eq!(point.status, PointStatus::Escaped, "{name}");
            assert_eq!(
                point.t_end.to_bits(),
                stop.t().to_bits(),
                "{name}: {point:?}"
            );
            assert_eq!(point.reason, stop.to_string(), "{name}");
            assert_eq!(escape_time(&point.reason), Some(point.t_end), "{name}");
        }
    }
}

/// A map of a discrete system written in the config: the Henon map over a square where most
/// orbits escape to infinity (and overflow to NaN) and the rest fall on the attractor, or the
/// standard map on the torus (both coordinates wrapped, MPM separations on the torus).
fn discrete_map(method: &str, indicator: &str, tau: u32, standard: bool) -> MapSpec {
    let model = if standard {
        "name = \"map\"\nnext = [\"x1 + x2 + K*sin(x1)\", \"x2 + K*sin(x1)\"]\n\
         params = { K = 1.0 }\nmodulo = [6.283185307179586, 6.283185307179586]"
    } else {
        "name = \"map\"\nnext = [\"1 - a*x1^2 + x2\", \"b*x1\"]\nparams = { a = 1.4, b = 0.3 }"
    };
    let (x, y) = if standard {
        (
            "{ coord = \"x1\", min = 0.0, max = 6.2, n = 5 }",
            "{ coord = \"x2\", min = -3.1, max = 3.1, n = 4 }",
        )
    } else {
        (
            "{ coord = \"x1\", min = -1.5, max = 1.5, n = 5 }",
            "{ coord = \"x2\", min = -0.6, max = 0.6, n = 4 }",
        )
    };
    let k = if indicator == "mle" { 1 } else { 2 };
    let text = format!(
        "[model]\n{model}\n[orbit]\nx = [0.0, 0.0]\n[integrator]\nh = 1\nt_final = 300\n\
         [deviations]\nk = {k}\nsets = 3\nseed = 5\n\
         [[scheme]]\nname = \"s\"\nmethod = \"{method}\"\nd0 = 1e-7\ntau = {tau}\n\
         [map]\nx = {x}\ny = {y}\nindicator = \"{indicator}\"\n"
    );
    let spec = MapSpec::from_config(&RunConfig::from_toml(&text).unwrap()).unwrap();
    assert!(
        spec.has_batched_kernel(),
        "a discrete map runs on the batched kernel"
    );
    spec
}

/// Discrete maps on the batched kernel (their compiled lane functions) equal the one-orbit
/// engine point for point, bit for bit, with 1 and 2 threads: orbits that stay bounded, orbits
/// that escape (the status and the window they stopped in), wrapped coordinates.
#[test]
fn discrete_map_points_equal_the_engine() {
    let mut statuses = Vec::new();
    for (method, indicator, tau, standard) in [
        ("vm", "sali", 1, true),
        ("mpm", "gali", 1, true),
        ("mpm", "mle", 3, true),
        ("vm", "gali", 1, false),
        ("mpm", "gali", 4, false),
        ("vm", "mle", 2, false),
        ("mpm", "megno", 1, true),
        ("vm", "fli", 2, false),
    ] {
        let spec = discrete_map(method, indicator, tau, standard);
        let want: Vec<PointResult> = (0..spec.grid_points())
            .map(|i| map::one_orbit::point(&spec, i))
            .collect();
        for threads in [1, 2] {
            let got = batched(&spec, threads, Isa::detect());
            assert_eq!(got.len(), want.len());
            for (g, w) in got.iter().zip(&want) {
                assert!(
                    g.same_numbers(w)
                        && (g.status != PointStatus::Ok || g.orbit_steps == w.orbit_steps),
                    "{method} {indicator} tau {tau} with {threads} threads:\n batch  {g:?}\n engine {w:?}"
                );
            }
        }
        statuses.extend(want.iter().map(|r| r.status));
    }
    // Both outcomes were exercised: the comparison covers escapes as well as finished points.
    assert!(statuses.contains(&PointStatus::Ok));
    assert!(statuses.contains(&PointStatus::Escaped));
}

/// A map of a flow written in the config (`ode`: Lorenz; `hamiltonian`: Henon-Heiles in a
/// magnetic field) with a fixed-step explicit method, or with a method that has no batched form.
fn flow_map(system: &str, method: &str, scheme: &str, indicator: &str) -> MapSpec {
    let model = match system {
        // The driven Duffing oscillator, `t` written explicitly: the lanes take every stage at
        // its time (every point starts at t = 0).
        "duffing" => {
            "name = \"ode\"\nrhs = [\"x2\", \"-0.3*x2 + x1 - x1^3 + 0.5*cos(1.2*t)\"]\n\
             [orbit]\nx = [1.0, 0.0]"
        }
        "driven" => {
            "name = \"hamiltonian\"\nn = 2\nhamiltonian = \"((p1 + B*q2/2)^2 + (p2 - B*q1/2)^2)/2 \
             + (q1^2 + q2^2)/2 + q1^2*q2 - q2^3/3 + 0.05*q1*sin(3*t)\"\nparams = { B = 0.2 }\n\
             [orbit]\nq = [0.0, 0.0]\np = [0.3, 0.0]"
        }
        "lorenz" => {
            "name = \"ode\"\nrhs = [\"sigma*(x2 - x1)\", \"x1*(rho - x3) - x2\", \"x1*x2 - beta*x3\"]\n\
             params = { sigma = 10.0, rho = 28.0, beta = 2.6666666666666665 }\n\
             [orbit]\nx = [1.0, 1.0, 20.0]"
        }
        _ => {
            "name = \"hamiltonian\"\nn = 2\nhamiltonian = \"((p1 + B*q2/2)^2 + (p2 - B*q1/2)^2)/2 \
             + (q1^2 + q2^2)/2 + q1^2*q2 - q2^3/3\"\nparams = { B = 0.2 }\n\
             [orbit]\nq = [0.0, 0.0]\np = [0.3, 0.0]"
        }
    };
    let (x, y) = if system == "lorenz" || system == "duffing" {
        ("x1", "x2")
    } else {
        ("q2", "p2")
    };
    let k = if indicator == "mle" { 1 } else { 2 };
    let text = format!(
        "[model]\n{model}\n[integrator]\nmethod = \"{method}\"\nh = 0.01\nt_final = 3\n\
         [deviations]\nk = {k}\nsets = 2\nseed = 5\n\
         [[scheme]]\nname = \"s\"\nmethod = \"{scheme}\"\nd0 = 1e-8\ntau = 0.5\n\
         [map]\nx = {{ coord = \"{x}\", min = -0.3, max = 0.3, n = 3 }}\n\
         y = {{ coord = \"{y}\", min = -0.2, max = 0.2, n = 2 }}\nindicator = \"{indicator}\"\n"
    );
    MapSpec::from_config(&RunConfig::from_toml(&text).unwrap()).unwrap()
}

/// Flows of compiled expressions with a fixed-step explicit Runge-Kutta method run on the
/// batched kernel and equal the engine bit for bit (VM and MPM, rk4 and dop853, an `ode` and a
/// `hamiltonian`, each also with explicit time); implicit and adaptive methods keep the engine
/// path.
#[test]
fn flow_points_equal_the_engine() {
    for (system, method, scheme, indicator) in [
        ("lorenz", "rk4", "vm", "gali"),
        ("lorenz", "dop853", "mpm", "mle"),
        ("magnetic", "rk4", "mpm", "gali"),
        ("magnetic", "dop853", "vm", "sali"),
        ("lorenz", "rk4", "mpm", "fli"),
        ("magnetic", "dop853", "vm", "megno_mean"),
        ("duffing", "rk4", "vm", "gali"),
        ("duffing", "dop853", "mpm", "mle"),
        ("driven", "rk4", "mpm", "sali"),
        ("driven", "dop853", "vm", "gali"),
    ] {
        let spec = flow_map(system, method, scheme, indicator);
        assert!(spec.has_batched_kernel(), "{system} {method}");
        let want: Vec<PointResult> = (0..spec.grid_points())
            .map(|i| map::one_orbit::point(&spec, i))
            .collect();
        assert!(want.iter().all(|r| r.status == PointStatus::Ok), "{want:?}");
        for threads in [1, 2] {
            let got = batched(&spec, threads, Isa::detect());
            assert_eq!(got.len(), want.len());
            for (g, w) in got.iter().zip(&want) {
                assert!(
                    g.same_numbers(w) && g.orbit_steps == w.orbit_steps,
                    "{system} {method} {scheme} {indicator}, {threads} threads:\n batch  {g:?}\n engine {w:?}"
                );
            }
        }
    }
    assert!(!flow_map("magnetic", "gl4", "vm", "gali").has_batched_kernel());
}

/// `[map] indicator = "spectrum"`: the first `k` exponents per point, by QR renormalization.
/// The batched kernel equals the engine bit for bit (VM and MPM, a separable Hamiltonian, a
/// discrete map and a flow); the spectrum keeps its laws: for a symplectic system and k = D the
/// exponents sum to zero (the tangent map has determinant 1, so `sum ln |R_jj|` over a window is
/// `ln |det M| = 0` up to the QR's rounding, a few ulps per window, over `t` at least 20: well
/// under 1e-12), for Lorenz to the divergence `-(sigma + 1 + beta)`; and lambda_1 is the MLE
/// map's value (the first vector is only scaled, by QR as by rescaling; the two differ in the
/// rounding of that scaling, amplified at most by e^(lambda t) ~ e^4 here: 1e-9 is generous).
#[test]
fn spectrum_maps_equal_the_engine_and_keep_the_spectrum_laws() {
    let qr = |spec: RunConfig| {
        let mut spec = spec;
        spec.schemes[0].orthonormalize = "qr".to_string();
        spec
    };
    let check = |spec: &MapSpec| -> Vec<PointResult> {
        let want: Vec<PointResult> = (0..spec.grid_points())
            .map(|i| map::one_orbit::point(spec, i))
            .collect();
        for threads in [1, 2] {
            let got = batched(spec, threads, Isa::detect());
            for (g, w) in got.iter().zip(&want) {
                assert!(
                    g.same_numbers(w),
                    "{threads} threads:\n batch  {g:?}\n engine {w:?}"
                );
            }
        }
        want
    };
    let spectrum = |k: usize| MapConfig {
        k: Some(k),
        ..grid("spectrum")
    };
    for method in ["vm", "mpm"] {
        let spec = MapSpec::from_config(&qr(hh_map_config(method, spectrum(4), 20.0, 2))).unwrap();
        let points = check(&spec);
        let mle = batched(&hh_map(method, grid("mle"), 20.0, 2), 1, Isa::detect());
        let mut integrated = 0;
        for (p, m) in points.iter().zip(&mle) {
            assert_eq!(p.status, m.status);
            if p.status != PointStatus::Ok {
                assert!(p.spectrum.is_empty());
                continue;
            }
            integrated += 1;
            assert_eq!(p.spectrum.len(), 4);
            assert_eq!(p.value.to_bits(), p.spectrum[0].to_bits());
            // MPM's nearby orbits at d0 = 1e-8 see the flow's non-linearity: their volume
            // changes by O(d0) per window, not by rounding.
            let tolerance = if method == "vm" { 1e-12 } else { 1e-6 };
            let sum: f64 = p.spectrum.iter().sum();
            assert!(
                sum.abs() < tolerance,
                "{method} point {}: sum {sum}",
                p.index
            );
            assert!(
                (p.value - m.value).abs() < if method == "vm" { 1e-9 } else { 1e-6 },
                "{method} point {}: lambda_1 {} vs MLE {}",
                p.index,
                p.value,
                m.value
            );
        }
        assert!(integrated >= 4, "only {integrated} points integrated");
    }
    // The standard map (2 exponents summing to 0) and Lorenz (3, summing to the divergence).
    let standard = "[model]\nname = \"map\"\nnext = [\"x1 + x2 + K*sin(x1)\", \"x2 + K*sin(x1)\"]\n\
         params = { K = 1.0 }\nmodulo = [6.283185307179586, 6.283185307179586]\n\
         [orbit]\nx = [0.0, 0.0]\n[integrator]\nt_final = 300\n\
         [deviations]\nk = 2\nsets = 2\nseed = 5\n\
         [[scheme]]\nname = \"s\"\nmethod = \"vm\"\nd0 = 1e-7\ntau = 1\northonormalize = \"qr\"\n\
         [map]\nx = { coord = \"x1\", min = 0.0, max = 6.2, n = 5 }\n\
         y = { coord = \"x2\", min = -3.1, max = 3.1, n = 4 }\nindicator = \"spectrum\"\n";
    let spec = MapSpec::from_config(&RunConfig::from_toml(standard).unwrap()).unwrap();
    let per_set = check(&spec);
    let (mut chaotic, mut regular) = (0, 0);
    for p in &per_set {
        assert_eq!(p.status, PointStatus::Ok);
        let sum = p.spectrum[0] + p.spectrum[1];
        assert!(sum.abs() < 1e-12, "point {}: {:?}", p.index, p.spectrum);
        // K = 1: the chaotic layer's MLE is about 0.1 or more; a torus gives ln t / t decay,
        // well below 0.05 by t = 300.
        if p.value > 0.08 {
            chaotic += 1;
        } else if p.value < 0.05 {
            regular += 1;
        }
    }
    assert!(
        chaotic > 0 && regular > 0,
        "{chaotic} chaotic, {regular} regular"
    );
    // The basis route: one QR basis per point from the coordinate axes, not the sets' random
    // directions. At t = 300 two generic starts differ in lambda_1 by |ln c| / t, c the first
    // vector's projection on the most unstable direction (|ln 1e-6| / 300 < 0.05).
    let basis = standard.replace("[map]\n", "[map]\nroute = \"basis\"\n");
    let spec = MapSpec::from_config(&RunConfig::from_toml(&basis).unwrap()).unwrap();
    for (b, p) in batched(&spec, 2, Isa::detect()).iter().zip(&per_set) {
        assert_eq!(
            b.per_set[0].to_bits(),
            b.per_set[1].to_bits(),
            "one basis per point"
        );
        assert!(
            (b.spectrum[0] + b.spectrum[1]).abs() < 1e-12,
            "{:?}",
            b.spectrum
        );
        assert!(
            (b.value - p.value).abs() < 0.05,
            "point {}: basis {} vs per-set {}",
            b.index,
            b.value,
            p.value
        );
    }
    let lorenz = "[model]\nname = \"ode\"\n\
         rhs = [\"sigma*(x2 - x1)\", \"x1*(rho - x3) - x2\", \"x1*x2 - beta*x3\"]\n\
         params = { sigma = 10.0, rho = 28.0, beta = 2.6666666666666665 }\n\
         [orbit]\nx = [1.0, 1.0, 20.0]\n[integrator]\nmethod = \"dop853\"\nh = 0.01\nt_final = 5\n\
         [deviations]\nk = 3\nsets = 2\nseed = 5\n\
         [[scheme]]\nname = \"s\"\nmethod = \"vm\"\nd0 = 1e-8\ntau = 0.5\northonormalize = \"qr\"\n\
         [map]\nx = { coord = \"x1\", min = -0.3, max = 0.3, n = 3 }\n\
         y = { coord = \"x2\", min = -0.2, max = 0.2, n = 2 }\nindicator = \"spectrum\"\n";
    let spec = MapSpec::from_config(&RunConfig::from_toml(lorenz).unwrap()).unwrap();
    assert!(spec.has_batched_kernel());
    for p in check(&spec) {
        // A step's tangent map has determinant exp(-(sigma + 1 + beta) h) only to the method's
        // order: DOP853's error in ln det per step is about (14.6 h)^9 / 9! ~ 1e-13 (rk4's,
        // (14.6 h)^5 / 5!, would be 5e-7, a sum off by 5e-5), 500 steps over t = 5: 1e-9 holds
        // it with room for the QR's rounding.
        let sum: f64 = p.spectrum.iter().sum();
        assert!(
            (sum + 13.666_666_666_666_666).abs() < 1e-9,
            "{:?}",
            p.spectrum
        );
    }
}

/// Spectrum maps need QR renormalization, and the other indicators refuse it: both errors name
/// the scheme's key.
#[test]
fn spectrum_and_qr_go_together() {
    let err = MapSpec::from_config(&hh_map_config(
        "vm",
        MapConfig {
            k: Some(4),
            ..grid("spectrum")
        },
        2.0,
        1,
    ))
    .err()
    .expect("refused");
    assert_eq!(err.key, "scheme[0].orthonormalize");
    assert!(err.message.contains("orthonormalize = \"qr\""), "{err}");
    let mut config = hh_map_config("vm", grid("mle"), 2.0, 1);
    config.schemes[0].orthonormalize = "qr".to_string();
    let err = MapSpec::from_config(&config).err().expect("refused");
    assert_eq!(err.key, "scheme[0].orthonormalize");
    assert!(err.message.contains("rescale"), "{err}");
}

/// The numbers of two points of different maps (their grid places aside), bit for bit.
fn same_point(a: &PointResult, b: &PointResult) -> bool {
    let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
    a.status == b.status
        && a.value.to_bits() == b.value.to_bits()
        && bits(&a.per_set) == bits(&b.per_set)
        && bits(&a.spectrum) == bits(&b.spectrum)
        && a.mean_log10.to_bits() == b.mean_log10.to_bits()
        && a.t_end.to_bits() == b.t_end.to_bits()
        && a.orbit_steps == b.orbit_steps
        && bits(&a.x0) == bits(&b.x0)
}

/// A map config of `model` (its `[model]` keys, `{params}` where the parameters go) with the
/// given `[orbit]`, `[integrator]`, scheme and axes.
#[allow(clippy::too_many_arguments)]
fn model_map(
    model: &str,
    params: &str,
    orbit: &str,
    integrator: &str,
    (method, tau, route): (&str, &str, &str),
    indicator: &str,
    x: &str,
    y: &str,
) -> MapSpec {
    let k = if indicator == "mle" { 1 } else { 2 };
    let model = model.replace("{params}", params);
    let threshold = if indicator == "gali-time" {
        "threshold = 1e-6\n"
    } else {
        ""
    };
    let qr = if indicator == "spectrum" {
        "orthonormalize = \"qr\"\n"
    } else {
        ""
    };
    let text = format!(
        "[model]\n{model}\n[orbit]\n{orbit}\n[integrator]\n{integrator}\n\
         [deviations]\nk = {k}\nsets = 2\nseed = 5\n\
         [[scheme]]\nname = \"s\"\nmethod = \"{method}\"\nd0 = 1e-7\ntau = {tau}\n{qr}\
         [map]\nx = {x}\ny = {y}\nindicator = \"{indicator}\"\nroute = \"{route}\"\n{threshold}"
    );
    MapSpec::from_config(&RunConfig::from_toml(&text).unwrap())
        .unwrap_or_else(|e| panic!("{e}\n{text}"))
}

const STANDARD_MAP: &str = "name = \"map\"\nnext = [\"x1 + x2 + K*sin(x1)\", \"x2 + K*sin(x1)\"]\n\
     params = { {params} }\nmodulo = [6.283185307179586, 6.283185307179586]";
const LORENZ: &str = "name = \"ode\"\n\
     rhs = [\"sigma*(x2 - x1)\", \"x1*(rho - x3) - x2\", \"x1*x2 - beta*x3\"]\n\
     params = { {params} }";
const MAGNETIC_HH: &str = "name = \"hamiltonian\"\nn = 2\n\
     hamiltonian = \"((p1 + B*q2/2)^2 + (p2 - B*q1/2)^2)/2 + (q1^2 + q2^2)/2 + q1^2*q2 - q2^3/3\"\n\
     params = { {params} }";

/// Parameter axes: a map over a parameter (`x = { param = "K", ... }`) computes
/// each point with its parameter as a lane value of the compiled functions, and its column at
/// a fixed value equals, bit for bit, a coordinate map at that value (the parameter folded as
/// a constant): the operations are the same (`K * sin(x1)` is one multiplication either way;
/// no identity folds at these values), for every indicator, VM and MPM, both routes, the
/// standard map and Lorenz (two parameter axes), with 1 and 2 threads; a Hamiltonian `H(q, p)`
/// to rounding (see there).
#[test]
fn parameter_axes_equal_coordinate_maps_at_fixed_values() {
    // The standard map over (K, p0) from theta0 = 2, against (theta, p) maps at each K.
    for (method, tau, route, indicator) in [
        ("vm", "1", "per-set", "sali"),
        ("mpm", "1", "per-set", "gali"),
        ("mpm", "3", "per-set", "mle"),
        ("vm", "2", "per-set", "fli"),
        ("mpm", "1", "per-set", "megno"),
        ("vm", "1", "per-set", "megno_mean"),
        ("vm", "1", "per-set", "gali-time"),
        ("mpm", "2", "per-set", "spectrum"),
        ("vm", "1", "basis", "gali"),
        ("mpm", "1", "basis", "sali"),
    ] {
        let scheme = (method, tau, route);
        let p_axis = "{ coord = \"x2\", min = -3.1, max = 3.1, n = 4 }";
        let integrator = "h = 1\nt_final = 300";
        let by_k = model_map(
            STANDARD_MAP,
            "K = 1.0",
            "x = [2.0, 0.0]",
            integrator,
            scheme,
            indicator,
            "{ param = \"K\", min = 0.3, max = 2.1, n = 3 }",
            p_axis,
        );
        assert!(by_k.x.is_param && !by_k.y.is_param);
        let got = batched(&by_k, 2, Isa::detect());
        assert_eq!(got, batched(&by_k, 1, Isa::detect()));
        for ik in 0..by_k.x.n {
            let k = by_k.x.value(ik);
            let at_k = model_map(
                STANDARD_MAP,
                &format!("K = {k:?}"),
                "x = [0.0, 0.0]",
                integrator,
                scheme,
                indicator,
                "{ coord = \"x1\", min = 2.0, max = 2.0, n = 1 }",
                p_axis,
            );
            let want = batched(&at_k, 1, Isa::detect());
            for (iy, w) in want.iter().enumerate() {
                let g = &got[iy * by_k.x.n + ik];
                assert!(
                    (g.x, g.y, g.ix, g.iy) == (k, w.y, ik as u32, iy as u32) && same_point(g, w),
                    "{method} {route} {indicator} K = {k}:\n param {g:?}\n coord {w:?}"
                );
            }
        }
    }

    // Lorenz over (rho, sigma), and a Hamiltonian over (B, q2), against coordinate maps.
    let lorenz_orbit = "x = [1.0, 1.0, 20.0]";
    let lorenz_params = |rho: f64, sigma: f64| {
        format!("sigma = {sigma:?}, rho = {rho:?}, beta = 2.6666666666666665")
    };
    for (integrator, scheme, indicator) in [
        (
            "method = \"rk4\"\nh = 0.01\nt_final = 3",
            ("vm", "0.5", "per-set"),
            "mle",
        ),
        (
            "method = \"dop853\"\nh = 0.01\nt_final = 3",
            ("mpm", "0.5", "per-set"),
            "gali",
        ),
        (
            "method = \"rk4\"\nh = 0.01\nt_final = 3",
            ("vm", "0.5", "basis"),
            "sali",
        ),
        (
            "method = \"rk4\"\nh = 0.01\nt_final = 3",
            ("vm", "0.5", "per-set"),
            "spectrum",
        ),
    ] {
        let by_params = model_map(
            LORENZ,
            &lorenz_params(28.0, 10.0),
            lorenz_orbit,
            integrator,
            scheme,
            indicator,
            "{ param = \"rho\", min = 0.5, max = 28.0, n = 2 }",
            "{ param = \"sigma\", min = 10.0, max = 16.0, n = 2 }",
        );
        let got = batched(&by_params, 2, Isa::detect());
        assert_eq!(got, batched(&by_params, 1, Isa::detect()));
        for g in &got {
            let at = model_map(
                LORENZ,
                &lorenz_params(g.x, g.y),
                lorenz_orbit,
                integrator,
                scheme,
                indicator,
                "{ coord = \"x1\", min = 1.0, max = 1.0, n = 1 }",
                "{ coord = \"x2\", min = 1.0, max = 1.0, n = 1 }",
            );
            let w = &batched(&at, 1, Isa::detect())[0];
            assert!(
                g.status == PointStatus::Ok && same_point(g, w),
                "lorenz {scheme:?} {indicator}:\n param {g:?}\n coord {w:?}"
            );
        }
    }
    let hh_orbit = "q = [0.0, 0.0]\np = [0.3, 0.0]";
    let q2_axis = "{ coord = \"q2\", min = -0.2, max = 0.2, n = 2 }";
    for (scheme, indicator) in [
        (("vm", "0.5", "per-set"), "gali"),
        (("mpm", "0.5", "basis"), "mle"),
    ] {
        let integrator = "method = \"rk4\"\nh = 0.01\nt_final = 3";
        let by_b = model_map(
            MAGNETIC_HH,
            "B = 0.2",
            hh_orbit,
            integrator,
            scheme,
            indicator,
            "{ param = \"B\", min = 0.1, max = 0.4, n = 2 }",
            q2_axis,
        );
        let got = batched(&by_b, 2, Isa::detect());
        for ib in 0..by_b.x.n {
            let b = by_b.x.value(ib);
            let at_b = model_map(
                MAGNETIC_HH,
                &format!("B = {b:?}"),
                hh_orbit,
                integrator,
                scheme,
                indicator,
                "{ coord = \"p2\", min = 0.0, max = 0.0, n = 1 }",
                q2_axis,
            );
            // Not bit for bit: the field is the symbolic gradient of H, and its Jacobian holds
            // products of parameter factors ((B/2) (B/2)) that fold into one constant when B is
            // one, but are multiplied at run time, in the order the derivative builds them, when
            // it is a lane value: a few roundings apart per step. Over these 300 steps of
            // regular orbits that stays within 1e-13 relative for VM (the outputs are of order
            // 1e-2 .. 1, so 1e-13 absolute at worst); MPM's separations are differences of
            // orbits at d0 = 1e-7, which carry the orbits' rounding difference divided by d0
            // (1e-16 / 1e-7 = 1e-9 relative; 1e-6 leaves a factor 1000 for its growth). The
            // steps and the classification are equal.
            let tol = if scheme.0 == "mpm" { 1e-6 } else { 1e-13 };
            let close = |a: f64, b: f64| (a - b).abs() <= tol * a.abs().max(b.abs()).max(1.0);
            for (iy, w) in batched(&at_b, 1, Isa::detect()).iter().enumerate() {
                let g = &got[iy * by_b.x.n + ib];
                assert!(
                    g.status == w.status
                        && g.orbit_steps == w.orbit_steps
                        && g.x0 == w.x0
                        && close(g.value, w.value)
                        && g.per_set.iter().zip(&w.per_set).all(|(a, b)| close(*a, *b)),
                    "hamiltonian {scheme:?} {indicator} B = {b}:\n param {g:?}\n coord {w:?}"
                );
            }
        }
    }
}

/// `a` and `b` are the same point to rounding: the same status, steps and initial condition,
/// every number within `tol` relative (absolute below 1). What a parameter axis gives where a
/// constant folds with another constant and the lane value cannot.
fn same_point_to(a: &PointResult, b: &PointResult, tol: f64) -> bool {
    let close = |x: f64, y: f64| (x - y).abs() <= tol * x.abs().max(y.abs()).max(1.0);
    let all_close =
        |x: &[f64], y: &[f64]| x.len() == y.len() && x.iter().zip(y).all(|(x, y)| close(*x, *y));
    a.status == b.status
        && a.orbit_steps == b.orbit_steps
        && a.t_end == b.t_end
        && a.x0 == b.x0
        && close(a.value, b.value)
        && close(a.mean_log10, b.mean_log10)
        && all_close(&a.per_set, &b.per_set)
        && all_close(&a.spectrum, &b.spectrum)
}

const COUPLED_HH: &str = "name = \"potential\"\nn = 2\n\
     potential = \"(q1^2 + q2^2)/2 + lam*q1*q1*q2 - lam*q2*q2*q2/3\"\n\
     params = { {params} }";
const COUPLED_HH_FACTORED: &str = "name = \"potential\"\nn = 2\n\
     potential = \"(q1^2 + q2^2)/2 + lam*(q1^2*q2 - q2^3/3)\"\n\
     params = { {params} }";
const DRIVEN_WELL: &str = "name = \"potential\"\nn = 1\n\
     potential = \"q1^2/2 + q1^4/4 - F*q1*cos(t)\"\n\
     params = { {params} }";
const KG_CHAIN: &str = "name = \"potential\"\nn = 4\nboundary = \"free\"\n\
     potential = \"sum(i = 1..N, eps[i]/2*q[i]^2 + q[i]^4/4) + sum(i = 1..N, (q[i+1] - q[i])^2/(2*W))\"\n\
     params = { eps = [0.8238, 0.6508, 1.1509, 0.5724], {params} }";

/// Parameter axes of a `potential` (`H = p^2/2 + V(q)` by a splitting): every point steps the
/// splitting's own code with its parameters bound (`WithParams`), and its column at a fixed
/// value equals the coordinate map at that value, which runs the compiled step kernels (bit
/// for bit the generic step loops, so the splitting's `step`). A coupling of Henon-Heiles
/// written two ways, to rounding with the same status and steps (bit for bit where no constant
/// folds differently); every indicator, VM and MPM, both routes, 1 and 2 threads. Bit for bit:
/// an energy solved per point at each point's own coupling, and a potential of the time
/// (whose coordinate map runs through the engine).
#[test]
fn potential_parameter_axes_equal_coordinate_maps_at_fixed_values() {
    let integrator = "method = \"aba864\"\nh = 0.05\nt_final = 4";
    let p2_axis = "{ coord = \"p2\", min = -0.1, max = 0.1, n = 2 }";
    for ((scheme, indicator), model) in [
        (("vm", "0.5", "per-set"), "gali"),
        (("mpm", "0.5", "per-set"), "mle"),
        (("vm", "0.5", "per-set"), "spectrum"),
        (("mpm", "1", "per-set"), "megno"),
        (("vm", "0.5", "per-set"), "fli"),
        (("vm", "0.5", "basis"), "sali"),
        (("mpm", "0.5", "basis"), "gali"),
    ]
    .into_iter()
    .flat_map(|case| [(case, COUPLED_HH), (case, COUPLED_HH_FACTORED)])
    {
        let orbit = "q = [0.0, 0.1]\np = [0.3, 0.0]";
        let by_lam = model_map(
            model,
            "lam = 1.0",
            orbit,
            integrator,
            scheme,
            indicator,
            "{ param = \"lam\", min = 0.5, max = 2.5, n = 3 }",
            p2_axis,
        );
        assert!(by_lam.x.is_param && !by_lam.y.is_param);
        let got = batched(&by_lam, 2, Isa::detect());
        assert_eq!(got, batched(&by_lam, 1, Isa::detect()));
        for il in 0..by_lam.x.n {
            let lam = by_lam.x.value(il);
            let at_lam = model_map(
                model,
                &format!("lam = {lam:?}"),
                orbit,
                integrator,
                scheme,
                indicator,
                "{ coord = \"q1\", min = 0.0, max = 0.0, n = 1 }",
                p2_axis,
            );
            // To rounding: a lane value is multiplied where the constant folds with another
            // constant of the derivatives (`lam * 3 / 3` is `lam` for a constant; `2 q1` times
            // `lam`, ...), a rounding apart per force evaluation. Over these 80 steps of
            // regular orbits that stays far below 1e-12 relative for VM (GALI, SALI, the
            // exponents are of order 1e-3 .. 1: 1e-12 absolute at worst); MPM's separations
            // are differences of orbits at d0 = 1e-7, which carry the orbits' rounding
            // difference divided by d0 (1e-16 / 1e-7 = 1e-9 relative; 1e-6 leaves a factor
            // 1000 for its growth). Steps and status are equal. Bit for bit where nothing
            // folds differently: the coupling written as products at lam = 0.5, a power of two,
            // whose products with the derivatives' constants are exact either way.
            let tol = if scheme.0 == "mpm" { 1e-6 } else { 1e-12 };
            let exact = model == COUPLED_HH && lam == 0.5;
            for (iy, w) in batched(&at_lam, 1, Isa::detect()).iter().enumerate() {
                let g = &got[iy * by_lam.x.n + il];
                assert!(
                    g.status == PointStatus::Ok
                        && same_point_to(g, w, tol)
                        && (!exact || same_point(g, w)),
                    "potential {scheme:?} {indicator} lam = {lam}:\n param {g:?}\n coord {w:?}"
                );
            }
        }
    }

    // The energy solved for p1 at each point's own coupling, over (q2, lam): the parameter on
    // the y axis, mixed with a coordinate on x.
    let on_shell = "q = [0.0, 0.0]\np = [0.0, 0.0]\nenergy = 0.08\nsolve_for = \"p1\"";
    let q2_axis = "{ coord = \"q2\", min = -0.2, max = 0.2, n = 3 }";
    let scheme = ("vm", "0.5", "per-set");
    let by_lam = model_map(
        COUPLED_HH,
        "lam = 1.0",
        on_shell,
        integrator,
        scheme,
        "gali",
        q2_axis,
        "{ param = \"lam\", min = 0.0, max = 2.0, n = 2 }",
    );
    let got = batched(&by_lam, 2, Isa::detect());
    for (il, lam) in [0.0, 2.0].into_iter().enumerate() {
        let at_lam = model_map(
            COUPLED_HH,
            &format!("lam = {lam:?}"),
            on_shell,
            integrator,
            scheme,
            "gali",
            q2_axis,
            "{ coord = \"q1\", min = 0.0, max = 0.0, n = 1 }",
        );
        let want = batched(&at_lam, 1, Isa::detect());
        assert_eq!(&got[il * 3..(il + 1) * 3].len(), &want.len());
        for (g, w) in got[il * 3..(il + 1) * 3].iter().zip(&want) {
            assert!(
                (g.y, g.x) == (lam, w.x) && same_point(g, w),
                "on the energy surface, lam = {lam}:\n param {g:?}\n coord {w:?}"
            );
        }
    }

    // A potential of the time: no step kernels either way (the coordinate map runs through
    // the engine, the parameter map lane by lane through the same splitting).
    let driven = "method = \"aba864\"\nh = 0.05\nt_final = 3";
    for scheme in [("vm", "0.5", "per-set"), ("mpm", "0.5", "per-set")] {
        let by_f = model_map(
            DRIVEN_WELL,
            "F = 0.1",
            "q = [0.2]\np = [0.0]",
            driven,
            scheme,
            "mle",
            "{ param = \"F\", min = 0.0, max = 0.6, n = 2 }",
            "{ coord = \"p1\", min = -0.3, max = 0.3, n = 2 }",
        );
        let got = batched(&by_f, 2, Isa::detect());
        for (i_f, f) in [0.0, 0.6].into_iter().enumerate() {
            let at_f = model_map(
                DRIVEN_WELL,
                &format!("F = {f:?}"),
                "q = [0.2]\np = [0.0]",
                driven,
                scheme,
                "mle",
                "{ coord = \"q1\", min = 0.2, max = 0.2, n = 1 }",
                "{ coord = \"p1\", min = -0.3, max = 0.3, n = 2 }",
            );
            for (iy, w) in batched(&at_f, 1, Isa::detect()).iter().enumerate() {
                let g = &got[iy * 2 + i_f];
                assert!(
                    same_point(g, w),
                    "driven {scheme:?} F = {f}:\n param {g:?}\n coord {w:?}"
                );
            }
        }
    }
}

/// The disordered Klein-Gordon chain over its coupling `1/W` (a lattice sum): with a constant
/// `W` its sums are compiled as loops, with `W` on an axis the derivatives are unrolled (a
/// potential with lane parameters has no loops), which may add a site's terms in another
/// order; see the tolerance below. Mixed with a momentum axis, VM and MPM.
#[test]
fn potential_parameter_axes_over_a_lattice_chain() {
    let integrator = "method = \"aba864\"\nh = 0.05\nt_final = 4";
    let orbit = "q = [0.0, 0.0, 0.0, 0.0]\np = [0.0, 0.4, 0.0, 0.0]";
    let p3_axis = "{ coord = \"p3\", min = -0.2, max = 0.2, n = 2 }";
    for (scheme, indicator) in [
        (("vm", "0.5", "per-set"), "gali"),
        (("mpm", "0.5", "per-set"), "mle"),
    ] {
        let by_w = model_map(
            KG_CHAIN,
            "W = 4.0",
            orbit,
            integrator,
            scheme,
            indicator,
            p3_axis,
            "{ param = \"W\", min = 2.0, max = 6.0, n = 2 }",
        );
        let got = batched(&by_w, 2, Isa::detect());
        // To rounding: the loops add each site's terms in the lattice order, the unrolled
        // gradient in the order of reverse accumulation, which can differ by a rounding per
        // force; the tolerances are argued as for the coupled Henon-Heiles potential above
        // (80 steps of regular orbits; MPM's d0 = 1e-7).
        let tol = if scheme.0 == "mpm" { 1e-6 } else { 1e-12 };
        for (iw, w_value) in [2.0, 6.0].into_iter().enumerate() {
            let at_w = model_map(
                KG_CHAIN,
                &format!("W = {w_value:?}"),
                orbit,
                integrator,
                scheme,
                indicator,
                p3_axis,
                "{ coord = \"q1\", min = 0.0, max = 0.0, n = 1 }",
            );
            for (ix, w) in batched(&at_w, 1, Isa::detect()).iter().enumerate() {
                let g = &got[iw * 2 + ix];
                assert!(
                    same_point_to(g, w, tol),
                    "kg {scheme:?} {indicator} W = {w_value}:\n param {g:?}\n coord {w:?}"
                );
            }
        }
    }
}

/// What a parameter axis of a potential refuses, with the key and why: a name not in `params`,
/// an array parameter; the built-in chain says what to write instead.
#[test]
fn potential_parameter_axes_refuse_what_they_cannot_vary() {
    let config = |params: &str, axis: &str, model: &str| {
        let model = model.replace("{params}", params);
        format!(
            "[model]\n{model}\n[orbit]\nq = [0.0, 0.0, 0.0, 0.0]\np = [0.0, 0.4, 0.0, 0.0]\n\
             [integrator]\nmethod = \"aba864\"\nh = 0.05\nt_final = 1\n\
             [deviations]\nk = 2\nsets = 1\nseed = 1\n\
             [[scheme]]\nname = \"s\"\nmethod = \"vm\"\nd0 = 1e-8\ntau = 1\n\
             [map]\nx = {{ param = \"{axis}\", min = 1.0, max = 2.0, n = 2 }}\n\
             y = {{ coord = \"p1\", min = 0.0, max = 0.1, n = 2 }}\nindicator = \"gali\"\n"
        )
    };
    let refused = |text: String| {
        MapSpec::from_config(&RunConfig::from_toml(&text).unwrap())
            .err()
            .unwrap_or_else(|| panic!("accepted:\n{text}"))
            .to_string()
    };
    let e = refused(config("W = 4.0", "V", KG_CHAIN));
    assert!(
        e.starts_with("map.x.param: 'V' is not a parameter of [model] params (scalars: W)"),
        "{e}"
    );
    let e = refused(config("W = 4.0", "eps", KG_CHAIN));
    assert!(
        e.starts_with("map.x.param: 'eps' is an array parameter"),
        "{e}"
    );
    let fput = "name = \"fput-beta\"\nn = 4\nbeta = 1.0";
    let e = refused(config("", "beta", fput));
    assert!(
        e.starts_with("map.x.param: the built-in fput-beta chain takes no parameter axis")
            && e.contains("name = \"potential\""),
        "{e}"
    );
}

/// Lorenz's largest Lyapunov exponent over parameter axes against what is known of it: at the
/// classical rho = 28, sigma = 10, beta = 8/3 it is 0.9056 (Sprott's reference value); below
/// rho = 1 the origin is a stable node, every orbit falls into it and the exponent is that of
/// its slowest direction, (-(sigma + 1) + sqrt((sigma + 1)^2 - 4 sigma (1 - rho))) / 2 =
/// -0.4751 at rho = 0.5, sigma = 10.
#[test]
fn lorenz_mle_over_rho_and_sigma() {
    let spec = model_map(
        LORENZ,
        "sigma = 10.0, rho = 28.0, beta = 2.6666666666666665",
        "x = [1.0, 1.0, 1.0]",
        "method = \"rk4\"\nh = 0.01\nt_final = 1000",
        ("vm", "1", "per-set"),
        "mle",
        "{ param = \"rho\", min = 0.5, max = 28.0, n = 2 }",
        "{ param = \"sigma\", min = 10.0, max = 10.0, n = 1 }",
    );
    let points = batched(&spec, 2, Isa::detect());
    let (stable, chaotic) = (&points[0], &points[1]);
    assert_eq!((stable.x, chaotic.x, chaotic.y), (0.5, 28.0, 10.0));
    // The finite-time exponent over T = 1000 (the transient from (1, 1, 1) included)
    // fluctuates from orbit to orbit with a spread ~ 1/sqrt(T): 20 orbits near rho = 28 gave
    // a standard deviation of 0.003 at T = 2000, so 0.005 here; the transient of a few time
    // units biases it by a few 1e-3. rk4's error at h = 0.01 is far below both. 0.03 is five
    // spreads plus the bias.
    assert!(
        (chaotic.value - 0.9056).abs() < 0.03,
        "MLE at rho = 28, sigma = 10: {}",
        chaotic.value
    );
    // Falling onto the node, the tangent vector aligns with its slowest eigendirection within
    // a few time units (the other rates are -10.5 and -8/3): the finite-time average differs
    // from -0.4751 by O(1/T).
    let slowest = (-11.0 + (121.0f64 - 20.0).sqrt()) / 2.0;
    assert!(
        stable.value < 0.0 && (stable.value - slowest).abs() < 0.01,
        "MLE at rho = 0.5, sigma = 10: {} (node {slowest})",
        stable.value
    );
}

const FORCED_DUFFING: &str = "name = \"ode\"\n\
     rhs = [\"x2\", \"-0.25*x2 + x1 - x1^3 + gamma*cos(1.2*t)\"]\n\
     params = { {params} }";

/// A parameter axis over a non-autonomous flow (the forced Duffing oscillator over its forcing
/// amplitude `gamma`): the time is one argument shared by the lanes and `gamma` another, read
/// per lane, so every point equals, bit for bit, the coordinate map at its `gamma` (the
/// parameter folded as a constant; `gamma * cos(1.2 t)` is one multiplication either way), VM
/// and MPM, both routes, on 1 and 2 threads; and the forcing enters (the column of
/// `gamma = 0`, the autonomous oscillator, differs from the forced ones).
#[test]
fn parameter_axes_over_a_non_autonomous_flow() {
    let orbit = "x = [0.5, 0.0]";
    let integrator = "method = \"rk4\"\nh = 0.01\nt_final = 5";
    let v_axis = "{ coord = \"x2\", min = -0.2, max = 0.2, n = 2 }";
    for (scheme, indicator) in [
        (("vm", "0.5", "per-set"), "mle"),
        (("mpm", "0.5", "per-set"), "gali"),
        (("vm", "0.5", "basis"), "sali"),
    ] {
        let by_gamma = model_map(
            FORCED_DUFFING,
            "gamma = 0.3",
            orbit,
            integrator,
            scheme,
            indicator,
            "{ param = \"gamma\", min = 0.0, max = 0.6, n = 3 }",
            v_axis,
        );
        let got = batched(&by_gamma, 2, Isa::detect());
        assert_eq!(got, batched(&by_gamma, 1, Isa::detect()));
        for ig in 0..by_gamma.x.n {
            let gamma = by_gamma.x.value(ig);
            let at = model_map(
                FORCED_DUFFING,
                &format!("gamma = {gamma:?}"),
                orbit,
                integrator,
                scheme,
                indicator,
                "{ coord = \"x1\", min = 0.5, max = 0.5, n = 1 }",
                v_axis,
            );
            for (iy, w) in batched(&at, 1, Isa::detect()).iter().enumerate() {
                let g = &got[iy * by_gamma.x.n + ig];
                assert!(
                    g.status == PointStatus::Ok && same_point(g, w),
                    "duffing {scheme:?} {indicator} gamma = {gamma}:\n param {g:?}\n coord {w:?}"
                );
            }
        }
        // The forcing moves the orbits: the unforced column differs from the forced ones.
        for iy in 0..2 {
            let row = &got[iy * by_gamma.x.n..(iy + 1) * by_gamma.x.n];
            assert!(
                row[1..].iter().all(|g| !same_point(g, &row[0])),
                "{scheme:?} {indicator}: gamma did not change the points of row {iy}"
            );
        }
    }
}
