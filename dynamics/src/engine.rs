//! The run driver: one reference orbit, and around it every scheme's deviation sets.
//!
//! The engine is sans-io: callers pull [`Sample`]s one renormalization time at a time and decide
//! what to do with them (publish on the bus, analyze in process, compare in a test).
//!
//! Determinism: every (scheme, set) task is a serial computation on its own data; rayon only
//! decides which core runs it, and results are gathered in (scheme, set) order. The output is
//! therefore bit-identical for any thread count. The reference orbit is integrated once; each
//! variational task also carries its own copy (the tangent map needs the orbit's stage positions)
//! stepped by the same code, so the copies agree with the reference bit for bit.
//!
//! The deviation lanes of a system with a batched form (`DynamicalSystem::batched`) are stepped
//! by it, many lanes in one fused pass, the same bits as lane by lane (`engine/stepping.rs`).
//! A set of a few tangent vectors of a system with a fused one-orbit kernel
//! (`ReferenceTangent::steps`: a lattice potential) steps them with its copy of
//! the reference in one pass; the first such set *carries* the reference: its copy, stepped
//! first in each window, is the reference (the same bits as stepping the reference itself), so
//! the orbit is integrated once, not once more beside that set. A system whose tangent pass
//! computes the orbit anyway and chooses its substeps from the orbit alone
//! (`AdaptiveSteps::steps_reference_with_tangents`: Taylor's method) steps the first plain VM
//! set together with the reference, in the reference's own loop (its substeps planned there for
//! the other sets), and that set is not stepped again.

mod stepping;

use rayon::prelude::*;

use crate::batch::{PointKernel, Soa};
use crate::integrator::{TangentError, Workspace};
use crate::method::{self, DeviationMethod};
use crate::model::KernelBuild;
use crate::system::DynamicalSystem;
use crate::window::{self, Window};
use chaoscope_schemas::run::{Route, Sample, SchemeSample};

use crate::spec::RunSpec;
use stepping::{BatchedAlong, Stepping};

pub use crate::window::RunError;

/// Below this many state values stepped in a window (steps x dimension x orbits, over every
/// task), the tasks of the window run one after another on the calling thread: waking rayon's
/// workers and gathering them again costs microseconds, more than such a window's work (a
/// Henon-Heiles run sampled at every step: 40), and the idle workers' spinning takes the core
/// a recorder needs. The bits are the same either way: each task is serial on its own data.
const PARALLEL_MIN_WORK: u64 = 1024;

/// Why a recorded run cannot be resumed from a sample ([`Engine::resume`]).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{0}")]
pub struct ResumeError(pub String);

/// One scheme's evolution of one set of deviation vectors, or of every set of a scheme on the
/// window-propagator route.
struct DeviationSet {
    scheme: usize,
    /// The set (the first one, for the window propagator).
    set: usize,
    method: &'static dyn DeviationMethod,
    /// Per set: its `k` lanes (tangent vectors or nearby orbits). Window propagator: the `D`
    /// tangent vectors evolved from the identity since the scheme's last renormalization
    /// (lane `j` is the image of `e_j`: column `j` of the window's tangent propagator `M`).
    lanes: Soa,
    /// Window propagator only: each set's `k` vectors, updated at renormalizations as `M w`
    /// then renormalized.
    propagated: Option<Vec<Vec<f64>>>,
    work: Workspace,
    /// Lanes as rows, for the steps and the renormalization.
    rows: Vec<f64>,
    /// The copy of the reference its tangent lanes follow through a window (one-orbit and
    /// fused stepping): at the window's end the reference's state.
    orbit: Vec<f64>,
    /// How its lanes are stepped.
    stepping: Stepping,
}

pub struct Engine {
    spec: RunSpec,
    reference: Vec<f64>,
    work: Workspace,
    tasks: Vec<DeviationSet>,
    step: u64,
    next_seq: u64,
    /// The divergence at the reference state now, and its integral (flows: trapezoidal over
    /// the steps) or sum (maps) from t = 0; `None` for systems that conserve volume.
    divergence: Option<(f64, f64)>,
    /// Substeps the reference took in the current window (adaptive systems), flat, with the
    /// bounds of each step's share: what the deviation sets follow.
    plan: Vec<f64>,
    plan_bounds: Vec<usize>,
    /// [`PARALLEL_MIN_WORK`]; tests move it to take either path.
    parallel_min_work: u64,
    /// Per (scheme, set): the stretching factors of its renormalizations since the last sample
    /// (`[run] sample_every`), which the next sample carries.
    earlier_stretch: Vec<Vec<f64>>,
    /// The task whose copy of the reference is the reference (see the module documentation).
    carrier: Option<usize>,
    /// The VM set stepped with the reference in one pass
    /// ([`crate::system::AdaptiveSteps::steps_reference_with_tangents`]), and its vectors as rows.
    tangent_carrier: Option<usize>,
    carried: Vec<f64>,
}

