//! chaoscope's expression language: the one place where user-written systems become numerics.
//!
//! Pipeline (one file per stage):
//! - `lexer` / `parser`: source text to an AST with source spans (`ast`), errors with line,
//!   column and a caret (`error`);
//! - `lower`: AST plus parameters, the lattice size and boundary condition to a [`Graph`]
//!   (hash-consed expression DAG; lattice sums expanded, parameters folded to constants);
//! - `smooth`: how many continuous derivatives each expression has, and which operation at
//!   which position limits it (the variational method needs two);
//! - `diff`: symbolic gradient (reverse mode over the DAG) and Hessian-vector product (forward
//!   mode over the gradient), as new nodes of the same graph;
//! - `eval`: a reference evaluator of the graph (tests, diagnosis of a non-finite value);
//! - `jit`: native code for the graph's outputs (Cranelift), scalar and over SoA lanes,
//!   bit-identical to `eval`;
//! - `table`: tabulated functions (CSV samples, cubic spline with its derivatives).
//!
//! No I/O except `table`'s reading of the CSV file a config names.

pub mod graph;
pub mod jit;

pub use graph::{Binary, Cmp, Graph, Node, NodeId, Unary};
pub use jit::{Compiled, FunctionSpec, JitError, Layout};
