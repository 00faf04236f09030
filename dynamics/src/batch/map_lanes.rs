//! The batched form of a discrete map `x -> F(x)` (`crate::system::Map`): many orbits (or
//! tangent vectors) iterated at once through the compiled lane functions of `F`, coordinates
//! with a period wrapped by [`wrap_coordinate`] (`chaoscope_indicators::periodic`, the one
//! definition of that wrap, which the map's one-orbit step, the analysis and the sections use
//! too).
//!
//! Lane by lane these are the bits of the map's `step` / `step_tangent`: the compiled lane
//! function of `F` (or of `J v` around one shared reference state) gives, per lane, exactly
//! the scalar function's result, and the wrap into `[0, P)` is the same function of each
//! value. The SIMD lives inside the compiled code (two or four lanes per vector instruction),
//! so there is no per-ISA instantiation here.

use chaoscope_expr::VectorFunction;

use super::Soa;

/// Iterate every lane of `x` (rows = coordinates) `n_steps` times by `f`, wrapping the
/// coordinates with a period `modulo[i] > 0`; `scratch` is reused.
pub fn map_orbit_steps(
    f: &VectorFunction,
    modulo: &[f64],
    x: &mut Soa,
    n_steps: u64,
    scratch: &mut Vec<f64>,
) {
    let lanes = x.lanes();
    // Rows beyond `D` are the lanes' parameters, read and never written.
    let n = f.dim() * lanes;
    scratch.resize(n, 0.0);
    for _ in 0..n_steps {
        f.value_lanes(x.data(), scratch, lanes);
        x.data_mut()[..n].copy_from_slice(scratch);
        wrap_rows(modulo, x.data_mut(), lanes);
    }
}

/// Iterate one reference orbit `x` `n_steps` times exactly as the map's `step` does, writing
/// the state before every iteration to `stages` (`n_steps * (D + P)` numbers, a state's
/// parameters included): where the tangent map of each iteration is taken.
pub fn record_map_reference(
    f: &VectorFunction,
    modulo: &[f64],
    x: &mut [f64],
    n_steps: u64,
    stages: &mut Vec<f64>,
) {
    let d = f.dim();
    let mut next = vec![0.0; d];
    stages.clear();
    for _ in 0..n_steps {
        stages.extend_from_slice(x);
        f.value(x, &mut next);
        x[..d].copy_from_slice(&next);
        wrap(modulo, x);
    }
}

/// Advance every lane of `v` (tangent vectors) by `n_steps` iterations of the tangent map
/// around the reference states `stages` (from [`record_map_reference`]). `false` when the map
/// has no tangent (the variational method was refused at validation already).
pub fn map_tangent_steps(
    f: &VectorFunction,
    stages: &[f64],
    v: &mut Soa,
    n_steps: u64,
    scratch: &mut Vec<f64>,
) -> bool {
    let lanes = v.lanes();
    let d = v.rows();
    scratch.resize(d * lanes, 0.0);
    for x in stages.chunks_exact(f.state_len()).take(n_steps as usize) {
        if !f.tangent_lanes(x, v.data(), scratch, lanes) {
            return false;
        }
        v.data_mut().copy_from_slice(scratch);
    }
    true
}

fn wrap_rows(modulo: &[f64], data: &mut [f64], lanes: usize) {
    for (row, &p) in data.chunks_exact_mut(lanes).zip(modulo) {
        if p > 0.0 {
            for v in row {
                *v = wrap_coordinate(*v, p);
            }
        }
    }
}

/// Every coordinate with a period `modulo[i] > 0` of `x` into `[0, P)`, and the wrap of one
/// coordinate: defined once, with the periodic coordinates of every system kind.
pub use chaoscope_indicators::periodic::{wrap, wrap_coordinate};
