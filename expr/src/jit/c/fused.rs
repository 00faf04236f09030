//! One orbit and its tangent vectors stepped together, vectorized along the lattice: the C
//! kernel `chaoscope_reference_tangent_steps` of a lattice potential, written into the same
//! library as its step kernels ([`super::lattice_steps`]).
//!
//! The step kernels vectorize across lanes (many orbits, many tangent vectors), which a run's
//! reference orbit with one or two tangent vectors cannot fill: stepped one by one through the
//! scalar functions it paid a compiled loop per gradient and per Hessian-vector product, each
//! writing a buffer that another loop applied, at about a fifth of a hand-written C's speed.
//! This kernel vectorizes along the sites instead, as a hand-written chain does, and reads the
//! reference's stage positions where they are (no recorded stages). Per stage:
//!
//! ```text
//! drift   q += c p, and dq += c dp of every vector              (vectors of 4 sites)
//! sites   g_j = the derivatives of the terms that read site j, in order; p_j -= dh g_j;
//!         the same for the first vector's Hess V(q) dq into dp  (vectors of 4 sites)
//! vectors the further vectors' Hess V(q) dq, site by site        (vectors of 4 sites)
//! ends    the sites near the ends one by one
//! ```
//!
//! The bits are [`crate::lattice::LatticeEvaluator`]'s, so those of the scalar functions and of
//! the step kernels: which sites one vector loop steps, in which order each site takes its
//! contributions, and which sites at the ends are written out one by one is the kernel's plan
//! ([`crate::jit::fused_plan`], printer-neutral); this file prints it as C. Drifts `q + c p`
//! (`c = ch * w_j` with masses) and kicks `p - dh g` as the splitting's own; no fused
//! multiply-add (the library's flags). The source holds `N`, one copy of each slot's derivative
//! and the end sites' lists; array parameters are read through `env`, as the step kernels read
//! them. A lattice without a plan gets no such kernel (the caller steps its orbit and vectors
//! the one-orbit way: the same bits). Cranelift prints the same plan ([`crate::jit::cranelift`]'s
//! `fused.rs`) for the C build's time, for hosts without a C compiler and where it fails.

use std::fmt::Write as _;
use std::sync::Arc;

use super::{emit_nodes, konst};
use crate::graph::{Graph, Node, NodeId};
use crate::jit::fused_plan::{Contribution, FusedPlan, TailIteration, tail_iteration};
use crate::jit::lattice_plan::{rest_derivatives, sum_contributions};
use crate::lattice::{
    ARG_Q, ARG_SITE, ARG_SITE_DIRECTION, ARG_SITE_PARAM, ARG_V, LatticePotential, SiteSum,
};

/// The C symbol of the kernel.
pub(crate) const SYMBOL: &[u8] = b"chaoscope_reference_tangent_steps\0";

/// When the one sweep per stage is compiled rather than the stage-by-stage form (where a
/// lattice has both): with vectors of 8 sites (AVX-512, 32 vector registers), and with 4 (AVX2,
/// 16 registers) on Intel CPUs only. With 16 registers the sweep's held positions, carried
/// terms and constants do not fit: gcc spills about 11 of its 62 instructions per vector of
/// sites. An AMD Zen 3 pays for the spills' round trips (the stage-by-stage form, whose kick
/// loop reads its neighbours from memory, is 15-25 % faster there), an Intel Xeon does not (the
/// sweep is 0-14 % faster there): `docs/decisions/0020-fused-form-by-register-count.md`.
/// [`HOST_INTEL`] says which CPU builds the kernel. Tests and benches pick a form on any host
/// with `-DCHAOSCOPE_FUSED_SWEEP` or `-DCHAOSCOPE_FUSED_STAGES`. Either form gives the same bits.
const SWEEP_CONDITION: &str = "defined(CHAOSCOPE_FUSED_SWEEP) || (!defined(CHAOSCOPE_FUSED_STAGES) \
    && (FLANES == 8 || (defined(__AVX2__) && defined(CHAOSCOPE_HOST_INTEL))))";

/// The line of the source that tells [`SWEEP_CONDITION`] the kernel is built on an Intel CPU
/// (the source, and so the cache key, differs by vendor: a cache shared by machines of both
/// keeps one kernel for each).
const HOST_INTEL: &str = "#define CHAOSCOPE_HOST_INTEL 1\n";

/// Whether this process runs on an Intel CPU (CPUID's vendor string).
fn host_is_intel() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        // CPUID exists on every x86-64 CPU and only reads (safe to call since Rust 1.87).
        let r = std::arch::x86_64::__cpuid(0);
        let vendor: Vec<u8> = [r.ebx, r.edx, r.ecx]
            .iter()
            .flat_map(|w| w.to_le_bytes())
            .collect();
        vendor == b"GenuineIntel"
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// The vectors of this kernel: as wide as the host's widest registers (eight lanes with
/// AVX-512, four otherwise), where the step kernels' (the prelude's `vd`) are four lanes in two
/// chains. The prelude's names are redefined to these types from here on (this kernel is the
/// last part of the source), so the expressions are written as everywhere else; the helpers
/// are the prelude's (`c_step::vector_helpers`) at the new width.
fn wide() -> String {
    let mut src = String::from(
        r#"
/* The fused one-orbit kernel (expr/src/jit/c/fused.rs): host-wide vectors. */
#if defined(__AVX512F__)
#define FLANES 8
#else
#define FLANES 4
#endif
typedef double vf __attribute__((vector_size(FLANES * 8)));
typedef int64_t vfi __attribute__((vector_size(FLANES * 8)));
"#,
    );
    src.push_str(&super::vector_helpers("F", "vf", "vfi", "FLANES"));
    src.push_str(
        r#"#undef LANES
#define LANES FLANES
#define vd vf
#define vi vfi
#define B FB
#define LD FLD
#define ST FST
#define SEL FSEL
#define VABS FVABS
#define VSQRT FVSQRT
#define VSTEP FVSTEP
#define VSIGN FVSIGN
#define VMAX FVMAX
#define VMIN FVMIN
#define V1 FV1
#define V2 FV2
#define VT FVT
"#,
    );
    src
}

