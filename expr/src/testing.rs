//! Helpers the unit tests of several stages share.

use crate::eval::Evaluator;
use crate::graph::{Graph, NodeId};

/// Deterministic pseudo-random numbers in [0, 1) (splitmix64).
pub(crate) fn uniform01(n: usize, seed: u64) -> Vec<f64> {
    let mut s = seed;
    (0..n)
        .map(|_| {
            s = s.wrapping_add(0x9E37_79B9_7F4A_7C15);
            let mut z = s;
            z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
            z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
            z ^= z >> 31;
            (z >> 11) as f64 / (1u64 << 53) as f64
        })
        .collect()
}

/// The values of `outputs` of `g` with argument arrays `args`, by the reference evaluator.
pub(crate) fn eval1(g: &Graph, args: &[&[f64]], outputs: &[NodeId]) -> Vec<f64> {
    let mut r = vec![0.0; outputs.len()];
    Evaluator::new().eval(g, args, outputs, &mut r);
    r
}
