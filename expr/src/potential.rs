//! A separable Hamiltonian `H = sum_j w_j p_j^2 / 2 + V(q)` whose potential is written as an
//! expression (`[model] name = "potential"`), compiled once to native code with its gradient and
//! Hessian-vector product derived symbolically.
//!
//! The expression is lowered to a DAG ([`crate::lower`]), differentiated there (reverse mode for
//! the gradient, forward mode over the gradient for `Hess V v`), and the potential, gradient and
//! Hessian-vector product are compiled by Cranelift, once per run: as scalar functions (the
//! one-orbit engine), and, at the batched kernel's first call, as whole splitting steps over
//! structure-of-arrays lanes, orbits and tangent vectors, with the force inline (a run never
//! builds them). Lattice sums that allow it are loops over their term
//! ([`crate::lattice`]): compile time and code size do not grow with `N`. The compiled
//! code performs exactly the reference evaluator's operations, so every path gives the same
//! bits.
//!
//! Time: `t` in the potential is the time (`V(q, t)`, a non-autonomous system), argument array
//! [`ARG_T`] of the scalar functions (`*_at` calls). A potential that reads it is always
//! unrolled (its lattice sums are not loops) and has no step kernels: the splittings step it
//! through the scalar functions, kick by kick at the time of each kick. One that does not
//! read it compiles to the same operations, loops and step kernels as it would without the
//! argument.

use std::collections::{BTreeMap, HashMap};
use std::io::Write as _;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex, Once, OnceLock, PoisonError};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use crate::graph::{Graph, NodeId, Tabulated};
use crate::jit::{Compiled, FunctionSpec, Layout, ScalarFnPtr, StepKernels, StepSpec};
use crate::lattice::{LatticeEvaluator, LatticePotential};
use crate::lower::{Boundary, Family, Lowered, ParamValue, Scope};
use crate::smooth::Smoothness;
use crate::{Span, diff, eval, jit, lower};

/// Everything that defines a potential model, validated except for the expression itself.
#[derive(Debug, Clone)]
pub struct PotentialDefinition {
    /// Degrees of freedom `N`.
    pub n: usize,
    /// The expression of `V(q)`.
    pub potential: String,
    pub params: BTreeMap<String, ParamValue>,
    /// `1 / m_i`, or `None` for unit masses.
    pub inverse_masses: Option<Vec<f64>>,
    pub boundary: Boundary,
    /// Tabulated functions by the name the expression calls them.
    pub tables: Vec<(String, Arc<dyn Tabulated>)>,
}

/// Why a potential could not be built: the expression (with line, column and caret) or the
/// compiler.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{0}")]
pub struct PotentialError(pub String);

// Function indices in the compiled module.
const POTENTIAL: usize = 0;
const GRADIENT: usize = 1;
const HESSIAN_VECTOR: usize = 2;

/// Argument arrays of the compiled functions: positions, and the direction of `Hess V v`.
use crate::lattice::{ARG_Q, ARG_V};

/// The time's argument array (one entry): beyond those of the lattice loops
/// ([`crate::lattice::ARG_SUM`] and below), so a graph holding a failed loop attempt's slot
/// inputs never mistakes one for the time.
pub const ARG_T: u8 = 6;

/// The lane parameters' argument array (a map's parameter axes: [`ParamValue::Lane`]s of this
/// argument, numbered from 0), after the time's.
pub const ARG_PARAMS: u8 = ARG_T + 1;

/// Argument arrays of a scalar function of the time: positions, direction, the unused lattice
/// ones, the time.
const ARGS: usize = ARG_T as usize + 1;

/// Argument arrays of a scalar call: as [`ARGS`], and the lane parameters (read only by a
/// potential that has some).
const CALL_ARGS: usize = ARG_PARAMS as usize + 1;

/// How the potential's derivatives are written.
enum Form {
    /// Every site's derivative a node of the graph (no lattice sum, or one that is not a loop).
    Unrolled {
        potential: NodeId,
        gradient: Vec<NodeId>,
        hessian_vector: Vec<NodeId>,
    },
    /// Loops over the terms of lattice sums.
    Lattice(Arc<LatticePotential>),
}

struct Inner {
    definition: PotentialDefinition,
    /// Shared with the background C build.
    graph: Arc<Graph>,
    origins: HashMap<NodeId, Span>,
    form: Form,
    smoothness: Smoothness,
    compiled: Compiled,
    /// Whole splitting steps over lanes by Cranelift: compiled at the batched kernel's first
    /// call (a run never calls it), its fallback while the C kernels build; why there are none
    /// if that failed (the generic step loops around the scalar functions run instead).
    steps: OnceLock<Result<StepKernels, String>>,
    /// The same steps in C (host-width vectors), built on a background thread from the
    /// batched kernel's first call (a `run` never pays for it) or loaded from the kernel
    /// cache.
    c_steps: Arc<CSteps>,
    /// The one-orbit hot path calls the machine code directly: the checked `Compiled::call`
    /// costs as much as the Henon-Heiles forces themselves. `new` checks that these read at
    /// most `N` entries of each argument, so slices of length `N` are enough.
    gradient_fn: ScalarFnPtr,
    hessian_vector_fn: ScalarFnPtr,
    /// Continuous second derivatives (the variational method applies).
    c2: bool,
    /// `V` reads the time.
    reads_time: bool,
    /// `P`: parameters read per call ([`ARG_PARAMS`]) instead of folded (a map's parameter
    /// axes). A potential with any is always unrolled and has no step kernels.
    lane_params: usize,
    /// `P` NaNs: the parameters of a call that gives none (`gradient`, `gradient_at`, ...),
    /// so such a call of a parametrized potential gives NaN, never reads a null pointer.
    no_params: Vec<f64>,
    build_time: Duration,
}

