//! A separable Hamiltonian advanced by a symplectic splitting.

use std::sync::Arc;

use chaoscope_schemas::run::SystemClass;

use super::{DynamicalSystem, ReferenceTangent, Time};
use crate::batch::{self, AnyLaneModel, Isa, LaneHamiltonian, PointKernel, Soa, StepCoeffs};
use crate::integrator::{Integrator, Splitting, TangentError, Workspace};
use crate::model::{At, KernelBuild, SeparableHamiltonian, WithParams};

/// `H = T(p) + V(q)` stepped by a splitting with fixed step `h`; its tangent map is the
/// splitting's own (`Splitting::step_tangent`), the variational equations of the discrete map.
///
/// A model with lane parameters (`SeparableHamiltonian::lane_params`, a map's parameter axes) has states `(q,
/// p)` followed by their values, which every step reads (the model bound to them,
/// [`WithParams`]) and never writes; its deviation vectors are `(dq, dp)`.
#[derive(Clone)]
pub struct SplitHamiltonian {
    model: Arc<dyn SeparableHamiltonian>,
    splitting: Splitting,
    h: f64,
    /// The model's lane implementation and the splitting's coefficients times `h`: the batched
    /// form ([`SplittingKernel`]).
    lanes: AnyLaneModel,
    coeffs: StepCoeffs,
}

impl SplitHamiltonian {
    pub fn new(model: Arc<dyn SeparableHamiltonian>, splitting: Splitting, h: f64) -> Self {
        Self {
            lanes: AnyLaneModel::new(model.clone()),
            coeffs: StepCoeffs::new(&splitting, h),
            model,
            splitting,
            h,
        }
    }

    pub fn model(&self) -> &Arc<dyn SeparableHamiltonian> {
        &self.model
    }

    pub fn splitting(&self) -> &Splitting {
        &self.splitting
    }

    pub fn h(&self) -> f64 {
        self.h
    }

    /// The model's lane implementation (the batched kernel's; a `potential`'s compiled model).
    pub fn lanes(&self) -> &AnyLaneModel {
        &self.lanes
    }

    /// The splitting's coefficients times `h`, as the batched kernel steps them.
    pub fn step_coeffs(&self) -> &StepCoeffs {
        &self.coeffs
    }
}

impl DynamicalSystem for SplitHamiltonian {
    fn name(&self) -> &str {
        self.model.name()
    }

    fn kind(&self) -> SystemClass {
        SystemClass::Hamiltonian
    }

    fn dim(&self) -> usize {
        2 * self.model.dof()
    }

    fn time(&self) -> Time {
        Time::Continuous { h: self.h }
    }

    fn reads_time(&self) -> bool {
        self.model.reads_time()
    }

    #[inline]
    fn step(&self, x: &mut [f64], t: f64, work: &mut Workspace) {
        if self.model.lane_params() > 0 {
            let model = WithParams::of_state(&self.model, x);
            let dim = self.dim();
            return self.splitting.step(&model, &mut x[..dim], t, self.h, work);
        }
        self.splitting.step(self.model.as_ref(), x, t, self.h, work)
    }

    #[inline]
    fn step_tangent(
        &self,
        x: &mut [f64],
        w: &mut [f64],
        t: f64,
        work: &mut Workspace,
    ) -> Result<(), TangentError> {
        if self.model.lane_params() > 0 {
            let model = WithParams::of_state(&self.model, x);
            let dim = self.dim();
            return self
                .splitting
                .step_tangent(&model, &mut x[..dim], w, t, self.h, work);
        }
        self.splitting
            .step_tangent(self.model.as_ref(), x, w, t, self.h, work)
    }

    fn no_tangent_reason(&self) -> Option<String> {
        self.model.no_hessian_reason()
    }

    /// The energy, conserved unless the potential reads the time.
    fn invariant(&self, x: &[f64]) -> Option<f64> {
        if self.model.reads_time() {
            return None;
        }
        Some(if self.model.lane_params() > 0 {
            WithParams::of_state(&self.model, x).energy(&x[..self.dim()], At::T0)
        } else {
            self.model.energy(x, At::T0)
        })
    }

    fn divergence(&self, _x: &[f64], _t: f64) -> Option<f64> {
        None
    }

    /// `(dq/dt, dp/dt) = (p / m, -dV/dq (q, t))`.
    fn vector_field(&self, x: &[f64], t: f64, out: &mut [f64]) -> bool {
        let n = self.model.dof();
        let model = WithParams::of_state(&self.model, x);
        let (q, p) = x[..2 * n].split_at(n);
        let (dq, dp) = out.split_at_mut(n);
        match self.model.inverse_masses() {
            None => dq.copy_from_slice(p),
            Some(w) => {
                for ((d, p), w) in dq.iter_mut().zip(p).zip(w) {
                    *d = p * w;
                }
            }
        }
        model.gradient(q, At::time(t), dp);
        for d in dp.iter_mut() {
            *d = -*d;
        }
        true
    }

