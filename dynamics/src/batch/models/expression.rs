//! A user-written potential over lanes: the compiled step kernels run whole steps of the
//! splitting on the chunk's rows as they are (`[[f64; L]]` flattened is row-major with stride
//! `L`, the layout the kernels read), drift, force and kick fused per block of lanes, the step
//! and stage loops in native code.

use crate::batch::lanes::{
    LaneHamiltonian, StepCoeffs, orbit_steps_generic, tangent_steps_generic,
};
use crate::model::ExpressionModel;

impl LaneHamiltonian for ExpressionModel {
    /// Wide chunks while a 32-lane chunk's rows fit in half of L1 (16 KiB: `N <= 32`): the
    /// kernel streams each stage over the chunk's blocks, which are independent dependency
    /// chains the CPU overlaps; a model with few rows (Henon-Heiles) needs many of them to
    /// hide the latency of one block's drift-force-kick chain. Longer chains have that
    /// parallelism across their sites and keep narrow chunks in cache.
    #[inline]
    fn register_resident(&self) -> bool {
        2 * self.dof() * 32 * 8 <= 16 * 1024
    }

    /// Its orbit and tangent steps are compiled step kernels; the generic fused loops would
    /// call its scalar functions lane by lane instead.
    #[inline]
    fn fuses_orbit_tangents(&self) -> bool {
        false
    }

    /// Lane by lane through the scalar compiled function: only the generic step loops call
    /// this, and this model replaces both of them.
    fn gradient_lanes<const L: usize>(&self, q: &[[f64; L]], out: &mut [[f64; L]]) {
        let n = self.dof();
        let (mut ql, mut g) = (vec![0.0; n], vec![0.0; n]);
        for l in 0..L {
            for (qi, row) in ql.iter_mut().zip(q) {
                *qi = row[l];
            }
            self.gradient(&ql, &mut g);
            for (row, gi) in out.iter_mut().zip(&g) {
                row[l] = *gi;
            }
        }
    }

    /// As [`Self::gradient_lanes`], lane by lane.
    fn hessian_vector_lanes<const L: usize>(
        &self,
        q: &[f64],
        v: &[[f64; L]],
        out: &mut [[f64; L]],
    ) {
        let n = self.dof();
        let (mut vl, mut h) = (vec![0.0; n], vec![0.0; n]);
        for l in 0..L {
            for (vi, row) in vl.iter_mut().zip(v) {
                *vi = row[l];
            }
            self.hessian_vector(q, &vl, &mut h);
            for (row, hi) in out.iter_mut().zip(&h) {
                row[l] = *hi;
            }
        }
    }

    #[inline(always)]
    fn orbit_steps<const L: usize>(
        &self,
        c: &StepCoeffs,
        x: &mut [[f64; L]],
        force: &mut [[f64; L]],
        n_steps: u64,
    ) {
        match self.step_kernels() {
            Some(k) => k.orbit_steps(
                x.as_flattened_mut(),
                L,
                L,
                n_steps,
                &c.drift,
                &c.kick,
                self.inverse_masses(),
            ),
            // No step kernels (their compilation failed, said on stderr): the same bits.
            None => orbit_steps_generic(self, c, x, force, n_steps),
        }
    }

    #[inline(always)]
    fn tangent_steps<const L: usize>(
        &self,
        c: &StepCoeffs,
        stages: &[f64],
        v: &mut [[f64; L]],
        force: &mut [[f64; L]],
        n_steps: u64,
    ) {
        match self.step_kernels() {
            Some(k) => k.tangent_steps(
                stages,
                v.as_flattened_mut(),
                L,
                L,
                n_steps,
                &c.drift,
                &c.kick,
                self.inverse_masses(),
            ),
            None => tangent_steps_generic(self, c, stages, v, force, n_steps),
        }
    }
}
