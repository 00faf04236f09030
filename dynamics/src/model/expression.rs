//! `[model] name = "potential"`: the compiled model of `chaoscope_expr::potential` (parsing,
//! symbolic derivatives, native code and step kernels live there) as a [`Model`].

use chaoscope_expr::potential::ExpressionModel;

use super::Model;

impl Model for ExpressionModel {
    fn name(&self) -> &str {
        "potential"
    }

    fn dof(&self) -> usize {
        ExpressionModel::dof(self)
    }

    #[inline]
    fn potential(&self, q: &[f64]) -> f64 {
        ExpressionModel::potential(self, q)
    }

    #[inline]
    fn gradient(&self, q: &[f64], out: &mut [f64]) {
        ExpressionModel::gradient(self, q, out)
    }

    #[inline]
    fn hessian_vector(&self, q: &[f64], v: &[f64], out: &mut [f64]) -> bool {
        ExpressionModel::hessian_vector(self, q, v, out)
    }

    fn has_hessian(&self) -> bool {
        ExpressionModel::has_hessian(self)
    }

    fn no_hessian_reason(&self) -> Option<String> {
        ExpressionModel::no_hessian_reason(self)
    }

    fn inverse_masses(&self) -> Option<&[f64]> {
        ExpressionModel::inverse_masses(self)
    }

    fn diagnose_non_finite(&self, q: &[f64]) -> Option<String> {
        ExpressionModel::diagnose_non_finite(self, q)
    }

    fn site_potentials(&self, q: &[f64], out: &mut [f64]) -> Result<(), String> {
        ExpressionModel::site_potentials(self, q, out)
    }

    fn reads_time(&self) -> bool {
        ExpressionModel::reads_time(self)
    }

    fn potential_at(&self, q: &[f64], t: f64) -> f64 {
        ExpressionModel::potential_at(self, q, t)
    }

    #[inline]
    fn gradient_at(&self, q: &[f64], t: f64, out: &mut [f64]) {
        ExpressionModel::gradient_at(self, q, t, out)
    }

    #[inline]
    fn hessian_vector_at(&self, q: &[f64], t: f64, v: &[f64], out: &mut [f64]) -> bool {
        ExpressionModel::hessian_vector_at(self, q, t, v, out)
    }

    fn diagnose_non_finite_at(&self, q: &[f64], t: f64) -> Option<String> {
        ExpressionModel::diagnose_non_finite_at(self, q, t)
    }

    fn lane_params(&self) -> usize {
        ExpressionModel::lane_params(self)
    }

    fn potential_with(&self, q: &[f64], t: f64, params: &[f64]) -> f64 {
        ExpressionModel::potential_with(self, q, t, params)
    }

    #[inline]
    fn gradient_with(&self, q: &[f64], t: f64, params: &[f64], out: &mut [f64]) {
        ExpressionModel::gradient_with(self, q, t, params, out)
    }

    #[inline]
    fn hessian_vector_with(
        &self,
        q: &[f64],
        t: f64,
        params: &[f64],
        v: &[f64],
        out: &mut [f64],
    ) -> bool {
        ExpressionModel::hessian_vector_with(self, q, t, params, v, out)
    }

    fn diagnose_non_finite_with(&self, q: &[f64], t: f64, params: &[f64]) -> Option<String> {
        ExpressionModel::diagnose_non_finite_with(self, q, t, params)
    }

    fn prepare_reference_tangent(&self, work: u64) {
        ExpressionModel::prepare_reference_tangent(self, work)
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
