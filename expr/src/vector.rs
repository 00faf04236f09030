//! A vector function `F: R^D -> R^D` written as `D` expressions over `x1..xD` (and `x[i]`):
//! the right-hand side `dx/dt = F(x)` of a flow (`rhs`) or the map `x -> F(x)` (`next`),
//! compiled once, with its derivatives.
//!
//! The `D` components are lowered into one graph (hash-consing shares what they have in common),
//! differentiated there, and compiled by Cranelift into three functions, each in scalar and lane
//! (structure-of-arrays) form:
//! - `F(x)`, all `D` components;
//! - the Jacobian-vector product `J(x) v` ([`crate::diff::jacobian_vector`]: the Jacobian's
//!   entries as coefficients that depend on `x` only, so in a lane call around one shared
//!   reference state they are formed once and only the products and sums run per lane); only for
//!   a function with continuous first derivatives (the tangent map of a system is wrong at every
//!   crossing of a kink), see [`VectorFunction::no_tangent_reason`];
//! - the divergence `tr J(x) = sum_i dF_i/dx_i` (summed left to right in `i`): a flow's phase-space
//!   contraction rate. Defined wherever `F` is differentiable (one-sided derivatives at a kink).
//!
//! Every compiled function performs exactly the operations of [`crate::eval`] on the same graph,
//! so the scalar calls, the lane calls and the reference evaluator agree bit for bit.
//!
//! Time: where the definition says so ([`VectorDefinition::time`]: a flow's `rhs`, and every
//! Hamiltonian), the name `t` is the time, argument array [`ARG_T`] of every compiled function
//! (shared by all lanes of a lane call: the batched integrators step their lanes together).
//! The `*_at` calls take it; the calls without `_at` evaluate at `t = 0`, the only value of a
//! function that does not read the time ([`VectorFunction::reads_time`]), whose arithmetic is
//! exactly that of the same function without the argument: one it never reads changes no
//! operation.
//!
//! Parameters given as [`ParamValue::Lane`] of [`ARG_PARAMS`] (a map's parameter axes) are
//! read by every function from the state, after its `D` coordinates: per lane in a lane call
//! over states, from the shared reference state in the Jacobian-vector product's. Derivatives
//! are taken with respect to the coordinates only. They are the last argument array, after the
//! time, and only there when `P > 0`: both can be read together (a parameter axis over a
//! non-autonomous flow), each with its own layout (the time shared by all lanes, the
//! parameters per lane).
//!
//! Components are numbered from 1, as the variables are: component `i` is `F_i`, written
//! `<key>[i]` in messages (`next[2]` is the map's second component, the new `x2`).

use std::collections::{BTreeMap, HashMap};
use std::sync::Arc;
use std::time::{Duration, Instant};

use crate::error::{ExprError, Span};
use crate::eval::{self, Evaluator};
use crate::graph::{Graph, NodeId, Tabulated};
use crate::jit::{self, Compiled, FunctionSpec, Layout, ScalarFnPtr};
use crate::lower::{self, Boundary, Family, ParamValue, Parts, Scope};
use crate::site_parts::SiteShares;
use crate::smooth::Smoothness;
use crate::taylor::{NativeBuild, TaylorTape};

/// Everything that defines a vector function. (A Hamiltonian's, from
/// [`VectorFunction::hamiltonian`], keeps its source, parameters and boundary for messages
/// only: a square lattice's shape is not among them, so it does not rebuild that function.)
#[derive(Debug, Clone)]
pub struct VectorDefinition {
    /// The config key the components come from (`"rhs"`, `"next"`), for messages.
    pub key: String,
    /// `F_1 .. F_D`; the dimension `D` is their number (and the value of `N` in them).
    pub components: Vec<String>,
    /// Parameters: a number, or an array of `D` entries (`k[i]`).
    pub params: BTreeMap<String, ParamValue>,
    /// What `x[i]` beyond `1..D` means in indexed references.
    pub boundary: Boundary,
    /// Tabulated functions by the name the expressions call them.
    pub tables: Vec<(String, Arc<dyn Tabulated>)>,
    /// Whether `t` is the time (a flow's `rhs`: non-autonomous systems); `false` for a map's
    /// `next`, where `t` is an ordinary name.
    pub time: bool,
}

/// Why a vector function could not be built.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum VectorError {
    /// A component's expression (1-based `component`), with line, column and caret.
    #[error("{key}[{component}]: {error}")]
    Component {
        key: String,
        component: usize,
        error: ExprError,
    },
    /// Anything else (no components, the compiler), one line.
    #[error("{0}")]
    Other(String),
}

