//! `[model] name = "map"`: a map `x -> F(x)` written as expressions
//! (`dynamics/src/spec/map.rs` builds it).

use std::collections::BTreeMap;

use schemars::JsonSchema;
use serde::{Deserialize, Serialize};

use super::{ModelKind, ParamValue};

/// `name = "map"`: `x -> F(x)`.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct MapModelConfig {
    /// Parameters the expressions name: a number, or an array with one entry per coordinate.
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub params: BTreeMap<String, ParamValue>,
    /// What lattice sums see beyond the ends (as for `potential`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub boundary: Option<String>,
    /// The map, one expression `F_i(x)` per coordinate over `x1..xD` (or `x[i]`) and `params`;
    /// `D` is the number of entries.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub next: Option<Vec<String>>,
    /// Per coordinate, the period it is taken modulo (e.g. `6.283185307179586` for an angle),
    /// or 0 for a coordinate that is not wrapped. Separations of nearby orbits are measured on
    /// the torus (the minimal image).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub modulo: Option<Vec<f64>>,
}

impl ModelKind for MapModelConfig {
    fn params(&self) -> Option<&BTreeMap<String, ParamValue>> {
        Some(&self.params)
    }
    fn modulo(&self) -> Option<&[f64]> {
        self.modulo.as_deref()
    }
}