impl Drop for Inner {
    /// The last handle to the model is gone: a C build still running is not wanted any more.
    /// It is cancelled (the compiler killed, its files removed) rather than awaited, so a map
    /// that ends, or is interrupted, before the build never waits for a compiler; the next map
    /// of the same potential starts it again (a build that finished is in the cache). The build
    /// thread sees the cancel within milliseconds; one that does not end within
    /// [`CANCEL_GRACE`] (a compiler stuck where even SIGKILL waits, on a stalled network mount)
    /// is left behind rather than joined, and ends with the process.
    fn drop(&mut self) {
        self.c_steps.cancel.store(true, Ordering::Relaxed);
        self.c_steps.join_within(CANCEL_GRACE);
    }
}

/// Longest a dropped model waits for its cancelled C build's thread to end.
const CANCEL_GRACE: Duration = Duration::from_millis(500);

/// Where the C step kernels stand.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum CStepState {
    /// No batched kernel call yet.
    NotStarted,
    /// Compiling on the background thread.
    Building,
    /// Built (`cached`: loaded from the kernel cache) and in use.
    Ready { cached: bool },
    /// Switched off (`CHAOSCOPE_CC=none`).
    Off,
    /// The compiler is missing or failed; the Cranelift kernels run.
    Failed,
    /// Cancelled (the model was dropped during the build).
    Cancelled,
    /// The potential has no step kernels (it reads the time or lane parameters): its lanes are
    /// stepped through its scalar functions.
    Unused,
}

impl CStepState {
    pub fn name(&self) -> &'static str {
        match self {
            CStepState::NotStarted => "not-started",
            CStepState::Building => "building",
            CStepState::Ready { cached: false } => "compiled",
            CStepState::Ready { cached: true } => "loaded-from-cache",
            CStepState::Off => "off",
            CStepState::Failed => "failed",
            CStepState::Cancelled => "cancelled",
            CStepState::Unused => "unused",
        }
    }
}

/// [`ExpressionModel::c_step_status`].
#[derive(Debug, Clone, PartialEq)]
pub struct CStepStatus {
    pub state: CStepState,
    /// Why there are no C kernels (off, failed, cancelled).
    pub reason: Option<String>,
    /// From the batched kernel's first call to the C kernels being ready.
    pub ready_after: Option<Duration>,
    /// Batched kernel calls (one per window and batch) that ran each backend.
    pub cranelift_calls: u64,
    pub c_calls: u64,
}

/// Why there are no C step kernels.
#[derive(Debug)]
struct CUnavailable {
    kind: CStepState,
    reason: String,
}

/// The background build of the C step kernels, shared by the model and the build's thread.
struct CSteps {
    started: Once,
    started_at: OnceLock<Instant>,
    /// Set once, by the build thread (or by `start_c_build` when there is no thread).
    result: OnceLock<Result<StepKernels, CUnavailable>>,
    ready_after: OnceLock<Duration>,
    /// Set when the model is dropped: stops the compiler.
    cancel: AtomicBool,
    /// Joined by whoever waits for the result (under the lock, so a second waiter blocks
    /// until the first has joined and the result is set).
    worker: Mutex<Option<JoinHandle<()>>>,
    /// The test hook of [`ExpressionModel::step_kernels`].
    switch_after_calls: Option<u64>,
    calls: AtomicU64,
    cranelift_calls: AtomicU64,
    c_calls: AtomicU64,
}

impl CSteps {
    fn new(switch_after_calls: Option<u64>) -> Self {
        Self {
            started: Once::new(),
            started_at: OnceLock::new(),
            result: OnceLock::new(),
            ready_after: OnceLock::new(),
            cancel: AtomicBool::new(false),
            worker: Mutex::new(None),
            switch_after_calls,
            calls: AtomicU64::new(0),
            cranelift_calls: AtomicU64::new(0),
            c_calls: AtomicU64::new(0),
        }
    }

    /// The build thread's body. A failure (not a cancel) is said once on stderr, in one line
    /// naming the cause: the run goes on with the Cranelift kernels, which give the same
    /// results more slowly, and the user should know why it is slower than it could be.
    fn build(&self, graph: &Graph, source: &StepSource, cc: &jit::CCompiler) {
        let built = source.compile_c(graph, cc, &self.cancel);
        let result = match built {
            Ok(k) => {
                if let Some(t0) = self.started_at.get() {
                    let _ = self.ready_after.set(t0.elapsed());
                }
                Ok(k)
            }
            Err(jit::JitError::Cancelled) => Err(CUnavailable {
                kind: CStepState::Cancelled,
                reason: "the C kernel build was cancelled".into(),
            }),
            Err(e) => {
                // Not `eprintln!`, which panics when stderr is closed or full: a message that
                // cannot be shown is lost, the run goes on.
                let _ = writeln!(
                    std::io::stderr(),
                    "chaoscope: {e}; running without the C kernels (the Cranelift kernels for \
                     a map, the one-orbit path for a run: the same results, more slowly)"
                );
                Err(CUnavailable {
                    kind: CStepState::Failed,
                    reason: e.to_string(),
                })
            }
        };
        let _ = self.result.set(result);
    }

    fn join(&self) {
        let mut worker = self.worker.lock().unwrap_or_else(PoisonError::into_inner);
        if let Some(handle) = worker.take() {
            let _ = handle.join();
        }
    }

    /// Joins the build thread if it ends within `limit`; else leaves it (detached).
    fn join_within(&self, limit: Duration) {
        let mut worker = self.worker.lock().unwrap_or_else(PoisonError::into_inner);
        let Some(handle) = worker.take() else {
            return;
        };
        let start = Instant::now();
        while !handle.is_finished() && start.elapsed() < limit {
            std::thread::sleep(Duration::from_millis(1));
        }
        if handle.is_finished() {
            let _ = handle.join();
        }
    }
}

/// What the step kernels are built from.
#[derive(Clone)]
enum StepSource {
    Graph(StepSpec),
    Lattice(Arc<LatticePotential>),
}

