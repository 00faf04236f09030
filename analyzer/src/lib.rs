//! chaoscope-analyzer: streaming analysis of a recorded or live run (GALI, SALI, Lyapunov
//! exponents, energy error), replay with other renormalization settings, Poincare sections, and
//! the plots.
//!
//! The core ([`analysis`]) is sans-io: it is fed a run header and samples. Readers around it
//! turn an MCAP file ([`recording`]), the bus (`chaoscope_bus::monitor`, as messages) or the engine
//! in process into samples.

pub mod analysis;
pub mod assemble;
pub mod chart;
pub mod csv;
pub mod inprocess;
pub mod map_png;
pub mod plot;
pub mod progress;
pub mod recording;
pub mod replay;
pub mod report;
pub mod run_info;
pub mod section;
pub mod series;
/// Averages over sets, shared with the recorder (re-exported from `chaoscope-indicators`).
pub use chaoscope_indicators::stats;
pub mod summary;
pub mod verdict;
pub mod vshape;
pub mod write;

pub use analysis::{Analysis, AnalysisOptions};
pub use report::Report;
pub use run_info::RunInfo;
