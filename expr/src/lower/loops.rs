//! Lattice sums lowered as loops ([`crate::lattice`]): the body of `sum(i = a..b, term)` lowered
//! once with its sites `q[i + k]` and array parameters `eps[i + k]` as slot inputs.
//!
//! A sum is lowered this way when its body reads the variables and array parameters only as
//! `name[i + k]`, or on a square as `name[r, i + k]` with the row `r` a number in the term (a
//! whole shift `k`; the index `i` nowhere else, not as a number), has no sum
//! of its own under free ends (whose terms would be left out site by site), reads array
//! parameters only inside the lattice under fixed ends, and has at most
//! [`MAX_BOUNDARY_TERMS`] terms reaching beyond an end. Anything else, including every error,
//! makes the sum unrolled site by site, and the unrolled lowering reports the error: the loop
//! form never changes what is accepted, only how it is lowered.

use std::sync::Arc;

use super::{Info, Lowerer, Meaning, R};
use crate::ast::{BinOp, Expr, ExprKind};
use crate::error::Span;
use crate::graph::{Node, NodeId};
use crate::lattice::{
    ARG_SITE, ARG_SITE_PARAM, ARG_SUM, MAX_BOUNDARY_TERMS, ParamSlot, SiteSum, split_shift,
};
use crate::lower::{Boundary, ParamValue, Shape};
use crate::smooth::Signs;

/// The sum whose body is being lowered as a term: its index and the slots met so far.
pub(super) struct Template<'a> {
    pub index: &'a str,
    pub variables: Vec<i64>,
    pub params: Vec<ParamSlot>,
    /// A slot reads a row beyond a free edge of a square: every term is left out.
    pub left_out: bool,
    /// The column offsets of the walls the term reads (rows beyond a fixed edge of a square):
    /// no slots, but past a free column edge they leave the term out as a slot would.
    pub wall_steps: Vec<i64>,
}

impl<'a> Lowerer<'a> {
    /// Whether `name` is the index of the sum being lowered as a term.
    pub(super) fn is_loop_index(&self, name: &str) -> bool {
        self.template.as_ref().is_some_and(|t| t.index == name)
    }

    /// The refusal of the loop form (never shown: the sum is then lowered unrolled).
    pub(super) fn not_a_loop(&self, span: Span) -> Box<crate::error::ExprError> {
        self.err(span, "not a site loop")
    }

    /// `index` as `c * i + k` in the loop index `i`.
    fn affine(&self, e: &Expr, index: &str) -> R<(i64, i64)> {
        self.tick(e.span)?;
        let overflow = || self.not_a_loop(e.span);
        match &e.kind {
            ExprKind::Name(n) if n == index => Ok((1, 0)),
            ExprKind::Neg { arg, .. } => {
                let (c, k) = self.affine(arg, index)?;
                Ok((
                    c.checked_neg().ok_or_else(overflow)?,
                    k.checked_neg().ok_or_else(overflow)?,
                ))
            }
            ExprKind::Chain { first, rest } => {
                let (mut c, mut k) = self.affine(first, index)?;
                for (op, _, x) in rest {
                    let (c2, k2) = self.affine(x, index)?;
                    let next = match op {
                        BinOp::Add => c.checked_add(c2).zip(k.checked_add(k2)),
                        BinOp::Sub => c.checked_sub(c2).zip(k.checked_sub(k2)),
                        BinOp::Mul if c == 0 => k.checked_mul(c2).zip(k.checked_mul(k2)),
                        BinOp::Mul if c2 == 0 => c.checked_mul(k2).zip(k.checked_mul(k2)),
                        _ => return Err(self.not_a_loop(e.span)),
                    };
                    (c, k) = next.ok_or_else(overflow)?;
                }
                Ok((c, k))
            }
            // No loop index inside: an ordinary index expression (whose errors are the
            // unrolled lowering's to report).
            _ if !mentions(e, index) => Ok((0, self.int(e)?)),
            _ => Err(self.not_a_loop(e.span)),
        }
    }

