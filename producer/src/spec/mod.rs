//! A validated run: the numerics' view of a [`RunConfig`].
//!
//! Everything a user can write is checked here, once, with an error that names the key and the
//! problem; past this point the engine only meets consistent input.

use std::sync::Arc;

use chaoscope_schemas::config::{OrbitConfig, RunConfig};
use chaoscope_schemas::run::{
    MAX_SCHEMES, MAX_SETS, MAX_STATE_VALUES, Method, Orthonormalization, Route, SchemeSpec,
    deviation_state_values,
};

use crate::deviation::{self, DirectionError, Directions};
use crate::integrator::runge_kutta::{RungeKutta, RungeKuttaKind, Tolerances};
use crate::integrator::{Splitting, SplittingKind};
use crate::model::{FputBeta, HenonHeiles, Model};
use crate::system::{DynamicalSystem, Map, RkFlow, SplitHamiltonian, Time};

mod potential;
pub mod vector;

pub use potential::{TableDigest, pin_tables};

/// The route a configuration names at `key` (absent: per-set).
pub fn route_from_config(key: &str, value: Option<&str>) -> Result<Route, SpecError> {
    match value {
        None => Ok(Route::PerSet),
        Some(name) => Route::from_name(name)
            .ok_or_else(|| SpecError::new(key, format!("'{name}' is not per-set or propagator"))),
    }
}

/// A problem with the configuration, naming the key.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{key}: {message}")]
pub struct SpecError {
    pub key: String,
    pub message: String,
}

impl SpecError {
    /// The message is kept on one line: control characters (a newline in a name the message
    /// quotes back) are written as escapes.
    pub fn new(key: impl Into<String>, message: impl Into<String>) -> Self {
        let message: String = message.into();
        let message = if message.chars().any(char::is_control) {
            message
                .chars()
                .flat_map(|c| {
                    let escaped: Vec<char> = if c.is_control() {
                        c.escape_default().collect()
                    } else {
                        vec![c]
                    };
                    escaped
                })
                .collect()
        } else {
            message
        };
        Self {
            key: key.into(),
            message,
        }
    }
}

/// Longest run accepted, in steps: beyond this `step * h` loses integer exactness in f64.
const MAX_STEPS: u64 = 1 << 52;

/// The parts of a separable Hamiltonian run, for what is specific to it (energy surfaces, the
/// batched splitting kernel of maps, sections).
#[derive(Clone)]
pub struct HamiltonianParts {
    pub model: Arc<dyn Model>,
    pub splitting: Splitting,
}

/// A validated run.
#[derive(Clone)]
pub struct RunSpec {
    /// What the engine steps: the model with its integrator and time step.
    pub system: Arc<dyn DynamicalSystem>,
    /// `Some` for separable Hamiltonians (`SplitHamiltonian`), `None` for every other kind.
    pub hamiltonian: Option<HamiltonianParts>,
    /// Time step (1 for maps: a step is an iteration).
    pub h: f64,
    pub total_steps: u64,
    /// Initial reference state: `(q, p)` of a Hamiltonian, `x` of any other system.
    pub x0: Vec<f64>,
    /// The invariant of `x0` (a Hamiltonian's energy); 0 for systems without one.
    pub e0: f64,
    /// Dimension `D` of the state (`2N` for a Hamiltonian).
    pub dim: usize,
    /// Deviation vectors per set.
    pub k: usize,
    /// Initial directions, one entry per set, shared by every scheme.
    pub directions: Vec<Directions>,
    pub schemes: Vec<SchemeSpec>,
    pub seed: u64,
    /// The tables the model read, with their digests (see [`RunSpec::pinned_config`]).
    pub tables: Vec<TableDigest>,
}

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
            .field("sets", &self.directions.len())
            .field("schemes", &self.schemes)
            .finish()
    }
}

fn finite_positive(key: &str, v: f64) -> Result<f64, SpecError> {
    if v.is_finite() && v > 0.0 {
        Ok(v)
    } else {
        Err(SpecError::new(
            key,
            format!("must be a finite positive number, got {}", num(v)),
        ))
    }
}

