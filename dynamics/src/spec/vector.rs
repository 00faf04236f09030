//! The config keys of a vector function, shared by every system written as `D` expressions over
//! `x1..xD`: a flow's `rhs = [...]` and a map's `next = [...]` (with `params` and `boundary` as
//! for potentials); and a map's `modulo = [...]`.

use std::collections::BTreeMap;

use chaoscope_expr::lower::{Boundary, ParamValue};
use chaoscope_expr::vector::HamiltonianDefinition;
use chaoscope_expr::{VectorDefinition, VectorError, VectorFunction};
use chaoscope_schemas::config;

use super::potential::param_value;
use super::{LaneParam, SpecError};

/// `params` as the expressions read them: each of `lanes` (a scalar of `params`) a
/// [`ParamValue::Lane`] of argument `arg` (the compiled functions' `ARG_PARAMS`: of
/// [`chaoscope_expr::vector`], or of [`chaoscope_expr::potential`]), numbered in the order of
/// `lanes`, the others their values; and the config's values of `lanes` in that order (a
/// state's entries after its coordinates).
pub(super) fn expression_params(
    params: &BTreeMap<String, config::ParamValue>,
    n: usize,
    size: &str,
    lanes: &[LaneParam],
    arg: u8,
) -> Result<(BTreeMap<String, ParamValue>, Vec<f64>), SpecError> {
    let mut values = BTreeMap::new();
    for (name, v) in params {
        values.insert(
            name.clone(),
            param_value(&format!("model.params.{name}"), v, n, size)?,
        );
    }
    let mut lane_values = Vec::with_capacity(lanes.len());
    for (j, lane) in lanes.iter().enumerate() {
        let key = format!("model.params.{}", lane.name);
        let value = match values.get(&lane.name) {
            Some(ParamValue::Scalar(v)) => *v,
            Some(_) => {
                return Err(SpecError::new(
                    key,
                    "is an array; a parameter axis sets a scalar parameter",
                ));
            }
            None => {
                return Err(SpecError::new(
                    key,
                    "is not a parameter of the model (a parameter axis names a key of [model] params)",
                ));
            }
        };
        lane_values.push(value);
        values.insert(
            lane.name.clone(),
            ParamValue::Lane {
                arg,
                index: j as u32,
                min: lane.min,
                max: lane.max,
            },
        );
    }
    Ok((values, lane_values))
}

/// `components` of the config key `model.<key>` compiled with `params` and `boundary`
/// (default `fixed`), the parameters `lanes` read from each state (with the config's values
/// of them). A component's error is reported under `model.<key>` as `<key>[i]: line L,
/// column C: ...` with the source line and a caret.
pub fn vector_function(
    key: &str,
    components: &[String],
    params: &BTreeMap<String, config::ParamValue>,
    boundary: Option<&str>,
    lanes: &[LaneParam],
) -> Result<(VectorFunction, Vec<f64>), SpecError> {
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
    let (values, lane_values) =
        expression_params(params, d, &size, lanes, chaoscope_expr::vector::ARG_PARAMS)?;
    let boundary = Boundary::from_name(boundary.unwrap_or("fixed"))
        .map_err(|e| SpecError::new("model.boundary", e))?;
    VectorFunction::new(VectorDefinition {
        key: key.to_string(),
        components: components.to_vec(),
        params: values,
        boundary,
        tables: Vec::new(),
        // A flow's right-hand side may read the time; a map's `next` may not (its time counts
        // iterations, and `t` stays an ordinary name there).
        time: key == "rhs",
    })
    .map(|f| (f, lane_values))
    .map_err(|e| match e {
        VectorError::Component { .. } => SpecError::new(&model_key, e.to_string()),
        VectorError::Other(m) => SpecError::new(&model_key, m),
    })
}

