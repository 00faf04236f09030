//! What the step kernels compute from and the one schedule of their stage, shared by both back
//! ends (Cranelift in [`super::cranelift::step`], C in [`super::c::emit`]): they accept exactly
//! the same kernels and print the same statements in the same order, each in its own language.

use super::{FunctionSpec, JitError, Layout, Plan, is_leaf, outputs_by_node};
use crate::graph::{Graph, Node, NodeId};

/// The derivatives of a separable Hamiltonian's potential as nodes of one [`Graph`].
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct StepSpec {
    /// Degrees of freedom `N`.
    pub n: usize,
    /// `dV/dq_j`, `N` nodes reading `q` as argument 0.
    pub gradient: Vec<NodeId>,
    /// `(Hess V(q) v)_j`, `N` nodes reading `q` as argument 0 and `v` as argument 1; `None`
    /// compiles no tangent kernel.
    pub hessian_vector: Option<Vec<NodeId>>,
}

/// The plan of step kernel `f` (gradient or Hessian-vector product), checked against the step's
/// shape: one output per degree of freedom, and no argument read beyond entry `N`. Shared by the
/// Cranelift and the C generators, which must accept exactly the same kernels.
pub(crate) fn kernel_plan(
    graph: &Graph,
    n: usize,
    f: usize,
    outputs: &[NodeId],
    args: Vec<Layout>,
) -> Result<Plan, JitError> {
    if outputs.len() != n || n == 0 {
        return Err(JitError::Steps(format!(
            "kernel {f}: {} outputs for {n} degrees of freedom",
            outputs.len()
        )));
    }
    let plan = Plan::new(
        graph,
        &FunctionSpec {
            args,
            outputs: outputs.to_vec(),
        },
        f,
    )?;
    if let Some(a) = plan.arg_len.iter().position(|&len| len > n) {
        return Err(JitError::Steps(format!(
            "kernel {f}: argument {a} is read at entry {}, beyond N = {n}",
            plan.arg_len[a] - 1
        )));
    }
    Ok(plan)
}

/// One statement of a block's code within a splitting stage (drift, force and kick fused), in
/// the order [`stage_schedule`] gives them.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum StageOp {
    /// `q_j += c_j p_j` for row `j`, stored; the drifted `q_j` and the `p_j` it read stay
    /// available to the statements after it.
    Drift(usize),
    /// The value of a varying node (one that reads the lane rows), in vector code; its operands
    /// are constants, uniform values, drifted rows or varying values already computed.
    Value(NodeId),
    /// `p_row -= dh * force`, with `p_row` the momentum row `row`'s drift read and `force` an
    /// operand as for [`StageOp::Value`].
    Kick { row: usize, force: NodeId },
}