/// A number as the user would write it: `1e-300` rather than three hundred zeros.
fn num(v: f64) -> String {
    let plain = format!("{v}");
    let sci = format!("{v:e}");
    if plain.len() <= sci.len() { plain } else { sci }
}

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

/// Most particles of the built-in FPUT chain.
const MAX_FPUT_SITES: usize = 1_000_000;

/// Degrees of freedom of the model a config names, without building it (`None` when the config
/// does not say; validation then names the problem).
pub fn model_dof(cfg: &chaoscope_schemas::config::ModelConfig) -> Option<usize> {
    match cfg.name.as_str() {
        "henon-heiles" => Some(2),
        "fput-beta" => cfg.n.filter(|&n| (1..=MAX_FPUT_SITES).contains(&n)),
        "potential" => cfg.n.filter(|&n| (1..=potential::MAX_SITES).contains(&n)),
        _ => None,
    }
}

/// Dimension `D` of the state of the system a config names, without building it (`None` when
/// the config does not say; validation then names the problem).
pub fn state_dim(cfg: &chaoscope_schemas::config::ModelConfig) -> Option<usize> {
    match SystemFamily::of(&cfg.name)? {
        SystemFamily::Hamiltonian => model_dof(cfg).map(|n| 2 * n),
        SystemFamily::Flow => cfg.rhs.as_ref().map(Vec::len),
        SystemFamily::Map => cfg.next.as_ref().map(Vec::len),
        SystemFamily::GeneralHamiltonian => cfg
            .n
            .filter(|&n| (1..=chaoscope_expr::vector::MAX_DIM / 2).contains(&n))
            .map(|n| 2 * n),
    }
}

/// The families of `[model] name`: the one place names are dispatched to kinds of system.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum SystemFamily {
    /// A separable Hamiltonian with a splitting: the built-in models and `potential`.
    Hamiltonian,
    /// `ode`: `dx/dt = f(x)` with a Runge-Kutta method (`system::RkFlow`).
    Flow,
    /// `map`: `x -> F(x)` (`system::Map`).
    Map,
    /// `hamiltonian`: any `H(q, p)`, its vector field integrated by a Runge-Kutta method
    /// (`system::RkFlow`), the symplectic Gauss-Legendre ones among them.
    GeneralHamiltonian,
}

/// Every `[model] name`, as error messages list them.
const KNOWN_MODELS: &str = "henon-heiles, fput-beta, potential, hamiltonian, ode, map";

impl SystemFamily {
    fn of(name: &str) -> Option<Self> {
        match name {
            "henon-heiles" | "fput-beta" | "potential" => Some(Self::Hamiltonian),
            "ode" => Some(Self::Flow),
            "map" => Some(Self::Map),
            "hamiltonian" => Some(Self::GeneralHamiltonian),
            _ => None,
        }
    }

    /// The `[model]` keys this family reads besides `name`; any other key given is a mistake
    /// worth naming (a `potential` under `ode`, an `rhs` under `map`).
    fn keys(self) -> &'static [&'static str] {
        match self {
            Self::Hamiltonian => &[
                "n",
                "beta",
                "potential",
                "params",
                "masses",
                "boundary",
                "tables",
            ],
            Self::Flow => &["rhs", "params", "boundary"],
            Self::Map => &["next", "params", "boundary", "modulo"],
            Self::GeneralHamiltonian => &["n", "hamiltonian", "params", "boundary"],
        }
    }
}

