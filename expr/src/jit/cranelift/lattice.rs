//! Native code for a potential made of lattice sums ([`crate::lattice`]): each sum a loop over
//! its term, whatever `N` is, performing the operations of
//! [`crate::lattice::LatticeEvaluator`] in its order, so the results are its bits.
//!
//! One loop per sum: the terms reading a site beyond an end (at most
//! [`crate::lattice::MAX_BOUNDARY_TERMS`], usually one per end) are written out with their
//! sites resolved (a wall is the constant 0, a periodic site its wrapped index), the others run
//! as a loop whose slots load `q[i + k]` at a fixed offset from the loop's row. The gradient and
//! the Hessian-vector product add each term's derivatives to the output as they come (load,
//! add, store), after the output has been set to `-0` and the expression around the sums has
//! added its own.
//!
//! [`Body`] emits a term for the scalar functions here and for the step kernels' blocks of lanes
//! alike: a node whose operands are all shared by the lanes (a scalar) is scalar code, any other
//! one `F64X2` code per unit, with scalar operands broadcast.

use std::sync::{Arc, Mutex};
use std::time::Instant;

use cranelift_codegen::Context;
use cranelift_codegen::ir::condcodes::IntCC;
use cranelift_codegen::ir::types::{F64, F64X2, I64};
use cranelift_codegen::ir::{AbiParam, BlockArg, InstBuilder, Type, UserFuncName, Value};
use cranelift_frontend::{FunctionBuilder, FunctionBuilderContext};
use cranelift_module::{Linkage, Module};

use super::{
    AllocationWork, Compiled, FnInfo, LanesFnPtr, ScalarFnPtr, Sigs, VConsts, emit_scalar,
    emit_vector, flags, new_module, regalloc_for,
};
use crate::graph::{Graph, Node, NodeId, Tabulated};
use crate::jit::lattice_plan::{
    ForcePart, OutputPlan, SumContributions, arrays_of, check_size, rest_derivatives, shift_range,
    sum_contributions,
};
use crate::jit::{JitError, Layout, Options, Regalloc, is_leaf, schedule};
use crate::lattice::{
    ARG_Q, ARG_SITE, ARG_SITE_DIRECTION, ARG_SITE_PARAM, ARG_SUM, ARG_V, LatticePotential, SiteSum,
};

/// A value of generated code: one scalar shared by every lane, or one `F64X2` per unit.
#[derive(Debug, Clone, Copy)]
pub(crate) enum Val {
    One(Value),
    Lanes([Value; 2]),
}

/// Emits graph nodes as scalar or lane code (see the module documentation).
pub(crate) struct Body<'a> {
    pub graph: &'a Graph,
    pub sigs: &'a Sigs,
    pub tables: &'a [Arc<dyn Tabulated>],
    /// `F64X2` values per lane value (1 or 2); 0 in scalar functions.
    pub units: usize,
    pub k: Option<&'a VConsts>,
}

