//! `[model] name = "henon-heiles"`: the Henon-Heiles potential, a built-in separable
//! Hamiltonian (`dynamics/src/spec/henon_heiles.rs` builds it).

use schemars::JsonSchema;
use serde::{Deserialize, Serialize};

use super::ModelKind;

/// `name = "henon-heiles"`.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct HenonHeilesConfig {
    /// Degrees of freedom: 2 (may be left out).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub n: Option<usize>,
}

impl ModelKind for HenonHeilesConfig {
    fn canonical(&self) -> bool {
        true
    }
}
