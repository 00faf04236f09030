//! `[model] name = "potential"`: a separable Hamiltonian whose potential the user writes as an
//! expression, compiled once to native code with its gradient and Hessian-vector product
//! derived symbolically.
//!
//! The expression is lowered to a DAG (`chaoscope_expr`), differentiated there (reverse mode for
//! the gradient, forward mode over the gradient for `Hess V v`), and the potential, gradient and
//! Hessian-vector product are compiled by Cranelift, once per run: as scalar functions (the
//! one-orbit engine), and as whole splitting steps over structure-of-arrays lanes, orbits and
//! tangent vectors, with the force inline (the batched kernel). The compiled code performs
//! exactly the reference evaluator's operations, so every path gives the same bits.

use std::collections::{BTreeMap, HashMap};
use std::sync::{Arc, OnceLock};
use std::time::Duration;

use chaoscope_expr::graph::{Graph, NodeId, Tabulated};
use chaoscope_expr::jit::{Compiled, FunctionSpec, Layout, ScalarFnPtr, StepKernels, StepSpec};
use chaoscope_expr::lower::{Boundary, Family, ParamValue, Scope};
use chaoscope_expr::smooth::Smoothness;
use chaoscope_expr::{Span, diff, eval, jit, lower};

use super::Model;

/// Everything that defines a potential model, validated except for the expression itself.
#[derive(Debug, Clone)]
pub struct PotentialDefinition {
    /// Degrees of freedom `N`.
    pub n: usize,
    /// The expression of `V(q)`.
    pub potential: String,
    pub params: BTreeMap<String, ParamValue>,
    /// `1 / m_i`, or `None` for unit masses.
    pub inverse_masses: Option<Vec<f64>>,
    pub boundary: Boundary,
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
const ARG_Q: u8 = 0;
const ARG_V: u8 = 1;

struct Inner {
    definition: PotentialDefinition,
    graph: Graph,
    origins: HashMap<NodeId, Span>,
    potential: NodeId,
    gradient: Vec<NodeId>,
    smoothness: Smoothness,
    compiled: Compiled,
    hessian_vector: Vec<NodeId>,
    /// Whole splitting steps over lanes by Cranelift: compiled with the model, the batched
    /// kernel's fallback.
    steps: StepKernels,
    /// The same steps in C (host-width vectors), built on the batched kernel's first call (a
    /// `run` never pays for it) or loaded from the kernel cache; the error if none could be.
    c_steps: OnceLock<Result<StepKernels, String>>,
    /// The one-orbit hot path calls the machine code directly: the checked `Compiled::call`
    /// costs as much as the Henon-Heiles forces themselves. `new` checks that these read at
    /// most `N` entries of each argument, so slices of length `N` are enough.
    gradient_fn: ScalarFnPtr,
    hessian_vector_fn: ScalarFnPtr,
    /// Continuous second derivatives (the variational method applies).
    c2: bool,
    build_time: Duration,
}

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
            n,
            boundary: definition.boundary,
        };
        let lowered = lower::lower(&definition.potential, &scope, &mut graph)
            .map_err(|e| PotentialError(e.to_string()))?;
        let potential = lowered.root;
        let gradient = diff::gradient(&mut graph, potential, ARG_Q, n)
            .map_err(|e| PotentialError(e.to_string()))?;
        // Second derivatives only where they exist: a potential that is not C^2 is refused
        // for VM anyway, and its Hessian-vector product is not compiled.
        let c2 = lowered.smoothness.require(2, "vm").is_ok();
        let hessian_vector = if c2 {
            diff::jacobian_vector(&mut graph, &gradient, ARG_Q, ARG_V)
                .map_err(|e| PotentialError(e.to_string()))?
        } else {
            vec![graph.constant(0.0); n]
        };
        let specs = [
            FunctionSpec {
                args: vec![Layout::Scalar],
                outputs: vec![potential],
            },
            FunctionSpec {
                args: vec![Layout::Scalar],
                outputs: gradient.clone(),
            },
            FunctionSpec {
                args: vec![Layout::Scalar, Layout::Scalar],
                outputs: hessian_vector.clone(),
            },
        ];
        // Scalar functions only: the batched kernel runs the step kernels below.
        let options = jit::Options {
            lane_functions: false,
            ..jit::Options::default()
        };
        let compiled = jit::compile_with(&graph, &specs, &options)
            .map_err(|e| PotentialError(format!("compiling the potential: {e}")))?;
        let steps = jit::compile_steps(
            &graph,
            &StepSpec {
                n,
                gradient: gradient.clone(),
                hessian_vector: Some(hessian_vector.clone()),
            },
            &jit::Options::default(),
        )
        .map_err(|e| PotentialError(format!("compiling the step kernels: {e}")))?;
        for (f, args) in [(GRADIENT, 1), (HESSIAN_VECTOR, 2)] {
            for a in 0..args {
                if compiled.arg_len(f, a) > n {
                    return Err(PotentialError(format!(
                        "compiled function {f} reads {} entries of argument {a}, more than N = {n}",
                        compiled.arg_len(f, a)
                    )));
                }
            }
        }
        Ok(Self(Arc::new(Inner {
            gradient_fn: compiled.raw_scalar(GRADIENT),
            hessian_vector_fn: compiled.raw_scalar(HESSIAN_VECTOR),
            c2,
            origins: lowered.origins,
            smoothness: lowered.smoothness,
            definition,
            graph,
            potential,
            gradient,
            compiled,
            hessian_vector,
            steps,
            c_steps: OnceLock::new(),
            build_time: started.elapsed(),
        })))
    }

    pub fn definition(&self) -> &PotentialDefinition {
        &self.0.definition
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

    /// The compiled splitting steps over structure-of-arrays lanes (orbits and tangent
    /// vectors), what the batched kernel runs: the C kernels when the system C compiler built
    /// them (built on the first call, see [`Self::c_step_kernels`]), else the Cranelift ones.
    /// Both give the same bits.
    pub fn step_kernels(&self) -> &StepKernels {
        self.c_step_kernels().unwrap_or(&self.0.steps)
    }

    /// Whether the C kernels `k` were loaded from the kernel cache rather than compiled.
    pub fn c_step_kernels_cached(&self, k: &StepKernels) -> bool {
        matches!(k.backend(), jit::StepBackend::C { cached: true, .. })
    }

    /// The Cranelift step kernels (compiled with the model).
    pub fn cranelift_step_kernels(&self) -> &StepKernels {
        &self.0.steps
    }

    /// The C step kernels, compiled (or loaded from the cache) on the first call by the
    /// compiler `CHAOSCOPE_CC` names (default `cc`; `none` switches them off); why there are
    /// none otherwise. A failure is not an error of the run: the Cranelift kernels compute the
    /// same bits, more slowly.
    pub fn c_step_kernels(&self) -> Result<&StepKernels, &str> {
        let built = self.0.c_steps.get_or_init(|| {
            let Some(cc) = jit::CCompiler::from_env() else {
                return Err("C kernels switched off (CHAOSCOPE_CC=none)".into());
            };
            let spec = StepSpec {
                n: self.0.definition.n,
                gradient: self.0.gradient.clone(),
                hessian_vector: Some(self.0.hessian_vector.clone()),
            };
            jit::compile_steps_c(&self.0.graph, &spec, &cc).map_err(|e| e.to_string())
        });
        built.as_ref().map_err(String::as_str)
    }

    fn describe(&self, id: NodeId, q: &[f64], what: &str) -> String {
        let mut value = [0.0];
        eval::Evaluator::new().eval(&self.0.graph, &[q], &[id], &mut value);
        let op = self.0.graph.operation_name(id);
        match self.0.origins.get(&id) {
            Some(span) => {
                let at = chaoscope_expr::ExprError::new(&self.0.definition.potential, *span, "");
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

impl Model for ExpressionModel {
    fn name(&self) -> &str {
        "potential"
    }

    fn dof(&self) -> usize {
        self.0.definition.n
    }

    #[inline]
    fn potential(&self, q: &[f64]) -> f64 {
        let mut v = [0.0];
        self.0.compiled.call(POTENTIAL, &[q], &mut v);
        v[0]
    }

    #[inline]
    fn gradient(&self, q: &[f64], out: &mut [f64]) {
        let n = self.0.definition.n;
        assert!(q.len() == n && out.len() == n, "gradient of {n} sites");
        let args = [q.as_ptr()];
        // SAFETY: the function reads at most N entries of `q` (checked in `new`) and writes N
        // outputs; both slices have N entries; `out` is a `&mut`, so it overlaps nothing; the
        // code lives as long as `self.0.compiled`.
        unsafe { (self.0.gradient_fn)(args.as_ptr(), out.as_mut_ptr()) }
    }

    #[inline]
    fn hessian_vector(&self, q: &[f64], v: &[f64], out: &mut [f64]) -> bool {
        if !self.0.c2 {
            return false;
        }
        let n = self.0.definition.n;
        assert!(
            q.len() == n && v.len() == n && out.len() == n,
            "Hessian-vector product of {n} sites"
        );
        let args = [q.as_ptr(), v.as_ptr()];
        // SAFETY: as in `gradient`, for the two arguments `q` and `v`.
        unsafe { (self.0.hessian_vector_fn)(args.as_ptr(), out.as_mut_ptr()) }
        true
    }

    fn has_hessian(&self) -> bool {
        self.0.c2
    }

    fn no_hessian_reason(&self) -> Option<String> {
        self.0
            .smoothness
            .require(2, "the variational method (vm)")
            .err()
    }

    fn inverse_masses(&self) -> Option<&[f64]> {
        self.0.definition.inverse_masses.as_deref()
    }

    fn diagnose_non_finite(&self, q: &[f64]) -> Option<String> {
        let g = &self.0.graph;
        if let Some(id) = eval::first_non_finite(g, &[q], self.0.potential) {
            return Some(self.describe(id, q, "in the potential"));
        }
        for (i, &out) in self.0.gradient.iter().enumerate() {
            if let Some(id) = eval::first_non_finite(g, &[q], out) {
                return Some(self.describe(id, q, &format!("in dV/dq{}", i + 1)));
            }
        }
        None
    }
}
