//! chaoscope-analyzer
pub mod map_png;
pub mod summary;
