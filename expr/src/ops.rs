//! Every operation of the language, defined once. For each one-argument function: its name in
//! a source, its value down to the rounding (the one Rust function the evaluator calls and the
//! compiled code calls back, so they agree bit for bit), its derivative as nodes of the graph,
//! what it does to the signs and poles of its argument (`smooth`), whether the code generators
//! write it as IEEE instructions or call its value function lane by lane, and its Taylor
//! decomposition. For each two-argument operation: its name in a source (if a source calls it
//! by name), how messages quote it, its value, whether it is written inline or called, and for
//! a called function its derivatives, smoothness rule and Taylor decomposition.
//!
//! Adding a one-argument function is one variant of [`Unary`] and one entry of [`UNARY_OPS`]
//! here: the lowering finds it by name, the evaluator and both code generators (Cranelift, C)
//! call its value function, `diff` takes its derivative, `smooth` its signs and Taylor's method
//! its decomposition from the entry.
//! A called two-argument function is one variant of [`Binary`] and one entry of
//! [`BINARY_OPS`]: its name, value, derivatives in both modes, kinks or jumps and Taylor
//! decomposition, read by the lowering, `diff`, both code generators and `taylor`.
//!
//! Every function's Taylor decomposition is its entry's `taylor`: the operations on series of
//! the tape (`taylor::Op`, whose recurrences `taylor.rs` and its C printer hold) that compute
//! it. A function whose series needs a recurrence the tape does not have adds one there.
//!
//! The kinks and jumps of `abs`, `step` and `sign` and the branch point of `sqrt` are their
//! entries' `kinks` rules. The operations written as instructions (`-`, `sqrt`, `abs`, `step`,
//! `sign`, `+ - * /`, `max`, `min`) keep their instruction sequences in the code generators;
//! their entries here still give their value and name.

use crate::diff::{Local, Term, mul_sorted, sub_opt};
use crate::error::Span;
use crate::graph::{Graph, NodeId};
use crate::smooth::{Info, Signs, SmoothnessLimit};
use crate::taylor::{Builder, Op as TapeOp};

/// One-argument operations, in the order of [`UNARY_OPS`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Unary {
    Neg,
    Sqrt,
    Exp,
    Log,
    Sin,
    Cos,
    Tan,
    Atan,
    Tanh,
    Cosh,
    Sinh,
    Abs,
    /// Heaviside step: `1` for `x > 0`, else `0` (so `step(0) = 0`); NaN stays NaN.
    Step,
    /// `-1`, `0` or `1` by the sign of `x` (`sign(0) = 0`, `sign(-0) = 0`); NaN stays NaN. The
    /// derivative of `abs`.
    Sign,
    /// `f64::asinh`: smooth and odd everywhere, `asinh(0) = 0`.
    Asinh,
}

/// Two-argument operations, in the order of [`BINARY_OPS`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Binary {
    Add,
    Sub,
    Mul,
    Div,
    /// `f64::powf` (real exponent; for whole exponents the lowering uses `Node::Powi`).
    Pow,
    /// `f64::atan2(a, b)`: the angle of the point `(b, a)`.
    Atan2,
    /// The larger of the two; NaN in either gives NaN (unlike `f64::max`).
    Max,
    Min,
}

/// The signs `op(u)` can take, given those `u` can.
#[derive(Debug, Clone, Copy)]
pub(crate) enum SignsOf {
    /// Positive whatever `u` is (`exp`, `cosh`).
    Positive,
    /// The signs of `u` (odd increasing functions through 0).
    Same,
    /// The opposite signs.
    Opposite,
    /// Those of `u * u`.
    Square,
    /// Zero or positive.
    NonNegative,
    /// Any sign.
    Any,
}

/// How the code generators compute an operation.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Lowering {
    /// IEEE instructions (and compares and bit selects) written by each code generator.
    Inline,
    /// A call, lane by lane, to the entry's value function.
    Call,
}

