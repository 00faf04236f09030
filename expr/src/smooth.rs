//! How many continuous derivatives a lowered expression has, and which operation limits it.
//!
//! The variational method integrates the tangent dynamics, which needs the Hessian of the
//! potential along the orbit: a potential whose second derivative jumps (a kink in the force)
//! gives a tangent map that is wrong at every crossing, silently. So lowering computes the
//! smoothness on the syntax tree (where parameter values are known, so `max(0, d)^(5/2)` is
//! recognised as C^2) and the caller refuses the method with a message naming the operation.
//!
//! Per subexpression we track: the lowest-order operation that limits it (`LimitAt`), the
//! set of signs it can take (to know that `1 + q^2` never reaches 0, so its square root is
//! smooth), and whether it is a "zero kink": Lipschitz and equal to 0 exactly where it is not
//! smooth (`abs(u)`, `max(0, u)`, `min(u, 0)` with a smooth `u`, and constant or smooth
//! multiples of those), whose powers gain smoothness (`max(0, d)^2` is C^1).
//!
//! Singularities are not losses of smoothness: `log(u)`, `1/u`, `u^-2`, `tan(u)` are infinite
//! where `u` reaches 0 (or pi/2), but an orbit of finite energy never reaches an infinite
//! potential, and everywhere it does move these functions are analytic; the tangent dynamics
//! there is exact. They are treated as smooth.
//!
//! One rule decides between a pole and a kink for roots, so that every spelling of a
//! Newtonian or Coulomb potential is judged alike: a value that is 0 at every point where it is
//! not smooth (`sqrt(u)`, `u^(3/2)`, `abs(u)`, `max(0, u)` with a smooth `u`, and products of
//! such values with each other and with smooth pole-free factors: `sqrt(r2)*r2`) is
//! "vanishing". Its reciprocal or negative power (`1/sqrt(r2)`, `sqrt(r2)^-3`,
//! `r2^(-1/2)`, `1/(sqrt(r2)*r2)`) is infinite at every one of those points and smooth
//! wherever it is finite: a pole, accepted. The non-smoothness it covered is kept aside
//! (`absorbed`) and comes back when something can undo the pole: a factor that depends on
//! the state and may be 0 (`x/sqrt(x^2)` is `sign(x)`, `x/sqrt(x^2 + y^2)` is bounded and jumps
//! at the origin), a reciprocal of the pole (`1/(1/sqrt(r2))`), or a function of it
//! (`sin(1/abs(x))` oscillates without bound and is crossed). Factors that do not depend on the
//! state (masses, charges, lane parameters) or cannot be 0 (`1 + q^2`, `exp(q)`) keep the pole.
//! Sums keep it too: poles of different terms are assumed not to cancel each other exactly.

use crate::error::{Span, locate};
use crate::graph::Unary;

/// The order of an infinitely differentiable expression in [`LimitAt::order`] terms.
pub(crate) const SMOOTH: i32 = i32::MAX;

/// The smoothness of a whole lowered expression.
#[derive(Debug, Clone, PartialEq)]
pub struct Smoothness {
    /// Derivatives up to this order are continuous (`u32::MAX`: infinitely smooth). A
    /// discontinuous expression also has 0 here; then `limited_by.order` is -1.
    pub order: u32,
    /// The leftmost operation that attains the lowest order; `None` when smooth.
    pub limited_by: Option<Limit>,
}

/// The operation that limits the smoothness, for messages.
#[derive(Debug, Clone, PartialEq)]
pub struct Limit {
    /// As written: `"abs"`, `"max"`, `"step"`, `"if"`, `"sqrt"`, `"^ 2.5"`, a table's name.
    pub operation: String,
    pub span: Span,
    pub line: usize,
    pub column: usize,
    /// Derivatives up to this order are continuous; -1 for a jump of the function itself.
    pub order: i32,
    /// What goes wrong there, as a phrase that follows the operation's name and position:
    /// `"has a kink (continuous, first derivative jumps)"`.
    pub reason: String,
}

impl Smoothness {
    /// Infinitely smooth.
    pub fn smooth() -> Self {
        Self {
            order: u32::MAX,
            limited_by: None,
        }
    }

    pub fn is_smooth(&self) -> bool {
        self.limited_by.is_none()
    }

