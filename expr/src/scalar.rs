//! A scalar function `S(x)` of a system's state written as one expression over the state's
//! coordinates (`x1..xD`, or `q1..qN`, `p1..pN` for a Hamiltonian), compiled with its
//! gradient: the surface `S(x) = 0` of a Poincare section, whose crossings are located by
//! Newton's method on `dS/dt = grad S . f`.
//!
//! The gradient is the symbolic one ([`crate::diff::gradient`], reverse accumulation over the
//! graph); both are compiled by Cranelift and compute exactly what [`crate::eval`] computes from
//! the same graph.

use std::collections::BTreeMap;

use crate::error::ExprError;
use crate::eval::{self, Evaluator};
use crate::graph::{Graph, Node, NodeId};
use crate::jit::{self, Compiled, FunctionSpec, Layout};
use crate::lower::{self, Boundary, Family, ParamValue, Scope};

/// Everything that defines a scalar function of a state.
#[derive(Debug, Clone)]
pub struct ScalarDefinition {
    /// Where the expression comes from (`"--surface"`), for messages.
    pub key: String,
    pub source: String,
    /// The state's coordinates as families of names laid out one after the other: `[("x",
    /// D)]` for a flow, `[("q", N), ("p", N)]` for a Hamiltonian.
    pub families: Vec<(String, usize)>,
    /// The value of `N` in the expression (the dimension of a flow, the degrees of freedom of a
    /// Hamiltonian), and the length of an array parameter.
    pub n: usize,
    /// Parameters: a number, or an array of `n` entries.
    pub params: BTreeMap<String, ParamValue>,
    /// What indexed references beyond `1..n` mean in lattice sums (along the rows of a
    /// square).
    pub boundary: Boundary,
    /// A chain, or a square of `n x n` sites read as `q[i, j]`.
    pub shape: crate::lower::Shape,
}

/// Why a scalar function could not be built.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ScalarError {
    /// The expression, with line, column and caret (the first line self-contained).
    #[error("{key}: {error}")]
    Expression { key: String, error: ExprError },
    /// Anything else, one line.
    #[error("{0}")]
    Other(String),
}

impl ScalarError {
    /// The message in one line (an expression error without its source line and caret).
    pub fn one_line(&self) -> String {
        match self {
            ScalarError::Expression { key, error } => format!("{key}: {}", error.one_line()),
            ScalarError::Other(m) => m.clone(),
        }
    }
}

/// Function indices in the compiled module.
const VALUE: usize = 0;
const GRADIENT: usize = 1;
/// The state's argument array.
const ARG_X: u8 = 0;

/// A compiled `S(x)` with its gradient.
pub struct ScalarFunction {
    definition: ScalarDefinition,
    graph: Graph,
    root: NodeId,
    /// The 0-based coordinates `S` reads, in increasing order.
    reads: Vec<usize>,
    dim: usize,
    compiled: Compiled,
}

impl std::fmt::Debug for ScalarFunction {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ScalarFunction")
            .field("key", &self.definition.key)
            .field("source", &self.definition.source)
            .field("nodes", &self.graph.len())
            .finish()
    }
}

impl ScalarFunction {
    /// Parse, differentiate and compile.
    pub fn new(definition: ScalarDefinition) -> Result<Self, ScalarError> {
        let mut families = Vec::with_capacity(definition.families.len());
        let mut dim = 0usize;
        for (name, len) in &definition.families {
            families.push(Family {
                name: name.clone(),
                len: *len,
                arg: ARG_X,
                offset: dim,
            });
            dim += len;
        }
        if dim == 0 {
            return Err(ScalarError::Other(format!(
                "{}: the state has no coordinates",
                definition.key
            )));
        }
        let mut graph = Graph::new();
        let scope = Scope {
            families: &families,
            params: &definition.params,
            tables: &[],
            n: definition.n,
            boundary: definition.boundary,
            shape: definition.shape,
            time: None,
        };
        let lowered = lower::lower(&definition.source, &scope, &mut graph).map_err(|error| {
            ScalarError::Expression {
                key: definition.key.clone(),
                error,
            }
        })?;
        let root = lowered.root;
        let gradient = crate::diff::gradient(&mut graph, root, ARG_X, dim)
            .map_err(|e| ScalarError::Other(format!("{}: {e}", definition.key)))?;
        let reads = inputs_read(&graph, root, dim);
        let specs = [
            FunctionSpec {
                args: vec![Layout::Lanes],
                outputs: vec![root],
            },
            FunctionSpec {
                args: vec![Layout::Lanes],
                outputs: gradient,
            },
        ];
        let compiled = jit::compile(&graph, &specs)
            .map_err(|e| ScalarError::Other(format!("compiling {}: {e}", definition.key)))?;
        for f in [VALUE, GRADIENT] {
            if compiled.arg_len(f, 0) > dim {
                return Err(ScalarError::Other(format!(
                    "{}: reads {} coordinates, more than the state's {dim}",
                    definition.key,
                    compiled.arg_len(f, 0)
                )));
            }
        }
        Ok(Self {
            definition,
            graph,
            root,
            reads,
            dim,
            compiled,
        })
    }

    /// The length of the state.
    pub fn dim(&self) -> usize {
        self.dim
    }

