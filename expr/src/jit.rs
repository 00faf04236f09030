//! Native code for a [`Graph`]'s outputs, compiled once at start with Cranelift.
//!
//! Each [`FunctionSpec`] becomes two machine-code functions:
//! - a *scalar* function: one evaluation, every argument a plain array;
//! - a *lane* function: `lanes` independent evaluations in structure-of-arrays layout (entry
//!   `i` of lane `l` at `[i * lanes + l]`), as the batched integrators store their particles.
//!
//! Both perform exactly the IEEE operations [`Graph::apply_unary`], [`Graph::apply_binary`]
//! and [`Graph::apply_powi`] define, on the same operands in the same order, so they agree with
//! the reference evaluator bit for bit (the tests find even NaN payloads equal, though IEEE 754
//! leaves them unspecified). Transcendental functions (and powf, atan2, tables) are calls back
//! into Rust functions that call those very definitions; `sqrt` is an IEEE operation and is
//! emitted inline. No fused multiply-add is ever emitted: Cranelift only emits `fma` for an
//! explicit `fma` instruction, which this module never creates.
//!
//! Lane functions:
//! - *uniform hoisting*: every node that depends only on constants and `Layout::Scalar`
//!   arguments (the stiffness at a shared reference position, say) is computed once, in scalar
//!   code, before the lane loop, into a stack array the loop reads (and broadcasts) at each use;
//! - the loop handles two or four lanes per iteration as one or two `F64X2` values per node
//!   (Cranelift's x86-64 back end has 128-bit vectors only). Arithmetic, `sqrt`, `neg`, `abs`
//!   are the packed forms of the same IEEE operations; `step`, `sign`, `max`, `min` and
//!   `select` are packed compares and bit selects whose results match the scalar definitions
//!   including NaN and signed zeros (`max` is not `maxpd`, which differs on `max(-0, +0)`);
//!   transcendental operations extract the lanes and call the scalar callback for each;
//! - a lane count that is not a multiple of the block is finished by one more block that
//!   *overlaps* the previous one (lanes `lanes - block ..`): the overlapped lanes are recomputed
//!   to the same bits, so no scalar copy of the (possibly 30k-instruction) body is needed.
//!   `lanes == 1` calls the scalar function (same layout); with four-lane blocks, 2 and 3 lanes
//!   use a second, two-lane copy of the loop.
//!
//! Code generation for large graphs (chains of a thousand sites give 10-30k operations per
//! function) is kept linear: nodes are emitted just before their first use (not in the graph's
//! order, which computes e.g. all bond stiffnesses first), constants and argument loads are
//! re-emitted at each use, and outputs are stored as soon as computed, so few values are live
//! at any point; large functions skip Cranelift's optimizer ([`Options::large_function`]).
//! Some expressions keep many values live whatever the order (a product of a thousand
//! factors: its gradient needs every partial product); Cranelift's backtracking register
//! allocator is superlinear in the values live at once, so functions whose values stay live
//! longer than [`MAX_MEAN_LIVE`] operations on average get the single-pass allocator
//! ([`regalloc_for`]), which is linear. Neither changes a result: both only place values.

use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use cranelift_codegen::Context;
use cranelift_codegen::ir::condcodes::{FloatCC, IntCC};
use cranelift_codegen::ir::types::{F64, F64X2, I64};
use cranelift_codegen::ir::{
    AbiParam, Block, BlockArg, Endianness, InstBuilder, MemFlagsData, SigRef, Signature, StackSlot,
    StackSlotData, StackSlotKind, TrapCode, UserFuncName, Value,
};
use cranelift_codegen::settings::{self, Configurable};
use cranelift_frontend::{FunctionBuilder, FunctionBuilderContext};
use cranelift_jit::{JITBuilder, JITModule};
use cranelift_module::{FuncId, Linkage, Module};

use crate::graph::{Binary, Cmp, Graph, Node, NodeId, Tabulated, Unary};

mod c_fused;
mod c_sites;
mod c_step;
mod site_steps;
mod sites;
mod step;
mod step_cranelift;
mod step_spec;

pub use c_fused::applies as fused_applies;
pub use c_sites::{
    compile_lattice_steps_c, compile_lattice_steps_c_cancellable, load_lattice_steps_c,
};
pub use c_step::{C_BLOCK_LANES, CCompiler};
pub use site_steps::compile_lattice_steps;
pub use sites::{LATTICE_GRADIENT, LATTICE_HESSIAN_VECTOR, LATTICE_POTENTIAL, compile_lattice};
pub use step::{
    StepBackend, StepKernels, compile_steps, compile_steps_c, compile_steps_c_cancellable,
};
pub use step_cranelift::{OrbitStepsFnPtr, TangentStepsFnPtr};
pub use step_spec::StepSpec;

/// How a function reads one argument array (or writes its output).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Layout {
    /// One value per entry, shared by all lanes of a lane call.
    Scalar,
    /// Structure of arrays: entry `i` of lane `l` at `[i * lanes + l]` in a lane call (plain in
    /// a scalar call).
    Lanes,
}

/// One function to compile: `args[a]` is the layout of argument array `a`
/// (`Node::Input { arg: a, .. }`), `outputs` the nodes written, in order, to the output array.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct FunctionSpec {
    pub args: Vec<Layout>,
    pub outputs: Vec<NodeId>,
}

/// Cranelift's optimization level.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum OptLevel {
    /// No mid-end optimization: fastest compilation.
    None,
    /// E-graph mid-end (GVN, LICM, simplification) and better instruction selection.
    Speed,
}

/// Cranelift's register allocator.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Regalloc {
    /// Backtracking with live-range splitting: better code.
    Backtracking,
    /// One pass: several times faster to compile, but measured 2-3x slower code on small
    /// gradients (many more spills and moves); for very large graphs only.
    SinglePass,
}

/// Code generation options; [`compile`] uses [`Options::default`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Options {
    pub opt_level: OptLevel,
    pub regalloc: Regalloc,
    /// Lanes per loop iteration: 2 (one `F64X2` per value) or 4 (two independent `F64X2`
    /// chains; lane counts 2 and 3 then use a second, two-lane copy of the loop).
    pub lane_block: usize,
    /// Functions with more operations than this are compiled with `OptLevel::None` whatever
    /// `opt_level` says: Cranelift's optimizer costs compile time in proportion to size (an FPUT
    /// chain of 1001 sites, gradient and HVP with four-lane blocks: 0.44 s instead of 1.4 s)
    /// for a measured 0-40% on such functions.
    pub large_function: usize,
    /// Compile each spec's lane function beside its scalar one. A caller that steps its lanes
    /// with the step kernels ([`compile_steps`]) needs only the scalar functions and halves
    /// the compile time with `false`; [`Compiled::call_lanes`] then panics.
    pub lane_functions: bool,
}

impl Default for Options {
    /// Chosen by measurement (`benches/jit.rs`): `speed` and four lanes per iteration make the
    /// small functions (a Henon-Heiles gradient) up to 2x faster than `none` and two lanes, at
    /// a compile cost that only matters for large functions, which `large_function` sends to
    /// `none` (an FPUT chain of 1001 sites: gradient and HVP in about 0.45 s, 0.23 s with
    /// two-lane blocks, which are 20-30% slower).
    fn default() -> Self {
        Options {
            opt_level: OptLevel::Speed,
            regalloc: Regalloc::Backtracking,
            lane_block: 4,
            large_function: 2000,
            lane_functions: true,
        }
    }
}

