//! A distribution over the sites of a lattice, from non-negative weights per site: its
//! normalized weights, second moment about the mean site and participation number. The one
//! definition the deviation vector distribution ([`crate::dvd`]) and the energy distribution
//! ([`crate::energy`]) share (Skokos, Gkolias and Flach, PRL 111, 064101 (2013); Senyange,
//! Many Manda and Skokos, PRE 98, 052229 (2018)).
//!
//! With weights `w_l` (sites numbered from 1), `xi_l = w_l / sum w`, the mean site
//! `lbar = sum_l l xi_l`, the second moment `m2 = sum_l (l - lbar)^2 xi_l` (0 on one site, the
//! spread of the distribution in sites squared) and the participation number
//! `P = 1 / sum_l xi_l^2` (1 on one site, `N` spread evenly).
//!
//! On an `L x L` square lattice (sites numbered row by row: site `l`, from 0, at row `l / L`
//! and column `l % L`) the distance is the plane's: with `r_l` the site's position,
//! `m2 = sum_l |r_l - rbar|^2 xi_l` about the mean position `rbar = sum_l r_l xi_l` (Many Manda,
//! Senyange and Skokos, PRE 101, 032206 (2020)), never the chain's over the flattened index,
//! which would count a step to the next row as `L` sites. `P` needs no geometry.

/// The normalized weights `xi_l = w_l / sum w`; `None` when the weights are not finite or
/// their sum is not positive.
pub fn normalized(weights: impl Iterator<Item = f64> + Clone) -> Option<Vec<f64>> {
    let total: f64 = weights.clone().sum();
    (total.is_finite() && total > 0.0).then(|| weights.map(|w| w / total).collect())
}

/// The second moment about the mean site and the participation number of the distribution whose
/// unnormalized weights are `weights` (sites numbered from 1); `None` when they are not finite or
/// all zero.
pub fn moments(weights: impl Iterator<Item = f64> + Clone) -> Option<(f64, f64)> {
    let total: f64 = weights.clone().sum();
    if !(total.is_finite() && total > 0.0) {
        return None;
    }
    let (mut mean, mut squares) = (0.0, 0.0);
    for (l, w) in weights.clone().enumerate() {
        let xi = w / total;
        mean += (l + 1) as f64 * xi;
        squares += xi * xi;
    }
    let m2 = weights
        .enumerate()
        .map(|(l, w)| {
            let d = (l + 1) as f64 - mean;
            d * d * (w / total)
        })
        .sum();
    Some((m2, 1.0 / squares))
}

/// The mean site `lbar = sum_l l xi_l` (sites numbered from 1); `None` as [`moments`].
pub fn mean_site(weights: impl Iterator<Item = f64> + Clone) -> Option<f64> {
    let xi = normalized(weights)?;
    Some(xi.iter().enumerate().map(|(l, x)| (l + 1) as f64 * x).sum())
}

/// [`moments`] over the lattice `square_side` describes: `None` a chain (exactly [`moments`]),
/// `Some(L)` an `L x L` square lattice numbered row by row, whose second moment is
/// `sum_l |r_l - rbar|^2 xi_l` over the plane. `None` (the result) as [`moments`], or when the
/// square does not hold the weights (`L^2` differs from their number).
pub fn moments_on(
    weights: impl Iterator<Item = f64> + Clone,
    square_side: Option<usize>,
) -> Option<(f64, f64)> {
    let Some(side) = square_side else {
        return moments(weights);
    };
    let sites = weights.clone().count();
    if side.checked_mul(side) != Some(sites) {
        return None;
    }
    let total: f64 = weights.clone().sum();
    if !(total.is_finite() && total > 0.0) {
        return None;
    }
    let position = |l: usize| ((l / side) as f64, (l % side) as f64);
    let (mut row, mut column, mut squares) = (0.0, 0.0, 0.0);
    for (l, w) in weights.clone().enumerate() {
        let xi = w / total;
        let (i, j) = position(l);
        row += i * xi;
        column += j * xi;
        squares += xi * xi;
    }
    let m2 = weights
        .enumerate()
        .map(|(l, w)| {
            let (i, j) = position(l);
            let (di, dj) = (i - row, j - column);
            (di * di + dj * dj) * (w / total)
        })
        .sum();
    Some((m2, 1.0 / squares))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn on_square(side: usize, weights: &[f64]) -> (f64, f64) {
        moments_on(weights.iter().copied(), Some(side)).expect("a distribution")
    }

    #[test]
    fn the_plane_second_moment_is_the_geometry_s() {
        // One site of a 5 x 5 square: no spread (m2 = 0), one site (P = 1).
        let mut w = vec![0.0; 25];
        w[12] = 0.3;
        assert_eq!(on_square(5, &w), (0.0, 1.0));
        // Two equal weights a distance d apart, each d / 2 from their midpoint: m2 = d^2 / 4,
        // P = 2, whatever the direction: d = 1 across a row, d = 1 down a column
        // (flattened, 5 sites apart: the chain's m2 would be 25 / 4), d = sqrt(2) diagonally,
        // d = 4 corner to corner along the top row.
        for (a, b, d2) in [(12, 13, 1.0), (12, 17, 1.0), (12, 18, 2.0), (0, 4, 16.0)] {
            let mut w = vec![0.0; 25];
            (w[a], w[b]) = (0.5, 0.5);
            let (m2, p) = on_square(5, &w);
            assert!(
                (m2 - d2 / 4.0).abs() < 1e-15 && (p - 2.0).abs() < 1e-15,
                "{a} {b}: {m2} {p}"
            );
        }
        // Evenly over an n x n square: each coordinate is uniform over n values, variance
        // (n^2 - 1) / 12, so m2 = (n^2 - 1) / 6 and P = n^2 (to rounding of 49 sums).
        for n in [1usize, 2, 7] {
            let (m2, p) = on_square(n, &vec![2.0; n * n]);
            let want = (n * n - 1) as f64 / 6.0;
            assert!(
                (m2 - want).abs() < 1e-13 && (p - (n * n) as f64).abs() < 1e-12,
                "{n}: {m2} {p}"
            );
        }
    }

    #[test]
    fn a_chain_is_the_flat_moments_and_a_square_must_fit() {
        let w = [0.1, 0.0, 0.7, 0.2, 0.4];
        assert_eq!(
            moments_on(w.iter().copied(), None),
            moments(w.iter().copied())
        );
        // Five weights on a 2 x 2 square, or a side so large that its square overflows.
        assert_eq!(moments_on(w.iter().copied(), Some(2)), None);
        assert_eq!(moments_on(w.iter().copied(), Some(usize::MAX)), None);
        assert_eq!(moments_on([0.0; 4].into_iter(), Some(2)), None);
    }
}
