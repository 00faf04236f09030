//! Taylor's method over the expression graph: the normalized Taylor coefficients `x_k` of the
//! solution of `dx/dt = F(x, t)` through a state (`x(t0 + s) = sum_k x_k s^k`), and of the
//! tangent vectors `dv/dt = J(x, t) v` along it, by automatic differentiation of the graph.
//!
//! The graph is decomposed into a tape of elementary operations on series (one slot each),
//! in the graph's order (a valid evaluation order), and each operation has its recurrence: the
//! coefficient `k` of its result from coefficients `0..=k` of its operands (and `0..k` of its
//! own, for the nonlinear ones), as in Jorba and Zou (2005, Experiment. Math. 14, 99) and
//! heyoka's decomposition. With the series of the state known to order `k`, one pass at order
//! `k` gives `F_k`, so `x_{k+1} = F_k / (k + 1)`; `order` passes give the state's series to
//! that order.
//!
//! What is computed once per step, not per order: nodes that read neither the state, the
//! time nor a tangent vector (constants and the parameters, whatever functions of them), whose
//! series is their value and zeros. What is shared: nodes the tangent vectors do not read (the
//! Jacobian's entries); the nodes that read a vector are on the tape once per vector. A
//! state's series never depends on the vectors', so stepping with vectors moves the state
//! exactly (bit for bit) as stepping without.
//!
//! Taylor's method needs a right-hand side analytic along the orbit: an operation with a kink,
//! a jump or a table (`abs`, `max`, `if`, a spline) on a quantity that moves is refused at
//! build time, naming it. On constants they are fine.

use std::collections::HashMap;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, OnceLock};

use crate::graph::{Binary, Graph, Node, NodeId, Tabulated, Unary};
use crate::jit::c::taylor::CTaylor;
use crate::jit::{CCompiler, JitError};
use crate::ops::UnarySeries;

/// The state, tangent-vector, time and parameter arguments of a vector function's graph.
const ARG_X: u8 = 0;
const ARG_V: u8 = 1;
const ARG_T: u8 = 2;
const ARG_PARAMS: u8 = 3;

/// The next tape's [`TaylorTape::id`].
static NEXT_ID: AtomicU64 = AtomicU64::new(0);

/// One operation on series, its operands and result as slots.
#[derive(Debug, Clone, Copy)]
pub(crate) enum Op {
    Add(u32, u32, u32),
    Sub(u32, u32, u32),
    Neg(u32, u32),
    /// `dst = a * c` with `c` constant in time (its value only).
    Scale(u32, u32, u32),
    /// `dst = a / c` with `c` constant in time.
    DivConst(u32, u32, u32),
    Mul(u32, u32, u32),
    Square(u32, u32),
    Div(u32, u32, u32),
    Sqrt(u32, u32),
    Exp(u32, u32),
    Log(u32, u32),
    /// `dst = a^e`, `e` constant in time.
    Pow(u32, u32, u32),
    /// `(sin a, cos a)`, or with `hyperbolic` `(sinh a, cosh a)`.
    SinCos {
        sin: u32,
        cos: u32,
        a: u32,
        hyperbolic: bool,
    },
    /// `dst = tan a` (`w' = (1 + w^2) a'`) or `tanh a` (`w' = (1 - w^2) a'`); `sq` holds `w^2`.
    Tan {
        dst: u32,
        a: u32,
        sq: u32,
        hyperbolic: bool,
    },
    /// `w' = a' / d` with `w_0 = f(a_0)`: `atan` (`d = 1 + a^2`), `asinh` (`d = sqrt(1 + a^2)`).
    Inverse {
        dst: u32,
        a: u32,
        d: u32,
        f: Unary,
    },
    /// `dst = atan2(a, b)`: `w' = (b a' - a b') / d`, `d = a^2 + b^2`.
    Atan2 {
        dst: u32,
        a: u32,
        b: u32,
        d: u32,
    },
    /// `dst = 1` (a whole power 0 of a moving quantity).
    One(u32),
    Copy(u32, u32),
}

/// A node constant in time: evaluated once per step at order 0.
#[derive(Debug, Clone, Copy)]
enum Fixed {
    Value(u32, f64),
    Param(u32, u32),
    Node(u32, Node),
}

