//! chaoscope-analyzer
pub mod summary;
pub mod map_png;
