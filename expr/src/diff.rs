//! Symbolic derivatives as new nodes of the same [`Graph`]: the gradient of a potential by
//! reverse accumulation, and Jacobian-vector products (the Hessian-vector product of the
//! variational equations) by forward accumulation.
//!
//! Both sweeps visit each node once, so the derivative costs `O(graph)` nodes, not
//! `O(n * graph)`; hash-consing shares the pieces the gradient and the Hessian-vector product
//! have in common with the function itself (the bond `q[i+1] - q[i]`, `sqrt(u)` reused by its
//! own derivative).
//!
//! # How the gradient stays simple
//!
//! A node's adjoint is kept as a short sum of scaled terms `Σ c_k t_k` (`c_k` a number, `t_k`
//! a node, `1` standing for "no node") rather than as one node, so that
//! - constant factors meet and fold: `-(q2^3 / 3)` contributes `(-1/3) · 3 q2^2 = -q2^2`, not
//!   `-0.333… * (3 * q2 * q2)`;
//! - an adjoint of the form `c0 + c1 t` is distributed over the local derivative `d` as
//!   `c0 d + c1 (t d)` (never more nodes than `(c0 + c1 t) d`), which turns the adjoint of
//!   `q1^2` in Henon-Heiles, `1/2 + q2`, into the hand-written `q1 + 2 q1 q2` instead of
//!   `(1/2 + q2) (2 q1)`.
//!
//! Every other adjoint is summed into one node before it is used (so a bond's `f'(r)` is built
//! once and shared by both ends: a site's force is one subtraction `f'(r_{i-1}) - f'(r_i)`).
//! Sums are built in a fixed order (the first positive term, then the constant, then by
//! increasing node id, negative coefficients as subtractions), so the output depends only on
//! the graph: no hash-map iteration order reaches it. With these rules the Henon-Heiles
//! gradient is bit-identical to the hand-written `q1 + 2 q1 q2`, `q2 + q1^2 - q2^2` (tested).
//!
//! # Non-smooth operations
//!
//! `abs`, `max`, `min`, `step`, `sign` and `select` get their one-sided derivatives (`abs' =
//! sign`, `max' = ` the derivative of the selected operand, `step' = sign' = 0`); where they
//! matter (a kink crossed by a trajectory) is the smoothness check's business, not this one's.
//! In reverse mode the derivative of the branch not taken is multiplied by `0`, so an infinite
//! derivative there (`max(x, sqrt(x))` at `x = 0`) gives NaN where forward mode would not.

use crate::graph::{Binary, Cmp, Graph, Node, NodeId, Unary};
use crate::ops::BinaryDerivatives;

/// What cannot be differentiated.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum DiffError {
    /// Tables carry their value and three derivatives; a fourth would be needed.
    #[error(
        "table `{table}` would need its derivative {deriv}, but tables provide derivatives 0 to 3 only \
         (a cubic spline has no continuous derivative beyond the second): use the table in an \
         expression that is differentiated fewer times"
    )]
    TableDerivative { table: String, deriv: u8 },
}

/// The highest derivative a [`Node::Table`] provides.
const MAX_TABLE_DERIV: u8 = 3;

/// `c · t`, with `t = None` meaning the number `c` alone.
pub(crate) type Term = (f64, Option<NodeId>);

/// The local derivative of a one-operand operation, in a form that lets coefficients fold.
#[derive(Debug, Clone, Copy)]
pub(crate) enum Local {
    /// `c · d`
    Mul(f64, Option<NodeId>),
    /// `c / d`
    Div(f64, NodeId),
}

/// `a * b` with the operands in id order, so `x * y` and `y * x` are one node.
pub(crate) fn mul_sorted(g: &mut Graph, a: NodeId, b: NodeId) -> NodeId {
    if a <= b { g.mul(a, b) } else { g.mul(b, a) }
}

/// `t · d` where either may be absent (the number one).
fn mul_opt(g: &mut Graph, t: Option<NodeId>, d: Option<NodeId>) -> Option<NodeId> {
    match (t, d) {
        (None, x) | (x, None) => x,
        (Some(a), Some(b)) => Some(mul_sorted(g, a, b)),
    }
}

/// A node seen as a term: constants become coefficients, `-x` and `c * x` expose their factor.
fn as_term(g: &Graph, n: NodeId) -> Term {
    match *g.node(n) {
        Node::Const(c) => (c, None),
        Node::Unary(Unary::Neg, x) => (-1.0, Some(x)),
        Node::Binary(Binary::Mul, a, b) => match (g.as_const(a), g.as_const(b)) {
            (Some(c), _) => (c, Some(b)),
            (_, Some(c)) => (c, Some(a)),
            _ => (1.0, Some(n)),
        },
        _ => (1.0, Some(n)),
    }
}

/// A term applied to a local derivative.
fn apply_local(g: &mut Graph, (c, t): Term, local: Local) -> Term {
    match local {
        Local::Mul(cl, d) => (c * cl, mul_opt(g, t, d)),
        Local::Div(cl, d) => {
            let num = match t {
                Some(t) => t,
                None => g.constant(1.0),
            };
            (c * cl, Some(g.div(num, d)))
        }
    }
}

/// `c · t` as one node.
fn scaled(g: &mut Graph, (c, t): Term) -> NodeId {
    match t {
        None => g.constant(c),
        Some(t) if c == 1.0 => t,
        Some(t) if c == -1.0 => g.neg(t),
        Some(t) => {
            let k = g.constant(c);
            g.mul(k, t)
        }
    }
}

/// Merge terms on the same node and order them: the constant first, then by node id. Terms
/// with a zero coefficient vanish (as `0 * x` does in [`Graph::add`]).
fn normalize(terms: &mut Vec<Term>) {
    // `None < Some(_)`: the constant sorts first.
    terms.sort_by_key(|&(_, t)| t);
    let mut merged: Vec<Term> = Vec::with_capacity(terms.len());
    for &(c, t) in terms.iter() {
        match merged.last_mut() {
            Some((lc, lt)) if *lt == t => *lc += c,
            _ => merged.push((c, t)),
        }
    }
    merged.retain(|&(c, _)| c != 0.0);
    *terms = merged;
}

