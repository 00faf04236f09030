//! Taylor's method (`integrator.method = "taylor"`): every operation's recurrence against an
//! integral computed another way, the Lorenz orbit against a multiple-precision reference, the
//! variational equations against the volume law, the compiled pass against the interpreted
//! tape bit for bit, and the configurations it refuses.

use std::collections::BTreeMap;

use chaoscope_dynamics::engine::Engine;
use chaoscope_dynamics::integrator::Workspace;
use chaoscope_dynamics::spec::RunSpec;
use chaoscope_expr::jit::CCompiler;
use chaoscope_expr::{Boundary, VectorDefinition, VectorFunction};
use chaoscope_schemas::config::RunConfig;

/// Lorenz's right-hand side (its parameters are `config`'s).
const LORENZ: [&str; 3] = ["sigma*(x2 - x1)", "x1*(rho - x3) - x2", "x1*x2 - beta*x3"];

fn config(rhs: &[&str], x: &[f64], integrator: &str, t_final: f64, extra: &str) -> String {
    let rhs: Vec<String> = rhs.iter().map(|r| format!("{r:?}")).collect();
    format!(
        r#"[run]
name = "taylor"
[model]
name = "ode"
rhs = [{}]
params = {{ sigma = 10.0, rho = 28.0, beta = 2.6666666666666665 }}
[orbit]
x = {x:?}
[integrator]
{integrator}
t_final = {t_final:?}
{}"#,
        rhs.join(", "),
        if extra.is_empty() {
            // One nearby orbit, renormalized once at the end: the state is what is tested.
            format!(
                "[deviations]\nk = 1\n[[scheme]]\nname = \"mpm\"\nmethod = \"mpm\"\nd0 = \
                 1e-8\ntau = {t_final:?}\n"
            )
        } else {
            extra.to_string()
        }
    )
}

fn spec(toml: &str) -> Result<RunSpec, String> {
    let cfg = RunConfig::from_toml(toml).map_err(|e| e.to_string())?;
    RunSpec::from_config(&cfg).map_err(|e| e.to_string())
}

/// `int_a^b g` by 16-point Gauss-Legendre on 64 panels: for these smooth integrands on panels
/// of 1/64 the rule's error (order 32) is far below rounding, about 1e-16 relative.
fn quadrature(g: impl Fn(f64) -> f64, a: f64, b: f64) -> f64 {
    // Nodes and weights of the 8 positive nodes of the 16-point rule.
    const X: [f64; 8] = [
        0.095_012_509_837_637_44,
        0.281_603_550_779_258_9,
        0.458_016_777_657_227_4,
        0.617_876_244_402_643_7,
        0.755_404_408_355_003,
        0.865_631_202_387_831_7,
        0.944_575_023_073_232_6,
        0.989_400_934_991_649_9,
    ];
    const W: [f64; 8] = [
        0.189_450_610_455_068_5,
        0.182_603_415_044_923_6,
        0.169_156_519_395_002_5,
        0.149_595_988_816_576_7,
        0.124_628_971_255_533_9,
        0.095_158_511_682_492_78,
        0.062_253_523_938_647_89,
        0.027_152_459_411_754_09,
    ];
    let panels = 64;
    let h = (b - a) / panels as f64;
    let mut sum = 0.0;
    for p in 0..panels {
        let mid = a + (p as f64 + 0.5) * h;
        for (x, w) in X.iter().zip(W) {
            sum += w * (g(mid - 0.5 * h * x) + g(mid + 0.5 * h * x));
        }
    }
    sum * 0.5 * h
}