    /// `Ok` if derivatives up to `order` are continuous, else a one-line message for the user:
    /// `the variational method (vm) needs continuous second derivatives, but 'abs' at line 1,
    /// column 5 has a kink (continuous, first derivative jumps); use mpm`. The suggestion of
    /// the multi-particle method (which needs only the forces) is added when second or higher
    /// derivatives are required and the function itself is at least continuous.
    pub fn require(&self, order: u32, purpose: &str) -> Result<(), String> {
        let Some(limit) = &self.limited_by else {
            return Ok(());
        };
        if i64::from(limit.order) >= i64::from(order) {
            return Ok(());
        }
        let need = match order {
            0 => "a continuous function".to_string(),
            1 => "continuous first derivatives".to_string(),
            2 => "continuous second derivatives".to_string(),
            3 => "continuous third derivatives".to_string(),
            n => format!("continuous derivatives up to order {n}"),
        };
        let hint = if order >= 2 && limit.order >= 0 {
            "; use mpm"
        } else {
            ""
        };
        Err(format!(
            "{purpose} needs {need}, but '{}' at line {}, column {} {}{hint}",
            limit.operation, limit.line, limit.column, limit.reason
        ))
    }
}

/// What limits smoothness at an operation (kept `Copy` so lowering a large lattice sum
/// allocates nothing for it; turned into text once, by [`finish`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) enum SmoothnessLimit {
    Abs,
    Min,
    Max,
    Step,
    Sign,
    If,
    Piecewise,
    Atan2,
    /// `u^a` with a fractional `a > 0` where `u` may reach 0; `sqrt` is `a = 1/2`.
    FracPow {
        exp: f64,
        sqrt: bool,
    },
    /// A whole power `a >= 2` of a zero kink.
    KinkPow {
        exp: f64,
    },
    /// `u^v` with a variable exponent and a base that may reach 0.
    VarPow,
    Table(u32),
}

#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct LimitAt {
    pub span: Span,
    pub order: i32,
    pub kind: SmoothnessLimit,
}

/// The lower order wins; on a tie, the leftmost operation.
pub(crate) fn worse(a: Option<LimitAt>, b: Option<LimitAt>) -> Option<LimitAt> {
    match (a, b) {
        (None, x) | (x, None) => x,
        (Some(x), Some(y)) => {
            if (y.order, y.span.start) < (x.order, x.span.start) {
                Some(y)
            } else {
                Some(x)
            }
        }
    }
}

/// The set of signs a value can take: a bit each for negative, zero and positive.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct Signs(u8);

impl Signs {
    pub const NEG: Signs = Signs(1);
    pub const ZERO: Signs = Signs(2);
    pub const POS: Signs = Signs(4);
    pub const NONNEG: Signs = Signs(6);
    pub const ALL: Signs = Signs(7);

    pub fn of(c: f64) -> Signs {
        if c > 0.0 {
            Self::POS
        } else if c < 0.0 {
            Self::NEG
        } else if c == 0.0 {
            Self::ZERO
        } else {
            Self::ALL
        }
    }

    fn has(self, s: Signs) -> bool {
        self.0 & s.0 != 0
    }

    pub(crate) fn union(self, s: Signs) -> Signs {
        Signs(self.0 | s.0)
    }

    /// Provably positive (never 0).
    pub fn positive(self) -> bool {
        self == Self::POS
    }

    fn without_zero(self) -> Signs {
        match Signs(self.0 & !Self::ZERO.0) {
            Signs(0) => Self::ALL,
            s => s,
        }
    }

    /// The signs of `|x|` or `x^2` (not `x * y`: the factors are the same value).
    pub(crate) fn square(self) -> Signs {
        let mut out = Signs(0);
        if self.has(Self::ZERO) {
            out = out.union(Self::ZERO);
        }
        if self.has(Self::NEG) || self.has(Self::POS) {
            out = out.union(Self::POS);
        }
        out
    }

    pub(crate) fn neg(self) -> Signs {
        Signs((self.0 & 2) | ((self.0 & 1) << 2) | ((self.0 & 4) >> 2))
    }

    /// Combine every pair of possible signs with `f` (on the representatives -1, 0, 1).
    fn pairwise(self, other: Signs, f: impl Fn(i8, i8) -> Signs) -> Signs {
        let members = |s: Signs| {
            [(Self::NEG, -1i8), (Self::ZERO, 0), (Self::POS, 1)]
                .into_iter()
                .filter(move |(m, _)| s.has(*m))
                .map(|(_, v)| v)
        };
        let mut out = Signs(0);
        for x in members(self) {
            for y in members(other) {
                out = out.union(f(x, y));
            }
        }
        if out.0 == 0 { Self::ALL } else { out }
    }

