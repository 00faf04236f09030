//! Flows `dx/dt = f(x)` (`[model] name = "ode"`), integrated by the Runge-Kutta or Taylor
//! method of `[integrator]` ([`super::flow`]).

use std::sync::Arc;

use chaoscope_schemas::config::{OdeConfig, RunConfig};

use super::flow::runge_kutta_system;
use super::{Built, LaneParam, SpecError, vector};

/// `[model] name = "ode"`: the compiled right-hand side with the Runge-Kutta method of
/// `[integrator]`, fixed step `h`, or adaptive `dop853` landing on the grid of `h` when `rtol`
/// and `atol` are given.
impl super::KindSpec for OdeConfig {
    fn build(&self, cfg: &RunConfig, lanes: &[LaneParam]) -> Result<Built, SpecError> {
        let model = self;
    let rhs = model.rhs.as_ref().ok_or_else(|| {
        SpecError::new(
            "model.rhs",
            "ode needs the right-hand side, e.g. rhs = [\"sigma * (x2 - x1)\", ...]",
        )
    })?;
    let (field, lane_values) =
        vector::vector_function("rhs", rhs, &model.params, model.boundary.as_deref(), lanes)?;
    let system = runge_kutta_system(cfg, Arc::new(field))?;
    super::state_x_with_lanes(cfg, system, Vec::new(), &lane_values)
    }
}