/// Why a graph could not be compiled. Every refusal of the code generator lands here; nothing
/// in [`compile`] panics on a valid [`Graph`].
#[derive(Debug, thiserror::Error)]
pub enum JitError {
    #[error("native compilation is not supported on this host: {0}")]
    Host(String),
    #[error("function {function}: output {output} is node {node}, but the graph has {len} nodes")]
    NoSuchNode {
        function: usize,
        output: usize,
        node: NodeId,
        len: usize,
    },
    #[error(
        "function {function}: node {node} reads argument {arg}, but the function declares {declared} argument(s)"
    )]
    MissingArgument {
        function: usize,
        node: NodeId,
        arg: u8,
        declared: usize,
    },
    #[error(
        "function {function}: node {node} reads table {table}, but the graph has {len} table(s)"
    )]
    NoSuchTable {
        function: usize,
        node: NodeId,
        table: u32,
        len: usize,
    },
    #[error("function {function}: an array offset overflows (entry {index} of {count})")]
    TooLarge {
        function: usize,
        index: u64,
        count: u64,
    },
    #[error("code generation failed for function {function} ({variant}): {message}")]
    Codegen {
        function: usize,
        variant: &'static str,
        message: String,
    },
    #[error("linking the compiled functions failed: {0}")]
    Link(String),
    /// A [`StepSpec`] that does not describe `N` degrees of freedom.
    #[error("step kernels: {0}")]
    Steps(String),
    /// The C step kernels could not be built or loaded (no compiler, a compiler error, the
    /// cache directory); [`compile_steps`] is the fallback.
    #[error("C step kernels: {0}")]
    CCompiler(String),
    /// The C build was cancelled by its caller (the compiler stopped, its files removed).
    #[error("C step kernels: the build was cancelled")]
    Cancelled,
    /// An entry of the kernel cache that is not a regular file (a FIFO, a device, a socket):
    /// refused without reading it. Said even by a lookup that only loads, where a miss is silent.
    #[error("C step kernels: {0}")]
    CacheEntry(String),
    /// A lookup that must not compile ([`load_lattice_steps_c`]) found no library in the cache.
    #[error("C step kernels: not in the kernel cache")]
    NotCached,
}

/// A compiled scalar function.
///
/// # Safety contract
/// `args` points to as many pointers as the function's spec has arguments; `args[a]` points to
/// at least [`Compiled::arg_len`]`(f, a)` readable `f64`s; `out` points to
/// [`Compiled::output_len`]`(f)` writable `f64`s that overlap no argument. The tables the graph
/// references are kept alive by the [`Compiled`] the pointer came from, which must outlive every
/// call.
pub type ScalarFnPtr = unsafe extern "C" fn(args: *const *const f64, out: *mut f64);

/// A compiled lane function: `lanes` evaluations whose entry `i` of lane `l` is at
/// `[i * stride + l]` (`stride == lanes` for a whole SoA array; `stride > lanes` evaluates a
/// group of consecutive lanes of a wider array, the pointers offset to its first lane).
///
/// # Safety contract
/// As [`ScalarFnPtr`], with: a `Layout::Lanes` argument `a` readable at `[i * stride + l]` for
/// `i < arg_len(f, a)`, `l < lanes`; a `Layout::Scalar` one holds `arg_len(f, a)` values; `out`
/// writable at `[j * stride + l]` for `j < output_len(f)`, `l < lanes`, overlapping no argument
/// (a lane count that is not a multiple of the block recomputes some lanes from the arguments
/// after having written them); `lanes <= stride`. `lanes == 0` does nothing; `lanes == 1`
/// requires `stride == 1` (it runs the scalar function) and traps otherwise.
pub type LanesFnPtr =
    unsafe extern "C" fn(args: *const *const f64, out: *mut f64, lanes: usize, stride: usize);

struct FnInfo {
    layouts: Vec<Layout>,
    arg_len: Vec<usize>,
    n_out: usize,
    scalar: ScalarFnPtr,
    lanes: Option<LanesFnPtr>,
}

/// The compiled functions of one [`compile`] call. Owns the executable memory (freed on drop)
/// and the tables the code calls into.
///
/// `Send + Sync` without any `unsafe impl`: the JIT module (which holds a `RefCell` and so is
/// not `Sync`) sits in a `Mutex` that is only locked on drop; calls use plain function pointers
/// to immutable code, and the tables are `Arc<dyn Tabulated>` (`Send + Sync` by the trait's
/// bounds).
pub struct Compiled {
    modules: Mutex<Vec<JITModule>>,
    fns: Vec<FnInfo>,
    /// Read by the compiled code through `*const Arc<dyn Tabulated>` pointers into this boxed
    /// slice, which never moves or changes after compilation.
    _tables: Box<[Arc<dyn Tabulated>]>,
    /// The array parameters lattice loops read by address ([`compile_lattice`]).
    _arrays: Vec<Arc<[f64]>>,
    compile_time: Duration,
    isa: String,
    /// The register allocators' input: see [`Compiled::allocation_work`].
    allocation: AllocationWork,
}

/// What the compiled functions gave Cranelift's register allocators: operations (non-leaf
/// values) in all, and the live span ([`live_span`]) of those given the backtracking
/// allocator, whose time grows faster than linearly with it. Kept at most [`MAX_MEAN_LIVE`]
/// times the operations, it keeps compilation time linear in the size of the expression.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct AllocationWork {
    pub operations: u64,
    pub backtracking_live_span: u64,
}

/// Frees the machine code of `modules`; the one teardown of every owner of compiled code
/// (`Compiled`, `StepKernels`).
///
/// # Safety
/// No function pointer into these modules may be called afterwards: their owners hand out raw
/// pointers documented to be valid only while the owner lives, and call this from `Drop`,
/// when no `&self` call can be running.
pub(crate) unsafe fn free_modules(modules: &mut Mutex<Vec<JITModule>>) {
    let modules = match modules.get_mut() {
        Ok(m) => std::mem::take(m),
        Err(poisoned) => std::mem::take(poisoned.into_inner()),
    };
    for module in modules {
        // SAFETY: see the function's contract.
        unsafe { module.free_memory() };
    }
}

impl Drop for Compiled {
    fn drop(&mut self) {
        // SAFETY: dropping; the pointers from `raw_scalar`/`raw_lanes` live only as long as
        // `self`.
        unsafe { free_modules(&mut self.modules) }
    }
}

impl std::fmt::Debug for Compiled {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Compiled")
            .field("functions", &self.fns.len())
            .field("compile_time", &self.compile_time)
            .field("isa", &self.isa)
            .finish()
    }
}

impl Compiled {
    /// Number of compiled functions (one per spec).
    pub fn len(&self) -> usize {
        self.fns.len()
    }

    pub fn is_empty(&self) -> bool {
        self.fns.is_empty()
    }

    /// Entries of argument `a` function `f` reads (largest `Input` index + 1): the minimal length
    /// of a scalar argument, or of one lane's row count in a lane call.
    pub fn arg_len(&self, f: usize, a: usize) -> usize {
        self.fns[f].arg_len[a]
    }

    /// Number of values function `f` writes per evaluation.
    pub fn output_len(&self, f: usize) -> usize {
        self.fns[f].n_out
    }

    /// The register allocators' input, per [`AllocationWork`] (what the compilation time
    /// scales with; tests check it is linear in the expression's size).
    pub fn allocation_work(&self) -> AllocationWork {
        self.allocation
    }

    /// Wall time of [`compile`] (code generation of every function and linking).
    pub fn compile_time(&self) -> Duration {
        self.compile_time
    }

    /// The target the code was generated for (triple and the ISA flags Cranelift detected).
    pub fn isa(&self) -> &str {
        &self.isa
    }

