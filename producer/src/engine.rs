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

use rayon::prelude::*;

use crate::integrator::{TangentError, Workspace};
use crate::renormalization::{self, RenormalizationError};
use chaoscope_schemas::run::{Method, Route, Sample, SchemeSample};

use crate::spec::RunSpec;

/// Below this many state values stepped in a window (steps x dimension x orbits, over every
/// task), the tasks of the window run one after another on the calling thread: waking rayon's
/// workers and gathering them again costs microseconds, more than such a window's work (a
/// Henon-Heiles run sampled at every step: 40), and the idle workers' spinning takes the core
/// a recorder needs. The bits are the same either way: each task is serial on its own data.
const PARALLEL_MIN_WORK: u64 = 1024;

/// A run that could not go on.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum RunError {
    #[error("the reference orbit escaped or became non-finite by t = {t} (|x| = {norm:e}){}",
        cause.as_ref().map(|c| format!(": {c}")).unwrap_or_default())]
    Escaped {
        t: f64,
        norm: f64,
        /// The operation that produced a non-finite value, where the system knows it.
        cause: Option<String>,
    },
    #[error("scheme '{scheme}', set {set}, t = {t}: {source}")]
    Renormalization {
        scheme: String,
        set: u32,
        t: f64,
        source: RenormalizationError,
    },
    #[error(transparent)]
    Tangent(#[from] TangentError),
}

/// Beyond this norm a state is treated as escaped: polynomial forces overflow soon after.
const ESCAPE_NORM: f64 = 1e100;

#[derive(Debug, Clone)]
enum Deviations {
    /// Tangent vectors and the task's own copy of the reference orbit.
    Variational { orbit: Vec<f64>, vectors: Vec<f64> },
    /// The `k` nearby orbits themselves.
    MultiParticle { orbits: Vec<f64> },
    /// A `route = "propagator"` VM scheme, every set at once: the images of the `2N` unit
    /// vectors under the tangent map since the scheme's last renormalization (column `j` is
    /// the image of `e_j`), the task's copy of the reference orbit, and each set's `k` vectors
    /// (`sets[s]`, updated only at renormalizations, as `M w` then renormalized).
    Propagated {
        orbit: Vec<f64>,
        basis: Vec<f64>,
        sets: Vec<Vec<f64>>,
    },
}

/// The `dim x dim` identity, column by column.
fn identity(dim: usize) -> Vec<f64> {
    let mut m = vec![0.0; dim * dim];
    set_identity(&mut m, dim);
    m
}

/// Makes `m` (`dim x dim`) the identity, in place.
fn set_identity(m: &mut [f64], dim: usize) {
    m.fill(0.0);
    m.iter_mut().step_by(dim + 1).for_each(|v| *v = 1.0);
}

/// One scheme's evolution of one set of deviation vectors (of every set, for the propagator
/// route): a `DeviationSet`.
#[derive(Debug, Clone)]
struct DeviationSet {
    scheme: usize,
    /// The set (the first one, for the propagator route).
    set: usize,
    deviations: Deviations,
    work: Workspace,
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
}

impl Engine {
    pub fn new(spec: RunSpec) -> Self {
        let dim = spec.dim();
        let mut tasks = Vec::with_capacity(spec.schemes().len() * spec.sets());
        for (si, scheme) in spec.schemes().iter().enumerate() {
            if scheme.route == Route::Propagator {
                tasks.push(DeviationSet {
                    scheme: si,
                    set: 0,
                    deviations: Deviations::Propagated {
                        orbit: spec.x0().to_vec(),
                        basis: identity(dim),
                        sets: spec
                            .directions()
                            .iter()
                            .map(|d| d.scaled(scheme.d0))
                            .collect(),
                    },
                    work: Workspace::new(),
                });
                continue;
            }
            for (set, dirs) in spec.directions().iter().enumerate() {
                let scaled = dirs.scaled(scheme.d0);
                let deviations = match scheme.method {
                    Method::Vm => Deviations::Variational {
                        orbit: spec.x0().to_vec(),
                        vectors: scaled,
                    },
                    Method::Mpm => Deviations::MultiParticle {
                        orbits: scaled
                            .chunks_exact(dim)
                            .flat_map(|d| spec.x0().iter().zip(d).map(|(x, d)| x + d))
                            .collect(),
                    },
                };
                tasks.push(DeviationSet {
                    scheme: si,
                    set,
                    deviations,
                    work: Workspace::new(),
                });
            }
        }
        let divergence = spec.system().divergence(spec.x0()).map(|d| (d, 0.0));
        Self {
            reference: spec.x0().to_vec(),
            spec,
            work: Workspace::new(),
            tasks,
            step: 0,
            next_seq: 0,
            divergence,
            plan: Vec::new(),
            plan_bounds: Vec::new(),
            parallel_min_work: PARALLEL_MIN_WORK,
        }
    }

