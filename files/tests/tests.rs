//! The file tests in one binary (one link; each file a module): the MCAP reader, map files and
//! the salvage of a killed writer's file. `scan_lengths.rs` is a binary of its own: it measures
//! the largest allocation of its whole process.

mod map_file;
mod recover;
mod scan;