/// The definition of one [`Unary`] operation.
pub(crate) struct UnaryOp {
    pub op: Unary,
    /// The function's name in a source (`-x` has none a source can call).
    pub name: Option<&'static str>,
    /// The value, the one definition of its rounding (an `extern "C"` function so compiled code
    /// calls it directly).
    pub eval: extern "C" fn(f64) -> f64,
    /// `d v / d u` for `v = op(u)` as nodes of the graph; `None` when it is zero.
    pub derivative: fn(&mut Graph, NodeId, NodeId) -> Option<Local>,
    pub lowering: Lowering,
    pub signs: SignsOf,
    /// An odd function with `f(0) = 0`, finite wherever its argument is: it keeps a value
    /// vanishing (`sin(sqrt(r2))`).
    pub keeps_zero: bool,
    /// Finite wherever its argument is finite.
    pub finite: bool,
    /// What `op(u)` is from what `u` is, for a function with a kink, a jump or a branch point
    /// (the call's span names it); `None` for one smooth wherever it is finite
    /// ([`Info::smooth_fn`] from the fields above).
    pub kinks: Option<fn(Info, Span) -> Info>,
    /// Taylor's method: the operations on series that compute `op(a)` (the tape's recurrences
    /// are in `taylor.rs`); `None` for a function with a kink or a jump (no series).
    pub taylor: Option<UnaryTaylor>,
}

/// Writes `op(a)`'s series from the slot of `a` into `dst` (or says which slot already holds
/// it).
pub(crate) type UnaryTaylor = fn(&mut Builder, Unary, u32, u32) -> UnarySeries;

/// Where a one-argument function's series is.
pub(crate) enum UnarySeries {
    /// Computed into `dst` by this operation (the last of its decomposition).
    Op(TapeOp),
    /// In this slot, written by an operation shared with another function (`sin` and `cos`).
    Slot(u32),
}

/// The definition of one [`Binary`] operation.
pub(crate) struct BinaryOp {
    pub op: Binary,
    /// The function's name in a source (`atan2(a, b)`); `None` for the infix operators.
    pub name: Option<&'static str>,
    /// How messages quote the operation (`'/'`, `'atan2'`).
    pub symbol: &'static str,
    /// The value, the one definition of its rounding (an `extern "C"` function so compiled code
    /// calls it directly).
    pub eval: extern "C" fn(f64, f64) -> f64,
    pub lowering: Lowering,
    /// The derivatives of a function a source calls by name; `None` for the arithmetic
    /// operators (`+ - * / ^`, whose derivatives `diff` writes so constants fold) and for `max`
    /// and `min` (the derivative of the operand selected).
    pub derivatives: Option<BinaryDerivatives>,
    /// What `op(a, b)` is from what `a` and `b` are (the call's span names it; `zero` says
    /// which operand is the constant 0), for a function a source calls by name; `None` for the
    /// infix operators, whose rules the lowering applies where it builds them.
    pub kinks: Option<BinaryKinks>,
    /// Taylor's method: the operations on series that compute a called function into slot
    /// `dst` from the operands' slots, the last one returned (the tape's recurrences are in
    /// `taylor.rs`); `None` where it has no series (`max`, `min`) or where `taylor.rs` writes it
    /// (the arithmetic operators).
    pub taylor: Option<TaylorDecomposition>,
}

/// `op(a, b)`'s smoothness from its operands', the call's span and which operand is the
/// constant 0.
pub(crate) type BinaryKinks = fn(Info, Info, Span, [bool; 2]) -> Info;

/// Writes a function's series into slot `dst` from its operands' slots; returns the last
/// operation.
pub(crate) type TaylorDecomposition = fn(&mut Builder, u32, [u32; 2]) -> TapeOp;

/// The adjoints `[a, b, v]`, `s` and `varies` give the operands ([`BinaryDerivatives`]).
pub(crate) type Adjoint = fn(&mut Graph, [NodeId; 3], NodeId, [bool; 2]) -> [Option<Term>; 2];