/// `[model] hamiltonian = "<H(q, p)>"` on `n` degrees of freedom: its vector field
/// `(dH/dp, -dH/dq)` compiled with `H` as the energy. Errors are reported under
/// `model.hamiltonian` with line, column and caret.
pub(crate) fn hamiltonian_function(
    source: &str,
    sites: super::lattice_shape::Sites,
    params: &BTreeMap<String, config::ParamValue>,
    lanes: &[LaneParam],
) -> Result<(VectorFunction, Vec<f64>), SpecError> {
    let key = "model.hamiltonian";
    let n = sites.count;
    let size = format!("the system has {n} degrees of freedom");
    let (values, lane_values) =
        expression_params(params, n, &size, lanes, chaoscope_expr::vector::ARG_PARAMS)?;
    VectorFunction::hamiltonian(HamiltonianDefinition {
        key: "hamiltonian".to_string(),
        n,
        source: source.to_string(),
        params: values,
        boundary: sites.boundary,
        shape: sites.shape,
        tables: Vec::new(),
    })
    .map(|f| (f, lane_values))
    .map_err(|e| match e {
        // One expression: "hamiltonian[1]: ..." says nothing the key does not.
        VectorError::Component { error, .. } => SpecError::new(key, error.to_string()),
        VectorError::Other(m) => SpecError::new(key, m),
    })
}

/// The `params` of an expression model that none of its expressions reads, each as the warning
/// a user is shown: `model.params.unused = 3 is used by no expression`. Not an error (an
/// expression commented out leaves its parameters behind); empty for the built-in models and
/// for expressions that do not parse (their error is the validation's to report).
pub fn unused_params(model: &config::ModelConfig) -> Vec<String> {
    use config::ModelConfig as M;
    let (params, sources): (_, Vec<&str>) = match model {
        M::Potential(m) => (&m.params, m.potential.iter().map(String::as_str).collect()),
        M::Hamiltonian(m) => (
            &m.params,
            m.hamiltonian.iter().map(String::as_str).collect(),
        ),
        M::Ode(m) => (
            &m.params,
            m.rhs.iter().flatten().map(String::as_str).collect(),
        ),
        M::Map(m) => (
            &m.params,
            m.next.iter().flatten().map(String::as_str).collect(),
        ),
        _ => return Vec::new(),
    };
    let mut read = std::collections::BTreeSet::new();
    for source in sources {
        let Ok(expr) = chaoscope_expr::parse(source) else {
            return Vec::new();
        };
        read.extend(expr.names().into_iter().map(str::to_string));
    }
    params
        .iter()
        .filter(|(name, _)| !read.contains(name.as_str()))
        .map(|(name, value)| {
            let value = match value {
                config::ParamValue::Scalar(v) => v.to_string(),
                config::ParamValue::Array(vs) => {
                    let shown: Vec<String> = vs.iter().take(4).map(f64::to_string).collect();
                    let more = if vs.len() > 4 { ", ..." } else { "" };
                    format!("[{}{more}]", shown.join(", "))
                }
                config::ParamValue::Drawn(d) => format!(
                    "{{ uniform = [{}, {}], seed = {} }}",
                    d.uniform[0], d.uniform[1], d.seed
                ),
            };
            format!("model.params.{name} = {value} is used by no expression")
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use chaoscope_schemas::config::RunConfig;

    use super::unused_params;

    #[test]
    fn a_parameter_no_expression_reads_is_named() {
        let config = |model: &str| {
            RunConfig::from_toml(&format!(
                "[model]\n{model}\n[orbit]\nx = [0.0, 0.0]\n[integrator]\nt_final = 1\n\
                 [deviations]\nk = 1\n"
            ))
            .unwrap()
            .model
        };
        let map = config(
            "name = \"map\"\nnext = [\"1 - a*x1^2 + x2\", \"b*x1\"]\n\
             params = { a = 1.4, b = 0.3, unused = 3, w = [1, 2, 3, 4, 5] }",
        );
        assert_eq!(
            unused_params(&map),
            [
                "model.params.unused = 3 is used by no expression",
                "model.params.w = [1, 2, 3, 4, ...] is used by no expression",
            ]
        );
        // Read only as an array entry, or inside a lattice sum: used.
        let potential = config(
            "name = \"potential\"\nn = 3\n\
             potential = \"sum(i = 1..N, k[i] * q[i]^2 / 2) + c\"\n\
             params = { k = [1, 2, 3], c = 0.5 }",
        );
        assert!(unused_params(&potential).is_empty());
        let ode = config("name = \"ode\"\nrhs = [\"x2\", \"-x1\"]\nparams = { gamma = 0.1 }");
        assert_eq!(
            unused_params(&ode),
            ["model.params.gamma = 0.1 is used by no expression"]
        );
        assert!(unused_params(&config("name = \"henon-heiles\"")).is_empty());
    }
}