impl Engine {
    /// The engine of `spec`, its deviation lanes stepped by the system's batched form where it
    /// has one.
    pub fn new(spec: RunSpec) -> Self {
        let stepping = Stepping::of(&spec);
        Self::with_stepping(spec, stepping)
    }

    /// The engine of `spec` with every deviation lane stepped one by one through the one-orbit
    /// system: the definition the batched kernels are tested against (a map point's
    /// reference, `map::one_orbit`); the same bits as [`Engine::new`], more slowly.
    pub fn one_orbit(spec: RunSpec) -> Self {
        Self::with_stepping(spec, Stepping::OneOrbit)
    }

    fn with_stepping(spec: RunSpec, stepping: Stepping) -> Self {
        let x0 = spec.x0().to_vec();
        let divergence = spec.system().divergence(&x0, 0.0).map(|d| (d, 0.0));
        // Every set starts from its directions at distance d0.
        let tasks = tasks(&spec, &x0, stepping, |scheme, set| {
            spec.directions()[set].scaled(spec.schemes()[scheme].d0)
        });
        prepare(&spec, &tasks, 0);
        let carrier = carrier(&tasks, divergence.is_some());
        Self {
            tangent_carrier: tangent_carrier(&spec, &tasks, carrier),
            carried: Vec::new(),
            carrier,
            reference: x0,
            spec,
            work: Workspace::new(),
            tasks,
            step: 0,
            next_seq: 0,
            divergence,
            plan: Vec::new(),
            plan_bounds: Vec::new(),
            parallel_min_work: PARALLEL_MIN_WORK,
            earlier_stretch: Vec::new(),
        }
    }

    /// The engine of a run recorded up to `sample`, at the point it was at just after emitting
    /// it: the next call of [`Engine::next_sample`] returns the sample after it, bit for bit
    /// what the uninterrupted run gives. Everything the engine carries from one window to the
    /// next is in a sample at which every scheme renormalized: the reference state, each set's
    /// separations (renormalized again here by the same function, to the same bits), the step,
    /// the sample number and the divergence sum; the random directions are drawn only at t = 0.
    /// `sample` must be one of this `spec`'s run (the caller checks the recording's header
    /// against it): what can still be wrong is said, never panicked on.
    pub fn resume(spec: RunSpec, sample: &Sample) -> Result<Self, ResumeError> {
        let stepping = Stepping::of(&spec);
        Self::resume_with_stepping(spec, sample, stepping)
    }

    /// [`Engine::resume`] with the lanes stepped by `stepping`.
    fn resume_with_stepping(
        spec: RunSpec,
        sample: &Sample,
        stepping: Stepping,
    ) -> Result<Self, ResumeError> {
        let dim = spec.dim();
        if let Some(Err(why)) = spec.system().adaptive().map(|a| a.resumable()) {
            return Err(ResumeError(why));
        }
        if sample.state.len() != dim || sample.step > spec.total_steps() {
            return Err(ResumeError(format!(
                "sample {} (step {}, {} state values) is not a sample of this run (dimension \
                 {dim}, {} steps)",
                sample.seq,
                sample.step,
                sample.state.len(),
                spec.total_steps()
            )));
        }
        // A sample of the resumed run too (with `sample_every`, a recording's end off its
        // multiples is not: the renormalizations before it belong to a later sample).
        let every = spec
            .schemes()
            .iter()
            .all(|s| sample.step.is_multiple_of(s.tau_steps))
            && (sample.step == 0 || spec.is_sample_step(sample.step));
        let sets = spec.schemes().len() * spec.sets();
        if !every || sample.schemes.len() != sets {
            return Err(ResumeError(format!(
                "sample {} (step {}) is not one at which every scheme renormalized, which a run \
                 resumes from",
                sample.seq, sample.step
            )));
        }
        let Some(next_seq) = sample.seq.checked_add(1) else {
            return Err(ResumeError(format!(
                "sample number {} has no next",
                sample.seq
            )));
        };
        // At t = 0 the run starts from its directions as they are (renormalizing them again
        // would change their last bits): the engine's own start, past its first sample.
        if sample.step == 0 {
            let mut engine = Self::with_stepping(spec, stepping);
            engine.next_seq = 1;
            return Ok(engine);
        }
        // The time of the step as the engine computes it, not as a file wrote it.
        let t = spec.time_of(sample.step);
        // Each (scheme, set)'s vectors as the engine left them: its separations renormalized.
        let mut renormalized = Vec::with_capacity(sets);
        for (i, s) in sample.schemes.iter().enumerate() {
            let (scheme, set) = (i / spec.sets(), i % spec.sets());
            if (s.scheme as usize, s.set as usize) != (scheme, set)
                || s.separations.len() != spec.k() * dim
            {
                return Err(ResumeError(format!(
                    "sample {}: separation set {i} is scheme {} set {} with {} values, where \
                     scheme {scheme} set {set} with {} values belongs",
                    sample.seq,
                    s.scheme,
                    s.set,
                    s.separations.len(),
                    spec.k() * dim
                )));
            }
            let mut vectors = s.separations.clone();
            window::renormalize(
                &spec,
                scheme,
                set,
                &mut vectors,
                &mut vec![0.0; spec.k()],
                t,
            )
            .map_err(|e| ResumeError(e.to_string()))?;
            renormalized.push(vectors);
        }
        let divergence = spec
            .system()
            .divergence(&sample.state, t)
            .map(|d| (d, sample.divergence_sum));
        let tasks = tasks(&spec, &sample.state, stepping, |scheme, set| {
            renormalized[scheme * spec.sets() + set].clone()
        });
        prepare(&spec, &tasks, sample.step);
        let carrier = carrier(&tasks, divergence.is_some());
        Ok(Self {
            tangent_carrier: tangent_carrier(&spec, &tasks, carrier),
            carried: Vec::new(),
            carrier,
            reference: sample.state.clone(),
            spec,
            work: Workspace::new(),
            tasks,
            step: sample.step,
            next_seq,
            divergence,
            plan: Vec::new(),
            plan_bounds: Vec::new(),
            parallel_min_work: PARALLEL_MIN_WORK,
            earlier_stretch: Vec::new(),
        })
    }

