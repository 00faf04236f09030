//! A separable Hamiltonian `H = sum_j w_j p_j^2 / 2 + V(q)` whose potential is written as an
//! expression (`[model] name = "potential"`), compiled once to native code with its gradient and
//! Hessian-vector product derived symbolically.
//!
//! The expression is lowered to a DAG ([`crate::lower`]), differentiated there (reverse mode for
//! the gradient, forward mode over the gradient for `Hess V v`), and the potential, gradient and
//! Hessian-vector product are compiled by Cranelift, once per run: as scalar functions (the
//! one-orbit engine), and, at the batched kernel's first call, as whole splitting steps over
//! structure-of-arrays lanes, orbits and tangent vectors, with the force inline (a run never
//! builds them). Lattice sums that allow it are loops over their term
//! ([`crate::lattice`]): compile time and code size do not grow with `N`. The compiled
//! code performs exactly the reference evaluator's operations, so every path gives the same
//! bits.
//!
//! Time: `t` in the potential is the time (`V(q, t)`, a non-autonomous system), argument array
//! [`ARG_T`] of the scalar functions (`*_at` calls). A potential that reads it is always
//! unrolled (its lattice sums are not loops) and has no step kernels: the splittings step it
//! through the scalar functions, kick by kick at the time of each kick. One that does not
//! read it compiles to the same operations, loops and step kernels as it would without the
//! argument.

use std::collections::{BTreeMap, HashMap};
use std::sync::atomic::Ordering;
use std::sync::{Arc, OnceLock};
use std::time::Duration;

use crate::graph::{Graph, NodeId, Tabulated};
use crate::jit::{Compiled, FunctionSpec, Layout, ScalarFnPtr, StepKernels};
use crate::lattice::{LatticeEvaluator, LatticePotential};
use crate::lower::{Boundary, Family, Lowered, ParamValue, Scope, Shape};
use crate::site_parts::SiteShares;
use crate::smooth::Smoothness;
use crate::{Span, diff, eval, jit, lower};

/// Everything that defines a potential model, validated except for the expression itself.
#[derive(Debug, Clone)]
pub struct PotentialDefinition {
    /// Degrees of freedom (the value of `N` in the expression on a chain; on a square
    /// lattice `N` is the side and this its square).
    pub n: usize,
    /// The expression of `V(q)`.
    pub potential: String,
    pub params: BTreeMap<String, ParamValue>,
    /// `1 / m_i`, or `None` for unit masses.
    pub inverse_masses: Option<Vec<f64>>,
    /// Along the rows on a square lattice.
    pub boundary: Boundary,
    /// A chain of sites, or a square read as `q[i, j]`.
    pub shape: crate::lower::Shape,
    /// Tabulated functions by the name the expression calls them.
    pub tables: Vec<(String, Arc<dyn Tabulated>)>,
}

/// Why a potential could not be built: the expression (with line, column and caret) or the
/// compiler.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{0}")]
pub struct PotentialError(pub String);

// Function indices in the compiled module.
const POTENTIAL: usize = 0;
const GRADIENT: usize = 1;
const HESSIAN_VECTOR: usize = 2;

/// Argument arrays of the compiled functions: positions, and the direction of `Hess V v`.
use crate::lattice::{ARG_Q, ARG_V};

mod kernel_switch;

use kernel_switch::{CANCEL_GRACE, CSteps};
pub use kernel_switch::{CStepState, CStepStatus, KernelBuild, uncounted};

/// The time's argument array (one entry): beyond those of the lattice loops
/// ([`crate::lattice::ARG_SUM`] and below), so a graph holding a failed loop attempt's slot
/// inputs never mistakes one for the time.
pub const ARG_T: u8 = 6;

/// The lane parameters' argument array (a map's parameter axes: [`ParamValue::Lane`]s of this
/// argument, numbered from 0), after the time's.
pub const ARG_PARAMS: u8 = ARG_T + 1;

/// Argument arrays of a scalar function of the time: positions, direction, the unused lattice
/// ones, the time.
const ARGS: usize = ARG_T as usize + 1;

/// Argument arrays of a scalar call: as [`ARGS`], and the lane parameters (read only by a
/// potential that has some).
const CALL_ARGS: usize = ARG_PARAMS as usize + 1;

/// How the potential's derivatives are written.
enum Form {
    /// Every site's derivative a node of the graph (no lattice sum, or one that is not a loop).
    Unrolled {
        potential: NodeId,
        gradient: Vec<NodeId>,
        hessian_vector: Vec<NodeId>,
        /// The parts of `V` ([`crate::lower::Lowered::parts`]) by site.
        parts: Arc<SiteShares>,
    },
    /// Loops over the terms of lattice sums.
    Lattice(Arc<LatticePotential>),
}

