//! Separable Hamiltonians `H = sum p_i^2 / (2 m_i) + V(q)` with a symplectic splitting: the
//! built-in models (`henon_heiles.rs`, `fput_beta.rs`), a `potential` (`potential.rs`) and
//! models built in code; their initial state from `[orbit]` (`q` and `p`, the energy solved for
//! one momentum, or a preset).

use std::sync::Arc;

use chaoscope_schemas::config::{KNOWN_MODELS, ModelConfig, OrbitConfig, RunConfig};

use super::potential::TableDigest;
use super::{Built, SeparableModel, SpecError};
use crate::integrator::{Splitting, SplittingScheme};
use crate::model::{At, SeparableHamiltonian, WithParams};
use crate::system::SplitHamiltonian;

/// The separable model `cfg` names, with the digests of the tables it read.
pub fn model_from_config(cfg: &ModelConfig) -> Result<SeparableModel, SpecError> {
    let Some(kind) = super::kind_spec(cfg) else {
        return Err(SpecError::new(
            "model.name",
            format!("unknown model '{}' (known: {KNOWN_MODELS})", cfg.name()),
        ));
    };
    kind.separable().unwrap_or_else(|| {
        Err(SpecError::new(
            "model.name",
            format!("'{}' is not a separable Hamiltonian model", cfg.name()),
        ))
    })
}

/// A separable Hamiltonian `model` with the splitting of `[integrator]`, from the initial state
/// of `[orbit]` (`q` and `p`, the energy solved for a momentum, or a preset).
pub(super) fn run(
    cfg: &RunConfig,
    model: Arc<dyn SeparableHamiltonian>,
    tables: Vec<TableDigest>,
) -> Result<Built, SpecError> {
    run_with_lanes(cfg, model, tables, &[])
}

