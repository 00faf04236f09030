//! The one indicator interface: an indicator accumulates from what a run already publishes and
//! names its outputs; the tracker, and through it the analysis, its reports, replay, monitor,
//! Python and maps, take every indicator registered here without a change of their own.
//!
//! Two shapes, by what they accumulate from:
//! - [`SetIndicator`]: one instance per (scheme, set), fed at every renormalization of its set
//!   with the stretching factors and the separation vectors before renormalization (and the
//!   vector field at the reference state where the system gives it). Outputs are averaged over
//!   the sets of a scheme as GALI is.
//! - [`OrbitIndicator`]: one instance per scheme, fed the reference state at each of that
//!   scheme's renormalizations (the orbit sampled every `tau`). Its outputs are one value per
//!   scheme.
//!
//! Adding an indicator: its file in this crate, and its constructor in [`set_indicators`] or
//! [`orbit_indicators`]; every reader then names and reports its outputs.

use std::fmt::Debug;
use std::sync::Arc;

/// What a set indicator sees at one renormalization of its set.
#[derive(Debug, Clone, Copy)]
pub struct SetObservation<'a> {
    /// Time of this renormalization (0 for the initial vectors).
    pub t: f64,
    /// Time since the set's previous renormalization seen (0 at t = 0).
    pub dt: f64,
    /// Phase-space dimension (entries per vector).
    pub dim: usize,
    /// The `k` separation vectors before renormalization, one after the other; empty at a
    /// renormalization between the samples of a run sampled every `sample_every`, where only
    /// the stretching factors are known (indicators of the vectors keep their last values).
    pub separations: &'a [f64],
    /// Stretching factor of each vector since the previous renormalization (`|d| / d0`, or
    /// `|R_ii|`; for the first vector both are its own growth). All 1 at t = 0.
    pub stretch: &'a [f64],
    /// The vector field `f(x)` at the reference state of this renormalization, where the system
    /// can give it (flows and Hamiltonians in process); `None` otherwise.
    pub flow: Option<&'a [f64]>,
    /// The number of sites `N` of a Hamiltonian (`dim = 2N`, site `l` at `q_l`, `p_l`); `None`
    /// for a system without them (a flow, a map).
    pub sites: Option<usize>,
    /// The energy of each site at the reference state of this renormalization: `None` when
    /// the reader was given no way to compute them (the recorder, which does not rebuild the
    /// model).
    pub site_energies: Option<SiteEnergyInput<'a>>,
}

/// The energy of each site of a lattice Hamiltonian at a state (`N` values into `out`: kinetic
/// energy plus the site's share of the potential), or why the system cannot say. Given, like
/// [`crate::tracker::FlowField`], by whoever holds the system, for the energy distribution.
#[derive(Clone)]
pub struct SiteEnergies(pub Arc<SiteEnergyFn>);

/// `h_l` of the state into `out`, or why not.
pub type SiteEnergyFn = dyn Fn(&[f64], &mut [f64]) -> Result<(), String> + Send + Sync;

impl std::fmt::Debug for SiteEnergies {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("SiteEnergies")
    }
}

/// The site energies of one renormalization, computed only when a value is asked for (an
/// indicator keeps the state and evaluates at [`SetIndicator::outputs`]): a lattice of many
/// sites costs one evaluation per reported point, not one per renormalization.
#[derive(Debug, Clone, Copy)]
pub enum SiteEnergyInput<'a> {
    /// The system's site energies, to be evaluated at the reference state `state`.
    At {
        energies: &'a SiteEnergies,
        state: &'a [f64],
    },
    /// Why there are none at this renormalization.
    Unavailable(&'a str),
}

impl SiteEnergyInput<'_> {
    /// The `n` site energies, or why there are none.
    pub fn evaluate(&self, n: usize) -> Result<Vec<f64>, String> {
        match self {
            SiteEnergyInput::At { energies, state } => {
                let mut out = vec![0.0; n];
                (energies.0)(state, &mut out).map(|()| out)
            }
            SiteEnergyInput::Unavailable(why) => Err(why.to_string()),
        }
    }
}

/// One output's value for one set (or one scheme).
#[derive(Debug, Clone, PartialEq)]
pub enum Output {
    Value(f64),
    /// The indicator cannot be computed from what this run gives, and says why.
    Unavailable(String),
}