/// The Taylor tape of a vector function with `vectors` tangent vectors, to a given order.
#[derive(Debug, Clone)]
pub struct TaylorTape {
    pub(crate) order: usize,
    pub(crate) dim: usize,
    pub(crate) vectors: usize,
    pub(crate) slots: usize,
    /// Slot of each state coordinate, then of each vector's coordinates (vector by vector).
    pub(crate) state: Vec<u32>,
    pub(crate) tangent: Vec<u32>,
    time: Option<u32>,
    fixed: Vec<Fixed>,
    /// Slots of the constant nodes by node (what [`Fixed::Node`] reads its operands from).
    node_slot: Vec<u32>,
    pub(crate) tables: Vec<Arc<dyn Tabulated>>,
    pub(crate) ops: Vec<Op>,
    /// Slot of `F_i`, then of `(J v_j)_i` vector by vector.
    pub(crate) f_out: Vec<u32>,
    pub(crate) jv_out: Vec<u32>,
    /// The pass over the orders compiled to C ([`Self::compile_native`]): the same bits, so it
    /// may take over between any two calls.
    native: OnceLock<Arc<CTaylor>>,
    /// Unique to the tape's build (its clones share it): what a coefficient buffer is kept for.
    id: u64,
}

/// A background build of a tape's compiled pass ([`TaylorTape::compile_native_in_background`]):
/// dropped, it lets a build still under way finish for up to [`FINISH_GRACE`] (unless a
/// SIGINT/SIGTERM came), then cancels it (the compiler's process group is stopped, so no
/// compiler outlives the system that wanted it) and waits for its thread a moment.
#[derive(Debug)]
pub struct NativeBuild {
    cancel: Arc<AtomicBool>,
    handle: Option<std::thread::JoinHandle<()>>,
}

/// How long a build still under way when its system is dropped is given to finish. A run shorter
/// than the build of its pass (the three-body problem to t = 1000: 0.1 s against a 0.4 s build)
/// would otherwise cancel it every time, never leave it in the kernel cache, and run
/// interpreted forever (measured: 10 such runs 0.92 CPU-s interpreted, 0.45 s compiled). Waiting
/// once per system, each later run of it loads the pass; a compiler that hangs costs this much
/// per pass being built (a system builds one or two).
pub const FINISH_GRACE: std::time::Duration = std::time::Duration::from_secs(2);

/// Longest a cancelled build is waited for (a cancelled compiler stops within milliseconds).
const CANCEL_GRACE: std::time::Duration = std::time::Duration::from_millis(500);

impl Drop for NativeBuild {
    fn drop(&mut self) {
        let Some(handle) = self.handle.take() else {
            self.cancel.store(true, Ordering::Relaxed);
            return;
        };
        let start = std::time::Instant::now();
        while !handle.is_finished()
            && start.elapsed() < FINISH_GRACE
            && !chaoscope_os::signals::requested()
        {
            std::thread::sleep(std::time::Duration::from_millis(1));
        }
        self.cancel.store(true, Ordering::Relaxed);
        let start = std::time::Instant::now();
        while !handle.is_finished() && start.elapsed() < CANCEL_GRACE {
            std::thread::sleep(std::time::Duration::from_millis(1));
        }
        if handle.is_finished() {
            let _ = handle.join();
        }
    }
}

/// Why a graph has no Taylor tape: the node whose operation is not analytic.
#[derive(Debug, Clone)]
pub struct NotAnalytic {
    pub node: NodeId,
    pub operation: String,
}

#[derive(Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
enum Class {
    /// Constant in time.
    Fixed,
    /// Reads the state or the time.
    Moving,
    /// Reads a tangent vector.
    Tangent,
}

/// Builds a tape; what each function's entry in `ops.rs` decomposes itself with
/// ([`Self::slot`], [`Self::push`], [`Self::sin_cos`], [`Self::one`]).
pub(crate) struct Builder<'g> {
    graph: &'g Graph,
    slots: u32,
    ops: Vec<Op>,
    fixed: Vec<Fixed>,
    one: Option<u32>,
    pairs: HashMap<(u32, bool), (u32, u32)>,
}