/// The sum of the terms as one node, negative coefficients as subtractions. The first
/// positive term leads, so `-a + b` is built as `b - a` (one node, not a negation and a sum).
fn materialize(g: &mut Graph, terms: &[Term]) -> NodeId {
    if terms.is_empty() {
        return g.constant(0.0);
    }
    let lead = terms.iter().position(|&(c, _)| c > 0.0).unwrap_or(0);
    let mut acc = scaled(g, terms[lead]);
    for &(c, t) in terms[..lead].iter().chain(&terms[lead + 1..]) {
        acc = if c < 0.0 {
            let s = scaled(g, (-c, t));
            g.sub(acc, s)
        } else {
            let s = scaled(g, (c, t));
            g.add2(acc, s)
        };
    }
    acc
}

fn table_deriv(g: &mut Graph, table: u32, deriv: u8, arg: NodeId) -> Result<NodeId, DiffError> {
    if deriv >= MAX_TABLE_DERIV {
        return Err(DiffError::TableDerivative {
            table: g.tables()[table as usize].name().to_string(),
            deriv: deriv + 1,
        });
    }
    Ok(g.add(Node::Table {
        table,
        deriv: deriv + 1,
        arg,
    }))
}

/// `d v / d u` for `v = op(u)` (its definition in [`crate::ops`]); `None` when it is zero.
fn unary_local(g: &mut Graph, op: Unary, u: NodeId, v: NodeId) -> Option<Local> {
    (op.def().derivative)(g, u, v)
}

/// `d u^n / d u = n u^(n-1)`, as `Powi` (so `(u^2)' = 2 u`).
fn powi_local(g: &mut Graph, u: NodeId, n: i32) -> Local {
    let p = g.powi(u, n - 1);
    match g.as_const(p) {
        Some(1.0) => Local::Mul(n as f64, None),
        _ => Local::Mul(n as f64, Some(p)),
    }
}

/// `d u^c / d u = c u^(c-1)` for a constant `c`: `Powi` when `c - 1` is whole.
fn pow_const_local(g: &mut Graph, u: NodeId, c: f64) -> Local {
    let e = c - 1.0;
    let p = if e == e.trunc() && e.abs() <= i32::MAX as f64 {
        g.powi(u, e as i32)
    } else {
        let k = g.constant(e);
        g.binary(Binary::Pow, u, k)
    };
    match g.as_const(p) {
        Some(1.0) => Local::Mul(c, None),
        _ => Local::Mul(c, Some(p)),
    }
}

/// Whether an adjoint can be pushed through a one-operand local derivative term by term
/// without creating more nodes than summing it first: at most one term carries a node.
///
/// A sum is never distributed, even over a constant factor (`-1` of a subtraction or a
/// negation): the adjoint of a bond `r` stays one node `f'(r)`, used whole by both its sites,
/// so a chain's force `f'(r_{i-1}) - f'(r_i)` comes out in the order a hand-written one has
/// (and the end sites, whose bond to a wall is `q_1 - 0` or `0 - q_N`, too).
fn distributable(terms: &[Term], _local: Local) -> bool {
    terms.iter().filter(|(_, t)| t.is_some()).count() <= 1
}

/// d root / d Input{arg, i} for i in 0..n, by reverse accumulation over the DAG (cost O(graph),
/// not O(n * graph)): the adjoints are new nodes of the same graph.
///
/// Inputs of other arguments, and indices `>= n`, are treated as constants. An input the root
/// does not depend on gets the constant `0`.
pub fn gradient(g: &mut Graph, root: NodeId, arg: u8, n: usize) -> Result<Vec<NodeId>, DiffError> {
    let len = root as usize + 1;
    let mut adj: Vec<Vec<Term>> = vec![Vec::new(); len];
    let mut input_ids: Vec<Option<NodeId>> = vec![None; n];
    adj[root as usize].push((1.0, None));

    for v in (0..=root).rev() {
        let node = *g.node(v);
        if let Node::Input { arg: a, index } = node {
            if a == arg && (index as usize) < n {
                input_ids[index as usize] = Some(v);
            }
            continue;
        }
        let mut terms = std::mem::take(&mut adj[v as usize]);
        normalize(&mut terms);
        if terms.is_empty() || matches!(node, Node::Const(_)) {
            continue;
        }
        // Push `terms · local` to operand `u` (a constant operand needs no adjoint).
        let push =
            |g: &mut Graph, adj: &mut Vec<Vec<Term>>, terms: &[Term], u: NodeId, local: Local| {
                if g.as_const(u).is_some() {
                    return;
                }
                for &t in terms {
                    let r = apply_local(g, t, local);
                    adj[u as usize].push(r);
                }
            };
        // The same through a one-operand local derivative, summing the terms first where
        // distributing them would cost nodes.
        let push_through =
            |g: &mut Graph, adj: &mut Vec<Vec<Term>>, terms: Vec<Term>, u: NodeId, local: Local| {
                let terms = through(g, terms, local);
                push(g, adj, &terms, u, local);
            };
        match node {
            Node::Const(_) | Node::Input { .. } => unreachable!(),
            Node::Unary(op, u) => {
                if let Some(local) = unary_local(g, op, u, v) {
                    push_through(g, &mut adj, terms, u, local);
                }
            }
            Node::Powi(u, k) => {
                let local = powi_local(g, u, k);
                push_through(g, &mut adj, terms, u, local);
            }
            Node::Table {
                table,
                deriv,
                arg: u,
            } => {
                if g.as_const(u).is_none() {
                    let d = table_deriv(g, table, deriv, u)?;
                    let local = Local::Mul(1.0, Some(d));
                    push_through(g, &mut adj, terms, u, local);
                }
            }
            Node::Binary(op, a, b) => {
                let (ca, cb) = (g.as_const(a), g.as_const(b));
                // With two varying operands the adjoint is summed once and shared.
                let shared = ca.is_none() && cb.is_none();
                let factor = |c: Option<f64>, other: NodeId| match c {
                    Some(c) => Local::Mul(c, None),
                    None => Local::Mul(1.0, Some(other)),
                };
                let locals = match op {
                    Binary::Add => [Local::Mul(1.0, None), Local::Mul(1.0, None)],
                    Binary::Sub => [Local::Mul(1.0, None), Local::Mul(-1.0, None)],
                    Binary::Mul => [factor(cb, b), factor(ca, a)],
                    _ => [Local::Mul(0.0, None); 2],
                };
                match op {
                    Binary::Add | Binary::Sub | Binary::Mul => {
                        let distribute = !shared && {
                            let l = if ca.is_none() { locals[0] } else { locals[1] };
                            distributable(&terms, l)
                        };
                        let terms = single_if(g, terms, !distribute);
                        push(g, &mut adj, &terms, a, locals[0]);
                        push(g, &mut adj, &terms, b, locals[1]);
                    }
                    Binary::Div => {
                        if let Some(c) = cb {
                            // x / c: the coefficient folds into the adjoint's constants, as a
                            // division (`x / 3` gives `adj / 3`, not `adj * 0.333…`).
                            // Divide each coefficient by c rather than multiply by 1/c.
                            if ca.is_none() {
                                for &(k, t) in &terms {
                                    adj[a as usize].push((k / c, t));
                                }
                            }
                        } else {
                            // a / b: da = 1 / b, db = -(a / b) / b, reusing the quotient v.
                            let s = single(g, &terms);
                            if ca.is_none() {
                                let r = g.div(s, b);
                                adj[a as usize].push((1.0, Some(r)));
                            }
                            let sv = mul_sorted(g, s, v);
                            let r = g.div(sv, b);
                            adj[b as usize].push((-1.0, Some(r)));
                        }
                    }
                    Binary::Pow => {
                        if let Some(c) = cb {
                            let local = pow_const_local(g, a, c);
                            push_through(g, &mut adj, terms, a, local);
                        } else {
                            // v = a^b: da = b v / a, db = v ln a.
                            let s = single(g, &terms);
                            if ca.is_none() {
                                let bv = mul_sorted(g, b, v);
                                let sbv = mul_sorted(g, s, bv);
                                let r = g.div(sbv, a);
                                adj[a as usize].push((1.0, Some(r)));
                            }
                            let ln = g.unary(Unary::Log, a);
                            let (lc, lt) = as_term(g, ln);
                            let vl = mul_opt(g, Some(v), lt);
                            let r = mul_opt(g, Some(s), vl);
                            adj[b as usize].push((lc, r));
                        }
                    }
                    Binary::Max | Binary::Min => {
                        let cmp = max_min_cmp(op);
                        push_selected(g, &mut adj, &terms, (cmp, a, b), [a, b]);
                    }
                    // A called function: its rule is in its table entry.
                    _ => {
                        let s = single(g, &terms);
                        let varies = [ca.is_none(), cb.is_none()];
                        let [ra, rb] = (derivatives(op).adjoint)(g, [a, b, v], s, varies);
                        if let Some(t) = ra {
                            adj[a as usize].push(t);
                        }
                        if let Some(t) = rb {
                            adj[b as usize].push(t);
                        }
                    }
                }
            }
            Node::Select {
                cmp,
                a,
                b,
                then,
                otherwise,
            } => push_selected(g, &mut adj, &terms, (cmp, a, b), [then, otherwise]),
        }
    }

    let mut out = Vec::with_capacity(n);
    for id in input_ids {
        out.push(match id {
            Some(id) => {
                let mut terms = std::mem::take(&mut adj[id as usize]);
                normalize(&mut terms);
                materialize(g, &terms)
            }
            None => g.constant(0.0),
        });
    }
    Ok(out)
}

