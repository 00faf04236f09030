//! The energy distribution over the sites of a lattice: how the energy of the reference state
//! spreads over the chain, the map the deviation vector distribution ([`crate::dvd`]) is read
//! against (chaos lives where the energy is: Senyange, Many Manda and Skokos, PRE 98, 052229
//! (2018); Flach, Krimer and Skokos, PRL 102, 024101 (2009)).
//!
//! At each renormalization, the energies `h_l` of the sites at the reference state (`p_l^2 / 2`
//! plus the site's on-site terms plus an equal share of each coupling term it takes part in; the
//! system gives them, [`crate::tracker::SiteEnergies`]) give the weights `h_l / sum h` and the
//! second moment and participation number of [`crate::distribution`], as the DVD's.
//!
//! A weight must be a share of the energy: where some `h_l < 0` (a potential not bounded below
//! site by site) or the total is not positive, the outputs are unavailable with the reason rather
//! than a distribution that is not one. Flows and maps have no sites; a reader that cannot
//! rebuild the model (the recorder) has no site energies: unavailable, saying why.

use crate::distribution::moments_on;
use crate::indicator::{
    Declared, Needs, Output, SetIndicator, SetObservation, SiteEnergies, SiteEnergyInput,
};

/// The energy distribution's second moment and participation number at the latest
/// renormalization: the state they are to be computed at (evaluated when asked for, so a long
/// run over a large lattice pays for its reported points only), or why there are none.
#[derive(Debug, Clone)]
pub struct EnergyDistribution {
    latest: Latest,
}

#[derive(Debug, Clone)]
enum Latest {
    At {
        energies: SiteEnergies,
        state: Vec<f64>,
        t: f64,
        sites: usize,
        square_side: Option<usize>,
        periodic: [bool; 2],
    },
    Unavailable(String),
}

impl Default for EnergyDistribution {
    fn default() -> Self {
        Self {
            latest: Latest::Unavailable("no reference state seen yet".to_string()),
        }
    }
}

/// The second moment and participation number of the energy distribution of `energies` on the
/// lattice `square_side` and `periodic` describe ([`crate::distribution::moments_on`]), or why it is not a
/// distribution (a negative or non-finite site energy, a total that is not positive).
pub fn energy_moments(
    energies: &[f64],
    square_side: Option<usize>,
    periodic: [bool; 2],
) -> Result<(f64, f64), String> {
    if let Some((l, e)) = energies.iter().enumerate().find(|(_, e)| !e.is_finite()) {
        return Err(format!("the energy of site {} is {e}", l + 1));
    }
    if let Some((l, e)) = energies.iter().enumerate().find(|(_, e)| **e < 0.0) {
        return Err(format!(
            "site {} has a negative energy ({e:e}): the potential is not bounded below site by \
             site, so h_l / sum h is no distribution",
            l + 1
        ));
    }
    moments_on(energies.iter().copied(), square_side, periodic)
        .ok_or_else(|| "the total energy of the sites is not positive".to_string())
}