    /// Scalar call: every argument array is plain (`args[a][i]` = entry `i`); writes
    /// `output_len(f)` values.
    ///
    /// # Panics
    /// If the number of arguments, an argument's length (shorter than [`Self::arg_len`]) or the
    /// output length (not exactly [`Self::output_len`]) is wrong.
    pub fn call(&self, f: usize, args: &[&[f64]], out: &mut [f64]) {
        let info = &self.fns[f];
        check_args(f, info, args, 1, false);
        assert!(
            out.len() == info.n_out,
            "jit function {f}: output has {} entries, expected {}",
            out.len(),
            info.n_out
        );
        with_pointers(args, |ptrs| {
            // SAFETY: lengths checked above; `out` is a `&mut` so it overlaps no argument; the
            // code lives as long as `self`.
            unsafe { (info.scalar)(ptrs, out.as_mut_ptr()) }
        });
    }

    /// Lane call over `lanes` independent evaluations in structure-of-arrays layout: an argument
    /// with `Layout::Lanes` holds entry `i` of lane `l` at `[i * lanes + l]`; `Layout::Scalar`
    /// arguments are shared by all lanes; the output is written as `out[j * lanes + l]`.
    ///
    /// # Panics
    /// On a wrong number of arguments, a `Lanes` argument whose length is not a multiple of
    /// `lanes` or has fewer than [`Self::arg_len`] rows, a short `Scalar` argument, or an output
    /// that is not exactly `output_len(f) * lanes` long.
    pub fn call_lanes(&self, f: usize, args: &[&[f64]], out: &mut [f64], lanes: usize) {
        let info = &self.fns[f];
        check_args(f, info, args, lanes, true);
        assert!(
            Some(out.len()) == info.n_out.checked_mul(lanes),
            "jit function {f}: output has {} entries, expected {} outputs x {lanes} lanes",
            out.len(),
            info.n_out
        );
        if lanes == 0 {
            return;
        }
        let f = self.raw_lanes(f);
        with_pointers(args, |ptrs| {
            // SAFETY: lengths checked above; `out` is a `&mut` so it overlaps no argument;
            // `stride == lanes`.
            unsafe { f(ptrs, out.as_mut_ptr(), lanes, lanes) }
        });
    }

    /// The scalar function's machine code, for hot loops that check lengths once outside. See
    /// [`ScalarFnPtr`] for the contract; valid while `self` lives.
    pub fn raw_scalar(&self, f: usize) -> ScalarFnPtr {
        self.fns[f].scalar
    }

    /// The lane function's machine code; see [`LanesFnPtr`]; valid while `self` lives.
    ///
    /// # Panics
    /// If compiled without lane functions ([`Options::lane_functions`]).
    pub fn raw_lanes(&self, f: usize) -> LanesFnPtr {
        self.fns[f]
            .lanes
            .expect("compiled without lane functions (Options::lane_functions)")
    }
}

fn check_args(f: usize, info: &FnInfo, args: &[&[f64]], lanes: usize, lane_call: bool) {
    assert!(
        args.len() == info.layouts.len(),
        "jit function {f}: {} argument arrays given, expected {}",
        args.len(),
        info.layouts.len()
    );
    for (a, (arg, (&layout, &need))) in args
        .iter()
        .zip(info.layouts.iter().zip(&info.arg_len))
        .enumerate()
    {
        if lane_call && layout == Layout::Lanes {
            if lanes == 0 {
                continue;
            }
            assert!(
                arg.len() % lanes == 0 && arg.len() / lanes >= need,
                "jit function {f}: lane argument {a} has {} entries, expected a multiple of \
                 {lanes} lanes with at least {need} rows",
                arg.len()
            );
        } else {
            assert!(
                arg.len() >= need,
                "jit function {f}: argument {a} has {} entries, expected at least {need}",
                arg.len()
            );
        }
    }
}

/// Calls `body` with a pointer to the arguments' base pointers, without allocating for the
/// common small argument counts.
fn with_pointers<R>(args: &[&[f64]], body: impl FnOnce(*const *const f64) -> R) -> R {
    const SMALL: usize = 8;
    if args.len() <= SMALL {
        let mut ptrs = [std::ptr::null::<f64>(); SMALL];
        for (p, a) in ptrs.iter_mut().zip(args) {
            *p = a.as_ptr();
        }
        body(ptrs.as_ptr())
    } else {
        let ptrs: Vec<*const f64> = args.iter().map(|a| a.as_ptr()).collect();
        body(ptrs.as_ptr())
    }
}

// ---------------------------------------------------------------------------------------------
// Callbacks: the compiled code calls these for every operation that is not a single IEEE
// instruction, so the result is by construction the one `Graph` defines.

macro_rules! unary_callbacks {
    ($($name:ident => $op:ident),* $(,)?) => {
        $(extern "C" fn $name(x: f64) -> f64 {
            Graph::apply_unary(Unary::$op, x)
        })*
        fn unary_callback(op: Unary) -> Option<usize> {
            match op {
                $(Unary::$op => Some($name as *const () as usize),)*
                _ => None,
            }
        }
    };
}

unary_callbacks! {
    cb_exp => Exp,
    cb_log => Log,
    cb_sin => Sin,
    cb_cos => Cos,
    cb_tan => Tan,
    cb_atan => Atan,
    cb_tanh => Tanh,
    cb_cosh => Cosh,
    cb_sinh => Sinh,
}

extern "C" fn cb_pow(a: f64, b: f64) -> f64 {
    Graph::apply_binary(Binary::Pow, a, b)
}

extern "C" fn cb_atan2(a: f64, b: f64) -> f64 {
    Graph::apply_binary(Binary::Atan2, a, b)
}

/// `table` points into `Compiled::_tables`. A panic inside `Tabulated::eval` aborts the process
/// (it cannot unwind through the compiled frames); `table::Spline` returns NaN instead.
extern "C" fn cb_table(table: *const Arc<dyn Tabulated>, deriv: u64, x: f64) -> f64 {
    // SAFETY: the pointer was taken from the boxed table slice owned by the `Compiled` whose
    // code is running, so it is valid and immutable for the duration of the call.
    let table = unsafe { &*table };
    table.eval(deriv as u8, x)
}

// ---------------------------------------------------------------------------------------------
// Compilation.

/// Compiles every spec with the default [`Options`].
pub fn compile(graph: &Graph, specs: &[FunctionSpec]) -> Result<Compiled, JitError> {
    compile_with(graph, specs, &Options::default())
}

