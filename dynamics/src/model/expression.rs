//! `[model] name = "potential"`: the compiled model of `chaoscope_expr::potential` (parsing,
//! symbolic derivatives, native code and step kernels live there) as a [`SeparableHamiltonian`].
//!
//! An [`At`] without lane parameters evaluates at the compiled model's own placeholder values
//! (its `*_at` functions), one with them at those values (its `*_with` functions).

use chaoscope_expr::potential::{ExpressionModel, KernelBuild};

use super::{At, SeparableHamiltonian};

impl SeparableHamiltonian for ExpressionModel {
    fn name(&self) -> &str {
        "potential"
    }

    fn dof(&self) -> usize {
        ExpressionModel::dof(self)
    }

    #[inline]
    fn potential(&self, q: &[f64], at: At<'_>) -> f64 {
        if at.params.is_empty() {
            ExpressionModel::potential_at(self, q, at.t)
        } else {
            ExpressionModel::potential_with(self, q, at.t, at.params)
        }
    }

    #[inline]
    fn gradient(&self, q: &[f64], at: At<'_>, out: &mut [f64]) {
        if at.params.is_empty() {
            ExpressionModel::gradient_at(self, q, at.t, out)
        } else {
            ExpressionModel::gradient_with(self, q, at.t, at.params, out)
        }
    }

    /// Nothing where `V` is not `C^2` (the compiled model then writes nothing).
    #[inline]
    fn hessian_vector(&self, q: &[f64], at: At<'_>, v: &[f64], out: &mut [f64]) {
        if at.params.is_empty() {
            ExpressionModel::hessian_vector_at(self, q, at.t, v, out);
        } else {
            ExpressionModel::hessian_vector_with(self, q, at.t, at.params, v, out);
        }
    }

    fn no_hessian_reason(&self) -> Option<String> {
        ExpressionModel::no_hessian_reason(self)
    }

    fn inverse_masses(&self) -> Option<&[f64]> {
        ExpressionModel::inverse_masses(self)
    }

    fn diagnose_non_finite(&self, q: &[f64], at: At<'_>) -> Option<String> {
        if at.params.is_empty() {
            ExpressionModel::diagnose_non_finite_at(self, q, at.t)
        } else {
            ExpressionModel::diagnose_non_finite_with(self, q, at.t, at.params)
        }
    }

    fn site_potentials(&self, q: &[f64], out: &mut [f64]) -> Result<(), String> {
        ExpressionModel::site_potentials(self, q, out)
    }

    fn reads_time(&self) -> bool {
        ExpressionModel::reads_time(self)
    }

    fn lane_params(&self) -> usize {
        ExpressionModel::lane_params(self)
    }

    fn prepare_reference_tangent(&self, work: u64, build: KernelBuild) {
        ExpressionModel::prepare_reference_tangent(self, work, build)
    }

    fn reference_tangent_steps(
        &self,
        x: &mut [f64],
        v: &mut [f64],
        n_steps: u64,
        drift: &[f64],
        kick: &[f64],
    ) -> bool {
        ExpressionModel::reference_tangent_steps(self, x, v, n_steps, drift, kick)
    }
}