    fn add(self, other: Signs) -> Signs {
        self.pairwise(other, |x, y| match (x, y) {
            (0, v) | (v, 0) => Signs::of(f64::from(v)),
            (a, b) if a == b => Signs::of(f64::from(a)),
            _ => Self::ALL,
        })
    }

    fn mul(self, other: Signs) -> Signs {
        self.pairwise(other, |x, y| Signs::of(f64::from(x * y)))
    }

    fn max(self, other: Signs) -> Signs {
        self.pairwise(other, |x, y| Signs::of(f64::from(x.max(y))))
    }

    fn min(self, other: Signs) -> Signs {
        self.pairwise(other, |x, y| Signs::of(f64::from(x.min(y))))
    }
}

/// Smoothness facts about one subexpression.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Info {
    pub limit: Option<LimitAt>,
    pub signs: Signs,
    pub zero_kink: bool,
    /// 0 at every point where it is not smooth (see the module documentation); true of every
    /// smooth value and implied by `zero_kink`.
    pub vanishing: bool,
    /// Finite wherever its inputs are (no division, negative power, `log`, `tan`, ...).
    pub pole_free: bool,
    /// Depends on the state (a variable or the time), not only on constants and parameters.
    pub varies: bool,
    /// The worst limit that a pole covers: this value is infinite at every point where that
    /// operation is not smooth, so it does not count unless the pole is undone.
    pub absorbed: Option<LimitAt>,
}

impl Info {
    pub fn constant(c: f64) -> Self {
        Self {
            limit: None,
            signs: Signs::of(c),
            zero_kink: false,
            vanishing: true,
            pole_free: c.is_finite(),
            varies: false,
            absorbed: None,
        }
    }

    /// A smooth value anywhere in `min..=max` (a parameter each lane brings: its signs are
    /// those of the range).
    pub fn within(min: f64, max: f64) -> Self {
        let mut signs = Signs::of(min).union(Signs::of(max));
        if min < 0.0 && max > 0.0 {
            signs = Signs::ALL;
        }
        Self {
            limit: None,
            signs,
            zero_kink: false,
            vanishing: true,
            pole_free: true,
            varies: false,
            absorbed: None,
        }
    }

    /// A smooth value of unknown sign (a variable).
    pub fn variable() -> Self {
        Self {
            limit: None,
            signs: Signs::ALL,
            zero_kink: false,
            vanishing: true,
            pole_free: true,
            varies: true,
            absorbed: None,
        }
    }

    pub fn is_smooth(&self) -> bool {
        self.limit.is_none()
    }

    /// Can be 0 somewhere along an orbit (and so can undo a pole it multiplies).
    fn may_vanish_on_orbit(&self) -> bool {
        self.varies && self.signs.has(Signs::ZERO)
    }

    /// Its limit with what its poles cover put back: for an operation that can undo a pole.
    fn undone(&self) -> Option<LimitAt> {
        worse(self.limit, self.absorbed)
    }

    /// A vanishing pole-free value: its reciprocal is a pole at every point where it is not
    /// smooth.
    fn covers_by_reciprocal(&self) -> bool {
        self.vanishing && self.pole_free
    }

    pub fn neg(self) -> Self {
        Self {
            signs: self.signs.neg(),
            ..self
        }
    }

    pub fn add(self, other: Self) -> Self {
        let limit = worse(self.limit, other.limit);
        Self {
            limit,
            signs: self.signs.add(other.signs),
            zero_kink: false,
            vanishing: limit.is_none(),
            pole_free: self.pole_free && other.pole_free,
            varies: self.varies || other.varies,
            absorbed: worse(self.absorbed, other.absorbed),
        }
    }

    pub fn sub(self, other: Self) -> Self {
        self.add(other.neg())
    }

    /// The facts of a product other than its signs and `zero_kink`: a pole times a factor that
    /// may be 0 on the orbit is no longer known to be a pole.
    fn product(self, other: Self) -> Self {
        let mut limit = worse(self.limit, other.limit);
        let mut absorbed = None;
        for (pole, factor) in [(&self, &other), (&other, &self)] {
            if factor.may_vanish_on_orbit() {
                limit = worse(limit, pole.absorbed);
            } else {
                absorbed = worse(absorbed, pole.absorbed);
            }
        }
        let pole_free = self.pole_free && other.pole_free;
        Self {
            limit,
            signs: self.signs.mul(other.signs),
            zero_kink: false,
            vanishing: pole_free && self.vanishing && other.vanishing,
            pole_free,
            varies: self.varies || other.varies,
            absorbed,
        }
    }

