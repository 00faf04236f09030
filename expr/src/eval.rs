//! The reference evaluator: the graph's meaning, operation by operation, with exactly the
//! rounding of [`Graph::apply_unary`], [`Graph::apply_binary`] and [`Graph::apply_powi`]. The
//! compiled code is tested against it bit for bit, and after a run produced a non-finite value
//! it names the operation that did ([`first_non_finite`]).

use std::sync::Arc;

use crate::graph::{Graph, Node, NodeId, Tabulated};

/// Evaluates `outputs` of `g` with argument arrays `args` (`Node::Input{arg, index}` reads
/// `args[arg][index]`).
///
/// Only the nodes the outputs depend on are evaluated (a graph holding a potential, its
/// gradient and its Hessian-vector product evaluates just the gradient's nodes when asked for
/// the gradient). [`Evaluator::eval`] marks the set anew on every call, into reused buffers:
/// marking is a single cheap pass, and a cache keyed on a graph would go stale silently when
/// the graph grows or is replaced. A caller that holds the graph borrowed and evaluates the
/// same outputs many times marks them once (`Needed::of`) and passes the marks to
/// `Evaluator::eval_marked`: the borrow is what keeps them valid.
#[derive(Debug, Default, Clone)]
pub struct Evaluator {
    /// Node values, indexed by node id (only needed entries are meaningful).
    values: Vec<f64>,
    /// Scratch: which nodes the outputs need.
    need: Vec<bool>,
}

impl Evaluator {
    pub fn new() -> Self {
        Self::default()
    }

    /// Writes the value of `outputs[k]` to `out[k]`.
    ///
    /// Panics if `out` is shorter than `outputs`, or an input reads past its argument array.
    pub fn eval(&mut self, g: &Graph, args: &[&[f64]], outputs: &[NodeId], out: &mut [f64]) {
        mark_needed(g, outputs, &mut self.need);
        eval_outputs(g, &self.need, &mut self.values, args, outputs, out);
    }

    /// [`Evaluator::eval`] with the nodes `outputs` need already marked in `need` (by
    /// [`Needed::of`] on this very graph): for a caller that evaluates the same outputs of a
    /// graph it holds borrowed many times (a lattice sum's term at every site), where the mark
    /// pass would cost as much as the evaluation.
    pub(crate) fn eval_marked(
        &mut self,
        g: &Graph,
        needed: &Needed,
        args: &[&[f64]],
        outputs: &[NodeId],
        out: &mut [f64],
    ) {
        debug_assert_eq!(needed.outputs, outputs, "marked for other outputs");
        debug_assert_eq!(needed.graph_len, g.len(), "marked on another graph");
        eval_outputs(g, &needed.need, &mut self.values, args, outputs, out);
    }
}

/// The marked nodes `need` evaluated into `values` (grown to fit), then `outputs` copied to
/// `out`: the part [`Evaluator::eval`] and [`Evaluator::eval_marked`] share.
fn eval_outputs(
    g: &Graph,
    need: &[bool],
    values: &mut Vec<f64>,
    args: &[&[f64]],
    outputs: &[NodeId],
    out: &mut [f64],
) {
    assert!(out.len() >= outputs.len(), "`out` shorter than `outputs`");
    if values.len() < need.len() {
        values.resize(need.len(), 0.0);
    }
    eval_needed(g, need, values, args, |_, _, _| false);
    for (o, &id) in out.iter_mut().zip(outputs) {
        *o = values[id as usize];
    }
}

/// The nodes some outputs of a graph depend on, marked once: valid for as long as the graph
/// it was marked on is borrowed unchanged (see [`Evaluator::eval_marked`]).
#[derive(Debug, Clone)]
pub(crate) struct Needed {
    outputs: Vec<NodeId>,
    need: Vec<bool>,
    /// The marked graph's node count, for a debug check that it is the graph evaluated.
    graph_len: usize,
}

impl Needed {
    pub(crate) fn of(g: &Graph, outputs: &[NodeId]) -> Self {
        let mut need = Vec::new();
        mark_needed(g, outputs, &mut need);
        Self {
            outputs: outputs.to_vec(),
            need,
            graph_len: g.len(),
        }
    }

