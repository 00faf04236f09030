//! The syntax tree of an expression, with source spans for messages.
//!
//! Chains of `+ -` and of `* /` are kept as one n-ary node ([`ExprKind::Chain`]) rather than
//! a left-deep tree of binary nodes: the tree's depth then grows only with parentheses, calls
//! and prefix operators (which the parser limits), never with the number of terms, so the
//! later recursive passes cannot overflow the stack on a long written-out sum.

use crate::error::Span;
use crate::graph::Cmp;

/// A node of the syntax tree.
#[derive(Debug, Clone, PartialEq)]
pub struct Expr {
    pub kind: ExprKind,
    /// The source text of the whole subexpression (without enclosing parentheses).
    pub span: Span,
}

/// Left-associative arithmetic operators of a [`ExprKind::Chain`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum BinOp {
    Add,
    Sub,
    Mul,
    Div,
}

impl BinOp {
    pub fn symbol(self) -> &'static str {
        match self {
            BinOp::Add => "+",
            BinOp::Sub => "-",
            BinOp::Mul => "*",
            BinOp::Div => "/",
        }
    }
}

#[derive(Debug, Clone, PartialEq)]
pub enum ExprKind {
    /// A numeric literal (always finite).
    Number(f64),
    /// A bare identifier: a numbered variable (`q3`), a scalar parameter, `N`, `pi` or a sum
    /// index; which one is decided when lowering.
    Name(String),
    /// `name[index]`, or `name[index, column]` on a square lattice (row `index`, column
    /// `column`): a variable of a family or an entry of an array parameter.
    Index {
        name: String,
        name_span: Span,
        index: Box<Expr>,
        column: Option<Box<Expr>>,
    },
    /// Unary minus (`op_span` is the `-`). A unary plus leaves no node.
    Neg { op_span: Span, arg: Box<Expr> },
    /// `first op1 x1 op2 x2 ...`, evaluated left to right: `((first op1 x1) op2 x2) ...`.
    /// All operators of one chain have the same precedence (`+ -` or `* /`).
    Chain {
        first: Box<Expr>,
        rest: Vec<(BinOp, Span, Expr)>,
    },
    /// `base ^ exp` (also written `**`); right-associative.
    Pow {
        op_span: Span,
        base: Box<Expr>,
        exp: Box<Expr>,
    },
    /// `name(args...)`: a built-in function, `if`, `piecewise` or a tabulated function.
    Call {
        name: String,
        name_span: Span,
        args: Vec<Expr>,
    },
    /// `lhs < rhs` etc.; only meaningful as the condition of `if` or `piecewise`.
    Compare {
        op: Cmp,
        op_span: Span,
        lhs: Box<Expr>,
        rhs: Box<Expr>,
    },
    /// `sum(index = from..to, body)`, bounds inclusive.
    Sum {
        index: String,
        index_span: Span,
        from: Box<Expr>,
        to: Box<Expr>,
        body: Box<Expr>,
    },
}

/// Fixed children, call arguments, chain operands.
type Parts<'e> = ([Option<&'e Expr>; 3], &'e [Expr], &'e [(BinOp, Span, Expr)]);

impl Expr {
    /// Every name the expression reads: bare names (variables, scalar parameters, `N`, `pi`,
    /// sum indices) and the names of indexed families and array parameters (`a` of `a[i]`);
    /// not the names of called functions. What tells a parameter no expression uses.
    pub fn names(&self) -> std::collections::BTreeSet<&str> {
        let mut names = std::collections::BTreeSet::new();
        let mut stack = vec![self];
        while let Some(e) = stack.pop() {
            match &e.kind {
                ExprKind::Name(name) | ExprKind::Index { name, .. } => {
                    names.insert(name.as_str());
                }
                _ => {}
            }
            stack.extend(e.children());
        }
        names
    }

    /// The direct subexpressions, in source order (no allocation: passes over a lattice sum's
    /// body run once per term).
    pub fn children(&self) -> impl Iterator<Item = &Expr> {
        let none: [Option<&Expr>; 3] = [None; 3];
        let (fixed, args, chain): Parts<'_> = match &self.kind {
            ExprKind::Number(_) | ExprKind::Name(_) => (none, &[], &[]),
            ExprKind::Index { index, column, .. } => {
                ([Some(index), column.as_deref(), None], &[], &[])
            }
            ExprKind::Neg { arg: x, .. } => ([Some(x), None, None], &[], &[]),
            ExprKind::Chain { first, rest } => ([Some(first), None, None], &[], rest),
            ExprKind::Pow { base, exp, .. } => ([Some(base), Some(exp), None], &[], &[]),
            ExprKind::Call { args, .. } => (none, args, &[]),
            ExprKind::Compare { lhs, rhs, .. } => ([Some(lhs), Some(rhs), None], &[], &[]),
            ExprKind::Sum { from, to, body, .. } => ([Some(from), Some(to), Some(body)], &[], &[]),
        };
        fixed
            .into_iter()
            .flatten()
            .chain(args.iter())
            .chain(chain.iter().map(|(_, _, x)| x))
    }
}

#[cfg(test)]
mod tests {
    #[test]
    fn names_are_every_name_read_but_no_function() {
        let e =
            crate::parser::parse("a * sin(x1) + sum(i = 1..N, w[i] * q[i]^2) - exp(b)").unwrap();
        let names: Vec<&str> = e.names().into_iter().collect();
        assert_eq!(names, ["N", "a", "b", "i", "q", "w", "x1"]);
    }
}