struct Inner {
    definition: PotentialDefinition,
    /// Shared with the background C build.
    graph: Arc<Graph>,
    origins: HashMap<NodeId, Span>,
    form: Form,
    smoothness: Smoothness,
    compiled: Compiled,
    /// Whole splitting steps over lanes by Cranelift: compiled at the batched kernel's first
    /// call (a run never calls it), its fallback while the C kernels build; why there are none
    /// if that failed (the generic step loops around the scalar functions run instead).
    steps: OnceLock<Result<StepKernels, String>>,
    /// The same steps in C (host-width vectors), built on a background thread from the
    /// batched kernel's first call (a `run` never pays for it) or loaded from the kernel
    /// cache.
    c_steps: Arc<CSteps>,
    /// The one-orbit hot path calls the machine code directly: the checked `Compiled::call`
    /// costs as much as the Henon-Heiles forces themselves. `new` checks that these read at
    /// most `N` entries of each argument, so slices of length `N` are enough.
    gradient_fn: ScalarFnPtr,
    hessian_vector_fn: ScalarFnPtr,
    /// Continuous second derivatives (the variational method applies).
    c2: bool,
    /// `V` reads the time.
    reads_time: bool,
    /// `P`: parameters read per call ([`ARG_PARAMS`]) instead of folded (a map's parameter
    /// axes). A potential with any is always unrolled and has no step kernels.
    lane_params: usize,
    /// `P` NaNs: the parameters of a call that gives none (`gradient`, `gradient_at`, ...),
    /// so such a call of a parametrized potential gives NaN, never reads a null pointer.
    no_params: Vec<f64>,
    build_time: Duration,
}

impl Drop for Inner {
    /// The last handle to the model is gone: a C build still running is not wanted any more.
    /// It is cancelled (the compiler killed, its files removed) rather than awaited, so a map
    /// that ends, or is interrupted, before the build never waits for a compiler; the next map
    /// of the same potential starts it again (a build that finished is in the cache). The build
    /// thread sees the cancel within milliseconds; one that does not end within
    /// [`CANCEL_GRACE`] (a compiler stuck where even SIGKILL waits, on a stalled network mount)
    /// is left behind rather than joined, and ends with the process.
    fn drop(&mut self) {
        self.c_steps.cancel.store(true, Ordering::Relaxed);
        self.c_steps.join_within(CANCEL_GRACE);
    }
}

/// Fewest state-value steps (steps times `2N`) of a run that builds a potential's C kernels for
/// the fused pass of its small sets of tangent vectors: the build costs about 0.15-0.5
/// CPU-seconds (a compiler process, and its memory) once per chain and machine (later runs load
/// the kernels from the cache), the pass saves about 5 ns per site and step against the
/// one-orbit path (AMD EPYC Zen 5, the DKG chain of 1000 sites, one vector: 2.0 s against 0.9 s
/// per 2 * 10^8 site-steps), so below about 10^8 state values the build costs more than it
/// saves (such a run still loads the kernels if an earlier one left them in the cache). The
/// bits are the same either way.
pub const MIN_FUSED_WORK: u64 = 100_000_000;

/// [`MIN_FUSED_WORK`] for a lattice, `side` the side of a square (`None` on a chain): a
/// square's C build
/// holds a loop per row in each step kernel and grows faster than its side (an Intel Xeon, the
/// 2-D Klein-Gordon lattice: 7 CPU-seconds at 32 x 32, 18 at 64 x 64, 71 at 128 x 128), while
/// the pass saves about 2.7e-8 s per state value and step there (64 x 64, one vector: 11.8 s
/// against 39 s to t = 6000). Its threshold grows as `side^2 / 256` (4 * 10^8 at 32 x 32,
/// 1.6 * 10^9 at 64 x 64), at or above where the build repays itself.
pub fn min_fused_work(side: Option<usize>) -> u64 {
    let Some(side) = side else {
        return MIN_FUSED_WORK;
    };
    let factor = (side as u64).saturating_mul(side as u64) / 256;
    MIN_FUSED_WORK.saturating_mul(factor.max(1))
}

