//! Models: the Hamiltonians chaoscope integrates.
//!
//! One trait, [`SeparableHamiltonian`], for separable Hamiltonians `H = sum p_i^2/(2 m_i) + V(q)`: that is what the
//! symplectic splittings and their tangent maps need. A model states which derivatives it has:
//! the Hessian-vector product is optional, and a model without it (a non-smooth or empirical
//! potential) can still be studied with the multi-particle method, never with the variational
//! one. Vector fields of other systems (for the Runge-Kutta integrators) are a sibling trait,
//! [`crate::vector_field::VectorField`]; the integrator trait is generic over the system so
//! both fit.
//!
//! Every method is pure and allocation-free: models are called in the innermost loop.

mod ddnls;
mod expression;
mod fput;
mod henon_heiles;
mod sin_cos;

/// `[model] name = "potential"`: compiled by `chaoscope-expr`; `expression.rs` makes it a [`SeparableHamiltonian`].
pub use chaoscope_expr::potential::{
    CStepState, CStepStatus, ExpressionModel, KernelBuild, PotentialDefinition, PotentialError,
    SQUARE_LOOPS_FROM_SIDE,
};
pub use ddnls::{Ddnls, DdnlsLattice};
pub use fput::FputBeta;
pub use henon_heiles::HenonHeiles;

/// Where a potential is evaluated besides the positions `q`: the time `t` and the lane
/// parameters. Built per call on the stack (a float and a slice), so every evaluation takes one
/// of these instead of a method per combination of what it reads.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct At<'a> {
    /// The time; read only by a model that [`SeparableHamiltonian::reads_time`].
    pub t: f64,
    /// The values of the model's lane parameters ([`SeparableHamiltonian::lane_params`]); empty for a model
    /// without them (a model with them then reads values that are not numbers).
    pub params: &'a [f64],
}

impl At<'static> {
    /// `t = 0` without lane parameters: where an autonomous model is evaluated.
    pub const T0: Self = Self {
        t: 0.0,
        params: &[],
    };

    /// The time `t` without lane parameters.
    #[inline]
    pub const fn time(t: f64) -> Self {
        Self { t, params: &[] }
    }
}

/// A separable Hamiltonian `H(q, p) = sum p_i^2 / (2 m_i) + V(q)` with `N` degrees of freedom.
///
/// Phase-space vectors are ordered `x = (q1..qN, p1..pN)`. Each quantity of `V` is one method
/// taking [`At`] (the time and the lane parameters): a model that reads neither ignores it, so
/// its arithmetic is that of `V(q)`.
pub trait SeparableHamiltonian: std::any::Any + Send + Sync {
    /// Short machine name, as written in configs (`"henon-heiles"`).
    fn name(&self) -> &str;

    /// Degrees of freedom `N`; the phase space has dimension `2N`.
    fn dof(&self) -> usize;

