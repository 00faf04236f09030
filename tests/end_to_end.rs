//! The workspace's end-to-end tests in one binary (one link; each file a module): the commands
//! as a user runs them, as processes that talk over the bus and through files, and the files
//! and services as other programs read them. The tests start the `chaoscope` binary, and each
//! takes its own run names, bus services and temporary directories, so they run side by side
//! on the harness's threads. Run one file with `cargo test --release --test end_to_end
//! output_paths::`.
//!
//! Three stay binaries of their own: `slurm_cluster.rs` and `aarch64_bit_identical.rs` need
//! what CI sets up apart (a Slurm cluster, an aarch64 build), and `load.rs` loads the machine
//! on purpose (six commands and a stream of watchers at once), which the time bounds of the
//! tests here must not share.

mod common;

mod analyzer_live_and_replay;
mod bad_configs;
mod c_kernel_switch;
mod crash_loop;
mod flows_and_maps;
mod full_disk;
mod fuzz_corpus;
mod gallery;
mod hostile_files;
mod independent_fput5;
mod indicators_channel;
mod map_bus;
mod map_cli;
mod node_foxglove;
mod other_users;
mod output_paths;
mod paper_reduced;
mod pipeline_crash;
mod pipeline_end_to_end;
mod potential_pipeline;
