//! `[model] name = "potential"`: user-written potentials against the built-in models they
//! restate, the integrable Toda lattice's GALI laws, a tabulated bond against the analytic one,
//! and the refusals (VM on a non-smooth potential, bad expressions, run-time NaN).

use chaoscope_dynamics::engine::{Engine, RunError};
use chaoscope_dynamics::indicators::{StretchSums, gali_log10, sali};
use chaoscope_dynamics::model::{At, FputBeta, SeparableHamiltonian};
use chaoscope_dynamics::spec::RunSpec;
use chaoscope_schemas::config::{
    DeviationsConfig, ModelConfig, ParamValue, PotentialConfig, RunConfig, SchemeConfig,
    TableConfig, TableSpec, paper,
};

use crate::common;

const HH_POTENTIAL: &str = "(q1^2 + q2^2)/2 + q1^2*q2 - q2^3/3";
const FPUT_POTENTIAL: &str = "sum(i = 0..N, (q[i+1] - q[i])^2/2 + beta/4*(q[i+1] - q[i])^4)";

fn vm_and_mpm() -> Vec<SchemeConfig> {
    vec![
        SchemeConfig::new("vm", "vm", 1e-8, 1.0),
        SchemeConfig::new("mpm", "mpm", 1e-8, 1.0),
    ]
}

/// Everything the indicators are computed from, at the end of a run, per (scheme, set):
/// log10 GALI_2..k, SALI, MLE.
#[derive(Debug, Clone, PartialEq)]
struct Final {
    state: Vec<f64>,
    gali: Vec<Vec<f64>>,
    sali: Vec<f64>,
    mle: Vec<f64>,
}

fn final_indicators(spec: RunSpec) -> Final {
    let dim = spec.dim();
    let n_tasks = spec.schemes().len() * spec.sets();
    let mut sums = vec![StretchSums::new(spec.k()); n_tasks];
    let mut last = None;
    Engine::new(spec)
        .run(|s| {
            if s.seq > 0 {
                for (i, d) in s.schemes.iter().enumerate() {
                    sums[i].add(&d.stretch);
                }
            }
            last = Some(s);
        })
        .expect("the run completes");
    let s = last.unwrap();
    Final {
        gali: s
            .schemes
            .iter()
            .map(|d| gali_log10(&d.separations, dim))
            .collect(),
        sali: s
            .schemes
            .iter()
            .map(|d| sali(&d.separations, dim).unwrap_or(f64::NAN))
            .collect(),
        mle: sums.iter().map(|m| m.mle(s.t)).collect(),
        state: s.state,
    }
}

/// Largest relative difference of two results, and whether all bits agree: the state relative
/// to its largest entry, GALI_k, SALI and the MLE each relative to their own value (GALI from
/// its log10: dG / G = ln 10 * d log10 G).
fn compare(a: &Final, b: &Final) -> (f64, bool) {
    let scale = a.state.iter().fold(0.0f64, |m, x| m.max(x.abs()));
    let rel = |x: f64, y: f64| (x - y).abs() / x.abs().max(y.abs()).max(1e-300);
    let mut worst = a
        .state
        .iter()
        .zip(&b.state)
        .map(|(x, y)| (x - y).abs() / scale)
        .fold(0.0, f64::max);
    for (x, y) in a.gali.iter().flatten().zip(b.gali.iter().flatten()) {
        worst = worst.max(std::f64::consts::LN_10 * (x - y).abs());
    }
    for (x, y) in a.sali.iter().zip(&b.sali).chain(a.mle.iter().zip(&b.mle)) {
        worst = worst.max(rel(*x, *y));
    }
    let bits = |f: &Final| -> Vec<u64> {
        f.state
            .iter()
            .chain(f.gali.iter().flatten())
            .chain(&f.sali)
            .chain(&f.mle)
            .map(|v| v.to_bits())
            .collect()
    };
    (worst, bits(a) == bits(b))
}

fn with_model(mut config: RunConfig, model: ModelConfig) -> RunConfig {
    config.model = model;
    config
}

fn hh_expression() -> ModelConfig {
    ModelConfig::potential(2, HH_POTENTIAL)
}