/// The `[model]` keys that are set, by name.
fn model_keys_present(cfg: &chaoscope_schemas::config::ModelConfig) -> [(&'static str, bool); 11] {
    [
        ("n", cfg.n.is_some()),
        ("beta", cfg.beta.is_some()),
        ("potential", cfg.potential.is_some()),
        ("params", !cfg.params.is_empty()),
        ("masses", cfg.masses.is_some()),
        ("boundary", cfg.boundary.is_some()),
        ("tables", !cfg.tables.is_empty()),
        ("rhs", cfg.rhs.is_some()),
        ("next", cfg.next.is_some()),
        ("modulo", cfg.modulo.is_some()),
        ("hamiltonian", cfg.hamiltonian.is_some()),
    ]
}

/// A `[model]` key that the named family does not read.
fn foreign_model_key(
    cfg: &chaoscope_schemas::config::ModelConfig,
    family: SystemFamily,
) -> Result<(), SpecError> {
    let used = family.keys();
    match model_keys_present(cfg)
        .into_iter()
        .find(|(k, present)| *present && !used.contains(k))
    {
        Some((key, _)) => Err(SpecError::new(
            format!("model.{key}"),
            format!(
                "does not apply to name = \"{}\" (its keys: {})",
                cfg.name,
                used.join(", ")
            ),
        )),
        None => Ok(()),
    }
}

/// Build the model named in the config, with the digests of the tables it read.
pub fn model_from_config(
    cfg: &chaoscope_schemas::config::ModelConfig,
) -> Result<(Arc<dyn Model>, Vec<TableDigest>), SpecError> {
    let builtin = |model: Arc<dyn Model>| {
        if let Some(key) = builtin_extra_key(cfg) {
            return Err(SpecError::new(
                format!("model.{key}"),
                format!(
                    "applies to name = \"potential\", not to the built-in '{}'",
                    cfg.name
                ),
            ));
        }
        Ok((model, Vec::new()))
    };
    match cfg.name.as_str() {
        "henon-heiles" => {
            if let Some(n) = cfg.n.filter(|&n| n != 2) {
                return Err(SpecError::new(
                    "model.n",
                    format!("henon-heiles has 2 degrees of freedom, got n = {n}"),
                ));
            }
            if cfg.beta.is_some() {
                return Err(SpecError::new(
                    "model.beta",
                    "henon-heiles has no parameter beta",
                ));
            }
            builtin(Arc::new(HenonHeiles))
        }
        "fput-beta" => {
            let n = cfg.n.ok_or_else(|| {
                SpecError::new("model.n", "fput-beta needs the number of particles n")
            })?;
            if n == 0 || n > MAX_FPUT_SITES {
                return Err(SpecError::new(
                    "model.n",
                    format!("must be between 1 and 1000000, got {n}"),
                ));
            }
            let beta = cfg.beta.unwrap_or(1.0);
            builtin(
                FputBeta::new(n, beta)
                    .map(|m| Arc::new(m) as Arc<dyn Model>)
                    .map_err(|e| SpecError::new("model.beta", e))?,
            )
        }
        "potential" => potential::potential_model(cfg),
        other => Err(SpecError::new(
            "model.name",
            match SystemFamily::of(other) {
                Some(_) => format!("'{other}' is not a separable Hamiltonian model"),
                None => format!("unknown model '{other}' (known: {KNOWN_MODELS})"),
            },
        )),
    }
}

/// A key of the `potential` model given to a built-in one (a likely mix-up worth naming).
fn builtin_extra_key(cfg: &chaoscope_schemas::config::ModelConfig) -> Option<&'static str> {
    model_keys_present(cfg)
        .into_iter()
        .find_map(|(k, present)| (present && !matches!(k, "n" | "beta")).then_some(k))
}

/// Parse a coordinate name `q3` / `p1` into (is_momentum, zero-based index) for `n` dof.
pub fn parse_coordinate(name: &str, n: usize) -> Option<(bool, usize)> {
    let (momentum, digits) = match name.as_bytes().first()? {
        b'q' | b'x' => (false, &name[1..]),
        b'p' => (true, &name[1..]),
        _ => return None,
    };
    let i: usize = digits.parse().ok()?;
    // `then`, not `then_some`: `i - 1` must not be evaluated for `p0` (it would overflow).
    (1..=n).contains(&i).then(|| (momentum, i - 1))
}

/// Parse a coordinate name `x3` of a `dim`-dimensional state into its zero-based index.
pub fn state_coordinate(name: &str, dim: usize) -> Option<usize> {
    let i: usize = name.strip_prefix('x')?.parse().ok()?;
    (1..=dim).contains(&i).then(|| i - 1)
}

