//! The compiled splitting step kernels against a plain Rust loop over the reference evaluator:
//! drift `q += (ch w) p`, force from `eval`, kick `p -= dh g`, lane by lane, bit for bit, for
//! Henon-Heiles and FPUT chains, several lane counts (whole blocks, a remainder, one lane, a
//! stride wider than the lanes), with and without masses, both block widths; and the same for
//! the C kernels the system C compiler builds (every operation of the language, tables, the
//! cache, compiler failures).

use std::collections::BTreeMap;

use std::sync::Arc;

use chaoscope_expr::graph::Tabulated;
use chaoscope_expr::jit::{self, CCompiler, Options, StepBackend, StepKernels, StepSpec};
use chaoscope_expr::lattice::{LatticeEvaluator, LatticePotential};
use chaoscope_expr::lower::{Boundary, Family, ParamValue, Scope, Shape, lower_with_loops};
use chaoscope_expr::table::{Spline, SplineEnds};
use chaoscope_expr::{Evaluator, Graph, NodeId, diff, lower};

/// Any fixed 8-drift / 7-kick splitting (symmetric, like ABA864), times a step of 0.01.
const DRIFT: [f64; 8] = [
    0.0711, 0.2411, 0.0933, 0.0945, 0.0945, 0.0933, 0.2411, 0.0711,
];
const KICK: [f64; 7] = [0.1839, 0.1212, 0.1737, 0.0424, 0.1737, 0.1212, 0.1839];
const H: f64 = 0.01;

struct System {
    n: usize,
    graph: Graph,
    gradient: Vec<NodeId>,
    hessian_vector: Vec<NodeId>,
    /// The potential's lattice sums as loops (then `gradient` and `hessian_vector` are empty).
    lattice: Option<LatticePotential>,
}

impl System {
    fn gradient(&self, ev: &mut Evaluator, q: &[f64], g: &mut [f64]) {
        match &self.lattice {
            Some(l) => LatticeEvaluator::new(&self.graph, l).gradient(q, g),
            None => ev.eval(&self.graph, &[q], &self.gradient, g),
        }
    }

    fn hessian_vector(&self, ev: &mut Evaluator, q: &[f64], v: &[f64], h: &mut [f64]) {
        match &self.lattice {
            Some(l) => LatticeEvaluator::new(&self.graph, l).hessian_vector(q, v, h),
            None => ev.eval(&self.graph, &[q, v], &self.hessian_vector, h),
        }
    }
}

fn system(n: usize, potential: &str) -> System {
    system_with_tables(n, potential, &[])
}

fn system_with_tables(n: usize, potential: &str, tables: &[(&str, Arc<dyn Tabulated>)]) -> System {
    let mut graph = Graph::new();
    let tables: Vec<(String, u32)> = tables
        .iter()
        .map(|(name, t)| (name.to_string(), graph.add_table(t.clone())))
        .collect();
    let mut params = BTreeMap::new();
    params.insert("beta".to_string(), ParamValue::Scalar(1.0));
    let families = [Family {
        name: "q".into(),
        len: n,
        arg: 0,
        offset: 0,
    }];
    let scope = Scope {
        families: &families,
        params: &params,
        tables: &tables,
        n,
        boundary: Boundary::Fixed,
        shape: chaoscope_expr::lower::Shape::Chain,
        time: None,
    };
    let root = lower(potential, &scope, &mut graph).unwrap().root;
    let gradient = diff::gradient(&mut graph, root, 0, n).unwrap();
    let hessian_vector = diff::jacobian_vector(&mut graph, &gradient, 0, 1).unwrap();
    System {
        n,
        graph,
        gradient,
        hessian_vector,
        lattice: None,
    }
}

/// A potential whose lattice sums are loops, with the array parameter `k` (one per site), the
/// table `U` (a cubic on [-4, 4]) and `beta`.
fn lattice_system(n: usize, boundary: Boundary, potential: &str) -> System {
    lattice_system_shaped(n, boundary, Shape::Chain, potential)
}

/// [`lattice_system`] on a lattice of any shape (`n` its `N`: a square's side).
fn lattice_system_shaped(side: usize, boundary: Boundary, shape: Shape, potential: &str) -> System {
    let n = shape.sites(side).unwrap();
    let mut graph = Graph::new();
    let xs: Vec<f64> = (0..81).map(|i| -4.0 + 0.1 * i as f64).collect();
    let ys: Vec<f64> = xs.iter().map(|x| x * x / 2.0 + x * x * x / 10.0).collect();
    let u: Arc<dyn Tabulated> = Arc::new(Spline::new("U", &xs, &ys, SplineEnds::Natural).unwrap());
    let tables = vec![("U".to_string(), graph.add_table(u))];
    let mut params = BTreeMap::new();
    params.insert("beta".to_string(), ParamValue::Scalar(1.0));
    params.insert(
        "k".to_string(),
        ParamValue::Array((0..n).map(|j| 0.5 + 0.07 * (j % 13) as f64).collect()),
    );
    let families = [Family {
        name: "q".into(),
        len: n,
        arg: 0,
        offset: 0,
    }];
    let scope = Scope {
        families: &families,
        params: &params,
        tables: &tables,
        n: side,
        boundary,
        shape,
        time: None,
    };
    let l = lower_with_loops(potential, &scope, &mut graph).unwrap();
    assert!(!l.sums.is_empty(), "{potential}: no loop");
    let lattice = LatticePotential::new(&mut graph, l.root, l.sums, n, true)
        .unwrap()
        .expect("affine in its sums");
    System {
        n,
        graph,
        gradient: Vec::new(),
        hessian_vector: Vec::new(),
        lattice: Some(lattice),
    }
}