#[test]
fn henon_heiles_as_an_expression_matches_the_built_in_model() {
    // Regular orbit to t = 1000, chaotic to t = 200. A last-bit difference in the
    // forces would grow linearly on the regular orbit and like exp(l1 t) ~ e^(0.05 * 200) ~ 2e4
    // on the chaotic one: 1e-9 relative leaves room for either. What we get is stated below.
    for (q2, t_final) in [
        (paper::HH_REGULAR_Q2, 1000.0),
        (paper::HH_CHAOTIC_Q2, 200.0),
    ] {
        let builtin =
            paper::henon_heiles(q2, t_final, DeviationsConfig::random(4, 2, 5), vm_and_mpm());
        let expression = with_model(builtin.clone(), hh_expression());
        let a = final_indicators(RunSpec::from_config(&builtin).unwrap());
        let b = final_indicators(RunSpec::from_config(&expression).unwrap());
        let (worst, identical) = compare(&a, &b);
        eprintln!(
            "HH x2 = {q2}, t = {t_final}: largest relative difference {worst:.2e}, bit-identical: {identical}"
        );
        assert!(worst <= 1e-9, "x2 = {q2}: {worst:e}");
    }
}

/// The paper's FPUT-beta N = 5 regular orbit, or a low-amplitude lowest mode for other N.
fn fput_orbit(n: usize) -> (Vec<f64>, Vec<f64>) {
    if n == 5 {
        return (
            paper::FPUT_N5_REGULAR_Q.to_vec(),
            paper::FPUT_N5_REGULAR_P.to_vec(),
        );
    }
    let q = (1..=n)
        .map(|i| 0.5 * (std::f64::consts::PI * i as f64 / (n + 1) as f64).sin())
        .collect();
    (q, vec![0.0; n])
}

fn fput_expression(n: usize) -> ModelConfig {
    let mut m = potential(n, FPUT_POTENTIAL);
    m.params.insert("beta".into(), ParamValue::Scalar(1.0));
    ModelConfig::Potential(m)
}

/// `[model] name = "potential"` with `V = source` on `n` sites.
fn potential(n: usize, source: &str) -> PotentialConfig {
    PotentialConfig {
        n: Some(n),
        potential: Some(source.into()),
        ..PotentialConfig::default()
    }
}

#[test]
fn fput_chain_as_a_lattice_sum_matches_the_built_in_chain() {
    // N = 101, a regular low-energy orbit (the lowest normal mode), t = 200.
    let n = 101;
    let (q, p) = fput_orbit(n);
    let builtin = paper::fput_beta(
        &q,
        &p,
        0.02,
        200.0,
        DeviationsConfig::random(4, 2, 9),
        vm_and_mpm(),
    );
    let expression = with_model(builtin.clone(), fput_expression(n));
    let a = final_indicators(RunSpec::from_config(&builtin).unwrap());
    let b = final_indicators(RunSpec::from_config(&expression).unwrap());
    let (worst, identical) = compare(&a, &b);
    eprintln!(
        "FPUT N = {n}, t = 200: largest relative difference {worst:.2e}, bit-identical: {identical}"
    );
    assert!(worst <= 1e-9, "{worst:e}");
}

#[test]
fn fput_lattice_sum_as_a_loop_gives_the_built_in_chain_bits_for_mpm_and_rounding_for_vm() {
    // N = 300 (the sum a loop over its term), the lowest normal mode at
    // amplitude 0.5 (a regular orbit), t = 100. The loop's forces are the built-in
    // `f(r_{i-1}) - f(r_i)` with f(r) = r + r^3 (beta = 1), bit for bit, so the reference orbit
    // and the MPM scheme (nearby orbits: forces only) must be the built-in's bits. The
    // Hessian-vector product is the bond's `(1 + 3 (r r)) dr` against the built-in's
    // `(1 + (3 beta r) r) dr`: a rounding apart per stiffness, which a regular orbit's tangent
    // map carries with linear growth (~ t / h = 5000 steps of 1e-16 roundings, relative): the
    // VM indicators agree to far better than 1e-9 (the value found is printed).
    let n = 300;
    let (q, p) = fput_orbit(n);
    let schemes = vec![
        SchemeConfig::new("mpm", "mpm", 1e-8, 1.0),
        SchemeConfig::new("vm", "vm", 1e-8, 1.0),
    ];
    let builtin = paper::fput_beta(
        &q,
        &p,
        0.02,
        100.0,
        DeviationsConfig::random(3, 2, 4),
        schemes,
    );
    let expression = with_model(builtin.clone(), fput_expression(n));
    let spec = RunSpec::from_config(&expression).unwrap();
    let model = spec.system().separable().unwrap().model().clone();
    let any: &dyn std::any::Any = model.as_ref();
    let compiled = any
        .downcast_ref::<chaoscope_dynamics::model::ExpressionModel>()
        .unwrap();
    assert!(compiled.has_loops(), "the lattice sum is a loop");
    let a = final_indicators(RunSpec::from_config(&builtin).unwrap());
    let b = final_indicators(spec);
    let bits = |x: &[f64]| x.iter().map(|v| v.to_bits()).collect::<Vec<_>>();
    assert_eq!(bits(&a.state), bits(&b.state), "the reference orbit");
    // (scheme, set) order: the two MPM sets first.
    for set in 0..2 {
        assert_eq!(
            bits(&a.gali[set]),
            bits(&b.gali[set]),
            "MPM GALI, set {set}"
        );
        assert_eq!(a.sali[set].to_bits(), b.sali[set].to_bits(), "MPM SALI");
        assert_eq!(a.mle[set].to_bits(), b.mle[set].to_bits(), "MPM MLE");
    }
    let (worst, identical) = compare(&a, &b);
    eprintln!(
        "FPUT N = {n} as a loop, t = 100: MPM bit-identical; VM largest relative difference \
         {worst:.2e} (all bits equal: {identical})"
    );
    assert!(worst <= 1e-9, "{worst:e}");
}

