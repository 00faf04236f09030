//! Non-autonomous systems (explicit time `t` in `rhs`, a Hamiltonian or a potential) through
//! the engine: the driven Duffing oscillator `x'' + delta x' + alpha x + beta x^3 = gamma cos(omega
//! t)` with `t` written explicitly against its autonomous rewrite with a phase variable `x3`
//! (`dx3/dt = omega`, `cos(x3)`), by VM and MPM; and the splittings' order on a time-dependent
//! potential (the extended phase space).

use chaoscope_dynamics::engine::Engine;
use chaoscope_dynamics::integrator::Workspace;
use chaoscope_dynamics::section::stroboscopic::{Stroboscopic, stroboscopic_samples};
use chaoscope_dynamics::spec::RunSpec;
use chaoscope_schemas::config::RunConfig;

const DELTA: f64 = 0.3;
/// Steps per forcing period `2 pi / omega` (omega = 1.2).
const STEPS_PER_PERIOD: f64 = 100.0;

/// MPM renormalizes 10 times per period (VM once): nearby orbits resolve a direction only
/// while the stretching within a window leaves its orthogonal part far above the nonlinear
/// terms of the others (`d0` times the stretch), as for Lorenz (examples/models/lorenz.toml).
const MPM_WINDOWS_PER_PERIOD: f64 = 10.0;

fn period() -> f64 {
    2.0 * std::f64::consts::PI / 1.2
}

/// The Duffing config: `explicit` writes the drive as `cos(omega*t)` on the state `(x, x')`;
/// otherwise the phase is the third coordinate, advanced by `dx3/dt = omega` from 0. `vectors`:
/// the explicit deviation directions (`None`: `k` random ones).
fn duffing(
    gamma: f64,
    explicit: bool,
    x0: [f64; 2],
    periods: f64,
    k: usize,
    vectors: Option<&str>,
) -> RunConfig {
    let (rhs, x) = if explicit {
        (
            r#"["x2", "-delta*x2 - alpha*x1 - beta*x1^3 + gamma*cos(omega*t)"]"#.to_string(),
            format!("[{:?}, {:?}]", x0[0], x0[1]),
        )
    } else {
        (
            r#"["x2", "-delta*x2 - alpha*x1 - beta*x1^3 + gamma*cos(x3)", "omega"]"#.to_string(),
            format!("[{:?}, {:?}, 0.0]", x0[0], x0[1]),
        )
    };
    let t = period();
    let deviations = match vectors {
        Some(v) => format!("k = {k}\nvectors = {v}"),
        None => format!("k = {k}\nsets = 1\nseed = 7"),
    };
    let toml = format!(
        r#"
[model]
name = "ode"
rhs = {rhs}
params = {{ delta = {DELTA:?}, alpha = -1.0, beta = 1.0, omega = 1.2, gamma = {gamma:?} }}
[orbit]
x = {x}
[integrator]
method = "dop853"
h = {h:?}
t_final = {t_final:?}
[deviations]
{deviations}
[[scheme]]
name = "vm"
method = "vm"
d0 = 1e-8
tau = {t:?}
orthonormalize = "qr"
[[scheme]]
name = "mpm"
method = "mpm"
d0 = 1e-8
tau = {tau_mpm:?}
orthonormalize = "qr"
"#,
        h = t / STEPS_PER_PERIOD,
        tau_mpm = t / MPM_WINDOWS_PER_PERIOD,
        t_final = t * periods,
    );
    RunConfig::from_toml(&toml).unwrap()
}

/// Per scheme (vm, mpm), at each of its renormalizations: the time and the finite-time
/// exponents `sum ln |R_jj| / t` of its one set so far.
fn finite_time_exponents(config: &RunConfig) -> [Vec<(f64, Vec<f64>)>; 2] {
    let spec = RunSpec::from_config(config).unwrap();
    let k = config.deviations.k;
    let mut sums = [vec![0.0; k], vec![0.0; k]];
    let mut out = [Vec::new(), Vec::new()];
    let mut engine = Engine::new(spec);
    while let Some(sample) = engine.next_sample().unwrap() {
        if sample.step == 0 {
            continue;
        }
        let t = sample.t;
        for s in &sample.schemes {
            let scheme = s.scheme as usize;
            for (acc, r) in sums[scheme].iter_mut().zip(&s.stretch) {
                *acc += r.ln();
            }
            out[scheme].push((t, sums[scheme].iter().map(|s| s / t).collect()));
        }
    }
    out
}

