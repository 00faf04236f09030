//! The compiled code against a reference evaluation of the same graph: bit for bit, in scalar
//! calls, in lane calls of several lane counts, with and without uniform (shared) arguments,
//! over random and special inputs (zeros of both signs, NaN, infinities, subnormals, huge).

use std::sync::Arc;

use chaoscope_expr::graph::Tabulated;
use chaoscope_expr::jit::{self, FunctionSpec, Layout, OptLevel, Options};
use chaoscope_expr::{Binary, Cmp, Graph, Node, NodeId, Unary};

// ----------------------------------------------------------------------------------------------
// Reference evaluator: walks the nodes in order with the `Graph::apply_*` definitions.

fn reference(g: &Graph, args: &[&[f64]], outputs: &[NodeId]) -> Vec<f64> {
    let mut v = vec![0.0; g.len()];
    for (i, node) in g.nodes().iter().enumerate() {
        v[i] = match *node {
            Node::Const(c) => c,
            Node::Input { arg, index } => args
                .get(arg as usize)
                .and_then(|a| a.get(index as usize))
                .copied()
                .unwrap_or(f64::NAN),
            Node::Unary(op, a) => Graph::apply_unary(op, v[a as usize]),
            Node::Binary(op, a, b) => Graph::apply_binary(op, v[a as usize], v[b as usize]),
            Node::Powi(a, n) => Graph::apply_powi(v[a as usize], n),
            Node::Select {
                cmp,
                a,
                b,
                then,
                otherwise,
            } => {
                if cmp.holds(v[a as usize], v[b as usize]) {
                    v[then as usize]
                } else {
                    v[otherwise as usize]
                }
            }
            Node::Table { table, deriv, arg } => {
                g.tables()[table as usize].eval(deriv, v[arg as usize])
            }
        };
    }
    outputs.iter().map(|&o| v[o as usize]).collect()
}

/// Bit-identical, NaN payloads and signs included. IEEE 754 and Rust leave a NaN result's
/// payload unspecified (x86 propagates the first operand's), so this relies on both sides
/// keeping the operand order of the graph; it held for every one of ~560k NaN results here. If
/// a future compiler commutes an operation in the reference, relax this to "both NaN".
fn same(a: f64, b: f64) -> bool {
    a.to_bits() == b.to_bits()
}

fn assert_same(what: &str, got: &[f64], want: &[f64], inputs: &dyn std::fmt::Debug) {
    assert_eq!(got.len(), want.len(), "{what}: length");
    for (j, (&x, &y)) in got.iter().zip(want).enumerate() {
        assert!(
            same(x, y),
            "{what}: output {j}: got {x:e} ({:#018x}), want {y:e} ({:#018x}); inputs {inputs:?}",
            x.to_bits(),
            y.to_bits()
        );
    }
}

// ----------------------------------------------------------------------------------------------
// Inputs.

struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        // splitmix64
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    }

    fn uniform(&mut self) -> f64 {
        (self.next() >> 11) as f64 / (1u64 << 53) as f64
    }

    /// Mostly moderate values, often a special one.
    fn value(&mut self) -> f64 {
        const SPECIAL: [f64; 16] = [
            0.0,
            -0.0,
            f64::NAN,
            f64::INFINITY,
            f64::NEG_INFINITY,
            5e-324,
            -2.2e-310,
            f64::MIN_POSITIVE,
            1e300,
            -1e308,
            f64::MAX,
            1.0,
            -1.0,
            0.5,
            2.0,
            -3.0,
        ];
        match self.next() % 8 {
            0 => SPECIAL[(self.next() % SPECIAL.len() as u64) as usize],
            1 => f64::from_bits(self.next()), // any bit pattern, NaNs included
            2 => (self.uniform() - 0.5) * 1e6,
            _ => (self.uniform() - 0.5) * 4.0,
        }
    }

    /// Moderate values only (for large chains, where one NaN would make every output NaN).
    fn moderate(&mut self) -> f64 {
        (self.uniform() - 0.5) * 2.0
    }
}

// ----------------------------------------------------------------------------------------------
// The harness: every spec, scalar and lanes (several lane counts), against the reference.

const LANE_COUNTS: [usize; 7] = [1, 2, 3, 4, 5, 8, 17];