fn select(
    g: &mut Graph,
    cmp: Cmp,
    a: NodeId,
    b: NodeId,
    then: NodeId,
    otherwise: NodeId,
) -> NodeId {
    g.add(Node::Select {
        cmp,
        a,
        b,
        then,
        otherwise,
    })
}

/// The condition under which `max` (`min`) selects its first operand: `a >= b` (`a <= b`).
fn max_min_cmp(op: Binary) -> Cmp {
    if op == Binary::Max { Cmp::Ge } else { Cmp::Le }
}

/// Pushes the adjoint `terms` of `cond ? then : otherwise` (a `select`, or `max`/`min` of its
/// operands) to each branch that is not constant, as the adjoint where the branch is taken
/// and zero elsewhere.
fn push_selected(
    g: &mut Graph,
    adj: &mut [Vec<Term>],
    terms: &[Term],
    (cmp, a, b): (Cmp, NodeId, NodeId),
    [then, otherwise]: [NodeId; 2],
) {
    let s = single(g, terms);
    let zero = g.constant(0.0);
    if g.as_const(then).is_none() {
        let r = select(g, cmp, a, b, s, zero);
        adj[then as usize].push((1.0, Some(r)));
    }
    if g.as_const(otherwise).is_none() {
        let r = select(g, cmp, a, b, zero, s);
        adj[otherwise as usize].push((1.0, Some(r)));
    }
}

/// The tangent of `cmp(a, b) ? then : otherwise` from the branches' tangents (`None`: zero).
fn select_tangent(
    g: &mut Graph,
    (cmp, a, b): (Cmp, NodeId, NodeId),
    [then, otherwise]: [Option<NodeId>; 2],
) -> Option<NodeId> {
    if then.is_none() && otherwise.is_none() {
        return None;
    }
    let zero = g.constant(0.0);
    Some(select(
        g,
        cmp,
        a,
        b,
        then.unwrap_or(zero),
        otherwise.unwrap_or(zero),
    ))
}

/// The adjoint as one node.
fn single(g: &mut Graph, terms: &[Term]) -> NodeId {
    materialize(g, terms)
}

/// The terms ready to pass through `local`: as they are when that costs no extra nodes, else
/// summed into one.
fn through(g: &mut Graph, terms: Vec<Term>, local: Local) -> Vec<Term> {
    let collapse = !distributable(&terms, local);
    single_if(g, terms, collapse)
}

/// The terms, summed into one term when `collapse` is set (and there is more than one).
fn single_if(g: &mut Graph, terms: Vec<Term>, collapse: bool) -> Vec<Term> {
    if collapse && terms.len() > 1 {
        let s = materialize(g, &terms);
        vec![as_term(g, s)]
    } else {
        terms
    }
}

/// `local · du` as one node. A product local derivative is built whole (`2 x`, `-sin x`) and
/// then multiplied by `du`, so it is the same node the gradient or another tangent uses.
fn apply_local_node(g: &mut Graph, local: Local, du: NodeId) -> NodeId {
    match local {
        Local::Mul(c, Some(d)) => {
            let l = scaled(g, (c, Some(d)));
            mul_sorted(g, l, du)
        }
        _ => {
            let term = apply_local(g, (1.0, Some(du)), local);
            scaled(g, term)
        }
    }
}

fn add_opt(g: &mut Graph, a: Option<NodeId>, b: Option<NodeId>) -> Option<NodeId> {
    match (a, b) {
        (None, x) | (x, None) => x,
        (Some(a), Some(b)) => Some(g.add2(a, b)),
    }
}