/// Compiles every spec (a scalar and a lane function each) into one block of executable
/// memory.
pub fn compile_with(
    graph: &Graph,
    specs: &[FunctionSpec],
    options: &Options,
) -> Result<Compiled, JitError> {
    let start = Instant::now();
    if options.lane_block != 2 && options.lane_block != 4 {
        return Err(JitError::Host(format!(
            "lane_block must be 2 or 4, not {}",
            options.lane_block
        )));
    }
    // One module per optimization level and register allocator actually used (both are
    // per-ISA flags in Cranelift).
    let mut modules: Vec<((OptLevel, Regalloc), JITModule)> = Vec::new();
    let mut allocation = AllocationWork::default();
    let mut isa_name = String::new();
    let tables: Box<[Arc<dyn Tabulated>]> = graph.tables().to_vec().into_boxed_slice();
    let mut ctx = Context::new();
    let mut fctx = FunctionBuilderContext::new();
    let mut defined = Vec::with_capacity(specs.len());
    for (f, spec) in specs.iter().enumerate() {
        let plan = Plan::new(graph, spec, f)?;
        let large = plan.scalar_order.len() > options.large_function;
        let (opt, lane_block) = if large {
            (OptLevel::None, options.lane_block)
        } else {
            (options.opt_level, options.lane_block)
        };
        // The scalar order stands for the lane function's too (the same operations).
        let (regalloc, span) = regalloc_for(options, graph, &plan.scalar_order);
        let key = (opt, regalloc);
        allocation.operations += plan.scalar_order.len() as u64;
        if regalloc == Regalloc::Backtracking {
            allocation.backtracking_live_span += span;
        }
        let m = match modules.iter().position(|(k, _)| *k == key) {
            Some(m) => m,
            None => {
                let (module, name) = new_module(key.0, key.1)?;
                isa_name = name;
                modules.push((key, module));
                modules.len() - 1
            }
        };
        let module = &mut modules[m].1;
        let ptr = module.target_config().pointer_type();
        let mut sig_s = module.make_signature();
        sig_s.params.push(AbiParam::new(ptr));
        sig_s.params.push(AbiParam::new(ptr));
        let mut sig_l = sig_s.clone();
        sig_l.params.push(AbiParam::new(ptr));
        sig_l.params.push(AbiParam::new(ptr));
        let codegen = |variant: &'static str| {
            move |e: cranelift_module::ModuleError| JitError::Codegen {
                function: f,
                variant,
                message: format!("{e:?}"),
            }
        };
        let id_s = module
            .declare_function(&format!("f{f}_scalar"), Linkage::Local, &sig_s)
            .map_err(codegen("scalar"))?;
        let id_l = if options.lane_functions {
            Some(
                module
                    .declare_function(&format!("f{f}_lanes"), Linkage::Local, &sig_l)
                    .map_err(codegen("lanes"))?,
            )
        } else {
            None
        };

        module.clear_context(&mut ctx);
        ctx.func.signature = sig_s;
        ctx.func.name = UserFuncName::user(0, id_s.as_u32());
        let mut emit = Emit {
            graph,
            plan: &plan,
            tables: &tables,
            module,
            ctx: &mut ctx,
            fctx: &mut fctx,
        };
        emit.scalar();
        emit.module
            .define_function(id_s, emit.ctx)
            .map_err(codegen("scalar"))?;

        if let Some(id_l) = id_l {
            emit.module.clear_context(emit.ctx);
            emit.ctx.func.signature = sig_l;
            emit.ctx.func.name = UserFuncName::user(0, id_l.as_u32());
            emit.lanes(id_s, lane_block / 2);
            emit.module
                .define_function(id_l, emit.ctx)
                .map_err(codegen("lanes"))?;
        }
        defined.push((m, id_s, id_l, spec.args.clone(), plan.arg_len.clone()));
    }
    for (_, module) in &mut modules {
        module
            .finalize_definitions()
            .map_err(|e| JitError::Link(format!("{e:?}")))?;
    }
    let fns = defined
        .into_iter()
        .zip(specs)
        .map(|((m, id_s, id_l, layouts, arg_len), spec)| {
            let module = &modules[m].1;
            let ps = module.get_finalized_function(id_s);
            let pl = id_l.map(|id| module.get_finalized_function(id));
            // SAFETY: both were defined above with exactly these signatures (two or four
            // pointer-sized integer parameters, no results, the host's C calling convention).
            let (scalar, lanes) = unsafe {
                (
                    std::mem::transmute::<*const u8, ScalarFnPtr>(ps),
                    pl.map(|pl| std::mem::transmute::<*const u8, LanesFnPtr>(pl)),
                )
            };
            FnInfo {
                layouts,
                arg_len,
                n_out: spec.outputs.len(),
                scalar,
                lanes,
            }
        })
        .collect();
    if isa_name.is_empty() {
        isa_name = new_module(options.opt_level, options.regalloc)?.1;
    }
    Ok(Compiled {
        modules: Mutex::new(modules.into_iter().map(|(_, m)| m).collect()),
        fns,
        _tables: tables,
        _arrays: Vec::new(),
        compile_time: start.elapsed(),
        isa: isa_name,
        allocation,
    })
}

/// A JIT module for the host at one optimization level, and a description of the target.
fn new_module(opt: OptLevel, regalloc: Regalloc) -> Result<(JITModule, String), JitError> {
    let mut flags = settings::builder();
    let set = |flags: &mut settings::Builder, k: &str, v: &str| {
        flags
            .set(k, v)
            .map_err(|e| JitError::Host(format!("setting {k}={v}: {e}")))
    };
    let opt = match opt {
        OptLevel::None => "none",
        OptLevel::Speed => "speed",
    };
    set(&mut flags, "opt_level", opt)?;
    set(&mut flags, "use_colocated_libcalls", "false")?;
    set(&mut flags, "is_pic", "false")?;
    // Frames beyond a page (thousands of spill slots or uniform values) touch every page on
    // entry, so a deep frame hits the guard page instead of jumping over it.
    set(&mut flags, "enable_probestack", "true")?;
    set(&mut flags, "probestack_strategy", "inline")?;
    let regalloc = match regalloc {
        Regalloc::Backtracking => "backtracking",
        Regalloc::SinglePass => "single_pass",
    };
    set(&mut flags, "regalloc_algorithm", regalloc)?;
    // The IR verifier costs compile time; this module's IR is checked by the tests (debug).
    let verify = if cfg!(debug_assertions) {
        "true"
    } else {
        "false"
    };
    set(&mut flags, "enable_verifier", verify)?;
    let isa_builder = cranelift_native::builder().map_err(|e| JitError::Host(e.to_string()))?;
    let isa = isa_builder
        .finish(settings::Flags::new(flags))
        .map_err(|e| JitError::Host(e.to_string()))?;
    let features: Vec<&str> = isa
        .isa_flags()
        .iter()
        .filter(|v| v.as_bool() == Some(true))
        .map(|v| v.name)
        .collect();
    let name = format!("{} [{}]", isa.triple(), features.join(","));
    let module = JITModule::new(JITBuilder::with_isa(
        isa,
        cranelift_module::default_libcall_names(),
    ));
    Ok((module, name))
}

/// Functions whose non-leaf values stay live for more than this many operations on average
/// (over the emission order) are compiled with [`Regalloc::SinglePass`]. Measured on products
/// of n factors (gradient and Hessian-vector product, scalar and lanes): the backtracking
/// allocator took 0.84 s, 3.4 s and 38 s for n = 250, 500, 1000 (their mean live spans are
/// about n / 3 operations), the single-pass one 0.04 s, 0.04 s and 0.14 s; an FPUT chain's
/// values live a few operations (mean below 8), where backtracking gives the better code.
pub const MAX_MEAN_LIVE: u64 = 32;

/// Sum over the non-leaf values of `order` (an emission order) of the number of operations
/// from a value's definition to its last use: the work a register allocator faces, computed in
/// one pass.
pub fn live_span(graph: &Graph, order: &[NodeId]) -> u64 {
    let mut position = vec![u32::MAX; graph.len()];
    for (i, &id) in order.iter().enumerate() {
        position[id as usize] = i as u32;
    }
    let mut last_use = vec![0u32; order.len()];
    for (i, &id) in order.iter().enumerate() {
        for o in graph.node(id).operands() {
            let p = position[o as usize];
            if p != u32::MAX {
                last_use[p as usize] = i as u32;
            }
        }
    }
    last_use
        .iter()
        .enumerate()
        .map(|(i, &last)| u64::from(last.saturating_sub(i as u32)))
        .sum()
}

/// The register allocator for a function of `order`: `options.regalloc`, unless its values
/// stay live longer than [`MAX_MEAN_LIVE`] operations on average (then the linear one); and
/// the order's live span.
pub(crate) fn regalloc_for(options: &Options, graph: &Graph, order: &[NodeId]) -> (Regalloc, u64) {
    let span = live_span(graph, order);
    if span > MAX_MEAN_LIVE * order.len() as u64 {
        (Regalloc::SinglePass, span)
    } else {
        (options.regalloc, span)
    }
}