impl StepSource {
    fn compile_cranelift(&self, graph: &Graph) -> Result<StepKernels, jit::JitError> {
        let options = jit::Options::default();
        match self {
            StepSource::Graph(spec) => jit::compile_steps(graph, spec, &options),
            StepSource::Lattice(l) => jit::compile_lattice_steps(graph, l, &options),
        }
    }

    fn compile_c(
        &self,
        graph: &Graph,
        cc: &jit::CCompiler,
        cancel: &AtomicBool,
    ) -> Result<StepKernels, jit::JitError> {
        match self {
            StepSource::Graph(spec) => jit::compile_steps_c_cancellable(graph, spec, cc, cancel),
            StepSource::Lattice(l) => {
                jit::compile_lattice_steps_c_cancellable(graph, l, cc, cancel)
            }
        }
    }
}

/// Fewest state-value steps (steps times `2N`) of a run that builds a potential's C kernels for
/// the fused pass of its small sets of tangent vectors: the build costs about 0.15-0.5
/// CPU-seconds (a compiler process, and its memory) once per chain and machine (later runs load
/// the kernels from the cache), the pass saves about 5 ns per site and step against the
/// one-orbit path (AMD EPYC Zen 5, the DKG chain of 1000 sites, one vector: 2.0 s against 0.9 s
/// per 2 * 10^8 site-steps), so below about 10^8 state values the build costs more than it
/// saves (such a run still loads the kernels if an earlier one left them in the cache). The
/// bits are the same either way.
pub const MIN_FUSED_WORK: u64 = 100_000_000;

/// A compiled potential model. Cheap to clone (shared compiled code).
#[derive(Clone)]
pub struct ExpressionModel(Arc<Inner>);

impl std::fmt::Debug for ExpressionModel {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ExpressionModel")
            .field("n", &self.0.definition.n)
            .field("potential", &self.0.definition.potential)
            .field("nodes", &self.0.graph.len())
            .finish()
    }
}

impl ExpressionModel {
    /// Parse, differentiate and compile.
    pub fn new(definition: PotentialDefinition) -> Result<Self, PotentialError> {
        let started = std::time::Instant::now();
        let n = definition.n;
        let mut graph = Graph::new();
        let tables: Vec<(String, u32)> = definition
            .tables
            .iter()
            .map(|(name, t)| (name.clone(), graph.add_table(t.clone())))
            .collect();
        let families = [Family {
            name: "q".to_string(),
            len: n,
            arg: ARG_Q,
            offset: 0,
        }];
        let scope = Scope {
            families: &families,
            params: &definition.params,
            tables: &tables,
            n,
            boundary: definition.boundary,
            time: Some(ARG_T),
        };
        let source = &definition.potential;
        let err = |e: &dyn std::fmt::Display| PotentialError(e.to_string());
        let lowered = lower::lower_with_loops(source, &scope, &mut graph).map_err(|e| err(&e))?;
        // Second derivatives only where they exist: a potential that is not C^2 is refused
        // for VM anyway, and its Hessian-vector product is not compiled.
        let c2 = lowered.smoothness.require(2, "vm").is_ok();
        let Lowered {
            root,
            smoothness,
            origins,
            sums,
        } = lowered;
        let had_sums = !sums.is_empty();
        let reads_time = graph
            .nodes()
            .iter()
            .any(|n| matches!(n, crate::graph::Node::Input { arg: ARG_T, .. }));
        let lane_params = lane_param_count(&definition.params)?;
        let lattice = if had_sums && !reads_time && lane_params == 0 {
            LatticePotential::new(&mut graph, root, sums, n, c2).map_err(|e| err(&e))?
        } else {
            None
        };
        let (graph, origins, form, compiled) = match lattice {
            Some(lattice) => {
                let compiled = jit::compile_lattice(&graph, &lattice, &jit::Options::default())
                    .map_err(|e| PotentialError(format!("compiling the potential: {e}")))?;
                (graph, origins, Form::Lattice(Arc::new(lattice)), compiled)
            }
            None => {
                // No sum is a loop, or the potential is not affine in its sums: every site's
                // derivative unrolled (lowered again without loops if some sum was one).
                let (mut graph, origins, potential) = if had_sums {
                    let mut graph = Graph::new();
                    for (_, t) in &definition.tables {
                        graph.add_table(t.clone());
                    }
                    let lowered = lower::lower(source, &scope, &mut graph).map_err(|e| err(&e))?;
                    (graph, lowered.origins, lowered.root)
                } else {
                    (graph, origins, root)
                };
                let gradient =
                    diff::gradient(&mut graph, potential, ARG_Q, n).map_err(|e| err(&e))?;
                let hessian_vector = if c2 {
                    diff::jacobian_vector(&mut graph, &gradient, ARG_Q, ARG_V)
                        .map_err(|e| err(&e))?
                } else {
                    vec![graph.constant(0.0); n]
                };
                let compiled = compile_unrolled(
                    &graph,
                    potential,
                    &gradient,
                    &hessian_vector,
                    reads_time,
                    lane_params,
                )?;
                let form = Form::Unrolled {
                    potential,
                    gradient,
                    hessian_vector,
                };
                (graph, origins, form, compiled)
            }
        };
        let switch_after_calls = std::env::var("CHAOSCOPE_C_KERNELS_AFTER_CALLS")
            .ok()
            .and_then(|v| v.trim().parse().ok());
        Ok(Self(Arc::new(Inner {
            gradient_fn: compiled.raw_scalar(GRADIENT),
            hessian_vector_fn: compiled.raw_scalar(HESSIAN_VECTOR),
            c2,
            reads_time,
            lane_params,
            no_params: vec![f64::NAN; lane_params],
            origins,
            smoothness,
            definition,
            graph: Arc::new(graph),
            form,
            compiled,
            steps: OnceLock::new(),
            c_steps: Arc::new(CSteps::new(switch_after_calls)),
            build_time: started.elapsed(),
        })))
    }