/// Each operation's recurrence: `s' = 1`, `y' = g(s)` over one unit of time is
/// `y(1) = int_{s0}^{s0+1} g`, which the quadrature gives independently. Taylor's method at
/// tol = eps takes steps whose truncation is below eps relative, so the two agree to a few
/// hundred eps of the integral's scale; a wrong recurrence (a sign, a missing term, an
/// off-by-one order) is off at the first order it enters, by far more.
#[test]
fn every_operation_s_recurrence_against_quadrature() {
    let s0 = 0.3;
    type Integrand = Box<dyn Fn(f64) -> f64>;
    let cases: Vec<(&str, Integrand)> = vec![
        ("sin(x1*x1 + 0.3)", Box::new(|s: f64| (s * s + 0.3).sin())),
        ("cos(2*x1)", Box::new(|s: f64| (2.0 * s).cos())),
        ("exp(0.5*x1*x1)", Box::new(|s: f64| (0.5 * s * s).exp())),
        ("log(2 + x1)", Box::new(|s: f64| (2.0 + s).ln())),
        ("sqrt(1.5 + x1*x1)", Box::new(|s: f64| (1.5 + s * s).sqrt())),
        ("(1.2 + x1)^2.5", Box::new(|s: f64| (1.2 + s).powf(2.5))),
        ("(1.5 + x1)^x1", Box::new(|s: f64| (1.5 + s).powf(s))),
        ("x1^3 - x1^2", Box::new(|s: f64| s * s * s - s * s)),
        ("(1 + x1)^(-2)", Box::new(|s: f64| (1.0 + s).powi(-2))),
        ("x1 / (2 + x1*x1)", Box::new(|s: f64| s / (2.0 + s * s))),
        ("tan(0.7*x1)", Box::new(|s: f64| (0.7 * s).tan())),
        ("tanh(2*x1 - 1)", Box::new(|s: f64| (2.0 * s - 1.0).tanh())),
        (
            "sinh(x1) * cosh(x1*x1)",
            Box::new(|s: f64| s.sinh() * (s * s).cosh()),
        ),
        ("atan(3*x1)", Box::new(|s: f64| (3.0 * s).atan())),
        ("asinh(2*x1)", Box::new(|s: f64| (2.0 * s).asinh())),
        (
            "atan2(x1, 2 - x1*x1)",
            Box::new(|s: f64| s.atan2(2.0 - s * s)),
        ),
        ("-exp(-x1) + 1/x1", Box::new(|s: f64| -(-s).exp() + 1.0 / s)),
    ];
    for (g, exact) in cases {
        let spec = spec(&config(
            &["1", g],
            &[s0, 0.0],
            "method = \"taylor\"\nh = 1.0",
            1.0,
            "",
        ))
        .unwrap_or_else(|e| panic!("{g}: {e}"));
        let mut x = spec.x0().to_vec();
        spec.system().step(&mut x, 0.0, &mut Workspace::new());
        let want = quadrature(exact, s0, s0 + 1.0);
        let scale = want.abs().max(1.0);
        assert!((x[0] - (s0 + 1.0)).abs() < 1e-15, "{g}: s = {}", x[0]);
        assert!(
            (x[1] - want).abs() < 200.0 * f64::EPSILON * scale,
            "{g}: {} against {want} (difference {:e})",
            x[1],
            x[1] - want
        );
    }
}

/// The Lorenz orbit from (1, 1, 1) at t = 10 against the reference of a multiple-precision
/// Taylor series (`benches/peer/heyoka_lorenz.py`, order 44 at 44 digits, its own error 3e-33).
/// Errors of eps per step grow along the orbit by about e^(0.9 t), 8e3 at t = 10, over about
/// 320 steps: a few 1e-13. dop853 at h = 0.01 is 1e-10 off; a wrong step rule or series would
/// be off by far more than 1e-11.
#[test]
fn lorenz_to_t_10_within_1e_11_of_the_multiple_precision_reference() {
    let reference = [-4.902687541134648, -3.743872921802919, 24.690858102790564];
    let spec = spec(&config(
        &LORENZ,
        &[1.0, 1.0, 1.0],
        "method = \"taylor\"\nh = 1.0",
        10.0,
        "",
    ))
    .unwrap();
    let mut x = spec.x0().to_vec();
    let mut work = Workspace::new();
    for step in 0..10 {
        spec.system().step(&mut x, step as f64, &mut work);
    }
    let e = x
        .iter()
        .zip(reference)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0, f64::max);
    assert!(e < 1e-11, "{x:?}: error {e:e}");
}

