//! Initial deviation directions: `k` orthonormal vectors in the `2N`-dimensional phase space.
//!
//! Random sets are Haar-distributed (QR of a Gaussian matrix with the sign of `R`'s diagonal
//! fixed), drawn from a ChaCha stream selected by the set index, so set `j` of seed `s` is the
//! same whatever the number of sets or threads. Explicit directions are orthonormalized in the
//! order given (Gram-Schmidt semantics), so the first direction keeps its own orientation.

use nalgebra::DMatrix;
use rand::SeedableRng;
use rand_chacha::ChaCha20Rng;
use rand_distr::{Distribution, StandardNormal};

/// `k` unit vectors of dimension `dim`, stored one after the other (`k * dim` numbers).
#[derive(Debug, Clone, PartialEq)]
pub struct Directions {
    pub dim: usize,
    pub k: usize,
    pub vectors: Vec<f64>,
}

impl Directions {
    pub fn vector(&self, i: usize) -> &[f64] {
        &self.vectors[i * self.dim..(i + 1) * self.dim]
    }

    /// The vectors scaled to length `d0`: a scheme's initial deviations.
    pub fn scaled(&self, d0: f64) -> Vec<f64> {
        self.vectors.iter().map(|u| d0 * u).collect()
    }
}

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum DirectionError {
    #[error(
        "k = {k} deviation vectors do not fit a {dim}-dimensional phase space (need 1 <= k <= {dim})"
    )]
    BadCount { k: usize, dim: usize },
    #[error("direction {index} has length {len}, expected 2N = {dim}")]
    BadLength {
        index: usize,
        len: usize,
        dim: usize,
    },
    #[error("direction {index} is not finite")]
    NotFinite { index: usize },
    #[error("direction {index} is (numerically) a combination of the previous ones")]
    Dependent { index: usize },
}

/// Orthonormalize the columns of `a` in order (Householder QR with the signs fixed so that
/// `R_ii > 0`: each vector keeps its orientation, as in Gram-Schmidt). Returns `Q` and the
/// `|R_ii|`. Fails with the index of the first column whose `|R_ii|` is not above
/// `rel_tol` times the largest column norm (dependent on the earlier ones).
pub(crate) fn orthonormal_columns(
    a: DMatrix<f64>,
    rel_tol: f64,
) -> Result<(DMatrix<f64>, Vec<f64>), usize> {
    let k = a.ncols();
    let scale = a.column_iter().map(|c| c.norm()).fold(0.0, f64::max);
    let qr = a.qr();
    let r = qr.r();
    let mut q = qr.q();
    let mut diag = Vec::with_capacity(k);
    for i in 0..k {
        let rii = r[(i, i)];
        if !rii.is_finite() || rii.abs() <= rel_tol * scale {
            return Err(i);
        }
        if rii < 0.0 {
            q.column_mut(i).neg_mut();
        }
        diag.push(rii.abs());
    }
    Ok((q, diag))
}

/// Directions closer to dependence than this (relative) are refused as user input.
const INPUT_DEPENDENCE_TOL: f64 = 1e-12;

/// Set `set` of `k` Haar-random orthonormal directions for seed `seed`.
pub fn random_directions(
    seed: u64,
    set: u64,
    dim: usize,
    k: usize,
) -> Result<Directions, DirectionError> {
    if k == 0 || k > dim {
        return Err(DirectionError::BadCount { k, dim });
    }
    let mut rng = ChaCha20Rng::seed_from_u64(seed);
    rng.set_stream(set);
    // Column-major fill: column i is the raw draw for vector i.
    let a = DMatrix::from_fn(dim, k, |_, _| StandardNormal.sample(&mut rng));
    // A Gaussian matrix is rank-deficient with probability zero; retrying would change the
    // stream, so a failure here is reported rather than papered over.
    let (q, _) = orthonormal_columns(a, INPUT_DEPENDENCE_TOL)
        .map_err(|index| DirectionError::Dependent { index })?;
    Ok(Directions {
        dim,
        k,
        vectors: q.as_slice().to_vec(),
    })
}

/// Orthonormalize explicit directions given as rows.
pub fn explicit_directions(rows: &[Vec<f64>], dim: usize) -> Result<Directions, DirectionError> {
    let k = rows.len();
    if k == 0 || k > dim {
        return Err(DirectionError::BadCount { k, dim });
    }
    for (index, r) in rows.iter().enumerate() {
        if r.len() != dim {
            return Err(DirectionError::BadLength {
                index,
                len: r.len(),
                dim,
            });
        }
        if r.iter().any(|v| !v.is_finite()) {
            return Err(DirectionError::NotFinite { index });
        }
    }
    let a = DMatrix::from_fn(dim, k, |i, j| rows[j][i]);
    let (q, _) = orthonormal_columns(a, INPUT_DEPENDENCE_TOL)
        .map_err(|index| DirectionError::Dependent { index })?;
    Ok(Directions {
        dim,
        k,
        vectors: q.as_slice().to_vec(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn assert_orthonormal(d: &Directions) {
        for i in 0..d.k {
            for j in 0..d.k {
                let dot: f64 = d
                    .vector(i)
                    .iter()
                    .zip(d.vector(j))
                    .map(|(a, b)| a * b)
                    .sum();
                let want = if i == j { 1.0 } else { 0.0 };
                assert!((dot - want).abs() < 1e-14, "<{i},{j}> = {dot}");
            }
        }
    }

    #[test]
    fn random_sets_are_orthonormal_reproducible_and_independent() {
        let a = random_directions(42, 0, 10, 6).unwrap();
        assert_orthonormal(&a);
        assert_eq!(a, random_directions(42, 0, 10, 6).unwrap());
        assert_ne!(a, random_directions(42, 1, 10, 6).unwrap());
        assert_ne!(a, random_directions(43, 0, 10, 6).unwrap());
    }

    #[test]
    fn explicit_keeps_first_direction_and_rejects_dependence() {
        let d =
            explicit_directions(&[vec![0.0, 2.0, 0.0, 0.0], vec![1.0, 1.0, 0.0, 0.0]], 4).unwrap();
        assert_orthonormal(&d);
        let want = [0.0, 1.0, 0.0, 0.0];
        assert!(
            d.vector(0)
                .iter()
                .zip(want)
                .all(|(a, b)| (a - b).abs() < 1e-15),
            "{:?}",
            d.vector(0)
        );
        assert!((d.vector(1)[0] - 1.0).abs() < 1e-15);
        let e = explicit_directions(&[vec![1.0, 0.0, 0.0, 0.0], vec![2.0, 0.0, 0.0, 0.0]], 4);
        assert_eq!(e, Err(DirectionError::Dependent { index: 1 }));
        assert!(matches!(
            explicit_directions(&[vec![1.0; 3]], 4),
            Err(DirectionError::BadLength { .. })
        ));
        assert!(matches!(
            explicit_directions(&[vec![f64::NAN; 4]], 4),
            Err(DirectionError::NotFinite { .. })
        ));
    }
}
