//! Gauss-Legendre implicit Runge-Kutta methods (`gl4`: 2 stages, order 4; `gl6`: 3 stages,
//! order 6): symplectic for every Hamiltonian, separable or not, so the energy error stays
//! bounded without drift (Hairer, Lubich, Wanner, Geometric Numerical Integration, IV.2 and
//! VI.4).
//!
//! The stage equations `K_i = f(x + h sum_j a_ij K_j)` are solved by fixed-point iteration,
//! from `K_i = f(x)`, until the update stops shrinking (it has reached rounding): the step is
//! the implicit method's, not an approximation of it with a tolerance. The iteration converges
//! when `h` times the Lipschitz constant of `f` is small (for the step sizes that resolve an
//! orbit it takes 8 to 15 sweeps); where it does not, the step fails and the run stops naming
//! `h`.
//!
//! The tangent map is the exact derivative of that step: the stage tangents solve the linear
//! system `Kt_i = J(X_i) (w + h sum_j a_ij Kt_j)` at the converged stage states `X_i`, by the
//! same iteration (it contracts at the same rate), and `w' = w + h sum_i b_i Kt_i`.

// The stage loops index the stage rows, the state and the tableau by the same coordinate.
#![allow(clippy::needless_range_loop)]

use crate::vector_field::VectorField;

/// Most fixed-point sweeps of one step: far beyond what converges (a sweep gains about
/// `-log10(h L)` digits), so reaching it means the step is too long for the iteration.
pub const MAX_SWEEPS: usize = 200;

/// A Gauss-Legendre tableau: the full `a` matrix (row by row), weights `b`, nodes `c`.
#[derive(Debug)]
pub struct ImplicitTableau {
    pub a: &'static [&'static [f64]],
    pub b: &'static [f64],
    pub c: &'static [f64],
}

impl ImplicitTableau {
    pub fn stages(&self) -> usize {
        self.b.len()
    }
}

// sqrt(3) / 6 and sqrt(15) / 10, ... written out to the last digit of f64.
const S3_6: f64 = 0.288_675_134_594_812_9;
const S15_10: f64 = 0.387_298_334_620_741_7;
const S15_15: f64 = 0.258_198_889_747_161_1;
const S15_24: f64 = 0.161_374_306_091_975_7;
const S15_30: f64 = 0.129_099_444_873_580_56;

/// 2 stages, order 4.
pub static GL4: ImplicitTableau = ImplicitTableau {
    a: &[&[0.25, 0.25 - S3_6], &[0.25 + S3_6, 0.25]],
    b: &[0.5, 0.5],
    c: &[0.5 - S3_6, 0.5 + S3_6],
};

/// 3 stages, order 6.
pub static GL6: ImplicitTableau = ImplicitTableau {
    a: &[
        &[5.0 / 36.0, 2.0 / 9.0 - S15_15, 5.0 / 36.0 - S15_30],
        &[5.0 / 36.0 + S15_24, 2.0 / 9.0, 5.0 / 36.0 - S15_24],
        &[5.0 / 36.0 + S15_30, 2.0 / 9.0 + S15_15, 5.0 / 36.0],
    ],
    b: &[5.0 / 18.0, 4.0 / 9.0, 5.0 / 18.0],
    c: &[0.5 - S15_10, 0.5, 0.5 + S15_10],
};

/// The fixed-point iteration did not settle within [`MAX_SWEEPS`].
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
#[error(
    "{} within {MAX_SWEEPS} sweeps (the step h is too long for this vector field here; use a \
     smaller h)",
    chaoscope_schemas::run::IMPLICIT_NOT_CONVERGED
)]
pub struct NotConverged;

/// `X_i = x + h sum_j a_ij K_j` for every stage, into `xs`.
fn stage_states(t: &ImplicitTableau, x: &[f64], h: f64, k: &[f64], xs: &mut [f64]) {
    let dim = x.len();
    for i in 0..t.stages() {
        for d in 0..dim {
            let mut sum = 0.0;
            for (j, &a) in t.a[i].iter().enumerate() {
                sum += a * k[j * dim + d];
            }
            xs[i * dim + d] = x[d] + h * sum;
        }
    }
}

/// Largest `|new - old|` over the stage values; NaN if any is NaN.
fn largest_change(new: &[f64], old: &[f64]) -> f64 {
    let mut m = 0.0f64;
    for (a, b) in new.iter().zip(old) {
        let d = (a - b).abs();
        if d.is_nan() {
            return f64::NAN;
        }
        m = m.max(d);
    }
    m
}

/// Iterate `update(k_old, k_new)` from `k` until the change stops shrinking: after the first
/// sweep whose change is 0, or once the change, already small against the values, no longer
/// decreases (rounding noise). Deterministic: the same input always takes the same sweeps.
fn iterate(
    k: &mut [f64],
    spare: &mut [f64],
    mut update: impl FnMut(&[f64], &mut [f64]),
) -> Result<(), NotConverged> {
    let mut previous = f64::INFINITY;
    for _ in 0..MAX_SWEEPS {
        update(k, spare);
        let change = largest_change(spare, k);
        k.copy_from_slice(spare);
        if change.is_nan() {
            return Err(NotConverged);
        }
        let scale = k.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        if change == 0.0 || (change >= previous && change <= 1e-10 * scale.max(f64::MIN_POSITIVE)) {
            return Ok(());
        }
        previous = change;
    }
    Err(NotConverged)
}

