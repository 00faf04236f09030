//! The disordered discrete nonlinear Schroedinger lattice (DDNLS) and the compositions of its
//! three parts' exact flows: their orders measured on the 1-D chain and the 2-D square lattice,
//! energy and norm conserved to that order, the exact flows against a Runge-Kutta reference,
//! the tangent maps against finite differences, VM against MPM on a chaotic orbit, and the same
//! bits on any thread count.

use crate::common;

use chaoscope_dynamics::integrator::composition::{Composition, CompositionScheme, SplitFlows};
use chaoscope_dynamics::integrator::runge_kutta::{RkScratch, RungeKutta, RungeKuttaTableau};
use chaoscope_dynamics::model::{Ddnls, DdnlsLattice};
use chaoscope_dynamics::spec::RunSpec;
use chaoscope_dynamics::vector_field::VectorField;
use chaoscope_schemas::config::RunConfig;

/// A small lattice in a nonlinear regime (W = 4, beta = 1.5), its disorder fixed by a formula,
/// and a generic state with every site excited (norm ~ 0.5 per site), so that every part and
/// every bond takes part in the error.
fn lattice(square: bool) -> (Ddnls, Vec<f64>) {
    let (geometry, sites) = if square {
        (DdnlsLattice::Square { n: 3 }, 9)
    } else {
        (DdnlsLattice::Chain { n: 8 }, 8)
    };
    let eps: Vec<f64> = (0..sites)
        .map(|l| 2.0 * ((l as f64) * 2.3 + 0.4).sin())
        .collect();
    let x: Vec<f64> = (0..2 * sites)
        .map(|i| 0.7 * ((i as f64) * 1.7 + 0.3).cos())
        .collect();
    (Ddnls::new(geometry, eps, 1.5), x)
}

fn integrate(model: &Ddnls, kind: CompositionScheme, x0: &[f64], h: f64, steps: usize) -> Vec<f64> {
    let times = Composition::new(kind, 3).times(h);
    let mut x = x0.to_vec();
    for _ in 0..steps {
        Composition::step(model, &times, &mut x);
    }
    x
}

fn distance(a: &[f64], b: &[f64]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y) * (x - y))
        .sum::<f64>()
        .sqrt()
}

/// The state at `t` by dop853 at a step small enough that its own error (8th order,
/// ~(h/h0)^8 of a step of the lattice's fastest rotation) is below 1e-14.
fn reference(model: &Ddnls, x0: &[f64], t: f64) -> Vec<f64> {
    let steps = (t / 0.002).round() as usize;
    let h = t / steps as f64;
    let rk = RungeKutta::new(RungeKuttaTableau::Dop853);
    let mut s = RkScratch::default();
    let mut x = x0.to_vec();
    for i in 0..steps {
        rk.advance(model, &mut x, i as f64 * h, h, &mut s);
    }
    x
}

/// Each composition's global error at `T = 4` on halving `h`: `log2(e(h)/e(h/2))` is the order
/// `p`. The compositions are symmetric, so their error expands in even powers of `h` and the
/// ratio is `2^p (1 + O(h^2))`; the step sizes are chosen per order so that the error lies
/// between ~1e-4 (asymptotic: the `h^(p+2)` term a few per cent) and ~1e-11 (far above the
/// reference's and the rounding's ~1e-14). Hence a measured slope within -0.3 .. +0.5 of `p`.
/// The lattice's fastest rotation is `|eps| + beta J + 4` (2-D) ~ 7, so `h = 0.1` is already
/// 0.7 rad a step for the base map.
#[test]
fn each_composition_has_its_order_in_1d_and_2d() {
    for square in [false, true] {
        let (model, x0) = lattice(square);
        let t = 4.0;
        let want = reference(&model, &x0, t);
        for (kind, h) in [
            (CompositionScheme::Abc2, 0.01),
            (CompositionScheme::Abc4, 0.02),
            (CompositionScheme::S9Abc6, 0.08),
            (CompositionScheme::S11Abc6, 0.08),
            (CompositionScheme::S17Abc8, 0.16),
        ] {
            let errors: Vec<f64> = [h, h / 2.0]
                .iter()
                .map(|&h| {
                    let steps = (t / h).round() as usize;
                    distance(&integrate(&model, kind, &x0, h, steps), &want)
                })
                .collect();
            let p = (errors[0] / errors[1]).log2();
            let order = kind.order() as f64;
            eprintln!(
                "{} {}: error {:.2e} at h = {h}, {:.2e} at h/2: order {p:.2}",
                if square { "2-D" } else { "1-D" },
                kind.name(),
                errors[0],
                errors[1]
            );
            assert!(
                p > order - 0.3 && p < order + 0.5,
                "{}: measured order {p} (errors {errors:?})",
                kind.name()
            );
        }
    }
}

