//! `[model] name = "potential"`: the config keys of a user-written potential, checked and
//! turned into a compiled [`ExpressionModel`].
//!
//! The one place in the validation that reads files: the tables a config names. Their SHA-256
//! digests are returned so the recording's configuration pins them (replay and map resume on
//! another machine then refuse a table that differs).

use std::sync::Arc;

use chaoscope_expr::lower::{ParamValue, Shape};
use chaoscope_expr::table::{self, Spline, SplineEnds};
use chaoscope_schemas::config::{self, ModelConfig, PotentialConfig, RunConfig, TableConfig};

use super::lattice_shape::Sites;
use super::{Built, LaneParam, SeparableModel, SpecError, separable};
use crate::integrator::SplittingScheme;
use crate::model::{ExpressionModel, PotentialDefinition, SeparableHamiltonian};

/// Most degrees of freedom of a potential model (the straight-line compiled code grows with N).
pub const MAX_SITES: usize = 100_000;

/// A table as loaded: its name in the expression and the digest of the file.
#[derive(Debug, Clone, PartialEq)]
pub struct TableDigest {
    pub name: String,
    pub sha256: String,
}

/// A parameter's value from the config: finite, and an array has one entry per site (`n`,
/// described as `size` in the message: "the model has n = 5 sites").
pub(crate) fn param_value(
    key: &str,
    v: &config::ParamValue,
    n: usize,
    size: &str,
) -> Result<ParamValue, SpecError> {
    match v {
        config::ParamValue::Scalar(x) if x.is_finite() => Ok(ParamValue::Scalar(*x)),
        config::ParamValue::Scalar(x) => {
            Err(SpecError::new(key, format!("must be finite, got {x}")))
        }
        config::ParamValue::Array(xs) => {
            if xs.len() != n {
                return Err(SpecError::new(
                    key,
                    format!("has {} entries but {size}", xs.len()),
                ));
            }
            if let Some(i) = xs.iter().position(|x| !x.is_finite()) {
                return Err(SpecError::new(
                    key,
                    format!("entry {} is not finite ({})", i + 1, xs[i]),
                ));
            }
            Ok(ParamValue::Array(xs.clone()))
        }
        config::ParamValue::Drawn(d) => {
            let [lo, hi] = d.uniform;
            if let Some(problem) = super::drawn::range_problem(lo, hi) {
                return Err(SpecError::new(key, problem));
            }
            Ok(ParamValue::Array(super::drawn::uniform(lo, hi, d.seed, n)))
        }
    }
}

fn sites(n: usize) -> String {
    format!("the model has n = {n} sites")
}

fn inverse_masses(
    m: &config::ParamValue,
    n: usize,
    size: &str,
) -> Result<Option<Vec<f64>>, SpecError> {
    let masses = match param_value("model.masses", m, n, size)? {
        ParamValue::Scalar(m) => vec![m; n],
        ParamValue::Array(ms) => ms,
        ParamValue::Lane { .. } => unreachable!("param_value gives no lane parameters"),
    };
    if let Some(i) = masses.iter().position(|&m| m <= 0.0) {
        return Err(SpecError::new(
            "model.masses",
            format!("mass {} must be positive, got {}", i + 1, masses[i]),
        ));
    }
    // Unit masses keep the mass-free code paths (bit-identical to the built-in models).
    Ok(if masses.iter().all(|&m| m == 1.0) {
        None
    } else {
        Some(masses.iter().map(|m| 1.0 / m).collect())
    })
}

fn load_table(name: &str, cfg: &TableConfig) -> Result<(Arc<Spline>, TableDigest), SpecError> {
    let key = format!("model.tables.{name}");
    let spec = cfg.spec();
    let data = table::read_csv(std::path::Path::new(&spec.file))
        .map_err(|e| SpecError::new(&key, e.to_string()))?;
    let digest = data.digest_hex();
    if let Some(pinned) = &spec.sha256
        && !pinned.eq_ignore_ascii_case(&digest)
    {
        return Err(SpecError::new(
            format!("{key}.sha256"),
            format!(
                "{} has SHA-256 {digest}, but this run was made with {pinned}: the table \
                 differs from the one recorded",
                spec.file
            ),
        ));
    }
    let kind = match (spec.spline.as_deref().unwrap_or("natural"), spec.slopes) {
        ("natural", None) => SplineEnds::Natural,
        ("natural", Some(_)) => {
            return Err(SpecError::new(
                format!("{key}.slopes"),
                "slopes apply to spline = \"clamped\"",
            ));
        }
        ("clamped", Some([left, right])) if left.is_finite() && right.is_finite() => {
            SplineEnds::Clamped { left, right }
        }
        ("clamped", _) => {
            return Err(SpecError::new(
                format!("{key}.slopes"),
                "a clamped spline needs finite slopes = [f'(x_first), f'(x_last)]",
            ));
        }
        (other, _) => {
            return Err(SpecError::new(
                format!("{key}.spline"),
                format!("'{other}' is not natural or clamped"),
            ));
        }
    };
    let spline = Spline::new(name, &data.xs, &data.ys, kind)
        .map_err(|e| SpecError::new(&key, e.to_string()))?;
    Ok((
        Arc::new(spline),
        TableDigest {
            name: name.to_string(),
            sha256: digest,
        },
    ))
}

