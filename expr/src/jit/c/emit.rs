//! The C text of the step kernels: the prelude, the vector helpers and each node as a C
//! expression over scalars or vectors.

use super::{ENV_BINARY, ENV_TABLE, ENV_TABLES};
use crate::graph::{Binary, Cmp, Graph, Node, NodeId, Unary};
use crate::jit::step_spec::{StageOp, StepSpec, kernel_plan, stage_schedule};
use crate::jit::{JitError, Layout, Plan, is_leaf};
use std::fmt::Write as _;
/// Helpers of every generated file. `vd` is one vector of `LANES` lanes (a block is two); compares give `vi`
/// masks (all ones where true, false when either side is NaN).
pub(crate) fn prelude() -> String {
    let mut src = String::from(
        r#"/* chaoscope step kernels, generated; see expr/src/jit/c/emit.rs. */
#include <stddef.h>
#include <stdint.h>
#include <string.h>
#define LANES 4
#define BLOCK 8
typedef double vd __attribute__((vector_size(LANES * 8)));
typedef int64_t vi __attribute__((vector_size(LANES * 8)));
typedef double (*fn1)(double);
typedef double (*fn2)(double, double);
typedef double (*fntab)(uintptr_t, uint64_t, double);
const char chaoscope_kernel_hash[] = "@HASH@";
static inline double K(uint64_t bits) { double d; memcpy(&d, &bits, 8); return d; }
"#,
    );
    src.push_str(&vector_helpers("", "vd", "vi", "LANES"));
    src.push_str(
        r#"static inline double SABS(double a) { uint64_t b; memcpy(&b, &a, 8); b &= 0x7fffffffffffffffull; memcpy(&a, &b, 8); return a; }
static inline double SSTEP(double x) { return x != x ? x : (x > 0.0 ? 1.0 : 0.0); }
static inline double SSIGN(double x) { return x != x ? x : (x > 0.0 ? 1.0 : (x < 0.0 ? -1.0 : 0.0)); }
static inline double SMAX(double a, double b) { return (a != a || b != b) ? K(0x7ff8000000000000ull) : (a >= b ? a : b); }
static inline double SMIN(double a, double b) { return (a != a || b != b) ? K(0x7ff8000000000000ull) : (a <= b ? a : b); }
"#,
    );
    src
}

/// The vector helpers over the vector type `vd` of `lanes` lanes and its mask type `vi`, each
/// name with `prefix` (the step kernels' four-lane ones without, the fused kernel's host-wide
/// ones with `F`): one definition of what each operation does lane by lane (NaN and signed
/// zeros as the scalar definitions), whatever the width.
pub(crate) fn vector_helpers(prefix: &str, vd: &str, vi: &str, lanes: &str) -> String {
    let p = prefix;
    format!(
        r#"static inline {vd} {p}B(double x) {{ {vd} r; for (int l = 0; l < {lanes}; l++) r[l] = x; return r; }}
static inline {vd} {p}LD(const double *p) {{ {vd} r; memcpy(&r, p, sizeof r); return r; }}
static inline void {p}ST(double *p, {vd} v) {{ memcpy(p, &v, sizeof v); }}
static inline {vd} {p}SEL({vi} m, {vd} t, {vd} e) {{ return ({vd})((m & ({vi})t) | (~m & ({vi})e)); }}
static inline {vd} {p}VABS({vd} a) {{ {vi} m; for (int l = 0; l < {lanes}; l++) m[l] = INT64_MAX; return ({vd})(({vi})a & m); }}
static inline {vd} {p}VSQRT({vd} a) {{ {vd} r; for (int l = 0; l < {lanes}; l++) r[l] = __builtin_sqrt(a[l]); return r; }}
static inline {vd} {p}VSTEP({vd} x) {{ {vd} r = {p}SEL(x > {p}B(0.0), {p}B(1.0), {p}B(0.0)); return {p}SEL(x != x, x, r); }}
static inline {vd} {p}VSIGN({vd} x) {{ {vd} r = {p}SEL(x < {p}B(0.0), {p}B(-1.0), {p}B(0.0)); r = {p}SEL(x > {p}B(0.0), {p}B(1.0), r); return {p}SEL(x != x, x, r); }}
static inline {vd} {p}VMAX({vd} a, {vd} b) {{ {vd} r = {p}SEL(a >= b, a, b); return {p}SEL((a != a) | (b != b), {p}B(K(0x7ff8000000000000ull)), r); }}
static inline {vd} {p}VMIN({vd} a, {vd} b) {{ {vd} r = {p}SEL(a <= b, a, b); return {p}SEL((a != a) | (b != b), {p}B(K(0x7ff8000000000000ull)), r); }}
static inline {vd} {p}V1(uintptr_t f, {vd} a) {{ {vd} r; for (int l = 0; l < {lanes}; l++) r[l] = ((fn1)f)(a[l]); return r; }}
static inline {vd} {p}V2(uintptr_t f, {vd} a, {vd} b) {{ {vd} r; for (int l = 0; l < {lanes}; l++) r[l] = ((fn2)f)(a[l], b[l]); return r; }}
static inline {vd} {p}VT(uintptr_t f, uintptr_t t, uint64_t d, {vd} a) {{ {vd} r; for (int l = 0; l < {lanes}; l++) r[l] = ((fntab)f)(t, d, a[l]); return r; }}
"#
    )
}