impl Body<'_> {
    /// Emits what `roots` need, operands first; `leaf` gives each constant and input (once).
    /// Returns the values by node id.
    pub fn emit(
        &self,
        b: &mut FunctionBuilder,
        roots: &[NodeId],
        leaf: &mut dyn FnMut(&mut FunctionBuilder, NodeId, &Node) -> Val,
    ) -> Vec<Option<Val>> {
        let graph = self.graph;
        let mut vals: Vec<Option<Val>> = vec![None; graph.len()];
        let mut splats: Vec<Option<Value>> = vec![None; graph.len()];
        let order = schedule(graph, roots, |_| true);
        for id in order {
            let node = graph.node(id);
            if is_leaf(node) {
                vals[id as usize] = Some(leaf(b, id, node));
                continue;
            }
            let scalar = node
                .operands()
                .all(|o| matches!(vals[o as usize], Some(Val::One(_))));
            let val = if scalar {
                let mut get = |_: &mut FunctionBuilder, o: NodeId| match vals[o as usize] {
                    Some(Val::One(v)) => v,
                    _ => unreachable!("scalar operands"),
                };
                Val::One(emit_scalar(b, self.sigs, self.tables, node, &mut get))
            } else {
                for o in node.operands() {
                    if let Some(Val::One(v)) = vals[o as usize]
                        && splats[o as usize].is_none()
                    {
                        splats[o as usize] = Some(b.ins().splat(F64X2, v));
                    }
                }
                let k = self.k.expect("lane code has its vector constants");
                let mut out = [None; 2];
                for (unit, slot) in out.iter_mut().enumerate().take(self.units.max(1)) {
                    let mut get = |_: &mut FunctionBuilder, o: NodeId| match vals[o as usize] {
                        Some(Val::Lanes(v)) => v[unit],
                        Some(Val::One(_)) => splats[o as usize].expect("broadcast above"),
                        None => unreachable!("operands come first"),
                    };
                    *slot = Some(emit_vector(b, self.sigs, self.tables, k, node, &mut get));
                }
                let v0 = out[0].expect("at least one unit");
                Val::Lanes([v0, out[1].unwrap_or(v0)])
            };
            vals[id as usize] = Some(val);
        }
        vals
    }
}

/// `acc + d`, `acc - d` or `acc + c * d` ([`crate::lattice::accumulate`]), on scalars or
/// `F64X2` values.
pub(crate) fn accumulate(
    b: &mut FunctionBuilder,
    c: f64,
    acc: Value,
    d: Value,
    vector: bool,
) -> Value {
    if c == 1.0 {
        b.ins().fadd(acc, d)
    } else if c == -1.0 {
        b.ins().fsub(acc, d)
    } else {
        let mut k = b.ins().f64const(c);
        if vector {
            k = b.ins().splat(F64X2, k);
        }
        let cd = b.ins().fmul(k, d);
        b.ins().fadd(acc, cd)
    }
}

/// The scalar functions of a lattice potential, in [`crate::jit::Compiled`]'s order.
pub const LATTICE_POTENTIAL: usize = 0;
pub const LATTICE_GRADIENT: usize = 1;
pub const LATTICE_HESSIAN_VECTOR: usize = 2;

/// Which derivative a function computes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum What {
    Potential,
    Gradient,
    HessianVector,
}

/// Compiles the potential (one output, argument `q`), its gradient (`N` outputs) and its
/// Hessian-vector product (`N` outputs, arguments `q` and `v`; `-0` everywhere without second
/// derivatives) as scalar functions with loops; lane functions are not compiled
/// ([`Compiled::call_lanes`] panics).
pub fn compile_lattice(
    graph: &Graph,
    lattice: &LatticePotential,
    options: &Options,
) -> Result<Compiled, JitError> {
    let start = Instant::now();
    check_size(lattice)?;
    let (regalloc, allocation) = lattice_regalloc(options, graph, lattice, true);
    let (mut module, isa) = new_module(options.opt_level, regalloc)?;
    let tables: Box<[Arc<dyn Tabulated>]> = graph.tables().to_vec().into_boxed_slice();
    let arrays = arrays_of(lattice);
    let mut ctx = Context::new();
    let mut fctx = FunctionBuilderContext::new();
    let ptr = module.target_config().pointer_type();
    let mut sig = module.make_signature();
    sig.params.push(AbiParam::new(ptr));
    sig.params.push(AbiParam::new(ptr));
    let n = lattice.n;
    let mut ids = Vec::new();
    for (f, what) in [What::Potential, What::Gradient, What::HessianVector]
        .into_iter()
        .enumerate()
    {
        let codegen = |e: cranelift_module::ModuleError| JitError::Codegen {
            function: f,
            variant: "scalar",
            message: format!("{e:?}"),
        };
        let id = module
            .declare_function(&format!("lattice{f}"), Linkage::Local, &sig)
            .map_err(codegen)?;
        module.clear_context(&mut ctx);
        ctx.func.signature = sig.clone();
        ctx.func.name = UserFuncName::user(0, id.as_u32());
        build(
            &mut ctx, &mut fctx, &module, graph, lattice, &tables, &arrays, what,
        );
        module.define_function(id, &mut ctx).map_err(codegen)?;
        ids.push((id, what));
    }
    module
        .finalize_definitions()
        .map_err(|e| JitError::Link(format!("{e:?}")))?;
    let fns = ids
        .into_iter()
        .map(|(id, what)| {
            let code = module.get_finalized_function(id);
            // SAFETY: defined above with exactly this signature (two pointer-sized integer
            // parameters, no results, the host's C calling convention).
            let scalar = unsafe { std::mem::transmute::<*const u8, ScalarFnPtr>(code) };
            let (layouts, arg_len, n_out) = match what {
                What::Potential => (vec![Layout::Scalar], vec![n], 1),
                What::Gradient => (vec![Layout::Scalar], vec![n], n),
                What::HessianVector => (vec![Layout::Scalar; 2], vec![n, n], n),
            };
            FnInfo {
                layouts,
                arg_len,
                n_out,
                scalar,
                lanes: None::<LanesFnPtr>,
            }
        })
        .collect();
    Ok(Compiled {
        modules: Mutex::new(vec![module]),
        fns,
        _tables: tables,
        _arrays: arrays.into_iter().map(|(_, a)| a).collect(),
        compile_time: start.elapsed(),
        isa,
        allocation,
    })
}