/// The least side of a square lattice whose sums are compiled as loops along its rows. A
/// smaller square is unrolled: its build takes a fraction of a second, and its straight-line
/// code steps faster than loops over rows of a few sites (one run on an AMD Zen 4, the 2-D
/// Klein-Gordon example: unrolled 1.7x faster at 11 x 11, 1.2x at 21 x 21, 1.1x at 30 x 30, the
/// loops 1.1x faster at 40 x 40).
pub const SQUARE_LOOPS_FROM_SIDE: usize = 32;

/// A compiled potential model. Cheap to clone (shared compiled code).
#[derive(Clone)]
pub struct ExpressionModel(Arc<Inner>);

impl std::fmt::Debug for ExpressionModel {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ExpressionModel")
            .field("n", &self.0.definition.n)
            .field("potential", &self.0.definition.potential)
            .field("nodes", &self.0.graph.len())
            .finish()
    }
}

impl ExpressionModel {
    /// Parse, differentiate and compile.
    pub fn new(definition: PotentialDefinition) -> Result<Self, PotentialError> {
        let started = std::time::Instant::now();
        let n = definition.n;
        let mut graph = Graph::new();
        let tables: Vec<(String, u32)> = definition
            .tables
            .iter()
            .map(|(name, t)| (name.clone(), graph.add_table(t.clone())))
            .collect();
        let families = [Family {
            name: "q".to_string(),
            len: n,
            arg: ARG_Q,
            offset: 0,
        }];
        let scope = Scope {
            families: &families,
            params: &definition.params,
            tables: &tables,
            n: definition.shape.n_of(n),
            boundary: definition.boundary,
            shape: definition.shape,
            time: Some(ARG_T),
        };
        let source = &definition.potential;
        let err = |e: &dyn std::fmt::Display| PotentialError(e.to_string());
        let small_square =
            matches!(definition.shape, Shape::Square { .. }) && scope.n < SQUARE_LOOPS_FROM_SIDE;
        let lowered = if small_square {
            lower::lower(source, &scope, &mut graph)
        } else {
            lower::lower_with_loops(source, &scope, &mut graph)
        }
        .map_err(|e| err(&e))?;
        // Second derivatives only where they exist: a potential that is not C^2 is refused
        // for VM anyway, and its Hessian-vector product is not compiled.
        let c2 = lowered.smoothness.require(2, "vm").is_ok();
        let Lowered {
            root,
            smoothness,
            origins,
            sums,
            parts,
        } = lowered;
        let had_sums = !sums.is_empty();
        let reads_time = graph
            .nodes()
            .iter()
            .any(|n| matches!(n, crate::graph::Node::Input { arg: ARG_T, .. }));
        let lane_params = lane_param_count(&definition.params)?;
        let lattice = if had_sums && !reads_time && lane_params == 0 {
            LatticePotential::new(&mut graph, root, sums, n, c2).map_err(|e| err(&e))?
        } else {
            None
        };
        let (graph, origins, form, compiled) = match lattice {
            Some(lattice) => {
                let compiled = jit::compile_lattice(&graph, &lattice, &jit::Options::default())
                    .map_err(|e| PotentialError(format!("compiling the potential: {e}")))?;
                (graph, origins, Form::Lattice(Arc::new(lattice)), compiled)
            }
            None => {
                // No sum is a loop, or the potential is not affine in its sums: every site's
                // derivative unrolled (lowered again without loops if some sum was one).
                let (mut graph, origins, potential, parts) = if had_sums {
                    let mut graph = Graph::new();
                    for (_, t) in &definition.tables {
                        graph.add_table(t.clone());
                    }
                    let lowered = lower::lower(source, &scope, &mut graph).map_err(|e| err(&e))?;
                    (graph, lowered.origins, lowered.root, lowered.parts)
                } else {
                    (graph, origins, root, parts)
                };
                let parts = Arc::new(SiteShares::new(parts, ARG_Q, n));
                let gradient =
                    diff::gradient(&mut graph, potential, ARG_Q, n).map_err(|e| err(&e))?;
                let hessian_vector = if c2 {
                    diff::jacobian_vector(&mut graph, &gradient, ARG_Q, ARG_V)
                        .map_err(|e| err(&e))?
                } else {
                    vec![graph.constant(0.0); n]
                };
                let compiled = compile_unrolled(
                    &graph,
                    potential,
                    &gradient,
                    &hessian_vector,
                    reads_time,
                    lane_params,
                )?;
                let form = Form::Unrolled {
                    potential,
                    gradient,
                    hessian_vector,
                    parts,
                };
                (graph, origins, form, compiled)
            }
        };
        let switch_after_calls = std::env::var("CHAOSCOPE_C_KERNELS_AFTER_CALLS")
            .ok()
            .and_then(|v| v.trim().parse().ok());
        Ok(Self(Arc::new(Inner {
            gradient_fn: compiled.raw_scalar(GRADIENT),
            hessian_vector_fn: compiled.raw_scalar(HESSIAN_VECTOR),
            c2,
            reads_time,
            lane_params,
            no_params: vec![f64::NAN; lane_params],
            origins,
            smoothness,
            definition,
            graph: Arc::new(graph),
            form,
            compiled,
            steps: OnceLock::new(),
            c_steps: Arc::new(CSteps::new(switch_after_calls)),
            build_time: started.elapsed(),
        })))
    }

