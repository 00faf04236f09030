//! Compile time and evaluation throughput of `jit` against hand-written Rust loops of the same
//! formulas over the same structure-of-arrays rows. One JSON object per line; every line carries
//! the CPU model and the ISA features Cranelift generated code for.
//!
//! `cargo bench -p chaoscope-expr --bench jit` (or run the bench binary with `--quick`).

use std::hint::black_box;
use std::time::{Duration, Instant};

use chaoscope_expr::jit::{self, Compiled, FunctionSpec, Layout, OptLevel, Options};
use chaoscope_expr::{Graph, NodeId};

fn cpu_model() -> String {
    std::fs::read_to_string("/proc/cpuinfo")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("model name"))
                .and_then(|l| l.split(':').nth(1))
                .map(|m| m.trim().to_string())
        })
        .unwrap_or_else(|| "unknown".into())
}

/// The host's vector extensions as the Rust side sees them (the hand-written loops are compiled
/// for the default target, x86-64 baseline SSE2, unless RUSTFLAGS say otherwise).
fn rust_target_features() -> String {
    let mut f = Vec::new();
    if cfg!(target_feature = "sse4.1") {
        f.push("sse4.1");
    }
    if cfg!(target_feature = "avx") {
        f.push("avx");
    }
    if cfg!(target_feature = "avx2") {
        f.push("avx2");
    }
    if cfg!(target_feature = "fma") {
        f.push("fma");
    }
    if cfg!(target_feature = "avx512f") {
        f.push("avx512f");
    }
    if f.is_empty() {
        "baseline".into()
    } else {
        f.join(",")
    }
}

fn esc(s: &str) -> String {
    s.replace('\\', "\\\\").replace('"', "\\\"")
}

struct Env {
    cpu: String,
    isa: String,
    rust: String,
}

impl Env {
    fn line(&self, fields: &str) {
        println!(
            "{{{fields},\"cpu\":\"{}\",\"jit_isa\":\"{}\",\"rust_target_features\":\"{}\"}}",
            esc(&self.cpu),
            esc(&self.isa),
            esc(&self.rust)
        );
    }
}

// ----------------------------------------------------------------------------------------------
// The graphs (as in tests/jit.rs).

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

/// Gradient (`q` per lane) and HVP (shared reference `q`, `v` per lane), as the variational
/// kernel calls them.
/// `(q1^2 + q2^2 + q3^2)/2 + 0.001 prod_{i<n} (1 + 0.0001 q_(i mod 3))`, written as the
/// expression a user would write: its gradient and Hessian-vector product.
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
    let root = chaoscope_expr::lower(&source, &scope, g)
        .expect("the product lowers")
        .root;
    let grad = chaoscope_expr::gradient(g, root, 0, 3).expect("gradient");
    let hvp = chaoscope_expr::jacobian_vector(g, &grad, 0, 1).expect("HVP");
    (grad, hvp)
}

fn specs(grad: &[NodeId], hvp: &[NodeId]) -> Vec<FunctionSpec> {
    vec![
        FunctionSpec {
            args: vec![Layout::Lanes],
            outputs: grad.to_vec(),
        },
        FunctionSpec {
            args: vec![Layout::Scalar, Layout::Lanes],
            outputs: hvp.to_vec(),
        },
    ]
}

// ----------------------------------------------------------------------------------------------
// Hand-written models over the same SoA rows (same operations in the same order).

#[inline(never)]
fn hh_grad_soa(q: &[f64], out: &mut [f64], lanes: usize) {
    let (q1, q2) = q.split_at(lanes);
    let (o1, o2) = out.split_at_mut(lanes);
    for l in 0..lanes {
        let (a, b) = (q1[l], q2[l]);
        o1[l] = a + 2.0 * a * b;
        o2[l] = b + a * a - b * b;
    }
}