/// The derivatives of `v = op(a, b)` as nodes of the graph, given `[a, b, v]` (the value may
/// be reused: `sqrt`'s derivative is `0.5 / v`).
pub(crate) struct BinaryDerivatives {
    /// Reverse mode: what the adjoints of `a` and `b` receive (only those whose `varies` is
    /// set), given `s`, the adjoint of `v` as one node.
    pub adjoint: Adjoint,
    /// Forward mode: the tangent of `v` from the tangents of `a` and `b` (at least one present).
    pub tangent: fn(&mut Graph, [NodeId; 3], [Option<NodeId>; 2]) -> NodeId,
}

impl Binary {
    /// This operation's definition.
    #[inline]
    pub(crate) fn def(self) -> &'static BinaryOp {
        &BINARY_OPS[self as usize]
    }

    /// The operation a source calls `name`.
    pub(crate) fn named(name: &str) -> Option<Binary> {
        BINARY_OPS
            .iter()
            .find(|d| d.name == Some(name))
            .map(|d| d.op)
    }
}

impl Unary {
    /// This operation's definition.
    #[inline]
    pub(crate) fn def(self) -> &'static UnaryOp {
        &UNARY_OPS[self as usize]
    }

    /// The operation a source calls `name`.
    pub(crate) fn named(name: &str) -> Option<Unary> {
        UNARY_OPS
            .iter()
            .find(|d| d.name == Some(name))
            .map(|d| d.op)
    }
}

extern "C" fn neg(x: f64) -> f64 {
    -x
}
extern "C" fn sqrt(x: f64) -> f64 {
    x.sqrt()
}
extern "C" fn exp(x: f64) -> f64 {
    x.exp()
}
extern "C" fn log(x: f64) -> f64 {
    x.ln()
}
extern "C" fn sin(x: f64) -> f64 {
    x.sin()
}
extern "C" fn cos(x: f64) -> f64 {
    x.cos()
}
extern "C" fn tan(x: f64) -> f64 {
    x.tan()
}
extern "C" fn atan(x: f64) -> f64 {
    x.atan()
}
extern "C" fn tanh(x: f64) -> f64 {
    x.tanh()
}
extern "C" fn cosh(x: f64) -> f64 {
    x.cosh()
}
extern "C" fn sinh(x: f64) -> f64 {
    x.sinh()
}
extern "C" fn abs(x: f64) -> f64 {
    x.abs()
}
extern "C" fn step(x: f64) -> f64 {
    if x.is_nan() {
        x
    } else if x > 0.0 {
        1.0
    } else {
        0.0
    }
}
extern "C" fn sign(x: f64) -> f64 {
    if x.is_nan() {
        x
    } else if x > 0.0 {
        1.0
    } else if x < 0.0 {
        -1.0
    } else {
        0.0
    }
}

extern "C" fn asinh(x: f64) -> f64 {
    x.asinh()
}

/// `c`, a constant local derivative.
fn constant(c: f64) -> Option<Local> {
    Some(Local::Mul(c, None))
}

/// `1 + u^2` (or `1 - u^2` for `minus`) of a node `u`: the derivatives of `tan`, `tanh`, `atan`.
fn one_and_square(g: &mut Graph, u: NodeId, minus: bool) -> NodeId {
    let one = g.constant(1.0);
    let u2 = g.powi(u, 2);
    if minus {
        g.sub(one, u2)
    } else {
        g.add2(one, u2)
    }
}

/// `sin`, `cos`, `sinh`, `cosh`: a member of the pair one operation computes.
fn sin_cos_series(t: &mut Builder, op: Unary, _dst: u32, a: u32) -> UnarySeries {
    let hyperbolic = matches!(op, Unary::Sinh | Unary::Cosh);
    let (sin, cos) = t.sin_cos(a, hyperbolic);
    UnarySeries::Slot(if matches!(op, Unary::Sin | Unary::Sinh) {
        sin
    } else {
        cos
    })
}

