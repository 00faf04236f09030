//! The Cranelift back end of the step kernels (see [`crate::jit::step`] for what they compute):
//! native code generated in process, at once, for any host Cranelift supports.

use std::cell::{Cell, RefCell};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use cranelift_codegen::Context;
use cranelift_codegen::ir::condcodes::IntCC;
use cranelift_codegen::ir::types::{F64, F64X2, I64};
use cranelift_codegen::ir::{AbiParam, BlockArg, InstBuilder, StackSlotData, StackSlotKind};
use cranelift_codegen::ir::{StackSlot, UserFuncName, Value};
use cranelift_frontend::{FunctionBuilder, FunctionBuilderContext};
use cranelift_jit::JITModule;
use cranelift_module::{Linkage, Module};

use super::step_loops::{LoopArgs, StepBody, step_loops};
use super::{
    AllocationWork, Sigs, VConsts, emit_scalar, emit_vector, flags, new_module, operand_scalar,
    regalloc_for,
};
use crate::graph::{Graph, Node, NodeId, Tabulated};
use crate::jit::step_spec::{StageOp, StepSpec, kernel_plan, stage_schedule};
use crate::jit::{JitError, Layout, OptLevel, Options, Plan, Regalloc};

/// `n_steps` steps of the splitting for `lanes` orbits whose row `r` (`q_1..q_N, p_1..p_N`) of
/// lane `l` is `x[r * stride + l]`; `drift` holds `n_kicks + 1` coefficients (already times the
/// step), `kick` `n_kicks`; `inverse_masses` is null (unit masses) or holds `N` values.
///
/// `scratch` is the kernel's working memory ([`crate::jit::StepKernels`] allocates it for each call:
/// the lattice loops' force of one block of lanes, `N` rows of a block; unused by other kernels).
///
/// # Safety contract
/// `x` readable and writable at `[r * stride + l]` for `r < 2N`, `l < lanes`; `lanes` a multiple
/// of [`crate::jit::StepKernels::block_lanes`] (other lanes are not touched); `drift`, `kick`,
/// `inverse_masses` readable as stated and not overlapping `x`; `scratch` writable for the
/// kernel's scratch length and overlapping nothing; the [`crate::jit::StepKernels`] it came from
/// alive.
pub type OrbitStepsFnPtr = unsafe extern "C" fn(
    x: *mut f64,
    stride: usize,
    lanes: usize,
    n_steps: u64,
    drift: *const f64,
    kick: *const f64,
    n_kicks: usize,
    inverse_masses: *const f64,
    scratch: *mut f64,
);

/// `n_steps` steps of the splitting's tangent map for `lanes` deviation vectors (rows `dq, dp`,
/// as [`OrbitStepsFnPtr`]'s `x`) around one reference orbit whose position before kick `i` of
/// step `s` is `stages[(s * n_kicks + i) * N ..][..N]`.
///
/// # Safety contract
/// As [`OrbitStepsFnPtr`], and `stages` readable for `n_steps * n_kicks * N` values.
pub type TangentStepsFnPtr = unsafe extern "C" fn(
    stages: *const f64,
    v: *mut f64,
    stride: usize,
    lanes: usize,
    n_steps: u64,
    drift: *const f64,
    kick: *const f64,
    n_kicks: usize,
    inverse_masses: *const f64,
    scratch: *mut f64,
);

/// The Cranelift kernels of one [`compile`] call.
pub(crate) struct CraneliftKernels {
    pub(crate) modules: Mutex<Vec<JITModule>>,
    pub(crate) orbit: OrbitStepsFnPtr,
    pub(crate) tangent: Option<TangentStepsFnPtr>,
    /// The fused one-orbit kernel of a lattice potential that has one ([`super::fused`]).
    pub(crate) fused: Option<crate::jit::c::CFusedFn>,
    /// What the register allocators were given.
    pub(crate) allocation: AllocationWork,
}

/// What a [`compile`] call built: the kernels, lanes per block of each (orbit, tangent), the
/// tables the code calls into, and the time it took.
pub(crate) type Compiled = (
    CraneliftKernels,
    [usize; 2],
    Box<[Arc<dyn Tabulated>]>,
    Duration,
);

