//! The lattice step kernels of `cranelift::lattice_steps` written as C (`c::emit`'s vectors,
//! flags, callbacks and cache): the same passes (drift and clear, the rest's derivatives and
//! each sum's boundary terms and loop into the scratch rows, kick) and the same operations in
//! the same order, so the same bits as the Cranelift kernels and the generic step loops.
//!
//! The source holds `N`, the sums' ranges and one copy of each term (and of its boundary
//! terms), never a site's own code: its size, and the compiler's time, do not grow with `N`.
//! Array parameters are read through pointers the caller appends to `env`, so their values are
//! not in the source either (nor in the cache key: a new disorder realization reuses the
//! library).

use std::fmt::Write as _;
use std::sync::Arc;
use std::sync::atomic::AtomicBool;

use super::emit::step_loops;
use super::{self as c_step, C_BLOCK_LANES, CCompiler, konst};
use crate::graph::{Graph, Node, NodeId, Tabulated};
use crate::jit::lattice_plan::{
    ForcePart, OutputPlan, WindowPlan, arrays_of, rest_derivatives, shift_range, sum_contributions,
};
use crate::jit::step::{Code, StepKernels};
use crate::jit::{AllocationWork, JitError};
use crate::lattice::{
    ARG_Q, ARG_SITE, ARG_SITE_DIRECTION, ARG_SITE_PARAM, ARG_V, LatticePotential, SiteSum,
};

/// The C kernels of a lattice potential (compiled by `cc` or loaded from its cache), as
/// [`crate::jit::compile_lattice_steps`] builds them with Cranelift; gives up once `cancel` is set
/// (see [`crate::jit::compile_steps_c_cancellable`]).
pub fn compile_lattice_steps_c_cancellable(
    graph: &Graph,
    lattice: &LatticePotential,
    cc: &CCompiler,
    cancel: &AtomicBool,
) -> Result<StepKernels, JitError> {
    lattice_steps_c(graph, lattice, cc, cancel, c_step::Mode::Build)
}

/// The C kernels of a lattice potential if an earlier build left them in `cc`'s cache, without
/// compiling them ([`JitError::NotCached`] otherwise) and without creating the cache: what a
/// run too short to repay a build takes (a few milliseconds where the compiler's target is
/// remembered, see `c_step`'s target record).
pub fn load_lattice_steps_c(
    graph: &Graph,
    lattice: &LatticePotential,
    cc: &CCompiler,
) -> Result<StepKernels, JitError> {
    lattice_steps_c(
        graph,
        lattice,
        cc,
        &AtomicBool::new(false),
        c_step::Mode::Load,
    )
}

fn lattice_steps_c(
    graph: &Graph,
    lattice: &LatticePotential,
    cc: &CCompiler,
    cancel: &AtomicBool,
    mode: c_step::Mode,
) -> Result<StepKernels, JitError> {
    let tables: Box<[Arc<dyn Tabulated>]> = graph.tables().to_vec().into_boxed_slice();
    let arrays = arrays_of(lattice);
    let src = source(graph, lattice, &arrays);
    let (kernels, compile_time) = c_step::build(&src, lattice.has_hessian(), cc, cancel, mode)?;
    let arrays: Vec<Arc<[f64]>> = arrays.into_iter().map(|(_, a)| a).collect();
    let env = c_step::env(&tables, &arrays);
    Ok(StepKernels::new(
        Code::C { kernels, env },
        lattice.n,
        [C_BLOCK_LANES; 2],
        lattice.n,
        tables,
        arrays,
        compile_time,
        AllocationWork::default(),
    ))
}

/// [`compile_lattice_steps_c_cancellable`] without cancellation.
pub fn compile_lattice_steps_c(
    graph: &Graph,
    lattice: &LatticePotential,
    cc: &CCompiler,
) -> Result<StepKernels, JitError> {
    compile_lattice_steps_c_cancellable(graph, lattice, cc, &AtomicBool::new(false))
}