/// Writes the C source of the kernels of `spec`.
pub(crate) fn source(graph: &Graph, spec: &StepSpec) -> Result<String, JitError> {
    let n = spec.n;
    let check =
        |f: usize, outputs: &[NodeId], args: Vec<Layout>| kernel_plan(graph, n, f, outputs, args);
    let mut src = String::with_capacity(64 * graph.len() + 4096);
    src.push_str(&prelude());
    let orbit = check(0, &spec.gradient, vec![Layout::Lanes])?;
    Kernel {
        graph,
        plan: &orbit,
        n,
        tangent: false,
    }
    .write(&mut src);
    if let Some(hv) = &spec.hessian_vector {
        let plan = check(1, hv, vec![Layout::Scalar, Layout::Lanes])?;
        Kernel {
            graph,
            plan: &plan,
            n,
            tangent: true,
        }
        .write(&mut src);
    }
    Ok(src)
}

/// One kernel (orbit or tangent) being written.
pub(crate) struct Kernel<'a> {
    graph: &'a Graph,
    plan: &'a Plan,
    n: usize,
    tangent: bool,
}

pub(crate) fn cmp_op(cmp: Cmp) -> &'static str {
    match cmp {
        Cmp::Lt => "<",
        Cmp::Le => "<=",
        Cmp::Gt => ">",
        Cmp::Ge => ">=",
    }
}

pub(crate) fn unary_slot(op: Unary) -> usize {
    crate::ops::called()
        .position(|d| d.op == op)
        .expect("a called-back unary operation")
}

pub(crate) fn binary_slot(op: Binary) -> usize {
    crate::ops::called_binary()
        .position(|d| d.op == op)
        .expect("a called-back binary operation")
}

/// A constant by its bits (no decimal round trip; NaN payloads and signed zeros kept).
pub(crate) fn konst(c: f64) -> String {
    format!("K(0x{:016x}ull)", c.to_bits())
}

/// `x^n` as [`Graph::apply_powi`]: a left-to-right product (C's `*` is left-associative).
pub(crate) fn powi(x: &str, n: i32, one: &str) -> String {
    if n == 0 {
        return one.to_string();
    }
    let product = vec![x; n.unsigned_abs() as usize].join(" * ");
    if n < 0 {
        format!("{one} / ({product})")
    } else {
        format!("({product})")
    }
}

