//! chaoscope-schemas: the single definition of chaoscope's data contract.
//!
//! - [`config`]: the TOML run configuration.
//! - [`proto`]: the protobuf messages stored in MCAP and their FileDescriptorSet.
//! - [`frame`]: the `#[repr(C)]` headers and payload layout on the iceoryx2 bus.
//! - [`names`]: run, service, node and topic names.
//! - [`bus`]: how every process opens the services (one place, so QoS cannot drift).
//! - [`convert`]: bus frames to protobuf messages.

pub mod bus;
pub mod config;
pub mod convert;
pub mod frame;
pub mod names;
pub mod proto;

/// Version of the bus and file formats. Bumped on any incompatible change; both the bus headers
/// and the recordings carry it, and readers refuse versions they do not know.
pub const FORMAT_VERSION: u32 = 1;