    /// The model's lane implementation over the instruction set `isa` ([`SplittingKernel`]);
    /// `None` for a potential of the time (the lane kernels take no time: its points run
    /// through the engine, one orbit at a time, with the same bits). A model with lane
    /// parameters (of the time or not) steps its lanes one by one through the splitting's own
    /// step with each lane's parameters ([`LaneByLaneKernel`]).
    fn batched(&self, isa: Isa) -> Option<Box<dyn PointKernel + '_>> {
        if self.model.lane_params() > 0 {
            return Some(Box::new(LaneByLaneKernel::new(self)));
        }
        if self.model.reads_time() {
            return None;
        }
        let coeffs = &self.coeffs;
        Some(crate::with_lane_model!(
            &self.lanes,
            |m| Box::new(SplittingKernel::new(m, coeffs, isa)) as Box<dyn PointKernel>
        ))
    }

    fn separable(&self) -> Option<&SplitHamiltonian> {
        Some(self)
    }

    fn diagnose_non_finite(&self, x: &[f64], t: f64) -> Option<String> {
        let n = self.model.dof();
        let model = WithParams::of_state(&self.model, x);
        let model = &model;
        let x = &x[..2 * n];
        // The potential itself undefined at x (the energy is what the run checks), ...
        if x.iter().all(|v| v.is_finite()) && !model.potential(&x[..n], At::time(t)).is_finite() {
            return model.diagnose_non_finite(&x[..n], At::time(t));
        }
        // ... or the step from x: replay it stage by stage and ask the model about the first
        // position whose forces are not finite.
        let w = self.model.inverse_masses();
        let mut x = x.to_vec();
        let mut force = vec![0.0; n];
        let (drifts, kicks) = (self.splitting.drifts(), self.splitting.kicks());
        for (i, &d) in kicks.iter().enumerate() {
            Splitting::drift(&mut x, n, drifts[i] * self.h, w);
            let tk = t + self.splitting.kick_times()[i] * self.h;
            model.gradient(&x[..n], At::time(tk), &mut force);
            if force.iter().any(|f| !f.is_finite()) || x.iter().any(|v| !v.is_finite()) {
                return model.diagnose_non_finite(&x[..n], At::time(tk));
            }
            let (_, p) = x.split_at_mut(n);
            for (pi, fi) in p.iter_mut().zip(&force) {
                *pi -= d * self.h * fi;
            }
        }
        None
    }

    /// Every model not of the time and without lane parameters: `Splitting::step_tangent`
    /// moves the orbit with `step`'s operations (`engine/stepping.rs`'s tests); the built-in
    /// FPUT chain and a potential whose lattice sums are loops (its C kernels', or Cranelift's
    /// for a run long enough) have a fused pass.
    fn reference_tangent(&self) -> Option<&dyn ReferenceTangent> {
        let fits = self.model.lane_params() == 0
            && !self.model.reads_time()
            && self.model.no_hessian_reason().is_none();
        fits.then_some(self)
    }
}

impl ReferenceTangent for SplitHamiltonian {
    fn prepare(&self, work: u64, build: KernelBuild) {
        self.model.prepare_reference_tangent(work, build);
    }

    fn steps(&self, x: &mut [f64], v: &mut [f64], _from: u64, steps: u64) -> bool {
        // The time is not read (`reference_tangent`): the step number does not matter.
        self.model
            .reference_tangent_steps(x, v, steps, &self.coeffs.drift, &self.coeffs.kick)
    }
}

/// A separable Hamiltonian's splitting over the lane kernel of the instruction set `isa`.
struct SplittingKernel<'a, M: LaneHamiltonian> {
    model: &'a M,
    coeffs: &'a StepCoeffs,
    isa: Isa,
    /// Positions before every kick of the last reference steps.
    stages: Vec<f64>,
    force: Vec<f64>,
}

impl<'a, M: LaneHamiltonian> SplittingKernel<'a, M> {
    fn new(model: &'a M, coeffs: &'a StepCoeffs, isa: Isa) -> Self {
        Self {
            model,
            coeffs,
            isa,
            stages: Vec::new(),
            force: vec![0.0; model.dof()],
        }
    }
}