/// Solve momentum `p_j` (positive root) so that `H(q, p) = energy`.
pub fn solve_momentum(
    model: &dyn Model,
    x: &mut [f64],
    j: usize,
    energy: f64,
) -> Result<(), SpecError> {
    let n = model.dof();
    x[n + j] = 0.0;
    let rest = model.energy(x);
    let twice_kinetic = 2.0 * (energy - rest);
    if !twice_kinetic.is_finite() || twice_kinetic < 0.0 {
        return Err(SpecError::new(
            "orbit.energy",
            format!(
                "no real p{} exists: the other coordinates already have energy {rest} > {energy} \
                 (the initial condition lies outside the energy surface)",
                j + 1
            ),
        ));
    }
    // p_j^2 / (2 m_j) = E - rest; with unit masses exactly the mass-free formula.
    x[n + j] = match model.inverse_masses() {
        None => twice_kinetic.sqrt(),
        Some(w) => (twice_kinetic / w[j]).sqrt(),
    };
    Ok(())
}

/// Initial state from the `[orbit]` section.
pub fn initial_state(model: &dyn Model, orbit: &OrbitConfig) -> Result<Vec<f64>, SpecError> {
    let n = model.dof();
    let mut x = vec![0.0; 2 * n];
    if let Some(preset) = &orbit.preset {
        let e = orbit.energy.ok_or_else(|| {
            SpecError::new("orbit.energy", format!("preset {preset} needs an energy"))
        })?;
        x = model
            .preset(preset, e)
            .ok_or_else(|| {
                SpecError::new(
                    "orbit.preset",
                    format!("model {} has no preset '{preset}'", model.name()),
                )
            })?
            .map_err(|m| SpecError::new("orbit.preset", m))?;
        if !orbit.q.is_empty() || !orbit.p.is_empty() || orbit.solve_for.is_some() {
            return Err(SpecError::new(
                "orbit",
                "give either a preset or q/p/solve_for, not both",
            ));
        }
        return Ok(x);
    }
    if orbit.q.len() != n {
        return Err(SpecError::new(
            "orbit.q",
            format!("needs {n} positions, got {}", orbit.q.len()),
        ));
    }
    if orbit.p.len() != n {
        return Err(SpecError::new(
            "orbit.p",
            format!("needs {n} momenta, got {}", orbit.p.len()),
        ));
    }
    x[..n].copy_from_slice(&orbit.q);
    x[n..].copy_from_slice(&orbit.p);
    if let Some(i) = x.iter().position(|v| !v.is_finite()) {
        let key = if i < n { "orbit.q" } else { "orbit.p" };
        return Err(SpecError::new(
            key,
            format!("entry {} is not finite", i % n + 1),
        ));
    }
    match (&orbit.solve_for, orbit.energy) {
        (Some(name), Some(e)) => {
            if !e.is_finite() {
                return Err(SpecError::new(
                    "orbit.energy",
                    format!("must be finite, got {e}"),
                ));
            }
            match parse_coordinate(name, n) {
                Some((true, j)) => solve_momentum(model, &mut x, j, e)?,
                _ => {
                    return Err(SpecError::new(
                        "orbit.solve_for",
                        format!("must name a momentum p1..p{n}, got '{name}'"),
                    ));
                }
            }
        }
        (Some(_), None) => return Err(SpecError::new("orbit.solve_for", "needs orbit.energy")),
        (None, Some(_)) => {
            return Err(SpecError::new(
                "orbit.energy",
                "needs orbit.solve_for (which momentum to solve) or a preset",
            ));
        }
        (None, None) => {}
    }
    if !model.energy(&x).is_finite() {
        return Err(SpecError::new("orbit", "the initial energy is not finite"));
    }
    Ok(x)
}