    /// Whether the lattice sums are loops (else every site's derivative is unrolled).
    pub fn has_loops(&self) -> bool {
        matches!(self.0.form, Form::Lattice(_))
    }

    pub fn definition(&self) -> &PotentialDefinition {
        &self.0.definition
    }

    /// Degrees of freedom `N`.
    pub fn dof(&self) -> usize {
        self.0.definition.n
    }

    /// Whether `V` reads the time `t` (a non-autonomous system: no step kernels, no loops).
    pub fn reads_time(&self) -> bool {
        self.0.reads_time
    }

    /// `V(q)` (at `t = 0`: the only value of a potential that does not read the time).
    #[inline]
    pub fn potential(&self, q: &[f64]) -> f64 {
        self.potential_at(q, 0.0)
    }

    /// `V(q, t)`.
    #[inline]
    pub fn potential_at(&self, q: &[f64], t: f64) -> f64 {
        self.potential_with(q, t, &self.0.no_params)
    }

    /// `P`: the parameters every call reads ([`ARG_PARAMS`], a map's parameter axes); 0 for a
    /// potential whose parameters are all constants.
    pub fn lane_params(&self) -> usize {
        self.0.lane_params
    }

    /// `V(q, t)` at the lane parameters `params` (`P` values; ignored when `P = 0`).
    ///
    /// # Panics
    /// If `params` has fewer than `P` entries.
    #[inline]
    pub fn potential_with(&self, q: &[f64], t: f64, params: &[f64]) -> f64 {
        let mut v = [0.0];
        if self.0.lane_params > 0 {
            let time = [t];
            let mut args: [&[f64]; CALL_ARGS] = [&[]; CALL_ARGS];
            args[ARG_Q as usize] = q;
            args[ARG_T as usize] = &time;
            args[ARG_PARAMS as usize] = params;
            self.0.compiled.call(POTENTIAL, &args, &mut v);
        } else if self.0.reads_time {
            let time = [t];
            let mut args: [&[f64]; ARGS] = [&[]; ARGS];
            args[ARG_Q as usize] = q;
            args[ARG_T as usize] = &time;
            self.0.compiled.call(POTENTIAL, &args, &mut v);
        } else {
            self.0.compiled.call(POTENTIAL, &[q], &mut v);
        }
        v[0]
    }

    /// `out = dV/dq (q)`.
    ///
    /// # Panics
    /// If `q` or `out` does not have `N` entries.
    #[inline]
    pub fn gradient(&self, q: &[f64], out: &mut [f64]) {
        self.gradient_at(q, 0.0, out)
    }

    /// `out = dV/dq (q, t)`.
    ///
    /// # Panics
    /// If `q` or `out` does not have `N` entries.
    #[inline]
    pub fn gradient_at(&self, q: &[f64], t: f64, out: &mut [f64]) {
        self.gradient_with(q, t, &self.0.no_params, out)
    }

    /// `out = dV/dq (q, t)` at the lane parameters `params` (`P` values).
    ///
    /// # Panics
    /// If `q` or `out` does not have `N` entries, or `params` fewer than `P`.
    #[inline]
    pub fn gradient_with(&self, q: &[f64], t: f64, params: &[f64], out: &mut [f64]) {
        let n = self.0.definition.n;
        assert!(q.len() == n && out.len() == n, "gradient of {n} sites");
        assert!(params.len() >= self.0.lane_params, "lane parameters");
        let time = [t];
        let mut args = [std::ptr::null(); CALL_ARGS];
        args[ARG_Q as usize] = q.as_ptr();
        args[ARG_T as usize] = time.as_ptr();
        args[ARG_PARAMS as usize] = params.as_ptr();
        // SAFETY: the function reads at most N entries of `q` and P of the parameters (checked
        // in `new`) and writes N outputs; the slices are that long; `out` is a `&mut`, so it
        // overlaps nothing; the code lives as long as `self.0.compiled`.
        unsafe { (self.0.gradient_fn)(args.as_ptr(), out.as_mut_ptr()) }
    }

    /// `out = Hess V(q) v`, or `false` (with `out` untouched) when `V` is not `C^2`.
    ///
    /// # Panics
    /// If `q`, `v` or `out` does not have `N` entries.
    #[inline]
    pub fn hessian_vector(&self, q: &[f64], v: &[f64], out: &mut [f64]) -> bool {
        self.hessian_vector_at(q, 0.0, v, out)
    }

    /// `out = Hess V(q, t) v` (second derivatives in `q`), or `false` as
    /// [`Self::hessian_vector`].
    ///
    /// # Panics
    /// If `q`, `v` or `out` does not have `N` entries.
    #[inline]
    pub fn hessian_vector_at(&self, q: &[f64], t: f64, v: &[f64], out: &mut [f64]) -> bool {
        self.hessian_vector_with(q, t, &self.0.no_params, v, out)
    }

    /// `out = Hess V(q, t) v` at the lane parameters `params` (`P` values), or `false` as
    /// [`Self::hessian_vector`].
    ///
    /// # Panics
    /// If `q`, `v` or `out` does not have `N` entries, or `params` fewer than `P`.
    #[inline]
    pub fn hessian_vector_with(
        &self,
        q: &[f64],
        t: f64,
        params: &[f64],
        v: &[f64],
        out: &mut [f64],
    ) -> bool {
        if !self.0.c2 {
            return false;
        }
        let n = self.0.definition.n;
        assert!(
            q.len() == n && v.len() == n && out.len() == n,
            "Hessian-vector product of {n} sites"
        );
        assert!(params.len() >= self.0.lane_params, "lane parameters");
        let time = [t];
        let mut args = [std::ptr::null(); CALL_ARGS];
        args[ARG_Q as usize] = q.as_ptr();
        args[ARG_V as usize] = v.as_ptr();
        args[ARG_T as usize] = time.as_ptr();
        args[ARG_PARAMS as usize] = params.as_ptr();
        // SAFETY: as in `gradient_with`, for the arguments `q`, `v`, the time and the
        // parameters.
        unsafe { (self.0.hessian_vector_fn)(args.as_ptr(), out.as_mut_ptr()) }
        true
    }