    pub(crate) fn outputs(&self) -> &[NodeId] {
        &self.outputs
    }
}

/// Marks the nodes `outputs` depend on (`need[v]`), for `v` up to the largest output.
pub(crate) fn mark_needed(g: &Graph, outputs: &[NodeId], need: &mut Vec<bool>) {
    let len = outputs.iter().map(|&o| o as usize + 1).max().unwrap_or(0);
    need.clear();
    need.resize(len, false);
    for &o in outputs {
        need[o as usize] = true;
    }
    // Operands precede their users, so one backward pass closes the set.
    for v in (0..len).rev() {
        if need[v] {
            for o in g.node(v as NodeId).operands() {
                need[o as usize] = true;
            }
        }
    }
}

/// Evaluates the nodes marked in `need`, in order, into `values`; stops at the first node for
/// which `stop(node, its value, the values so far)` holds, and returns it.
#[inline]
fn eval_needed(
    g: &Graph,
    need: &[bool],
    values: &mut [f64],
    args: &[&[f64]],
    mut stop: impl FnMut(&Node, f64, &[f64]) -> bool,
) -> Option<NodeId> {
    for v in (0..need.len()).filter(|&v| need[v]) {
        let node = g.node(v as NodeId);
        let x = eval_node(g, node, values, args);
        values[v] = x;
        if stop(node, x, values) {
            return Some(v as NodeId);
        }
    }
    None
}

/// One node's value from its operands' values.
#[inline]
fn eval_node(g: &Graph, node: &Node, values: &[f64], args: &[&[f64]]) -> f64 {
    node_value(
        node,
        g.tables(),
        |id| values[id as usize],
        |arg, index| args[arg as usize][index as usize],
    )
}

/// One node's value, its operands' values given by `val`, its inputs' by `input`: the one
/// place a node's operation is applied to numbers.
#[inline]
pub(crate) fn node_value(
    node: &Node,
    tables: &[Arc<dyn Tabulated>],
    val: impl Fn(NodeId) -> f64,
    input: impl Fn(u8, u32) -> f64,
) -> f64 {
    match *node {
        Node::Const(c) => c,
        Node::Input { arg, index } => input(arg, index),
        Node::Unary(op, a) => Graph::apply_unary(op, val(a)),
        Node::Binary(op, a, b) => Graph::apply_binary(op, val(a), val(b)),
        Node::Powi(a, n) => Graph::apply_powi(val(a), n),
        Node::Select {
            cmp,
            a,
            b,
            then,
            otherwise,
        } => {
            if cmp.holds(val(a), val(b)) {
                val(then)
            } else {
                val(otherwise)
            }
        }
        Node::Table { table, deriv, arg } => tables[table as usize].eval(deriv, val(arg)),
    }
}