    /// Whether the lattice sums are loops (else every site's derivative is unrolled).
    pub fn has_loops(&self) -> bool {
        matches!(self.0.form, Form::Lattice(_))
    }

    pub fn definition(&self) -> &PotentialDefinition {
        &self.0.definition
    }

    /// Degrees of freedom `N`.
    pub fn dof(&self) -> usize {
        self.0.definition.n
    }

    /// Whether `V` reads the time `t` (a non-autonomous system: no step kernels, no loops).
    pub fn reads_time(&self) -> bool {
        self.0.reads_time
    }

    /// `V(q)` (at `t = 0`: the only value of a potential that does not read the time).
    #[inline]
    pub fn potential(&self, q: &[f64]) -> f64 {
        self.potential_at(q, 0.0)
    }

    /// `V(q, t)`.
    #[inline]
    pub fn potential_at(&self, q: &[f64], t: f64) -> f64 {
        self.potential_with(q, t, &self.0.no_params)
    }

    /// `P`: the parameters every call reads ([`ARG_PARAMS`], a map's parameter axes); 0 for a
    /// potential whose parameters are all constants.
    pub fn lane_params(&self) -> usize {
        self.0.lane_params
    }

    /// `V(q, t)` at the lane parameters `params` (`P` values; ignored when `P = 0`).
    ///
    /// # Panics
    /// If `params` has fewer than `P` entries.
    #[inline]
    pub fn potential_with(&self, q: &[f64], t: f64, params: &[f64]) -> f64 {
        let mut v = [0.0];
        if self.0.lane_params > 0 {
            let time = [t];
            let mut args: [&[f64]; CALL_ARGS] = [&[]; CALL_ARGS];
            args[ARG_Q as usize] = q;
            args[ARG_T as usize] = &time;
            args[ARG_PARAMS as usize] = params;
            self.0.compiled.call(POTENTIAL, &args, &mut v);
        } else if self.0.reads_time {
            let time = [t];
            let mut args: [&[f64]; ARGS] = [&[]; ARGS];
            args[ARG_Q as usize] = q;
            args[ARG_T as usize] = &time;
            self.0.compiled.call(POTENTIAL, &args, &mut v);
        } else {
            self.0.compiled.call(POTENTIAL, &[q], &mut v);
        }
        v[0]
    }

    /// `out = dV/dq (q)`.
    ///
    /// # Panics
    /// If `q` or `out` does not have `N` entries.
    #[inline]
    pub fn gradient(&self, q: &[f64], out: &mut [f64]) {
        self.gradient_at(q, 0.0, out)
    }

    /// `out = dV/dq (q, t)`.
    ///
    /// # Panics
    /// If `q` or `out` does not have `N` entries.
    #[inline]
    pub fn gradient_at(&self, q: &[f64], t: f64, out: &mut [f64]) {
        self.gradient_with(q, t, &self.0.no_params, out)
    }

    /// `out = dV/dq (q, t)` at the lane parameters `params` (`P` values).
    ///
    /// # Panics
    /// If `q` or `out` does not have `N` entries, or `params` fewer than `P`.
    #[inline]
    pub fn gradient_with(&self, q: &[f64], t: f64, params: &[f64], out: &mut [f64]) {
        let n = self.0.definition.n;
        assert!(q.len() == n && out.len() == n, "gradient of {n} sites");
        assert!(params.len() >= self.0.lane_params, "lane parameters");
        let time = [t];
        let mut args = [std::ptr::null(); CALL_ARGS];
        args[ARG_Q as usize] = q.as_ptr();
        args[ARG_T as usize] = time.as_ptr();
        args[ARG_PARAMS as usize] = params.as_ptr();
        // SAFETY: the function reads at most N entries of `q` and P of the parameters (checked
        // in `new`) and writes N outputs; the slices are that long; `out` is a `&mut`, so it
        // overlaps nothing; the code lives as long as `self.0.compiled`.
        unsafe { (self.0.gradient_fn)(args.as_ptr(), out.as_mut_ptr()) }
    }

