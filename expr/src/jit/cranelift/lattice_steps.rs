//! The splitting step kernels of [`crate::jit::step`] for a potential made of lattice sums: the force
//! (or `Hess V dq`) of each block of lanes computed by the sums' loops ([`crate::jit::cranelift::lattice`]) into
//! the call's scratch rows, in the order of [`crate::lattice::LatticeEvaluator`], so every lane
//! gets the bits of the generic step loops around the scalar functions.
//!
//! ```text
//! for step, for stage i                      (as the graph kernels)
//!     for each block of 2 or 4 lanes
//!         drift   q_j += c_j p_j, g_j = -0    (one pass over the rows)
//!         force   the rest's derivatives, then each sum: its boundary terms and the loop
//!                 over its interior, g_{i+k} += d_k term by term
//!         kick    p_j -= dh g_j               (one pass)
//!     last drift, block by block
//! ```
//!
//! The tangent kernel reads the reference position of the stage (shared by the lanes) where the
//! orbit kernel reads each lane's own: the term's position-only operations are scalar code,
//! once per term and block, broadcast into the lane code of the direction's.
//!
//! Beside them, where the lattice has a plan for it and `options.fused_pass` asks, the fused
//! one-orbit pass ([`super::fused`]).

use std::sync::{Arc, Mutex};
use std::time::Instant;

use cranelift_codegen::Context;
use cranelift_codegen::ir::condcodes::IntCC;
use cranelift_codegen::ir::types::{F64, F64X2, I64};
use cranelift_codegen::ir::{AbiParam, BlockArg, InstBuilder, UserFuncName, Value};
use cranelift_frontend::{FunctionBuilder, FunctionBuilderContext};
use cranelift_jit::JITModule;
use cranelift_module::{Linkage, Module};

use super::lattice::{Body, Val, accumulate, site_loop};
use super::step::{CraneliftKernels, OrbitStepsFnPtr, TangentStepsFnPtr, vconsts};
use super::step_loops::{LoopArgs, StepBody, step_loops};
use super::{Sigs, VConsts, flags, new_module};
use crate::graph::{Graph, Node, NodeId, Tabulated};
use crate::jit::lattice_plan::{
    ForcePart, OutputPlan, WindowPlan, arrays_of, check_size, rest_derivatives, shift_range,
    sum_contributions,
};
use crate::jit::step::{Code, StepKernels};
use crate::jit::{JitError, Options};
use crate::lattice::{
    ARG_Q, ARG_SITE, ARG_SITE_DIRECTION, ARG_SITE_PARAM, ARG_V, LatticePotential, SiteSum,
};

