//! The distributions over the sites of a lattice over time, for the space-time picture of where
//! the energy is and where the chaos is (`analyze --plot`'s `distributions.png`): at a bounded
//! number of renormalization times (evenly thinned by stride doubling, as the curves are), the
//! normalized energy of each site at the reference state and the deviation vector distribution
//! of the first scheme's first set (its first vector: the one whose stretching the MLE
//! measures), both by the definitions of `chaoscope-indicators` ([`chaoscope_indicators::distribution`]).

use chaoscope_indicators::distribution::normalized;
use chaoscope_indicators::dvd::site_weights;
use chaoscope_schemas::run::Sample;

use crate::series::Series;

/// Times kept, at most (plus one per decade of the log thinning).
const CAPACITY: usize = 256;

/// The two distributions at one time.
#[derive(Debug, Clone, PartialEq)]
pub struct SiteProfile {
    /// `h_l / sum h` of the `N` sites, or why there is no energy distribution at this time.
    pub energy: Result<Vec<f64>, String>,
    /// `xi_l` of the `N` sites.
    pub dvd: Vec<f64>,
}

/// The kept profiles of a run with `N` sites.
#[derive(Debug, Clone)]
pub struct SiteProfiles {
    sites: usize,
    series: Series<SiteProfile>,
}

/// What `Series::offer` would keep for a time it does not want (never made).
fn unreachable_profile() -> SiteProfile {
    SiteProfile {
        energy: Err(String::new()),
        dvd: Vec::new(),
    }
}

impl SiteProfiles {
    pub fn new(sites: usize) -> Self {
        Self {
            sites,
            series: Series::new(CAPACITY, 1),
        }
    }

    pub fn sites(&self) -> usize {
        self.sites
    }

    /// Takes `sample` if it renormalized the first set of the first scheme (the DVD's vector),
    /// with the site energies at its reference state from `energies` (called only for a kept
    /// time; `None` when the analysis has no way to compute them).
    pub fn offer(
        &mut self,
        sample: &Sample,
        energies: impl FnOnce() -> Option<Result<Vec<f64>, String>>,
    ) {
        let n = self.sites;
        let Some(first) = sample
            .schemes
            .iter()
            .find(|s| s.scheme == 0 && s.set == 0)
            .and_then(|s| s.separations.get(..2 * n))
        else {
            return;
        };
        if sample.state.len() != 2 * n {
            return;
        }
        // Every renormalization of the set is offered (the even thinning counts them); the
        // profile is made only for the kept ones.
        if !self.series.wants(sample.t) {
            self.series.offer(sample.t, unreachable_profile);
            return;
        }
        let Some(dvd) = normalized(site_weights(first, n)) else {
            return;
        };
        let energy = match energies() {
            None => Err("no site energies (the model was not rebuilt)".to_string()),
            Some(Err(why)) => Err(why),
            Some(Ok(e)) => chaoscope_indicators::energy::energy_moments(&e).and_then(|_| {
                normalized(e.iter().copied()).ok_or_else(|| "no positive total".to_string())
            }),
        };
        self.series.offer(sample.t, || SiteProfile { energy, dvd });
    }

    /// The kept profiles in time order.
    pub fn points(&self) -> Vec<(f64, &SiteProfile)> {
        self.series.points_ref()
    }
}
