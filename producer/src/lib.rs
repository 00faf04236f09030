//! chaoscope-producer: the numerical core (models, integrators, deviation dynamics, indicators,
//! the run engine) and the producer process that publishes a run on the bus.
//!
//! Every module except the process wrapper is pure computation with no I/O.

pub mod batch;
pub mod deviation;
pub mod engine;
pub mod estimate;
pub mod integrator;
pub mod map;
pub mod method;
pub mod model;
pub mod propagator;
pub mod publish;
pub mod renormalization;
pub mod section;
pub mod spec;
pub mod system;
pub mod vector_field;

/// GALI, SALI and the finite-time exponents live in their own crate (the recorder computes them
/// too, and must not depend on the producer); re-exported under their old path.
pub use chaoscope_indicators as indicators;