/// Compiles the orbit kernel (and the tangent kernel if `spec` has a Hessian-vector product).
/// `options.lane_block` is the block width; a force with more operations than
/// `options.large_function` is compiled without Cranelift's optimizer and with two-lane blocks
/// (half the code: an FPUT chain of 1001 sites compiles both kernels in about 0.25 s instead
/// of 0.7 s).
pub(crate) fn compile(
    graph: &Graph,
    spec: &StepSpec,
    options: &Options,
) -> Result<Compiled, JitError> {
    let start = Instant::now();
    if options.lane_block != 2 && options.lane_block != 4 {
        return Err(JitError::Host(format!(
            "lane_block must be 2 or 4, not {}",
            options.lane_block
        )));
    }
    let n = spec.n;
    let tables: Box<[Arc<dyn Tabulated>]> = graph.tables().to_vec().into_boxed_slice();
    let mut kernels: Vec<(usize, Plan, u8, bool)> = Vec::new();
    let check =
        |f: usize, outputs: &[NodeId], args: Vec<Layout>| kernel_plan(graph, n, f, outputs, args);
    let orbit_plan = check(0, &spec.gradient, vec![Layout::Lanes])?;
    kernels.push((0, orbit_plan, 0, false));
    if let Some(hv) = &spec.hessian_vector {
        let plan = check(1, hv, vec![Layout::Scalar, Layout::Lanes])?;
        kernels.push((1, plan, 1, true));
    }

    let mut modules: Vec<((OptLevel, Regalloc), JITModule)> = Vec::new();
    let mut allocation = AllocationWork::default();
    let mut ctx = Context::new();
    let mut fctx = FunctionBuilderContext::new();
    let mut defined = Vec::new();
    let mut blocks = [options.lane_block; 2];
    for (f, plan, lane_arg, tangent) in &kernels {
        let large = plan.varying_order.len() > options.large_function;
        let opt = if large {
            OptLevel::None
        } else {
            options.opt_level
        };
        let block = if large { 2 } else { options.lane_block };
        blocks[usize::from(*tangent)] = block;
        // The uniform part (what depends on the stage's positions only: in the tangent kernel
        // the Hessian's entries, most of the work) is emitted before the lane loop, the
        // varying part inside it: either can keep many values live.
        let (uniform, uniform_span) = regalloc_for(options, graph, &plan.uniform_order);
        let (varying, varying_span) = regalloc_for(options, graph, &plan.varying_order);
        let regalloc = if uniform == Regalloc::SinglePass {
            uniform
        } else {
            varying
        };
        allocation.operations += (plan.uniform_order.len() + plan.varying_order.len()) as u64;
        if regalloc == Regalloc::Backtracking {
            allocation.backtracking_live_span += uniform_span + varying_span;
        }
        let key = (opt, regalloc);
        let m = match modules.iter().position(|(k, _)| *k == key) {
            Some(m) => m,
            None => {
                modules.push((key, new_module(key.0, key.1)?.0));
                modules.len() - 1
            }
        };
        let module = &mut modules[m].1;
        let ptr = module.target_config().pointer_type();
        let mut sig = module.make_signature();
        let params = if *tangent { 10 } else { 9 };
        for _ in 0..params {
            sig.params.push(AbiParam::new(ptr));
        }
        let variant = if *tangent { "tangent" } else { "orbit" };
        let codegen = |e: cranelift_module::ModuleError| JitError::Codegen {
            function: *f,
            variant,
            message: format!("{e:?}"),
        };
        let id = module
            .declare_function(&format!("steps_{variant}"), Linkage::Local, &sig)
            .map_err(codegen)?;
        module.clear_context(&mut ctx);
        ctx.func.signature = sig;
        ctx.func.name = UserFuncName::user(0, id.as_u32());
        build_kernel(
            &mut ctx,
            &mut fctx,
            module,
            graph,
            plan,
            &tables,
            n,
            *lane_arg,
            *tangent,
            block / 2,
        );
        module.define_function(id, &mut ctx).map_err(codegen)?;
        defined.push((m, id, *tangent));
    }
    for (_, module) in &mut modules {
        module
            .finalize_definitions()
            .map_err(|e| JitError::Link(format!("{e:?}")))?;
    }
    let mut orbit = None;
    let mut tangent = None;
    for (m, id, is_tangent) in defined {
        let code = modules[m].1.get_finalized_function(id);
        // SAFETY: defined above with exactly these signatures (nine or ten pointer-sized
        // integer parameters, no results, the host's C calling convention).
        unsafe {
            if is_tangent {
                tangent = Some(std::mem::transmute::<*const u8, TangentStepsFnPtr>(code));
            } else {
                orbit = Some(std::mem::transmute::<*const u8, OrbitStepsFnPtr>(code));
            }
        }
    }
    let kernels = CraneliftKernels {
        modules: Mutex::new(modules.into_iter().map(|(_, m)| m).collect()),
        orbit: orbit.expect("the orbit kernel is always compiled"),
        tangent,
        fused: None,
        allocation,
    };
    Ok((kernels, blocks, tables, start.elapsed()))
}

