//! The step kernels of an [`ExpressionModel`]: Cranelift's, compiled at the batched kernel's
//! first call, and the C ones, built on a background thread (or loaded from the kernel cache)
//! and switched to between two kernel calls once ready; the state of that build as the map's
//! report gives it, its cancellation when the model is dropped, and the calls a resource
//! estimate makes without moving the switch ([`uncounted`]).

use std::io::Write as _;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex, Once, OnceLock, PoisonError};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use super::{ExpressionModel, Form};
use crate::graph::Graph;
use crate::jit::{self, StepKernels, StepSpec};
use crate::lattice::LatticePotential;

/// Least work (state values times steps) of a run for which the Cranelift step kernels, with
/// their fused pass, are compiled (for the C build's time, or where there is none). Their
/// build (an Intel Xeon: 4 ms for a 1000-site chain, 0.2 s for a 128 x 128 square) costs at
/// most 4e-9 s per state value and step of such a run, half of the least the pass saves
/// (8e-9 s: the DKG chain at 1000 sites, one vector; 1.4e-8 s on the 2-D lattice at 64 x 64).
const MIN_CRANELIFT_FUSED_WORK: u64 = 50_000_000;

/// What [`ExpressionModel::prepare_reference_tangent`] may do about the C kernels.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum KernelBuild {
    /// Start their build in the background where the run repays it (the run itself).
    Background,
    /// Load them where the kernel cache has them, never build: a resource estimate times the
    /// pass its run will take without paying for a compiler (the Cranelift pass, slower, until
    /// a first run has left the C kernels in the cache).
    CacheOnly,
}

/// Longest a dropped model waits for its cancelled C build's thread to end.
pub(super) const CANCEL_GRACE: Duration = Duration::from_millis(500);

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
    /// Kernel calls that ran each backend: batched calls (one per window and batch) and calls
    /// of the fused one-orbit pass.
    pub cranelift_calls: u64,
    pub c_calls: u64,
}

/// Why there are no C step kernels.
#[derive(Debug)]
pub(super) struct CUnavailable {
    kind: CStepState,
    reason: String,
}

/// The background build of the C step kernels, shared by the model and the build's thread.
pub(super) struct CSteps {
    started: Once,
    started_at: OnceLock<Instant>,
    /// Set once, by the build thread (or by `start_c_build` when there is no thread).
    result: OnceLock<Result<StepKernels, CUnavailable>>,
    ready_after: OnceLock<Duration>,
    /// Set when the model is dropped: stops the compiler.
    pub(super) cancel: AtomicBool,
    /// Joined by whoever waits for the result (under the lock, so a second waiter blocks
    /// until the first has joined and the result is set).
    worker: Mutex<Option<JoinHandle<()>>>,
    /// A run long enough to repay the Cranelift step kernels' build asked for the fused
    /// one-orbit kernel ([`ExpressionModel::prepare_reference_tangent`]): theirs is compiled
    /// and runs wherever the C one is not ready (building, failed, cancelled, no compiler).
    cranelift_fused: AtomicBool,
    /// The test hook of [`ExpressionModel::step_kernels`].
    switch_after_calls: Option<u64>,
    calls: AtomicU64,
    cranelift_calls: AtomicU64,
    c_calls: AtomicU64,
}

impl CSteps {
    pub(super) fn new(switch_after_calls: Option<u64>) -> Self {
        Self {
            started: Once::new(),
            started_at: OnceLock::new(),
            result: OnceLock::new(),
            ready_after: OnceLock::new(),
            cancel: AtomicBool::new(false),
            worker: Mutex::new(None),
            cranelift_fused: AtomicBool::new(false),
            switch_after_calls,
            calls: AtomicU64::new(0),
            cranelift_calls: AtomicU64::new(0),
            c_calls: AtomicU64::new(0),
        }
    }