/// `arg_lens[a]` entries per argument; `gen` draws one value.
fn check(
    g: &Graph,
    specs: &[FunctionSpec],
    arg_lens: &[usize],
    samples: usize,
    seed: u64,
    draw: fn(&mut Rng) -> f64,
) {
    for (opt, lane_block) in [
        (OptLevel::None, 2),
        (OptLevel::Speed, 2),
        (OptLevel::Speed, 4),
    ] {
        // Every setting on every function, whatever its size.
        let options = Options {
            opt_level: opt,
            lane_block,
            large_function: usize::MAX,
            ..Options::default()
        };
        let c = jit::compile_with(g, specs, &options).expect("compiles");
        let mut rng = Rng(seed);
        for (f, spec) in specs.iter().enumerate() {
            let n_out = spec.outputs.len();
            for _ in 0..samples {
                // Scalar calls.
                let args: Vec<Vec<f64>> = arg_lens
                    .iter()
                    .map(|&n| (0..n).map(|_| draw(&mut rng)).collect())
                    .collect();
                let refs: Vec<&[f64]> = args.iter().map(|a| a.as_slice()).collect();
                let want = reference(g, &refs, &spec.outputs);
                let mut out = vec![0.0; n_out];
                c.call(f, &refs, &mut out);
                assert_same(
                    &format!("{opt:?}/{lane_block} f{f} scalar"),
                    &out,
                    &want,
                    &args,
                );
            }
            for &lanes in &LANE_COUNTS {
                for _ in 0..samples.div_ceil(lanes).max(2) {
                    // Per lane inputs; `Scalar` arguments shared by every lane.
                    let shared: Vec<Vec<f64>> = arg_lens
                        .iter()
                        .map(|&n| (0..n).map(|_| draw(&mut rng)).collect())
                        .collect();
                    let per_lane: Vec<Vec<Vec<f64>>> = (0..lanes)
                        .map(|_| {
                            arg_lens
                                .iter()
                                .zip(&spec.args)
                                .zip(&shared)
                                .map(|((&n, &layout), s)| match layout {
                                    Layout::Scalar => s.clone(),
                                    Layout::Lanes => (0..n).map(|_| draw(&mut rng)).collect(),
                                })
                                .collect()
                        })
                        .collect();
                    let soa: Vec<Vec<f64>> = arg_lens
                        .iter()
                        .enumerate()
                        .map(|(a, &n)| match spec.args[a] {
                            Layout::Scalar => shared[a].clone(),
                            Layout::Lanes => (0..n * lanes)
                                .map(|k| per_lane[k % lanes][a][k / lanes])
                                .collect(),
                        })
                        .collect();
                    let refs: Vec<&[f64]> = soa.iter().map(|a| a.as_slice()).collect();
                    let mut out = vec![f64::from_bits(0x7ff4_dead_beef_0000); n_out * lanes];
                    c.call_lanes(f, &refs, &mut out, lanes);
                    for (l, lane_args) in per_lane.iter().enumerate() {
                        let lane_refs: Vec<&[f64]> =
                            lane_args.iter().map(|a| a.as_slice()).collect();
                        let want = reference(g, &lane_refs, &spec.outputs);
                        let got: Vec<f64> = (0..n_out).map(|j| out[j * lanes + l]).collect();
                        assert_same(
                            &format!("{opt:?}/{lane_block} f{f} lanes={lanes} lane {l}"),
                            &got,
                            &want,
                            lane_args,
                        );
                        let mut scalar = vec![0.0; n_out];
                        c.call(f, &lane_refs, &mut scalar);
                        for (x, y) in got.iter().zip(&scalar) {
                            assert!(same(*x, *y), "lane and scalar call differ");
                        }
                    }
                }
            }
        }
    }
}

// ----------------------------------------------------------------------------------------------
// Graphs.

/// Hénon–Heiles: gradient `[q1 + 2 q1 q2, q2 + q1^2 - q2^2]` (arg 0 = q) and Hessian-vector
/// product `[(1 + 2 q2) v1 + 2 q1 v2, 2 q1 v1 + (1 - 2 q2) v2]` (arg 1 = v).
fn henon_heiles(g: &mut Graph) -> (Vec<NodeId>, Vec<NodeId>) {
    let q1 = g.input(0, 0);
    let q2 = g.input(0, 1);
    let v1 = g.input(1, 0);
    let v2 = g.input(1, 1);
    let two = g.constant(2.0);
    let one = g.constant(1.0);
    let t = g.mul(two, q1);
    let t = g.mul(t, q2);
    let g1 = g.add2(q1, t);
    let q1s = g.powi(q1, 2);
    let q2s = g.powi(q2, 2);
    let a = g.add2(q2, q1s);
    let g2 = g.sub(a, q2s);
    let tq2 = g.mul(two, q2);
    let tq1 = g.mul(two, q1);
    let h11 = g.add2(one, tq2);
    let h22 = g.sub(one, tq2);
    let a = g.mul(h11, v1);
    let b = g.mul(tq1, v2);
    let hv1 = g.add2(a, b);
    let a = g.mul(tq1, v1);
    let b = g.mul(h22, v2);
    let hv2 = g.add2(a, b);
    (vec![g1, g2], vec![hv1, hv2])
}

/// FPUT-beta chain with fixed ends, `n` sites (arg 0 = q, arg 1 = v): gradient
/// `f(r_{i-1}) - f(r_i)` with `r_i = q_{i+1} - q_i`, `f(r) = r + beta r^3`, and the
/// Hessian-vector product `k(r_{i-1}) (v_i - v_{i-1}) - k(r_i) (v_{i+1} - v_i)`,
/// `k(r) = 1 + 3 beta r^2`.
fn fput(g: &mut Graph, n: u32, beta: f64) -> (Vec<NodeId>, Vec<NodeId>) {
    let zero = g.constant(0.0);
    let one = g.constant(1.0);
    let b = g.constant(beta);
    let b3 = g.constant(3.0 * beta);
    let q: Vec<NodeId> = (0..n).map(|i| g.input(0, i)).collect();
    let v: Vec<NodeId> = (0..n).map(|i| g.input(1, i)).collect();
    let at = |x: &[NodeId], i: i64| {
        if i < 0 || i >= n as i64 {
            zero
        } else {
            x[i as usize]
        }
    };
    // Bond i joins site i-1 and site i (sites -1 and n are the fixed walls).
    let mut force = Vec::new();
    let mut stiff = Vec::new();
    let mut dv = Vec::new();
    for i in 0..=n as i64 {
        let r = g.sub(at(&q, i), at(&q, i - 1));
        let r3 = g.powi(r, 3);
        let br3 = g.mul(b, r3);
        force.push(g.add2(r, br3));
        let r2 = g.powi(r, 2);
        let k = g.mul(b3, r2);
        stiff.push(g.add2(one, k));
        dv.push(g.sub(at(&v, i), at(&v, i - 1)));
    }
    let mut grad = Vec::new();
    let mut hvp = Vec::new();
    for i in 0..n as usize {
        grad.push(g.sub(force[i], force[i + 1]));
        let a = g.mul(stiff[i], dv[i]);
        let c = g.mul(stiff[i + 1], dv[i + 1]);
        hvp.push(g.sub(a, c));
    }
    (grad, hvp)
}

