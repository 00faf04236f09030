//! The one indicator interface and its registry: an indicator accumulates from what a run
//! already publishes and declares its outputs with what each needs; the tracker, and through it
//! the analysis, its reports, replay, monitor and Python, and the maps take every indicator
//! registered here by its declarations, without a change of their own.
//!
//! Two shapes, by what they accumulate from:
//! - [`SetIndicator`]: one instance per (scheme, set), fed at renormalizations of its set with
//!   the stretching factors and the separation vectors before renormalization (and the vector
//!   field at the reference state where the system gives it).
//! - [`OrbitIndicator`]: one instance per scheme, fed the reference state at each of that
//!   scheme's renormalizations (the orbit sampled every `tau`). Its outputs are one value per
//!   scheme.
//!
//! Adding an indicator: its file in this crate, its `pub mod` line and its constructor in
//! [`set_indicators`] or [`orbit_indicators`] (both in `lib.rs`, beside the modules); every
//! reader then takes its outputs by their declarations.

use std::any::Any;
use std::fmt::Debug;
use std::sync::Arc;

pub use crate::{orbit_indicators, set_indicators};

/// What a set indicator sees at one renormalization of its set.
#[derive(Debug, Clone, Copy)]
pub struct SetObservation<'a> {
    /// Time of this renormalization (0 for the initial vectors).
    pub t: f64,
    /// Time since the set's previous renormalization seen (0 at t = 0).
    pub dt: f64,
    /// Time the stretching factors observed so far cover, these included: `t`, unless some
    /// renormalizations were never seen (a live monitor's lost frames), whose factors are in no
    /// sum. The exponents divide by it.
    pub covered: f64,
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
    /// `Some(L)`: the `N = L^2` sites form an `L x L` square lattice numbered row by row (site
    /// `l`, from 0, at row `l / L`, column `l % L`), over whose plane the distributions' second
    /// moments are taken; `None`: a chain (site `l` at position `l`).
    pub square_side: Option<usize>,
    /// Which lattice axes close on themselves (periodic boundaries; along `i`, then `j`; a
    /// chain reads the first): distances along them are taken around the ring.
    pub periodic: [bool; 2],
    /// The system conserves the norm `S = sum_l (q_l^2 + p_l^2) / 2` (the DDNLS), whose
    /// distribution over the sites `z_l = (q_l^2 + p_l^2) / (2 S)` is then defined.
    pub norm_conserved: bool,
    /// The reference state of this renormalization, where one came with it (a sample).
    pub state: Option<&'a [f64]>,
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

/// What an output needs of a run, declared as data: a reader gives an indicator what its
/// outputs need, or leaves out the outputs it cannot give (a map point has no vector field and
/// no sites), without trying the indicator.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Needs {
    /// Deviation vectors per set, at least.
    pub vectors: usize,
    /// Stretching factors that are QR's `|R_jj|` (the spectrum) rather than each vector's own
    /// growth.
    pub qr: bool,
    /// The vector field at the reference state.
    pub flow: bool,
    /// The sites of a Hamiltonian (and, for the energy distribution, their energies).
    pub sites: bool,
    /// Every renormalization of the set; `false`: only its vectors at the end (an instantaneous
    /// function of them, which a map evaluates once per set).
    pub every_renormalization: bool,
}

impl Needs {
    /// The first vector's stretching factor at every renormalization, nothing else.
    pub const STRETCH: Needs = Needs {
        vectors: 1,
        qr: false,
        flow: false,
        sites: false,
        every_renormalization: true,
    };
    /// QR's stretching factors of every vector at every renormalization (the spectrum).
    pub const QR: Needs = Needs {
        qr: true,
        ..Needs::STRETCH
    };
    /// The first two vectors at the end (the alignment indices).
    pub const FINAL_PAIR: Needs = Needs {
        vectors: 2,
        every_renormalization: false,
        ..Needs::STRETCH
    };
    /// The first vector at every renormalization and the vector field at the reference state.
    pub const FLOW: Needs = Needs {
        flow: true,
        ..Needs::STRETCH
    };
    /// The first vector at every renormalization, over a Hamiltonian's sites.
    pub const SITES: Needs = Needs {
        sites: true,
        ..Needs::STRETCH
    };
}

/// Where reports carry an output.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Carried {
    /// Under its name among every scheme's named outputs (`analyze --json`'s scheme fields, a
    /// CSV column, the `named` entries of the recording's indicators channel).
    Named,
    /// In fields of its own whose layout is older than the named outputs (GALI by order,
    /// SALI, the exponents: `gali`, `sali`, `mle`, `lyapunov` of the reports, their columns and
    /// message fields), which the tracker fills from the registered instance (every order of
    /// GALI, every vector's exponent).
    OwnFields,
}

