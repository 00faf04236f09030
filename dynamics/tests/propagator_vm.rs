//! The scaled QR propagator (`propagator.rs`, the map's basis route) against per-set VM on the paper's orbits: log10 GALI_k
//! of every set agrees to 1e-6 decades at every renormalization while per-set VM resolves it.
//!
//! Both are computed in one pass over one reference orbit: the tangent vectors of every set and
//! the propagator's basis are advanced by the same tangent steps, so the only difference is the
//! route. Per-set VM rescales each vector every `tau` and forms GALI_k from the unit vectors
//! (`indicators::volume_log10`). Its error is the rounding its vectors carry across the slow
//! directions: every step adds about `eps |v|` there, and along a direction that does not
//! contract (the chaotic orbit's zero exponents) it stays, while the true transverse component
//! is `GALI |v|`; summed over the last `1 / (lambda_1 h)` steps that is a relative error of about
//! `eps / (lambda_1 h GALI)`, `~ 5e-13 / GALI` on the chaotic HH orbit (`lambda_1 h ~ 4.5e-4`).
//! Measured (printed by the test, largest deviation per decade of GALI): 4e-8 decades for GALI_2
//! in [1e-7, 1e-6], 6e-6 in [1e-8, 1e-7], 1e-3 in [1e-11, 1e-10]: growing as 1 / GALI, per-set
//! VM's resolution, not the route's (the route agrees with the closed form of a linear map to
//! 1e-12 decades far below that, `propagator.rs`). So per-set VM resolves GALI_k to 1e-6 decades
//! while `log10 GALI_k > -7`, and that is where the two are compared.

use chaoscope_dynamics::indicators::volume_log10 as log10_gali;
use chaoscope_dynamics::integrator::Workspace;
use chaoscope_dynamics::propagator::{Propagator, SetImage};
use chaoscope_dynamics::spec::RunSpec;
use chaoscope_schemas::config::paper::{self, FPUT_N5_REGULAR_P, FPUT_N5_REGULAR_Q, fput_beta};
use chaoscope_schemas::config::{DeviationsConfig, RunConfig, SchemeConfig};

/// Per-set VM resolves GALI_k to 1e-6 decades above this (see the module comment).
const RESOLVED_LOG10: f64 = -7.0;

/// Largest |route - per-set| over resolved values, and how many values were compared; also
/// the smallest log10 GALI the route reached (to show the run went far below the cut-off).
fn compare(config: &RunConfig, ks: &[usize]) -> (f64, usize, f64) {
    let run = RunSpec::from_config(config).unwrap();
    let (dim, k, sets) = (run.dim(), run.k(), run.sets());
    let tau = run.schemes()[0].tau_steps;
    let mut x = run.x0().to_vec();
    // Per-set vectors first (set s, vector i at (s k + i) dim), then the propagator's basis.
    let mut w = Vec::with_capacity((sets * k + dim) * dim);
    for d in run.directions() {
        w.extend_from_slice(&d.vectors);
    }
    let mut prop = Propagator::new(dim);
    w.extend_from_slice(prop.basis());
    let split = sets * k * dim;
    let mut work = Workspace::new();
    let (mut img, mut scratch, mut gs) = (SetImage::default(), Vec::new(), Vec::new());
    let (mut worst, mut compared, mut lowest) = (0.0f64, 0usize, 0.0f64);
    let mut step = 0;
    let mut bins = [0.0f64; 16];
    while step < run.total_steps() {
        for _ in 0..tau {
            run.system()
                .step_tangent(&mut x, &mut w, 0.0, &mut work)
                .unwrap();
        }
        step += tau;
        for v in w[..split].chunks_exact_mut(dim) {
            let n = v.iter().map(|x| x * x).sum::<f64>().sqrt();
            v.iter_mut().for_each(|x| *x /= n);
        }
        prop.renormalize(&w[split..], 1.0).unwrap();
        w[split..].copy_from_slice(prop.basis());
        for (s, d) in run.directions().iter().enumerate() {
            let vectors = &w[s * k * dim..(s + 1) * k * dim];
            for &j in ks {
                let per_set = log10_gali(vectors, dim, j, &mut gs);
                prop.image(&d.vectors[..j * dim], &mut img);
                let route = prop.log10_gali(&img, &mut scratch);
                assert!(
                    route.is_finite(),
                    "t {}: GALI_{j} {route}",
                    run.time_of(step)
                );
                lowest = lowest.min(route);
                let bin = (-per_set).floor().clamp(0.0, 15.0) as usize;
                bins[bin] = bins[bin].max((route - per_set).abs());
                if per_set > RESOLVED_LOG10 {
                    worst = worst.max((route - per_set).abs());
                    compared += 1;
                }
            }
        }
    }
    let shown: Vec<String> = bins
        .iter()
        .enumerate()
        .map(|(b, e)| format!("-{b}: {e:.1e}"))
        .collect();
    eprintln!(
        "largest deviation by decade of per-set log10 GALI: {}",
        shown.join(", ")
    );
    (worst, compared, lowest)
}

fn check(name: &str, config: &RunConfig, ks: &[usize], must_reach: f64) {
    let (worst, compared, lowest) = compare(config, ks);
    eprintln!(
        "{name}: {compared} resolved values, largest deviation {worst:.2e} decades; \
         the route reached log10 GALI = {lowest:.1}"
    );
    assert!(compared > 0, "{name}: nothing compared");
    assert!(worst < 1e-6, "{name}: {worst} decades off per-set VM");
    // The runs go past the cut-off, so the comparison covers everything per-set VM resolves.
    assert!(lowest < must_reach, "{name}: reached only {lowest}");
}

fn vm() -> Vec<SchemeConfig> {
    vec![SchemeConfig::new("vm", "vm", 1e-8, 1.0)]
}

#[test]
fn hh_chaotic_orbit() {
    // The chaotic orbit's GALI_2 falls like exp(-lambda_1 t) (lambda_1 ~ 0.05): past 1e-8 by
    // t ~ 400; GALI_3, GALI_4 much earlier.
    let cfg = paper::henon_heiles(
        paper::HH_CHAOTIC_Q2,
        600.0,
        DeviationsConfig::random(4, 5, 7),
        vm(),
    );
    check("HH chaotic", &cfg, &[2, 3, 4], -10.0);
}

#[test]
fn hh_regular_orbit() {
    // GALI_4 ~ t^-4 passes 1e-8 near t ~ 1e3 on this orbit; GALI_2 stays O(1).
    let cfg = paper::henon_heiles(
        paper::HH_REGULAR_Q2,
        3000.0,
        DeviationsConfig::random(4, 3, 7),
        vm(),
    );
    check("HH regular", &cfg, &[2, 3, 4], -9.0);
}

#[test]
fn fput_n5_regular_orbit() {
    // The paper's regular FPUT N = 5 orbit (a 5-torus): GALI_2..5 stay O(1), GALI_k for k > 5
    // fall as t^-2(k-5).
    let cfg = fput_beta(
        &FPUT_N5_REGULAR_Q,
        &FPUT_N5_REGULAR_P,
        0.01,
        1000.0,
        DeviationsConfig::random(10, 2, 7),
        vm(),
    );
    check("FPUT N=5 regular", &cfg, &[2, 5, 6, 8, 10], -9.0);
}
