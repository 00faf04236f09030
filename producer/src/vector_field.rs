//! A vector field `f: R^D -> R^D` with its derivatives: what a flow is made of
//! ([`crate::system::RkFlow`]) and what the Runge-Kutta integrators step
//! ([`crate::integrator::runge_kutta`]). Its own file so that both depend on it and neither on
//! the other.

/// A vector field `f: R^D -> R^D` with its Jacobian-vector product, what a Runge-Kutta flow
/// needs (the compiled expressions of `[model] name = "ode"` implement it).
pub trait VectorField: Send + Sync {
    /// Dimension `D`.
    fn dim(&self) -> usize;

    /// `out = f(x)`.
    fn value(&self, x: &[f64], out: &mut [f64]);

    /// `out = J(x) v`, the derivative of `f` at `x` in direction `v`.
    fn tangent(&self, x: &[f64], v: &[f64], out: &mut [f64]);

    /// `div f(x)`, the trace of the Jacobian.
    fn divergence(&self, x: &[f64]) -> f64;

    /// Why `J` is not available (a kink or jump of `f`, naming the operation); `None` when it is.
    fn no_tangent_reason(&self) -> Option<String>;

    /// The operation that makes `f` non-finite at `x`, if known.
    fn diagnose_non_finite(&self, x: &[f64]) -> Option<String>;

    /// `H(x)` when `f` is the vector field of a Hamiltonian `H` (`dq/dt = dH/dp`, `dp/dt =
    /// -dH/dq` on `x = (q, p)`): the energy the report follows; `None` otherwise.
    fn energy(&self, _x: &[f64]) -> Option<f64> {
        None
    }

    /// Whether `f` is a Hamiltonian vector field (then [`VectorField::energy`] is `Some`).
    fn is_hamiltonian(&self) -> bool {
        false
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
    fn value(&self, x: &[f64], out: &mut [f64]) {
        chaoscope_expr::VectorFunction::value(self, x, out)
    }

    #[inline]
    fn tangent(&self, x: &[f64], v: &[f64], out: &mut [f64]) {
        // Validation refuses VM for a field without a tangent (`no_tangent_reason`), so this is
        // not reached there; were it reached, NaN stops the run with an error naming the time
        // rather than continuing with a wrong tangent.
        if !chaoscope_expr::VectorFunction::tangent(self, x, v, out) {
            out.fill(f64::NAN);
        }
    }

    fn divergence(&self, x: &[f64]) -> f64 {
        chaoscope_expr::VectorFunction::divergence(self, x)
    }

    fn no_tangent_reason(&self) -> Option<String> {
        chaoscope_expr::VectorFunction::no_tangent_reason(self)
    }

    fn diagnose_non_finite(&self, x: &[f64]) -> Option<String> {
        chaoscope_expr::VectorFunction::diagnose_non_finite(self, x)
    }

    fn energy(&self, x: &[f64]) -> Option<f64> {
        chaoscope_expr::VectorFunction::energy(self, x)
    }

    fn is_hamiltonian(&self) -> bool {
        chaoscope_expr::VectorFunction::is_hamiltonian(self)
    }

    fn compiled(&self) -> Option<&chaoscope_expr::VectorFunction> {
        Some(self)
    }
}
