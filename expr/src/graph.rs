//! The expression DAG every stage shares: parsed systems are lowered into it, derivatives are
//! added to it, the evaluator and the native compiler read it.
//!
//! Nodes are hash-consed: building the same node twice returns the same id, so common
//! subexpressions (the bond `q[i+1] - q[i]` used by two sites, a stiffness shared by the
//! gradient and the Hessian) are computed once. A node only refers to nodes created before it,
//! so the node order is a valid evaluation order.
//!
//! The meaning of every operation is fixed here (the one-argument functions in `ops`), down to
//! the rounding: the evaluator (`eval`) and the compiled code (`jit`) perform exactly these
//! IEEE operations in this order and call the same Rust functions for the transcendental ones,
//! so they agree bit for bit. No fused multiply-add anywhere.

use std::collections::HashMap;
use std::sync::Arc;

/// Largest `|n|` of a [`Node::Powi`]; a larger whole power is built as `powf` (see
/// [`Graph::add`]).
pub const MAX_POWI: u32 = 64;

/// Index of a node in its [`Graph`].
pub type NodeId = u32;

/// One-argument operations, each defined in [`crate::ops`].
pub use crate::ops::Unary;

/// Two-argument operations, each defined in [`crate::ops`].
pub use crate::ops::Binary;

/// Comparisons of a [`Node::Select`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Cmp {
    Lt,
    Le,
    Gt,
    Ge,
}

impl Cmp {
    #[inline]
    pub fn holds(self, a: f64, b: f64) -> bool {
        match self {
            Cmp::Lt => a < b,
            Cmp::Le => a <= b,
            Cmp::Gt => a > b,
            Cmp::Ge => a >= b,
        }
    }
}

/// One operation of the DAG. Constants are compared by their bits (so `0.0` and `-0.0` and
/// different NaNs are different nodes).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Node {
    Const(f64),
    /// Entry `index` of the function's argument array `arg` (for a potential, `arg 0` is `q`;
    /// for a Hessian-vector product `arg 1` is the direction `v`; see the producer of the graph).
    Input {
        arg: u8,
        index: u32,
    },
    Unary(Unary, NodeId),
    Binary(Binary, NodeId, NodeId),
    /// `x^n` for a whole `n`: `x * x * ... * x` (n factors, multiplied left to right) for
    /// `n >= 1`, `1` for `n = 0`, `1 / x^|n|` for `n < 0`. A fixed product order, so both
    /// back ends round alike, and `q^3` is exactly the hand-written `q * q * q`.
    Powi(NodeId, i32),
    /// `if cmp(a, b) { then } else { otherwise }`; both branches are evaluated (no side effects).
    Select {
        cmp: Cmp,
        a: NodeId,
        b: NodeId,
        then: NodeId,
        otherwise: NodeId,
    },
    /// Derivative `deriv` (0 to 3) of tabulated function `table` at `arg`.
    Table {
        table: u32,
        deriv: u8,
        arg: NodeId,
    },
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
enum Key {
    Const(u64),
    Input(u8, u32),
    Unary(Unary, NodeId),
    Binary(Binary, NodeId, NodeId),
    Powi(NodeId, i32),
    Select(Cmp, NodeId, NodeId, NodeId, NodeId),
    Table(u32, u8, NodeId),
}

impl Node {
    fn key(&self) -> Key {
        match *self {
            Node::Const(c) => Key::Const(c.to_bits()),
            Node::Input { arg, index } => Key::Input(arg, index),
            Node::Unary(u, a) => Key::Unary(u, a),
            Node::Binary(b, x, y) => Key::Binary(b, x, y),
            Node::Powi(x, n) => Key::Powi(x, n),
            Node::Select {
                cmp,
                a,
                b,
                then,
                otherwise,
            } => Key::Select(cmp, a, b, then, otherwise),
            Node::Table { table, deriv, arg } => Key::Table(table, deriv, arg),
        }
    }

    /// The nodes this one reads.
    pub fn operands(&self) -> impl Iterator<Item = NodeId> {
        let (ops, n): ([NodeId; 4], usize) = match *self {
            Node::Const(_) | Node::Input { .. } => ([0; 4], 0),
            Node::Unary(_, a) | Node::Powi(a, _) | Node::Table { arg: a, .. } => ([a, 0, 0, 0], 1),
            Node::Binary(_, a, b) => ([a, b, 0, 0], 2),
            Node::Select {
                a,
                b,
                then,
                otherwise,
                ..
            } => ([a, b, then, otherwise], 4),
        };
        ops.into_iter().take(n)
    }
}

/// A tabulated function of one variable with its first two derivatives, as the graph sees it.
/// Implemented by `table::Spline`; a trait so the graph does not depend on how tables are read.
pub trait Tabulated: Send + Sync + std::fmt::Debug {
    /// Derivative `deriv` (0 to 3) at `x`; NaN outside the tabulated range.
    fn eval(&self, deriv: u8, x: f64) -> f64;
    /// Name for messages (the config's name of the table).
    fn name(&self) -> &str;
}

