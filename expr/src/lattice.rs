//! Lattice sums as loops: a `sum(i = a..b, term)` over sites kept as one *term* (the body
//! lowered once, with the sites it reads as inputs) and its index range, instead of `b - a + 1`
//! copies of the term; and the potential, gradient and Hessian-vector product of a potential
//! made of such sums, with the one definition of their operation order.
//!
//! # What a site sum is
//!
//! [`crate::lower::lower_with_loops`] lowers a sum whose body reads the variables and array
//! parameters only at `name[i + k]` (any whole shift `k`, the same index `i`) as a [`SiteSum`]:
//! its term is a graph expression whose inputs are the term's *slots*, variable slot `s` the
//! value of `q[i + shift_s]` (`Input { arg: ARG_SITE, index: s }`) and parameter slot `p` the
//! value of `eps[i + shift_p]` (`ARG_SITE_PARAM`); the expression around the sums reads sum
//! `s`'s value as `Input { arg: ARG_SUM, index: s }`. The boundary condition decides what a
//! slot reads at a site beyond the ends ([`SiteSum::site`]): a wall (`0`) with fixed ends, the
//! wrapped site with periodic ones; with free ends the range holds only the terms whose slots
//! are all inside. Compile time and code size are those of one term, whatever `N` is.
//!
//! On a square lattice of side `L` the loops run along rows: in `sum(i, sum(j, term))` the outer
//! sum is unrolled, so each row's `i` is a number, and the inner sum is a loop whose slots read
//! `q[r, j + d]` for rows `r` fixed in that row's term (a row beyond an edge already wrapped,
//! walled or left out). A slot's shift is `(r - 1) L + d` with `2 |d| < L`, so inside the row
//! a slot reads site `j + shift` as on a chain and [`SiteSum::site`] applies the columns'
//! boundary at the row's ends. Code size grows with `L` (a loop per row and sum), not `L^2`;
//! the rows inside share one term in the graph.
//!
//! # The order of operations (what the compiled loops and [`LatticePotential`]'s reference
//! evaluation both do)
//!
//! - The value of a sum is its terms added left to right in increasing `i` (as the unrolled
//!   lowering's left fold: the accumulator starts at `-0`, and `-0 + t = t` exactly).
//! - The gradient `g` starts at `-0` in every site. First the expression around the sums adds
//!   its own derivatives (`g_j += dV_rest/dq_j`, for the sites where that is not the constant
//!   `0`, in increasing `j`); then every sum in turn, term by term in increasing `i`, adds the
//!   term's derivative with respect to each variable slot, in slot order, to the slot's site
//!   (`g_j += d_s`; `g_j -= d_s` when the sum enters the potential with the coefficient `-1`,
//!   `g_j += c d_s` with any other constant `c`; a derivative `-x` is `x` subtracted, see
//!   [`SumDerivatives::contributions`]). A slot at a wall adds nothing.
//! - The Hessian-vector product likewise, with the term's derivative along the direction's
//!   slots (forward mode over the term's gradient) in place of `d_s`.
//!
//! So a site's force is its contributions summed in the order of the terms, which for a chain
//! of bonds is the hand-written `f(r_{j-1}) - f(r_j)`, bit for bit the unrolled lowering's. A
//! site with more than two contributions (several sums, longer-range couplings) may sum them in
//! another order than the unrolled lowering, whose gradient orders a site's terms by node
//! number: the results then agree to rounding.
//!
//! A potential is written with loops only where it is affine in its sums (`sum(...) + q1^2`,
//! `-sum(...)`, `0.5 * sum(...)`; not `sum(...)^2`, whose Hessian couples every pair of sites);
//! [`LatticePotential::new`] says `None` otherwise and the caller lowers it unrolled.

use std::sync::Arc;

use crate::diff::{self, DiffError};
use crate::error::Span;
use crate::eval::{Evaluator, Needed};
use crate::graph::{Binary, Graph, Node, NodeId, Unary};
use crate::lower::Boundary;

/// Argument of a term's variable slots: `Input { arg: ARG_SITE, index: s }` is `q[i + shift_s]`.
pub const ARG_SITE: u8 = 2;
/// Argument of a term's direction slots in its Hessian-vector product: `v[i + shift_s]`.
pub const ARG_SITE_DIRECTION: u8 = 3;
/// Argument of a term's array-parameter slots: `eps[i + shift_p]`.
pub const ARG_SITE_PARAM: u8 = 4;
/// Argument of the sums' values in the expression around them.
pub const ARG_SUM: u8 = 5;
/// Arguments of the potential's own variables and direction, below the slots' arguments.
pub const ARG_Q: u8 = 0;
pub const ARG_V: u8 = 1;

/// Largest number of terms of a sum that read a site beyond an end (the boundary terms, which
/// the compiled code writes out one by one beside the loop over the interior); a sum with more
/// (a range far beyond the lattice) is lowered unrolled.
pub const MAX_BOUNDARY_TERMS: i64 = 32;

/// An array parameter read by a term at `name[i + shift]`.
#[derive(Debug, Clone, PartialEq)]
pub struct ParamSlot {
    pub name: String,
    pub values: Arc<[f64]>,
    pub shift: i64,
}

/// One lattice sum lowered as a loop (see the module documentation).
#[derive(Debug, Clone, PartialEq)]
pub struct SiteSum {
    /// The `sum(...)` in the source.
    pub span: Span,
    /// The terms `first..=last` (not empty; with free ends only the terms whose slots are all
    /// inside `1..=N`).
    pub first: i64,
    pub last: i64,
    /// Variable slot `s` reads `q[i + variables[s]]` (1-based site).
    pub variables: Vec<i64>,
    pub params: Vec<ParamSlot>,
    /// The term, reading its slots ([`ARG_SITE`], [`ARG_SITE_PARAM`]) and constants.
    pub term: NodeId,
    /// The number of sites.
    pub n: usize,
    /// The boundary along the loop: the chain's, or on a square the columns'.
    pub boundary: Boundary,
    /// On a square lattice, its side: the sum runs along one row's columns (see [`Self::site`]).
    pub side: Option<usize>,
}