/// The register allocator of a lattice potential's functions (one module): the single-pass
/// one if any group of nodes emitted together (the potential with `potential`, the rest's
/// derivatives, each term's) keeps its values live longer than [`crate::jit::MAX_MEAN_LIVE`]
/// operations on average, as [`regalloc_for`] decides for the unrolled functions; else
/// `options.regalloc`. A term is emitted once per loop, so its live span is that of one
/// term, whatever `N`. Also what the allocators were given (each group counted once).
pub(crate) fn lattice_regalloc(
    options: &Options,
    graph: &Graph,
    lattice: &LatticePotential,
    potential: bool,
) -> (Regalloc, AllocationWork) {
    let mut groups: Vec<Vec<NodeId>> = Vec::new();
    if potential {
        groups.push(vec![lattice.root]);
        groups.extend(lattice.sums.iter().map(|s| vec![s.term]));
    }
    groups.push(lattice.rest_gradient.iter().map(|&(_, id)| id).collect());
    if let Some(rest) = &lattice.rest_hessian_vector {
        groups.push(rest.iter().map(|&(_, id)| id).collect());
    }
    for d in &lattice.derivatives {
        groups.push(d.gradient.clone());
        groups.extend(d.hessian_vector.clone());
    }
    let mut regalloc = options.regalloc;
    let mut spans = Vec::with_capacity(groups.len());
    let mut allocation = AllocationWork::default();
    for roots in groups.iter().filter(|r| !r.is_empty()) {
        let order: Vec<NodeId> = schedule(graph, roots, |_| true)
            .into_iter()
            .filter(|&id| !is_leaf(graph.node(id)))
            .collect();
        let (chosen, span) = regalloc_for(options, graph, &order);
        if chosen == Regalloc::SinglePass {
            regalloc = Regalloc::SinglePass;
        }
        allocation.operations += order.len() as u64;
        spans.push(span);
    }
    if regalloc == Regalloc::Backtracking {
        allocation.backtracking_live_span = spans.iter().sum();
    }
    (regalloc, allocation)
}

/// The address of the array parameter `name`'s values.
fn array_address(arrays: &[(String, Arc<[f64]>)], name: &str) -> i64 {
    let (_, a) = arrays
        .iter()
        .find(|(n, _)| n == name)
        .expect("every array a sum reads");
    a.as_ptr() as i64
}

/// Where one term's slots are: in a boundary term, sites known at compile time; in the loop,
/// `i * 8` added to each array's base.
#[derive(Clone, Copy)]
pub(crate) enum At {
    Term(i64),
    Loop { off: Value },
}