impl Builder<'_> {
    /// A new slot (a series).
    pub(crate) fn slot(&mut self) -> u32 {
        self.slots += 1;
        self.slots - 1
    }

    /// Appends an operation to the tape.
    pub(crate) fn push(&mut self, op: Op) {
        self.ops.push(op);
    }

    /// The slots of `(sin a, cos a)`, or with `hyperbolic` `(sinh a, cosh a)`: one operation
    /// computes both, written the first time either is asked for.
    pub(crate) fn sin_cos(&mut self, a: u32, hyperbolic: bool) -> (u32, u32) {
        if let Some(&pair) = self.pairs.get(&(a, hyperbolic)) {
            return pair;
        }
        let pair = (self.slot(), self.slot());
        self.ops.push(Op::SinCos {
            sin: pair.0,
            cos: pair.1,
            a,
            hyperbolic,
        });
        self.pairs.insert((a, hyperbolic), pair);
        pair
    }

    /// The slot of the series `1`.
    pub(crate) fn one(&mut self) -> u32 {
        if let Some(s) = self.one {
            return s;
        }
        let s = self.slot();
        self.fixed.push(Fixed::Value(s, 1.0));
        self.one = Some(s);
        s
    }

    /// `x^n` for a whole `n >= 2`, by squaring.
    fn power(&mut self, dst: u32, x: u32, n: u32) {
        if n == 1 {
            self.ops.push(Op::Copy(dst, x));
            return;
        }
        let half = if n / 2 == 1 { x } else { self.slot() };
        if n / 2 > 1 {
            self.power(half, x, n / 2);
        }
        if n.is_multiple_of(2) {
            self.ops.push(Op::Square(dst, half));
        } else {
            let sq = self.slot();
            self.ops.push(Op::Square(sq, half));
            self.ops.push(Op::Mul(dst, sq, x));
        }
    }

    /// The ops of node `id` (of class `Moving` or `Tangent`) into `dst`, its operands at
    /// `slot_of`; `is_fixed` tells operands constant in time.
    fn emit(
        &mut self,
        id: NodeId,
        dst: u32,
        slot_of: &dyn Fn(NodeId) -> u32,
        is_fixed: &dyn Fn(NodeId) -> bool,
    ) -> Result<Option<u32>, NotAnalytic> {
        let refuse = || NotAnalytic {
            node: id,
            operation: self.graph.operation_name(id),
        };
        let op = match *self.graph.node(id) {
            Node::Const(_) | Node::Input { .. } => unreachable!("inputs and constants have slots"),
            Node::Binary(b, x, y) => {
                let (sx, sy) = (slot_of(x), slot_of(y));
                match b {
                    Binary::Add => Op::Add(dst, sx, sy),
                    Binary::Sub => Op::Sub(dst, sx, sy),
                    Binary::Mul if is_fixed(x) => Op::Scale(dst, sy, sx),
                    Binary::Mul if is_fixed(y) => Op::Scale(dst, sx, sy),
                    Binary::Mul if x == y => Op::Square(dst, sx),
                    Binary::Mul => Op::Mul(dst, sx, sy),
                    Binary::Div if is_fixed(y) => Op::DivConst(dst, sx, sy),
                    Binary::Div => Op::Div(dst, sx, sy),
                    Binary::Pow if is_fixed(y) => Op::Pow(dst, sx, sy),
                    Binary::Pow => {
                        // a^b = exp(b log a).
                        let (l, m) = (self.slot(), self.slot());
                        self.ops.push(Op::Log(l, sx));
                        self.ops.push(Op::Mul(m, sy, l));
                        Op::Exp(dst, m)
                    }
                    // A called function decomposes itself (its entry in `ops.rs`); one with
                    // no series (a kink, a selection) has no decomposition.
                    _ => match b.def().taylor {
                        Some(decompose) => decompose(self, dst, [sx, sy]),
                        None => return Err(refuse()),
                    },
                }
            }
            Node::Unary(u, x) => {
                // Each function decomposes itself (its entry in `ops.rs`); one with a kink or a
                // jump has no series.
                match u.def().taylor {
                    Some(decompose) => match decompose(self, u, dst, slot_of(x)) {
                        UnarySeries::Op(op) => op,
                        UnarySeries::Slot(slot) => return Ok(Some(slot)),
                    },
                    None => return Err(refuse()),
                }
            }
            Node::Powi(x, n) => {
                let sx = slot_of(x);
                match n {
                    0 => Op::One(dst),
                    n if n > 0 => {
                        self.power(dst, sx, n as u32);
                        return Ok(None);
                    }
                    n => {
                        let p = self.slot();
                        self.power(p, sx, n.unsigned_abs());
                        let one = self.one();
                        Op::Div(dst, one, p)
                    }
                }
            }
            Node::Select { .. } | Node::Table { .. } => return Err(refuse()),
        };
        self.ops.push(op);
        Ok(None)
    }
}

