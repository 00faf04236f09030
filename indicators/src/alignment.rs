//! Alignment indices of deviation vectors: GALI (the volume of the unit vectors) and SALI.

use nalgebra::DMatrix;

use crate::indicator::{Declared, Needs, Output, SetIndicator, SetObservation};

/// Smallest singular value taken into a GALI product. The unit vectors carry rounding errors of
/// order machine epsilon, so a singular value below it is not resolved: once chaotic deviation
/// vectors have aligned to the last bit a singular value becomes exactly zero (`log10 = -inf`).
/// Such values are reported as epsilon, meaning "at or below double precision"; a GALI at
/// `eps^m` says that `m` directions have collapsed.
pub const SIGMA_FLOOR: f64 = f64::EPSILON;

/// `log10 GALI_j` for `j = 2..=k`, where `GALI_j` is the volume spanned by the first `j` of the
/// `k` vectors (each normalized to unit length first). Returns `k - 1` values (empty for
/// `k < 2`). One QR factorization gives them all ([`volume_log10_each`]).
pub fn gali_log10(vectors: &[f64], dim: usize) -> Vec<f64> {
    let k = vectors.len() / dim;
    if k < 2 {
        return Vec::new();
    }
    let mut gali = Vec::with_capacity(k - 1);
    volume_log10_each(vectors, dim, k, &mut Vec::new(), |j, log| {
        if j > 0 {
            gali.push(log);
        }
    });
    gali
}

/// `log10 GALI_k`: the volume spanned by the `k` unit vectors of length `dim` in `vectors`, as
/// [`gali_log10`] computes it, bit for bit, without allocating once `scratch` has grown (the
/// maps evaluate it at every renormalization of every set of every point).
pub fn volume_log10(vectors: &[f64], dim: usize, k: usize, scratch: &mut Vec<f64>) -> f64 {
    volume_log10_each(vectors, dim, k, scratch, |_, _| {})
}

/// Calls `each(j, log10 of the volume spanned by the first j + 1 vectors)` for `j = 0..k` and
/// returns the whole volume's, the vectors (of length `dim`) normalized to unit length first.
/// The volume is `prod |R_ii|` of their QR factorization, computed by modified Gram-Schmidt
/// with one re-orthogonalization pass, which keeps `R` accurate down to nearly parallel vectors:
/// the product of the singular values to rounding (tested against the SVD below), at a fraction
/// of its cost. Each `|R_ii|` is floored at [`SIGMA_FLOOR`]: below it nothing is resolved.
fn volume_log10_each(
    vectors: &[f64],
    dim: usize,
    k: usize,
    scratch: &mut Vec<f64>,
    mut each: impl FnMut(usize, f64),
) -> f64 {
    scratch.clear();
    scratch.extend_from_slice(&vectors[..k * dim]);
    for v in scratch.chunks_exact_mut(dim) {
        let n = norm(v);
        if n > 0.0 {
            v.iter_mut().for_each(|x| *x /= n);
        }
    }
    let mut log = 0.0;
    for j in 0..k {
        let (done, rest) = scratch.split_at_mut(j * dim);
        let v = &mut rest[..dim];
        for _pass in 0..2 {
            for q in done.chunks_exact(dim) {
                let r: f64 = q.iter().zip(v.iter()).map(|(a, b)| a * b).sum();
                v.iter_mut().zip(q).for_each(|(x, qi)| *x -= r * qi);
            }
        }
        let r = norm(v);
        log += r.max(SIGMA_FLOOR).log10();
        if r > 0.0 {
            v.iter_mut().for_each(|x| *x /= r);
        }
        each(j, log);
    }
    log
}