#[allow(clippy::too_many_arguments)]
fn build(
    ctx: &mut Context,
    fctx: &mut FunctionBuilderContext,
    module: &cranelift_jit::JITModule,
    graph: &Graph,
    lattice: &LatticePotential,
    tables: &[Arc<dyn Tabulated>],
    arrays: &[(String, Arc<[f64]>)],
    what: What,
) {
    let mut b = FunctionBuilder::new(&mut ctx.func, fctx);
    let entry = b.create_block();
    b.append_block_params_for_function_params(entry);
    b.switch_to_block(entry);
    let (args, out) = (b.block_params(entry)[0], b.block_params(entry)[1]);
    let sigs = Sigs::new(&mut b, module);
    let q = b.ins().load(I64, flags(), args, 0);
    let v = (what == What::HessianVector).then(|| b.ins().load(I64, flags(), args, 8));
    let body = Body {
        graph,
        sigs: &sigs,
        tables,
        units: 0,
        k: None,
    };
    let layout = (what != What::Potential)
        .then(|| OutputPlan::new(graph, lattice, what == What::HessianVector, false));
    // Per sum, what its derivatives add per slot (none for the potential) and the roots to emit.
    let sums: Vec<SumContributions> = match what {
        What::Potential => (lattice.sums.iter())
            .map(|sum| (Vec::new(), vec![sum.term]))
            .collect(),
        _ => sum_contributions(graph, lattice, what == What::HessianVector),
    };
    let parts = match &layout {
        Some(layout) => {
            // out = -0 (`-0 + x` is `x`: the first contribution is taken as it is), where a
            // site is read before a loop writes it first.
            for &(a, z) in &layout.init {
                fill(&mut b, out, a, z, -0.0);
            }
            layout.parts.clone()
        }
        None => (lattice.sums.iter().enumerate())
            .flat_map(|(s, sum)| ForcePart::of_sum(sum, s))
            .collect(),
    };
    // The potential's value of each sum so far.
    let zero = b.ins().f64const(-0.0);
    let mut acc: Vec<Option<Value>> =
        vec![(what == What::Potential).then_some(zero); lattice.sums.len()];
    for part in parts {
        let s = match part {
            ForcePart::Rest => {
                let rest = rest_derivatives(lattice, what == What::HessianVector);
                let roots: Vec<NodeId> = rest.iter().map(|&(_, id)| id).collect();
                let mut leaf = |b: &mut FunctionBuilder, _: NodeId, node: &Node| {
                    Val::One(global_leaf(b, node, q, v, &[]))
                };
                let vals = body.emit(&mut b, &roots, &mut leaf);
                for &(j, id) in rest {
                    let Some(Val::One(x)) = vals[id as usize] else {
                        unreachable!("scalar code")
                    };
                    let off = (j as usize * 8) as i32;
                    let acc = b.ins().load(F64, flags(), out, off);
                    let acc = b.ins().fadd(acc, x);
                    b.ins().store(flags(), acc, out, off);
                }
                continue;
            }
            ForcePart::Term { sum, .. } | ForcePart::Loop { sum, .. } => sum,
        };
        let (sum, (contributions, roots)) = (&lattice.sums[s], &sums[s]);
        let term = |b: &mut FunctionBuilder, at: At, acc: Option<Value>| -> Option<Value> {
            let mut leaf = |b: &mut FunctionBuilder, _: NodeId, node: &Node| {
                Val::One(slot_leaf(b, node, sum, at, (q, v), arrays, F64))
            };
            let vals = body.emit(b, roots, &mut leaf);
            let value = |id: NodeId| match vals[id as usize] {
                Some(Val::One(x)) => x,
                _ => unreachable!("scalar code"),
            };
            if what == What::Potential {
                let t = value(sum.term);
                return acc.map(|acc| b.ins().fadd(acc, t));
            }
            for (&shift, &(factor, r)) in sum.variables.iter().zip(contributions) {
                let off = match at {
                    At::Term(i) => sum.site(i, shift).map(|j| (out, (j * 8) as i32)),
                    At::Loop { off } => Some((b.ins().iadd(out, off), ((shift - 1) * 8) as i32)),
                };
                if let Some((base, off)) = off {
                    let x = value(r);
                    let acc = b.ins().load(F64, flags(), base, off);
                    let acc = accumulate(b, factor, acc, x, false);
                    b.ins().store(flags(), acc, base, off);
                }
            }
            None
        };
        acc[s] = match part {
            ForcePart::Term { i, .. } => term(&mut b, At::Term(i), acc[s]),
            ForcePart::Loop { from, to, .. } => match layout.as_ref().and_then(|l| l.window[s]) {
                Some(w) => {
                    let window = Window {
                        body: &body,
                        sum,
                        contributions,
                        roots,
                        q,
                        v,
                        out,
                        arrays,
                    };
                    window.build(&mut b, (from, to), w.fresh);
                    acc[s]
                }
                None => site_loop(&mut b, from, to, acc[s], &mut |b, i, acc| {
                    let off = b.ins().ishl_imm_u(i, 3);
                    term(b, At::Loop { off }, acc)
                }),
            },
            ForcePart::Rest => unreachable!(),
        };
    }
    if what == What::Potential {
        let mut leaf = |b: &mut FunctionBuilder, _: NodeId, node: &Node| {
            Val::One(global_leaf(b, node, q, v, &acc))
        };
        let vals = body.emit(&mut b, &[lattice.root], &mut leaf);
        let Some(Val::One(x)) = vals[lattice.root as usize] else {
            unreachable!("scalar code")
        };
        b.ins().store(flags(), x, out, 0);
    }
    b.ins().return_(&[]);
    b.seal_all_blocks();
    b.finalize(module.target_config());
}