impl SiteSum {
    /// The 0-based site a slot with `shift` reads in term `i`, `None` for a wall.
    ///
    /// On a square lattice of side `L` the sum runs along the columns `j = i` of rows fixed
    /// when it was lowered (the rows' index is a number in each of the enclosing sum's terms):
    /// a slot reading row `r` (0-based, inside the lattice: a row beyond an edge was wrapped,
    /// walled or left out then) and column `j + d` has the shift `r L + d`, `2 |d| < L`, so that
    /// inside the row the site is `i + shift` as on a chain, and beyond a column edge the
    /// columns' boundary applies within the row.
    pub fn site(&self, i: i64, shift: i64) -> Option<usize> {
        let (len, k, row) = match self.side {
            None => (self.n as i64, i + shift, 0),
            Some(side) => {
                let (row, d) = split_shift(shift, side);
                (side as i64, i + d, row * side as i64)
            }
        };
        if (1..=len).contains(&k) {
            return Some((row + k - 1) as usize);
        }
        match self.boundary {
            Boundary::Periodic => Some((row + (k - 1).rem_euclid(len)) as usize),
            // Free ends: the range holds no term reading beyond an end.
            Boundary::Fixed | Boundary::Free => None,
        }
    }

    /// The least and greatest step along the loop of the slots (variables and parameters):
    /// the shifts on a chain, the column offsets `d` on a square.
    pub fn reach(&self) -> (i64, i64) {
        let steps = self
            .variables
            .iter()
            .copied()
            .chain(self.params.iter().map(|p| p.shift))
            .map(|s| self.side.map_or(s, |side| split_shift(s, side).1));
        steps.fold((0i64, 0i64), |(lo, hi), s| (lo.min(s), hi.max(s)))
    }

    /// The terms whose slots all read sites inside the lattice (the loop over the interior),
    /// `None` when there is none.
    pub fn interior(&self) -> Option<(i64, i64)> {
        let (lo, hi) = self.reach();
        let len = self.side.unwrap_or(self.n) as i64;
        let from = self.first.max(1 - lo);
        let to = self.last.min(len - hi);
        (from <= to).then_some((from, to))
    }

    /// The terms outside [`Self::interior`], in increasing `i`: before and after it.
    pub fn boundary_terms(&self) -> (Vec<i64>, Vec<i64>) {
        match self.interior() {
            Some((a, b)) => ((self.first..a).collect(), (b + 1..=self.last).collect()),
            None => ((self.first..=self.last).collect(), Vec::new()),
        }
    }

    /// The values of the parameter slots in term `i` (fixed ends: always inside, checked when
    /// lowering; periodic: wrapped; free: the range keeps them inside).
    fn param_values(&self, i: i64, out: &mut Vec<f64>) {
        out.clear();
        for p in &self.params {
            let j = self
                .site(i, p.shift)
                .expect("parameter slots read inside the lattice");
            out.push(p.values[j]);
        }
    }
}

/// A square lattice's shift `r L + d` (see [`SiteSum::site`]) as its row `r` and column offset
/// `d`, `2 |d| < L`.
pub fn split_shift(shift: i64, side: usize) -> (i64, i64) {
    let side = side as i64;
    let d = (shift + (side - 1) / 2).rem_euclid(side) - (side - 1) / 2;
    ((shift - d) / side, d)
}

/// A sum's derivatives, per variable slot.
#[derive(Debug, Clone, PartialEq)]
pub struct SumDerivatives {
    /// `dV / dS`: how the sum enters the potential (a constant: `1`, `-1`, ...).
    pub coefficient: f64,
    /// `d term / d slot s`.
    pub gradient: Vec<NodeId>,
    /// `sum_r (d^2 term / d slot s d slot r) v_r`, reading [`ARG_SITE_DIRECTION`] (see
    /// [`term_hessian_vector`]); `None` without second derivatives.
    pub hessian_vector: Option<Vec<NodeId>>,
}

impl SumDerivatives {
    /// What each slot adds to its site (the gradient's, or with `hessian` the Hessian-vector
    /// product's): `(factor, node)`, the contribution being `factor * value(node)`, added by
    /// [`accumulate`]. A derivative `-x` (the bond's far end, say) is `(-coefficient, x)`:
    /// subtracted, as the unrolled gradient writes it, with no negation of its own.
    pub fn contributions(&self, graph: &Graph, hessian: bool) -> Vec<(f64, NodeId)> {
        let nodes = if hessian {
            self.hessian_vector
                .as_deref()
                .expect("the Hessian-vector product was derived")
        } else {
            &self.gradient
        };
        nodes
            .iter()
            .map(|&id| match *graph.node(id) {
                Node::Unary(Unary::Neg, x) => (-self.coefficient, x),
                _ => (self.coefficient, id),
            })
            .collect()
    }
}

/// How a contribution `d` (times the slot's factor `c`) is added to a site's accumulator:
/// `acc + d`, `acc - d`, or `acc + c * d`. The one definition the compiled code follows.
#[inline]
pub fn accumulate(c: f64, acc: f64, d: f64) -> f64 {
    if c == 1.0 {
        acc + d
    } else if c == -1.0 {
        acc - d
    } else {
        acc + c * d
    }
}

/// A potential made of site sums and an expression around them (the *rest*), with its
/// gradient and Hessian-vector product in loop form.
#[derive(Debug, Clone)]
pub struct LatticePotential {
    pub n: usize,
    /// The potential: reads `q` ([`ARG_Q`]) and the sums ([`ARG_SUM`]).
    pub root: NodeId,
    pub sums: Vec<SiteSum>,
    pub derivatives: Vec<SumDerivatives>,
    /// The rest's gradient where it is not the constant 0: (0-based site, node).
    pub rest_gradient: Vec<(u32, NodeId)>,
    /// The rest's Hessian-vector product (reading [`ARG_V`]) where it is not the constant 0;
    /// `None` without second derivatives.
    pub rest_hessian_vector: Option<Vec<(u32, NodeId)>>,
}

fn nonzero(graph: &Graph, nodes: Vec<NodeId>) -> Vec<(u32, NodeId)> {
    nodes
        .into_iter()
        .enumerate()
        .filter(|&(_, id)| !matches!(graph.node(id), Node::Const(c) if c.to_bits() == 0))
        .map(|(j, id)| (j as u32, id))
        .collect()
}

/// Whether each node (up to the largest of `outputs`) is a linear combination of a term's
/// variable slots with constant coefficients (a slot, a sum or difference of such, a constant
/// multiple or fraction of one): `q[i+1] - q[i]`, say.
fn linear_in_slots(graph: &Graph, len: usize) -> Vec<bool> {
    let mut linear = vec![false; len];
    for v in 0..len {
        let lin = |x: NodeId| linear[x as usize];
        let constant = |x: NodeId| graph.as_const(x).is_some();
        linear[v] = match *graph.node(v as NodeId) {
            Node::Input { arg: ARG_SITE, .. } => true,
            Node::Unary(Unary::Neg, a) => lin(a),
            Node::Binary(Binary::Add | Binary::Sub, a, b) => {
                (lin(a) || constant(a)) && (lin(b) || constant(b)) && (lin(a) || lin(b))
            }
            Node::Binary(Binary::Mul, a, b) => (lin(a) && constant(b)) || (constant(a) && lin(b)),
            Node::Binary(Binary::Div, a, b) => lin(a) && constant(b),
            _ => false,
        };
    }
    linear
}