#[test]
fn fput_chain_of_1001_sites_compiles_quickly() {
    // Compile time for N = 1001 (the timing itself is reported, and measured again
    // by `chaoscope bench`; here only that it builds and agrees with the built-in forces).
    let n = 1001;
    let (model, _) = chaoscope_dynamics::spec::model_from_config(&fput_expression(n)).unwrap();
    let builtin = FputBeta::new(n, 1.0).unwrap();
    let any: &dyn std::any::Any = model.as_ref();
    let compiled = any
        .downcast_ref::<chaoscope_dynamics::model::ExpressionModel>()
        .unwrap();
    eprintln!(
        "FPUT N = 1001: {} graph nodes, parse + differentiate + compile {:.3} s",
        compiled.graph_nodes(),
        compiled.build_time().as_secs_f64()
    );
    assert!(compiled.has_loops());
    let q: Vec<f64> = (0..n).map(|i| 0.3 * (i as f64 * 0.7).sin()).collect();
    let (mut g1, mut g2) = (vec![0.0; n], vec![0.0; n]);
    model.gradient(&q, At::T0, &mut g1);
    builtin.gradient(&q, At::T0, &mut g2);
    let differ: Vec<usize> = (0..n)
        .filter(|&i| g1[i].to_bits() != g2[i].to_bits())
        .collect();
    eprintln!(
        "sites whose force differs in bits: {} {:?}",
        differ.len(),
        &differ[..differ.len().min(10)]
    );
    for i in 0..n {
        assert!(
            (g1[i] - g2[i]).abs() <= 1e-14 * (1.0 + g2[i].abs()),
            "site {i}: {} vs {}",
            g1[i],
            g2[i]
        );
    }
}

#[test]
fn toda_lattice_gali_follows_the_torus_laws() {
    // The periodic Toda lattice is integrable: an orbit lies on an N-torus, so
    // GALI_k tends to a constant for k <= N and decays as t^-2(k-N) for k > N. N = 3 keeps
    // the test fast. The laws are asymptotic: the deviation vectors need many periods to
    // align with the torus (the frequencies here are O(1), periods ~ 5), so the slopes are
    // fitted over the last decade [1e3, 1e4].
    let text = std::fs::read_to_string(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../examples/models/toda.toml"
    ))
    .unwrap();
    let config = RunConfig::from_toml(&text).unwrap();
    let rec = common::run(&config);
    let vm = rec.scheme("vm");
    let n = 3;
    let window: Vec<&common::Point> = vm.iter().filter(|p| p.t >= 1e3).collect();
    let x: Vec<f64> = window.iter().map(|p| p.t.log10()).collect();
    for k in 2..=2 * n {
        let y: Vec<f64> = window.iter().map(|p| p.mean_log_gali(k)).collect();
        let slope = common::slope(&x, &y);
        let expected = if k <= n { 0.0 } else { -2.0 * (k - n) as f64 };
        eprintln!("Toda N = 3: GALI_{k} slope over [1e3, 1e4] = {slope:.3} (law {expected})");
        assert!((slope - expected).abs() <= 0.25, "GALI_{k}: {slope}");
    }
    // Energy conserved by the symplectic scheme (bounded error, no drift).
    let worst = vm.iter().map(|p| p.energy_error).fold(0.0, f64::max);
    assert!(worst < 1e-8, "energy error {worst:e}");
}