impl TaylorTape {
    /// The tape of `dx/dt = F` (`values`: the nodes of `F_i`) and, with `vectors > 0`, of the
    /// tangent vectors (`tangent`: the nodes of `(J v)_i`, reading the direction `v` as argument
    /// 1), to `order` (at least 1).
    pub fn build(
        graph: &Graph,
        values: &[NodeId],
        tangent: &[NodeId],
        vectors: usize,
        order: usize,
    ) -> Result<Self, NotAnalytic> {
        assert!(order >= 1, "a Taylor tape of order 0");
        let dim = values.len();
        let n = graph.len();
        // What the outputs need.
        let mut needed = vec![false; n];
        let roots = values
            .iter()
            .chain(if vectors > 0 { tangent } else { &[] })
            .copied();
        let mut stack: Vec<NodeId> = roots.collect();
        while let Some(id) = stack.pop() {
            if std::mem::replace(&mut needed[id as usize], true) {
                continue;
            }
            stack.extend(graph.node(id).operands());
        }
        let mut class = vec![Class::Fixed; n];
        for id in 0..n {
            if !needed[id] {
                continue;
            }
            class[id] = match *graph.node(id as NodeId) {
                Node::Input {
                    arg: ARG_X | ARG_T, ..
                } => Class::Moving,
                Node::Input { arg: ARG_V, .. } => Class::Tangent,
                ref node => node
                    .operands()
                    .map(|o| class[o as usize])
                    .max()
                    .unwrap_or(Class::Fixed),
            };
        }
        let mut b = Builder {
            graph,
            slots: 0,
            ops: Vec::new(),
            fixed: Vec::new(),
            one: None,
            pairs: HashMap::new(),
        };
        let state: Vec<u32> = (0..dim).map(|_| b.slot()).collect();
        let tangent_slots: Vec<u32> = (0..vectors * dim).map(|_| b.slot()).collect();
        let mut time = None;
        // Slot of each node: shared nodes one, tangent nodes one per vector.
        const NONE: u32 = u32::MAX;
        let mut shared = vec![NONE; n];
        let mut per_vector = vec![NONE; n * vectors.max(1)];
        for id in 0..n {
            if !needed[id] {
                continue;
            }
            let node = *graph.node(id as NodeId);
            match (class[id], node) {
                (_, Node::Input { arg: ARG_X, index }) => shared[id] = state[index as usize],
                (_, Node::Input { arg: ARG_T, .. }) => {
                    let s = *time.get_or_insert_with(|| b.slot());
                    shared[id] = s;
                }
                (_, Node::Input { arg: ARG_V, index }) => {
                    for j in 0..vectors {
                        per_vector[id * vectors + j] = tangent_slots[j * dim + index as usize];
                    }
                }
                (Class::Fixed, node) => {
                    let s = b.slot();
                    b.fixed.push(match node {
                        Node::Const(c) => Fixed::Value(s, c),
                        Node::Input {
                            arg: ARG_PARAMS,
                            index,
                        } => Fixed::Param(s, index),
                        Node::Input { arg, .. } => unreachable!("argument {arg} of a vector field"),
                        node => Fixed::Node(s, node),
                    });
                    shared[id] = s;
                }
                (Class::Moving, _) => {
                    let s = b.slot();
                    let slot_of = |o: NodeId| shared[o as usize];
                    let is_fixed = |o: NodeId| class[o as usize] == Class::Fixed;
                    shared[id] = b.emit(id as NodeId, s, &slot_of, &is_fixed)?.unwrap_or(s);
                }
                (Class::Tangent, _) => {
                    for j in 0..vectors {
                        let s = b.slot();
                        let slot_of = |o: NodeId| {
                            if class[o as usize] == Class::Tangent {
                                per_vector[o as usize * vectors + j]
                            } else {
                                shared[o as usize]
                            }
                        };
                        let is_fixed = |o: NodeId| class[o as usize] == Class::Fixed;
                        per_vector[id * vectors + j] =
                            b.emit(id as NodeId, s, &slot_of, &is_fixed)?.unwrap_or(s);
                    }
                }
            }
        }
        let f_out = values.iter().map(|&v| shared[v as usize]).collect();
        let mut jv_out = Vec::with_capacity(vectors * dim);
        for j in 0..vectors {
            for &t in tangent {
                jv_out.push(if class[t as usize] == Class::Tangent {
                    per_vector[t as usize * vectors + j]
                } else {
                    shared[t as usize]
                });
            }
        }
        Ok(Self {
            order,
            dim,
            vectors,
            slots: b.slots as usize,
            state,
            tangent: tangent_slots,
            time,
            fixed: b.fixed,
            node_slot: shared,
            tables: graph.tables().to_vec(),
            ops: b.ops,
            f_out,
            jv_out,
            native: OnceLock::new(),
            id: NEXT_ID.fetch_add(1, Ordering::Relaxed),
        })
    }