/// A term's Hessian-vector product per slot, from its gradient `gradient` (per slot), in the
/// factored form a hand-written one has: the *cuts* are the linear combinations of slots that
/// something non-linear reads (a chain's bond `r = q[i+1] - q[i]`), or that are themselves a
/// slot's derivative; each slot's `sum_c (d gradient / d cut_c) t_c` with `t_c` the cut's
/// direction (`v[i+1] - v[i]`), so a bond's product is `f'(r) (v[i+1] - v[i])`, formed once
/// for both its ends (`d / d cut` of a derivative `-x` is written `-(d x / d cut)`, and the
/// product with it `-(f' t)`: the same product, subtracted).
fn term_hessian_vector(graph: &mut Graph, gradient: &[NodeId]) -> Result<Vec<NodeId>, DiffError> {
    let mut need = Vec::new();
    crate::eval::mark_needed(graph, gradient, &mut need);
    let linear = linear_in_slots(graph, need.len());
    let mut cut = vec![false; need.len()];
    for v in 0..need.len() {
        if !need[v] {
            continue;
        }
        if !linear[v] {
            for o in graph.node(v as NodeId).operands() {
                if linear[o as usize] {
                    cut[o as usize] = true;
                }
            }
        }
    }
    for &o in gradient {
        if linear[o as usize] {
            cut[o as usize] = true;
        }
    }
    let cuts: Vec<NodeId> = (0..need.len() as NodeId)
        .filter(|&v| cut[v as usize])
        .collect();
    let tangents = diff::directional(graph, &cuts, ARG_SITE, ARG_SITE_DIRECTION)?;
    let partials = diff::partials_at(graph, gradient, &cuts)?;
    let mut out = Vec::with_capacity(gradient.len());
    for row in partials {
        let mut acc: Option<NodeId> = None;
        for (&k, &t) in row.iter().zip(&tangents) {
            if graph.as_const(k) == Some(0.0) {
                continue;
            }
            // `-x` times t as `-(x t)`: one product shared by the ends of a bond.
            let term = match *graph.node(k) {
                Node::Unary(Unary::Neg, x) => {
                    let p = graph.mul(x, t);
                    graph.neg(p)
                }
                _ => graph.mul(k, t),
            };
            acc = Some(match acc {
                None => term,
                Some(a) => match *graph.node(term) {
                    Node::Unary(Unary::Neg, x) => graph.sub(a, x),
                    _ => graph.add2(a, term),
                },
            });
        }
        out.push(acc.unwrap_or_else(|| graph.constant(0.0)));
    }
    Ok(out)
}

impl LatticePotential {
    /// Differentiates the potential `root` (lowered by [`crate::lower::lower_with_loops`] with
    /// its `sums`): the rest by reverse accumulation over `q`, each term by reverse
    /// accumulation over its slots, and with `hessian` their Hessian-vector products (the
    /// rest's as [`diff::jacobian_vector`], a term's in the factored form of
    /// [`term_hessian_vector`]). `None` when the potential is not affine in its sums (some `dV/dS` is not a
    /// constant): the caller lowers it unrolled.
    pub fn new(
        graph: &mut Graph,
        root: NodeId,
        sums: Vec<SiteSum>,
        n: usize,
        hessian: bool,
    ) -> Result<Option<Self>, DiffError> {
        // `n` is the number of sites (a square's `N^2`), which the sums index.
        assert!(
            sums.iter().all(|s| s.n == n),
            "lattice sums over {:?} sites in a potential of {n}",
            sums.iter().map(|s| s.n).collect::<Vec<_>>()
        );
        let adjoints = diff::gradient(graph, root, ARG_SUM, sums.len())?;
        let mut coefficients = Vec::with_capacity(sums.len());
        for &a in &adjoints {
            match graph.as_const(a) {
                Some(c) if c.is_finite() => coefficients.push(c),
                _ => return Ok(None),
            }
        }
        let rest = diff::gradient(graph, root, ARG_Q, n)?;
        let rest_hessian_vector = if hessian {
            let hv = diff::jacobian_vector(graph, &rest, ARG_Q, ARG_V)?;
            Some(nonzero(graph, hv))
        } else {
            None
        };
        let rest_gradient = nonzero(graph, rest);
        let mut derivatives = Vec::with_capacity(sums.len());
        for (sum, coefficient) in sums.iter().zip(coefficients) {
            let gradient = diff::gradient(graph, sum.term, ARG_SITE, sum.variables.len())?;
            let hessian_vector = if hessian {
                Some(term_hessian_vector(graph, &gradient)?)
            } else {
                None
            };
            derivatives.push(SumDerivatives {
                coefficient,
                gradient,
                hessian_vector,
            });
        }
        Ok(Some(Self {
            n,
            root,
            sums,
            derivatives,
            rest_gradient,
            rest_hessian_vector,
        }))
    }

    /// Whether the Hessian-vector product was derived.
    pub fn has_hessian(&self) -> bool {
        self.rest_hessian_vector.is_some()
    }

    /// Terms of every sum (the loop iterations of one evaluation).
    pub fn terms(&self) -> u64 {
        self.sums
            .iter()
            .map(|s| (s.last - s.first + 1) as u64)
            .sum()
    }
}

/// The reference evaluation of a [`LatticePotential`]: the operations of the compiled loops, in
/// their order, by the graph's evaluator (what the compiled code is tested against bit for bit,
/// and what names the operation that produced a non-finite value).
#[derive(Debug)]
pub struct LatticeEvaluator<'a> {
    graph: &'a Graph,
    lattice: &'a LatticePotential,
    ev: Evaluator,
    /// The marks of every set of outputs a term was evaluated for: the graph is borrowed for
    /// the evaluator's life, so they stay valid, and a sum's term is evaluated at every site.
    needed: Vec<Needed>,
    window: Vec<f64>,
    direction: Vec<f64>,
    params: Vec<f64>,
    values: Vec<f64>,
}