/// Function indices in the compiled module.
const VALUE: usize = 0;
const TANGENT: usize = 1;
const DIVERGENCE: usize = 2;
const ENERGY: usize = 3;

/// Argument arrays: the state, the direction of `J v`, the time (one entry), and the lane
/// parameters.
const ARG_X: u8 = 0;
const ARG_V: u8 = 1;
pub const ARG_T: u8 = 2;
/// The argument of the parameters given per evaluation ([`ParamValue::Lane`] with this `arg`,
/// indices `0..P`): a map's parameter axes. Every function reads them after the state: a state
/// given to this function is `D` coordinates followed by the `P` parameter values (in lane
/// calls, `D` rows then `P` rows), the "extended state". With `P = 0` nothing changes (the
/// functions are compiled exactly as without this argument, which they then do not declare).
pub const ARG_PARAMS: u8 = 3;

/// Most components of a vector function (the straight-line code grows with `D`).
pub const MAX_DIM: usize = 100_000;

struct Inner {
    definition: VectorDefinition,
    graph: Graph,
    /// Each node's first creator: (0-based component, span in that component's source).
    origins: HashMap<NodeId, (usize, Span)>,
    values: Vec<NodeId>,
    tangent: Vec<NodeId>,
    divergence: NodeId,
    smoothness: Vec<Smoothness>,
    /// Continuous first derivatives in every component (the variational method applies).
    c1: bool,
    /// Why the variational method is refused (`None` when `c1`).
    tangent_refusal: Option<String>,
    /// A Hamiltonian vector field's `H` (see [`VectorFunction::hamiltonian`]).
    energy: Option<NodeId>,
    /// `H`'s parts ([`crate::lower::Lowered::parts`]) by site, and its degrees of freedom (the
    /// energy distribution, [`VectorFunction::site_energies`]).
    energy_parts: Option<(SiteShares, usize)>,
    /// Some expression reads the time `t`.
    reads_time: bool,
    compiled: Compiled,
    value_fn: ScalarFnPtr,
    tangent_fn: ScalarFnPtr,
    divergence_fn: ScalarFnPtr,
    energy_fn: Option<ScalarFnPtr>,
    /// `P`: parameters read from [`ARG_PARAMS`] after the `D` coordinates of every state.
    lane_params: usize,
    build_time: Duration,
}

/// A Hamiltonian `H(q, p)` written as one expression over `q1..qN`, `p1..pN` (and `q[i]`,
/// `p[i]`): the vector field `dq/dt = dH/dp`, `dp/dt = -dH/dq` on the state `(q1..qN,
/// p1..pN)`.
#[derive(Debug, Clone)]
pub struct HamiltonianDefinition {
    /// The config key `H` comes from (`"hamiltonian"`), for messages.
    pub key: String,
    /// Degrees of freedom (the value of `N` in the expression on a chain; on a square
    /// lattice `N` is the side and this its square).
    pub n: usize,
    pub source: String,
    /// Parameters: a number, or an array of one entry per degree of freedom.
    pub params: BTreeMap<String, ParamValue>,
    /// What `q[i]`, `p[i]` beyond `1..N` mean in lattice sums (along the rows on a square).
    pub boundary: Boundary,
    /// A chain of sites, or a square read as `q[i, j]`, `p[i, j]`.
    pub shape: crate::lower::Shape,
    pub tables: Vec<(String, Arc<dyn Tabulated>)>,
}

/// A compiled vector function. Cheap to clone (shared compiled code).
#[derive(Clone)]
pub struct VectorFunction(Arc<Inner>);

impl std::fmt::Debug for VectorFunction {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("VectorFunction")
            .field("key", &self.0.definition.key)
            .field("components", &self.0.definition.components)
            .field("nodes", &self.0.graph.len())
            .finish()
    }
}