/// What one function needs from the graph.
struct Plan {
    /// Non-leaf nodes of the scalar function in emission order (see [`schedule`]).
    scalar_order: Vec<NodeId>,
    /// Non-leaf uniform nodes the lane loop reads, in emission order (before the loop).
    uniform_order: Vec<NodeId>,
    /// Non-leaf varying nodes, in emission order (the loop body).
    varying_order: Vec<NodeId>,
    /// Per node: depends only on constants and `Layout::Scalar` arguments.
    uniform: Vec<bool>,
    /// Per node: a uniform node read by a varying node or written as an output (must be
    /// broadcast before the lane loop).
    broadcast: Vec<bool>,
    arg_len: Vec<usize>,
    layouts: Vec<Layout>,
    outputs: Vec<NodeId>,
}

impl Plan {
    fn new(graph: &Graph, spec: &FunctionSpec, f: usize) -> Result<Plan, JitError> {
        let n = graph.len();
        let mut needed = vec![false; n];
        for (j, &o) in spec.outputs.iter().enumerate() {
            if o as usize >= n {
                return Err(JitError::NoSuchNode {
                    function: f,
                    output: j,
                    node: o,
                    len: n,
                });
            }
            needed[o as usize] = true;
        }
        for id in (0..n).rev() {
            if needed[id] {
                for op in graph.nodes()[id].operands() {
                    needed[op as usize] = true;
                }
            }
        }
        let order: Vec<NodeId> = (0..n as NodeId).filter(|&i| needed[i as usize]).collect();
        let mut uniform = vec![false; n];
        let mut broadcast = vec![false; n];
        let mut arg_len = vec![0usize; spec.args.len()];
        for &id in &order {
            let node = graph.node(id);
            uniform[id as usize] = match *node {
                Node::Const(_) => true,
                Node::Input { arg, index } => {
                    let Some(&layout) = spec.args.get(arg as usize) else {
                        return Err(JitError::MissingArgument {
                            function: f,
                            node: id,
                            arg,
                            declared: spec.args.len(),
                        });
                    };
                    let len = &mut arg_len[arg as usize];
                    *len = (*len).max(index as usize + 1);
                    layout == Layout::Scalar
                }
                Node::Table { table, .. } if table as usize >= graph.tables().len() => {
                    return Err(JitError::NoSuchTable {
                        function: f,
                        node: id,
                        table,
                        len: graph.tables().len(),
                    });
                }
                _ => node.operands().all(|o| uniform[o as usize]),
            };
            if !uniform[id as usize] {
                for o in node.operands() {
                    if uniform[o as usize] && !is_leaf(graph.node(o)) {
                        broadcast[o as usize] = true;
                    }
                }
            }
        }
        for &o in &spec.outputs {
            if uniform[o as usize] && !is_leaf(graph.node(o)) {
                broadcast[o as usize] = true;
            }
        }
        // Offsets are `i32` immediates or 64-bit products; refuse arrays whose byte offsets
        // cannot be formed.
        for (a, &len) in arg_len.iter().enumerate() {
            if len as u64 * 8 > i32::MAX as u64 {
                return Err(JitError::TooLarge {
                    function: f,
                    index: a as u64,
                    count: len as u64,
                });
            }
        }
        if spec.outputs.len() as u64 * 8 > i32::MAX as u64 {
            return Err(JitError::TooLarge {
                function: f,
                index: 0,
                count: spec.outputs.len() as u64,
            });
        }
        let non_leaf = |id: NodeId| !is_leaf(graph.node(id));
        let scalar_order = schedule(graph, &spec.outputs, non_leaf);
        let roots: Vec<NodeId> = order
            .iter()
            .copied()
            .filter(|&id| broadcast[id as usize])
            .collect();
        let uniform_order = schedule(graph, &roots, |id| non_leaf(id) && uniform[id as usize]);
        let varying_order = schedule(graph, &spec.outputs, |id| {
            non_leaf(id) && !uniform[id as usize]
        });
        Ok(Plan {
            scalar_order,
            uniform_order,
            varying_order,
            uniform,
            broadcast,
            arg_len,
            layouts: spec.args.clone(),
            outputs: spec.outputs.clone(),
        })
    }
}

/// Emission order: each root's not yet emitted dependencies (those `include` accepts) in
/// post-order, root by root. A valid evaluation order (operands first) in which a value is
/// computed just before its first use: the graph's own order computes, say, every bond's
/// stiffness of a chain before the first product that reads one, which keeps a thousand values
/// live at once and made register allocation take most of a second. The order of independent
/// operations does not change any result.
fn schedule(graph: &Graph, roots: &[NodeId], include: impl Fn(NodeId) -> bool) -> Vec<NodeId> {
    let mut done = vec![false; graph.len()];
    let mut order = Vec::new();
    // (node, operands already pushed)
    let mut stack: Vec<(NodeId, bool)> = Vec::new();
    for &root in roots {
        if done[root as usize] || !include(root) {
            continue;
        }
        stack.push((root, false));
        while let Some((id, expanded)) = stack.pop() {
            if done[id as usize] {
                continue;
            }
            if expanded {
                done[id as usize] = true;
                order.push(id);
                continue;
            }
            stack.push((id, true));
            let ops: Vec<NodeId> = graph.node(id).operands().collect();
            // Reversed, so the first operand is emitted first.
            for &o in ops.iter().rev() {
                if !done[o as usize] && include(o) {
                    stack.push((o, false));
                }
            }
        }
    }
    order
}

/// Imported callback signatures of one function.
struct Sigs {
    unary: SigRef,
    binary: SigRef,
    table: SigRef,
}

impl Sigs {
    fn new(b: &mut FunctionBuilder, module: &JITModule) -> Sigs {
        let cc = module.target_config().default_call_conv;
        let mut unary = Signature::new(cc);
        unary.params.push(AbiParam::new(F64));
        unary.returns.push(AbiParam::new(F64));
        let mut binary = unary.clone();
        binary.params.push(AbiParam::new(F64));
        let mut table = Signature::new(cc);
        table.params.push(AbiParam::new(I64));
        table.params.push(AbiParam::new(I64));
        table.params.push(AbiParam::new(F64));
        table.returns.push(AbiParam::new(F64));
        Sigs {
            unary: b.import_signature(unary),
            binary: b.import_signature(binary),
            table: b.import_signature(table),
        }
    }
}

fn flags() -> MemFlagsData {
    // Never traps (the caller guarantees the lengths); no alignment beyond `f64`'s is promised.
    MemFlagsData::new().with_notrap()
}

fn call1(b: &mut FunctionBuilder, sig: SigRef, addr: usize, args: &[Value]) -> Value {
    let callee = b.ins().iconst(I64, addr as i64);
    let inst = b.ins().call_indirect(sig, callee, args);
    b.inst_results(inst)[0]
}