    /// Compiles the pass over the orders with the C compiler `cc` (or loads it from the
    /// kernel cache), so that [`Self::coefficients`] runs it instead of interpreting the tape:
    /// the same operations in the same order, the same bits. On an error the tape stays
    /// interpreted (the caller may say why).
    pub fn compile_native(&self, cc: &CCompiler, cancel: &AtomicBool) -> Result<(), JitError> {
        let pass = crate::jit::c::taylor::compile(self, cc, cancel)?;
        let _ = self.native.set(Arc::new(pass));
        Ok(())
    }

    /// [`Self::compile_native`] on a thread of its own: the tape runs interpreted until the
    /// build is done and compiled from the call after (the same bits, so the switch is
    /// invisible). Dropping the returned guard lets the build finish for a moment, then stops
    /// it (its compiler's process group killed): [`NativeBuild`].
    pub fn compile_native_in_background(self: &Arc<Self>, cc: CCompiler) -> NativeBuild {
        let cancel = Arc::new(AtomicBool::new(false));
        let (tape, stop) = (Arc::clone(self), Arc::clone(&cancel));
        let handle = std::thread::Builder::new()
            .name("taylor-c-build".into())
            .spawn(move || {
                let _ = tape.compile_native(&cc, &stop);
            })
            .ok();
        NativeBuild { cancel, handle }
    }

    /// Whether the pass over the orders runs compiled ([`Self::compile_native`]).
    pub fn is_native(&self) -> bool {
        self.native.get().is_some()
    }

    /// Unique to this tape's build: a coefficient buffer written by one tape holds values
    /// where another tape's constants must read zeros, so buffers are kept per tape.
    pub fn id(&self) -> u64 {
        self.id
    }

    /// `D`, the state's coordinates (its lane parameters follow them in a state).
    pub fn dim(&self) -> usize {
        self.dim
    }

    /// The length of the coefficient buffer [`Self::coefficients`] works in.
    pub fn buffer_len(&self) -> usize {
        self.slots * (self.order + 1)
    }

    /// The series to [`Self::order`] of the state `x` (its `D` coordinates, then its lane
    /// parameters) and of the vectors `w` (one after the other) from time `t`, into `coef`
    /// (of [`Self::buffer_len`], zero where never written: pass it back unchanged between calls).
    pub fn coefficients(&self, coef: &mut [f64], x: &[f64], w: &[f64], t: f64) {
        let stride = self.order + 1;
        debug_assert!(coef.len() == self.buffer_len());
        debug_assert!(w.len() == self.vectors * self.dim);
        for (&s, &v) in self.state.iter().zip(x) {
            coef[s as usize * stride] = v;
        }
        for (&s, &v) in self.tangent.iter().zip(w) {
            coef[s as usize * stride] = v;
        }
        if let Some(s) = self.time {
            coef[s as usize * stride] = t;
            coef[s as usize * stride + 1] = 1.0;
        }
        let params = &x[self.dim.min(x.len())..];
        for f in &self.fixed {
            let (s, v) = match *f {
                Fixed::Value(s, v) => (s, v),
                Fixed::Param(s, i) => (s, params[i as usize]),
                Fixed::Node(s, ref node) => (s, self.fixed_value(coef, node)),
            };
            coef[s as usize * stride] = v;
        }
        if let Some(native) = self.native.get() {
            assert!(coef.len() == self.buffer_len(), "a buffer of another tape");
            native.run(coef);
            return;
        }
        for k in 0..self.order {
            for op in &self.ops {
                let v = order_k(op, coef, stride, k);
                let dst = match *op {
                    Op::SinCos { sin, cos, .. } => {
                        coef[sin as usize * stride + k] = v;
                        let c = cosine_k(op, coef, stride, k);
                        coef[cos as usize * stride + k] = c;
                        continue;
                    }
                    Op::Tan { dst, sq, .. } => {
                        coef[dst as usize * stride + k] = v;
                        let w = &coef[dst as usize * stride..];
                        coef[sq as usize * stride + k] = square_k(w, k);
                        continue;
                    }
                    Op::Add(d, ..)
                    | Op::Sub(d, ..)
                    | Op::Neg(d, _)
                    | Op::Scale(d, ..)
                    | Op::DivConst(d, ..)
                    | Op::Mul(d, ..)
                    | Op::Square(d, _)
                    | Op::Div(d, ..)
                    | Op::Sqrt(d, _)
                    | Op::Exp(d, _)
                    | Op::Log(d, _)
                    | Op::Pow(d, ..)
                    | Op::Inverse { dst: d, .. }
                    | Op::Atan2 { dst: d, .. }
                    | Op::One(d)
                    | Op::Copy(d, _) => d,
                };
                coef[dst as usize * stride + k] = v;
            }
            let next = 1.0 / (k + 1) as f64;
            for (&s, &f) in self.state.iter().zip(&self.f_out) {
                coef[s as usize * stride + k + 1] = coef[f as usize * stride + k] * next;
            }
            for (&s, &f) in self.tangent.iter().zip(&self.jv_out) {
                coef[s as usize * stride + k + 1] = coef[f as usize * stride + k] * next;
            }
        }
    }

