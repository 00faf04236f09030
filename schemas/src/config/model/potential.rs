//! `[model] name = "potential"`: a separable Hamiltonian whose potential `V(q)` is written as
//! an expression, on a chain or a square lattice, with tabulated functions
//! (`dynamics/src/spec/potential.rs` builds it).

use std::collections::BTreeMap;

use schemars::JsonSchema;
use serde::{Deserialize, Serialize};

use super::{BoundaryConfig, ModelKind, ParamValue, TableConfig};

/// `name = "potential"`: `H = sum p_i^2 / (2 m_i) + V(q)` with `V` in chaoscope's expression
/// language.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct PotentialConfig {
    /// Number of degrees of freedom (lattice sites) `N`; with `lattice = "square"` the side of
    /// the square (`n^2` sites).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub n: Option<usize>,
    /// `"chain"` (default: `q1..qN`, `q[i]`) or `"square"`: an `n x n` lattice whose sites are
    /// `q[i, j]` (row `i`, column `j`), numbered row by row.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub lattice: Option<String>,
    /// `V(q)` over `q1..qN` (or `q[i]`), `params` and `tables`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub potential: Option<String>,
    /// Parameters the expression names: a number, or an array with one entry per site.
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub params: BTreeMap<String, ParamValue>,
    /// Masses `m_i`: one number for every site or one per site (default 1).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub masses: Option<ParamValue>,
    /// What lattice sums see beyond the ends: `"fixed"` (default: `q[0] = q[N+1] = 0`),
    /// `"periodic"` (`q[N+1] = q[1]`) or `"free"` (terms reaching past an end are left out);
    /// on a square lattice one for both axes or one per axis, `["fixed", "periodic"]` (along
    /// `i`, then along `j`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub boundary: Option<BoundaryConfig>,
    /// Tabulated functions the expression may call by name, e.g. `U = "bond.csv"`.
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub tables: BTreeMap<String, TableConfig>,
    /// Per coordinate of the state `q1..qN, p1..pN` (2N entries), the period it is taken
    /// modulo (e.g. `6.283185307179586` for an angle), or 0 for a coordinate that is not
    /// periodic: as a map's `modulo`. The integration never wraps the state (the exponents are
    /// those of the unwrapped flow); what is read and shown of it (the verdict's extent, the 0-1
    /// test, sections) takes the wrapped value.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub modulo: Option<Vec<f64>>,
}

impl ModelKind for PotentialConfig {
    lattice_expression_answers!();
    fn tables(&self) -> Option<&BTreeMap<String, TableConfig>> {
        Some(&self.tables)
    }
    fn tables_mut(&mut self) -> Option<&mut BTreeMap<String, TableConfig>> {
        Some(&mut self.tables)
    }
}