pub(crate) fn sub_opt(g: &mut Graph, a: Option<NodeId>, b: Option<NodeId>) -> Option<NodeId> {
    match (a, b) {
        (x, None) => x,
        (None, Some(b)) => Some(g.neg(b)),
        (Some(a), Some(b)) => Some(g.sub(a, b)),
    }
}

/// Forward mode: for each output o, sum_j d o / d Input{arg, j} * Input{dir_arg, j} (a
/// Jacobian-vector product; applied to the gradient it is the Hessian-vector product). Cost
/// O(graph).
///
/// Only the nodes the outputs depend on get a tangent. An output that does not depend on
/// `arg` gets the constant `0`.
pub fn directional(
    g: &mut Graph,
    outputs: &[NodeId],
    arg: u8,
    dir_arg: u8,
) -> Result<Vec<NodeId>, DiffError> {
    let mut need = Vec::new();
    crate::eval::mark_needed(g, outputs, &mut need);
    let mut tan: Vec<Option<NodeId>> = vec![None; need.len()];
    let seed = |g: &mut Graph, a: u8, index: u32| (a == arg).then(|| g.input(dir_arg, index));
    for v in 0..need.len() as NodeId {
        if need[v as usize] {
            tan[v as usize] = node_tangent(g, v, &tan, &seed)?;
        }
    }
    Ok(outputs
        .iter()
        .map(|&o| match tan[o as usize] {
            Some(d) => d,
            None => g.constant(0.0),
        })
        .collect())
}

/// The tangent of node `v` from its operands' tangents `tan` (`None`: zero), with the inputs'
/// own tangents given by `seed` (argument array, index).
fn node_tangent(
    g: &mut Graph,
    v: NodeId,
    tan: &[Option<NodeId>],
    seed: &dyn Fn(&mut Graph, u8, u32) -> Option<NodeId>,
) -> Result<Option<NodeId>, DiffError> {
    let t = |u: NodeId| tan[u as usize];
    let node = *g.node(v);
    Ok(match node {
        Node::Const(_) => None,
        Node::Input { arg: a, index } => seed(g, a, index),
        Node::Unary(op, u) => match (t(u), unary_local(g, op, u, v)) {
            (Some(du), Some(local)) => Some(apply_local_node(g, local, du)),
            _ => None,
        },
        Node::Powi(u, k) => t(u).map(|du| {
            let local = powi_local(g, u, k);
            apply_local_node(g, local, du)
        }),
        Node::Table {
            table,
            deriv,
            arg: u,
        } => match t(u) {
            Some(du) => {
                let d = table_deriv(g, table, deriv, u)?;
                Some(mul_sorted(g, d, du))
            }
            None => None,
        },
        Node::Binary(op, a, b) => {
            let (da, db) = (t(a), t(b));
            if da.is_none() && db.is_none() {
                None
            } else {
                binary_tangent(g, op, a, b, v, da, db)
            }
        }
        Node::Select {
            cmp,
            a,
            b,
            then,
            otherwise,
        } => select_tangent(g, (cmp, a, b), [t(then), t(otherwise)]),
    })
}

/// The partial derivatives of `outputs` with respect to the nodes `cuts`, each cut taken as an
/// independent variable (the other cuts held fixed, whatever they are computed from):
/// `result[o][c]` is `d outputs[o] / d cuts[c]`, the constant 0 where it does not depend on it.
/// Forward mode, one sweep per cut over the nodes the outputs need. With the cuts' own
/// tangents `t_c`, `sum_c result[o][c] t_c` is the directional derivative of `outputs[o]`.
pub fn partials_at(
    g: &mut Graph,
    outputs: &[NodeId],
    cuts: &[NodeId],
) -> Result<Vec<Vec<NodeId>>, DiffError> {
    let mut need = Vec::new();
    crate::eval::mark_needed(g, outputs, &mut need);
    let len = need.len();
    let mut out = vec![Vec::with_capacity(cuts.len()); outputs.len()];
    let none = |_: &mut Graph, _: u8, _: u32| None;
    for &c in cuts {
        let mut tan: Vec<Option<NodeId>> = vec![None; len];
        for v in 0..len as NodeId {
            if !need[v as usize] {
                continue;
            }
            tan[v as usize] = if v == c {
                Some(g.constant(1.0))
            } else if cuts.contains(&v) {
                None
            } else {
                node_tangent(g, v, &tan, &none)?
            };
        }
        for (o, &id) in outputs.iter().enumerate() {
            let d = match tan[id as usize] {
                Some(d) => d,
                None => g.constant(0.0),
            };
            out[o].push(d);
        }
    }
    Ok(out)
}

/// A sparse Jacobian: per output, `(input index, partial derivative node)` by increasing index.
pub type SparseRows = Vec<Vec<(u32, NodeId)>>;

/// Most (output, input) dependency pairs [`jacobian`] tracks before it gives up (dense
/// couplings of many sites: the sparse form would be no better than forward mode).
pub const MAX_JACOBIAN_ENTRIES: usize = 20_000_000;

/// The Jacobian of `outputs` with respect to `Input{arg, 0..}`, as sparse rows of symbolic
/// partial derivatives: `rows[i]` lists `(j, dO_i/dq_j)` for every input `j` output `i` depends
/// on, in increasing `j`. Each column is one forward pass seeded with `dq_j = 1` over the nodes
/// that depend on `q_j`, so a lattice with local couplings costs O(N). `None` when the
/// dependencies exceed [`MAX_JACOBIAN_ENTRIES`].
pub fn jacobian(
    g: &mut Graph,
    outputs: &[NodeId],
    arg: u8,
) -> Result<Option<SparseRows>, DiffError> {
    let mut need = Vec::new();
    crate::eval::mark_needed(g, outputs, &mut need);
    let len = need.len();
    // The inputs each needed node depends on, sorted.
    let mut deps: Vec<Vec<u32>> = vec![Vec::new(); len];
    let mut entries = 0usize;
    for v in 0..len {
        if !need[v] {
            continue;
        }
        let node = *g.node(v as NodeId);
        let mut d: Vec<u32> = match node {
            Node::Input { arg: a, index } if a == arg => vec![index],
            _ => Vec::new(),
        };
        for o in node.operands() {
            d.extend_from_slice(&deps[o as usize]);
        }
        d.sort_unstable();
        d.dedup();
        entries += d.len();
        if entries > MAX_JACOBIAN_ENTRIES {
            return Ok(None);
        }
        deps[v] = d;
    }
    // Nodes by the input they depend on, in evaluation order.
    let n_inputs = deps
        .iter()
        .flatten()
        .map(|&j| j as usize + 1)
        .max()
        .unwrap_or(0);
    let mut by_input: Vec<Vec<NodeId>> = vec![Vec::new(); n_inputs];
    for (v, d) in deps.iter().enumerate() {
        for &j in d {
            by_input[j as usize].push(v as NodeId);
        }
    }
    let mut rows: Vec<Vec<(u32, NodeId)>> = vec![Vec::new(); outputs.len()];
    // Which outputs a node is (an output may be listed twice).
    let mut output_of: std::collections::BTreeMap<NodeId, Vec<usize>> = Default::default();
    for (i, &o) in outputs.iter().enumerate() {
        output_of.entry(o).or_default().push(i);
    }
    let mut tan: Vec<Option<NodeId>> = vec![None; len];
    for (j, nodes) in by_input.iter().enumerate() {
        let j = j as u32;
        let seed =
            |g: &mut Graph, a: u8, index: u32| (a == arg && index == j).then(|| g.constant(1.0));
        for &v in nodes {
            tan[v as usize] = node_tangent(g, v, &tan, &seed)?;
        }
        for &v in nodes {
            let Some(d) = tan[v as usize].filter(|&d| g.as_const(d) != Some(0.0)) else {
                continue;
            };
            for &i in output_of.get(&v).map(Vec::as_slice).unwrap_or(&[]) {
                rows[i].push((j, d));
            }
        }
        for &v in nodes {
            tan[v as usize] = None;
        }
    }
    Ok(Some(rows))
}