#[derive(Debug)]
struct Cubic;

impl Tabulated for Cubic {
    fn eval(&self, deriv: u8, x: f64) -> f64 {
        if !(-10.0..=10.0).contains(&x) {
            return f64::NAN;
        }
        match deriv {
            0 => x * x * x - x,
            1 => 3.0 * x * x - 1.0,
            2 => 6.0 * x,
            _ => 6.0,
        }
    }

    fn name(&self) -> &str {
        "cubic"
    }
}

const UNARY: [Unary; 15] = [
    Unary::Neg,
    Unary::Sqrt,
    Unary::Exp,
    Unary::Log,
    Unary::Sin,
    Unary::Cos,
    Unary::Tan,
    Unary::Atan,
    Unary::Tanh,
    Unary::Cosh,
    Unary::Sinh,
    Unary::Abs,
    Unary::Step,
    Unary::Sign,
    Unary::Asinh,
];

const BINARY: [Binary; 8] = [
    Binary::Add,
    Binary::Sub,
    Binary::Mul,
    Binary::Div,
    Binary::Pow,
    Binary::Atan2,
    Binary::Max,
    Binary::Min,
];

/// Every operation on inputs `a = arg0[0]`, `b = arg1[0]`, `c = arg0[1]`, `d = arg1[1]`.
fn all_ops(g: &mut Graph) -> Vec<NodeId> {
    let table = g.add_table(Arc::new(Cubic));
    let a = g.input(0, 0);
    let b = g.input(1, 0);
    let c = g.input(0, 1);
    let d = g.input(1, 1);
    let mut out = Vec::new();
    for op in UNARY {
        out.push(g.unary(op, a));
        out.push(g.unary(op, b));
        let s = g.add2(a, b);
        out.push(g.unary(op, s));
    }
    for op in BINARY {
        out.push(g.binary(op, a, b));
        out.push(g.binary(op, b, a));
        out.push(g.binary(op, a, a));
        let k = g.constant(-0.0);
        out.push(g.binary(op, a, k));
        out.push(g.binary(op, k, b));
    }
    for n in -3..=5 {
        out.push(g.powi(a, n));
        out.push(g.powi(b, n));
    }
    for cmp in [Cmp::Lt, Cmp::Le, Cmp::Gt, Cmp::Ge] {
        out.push(g.add(Node::Select {
            cmp,
            a,
            b,
            then: c,
            otherwise: d,
        }));
        out.push(g.add(Node::Select {
            cmp,
            a: c,
            b: a,
            then: b,
            otherwise: d,
        }));
    }
    for deriv in 0..4 {
        out.push(g.add(Node::Table {
            table,
            deriv,
            arg: a,
        }));
        out.push(g.add(Node::Table {
            table,
            deriv,
            arg: b,
        }));
    }
    // A few compositions (transcendental results feeding vector ops and back).
    let s = g.unary(Unary::Sin, a);
    let e = g.binary(Binary::Mul, s, b);
    let m = g.binary(Binary::Max, e, c);
    let t = g.add(Node::Table {
        table,
        deriv: 1,
        arg: m,
    });
    let p = g.binary(Binary::Pow, t, d);
    out.push(p);
    // Constant and input outputs.
    let k = g.constant(3.5);
    out.push(k);
    out.push(a);
    out.push(b);
    out
}

const ALL_LAYOUTS: [[Layout; 2]; 4] = [
    [Layout::Lanes, Layout::Lanes],
    [Layout::Scalar, Layout::Lanes],
    [Layout::Lanes, Layout::Scalar],
    [Layout::Scalar, Layout::Scalar],
];

fn specs(outputs: &[NodeId]) -> Vec<FunctionSpec> {
    ALL_LAYOUTS
        .iter()
        .map(|l| FunctionSpec {
            args: l.to_vec(),
            outputs: outputs.to_vec(),
        })
        .collect()
}

// ----------------------------------------------------------------------------------------------
// Tests.

#[test]
fn every_operation_is_bit_identical() {
    let mut g = Graph::new();
    let out = all_ops(&mut g);
    check(&g, &specs(&out), &[2, 2], 400, 1, Rng::value);
}

#[test]
fn henon_heiles_gradient_and_hvp() {
    let mut g = Graph::new();
    let (grad, hvp) = henon_heiles(&mut g);
    let mut all = specs(&grad);
    all.extend(specs(&hvp));
    check(&g, &all, &[2, 2], 300, 2, Rng::value);
    check(&g, &all, &[2, 2], 300, 3, Rng::moderate);
}

#[test]
fn fput_chain_n5() {
    let mut g = Graph::new();
    let (grad, hvp) = fput(&mut g, 5, 0.7);
    let mut all = specs(&grad);
    all.extend(specs(&hvp));
    check(&g, &all, &[5, 5], 200, 4, Rng::value);
    check(&g, &all, &[5, 5], 200, 5, Rng::moderate);
}