    /// `out = Hess V(q) v`, or `false` (with `out` untouched) when `V` is not `C^2`.
    ///
    /// # Panics
    /// If `q`, `v` or `out` does not have `N` entries.
    #[inline]
    pub fn hessian_vector(&self, q: &[f64], v: &[f64], out: &mut [f64]) -> bool {
        self.hessian_vector_at(q, 0.0, v, out)
    }

    /// `out = Hess V(q, t) v` (second derivatives in `q`), or `false` as
    /// [`Self::hessian_vector`].
    ///
    /// # Panics
    /// If `q`, `v` or `out` does not have `N` entries.
    #[inline]
    pub fn hessian_vector_at(&self, q: &[f64], t: f64, v: &[f64], out: &mut [f64]) -> bool {
        self.hessian_vector_with(q, t, &self.0.no_params, v, out)
    }

    /// `out = Hess V(q, t) v` at the lane parameters `params` (`P` values), or `false` as
    /// [`Self::hessian_vector`].
    ///
    /// # Panics
    /// If `q`, `v` or `out` does not have `N` entries, or `params` fewer than `P`.
    #[inline]
    pub fn hessian_vector_with(
        &self,
        q: &[f64],
        t: f64,
        params: &[f64],
        v: &[f64],
        out: &mut [f64],
    ) -> bool {
        if !self.0.c2 {
            return false;
        }
        let n = self.0.definition.n;
        assert!(
            q.len() == n && v.len() == n && out.len() == n,
            "Hessian-vector product of {n} sites"
        );
        assert!(params.len() >= self.0.lane_params, "lane parameters");
        let time = [t];
        let mut args = [std::ptr::null(); CALL_ARGS];
        args[ARG_Q as usize] = q.as_ptr();
        args[ARG_V as usize] = v.as_ptr();
        args[ARG_T as usize] = time.as_ptr();
        args[ARG_PARAMS as usize] = params.as_ptr();
        // SAFETY: as in `gradient_with`, for the arguments `q`, `v`, the time and the
        // parameters.
        unsafe { (self.0.hessian_vector_fn)(args.as_ptr(), out.as_mut_ptr()) }
        true
    }

    /// Whether `V` has continuous second derivatives (the variational method applies).
    pub fn has_hessian(&self) -> bool {
        self.0.c2
    }

    /// Why the variational method cannot be used, naming the operation that limits the
    /// smoothness of `V`; `None` when it can.
    pub fn no_hessian_reason(&self) -> Option<String> {
        self.0
            .smoothness
            .require(2, "the variational method (vm)")
            .err()
    }

    /// `1 / m_i`, or `None` for unit masses.
    pub fn inverse_masses(&self) -> Option<&[f64]> {
        self.0.definition.inverse_masses.as_deref()
    }

    /// The potential energy of each site at `q` into `out` (`N` values): each term of a
    /// lattice sum shared equally by the sites it reads ([`LatticeEvaluator::site_potentials`],
    /// which defines it; for unrolled sums, the terms of the sums `V` adds, each with its
    /// constant factor). An error saying why where the sites of `V`'s parts are not known: a
    /// potential not written as lattice sums added together, or one that reads the time or
    /// parameters per evaluation.
    pub fn site_potentials(&self, q: &[f64], out: &mut [f64]) -> Result<(), String> {
        let n = self.0.definition.n;
        if q.len() != n || out.len() != n {
            return Err(format!(
                "{n} sites expected, got {} and {}",
                q.len(),
                out.len()
            ));
        }
        match &self.0.form {
            Form::Lattice(lattice) => {
                LatticeEvaluator::new(&self.0.graph, lattice).site_potentials(q, out)
            }
            Form::Unrolled { .. } if self.0.reads_time => Err(
                "V reads the time, so it is not compiled as lattice sums and its terms' sites \
                 are not known"
                    .to_string(),
            ),
            Form::Unrolled { .. } if self.0.lane_params > 0 => Err(
                "V reads parameters per evaluation (a map's axes), so its terms' values are \
                 not those of one model"
                    .to_string(),
            ),
            Form::Unrolled { parts, .. } if !parts.has_no_sums() => {
                let mut args: [&[f64]; ARGS] = [&[]; ARGS];
                args[ARG_Q as usize] = q;
                parts.shares(&self.0.graph, &args, out)
            }
            Form::Unrolled { .. } => Err(
                "V is not written as lattice sums added at its top level (sum(i = a..b, term) \
                 + ..., or sums of sums on a square lattice), so which of its terms belongs \
                 to which site is not known"
                    .to_string(),
            ),
        }
    }