impl<M: LaneHamiltonian> PointKernel for SplittingKernel<'_, M> {
    fn orbit_steps(&mut self, x: &mut Soa, _from: u64, steps: u64) {
        batch::orbit_steps(self.isa, self.model, self.coeffs, x, steps);
    }

    fn reference_steps(&mut self, x: &mut [f64], _from: u64, steps: u64) {
        batch::record_reference_stages(
            self.model,
            self.coeffs,
            x,
            steps,
            &mut self.stages,
            &mut self.force,
        );
    }

    fn tangent_steps(&mut self, v: &mut Soa, _from: u64, steps: u64) -> Result<(), TangentError> {
        batch::tangent_steps(self.isa, self.model, self.coeffs, &self.stages, v, steps);
        Ok(())
    }

    /// Each lane its own orbit with its basis, all in one pass of the lane kernel.
    fn fuses_orbits_and_tangents(&self) -> bool {
        true
    }

    fn fuses_few_vectors(&self) -> bool {
        self.model.fuses_orbit_tangents()
    }

    fn orbit_tangent_steps(
        &mut self,
        x: &mut Soa,
        _from: u64,
        steps: u64,
    ) -> Result<(), TangentError> {
        batch::orbit_tangent_steps(self.isa, self.model, self.coeffs, x, steps);
        Ok(())
    }
}

/// The batched form of a model with lane parameters: every lane stepped by the splitting's own
/// `step` / `step_tangent` with its parameters bound (the one-orbit engine's code, so the same
/// bits), at the time of each step (a potential of the time takes parameter axes too). The
/// compiled step kernels have no parameter input; this is correct, not fast.
struct LaneByLaneKernel<'a> {
    system: &'a SplitHamiltonian,
    work: Workspace,
    /// The reference's states at the start of each of its last steps (`2N + P` each).
    reference: Vec<f64>,
    lane: Vec<f64>,
    vectors: Vec<f64>,
}

impl<'a> LaneByLaneKernel<'a> {
    fn new(system: &'a SplitHamiltonian) -> Self {
        Self {
            system,
            work: Workspace::default(),
            reference: Vec::new(),
            lane: Vec::new(),
            vectors: Vec::new(),
        }
    }

    fn state_len(&self) -> usize {
        self.system.dim() + self.system.model.lane_params()
    }
}

impl PointKernel for LaneByLaneKernel<'_> {
    /// Each lane's model bound once for all its steps (what `SplitHamiltonian::step` does at
    /// every step).
    fn orbit_steps(&mut self, x: &mut Soa, from: u64, steps: u64) {
        let (system, time, dim) = (self.system, self.system.time(), self.system.dim());
        self.lane.resize(x.rows(), 0.0);
        for l in 0..x.lanes() {
            x.read_lane(l, &mut self.lane);
            let model = WithParams::of_state(&system.model, &self.lane);
            for s in from..from + steps {
                let state = &mut self.lane[..dim];
                system
                    .splitting
                    .step(&model, state, time.at(s), system.h, &mut self.work);
            }
            x.write_lane(l, &self.lane);
        }
    }

    fn reference_steps(&mut self, x: &mut [f64], from: u64, steps: u64) {
        let (system, time, dim) = (self.system, self.system.time(), self.system.dim());
        let model = WithParams::of_state(&system.model, x);
        self.reference.clear();
        for s in from..from + steps {
            self.reference.extend_from_slice(x);
            system
                .splitting
                .step(&model, &mut x[..dim], time.at(s), system.h, &mut self.work);
        }
    }

    /// Every vector of `v` around the recorded reference: each step's tangent map taken from
    /// the reference's state at its start, as `step_tangent` takes it along the orbit.
    fn tangent_steps(&mut self, v: &mut Soa, from: u64, steps: u64) -> Result<(), TangentError> {
        let (time, len, dim) = (self.system.time(), self.state_len(), self.system.dim());
        let lanes = v.lanes();
        self.vectors.resize(lanes * dim, 0.0);
        for (l, w) in self.vectors.chunks_exact_mut(dim).enumerate() {
            v.read_lane(l, w);
        }
        // The parameters are the same at every step of the reference.
        let Some(first) = self.reference.get(..len) else {
            return Ok(());
        };
        let model = WithParams::of_state(&self.system.model, first);
        for (k, s) in (from..from + steps).enumerate() {
            self.lane.clear();
            self.lane
                .extend_from_slice(&self.reference[k * len..][..dim]);
            self.system.splitting.step_tangent(
                &model,
                &mut self.lane,
                &mut self.vectors,
                time.at(s),
                self.system.h,
                &mut self.work,
            )?;
        }
        for (l, w) in self.vectors.chunks_exact(dim).enumerate() {
            v.write_lane(l, w);
        }
        Ok(())
    }
}