#[test]
fn fput_chain_n1001() {
    let mut g = Graph::new();
    let (grad, hvp) = fput(&mut g, 1001, 0.7);
    let all = vec![
        FunctionSpec {
            args: vec![Layout::Lanes, Layout::Scalar],
            outputs: grad.clone(),
        },
        FunctionSpec {
            args: vec![Layout::Lanes, Layout::Lanes],
            outputs: hvp.clone(),
        },
        FunctionSpec {
            args: vec![Layout::Scalar, Layout::Lanes],
            outputs: hvp.clone(),
        },
    ];
    check(&g, &all, &[1001, 1001], 6, 6, Rng::moderate);
    check(&g, &all, &[1001, 1001], 3, 7, Rng::value);
}

/// The HVP at a shared reference position (`q` a `Scalar` argument: the stiffnesses are computed
/// once before the lane loop) gives the same bits as the same position replicated in every lane.
#[test]
fn uniform_hoisting_gives_the_same_bits() {
    let mut g = Graph::new();
    let (_, hvp) = fput(&mut g, 37, 1.3);
    let spec = |q| FunctionSpec {
        args: vec![q, Layout::Lanes],
        outputs: hvp.clone(),
    };
    let c = jit::compile(&g, &[spec(Layout::Scalar), spec(Layout::Lanes)]).unwrap();
    let mut rng = Rng(8);
    for lanes in [1, 2, 3, 8, 17, 64] {
        let q: Vec<f64> = (0..37).map(|_| rng.moderate()).collect();
        let v: Vec<f64> = (0..37 * lanes).map(|_| rng.moderate()).collect();
        let q_rep: Vec<f64> = (0..37 * lanes).map(|k| q[k / lanes]).collect();
        let mut hoisted = vec![0.0; 37 * lanes];
        let mut replicated = vec![0.0; 37 * lanes];
        c.call_lanes(0, &[&q, &v], &mut hoisted, lanes);
        c.call_lanes(1, &[&q_rep, &v], &mut replicated, lanes);
        for (x, y) in hoisted.iter().zip(&replicated) {
            assert_eq!(x.to_bits(), y.to_bits());
        }
    }
}

#[test]
fn compiled_functions_are_send_sync_and_usable_across_threads() {
    fn assert_send_sync<T: Send + Sync>() {}
    assert_send_sync::<jit::Compiled>();
    let mut g = Graph::new();
    let (grad, _) = henon_heiles(&mut g);
    let c = jit::compile(
        &g,
        &[FunctionSpec {
            args: vec![Layout::Lanes],
            outputs: grad,
        }],
    )
    .unwrap();
    std::thread::scope(|s| {
        for t in 0..2 {
            let c = &c;
            s.spawn(move || {
                let q = [0.1 * t as f64, 0.2];
                let mut out = [0.0; 2];
                c.call(0, &[&q], &mut out);
                assert_eq!(out[0], q[0] + 2.0 * q[0] * q[1]);
            });
        }
    });
}

#[test]
fn errors_not_panics() {
    let mut g = Graph::new();
    let x = g.input(2, 0);
    let e = jit::compile(
        &g,
        &[FunctionSpec {
            args: vec![Layout::Scalar],
            outputs: vec![x],
        }],
    )
    .unwrap_err();
    assert!(e.to_string().contains("argument 2"), "{e}");
    let e = jit::compile(
        &g,
        &[FunctionSpec {
            args: vec![],
            outputs: vec![99],
        }],
    )
    .unwrap_err();
    assert!(e.to_string().contains("node 99"), "{e}");
}

#[test]
#[should_panic(expected = "output has 3 entries, expected 2")]
fn wrong_output_length_panics() {
    let mut g = Graph::new();
    let (grad, _) = henon_heiles(&mut g);
    let c = jit::compile(
        &g,
        &[FunctionSpec {
            args: vec![Layout::Lanes],
            outputs: grad,
        }],
    )
    .unwrap();
    c.call(0, &[&[1.0, 2.0]], &mut [0.0; 3]);
}

#[test]
#[should_panic(expected = "lane argument 0 has 5 entries")]
fn wrong_lane_argument_length_panics() {
    let mut g = Graph::new();
    let (grad, _) = henon_heiles(&mut g);
    let c = jit::compile(
        &g,
        &[FunctionSpec {
            args: vec![Layout::Lanes],
            outputs: grad,
        }],
    )
    .unwrap();
    c.call_lanes(0, &[&[1.0; 5]], &mut [0.0; 6], 3);
}

#[test]
fn zero_lanes_and_empty_functions() {
    let mut g = Graph::new();
    let k = g.constant(2.5);
    let c = jit::compile(
        &g,
        &[
            FunctionSpec {
                args: vec![],
                outputs: vec![k],
            },
            FunctionSpec {
                args: vec![Layout::Lanes],
                outputs: vec![],
            },
        ],
    )
    .unwrap();
    let mut out = [0.0; 3];
    c.call_lanes(0, &[], &mut out, 3);
    assert_eq!(out, [2.5; 3]);
    c.call_lanes(0, &[], &mut [], 0);
    c.call(1, &[&[]], &mut []);
    c.call_lanes(1, &[&[0.0; 4]], &mut [], 4);
}