impl<'a> LatticeEvaluator<'a> {
    pub fn new(graph: &'a Graph, lattice: &'a LatticePotential) -> Self {
        Self {
            graph,
            lattice,
            ev: Evaluator::new(),
            needed: Vec::new(),
            window: Vec::new(),
            direction: Vec::new(),
            params: Vec::new(),
            values: Vec::new(),
        }
    }

    /// Fills the slots of term `i` of `sum` from `q` (and `v`, when given).
    fn load(&mut self, sum: &SiteSum, i: i64, q: &[f64], v: Option<&[f64]>) {
        self.window.clear();
        self.direction.clear();
        for &shift in &sum.variables {
            let j = sum.site(i, shift);
            self.window.push(j.map_or(0.0, |j| q[j]));
            if let Some(v) = v {
                self.direction.push(j.map_or(0.0, |j| v[j]));
            }
        }
        sum.param_values(i, &mut self.params);
    }

    /// `outputs` of term `i` of sum `s` at `q` (and `v`) into `self.values`.
    fn term(&mut self, s: usize, i: i64, q: &[f64], v: Option<&[f64]>, outputs: &[NodeId]) {
        let lattice = self.lattice;
        let sum = &lattice.sums[s];
        self.load(sum, i, q, v);
        self.values.resize(outputs.len(), 0.0);
        let args: [&[f64]; 5] = [
            q,
            v.unwrap_or(&[]),
            &self.window,
            &self.direction,
            &self.params,
        ];
        let at = match self.needed.iter().position(|n| n.outputs() == outputs) {
            Some(at) => at,
            None => {
                self.needed.push(Needed::of(self.graph, outputs));
                self.needed.len() - 1
            }
        };
        self.ev.eval_marked(
            self.graph,
            &self.needed[at],
            &args,
            outputs,
            &mut self.values,
        );
    }

    /// The argument arrays of term `i` of sum `s` at `q` (`q`, no direction, the slots, the
    /// parameter slots): what evaluates one of its nodes (to say what went wrong in it).
    pub fn term_args(&mut self, s: usize, i: i64, q: &[f64]) -> Vec<Vec<f64>> {
        let lattice = self.lattice;
        self.load(&lattice.sums[s], i, q, None);
        vec![
            q.to_vec(),
            Vec::new(),
            self.window.clone(),
            Vec::new(),
            self.params.clone(),
        ]
    }

    /// The value of each sum at `q`.
    pub fn sums(&mut self, q: &[f64]) -> Vec<f64> {
        let lattice = self.lattice;
        (0..lattice.sums.len())
            .map(|s| {
                let sum = &lattice.sums[s];
                let mut acc = -0.0;
                for i in sum.first..=sum.last {
                    self.term(s, i, q, None, &[sum.term]);
                    acc += self.values[0];
                }
                acc
            })
            .collect()
    }

    /// The potential at `q`.
    pub fn potential(&mut self, q: &[f64]) -> f64 {
        let sums = self.sums(q);
        let mut out = [0.0];
        let args: [&[f64]; 6] = [q, &[], &[], &[], &[], &sums];
        self.ev
            .eval(self.graph, &args, &[self.lattice.root], &mut out);
        out[0]
    }

    /// The potential energy of each site at `q` (`N` values into `out`), as the lattice
    /// literature defines the energy distribution (Flach, Krimer and Skokos 2009; Senyange,
    /// Many Manda and Skokos 2018): each term of a sum, times the sum's coefficient in `V`, is
    /// shared equally by the distinct sites its variable slots read (a wall is no site), so an
    /// on-site term goes whole to its site and a bond half to each end (whole to the one end
    /// of a bond to a fixed wall). The expression around the sums, where it is not zero, goes
    /// to the one site it reads (a pinned end, `q1^2/2`). The shares add up to `V` to rounding.
    ///
    /// An error saying why where no site can be named: a term (or the rest) that reads no
    /// site but is not zero (a constant), or a rest that reads several sites (which part is
    /// whose is not written down: write it as sums).
    pub fn site_potentials(&mut self, q: &[f64], out: &mut [f64]) -> Result<(), String> {
        let lattice = self.lattice;
        let n = lattice.n;
        assert!(q.len() >= n && out.len() >= n, "{n} sites");
        out[..n].fill(0.0);
        let mut sites: Vec<usize> = Vec::new();
        for (s, (sum, d)) in lattice.sums.iter().zip(&lattice.derivatives).enumerate() {
            for i in sum.first..=sum.last {
                self.term(s, i, q, None, &[sum.term]);
                let value = d.coefficient * self.values[0];
                sites.clear();
                sites.extend(sum.variables.iter().filter_map(|&k| sum.site(i, k)));
                sites.sort_unstable();
                sites.dedup();
                if sites.is_empty() {
                    if value != 0.0 {
                        return Err(format!(
                            "the term i = {i} of lattice sum {} reads no site but is {value}, \
                             which belongs to no site",
                            s + 1
                        ));
                    }
                    continue;
                }
                let share = value / sites.len() as f64;
                for &j in &sites {
                    out[j] += share;
                }
            }
        }
        // The rest: V with every sum at 0 (V is affine in its sums).
        let zeros = vec![0.0; lattice.sums.len()];
        let mut rest = [0.0];
        let args: [&[f64]; 6] = [q, &[], &[], &[], &[], &zeros];
        self.ev.eval(self.graph, &args, &[lattice.root], &mut rest);
        let rest = rest[0];
        if rest != 0.0 {
            match lattice.rest_gradient[..] {
                [(j, _)] => out[j as usize] += rest,
                [] => {
                    return Err(format!(
                        "V has a constant part {rest} outside its lattice sums, which belongs \
                         to no site"
                    ));
                }
                _ => {
                    let names: Vec<String> = lattice
                        .rest_gradient
                        .iter()
                        .map(|&(j, _)| format!("q{}", j + 1))
                        .collect();
                    return Err(format!(
                        "the part of V outside its lattice sums reads several sites ({}), so \
                         which share is whose is not written down: write it as lattice sums",
                        names.join(", ")
                    ));
                }
            }
        }
        Ok(())
    }

    /// `dV/dq` at `q` into `out` (`N` values).
    pub fn gradient(&mut self, q: &[f64], out: &mut [f64]) {
        self.accumulate(q, None, out);
    }

    /// `Hess V(q) v` into `out`.
    ///
    /// # Panics
    /// If the Hessian-vector product was not derived.
    pub fn hessian_vector(&mut self, q: &[f64], v: &[f64], out: &mut [f64]) {
        self.accumulate(q, Some(v), out);
    }

