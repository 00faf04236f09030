//! The batched form of a flow `dx/dt = f(x)` stepped by a fixed-step explicit Runge-Kutta
//! method: many orbits (or tangent vectors around one reference) advanced at once through the
//! compiled lane functions of `f` and of `J v`.
//!
//! Lane by lane these are the bits of [`crate::integrator::RungeKutta`]'s `advance` /
//! `advance_tangent`: every stage sum starts at `0.0` and adds the tableau's nonzero terms in
//! the same order (the loops over lanes sit inside the loop over terms, which changes no
//! lane's sequence of operations), and the compiled lane functions give per lane the scalar
//! function's result. The SIMD lives inside the compiled code and in these row loops, so there
//! is no per-ISA instantiation here.

use chaoscope_expr::VectorFunction;

use super::Soa;
use crate::integrator::runge_kutta::Tableau;

/// Stage derivatives and one stage argument over all lanes, reused across calls.
#[derive(Debug, Default)]
pub struct FlowScratch {
    k: Vec<f64>,
    arg: Vec<f64>,
}

/// `out[e] = x[e] + h * sum_j w[j] * k[j][e]` over the nonzero weights, in order (each row of
/// `k` has `out.len()` entries).
fn combine(x: &[f64], h: f64, weights: &[f64], k: &[f64], out: &mut [f64]) {
    let n = out.len();
    out.fill(0.0);
    for (j, &w) in weights.iter().enumerate() {
        if w != 0.0 {
            for (o, kj) in out.iter_mut().zip(&k[j * n..(j + 1) * n]) {
                *o += w * kj;
            }
        }
    }
    for (o, xe) in out.iter_mut().zip(x) {
        *o = xe + h * *o;
    }
}

/// One step of every lane of `x` (`(D + P) * lanes` numbers, rows = coordinates, then the
/// lanes' parameters, which every stage state carries unchanged); the stage states are
/// appended to `stages` when given (for one lane: where the tangent map is taken).
fn step(
    t: &Tableau,
    f: &VectorFunction,
    h: f64,
    x: &mut [f64],
    lanes: usize,
    s: &mut FlowScratch,
    mut stages: Option<&mut Vec<f64>>,
) {
    let n = f.dim() * lanes;
    s.k.resize(t.stages() * n, 0.0);
    s.arg.resize(x.len(), 0.0);
    s.arg[n..].copy_from_slice(&x[n..]);
    for i in 0..t.stages() {
        let (done, rest) = s.k.split_at_mut(i * n);
        combine(&x[..n], h, t.a[i], done, &mut s.arg[..n]);
        if let Some(stages) = stages.as_deref_mut() {
            stages.extend_from_slice(&s.arg);
        }
        f.value_lanes(&s.arg, &mut rest[..n], lanes);
    }
    combine(&x[..n], h, t.b, &s.k, &mut s.arg[..n]);
    x[..n].copy_from_slice(&s.arg[..n]);
}

/// Advance every lane of `x` by `n_steps` steps of size `h`.
pub fn flow_orbit_steps(
    t: &Tableau,
    f: &VectorFunction,
    h: f64,
    x: &mut Soa,
    n_steps: u64,
    s: &mut FlowScratch,
) {
    let lanes = x.lanes();
    for _ in 0..n_steps {
        step(t, f, h, x.data_mut(), lanes, s, None);
    }
}

/// Advance one reference orbit `x` by `n_steps` steps exactly as `RungeKutta::advance` does,
/// writing every stage state to `stages` (`n_steps * stages * D` numbers): where the tangent
/// map of each stage is taken.
pub fn record_flow_reference(
    t: &Tableau,
    f: &VectorFunction,
    h: f64,
    x: &mut [f64],
    n_steps: u64,
    stages: &mut Vec<f64>,
    s: &mut FlowScratch,
) {
    stages.clear();
    for _ in 0..n_steps {
        step(t, f, h, x, 1, s, Some(stages));
    }
}

