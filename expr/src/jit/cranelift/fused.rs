//! The fused one-orbit pass of a lattice potential ([`crate::jit::fused_plan`]) printed as
//! Cranelift code, for hosts without a C compiler (or `CHAOSCOPE_CC=none`): one orbit and its
//! tangent vectors stepped together, vectorized along the sites in vectors of two (`F64X2`, the
//! width Cranelift gives on x86-64 and aarch64). It prints the plan's stage-by-stage form; the
//! C printer's one-pass sweep ([`crate::jit::c::fused`]) leans on shuffles and wide registers
//! that two lanes do not repay. Per step:
//!
//! ```text
//! for each stage i
//!     drift   q += (drift[i] w) p of the orbit and of every vector      (two sites a vector)
//!     kick    the orbit's regular sites: g_j = the derivatives of the terms that read site j,
//!             in the plan's order; p_j -= kick[i] g_j                   (two sites a vector,
//!             the rest of a run one by one); the end sites one by one
//!             every vector: the same with Hess V(q) dq into dp
//! last drift
//! ```
//!
//! Every site adds what the C printer's adds, in the same order, and the drifts and kicks are
//! the splitting's own (`q + (ch w_j) p`, `p - dh g`, no fused multiply-add), so the bits are
//! [`crate::lattice::LatticeEvaluator`]'s, as are those of the C kernel and the step kernels.
//! The signature is the C kernel's ([`crate::jit::c::CFusedFn`]); its `env` is not read: the
//! array parameters are read by address, as the other Cranelift kernels read them.

use std::sync::Arc;

use cranelift_codegen::Context;
use cranelift_codegen::ir::condcodes::IntCC;
use cranelift_codegen::ir::types::{F64, F64X2, I64};
use cranelift_codegen::ir::{AbiParam, BlockArg, InstBuilder, UserFuncName, Value};
use cranelift_frontend::{FunctionBuilder, FunctionBuilderContext};
use cranelift_jit::JITModule;
use cranelift_module::{FuncId, Linkage, Module};

use super::lattice::{At, Body, Val, accumulate, slot_leaf};
use super::step::vconsts;
use super::{Sigs, flags};
use crate::graph::{Graph, Node, NodeId, Tabulated};
use crate::jit::JitError;
use crate::jit::fused_plan::{Contribution, FusedPlan};
use crate::jit::lattice_plan::{rest_derivatives, sum_contributions};
use crate::lattice::{ARG_Q, ARG_V, LatticePotential, SiteSum};

/// Defines the kernel in `module` where the lattice has a plan ([`FusedPlan::new`]); `None`
/// where it has none (its caller steps the orbit and vectors the one-orbit way: the same bits).
pub(crate) fn define(
    module: &mut JITModule,
    ctx: &mut Context,
    fctx: &mut FunctionBuilderContext,
    graph: &Graph,
    lattice: &LatticePotential,
    tables: &[Arc<dyn Tabulated>],
    arrays: &[(String, Arc<[f64]>)],
) -> Result<Option<FuncId>, JitError> {
    let Some(plan) = FusedPlan::new(lattice) else {
        return Ok(None);
    };
    let ptr = module.target_config().pointer_type();
    let mut sig = module.make_signature();
    for _ in 0..9 {
        sig.params.push(AbiParam::new(ptr));
    }
    let codegen = |e: cranelift_module::ModuleError| JitError::Codegen {
        function: 2,
        variant: "fused",
        message: format!("{e:?}"),
    };
    let id = module
        .declare_function("lattice_fused", Linkage::Local, &sig)
        .map_err(codegen)?;
    module.clear_context(ctx);
    ctx.func.signature = sig;
    ctx.func.name = UserFuncName::user(0, id.as_u32());
    let kernel = Kernel {
        graph,
        lattice,
        plan: &plan,
        tables,
        arrays,
        contributions: [false, true].map(|tangent| {
            let sums = sum_contributions(graph, lattice, tangent);
            sums.into_iter().map(|(c, _)| c).collect()
        }),
    };
    kernel.build(ctx, fctx, module);
    module.define_function(id, ctx).map_err(codegen)?;
    Ok(Some(id))
}

