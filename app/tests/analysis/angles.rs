//! Periodic coordinates (`[model] modulo`) of flows and Hamiltonians: the integration never
//! wraps the state (the exponents are those of the unwrapped flow), and what the analysis reads
//! of the state (the extent the verdict's `unbounded` tests, the 0-1 test's observable) takes
//! the angle on its circle (the 0-1 test by its sine and cosine), so a pendulum that keeps
//! rotating is no drift.

use chaoscope_analyzer::analysis::{Analysis, AnalysisOptions};
use chaoscope_analyzer::report::Report;
use chaoscope_analyzer::verdict::Class;
use chaoscope_app::inprocess::run_info;
use chaoscope_dynamics::engine::Engine;
use chaoscope_dynamics::spec::RunSpec;
use chaoscope_schemas::config::{ModelConfig, RunConfig};

const TWO_PI: f64 = std::f64::consts::TAU;

/// The reports every `every` samples, and the last.
fn reports(cfg: &RunConfig, every: u64) -> (Vec<Report>, Report) {
    let spec = RunSpec::from_config(cfg).unwrap();
    let mut a = Analysis::new(run_info("angles", cfg, &spec), &AnalysisOptions::default());
    let mut engine = Engine::new(spec);
    let mut out = Vec::new();
    while let Some(s) = engine.next_sample().unwrap() {
        a.feed(&s);
        if a.samples().is_multiple_of(every) {
            out.push(a.report());
        }
    }
    let last = a.report();
    (out, last)
}

fn never(reports: &[Report], wrong: Class, name: &str) {
    for r in reports {
        for s in &r.schemes {
            assert_ne!(
                s.verdict.class, wrong,
                "{name}: scheme {} at t = {}: {:?}",
                s.name, r.run.t, s.verdict
            );
        }
    }
}

/// The pendulum `H = p^2/2 - cos(q)` from `q = 0, p = 2.5`: energy 2.125 above the separatrix
/// (1), so the angle rotates, `q(t)` growing by about 2.3 per unit time without end.
fn rotating_pendulum(modulo: Option<&str>) -> RunConfig {
    let modulo = modulo.map_or(String::new(), |m| format!("modulo = {m}\n"));
    RunConfig::from_toml(&format!(
        r#"
[model]
name = "hamiltonian"
n = 1
hamiltonian = "p1^2/2 - cos(q1)"
{modulo}[orbit]
q = [0.0]
p = [2.5]
[integrator]
method = "dop853"
h = 0.05
t_final = 3000.0
[deviations]
k = 2
sets = 2
seed = 1
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
"#
    ))
    .unwrap()
}

#[test]
fn a_rotating_pendulum_with_a_periodic_angle_is_regular_not_unbounded() {
    // Unwrapped, the angle's drift makes the extent grow tenfold per decade of time: the
    // verdict's `unbounded`, although the orbit is a rotation on a 1-torus of the cylinder.
    let (_, last) = reports(&rotating_pendulum(None), 1000);
    let vm = &last.scheme("vm").unwrap().verdict;
    assert_eq!(vm.class, Class::Unbounded, "without modulo: {vm:?}");

    // With the angle declared periodic the extent is bounded by |(2 pi, p_max)| and the orbit
    // gets the verdict of a rotation: an integrable 1-dof orbit whose period depends on the
    // energy (shear), so a deviation grows linearly and GALI_2 ~ t^-2, a 1-torus.
    let (live, last) = reports(&rotating_pendulum(Some("[6.283185307179586, 0]")), 50);
    never(&live, Class::Unbounded, "rotating pendulum");
    never(&live, Class::Chaotic, "rotating pendulum");
    let vm = &last.scheme("vm").unwrap().verdict;
    eprintln!(
        "rotating pendulum: {vm:?}; mpm {:?}",
        last.scheme("mpm").unwrap().verdict
    );
    assert_eq!(vm.class, Class::Regular, "{vm:?}");
    assert_eq!(vm.torus_dimension, Some(1));
    // The exponents are the unwrapped flow's (the integration never wraps): identical with and
    // without the declaration, bit for bit.
    let (_, unwrapped) = reports(&rotating_pendulum(None), 1000);
    for name in ["vm", "mpm"] {
        assert_eq!(
            last.scheme(name).unwrap().lyapunov,
            unwrapped.scheme(name).unwrap().lyapunov,
            "{name}"
        );
    }
    // The 0-1 test never reads the wrapped angle's sawtooth, whose jumps it would read as
    // chaos (K = 0.70 at t = 3000): its generic observable takes a declared angle by its sine
    // and cosine (no seam), an undeclared one as integrated, continuous. Both are regular
    // readings of this rotation (K = 0.003 and -0.077): the rotation is periodic, so D_c is
    // bounded and the median K is within 0.1 of 0, as for the regular orbits of the maps.
    let k_declared = last.scheme("vm").unwrap().indicators.value("zero_one_k");
    let k_raw = unwrapped
        .scheme("vm")
        .unwrap()
        .indicators
        .value("zero_one_k");
    eprintln!("rotating pendulum: K = {k_declared:?} (declared periodic), {k_raw:?} (not)");
    for k in [k_declared, k_raw] {
        let k = k.expect("3001 samples, more than the 0-1 test needs");
        assert!(k.abs() < 0.1, "rotating pendulum: K = {k}");
    }
}

