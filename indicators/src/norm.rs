//! The norm distribution over the sites of a lattice that conserves the norm
//! `S = sum_l (q_l^2 + p_l^2) / 2` (the disordered discrete nonlinear Schroedinger lattice):
//! `z_l = |psi_l|^2 / S = (q_l^2 + p_l^2) / (2 S)` at the reference state, the wave packet whose
//! spreading the DDNLS papers measure (Flach, Krimer and Skokos, PRL 102, 024101 (2009); Many
//! Manda, Senyange and Skokos, PRE 101, 032206 (2020)). Its second moment and participation
//! number are those of [`crate::distribution`] (over the plane on a square lattice).
//!
//! The DDNLS's site energies are no distribution (its on-site terms `eps_l |psi_l|^2` take
//! either sign), so its energy distribution is unavailable and this one is the one to read. A
//! system that conserves no such norm gets the outputs as unavailable, with the reason.

use crate::distribution::moments_on;
use crate::indicator::{Declared, Needs, Output, SetIndicator, SetObservation};

/// The norm distribution's second moment and participation number at the latest reference
/// state seen, or why there are none.
#[derive(Debug, Clone)]
pub struct NormDistribution {
    latest: Result<(f64, f64), String>,
}

impl Default for NormDistribution {
    fn default() -> Self {
        Self {
            latest: Err("no reference state seen yet".to_string()),
        }
    }
}

/// The unnormalized norm weights `(q_l^2 + p_l^2) / 2` of the `N` sites of a state of `2N`
/// entries (`(q_1..q_N, p_1..p_N)`).
pub fn site_norms(x: &[f64], n: usize) -> impl Iterator<Item = f64> + Clone + '_ {
    (0..n).map(move |l| 0.5 * (x[l] * x[l] + x[n + l] * x[n + l]))
}

impl SetIndicator for NormDistribution {
    fn declared(&self) -> &'static [Declared] {
        const DECLARED: &[Declared] = &[
            Declared::named("norm_m2", Needs::SITES),
            Declared::named("norm_participation", Needs::SITES),
        ];
        DECLARED
    }

    fn observe(&mut self, obs: &SetObservation<'_>) {
        let Some(n) = obs.sites.filter(|&n| n > 0 && 2 * n == obs.dim) else {
            self.latest = Err("the norm distribution is over the sites (q_l, p_l) of a \
                               Hamiltonian; this system has none"
                .to_string());
            return;
        };
        if !obs.norm_conserved {
            self.latest = Err(
                "the norm distribution is defined for a lattice that conserves \
                               the norm sum_l (q_l^2 + p_l^2) / 2 (the DDNLS); this one does \
                               not (read the energy distribution)"
                    .to_string(),
            );
            return;
        }
        // A renormalization between the samples brings no state: the latest sample's stands.
        let Some(x) = obs.state.filter(|x| x.len() == 2 * n) else {
            return;
        };
        self.latest =
            moments_on(site_norms(x, n), obs.square_side, obs.periodic).ok_or_else(|| {
                format!(
                    "at t = {}: the norm of the state is not positive and finite",
                    obs.t
                )
            });
    }

    fn outputs(&self) -> Vec<Output> {
        match &self.latest {
            Ok((m2, p)) => vec![Output::Value(*m2), Output::Value(*p)],
            Err(why) => vec![Output::Unavailable(why.clone()); 2],
        }
    }

    fn boxed_clone(&self) -> Box<dyn SetIndicator> {
        Box::new(self.clone())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn observe(
        sites: Option<usize>,
        square_side: Option<usize>,
        norm_conserved: bool,
        x: &[f64],
    ) -> Vec<Output> {
        let mut d = NormDistribution::default();
        d.observe(&SetObservation {
            t: 3.0,
            dt: 1.0,
            covered: 3.0,
            dim: x.len(),
            separations: x,
            stretch: &[1.0],
            flow: None,
            sites,
            square_side,
            periodic: [false; 2],
            norm_conserved,
            state: Some(x),
            site_energies: None,
        });
        d.outputs()
    }

    #[test]
    fn the_norm_spreads_over_the_plane() {
        // A 3 x 3 square, |psi|^2 = 2 on the corners (0, 0) and (2, 2) (q = 2 on one, p = 2 on
        // the other: the phase does not count): a distance sqrt(8) apart, m2 = 8 / 4 = 2
        // about the centre, P = 2. The flattened chain would put them 8 sites apart (m2 = 16).
        let mut x = vec![0.0; 18];
        x[0] = 2.0;
        x[9 + 8] = 2.0;
        assert_eq!(
            observe(Some(9), Some(3), true, &x),
            [Output::Value(2.0), Output::Value(2.0)]
        );
        assert_eq!(
            observe(Some(9), None, true, &x),
            [Output::Value(16.0), Output::Value(2.0)]
        );
    }

    #[test]
    fn without_a_conserved_norm_or_sites_it_says_why() {
        let x = [1.0, 0.5, 0.0, 2.0];
        for out in observe(Some(2), None, false, &x) {
            assert!(matches!(out, Output::Unavailable(why) if why.contains("DDNLS")));
        }
        for out in observe(None, None, true, &x[..3]) {
            assert!(matches!(out, Output::Unavailable(why) if why.contains("Hamiltonian")));
        }
        for out in observe(Some(2), None, true, &[0.0; 4]) {
            assert!(matches!(out, Output::Unavailable(why) if why.contains("t = 3")));
        }
    }
}