/// The kernel's C source (after the step kernels' prelude), `None` when it does not apply.
/// `arrays` are the array parameters as `env` holds them from slot `array_env` on.
pub(crate) fn source(
    graph: &Graph,
    lattice: &LatticePotential,
    arrays: &[(String, Arc<[f64]>)],
    array_env: usize,
) -> Option<String> {
    let plan = FusedPlan::new(lattice)?;
    let writer = Writer {
        graph,
        lattice,
        arrays,
        array_env,
        plan: &plan,
        contributions: [false, true].map(|tangent| {
            let sums = sum_contributions(graph, lattice, tangent);
            sums.into_iter().map(|(c, _)| c).collect()
        }),
    };
    let mut src = wide();
    if host_is_intel() {
        src.push_str(HOST_INTEL);
    }
    writer.drift(&mut src);
    match writer.plan.held_offsets(lattice) {
        // Both forms, the compiler keeping the one for the host's registers: see
        // [`SWEEP_CONDITION`].
        Some(offsets) => {
            let _ = writeln!(src, "#if {SWEEP_CONDITION}");
            writer.swept(&mut src, &offsets);
            let _ = writeln!(src, "#else");
            writer.stagewise(&mut src);
            let _ = writeln!(src, "#endif");
        }
        None => writer.stagewise(&mut src),
    }
    Some(src)
}

struct Writer<'a> {
    graph: &'a Graph,
    lattice: &'a LatticePotential,
    arrays: &'a [(String, Arc<[f64]>)],
    /// `env` slot of the first array parameter.
    array_env: usize,
    plan: &'a FusedPlan,
    /// Per sum, what each slot adds to its site (`factor`, node): the gradient's `[0]`, the
    /// Hessian-vector product's `[1]`.
    contributions: [Vec<Vec<(f64, NodeId)>>; 2],
}

/// Where a term's slots are read: relative to the loop's site `j` (vectors of `LANES` sites,
/// or one), or at a term known when writing (its sites resolved: a wall is `0`).
#[derive(Clone, Copy, PartialEq, Eq)]
enum At {
    /// The term that reads site `j` through the slot of this shift; `held`: the positions
    /// (`q`, `dq`) from the sweep's registers ([`held_name`]), not from memory.
    Site {
        shift: i64,
        vector: bool,
        held: bool,
    },
    Term(i64),
    /// The terms `j + base` of the loop's vector (in the sweep: positions from its
    /// registers).
    Block(i64),
}

/// The sweep's register holding `base` (`q`, `dq`) at the sites `j + offset` of the loop's
/// vector.
fn held_name(base: &str, offset: i64) -> String {
    format!("h{base}_{}", offset_suffix(offset))
}

/// `m2` for -2, `p1` for 1.
fn offset_suffix(offset: i64) -> String {
    let sign = if offset < 0 { "m" } else { "p" };
    format!("{sign}{}", offset.unsigned_abs())
}

/// How the regular sites' loop body is written: a vector of sites, the last vector with the
/// lanes already done kept, or one site; or a vector of the sweep (positions and momenta from
/// its registers).
#[derive(Clone, Copy, PartialEq, Eq)]
enum Body {
    Vector,
    Masked,
    Scalar,
    Swept,
}

/// `o` for the orbit's force, `t` for a vector's Hessian-vector product.
fn part_tag(tangent: bool) -> &'static str {
    if tangent { "t" } else { "o" }
}

/// The register holding slot `slot` of sum `s`'s contributions at the previous vector of terms.
fn carried_name(tangent: bool, s: usize, slot: usize) -> String {
    format!("tp{}_{s}_{slot}", part_tag(tangent))
}

/// The value of slot `slot` of sum `s`'s contributions at the current vector of terms.
fn current_name(tangent: bool, s: usize, slot: usize) -> String {
    format!("tc{}_{s}_{slot}", part_tag(tangent))
}

/// `lines` as a block of the sweep's loop body.
fn write_block(out: &mut String, lines: &[String]) {
    let _ = writeln!(out, "      {{");
    for l in lines {
        let _ = writeln!(out, "        {l}");
    }
    let _ = writeln!(out, "      }}");
}

/// `acc + x`, `acc - x` or `acc + c x` ([`crate::lattice::accumulate`]).
fn add(acc: &str, c: f64, x: &str, vector: bool) -> String {
    if c == 1.0 {
        format!("{acc} + {x}")
    } else if c == -1.0 {
        format!("{acc} - {x}")
    } else if vector {
        format!("{acc} + B({}) * {x}", konst(c))
    } else {
        format!("{acc} + {} * {x}", konst(c))
    }
}