/// Scratch of the stages, reused across steps.
#[derive(Debug, Default, Clone)]
pub struct ImplicitScratch {
    k: Vec<f64>,
    spare: Vec<f64>,
    xs: Vec<f64>,
    kt: Vec<f64>,
    wt: Vec<f64>,
}

impl ImplicitScratch {
    fn ensure(&mut self, stages: usize, dim: usize) {
        let n = stages * dim;
        if self.k.len() != n {
            self.k = vec![0.0; n];
            self.spare = vec![0.0; n];
            self.xs = vec![0.0; n];
            self.kt = vec![0.0; n];
            self.wt = vec![0.0; dim];
        }
    }
}

/// Solve the stages of a step from `x` (into `s.k`, with the stage states in `s.xs`).
/// Stage `i` is evaluated at the time `time + c_i h`.
fn solve_stages(
    t: &ImplicitTableau,
    f: &dyn VectorField,
    x: &[f64],
    time: f64,
    h: f64,
    s: &mut ImplicitScratch,
) -> Result<(), NotConverged> {
    let dim = x.len();
    s.ensure(t.stages(), dim);
    f.value(x, time, &mut s.k[..dim]);
    for i in 1..t.stages() {
        s.k.copy_within(0..dim, i * dim);
    }
    let xs = &mut s.xs;
    iterate(&mut s.k, &mut s.spare, |k, out| {
        stage_states(t, x, h, k, xs);
        for i in 0..t.stages() {
            f.value(
                &xs[i * dim..(i + 1) * dim],
                time + t.c[i] * h,
                &mut out[i * dim..(i + 1) * dim],
            );
        }
    })?;
    // The stage states of the converged stages (where the tangent takes its Jacobians).
    stage_states(t, x, h, &s.k, &mut s.xs);
    Ok(())
}

/// `x += h sum_i b_i K_i`.
fn update_state(t: &ImplicitTableau, x: &mut [f64], h: f64, k: &[f64]) {
    let dim = x.len();
    for d in 0..dim {
        let mut sum = 0.0;
        for (i, &b) in t.b.iter().enumerate() {
            sum += b * k[i * dim + d];
        }
        x[d] += h * sum;
    }
}

/// One step of size `h` from the time `time`; on failure `x` is left as it was.
pub fn advance(
    t: &ImplicitTableau,
    f: &dyn VectorField,
    x: &mut [f64],
    time: f64,
    h: f64,
    s: &mut ImplicitScratch,
) -> Result<(), NotConverged> {
    solve_stages(t, f, x, time, h, s)?;
    update_state(t, x, h, &s.k);
    Ok(())
}

/// One step of `x` and of the deviation vectors in `w` (one after the other) by the exact
/// derivative of the step. The orbit moves to the bits of [`advance`].
pub fn advance_tangent(
    t: &ImplicitTableau,
    f: &dyn VectorField,
    x: &mut [f64],
    w: &mut [f64],
    time: f64,
    h: f64,
    s: &mut ImplicitScratch,
) -> Result<(), NotConverged> {
    let dim = x.len();
    solve_stages(t, f, x, time, h, s)?;
    let stages = t.stages();
    for v in w.chunks_exact_mut(dim) {
        let ImplicitScratch {
            kt, spare, xs, wt, ..
        } = &mut *s;
        for i in 0..stages {
            f.tangent(
                &xs[i * dim..(i + 1) * dim],
                time + t.c[i] * h,
                v,
                &mut kt[i * dim..(i + 1) * dim],
            );
        }
        iterate(kt, spare, |kt, out| {
            for i in 0..stages {
                for d in 0..dim {
                    let mut sum = 0.0;
                    for (j, &a) in t.a[i].iter().enumerate() {
                        sum += a * kt[j * dim + d];
                    }
                    wt[d] = v[d] + h * sum;
                }
                f.tangent(
                    &xs[i * dim..(i + 1) * dim],
                    time + t.c[i] * h,
                    wt,
                    &mut out[i * dim..(i + 1) * dim],
                );
            }
        })?;
        update_state(t, v, h, kt);
    }
    update_state(t, x, h, &s.k);
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tableaus_satisfy_the_simplifying_assumptions() {
        // B(2s): sum b_i c_i^(q-1) = 1/q; C(s): sum_j a_ij c_j^(q-1) = c_i^q / q.
        for t in [&GL4, &GL6] {
            let s = t.stages();
            for q in 1..=2 * s {
                let sum: f64 = (0..s).map(|i| t.b[i] * t.c[i].powi(q as i32 - 1)).sum();
                assert!((sum - 1.0 / q as f64).abs() < 1e-15, "B({q}): {sum}");
            }
            for i in 0..s {
                for q in 1..=s {
                    let sum: f64 = (0..s).map(|j| t.a[i][j] * t.c[j].powi(q as i32 - 1)).sum();
                    let want = t.c[i].powi(q as i32) / q as f64;
                    assert!(
                        (sum - want).abs() < 1e-15,
                        "C({q}) row {i}: {sum} vs {want}"
                    );
                }
            }
        }
    }
}