/// The energy and the norm are conserved to the composition's order: their largest relative
/// errors over `[0, 20]` fall by `2^p` on halving `h` (slope within -0.5 .. +0.7 of `p`: a
/// maximum over a run of an oscillating error is noisier than the error at one time), and at
/// the smaller step both are below `C h^p` with the constants measured here.
#[test]
fn energy_and_norm_are_conserved_to_the_order() {
    for square in [false, true] {
        let (model, x0) = lattice(square);
        let (e0, s0) = (model.energy(&x0), model.norm(&x0));
        for (kind, h) in [
            (CompositionScheme::Abc2, 0.02),
            (CompositionScheme::Abc4, 0.04),
            (CompositionScheme::S9Abc6, 0.1),
            (CompositionScheme::S11Abc6, 0.1),
            (CompositionScheme::S17Abc8, 0.2),
        ] {
            let worst = |h: f64| {
                let times = Composition::new(kind, 3).times(h);
                let mut x = x0.clone();
                let (mut de, mut ds): (f64, f64) = (0.0, 0.0);
                for _ in 0..(20.0 / h).round() as usize {
                    Composition::step(&model, &times, &mut x);
                    de = de.max(((model.energy(&x) - e0) / e0).abs());
                    ds = ds.max(((model.norm(&x) - s0) / s0).abs());
                }
                (de, ds)
            };
            let (a, b) = (worst(h), worst(h / 2.0));
            let order = kind.order() as f64;
            for (what, big, small) in [("energy", a.0, b.0), ("norm", a.1, b.1)] {
                let p = (big / small).log2();
                eprintln!(
                    "{} {} {what}: {big:.2e} at h = {h}, {small:.2e} at h/2: order {p:.2}",
                    if square { "2-D" } else { "1-D" },
                    kind.name()
                );
                assert!(
                    p > order - 0.5 && p < order + 0.7,
                    "{} {what}: measured order {p} ({big:e}, {small:e})",
                    kind.name()
                );
            }
        }
    }
}

/// One part of the DDNLS as a vector field, to check its exact flow against dop853.
struct Part<'a> {
    model: &'a Ddnls,
    part: usize,
}

impl VectorField for Part<'_> {
    fn dim(&self) -> usize {
        2 * self.model.sites()
    }
    /// A: `dq = a p`, `dp = -a q` (`a = eps + beta J`); B: `dp = sum_nb q`; C: `dq = -sum_nb p`.
    fn value(&self, x: &[f64], _t: f64, out: &mut [f64]) {
        let n = self.model.sites();
        let (q, p) = x.split_at(n);
        out.fill(0.0);
        let (dq, dp) = out.split_at_mut(n);
        match self.part {
            0 => {
                for l in 0..n {
                    let a =
                        self.model.eps()[l] + self.model.beta() * 0.5 * (q[l] * q[l] + p[l] * p[l]);
                    dq[l] = a * p[l];
                    dp[l] = -a * q[l];
                }
            }
            1 => self.model.neighbour_sum(q, dp),
            _ => {
                self.model.neighbour_sum(p, dq);
                for v in dq.iter_mut() {
                    *v = -*v;
                }
            }
        }
    }
    fn tangent(&self, _x: &[f64], _t: f64, _v: &[f64], _out: &mut [f64]) {
        unreachable!("only the orbit is integrated")
    }
    fn divergence(&self, _x: &[f64], _t: f64) -> f64 {
        0.0
    }
    fn no_tangent_reason(&self) -> Option<String> {
        None
    }
    fn diagnose_non_finite(&self, _x: &[f64], _t: f64) -> Option<String> {
        None
    }
}

