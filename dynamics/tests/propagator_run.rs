//! `[[scheme]] route = "propagator"` of a VM scheme in a run, against the per-set route of the
//! same scheme on the same reference orbit (one run, two schemes).
//!
//! The route integrates the `2N` unit vectors once per renormalization window and applies the
//! resulting tangent propagator `M` to every set's vectors; per-set VM integrates each vector.
//! The tangent map is linear, so the two differ only by rounding: per window, `M w` carries the
//! rounding of `M`'s columns, about `eps |M|`, against `eps |M w|` for the integrated vector, so
//! a direction compressed by `kappa(M)` in the window (`kappa ~ e^{(l_1 - l_2N) tau}`, a few on
//! these orbits at `tau = 1`) is off by `eps kappa` relative. Between windows both routes
//! inherit the same renormalized vectors' rounding, so in `log10 GALI_k` they agree as far as
//! per-set VM itself resolves GALI_k: to 1e-6 decades while `log10 GALI_k > -7`
//! (`propagator_vm.rs` derives and measures that resolution on the same orbits: the paper's HH
//! chaotic and regular orbits and the FPUT N = 5 regular one. On FPUT's chaotic orbit per-set
//! VM's own resolution is coarser than that cut-off, about 1e-3 decades just above it.)

use chaoscope_dynamics::engine::Engine;
use chaoscope_dynamics::indicators::gali_log10;
use chaoscope_dynamics::spec::RunSpec;
use chaoscope_schemas::config::paper::{self, FPUT_N5_REGULAR_P, FPUT_N5_REGULAR_Q, fput_beta};
use chaoscope_schemas::config::{DeviationsConfig, RunConfig, SchemeConfig};
use chaoscope_schemas::run::Sample;

/// Per-set VM resolves GALI_k to 1e-6 decades above this (module comment).
const RESOLVED_LOG10: f64 = -7.0;

/// The two routes of one VM scheme.
fn schemes(tau: f64) -> Vec<SchemeConfig> {
    let per_set = SchemeConfig::new("per-set", "vm", 1.0, tau);
    let propagator = SchemeConfig {
        route: Some("propagator".into()),
        ..SchemeConfig::new("propagator", "vm", 1.0, tau)
    };
    vec![per_set, propagator]
}

fn samples(config: &RunConfig) -> Vec<Sample> {
    let mut out = Vec::new();
    Engine::new(RunSpec::from_config(config).unwrap())
        .run(|s| out.push(s))
        .unwrap();
    out
}

/// Comparison of the two schemes of `config` over the whole run.
struct Agreement {
    /// Largest |route - per-set| in log10 GALI_j over resolved values, and their count.
    worst_gali: f64,
    compared: usize,
    /// Smallest per-set log10 GALI_k reached (how far past the cut-off the run went).
    lowest: f64,
    /// Largest relative difference of the finite-time exponents at the end.
    worst_exponent: f64,
}

fn agreement(config: &RunConfig) -> Agreement {
    let spec = RunSpec::from_config(config).unwrap();
    let (dim, sets) = (spec.dim(), spec.sets());
    let mut a = Agreement {
        worst_gali: 0.0,
        compared: 0,
        lowest: 0.0,
        worst_exponent: 0.0,
    };
    let mut log_stretch = vec![vec![0.0; spec.k() * sets]; 2];
    let samples = samples(config);
    for sample in &samples[1..] {
        assert_eq!(sample.schemes.len(), 2 * sets, "every set of both schemes");
        for set in 0..sets {
            let (p, r) = (&sample.schemes[set], &sample.schemes[sets + set]);
            assert_eq!(
                (p.scheme, p.set, r.scheme, r.set),
                (0, set as u32, 1, set as u32)
            );
            let (gp, gr) = (
                gali_log10(&p.separations, dim),
                gali_log10(&r.separations, dim),
            );
            for (x, y) in gp.iter().zip(&gr) {
                a.lowest = a.lowest.min(*x);
                if *x > RESOLVED_LOG10 {
                    a.worst_gali = a.worst_gali.max((x - y).abs());
                    a.compared += 1;
                }
            }
            for (scheme, s) in [p, r].into_iter().enumerate() {
                for (i, f) in s.stretch.iter().enumerate() {
                    log_stretch[scheme][set * spec.k() + i] += f.ln();
                }
            }
        }
    }
    for (x, y) in log_stretch[0].iter().zip(&log_stretch[1]) {
        a.worst_exponent = a.worst_exponent.max((x - y).abs() / x.abs().max(1.0));
    }
    a
}

