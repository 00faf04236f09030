//! chaoscope-dynamics: the numerical core (models, systems, integrators, the deviation methods,
//! the run engine, phase-space maps, sections, estimates). The process that publishes a run on
//! the bus is `chaoscope-dynamics`, around it.
//!
//! Every module is computation without I/O, with two exceptions stated where they live: the
//! validation of a `potential` reads the tables its config names (`spec`), and
//! `estimate::Machine::this_host` reads the machine's cores and memory.

pub mod batch;
pub(crate) mod deviation;
pub mod engine;
pub mod estimate;
pub mod header;
pub mod integrator;
pub mod map;
pub(crate) mod method;
pub mod model;
pub mod propagator;
pub mod renormalization;
pub mod section;
pub mod spec;
pub mod system;
pub mod vector_field;
pub(crate) mod window;

/// GALI, SALI and the finite-time exponents live in their own crate (the recorder computes them
/// too, and must not depend on the producer); re-exported under their old path.
pub use chaoscope_indicators as indicators;