    /// Whether `V` has continuous second derivatives (the variational method applies).
    pub fn has_hessian(&self) -> bool {
        self.0.c2
    }

    /// Why the variational method cannot be used, naming the operation that limits the
    /// smoothness of `V`; `None` when it can.
    pub fn no_hessian_reason(&self) -> Option<String> {
        self.0
            .smoothness
            .require(2, "the variational method (vm)")
            .err()
    }

    /// `1 / m_i`, or `None` for unit masses.
    pub fn inverse_masses(&self) -> Option<&[f64]> {
        self.0.definition.inverse_masses.as_deref()
    }

    /// The potential energy of each site at `q` into `out` (`N` values): each term of a
    /// lattice sum shared equally by the sites it reads ([`LatticeEvaluator::site_potentials`],
    /// which defines it). An error saying why where the sites of `V`'s parts are not known: a
    /// potential without lattice sums compiled as loops, or one that reads the time.
    pub fn site_potentials(&self, q: &[f64], out: &mut [f64]) -> Result<(), String> {
        let n = self.0.definition.n;
        if q.len() != n || out.len() != n {
            return Err(format!(
                "{n} sites expected, got {} and {}",
                q.len(),
                out.len()
            ));
        }
        match &self.0.form {
            Form::Lattice(lattice) => {
                LatticeEvaluator::new(&self.0.graph, lattice).site_potentials(q, out)
            }
            Form::Unrolled { .. } if self.0.reads_time => Err(
                "V reads the time, so it is not compiled as lattice sums and its terms' sites \
                 are not known"
                    .to_string(),
            ),
            Form::Unrolled { .. } => Err(
                "V is not written as lattice sums compiled as loops (sum(i = a..b, term) with \
                 the term reading q[i + k] only, V affine in its sums), so which of its terms \
                 belongs to which site is not known"
                    .to_string(),
            ),
        }
    }

    /// The operation (with its line and column in the source) that makes `V` or a component
    /// of its gradient non-finite at `q`, if any; in a lattice loop, with the term it arose in.
    pub fn diagnose_non_finite(&self, q: &[f64]) -> Option<String> {
        self.diagnose_non_finite_at(q, 0.0)
    }

    /// [`Self::diagnose_non_finite`] at time `t`.
    pub fn diagnose_non_finite_at(&self, q: &[f64], t: f64) -> Option<String> {
        self.diagnose_non_finite_with(q, t, &self.0.no_params)
    }

    /// [`Self::diagnose_non_finite`] at time `t` and the lane parameters `params`.
    pub fn diagnose_non_finite_with(&self, q: &[f64], t: f64, params: &[f64]) -> Option<String> {
        let g = &self.0.graph;
        match &self.0.form {
            Form::Unrolled {
                potential,
                gradient,
                ..
            } => {
                let time = [t];
                let mut a: [&[f64]; CALL_ARGS] = [&[]; CALL_ARGS];
                a[ARG_Q as usize] = q;
                a[ARG_T as usize] = &time;
                a[ARG_PARAMS as usize] = params;
                if let Some(id) = eval::first_non_finite(g, &a, *potential) {
                    return Some(self.describe(id, &a, "in the potential"));
                }
                for (i, &out) in gradient.iter().enumerate() {
                    if let Some(id) = eval::first_non_finite(g, &a, out) {
                        return Some(self.describe(id, &a, &format!("in dV/dq{}", i + 1)));
                    }
                }
                None
            }
            Form::Lattice(lattice) => {
                let mut e = LatticeEvaluator::new(g, lattice);
                let (id, term) = e.first_non_finite(q)?;
                match term {
                    Some((s, i)) => {
                        let args = e.term_args(s, i, q);
                        let args: Vec<&[f64]> = args.iter().map(Vec::as_slice).collect();
                        Some(self.describe(id, &args, &format!("in the term i = {i} of a sum")))
                    }
                    None => {
                        let sums = e.sums(q);
                        let args: [&[f64]; 6] = [q, &[], &[], &[], &[], &sums];
                        Some(self.describe(id, &args, "in the potential"))
                    }
                }
            }
        }
    }

    /// Parse, differentiate and compile time of this model.
    pub fn build_time(&self) -> Duration {
        self.0.build_time
    }

    /// Nodes of the expression DAG (potential, gradient, Hessian-vector product).
    pub fn graph_nodes(&self) -> usize {
        self.0.graph.len()
    }

    pub fn smoothness(&self) -> &Smoothness {
        &self.0.smoothness
    }

    /// The compiled splitting steps over structure-of-arrays lanes (orbits and tangent
    /// vectors) that the batched kernel's next call runs. The first call starts building the
    /// C kernels on a background thread and returns the Cranelift ones; every call returns the
    /// C kernels once they are ready (the switch happens between two kernel calls, at a window
    /// or batch boundary), else the Cranelift ones. Both give the same bits, step by step, so
    /// the results do not depend on when (or whether) the switch happens.
    ///
    /// Test hook: `CHAOSCOPE_C_KERNELS_AFTER_CALLS=k` (read when the model is built) makes the
    /// first `k` calls run the Cranelift kernels and every later call wait for the C build,
    /// so a test can place the switch where it wants (`0`: only the C kernels).
    pub fn step_kernels(&self) -> Option<&StepKernels> {
        if self.0.reads_time || self.0.lane_params > 0 {
            // Kernels have no time or parameter input; such a potential is stepped through its
            // scalar functions.
            return None;
        }
        if UNCOUNTED.get() {
            return self.cranelift_step_kernels().ok();
        }
        let c = &self.0.c_steps;
        match self.c_kernels_for_this_call() {
            Some(Ok(k)) => {
                c.c_calls.fetch_add(1, Ordering::Relaxed);
                Some(k)
            }
            _ => {
                c.cranelift_calls.fetch_add(1, Ordering::Relaxed);
                self.cranelift_step_kernels().ok()
            }
        }
    }