/// Each part's exact flow over `tau = 0.7` (and backwards) equals dop853's integration of that
/// part's equations at step 1e-3 (its error ~1e-15 per unit time at these rates): to 1e-12,
/// far below the ~1e-3 a wrong sign or a missing neighbour would give. The whole composition
/// then follows the full equations: s17abc8 at h = 0.05 against dop853 to 1e-10 at t = 3.
#[test]
fn exact_flows_match_a_runge_kutta_reference() {
    let rk = RungeKutta::new(RungeKuttaTableau::Dop853);
    let mut s = RkScratch::default();
    for square in [false, true] {
        let (model, x0) = lattice(square);
        for part in 0..3 {
            for tau in [0.7, -0.7] {
                let mut exact = x0.clone();
                model.flow(part, &mut exact, tau);
                let field = Part {
                    model: &model,
                    part,
                };
                let mut x = x0.clone();
                let steps = 700;
                for i in 0..steps {
                    rk.advance(&field, &mut x, i as f64 * tau / 700.0, tau / 700.0, &mut s);
                }
                let d = distance(&exact, &x);
                assert!(d < 1e-12, "part {part}, tau {tau}: {d:e}");
            }
        }
        let got = integrate(&model, CompositionScheme::S17Abc8, &x0, 0.05, 60);
        let d = distance(&got, &reference(&model, &x0, 3.0));
        assert!(d < 1e-10, "s17abc8 against dop853: {d:e}");
    }
}

/// Each part's tangent map, and a whole step's, is the derivative of its flow: central
/// differences with `delta = 1e-5` agree to ~delta^2 |D^3 flow| + eps / delta ~ 1e-10 relative;
/// 1e-8 leaves room, while a wrong term (the rate's `tau da` of A) is off by O(1).
#[test]
fn tangent_maps_match_finite_differences() {
    for square in [false, true] {
        let (model, x0) = lattice(square);
        let dim = x0.len();
        let v: Vec<f64> = (0..dim).map(|i| ((i as f64) * 0.91 + 0.2).sin()).collect();
        let delta = 1e-5;
        let check = |flow: &dyn Fn(&mut [f64]), tangent: &dyn Fn(&mut [f64], &mut [f64]), what| {
            let shifted = |sign: f64| {
                let mut y: Vec<f64> = x0
                    .iter()
                    .zip(&v)
                    .map(|(x, v)| x + sign * delta * v)
                    .collect();
                flow(&mut y);
                y
            };
            let (plus, minus) = (shifted(1.0), shifted(-1.0));
            let fd: Vec<f64> = plus
                .iter()
                .zip(&minus)
                .map(|(a, b)| (a - b) / (2.0 * delta))
                .collect();
            let mut x = x0.clone();
            let mut w = v.clone();
            tangent(&mut x, &mut w);
            let mut y = x0.clone();
            flow(&mut y);
            assert_eq!(
                x, y,
                "{what}: the tangent step moves the orbit as the flow does"
            );
            let scale = fd.iter().map(|v| v.abs()).fold(0.0, f64::max);
            let d = distance(&fd, &w) / scale;
            assert!(d < 1e-8, "{what}: tangent map off by {d:e}");
        };
        for part in 0..3 {
            check(
                &|x| model.flow(part, x, 0.9),
                &|x, w| model.flow_tangent(part, x, w, 0.9),
                format!("part {part}"),
            );
        }
        for kind in CompositionScheme::ALL {
            let times = Composition::new(kind, 3).times(0.3);
            check(
                &|x| Composition::step(&model, &times, x),
                &|x, w| Composition::step_tangent(&model, &times, x, w),
                kind.name().to_string(),
            );
        }
    }
}

/// A DDNLS run config: a block of sites sharing `norm` with random phases (norm 1 per site in
/// the tests, as the block excitations of the literature), W = 4 and a strong nonlinearity
/// (beta = 3) on a small lattice, so the orbit is chaotic within t ~ 100.
fn chaotic_config(lattice: &str, n: usize, sites: &str, norm: f64, extra: &str) -> RunConfig {
    let text = format!(
        r#"
[model]
name = "ddnls"
lattice = "{lattice}"
n = {n}
W = 4.0
beta = 3.0
seed = 7
[orbit]
excite = {{ sites = {sites}, norm = {norm}, seed = 3 }}
[integrator]
method = "s11abc6"
h = 0.02
t_final = 100.0
[deviations]
k = 2
sets = 4
seed = 9
[[scheme]]
name = "vm"
method = "vm"
d0 = 1e-8
tau = 1.0
[[scheme]]
name = "mpm"
method = "mpm"
d0 = 1e-8
tau = 1.0
{extra}"#
    );
    RunConfig::from_toml(&text).expect("config parses")
}

