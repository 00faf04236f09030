//! Maps `x -> F(x)` (`[model] name = "map"`): iterated, `h` = 1 (may be left out), `t_final` and every `tau` a
//! whole number of iterations; coordinates with a `modulo` wrap.

use std::sync::Arc;

use chaoscope_schemas::config::{MapModelConfig, RunConfig};

use super::{Built, LaneParam, SpecError, num, vector};
use crate::system::Map;

/// `[model] name = "map"`: the compiled map with its periods. Time counts iterations: `h` is 1,
/// `t_final` and every `tau` are whole numbers of iterations.
impl super::KindSpec for MapModelConfig {
    fn build(&self, cfg: &RunConfig, lanes: &[LaneParam]) -> Result<Built, SpecError> {
        let model = self;
    let next = model.next.as_ref().ok_or_else(|| {
        SpecError::new(
            "model.next",
            "map needs the image of every coordinate, e.g. next = [\"1 - a * x1^2 + x2\", \"b * x1\"]",
        )
    })?;
    let (function, lane_values) = vector::vector_function(
        "next",
        next,
        &model.params,
        model.boundary.as_deref(),
        lanes,
    )?;
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
    // A map's time counts iterations: `h` may be left out, and if given it must say so.
    if let Some(h) = integrator.h.filter(|h| h.to_bits() != 1.0f64.to_bits()) {
        return Err(SpecError::new(
            "integrator.h",
            format!(
                "a map's time counts iterations: h = 1 (or leave it out), got {}",
                num(h)
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
    super::state_x_with_lanes(cfg, Arc::new(map), Vec::new(), &lane_values)
    }
}
