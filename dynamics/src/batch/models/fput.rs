//! The beta-FPUT chain over lanes (lanes are independent chains; rows are sites).

use crate::batch::lanes::{LaneHamiltonian, StepCoeffs};
use crate::model::{FputBeta, SeparableHamiltonian};

impl LaneHamiltonian for FputBeta {
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

    /// One pass over the chain per stage: row `i + 1` of `dq` is drifted just before the force
    /// on site `i` needs it (it uses `dp_{i+1}`, not yet kicked in this stage, exactly as a
    /// drift of the whole chain would), and site `i` is kicked at once with
    /// `f'(r_{i-1}) (dq_i - dq_{i-1}) - f'(r_i) (dq_{i+1} - dq_i)`, the expression of
    /// `hessian_vector_lanes` (hence the bits of `FputBeta::hessian_vector`). Each bond term is
    /// formed for both its sites rather than carried across sites: a carried row of `L` lanes
    /// does not stay in registers at the tangent kernel's wide chunks, and its copies cost more
    /// than the two operations saved. The generic stage would stream the chunk three times.
    #[inline(always)]
    fn tangent_steps<const L: usize>(
        &self,
        c: &StepCoeffs,
        stages: &[f64],
        v: &mut [[f64; L]],
        force: &mut [[f64; L]],
        n_steps: u64,
    ) {
        let n = self.dof();
        let (dq, dp) = v.split_at_mut(n);
        let mut stage = stages.chunks_exact(n);
        let last = c.last_drift();
        if n == 1 {
            // A single site: the generic stage (drift, Hessian-vector product, kick).
            for _ in 0..n_steps {
                for (&ch, &dh) in c.drift.iter().zip(&c.kick) {
                    for l in 0..L {
                        dq[0][l] += ch * dp[0][l];
                    }
                    let q = stage.next().expect("one recorded position per kick");
                    self.hessian_vector_lanes(q, dq, force);
                    for l in 0..L {
                        dp[0][l] -= dh * force[0][l];
                    }
                }
                for l in 0..L {
                    dq[0][l] += last * dp[0][l];
                }
            }
            return;
        }
        let beta = self.beta();
        let k = |r: f64| 1.0 + 3.0 * beta * r * r;
        for _ in 0..n_steps {
            for (&ch, &dh) in c.drift.iter().zip(&c.kick) {
                let q = stage.next().expect("one recorded position per kick");
                drift_row(&mut dq[0], &dp[0], ch);
                drift_row(&mut dq[1], &dp[1], ch);
                // Site 0 (its left bond ends at the fixed wall).
                let (k0, mut kl) = (k(q[0]), k(q[1] - q[0]));
                first_site(&dq[0], &dq[1], &mut dp[0], dh, (k0, kl));
                for i in 1..n - 1 {
                    let kr = k(q[i + 1] - q[i]);
                    let (lo, hi) = dq.split_at_mut(i + 1);
                    let (plo, phi) = dp.split_at_mut(i + 1);
                    let rows = (&lo[i - 1], &lo[i], &mut hi[0]);
                    inner_site(rows, &phi[0], &mut plo[i], (ch, dh, kl, kr));
                    kl = kr;
                }
                // Site N - 1 (its right bond ends at the fixed wall).
                let kn = k(-q[n - 1]);
                last_site(&dq[n - 2], &dq[n - 1], &mut dp[n - 1], dh, (kl, kn));
            }
            for (qr, pr) in dq.iter_mut().zip(dp.iter()) {
                for l in 0..L {
                    qr[l] += last * pr[l];
                }
            }
        }
    }

