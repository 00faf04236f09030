//! `[model] name = "hamiltonian"`: any Hamiltonian `H(q, p)` written as an expression,
//! integrated by a Runge-Kutta method (`dynamics/src/spec/hamiltonian.rs` builds it).

use std::collections::BTreeMap;

use schemars::JsonSchema;
use serde::{Deserialize, Serialize};

use super::{BoundaryConfig, ModelKind, ParamValue};

/// `name = "hamiltonian"`: any `H(q, p)`, separable or not.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct HamiltonianConfig {
    /// Degrees of freedom `N`; with `lattice = "square"` the side of the square (`n^2` sites).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub n: Option<usize>,
    /// `"chain"` (default) or `"square"` (`q[i, j]`, `p[i, j]`), as for `potential`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub lattice: Option<String>,
    /// Parameters the expression names: a number, or an array with one entry per degree of
    /// freedom.
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub params: BTreeMap<String, ParamValue>,
    /// What lattice sums see beyond the ends (as for `potential`, also per axis).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub boundary: Option<BoundaryConfig>,
    /// `H(q, p)` over `q1..qN`, `p1..pN` (and `q[i]`, `p[i]`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub hamiltonian: Option<String>,
    /// Per coordinate of the state `q1..qN, p1..pN` (2N entries), its period or 0, as for
    /// `potential`: the integration never wraps the state, what is read and shown of it does.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub modulo: Option<Vec<f64>>,
}

impl ModelKind for HamiltonianConfig {
    lattice_expression_answers!();
}
