//! A validated run: the numerics' view of a [`RunConfig`].
//!
//! Everything a user can write is checked here, once, with an error that names the key and the
//! problem; past this point the engine only meets consistent input: a [`RunSpec`] is made only
//! by this validation (its fields are private), and nothing draws or allocates in proportion to
//! the run before the caller has seen the resource estimate (the random directions are drawn
//! on first use).
//!
//! One file per kind of `[model]`, named by the kind table
//! (`chaoscope_schemas::for_each_model_kind`), each implementing [`KindSpec`] on its keys'
//! struct: its keys turned into a system and an initial state ([`Built`]). This file dispatches
//! on the kind (the match is generated from the table) and checks what every kind shares (the
//! time grid, the deviations, the schemes). Beside the kinds' files: `separable.rs`, the
//! splitting and initial state of any separable Hamiltonian (built in, a `potential`, or built in
//! code); `flow.rs`, the Runge-Kutta and Taylor settings of the kinds integrated as flows;
//! `vector.rs`, the expression keys they share; `lattice_shape.rs`, chains and square lattices.

use std::sync::{Arc, OnceLock};

use chaoscope_schemas::config::{IntegratorConfig, ModelConfig, RunConfig};
use chaoscope_schemas::run::{
    MAX_SCHEMES, MAX_SETS, MAX_STATE_VALUES, Method, Orthonormalization, Route, SchemeSpec,
    deviation_state_values,
};

use crate::deviation::{self, DirectionError, Directions};
use crate::model::SeparableHamiltonian;
use crate::system::{DynamicalSystem, Time};

pub mod drawn;
mod flow;
mod lattice_shape;
mod separable;
pub mod state_function;
pub mod vector;

pub use ddnls::model_from_config as ddnls_lattice;

pub(crate) use potential::param_value;
pub use potential::{TableDigest, pin_tables};
pub use separable::{
    initial_state, model_from_config, parse_coordinate, solve_momentum, state_coordinate,
};
pub use vector::unused_params;

/// A separable Hamiltonian, with the digests of the tables it read.
pub type SeparableModel = (Arc<dyn SeparableHamiltonian>, Vec<TableDigest>);

/// A kind of `[model]` as the validation sees it, in the kind's file (`spec/MODULE.rs`, one
/// module per line of the kind table, `chaoscope_schemas::for_each_model_kind`).
trait KindSpec {
    /// The system and initial state its keys and `cfg` describe, reading the parameters `lanes`
    /// from every state (a map over parameter axes). By default those of a separable
    /// Hamiltonian without parameter axes ([`separable_without_axes`]).
    fn build(&self, cfg: &RunConfig, lanes: &[LaneParam]) -> Result<Built, SpecError> {
        separable_without_axes(cfg, lanes)
    }

    /// Its separable Hamiltonian with the digests of the tables it read, for the kinds that
    /// are one.
    fn separable(&self) -> Option<Result<SeparableModel, SpecError>> {
        None
    }

    /// Why a map may not put a parameter of the kind `name` on an axis.
    fn why_no_parameter_axes(&self, name: &str) -> String {
        no_parameter_axes(name)
    }
}

