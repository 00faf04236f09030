//! Any Hamiltonian written as `H(q, p)` (`[model] name = "hamiltonian"`): its vector field from
//! symbolic derivatives, integrated by the symplectic Gauss-Legendre methods (`gl4`, `gl6`) and
//! by adaptive `dop853`.
//!
//! The system is the Henon-Heiles Hamiltonian after the canonical change of momenta
//! `P = p + grad F(q)` with `F = c q1 q2`:
//! `H'(q, P) = (P1 - c q2)^2 / 2 + (P2 - c q1)^2 / 2 + V_HH(q)`, not separable (the momenta
//! and coordinates mix in the kinetic term, as for a charged particle in a magnetic field,
//! here with a vector potential of zero curl). Its orbits are the paper's Henon-Heiles orbits
//! (`q(t)` the same, `p = P - grad F(q)`), so the built-in model is an exact reference, and the
//! laws the paper's orbits obey hold: energy conservation, GALI power laws on the regular
//! orbit, the MLE of the chaotic one.

use chaoscope_analyzer::analysis::AnalysisOptions;
use chaoscope_app::inprocess::analyze_config;
use chaoscope_dynamics::engine::Engine;
use chaoscope_dynamics::indicators::gali_log10;
use chaoscope_dynamics::integrator::Workspace;
use chaoscope_dynamics::spec::RunSpec;
use chaoscope_schemas::config::RunConfig;

const C: f64 = 0.5;
const ENERGY: f64 = 0.125;

fn v_hh(x: f64, y: f64) -> f64 {
    0.5 * (x * x + y * y) + x * x * y - y * y * y / 3.0
}

/// The paper's orbits on the section x = 0 at H = 1/8 (numerics.md): `p1` from the energy.
fn hh_state(y: f64) -> ([f64; 2], [f64; 2]) {
    let p1 = (2.0 * (ENERGY - v_hh(0.0, y))).sqrt();
    ([0.0, y], [p1, 0.0])
}

const REGULAR_Y: f64 = 0.558;
const CHAOTIC_Y: f64 = -0.25;

/// The gauge-transformed Henon-Heiles run: `P = p + c (q2, q1)`.
fn config(
    q: [f64; 2],
    p: [f64; 2],
    method: &str,
    h: f64,
    t_final: f64,
    k: usize,
    tau: f64,
) -> RunConfig {
    let big_p = [p[0] + C * q[1], p[1] + C * q[0]];
    let text = format!(
        r#"
[model]
name = "hamiltonian"
n = 2
hamiltonian = "(p1 - c*q2)^2/2 + (p2 - c*q1)^2/2 + (q1^2 + q2^2)/2 + q1^2*q2 - q2^3/3"
params = {{ c = {C:?} }}
[orbit]
q = [{:?}, {:?}]
p = [{:?}, {:?}]
[integrator]
method = "{method}"
h = {h:?}
t_final = {t_final:?}
[deviations]
k = {k}
sets = 1
seed = 3
[[scheme]]
name = "vm"
method = "vm"
d0 = 1e-8
tau = {tau:?}
orthonormalize = "rescale"
"#,
        q[0], q[1], big_p[0], big_p[1]
    );
    RunConfig::from_toml(&text).unwrap()
}