/// Advance every lane of `v` (tangent vectors) by `n_steps` steps of the exact derivative of the
/// step around the reference's stage states `stages` (from [`record_flow_reference`]). `false`
/// when `f` has no tangent (the variational method was refused at validation already).
pub fn flow_tangent_steps(
    t: &Tableau,
    f: &VectorFunction,
    h: f64,
    stages: &[f64],
    v: &mut Soa,
    n_steps: u64,
    s: &mut FlowScratch,
) -> bool {
    let (lanes, d) = (v.lanes(), v.rows());
    let n = d * lanes;
    s.k.resize(t.stages() * n, 0.0);
    s.arg.resize(n, 0.0);
    let state = f.state_len();
    for states in stages
        .chunks_exact(t.stages() * state)
        .take(n_steps as usize)
    {
        let v = v.data_mut();
        for (i, xs) in states.chunks_exact(state).enumerate() {
            let (done, rest) = s.k.split_at_mut(i * n);
            combine(v, h, t.a[i], done, &mut s.arg);
            if !f.tangent_lanes(xs, &s.arg, &mut rest[..n], lanes) {
                return false;
            }
        }
        combine(v, h, t.b, &s.k, &mut s.arg);
        v.copy_from_slice(&s.arg);
    }
    true
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::integrator::{RungeKutta, RungeKuttaKind, Workspace};
    use crate::system::{DynamicalSystem, RkFlow};
    use chaoscope_expr::{Boundary, ParamValue, VectorDefinition};
    use std::sync::Arc;

    fn lorenz() -> VectorFunction {
        VectorFunction::new(VectorDefinition {
            key: "rhs".into(),
            components: vec![
                "sigma * (x2 - x1)".into(),
                "x1 * (rho - x3) - x2".into(),
                "x1 * x2 - beta * x3".into(),
            ],
            params: [
                ("sigma".to_string(), ParamValue::Scalar(10.0)),
                ("rho".to_string(), ParamValue::Scalar(28.0)),
                ("beta".to_string(), ParamValue::Scalar(8.0 / 3.0)),
            ]
            .into(),
            boundary: Boundary::Fixed,
            tables: Vec::new(),
        })
        .unwrap()
    }

    /// Every lane equals the one-orbit flow's `step` / `step_tangent` bit for bit, for rk4 and
    /// fixed-step dop853, lane counts that are and are not multiples of the compiled block.
    #[test]
    fn lanes_match_the_one_orbit_steps_bit_for_bit() {
        let f = lorenz();
        for kind in [RungeKuttaKind::Rk4, RungeKuttaKind::Dop853] {
            let t = kind.tableau().unwrap();
            let flow = RkFlow {
                name: "ode".into(),
                field: Arc::new(f.clone()),
                method: RungeKutta::new(kind),
                h: 0.01,
                tolerances: None,
            };
            for used in [1usize, 3, 8, 13] {
                let starts: Vec<Vec<f64>> = (0..used)
                    .map(|l| vec![1.0 + 0.3 * l as f64, 2.0 - 0.2 * l as f64, 20.0 + l as f64])
                    .collect();
                let mut soa = Soa::new(3, used);
                for (l, x) in starts.iter().enumerate() {
                    soa.write_lane(l, x);
                }
                let mut s = FlowScratch::default();
                flow_orbit_steps(t, &f, 0.01, &mut soa, 200, &mut s);
                let mut w = Workspace::new();
                for (l, x0) in starts.iter().enumerate() {
                    let mut x = x0.clone();
                    for _ in 0..200 {
                        flow.step(&mut x, &mut w);
                    }
                    let mut got = vec![0.0; 3];
                    soa.read_lane(l, &mut got);
                    assert_eq!(got, x, "{kind:?} lane {l} of {used}");
                }

                let mut x = starts[0].clone();
                let mut stages = Vec::new();
                record_flow_reference(t, &f, 0.01, &mut x, 200, &mut stages, &mut s);
                let dirs: Vec<Vec<f64>> = (0..used)
                    .map(|l| {
                        let a = l as f64;
                        vec![a.cos(), a.sin(), 0.5 - 0.1 * a]
                    })
                    .collect();
                let mut v = Soa::new(3, used);
                for (l, d) in dirs.iter().enumerate() {
                    v.write_lane(l, d);
                }
                assert!(flow_tangent_steps(
                    t, &f, 0.01, &stages, &mut v, 200, &mut s
                ));
                for (l, d) in dirs.iter().enumerate() {
                    let (mut y, mut w1) = (starts[0].clone(), d.clone());
                    for _ in 0..200 {
                        flow.step_tangent(&mut y, &mut w1, &mut w).unwrap();
                    }
                    assert_eq!(y, x, "{kind:?} reference");
                    let mut got = vec![0.0; 3];
                    v.read_lane(l, &mut got);
                    assert_eq!(got, w1, "{kind:?} tangent lane {l} of {used}");
                }
            }
        }
    }
}