/// `tan`, `tanh`: `w' = (1 +- w^2) a'`.
fn tan_series(t: &mut Builder, op: Unary, dst: u32, a: u32) -> UnarySeries {
    UnarySeries::Op(TapeOp::Tan {
        dst,
        a,
        sq: t.slot(),
        hyperbolic: op == Unary::Tanh,
    })
}

/// `atan`, `asinh`: `w' = a' / d` with `d = 1 + a^2`, `sqrt(1 + a^2)`.
fn inverse_series(t: &mut Builder, op: Unary, dst: u32, a: u32) -> UnarySeries {
    let (sq, d) = (t.slot(), t.slot());
    let one = t.one();
    t.push(TapeOp::Square(sq, a));
    if op == Unary::Atan {
        t.push(TapeOp::Add(d, sq, one));
    } else {
        let e = t.slot();
        t.push(TapeOp::Add(e, sq, one));
        t.push(TapeOp::Sqrt(d, e));
    }
    UnarySeries::Op(TapeOp::Inverse { dst, a, d, f: op })
}

/// Indexed by `Unary as usize`.
pub(crate) const UNARY_OPS: &[UnaryOp] = &[
    UnaryOp {
        op: Unary::Neg,
        name: None,
        eval: neg,
        derivative: |_, _, _| constant(-1.0),
        lowering: Lowering::Inline,
        signs: SignsOf::Opposite,
        keeps_zero: true,
        finite: true,
        kinks: None,
        taylor: Some(|_, _, dst, a| UnarySeries::Op(TapeOp::Neg(dst, a))),
    },
    UnaryOp {
        op: Unary::Sqrt,
        name: Some("sqrt"),
        eval: sqrt,
        // (sqrt u)' = 1 / (2 sqrt u), written 0.5 / v: exact scaling, and the node v is reused.
        derivative: |_, _, v| Some(Local::Div(0.5, v)),
        lowering: Lowering::Inline,
        signs: SignsOf::Any,
        keeps_zero: false,
        finite: false,
        kinks: Some(|u, span| u.power(0.5, span, true)),
        taylor: Some(|_, _, dst, a| UnarySeries::Op(TapeOp::Sqrt(dst, a))),
    },
    UnaryOp {
        op: Unary::Exp,
        name: Some("exp"),
        eval: exp,
        derivative: |_, _, v| Some(Local::Mul(1.0, Some(v))),
        lowering: Lowering::Call,
        signs: SignsOf::Positive,
        keeps_zero: false,
        finite: true,
        kinks: None,
        taylor: Some(|_, _, dst, a| UnarySeries::Op(TapeOp::Exp(dst, a))),
    },
    UnaryOp {
        op: Unary::Log,
        name: Some("log"),
        eval: log,
        derivative: |_, u, _| Some(Local::Div(1.0, u)),
        lowering: Lowering::Call,
        signs: SignsOf::Any,
        keeps_zero: false,
        finite: false,
        kinks: None,
        taylor: Some(|_, _, dst, a| UnarySeries::Op(TapeOp::Log(dst, a))),
    },
    UnaryOp {
        op: Unary::Sin,
        name: Some("sin"),
        eval: sin,
        derivative: |g, u, _| Some(Local::Mul(1.0, Some(g.unary(Unary::Cos, u)))),
        lowering: Lowering::Call,
        signs: SignsOf::Any,
        keeps_zero: true,
        finite: true,
        kinks: None,
        taylor: Some(sin_cos_series),
    },
    UnaryOp {
        op: Unary::Cos,
        name: Some("cos"),
        eval: cos,
        derivative: |g, u, _| Some(Local::Mul(-1.0, Some(g.unary(Unary::Sin, u)))),
        lowering: Lowering::Call,
        signs: SignsOf::Any,
        keeps_zero: false,
        finite: true,
        kinks: None,
        taylor: Some(sin_cos_series),
    },
    UnaryOp {
        op: Unary::Tan,
        name: Some("tan"),
        eval: tan,
        // 1 + tan^2 reuses the tan node (no cos, no division).
        derivative: |g, _, v| Some(Local::Mul(1.0, Some(one_and_square(g, v, false)))),
        lowering: Lowering::Call,
        signs: SignsOf::Any,
        keeps_zero: false,
        finite: false,
        kinks: None,
        taylor: Some(tan_series),
    },
    UnaryOp {
        op: Unary::Atan,
        name: Some("atan"),
        eval: atan,
        derivative: |g, u, _| Some(Local::Div(1.0, one_and_square(g, u, false))),
        lowering: Lowering::Call,
        signs: SignsOf::Same,
        keeps_zero: true,
        finite: true,
        kinks: None,
        taylor: Some(inverse_series),
    },
    UnaryOp {
        op: Unary::Tanh,
        name: Some("tanh"),
        eval: tanh,
        derivative: |g, _, v| Some(Local::Mul(1.0, Some(one_and_square(g, v, true)))),
        lowering: Lowering::Call,
        signs: SignsOf::Same,
        keeps_zero: true,
        finite: true,
        kinks: None,
        taylor: Some(tan_series),
    },
    UnaryOp {
        op: Unary::Cosh,
        name: Some("cosh"),
        eval: cosh,
        derivative: |g, u, _| Some(Local::Mul(1.0, Some(g.unary(Unary::Sinh, u)))),
        lowering: Lowering::Call,
        signs: SignsOf::Positive,
        keeps_zero: false,
        finite: true,
        kinks: None,
        taylor: Some(sin_cos_series),
    },
    UnaryOp {
        op: Unary::Sinh,
        name: Some("sinh"),
        eval: sinh,
        derivative: |g, u, _| Some(Local::Mul(1.0, Some(g.unary(Unary::Cosh, u)))),
        lowering: Lowering::Call,
        signs: SignsOf::Same,
        keeps_zero: true,
        finite: true,
        kinks: None,
        taylor: Some(sin_cos_series),
    },
    UnaryOp {
        op: Unary::Abs,
        name: Some("abs"),
        eval: abs,
        derivative: |g, u, _| Some(Local::Mul(1.0, Some(g.unary(Unary::Sign, u)))),
        lowering: Lowering::Inline,
        signs: SignsOf::Square,
        keeps_zero: false,
        finite: false,
        kinks: Some(|u, span| u.abs(span)),
        taylor: None,
    },
    UnaryOp {
        op: Unary::Step,
        name: Some("step"),
        eval: step,
        derivative: |_, _, _| None,
        lowering: Lowering::Inline,
        signs: SignsOf::NonNegative,
        keeps_zero: false,
        finite: false,
        kinks: Some(|u, span| Info::jump(SmoothnessLimit::Step, span, &[u], Signs::NONNEG)),
        taylor: None,
    },
    UnaryOp {
        op: Unary::Sign,
        name: Some("sign"),
        eval: sign,
        derivative: |_, _, _| None,
        lowering: Lowering::Inline,
        signs: SignsOf::Same,
        keeps_zero: false,
        finite: false,
        kinks: Some(|u, span| Info::jump(SmoothnessLimit::Sign, span, &[u], u.signs)),
        taylor: None,
    },
    UnaryOp {
        op: Unary::Asinh,
        name: Some("asinh"),
        eval: asinh,
        // 1 / sqrt(1 + u^2)
        derivative: |g, u, _| {
            let s = one_and_square(g, u, false);
            Some(Local::Div(1.0, g.unary(Unary::Sqrt, s)))
        },
        lowering: Lowering::Call,
        signs: SignsOf::Same,
        keeps_zero: true,
        finite: true,
        kinks: None,
        taylor: Some(inverse_series),
    },
];

