//! Poincare surfaces of section: where an orbit crosses the plane `q_i = 0` in the direction
//! `p_i > 0`. The crossing between two integrator steps is located on the cubic Hermite
//! interpolant of `q_i(t)` (the steps give `q_i` and its derivative `p_i` at both ends), and the
//! whole state is interpolated the same way, using `dq/dt = p`, `dp/dt = -grad V`: error
//! O(h^4), far below what a plot resolves.
//!
//! [`surface`]: sections of any flow (and any Hamiltonian) through a surface `S(x) = 0`
//! written as an expression, crossings located to rounding.
//!
//! [`stroboscopic`]: the state every `T` time units, the section of a periodically forced
//! system at a fixed phase of its forcing.

pub mod stroboscopic;
pub mod surface;

use crate::integrator::{Integrator, Workspace};
use crate::model::{At, SeparableHamiltonian};
use crate::spec::RunSpec;

/// Time derivative of the state `(q, p)` of `H = |p|^2/2 + V(q, t)` at time `t`.
fn velocity(model: &dyn SeparableHamiltonian, x: &[f64], t: f64, out: &mut [f64]) {
    let n = x.len() / 2;
    out[..n].copy_from_slice(&x[n..]);
    model.gradient(&x[..n], At::time(t), &mut out[n..]);
    for v in &mut out[n..] {
        *v = -*v;
    }
}

/// Cubic Hermite interpolation on [0, h] at fraction s.
fn hermite(y0: f64, d0: f64, y1: f64, d1: f64, h: f64, s: f64) -> f64 {
    let (s2, s3) = (s * s, s * s * s);
    (2.0 * s3 - 3.0 * s2 + 1.0) * y0
        + (s3 - 2.0 * s2 + s) * h * d0
        + (-2.0 * s3 + 3.0 * s2) * y1
        + (s3 - s2) * h * d1
}

/// States at the crossings of `q_plane = 0` with `p_plane > 0`, for the orbit starting at `x0`,
/// integrated with the run's integrator and step for `steps` steps (at most `max` crossings).
/// Sections are drawn for separable Hamiltonians; other systems have none here.
pub fn crossings(
    spec: &RunSpec,
    x0: &[f64],
    plane: usize,
    steps: u64,
    max: usize,
) -> Vec<Vec<f64>> {
    let Some(hamiltonian) = spec.system().separable() else {
        return Vec::new();
    };
    let model = hamiltonian.model().as_ref();
    let dim = x0.len();
    let mut x = x0.to_vec();
    let mut prev = x.clone();
    let (mut v0, mut v1) = (vec![0.0; dim], vec![0.0; dim]);
    let mut work = Workspace::new();
    let mut out = Vec::new();
    let h = spec.h();
    for step in 0..steps {
        let (t0, t1) = (spec.time_of(step), spec.time_of(step + 1));
        prev.copy_from_slice(&x);
        hamiltonian
            .splitting()
            .step(model, &mut x, t0, h, &mut work);
        if !x.iter().all(|v| v.is_finite()) {
            break;
        }
        let (a, b) = (prev[plane], x[plane]);
        if a < 0.0 && b >= 0.0 {
            velocity(model, &prev, t0, &mut v0);
            velocity(model, &x, t1, &mut v1);
            // Root of the Hermite cubic of q_plane by bisection (monotone enough on one step).
            let f = |s: f64| hermite(a, v0[plane], b, v1[plane], h, s);
            let (mut lo, mut hi) = (0.0, 1.0);
            for _ in 0..60 {
                let mid = 0.5 * (lo + hi);
                if f(mid) < 0.0 { lo = mid } else { hi = mid }
            }
            let s = 0.5 * (lo + hi);
            let state: Vec<f64> = (0..dim)
                .map(|i| hermite(prev[i], v0[i], x[i], v1[i], h, s))
                .collect();
            let n = dim / 2;
            if state[n + plane] > 0.0 {
                out.push(state);
                if out.len() >= max {
                    break;
                }
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use chaoscope_schemas::config::{DeviationsConfig, SchemeConfig, paper};

    #[test]
    fn henon_heiles_crossings_lie_on_the_energy_surface_and_the_plane() {
        let cfg = paper::henon_heiles(
            paper::HH_REGULAR_Q2,
            1.0,
            DeviationsConfig::random(1, 1, 0),
            vec![SchemeConfig::new("vm", "vm", 1e-8, 1.0)],
        );
        let spec = RunSpec::from_config(&cfg).unwrap();
        let pts = crossings(&spec, spec.x0(), 0, 200_000, 200);
        assert!(pts.len() > 100, "{} crossings", pts.len());
        for p in &pts {
            // On the plane to interpolation accuracy, moving through it the right way, and on
            // the energy surface to integrator plus interpolation error.
            assert!(p[0].abs() < 1e-8, "q1 = {}", p[0]);
            assert!(p[2] > 0.0);
            let model = spec.system().separable().unwrap().model();
            assert!((model.energy(p, At::T0) - paper::HH_ENERGY).abs() < 1e-7);
        }
        // A regular orbit (x2 = 0.558 is the paper's regular one): its section points lie on
        // a closed curve, here well inside the allowed region |q2| < 0.7.
        assert!(pts.iter().all(|p| p[1].abs() < 0.7));
    }
}