/// `sum_j J_ij v_j` for each output, with the Jacobian's entries as coefficients (they depend on
/// `arg` only) times `Input{dir_arg, j}`, summed left to right in increasing `j`. For a
/// gradient this is the Hessian-vector product in the form written by hand (`(1 + 2 q2) v1 +
/// 2 q1 v2` for Henon-Heiles, bit for bit), and in the batched kernel the coefficients are
/// formed once per reference position while only the products and sums run per lane. Falls
/// back to [`directional`] when the dependencies are dense (see [`jacobian`]).
pub fn jacobian_vector(
    g: &mut Graph,
    outputs: &[NodeId],
    arg: u8,
    dir_arg: u8,
) -> Result<Vec<NodeId>, DiffError> {
    let Some(rows) = jacobian(g, outputs, arg)? else {
        return directional(g, outputs, arg, dir_arg);
    };
    Ok(rows
        .into_iter()
        .map(|row| {
            let mut acc: Option<NodeId> = None;
            for (j, c) in row {
                let v = g.input(dir_arg, j);
                let term = g.mul(c, v);
                acc = Some(match acc {
                    None => term,
                    Some(a) => g.add2(a, term),
                });
            }
            acc.unwrap_or_else(|| g.constant(0.0))
        })
        .collect())
}

/// The tangent of `v = op(a, b)` given the operands' tangents (at least one present).
fn binary_tangent(
    g: &mut Graph,
    op: Binary,
    a: NodeId,
    b: NodeId,
    v: NodeId,
    da: Option<NodeId>,
    db: Option<NodeId>,
) -> Option<NodeId> {
    match op {
        Binary::Add => add_opt(g, da, db),
        Binary::Sub => sub_opt(g, da, db),
        Binary::Mul => {
            let x = da.map(|da| mul_sorted(g, da, b));
            let y = db.map(|db| mul_sorted(g, a, db));
            add_opt(g, x, y)
        }
        Binary::Div => match db {
            // a / b with b constant: a' / b.
            None => da.map(|da| g.div(da, b)),
            // (a' - v b') / b, reusing the quotient v.
            Some(db) => {
                let vdb = mul_sorted(g, v, db);
                let num = sub_opt(g, da, Some(vdb)).expect("present");
                Some(g.div(num, b))
            }
        },
        Binary::Pow => {
            if let (Some(c), Some(da)) = (g.as_const(b), da) {
                let local = pow_const_local(g, a, c);
                return Some(apply_local_node(g, local, da));
            }
            // v (b' ln a + b a' / a)
            let x = db.map(|db| {
                let ln = g.unary(Unary::Log, a);
                mul_sorted(g, db, ln)
            });
            let y = da.map(|da| {
                let bda = mul_sorted(g, b, da);
                g.div(bda, a)
            });
            let s = add_opt(g, x, y).expect("present");
            Some(mul_sorted(g, v, s))
        }
        Binary::Max | Binary::Min => select_tangent(g, (max_min_cmp(op), a, b), [da, db]),
        // A called function: its rule is in its table entry.
        _ => Some((derivatives(op).tangent)(g, [a, b, v], [da, db])),
    }
}

