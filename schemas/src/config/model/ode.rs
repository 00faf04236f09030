//! `[model] name = "ode"`: a flow `dx/dt = f(x)` written as expressions
//! (`dynamics/src/spec/ode.rs` builds it).

use std::collections::BTreeMap;

use schemars::JsonSchema;
use serde::{Deserialize, Serialize};

use super::{BoundaryConfig, ModelKind, ParamValue};

/// `name = "ode"`: `dx/dt = f(x)`.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct OdeConfig {
    /// Parameters the expressions name: a number, or an array with one entry per coordinate.
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub params: BTreeMap<String, ParamValue>,
    /// What lattice sums see beyond the ends (as for `potential`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub boundary: Option<String>,
    /// The right-hand side `f_1(x), ..., f_D(x)`, one expression per coordinate over `x1..xD`
    /// (or `x[i]`) and `params`; `D` is the number of entries.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rhs: Option<Vec<String>>,
    /// Per coordinate of the state `x1..xD` (D entries), its period or 0, as for `potential`:
    /// the integration never wraps the state, what is read and shown of it does.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub modulo: Option<Vec<f64>>,
}

impl ModelKind for OdeConfig {
    fn params(&self) -> Option<&BTreeMap<String, ParamValue>> {
        Some(&self.params)
    }
    fn modulo(&self) -> Option<&[f64]> {
        self.modulo.as_deref()
    }
    fn summed_sites(&self) -> (Option<&str>, Option<BoundaryConfig>, Option<usize>) {
        (None, self.boundary.clone().map(BoundaryConfig::Every), None)
    }
}