/// A drifted row: the new `q_j` and the `p_j` it was drifted with, per unit.
type Row = ([Value; 2], [Value; 2]);

/// The code of one block of lanes within a stage.
struct Block<'a> {
    kernel: &'a SeparableBody<'a>,
    /// Lane 0 of row 0 of this block, and the row stride in bytes.
    base: Value,
    stride: Value,
    /// Row addresses already formed in the current basic block (row `r` from row `r - 1`
    /// with one add, `p_j` from `q_j`), and `N * stride`.
    addr: RefCell<Vec<Option<Value>>>,
    half: Cell<Option<Value>>,
}

impl Block<'_> {
    /// Forget the row addresses (a new basic block, or a new base).
    fn reset(&self) {
        self.addr.borrow_mut().iter_mut().for_each(|a| *a = None);
        self.half.set(None);
    }

    fn row(&self, b: &mut FunctionBuilder, r: usize) -> Value {
        if let Some(a) = self.addr.borrow()[r] {
            return a;
        }
        let a = if r == 0 {
            self.base
        } else if r >= self.kernel.n {
            let q = self.row(b, r - self.kernel.n);
            let half = match self.half.get() {
                Some(h) => h,
                None => {
                    let h = b.ins().imul_imm_s(self.stride, self.kernel.n as i64);
                    self.half.set(Some(h));
                    h
                }
            };
            b.ins().iadd(q, half)
        } else if let Some(prev) = self.addr.borrow()[r - 1] {
            b.ins().iadd(prev, self.stride)
        } else {
            let off = b.ins().imul_imm_s(self.stride, r as i64);
            b.ins().iadd(self.base, off)
        };
        self.addr.borrow_mut()[r] = Some(a);
        a
    }

    /// `q_j += c_j p_j` for every unit, stored back; returns the new `q_j` and `p_j`.
    fn drift_row(&self, b: &mut FunctionBuilder, j: usize) -> ([Value; 2], [Value; 2]) {
        let c = match self.kernel.hoisted_coef.get(j) {
            Some(&c) => c,
            None => {
                let c = b
                    .ins()
                    .stack_load(I64, F64, self.kernel.coef, (j * 8) as i32);
                b.ins().splat(F64X2, c)
            }
        };
        let (qa, pa) = (self.row(b, j), self.row(b, self.kernel.n + j));
        let (mut out, mut ps) = ([c; 2], [c; 2]);
        for unit in 0..self.kernel.units {
            let off = 16 * unit as i32;
            let q = b.ins().load(F64X2, flags(), qa, off);
            let p = b.ins().load(F64X2, flags(), pa, off);
            let cp = b.ins().fmul(c, p);
            let q = b.ins().fadd(q, cp);
            b.ins().store(flags(), q, qa, off);
            out[unit] = q;
            ps[unit] = p;
        }
        if self.kernel.units == 1 {
            out[1] = out[0];
            ps[1] = ps[0];
        }
        (out, ps)
    }

    fn operand(
        &self,
        b: &mut FunctionBuilder,
        rows: &[Option<Row>],
        vvals: &[Option<[Value; 2]>],
        id: NodeId,
        unit: usize,
    ) -> Value {
        match *self.kernel.graph.node(id) {
            Node::Const(c) => {
                let s = b.ins().f64const(c);
                b.ins().splat(F64X2, s)
            }
            Node::Input { arg, index } if arg == self.kernel.lane_arg => {
                rows[index as usize]
                    .expect("the schedule drifts a row before its first use")
                    .0[unit]
            }
            Node::Input { index, .. } => {
                let p = self
                    .kernel
                    .shared
                    .expect("only the tangent kernel has a shared argument");
                let s = b.ins().load(F64, flags(), p, (index as usize * 8) as i32);
                b.ins().splat(F64X2, s)
            }
            _ if self.kernel.plan.uniform[id as usize]
                && !self.kernel.hoisted_uniform.is_empty() =>
            {
                self.kernel.hoisted_uniform[id as usize].expect("broadcast uniform value")
            }
            _ if self.kernel.plan.uniform[id as usize] => {
                let off = self.kernel.uniform_offset[id as usize] as i32;
                let s = b.ins().stack_load(I64, F64, self.kernel.uniforms, off);
                b.ins().splat(F64X2, s)
            }
            _ => vvals[id as usize].expect("operands come first")[unit],
        }
    }

    /// `p_j -= dh * f_j` for every unit (`p`: the momentum the drift read, not changed since).
    fn kick_row(&self, b: &mut FunctionBuilder, j: usize, dh: Value, f: [Value; 2], p: [Value; 2]) {
        let pa = self.row(b, self.kernel.n + j);
        for (unit, (&f, &p)) in f.iter().zip(&p).enumerate().take(self.kernel.units) {
            let off = 16 * unit as i32;
            let df = b.ins().fmul(dh, f);
            let p = b.ins().fsub(p, df);
            b.ins().store(flags(), p, pa, off);
        }
    }

    /// Drift, force and kick of one stage, statement by statement as [`stage_schedule`] orders
    /// them.
    fn stage(&self, b: &mut FunctionBuilder, k: &VConsts, dh: Value) {
        let graph = self.kernel.graph;
        self.reset();
        let mut rows: Vec<Option<Row>> = vec![None; self.kernel.n];
        let mut vvals: Vec<Option<[Value; 2]>> = vec![None; graph.len()];
        for op in stage_schedule(graph, self.kernel.plan, self.kernel.n, self.kernel.lane_arg) {
            match op {
                StageOp::Drift(j) => rows[j] = Some(self.drift_row(b, j)),
                StageOp::Value(id) => {
                    let node = graph.node(id);
                    let mut emitted = [None; 2];
                    for (unit, slot) in emitted.iter_mut().enumerate().take(self.kernel.units) {
                        let mut get =
                            |b: &mut FunctionBuilder, o| self.operand(b, &rows, &vvals, o, unit);
                        *slot = Some(emit_vector(
                            b,
                            self.kernel.sigs,
                            self.kernel.tables,
                            k,
                            node,
                            &mut get,
                        ));
                    }
                    let v0 = emitted[0].expect("at least one unit");
                    vvals[id as usize] = Some([v0, emitted[1].unwrap_or(v0)]);
                }
                StageOp::Kick { row, force } => {
                    let (_, p) = rows[row].expect("the schedule drifts a row before its kick");
                    let mut f = [dh; 2];
                    for (unit, slot) in f.iter_mut().enumerate().take(self.kernel.units) {
                        *slot = self.operand(b, &rows, &vvals, force, unit);
                    }
                    self.kick_row(b, row, dh, f, p);
                }
            }
        }
    }
}