    fn accumulate(&mut self, q: &[f64], v: Option<&[f64]>, out: &mut [f64]) {
        let lattice = self.lattice;
        let n = lattice.n;
        assert!(q.len() >= n && out.len() >= n, "{n} sites");
        out[..n].fill(-0.0);
        let rest = match v {
            None => &lattice.rest_gradient,
            Some(_) => lattice
                .rest_hessian_vector
                .as_ref()
                .expect("the Hessian-vector product was derived"),
        };
        if !rest.is_empty() {
            let nodes: Vec<NodeId> = rest.iter().map(|&(_, id)| id).collect();
            let mut values = vec![0.0; nodes.len()];
            let args: [&[f64]; 2] = [q, v.unwrap_or(&[])];
            self.ev.eval(self.graph, &args, &nodes, &mut values);
            for (&(j, _), x) in rest.iter().zip(values) {
                out[j as usize] += x;
            }
        }
        for (s, (sum, d)) in lattice.sums.iter().zip(&lattice.derivatives).enumerate() {
            let contributions = d.contributions(self.graph, v.is_some());
            let outputs: Vec<NodeId> = contributions.iter().map(|&(_, id)| id).collect();
            for i in sum.first..=sum.last {
                self.term(s, i, q, v, &outputs);
                for (k, &shift) in sum.variables.iter().enumerate() {
                    if let Some(j) = sum.site(i, shift) {
                        out[j] = accumulate(contributions[k].0, out[j], self.values[k]);
                    }
                }
            }
        }
    }