/// Lattice potentials: each boundary condition, array parameters, a rest around the sums,
/// coefficients other than 1, shifts of two, a table, the operations with masks and calls.
fn lattices() -> Vec<(String, System)> {
    let fput = "sum(i = 0..N, (q[i+1] - q[i])^2/2 + beta/4*(q[i+1] - q[i])^4)";
    let kg = "sum(i = 1..N, k[i]/2*q[i]^2 + q[i]^4/4) + sum(i = 1..N, (q[i+1] - q[i])^2/(2*4))";
    let mixed = "q1^2*q2 - 0.5*sum(i = 1..N, k[i+1]*(q[i+2] - q[i])^2 + cos(q[i-1])*q[i]^2) \
                 + sum(i = 0..N, U(q[i+1] - q[i]) + max(q[i], 0.3*q[i+1])^3 \
                 + if(q[i] < q[i+1], q[i]^2, tanh(q[i])) + exp(q[i]/4)*sin(q[i+1]) \
                 + sqrt(2 + q[i]^2) + atan2(q[i], 2 + q[i+1]) + (1 + q[i+1]^2)^1.5)";
    let mut out = Vec::new();
    for n in [1usize, 5, 33] {
        out.push((
            format!("FPUT-{n} loops"),
            lattice_system(n, Boundary::Fixed, fput),
        ));
    }
    for (name, b) in [("free", Boundary::Free), ("periodic", Boundary::Periodic)] {
        out.push((format!("KG-9 {name} loops"), lattice_system(9, b, kg)));
    }
    out.push((
        "Toda-7 periodic loops".into(),
        lattice_system(
            7,
            Boundary::Periodic,
            "sum(i = 1..N, exp(q[i+1] - q[i]) - (q[i+1] - q[i]) - 1)",
        ),
    ));
    out.push((
        "mixed-11 periodic loops".into(),
        lattice_system(11, Boundary::Periodic, mixed),
    ));
    // Walls under a term reaching two sites back and one ahead.
    out.push((
        "next-nearest-6 fixed loops".into(),
        lattice_system(
            6,
            Boundary::Fixed,
            "sum(i = -1..N+1, (q[i+1] - q[i-1])^2*(1 + q[i]^2))",
        ),
    ));
    out.extend(squares());
    out
}

/// Square lattices, their sums loops along the rows: the Klein-Gordon lattice with a boundary
/// per axis, and a term reaching two rows down and two columns back, with a table.
fn squares() -> Vec<(String, System)> {
    let kg = "sum(i = 1..N, sum(j = 1..N, k[i, j]/2*q[i, j]^2 + q[i, j]^4/4)) \
              + sum(i = 1..N, sum(j = 1..N, ((q[i+1, j] - q[i, j])^2 + (q[i, j+1] - q[i, j])^2)/8))";
    let far =
        "q[1, 1]^2 + sum(i = 1..N, sum(j = 1..N, U(q[i+2, j] - q[i, j-2])*(1 + q[i-1, j+1]^2)))";
    let mut out = Vec::new();
    for (rows, columns) in [
        (Boundary::Fixed, Boundary::Periodic),
        (Boundary::Periodic, Boundary::Free),
        (Boundary::Free, Boundary::Fixed),
    ] {
        out.push((
            format!("KG 6 x 6 {rows:?} x {columns:?} loops"),
            lattice_system_shaped(6, rows, Shape::Square { columns }, kg),
        ));
    }
    out.push((
        "far 7 x 7 periodic loops".into(),
        lattice_system_shaped(
            7,
            Boundary::Periodic,
            Shape::Square {
                columns: Boundary::Periodic,
            },
            far,
        ),
    ));
    out
}

fn henon_heiles() -> System {
    system(2, "(q1^2 + q2^2)/2 + q1^2*q2 - q2^3/3")
}

fn fput(n: usize) -> System {
    system(
        n,
        "sum(i = 0..N, (q[i+1] - q[i])^2/2 + beta/4*(q[i+1] - q[i])^4)",
    )
}

fn coeffs() -> (Vec<f64>, Vec<f64>) {
    (
        DRIFT.iter().map(|a| a * H).collect(),
        KICK.iter().map(|b| b * H).collect(),
    )
}

fn drift(q: &mut [f64], p: &[f64], ch: f64, w: Option<&[f64]>) {
    for (i, (qi, pi)) in q.iter_mut().zip(p).enumerate() {
        match w {
            None => *qi += ch * pi,
            Some(w) => *qi += (ch * w[i]) * pi,
        }
    }
}

/// One orbit, `n_steps` steps, positions before each kick appended to `stages`.
fn reference_orbit(
    s: &System,
    x: &mut [f64],
    n_steps: u64,
    w: Option<&[f64]>,
    stages: &mut Vec<f64>,
) {
    let (dr, ki) = coeffs();
    let n = s.n;
    let mut ev = Evaluator::new();
    let mut g = vec![0.0; n];
    for _ in 0..n_steps {
        for (&ch, &dh) in dr.iter().zip(&ki) {
            let (q, p) = x.split_at_mut(n);
            drift(q, p, ch, w);
            stages.extend_from_slice(q);
            s.gradient(&mut ev, q, &mut g);
            for (pi, gi) in p.iter_mut().zip(&g) {
                *pi -= dh * gi;
            }
        }
        let (q, p) = x.split_at_mut(n);
        drift(q, p, dr[KICK.len()], w);
    }
}

fn reference_tangent(s: &System, v: &mut [f64], n_steps: u64, w: Option<&[f64]>, stages: &[f64]) {
    let (dr, ki) = coeffs();
    let n = s.n;
    let mut ev = Evaluator::new();
    let mut f = vec![0.0; n];
    let mut stage = stages.chunks_exact(n);
    for _ in 0..n_steps {
        for (&ch, &dh) in dr.iter().zip(&ki) {
            let (dq, dp) = v.split_at_mut(n);
            drift(dq, dp, ch, w);
            let q = stage.next().unwrap();
            s.hessian_vector(&mut ev, q, dq, &mut f);
            for (pi, fi) in dp.iter_mut().zip(&f) {
                *pi -= dh * fi;
            }
        }
        let (dq, dp) = v.split_at_mut(n);
        drift(dq, dp, dr[KICK.len()], w);
    }
}

fn compile(s: &System, lane_block: usize) -> StepKernels {
    let options = Options {
        lane_block,
        ..Options::default()
    };
    if let Some(l) = &s.lattice {
        return jit::compile_lattice_steps(&s.graph, l, &options).unwrap();
    }
    jit::compile_steps(
        &s.graph,
        &StepSpec {
            n: s.n,
            gradient: s.gradient.clone(),
            hessian_vector: Some(s.hessian_vector.clone()),
        },
        &options,
    )
    .unwrap()
}

/// Lane `l`'s state: small, different per lane and row.
fn state(n: usize, l: usize, scale: f64) -> Vec<f64> {
    (0..2 * n)
        .map(|r| scale * (0.11 * ((l * 7 + r * 13) % 17) as f64 / 17.0 - 0.05 + 0.001 * l as f64))
        .collect()
}