/// The last finite-time exponents of each scheme.
fn final_exponents(exponents: &[Vec<(f64, Vec<f64>)>; 2]) -> [(f64, Vec<f64>); 2] {
    exponents.clone().map(|e| e.last().unwrap().clone())
}

#[test]
fn duffing_periodic_orbit_explicit_time_equals_the_phase_variable_rewrite() {
    // gamma = 0.1: the response settles on a stable period-1 orbit in the right well (checked
    // below: the stroboscopic samples repeat to 1e-9 after the transient). Both exponents of
    // that orbit are negative (Floquet exponents, summing to -delta).
    let gamma = 0.1;
    let x0 = [1.0, 0.0];
    let periods = 400.0;
    let explicit = duffing(gamma, true, x0, periods, 2, None);
    let spec = RunSpec::from_config(&explicit).unwrap();
    let every = Stroboscopic::new(&spec, &explicit.model, "2*pi/omega").unwrap();
    assert_eq!(every.steps, STEPS_PER_PERIOD as u64);
    let strobe = stroboscopic_samples(&spec, every, spec.x0(), spec.total_steps(), 0, usize::MAX);
    let last = strobe.crossings.len() - 1;
    let (a, b) = (&strobe.crossings[last - 1].x, &strobe.crossings[last].x);
    let drift = ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2)).sqrt();
    assert!(drift < 1e-9, "not a period-1 orbit: {a:?} -> {b:?}");

    // The rewrite's tangent dynamics is block triangular: a deviation without an x3 component
    // keeps none (dx3/dt = omega reads no coordinate), and its (x1, x2) part follows the
    // explicit system's tangent map with the phase x3 in place of omega t. So with the
    // directions e1, e2 (given explicitly to both) VM and MPM see the same deviations; x3 and
    // omega t differ only in rounding (about one ulp of x3 per step, |x3| < 2600: below 1e-9
    // after the run's 40 000 steps), which a contracting orbit does not amplify: each
    // exponent's finite-time estimate differs by far less than the 1e-6 asked.
    let e12_2d = "[[1.0, 0.0], [0.0, 1.0]]";
    let e12_3d = "[[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]";
    let by_time = final_exponents(&finite_time_exponents(&duffing(
        gamma,
        true,
        x0,
        periods,
        2,
        Some(e12_2d),
    )));
    let by_phase = final_exponents(&finite_time_exponents(&duffing(
        gamma,
        false,
        x0,
        periods,
        2,
        Some(e12_3d),
    )));
    let final_time = by_time.clone().map(|(_, l)| l);
    for scheme in 0..2 {
        assert_eq!(by_time[scheme].0, by_phase[scheme].0);
        for j in 0..2 {
            let (a, b) = (by_time[scheme].1[j], by_phase[scheme].1[j]);
            assert!(
                (a - b).abs() < 1e-6,
                "scheme {scheme} exponent {j}: explicit t {a} vs phase {b}"
            );
        }
        // Negative (a stable orbit), summing to the divergence -delta.
        let l = &final_time[scheme];
        assert!(l[0] < 0.0 && l[1] < 0.0, "{l:?}");
        assert!((l[0] + l[1] + DELTA).abs() < 1e-6, "{l:?}");
    }

    // The rewrite's extra exponent: e3 first (QR keeps its direction first), whose tangent
    // vector is (v(t), 1) with v the response to a shift of the phase, bounded on a stable
    // orbit. So its accumulated log stretch ln|w(t)| stays bounded: the estimate is 0 up to a
    // 1/t decay. A nonzero exponent l would make the accumulated stretch grow by l (t2 - t1)
    // between two times; here it changes by less than 0.05 between t/2 and t (= 1047), so
    // |l| < 5e-5, and the estimate itself is below ln(1 + max|v|^2)/2t.
    let e3_first = "[[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]";
    let full = finite_time_exponents(&duffing(gamma, false, x0, periods, 3, Some(e3_first)));
    for scheme in 0..2 {
        let (t_end, l_end) = full[scheme].last().unwrap();
        let (t_half, l_half) = &full[scheme][full[scheme].len() / 2 - 1];
        let (s_end, s_half) = (l_end[0] * t_end, l_half[0] * t_half);
        assert!(
            (-1e-6..3.0).contains(&s_end),
            "scheme {scheme}: ln|w| = {s_end}"
        );
        assert!(
            (s_end - s_half).abs() < 0.05,
            "scheme {scheme}: the phase's stretch grows: {s_half} -> {s_end}"
        );
        // Its other two exponents are the explicit system's.
        for j in 0..2 {
            let (a, b) = (final_time[scheme][j], l_end[j + 1]);
            assert!(
                (a - b).abs() < 1e-3,
                "scheme {scheme} exponent {j}: {a} vs {b}"
            );
        }
    }
}

