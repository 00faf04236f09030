//! Any [`SeparableHamiltonian`] over lanes through its scalar methods: the fallback for models without a lane
//! implementation. Bit-identical by construction (it calls the very same code), not fast.

use std::sync::Arc;

use crate::batch::lanes::LaneHamiltonian;
use crate::model::{At, SeparableHamiltonian};

#[derive(Clone)]
pub struct DynLanes(Arc<dyn SeparableHamiltonian>);

impl DynLanes {
    pub fn new(model: Arc<dyn SeparableHamiltonian>) -> Self {
        Self(model)
    }
}

impl SeparableHamiltonian for DynLanes {
    fn name(&self) -> &str {
        self.0.name()
    }
    fn dof(&self) -> usize {
        self.0.dof()
    }
    fn potential(&self, q: &[f64], at: At<'_>) -> f64 {
        self.0.potential(q, at)
    }
    fn gradient(&self, q: &[f64], at: At<'_>, out: &mut [f64]) {
        self.0.gradient(q, at, out)
    }
    fn hessian_vector(&self, q: &[f64], at: At<'_>, v: &[f64], out: &mut [f64]) {
        self.0.hessian_vector(q, at, v, out)
    }
    fn no_hessian_reason(&self) -> Option<String> {
        self.0.no_hessian_reason()
    }
    fn kinetic(&self, p: &[f64]) -> f64 {
        self.0.kinetic(p)
    }
    fn inverse_masses(&self) -> Option<&[f64]> {
        self.0.inverse_masses()
    }
    fn energy(&self, x: &[f64], at: At<'_>) -> f64 {
        self.0.energy(x, at)
    }
}

impl LaneHamiltonian for DynLanes {
    fn gradient_lanes<const L: usize>(&self, q: &[[f64; L]], out: &mut [[f64; L]]) {
        let n = self.dof();
        let (mut ql, mut ol) = (vec![0.0; n], vec![0.0; n]);
        for l in 0..L {
            for i in 0..n {
                ql[i] = q[i][l];
            }
            self.0.gradient(&ql, At::T0, &mut ol);
            for i in 0..n {
                out[i][l] = ol[i];
            }
        }
    }

    fn hessian_vector_lanes<const L: usize>(
        &self,
        q: &[f64],
        v: &[[f64; L]],
        out: &mut [[f64; L]],
    ) {
        let n = self.dof();
        let (mut vl, mut ol) = (vec![0.0; n], vec![0.0; n]);
        for l in 0..L {
            for i in 0..n {
                vl[i] = v[i][l];
            }
            self.0.hessian_vector(q, At::T0, &vl, &mut ol);
            for i in 0..n {
                out[i][l] = ol[i];
            }
        }
    }
}