/// A constant, or an entry of `q`, `v` or the sums' values.
fn global_leaf(
    b: &mut FunctionBuilder,
    node: &Node,
    q: Value,
    v: Option<Value>,
    sums: &[Option<Value>],
) -> Value {
    match *node {
        Node::Const(c) => b.ins().f64const(c),
        Node::Input { arg: ARG_Q, index } => b.ins().load(F64, flags(), q, (index * 8) as i32),
        Node::Input { arg: ARG_V, index } => {
            let v = v.expect("the direction of a Hessian-vector product");
            b.ins().load(F64, flags(), v, (index * 8) as i32)
        }
        Node::Input {
            arg: ARG_SUM,
            index,
        } => sums[index as usize].expect("sums come first"),
        _ => unreachable!("a leaf of the expression around the sums: {node:?}"),
    }
}

/// A leaf of a term: a constant, a slot at a site (a wall is 0), an array parameter; a slot or
/// a parameter in the loop is loaded as `ty` (`F64`, or `F64X2` for two consecutive terms).
pub(crate) fn slot_leaf(
    b: &mut FunctionBuilder,
    node: &Node,
    sum: &SiteSum,
    at: At,
    (q, v): (Value, Option<Value>),
    arrays: &[(String, Arc<[f64]>)],
    ty: Type,
) -> Value {
    let (base, shift) = match *node {
        Node::Const(c) => return b.ins().f64const(c),
        Node::Input {
            arg: ARG_SITE,
            index,
        } => (q, sum.variables[index as usize]),
        Node::Input {
            arg: ARG_SITE_DIRECTION,
            index,
        } => (
            v.expect("the direction of a Hessian-vector product"),
            sum.variables[index as usize],
        ),
        Node::Input {
            arg: ARG_SITE_PARAM,
            index,
        } => {
            let p = &sum.params[index as usize];
            match at {
                // A known value: the constant itself.
                At::Term(i) => {
                    let j = sum.site(i, p.shift).expect("parameters inside the lattice");
                    return b.ins().f64const(p.values[j]);
                }
                At::Loop { .. } => {
                    let base = b.ins().iconst(I64, array_address(arrays, &p.name));
                    (base, p.shift)
                }
            }
        }
        _ => unreachable!("a leaf of a term: {node:?}"),
    };
    match at {
        At::Term(i) => match sum.site(i, shift) {
            Some(j) => b.ins().load(F64, flags(), base, (j * 8) as i32),
            None => b.ins().f64const(0.0),
        },
        At::Loop { off } => {
            let row = b.ins().iadd(base, off);
            b.ins().load(ty, flags(), row, ((shift - 1) * 8) as i32)
        }
    }
}

