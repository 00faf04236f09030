//! How the engine steps its deviation lanes: through the system's batched form
//! ([`DynamicalSystem::batched`], the same kernel the phase-space maps run on) where the system
//! has one, else lane by lane along the reference's plan (`AlongReference`, in `engine.rs`).
//!
//! The batched form is, lane by lane, the bits of the one-orbit `step` / `step_tangent`
//! (`dynamics/tests/map_batch.rs`), so the choice changes no number of a run (the engine's tests
//! compare both paths sample by sample); what it changes is the speed: a compiled expression
//! potential steps whole splitting steps in one fused pass over its sites (its step kernels),
//! vectorized across lanes, instead of a gradient and a Hessian-vector product each writing a
//! buffer per lane and stage.
//!
//! Where the batched form applies is the system's decision, the one the maps take
//! (`batched(isa).is_some()`: fixed-step splittings of a potential that does not read the time,
//! discrete maps, fixed-step explicit Runge-Kutta flows of compiled fields); adaptive and implicit
//! methods, time-dependent potentials and hand-written vector fields keep the one-orbit path.
//! Whether it pays is the task's: the batched kernels step whole chunks of lanes (8 at least:
//! the `Soa`'s lane quantum, the C step kernels' block), so a task of fewer
//! than [`MIN_BATCHED_LANES`] lanes (a set of one or two vectors) keeps the one-orbit path,
//! where the chunk's padding would be most of the work.

use crate::batch::{Isa, PointKernel, Soa};
use crate::integrator::TangentError;
use crate::spec::RunSpec;
use crate::system::DynamicalSystem;

/// A window's tangent steps go in chunks of whole steps of about this many state values: each
/// chunk's reference steps record the position before every kick (half a state per kick, about
/// 450 KiB for ABA864's 7 kicks), which its tangent steps read back at once, so they stay in
/// L2 cache; and a long window of a long chain records no more than a chunk (a whole window of
/// 2000 steps over 4000 sites would be 450 MB). Chunking changes no bit: steps never merge.
/// (The unit tests take small chunks, so their short windows span several: the chunk size is
/// a matter of speed alone, the bits are the same.)
const CHUNK_STATE_VALUES: u64 = if cfg!(test) { 1 << 8 } else { 1 << 14 };

/// At least this many steps per chunk, so a very long chain's per-call costs (the tangent
/// kernel gathers and scatters its lanes) stay small beside the steps.
const MIN_CHUNK_STEPS: u64 = 4;

/// A task of fewer lanes than this steps them one by one even where the system has a batched
/// form. Measured on AMD EPYC (Zen 3, AVX2; `chaoscope produce --recorders 0`, one thread, CPU
/// time), one-orbit against batched per set of `k` vectors: the DKG chain of 1000 sites as an
/// expression (C step kernels), VM, k = 1: 1.88 s against 2.7 s per 1000 time units; k = 4:
/// 3.64 s against 2.35 s; k = 8: 6.19 s against 2.83 s. Lorenz by rk4 (compiled lane
/// functions), VM and MPM, 8 sets: k = 1: 1.87 s against 4.73 s, k = 2: 3.82 s against 5.43 s
/// (one-orbit about linear in k, batched nearly flat: even near k = 4). Henon-Heiles (built-in
/// lanes) gains at every k (k = 1: 7.9 s against 4.4 s; k = 4: 19.7 s against 4.5 s), but one
/// threshold at which no kind measured is slower serves them all.
pub(crate) const MIN_BATCHED_LANES: usize = 4;

/// How the deviation lanes of a run are stepped.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Stepping {
    /// Lane by lane through the one-orbit system, following the reference's steps and
    /// substeps: every system, and the definition the batched form reproduces.
    OneOrbit,
    /// As [`Stepping::OneOrbit`], but a set's tangent vectors step with their copy of the
    /// reference, which can carry the reference ([`DynamicalSystem::reference_tangent`]),
    /// in one fused pass where the system has one now
    /// ([`crate::system::ReferenceTangent::steps`]; the same bits): the few vectors the
    /// batched kernels would pad to a chunk.
    Fused,
    /// The system's batched form on the instruction set `isa`, for tasks of at least
    /// `min_lanes` lanes ([`Stepping::for_lanes`]); smaller tasks are [`Stepping::Fused`] where
    /// the system allows it (`fused`), else the one-orbit path.
    Batched {
        isa: Isa,
        min_lanes: usize,
        fused: bool,
    },
}

