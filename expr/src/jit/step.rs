//! Splitting step kernels: whole steps of a symplectic splitting of a separable Hamiltonian
//! `H = sum_j w_j p_j^2 / 2 + V(q)` in native code, with the force (or the tangent force
//! `Hess V(q) dq`) emitted inline from the graph.
//!
//! The lane functions of the parent module cost one call and a round trip of every row through
//! memory per stage; these kernels run the step and stage loops themselves:
//!
//! ```text
//! for step in 0..n_steps
//!     for i in 0..n_kicks                     (stage loop)
//!         [tangent: the uniform part of Hess V at the stage's reference position, once]
//!         for each block of 2 or 4 lanes      (block loop)
//!             drift  q_j += (drift[i] w_j) p_j     (row j drifted just before its first use)
//!             force  g = grad V(q)                 (the graph's nodes, inline)
//!             kick   p_j -= kick[i] g_j            (as soon as g_j is known)
//!     for each block: q_j += (drift[n_kicks] w_j) p_j
//! ```
//!
//! Stage-outer, block-inner: the blocks of one stage are independent dependency chains that the
//! CPU overlaps (a block's own drift-force-kick chain is long, and Cranelift's x86-64 vectors
//! have two lanes), the tangent kernel's per-stage coefficients are computed once for all
//! lanes, and the state stays in the caller's rows (a chunk sized for L1), so nothing is live
//! across the loops but a few pointers and coefficients whatever `N` is (an FPUT chain of 1001
//! sites compiles as fast as its gradient).
//!
//! Every lane performs exactly the operations of the generic `LaneHamiltonian::orbit_steps` /
//! `tangent_steps` loops: `q + ch * p` (unit masses) or `q + (ch * w_j) * p`, the graph's
//! operations as `cranelift::emit_vector` emits them, and `p - dh * g`; so the kernels are
//! bit-identical to `Graph::apply_*` step by step, and never emit a fused multiply-add.

//!
//! This file is the facade: what a compiled set of kernels is ([`StepKernels`]) and how it is
//! built, by Cranelift ([`super::cranelift::step`], at once) or by the system C compiler
//! ([`super::c`], cached); both compile the same [`StepSpec`] ([`super::step_spec`]).

use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::AtomicBool;
use std::time::Duration;

use super::c::{self as c_step, C_BLOCK_LANES, CCompiler, CFusedFn, CKernels};
use super::cranelift::step::{self as step_cranelift, CraneliftKernels};
use super::step_spec::StepSpec;
use super::{AllocationWork, JitError, Options};
use crate::graph::{Graph, Tabulated};

/// The compiled step kernels of one [`compile_steps`] or [`compile_steps_c`] call (owns the
/// code and the tables it calls into). `Send + Sync` for the same reasons as
/// [`super::Compiled`]; a loaded C library is `Send + Sync` too.
pub struct StepKernels {
    code: Code,
    n: usize,
    /// Lanes per block of each kernel (orbit, tangent).
    blocks: [usize; 2],
    /// Values of working memory each call needs per lane of a block (the lattice loops' force,
    /// `N`; 0 for the other kernels).
    scratch_per_lane: usize,
    _tables: Box<[Arc<dyn Tabulated>]>,
    /// The array parameters lattice loops read by address.
    _arrays: Vec<Arc<[f64]>>,
    compile_time: Duration,
    /// What Cranelift's register allocators were given (zero for the C kernels).
    allocation: AllocationWork,
}

/// Who generated the machine code.
pub(crate) enum Code {
    /// Cranelift ([`super::cranelift::step`]).
    Cranelift(CraneliftKernels),
    /// The system C compiler ([`super::c`]); `env` is the callback table the code reads
    /// (pointers to the Rust callbacks, into `_tables` and to `_arrays`).
    C {
        kernels: CKernels,
        env: Box<[usize]>,
    },
}

/// Which code generator built a [`StepKernels`].
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum StepBackend {
    Cranelift,
    /// Compiled by the system C compiler, or loaded from its cache (`cached`).
    C {
        cached: bool,
        library: PathBuf,
    },
}

impl Drop for StepKernels {
    fn drop(&mut self) {
        if let Code::Cranelift(CraneliftKernels { modules, .. }) = &mut self.code {
            // SAFETY: dropping; the raw pointers handed out live only as long as `self`.
            unsafe { super::free_modules(modules) }
        }
    }
}

impl std::fmt::Debug for StepKernels {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("StepKernels")
            .field("n", &self.n)
            .field("blocks", &self.blocks)
            .field("tangent", &self.has_tangent())
            .field("backend", &self.backend())
            .field("compile_time", &self.compile_time)
            .finish()
    }
}