/// With the default options a small and a large function land in different code modules
/// (`speed` and `none`); both must still match the reference.
#[test]
fn small_and_large_functions_in_one_compile() {
    let mut g = Graph::new();
    let (hh, _) = henon_heiles(&mut g);
    let mut g2 = g.clone();
    let (chain, _) = fput(&mut g2, 1001, 0.7);
    let specs = vec![
        FunctionSpec {
            args: vec![Layout::Lanes, Layout::Lanes],
            outputs: hh,
        },
        FunctionSpec {
            args: vec![Layout::Lanes, Layout::Lanes],
            outputs: chain,
        },
    ];
    let c = jit::compile(&g2, &specs).unwrap();
    let mut rng = Rng(9);
    for lanes in [1, 3, 8, 33] {
        let args: Vec<Vec<f64>> = (0..2)
            .map(|_| (0..1001 * lanes).map(|_| rng.moderate()).collect())
            .collect();
        let refs: Vec<&[f64]> = args.iter().map(|a| a.as_slice()).collect();
        for (f, spec) in specs.iter().enumerate() {
            let n_out = spec.outputs.len();
            let mut out = vec![0.0; n_out * lanes];
            c.call_lanes(f, &refs, &mut out, lanes);
            for l in 0..lanes {
                let lane: Vec<Vec<f64>> = args
                    .iter()
                    .map(|a| (0..1001).map(|i| a[i * lanes + l]).collect())
                    .collect();
                let lane_refs: Vec<&[f64]> = lane.iter().map(|a| a.as_slice()).collect();
                let want = reference(&g2, &lane_refs, &spec.outputs);
                let got: Vec<f64> = (0..n_out).map(|j| out[j * lanes + l]).collect();
                assert_same(&format!("f{f} lanes={lanes} lane {l}"), &got, &want, &"");
            }
        }
    }
}

/// The raw lane function over groups of consecutive lanes of a wider array (`stride > lanes`)
/// gives the same bits as one call over all lanes.
#[test]
fn lane_groups_with_a_stride() {
    let mut g = Graph::new();
    let (grad, hvp) = fput(&mut g, 37, 0.9);
    let specs = [
        FunctionSpec {
            args: vec![Layout::Lanes, Layout::Lanes],
            outputs: grad,
        },
        FunctionSpec {
            args: vec![Layout::Scalar, Layout::Lanes],
            outputs: hvp,
        },
    ];
    for lane_block in [2, 4] {
        let options = Options {
            lane_block,
            ..Options::default()
        };
        let c = jit::compile_with(&g, &specs, &options).unwrap();
        let mut rng = Rng(10);
        let total = 23;
        for f in 0..2 {
            let q: Vec<f64> = (0..37 * total).map(|_| rng.moderate()).collect();
            let v: Vec<f64> = (0..37 * total).map(|_| rng.moderate()).collect();
            let mut whole = vec![0.0; 37 * total];
            c.call_lanes(f, &[&q, &v], &mut whole, total);
            let mut grouped = vec![f64::NAN; 37 * total];
            let raw = c.raw_lanes(f);
            let mut first = 0;
            for count in [2, 3, 5, 4, 9] {
                let q_ptr = if f == 0 {
                    q[first..].as_ptr()
                } else {
                    q.as_ptr()
                };
                let ptrs = [q_ptr, v[first..].as_ptr()];
                // SAFETY: lanes `first .. first + count` of arrays of 37 rows x `total` lanes,
                // stride `total`; the output does not overlap the arguments.
                unsafe { raw(ptrs.as_ptr(), grouped[first..].as_mut_ptr(), count, total) };
                first += count;
            }
            assert_eq!(first, total);
            for (x, y) in whole.iter().zip(&grouped) {
                assert_eq!(x.to_bits(), y.to_bits());
            }
        }
    }
}

/// The gradient and Hessian-vector product of a product of `n` factors written as a user would
/// (`(1 + 0.0001*q[1])*(1 + 0.0001*q[2])*...`, over three variables).
fn product(g: &mut Graph, n: usize) -> (Vec<NodeId>, Vec<NodeId>) {
    let factors: Vec<String> = (0..n)
        .map(|i| format!("(1 + 0.0001*q[{}])", 1 + i % 3))
        .collect();
    let source = format!("0.5*(q1^2 + q2^2 + q3^2) + 0.001*{}", factors.join("*"));
    let families = [chaoscope_expr::Family {
        name: "q".into(),
        len: 3,
        arg: 0,
        offset: 0,
    }];
    let params = std::collections::BTreeMap::new();
    let scope = chaoscope_expr::Scope {
        families: &families,
        params: &params,
        tables: &[],
        n: 3,
        boundary: chaoscope_expr::Boundary::Fixed,
        shape: chaoscope_expr::lower::Shape::Chain,
        time: None,
    };
    let root = chaoscope_expr::lower(&source, &scope, g).unwrap().root;
    let grad = chaoscope_expr::gradient(g, root, 0, 3).unwrap();
    let hvp = chaoscope_expr::jacobian_vector(g, &grad, 0, 1).unwrap();
    (grad, hvp)
}

