//! What a map point's batched methods need from a system, written once for every kind of system
//! that has a batched form: advance lanes of orbits (MPM), advance the reference orbit while
//! keeping where each step's tangent map is taken, advance lanes of tangent vectors along it
//! (VM), and measure a nearby orbit's separation as the system does.
//!
//! - [`SplittingKernel`]: a separable Hamiltonian's splitting, over the ISA-dispatched lane
//!   kernel ([`crate::batch::orbit_steps`] / [`crate::batch::tangent_steps`]).
//! - [`MapKernel`]: a discrete map's compiled lane functions ([`crate::batch::map_orbit_steps`]
//!   / [`crate::batch::map_tangent_steps`]); separations on the torus for wrapped coordinates.
//! - [`FlowKernel`]: a flow's compiled right-hand side (an `ode`'s `rhs`, or the vector field of
//!   a `hamiltonian`) stepped by a fixed-step explicit Runge-Kutta method
//!   ([`crate::batch::flow_orbit_steps`] / [`crate::batch::flow_tangent_steps`]).
//!
//! Both are lane by lane the bits of the one-orbit system's `step` / `step_tangent`, so `mpm.rs`
//! and `vm.rs` compute one point the same way for either and the batched map equals the engine
//! (`producer/tests/map_batch.rs`). Systems without a batched form (adaptive or implicit
//! Runge-Kutta steps, whose substeps or stage iterations differ per orbit, and hand-written
//! vector fields) run their points through the engine ([`super::one_orbit`]).

use chaoscope_expr::VectorFunction;

use crate::batch::{self, FlowScratch, Isa, LaneModel, Soa, StepCoeffs, record_reference_stages};
use crate::engine::RunError;
use crate::integrator::TangentError;
use crate::integrator::runge_kutta::Tableau;
use crate::system::{DynamicalSystem, Map, RkFlow};

/// A system's batched steps, as the map's MPM and VM kernels use them.
pub trait PointKernel {
    /// Advance every lane of `x` (orbits; rows are coordinates) by `steps` steps.
    fn orbit_steps(&mut self, x: &mut Soa, steps: u64);

    /// Advance the reference orbit `x` by `steps` steps exactly as the one-orbit system does,
    /// keeping where each step's tangent map is taken for [`PointKernel::tangent_steps`].
    fn reference_steps(&mut self, x: &mut [f64], steps: u64);

    /// Advance every lane of `v` (tangent vectors) along the steps of the last
    /// [`PointKernel::reference_steps`].
    fn tangent_steps(&mut self, v: &mut Soa, steps: u64) -> Result<(), RunError>;

    /// The separation `out = y - x` of a nearby orbit from the reference, as the system's
    /// [`DynamicalSystem::separation`] measures it: the plain difference unless the system has
    /// periodic coordinates.
    #[inline]
    fn separation(&self, y: &[f64], x: &[f64], out: &mut [f64]) {
        for ((o, a), b) in out.iter_mut().zip(y).zip(x) {
            *o = a - b;
        }
    }
}

/// A separable Hamiltonian's splitting over the lane kernel of the instruction set `isa`.
pub struct SplittingKernel<'a, M: LaneModel> {
    model: &'a M,
    coeffs: &'a StepCoeffs,
    isa: Isa,
    /// Positions before every kick of the last reference steps.
    stages: Vec<f64>,
    force: Vec<f64>,
}

impl<'a, M: LaneModel> SplittingKernel<'a, M> {
    pub fn new(model: &'a M, coeffs: &'a StepCoeffs, isa: Isa) -> Self {
        Self {
            model,
            coeffs,
            isa,
            stages: Vec::new(),
            force: vec![0.0; model.dof()],
        }
    }
}

impl<M: LaneModel> PointKernel for SplittingKernel<'_, M> {
    fn orbit_steps(&mut self, x: &mut Soa, steps: u64) {
        batch::orbit_steps(self.isa, self.model, self.coeffs, x, steps);
    }

    fn reference_steps(&mut self, x: &mut [f64], steps: u64) {
        record_reference_stages(
            self.model,
            self.coeffs,
            x,
            steps,
            &mut self.stages,
            &mut self.force,
        );
    }

    fn tangent_steps(&mut self, v: &mut Soa, steps: u64) -> Result<(), RunError> {
        batch::tangent_steps(self.isa, self.model, self.coeffs, &self.stages, v, steps);
        Ok(())
    }
}

/// A discrete map over its compiled lane functions (the SIMD is inside the compiled code, so
/// there is no instruction-set choice here).
pub struct MapKernel<'a> {
    map: &'a Map,
    /// States before every iteration of the last reference steps.
    stages: Vec<f64>,
    scratch: Vec<f64>,
}

