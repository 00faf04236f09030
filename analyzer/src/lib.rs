//! chaoscope-analyzer
pub mod summary;