    /// The value of a node constant in time, from its operands' slots.
    fn fixed_value(&self, coef: &[f64], node: &Node) -> f64 {
        let stride = self.order + 1;
        crate::eval::node_value(
            node,
            &self.tables,
            |o| coef[self.node_slot[o as usize] as usize * stride],
            |arg, _| unreachable!("argument {arg} is set, not evaluated"),
        )
    }

    /// The state's coefficients of order `k`, coordinate by coordinate.
    pub fn state_coefficients(&self, coef: &[f64], k: usize) -> impl Iterator<Item = f64> {
        let stride = self.order + 1;
        self.state
            .iter()
            .map(move |&s| coef[s as usize * stride + k])
    }

    /// `x(t0 + h)` and `w(t0 + h)` from the series in `coef`, by Horner's rule.
    pub fn sum(&self, coef: &[f64], h: f64, x: &mut [f64], w: &mut [f64]) {
        let stride = self.order + 1;
        let n = self.dim.min(x.len());
        horner(coef, stride, &self.state[..n], h, &mut x[..n]);
        horner(coef, stride, &self.tangent, h, w);
    }
}

/// `out_i = sum_k c_{s_i, k} h^k` by Horner's rule, four series at a time (four independent
/// chains of multiply-adds instead of one waiting on the other).
fn horner(coef: &[f64], stride: usize, slots: &[u32], h: f64, out: &mut [f64]) {
    let one = |s: u32| {
        let c = &coef[s as usize * stride..s as usize * stride + stride];
        c.iter().rev().fold(0.0, |acc, &ck| acc * h + ck)
    };
    let mut four = slots.chunks_exact(4);
    let mut outs = out.chunks_exact_mut(4);
    for (s, o) in (&mut four).zip(&mut outs) {
        let c: [&[f64]; 4] =
            std::array::from_fn(|l| &coef[s[l] as usize * stride..s[l] as usize * stride + stride]);
        let mut acc = [0.0f64; 4];
        for k in (0..stride).rev() {
            for l in 0..4 {
                acc[l] = acc[l] * h + c[l][k];
            }
        }
        o.copy_from_slice(&acc);
    }
    for (&s, o) in four.remainder().iter().zip(outs.into_remainder()) {
        *o = one(s);
    }
}

/// `sum_{j=0}^{k} a_j b_{k-j}`, in four running sums: one sum would wait on each addition's
/// latency, which is what a step costs (the products are independent).
#[inline(always)]
fn cauchy(a: &[f64], b: &[f64], k: usize) -> f64 {
    let (a, b) = (&a[..=k], &b[..=k]);
    let mut acc = [0.0f64; 4];
    let mut pairs = a.chunks_exact(4).zip(b.rchunks_exact(4));
    for (x, y) in &mut pairs {
        acc[0] += x[0] * y[3];
        acc[1] += x[1] * y[2];
        acc[2] += x[2] * y[1];
        acc[3] += x[3] * y[0];
    }
    let done = a.len() / 4 * 4;
    let mut sum = (acc[0] + acc[1]) + (acc[2] + acc[3]);
    for j in done..=k {
        sum += a[j] * b[k - j];
    }
    sum
}

/// Coefficient `k` of `w^2` from `w_0..=w_k`.
#[inline(always)]
fn square_k(w: &[f64], k: usize) -> f64 {
    cauchy(w, w, k)
}