impl StepKernels {
    /// Kernels built elsewhere in `jit` (the lattice loops); `allocation` as
    /// [`StepKernels::allocation_work`] (zero for C kernels).
    #[allow(clippy::too_many_arguments)]
    pub(crate) fn new(
        code: Code,
        n: usize,
        blocks: [usize; 2],
        scratch_per_lane: usize,
        tables: Box<[Arc<dyn Tabulated>]>,
        arrays: Vec<Arc<[f64]>>,
        compile_time: Duration,
        allocation: AllocationWork,
    ) -> Self {
        Self {
            code,
            n,
            blocks,
            scratch_per_lane,
            _tables: tables,
            _arrays: arrays,
            compile_time,
            allocation,
        }
    }

    /// Whether [`Self::reference_tangent_steps`] has a kernel (the kernels of a lattice
    /// potential with a plan for it, [`super::fused_plan`]: C's or Cranelift's).
    pub fn has_reference_tangent(&self) -> bool {
        self.fused().is_some()
    }

    /// The fused one-orbit kernel and the callback table it reads (empty for Cranelift's,
    /// which reads nothing through it).
    fn fused(&self) -> Option<(CFusedFn, &[usize])> {
        match &self.code {
            Code::C { kernels, env } => kernels.fused.map(|f| (f, &env[..])),
            Code::Cranelift(kernels) => kernels.fused.map(|f| (f, &[][..])),
        }
    }

    /// `n_steps` steps of the splitting for one orbit `x` (rows `q, p`) and `k` tangent vectors
    /// around it in `v` (`k` rows of `2N` values each, `dq, dp`), in one pass per stage
    /// vectorized along the sites: bit for bit [`Self::orbit_steps`] of `x` and
    /// [`Self::tangent_steps`] of `v` around its stages. False (nothing stepped) where there is
    /// no such kernel ([`Self::has_reference_tangent`]).
    ///
    /// # Panics
    /// If `x` does not hold `2N` values or `v` a whole number of `2N`-value vectors, or as
    /// [`Self::orbit_steps`] for the coefficients and masses.
    pub fn reference_tangent_steps(
        &self,
        x: &mut [f64],
        v: &mut [f64],
        n_steps: u64,
        drift: &[f64],
        kick: &[f64],
        inverse_masses: Option<&[f64]>,
    ) -> bool {
        let Some((f, env)) = self.fused() else {
            return false;
        };
        let dim = 2 * self.n;
        assert!(
            x.len() == dim && v.len().is_multiple_of(dim),
            "fused steps: an orbit of {} values and vectors of {} for {dim}",
            x.len(),
            v.len()
        );
        self.check(x, 1, 1, drift, kick, inverse_masses);
        if n_steps == 0 {
            return true;
        }
        let w = inverse_masses.map_or(std::ptr::null(), |w| w.as_ptr());
        // SAFETY: lengths checked above; the kernel reads `2N` values of `x`, `k` vectors of
        // `2N` of `v`, `n_kicks + 1` drifts, `n_kicks` kicks, `N` inverse masses; the code,
        // tables and arrays `env` points to live as long as `self`.
        unsafe {
            f(
                x.as_mut_ptr(),
                v.as_mut_ptr(),
                v.len() / dim,
                n_steps,
                drift.as_ptr(),
                kick.as_ptr(),
                kick.len(),
                w,
                env.as_ptr(),
            )
        };
        true
    }

    /// The working memory of one call of a kernel with `block`-lane blocks.
    fn scratch(&self, block: usize) -> Vec<f64> {
        vec![0.0; self.scratch_per_lane * block]
    }

    /// Degrees of freedom `N` (the state has `2N` rows).
    pub fn dof(&self) -> usize {
        self.n
    }

    /// Lanes per block of the orbit kernel (2 or 4): the raw function only steps whole
    /// blocks.
    pub fn block_lanes(&self) -> usize {
        self.blocks[0]
    }

    /// Lanes per block of the tangent kernel (2 or 4).
    pub fn tangent_block_lanes(&self) -> usize {
        self.blocks[1]
    }

    pub fn has_tangent(&self) -> bool {
        match &self.code {
            Code::Cranelift(k) => k.tangent.is_some(),
            Code::C { kernels, .. } => kernels.tangent.is_some(),
        }
    }

    /// Code generation (and, for C, compilation or cache lookup) and linking time.
    pub fn compile_time(&self) -> Duration {
        self.compile_time
    }