/// One output of an indicator: its name as reports and `[map] indicator` carry it (a public
/// contract), what it needs, and how it is carried and averaged.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Declared {
    pub name: &'static str,
    pub needs: Needs,
    pub carried: Carried,
    /// The value is a `log10` (GALI, SALI): sets combine into the mean of `10^v` and the mean
    /// of `v` (the geometric mean), as their values span decades.
    pub log10: bool,
    /// The output comes with one value per vector ([`SetIndicator::per_vector`]: the spectrum
    /// `lambda_1..k`), which a map point carries.
    pub per_vector: bool,
}

impl Declared {
    /// An output carried by name, averaged linearly over the sets.
    pub const fn named(name: &'static str, needs: Needs) -> Self {
        Self {
            name,
            needs,
            carried: Carried::Named,
            log10: false,
            per_vector: false,
        }
    }

    /// An output carried in fields of its own ([`Carried::OwnFields`]).
    pub const fn own(name: &'static str, needs: Needs) -> Self {
        let mut d = Self::named(name, needs);
        d.carried = Carried::OwnFields;
        d
    }

    /// The output as a `log10` ([`Declared::log10`]).
    pub const fn in_log10(mut self) -> Self {
        self.log10 = true;
        self
    }

    /// The output with its per-vector values ([`Declared::per_vector`]).
    pub const fn with_per_vector(mut self) -> Self {
        self.per_vector = true;
        self
    }

    /// Whether a phase-space map's point can give it: a map's kernels compute no vector field
    /// at the points' reference states, and a map has no sites.
    pub fn on_maps(&self) -> bool {
        !self.needs.flow && !self.needs.sites
    }
}

/// An indicator accumulated per (scheme, set) from the renormalizations of its set. `Any`, so
/// that the tracker reads the built-in GALI, SALI and exponents' values of every order and
/// vector from the registered instances themselves.
pub trait SetIndicator: Any + Debug + Send + Sync {
    /// Its outputs with what each needs, in the order of [`SetIndicator::outputs`].
    fn declared(&self) -> &'static [Declared];
    /// Accumulates one renormalization (called in increasing time; where an output needs every
    /// renormalization, the first at t = 0 or, on a map, at the first window's end).
    fn observe(&mut self, obs: &SetObservation<'_>);
    /// The current value of each output, in the order of [`SetIndicator::declared`].
    fn outputs(&self) -> Vec<Output>;
    /// The per-vector values behind the outputs declared [`Declared::per_vector`] (the
    /// spectrum); empty for an indicator without them.
    fn per_vector(&self) -> Vec<f64> {
        Vec::new()
    }
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

/// Every registered set output's declaration, in report order.
pub fn declared_outputs() -> &'static [Declared] {
    static DECLARED: std::sync::OnceLock<Vec<Declared>> = std::sync::OnceLock::new();
    DECLARED.get_or_init(|| {
        set_indicators()
            .iter()
            .flat_map(|i| i.declared().iter().copied())
            .collect()
    })
}

/// The names of the set outputs carried by name, in report order (the columns of a time series
/// of them: CSV, plots, the recording's indicators channel).
pub fn set_output_names() -> &'static [&'static str] {
    static NAMES: std::sync::OnceLock<Vec<&'static str>> = std::sync::OnceLock::new();
    NAMES.get_or_init(|| {
        declared_outputs()
            .iter()
            .filter(|d| d.carried == Carried::Named)
            .map(|d| d.name)
            .collect()
    })
}

/// The map's own rule on the `gali` output: the time `GALI_k` first falls below `[map]
/// threshold`, where the set stops.
pub const GALI_TIME: &str = "gali-time";

/// Every value `[map] indicator` takes, in order: each registered set output a map's point can
/// give ([`Declared::on_maps`]), and [`GALI_TIME`] after `gali`. The one list the map's
/// validation and every reader of map files check against.
pub fn map_indicators() -> Vec<&'static str> {
    declared_outputs()
        .iter()
        .filter(|d| d.on_maps())
        .flat_map(|d| match d.name {
            "gali" => vec![d.name, GALI_TIME],
            _ => vec![d.name],
        })
        .collect()
}

/// The registered indicator giving the set output `name`, with that output's declaration and
/// position among its outputs.
pub fn set_indicator_of(name: &str) -> Option<(Box<dyn SetIndicator>, Declared, usize)> {
    set_indicators().into_iter().find_map(|i| {
        let at = i.declared().iter().position(|d| d.name == name)?;
        let declared = i.declared()[at];
        Some((i, declared, at))
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_map_shows_every_output_but_ofli_and_the_sites() {
        // OFLI needs the flow direction, the DVD and the energy distribution a Hamiltonian's
        // sites; GALI, SALI, the exponents, FLI and MEGNO only the vectors and their stretching.
        assert_eq!(
            map_indicators(),
            [
                "gali",
                "gali-time",
                "sali",
                "mle",
                "spectrum",
                "fli",
                "megno",
                "megno_mean"
            ]
        );
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
                "energy_participation",
                "norm_m2",
                "norm_participation"
            ]
        );
        let mut unique = names.to_vec();
        unique.sort_unstable();
        unique.dedup();
        assert_eq!(unique.len(), names.len());
    }
}