pub(crate) fn vconsts(b: &mut FunctionBuilder) -> VConsts {
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
}

/// Fills the coefficient array with `ch * w_j` (or `ch` where `w` is null: unit masses, the
/// mass-free drift's own coefficient), then continues in a new block.
fn fill_coefficients(b: &mut FunctionBuilder, coef: StackSlot, n: usize, ch: Value, w: Value) {
    let unit = b.create_block();
    let masses = b.create_block();
    let cont = b.create_block();
    let ju = b.append_block_param(unit, I64);
    let jm = b.append_block_param(masses, I64);
    let zero = b.ins().iconst(I64, 0);
    let base = b.ins().stack_addr(I64, coef, 0);
    let null = b.ins().icmp_imm_u(IntCC::Equal, w, 0);
    b.ins().brif(
        null,
        unit,
        &[BlockArg::Value(zero)],
        masses,
        &[BlockArg::Value(zero)],
    );
    for (block, j, with_masses) in [(unit, ju, false), (masses, jm, true)] {
        b.switch_to_block(block);
        let off = b.ins().ishl_imm_u(j, 3);
        let c = if with_masses {
            let wp = b.ins().iadd(w, off);
            let wj = b.ins().load(F64, flags(), wp, 0);
            b.ins().fmul(ch, wj)
        } else {
            ch
        };
        let at = b.ins().iadd(base, off);
        b.ins().store(flags(), c, at, 0);
        let j1 = b.ins().iadd_imm_s(j, 1);
        let more = b.ins().icmp_imm_u(IntCC::UnsignedLessThan, j1, n as i64);
        b.ins().brif(more, block, &[BlockArg::Value(j1)], cont, &[]);
    }
    b.switch_to_block(cont);
}

