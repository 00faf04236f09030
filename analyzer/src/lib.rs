//! chaoscope-analyzer: streaming analysis of a recorded or live run (GALI, SALI, Lyapunov
//! exponents, energy error, the verdict), and its tables, CSV, plots and map images.
//!
//! The core ([`analysis`]) is sans-io: it is fed a run header and samples. Readers around it
//! turn an MCAP file ([`recording`]) or the messages of the bus's monitor stream
//! ([`assemble`], fed by `chaoscope_bus::monitor`) into samples. It depends on no engine:
//! replay and in-process runs are `chaoscope-app`'s, Poincare sections the producer's.

pub mod analysis;
pub mod assemble;
pub mod chart;
pub mod clv;
pub mod csv;
pub mod map_png;
pub(crate) mod npy;
pub mod plane_png;
pub mod plot;
pub mod progress;
pub mod recording;
pub mod report;
pub mod run_info;
pub(crate) mod series;
pub(crate) mod site_png;
pub(crate) mod site_profiles;
/// Averages over sets, shared with the recorder (re-exported from `chaoscope-indicators`).
pub use chaoscope_indicators::stats;
pub mod summary;
pub mod table;
pub mod verdict;
pub mod vshape;
pub mod write;

pub use analysis::{Analysis, AnalysisOptions};
pub use report::Report;
pub use run_info::RunInfo;
