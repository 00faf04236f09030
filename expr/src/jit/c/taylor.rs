//! A Taylor tape ([`crate::taylor`]) printed as C: the pass over the orders, every operation's
//! recurrence written out with its slots as constants, compiled by the system C compiler and
//! cached like the step kernels ([`super::build_with`]).
//!
//! Why: the tape interpreted dispatches once per operation and order (about 700 times per
//! Lorenz step with three vectors), which costs more than the recurrences' arithmetic; printed
//! as straight-line C inside the loop over the orders, the compiler overlaps the
//! independent recurrences.
//!
//! The same bits as the interpreter: each recurrence sums in the interpreter's order (the
//! four running sums of `cauchy`, the two of `weighted`, the loops of the others), with
//! `-ffp-contract=off` and no fast-math (the flags of every C kernel), and order 0 of the
//! transcendental functions calls the very Rust definitions through the callback table.

use std::fmt::Write as _;
use std::sync::atomic::AtomicBool;

use super::emit::{binary_slot, unary_slot};
use super::{CCompiler, ENV_BINARY, Mode};
use crate::graph::{Binary, Unary};
use crate::jit::JitError;
use crate::taylor::{Op, TaylorTape};

/// The compiled pass's C signature: the coefficient buffer (inputs and constants at order 0
/// set) and the callback table.
pub(crate) type CTaylorFn = unsafe extern "C" fn(c: *mut f64, env: *const usize);

const SYMBOL: &[u8] = b"chaoscope_taylor\0";

/// A loaded Taylor pass.
pub struct CTaylor {
    _library: libloading::Library,
    _memory_file: Option<std::fs::File>,
    pass: CTaylorFn,
    env: Box<[usize]>,
    /// Whether the library came from the cache (no compilation in this build).
    pub cached: bool,
}

impl std::fmt::Debug for CTaylor {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("CTaylor")
            .field("cached", &self.cached)
            .finish()
    }
}

impl CTaylor {
    /// Runs the pass over the orders on `coef` (a buffer of the tape it was compiled from).
    pub(crate) fn run(&self, coef: &mut [f64]) {
        // SAFETY: the source was printed from the tape whose buffer `coef` is (the caller's
        // invariant, checked by length there): every slot offset it writes or reads is below
        // `slots * (order + 1)`; `env` holds the callbacks the source indexes and lives with
        // `self`, as does the library.
        unsafe { (self.pass)(coef.as_mut_ptr(), self.env.as_ptr()) }
    }
}

/// Compiles (or loads from the cache) the pass of `tape`.
pub(crate) fn compile(
    tape: &TaylorTape,
    cc: &CCompiler,
    cancel: &AtomicBool,
) -> Result<CTaylor, JitError> {
    let src = source(tape);
    let env = super::env(&tape.tables, &[]);
    let (pass, _) = super::build_with(
        &src,
        cc,
        cancel,
        Mode::Build,
        |library, memory, _, cached| {
            // SAFETY: the generated source defines the symbol with exactly this signature.
            let pass = *unsafe { library.get::<CTaylorFn>(SYMBOL) }
                .map_err(|e| JitError::CCompiler(format!("the Taylor pass: {e}")))?;
            Ok(CTaylor {
                _library: library,
                _memory_file: memory,
                pass,
                env: env.clone(),
                cached,
            })
        },
    )?;
    Ok(pass)
}

/// Order 0 of a unary operation of `x`: a call of its Rust definition, or the IEEE square root.
fn unary0(op: Unary, x: &str) -> String {
    if crate::ops::called().any(|d| d.op == op) {
        format!("((fn1)env[{}])({x})", unary_slot(op))
    } else {
        assert!(op == Unary::Sqrt, "{op:?} at order 0 of a Taylor pass");
        format!("__builtin_sqrt({x})")
    }
}

fn binary0(op: Binary, a: &str, b: &str) -> String {
    format!("((fn2)env[{}])({a}, {b})", ENV_BINARY + binary_slot(op))
}

