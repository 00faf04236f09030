//! The analysis of real runs: the engine in process, its samples fed to the analyzer (one test
//! binary: these modules share their link).

mod analysis_core;
mod angles;
mod clv;
mod flows;
mod general_hamiltonian;
mod hostile_input;
mod indicators;
mod lattice_distributions;
mod nonautonomous;
mod v_shape;
mod verdict;