fn check(name: &str, s: &System, k: &StepKernels) {
    let n = s.n;
    let rows = 2 * n;
    let (dr, ki) = coeffs();
    let masses: Vec<f64> = (0..n).map(|i| 1.0 / (1.0 + 0.37 * i as f64)).collect();
    for w in [None, Some(&masses[..])] {
        for lanes in [1usize, 3, 4, 8, 17] {
            for n_steps in [1u64, 3, 10] {
                for extra in [0usize, 3] {
                    let stride = lanes + extra;
                    // Orbits.
                    let mut x = vec![f64::NAN; rows * stride];
                    let mut want = Vec::new();
                    let mut stages0 = Vec::new();
                    for l in 0..lanes {
                        let mut xl = state(n, l, 1.0);
                        for r in 0..rows {
                            x[r * stride + l] = xl[r];
                        }
                        let mut st = Vec::new();
                        reference_orbit(s, &mut xl, n_steps, w, &mut st);
                        if l == 0 {
                            stages0 = st;
                        }
                        want.push(xl);
                    }
                    k.orbit_steps(&mut x, stride, lanes, n_steps, &dr, &ki, w);
                    for r in 0..rows {
                        for c in 0..stride {
                            let got = x[r * stride + c];
                            if c < lanes {
                                assert_eq!(
                                    got.to_bits(),
                                    want[c][r].to_bits(),
                                    "{name} orbit: masses {}, lanes {lanes}, stride {stride}, \
                                     steps {n_steps}, row {r}, lane {c}: {got} vs {}",
                                    w.is_some(),
                                    want[c][r]
                                );
                            } else {
                                assert!(got.is_nan(), "{name}: padding column {c} written");
                            }
                        }
                    }
                    // Tangent vectors around lane 0's orbit.
                    let mut v = vec![f64::NAN; rows * stride];
                    let mut want = Vec::new();
                    for l in 0..lanes {
                        let mut vl = state(n, l + 5, 1e-3);
                        for r in 0..rows {
                            v[r * stride + l] = vl[r];
                        }
                        reference_tangent(s, &mut vl, n_steps, w, &stages0);
                        want.push(vl);
                    }
                    k.tangent_steps(&stages0, &mut v, stride, lanes, n_steps, &dr, &ki, w);
                    for r in 0..rows {
                        for c in 0..stride {
                            let got = v[r * stride + c];
                            if c < lanes {
                                assert_eq!(
                                    got.to_bits(),
                                    want[c][r].to_bits(),
                                    "{name} tangent: masses {}, lanes {lanes}, stride \
                                     {stride}, steps {n_steps}, row {r}, lane {c}",
                                    w.is_some(),
                                );
                            } else {
                                assert!(got.is_nan(), "{name}: padding column {c} written");
                            }
                        }
                    }
                }
            }
        }
    }
}

#[test]
fn henon_heiles_steps_are_bit_identical() {
    let s = henon_heiles();
    for block in [2, 4] {
        check("HH", &s, &compile(&s, block));
    }
}

#[test]
fn fput_5_steps_are_bit_identical() {
    let s = fput(5);
    for block in [2, 4] {
        check("FPUT-5", &s, &compile(&s, block));
    }
}

#[test]
fn fput_101_steps_are_bit_identical() {
    let s = fput(101);
    check("FPUT-101", &s, &compile(&s, 4));
}

#[test]
fn lattice_loop_steps_are_bit_identical() {
    for (name, s) in lattices() {
        for block in [2, 4] {
            check(&format!("{name} block {block}"), &s, &compile(&s, block));
        }
    }
}

#[test]
fn c_lattice_loop_steps_are_bit_identical() {
    let cache = tempfile::tempdir().unwrap();
    for (name, s) in lattices() {
        check(&format!("C {name}"), &s, &compile_c(&s, cache.path()));
    }
}

#[test]
fn unoptimized_large_functions_are_bit_identical() {
    // The code path of large graphs (no optimizer) on a small one.
    let s = fput(5);
    let options = Options {
        large_function: 0,
        ..Options::default()
    };
    let k = jit::compile_steps(
        &s.graph,
        &StepSpec {
            n: s.n,
            gradient: s.gradient.clone(),
            hessian_vector: Some(s.hessian_vector.clone()),
        },
        &options,
    )
    .unwrap();
    check("FPUT-5 unoptimized", &s, &k);
}

#[test]
fn potentials_whose_force_skips_rows_and_reads_constants() {
    // dV/dq1 = q2 and dV/dq2 = q1 (each force reads the other row only, so a kick must not
    // precede the drift of its own row), a constant force (q3: linear potential) and a free
    // coordinate (q4: no force at all).
    let s = system(4, "q1*q2 + 2.5*q3 + sin(q1)");
    check("coupled", &s, &compile(&s, 4));
    check("coupled", &s, &compile(&s, 2));
}

#[test]
fn no_lanes_or_steps_do_nothing() {
    let s = henon_heiles();
    let k = compile(&s, 4);
    let (dr, ki) = coeffs();
    let mut x = vec![1.0; 4 * 4];
    k.orbit_steps(&mut x, 4, 0, 10, &dr, &ki, None);
    k.orbit_steps(&mut x, 4, 4, 0, &dr, &ki, None);
    assert!(x.iter().all(|&v| v == 1.0));
}

#[test]
fn specs_that_are_not_n_degrees_of_freedom_are_refused() {
    let s = fput(5);
    let refuse = |n: usize, gradient: Vec<NodeId>| {
        let e = jit::compile_steps(
            &s.graph,
            &StepSpec {
                n,
                gradient,
                hessian_vector: None,
            },
            &Options::default(),
        )
        .unwrap_err();
        assert!(matches!(e, jit::JitError::Steps(_)), "{e}");
    };
    // Four forces for five sites; five for four; four forces of which the last reads q5,
    // declared as four sites; nothing.
    refuse(5, s.gradient[..4].to_vec());
    refuse(4, s.gradient.clone());
    refuse(4, s.gradient[..4].to_vec());
    refuse(0, Vec::new());
}

/// The C kernels, built by the system C compiler (`cc`, or `CHAOSCOPE_CC`) into `cache`. CI
/// has gcc: a missing compiler fails these tests instead of skipping them.
fn compile_c(s: &System, cache: &std::path::Path) -> StepKernels {
    let program = CCompiler::from_env().map_or_else(|| "cc".into(), |c| c.program);
    compile_c_by(s, &CCompiler::new(program, cache.to_path_buf()))
}