impl VectorFunction {
    /// Parse every component, differentiate and compile.
    pub fn new(definition: VectorDefinition) -> Result<Self, VectorError> {
        let started = Instant::now();
        let d = definition.components.len();
        if d == 0 {
            return Err(VectorError::Other(format!(
                "{} needs at least one component",
                definition.key
            )));
        }
        if d > MAX_DIM {
            return Err(VectorError::Other(format!(
                "{} has {d} components, more than {MAX_DIM}",
                definition.key
            )));
        }
        let mut graph = Graph::new();
        let tables: Vec<(String, u32)> = definition
            .tables
            .iter()
            .map(|(name, t)| (name.clone(), graph.add_table(t.clone())))
            .collect();
        let families = [Family {
            name: "x".to_string(),
            len: d,
            arg: ARG_X,
            offset: 0,
        }];
        let scope = Scope {
            families: &families,
            params: &definition.params,
            tables: &tables,
            n: d,
            boundary: definition.boundary,
            shape: crate::lower::Shape::Chain,
            time: definition.time.then_some(ARG_T),
        };
        let mut values = Vec::with_capacity(d);
        let mut smoothness = Vec::with_capacity(d);
        let mut origins = HashMap::new();
        for (i, source) in definition.components.iter().enumerate() {
            let lowered = lower::lower(source, &scope, &mut graph).map_err(|error| {
                VectorError::Component {
                    key: definition.key.clone(),
                    component: i + 1,
                    error,
                }
            })?;
            values.push(lowered.root);
            smoothness.push(lowered.smoothness);
            for (id, span) in lowered.origins {
                origins.entry(id).or_insert((i, span));
            }
        }
        let key = definition.key.clone();
        let tangent_refusal = smoothness.iter().enumerate().find_map(|(i, s)| {
            let limit = s.limited_by.as_ref().filter(|l| l.order < 1)?;
            Some(format!(
                "the variational method (vm) needs continuous first derivatives, but '{}' at \
                 line {}, column {} of {key}[{}] {}; use mpm",
                limit.operation,
                limit.line,
                limit.column,
                i + 1,
                limit.reason
            ))
        });
        Self::finish(
            definition,
            graph,
            origins,
            values,
            smoothness,
            tangent_refusal,
            None,
            started,
        )
    }

    /// The vector field of a Hamiltonian, `F = (dH/dp, -dH/dq)` on the state `(q, p)`, its
    /// gradient taken symbolically (reverse mode over the graph) and then compiled like any
    /// vector function, with `H` itself as [`Self::energy`]. The variational method needs `F`
    /// continuously differentiable, so `H` with continuous second derivatives; otherwise it is
    /// refused naming the operation of `H` that lacks them.
    pub fn hamiltonian(h: HamiltonianDefinition) -> Result<Self, VectorError> {
        let started = Instant::now();
        let n = h.n;
        if n == 0 || 2 * n > MAX_DIM {
            return Err(VectorError::Other(format!(
                "{} needs between 1 and {} degrees of freedom, got {n}",
                h.key,
                MAX_DIM / 2
            )));
        }
        let mut graph = Graph::new();
        let tables: Vec<(String, u32)> = h
            .tables
            .iter()
            .map(|(name, t)| (name.clone(), graph.add_table(t.clone())))
            .collect();
        let families = [
            Family {
                name: "q".to_string(),
                len: n,
                arg: ARG_X,
                offset: 0,
            },
            Family {
                name: "p".to_string(),
                len: n,
                arg: ARG_X,
                offset: n,
            },
        ];
        let scope = Scope {
            families: &families,
            params: &h.params,
            tables: &tables,
            n: h.shape.n_of(n),
            boundary: h.boundary,
            shape: h.shape,
            time: Some(ARG_T),
        };
        let lowered = lower::lower(&h.source, &scope, &mut graph).map_err(|error| {
            VectorError::Component {
                key: h.key.clone(),
                component: 1,
                error,
            }
        })?;
        let root = lowered.root;
        let grad = crate::diff::gradient(&mut graph, root, ARG_X, 2 * n)
            .map_err(|e| VectorError::Other(e.to_string()))?;
        let mut values = Vec::with_capacity(2 * n);
        values.extend_from_slice(&grad[n..]);
        for &g in &grad[..n] {
            let minus = graph.neg(g);
            values.push(minus);
        }
        let tangent_refusal = lowered
            .smoothness
            .require(2, "the variational method (vm)")
            .err()
            .map(|m| format!("{m} (of {})", h.key));
        // Each component is one order less smooth than H; what limits H limits them all.
        let component = match &lowered.smoothness.limited_by {
            None => Smoothness::smooth(),
            Some(limit) => Smoothness {
                order: lowered.smoothness.order.saturating_sub(1),
                limited_by: Some(crate::smooth::Limit {
                    order: limit.order - 1,
                    ..limit.clone()
                }),
            },
        };
        let origins = lowered
            .origins
            .into_iter()
            .map(|(id, span)| (id, (0, span)))
            .collect();
        let definition = VectorDefinition {
            key: h.key,
            components: vec![h.source],
            params: h.params,
            boundary: h.boundary,
            tables: h.tables,
            time: true,
        };
        Self::finish(
            definition,
            graph,
            origins,
            values,
            vec![component; 2 * n],
            tangent_refusal,
            Some((root, lowered.parts, n)),
            started,
        )
    }