impl Stepping {
    /// The batched form where the system has one (its own decision, as for the maps) and the
    /// run's states are plain coordinates (a state that carries a map point's parameter values
    /// after them runs one orbit at a time); the one-orbit path otherwise.
    pub(crate) fn of(spec: &RunSpec) -> Self {
        let system = spec.system().as_ref();
        let isa = Isa::detect();
        let plain = spec.x0().len() == system.dim();
        let fused = plain && system.reference_tangent().is_some();
        if plain && system.batched(isa).is_some() {
            Stepping::Batched {
                isa,
                min_lanes: MIN_BATCHED_LANES,
                fused,
            }
        } else if fused {
            Stepping::Fused
        } else {
            Stepping::OneOrbit
        }
    }

    /// The stepping of a task of `lanes` lanes: the batched form only if they are enough, else
    /// the fused pass where the system has it.
    pub(crate) fn for_lanes(self, lanes: usize) -> Self {
        match self {
            Stepping::Batched { min_lanes, .. } if lanes >= min_lanes => self,
            Stepping::Batched { fused: true, .. } | Stepping::Fused => Stepping::Fused,
            _ => Stepping::OneOrbit,
        }
    }

    /// Storage for `lanes` lanes of `rows` values: padded to whole chunks for the batched
    /// kernels (the padding lanes hold zeros, which the kernels step and nobody reads), exact
    /// for the one-orbit path, which steps every lane it is given.
    pub(crate) fn lanes(self, rows: usize, lanes: usize) -> Soa {
        match self {
            Stepping::OneOrbit | Stepping::Fused => Soa::unpadded(rows, lanes),
            Stepping::Batched { .. } => Soa::new(rows, lanes),
        }
    }
}

/// The system's batched form as the engine's stepper: orbit lanes (MPM) through its orbit
/// kernel; tangent lanes (VM) along a copy of the reference from its state at the window's
/// start, stepped by the kernel's `reference_steps` (exactly the one-orbit steps, so the copy
/// agrees with the reference bit for bit) in chunks of whole steps, each chunk's recorded
/// stages then taken by the tangent kernel.
pub(crate) struct BatchedAlong<'a> {
    kernel: Box<dyn PointKernel + 'a>,
    /// The reference at the window's start.
    start: &'a [f64],
    /// The copy of the reference the tangent lanes follow.
    orbit: Vec<f64>,
}

impl<'a> BatchedAlong<'a> {
    /// `None` where the system has no batched form on `isa` (never for a `Stepping::Batched`
    /// chosen by [`Stepping::of`]).
    pub(crate) fn new(system: &'a dyn DynamicalSystem, isa: Isa, start: &'a [f64]) -> Option<Self> {
        Some(Self {
            kernel: system.batched(isa)?,
            start,
            orbit: Vec::new(),
        })
    }
}