/// The C lines computing `roots`, operands first (in [`crate::jit::schedule`]'s order): each leaf's
/// expression and whether it is lane code from `leaf`; a node with a lane operand becomes
/// `const vd NAME = ...;` (its scalar operands broadcast), any other `const double NAME = ...;`,
/// named by `name(id, lane)` and handed to `line(lane, text)`. Returns every emitted node's
/// (name or expression, lane).
pub(crate) fn emit_nodes(
    graph: &Graph,
    roots: &[NodeId],
    leaf: &mut dyn FnMut(&Node) -> (String, bool),
    name: &dyn Fn(NodeId, bool) -> String,
    line: &mut dyn FnMut(bool, String),
) -> Vec<Option<(String, bool)>> {
    let mut vals: Vec<Option<(String, bool)>> = vec![None; graph.len()];
    for id in crate::jit::schedule(graph, roots, |_| true) {
        let node = graph.node(id);
        if is_leaf(node) {
            vals[id as usize] = Some(leaf(node));
            continue;
        }
        let lane = node
            .operands()
            .any(|o| vals[o as usize].as_ref().is_some_and(|v| v.1));
        let e = if lane {
            vector_expr(node, &mut |o| {
                let (x, lane) = vals[o as usize].clone().expect("operands first");
                if lane { x } else { format!("B({x})") }
            })
        } else {
            scalar_expr(node, &mut |o| {
                vals[o as usize].clone().expect("operands first").0
            })
        };
        let n = name(id, lane);
        let ty = if lane { "vd" } else { "double" };
        line(lane, format!("const {ty} {n} = {e};"));
        vals[id as usize] = Some((n, lane));
    }
    vals
}

/// A scalar node as a C expression of its operands (`o` names them).
pub(crate) fn scalar_expr(node: &Node, o: &mut dyn FnMut(NodeId) -> String) -> String {
    c_expr(node, o, Lanes::Scalar)
}

/// A vector node (`vd` values) as a C expression of its operands (`o` names them, as vectors).
pub(crate) fn vector_expr(node: &Node, o: &mut dyn FnMut(NodeId) -> String) -> String {
    c_expr(node, o, Lanes::Vector)
}

/// Whether C code computes one value (plain `double`) or `vd` lanes at once (the vector type
/// and its helper macros): the two spell only calls, branches and the non-arithmetic
/// operations differently.
#[derive(Clone, Copy, PartialEq, Eq)]
pub(crate) enum Lanes {
    Scalar,
    Vector,
}

impl Lanes {
    /// The helper macro for an operation the prelude defines in both flavours (`SABS`/`VABS`).
    fn helper(self, name: &str) -> String {
        match self {
            Lanes::Scalar => format!("S{name}"),
            Lanes::Vector => format!("V{name}"),
        }
    }

    /// A call of the unary function in environment slot `slot`.
    fn call1(self, slot: usize, a: &str) -> String {
        match self {
            Lanes::Scalar => format!("((fn1)env[{slot}])({a})"),
            Lanes::Vector => format!("V1(env[{slot}], {a})"),
        }
    }

    /// A call of the binary function in environment slot `slot`.
    fn call2(self, slot: usize, a: &str, b: &str) -> String {
        match self {
            Lanes::Scalar => format!("((fn2)env[{slot}])({a}, {b})"),
            Lanes::Vector => format!("V2(env[{slot}], {a}, {b})"),
        }
    }
}

