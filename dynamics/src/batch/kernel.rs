//! What the batched methods need from a system, written once for every kind of system: advance
//! lanes of orbits (MPM), advance one reference orbit while keeping where each step's tangent
//! map is taken, advance lanes of tangent vectors along it (VM), and measure a nearby orbit's
//! separation as the system does.
//!
//! A system hands out its kernel through its one extension point for the batched form,
//! `DynamicalSystem::batched`; each kind implements it beside itself (`system/`). Every kernel
//! is, lane by lane, the bits of the one-orbit system's `step` / `step_tangent`, so a point
//! computed through any kernel equals the engine's (`dynamics/tests/map_batch.rs`).

use super::Soa;
use crate::integrator::TangentError;

/// A system's batched steps, as the map's methods use them. Every call advances `steps` steps
/// starting with step number `from` of the run (the first step of a run is number 0): a system
/// that reads the time takes step `n` at its time `n h` (`Time::at`); others ignore it.
pub trait PointKernel {
    /// Advance every lane of `x` (orbits; rows are coordinates) by `steps` steps.
    fn orbit_steps(&mut self, x: &mut Soa, from: u64, steps: u64);

    /// Advance the reference orbit `x` by `steps` steps exactly as the one-orbit system does,
    /// keeping where each step's tangent map is taken for [`PointKernel::tangent_steps`].
    fn reference_steps(&mut self, x: &mut [f64], from: u64, steps: u64);

    /// Advance every lane of `v` (tangent vectors) along the steps of the last
    /// [`PointKernel::reference_steps`] (the same `from` and `steps`).
    fn tangent_steps(&mut self, v: &mut Soa, from: u64, steps: u64) -> Result<(), TangentError>;

    /// The separation `out = y - x` of a nearby orbit from the reference, as the system's
    /// `DynamicalSystem::separation` measures it: the plain difference unless the system has
    /// periodic coordinates.
    #[inline]
    fn separation(&self, y: &[f64], x: &[f64], out: &mut [f64]) {
        for ((o, a), b) in out.iter_mut().zip(y).zip(x) {
            *o = a - b;
        }
    }

    /// Whether [`PointKernel::orbit_tangent_steps`] advances many points' orbits and tangent
    /// bases in one fused pass (worth batching points for); otherwise it steps them one by one.
    fn fuses_orbits_and_tangents(&self) -> bool {
        false
    }

    /// Whether [`PointKernel::orbit_tangent_steps`] is also worth it for a few vectors per
    /// lane (the per-set route's sets) rather than only for a basis: its fused pass costs no
    /// more per lane than the separate steps.
    fn fuses_few_vectors(&self) -> bool {
        self.fuses_orbits_and_tangents()
    }

    /// Advance every lane of `x` by `steps` steps: rows `0..D` are an orbit, each further `D`
    /// rows a tangent vector around that lane's own orbit (the variational equations of many
    /// points at once). Lane by lane the bits of [`PointKernel::reference_steps`] followed by
    /// [`PointKernel::tangent_steps`], which is what this default does for a lane holding an
    /// orbit and a basis of `D` vectors (the only shape a map gives a kernel that does not fuse);
    /// a kernel that fuses takes any number of vectors.
    fn orbit_tangent_steps(
        &mut self,
        x: &mut Soa,
        from: u64,
        steps: u64,
    ) -> Result<(), TangentError> {
        let rows = x.rows();
        let dim = (1..=rows).find(|d| d * (d + 1) == rows).unwrap_or(rows);
        let mut column = vec![0.0; rows];
        let mut vectors = Soa::new(dim, dim);
        for lane in 0..x.lanes() {
            x.read_lane(lane, &mut column);
            let (orbit, basis) = column.split_at_mut(dim);
            for (j, v) in basis.chunks_exact(dim).enumerate() {
                vectors.write_lane(j, v);
            }
            self.reference_steps(orbit, from, steps);
            self.tangent_steps(&mut vectors, from, steps)?;
            for (j, v) in basis.chunks_exact_mut(dim).enumerate() {
                vectors.read_lane(j, v);
            }
            x.write_lane(lane, &column);
        }
        Ok(())
    }
}
