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
