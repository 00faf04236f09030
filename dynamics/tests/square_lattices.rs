//! Two-dimensional lattices written as expressions (`lattice = "square"`, `q[i, j]`): the
//! sites and the boundary of each axis against a hand-written energy (the sums unrolled and
//! compiled as loops along the rows), the energy distribution
//! over the plane, the DDNLS written as a `hamiltonian` against the built-in square lattice,
//! block excitations, VM against MPM on a chaotic 2-D Klein-Gordon orbit, and the refusals.

use crate::common;

use chaoscope_dynamics::engine::Engine;
use chaoscope_dynamics::model::{At, ExpressionModel};
use chaoscope_dynamics::spec::{RunSpec, model_from_config};
use chaoscope_expr::potential::SQUARE_LOOPS_FROM_SIDE;
use chaoscope_schemas::config::RunConfig;

/// The 2-D disordered Klein-Gordon potential with bonds `(q[i+1, j] - q[i, j])^2 / (4W)` and
/// `(q[i, j+1] - q[i, j])^2 / (4W)`, over `i` (or `j`) from 0 to N as for fixed walls.
const DKG2: &str = r#"potential = """
  sum(i = 1..N, sum(j = 1..N, eps[i, j]/2*q[i, j]^2 + q[i, j]^4/4))
+ sum(i = 0..N, sum(j = 1..N, (q[i+1, j] - q[i, j])^2/(4*W)))
+ sum(i = 1..N, sum(j = 0..N, (q[i, j+1] - q[i, j])^2/(4*W)))""""#;

/// The 2-D DDNLS written as a `hamiltonian` (`psi = (q + i p) / sqrt(2)`, hopping to the four
/// neighbours), with `beta` and `eps` from the config's params.
const DDNLS2: &str = r#"hamiltonian = """
  sum(i = 1..N, sum(j = 1..N, eps[i, j]*(q[i, j]^2 + p[i, j]^2)/2
                              + beta/8*(q[i, j]^2 + p[i, j]^2)^2))