impl SetIndicator for EnergyDistribution {
    fn declared(&self) -> &'static [Declared] {
        const DECLARED: &[Declared] = &[
            Declared::named("energy_m2", Needs::SITES),
            Declared::named("energy_participation", Needs::SITES),
        ];
        DECLARED
    }

    fn observe(&mut self, obs: &SetObservation<'_>) {
        let Some(n) = obs.sites.filter(|&n| n > 0 && 2 * n == obs.dim) else {
            self.latest = Latest::Unavailable(
                "the energy distribution is over the sites (q_l, p_l) of a Hamiltonian; this \
                 system has none"
                    .to_string(),
            );
            return;
        };
        match obs.site_energies {
            None => {
                self.latest = Latest::Unavailable(
                    "the site energies need the model, which this reader does not rebuild \
                     (chaoscope analyze and monitor do)"
                        .to_string(),
                );
            }
            Some(SiteEnergyInput::Unavailable(why)) => {
                self.latest = Latest::Unavailable(why.to_string());
            }
            // The previous state's buffer reused: one copy of 2N numbers per observation.
            Some(SiteEnergyInput::At { energies, state }) => match &mut self.latest {
                Latest::At {
                    energies: e,
                    state: s,
                    t,
                    sites,
                    square_side,
                    periodic,
                } => {
                    (*e, *t, *sites, *square_side, *periodic) =
                        (energies.clone(), obs.t, n, obs.square_side, obs.periodic);
                    s.clear();
                    s.extend_from_slice(state);
                }
                latest => {
                    *latest = Latest::At {
                        energies: energies.clone(),
                        state: state.to_vec(),
                        t: obs.t,
                        sites: n,
                        square_side: obs.square_side,
                        periodic: obs.periodic,
                    };
                }
            },
        }
    }

    fn outputs(&self) -> Vec<Output> {
        let moments = match &self.latest {
            Latest::Unavailable(why) => Err(why.clone()),
            Latest::At {
                energies,
                state,
                t,
                sites,
                square_side,
                periodic,
            } => SiteEnergyInput::At { energies, state }
                .evaluate(*sites)
                .and_then(|e| {
                    energy_moments(&e, *square_side, *periodic)
                        .map_err(|why| format!("at t = {t}: {why}"))
                }),
        };
        match moments {
            Ok((m2, p)) => vec![Output::Value(m2), Output::Value(p)],
            Err(why) => vec![Output::Unavailable(why); 2],
        }
    }

    fn boxed_clone(&self) -> Box<dyn SetIndicator> {
        Box::new(self.clone())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    use std::sync::Arc;

    /// The distribution after one observation whose site energies are `energies` (as a
    /// system's function would give them; `Err` as a system that has none).
    fn observe(sites: Option<usize>, energies: Option<Result<&[f64], &str>>) -> Vec<Output> {
        let w = vec![1.0; 2 * sites.unwrap_or(1)];
        let given: Option<Result<Vec<f64>, String>> =
            energies.map(|e| e.map(<[f64]>::to_vec).map_err(str::to_string));
        let function = SiteEnergies(Arc::new(move |_x: &[f64], out: &mut [f64]| {
            match given.as_ref().expect("asked only where given") {
                Ok(e) if e.len() == out.len() => {
                    out.copy_from_slice(e);
                    Ok(())
                }
                Ok(e) => Err(format!("{} site energies for {} sites", e.len(), out.len())),
                Err(why) => Err(why.clone()),
            }
        }));
        let input = energies.map(|_| SiteEnergyInput::At {
            energies: &function,
            state: &w,
        });
        let mut d = EnergyDistribution::default();
        d.observe(&SetObservation {
            t: 2.0,
            dt: 1.0,
            covered: 2.0,
            dim: w.len(),
            separations: &w,
            stretch: &[1.0],
            flow: None,
            sites,
            square_side: None,
            periodic: [false; 2],
            norm_conserved: false,
            state: None,
            site_energies: input,
        });
        d.outputs()
    }

    #[test]
    fn all_energy_on_one_site_and_an_even_spread_are_the_limits() {
        // Everything on site 2 of 4: P = 1, m2 = 0 exactly.
        assert_eq!(
            observe(Some(4), Some(Ok(&[0.0, 0.7, 0.0, 0.0]))),
            [Output::Value(0.0), Output::Value(1.0)]
        );
        // Evenly over 5 sites: P = 5, m2 = (N^2 - 1) / 12 = 2, to rounding of the sums.
        let [Output::Value(m2), Output::Value(p)] = observe(Some(5), Some(Ok(&[0.3; 5])))[..]
        else {
            panic!("values expected");
        };
        assert!(
            (m2 - 2.0).abs() < 1e-14 && (p - 5.0).abs() < 1e-14,
            "{m2} {p}"
        );
    }

    #[test]
    fn what_is_not_a_distribution_is_unavailable_with_the_reason() {
        let negative = observe(Some(3), Some(Ok(&[1.0, -1e-3, 2.0])));
        assert!(
            matches!(&negative[0], Output::Unavailable(why) if why.contains("site 2 has a negative energy") && why.contains("t = 2")),
            "{negative:?}"
        );
        let zero = observe(Some(2), Some(Ok(&[0.0, 0.0])));
        assert!(matches!(&zero[1], Output::Unavailable(why) if why.contains("not positive")));
        let nan = observe(Some(2), Some(Ok(&[f64::NAN, 1.0])));
        assert!(matches!(&nan[0], Output::Unavailable(why) if why.contains("site 1")));
        let refused = observe(Some(2), Some(Err("model 'x' says no")));
        assert!(matches!(&refused[0], Output::Unavailable(why) if why == "model 'x' says no"));
        let recorder = observe(Some(2), None);
        assert!(matches!(&recorder[0], Output::Unavailable(why) if why.contains("rebuild")));
        let flow = observe(None, Some(Ok(&[1.0])));
        assert!(matches!(&flow[0], Output::Unavailable(why) if why.contains("Hamiltonian")));
    }
}
