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
//!
//! Time: step number `n` starts at `n h` (computed, as the engine's `Time::at`), stage `i` at
//! `n h + c_i h`, the same for every lane (every orbit of a map starts at `t = 0` and takes the
//! same steps), so the time is one scalar argument of the lane functions.
//!
//! Parameter axes: a lane's state carries its `P` parameters after its `D` coordinates (rows
//! `D..D + P`, [`VectorFunction::state_len`]), which every stage keeps unchanged; so one batch
//! steps orbits of different parameters, all at the same time.

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

/// One step from time `time` of every lane of `x` (`(D + P) * lanes` numbers, rows =
/// coordinates, then the lanes' parameters, which every stage state carries unchanged); the
/// stage states are appended to `stages` when given (for one lane: where the tangent map is
/// taken).
#[allow(clippy::too_many_arguments)]
fn step(
    t: &Tableau,
    f: &VectorFunction,
    time: f64,
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
        f.value_lanes_at(&s.arg, time + t.c[i] * h, &mut rest[..n], lanes);
    }
    combine(&x[..n], h, t.b, &s.k, &mut s.arg[..n]);
    x[..n].copy_from_slice(&s.arg[..n]);
}

/// The time of step number `n`, as the engine computes it (`Time::at`).
fn time_of(n: u64, h: f64) -> f64 {
    n as f64 * h
}

/// Advance every lane of `x` by `n_steps` steps of size `h`, the first step number `from`.
pub fn flow_orbit_steps(
    t: &Tableau,
    f: &VectorFunction,
    h: f64,
    x: &mut Soa,
    from: u64,
    n_steps: u64,
    s: &mut FlowScratch,
) {
    let lanes = x.lanes();
    for k in 0..n_steps {
        step(t, f, time_of(from + k, h), h, x.data_mut(), lanes, s, None);
    }
}

/// Advance one reference orbit `x` by `n_steps` steps exactly as `RungeKutta::advance` does,
/// writing every stage state to `stages` (`n_steps * stages * (D + P)` numbers): where the
/// tangent map of each stage is taken.
#[allow(clippy::too_many_arguments)]
pub fn record_flow_reference(
    t: &Tableau,
    f: &VectorFunction,
    h: f64,
    x: &mut [f64],
    from: u64,
    n_steps: u64,
    stages: &mut Vec<f64>,
    s: &mut FlowScratch,
) {
    stages.clear();
    for k in 0..n_steps {
        step(t, f, time_of(from + k, h), h, x, 1, s, Some(stages));
    }
}

/// Advance every lane of `v` (tangent vectors) by `n_steps` steps of the exact derivative of the
/// step around the reference's stage states `stages` (from [`record_flow_reference`]). `false`
/// when `f` has no tangent (the variational method was refused at validation already).
#[allow(clippy::too_many_arguments)]
pub fn flow_tangent_steps(
    t: &Tableau,
    f: &VectorFunction,
    h: f64,
    stages: &[f64],
    v: &mut Soa,
    from: u64,
    n_steps: u64,
    s: &mut FlowScratch,
) -> bool {
    let (lanes, d) = (v.lanes(), v.rows());
    let n = d * lanes;
    s.k.resize(t.stages() * n, 0.0);
    s.arg.resize(n, 0.0);
    let state = f.state_len();
    for (k, states) in stages
        .chunks_exact(t.stages() * state)
        .take(n_steps as usize)
        .enumerate()
    {
        let time = time_of(from + k as u64, h);
        let v = v.data_mut();
        for (i, xs) in states.chunks_exact(state).enumerate() {
            let (done, rest) = s.k.split_at_mut(i * n);
            combine(v, h, t.a[i], done, &mut s.arg);
            if !f.tangent_lanes_at(xs, time + t.c[i] * h, &s.arg, &mut rest[..n], lanes) {
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
    use crate::integrator::{RungeKutta, RungeKuttaTableau, Workspace};
    use crate::system::{DynamicalSystem, RkFlow};
    use chaoscope_expr::{Boundary, ParamValue, VectorDefinition};
    use std::sync::Arc;

    /// The Lorenz system, and with `forced` a periodic force `2 cos(1.3 t)` on `x1`: a field
    /// that reads the time.
    fn lorenz(forced: bool) -> VectorFunction {
        let first = if forced {
            "sigma * (x2 - x1) + 2 * cos(1.3 * t)"
        } else {
            "sigma * (x2 - x1)"
        };
        VectorFunction::new(VectorDefinition {
            key: "rhs".into(),
            components: vec![
                first.into(),
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
            time: true,
        })
        .unwrap()
    }

    /// Every lane equals the one-orbit flow's `step` / `step_tangent` bit for bit, for rk4 and
    /// fixed-step dop853, lane counts that are and are not multiples of the compiled block, an
    /// autonomous field and one that reads the time (steps numbered from 37: each lane and
    /// stage takes the time the one-orbit step at `37 h` etc. gives it).
    #[test]
    fn lanes_match_the_one_orbit_steps_bit_for_bit() {
        const FROM: u64 = 37;
        let h = 0.01;
        for forced in [false, true] {
            let f = lorenz(forced);
            assert_eq!(f.reads_time(), forced);
            lanes_match(&f, FROM, h);
        }
    }

    fn lanes_match(f: &VectorFunction, from: u64, h: f64) {
        let time = |k: u64| crate::system::Time::Continuous { h }.at(from + k);
        for kind in [RungeKuttaTableau::Rk4, RungeKuttaTableau::Dop853] {
            let t = kind.tableau().unwrap();
            let flow = RkFlow {
                name: "ode".into(),
                field: Arc::new(f.clone()),
                method: RungeKutta::new(kind),
                h,
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
                flow_orbit_steps(t, f, h, &mut soa, from, 200, &mut s);
                let mut w = Workspace::new();
                for (l, x0) in starts.iter().enumerate() {
                    let mut x = x0.clone();
                    for k in 0..200 {
                        flow.step(&mut x, time(k), &mut w);
                    }
                    let mut got = vec![0.0; 3];
                    soa.read_lane(l, &mut got);
                    assert_eq!(got, x, "{kind:?} lane {l} of {used}");
                }

                let mut x = starts[0].clone();
                let mut stages = Vec::new();
                record_flow_reference(t, f, h, &mut x, from, 200, &mut stages, &mut s);
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
                    t, f, h, &stages, &mut v, from, 200, &mut s
                ));
                for (l, d) in dirs.iter().enumerate() {
                    let (mut y, mut w1) = (starts[0].clone(), d.clone());
                    for k in 0..200 {
                        flow.step_tangent(&mut y, &mut w1, time(k), &mut w).unwrap();
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