    /// `n_steps` steps of the splitting (coefficients times `h`: `drift`, `kick`) for the orbit
    /// `x` (`2N`) and the tangent vectors `v` around it (a whole number of `2N`-value vectors),
    /// in one pass per stage vectorized along the sites, where the potential's C kernels have
    /// that kernel (lattice sums as loops; `jit::StepKernels::reference_tangent_steps`): the
    /// bits of the splitting's `step` and `step_tangent` through this model's scalar functions.
    /// False, with nothing stepped, while those kernels are not ready, where nothing started
    /// their build ([`Self::prepare_reference_tangent`], or a batched call), or where there is
    /// none: the caller then steps the orbit and vectors through the scalar functions, to the
    /// same bits. The test hook of [`Self::step_kernels`] places the switch here too.
    pub fn reference_tangent_steps(
        &self,
        x: &mut [f64],
        v: &mut [f64],
        n_steps: u64,
        drift: &[f64],
        kick: &[f64],
    ) -> bool {
        if self.0.reads_time || self.0.lane_params > 0 || !matches!(self.0.form, Form::Lattice(_)) {
            return false;
        }
        // Only a run that asked for the C kernels (`prepare_reference_tangent`: one long enough
        // to repay their build) uses them; a short one steps the one-orbit way and builds none.
        if UNCOUNTED.get() || !self.0.c_steps.started.is_completed() {
            return false;
        }
        match self.c_kernels_for_this_call() {
            Some(Ok(k)) if k.has_reference_tangent() => {
                self.0.c_steps.c_calls.fetch_add(1, Ordering::Relaxed);
                k.reference_tangent_steps(x, v, n_steps, drift, kick, self.inverse_masses())
            }
            _ => false,
        }
    }

    /// The C kernels if this kernel call is to run them: the build started (by the first
    /// call), its result once ready (`None` while it builds), or as the test hook of
    /// [`Self::step_kernels`] says (the first `k` calls none, every later one waiting for it).
    fn c_kernels_for_this_call(&self) -> Option<&Result<StepKernels, CUnavailable>> {
        let c = &self.0.c_steps;
        self.start_c_build();
        match c.switch_after_calls {
            None => c.result.get(),
            Some(k) if c.calls.fetch_add(1, Ordering::Relaxed) < k => None,
            Some(_) => Some(self.wait_c_build()),
        }
    }

    /// A run of `work` state-value steps (steps times `2N`) will call
    /// [`Self::reference_tangent_steps`]: the C kernels' build starts in the background if the
    /// run is long enough to repay it ([`MIN_FUSED_WORK`]) and the potential has that kernel.
    pub fn prepare_reference_tangent(&self, work: u64) {
        let has_kernel = !self.0.reads_time
            && self.0.lane_params == 0
            && self.0.c2
            && jit::CCompiler::from_env().is_some()
            && matches!(&self.0.form, Form::Lattice(l) if jit::fused_applies(l));
        if !has_kernel {
            return;
        }
        if work >= MIN_FUSED_WORK {
            self.start_c_build();
        } else {
            self.load_cached_c_kernels();
        }
    }

    /// A run too short to repay the C build still takes the kernels where an earlier run left
    /// them in the cache (the kernels of one potential serve every `N`: neither the source nor
    /// the cache key holds it), loaded here at once; a miss changes nothing (no build, and a
    /// later batched call may still start one), and neither does a cache that cannot be used
    /// (a build would say why).
    fn load_cached_c_kernels(&self) {
        let c = &self.0.c_steps;
        let Form::Lattice(lattice) = &self.0.form else {
            return;
        };
        if c.started.is_completed() {
            return;
        }
        let Some(cc) = jit::CCompiler::from_env() else {
            return;
        };
        let started = Instant::now();
        let kernels = match jit::load_lattice_steps_c(&self.0.graph, lattice, &cc) {
            Ok(kernels) => kernels,
            Err(e @ jit::JitError::CacheEntry(_)) => {
                // Not `eprintln!` (see `CSteps::build`).
                let _ = writeln!(
                    std::io::stderr(),
                    "chaoscope: {e}; running without the C kernels (the same results, more \
                     slowly)"
                );
                return;
            }
            Err(_) => return,
        };
        let mut kernels = Some(kernels);
        c.started.call_once(|| {
            let _ = c.started_at.set(started);
            let _ = c.ready_after.set(started.elapsed());
            let _ = c.result.set(Ok(kernels.take().expect("set once")));
        });
    }

    /// Whether the C kernels `k` were loaded from the kernel cache rather than compiled.
    pub fn c_step_kernels_cached(&self, k: &StepKernels) -> bool {
        matches!(k.backend(), jit::StepBackend::C { cached: true, .. })
    }

    /// The Cranelift step kernels (compiled at the first call); why there are none if their
    /// compilation failed (said once on stderr: the batched kernel then runs the generic step
    /// loops around the scalar functions, the same bits more slowly).
    pub fn cranelift_step_kernels(&self) -> Result<&StepKernels, &str> {
        self.0
            .steps
            .get_or_init(|| {
                self.step_source()
                    .compile_cranelift(&self.0.graph)
                    .map_err(|e| {
                        let e = format!("compiling the step kernels: {e}");
                        // Not `eprintln!`, which panics when stderr is closed or full (as for
                        // the C kernels above): a message that cannot be shown is lost.
                        let _ = writeln!(
                            std::io::stderr(),
                            "chaoscope: {e}; the batched kernel steps the compiled forces lane \
                             by lane instead (the same results, more slowly)"
                        );
                        e
                    })
            })
            .as_ref()
            .map_err(String::as_str)
    }