/// The C source of the kernels.
fn source(graph: &Graph, lattice: &LatticePotential, arrays: &[(String, Arc<[f64]>)]) -> String {
    let mut src = c_step::prelude();
    let n_tables = graph.tables().len();
    for tangent in [false, true] {
        if tangent && !lattice.has_hessian() {
            continue;
        }
        let k = Kernel {
            graph,
            lattice,
            plan: OutputPlan::new(graph, lattice, tangent, true),
            arrays,
            array_env: c_step::ENV_TABLES + n_tables,
            tangent,
        };
        k.write(&mut src);
    }
    let array_env = c_step::ENV_TABLES + n_tables;
    if let Some(fused) = super::fused::source(graph, lattice, arrays, array_env) {
        src.push_str(&fused);
    }
    src
}

struct Kernel<'a> {
    graph: &'a Graph,
    lattice: &'a LatticePotential,
    /// Which sums' interior loops keep their window of sites in variables.
    plan: OutputPlan,
    arrays: &'a [(String, Arc<[f64]>)],
    /// `env` slot of the first array parameter.
    array_env: usize,
    tangent: bool,
}

/// Where a term's slots are: a boundary term's known sites, or the loop's `i` (its variable
/// slots read directly, or, in a window loop, from the variables `x{s}` (lanes) and `y{s}`
/// (the tangent kernel's shared position) declared at the top of the loop's body).
#[derive(Clone, Copy, PartialEq, Eq)]
enum At {
    Term(i64),
    Loop,
    Window,
}

/// One line of a term: scalar code (written once) or lane code (written once per unit, with
/// `_@` and `@O` the unit's name suffix and lane offset).
enum Line {
    Once(String),
    PerUnit(String),
}

