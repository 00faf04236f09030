//! chaoscope-recorder