/// [`run`] of a model with lane parameters (`SeparableHamiltonian::lane_params`): its initial state is `(q,
/// p)` at the config's values `lane_values` of them, followed by those values.
pub(super) fn run_with_lanes(
    cfg: &RunConfig,
    model: Arc<dyn SeparableHamiltonian>,
    tables: Vec<TableDigest>,
    lane_values: &[f64],
) -> Result<Built, SpecError> {
    let kind = SplittingScheme::from_name(&cfg.integrator.method).ok_or_else(|| {
        SpecError::new(
            "integrator.method",
            format!(
                "unknown method '{}' for a separable Hamiltonian (known: {})",
                cfg.integrator.method,
                SplittingScheme::catalogue()
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
    let h = super::time_step(&cfg.integrator)?;
    let mut x0 = if lane_values.is_empty() {
        initial_state(model.as_ref(), &cfg.orbit, cfg.model.square_side())?
    } else {
        initial_state(
            &WithParams::new(&model, lane_values),
            &cfg.orbit,
            cfg.model.square_side(),
        )?
    };
    x0.extend_from_slice(lane_values);
    let system = Arc::new(SplitHamiltonian::new(model, Splitting::new(kind), h));
    Ok(Built { system, x0, tables })
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
    model: &dyn SeparableHamiltonian,
    x: &mut [f64],
    j: usize,
    energy: f64,
) -> Result<(), SpecError> {
    let n = model.dof();
    x[n + j] = 0.0;
    let rest = model.energy(x, At::T0);
    let twice_kinetic = 2.0 * (energy - rest);
    let p = match model.inverse_masses() {
        None => twice_kinetic.sqrt(),
        Some(w) => (twice_kinetic / w[j]).sqrt(),
    };
    if twice_kinetic >= 0.0 && !p.is_finite() {
        // Not below the surface but beyond the numbers: 2 (E - V) / m overflows.
        return Err(SpecError::new(
            "orbit.energy",
            format!(
                "p{} = sqrt(2 m (E - V)) is not finite at energy {energy:?} (the other \
                 coordinates have energy {rest:?}): the energy is too large",
                j + 1
            ),
        ));
    }
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
    x[n + j] = p;
    Ok(())
}

/// `[orbit] excite`: the momenta of the excited sites in `x` (all else 0), `p_l = +-sqrt(2 m_l
/// E / L)` for a block of `L` sites sharing the energy `E`.
fn excited_momenta(
    model: &dyn SeparableHamiltonian,
    excite: &chaoscope_schemas::config::Excitation,
    side: Option<usize>,
    x: &mut [f64],
) -> Result<(), SpecError> {
    let n = model.dof();
    let excited = super::lattice_shape::excited_sites(excite.sites.range(), n, side)?;
    if excite.norm.is_some() {
        return Err(SpecError::new(
            "orbit.excite.norm",
            "applies to the ddnls model; a separable Hamiltonian's excitation shares an energy",
        ));
    }
    let e = excite.energy.ok_or_else(|| {
        SpecError::new(
            "orbit.excite.energy",
            "missing: the energy the excited sites share",
        )
    })?;
    if !(e.is_finite() && e > 0.0) {
        return Err(SpecError::new(
            "orbit.excite.energy",
            format!("must be positive and finite, got {e}"),
        ));
    }
    let sites = excited.len();
    let per_site = e / sites as f64;
    let signs = match excite.seed {
        Some(seed) => super::drawn::signs(seed, sites),
        None => vec![1.0; sites],
    };
    for (l, sign) in excited.into_iter().zip(signs) {
        // p^2 / (2 m) = E / L; unit masses give sqrt(2 E / L) exactly.
        let twice = 2.0 * per_site;
        let p = match model.inverse_masses() {
            None => twice.sqrt(),
            Some(w) => (twice / w[l]).sqrt(),
        };
        if !p.is_finite() {
            return Err(SpecError::new(
                "orbit.excite.energy",
                format!(
                    "site {}'s momentum sqrt(2 m E / L) is not finite at energy {e:?}: the \
                     energy is too large",
                    l + 1
                ),
            ));
        }
        x[n + l] = sign * p;
    }
    Ok(())
}

/// Initial state from the `[orbit]` section; `side` is the side of the square the sites form
/// (`None` for a chain), where an excitation names a block of rows and columns.
pub fn initial_state(
    model: &dyn SeparableHamiltonian,
    orbit: &OrbitConfig,
    side: Option<usize>,
) -> Result<Vec<f64>, SpecError> {
    let n = model.dof();
    let mut x = vec![0.0; 2 * n];
    if let Some(excite) = &orbit.excite {
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
                    "orbit.excite gives the whole initial state (q = 0, the excited momenta); \
                     leave this out",
                ));
            }
        }
        excited_momenta(model, excite, side, &mut x)?;
        check_initial_energy(model, &x)?;
        return Ok(x);
    }
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
        if let Some(i) = x.iter().position(|v| !v.is_finite()) {
            return Err(SpecError::new(
                "orbit.energy",
                format!(
                    "preset {preset} at energy {e:?} puts {} at a value that is not finite: the \
                     energy is too large",
                    if i < n {
                        format!("q{}", i + 1)
                    } else {
                        format!("p{}", i - n + 1)
                    }
                ),
            ));
        }
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
    // With a momentum solved from the energy, `p` may be left out: every other momentum is then
    // 0 (no placeholder for the solved one). Given, it holds all N momenta.
    let solving = orbit.solve_for.is_some() && orbit.energy.is_some();
    if orbit.p.len() != n && !(solving && orbit.p.is_empty()) {
        return Err(SpecError::new(
            "orbit.p",
            format!(
                "needs {n} momenta, got {}{}",
                orbit.p.len(),
                if solving {
                    " (or leave p out: with solve_for, the other momenta are then 0)"
                } else {
                    ""
                }
            ),
        ));
    }
    x[..n].copy_from_slice(&orbit.q);
    if !orbit.p.is_empty() {
        x[n..].copy_from_slice(&orbit.p);
    }
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
    check_initial_energy(model, &x)?;
    Ok(x)
}

/// An error unless the energy of the initial state `x` is finite, naming the operation that
/// made it not (a parameter such as `W = 0` in `1/(2*W)` is no fault of the orbit's).
fn check_initial_energy(model: &dyn SeparableHamiltonian, x: &[f64]) -> Result<(), SpecError> {
    if model.energy(x, At::T0).is_finite() {
        return Ok(());
    }
    let n = model.dof();
    let why = match model.diagnose_non_finite(&x[..n], At::T0) {
        Some(cause) => format!("the initial energy is not finite: {cause}"),
        None => "the initial energy is not finite".to_string(),
    };
    Err(SpecError::new("orbit", why))
}
