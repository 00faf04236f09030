//! Taylor's method with the step and order from one tolerance (Jorba and Zou, Experiment.
//! Math. 14, 99 (2005), as heyoka uses it): the series of the solution through the state
//! ([`chaoscope_expr::taylor`]) to order `p = ceil(-ln(tol) / 2 + 1)`, and the step
//!
//! ```text
//! h = rho_m / e^2 * exp(-0.7 / (p - 1)),   rho_m = min_{j in {p-1, p}} (s / |x_j|_inf)^(1/j),
//! ```
//!
//! with `s = max(1, |x_0|_inf)` (absolute error below 1, relative above). The two last
//! coefficients estimate the series' radius of convergence; the factor keeps the truncation
//! below `tol` of `s`. The step is chosen from the state's series alone, never the tangent
//! vectors', so a state moves the same whatever vectors ride along, and from the state at the
//! step's start alone, so a run resumed from a recorded state takes the very same steps.

use chaoscope_expr::taylor::TaylorTape;

use super::runge_kutta::substep_times;

/// The order and step rule of one tolerance.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Taylor {
    pub order: usize,
    /// `exp(-0.7 / (p - 1)) / e^2`, the step's factor on the radius estimate.
    safety: f64,
}

/// A step this far below the remaining interval has lost the series (a singularity of the
/// solution or of `F` within reach): the step fails instead of crawling.
const COLLAPSE: f64 = 1e-12;

/// Why a Taylor step failed.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum TaylorStepError {
    #[error("a Taylor coefficient is not finite at t = {t}")]
    NotFinite { t: f64 },
    #[error(
        "the Taylor step collapsed to {h:e} at t = {t} (the series' radius of convergence \
         vanishes: the solution or the right-hand side is singular there)"
    )]
    Collapsed { h: f64, t: f64 },
}

impl Taylor {
    /// The order for `tol` (at least 2).
    pub fn new(tol: f64) -> Self {
        let order = ((-tol.ln()) / 2.0 + 1.0).ceil().max(2.0) as usize;
        let safety = (-0.7 / (order - 1) as f64).exp() / std::f64::consts::E.powi(2);
        Self { order, safety }
    }

    /// The step the series in `coef` allow (of `tape`, computed to [`Self::order`]).
    pub fn step_size(&self, tape: &TaylorTape, coef: &[f64]) -> f64 {
        let p = self.order;
        let norm = |k| {
            tape.state_coefficients(coef, k)
                .fold(0.0f64, |m, c| m.max(c.abs()))
        };
        let scale = norm(0).max(1.0);
        let rho = |k: usize| (scale / norm(k)).powf(1.0 / k as f64);
        let rho_m = rho(p - 1).min(rho(p));
        rho_m * self.safety
    }

    /// Advance `x` (and the vectors `w`, when `tape` carries them) from `t0` to `t1`, the
    /// steps chosen by the state (or taken from `plan` when it is given), appending the steps
    /// taken to `taken`.
    #[allow(clippy::too_many_arguments)]
    pub fn advance(
        &self,
        tape: &TaylorTape,
        coef: &mut [f64],
        x: &mut [f64],
        w: &mut [f64],
        t0: f64,
        t1: f64,
        plan: Option<&[f64]>,
        mut taken: Option<&mut Vec<f64>>,
    ) -> Result<(), TaylorStepError> {
        let dim = tape.dim();
        // Each substep starts at t0 plus the substeps before it, as every method's substeps
        // (`substep_times`), so a plan walked one substep at a time gives the same bits.
        if let Some(plan) = plan {
            for (t, h) in substep_times(t0, plan) {
                tape.coefficients(coef, x, w, t);
                tape.sum(coef, h, &mut x[..dim], w);
            }
            return Ok(());
        }
        let mut done = 0.0;
        loop {
            let t = t0 + done;
            tape.coefficients(coef, x, w, t);
            let choice = self.step_size(tape, coef);
            let remaining = t1 - t;
            if choice.is_nan() {
                return Err(TaylorStepError::NotFinite { t });
            }
            if choice < COLLAPSE * remaining {
                return Err(TaylorStepError::Collapsed { h: choice, t });
            }
            let last = choice >= remaining;
            let h = if last { remaining } else { choice };
            tape.sum(coef, h, &mut x[..dim], w);
            if let Some(taken) = taken.as_deref_mut() {
                taken.push(h);
            }
            if last {
                return Ok(());
            }
            done += h;
        }
    }
}

/// Coefficient buffers of the tapes a thread steps with, one per tape
/// ([`TaylorTape::id`]): each keeps the zeros its tape never writes.
#[derive(Debug, Default, Clone)]
pub struct TaylorScratch {
    buffers: Vec<(u64, Vec<f64>)>,
}

impl TaylorScratch {
    pub fn buffer(&mut self, tape: &TaylorTape) -> &mut [f64] {
        let i = match self.buffers.iter().position(|(id, _)| *id == tape.id()) {
            Some(i) => i,
            None => {
                self.buffers.push((tape.id(), vec![0.0; tape.buffer_len()]));
                self.buffers.len() - 1
            }
        };
        &mut self.buffers[i].1
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// heyoka's orders: 20 at double precision's epsilon, 11 at 1e-8.
    #[test]
    fn the_order_of_a_tolerance() {
        assert_eq!(Taylor::new(f64::EPSILON).order, 20);
        assert_eq!(Taylor::new(1e-8).order, 11);
        assert_eq!(Taylor::new(0.5).order, 2);
    }
}