impl Writer<'_> {
    /// `q += c p` over one state's `N` sites: vectors, then the remaining sites.
    fn drift(&self, out: &mut String) {
        let n = self.lattice.n;
        let _ = writeln!(
            out,
            "static inline void fused_drift(double *restrict x, double ch, const double *w) {{
  size_t j = 0;
  if (w) {{
    for (; j + LANES <= {n}; j += LANES) ST(x + j, LD(x + j) + (B(ch) * LD(w + j)) * LD(x + {n} + j));
    for (; j < {n}; j++) x[j] = x[j] + (ch * w[j]) * x[{n} + j];
  }} else {{
    for (; j + LANES <= {n}; j += LANES) ST(x + j, LD(x + j) + B(ch) * LD(x + {n} + j));
    for (; j < {n}; j++) x[j] = x[j] + ch * x[{n} + j];
  }}
}}"
        );
    }

    /// Each array parameter's local pointer, from `env`.
    fn array_pointers(&self, out: &mut String, indent: &str) {
        for a in 0..self.arrays.len() {
            let _ = writeln!(
                out,
                "{indent}const double *arr{a} = (const double *)env[{}];",
                self.array_env + a
            );
        }
    }

    /// The sites outside the regular run: the orbit's, then every vector's.
    fn all_ends(&self, out: &mut String) {
        let n = self.lattice.n;
        let two_n = 2 * n;
        let _ = writeln!(
            out,
            "  {{\n  const double *restrict q = x;\n  double *restrict p = x + {n};"
        );
        self.array_pointers(out, "  ");
        self.ends(out, false);
        let _ = writeln!(
            out,
            "  for (size_t m = 0; m < k; m++) {{\n    const double *dq = v + m * {two_n};\n    double *dp = v + m * {two_n} + {n};"
        );
        self.ends(out, true);
        let _ = writeln!(out, "  }}\n  }}");
    }

    /// The kernel as a drift pass over each state, then a stage's kicks (the orbit's and the
    /// first vector's force in one loop over the regular sites, the other vectors' each in
    /// another, the ends): for terms that read positions farther than the sweep's registers.
    /// Opens the stage's block that reads the state from memory: the orbit's halves and the
    /// arrays' pointers.
    fn open_memory_block(&self, src: &mut String) {
        let n = self.lattice.n;
        let _ = writeln!(
            src,
            "  {{\n  const double *restrict q = x;\n  double *restrict p = x + {n};\n  (void)env;"
        );
        self.array_pointers(src, "  ");
    }

    /// Kicks the vectors after the first from memory, one after the other, then the sites near
    /// the ends, and closes the block and the stage function (both kernels end their stage so).
    fn later_vectors_and_ends(&self, src: &mut String) {
        let n = self.lattice.n;
        let two_n = 2 * n;
        let _ = writeln!(
            src,
            "  for (size_t m = 1; m < k; m++) {{\n    const double *dq = v + m * {two_n};\n    double *dp = v + m * {two_n} + {n};"
        );
        self.regular(src, &[true]);
        let _ = writeln!(src, "  }}\n  }}");
        self.all_ends(src);
        let _ = writeln!(src, "}}");
    }

    fn stagewise(&self, src: &mut String) {
        let n = self.lattice.n;
        let two_n = 2 * n;
        let _ = writeln!(
            src,
            "static void fused_stage(double *restrict x, double *restrict v, size_t k, double dh, \
             const uintptr_t *env) {{"
        );
        self.open_memory_block(src);
        let _ = writeln!(
            src,
            "  if (k > 0) {{\n    const double *dq = v;\n    double *dp = v + {n};"
        );
        self.regular(src, &[false, true]);
        let _ = writeln!(src, "  }} else {{");
        self.regular(src, &[false]);
        let _ = writeln!(src, "  }}");
        self.later_vectors_and_ends(src);
        let _ = writeln!(
            src,
            "void chaoscope_reference_tangent_steps(double *restrict x, double *restrict v, size_t k, \
             uint64_t n_steps, const double *drift, const double *kick, size_t n_kicks, \
             const double *w, const uintptr_t *env) {{
  for (uint64_t s = 0; s < n_steps; s++) {{
    for (size_t kk = 0; kk < n_kicks; kk++) {{
      const double ch = drift[kk];
      fused_drift(x, ch, w);
      for (size_t m = 0; m < k; m++) fused_drift(v + m * {two_n}, ch, w);
      fused_stage(x, v, k, kick[kk], env);
    }}
    const double ch = drift[n_kicks];
    fused_drift(x, ch, w);
    for (size_t m = 0; m < k; m++) fused_drift(v + m * {two_n}, ch, w);
  }}
}}"
        );
    }

    /// The kernel as one sweep over the sites per stage: each vector of sites drifted (by the
    /// stage's drift, or by the step's last drift and then the next step's first: two
    /// additions, as two passes make them) into registers that a vector later kicks from, its
    /// neighbours' positions two of those registers joined (`offsets`: [`FusedPlan::held_offsets`]),
    /// for the orbit and the first vector: each state read and written once per stage, where
    /// a drift pass and a kick pass each stream it through the cache. The sites outside the
    /// sweep's vectors (before the regular run, at the end of the chain) are drifted one by one
    /// before and after it, and kicked from memory after it; every value is the same
    /// operations on the same inputs as in the stage-by-stage kernel, so the same bits.
    fn swept(&self, src: &mut String, offsets: &[i64]) {
        let n = self.lattice.n;
        let two_n = 2 * n;
        // The shifted vectors: lanes of (previous, current) or (current, next) joined.
        let _ = writeln!(
            src,
            "#if defined(__clang__)\n#define FJOIN(a, b, ...) __builtin_shufflevector(a, b, __VA_ARGS__)\n#else\n#define FJOIN(a, b, ...) __builtin_shuffle(a, b, (vi){{__VA_ARGS__}})\n#endif"
        );
        for &offset in offsets.iter().filter(|&&o| o != 0) {
            let name = offset_suffix(offset);
            for (i, lanes) in [8_i64, 4].into_iter().enumerate() {
                let (pair, first) = if offset < 0 {
                    ("P, C", lanes + offset)
                } else {
                    ("C, N", offset)
                };
                let mask: Vec<String> = (first..first + lanes).map(|l| l.to_string()).collect();
                let _ = writeln!(
                    src,
                    "#{} FLANES == {lanes}\n#define FSHIFT_{name}(P, C, N) FJOIN({pair}, {})",
                    if i == 0 { "if" } else { "elif" },
                    mask.join(", ")
                );
            }
            let _ = writeln!(src, "#endif");
        }
        // The drifts as `fused_drift` writes them: `q + (ch w) p`, or `q + ch p`.
        let _ = writeln!(
            src,
            "#define FDRIFTV(X, P, J, C) (has_w ? (X) + (B(C) * LD(w + (J))) * (P) : (X) + B(C) * (P))\n\
             #define FDRIFTS(X, P, J, C) (has_w ? (X) + ((C) * w[J]) * (P) : (X) + (C) * (P))"
        );
        self.sweep(src, "fused_sweep_vector", &[false, true]);
        self.sweep(src, "fused_sweep_orbit", &[false]);
        let dispatch = |name: &str| {
            format!(
                "if (w) {{ if (two) {name}(x, v, c0, c1, 1, w, 1, dh, env); else {name}(x, v, c0, c1, 0, w, 1, dh, env); }}\n    \
                 else {{ if (two) {name}(x, v, c0, c1, 1, w, 0, dh, env); else {name}(x, v, c0, c1, 0, w, 0, dh, env); }}"
            )
        };
        let _ = writeln!(
            src,
            "static void fused_stage(double *restrict x, double *restrict v, size_t k, double c0, \
             double c1, int two, const double *w, double dh, const uintptr_t *env) {{
  if (k > 0) {{
    {}
  }} else {{
    {}
  }}",
            dispatch("fused_sweep_vector"),
            dispatch("fused_sweep_orbit")
        );
        self.open_memory_block(src);
        self.later_vectors_and_ends(src);
        // The vectors after the first are drifted by passes of their own before each stage.
        let _ = writeln!(
            src,
            "void chaoscope_reference_tangent_steps(double *restrict x, double *restrict v, size_t k, \
             uint64_t n_steps, const double *drift, const double *kick, size_t n_kicks, \
             const double *w, const uintptr_t *env) {{
  if (n_kicks == 0) {{
    for (uint64_t s = 0; s < n_steps; s++) {{
      fused_drift(x, drift[0], w);
      for (size_t m = 0; m < k; m++) fused_drift(v + m * {two_n}, drift[0], w);
    }}
    return;
  }}
  for (uint64_t s = 0; s < n_steps; s++) {{
    for (size_t kk = 0; kk < n_kicks; kk++) {{
      const int two = s > 0 && kk == 0;
      const double c0 = two ? drift[n_kicks] : drift[kk];
      const double c1 = drift[kk];
      for (size_t m = 1; m < k; m++) {{
        fused_drift(v + m * {two_n}, c0, w);
        if (two) fused_drift(v + m * {two_n}, c1, w);
      }}
      fused_stage(x, v, k, c0, c1, two, w, kick[kk], env);
    }}
  }}
  if (n_steps > 0) {{
    const double ch = drift[n_kicks];
    fused_drift(x, ch, w);
    for (size_t m = 0; m < k; m++) fused_drift(v + m * {two_n}, ch, w);
  }}
}}"
        );
    }

    /// One stage's sweep of the orbit (`parts` `[false]`) or of the orbit and the first vector
    /// (`[false, true]`): drift `c0` (then `c1` where `two`) of every site, and the kick of
    /// the regular sites, in one pass; `two` and `has_w` are constants where it is inlined.
    fn sweep(&self, src: &mut String, name: &str, parts: &[bool]) {
        let n = self.lattice.n;
        let (ja, jb) = self.plan.regular;
        let tangent = parts.contains(&true);
        let offsets = self
            .plan
            .held_offsets(self.lattice)
            .expect("the sweep is written for held offsets");
        // Per state swept: (positions, momenta) pointers' names.
        let states: &[(&str, &str)] = if tangent {
            &[("q", "p"), ("dq", "dp")]
        } else {
            &[("q", "p")]
        };
        let _ = writeln!(
            src,
            "static inline __attribute__((always_inline)) void {name}(double *restrict x, \
             double *restrict v, double c0, double c1, const int two, const double *restrict w, \
             const int has_w, double dh, const uintptr_t *env) {{
  double *restrict q = x;
  double *restrict p = x + {n};
  (void)v; (void)env;"
        );
        if tangent {
            let _ = writeln!(
                src,
                "  double *restrict dq = v;\n  double *restrict dp = v + {n};"
            );
        }
        self.array_pointers(src, "  ");
        // The last vector of every state, as the previous stage left it: read before this
        // stage stores anything near it (a load overlapping a store still in flight waits for
        // it), for the last whole vector of regular sites ([`tail_iteration`]).
        let tails: Vec<(i64, Option<TailIteration>)> = [8_i64, 4]
            .into_iter()
            .map(|lanes| (lanes, tail_iteration(n as i64, ja as i64, jb as i64, lanes)))
            .collect();
        for (i, (lanes, tail)) in tails.iter().enumerate() {
            let _ = writeln!(
                src,
                "#{} FLANES == {lanes}",
                if i == 0 { "if" } else { "elif" }
            );
            if tail.is_some() {
                for (x, p) in states {
                    let _ = writeln!(
                        src,
                        "  const vd t{x}_old = LD({x} + {n} - LANES), t{p}_old = LD({p} + {n} - LANES);"
                    );
                }
            }
        }
        let _ = writeln!(src, "#endif");
        let scalar_drift = |src: &mut String, from: &str, to: &str| {
            let _ = writeln!(src, "  for (int64_t s = {from}; s < {to}; s++) {{");
            for (x, p) in states {
                let _ = writeln!(
                    src,
                    "    double {x}s = FDRIFTS({x}[s], {p}[s], s, c0);\n    if (two) {x}s = FDRIFTS({x}s, {p}[s], s, c1);\n    {x}[s] = {x}s;"
                );
            }
            let _ = writeln!(src, "  }}");
        };
        // The sites before the regular run.
        scalar_drift(src, "0", &ja.to_string());
        let _ = writeln!(
            src,
            "  int64_t js = {ja}, drifted = {ja};\n  if ({ja} + 2 * LANES <= {n} && {ja} + LANES - 1 <= {jb}) {{\n    int64_t j = {ja};"
        );
        // The first vector drifted, the one before it (drifted, or outside the chain) loaded.
        for (x, p) in states {
            let _ = writeln!(
                src,
                "    vd h{p}_cur = LD({p} + j);\n    vd h{x}_cur = FDRIFTV(LD({x} + j), h{p}_cur, j, c0);\n    if (two) h{x}_cur = FDRIFTV(h{x}_cur, h{p}_cur, j, c1);\n    ST({x} + j, h{x}_cur);\n    vd h{x}_prev = B(0.0);\n    for (int l = 0; l < LANES; l++) h{x}_prev[l] = j - LANES + l >= 0 ? {x}[j - LANES + l] : 0.0;"
            );
        }
        // Each term's values at the previous vector of terms, for the sites that take them from
        // there (see `Self::block_kicks`).
        for &t in parts {
            for (s, slot) in self.carried_slots() {
                let _ = writeln!(src, "    vd {};", carried_name(t, s, slot));
            }
        }
        let condition = format!("j + LANES - 1 <= {jb} && j + 2 * LANES <= {n}");
        // The next vector drifted (the current one's neighbours), and the positions at every
        // offset the terms read.
        let held = |src: &mut String| {
            for (x, _) in states {
                for &offset in &offsets {
                    let held = held_name(x, offset);
                    if offset == 0 {
                        let _ = writeln!(src, "      const vd {held} = h{x}_cur;");
                    } else {
                        let _ = writeln!(
                            src,
                            "      const vd {held} = FSHIFT_{}(h{x}_prev, h{x}_cur, h{x}_next);",
                            offset_suffix(offset)
                        );
                    }
                }
            }
        };
        let advance = |src: &mut String| {
            let _ = writeln!(src, "      const int64_t jn = j + LANES;");
            for (x, p) in states {
                let _ = writeln!(
                    src,
                    "      const vd h{p}_next = LD({p} + jn);\n      vd h{x}_next = FDRIFTV(LD({x} + jn), h{p}_next, jn, c0);\n      if (two) h{x}_next = FDRIFTV(h{x}_next, h{p}_next, jn, c1);\n      ST({x} + jn, h{x}_next);"
                );
            }
            held(src);
        };
        let rotate = |src: &mut String| {
            for (x, p) in states {
                let _ = writeln!(
                    src,
                    "      h{x}_prev = h{x}_cur; h{x}_cur = h{x}_next; h{p}_cur = h{p}_next;"
                );
            }
        };
        // The first vector: each site's terms computed at the site (no earlier vector of terms),
        // and the terms the next vector takes from this one's.
        let _ = writeln!(src, "    if ({condition}) {{");
        advance(src);
        for &t in parts {
            self.site(src, t, Body::Swept);
            let mut lines = Vec::new();
            self.block_terms(t, &mut lines);
            self.carry(t, &mut lines);
            write_block(src, &lines);
        }
        rotate(src);
        let _ = writeln!(src, "      j += LANES;\n    }}");
        // The others: each term computed once, at a vector of terms, and handed to the sites
        // that read it.
        let _ = writeln!(src, "    for (; {condition}; j += LANES) {{");
        advance(src);
        for &t in parts {
            self.block_kicks(src, t);
        }
        rotate(src);
        let _ = writeln!(src, "    }}\n    drifted = j + LANES;");
        // The last whole vector of regular sites, whose next vector would run past the chain's
        // end: that vector is the sites left (drifted from the last vector as the stage found
        // it) and zeros past the end (positions no regular site reads).
        for (i, (lanes, tail)) in tails.iter().enumerate() {
            let _ = writeln!(
                src,
                "#{} FLANES == {lanes}",
                if i == 0 { "if" } else { "elif" }
            );
            let Some(tail) = tail else {
                continue;
            };
            let _ = writeln!(src, "    if (j == {}) {{", tail.at);
            let r = tail.reach;
            let lanes_idx = |f: &dyn Fn(i64) -> i64| -> String {
                (0..*lanes)
                    .map(|l| f(l).to_string())
                    .collect::<Vec<_>>()
                    .join(", ")
            };
            for (x, p) in states {
                if r < *lanes {
                    // The chain's last vector: this vector's sites as drifted, then the rest.
                    let _ = writeln!(
                        src,
                        "      vd t{x} = FDRIFTV(t{x}_old, t{p}_old, {n} - LANES, c0);\n      if (two) t{x} = FDRIFTV(t{x}, t{p}_old, {n} - LANES, c1);\n      ST({x} + {n} - LANES, FJOIN(h{x}_cur, t{x}, {}));\n      const vd h{x}_next = FJOIN(t{x}, B(0.0), {});",
                        lanes_idx(&|l| if l < r { lanes - r + l } else { lanes + l }),
                        lanes_idx(&|l| r + l)
                    );
                } else {
                    let _ = writeln!(src, "      const vd h{x}_next = B(0.0);");
                }
            }
            held(src);
            for &t in parts {
                self.block_kicks(src, t);
            }
            let _ = writeln!(src, "      j += LANES;\n      drifted = {n};\n    }}");
        }
        let _ = writeln!(src, "#endif\n    js = j;\n  }}");
        // The sites after the last vector drifted, then the regular sites not yet kicked.
        scalar_drift(src, "drifted", &n.to_string());
        let (ja, jb) = self.plan.regular;
        self.regular_from(src, parts, "js", &jb.to_string(), jb + 1 - ja);
        let _ = writeln!(src, "}}");
    }

    /// The first (least) shift of `sum`'s slots: its vector of terms in the sweep starts at
    /// `j + 1 - least` (the term the site `j` reads through that slot), so every other slot
    /// takes its site's term from this vector or the one before.
    fn least_shift(sum: &SiteSum) -> Option<i64> {
        sum.variables.iter().copied().min()
    }

    /// The (sum, slot)s whose sites take their term from the previous vector of terms too:
    /// every slot but the least-shift ones.
    fn carried_slots(&self) -> Vec<(usize, usize)> {
        let mut out = Vec::new();
        for (s, sum) in self.lattice.sums.iter().enumerate() {
            let Some(least) = Self::least_shift(sum) else {
                continue;
            };
            for &slot in &self.plan.order[s] {
                if sum.variables[slot] > least {
                    out.push((s, slot));
                }
            }
        }
        out
    }

    /// Lines computing, for every sum, each slot's contribution (the gradient's, or the
    /// Hessian-vector product's where `tangent`) at the vector of terms `j + 1 - least`, as
    /// [`current_name`]s: the slots of one term share their common operations.
    fn block_terms(&self, tangent: bool, lines: &mut Vec<String>) {
        let contributions = &self.contributions[usize::from(tangent)];
        for (s, sum) in self.lattice.sums.iter().enumerate() {
            let Some(least) = Self::least_shift(sum) else {
                continue;
            };
            let roots: Vec<NodeId> = contributions[s].iter().map(|&(_, r)| r).collect();
            let tag = format!("_{}{s}", part_tag(tangent));
            let vals = emit_nodes(
                self.graph,
                &roots,
                &mut |node| self.leaf(node, sum, At::Block(1 - least)),
                &|id, lane| format!("{}{id}{tag}", if lane { "v" } else { "s" }),
                &mut |_, text| lines.push(text),
            );
            for &slot in &self.plan.order[s] {
                let (x, lane) = vals[contributions[s][slot].1 as usize]
                    .clone()
                    .expect("emitted");
                let x = if lane { x } else { format!("B({x})") };
                lines.push(format!(
                    "const vd {} = {x};",
                    current_name(tangent, s, slot)
                ));
            }
        }
    }

    /// The sweep's kick of a vector of sites from vectors of terms: site `j + l` takes slot
    /// `slot` (shift `shift`) of sum `s` from term `j + l + 1 - shift`, lane `l - (shift -
    /// least)` of this vector of terms (or, for the lanes before, of the previous one):
    /// the same value, added in the same order, as [`Self::site`] computes at the site.
    fn block_kicks(&self, out: &mut String, tangent: bool) {
        let lattice = self.lattice;
        let contributions = &self.contributions[usize::from(tangent)];
        let mut lines = Vec::new();
        self.block_terms(tangent, &mut lines);
        let mut acc = "B(-0.0)".to_string();
        for (s, sum) in lattice.sums.iter().enumerate() {
            let Some(least) = Self::least_shift(sum) else {
                continue;
            };
            for &slot in &self.plan.order[s] {
                let (factor, _) = contributions[s][slot];
                let back = sum.variables[slot] - least;
                let current = current_name(tangent, s, slot);
                let x = if back == 0 {
                    current
                } else {
                    format!(
                        "FSHIFT_{}({}, {current}, {current})",
                        offset_suffix(-back),
                        carried_name(tangent, s, slot)
                    )
                };
                let next = format!("a{s}_{slot}");
                lines.push(format!(
                    "const vd {next} = {};",
                    add(&acc, factor, &x, true)
                ));
                acc = next;
            }
        }
        let p = if tangent { "dp" } else { "p" };
        lines.push(format!("ST({p} + j, h{p}_cur - B(dh) * {acc});"));
        self.carry(tangent, &mut lines);
        write_block(out, &lines);
    }

    /// The statements that carry each slot's current vector of sites over to the next sweep
    /// step (of the orbit, or of the first tangent vector with `tangent`).
    fn carry(&self, tangent: bool, lines: &mut Vec<String>) {
        for (s, slot) in self.carried_slots() {
            lines.push(format!(
                "{} = {};",
                carried_name(tangent, s, slot),
                current_name(tangent, s, slot)
            ));
        }
    }

    /// The array parameter `name`'s local pointer.
    fn array(&self, name: &str) -> usize {
        self.arrays
            .iter()
            .position(|(a, _)| a == name)
            .expect("every array a sum reads")
    }

    /// A term leaf's C expression, and whether it is a vector.
    fn leaf(&self, node: &Node, sum: &SiteSum, at: At) -> (String, bool) {
        // Positions (the orbit's, the vector's) change along the sweep; parameters never.
        let (shift, base, position) = match *node {
            Node::Const(c) => return (konst(c), false),
            Node::Input {
                arg: ARG_SITE,
                index,
            } => (sum.variables[index as usize], "q".to_string(), true),
            Node::Input {
                arg: ARG_SITE_DIRECTION,
                index,
            } => (sum.variables[index as usize], "dq".to_string(), true),
            Node::Input {
                arg: ARG_SITE_PARAM,
                index,
            } => {
                let p = &sum.params[index as usize];
                (p.shift, format!("arr{}", self.array(&p.name)), false)
            }
            _ => unreachable!("a leaf of a term: {node:?}"),
        };
        match at {
            At::Block(b) => {
                // Term i = j + b reads site i + shift - 1.
                let offset = b + shift - 1;
                if position {
                    (held_name(&base, offset), true)
                } else {
                    (format!("LD({base} + (j + {offset}))"), true)
                }
            }
            // Term i = j + 1 - s reads site i + shift - 1 = j + shift - s.
            At::Site {
                shift: s,
                vector,
                held,
            } => {
                let at = format!("j + {}", shift - s);
                if held && position {
                    (held_name(&base, shift - s), true)
                } else if vector {
                    (format!("LD({base} + ({at}))"), true)
                } else {
                    (format!("{base}[{at}]"), false)
                }
            }
            At::Term(i) => match sum.site(i, shift) {
                Some(j) => (format!("{base}[{j}]"), false),
                // A wall (parameter slots always read inside the lattice).
                None => (konst(0.0), false),
            },
        }
    }

    /// Lines computing `root` of a term of `sum` at `at` into `lines` (names suffixed by
    /// `tag`); the root's value (a vector in vector code).
    fn term(
        &self,
        root: NodeId,
        sum: &SiteSum,
        at: At,
        tag: &str,
        lines: &mut Vec<String>,
    ) -> String {
        let vector = matches!(at, At::Site { vector: true, .. } | At::Block(_));
        let vals = emit_nodes(
            self.graph,
            &[root],
            &mut |node| self.leaf(node, sum, at),
            &|id, lane| format!("{}{id}{tag}", if lane { "v" } else { "s" }),
            &mut |_, text| lines.push(text),
        );
        let (x, lane) = vals[root as usize].clone().expect("emitted");
        if vector && !lane {
            format!("B({x})")
        } else {
            x
        }
    }

    /// The loop over the regular sites for `parts` (the orbit's force, `false`; the vector
    /// `dq, dp`'s Hessian-vector product, `true`): vectors of `LANES` sites, the last ones a
    /// vector ending at the last regular site whose lanes already done keep their values (or
    /// one by one, for fewer regular sites than a vector).
    fn regular(&self, out: &mut String, parts: &[bool]) {
        let Some(blocks) = &self.plan.square else {
            let (ja, jb) = self.plan.regular;
            self.regular_from(out, parts, &ja.to_string(), &jb.to_string(), jb + 1 - ja);
            return;
        };
        // Row by row: each row's regular sites are a run, the previous row's shifted by `side`.
        for rect in blocks {
            let (side, (ra, rb), (ca, cb)) = (rect.side, rect.rows, rect.columns);
            let _ = writeln!(out, "    for (int64_t r = {ra}; r <= {rb}; r++) {{");
            self.regular_from(
                out,
                parts,
                &format!("r * {side} + {ca}"),
                &format!("(r * {side} + {cb})"),
                cb + 1 - ca,
            );
            let _ = writeln!(out, "    }}");
        }
    }

    /// [`Self::regular`] over the run of `len` regular sites from `start` to `jb` (C
    /// expressions), or from a later `start` (the regular sites before it done) to `jb`.
    fn regular_from(&self, out: &mut String, parts: &[bool], start: &str, jb: &str, len: usize) {
        // The step's broadcast once, before the loop: written in the kick, gcc 12 builds it
        // anew in every iteration from copies of `dh` (5 shuffles of a 45-instruction loop).
        let _ = writeln!(
            out,
            "    {{ int64_t j = {start};\n    const vd vdh = B(dh);"
        );
        let _ = writeln!(out, "    for (; j + LANES - 1 <= {jb}; j += LANES) {{");
        for &t in parts {
            self.site(out, t, Body::Vector);
        }
        let _ = writeln!(out, "    }}");
        // LANES is 4 or 8, as the host has.
        if len >= 8 {
            // A vector ending at the last regular site, the lanes before `j` (done) kept.
            let _ = writeln!(
                out,
                "    if (j <= {jb}) {{\n      const int64_t done = j;\n      j = {jb} - LANES + 1;\n      vi keep;\n      for (int l = 0; l < LANES; l++) keep[l] = j + l < done ? -1 : 0;"
            );
            for &t in parts {
                self.site(out, t, Body::Masked);
            }
            let _ = writeln!(out, "    }}");
        } else {
            let _ = writeln!(out, "    for (; j <= {jb}; j++) {{");
            for &t in parts {
                self.site(out, t, Body::Scalar);
            }
            let _ = writeln!(out, "    }}");
        }
        let _ = writeln!(out, "    }}");
    }

    /// The body of the regular sites' loop at site `j`: the orbit's force kicked into `p`, or
    /// (`tangent`) the Hessian-vector product along `dq` kicked into `dp`.
    fn site(&self, out: &mut String, tangent: bool, body: Body) {
        let vector = body != Body::Scalar;
        let held = body == Body::Swept;
        let lattice = self.lattice;
        let contributions = &self.contributions[usize::from(tangent)];
        let mut lines = Vec::new();
        let mut acc = if vector { "B(-0.0)" } else { "-0.0" }.to_string();
        for &(s, slot) in &self.plan.pattern {
            let sum = &lattice.sums[s];
            let (factor, root) = contributions[s][slot];
            let at = At::Site {
                shift: sum.variables[slot],
                vector,
                held,
            };
            let x = self.term(root, sum, at, &format!("_{s}_{slot}"), &mut lines);
            let next = format!("a{s}_{slot}");
            let ty = if vector { "vd" } else { "double" };
            lines.push(format!(
                "const {ty} {next} = {};",
                add(&acc, factor, &x, vector)
            ));
            acc = next;
        }
        let p = if tangent { "dp" } else { "p" };
        match body {
            Body::Vector => lines.push(format!("ST({p} + j, LD({p} + j) - vdh * {acc});")),
            Body::Masked => lines.push(format!(
                "ST({p} + j, SEL(keep, LD({p} + j), LD({p} + j) - vdh * {acc}));"
            )),
            Body::Scalar => lines.push(format!("{p}[j] = {p}[j] - dh * {acc};")),
            // The momenta as loaded before the kick, held since the drift.
            Body::Swept => lines.push(format!("ST({p} + j, h{p}_cur - B(dh) * {acc});")),
        }
        let _ = writeln!(out, "      {{");
        for l in lines {
            let _ = writeln!(out, "        {l}");
        }
        let _ = writeln!(out, "      }}");
    }

    /// The sites outside the regular run, one by one, each with its own list (the rest first).
    fn ends(&self, out: &mut String, tangent: bool) {
        let lattice = self.lattice;
        let contributions = &self.contributions[usize::from(tangent)];
        // The kernel is written only with the Hessian-vector product.
        let rest = rest_derivatives(lattice, tangent);
        let (p, indent) = if tangent { ("dp", "    ") } else { ("p", "  ") };
        let mut lines = Vec::new();
        // The expression around the sums, computed once.
        let mut rest_of = vec![None; lattice.n];
        if !rest.is_empty() {
            let roots: Vec<NodeId> = rest.iter().map(|&(_, id)| id).collect();
            let vals = emit_nodes(
                self.graph,
                &roots,
                &mut |node| match *node {
                    Node::Const(c) => (konst(c), false),
                    Node::Input { arg: ARG_Q, index } => (format!("q[{index}]"), false),
                    Node::Input { arg: ARG_V, index } => (format!("dq[{index}]"), false),
                    _ => unreachable!("the rest reads q and v: {node:?}"),
                },
                &|id, _| format!("r{id}"),
                &mut |_, text| lines.push(text),
            );
            for &(j, id) in rest {
                rest_of[j as usize] = vals[id as usize].clone().map(|v| v.0);
            }
        }
        for (e, (j, list)) in self.plan.ends.iter().enumerate() {
            let mut acc = "-0.0".to_string();
            let mut step = 0;
            let mut push = |lines: &mut Vec<String>, acc: &mut String, value: String| {
                let next = format!("e{e}_{step}");
                step += 1;
                lines.push(format!("const double {next} = {value};"));
                *acc = next;
            };
            if let Some(r) = &rest_of[*j] {
                let v = add(&acc, 1.0, r, false);
                push(&mut lines, &mut acc, v);
            }
            for (c, &Contribution { sum, term, slot }) in list.iter().enumerate() {
                let (factor, root) = contributions[sum][slot];
                let x = self.term(
                    root,
                    &lattice.sums[sum],
                    At::Term(term),
                    &format!("_e{e}_{c}"),
                    &mut lines,
                );
                let v = add(&acc, factor, &x, false);
                push(&mut lines, &mut acc, v);
            }
            lines.push(format!("{p}[{j}] = {p}[{j}] - dh * {acc};"));
        }
        let _ = writeln!(out, "{indent}{{");
        for l in lines {
            let _ = writeln!(out, "{indent}  {l}");
        }
        let _ = writeln!(out, "{indent}}}");
    }
}

#[cfg(test)]
mod tests {
    /// CPUID's vendor, read from its three registers in their order (EBX, EDX, ECX), is the one
    /// Linux reports: a misread would keep the slower 4-lane form on Intel without a sign.
    #[cfg(all(target_arch = "x86_64", target_os = "linux"))]
    #[test]
    fn the_vendor_is_the_one_linux_reports() {
        let cpuinfo = std::fs::read_to_string("/proc/cpuinfo").unwrap();
        let vendor = cpuinfo
            .lines()
            .find_map(|l| l.strip_prefix("vendor_id"))
            .and_then(|rest| rest.split(':').nth(1))
            .map(str::trim)
            .expect("/proc/cpuinfo names the vendor");
        assert_eq!(super::host_is_intel(), vendor == "GenuineIntel", "{vendor}");
    }
}
