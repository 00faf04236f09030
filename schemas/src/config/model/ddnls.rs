//! `[model] name = "ddnls"`: the disordered discrete nonlinear Schroedinger lattice, a built-in
//! Hamiltonian that is not separable into `T(p) + V(q)` (the producer integrates it by
//! compositions of its three parts' exact flows). What the values may be is checked by the
//! validation (`dynamics/src/spec/ddnls.rs`).

use schemars::JsonSchema;
use serde::{Deserialize, Serialize};

/// `name = "ddnls"`: `H = sum_l [eps_l |psi_l|^2 + (beta/2) |psi_l|^4] - sum over neighbours
/// (psi_l psi_m* + c.c.)`, `psi_l = (q_l + i p_l)/sqrt(2)`, fixed ends, `eps_l` uniform in
/// `[-W/2, W/2]` drawn from `seed`.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct DdnlsConfig {
    /// `"chain"` (default: a 1-D chain of `n` sites) or `"square"` (a 2-D `n x n` lattice,
    /// sites numbered row by row).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub lattice: Option<String>,
    /// Sites of the chain, or per side of the square lattice.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub n: Option<usize>,
    /// Disorder strength: `eps_l` uniform in `[-W/2, W/2]` (0: an ordered lattice).
    #[serde(default, rename = "W", skip_serializing_if = "Option::is_none")]
    pub w: Option<f64>,
    /// Nonlinearity `beta`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub beta: Option<f64>,
    /// The disorder realization: another seed, another `eps_l`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub seed: Option<u64>,
}

impl super::ModelKind for DdnlsConfig {
    fn canonical(&self) -> bool {
        true
    }
    fn square_side(&self) -> Option<usize> {
        super::square_side(self.lattice.as_deref(), self.n)
    }
}
