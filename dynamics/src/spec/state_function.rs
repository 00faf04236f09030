//! Scalar functions of a run's state written as expressions over its coordinates (`x1..xD`, or
//! `q1..qN`, `p1..pN` of a Hamiltonian) with the config's `params` and `boundary`: a section's
//! surface and axes, and the 0-1 test's observable (`[analysis] zero_one_observable`, checked
//! with the rest of the config so a bad one is refused before a run starts).

use chaoscope_expr::ScalarDefinition;
use chaoscope_expr::ScalarFunction;

use chaoscope_schemas::config::{ModelConfig, RunConfig};
use chaoscope_schemas::run::SystemClass;

use super::{RunSpec, SpecError, param_value};

/// The key of the 0-1 test's observable in a config.
pub const ZERO_ONE_OBSERVABLE_KEY: &str = "analysis.zero_one_observable";

/// `cfg`'s `[analysis] zero_one_observable` compiled over the state of `spec`'s system; `None`
/// without the key. Refused in one line naming the key: an expression that does not compile,
/// or one that reads no coordinate (a constant observes nothing of the orbit).
pub fn zero_one_observable(
    spec: &RunSpec,
    cfg: &RunConfig,
) -> Result<Option<ScalarFunction>, SpecError> {
    let Some(source) = &cfg.analysis.zero_one_observable else {
        return Ok(None);
    };
    let function = scalar_over_state(spec, &cfg.model, ZERO_ONE_OBSERVABLE_KEY, source)?;
    if function.reads().is_empty() {
        return Err(SpecError::new(
            ZERO_ONE_OBSERVABLE_KEY,
            format!(
                "'{source}' reads no coordinate of the state: a constant observes nothing of the orbit"
            ),
        ));
    }
    Ok(Some(function))
}

/// `source` compiled as a scalar function of the state of `spec`'s system (its coordinate
/// names, the config's `params` and `boundary`), errors in one line naming `key`: a section's
/// surface, or the period of a stroboscopic section (which reads no coordinate).
pub fn scalar_over_state(
    spec: &RunSpec,
    model: &ModelConfig,
    key: &str,
    source: &str,
) -> Result<ScalarFunction, SpecError> {
    ScalarFunction::new(scalar_definition(spec, model, key, source)?).map_err(|e| {
        let line = e.one_line();
        // The error already starts with the key.
        let message = line
            .strip_prefix(&format!("{key}: ") as &str)
            .unwrap_or(&line)
            .to_string();
        SpecError::new(key, message)
    })
}

/// What defines a scalar function of the state of `spec`'s system: its coordinate families,
/// the config's `params` (checked against the system's size) and `boundary`.
pub(crate) fn scalar_definition(
    spec: &RunSpec,
    model: &ModelConfig,
    key: &str,
    source: &str,
) -> Result<ScalarDefinition, SpecError> {
    let system = spec.system();
    let dim = spec.dim();
    let canonical = system.kind() == SystemClass::Hamiltonian;
    let (families, n) = if canonical {
        let n = dim / 2;
        (vec![("q".to_string(), n), ("p".to_string(), n)], n)
    } else {
        (vec![("x".to_string(), dim)], dim)
    };
    let (lattice, boundary, side) = model
        .kind()
        .map_or((None, None, None), |k| k.summed_sites());
    let sites = super::lattice_shape::sites(lattice, boundary.as_ref(), side.unwrap_or(n))?;
    let params = model.params();
    let size = format!("the system has N = {n}");
    let mut values = std::collections::BTreeMap::new();
    for (name, v) in params.into_iter().flatten() {
        values.insert(
            name.clone(),
            param_value(&format!("model.params.{name}"), v, n, &size)?,
        );
    }
    Ok(ScalarDefinition {
        key: key.to_string(),
        source: source.to_string(),
        families,
        n: sites.shape.n_of(n),
        params: values,
        boundary: sites.boundary,
        shape: sites.shape,
    })
}