#[test]
fn the_orbit_is_the_built_in_henon_heiles_orbit() {
    // q(t) of H' equals q(t) of HH: gl6 at h = 0.01 against the built-in ABA864 at h = 0.001
    // on the regular orbit to t = 100; both errors are far below 1e-9 there (order 6 and 8).
    let (q, p) = hh_state(REGULAR_Y);
    let spec = RunSpec::from_config(&config(q, p, "gl6", 0.01, 100.0, 1, 100.0)).unwrap();
    let mut x = spec.x0().to_vec();
    let mut w = Workspace::new();
    for _ in 0..10_000 {
        spec.system().step(&mut x, 0.0, &mut w);
    }
    let reference = format!(
        r#"
[model]
name = "henon-heiles"
[orbit]
q = [0.0, {REGULAR_Y:?}]
p = [{:?}, 0.0]
[integrator]
method = "aba864"
h = 0.001
t_final = 100.0
[deviations]
k = 1
[[scheme]]
name = "vm"
method = "vm"
d0 = 1e-8
tau = 100.0
"#,
        p[0]
    );
    let hh = RunSpec::from_config(&RunConfig::from_toml(&reference).unwrap()).unwrap();
    let mut y = hh.x0().to_vec();
    for _ in 0..100_000 {
        hh.system().step(&mut y, 0.0, &mut w);
    }
    let dq = (x[0] - y[0]).hypot(x[1] - y[1]);
    // And the momenta through the change of variables.
    let dp = (x[2] - C * x[1] - y[2]).hypot(x[3] - C * x[0] - y[3]);
    eprintln!("t = 100: |dq| = {dq:e}, |dp| = {dp:e}");
    assert!(dq < 1e-9 && dp < 1e-9, "{dq:e} {dp:e}");
}

#[test]
fn gauss_legendre_keeps_the_energy_without_drift_over_a_million_steps() {
    // gl4 at h = 0.05 on the chaotic orbit (the harder case: no torus to stay near), 1e6
    // steps to t = 5e4. A symplectic method's energy error oscillates at O(h^4) without
    // secular growth: the largest error in the last tenth of the run is no larger than a
    // small multiple of the largest in the first tenth (an explicit method's error grows
    // linearly: 10x between the two), and all of it is O(h^4) = 6e-6 times a constant of
    // order one.
    let (q, p) = hh_state(CHAOTIC_Y);
    let spec = RunSpec::from_config(&config(q, p, "gl4", 0.05, 5e4, 1, 5e4)).unwrap();
    let e0 = spec.system().invariant(spec.x0()).unwrap();
    assert!((e0 - ENERGY).abs() < 1e-15, "{e0}");
    let mut x = spec.x0().to_vec();
    let mut w = Workspace::new();
    let steps = 1_000_000;
    let (mut first, mut last, mut all) = (0.0f64, 0.0f64, 0.0f64);
    for i in 1..=steps {
        spec.system().step(&mut x, 0.0, &mut w);
        if i % 100 == 0 {
            let err = ((spec.system().invariant(&x).unwrap() - e0) / e0).abs();
            all = all.max(err);
            if i <= steps / 10 {
                first = first.max(err);
            } else if i > steps - steps / 10 {
                last = last.max(err);
            }
        }
    }
    eprintln!(
        "gl4, h = 0.05, 1e6 steps: max |dE/E| first tenth {first:e}, last tenth {last:e}, all {all:e}"
    );
    // Measured 1.4e-8: the O(h^4) constant is small for this smooth H.
    assert!(all < 1e-6, "{all:e}");
    assert!(last < 2.0 * first, "drift: {first:e} -> {last:e}");
}

/// log10 GALI_2..4 at the renormalization times of a VM run with k = 4.
fn gali_curve(config: &RunConfig) -> Vec<(f64, Vec<f64>)> {
    let mut out = Vec::new();
    analyze_config(config, &AnalysisOptions::default(), |s| {
        if let Some(set) = s.schemes.first() {
            out.push((s.t, gali_log10(&set.separations, 4)));
        }
    })
    .unwrap();
    out
}

fn slope(xs: &[f64], ys: &[f64]) -> f64 {
    let n = xs.len() as f64;
    let (mx, my) = (xs.iter().sum::<f64>() / n, ys.iter().sum::<f64>() / n);
    let sxy: f64 = xs.iter().zip(ys).map(|(x, y)| (x - mx) * (y - my)).sum();
    let sxx: f64 = xs.iter().map(|x| (x - mx) * (x - mx)).sum();
    sxy / sxx
}