    /// `1 / self`: a pole wherever a vanishing value is not smooth; anything else keeps its
    /// limit and loses any pole it had (`1/(1/sqrt(r2))` is `sqrt(r2)`).
    fn reciprocal(self) -> Self {
        let (limit, absorbed) = if self.covers_by_reciprocal() {
            (None, self.limit)
        } else {
            (self.undone(), None)
        };
        Self {
            limit,
            signs: self.signs.without_zero(),
            zero_kink: false,
            vanishing: limit.is_none(),
            pole_free: self.pole_free && !self.signs.has(Signs::ZERO),
            varies: self.varies,
            absorbed,
        }
    }

    /// A smooth multiple of a zero kink is still one (Lipschitz, 0 at the kink).
    pub fn mul(self, other: Self) -> Self {
        Self {
            zero_kink: (self.zero_kink && other.is_smooth())
                || (other.zero_kink && self.is_smooth()),
            ..self.product(other)
        }
    }

    /// Division by 0 is a singularity, not a kink (see the module documentation).
    pub fn div(self, other: Self) -> Self {
        Self {
            signs: self.signs.mul(other.signs.without_zero()),
            zero_kink: self.zero_kink && other.is_smooth(),
            ..self.product(other.reciprocal())
        }
    }

    /// A smooth (where finite) function of `self`: `exp`, `log`, `sin`, ..., and the signs it
    /// can take. A function of a pole may undo it (`sin(1/abs(q))` is bounded and crossed).
    pub fn smooth_fn(self, op: Unary) -> Self {
        let def = op.def();
        let signs = crate::ops::signs_of(op, self.signs);
        // Odd functions with f(0) = 0, finite wherever their argument is: they keep a value
        // vanishing (`sin(sqrt(r2))`).
        let keeps_zero = def.keeps_zero;
        let finite = def.finite;
        let limit = self.undone();
        Self {
            limit,
            signs,
            zero_kink: false,
            vanishing: limit.is_none() || (keeps_zero && self.covers_by_reciprocal()),
            pole_free: finite && self.pole_free,
            varies: self.varies,
            absorbed: None,
        }
    }

    /// `abs(u)`: a kink where `u` crosses 0.
    pub fn abs(self, span: Span) -> Self {
        let own = LimitAt {
            span,
            order: 0,
            kind: SmoothnessLimit::Abs,
        };
        Self {
            limit: worse(Some(own), self.limit),
            signs: self.signs.square(),
            zero_kink: self.is_smooth(),
            vanishing: self.covers_by_reciprocal(),
            pole_free: self.pole_free,
            varies: self.varies,
            absorbed: self.absorbed,
        }
    }

    /// `max(a, b)` or `min(a, b)`; `a_zero`/`b_zero` say which argument is the constant 0.
    pub fn min_max(is_max: bool, span: Span, a: Self, b: Self, a_zero: bool, b_zero: bool) -> Self {
        let own = LimitAt {
            span,
            order: 0,
            kind: if is_max {
                SmoothnessLimit::Max
            } else {
                SmoothnessLimit::Min
            },
        };
        let zero_kink = (a_zero && b.is_smooth()) || (b_zero && a.is_smooth());
        let pole_free = a.pole_free && b.pole_free;
        Self {
            limit: worse(Some(own), worse(a.undone(), b.undone())),
            signs: if is_max {
                a.signs.max(b.signs)
            } else {
                a.signs.min(b.signs)
            },
            zero_kink,
            vanishing: zero_kink && pole_free,
            pole_free,
            varies: a.varies || b.varies,
            absorbed: None,
        }
    }

    /// An operation whose value jumps (`step`, `sign`, `if`, `atan2`) at `span`, combining
    /// the facts of the parts that flow into its value.
    pub fn jump(kind: SmoothnessLimit, span: Span, parts: &[Self], signs: Signs) -> Self {
        let own = LimitAt {
            span,
            order: -1,
            kind,
        };
        let mut limit = Some(own);
        for p in parts {
            limit = worse(limit, p.undone());
        }
        Self {
            limit,
            signs,
            zero_kink: false,
            vanishing: false,
            pole_free: parts.iter().all(|p| p.pole_free),
            varies: parts.iter().any(|p| p.varies),
            absorbed: None,
        }
    }