/// The hash-consed DAG.
#[derive(Debug, Clone, Default)]
pub struct Graph {
    nodes: Vec<Node>,
    index: HashMap<Key, NodeId>,
    tables: Vec<Arc<dyn Tabulated>>,
}

impl Graph {
    pub fn new() -> Self {
        Self::default()
    }

    pub fn len(&self) -> usize {
        self.nodes.len()
    }

    pub fn is_empty(&self) -> bool {
        self.nodes.is_empty()
    }

    pub fn node(&self, id: NodeId) -> &Node {
        &self.nodes[id as usize]
    }

    pub fn nodes(&self) -> &[Node] {
        &self.nodes
    }

    pub fn tables(&self) -> &[Arc<dyn Tabulated>] {
        &self.tables
    }

    /// Register a tabulated function; returns its index for [`Node::Table`].
    pub fn add_table(&mut self, table: Arc<dyn Tabulated>) -> u32 {
        self.tables.push(table);
        (self.tables.len() - 1) as u32
    }

    /// The node's id, creating it if it is new. Constant operands are folded (the same IEEE
    /// operation the evaluator would perform), and a few exact identities are applied
    /// (`x + 0`, `x * 1`, `x / 1`, `0 * x` and `x * 0`, `0 - x` as `-x`, `-(-x)`, `x^1`):
    /// derivatives produce many of them. `x - 0` stays a node of its own: it is how a lattice
    /// sum writes the bond to a wall, and as a separate node its adjoint is that bond's force
    /// as a whole (see `diff`).
    pub fn add(&mut self, node: Node) -> NodeId {
        let node = match self.simplify(node) {
            Ok(id) => return id,
            Err(node) => node,
        };
        let key = node.key();
        if let Some(&id) = self.index.get(&key) {
            return id;
        }
        debug_assert!(node.operands().all(|o| (o as usize) < self.nodes.len()));
        let id = self.nodes.len() as NodeId;
        self.nodes.push(node);
        self.index.insert(key, id);
        id
    }

    pub fn constant(&mut self, c: f64) -> NodeId {
        self.add(Node::Const(c))
    }

    pub fn input(&mut self, arg: u8, index: u32) -> NodeId {
        self.add(Node::Input { arg, index })
    }

    pub fn unary(&mut self, op: Unary, a: NodeId) -> NodeId {
        self.add(Node::Unary(op, a))
    }

    pub fn binary(&mut self, op: Binary, a: NodeId, b: NodeId) -> NodeId {
        self.add(Node::Binary(op, a, b))
    }

    pub fn add2(&mut self, a: NodeId, b: NodeId) -> NodeId {
        self.binary(Binary::Add, a, b)
    }

    pub fn sub(&mut self, a: NodeId, b: NodeId) -> NodeId {
        self.binary(Binary::Sub, a, b)
    }

    pub fn mul(&mut self, a: NodeId, b: NodeId) -> NodeId {
        self.binary(Binary::Mul, a, b)
    }

    pub fn div(&mut self, a: NodeId, b: NodeId) -> NodeId {
        self.binary(Binary::Div, a, b)
    }

    pub fn neg(&mut self, a: NodeId) -> NodeId {
        self.unary(Unary::Neg, a)
    }

    pub fn powi(&mut self, a: NodeId, n: i32) -> NodeId {
        self.add(Node::Powi(a, n))
    }

    /// The constant value of a node, if it is one.
    pub fn as_const(&self, id: NodeId) -> Option<f64> {
        match self.nodes[id as usize] {
            Node::Const(c) => Some(c),
            _ => None,
        }
    }

    /// The operation of a node as messages quote it: `'log'`, `'/'`, `'^3'`, `'unary -'`,
    /// `table 'U'` (what produced a non-finite value, say).
    pub fn operation_name(&self, id: NodeId) -> String {
        let op = match self.nodes[id as usize] {
            Node::Unary(u, _) => match u {
                Unary::Neg => "unary -".into(),
                other => format!("{other:?}").to_lowercase(),
            },
            Node::Binary(b, _, _) => b.def().symbol.into(),
            Node::Powi(_, n) => format!("^{n}"),
            Node::Select { .. } => "if".into(),
            Node::Table { table, .. } => {
                return format!("table '{}'", self.tables[table as usize].name());
            }
            Node::Const(_) | Node::Input { .. } => "value".into(),
        };
        format!("'{op}'")
    }

    fn is_const(&self, id: NodeId, v: f64) -> bool {
        self.as_const(id).is_some_and(|c| c == v)
    }