/// `[model] name = "ode"`: the compiled right-hand side with the Runge-Kutta method of
/// `[integrator]`, fixed step `h`, or adaptive `dop853` landing on the grid of `h` when `rtol`
/// and `atol` are given.
fn flow_from_config(cfg: &RunConfig) -> Result<Arc<dyn DynamicalSystem>, SpecError> {
    let model = &cfg.model;
    let rhs = model.rhs.as_ref().ok_or_else(|| {
        SpecError::new(
            "model.rhs",
            "ode needs the right-hand side, e.g. rhs = [\"sigma * (x2 - x1)\", ...]",
        )
    })?;
    let field = vector::vector_function("rhs", rhs, &model.params, model.boundary.as_deref())?;
    runge_kutta_system(cfg, Arc::new(field))
}

/// `[model] name = "hamiltonian"`: the vector field of `H(q, p)` (derivatives taken
/// symbolically) with a Runge-Kutta method; `gl4` and `gl6` are symplectic.
fn general_hamiltonian_from_config(cfg: &RunConfig) -> Result<Arc<dyn DynamicalSystem>, SpecError> {
    let model = &cfg.model;
    let source = model.hamiltonian.as_ref().ok_or_else(|| {
        SpecError::new(
            "model.hamiltonian",
            "needs H(q, p), e.g. hamiltonian = \"(p1^2 + p2^2)/2 + (q1^2 + q2^2)/2\"",
        )
    })?;
    let max = chaoscope_expr::vector::MAX_DIM / 2;
    let n = model
        .n
        .ok_or_else(|| SpecError::new("model.n", "needs the number of degrees of freedom n"))?;
    if n == 0 || n > max {
        return Err(SpecError::new(
            "model.n",
            format!("must be between 1 and {max}, got {n}"),
        ));
    }
    let field = vector::hamiltonian_function(source, n, &model.params, model.boundary.as_deref())?;
    runge_kutta_system(cfg, Arc::new(field))
}

/// `[orbit] q` and `p` (or `x`) of a Hamiltonian given as an expression, as the state `x =
/// (q, p)`.
fn state_of_q_and_p(orbit: &OrbitConfig, n: usize) -> Result<OrbitConfig, SpecError> {
    for (key, present) in [
        ("orbit.energy", orbit.energy.is_some()),
        ("orbit.solve_for", orbit.solve_for.is_some()),
        ("orbit.preset", orbit.preset.is_some()),
    ] {
        if present {
            return Err(SpecError::new(
                key,
                "solving the energy for a momentum and presets are offered for separable \
                 Hamiltonians; give q and p",
            ));
        }
    }
    let x = match (orbit.q.is_empty() && orbit.p.is_empty(), orbit.x.is_empty()) {
        (false, true) => {
            for (key, v) in [("orbit.q", &orbit.q), ("orbit.p", &orbit.p)] {
                if v.len() != n {
                    return Err(SpecError::new(
                        key,
                        format!(
                            "needs {n} values (one per degree of freedom), got {}",
                            v.len()
                        ),
                    ));
                }
            }
            orbit.q.iter().chain(&orbit.p).copied().collect()
        }
        (true, false) => orbit.x.clone(),
        (false, false) => {
            return Err(SpecError::new(
                "orbit.x",
                "give either q and p or x = [q1..qN, p1..pN], not both",
            ));
        }
        (true, true) => {
            return Err(SpecError::new(
                "orbit.q",
                "needs q and p (the initial state)",
            ));
        }
    };
    Ok(OrbitConfig {
        x,
        ..OrbitConfig::default()
    })
}

