//! chaoscope-recorder: subscribes to a run on the iceoryx2 bus and writes it to MCAP.
//!
//! Sans-io core and I/O shell:
//! - [`sequence`]: gap and duplicate accounting of frame sequence numbers (pure).
//! - [`file`]: the MCAP layout of a recording (schemas, channels, metadata) over any
//!   `Write + Seek` (pure of the bus).
//! - [`indicators`]: the indicators channel (GALI, SALI, exponents per scheme and sample), from
//!   the same tracker as `chaoscope analyze`.
//! - [`recording`]: what a recorder does with each bus message and how it finalizes (pure).
//! - [`subscription`]: the bus side, waking on iceoryx2 events and watching the producer's
//!   node liveness.
//! - [`discover`]: finding a run to record.
//! - [`write_thread`]: a recording written on a thread of its own, the indicators computed on
//!   the caller's (the recorder's two cores).
//! - [`record`]: the recorder process loop gluing the above.
//! - [`recover`]: salvaging a file whose writer was killed, streamed through [`scan`].
//! - `testing` (feature `testing`): synthetic recordings and hostile variants of files, for tests
//!   and benches.

pub mod discover;
pub mod file;
pub mod indicators;
pub mod map_file;
pub mod record;
pub mod recording;
pub mod recover;
pub mod scan;
pub mod sequence;
pub mod subscription;
#[cfg(any(test, feature = "testing"))]
pub mod testing;
pub mod write_thread;

pub use record::{RecordError, RecordOptions, RecordOutcome, record};
pub use recover::{RecoverReport, recover};