    /// `if` or `piecewise` over branch facts.
    pub fn select(kind: SmoothnessLimit, span: Span, branches: &[Self]) -> Self {
        let signs = branches.iter().fold(Signs(0), |s, b| s.union(b.signs));
        Self::jump(
            kind,
            span,
            branches,
            if signs.0 == 0 { Signs::ALL } else { signs },
        )
    }

    /// `self ^ a` for a constant `a` (`sqrt` is `a = 1/2` with `sqrt` set). A negative power
    /// is the reciprocal of the positive one.
    pub fn power(self, a: f64, span: Span, sqrt: bool) -> Self {
        if a < 0.0 && a.is_finite() {
            return self.power(-a, span, sqrt).reciprocal();
        }
        if a == 0.0 || !a.is_finite() {
            return Self {
                limit: None,
                signs: if a == 0.0 || self.signs.positive() {
                    Signs::POS
                } else {
                    Signs::NONNEG
                },
                zero_kink: false,
                vanishing: true,
                pole_free: a == 0.0,
                varies: self.varies && a != 0.0,
                absorbed: None,
            };
        }
        let whole = a.fract() == 0.0;
        let signs = if whole {
            let even = (a / 2.0).fract() == 0.0;
            if even {
                self.signs.square()
            } else {
                self.signs
            }
        } else if self.signs.positive() {
            Signs::POS
        } else {
            Signs::NONNEG
        };
        let (limit, absorbed) = if whole {
            if a >= 2.0 && self.zero_kink {
                (
                    Some(LimitAt {
                        span,
                        order: (a - 1.0).min(f64::from(SMOOTH - 1)) as i32,
                        kind: SmoothnessLimit::KinkPow { exp: a },
                    }),
                    None,
                )
            } else {
                // A positive whole power of a pole is a pole at the same points.
                (self.limit, self.absorbed)
            }
        } else if self.signs.positive() {
            // A base that never reaches 0 (a pole's power is still a pole).
            (self.limit, self.absorbed)
        } else {
            let own = Some(LimitAt {
                span,
                order: (a.ceil() - 1.0).min(f64::from(SMOOTH - 1)) as i32,
                kind: SmoothnessLimit::FracPow { exp: a, sqrt },
            });
            if self.zero_kink {
                // `max(0, d)^(5/2)`: the kink is absorbed, the power's order is what remains.
                (own, None)
            } else {
                (worse(self.undone(), own), None)
            }
        };
        Self {
            limit,
            signs,
            zero_kink: false,
            // `u^a` is 0 exactly where `u` is: where `u` is not smooth and where the power is
            // not (u = 0).
            vanishing: limit.is_none() || self.covers_by_reciprocal(),
            pole_free: self.pole_free,
            varies: self.varies,
            absorbed,
        }
    }

    /// `self ^ exp` for a variable exponent: `exp(v log u)`, smooth where the base is
    /// positive; where the base may reach 0 we assume the worst a power of a smooth base can
    /// do there for exponents near the small positive ones (a kink, as `sqrt` of `q^2`).
    pub fn power_var(self, exp: Self, span: Span) -> Self {
        let parts = worse(self.undone(), exp.undone());
        let varies = self.varies || exp.varies;
        if self.signs.positive() {
            return Self {
                limit: parts,
                signs: Signs::POS,
                zero_kink: false,
                vanishing: parts.is_none(),
                pole_free: false,
                varies,
                absorbed: None,
            };
        }
        let own = LimitAt {
            span,
            order: 0,
            kind: SmoothnessLimit::VarPow,
        };
        Self {
            limit: worse(Some(own), parts),
            signs: if self.signs.has(Signs::NEG) {
                Signs::ALL
            } else {
                Signs::NONNEG
            },
            zero_kink: false,
            vanishing: false,
            pole_free: false,
            varies,
            absorbed: None,
        }
    }

    /// A tabulated function: a cubic spline, C^2.
    pub fn table(self, table: u32, span: Span) -> Self {
        let own = LimitAt {
            span,
            order: 2,
            kind: SmoothnessLimit::Table(table),
        };
        Self {
            limit: worse(Some(own), self.undone()),
            signs: Signs::ALL,
            zero_kink: false,
            vanishing: false,
            pole_free: self.pole_free,
            varies: self.varies,
            absorbed: None,
        }
    }
}