/// Compiles the orbit kernel (and the tangent kernel when the potential's Hessian-vector
/// product was derived) of a lattice potential with `options.lane_block` lanes per block, and
/// its fused one-orbit pass where `options.fused_pass` asks and it has a plan.
pub fn compile_lattice_steps(
    graph: &Graph,
    lattice: &LatticePotential,
    options: &Options,
) -> Result<StepKernels, JitError> {
    let start = Instant::now();
    if options.lane_block != 2 && options.lane_block != 4 {
        return Err(JitError::Host(format!(
            "lane_block must be 2 or 4, not {}",
            options.lane_block
        )));
    }
    let units = options.lane_block / 2;
    check_size(lattice)?;
    let (regalloc, allocation) = super::lattice::lattice_regalloc(options, graph, lattice, false);
    let (mut module, _) = new_module(options.opt_level, regalloc)?;
    let tables: Box<[Arc<dyn Tabulated>]> = graph.tables().to_vec().into_boxed_slice();
    let arrays = arrays_of(lattice);
    let mut ctx = Context::new();
    let mut fctx = FunctionBuilderContext::new();
    let mut ids = Vec::new();
    let kinds: &[bool] = if lattice.has_hessian() {
        &[false, true]
    } else {
        &[false]
    };
    for &tangent in kinds {
        let ptr = module.target_config().pointer_type();
        let mut sig = module.make_signature();
        for _ in 0..if tangent { 10 } else { 9 } {
            sig.params.push(AbiParam::new(ptr));
        }
        let variant = if tangent { "tangent" } else { "orbit" };
        let codegen = |e: cranelift_module::ModuleError| JitError::Codegen {
            function: usize::from(tangent),
            variant,
            message: format!("{e:?}"),
        };
        let id = module
            .declare_function(&format!("lattice_steps_{variant}"), Linkage::Local, &sig)
            .map_err(codegen)?;
        module.clear_context(&mut ctx);
        ctx.func.signature = sig;
        ctx.func.name = UserFuncName::user(0, id.as_u32());
        let kernel = Kernel {
            graph,
            lattice,
            plan: OutputPlan::new(graph, lattice, tangent, true),
            tables: &tables,
            arrays: &arrays,
            units,
            tangent,
        };
        kernel.build(&mut ctx, &mut fctx, &module);
        module.define_function(id, &mut ctx).map_err(codegen)?;
        ids.push((id, tangent));
    }
    // The pass is an optimization with the same bits as the one-orbit way: a function it
    // cannot define leaves the caller that way, not without step kernels.
    let fused_id = if options.fused_pass {
        super::fused::define(
            &mut module,
            &mut ctx,
            &mut fctx,
            graph,
            lattice,
            &tables,
            &arrays,
        )
        .unwrap_or(None)
    } else {
        None
    };
    module
        .finalize_definitions()
        .map_err(|e| JitError::Link(format!("{e:?}")))?;
    let mut orbit = None;
    let mut tangent = None;
    for (id, is_tangent) in ids {
        let code = module.get_finalized_function(id);
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
    // SAFETY: defined by `fused::define` with the C kernel's signature (nine pointer-sized
    // integer parameters, no results, the host's C calling convention).
    let fused = fused_id.map(|id| unsafe {
        std::mem::transmute::<*const u8, crate::jit::c::CFusedFn>(module.get_finalized_function(id))
    });
    let block = options.lane_block;
    Ok(StepKernels::new(
        Code::Cranelift(CraneliftKernels {
            modules: Mutex::new(vec![module]),
            orbit: orbit.expect("the orbit kernel is always compiled"),
            tangent,
            fused,
            allocation,
        }),
        lattice.n,
        [block; 2],
        lattice.n,
        tables,
        arrays.into_iter().map(|(_, a)| a).collect(),
        start.elapsed(),
        allocation,
    ))
}

struct Kernel<'a> {
    graph: &'a Graph,
    lattice: &'a LatticePotential,
    /// Where each row is drifted and kicked, which loops keep a window of sites.
    plan: OutputPlan,
    tables: &'a [Arc<dyn Tabulated>],
    arrays: &'a [(String, Arc<[f64]>)],
    units: usize,
    tangent: bool,
}

/// What one block's code reads: its lanes' rows, the stage's reference position (tangent), the
/// scratch rows of the force, the row stride in bytes.
#[derive(Clone, Copy)]
struct Rows {
    x: Value,
    stride: Value,
    stage: Option<Value>,
    g: Value,
}

/// What a stage's passes over a block need: the drift coefficient `ch` and the inverse masses
/// `w` (null: unit masses), `dh` broadcast, `N` rows in bytes (from `q_r` to `p_r`).
struct Stage {
    ch: Value,
    w: Value,
    dhv: Value,
    half: Value,
}

/// Where a term's slots are: a boundary term's sites known at compile time, or the loop's term
/// `i` (an SSA value).
#[derive(Clone, Copy)]
enum At {
    Term(i64),
    Loop(Value),
}

/// The lattice kernel's work in the loop nest: per block the plan's passes (rows drifted before
/// the parts, the force's rows that must start at -0, the parts, whose window loops drift and
/// kick as they go, the rows the force never read, the rows left to kick); the last drift over
/// every row.
struct LatticeBody<'a> {
    kernel: &'a Kernel<'a>,
    sigs: &'a Sigs,
    x: Value,
    /// The row stride in bytes, and `N` rows in bytes.
    sb: Value,
    half: Value,
    w: Value,
    scratch: Value,
    /// The stage's drift coefficient, `dh` broadcast and reference position (tangent).
    stage: Option<(Value, Value, Option<Value>)>,
}

