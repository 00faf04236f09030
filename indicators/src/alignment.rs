//! Alignment indices of deviation vectors: GALI (the volume of the unit vectors) and SALI.

use nalgebra::DMatrix;

/// Smallest singular value taken into a GALI product. The unit vectors carry rounding errors of
/// order machine epsilon, so a singular value below it is not resolved: once chaotic deviation
/// vectors have aligned to the last bit a singular value becomes exactly zero (`log10 = -inf`).
/// Such values are reported as epsilon, meaning "at or below double precision"; a GALI at
/// `eps^m` says that `m` directions have collapsed.
pub const SIGMA_FLOOR: f64 = f64::EPSILON;

/// `log10 GALI_j` for `j = 2..=k`, where `GALI_j` is the volume spanned by the first `j` of the
/// `k` vectors (each normalized to unit length first), computed as the product of the singular
/// values of the `dim x j` matrix of unit vectors. Returns `k - 1` values (empty for `k < 2`).
pub fn gali_log10(vectors: &[f64], dim: usize) -> Vec<f64> {
    let k = vectors.len() / dim;
    let units = unit_columns(vectors, dim);
    (2..=k)
        .map(|j| {
            let m = units.columns(0, j).clone_owned();
            m.singular_values()
                .iter()
                .map(|s| s.max(SIGMA_FLOOR).log10())
                .sum()
        })
        .collect()
}

/// The `dim x k` matrix whose columns are the given vectors normalized to unit length.
pub fn unit_columns(vectors: &[f64], dim: usize) -> DMatrix<f64> {
    let k = vectors.len() / dim;
    let mut m = DMatrix::from_column_slice(dim, k, vectors);
    for mut c in m.column_iter_mut() {
        let n = c.norm();
        if n > 0.0 {
            c /= n;
        }
    }
    m
}

/// Smaller Alignment Index of the first two vectors: `min(|u1 + u2|, |u1 - u2|)` of the unit
/// vectors. Equals `GALI_2` up to a factor between 1 and 2 (`GALI_2 = |u1 + u2| |u1 - u2| / 2`).
/// `None` when fewer than two vectors are given.
pub fn sali(vectors: &[f64], dim: usize) -> Option<f64> {
    if vectors.len() < 2 * dim {
        return None;
    }
    let u = unit_columns(&vectors[..2 * dim], dim);
    let plus = (u.column(0) + u.column(1)).norm();
    let minus = (u.column(0) - u.column(1)).norm();
    Some(plus.min(minus))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn gali_of_orthonormal_is_one_and_of_aligned_is_small() {
        let e = [1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 3.0, 0.0];
        let g = gali_log10(&e, 4);
        assert_eq!(g.len(), 2);
        assert!(g.iter().all(|v| v.abs() < 1e-15), "{g:?}");
        // Two vectors at angle theta: GALI_2 = |sin theta|.
        let th: f64 = 1e-3;
        let v = [1.0, 0.0, th.cos(), th.sin()];
        let g2 = 10f64.powf(gali_log10(&v, 2)[0]);
        assert!((g2 - th.sin()).abs() < 1e-12, "{g2}");
        // SALI = 2 sin(theta/2) for the nearly parallel pair, and GALI_2 = SALI * |u1+u2| / 2.
        let s = sali(&v, 2).unwrap();
        assert!((s - 2.0 * (th / 2.0).sin()).abs() < 1e-15);
        assert_eq!(sali(&v[..2], 2), None);
    }

    #[test]
    fn gali_equals_product_of_qr_diagonal() {
        // The volume is basis independent: prod sigma_i = prod |R_ii| of the unit-vector matrix.
        let v: Vec<f64> = (0..24)
            .map(|i| ((i * 7 % 11) as f64 - 5.0) / 3.0 + 0.1 * i as f64)
            .collect();
        let g = gali_log10(&v, 6);
        let u = unit_columns(&v, 6);
        for j in 2..=4 {
            let r = u.columns(0, j).clone_owned().qr().r();
            let want: f64 = (0..j).map(|i| r[(i, i)].abs().log10()).sum();
            assert!(
                (g[j - 2] - want).abs() < 1e-12,
                "GALI_{j}: {} vs {want}",
                g[j - 2]
            );
        }
    }
}