    /// The mean divergence from t = 0 to step `step` (see [`Sample::mean_divergence`]).
    fn mean_divergence(&self, step: u64) -> f64 {
        match self.divergence {
            None => 0.0,
            Some((now, _)) if step == 0 => now,
            Some((_, integral)) => integral / self.spec.time_of(step),
        }
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

    /// The step of the next renormalization of any scheme (the run's last step at the latest).
    fn next_stop(&self) -> u64 {
        self.spec
            .schemes()
            .iter()
            .map(|s| (self.step / s.tau_steps + 1) * s.tau_steps)
            .min()
            .unwrap_or(self.spec.total_steps())
            .min(self.spec.total_steps())
    }

    fn renormalizes_at(&self, scheme: usize, step: u64) -> bool {
        step.is_multiple_of(self.spec.schemes()[scheme].tau_steps)
            || step == self.spec.total_steps()
    }

    /// Advance to the next renormalization time and return what it produced; `Ok(None)` once the
    /// run is complete. The first call returns the initial state (seq 0, t = 0) with every
    /// scheme's initial vectors and unit stretching.
    pub fn next_sample(&mut self) -> Result<Option<Sample>, RunError> {
        if self.next_seq == 0 {
            return Ok(Some(self.initial_sample()));
        }
        if self.step >= self.spec.total_steps() {
            return Ok(None);
        }
        let target = self.next_stop();
        let n_steps = target - self.step;
        let spec = &self.spec;
        let system = spec.system().as_ref();
        let last_good = self.reference.clone();
        let divergence_before = self.divergence;
        self.plan.clear();
        self.plan_bounds.clear();
        self.plan_bounds.push(0);
        for _ in 0..n_steps {
            system.step_reference(&mut self.reference, &mut self.plan, &mut self.work);
            self.plan_bounds.push(self.plan.len());
            if let Some((before, integral)) = &mut self.divergence {
                // Non-finite values are caught below, once per window.
                let after = system.divergence(&self.reference).unwrap_or(f64::NAN);
                *integral += match system.time() {
                    // The trapezoidal rule over the step: the mean of div f along the orbit.
                    crate::system::Time::Continuous { h } => 0.5 * h * (*before + after),
                    // ln |det DF| at the state the iteration starts from.
                    crate::system::Time::Discrete => *before,
                };
                *before = after;
            }
        }
        let norm = self.reference.iter().map(|v| v * v).sum::<f64>().sqrt();
        // A NaN norm counts as escaped too, and so does a state whose energy or divergence is
        // not finite (a potential or vector field undefined there: no NaN may reach an output).
        let invariant_finite = system
            .invariant(&self.reference)
            .is_none_or(|e| e.is_finite())
            && self
                .divergence
                .is_none_or(|(d, integral)| d.is_finite() && integral.is_finite());
        if norm.is_nan() || norm >= ESCAPE_NORM || !invariant_finite {
            self.divergence = divergence_before;
            return Err(self.escaped(last_good, target, norm));
        }
        let t = spec.time_of(target);

        let reference = &self.reference;
        let renorm: Vec<bool> = (0..spec.schemes().len())
            .map(|s| self.renormalizes_at(s, target))
            .collect();
        let plan = Plan {
            substeps: &self.plan,
            bounds: &self.plan_bounds,
        };
        let advance =
            |task: &mut DeviationSet| task.advance(spec, reference, &plan, renorm[task.scheme], t);
        // Work of this window: state values stepped, over every task's orbits.
        let work = n_steps
            .saturating_mul((spec.k() as u64 + 1) * spec.dim() as u64)
            .saturating_mul(self.tasks.len() as u64);
        let results: Vec<Result<Vec<SchemeSample>, RunError>> = if work < self.parallel_min_work {
            self.tasks.iter_mut().map(advance).collect()
        } else {
            self.tasks.par_iter_mut().map(advance).collect()
        };
        let mut schemes = Vec::new();
        for r in results {
            schemes.extend(r?);
        }
        self.step = target;
        // Systems without a conserved quantity report 0 (never NaN in an output).
        let energy = system.invariant(&self.reference).unwrap_or(0.0);
        let seq = self.next_seq;
        self.next_seq += 1;
        Ok(Some(Sample {
            seq,
            step: target,
            t,
            state: self.reference.clone(),
            energy,
            mean_divergence: self.mean_divergence(target),
            schemes,
        }))
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
            schemes,
        }
    }