#[test]
fn regular_orbit_gali_power_laws_by_gauss_legendre_and_adaptive_dop853() {
    // The regular orbit lies on a 2-torus: GALI_2 constant, GALI_3 ~ t^-2, GALI_4 ~ t^-4,
    // fitted in log-log over t in [1e3, 1e4]: past the transient in which the vectors fall
    // onto the torus's tangent space (over [100, 1000] GALI_3's exponent is still -2.3), and
    // with GALI_4 (about 1e-12 at t = 1e4) above the rounding floor.
    let (q, p) = hh_state(REGULAR_Y);
    let gl4 = config(q, p, "gl4", 0.01, 1e4, 4, 10.0);
    let mut dop = config(q, p, "dop853", 0.5, 1e4, 4, 10.0);
    dop.integrator.rtol = Some(1e-12);
    dop.integrator.atol = Some(1e-12);
    let mut slopes = Vec::new();
    for (name, cfg) in [("gl4", gl4), ("dop853 adaptive", dop)] {
        let curve: Vec<(f64, Vec<f64>)> = gali_curve(&cfg)
            .into_iter()
            .filter(|(t, _)| *t >= 1000.0)
            .collect();
        let xs: Vec<f64> = curve.iter().map(|(t, _)| t.log10()).collect();
        let s: Vec<f64> = (0..3)
            .map(|j| {
                let ys: Vec<f64> = curve.iter().map(|(_, g)| g[j]).collect();
                slope(&xs, &ys)
            })
            .collect();
        eprintln!("{name}: slopes of GALI_2, 3, 4 over t in [1e3, 1e4]: {s:?}");
        assert!(s[0].abs() < 0.25, "{name}: GALI_2 {}", s[0]);
        assert!((s[1] + 2.0).abs() < 0.25, "{name}: GALI_3 {}", s[1]);
        assert!((s[2] + 4.0).abs() < 0.25, "{name}: GALI_4 {}", s[2]);
        slopes.push(s);
    }
    // The same laws: the two methods' fitted exponents agree closely (both resolve the orbit).
    for (j, (a, b)) in slopes[0].iter().zip(&slopes[1]).enumerate() {
        assert!((a - b).abs() < 0.05, "GALI_{}: {a} vs {b}", j + 2);
    }
}

/// Finite-time MLE at `t_final` of the chaotic orbit shifted by `dy` on the section.
fn chaotic_mle(method: &str, dy: f64, t_final: f64) -> f64 {
    let (q, p) = hh_state(CHAOTIC_Y + dy);
    let mut cfg = match method {
        "gl4" => config(q, p, "gl4", 0.05, t_final, 1, 10.0),
        _ => {
            let mut c = config(q, p, "dop853", 0.5, t_final, 1, 10.0);
            c.integrator.rtol = Some(1e-10);
            c.integrator.atol = Some(1e-10);
            c
        }
    };
    cfg.schemes[0].orthonormalize = "qr".into();
    let spec = RunSpec::from_config(&cfg).unwrap();
    let mut sum = 0.0;
    let mut t = 0.0;
    Engine::new(spec)
        .run(|s| {
            if let Some(set) = s.schemes.first() {
                sum += set.stretch[0].ln();
                t = s.t;
            }
        })
        .unwrap();
    sum / t
}