#[test]
fn duffing_attractor_explicit_time_and_phase_rewrite_have_one_exponent_distribution() {
    // gamma = 0.5: the strange attractor (docs: its stroboscopic section). x3 and omega t differ
    // in rounding, which the chaos amplifies: the orbits separate after about ln(1/eps)/0.13 =
    // 280 time units, so only distributions compare. 10 initial conditions 1e-3 apart, each
    // with both forms over 200 forcing periods (t = 1047).
    let gamma = 0.5;
    let periods = 200.0;
    let mut mles = [Vec::new(), Vec::new()];
    for i in 0..10 {
        let x0 = [1.0 + 1e-3 * i as f64, 0.0];
        for (form, explicit) in [(0, true), (1, false)] {
            let k = if explicit { 2 } else { 3 };
            let exponents = finite_time_exponents(&duffing(gamma, explicit, x0, periods, k, None));
            for (scheme, series) in exponents.iter().enumerate() {
                // At every renormalization the exponents (the whole spectrum) sum to the
                // divergence: -delta for the explicit form, -delta + 0 for the rewrite. VM's sum
                // is ln |det| of the tangent map of the DOP853 steps over t, divided by t: the
                // exact -delta t up to the method's error (h^9 per step: C h^8 per unit time,
                // h^8 = 6e-11, C << 1 for a linear damping) and the rounding of the tangent
                // steps and of each QR, a few eps per step: (t / h) eps / t = eps / h = 4e-15
                // per few eps, whatever t. 1e-11 bounds both (measured: 4e-14). MPM's nearby
                // orbits at d0 = 1e-8 follow the tangent map up to their nonlinear terms, d0
                // times the stretch within a window (below 10 at 10 windows per period), and
                // x + d is rounded to eps |x| / d0 = 2e-8 relative per step: 1e-6 (measured:
                // 3.5e-7 at worst over the 20 runs).
                let tol = [1e-11, 1e-6][scheme];
                for (t, l) in series {
                    let sum: f64 = l.iter().sum();
                    assert!(
                        (sum + DELTA).abs() < tol,
                        "x0 {x0:?} form {form} scheme {scheme} t = {t}: sum {sum}"
                    );
                }
            }
            let [(_, vm), (_, mpm)] = final_exponents(&exponents);
            // VM and MPM on one orbit: the same MLE to O(d0) amplified by the chaos, well
            // within 1e-3.
            assert!((vm[0] - mpm[0]).abs() < 1e-3, "{vm:?} {mpm:?}");
            mles[form].push(vm[0]);
        }
    }
    let stats = |v: &[f64]| {
        let n = v.len() as f64;
        let mean = v.iter().sum::<f64>() / n;
        let var = v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1.0);
        (mean, var.sqrt())
    };
    let (m_time, s_time) = stats(&mles[0]);
    let (m_phase, s_phase) = stats(&mles[1]);
    // The attractor is chaotic: a clearly positive exponent in every run.
    assert!(mles.iter().flatten().all(|&l| l > 0.05), "{mles:?}");
    // Two samples of 10 from one distribution: their means differ by about sigma sqrt(2/10) =
    // 0.45 sigma; within one spread (the larger sample standard deviation) is a 2.2-sigma
    // bound. A wrong stage time (the force taken at the step's start, a first-order error of
    // 0.5 h omega gamma in the forcing) shifts the whole orbit, not the rounding.
    let spread = s_time.max(s_phase);
    assert!(
        (m_time - m_phase).abs() < spread,
        "means {m_time} vs {m_phase}, spreads {s_time}, {s_phase}"
    );
}