    /// The mean divergence from t = 0 to step `step` (see [`Sample::mean_divergence`]).
    fn mean_divergence(&self, step: u64) -> f64 {
        match self.divergence {
            None => 0.0,
            Some((now, _)) if step == 0 => now,
            Some((_, integral)) => integral / self.spec.time_of(step),
        }
    }

    /// The divergence's integral (or sum) from t = 0 to now (see [`Sample::divergence_sum`]).
    fn divergence_sum(&self) -> f64 {
        self.divergence.map_or(0.0, |(_, sum)| sum)
    }

    pub fn spec(&self) -> &RunSpec {
        &self.spec
    }

    pub fn total_steps(&self) -> u64 {
        self.spec.total_steps()
    }

    pub fn current_step(&self) -> u64 {
        self.step
    }

    /// The reference state now.
    pub fn state(&self) -> &[f64] {
        &self.reference
    }

    /// Advance to the next sample time (the next renormalization of any scheme, or with
    /// `[run] sample_every` the next multiple of it) and return what it produced; `Ok(None)`
    /// once the run is complete. The first call returns the initial state (seq 0, t = 0) with
    /// every scheme's initial vectors and unit stretching. The renormalizations between two
    /// samples give the next one their stretching factors (`SchemeSample::earlier_stretch`).
    pub fn next_sample(&mut self) -> Result<Option<Sample>, RunError> {
        if self.next_seq == 0 {
            return Ok(Some(self.initial_sample()));
        }
        loop {
            let Some(schemes) = self.next_window()? else {
                return Ok(None);
            };
            if self.spec.is_sample_step(self.step) {
                return Ok(Some(self.sample(schemes)));
            }
            let sets = self.spec.sets();
            if self.earlier_stretch.is_empty() {
                self.earlier_stretch = vec![Vec::new(); self.spec.schemes().len() * sets];
            }
            for s in schemes {
                self.earlier_stretch[s.scheme as usize * sets + s.set as usize]
                    .extend_from_slice(&s.stretch);
            }
        }
    }

    /// The sample at the current step, of the sets renormalized there (`schemes`), with the
    /// stretching factors of their renormalizations since the previous sample.
    fn sample(&mut self, mut schemes: Vec<SchemeSample>) -> Sample {
        let sets = self.spec.sets();
        for s in &mut schemes {
            if let Some(earlier) = self
                .earlier_stretch
                .get_mut(s.scheme as usize * sets + s.set as usize)
            {
                s.earlier_stretch = std::mem::take(earlier);
            }
        }
        let system = self.spec.system().as_ref();
        // Systems without a conserved quantity report 0 (never NaN in an output).
        let energy = system.invariant(&self.reference).unwrap_or(0.0);
        let seq = self.next_seq;
        self.next_seq += 1;
        Sample {
            seq,
            step: self.step,
            t: self.spec.time_of(self.step),
            state: self.reference.clone(),
            energy,
            mean_divergence: self.mean_divergence(self.step),
            divergence_sum: self.divergence_sum(),
            schemes,
        }
    }