    /// `name[index]` in a term where `index` mentions the loop index: a slot input.
    pub(super) fn slot(&mut self, e: &'a Expr, name: &str, index: &'a Expr) -> R<(NodeId, Info)> {
        if self.scope.shape != Shape::Chain {
            // On a square a single index names a site with no boundary: unrolled.
            return Err(self.not_a_loop(e.span));
        }
        let loop_index = self.template.as_ref().map_or("", |t| t.index);
        let (c, shift) = self.affine(index, loop_index)?;
        if c != 1 {
            return Err(self.not_a_loop(e.span));
        }
        self.slot_at(e, name, shift)
    }

    /// `name[row, column]` on a square lattice in a term whose column mentions the loop index
    /// (the loop runs along a row) and whose row does not (a number in this term of the
    /// enclosing sum): a slot input with the shift `r L + d` of [`crate::lattice::SiteSum`].
    pub(super) fn square_slot(
        &mut self,
        e: &'a Expr,
        name: &str,
        row: &'a Expr,
        column: &'a Expr,
    ) -> R<(NodeId, Info)> {
        let loop_index = self.template.as_ref().map_or("", |t| t.index);
        let Shape::Square { .. } = self.scope.shape else {
            return Err(self.not_a_loop(e.span));
        };
        if mentions(row, loop_index) {
            return Err(self.not_a_loop(e.span));
        }
        let (c, d) = self.affine(column, loop_index)?;
        let side = self.scope.n as i64;
        // The column offset must be told apart from a step to another row (`split_shift`).
        if c != 1 || d.unsigned_abs().saturating_mul(2) >= side as u64 {
            return Err(self.not_a_loop(e.span));
        }
        let is_family = matches!(self.meaning(name), Meaning::Family(_));
        let r = self.int(row)?;
        let r = if (1..=side).contains(&r) {
            r - 1
        } else {
            match self.scope.boundary {
                Boundary::Periodic => r
                    .checked_sub(1)
                    .ok_or_else(|| self.not_a_loop(e.span))?
                    .rem_euclid(side),
                // A wall along the rows, in every term.
                Boundary::Fixed if is_family => {
                    self.template
                        .as_mut()
                        .expect("in a term")
                        .wall_steps
                        .push(d);
                    return self.constant(0.0, e.span);
                }
                // A row beyond a free edge: every term of this sum is left out.
                Boundary::Free if is_family => {
                    self.template.as_mut().expect("in a term").left_out = true;
                    return self.constant(0.0, e.span);
                }
                // Parameters beyond an edge are an error, which the unrolled lowering reports.
                _ => return Err(self.not_a_loop(e.span)),
            }
        };
        self.slot_at(e, name, r * side + d)
    }

    /// The slot input of `name` at `shift` (a variable or array-parameter slot of the term).
    fn slot_at(&mut self, e: &'a Expr, name: &str, shift: i64) -> R<(NodeId, Info)> {
        let sites = self.scope.shape.sites(self.scope.n);
        match self.meaning(name) {
            Meaning::Family(f) if Some(f.len) == sites && f.offset == 0 => {
                let t = self.template.as_mut().expect("in a term");
                let s = match t.variables.iter().position(|&k| k == shift) {
                    Some(s) => s,
                    None => {
                        t.variables.push(shift);
                        t.variables.len() - 1
                    }
                };
                let node = Node::Input {
                    arg: ARG_SITE,
                    index: s as u32,
                };
                Ok((self.emit(node, e.span)?, Info::variable()))
            }
            Meaning::Param(ParamValue::Array(v)) if Some(v.len()) == sites => {
                // A known constant in every term: its signs are those of the entries.
                let signs = v
                    .iter()
                    .fold(None, |acc: Option<Signs>, &x| {
                        let s = Signs::of(x);
                        Some(acc.map_or(s, |a| a.union(s)))
                    })
                    .unwrap_or(Signs::ALL);
                let t = self.template.as_mut().expect("in a term");
                let p = match t
                    .params
                    .iter()
                    .position(|p| p.name == name && p.shift == shift)
                {
                    Some(p) => p,
                    None => {
                        t.params.push(ParamSlot {
                            name: name.to_string(),
                            values: Arc::from(v.as_slice()),
                            shift,
                        });
                        t.params.len() - 1
                    }
                };
                let node = Node::Input {
                    arg: ARG_SITE_PARAM,
                    index: p as u32,
                };
                // A per-site parameter: constant along every orbit.
                let info = Info {
                    limit: None,
                    signs,
                    zero_kink: false,
                    vanishing: true,
                    pole_free: true,
                    varies: false,
                    absorbed: None,
                };
                Ok((self.emit(node, e.span)?, info))
            }
            _ => Err(self.not_a_loop(e.span)),
        }
    }

