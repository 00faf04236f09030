//! Must-show 1: the energy error of ABA864 falls as h^4, the leapfrog's as h^2.

use chaoscope_producer::integrator::{
    Integrator, Splitting, SplittingKind, Workspace, relative_energy_error,
};
use chaoscope_producer::model::{HenonHeiles, Model};
use chaoscope_schemas::config::{DeviationsConfig, SchemeConfig, paper};

mod common;

/// Maximum relative energy error along the HH chaotic orbit up to t = 200.
fn max_energy_error(kind: SplittingKind, h: f64) -> f64 {
    let mut config = paper::henon_heiles(
        paper::HH_CHAOTIC_Q2,
        200.0,
        DeviationsConfig::random(2, 1, 0),
        vec![SchemeConfig::new("v", "vm", 1e-8, 200.0)],
    );
    config.integrator.h = Some(h);
    let spec = common::spec(&config);
    let model = HenonHeiles;
    let integ = Splitting::new(kind);
    let mut x = spec.x0().to_vec();
    let e0 = model.energy(&x);
    let mut work = Workspace::new();
    let mut worst: f64 = 0.0;
    for _ in 0..spec.total_steps() {
        integ.step(&model, &mut x, 0.0, h, &mut work);
        worst = worst.max(relative_energy_error(&model, &x, e0));
    }
    worst
}

fn order(kind: SplittingKind, hs: &[f64]) -> (f64, Vec<f64>) {
    let errs: Vec<f64> = hs.iter().map(|&h| max_energy_error(kind, h)).collect();
    let lx: Vec<f64> = hs.iter().map(|h| h.log10()).collect();
    let ly: Vec<f64> = errs.iter().map(|e| e.log10()).collect();
    (common::slope(&lx, &ly), errs)
}

#[test]
fn aba864_energy_error_is_fourth_order() {
    let (slope, errs) = order(SplittingKind::Aba864, &[0.2, 0.1, 0.05, 0.025]);
    eprintln!("ABA864 max E_r {errs:?}, slope {slope}");
    // numerics.md: slope 3.99, E_r = 1.4e-8 at h = 0.1 from an independent implementation.
    assert!((slope - 4.0).abs() <= 0.2, "slope {slope}");
    assert!(
        errs[1] > 0.5e-8 && errs[1] < 3e-8,
        "E_r(h = 0.1) = {}",
        errs[1]
    );
}

#[test]
fn leapfrog_energy_error_is_second_order() {
    let (slope, errs) = order(SplittingKind::Leapfrog, &[0.2, 0.1, 0.05, 0.025]);
    eprintln!("leapfrog max E_r {errs:?}, slope {slope}");
    assert!((slope - 2.0).abs() <= 0.2, "slope {slope}");
}

#[test]
fn other_splittings_have_their_order() {
    // SABA2 is second order for a general split; Yoshida's triple jump fourth.
    let (s2, _) = order(SplittingKind::Saba2, &[0.2, 0.1, 0.05, 0.025]);
    let (s4, _) = order(SplittingKind::Yoshida4, &[0.1, 0.05, 0.025, 0.0125]);
    eprintln!("saba2 slope {s2}, yoshida4 slope {s4}");
    assert!((s2 - 2.0).abs() <= 0.3, "saba2 slope {s2}");
    assert!((s4 - 4.0).abs() <= 0.3, "yoshida4 slope {s4}");
}