    /// The operation (with its line and column in the source) that makes `V` or a component
    /// of its gradient non-finite at `q`, if any; in a lattice loop, with the term it arose in.
    pub fn diagnose_non_finite(&self, q: &[f64]) -> Option<String> {
        self.diagnose_non_finite_at(q, 0.0)
    }

    /// [`Self::diagnose_non_finite`] at time `t`.
    pub fn diagnose_non_finite_at(&self, q: &[f64], t: f64) -> Option<String> {
        self.diagnose_non_finite_with(q, t, &self.0.no_params)
    }

    /// [`Self::diagnose_non_finite`] at time `t` and the lane parameters `params`.
    pub fn diagnose_non_finite_with(&self, q: &[f64], t: f64, params: &[f64]) -> Option<String> {
        let g = &self.0.graph;
        match &self.0.form {
            Form::Unrolled {
                potential,
                gradient,
                ..
            } => {
                let time = [t];
                let mut a: [&[f64]; CALL_ARGS] = [&[]; CALL_ARGS];
                a[ARG_Q as usize] = q;
                a[ARG_T as usize] = &time;
                a[ARG_PARAMS as usize] = params;
                if let Some(id) = eval::first_non_finite(g, &a, *potential) {
                    return Some(self.describe(id, &a, "in the potential"));
                }
                for (i, &out) in gradient.iter().enumerate() {
                    if let Some(id) = eval::first_non_finite(g, &a, out) {
                        return Some(self.describe(id, &a, &format!("in dV/dq{}", i + 1)));
                    }
                }
                None
            }
            Form::Lattice(lattice) => {
                let mut e = LatticeEvaluator::new(g, lattice);
                let (id, term) = e.first_non_finite(q)?;
                match term {
                    Some((s, i)) => {
                        let args = e.term_args(s, i, q);
                        let args: Vec<&[f64]> = args.iter().map(Vec::as_slice).collect();
                        Some(self.describe(id, &args, &format!("in the term i = {i} of a sum")))
                    }
                    None => {
                        let sums = e.sums(q);
                        let args: [&[f64]; 6] = [q, &[], &[], &[], &[], &sums];
                        Some(self.describe(id, &args, "in the potential"))
                    }
                }
            }
        }
    }

    /// Parse, differentiate and compile time of this model.
    pub fn build_time(&self) -> Duration {
        self.0.build_time
    }

    /// Nodes of the expression DAG (potential, gradient, Hessian-vector product).
    pub fn graph_nodes(&self) -> usize {
        self.0.graph.len()
    }

    pub fn smoothness(&self) -> &Smoothness {
        &self.0.smoothness
    }

    /// `'log' at line 1, column 9 of the potential gave NaN (what)`: node `id` evaluated with
    /// the argument arrays `args`.
    fn describe(&self, id: NodeId, args: &[&[f64]], what: &str) -> String {
        let mut value = [0.0];
        eval::Evaluator::new().eval(&self.0.graph, args, &[id], &mut value);
        let op = self.0.graph.operation_name(id);
        match self.0.origins.get(&id) {
            Some(span) => {
                let at = crate::ExprError::new(&self.0.definition.potential, *span, "");
                let (line, column) = (at.line, at.column);
                format!(
                    "{op} at line {line}, column {column} of the potential gave {} ({what})",
                    value[0]
                )
            }
            None => format!("{op} gave {} ({what})", value[0]),
        }
    }
}

/// The potential, its gradient and its Hessian-vector product as scalar functions (the
/// batched kernel runs the step kernels), each checked to read at most `N` entries of each
/// argument.
fn compile_unrolled(
    graph: &Graph,
    potential: NodeId,
    gradient: &[NodeId],
    hessian_vector: &[NodeId],
    reads_time: bool,
    lane_params: usize,
) -> Result<Compiled, PotentialError> {
    let n = gradient.len();
    // A potential of the time takes every argument array up to the time's (the lattice ones
    // unused), one with lane parameters up to theirs; one that reads neither keeps its one or
    // two.
    let args = |k: usize| {
        let count = if lane_params > 0 {
            CALL_ARGS
        } else if reads_time {
            ARGS
        } else {
            k
        };
        vec![Layout::Scalar; count]
    };
    let specs = [
        FunctionSpec {
            args: args(1),
            outputs: vec![potential],
        },
        FunctionSpec {
            args: args(1),
            outputs: gradient.to_vec(),
        },
        FunctionSpec {
            args: args(2),
            outputs: hessian_vector.to_vec(),
        },
    ];
    let options = jit::Options {
        lane_functions: false,
        ..jit::Options::default()
    };
    let compiled = jit::compile_with(graph, &specs, &options)
        .map_err(|e| PotentialError(format!("compiling the potential: {e}")))?;
    for (f, args) in [(GRADIENT, 1), (HESSIAN_VECTOR, 2)] {
        for a in 0..args {
            if compiled.arg_len(f, a) > n {
                return Err(PotentialError(format!(
                    "compiled function {f} reads {} entries of argument {a}, more than N = {n}",
                    compiled.arg_len(f, a)
                )));
            }
        }
        if lane_params > 0 && compiled.arg_len(f, ARG_PARAMS as usize) > lane_params {
            return Err(PotentialError(format!(
                "compiled function {f} reads {} lane parameters, more than P = {lane_params}",
                compiled.arg_len(f, ARG_PARAMS as usize)
            )));
        }
    }
    Ok(compiled)
}

