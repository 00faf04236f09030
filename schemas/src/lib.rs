//! chaoscope-schemas: the single definition of chaoscope's data contract.
//!
//! - [`config`]: the TOML run configuration (`config::sweep`: `[[sweep]]` ranges expanded into
//!   schemes).
//! - [`proto`]: the protobuf messages stored in MCAP and their FileDescriptorSet.
//! - [`names`]: run, service, node and topic names.
//! - [`run`]: what a run is made of as recordings carry it: samples, schemes, the kind of
//!   system, the size limits.

pub mod config;
pub mod names;
pub mod proto;
pub mod run;

/// Version of the bus and file formats. Bumped on any incompatible change; both the bus headers
/// and the recordings carry it, and readers refuse versions they do not know.
pub const FORMAT_VERSION: u32 = 1;