struct Kernel<'a> {
    graph: &'a Graph,
    lattice: &'a LatticePotential,
    plan: &'a FusedPlan,
    tables: &'a [Arc<dyn Tabulated>],
    arrays: &'a [(String, Arc<[f64]>)],
    /// Per sum, what each slot adds to its site (`factor`, node): the gradient's `[0]`, the
    /// Hessian-vector product's `[1]`.
    contributions: [Vec<Vec<(f64, NodeId)>>; 2],
}

/// The state a stage's kick reads and writes: the orbit's positions `q`, and the state kicked
/// (the orbit, or a vector whose `dq` the Hessian-vector product reads); addresses.
#[derive(Clone, Copy)]
struct Kicked {
    q: Value,
    state: Value,
    tangent: bool,
}

/// `for (i = start; i + step <= limit; i += step) body(i)`; the `i` it stops at.
fn for_loop(
    b: &mut FunctionBuilder,
    start: Value,
    limit: Value,
    step: i64,
    body: &mut dyn FnMut(&mut FunctionBuilder, Value),
) -> Value {
    let head = b.create_block();
    let inside = b.create_block();
    let exit = b.create_block();
    let i = b.append_block_param(head, I64);
    let stopped = b.append_block_param(exit, I64);
    b.ins().jump(head, &[BlockArg::Value(start)]);
    b.switch_to_block(head);
    let next = b.ins().iadd_imm_s(i, step);
    let more = b.ins().icmp(IntCC::UnsignedLessThanOrEqual, next, limit);
    b.ins().brif(more, inside, &[], exit, &[BlockArg::Value(i)]);
    b.switch_to_block(inside);
    body(b, i);
    b.ins().jump(head, &[BlockArg::Value(next)]);
    b.switch_to_block(exit);
    stopped
}

/// The address of entry `j` (an SSA index) of the `f64` array at `base`.
fn entry(b: &mut FunctionBuilder, base: Value, j: Value) -> Value {
    let off = b.ins().ishl_imm_u(j, 3);
    b.ins().iadd(base, off)
}