/// The C kernels of `s`, built by `cc`.
fn compile_c_by(s: &System, cc: &CCompiler) -> StepKernels {
    if let Some(l) = &s.lattice {
        let k = jit::compile_lattice_steps_c(&s.graph, l, cc).unwrap_or_else(|e| panic!("{e}"));
        assert!(matches!(k.backend(), StepBackend::C { .. }));
        return k;
    }
    let k = jit::compile_steps_c(
        &s.graph,
        &StepSpec {
            n: s.n,
            gradient: s.gradient.clone(),
            hessian_vector: Some(s.hessian_vector.clone()),
        },
        cc,
    )
    .unwrap_or_else(|e| panic!("{e}"));
    assert!(matches!(k.backend(), StepBackend::C { .. }));
    k
}

#[test]
fn c_steps_are_bit_identical() {
    let cache = tempfile::tempdir().unwrap();
    for (name, s) in [
        ("HH", henon_heiles()),
        ("FPUT-5", fput(5)),
        ("FPUT-101", fput(101)),
        ("coupled", system(4, "q1*q2 + 2.5*q3 + sin(q1)")),
    ] {
        check(&format!("C {name}"), &s, &compile_c(&s, cache.path()));
    }
}

/// Kernels built for a named instruction set (`CHAOSCOPE_CC_MARCH`, here AVX2 without AVX-512:
/// `x86-64-v3`, on any x86-64 host that has AVX2) give the bits of the generic loops too, and
/// are a library of their own beside the host's; an instruction set with features this CPU
/// lacks is refused in one line naming them, and a value that is not a plain name in one line
/// naming the variable, before any compiler runs.
#[test]
fn c_steps_for_another_instruction_set_are_bit_identical_and_hostile_names_are_refused() {
    let cache = tempfile::tempdir().unwrap();
    let program = CCompiler::from_env().map_or_else(|| "cc".into(), |c| c.program);
    let s = fput(101);
    let spec = StepSpec {
        n: s.n,
        gradient: s.gradient.clone(),
        hessian_vector: Some(s.hessian_vector.clone()),
    };
    let with = |march: &str| {
        let mut cc = CCompiler::new(program.clone(), cache.path().to_path_buf());
        cc.march = march.to_owned();
        jit::compile_steps_c(&s.graph, &spec, &cc)
    };
    let libraries = || {
        std::fs::read_dir(cache.path())
            .unwrap()
            .filter(|e| {
                e.as_ref()
                    .unwrap()
                    .file_name()
                    .to_string_lossy()
                    .ends_with(".so")
            })
            .count()
    };
    check("C FPUT-101 native", &s, &with("native").unwrap());
    assert_eq!(libraries(), 1);
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma") {
        check("C FPUT-101 x86-64-v3", &s, &with("x86-64-v3").unwrap());
        assert_eq!(libraries(), 2, "another instruction set is another library");
    }
    // Sets with features no CPU of today has: Knights Landing's AVX-512 ER and PF (Xeon Phi
    // only) and k8's 3DNow! (on no CPU since 2011; a feature macro in mixed case). Their code
    // would stop at an illegal instruction here, so the build is refused, naming them.
    for (march, lacking) in [("knl", "AVX512ER"), ("k8", "3dNOW")] {
        let known = std::process::Command::new(&program)
            .args([&format!("-march={march}"), "-E", "-x", "c", "/dev/null"])
            .output()
            .is_ok_and(|o| o.status.success());
        if !(cfg!(target_arch = "x86_64") && known) {
            continue;
        }
        let Err(e) = with(march) else {
            panic!("code for -march={march} was built for this CPU")
        };
        let e = e.to_string();
        assert!(
            e.contains(&format!("CHAOSCOPE_CC_MARCH='{march}' asks for")) && e.contains(lacking),
            "{e}"
        );
        assert_eq!(e.lines().count(), 1, "{e}");
    }
    for hostile in [
        "native -o /tmp/x",
        "",
        "-O0",
        "native;true",
        &"v".repeat(65),
    ] {
        let Err(e) = with(hostile) else {
            panic!("{hostile:?} was accepted")
        };
        let e = e.to_string();
        assert!(
            e.contains("CHAOSCOPE_CC_MARCH=") && e.contains("is not an instruction set name"),
            "{hostile:?}: {e}"
        );
        assert_eq!(e.lines().count(), 1, "{e}");
    }
}

#[test]
fn c_steps_of_every_operation_and_a_table_are_bit_identical() {
    // Every unary and binary operation (asinh the one added in `ops` alone), whole and real powers (negative too), `if` with each
    // comparison, and a tabulated function: the callbacks, the compares and bit selects (NaN
    // and signed-zero rules), the constants written by their bits.
    let xs: Vec<f64> = (0..41).map(|i| -2.0 + 0.1 * i as f64).collect();
    let ys: Vec<f64> = xs.iter().map(|x| (1.0 + x * x).ln()).collect();
    let table: Arc<dyn Tabulated> =
        Arc::new(Spline::new("U", &xs, &ys, SplineEnds::Natural).unwrap());
    let s = system_with_tables(
        3,
        "exp(q1/4)*sin(q2) + log(3 + cos(q3)) + tan(q1/3) + atan(q2) + tanh(q1*q2) \
         + cosh(q2)/4 + sinh(q3)/5 + atan2(q1, 2 + q2) + sqrt(2 + q1^2) + abs(q2)^3 \
         + max(q1, q3)^3 + min(q2, -0.01)^3 + (1 + q1^2)^1.5 + q3^-2/1000 + step(q1)*q1^4 \
         + if(q2 < q3, q2^2, q3^2) + if(q1 >= 0, q1^3, 0) + if(q2 <= q1, 0, q2^4) \
         + if(q3 > 0.01, q3^3, 0.1) + U(q3 - q1) + 0.1/(2 + q2^2) + asinh(q1 - q3)",
        &[("U", table)],
    );
    let cache = tempfile::tempdir().unwrap();
    check("C every operation", &s, &compile_c(&s, cache.path()));
    check("Cranelift every operation", &s, &compile(&s, 4));
}

#[test]
fn c_steps_come_from_the_cache_the_second_time() {
    let cache = tempfile::tempdir().unwrap();
    let s = henon_heiles();
    let first = compile_c(&s, cache.path());
    let second = compile_c(&s, cache.path());
    assert!(matches!(
        first.backend(),
        StepBackend::C { cached: false, .. }
    ));
    let StepBackend::C {
        cached: true,
        library,
    } = second.backend()
    else {
        panic!(
            "the second build was not a cache hit: {:?}",
            second.backend()
        );
    };
    assert!(library.starts_with(cache.path()));
    // A damaged cache file is rebuilt, not loaded (unloaded first: writing into a mapped
    // library would pull the code from under it; the builder itself only ever renames).
    drop((first, second));
    std::fs::write(&library, b"not a library").unwrap();
    let third = compile_c(&s, cache.path());
    assert!(matches!(
        third.backend(),
        StepBackend::C { cached: false, .. }
    ));
    check("C HH after a damaged cache", &s, &third);
}

