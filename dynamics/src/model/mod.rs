//! Models: the Hamiltonians chaoscope integrates.
//!
//! One trait, [`Model`], for separable Hamiltonians `H = sum p_i^2/(2 m_i) + V(q)`: that is what the
//! symplectic splittings and their tangent maps need. A model states which derivatives it has:
//! the Hessian-vector product is optional, and a model without it (a non-smooth or empirical
//! potential) can still be studied with the multi-particle method, never with the variational
//! one. Vector fields of other systems (for the Runge-Kutta integrators) are a sibling trait,
//! [`crate::vector_field::VectorField`]; the integrator trait is generic over the system so
//! both fit.
//!
//! Every method is pure and allocation-free: models are called in the innermost loop.

mod expression;
mod fput;
mod henon_heiles;

/// `[model] name = "potential"`: compiled by `chaoscope-expr`; `expression.rs` makes it a [`Model`].
pub use chaoscope_expr::potential::{
    CStepState, CStepStatus, ExpressionModel, PotentialDefinition, PotentialError,
};
pub use fput::FputBeta;
pub use henon_heiles::HenonHeiles;

/// A separable Hamiltonian `H(q, p) = sum p_i^2 / (2 m_i) + V(q)` with `N` degrees of freedom.
///
/// Phase-space vectors are ordered `x = (q1..qN, p1..pN)`.
pub trait Model: std::any::Any + Send + Sync {
    /// Short machine name, as written in configs (`"henon-heiles"`).
    fn name(&self) -> &str;

    /// Degrees of freedom `N`; the phase space has dimension `2N`.
    fn dof(&self) -> usize;

    /// Potential energy `V(q)`.
    fn potential(&self, q: &[f64]) -> f64;

    /// `out = dV/dq (q)`.
    fn gradient(&self, q: &[f64], out: &mut [f64]);

    /// `out = Hess V(q) * v`, or `false` (with `out` untouched) when the model has no second
    /// derivatives and only the multi-particle method applies.
    fn hessian_vector(&self, q: &[f64], v: &[f64], out: &mut [f64]) -> bool;

    /// Whether [`Model::hessian_vector`] is available (the variational method needs it).
    fn has_hessian(&self) -> bool;

    /// `1 / m_i` for each degree of freedom, or `None` for unit masses (the built-in models:
    /// their code paths then stay exactly as they were).
    fn inverse_masses(&self) -> Option<&[f64]> {
        None
    }

    /// Kinetic energy `sum p_i^2 / (2 m_i)`.
    fn kinetic(&self, p: &[f64]) -> f64 {
        match self.inverse_masses() {
            None => 0.5 * p.iter().map(|v| v * v).sum::<f64>(),
            Some(w) => 0.5 * p.iter().zip(w).map(|(v, w)| v * v * w).sum::<f64>(),
        }
    }

    /// Why the variational method cannot be used, naming the operation that lacks second
    /// derivatives (when the model knows it); `None` when it can.
    fn no_hessian_reason(&self) -> Option<String> {
        (!self.has_hessian()).then(|| format!("model '{}' has no Hessian", self.name()))
    }

    /// Where a non-finite value arises when the forces are evaluated at `q`, e.g. "'log' at
    /// line 1, column 9 gave NaN"; `None` when unknown or everything is finite. Called only
    /// after a run has failed, off the hot path.
    fn diagnose_non_finite(&self, _q: &[f64]) -> Option<String> {
        None
    }

    /// A named initial condition of this model at the given energy (e.g. the FPUT chain's
    /// `"spo1"`): `None` when the model has no preset of that name.
    fn preset(&self, _name: &str, _energy: f64) -> Option<Result<Vec<f64>, String>> {
        None
    }

    /// The potential energy of each site at `q` into `out` (`N` values), where the model is a
    /// lattice that says which part of `V` is whose: each on-site term whole to its site, each
    /// coupling term shared equally by the sites it touches (the energy distribution of the
    /// lattice literature). They add up to `V` to rounding. An error saying why otherwise.
    fn site_potentials(&self, _q: &[f64], _out: &mut [f64]) -> Result<(), String> {
        Err(format!(
            "model '{}' does not say which part of its potential belongs to which site",
            self.name()
        ))
    }

    /// The energy of each site of `x = (q, p)` into `out` (`N` values): `p_l^2 / (2 m_l)` plus
    /// [`Model::site_potentials`]; they add up to [`Model::energy`] to rounding.
    fn site_energies(&self, x: &[f64], out: &mut [f64]) -> Result<(), String> {
        let n = self.dof();
        if x.len() != 2 * n || out.len() != n {
            return Err(format!(
                "a state of {} entries and {n} sites expected",
                2 * n
            ));
        }
        self.site_potentials(&x[..n], out)?;
        let p = &x[n..];
        match self.inverse_masses() {
            None => out.iter_mut().zip(p).for_each(|(e, v)| *e += 0.5 * (v * v)),
            Some(w) => out
                .iter_mut()
                .zip(p.iter().zip(w))
                .for_each(|(e, (v, w))| *e += 0.5 * (v * v * w)),
        }
        Ok(())
    }

