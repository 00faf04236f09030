//! Any Hamiltonian `H(q, p)` written as an expression (`[model] name = "hamiltonian"`): its
//! vector field, derivatives taken symbolically, integrated by a Runge-Kutta method (`gl4` and
//! `gl6` are symplectic); the initial state is `[orbit] q` and `p`.

use std::sync::Arc;

use chaoscope_schemas::config::{HamiltonianConfig, OrbitConfig, RunConfig};

use super::flow::runge_kutta_system;
use super::{Built, LaneParam, SpecError, vector};

/// `[model] name = "hamiltonian"`: the vector field of `H(q, p)` (derivatives taken
/// symbolically) with a Runge-Kutta method; `gl4` and `gl6` are symplectic.
impl super::KindSpec for HamiltonianConfig {
    fn build(&self, cfg: &RunConfig, lanes: &[LaneParam]) -> Result<Built, SpecError> {
        let model = self;
    let source = model.hamiltonian.as_ref().ok_or_else(|| {
        SpecError::new(
            "model.hamiltonian",
            "needs H(q, p), e.g. hamiltonian = \"(p1^2 + p2^2)/2 + (q1^2 + q2^2)/2\"",
        )
    })?;
    let max = chaoscope_expr::vector::MAX_DIM / 2;
    let side = model
        .n
        .ok_or_else(|| SpecError::new("model.n", "needs the number of degrees of freedom n"))?;
    let sites =
        super::lattice_shape::sites(model.lattice.as_deref(), model.boundary.as_ref(), side)?;
    let n = sites.count;
    if side == 0 {
        return Err(SpecError::new(
            "model.n",
            format!("must be between 1 and {max}, got 0"),
        ));
    }
    if n > max {
        return Err(SpecError::new(
            "model.n",
            if n == side {
                format!("must be between 1 and {max}, got {n}")
            } else {
                format!("a square of side {side} has {n} sites; at most {max} are allowed")
            },
        ));
    }
    let (field, lane_values) = vector::hamiltonian_function(source, sites, &model.params, lanes)?;
    let system = runge_kutta_system(cfg, Arc::new(field))?;
    // The initial state is q and p, as for every Hamiltonian; inside, x = (q, p).
    let mut with_x = cfg.clone();
    with_x.orbit = state_of_q_and_p(&cfg.orbit, n)?;
    super::state_x_with_lanes(&with_x, system, Vec::new(), &lane_values)
    }
}

/// `[orbit] q` and `p` (or `x`) of a Hamiltonian given as an expression, as the state `x =
/// (q, p)`.
fn state_of_q_and_p(orbit: &OrbitConfig, n: usize) -> Result<OrbitConfig, SpecError> {
    for (key, present) in [
        ("orbit.energy", orbit.energy.is_some()),
        ("orbit.solve_for", orbit.solve_for.is_some()),
        ("orbit.preset", orbit.preset.is_some()),
        ("orbit.excite", orbit.excite.is_some()),
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
