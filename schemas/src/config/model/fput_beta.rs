//! `[model] name = "fput-beta"`: the beta-FPUT chain with fixed ends, a built-in separable
//! Hamiltonian (`dynamics/src/spec/fput_beta.rs` builds it).

use schemars::JsonSchema;
use serde::{Deserialize, Serialize};

use super::ModelKind;

/// `name = "fput-beta"`: `H = sum p_i^2/2 + sum (q_{i+1} - q_i)^2/2 + beta (q_{i+1} - q_i)^4/4`.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct FputBetaConfig {
    /// Number of particles `N`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub n: Option<usize>,
    /// Quartic coupling (default 1).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub beta: Option<f64>,
}

impl ModelKind for FputBetaConfig {
    fn canonical(&self) -> bool {
        true
    }
}