    /// Total energy of a phase-space point `x = (q, p)`.
    fn energy(&self, x: &[f64]) -> f64 {
        let n = self.dof();
        self.kinetic(&x[n..]) + self.potential(&x[..n])
    }

    /// Whether the potential depends on the time, `V(q, t)` (a non-autonomous system; only
    /// `[model] name = "potential"` can). The `*_at` methods below take the time; a model that
    /// does not read it keeps them as its plain methods, so its arithmetic is unchanged.
    fn reads_time(&self) -> bool {
        false
    }

    /// `V(q, t)`.
    fn potential_at(&self, q: &[f64], _t: f64) -> f64 {
        self.potential(q)
    }

    /// `out = dV/dq (q, t)`.
    #[inline]
    fn gradient_at(&self, q: &[f64], _t: f64, out: &mut [f64]) {
        self.gradient(q, out)
    }

    /// `out = Hess V(q, t) * v`, or `false` as [`Model::hessian_vector`].
    #[inline]
    fn hessian_vector_at(&self, q: &[f64], _t: f64, v: &[f64], out: &mut [f64]) -> bool {
        self.hessian_vector(q, v, out)
    }

    /// [`Model::diagnose_non_finite`] at time `t`.
    fn diagnose_non_finite_at(&self, q: &[f64], _t: f64) -> Option<String> {
        self.diagnose_non_finite(q)
    }

    /// `H(x, t)`: what the energy of a time-dependent potential is at time `t` (not conserved).
    fn energy_at(&self, x: &[f64], t: f64) -> f64 {
        if !self.reads_time() {
            return self.energy(x);
        }
        let n = self.dof();
        self.kinetic(&x[n..]) + self.potential_at(&x[..n], t)
    }

    /// `P`: parameters the potential reads per evaluation instead of folding them (a map's
    /// parameter axes, [`crate::spec::LaneParam`]); a state of such a model is `(q, p)`
    /// followed by their values. The `*_with` methods below take them; [`WithParams`] binds
    /// them to give the plain model of one point. 0 for every model but a `potential` built
    /// with lane parameters.
    fn lane_params(&self) -> usize {
        0
    }

    /// `V(q, t)` at the lane parameters `params`.
    fn potential_with(&self, q: &[f64], t: f64, _params: &[f64]) -> f64 {
        self.potential_at(q, t)
    }

    /// `out = dV/dq (q, t)` at the lane parameters `params`.
    #[inline]
    fn gradient_with(&self, q: &[f64], t: f64, _params: &[f64], out: &mut [f64]) {
        self.gradient_at(q, t, out)
    }

    /// `out = Hess V(q, t) * v` at the lane parameters `params`, or `false` as
    /// [`Model::hessian_vector`].
    #[inline]
    fn hessian_vector_with(
        &self,
        q: &[f64],
        t: f64,
        _params: &[f64],
        v: &[f64],
        out: &mut [f64],
    ) -> bool {
        self.hessian_vector_at(q, t, v, out)
    }

    /// [`Model::diagnose_non_finite_at`] at the lane parameters `params`.
    fn diagnose_non_finite_with(&self, q: &[f64], t: f64, _params: &[f64]) -> Option<String> {
        self.diagnose_non_finite_at(q, t)
    }

    /// A run of `work` state-value steps (steps times `2N`) will ask
    /// [`Model::reference_tangent_steps`] to step its small sets: build what that needs, where
    /// it repays (a `potential` whose lattice sums are loops starts its C kernels' build in the
    /// background). Nothing for every other model.
    fn prepare_reference_tangent(&self, work: u64) {
        let _ = work;
    }

    /// `n_steps` steps of a splitting (its coefficients times `h`) for the state `x` (`q, p`)
    /// and the tangent vectors `v` around it (each `dq, dp`) in one fused pass per stage: bit
    /// for bit `Splitting::step` and `step_tangent` through this model's own functions. False,
    /// with nothing stepped, where the model has no such kernel (yet): the caller steps them
    /// as usual.
    fn reference_tangent_steps(
        &self,
        x: &mut [f64],
        v: &mut [f64],
        n_steps: u64,
        drift: &[f64],
        kick: &[f64],
    ) -> bool {
        let _ = (x, v, n_steps, drift, kick);
        false
    }
}

/// Most lane parameters of a model: a map has two axes.
pub const MAX_LANE_PARAMS: usize = 2;

/// A model whose lane parameters ([`Model::lane_params`]) are bound to one point's values: the
/// plain model of that point (its `*_at` methods call the model's `*_with` ones), which the
/// splittings step exactly as a model with those values as constants, up to how a constant
/// folds. The values are copied, so the state they came from can be stepped meanwhile (and the
/// model is shared, not borrowed: a `Model` is `'static`).
#[derive(Clone)]
pub struct WithParams {
    model: std::sync::Arc<dyn Model>,
    params: [f64; MAX_LANE_PARAMS],
}