/// The FPUT bond `r^2/2 + r^4/4` sampled every `dx` on [-3, 3] into a CSV file.
fn write_fput_bond(dir: &std::path::Path, dx: f64) -> std::path::PathBuf {
    let n = (6.0 / dx).round() as usize;
    let mut text = String::from("r,U\n");
    for j in 0..=n {
        let r = -3.0 + j as f64 * dx;
        text.push_str(&format!("{r:e},{:e}\n", r * r / 2.0 + r.powi(4) / 4.0));
    }
    let path = dir.join("bond.csv");
    std::fs::write(&path, text).unwrap();
    path
}

#[test]
fn tabulated_bond_reproduces_the_analytic_chain() {
    // A clamped cubic spline s through samples of
    // U(r) = r^2/2 + r^4/4 at spacing dx has (Hall & Meyer 1976), with max|U''''| = 6:
    //   |U - s| <= 5/384 * 6 dx^4, |U' - s'| <= 1/24 * 6 dx^3, |U'' - s''| <= 3/8 * 6 dx^2,
    // i.e. 7.8e-14, 2.5e-10 and 2.25e-6 for dx = 1e-3. The orbit feels the force error:
    // on a regular orbit it shifts the state by ~ |dU'| t^2 at worst, 2.5e-4 at t = 1000 (in
    // practice far less: the error averages over the torus). The deviation vectors (VM through
    // the Hessian, MPM through force differences over d0) feel the Hessian error: each vector's
    // direction drifts by at most ~ t |dU''| = 2.25e-3 relative, and GALI_k, a product of k
    // singular values of k such vectors, by k times that in ln: |d ln GALI_k| <= 4 * 2.25e-3,
    // i.e. 3.9e-3 in log10 for k = 4. The MLE estimate ln(stretch)/t moves by ~ |dU''| (the
    // stretching rate's error), 2.25e-6.
    let dir = tempfile::tempdir().unwrap();
    let csv = write_fput_bond(dir.path(), 1e-3);
    let analytic = paper::fput_beta(
        &paper::FPUT_N5_REGULAR_Q,
        &paper::FPUT_N5_REGULAR_P,
        0.01,
        1000.0,
        DeviationsConfig::random(4, 2, 1),
        vm_and_mpm(),
    );
    let mut model = potential(5, "sum(i = 0..N, U(q[i+1] - q[i]))");
    model.tables.insert(
        "U".into(),
        TableConfig::Detailed(TableSpec {
            file: csv.to_string_lossy().into_owned(),
            spline: Some("clamped".into()),
            slopes: Some([-30.0, 30.0]),
            sha256: None,
        }),
    );
    let tabulated = with_model(analytic.clone(), ModelConfig::Potential(model));
    let a = final_indicators(RunSpec::from_config(&analytic).unwrap());
    let b = final_indicators(RunSpec::from_config(&tabulated).unwrap());
    let state = common::max_difference(&a.state, &b.state);
    let gali = a
        .gali
        .iter()
        .flatten()
        .zip(b.gali.iter().flatten())
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f64::max);
    let mle = a
        .mle
        .iter()
        .zip(&b.mle)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f64::max);
    eprintln!(
        "tabulated vs analytic FPUT N = 5 at t = 1000: |dx| {state:.2e}, |d log10 GALI| {gali:.2e}, |d MLE| {mle:.2e}"
    );
    assert!(state < 2.5e-4, "{state:e}");
    assert!(gali < 3.9e-3, "{gali:e}");
    assert!(mle < 2.25e-6, "{mle:e}");
}

#[test]
fn non_smooth_potential_is_refused_for_vm_naming_the_operation() {
    let mut config = paper::henon_heiles(
        paper::HH_CHAOTIC_Q2,
        10.0,
        DeviationsConfig::random(2, 1, 1),
        vm_and_mpm(),
    );
    config.model = ModelConfig::potential(2, "(q1^2 + q2^2)/2 + abs(q1)*q2^2");
    let err = RunSpec::from_config(&config).unwrap_err();
    eprintln!("{err}");
    assert_eq!(err.key, "scheme[0].method");
    assert!(err.message.contains("'abs'"), "{err}");
    assert!(err.message.contains("column 19"), "{err}");
    // MPM runs it.
    config.schemes.remove(0);
    let spec = RunSpec::from_config(&config).unwrap();
    Engine::new(spec).run(|_| {}).unwrap();
}

#[test]
fn hertz_contact_allows_vm() {
    // max(0, d)^(5/2): a kink at zero raised to 5/2 has continuous second derivatives.
    let text = std::fs::read_to_string(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../examples/models/hertz-chain.toml"
    ))
    .unwrap();
    let mut config = RunConfig::from_toml(&text).unwrap();
    config.integrator.t_final = 10.0;
    config.sweeps.clear();
    RunSpec::from_config(&config).expect("vm is allowed for the Hertz chain");
}

