//! Renormalization of deviation vectors every `tau`.
//!
//! Two modes: per-vector rescaling (each vector back to norm `d0`, directions untouched: what
//! GALI and SALI need, since they measure how the directions align) and QR (Gram-Schmidt: the
//! vectors are made orthonormal again, and `|R_ii|` are the stretching factors of the standard
//! method for the Lyapunov spectrum).

use chaoscope_schemas::run::Orthonormalization;

use crate::deviation::orthonormal_columns;
use nalgebra::DMatrix;

/// A renormalization failed: a vector vanished or stopped being finite (an escaping orbit, or
/// vectors that became linearly dependent to machine precision in QR mode).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum RenormalizationError {
    #[error("deviation vector {index} is not finite (norm {norm})")]
    NotFinite { index: usize, norm: f64 },
    #[error("deviation vector {index} vanished")]
    Vanished { index: usize },
    #[error("deviation vectors became linearly dependent at vector {index}")]
    Dependent { index: usize },
}

fn norm(v: &[f64]) -> f64 {
    v.iter().map(|x| x * x).sum::<f64>().sqrt()
}

/// Renormalize `k` vectors of length `dim` stored in `vectors` to norm `d0` in place, writing the
/// stretching factor of each (its growth since it last had norm `d0`) to `stretch`.
pub fn renormalize(
    vectors: &mut [f64],
    dim: usize,
    d0: f64,
    mode: Orthonormalization,
    stretch: &mut [f64],
) -> Result<(), RenormalizationError> {
    let k = vectors.len() / dim;
    for (index, v) in vectors.chunks_exact(dim).enumerate() {
        let n = norm(v);
        if !n.is_finite() {
            return Err(RenormalizationError::NotFinite { index, norm: n });
        }
        if n == 0.0 {
            return Err(RenormalizationError::Vanished { index });
        }
    }
    match mode {
        Orthonormalization::Rescale => {
            for (v, s) in vectors.chunks_exact_mut(dim).zip(stretch.iter_mut()) {
                let n = norm(v);
                *s = n / d0;
                let f = d0 / n;
                v.iter_mut().for_each(|x| *x *= f);
            }
        }
        Orthonormalization::Qr => {
            let a = DMatrix::from_column_slice(dim, k, vectors) / d0;
            // Strongly contracted directions legitimately have tiny R_ii (that is the measured
            // spectrum); only an exact collapse is an error.
            let (q, diag) = orthonormal_columns(a, 0.0)
                .map_err(|index| RenormalizationError::Dependent { index })?;
            stretch[..k].copy_from_slice(&diag);
            for (dst, src) in vectors.iter_mut().zip(q.as_slice()) {
                *dst = d0 * src;
            }
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rescale_keeps_directions() {
        let mut v = vec![3.0, 4.0, 0.0, 0.0, 0.0, 0.0, 0.0, 2.0];
        let mut s = vec![0.0; 2];
        renormalize(&mut v, 4, 0.5, Orthonormalization::Rescale, &mut s).unwrap();
        assert_eq!(s, vec![10.0, 4.0]);
        let want = [0.3, 0.4, 0.0, 0.0, 0.0, 0.0, 0.0, 0.5];
        assert!(
            v.iter().zip(want).all(|(a, b)| (a - b).abs() < 1e-16),
            "{v:?}"
        );
    }

    #[test]
    fn qr_stretch_is_gram_schmidt() {
        // v1 = (2, 0), v2 = (1, 3): GS gives |R11| = 2, |R22| = 3 (in units of d0 = 1).
        let mut v = vec![2.0, 0.0, 1.0, 3.0];
        let mut s = vec![0.0; 2];
        renormalize(&mut v, 2, 1.0, Orthonormalization::Qr, &mut s).unwrap();
        assert!(
            (s[0] - 2.0).abs() < 1e-15 && (s[1] - 3.0).abs() < 1e-15,
            "{s:?}"
        );
        let expect = [1.0, 0.0, 0.0, 1.0];
        for (a, b) in v.iter().zip(expect) {
            assert!((a - b).abs() < 1e-15, "{v:?}");
        }
    }

    #[test]
    fn broken_vectors_are_reported() {
        let mut s = vec![0.0; 1];
        let mut v = vec![f64::INFINITY, 0.0];
        assert!(renormalize(&mut v, 2, 1.0, Orthonormalization::Rescale, &mut s).is_err());
        let mut v = vec![0.0, 0.0];
        assert!(renormalize(&mut v, 2, 1.0, Orthonormalization::Rescale, &mut s).is_err());
    }
}