/// The first node in evaluation order (below `root`) whose value is NaN or infinite while all
/// its operands are finite: what produced a non-finite value (for a run-time error naming the
/// operation). An input or constant that is itself non-finite is its own culprit.
///
/// All nodes the root depends on are examined, so a NaN that a `select` discards is still
/// reported; callers ask after the root came out non-finite. `None` when every value is finite.
pub fn first_non_finite(g: &Graph, args: &[&[f64]], root: NodeId) -> Option<NodeId> {
    let mut need = Vec::new();
    mark_needed(g, &[root], &mut need);
    let mut values = vec![0.0; need.len()];
    eval_needed(g, &need, &mut values, args, |node, x, values| {
        !x.is_finite() && node.operands().all(|o| values[o as usize].is_finite())
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::graph::{Binary, Cmp, Tabulated, Unary};
    use std::sync::Arc;

    #[derive(Debug)]
    struct Panics;
    impl Tabulated for Panics {
        fn eval(&self, _: u8, _: f64) -> f64 {
            panic!("evaluated a node no output needs")
        }
        fn name(&self) -> &str {
            "panics"
        }
    }

    #[test]
    fn evaluates_with_the_graph_semantics() {
        let mut g = Graph::new();
        let x = g.input(0, 0);
        let v = g.input(1, 2);
        let s = g.unary(Unary::Sin, x);
        let p = g.powi(x, 3);
        let m = g.binary(Binary::Max, s, v);
        let sel = g.add(Node::Select {
            cmp: Cmp::Lt,
            a: x,
            b: v,
            then: p,
            otherwise: m,
        });
        let mut ev = Evaluator::new();
        let mut out = [0.0; 3];
        for &(xv, vv) in &[(0.3, 0.5), (0.9, -2.0), (-1.5, -1.6)] {
            ev.eval(&g, &[&[xv], &[0.0, 0.0, vv]], &[sel, p, m], &mut out);
            let want_m = Graph::apply_binary(Binary::Max, xv.sin(), vv);
            let want = if xv < vv { xv * xv * xv } else { want_m };
            assert_eq!(out[0].to_bits(), want.to_bits());
            assert_eq!(out[1].to_bits(), (xv * xv * xv).to_bits());
            assert_eq!(out[2].to_bits(), want_m.to_bits());
        }
    }

    #[test]
    fn evaluates_only_what_the_outputs_need() {
        let mut g = Graph::new();
        let t = g.add_table(Arc::new(Panics));
        let x = g.input(0, 0);
        let unused = g.add(Node::Table {
            table: t,
            deriv: 0,
            arg: x,
        });
        let y = g.powi(x, 2);
        let mut out = [0.0];
        let mut ev = Evaluator::new();
        ev.eval(&g, &[&[3.0]], &[y], &mut out);
        assert_eq!(out[0], 9.0);
        // The scratch shrinks and grows with the output list.
        ev.eval(&g, &[&[2.0]], &[x], &mut out);
        assert_eq!(out[0], 2.0);
        assert!(first_non_finite(&g, &[&[f64::NAN]], y) == Some(x));
        let _ = unused;
    }

    /// Marks taken once serve every later evaluation of the same outputs: the same bits as
    /// marking anew, and still nothing evaluated that the outputs do not need (the table that
    /// panics sits before them in the graph).
    #[test]
    fn marks_taken_once_evaluate_as_marking_anew() {
        let mut g = Graph::new();
        let t = g.add_table(Arc::new(Panics));
        let (x, y) = (g.input(0, 0), g.input(2, 1));
        let _unused = g.add(Node::Table {
            table: t,
            deriv: 0,
            arg: x,
        });
        let xy = g.mul(x, y);
        let s = g.unary(Unary::Sin, xy);
        let q = g.powi(y, 3);
        let outputs = [s, q];
        let needed = Needed::of(&g, &outputs);
        let (mut marked, mut fresh) = (Evaluator::new(), Evaluator::new());
        for &(xv, yv) in &[(0.3, 0.5), (1e3, -2.5), (-0.7, 7.0)] {
            let args: [&[f64]; 3] = [&[xv], &[], &[0.0, yv]];
            let (mut a, mut b) = ([0.0; 2], [0.0; 2]);
            marked.eval_marked(&g, &needed, &args, &outputs, &mut a);
            fresh.eval(&g, &args, &outputs, &mut b);
            assert_eq!(a.map(f64::to_bits), b.map(f64::to_bits));
            assert_eq!(a[1], yv * yv * yv);
        }
    }

    #[test]
    fn names_the_operation_that_went_non_finite() {
        let mut g = Graph::new();
        let x = g.input(0, 0);
        let one = g.constant(1.0);
        let d = g.sub(x, one);
        let l = g.unary(Unary::Log, d); // NaN for x < 1
        let e = g.unary(Unary::Exp, x); // inf for large x
        let s = g.add2(l, e);
        let r = g.div(one, s);
        assert_eq!(first_non_finite(&g, &[&[0.5]], r), Some(l));
        assert_eq!(first_non_finite(&g, &[&[1000.0]], r), Some(e));
        assert_eq!(first_non_finite(&g, &[&[2.0]], r), None);
        // 1 / (log(1) + exp(-inf)) = 1 / 0: the division.
        let z = g.unary(Unary::Sqrt, d);
        let q = g.div(one, z);
        assert_eq!(first_non_finite(&g, &[&[1.0]], q), Some(q));
        assert_eq!(first_non_finite(&g, &[&[0.0]], q), Some(z));
    }
}
