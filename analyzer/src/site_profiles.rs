//! The distributions over the sites of a lattice over time, for the space-time picture of where
//! the energy (or the norm) is and where the chaos is (`analyze --plot`'s `distributions.png`)
//! and, on a square lattice, the pictures over the plane at chosen times (`plane-t<T>.png`): at
//! a bounded number of renormalization times (evenly thinned by stride doubling, as the curves
//! are), the normalized energy of each site at the reference state, the norm distribution
//! `z_l = |psi_l|^2 / S` of a model that conserves the norm (the DDNLS, whose site energies are
//! no distribution), and the deviation vector distribution of the first scheme's first set (its
//! first vector: the one whose stretching the MLE measures), all by the definitions of
//! `chaoscope-indicators` ([`chaoscope_indicators::distribution`]).

use chaoscope_indicators::distribution::normalized;
use chaoscope_indicators::dvd::site_weights;
use chaoscope_indicators::norm::site_norms;
use chaoscope_schemas::config::num;
use chaoscope_schemas::run::Sample;

use crate::run_info::RunInfo;
use crate::series::Series;

/// Times kept, at most (plus one per decade of the log thinning).
const CAPACITY: usize = 256;

/// The distributions at one time.
#[derive(Debug, Clone, PartialEq)]
pub struct SiteProfile {
    /// `h_l / sum h` of the `N` sites, or why there is no energy distribution at this time.
    pub energy: Result<Vec<f64>, String>,
    /// `z_l = (q_l^2 + p_l^2) / (2 S)` of the `N` sites, for a model that conserves the norm
    /// `S`; `None` for any other.
    pub norm: Option<Vec<f64>>,
    /// `xi_l` of the `N` sites.
    pub dvd: Vec<f64>,
}

impl SiteProfile {
    /// The distribution a picture shows beside the DVD: the norm's where the model conserves
    /// one (the DDNLS), else the energy's; with its name, or why there is none.
    pub fn carrier(&self) -> (&'static str, Result<&[f64], &str>) {
        match &self.norm {
            Some(z) => ("norm distribution z_l", Ok(z)),
            None => (
                "energy distribution h_l / Σ h",
                self.energy.as_deref().map_err(String::as_str),
            ),
        }
    }
}

/// One time asked for a picture over the plane, and the profile of the latest renormalization
/// at or before it (the time it was taken at beside it).
#[derive(Debug, Clone)]
pub struct PlaneCapture {
    pub asked: f64,
    pub taken: Option<(f64, SiteProfile)>,
}

/// The kept profiles of a run with `N` sites.
#[derive(Debug, Clone)]
pub struct SiteProfiles {
    sites: usize,
    square_side: Option<usize>,
    periodic: [bool; 2],
    norm_conserved: bool,
    series: Series<SiteProfile>,
    planes: Vec<PlaneCapture>,
}

/// What `Series::offer` would keep for a time it does not want (never made).
fn unreachable_profile() -> SiteProfile {
    SiteProfile {
        energy: Err(String::new()),
        norm: None,
        dvd: Vec::new(),
    }
}

/// A sample time at or before an asked time, to the rounding of `step * h` (1e-9 relative).
fn at_or_before(t: f64, asked: f64) -> bool {
    t <= asked + 1e-9 * asked.abs().max(1.0)
}

/// The default times of the pictures over the plane: four, a decade apart, ending at the run's
/// end (`t_final / 1000 .. t_final`).
pub fn default_plane_times(t_final: f64) -> Vec<f64> {
    [1e-3, 1e-2, 1e-1, 1.0]
        .iter()
        .map(|f| f * t_final)
        .collect()
}

