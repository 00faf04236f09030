//! chaoscope-recorder: subscribes to a run on the iceoryx2 bus and writes it to MCAP (the file's
//! layout, the indicators channel and the per-message logic are `chaoscope-files`).
//!
//! - [`subscription`]: the bus side, waking on iceoryx2 events and watching the producer's
//!   node liveness.
//! - `discover`: finding a run to record.
//! - `write_thread`: a recording written on a thread of its own, the indicators computed on
//!   the caller's (the recorder's two cores).
//! - [`record`]: the recorder process loop gluing the above.

mod discover;
pub(crate) mod record;
pub mod subscription;
mod write_thread;

pub use record::{RecordError, RecordOptions, RecordOutcome, record};
