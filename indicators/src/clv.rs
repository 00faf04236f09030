//! Covariant Lyapunov vectors (Ginelli et al., PRL 99, 130601, 2007) from the QR factors of a
//! run's tangent dynamics: pure numerics, no I/O (the analyzer streams a recording into it).
//!
//! A variational scheme renormalized by QR evolves an orthonormal basis `Q_{n-1}` (`k` columns
//! of dimension `D`) over one window into `W_n = M_n Q_{n-1}` (the recorded separations, times
//! `d0`), and factors `W_n = Q_n R_n` with `R_n` upper triangular. [`qr_factors`] recomputes
//! that factorization from the separations exactly as the producer does (nalgebra's Householder
//! QR of `W_n / d0`, signs fixed so that `R_ii > 0`), so `|R_ii|` equals the recorded stretching
//! factor bit for bit and `Q_n` is the basis the producer carried on.
//!
//! The forward pass gives the backward Lyapunov vectors `Q_n` (Gram-Schmidt vectors). The
//! CLVs at time `n` are `V_n = Q_n C_n`, with `C_n` upper triangular: a CLV `j` lies in the span
//! of the first `j` Gram-Schmidt vectors. Going back in time, `C_{n-1} = R_n^{-1} C_n` (each
//! column normalized, [`Backward::step`]) converges from any upper-triangular start with a
//! non-zero diagonal to the CLVs' coefficients (the backward iteration of the inverse map picks
//! the least contracted direction in each nested subspace). The norm `|(R_n^{-1} C_n)_j|` is
//! the inverse of CLV `j`'s growth over the window, so the logarithms accumulated over the
//! backward pass are the CLVs' growth rates. Only the first `k` CLVs need `k` vectors: with
//! `k < D` the `C` matrices are `k x k` and the vectors the first `k` CLVs.

use nalgebra::DMatrix;

/// Why the CLVs cannot be computed from the factors given.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ClvError {
    #[error(
        "the separations hold {values} values, not k = {k} vectors of dimension {dim} with k <= dim"
    )]
    Shape { values: usize, k: usize, dim: usize },
    #[error("the separation vectors are not finite or are linearly dependent (vector {index})")]
    Dependent { index: usize },
    #[error(
        "R_{index}{index} = {value:e}: the backward iteration left the doubles (a contraction \
         beyond 1e-300 over one renormalization window; renormalize more often)"
    )]
    Degenerate { index: usize, value: f64 },
}

/// Number of values of a `k x k` upper-triangular matrix packed by columns (column `j` holds
/// rows `0..=j`).
pub fn packed_len(k: usize) -> usize {
    k * (k + 1) / 2
}

/// Position of `(i, j)`, `i <= j`, in a packed upper-triangular matrix.
fn packed(i: usize, j: usize) -> usize {
    j * (j + 1) / 2 + i
}

/// The QR factors of one renormalization, recomputed from its `k` separation vectors of length
/// `dim` (one after the other) and the scheme's `d0`, as the producer factors them: `Q` (`dim x
/// k`, by columns, orthonormal) and `R` (packed by columns, [`packed_len`]), with `R_ii > 0`.
pub fn qr_factors(
    separations: &[f64],
    dim: usize,
    k: usize,
    d0: f64,
) -> Result<(Vec<f64>, Vec<f64>), ClvError> {
    if k == 0 || k > dim || separations.len() != dim * k {
        return Err(ClvError::Shape {
            values: separations.len(),
            k,
            dim,
        });
    }
    // The producer's operations, in its order (renormalization.rs, deviation.rs): the same
    // bits for Q and |R_ii|.
    let a = DMatrix::from_column_slice(dim, k, separations) / d0;
    let qr = a.qr();
    let full_r = qr.r();
    let mut q = qr.q();
    let mut r = vec![0.0; packed_len(k)];
    for i in 0..k {
        let rii = full_r[(i, i)];
        if !rii.is_finite() || rii == 0.0 {
            return Err(ClvError::Dependent { index: i });
        }
        // Negating row i of R with column i of Q keeps Q R (exact: a sign).
        let sign = if rii < 0.0 { -1.0 } else { 1.0 };
        if rii < 0.0 {
            q.column_mut(i).neg_mut();
        }
        for j in i..k {
            let v = sign * full_r[(i, j)];
            if !v.is_finite() {
                return Err(ClvError::Dependent { index: j });
            }
            r[packed(i, j)] = v;
        }
    }
    Ok((q.as_slice().to_vec(), r))
}