    /// The C step kernels, waiting for their build (started here if it was not): compiled or
    /// loaded from the cache by the compiler `CHAOSCOPE_CC` names (default `cc`; `none`
    /// switches them off); why there are none otherwise. A failure is not an error of the run:
    /// the Cranelift kernels compute the same bits, more slowly.
    pub fn c_step_kernels(&self) -> Result<&StepKernels, &str> {
        self.start_c_build();
        match self.wait_c_build() {
            Ok(k) => Ok(k),
            Err(e) => Err(&e.reason),
        }
    }

    /// Where the background C build stands, and how many batched kernel calls each backend ran.
    pub fn c_step_status(&self) -> CStepStatus {
        let c = &self.0.c_steps;
        if self.0.reads_time || self.0.lane_params > 0 {
            return CStepStatus {
                state: CStepState::Unused,
                reason: Some(
                    "the potential reads the time or lane parameters, which the step kernels \
                     do not take"
                        .into(),
                ),
                ready_after: None,
                cranelift_calls: 0,
                c_calls: 0,
            };
        }
        let state = match c.result.get() {
            _ if !c.started.is_completed() => CStepState::NotStarted,
            None => CStepState::Building,
            Some(Ok(k)) => CStepState::Ready {
                cached: self.c_step_kernels_cached(k),
            },
            Some(Err(e)) => e.kind.clone(),
        };
        CStepStatus {
            state,
            reason: c
                .result
                .get()
                .and_then(|r| r.as_ref().err())
                .map(|e| e.reason.clone()),
            ready_after: c.ready_after.get().copied(),
            cranelift_calls: c.cranelift_calls.load(Ordering::Relaxed),
            c_calls: c.c_calls.load(Ordering::Relaxed),
        }
    }

    /// A build of the C step kernels apart from the model's own, by the compiler of the
    /// environment (as [`Self::c_step_kernels`]) into the cache directory `cache_dir`: what
    /// `bench` times (an empty directory gives a full compilation).
    pub fn build_c_step_kernels(&self, cache_dir: &std::path::Path) -> Result<StepKernels, String> {
        let Some(cc) = jit::CCompiler::from_env() else {
            return Err("C kernels switched off (CHAOSCOPE_CC=none)".into());
        };
        let cc = jit::CCompiler {
            cache_dir: cache_dir.to_path_buf(),
            ..cc
        };
        self.step_source()
            .compile_c(&self.0.graph, &cc, &AtomicBool::new(false))
            .map_err(|e| e.to_string())
    }

    fn step_source(&self) -> StepSource {
        match &self.0.form {
            Form::Unrolled {
                gradient,
                hessian_vector,
                ..
            } => StepSource::Graph(StepSpec {
                n: self.0.definition.n,
                gradient: gradient.clone(),
                hessian_vector: Some(hessian_vector.clone()),
            }),
            Form::Lattice(l) => StepSource::Lattice(l.clone()),
        }
    }

    /// Starts the background C build once (or records why there is none).
    fn start_c_build(&self) {
        let c = &self.0.c_steps;
        c.started.call_once(|| {
            let _ = c.started_at.set(Instant::now());
            let Some(cc) = jit::CCompiler::from_env() else {
                let _ = c.result.set(Err(CUnavailable {
                    kind: CStepState::Off,
                    reason: "C kernels switched off (CHAOSCOPE_CC=none)".into(),
                }));
                return;
            };
            let (graph, source, shared) = (self.0.graph.clone(), self.step_source(), c.clone());
            let worker = std::thread::Builder::new()
                .name("c-step-kernels".into())
                .spawn(move || shared.build(&graph, &source, &cc));
            match worker {
                Ok(handle) => {
                    *c.worker.lock().unwrap_or_else(PoisonError::into_inner) = Some(handle)
                }
                Err(e) => {
                    let _ = c.result.set(Err(CUnavailable {
                        kind: CStepState::Failed,
                        reason: format!("cannot start the C kernel build thread: {e}"),
                    }));
                }
            }
        });
    }

    /// The build's outcome, waiting for it (the build must have been started).
    fn wait_c_build(&self) -> &Result<StepKernels, CUnavailable> {
        let c = &self.0.c_steps;
        if let Some(r) = c.result.get() {
            return r;
        }
        c.join();
        c.result.get_or_init(|| {
            Err(CUnavailable {
                kind: CStepState::Failed,
                reason: "the C kernel build stopped without a result".into(),
            })
        })
    }

    /// `'log' at line 1, column 9 of the potential gave NaN (what)`: node `id` evaluated with
    /// the argument arrays `args`.
    fn describe(&self, id: NodeId, args: &[&[f64]], what: &str) -> String {
        let mut value = [0.0];
        eval::Evaluator::new().eval(&self.0.graph, args, &[id], &mut value);
        let op = self.0.graph.operation_name(id);
        match self.0.origins.get(&id) {
            Some(span) => {
                let at = crate::ExprError::new(&self.0.definition.potential, *span, "");
                let (line, column) = (at.line, at.column);
                format!(
                    "{op} at line {line}, column {column} of the potential gave {} ({what})",
                    value[0]
                )
            }
            None => format!("{op} gave {} ({what})", value[0]),
        }
    }
}

thread_local! {
    /// Set by [`uncounted`] on this thread.
    static UNCOUNTED: std::cell::Cell<bool> = const { std::cell::Cell::new(false) };
}

/// Runs `f` with this thread's step-kernel calls served by the Cranelift kernels, neither
/// counted nor starting the C build. The resource estimate times a few steps of a map before
/// the map starts: those calls must not move the C-kernel switch (its test hook counts calls)
/// nor show in the map's call counts, and how many there are depends on the wall clock.
pub fn uncounted<R>(f: impl FnOnce() -> R) -> R {
    struct Reset(bool);
    impl Drop for Reset {
        fn drop(&mut self) {
            UNCOUNTED.set(self.0);
        }
    }
    let _reset = Reset(UNCOUNTED.replace(true));
    f()
}