    /// Advances to the next renormalization of any scheme; returns the sets renormalized
    /// there, `Ok(None)` once the run is complete.
    fn next_window(&mut self) -> Result<Option<Vec<SchemeSample>>, RunError> {
        let Some(w) = Window::after(&self.spec, self.step) else {
            return Ok(None);
        };
        let (target, t) = (w.end(), w.t);
        let spec = &self.spec;
        let system = spec.system().as_ref();
        // The window's start: where tangent lanes take the reference from.
        let last_good = self.reference.clone();
        let divergence_before = self.divergence;
        self.plan.clear();
        self.plan_bounds.clear();
        self.plan_bounds.push(0);
        if let Some(c) = self.carrier {
            // The carrier's copy is the reference: a fixed-step system with no divergence (no
            // substeps to plan, nothing to integrate along the orbit).
            self.plan_bounds.extend((self.step..target).map(|_| 0));
            let plan = Plan {
                substeps: &self.plan,
                bounds: &self.plan_bounds,
                from: self.step,
            };
            let carrier = &mut self.tasks[c];
            carrier.advance(spec, &last_good, &last_good, &plan, false, t, false)?;
            self.reference.copy_from_slice(&carrier.orbit);
        } else {
            if let Some(c) = self.tangent_carrier {
                let lanes = &self.tasks[c].lanes;
                let dim = lanes.rows();
                self.carried.resize(lanes.lanes() * dim, 0.0);
                for (lane, row) in self.carried.chunks_exact_mut(dim).enumerate() {
                    lanes.read_lane(lane, row);
                }
            }
            for step in self.step..target {
                let t = spec.time_of(step);
                // A tangent carrier is chosen only for a system whose adaptive steps take the
                // reference and its tangents in one pass (`tangent_carrier`).
                match (self.tangent_carrier, system.adaptive()) {
                    (Some(_), Some(adaptive)) => adaptive.step_reference_tangent(
                        &mut self.reference,
                        &mut self.carried,
                        t,
                        &mut self.plan,
                        &mut self.work,
                    )?,
                    _ => system.step_reference(
                        &mut self.reference,
                        t,
                        &mut self.plan,
                        &mut self.work,
                    ),
                }
                self.plan_bounds.push(self.plan.len());
                if let Some((before, integral)) = &mut self.divergence {
                    // Non-finite values are caught below, once per window.
                    let after = system
                        .divergence(&self.reference, spec.time_of(step + 1))
                        .unwrap_or(f64::NAN);
                    *integral += match system.time() {
                        // The trapezoidal rule over the step: the mean of div f along the orbit.
                        crate::system::Time::Continuous { h } => 0.5 * h * (*before + after),
                        // ln |det DF| at the state the iteration starts from.
                        crate::system::Time::Discrete => *before,
                    };
                    *before = after;
                }
            }
        }
        if let Err(e) =
            window::check_reference(spec, &last_good, &self.reference, &w, self.divergence)
        {
            self.divergence = divergence_before;
            return Err(e);
        }
        if let Some(c) = self.tangent_carrier {
            let lanes = &mut self.tasks[c].lanes;
            let dim = lanes.rows();
            for (lane, row) in self.carried.chunks_exact(dim).enumerate() {
                lanes.write_lane(lane, row);
            }
        }
        let reference = &self.reference;
        let renorm: Vec<bool> = spec.schemes().iter().map(|s| w.renormalizes(s)).collect();
        let plan = Plan {
            substeps: &self.plan,
            bounds: &self.plan_bounds,
            from: self.step,
        };
        let start = &last_good;
        let carrier = self.carrier;
        let tangent_carrier = self.tangent_carrier;
        let advance = |(i, task): (usize, &mut DeviationSet)| {
            let stepped = carrier == Some(i) || tangent_carrier == Some(i);
            task.advance(
                spec,
                start,
                reference,
                &plan,
                renorm[task.scheme],
                t,
                stepped,
            )
        };
        // Work of this window: state values stepped, over every task's orbits.
        let work = w
            .steps
            .saturating_mul((spec.k() as u64 + 1) * spec.dim() as u64)
            .saturating_mul(self.tasks.len() as u64);
        let results: Vec<Result<Vec<SchemeSample>, RunError>> = if work < self.parallel_min_work {
            self.tasks.iter_mut().enumerate().map(advance).collect()
        } else {
            self.tasks.par_iter_mut().enumerate().map(advance).collect()
        };
        let mut schemes = Vec::new();
        for r in results {
            schemes.extend(r?);
        }
        self.step = target;
        Ok(Some(schemes))
    }

    fn initial_sample(&mut self) -> Sample {
        self.next_seq = 1;
        let spec = &self.spec;
        let schemes = spec
            .schemes()
            .iter()
            .enumerate()
            .flat_map(|(si, scheme)| {
                spec.directions()
                    .iter()
                    .enumerate()
                    .map(move |(set, dirs)| SchemeSample {
                        scheme: si as u32,
                        set: set as u32,
                        separations: dirs.scaled(scheme.d0),
                        stretch: vec![1.0; spec.k()],
                        earlier_stretch: Vec::new(),
                    })
            })
            .collect();
        Sample {
            seq: 0,
            step: 0,
            t: 0.0,
            state: self.reference.clone(),
            energy: self.spec.e0(),
            mean_divergence: self.mean_divergence(0),
            divergence_sum: self.divergence_sum(),
            schemes,
        }
    }

