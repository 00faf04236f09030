//! chaoscope-files: what lands in files, and the one way they are read back. No bus: the
//! recorder process (`chaoscope-recorder`) and the in-process writers drive these.
//!
//! - `sequence`: gap and duplicate accounting of frame sequence numbers (pure).
//! - [`file`]: the MCAP layout of a recording (schemas, channels, metadata) over any
//!   `Write + Seek`.
//! - [`indicators`]: the indicators channel (GALI, SALI, exponents per scheme and sample), from
//!   the same tracker as `chaoscope analyze`.
//! - [`recording`]: what a recorder does with each message of a run and how it finalizes (pure).
//! - [`scan`]: the one MCAP reader of the workspace.
//! - [`map_file`]: map files.
//! - [`recover`]: salvaging a file whose writer was killed, streamed through [`scan`].
//! - `testing` (feature `testing`): synthetic recordings and hostile variants of files, for tests
//!   and benches.

pub mod file;
pub mod indicators;
pub mod map_file;
pub mod recording;
pub mod recover;
pub mod scan;
mod sequence;
#[cfg(any(test, feature = "testing"))]
pub mod testing;

pub use recover::{RecoverReport, recover};
