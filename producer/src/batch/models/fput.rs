//! The beta-FPUT chain over lanes (lanes are independent chains; rows are sites).

use crate::batch::lanes::{LaneModel, StepCoeffs};
use crate::model::{FputBeta, Model};

impl LaneModel for FputBeta {
    #[inline(always)]
    fn gradient_lanes<const L: usize>(&self, q: &[[f64; L]], out: &mut [[f64; L]]) {
        // FputBeta::gradient, lane by lane: f(r) = r + beta r^3 written the same way.
        let beta = self.beta();
        let f = |r: f64| r + beta * r * r * r;
        let n = self.dof();
        if n == 1 {
            for l in 0..L {
                out[0][l] = f(q[0][l]) - f(-q[0][l]);
            }
            return;
        }
        for l in 0..L {
            out[0][l] = f(q[0][l]) - f(q[1][l] - q[0][l]);
        }
        for i in 1..n - 1 {
            let (a, b, c) = (&q[i - 1], &q[i], &q[i + 1]);
            let o = &mut out[i];
            for l in 0..L {
                o[l] = f(b[l] - a[l]) - f(c[l] - b[l]);
            }
        }
        for l in 0..L {
            out[n - 1][l] = f(q[n - 1][l] - q[n - 2][l]) - f(-q[n - 1][l]);
        }
    }

    #[inline(always)]
    fn hessian_vector_lanes<const L: usize>(
        &self,
        q: &[f64],
        v: &[[f64; L]],
        out: &mut [[f64; L]],
    ) {
        // FputBeta::hessian_vector at the shared position q: the bond stiffness
        // (1 + 3 beta r^2) is formed once per bond (the same bits for every lane).
        let beta = self.beta();
        let k = |r: f64| 1.0 + 3.0 * beta * r * r;
        let n = self.dof();
        if n == 1 {
            let (k0, k1) = (k(q[0]), k(-q[0]));
            for l in 0..L {
                out[0][l] = k0 * v[0][l] - k1 * -v[0][l];
            }
            return;
        }
        let (k0, k1) = (k(q[0]), k(q[1] - q[0]));
        for l in 0..L {
            out[0][l] = k0 * v[0][l] - k1 * (v[1][l] - v[0][l]);
        }
        let mut left = k1;
        for i in 1..n - 1 {
            let right = k(q[i + 1] - q[i]);
            let (a, b, c) = (&v[i - 1], &v[i], &v[i + 1]);
            let o = &mut out[i];
            for l in 0..L {
                o[l] = left * (b[l] - a[l]) - right * (c[l] - b[l]);
            }
            left = right;
        }
        let last = k(-q[n - 1]);
        for l in 0..L {
            out[n - 1][l] = left * (v[n - 1][l] - v[n - 2][l]) - last * -v[n - 1][l];
        }
    }

    /// One pass over the chain per stage: row `i + 1` is drifted just before the force on site
    /// `i` needs it (it uses `p[i + 1]`, not yet kicked in this stage, exactly as a drift of the
    /// whole chain would), and each bond force is evaluated once and used for both its sites
    /// (the same expression on the same inputs, so the same bits as `FputBeta::gradient`, which
    /// evaluates it twice). The chain is streamed through the cache once per stage instead of
    /// three times.
    #[inline(always)]
    fn orbit_steps<const L: usize>(
        &self,
        c: &StepCoeffs,
        x: &mut [[f64; L]],
        _force: &mut [[f64; L]],
        n_steps: u64,
    ) {
        let beta = self.beta();
        let f = |r: f64| r + beta * r * r * r;
        let n = self.dof();
        let (q, p) = x.split_at_mut(n);
        for _ in 0..n_steps {
            for (&ch, &dh) in c.drift.iter().zip(&c.kick) {
                for l in 0..L {
                    q[0][l] += ch * p[0][l];
                }
                // Bond force left of site 0 (fixed end: r = q_1 - 0, written as q_1).
                let mut left = [0.0; L];
                for l in 0..L {
                    left[l] = f(q[0][l]);
                }
                for i in 0..n {
                    let mut right = [0.0; L];
                    if i + 1 < n {
                        let (lo, hi) = q.split_at_mut(i + 1);
                        let (qi, qn) = (&lo[i], &mut hi[0]);
                        let pn = &p[i + 1];
                        for l in 0..L {
                            qn[l] += ch * pn[l];
                            right[l] = f(qn[l] - qi[l]);
                        }
                    } else {
                        for l in 0..L {
                            right[l] = f(-q[i][l]);
                        }
                    }
                    let pi = &mut p[i];
                    for l in 0..L {
                        pi[l] -= dh * (left[l] - right[l]);
                    }
                    left = right;
                }
            }
            let last = c.last_drift();
            for (qr, pr) in q.iter_mut().zip(p.iter()) {
                for l in 0..L {
                    qr[l] += last * pr[l];
                }
            }
        }
    }
}