    /// Differentiate (`J v`, `tr J`) and compile: what every kind of vector function shares.
    #[allow(clippy::too_many_arguments)]
    fn finish(
        definition: VectorDefinition,
        mut graph: Graph,
        origins: HashMap<NodeId, (usize, Span)>,
        values: Vec<NodeId>,
        smoothness: Vec<Smoothness>,
        tangent_refusal: Option<String>,
        hamiltonian: Option<(NodeId, Parts, usize)>,
        started: Instant,
    ) -> Result<Self, VectorError> {
        let (energy, energy_parts) = match hamiltonian {
            Some((root, parts, n)) => (Some(root), Some((SiteShares::new(parts, ARG_X, n), n))),
            None => (None, None),
        };
        let d = values.len();
        let lane_params = definition
            .params
            .values()
            .filter_map(|v| match v {
                ParamValue::Lane { arg, index, .. } if *arg == ARG_PARAMS => {
                    Some(*index as usize + 1)
                }
                _ => None,
            })
            .max()
            .unwrap_or(0);
        let c1 = tangent_refusal.is_none();
        let other = |e: crate::diff::DiffError| VectorError::Other(e.to_string());
        // The tangent only where it means something (as the Hessian-vector product of a
        // potential that is not C^2 is not compiled): VM is refused for such a function.
        let tangent = if c1 {
            crate::diff::jacobian_vector(&mut graph, &values, ARG_X, ARG_V).map_err(other)?
        } else {
            vec![graph.constant(0.0); d]
        };
        let rows = crate::diff::jacobian(&mut graph, &values, ARG_X)
            .map_err(other)?
            .ok_or_else(|| {
                VectorError::Other(format!(
                    "{}: the Jacobian has more than {} nonzero entries (too densely coupled \
                     for its divergence)",
                    definition.key,
                    crate::diff::MAX_JACOBIAN_ENTRIES
                ))
            })?;
        let mut divergence: Option<NodeId> = None;
        for (i, row) in rows.iter().enumerate() {
            if let Some(&(_, dii)) = row.iter().find(|(j, _)| *j as usize == i) {
                divergence = Some(match divergence {
                    None => dii,
                    Some(acc) => graph.add2(acc, dii),
                });
            }
        }
        let divergence = divergence.unwrap_or_else(|| graph.constant(0.0));
        // Every function takes the time as argument ARG_T, one value shared by all lanes
        // (argument ARG_V of the functions other than `J v` is never read). The parameters come
        // with the state, after the time: one per lane where the state is one per lane, shared
        // where it is shared (the tangent's reference state).
        let with_params = |mut args: Vec<Layout>, layout: Layout| {
            if lane_params > 0 {
                args.push(layout);
            }
            args
        };
        let unary = with_params(
            vec![Layout::Lanes, Layout::Scalar, Layout::Scalar],
            Layout::Lanes,
        );
        let mut specs = vec![
            FunctionSpec {
                args: unary.clone(),
                outputs: values.clone(),
            },
            FunctionSpec {
                args: with_params(
                    vec![Layout::Scalar, Layout::Lanes, Layout::Scalar],
                    Layout::Scalar,
                ),
                outputs: tangent.clone(),
            },
            FunctionSpec {
                args: unary.clone(),
                outputs: vec![divergence],
            },
        ];
        if let Some(h) = energy {
            specs.push(FunctionSpec {
                args: unary,
                outputs: vec![h],
            });
        }

        let compiled = jit::compile(&graph, &specs)
            .map_err(|e| VectorError::Other(format!("compiling {}: {e}", definition.key)))?;
        let energy_fn = energy.map(|_| (ENERGY, 1));
        let reads_time = (0..specs.len()).any(|f| compiled.arg_len(f, ARG_T as usize) > 0);
        for (f, args) in [(VALUE, 1), (TANGENT, 2), (DIVERGENCE, 1)]
            .into_iter()
            .chain(energy_fn)
        {
            if compiled.arg_len(f, ARG_T as usize) > 1 {
                return Err(VectorError::Other(format!(
                    "compiled function {f} reads {} entries of the time",
                    compiled.arg_len(f, ARG_T as usize)
                )));
            }
            for a in 0..args {
                if compiled.arg_len(f, a) > d {
                    return Err(VectorError::Other(format!(
                        "compiled function {f} reads {} entries of argument {a}, more than D = {d}",
                        compiled.arg_len(f, a)
                    )));
                }
            }
            let p = ARG_PARAMS as usize;
            if lane_params > 0 && compiled.arg_len(f, p) > lane_params {
                return Err(VectorError::Other(format!(
                    "compiled function {f} reads {} parameters, more than P = {lane_params}",
                    compiled.arg_len(f, p)
                )));
            }
        }
        Ok(Self(Arc::new(Inner {
            value_fn: compiled.raw_scalar(VALUE),
            tangent_fn: compiled.raw_scalar(TANGENT),
            divergence_fn: compiled.raw_scalar(DIVERGENCE),
            energy_fn: energy.map(|_| compiled.raw_scalar(ENERGY)),
            energy,
            energy_parts,
            lane_params,
            reads_time,
            tangent_refusal,
            definition,
            graph,
            origins,
            values,
            tangent,
            divergence,
            smoothness,
            c1,
            compiled,
            build_time: started.elapsed(),
        })))
    }