/// The Lorenz spectrum with three VM vectors: QR keeps the volume, so the exponents sum to the
/// mean divergence -(sigma + 1 + beta) = -13.6667 to the vectors' truncation; at t = 200 the largest is
/// within 0.1 of 0.9056 (finite-time values over such spans spread by several hundredths: 0.85
/// here, 0.904 at t = 1e4), the second within 0.02 of 0 and the third within 0.1 of -14.572.
/// A tangent tape that did not follow J would break the sum; one on the wrong orbit, the values.
#[test]
fn lorenz_spectrum_by_the_variational_equations() {
    let schemes = r#"[deviations]
k = 3
vectors = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
[[scheme]]
name = "vm"
method = "vm"
d0 = 1e-8
tau = 1.0
orthonormalize = "qr"
"#;
    let spec = spec(&config(
        &LORENZ,
        &[1.0, 1.0, 1.0],
        "method = \"taylor\"\nh = 1.0",
        200.0,
        schemes,
    ))
    .unwrap();
    let mut engine = Engine::new(spec);
    let mut logs = [0.0f64; 3];
    let mut t_end = 0.0;
    while let Some(sample) = engine.next_sample().unwrap() {
        t_end = sample.t;
        for s in &sample.schemes {
            for (l, r) in logs.iter_mut().zip(&s.stretch) {
                *l += r.ln();
            }
        }
    }
    let l = logs.map(|v| v / t_end);
    let sum: f64 = l.iter().sum();
    // The series of the vectors are truncated at eps of their size, so the one that contracts
    // by e^-14.6 per window carries a relative error of about eps e^14.6 = 5e-10 in its log per
    // window: the mean over 200 windows is within 1e-8 (measured 2e-10); a tangent tape not
    // following J is off by order 1.
    assert!((sum + 10.0 + 1.0 + 8.0 / 3.0).abs() < 1e-8, "{l:?}");
    assert!((l[0] - 0.9056).abs() < 0.1, "{l:?}");
    assert!(l[1].abs() < 0.02, "{l:?}");
    assert!((l[2] + 14.572).abs() < 0.1, "{l:?}");
}

fn lorenz_function() -> VectorFunction {
    let params = BTreeMap::new();
    VectorFunction::new(VectorDefinition {
        key: "rhs".into(),
        components: vec![
            "10*(x2 - x1) + 0.001*sin(t)".into(),
            "x1*(28 - x3) - x2".into(),
            "x1*x2 - 2.6666666666666665*x3 + sin(x1)*exp(-x3*x3/1000) + atan2(x2, 3 + x1*x1)"
                .into(),
        ],
        params,
        boundary: Boundary::Fixed,
        tables: Vec::new(),
        time: true,
    })
    .unwrap()
}

/// The compiled pass performs the interpreted tape's operations in its order: every
/// coefficient of the state and of three vectors is the same bits (a field with calls,
/// quotients and the time, so every kind of recurrence runs). Skipped, saying so, where no C
/// compiler runs.
#[test]
fn the_compiled_pass_gives_the_interpreted_bits() {
    let Some(cc) = CCompiler::from_env() else {
        eprintln!("no C compiler (CHAOSCOPE_CC): the compiled pass is not compared");
        return;
    };
    let f = lorenz_function();
    let interpreted = f.taylor_tape(3, 20).unwrap();
    let compiled = interpreted.clone();
    if let Err(e) = compiled.compile_native(&cc, &std::sync::atomic::AtomicBool::new(false)) {
        eprintln!("the C compiler failed ({e}): the compiled pass is not compared");
        return;
    }
    assert!(compiled.is_native() && !interpreted.is_native());
    let x = [1.3, -0.7, 20.5];
    let w = [1.0, 0.0, 0.0, 0.3, 1.0, 0.0, -0.2, 0.5, 1.0];
    let mut a = vec![0.0; interpreted.buffer_len()];
    let mut b = a.clone();
    interpreted.coefficients(&mut a, &x, &w, 0.25);
    compiled.coefficients(&mut b, &x, &w, 0.25);
    let bits = |v: &[f64]| v.iter().map(|c| c.to_bits()).collect::<Vec<_>>();
    assert_eq!(bits(&a), bits(&b));
    assert!(a.iter().all(|c| c.is_finite()) && a.iter().filter(|c| **c != 0.0).count() > 100);
}

/// The state moves bit for bit the same with tangent vectors riding along as without (the
/// steps are chosen from the state's series alone), and a step depends only on the state it
/// starts from (what makes a run resumable).
#[test]
fn vectors_do_not_move_the_state_and_steps_are_memoryless() {
    let spec = spec(&config(
        &LORENZ,
        &[1.0, 1.0, 1.0],
        "method = \"taylor\"\nh = 0.5",
        10.0,
        "",
    ))
    .unwrap();
    let system = spec.system();
    let (mut x, mut y) = (spec.x0().to_vec(), spec.x0().to_vec());
    let mut w = vec![1.0, 0.0, 0.0, 0.0, 1.0, 0.0];
    let mut work = Workspace::new();
    for step in 0..20 {
        let t = step as f64 * 0.5;
        system.step(&mut x, t, &mut work);
        system.step_tangent(&mut y, &mut w, t, &mut work).unwrap();
        assert_eq!(x, y, "step {step}");
    }
    let mut fresh = Workspace::new();
    let mut z = x.clone();
    system.step(&mut x, 10.0, &mut work);
    system.step(&mut z, 10.0, &mut fresh);
    assert_eq!(x, z);
}

