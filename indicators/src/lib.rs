//! chaoscope-indicators: the chaos indicators of a run as pure functions of the separation
//! vectors and stretching factors it publishes, with no I/O and no knowledge of the bus or the
//! file formats.
//!
//! One implementation for every reader: the producer (maps), the analyzer (`analyze`, `monitor`,
//! `run`'s summary) and the recorder (the `/chaoscope/indicators/<scheme>` channel of every
//! recording) all compute GALI, SALI and the finite-time Lyapunov exponents here, so a value in
//! a file equals the value `analyze` reports to the last bit.
//!
//! - [`alignment`]: GALI (volume of the unit vectors, from a QR factorization) and SALI.
//! - [`clv`]: covariant Lyapunov vectors (Ginelli's backward pass over the QR factors of a VM
//!   QR scheme) and principal angles between subspaces.
//! - [`stretch`]: accumulated logarithmic stretching, the finite-time exponents.
//! - [`stats`]: averages over the random sets of a scheme.
//! - [`indicator`]: the one indicator interface (set and orbit indicators, their outputs
//!   declared with what each needs); the registry ([`set_indicators`], [`orbit_indicators`],
//!   below the modules) holds GALI, SALI, the exponents, [`fli`] (FLI, OFLI), [`megno`] (MEGNO and
//!   its mean), [`dvd`] (the deviation vector distribution over a lattice's sites: its second
//!   moment and participation number), [`energy`] (the energy distribution over the sites,
//!   the same two numbers; both from [`distribution`]), [`zero_one`] (the 0-1 test for chaos).
//! - [`periodic`]: periodic coordinates (angles): their wrap into one period, which the
//!   orbit indicators and every reader of states see.
//! - [`tracker`]: the streaming state of a run (per scheme and set: stretching sums and latest
//!   vectors) and a scheme's indicators averaged over its sets at its latest renormalization.

pub(crate) mod alignment;
pub mod clv;
pub mod distribution;
pub mod dvd;
pub mod energy;
pub(crate) mod fli;
pub mod indicator;
pub(crate) mod megno;
pub mod norm;
pub mod periodic;
pub mod stats;
pub(crate) mod stretch;
pub mod tracker;
pub mod zero_one;

/// The registry: every set indicator, in report order (GALI, SALI and the exponents, carried in
/// fields of their own; then those carried by name). Adding one: its `pub mod` line above and
/// its line here.
pub fn set_indicators() -> Vec<Box<dyn SetIndicator>> {
    vec![
        Box::new(alignment::Alignment::default()),
        Box::new(stretch::Exponents::default()),
        Box::new(fli::Fli::default()),
        Box::new(megno::Megno::default()),
        Box::new(dvd::DeviationDistribution::default()),
        Box::new(energy::EnergyDistribution::default()),
        Box::new(norm::NormDistribution::default()),
    ]
}

/// The orbit indicators every run tracks, in report order; the 0-1 test observes `zero_one`.
pub fn orbit_indicators(zero_one: &zero_one::ZeroOneObservable) -> Vec<Box<dyn OrbitIndicator>> {
    vec![Box::new(zero_one::ZeroOneTest::new(zero_one.clone()))]
}

pub use alignment::{SIGMA_FLOOR, gali_log10, sali, unit_columns, volume_log10};
pub use indicator::{OrbitIndicator, Output, SetIndicator, SetObservation};
pub use stats::{LogStat, Stat};
pub use stretch::StretchSums;
pub use tracker::{
    FlowField, Layout, Named, NamedOutputs, SchemeIndicators, SetValues, SiteEnergies, Tracker,
};