impl StepBody for LatticeBody<'_> {
    fn run(&mut self, _: &mut FunctionBuilder) {}

    fn stage(&mut self, b: &mut FunctionBuilder, ch: Value, dh: Value, reference: Option<Value>) {
        self.stage = Some((ch, b.ins().splat(F64X2, dh), reference));
    }

    fn block(&mut self, b: &mut FunctionBuilder, off: Value) {
        let kernel = self.kernel;
        let (ch, dhv, stage) = self.stage.expect("a stage before its blocks");
        let k = vconsts(b);
        let rows = Rows {
            x: b.ins().iadd(self.x, off),
            stride: self.sb,
            stage,
            g: self.scratch,
        };
        let (w, half) = (self.w, self.half);
        let st = Stage { ch, w, dhv, half };
        for &range in &kernel.plan.pre_drift {
            kernel.drift_rows(b, &st, rows, range);
        }
        for &range in &kernel.plan.init {
            kernel.clear_rows(b, rows, range);
        }
        kernel.force(b, self.sigs, &k, rows, &st);
        for &range in &kernel.plan.post_drift {
            kernel.drift_rows(b, &st, rows, range);
        }
        for &range in &kernel.plan.post_kick {
            kernel.kick_rows(b, &st, rows, range);
        }
    }

    fn last(&mut self, _: &mut FunctionBuilder, ch: Value) {
        self.stage = Some((ch, ch, None));
    }

    fn last_block(&mut self, b: &mut FunctionBuilder, off: Value) {
        let (ch, _, _) = self.stage.expect("the last drift's coefficient");
        let rows = Rows {
            x: b.ins().iadd(self.x, off),
            stride: self.sb,
            stage: None,
            g: self.scratch,
        };
        let st = Stage {
            ch,
            w: self.w,
            dhv: ch,
            half: self.half,
        };
        self.kernel
            .drift_rows(b, &st, rows, (0, self.kernel.lattice.n));
    }
}