/// The kind table's items here: a module per kind and the dispatch.
macro_rules! kind_specs {
    ($($(#[doc = $doc:literal])* $variant:ident = $name:literal in $module:ident: $config:ident;)*) => {
        $(mod $module;)*

        /// The kind `model` names (none for a model built in code).
        fn kind_spec(model: &ModelConfig) -> Option<&dyn KindSpec> {
            match model {
                $(ModelConfig::$variant(m) => Some(m),)*
                ModelConfig::Custom(_) => None,
            }
        }
    };
}

chaoscope_schemas::for_each_model_kind!(kind_specs);

/// The refusal of parameter axes for a kind `name` that takes none.
fn no_parameter_axes(name: &str) -> String {
    format!(
        "parameter axes are not supported for [model] name = {name} (they are for map, ode, \
         hamiltonian and potential)"
    )
}

/// Why the parameter axes of a map cannot be over `model`'s parameters.
pub(crate) fn why_no_parameter_axes(model: &ModelConfig) -> String {
    match kind_spec(model) {
        Some(kind) => kind.why_no_parameter_axes(model.name()),
        None => no_parameter_axes(model.name()),
    }
}

/// The separable Hamiltonian `cfg` names ([`model_from_config`]) with the splitting of
/// `[integrator]`: the built-in models and those built in code, none of which takes parameter
/// axes.
fn separable_without_axes(cfg: &RunConfig, lanes: &[LaneParam]) -> Result<Built, SpecError> {
    refuse_parameter_axes(cfg, lanes)?;
    let (model, tables) = model_from_config(&cfg.model)?;
    separable::run(cfg, model, tables)
}

/// An error unless `lanes` is empty, for a kind that takes no parameter axes.
fn refuse_parameter_axes(cfg: &RunConfig, lanes: &[LaneParam]) -> Result<(), SpecError> {
    if lanes.is_empty() {
        return Ok(());
    }
    Err(SpecError::new("map", why_no_parameter_axes(&cfg.model)))
}

/// The route a configuration names at `key` (absent: per-set).
pub fn route_from_config(key: &str, value: Option<&str>) -> Result<Route, SpecError> {
    match value {
        None => Ok(Route::PerSet),
        Some(name) => Route::from_name(name)
            .ok_or_else(|| SpecError::new(key, format!("'{name}' is not per-set or propagator"))),
    }
}

/// A parameter whose value every point of a map brings (a parameter axis): the compiled
/// functions read it per lane instead of folding it as a constant, and a state of the run is
/// its `D` coordinates followed by these parameters' values, in this order.
#[derive(Debug, Clone, PartialEq)]
pub struct LaneParam {
    /// The name in `[model] params` (a scalar there).
    pub name: String,
    /// The range the axis covers (the smoothness analysis reads its signs).
    pub min: f64,
    pub max: f64,
}

/// A problem with the configuration, naming the key.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{key}: {message}")]
pub struct SpecError {
    pub key: String,
    pub message: String,
}

impl SpecError {
    /// The first line of the message is self-contained, and nothing in it can start a line of
    /// its own: control characters (a newline in a name the message quotes back) are written as
    /// escapes. The one exception is context that follows it on indented lines, as an
    /// expression error's source line and caret (`line 1, column 14: ...\n  x1 +* x2\n     ^`):
    /// where every line after the first starts with two spaces, the line breaks stay real (and
    /// other control characters are still escaped), so a terminal shows the caret under the
    /// mistake while a log's first line still says it all. An indented line cannot pass for an
    /// error line of its own.
    pub fn new(key: impl Into<String>, message: impl Into<String>) -> Self {
        let message: String = message.into();
        // Control characters as escapes; tabs kept where they line a caret up.
        let escape = |text: &str, keep_tabs: bool| -> String {
            text.chars()
                .flat_map(|c| {
                    let escaped: Vec<char> = if c.is_control() && !(keep_tabs && c == '\t') {
                        c.escape_default().collect()
                    } else {
                        vec![c]
                    };
                    escaped
                })
                .collect()
        };
        let mut lines = message.split('\n');
        let first = lines.next().unwrap_or_default();
        let context: Vec<&str> = lines.collect();
        let message = if !context.is_empty() && context.iter().all(|l| l.starts_with("  ")) {
            std::iter::once(escape(first, false))
                .chain(context.iter().map(|l| escape(l, true)))
                .collect::<Vec<_>>()
                .join("\n")
        } else {
            escape(&message, false)
        };
        Self {
            key: key.into(),
            message,
        }
    }
}

/// Longest run accepted, in steps: beyond this `step * h` loses integer exactness in f64.
const MAX_STEPS: u64 = 1 << 52;

/// What the validation of one kind of `[model]` gives: the system, its initial state, and the
/// tables it read.
struct Built {
    system: Arc<dyn DynamicalSystem>,
    x0: Vec<f64>,
    tables: Vec<TableDigest>,
}

/// The initial directions of a run, one entry per set, shared by every scheme: explicit ones
/// (orthonormalized when validated), or random ones drawn on first use.
#[derive(Clone)]
struct DirectionSets {
    random: Option<(u64, usize, usize, usize)>,
    drawn: OnceLock<Vec<Directions>>,
}

impl DirectionSets {
    fn drawn(sets: Vec<Directions>) -> Self {
        Self {
            random: None,
            drawn: OnceLock::from(sets),
        }
    }

    /// `sets` sets of `k` Haar-random directions in dimension `dim` from `seed`.
    fn random(seed: u64, sets: usize, dim: usize, k: usize) -> Self {
        Self {
            random: Some((seed, sets, dim, k)),
            drawn: OnceLock::new(),
        }
    }

    fn sets(&self) -> usize {
        match (self.random, self.drawn.get()) {
            (Some((_, sets, _, _)), _) => sets,
            (None, Some(drawn)) => drawn.len(),
            (None, None) => 0,
        }
    }

    fn get(&self) -> &[Directions] {
        self.drawn.get_or_init(|| {
            let (seed, sets, dim, k) = self.random.expect("explicit directions are drawn");
            (0..sets as u64)
                .map(|s| {
                    // Validation checked 1 <= k <= dim, the only way a draw can fail but for a
                    // rank-deficient Gaussian matrix, an event of probability zero.
                    deviation::random_directions(seed, s, dim, k)
                        .expect("random directions of a validated run")
                })
                .collect()
        })
    }
}

/// A validated run. Made only by [`RunSpec::from_config`], [`RunSpec::with_system`] and
/// [`RunSpec::with_model`]; read through its accessors.
#[derive(Clone)]
pub struct RunSpec {
    system: Arc<dyn DynamicalSystem>,
    h: f64,
    total_steps: u64,
    x0: Vec<f64>,
    e0: f64,
    dim: usize,
    k: usize,
    directions: DirectionSets,
    schemes: Vec<SchemeSpec>,
    seed: u64,
    tables: Vec<TableDigest>,
    /// `[run] sample_every` in steps: a sample at its multiples (and at the end) only; `None`:
    /// at every renormalization.
    sample_every_steps: Option<u64>,
    /// `[model] modulo`: the period of each coordinate (`0`: none), empty when none is
    /// declared. A map's iteration wraps them; a flow's integration never does (what is read
    /// and shown of its state is wrapped).
    periods: Vec<f64>,
}

/// Most values the stretching factors of the renormalizations between two samples of one set
/// may take (`[run] sample_every` over the shortest `tau`, times `k`): 2^20, 8 MiB per record
/// on the bus and in the file.
pub const MAX_EARLIER_STRETCH: u64 = 1 << 20;

impl std::fmt::Debug for RunSpec {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("RunSpec")
            .field("system", &self.system.name())
            .field("kind", &self.system.kind())
            .field("dim", &self.dim)
            .field("h", &self.h)
            .field("total_steps", &self.total_steps)
            .field("x0", &self.x0)
            .field("k", &self.k)
            .field("sets", &self.sets())
            .field("schemes", &self.schemes)
            .finish()
    }
}

pub(crate) fn finite_positive(key: &str, v: f64) -> Result<f64, SpecError> {
    if v.is_finite() && v > 0.0 {
        Ok(v)
    } else {
        Err(SpecError::new(
            key,
            format!("must be a finite positive number, got {}", num(v)),
        ))
    }
}

/// The time step `integrator.h` of a Hamiltonian or a flow, which must be given (only a map,
/// whose time counts iterations, may leave it out).
pub(crate) fn time_step(integrator: &IntegratorConfig) -> Result<f64, SpecError> {
    let h = integrator.h.ok_or_else(|| {
        SpecError::new(
            "integrator.h",
            "missing: the time step of a Hamiltonian or a flow (only a map may leave it out)",
        )
    })?;
    finite_positive("integrator.h", h)
}

pub(crate) use chaoscope_schemas::config::num;

/// `round(t / h)` when `t` is a whole number of steps `h` (to rounding), else an error.
pub fn whole_steps(key: &str, t: f64, h: f64) -> Result<u64, SpecError> {
    let ratio = t / h;
    let n = ratio.round();
    let message = if n.is_nan() {
        format!(
            "{} is not a whole number of time steps h = {}",
            num(t),
            num(h)
        )
    } else if n < 1.0 {
        format!("{} is shorter than one step h = {}", num(t), num(h))
    } else if n > MAX_STEPS as f64 {
        format!(
            "{} is {ratio:.3e} steps of h = {}, more than the limit of 2^52 steps (beyond it \
             step * h is no longer exact)",
            num(t),
            num(h)
        )
    } else if (ratio - n).abs() > 1e-9 * n.max(1.0) {
        format!(
            "{} is not a whole number of time steps h = {} ({ratio} steps)",
            num(t),
            num(h)
        )
    } else {
        return Ok(n as u64);
    };
    Err(SpecError::new(key, message))
}

/// A system other than a separable Hamiltonian, from the initial state `[orbit] x`.
fn state_x(
    cfg: &RunConfig,
    system: Arc<dyn DynamicalSystem>,
    tables: Vec<TableDigest>,
) -> Result<Built, SpecError> {
    state_x_with_lanes(cfg, system, tables, &[])
}

/// [`state_x`] of a system whose states carry `lane_values` (the config's values of its
/// [`LaneParam`]s) after the coordinates.
fn state_x_with_lanes(
    cfg: &RunConfig,
    system: Arc<dyn DynamicalSystem>,
    tables: Vec<TableDigest>,
    lane_values: &[f64],
) -> Result<Built, SpecError> {
    let dim = system.dim();
    let orbit = &cfg.orbit;
    for (key, present) in [
        ("orbit.q", !orbit.q.is_empty()),
        ("orbit.p", !orbit.p.is_empty()),
        ("orbit.energy", orbit.energy.is_some()),
        ("orbit.solve_for", orbit.solve_for.is_some()),
        ("orbit.preset", orbit.preset.is_some()),
        ("orbit.excite", orbit.excite.is_some()),
    ] {
        if present {
            return Err(SpecError::new(
                key,
                format!(
                    "applies to Hamiltonians; the initial state of '{}' is x = [x1, ..., x{dim}]",
                    cfg.model.name()
                ),
            ));
        }
    }
    if orbit.x.len() != dim {
        return Err(SpecError::new(
            "orbit.x",
            format!("needs {dim} values x1..x{dim}, got {}", orbit.x.len()),
        ));
    }
    if let Some(i) = orbit.x.iter().position(|v| !v.is_finite()) {
        return Err(SpecError::new(
            "orbit.x",
            format!("entry {} is not finite", i + 1),
        ));
    }
    let mut x0 = orbit.x.clone();
    x0.extend_from_slice(lane_values);
    if system.invariant(&x0).is_some_and(|e| !e.is_finite())
        || system.divergence(&x0, 0.0).is_some_and(|d| !d.is_finite())
    {
        return Err(SpecError::new(
            "orbit.x",
            format!(
                "the system is not defined at the initial state{}",
                system
                    .diagnose_non_finite(&x0, 0.0)
                    .map(|c| format!(": {c}"))
                    .unwrap_or_default()
            ),
        ));
    }
    Ok(Built { system, x0, tables })
}

impl RunSpec {
    /// Validate a configuration into a run.
    pub fn from_config(cfg: &RunConfig) -> Result<Self, SpecError> {
        Self::from_config_with_lanes(cfg, &[])
    }

    /// A run whose system reads the parameters `lanes` from every state instead of folding
    /// them (a map over parameter axes): its states, `x0` included, are `D` coordinates then
    /// the lane parameters' values (`x0` holds the config's values). The kinds written as
    /// expressions (`map`, `ode`, `hamiltonian`, `potential`) take them; the caller names the
    /// axis in the error of any other kind.
    pub fn from_config_with_lanes(cfg: &RunConfig, lanes: &[LaneParam]) -> Result<Self, SpecError> {
        // `[[sweep]]` ranges are shorthand for schemes: expand them before anything is checked.
        let cfg = &cfg
            .with_sweeps_expanded()
            .map_err(|e| SpecError::new(e.key, e.message))?;
        let built = match kind_spec(&cfg.model) {
            Some(kind) => kind.build(cfg, lanes)?,
            None => separable_without_axes(cfg, lanes)?,
        };
        let spec = Self::validated(cfg, built)?;
        // A map over parameter axes has the lanes' values in its state; it runs no 0-1 test.
        if lanes.is_empty() {
            state_function::zero_one_observable(&spec, cfg)?;
        }
        Ok(spec)
    }

    /// A run of a system built in code (any [`DynamicalSystem`]: a flow, a map, ...): `[orbit]
    /// x` is its initial state, `[integrator] h` and `t_final` its time grid (`h` must be the
    /// system's own step), everything else is validated as usual; `[model] name` is the name
    /// recordings carry.
    pub fn with_system(
        cfg: &RunConfig,
        system: Arc<dyn DynamicalSystem>,
    ) -> Result<Self, SpecError> {
        let cfg = &cfg
            .with_sweeps_expanded()
            .map_err(|e| SpecError::new(e.key, e.message))?;
        let spec = Self::validated(cfg, state_x(cfg, system, Vec::new())?)?;
        state_function::zero_one_observable(&spec, cfg)?;
        Ok(spec)
    }

    /// A run of a model built in code rather than named in the config (the library route for
    /// hand-written models, `examples/custom-model/`): everything but `[model]` is validated as
    /// usual; `[model] name` is the name recordings carry.
    pub fn with_model(
        cfg: &RunConfig,
        model: Arc<dyn SeparableHamiltonian>,
    ) -> Result<Self, SpecError> {
        let cfg = &cfg
            .with_sweeps_expanded()
            .map_err(|e| SpecError::new(e.key, e.message))?;
        let spec = Self::validated(cfg, separable::run(cfg, model, Vec::new())?)?;
        state_function::zero_one_observable(&spec, cfg)?;
        Ok(spec)
    }

    /// What every kind shares: the time grid, deviations and schemes.
    fn validated(cfg: &RunConfig, built: Built) -> Result<Self, SpecError> {
        let Built { system, x0, tables } = built;
        let dim = system.dim();
        let h = match system.time() {
            Time::Continuous { h } => h,
            Time::Discrete => 1.0,
        };
        if matches!(system.time(), Time::Continuous { .. }) {
            let given = time_step(&cfg.integrator)?;
            if h.to_bits() != given.to_bits() {
                return Err(SpecError::new(
                    "integrator.h",
                    format!(
                        "{} differs from the system's own step {}",
                        num(given),
                        num(h)
                    ),
                ));
            }
        }
        let h = finite_positive("integrator.h", h)?;
        let t_final = finite_positive("integrator.t_final", cfg.integrator.t_final)?;
        let total_steps = whole_steps("integrator.t_final", t_final, h)?;
        let e0 = system.invariant(&x0).unwrap_or(0.0);
        let periods = cfg.model.modulo().map(<[f64]>::to_vec).unwrap_or_default();
        chaoscope_indicators::periodic::check_periods(&periods, dim)
            .map_err(|e| SpecError::new("model.modulo", e))?;

        let dev = &cfg.deviations;
        if dev.k == 0 || dev.k > dim {
            return Err(SpecError::new(
                "deviations.k",
                format!(
                    "must be between 1 and {} = {dim} (the dimension), got {}",
                    if system.separable().is_some() {
                        "2N"
                    } else {
                        "D"
                    },
                    dev.k
                ),
            ));
        }
        let state_values = deviation_state_values(
            cfg.schemes.len(),
            dev.sets.max(1) as u64,
            dev.k as u64,
            dim as u64,
        );
        if state_values > MAX_STATE_VALUES {
            return Err(SpecError::new(
                "deviations.sets",
                format!(
                    "{} schemes x {} sets x k = {} x dimension {dim} needs {:.1} GiB of deviation state \
                     (limit {} GiB); use fewer sets or schemes, or split the run",
                    cfg.schemes.len(),
                    dev.sets,
                    dev.k,
                    state_values as f64 * 8.0 / (1u64 << 30) as f64,
                    (MAX_STATE_VALUES * 8) >> 30
                ),
            ));
        }
        let dir_err = |e: DirectionError| SpecError::new("deviations.vectors", e.to_string());
        let directions = match &dev.vectors {
            Some(rows) => {
                if dev.sets != 1 {
                    return Err(SpecError::new(
                        "deviations.sets",
                        "explicit vectors define exactly one set",
                    ));
                }
                if rows.len() != dev.k {
                    return Err(SpecError::new(
                        "deviations.vectors",
                        format!("k = {} but {} vectors are given", dev.k, rows.len()),
                    ));
                }
                let explicit = deviation::explicit_directions(rows, dim).map_err(dir_err)?;
                DirectionSets::drawn(vec![explicit])
            }
            None => {
                if dev.sets == 0 || dev.sets > MAX_SETS {
                    return Err(SpecError::new(
                        "deviations.sets",
                        format!("must be between 1 and {MAX_SETS}, got {}", dev.sets),
                    ));
                }
                DirectionSets::random(dev.seed, dev.sets, dim, dev.k)
            }
        };
        let sets = directions.sets();

        if cfg.schemes.is_empty() {
            return Err(SpecError::new(
                "scheme",
                "at least one [[scheme]] is needed",
            ));
        }
        if cfg.schemes.len() > MAX_SCHEMES {
            return Err(SpecError::new(
                "scheme",
                format!(
                    "{} schemes ([[scheme]] and [[sweep]] together) exceed the limit of \
                     {MAX_SCHEMES}; split the run",
                    cfg.schemes.len()
                ),
            ));
        }
        if let Some(name) = &cfg.run.name {
            chaoscope_schemas::names::validate_run_name(name)
                .map_err(|problem| SpecError::new("run.name", problem))?;
        }
        let mut schemes = Vec::with_capacity(cfg.schemes.len());
        for (i, s) in cfg.schemes.iter().enumerate() {
            let key = |k: &str| format!("scheme[{i}].{k}");
            chaoscope_schemas::names::validate_scheme_name(&s.name)
                .map_err(|problem| SpecError::new(key("name"), problem))?;
            if schemes.iter().any(|o: &SchemeSpec| o.name == s.name) {
                return Err(SpecError::new(
                    key("name"),
                    format!("'{}' is used twice", s.name),
                ));
            }
            let method = Method::from_name(&s.method).ok_or_else(|| {
                SpecError::new(key("method"), format!("'{}' is not vm or mpm", s.method))
            })?;
            if method == Method::Vm
                && let Some(reason) = system.no_tangent_reason()
            {
                return Err(SpecError::new(
                    key("method"),
                    format!("vm refused: {reason}"),
                ));
            }
            let d0 = finite_positive(&key("d0"), s.d0)?;
            let tau = finite_positive(&key("tau"), s.tau)?;
            let tau_steps = whole_steps(&key("tau"), tau, h)?;
            if tau_steps > total_steps {
                return Err(SpecError::new(
                    key("tau"),
                    format!(
                        "{tau} is longer than the run (t_final = {t_final}): it would never be \
                         sampled"
                    ),
                ));
            }
            let orthonormalize =
                Orthonormalization::from_name(&s.orthonormalize).ok_or_else(|| {
                    SpecError::new(
                        key("orthonormalize"),
                        format!("'{}' is not rescale or qr", s.orthonormalize),
                    )
                })?;
            let route = route_from_config(&key("route"), s.route.as_deref())?;
            if route == Route::WindowPropagator {
                if method != Method::Vm {
                    return Err(SpecError::new(
                        key("route"),
                        "the propagator route of a run (the window's tangent propagator) is for \
                         vm schemes (a map's basis route also takes mpm: [map] route)",
                    ));
                }
                // It integrates 2N tangent vectors where the per-set route integrates sets x k,
                // and applies a 2N x 2N matrix to each set's vectors: no gain otherwise.
                let per_set = sets * dev.k;
                if dim >= per_set {
                    return Err(SpecError::new(
                        key("route"),
                        format!(
                            "the propagator integrates 2N = {dim} tangent vectors, the per-set \
                             route sets x k = {per_set}: use \"per-set\""
                        ),
                    ));
                }
            }
            schemes.push(SchemeSpec {
                name: s.name.clone(),
                method,
                d0,
                tau,
                tau_steps,
                orthonormalize,
                route,
            });
        }

        let sample_every_steps = match cfg.run.sample_every {
            None => None,
            Some(every) => {
                let key = "run.sample_every";
                let every = finite_positive(key, every)?;
                let steps = whole_steps(key, every, h)?;
                if let Some(s) = schemes.iter().find(|s| !steps.is_multiple_of(s.tau_steps)) {
                    return Err(SpecError::new(
                        key,
                        format!(
                            "{} is not a multiple of scheme '{}''s tau = {}: a sample is taken \
                             where every scheme renormalizes",
                            num(every),
                            s.name,
                            num(s.tau)
                        ),
                    ));
                }
                let shortest = schemes.iter().map(|s| s.tau_steps).min().unwrap_or(steps);
                let values = (steps / shortest - 1).saturating_mul(dev.k as u64);
                if values > MAX_EARLIER_STRETCH {
                    return Err(SpecError::new(
                        key,
                        format!(
                            "{} carries {} renormalizations' stretching factors of k = {} \
                             vectors to each sample ({values} values, limit \
                             {MAX_EARLIER_STRETCH}): sample more often or renormalize less \
                             often",
                            num(every),
                            steps / shortest - 1,
                            dev.k
                        ),
                    ));
                }
                Some(steps)
            }
        };

        Ok(RunSpec {
            system,
            h,
            total_steps,
            x0,
            e0,
            dim,
            k: dev.k,
            directions,
            schemes,
            seed: dev.seed,
            tables,
            sample_every_steps,
            periods,
        })
    }

    /// `cfg` (the config this run was validated from) with the digest of every table it read
    /// filled in: what recordings and map files carry, so a replay or a resume elsewhere
    /// refuses a table that differs.
    pub fn pinned_config(&self, cfg: &RunConfig) -> RunConfig {
        let mut pinned = cfg.clone();
        pinned.model = pin_tables(&cfg.model, &self.tables);
        pinned
    }

    /// What the engine steps: the model with its integrator and time step.
    pub fn system(&self) -> &Arc<dyn DynamicalSystem> {
        &self.system
    }

    /// Time step (1 for maps: a step is an iteration).
    /// The period of each coordinate of the state (`[model] modulo`, `0`: none); empty when
    /// the model declares none.
    pub fn periods(&self) -> &[f64] {
        &self.periods
    }

    pub fn h(&self) -> f64 {
        self.h
    }

    pub fn total_steps(&self) -> u64 {
        self.total_steps
    }

    /// `[run] sample_every` in steps (`None`: a sample at every renormalization).
    pub fn sample_every_steps(&self) -> Option<u64> {
        self.sample_every_steps
    }

    /// Whether the engine emits a sample at `step` (a renormalization of some scheme): at
    /// every one, or at the multiples of `sample_every` and the end.
    pub fn is_sample_step(&self, step: u64) -> bool {
        step == self.total_steps
            || self
                .sample_every_steps
                .is_none_or(|every| step.is_multiple_of(every))
    }

    /// Most renormalizations of one scheme between two samples (the stretching factors a
    /// sample carries besides its own, per vector): 0 without `sample_every`.
    pub fn most_earlier_renormalizations(&self) -> u64 {
        let Some(every) = self.sample_every_steps else {
            return 0;
        };
        self.schemes
            .iter()
            .map(|s| every / s.tau_steps - 1)
            .max()
            .unwrap_or(0)
    }

    /// Initial reference state: `(q, p)` of a Hamiltonian, `x` of any other system.
    pub fn x0(&self) -> &[f64] {
        &self.x0
    }

    /// The invariant of `x0` (a Hamiltonian's energy); 0 for systems without one.
    pub fn e0(&self) -> f64 {
        self.e0
    }

    /// Dimension `D` of the state (`2N` for a Hamiltonian).
    pub fn dim(&self) -> usize {
        self.dim
    }

    /// Deviation vectors per set.
    pub fn k(&self) -> usize {
        self.k
    }

    /// Initial directions, one entry per set, shared by every scheme (random ones are drawn on
    /// the first call).
    pub fn directions(&self) -> &[Directions] {
        self.directions.get()
    }

    pub fn schemes(&self) -> &[SchemeSpec] {
        &self.schemes
    }

    /// Seed of the random directions.
    pub fn seed(&self) -> u64 {
        self.seed
    }

    /// The tables the model read, with their digests (see [`RunSpec::pinned_config`]).
    pub fn tables(&self) -> &[TableDigest] {
        &self.tables
    }

    /// The same run from another initial state `x0` (a point of a phase-space map: the grid
    /// overwrites coordinates of the validated base state), with its invariant.
    pub(crate) fn starting_at(&self, x0: &[f64]) -> RunSpec {
        let mut run = self.clone();
        run.x0 = x0.to_vec();
        run.e0 = run.system.invariant(x0).unwrap_or(0.0);
        run
    }

    /// The same run cut to its first `steps` steps (at least one, at most the run's own): what
    /// the estimate's calibration times ([`crate::estimate`]).
    pub(crate) fn truncated(&self, steps: u64) -> RunSpec {
        let mut run = self.clone();
        run.total_steps = steps.clamp(1, self.total_steps.max(1));
        run
    }

    /// Number of direction sets.
    pub fn sets(&self) -> usize {
        self.directions.sets()
    }

    /// Time of step `step` (computed, never accumulated, so it carries no drift).
    pub fn time_of(&self, step: u64) -> f64 {
        step as f64 * self.h
    }

    pub fn t_final(&self) -> f64 {
        self.time_of(self.total_steps)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_expression_error_keeps_its_caret_lines_and_a_quoted_newline_is_escaped() {
        // An expression error: the first line says it all, the source line and the caret
        // follow on real, indented lines (what a terminal needs to show the caret).
        let e = SpecError::new(
            "model.rhs",
            "rhs[1]: line 1, column 4: unexpected '*'\n  x1 +* x2\n     ^",
        );
        assert_eq!(
            e.to_string(),
            "model.rhs: rhs[1]: line 1, column 4: unexpected '*'\n  x1 +* x2\n     ^"
        );
        // A newline in a name quoted back does not start a line of its own.
        let e = SpecError::new("model.name", "unknown model 'a\nchaoscope: fine'");
        assert_eq!(
            e.to_string(),
            "model.name: unknown model 'a\\nchaoscope: fine'"
        );
        // Nor inside the indented context: its other control characters are escaped too.
        let e = SpecError::new("model.rhs", "bad\n  x\u{1b}[2J\n  ^");
        assert!(!e.to_string().contains('\u{1b}'), "{e}");
        assert_eq!(e.to_string().lines().count(), 3);
    }

    use chaoscope_schemas::config::{DeviationsConfig, SchemeConfig, paper};

    /// The paper's chaotic Henon-Heiles orbit up to t = 10 with one VM scheme.
    fn hh_config() -> RunConfig {
        paper::henon_heiles(
            paper::HH_CHAOTIC_Q2,
            10.0,
            DeviationsConfig::random(4, 2, 1),
            vec![SchemeConfig::new("vm", "vm", 1e-8, 1.0)],
        )
    }

    fn spec(text: &str) -> Result<RunSpec, SpecError> {
        RunSpec::from_config(&RunConfig::from_toml(text).unwrap())
    }

    #[test]
    fn paper_hh_chaotic_initial_condition() {
        let s = RunSpec::from_config(&hh_config()).unwrap();
        // numerics.md: p1 = 0.42081270576508656.
        assert!((s.x0[2] - 0.42081270576508656).abs() < 1e-16, "{}", s.x0[2]);
        // t_final = 10 and tau = 1 in steps of h = 0.01.
        assert_eq!(s.total_steps, 1000);
        assert_eq!(s.schemes[0].tau_steps, 100);
    }

    #[test]
    fn impossible_energy_is_a_clear_error() {
        let mut config = hh_config();
        config.orbit.q = vec![0.0, 0.9];
        let e = RunSpec::from_config(&config).unwrap_err();
        assert_eq!(e.key, "orbit.energy");
        assert!(e.message.contains("no real p1"), "{e}");
    }

    /// The Henon map up to 10 iterations, with `h_line` in `[integrator]`.
    fn henon_map(h_line: &str) -> String {
        format!(
            "[model]\nname = \"map\"\nnext = [\"1 - a*x1^2 + x2\", \"b*x1\"]\n\
             params = {{ a = 1.4, b = 0.3 }}\n[orbit]\nx = [0.0, 0.0]\n\
             [integrator]\n{h_line}\nt_final = 10\n\
             [deviations]\nk = 2\nsets = 1\nseed = 1\n\
             [[scheme]]\nname = \"vm\"\nmethod = \"vm\"\nd0 = 1e-8\ntau = 1\n\
             orthonormalize = \"qr\"\n"
        )
    }

    #[test]
    fn a_map_may_leave_h_out_and_refuses_any_h_but_one() {
        // Time counts iterations: h is 1 whether written or left out.
        for h_line in ["", "h = 1", "h = 1.0"] {
            let s = spec(&henon_map(h_line)).unwrap();
            assert_eq!(s.h().to_bits(), 1.0f64.to_bits(), "{h_line:?}");
            assert_eq!(s.total_steps, 10, "{h_line:?}");
        }
        for (h_line, got) in [("h = 0.5", "got 0.5"), ("h = 2", "got 2")] {
            let e = spec(&henon_map(h_line)).unwrap_err();
            assert_eq!(e.key, "integrator.h", "{e}");
            assert!(e.message.contains(got), "{e}");
            assert_eq!(e.to_string().lines().count(), 1, "{e}");
        }
    }

    #[test]
    fn a_hamiltonian_or_flow_still_needs_h() {
        let mut config = hh_config();
        config.integrator.h = None;
        let e = RunSpec::from_config(&config).unwrap_err();
        assert_eq!(e.key, "integrator.h");
        assert!(e.message.contains("missing"), "{e}");
    }

    #[test]
    fn solve_for_needs_no_placeholder_momentum() {
        // The paper's orbit writes p = [0, 0], p1 solved from the energy; leaving p out gives
        // the same state bit for bit (the other momenta are 0).
        let mut config = hh_config();
        assert_eq!(config.orbit.p, [0.0, 0.0]);
        let with_p = RunSpec::from_config(&config).unwrap().x0.clone();
        config.orbit.p.clear();
        let without_p = RunSpec::from_config(&config).unwrap().x0.clone();
        let bits = |x: &[f64]| x.iter().map(|v| v.to_bits()).collect::<Vec<_>>();
        assert_eq!(bits(&with_p), bits(&without_p));
        // A p of the wrong length is still an error, with the hint.
        config.orbit.p = vec![0.0];
        let e = RunSpec::from_config(&config).unwrap_err();
        assert_eq!(e.key, "orbit.p");
        assert!(e.message.contains("leave p out"), "{e}");
        // Without solve_for, p stays required.
        config.orbit.p.clear();
        config.orbit.solve_for = None;
        config.orbit.energy = None;
        assert_eq!(RunSpec::from_config(&config).unwrap_err().key, "orbit.p");
    }

    #[test]
    fn bad_values_name_their_key() {
        // Each case spoils one value of a valid config.
        type Spoil = fn(&mut RunConfig);
        let cases: [(Spoil, &str); 9] = [
            (|c| c.integrator.h = Some(-1.0), "integrator.h"),
            (|c| c.schemes[0].tau = 0.015, "scheme[0].tau"),
            (|c| c.deviations.k = 5, "deviations.k"),
            (|c| c.schemes[0].d0 = f64::NAN, "scheme[0].d0"),
            (|c| c.integrator.method = "rk4".into(), "integrator.method"),
            (|c| c.schemes[0].method = "xm".into(), "scheme[0].method"),
            (
                |c| c.schemes.push(SchemeConfig::new("vm", "mpm", 1e-8, 1.0)),
                "scheme[1].name",
            ),
            (|c| c.orbit.solve_for = Some("q1".into()), "orbit.solve_for"),
            (|c| c.integrator.t_final = 10.005, "integrator.t_final"),
        ];
        for (spoil, key) in cases {
            let mut config = hh_config();
            spoil(&mut config);
            let e = RunSpec::from_config(&config).unwrap_err();
            assert_eq!(e.key, key, "{e}");
        }
    }

    #[test]
    fn fput_spo1_preset_and_explicit_vectors() {
        let text = r#"
[model]
name = "fput-beta"
n = 5
beta = 1.0
[orbit]
preset = "spo1"
energy = 5.0
[integrator]
method = "aba864"
h = 0.05
t_final = 1.0
[deviations]
k = 2
vectors = [[1,0,0,0,0,0,0,0,0,0],[1,1,0,0,0,0,0,0,0,0]]
[[scheme]]
name = "m"
method = "mpm"
d0 = 1e-8
tau = 0.5
"#;
        let s = spec(text).unwrap();
        assert!((s.e0 - 5.0).abs() < 1e-13);
        assert_eq!(s.directions().len(), 1);
        assert!((s.directions()[0].vector(1)[1] - 1.0).abs() < 1e-15);
    }
}
