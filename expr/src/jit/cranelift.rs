//! Cranelift code for a [`Graph`]'s outputs, compiled once at start.
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

mod fused;
pub(crate) mod lattice;
pub(crate) mod lattice_steps;
pub(crate) mod step;
mod step_loops;

use super::outputs_by_node;
use super::{FunctionSpec, JitError, Layout, OptLevel, Options, Plan, Regalloc, is_leaf};
use super::{binary_callback, cb_table, unary_callback};

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
    /// The array parameters lattice loops read by address ([`lattice::compile_lattice`]).
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

/// Imported callback signatures of one function.
pub(crate) struct Sigs {
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
                _ => {
                    let addr = binary_callback(op).expect("every other binary op has a callback");
                    call1(b, sigs.binary, addr, &[x, y])
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
pub(crate) struct VConsts {
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
                _ => {
                    let addr = binary_callback(op).expect("every other binary op has a callback");
                    per_lane(b, sigs.binary, addr, &[], &[x, y])
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