/// `sum_{j=1}^{k} j a_j b_{k-j}` (the derivative's convolution), in two running sums.
#[inline(always)]
fn weighted(a: &[f64], b: &[f64], k: usize) -> f64 {
    let (a, b) = (&a[..=k], &b[..=k]);
    let mut acc = [0.0f64; 2];
    let mut j = 1;
    while j < k {
        acc[0] += j as f64 * a[j] * b[k - j];
        acc[1] += (j + 1) as f64 * a[j + 1] * b[k - j - 1];
        j += 2;
    }
    if j == k {
        acc[0] += k as f64 * a[k] * b[0];
    }
    acc[0] + acc[1]
}

/// Coefficient `k` of the result of `op` (of the sine for a pair, of `tan` for `Tan`).
#[inline(always)]
fn order_k(op: &Op, c: &[f64], stride: usize, k: usize) -> f64 {
    let s = |slot: u32| &c[slot as usize * stride..slot as usize * stride + stride];
    let kf = k as f64;
    match *op {
        Op::Add(_, a, b) => s(a)[k] + s(b)[k],
        Op::Sub(_, a, b) => s(a)[k] - s(b)[k],
        Op::Neg(_, a) => -s(a)[k],
        Op::Scale(_, a, f) => s(a)[k] * s(f)[0],
        Op::DivConst(_, a, f) => s(a)[k] / s(f)[0],
        Op::Mul(_, a, b) => cauchy(s(a), s(b), k),
        Op::Square(_, a) => square_k(s(a), k),
        Op::Copy(_, a) => s(a)[k],
        Op::One(_) => {
            if k == 0 {
                1.0
            } else {
                0.0
            }
        }
        Op::Div(d, a, b) => {
            // w b = a: w_k = (a_k - sum_{j=1}^k b_j w_{k-j}) / b_0.
            let (a, b, w) = (s(a), s(b), s(d));
            let mut acc = a[k];
            for j in 1..=k {
                acc -= b[j] * w[k - j];
            }
            acc / b[0]
        }
        Op::Sqrt(d, a) => {
            let (a, w) = (s(a), s(d));
            if k == 0 {
                return Graph::apply_unary(Unary::Sqrt, a[0]);
            }
            // 2 w_0 w_k = a_k - sum_{j=1}^{k-1} w_j w_{k-j}.
            let mut acc = a[k];
            for j in 1..k {
                acc -= w[j] * w[k - j];
            }
            acc / (2.0 * w[0])
        }
        Op::Exp(d, a) => {
            let (a, w) = (s(a), s(d));
            if k == 0 {
                return Graph::apply_unary(Unary::Exp, a[0]);
            }
            // w' = a' w.
            weighted(a, w, k) / kf
        }
        Op::Log(d, a) => {
            let (a, w) = (s(a), s(d));
            if k == 0 {
                return Graph::apply_unary(Unary::Log, a[0]);
            }
            // a w' = a': k a_0 w_k = k a_k - sum_{j=1}^{k-1} j w_j a_{k-j}.
            let mut acc = kf * a[k];
            for j in 1..k {
                acc -= j as f64 * w[j] * a[k - j];
            }
            acc / (kf * a[0])
        }
        Op::Pow(d, a, e) => {
            let (a, w, e) = (s(a), s(d), s(e)[0]);
            if k == 0 {
                return Graph::apply_binary(Binary::Pow, a[0], e);
            }
            // a w' = e a' w: k a_0 w_k = sum_{j=0}^{k-1} (e (k - j) - j) a_{k-j} w_j.
            let mut acc = 0.0;
            for j in 0..k {
                acc += (e * (k - j) as f64 - j as f64) * a[k - j] * w[j];
            }
            acc / (kf * a[0])
        }
        Op::SinCos {
            a, cos, hyperbolic, ..
        } => {
            let a = s(a);
            if k == 0 {
                return Graph::apply_unary(if hyperbolic { Unary::Sinh } else { Unary::Sin }, a[0]);
            }
            // sin' = a' cos, sinh' = a' cosh.
            weighted(a, s(cos), k) / kf
        }
        Op::Tan {
            a, sq, hyperbolic, ..
        } => {
            let (a, q) = (s(a), s(sq));
            if k == 0 {
                return Graph::apply_unary(if hyperbolic { Unary::Tanh } else { Unary::Tan }, a[0]);
            }
            // w' = a' (1 +- w^2).
            let sign = if hyperbolic { -1.0 } else { 1.0 };
            (a[k] * kf + sign * weighted(a, q, k)) / kf
        }
        Op::Inverse { dst, a, d, f } => {
            let (a, w, d) = (s(a), s(dst), s(d));
            if k == 0 {
                return Graph::apply_unary(f, a[0]);
            }
            // d w' = a': k d_0 w_k = k a_k - sum_{j=1}^{k-1} j w_j d_{k-j}.
            let mut acc = kf * a[k];
            for j in 1..k {
                acc -= j as f64 * w[j] * d[k - j];
            }
            acc / (kf * d[0])
        }
        Op::Atan2 { dst, a, b, d } => {
            let (a, b, w, d) = (s(a), s(b), s(dst), s(d));
            if k == 0 {
                return Graph::apply_binary(Binary::Atan2, a[0], b[0]);
            }
            // d w' = b a' - a b'.
            let mut acc = 0.0;
            for j in 1..=k {
                acc += j as f64 * (b[k - j] * a[j] - a[k - j] * b[j]);
            }
            for j in 1..k {
                acc -= j as f64 * w[j] * d[k - j];
            }
            acc / (kf * d[0])
        }
    }
}

