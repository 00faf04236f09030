//! Native code for a [`Graph`]'s outputs, by two code generators that perform exactly the
//! IEEE operations [`Graph::apply_unary`], [`Graph::apply_binary`] and [`Graph::apply_powi`]
//! define, on the same operands in the same order, so they agree with the reference evaluator
//! bit for bit:
//! - `cranelift`: functions (a scalar and a lane function each), the splitting step kernels
//!   and the lattice sums' loops and site steps, compiled in-process at start;
//! - `c`: the same step kernels and lattice site steps as C text (`c/emit.rs`, `c/fused.rs`,
//!   `c/lattice_steps.rs`), built by the system C compiler (`c/compiler.rs`: its process group,
//!   deadline and signals), kept in an on-disk cache (`c/cache.rs`, with its ownership and
//!   digest checks) and loaded from checked bytes (`c/load.rs`).
//!
//! This file holds what both share: the function specs and their layouts, the errors, the
//! emission plan of one function (which nodes, in which order, which are uniform over lanes)
//! and the callbacks the compiled code calls for every operation that is not a single IEEE
//! instruction. `step.rs` chooses between the two step-kernel back ends.

use std::sync::Arc;

use crate::graph::{Binary, Graph, Node, NodeId, Tabulated, Unary};

pub(crate) mod c;
mod cranelift;
mod fused_plan;
mod lattice_plan;
mod step;
mod step_spec;

pub use c::lattice_steps::{
    compile_lattice_steps_c, compile_lattice_steps_c_cancellable, load_lattice_steps_c,
};
pub use c::{C_BLOCK_LANES, CCompiler};
pub(crate) use cranelift::free_modules;
pub use cranelift::lattice::{
    LATTICE_GRADIENT, LATTICE_HESSIAN_VECTOR, LATTICE_POTENTIAL, compile_lattice,
};
pub use cranelift::lattice_steps::compile_lattice_steps;
pub use cranelift::step::{OrbitStepsFnPtr, TangentStepsFnPtr};
pub use cranelift::{
    AllocationWork, Compiled, LanesFnPtr, MAX_MEAN_LIVE, ScalarFnPtr, compile, compile_with,
    live_span,
};
pub use fused_plan::applies as fused_applies;
pub use step::{
    StepBackend, StepKernels, compile_steps, compile_steps_c, compile_steps_c_cancellable,
};
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
    /// Compile a lattice's fused one-orbit pass beside its step kernels
    /// ([`compile_lattice_steps`]; [`StepKernels::reference_tangent_steps`]), which only a
    /// run's small sets call (a map's batched kernels never do).
    pub fused_pass: bool,
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
            fused_pass: true,
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

// ---------------------------------------------------------------------------------------------
// Callbacks: the compiled code calls these for every operation that is not a single IEEE
// instruction, so the result is by construction the one `Graph` defines.

/// The address of the value function the compiled code calls for `op`, if it calls one.
fn unary_callback(op: Unary) -> Option<usize> {
    let def = op.def();
    (def.lowering == crate::ops::Lowering::Call).then_some(def.eval as usize)
}

/// The address of the value function the compiled code calls for `op`, if it calls one.
fn binary_callback(op: Binary) -> Option<usize> {
    let def = op.def();
    (def.lowering == crate::ops::Lowering::Call).then_some(def.eval as usize)
}

/// `table` points into `Compiled::_tables`. A panic inside `Tabulated::eval` aborts the process
/// (it cannot unwind through the compiled frames); `table::Spline` returns NaN instead.
extern "C" fn cb_table(table: *const Arc<dyn Tabulated>, deriv: u64, x: f64) -> f64 {
    // SAFETY: the pointer was taken from the boxed table slice owned by the `Compiled` whose
    // code is running, so it is valid and immutable for the duration of the call.
    let table = unsafe { &*table };
    table.eval(deriv as u8, x)
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
