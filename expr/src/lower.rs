//! Syntax tree plus parameters, lattice size and boundary condition to [`Graph`] nodes.
//!
//! Everything that is known before the run is resolved here, so the graph holds only
//! arithmetic on the variables: parameters become constants (except a [`ParamValue::Lane`],
//! an input each evaluation brings: a map's parameter axis), `N` and sum indices become
//! numbers, lattice sums are expanded term by term (a left fold, in index order), and the
//! boundary condition decides what a site beyond the ends means. The smoothness of the result
//! ([`crate::smooth`]) is computed alongside, on the same walk, where parameter values are
//! known.
//!
//! Lowering never panics: every failure is an [`ExprError`] pointing into the source. On an
//! error, the nodes created so far stay in the graph, unreferenced.
//!
//! Decisions a config author may notice:
//! - Boundary conditions apply to indexed references (`q[i+1]`, `k[i]`) only. A numbered
//!   variable (`q7`) names one variable directly and must lie in `1..len`, whatever the
//!   boundary (`q7` with `N = 5` is a typo, not a wall or a wrap).
//! - Under `Fixed`, every site beyond the ends is a wall (`q[N+2]` is 0 too); under `Free`,
//!   the check whether a term exists runs before the term is lowered, so a left-out term
//!   leaves no dead nodes; only the innermost enclosing sum's term is left out.
//! - A constant whole exponent up to 64 in size becomes [`Node::Powi`], also when it
//!   is computed (`^(4/2)`, `^N`, a parameter); any other exponent becomes [`Binary::Pow`].
//! - Parameters may not reuse the name of a built-in (`N`, `pi`), a variable (`q`, `q3`), a
//!   function or a table; a sum index may not shadow any name in scope, including an
//!   enclosing sum's index.
//! - Index expressions and sum bounds are evaluated exactly in 64-bit integers (overflow is
//!   an error); parameters are not allowed in them, even whole-valued ones.

use std::cell::{Cell, RefCell};
use std::collections::{BTreeMap, BTreeSet, HashMap};

use crate::ast::{BinOp, Expr, ExprKind};
use crate::error::{ExprError, Span};
use crate::graph::{Binary, Cmp, Graph, Node, NodeId, Unary};
use crate::lattice::SiteSum;
use crate::parser::{on_big_stack, parse_here};
use crate::smooth::{self, Info, Smoothness, SmoothnessLimit};

mod loops;

/// Refuse expressions that expand to more graph nodes than this (a lattice sum over a huge
/// range, nested sums): the graph, its derivatives and the compiled code would not fit. A
/// node costs about 110 bytes while lowering (the node, its hash-consing entry, its origin), so
/// the refusal comes before about 220 MB; a chain of 10^5 sites (about 10 nodes a site) fits.
/// A single sum with more terms than this is refused before its first term is lowered.
pub const MAX_NODES: usize = 2_000_000;

/// Refuse expressions whose expansion takes more steps than this, even if constant folding
/// keeps the graph small (`sum(i = 1..10^12, 0)` must not run for hours).
pub const MAX_STEPS: u64 = 50_000_000;

/// Whole exponents up to this size become [`Node::Powi`] (an exact product, as written by
/// hand); larger ones use `powf`, whose single rounding is then more accurate than a long
/// chain of products.
const MAX_POWI: f64 = 64.0;

/// What a site index outside `1..N` means.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Boundary {
    /// Walls: every variable beyond the ends is 0 (`q[0] = q[N+1] = 0`). An array parameter
    /// has no value there (an error).
    Fixed,
    /// A ring: `q[N+1] = q[1]`, `q[0] = q[N]`; array parameters wrap alike.
    Periodic,
    /// Open ends: a term of a sum that refers to a site beyond the ends is left out (a bond to
    /// nothing does not exist); outside a sum such a reference is an error.
    Free,
}

impl Boundary {
    /// From a config's spelling: `fixed`, `periodic` or `free`.
    pub fn from_name(name: &str) -> Result<Self, String> {
        match name {
            "fixed" => Ok(Boundary::Fixed),
            "periodic" => Ok(Boundary::Periodic),
            "free" => Ok(Boundary::Free),
            _ => Err(format!(
                "unknown boundary condition '{name}' (known: fixed, periodic, free)"
            )),
        }
    }

    pub fn name(self) -> &'static str {
        match self {
            Boundary::Fixed => "fixed",
            Boundary::Periodic => "periodic",
            Boundary::Free => "free",
        }
    }
}

/// How the sites are laid out, which says what an indexed reference means.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub enum Shape {
    /// A chain of `N` sites, `q[i]`, with [`Scope::boundary`] at both ends.
    #[default]
    Chain,
    /// An `N x N` square of `N^2` sites numbered row by row: `q[i, j]` is row `i`, column `j`
    /// (1-based), entry `(i - 1) N + j` of the family. [`Scope::boundary`] applies along the
    /// rows' index `i`, `columns` along `j` (a cylinder is `fixed` along one, `periodic` along
    /// the other). A single index `q[k]` names entry `k` directly and must lie in `1..N^2`.
    Square { columns: Boundary },
}

impl Shape {
    /// The number of sites of a lattice whose `N` is `n`.
    pub fn sites(self, n: usize) -> Option<usize> {
        match self {
            Shape::Chain => Some(n),
            Shape::Square { .. } => n.checked_mul(n),
        }
    }

    /// The value of `N` on a lattice of `sites` sites: `sites` on a chain, the side of a
    /// square (`sites` is a square number there: the side is taken to the nearest whole).
    pub fn n_of(self, sites: usize) -> usize {
        match self {
            Shape::Chain => sites,
            Shape::Square { .. } => (sites as f64).sqrt().round() as usize,
        }
    }
}

/// A parameter's value from the config.
#[derive(Debug, Clone, PartialEq)]
pub enum ParamValue {
    Scalar(f64),
    /// One entry per site (`k[1]` is the first); must have exactly `N` entries (`N^2` on a
    /// square lattice, row by row: `k[i, j]`).
    Array(Vec<f64>),
    /// A scalar whose value every evaluation brings: entry `index` of the function's argument
    /// `arg`, not folded as a constant (a map's parameter axis, where each lane of a lane call
    /// is a point with a value of its own). `min..=max` is the range it takes: its signs decide
    /// the smoothness of what reads it, as a constant's do. Operations on it round as they
    /// would on the constant, so a lane holding the value the constant would have gives the
    /// same bits wherever the constant would not fold differently (an identity such as
    /// `x * 1`, a whole exponent, a branch of `if`).
    Lane {
        arg: u8,
        index: u32,
        min: f64,
        max: f64,
    },
}

/// A family of variables: `q1..qN` and `q[i]` are entries of the function's argument `arg`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Family {
    pub name: String,
    pub len: usize,
    pub arg: u8,
    /// Index of the family's first variable in its argument array: a Hamiltonian's `q` and
    /// `p` share one state array, `q` at 0 and `p` at `N`.
    pub offset: usize,
}

/// Everything names in an expression can refer to.
#[derive(Debug, Clone, Copy)]
pub struct Scope<'a> {
    pub families: &'a [Family],
    pub params: &'a BTreeMap<String, ParamValue>,
    /// Table name and its index, already registered in the graph ([`Graph::add_table`]).
    pub tables: &'a [(String, u32)],
    /// The value of `N` (number of sites or dimension; a square lattice's side).
    pub n: usize,
    pub boundary: Boundary,
    /// A chain, or a square of `N x N` sites read as `q[i, j]`.
    pub shape: Shape,
    /// The argument array whose entry 0 is the time, where the name `t` means the time (a
    /// flow's `rhs`, a Hamiltonian, a potential: non-autonomous systems); `None` where `t` is
    /// an ordinary name (a map's `next`, a section's surface). Where it is `Some`, `t` is a
    /// built-in like `N`: a parameter or sum index of that name is an error.
    pub time: Option<u8>,
}

/// The result of [`lower`].
#[derive(Debug, Clone)]
pub struct Lowered {
    pub root: NodeId,
    pub smoothness: Smoothness,
    /// For each node created by this lowering, the source span of the operation that first
    /// created it (for messages such as "log of a negative number at line 1, column 7"): a
    /// call's whole text (`log(q2 - 3)`), an operator's symbol (`/`, `^`), a name or number,
    /// the whole `sum(...)` for the additions of its fold. Nodes that already existed in the
    /// graph are not included.
    pub origins: HashMap<NodeId, Span>,
    /// The lattice sums lowered as loops ([`lower_with_loops`]; empty for [`lower`]): sum `s`
    /// is `Input { arg: ARG_SUM, index: s }` in `root`.
    pub sums: Vec<SiteSum>,
    /// `root` as `sum_k c_k * terms[k] + sum_k c_k * rest[k]` (node, `c = +-1`), where the
    /// expression adds (`+`, `-`) lattice sums at its top level: the terms of those sums that
    /// were unrolled (every term of a nested sum `sum(i, sum(j, term))`), and the other parts.
    /// What says which part of a potential belongs to which site when its sums are not loops.
    /// Empty where the expression is not such a sum of parts.
    pub parts: Parts,
}

/// See [`Lowered::parts`].
#[derive(Debug, Clone, Default)]
pub struct Parts {
    pub terms: Vec<(NodeId, f64)>,
    pub rest: Vec<(NodeId, f64)>,
}

/// Every built-in function, for "unknown function" messages.
fn known() -> String {
    let unary = crate::ops::UNARY_OPS.iter().filter_map(|d| d.name);
    let binary = crate::ops::BINARY_OPS.iter().filter_map(|d| d.name);
    let other = ["if", "piecewise", "sum"];
    unary
        .chain(binary)
        .chain(other)
        .collect::<Vec<_>>()
        .join(", ")
}

fn is_function(name: &str) -> bool {
    Unary::named(name).is_some()
        || Binary::named(name).is_some()
        || matches!(name, "if" | "piecewise" | "sum")
}

/// Parse `source` and lower it into `graph`.
pub fn lower(source: &str, scope: &Scope, graph: &mut Graph) -> Result<Lowered, ExprError> {
    on_big_stack(|| lower_limited(source, scope, graph, MAX_NODES, MAX_STEPS, false))
}

/// [`lower`], with the lattice sums that allow it lowered as loops (their terms once, see
/// [`crate::lattice`]) rather than unrolled: for a potential of the variables `q` (one family,
/// argument [`crate::lattice::ARG_Q`], offset 0, `N` entries, `N^2` on a square). Accepts and refuses exactly the
/// expressions [`lower`] does, with the same errors.
pub fn lower_with_loops(
    source: &str,
    scope: &Scope,
    graph: &mut Graph,
) -> Result<Lowered, ExprError> {
    let loops = matches!(scope.families, [f] if f.arg == crate::lattice::ARG_Q && f.offset == 0
        && Some(f.len) == scope.shape.sites(scope.n));
    on_big_stack(|| lower_limited(source, scope, graph, MAX_NODES, MAX_STEPS, loops))
}

/// [`lower`] with other size limits (tests reach them without building ten million nodes).
fn lower_limited(
    source: &str,
    scope: &Scope,
    graph: &mut Graph,
    max_nodes: usize,
    max_steps: u64,
    loops: bool,
) -> Result<Lowered, ExprError> {
    let ast = parse_here(source)?;
    let start_len = graph.len();
    let mut l = Lowerer {
        src: source,
        scope,
        graph,
        sums: Vec::new(),
        origins: Vec::new(),
        start_len,
        steps: Cell::new(0),
        max_nodes,
        max_steps,
        loops,
        site_sums: Vec::new(),
        template: None,
        lane_args: scope
            .params
            .values()
            .filter_map(|v| match v {
                ParamValue::Lane { arg, .. } => Some(*arg),
                _ => None,
            })
            .collect(),
        lane_only: RefCell::new(HashMap::new()),
        parts: Parts::default(),
        recording: None,
    };
    let (root, info) = l.root(&ast).map_err(|e| *e)?;
    let tables = scope.tables;
    let smoothness = smooth::finish(&info, source, |t| {
        tables
            .iter()
            .find(|(_, i)| *i == t)
            .map_or_else(|| format!("table {t}"), |(n, _)| n.clone())
    });
    Ok(Lowered {
        root,
        smoothness,
        origins: (l.start_len..)
            .zip(l.origins)
            .map(|(id, span)| (id as NodeId, span))
            .collect(),
        sums: l.site_sums,
        parts: l.parts,
    })
}