/// At most this many drift coefficients and uniform values are kept in registers across the
/// block loop (16 XMM registers, the body needs the rest).
const HOIST: usize = 8;

fn hoist_coefficients(b: &mut FunctionBuilder, coef: StackSlot, n: usize) -> Vec<Value> {
    (0..n)
        .map(|j| {
            let c = b.ins().stack_load(I64, F64, coef, (j * 8) as i32);
            b.ins().splat(F64X2, c)
        })
        .collect()
}

#[allow(clippy::too_many_arguments)]
fn build_kernel(
    ctx: &mut Context,
    fctx: &mut FunctionBuilderContext,
    module: &JITModule,
    graph: &Graph,
    plan: &Plan,
    tables: &[Arc<dyn Tabulated>],
    n: usize,
    lane_arg: u8,
    tangent: bool,
    units: usize,
) {
    let config = module.target_config();
    let mut b = FunctionBuilder::new(&mut ctx.func, fctx);
    let entry = b.create_block();
    b.append_block_params_for_function_params(entry);
    b.switch_to_block(entry);
    let (args, [x, stride, w, _]) = LoopArgs::read(&mut b, tangent, n, 2 * units as i64);
    let sigs = Sigs::new(&mut b, module);
    // The row stride in bytes, reloaded in each block: a load is not loop-invariant code, so
    // the optimizer keeps the row offsets of a long chain inside the loop instead of hoisting
    // them all out into spilled values.
    let stride_slot =
        b.create_sized_stack_slot(StackSlotData::new(StackSlotKind::ExplicitSlot, 8, 3));
    let stride_bytes = b.ins().ishl_imm_u(stride, 3);
    b.ins().stack_store(I64, stride_bytes, stride_slot, 0);
    // The arrays of uniform values and drift coefficients.
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
    let coef = b.create_sized_stack_slot(StackSlotData::new(
        StackSlotKind::ExplicitSlot,
        (n * 8) as u32,
        4,
    ));
    let mut body = SeparableBody {
        graph,
        plan,
        tables,
        sigs: &sigs,
        n,
        units,
        lane_arg,
        tangent,
        x,
        w,
        stride_slot,
        uniforms,
        uniform_offset: vec![0u32; graph.len()],
        coef,
        hoist: n + n_uniform <= HOIST,
        shared: None,
        dhv: None,
        hoisted_coef: Vec::new(),
        hoisted_uniform: Vec::new(),
    };
    step_loops(&mut b, &args, &mut body);
    b.finalize(config);
}

/// The separable kernel's work in the loop nest: the orbit kernel's uniform (constant)
/// subexpressions once per call, the tangent kernel's per stage; per stage the drift
/// coefficients (and, when few, them and the uniform values splatted once for every block);
/// per block the stage's schedule ([`Block::stage`]).
struct SeparableBody<'a> {
    graph: &'a Graph,
    plan: &'a Plan,
    tables: &'a [Arc<dyn Tabulated>],
    sigs: &'a Sigs,
    n: usize,
    units: usize,
    /// The argument the lane rows stand for (0: positions of the orbit; 1: `dq` of the tangent).
    lane_arg: u8,
    tangent: bool,
    x: Value,
    w: Value,
    stride_slot: StackSlot,
    uniforms: StackSlot,
    uniform_offset: Vec<u32>,
    /// The stage's drift coefficients `ch * w_j` (or `ch`), one per row.
    coef: StackSlot,
    hoist: bool,
    /// Argument 0 of the tangent kernel: the stage's shared reference position.
    shared: Option<Value>,
    /// The stage's `dh`, broadcast.
    dhv: Option<Value>,
    /// When few: the coefficients and broadcast uniform values splatted once per stage (kept
    /// in registers across the block loop instead of a load and a shuffle at each use); empty
    /// otherwise.
    hoisted_coef: Vec<Value>,
    hoisted_uniform: Vec<Option<Value>>,
}