    /// The first operation (in the order above) whose value is NaN or infinite while its
    /// operands are finite, in the potential or its gradient at `q`: the node, and the term
    /// (sum, index) it was met in, `None` for the rest.
    pub fn first_non_finite(&mut self, q: &[f64]) -> Option<(NodeId, Option<(usize, i64)>)> {
        let lattice = self.lattice;
        for (s, (sum, d)) in lattice.sums.iter().zip(&lattice.derivatives).enumerate() {
            for i in sum.first..=sum.last {
                self.load(sum, i, q, None);
                let args: [&[f64]; 5] = [q, &[], &self.window, &[], &self.params];
                for &root in std::iter::once(&sum.term).chain(&d.gradient) {
                    if let Some(id) = crate::eval::first_non_finite(self.graph, &args, root) {
                        return Some((id, Some((s, i))));
                    }
                }
            }
        }
        let sums = self.sums(q);
        let args: [&[f64]; 6] = [q, &[], &[], &[], &[], &sums];
        let roots = std::iter::once(lattice.root).chain(lattice.rest_gradient.iter().map(|r| r.1));
        for root in roots {
            if let Some(id) = crate::eval::first_non_finite(self.graph, &args, root) {
                return Some((id, None));
            }
        }
        None
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use std::collections::BTreeMap;

    use super::*;
    use crate::lower::{Family, ParamValue, Scope, Shape, lower, lower_with_loops};
    use crate::testing::{eval1, uniform01};

    /// A potential lowered both ways: unrolled (gradient by reverse accumulation, Hessian-vector
    /// product by `jacobian_vector`, as the model always did) and with loops.
    struct Both {
        n: usize,
        unrolled: Graph,
        root: NodeId,
        gradient: Vec<NodeId>,
        hessian_vector: Vec<NodeId>,
        looped: Graph,
        lattice: LatticePotential,
    }

    fn scope_parts(
        sites: usize,
        params: &[(&str, ParamValue)],
    ) -> (Vec<Family>, BTreeMap<String, ParamValue>) {
        let families = vec![Family {
            name: "q".into(),
            len: sites,
            arg: ARG_Q,
            offset: 0,
        }];
        let params = params
            .iter()
            .map(|(k, v)| (k.to_string(), v.clone()))
            .collect();
        (families, params)
    }

    /// The lattice potential (with its Hessian-vector product) of `src` on a lattice of side
    /// (or length) `side`, for the plans' tests.
    pub(crate) fn lattice_of(
        side: usize,
        boundary: Boundary,
        shape: Shape,
        params: &[(&str, ParamValue)],
        src: &str,
    ) -> LatticePotential {
        let (mut g, l) = lowered_shaped(side, boundary, shape, params, src);
        LatticePotential::new(&mut g, l.root, l.sums, shape.sites(side).unwrap(), true)
            .unwrap()
            .expect("affine in its sums")
    }

    fn lowered_with_loops(
        n: usize,
        boundary: Boundary,
        params: &[(&str, ParamValue)],
        src: &str,
    ) -> (Graph, crate::lower::Lowered) {
        lowered_shaped(n, boundary, Shape::Chain, params, src)
    }

    /// `f` of the scope of a lattice of side (or length) `n`, with `params`.
    fn in_scope<R>(
        n: usize,
        boundary: Boundary,
        shape: Shape,
        params: &[(&str, ParamValue)],
        f: impl FnOnce(&Scope) -> R,
    ) -> R {
        let (families, params) = scope_parts(shape.sites(n).unwrap(), params);
        f(&Scope {
            families: &families,
            params: &params,
            tables: &[],
            n,
            boundary,
            shape,
            time: None,
        })
    }

    fn lowered_shaped(
        n: usize,
        boundary: Boundary,
        shape: Shape,
        params: &[(&str, ParamValue)],
        src: &str,
    ) -> (Graph, crate::lower::Lowered) {
        in_scope(n, boundary, shape, params, |scope| {
            let mut g = Graph::new();
            let l = lower_with_loops(src, scope, &mut g).unwrap_or_else(|e| panic!("{e}"));
            (g, l)
        })
    }

    fn both(n: usize, boundary: Boundary, params: &[(&str, ParamValue)], src: &str) -> Both {
        both_shaped(n, boundary, Shape::Chain, params, src)
    }

    fn both_shaped(
        side: usize,
        boundary: Boundary,
        shape: Shape,
        params: &[(&str, ParamValue)],
        src: &str,
    ) -> Both {
        let n = shape.sites(side).unwrap();
        let mut unrolled = Graph::new();
        let root = in_scope(side, boundary, shape, params, |scope| {
            lower(src, scope, &mut unrolled).unwrap().root
        });
        let gradient = diff::gradient(&mut unrolled, root, ARG_Q, n).unwrap();
        let hessian_vector = diff::jacobian_vector(&mut unrolled, &gradient, ARG_Q, ARG_V).unwrap();
        let (mut looped, l) = lowered_shaped(side, boundary, shape, params, src);
        assert!(!l.sums.is_empty(), "{src}: no sum lowered as a loop");
        let lattice = LatticePotential::new(&mut looped, l.root, l.sums, n, true)
            .unwrap()
            .expect("affine in its sums");
        Both {
            n,
            unrolled,
            root,
            gradient,
            hessian_vector,
            looped,
            lattice,
        }
    }

    /// Largest difference relative to the largest value.
    fn rel(a: &[f64], b: &[f64]) -> f64 {
        let scale = a.iter().fold(1e-300f64, |m, x| m.max(x.abs()));
        a.iter()
            .zip(b)
            .map(|(x, y)| (x - y).abs() / scale)
            .fold(0.0, f64::max)
    }

    fn bits(a: &[f64]) -> Vec<u64> {
        a.iter().map(|x| x.to_bits()).collect()
    }

    impl Both {
        /// (potential, gradient, Hessian-vector product) unrolled and looped at a random point.
        fn at(&self, seed: u64) -> [(Vec<f64>, Vec<f64>); 3] {
            let n = self.n;
            let q: Vec<f64> = uniform01(n, seed).iter().map(|x| x - 0.5).collect();
            let v: Vec<f64> = uniform01(n, seed + 1).iter().map(|x| x - 0.5).collect();
            let u = &self.unrolled;
            let pu = eval1(u, &[&q], &[self.root]);
            let gu = eval1(u, &[&q], &self.gradient);
            let hu = eval1(u, &[&q, &v], &self.hessian_vector);
            let mut e = LatticeEvaluator::new(&self.looped, &self.lattice);
            let pl = vec![e.potential(&q)];
            let (mut gl, mut hl) = (vec![0.0; n], vec![0.0; n]);
            e.gradient(&q, &mut gl);
            e.hessian_vector(&q, &v, &mut hl);
            [(pu, pl), (gu, gl), (hu, hl)]
        }

        /// Potential, gradient and Hessian-vector product agree at three random points, to
        /// a few roundings of the terms (of order 1).
        fn agree(&self, case: &str) {
            for seed in 0..3 {
                let [(pu, pl), (gu, gl), (hu, hl)] = self.at(seed);
                for (what, x, y) in [("V", &pu, &pl), ("grad", &gu, &gl), ("Hv", &hu, &hl)] {
                    assert!(rel(x, y) < 1e-14, "{case} {what}: {}", rel(x, y));
                }
            }
        }
    }

    const FPUT: &str = "sum(i = 0..N, (q[i+1] - q[i])^2/2 + beta/4*(q[i+1] - q[i])^4)";

    #[test]
    fn fput_chain_loops_give_the_unrolled_potential_and_forces_bit_for_bit() {
        for n in [1, 2, 3, 10, 57] {
            let b = both(
                n,
                Boundary::Fixed,
                &[("beta", ParamValue::Scalar(1.3))],
                FPUT,
            );
            assert_eq!(b.lattice.sums.len(), 1);
            // One term: two slots, q[i+1] and q[i]; the walls are the two boundary terms.
            let sum = &b.lattice.sums[0];
            assert_eq!(sum.variables, vec![1, 0]);
            assert_eq!((sum.first, sum.last), (0, n as i64));
            let (before, after) = sum.boundary_terms();
            if n > 1 {
                assert_eq!((before, after), (vec![0], vec![n as i64]));
            } else {
                // No term reads two sites inside.
                assert_eq!((before, after), (vec![0, 1], vec![]));
            }
            for seed in 0..5 {
                let [(pu, pl), (gu, gl), (hu, hl)] = b.at(seed);
                assert_eq!(bits(&pu), bits(&pl), "N = {n}: potential");
                assert_eq!(bits(&gu), bits(&gl), "N = {n}: gradient");
                // The Hessian-vector product: the bond's f'(r) (v_{i+1} - v_i) per term
                // here, per-site coefficients times v there; a few roundings of values of
                // order 1 apart.
                assert!(rel(&hu, &hl) < 1e-14, "N = {n}: {}", rel(&hu, &hl));
            }
        }
    }

    #[test]
    fn free_periodic_and_array_parameters_agree_with_the_unrolled_sums() {
        let eps = ParamValue::Array((0..9).map(|k| 0.5 + 0.1 * k as f64).collect());
        let kg =
            "sum(i = 1..N, eps[i]/2*q[i]^2 + q[i]^4/4) + sum(i = 1..N, (q[i+1] - q[i])^2/(2*W))";
        type Case<'a> = (Boundary, &'a str, Vec<(&'a str, ParamValue)>);
        let cases: Vec<Case> = vec![
            (
                Boundary::Free,
                kg,
                vec![("eps", eps.clone()), ("W", ParamValue::Scalar(4.0))],
            ),
            (
                Boundary::Periodic,
                kg,
                vec![("eps", eps.clone()), ("W", ParamValue::Scalar(4.0))],
            ),
            (
                Boundary::Fixed,
                kg,
                vec![("eps", eps.clone()), ("W", ParamValue::Scalar(4.0))],
            ),
            (
                Boundary::Periodic,
                "sum(i = 1..N, exp(q[i+1] - q[i]) - (q[i+1] - q[i]) - 1)",
                vec![],
            ),
            // Next-nearest neighbours, a parameter read at a shift, a rest around the sums.
            (
                Boundary::Periodic,
                "q1^2 - 0.5*sum(i = 1..N, eps[i+1]*(q[i+2] - q[i])^2 + cos(q[i-1])*q[i]) + sum(j = 2..N-1, q[j]^4)/3",
                vec![("eps", eps.clone())],
            ),
            (
                Boundary::Fixed,
                "sum(i = -1..N+2, (q[i+2] - q[i-1])^2 + q[i]*q[i+1]*q[i+2])",
                vec![],
            ),
        ];
        for (boundary, src, params) in cases {
            both(9, boundary, &params, src).agree(&format!("{boundary:?} {src}"));
        }
    }

    #[test]
    fn tiny_periodic_rings_read_one_site_through_several_slots() {
        // N = 1 and 2: q[i+1] and q[i] are the same site, or q[i+2] is q[i].
        for n in [1, 2] {
            let b = both(
                n,
                Boundary::Periodic,
                &[],
                "sum(i = 1..N, (q[i+1] - q[i])^2 + q[i+2]*q[i]^3)",
            );
            let [(pu, pl), (gu, gl), (hu, hl)] = b.at(7);
            for (x, y) in [(&pu, &pl), (&gu, &gl), (&hu, &hl)] {
                assert!(rel(x, y) < 1e-14, "N = {n}: {x:?} vs {y:?}");
            }
        }
    }

    #[test]
    fn what_is_not_a_loop_stays_unrolled() {
        let params = [
            ("beta", ParamValue::Scalar(1.0)),
            ("k", ParamValue::Array(vec![1.0; 6])),
        ];
        for src in [
            // The index as a number, a stride, a fixed site, a constant term.
            "sum(i = 1..N, i*q[i]^2)",
            "sum(i = 1..3, q[2*i]^2)",
            "sum(i = 1..N, (q[i] - q1)^2)",
            "sum(i = 1..N, (q[i] - q[1])^2)",
            "sum(i = 1..N, beta)",
            // A range far beyond the lattice.
            "sum(i = 1..N+40, q[i]^2)",
        ] {
            let (_, l) = lowered_with_loops(6, Boundary::Fixed, &params, src);
            assert!(l.sums.is_empty(), "{src}");
        }
        // An inner sum whose range depends on the outer index: the outer sum is unrolled,
        // each of its terms' inner sums a loop.
        let (_, l) = lowered_with_loops(
            6,
            Boundary::Fixed,
            &params,
            "sum(i = 1..N, sum(j = i..N, q[j]))",
        );
        assert_eq!(l.sums.len(), 6);
        // Free ends and an inner sum, whose terms would be left out site by site: the outer
        // sum is unrolled, its terms' inner sums are loops (the last one is empty).
        let (_, l) = lowered_with_loops(
            6,
            Boundary::Free,
            &params,
            "sum(i = 1..N, q[i]*sum(j = 1..2, q[i+j]))",
        );
        assert_eq!(l.sums.len(), 5);
        // Fixed ends and an inner sum: a term of two slots.
        let (_, l) = lowered_with_loops(
            6,
            Boundary::Fixed,
            &params,
            "sum(i = 1..N, q[i]*sum(j = 1..2, q[i+j]))",
        );
        assert_eq!(l.sums.len(), 1);
        assert_eq!(l.sums[0].variables, vec![0, 1, 2]);
        // A sum inside an unrolled one: one loop per outer term.
        let (_, l) = lowered_with_loops(
            6,
            Boundary::Fixed,
            &params,
            "sum(j = 1..2, j*sum(i = 1..N, q[i+j-1]^2))",
        );
        assert_eq!(l.sums.len(), 2);
        assert_eq!(
            (l.sums[0].variables.clone(), l.sums[1].variables.clone()),
            (vec![0], vec![1])
        );
        // Not affine in its sums: no loop form of the derivatives.
        let (mut g, l) = lowered_with_loops(6, Boundary::Fixed, &params, "sum(i = 1..N, q[i]^2)^2");
        assert_eq!(l.sums.len(), 1);
        assert!(
            LatticePotential::new(&mut g, l.root, l.sums, 6, true)
                .unwrap()
                .is_none()
        );
        // Free ends: the range keeps the terms inside; an empty one is the constant 0.
        let (_, l) = lowered_with_loops(6, Boundary::Free, &params, "sum(i = 0..N, k[i]*q[i+1]^2)");
        assert_eq!((l.sums[0].first, l.sums[0].last), (1, 5));
        let (g, l) = lowered_with_loops(6, Boundary::Free, &params, "sum(i = 5..N, q[i+3]^2)");
        assert!(l.sums.is_empty());
        assert_eq!(g.as_const(l.root), Some(0.0));
    }

    #[test]
    fn loops_refuse_what_the_unrolled_lowering_refuses_with_its_message() {
        let params = BTreeMap::from([("k".to_string(), ParamValue::Array(vec![1.0; 4]))]);
        let families = [Family {
            name: "q".into(),
            len: 4,
            arg: ARG_Q,
            offset: 0,
        }];
        for boundary in [Boundary::Fixed, Boundary::Free, Boundary::Periodic] {
            let scope = Scope {
                families: &families,
                params: &params,
                tables: &[],
                n: 4,
                boundary,
                shape: crate::lower::Shape::Chain,
                time: None,
            };
            for src in [
                "sum(i = 0..N, k[i]*q[i]^2)",
                "sum(i = 1..N, k[i]*r[i])",
                "sum(i = 1..N, q[i]^2 + foo(q[i]))",
                "sum(i = 1..N, q[i/2])",
                "sum(i = 1..N, q[i]) + q[7]",
            ] {
                let a = lower(src, &scope, &mut Graph::new()).map(|_| ());
                let b = lower_with_loops(src, &scope, &mut Graph::new()).map(|_| ());
                assert_eq!(
                    a.map_err(|e| e.to_string()),
                    b.map_err(|e| e.to_string()),
                    "{boundary:?}: {src}"
                );
            }
        }
    }

    #[test]
    fn a_chain_of_a_hundred_thousand_sites_is_one_term() {
        let n = 100_000;
        let (mut g, l) = lowered_with_loops(
            n,
            Boundary::Fixed,
            &[("beta", ParamValue::Scalar(1.0))],
            FPUT,
        );
        let lattice = LatticePotential::new(&mut g, l.root, l.sums, n, true)
            .unwrap()
            .unwrap();
        // The term, its two derivatives and their directional derivatives: a few dozen nodes.
        assert!(g.len() < 100, "{} nodes", g.len());
        assert!(lattice.rest_gradient.is_empty());
        assert_eq!(lattice.terms(), n as u64 + 1);
    }

    #[test]
    fn a_sum_that_is_not_a_loop_leaves_its_indices_to_the_next_sum() {
        // The first sum's loop attempt fails inside its unrolled inner sum (`q[j]` is a fixed
        // site in every term); the second sum reuses the name `i`, which must be free again.
        let src = "sum(i = 1..N, sum(j = 1..2, q[j]^3)) + sum(i = 1..N, q[i]^2)";
        let b = both(5, Boundary::Fixed, &[], src);
        let [(pu, pl), (gu, gl), _] = b.at(3);
        assert!(rel(&pu, &pl) < 1e-14 && rel(&gu, &gl) < 1e-14);
    }

    /// The two-dimensional Klein-Gordon lattice: on-site terms and the bonds along both axes.
    const KG_SQUARE: &str = "sum(i = 1..N, sum(j = 1..N, eps[i, j]/2*q[i, j]^2 + q[i, j]^4/4)) \
        + sum(i = 1..N, sum(j = 1..N, ((q[i+1, j] - q[i, j])^2 + (q[i, j+1] - q[i, j])^2)/(2*W)))";

    fn square_params(side: usize) -> Vec<(&'static str, ParamValue)> {
        let eps = (0..side * side).map(|k| 0.5 + 0.01 * k as f64).collect();
        vec![
            ("eps", ParamValue::Array(eps)),
            ("W", ParamValue::Scalar(4.0)),
        ]
    }

    #[test]
    fn square_lattice_sums_are_loops_along_rows_that_agree_with_the_unrolled_sums() {
        use Boundary::{Fixed, Free, Periodic};
        // Next-nearest neighbours along both axes, a parameter read at a shift in both, and a
        // rest around the sums, beside the Klein-Gordon lattice.
        let long = "q[1, 2]^2 - 0.5*sum(i = 1..N, sum(j = 1..N, \
            k[i, j+1]*(q[i+2, j] - q[i, j-2])^2 + cos(q[i-1, j+1])*q[i, j]))";
        for side in [5, 6, 9] {
            let k = ParamValue::Array((0..side * side).map(|x| 1.0 + 0.1 * x as f64).collect());
            for rows in [Fixed, Free, Periodic] {
                for columns in [Fixed, Free, Periodic] {
                    let shape = Shape::Square { columns };
                    let mut cases = vec![(KG_SQUARE, square_params(side))];
                    // A parameter beyond a fixed column edge is an error (tested with the
                    // square's refusals), not a loop.
                    if columns == Periodic {
                        cases.push((long, vec![("k", k.clone())]));
                    }
                    if columns == Free {
                        // A wall two columns on: past the free edge it leaves the term out,
                        // as a slot there would.
                        let wall = "sum(i = 1..N, sum(j = 1..N, q[i, j]^2 + q[i+1, j+2]^2))";
                        cases.push((wall, vec![]));
                    }
                    for (src, params) in cases {
                        let b = both_shaped(side, rows, shape, &params, src);
                        // One loop per row and sum, none of them unrolled.
                        let rows_in = b.lattice.sums.len();
                        assert!(rows_in <= 2 * side, "{rows_in} sums");
                        assert!(
                            b.lattice.sums.iter().all(|s| s.side == Some(side)),
                            "{rows:?} {columns:?}"
                        );
                        b.agree(&format!("side {side}, {rows:?} x {columns:?}, {src}"));
                    }
                }
            }
        }
    }

    #[test]
    fn a_square_lattice_s_code_grows_with_its_side_not_its_area() {
        // 400 x 400 = 160,000 sites: unrolled, over a million graph nodes. As loops the terms
        // of the inner rows are the same graph (their slots differ only in the rows they read,
        // which the shifts carry), so the graph holds a few distinct terms.
        let side = 400;
        let (mut g, l) = lowered_shaped(
            side,
            Boundary::Fixed,
            Shape::Square {
                columns: Boundary::Periodic,
            },
            &square_params(side),
            KG_SQUARE,
        );
        assert_eq!(l.sums.len(), 2 * side);
        let sites = side * side;
        let lattice = LatticePotential::new(&mut g, l.root, l.sums, sites, true)
            .unwrap()
            .unwrap();
        assert!(g.len() < 20 * side, "{} nodes", g.len());
        // Every site's on-site term and two bonds (the walls' bonds of the last row read one
        // site, the wall).
        assert_eq!(lattice.terms(), 2 * sites as u64);
        // A bond in the middle of a row reads its site, the one below and the one after it.
        let bonds = &lattice.sums[side + 7];
        let (r, c) = (7, 10);
        let i = c as i64 + 1;
        let mut read: Vec<usize> = bonds
            .variables
            .iter()
            .filter_map(|&k| bonds.site(i, k))
            .collect();
        read.sort_unstable();
        assert_eq!(
            read,
            vec![r * side + c, r * side + c + 1, (r + 1) * side + c]
        );
        // The last column wraps within its row, not into the next.
        let mut read: Vec<usize> = bonds
            .variables
            .iter()
            .filter_map(|&k| bonds.site(side as i64, k))
            .collect();
        read.sort_unstable();
        let last = r * side + side - 1;
        assert_eq!(read, vec![r * side, last, last + side]);
    }

    #[test]
    fn square_sums_that_are_not_loops_along_rows_stay_unrolled() {
        let side = 6;
        let shape = Shape::Square {
            columns: Boundary::Fixed,
        };
        for src in [
            // A column offset that could be a step to another row.
            "sum(i = 1..N, sum(j = 1..N, q[i, j]*q[i, j+3]))",
            // A single index names a site with no boundary.
            "sum(k = 1..N*N, q[k]^2)",
            // A fixed site in every term.
            "sum(i = 1..N, sum(j = 1..N, q[i, j]*q[1, 1]))",
            // Columns outside, rows inside: a loop along the columns would have a whole column
            // as its term, one part of the energy distribution where the unrolled sum has a
            // part per site.
            "sum(j = 1..N, sum(i = 1..N, q[i, j]*q[i+1, j] + q[i, j]^4))",
        ] {
            let (_, l) = lowered_shaped(side, Boundary::Fixed, shape, &[], src);
            assert!(l.sums.is_empty(), "{src}");
        }
        // A row index at the end of the 64-bit range on periodic rows: wrapped as the
        // unrolled lowering wraps it (128-bit), not overflowed.
        let far = "sum(j = 1..N, q[(0 - 4294967296)*2147483648, j]^2)";
        let (_, l) = lowered_shaped(side, Boundary::Periodic, shape, &[], far);
        assert!(l.sums.is_empty(), "{far}");
        // Free rows: a sum whose every term reads past the last row has none.
        let (g, l) = lowered_shaped(
            side,
            Boundary::Free,
            shape,
            &[],
            "sum(j = 1..N, q[N+1, j]^2) + sum(j = 1..N, q[N, j]^2)",
        );
        assert_eq!(l.sums.len(), 1);
        assert!(g.len() < 20);
    }

    #[test]
    fn first_non_finite_names_the_term() {
        let (mut g, l) = lowered_with_loops(
            5,
            Boundary::Free,
            &[],
            "sum(i = 1..N, log(q[i]) + q[i+1]^2)",
        );
        let lattice = LatticePotential::new(&mut g, l.root, l.sums, 5, false)
            .unwrap()
            .unwrap();
        let q = [1.0, 2.0, -3.0, 1.0, 1.0];
        let mut e = LatticeEvaluator::new(&g, &lattice);
        let (id, at) = e.first_non_finite(&q).unwrap();
        assert_eq!(g.operation_name(id), "'log'");
        assert_eq!(at, Some((0, 3)));
        assert!(e.first_non_finite(&[1.0; 5]).is_none());
    }
}