    /// Run to the end, handing every sample to `sink`.
    pub fn run(mut self, mut sink: impl FnMut(Sample)) -> Result<(), RunError> {
        while let Some(s) = self.next_sample()? {
            sink(s);
        }
        Ok(())
    }
}

/// The substeps the reference orbit took in a window, step by step (empty for fixed-step
/// systems): `substeps[bounds[i]..bounds[i + 1]]` belong to step `from + i` of the run.
struct Plan<'a> {
    substeps: &'a [f64],
    bounds: &'a [usize],
    from: u64,
}

impl Plan<'_> {
    /// Each step's number and substeps.
    fn steps(&self) -> impl Iterator<Item = (u64, &[f64])> + '_ {
        (self.from..).zip(self.bounds.windows(2).map(|b| &self.substeps[b[0]..b[1]]))
    }
}

/// The engine's stepper as a [`PointKernel`]: every lane follows the steps (and the substeps of
/// adaptive systems) the reference took in the current window, lane by lane through the
/// one-orbit system; tangent lanes are carried along a copy of the reference from its state at
/// the window's start, stepped with them by the same code (so it agrees with the reference bit
/// for bit).
struct AlongReference<'a> {
    system: &'a dyn DynamicalSystem,
    plan: &'a Plan<'a>,
    /// The reference at the window's start.
    start: &'a [f64],
    work: &'a mut Workspace,
    rows: &'a mut Vec<f64>,
    /// The copy of the reference the tangent lanes follow.
    orbit: &'a mut Vec<f64>,
    /// Tangent lanes and their copy in one fused pass where the system has it now
    /// ([`Stepping::Fused`]).
    fused: bool,
}

impl PointKernel for AlongReference<'_> {
    // The plan knows its steps' numbers (`from`, `steps` are the window's, as the plan's).
    fn orbit_steps(&mut self, x: &mut Soa, _from: u64, _steps: u64) {
        let time = self.system.time();
        self.rows.resize(x.rows(), 0.0);
        for lane in 0..x.lanes() {
            x.read_lane(lane, self.rows);
            for (step, substeps) in self.plan.steps() {
                self.system
                    .step_along(self.rows, time.at(step), substeps, self.work);
            }
            x.write_lane(lane, self.rows);
        }
    }

    fn reference_steps(&mut self, x: &mut [f64], _from: u64, _steps: u64) {
        let time = self.system.time();
        for (step, substeps) in self.plan.steps() {
            self.system
                .step_along(x, time.at(step), substeps, self.work);
        }
    }

    fn tangent_steps(&mut self, v: &mut Soa, _from: u64, _steps: u64) -> Result<(), TangentError> {
        let time = self.system.time();
        let dim = v.rows();
        self.rows.resize(v.lanes() * dim, 0.0);
        for (lane, row) in self.rows.chunks_exact_mut(dim).enumerate() {
            v.read_lane(lane, row);
        }
        self.orbit.clear();
        self.orbit.extend_from_slice(self.start);
        let steps = self.plan.bounds.len() as u64 - 1;
        let fused = self.fused
            && self.plan.substeps.is_empty()
            && self
                .system
                .reference_tangent()
                .is_some_and(|r| r.steps(self.orbit, self.rows, self.plan.from, steps));
        if !fused {
            for (step, substeps) in self.plan.steps() {
                self.system.step_tangent_along(
                    self.orbit,
                    self.rows,
                    time.at(step),
                    substeps,
                    self.work,
                )?;
            }
        }
        for (lane, row) in self.rows.chunks_exact(dim).enumerate() {
            v.write_lane(lane, row);
        }
        Ok(())
    }

    #[inline]
    fn separation(&self, y: &[f64], x: &[f64], out: &mut [f64]) {
        self.system.separation(y, x, out);
    }
}

/// Every (scheme, set)'s task at reference state `x`, its deviation vectors (`k` of the run's
/// dimension, at their scheme's scale) given by `vectors(scheme index, set)`: at t = 0 the
/// sets' directions, on resuming the recorded separations renormalized.
fn tasks(
    spec: &RunSpec,
    x: &[f64],
    stepping: Stepping,
    vectors: impl Fn(usize, usize) -> Vec<f64>,
) -> Vec<DeviationSet> {
    let dim = spec.dim();
    let mut tasks = Vec::with_capacity(spec.schemes().len() * spec.sets());
    for (si, scheme) in spec.schemes().iter().enumerate() {
        let method = method::of(scheme.method);
        let task = |set, lanes, propagated, stepping| DeviationSet {
            scheme: si,
            set,
            method,
            lanes,
            propagated,
            work: Workspace::new(),
            rows: Vec::new(),
            orbit: Vec::new(),
            stepping,
        };
        if scheme.route == Route::WindowPropagator {
            let sets = (0..spec.sets()).map(|set| vectors(si, set)).collect();
            let stepping = stepping.for_lanes(dim);
            tasks.push(task(
                0,
                identity_lanes(method, x, stepping),
                Some(sets),
                stepping,
            ));
            continue;
        }
        let stepping = stepping.for_lanes(spec.k());
        for set in 0..spec.sets() {
            let mut lanes = stepping.lanes(dim, spec.k());
            window::restart(
                method,
                &mut lanes,
                0,
                x,
                &vectors(si, set),
                &mut vec![0.0; dim],
            );
            tasks.push(task(set, lanes, None, stepping));
        }
    }
    tasks
}