    pub fn definition(&self) -> &ScalarDefinition {
        &self.definition
    }

    /// The 0-based coordinates the expression reads, in increasing order (empty for a
    /// constant).
    pub fn reads(&self) -> &[usize] {
        &self.reads
    }

    /// `S(x)`.
    ///
    /// # Panics
    /// If `x` does not have [`Self::dim`] entries.
    pub fn value(&self, x: &[f64]) -> f64 {
        assert_eq!(x.len(), self.dim, "a state of {} coordinates", self.dim);
        let mut out = [0.0];
        self.compiled.call(VALUE, &[x], &mut out);
        out[0]
    }

    /// `out = grad S(x)`.
    ///
    /// # Panics
    /// If `x` or `out` does not have [`Self::dim`] entries.
    pub fn gradient(&self, x: &[f64], out: &mut [f64]) {
        assert_eq!(x.len(), self.dim, "a state of {} coordinates", self.dim);
        self.compiled.call(GRADIENT, &[x], out);
    }

    /// What made `S(x)` non-finite: the first operation whose value is NaN or infinite while
    /// its operands are finite, with its position, e.g. `'log' at line 1, column 1 of
    /// --surface gave NaN`. `None` when `S(x)` is finite.
    pub fn diagnose_non_finite(&self, x: &[f64]) -> Option<String> {
        let g = &self.graph;
        let id = eval::first_non_finite(g, &[x], self.root)?;
        let mut value = [0.0];
        Evaluator::new().eval(g, &[x], &[id], &mut value);
        Some(format!(
            "{} of {} gave {} (x = {x:?})",
            g.operation_name(id),
            self.definition.key,
            value[0]
        ))
    }
}

/// The indices below `dim` of the state entries the node `root` depends on.
fn inputs_read(g: &Graph, root: NodeId, dim: usize) -> Vec<usize> {
    let mut seen = vec![false; root as usize + 1];
    let mut read = vec![false; dim];
    let mut stack = vec![root];
    seen[root as usize] = true;
    while let Some(id) = stack.pop() {
        let node = g.node(id);
        if let Node::Input { arg: ARG_X, index } = *node
            && (index as usize) < dim
        {
            read[index as usize] = true;
        }
        for o in node.operands() {
            if !seen[o as usize] {
                seen[o as usize] = true;
                stack.push(o);
            }
        }
    }
    (0..dim).filter(|&i| read[i]).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn flow(source: &str, d: usize) -> Result<ScalarFunction, ScalarError> {
        let mut params = BTreeMap::new();
        params.insert("c".to_string(), ParamValue::Scalar(27.0));
        ScalarFunction::new(ScalarDefinition {
            key: "--surface".into(),
            source: source.into(),
            families: vec![("x".into(), d)],
            n: d,
            params,
            boundary: Boundary::Fixed,
            shape: crate::lower::Shape::Chain,
        })
    }

    #[test]
    fn value_gradient_and_the_coordinates_read() {
        let s = flow("x3 - c + x1 * x1", 3).unwrap();
        let x = [2.0, 5.0, 30.0];
        assert_eq!(s.value(&x), 30.0 - 27.0 + 4.0);
        let mut g = [0.0; 3];
        s.gradient(&x, &mut g);
        assert_eq!(g, [4.0, 0.0, 1.0]);
        assert_eq!(s.reads(), &[0, 2]);
        assert_eq!(flow("x2", 3).unwrap().reads(), &[1]);
        assert!(flow("1", 3).unwrap().reads().is_empty());
    }

    #[test]
    fn hamiltonian_names_lay_q_before_p() {
        let s = ScalarFunction::new(ScalarDefinition {
            key: "--surface".into(),
            source: "q2 + 10 * p1".into(),
            families: vec![("q".into(), 2), ("p".into(), 2)],
            n: 2,
            params: BTreeMap::new(),
            boundary: Boundary::Fixed,
            shape: crate::lower::Shape::Chain,
        })
        .unwrap();
        assert_eq!(s.value(&[0.0, 1.0, 2.0, 3.0]), 21.0);
        assert_eq!(s.reads(), &[1, 2]);
    }

    #[test]
    fn errors_name_the_key_and_position_in_one_line() {
        let e = flow("x4 - 1", 3).unwrap_err().one_line();
        assert!(
            e.starts_with("--surface: line 1, column 1: variable 'x4' does not exist"),
            "{e}"
        );
        assert!(!e.contains('\n'), "{e}");
        let e = flow("x1 +", 3).unwrap_err().one_line();
        assert!(e.starts_with("--surface: line 1, column"), "{e}");
        let e = flow("sinn(x1)", 3).unwrap_err().one_line();
        assert!(e.contains("unknown function 'sinn'"), "{e}");
    }

    #[test]
    fn a_non_finite_value_is_diagnosed() {
        let s = flow("log(x1)", 1).unwrap();
        assert!(s.value(&[-1.0]).is_nan());
        let why = s.diagnose_non_finite(&[-1.0]).unwrap();
        assert!(why.contains("log") && why.contains("--surface"), "{why}");
        assert_eq!(s.diagnose_non_finite(&[1.0]), None);
    }
}
