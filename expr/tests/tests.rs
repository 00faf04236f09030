//! The expression language's tests in one binary (one link; each file a module): the compiled
//! functions and step kernels against the reference evaluator.

mod jit;
mod steps;
mod vector;