#[test]
fn bad_expressions_name_line_and_column() {
    let cases: [(&str, &str); 6] = [
        ("q1^2 + sinn(q2)", "column 8"),
        ("q1^2 + r", "unknown"),
        ("max(q1)", "max"),
        ("q1 + (q2", "column"),
        ("q1 +\n  q3", "line 2"),
        ("beta*q1^2 + q2^2", "beta"),
    ];
    for (potential, needle) in cases {
        let mut config = paper::henon_heiles(
            paper::HH_CHAOTIC_Q2,
            10.0,
            DeviationsConfig::random(2, 1, 1),
            vm_and_mpm(),
        );
        config.model = ModelConfig::potential(2, potential);
        let err = RunSpec::from_config(&config).unwrap_err();
        eprintln!("{err}");
        assert_eq!(err.key, "model.potential", "{potential}: {err}");
        assert!(err.message.contains(needle), "{potential}: {err}");
        assert!(
            err.message.contains('^'),
            "{potential}: a caret under the place: {err}"
        );
    }
}

#[test]
fn nan_at_run_time_names_the_time_and_the_operation() {
    // log(1 + q2) is fine until q2 reaches -1: this orbit at H = 0.125 does not, but one
    // started at q2 = -0.9 with momentum towards -1 does.
    let mut config = paper::henon_heiles(
        -0.9,
        50.0,
        DeviationsConfig::random(2, 1, 1),
        vec![SchemeConfig::new("mpm", "mpm", 1e-8, 1.0)],
    );
    config.model = ModelConfig::potential(2, "(q1^2 + q2^2)/2 + log(1 + q2)");
    config.orbit.energy = None;
    config.orbit.solve_for = None;
    config.orbit.p = vec![0.0, -1.0];
    let spec = RunSpec::from_config(&config).unwrap();
    let err = Engine::new(spec).run(|_| {}).unwrap_err();
    eprintln!("{err}");
    assert!(matches!(err, RunError::Escaped { .. }), "{err}");
    let text = err.to_string();
    assert!(text.contains("t = "), "{text}");
    assert!(text.contains("'log'") || text.contains("'/'"), "{text}");
}

#[test]
fn bad_parameters_and_tables_name_their_key() {
    let base = || {
        paper::henon_heiles(
            paper::HH_CHAOTIC_Q2,
            10.0,
            DeviationsConfig::random(2, 1, 1),
            vm_and_mpm(),
        )
    };
    let dir = tempfile::tempdir().unwrap();
    let unsorted = dir.path().join("unsorted.csv");
    std::fs::write(&unsorted, "x,U\n0,0\n1,1\n0.5,2\n2,3\n3,4\n").unwrap();
    let non_finite = dir.path().join("nan.csv");
    std::fs::write(&non_finite, "x,U\n0,0\n1,nan\n2,3\n3,4\n").unwrap();
    type Spoil = Box<dyn Fn(&mut PotentialConfig)>;
    let table = |path: std::path::PathBuf| -> Spoil {
        Box::new(move |m: &mut PotentialConfig| {
            m.potential = Some("U(q1) + q2^2".into());
            m.tables.insert(
                "U".into(),
                TableConfig::File(path.to_string_lossy().into_owned()),
            );
        })
    };
    let cases: Vec<(Spoil, &str, &str)> = vec![
        (
            Box::new(|m| {
                m.potential = Some("sum(i = 1..N, k[i]*q[i]^2)".into());
                m.params
                    .insert("k".into(), ParamValue::Array(vec![1.0, 2.0, 3.0]));
            }),
            "model.params.k",
            "3 entries",
        ),
        (
            Box::new(|m| {
                m.params.insert("beta".into(), ParamValue::Scalar(f64::NAN));
            }),
            "model.params.beta",
            "finite",
        ),
        (
            Box::new(|m| m.masses = Some(ParamValue::Array(vec![1.0, -1.0]))),
            "model.masses",
            "positive",
        ),
        (
            Box::new(|m| m.boundary = Some("circular".into())),
            "model.boundary",
            "circular",
        ),
        (
            table(dir.path().join("missing.csv")),
            "model.tables.U",
            "missing.csv",
        ),
        (table(unsorted), "model.tables.U", "line 4"),
        (table(non_finite), "model.tables.U", "line 3"),
    ];
    for (spoil, key, needle) in cases {
        let mut config = base();
        let mut model = potential(2, HH_POTENTIAL);
        spoil(&mut model);
        config.model = ModelConfig::Potential(model);
        let err = RunSpec::from_config(&config).unwrap_err();
        eprintln!("{err}");
        assert_eq!(err.key, key, "{err}");
        assert!(err.message.contains(needle), "{err}");
    }
}