/// An indicator accumulated per (scheme, set) from the renormalizations of its set.
pub trait SetIndicator: Debug + Send + Sync {
    /// The names of its outputs, as reports carry them (a public contract).
    fn names(&self) -> &'static [&'static str];
    /// Accumulates one renormalization (called in increasing time, the first at t = 0).
    fn observe(&mut self, obs: &SetObservation<'_>);
    /// The current value of each output, in the order of [`SetIndicator::names`].
    fn outputs(&self) -> Vec<Output>;
    fn boxed_clone(&self) -> Box<dyn SetIndicator>;
}

/// An indicator accumulated per scheme from the reference orbit sampled at its
/// renormalizations.
pub trait OrbitIndicator: Debug + Send + Sync {
    fn names(&self) -> &'static [&'static str];
    /// Accumulates the reference state at time `t` (called in increasing time).
    fn observe(&mut self, t: f64, state: &[f64]);
    fn outputs(&self) -> Vec<Output>;
    fn boxed_clone(&self) -> Box<dyn OrbitIndicator>;
}

impl Clone for Box<dyn SetIndicator> {
    fn clone(&self) -> Self {
        self.boxed_clone()
    }
}

impl Clone for Box<dyn OrbitIndicator> {
    fn clone(&self) -> Self {
        self.boxed_clone()
    }
}

/// The set indicators every run tracks, in report order.
pub fn set_indicators() -> Vec<Box<dyn SetIndicator>> {
    vec![
        Box::new(crate::fli::Fli::default()),
        Box::new(crate::megno::Megno::default()),
        Box::new(crate::dvd::DeviationDistribution::default()),
        Box::new(crate::energy::EnergyDistribution::default()),
    ]
}

/// The orbit indicators every run tracks, in report order; the 0-1 test observes `zero_one`.
pub fn orbit_indicators(
    zero_one: &crate::zero_one::ZeroOneObservable,
) -> Vec<Box<dyn OrbitIndicator>> {
    vec![Box::new(crate::zero_one::ZeroOneTest::new(
        zero_one.clone(),
    ))]
}

/// The names of every registered set indicator's outputs, in report order (the columns of a
/// time series of them: CSV, plots, the recording's indicators channel).
pub fn set_output_names() -> &'static [&'static str] {
    static NAMES: std::sync::OnceLock<Vec<&'static str>> = std::sync::OnceLock::new();
    NAMES.get_or_init(|| {
        set_indicators()
            .iter()
            .flat_map(|i| i.names().iter().copied())
            .collect()
    })
}

/// The outputs of the registered set indicators that a run without the flow direction can give
/// (a phase-space map's points carry no vector field), in report order: those available after
/// one observation with `flow: None` and no sites. The map indicators by output name.
pub fn flowless_set_outputs() -> Vec<&'static str> {
    let observation = SetObservation {
        t: 0.0,
        dt: 0.0,
        dim: 1,
        separations: &[1.0],
        stretch: &[1.0],
        flow: None,
        sites: None,
        site_energies: None,
    };
    set_indicators()
        .into_iter()
        .flat_map(|mut i| {
            i.observe(&observation);
            i.names()
                .iter()
                .copied()
                .zip(i.outputs())
                .collect::<Vec<_>>()
        })
        .filter_map(|(name, output)| matches!(output, Output::Value(_)).then_some(name))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_map_shows_every_output_but_ofli() {
        // OFLI needs the flow direction, the DVD and the energy distribution a Hamiltonian's
        // sites; FLI and MEGNO only the stretching factors.
        assert_eq!(flowless_set_outputs(), ["fli", "megno", "megno_mean"]);
    }

    #[test]
    fn every_set_output_is_named_once() {
        let names = set_output_names();
        assert_eq!(
            names,
            [
                "fli",
                "ofli",
                "megno",
                "megno_mean",
                "dvd_m2",
                "dvd_participation",
                "energy_m2",
                "energy_participation"
            ]
        );
        let mut unique = names.to_vec();
        unique.sort_unstable();
        unique.dedup();
        assert_eq!(unique.len(), names.len());
    }
}