/// A vector field with the Runge-Kutta method of `[integrator]`: fixed step `h`, or adaptive
/// `dop853` landing on the grid of `h` when `rtol` and `atol` are given.
fn runge_kutta_system(
    cfg: &RunConfig,
    field: Arc<dyn crate::vector_field::VectorField>,
) -> Result<Arc<dyn DynamicalSystem>, SpecError> {
    let model = &cfg.model;
    let integrator = &cfg.integrator;
    let kind = RungeKuttaKind::from_name(&integrator.method).ok_or_else(|| {
        SpecError::new(
            "integrator.method",
            format!(
                "unknown method '{}' for a flow (known: rk4, dop853, gl4, gl6)",
                integrator.method
            ),
        )
    })?;
    let h = finite_positive("integrator.h", integrator.h)?;
    let tolerances = match (integrator.rtol, integrator.atol) {
        (None, None) => None,
        (Some(rtol), Some(atol)) => {
            if kind != RungeKuttaKind::Dop853 {
                return Err(SpecError::new(
                    "integrator.rtol",
                    format!("error control is offered by dop853, not {}", kind.name()),
                ));
            }
            for (key, v) in [("integrator.rtol", rtol), ("integrator.atol", atol)] {
                if !(v.is_finite() && v >= 0.0) {
                    return Err(SpecError::new(
                        key,
                        format!("must be finite and >= 0, got {}", num(v)),
                    ));
                }
            }
            if rtol == 0.0 && atol == 0.0 {
                return Err(SpecError::new(
                    "integrator.rtol",
                    "rtol and atol cannot both be 0 (no step would ever be accepted)",
                ));
            }
            // Below about 100 eps relative the controller chases rounding and shrinks the step
            // without end.
            if rtol > 0.0 && rtol < 100.0 * f64::EPSILON {
                return Err(SpecError::new(
                    "integrator.rtol",
                    format!(
                        "{} is below what double precision resolves (use >= 2.3e-14)",
                        num(rtol)
                    ),
                ));
            }
            Some(Tolerances { rtol, atol })
        }
        (Some(_), None) => {
            return Err(SpecError::new("integrator.atol", "rtol needs atol as well"));
        }
        (None, Some(_)) => {
            return Err(SpecError::new("integrator.rtol", "atol needs rtol as well"));
        }
    };
    Ok(Arc::new(RkFlow {
        name: model.name.clone(),
        field,
        method: RungeKutta::new(kind),
        h,
        tolerances,
    }))
}

/// `[model] name = "map"`: the compiled map with its periods. Time counts iterations: `h` is 1,
/// `t_final` and every `tau` are whole numbers of iterations.
fn map_from_config(cfg: &RunConfig) -> Result<Arc<dyn DynamicalSystem>, SpecError> {
    let model = &cfg.model;
    let next = model.next.as_ref().ok_or_else(|| {
        SpecError::new(
            "model.next",
            "map needs the image of every coordinate, e.g. next = [\"1 - a * x1^2 + x2\", \"b * x1\"]",
        )
    })?;
    let function = vector::vector_function("next", next, &model.params, model.boundary.as_deref())?;
    let integrator = &cfg.integrator;
    if !integrator.method.is_empty() && integrator.method != "iterate" {
        return Err(SpecError::new(
            "integrator.method",
            format!(
                "a map is iterated: method = \"iterate\" (or leave it out), got '{}'",
                integrator.method
            ),
        ));
    }
    if integrator.h.to_bits() != 1.0f64.to_bits() {
        return Err(SpecError::new(
            "integrator.h",
            format!(
                "a map's time counts iterations: h = 1, got {}",
                num(integrator.h)
            ),
        ));
    }
    for (key, present) in [
        ("integrator.rtol", integrator.rtol.is_some()),
        ("integrator.atol", integrator.atol.is_some()),
    ] {
        if present {
            return Err(SpecError::new(key, "a map has no step size to control"));
        }
    }
    let modulo = model.modulo.clone().unwrap_or_default();
    let map = Map::new(function, modulo).map_err(|e| SpecError::new("model.modulo", e))?;
    Ok(Arc::new(map))
}