#[test]
fn every_example_model_validates_and_runs() {
    // Each config under examples/models/ as a user would run it, shortened to a few samples.
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../examples/models");
    let mut seen = 0;
    for entry in std::fs::read_dir(&dir).unwrap() {
        let path = entry.unwrap().path();
        if path.extension().is_none_or(|e| e != "toml") {
            continue;
        }
        let text = std::fs::read_to_string(&path).unwrap();
        let mut config = RunConfig::from_file_text(&text, &path).unwrap();
        let tau = config.schemes[0].tau;
        config.integrator.t_final = 3.0 * tau;
        config.sweeps.clear();
        let spec =
            RunSpec::from_config(&config).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
        Engine::new(spec)
            .run(|_| {})
            .unwrap_or_else(|e| panic!("{}: {e}", path.display()));
        seen += 1;
    }
    assert!(seen >= 6, "{seen} example models");
}

/// The disordered Klein-Gordon chain of `examples/models`, shortened to `t_final`, with
/// `[orbit]` and `params` as given.
fn dkg(orbit: &str, eps: &str, t_final: f64) -> RunConfig {
    RunConfig::from_toml(&format!(
        "[model]\nname = \"potential\"\nn = 40\nboundary = \"fixed\"\n\
         params = {{ W = 4.0, eps = {eps} }}\n\
         potential = \"sum(i = 1..N, eps[i]/2*q[i]^2 + q[i]^4/4) + sum(i = 0..N, \
         (q[i+1] - q[i])^2/(2*W))\"\n\
         [orbit]\n{orbit}\n[integrator]\nmethod = \"aba864\"\nh = 0.05\nt_final = {t_final}\n\
         [deviations]\nk = 2\nseed = 1\n\
         [[scheme]]\nname = \"vm\"\nmethod = \"vm\"\nd0 = 1e-8\ntau = 1.0\n\
         [[scheme]]\nname = \"mpm\"\nmethod = \"mpm\"\nd0 = 1e-8\ntau = 1.0\n"
    ))
    .expect("the DKG config parses")
}

/// A drawn disorder is the array it stands for: the same run, bit for bit, as the drawn
/// values written out (they are uniform in [1/2, 3/2], another seed another array).
#[test]
fn drawn_disorder_runs_as_the_written_out_array() {
    let orbit = "excite = { sites = 20, energy = 0.4 }";
    let drawn = dkg(orbit, "{ uniform = [0.5, 1.5], seed = 11 }", 20.0);
    let spec = RunSpec::from_config(&drawn).expect("valid");
    // The values the spec drew, read back through a config that writes them out.
    let values = chaoscope_dynamics::spec::drawn::uniform(0.5, 1.5, 11, 40);
    assert!(values.iter().all(|e| (0.5..1.5).contains(e)));
    assert_ne!(
        values,
        chaoscope_dynamics::spec::drawn::uniform(0.5, 1.5, 12, 40)
    );
    let written: Vec<String> = values.iter().map(|v| format!("{v:?}")).collect();
    let explicit = dkg(orbit, &format!("[{}]", written.join(", ")), 20.0);
    let a = final_indicators(spec);
    let b = final_indicators(RunSpec::from_config(&explicit).expect("valid"));
    assert_eq!(
        a, b,
        "a drawn array and its values written out run differently"
    );
    assert!(a.mle.iter().all(|m| m.is_finite()));
}