/// What Taylor's method refuses, each naming the key and the reason.
#[test]
fn taylor_refuses_what_it_cannot_do() {
    let cases = [
        (
            config(
                &["abs(x1) - x2", "x1"],
                &[1.0, 0.0],
                "method = \"taylor\"\nh = 0.1",
                1.0,
                "",
            ),
            "'abs' at line 1, column 1 of rhs[1] is not analytic",
        ),
        (
            config(
                &["x2", "-x1"],
                &[1.0, 0.0],
                "method = \"taylor\"\nh = 0.1\ntol = 0.5",
                1.0,
                "",
            ),
            "integrator.tol",
        ),
        (
            config(
                &["x2", "-x1"],
                &[1.0, 0.0],
                "method = \"taylor\"\nh = 0.1\ntol = nan",
                1.0,
                "",
            ),
            "integrator.tol",
        ),
        (
            config(
                &["x2", "-x1"],
                &[1.0, 0.0],
                "method = \"taylor\"\nh = 0.1\nrtol = 1e-10\natol = 1e-10",
                1.0,
                "",
            ),
            "taylor takes one tolerance, tol",
        ),
        (
            config(
                &["x2", "-x1"],
                &[1.0, 0.0],
                "method = \"rk4\"\nh = 0.1\ntol = 1e-10",
                1.0,
                "",
            ),
            "tol is the tolerance of taylor",
        ),
    ];
    for (toml, want) in cases {
        match spec(&toml) {
            Ok(_) => panic!("accepted: {toml}"),
            Err(e) => assert!(e.contains(want), "{e}\nwanted: {want}"),
        }
    }
}

/// A solution that blows up in finite time (x' = x^2 from 1, at t = 1) stops the run at the
/// collapse with a message, never a NaN in a sample.
#[test]
fn a_blow_up_stops_the_run_with_the_reason() {
    let spec = spec(&config(
        &["x1*x1"],
        &[1.0],
        "method = \"taylor\"\nh = 0.25",
        2.0,
        "",
    ))
    .unwrap();
    let mut engine = Engine::new(spec);
    let err = loop {
        match engine.next_sample() {
            Ok(Some(s)) => assert!(s.state.iter().all(|v| v.is_finite()), "{:?}", s.state),
            Ok(None) => panic!("the run ended past the blow-up"),
            Err(e) => break e.to_string(),
        }
    };
    assert!(err.contains("Taylor step collapsed"), "{err}");
}

/// A section of a flow stepped by Taylor's method on a coarse grid: the steps of one grid
/// interval (h = 1, about 30 Taylor steps and more than one turn of the Lorenz attractor) are
/// walked one by one, so no crossing between them is missed. The first 12 upward crossings of
/// x3 = 27 are those of dop853 at h = 0.005 (a section located to rounding on an orbit known
/// to 1e-12 at t = 10; by the 12th crossing, near t = 9, both orbits agree to 1e-9).
#[test]
fn sections_of_a_taylor_flow_on_a_coarse_grid_miss_no_crossing() {
    use chaoscope_dynamics::section::surface::{Direction, Surface, surface_crossings};
    let crossings = |integrator: &str, steps: u64| {
        let toml = config(&LORENZ, &[1.0, 1.0, 1.0], integrator, 20.0, "");
        let cfg = RunConfig::from_toml(&toml).unwrap();
        let spec = RunSpec::from_config(&cfg).unwrap();
        let surface = Surface::new(&spec, &cfg.model, "x3 - 27").unwrap();
        surface_crossings(&spec, &surface, Direction::Up, spec.x0(), steps, 12).crossings
    };
    let taylor = crossings("method = \"taylor\"\nh = 1.0", 20);
    let dop853 = crossings("method = \"dop853\"\nh = 0.005", 4000);
    assert_eq!(taylor.len(), 12, "{taylor:?}");
    assert_eq!(dop853.len(), 12);
    for (a, b) in taylor.iter().zip(&dop853) {
        assert!((a.t - b.t).abs() < 1e-8, "{} against {}", a.t, b.t);
        for (u, v) in a.x.iter().zip(&b.x) {
            assert!((u - v).abs() < 1e-7, "{:?} against {:?}", a.x, b.x);
        }
    }
    // The crossings are 0.6 to 1.5 apart: several of them within one grid interval of 1.
    assert!(taylor.windows(2).any(|w| w[1].t.floor() == w[0].t.floor()));
}