- sum(i = 1..N, sum(j = 1..N, q[i, j]*(q[i+1, j] + q[i, j+1]) + p[i, j]*(p[i+1, j] + p[i, j+1])))""""#;

fn parse(text: &str) -> RunConfig {
    RunConfig::from_toml(text).unwrap_or_else(|e| panic!("{e}\n{text}"))
}

/// The keys every run needs beside the model, orbit and integrator.
const ONE_VM: &str = "[deviations]\nk = 1\nsets = 1\nseed = 1\n\
                      [[scheme]]\nname = \"vm\"\nmethod = \"vm\"\nd0 = 1e-8\ntau = 1.0";

/// A `potential` on an `n x n` square with the given `boundary` value, disorder from `eps`.
fn dkg2_config(n: usize, boundary: &str, eps: &[f64], orbit: &str, rest: &str) -> RunConfig {
    let eps: Vec<String> = eps.iter().map(|e| format!("{e:?}")).collect();
    parse(&format!(
        "[model]\nname = \"potential\"\nlattice = \"square\"\nn = {n}\nboundary = {boundary}\n\
         params = {{ W = 3.0, eps = [{}] }}\n{DKG2}\n[orbit]\n{orbit}\n{rest}\n{ONE_VM}",
        eps.join(", ")
    ))
}

/// What site `k` (1-based, along one axis of `n`) means under `boundary`: the 0-based index,
/// `Some(None)` for a wall, `None` where the term does not exist (free ends).
fn along(k: i64, n: i64, boundary: &str) -> Option<Option<usize>> {
    if (1..=n).contains(&k) {
        return Some(Some((k - 1) as usize));
    }
    match boundary {
        "fixed" => Some(None),
        "periodic" => Some(Some((k - 1).rem_euclid(n) as usize)),
        _ => None,
    }
}

/// The same potential by hand: every term the expression's sums write, each site resolved
/// along its axis, a wall read as 0 and a term reaching past a free edge left out.
fn dkg2_by_hand(q: &[f64], eps: &[f64], n: usize, w: f64, bi: &str, bj: &str) -> f64 {
    let ni = n as i64;
    let value = |i: i64, j: i64| -> Option<f64> {
        let (r, c) = (along(i, ni, bi)?, along(j, ni, bj)?);
        Some(match (r, c) {
            (Some(r), Some(c)) => q[r * n + c],
            _ => 0.0,
        })
    };
    let mut v = 0.0;
    for l in 0..n * n {
        v += eps[l] / 2.0 * q[l] * q[l] + q[l].powi(4) / 4.0;
    }
    for i in 0..=ni {
        for j in 1..=ni {
            if let (Some(a), Some(b)) = (value(i + 1, j), value(i, j)) {
                v += (a - b).powi(2) / (4.0 * w);
            }
        }
    }
    for i in 1..=ni {
        for j in 0..=ni {
            if let (Some(a), Some(b)) = (value(i, j + 1), value(i, j)) {
                v += (a - b).powi(2) / (4.0 * w);
            }
        }
    }
    v
}

/// On-site frequencies `eps` in [1/2, 3/2], irregular from site to site.
fn disorder(len: usize) -> Vec<f64> {
    irregular(len, 0.5, 0.2).iter().map(|e| 1.0 + e).collect()
}

fn irregular(len: usize, scale: f64, phase: f64) -> Vec<f64> {
    (0..len)
        .map(|k| scale * ((k as f64) * 1.37 + phase).sin())
        .collect()
}

/// `q[i, j]` is site `(i - 1) N + j` and each axis follows its own boundary: for all nine
/// pairs of fixed, periodic and free, the model's potential at an irregular state equals the
/// hand-written sum to rounding (a few ulps of a sum of ~100 terms of size ~0.1). A swapped
/// axis, a wrong row length or a boundary applied to the wrong axis changes the bonds by
/// O(0.1) at this state.
#[test]
fn a_square_s_sites_and_each_axis_boundary_are_the_hand_written_ones() {
    // Unrolled below the side where sums become loops along the rows, loops from it.
    for n in [4, SQUARE_LOOPS_FROM_SIDE] {
        sites_and_boundaries_of_a_square(n);
    }
}

fn sites_and_boundaries_of_a_square(n: usize) {
    let eps = disorder(n * n);
    let q = irregular(n * n, 0.8, 1.1);
    for bi in ["fixed", "periodic", "free"] {
        for bj in ["fixed", "periodic", "free"] {
            let cfg = dkg2_config(
                n,
                &format!("[\"{bi}\", \"{bj}\"]"),
                &eps,
                "excite = { sites = 1, energy = 0.1 }",
                "[integrator]\nmethod = \"aba864\"\nh = 0.05\nt_final = 1.0",
            );
            let (model, _) = model_from_config(&cfg.model).unwrap();
            assert_eq!(model.dof(), n * n);
            // From a side of 32, compiled as loops along the rows (one per row and sum).
            let any: &dyn std::any::Any = model.as_ref();
            let compiled = any.downcast_ref::<ExpressionModel>().unwrap();
            let loops = n >= SQUARE_LOOPS_FROM_SIDE;
            assert_eq!(compiled.has_loops(), loops, "{n} x {n} [{bi}, {bj}]");
            let got = model.potential(&q, At::T0);
            let want = dkg2_by_hand(&q, &eps, n, 3.0, bi, bj);
            assert!(
                ((got - want) / want).abs() < 1e-14,
                "{n} x {n} [{bi}, {bj}]: {got} against {want}"
            );
            // The forces are the potential's: central differences, whose truncation error is
            // ~1e-12 here and whose rounding is that of two potentials of size |V| over 2e-6,
            // about 1.1e-10 |V| (|V| grows with the sites): ten times that is allowed.
            let tol = 1e-9 * (1.0 + want.abs());
            let mut g = vec![0.0; n * n];
            model.gradient(&q, At::T0, &mut g);
            for (l, &gl) in g.iter().enumerate() {
                let (mut up, mut down) = (q.clone(), q.clone());
                up[l] += 1e-6;
                down[l] -= 1e-6;
                let fd = (model.potential(&up, At::T0) - model.potential(&down, At::T0)) / 2e-6;
                assert!(
                    (fd - gl).abs() < tol,
                    "{n} x {n} [{bi}, {bj}] site {l}: {fd} against {gl}"
                );
            }
        }
    }
}

/// The energy distribution over the plane: the site energies add up to `H`, and with one
/// site displaced (momenta 0) that site holds its on-site energy and half of each of its four
/// bonds, each neighbour the other half of its bond, every other site nothing.
#[test]
fn site_energies_share_each_bond_of_the_plane_between_its_ends() {
    let n = 5;
    let eps = vec![1.0; n * n];
    let cfg = dkg2_config(
        n,
        "\"fixed\"",
        &eps,
        "excite = { sites = 1, energy = 0.1 }",
        "[integrator]\nmethod = \"aba864\"\nh = 0.05\nt_final = 1.0",
    );
    let (model, _) = model_from_config(&cfg.model).unwrap();
    let x: Vec<f64> = irregular(2 * n * n, 0.6, 0.4);
    let mut e = vec![0.0; n * n];
    model.site_energies(&x, &mut e).unwrap();
    let total: f64 = e.iter().sum();
    let h = model.energy(&x, At::T0);
    assert!(((total - h) / h).abs() < 1e-14, "{total} against {h}");

    let a = 0.7;
    let centre = n + 2; // row 2, column 3 (0-based 1, 2)
    let mut x = vec![0.0; 2 * n * n];
    x[centre] = a;
    model.site_energies(&x, &mut e).unwrap();
    let bond = a * a / (4.0 * 3.0);
    let on_site = a * a / 2.0 + a.powi(4) / 4.0;
    for (l, &got) in e.iter().enumerate() {
        let want = if l == centre {
            on_site + 4.0 * bond / 2.0
        } else if [centre - n, centre + n, centre - 1, centre + 1].contains(&l) {
            bond / 2.0
        } else {
            0.0
        };
        assert!((got - want).abs() < 1e-15, "site {l}: {got} against {want}");
    }
}

/// The DDNLS of `lattices.md` written as a `hamiltonian` on a 5 x 5 square, in real
/// coordinates, with the built-in model's disorder (the same seed draws the same
/// `eps_l` in [-W/2, W/2]) and its initial state: the same energy to rounding, and after
/// t = 2 the same state. The built-in lattice is integrated by its three-part s11abc6 at
/// h = 0.005 (error ~(7 h)^6 ~ 1e-9 per unit time at the fastest rotation ~7), the expression
/// by dop853 at the same step (error ~1e-14), so the two states agree to ~1e-8; a site read
/// from the wrong row, a missed bond or a wrong sign changes the state by O(0.1) over this
/// time. The orbit is chaotic (MLE ~0.3) but t = 2 amplifies the difference by e^0.6 only.
/// Their VM exponents, from the same seeded initial vectors, agree to 1e-5.
#[test]
fn the_ddnls_written_as_a_hamiltonian_on_a_square_is_the_built_in_lattice() {
    let common_keys = "[deviations]\nk = 2\nsets = 1\nseed = 9\n\
                       [[scheme]]\nname = \"vm\"\nmethod = \"vm\"\nd0 = 1e-8\ntau = 1.0\n";
    let builtin = parse(&format!(
        "[model]\nname = \"ddnls\"\nlattice = \"square\"\nn = 5\nW = 4.0\nbeta = 3.0\nseed = 7\n\
         [orbit]\nexcite = {{ sites = [2, 4], norm = 9.0, seed = 3 }}\n\
         [integrator]\nmethod = \"s11abc6\"\nh = 0.005\nt_final = 2.0\n{common_keys}"
    ));
    let spec = RunSpec::from_config(&builtin).unwrap();
    let x0 = spec.x0().to_vec();
    let fmt = |v: &[f64]| {
        v.iter()
            .map(|x| format!("{x:?}"))
            .collect::<Vec<_>>()
            .join(", ")
    };
    let written = parse(&format!(
        r#"[model]
name = "hamiltonian"
lattice = "square"
n = 5
boundary = "fixed"
params = {{ beta = 3.0, eps = {{ uniform = [-2.0, 2.0], seed = 7 }} }}
{DDNLS2}
[orbit]
q = [{}]
p = [{}]
[integrator]
method = "dop853"
h = 0.005
t_final = 2.0
{common_keys}"#,
        fmt(&x0[..25]),
        fmt(&x0[25..])
    ));
    let other = RunSpec::from_config(&written).unwrap();
    assert_eq!(other.x0(), &x0[..]);
    let (e1, e2) = (spec.e0(), other.e0());
    assert!(((e1 - e2) / e1).abs() < 1e-14, "energy {e1} against {e2}");
    let last = |spec: RunSpec| {
        let mut last = None;
        Engine::new(spec).run(|s| last = Some(s)).unwrap();
        last.unwrap()
    };
    let (a, b) = (last(spec), last(other));
    assert_eq!(a.t, 2.0);
    let diff = common::max_difference(&a.state, &b.state);
    assert!(diff < 1e-7, "states at t = 2 differ by {diff}");
    let (ra, rb) = (
        common::run(&builtin)
            .scheme("vm")
            .last()
            .unwrap()
            .mean_exponent(0),
        common::run(&written)
            .scheme("vm")
            .last()
            .unwrap()
            .mean_exponent(0),
    );
    assert!(((ra - rb) / ra).abs() < 1e-5, "MLE {ra} against {rb}");
}

/// `excite = { sites = [2, 3], energy = E }` on a square excites the 2 x 2 block of rows and
/// columns 2..3 (row by row: sites 7, 8, 12, 13 of 5 x 5), with the energy shared; the run
/// header says the side, so the analyzer takes distributions over the plane.
#[test]
fn a_block_excitation_is_a_square_of_rows_and_columns() {
    let n = 5;
    let cfg = dkg2_config(
        n,
        "\"periodic\"",
        &vec![1.0; n * n],
        "excite = { sites = [2, 3], energy = 0.8, seed = 5 }",
        "[integrator]\nmethod = \"aba864\"\nh = 0.05\nt_final = 1.0",
    );
    let spec = RunSpec::from_config(&cfg).unwrap();
    let p = &spec.x0()[n * n..];
    let excited: Vec<usize> = (0..n * n).filter(|&l| p[l] != 0.0).collect();
    assert_eq!(excited, [6, 7, 11, 12]);
    assert!(
        p.iter()
            .all(|v| v * v == 0.0 || (v * v - 0.4).abs() < 1e-15)
    );
    assert!((spec.e0() - 0.8).abs() < 1e-15);
    let header = chaoscope_dynamics::header::run_header("square", &cfg, &spec);
    assert_eq!(header.lattice_side, 5);
    assert_eq!(chaoscope_schemas::run::square_side(&header), Ok(Some(5)));
}

/// VM against MPM on a chaotic orbit of the 2-D Klein-Gordon lattice written as an
/// expression (the example's 21 x 21 square, its 3 x 3 block at E = 9), as the GALI paper
/// compares them: the same seeded directions give the same MLE to 1 % (one trajectory's
/// stretching, MPM's nearby orbits 1e-8 away) and, while it is above MPM's noise floor of
/// ~1e-5, the same GALI_2 to 0.1 in log10. The orbit is chaotic: GALI_2 of two vectors,
/// constant on a torus, falls below 0.1 by t = 200 (measured 10^-1.7) and the MLE (0.049)
/// stays above 1.5 ln(t)/t = 0.04, a regular orbit's bound; ABA864 at h = 0.05 keeps the
/// energy to 1e-8.
#[test]
fn vm_and_mpm_agree_on_a_chaotic_square_klein_gordon_orbit() {
    let text = std::fs::read_to_string(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../examples/models/dkg-square.toml"
    ))
    .unwrap()
    .replace("t_final = 500.0", "t_final = 200.0")
    .replace("tau = 10.0", "tau = 1.0");
    let rec = common::run(&parse(&text));
    let (vm, mpm) = (rec.scheme("vm"), rec.scheme("mpm"));
    let mut worst: f64 = 0.0;
    for (a, b) in vm.iter().zip(mpm) {
        if a.mean_log_gali(2) > -4.0 {
            worst = worst.max((a.mean_log_gali(2) - b.mean_log_gali(2)).abs());
        }
    }
    let (l_vm, l_mpm) = (
        vm.last().unwrap().mean_exponent(0),
        mpm.last().unwrap().mean_exponent(0),
    );
    eprintln!(
        "MLE VM {l_vm:.5} MPM {l_mpm:.5}, log10 GALI_2 {:.2}, worst {worst:.2e}, energy {:.1e}",
        vm.last().unwrap().mean_log_gali(2),
        vm.last().unwrap().energy_error
    );
    assert!(
        ((l_mpm - l_vm) / l_vm).abs() < 0.01,
        "MLE {l_vm} vs {l_mpm}"
    );
    assert!(worst < 0.1, "GALI_2 of MPM and VM differ by {worst}");
    assert!(
        l_vm > 1.5 * 200f64.ln() / 200.0,
        "MLE {l_vm} is not chaotic"
    );
    assert!(
        vm.last().unwrap().mean_log_gali(2) < -1.0,
        "GALI_2 did not fall"
    );
    assert!(vm.last().unwrap().energy_error < 1e-8);
}

/// Each mistake in a square lattice's configuration is refused naming its key.
#[test]
fn square_lattice_configs_are_refused_naming_the_key() {
    let base = |model_extra: &str, potential: &str| {
        format!(
            "[model]\nname = \"potential\"\nn = 4\n{model_extra}\npotential = \"{potential}\"\n\
             [orbit]\nexcite = {{ sites = 1, energy = 0.1 }}\n\
             [integrator]\nmethod = \"aba864\"\nh = 0.05\nt_final = 1.0\n{ONE_VM}"
        )
    };
    let sq = "sum(i = 1..N, sum(j = 1..N, q[i, j]^2))";
    for (model_extra, potential, key, says) in [
        (
            "lattice = \"hexagonal\"",
            sq,
            "model.lattice",
            "not chain or square",
        ),
        (
            "lattice = \"square\"\nboundary = [\"fixed\"]",
            sq,
            "model.boundary",
            "two axes",
        ),
        (
            "boundary = [\"fixed\", \"free\"]",
            "q1^2",
            "model.boundary",
            "is for lattice = \"square\"",
        ),
        (
            "lattice = \"square\"\nboundary = [\"fixed\", \"open\"]",
            sq,
            "model.boundary",
            "open",
        ),
        ("", sq, "model.potential", "square lattice"),
        (
            "lattice = \"square\"",
            "sum(i = 0..N, q[i]^2)",
            "model.potential",
            "single index",
        ),
        (
            "lattice = \"square\"\nparams = { e = [1.0, 2.0] }",
            "e[1, 1]*q1^2",
            "model.params.e",
            "the 4 x 4 lattice has 16 sites",
        ),
    ] {
        let text = base(model_extra, potential);
        let cfg = RunConfig::from_toml(&text).unwrap();
        let err = RunSpec::from_config(&cfg).unwrap_err().to_string();
        assert!(
            err.contains(key) && err.contains(says),
            "{model_extra} / {potential}: {err}"
        );
    }
    // A side of 0, and one whose square exceeds the site limit.
    let text = base("lattice = \"square\"", sq).replace("n = 4", "n = 0");
    let err = RunSpec::from_config(&RunConfig::from_toml(&text).unwrap())
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("model.n") && err.contains("at least 1"),
        "{err}"
    );
    let text = base("lattice = \"square\"", sq).replace("n = 4", "n = 400");
    let err = RunSpec::from_config(&RunConfig::from_toml(&text).unwrap())
        .unwrap_err()
        .to_string();
    assert!(err.contains("160000 sites"), "{err}");
}

/// The energy distribution of Hamiltonians integrated as flows of expressions. A potential run
/// by Taylor's method has, at its initial state, the site energies its splitting run has (the
/// kinetic sum's terms each on its own site beside `V`'s terms), to rounding. The 2-D DDNLS
/// written as a `hamiltonian` has site energies that add up to `H`, and with one site excited
/// all of `H` is on that site (its hopping terms read zeros).
#[test]
fn hamiltonians_integrated_as_flows_have_site_energies() {
    let n = 5;
    let eps = disorder(n * n);
    let split = dkg2_config(
        n,
        "[\"fixed\", \"periodic\"]",
        &eps,
        "excite = { sites = [2, 4], energy = 2.0, seed = 3 }",
        "[integrator]\nmethod = \"aba864\"\nh = 0.05\nt_final = 1.0",
    );
    let mut flow = split.clone();
    flow.integrator.method = "taylor".into();
    flow.integrator.h = Some(0.05);
    let (a, b) = (
        RunSpec::from_config(&split).unwrap(),
        RunSpec::from_config(&flow).unwrap(),
    );
    assert_eq!(a.x0(), b.x0());
    let x: Vec<f64> = irregular(2 * n * n, 0.6, 0.4);
    let (mut ea, mut eb) = (vec![0.0; n * n], vec![0.0; n * n]);
    a.system().site_energies(&x, &mut ea).unwrap();
    b.system().site_energies(&x, &mut eb).unwrap();
    assert!(
        common::max_difference(&ea, &eb) < 1e-15,
        "{ea:?} against {eb:?}"
    );

    let ddnls = parse(&format!(
        r#"[model]
name = "hamiltonian"
lattice = "square"
n = {n}
params = {{ beta = 3.0, eps = {{ uniform = [-2.0, 2.0], seed = 7 }} }}
{DDNLS2}
[orbit]
q = [{q}]
p = [{p}]
[integrator]
method = "taylor"
h = 1.0
t_final = 1.0
{ONE_VM}"#,
        q = vec!["0.3"; n * n].join(", "),
        p = vec!["-0.2"; n * n].join(", "),
    ));
    let spec = RunSpec::from_config(&ddnls).unwrap();
    let mut e = vec![0.0; n * n];
    spec.system().site_energies(spec.x0(), &mut e).unwrap();
    let total: f64 = e.iter().sum();
    assert!(
        ((total - spec.e0()) / spec.e0()).abs() < 1e-14,
        "{total} against {}",
        spec.e0()
    );
    let mut one = vec![0.0; 2 * n * n];
    (one[7], one[n * n + 7]) = (0.5, 0.3);
    spec.system().site_energies(&one, &mut e).unwrap();
    let h = spec.system().invariant(&one).unwrap();
    for (l, &el) in e.iter().enumerate() {
        let want = if l == 7 { h } else { 0.0 };
        assert!((el - want).abs() < 1e-15, "site {l}: {el} against {want}");
    }
}