extern "C" fn add(a: f64, b: f64) -> f64 {
    a + b
}
extern "C" fn sub(a: f64, b: f64) -> f64 {
    a - b
}
extern "C" fn mul(a: f64, b: f64) -> f64 {
    a * b
}
extern "C" fn div(a: f64, b: f64) -> f64 {
    a / b
}
extern "C" fn pow(a: f64, b: f64) -> f64 {
    a.powf(b)
}
extern "C" fn atan2(a: f64, b: f64) -> f64 {
    a.atan2(b)
}
extern "C" fn max(a: f64, b: f64) -> f64 {
    if a.is_nan() || b.is_nan() {
        f64::NAN
    } else if a >= b {
        a
    } else {
        b
    }
}
extern "C" fn min(a: f64, b: f64) -> f64 {
    if a.is_nan() || b.is_nan() {
        f64::NAN
    } else if a <= b {
        a
    } else {
        b
    }
}

/// Indexed by `Binary as usize`.
pub(crate) const BINARY_OPS: &[BinaryOp] = &[
    BinaryOp {
        op: Binary::Add,
        name: None,
        symbol: "+",
        eval: add,
        lowering: Lowering::Inline,
        derivatives: None,
        kinks: None,
        taylor: None,
    },
    BinaryOp {
        op: Binary::Sub,
        name: None,
        symbol: "-",
        eval: sub,
        lowering: Lowering::Inline,
        derivatives: None,
        kinks: None,
        taylor: None,
    },
    BinaryOp {
        op: Binary::Mul,
        name: None,
        symbol: "*",
        eval: mul,
        lowering: Lowering::Inline,
        derivatives: None,
        kinks: None,
        taylor: None,
    },
    BinaryOp {
        op: Binary::Div,
        name: None,
        symbol: "/",
        eval: div,
        lowering: Lowering::Inline,
        derivatives: None,
        kinks: None,
        taylor: None,
    },
    BinaryOp {
        op: Binary::Pow,
        name: None,
        symbol: "^",
        eval: pow,
        lowering: Lowering::Call,
        derivatives: None,
        kinks: None,
        taylor: None,
    },
    BinaryOp {
        op: Binary::Atan2,
        name: Some("atan2"),
        symbol: "atan2",
        eval: atan2,
        lowering: Lowering::Call,
        derivatives: Some(BinaryDerivatives {
            // da = s b / (a^2 + b^2), db = -(s a) / (a^2 + b^2)
            adjoint: |g, [a, b, _], s, varies| {
                let a2 = g.powi(a, 2);
                let b2 = g.powi(b, 2);
                let den = g.add2(a2, b2);
                let da = varies[0].then(|| {
                    let sb = mul_sorted(g, s, b);
                    (1.0, Some(g.div(sb, den)))
                });
                let db = varies[1].then(|| {
                    let sa = mul_sorted(g, s, a);
                    (-1.0, Some(g.div(sa, den)))
                });
                [da, db]
            },
            // (b a' - a b') / (a^2 + b^2)
            tangent: |g, [a, b, _], [da, db]| {
                let x = da.map(|da| mul_sorted(g, b, da));
                let y = db.map(|db| mul_sorted(g, a, db));
                let num = sub_opt(g, x, y).expect("a tangent is present");
                let a2 = g.powi(a, 2);
                let b2 = g.powi(b, 2);
                let den = g.add2(a2, b2);
                g.div(num, den)
            },
        }),
        kinks: Some(|a, b, span, _| Info::jump(SmoothnessLimit::Atan2, span, &[a, b], Signs::ALL)),
        // w' = (b a' - a b') / d with d = a^2 + b^2.
        taylor: Some(|t, dst, [a, b]| {
            let (a2, b2, d) = (t.slot(), t.slot(), t.slot());
            t.push(TapeOp::Square(a2, a));
            t.push(TapeOp::Square(b2, b));
            t.push(TapeOp::Add(d, a2, b2));
            TapeOp::Atan2 { dst, a, b, d }
        }),
    },
    BinaryOp {
        op: Binary::Max,
        name: Some("max"),
        symbol: "max",
        eval: max,
        lowering: Lowering::Inline,
        derivatives: None,
        kinks: Some(|a, b, span, zero| Info::min_max(true, span, a, b, zero[0], zero[1])),
        taylor: None,
    },
    BinaryOp {
        op: Binary::Min,
        name: Some("min"),
        symbol: "min",
        eval: min,
        lowering: Lowering::Inline,
        derivatives: None,
        kinks: Some(|a, b, span, zero| Info::min_max(false, span, a, b, zero[0], zero[1])),
        taylor: None,
    },
];