    /// The error for an orbit found non-finite or escaped by step `target` (the end of the
    /// window, which is what the batched map kernel, testing once per window, reports too):
    /// steps again from the last finite state to the first step that leaves it, and names that
    /// step's time or iteration and, where the system knows it, the operation that failed.
    fn escaped(&self, last_good: Vec<f64>, target: u64, norm: f64) -> RunError {
        let system = self.spec.system().as_ref();
        let mut x = last_good;
        let mut work = Workspace::new();
        let mut cause = None;
        let mut step = self.step;
        let mut plan = Vec::new();
        while step < target {
            let before = x.clone();
            plan.clear();
            system.step_reference(&mut x, &mut plan, &mut work);
            step += 1;
            let at = format!("in the step to t = {}", self.spec.time_of(step));
            if x.iter().any(|v| !v.is_finite()) {
                cause = Some(
                    system
                        .diagnose_non_finite(&before)
                        .map_or(format!("the state became non-finite {at}"), |c| {
                            format!("{c} {at}")
                        }),
                );
                break;
            }
            if system.invariant(&x).is_some_and(|e| !e.is_finite())
                || system.divergence(&x).is_some_and(|d| !d.is_finite())
            {
                cause = Some(
                    system
                        .diagnose_non_finite(&x)
                        .map_or(format!("the system is not defined {at}"), |c| {
                            format!("{c} {at}")
                        }),
                );
                break;
            }
            let n = x.iter().map(|v| v * v).sum::<f64>().sqrt();
            if n >= ESCAPE_NORM {
                cause = Some(format!("|x| passed {ESCAPE_NORM:e} {at}"));
                break;
            }
        }
        RunError::Escaped {
            t: self.spec.time_of(target),
            norm,
            cause,
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
/// systems): `substeps[bounds[i]..bounds[i + 1]]` belong to step `i`.
struct Plan<'a> {
    substeps: &'a [f64],
    bounds: &'a [usize],
}

impl Plan<'_> {
    fn steps(&self) -> impl Iterator<Item = &[f64]> + '_ {
        self.bounds.windows(2).map(|b| &self.substeps[b[0]..b[1]])
    }
}

impl DeviationSet {
    fn advance(
        &mut self,
        spec: &RunSpec,
        reference: &[f64],
        plan: &Plan<'_>,
        renormalize: bool,
        t: f64,
    ) -> Result<Vec<SchemeSample>, RunError> {
        let system = spec.system().as_ref();
        let dim = spec.dim();
        match &mut self.deviations {
            Deviations::Propagated { orbit, basis, sets } => {
                for substeps in plan.steps() {
                    system.step_tangent_along(orbit, basis, substeps, &mut self.work)?;
                }
                debug_assert_eq!(orbit.as_slice(), reference);
                if !renormalize {
                    return Ok(Vec::new());
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
                set_identity(basis, dim);
                Ok(samples)
            }
            Deviations::Variational { orbit, vectors } => {
                for substeps in plan.steps() {
                    system.step_tangent_along(orbit, vectors, substeps, &mut self.work)?;
                }
                debug_assert_eq!(
                    orbit.as_slice(),
                    reference,
                    "variational copy of the orbit diverged"
                );
                if !renormalize {
                    return Ok(Vec::new());
                }
                Ok(vec![renormalized(spec, self.scheme, self.set, vectors, t)?])
            }
            Deviations::MultiParticle { orbits } => {
                for y in orbits.chunks_exact_mut(dim) {
                    for substeps in plan.steps() {
                        system.step_along(y, substeps, &mut self.work);
                    }
                }
                if !renormalize {
                    return Ok(Vec::new());
                }
                // Measured as the system measures separations (on the torus for angles).
                let mut separations = vec![0.0; orbits.len()];
                for (d, y) in separations
                    .chunks_exact_mut(dim)
                    .zip(orbits.chunks_exact(dim))
                {
                    system.separation(y, reference, d);
                }
                let sample = renormalized(spec, self.scheme, self.set, &mut separations, t)?;
                for (y, d) in orbits
                    .chunks_exact_mut(dim)
                    .zip(separations.chunks_exact(dim))
                {
                    for ((yi, di), xi) in y.iter_mut().zip(d).zip(reference) {
                        *yi = xi + di;
                    }
                }
                Ok(vec![sample])
            }
        }
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
    let s = &spec.schemes()[scheme];
    let separations = vectors.to_vec();
    let mut stretch = vec![0.0; spec.k()];
    renormalization::renormalize(vectors, spec.dim(), s.d0, s.orthonormalize, &mut stretch)
        .map_err(|source| RunError::Renormalization {
            scheme: s.name.clone(),
            set: set as u32,
            t,
            source,
        })?;
    Ok(SchemeSample {
        scheme: scheme as u32,
        set: set as u32,
        separations,
        stretch,
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
                .step(hamiltonian.model().as_ref(), &mut x, s.h(), &mut w);
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
