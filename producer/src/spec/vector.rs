//! The config keys of a vector function, shared by every system written as `D` expressions over
//! `x1..xD`: a flow's `rhs = [...]` and a map's `next = [...]` (with `params` and `boundary` as
//! for potentials); and a map's `modulo = [...]`.

use std::collections::BTreeMap;

use chaoscope_expr::lower::Boundary;
use chaoscope_expr::vector::HamiltonianDefinition;
use chaoscope_expr::{VectorDefinition, VectorError, VectorFunction};
use chaoscope_schemas::config;

use super::SpecError;
use super::potential::param_value;

/// `components` of the config key `model.<key>` compiled with `params` and `boundary`
/// (default `fixed`). A component's error is reported under `model.<key>` as `<key>[i]: line
/// L, column C: ...` with the source line and a caret.
pub fn vector_function(
    key: &str,
    components: &[String],
    params: &BTreeMap<String, config::ParamValue>,
    boundary: Option<&str>,
) -> Result<VectorFunction, SpecError> {
    let model_key = format!("model.{key}");
    if components.is_empty() {
        return Err(SpecError::new(
            &model_key,
            format!("needs one expression per coordinate, e.g. {key} = [\"x2\", \"-x1\"]"),
        ));
    }
    let d = components.len();
    if d > chaoscope_expr::vector::MAX_DIM {
        return Err(SpecError::new(
            &model_key,
            format!(
                "has {d} components, more than {}",
                chaoscope_expr::vector::MAX_DIM
            ),
        ));
    }
    let size = format!("the system has dimension {d}");
    let mut values = BTreeMap::new();
    for (name, v) in params {
        values.insert(
            name.clone(),
            param_value(&format!("model.params.{name}"), v, d, &size)?,
        );
    }
    let boundary = Boundary::from_name(boundary.unwrap_or("fixed"))
        .map_err(|e| SpecError::new("model.boundary", e))?;
    VectorFunction::new(VectorDefinition {
        key: key.to_string(),
        components: components.to_vec(),
        params: values,
        boundary,
        tables: Vec::new(),
    })
    .map_err(|e| match e {
        VectorError::Component { .. } => SpecError::new(&model_key, e.to_string()),
        VectorError::Other(m) => SpecError::new(&model_key, m),
    })
}

/// `[model] hamiltonian = "<H(q, p)>"` on `n` degrees of freedom: its vector field
/// `(dH/dp, -dH/dq)` compiled with `H` as the energy. Errors are reported under
/// `model.hamiltonian` with line, column and caret.
pub fn hamiltonian_function(
    source: &str,
    n: usize,
    params: &BTreeMap<String, config::ParamValue>,
    boundary: Option<&str>,
) -> Result<VectorFunction, SpecError> {
    let key = "model.hamiltonian";
    let size = format!("the system has {n} degrees of freedom");
    let mut values = BTreeMap::new();
    for (name, v) in params {
        values.insert(
            name.clone(),
            param_value(&format!("model.params.{name}"), v, n, &size)?,
        );
    }
    let boundary = Boundary::from_name(boundary.unwrap_or("fixed"))
        .map_err(|e| SpecError::new("model.boundary", e))?;
    VectorFunction::hamiltonian(HamiltonianDefinition {
        key: "hamiltonian".to_string(),
        n,
        source: source.to_string(),
        params: values,
        boundary,
        tables: Vec::new(),
    })
    .map_err(|e| match e {
        // One expression: "hamiltonian[1]: ..." says nothing the key does not.
        VectorError::Component { error, .. } => SpecError::new(key, error.to_string()),
        VectorError::Other(m) => SpecError::new(key, m),
    })
}