/// Compilation time is linear in the expression's size, shown by what it is made of rather than
/// by a clock: the operations compiled grow in proportion to the factors of a product, and the
/// live span handed to the backtracking register allocator (superlinear in it: a product of
/// 1000 factors took 38 s) stays within `MAX_MEAN_LIVE` per operation. A product keeps every
/// partial product live for its gradient, so it goes to the single-pass allocator (span 0 for
/// backtracking); an FPUT chain's values live a few operations, so it keeps the backtracking
/// allocator and its better code. `benches/jit.rs` (`compile product`) times it.
#[test]
fn compile_work_is_linear_in_the_size_of_a_product() {
    let mut per_factor = Vec::new();
    for n in [250usize, 500, 1000, 2000] {
        let mut g = Graph::new();
        let (grad, hvp) = product(&mut g, n);
        let c = jit::compile(&g, &specs_of(&grad, &hvp)).unwrap();
        let work = c.allocation_work();
        assert_eq!(work.backtracking_live_span, 0, "n = {n}: {work:?}");
        // The splitting step kernels (the batched kernel's): the Hessian's entries, uniform
        // over the lanes, are computed before the lane loop and keep as many values live.
        let steps = jit::compile_steps(
            &g,
            &jit::StepSpec {
                n: 3,
                gradient: grad.clone(),
                hessian_vector: Some(hvp.clone()),
            },
            &Options::default(),
        )
        .unwrap();
        let step_work = steps.allocation_work();
        assert_eq!(
            step_work.backtracking_live_span, 0,
            "n = {n}: {step_work:?}"
        );
        per_factor.push(work.operations as f64 / n as f64);
    }
    // Operations per factor: constant to within 2% from 250 to 2000 factors (the terms that do
    // not grow with n, the quadratic part and the sums of the gradient, are a few dozen).
    let (lo, hi) = (
        per_factor.iter().copied().fold(f64::INFINITY, f64::min),
        per_factor.iter().copied().fold(0.0, f64::max),
    );
    assert!(hi / lo < 1.02, "operations per factor {per_factor:?}");

    let mut g = Graph::new();
    let (grad, hvp) = fput(&mut g, 1001, 0.7);
    let work = jit::compile(&g, &specs_of(&grad, &hvp))
        .unwrap()
        .allocation_work();
    assert!(
        work.backtracking_live_span > 0 && work.backtracking_live_span < 8 * work.operations,
        "the FPUT chain keeps the backtracking allocator, its values short-lived: {work:?}"
    );

    // The single-pass allocator only places values: the same bits as the reference.
    let mut g = Graph::new();
    let (grad, hvp) = product(&mut g, 300);
    let mut all = specs(&grad);
    all.extend(specs(&hvp));
    check(&g, &all, &[3, 3], 50, 8, Rng::moderate);
}

fn specs_of(grad: &[NodeId], hvp: &[NodeId]) -> Vec<FunctionSpec> {
    vec![
        FunctionSpec {
            args: vec![Layout::Scalar],
            outputs: grad.to_vec(),
        },
        FunctionSpec {
            args: vec![Layout::Scalar, Layout::Lanes],
            outputs: hvp.to_vec(),
        },
    ]
}

// ----------------------------------------------------------------------------------------------
// Lattice sums as loops: the compiled potential, gradient and Hessian-vector product against
// the lattice's reference evaluation, bit for bit.

mod lattice_loops {
    use std::collections::BTreeMap;
    use std::sync::Arc;

    use chaoscope_expr::Graph;
    use chaoscope_expr::graph::Tabulated;
    use chaoscope_expr::jit::OptLevel;
    use chaoscope_expr::jit::{self, LATTICE_GRADIENT, LATTICE_HESSIAN_VECTOR, LATTICE_POTENTIAL};
    use chaoscope_expr::lattice::{LatticeEvaluator, LatticePotential};
    use chaoscope_expr::lower::{Boundary, Family, ParamValue, Scope, Shape, lower_with_loops};
    use chaoscope_expr::table::{Spline, SplineEnds};

    use super::Rng;

    /// Bit for bit, except that any NaN equals any NaN: when two contributions to one site are
    /// both NaN, x86 returns the first operand's payload, and the Rust compiler is free to
    /// commute the reference's `acc + d` (every non-NaN result, signed zeros included, is
    /// compared by its bits).
    fn assert_same(what: &str, got: &[f64], want: &[f64], inputs: &dyn std::fmt::Debug) {
        assert_eq!(got.len(), want.len(), "{what}: length");
        for (j, (&x, &y)) in got.iter().zip(want).enumerate() {
            assert!(
                x.to_bits() == y.to_bits() || (x.is_nan() && y.is_nan()),
                "{what}: output {j}: got {x:e} ({:#018x}), want {y:e} ({:#018x}); inputs {inputs:?}",
                x.to_bits(),
                y.to_bits()
            );
        }
    }

    fn lattice(n: usize, boundary: Boundary, src: &str) -> (Graph, LatticePotential) {
        lattice_shaped(n, boundary, Shape::Chain, src)
    }