impl Kernel<'_> {
    fn n(&self) -> i64 {
        self.lattice.n as i64
    }

    fn build(&self, ctx: &mut Context, fctx: &mut FunctionBuilderContext, module: &JITModule) {
        let n = self.n();
        let mut b = FunctionBuilder::new(&mut ctx.func, fctx);
        let start = b.create_block();
        b.append_block_params_for_function_params(start);
        b.switch_to_block(start);
        let params = b.block_params(start).to_vec();
        let [x, v, k, n_steps, drift, kick, n_kicks, w] = params[..8] else {
            unreachable!("nine parameters declared")
        };
        let sigs = Sigs::new(&mut b, module);
        let consts = vconsts(&mut b);
        let body = Body {
            graph: self.graph,
            sigs: &sigs,
            tables: self.tables,
            units: 1,
            k: Some(&consts),
        };
        let zero = b.ins().iconst(I64, 0);
        // Vector `m` (an SSA index): `2N` values each.
        let vector_at = |b: &mut FunctionBuilder, m: Value| {
            let off = b.ins().imul_imm_s(m, 16 * n);
            b.ins().iadd(v, off)
        };
        let drift_all = |b: &mut FunctionBuilder, i: Value| {
            let c = entry(b, drift, i);
            let ch = b.ins().load(F64, flags(), c, 0);
            self.drift(b, x, ch, w);
            for_loop(b, zero, k, 1, &mut |b, m| {
                let vm = vector_at(b, m);
                self.drift(b, vm, ch, w);
            });
        };
        for_loop(&mut b, zero, n_steps, 1, &mut |b, _| {
            for_loop(b, zero, n_kicks, 1, &mut |b, i| {
                drift_all(b, i);
                let c = entry(b, kick, i);
                let dh = b.ins().load(F64, flags(), c, 0);
                let orbit = Kicked {
                    q: x,
                    state: x,
                    tangent: false,
                };
                self.kick(b, &body, orbit, dh);
                for_loop(b, zero, k, 1, &mut |b, m| {
                    let vector = Kicked {
                        q: x,
                        state: vector_at(b, m),
                        tangent: true,
                    };
                    self.kick(b, &body, vector, dh);
                });
            });
            drift_all(b, n_kicks);
        });
        b.ins().return_(&[]);
        b.seal_all_blocks();
        b.finalize(module.target_config());
    }

    /// `q += c p` over the `N` sites of the state at `s` (`c = ch w_j`, or `ch` where `w` is
    /// null): vectors of two sites, then the last one.
    fn drift(&self, b: &mut FunctionBuilder, s: Value, ch: Value, w: Value) {
        let n = self.n();
        let masses = b.create_block();
        let unit = b.create_block();
        let done = b.create_block();
        let p = b.ins().iadd_imm_s(s, 8 * n);
        let zero = b.ins().iconst(I64, 0);
        let limit = b.ins().iconst(I64, n);
        let null = b.ins().icmp_imm_u(IntCC::Equal, w, 0);
        b.ins().brif(null, unit, &[], masses, &[]);
        for (block, with_masses) in [(unit, false), (masses, true)] {
            b.switch_to_block(block);
            let chv = b.ins().splat(F64X2, ch);
            let site = |b: &mut FunctionBuilder, j: Value, ty| {
                let (qa, pa) = (entry(b, s, j), entry(b, p, j));
                let q = b.ins().load(ty, flags(), qa, 0);
                let pj = b.ins().load(ty, flags(), pa, 0);
                let c = if with_masses {
                    let wa = entry(b, w, j);
                    let wj = b.ins().load(ty, flags(), wa, 0);
                    b.ins().fmul(if ty == F64X2 { chv } else { ch }, wj)
                } else if ty == F64X2 {
                    chv
                } else {
                    ch
                };
                let cp = b.ins().fmul(c, pj);
                let q = b.ins().fadd(q, cp);
                b.ins().store(flags(), q, qa, 0);
            };
            let rest = for_loop(b, zero, limit, 2, &mut |b, j| site(b, j, F64X2));
            for_loop(b, rest, limit, 1, &mut |b, j| site(b, j, F64));
            b.ins().jump(done, &[]);
        }
        b.switch_to_block(done);
    }

    /// One stage's kick of `kicked`: its regular sites, then its end sites.
    fn kick(&self, b: &mut FunctionBuilder, body: &Body, kicked: Kicked, dh: Value) {
        match &self.plan.square {
            None => {
                let (ja, jb) = self.plan.regular;
                let start = b.ins().iconst(I64, ja as i64);
                let limit = b.ins().iconst(I64, jb as i64 + 1);
                self.regular(b, body, kicked, dh, start, limit);
            }
            Some(blocks) => {
                for rect in blocks {
                    let (side, (ra, rb), (ca, cb)) = (rect.side as i64, rect.rows, rect.columns);
                    let first = b.ins().iconst(I64, ra as i64);
                    let last = b.ins().iconst(I64, rb as i64 + 1);
                    for_loop(b, first, last, 1, &mut |b, r| {
                        let row = b.ins().imul_imm_s(r, side);
                        let start = b.ins().iadd_imm_s(row, ca as i64);
                        let limit = b.ins().iadd_imm_s(row, cb as i64 + 1);
                        self.regular(b, body, kicked, dh, start, limit);
                    });
                }
            }
        }
        self.ends(b, body, kicked, dh);
    }

    /// The regular sites `start..limit` (SSA indices): vectors of two, then the last one.
    fn regular(
        &self,
        b: &mut FunctionBuilder,
        body: &Body,
        kicked: Kicked,
        dh: Value,
        start: Value,
        limit: Value,
    ) {
        let p = b.ins().iadd_imm_s(kicked.state, 8 * self.n());
        let dhv = b.ins().splat(F64X2, dh);
        let site = |b: &mut FunctionBuilder, j: Value, vector: bool| {
            let g = self.site(b, body, kicked, j, vector);
            let pa = entry(b, p, j);
            let ty = if vector { F64X2 } else { F64 };
            let pj = b.ins().load(ty, flags(), pa, 0);
            let dg = b.ins().fmul(if vector { dhv } else { dh }, g);
            let pj = b.ins().fsub(pj, dg);
            b.ins().store(flags(), pj, pa, 0);
        };
        let rest = for_loop(b, start, limit, 2, &mut |b, j| site(b, j, true));
        for_loop(b, rest, limit, 1, &mut |b, j| site(b, j, false));
    }

    /// The force (or Hessian-vector product) at the regular site `j` (two sites from `j` where
    /// `vector`): each term that reads it, in the plan's order, added to `-0`.
    fn site(
        &self,
        b: &mut FunctionBuilder,
        body: &Body,
        kicked: Kicked,
        j: Value,
        vector: bool,
    ) -> Value {
        let contributions = &self.contributions[usize::from(kicked.tangent)];
        let mut acc = b.ins().f64const(-0.0);
        if vector {
            acc = b.ins().splat(F64X2, acc);
        }
        for &(s, slot) in &self.plan.pattern {
            let sum = &self.lattice.sums[s];
            let (factor, root) = contributions[s][slot];
            // The term that reads site `j` through this slot: `i = j + 1 - shift`.
            let i = b.ins().iadd_imm_s(j, 1 - sum.variables[slot]);
            let off = b.ins().ishl_imm_u(i, 3);
            let at = At::Loop { off };
            let vals = body.emit(b, &[root], &mut |b, _, node| {
                self.leaf(b, node, sum, at, kicked, vector)
            });
            let x = match vals[root as usize].expect("emitted") {
                Val::One(x) if vector => b.ins().splat(F64X2, x),
                Val::One(x) => x,
                Val::Lanes([x, _]) => x,
            };
            acc = accumulate(b, factor, acc, x, vector);
        }
        acc
    }

    /// A leaf of a term of `sum` at `at` ([`slot_leaf`]): the loop's vectors of two terms
    /// where `vector`, else one term.
    fn leaf(
        &self,
        b: &mut FunctionBuilder,
        node: &Node,
        sum: &SiteSum,
        at: At,
        kicked: Kicked,
        vector: bool,
    ) -> Val {
        let ty = if vector { F64X2 } else { F64 };
        let states = (kicked.q, Some(kicked.state));
        let x = slot_leaf(b, node, sum, at, states, self.arrays, ty);
        if vector && !matches!(node, Node::Const(_)) {
            Val::Lanes([x, x])
        } else {
            Val::One(x)
        }
    }

    /// The sites outside the regular ones, one by one, each with its own list (the expression
    /// around the sums first, computed once for them all).
    fn ends(&self, b: &mut FunctionBuilder, body: &Body, kicked: Kicked, dh: Value) {
        let lattice = self.lattice;
        let contributions = &self.contributions[usize::from(kicked.tangent)];
        let (q, dq) = (kicked.q, kicked.state);
        let p = b.ins().iadd_imm_s(kicked.state, 8 * self.n());
        let rest = rest_derivatives(lattice, kicked.tangent);
        let mut rest_of = vec![None; lattice.n];
        if !rest.is_empty() {
            let roots: Vec<NodeId> = rest.iter().map(|&(_, id)| id).collect();
            let vals = body.emit(b, &roots, &mut |b, _, node| match *node {
                Node::Const(c) => Val::One(b.ins().f64const(c)),
                Node::Input { arg: ARG_Q, index } => {
                    Val::One(b.ins().load(F64, flags(), q, 8 * index as i32))
                }
                Node::Input { arg: ARG_V, index } => {
                    Val::One(b.ins().load(F64, flags(), dq, 8 * index as i32))
                }
                _ => unreachable!("the rest reads q and v: {node:?}"),
            });
            for &(j, id) in rest {
                rest_of[j as usize] = vals[id as usize];
            }
        }
        let scalar = |v: Val| match v {
            Val::One(x) => x,
            Val::Lanes(_) => unreachable!("the end sites are scalar code"),
        };
        for (j, list) in &self.plan.ends {
            let mut acc = b.ins().f64const(-0.0);
            if let Some(r) = rest_of[*j] {
                acc = accumulate(b, 1.0, acc, scalar(r), false);
            }
            for &Contribution { sum, term, slot } in list {
                let (factor, root) = contributions[sum][slot];
                let s = &lattice.sums[sum];
                let vals = body.emit(b, &[root], &mut |b, _, node| {
                    self.leaf(b, node, s, At::Term(term), kicked, false)
                });
                let x = scalar(vals[root as usize].expect("emitted"));
                acc = accumulate(b, factor, acc, x, false);
            }
            let off = 8 * *j as i32;
            let pj = b.ins().load(F64, flags(), p, off);
            let dg = b.ins().fmul(dh, acc);
            let pj = b.ins().fsub(pj, dg);
            b.ins().store(flags(), pj, p, off);
        }
    }
}