/// Tells the system that the run's steps from `from` on will go through its fused pass, where
/// some task steps that way: it builds what the pass needs if the run is long enough to repay
/// it.
fn prepare(spec: &RunSpec, tasks: &[DeviationSet], from: u64) {
    if tasks.iter().any(|t| t.stepping == Stepping::Fused) {
        let steps = spec.total_steps().saturating_sub(from);
        if let Some(pass) = spec.system().reference_tangent() {
            pass.prepare(
                steps.saturating_mul(spec.dim() as u64),
                KernelBuild::Background,
            );
        }
    }
}

/// Whether a run of `spec` will step its reference in the system's fused pass, carried by its
/// first set of tangent vectors ([`carrier`]): what the resource estimate times then.
pub(crate) fn carries_the_reference(spec: &RunSpec) -> bool {
    let divergence = spec.system().divergence(spec.x0(), 0.0).is_some();
    !divergence
        && Stepping::of(spec).for_lanes(spec.k()) == Stepping::Fused
        && spec
            .schemes()
            .iter()
            .any(|s| s.route == Route::PerSet && !method::of(s.method).lanes_are_orbits())
}

/// The task that carries the reference (see the module documentation): the first set of
/// tangent vectors stepped by the fused pass, where no divergence is integrated along the orbit.
fn carrier(tasks: &[DeviationSet], divergence: bool) -> Option<usize> {
    if divergence {
        return None;
    }
    tasks.iter().position(|t| {
        t.stepping == Stepping::Fused && !t.method.lanes_are_orbits() && t.propagated.is_none()
    })
}

/// The VM set a system that [`crate::system::AdaptiveSteps::steps_reference_with_tangents`] steps with the
/// reference: the first set of tangent vectors stepped one orbit at a time, where no task
/// carries the reference already.
fn tangent_carrier(
    spec: &RunSpec,
    tasks: &[DeviationSet],
    carrier: Option<usize>,
) -> Option<usize> {
    let one_pass = spec
        .system()
        .adaptive()
        .is_some_and(|a| a.steps_reference_with_tangents());
    if carrier.is_some() || !one_pass {
        return None;
    }
    tasks.iter().position(|t| {
        matches!(t.stepping, Stepping::OneOrbit | Stepping::Fused)
            && !t.method.lanes_are_orbits()
            && t.propagated.is_none()
    })
}

/// The window propagator's lanes: the identity, `e_j` in lane `j` (unit vectors: the window
/// propagator is VM's, and the tangent map is linear).
fn identity_lanes(method: &dyn DeviationMethod, x: &[f64], stepping: Stepping) -> Soa {
    let dim = x.len();
    let mut lanes = stepping.lanes(dim, dim);
    let mut identity = vec![0.0; dim * dim];
    identity.iter_mut().step_by(dim + 1).for_each(|e| *e = 1.0);
    window::restart(method, &mut lanes, 0, x, &identity, &mut vec![0.0; dim]);
    lanes
}