    /// `sum(index = a..b, body)` as a loop, or `None` to lower it unrolled.
    pub(super) fn sum_as_loop(
        &mut self,
        e: &'a Expr,
        index: &'a str,
        (a, b): (i64, i64),
        body: &'a Expr,
    ) -> R<Option<(NodeId, Info)>> {
        if !self.loops || self.template.is_some() || a > b {
            return Ok(None);
        }
        if matches!(body.kind, ExprKind::Sum { .. }) {
            // Each term of a directly nested sum is a part of the energy distribution
            // (`Lowered::parts`), where a loop's term would be one part shared by all its
            // sites: this sum is unrolled, and the nested sums may be loops.
            return Ok(None);
        }
        self.template = Some(Template {
            index,
            variables: Vec::new(),
            params: Vec::new(),
            left_out: false,
            wall_steps: Vec::new(),
        });
        // The loop index stands in the scope as a name (so it is not "unknown"); every use
        // of it outside a slot's index refuses the loop form.
        let depth = self.sums.len();
        self.sums.push((index, 0));
        let lowered = self.value(body);
        // An error leaves the indices of the sums it came through (see `Lowerer::sum`).
        self.sums.truncate(depth);
        let template = self.template.take().expect("set above");
        let Ok((term, info)) = lowered else {
            return Ok(None);
        };
        if template.left_out {
            // Every term reads a row beyond a free edge: the unrolled sum has no term.
            return self.constant(0.0, e.span).map(Some);
        }
        if self.graph.as_const(term).is_some() {
            // The same term at every site: the unrolled sum folds to one constant.
            return Ok(None);
        }
        // Along the loop: a chain, or on a square the columns of one row.
        let (side, boundary) = match self.scope.shape {
            Shape::Chain => (None, self.scope.boundary),
            Shape::Square { columns } => (Some(self.scope.n), columns),
        };
        let n = self.scope.n as i64;
        let step = |s: i64| side.map_or(s, |side| split_shift(s, side).1);
        let steps = || {
            template
                .variables
                .iter()
                .copied()
                .chain(template.params.iter().map(|p| p.shift))
                .map(step)
        };
        // Past a free edge a wall's column leaves the term out too (`Lowerer::term_exists`).
        let reach = || steps().chain(template.wall_steps.iter().copied());
        let lo = reach().min().unwrap_or(0);
        let hi = reach().max().unwrap_or(0);
        let (first, last) = match boundary {
            Boundary::Free => (a.max(1 - lo), b.min(n - hi)),
            Boundary::Periodic if n == 0 => return Ok(None),
            Boundary::Periodic => (a, b),
            Boundary::Fixed => {
                let inside = template
                    .params
                    .iter()
                    .all(|p| a + step(p.shift) >= 1 && b + step(p.shift) <= n);
                if !inside {
                    return Ok(None);
                }
                (a, b)
            }
        };
        if first > last {
            return self.constant(0.0, e.span).map(Some);
        }
        let sum = SiteSum {
            span: e.span,
            first,
            last,
            variables: template.variables,
            params: template.params,
            term,
            n: self.scope.shape.sites(self.scope.n).unwrap_or(0),
            boundary,
            side,
        };
        let (before, after) = sum.boundary_terms();
        if (before.len() + after.len()) as i64 > MAX_BOUNDARY_TERMS {
            return Ok(None);
        }
        let s = self.site_sums.len() as u32;
        self.site_sums.push(sum);
        let id = self.emit(
            Node::Input {
                arg: ARG_SUM,
                index: s,
            },
            e.span,
        )?;
        // Every term has the facts of the one lowered (a constant term gives a constant
        // sum only in the unrolled form, where it folds; here it is a sum of unknown sign).
        let info = if first == last { info } else { info.add(info) };
        Ok(Some((id, info)))
    }
}

/// Whether `e` mentions the name `index` anywhere.
pub(super) fn mentions(e: &Expr, index: &str) -> bool {
    match &e.kind {
        ExprKind::Name(n) => n == index,
        _ => e.children().any(|c| mentions(c, index)),
    }
}