/// Scalar code for node `id` given its operands' scalar values.
fn emit_scalar(
    b: &mut FunctionBuilder,
    sigs: &Sigs,
    tables: &[Arc<dyn Tabulated>],
    node: &Node,
    v: &mut dyn FnMut(&mut FunctionBuilder, NodeId) -> Value,
) -> Value {
    match *node {
        Node::Const(_) | Node::Input { .. } => unreachable!("leaves are emitted at each use"),
        Node::Unary(op, a) => {
            let x = v(b, a);
            match op {
                Unary::Neg => b.ins().fneg(x),
                Unary::Abs => b.ins().fabs(x),
                Unary::Sqrt => b.ins().sqrt(x),
                Unary::Step => {
                    let zero = b.ins().f64const(0.0);
                    let one = b.ins().f64const(1.0);
                    let gt = b.ins().fcmp(FloatCC::GreaterThan, x, zero);
                    let r = b.ins().select(gt, one, zero);
                    let nan = b.ins().fcmp(FloatCC::Unordered, x, x);
                    b.ins().select(nan, x, r)
                }
                Unary::Sign => {
                    let zero = b.ins().f64const(0.0);
                    let one = b.ins().f64const(1.0);
                    let m_one = b.ins().f64const(-1.0);
                    let lt = b.ins().fcmp(FloatCC::LessThan, x, zero);
                    let r = b.ins().select(lt, m_one, zero);
                    let gt = b.ins().fcmp(FloatCC::GreaterThan, x, zero);
                    let r = b.ins().select(gt, one, r);
                    let nan = b.ins().fcmp(FloatCC::Unordered, x, x);
                    b.ins().select(nan, x, r)
                }
                _ => {
                    let addr = unary_callback(op).expect("every other unary op has a callback");
                    call1(b, sigs.unary, addr, &[x])
                }
            }
        }
        Node::Binary(op, a, c) => {
            let (x, y) = (v(b, a), v(b, c));
            match op {
                Binary::Add => b.ins().fadd(x, y),
                Binary::Sub => b.ins().fsub(x, y),
                Binary::Mul => b.ins().fmul(x, y),
                Binary::Div => b.ins().fdiv(x, y),
                Binary::Pow => call1(b, sigs.binary, cb_pow as *const () as usize, &[x, y]),
                Binary::Atan2 => call1(b, sigs.binary, cb_atan2 as *const () as usize, &[x, y]),
                Binary::Max | Binary::Min => {
                    let cc = if op == Binary::Max {
                        FloatCC::GreaterThanOrEqual
                    } else {
                        FloatCC::LessThanOrEqual
                    };
                    let keep = b.ins().fcmp(cc, x, y);
                    let r = b.ins().select(keep, x, y);
                    let nan = b.ins().fcmp(FloatCC::Unordered, x, y);
                    let qnan = b.ins().f64const(f64::NAN);
                    b.ins().select(nan, qnan, r)
                }
            }
        }
        Node::Powi(a, n) => {
            let x = v(b, a);
            if n == 0 {
                return b.ins().f64const(1.0);
            }
            let mut acc = x;
            for _ in 1..n.unsigned_abs() {
                acc = b.ins().fmul(acc, x);
            }
            if n < 0 {
                let one = b.ins().f64const(1.0);
                acc = b.ins().fdiv(one, acc);
            }
            acc
        }
        Node::Select {
            cmp,
            a,
            b: c,
            then,
            otherwise,
        } => {
            let (x, y) = (v(b, a), v(b, c));
            let cond = b.ins().fcmp(float_cc(cmp), x, y);
            let (t, e) = (v(b, then), v(b, otherwise));
            b.ins().select(cond, t, e)
        }
        Node::Table { table, deriv, arg } => {
            let x = v(b, arg);
            let t = b.ins().iconst(
                I64,
                &tables[table as usize] as *const Arc<dyn Tabulated> as i64,
            );
            let d = b.ins().iconst(I64, deriv as i64);
            call1(b, sigs.table, cb_table as *const () as usize, &[t, d, x])
        }
    }
}

/// IEEE (ordered) comparisons: false when either side is NaN, as `Cmp::holds`.
fn float_cc(cmp: Cmp) -> FloatCC {
    match cmp {
        Cmp::Lt => FloatCC::LessThan,
        Cmp::Le => FloatCC::LessThanOrEqual,
        Cmp::Gt => FloatCC::GreaterThan,
        Cmp::Ge => FloatCC::GreaterThanOrEqual,
    }
}

/// Constants a vector body needs, broadcast once before the loop.
struct VConsts {
    zero: Value,
    one: Value,
    m_one: Value,
    nan: Value,
}

fn mask(b: &mut FunctionBuilder, cc: FloatCC, x: Value, y: Value) -> Value {
    let m = b.ins().fcmp(cc, x, y);
    b.ins().bitcast(
        F64X2,
        MemFlagsData::new().with_endianness(Endianness::Little),
        m,
    )
}

/// Two-lane code for a varying node given its operands' `F64X2` values.
#[allow(clippy::too_many_arguments)]
fn emit_vector(
    b: &mut FunctionBuilder,
    sigs: &Sigs,
    tables: &[Arc<dyn Tabulated>],
    k: &VConsts,
    node: &Node,
    v: &mut dyn FnMut(&mut FunctionBuilder, NodeId) -> Value,
) -> Value {
    // A scalar callback applied to each lane.
    let per_lane =
        |b: &mut FunctionBuilder, sig: SigRef, addr: usize, pre: &[Value], xs: &[Value]| {
            let mut lanes = [None; 2];
            for (l, slot) in lanes.iter_mut().enumerate() {
                let mut args: Vec<Value> = pre.to_vec();
                for &x in xs {
                    args.push(b.ins().extractlane(x, l as u8));
                }
                *slot = Some(call1(b, sig, addr, &args));
            }
            let [Some(r0), Some(r1)] = lanes else {
                unreachable!()
            };
            let r = b.ins().scalar_to_vector(F64X2, r0);
            b.ins().insertlane(r, r1, 1)
        };
    match *node {
        Node::Const(_) | Node::Input { .. } => unreachable!("leaves are emitted at each use"),
        Node::Unary(op, a) => {
            let x = v(b, a);
            match op {
                Unary::Neg => b.ins().fneg(x),
                Unary::Abs => b.ins().fabs(x),
                Unary::Sqrt => b.ins().sqrt(x),
                Unary::Step => {
                    let gt = mask(b, FloatCC::GreaterThan, x, k.zero);
                    let r = b.ins().bitselect(gt, k.one, k.zero);
                    let nan = mask(b, FloatCC::Unordered, x, x);
                    b.ins().bitselect(nan, x, r)
                }
                Unary::Sign => {
                    let lt = mask(b, FloatCC::LessThan, x, k.zero);
                    let r = b.ins().bitselect(lt, k.m_one, k.zero);
                    let gt = mask(b, FloatCC::GreaterThan, x, k.zero);
                    let r = b.ins().bitselect(gt, k.one, r);
                    let nan = mask(b, FloatCC::Unordered, x, x);
                    b.ins().bitselect(nan, x, r)
                }
                _ => {
                    let addr = unary_callback(op).expect("every other unary op has a callback");
                    per_lane(b, sigs.unary, addr, &[], &[x])
                }
            }
        }
        Node::Binary(op, a, c) => {
            let (x, y) = (v(b, a), v(b, c));
            match op {
                Binary::Add => b.ins().fadd(x, y),
                Binary::Sub => b.ins().fsub(x, y),
                Binary::Mul => b.ins().fmul(x, y),
                Binary::Div => b.ins().fdiv(x, y),
                Binary::Pow => per_lane(b, sigs.binary, cb_pow as *const () as usize, &[], &[x, y]),
                Binary::Atan2 => {
                    per_lane(b, sigs.binary, cb_atan2 as *const () as usize, &[], &[x, y])
                }
                Binary::Max | Binary::Min => {
                    // `a >= b ? a : b` (not `maxpd`, which returns `b` for equal zeros).
                    let cc = if op == Binary::Max {
                        FloatCC::GreaterThanOrEqual
                    } else {
                        FloatCC::LessThanOrEqual
                    };
                    let keep = mask(b, cc, x, y);
                    let r = b.ins().bitselect(keep, x, y);
                    let nan = mask(b, FloatCC::Unordered, x, y);
                    b.ins().bitselect(nan, k.nan, r)
                }
            }
        }
        Node::Powi(a, n) => {
            let x = v(b, a);
            if n == 0 {
                return k.one;
            }
            let mut acc = x;
            for _ in 1..n.unsigned_abs() {
                acc = b.ins().fmul(acc, x);
            }
            if n < 0 {
                acc = b.ins().fdiv(k.one, acc);
            }
            acc
        }
        Node::Select {
            cmp,
            a,
            b: c,
            then,
            otherwise,
        } => {
            let (x, y) = (v(b, a), v(b, c));
            let cond = mask(b, float_cc(cmp), x, y);
            let (t, e) = (v(b, then), v(b, otherwise));
            b.ins().bitselect(cond, t, e)
        }
        Node::Table { table, deriv, arg } => {
            let x = v(b, arg);
            let t = b.ins().iconst(
                I64,
                &tables[table as usize] as *const Arc<dyn Tabulated> as i64,
            );
            let d = b.ins().iconst(I64, deriv as i64);
            per_lane(b, sigs.table, cb_table as *const () as usize, &[t, d], &[x])
        }
    }
}