/// Text for the whole expression's facts. `table_name` names a table by its graph index.
pub(crate) fn finish(info: &Info, source: &str, table_name: impl Fn(u32) -> String) -> Smoothness {
    let Some(l) = info.limit else {
        return Smoothness::smooth();
    };
    let kink = "has a kink (continuous, first derivative jumps)";
    let jump = "jumps (the function itself is discontinuous)";
    let (operation, reason) = match l.kind {
        SmoothnessLimit::Abs => ("abs".to_string(), kink.to_string()),
        SmoothnessLimit::Min => ("min".to_string(), kink.to_string()),
        SmoothnessLimit::Max => ("max".to_string(), kink.to_string()),
        SmoothnessLimit::Step => ("step".to_string(), jump.to_string()),
        SmoothnessLimit::Sign => ("sign".to_string(), jump.to_string()),
        SmoothnessLimit::If | SmoothnessLimit::Piecewise => (
            if l.kind == SmoothnessLimit::If {
                "if"
            } else {
                "piecewise"
            }
            .to_string(),
            "jumps where its condition switches (whether the branches agree there is not checked)"
                .to_string(),
        ),
        SmoothnessLimit::Atan2 => (
            "atan2".to_string(),
            "jumps by 2 pi across the negative x axis (its first argument 0, second negative)"
                .to_string(),
        ),
        SmoothnessLimit::FracPow { exp, sqrt } => (
            if sqrt {
                "sqrt".to_string()
            } else {
                format!("^ {exp}")
            },
            if l.order == 0 {
                "is not differentiable where its base reaches 0 (continuous only)".to_string()
            } else {
                format!(
                    "has continuous derivatives only up to order {} where its base reaches 0 (derivative {} is infinite or jumps there)",
                    l.order,
                    i64::from(l.order) + 1
                )
            },
        ),
        SmoothnessLimit::KinkPow { exp } => (
            format!("^ {exp}"),
            format!(
                "is a power of a kink: continuous up to derivative {}, derivative {} jumps",
                l.order,
                i64::from(l.order) + 1
            ),
        ),
        SmoothnessLimit::VarPow => (
            "^".to_string(),
            "has a variable exponent and a base that may reach 0 (assumed continuous only)"
                .to_string(),
        ),
        SmoothnessLimit::Table(t) => (
            table_name(t),
            "is a cubic spline table (C^2: its third derivative jumps at the knots)".to_string(),
        ),
    };
    let (line, column, _, _) = locate(source, l.span.start);
    Smoothness {
        order: u32::try_from(l.order).unwrap_or(0),
        limited_by: Some(Limit {
            operation,
            span: l.span,
            line,
            column,
            order: l.order,
            reason,
        }),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sign_sets() {
        assert_eq!(Signs::POS.add(Signs::NONNEG), Signs::POS);
        assert_eq!(Signs::POS.add(Signs::NEG), Signs::ALL);
        assert_eq!(Signs::ALL.mul(Signs::ALL), Signs::ALL);
        assert_eq!(Signs::NEG.mul(Signs::NEG), Signs::POS);
        assert_eq!(Signs::ALL.neg(), Signs::ALL);
        assert_eq!(Signs::NONNEG.neg(), Signs(3));
        assert_eq!(Signs::ZERO.max(Signs::ALL), Signs::NONNEG);
        assert_eq!(Signs::ZERO.add(Signs::ZERO), Signs::ZERO);
        assert_eq!(Signs::ALL.square(), Signs::NONNEG);
        assert_eq!(Signs::NEG.square(), Signs::POS);
    }

    #[test]
    fn require_messages() {
        let s = Smoothness {
            order: 0,
            limited_by: Some(Limit {
                operation: "abs".into(),
                span: Span::new(4, 7),
                line: 1,
                column: 5,
                order: 0,
                reason: "has a kink (continuous, first derivative jumps)".into(),
            }),
        };
        assert_eq!(
            s.require(2, "the variational method (vm)").unwrap_err(),
            "the variational method (vm) needs continuous second derivatives, but 'abs' at line 1, column 5 has a kink (continuous, first derivative jumps); use mpm"
        );
        assert!(s.require(0, "x").is_ok());
        assert!(Smoothness::smooth().require(100, "x").is_ok());
    }
}