impl DeviationSet {
    /// Steps the lanes through the window `plan` from the reference's state `start` (unless
    /// `stepped`: the carrier, stepped before the others) and renormalizes them where
    /// `renormalize`, against the reference's state at the window's end `reference`.
    #[allow(clippy::too_many_arguments)]
    fn advance(
        &mut self,
        spec: &RunSpec,
        start: &[f64],
        reference: &[f64],
        plan: &Plan<'_>,
        renormalize: bool,
        t: f64,
        stepped: bool,
    ) -> Result<Vec<SchemeSample>, RunError> {
        let dim = spec.dim();
        let system = spec.system().as_ref();
        let mut batched = match self.stepping {
            Stepping::Batched { isa, .. } => BatchedAlong::new(system, isa, start),
            Stepping::OneOrbit | Stepping::Fused => None,
        };
        let mut along;
        let kernel: &mut dyn PointKernel = match &mut batched {
            Some(b) => b,
            None => {
                along = AlongReference {
                    system,
                    plan,
                    start,
                    work: &mut self.work,
                    rows: &mut self.rows,
                    orbit: &mut self.orbit,
                    fused: self.stepping == Stepping::Fused,
                };
                &mut along
            }
        };
        let steps = plan.bounds.len() as u64 - 1;
        if !stepped {
            self.method
                .advance(kernel, &mut self.lanes, plan.from, steps)?;
        }
        if !renormalize {
            return Ok(Vec::new());
        }
        let method = self.method;
        let lanes = &mut self.lanes;
        let Some(sets) = &mut self.propagated else {
            // Per set: the lanes' deviations, renormalized; the lanes restart from them.
            let mut separations = vec![0.0; spec.k() * dim];
            let mut lane = vec![0.0; dim];
            window::deviations(
                method,
                kernel,
                lanes,
                0,
                reference,
                &mut separations,
                &mut lane,
            );
            let sample = renormalized(spec, self.scheme, self.set, &mut separations, t)?;
            window::restart(method, lanes, 0, reference, &separations, &mut lane);
            return Ok(vec![sample]);
        };
        // Window propagator: M, column by column, applied to every set's vectors.
        let mut basis = vec![0.0; dim * dim];
        for (j, column) in basis.chunks_exact_mut(dim).enumerate() {
            lanes.read_lane(j, column);
        }
        let mut samples = Vec::with_capacity(sets.len());
        for (set, vectors) in sets.iter_mut().enumerate() {
            // M w, column by column of M: the same tangent map applied to w.
            let mut images = vec![0.0; vectors.len()];
            for (image, w) in images.chunks_exact_mut(dim).zip(vectors.chunks_exact(dim)) {
                for (column, wj) in basis.chunks_exact(dim).zip(w) {
                    for (x, m) in image.iter_mut().zip(column) {
                        *x += m * wj;
                    }
                }
            }
            *vectors = images;
            samples.push(renormalized(spec, self.scheme, set, vectors, t)?);
        }
        *lanes = identity_lanes(method, reference, self.stepping);
        Ok(samples)
    }
}