/// The driven pendulum-like potential `V(q, t) = -cos(q) (1 + a cos(w t))` from (q, p) = (0.5,
/// 0.2), as config sections.
const DRIVEN_POTENTIAL: &str = r#"[model]
name = "potential"
n = 1
potential = "-cos(q1) * (1 + a*cos(w*t))"
params = { a = 0.5, w = 2.0 }
[orbit]
q = [0.5]
p = [0.2]
"#;

/// The driven pendulum-like potential `V(q, t) = -cos(q) (1 + a cos(w t))`, stepped by
/// `method` at `h` to `t_final` from (q, p) = (0.5, 0.2): the final state.
fn driven_potential_state(method: &str, h: f64, t_final: f64) -> Vec<f64> {
    let toml = format!(
        r#"
{DRIVEN_POTENTIAL}[integrator]
method = "{method}"
h = {h:?}
t_final = {t_final:?}
[deviations]
k = 2
[[scheme]]
name = "mpm"
method = "mpm"
d0 = 1e-8
tau = {t_final:?}
"#
    );
    let config = RunConfig::from_toml(&toml).unwrap();
    let spec = RunSpec::from_config(&config).unwrap();
    assert!(spec.system().reads_time());
    let mut x = spec.x0().to_vec();
    let mut w = Workspace::new();
    for step in 0..spec.total_steps() {
        spec.system().step(&mut x, spec.time_of(step), &mut w);
    }
    x
}

#[test]
fn splittings_keep_their_order_on_a_time_dependent_potential() {
    // H = p^2/2 + V(q, t) in the extended phase space (each kick at the time its drifts
    // reached): a splitting of order r has a global error C h^r, so halving h divides the
    // error of the final state (against a fine reference) by 2^r. The energy is not
    // conserved here, so the final state is compared. Over t = 4 from h = 0.1 down to 0.025
    // the leading term dominates (the next is O(h^(r+2)) for these symmetric methods: its
    // share is (h/T)^2 ~ 1e-3 relative), so each halving's ratio is 2^r within 15 %; the
    // reference (ABA864 at h = 1/2560, error ~ 1e-14) is far below the smallest error (~1e-9).
    let t_final = 4.0;
    let reference = driven_potential_state("aba864", 1.0 / 2560.0, t_final);
    for (method, order) in [("leapfrog", 2), ("saba2", 2), ("aba864", 4)] {
        let errors: Vec<f64> = [0.1, 0.05, 0.025]
            .iter()
            .map(|&h| {
                let x = driven_potential_state(method, h, t_final);
                x.iter()
                    .zip(&reference)
                    .map(|(a, b)| (a - b).powi(2))
                    .sum::<f64>()
                    .sqrt()
            })
            .collect();
        let want = 2f64.powi(order);
        for pair in errors.windows(2) {
            let ratio = pair[0] / pair[1];
            assert!(
                (ratio / want - 1.0).abs() < 0.15,
                "{method}: error ratio {ratio} for order {order} (errors {errors:?})"
            );
        }
    }
}

