//! What the step kernels compute from, shared by both back ends (Cranelift in
//! [`super::cranelift::step`], C in [`super::c`]), which must accept exactly the same
//! kernels.

use super::{FunctionSpec, JitError, Layout, Plan};
use crate::graph::{Graph, NodeId};

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