/// Renormalizes the deviation vectors of set `set` of scheme `scheme` in place; returns their
/// sample: the vectors as they were (the separations) and the stretching factors.
fn renormalized(
    spec: &RunSpec,
    scheme: usize,
    set: usize,
    vectors: &mut [f64],
    t: f64,
) -> Result<SchemeSample, RunError> {
    let separations = vectors.to_vec();
    let mut stretch = vec![0.0; spec.k()];
    window::renormalize(spec, scheme, set, vectors, &mut stretch, t)?;
    Ok(SchemeSample {
        scheme: scheme as u32,
        set: set as u32,
        separations,
        stretch,
        earlier_stretch: Vec::new(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::integrator::Integrator;
    use chaoscope_schemas::config::{DeviationsConfig, SchemeConfig, paper};

    /// Henon-Heiles from the paper's chaotic starting point `q = (0, -0.25)`, with `p1` solved
    /// from `energy`; k = 3, two sets.
    fn spec(schemes: Vec<SchemeConfig>, energy: f64, t_final: f64) -> RunSpec {
        let mut config = paper::henon_heiles(
            paper::HH_CHAOTIC_Q2,
            t_final,
            DeviationsConfig::random(3, 2, 4),
            schemes,
        );
        config.orbit.energy = Some(energy);
        RunSpec::from_config(&config).unwrap()
    }

    fn scheme(name: &str, method: &str, tau: f64) -> SchemeConfig {
        SchemeConfig::new(name, method, 1e-8, tau)
    }

    #[test]
    fn a_run_resumed_from_any_of_its_resumable_samples_goes_on_bit_for_bit() {
        // Taus 0.02 and 0.03 (2 and 3 steps): resumable every 6 steps, at t = 0 too (where the
        // directions are taken as they are, not renormalized again). QR and rescale, VM and MPM.
        let mut qr = scheme("mpm-qr", "mpm", 0.03);
        qr.orthonormalize = "qr".into();
        let make = || spec(vec![scheme("vm", "vm", 0.02), qr.clone()], 0.125, 0.6);
        let mut whole = Vec::new();
        Engine::new(make()).run(|x| whole.push(x)).unwrap();
        let resumable: Vec<usize> = (0..whole.len())
            .filter(|&i| whole[i].step % 6 == 0 && whole[i].step < 60)
            .collect();
        assert!(resumable.len() >= 5, "{resumable:?}");
        for i in resumable {
            let mut rest = Vec::new();
            Engine::resume(make(), &whole[i])
                .unwrap()
                .run(|x| rest.push(x))
                .unwrap();
            assert_eq!(rest, whole[i + 1..], "resumed from sample {i}");
        }
        // A sample where a scheme did not renormalize is not one to resume from.
        let off = whole.iter().find(|s| s.step % 6 != 0).unwrap();
        assert!(Engine::resume(make(), off).is_err());
    }

    #[test]
    fn small_windows_run_serially_to_the_same_bits() {
        // Sampled at every step (work 1 x 4 x 4 x 4 = 64, serial by default) and forced onto
        // rayon: each task is serial on its own data, so every value must match bit for bit.
        let run = |parallel_min_work| {
            let s = spec(
                vec![scheme("vm", "vm", 0.01), scheme("mpm", "mpm", 0.01)],
                0.125,
                2.0,
            );
            let mut engine = Engine::new(s);
            engine.parallel_min_work = parallel_min_work;
            let mut samples = Vec::new();
            engine.run(|x| samples.push(x)).unwrap();
            samples
        };
        let (serial, parallel) = (run(u64::MAX), run(0));
        assert_eq!(serial.len(), 201);
        assert_eq!(serial.len(), parallel.len());
        let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        for (a, b) in serial.iter().zip(&parallel) {
            assert_eq!(bits(&a.state), bits(&b.state));
            assert_eq!(a.schemes.len(), 4);
            for (x, y) in a.schemes.iter().zip(&b.schemes) {
                assert_eq!((x.scheme, x.set), (y.scheme, y.set));
                assert_eq!(bits(&x.separations), bits(&y.separations));
                assert_eq!(bits(&x.stretch), bits(&y.stretch));
            }
        }
    }

    #[test]
    fn reference_orbit_does_not_depend_on_the_schemes() {
        // Replay relies on this: other tau / d0 / methods, the very same trajectory bits.
        let collect = |s: RunSpec| {
            let mut states = std::collections::BTreeMap::new();
            Engine::new(s)
                .run(|x| drop(states.insert(x.step, x.state)))
                .unwrap();
            states
        };
        let a = collect(spec(vec![scheme("a", "vm", 1.0)], 0.125, 20.0));
        let b = collect(spec(
            vec![scheme("b", "mpm", 0.1), scheme("c", "vm", 2.5)],
            0.125,
            20.0,
        ));
        assert_eq!(a.len(), 21);
        // Multiples of 0.1 include those of 2.5.
        assert_eq!(b.len(), 201);
        for (step, state) in &a {
            assert_eq!(state, &b[step], "step {step}");
        }
        // And it is the plain integration of the initial condition.
        let s = spec(vec![scheme("a", "vm", 1.0)], 0.125, 20.0);
        let mut x = s.x0().to_vec();
        let mut w = Workspace::new();
        let hamiltonian = s.system().separable().unwrap();
        for _ in 0..2000 {
            hamiltonian
                .splitting()
                .step(hamiltonian.model().as_ref(), &mut x, 0.0, s.h(), &mut w);
        }
        assert_eq!(x, a[&2000]);
    }

    #[test]
    fn sample_stream_is_gapless_and_ends() {
        let mut e = Engine::new(spec(
            vec![scheme("a", "vm", 0.3), scheme("b", "mpm", 0.5)],
            0.125,
            1.0,
        ));
        let mut seen = Vec::new();
        while let Some(s) = e.next_sample().unwrap() {
            seen.push((
                s.seq,
                s.step,
                s.schemes.iter().map(|d| d.scheme).collect::<Vec<_>>(),
            ));
        }
        // Renormalizations at 30, 50, 60, 90 (a), 50, 100 (b), and the final step 100 for both.
        let steps: Vec<u64> = seen.iter().map(|s| s.1).collect();
        assert_eq!(steps, vec![0, 30, 50, 60, 90, 100]);
        assert!(seen.iter().enumerate().all(|(i, s)| s.0 == i as u64));
        assert_eq!(seen[2].2, vec![1, 1]);
        assert_eq!(seen[5].2, vec![0, 0, 1, 1]);
        assert!(e.next_sample().unwrap().is_none());
    }

    #[test]
    fn escaping_orbit_is_an_error_naming_the_time() {
        // Above H = 1/6 the Henon-Heiles potential opens and this orbit leaves for infinity.
        let mut e = Engine::new(spec(vec![scheme("a", "mpm", 1.0)], 0.3, 1000.0));
        let err = loop {
            match e.next_sample() {
                Ok(Some(_)) => continue,
                Ok(None) => panic!("an orbit at H = 0.3 should escape"),
                Err(err) => break err,
            }
        };
        assert!(
            matches!(err, RunError::Escaped { t, .. } if t > 0.0 && t < 1000.0),
            "{err}"
        );
        assert!(err.to_string().contains("escaped"), "{err}");
    }

    #[test]
    fn vm_and_mpm_start_from_the_same_directions() {
        let mut e = Engine::new(spec(
            vec![scheme("v", "vm", 1.0), scheme("m", "mpm", 1.0)],
            0.125,
            1.0,
        ));
        let s0 = e.next_sample().unwrap().unwrap();
        assert_eq!(s0.schemes.len(), 4);
        for set in 0..2 {
            let (v, m) = (&s0.schemes[set], &s0.schemes[2 + set]);
            assert_eq!(v.separations, m.separations);
            assert_eq!(v.stretch, vec![1.0; 3]);
        }
    }
}