impl Kernel<'_> {
    /// A scalar leaf's C expression, or a lane leaf's (`None` for a scalar).
    fn leaf(&self, node: &Node, sum: Option<&SiteSum>, at: At) -> (String, bool) {
        let lanes = |row: String| (format!("LD(xb + ({row}) * stride + @O)"), true);
        match *node {
            Node::Const(c) => (konst(c), false),
            Node::Input { arg: ARG_Q, index } if !self.tangent => lanes(index.to_string()),
            Node::Input { arg: ARG_Q, index } => (format!("qs[{index}]"), false),
            Node::Input { arg: ARG_V, index } => lanes(index.to_string()),
            Node::Input { arg, index } => {
                let sum = sum.expect("a term's slot");
                let (shift, param) = match arg {
                    ARG_SITE | ARG_SITE_DIRECTION => (sum.variables[index as usize], None),
                    ARG_SITE_PARAM => {
                        let p = &sum.params[index as usize];
                        (p.shift, Some(p))
                    }
                    _ => unreachable!("a leaf of a term: {node:?}"),
                };
                if at == At::Window && param.is_none() {
                    return if arg == ARG_SITE && self.tangent {
                        (format!("y{index}"), false)
                    } else {
                        (format!("x{index}_@"), true)
                    };
                }
                let row = match at {
                    At::Term(i) => match sum.site(i, shift) {
                        Some(j) => j.to_string(),
                        None => return (konst(0.0), false),
                    },
                    At::Loop | At::Window => format!("i + {}", shift - 1),
                };
                if let Some(p) = param {
                    if let At::Term(i) = at {
                        let j = sum.site(i, p.shift).expect("parameters inside the lattice");
                        return (konst(p.values[j]), false);
                    }
                    let a = self
                        .arrays
                        .iter()
                        .position(|(name, _)| *name == p.name)
                        .expect("every array a sum reads");
                    return (format!("arr{a}[{row}]"), false);
                }
                if arg == ARG_SITE && self.tangent {
                    (format!("qs[{row}]"), false)
                } else {
                    lanes(row)
                }
            }
            _ => unreachable!("not a leaf: {node:?}"),
        }
    }

    /// The lines computing `roots` (in [`crate::jit::cranelift::lattice::Body`]'s order), and each root's
    /// expression as a lane value.
    fn emit(
        &self,
        roots: &[NodeId],
        sum: Option<&SiteSum>,
        at: At,
        lines: &mut Vec<Line>,
    ) -> Vec<String> {
        let vals = c_step::emit_nodes(
            self.graph,
            roots,
            &mut |node| self.leaf(node, sum, at),
            &|id, lane| {
                if lane {
                    format!("v{id}_@")
                } else {
                    format!("s{id}")
                }
            },
            &mut |lane, text| {
                lines.push(if lane {
                    Line::PerUnit(text)
                } else {
                    Line::Once(text)
                })
            },
        );
        roots
            .iter()
            .map(|&r| {
                let (x, lane) = vals[r as usize].clone().expect("emitted");
                if lane { x } else { format!("B({x})") }
            })
            .collect()
    }

    /// `g[row] += c d` in every unit.
    fn add_to(lines: &mut Vec<Line>, row: &str, c: f64, d: &str) {
        let at = format!("g + ({row}) * BLOCK + @O");
        let e = if c == 1.0 {
            format!("LD({at}) + {d}")
        } else if c == -1.0 {
            format!("LD({at}) - {d}")
        } else {
            format!("LD({at}) + B({}) * {d}", konst(c))
        };
        lines.push(Line::PerUnit(format!("ST({at}, {e});")));
    }

    fn write_lines(out: &mut String, lines: &[Line], indent: &str) {
        for line in lines {
            match line {
                Line::Once(l) => {
                    let _ = writeln!(out, "{indent}{l}");
                }
                Line::PerUnit(l) => {
                    for (suffix, offset) in [("_0", "0"), ("_1", "LANES")] {
                        let l = l.replace("_@", suffix).replace("@O", offset);
                        let _ = writeln!(out, "{indent}{l}");
                    }
                }
            }
        }
    }

    /// The force of one block into `g`, which holds `-0`: the plan's parts in order.
    fn force(&self, out: &mut String) {
        let lattice = self.lattice;
        let sums = sum_contributions(self.graph, lattice, self.tangent);
        for part in &self.plan.parts {
            match *part {
                ForcePart::Rest => {
                    let rest = rest_derivatives(lattice, self.tangent);
                    let roots: Vec<NodeId> = rest.iter().map(|&(_, id)| id).collect();
                    let mut lines = Vec::new();
                    let d = self.emit(&roots, None, At::Loop, &mut lines);
                    for (&(j, _), d) in rest.iter().zip(&d) {
                        Self::add_to(&mut lines, &j.to_string(), 1.0, d);
                    }
                    let _ = writeln!(out, "        {{");
                    Self::write_lines(out, &lines, "          ");
                    let _ = writeln!(out, "        }}");
                }
                ForcePart::Term { sum, i } => {
                    let _ = writeln!(out, "        {{ /* term {i} */");
                    self.term(out, sum, &sums[sum].0, &sums[sum].1, At::Term(i));
                    let _ = writeln!(out, "        }}");
                }
                ForcePart::Loop { sum: s, from, to } => {
                    let (sum, (contributions, roots)) = (&lattice.sums[s], &sums[s]);
                    match self.plan.window[s] {
                        Some(plan) => {
                            self.window_loop(out, sum, contributions, roots, (from, to), plan);
                        }
                        None => {
                            let _ = writeln!(
                                out,
                                "        for (int64_t i = {from}; i <= {to}; i++) {{"
                            );
                            self.term(out, s, contributions, roots, At::Loop);
                            let _ = writeln!(out, "        }}");
                        }
                    }
                }
            }
        }
    }

    /// One term of sum `s` (at a boundary site or as the loop's body): its derivatives added
    /// to the scratch rows of the sites its slots read.
    fn term(
        &self,
        out: &mut String,
        s: usize,
        contributions: &[(f64, NodeId)],
        roots: &[NodeId],
        at: At,
    ) {
        let sum = &self.lattice.sums[s];
        let mut lines = Vec::new();
        let ds = self.emit(roots, Some(sum), at, &mut lines);
        for ((&shift, dv), &(factor, _)) in sum.variables.iter().zip(&ds).zip(contributions) {
            let row = match at {
                At::Term(i) => match sum.site(i, shift) {
                    Some(j) => j.to_string(),
                    None => continue,
                },
                At::Loop | At::Window => format!("i + {}", shift - 1),
            };
            Self::add_to(&mut lines, &row, factor, dv);
        }
        Self::write_lines(out, &lines, "          ");
    }

    /// The interior loop of a sum with the sites its terms reach (`i + kmin .. i + kmax`) kept
    /// in variables from term to term, as [`crate::jit::cranelift::lattice`]'s window loop: the same additions in
    /// the same order as adding to the scratch rows in memory, one store per site; the slots
    /// a term shares with the next one read once.
    fn window_loop(
        &self,
        out: &mut String,
        sum: &SiteSum,
        contributions: &[(f64, NodeId)],
        roots: &[NodeId],
        (from, to): (i64, i64),
        plan: WindowPlan,
    ) {
        let fresh = plan.fresh;
        let n = self.lattice.n;
        let shifts = &sum.variables;
        let (kmin, kmax) = shift_range(shifts);
        let w = (kmax - kmin) as usize;
        let carry: Vec<(usize, usize)> = shifts
            .iter()
            .enumerate()
            .filter_map(|(s, &k)| shifts.iter().position(|&k2| k2 == k + 1).map(|s2| (s, s2)))
            .collect();
        let mut pre = Vec::new();
        for t in 0..w {
            pre.push(Line::PerUnit(format!(
                "vd w{t}_@ = LD(g + ({}) * BLOCK + @O);",
                from + kmin + t as i64 - 1
            )));
        }
        for &(s, _) in &carry {
            let row = from + shifts[s] - 1;
            pre.push(Line::PerUnit(format!(
                "vd cx{s}_@ = LD(xb + ({row}) * stride + @O);"
            )));
            if self.tangent {
                pre.push(Line::Once(format!("double cy{s} = qs[{row}];")));
            }
        }
        let _ = writeln!(out, "        {{");
        Self::write_lines(out, &pre, "          ");
        let _ = writeln!(out, "          for (int64_t i = {from}; i <= {to}; i++) {{");
        let mut lines = Vec::new();
        if plan.drift {
            // The row entering the window, drifted before its first read.
            let r = format!("i + {}", kmax - 1);
            lines.push(Line::Once(format!(
                "const double c = w ? ch * w[{r}] : ch;"
            )));
            lines.push(Line::PerUnit(format!(
                "ST(xb + ({r}) * stride + @O, LD(xb + ({r}) * stride + @O) + B(c) * LD(xb + ({n} + {r}) * stride + @O));"
            )));
        }
        for (s, &shift) in shifts.iter().enumerate() {
            let carried = carry.iter().any(|&(c, _)| c == s);
            let x = if carried {
                format!("cx{s}_@")
            } else {
                format!("LD(xb + (i + {}) * stride + @O)", shift - 1)
            };
            lines.push(Line::PerUnit(format!("const vd x{s}_@ = {x};")));
            if self.tangent {
                let y = if carried {
                    format!("cy{s}")
                } else {
                    format!("qs[i + {}]", shift - 1)
                };
                lines.push(Line::Once(format!("const double y{s} = {y};")));
            }
        }
        let ds = self.emit(roots, Some(sum), At::Window, &mut lines);
        if !fresh {
            lines.push(Line::PerUnit(format!(
                "vd w{w}_@ = LD(g + (i + {}) * BLOCK + @O);",
                kmax - 1
            )));
        }
        for ((&shift, d), &(factor, _)) in shifts.iter().zip(&ds).zip(contributions) {
            let t = (shift - kmin) as usize;
            let first = fresh && t == w;
            let acc = if first {
                "B(-0.0)".to_string()
            } else {
                format!("w{t}_@")
            };
            let e = if factor == 1.0 {
                if first {
                    d.clone()
                } else {
                    format!("{acc} + {d}")
                }
            } else if factor == -1.0 {
                format!("{acc} - {d}")
            } else {
                format!("{acc} + B({}) * {d}", konst(factor))
            };
            let decl = if first { "vd " } else { "" };
            lines.push(Line::PerUnit(format!("{decl}w{t}_@ = {e};")));
        }
        if plan.kick {
            // The site the term completes, kicked at once.
            let r = format!("i + {}", kmin - 1);
            lines.push(Line::PerUnit(format!(
                "ST(xb + ({n} + {r}) * stride + @O, LD(xb + ({n} + {r}) * stride + @O) - dh * w0_@);"
            )));
        } else {
            lines.push(Line::PerUnit(format!(
                "ST(g + (i + {}) * BLOCK + @O, w0_@);",
                kmin - 1
            )));
        }
        for t in 0..w {
            lines.push(Line::PerUnit(format!("w{t}_@ = w{}_@;", t + 1)));
        }
        for &(s, s2) in &carry {
            lines.push(Line::PerUnit(format!("cx{s}_@ = x{s2}_@;")));
            if self.tangent {
                lines.push(Line::Once(format!("cy{s} = y{s2};")));
            }
        }
        Self::write_lines(out, &lines, "            ");
        let _ = writeln!(out, "          }}");
        let mut post = Vec::new();
        for t in 0..w {
            post.push(Line::PerUnit(format!(
                "ST(g + ({}) * BLOCK + @O, w{t}_@);",
                to + 1 + kmin + t as i64 - 1
            )));
        }
        Self::write_lines(out, &post, "          ");
        let _ = writeln!(out, "        }}");
    }

    /// `q_j += c_j p_j` for the rows `a..z` of the block.
    fn drift_rows(out: &mut String, n: usize, a: usize, z: usize) {
        let _ = writeln!(
            out,
            "        for (size_t j = {a}; j < {z}; j++) {{\n          const double c = w ? ch * w[j] : ch;\n          ST(xb + j * stride, LD(xb + j * stride) + B(c) * LD(xb + ({n} + j) * stride));\n          ST(xb + j * stride + LANES, LD(xb + j * stride + LANES) + B(c) * LD(xb + ({n} + j) * stride + LANES));\n        }}"
        );
    }

    fn write(&self, out: &mut String) {
        let n = self.lattice.n;
        let head = |out: &mut String| {
            for a in 0..self.arrays.len() {
                let _ = writeln!(
                    out,
                    "  const double *arr{a} = (const double *)env[{}];",
                    self.array_env + a
                );
            }
        };
        // The plan's passes: rows drifted before the parts, the force's rows that must start
        // at -0, the parts (whose loops drift and kick as they go), the rows the force never
        // read, the rows left to kick.
        let block = |out: &mut String| {
            for &(a, z) in &self.plan.pre_drift {
                Self::drift_rows(out, n, a, z);
            }
            for &(a, z) in &self.plan.init {
                let _ = writeln!(
                    out,
                    "        for (size_t j = {a}; j < {z}; j++) {{ ST(g + j * BLOCK, B(-0.0)); ST(g + j * BLOCK + LANES, B(-0.0)); }}"
                );
            }
            self.force(out);
            for &(a, z) in &self.plan.post_drift {
                Self::drift_rows(out, n, a, z);
            }
            for &(a, z) in &self.plan.post_kick {
                let _ = writeln!(
                    out,
                    "        for (size_t j = {a}; j < {z}; j++) {{\n          ST(xb + ({n} + j) * stride, LD(xb + ({n} + j) * stride) - dh * LD(g + j * BLOCK));\n          ST(xb + ({n} + j) * stride + LANES, LD(xb + ({n} + j) * stride + LANES) - dh * LD(g + j * BLOCK + LANES));\n        }}"
                );
            }
        };
        step_loops(out, n, self.tangent, "g", head, |_| {}, block);
    }
}