type R<T> = Result<T, Box<ExprError>>;

/// What a name refers to.
enum Meaning<'a> {
    SumIndex(i64),
    N,
    Pi,
    Param(&'a ParamValue),
    /// The time `t` (where the scope has one): entry 0 of this argument array.
    Time(u8),
    /// A numbered variable `q3`: its family and number (not yet checked against the length).
    Var(&'a Family, u64),
    Family(&'a Family),
    Table(u32),
    Function,
    Unknown,
}

struct Lowerer<'a> {
    src: &'a str,
    scope: &'a Scope<'a>,
    graph: &'a mut Graph,
    /// The enclosing sums' indices and their current values, innermost last.
    sums: Vec<(&'a str, i64)>,
    /// The origin of each node created here: new nodes are appended to the graph, so node
    /// `start_len + k` has `origins[k]` (a vector while lowering, a map for the caller).
    origins: Vec<Span>,
    start_len: usize,
    /// Every pass over a tree node counts (`Cell`: the read-only passes count too).
    steps: Cell<u64>,
    max_nodes: usize,
    max_steps: u64,
    /// Lower the lattice sums that allow it as loops.
    loops: bool,
    /// Those sums, in the order met.
    site_sums: Vec<SiteSum>,
    /// The sum whose term is being lowered (once, as a loop's body).
    template: Option<loops::Template<'a>>,
    /// The arguments [`ParamValue::Lane`] parameters are read from, and which nodes depend on
    /// nothing else (no variable): see [`Lowerer::settle`].
    lane_args: Vec<u8>,
    lane_only: RefCell<HashMap<NodeId, bool>>,
    /// The root's parts (see [`Lowered::parts`]), and the coefficient of the top-level sum
    /// whose terms are being recorded.
    parts: Parts,
    recording: Option<f64>,
}

impl<'a> Lowerer<'a> {
    fn err(&self, span: Span, msg: impl Into<String>) -> Box<ExprError> {
        Box::new(ExprError::new(self.src, span, msg))
    }

    fn root(&mut self, ast: &'a Expr) -> R<(NodeId, Info)> {
        let mut checked = BTreeSet::new();
        self.check_params(ast, &mut checked)?;
        // A sum of parts: each part lowered as `value` would, its terms recorded on the way
        // (the same nodes in the same order, so the same graph).
        let ExprKind::Chain { first, rest } = &ast.kind else {
            return self.part(ast, 1.0);
        };
        if rest
            .iter()
            .any(|(op, _, _)| !matches!(op, BinOp::Add | BinOp::Sub))
        {
            return self.value(ast);
        }
        self.tick(ast.span)?;
        let (mut acc, mut info) = self.part(first, 1.0)?;
        for (op, op_span, x) in rest {
            let sign = if *op == BinOp::Add { 1.0 } else { -1.0 };
            let (b, bi) = self.part(x, sign)?;
            let (bin, combined) = match op {
                BinOp::Add => (Binary::Add, info.add(bi)),
                _ => (Binary::Sub, info.sub(bi)),
            };
            acc = self.emit(Node::Binary(bin, acc, b), *op_span)?;
            info = self.settle(acc, combined);
        }
        Ok((acc, info))
    }

    /// A part of the root with its coefficient (see [`Lowered::parts`]): a sum, `-sum`, or a
    /// sum times or over a constant (`0.5*sum(...)`, `sum(...)/(4*W)`) has its terms recorded
    /// with that coefficient; anything else is one part of the rest. Each is lowered as
    /// [`Lowerer::value`] lowers it (the same ticks, operands in the same order, the same
    /// nodes).
    fn part(&mut self, e: &'a Expr, sign: f64) -> R<(NodeId, Info)> {
        let is_sum = |x: &Expr| matches!(x.kind, ExprKind::Sum { .. });
        match &e.kind {
            ExprKind::Sum { .. } => self.sum_part(e, sign),
            ExprKind::Neg { op_span, arg } if is_sum(arg) => {
                self.tick(e.span)?;
                let (a, ai) = self.sum_part(arg, -sign)?;
                let id = self.emit(Node::Unary(Unary::Neg, a), *op_span)?;
                Ok((id, self.settle(id, ai.neg())))
            }
            ExprKind::Chain { first, rest }
                if rest.len() == 1
                    && (is_sum(first) && matches!(rest[0].0, BinOp::Mul | BinOp::Div)
                        || !is_sum(first) && rest[0].0 == BinOp::Mul && is_sum(&rest[0].2)) =>
            {
                self.tick(e.span)?;
                let mark = self.parts.terms.len();
                let (op, op_span, x) = &rest[0];
                let (a, ai) = self.sum_part_or_value(first, 1.0)?;
                let (b, bi) = self.sum_part_or_value(x, 1.0)?;
                let (bin, combined) = match op {
                    BinOp::Mul => (Binary::Mul, ai.mul(bi)),
                    _ => (Binary::Div, ai.div(bi)),
                };
                let id = self.emit(Node::Binary(bin, a, b), *op_span)?;
                let info = self.settle(id, combined);
                // The factor beside the sum, where it is a constant.
                let factor = if is_sum(first) { b } else { a };
                match self.graph.as_const(factor) {
                    Some(c) if c != 0.0 && c.is_finite() => {
                        let c = if *op == BinOp::Div { 1.0 / c } else { c };
                        for t in &mut self.parts.terms[mark..] {
                            t.1 *= sign * c;
                        }
                    }
                    _ => {
                        self.parts.terms.truncate(mark);
                        self.parts.rest.push((id, sign));
                    }
                }
                Ok((id, info))
            }
            _ => {
                let (id, info) = self.value(e)?;
                self.parts.rest.push((id, sign));
                Ok((id, info))
            }
        }
    }

    /// A sum lowered with its terms recorded with coefficient `sign`.
    fn sum_part(&mut self, e: &'a Expr, sign: f64) -> R<(NodeId, Info)> {
        self.recording = Some(sign);
        let lowered = self.value(e);
        self.recording = None;
        lowered
    }

    /// [`Lowerer::sum_part`] for a sum, [`Lowerer::value`] for anything else.
    fn sum_part_or_value(&mut self, e: &'a Expr, sign: f64) -> R<(NodeId, Info)> {
        match e.kind {
            ExprKind::Sum { .. } => self.sum_part(e, sign),
            _ => self.value(e),
        }
    }

    /// Add a node, recording where it came from and refusing runaway expansions.
    fn emit(&mut self, node: Node, span: Span) -> R<NodeId> {
        if let Node::Table { table, .. } = node
            && table as usize >= self.graph.tables().len()
        {
            return Err(self.err(
                span,
                format!("table index {table} is not registered in the graph"),
            ));
        }
        let before = self.graph.len();
        let id = self.graph.add(node);
        let after = self.graph.len();
        if after > before {
            self.origins.resize(after - self.start_len, span);
            if after - self.start_len > self.max_nodes {
                return Err(self.err(
                    span,
                    format!(
                        "the expression expands to more than {} graph nodes (lattice sums over too many sites?)",
                        self.max_nodes
                    ),
                ));
            }
        }
        Ok(id)
    }

    fn constant(&mut self, c: f64, span: Span) -> R<(NodeId, Info)> {
        Ok((self.emit(Node::Const(c), span)?, Info::constant(c)))
    }

    /// Variable `j` (0-based) of family `f`.
    fn input(&mut self, f: &Family, j: usize, span: Span) -> R<(NodeId, Info)> {
        let node = Node::Input {
            arg: f.arg,
            index: (f.offset + j) as u32,
        };
        Ok((self.emit(node, span)?, Info::variable()))
    }

    /// The facts of a freshly built node: a node that folded to a constant is smooth whatever
    /// operations it was written with (`abs(beta)`, `step(N - 2)`), and so is one of lane
    /// parameters alone (`sqrt(K)` over `K` in `0..1`): constant along every orbit, it limits
    /// no derivative with respect to the variables.
    fn settle(&self, id: NodeId, info: Info) -> Info {
        match self.graph.as_const(id) {
            Some(c) => Info::constant(c),
            None if !self.lane_args.is_empty() && self.reads_lane_params_only(id) => Info {
                limit: None,
                zero_kink: false,
                vanishing: true,
                pole_free: true,
                varies: false,
                absorbed: None,
                ..info
            },
            None => info,
        }
    }

    /// Whether node `id` reads no input but lane parameters (memoized; iterative, so a long
    /// chain of operations cannot overflow the stack).
    fn reads_lane_params_only(&self, id: NodeId) -> bool {
        let mut memo = self.lane_only.borrow_mut();
        let mut stack = vec![id];
        while let Some(&top) = stack.last() {
            if memo.contains_key(&top) {
                stack.pop();
                continue;
            }
            let node = self.graph.node(top);
            let pending: Vec<NodeId> = node.operands().filter(|o| !memo.contains_key(o)).collect();
            if !pending.is_empty() {
                stack.extend(pending);
                continue;
            }
            let only = match *node {
                Node::Input { arg, .. } => self.lane_args.contains(&arg),
                _ => node.operands().all(|o| memo[&o]),
            };
            memo.insert(top, only);
            stack.pop();
        }
        memo[&id]
    }

    fn tick(&self, span: Span) -> R<()> {
        self.steps.set(self.steps.get() + 1);
        if self.steps.get() > self.max_steps {
            return Err(self.err(
                span,
                format!(
                    "the expression expands to more than {} operations (lattice sums over too many sites?)",
                    self.max_steps
                ),
            ));
        }
        Ok(())
    }

    fn numbered(&self, name: &str) -> Option<(&'a Family, u64)> {
        self.scope.families.iter().find_map(|f| {
            let rest = name.strip_prefix(f.name.as_str())?;
            (!rest.is_empty() && rest.bytes().all(|b| b.is_ascii_digit()))
                .then(|| (f, rest.parse::<u64>().unwrap_or(u64::MAX)))
        })
    }

    fn meaning(&self, name: &str) -> Meaning<'a> {
        if let Some(&(_, i)) = self.sums.iter().rev().find(|(n, _)| *n == name) {
            return Meaning::SumIndex(i);
        }
        match name {
            "N" => return Meaning::N,
            "pi" => return Meaning::Pi,
            "t" if let Some(arg) = self.scope.time => return Meaning::Time(arg),
            _ => {}
        }
        if let Some(p) = self.scope.params.get(name) {
            return Meaning::Param(p);
        }
        if let Some((f, k)) = self.numbered(name) {
            return Meaning::Var(f, k);
        }
        if let Some(f) = self.scope.families.iter().find(|f| f.name == name) {
            return Meaning::Family(f);
        }
        if let Some(&(_, t)) = self.scope.tables.iter().find(|(n, _)| n == name) {
            return Meaning::Table(t);
        }
        if is_function(name) {
            return Meaning::Function;
        }
        Meaning::Unknown
    }

    /// `unknown name 'r' (variables: q1..q5 or q[i]; parameters: beta, k)`.
    fn unknown(&self, name: &str, span: Span) -> Box<ExprError> {
        let vars: Vec<String> = self
            .scope
            .families
            .iter()
            .map(|f| match f.len {
                0 => format!("{} (none)", f.name),
                1 => format!("{n}1 or {n}[i]", n = f.name),
                len => format!("{n}1..{n}{len} or {n}[i]", n = f.name),
            })
            .collect();
        let params: Vec<&str> = self.scope.params.keys().map(String::as_str).collect();
        let mut msg = format!(
            "unknown name '{name}' (variables: {}; parameters: {}",
            list_or_none(&vars),
            list_or_none(&params)
        );
        if !self.sums.is_empty() {
            let idx: Vec<&str> = self.sums.iter().map(|(n, _)| *n).collect();
            msg += &format!("; sum indices: {}", idx.join(", "));
        }
        msg += &self.tables_note();
        msg.push(')');
        self.err(span, msg)
    }

    /// `; tables: U, V` for messages that list the names in scope (empty without tables).
    fn tables_note(&self) -> String {
        if self.scope.tables.is_empty() {
            return String::new();
        }
        let t: Vec<&str> = self.scope.tables.iter().map(|(n, _)| n.as_str()).collect();
        format!("; tables: {}", t.join(", "))
    }

    /// Every parameter the expression names: finite values, arrays of exactly `N` entries,
    /// and a name that does not hide a built-in, a variable or a function. Checked once per
    /// name, before lowering, so the error names the first use whatever the sums do.
    fn check_params(&self, e: &'a Expr, checked: &mut BTreeSet<&'a str>) -> R<()> {
        let (name, span) = match &e.kind {
            ExprKind::Name(n) => (Some(n.as_str()), e.span),
            ExprKind::Index {
                name, name_span, ..
            }
            | ExprKind::Call {
                name, name_span, ..
            } => (Some(name.as_str()), *name_span),
            _ => (None, e.span),
        };
        if let Some(name) = name
            && let Some(value) = self.scope.params.get(name)
            && checked.insert(name)
        {
            self.check_param(name, value, span)?;
        }
        for c in e.children() {
            self.check_params(c, checked)?;
        }
        Ok(())
    }

    fn check_param(&self, name: &str, value: &ParamValue, span: Span) -> R<()> {
        let clash = if matches!(name, "N" | "pi") {
            Some("the built-in")
        } else if name == "t" && self.scope.time.is_some() {
            Some("the time")
        } else if self.numbered(name).is_some()
            || self.scope.families.iter().any(|f| f.name == name)
        {
            Some("a variable")
        } else if is_function(name) {
            Some("a function")
        } else if self.scope.tables.iter().any(|(n, _)| n == name) {
            Some("a table")
        } else {
            None
        };
        if let Some(what) = clash {
            return Err(self.err(
                span,
                format!("parameter '{name}' has the name of {what} '{name}'; rename the parameter"),
            ));
        }
        match value {
            ParamValue::Scalar(v) if !v.is_finite() => Err(self.err(
                span,
                format!("parameter '{name}' is not a finite number ({v})"),
            )),
            ParamValue::Array(v) if Some(v.len()) != self.scope.shape.sites(self.scope.n) => {
                Err(self.err(
                    span,
                    match self.scope.shape {
                        Shape::Chain => format!(
                            "parameter '{name}' has {} entries but N = {}",
                            v.len(),
                            self.scope.n
                        ),
                        Shape::Square { .. } => format!(
                            "parameter '{name}' has {} entries but the {n} x {n} lattice has \
                             {} sites (one entry per site, row by row)",
                            v.len(),
                            self.scope.n.saturating_mul(self.scope.n),
                            n = self.scope.n
                        ),
                    },
                ))
            }
            ParamValue::Array(v) => match v.iter().position(|x| !x.is_finite()) {
                Some(k) => Err(self.err(
                    span,
                    format!(
                        "parameter '{name}' entry {} is not a finite number ({})",
                        k + 1,
                        v[k]
                    ),
                )),
                None => Ok(()),
            },
            ParamValue::Lane { min, max, .. } if !(min.is_finite() && max.is_finite()) => Err(self
                .err(
                    span,
                    format!("parameter '{name}' ranges over {min} .. {max}, not finite numbers"),
                )),
            ParamValue::Scalar(_) | ParamValue::Lane { .. } => Ok(()),
        }
    }

    fn value(&mut self, e: &'a Expr) -> R<(NodeId, Info)> {
        self.tick(e.span)?;
        match &e.kind {
            ExprKind::Number(v) => self.constant(*v, e.span),
            ExprKind::Name(n) => self.name(n, e.span),
            ExprKind::Index {
                name,
                name_span,
                index,
                column: None,
            } => self.indexed(e, name, *name_span, index),
            ExprKind::Index {
                name,
                name_span,
                index,
                column: Some(column),
            } => self.indexed_square(e, name, *name_span, index, column),
            ExprKind::Neg { op_span, arg } => {
                let (a, ai) = self.value(arg)?;
                let id = self.emit(Node::Unary(Unary::Neg, a), *op_span)?;
                Ok((id, self.settle(id, ai.neg())))
            }
            ExprKind::Chain { first, rest } => {
                let (mut acc, mut info) = self.value(first)?;
                for (op, op_span, x) in rest {
                    let (b, bi) = self.value(x)?;
                    let (bin, combined) = match op {
                        BinOp::Add => (Binary::Add, info.add(bi)),
                        BinOp::Sub => (Binary::Sub, info.sub(bi)),
                        BinOp::Mul => (Binary::Mul, info.mul(bi)),
                        BinOp::Div => (Binary::Div, info.div(bi)),
                    };
                    acc = self.emit(Node::Binary(bin, acc, b), *op_span)?;
                    info = self.settle(acc, combined);
                }
                Ok((acc, info))
            }
            ExprKind::Pow { op_span, base, exp } => self.power(base, exp, *op_span),
            ExprKind::Call {
                name,
                name_span,
                args,
            } => self.call(e, name, *name_span, args),
            ExprKind::Compare { op, op_span, .. } => Err(self.err(
                *op_span,
                format!(
                    "a comparison ('{}') is only allowed as the condition of if or piecewise",
                    cmp_symbol(*op)
                ),
            )),
            ExprKind::Sum {
                index,
                index_span,
                from,
                to,
                body,
            } => self.sum(e, index, *index_span, from, to, body),
        }
    }

    fn name(&mut self, n: &str, span: Span) -> R<(NodeId, Info)> {
        if self.is_loop_index(n)
            || (self.template.is_some()
                && matches!(self.meaning(n), Meaning::Var(..) | Meaning::Time(_)))
        {
            // (A term that reads the time is not the same function of its slots at every
            // step; such a sum is unrolled.)
            // A site loop's term reads its index and the variables only as q[i + k].
            return Err(self.not_a_loop(span));
        }
        match self.meaning(n) {
            Meaning::SumIndex(i) => self.constant(i as f64, span),
            Meaning::N => self.constant(self.scope.n as f64, span),
            Meaning::Pi => self.constant(std::f64::consts::PI, span),
            Meaning::Time(arg) => {
                let node = Node::Input { arg, index: 0 };
                Ok((self.emit(node, span)?, Info::variable()))
            }
            Meaning::Param(ParamValue::Scalar(v)) => self.constant(*v, span),
            Meaning::Param(&ParamValue::Lane {
                arg,
                index,
                min,
                max,
            }) => {
                let id = self.emit(Node::Input { arg, index }, span)?;
                Ok((id, Info::within(min, max)))
            }
            Meaning::Param(ParamValue::Array(_)) => Err(self.err(
                span,
                format!("parameter '{n}' is an array (one entry per site): write {n}[i]"),
            )),
            Meaning::Var(f, k) => {
                if k >= 1 && k <= f.len as u64 {
                    self.input(f, (k - 1) as usize, span)
                } else {
                    let size = if f.len == self.scope.n {
                        format!("N = {}", f.len)
                    } else {
                        format!("'{}' has {} entries", f.name, f.len)
                    };
                    Err(self.err(
                        span,
                        format!(
                            "variable '{n}' does not exist: {size} ({m}1..{m}{}); boundary conditions apply to indexed variables such as {m}[i+1] only",
                            f.len,
                            m = f.name
                        ),
                    ))
                }
            }
            Meaning::Family(f) => Err(self.err(
                span,
                format!(
                    "'{n}' is a family of variables: write {n}1..{n}{} or {n}[i]",
                    f.len
                ),
            )),
            Meaning::Function if n == "sum" => {
                Err(self.err(span, "'sum' needs a range and a term: sum(i = 1..N, term)"))
            }
            m @ (Meaning::Table(_) | Meaning::Function | Meaning::Unknown) => {
                Err(self.not_a_value(m, n, span))
            }
        }
    }

    /// The error for `name` where a value is wanted, when it means a table, a function or
    /// nothing.
    fn not_a_value(&self, meaning: Meaning<'a>, name: &str, span: Span) -> Box<ExprError> {
        match meaning {
            Meaning::Table(_) => self.err(
                span,
                format!("'{name}' is a tabulated function: write {name}(x)"),
            ),
            Meaning::Function => {
                self.err(span, format!("'{name}' is a function: write {name}(...)"))
            }
            _ => self.unknown(name, span),
        }
    }

    fn indexed(
        &mut self,
        e: &'a Expr,
        name: &str,
        name_span: Span,
        index: &'a Expr,
    ) -> R<(NodeId, Info)> {
        if let Some(t) = &self.template {
            if loops::mentions(index, t.index) {
                return self.slot(e, name, index);
            }
            if matches!(self.meaning(name), Meaning::Family(_)) {
                // A fixed site in every term: not a loop's slot.
                return Err(self.not_a_loop(e.span));
            }
        }
        match self.meaning(name) {
            Meaning::Family(f) => {
                let k = self.int(index)?;
                match self.site(k, f.len, name, false, e.span)? {
                    Some(j) => self.input(f, j, e.span),
                    // A wall.
                    None => self.constant(0.0, e.span),
                }
            }
            Meaning::Param(ParamValue::Array(v)) => {
                let k = self.int(index)?;
                match self.site(k, v.len(), name, true, e.span)? {
                    Some(j) => self.constant(v[j], e.span),
                    None => Err(self.err(e.span, format!("{name}[{k}] does not exist"))),
                }
            }
            Meaning::Param(ParamValue::Scalar(_) | ParamValue::Lane { .. }) => Err(self.err(
                name_span,
                format!("'{name}' is a scalar parameter, not an array: write {name}"),
            )),
            Meaning::SumIndex(_) => {
                Err(self.err(name_span, format!("'{name}' is a sum index, not an array")))
            }
            Meaning::Var(f, _) => Err(self.err(
                name_span,
                format!(
                    "'{name}' is a single variable; an indexed variable is written {}[i]",
                    f.name
                ),
            )),
            Meaning::N | Meaning::Pi | Meaning::Time(_) => {
                Err(self.err(name_span, format!("'{name}' is a number, not an array")))
            }
            m @ (Meaning::Table(_) | Meaning::Function | Meaning::Unknown) => {
                Err(self.not_a_value(m, name, name_span))
            }
        }
    }

    /// `name[i, j]`: the site in row `i` and column `j` of a square lattice, each index taken
    /// along its own axis with that axis's boundary (a wall, a wrap, or no site at all).
    fn indexed_square(
        &mut self,
        e: &'a Expr,
        name: &str,
        name_span: Span,
        row: &'a Expr,
        column: &'a Expr,
    ) -> R<(NodeId, Info)> {
        if let Some(t) = &self.template {
            if loops::mentions(row, t.index) || loops::mentions(column, t.index) {
                return self.square_slot(e, name, row, column);
            }
            if matches!(self.meaning(name), Meaning::Family(_)) {
                // A fixed site in every term: not a loop's slot.
                return Err(self.not_a_loop(e.span));
            }
        }
        let Shape::Square { columns } = self.scope.shape else {
            return Err(self.err(
                e.span,
                format!(
                    "{name}[i, j] names a site of a square lattice, but these sites form a chain \
                     (write {name}[i], or set lattice = \"square\")"
                ),
            ));
        };
        let side = self.scope.n;
        let (family, values) = match self.meaning(name) {
            Meaning::Family(f) => (Some(f), None),
            Meaning::Param(ParamValue::Array(v)) => (None, Some(v)),
            // Not something with sites: the single index's message says what it is.
            _ => return self.indexed(e, name, name_span, row),
        };
        let len = family.map_or_else(|| values.map_or(0, Vec::len), |f| f.len);
        if Some(len) != side.checked_mul(side) {
            return Err(self.err(
                name_span,
                format!(
                    "'{name}' has {len} entries, not one per site of the {side} x {side} lattice"
                ),
            ));
        }
        let is_param = values.is_some();
        let along = |index: &'a Expr, boundary: Boundary| -> R<Option<usize>> {
            let k = i128::from(self.int(index)?);
            if (1..=side as i128).contains(&k) {
                return Ok(Some((k - 1) as usize));
            }
            self.beyond_end(k, side as i128, name, is_param, index.span, boundary)
        };
        let r = along(row, self.scope.boundary)?;
        let c = along(column, columns)?;
        match (r.zip(c), family, values) {
            (Some((r, c)), Some(f), _) => self.input(f, r * side + c, e.span),
            (Some((r, c)), None, Some(v)) => self.constant(v[r * side + c], e.span),
            // A wall along either axis (parameters have none: `beyond_end` refused them).
            _ => self.constant(0.0, e.span),
        }
    }

    /// Whether a term reaching past an end along some axis is left out (free ends).
    fn any_free(&self) -> bool {
        self.scope.boundary == Boundary::Free
            || self.scope.shape
                == (Shape::Square {
                    columns: Boundary::Free,
                })
    }

    /// The 0-based entry for site `k` of something with `len` sites, `None` for a wall.
    fn site(&self, k: i64, len: usize, name: &str, is_param: bool, span: Span) -> R<Option<usize>> {
        let n = len as i128;
        let k = i128::from(k);
        if (1..=n).contains(&k) {
            return Ok(Some((k - 1) as usize));
        }
        if let Shape::Square { .. } = self.scope.shape {
            return Err(self.err(
                span,
                format!(
                    "{name}[{k}] does not exist: on the {s} x {s} lattice a single index names \
                     one of the {n} sites row by row, and boundary conditions apply to \
                     {name}[i, j] only",
                    s = self.scope.n
                ),
            ));
        }
        self.beyond_end(k, n, name, is_param, span, self.scope.boundary)
    }

    /// What index `k` outside `1..=n` means along an axis with `boundary`: the wrapped entry
    /// (0-based), `None` for a wall, or the error of a site that is not there.
    fn beyond_end(
        &self,
        k: i128,
        n: i128,
        name: &str,
        is_param: bool,
        span: Span,
        boundary: Boundary,
    ) -> R<Option<usize>> {
        let msg = match boundary {
            Boundary::Periodic if n > 0 => return Ok(Some((k - 1).rem_euclid(n) as usize)),
            Boundary::Periodic => format!("{name}[{k}]: '{name}' has no entries"),
            Boundary::Fixed if !is_param => return Ok(None),
            Boundary::Fixed => format!(
                "index {k} of the array parameter '{name}' is outside 1..{n}: with fixed ends there are no parameters beyond the walls"
            ),
            Boundary::Free => format!(
                "index {k} of '{name}' is outside 1..{n}: with free ends there is no site there (inside a sum, a term that refers to one is left out)"
            ),
        };
        Err(self.err(span, msg))
    }

    /// The value of an index or sum-bound expression: whole numbers, sum indices, `N`,
    /// `+ - *` and parentheses.
    fn int(&self, e: &Expr) -> R<i64> {
        self.tick(e.span)?;
        const RULE: &str = "index expressions may only contain whole numbers, sum indices, N, + - * and parentheses";
        let overflow = || self.err(e.span, "index expression overflows a 64-bit integer");
        let text = &self.src[e.span.start..e.span.end];
        match &e.kind {
            ExprKind::Number(v) => {
                if v.fract() == 0.0 && v.abs() <= 9.0e15 {
                    Ok(*v as i64)
                } else if v.fract() == 0.0 {
                    Err(self.err(e.span, format!("index '{text}' is too large")))
                } else {
                    Err(self.err(
                        e.span,
                        format!("index expression is not an integer: '{text}' ({RULE})"),
                    ))
                }
            }
            ExprKind::Name(n) if self.is_loop_index(n) => Err(self.not_a_loop(e.span)),
            ExprKind::Name(n) => match self.meaning(n) {
                Meaning::SumIndex(i) => Ok(i),
                Meaning::N => i64::try_from(self.scope.n).map_err(|_| overflow()),
                Meaning::Unknown if self.sums.is_empty() => Err(self.err(
                    e.span,
                    format!(
                        "unknown name '{n}' in an index (a sum index exists only inside sum({n} = a..b, term))"
                    ),
                )),
                Meaning::Unknown => Err(self.unknown(n, e.span)),
                Meaning::Param(_) => Err(self.err(
                    e.span,
                    format!("index expression is not an integer: '{n}' is a parameter ({RULE})"),
                )),
                Meaning::Var(..) | Meaning::Family(_) => Err(self.err(
                    e.span,
                    format!("index expression is not an integer: '{n}' is a variable ({RULE})"),
                )),
                _ => Err(self.err(
                    e.span,
                    format!("index expression is not an integer: '{n}' ({RULE})"),
                )),
            },
            ExprKind::Neg { arg, .. } => self.int(arg)?.checked_neg().ok_or_else(overflow),
            ExprKind::Chain { first, rest } => {
                let mut acc = self.int(first)?;
                for (op, op_span, x) in rest {
                    let v = self.int(x)?;
                    acc = match op {
                        BinOp::Add => acc.checked_add(v),
                        BinOp::Sub => acc.checked_sub(v),
                        BinOp::Mul => acc.checked_mul(v),
                        BinOp::Div => {
                            return Err(self.err(
                                *op_span,
                                format!("'/' is not allowed in an index ({RULE})"),
                            ));
                        }
                    }
                    .ok_or_else(overflow)?;
                }
                Ok(acc)
            }
            ExprKind::Pow { op_span, .. } => {
                Err(self.err(*op_span, format!("'^' is not allowed in an index ({RULE})")))
            }
            _ => Err(self.err(
                e.span,
                format!("index expression is not an integer: '{text}' ({RULE})"),
            )),
        }
    }

    fn power(&mut self, base: &'a Expr, exp: &'a Expr, op_span: Span) -> R<(NodeId, Info)> {
        let (b, bi) = self.value(base)?;
        let (x, xi) = self.value(exp)?;
        let (id, info) = match self.graph.as_const(x) {
            Some(a) if a.fract() == 0.0 && a.abs() <= MAX_POWI => (
                self.emit(Node::Powi(b, a as i32), op_span)?,
                bi.power(a, op_span, false),
            ),
            Some(a) => (
                self.emit(Node::Binary(Binary::Pow, b, x), op_span)?,
                bi.power(a, op_span, false),
            ),
            None => (
                self.emit(Node::Binary(Binary::Pow, b, x), op_span)?,
                bi.power_var(xi, op_span),
            ),
        };
        Ok((id, self.settle(id, info)))
    }

    fn arity(&self, name: &str, args: &[Expr], want: usize, span: Span) -> R<()> {
        if args.len() == want {
            return Ok(());
        }
        let s = if want == 1 { "" } else { "s" };
        Err(self.err(
            span,
            format!("{name} takes {want} argument{s}, got {}", args.len()),
        ))
    }

    /// The comparison of an `if` or `piecewise` condition, lowered.
    fn condition(&mut self, c: &'a Expr, of: &str) -> R<(Cmp, NodeId, NodeId)> {
        let ExprKind::Compare { op, lhs, rhs, .. } = &c.kind else {
            return Err(self.err(
                c.span,
                format!(
                    "a condition of {of} must be a comparison such as q1 < 0 (with <, <=, > or >=)"
                ),
            ));
        };
        let (a, _) = self.value(lhs)?;
        let (b, _) = self.value(rhs)?;
        Ok((*op, a, b))
    }

    /// `cmp(a, b) ? then : otherwise`, with the facts of the branch that was kept when the
    /// select folded away.
    fn select(
        &mut self,
        (cmp, a, b): (Cmp, NodeId, NodeId),
        (then, ti): (NodeId, Info),
        (otherwise, oi): (NodeId, Info),
        kind: SmoothnessLimit,
        name_span: Span,
        span: Span,
    ) -> R<(NodeId, Info)> {
        let id = self.emit(
            Node::Select {
                cmp,
                a,
                b,
                then,
                otherwise,
            },
            span,
        )?;
        let info = if id == then {
            ti
        } else if id == otherwise {
            oi
        } else {
            Info::select(kind, name_span, &[ti, oi])
        };
        Ok((id, self.settle(id, info)))
    }

    fn call(
        &mut self,
        e: &'a Expr,
        name: &str,
        name_span: Span,
        args: &'a [Expr],
    ) -> R<(NodeId, Info)> {
        let span = e.span;
        if is_function(name) && self.scope.tables.iter().any(|(n, _)| n == name) {
            return Err(self.err(
                name_span,
                format!("table '{name}' has the name of a built-in function; rename the table"),
            ));
        }
        if let Some(op) = Unary::named(name) {
            self.arity(name, args, 1, span)?;
            let (a, ai) = self.value(&args[0])?;
            let id = self.emit(Node::Unary(op, a), span)?;
            let info = match op.def().kinks {
                Some(kinks) => kinks(ai, name_span),
                None => ai.smooth_fn(op),
            };
            return Ok((id, self.settle(id, info)));
        }
        if let Some(op) = Binary::named(name) {
            self.arity(name, args, 2, span)?;
            let (a, ai) = self.value(&args[0])?;
            let (b, bi) = self.value(&args[1])?;
            let id = self.emit(Node::Binary(op, a, b), span)?;
            let kinks = op
                .def()
                .kinks
                .expect("a two-argument function a source calls has its kinks rule in ops.rs");
            let zero = [a, b].map(|x| self.graph.as_const(x) == Some(0.0));
            let info = kinks(ai, bi, name_span, zero);
            return Ok((id, self.settle(id, info)));
        }
        match name {
            "if" => {
                if args.len() != 3 {
                    return Err(self.err(
                        span,
                        format!(
                            "if takes 3 arguments (condition, value if true, value otherwise), got {}",
                            args.len()
                        ),
                    ));
                }
                let cond = self.condition(&args[0], "if")?;
                let then = self.value(&args[1])?;
                let otherwise = self.value(&args[2])?;
                return self.select(cond, then, otherwise, SmoothnessLimit::If, name_span, span);
            }
            "piecewise" => {
                if args.len() < 3 || args.len().is_multiple_of(2) {
                    return Err(self.err(
                        span,
                        format!(
                            "piecewise takes pairs of condition and value, then a default: piecewise(c1, v1, c2, v2, ..., default); got {} argument{}",
                            args.len(),
                            if args.len() == 1 { "" } else { "s" }
                        ),
                    ));
                }
                // Lowered in source order (so node origins follow the text), nested from the
                // end: piecewise(c1, v1, c2, v2, d) = if(c1, v1, if(c2, v2, d)).
                let mut pairs = Vec::with_capacity(args.len() / 2);
                for pair in args.chunks_exact(2) {
                    let cond = self.condition(&pair[0], "piecewise")?;
                    let v = self.value(&pair[1])?;
                    pairs.push((cond, v));
                }
                let mut acc = self.value(&args[args.len() - 1])?;
                for (cond, v) in pairs.into_iter().rev() {
                    acc = self.select(cond, v, acc, SmoothnessLimit::Piecewise, name_span, span)?;
                }
                return Ok(acc);
            }
            _ => {}
        }
        match self.meaning(name) {
            Meaning::Table(t) => {
                self.arity(name, args, 1, span)?;
                let (a, ai) = self.value(&args[0])?;
                let id = self.emit(
                    Node::Table {
                        table: t,
                        deriv: 0,
                        arg: a,
                    },
                    span,
                )?;
                Ok((id, self.settle(id, ai.table(t, name_span))))
            }
            Meaning::Param(_)
            | Meaning::Var(..)
            | Meaning::SumIndex(_)
            | Meaning::N
            | Meaning::Pi
            | Meaning::Time(_) => Err(self.err(
                name_span,
                format!("'{name}' is not a function (for a product write {name}*(...))"),
            )),
            _ => Err(self.err(
                name_span,
                format!(
                    "unknown function '{name}' (known: {}{})",
                    known(),
                    self.tables_note()
                ),
            )),
        }
    }

    fn sum(
        &mut self,
        e: &'a Expr,
        index: &'a str,
        index_span: Span,
        from: &'a Expr,
        to: &'a Expr,
        body: &'a Expr,
    ) -> R<(NodeId, Info)> {
        // Only this sum's own terms are recorded, not those of sums inside them.
        let record = self.recording.take();
        let clash = match self.meaning(index) {
            Meaning::Unknown => None,
            Meaning::SumIndex(_) => Some("the index of an enclosing sum".to_string()),
            Meaning::N | Meaning::Pi => Some(format!("the built-in '{index}'")),
            Meaning::Time(_) => Some(format!("the time '{index}'")),
            Meaning::Param(_) => Some(format!("the parameter '{index}'")),
            Meaning::Var(..) => Some(format!("the variable '{index}'")),
            Meaning::Family(_) => Some(format!("the variables '{index}'")),
            Meaning::Table(_) => Some(format!("the table '{index}'")),
            Meaning::Function => Some(format!("the function '{index}'")),
        };
        if let Some(what) = clash {
            return Err(self.err(
                index_span,
                format!("sum index '{index}' shadows {what}; choose another name"),
            ));
        }
        let a = self.int(from)?;
        let b = self.int(to)?;
        // Bounded before anything is built: a sum of more terms than the graph may hold nodes
        // is refused at once (a 36-byte `sum(i = 1..100000000, q1)` would otherwise allocate
        // a node per term until the limit, hundreds of megabytes, before being refused).
        let terms = i128::from(b) - i128::from(a) + 1;
        if terms > self.max_nodes as i128 {
            return Err(self.err(
                e.span,
                format!(
                    "sum over {terms} terms: an expression may expand to at most {} graph nodes \
                     (lattice sums over too many sites?)",
                    self.max_nodes
                ),
            ));
        }
        let free = self.any_free();
        if self.template.is_some() && free {
            // Its terms would be left out site by site of the enclosing loop.
            return Err(self.not_a_loop(e.span));
        }
        if let Some(looped) = self.sum_as_loop(e, index, (a, b), body)? {
            return Ok(looped);
        }
        let mut acc: Option<(NodeId, Info)> = None;
        let mut i = a;
        while i <= b {
            self.tick(e.span)?;
            self.sums.push((index, i));
            // An error ends the whole lowering, so the index need not be popped on that path.
            let exists = !free || self.term_exists(body)?;
            let term = if exists {
                // A nested sum records its own terms; any other body is one term.
                let nested = matches!(body.kind, ExprKind::Sum { .. });
                self.recording = record.filter(|_| nested);
                let term = self.value(body)?;
                self.recording = None;
                if let (Some(c), false) = (record, nested) {
                    self.parts.terms.push((term.0, c));
                }
                Some(term)
            } else {
                None
            };
            self.sums.pop();
            if let Some((t, ti)) = term {
                acc = Some(match acc {
                    None => (t, ti),
                    Some((s, si)) => {
                        let id = self.emit(Node::Binary(Binary::Add, s, t), e.span)?;
                        (id, self.settle(id, si.add(ti)))
                    }
                });
            }
            if i == i64::MAX {
                break;
            }
            i += 1;
        }
        match acc {
            Some(x) => Ok(x),
            None => self.constant(0.0, e.span),
        }
    }

    /// With free ends: whether the current term of the innermost sum refers only to sites
    /// inside `1..N` (else the term is left out). Checked before lowering the term, so a
    /// left-out term leaves no dead nodes in the graph. Inner sums decide for their own terms;
    /// an index that does not evaluate is left for lowering to report.
    fn term_exists(&self, e: &'a Expr) -> R<bool> {
        self.tick(e.span)?;
        match &e.kind {
            ExprKind::Sum { .. } => Ok(true),
            // On a square a single index names a site directly: no boundary, no left-out term
            // (lowering refuses one outside the lattice).
            ExprKind::Index { column: None, .. } if self.scope.shape != Shape::Chain => Ok(true),
            ExprKind::Index {
                name,
                index,
                column: None,
                ..
            } => {
                let len = match self.meaning(name) {
                    Meaning::Family(f) => f.len,
                    Meaning::Param(ParamValue::Array(v)) => v.len(),
                    _ => return Ok(true),
                };
                match self.int(index) {
                    Ok(k) => Ok(k >= 1 && (k as u64) <= len as u64),
                    Err(_) => Ok(true),
                }
            }
            ExprKind::Index {
                index,
                column: Some(column),
                ..
            } => {
                // Along a free axis only; the other axis walls or wraps.
                let Shape::Square { columns } = self.scope.shape else {
                    return Ok(true);
                };
                let inside = |e: &Expr, boundary: Boundary| {
                    boundary != Boundary::Free
                        || self
                            .int(e)
                            .map_or(true, |k| k >= 1 && (k as u64) <= self.scope.n as u64)
                };
                Ok(inside(index, self.scope.boundary) && inside(column, columns))
            }
            _ => {
                for c in e.children() {
                    if !self.term_exists(c)? {
                        return Ok(false);
                    }
                }
                Ok(true)
            }
        }
    }
}