/// How many operations are [`Lowering::Call`]: the C kernels' callback slots.
pub(crate) const UNARY_CALLS: usize = {
    let mut n = 0;
    let mut i = 0;
    while i < UNARY_OPS.len() {
        if matches!(UNARY_OPS[i].lowering, Lowering::Call) {
            n += 1;
        }
        i += 1;
    }
    n
};

/// The operations the compiled code calls, in table order (the C kernels' `env` slots).
pub(crate) fn called() -> impl Iterator<Item = &'static UnaryOp> {
    UNARY_OPS.iter().filter(|d| d.lowering == Lowering::Call)
}

/// How many two-argument operations are [`Lowering::Call`].
pub(crate) const BINARY_CALLS: usize = {
    let mut n = 0;
    let mut i = 0;
    while i < BINARY_OPS.len() {
        if matches!(BINARY_OPS[i].lowering, Lowering::Call) {
            n += 1;
        }
        i += 1;
    }
    n
};

/// The two-argument operations the compiled code calls, in table order (the C kernels' `env`
/// slots after the unary ones).
pub(crate) fn called_binary() -> impl Iterator<Item = &'static BinaryOp> {
    BINARY_OPS.iter().filter(|d| d.lowering == Lowering::Call)
}

/// The signs of `op(u)` from those of `u`.
pub(crate) fn signs_of(op: Unary, u: Signs) -> Signs {
    match op.def().signs {
        SignsOf::Positive => Signs::POS,
        SignsOf::Same => u,
        SignsOf::Opposite => u.neg(),
        SignsOf::Square => u.square(),
        SignsOf::NonNegative => Signs::NONNEG,
        SignsOf::Any => Signs::ALL,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A two-argument function a source calls carries its smoothness rule, and, unless it
    /// selects an operand (`max`, `min`: one-sided derivatives written by `diff`, no series),
    /// its derivatives and its Taylor decomposition, so the lowering, `diff` and Taylor's method
    /// never meet it without a rule. The infix operators have theirs where they are built.
    #[test]
    fn every_function_a_source_calls_has_its_rules() {
        for d in BINARY_OPS {
            if d.name.is_none() {
                assert!(d.kinks.is_none() && d.derivatives.is_none() && d.taylor.is_none());
                continue;
            }
            let selects = matches!(d.op, Binary::Max | Binary::Min);
            assert!(d.kinks.is_some(), "{:?}", d.op);
            assert_eq!(d.derivatives.is_some(), !selects, "{:?}", d.op);
            assert_eq!(d.taylor.is_some(), !selects, "{:?}", d.op);
        }
    }

    /// Every function has its Taylor decomposition but those with a kink or a jump.
    #[test]
    fn every_function_with_a_series_has_its_decomposition() {
        for d in UNARY_OPS {
            let no_series = matches!(d.op, Unary::Abs | Unary::Step | Unary::Sign);
            assert_eq!(d.taylor.is_none(), no_series, "{:?}", d.op);
        }
    }

    #[test]
    fn the_table_is_in_the_order_of_the_enum() {
        for (i, d) in UNARY_OPS.iter().enumerate() {
            assert_eq!(d.op as usize, i, "{:?}", d.op);
        }
        for (i, d) in BINARY_OPS.iter().enumerate() {
            assert_eq!(d.op as usize, i, "{:?}", d.op);
        }
    }
}
