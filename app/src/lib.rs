//! chaoscope-app: the application layer, what a command does once its arguments are read, shared
//! by the command line and the Python package. It runs the engine in this process, where the
//! dynamics and the analysis meet (the analyzer reads recordings and samples and depends on no
//! engine), and writes what it computes through the one output path of `chaoscope_os`.
//!
//! - [`replay`]: a recording re-run with other `tau`/`d0` on the bit-identical reference orbit;
//! - [`resume`]: a killed, interrupted or finished run continued from its recording;
//! - [`record`]: a run computed in this process and written to a recording;
//! - [`map`]: a phase-space map computed to a map file, resuming what an earlier one left;
//! - [`inprocess`]: a run computed in this process and fed to an analysis, no file;
//! - [`flow`]: what the analysis needs of the system (vector field, site energies, the 0-1
//!   observable), from a run or a recording.

pub mod flow;
pub mod inprocess;
pub mod map;
pub mod record;
pub mod replay;
pub mod resume;

/// How often a recording being written in process is put on disk in whole chunks: what a kill
/// can lose.
const CHECKPOINT_EVERY: std::time::Duration = std::time::Duration::from_secs(5);

pub use replay::{ReplayError, ReplayOptions, ReplayOutcome, replay};