#[test]
fn the_driven_pendulum_with_a_periodic_angle_is_chaotic() {
    // Baker and Gollub's damped driven pendulum (examples/models/driven-pendulum.toml, gamma =
    // 0.5, A = 1.5, Omega = 2/3: MLE ~ 0.11, exponents summing to -0.5), its angle x1 and the
    // drive's phase x3 declared periodic. Its angle rotates in bursts: unwrapped it drifts, and
    // a drift was read as `unbounded` before exponential divergence. On its circle the extent is
    // bounded, and the MLE's 5 e-folds over [t/2, t] are there from t ~ 100: by t = 1000 the
    // VM scheme's verdict is chaotic, and after the transient no scheme says unbounded.
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../examples/models/driven-pendulum.toml");
    let mut cfg = RunConfig::from_toml(&std::fs::read_to_string(path).unwrap()).unwrap();
    let ModelConfig::Ode(ode) = &cfg.model else {
        panic!("a flow")
    };
    assert_eq!(ode.modulo, Some(vec![TWO_PI, 0.0, TWO_PI]));
    cfg.integrator.t_final = 1000.0;
    let (live, last) = reports(&cfg, 20);
    // The first few drive periods are a transient from rest (the swing grows from x1 = 0.2 to
    // whole turns: the extent's early growth from its small start may read as a drift then);
    // from t = 100, a tenth of the run, the extent of the wrapped state is settled.
    let settled: Vec<Report> = live.into_iter().filter(|r| r.run.t >= 100.0).collect();
    never(&settled, Class::Unbounded, "driven pendulum");
    never(&settled, Class::Regular, "driven pendulum");
    let vm = &last.scheme("vm").unwrap().verdict;
    eprintln!(
        "driven pendulum: {vm:?}; mpm {:?}",
        last.scheme("mpm").unwrap().verdict
    );
    assert_eq!(vm.class, Class::Chaotic, "{vm:?}");
    let mle = last.scheme("vm").unwrap().lyapunov[0];
    // Baker and Gollub's 0.11 (finite-time at t = 1000: within 0.03).
    assert!((mle - 0.11).abs() < 0.03, "MLE {mle}");
}

#[test]
fn a_wrong_modulo_is_refused_naming_the_key() {
    // Every kind that takes `modulo` checks it against its state: one period per coordinate
    // (a Hamiltonian's state is q1..qN, p1..pN), each finite and >= 0.
    let ode = "[model]\nname = \"ode\"\nrhs = [\"x2\", \"-sin(x1)\"]\n{modulo}\n[orbit]\nx = [1.0, 0.0]\n";
    let ham = "[model]\nname = \"hamiltonian\"\nn = 1\nhamiltonian = \"p1^2/2 - cos(q1)\"\n{modulo}\n\
               [orbit]\nx = [1.0, 0.0]\n";
    let pot = "[model]\nname = \"potential\"\nn = 1\npotential = \"-cos(q1)\"\n{modulo}\n\
               [orbit]\nq = [1.0]\np = [0.0]\n";
    let rest = "[integrator]\nmethod = \"{method}\"\nh = 0.05\nt_final = 10.0\n[deviations]\nk = 1\n\
                sets = 1\nseed = 1\n[[scheme]]\nname = \"vm\"\nmethod = \"vm\"\nd0 = 1e-8\ntau = 1.0\n";
    for (model, method) in [(ode, "rk4"), (ham, "rk4"), (pot, "leapfrog")] {
        let config = |modulo: &str| {
            RunConfig::from_toml(
                &(model.replace("{modulo}", modulo) + &rest.replace("{method}", method)),
            )
            .unwrap()
        };
        // Valid: the state's two coordinates, the angle periodic.
        let spec = RunSpec::from_config(&config("modulo = [6.283185307179586, 0]")).unwrap();
        assert_eq!(spec.periods(), &[TWO_PI, 0.0]);
        for (modulo, problem) in [
            (
                "modulo = [6.283185307179586]",
                "has 1 entries but the state has dimension 2",
            ),
            (
                "modulo = [6.283185307179586, -1]",
                "entry 2 must be a period > 0",
            ),
            (
                "modulo = [6.283185307179586, inf]",
                "entry 2 must be a period > 0",
            ),
        ] {
            let e = RunSpec::from_config(&config(modulo)).unwrap_err();
            assert_eq!(e.key, "model.modulo", "{model}: {e:?}");
            assert!(e.message.contains(problem), "{modulo}: {e:?}");
        }
    }
    // A recording's header whose configuration declares periods that do not fit its state is
    // refused by the analysis, naming the key (a hostile file, not a crash).
    let cfg = rotating_pendulum(Some("[6.283185307179586, 0]"));
    let spec = RunSpec::from_config(&cfg).unwrap();
    let mut header = run_info("angles", &cfg, &spec).header;
    header.config_toml = rotating_pendulum(Some("[6.283185307179586, 0, 1]")).to_toml();
    let e = chaoscope_analyzer::run_info::RunInfo::from_header(header).unwrap_err();
    assert!(e.to_string().contains("model.modulo has 3 entries"), "{e}");
}
