//! Henon-Heiles over lanes, with register-resident step loops: the whole state of `L` orbits
//! (4 rows) stays in vector registers for all the steps between two renormalizations.

use crate::batch::lanes::{LaneHamiltonian, StepCoeffs};
use crate::model::HenonHeiles;

impl LaneHamiltonian for HenonHeiles {
    const REGISTER_RESIDENT: bool = true;

    #[inline(always)]
    fn gradient_lanes<const L: usize>(&self, q: &[[f64; L]], out: &mut [[f64; L]]) {
        let (x1, x2) = (&q[0], &q[1]);
        for l in 0..L {
            // HenonHeiles::gradient, lane by lane.
            out[0][l] = x1[l] + 2.0 * x1[l] * x2[l];
            out[1][l] = x2[l] + x1[l] * x1[l] - x2[l] * x2[l];
        }
    }

    #[inline(always)]
    fn hessian_vector_lanes<const L: usize>(
        &self,
        q: &[f64],
        v: &[[f64; L]],
        out: &mut [[f64; L]],
    ) {
        let (x1, x2) = (q[0], q[1]);
        for l in 0..L {
            out[0][l] = (1.0 + 2.0 * x2) * v[0][l] + 2.0 * x1 * v[1][l];
            out[1][l] = 2.0 * x1 * v[0][l] + (1.0 - 2.0 * x2) * v[1][l];
        }
    }

    #[inline(always)]
    fn hessian_vector_each_lane<const L: usize>(
        &self,
        q: &[[f64; L]],
        v: &[[f64; L]],
        out: &mut [[f64; L]],
    ) {
        for l in 0..L {
            let (x1, x2) = (q[0][l], q[1][l]);
            out[0][l] = (1.0 + 2.0 * x2) * v[0][l] + 2.0 * x1 * v[1][l];
            out[1][l] = 2.0 * x1 * v[0][l] + (1.0 - 2.0 * x2) * v[1][l];
        }
    }

    #[inline(always)]
    fn orbit_tangent_steps<const L: usize>(
        &self,
        c: &StepCoeffs,
        x: &mut [[f64; L]],
        force: &mut [[f64; L]],
        n_steps: u64,
    ) {
        // The shapes maps use (orbit + one vector for the MLE, + two for SALI, + the basis of
        // four for the basis route) in registers; any other through the generic loops.
        match x.len() {
            8 => orbit_tangents_in_registers::<L, 1, 8>(c, x, n_steps),
            12 => orbit_tangents_in_registers::<L, 2, 12>(c, x, n_steps),
            20 => orbit_tangents_in_registers::<L, 4, 20>(c, x, n_steps),
            _ => super::super::lanes::orbit_tangent_steps_generic(self, c, x, force, n_steps),
        }
    }

    #[inline(always)]
    fn orbit_steps<const L: usize>(
        &self,
        c: &StepCoeffs,
        x: &mut [[f64; L]],
        _force: &mut [[f64; L]],
        n_steps: u64,
    ) {
        let (mut q1, mut q2, mut p1, mut p2) = (x[0], x[1], x[2], x[3]);
        let last = c.last_drift();
        for _ in 0..n_steps {
            for (&ch, &dh) in c.drift.iter().zip(&c.kick) {
                for l in 0..L {
                    q1[l] += ch * p1[l];
                    q2[l] += ch * p2[l];
                    let (a, b) = (q1[l], q2[l]);
                    let g0 = a + 2.0 * a * b;
                    let g1 = b + a * a - b * b;
                    p1[l] -= dh * g0;
                    p2[l] -= dh * g1;
                }
            }
            for l in 0..L {
                q1[l] += last * p1[l];
                q2[l] += last * p2[l];
            }
        }
        (x[0], x[1], x[2], x[3]) = (q1, q2, p1, p2);
    }

    #[inline(always)]
    fn tangent_steps<const L: usize>(
        &self,
        c: &StepCoeffs,
        stages: &[f64],
        v: &mut [[f64; L]],
        _force: &mut [[f64; L]],
        n_steps: u64,
    ) {
        let (mut u1, mut u2, mut w1, mut w2) = (v[0], v[1], v[2], v[3]);
        let last = c.last_drift();
        let mut stage = stages.chunks_exact(2);
        for _ in 0..n_steps {
            for (&ch, &dh) in c.drift.iter().zip(&c.kick) {
                let q = stage.next().expect("one recorded position per kick");
                let (x1, x2) = (q[0], q[1]);
                // The Hessian entries, formed as in HenonHeiles::hessian_vector.
                let (h11, h12, h22) = (1.0 + 2.0 * x2, 2.0 * x1, 1.0 - 2.0 * x2);
                for l in 0..L {
                    u1[l] += ch * w1[l];
                    u2[l] += ch * w2[l];
                    let f0 = h11 * u1[l] + h12 * u2[l];
                    let f1 = h12 * u1[l] + h22 * u2[l];
                    w1[l] -= dh * f0;
                    w2[l] -= dh * f1;
                }
            }
            for l in 0..L {
                u1[l] += last * w1[l];
                u2[l] += last * w2[l];
            }
        }
        (v[0], v[1], v[2], v[3]) = (u1, u2, w1, w2);
    }
}

/// `n_steps` steps of the orbit (rows 0..4) and its `V` tangent vectors (`R = 4 + 4 V` rows)
/// of `L` lanes with the whole state in registers: the operations of `orbit_steps` and
/// `hessian_vector_each_lane`, in the generic loops' order, so the bits of
/// `orbit_tangent_steps_generic`.
// The lane index runs across rows of the state: an index loop is the layout, not a habit.
#[allow(clippy::needless_range_loop)]
#[inline(always)]
fn orbit_tangents_in_registers<const L: usize, const V: usize, const R: usize>(
    c: &StepCoeffs,
    x: &mut [[f64; L]],
    n_steps: u64,
) {
    debug_assert_eq!(R, 4 + 4 * V);
    let mut r: [[f64; L]; R] = [[0.0; L]; R];
    r.copy_from_slice(x);
    let last = c.last_drift();
    for _ in 0..n_steps {
        for (&ch, &dh) in c.drift.iter().zip(&c.kick) {
            for l in 0..L {
                r[0][l] += ch * r[2][l];
                r[1][l] += ch * r[3][l];
                let (a, b) = (r[0][l], r[1][l]);
                for v in 0..V {
                    let o = 4 + 4 * v;
                    r[o][l] += ch * r[o + 2][l];
                    r[o + 1][l] += ch * r[o + 3][l];
                    let (v0, v1) = (r[o][l], r[o + 1][l]);
                    let h0 = (1.0 + 2.0 * b) * v0 + 2.0 * a * v1;
                    let h1 = 2.0 * a * v0 + (1.0 - 2.0 * b) * v1;
                    r[o + 2][l] -= dh * h0;
                    r[o + 3][l] -= dh * h1;
                }
                let g0 = a + 2.0 * a * b;
                let g1 = b + a * a - b * b;
                r[2][l] -= dh * g0;
                r[3][l] -= dh * g1;
            }
        }
        for l in 0..L {
            for v in 0..=V {
                let o = 4 * v;
                r[o][l] += last * r[o + 2][l];
                r[o + 1][l] += last * r[o + 3][l];
            }
        }
    }
    x.copy_from_slice(&r);
}