/// `a, b, c`, or `none`.
fn list_or_none<S: std::borrow::Borrow<str>>(items: &[S]) -> String {
    if items.is_empty() {
        "none".to_string()
    } else {
        items.join(", ")
    }
}

fn cmp_symbol(c: Cmp) -> &'static str {
    match c {
        Cmp::Lt => "<",
        Cmp::Le => "<=",
        Cmp::Gt => ">",
        Cmp::Ge => ">=",
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::graph::Tabulated;
    use crate::testing::eval1;
    use std::sync::Arc;

    /// `U(x) = x^2/2 + x^3`, defined everywhere (a stand-in for a spline).
    #[derive(Debug)]
    struct Cubic;

    impl Tabulated for Cubic {
        fn eval(&self, deriv: u8, x: f64) -> f64 {
            match deriv {
                0 => x * x / 2.0 + x * x * x,
                1 => x + 3.0 * x * x,
                2 => 1.0 + 6.0 * x,
                _ => 6.0,
            }
        }
        fn name(&self) -> &str {
            "U"
        }
    }

    /// The value of `root` with the family `q` (argument 0) at `q`.
    fn eval(g: &Graph, root: NodeId, q: &[f64]) -> f64 {
        eval1(g, &[q], &[root])[0]
    }

    /// `t_0 + t_1 + ...` summed left to right, as a lattice sum is lowered (0 when empty).
    fn left_sum(terms: impl IntoIterator<Item = f64>) -> f64 {
        terms.into_iter().reduce(|acc, t| acc + t).unwrap_or(0.0)
    }

    /// Site `k` (1-based) of `q` with fixed ends: 0 at the walls beyond `1..=q.len()`.
    fn walled(q: &[f64], k: usize) -> f64 {
        if (1..=q.len()).contains(&k) {
            q[k - 1]
        } else {
            0.0
        }
    }

    /// Everything a test needs to lower: the family `q` of length `n`, parameters, the table
    /// `U` registered in the graph.
    struct Setup {
        families: Vec<Family>,
        params: BTreeMap<String, ParamValue>,
        tables: Vec<(String, u32)>,
        graph: Graph,
        n: usize,
        boundary: Boundary,
        shape: Shape,
    }

    impl Setup {
        /// An `n x n` square lattice, `boundary` along `i` and `columns` along `j`.
        fn square(n: usize, boundary: Boundary, columns: Boundary) -> Self {
            let mut s = Self::new(n * n, boundary);
            s.n = n;
            s.shape = Shape::Square { columns };
            s
        }

        fn new(n: usize, boundary: Boundary) -> Self {
            let mut graph = Graph::new();
            let u = graph.add_table(Arc::new(Cubic));
            Self {
                families: vec![Family {
                    name: "q".into(),
                    len: n,
                    arg: 0,
                    offset: 0,
                }],
                params: BTreeMap::new(),
                tables: vec![("U".into(), u)],
                graph,
                n,
                boundary,
                shape: Shape::Chain,
            }
        }

        fn param(mut self, name: &str, v: f64) -> Self {
            self.params.insert(name.into(), ParamValue::Scalar(v));
            self
        }

        fn array(mut self, name: &str, v: Vec<f64>) -> Self {
            self.params.insert(name.into(), ParamValue::Array(v));
            self
        }

        /// The scope to lower in, and the graph to lower into.
        fn parts(&mut self) -> (Scope<'_>, &mut Graph) {
            let scope = Scope {
                families: &self.families,
                params: &self.params,
                tables: &self.tables,
                n: self.n,
                boundary: self.boundary,
                shape: self.shape,
                time: None,
            };
            (scope, &mut self.graph)
        }

        fn lower(&mut self, src: &str) -> Result<Lowered, ExprError> {
            let (scope, graph) = self.parts();
            lower(src, &scope, graph)
        }

        fn ok(&mut self, src: &str) -> Lowered {
            self.lower(src).unwrap_or_else(|e| panic!("{src}:\n{e}"))
        }

        fn err(&mut self, src: &str) -> ExprError {
            match self.lower(src) {
                Ok(_) => panic!("{src} lowered without error"),
                Err(e) => e,
            }
        }
    }

    /// Test coordinates: distinct, irregular, of both signs.
    fn coords(n: usize) -> Vec<f64> {
        (0..n)
            .map(|k| 0.3 * (k as f64 + 1.0).sin() + 0.01 * k as f64)
            .collect()
    }

    fn same(a: f64, b: f64, what: &str) {
        assert_eq!(a.to_bits(), b.to_bits(), "{what}: {a} vs {b}");
    }

    /// `q[i, j]` is entry `(i - 1) N + j`; past an edge each axis follows its own boundary:
    /// rows wrap (periodic along `i`), columns end at walls (fixed along `j`), and with free
    /// columns a term reaching past an edge is left out. Array parameters are read the same
    /// way, and `N` is the side.
    #[test]
    fn a_square_s_sites_are_read_row_by_row_with_a_boundary_per_axis() {
        let n = 3;
        let q = coords(n * n);
        let at = |i: usize, j: usize| q[(i - 1) * n + j - 1];
        let mut s = Setup::square(n, Boundary::Periodic, Boundary::Fixed);
        let l = s.ok("sum(i = 1..N, sum(j = 1..N, (10*i + j)*q[i, j]))");
        let want = (1..=n)
            .flat_map(|i| (1..=n).map(move |j| (i, j)))
            .map(|(i, j)| (10 * i + j) as f64 * at(i, j));
        assert!((eval(&s.graph, l.root, &q) - want.sum::<f64>()).abs() < 1e-14);
        // The row past the last wraps to the first; the column past the last is a wall.
        let l = s.ok("q[N+1, 2] + 100*q[2, N+1] + 1000*q[0, 1]");
        same(
            eval(&s.graph, l.root, &q),
            at(1, 2) + 100.0 * 0.0 + 1000.0 * at(n, 1),
            "wrap and wall",
        );
        // Free columns: the bond past the last column is left out, the others stay.
        let mut s = Setup::square(n, Boundary::Fixed, Boundary::Free);
        let l = s.ok("sum(i = 1..N, sum(j = 1..N, (q[i, j+1] - q[i, j])^2))");
        let want: f64 = (1..=n)
            .flat_map(|i| (1..n).map(move |j| (i, j)))
            .map(|(i, j)| (at(i, j + 1) - at(i, j)).powi(2))
            .sum();
        assert!((eval(&s.graph, l.root, &q) - want).abs() < 1e-14);
        // An array parameter has one entry per site, read by row and column.
        let eps: Vec<f64> = (0..n * n).map(|k| k as f64 + 0.5).collect();
        let mut s = Setup::square(n, Boundary::Fixed, Boundary::Fixed).array("eps", eps);
        let l = s.ok("eps[2, 3]*q[2, 3] + q[9]");
        same(
            eval(&s.graph, l.root, &q),
            5.5 * at(2, 3) + at(3, 3),
            "eps and q9",
        );
    }

    #[test]
    fn square_indices_are_refused_where_they_mean_nothing() {
        let mut chain = Setup::new(4, Boundary::Fixed);
        let e = chain.err("q[1, 2]");
        assert!(e.message.contains("square lattice"), "{}", e.message);
        let mut s = Setup::square(3, Boundary::Fixed, Boundary::Fixed).array("eps", vec![1.0; 9]);
        for (src, says) in [
            ("q[10]", "single index"),
            ("q[0]", "single index"),
            ("eps[0, 1]", "no parameters beyond the walls"),
            ("q[1, 2, 3]", "expected ']'"),
            ("beta[1, 2]", "unknown name"),
        ] {
            let e = s.err(src);
            assert!(e.message.contains(says), "{src}: {}", e.message);
        }
        let mut s = Setup::square(3, Boundary::Free, Boundary::Fixed);
        let e = s.err("q[4, 1]");
        assert!(e.message.contains("free ends"), "{}", e.message);
        let mut s = Setup::square(2, Boundary::Fixed, Boundary::Fixed).array("eps", vec![1.0; 3]);
        let e = s.err("eps[1, 1]");
        assert!(
            e.message.contains("2 x 2 lattice has 4 sites"),
            "{}",
            e.message
        );
    }

    /// A root that adds lattice sums is recorded as their terms (those of nested sums one by
    /// one) and its other parts, with their signs; the graph is the one `value` builds.
    #[test]
    fn a_sum_of_sums_is_recorded_term_by_term() {
        let src = "sum(i = 1..N, sum(j = 1..N, q[i, j]^2)) - 2*q1 + sum(i = 1..N, q[i, 1]*q[i, 2]) \
                   - 0.5*sum(i = 1..N, q[i, 3]) + sum(j = 1..N, q[1, j])/4";
        let mut s = Setup::square(3, Boundary::Fixed, Boundary::Fixed);
        let l = s.ok(src);
        assert_eq!(l.parts.terms.len(), 9 + 3 + 3 + 3);
        let coefficients: Vec<f64> = l.parts.terms.iter().map(|t| t.1).collect();
        assert_eq!(
            coefficients[9..],
            [1.0, 1.0, 1.0, -0.5, -0.5, -0.5, 0.25, 0.25, 0.25]
        );
        assert_eq!(l.parts.rest.len(), 1);
        assert_eq!(l.parts.rest[0].1, -1.0);
        let q = coords(9);
        let mut total = 0.0;
        for &(id, c) in l.parts.terms.iter().chain(&l.parts.rest) {
            total += c * eval(&s.graph, id, &q);
        }
        assert!((total - eval(&s.graph, l.root, &q)).abs() < 1e-14);
        // The same nodes as lowering the expression as one value (inside a product, so not
        // a root chain; `x * 1` folds to `x`, the `1` a node after the others): in two fresh
        // graphs, the same root id means the same nodes up to it, built in the same order.
        let mut fresh = Setup::square(3, Boundary::Fixed, Boundary::Fixed);
        let wrapped = fresh.ok(&format!("({src})*1"));
        assert!(wrapped.parts.terms.is_empty());
        assert_eq!(wrapped.root, l.root);
        assert_eq!(
            fresh.graph.nodes()[..=l.root as usize],
            s.graph.nodes()[..=l.root as usize]
        );
    }

    #[test]
    fn henon_heiles_is_the_hand_written_formula() {
        let mut s = Setup::new(2, Boundary::Free);
        let l = s.ok("(q1^2 + q2^2)/2 + q1^2*q2 - q2^3/3");
        let [x, y] = [0.3, -0.7];
        let want = (x * x + y * y) / 2.0 + x * x * y - y * y * y / 3.0;
        same(eval(&s.graph, l.root, &[x, y]), want, "HH");
        assert!(l.smoothness.is_smooth());
        // q2^3 is a Powi node, exactly q2*q2*q2.
        assert!(
            s.graph
                .nodes()
                .contains(&Node::Powi(s.graph.clone().input(0, 1), 3))
        );
    }

    #[test]
    fn fput_beta_fixed_ends() {
        let n = 6;
        let beta = 1.3;
        let mut s = Setup::new(n, Boundary::Fixed).param("beta", beta);
        let l = s.ok("sum(i = 0..N, (q[i+1]-q[i])^2/2 + beta/4*(q[i+1]-q[i])^4)");
        let q = coords(n);
        let want = left_sum((0..=n).map(|i| {
            let d = walled(&q, i + 1) - walled(&q, i);
            d * d / 2.0 + beta / 4.0 * (d * d * d * d)
        }));
        same(eval(&s.graph, l.root, &q), want, "FPUT");
        assert!(l.smoothness.is_smooth());
        assert_eq!(dead_operations(&s.graph, l.root), 0);
    }

    #[test]
    fn klein_gordon_free_ends_leaves_out_the_missing_bond() {
        let n = 5;
        let k = vec![1.1, 0.9, 1.4, 0.7, 1.2];
        let w = 4.0;
        let mut s = Setup::new(n, Boundary::Free)
            .array("k", k.clone())
            .param("W", w);
        let l = s.ok(
            "sum(i = 1..N, k[i]/2*q[i]^2 + q[i]^4/4)\n  + sum(i = 1..N, (q[i+1]-q[i])^2/(2*W))",
        );
        let q = coords(n);
        let onsite =
            left_sum((0..n).map(|i| k[i] / 2.0 * (q[i] * q[i]) + q[i] * q[i] * q[i] * q[i] / 4.0));
        let bonds = left_sum((0..n - 1).map(|i| {
            let d = q[i + 1] - q[i];
            d * d / (2.0 * w)
        }));
        same(eval(&s.graph, l.root, &q), onsite + bonds, "KG");
        // The left-out term i = N was never lowered: every operation is used.
        assert_eq!(dead_operations(&s.graph, l.root), 0);
    }

    /// Non-constant nodes the root does not depend on (constants folded away are expected).
    fn dead_operations(g: &Graph, root: NodeId) -> usize {
        let mut live = vec![false; g.len()];
        live[root as usize] = true;
        for k in (0..g.len()).rev() {
            if live[k] {
                for o in g.node(k as NodeId).operands() {
                    live[o as usize] = true;
                }
            }
        }
        g.nodes()
            .iter()
            .zip(&live)
            .filter(|(n, l)| !**l && !matches!(n, Node::Const(_)))
            .count()
    }

    #[test]
    fn toda_periodic_wraps() {
        let n = 4;
        let mut s = Setup::new(n, Boundary::Periodic);
        let l = s.ok("sum(i = 1..N, exp(q[i+1]-q[i]) - (q[i+1]-q[i]) - 1)");
        let q = coords(n);
        let want = left_sum((0..n).map(|i| {
            let d = q[(i + 1) % n] - q[i];
            d.exp() - d - 1.0
        }));
        same(eval(&s.graph, l.root, &q), want, "Toda");
        assert!(l.smoothness.is_smooth());
        // q[0] is q[N], array parameters wrap too.
        let mut s = Setup::new(3, Boundary::Periodic).array("m", vec![1.0, 2.0, 3.0]);
        let l = s.ok("q[0] * m[4] + m[-3]");
        same(
            eval(&s.graph, l.root, &[5.0, 6.0, 7.0]),
            7.0 * 1.0 + 3.0,
            "wrap",
        );
    }

    #[test]
    fn morse_chain() {
        let n = 5;
        let (d0, a) = (2.0, 0.8);
        let mut s = Setup::new(n, Boundary::Fixed).param("D", d0).param("a", a);
        let l = s.ok("sum(i = 1..N-1, D*(1 - exp(-a*(q[i+1]-q[i])))^2)");
        let q = coords(n);
        let want = left_sum((0..n - 1).map(|i| {
            let e = 1.0 - (-a * (q[i + 1] - q[i])).exp();
            d0 * (e * e)
        }));
        same(eval(&s.graph, l.root, &q), want, "Morse");
        assert!(l.smoothness.is_smooth());
    }

    #[test]
    fn hertz_chain_is_c2_and_passes_the_variational_method() {
        let n = 5;
        let (amp, delta0) = (1.5, 0.2);
        let mut s = Setup::new(n, Boundary::Fixed)
            .param("A", amp)
            .param("delta0", delta0);
        let src = "sum(i = 0..N, A*max(0, delta0 - (q[i+1]-q[i]))^(5/2))";
        let l = s.ok(src);
        let q = coords(n);
        let want = left_sum((0..=n).map(|i| {
            let d = Graph::apply_binary(
                Binary::Max,
                0.0,
                delta0 - (walled(&q, i + 1) - walled(&q, i)),
            );
            amp * d.powf(2.5)
        }));
        same(eval(&s.graph, l.root, &q), want, "Hertz");
        assert!(
            s.graph
                .nodes()
                .iter()
                .any(|n| matches!(n, Node::Binary(Binary::Pow, _, _)))
        );
        let sm = &l.smoothness;
        assert_eq!(sm.order, 2);
        let lim = sm.limited_by.as_ref().unwrap();
        assert_eq!(lim.operation, "^ 2.5");
        assert_eq!((lim.line, lim.column), (1, src.find('^').unwrap() + 1));
        sm.require(2, "the variational method (vm)").unwrap();
        let e = sm.require(3, "a third-order method").unwrap_err();
        assert!(e.contains("'^ 2.5' at line 1, column 47"), "{e}");
    }

    #[test]
    fn tabulated_bond() {
        let n = 4;
        let mut s = Setup::new(n, Boundary::Fixed);
        let src = "sum(i = 0..N, U(q[i+1]-q[i]))";
        let l = s.ok(src);
        let q = coords(n);
        let want = left_sum((0..=n).map(|i| Cubic.eval(0, walled(&q, i + 1) - walled(&q, i))));
        same(eval(&s.graph, l.root, &q), want, "table");
        let lim = l.smoothness.limited_by.as_ref().unwrap();
        assert_eq!((l.smoothness.order, lim.operation.as_str()), (2, "U"));
        assert_eq!((lim.line, lim.column, lim.order), (1, 15, 2));
        assert!(lim.reason.contains("cubic spline"));
        l.smoothness.require(2, "vm").unwrap();
    }

    #[test]
    fn rounding_order_and_node_kinds() {
        let mut s = Setup::new(3, Boundary::Fixed);
        let q = [0.1, 0.2, 0.3];
        let l = s.ok("q1 + q2 + q3");
        same(eval(&s.graph, l.root, &q), (0.1 + 0.2) + 0.3, "left fold");
        let l = s.ok("q1 * q2 * q3 / q2");
        same(
            eval(&s.graph, l.root, &q),
            ((0.1 * 0.2) * 0.3) / 0.2,
            "left fold *",
        );
        let l = s.ok("2^3^2");
        assert_eq!(s.graph.as_const(l.root), Some(512.0));
        let l = s.ok("-q1^2");
        same(eval(&s.graph, l.root, &q), -(0.1 * 0.1), "-x^2");
        let l = s.ok("q1**(4/2) + q2^N + q3^-1");
        same(
            eval(&s.graph, l.root, &q),
            0.1 * 0.1 + 0.2 * 0.2 * 0.2 + 1.0 / 0.3,
            "whole powers",
        );
        let l = s.ok("q1^0.5");
        assert!(matches!(
            s.graph.node(l.root),
            Node::Binary(Binary::Pow, _, _)
        ));
        let l = s.ok("sum(i = 1..N, i*q[i]^2) + pi + sum(i = 3..1, q[i])");
        same(
            eval(&s.graph, l.root, &q),
            ((1.0 * (0.1 * 0.1) + 2.0 * (0.2 * 0.2)) + 3.0 * (0.3 * 0.3)) + std::f64::consts::PI,
            "index as a number, empty sum",
        );
        let l = s.ok("sum(i = 1..2, sum(j = i..N, q[i]*q[j]))");
        same(
            eval(&s.graph, l.root, &q),
            ((0.1 * 0.1 + 0.1 * 0.2) + 0.1 * 0.3) + (0.2 * 0.2 + 0.2 * 0.3),
            "nested sums",
        );
        let l = s.ok("q[2*2-1] + q[N] + q[N+1] + q[0]");
        same(
            eval(&s.graph, l.root, &q),
            0.3 + 0.3,
            "index arithmetic, walls",
        );
        let l =
            s.ok("if(q1 < q2, atan2(q1, q2), min(q1, q3)) + piecewise(q1 > 1, 1, q1 >= 0, 2, 3)");
        same(
            eval(&s.graph, l.root, &q),
            0.1f64.atan2(0.2) + 2.0,
            "if, piecewise",
        );
        let l = s.ok("sqrt(q1) + exp(q1) + log(q1) + sin(q1) + cos(q1) + tan(q1) + atan(q1) + tanh(q1) + cosh(q1) + sinh(q1) + abs(q1) + step(q1) + sign(q1) + max(q1, q2)");
        let x: f64 = 0.1;
        let want = x.sqrt()
            + x.exp()
            + x.ln()
            + x.sin()
            + x.cos()
            + x.tan()
            + x.atan()
            + x.tanh()
            + x.cosh()
            + x.sinh()
            + x.abs()
            + 1.0
            + 1.0
            + 0.2;
        same(eval(&s.graph, l.root, &q), want, "functions");
    }

    #[test]
    fn origins_point_at_the_operation() {
        let mut s = Setup::new(2, Boundary::Fixed);
        let src = "q1 + 2 *\n  log(q2 - 3)";
        let l = s.ok(src);
        let log = s
            .graph
            .nodes()
            .iter()
            .position(|n| matches!(n, Node::Unary(Unary::Log, _)))
            .unwrap() as NodeId;
        let span = l.origins[&log];
        let e = ExprError::new(src, span, "log of a negative number");
        assert_eq!((e.line, e.column), (2, 3));
        assert_eq!(&src[span.start..span.end], "log(q2 - 3)");
        assert_eq!(l.origins.len(), s.graph.len(), "every node has an origin");
    }

    /// (source, expected message part, line, column)
    fn check_errors(s: &mut Setup, cases: &[(&str, &str, usize, usize)]) {
        let mut wrong = Vec::new();
        for &(src, msg, line, column) in cases {
            let e = s.err(src);
            if !e.message.contains(msg) || (e.line, e.column) != (line, column) {
                wrong.push(format!("{src:?}: want {line}:{column} {msg:?}, got {e}"));
            }
            assert!(e.to_string().starts_with(&e.one_line()));
        }
        assert!(wrong.is_empty(), "{}", wrong.join("\n"));
    }

    #[test]
    fn name_errors() {
        let mut s = Setup::new(5, Boundary::Fixed)
            .param("beta", 1.0)
            .array("k", vec![1.0; 5]);
        check_errors(
            &mut s,
            &[
                (
                    "q1 + r",
                    "unknown name 'r' (variables: q1..q5 or q[i]; parameters: beta, k; tables: U)",
                    1,
                    6,
                ),
                (
                    "1 + sinn(q1)",
                    "unknown function 'sinn' (known: sqrt, exp,",
                    1,
                    5,
                ),
                ("max(q1)", "max takes 2 arguments, got 1", 1, 1),
                ("q1 + sin(q1, q2)", "sin takes 1 argument, got 2", 1, 6),
                ("U(q1, q2)", "U takes 1 argument, got 2", 1, 1),
                ("if(q1 < 0, 1)", "if takes 3 arguments", 1, 1),
                ("piecewise(q1 < 0, 1, 2, 3)", "piecewise takes pairs", 1, 1),
                ("if(q1, 1, 2)", "must be a comparison", 1, 4),
                (
                    "q1 + (q2 < 1)",
                    "only allowed as the condition of if",
                    1,
                    10,
                ),
                (
                    "max(q1 < 1, 2)",
                    "only allowed as the condition of if",
                    1,
                    8,
                ),
                ("q7", "variable 'q7' does not exist: N = 5 (q1..q5)", 1, 1),
                ("q0", "variable 'q0' does not exist", 1, 1),
                ("2 * q", "'q' is a family of variables", 1, 5),
                ("k", "parameter 'k' is an array", 1, 1),
                ("beta[1]", "'beta' is a scalar parameter", 1, 1),
                (
                    "k[6]",
                    "index 6 of the array parameter 'k' is outside 1..5",
                    1,
                    1,
                ),
                ("sum(i = 1..N, k[i+1])", "outside 1..5", 1, 15),
                ("q[1.5]", "index expression is not an integer: '1.5'", 1, 3),
                ("q[beta]", "'beta' is a parameter", 1, 3),
                ("q[N/2]", "'/' is not allowed in an index", 1, 4),
                (
                    "sum(i = 1..N/2, q[i])",
                    "'/' is not allowed in an index",
                    1,
                    13,
                ),
                (
                    "sum(beta = 1..N, q[beta])",
                    "sum index 'beta' shadows the parameter",
                    1,
                    5,
                ),
                (
                    "sum(i = 1..N, sum(i = 1..N, q[i]))",
                    "shadows the index of an enclosing",
                    1,
                    19,
                ),
                ("sum(q = 1..N, 1)", "shadows the variables 'q'", 1, 5),
                ("sum(N = 1..3, 1)", "shadows the built-in 'N'", 1, 5),
                ("i + sum(i = 1..N, q[i])", "unknown name 'i'", 1, 1),
                (
                    "q[i] + 1",
                    "a sum index exists only inside sum(i = a..b, term)",
                    1,
                    3,
                ),
                (
                    "sum(i = 1..N,\n    q[i] * j)",
                    "unknown name 'j' (variables: q1..q5 or q[i]; parameters: beta, k; sum indices: i",
                    2,
                    12,
                ),
                (
                    "beta(q1 + q2)",
                    "'beta' is not a function (for a product write beta*(...))",
                    1,
                    1,
                ),
                ("sin", "'sin' is a function", 1, 1),
                ("U", "'U' is a tabulated function", 1, 1),
                ("sum + 1", "'sum' needs a range", 1, 1),
                ("q[3000000000 * 3000000000 * 3]", "overflows", 1, 3),
                ("q[1e300]", "index '1e300' is too large", 1, 3),
                (
                    "q1 +\n   q2 +\n      sinn(q3)",
                    "unknown function 'sinn'",
                    3,
                    7,
                ),
            ],
        );
    }

    #[test]
    fn boundary_errors_and_free_ends() {
        let mut free = Setup::new(3, Boundary::Free).array("m", vec![1.0, 2.0, 3.0]);
        check_errors(
            &mut free,
            &[
                ("q[4]", "with free ends there is no site there", 1, 1),
                ("q1 + m[0]", "index 0 of 'm' is outside 1..3", 1, 6),
            ],
        );
        // Every term refers outside: the sum is 0; parameters drop out like variables.
        let l = free.ok("sum(i = 3..5, q[i+1]) + sum(i = 1..N, m[i+1]*q[i])");
        same(
            eval(&free.graph, l.root, &[1.0, 10.0, 100.0]),
            2.0 * 1.0 + 3.0 * 10.0,
            "free",
        );
        // Only the innermost sum's term is left out.
        let l = free.ok("sum(i = 1..N, q[i] * (1 + sum(j = 1..1, q[i+1])))");
        let q = [1.0, 10.0, 100.0];
        same(
            eval(&free.graph, l.root, &q),
            (1.0 * (1.0 + 10.0) + 10.0 * (1.0 + 100.0)) + 100.0 * 1.0,
            "innermost",
        );
        let mut periodic = Setup::new(0, Boundary::Periodic);
        check_errors(&mut periodic, &[("q[1]", "'q' has no entries", 1, 1)]);
    }

    #[test]
    fn boundary_names_and_table_clashes() {
        assert_eq!(Boundary::from_name("free"), Ok(Boundary::Free));
        assert_eq!(Boundary::from_name("periodic"), Ok(Boundary::Periodic));
        assert_eq!(
            Boundary::from_name("fixed").map(Boundary::name),
            Ok("fixed")
        );
        assert!(
            Boundary::from_name("open")
                .unwrap_err()
                .contains("fixed, periodic, free")
        );
        let mut s = Setup::new(2, Boundary::Fixed);
        s.tables.push(("exp".into(), 0));
        check_errors(
            &mut s,
            &[(
                "q1 + exp(q2)",
                "table 'exp' has the name of a built-in",
                1,
                6,
            )],
        );
        s.tables.push(("V".into(), 7));
        check_errors(
            &mut s,
            &[("V(q1)", "table index 7 is not registered", 1, 1)],
        );
    }

    #[test]
    fn parameter_checks() {
        let mut s = Setup::new(5, Boundary::Fixed)
            .array("k", vec![1.0; 4])
            .array("m", vec![1.0, 2.0, f64::NAN, 4.0, 5.0])
            .param("g", f64::INFINITY)
            .param("q2", 1.0)
            .param("ok", 1.0);
        check_errors(
            &mut s,
            &[
                (
                    "q1 + sum(i = 1..N, k[i])",
                    "parameter 'k' has 4 entries but N = 5",
                    1,
                    20,
                ),
                (
                    "m[1]",
                    "parameter 'm' entry 3 is not a finite number (NaN)",
                    1,
                    1,
                ),
                ("ok * g", "parameter 'g' is not a finite number (inf)", 1, 6),
                ("q2", "parameter 'q2' has the name of a variable", 1, 1),
            ],
        );
        // Unused parameters are not checked.
        s.ok("ok * q1");
        let mut s = Setup::new(5, Boundary::Fixed).param("N", 3.0);
        check_errors(
            &mut s,
            &[("q1 * N", "parameter 'N' has the name of the built-in", 1, 6)],
        );
    }

    #[test]
    fn size_limits() {
        let limited = |boundary, src: &str| {
            let mut s = Setup::new(5, boundary);
            let (scope, graph) = s.parts();
            on_big_stack(|| lower_limited(src, &scope, graph, 10_000, 50_000, false)).unwrap_err()
        };
        let e = limited(
            Boundary::Fixed,
            "sum(i = 1..1000, sum(j = 1..1000, q1*i*j))",
        );
        assert!(e.message.contains("more than 10000 graph nodes"), "{e}");
        assert_eq!((e.line, e.column), (1, 39), "the product that overflowed");
        // A sum of more terms than the graph may hold is refused before its first term (even
        // one that folds to a constant), naming the sum.
        let e = limited(Boundary::Fixed, "sum(i = 1..1000000000000, 0)");
        assert!(
            e.message.contains(
                "sum over 1000000000000 terms: an expression may expand to at most 10000"
            ),
            "{e}"
        );
        assert_eq!((e.line, e.column), (1, 1));
        let e = limited(Boundary::Free, "sum(i = 10..9000000000000000, q[i])");
        assert!(e.message.contains("sum over 8999999999999991 terms"), "{e}");
        let e = limited(
            Boundary::Fixed,
            "sum(i = -9000000000000000..9000000000000000, 0)",
        );
        assert!(
            e.message.contains("sum over 18000000000000001 terms"),
            "{e}"
        );
        // Sums of fewer terms each that fold to constants are bounded by the operations.
        let e = limited(Boundary::Fixed, "sum(i = 1..10000, sum(j = 1..10000, 0))");
        assert!(e.message.contains("more than 50000 operations"), "{e}");
        // Checking whether a term exists and evaluating indices count too.
        let long = "q1 + ".repeat(1000);
        let e = limited(Boundary::Free, &format!("sum(i = 10..1000, {long}q[i])"));
        assert!(e.message.contains("operations"), "{e}");
        let long = vec!["1"; 1000].join(" + ");
        let e = limited(Boundary::Fixed, &format!("sum(i = 10..1000, q[{long}])"));
        assert!(e.message.contains("operations"), "{e}");
    }

    #[test]
    fn fput_with_a_thousand_sites_stays_small() {
        let n = 1001;
        let mut s = Setup::new(n, Boundary::Fixed).param("beta", 1.0);
        let l = s.ok("sum(i = 0..N, (q[i+1]-q[i])^2/2 + beta/4*(q[i+1]-q[i])^4)");
        // Per bond: the difference, its square, /2, its fourth power, *beta/4, the term's
        // sum, and the fold's add; the input; plus a few constants.
        let nodes = s.graph.len();
        assert!(nodes > 6 * n && nodes < 9 * n, "{nodes} nodes");
        let q = coords(n);
        assert!(eval(&s.graph, l.root, &q).is_finite());
    }

    #[test]
    fn smoothness_rules() {
        let mut s = Setup::new(3, Boundary::Fixed)
            .param("d0", 0.5)
            .param("p", 2.0);
        // Order (i64::MAX when smooth), and the limiting operation and its column.
        type Expect = (i64, Option<(String, usize)>);
        let order = |s: &mut Setup, src: &str| -> Expect {
            let l = s.ok(src);
            let sm = l.smoothness;
            match sm.limited_by {
                None => {
                    assert_eq!(sm.order, u32::MAX);
                    (i64::MAX, None)
                }
                Some(l) => {
                    assert_eq!(sm.order, u32::try_from(l.order).unwrap_or(0));
                    (i64::from(l.order), Some((l.operation, l.column)))
                }
            }
        };
        let smooth = (i64::MAX, None);
        let at = |k: i64, op: &str, col: usize| (k, Some((op.to_string(), col)));
        let cases: Vec<(&str, Expect)> = vec![
            (
                "q1^2 + exp(q2) * sin(q3) / cosh(q1) - atan(q2) + tanh(q3) + sinh(q1) + cos(q2)",
                smooth.clone(),
            ),
            ("abs(q1)", at(0, "abs", 1)),
            ("q2 + abs(q1)", at(0, "abs", 6)),
            ("step(q1)", at(-1, "step", 1)),
            ("sign(q1) + abs(q2)", at(-1, "sign", 1)),
            ("abs(q2) + step(q1)", at(-1, "step", 11)),
            ("abs(q1) + max(q1, q2)", at(0, "abs", 1)),
            ("if(q1 < 0, q1, q2)", at(-1, "if", 1)),
            (
                "piecewise(q1 < 0, q1, q2 > 1, 1, q2)",
                at(-1, "piecewise", 1),
            ),
            ("sqrt(q1^2+q2^2)", at(0, "sqrt", 1)),
            ("sqrt(1+q1^2)", smooth.clone()),
            ("(q1^2 + d0)^0.5", smooth.clone()),
            ("(exp(q1) + q2^2)^(1/3)", smooth.clone()),
            ("max(0, d0 - q1)^(5/2)", at(2, "^ 2.5", 16)),
            ("max(0, d0 - q1)^2", at(1, "^ 2", 16)),
            ("(d0*min(q1 - d0, 0))^3", at(2, "^ 3", 21)),
            ("abs(q1)^p", at(1, "^ 2", 8)),
            ("max(q1, q2)^2", at(0, "max", 1)),
            ("max(0, abs(q1))^2", at(0, "max", 1)),
            ("(q1^2 + q2^2)^(3/2)", at(1, "^ 1.5", 14)),
            ("q1^(1/2)", at(0, "^ 0.5", 3)),
            (
                "1/q1 + log(q2) + q3^-2 + q1^(-1/2) + tan(q1)",
                smooth.clone(),
            ),
            ("q1^q2", at(0, "^", 3)),
            ("exp(q1)^q2", smooth.clone()),
            ("U(q1) + abs(q2)", at(0, "abs", 9)),
            ("U(q1)", at(2, "U", 1)),
            ("atan2(q1, q2)", at(-1, "atan2", 1)),
            (
                "abs(d0) + step(d0 - 1) + if(N > 2, q1, abs(q1))",
                smooth.clone(),
            ),
            ("if(q1 < 0, q2, q2)", smooth.clone()),
            ("sqrt(abs(q1))", at(0, "sqrt", 1)),
            ("sqrt(step(q1))", at(-1, "step", 6)),
            // Every spelling of a Newtonian pole is a pole (module documentation of smooth).
            ("-2/sqrt((q3-q1)^2 + (q2-q1)^2)", smooth.clone()),
            ("(q1^2 + q2^2)^(-1/2)", smooth.clone()),
            ("1/sqrt(q1^2 + q2^2)^3", smooth.clone()),
            ("(q1^2 + q2^2)^(-3/2)", smooth.clone()),
            ("1/(sqrt(q1^2 + q2^2)*(q1^2 + q2^2))", smooth.clone()),
            ("sqrt(q1^2 + q2^2)^-1", smooth.clone()),
            ("p*d0/(2*sqrt(q1^2 + q2^2))", smooth.clone()),
            (
                "-1/sqrt(q1^2 + q2^2) - p/sqrt((q1 - q3)^2 + q2^2)",
                smooth.clone(),
            ),
            ("(1 + q3^2)/sqrt(q1^2) + exp(q2)/abs(q3)", smooth.clone()),
            (
                "1/sqrt(abs(q1)) + 1/max(0, q2)^2 + sqrt(1/sqrt(q1^2))",
                smooth.clone(),
            ),
            ("1/sin(sqrt(q1^2 + q2^2))", smooth.clone()),
            // A state-dependent factor that may be 0 can undo the pole: x/|x| jumps.
            ("q1/sqrt(q1^2)", at(0, "sqrt", 4)),
            ("q1*(q1^2)^(-1/2)", at(0, "^ 0.5", 10)),
            ("q1^2/sqrt(q1^2 + q2^2)", at(0, "sqrt", 6)),
            ("1/sqrt(q1^2) + sqrt(q1^2)", at(0, "sqrt", 16)),
            ("sin(1/abs(q1))", at(0, "abs", 7)),
            ("1/(1/sqrt(q1^2 + q2^2))", at(0, "sqrt", 6)),
            ("1/(1 + sqrt(q1^2 + q2^2))", at(0, "sqrt", 8)),
            ("1/(sqrt(q1^2 + q2^2) + q3^2)", at(0, "sqrt", 4)),
        ];
        let wrong: Vec<String> = cases
            .into_iter()
            .filter_map(|(src, want)| {
                let got = order(&mut s, src);
                (got != want).then(|| format!("{src}: got {got:?}, want {want:?}"))
            })
            .collect();
        assert!(wrong.is_empty(), "{}", wrong.join("\n"));
        let l = s.ok("q2 + abs(q1)");
        assert_eq!(
            l.smoothness
                .require(2, "the variational method (vm)")
                .unwrap_err(),
            "the variational method (vm) needs continuous second derivatives, but 'abs' at line 1, column 6 has a kink (continuous, first derivative jumps); use mpm"
        );
        l.smoothness.require(0, "x").unwrap();
        let l = s.ok("step(q1)");
        let e = l.smoothness.require(1, "the forces").unwrap_err();
        assert!(e.contains("'step' at line 1, column 1 jumps"), "{e}");
        assert!(!e.contains("mpm"));
        assert!(l.smoothness.require(0, "x").is_err());
    }

    /// A small deterministic generator (no dependency for one test).
    struct Rng(u64);

    impl Rng {
        fn next(&mut self) -> u64 {
            self.0 ^= self.0 << 13;
            self.0 ^= self.0 >> 7;
            self.0 ^= self.0 << 17;
            self.0
        }
        fn below(&mut self, n: usize) -> usize {
            (self.next() % n as u64) as usize
        }
    }

    #[test]
    fn garbage_never_panics() {
        let seeds = [
            "(q1^2 + q2^2)/2 + q1^2*q2 - q2^3/3",
            "sum(i = 0..N, (q[i+1]-q[i])^2/2 + beta/4*(q[i+1]-q[i])^4)",
            "sum(i = 1..N, k[i]/2*q[i]^2 + q[i]^4/4) + sum(i = 1..N, (q[i+1]-q[i])^2/(2*W))",
            "sum(i = 1..N-1, D*(1 - exp(-a*(q[i+1]-q[i])))^2)",
            "sum(i = 0..N, A*max(0, delta0 - (q[i+1]-q[i]))^(5/2))",
            "piecewise(q1 < 0, U(q2), q2 >= 1e-3, atan2(q1, .5), if(q1 <= q2, -pi, N))",
        ];
        let pieces = [
            "q1",
            "q[",
            "]",
            "(",
            ")",
            "+",
            "-",
            "*",
            "/",
            "^",
            "**",
            ",",
            "..",
            "=",
            "<",
            ">=",
            "sum(",
            "i",
            "N",
            "pi",
            "1",
            "0",
            "2.5",
            "1e",
            ".",
            "k[i]",
            "beta",
            "max(",
            "if(",
            "piecewise(",
            "U(",
            "sqrt(",
            "\n",
            " ",
            "é",
            "$",
            "q99",
            "q[i+1]",
            "sum(i = 1..N, ",
        ];
        // One thread with a big stack for all rounds (as `parse` and `lower` do per call).
        on_big_stack(|| fuzz_rounds(&seeds, &pieces));
    }

    fn fuzz_rounds(seeds: &[&str], pieces: &[&str]) {
        let mut rng = Rng(0x9E37_79B9_7F4A_7C15);
        for round in 0..20_000 {
            let src: String = if round % 2 == 0 {
                let mut b: Vec<char> = seeds[rng.below(seeds.len())].chars().collect();
                for _ in 0..1 + rng.below(4) {
                    let at = rng.below(b.len() + 1);
                    match rng.below(3) {
                        0 if at < b.len() => {
                            b.remove(at);
                        }
                        1 => {
                            let p = pieces[rng.below(pieces.len())];
                            for (j, c) in p.chars().enumerate() {
                                b.insert(at + j, c);
                            }
                        }
                        _ if at < b.len() => {
                            b[at] = "()[]+-*/^,.=<>0129qiNé "
                                .chars()
                                .nth(rng.below(23))
                                .unwrap_or(' ')
                        }
                        _ => {}
                    }
                }
                b.into_iter().collect()
            } else {
                (0..rng.below(30))
                    .map(|_| pieces[rng.below(pieces.len())])
                    .collect()
            };
            let _ = crate::parser::parse_here(&src);
            for boundary in [Boundary::Fixed, Boundary::Periodic, Boundary::Free] {
                let mut s = Setup::new(4, boundary)
                    .param("beta", 1.0)
                    .param("W", 2.0)
                    .param("D", 1.0)
                    .param("a", 1.0)
                    .param("A", 1.0)
                    .param("delta0", 0.1)
                    .array("k", vec![1.0; 4]);
                let (scope, graph) = s.parts();
                let unrolled = lower_limited(&src, &scope, graph, MAX_NODES, MAX_STEPS, false);
                match &unrolled {
                    // Every error renders, and its position is inside the source.
                    Err(e) => {
                        let _ = e.to_string();
                        assert!(e.span.start <= src.len(), "{src:?}");
                    }
                    Ok(l) => {
                        let _ = l.smoothness.require(2, "vm");
                    }
                }
                // Loops change how sums are lowered, never what is accepted or refused.
                let looped = lower_limited(&src, &scope, graph, MAX_NODES, MAX_STEPS, true);
                match (&unrolled, &looped) {
                    (Err(a), Err(b)) => assert_eq!(a.to_string(), b.to_string(), "{src:?}"),
                    (Ok(a), Ok(b)) => assert_eq!(a.smoothness, b.smoothness, "{src:?}"),
                    _ => panic!("{src:?}: unrolled {unrolled:?}, looped {looped:?}"),
                }
            }
        }
    }
}