    /// What Cranelift's register allocators were given, as [`super::Compiled::allocation_work`]
    /// (zero for the C kernels).
    pub fn allocation_work(&self) -> AllocationWork {
        self.allocation
    }

    pub fn backend(&self) -> StepBackend {
        match &self.code {
            Code::Cranelift(_) => StepBackend::Cranelift,
            Code::C { kernels, .. } => StepBackend::C {
                cached: kernels.cached,
                library: kernels.path.clone(),
            },
        }
    }

    fn check(
        &self,
        x: &[f64],
        stride: usize,
        lanes: usize,
        drift: &[f64],
        kick: &[f64],
        inverse_masses: Option<&[f64]>,
    ) {
        assert!(
            drift.len() == kick.len() + 1,
            "step kernels: {} drift coefficients for {} kicks (one more drift than kicks)",
            drift.len(),
            kick.len()
        );
        if let Some(w) = inverse_masses {
            assert!(
                w.len() >= self.n,
                "step kernels: {} inverse masses for {} degrees of freedom",
                w.len(),
                self.n
            );
        }
        assert!(
            lanes <= stride,
            "step kernels: {lanes} lanes wider than the stride {stride}"
        );
        let need = (2 * self.n - 1)
            .checked_mul(stride)
            .and_then(|v| v.checked_add(lanes));
        assert!(
            need.is_some_and(|need| x.len() >= need),
            "step kernels: {} values hold fewer than {} rows of stride {stride}",
            x.len(),
            2 * self.n
        );
    }

    /// Runs `kernel` on the whole blocks of `x`, and on the remaining `lanes % block` lanes
    /// through a padded copy (lanes never interact, so the padding's copies of the last lane are
    /// harmless and the real lanes get the same bits).
    fn by_blocks(
        &self,
        x: &mut [f64],
        stride: usize,
        lanes: usize,
        block: usize,
        mut kernel: impl FnMut(*mut f64, usize, usize),
    ) {
        let full = lanes - lanes % block;
        if full > 0 {
            kernel(x.as_mut_ptr(), stride, full);
        }
        let rest = lanes - full;
        if rest > 0 {
            let rows = 2 * self.n;
            let mut pad = vec![0.0; rows * block];
            for r in 0..rows {
                for l in 0..block {
                    pad[r * block + l] = x[r * stride + full + l.min(rest - 1)];
                }
            }
            kernel(pad.as_mut_ptr(), block, block);
            for r in 0..rows {
                x[r * stride + full..][..rest].copy_from_slice(&pad[r * block..][..rest]);
            }
        }
    }

    /// `n_steps` steps of the splitting for `lanes` orbits in `x` (row `r` of lane `l` at
    /// `x[r * stride + l]`, rows `q_1..q_N, p_1..p_N`), any lane count.
    ///
    /// # Panics
    /// If `drift` does not hold one more value than `kick`, `inverse_masses` has fewer than `N`
    /// values, `lanes > stride`, or `x` is too short.
    #[allow(clippy::too_many_arguments)]
    pub fn orbit_steps(
        &self,
        x: &mut [f64],
        stride: usize,
        lanes: usize,
        n_steps: u64,
        drift: &[f64],
        kick: &[f64],
        inverse_masses: Option<&[f64]>,
    ) {
        if lanes == 0 || n_steps == 0 {
            return;
        }
        self.check(x, stride, lanes, drift, kick, inverse_masses);
        let w = inverse_masses.map_or(std::ptr::null(), |w| w.as_ptr());
        let (d, k, nk) = (drift.as_ptr(), kick.as_ptr(), kick.len());
        let mut scratch = self.scratch(self.blocks[0]);
        let sc = scratch.as_mut_ptr();
        self.by_blocks(x, stride, lanes, self.blocks[0], |p, stride, lanes| {
            // SAFETY: lengths checked above (the padded copy has `2N` rows of `block` lanes);
            // `lanes` is a multiple of the block; `scratch` is this call's own; the code (and
            // the tables, arrays and callbacks `env` points to) lives as long as `self`.
            unsafe {
                match &self.code {
                    Code::Cranelift(c) => (c.orbit)(p, stride, lanes, n_steps, d, k, nk, w, sc),
                    Code::C { kernels, env } => {
                        (kernels.orbit)(p, stride, lanes, n_steps, d, k, nk, w, sc, env.as_ptr())
                    }
                }
            }
        });
    }