#[inline(never)]
fn fput_grad_soa(q: &[f64], out: &mut [f64], n: usize, lanes: usize, beta: f64, zero: &[f64]) {
    let row = |i: isize| -> &[f64] {
        if i < 0 || i >= n as isize {
            zero
        } else {
            &q[i as usize * lanes..(i as usize + 1) * lanes]
        }
    };
    for (i, o) in out.chunks_exact_mut(lanes).enumerate() {
        let (qm, q0, qp) = (row(i as isize - 1), row(i as isize), row(i as isize + 1));
        for l in 0..lanes {
            let r0 = q0[l] - qm[l];
            let r1 = qp[l] - q0[l];
            o[l] = (r0 + beta * (r0 * r0 * r0)) - (r1 + beta * (r1 * r1 * r1));
        }
    }
}

// ----------------------------------------------------------------------------------------------
// Timing.

/// Time per call of `a` and of `b`, measured in alternating short runs so that both see the
/// same interference (this machine is shared): the minimum over runs of each (the least
/// disturbed estimate) and the median of the per-round ratio `a / b`.
fn time_pair(
    mut a: impl FnMut(),
    mut b: impl FnMut(),
    min_run: Duration,
    rounds: usize,
) -> (f64, f64, f64) {
    let mut iters = 1u64;
    loop {
        let t = Instant::now();
        for _ in 0..iters {
            a();
        }
        if t.elapsed() >= min_run {
            break;
        }
        iters *= 2;
    }
    let run = |f: &mut dyn FnMut()| {
        let t = Instant::now();
        for _ in 0..iters {
            f();
        }
        t.elapsed().as_secs_f64() / iters as f64
    };
    let (mut ta, mut tb, mut ratio) = (Vec::new(), Vec::new(), Vec::new());
    for _ in 0..rounds {
        let x = run(&mut a);
        let y = run(&mut b);
        ta.push(x);
        tb.push(y);
        ratio.push(x / y);
    }
    ratio.sort_by(f64::total_cmp);
    let min = |v: &[f64]| v.iter().copied().fold(f64::INFINITY, f64::min);
    (min(&ta), min(&tb), ratio[rounds / 2])
}

/// The hot-path call: the raw lane function with argument pointers prepared once, as the
/// batched kernel will call it (one call over all lanes, `stride == lanes`).
fn lanes_call(c: &Compiled, f: usize, ptrs: &[*const f64], out: &mut [f64], lanes: usize) {
    let raw = c.raw_lanes(f);
    // SAFETY: the arrays behind `ptrs` and `out` have the sizes `call_lanes` checked once on the
    // same arrays before timing.
    unsafe { raw(ptrs.as_ptr(), out.as_mut_ptr(), lanes, lanes) }
}

/// (opt_level, its name, lanes per loop iteration, size threshold) measured: each setting on
/// every function, then the defaults (`speed`, 4 lanes, but `none` above 2000 operations).
const CONFIGS: [(OptLevel, &str, usize, usize); 5] = [
    (OptLevel::None, "none", 2, usize::MAX),
    (OptLevel::None, "none", 4, usize::MAX),
    (OptLevel::Speed, "speed", 2, usize::MAX),
    (OptLevel::Speed, "speed", 4, usize::MAX),
    (OptLevel::Speed, "default", 4, 2000),
];