#[test]
fn c_compiler_failures_are_errors_naming_the_cause() {
    let s = henon_heiles();
    let cache = tempfile::tempdir().unwrap();
    let spec = StepSpec {
        n: s.n,
        gradient: s.gradient.clone(),
        hessian_vector: Some(s.hessian_vector.clone()),
    };
    let build = |program: &str| {
        jit::compile_steps_c(
            &s.graph,
            &spec,
            &CCompiler::new(program, cache.path().to_path_buf()),
        )
        .unwrap_err()
        .to_string()
    };
    let missing = build("/nonexistent/cc");
    assert!(
        missing.contains("cannot run the C compiler '/nonexistent/cc'"),
        "{missing}"
    );
    // `false` runs and fails: the error names it.
    let failing = build("false");
    assert!(
        failing.contains("the C compiler 'false' failed"),
        "{failing}"
    );
    // An unwritable cache directory (a file in its place).
    let file = cache.path().join("a-file");
    std::fs::write(&file, b"").unwrap();
    let program = CCompiler::from_env().map_or_else(|| "cc".into(), |c| c.program);
    let e = jit::compile_steps_c(
        &s.graph,
        &spec,
        &CCompiler::new(program, file.join("kernels")),
    )
    .unwrap_err()
    .to_string();
    assert!(e.contains("cannot create the kernel cache"), "{e}");
}

#[test]
fn c_builds_clean_up_after_dead_processes_and_cancels() {
    let cache = tempfile::tempdir().unwrap();
    // The build directory of a process that no longer exists (a chaoscope killed by SIGKILL
    // during its build): the next build removes it. A live process's directory is kept.
    let mut gone = std::process::Command::new("true").spawn().unwrap();
    let dead_pid = gone.id();
    gone.wait().unwrap();
    let abandoned = cache.path().join(format!("build-{dead_pid}-0"));
    let alive = cache.path().join("build-1-0");
    for d in [&abandoned, &alive] {
        std::fs::create_dir(d).unwrap();
        std::fs::write(d.join("steps.c"), "half a source").unwrap();
    }
    let s = henon_heiles();
    let spec = StepSpec {
        n: s.n,
        gradient: s.gradient.clone(),
        hessian_vector: Some(s.hessian_vector.clone()),
    };
    let program = CCompiler::from_env().map_or_else(|| "cc".into(), |c| c.program);
    let cc = CCompiler::new(program, cache.path().to_path_buf());
    // Cancelled before it starts: no compiler run, nothing written.
    let cancel = std::sync::atomic::AtomicBool::new(true);
    let e = jit::compile_steps_c_cancellable(&s.graph, &spec, &cc, &cancel).unwrap_err();
    assert!(matches!(e, jit::JitError::Cancelled), "{e}");
    assert!(abandoned.exists(), "a cancelled build touches nothing");
    let k = jit::compile_steps_c(&s.graph, &spec, &cc).unwrap_or_else(|e| panic!("{e}"));
    assert!(
        !abandoned.exists(),
        "the dead process's build directory was removed"
    );
    assert!(
        alive.exists(),
        "a live process's (pid 1) build directory was kept"
    );
    // The compiler's target record (`target-*`, a finished record every later build reads)
    // aside.
    let mut left: Vec<String> = std::fs::read_dir(cache.path())
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|n| !n.starts_with("target-"))
        .collect();
    left.sort();
    // The live process's directory, the library and its digest.
    assert_eq!(left.len(), 3, "{left:?}");
    assert!(
        left[0] == "build-1-0" && left[1].starts_with("steps-") && left[1].ends_with(".sha256")
    );
    assert_eq!(left[2], left[1].replace(".sha256", ".so"), "{left:?}");
    check("C HH after the clean-up", &s, &k);
}

/// A shared library whose constructor writes `marker` when it is loaded (what someone who can
/// write into a kernel cache would plant), with the stamp of kernel `hash` so that even a
/// loader that checks the stamp after loading would take it for the kernels.
fn planted_library(dir: &std::path::Path, hash: &str, marker: &std::path::Path) -> Vec<u8> {
    let src = dir.join("planted.c");
    let lib = dir.join("planted.so");
    std::fs::write(
        &src,
        format!(
            "#include <stdio.h>\nconst char chaoscope_kernel_hash[] = \"{hash}\";\n\
             __attribute__((constructor)) static void planted(void) {{\n\
             FILE *f = fopen(\"{}\", \"w\"); if (f) {{ fputs(\"loaded\", f); fclose(f); }} }}\n",
            marker.display()
        ),
    )
    .unwrap();
    let status = std::process::Command::new("cc")
        .args(["-shared", "-fPIC", "-o"])
        .arg(&lib)
        .arg(&src)
        .status()
        .unwrap();
    assert!(status.success(), "cc builds the planted library");
    std::fs::read(&lib).unwrap()
}

/// The cache's library file and its kernel hash (`steps-<hash>.so`).
fn cached_library(cache: &std::path::Path) -> (std::path::PathBuf, String) {
    let lib = std::fs::read_dir(cache)
        .unwrap()
        .map(|e| e.unwrap().path())
        .find(|p| p.extension().is_some_and(|x| x == "so"))
        .expect("a library in the cache");
    let name = lib.file_name().unwrap().to_string_lossy();
    let hash = name["steps-".len()..name.len() - ".so".len()].to_string();
    (lib, hash)
}