/// Check the keys of a `potential` model, load its tables and compile it.
pub fn potential_model(
    cfg: &PotentialConfig,
) -> Result<SeparableModel, SpecError> {
    potential_model_with_lanes(cfg, &[]).map(|(model, tables, _, _)| (model, tables))
}

/// A compiled potential, the digests of its tables, the config values of its lane parameters
/// and its sites.
type CompiledPotential = (
    Arc<dyn SeparableHamiltonian>,
    Vec<TableDigest>,
    Vec<f64>,
    Sites,
);

/// [`potential_model`] with the parameters `lanes` read per evaluation (a map's parameter
/// axes, entries `0..P` of [`chaoscope_expr::potential::ARG_PARAMS`] in the order of `lanes`)
/// instead of folded; also their config values in that order.
fn potential_model_with_lanes(
    cfg: &PotentialConfig,
    lanes: &[LaneParam],
) -> Result<CompiledPotential, SpecError> {
    let side = cfg.n.ok_or_else(|| {
        SpecError::new("model.n", "a potential model needs the number of sites n")
    })?;
    let lattice = super::lattice_shape::sites(cfg.lattice.as_deref(), cfg.boundary.as_ref(), side)?;
    let n = lattice.count;
    let size = match lattice.shape {
        Shape::Chain => sites(n),
        Shape::Square { .. } => format!("the {side} x {side} lattice has {n} sites"),
    };
    if side == 0 {
        return Err(SpecError::new("model.n", "must be at least 1, got 0"));
    }
    if n > MAX_SITES {
        return Err(SpecError::new(
            "model.n",
            match lattice.shape {
                Shape::Chain => format!("must be between 1 and {MAX_SITES}, got {n}"),
                Shape::Square { .. } => format!(
                    "a square of side {side} has {n} sites; at most {MAX_SITES} are allowed"
                ),
            },
        ));
    }
    let potential = cfg.potential.as_ref().ok_or_else(|| {
        SpecError::new(
            "model.potential",
            "a potential model needs potential = \"...\"",
        )
    })?;
    let (params, lane_values) = super::vector::expression_params(
        &cfg.params,
        n,
        &size,
        lanes,
        chaoscope_expr::potential::ARG_PARAMS,
    )?;
    let inverse_masses = match &cfg.masses {
        Some(m) => inverse_masses(m, n, &size)?,
        None => None,
    };
    let mut tables = Vec::new();
    let mut digests = Vec::new();
    for (name, t) in &cfg.tables {
        let (spline, digest) = load_table(name, t)?;
        tables.push((
            name.clone(),
            spline as Arc<dyn chaoscope_expr::graph::Tabulated>,
        ));
        digests.push(digest);
    }
    let model = ExpressionModel::new(PotentialDefinition {
        n,
        potential: potential.clone(),
        params,
        inverse_masses,
        boundary: lattice.boundary,
        shape: lattice.shape,
        tables,
    })
    .map_err(|e| SpecError::new("model.potential", e.0))?;
    Ok((Arc::new(model), digests, lane_values, lattice))
}

/// The methods that integrate a potential as the flow of its Hamiltonian instead of by a
/// splitting.
const FLOW_METHODS: [&str; 5] = ["rk4", "dop853", "gl4", "gl6", "taylor"];

/// The parameter that carries `1 / m_i` into the kinetic energy of a potential run as a flow
/// (a name no user parameter may take).
const INVERSE_MASS: &str = "_inverse_mass";

/// `name = "potential"`: the compiled model with the splitting of `[integrator]`, reading the
/// parameters `lanes` from every state after its `2N` coordinates; or, with a Runge-Kutta
/// method or Taylor's, the flow of `H = sum p_i^2 / (2 m_i) + V(q)`.
impl super::KindSpec for PotentialConfig {
    fn separable(&self) -> Option<Result<SeparableModel, SpecError>> {
        Some(potential_model(self))
    }

