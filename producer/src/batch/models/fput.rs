//! The beta-FPUT chain over lanes (lanes are independent chains; rows are sites).

use crate::batch::lanes::LaneModel;
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
}