#[test]
fn a_library_planted_in_the_kernel_cache_is_rebuilt_not_loaded() {
    let cache = tempfile::tempdir().unwrap();
    let scratch = tempfile::tempdir().unwrap();
    let marker = scratch.path().join("planted-code-ran");
    let s = henon_heiles();
    drop(compile_c(&s, cache.path()));
    let (lib, hash) = cached_library(cache.path());
    // The planted library in place of the real one (its digest file left as it was), and as
    // a library with its own matching digest under the name of a kernel never built here.
    let planted = planted_library(scratch.path(), &hash, &marker);
    std::fs::write(&lib, &planted).unwrap();
    let k = compile_c(&s, cache.path());
    assert!(
        !marker.exists(),
        "the planted library was loaded (its constructor ran)"
    );
    assert!(
        matches!(k.backend(), StepBackend::C { cached: false, .. }),
        "a library that does not match its digest is rebuilt: {:?}",
        k.backend()
    );
    check("C HH rebuilt over a planted library", &s, &k);
    drop(k);
    // Without its digest file a library is never loaded either.
    std::fs::write(&lib, &planted).unwrap();
    std::fs::remove_file(lib.with_extension("sha256")).unwrap();
    let k = compile_c(&s, cache.path());
    assert!(!marker.exists(), "a library without digest was loaded");
    assert!(matches!(k.backend(), StepBackend::C { cached: false, .. }));
    // And the rebuilt cache is used again.
    drop(k);
    let k = compile_c(&s, cache.path());
    assert!(matches!(k.backend(), StepBackend::C { cached: true, .. }));
}

#[test]
fn a_kernel_cache_others_could_write_is_refused_with_one_line() {
    use std::os::unix::fs::PermissionsExt;
    let s = henon_heiles();
    let spec = StepSpec {
        n: s.n,
        gradient: s.gradient.clone(),
        hessian_vector: Some(s.hessian_vector.clone()),
    };
    let program = CCompiler::from_env().map_or_else(|| "cc".into(), |c| c.program);
    let build = |dir: &std::path::Path| {
        jit::compile_steps_c(
            &s.graph,
            &spec,
            &CCompiler::new(program.clone(), dir.to_path_buf()),
        )
        .map(|_| ())
        .map_err(|e| e.to_string())
    };
    let root = tempfile::tempdir().unwrap();
    // Writable by the group or by everyone: another user could put a library there.
    for mode in [0o777, 0o775, 0o1777] {
        let dir = root.path().join(format!("mode{mode:o}"));
        std::fs::create_dir(&dir).unwrap();
        std::fs::set_permissions(&dir, std::fs::Permissions::from_mode(mode)).unwrap();
        let e = build(&dir).unwrap_err();
        assert!(
            e.contains(&dir.display().to_string())
                && e.contains("is writable by others")
                && !e.contains('\n'),
            "mode {mode:o}: {e}"
        );
        assert_eq!(
            std::fs::read_dir(&dir).unwrap().count(),
            0,
            "nothing built there"
        );
    }
    // A link, even to a directory of one's own: refused, not followed.
    let own = root.path().join("own");
    std::fs::create_dir(&own).unwrap();
    let link = root.path().join("link");
    std::os::unix::fs::symlink(&own, &link).unwrap();
    let e = build(&link).unwrap_err();
    assert!(e.contains("not a directory but a link"), "{e}");
    // A directory of another user (root can make one; others cannot, and skip this part).
    // SAFETY: geteuid(2) cannot fail.
    if unsafe { libc::geteuid() } == 0 {
        let foreign = root.path().join("foreign");
        std::fs::create_dir(&foreign).unwrap();
        std::os::unix::fs::chown(&foreign, Some(65534), Some(65534)).unwrap();
        std::fs::set_permissions(&foreign, std::fs::Permissions::from_mode(0o755)).unwrap();
        let e = build(&foreign).unwrap_err();
        assert!(
            e.contains("belongs to uid 65534, not to you (uid 0)"),
            "{e}"
        );
    }
    // The user's own private directory is used.
    assert_eq!(build(&own), Ok(()));
}

