//! The batched kernel: many independent orbits (or deviation vectors) advanced at once.
//!
//! [`PointKernel`] (`kernel.rs`) is what the map's methods need from a system's batched form;
//! each kind of system implements it beside itself (`crate::system`), over the lane loops here:
//! a separable Hamiltonian's splitting over a [`LaneHamiltonian`] (`lanes.rs`, the models' lane
//! implementations in `models/`), a map's (`map_lanes.rs`) and a flow's (`flow_lanes.rs`)
//! compiled lane functions.
//!
//! Layout: structure of arrays ([`Soa`]): row `c` holds coordinate `c` of every lane, so one
//! arithmetic expression applied across a row is a plain loop the compiler turns into SIMD.
//! The kernel is compiled three times (AVX-512, AVX2, portable SSE2) and the widest one the CPU
//! supports is picked at run time ([`Isa`]), so one binary runs everywhere.
//!
//! Bit-exactness with the one-orbit path ([`crate::integrator::Splitting`]): every lane performs
//! exactly the floating-point operations of `Splitting::step` / `step_tangent` in the same order,
//! written without fused multiply-add (Rust never contracts `a * b + c`), so a SIMD lane rounds
//! exactly as the scalar code does. Lanes never interact, hence results do not depend on the ISA,
//! on which lanes share a vector, or on the thread that runs them.

mod flow_lanes;
mod isa;
mod kernel;
mod lanes;
mod map_lanes;
mod models;
mod soa;

pub use flow_lanes::{FlowScratch, flow_orbit_steps, flow_tangent_steps, record_flow_reference};
pub use isa::Isa;
pub(crate) use isa::on_isa;
pub use kernel::PointKernel;
pub use lanes::{LaneHamiltonian, StepCoeffs, record_reference_stages};
pub use map_lanes::{
    map_orbit_steps, map_tangent_steps, record_map_reference, wrap, wrap_coordinate,
};
pub use models::{AnyLaneModel, DynLanes};
pub use soa::Soa;

/// Advance every lane of `x` (rows `0..2N` = q, p) by `n_steps` steps of the splitting.
pub fn orbit_steps<M: LaneHamiltonian>(
    isa: Isa,
    model: &M,
    coeffs: &StepCoeffs,
    x: &mut Soa,
    n_steps: u64,
) {
    isa::dispatch_orbits(isa, model, coeffs, x, n_steps)
}

/// Advance every lane of `v` (deviation vectors, rows = dq, dp) by `n_steps` steps of the tangent
/// map around one shared reference orbit, whose positions before each kick are in `stages`
/// (`n_steps * kicks * N` numbers, from [`record_reference_stages`]).
pub fn tangent_steps<M: LaneHamiltonian>(
    isa: Isa,
    model: &M,
    coeffs: &StepCoeffs,
    stages: &[f64],
    v: &mut Soa,
    n_steps: u64,
) {
    isa::dispatch_tangents(isa, model, coeffs, stages, v, n_steps)
}

/// Advance every lane of `x` by `n_steps` steps: rows `0..2N` are an orbit, each further `2N`
/// rows a tangent vector around that lane's own orbit (the variational equations of many
/// points at once, for the map's VM basis route). Lane by lane the bits of
/// [`record_reference_stages`] + [`tangent_steps`].
pub fn orbit_tangent_steps<M: LaneHamiltonian>(
    isa: Isa,
    model: &M,
    coeffs: &StepCoeffs,
    x: &mut Soa,
    n_steps: u64,
) {
    isa::dispatch_orbit_tangents(isa, model, coeffs, x, n_steps)
}