impl SeparableBody<'_> {
    fn emit_uniforms(&mut self, b: &mut FunctionBuilder) {
        let (graph, plan) = (self.graph, self.plan);
        let ptrs: Vec<Option<Value>> = (0..plan.layouts.len())
            .map(|a| {
                if a as u8 == self.lane_arg {
                    None
                } else {
                    self.shared
                }
            })
            .collect();
        let mut svals: Vec<Option<Value>> = vec![None; graph.len()];
        let mut next = 0u32;
        for &id in &plan.uniform_order {
            let node = graph.node(id);
            let val = {
                let mut get =
                    |b: &mut FunctionBuilder, o| operand_scalar(b, graph, &ptrs, &svals, o);
                emit_scalar(b, self.sigs, self.tables, node, &mut get)
            };
            svals[id as usize] = Some(val);
            if plan.broadcast[id as usize] {
                self.uniform_offset[id as usize] = next;
                b.ins().stack_store(I64, val, self.uniforms, next as i32);
                next += 8;
            }
        }
    }

    /// The code of one block of lanes at byte offset `off`.
    fn lanes<'b>(&'b self, b: &mut FunctionBuilder, off: Value) -> Block<'b> {
        Block {
            kernel: self,
            base: b.ins().iadd(self.x, off),
            stride: b.ins().stack_load(I64, I64, self.stride_slot, 0),
            addr: RefCell::new(vec![None; 2 * self.n]),
            half: Cell::new(None),
        }
    }

    /// The drift coefficients `ch * w_j` (or `ch`), and splatted when few.
    fn coefficients(&mut self, b: &mut FunctionBuilder, ch: Value) {
        fill_coefficients(b, self.coef, self.n, ch, self.w);
        self.hoisted_coef = if self.hoist {
            hoist_coefficients(b, self.coef, self.n)
        } else {
            Vec::new()
        };
    }
}

impl StepBody for SeparableBody<'_> {
    fn run(&mut self, b: &mut FunctionBuilder) {
        if !self.tangent {
            self.emit_uniforms(b);
        }
    }

    fn stage(&mut self, b: &mut FunctionBuilder, ch: Value, dh: Value, reference: Option<Value>) {
        self.shared = reference;
        if self.tangent {
            self.emit_uniforms(b);
        }
        self.dhv = Some(b.ins().splat(F64X2, dh));
        self.coefficients(b, ch);
        self.hoisted_uniform = Vec::new();
        if self.hoist {
            self.hoisted_uniform = vec![None; self.graph.len()];
            for &id in &self.plan.uniform_order {
                if self.plan.broadcast[id as usize] {
                    let off = self.uniform_offset[id as usize] as i32;
                    let v = b.ins().stack_load(I64, F64, self.uniforms, off);
                    self.hoisted_uniform[id as usize] = Some(b.ins().splat(F64X2, v));
                }
            }
        }
    }

    fn block(&mut self, b: &mut FunctionBuilder, off: Value) {
        let k = vconsts(b);
        let dhv = self.dhv.expect("a stage before its blocks");
        self.lanes(b, off).stage(b, &k, dhv);
    }

    fn last(&mut self, b: &mut FunctionBuilder, ch: Value) {
        self.shared = None;
        self.hoisted_uniform = Vec::new();
        self.coefficients(b, ch);
    }

    fn last_block(&mut self, b: &mut FunctionBuilder, off: Value) {
        let block = self.lanes(b, off);
        for j in 0..self.n {
            block.drift_row(b, j);
        }
    }
}