/// The table's derivatives of a called two-argument function.
fn derivatives(op: Binary) -> &'static BinaryDerivatives {
    op.def()
        .derivatives
        .as_ref()
        .expect("a called two-argument function has its derivatives in ops.rs")
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::eval::Evaluator;
    use crate::graph::Tabulated;
    use crate::testing::{eval1, uniform01};
    use std::sync::Arc;

    /// Henon-Heiles as the lowering writes `(q1^2 + q2^2)/2 + q1^2*q2 - q2^3/3`.
    fn henon_heiles(g: &mut Graph) -> NodeId {
        henon_heiles_written(g, false)
    }

    /// Henon-Heiles, with `x / 2` and `x / 3` written as `x * 0.5` and `x * (1/3)` when
    /// `by_reciprocal`.
    fn henon_heiles_written(g: &mut Graph, by_reciprocal: bool) -> NodeId {
        let over = |g: &mut Graph, x: NodeId, d: f64| {
            if by_reciprocal {
                let c = g.constant(1.0 / d);
                g.mul(x, c)
            } else {
                let c = g.constant(d);
                g.div(x, c)
            }
        };
        let q1 = g.input(0, 0);
        let q2 = g.input(0, 1);
        let q1s = g.powi(q1, 2);
        let q2s = g.powi(q2, 2);
        let s = g.add2(q1s, q2s);
        let a = over(g, s, 2.0);
        let b = g.mul(q1s, q2);
        let ab = g.add2(a, b);
        let q2c = g.powi(q2, 3);
        let c = over(g, q2c, 3.0);
        g.sub(ab, c)
    }

    /// Deterministic pseudo-random numbers in [-1, 1).
    fn points(n: usize, seed: u64) -> Vec<f64> {
        uniform01(n, seed).iter().map(|u| 2.0 * u - 1.0).collect()
    }

    #[test]
    fn henon_heiles_gradient_is_bit_identical_to_the_hand_written_one() {
        for by_reciprocal in [false, true] {
            henon_heiles_gradient_bits(by_reciprocal);
        }
    }

    /// `by_reciprocal`: a lowering that writes `x / 2` as `x * 0.5` and `x / 3` as
    /// `x * (1/3)` gets the same gradient.
    fn henon_heiles_gradient_bits(by_reciprocal: bool) {
        let mut g = Graph::new();
        let v = henon_heiles_written(&mut g, by_reciprocal);
        let before = g.len();
        let grad = gradient(&mut g, v, 0, 2).unwrap();
        // q1 + 2 q1 q2: a product, a doubling, a sum; q2 + q1^2 - q2^2 reuses q1^2 and q2^2.
        let new_ops = g.nodes()[before..]
            .iter()
            .filter(|n| !matches!(n, Node::Const(_)))
            .count();
        assert_eq!(new_ops, 5, "{:?}", &g.nodes()[before..]);
        let mut ev = Evaluator::new();
        let mut out = [0.0; 2];
        let mut scales = vec![1e-300, 1e-8, 1.0, 3.0, 1e5, 1e150];
        scales.extend(points(20, 7).iter().map(|x| 10f64.powf(40.0 * x)));
        for (k, &scale) in scales.iter().enumerate() {
            // 26 scales x 50 000 points.
            let p = points(100_000, k as u64);
            for pair in p.chunks(2) {
                let (q1, q2) = (pair[0] * scale, pair[1] * scale);
                ev.eval(&g, &[&[q1, q2]], &grad, &mut out);
                let hand = [q1 + 2.0 * q1 * q2, q2 + q1 * q1 - q2 * q2];
                assert_eq!(
                    out[0].to_bits(),
                    hand[0].to_bits(),
                    "dV/dq1 at ({q1}, {q2})"
                );
                assert_eq!(
                    out[1].to_bits(),
                    hand[1].to_bits(),
                    "dV/dq2 at ({q1}, {q2})"
                );
            }
        }
    }

    /// A product of the Jacobian of outputs with a vector ([`directional`], [`jacobian_vector`]).
    type Product = fn(&mut Graph, &[NodeId], u8, u8) -> Result<Vec<NodeId>, DiffError>;

    /// The Henon-Heiles Hessian-vector product built by `product` from the gradient
    /// (positions in argument 0, the vector in argument 1).
    fn henon_heiles_hvp(product: Product) -> (Graph, Vec<NodeId>) {
        let mut g = Graph::new();
        let v = henon_heiles(&mut g);
        let grad = gradient(&mut g, v, 0, 2).unwrap();
        let hv = product(&mut g, &grad, 0, 1).unwrap();
        (g, hv)
    }

    /// The hand-written Henon-Heiles Hessian-vector product at `q` along `v`.
    fn henon_heiles_hvp_by_hand(q: &[f64], v: &[f64]) -> [f64; 2] {
        let (q1, q2, v1, v2) = (q[0], q[1], v[0], v[1]);
        [
            (1.0 + 2.0 * q2) * v1 + 2.0 * q1 * v2,
            2.0 * q1 * v1 + (1.0 - 2.0 * q2) * v2,
        ]
    }

    #[test]
    fn henon_heiles_hessian_vector_product() {
        let (g, hv) = henon_heiles_hvp(directional);
        for pt in points(4000, 3).chunks(4) {
            let (q, v) = pt.split_at(2);
            let r = eval1(&g, &[q, v], &hv);
            let hand = henon_heiles_hvp_by_hand(q, v);
            for k in 0..2 {
                assert!(
                    (r[k] - hand[k]).abs() <= 1e-15 * (1.0 + hand[k].abs()),
                    "{r:?} vs {hand:?}"
                );
            }
        }
    }

    #[test]
    fn henon_heiles_jacobian_vector_is_the_hand_written_hessian_vector_product() {
        let (g, hv) = henon_heiles_hvp(jacobian_vector);
        for (i, q) in points(2000, 3).chunks(2).enumerate() {
            let d = [((i * 7) % 11) as f64 - 5.3, 0.7 - (i % 5) as f64];
            let got = eval1(&g, &[q, &d], &hv);
            let want = henon_heiles_hvp_by_hand(q, &d);
            for k in 0..2 {
                assert_eq!(got[k].to_bits(), want[k].to_bits(), "q = {q:?}, v = {d:?}");
            }
        }
    }

    #[test]
    fn chain_jacobian_is_tridiagonal() {
        let mut g = Graph::new();
        let v = chain(&mut g, 50);
        let grad = gradient(&mut g, v, 0, 50).unwrap();
        let rows = jacobian(&mut g, &grad, 0).unwrap().unwrap();
        for (i, row) in rows.iter().enumerate() {
            let cols: Vec<u32> = row.iter().map(|(j, _)| *j).collect();
            let want: Vec<u32> = (i.saturating_sub(1)..(i + 2).min(50))
                .map(|j| j as u32)
                .collect();
            assert_eq!(cols, want, "row {i}");
        }
        // The same product as forward mode, to rounding.
        let a = jacobian_vector(&mut g, &grad, 0, 1).unwrap();
        let b = directional(&mut g, &grad, 0, 1).unwrap();
        let q: Vec<f64> = (0..50).map(|i| 0.1 * (i as f64).sin()).collect();
        let d: Vec<f64> = (0..50).map(|i| (i as f64 * 0.3).cos()).collect();
        let (x, y) = (eval1(&g, &[&q, &d], &a), eval1(&g, &[&q, &d], &b));
        for i in 0..50 {
            assert!(
                (x[i] - y[i]).abs() <= 1e-14 * (1.0 + y[i].abs()),
                "{i}: {} {}",
                x[i],
                y[i]
            );
        }
    }

    #[test]
    fn square_gives_a_doubling_not_a_power() {
        let mut g = Graph::new();
        let x = g.input(0, 0);
        let x2 = g.powi(x, 2);
        let d = gradient(&mut g, x2, 0, 1).unwrap()[0];
        let two = g.constant(2.0);
        assert_eq!(*g.node(d), Node::Binary(Binary::Mul, two, x));
        let t = directional(&mut g, &[x2], 0, 1).unwrap()[0];
        // (2 x) * v
        let v = g.input(1, 0);
        let tx = g.mul(two, x);
        assert_eq!(t, mul_sorted(&mut g, tx, v));
    }

    #[derive(Debug)]
    struct Cubic;
    impl Tabulated for Cubic {
        fn eval(&self, deriv: u8, x: f64) -> f64 {
            match deriv {
                0 => x * x * x,
                1 => 3.0 * x * x,
                2 => 6.0 * x,
                3 => 6.0,
                _ => panic!(),
            }
        }
        fn name(&self) -> &str {
            "cubic"
        }
    }

    type Build = fn(&mut Graph, NodeId, NodeId) -> NodeId;

    /// Every operation against central differences, in both modes, at points where it is
    /// smooth.
    #[test]
    fn every_operation_matches_finite_differences() {
        let cases: Vec<(&str, Build, [f64; 2])> = vec![
            ("neg", |g, x, _| g.neg(x), [0.3, 0.2]),
            ("add", |g, x, y| g.add2(x, y), [0.3, 0.2]),
            ("sub", |g, x, y| g.sub(x, y), [0.3, 0.2]),
            ("mul", |g, x, y| g.mul(x, y), [0.3, 0.2]),
            ("mul self", |g, x, _| g.mul(x, x), [0.3, 0.2]),
            ("div", |g, x, y| g.div(x, y), [0.3, 0.7]),
            (
                "div const",
                |g, x, _| {
                    let c = g.constant(3.0);
                    g.div(x, c)
                },
                [0.3, 0.7],
            ),
            (
                "const div",
                |g, x, _| {
                    let c = g.constant(3.0);
                    g.div(c, x)
                },
                [0.3, 0.7],
            ),
            ("powi 3", |g, x, _| g.powi(x, 3), [0.7, 0.0]),
            ("powi -2", |g, x, _| g.powi(x, -2), [0.7, 0.0]),
            (
                "pow 2.5",
                |g, x, _| {
                    let c = g.constant(2.5);
                    g.binary(Binary::Pow, x, c)
                },
                [0.7, 0.0],
            ),
            (
                "pow 3.0",
                |g, x, _| {
                    let c = g.constant(3.0);
                    g.binary(Binary::Pow, x, c)
                },
                [0.7, 0.0],
            ),
            ("pow xy", |g, x, y| g.binary(Binary::Pow, x, y), [0.7, 1.3]),
            (
                "pow 2^y",
                |g, _, y| {
                    let c = g.constant(2.0);
                    g.binary(Binary::Pow, c, y)
                },
                [0.7, 1.3],
            ),
            ("sqrt", |g, x, _| g.unary(Unary::Sqrt, x), [0.7, 0.0]),
            ("exp", |g, x, _| g.unary(Unary::Exp, x), [0.7, 0.0]),
            ("log", |g, x, _| g.unary(Unary::Log, x), [0.7, 0.0]),
            ("sin", |g, x, _| g.unary(Unary::Sin, x), [0.7, 0.0]),
            ("cos", |g, x, _| g.unary(Unary::Cos, x), [0.7, 0.0]),
            ("tan", |g, x, _| g.unary(Unary::Tan, x), [0.7, 0.0]),
            ("atan", |g, x, _| g.unary(Unary::Atan, x), [0.7, 0.0]),
            ("tanh", |g, x, _| g.unary(Unary::Tanh, x), [0.7, 0.0]),
            ("cosh", |g, x, _| g.unary(Unary::Cosh, x), [0.7, 0.0]),
            ("sinh", |g, x, _| g.unary(Unary::Sinh, x), [0.7, 0.0]),
            ("asinh", |g, x, _| g.unary(Unary::Asinh, x), [-1.3, 0.0]),
            ("abs", |g, x, _| g.unary(Unary::Abs, x), [-0.7, 0.0]),
            (
                "step",
                |g, x, y| {
                    let s = g.unary(Unary::Step, x);
                    g.mul(s, y)
                },
                [-0.7, 0.4],
            ),
            (
                "sign",
                |g, x, y| {
                    let s = g.unary(Unary::Sign, x);
                    g.mul(s, y)
                },
                [0.7, 0.4],
            ),
            (
                "atan2",
                |g, x, y| g.binary(Binary::Atan2, x, y),
                [0.7, -0.4],
            ),
            ("max a", |g, x, y| g.binary(Binary::Max, x, y), [0.7, -0.4]),
            ("max b", |g, x, y| g.binary(Binary::Max, x, y), [-0.7, -0.4]),
            ("min a", |g, x, y| g.binary(Binary::Min, x, y), [-0.7, -0.4]),
            ("min b", |g, x, y| g.binary(Binary::Min, x, y), [0.7, -0.4]),
            (
                "select",
                |g, x, y| {
                    let s = g.unary(Unary::Sin, x);
                    let c = g.unary(Unary::Cos, y);
                    g.add(Node::Select {
                        cmp: Cmp::Lt,
                        a: x,
                        b: y,
                        then: s,
                        otherwise: c,
                    })
                },
                [0.7, -0.4],
            ),
            (
                "select other",
                |g, x, y| {
                    let s = g.unary(Unary::Sin, x);
                    let c = g.mul(x, y);
                    g.add(Node::Select {
                        cmp: Cmp::Gt,
                        a: x,
                        b: y,
                        then: c,
                        otherwise: s,
                    })
                },
                [-0.7, 0.4],
            ),
            (
                "table",
                |g, x, _| {
                    g.add(Node::Table {
                        table: 0,
                        deriv: 0,
                        arg: x,
                    })
                },
                [0.7, 0.0],
            ),
            (
                "table'",
                |g, x, _| {
                    g.add(Node::Table {
                        table: 0,
                        deriv: 1,
                        arg: x,
                    })
                },
                [0.7, 0.0],
            ),
            (
                "composite",
                |g, x, y| {
                    let s = g.unary(Unary::Sin, x);
                    let e = g.mul(s, y);
                    let l = g.unary(Unary::Exp, e);
                    let q = g.powi(x, 2);
                    let d = g.div(l, q);
                    g.mul(d, s)
                },
                [0.7, -0.4],
            ),
        ];
        for (name, build, at) in cases {
            let mut g = Graph::new();
            g.add_table(Arc::new(Cubic));
            let x = g.input(0, 0);
            let y = g.input(0, 1);
            let f = build(&mut g, x, y);
            let grad = gradient(&mut g, f, 0, 2).unwrap();
            let jv = directional(&mut g, &[f], 0, 1).unwrap();
            let dir = [0.6, -0.8];
            let r = eval1(&g, &[&at, &dir], &grad);
            let rjv = eval1(&g, &[&at, &dir], &jv)[0];
            let h = 1e-6;
            let mut fd = [0.0; 2];
            for k in 0..2 {
                let (mut p, mut m) = (at, at);
                p[k] += h;
                m[k] -= h;
                fd[k] = (eval1(&g, &[&p], &[f])[0] - eval1(&g, &[&m], &[f])[0]) / (2.0 * h);
                assert!(
                    (r[k] - fd[k]).abs() < 1e-7 * (1.0 + fd[k].abs()),
                    "{name}: d/dx{k} = {} vs {}",
                    r[k],
                    fd[k]
                );
            }
            let want = fd[0] * dir[0] + fd[1] * dir[1];
            assert!(
                (rjv - want).abs() < 1e-7 * (1.0 + want.abs()),
                "{name}: directional {rjv} vs {want}"
            );
        }
    }

    #[test]
    fn asinh_has_the_analytic_derivatives() {
        // d/dx asinh x = 1 / sqrt(1 + x^2), d2/dx2 = -x / (1 + x^2)^(3/2). The gradient is
        // built as exactly that expression (one rounding per operation, as the formula here), so
        // it agrees to an ulp or two; the second derivative is the forward-mode tangent of the
        // gradient, a different but equivalent order of operations: a few ulps, 1e-14 relative.
        for x in [-3.0, -0.4, 0.0, 0.25, 2.0, 40.0] {
            let mut g = Graph::new();
            let q = g.input(0, 0);
            let f = g.unary(Unary::Asinh, q);
            let d = gradient(&mut g, f, 0, 1).unwrap();
            let h = directional(&mut g, &d, 0, 1).unwrap();
            let d1 = eval1(&g, &[&[x]], &d)[0];
            let want1 = 1.0 / (1.0 + x * x).sqrt();
            assert!(
                (d1 - want1).abs() <= 4.0 * f64::EPSILON * want1,
                "{x}: {d1} vs {want1}"
            );
            let h1 = eval1(&g, &[&[x], &[1.0]], &h)[0];
            let want2 = -x / (1.0 + x * x).powf(1.5);
            assert!(
                (h1 - want2).abs() <= 1e-14 * want2.abs().max(1e-300),
                "{x}: {h1} vs {want2}"
            );
        }
    }

    #[test]
    fn a_fourth_table_derivative_is_an_error_naming_the_table() {
        let mut g = Graph::new();
        let t = g.add_table(Arc::new(Cubic));
        let x = g.input(0, 0);
        let f = g.add(Node::Table {
            table: t,
            deriv: 3,
            arg: x,
        });
        let e = gradient(&mut g, f, 0, 1).unwrap_err();
        assert_eq!(
            e,
            DiffError::TableDerivative {
                table: "cubic".into(),
                deriv: 4
            }
        );
        assert!(e.to_string().contains("table `cubic`"));
        assert!(directional(&mut g, &[f], 0, 1).is_err());
        // Two derivatives of the value are fine.
        let f0 = g.add(Node::Table {
            table: t,
            deriv: 0,
            arg: x,
        });
        let d = gradient(&mut g, f0, 0, 1).unwrap();
        assert!(directional(&mut g, &d, 0, 1).is_ok());
    }

    /// `sum over bonds of f(q[i+1] - q[i])` with an FPUT bond.
    fn chain(g: &mut Graph, n: u32) -> NodeId {
        let mut acc = g.constant(0.0);
        let (two, four) = (g.constant(2.0), g.constant(4.0));
        for i in 0..n - 1 {
            let a = g.input(0, i + 1);
            let b = g.input(0, i);
            let r = g.sub(a, b);
            let r2 = g.powi(r, 2);
            let r4 = g.powi(r, 4);
            let t2 = g.div(r2, two);
            let t4 = g.div(r4, four);
            let f = g.add2(t2, t4);
            acc = g.add2(acc, f);
        }
        acc
    }

    #[test]
    fn chain_gradient_stays_linear_in_the_length() {
        let mut sizes = Vec::new();
        for n in [101u32, 1001] {
            let mut g = Graph::new();
            let v = chain(&mut g, n);
            let before = g.len();
            let grad = gradient(&mut g, v, 0, n as usize).unwrap();
            let mid = g.len();
            directional(&mut g, &grad, 0, 1).unwrap();
            sizes.push((n, before, mid - before, g.len() - mid));
            // Interior sites: f'(r_{i-1}) - f'(r_i), with f'(r) = r + r^3 shared by both ends.
            let q: Vec<f64> = points(n as usize, 11);
            let r = eval1(&g, &[&q], &grad);
            let fp = |r: f64| r + r * r * r;
            for i in 1..n as usize - 1 {
                let want = fp(q[i] - q[i - 1]) - fp(q[i + 1] - q[i]);
                assert_eq!(r[i].to_bits(), want.to_bits(), "site {i}");
            }
        }
        let (n0, _, g0, h0) = sizes[0];
        let (n1, _, g1, h1) = sizes[1];
        let ratio = (n1 - 1) as f64 / (n0 - 1) as f64;
        assert!((g1 as f64 / g0 as f64) < 1.05 * ratio, "{sizes:?}");
        assert!((h1 as f64 / h0 as f64) < 1.05 * ratio, "{sizes:?}");
        // Three nodes per bond: r^3, r + r^3, and one subtraction per site.
        assert!(g1 <= 3 * n1 as usize, "{sizes:?}");
    }

    #[test]
    fn derivatives_are_deterministic() {
        let build = || {
            let mut g = Graph::new();
            let v = chain(&mut g, 50);
            let hh = henon_heiles(&mut g);
            let s = g.add2(v, hh);
            let e = g.unary(Unary::Exp, s);
            let grad = gradient(&mut g, e, 0, 50).unwrap();
            let hv = directional(&mut g, &grad, 0, 1).unwrap();
            (g.nodes().to_vec(), grad, hv)
        };
        let a = build();
        let b = build();
        assert_eq!(a.1, b.1);
        assert_eq!(a.2, b.2);
        assert_eq!(a.0.len(), b.0.len());
        for (x, y) in a.0.iter().zip(&b.0) {
            // Node's PartialEq compares constants by value; NaN-free here.
            assert_eq!(x, y);
        }
    }

    #[test]
    fn inputs_not_reached_get_zero() {
        let mut g = Graph::new();
        let x = g.input(0, 0);
        let y = g.input(1, 0);
        let f = g.mul(x, y);
        let grad = gradient(&mut g, f, 0, 3).unwrap();
        assert_eq!(grad[0], y);
        assert_eq!(g.as_const(grad[1]), Some(0.0));
        assert_eq!(g.as_const(grad[2]), Some(0.0));
    }
}