/// The diagonal `R_ii` of a packed upper-triangular `R`.
pub fn diagonal(r: &[f64], k: usize) -> Vec<f64> {
    (0..k).map(|i| r[packed(i, i)]).collect()
}

/// The backward pass of Ginelli's algorithm: the CLVs' coefficients `C_n` in the Gram-Schmidt
/// basis `Q_n`, stepped from the end of a run towards its start, with the logarithmic growth of
/// each CLV accumulated over the steps asked for.
#[derive(Debug, Clone, PartialEq)]
pub struct Backward {
    k: usize,
    /// `C`, packed upper triangular, each column of unit norm.
    c: Vec<f64>,
    /// `sum ln(growth)` of each CLV over the accumulated steps.
    log_growth: Vec<f64>,
    steps: u64,
}

impl Backward {
    /// Starts from a fixed upper-triangular `C` with unit diagonal and off-diagonal entries in
    /// `[-1, 1)` from a fixed-seed generator (SplitMix64): generic (no CLV's coefficient
    /// vanishes by construction, as it could for the identity with a triangular dynamics) and
    /// the same on every run.
    pub fn new(k: usize) -> Self {
        let mut state: u64 = 0x9E37_79B9_7F4A_7C15;
        let mut next = || {
            state = state.wrapping_add(0x9E37_79B9_7F4A_7C15);
            let mut z = state;
            z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
            z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
            z ^= z >> 31;
            // 53 random bits to [0, 1), then to [-1, 1).
            2.0 * ((z >> 11) as f64 / (1u64 << 53) as f64) - 1.0
        };
        let mut c = vec![0.0; packed_len(k)];
        for j in 0..k {
            for i in 0..j {
                c[packed(i, j)] = next();
            }
            c[packed(j, j)] = 1.0;
        }
        let mut b = Self {
            k,
            c,
            log_growth: vec![0.0; k],
            steps: 0,
        };
        b.normalize_columns();
        b
    }

    fn normalize_columns(&mut self) -> Vec<f64> {
        (0..self.k)
            .map(|j| {
                let col = &mut self.c[packed(0, j)..=packed(j, j)];
                let norm = col.iter().map(|x| x * x).sum::<f64>().sqrt();
                col.iter_mut().for_each(|x| *x /= norm);
                norm
            })
            .collect()
    }

    /// One window back: `C_{n-1} = R_n^{-1} C_n`, columns normalized. With `accumulate`, each
    /// CLV's growth over the window (`1 / |(R_n^{-1} C_n)_j|`) is added to its sum.
    pub fn step(&mut self, r: &[f64], accumulate: bool) -> Result<(), ClvError> {
        let k = self.k;
        // Back substitution, column by column: R X = C with X upper triangular.
        for j in 0..k {
            for i in (0..=j).rev() {
                let mut s = self.c[packed(i, j)];
                for l in i + 1..=j {
                    s -= r[packed(i, l)] * self.c[packed(l, j)];
                }
                let rii = r[packed(i, i)];
                let x = s / rii;
                if !(rii > 0.0 && x.is_finite()) {
                    return Err(ClvError::Degenerate {
                        index: i + 1,
                        value: rii,
                    });
                }
                self.c[packed(i, j)] = x;
            }
        }
        let norms = self.normalize_columns();
        if let Some(j) = norms.iter().position(|n| !(n.is_finite() && *n > 0.0)) {
            return Err(ClvError::Degenerate {
                index: j + 1,
                value: r[packed(j, j)],
            });
        }
        if accumulate {
            for (s, n) in self.log_growth.iter_mut().zip(&norms) {
                *s -= n.ln();
            }
            self.steps += 1;
        }
        Ok(())
    }

    /// `sum ln(growth)` of each CLV over the accumulated windows.
    pub fn log_growth(&self) -> &[f64] {
        &self.log_growth
    }

    /// Windows accumulated.
    pub fn steps(&self) -> u64 {
        self.steps
    }

    /// The CLVs at the current time, `V = Q C`, for the Gram-Schmidt basis `q` (`dim x k`, by
    /// columns): `k` unit vectors of length `dim`, one after the other.
    pub fn vectors(&self, q: &[f64], dim: usize) -> Vec<f64> {
        let k = self.k;
        let mut v = vec![0.0; dim * k];
        for j in 0..k {
            let out = &mut v[j * dim..(j + 1) * dim];
            for i in 0..=j {
                let c = self.c[packed(i, j)];
                for (o, x) in out.iter_mut().zip(&q[i * dim..(i + 1) * dim]) {
                    *o += c * x;
                }
            }
        }
        v
    }
}