#[cfg(test)]
mod deep {
    use super::*;

    /// The deepest expressions the parser accepts also lower, even when called from a thread
    /// with a small stack (recursion in every pass is bounded by the parser's nesting limit,
    /// and runs on a thread of its own with a big stack).
    #[test]
    fn deepest_allowed_expressions_lower_on_a_small_stack() {
        let run = || {
            let d = crate::parser::MAX_DEPTH;
            let families = [Family {
                name: "q".into(),
                len: 3,
                arg: 0,
                offset: 0,
            }];
            let params = BTreeMap::new();
            let scope = Scope {
                families: &families,
                params: &params,
                tables: &[],
                n: 3,
                boundary: Boundary::Free,
                shape: crate::lower::Shape::Chain,
                time: None,
            };
            let shapes = [
                format!("{}q1{}", "(q1 + q1*".repeat(d - 1), ")".repeat(d - 1)),
                format!(
                    "{}q1{}",
                    "q1^(q1 + q1*".repeat(d / 2 - 1),
                    ")".repeat(d / 2 - 1)
                ),
                format!("{}q1{}", "sin(q1 + q1*".repeat(d - 1), ")".repeat(d - 1)),
                format!("{}q1{}", "-q1 - q1*".repeat(d - 1), ""),
                format!(
                    "{}q[i1]{}",
                    (0..d - 1)
                        .map(|k| format!("sum(i{k} = 1..1, q1 + q1*"))
                        .collect::<String>(),
                    ")".repeat(d - 1)
                ),
                format!(
                    "{}q1{}",
                    "if(q1 < 0, q1 + q1*".repeat(d - 1),
                    ", 0)".repeat(d - 1)
                ),
            ];
            for src in shapes {
                crate::parser::parse(&src).unwrap_or_else(|e| panic!("{e}"));
                let mut g = Graph::new();
                lower(&src, &scope, &mut g).unwrap_or_else(|e| panic!("{e}"));
            }
        };
        std::thread::Builder::new()
            .stack_size(256 << 10)
            .spawn(run)
            .unwrap()
            .join()
            .unwrap();
    }
}