#[test]
fn the_propagator_route_of_a_run_agrees_with_per_set_vm() {
    let hh =
        |q2: f64| paper::henon_heiles(q2, 2000.0, DeviationsConfig::random(4, 6, 3), schemes(1.0));
    let fput = |q: &[f64], p: &[f64]| {
        fput_beta(
            q,
            p,
            0.05,
            2000.0,
            DeviationsConfig::random(4, 4, 5),
            schemes(1.0),
        )
    };
    for (name, config, must_decay) in [
        ("HH chaotic", hh(paper::HH_CHAOTIC_Q2), true),
        ("HH regular", hh(paper::HH_REGULAR_Q2), false),
        (
            "FPUT N = 5 regular",
            fput(&FPUT_N5_REGULAR_Q, &FPUT_N5_REGULAR_P),
            false,
        ),
    ] {
        let a = agreement(&config);
        println!(
            "{name}: {} values compared, worst {:.1e} decades, lowest per-set log10 GALI {:.1}, \
             exponents {:.1e} relative",
            a.compared, a.worst_gali, a.lowest, a.worst_exponent
        );
        assert!(a.compared > 1000, "{name}: {} compared", a.compared);
        assert!(a.worst_gali < 1e-6, "{name}: {:e} decades", a.worst_gali);
        // The finite-time exponents are sums of ln |M w| over 2000 windows: each carries the
        // per-window rounding above, a few eps relative, so 1e-9 is a loose bound.
        assert!(a.worst_exponent < 1e-9, "{name}: {:e}", a.worst_exponent);
        if must_decay {
            assert!(
                a.lowest < RESOLVED_LOG10,
                "{name}: the chaotic run reaches beyond what is compared ({})",
                a.lowest
            );
        }
    }
}

/// The route's task is serial on its own data, like every other: the same bits on any number
/// of threads, and the same bits with the scheme's renormalizations falling between another
/// scheme's (windows of the engine shorter than the scheme's `tau`).
#[test]
fn the_propagator_route_is_deterministic_and_follows_shorter_windows() {
    let mut config = paper::henon_heiles(
        paper::HH_CHAOTIC_Q2,
        50.0,
        DeviationsConfig::random(3, 40, 9),
        schemes(0.5),
    );
    let one: Vec<Sample> = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .unwrap()
        .install(|| samples(&config));
    let two: Vec<Sample> = rayon::ThreadPoolBuilder::new()
        .num_threads(2)
        .build()
        .unwrap()
        .install(|| samples(&config));
    assert!(one == two, "thread count changed the bits");

    // Alone, and beside an MPM scheme renormalized every step (the engine stops every step).
    config.schemes.remove(0);
    let alone = samples(&config);
    config
        .schemes
        .push(SchemeConfig::new("mpm", "mpm", 1e-8, paper::HH_STEP));
    let beside = samples(&config);
    let of_route = |samples: &[Sample]| -> Vec<(u64, Vec<f64>, Vec<f64>)> {
        samples
            .iter()
            .flat_map(|s| {
                s.schemes
                    .iter()
                    .filter(|x| x.scheme == 0)
                    .map(move |x| (s.step, x.separations.clone(), x.stretch.clone()))
            })
            .collect()
    };
    assert_eq!(of_route(&alone).len(), 101 * 40);
    assert!(of_route(&alone) == of_route(&beside));
}

#[test]
fn the_propagator_route_is_refused_where_it_cannot_help() {
    let base = |sets: usize, k: usize, method: &str| {
        let mut c = paper::henon_heiles(
            paper::HH_CHAOTIC_Q2,
            10.0,
            DeviationsConfig::random(k, sets, 1),
            schemes(1.0),
        );
        c.schemes[1].method = method.into();
        c
    };
    let error = |c: &RunConfig| RunSpec::from_config(c).err().unwrap().to_string();
    let mpm = error(&base(8, 2, "mpm"));
    assert!(mpm.starts_with("scheme[1].route: "), "{mpm}");
    assert!(mpm.contains("vm"), "{mpm}");
    // 2N = 4 tangent vectors against sets x k = 4: nothing to gain.
    let small = error(&base(2, 2, "vm"));
    assert!(small.starts_with("scheme[1].route: "), "{small}");
    assert!(small.contains("per-set"), "{small}");
    let mut unknown = base(8, 2, "vm");
    unknown.schemes[1].route = Some("basis".into());
    let unknown = error(&unknown);
    assert!(
        unknown.starts_with("scheme[1].route: 'basis' is not per-set or propagator"),
        "{unknown}"
    );
    assert!(RunSpec::from_config(&base(3, 2, "vm")).is_ok());
}