    /// One pass over the chain per stage: row `i + 1` is drifted just before the force on site
    /// `i` needs it (it uses `p[i + 1]`, not yet kicked in this stage, exactly as a drift of the
    /// whole chain would), and site `i` is kicked at once. Each bond force is evaluated for both
    /// its sites, as `FputBeta::gradient` does (the same bits): carrying it across sites in a
    /// row of `L` lanes on the stack made the speed depend on how the compiler copied that row
    /// (store-forwarding stalls: 0.4x to 2x the plain loop from one build to the next). The
    /// chain is streamed through the cache once per stage instead of three times.
    #[inline(always)]
    fn orbit_steps<const L: usize>(
        &self,
        c: &StepCoeffs,
        x: &mut [[f64; L]],
        _force: &mut [[f64; L]],
        n_steps: u64,
    ) {
        let beta = self.beta();
        let n = self.dof();
        let (q, p) = x.split_at_mut(n);
        for _ in 0..n_steps {
            for (&ch, &dh) in c.drift.iter().zip(&c.kick) {
                drift_row(&mut q[0], &p[0], ch);
                if n == 1 {
                    end_site(&q[0], &mut p[0], (dh, beta));
                    continue;
                }
                drift_row(&mut q[1], &p[1], ch);
                first_orbit_site(&q[0], &q[1], &mut p[0], (dh, beta));
                for i in 1..n - 1 {
                    let (lo, hi) = q.split_at_mut(i + 1);
                    let (plo, phi) = p.split_at_mut(i + 1);
                    let rows = (&lo[i - 1], &lo[i], &mut hi[0]);
                    inner_orbit_site(rows, &phi[0], &mut plo[i], (ch, dh, beta));
                }
                last_orbit_site(&q[n - 2], &q[n - 1], &mut p[n - 1], (dh, beta));
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

// The row loops of `FputBeta`'s step loops, one function each so that every row is a
// separate reference: the compiler then knows the rows do not overlap and vectorizes the lane
// loop (rows split off one array at run-time indices are not proven disjoint once inlined).

/// Site 0: `dp_0 -= dh (f'(r_0) dq_0 - f'(r_1) (dq_1 - dq_0))`.
#[inline(always)]
fn first_site<const L: usize>(
    d0: &[f64; L],
    d1: &[f64; L],
    p0: &mut [f64; L],
    dh: f64,
    (k0, k1): (f64, f64),
) {
    for l in 0..L {
        let f = k0 * d0[l] - k1 * (d1[l] - d0[l]);
        p0[l] -= dh * f;
    }
}

/// Interior site `i`: drift `dq_{i+1}` (with `dp_{i+1}`, not yet kicked), then
/// `dp_i -= dh (f'(r_{i-1}) (dq_i - dq_{i-1}) - f'(r_i) (dq_{i+1} - dq_i))`.
#[inline(always)]
fn inner_site<const L: usize>(
    (a, b, c): (&[f64; L], &[f64; L], &mut [f64; L]),
    pn: &[f64; L],
    pi: &mut [f64; L],
    (ch, dh, kl, kr): (f64, f64, f64, f64),
) {
    for l in 0..L {
        c[l] += ch * pn[l];
        let f = kl * (b[l] - a[l]) - kr * (c[l] - b[l]);
        pi[l] -= dh * f;
    }
}

/// Site N - 1: `dp -= dh (f'(r_{N-1}) (dq_{N-1} - dq_{N-2}) - f'(r_N) (-dq_{N-1}))`.
#[inline(always)]
fn last_site<const L: usize>(
    a: &[f64; L],
    b: &[f64; L],
    pi: &mut [f64; L],
    dh: f64,
    (kl, kn): (f64, f64),
) {
    for l in 0..L {
        let f = kl * (b[l] - a[l]) - kn * -b[l];
        pi[l] -= dh * f;
    }
}

/// `q += ch p` for one row.
#[inline(always)]
fn drift_row<const L: usize>(q: &mut [f64; L], p: &[f64; L], ch: f64) {
    for l in 0..L {
        q[l] += ch * p[l];
    }
}

/// The bond force `f(r) = r + beta r^3`, written as `FputBeta::gradient` writes it.
#[inline(always)]
fn bond(r: f64, beta: f64) -> f64 {
    r + beta * r * r * r
}

/// A chain of one site: `p_0 -= dh (f(q_0) - f(-q_0))`.
#[inline(always)]
fn end_site<const L: usize>(q0: &[f64; L], p0: &mut [f64; L], (dh, beta): (f64, f64)) {
    for l in 0..L {
        p0[l] -= dh * (bond(q0[l], beta) - bond(-q0[l], beta));
    }
}

/// Site 0: `p_0 -= dh (f(q_0) - f(q_1 - q_0))`.
#[inline(always)]
fn first_orbit_site<const L: usize>(
    q0: &[f64; L],
    q1: &[f64; L],
    p0: &mut [f64; L],
    (dh, beta): (f64, f64),
) {
    for l in 0..L {
        p0[l] -= dh * (bond(q0[l], beta) - bond(q1[l] - q0[l], beta));
    }
}

/// Interior site `i`: drift `q_{i+1}` (with `p_{i+1}`, not yet kicked), then
/// `p_i -= dh (f(q_i - q_{i-1}) - f(q_{i+1} - q_i))`.
#[inline(always)]
fn inner_orbit_site<const L: usize>(
    (a, b, c): (&[f64; L], &[f64; L], &mut [f64; L]),
    pn: &[f64; L],
    pi: &mut [f64; L],
    (ch, dh, beta): (f64, f64, f64),
) {
    for l in 0..L {
        c[l] += ch * pn[l];
        pi[l] -= dh * (bond(b[l] - a[l], beta) - bond(c[l] - b[l], beta));
    }
}

/// Site N - 1: `p -= dh (f(q_{N-1} - q_{N-2}) - f(-q_{N-1}))`.
#[inline(always)]
fn last_orbit_site<const L: usize>(
    a: &[f64; L],
    b: &[f64; L],
    pi: &mut [f64; L],
    (dh, beta): (f64, f64),
) {
    for l in 0..L {
        pi[l] -= dh * (bond(b[l] - a[l], beta) - bond(-b[l], beta));
    }
}
