//! chaoscope's expression language: the one place where user-written systems become numerics.
//!
//! Pipeline (one file per stage):
//! - `lexer` / `parser`: source text to an AST with source spans (`ast`), errors with line,
//!   column and a caret (`error`);
//! - `lower`: AST plus parameters, the lattice size and boundary condition to a [`Graph`]
//!   (hash-consed expression DAG; lattice sums expanded, or kept as loops over one term,
//!   parameters folded to constants);
//! - `lattice`: lattice sums as loops (a term, its slots and index range), the gradient and
//!   Hessian-vector product of a potential made of them, and their order of operations;
//! - `smooth`: how many continuous derivatives each expression has, and which operation at
//!   which position limits it (the variational method needs two);
//! - `diff`: symbolic gradient (reverse mode over the DAG) and Hessian-vector product (forward
//!   mode over the gradient), as new nodes of the same graph;
//! - `eval`: a reference evaluator of the graph (tests, diagnosis of a non-finite value);
//! - `jit`: native code for the graph's outputs (Cranelift), scalar and over SoA lanes,
//!   bit-identical to `eval`;
//! - `table`: tabulated functions (CSV samples, cubic spline with its derivatives);
//! - `scalar`: a scalar function `S(x)` of a state (a Poincare section's surface `S = 0`),
//!   compiled with its gradient;
//! - `vector`: a vector function `F: R^D -> R^D` (a flow's right-hand side, a map) from `D`
//!   expressions, compiled with its Jacobian-vector product and divergence;
//! - `potential`: a separable Hamiltonian's potential `V(q)` compiled with its gradient,
//!   Hessian-vector product and whole splitting steps over lanes (Cranelift at once, C on a
//!   background thread).
//!
//! I/O, in three places only: `table` reads the CSV file a config names; `jit::c` runs
//! the system C compiler and reads and writes its kernel cache (`CHAOSCOPE_KERNEL_CACHE`, else
//! the user's cache directory); `potential` says once on stderr why the C kernels could not be
//! built (`potential/kernel_switch.rs`).

pub(crate) mod ast;
pub mod diff;
pub(crate) mod error;
pub(crate) mod eval;
pub mod graph;
pub mod jit;
pub mod lattice;
mod lexer;
pub mod lower;
mod ops;
pub(crate) mod parser;
pub mod potential;
pub(crate) mod scalar;
mod site_parts;
pub(crate) mod smooth;
pub mod table;
pub mod taylor;
#[cfg(test)]
mod testing;
pub mod vector;

pub use diff::{DiffError, directional, gradient, jacobian, jacobian_vector};
pub use error::{ExprError, Span};
pub use eval::{Evaluator, first_non_finite};
pub use graph::{Binary, Cmp, Graph, Node, NodeId, Unary};
pub use jit::{Compiled, FunctionSpec, JitError, Layout};
pub use lower::{Boundary, Family, Lowered, ParamValue, Scope, Shape, lower, lower_with_loops};
pub use parser::parse;
pub use scalar::{ScalarDefinition, ScalarError, ScalarFunction};
pub use smooth::{Limit, Smoothness};
pub use table::{
    ErrorBound, Spline, SplineEnds, TableData, TableError, interpolation_error_bound, parse_csv,
    read_csv,
};
pub use vector::{VectorDefinition, VectorError, VectorFunction};