/// The statements of one stage of the kernel `plan` (the gradient or the Hessian-vector product
/// of an `N`-row step, its lane rows read as argument `lane_arg`).
///
/// Rows are drifted just before their first use, so nothing of a row is live before it is
/// needed; a row's kick comes as soon as its force is known and always after its drift (a row
/// the force never reads is drifted for it), so every drift reads the momentum from before this
/// stage's kick, as separate drift and kick passes would; rows neither read nor kicked are
/// drifted at the end.
pub(crate) fn stage_schedule(graph: &Graph, plan: &Plan, n: usize, lane_arg: u8) -> Vec<StageOp> {
    let outs = outputs_by_node(plan, graph.len());
    let lane_row = |id: NodeId| match *graph.node(id) {
        Node::Input { arg, index } if arg == lane_arg => Some(index as usize),
        _ => None,
    };
    let mut drifted = vec![false; n];
    let mut ops = Vec::with_capacity(plan.varying_order.len() + 3 * n);
    let mut drift = |ops: &mut Vec<StageOp>, j: usize| {
        if !std::mem::replace(&mut drifted[j], true) {
            ops.push(StageOp::Drift(j));
        }
    };
    for &id in &plan.varying_order {
        for j in graph.node(id).operands().filter_map(lane_row) {
            drift(&mut ops, j);
        }
        ops.push(StageOp::Value(id));
        for &row in &outs[id as usize] {
            drift(&mut ops, row);
            ops.push(StageOp::Kick { row, force: id });
        }
    }
    // Forces that are not varying values: uniform ones, constants and a row itself.
    for (row, &force) in plan.outputs.iter().enumerate() {
        if plan.uniform[force as usize] || is_leaf(graph.node(force)) {
            drift(&mut ops, row);
            if let Some(j) = lane_row(force) {
                drift(&mut ops, j);
            }
            ops.push(StageOp::Kick { row, force });
        }
    }
    for j in 0..n {
        drift(&mut ops, j);
    }
    ops
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Where each statement of `ops` stands, per row: (drifts, kicks, first drift, first kick,
    /// first value reading the row).
    fn check_schedule(graph: &Graph, plan: &Plan, n: usize, lane_arg: u8, ops: &[StageOp]) {
        let mut drift_at = vec![None; n];
        let mut kicks = vec![0; n];
        let mut valued = vec![false; graph.len()];
        for (at, op) in ops.iter().enumerate() {
            match *op {
                StageOp::Drift(j) => {
                    assert!(drift_at[j].is_none(), "row {j} drifted twice: {ops:?}");
                    drift_at[j] = Some(at);
                }
                StageOp::Value(id) => {
                    for o in graph.node(id).operands() {
                        match *graph.node(o) {
                            Node::Input { arg, index } if arg == lane_arg => assert!(
                                drift_at[index as usize].is_some(),
                                "row {index} read before its drift: {ops:?}"
                            ),
                            Node::Const(_) | Node::Input { .. } => {}
                            _ => assert!(
                                plan.uniform[o as usize] || valued[o as usize],
                                "node {o} used before its value: {ops:?}"
                            ),
                        }
                    }
                    valued[id as usize] = true;
                }
                StageOp::Kick { row, force } => {
                    assert!(drift_at[row].is_some(), "row {row} kicked before its drift");
                    if let Node::Input { arg, index } = *graph.node(force)
                        && arg == lane_arg
                    {
                        assert!(
                            drift_at[index as usize].is_some(),
                            "row {row} kicked by row {index} before its drift"
                        );
                    }
                    assert_eq!(
                        force, plan.outputs[row],
                        "row {row} kicked by another force"
                    );
                    kicks[row] += 1;
                }
            }
        }
        assert!(
            drift_at.iter().all(Option::is_some),
            "a row never drifted: {ops:?}"
        );
        assert!(
            kicks.iter().all(|&k| k == 1),
            "kicks per row {kicks:?}: {ops:?}"
        );
    }

    /// A force that skips row 1, reads a constant, kicks row 3 by row 0 itself and row 2 by
    /// a varying value two rows share: every row drifted once, before it is read or kicked,
    /// and kicked once by its own force.
    #[test]
    fn every_row_is_drifted_once_before_its_use_and_kicked_once() {
        let mut g = Graph::new();
        let (q0, q2) = (g.input(0, 0), g.input(0, 2));
        let q0q2 = g.mul(q0, q2);
        let cube = g.powi(q0q2, 3);
        let two = g.constant(2.0);
        let outputs = vec![cube, two, q0q2, q0];
        let plan = kernel_plan(&g, 4, 0, &outputs, vec![Layout::Lanes]).unwrap();
        let ops = stage_schedule(&g, &plan, 4, 0);
        check_schedule(&g, &plan, 4, 0, &ops);
        // Rows are drifted at first use: 0 and 2 before the first value, 1 and 3 only for
        // their kicks.
        assert_eq!(
            &ops[..3],
            &[StageOp::Drift(0), StageOp::Drift(2), StageOp::Value(q0q2)]
        );
    }

    /// The tangent kernel's shape: the lanes are argument 1 (`dq`), argument 0 the stage's
    /// shared position (uniform): a uniform force, a row as another row's force, products of
    /// both.
    #[test]
    fn the_tangent_kernels_schedule_drifts_its_lane_rows_before_use() {
        let mut g = Graph::new();
        let (q0, q1) = (g.input(0, 0), g.input(0, 1));
        let (v0, v1, v2) = (g.input(1, 0), g.input(1, 1), g.input(1, 2));
        let q0v1 = g.mul(q0, v1);
        let v1v2 = g.mul(v1, v2);
        let q0q1 = g.mul(q0, q1);
        let outputs = vec![q0v1, v0, q0q1, v1v2];
        let plan = kernel_plan(&g, 4, 1, &outputs, vec![Layout::Scalar, Layout::Lanes]).unwrap();
        assert!(plan.uniform[q0q1 as usize]);
        let ops = stage_schedule(&g, &plan, 4, 1);
        check_schedule(&g, &plan, 4, 1, &ops);
    }
}