impl RunSpec {
    /// Validate a configuration into a run.
    pub fn from_config(cfg: &RunConfig) -> Result<Self, SpecError> {
        // `[[sweep]]` ranges are shorthand for schemes: expand them before anything is checked.
        let expanded = cfg
            .with_sweeps_expanded()
            .map_err(|e| SpecError::new(e.key, e.message))?;
        let model = &expanded.model;
        let family = SystemFamily::of(&model.name);
        if let Some(family) = family {
            foreign_model_key(model, family)?;
        }
        match family {
            // An unknown name is reported by the Hamiltonian dispatch, with the list of all.
            Some(SystemFamily::Hamiltonian) | None => {
                let (model, tables) = model_from_config(model)?;
                Self::build(&expanded, model, tables)
            }
            Some(SystemFamily::Flow) => {
                let system = flow_from_config(&expanded)?;
                Self::build_general(&expanded, system, Vec::new())
            }
            Some(SystemFamily::Map) => {
                let system = map_from_config(&expanded)?;
                Self::build_general(&expanded, system, Vec::new())
            }
            Some(SystemFamily::GeneralHamiltonian) => {
                let system = general_hamiltonian_from_config(&expanded)?;
                // The initial state is q and p, as for every Hamiltonian; inside, x = (q, p).
                let mut with_x = expanded.clone();
                with_x.orbit = state_of_q_and_p(&expanded.orbit, system.dim() / 2)?;
                Self::build_general(&with_x, system, Vec::new())
            }
        }
    }

    /// A run of a system built in code (any [`DynamicalSystem`]: a flow, a map, ...): `[orbit]
    /// x` is its initial state, `[integrator] h` and `t_final` its time grid (`h` must be the
    /// system's own step), everything else is validated as usual; `cfg.model.name` is the name
    /// recordings carry.
    pub fn with_system(
        cfg: &RunConfig,
        system: Arc<dyn DynamicalSystem>,
    ) -> Result<Self, SpecError> {
        let expanded = cfg
            .with_sweeps_expanded()
            .map_err(|e| SpecError::new(e.key, e.message))?;
        Self::build_general(&expanded, system, Vec::new())
    }

    /// A run of a model built in code rather than named in the config (the library route for
    /// hand-written models, `examples/custom-model/`): everything but `[model]` is validated as
    /// usual; `cfg.model.name` is the name recordings carry.
    pub fn with_model(cfg: &RunConfig, model: Arc<dyn Model>) -> Result<Self, SpecError> {
        let expanded = cfg
            .with_sweeps_expanded()
            .map_err(|e| SpecError::new(e.key, e.message))?;
        Self::build(&expanded, model, Vec::new())
    }

    /// A separable Hamiltonian with a splitting.
    fn build(
        cfg: &RunConfig,
        model: Arc<dyn Model>,
        tables: Vec<TableDigest>,
    ) -> Result<Self, SpecError> {
        let kind = SplittingKind::from_name(&cfg.integrator.method).ok_or_else(|| {
            SpecError::new(
                "integrator.method",
                format!(
                    "unknown method '{}' for a separable Hamiltonian (known: aba864, leapfrog, \
                     saba2, yoshida4)",
                    cfg.integrator.method
                ),
            )
        })?;
        for (key, present) in [
            ("integrator.rtol", cfg.integrator.rtol.is_some()),
            ("integrator.atol", cfg.integrator.atol.is_some()),
        ] {
            if present {
                return Err(SpecError::new(
                    key,
                    "splittings take a fixed step; tolerances apply to adaptive dop853",
                ));
            }
        }
        if !cfg.orbit.x.is_empty() {
            return Err(SpecError::new(
                "orbit.x",
                "a Hamiltonian's initial state is q and p (x is for flows and maps)",
            ));
        }
        let h = finite_positive("integrator.h", cfg.integrator.h)?;
        let x0 = initial_state(model.as_ref(), &cfg.orbit)?;
        let splitting = Splitting::new(kind);
        let system = Arc::new(SplitHamiltonian {
            model: model.clone(),
            splitting: splitting.clone(),
            h,
        });
        let hamiltonian = HamiltonianParts { model, splitting };
        Self::validated(cfg, system, Some(hamiltonian), x0, tables)
    }