    /// `n_steps` steps of the tangent map for `lanes` deviation vectors in `v` (rows `dq, dp`)
    /// around the reference positions `stages` (`n_steps * kicks * N` values: the position
    /// before each kick).
    ///
    /// # Panics
    /// As [`Self::orbit_steps`]; also if no tangent kernel was compiled or `stages` is short.
    #[allow(clippy::too_many_arguments)]
    pub fn tangent_steps(
        &self,
        stages: &[f64],
        v: &mut [f64],
        stride: usize,
        lanes: usize,
        n_steps: u64,
        drift: &[f64],
        kick: &[f64],
        inverse_masses: Option<&[f64]>,
    ) {
        assert!(
            self.has_tangent(),
            "step kernels: no tangent kernel was compiled"
        );
        if lanes == 0 || n_steps == 0 {
            return;
        }
        self.check(v, stride, lanes, drift, kick, inverse_masses);
        let need = (n_steps as u128) * (kick.len() as u128) * (self.n as u128);
        assert!(
            (stages.len() as u128) >= need,
            "step kernels: {} stage positions, {need} needed",
            stages.len()
        );
        let w = inverse_masses.map_or(std::ptr::null(), |w| w.as_ptr());
        let (st, d, k, nk) = (stages.as_ptr(), drift.as_ptr(), kick.as_ptr(), kick.len());
        let mut scratch = self.scratch(self.blocks[1]);
        let sc = scratch.as_mut_ptr();
        self.by_blocks(v, stride, lanes, self.blocks[1], |p, stride, lanes| {
            // SAFETY: as in `orbit_steps`, and `stages` holds every position the steps read;
            // the tangent kernel exists (asserted above).
            unsafe {
                match &self.code {
                    Code::Cranelift(CraneliftKernels {
                        tangent: Some(f), ..
                    }) => f(st, p, stride, lanes, n_steps, d, k, nk, w, sc),
                    Code::C {
                        kernels:
                            CKernels {
                                tangent: Some(f), ..
                            },
                        env,
                    } => f(st, p, stride, lanes, n_steps, d, k, nk, w, sc, env.as_ptr()),
                    _ => unreachable!("has_tangent checked above"),
                }
            }
        });
    }
}

/// Compiles the orbit kernel (and the tangent kernel if `spec` has a Hessian-vector product).
/// `options.lane_block` is the block width; a force with more operations than
/// `options.large_function` is compiled without Cranelift's optimizer and with two-lane blocks
/// (half the code: an FPUT chain of 1001 sites compiles both kernels in about 0.25 s instead
/// of 0.7 s).
pub fn compile_steps(
    graph: &Graph,
    spec: &StepSpec,
    options: &Options,
) -> Result<StepKernels, JitError> {
    let (kernels, blocks, tables, compile_time) = step_cranelift::compile(graph, spec, options)?;
    let allocation = kernels.allocation;
    Ok(StepKernels::new(
        Code::Cranelift(kernels),
        spec.n,
        blocks,
        0,
        tables,
        Vec::new(),
        compile_time,
        allocation,
    ))
}

/// The same kernels as [`compile_steps`], written as C and compiled by `cc` (or loaded from its
/// cache): [`C_BLOCK_LANES`] lanes per block in the host's widest vectors. Bit-identical to the
/// Cranelift kernels and to the generic step loops (see the `c_step` module). Any failure (no
/// compiler, a compiler error, an unwritable cache) is a [`JitError::CCompiler`] naming the
/// cause; the caller falls back to [`compile_steps`].
pub fn compile_steps_c(
    graph: &Graph,
    spec: &StepSpec,
    cc: &CCompiler,
) -> Result<StepKernels, JitError> {
    compile_steps_c_cancellable(graph, spec, cc, &AtomicBool::new(false))
}

/// [`compile_steps_c`] that gives up once `cancel` is set (it is read while the compiler runs,
/// every few milliseconds): the compiler and everything it started are killed and its files
/// removed before this returns [`JitError::Cancelled`]. For a build on a background thread
/// whose result may no longer be wanted.
pub fn compile_steps_c_cancellable(
    graph: &Graph,
    spec: &StepSpec,
    cc: &CCompiler,
    cancel: &AtomicBool,
) -> Result<StepKernels, JitError> {
    let tables: Box<[Arc<dyn Tabulated>]> = graph.tables().to_vec().into_boxed_slice();
    let src = c_step::source(graph, spec)?;
    let tangent = spec.hessian_vector.is_some();
    let (kernels, compile_time) = c_step::build(&src, tangent, cc, cancel, c_step::Mode::Build)?;
    let env = c_step::env(&tables, &[]);
    Ok(StepKernels::new(
        Code::C { kernels, env },
        spec.n,
        [C_BLOCK_LANES; 2],
        0,
        tables,
        Vec::new(),
        compile_time,
        AllocationWork::default(),
    ))
}