impl<'a> MapKernel<'a> {
    pub fn new(map: &'a Map) -> Self {
        Self {
            map,
            stages: Vec::new(),
            scratch: Vec::new(),
        }
    }
}

impl PointKernel for MapKernel<'_> {
    fn orbit_steps(&mut self, x: &mut Soa, steps: u64) {
        batch::map_orbit_steps(self.map, x, steps, &mut self.scratch);
    }

    fn reference_steps(&mut self, x: &mut [f64], steps: u64) {
        batch::record_map_reference(self.map, x, steps, &mut self.stages);
    }

    fn tangent_steps(&mut self, v: &mut Soa, steps: u64) -> Result<(), RunError> {
        if batch::map_tangent_steps(self.map, &self.stages, v, steps, &mut self.scratch) {
            Ok(())
        } else {
            // Validation refuses VM for a map without a tangent; this is the same error the
            // engine would raise, should that ever be bypassed.
            Err(RunError::Tangent(TangentError::NoHessian(
                self.map
                    .no_tangent_reason()
                    .unwrap_or_else(|| "the map's Jacobian".into()),
            )))
        }
    }

    #[inline]
    fn separation(&self, y: &[f64], x: &[f64], out: &mut [f64]) {
        self.map.separation(y, x, out);
    }
}

/// A flow with a fixed-step explicit Runge-Kutta method and a compiled right-hand side.
pub struct FlowKernel<'a> {
    tableau: &'static Tableau,
    f: &'a VectorFunction,
    h: f64,
    /// Stage states of every step of the last reference steps.
    stages: Vec<f64>,
    scratch: FlowScratch,
}

impl<'a> FlowKernel<'a> {
    /// `None` when the flow has no batched form: adaptive steps (every orbit would choose its
    /// own substeps), implicit methods (per-orbit stage iterations), a hand-written field.
    pub fn new(flow: &'a RkFlow) -> Option<Self> {
        if flow.tolerances.is_some() {
            return None;
        }
        Some(Self {
            tableau: flow.method.kind.tableau()?,
            f: flow.field.compiled()?,
            h: flow.h,
            stages: Vec::new(),
            scratch: FlowScratch::default(),
        })
    }
}

impl PointKernel for FlowKernel<'_> {
    fn orbit_steps(&mut self, x: &mut Soa, steps: u64) {
        batch::flow_orbit_steps(self.tableau, self.f, self.h, x, steps, &mut self.scratch);
    }

    fn reference_steps(&mut self, x: &mut [f64], steps: u64) {
        batch::record_flow_reference(
            self.tableau,
            self.f,
            self.h,
            x,
            steps,
            &mut self.stages,
            &mut self.scratch,
        );
    }

    fn tangent_steps(&mut self, v: &mut Soa, steps: u64) -> Result<(), RunError> {
        if batch::flow_tangent_steps(
            self.tableau,
            self.f,
            self.h,
            &self.stages,
            v,
            steps,
            &mut self.scratch,
        ) {
            Ok(())
        } else {
            Err(RunError::Tangent(TangentError::NoHessian(
                self.f
                    .no_tangent_reason()
                    .unwrap_or_else(|| "the right-hand side's Jacobian".into()),
            )))
        }
    }
}

/// Whether `system` has a batched form here (see the module's list).
pub fn has_batched_form(system: &dyn DynamicalSystem) -> bool {
    system.as_discrete_map().is_some() || system.as_rk_flow().and_then(FlowKernel::new).is_some()
}

/// Runs `$body` with `$k` bound to the point kernel of `$spec`'s system on `$isa`, or evaluates
/// `$none` when the system has no batched form.
#[macro_export]
macro_rules! with_point_kernel {
    ($spec:expr, $isa:expr, |$k:ident| $body:expr, $none:expr) => {{
        let spec: &$crate::map::MapSpec = $spec;
        if let Some(batched) = spec.batched.as_ref() {
            let coeffs = &batched.coeffs;
            $crate::with_lane_model!(&batched.lanes, |m| {
                let mut kernel = $crate::map::kernel::SplittingKernel::new(m, coeffs, $isa);
                let $k = &mut kernel;
                $body
            })
        } else if let Some(map) = spec.run.system().as_discrete_map() {
            let mut kernel = $crate::map::kernel::MapKernel::new(map);
            let $k = &mut kernel;
            $body
        } else if let Some(mut kernel) = spec
            .run
            .system()
            .as_rk_flow()
            .and_then($crate::map::kernel::FlowKernel::new)
        {
            let $k = &mut kernel;
            $body
        } else {
            $none
        }
    }};
}