/// The smallest principal angle (radians, in `[0, pi/2]`) between the spans of two sets of
/// vectors of length `dim` (each set one vector after the other, linearly independent within
/// itself). Computed from sines, `sin theta_min = sigma_min((I - P_B) Q_A)` with `A` the smaller
/// set, so small angles keep their relative accuracy (an arccos of the cosines would round an
/// angle below 1e-8 to zero); for two lines, `atan2(|a x b|, |a . b|)`.
pub fn min_principal_angle(a: &[f64], b: &[f64], dim: usize) -> f64 {
    let (a, b) = if a.len() <= b.len() { (a, b) } else { (b, a) };
    let (p, q) = (a.len() / dim, b.len() / dim);
    let qa = orthonormal(a, dim, p);
    let qb = orthonormal(b, dim, q);
    // Residual of A's basis after projecting out B. Written as loops: nalgebra multiplies
    // dynamic matrices above 5 x 5 with matrixmultiply, whose kernels use fused multiply-add
    // where the CPU has it, and no numerics here may (the same bits on every machine).
    let proj = DMatrix::from_fn(q, p, |i, j| {
        (0..dim).fold(0.0, |s, r| s + qb[(r, i)] * qa[(r, j)])
    });
    let residual = DMatrix::from_fn(dim, p, |r, j| {
        qa[(r, j)] - (0..q).fold(0.0, |s, i| s + qb[(r, i)] * proj[(i, j)])
    });
    if p == 1 {
        let s = residual.norm();
        let c = proj.norm();
        return s.atan2(c);
    }
    let sines = residual.svd(false, false).singular_values;
    let s = sines.iter().copied().fold(f64::INFINITY, f64::min);
    s.clamp(0.0, 1.0).asin()
}