/// A run resumed from one of its samples continues bit for bit: every later sample (state,
/// stretching factors) equals the uninterrupted run's, VM and MPM, as a resumed `chaoscope
/// resume` is promised (a Taylor step depends only on the state it starts from).
#[test]
fn a_resumed_run_continues_bit_for_bit() {
    let schemes = r#"[deviations]
k = 2
sets = 1
seed = 3
[[scheme]]
name = "vm"
method = "vm"
d0 = 1e-8
tau = 0.5
[[scheme]]
name = "mpm"
method = "mpm"
d0 = 1e-8
tau = 0.5
"#;
    let toml = config(
        &LORENZ,
        &[1.0, 1.0, 1.0],
        "method = \"taylor\"\nh = 0.25",
        20.0,
        schemes,
    );
    let samples = |mut engine: Engine| {
        let mut all = Vec::new();
        while let Some(s) = engine.next_sample().unwrap() {
            all.push(s);
        }
        all
    };
    let whole = samples(Engine::new(spec(&toml).unwrap()));
    let at = whole.iter().position(|s| s.t == 7.5).unwrap();
    let resumed = samples(Engine::resume(spec(&toml).unwrap(), &whole[at]).unwrap());
    assert_eq!(resumed.len(), whole.len() - at - 1);
    for (a, b) in resumed.iter().zip(&whole[at + 1..]) {
        assert_eq!((a.t, &a.state), (b.t, &b.state));
        for (x, y) in a.schemes.iter().zip(&b.schemes) {
            assert_eq!(x.stretch, y.stretch, "t = {}", a.t);
            assert_eq!(x.separations, y.separations, "t = {}", a.t);
        }
    }
}

/// The first VM set steps with the reference in one pass (the tangent pass computes the orbit
/// anyway); a second VM scheme with the same vectors steps after it along the substeps the
/// reference took, as every other set does: the two give the same bits at every
/// renormalization, and an MPM scheme beside them the MLE the VM sets give, to the MPM's
/// d0-limited precision: its nearby orbits feel the second derivatives of Lorenz's products at
/// d0 = 1e-8 times their size, about 1e-7 of the stretch per window before QR (measured over
/// 30 windows: 2.2e-6 of the summed log), so within 1e-5.
#[test]
fn the_set_stepped_with_the_reference_equals_one_stepped_after_it() {
    let schemes = r#"[deviations]
k = 3
vectors = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
[[scheme]]
name = "carried"
method = "vm"
d0 = 1e-8
tau = 1.0
orthonormalize = "qr"
[[scheme]]
name = "after"
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
    let toml = config(
        &LORENZ,
        &[1.0, 1.0, 1.0],
        "method = \"taylor\"\nh = 0.5",
        30.0,
        schemes,
    );
    let mut engine = Engine::new(spec(&toml).unwrap());
    let mut logs = [[0.0f64; 3]; 3];
    let mut renormalizations = 0;
    while let Some(s) = engine.next_sample().unwrap() {
        if s.schemes.len() < 3 {
            continue;
        }
        renormalizations += 1;
        assert_eq!(s.schemes[0].stretch, s.schemes[1].stretch, "t = {}", s.t);
        assert_eq!(
            s.schemes[0].separations, s.schemes[1].separations,
            "t = {}",
            s.t
        );
        for (l, sc) in logs.iter_mut().zip(&s.schemes) {
            for (a, r) in l.iter_mut().zip(&sc.stretch) {
                *a += r.ln();
            }
        }
    }
    // The initial sample and one per tau to t = 30.
    assert_eq!(renormalizations, 31);
    assert!(
        ((logs[2][0] - logs[0][0]) / logs[0][0]).abs() < 1e-5,
        "{logs:?}"
    );
}