/// Loads the base pointers of the argument arrays (only those the function reads).
fn arg_pointers(b: &mut FunctionBuilder, args: Value, plan: &Plan) -> Vec<Option<Value>> {
    plan.arg_len
        .iter()
        .enumerate()
        .map(|(a, &len)| (len > 0).then(|| b.ins().load(I64, flags(), args, (a * 8) as i32)))
        .collect()
}

fn is_leaf(node: &Node) -> bool {
    matches!(node, Node::Const(_) | Node::Input { .. })
}

/// For each node, the output slots it is written to.
fn outputs_by_node(plan: &Plan, n: usize) -> Vec<Vec<usize>> {
    let mut outs = vec![Vec::new(); n];
    for (j, &o) in plan.outputs.iter().enumerate() {
        outs[o as usize].push(j);
    }
    outs
}

/// A scalar operand. Leaves (constants, argument entries) are emitted afresh at every use
/// rather than once at their place in the node order: graphs list all inputs and constants
/// first, and keeping thousands of them live across a straight-line function made register
/// allocation superlinear (seconds for a 1001-site chain). A reload is one load, as cheap as a
/// spill reload.
fn operand_scalar(
    b: &mut FunctionBuilder,
    graph: &Graph,
    ptrs: &[Option<Value>],
    vals: &[Option<Value>],
    id: NodeId,
) -> Value {
    match *graph.node(id) {
        Node::Const(c) => b.ins().f64const(c),
        Node::Input { arg, index } => {
            let p = ptrs[arg as usize].expect("argument read");
            b.ins().load(F64, flags(), p, (index as usize * 8) as i32)
        }
        _ => vals[id as usize].expect("operands come first"),
    }
}

/// One function being generated.
struct Emit<'a> {
    graph: &'a Graph,
    plan: &'a Plan,
    tables: &'a [Arc<dyn Tabulated>],
    module: &'a mut JITModule,
    ctx: &'a mut Context,
    fctx: &'a mut FunctionBuilderContext,
}

impl Emit<'_> {
    fn scalar(&mut self) {
        build_scalar(
            self.ctx,
            self.fctx,
            self.module,
            self.graph,
            self.plan,
            self.tables,
        );
    }

    fn lanes(&mut self, scalar: FuncId, units: usize) {
        build_lanes(self, scalar, units);
    }
}

fn build_scalar(
    ctx: &mut Context,
    fctx: &mut FunctionBuilderContext,
    module: &JITModule,
    graph: &Graph,
    plan: &Plan,
    tables: &[Arc<dyn Tabulated>],
) {
    let mut b = FunctionBuilder::new(&mut ctx.func, fctx);
    let entry = b.create_block();
    b.append_block_params_for_function_params(entry);
    b.switch_to_block(entry);
    let (args, out) = (b.block_params(entry)[0], b.block_params(entry)[1]);
    let sigs = Sigs::new(&mut b, module);
    let ptrs = arg_pointers(&mut b, args, plan);
    let outs = outputs_by_node(plan, graph.len());
    let mut vals: Vec<Option<Value>> = vec![None; graph.len()];
    for &id in &plan.scalar_order {
        let node = graph.node(id);
        let val = {
            let mut get = |b: &mut FunctionBuilder, o| operand_scalar(b, graph, &ptrs, &vals, o);
            emit_scalar(&mut b, &sigs, tables, node, &mut get)
        };
        vals[id as usize] = Some(val);
        // Stored as soon as computed, so outputs do not stay live to the end.
        for &j in &outs[id as usize] {
            b.ins().store(flags(), val, out, (j * 8) as i32);
        }
    }
    for (j, &o) in plan.outputs.iter().enumerate() {
        if is_leaf(graph.node(o)) {
            let v = operand_scalar(&mut b, graph, &ptrs, &vals, o);
            b.ins().store(flags(), v, out, (j * 8) as i32);
        }
    }
    b.ins().return_(&[]);
    b.seal_all_blocks();
    b.finalize(module.target_config());
}

/// Where the lane loop body finds its operands.
struct LaneBody<'a> {
    graph: &'a Graph,
    plan: &'a Plan,
    ptrs: &'a [Option<Value>],
    /// `ptrs[a] + 8 l` for `Lanes` arguments: entry 0 of lane `l`.
    rows: &'a [Option<Value>],
    /// The stack slot holding the broadcast uniform values, and each node's offset in it.
    uniforms: StackSlot,
    uniform_offset: &'a [u32],
    /// `8 * lanes`, as a loop block parameter (so the per-entry offsets `index * stride` stay in
    /// the loop instead of being hoisted into thousands of loop-invariant spilled values).
    stride: Value,
}

impl LaneBody<'_> {
    /// A two-lane operand: leaves afresh at each use (a `Lanes` entry is one unaligned 16-byte
    /// load, a shared entry or a constant a load and broadcast), other nodes as computed.
    fn operand(
        &self,
        b: &mut FunctionBuilder,
        vvals: &[Option<[Value; 2]>],
        id: NodeId,
        unit: usize,
    ) -> Value {
        match *self.graph.node(id) {
            Node::Const(c) => {
                let s = b.ins().f64const(c);
                b.ins().splat(F64X2, s)
            }
            Node::Input { arg, index } => match self.plan.layouts[arg as usize] {
                Layout::Scalar => {
                    let p = self.ptrs[arg as usize].expect("argument read");
                    let s = b.ins().load(F64, flags(), p, (index as usize * 8) as i32);
                    b.ins().splat(F64X2, s)
                }
                Layout::Lanes => {
                    let row = self.rows[arg as usize].expect("lane argument read");
                    let p = if index == 0 {
                        row
                    } else {
                        let off = b.ins().imul_imm_s(self.stride, index as i64);
                        b.ins().iadd(row, off)
                    };
                    b.ins().load(F64X2, flags(), p, 16 * unit as i32)
                }
            },
            _ if self.plan.uniform[id as usize] => {
                let off = self.uniform_offset[id as usize] as i32;
                let s = b.ins().stack_load(I64, F64, self.uniforms, off);
                b.ins().splat(F64X2, s)
            }
            _ => vvals[id as usize].expect("operands come first")[unit],
        }
    }
}