    /// The dimension `D`.
    #[inline]
    pub fn dim(&self) -> usize {
        self.0.values.len()
    }

    /// `P`: the parameters every state carries after its `D` coordinates ([`ARG_PARAMS`]); 0
    /// unless parameters were given as [`ParamValue::Lane`].
    #[inline]
    pub fn lane_params(&self) -> usize {
        self.0.lane_params
    }

    /// `D + P`: the length of a state (a lane's rows) the functions read.
    #[inline]
    pub fn state_len(&self) -> usize {
        self.dim() + self.0.lane_params
    }

    /// A state's coordinates and its parameters, as the scalar functions' argument arrays.
    #[inline]
    fn split<'a>(&self, x: &'a [f64]) -> (&'a [f64], &'a [f64]) {
        x.split_at(self.dim())
    }

    /// The argument arrays of a lane call over `x` (`D + P` rows of `lanes`): the state, `middle`
    /// (the direction of `J v`; an unread empty array for the other functions), the time, and
    /// the parameters when there are any.
    /// (No allocation: these calls sit in the kernels' inner loops.)
    fn lane_args<'a>(
        &self,
        x: &'a [f64],
        middle: &'a [f64],
        time: &'a [f64],
        lanes: usize,
    ) -> ([&'a [f64]; 4], usize) {
        let (x, p) = x.split_at(self.dim() * lanes);
        let args: [&[f64]; 4] = [x, middle, time, p];
        let n = if self.0.lane_params > 0 {
            ARG_PARAMS as usize + 1
        } else {
            ARG_T as usize + 1
        };
        (args, n)
    }

    pub fn definition(&self) -> &VectorDefinition {
        &self.0.definition
    }

    /// Parse, differentiate and compile time.
    pub fn build_time(&self) -> Duration {
        self.0.build_time
    }

    /// Nodes of the graph (components, Jacobian-vector product, divergence).
    pub fn graph_nodes(&self) -> usize {
        self.0.graph.len()
    }

    /// The graph and its outputs `F`, `J v`, `tr J`: what the reference evaluator
    /// ([`crate::eval`]) computes the compiled functions' bits from.
    pub fn graph(&self) -> (&Graph, &[NodeId], &[NodeId], NodeId) {
        (
            &self.0.graph,
            &self.0.values,
            &self.0.tangent,
            self.0.divergence,
        )
    }

    /// The smoothness of each component (0-based).
    pub fn smoothness(&self) -> &[Smoothness] {
        &self.0.smoothness
    }

    /// Continuous first derivatives everywhere: [`Self::tangent`] is compiled.
    pub fn has_tangent(&self) -> bool {
        self.0.c1
    }

    /// Why the variational method cannot be used: the first component whose first derivatives
    /// are not continuous, naming the operation and its position, e.g. `the variational method
    /// (vm) needs continuous first derivatives, but 'abs' at line 1, column 5 of next[2] has a
    /// kink (continuous, first derivative jumps); use mpm`. `None` when it can.
    pub fn no_tangent_reason(&self) -> Option<String> {
        self.0.tangent_refusal.clone()
    }

    /// Whether some compiled function reads the time `t` (a non-autonomous system). When it
    /// does not, every `*_at` call gives the bits of the call at any other time.
    pub fn reads_time(&self) -> bool {
        self.0.reads_time
    }

    /// `H(x)` of a Hamiltonian vector field ([`Self::hamiltonian`]) at `t = 0`; `None` for
    /// others.
    #[inline]
    pub fn energy(&self, x: &[f64]) -> Option<f64> {
        self.energy_at(x, 0.0)
    }

    /// `H(x, t)` of a Hamiltonian vector field; `None` for others.
    ///
    /// # Panics
    /// If `x` does not have `D + P` entries.
    #[inline]
    pub fn energy_at(&self, x: &[f64], t: f64) -> Option<f64> {
        let f = self.0.energy_fn?;
        let n = self.state_len();
        assert!(x.len() == n, "energy of a state of {n}");
        let (x, p) = self.split(x);
        let time = [t];
        let args = [x.as_ptr(), std::ptr::null(), time.as_ptr(), p.as_ptr()];
        let mut out = [0.0];
        // SAFETY: as in `value_at`; one output.
        unsafe { f(args.as_ptr(), out.as_mut_ptr()) }
        Some(out[0])
    }

    /// The energy of each site of a Hamiltonian lattice at the state `x` (`N` values into
    /// `out`; site `l` is `q_l` and `p_l`), as the lattice literature defines the energy
    /// distribution: each term of the lattice sums `H` adds, times its coefficient, shared
    /// equally by the distinct sites it reads, and the rest of `H`, where it is not zero, to
    /// the one site it reads. They add up to `H` to rounding. An error saying why otherwise.
    pub fn site_energies(&self, x: &[f64], out: &mut [f64]) -> Result<(), String> {
        let Some((parts, n)) = &self.0.energy_parts else {
            return Err("only a Hamiltonian has site energies".to_string());
        };
        if x.len() != 2 * n || out.len() != *n {
            return Err(format!(
                "a state of {} entries and {n} sites expected",
                2 * n
            ));
        }
        if self.0.reads_time || self.0.lane_params > 0 {
            return Err(
                "H reads the time or parameters per evaluation, so its terms' values are not \
                 those of one system"
                    .to_string(),
            );
        }
        if parts.has_no_sums() {
            return Err(
                "H is not written as lattice sums added at its top level (sum(i = a..b, term) \
                 + ...), so which of its terms belongs to which site is not known"
                    .to_string(),
            );
        }
        parts.shares(&self.0.graph, &[x], out)
    }

    /// Whether this is the vector field of a Hamiltonian.
    pub fn is_hamiltonian(&self) -> bool {
        self.0.energy.is_some()
    }

    /// `out = F(x)` at `t = 0`.
    #[inline]
    pub fn value(&self, x: &[f64], out: &mut [f64]) {
        self.value_at(x, 0.0, out)
    }

    /// `out = F(x, t)` (`x`: the `D + P` entries of a state, `out`: `D`).
    ///
    /// # Panics
    /// If `x` does not have `D + P` entries or `out` `D`.
    #[inline]
    pub fn value_at(&self, x: &[f64], t: f64, out: &mut [f64]) {
        let (d, n) = (self.dim(), self.state_len());
        assert!(
            x.len() == n && out.len() == d,
            "{d} components of a state of {n}"
        );
        let (x, p) = self.split(x);
        let time = [t];
        let args = [x.as_ptr(), std::ptr::null(), time.as_ptr(), p.as_ptr()];
        // SAFETY: the function reads at most D entries of `x`, one of the time and P of `p`
        // (checked in `new`; a function without parameters does not declare the last
        // argument), never argument ARG_V (null), and writes D outputs; the slices have D, 1
        // and P entries; `out` is a `&mut`, so it overlaps nothing; the code lives as long as
        // `self.0.compiled`.
        unsafe { (self.0.value_fn)(args.as_ptr(), out.as_mut_ptr()) }
    }

    /// `out = J(x) v` at `t = 0`; see [`Self::tangent_at`].
    #[inline]
    pub fn tangent(&self, x: &[f64], v: &[f64], out: &mut [f64]) -> bool {
        self.tangent_at(x, 0.0, v, out)
    }

    /// `out = J(x, t) v` (the derivative in the coordinates of `x` at time `t`); `false` (and
    /// `out` untouched) when the function has no continuous first derivatives
    /// ([`Self::no_tangent_reason`]).
    ///
    /// # Panics
    /// If `x` does not have `D + P` entries, or `v` or `out` not `D`.
    #[inline]
    pub fn tangent_at(&self, x: &[f64], t: f64, v: &[f64], out: &mut [f64]) -> bool {
        if !self.0.c1 {
            return false;
        }
        let (d, n) = (self.dim(), self.state_len());
        assert!(
            x.len() == n && v.len() == d && out.len() == d,
            "Jacobian-vector product of {d} components"
        );
        let (x, p) = self.split(x);
        let time = [t];
        let args = [x.as_ptr(), v.as_ptr(), time.as_ptr(), p.as_ptr()];
        // SAFETY: as in `value_at`, for the arguments `x`, `v`, the time and the parameters.
        unsafe { (self.0.tangent_fn)(args.as_ptr(), out.as_mut_ptr()) }
        true
    }

    /// [`Self::tangent_at`] of each of the vectors in `v` (one after the other, `D` values
    /// each) into the same place of `out`, the bits of one call per vector; `false` (and `out`
    /// untouched) when the function has no continuous first derivatives.
    ///
    /// # Panics
    /// If `x` does not have `D + P` entries, or `v` and `out` not the same multiple of `D`.
    #[inline]
    pub fn tangents_at(&self, x: &[f64], t: f64, v: &[f64], out: &mut [f64]) -> bool {
        if !self.0.c1 {
            return false;
        }
        let (d, n) = (self.dim(), self.state_len());
        assert!(
            x.len() == n && v.len() == out.len() && d > 0 && v.len().is_multiple_of(d),
            "Jacobian-vector products of {d} components"
        );
        let (x, p) = self.split(x);
        let time = [t];
        let mut args = [x.as_ptr(), v.as_ptr(), time.as_ptr(), p.as_ptr()];
        for (v, out) in v.chunks_exact(d).zip(out.chunks_exact_mut(d)) {
            args[1] = v.as_ptr();
            // SAFETY: as in `tangent_at`: each chunk of `v` and `out` has D entries.
            unsafe { (self.0.tangent_fn)(args.as_ptr(), out.as_mut_ptr()) }
        }
        true
    }

    /// `tr J(x)` at `t = 0`.
    #[inline]
    pub fn divergence(&self, x: &[f64]) -> f64 {
        self.divergence_at(x, 0.0)
    }

    /// `tr J(x, t)`.
    ///
    /// # Panics
    /// If `x` does not have `D + P` entries.
    #[inline]
    pub fn divergence_at(&self, x: &[f64], t: f64) -> f64 {
        let n = self.state_len();
        assert!(x.len() == n, "divergence at a state of {n}");
        let (x, p) = self.split(x);
        let time = [t];
        let args = [x.as_ptr(), std::ptr::null(), time.as_ptr(), p.as_ptr()];
        let mut out = [0.0];
        // SAFETY: as in `value_at`; one output.
        unsafe { (self.0.divergence_fn)(args.as_ptr(), out.as_mut_ptr()) }
        out[0]
    }

    /// `F` at `t = 0` over lanes; see [`Self::value_lanes_at`].
    pub fn value_lanes(&self, x: &[f64], out: &mut [f64], lanes: usize) {
        self.value_lanes_at(x, 0.0, out, lanes)
    }

    /// `F(., t)` over `lanes` states in structure-of-arrays layout, all at the time `t`:
    /// `x[i * lanes + l]` is `x_i` of lane `l` (rows `D..D + P` its parameters),
    /// `out[i * lanes + l]` its `F_i`. Lane by lane the bits of [`Self::value_at`].
    ///
    /// # Panics
    /// If `x` does not have `(D + P) * lanes` entries or `out` `D * lanes`.
    pub fn value_lanes_at(&self, x: &[f64], t: f64, out: &mut [f64], lanes: usize) {
        let n = self.state_len();
        assert_eq!(x.len(), n * lanes, "{n} rows of {lanes} lanes");
        let time = [t];
        let (args, n) = self.lane_args(x, &[], &time, lanes);
        self.0.compiled.call_lanes(VALUE, &args[..n], out, lanes)
    }

    /// `J v` at `t = 0` over lanes; see [`Self::tangent_lanes_at`].
    pub fn tangent_lanes(&self, x: &[f64], v: &[f64], out: &mut [f64], lanes: usize) -> bool {
        self.tangent_lanes_at(x, 0.0, v, out, lanes)
    }

    /// `J(x, t) v` at one shared state `x` (the reference orbit, with its parameters) and time
    /// `t` for `lanes` directions in structure-of-arrays layout (`v[i * lanes + l]`); `false`
    /// as [`Self::tangent_at`].
    ///
    /// # Panics
    /// If `x` does not have `D + P` entries, or `v` or `out` not `D * lanes`.
    pub fn tangent_lanes_at(
        &self,
        x: &[f64],
        t: f64,
        v: &[f64],
        out: &mut [f64],
        lanes: usize,
    ) -> bool {
        if !self.0.c1 {
            return false;
        }
        let (d, n) = (self.dim(), self.state_len());
        assert!(
            x.len() == n && v.len() == d * lanes,
            "a state of {n} and {d} rows of {lanes} lanes"
        );
        let time = [t];
        let (args, n) = self.lane_args(x, v, &time, 1);
        self.0.compiled.call_lanes(TANGENT, &args[..n], out, lanes);
        true
    }

    /// The divergence at `t = 0` over lanes; see [`Self::divergence_lanes_at`].
    pub fn divergence_lanes(&self, x: &[f64], out: &mut [f64], lanes: usize) {
        self.divergence_lanes_at(x, 0.0, out, lanes)
    }

    /// The divergence at time `t` over `lanes` states in structure-of-arrays layout (`D + P`
    /// rows); `out` has `lanes` entries.
    pub fn divergence_lanes_at(&self, x: &[f64], t: f64, out: &mut [f64], lanes: usize) {
        let n = self.state_len();
        assert_eq!(x.len(), n * lanes, "{n} rows of {lanes} lanes");
        let time = [t];
        let (args, n) = self.lane_args(x, &[], &time, lanes);
        self.0
            .compiled
            .call_lanes(DIVERGENCE, &args[..n], out, lanes)
    }

    /// The Taylor tape of `dx/dt = F(x, t)` with `vectors` tangent vectors to `order`
    /// ([`crate::taylor`]), or why there is none: the first operation that is not analytic on
    /// a quantity that moves, e.g. `'abs' at line 1, column 5 of rhs[2] is not analytic
    /// (Taylor's method needs a right-hand side with a convergent series: use dop853)`.
    pub fn taylor_tape(&self, vectors: usize, order: usize) -> Result<TaylorTape, String> {
        let inner = &self.0;
        TaylorTape::build(&inner.graph, &inner.values, &inner.tangent, vectors, order).map_err(
            |e| {
                let key = &inner.definition.key;
                let at = match inner.origins.get(&e.node) {
                    Some(&(c, span)) => {
                        let at = ExprError::new(&inner.definition.components[c], span, "");
                        format!(
                            " at line {}, column {} of {key}[{}]",
                            at.line,
                            at.column,
                            c + 1
                        )
                    }
                    None => format!(" in {key}"),
                };
                format!(
                    "{}{at} is not analytic (Taylor's method needs a right-hand side whose \
                 series converge along the orbit: no kinks, jumps, branches or tables on a \
                 quantity that moves); use dop853",
                    e.operation
                )
            },
        )
    }

    /// [`Self::taylor_tape`], its pass over the orders compiled to C in the background where a
    /// C compiler is configured (`CHAOSCOPE_CC`, [`crate::jit::CCompiler::from_env`]; cached
    /// like the step kernels) and run compiled from the call after the build: the same bits
    /// either way, so the switch is invisible, and a compiler that is missing, fails or hangs
    /// until its deadline costs speed, never a stalled run or a different orbit. Keep the
    /// build guard as long as the tape steps: dropping it ends the build ([`NativeBuild`]).
    pub fn taylor_tape_compiled(
        &self,
        vectors: usize,
        order: usize,
    ) -> Result<(Arc<TaylorTape>, Option<NativeBuild>), String> {
        let tape = Arc::new(self.taylor_tape(vectors, order)?);
        let build =
            crate::jit::CCompiler::from_env().map(|cc| tape.compile_native_in_background(cc));
        Ok((tape, build))
    }

    /// What made `F(x)` non-finite: the first operation, in component order and evaluation
    /// order, whose value is NaN or infinite while its operands are finite, e.g. `'log' at line
    /// 1, column 3 of next[2] gave NaN (x = [0.5, -1])`. `None` when `F(x)` is finite. Off the
    /// hot path: called after a run met a non-finite state.
    pub fn diagnose_non_finite(&self, x: &[f64]) -> Option<String> {
        self.diagnose_non_finite_at(x, 0.0)
    }

    /// [`Self::diagnose_non_finite`] at time `t`.
    pub fn diagnose_non_finite_at(&self, x: &[f64], t: f64) -> Option<String> {
        let g = &self.0.graph;
        let key = &self.0.definition.key;
        let state = format!("{x:?}");
        let (coordinates, params) = self.split(x);
        let time = [t];
        let args: [&[f64]; 4] = [coordinates, &[], &time, params];
        let args = if self.0.lane_params > 0 {
            &args[..]
        } else {
            &args[..ARG_PARAMS as usize]
        };
        for (i, &root) in self.0.values.iter().enumerate() {
            let Some(id) = eval::first_non_finite(g, args, root) else {
                continue;
            };
            let mut value = [0.0];
            Evaluator::new().eval(g, args, &[id], &mut value);
            let op = g.operation_name(id);
            return Some(match self.0.origins.get(&id) {
                Some(&(c, span)) => {
                    let at = ExprError::new(&self.0.definition.components[c], span, "");
                    format!(
                        "{op} at line {}, column {} of {key}[{}] gave {} in {key}[{}] (x = {state})",
                        at.line,
                        at.column,
                        c + 1,
                        value[0],
                        i + 1
                    )
                }
                None => format!("{op} gave {} in {key}[{}] (x = {state})", value[0], i + 1),
            });
        }
        None
    }
}