/// The potential, its gradient and its Hessian-vector product as scalar functions (the
/// batched kernel runs the step kernels), each checked to read at most `N` entries of each
/// argument.
fn compile_unrolled(
    graph: &Graph,
    potential: NodeId,
    gradient: &[NodeId],
    hessian_vector: &[NodeId],
    reads_time: bool,
    lane_params: usize,
) -> Result<Compiled, PotentialError> {
    let n = gradient.len();
    // A potential of the time takes every argument array up to the time's (the lattice ones
    // unused), one with lane parameters up to theirs; one that reads neither keeps its one or
    // two.
    let args = |k: usize| {
        let count = if lane_params > 0 {
            CALL_ARGS
        } else if reads_time {
            ARGS
        } else {
            k
        };
        vec![Layout::Scalar; count]
    };
    let specs = [
        FunctionSpec {
            args: args(1),
            outputs: vec![potential],
        },
        FunctionSpec {
            args: args(1),
            outputs: gradient.to_vec(),
        },
        FunctionSpec {
            args: args(2),
            outputs: hessian_vector.to_vec(),
        },
    ];
    let options = jit::Options {
        lane_functions: false,
        ..jit::Options::default()
    };
    let compiled = jit::compile_with(graph, &specs, &options)
        .map_err(|e| PotentialError(format!("compiling the potential: {e}")))?;
    for (f, args) in [(GRADIENT, 1), (HESSIAN_VECTOR, 2)] {
        for a in 0..args {
            if compiled.arg_len(f, a) > n {
                return Err(PotentialError(format!(
                    "compiled function {f} reads {} entries of argument {a}, more than N = {n}",
                    compiled.arg_len(f, a)
                )));
            }
        }
        if lane_params > 0 && compiled.arg_len(f, ARG_PARAMS as usize) > lane_params {
            return Err(PotentialError(format!(
                "compiled function {f} reads {} lane parameters, more than P = {lane_params}",
                compiled.arg_len(f, ARG_PARAMS as usize)
            )));
        }
    }
    Ok(compiled)
}

/// `P`: how many parameters are [`ParamValue::Lane`]s; they must be entries `0..P` of
/// [`ARG_PARAMS`].
fn lane_param_count(params: &BTreeMap<String, ParamValue>) -> Result<usize, PotentialError> {
    let mut indices: Vec<u32> = Vec::new();
    for v in params.values() {
        if let ParamValue::Lane { arg, index, .. } = v {
            if *arg != ARG_PARAMS {
                return Err(PotentialError(format!(
                    "a lane parameter of a potential is read from argument {ARG_PARAMS}, not {arg}"
                )));
            }
            indices.push(*index);
        }
    }
    indices.sort_unstable();
    if indices.iter().enumerate().any(|(i, &j)| j as usize != i) {
        return Err(PotentialError(
            "lane parameters must be entries 0..P of their argument, each once".into(),
        ));
    }
    Ok(indices.len())
}

#[cfg(test)]
mod site_energy_tests {
    use super::*;

    fn model(n: usize, potential: &str, boundary: Boundary) -> ExpressionModel {
        ExpressionModel::new(PotentialDefinition {
            n,
            potential: potential.to_string(),
            params: BTreeMap::new(),
            inverse_masses: None,
            boundary,
            tables: Vec::new(),
        })
        .unwrap()
    }

    fn sites(m: &ExpressionModel, q: &[f64]) -> Result<Vec<f64>, String> {
        let mut out = vec![f64::NAN; q.len()];
        m.site_potentials(q, &mut out).map(|()| out)
    }

    /// Each term shared equally by the distinct sites it reads (values exact in binary: halves
    /// and quarters of small integers), a wall being no site; the rest to its one site.
    #[test]
    fn terms_are_shared_by_the_sites_they_read() {
        // A ring of 3: bonds (1,2) and (3,1) stretched by 1, each 1/2, half to each end.
        let ring = model(3, "sum(i = 1..N, (q[i+1] - q[i])^2/2)", Boundary::Periodic);
        assert_eq!(sites(&ring, &[1.0, 0.0, 0.0]).unwrap(), [0.5, 0.25, 0.25]);
        // Fixed walls: the bond to the left wall whole to site 1.
        let chain = model(2, "sum(i = 0..N, (q[i+1] - q[i])^2/2)", Boundary::Fixed);
        assert_eq!(sites(&chain, &[1.0, 0.0]).unwrap(), [0.75, 0.25]);
        // A sum's coefficient, and a rest reading one site (a pinned first site).
        let pinned = model(2, "0.5*sum(i = 1..N, q[i]^2) + q1^4", Boundary::Free);
        assert_eq!(sites(&pinned, &[1.0, 2.0]).unwrap(), [1.5, 2.0]);
        let v = pinned.potential(&[1.0, 2.0]);
        assert_eq!(v, 3.5);
    }

    #[test]
    fn parts_with_no_site_or_several_are_refused_with_the_reason() {
        let constant = model(2, "sum(i = 1..N, q[i]^2) + 1", Boundary::Free);
        let why = sites(&constant, &[1.0, 2.0]).unwrap_err();
        assert!(why.contains("constant part 1"), "{why}");
        let two = model(2, "sum(i = 1..N, q[i]^2) + q1*q2", Boundary::Free);
        let why = sites(&two, &[1.0, 2.0]).unwrap_err();
        assert!(why.contains("several sites (q1, q2)"), "{why}");
        let unrolled = model(2, "q1^2 + q2^2", Boundary::Free);
        let why = sites(&unrolled, &[1.0, 2.0]).unwrap_err();
        assert!(why.contains("not written as lattice sums"), "{why}");
    }
}