/// The interior loop of a sum's gradient or Hessian-vector product with the sums of the sites
/// its terms reach carried from term to term in registers: in term `i`, the sites `i + kmin ..
/// i + kmax` hold what the terms before `i` added (and, for a site a term reached first before
/// the loop, what the output held then); site `i + kmin` is complete after term `i` and stored.
/// The same additions in the same order as adding to the output in memory. The slot values
/// of a site read by the previous term are carried too (`q[i + k + 1]` of term `i` is
/// `q[i + k]` of term `i + 1`).
struct Window<'a> {
    body: &'a Body<'a>,
    sum: &'a SiteSum,
    contributions: &'a [(f64, NodeId)],
    roots: &'a [NodeId],
    q: Value,
    v: Option<Value>,
    out: Value,
    arrays: &'a [(String, Arc<[f64]>)],
}

/// What a [`Window`] loop carries from term to term: the sums of the sites `i + kmin ..
/// i + kmax - 1`, and the values of the carried slots (per argument array: `q`, then `v`).
#[derive(Clone)]
struct WindowState {
    accs: Vec<Value>,
    carried: Vec<Vec<Value>>,
}

impl WindowState {
    fn args(&self) -> Vec<BlockArg> {
        self.accs
            .iter()
            .chain(self.carried.iter().flatten())
            .map(|&x| BlockArg::Value(x))
            .collect()
    }

    /// The same shape as block parameters of `block`.
    fn params(&self, b: &mut FunctionBuilder, block: cranelift_codegen::ir::Block) -> Self {
        let accs = self
            .accs
            .iter()
            .map(|_| b.append_block_param(block, F64))
            .collect();
        let carried = self
            .carried
            .iter()
            .map(|c| c.iter().map(|_| b.append_block_param(block, F64)).collect())
            .collect();
        WindowState { accs, carried }
    }
}