/// Lattices long enough for the fused one-orbit kernel (`StepKernels::reference_tangent_steps`,
/// vectorized along the sites): each boundary condition, array parameters, a rest around the
/// sums at a site of its own and at two, coefficients other than 1, shifts of two and of five
/// (beyond the one-pass sweep's reach), no coupling, a table, every operation of `lattices`'
/// mixed chain; lengths that leave the vector loops a remainder and lengths that do not.
fn long_lattices() -> Vec<(String, System)> {
    let fput = "sum(i = 0..N, (q[i+1] - q[i])^2/2 + beta/4*(q[i+1] - q[i])^4)";
    let kg = "sum(i = 1..N, k[i]/2*q[i]^2 + q[i]^4/4) + sum(i = 0..N, (q[i+1] - q[i])^2/(2*4))";
    let mixed = "q1^2*q2 - 0.5*sum(i = 1..N, k[i+1]*(q[i+2] - q[i])^2 + cos(q[i-1])*q[i]^2) \
                 + sum(i = 0..N, U(q[i+1] - q[i]) + max(q[i], 0.3*q[i+1])^3 \
                 + if(q[i] < q[i+1], q[i]^2, tanh(q[i])) + exp(q[i]/4)*sin(q[i+1]) \
                 + sqrt(2 + q[i]^2) + atan2(q[i], 2 + q[i+1]) + (1 + q[i+1]^2)^1.5)";
    let mut out = Vec::new();
    for n in [16usize, 33, 64] {
        out.push((
            format!("FPUT-{n}"),
            lattice_system(n, Boundary::Fixed, fput),
        ));
    }
    for (name, b) in [
        ("fixed", Boundary::Fixed),
        ("free", Boundary::Free),
        ("periodic", Boundary::Periodic),
    ] {
        out.push((format!("KG-41 {name}"), lattice_system(41, b, kg)));
    }
    out.push((
        "KG-40 pinned end".into(),
        lattice_system(40, Boundary::Free, &format!("{kg} + q1^2/2")),
    ));
    out.push((
        "Toda-37 periodic".into(),
        lattice_system(
            37,
            Boundary::Periodic,
            "sum(i = 1..N, exp(q[i+1] - q[i]) - (q[i+1] - q[i]) - 1)",
        ),
    ));
    out.push((
        "mixed-43 periodic".into(),
        lattice_system(43, Boundary::Periodic, mixed),
    ));
    out.push((
        "mixed-21 fixed".into(),
        lattice_system(21, Boundary::Fixed, &mixed.replace("k[i+1]", "k[i]")),
    ));
    out.push((
        "next-nearest-38 fixed".into(),
        lattice_system(
            38,
            Boundary::Fixed,
            "sum(i = -1..N+1, (q[i+1] - q[i-1])^2*(1 + q[i]^2))",
        ),
    ));
    // Sites on their own (no coupling): every site regular, to the chain's last, whose vector
    // ends the chain (no site past it to drift).
    out.push((
        "on-site-48 fixed".into(),
        lattice_system(
            48,
            Boundary::Fixed,
            "sum(i = 1..N, k[i]/2*q[i]^2 + q[i]^4/4)",
        ),
    ));
    // A term reading five sites apart: farther than the sweep's registers reach, so the kernel
    // drifts and kicks stage by stage.
    out.push((
        "far-reaching-45 fixed".into(),
        lattice_system(
            45,
            Boundary::Fixed,
            "sum(i = 1..N, q[i]^4/4) + sum(i = 1..N-5, (q[i+5] - q[i])^2*(2 + q[i+1]))",
        ),
    ));
    // Squares: the small ones (rows of regular sites shorter than a vector), and larger ones
    // with every boundary per axis, the 2-D Klein-Gordon lattice as the guide writes it (walls
    // as sums from 0), a rest at a corner and at the middle, a term reaching two rows down
    // and two columns back.
    // The first (rows of regular sites shorter than a vector: the scalar tail).
    out.extend(squares().into_iter().take(1));
    let kg2 = "sum(i = 1..N, sum(j = 1..N, k[i, j]/2*q[i, j]^2 + q[i, j]^4/4)) \
               + sum(i = 0..N, sum(j = 1..N, (q[i+1, j] - q[i, j])^2/40)) \
               + sum(i = 1..N, sum(j = 0..N, (q[i, j+1] - q[i, j])^2/40))";
    let kg = "sum(i = 1..N, sum(j = 1..N, k[i, j]/2*q[i, j]^2 + q[i, j]^4/4)) \
              + sum(i = 1..N, sum(j = 1..N, ((q[i+1, j] - q[i, j])^2 + (q[i, j+1] - q[i, j])^2)/8))";
    for (side, rows, columns) in [
        (20, Boundary::Fixed, Boundary::Fixed),
        (12, Boundary::Fixed, Boundary::Periodic),
        (15, Boundary::Periodic, Boundary::Free),
        (14, Boundary::Fixed, Boundary::Free),
        (13, Boundary::Free, Boundary::Periodic),
    ] {
        out.push((
            format!("KG {side} x {side} {rows:?} x {columns:?}"),
            lattice_system_shaped(side, rows, Shape::Square { columns }, kg),
        ));
    }
    // Sides that are not multiples of `state`'s period (17) or `k`'s (13), so no two rows
    // start alike. A pinned middle splits its row's regular sites in two runs; a pinned column
    // splits every row's.
    out.push((
        "KG walls 19 x 19 fixed, pinned corner and middle".into(),
        lattice_system_shaped(
            19,
            Boundary::Fixed,
            Shape::Square {
                columns: Boundary::Fixed,
            },
            &format!("{kg2} + q1^2/2 + q[10, 10]^4"),
        ),
    ));
    out.push((
        "KG walls 18 x 18 fixed, pinned column".into(),
        lattice_system_shaped(
            18,
            Boundary::Fixed,
            Shape::Square {
                columns: Boundary::Fixed,
            },
            &format!("{kg2} + sum(i = 1..N, q[i, 9]^4)"),
        ),
    ));
    // Parameters read a row down (wrapped on the last row) and a column on.
    out.push((
        "KG 14 x 14 periodic, shifted parameters".into(),
        lattice_system_shaped(
            14,
            Boundary::Periodic,
            Shape::Square {
                columns: Boundary::Periodic,
            },
            &format!(
                "{kg} + sum(i = 1..N, sum(j = 1..N, k[i+1, j]*q[i, j]^2 + k[i, j+1]*q[i, j]^4))"
            ),
        ),
    ));
    out.push((
        "far 14 x 14 periodic".into(),
        lattice_system_shaped(
            14,
            Boundary::Periodic,
            Shape::Square {
                columns: Boundary::Periodic,
            },
            "q[1, 1]^2 + sum(i = 1..N, sum(j = 1..N, U(q[i+2, j] - q[i, j-2])*(1 + q[i-1, j+1]^2)))",
        ),
    ));
    out
}

/// A short chain has no fused C kernel (its caller steps the one-orbit way). The long ones'
/// kernels are checked against the reference loops in each of their two forms below: the
/// kernel a plain build keeps is one of them, the same source with the same flags, so building
/// it a third time here would check nothing new (and cost a C build of every long lattice).
#[test]
fn c_fused_reference_tangent_steps_of_a_short_chain_are_not_taken() {
    let cache = tempfile::tempdir().unwrap();
    let no_fused = lattices().into_iter().filter(|(_, s)| s.n < 16);
    for (name, s) in no_fused {
        let k = compile_c(&s, cache.path());
        assert!(
            !k.has_reference_tangent(),
            "{name}: {} sites, a fused kernel",
            s.n
        );
        let (dr, ki) = coeffs();
        let (mut x, mut v) = (state(s.n, 0, 1.0), state(s.n, 1, 1e-3));
        let (x0, v0) = (x.clone(), v.clone());
        assert!(!k.reference_tangent_steps(&mut x, &mut v, 3, &dr, &ki, None));
        assert_eq!((x, v), (x0, v0), "{name}: stepped without a kernel");
    }
}

/// The same plan printed by Cranelift (a host without a C compiler): the same bits, for both
/// lane widths of its step kernels; a short chain has none, nor kernels built without it (a
/// map's).
#[test]
fn cranelift_fused_reference_tangent_steps_are_bit_identical() {
    for lane_block in [2, 4] {
        let options = Options {
            lane_block,
            ..Options::default()
        };
        fused_bit_identical(&|s| {
            let l = s.lattice.as_ref().expect("a lattice");
            let k =
                jit::compile_lattice_steps(&s.graph, l, &options).unwrap_or_else(|e| panic!("{e}"));
            assert_eq!(k.backend(), StepBackend::Cranelift);
            k
        });
    }
    for (name, s) in lattices().into_iter().filter(|(_, s)| s.n < 16) {
        let l = s.lattice.as_ref().expect("a lattice");
        let k = jit::compile_lattice_steps(&s.graph, l, &Options::default()).unwrap();
        assert!(
            !k.has_reference_tangent(),
            "{name}: {} sites, a fused kernel",
            s.n
        );
    }
    let without = Options {
        fused_pass: false,
        ..Options::default()
    };
    for (name, s) in long_lattices() {
        let l = s.lattice.as_ref().expect("a lattice");
        let k = jit::compile_lattice_steps(&s.graph, l, &without).unwrap();
        assert!(
            !k.has_reference_tangent(),
            "{name}: a fused kernel not asked for"
        );
    }
}