    fn build(&self, cfg: &RunConfig, lanes: &[LaneParam]) -> Result<Built, SpecError> {
        let model = self;
    let method = cfg.integrator.method.as_str();
    if SplittingScheme::from_name(method).is_none() && !FLOW_METHODS.contains(&method) {
        return Err(SpecError::new(
            "integrator.method",
            format!(
                "unknown method '{method}' for a potential (known: the splittings {}; as the \
                 flow of its Hamiltonian: {})",
                SplittingScheme::catalogue(),
                FLOW_METHODS.join(", ")
            ),
        ));
    }
    let (compiled, tables, lane_values, sites) = potential_model_with_lanes(model, lanes)?;
    if FLOW_METHODS.contains(&method) {
        return as_flow(model, cfg, compiled, sites, tables, lanes);
    }
    separable::run_with_lanes(cfg, compiled, tables, &lane_values)
    }
}

/// A potential integrated as the flow of its Hamiltonian `V + sum_i p_i^2 w_i / 2` (`w_i = 1 /
/// m_i`) by `[integrator] method` (Runge-Kutta or Taylor's), from the initial state a
/// splitting would start from (`q` and `p`, an energy solved for a momentum, a preset, an
/// excitation). `V` is the expression as written, so its operations keep their lines and
/// columns in messages; its tables are offered with the splittings only.
fn as_flow(
    cfg_model: &PotentialConfig,
    cfg: &RunConfig,
    compiled: Arc<dyn SeparableHamiltonian>,
    sites: Sites,
    tables: Vec<TableDigest>,
    lanes: &[LaneParam],
) -> Result<Built, SpecError> {
    if let Some(name) = cfg_model.tables.keys().next() {
        return Err(SpecError::new(
            "integrator.method",
            format!(
                "{} integrates V as an expression without tables, and the model has the table \
                 '{name}': use a splitting, or leave the table out",
                cfg.integrator.method
            ),
        ));
    }
    if !cfg.orbit.x.is_empty() {
        return Err(SpecError::new(
            "orbit.x",
            "a Hamiltonian's initial state is q and p (x is for flows and maps)",
        ));
    }
    if cfg_model.params.contains_key(INVERSE_MASS) {
        return Err(SpecError::new(
            format!("model.params.{INVERSE_MASS}"),
            "is the name of the inverse masses of a potential run as a flow: rename it",
        ));
    }
    let n = compiled.dof();
    let mut params = cfg_model.params.clone();
    let site = match sites.shape {
        Shape::Chain => "[i]",
        Shape::Square { .. } => "[i, j]",
    };
    let term = match compiled.inverse_masses() {
        None => format!("p{site}^2/2"),
        Some(w) => {
            params.insert(
                INVERSE_MASS.to_string(),
                config::ParamValue::Array(w.to_vec()),
            );
            format!("p{site}^2*{INVERSE_MASS}{site}/2")
        }
    };
    let kinetic = match sites.shape {
        Shape::Chain => format!("sum(i = 1..N, {term})"),
        Shape::Square { .. } => format!("sum(i = 1..N, sum(j = 1..N, {term}))"),
    };
    let potential = cfg_model.potential.as_deref().unwrap_or("0");
    let source = format!("{potential}\n+ {kinetic}");
    let (field, lane_values) = super::vector::hamiltonian_function(&source, sites, &params, lanes)
        .map_err(|mut e| {
            e.key = "model.potential".to_string();
            e
        })?;
    let system = super::flow::runge_kutta_system(cfg, Arc::new(field))?;
    let x0 = if lane_values.is_empty() {
        super::initial_state(compiled.as_ref(), &cfg.orbit, cfg.model.square_side())?
    } else {
        let bound = crate::model::WithParams::new(&compiled, &lane_values);
        super::initial_state(&bound, &cfg.orbit, cfg.model.square_side())?
    };
    debug_assert_eq!(x0.len(), 2 * n);
    let mut with_x = cfg.clone();
    with_x.orbit = config::OrbitConfig {
        x: x0,
        ..config::OrbitConfig::default()
    };
    super::state_x_with_lanes(&with_x, system, tables, &lane_values)
}

/// `cfg` with every table's `sha256` filled in from `digests` (what recordings carry).
pub fn pin_tables(cfg: &ModelConfig, digests: &[TableDigest]) -> ModelConfig {
    let mut cfg = cfg.clone();
    for d in digests {
        if let Some(t) = cfg.tables_mut().and_then(|tables| tables.get_mut(&d.name)) {
            let mut spec = t.spec();
            spec.sha256 = Some(d.sha256.clone());
            *t = TableConfig::Detailed(spec);
        }
    }
    cfg
}