/// The C source of the pass of `tape`.
pub(crate) fn source(tape: &TaylorTape) -> String {
    let stride = tape.order + 1;
    let at = |slot: u32| slot as usize * stride;
    let mut s = String::from(
        r#"/* chaoscope Taylor pass, generated; see expr/src/jit/c/taylor.rs. */
#include <stdint.h>
typedef double (*fn1)(double);
typedef double (*fn2)(double, double);
const char chaoscope_kernel_hash[] = "@HASH@";
static inline double cauchy(const double *a, const double *b, int k) {
    double s0 = 0.0, s1 = 0.0, s2 = 0.0, s3 = 0.0;
    int j = 0;
    for (; j + 4 <= k + 1; j += 4) {
        s0 += a[j] * b[k - j];
        s1 += a[j + 1] * b[k - j - 1];
        s2 += a[j + 2] * b[k - j - 2];
        s3 += a[j + 3] * b[k - j - 3];
    }
    double s = (s0 + s1) + (s2 + s3);
    for (; j <= k; j++) s += a[j] * b[k - j];
    return s;
}
static inline double weighted(const double *a, const double *b, int k) {
    double s0 = 0.0, s1 = 0.0;
    int j = 1;
    for (; j + 1 <= k; j += 2) {
        s0 += (double)j * a[j] * b[k - j];
        s1 += (double)(j + 1) * a[j + 1] * b[k - j - 1];
    }
    if (j == k) s0 += (double)k * a[k] * b[0];
    return s0 + s1;
}
void chaoscope_taylor(double *restrict c, const uintptr_t *restrict env) {
"#,
    );
    let _ = writeln!(s, "  for (int k = 0; k < {}; k++) {{", tape.order);
    s.push_str("    const double kf = (double)k;\n");
    for op in &tape.ops {
        let line = match *op {
            Op::Add(d, a, b) => format!("c[{}+k] = c[{}+k] + c[{}+k];", at(d), at(a), at(b)),
            Op::Sub(d, a, b) => format!("c[{}+k] = c[{}+k] - c[{}+k];", at(d), at(a), at(b)),
            Op::Neg(d, a) => format!("c[{}+k] = -c[{}+k];", at(d), at(a)),
            Op::Scale(d, a, f) => format!("c[{}+k] = c[{}+k] * c[{}];", at(d), at(a), at(f)),
            Op::DivConst(d, a, f) => format!("c[{}+k] = c[{}+k] / c[{}];", at(d), at(a), at(f)),
            Op::Mul(d, a, b) => format!("c[{}+k] = cauchy(c+{}, c+{}, k);", at(d), at(a), at(b)),
            Op::Square(d, a) => format!("c[{}+k] = cauchy(c+{}, c+{}, k);", at(d), at(a), at(a)),
            Op::Copy(d, a) => format!("c[{}+k] = c[{}+k];", at(d), at(a)),
            Op::One(d) => format!("c[{}+k] = k == 0 ? 1.0 : 0.0;", at(d)),
            Op::Div(d, a, b) => format!(
                "{{ double acc = c[{a}+k]; for (int j = 1; j <= k; j++) acc -= c[{b}+j] * \
                 c[{d}+k-j]; c[{d}+k] = acc / c[{b}]; }}",
                a = at(a),
                b = at(b),
                d = at(d)
            ),
            Op::Sqrt(d, a) => format!(
                "if (k == 0) c[{d}] = {z}; else {{ double acc = c[{a}+k]; for (int j = 1; j < k; \
                 j++) acc -= c[{d}+j] * c[{d}+k-j]; c[{d}+k] = acc / (2.0 * c[{d}]); }}",
                z = unary0(Unary::Sqrt, &format!("c[{}]", at(a))),
                a = at(a),
                d = at(d)
            ),
            Op::Exp(d, a) => format!(
                "if (k == 0) c[{d}] = {z}; else c[{d}+k] = weighted(c+{a}, c+{d}, k) / kf;",
                z = unary0(Unary::Exp, &format!("c[{}]", at(a))),
                a = at(a),
                d = at(d)
            ),
            Op::Log(d, a) => format!(
                "if (k == 0) c[{d}] = {z}; else {{ double acc = kf * c[{a}+k]; for (int j = 1; \
                 j < k; j++) acc -= (double)j * c[{d}+j] * c[{a}+k-j]; c[{d}+k] = acc / (kf * \
                 c[{a}]); }}",
                z = unary0(Unary::Log, &format!("c[{}]", at(a))),
                a = at(a),
                d = at(d)
            ),
            Op::Pow(d, a, e) => format!(
                "if (k == 0) c[{d}] = {z}; else {{ double acc = 0.0; for (int j = 0; j < k; j++) \
                 acc += (c[{e}] * (double)(k - j) - (double)j) * c[{a}+k-j] * c[{d}+j]; \
                 c[{d}+k] = acc / (kf * c[{a}]); }}",
                z = binary0(
                    Binary::Pow,
                    &format!("c[{}]", at(a)),
                    &format!("c[{}]", at(e))
                ),
                a = at(a),
                d = at(d),
                e = at(e)
            ),
            Op::SinCos {
                sin,
                cos,
                a,
                hyperbolic,
            } => {
                let (fs, fc) = if hyperbolic {
                    (Unary::Sinh, Unary::Cosh)
                } else {
                    (Unary::Sin, Unary::Cos)
                };
                let x0 = format!("c[{}]", at(a));
                format!(
                    "if (k == 0) {{ c[{si}] = {zs}; c[{co}] = {zc}; }} else {{ c[{si}+k] = \
                     weighted(c+{a}, c+{co}, k) / kf; double v = weighted(c+{a}, c+{si}, k) / \
                     kf; c[{co}+k] = {v}; }}",
                    zs = unary0(fs, &x0),
                    zc = unary0(fc, &x0),
                    si = at(sin),
                    co = at(cos),
                    a = at(a),
                    v = if hyperbolic { "v" } else { "-v" }
                )
            }
            Op::Tan {
                dst,
                a,
                sq,
                hyperbolic,
            } => format!(
                "if (k == 0) c[{d}] = {z}; else c[{d}+k] = (c[{a}+k] * kf + {sign} * \
                 weighted(c+{a}, c+{q}, k)) / kf; c[{q}+k] = cauchy(c+{d}, c+{d}, k);",
                z = unary0(
                    if hyperbolic { Unary::Tanh } else { Unary::Tan },
                    &format!("c[{}]", at(a))
                ),
                sign = if hyperbolic { "-1.0" } else { "1.0" },
                a = at(a),
                d = at(dst),
                q = at(sq)
            ),
            Op::Inverse { dst, a, d, f } => format!(
                "if (k == 0) c[{w}] = {z}; else {{ double acc = kf * c[{a}+k]; for (int j = 1; \
                 j < k; j++) acc -= (double)j * c[{w}+j] * c[{d}+k-j]; c[{w}+k] = acc / (kf * \
                 c[{d}]); }}",
                z = unary0(f, &format!("c[{}]", at(a))),
                a = at(a),
                d = at(d),
                w = at(dst)
            ),
            Op::Atan2 { dst, a, b, d } => format!(
                "if (k == 0) c[{w}] = {z}; else {{ double acc = 0.0; for (int j = 1; j <= k; \
                 j++) acc += (double)j * (c[{b}+k-j] * c[{a}+j] - c[{a}+k-j] * c[{b}+j]); for \
                 (int j = 1; j < k; j++) acc -= (double)j * c[{w}+j] * c[{d}+k-j]; c[{w}+k] = \
                 acc / (kf * c[{d}]); }}",
                z = binary0(
                    Binary::Atan2,
                    &format!("c[{}]", at(a)),
                    &format!("c[{}]", at(b))
                ),
                a = at(a),
                b = at(b),
                d = at(d),
                w = at(dst)
            ),
        };
        let _ = writeln!(s, "    {line}");
    }
    s.push_str("    const double next = 1.0 / (double)(k + 1);\n");
    for (&x, &f) in tape
        .state
        .iter()
        .zip(&tape.f_out)
        .chain(tape.tangent.iter().zip(&tape.jv_out))
    {
        let _ = writeln!(s, "    c[{}+k+1] = c[{}+k] * next;", at(x), at(f));
    }
    s.push_str("  }\n}\n");
    s
}
