//! `[map] route = "propagator"` against the per-set route on a small HH GALI_2 map: the VM
//! route gives every set's value per-set VM gives wherever per-set VM resolves it, and the MPM
//! route is as close to VM as per-set MPM is. Config mistakes name `map.route`.

use chaoscope_dynamics::map::{MapOptions, MapRoute, MapSpec, PointResult, PointStatus, run_map};
use chaoscope_schemas::config::{DeviationsConfig, MapConfig, RunConfig, SchemeConfig, paper};

fn config(method: &str, route: &str, d0: f64) -> RunConfig {
    let mut cfg = paper::henon_heiles(
        0.0,
        200.0,
        DeviationsConfig::random(2, 10, 3),
        vec![SchemeConfig::new(method, method, d0, 1.0)],
    );
    cfg.map = Some(MapConfig {
        k: Some(2),
        route: Some(route.to_string()),
        ..paper::hh_section_map(6, 5, "gali")
    });
    cfg
}

fn map(method: &str, route: &str) -> Vec<PointResult> {
    let spec = MapSpec::from_config(&config(method, route, 1e-8)).unwrap();
    let points: Vec<u64> = (0..spec.grid_points()).collect();
    let mut out = Vec::new();
    run_map(&spec, &points, &MapOptions::default(), |r| {
        out.push(r);
        true
    })
    .unwrap();
    out.sort_by_key(|r| r.index);
    out
}

#[test]
fn vm_route_gives_per_set_vm_values_where_resolved() {
    let (per_set, route) = (map("vm", "per-set"), map("vm", "propagator"));
    let mut compared = 0;
    for (p, r) in per_set.iter().zip(&route) {
        assert_eq!(p.status, r.status, "point {}", p.index);
        if p.status != PointStatus::Ok {
            continue;
        }
        // The route evolves 4 tangent vectors instead of 20.
        assert!(r.orbit_steps * 4 < p.orbit_steps);
        for (a, b) in p.per_set.iter().zip(&r.per_set) {
            // Per-set VM resolves log10 GALI to 1e-6 decades above -7 (tests/propagator_vm.rs).
            if *a > -7.0 {
                assert!((a - b).abs() < 1e-6, "point {}: {a} vs {b}", p.index);
                compared += 1;
            }
        }
    }
    assert!(compared > 50, "only {compared} resolved values");
}

/// The VM map of `indicator` (k = 2, 3 sets, t = 200) on `route`, every point.
fn vm_map(indicator: &str, route: &str) -> (MapSpec, Vec<PointResult>) {
    let mut cfg = config("vm", route, 1e-8);
    cfg.deviations = DeviationsConfig::random(2, 3, 3);
    if let Some(map) = &mut cfg.map {
        map.indicator = indicator.to_string();
        map.k = None;
    }
    let spec = MapSpec::from_config(&cfg).unwrap();
    let points: Vec<u64> = (0..spec.grid_points()).collect();
    let mut out = Vec::new();
    run_map(&spec, &points, &MapOptions::default(), |r| {
        out.push(r);
        true
    })
    .unwrap();
    out.sort_by_key(|r| r.index);
    (spec, out)
}

/// Where a map that names no route may be given the basis route by cost
/// (`MapSpec::routes_agree`: VM, every indicator but `spectrum` and `gali-time`), the basis
/// route gives the per-set route's numbers: MLE, FLI and MEGNO to 1e-8 relative (both routes
/// stretch the same tangent vectors, the basis route forming each set's from the propagator in
/// logs: rounding, 1e-11 measured, amplified along a chaotic orbit), log10 GALI and log10 SALI
/// to 1e-6 decades where per-set VM resolves them (above -7, tests/propagator_vm.rs).
#[test]
fn the_routes_a_default_map_chooses_between_give_the_same_numbers() {
    for indicator in ["mle", "sali", "gali", "fli", "megno", "megno_mean"] {
        let (spec, per_set) = vm_map(indicator, "per-set");
        assert!(spec.routes_agree(), "{indicator}");
        let (_, basis) = vm_map(indicator, "basis");
        let mut compared = 0;
        for (p, b) in per_set.iter().zip(&basis) {
            assert_eq!(p.status, b.status, "{indicator} point {}", p.index);
            if p.status != PointStatus::Ok {
                continue;
            }
            let logarithmic = matches!(indicator, "sali" | "gali");
            for (a, b) in p.per_set.iter().zip(&b.per_set) {
                let close = if logarithmic {
                    *a <= -7.0 || (a - b).abs() < 1e-6
                } else {
                    (a - b).abs() <= 1e-8 * a.abs().max(1e-3)
                };
                assert!(close, "{indicator} point {}: {a} vs {b}", p.index);
                compared += 1;
            }
        }
        assert!(compared > 50, "{indicator}: only {compared} values");
    }
    // Where they differ, a map keeps the route it names or per-set.
    for (method, indicator) in [("mpm", "gali"), ("vm", "gali-time"), ("vm", "spectrum")] {
        let mut cfg = config(method, "per-set", 1e-8);
        if let Some(map) = &mut cfg.map {
            map.indicator = indicator.to_string();
            map.threshold = (indicator == "gali-time").then_some(0.05);
        }
        if indicator == "spectrum" {
            cfg.schemes[0].orthonormalize = "qr".into();
        }
        let spec = MapSpec::from_config(&cfg).unwrap();
        assert!(!spec.routes_agree(), "{method} {indicator}");
    }
}