    /// [`lattice`] of any shape, `side` its `N` (a square's side).
    fn lattice_shaped(
        side: usize,
        boundary: Boundary,
        shape: Shape,
        src: &str,
    ) -> (Graph, LatticePotential) {
        let n = shape.sites(side).unwrap();
        let mut g = Graph::new();
        // A table defined on [-50, 50]: U(x) = x^2 / (1 + x^2/100), sampled.
        let xs: Vec<f64> = (0..=200).map(|k| -50.0 + 0.5 * k as f64).collect();
        let ys: Vec<f64> = xs.iter().map(|x| x * x / (1.0 + x * x / 100.0)).collect();
        let u: Arc<dyn Tabulated> =
            Arc::new(Spline::new("U", &xs, &ys, SplineEnds::Natural).unwrap());
        let tables = vec![("U".to_string(), g.add_table(u))];
        let mut params = BTreeMap::new();
        params.insert("beta".to_string(), ParamValue::Scalar(1.3));
        params.insert(
            "k".to_string(),
            ParamValue::Array(
                (0..n)
                    .map(|j| 0.5 + (j as f64 * 0.37).sin().abs())
                    .collect(),
            ),
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
        let l = lower_with_loops(src, &scope, &mut g).unwrap_or_else(|e| panic!("{e}"));
        assert!(!l.sums.is_empty(), "{src}: no loop");
        let lp = LatticePotential::new(&mut g, l.root, l.sums, n, true)
            .unwrap()
            .expect("affine in its sums");
        (g, lp)
    }

    const CASES: &[(Boundary, &str)] = &[
        (
            Boundary::Fixed,
            "sum(i = 0..N, (q[i+1] - q[i])^2/2 + beta/4*(q[i+1] - q[i])^4)",
        ),
        (
            Boundary::Free,
            "sum(i = 1..N, k[i]/2*q[i]^2 + q[i]^4/4) + sum(i = 1..N, (q[i+1] - q[i])^2/(2*4))",
        ),
        (
            Boundary::Periodic,
            "sum(i = 1..N, exp(q[i+1] - q[i]) - (q[i+1] - q[i]) - 1)",
        ),
        // Every operation of the language in one term, tables and array parameters, a rest
        // around the sums, coefficients -1 and 0.25, a slot two sites back.
        (
            Boundary::Periodic,
            "q1^2*q2 - sum(i = 1..N, sin(q[i])*cos(q[i+1]) + sqrt(1 + q[i]^2) + abs(q[i+1]) \
             + max(q[i], 0.5*q[i+1])^3 + min(q[i-2], -q[i]) + if(q[i] < q[i+1], q[i]^2, tanh(q[i])) \
             + piecewise(q[i] >= 1, step(q[i]), q[i] <= -1, sign(q[i+1]), atan(q[i])) \
             + atan2(q[i], 1 + q[i+1]^2) + (2 + q[i]^2)^1.5 + q[i]^q[i+1] + log(3 + q[i+1]) \
             + tan(q[i]/4) + cosh(q[i]) - sinh(q[i+1]) + k[i+1]*q[i]^3/(1 + q[i-2]^2)) \
             + sum(j = 1..N, U(q[j+1] - q[j]))/4",
        ),
        (
            Boundary::Fixed,
            "sum(i = -1..N+2, (q[i+2] - q[i-1])^2 + q[i]*q[i+1]*q[i+2]) + q3^4",
        ),
    ];

    #[test]
    fn compiled_loops_are_the_reference_evaluation_bit_for_bit() {
        for &(boundary, src) in CASES {
            for n in [1, 2, 3, 5, 17, 64] {
                if (src.contains("q3") && n < 3) || (src.contains("q2") && n < 2) {
                    continue;
                }
                let (g, lp) = lattice(n, boundary, src);
                compiled_is_reference(&g, &lp, &format!("{boundary:?} N = {n}: {src}"));
            }
        }
    }

    /// The compiled potential, gradient and Hessian-vector product against the reference
    /// evaluation, unoptimized and optimized, at moderate and special values.
    fn compiled_is_reference(g: &Graph, lp: &LatticePotential, name: &str) {
        let n = lp.n;
        for opt_level in [OptLevel::None, OptLevel::Speed] {
            let options = jit::Options {
                opt_level,
                ..jit::Options::default()
            };
            let c = jit::compile_lattice(g, lp, &options).unwrap();
            let mut e = LatticeEvaluator::new(g, lp);
            let mut rng = Rng(n as u64 * 7919);
            for sample in 0..20 {
                // Moderate values mostly; special ones (NaN, infinities, zeros of both signs)
                // in a few samples.
                let draw = |rng: &mut Rng| {
                    if sample % 5 == 4 {
                        rng.value()
                    } else {
                        rng.moderate()
                    }
                };
                let q: Vec<f64> = (0..n).map(|_| draw(&mut rng)).collect();
                let v: Vec<f64> = (0..n).map(|_| draw(&mut rng)).collect();
                let what = format!("{name} {opt_level:?}");
                let mut got = vec![0.0; 1];
                c.call(LATTICE_POTENTIAL, &[&q], &mut got);
                assert_same(&format!("{what}: V"), &got, &[e.potential(&q)], &q);
                let (mut got, mut want) = (vec![0.0; n], vec![0.0; n]);
                c.call(LATTICE_GRADIENT, &[&q], &mut got);
                e.gradient(&q, &mut want);
                assert_same(&format!("{what}: gradient"), &got, &want, &q);
                c.call(LATTICE_HESSIAN_VECTOR, &[&q, &v], &mut got);
                e.hessian_vector(&q, &v, &mut want);
                assert_same(&format!("{what}: Hv"), &got, &want, &(&q, &v));
            }
        }
    }

    /// A square lattice's sums, loops along its rows: every boundary pair, a term reaching two
    /// rows and two columns, a table and an array parameter read at a shift along both axes.
    #[test]
    fn compiled_square_loops_are_the_reference_evaluation_bit_for_bit() {
        let kg = "sum(i = 1..N, sum(j = 1..N, k[i, j]/2*q[i, j]^2 + q[i, j]^4/4)) \
                  + sum(i = 1..N, sum(j = 1..N, ((q[i+1, j] - q[i, j])^2 + (q[i, j+1] - q[i, j])^2)/8))";
        let far = "q[1, 2]^2 - sum(i = 1..N, sum(j = 1..N, U(q[i+2, j] - q[i, j-2]) \
                   * (1 + q[i-1, j+1]^2) + k[i+1, j-1]*sin(q[i, j])))";
        let mut compiled = 0;
        for side in [2, 3, 5, 8] {
            for rows in [Boundary::Fixed, Boundary::Free, Boundary::Periodic] {
                for columns in [Boundary::Fixed, Boundary::Free, Boundary::Periodic] {
                    let shape = Shape::Square { columns };
                    let mut cases = vec![kg];
                    if rows == Boundary::Periodic && columns == Boundary::Periodic && side >= 5 {
                        cases.push(far);
                    }
                    for src in cases {
                        let (g, lp) = lattice_shaped(side, rows, shape, src);
                        let what = format!("{side} x {side} {rows:?} x {columns:?}: {src}");
                        assert!(lp.sums.iter().all(|s| s.side == Some(side)), "{what}");
                        compiled_is_reference(&g, &lp, &what);
                        compiled += 1;
                    }
                }
            }
        }
        assert_eq!(compiled, 4 * 9 + 2);
    }

    #[test]
    fn a_chain_of_a_hundred_thousand_sites_compiles_to_the_code_of_one_term() {
        let fput = CASES[0].1;
        let time = |n: usize| {
            let (g, lp) = lattice(n, Boundary::Fixed, fput);
            let c = jit::compile_lattice(&g, &lp, &jit::Options::default()).unwrap();
            let q: Vec<f64> = (0..n).map(|j| 0.1 * (j as f64 * 0.3).sin()).collect();
            let mut out = vec![0.0; n];
            c.call(LATTICE_GRADIENT, &[&q], &mut out);
            let mut want = vec![0.0; n];
            LatticeEvaluator::new(&g, &lp).gradient(&q, &mut want);
            assert_same("N = 10^5 gradient", &out, &want, &n);
            (g.len(), c.compile_time())
        };
        let (small_nodes, _) = time(100);
        let (large_nodes, compile) = time(100_000);
        // The same graph whatever N (the term, its derivatives), and milliseconds of code
        // generation (the timing itself is the bench's business; this catches an unrolling).
        assert_eq!(small_nodes, large_nodes);
        assert!(compile.as_secs_f64() < 5.0, "{compile:?}");
    }

    /// The register allocator of the loops' functions follows the rule of the unrolled ones
    /// (`compile_work_is_linear_in_the_size_of_a_product`): a rest around the sums that is a
    /// product of 300 factors keeps every partial product live for its gradient (mean live span
    /// about a third of its operations, far above `MAX_MEAN_LIVE`), so the scalar functions and
    /// the step kernels get the single-pass allocator (no span given to backtracking); an FPUT
    /// sum's term keeps its values live a few operations and keeps backtracking. The
    /// single-pass allocator only places values: the reference's bits.
    #[test]
    fn long_lived_values_around_the_sums_get_the_single_pass_allocator() {
        let factors: Vec<String> = (0..300)
            .map(|i| format!("(1 + 0.0001*q[{}])", 1 + i % 3))
            .collect();
        let src = format!(
            "0.001*{} + sum(i = 0..N, (q[i+1] - q[i])^2/2 + beta/4*(q[i+1] - q[i])^4)",
            factors.join("*")
        );
        let n = 5;
        let (g, lp) = lattice(n, Boundary::Fixed, &src);
        let c = jit::compile_lattice(&g, &lp, &jit::Options::default()).unwrap();
        let work = c.allocation_work();
        assert!(work.operations > 300, "{work:?}");
        assert_eq!(work.backtracking_live_span, 0, "{work:?}");
        let steps = jit::compile_lattice_steps(&g, &lp, &jit::Options::default()).unwrap();
        let step_work = steps.allocation_work();
        assert!(step_work.operations > 300, "{step_work:?}");
        assert_eq!(step_work.backtracking_live_span, 0, "{step_work:?}");
        let mut e = LatticeEvaluator::new(&g, &lp);
        let mut rng = Rng(17);
        for _ in 0..20 {
            let q: Vec<f64> = (0..n).map(|_| rng.moderate()).collect();
            let v: Vec<f64> = (0..n).map(|_| rng.moderate()).collect();
            let (mut got, mut want) = (vec![0.0; n], vec![0.0; n]);
            c.call(LATTICE_GRADIENT, &[&q], &mut got);
            e.gradient(&q, &mut want);
            assert_same("product rest: gradient", &got, &want, &q);
            c.call(LATTICE_HESSIAN_VECTOR, &[&q, &v], &mut got);
            e.hessian_vector(&q, &v, &mut want);
            assert_same("product rest: Hv", &got, &want, &(&q, &v));
        }

        let (g, lp) = lattice(n, Boundary::Fixed, CASES[0].1);
        let c = jit::compile_lattice(&g, &lp, &jit::Options::default()).unwrap();
        let work = c.allocation_work();
        assert!(
            work.backtracking_live_span > 0 && work.backtracking_live_span < 8 * work.operations,
            "an FPUT term keeps the backtracking allocator: {work:?}"
        );
        let steps = jit::compile_lattice_steps(&g, &lp, &jit::Options::default()).unwrap();
        assert!(steps.allocation_work().backtracking_live_span > 0);
    }
}
