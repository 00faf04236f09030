//! chaoscope-analyzer