/// VM and MPM on a chaotic DDNLS orbit, as the GALI paper compares them: the same four sets of
/// initial directions, so their GALI_2 (which decays as exp(-(l1 - l2) t)) agree until MPM
/// meets its double-precision floor, and their MLE to 1 % (both measure one trajectory's
/// stretching; MPM's nearby orbits differ by d0 ~ 1e-8 from the linearization). The floor:
/// every one of the ~45 flows of an s11abc6 step rounds `x + d` at ~eps |x| ~ 1e-16, i.e.
/// ~1e-8 of d0, and ~2000 of them per tau = 1 put a noise of ~1e-6 .. 1e-5 across the
/// separations, which the contraction toward the most unstable direction does not remove:
/// MPM's GALI_2 levels off near 1e-5 (measured: 10^-4.3 .. 10^-5.7 from t ~ 45 on, where VM's
/// falls to 1e-8), the limit numerics.md describes for HH's higher GALIs. So the comparison
/// runs while VM's GALI_2 is above 1e-4, a decade over the floor (noise of ~10 % of GALI_2
/// at most, 0.04 in log10): within 0.1 of VM. The orbit is chaotic: the MLE at t = 100 is
/// well above the ~ln(t)/t ~ 0.05 of a regular one, GALI_2 falls below 1e-3, and the energy
/// stays conserved to 1e-7.
#[test]
fn vm_and_mpm_agree_on_a_chaotic_orbit() {
    for (lattice, n, sites) in [("chain", 24, "[9, 15]"), ("square", 5, "[2, 4]")] {
        let norm = if lattice == "chain" { 7.0 } else { 9.0 };
        let rec = common::run(&chaotic_config(lattice, n, sites, norm, ""));
        let (vm, mpm) = (rec.scheme("vm"), rec.scheme("mpm"));
        let mut worst: f64 = 0.0;
        for (a, b) in vm.iter().zip(mpm) {
            assert_eq!(a.t, b.t);
            if a.mean_log_gali(2) > -4.0 {
                worst = worst.max((a.mean_log_gali(2) - b.mean_log_gali(2)).abs());
            }
        }
        let (last_vm, last_mpm) = (vm.last().unwrap(), mpm.last().unwrap());
        let (l_vm, l_mpm) = (last_vm.mean_exponent(0), last_mpm.mean_exponent(0));
        eprintln!(
            "{lattice}: MLE VM {l_vm:.5} MPM {l_mpm:.5}, log10 GALI_2 VM {:.3} MPM {:.3}, \
             largest |delta log10 GALI_2| {worst:.2e}, energy error {:.1e}",
            last_vm.mean_log_gali(2),
            last_mpm.mean_log_gali(2),
            last_vm.energy_error
        );
        assert!(
            worst < 0.1,
            "{lattice}: GALI_2 of MPM and VM differ by {worst}"
        );
        assert!(
            ((l_mpm - l_vm) / l_vm).abs() < 0.01,
            "{lattice}: MLE {l_vm} (VM) vs {l_mpm} (MPM)"
        );
        assert!(l_vm > 0.1, "{lattice}: MLE {l_vm} is not chaotic");
        assert!(
            last_vm.mean_log_gali(2) < -3.0,
            "{lattice}: GALI_2 did not decay"
        );
        assert!(last_vm.energy_error < 1e-7, "{lattice}: energy error");
    }
}

/// The same config and seed give the same bits on one, two and four threads (a DDNLS run of
/// VM and MPM sets, rescaled and QR).
#[test]
fn ddnls_runs_are_bit_identical_on_any_thread_count() {
    let mut config = chaotic_config("square", 4, "2", 1.0, "");
    config.integrator.t_final = 5.0;
    let collect = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        let spec = RunSpec::from_config(&config).unwrap();
        pool.install(|| {
            let mut out = Vec::new();
            chaoscope_dynamics::engine::Engine::new(spec)
                .run(|s| {
                    out.extend(s.state.iter().map(|v| v.to_bits()));
                    for d in &s.schemes {
                        out.extend(d.separations.iter().chain(&d.stretch).map(|v| v.to_bits()));
                    }
                })
                .unwrap();
            out
        })
    };
    let one = collect(1);
    assert!(one.len() > 1000);
    assert_eq!(one, collect(2));
    assert_eq!(one, collect(4));
}