/// A node as a C expression of its operands, in scalar or vector code.
pub(crate) fn c_expr(node: &Node, o: &mut dyn FnMut(NodeId) -> String, lanes: Lanes) -> String {
    match *node {
        Node::Const(_) | Node::Input { .. } => unreachable!("leaves are operands"),
        Node::Unary(op, a) => {
            let a = o(a);
            match op {
                Unary::Neg => format!("-{a}"),
                Unary::Abs => format!("{}({a})", lanes.helper("ABS")),
                Unary::Sqrt if lanes == Lanes::Scalar => format!("__builtin_sqrt({a})"),
                Unary::Sqrt => format!("VSQRT({a})"),
                Unary::Step => format!("{}({a})", lanes.helper("STEP")),
                Unary::Sign => format!("{}({a})", lanes.helper("SIGN")),
                _ => lanes.call1(unary_slot(op), &a),
            }
        }
        Node::Binary(op, a, b) => {
            let (a, b) = (o(a), o(b));
            match op {
                Binary::Add => format!("{a} + {b}"),
                Binary::Sub => format!("{a} - {b}"),
                Binary::Mul => format!("{a} * {b}"),
                Binary::Div => format!("{a} / {b}"),
                Binary::Max => format!("{}({a}, {b})", lanes.helper("MAX")),
                Binary::Min => format!("{}({a}, {b})", lanes.helper("MIN")),
                _ => lanes.call2(ENV_BINARY + binary_slot(op), &a, &b),
            }
        }
        Node::Powi(a, n) => {
            let one = match lanes {
                Lanes::Scalar => "1.0",
                Lanes::Vector => "B(1.0)",
            };
            powi(&o(a), n, one)
        }
        Node::Select {
            cmp,
            a,
            b,
            then,
            otherwise,
        } => {
            let (a, b) = (o(a), o(b));
            let (t, e) = (o(then), o(otherwise));
            match lanes {
                Lanes::Scalar => format!("({a} {} {b}) ? {t} : {e}", cmp_op(cmp)),
                Lanes::Vector => format!("SEL({a} {} {b}, {t}, {e})", cmp_op(cmp)),
            }
        }
        Node::Table { table, deriv, arg } => {
            let data = ENV_TABLES + table as usize;
            let arg = o(arg);
            match lanes {
                Lanes::Scalar => {
                    format!("((fntab)env[{ENV_TABLE}])(env[{data}], {deriv}, {arg})")
                }
                Lanes::Vector => format!("VT(env[{ENV_TABLE}], env[{data}], {deriv}, {arg})"),
            }
        }
    }
}

impl Kernel<'_> {
    /// The lane argument: the orbit's positions (0) or the tangent's `dq` (1).
    fn lane_arg(&self) -> u8 {
        u8::from(self.tangent)
    }

    /// A scalar operand in the uniform code (computed once per call or per stage).
    fn scalar_operand(&self, id: NodeId) -> String {
        match *self.graph.node(id) {
            Node::Const(c) => konst(c),
            Node::Input { index, .. } => format!("qs[{index}]"),
            _ => format!("u{id}"),
        }
    }

    fn scalar_node(&self, node: &Node) -> String {
        scalar_expr(node, &mut |id| self.scalar_operand(id))
    }

    /// A vector operand in the block code (a row is drifted before its first use).
    fn operand(&self, id: NodeId) -> String {
        match *self.graph.node(id) {
            Node::Const(c) => format!("B({})", konst(c)),
            Node::Input { arg, index } if arg == self.lane_arg() => format!("q{index}_@"),
            Node::Input { index, .. } => format!("B(qs[{index}])"),
            _ if self.plan.uniform[id as usize] => format!("B(u{id})"),
            _ => format!("v{id}_@"),
        }
    }

    /// The uniform values: scalar code, once per call (orbit) or per stage (tangent).
    fn uniforms(&self, out: &mut String) {
        for &id in &self.plan.uniform_order {
            let e = self.scalar_node(self.graph.node(id));
            let _ = writeln!(out, "      const double u{id} = {e};");
        }
    }

    /// Drift, force and kick of one block within one stage, in the Cranelift kernel's order
    /// (rows drifted on first use, each row's kick after its drift).
    ///
    /// A block is two units of `LANES` lanes (two vectors per value, independent chains):
    /// each statement is written once with the placeholders `_@` (name suffix) and `@O` (lane
    /// offset) and emitted once per unit, interleaved.
    fn block(&self, out: &mut String) {
        let mut body = String::new();
        self.block_statements(&mut body);
        for line in body.lines() {
            for (suffix, offset) in [("_0", "0"), ("_1", "LANES")] {
                let _ = writeln!(out, "{}", line.replace("_@", suffix).replace("@O", offset));
            }
        }
    }

    /// The stage's statements ([`stage_schedule`]) for one unit, with the placeholders.
    fn block_statements(&self, out: &mut String) {
        let n = self.n;
        for op in stage_schedule(self.graph, self.plan, n, self.lane_arg()) {
            let _ = match op {
                StageOp::Drift(j) => writeln!(
                    out,
                    "  vd p{j}_@ = LD(xb + {p} * stride + @O); vd q{j}_@ = LD(xb + {j} * stride + @O) + B(c[{j}]) * p{j}_@; ST(xb + {j} * stride + @O, q{j}_@);",
                    p = n + j
                ),
                StageOp::Value(id) => {
                    let e = vector_expr(self.graph.node(id), &mut |o| self.operand(o));
                    writeln!(out, "  const vd v{id}_@ = {e};")
                }
                StageOp::Kick { row, force } => writeln!(
                    out,
                    "  ST(xb + {} * stride + @O, p{row}_@ - dh * {});",
                    n + row,
                    self.operand(force)
                ),
            };
        }
    }

    fn write(&self, out: &mut String) {
        let n = self.n;
        let coefficients = |out: &mut String| {
            let _ = writeln!(
                out,
                "      if (w) {{ for (size_t j = 0; j < {n}; j++) c[j] = ch * w[j]; }} else {{ for (size_t j = 0; j < {n}; j++) c[j] = ch; }}"
            );
        };
        step_loops(
            out,
            n,
            self.tangent,
            "scratch",
            |out| {
                let _ = writeln!(out, "  double c[{n}];");
                if !self.tangent {
                    self.uniforms(out);
                }
            },
            |out| {
                coefficients(out);
                if self.tangent {
                    self.uniforms(out);
                }
            },
            |out| {
                let _ = writeln!(out, "  (void)dh;");
                self.block(out);
            },
        );
    }
}