impl Window<'_> {
    /// The arrays whose slots are carried: `q`, and `v` in a Hessian-vector product.
    fn arrays(&self) -> Vec<Value> {
        std::iter::once(self.q).chain(self.v).collect()
    }

    /// Slot `s` is carried from slot `carry[s].1` of the previous term (`(s, source)` pairs).
    fn carry(&self) -> Vec<(usize, usize)> {
        let shifts = &self.sum.variables;
        shifts
            .iter()
            .enumerate()
            .filter_map(|(s, &k)| shifts.iter().position(|&k2| k2 == k + 1).map(|s2| (s, s2)))
            .collect()
    }

    /// The loop over the terms `from..=to`, two terms per iteration (and the last one of an
    /// odd count after it); `fresh`: no part wrote the sites `i + kmax` before (their first
    /// contribution is then taken as it is).
    fn build(&self, b: &mut FunctionBuilder, (from, to): (i64, i64), fresh: bool) {
        let shifts = &self.sum.variables;
        let (kmin, kmax) = shift_range(shifts);
        let carry = self.carry();
        // Entry: the window's sites as the output holds them, the carried slots' values.
        let accs = (0..kmax - kmin)
            .map(|t| {
                let off = ((from + kmin + t - 1) * 8) as i32;
                b.ins().load(F64, flags(), self.out, off)
            })
            .collect();
        let carried = self
            .arrays()
            .iter()
            .map(|&base| {
                carry
                    .iter()
                    .map(|&(s, _)| {
                        let off = ((from + shifts[s] - 1) * 8) as i32;
                        b.ins().load(F64, flags(), base, off)
                    })
                    .collect()
            })
            .collect();
        let mut state = WindowState { accs, carried };
        let count = to - from + 1;
        let pairs = count / 2;
        if pairs > 0 {
            let head = b.create_block();
            let after = b.create_block();
            let i = b.append_block_param(head, I64);
            let inside = state.params(b, head);
            let out_state = state.params(b, after);
            let mut args = vec![BlockArg::Value(b.ins().iconst(I64, from))];
            args.extend(state.args());
            b.ins().jump(head, &args);
            b.switch_to_block(head);
            let st = self.step(b, i, inside, fresh);
            let i1 = b.ins().iadd_imm_s(i, 1);
            let st = self.step(b, i1, st, fresh);
            let i2 = b.ins().iadd_imm_s(i, 2);
            let more = b
                .ins()
                .icmp_imm_s(IntCC::SignedLessThan, i2, from + 2 * pairs);
            let mut loop_args = vec![BlockArg::Value(i2)];
            loop_args.extend(st.args());
            b.ins().brif(more, head, &loop_args, after, &st.args());
            b.switch_to_block(after);
            state = out_state;
        }
        if count % 2 == 1 {
            let i = b.ins().iconst(I64, to);
            state = self.step(b, i, state, fresh);
        }
        // The window's sites after the last term.
        for (t, &x) in state.accs.iter().enumerate() {
            let off = ((to + 1 + kmin + t as i64 - 1) * 8) as i32;
            b.ins().store(flags(), x, self.out, off);
        }
    }

    /// Term `i`: its contributions added to the window, site `i + kmin` stored.
    fn step(
        &self,
        b: &mut FunctionBuilder,
        i: Value,
        state: WindowState,
        fresh: bool,
    ) -> WindowState {
        let sum = self.sum;
        let shifts = &sum.variables;
        let (kmin, kmax) = shift_range(shifts);
        let carry = self.carry();
        let i8 = b.ins().ishl_imm_u(i, 3);
        let rows: Vec<Value> = self.arrays().iter().map(|&a| b.ins().iadd(a, i8)).collect();
        let oi = b.ins().iadd(self.out, i8);
        // The slots' values in this term (per array).
        let mut slot_vals: Vec<Vec<Option<Value>>> = vec![vec![None; shifts.len()]; rows.len()];
        for (a, c) in state.carried.iter().enumerate() {
            for (&(s, _), &x) in carry.iter().zip(c) {
                slot_vals[a][s] = Some(x);
            }
        }
        let load_slot = |b: &mut FunctionBuilder,
                         slot_vals: &mut Vec<Vec<Option<Value>>>,
                         a: usize,
                         s: usize| {
            if let Some(x) = slot_vals[a][s] {
                return x;
            }
            let x = b
                .ins()
                .load(F64, flags(), rows[a], ((shifts[s] - 1) * 8) as i32);
            slot_vals[a][s] = Some(x);
            x
        };
        let vals = {
            let mut leaf = |b: &mut FunctionBuilder, _: NodeId, node: &Node| match *node {
                Node::Input {
                    arg: ARG_SITE,
                    index,
                } => Val::One(load_slot(b, &mut slot_vals, 0, index as usize)),
                Node::Input {
                    arg: ARG_SITE_DIRECTION,
                    index,
                } => Val::One(load_slot(b, &mut slot_vals, 1, index as usize)),
                _ => Val::One(slot_leaf(
                    b,
                    node,
                    sum,
                    At::Loop { off: i8 },
                    (self.q, self.v),
                    self.arrays,
                    F64,
                )),
            };
            self.body.emit(b, self.roots, &mut leaf)
        };
        let mut accs: Vec<Option<Value>> = state.accs.iter().map(|&a| Some(a)).collect();
        accs.push(if fresh {
            None
        } else {
            Some(b.ins().load(F64, flags(), oi, ((kmax - 1) * 8) as i32))
        });
        for (&shift, &(factor, r)) in shifts.iter().zip(self.contributions) {
            let Some(Val::One(d)) = vals[r as usize] else {
                unreachable!("scalar code")
            };
            let t = (shift - kmin) as usize;
            accs[t] = Some(match accs[t] {
                // `-0 + d` is `d`.
                None if factor == 1.0 => d,
                None => {
                    let z = b.ins().f64const(-0.0);
                    accumulate(b, factor, z, d, false)
                }
                Some(a) => accumulate(b, factor, a, d, false),
            });
        }
        let value = |b: &mut FunctionBuilder, x: Option<Value>| match x {
            Some(x) => x,
            None => b.ins().f64const(-0.0),
        };
        let done = value(b, accs[0]);
        b.ins().store(flags(), done, oi, ((kmin - 1) * 8) as i32);
        let accs = accs[1..].iter().map(|&x| value(b, x)).collect();
        let carried = (0..rows.len())
            .map(|a| {
                carry
                    .iter()
                    .map(|&(_, s2)| load_slot(b, &mut slot_vals, a, s2))
                    .collect()
            })
            .collect();
        WindowState { accs, carried }
    }
}

