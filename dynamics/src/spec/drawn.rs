//! Array parameters drawn from a seed (`eps = { uniform = [0.5, 1.5], seed = 7 }`): disorder
//! realizations written in two numbers.
//!
//! The draw is fixed here once and for all, so a config gives the same array on every machine,
//! thread count and version (recordings carry the config, not the drawn values): a ChaCha20
//! stream seeded by `seed_from_u64(seed)` (rand_core's documented seeding), stream 0, and entry
//! `l` (from 1) is `lo + (hi - lo) u_l` with `u_l = (x_l >> 11) 2^-53` for the `l`-th 64-bit
//! output `x_l`: 53 random bits, so `u_l` is uniform on the doubles `k 2^-53` of `[0, 1)`.
//! Neither a `rand` distribution (whose algorithm may change between versions) nor floating
//! point beyond one multiply-add in a fixed order is involved.

use rand::{RngCore, SeedableRng};
use rand_chacha::ChaCha20Rng;

/// `n` entries uniform in `[lo, hi)` from `seed`, as the module header says.
pub fn uniform(lo: f64, hi: f64, seed: u64, n: usize) -> Vec<f64> {
    let mut rng = ChaCha20Rng::seed_from_u64(seed);
    let width = hi - lo;
    (0..n)
        .map(|_| {
            let u = (rng.next_u64() >> 11) as f64 * (1.0 / (1u64 << 53) as f64);
            lo + width * u
        })
        .collect()
}

/// `n` signs `+1.0` or `-1.0` from `seed`, the top bit of each 64-bit output of the same
/// stream (1 gives `-1`).
pub fn signs(seed: u64, n: usize) -> Vec<f64> {
    let mut rng = ChaCha20Rng::seed_from_u64(seed);
    (0..n)
        .map(|_| if rng.next_u64() >> 63 == 1 { -1.0 } else { 1.0 })
        .collect()
}

/// Why `[lo, hi]` cannot be drawn from (both finite, `lo < hi`), or `None`.
pub fn range_problem(lo: f64, hi: f64) -> Option<String> {
    if !(lo.is_finite() && hi.is_finite()) {
        // `{:?}`: the shortest form (`1e308`), not 309 digits.
        return Some(format!("uniform = [{lo:?}, {hi:?}] must be finite"));
    }
    // Both finite here, so `>=` is the negation of `<`.
    if lo >= hi || !(hi - lo).is_finite() {
        return Some(format!(
            "uniform = [{lo:?}, {hi:?}] needs lo < hi (and a finite width)"
        ));
    }
    None
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn draws_are_in_range_reproducible_and_differ_between_seeds() {
        let a = uniform(0.5, 1.5, 7, 1000);
        assert_eq!(a, uniform(0.5, 1.5, 7, 1000));
        assert_ne!(a, uniform(0.5, 1.5, 8, 1000));
        assert!(a.iter().all(|&x| (0.5..1.5).contains(&x)));
        // A prefix does not depend on how many entries follow it.
        assert_eq!(uniform(0.5, 1.5, 7, 10), a[..10]);
        // Mean 1 and variance 1/12 of U[1/2, 3/2], within 4 standard errors for 1000 draws
        // (sd of the mean 0.0091, of the variance ~0.0024).
        let mean = a.iter().sum::<f64>() / 1000.0;
        let var = a.iter().map(|x| (x - mean) * (x - mean)).sum::<f64>() / 999.0;
        assert!((mean - 1.0).abs() < 0.037, "mean {mean}");
        assert!((var - 1.0 / 12.0).abs() < 0.01, "variance {var}");
    }

    /// The first entries of seed 1, pinned: the draw is a contract (a recorded config must
    /// give the same disorder in every later version).
    #[test]
    fn the_draw_is_pinned() {
        let got = uniform(0.5, 1.5, 1, 3);
        assert_eq!(
            got,
            [1.1187038583014022, 0.6530042583196669, 1.0467185131369483]
        );
        assert_eq!(signs(3, 4), [-1.0, 1.0, 1.0, -1.0]);
    }

    #[test]
    fn bad_ranges_are_named() {
        assert!(range_problem(0.5, 1.5).is_none());
        assert!(range_problem(1.5, 0.5).unwrap().contains("lo < hi"));
        assert!(range_problem(1.0, 1.0).unwrap().contains("lo < hi"));
        assert!(range_problem(f64::NAN, 1.0).unwrap().contains("finite"));
        assert!(
            range_problem(-f64::MAX, f64::MAX)
                .unwrap()
                .contains("finite width")
        );
    }
}
