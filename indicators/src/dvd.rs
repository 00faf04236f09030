//! The deviation vector distribution (DVD) over the sites of a lattice: how a deviation vector's
//! weight spreads over the sites, the measure of where chaos lives in a chain (Skokos, Gkolias
//! and Flach, PRL 111, 064101 (2013); Senyange, Many Manda and Skokos, PRE 98, 052229 (2018)).
//!
//! At each renormalization of a set, its first deviation vector `w = (dq_1..dq_N, dp_1..dp_N)`
//! gives the weights `xi_l = (dq_l^2 + dp_l^2) / |w|^2` of the `N` sites (they sum to 1), and
//! two numbers of the distribution ([`crate::distribution`], shared with the energy
//! distribution): its second moment about its mean site, `m2 = sum_l (l - lbar)^2 xi_l` with
//! `lbar = sum_l l xi_l`, and its participation number `P = 1 / sum_l xi_l^2` (1 on one site,
//! `N` spread evenly); on a square lattice the second moment is over the plane
//! ([`crate::distribution::moments_on`]). The first vector is the one whose stretching the maximal Lyapunov
//! exponent measures.
//!
//! Sites are the degrees of freedom of a Hamiltonian (`q_l`, `p_l`); a run whose system has none
//! (a flow, a map) gets the outputs as unavailable, with the reason.

use crate::distribution::moments_on;
use crate::indicator::{Declared, Needs, Output, SetIndicator, SetObservation};

/// The DVD's second moment and participation number at the latest renormalization.
#[derive(Debug, Clone, Default)]
pub struct DeviationDistribution {
    /// `(m2, P)` of the latest observation; `None` before one, or when the run has no sites.
    latest: Option<(f64, f64)>,
    /// Observed without sites (a flow or a map).
    no_sites: bool,
}

/// The unnormalized DVD weights `dq_l^2 + dp_l^2` of the `N` sites of a vector `w` of `2N`
/// entries (`(q_1..q_N, p_1..p_N)`).
pub fn site_weights(w: &[f64], n: usize) -> impl Iterator<Item = f64> + Clone + '_ {
    (0..n).map(move |l| w[l] * w[l] + w[n + l] * w[n + l])
}

impl SetIndicator for DeviationDistribution {
    fn declared(&self) -> &'static [Declared] {
        const DECLARED: &[Declared] = &[
            Declared::named("dvd_m2", Needs::SITES),
            Declared::named("dvd_participation", Needs::SITES),
        ];
        DECLARED
    }

    fn observe(&mut self, obs: &SetObservation<'_>) {
        let Some(n) = obs.sites.filter(|&n| n > 0 && 2 * n == obs.dim) else {
            self.no_sites = true;
            return;
        };
        let Some(w) = obs.separations.get(..obs.dim) else {
            return;
        };
        if let Some(m) = moments_on(site_weights(w, n), obs.square_side, obs.periodic) {
            self.latest = Some(m);
        }
    }

    fn outputs(&self) -> Vec<Output> {
        match self.latest {
            Some((m2, p)) if !self.no_sites => vec![Output::Value(m2), Output::Value(p)],
            _ => {
                let why = if self.no_sites {
                    "the deviation vector distribution is over the sites (q_l, p_l) of a \
                     Hamiltonian; this system has none"
                } else {
                    "no deviation vector seen yet"
                };
                vec![Output::Unavailable(why.to_string()); 2]
            }
        }
    }

    fn boxed_clone(&self) -> Box<dyn SetIndicator> {
        Box::new(self.clone())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn observe(sites: Option<usize>, w: &[f64]) -> Vec<Output> {
        let mut d = DeviationDistribution::default();
        d.observe(&SetObservation {
            t: 0.0,
            dt: 0.0,
            covered: 0.0,
            dim: w.len(),
            separations: w,
            stretch: &[1.0],
            flow: None,
            sites,
            square_side: None,
            periodic: [false; 2],
            norm_conserved: false,
            state: None,
            site_energies: None,
        });
        d.outputs()
    }

    #[test]
    fn one_site_and_an_even_spread_are_the_limits() {
        // All weight on site 3 of 5 (q and p): no spread, one site.
        let mut w = vec![0.0; 10];
        w[2] = 3.0;
        w[7] = 4.0;
        assert_eq!(
            observe(Some(5), &w),
            [Output::Value(0.0), Output::Value(1.0)]
        );
        // Evenly over N = 5 sites: P = N, m2 the variance of a uniform site, (N^2 - 1) / 12.
        let w = [1.0, -1.0, 1.0, 1.0, -1.0, 0.0, 0.0, 0.0, 0.0, 0.0];
        let [Output::Value(m2), Output::Value(p)] = observe(Some(5), &w)[..] else {
            panic!("values expected");
        };
        assert!(
            (m2 - 2.0).abs() < 1e-15 && (p - 5.0).abs() < 1e-14,
            "{m2} {p}"
        );
        // Two end sites of 5, equal weights: mean 3, m2 = 4, P = 2.
        let w = [0.0, 0.0, 0.0, 0.0, 2.0, 2.0, 0.0, 0.0, 0.0, 0.0];
        assert_eq!(
            observe(Some(5), &w),
            [Output::Value(4.0), Output::Value(2.0)]
        );
    }

    #[test]
    fn the_weights_sum_to_one_whatever_the_scale() {
        // A vector and the same vector times 1e150 (a chaotic VM vector before renormalization)
        // give the same moments to rounding: the weights are normalized, not the vector.
        let w: Vec<f64> = (0..16).map(|i| ((i * 7 % 5) as f64 - 2.0) * 0.3).collect();
        let big: Vec<f64> = w.iter().map(|x| x * 1e150).collect();
        let (a, b) = (observe(Some(8), &w), observe(Some(8), &big));
        for (x, y) in a.iter().zip(&b) {
            let (Output::Value(x), Output::Value(y)) = (x, y) else {
                panic!("values expected");
            };
            assert!((x - y).abs() <= 1e-14 * x.abs(), "{x} vs {y}");
        }
    }

    #[test]
    fn systems_without_sites_say_so() {
        for out in observe(None, &[1.0, 2.0, 3.0]) {
            assert!(matches!(out, Output::Unavailable(why) if why.contains("Hamiltonian")));
        }
        // A vector that vanished (or is not finite) leaves the previous value, here none.
        assert!(matches!(
            observe(Some(2), &[0.0; 4])[0],
            Output::Unavailable(_)
        ));
    }
}