#[test]
fn time_dependent_lattice_potential_by_vm_and_mpm() {
    // An FPUT-like chain of 3 sites with a pumped on-site term, V(q, t): its sum that reads t
    // is unrolled (not a loop), the forces and the Hessian-vector product are taken at each
    // kick's time (VM's tangent kick at the same time as the orbit's), so VM and MPM, on the
    // same orbit with the same directions, give the same largest exponent up to MPM's O(d0)
    // and rounding (1e-3 relative asked; measured 6e-5). The pump (w = 7) is above twice every normal
    // mode's frequency (1 to 2.2): no parametric resonance, the orbit stays bounded.
    let toml = r#"
[model]
name = "potential"
n = 3
potential = "sum(i = 1..N-1, (q[i+1] - q[i])^2/2 + (q[i+1] - q[i])^4/4) + sum(i = 1..N, (1 + a*cos(w*t)) * q[i]^2/2)"
params = { a = 0.5, w = 7.0 }
[orbit]
q = [0.9, -0.4, 0.3]
p = [0.0, 0.5, -0.2]
[integrator]
method = "aba864"
h = 0.01
t_final = 400.0
[deviations]
k = 2
sets = 1
seed = 3
[[scheme]]
name = "vm"
method = "vm"
d0 = 1e-8
tau = 1.0
orthonormalize = "qr"
[[scheme]]
name = "mpm"
method = "mpm"
d0 = 1e-8
tau = 1.0
orthonormalize = "qr"
"#;
    let config = RunConfig::from_toml(toml).unwrap();
    let spec = RunSpec::from_config(&config).unwrap();
    let model = spec.system().separable().unwrap().model().clone();
    assert!(model.reads_time());
    // V itself at a time: the pumped term's factor 1 + a cos(w t).
    let (q, t) = ([0.1, 0.2, 0.3], 0.7);
    let bond = |d: f64| d * d / 2.0 + d.powi(4) / 4.0;
    let want =
        bond(0.1) + bond(0.1) + (1.0 + 0.5 * (7.0f64 * t).cos()) * (0.01 + 0.04 + 0.09) / 2.0;
    assert!(
        (model.potential(&q, chaoscope_dynamics::model::At::time(t)) - want).abs() < 1e-15,
        "{want}"
    );
    let [(_, vm), (_, mpm)] = final_exponents(&finite_time_exponents(&config));
    assert!(vm[0] > 0.0, "{vm:?}");
    assert!(
        (vm[0] - mpm[0]).abs() < 1e-3 * vm[0],
        "VM {vm:?} vs MPM {mpm:?}"
    );
}

#[test]
fn map_of_a_time_dependent_potential_runs_through_the_engine() {
    // A potential of t has no lane kernels (they take no time): its map points run through
    // the one-orbit engine, every point from t = 0, on any number of threads with the same
    // bits; the basis route (batched kernel only) is refused naming the reason.
    let text = |route: &str| {
        format!(
            r#"
{DRIVEN_POTENTIAL}[integrator]
method = "aba864"
h = 0.01
t_final = 20.0
[deviations]
k = 1
sets = 1
seed = 1
[[scheme]]
name = "s"
method = "mpm"
d0 = 1e-8
tau = 1.0
[map]
x = {{ coord = "q1", min = -1.0, max = 1.0, n = 3 }}
y = {{ coord = "p1", min = -0.5, max = 0.5, n = 2 }}
indicator = "mle"
{route}
"#
        )
    };
    use chaoscope_dynamics::batch::Isa;
    use chaoscope_dynamics::map::schedule::{MapOptions, run_map};
    use chaoscope_dynamics::map::spec::MapSpec;
    use chaoscope_dynamics::map::{PointStatus, one_orbit};
    let spec = MapSpec::from_config(&RunConfig::from_toml(&text("")).unwrap()).unwrap();
    assert!(!spec.has_batched_kernel());
    let want: Vec<_> = (0..spec.grid_points())
        .map(|i| one_orbit::point(&spec, i))
        .collect();
    assert!(want.iter().all(|r| r.status == PointStatus::Ok), "{want:?}");
    for threads in [1, 2] {
        let mut got = Vec::new();
        let options = MapOptions {
            threads: Some(threads),
            isa: Isa::detect(),
            mpm_points_per_batch: 2,
            termination: None,
        };
        run_map(
            &spec,
            &(0..spec.grid_points()).collect::<Vec<_>>(),
            &options,
            |r| {
                got.push(r);
                true
            },
        )
        .unwrap();
        got.sort_by_key(|r| r.index);
        for (g, w) in got.iter().zip(&want) {
            assert!(g.same_numbers(w), "{threads} threads: {g:?} vs {w:?}");
        }
    }
    let Err(basis) =
        MapSpec::from_config(&RunConfig::from_toml(&text("route = \"basis\"")).unwrap())
    else {
        panic!("the basis route of a potential of t is refused")
    };
    let basis = basis.to_string();
    assert!(basis.contains("potential does not read t"), "{basis}");
}