#[test]
fn mpm_route_is_as_close_to_vm_as_per_set_mpm() {
    let (vm, mpm, route) = (
        map("vm", "per-set"),
        map("mpm", "per-set"),
        map("mpm", "propagator"),
    );
    let dist = |a: &PointResult, b: &PointResult| {
        a.per_set
            .iter()
            .zip(&b.per_set)
            .map(|(x, y)| (x - y).abs())
            .sum::<f64>()
            / a.per_set.len() as f64
    };
    // On regular points (VM's GALI_2 stays above 1e-3) both MPM routes approximate VM to
    // O(d0) plus the rounding of x + d0 q (eps |x| / d0 ~ 1e-8 relative per window): the
    // route's largest distance to VM may exceed per-set MPM's by the spread of two independent
    // approximations of one size, not by orders of magnitude.
    let (mut worst_mpm, mut worst_route, mut n) = (0.0f64, 0.0f64, 0);
    for ((v, m), r) in vm.iter().zip(&mpm).zip(&route) {
        if v.status != PointStatus::Ok || v.per_set.iter().any(|g| *g < -3.0) {
            continue;
        }
        worst_mpm = worst_mpm.max(dist(m, v));
        worst_route = worst_route.max(dist(r, v));
        n += 1;
    }
    eprintln!(
        "{n} regular points: largest distance to VM, per-set MPM {worst_mpm:.2e}, route {worst_route:.2e}"
    );
    assert!(n >= 5, "only {n} regular points");
    assert!(
        worst_route < 3.0 * worst_mpm + 1e-6,
        "route {worst_route} vs per-set {worst_mpm}"
    );
}

#[test]
fn route_mistakes_name_the_key() {
    let err = |cfg: RunConfig| {
        MapSpec::from_config(&cfg)
            .err()
            .expect("refused")
            .to_string()
    };
    let e = err(config("vm", "shared", 1e-8));
    assert!(e.contains("map.route") && e.contains("shared"), "{e}");
    for d0 in [1e-4, 1e-12] {
        let e = err(config("mpm", "propagator", d0));
        assert!(e.contains("map.route") && e.contains("d0"), "{e}");
    }
    // VM is linear: any d0 is the same propagator.
    assert!(MapSpec::from_config(&config("vm", "propagator", 1e-4)).is_ok());
    // "basis" is the route's name, "propagator" its former spelling: the same map.
    let (a, b) = (
        MapSpec::from_config(&config("mpm", "basis", 1e-8)).unwrap(),
        MapSpec::from_config(&config("mpm", "propagator", 1e-8)).unwrap(),
    );
    assert_eq!((a.route, b.route), (MapRoute::Basis, MapRoute::Basis));
}

#[test]
fn batched_vm_route_is_the_per_point_vm_route_bit_for_bit() {
    // run_map takes separable Hamiltonians' VM basis route through the fused many-points kernel
    // (one lane per point: orbit and basis); basis::compute integrates one point with its
    // recorded reference.
    let spec = MapSpec::from_config(&config("vm", "propagator", 1e-8)).unwrap();
    let batched = map("vm", "propagator");
    let isa = chaoscope_dynamics::batch::Isa::detect();
    for r in &batched {
        let one = chaoscope_dynamics::map::basis::compute(&spec, isa, &[r.index], &|| false)
            .pop()
            .unwrap();
        assert!(r.same_numbers(&one), "point {}: {r:?} vs {one:?}", r.index);
    }
}