/// The loop nest of a step kernel, the C twin of the Cranelift kernels' (`step_loops.rs` there):
/// the signature, the step and stage loops, the blocks of lanes, the last drift. `head` writes
/// what the whole call shares, `stage` what a stage computes before its blocks (`ch`, `dh` and,
/// in a tangent kernel, the reference position `qs` are defined), `block` one block's work
/// (`xb`, its first lane, is defined); `scratch` names the kernel's working memory.
pub(crate) fn step_loops(
    out: &mut String,
    n: usize,
    tangent: bool,
    scratch: &str,
    head: impl FnOnce(&mut String),
    stage: impl FnOnce(&mut String),
    block: impl FnOnce(&mut String),
) {
    let (name, lead) = if tangent {
        ("chaoscope_tangent_steps", "const double *stages, ")
    } else {
        ("chaoscope_orbit_steps", "")
    };
    let _ = writeln!(
        out,
        "void {name}({lead}double *restrict x, size_t stride, size_t lanes, uint64_t n_steps, \
         const double *drift, const double *kick, size_t n_kicks, const double *w, \
         double *restrict {scratch}, const uintptr_t *env) {{\n  \
         const size_t end = lanes - lanes % BLOCK;\n  if (end == 0 || n_steps == 0) return;"
    );
    if !tangent {
        let _ = writeln!(out, "  const double *qs = 0; (void)qs;");
    }
    head(out);
    let _ = writeln!(
        out,
        "  for (uint64_t s = 0; s < n_steps; s++) {{\n    for (size_t k = 0; k < n_kicks; k++) {{\n      const double ch = drift[k];\n      const vd dh = B(kick[k]);"
    );
    if tangent {
        let _ = writeln!(
            out,
            "      const double *qs = stages + (s * n_kicks + k) * {n}; (void)qs;"
        );
    }
    stage(out);
    let _ = writeln!(
        out,
        "      for (size_t o = 0; o < end; o += BLOCK) {{\n        double *xb = x + o;"
    );
    block(out);
    let _ = writeln!(
        out,
        "      }}\n    }}\n    {{\n      const double ch = drift[n_kicks];\n      for (size_t o = 0; o < end; o += LANES) {{\n        double *xb = x + o;\n        for (size_t j = 0; j < {n}; j++) {{\n          const double c = w ? ch * w[j] : ch;\n          ST(xb + j * stride, LD(xb + j * stride) + B(c) * LD(xb + ({n} + j) * stride));\n        }}\n      }}\n    }}\n  }}\n}}"
    );
}