fn norm(v: &[f64]) -> f64 {
    v.iter().map(|x| x * x).sum::<f64>().sqrt()
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

/// GALI and SALI of a set as a registered indicator, of the `k` vectors observed last: every
/// order `log10 GALI_2..k` from one [`gali_log10`] (the `gali` output is `GALI_k`, the bits of
/// [`volume_log10`]), and their [`sali`], whose output is its `log10` floored at [`SIGMA_FLOOR`]
/// like GALI's singular values (below it the two directions are not resolved in double
/// precision, and `log10 0` is no number). The tracker reads every order and the SALI itself
/// ([`Alignment::gali_log10`], [`Alignment::sali`]); a map point its outputs.
#[derive(Debug, Clone, Default)]
pub struct Alignment {
    gali: Vec<f64>,
    sali: Option<f64>,
}

impl Alignment {
    /// `log10 GALI_j`, `j = 2..=k`, of the vectors observed last (empty for `k < 2` or before
    /// any).
    pub fn gali_log10(&self) -> &[f64] {
        &self.gali
    }

    /// The SALI of the first two vectors observed last, not floored (`None` for `k < 2` or
    /// before any).
    pub fn sali(&self) -> Option<f64> {
        self.sali
    }
}

impl SetIndicator for Alignment {
    fn declared(&self) -> &'static [Declared] {
        const DECLARED: &[Declared] = &[
            Declared::own("gali", Needs::FINAL_PAIR).in_log10(),
            Declared::own("sali", Needs::FINAL_PAIR).in_log10(),
        ];
        DECLARED
    }

    fn observe(&mut self, obs: &SetObservation<'_>) {
        // A renormalization between samples has no vectors: the last ones stand.
        if !obs.separations.is_empty() {
            self.gali = gali_log10(obs.separations, obs.dim);
            self.sali = sali(obs.separations, obs.dim);
        }
    }

    fn outputs(&self) -> Vec<Output> {
        let why = || Output::Unavailable("the alignment of vectors needs two of them".into());
        vec![
            self.gali.last().copied().map_or_else(why, Output::Value),
            self.sali
                .map(|s| s.max(SIGMA_FLOOR).log10())
                .map_or_else(why, Output::Value),
        ]
    }

    fn boxed_clone(&self) -> Box<dyn SetIndicator> {
        Box::new(self.clone())
    }
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

    /// The product of the singular values, each floored as the `|R_ii|` are.
    fn svd_log10(vectors: &[f64], dim: usize, j: usize) -> f64 {
        unit_columns(vectors, dim)
            .columns(0, j)
            .clone_owned()
            .singular_values()
            .iter()
            .map(|s| s.max(SIGMA_FLOOR).log10())
            .sum()
    }

    #[test]
    fn gali_is_the_product_of_the_singular_values() {
        // The volume is basis independent: prod |R_ii| = prod sigma_i of the unit vectors.
        let v: Vec<f64> = (0..24)
            .map(|i| ((i * 7 % 11) as f64 - 5.0) / 3.0 + 0.1 * i as f64)
            .collect();
        let g = gali_log10(&v, 6);
        for j in 2..=4 {
            let want = svd_log10(&v, 6, j);
            assert!(
                (g[j - 2] - want).abs() < 1e-12,
                "GALI_{j}: {} vs {want}",
                g[j - 2]
            );
        }
        // Nearly dependent sets: log10 of a volume of size `e^m` is resolved to rounding of
        // the smallest singular value, eps / e^m relative, so 1e-6 decades is a loose bound down
        // to e = 1e-9.
        for e in [1.0, 1e-3, 1e-6, 1e-9] {
            #[rustfmt::skip]
            let v = [
                0.3, -0.2, 0.7, 0.1,
                0.3 + e, -0.2, 0.7, 0.1 - e,
                0.3, -0.2 + 2.0 * e, 0.7 + e, 0.1,
                -0.5, 0.4, 0.2 * e, 0.9,
            ];
            let g = gali_log10(&v, 4);
            for j in 2..=4 {
                let want = svd_log10(&v, 4, j);
                assert!(
                    (g[j - 2] - want).abs() < 1e-6,
                    "e {e} GALI_{j}: {} vs {want}",
                    g[j - 2]
                );
            }
        }
    }
}
