//! chaoscope-schemas: the one definition of what travels on the bus and what lands in files.

pub mod config;
