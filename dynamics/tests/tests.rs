//! The dynamics crate's tests in one binary (one link; each file a module): the physics of the
//! integrators and indicators, the engine, maps and the batched kernel.

mod batch_kernel;
mod common;
mod ddnls;
mod discrete_maps;
mod energy_error_order;
mod fput_n5;
mod hh_chaotic;
mod hh_regular_gali;
mod hostile_configs;
mod indicator_properties;
mod map_batch;
mod map_routes;
mod potential_models;
mod propagator_run;
mod propagator_vm;
mod square_lattices;
mod taylor;
