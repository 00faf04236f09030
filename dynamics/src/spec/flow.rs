//! The Runge-Kutta (and Taylor) integration of `[integrator]` that flows, general Hamiltonians,
//! potentials integrated as flows and the DDNLS lattice share.

use std::sync::Arc;

use chaoscope_schemas::config::RunConfig;

use super::{SpecError, num};
use crate::integrator::runge_kutta::{RungeKutta, RungeKuttaTableau, Tolerances};
use crate::system::{DynamicalSystem, RkFlow, TaylorFlow};
use crate::vector_field::VectorField;

/// A vector field with the Runge-Kutta method of `[integrator]`: fixed step `h`, or adaptive
/// `dop853` landing on the grid of `h` when `rtol` and `atol` are given.
pub(super) fn runge_kutta_system(
    cfg: &RunConfig,
    field: Arc<dyn VectorField>,
) -> Result<Arc<dyn DynamicalSystem>, SpecError> {
    let integrator = &cfg.integrator;
    if integrator.method == "taylor" {
        return taylor_system(cfg, field);
    }
    if integrator.tol.is_some() {
        return Err(SpecError::new(
            "integrator.tol",
            format!(
                "tol is the tolerance of taylor; {} takes rtol and atol",
                integrator.method
            ),
        ));
    }
    let kind = RungeKuttaTableau::from_name(&integrator.method).ok_or_else(|| {
        SpecError::new(
            "integrator.method",
            format!(
                "unknown method '{}' for a flow (known: rk4, dop853, gl4, gl6, taylor)",
                integrator.method
            ),
        )
    })?;
    let h = super::time_step(integrator)?;
    let tolerances = match (integrator.rtol, integrator.atol) {
        (None, None) => None,
        (Some(rtol), Some(atol)) => {
            if kind != RungeKuttaTableau::Dop853 {
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
        name: cfg.model.name().to_string(),
        field,
        method: RungeKutta::new(kind),
        h,
        tolerances,
    }))
}

/// Taylor's method of `[integrator]` (`method = "taylor"`): on the grid of `h`, at `tol`.
fn taylor_system(
    cfg: &RunConfig,
    field: Arc<dyn VectorField>,
) -> Result<Arc<dyn DynamicalSystem>, SpecError> {
    let integrator = &cfg.integrator;
    if integrator.rtol.is_some() || integrator.atol.is_some() {
        let key = if integrator.rtol.is_some() {
            "integrator.rtol"
        } else {
            "integrator.atol"
        };
        return Err(SpecError::new(
            key,
            "taylor takes one tolerance, tol (absolute below |x| = 1, relative above)",
        ));
    }
    let h = super::time_step(integrator)?;
    let tol = integrator.tol.unwrap_or(f64::EPSILON);
    // Below 1e-20 the order passes 24 for digits a double does not have; at 0.1 and above
    // the series is cut after two terms.
    if !(1e-20..0.1).contains(&tol) {
        return Err(SpecError::new(
            "integrator.tol",
            format!("must be in [1e-20, 0.1), got {}", num(tol)),
        ));
    }
    let system = TaylorFlow::new(cfg.model.name(), field, tol, h)
        .map_err(|e| SpecError::new("integrator.method", e))?;
    Ok(Arc::new(system))
}