impl WithParams {
    /// `model` at the parameter values `params` (its `P` values: the entries of a state after
    /// its `2N` coordinates).
    ///
    /// # Panics
    /// If `params` does not have `P` entries, or `P` exceeds [`MAX_LANE_PARAMS`].
    pub fn new(model: &std::sync::Arc<dyn Model>, params: &[f64]) -> Self {
        let p = model.lane_params();
        assert!(
            params.len() == p && p <= MAX_LANE_PARAMS,
            "{} lane parameter values for a model of {p}",
            params.len()
        );
        let mut values = [0.0; MAX_LANE_PARAMS];
        values[..p].copy_from_slice(params);
        Self {
            model: model.clone(),
            params: values,
        }
    }

    /// The model at the parameters a state `x = (q, p, params)` carries after its `2N`
    /// coordinates.
    pub fn of_state(model: &std::sync::Arc<dyn Model>, x: &[f64]) -> Self {
        Self::new(model, &x[2 * model.dof()..])
    }

    fn params(&self) -> &[f64] {
        &self.params[..self.model.lane_params()]
    }
}

impl Model for WithParams {
    fn name(&self) -> &str {
        self.model.name()
    }

    fn dof(&self) -> usize {
        self.model.dof()
    }

    fn potential(&self, q: &[f64]) -> f64 {
        self.model.potential_with(q, 0.0, self.params())
    }

    #[inline]
    fn gradient(&self, q: &[f64], out: &mut [f64]) {
        self.model.gradient_with(q, 0.0, self.params(), out)
    }

    #[inline]
    fn hessian_vector(&self, q: &[f64], v: &[f64], out: &mut [f64]) -> bool {
        self.model
            .hessian_vector_with(q, 0.0, self.params(), v, out)
    }

    fn has_hessian(&self) -> bool {
        self.model.has_hessian()
    }

    fn inverse_masses(&self) -> Option<&[f64]> {
        self.model.inverse_masses()
    }

    fn no_hessian_reason(&self) -> Option<String> {
        self.model.no_hessian_reason()
    }

    fn diagnose_non_finite(&self, q: &[f64]) -> Option<String> {
        self.model.diagnose_non_finite_with(q, 0.0, self.params())
    }

    fn reads_time(&self) -> bool {
        self.model.reads_time()
    }

    fn potential_at(&self, q: &[f64], t: f64) -> f64 {
        self.model.potential_with(q, t, self.params())
    }

    #[inline]
    fn gradient_at(&self, q: &[f64], t: f64, out: &mut [f64]) {
        self.model.gradient_with(q, t, self.params(), out)
    }

    #[inline]
    fn hessian_vector_at(&self, q: &[f64], t: f64, v: &[f64], out: &mut [f64]) -> bool {
        self.model.hessian_vector_with(q, t, self.params(), v, out)
    }

    fn diagnose_non_finite_at(&self, q: &[f64], t: f64) -> Option<String> {
        self.model.diagnose_non_finite_with(q, t, self.params())
    }
}

#[cfg(test)]
pub(crate) mod check {
    //! Finite-difference checks shared by the model tests: a model's derivatives must agree
    //! with its own potential.
    use super::Model;

    pub fn gradient_matches_potential(m: &dyn Model, q: &[f64]) {
        let n = m.dof();
        let mut g = vec![0.0; n];
        m.gradient(q, &mut g);
        for i in 0..n {
            let eps = 1e-6;
            let mut qp = q.to_vec();
            let mut qm = q.to_vec();
            qp[i] += eps;
            qm[i] -= eps;
            let fd = (m.potential(&qp) - m.potential(&qm)) / (2.0 * eps);
            // Central differences: error ~ eps^2 * V''' plus rounding ~ 1e-16 / eps.
            assert!(
                (fd - g[i]).abs() < 1e-8 * (1.0 + g[i].abs()),
                "dV/dq{i}: fd {fd} vs {}",
                g[i]
            );
        }
    }

    pub fn hessian_matches_gradient(m: &dyn Model, q: &[f64], v: &[f64]) {
        let n = m.dof();
        let mut hv = vec![0.0; n];
        assert!(m.hessian_vector(q, v, &mut hv));
        let eps = 1e-6;
        let qp: Vec<f64> = q.iter().zip(v).map(|(a, b)| a + eps * b).collect();
        let qm: Vec<f64> = q.iter().zip(v).map(|(a, b)| a - eps * b).collect();
        let (mut gp, mut gm) = (vec![0.0; n], vec![0.0; n]);
        m.gradient(&qp, &mut gp);
        m.gradient(&qm, &mut gm);
        for i in 0..n {
            let fd = (gp[i] - gm[i]) / (2.0 * eps);
            assert!(
                (fd - hv[i]).abs() < 1e-7 * (1.0 + hv[i].abs()),
                "Hv[{i}]: fd {fd} vs {}",
                hv[i]
            );
        }
    }
}