/// `out[a..z] = x`.
fn fill(b: &mut FunctionBuilder, out: Value, a: usize, z: usize, x: f64) {
    if z - a <= 4 {
        for j in a..z {
            let x = b.ins().f64const(x);
            b.ins().store(flags(), x, out, (j * 8) as i32);
        }
        return;
    }
    let body = b.create_block();
    let exit = b.create_block();
    let j = b.append_block_param(body, I64);
    let xv = b.append_block_param(body, F64);
    let start = b.ins().iconst(I64, a as i64);
    let x = b.ins().f64const(x);
    b.ins()
        .jump(body, &[BlockArg::Value(start), BlockArg::Value(x)]);
    b.switch_to_block(body);
    let off = b.ins().ishl_imm_u(j, 3);
    let p = b.ins().iadd(out, off);
    b.ins().store(flags(), xv, p, 0);
    let j1 = b.ins().iadd_imm_s(j, 1);
    let more = b.ins().icmp_imm_u(IntCC::UnsignedLessThan, j1, z as i64);
    b.ins().brif(
        more,
        body,
        &[BlockArg::Value(j1), BlockArg::Value(xv)],
        exit,
        &[],
    );
    b.switch_to_block(exit);
}

/// A loop's term: `(builder, i, acc) -> acc`.
pub(crate) type TermBody<'a> =
    dyn FnMut(&mut FunctionBuilder, Value, Option<Value>) -> Option<Value> + 'a;

/// `for i in from..=to`: `body(i, acc)` with the accumulator `acc` (of the potential) carried
/// from term to term; returns it after the last term.
pub(crate) fn site_loop(
    b: &mut FunctionBuilder,
    from: i64,
    to: i64,
    acc: Option<Value>,
    body: &mut TermBody,
) -> Option<Value> {
    let head = b.create_block();
    let exit = b.create_block();
    let i = b.append_block_param(head, I64);
    let acc_param = acc.map(|_| b.append_block_param(head, F64));
    let exit_acc = acc.map(|_| b.append_block_param(exit, F64));
    let start = b.ins().iconst(I64, from);
    let mut args = vec![BlockArg::Value(start)];
    args.extend(acc.map(BlockArg::Value));
    b.ins().jump(head, &args);
    b.switch_to_block(head);
    let acc = body(b, i, acc_param);
    let i1 = b.ins().iadd_imm_s(i, 1);
    let more = b.ins().icmp_imm_s(IntCC::SignedLessThanOrEqual, i1, to);
    let mut args = vec![BlockArg::Value(i1)];
    args.extend(acc.map(BlockArg::Value));
    let exit_args: Vec<BlockArg> = acc.map(BlockArg::Value).into_iter().collect();
    b.ins().brif(more, head, &args, exit, &exit_args);
    b.switch_to_block(exit);
    exit_acc
}