    /// Potential energy `V(q, t)` at the lane parameters of `at`.
    fn potential(&self, q: &[f64], at: At<'_>) -> f64;

    /// `out = dV/dq (q, t)` at the lane parameters of `at`.
    fn gradient(&self, q: &[f64], at: At<'_>, out: &mut [f64]);

    /// `out = Hess V(q, t) * v` at the lane parameters of `at`. Called only on a model whose
    /// [`SeparableHamiltonian::no_hessian_reason`] is `None`; otherwise `out` is left as it is.
    fn hessian_vector(&self, q: &[f64], at: At<'_>, v: &[f64], out: &mut [f64]);

    /// Why the model has no Hessian-vector product (so the variational method cannot be used),
    /// naming the operation that lacks second derivatives; `None` when it has one (the default:
    /// a model with a non-smooth or empirical potential says why here, and can still be studied
    /// with the multi-particle method).
    fn no_hessian_reason(&self) -> Option<String> {
        None
    }

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

    /// Where a non-finite value arises when the forces are evaluated at `q` and `at`, e.g.
    /// "'log' at line 1, column 9 gave NaN"; `None` when unknown or everything is finite.
    /// Called only after a run has failed, off the hot path.
    fn diagnose_non_finite(&self, _q: &[f64], _at: At<'_>) -> Option<String> {
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
    /// [`SeparableHamiltonian::site_potentials`]; they add up to [`SeparableHamiltonian::energy`] to rounding.
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

    /// Total energy `H(x, t)` of a phase-space point `x = (q, p)` (conserved unless the model
    /// [`SeparableHamiltonian::reads_time`]).
    fn energy(&self, x: &[f64], at: At<'_>) -> f64 {
        let n = self.dof();
        self.kinetic(&x[n..]) + self.potential(&x[..n], at)
    }

    /// Whether the potential depends on the time, `V(q, t)` (a non-autonomous system; only
    /// `[model] name = "potential"` can).
    fn reads_time(&self) -> bool {
        false
    }

    /// `P`: parameters the potential reads per evaluation instead of folding them (a map's
    /// parameter axes, [`crate::spec::LaneParam`]), passed in [`At::params`]; a state of such
    /// a model is `(q, p)` followed by their values, and [`WithParams`] binds them to give the
    /// plain model of one point. 0 for every model but a `potential` built with lane
    /// parameters.
    fn lane_params(&self) -> usize {
        0
    }

    /// A run of `work` state-value steps (steps times `2N`) will ask
    /// [`SeparableHamiltonian::reference_tangent_steps`] to step its small sets: build what that needs, where
    /// it repays (a `potential` whose lattice sums are loops asks for the Cranelift kernels'
    /// fused pass and starts its C kernels' build in the background, as far as `build`
    /// allows). Nothing for every other model.
    fn prepare_reference_tangent(&self, work: u64, build: KernelBuild) {
        let _ = (work, build);
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

/// A model whose lane parameters ([`SeparableHamiltonian::lane_params`]) are bound to one point's values: the
/// plain model of that point (it evaluates the model at its own parameters, whatever [`At`]
/// carries), which the splittings step exactly as a model with those values as constants, up
/// to how a constant folds. The values are copied, so the state they came from can be stepped
/// meanwhile (and the model is shared, not borrowed: a `SeparableHamiltonian` is `'static`).
#[derive(Clone)]
pub struct WithParams {
    model: std::sync::Arc<dyn SeparableHamiltonian>,
    params: [f64; MAX_LANE_PARAMS],
}

impl WithParams {
    /// `model` at the parameter values `params` (its `P` values: the entries of a state after
    /// its `2N` coordinates).
    ///
    /// # Panics
    /// If `params` does not have `P` entries, or `P` exceeds [`MAX_LANE_PARAMS`].
    pub fn new(model: &std::sync::Arc<dyn SeparableHamiltonian>, params: &[f64]) -> Self {
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
    pub fn of_state(model: &std::sync::Arc<dyn SeparableHamiltonian>, x: &[f64]) -> Self {
        Self::new(model, &x[2 * model.dof()..])
    }

    /// `at`'s time with this point's parameters.
    #[inline]
    fn at(&self, at: At<'_>) -> At<'_> {
        At {
            t: at.t,
            params: &self.params[..self.model.lane_params()],
        }
    }
}

impl SeparableHamiltonian for WithParams {
    fn name(&self) -> &str {
        self.model.name()
    }

    fn dof(&self) -> usize {
        self.model.dof()
    }

    fn potential(&self, q: &[f64], at: At<'_>) -> f64 {
        self.model.potential(q, self.at(at))
    }

    #[inline]
    fn gradient(&self, q: &[f64], at: At<'_>, out: &mut [f64]) {
        self.model.gradient(q, self.at(at), out)
    }

    #[inline]
    fn hessian_vector(&self, q: &[f64], at: At<'_>, v: &[f64], out: &mut [f64]) {
        self.model.hessian_vector(q, self.at(at), v, out)
    }

    fn no_hessian_reason(&self) -> Option<String> {
        self.model.no_hessian_reason()
    }

    fn inverse_masses(&self) -> Option<&[f64]> {
        self.model.inverse_masses()
    }

    fn diagnose_non_finite(&self, q: &[f64], at: At<'_>) -> Option<String> {
        self.model.diagnose_non_finite(q, self.at(at))
    }

    fn reads_time(&self) -> bool {
        self.model.reads_time()
    }
}

#[cfg(test)]
pub(crate) mod check {
    //! Finite-difference checks shared by the model tests: a model's derivatives must agree
    //! with its own potential.
    use super::{At, SeparableHamiltonian};

    pub fn gradient_matches_potential(m: &dyn SeparableHamiltonian, q: &[f64]) {
        let n = m.dof();
        let mut g = vec![0.0; n];
        m.gradient(q, At::T0, &mut g);
        for i in 0..n {
            let eps = 1e-6;
            let mut qp = q.to_vec();
            let mut qm = q.to_vec();
            qp[i] += eps;
            qm[i] -= eps;
            let fd = (m.potential(&qp, At::T0) - m.potential(&qm, At::T0)) / (2.0 * eps);
            // Central differences: error ~ eps^2 * V''' plus rounding ~ 1e-16 / eps.
            assert!(
                (fd - g[i]).abs() < 1e-8 * (1.0 + g[i].abs()),
                "dV/dq{i}: fd {fd} vs {}",
                g[i]
            );
        }
    }

    pub fn hessian_matches_gradient(m: &dyn SeparableHamiltonian, q: &[f64], v: &[f64]) {
        let n = m.dof();
        let mut hv = vec![0.0; n];
        assert!(m.no_hessian_reason().is_none());
        m.hessian_vector(q, At::T0, v, &mut hv);
        let eps = 1e-6;
        let qp: Vec<f64> = q.iter().zip(v).map(|(a, b)| a + eps * b).collect();
        let qm: Vec<f64> = q.iter().zip(v).map(|(a, b)| a - eps * b).collect();
        let (mut gp, mut gm) = (vec![0.0; n], vec![0.0; n]);
        m.gradient(&qp, At::T0, &mut gp);
        m.gradient(&qm, At::T0, &mut gm);
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