impl Kernel<'_> {
    /// Bytes of one scratch row (a block of lanes).
    fn g_row(&self) -> i64 {
        16 * self.units as i64
    }

    fn build(&self, ctx: &mut Context, fctx: &mut FunctionBuilderContext, module: &JITModule) {
        let n = self.lattice.n;
        let mut b = FunctionBuilder::new(&mut ctx.func, fctx);
        let entry = b.create_block();
        b.append_block_params_for_function_params(entry);
        b.switch_to_block(entry);
        let block_lanes = 2 * self.units as i64;
        let (args, [x, stride, w, scratch]) = LoopArgs::read(&mut b, self.tangent, n, block_lanes);
        let sigs = Sigs::new(&mut b, module);
        let sb = b.ins().ishl_imm_u(stride, 3);
        let half = b.ins().imul_imm_s(sb, n as i64);
        let mut body = LatticeBody {
            kernel: self,
            sigs: &sigs,
            x,
            sb,
            half,
            w,
            scratch,
            stage: None,
        };
        step_loops(&mut b, &args, &mut body);
        b.finalize(module.target_config());
    }

    /// The drift coefficient of row `r` (an SSA row index): `ch w_r`, or `ch` where `w` is null
    /// (unit masses: the mass-free drift's own coefficient).
    fn coefficient(&self, b: &mut FunctionBuilder, st: &Stage, r: Value) -> Value {
        let masses = b.create_block();
        let done = b.create_block();
        let c = b.append_block_param(done, F64);
        let null = b.ins().icmp_imm_u(IntCC::Equal, st.w, 0);
        b.ins()
            .brif(null, done, &[BlockArg::Value(st.ch)], masses, &[]);
        b.switch_to_block(masses);
        let off = b.ins().ishl_imm_u(r, 3);
        let wp = b.ins().iadd(st.w, off);
        let wr = b.ins().load(F64, flags(), wp, 0);
        let cw = b.ins().fmul(st.ch, wr);
        b.ins().jump(done, &[BlockArg::Value(cw)]);
        b.switch_to_block(done);
        c
    }

    /// `q_r += c_r p_r` for the row `r` at `row`; returns the drifted lane values.
    fn drift_row(&self, b: &mut FunctionBuilder, st: &Stage, row: Value, c: Value) -> [Value; 2] {
        let cv = b.ins().splat(F64X2, c);
        let prow = b.ins().iadd(row, st.half);
        let mut out = [cv; 2];
        for (unit, slot) in out.iter_mut().enumerate().take(self.units) {
            let o = 16 * unit as i32;
            let q = b.ins().load(F64X2, flags(), row, o);
            let p = b.ins().load(F64X2, flags(), prow, o);
            let cp = b.ins().fmul(cv, p);
            let q = b.ins().fadd(q, cp);
            b.ins().store(flags(), q, row, o);
            *slot = q;
        }
        if self.units == 1 {
            out[1] = out[0];
        }
        out
    }

    /// `p_r -= dh f` for the row `r` at `row` (`f` per unit).
    fn kick_row(&self, b: &mut FunctionBuilder, st: &Stage, row: Value, f: [Value; 2]) {
        let prow = b.ins().iadd(row, st.half);
        for (unit, &f) in f.iter().enumerate().take(self.units) {
            let o = 16 * unit as i32;
            let p = b.ins().load(F64X2, flags(), prow, o);
            let df = b.ins().fmul(st.dhv, f);
            let p = b.ins().fsub(p, df);
            b.ins().store(flags(), p, prow, o);
        }
    }

    /// `for r in a..z`: `body(r, row address, scratch row address)`.
    fn rows_loop(
        &self,
        b: &mut FunctionBuilder,
        rows: Rows,
        (a, z): (usize, usize),
        body: &mut dyn FnMut(&mut FunctionBuilder, Value, Value, Value),
    ) {
        let head = b.create_block();
        let done = b.create_block();
        let r = b.append_block_param(head, I64);
        let row = b.append_block_param(head, I64);
        let g = b.append_block_param(head, I64);
        let r0 = b.ins().iconst(I64, a as i64);
        let off = b.ins().imul_imm_s(rows.stride, a as i64);
        let row0 = b.ins().iadd(rows.x, off);
        let g0 = b.ins().iadd_imm_s(rows.g, a as i64 * self.g_row());
        b.ins().jump(
            head,
            &[
                BlockArg::Value(r0),
                BlockArg::Value(row0),
                BlockArg::Value(g0),
            ],
        );
        b.switch_to_block(head);
        body(b, r, row, g);
        let r1 = b.ins().iadd_imm_s(r, 1);
        let row1 = b.ins().iadd(row, rows.stride);
        let g1 = b.ins().iadd_imm_s(g, self.g_row());
        let more = b.ins().icmp_imm_s(IntCC::SignedLessThan, r1, z as i64);
        b.ins().brif(
            more,
            head,
            &[
                BlockArg::Value(r1),
                BlockArg::Value(row1),
                BlockArg::Value(g1),
            ],
            done,
            &[],
        );
        b.switch_to_block(done);
    }

    /// `q_r += c_r p_r` for the rows `a..z`.
    fn drift_rows(&self, b: &mut FunctionBuilder, st: &Stage, rows: Rows, range: (usize, usize)) {
        self.rows_loop(b, rows, range, &mut |b, r, row, _| {
            let c = self.coefficient(b, st, r);
            self.drift_row(b, st, row, c);
        });
    }

    /// `p_r -= dh g_r` for the rows `a..z`.
    fn kick_rows(&self, b: &mut FunctionBuilder, st: &Stage, rows: Rows, range: (usize, usize)) {
        self.rows_loop(b, rows, range, &mut |b, _, row, g| {
            let mut f = [g; 2];
            for (unit, slot) in f.iter_mut().enumerate().take(self.units) {
                *slot = b.ins().load(F64X2, flags(), g, 16 * unit as i32);
            }
            self.kick_row(b, st, row, f);
        });
    }

    /// The force's scratch rows `a..z` set to `-0`.
    fn clear_rows(&self, b: &mut FunctionBuilder, rows: Rows, range: (usize, usize)) {
        self.rows_loop(b, rows, range, &mut |b, _, _, g| {
            let z = b.ins().f64const(-0.0);
            let z = b.ins().splat(F64X2, z);
            for unit in 0..self.units {
                b.ins().store(flags(), z, g, 16 * unit as i32);
            }
        });
    }

    /// The lanes' values of row `j` of the block (`F64X2` per unit).
    fn lane_row(&self, b: &mut FunctionBuilder, row: Value) -> Val {
        let mut v = [row; 2];
        for (unit, slot) in v.iter_mut().enumerate().take(self.units) {
            *slot = b.ins().load(F64X2, flags(), row, 16 * unit as i32);
        }
        if self.units == 1 {
            v[1] = v[0];
        }
        Val::Lanes(v)
    }

    /// `g_row += c d` for every unit at the scratch row's address `row + off`.
    fn add_to(&self, b: &mut FunctionBuilder, row: Value, off: i64, c: f64, d: Val) {
        let d = match d {
            Val::Lanes(v) => v,
            Val::One(x) => {
                let v = b.ins().splat(F64X2, x);
                [v, v]
            }
        };
        for (unit, &d) in d.iter().enumerate().take(self.units) {
            let o = (off + 16 * unit as i64) as i32;
            let acc = b.ins().load(F64X2, flags(), row, o);
            let acc = accumulate(b, c, acc, d, true);
            b.ins().store(flags(), acc, row, o);
        }
    }

    /// The force (or `Hess V dq`) of the block into the scratch rows, which hold `-0`.
    fn force(&self, b: &mut FunctionBuilder, sigs: &Sigs, k: &VConsts, rows: Rows, st: &Stage) {
        let lattice = self.lattice;
        let body = Body {
            graph: self.graph,
            sigs,
            tables: self.tables,
            units: self.units,
            k: Some(k),
        };
        let sums = sum_contributions(self.graph, lattice, self.tangent);
        // One term of sum `s`: its derivatives added to the scratch rows of the sites its slots
        // read.
        let term = |b: &mut FunctionBuilder, s: usize, roots: &[NodeId], at: At| {
            let sum = &lattice.sums[s];
            let mut leaf =
                |b: &mut FunctionBuilder, _: NodeId, node: &Node| self.slot(b, node, sum, at, rows);
            let vals = body.emit(b, roots, &mut leaf);
            // Where the scratch row of site `i + shift` is: a constant site's, or the
            // loop's row `i - 1` and an offset.
            let g_base = match at {
                At::Term(_) => rows.g,
                At::Loop(i) => {
                    let im1 = b.ins().iadd_imm_s(i, -1);
                    let off = b.ins().imul_imm_s(im1, self.g_row());
                    b.ins().iadd(rows.g, off)
                }
            };
            for (&shift, &(factor, r)) in sum.variables.iter().zip(&sums[s].0) {
                let off = match at {
                    At::Term(i) => match sum.site(i, shift) {
                        Some(j) => j as i64 * self.g_row(),
                        None => continue,
                    },
                    At::Loop(_) => shift * self.g_row(),
                };
                let dv = vals[r as usize].expect("emitted");
                self.add_to(b, g_base, off, factor, dv);
            }
        };
        for part in &self.plan.parts {
            match *part {
                ForcePart::Rest => {
                    let rest = rest_derivatives(lattice, self.tangent);
                    let roots: Vec<NodeId> = rest.iter().map(|&(_, id)| id).collect();
                    let mut leaf = |b: &mut FunctionBuilder, _: NodeId, node: &Node| match *node {
                        Node::Const(c) => Val::One(b.ins().f64const(c)),
                        Node::Input { arg: ARG_Q, index } if !self.tangent => {
                            let row = self.row(b, rows, index as i64);
                            self.lane_row(b, row)
                        }
                        Node::Input { arg: ARG_Q, index } => {
                            let st = rows.stage.expect("the tangent kernel's stage");
                            Val::One(b.ins().load(F64, flags(), st, (index * 8) as i32))
                        }
                        Node::Input { arg: ARG_V, index } => {
                            let row = self.row(b, rows, index as i64);
                            self.lane_row(b, row)
                        }
                        _ => unreachable!("a leaf of the expression around the sums: {node:?}"),
                    };
                    let vals = body.emit(b, &roots, &mut leaf);
                    for &(j, id) in rest {
                        let d = vals[id as usize].expect("emitted");
                        self.add_to(b, rows.g, j as i64 * self.g_row(), 1.0, d);
                    }
                }
                ForcePart::Term { sum, i } => term(b, sum, &sums[sum].1, At::Term(i)),
                ForcePart::Loop { sum: s, from, to } => {
                    let roots = &sums[s].1;
                    match self.plan.window[s] {
                        Some(plan) => {
                            let window = LaneWindow {
                                kernel: self,
                                body: &body,
                                sum: &lattice.sums[s],
                                contributions: &sums[s].0,
                                roots,
                                rows,
                                st,
                                plan,
                            };
                            window.build(b, (from, to));
                        }
                        None => {
                            site_loop(b, from, to, None, &mut |b, i, _| {
                                term(b, s, roots, At::Loop(i));
                                None
                            });
                        }
                    }
                }
            }
        }
    }

    /// The address of the block's row `j` (0-based).
    fn row(&self, b: &mut FunctionBuilder, rows: Rows, j: i64) -> Value {
        if j == 0 {
            return rows.x;
        }
        let off = b.ins().imul_imm_s(rows.stride, j);
        b.ins().iadd(rows.x, off)
    }

    /// A leaf of a term: a constant, a slot (the lanes' rows, or the stage's shared position in
    /// the tangent kernel; a wall is 0), an array parameter.
    fn slot(&self, b: &mut FunctionBuilder, node: &Node, sum: &SiteSum, at: At, rows: Rows) -> Val {
        enum Source {
            Lanes,
            Stage,
            Array(i64),
        }
        let (source, shift) = match *node {
            Node::Const(c) => return Val::One(b.ins().f64const(c)),
            Node::Input {
                arg: ARG_SITE,
                index,
            } if self.tangent => (Source::Stage, sum.variables[index as usize]),
            Node::Input {
                arg: ARG_SITE,
                index,
            } => (Source::Lanes, sum.variables[index as usize]),
            Node::Input {
                arg: ARG_SITE_DIRECTION,
                index,
            } => (Source::Lanes, sum.variables[index as usize]),
            Node::Input {
                arg: ARG_SITE_PARAM,
                index,
            } => {
                let p = &sum.params[index as usize];
                if let At::Term(i) = at {
                    let j = sum.site(i, p.shift).expect("parameters inside the lattice");
                    return Val::One(b.ins().f64const(p.values[j]));
                }
                let (_, a) = self
                    .arrays
                    .iter()
                    .find(|(name, _)| *name == p.name)
                    .expect("every array a sum reads");
                (Source::Array(a.as_ptr() as i64), p.shift)
            }
            _ => unreachable!("a leaf of a term: {node:?}"),
        };
        match at {
            At::Term(i) => {
                let Some(j) = sum.site(i, shift) else {
                    return Val::One(b.ins().f64const(0.0));
                };
                match source {
                    Source::Lanes => {
                        let row = self.row(b, rows, j as i64);
                        self.lane_row(b, row)
                    }
                    Source::Stage => {
                        let st = rows.stage.expect("the tangent kernel's stage");
                        Val::One(b.ins().load(F64, flags(), st, (j * 8) as i32))
                    }
                    Source::Array(_) => unreachable!("a constant above"),
                }
            }
            At::Loop(i) => {
                // Site i + shift is row i + shift - 1.
                let r = b.ins().iadd_imm_s(i, shift - 1);
                match source {
                    Source::Lanes => {
                        let off = b.ins().imul(r, rows.stride);
                        let row = b.ins().iadd(rows.x, off);
                        self.lane_row(b, row)
                    }
                    Source::Stage | Source::Array(_) => {
                        let base = match source {
                            Source::Stage => rows.stage.expect("the tangent kernel's stage"),
                            Source::Array(addr) => b.ins().iconst(I64, addr),
                            Source::Lanes => unreachable!(),
                        };
                        let off = b.ins().ishl_imm_u(r, 3);
                        let p = b.ins().iadd(base, off);
                        Val::One(b.ins().load(F64, flags(), p, 0))
                    }
                }
            }
        }
    }
}