/// `excite`: q = 0, the excited momenta share the energy (`p = sqrt(2 E / L)`, signs from the
/// seed), so `H = E` to rounding since `V(0) = 0` for this chain.
#[test]
fn single_site_and_block_excitations_carry_their_energy() {
    let eps = "{ uniform = [0.5, 1.5], seed = 1 }";
    let single = RunSpec::from_config(&dkg("excite = { sites = 20, energy = 0.4 }", eps, 1.0))
        .expect("valid");
    let x = single.x0();
    assert!(x[..40].iter().all(|&q| q == 0.0));
    let excited: Vec<usize> = (0..40).filter(|&l| x[40 + l] != 0.0).collect();
    assert_eq!(excited, [19]);
    assert_eq!(x[40 + 19], 0.8f64.sqrt());
    let energy = single.system().invariant(x).expect("energy");
    assert!((energy - 0.4).abs() <= 1e-15, "H = {energy}");

    let block = RunSpec::from_config(&dkg(
        "excite = { sites = [15, 25], energy = 4.125, seed = 3 }",
        eps,
        1.0,
    ))
    .expect("valid");
    let x = block.x0();
    let p: Vec<f64> = x[40..].to_vec();
    let per_site = (2.0f64 * 4.125 / 11.0).sqrt();
    for (l, &pl) in p.iter().enumerate() {
        if (14..25).contains(&l) {
            assert_eq!(pl.abs(), per_site, "site {}", l + 1);
        } else {
            assert_eq!(pl, 0.0, "site {}", l + 1);
        }
    }
    // Random signs: both occur (11 fair coins all alike has probability 2^-10; seed 3 is pinned).
    assert!(p.iter().any(|&v| v > 0.0) && p.iter().any(|&v| v < 0.0));
    let energy = block.system().invariant(x).expect("energy");
    // Eleven terms of size 0.375 summed: a few ulps of 4.125.
    assert!(
        (energy - 4.125).abs() <= 8.0 * f64::EPSILON * 4.125,
        "H = {energy}"
    );
}

#[test]
fn bad_excitations_and_draws_are_named() {
    let eps = "{ uniform = [0.5, 1.5], seed = 1 }";
    let refused = |orbit: &str, eps: &str| -> String {
        match RunSpec::from_config(&dkg(orbit, eps, 1.0)) {
            Ok(_) => panic!("{orbit} / {eps} was accepted"),
            Err(e) => format!("{}: {}", e.key, e.message),
        }
    };
    let e = refused("excite = { sites = 41, energy = 0.4 }", eps);
    assert!(
        e.starts_with("orbit.excite.sites") && e.contains("<= 40"),
        "{e}"
    );
    let e = refused("excite = { sites = [25, 15], energy = 0.4 }", eps);
    assert!(e.starts_with("orbit.excite.sites"), "{e}");
    let e = refused("excite = { sites = 0, energy = 0.4 }", eps);
    assert!(e.starts_with("orbit.excite.sites"), "{e}");
    let e = refused("excite = { sites = 3, energy = -1.0 }", eps);
    assert!(
        e.starts_with("orbit.excite.energy") && e.contains("positive"),
        "{e}"
    );
    let e = refused("excite = { sites = 3, energy = 0.4 }\nq = [0.0]", eps);
    assert!(
        e.starts_with("orbit.q") && e.contains("orbit.excite"),
        "{e}"
    );
    let e = refused(
        "excite = { sites = 3, energy = 0.4 }",
        "{ uniform = [1.5, 0.5], seed = 1 }",
    );
    assert!(
        e.starts_with("model.params.eps") && e.contains("lo < hi"),
        "{e}"
    );
    // A wrong shape, an unknown or a missing key of a drawn array: parse errors naming them.
    let text = include_str!("../../examples/models/dkg-single-site.toml");
    for (bad, says) in [
        (
            "seed = 1, normal = 2 }",
            "model.params.eps.normal (line 15, column 61): unknown field `normal`",
        ),
        (
            "}",
            "model.params.eps.seed (line 15, column 27): missing field `seed`",
        ),
        ("seed = 1 }", ""),
    ] {
        let spoiled = text.replace(", seed = 1 }", &format!(", {bad}"));
        let spoiled = if says.is_empty() {
            spoiled.replace("eps = { uniform", "eps = { uniforms")
        } else {
            spoiled
        };
        let e = RunConfig::from_toml(&spoiled).expect_err(bad).to_string();
        let says = if says.is_empty() {
            "unknown field `uniforms`"
        } else {
            says
        };
        assert!(e.contains(says), "{bad}: {e}");
    }
    let e = RunConfig::from_toml(
        &text.replace("eps = { uniform = [0.5, 1.5], seed = 1 }", "eps = \"x\""),
    )
    .expect_err("a string parameter")
    .to_string();
    assert!(e.contains("a number, an array of numbers"), "{e}");
}

/// The state at the end of a run of `text`.
fn final_state(text: &str) -> Vec<f64> {
    let spec = RunSpec::from_config(&RunConfig::from_toml(text).unwrap()).unwrap();
    let mut last = None;
    Engine::new(spec).run(|s| last = Some(s.state)).unwrap();
    last.unwrap()
}