fn main() {
    let quick = std::env::args().any(|a| a == "--quick");
    // Optional filters (e.g. `compile`, `eval`, `fput1001`, `henon_heiles`): a case runs if every
    // filter matches its kind or its system name (`fput` + N).
    let filters: Vec<String> = std::env::args()
        .skip(1)
        .filter(|a| !a.starts_with("--"))
        .collect();
    let wanted = |kind: &str, system: &str| {
        filters
            .iter()
            .all(|f| f == kind || system.contains(f.as_str()))
    };
    let (min_run, runs) = if quick {
        (Duration::from_millis(2), 9)
    } else {
        (Duration::from_millis(5), 41)
    };
    let probe = {
        let mut g = Graph::new();
        let (gr, hv) = henon_heiles(&mut g);
        jit::compile(&g, &specs(&gr, &hv)).expect("compiles")
    };
    let env = Env {
        cpu: cpu_model(),
        isa: probe.isa().to_string(),
        rust: rust_target_features(),
    };

    // Compile time of products of n factors (gradient and Hessian-vector product): every
    // partial product is live at once in the gradient, the case that made register allocation
    // superlinear (a product of 1000 factors took 38 s with the backtracking allocator). Linear
    // means `seconds_per_operation` about constant across n.
    if wanted("compile", "product") {
        for n in [250usize, 500, 1000, 2000, 4000] {
            let mut g = Graph::new();
            let (gr, hv) = product(&mut g, n);
            let c = jit::compile(&g, &specs(&gr, &hv)).expect("compiles");
            let work = c.allocation_work();
            let seconds = c.compile_time().as_secs_f64();
            env.line(&format!(
                "\"kind\":\"compile\",\"system\":\"product{n}\",\"factors\":{n},\
                 \"operations\":{},\"backtracking_live_span\":{},\"seconds\":{seconds:.4},\
                 \"seconds_per_operation\":{:.3e}",
                work.operations,
                work.backtracking_live_span,
                seconds / work.operations as f64
            ));
        }
    }

    // Compile times.
    for (name, n) in [("henon_heiles", 0u32), ("fput", 101), ("fput", 1001)] {
        let system = if n == 0 {
            name.to_string()
        } else {
            format!("{name}{n}")
        };
        if !wanted("compile", &system) {
            continue;
        }
        let mut g = Graph::new();
        let (gr, hv) = if n == 0 {
            henon_heiles(&mut g)
        } else {
            fput(&mut g, n, 0.7)
        };
        for (opt, label, lane_block, large_function) in CONFIGS {
            let mut times: Vec<f64> = (0..if quick { 1 } else { 3 })
                .map(|_| {
                    jit::compile_with(
                        &g,
                        &specs(&gr, &hv),
                        &Options {
                            opt_level: opt,
                            lane_block,
                            large_function,
                            ..Options::default()
                        },
                    )
                    .expect("compiles")
                    .compile_time()
                    .as_secs_f64()
                })
                .collect();
            times.sort_by(f64::total_cmp);
            let one = |spec: FunctionSpec| {
                jit::compile_with(
                    &g,
                    &[spec],
                    &Options {
                        opt_level: opt,
                        lane_block,
                        large_function,
                        ..Options::default()
                    },
                )
                .expect("compiles")
                .compile_time()
                .as_secs_f64()
                    * 1e3
            };
            let [grad_spec, hvp_spec]: [FunctionSpec; 2] =
                specs(&gr, &hv).try_into().expect("two specs");
            let (t_grad, t_hvp) = (one(grad_spec), one(hvp_spec));
            env.line(&format!(
                "\"bench\":\"compile\",\"system\":\"{name}\",\"n\":{n},\"graph_nodes\":{},\
                 \"functions\":\"grad+hvp (scalar+lanes each)\",\"opt_level\":\"{label}\",\"lane_block\":{lane_block},\
                 \"compile_ms\":{:.3},\"grad_only_ms\":{t_grad:.3},\"hvp_only_ms\":{t_hvp:.3}",
                g.len(),
                times[times.len() / 2] * 1e3
            ));
        }
    }

    // Throughput: HH gradient.
    if wanted("eval", "henon_heiles") {
        let mut g = Graph::new();
        let (gr, hv) = henon_heiles(&mut g);
        for (opt, label, lane_block, large_function) in CONFIGS {
            let c = jit::compile_with(
                &g,
                &specs(&gr, &hv),
                &Options {
                    opt_level: opt,
                    lane_block,
                    large_function,
                    ..Options::default()
                },
            )
            .unwrap();
            for lanes in [8usize, 16, 64, 256] {
                let q: Vec<f64> = (0..2 * lanes).map(|k| 0.01 * k as f64 - 0.3).collect();
                let mut out = vec![0.0; 2 * lanes];
                let mut hand = vec![0.0; 2 * lanes];
                c.call_lanes(0, &[&q], &mut out, lanes);
                hh_grad_soa(&q, &mut hand, lanes);
                assert!(
                    out.iter()
                        .zip(&hand)
                        .all(|(a, b)| a.to_bits() == b.to_bits())
                );
                let ptrs = [q.as_ptr()];
                let (t_jit, t_hand, ratio) = time_pair(
                    || lanes_call(&c, 0, black_box(&ptrs), black_box(&mut out), lanes),
                    || hh_grad_soa(black_box(&q), black_box(&mut hand), lanes),
                    min_run,
                    runs,
                );
                env.line(&format!(
                "\"bench\":\"eval\",\"system\":\"henon_heiles\",\"function\":\"grad\",\
                 \"opt_level\":\"{label}\",\"lane_block\":{lane_block},\"lanes\":{lanes},\"jit_ns_per_call\":{:.2},\
                 \"hand_ns_per_call\":{:.2},\"jit_ns_per_lane\":{:.3},\"hand_ns_per_lane\":{:.3},\
                 \"jit_over_hand_min\":{:.3},\"jit_over_hand_median_round\":{ratio:.3}",
                t_jit * 1e9,
                t_hand * 1e9,
                t_jit * 1e9 / lanes as f64,
                t_hand * 1e9 / lanes as f64,
                t_jit / t_hand
            ));
            }
        }
    }

    // Throughput: FPUT gradient.
    for n in [101usize, 1001] {
        if !wanted("eval", &format!("fput{n}")) {
            continue;
        }
        let beta = 0.7;
        let mut g = Graph::new();
        let (gr, hv) = fput(&mut g, n as u32, beta);
        for (opt, label, lane_block, large_function) in CONFIGS {
            let c = jit::compile_with(
                &g,
                &specs(&gr, &hv),
                &Options {
                    opt_level: opt,
                    lane_block,
                    large_function,
                    ..Options::default()
                },
            )
            .unwrap();
            for lanes in [8usize, 16, 64] {
                let q: Vec<f64> = (0..n * lanes)
                    .map(|k| ((k * 7919) % 1000) as f64 * 1e-3 - 0.5)
                    .collect();
                let zero = vec![0.0; lanes];
                let mut out = vec![0.0; n * lanes];
                let mut hand = vec![0.0; n * lanes];
                c.call_lanes(0, &[&q], &mut out, lanes);
                fput_grad_soa(&q, &mut hand, n, lanes, beta, &zero);
                assert!(
                    out.iter()
                        .zip(&hand)
                        .all(|(a, b)| a.to_bits() == b.to_bits())
                );
                let ptrs = [q.as_ptr()];
                let (t_jit, t_hand, ratio) = time_pair(
                    || lanes_call(&c, 0, black_box(&ptrs), black_box(&mut out), lanes),
                    || fput_grad_soa(black_box(&q), black_box(&mut hand), n, lanes, beta, &zero),
                    min_run,
                    runs,
                );
                env.line(&format!(
                    "\"bench\":\"eval\",\"system\":\"fput\",\"n\":{n},\"function\":\"grad\",\
                     \"opt_level\":\"{label}\",\"lane_block\":{lane_block},\"lanes\":{lanes},\"jit_ns_per_call\":{:.1},\
                     \"hand_ns_per_call\":{:.1},\"jit_ns_per_site_lane\":{:.3},\
                     \"hand_ns_per_site_lane\":{:.3},\"jit_over_hand_min\":{:.3},\"jit_over_hand_median_round\":{ratio:.3}",
                    t_jit * 1e9,
                    t_hand * 1e9,
                    t_jit * 1e9 / (n * lanes) as f64,
                    t_hand * 1e9 / (n * lanes) as f64,
                    t_jit / t_hand
                ));
            }
        }
    }
}