/// A sum's interior loop in a step kernel, with its window of sites carried in registers from
/// term to term (as [`crate::jit::cranelift::lattice`]'s scalar window, for a block of lanes): the row entering
/// the window drifted before its first read when the plan says so, the site a term completes
/// kicked at once when the plan says so (else stored in its scratch row), the slots a term
/// shares with the next one read once.
struct LaneWindow<'a> {
    kernel: &'a Kernel<'a>,
    body: &'a Body<'a>,
    sum: &'a SiteSum,
    contributions: &'a [(f64, NodeId)],
    roots: &'a [NodeId],
    rows: Rows,
    st: &'a Stage,
    plan: WindowPlan,
}

/// What a [`LaneWindow`] carries from term to term: the sums of the sites `i + kmin ..
/// i + kmax - 1` (lanes), the carried slots' lane values (positions or directions) and, in the
/// tangent kernel, their shared positions.
struct LaneState {
    accs: Vec<[Value; 2]>,
    lanes: Vec<[Value; 2]>,
    shared: Vec<Value>,
}

impl LaneWindow<'_> {
    fn units(&self) -> usize {
        self.kernel.units
    }

    fn carry(&self) -> Vec<(usize, usize)> {
        let shifts = &self.sum.variables;
        shifts
            .iter()
            .enumerate()
            .filter_map(|(s, &k)| shifts.iter().position(|&k2| k2 == k + 1).map(|s2| (s, s2)))
            .collect()
    }

    /// The lane values at `row`.
    fn load(&self, b: &mut FunctionBuilder, row: Value, off: i32) -> [Value; 2] {
        let mut v = [row; 2];
        for (unit, slot) in v.iter_mut().enumerate().take(self.units()) {
            *slot = b.ins().load(F64X2, flags(), row, off + 16 * unit as i32);
        }
        if self.units() == 1 {
            v[1] = v[0];
        }
        v
    }

    fn args(&self, state: &LaneState) -> Vec<BlockArg> {
        let u = self.units();
        state
            .accs
            .iter()
            .chain(&state.lanes)
            .flat_map(|v| v[..u].iter().copied())
            .chain(state.shared.iter().copied())
            .map(BlockArg::Value)
            .collect()
    }

    fn params(
        &self,
        b: &mut FunctionBuilder,
        block: cranelift_codegen::ir::Block,
        like: &LaneState,
    ) -> LaneState {
        let u = self.units();
        let lanes = |b: &mut FunctionBuilder| {
            let mut v = [Value::from_u32(0); 2];
            for slot in v.iter_mut().take(u) {
                *slot = b.append_block_param(block, F64X2);
            }
            if u == 1 {
                v[1] = v[0];
            }
            v
        };
        let accs = like.accs.iter().map(|_| lanes(b)).collect();
        let carried = like.lanes.iter().map(|_| lanes(b)).collect();
        let shared = like
            .shared
            .iter()
            .map(|_| b.append_block_param(block, F64))
            .collect();
        LaneState {
            accs,
            lanes: carried,
            shared,
        }
    }

    fn build(&self, b: &mut FunctionBuilder, (from, to): (i64, i64)) {
        let rows = self.rows;
        let shifts = &self.sum.variables;
        let (kmin, kmax) = shift_range(shifts);
        let carry = self.carry();
        let g_row = self.kernel.g_row();
        // Entry: the window's sites as the scratch rows hold them, the carried slots' values.
        let mut accs = Vec::new();
        for t in 0..kmax - kmin {
            let off = ((from + kmin + t - 1) * g_row) as i32;
            accs.push(self.load(b, rows.g, off));
        }
        let mut lanes = Vec::new();
        let mut shared = Vec::new();
        for &(s, _) in &carry {
            let r = from + shifts[s] - 1;
            let row = self.kernel.row(b, rows, r);
            lanes.push(self.load(b, row, 0));
            if let Some(stage) = rows.stage {
                shared.push(b.ins().load(F64, flags(), stage, (r * 8) as i32));
            }
        }
        let state = LaneState {
            accs,
            lanes,
            shared,
        };
        let head = b.create_block();
        let exit = b.create_block();
        let i = b.append_block_param(head, I64);
        let inside = self.params(b, head, &state);
        let out = self.params(b, exit, &state);
        let mut args = vec![BlockArg::Value(b.ins().iconst(I64, from))];
        args.extend(self.args(&state));
        b.ins().jump(head, &args);
        b.switch_to_block(head);
        let next = self.step(b, i, inside, &carry);
        let i1 = b.ins().iadd_imm_s(i, 1);
        let more = b.ins().icmp_imm_s(IntCC::SignedLessThanOrEqual, i1, to);
        let mut loop_args = vec![BlockArg::Value(i1)];
        loop_args.extend(self.args(&next));
        b.ins()
            .brif(more, head, &loop_args, exit, &self.args(&next));
        b.switch_to_block(exit);
        // The window's sites after the last term.
        for (t, acc) in out.accs.iter().enumerate() {
            let off = (to + 1 + kmin + t as i64 - 1) * g_row;
            for (unit, &v) in acc.iter().enumerate().take(self.units()) {
                b.ins()
                    .store(flags(), v, rows.g, (off + 16 * unit as i64) as i32);
            }
        }
    }

    /// Term `i`: the entering row drifted (if planned), the term's contributions added to the
    /// window, the completed site kicked or stored.
    fn step(
        &self,
        b: &mut FunctionBuilder,
        i: Value,
        state: LaneState,
        carry: &[(usize, usize)],
    ) -> LaneState {
        let (rows, sum, k) = (self.rows, self.sum, self.kernel);
        let shifts = &sum.variables;
        let (kmin, kmax) = shift_range(shifts);
        let g_row = k.g_row();
        let im1 = b.ins().iadd_imm_s(i, -1);
        let off = b.ins().imul(im1, rows.stride);
        let xi = b.ins().iadd(rows.x, off);
        let goff = b.ins().imul_imm_s(im1, g_row);
        let gi = b.ins().iadd(rows.g, goff);
        let si = rows.stage.map(|st| {
            let o = b.ins().ishl_imm_u(im1, 3);
            b.ins().iadd(st, o)
        });
        // The row of shift k in this term: row i + k - 1.
        let row_of = |b: &mut FunctionBuilder, k: i64| {
            if k == 0 {
                xi
            } else {
                let o = b.ins().imul_imm_s(rows.stride, k);
                b.ins().iadd(xi, o)
            }
        };
        let mut entering = None;
        if self.plan.drift {
            let r = b.ins().iadd_imm_s(i, kmax - 1);
            let c = k.coefficient(b, self.st, r);
            let row = row_of(b, kmax);
            entering = Some(k.drift_row(b, self.st, row, c));
        }
        // The slots' values.
        let mut lane_vals: Vec<Option<[Value; 2]>> = vec![None; shifts.len()];
        let mut shared_vals: Vec<Option<Value>> = vec![None; shifts.len()];
        for ((&(s, _), &v), sh) in carry
            .iter()
            .zip(&state.lanes)
            .zip(state.shared.iter().map(Some).chain(std::iter::repeat(None)))
        {
            lane_vals[s] = Some(v);
            shared_vals[s] = sh.copied();
        }
        for (s, &shift) in shifts.iter().enumerate() {
            if lane_vals[s].is_none() {
                lane_vals[s] = Some(match entering {
                    Some(v) if shift == kmax => v,
                    _ => {
                        let row = row_of(b, shift);
                        self.load(b, row, 0)
                    }
                });
            }
            if let (Some(si), None) = (si, shared_vals[s]) {
                shared_vals[s] = Some(b.ins().load(F64, flags(), si, (shift * 8) as i32));
            }
        }
        let vals = {
            let mut leaf = |b: &mut FunctionBuilder, _: NodeId, node: &Node| match *node {
                Node::Input {
                    arg: ARG_SITE,
                    index,
                } if k.tangent => Val::One(shared_vals[index as usize].expect("loaded")),
                Node::Input {
                    arg: ARG_SITE,
                    index,
                }
                | Node::Input {
                    arg: ARG_SITE_DIRECTION,
                    index,
                } => Val::Lanes(lane_vals[index as usize].expect("loaded")),
                _ => k.slot(b, node, sum, At::Loop(i), rows),
            };
            self.body.emit(b, self.roots, &mut leaf)
        };
        let u = self.units();
        let mut accs: Vec<Option<[Value; 2]>> = state.accs.iter().map(|&a| Some(a)).collect();
        accs.push(if self.plan.fresh {
            None
        } else {
            Some(self.load(b, gi, ((kmax) * g_row) as i32))
        });
        for (&shift, &(factor, r)) in shifts.iter().zip(self.contributions) {
            let d = match vals[r as usize].expect("emitted") {
                Val::Lanes(v) => v,
                Val::One(x) => {
                    let v = b.ins().splat(F64X2, x);
                    [v, v]
                }
            };
            let t = (shift - kmin) as usize;
            let mut next = [d[0]; 2];
            for unit in 0..u {
                next[unit] = match accs[t] {
                    // `-0 + d` is `d`.
                    None if factor == 1.0 => d[unit],
                    None => {
                        let z = b.ins().f64const(-0.0);
                        let z = b.ins().splat(F64X2, z);
                        accumulate(b, factor, z, d[unit], true)
                    }
                    Some(a) => accumulate(b, factor, a[unit], d[unit], true),
                };
            }
            if u == 1 {
                next[1] = next[0];
            }
            accs[t] = Some(next);
        }
        let zero = |b: &mut FunctionBuilder| {
            let z = b.ins().f64const(-0.0);
            let z = b.ins().splat(F64X2, z);
            [z, z]
        };
        let done = match accs[0] {
            Some(a) => a,
            None => zero(b),
        };
        if self.plan.kick {
            let row = row_of(b, kmin);
            k.kick_row(b, self.st, row, done);
        } else {
            for (unit, &v) in done.iter().enumerate().take(u) {
                b.ins()
                    .store(flags(), v, gi, (kmin * g_row + 16 * unit as i64) as i32);
            }
        }
        let accs = accs[1..]
            .iter()
            .map(|&a| match a {
                Some(a) => a,
                None => zero(b),
            })
            .collect();
        let lanes = carry
            .iter()
            .map(|&(_, s2)| lane_vals[s2].expect("loaded"))
            .collect();
        let shared = if rows.stage.is_some() {
            carry
                .iter()
                .map(|&(_, s2)| shared_vals[s2].expect("loaded"))
                .collect()
        } else {
            Vec::new()
        };
        LaneState {
            accs,
            lanes,
            shared,
        }
    }
}