/// `P`: how many parameters are [`ParamValue::Lane`]s; they must be entries `0..P` of
/// [`ARG_PARAMS`].
fn lane_param_count(params: &BTreeMap<String, ParamValue>) -> Result<usize, PotentialError> {
    let mut indices: Vec<u32> = Vec::new();
    for v in params.values() {
        if let ParamValue::Lane { arg, index, .. } = v {
            if *arg != ARG_PARAMS {
                return Err(PotentialError(format!(
                    "a lane parameter of a potential is read from argument {ARG_PARAMS}, not {arg}"
                )));
            }
            indices.push(*index);
        }
    }
    indices.sort_unstable();
    if indices.iter().enumerate().any(|(i, &j)| j as usize != i) {
        return Err(PotentialError(
            "lane parameters must be entries 0..P of their argument, each once".into(),
        ));
    }
    Ok(indices.len())
}

#[cfg(test)]
mod site_energy_tests {
    use super::*;

    fn model(n: usize, potential: &str, boundary: Boundary) -> ExpressionModel {
        ExpressionModel::new(PotentialDefinition {
            n,
            potential: potential.to_string(),
            params: BTreeMap::new(),
            inverse_masses: None,
            boundary,
            shape: crate::lower::Shape::Chain,
            tables: Vec::new(),
        })
        .unwrap()
    }

    fn sites(m: &ExpressionModel, q: &[f64]) -> Result<Vec<f64>, String> {
        let mut out = vec![f64::NAN; q.len()];
        m.site_potentials(q, &mut out).map(|()| out)
    }

    /// Each term shared equally by the distinct sites it reads (values exact in binary: halves
    /// and quarters of small integers), a wall being no site; the rest to its one site.
    #[test]
    fn terms_are_shared_by_the_sites_they_read() {
        // A ring of 3: bonds (1,2) and (3,1) stretched by 1, each 1/2, half to each end.
        let ring = model(3, "sum(i = 1..N, (q[i+1] - q[i])^2/2)", Boundary::Periodic);
        assert_eq!(sites(&ring, &[1.0, 0.0, 0.0]).unwrap(), [0.5, 0.25, 0.25]);
        // Fixed walls: the bond to the left wall whole to site 1.
        let chain = model(2, "sum(i = 0..N, (q[i+1] - q[i])^2/2)", Boundary::Fixed);
        assert_eq!(sites(&chain, &[1.0, 0.0]).unwrap(), [0.75, 0.25]);
        // A sum's coefficient, and a rest reading one site (a pinned first site).
        let pinned = model(2, "0.5*sum(i = 1..N, q[i]^2) + q1^4", Boundary::Free);
        assert_eq!(sites(&pinned, &[1.0, 2.0]).unwrap(), [1.5, 2.0]);
        let v = pinned.potential(&[1.0, 2.0]);
        assert_eq!(v, 3.5);
    }