/// Which squares get the fused kernel: any side from 4 (16 sites) with regular sites, edges of
/// more than 256 sites written out (a side of 100), up to a side of 128; a larger square steps
/// the one-orbit way (its ends' straight code would take the compiler minutes).
#[test]
fn squares_get_the_fused_kernel_up_to_a_side_of_128() {
    let kg = "sum(i = 1..N, sum(j = 1..N, k[i, j]/2*q[i, j]^2 + q[i, j]^4/4)) \
              + sum(i = 0..N, sum(j = 1..N, (q[i+1, j] - q[i, j])^2/40)) \
              + sum(i = 1..N, sum(j = 0..N, (q[i, j+1] - q[i, j])^2/40))";
    let fixed = Shape::Square {
        columns: Boundary::Fixed,
    };
    for (side, applies) in [
        (32, true),
        (100, true),
        (128, true),
        (129, false),
        (160, false),
    ] {
        let s = lattice_system_shaped(side, Boundary::Fixed, fixed, kg);
        let l = s.lattice.as_ref().expect("a lattice");
        assert_eq!(jit::fused_applies(l), applies, "side {side}");
    }
}

/// The fused kernel's vectors are as wide as the host's (8 lanes with AVX-512, 4 otherwise):
/// on an AVX-512 host the 4-lane kernel an AVX2 machine builds is built too, through a compiler
/// that targets the host without AVX-512, and is bit-identical as well. Elsewhere the host's
/// own kernels are the 4-lane ones, which the two form tests below already check in both forms.
#[cfg(target_arch = "x86_64")]
#[test]
fn c_fused_kernel_of_four_lanes_is_bit_identical() {
    if !std::arch::is_x86_feature_detected!("avx512f") {
        eprintln!(
            "no AVX-512 here: the host's kernels are the 4-lane ones, checked by the form tests"
        );
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let cc = wrapped_cc(dir.path(), "cc-no-avx512", "-mno-avx512f");
    fused_bit_identical(&|s| compile_c_by(s, &cc));
}

/// A lattice's fused C kernel has two forms, the compiler keeping one by the vectors' width and
/// the CPU (the one sweep per stage with 8 lanes, and with 4 on Intel; the stage-by-stage form
/// otherwise). Each form, asked for by name, is bit-identical to the reference loops (the orbit's
/// steps, and each vector's along the orbit's stages) for every long lattice, 0 (the orbit
/// alone) to 3 vectors, 1 to 10 steps, with and without masses. One test per form, so that the
/// two C builds of every lattice run side by side.
#[test]
fn c_fused_kernel_swept_is_bit_identical() {
    fused_bit_identical_in_form("CHAOSCOPE_FUSED_SWEEP");
}

/// The stage-by-stage form, as the test above.
#[test]
fn c_fused_kernel_stage_by_stage_is_bit_identical() {
    fused_bit_identical_in_form("CHAOSCOPE_FUSED_STAGES");
}

/// [`fused_bit_identical`] of the kernels built with the form `form` asked for by name.
fn fused_bit_identical_in_form(form: &str) {
    let dir = tempfile::tempdir().unwrap();
    let cc = wrapped_cc(dir.path(), form, &format!("-D{form}"));
    fused_bit_identical(&|s| compile_c_by(s, &cc));
}

/// The test's C compiler (`CHAOSCOPE_CC`, else `cc`) behind a script `name` in `dir` that adds
/// `flags`, with its own cache under `dir`.
fn wrapped_cc(dir: &std::path::Path, name: &str, flags: &str) -> CCompiler {
    use std::os::unix::fs::PermissionsExt;
    let program = CCompiler::from_env().map_or_else(|| "cc".into(), |c| c.program);
    let wrapper = dir.join(name);
    std::fs::write(
        &wrapper,
        format!("#!/bin/sh\nexec '{}' \"$@\" {flags}\n", program.display()),
    )
    .unwrap();
    std::fs::set_permissions(&wrapper, std::fs::Permissions::from_mode(0o755)).unwrap();
    CCompiler::new(wrapper, dir.join(format!("cache-{name}")))
}

/// Every long lattice's fused kernel, built by `build`, against the reference loops.
fn fused_bit_identical(build: &dyn Fn(&System) -> StepKernels) {
    let (dr, ki) = coeffs();
    for (name, s) in long_lattices() {
        let k = build(&s);
        assert!(k.has_reference_tangent(), "{name}: no fused kernel");
        let n = s.n;
        let masses: Vec<f64> = (0..n).map(|i| 1.0 / (1.0 + 0.37 * i as f64)).collect();
        for w in [None, Some(&masses[..])] {
            for vectors in [0usize, 1, 2, 3] {
                for n_steps in [1u64, 3, 10] {
                    let mut x = state(n, 0, 1.0);
                    let mut v: Vec<f64> = (1..=vectors).flat_map(|l| state(n, l, 1e-3)).collect();
                    let mut want_x = x.clone();
                    let mut stages = Vec::new();
                    reference_orbit(&s, &mut want_x, n_steps, w, &mut stages);
                    let mut want_v = v.clone();
                    for vec in want_v.chunks_exact_mut(2 * n) {
                        reference_tangent(&s, vec, n_steps, w, &stages);
                    }
                    assert!(k.reference_tangent_steps(&mut x, &mut v, n_steps, &dr, &ki, w));
                    let bits = |a: &[f64]| a.iter().map(|v| v.to_bits()).collect::<Vec<_>>();
                    assert_eq!(
                        bits(&x),
                        bits(&want_x),
                        "{name}: orbit, {vectors} vectors, {n_steps} steps, masses {}",
                        w.is_some()
                    );
                    assert_eq!(
                        bits(&v),
                        bits(&want_v),
                        "{name}: vectors, {vectors} of them, {n_steps} steps, masses {}",
                        w.is_some()
                    );
                }
            }
        }
    }
}

/// Two kernel libraries loaded at once: the second is its own, not the first handed back
/// (`dlopen` knows a library by the `/proc/self/fd/N` name it was opened by, which a closed
/// and reused descriptor would give the second).
#[test]
fn two_c_kernel_libraries_loaded_at_once_are_each_their_own() {
    let cache = tempfile::tempdir().unwrap();
    let (a, b) = (henon_heiles(), fput(5));
    let ka = compile_c(&a, cache.path());
    let kb = compile_c(&b, cache.path());
    check("C HH beside FPUT-5", &a, &ka);
    check("C FPUT-5 beside HH", &b, &kb);
}
