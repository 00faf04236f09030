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
///
/// `periodic` says which axes close on themselves (a ring; a cylinder or a torus: along the
/// rows' index `i`, then the columns' `j`; a chain reads the first): distances along such an
/// axis are taken around it ([`periodic_spread`]), so a packet astride the seam has the second
/// moment it has anywhere else on the ring.
pub fn moments_on(
    weights: impl Iterator<Item = f64> + Clone,
    square_side: Option<usize>,
    periodic: [bool; 2],
) -> Option<(f64, f64)> {
    if periodic[0] || (square_side.is_some() && periodic[1]) {
        return periodic_moments(weights, square_side, periodic);
    }
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

/// [`moments_on`] with at least one periodic axis: the spread along each axis from the
/// marginal weights over it (the plane's `m2` is the sum of the two axes'), a periodic axis's by
/// [`periodic_spread`].
fn periodic_moments(
    weights: impl Iterator<Item = f64> + Clone,
    square_side: Option<usize>,
    periodic: [bool; 2],
) -> Option<(f64, f64)> {
    let sites = weights.clone().count();
    let total: f64 = weights.clone().sum();
    if !(total.is_finite() && total > 0.0) {
        return None;
    }
    let (rows, columns) = match square_side {
        Some(side) if side.checked_mul(side) == Some(sites) => (side, side),
        Some(_) => return None,
        None => (sites, 1),
    };
    let mut marginals = [vec![0.0; rows], vec![0.0; columns]];
    let mut squares = 0.0;
    for (l, w) in weights.enumerate() {
        let xi = w / total;
        marginals[0][l / columns] += xi;
        marginals[1][l % columns] += xi;
        squares += xi * xi;
    }
    let m2 = marginals
        .iter()
        .zip(periodic)
        .map(|(m, closed)| {
            if closed {
                periodic_spread(m)
            } else {
                spread(m.iter().enumerate().map(|(i, &x)| (i as f64, x)))
            }
        })
        .sum();
    Some((m2, 1.0 / squares))
}

/// `sum x (r - rbar)^2` over `(r, x)` with `sum x = 1`.
fn spread(points: impl Iterator<Item = (f64, f64)> + Clone) -> f64 {
    let mean: f64 = points.clone().map(|(r, x)| r * x).sum();
    points.map(|(r, x)| (r - mean) * (r - mean) * x).sum()
}

/// The spread of normalized weights `xi` around a ring of `n = xi.len()` sites: the least
/// [`spread`] over the `n` places where the ring can be cut open into a chain (the packet whole
/// on one side of the cut). Away from the seam that is the chain's spread whenever the ring
/// holds a cut through empty sites; a packet astride the seam gets the spread it has elsewhere.
/// Every cut is weighed in one pass (sums over the sites before the cut), the chosen one's
/// spread then computed as [`spread`] computes it.
fn periodic_spread(xi: &[f64]) -> f64 {
    let n = xi.len();
    if n < 2 {
        return 0.0;
    }
    // Cut before site k: sites k.. sit at r - k, sites ..k at r - k + n. With S0, S1, S2 the
    // sums of x, r x, r^2 x over the sites before k (and totals T1, T2), the spread is
    // E[(r - k)^2] + 2 n (S1 - k S0) + n^2 S0 - (E[r] - k + n S0)^2.
    let (t1, t2) = xi.iter().enumerate().fold((0.0, 0.0), |(a, b), (r, &x)| {
        let r = r as f64;
        (a + r * x, b + r * r * x)
    });
    let nf = n as f64;
    let (mut s0, mut s1) = (0.0f64, 0.0f64);
    let (mut best, mut best_cut) = (f64::INFINITY, 0);
    for (k, &x) in xi.iter().enumerate() {
        let kf = k as f64;
        let second = t2 - 2.0 * kf * t1 + kf * kf + 2.0 * nf * (s1 - kf * s0) + nf * nf * s0;
        let mean = t1 - kf + nf * s0;
        let value = second - mean * mean;
        if value < best {
            (best, best_cut) = (value, k);
        }
        s0 += x;
        s1 += kf * x;
    }
    let k = best_cut;
    spread(
        xi.iter()
            .enumerate()
            .map(|(r, &x)| (((r + n - k) % n) as f64, x)),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    fn on_square(side: usize, weights: &[f64]) -> (f64, f64) {
        moments_on(weights.iter().copied(), Some(side), [false; 2]).expect("a distribution")
    }

    /// Around a ring or a torus the second moment does not depend on where the packet sits:
    /// a packet astride the seam has the spread it has in the middle (before, a ring's seam
    /// made a three-site packet on 64 sites look 200 times wider), and one away from the seam
    /// has the chain's.
    #[test]
    fn a_periodic_axis_measures_distances_around_it() {
        let packet = [0.25, 0.5, 0.25]; // spread 0.5 about the middle site
        for n in [3usize, 8, 64] {
            for start in 0..n {
                let mut w = vec![0.0; n];
                for (i, x) in packet.iter().enumerate() {
                    w[(start + i) % n] += x;
                }
                let (m2, p) = moments_on(w.iter().copied(), None, [true, false]).unwrap();
                assert!((m2 - 0.5).abs() < 1e-15, "n {n} start {start}: {m2}");
                assert!((p - 1.0 / 0.375).abs() < 1e-12);
            }
        }
        // In the middle of a long ring, the chain's value (to rounding: the mean is taken
        // from another origin).
        let mut w = vec![0.0; 64];
        (w[30], w[31], w[33]) = (0.2, 0.5, 0.3);
        let ring = moments_on(w.iter().copied(), None, [true, false])
            .unwrap()
            .0;
        let chain = moments(w.iter().copied()).unwrap().0;
        assert!((ring - chain).abs() < 1e-14 * chain, "{ring} {chain}");
        // A torus: the same packet in the corner (astride both seams) and in the middle; a
        // cylinder periodic along j only: the corner's spread along i is the chain's.
        let side = 9;
        let place = |i0: usize, j0: usize| {
            let mut w = vec![0.0; side * side];
            for (di, a) in packet.iter().enumerate() {
                for (dj, b) in packet.iter().enumerate() {
                    w[((i0 + di) % side) * side + (j0 + dj) % side] += a * b;
                }
            }
            w
        };
        let torus = |w: &[f64], periodic| moments_on(w.iter().copied(), Some(side), periodic);
        let middle = torus(&place(3, 3), [true, true]).unwrap().0;
        assert!((middle - 1.0).abs() < 1e-15, "{middle}");
        assert!((torus(&place(8, 8), [true, true]).unwrap().0 - 1.0).abs() < 1e-15);
        let cylinder = torus(&place(8, 8), [false, true]).unwrap().0;
        // Along i the packet is cut by the fixed edge: rows 8, 0, 1 (weights 1/4, 1/2, 1/4).
        let along_i = spread([(8.0, 0.25), (0.0, 0.5), (1.0, 0.25)].into_iter());
        assert!((cylinder - (along_i + 0.5)).abs() < 1e-12, "{cylinder}");
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
            moments_on(w.iter().copied(), None, [false; 2]),
            moments(w.iter().copied())
        );
        // Five weights on a 2 x 2 square, or a side so large that its square overflows.
        for periodic in [[false; 2], [true; 2]] {
            assert_eq!(moments_on(w.iter().copied(), Some(2), periodic), None);
            assert_eq!(
                moments_on(w.iter().copied(), Some(usize::MAX), periodic),
                None
            );
            assert_eq!(moments_on([0.0; 4].into_iter(), Some(2), periodic), None);
        }
    }
}