/// Coefficient `k` of a pair's cosine (after its sine's coefficient `k` is written).
#[inline(always)]
fn cosine_k(op: &Op, c: &[f64], stride: usize, k: usize) -> f64 {
    let Op::SinCos {
        sin, a, hyperbolic, ..
    } = *op
    else {
        unreachable!("the cosine of a sine-cosine pair")
    };
    let s = |slot: u32| &c[slot as usize * stride..slot as usize * stride + stride];
    let a = s(a);
    if k == 0 {
        return Graph::apply_unary(if hyperbolic { Unary::Cosh } else { Unary::Cos }, a[0]);
    }
    // cos' = -a' sin, cosh' = a' sinh.
    let v = weighted(a, s(sin), k) / k as f64;
    if hyperbolic { v } else { -v }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The series of `x' = x` from `x0` is `x0 / k!`, of `x' = 1 + x^2` from 0 `tan t`'s.
    #[test]
    fn series_of_known_solutions() {
        let mut g = Graph::new();
        let x = g.input(ARG_X, 0);
        let tape = TaylorTape::build(&g, &[x], &[], 0, 10).unwrap();
        let mut c = vec![0.0; tape.buffer_len()];
        tape.coefficients(&mut c, &[2.0], &[], 0.0);
        let mut fact = 1.0;
        for (k, ck) in (0..=10).map(|k| (k, tape.state_coefficients(&c, k).next().unwrap())) {
            if k > 0 {
                fact *= k as f64;
            }
            assert!((ck - 2.0 / fact).abs() < 1e-15 * (2.0 / fact), "{k}: {ck}");
        }
        let mut g = Graph::new();
        let x = g.input(ARG_X, 0);
        let sq = g.mul(x, x);
        let one = g.constant(1.0);
        let f = g.add2(one, sq);
        let tape = TaylorTape::build(&g, &[f], &[], 0, 9).unwrap();
        let mut c = vec![0.0; tape.buffer_len()];
        tape.coefficients(&mut c, &[0.0], &[], 0.0);
        // tan t = t + t^3/3 + 2 t^5/15 + 17 t^7/315 + 62 t^9/2835.
        let want = [
            0.0,
            1.0,
            0.0,
            1.0 / 3.0,
            0.0,
            2.0 / 15.0,
            0.0,
            17.0 / 315.0,
            0.0,
            62.0 / 2835.0,
        ];
        for (k, w) in want.iter().enumerate() {
            let ck = tape.state_coefficients(&c, k).next().unwrap();
            assert!((ck - w).abs() < 1e-15, "{k}: {ck} against {w}");
        }
    }

    #[test]
    fn a_kink_on_a_moving_quantity_is_refused_and_on_a_constant_not() {
        let mut g = Graph::new();
        let x = g.input(ARG_X, 0);
        let a = g.unary(Unary::Abs, x);
        let e = TaylorTape::build(&g, &[a], &[], 0, 5).unwrap_err();
        assert_eq!(e.operation, "'abs'");
        let p = g.input(ARG_PARAMS, 0);
        let ap = g.unary(Unary::Abs, p);
        let f = g.mul(ap, x);
        let tape = TaylorTape::build(&g, &[f], &[], 0, 5).unwrap();
        let mut c = vec![0.0; tape.buffer_len()];
        // x' = |p| x with p = -3: x_k = 3^k / k!.
        tape.coefficients(&mut c, &[1.0, -3.0], &[], 0.0);
        let c2 = tape.state_coefficients(&c, 2).next().unwrap();
        assert!((c2 - 4.5).abs() < 1e-14, "{c2}");
    }
}