    /// The build thread's body. A failure (not a cancel) is said once on stderr, in one line
    /// naming the cause: the run goes on with the Cranelift kernels, which give the same
    /// results more slowly, and the user should know why it is slower than it could be.
    pub(super) fn build(&self, graph: &Graph, source: &StepSource, cc: &jit::CCompiler) {
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
                    "chaoscope: {e}; running without the C kernels (the Cranelift kernels: \
                     the same results, more slowly)"
                );
                Err(CUnavailable {
                    kind: CStepState::Failed,
                    reason: e.to_string(),
                })
            }
        };
        let _ = self.result.set(result);
    }

    pub(super) fn join(&self) {
        let mut worker = self.worker.lock().unwrap_or_else(PoisonError::into_inner);
        if let Some(handle) = worker.take() {
            let _ = handle.join();
        }
    }

    /// Joins the build thread if it ends within `limit`; else leaves it (detached).
    pub(super) fn join_within(&self, limit: Duration) {
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
pub(super) enum StepSource {
    Graph(StepSpec),
    Lattice(Arc<LatticePotential>),
}

impl StepSource {
    /// `fused_pass`: with a lattice's fused pass ([`jit::Options::fused_pass`]).
    pub(super) fn compile_cranelift(
        &self,
        graph: &Graph,
        fused_pass: bool,
    ) -> Result<StepKernels, jit::JitError> {
        let options = jit::Options {
            fused_pass,
            ..jit::Options::default()
        };
        match self {
            StepSource::Graph(spec) => jit::compile_steps(graph, spec, &options),
            StepSource::Lattice(l) => jit::compile_lattice_steps(graph, l, &options),
        }
    }

    pub(super) fn compile_c(
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

impl ExpressionModel {
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
    /// in one pass per stage vectorized along the sites, where the potential's step kernels have
    /// that kernel (lattice sums as loops; `jit::StepKernels::reference_tangent_steps`): the C
    /// ones once ready, else Cranelift's (while the C build runs, where it failed, or without a
    /// compiler) for a run long enough to repay their build; the
    /// bits of the splitting's `step` and `step_tangent` through this model's scalar functions.
    /// False, with nothing stepped, where neither applies (a run that did not ask through
    /// [`Self::prepare_reference_tangent`], a short run before C kernels are ready) or where
    /// there is no such kernel: the caller then steps the orbit and vectors through the scalar
    /// functions, to the same bits. The test hook of [`Self::step_kernels`] places the switch here too.
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
        let c = &self.0.c_steps;
        // The C kernels once ready, wherever a run started their build or found them in the
        // cache (`prepare_reference_tangent`); else (building, failed, cancelled, none)
        // Cranelift's, for a run long enough to repay their build; else the one-orbit way.
        // An uncounted call takes what is ready now, the test hook aside.
        let uncounted = UNCOUNTED.get();
        let ready_c = if c.started.is_completed() {
            let result = if uncounted {
                c.result.get()
            } else {
                self.c_kernels_for_this_call()
            };
            result.and_then(|r| r.as_ref().ok())
        } else {
            None
        };
        let (k, calls) = match ready_c {
            Some(k) => (k, &c.c_calls),
            None if c.cranelift_fused.load(Ordering::Relaxed) => {
                match self.cranelift_step_kernels() {
                    Ok(k) => (k, &c.cranelift_calls),
                    Err(_) => return false,
                }
            }
            None => return false,
        };
        if !k.has_reference_tangent() {
            return false;
        }
        if !uncounted {
            calls.fetch_add(1, Ordering::Relaxed);
        }
        k.reference_tangent_steps(x, v, n_steps, drift, kick, self.inverse_masses())
    }

    /// The C kernels if this kernel call is to run them: the build started (by the first
    /// call), its result once ready (`None` while it builds), or as the test hook of
    /// [`Self::step_kernels`] says (the first `k` calls none, every later one waiting for it).
    pub(super) fn c_kernels_for_this_call(&self) -> Option<&Result<StepKernels, CUnavailable>> {
        let c = &self.0.c_steps;
        self.start_c_build();
        match c.switch_after_calls {
            None => c.result.get(),
            Some(k) if c.calls.fetch_add(1, Ordering::Relaxed) < k => None,
            Some(_) => Some(self.wait_c_build()),
        }
    }

    /// A run of `work` state-value steps (steps times `2N`) will call
    /// [`Self::reference_tangent_steps`]: where the potential has that kernel, the Cranelift
    /// one is wanted if the run is long enough to repay its build ([`MIN_CRANELIFT_FUSED_WORK`]),
    /// and the C kernels' build starts in the background if it is long enough to repay theirs
    /// ([`super::min_fused_work`]) and `build` allows it; else they are loaded if in the cache.
    pub fn prepare_reference_tangent(&self, work: u64, build: KernelBuild) {
        let has_kernel = !self.0.reads_time
            && self.0.lane_params == 0
            && self.0.c2
            && matches!(&self.0.form, Form::Lattice(l) if jit::fused_applies(l));
        if !has_kernel {
            return;
        }
        // Cranelift prints the same plan, compiled at the first call in a fraction of a
        // second: the kernel while the C build runs, or where there is none.
        if work >= MIN_CRANELIFT_FUSED_WORK {
            self.0
                .c_steps
                .cranelift_fused
                .store(true, Ordering::Relaxed);
        }
        if jit::CCompiler::from_env().is_none() {
            return;
        }
        let side = match &self.0.form {
            Form::Lattice(l) => l.sums.first().and_then(|s| s.side),
            _ => None,
        };
        if build == KernelBuild::Background && work >= super::min_fused_work(side) {
            self.start_c_build();
        } else {
            // The estimate's load leaves saying why an entry is unusable to the run's.
            self.load_cached_c_kernels(build == KernelBuild::Background);
        }
    }

    /// A run too short to repay the C build still takes the kernels where an earlier run left
    /// them in the cache (the kernels of one potential serve every `N`: neither the source nor
    /// the cache key holds it), loaded here at once; a miss changes nothing (no build, and a
    /// later batched call may still start one), and neither does a cache that cannot be used
    /// (a build would say why; an unusable entry is named on stderr if `say_why`).
    pub(super) fn load_cached_c_kernels(&self, say_why: bool) {
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
            Err(e @ jit::JitError::CacheEntry(_)) if say_why => {
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
                    .compile_cranelift(
                        &self.0.graph,
                        self.0.c_steps.cranelift_fused.load(Ordering::Relaxed),
                    )
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

    pub(super) fn step_source(&self) -> StepSource {
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
    pub(super) fn start_c_build(&self) {
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
    pub(super) fn wait_c_build(&self) -> &Result<StepKernels, CUnavailable> {
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
}

thread_local! {
    /// Set by [`uncounted`] on this thread.
    static UNCOUNTED: std::cell::Cell<bool> = const { std::cell::Cell::new(false) };
}

/// Runs `f` with this thread's step-kernel calls neither counted nor starting the C build:
/// batched calls are served by the Cranelift kernels, fused passes by the kernels ready now.
/// The resource estimate times a few steps of a map or a run before it starts: those calls
/// must not move the C-kernel switch (its test hook counts calls) nor show in the call counts,
/// and how many there are depends on the wall clock.
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
