//! The Henon-Heiles system (N = 2):
//! `H = (p1^2 + p2^2)/2 + (x1^2 + x2^2)/2 + x1^2 x2 - x2^3/3`. Orbits escape for `H > 1/6`.

use super::{At, SeparableHamiltonian};

#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct HenonHeiles;

impl SeparableHamiltonian for HenonHeiles {
    fn name(&self) -> &str {
        "henon-heiles"
    }

    fn dof(&self) -> usize {
        2
    }

    #[inline]
    fn potential(&self, q: &[f64], _at: At<'_>) -> f64 {
        let (x1, x2) = (q[0], q[1]);
        0.5 * (x1 * x1 + x2 * x2) + x1 * x1 * x2 - x2 * x2 * x2 / 3.0
    }

    #[inline]
    fn gradient(&self, q: &[f64], _at: At<'_>, out: &mut [f64]) {
        let (x1, x2) = (q[0], q[1]);
        out[0] = x1 + 2.0 * x1 * x2;
        out[1] = x2 + x1 * x1 - x2 * x2;
    }

    #[inline]
    fn hessian_vector(&self, q: &[f64], _at: At<'_>, v: &[f64], out: &mut [f64]) {
        let (x1, x2) = (q[0], q[1]);
        out[0] = (1.0 + 2.0 * x2) * v[0] + 2.0 * x1 * v[1];
        out[1] = 2.0 * x1 * v[0] + (1.0 - 2.0 * x2) * v[1];
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::check;

    #[test]
    fn derivatives_agree_with_potential() {
        for q in [[0.0, -0.25], [0.3, 0.1], [-0.4, 0.55]] {
            check::gradient_matches_potential(&HenonHeiles, &q);
            check::hessian_matches_gradient(&HenonHeiles, &q, &[0.6, -0.8]);
        }
    }

    #[test]
    fn energy_of_the_paper_chaotic_orbit() {
        // x1 = 0, x2 = -0.25, p2 = 0, p1 from numerics.md: H = 0.125.
        let x = [0.0, -0.25, 0.42081270576508656, 0.0];
        assert!((HenonHeiles.energy(&x, At::T0) - 0.125).abs() < 1e-15);
    }
}