fn orthonormal(v: &[f64], dim: usize, n: usize) -> DMatrix<f64> {
    let m = DMatrix::from_column_slice(dim, n, v);
    let mut q = m.qr().q();
    // `q()` is dim x min(dim, n): exactly n columns here since n <= dim.
    q.resize_horizontally_mut(n, 0.0);
    q
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Iterates the constant map `M` from a basis and returns the forward QR factors.
    fn factors(m: &DMatrix<f64>, steps: usize) -> Vec<(Vec<f64>, Vec<f64>)> {
        let dim = m.nrows();
        let mut q = DMatrix::<f64>::identity(dim, dim);
        (0..steps)
            .map(|_| {
                let w = m * &q;
                let (qn, r) = qr_factors(w.as_slice(), dim, dim, 1.0).unwrap();
                q = DMatrix::from_column_slice(dim, dim, &qn);
                (qn, r)
            })
            .collect()
    }

    #[test]
    fn the_clvs_of_a_constant_non_normal_map_are_its_eigenvectors() {
        // M = [[2, 1], [0, 0.5]]: eigenvalues 2 and 0.5 with eigenvectors (1, 0) and
        // (1, -1.5) / |.|, at 56.3 degrees to each other (non-normal: the QR vectors are
        // orthogonal and differ from them). Exponents ln 2 and ln 0.5 exactly.
        let m = DMatrix::from_row_slice(2, 2, &[2.0, 1.0, 0.0, 0.5]);
        let f = factors(&m, 200);
        let mut b = Backward::new(2);
        for (n, (_, r)) in f.iter().enumerate().rev() {
            // Growth over the middle 100 windows, after 50 windows of backward convergence
            // (the error of C shrinks by (0.5/2)^1 = 1/4 a window: 4^-50 is far below
            // rounding).
            b.step(r, (50..150).contains(&n)).unwrap();
            if n == 100 {
                let v = b.vectors(&f[n - 1].0, 2);
                // V_{n-1} (after the step back): the eigenvectors, up to sign.
                let e2 = [1.0 / 3.25f64.sqrt(), -1.5 / 3.25f64.sqrt()];
                assert!(
                    (v[0].abs() - 1.0).abs() < 1e-14 && v[1].abs() < 1e-14,
                    "{v:?}"
                );
                let dot = (v[2] * e2[0] + v[3] * e2[1]).abs();
                assert!((dot - 1.0).abs() < 1e-14, "{v:?}");
                let angle = min_principal_angle(&v[0..2], &v[2..4], 2);
                let want = (1.5f64).atan();
                assert!((angle - want).abs() < 1e-13, "{angle} vs {want}");
            }
        }
        let rates: Vec<f64> = b.log_growth().iter().map(|s| s / 100.0).collect();
        // Rounding per window is ~1e-16 relative; 100 windows: well inside 1e-12.
        assert_eq!(b.steps(), 100);
        assert!((rates[0] - 2f64.ln()).abs() < 1e-12, "{rates:?}");
        assert!((rates[1] - 0.5f64.ln()).abs() < 1e-12, "{rates:?}");
    }

    #[test]
    fn a_3d_map_with_a_degenerate_looking_start_converges_too() {
        // Upper-triangular M: the identity would already be its QR basis at every step, and
        // C = I a fixed point for column 2 only if its eigenvector were e_2; the eigenvectors
        // here are (1,0,0), (1,-1,0)/sqrt2 (lambda 1), and a third (lambda 0.25).
        let m = DMatrix::from_row_slice(3, 3, &[3.0, 2.0, 1.0, 0.0, 1.0, 1.0, 0.0, 0.0, 0.25]);
        let f = factors(&m, 120);
        let mut b = Backward::new(3);
        for (n, (_, r)) in f.iter().enumerate().rev() {
            // 40 windows of backward convergence: the slowest ratio is 1/3 a window (CLV 2
            // against CLV 1 under R^{-1}), 3^-40 ~ 1e-19.
            b.step(r, (20..80).contains(&n)).unwrap();
        }
        let rates: Vec<f64> = b.log_growth().iter().map(|s| s / 60.0).collect();
        for (got, want) in rates.iter().zip([3f64.ln(), 0.0, 0.25f64.ln()]) {
            assert!((got - want).abs() < 1e-12, "{rates:?}");
        }
        // The eigenvectors of M: check M v = lambda v for the CLVs at the start.
        let v = b.vectors(&f[0].0, 3);
        for (j, lambda) in [3.0, 1.0, 0.25].into_iter().enumerate() {
            let x = DMatrix::from_column_slice(3, 1, &v[3 * j..3 * j + 3]);
            let res = (&m * &x - &x * lambda).norm();
            assert!(res < 1e-12, "CLV {j}: |Mv - lambda v| = {res}");
        }
    }

    #[test]
    fn qr_factors_reproduce_the_columns_with_a_positive_diagonal() {
        let w = [1.0, 2.0, -3.0, 0.5, -1.0, 4.0];
        let (q, r) = qr_factors(&w, 3, 2, 0.5).unwrap();
        assert!(diagonal(&r, 2).iter().all(|&d| d > 0.0));
        for j in 0..2 {
            for row in 0..3 {
                let mut s = 0.0;
                for i in 0..=j {
                    s += q[i * 3 + row] * r[packed(i, j)];
                }
                assert!((s - w[j * 3 + row] / 0.5).abs() < 1e-14);
            }
        }
        assert!(qr_factors(&w, 3, 3, 1.0).is_err());
        assert!(qr_factors(&[1.0, 0.0, 2.0, 0.0], 2, 2, 1.0).is_err());
    }

    #[test]
    fn principal_angles_of_planes_and_lines() {
        let x = [1.0, 0.0, 0.0];
        let t = 1e-9f64;
        let near = [t.cos(), t.sin(), 0.0];
        assert!((min_principal_angle(&x, &near, 3) - t).abs() < 1e-24);
        // The xy plane and the line (0, sin t, cos t): angle pi/2 - t.
        let plane = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0];
        let line = [0.0, 0.3f64.sin(), 0.3f64.cos()];
        let a = min_principal_angle(&plane, &line, 3);
        assert!(
            (a - (std::f64::consts::FRAC_PI_2 - 0.3)).abs() < 1e-14,
            "{a}"
        );
        // Two planes in R^4 sharing a line: smallest angle 0.
        let p1 = [1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0];
        let p2 = [1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0];
        assert!(min_principal_angle(&p1, &p2, 4) < 1e-15);
        // Seven-dimensional subspaces of R^14 (past nalgebra's 5 x 5 threshold for its own
        // products): a_i = cos t_i e_i + sin t_i e_{7+i} against span(e_1..e_7), whose
        // principal angles are the t_i. The smallest, 1e-9, from sines: to the SVD's absolute
        // error of a few eps over a unit matrix, 1e-6 relative.
        let dim = 14;
        let angles: Vec<f64> = (0..7)
            .map(|i| if i == 3 { 1e-9 } else { 0.2 + 0.1 * i as f64 })
            .collect();
        let mut a = vec![0.0; dim * 7];
        let mut b = vec![0.0; dim * 7];
        for (i, t) in angles.iter().enumerate() {
            a[i * dim + i] = t.cos();
            a[i * dim + 7 + i] = t.sin();
            b[i * dim + i] = 1.0;
        }
        let got = min_principal_angle(&a, &b, dim);
        assert!((got - 1e-9).abs() < 1e-15, "{got}");
    }
}
