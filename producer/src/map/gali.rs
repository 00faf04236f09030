//! `log10 GALI_k` of `k` separation vectors, without allocation: the volume of the unit vectors
//! as `prod |R_jj|` of their QR factorization (modified Gram-Schmidt with one re-orthogonalization
//! pass, which keeps `R` accurate down to nearly parallel vectors).
//!
//! The same quantity as [`crate::indicators::gali_log10`] (product of singular values) to
//! rounding, at a fraction of the cost: a `gali-time` map evaluates it at every renormalization
//! of every set of every point.

use crate::indicators::SIGMA_FLOOR;

/// `log10 GALI_k` of the first `k` vectors of length `dim` in `vectors`. Each `|R_jj|` is floored
/// at [`SIGMA_FLOOR`] as the singular values are in `gali_log10`: below it nothing is resolved.
/// `scratch` is resized as needed and reused across calls.
pub fn log10_gali(vectors: &[f64], dim: usize, k: usize, scratch: &mut Vec<f64>) -> f64 {
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
    }
    log
}

fn norm(v: &[f64]) -> f64 {
    v.iter().map(|x| x * x).sum::<f64>().sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::indicators::gali_log10;

    #[test]
    fn agrees_with_the_svd_definition() {
        let mut scratch = Vec::new();
        // Well conditioned and nearly dependent sets, k = 2..4 in dim 4.
        for eps in [1.0, 1e-3, 1e-6, 1e-9] {
            let v = [
                0.3,
                -0.2,
                0.7,
                0.1, //
                0.3 + eps,
                -0.2,
                0.7,
                0.1 - eps, //
                0.3,
                -0.2 + 2.0 * eps,
                0.7 + eps,
                0.1, //
                -0.5,
                0.4,
                0.2 * eps,
                0.9,
            ];
            let svd = gali_log10(&v, 4);
            for k in 2..=4 {
                let qr = log10_gali(&v, 4, k, &mut scratch);
                assert!(
                    (qr - svd[k - 2]).abs() < 1e-6,
                    "eps {eps} k {k}: {qr} vs {}",
                    svd[k - 2]
                );
            }
        }
    }
}