fn build_lanes(e: &mut Emit, scalar: FuncId, units: usize) {
    let (graph, plan, tables) = (e.graph, e.plan, e.tables);
    let (ctx, fctx, module) = (&mut *e.ctx, &mut *e.fctx, &mut *e.module);
    let scalar_ref = module.declare_func_in_func(scalar, &mut ctx.func);
    let config = module.target_config();
    let mut b = FunctionBuilder::new(&mut ctx.func, fctx);
    let entry = b.create_block();
    let single = b.create_block();
    let call_block = b.create_block();
    let pre = b.create_block();
    let body = b.create_block();
    let cont = b.create_block();
    let exit = b.create_block();
    b.append_block_params_for_function_params(entry);
    let l = b.append_block_param(body, I64);
    let stride = b.append_block_param(body, I64);

    // entry: fewer than two lanes -> `single` (0: nothing; 1: the scalar function, whose layout
    // is the same).
    b.switch_to_block(entry);
    let (args, out, lanes, stride_elems) = (
        b.block_params(entry)[0],
        b.block_params(entry)[1],
        b.block_params(entry)[2],
        b.block_params(entry)[3],
    );
    let few = b.ins().icmp_imm_u(IntCC::UnsignedLessThan, lanes, 2);
    b.ins().brif(few, single, &[], pre, &[]);

    b.switch_to_block(single);
    let one_lane = b.ins().icmp_imm_u(IntCC::Equal, lanes, 1);
    b.ins().brif(one_lane, call_block, &[], exit, &[]);
    b.switch_to_block(call_block);
    let contiguous = b.ins().icmp_imm_u(IntCC::Equal, stride_elems, 1);
    let call_scalar = b.create_block();
    let misuse = b.create_block();
    b.ins().brif(contiguous, call_scalar, &[], misuse, &[]);
    b.switch_to_block(misuse);
    b.ins().trap(TrapCode::unwrap_user(1));
    b.switch_to_block(call_scalar);
    b.ins().call(scalar_ref, &[args, out]);
    b.ins().jump(exit, &[]);

    // pre: argument pointers; uniform nodes once, in scalar code, broadcast for the loop.
    b.switch_to_block(pre);
    let sigs = Sigs::new(&mut b, module);
    let ptrs = arg_pointers(&mut b, args, plan);
    // Uniform values the loop reads go to a stack array (8 bytes each) and are reloaded and
    // broadcast at each use: as SSA values live across the loop, a thousand of them (the
    // stiffnesses of a chain's HVP at a shared position) cost the register allocator a second.
    let n_uniform = plan
        .uniform_order
        .iter()
        .filter(|&&id| plan.broadcast[id as usize])
        .count();
    let uniforms = b.create_sized_stack_slot(StackSlotData::new(
        StackSlotKind::ExplicitSlot,
        (n_uniform.max(1) * 8) as u32,
        4,
    ));
    let mut uniform_offset = vec![0u32; graph.len()];
    let mut svals: Vec<Option<Value>> = vec![None; graph.len()];
    let mut next_offset = 0u32;
    for &id in &plan.uniform_order {
        let node = graph.node(id);
        let val = {
            let mut get = |b: &mut FunctionBuilder, o| operand_scalar(b, graph, &ptrs, &svals, o);
            emit_scalar(&mut b, &sigs, tables, node, &mut get)
        };
        svals[id as usize] = Some(val);
        if plan.broadcast[id as usize] {
            uniform_offset[id as usize] = next_offset;
            b.ins().stack_store(I64, val, uniforms, next_offset as i32);
            next_offset += 8;
        }
    }
    let k = {
        let mut sp = |c: f64| {
            let s = b.ins().f64const(c);
            b.ins().splat(F64X2, s)
        };
        VConsts {
            zero: sp(0.0),
            one: sp(1.0),
            m_one: sp(-1.0),
            nan: sp(f64::NAN),
        }
    };
    let stride0 = b.ins().ishl_imm_u(stride_elems, 3);
    let zero = b.ins().iconst(I64, 0);

    let body_pair = b.create_block();
    let cont_pair = b.create_block();
    let lp = b.append_block_param(body_pair, I64);
    let stride_p = b.append_block_param(body_pair, I64);
    let bodies: Vec<(usize, Block, Block, Value, Value)> = if units == 2 {
        vec![
            (2, body, cont, l, stride),
            (1, body_pair, cont_pair, lp, stride_p),
        ]
    } else {
        vec![(1, body, cont, l, stride)]
    };
    if units == 2 {
        // Fewer lanes than one block: the two-lane loop.
        let small = b.ins().icmp_imm_u(IntCC::UnsignedLessThan, lanes, 4);
        b.ins().brif(
            small,
            body_pair,
            &[BlockArg::Value(zero), BlockArg::Value(stride0)],
            body,
            &[BlockArg::Value(zero), BlockArg::Value(stride0)],
        );
    } else {
        b.ins()
            .jump(body, &[BlockArg::Value(zero), BlockArg::Value(stride0)]);
    }
    let outs = outputs_by_node(plan, graph.len());
    for (units, body, cont, l, stride) in bodies {
        // body(l, stride): lanes l .. l + 2 units.
        b.switch_to_block(body);
        let loff = b.ins().ishl_imm_u(l, 3);
        let rows: Vec<Option<Value>> = ptrs
            .iter()
            .zip(&plan.layouts)
            .map(|(p, &layout)| match (p, layout) {
                (Some(p), Layout::Lanes) => Some(b.ins().iadd(*p, loff)),
                _ => None,
            })
            .collect();
        let orow = b.ins().iadd(out, loff);
        let lb = LaneBody {
            graph,
            plan,
            ptrs: &ptrs,
            rows: &rows,
            uniforms,
            uniform_offset: &uniform_offset,
            stride,
        };
        let store = |b: &mut FunctionBuilder, v: Value, j: usize, unit: usize| {
            let p = if j == 0 {
                orow
            } else {
                let off = b.ins().imul_imm_s(stride, j as i64);
                b.ins().iadd(orow, off)
            };
            b.ins().store(flags(), v, p, 16 * unit as i32);
        };
        let mut vvals: Vec<Option<[Value; 2]>> = vec![None; graph.len()];
        for &id in &plan.varying_order {
            let node = graph.node(id);
            let mut emitted = [None; 2];
            for (unit, slot) in emitted.iter_mut().enumerate().take(units) {
                let mut get = |b: &mut FunctionBuilder, o| lb.operand(b, &vvals, o, unit);
                *slot = Some(emit_vector(&mut b, &sigs, tables, &k, node, &mut get));
            }
            let v0 = emitted[0].expect("at least one unit");
            let val = [v0, emitted[1].unwrap_or(v0)];
            vvals[id as usize] = Some(val);
            for &j in &outs[id as usize] {
                for (unit, &v) in val.iter().enumerate().take(units) {
                    store(&mut b, v, j, unit);
                }
            }
        }
        for (j, &o) in plan.outputs.iter().enumerate() {
            if plan.uniform[o as usize] || is_leaf(graph.node(o)) {
                for unit in 0..units {
                    let v = lb.operand(&mut b, &vvals, o, unit);
                    store(&mut b, v, j, unit);
                }
            }
        }
        // Next block; the last block of a count that is not a multiple overlaps the previous.
        let width = 2 * units as i64;
        let next = b.ins().iadd_imm_s(l, width);
        let done = b.ins().icmp(IntCC::UnsignedGreaterThanOrEqual, next, lanes);
        b.ins().brif(done, exit, &[], cont, &[]);
        b.switch_to_block(cont);
        let last = b.ins().iadd_imm_s(lanes, -width);
        let next = b.ins().umin(next, last);
        b.ins()
            .jump(body, &[BlockArg::Value(next), BlockArg::Value(stride)]);
    }

    b.switch_to_block(exit);
    b.ins().return_(&[]);
    b.seal_all_blocks();
    b.finalize(config);
}