impl PointKernel for BatchedAlong<'_> {
    fn orbit_steps(&mut self, x: &mut Soa, from: u64, steps: u64) {
        self.kernel.orbit_steps(x, from, steps);
    }

    fn reference_steps(&mut self, x: &mut [f64], from: u64, steps: u64) {
        self.kernel.reference_steps(x, from, steps);
    }

    fn tangent_steps(&mut self, v: &mut Soa, from: u64, steps: u64) -> Result<(), TangentError> {
        self.orbit.clear();
        self.orbit.extend_from_slice(self.start);
        let chunk = (CHUNK_STATE_VALUES / self.orbit.len().max(1) as u64).max(MIN_CHUNK_STEPS);
        let end = from + steps;
        let mut step = from;
        while step < end {
            let n = chunk.min(end - step);
            self.kernel.reference_steps(&mut self.orbit, step, n);
            self.kernel.tangent_steps(v, step, n)?;
            step += n;
        }
        Ok(())
    }

    #[inline]
    fn separation(&self, y: &[f64], x: &[f64], out: &mut [f64]) {
        self.kernel.separation(y, x, out);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::engine::Engine;
    use chaoscope_schemas::config::{DeviationsConfig, RunConfig, SchemeConfig, paper};
    use chaoscope_schemas::run::Sample;

    /// Every scheme kind the engine has: VM and MPM, rescaled and QR, per set and on the
    /// window propagator, renormalized every 12, 20, 25 (and 36) steps of `h`: windows of 1 to
    /// 12 steps, each of the longer ones stepped in several chunks (the tests' chunks are
    /// short). The window propagator only where the sets hold at least `D` vectors (which it
    /// requires).
    fn schemes(d0: f64, h: f64, propagator: bool) -> Vec<SchemeConfig> {
        let mut prop = SchemeConfig::new("prop", "vm", 1.0, 36.0 * h).with_orthonormalize("qr");
        prop.route = Some("propagator".into());
        let mut schemes = vec![
            SchemeConfig::new("vm", "vm", 1.0, 12.0 * h),
            SchemeConfig::new("vm-qr", "vm", 1.0, 20.0 * h).with_orthonormalize("qr"),
            SchemeConfig::new("mpm", "mpm", d0, 25.0 * h),
            SchemeConfig::new("mpm-qr", "mpm", d0, 20.0 * h).with_orthonormalize("qr"),
        ];
        if propagator {
            schemes.push(prop);
        }
        schemes
    }

    fn samples(engine: Engine) -> Vec<Sample> {
        let mut out = Vec::new();
        engine.run(|s| out.push(s)).unwrap();
        out
    }

    /// The run of `config` through the batched form (which the system must have) for every
    /// task, as the engine chooses (batched for tasks of enough lanes), and through the
    /// one-orbit path: every sample the same, bit for bit.
    fn batched_equals_one_orbit(config: &RunConfig, expect_samples: usize) {
        let spec = RunSpec::from_config(config).unwrap();
        let Stepping::Batched { isa, .. } = Stepping::of(&spec) else {
            panic!("{}: the batched form should apply", spec.system().name());
        };
        let all = Stepping::Batched {
            isa,
            min_lanes: 1,
            fused: false,
        };
        let batched = samples(Engine::with_stepping(spec.clone(), all));
        let one_orbit = samples(Engine::one_orbit(spec.clone()));
        let chosen = Engine::new(spec);
        let k = chosen.spec().k();
        assert!(chosen.tasks.iter().all(|t| {
            let lanes = if t.propagated.is_some() {
                t.lanes.rows()
            } else {
                k
            };
            matches!(t.stepping, Stepping::Batched { .. }) == (lanes >= MIN_BATCHED_LANES)
        }));
        assert_eq!(one_orbit.len(), expect_samples);
        same_bits(&batched, &one_orbit);
        same_bits(&samples(chosen), &one_orbit);
        // Not a run that stands still: the deviations grew or turned, so a lane stepped wrong
        // would show.
        let last = batched.last().unwrap();
        assert!(
            last.schemes
                .iter()
                .any(|s| s.stretch.iter().any(|&f| f != 1.0))
        );
    }

    fn same_bits(batched: &[Sample], one_orbit: &[Sample]) {
        assert_eq!(batched.len(), one_orbit.len());
        let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        for (a, b) in batched.iter().zip(one_orbit) {
            assert_eq!((a.seq, a.step), (b.seq, b.step));
            assert_eq!(bits(&a.state), bits(&b.state));
            assert_eq!(a.energy.to_bits(), b.energy.to_bits());
            assert_eq!(a.mean_divergence.to_bits(), b.mean_divergence.to_bits());
            assert_eq!(a.schemes.len(), b.schemes.len());
            for (x, y) in a.schemes.iter().zip(&b.schemes) {
                assert_eq!((x.scheme, x.set), (y.scheme, y.set));
                assert_eq!(
                    bits(&x.separations),
                    bits(&y.separations),
                    "step {}",
                    a.step
                );
                assert_eq!(bits(&x.stretch), bits(&y.stretch), "step {}", a.step);
            }
        }
    }

    /// The DKG chain of the examples, written as an expression, at 24 sites (a lattice sum
    /// compiled as loops: the fused site-step kernels), two sets of k = 3.
    #[test]
    fn dkg_expression_chain_batched_is_one_orbit_bit_for_bit() {
        let text = include_str!("../../../examples/models/dkg-single-site.toml")
            .replace("n = 1000\n", "n = 24\n")
            .replace("sites = 500,", "sites = 12,");
        let mut config = RunConfig::from_toml(&text).unwrap();
        config.integrator.t_final = 5.0;
        config.deviations = DeviationsConfig::random(4, 2, 7);
        config.schemes = schemes(1e-7, 0.05, false);
        batched_equals_one_orbit(&config, 16);
    }

    /// The DKG chain as an expression at 24 and 37 sites with sets of 1 to 3 vectors (fewer
    /// than the batched kernels take): their tangent vectors and the reference step in the fused
    /// pass along the sites, the first VM set carrying the reference; every sample the one-orbit
    /// path's, bit for bit, and so is a run resumed from a sample of it.
    #[test]
    fn dkg_expression_chain_fused_is_one_orbit_bit_for_bit() {
        for (n, k) in [(24usize, 1usize), (37, 2), (24, 3)] {
            let text = include_str!("../../../examples/models/dkg-single-site.toml")
                .replace("n = 1000\n", &format!("n = {n}\n"))
                .replace("sites = 500,", &format!("sites = {},", n / 2));
            let mut config = RunConfig::from_toml(&text).unwrap();
            // 320 steps: every scheme renormalizes at step 300 (12, 20 and 25 divide it).
            config.integrator.t_final = 16.0;
            config.deviations = DeviationsConfig::random(k, 2, 7);
            config.schemes = schemes(1e-7, 0.05, false);
            fused_is_one_orbit(&config, &format!("n = {n}, k = {k}"));
        }
    }

    /// The 2-D Klein-Gordon lattice of the examples on a 32 x 32 square (its sums loops along
    /// the rows) with one vector per set: the fused pass steps its rectangle of regular sites
    /// row by row and the sites at its edges one by one, bit for bit the one-orbit path.
    #[test]
    fn dkg_expression_square_fused_is_one_orbit_bit_for_bit() {
        let text = include_str!("../../../examples/models/dkg-square.toml")
            .replace("n = 21\n", "n = 32\n")
            .replace("sites = [10, 12]", "sites = [15, 17]");
        let mut config = RunConfig::from_toml(&text).unwrap();
        config.integrator.t_final = 16.0;
        config.deviations = DeviationsConfig::random(1, 2, 7);
        config.schemes = schemes(1e-7, 0.05, false);
        fused_is_one_orbit(&config, "32 x 32");
    }

    /// `config`'s run through the fused pass (its C kernels built first) against the one-orbit
    /// path: every sample, and a run resumed from the sample at step 300, bit for bit.
    fn fused_is_one_orbit(config: &RunConfig, what: &str) {
        use chaoscope_expr::potential::ExpressionModel;
        let spec = RunSpec::from_config(config).unwrap();
        // The C kernels built first (a run switches to them when they are ready: the
        // same bits either way), so the fused pass steps from the first window.
        let model = spec.system().separable().unwrap().model().clone();
        let expression = (model.as_ref() as &dyn std::any::Any)
            .downcast_ref::<ExpressionModel>()
            .unwrap();
        expression.c_step_kernels().unwrap();
        // A short run builds no C kernels for itself (it would not repay the build): they
        // were built above, as a long run builds them.
        let Stepping::Batched { isa, min_lanes, .. } = Stepping::of(&spec) else {
            panic!("{what}: the lattice has a batched form");
        };
        let fused_stepping = Stepping::Batched {
            isa,
            min_lanes,
            fused: true,
        };
        let engine = Engine::with_stepping(spec.clone(), fused_stepping);
        assert!(engine.tasks.iter().all(|t| t.stepping == Stepping::Fused));
        assert_eq!(
            engine.carrier,
            Some(0),
            "the first VM set carries the reference"
        );
        let calls = expression.c_step_status().c_calls;
        let fused = samples(engine);
        assert!(
            expression.c_step_status().c_calls > calls,
            "{what}: the fused kernel never ran"
        );
        let one_orbit = samples(Engine::one_orbit(spec.clone()));
        assert!(one_orbit.len() > 40);
        same_bits(&fused, &one_orbit);
        assert!(
            fused
                .last()
                .unwrap()
                .schemes
                .iter()
                .any(|s| s.stretch.iter().any(|&f| f != 1.0))
        );
        // Resumed from a sample at which every scheme renormalized.
        let from = one_orbit
            .iter()
            .position(|s| s.step == 300)
            .expect("a sample at step 300");
        let mut resumed = vec![];
        let engine =
            Engine::resume_with_stepping(spec.clone(), &one_orbit[from], fused_stepping).unwrap();
        assert_eq!(engine.carrier, Some(0));
        engine.run(|s| resumed.push(s)).unwrap();
        same_bits(&resumed, &one_orbit[from + 1..]);
    }

    /// The carrier where the system has no fused kernel (or before it is built): its copy of
    /// the reference, stepped by the one-orbit tangent steps, is the reference too, bit for bit
    /// (Henon-Heiles, with the fused stepping forced); and through the built-in FPUT chain's
    /// own fused pass (in Rust), which a run of it takes at any length.
    #[test]
    fn a_carrier_is_the_reference_bit_for_bit() {
        let hh = paper::henon_heiles(
            paper::HH_CHAOTIC_Q2,
            3.0,
            DeviationsConfig::random(2, 2, 4),
            schemes(1e-8, 0.01, false),
        );
        let fput = paper::fput_beta(
            &paper::FPUT_N5_CHAOTIC_Q,
            &paper::FPUT_N5_CHAOTIC_P,
            0.05,
            5.0,
            DeviationsConfig::random(3, 2, 5),
            schemes(1e-8, 0.05, false),
        );
        let fput_spec = RunSpec::from_config(&fput).unwrap();
        assert!(matches!(
            Stepping::of(&fput_spec),
            Stepping::Batched { fused: true, .. }
        ));
        for config in [hh, fput] {
            let spec = RunSpec::from_config(&config).unwrap();
            let Stepping::Batched { isa, min_lanes, .. } = Stepping::of(&spec) else {
                panic!("{}: a batched form", spec.system().name());
            };
            let forced = Stepping::Batched {
                isa,
                min_lanes,
                fused: true,
            };
            let engine = Engine::with_stepping(spec.clone(), forced);
            assert_eq!(engine.carrier, Some(0));
            same_bits(&samples(engine), &samples(Engine::one_orbit(spec)));
        }
    }

    #[test]
    fn henon_heiles_and_fput_batched_are_one_orbit_bit_for_bit() {
        let hh = paper::henon_heiles(
            paper::HH_CHAOTIC_Q2,
            3.0,
            DeviationsConfig::random(4, 2, 4),
            schemes(1e-8, 0.01, true),
        );
        batched_equals_one_orbit(&hh, 45);
        let fput = paper::fput_beta(
            &paper::FPUT_N5_CHAOTIC_Q,
            &paper::FPUT_N5_CHAOTIC_P,
            0.05,
            5.0,
            DeviationsConfig::random(4, 3, 5),
            schemes(1e-8, 0.05, true),
        );
        batched_equals_one_orbit(&fput, 16);
        // Henon-Heiles written as an expression (unrolled, not a lattice sum).
        let mut expr =
            RunConfig::from_toml(include_str!("../../../examples/models/henon-heiles.toml"))
                .unwrap();
        expr.integrator.t_final = 3.0;
        expr.deviations = DeviationsConfig::random(3, 2, 4);
        expr.schemes = schemes(1e-8, 0.01, true);
        batched_equals_one_orbit(&expr, 45);
    }

    /// The other kinds with a batched form: a fixed-step Runge-Kutta flow (its divergence
    /// summed beside) and a discrete map (separations on the torus).
    #[test]
    fn flows_and_maps_batched_are_one_orbit_bit_for_bit() {
        let mut lorenz =
            RunConfig::from_toml(include_str!("../../../examples/models/lorenz.toml")).unwrap();
        lorenz.integrator.t_final = 1.0;
        lorenz.integrator.method = "rk4".into();
        lorenz.deviations = DeviationsConfig::random(3, 2, 4);
        lorenz.schemes = schemes(1e-8, 0.01, true);
        batched_equals_one_orbit(&lorenz, 16);
        let mut map =
            RunConfig::from_toml(include_str!("../../../examples/models/standard-map.toml"))
                .unwrap();
        map.integrator.t_final = 300.0;
        map.deviations = DeviationsConfig::random(2, 2, 4);
        map.schemes = schemes(1e-8, 1.0, true);
        batched_equals_one_orbit(&map, 45);
    }

    /// Adaptive steps have no batched form (each orbit would choose its substeps): the engine
    /// keeps the one-orbit path, which follows the reference's plan.
    #[test]
    fn adaptive_flows_keep_the_one_orbit_path() {
        let mut lorenz =
            RunConfig::from_toml(include_str!("../../../examples/models/lorenz.toml")).unwrap();
        lorenz.integrator.t_final = 1.0;
        lorenz.integrator.rtol = Some(1e-10);
        lorenz.integrator.atol = Some(1e-12);
        let spec = RunSpec::from_config(&lorenz).unwrap();
        assert_eq!(Stepping::of(&spec), Stepping::OneOrbit);
    }
}