/// Checks the times asked for pictures over the plane (`--plane-times`) against the run: a
/// square lattice, times finite, from 0 to its final time. The problem in one line otherwise.
pub fn check_plane_times(times: &[f64], run: &RunInfo) -> Result<(), String> {
    let Some(side) = run.square_side else {
        let what = match run.kind.lattice_sites(run.dim) {
            Some(n) => format!("a chain of {n} sites (its distributions are distributions.png)"),
            None => format!("a {} without lattice sites", run.kind.name()),
        };
        return Err(format!(
            "--plane-times: the run is {what}, not a square lattice: there is no plane to draw"
        ));
    };
    if times.is_empty() {
        return Err("--plane-times: no time given".to_string());
    }
    let t_final = run.header.t_final;
    for &t in times {
        let (t_shown, end) = (num(t), num(t_final));
        if !(t.is_finite() && t >= 0.0) {
            return Err(format!("--plane-times {t_shown}: a time from 0 on"));
        }
        if !at_or_before(t, t_final) {
            return Err(format!(
                "--plane-times {t_shown}: after the run's end, t = {end} ({side} x {side} lattice)"
            ));
        }
    }
    Ok(())
}

impl SiteProfiles {
    /// Profiles of a chain of `sites` whose model conserves no norm.
    pub fn new(sites: usize) -> Self {
        Self {
            sites,
            square_side: None,
            periodic: [false; 2],
            norm_conserved: false,
            series: Series::new(CAPACITY, 1),
            planes: Vec::new(),
        }
    }

    /// Profiles of the run's `sites`, with pictures over the plane at `plane_times` (each
    /// once, in the order given) where its sites form a square (`None`:
    /// [`default_plane_times`]); a chain takes none.
    pub fn for_run(run: &RunInfo, sites: usize, plane_times: Option<&[f64]>) -> Self {
        let mut planes: Vec<PlaneCapture> = Vec::new();
        if run.square_side.is_some() {
            let times = plane_times
                .map_or_else(|| default_plane_times(run.header.t_final), <[f64]>::to_vec);
            for asked in times {
                if planes.iter().all(|p| p.asked != asked) {
                    planes.push(PlaneCapture { asked, taken: None });
                }
            }
        }
        Self {
            square_side: run.square_side,
            periodic: run.periodic,
            norm_conserved: run.layout().norm_conserved,
            planes,
            ..Self::new(sites)
        }
    }

    pub fn sites(&self) -> usize {
        self.sites
    }

    /// `Some(L)` when the sites form an `L x L` square lattice numbered row by row.
    pub fn square_side(&self) -> Option<usize> {
        self.square_side
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
        let t = sample.t;
        let for_planes = self.planes.iter().any(|p| at_or_before(t, p.asked));
        // Every renormalization of the set is offered (the even thinning counts them); the
        // profile is made only for the kept ones and the pictures over the plane.
        if !self.series.wants(t) && !for_planes {
            self.series.offer(t, unreachable_profile);
            return;
        }
        let Some(dvd) = normalized(site_weights(first, n)) else {
            return;
        };
        let energy = match energies() {
            None => Err("no site energies (the model was not rebuilt)".to_string()),
            Some(Err(why)) => Err(why),
            Some(Ok(e)) => {
                chaoscope_indicators::energy::energy_moments(&e, self.square_side, self.periodic)
                    .and_then(|_| {
                        normalized(e.iter().copied()).ok_or_else(|| "no positive total".to_string())
                    })
            }
        };
        let norm = self
            .norm_conserved
            .then(|| normalized(site_norms(&sample.state, n)))
            .flatten();
        let profile = SiteProfile { energy, norm, dvd };
        for plane in &mut self.planes {
            if at_or_before(t, plane.asked) {
                plane.taken = Some((t, profile.clone()));
            }
        }
        self.series.offer(t, || profile);
    }

    /// The kept profiles in time order.
    pub fn points(&self) -> Vec<(f64, &SiteProfile)> {
        self.series.points_ref()
    }

    /// The pictures over the plane asked for, in the order asked (none for a chain).
    pub fn planes(&self) -> &[PlaneCapture] {
        &self.planes
    }
}