    #[test]
    fn parts_with_no_site_or_several_are_refused_with_the_reason() {
        let constant = model(2, "sum(i = 1..N, q[i]^2) + 1", Boundary::Free);
        let why = sites(&constant, &[1.0, 2.0]).unwrap_err();
        assert!(why.contains("constant part 1"), "{why}");
        let two = model(2, "sum(i = 1..N, q[i]^2) + q1*q2", Boundary::Free);
        let why = sites(&two, &[1.0, 2.0]).unwrap_err();
        assert!(why.contains("several sites (q1, q2)"), "{why}");
        let unrolled = model(2, "q1^2 + q2^2", Boundary::Free);
        let why = sites(&unrolled, &[1.0, 2.0]).unwrap_err();
        assert!(why.contains("not written as lattice sums"), "{why}");
        // The same refusals where the sums are unrolled (the index read as a number, `0*i`).
        let constant = model(2, "sum(i = 1..N, q[i]^2 + 0*i) + 1", Boundary::Free);
        assert!(!constant.has_loops());
        let why = sites(&constant, &[1.0, 2.0]).unwrap_err();
        assert!(why.contains("constant part 1"), "{why}");
        let two = model(2, "sum(i = 1..N, q[i]^2 + 0*i) + q1*q2", Boundary::Free);
        let why = sites(&two, &[1.0, 2.0]).unwrap_err();
        assert!(why.contains("several sites (q1, q2)"), "{why}");
    }

    /// Unrolled sums share the energy as loops do: the same potential written so that its
    /// sums are loops, and with `0*i` in every term (the index read as a number, which
    /// unrolls them), gives the same site energies to rounding, with sums entering as `+`,
    /// `-`, times a constant and over one, on fixed, periodic and free ends, beside a rest on
    /// one site. A sum times a variable is no coefficient: its terms join the rest, which then
    /// reads several sites and is refused alike.
    #[test]
    fn unrolled_sums_share_the_energy_as_loops_do() {
        let q: Vec<f64> = (0..7).map(|k| 0.4 * (k as f64 * 1.3 + 0.2).sin()).collect();
        for boundary in [Boundary::Fixed, Boundary::Periodic, Boundary::Free] {
            let looped = "0.5*sum(i = 0..N, (q[i+1] - q[i])^2) - sum(i = 1..N, q[i]*q[i+1]) \
                          + sum(i = 1..N, q[i]^4)/4 + q1^2";
            let unrolled = looped
                .replace("^2)", "^2 + 0*i)")
                .replace("q[i+1])", "q[i+1] + 0*i)")
                .replace("^4)", "^4 + 0*i)");
            let (a, b) = (model(7, looped, boundary), model(7, &unrolled, boundary));
            assert!(a.has_loops() && !b.has_loops(), "{unrolled}");
            let (sa, sb) = (sites(&a, &q).unwrap(), sites(&b, &q).unwrap());
            for (x, y) in sa.iter().zip(&sb) {
                assert!((x - y).abs() < 1e-15, "{boundary:?}: {sa:?} against {sb:?}");
            }
            let total: f64 = sb.iter().sum();
            assert!((total - b.potential(&q)).abs() < 1e-15);
        }
        // A square from the side where its sums are loops along the rows, each axis's
        // boundary, against the same square unrolled (`+ 0*j` keeps a term from being a loop).
        let side = SQUARE_LOOPS_FROM_SIDE;
        let q: Vec<f64> = (0..side * side)
            .map(|k| 0.4 * (k as f64 * 1.3 + 0.2).sin())
            .collect();
        let square = |potential: &str, rows: Boundary, columns: Boundary| {
            ExpressionModel::new(PotentialDefinition {
                n: side * side,
                potential: potential.to_string(),
                params: BTreeMap::new(),
                inverse_masses: None,
                boundary: rows,
                shape: Shape::Square { columns },
                tables: Vec::new(),
            })
            .unwrap()
        };
        let looped = "sum(i = 1..N, sum(j = 1..N, q[i, j]^4/4 + (q[i+1, j] - q[i, j])^2/2 \
                      + (q[i, j+1] - q[i, j])^2/2))";
        let unrolled = looped.replace("^2/2))", "^2/2 + 0*j))");
        for rows in [Boundary::Fixed, Boundary::Periodic, Boundary::Free] {
            for columns in [Boundary::Fixed, Boundary::Periodic, Boundary::Free] {
                let (a, b) = (
                    square(looped, rows, columns),
                    square(&unrolled, rows, columns),
                );
                assert!(a.has_loops() && !b.has_loops(), "{rows:?} x {columns:?}");
                let (sa, sb) = (sites(&a, &q).unwrap(), sites(&b, &q).unwrap());
                for (x, y) in sa.iter().zip(&sb) {
                    assert!(
                        (x - y).abs() < 1e-15,
                        "{rows:?} x {columns:?}: {x} against {y}"
                    );
                }
            }
        }
        let product = model(3, "q1*sum(i = 1..N, q[i]^2 + 0*i)", Boundary::Free);
        let why = sites(&product, &[1.0, 2.0, 3.0]).unwrap_err();
        assert!(why.contains("not written as lattice sums"), "{why}");
    }
}