#[test]
fn chaotic_orbit_mles_of_both_methods_agree_within_their_spread() {
    // Chaotic orbits of different integrators separate exponentially, so single runs are not
    // compared: for 10 nearby initial conditions (dy = 0 .. 9e-4 on the section) each method
    // gives a distribution of finite-time MLEs at t = 1e5; the means must agree within the
    // spread (two standard deviations of either distribution, the larger). Measured: gl4
    // 0.0452 +- 0.0039, dop853 0.0458 +- 0.0039 (40 CPU seconds for the 20 runs).
    let t_final = 1e5;
    let dys: Vec<f64> = (0..10).map(|i| i as f64 * 1e-4).collect();
    let stats = |method: &str| {
        // One thread per initial condition: independent runs, the results in order.
        let v: Vec<f64> = std::thread::scope(|scope| {
            let handles: Vec<_> = dys
                .iter()
                .map(|&dy| scope.spawn(move || chaotic_mle(method, dy, t_final)))
                .collect();
            handles.into_iter().map(|h| h.join().unwrap()).collect()
        });
        let n = v.len() as f64;
        let mean = v.iter().sum::<f64>() / n;
        let sd = (v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1.0)).sqrt();
        (mean, sd, v)
    };
    let (m1, s1, v1) = stats("gl4");
    let (m2, s2, v2) = stats("dop853");
    eprintln!("gl4: MLE {m1:.5} +- {s1:.5} {v1:.5?}");
    eprintln!("dop853: MLE {m2:.5} +- {s2:.5} {v2:.5?}");
    // Both in the paper's range for this orbit (0.040 .. 0.055, numerics.md).
    assert!((0.035..0.06).contains(&m1) && (0.035..0.06).contains(&m2));
    assert!((m1 - m2).abs() < 2.0 * s1.max(s2), "{m1} vs {m2}");
}

/// The DDNLS, a non-separable Hamiltonian with a second conserved quantity: its report carries
/// the norm's largest relative error beside the energy's (the run's and each scheme's), equal
/// to the largest `|S - S0| / S0` over the samples computed here from the model's own norm (to
/// the rounding of two ~100-term sums, 1e-15 of S); by its three-part composition (s11abc6,
/// order 6 at h = 0.05: ~1e-10 measured, below 1e-8) and by gl6 (symplectic Gauss-Legendre,
/// which conserves quadratic invariants such as S to the stage iterations' rounding: below
/// 1e-12). A model without a norm (Henon-Heiles) reports none.
#[test]
fn the_ddnls_norm_error_is_reported_beside_the_energy_error() {
    use chaoscope_dynamics::spec::ddnls_lattice;
    use chaoscope_schemas::config::ModelConfig;
    for (method, bound) in [("s11abc6", 1e-8), ("gl6", 1e-12)] {
        let text = format!(
            r#"
[model]
name = "ddnls"
n = 40
W = 4.0
beta = 0.72
seed = 1
[orbit]
excite = {{ sites = [16, 24], norm = 9.0, seed = 4 }}
[integrator]
method = "{method}"
h = 0.05
t_final = 50.0
[deviations]
k = 2
[[scheme]]
name = "vm"
method = "vm"
d0 = 1e-8
tau = 1.0
"#
        );
        let config = RunConfig::from_toml(&text).unwrap();
        let ModelConfig::Ddnls(model) = &config.model else {
            unreachable!()
        };
        let lattice = ddnls_lattice(model).unwrap();
        let mut worst: f64 = 0.0;
        let s0 = 9.0;
        let report = analyze_config(&config, &AnalysisOptions::default(), |sample| {
            worst = worst.max(((lattice.norm(&sample.state) - s0) / s0).abs());
        })
        .unwrap()
        .report();
        let run = &report.run;
        assert!((run.norm0.unwrap() - s0).abs() < 1e-14, "{:?}", run.norm0);
        let reported = run.norm_error_max.unwrap();
        assert_eq!(report.scheme("vm").unwrap().norm_error_max, Some(reported));
        assert!(
            (reported - worst).abs() < 1e-14,
            "{reported:e} vs {worst:e}"
        );
        assert!(reported < bound, "{method}: norm error {reported:e}");
        assert!(worst > 0.0 || method == "gl6");
        assert!(run.energy_error_max.unwrap() < 1e-8);
    }
    let (q, p) = hh_state(-0.25);
    let hh = analyze_config(
        &config(q, p, "gl6", 0.05, 10.0, 2, 1.0),
        &AnalysisOptions::default(),
        |_| {},
    )
    .unwrap()
    .report();
    assert!(hh.run.energy_error_max.is_some() && hh.run.norm_error_max.is_none());
}