    /// `Ok(existing node)` when `node` folds or simplifies, else the node to insert.
    fn simplify(&mut self, node: Node) -> Result<NodeId, Node> {
        let c = |g: &Self, id| g.as_const(id);
        let folded = match node {
            Node::Unary(op, a) => match op {
                Unary::Neg => match self.nodes[a as usize] {
                    Node::Unary(Unary::Neg, inner) => return Ok(inner),
                    _ => c(self, a).map(|x| Self::apply_unary(op, x)),
                },
                _ => c(self, a).map(|x| Self::apply_unary(op, x)),
            },
            Node::Binary(op, a, b) => {
                if let (Some(x), Some(y)) = (c(self, a), c(self, b)) {
                    Some(Self::apply_binary(op, x, y))
                } else {
                    match op {
                        Binary::Add if self.is_const(b, 0.0) => return Ok(a),
                        Binary::Add if self.is_const(a, 0.0) => return Ok(b),
                        Binary::Sub if self.is_const(a, 0.0) => {
                            return Ok(self.add(Node::Unary(Unary::Neg, b)));
                        }
                        Binary::Mul if self.is_const(b, 1.0) => return Ok(a),
                        Binary::Mul if self.is_const(a, 1.0) => return Ok(b),
                        Binary::Mul if self.is_const(a, 0.0) || self.is_const(b, 0.0) => Some(0.0),
                        Binary::Div if self.is_const(b, 1.0) => return Ok(a),
                        Binary::Div if self.is_const(a, 0.0) => Some(0.0),
                        _ => None,
                    }
                }
            }
            Node::Powi(a, n) => {
                if n.unsigned_abs() > MAX_POWI {
                    // A product of thousands of factors would be as many instructions in the
                    // compiled code (and as many multiplications per evaluation): `powf` instead.
                    let c = self.insert_const(f64::from(n));
                    return Ok(self.add(Node::Binary(Binary::Pow, a, c)));
                }
                if n == 1 {
                    return Ok(a);
                }
                if n == 0 {
                    Some(1.0)
                } else {
                    c(self, a).map(|x| Self::apply_powi(x, n))
                }
            }
            Node::Select {
                cmp,
                a,
                b,
                then,
                otherwise,
            } => {
                if then == otherwise {
                    return Ok(then);
                }
                match (c(self, a), c(self, b)) {
                    (Some(x), Some(y)) => {
                        return Ok(if cmp.holds(x, y) { then } else { otherwise });
                    }
                    _ => None,
                }
            }
            Node::Table { table, deriv, arg } => c(self, arg)
                .map(|x| self.tables[table as usize].eval(deriv, x))
                .filter(|v| v.is_finite()),
            Node::Const(_) | Node::Input { .. } => None,
        };
        match folded {
            Some(v) => Ok(self.insert_const(v)),
            None => Err(node),
        }
    }

    fn insert_const(&mut self, v: f64) -> NodeId {
        let key = Key::Const(v.to_bits());
        if let Some(&id) = self.index.get(&key) {
            return id;
        }
        let id = self.nodes.len() as NodeId;
        self.nodes.push(Node::Const(v));
        self.index.insert(key, id);
        id
    }

    /// The value of a unary operation: its one definition in [`crate::ops`], which the
    /// compiled code calls too.
    #[inline]
    pub fn apply_unary(op: Unary, x: f64) -> f64 {
        (op.def().eval)(x)
    }

    /// The value of a binary operation: its one definition in [`crate::ops`], which the
    /// compiled code calls too.
    #[inline]
    pub fn apply_binary(op: Binary, a: f64, b: f64) -> f64 {
        (op.def().eval)(a, b)
    }

    /// `x^n` as [`Node::Powi`] defines it.
    #[inline]
    pub fn apply_powi(x: f64, n: i32) -> f64 {
        if n == 0 {
            return 1.0;
        }
        let m = n.unsigned_abs();
        let mut acc = x;
        for _ in 1..m {
            acc *= x;
        }
        if n < 0 { 1.0 / acc } else { acc }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hash_consing_and_folding() {
        let mut g = Graph::new();
        let q = g.input(0, 0);
        let two = g.constant(2.0);
        let a = g.mul(two, q);
        let b = g.mul(two, q);
        assert_eq!(a, b);
        let one = g.constant(1.0);
        assert_eq!(g.mul(q, one), q);
        let zero = g.constant(0.0);
        assert_eq!(g.as_const(g.clone().mul(q, zero)), Some(0.0));
        let three = g.constant(3.0);
        let six = g.mul(two, three);
        assert_eq!(g.as_const(six), Some(6.0));
        let n = g.neg(q);
        assert_eq!(g.neg(n), q);
    }

    #[test]
    fn powi_is_a_left_to_right_product() {
        let x = 1.1_f64;
        assert_eq!(Graph::apply_powi(x, 3).to_bits(), (x * x * x).to_bits());
        assert_eq!(
            Graph::apply_powi(x, -2).to_bits(),
            (1.0 / (x * x)).to_bits()
        );
        assert_eq!(Graph::apply_powi(x, 0), 1.0);
    }

    #[test]
    fn max_min_propagate_nan() {
        assert!(Graph::apply_binary(Binary::Max, f64::NAN, 1.0).is_nan());
        assert!(Graph::apply_binary(Binary::Min, 1.0, f64::NAN).is_nan());
        assert_eq!(Graph::apply_binary(Binary::Max, 0.0, -1.0), 0.0);
    }
}