    /// Any other system: the initial state is `[orbit] x`.
    fn build_general(
        cfg: &RunConfig,
        system: Arc<dyn DynamicalSystem>,
        tables: Vec<TableDigest>,
    ) -> Result<Self, SpecError> {
        let dim = system.dim();
        let orbit = &cfg.orbit;
        for (key, present) in [
            ("orbit.q", !orbit.q.is_empty()),
            ("orbit.p", !orbit.p.is_empty()),
            ("orbit.energy", orbit.energy.is_some()),
            ("orbit.solve_for", orbit.solve_for.is_some()),
            ("orbit.preset", orbit.preset.is_some()),
        ] {
            if present {
                return Err(SpecError::new(
                    key,
                    format!(
                        "applies to Hamiltonians; the initial state of '{}' is x = [x1, ..., x{dim}]",
                        cfg.model.name
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
        let x0 = orbit.x.clone();
        if system.invariant(&x0).is_some_and(|e| !e.is_finite())
            || system.divergence(&x0).is_some_and(|d| !d.is_finite())
        {
            return Err(SpecError::new(
                "orbit.x",
                format!(
                    "the system is not defined at the initial state{}",
                    system
                        .diagnose_non_finite(&x0)
                        .map(|c| format!(": {c}"))
                        .unwrap_or_default()
                ),
            ));
        }
        Self::validated(cfg, system, None, x0, tables)
    }

    /// What every kind shares: the time grid, deviations and schemes.
    fn validated(
        cfg: &RunConfig,
        system: Arc<dyn DynamicalSystem>,
        hamiltonian: Option<HamiltonianParts>,
        x0: Vec<f64>,
        tables: Vec<TableDigest>,
    ) -> Result<Self, SpecError> {
        let dim = system.dim();
        let h = match system.time() {
            Time::Continuous { h } => h,
            Time::Discrete => 1.0,
        };
        if matches!(system.time(), Time::Continuous { .. })
            && h.to_bits() != cfg.integrator.h.to_bits()
        {
            return Err(SpecError::new(
                "integrator.h",
                format!(
                    "{} differs from the system's own step {}",
                    num(cfg.integrator.h),
                    num(h)
                ),
            ));
        }
        let h = finite_positive("integrator.h", h)?;
        let t_final = finite_positive("integrator.t_final", cfg.integrator.t_final)?;
        let total_steps = whole_steps("integrator.t_final", t_final, h)?;
        let e0 = system.invariant(&x0).unwrap_or(0.0);

        let dev = &cfg.deviations;
        if dev.k == 0 || dev.k > dim {
            return Err(SpecError::new(
                "deviations.k",
                format!(
                    "must be between 1 and {} = {dim} (the dimension), got {}",
                    if hamiltonian.is_some() { "2N" } else { "D" },
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
                vec![deviation::explicit_directions(rows, dim).map_err(dir_err)?]
            }
            None => {
                if dev.sets == 0 || dev.sets > MAX_SETS {
                    return Err(SpecError::new(
                        "deviations.sets",
                        format!("must be between 1 and {MAX_SETS}, got {}", dev.sets),
                    ));
                }
                (0..dev.sets as u64)
                    .map(|s| deviation::random_directions(dev.seed, s, dim, dev.k).map_err(dir_err))
                    .collect::<Result<_, _>>()?
            }
        };

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
            if route == Route::Propagator {
                if method != Method::Vm {
                    return Err(SpecError::new(
                        key("route"),
                        "the propagator route of a run is for vm schemes (maps also offer it \
                         for mpm: [map] route)",
                    ));
                }
                // It integrates 2N tangent vectors where the per-set route integrates sets x k,
                // and applies a 2N x 2N matrix to each set's vectors: no gain otherwise.
                let per_set = directions.len() * dev.k;
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

        Ok(RunSpec {
            system,
            hamiltonian,
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

    pub fn sets(&self) -> usize {
        self.directions.len()
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

    #[test]
    fn bad_values_name_their_key() {
        // Each case spoils one value of a valid config.
        type Spoil = fn(&mut RunConfig);
        let cases: [(Spoil, &str); 9] = [
            (|c| c.integrator.h = -1.0, "integrator.h"),
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
        assert_eq!(s.directions.len(), 1);
        assert!((s.directions[0].vector(1)[1] - 1.0).abs() < 1e-15);
    }
}