fn hh_run(model: &str, method: &str, h: f64, t: f64) -> String {
    format!(
        "[model]\n{model}\n[orbit]\nq = [0.0, -0.25]\np = [0.0, 0.0]\nenergy = 0.125\n\
         solve_for = \"p1\"\n[integrator]\nmethod = \"{method}\"\nh = {h:?}\nt_final = {t:?}\n\
         [deviations]\nk = 2\nsets = 1\nseed = 1\n\
         [[scheme]]\nname = \"vm\"\nmethod = \"vm\"\nd0 = 1e-8\ntau = 1.0\n"
    )
}

/// A potential run with a Runge-Kutta method or Taylor's integrates the flow of `H = T + V`
/// from the initial state a splitting starts from (here the energy solved for `p1`): the
/// paper's chaotic Henon-Heiles orbit by `taylor` (tolerance eps) against the built-in model
/// by `s17odr8` at h = 0.002 (energy error ~1e-15) agree to 1e-9 at t = 20 (the two errors,
/// ~1e-13 each, grown by e^(0.05 t) at the orbit's MLE ~0.05 and by the orbit's shear), and
/// with unequal masses `dop853` on the potential equals `dop853` on the Hamiltonian written
/// out by hand, `p1^2/(2 m1) + p2^2/(2 m2) + V`, to rounding (1e-13 at t = 5).
#[test]
fn a_potential_runs_as_the_flow_of_its_hamiltonian() {
    let taylor = final_state(&hh_run(
        &format!("name = \"potential\"\nn = 2\npotential = \"{HH_POTENTIAL}\""),
        "taylor",
        1.0,
        20.0,
    ));
    let split = final_state(&hh_run("name = \"henon-heiles\"", "s17odr8", 0.002, 20.0));
    let diff = common::max_difference(&taylor, &split);
    assert!(diff < 1e-9, "taylor against s17odr8: {diff:e}");

    let masses = final_state(&hh_run(
        &format!(
            "name = \"potential\"\nn = 2\nmasses = [2.0, 0.5]\npotential = \"{HH_POTENTIAL}\""
        ),
        "dop853",
        0.01,
        5.0,
    ));
    let by_hand = final_state(
        &hh_run(
            &format!(
                "name = \"hamiltonian\"\nn = 2\nhamiltonian = \"{HH_POTENTIAL} + p1^2/4 + p2^2\""
            ),
            "dop853",
            0.01,
            5.0,
        )
        // The same solved initial momentum, written by hand.
        .replace("energy = 0.125\nsolve_for = \"p1\"\n", "")
        .replace("p = [0.0, 0.0]", &{
            // p1 with p1^2/(2 m1) = E - V(0, -0.25): m1 = 2.
            let v = 0.25f64.powi(2) / 2.0 + 0.25f64.powi(3) / 3.0;
            format!("p = [{:?}, 0.0]", (2.0 * 2.0 * (0.125 - v)).sqrt())
        }),
    );
    let diff = common::max_difference(&masses, &by_hand);
    assert!(diff < 1e-13, "masses: {diff:e}");
}

/// What a potential run as a flow cannot take is refused naming its key.
#[test]
fn a_potential_run_as_a_flow_refuses_what_it_cannot_do() {
    let model = format!("name = \"potential\"\nn = 2\npotential = \"{HH_POTENTIAL}\"");
    for (text, key, says) in [
        (
            hh_run(&model, "rk45", 0.01, 1.0),
            "integrator.method",
            "as the flow of its Hamiltonian: rk4, dop853, gl4, gl6, taylor",
        ),
        (
            hh_run(
                &format!("{model}\nparams = {{ _inverse_mass = 1.0 }}"),
                "gl6",
                0.01,
                1.0,
            ),
            "model.params._inverse_mass",
            "rename it",
        ),
        (
            hh_run(&model, "taylor", 1.0, 1.0).replace(
                "q = [0.0, -0.25]\np = [0.0, 0.0]\nenergy = 0.125\nsolve_for = \"p1\"",
                "x = [0.0, -0.25, 0.1, 0.0]",
            ),
            "orbit.x",
            "q and p",
        ),
        (
            hh_run(
                &format!(
                    "{model}\ntables = {{ U = \"{}/../examples/models/fput-bond.csv\" }}",
                    env!("CARGO_MANIFEST_DIR")
                ),
                "taylor",
                1.0,
                1.0,
            ),
            "integrator.method",
            "the table 'U'",
        ),
    ] {
        let cfg = RunConfig::from_toml(&text).unwrap();
        let e = RunSpec::from_config(&cfg).unwrap_err();
        assert!(e.key == key && e.to_string().contains(says), "{key}: {e}");
    }
}
