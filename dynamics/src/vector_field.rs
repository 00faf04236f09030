//! A vector field `f: R^D -> R^D` with its derivatives: what a flow is made of
//! ([`crate::system::RkFlow`]) and what the Runge-Kutta integrators step
//! ([`crate::integrator::runge_kutta`]). Its own file so that both depend on it and neither on
//! the other.

use chaoscope_schemas::run::SystemClass;

/// A vector field `f(x, t)` on `R^D` with its Jacobian-vector product (in `x`), what a
/// Runge-Kutta flow needs (the compiled expressions of `[model] name = "ode"` implement it).
/// `t` is the time; a field that does not read it (an autonomous system) ignores it.
pub trait VectorField: Send + Sync {
    /// Dimension `D`.
    fn dim(&self) -> usize;

    /// `out = f(x, t)`.
    fn value(&self, x: &[f64], t: f64, out: &mut [f64]);

    /// `out = J(x, t) v`, the derivative of `f` in `x` at `(x, t)` in direction `v`.
    fn tangent(&self, x: &[f64], t: f64, v: &[f64], out: &mut [f64]);

    /// [`VectorField::tangent`] of each of the vectors in `v` (one after the other, `D`
    /// values each) into the same place of `out`: the bits of one call per vector.
    fn tangents(&self, x: &[f64], t: f64, v: &[f64], out: &mut [f64]) {
        let dim = self.dim();
        for (v, out) in v.chunks_exact(dim).zip(out.chunks_exact_mut(dim)) {
            self.tangent(x, t, v, out);
        }
    }

    /// `div f(x, t)`, the trace of the Jacobian.
    fn divergence(&self, x: &[f64], t: f64) -> f64;

    /// Why `J` is not available (a kink or jump of `f`, naming the operation); `None` when it is.
    fn no_tangent_reason(&self) -> Option<String>;

    /// The operation that makes `f` non-finite at `(x, t)`, if known.
    fn diagnose_non_finite(&self, x: &[f64], t: f64) -> Option<String>;

    /// Whether `f` depends on the time (a non-autonomous system).
    fn reads_time(&self) -> bool {
        false
    }

    /// `H(x, t)` when `f` is the vector field of a Hamiltonian `H` (`dq/dt = dH/dp`, `dp/dt =
    /// -dH/dq` on `x = (q, p)`): the energy the report follows; `None` otherwise.
    fn energy(&self, _x: &[f64], _t: f64) -> Option<f64> {
        None
    }

    /// Whether `f` is a Hamiltonian vector field (then [`VectorField::energy`] is `Some`).
    fn is_hamiltonian(&self) -> bool {
        false
    }

    /// How a run reports a system made of this field: a Hamiltonian (its energy error) or a
    /// flow.
    fn class(&self) -> SystemClass {
        if self.is_hamiltonian() {
            SystemClass::Hamiltonian
        } else {
            SystemClass::Flow
        }
    }

    /// The conserved quantity a run reports: the energy of a Hamiltonian field that does not
    /// read the time; `None` otherwise.
    fn invariant(&self, x: &[f64]) -> Option<f64> {
        if self.reads_time() {
            return None;
        }
        self.energy(x, 0.0)
    }

    /// The rate of phase-space volume change a run reports, `div f`; `None` for a Hamiltonian
    /// field (its flow conserves volume identically).
    fn volume_rate(&self, x: &[f64], t: f64) -> Option<f64> {
        (!self.is_hamiltonian()).then(|| self.divergence(x, t))
    }

    /// The energy of each site of the state `x` of a Hamiltonian written as lattice sums (the
    /// weights of the energy distribution); for any other field an error saying that the
    /// system `name` has none.
    fn site_energies(&self, x: &[f64], out: &mut [f64], name: &str) -> Result<(), String> {
        match self.compiled() {
            Some(f) if f.is_hamiltonian() => f.site_energies(x, out),
            _ => Err(crate::system::no_site_energies(name)),
        }
    }

    /// The compiled function behind `f`, whose lane functions the batched kernel of
    /// phase-space maps steps many orbits with (`crate::batch::flow_orbit_steps`); `None` for a
    /// hand-written field, whose points run through the engine.
    fn compiled(&self) -> Option<&chaoscope_expr::VectorFunction> {
        None
    }
}

/// The right-hand side of `[model] name = "ode"`: the compiled expressions and their automatic
/// derivatives.
impl VectorField for chaoscope_expr::VectorFunction {
    fn dim(&self) -> usize {
        chaoscope_expr::VectorFunction::dim(self)
    }

    #[inline]
    fn value(&self, x: &[f64], t: f64, out: &mut [f64]) {
        chaoscope_expr::VectorFunction::value_at(self, x, t, out)
    }

    #[inline]
    fn tangent(&self, x: &[f64], t: f64, v: &[f64], out: &mut [f64]) {
        // Validation refuses VM for a field without a tangent (`no_tangent_reason`), so this is
        // not reached there; were it reached, NaN stops the run with an error naming the time
        // rather than continuing with a wrong tangent.
        if !chaoscope_expr::VectorFunction::tangent_at(self, x, t, v, out) {
            out.fill(f64::NAN);
        }
    }

    #[inline]
    fn tangents(&self, x: &[f64], t: f64, v: &[f64], out: &mut [f64]) {
        // As in `tangent`: NaN where there is no tangent.
        if !chaoscope_expr::VectorFunction::tangents_at(self, x, t, v, out) {
            out.fill(f64::NAN);
        }
    }

    fn divergence(&self, x: &[f64], t: f64) -> f64 {
        chaoscope_expr::VectorFunction::divergence_at(self, x, t)
    }

    fn no_tangent_reason(&self) -> Option<String> {
        chaoscope_expr::VectorFunction::no_tangent_reason(self)
    }

    fn diagnose_non_finite(&self, x: &[f64], t: f64) -> Option<String> {
        chaoscope_expr::VectorFunction::diagnose_non_finite_at(self, x, t)
    }

    fn reads_time(&self) -> bool {
        chaoscope_expr::VectorFunction::reads_time(self)
    }

    fn energy(&self, x: &[f64], t: f64) -> Option<f64> {
        chaoscope_expr::VectorFunction::energy_at(self, x, t)
    }

    fn is_hamiltonian(&self) -> bool {
        chaoscope_expr::VectorFunction::is_hamiltonian(self)
    }

    fn compiled(&self) -> Option<&chaoscope_expr::VectorFunction> {
        Some(self)
    }
}
