//! Properties of the chaos indicators (`indicators.rs`) over random vector sets (proptest).
//!
//! Tolerances are argued from rounding, with `eps = f64::EPSILON` and the vectors of dimension
//! `dim` normalized to unit columns `U` (`dim x j`, `j <= k <= dim <= 8`):
//! - normalizing a column costs a relative error of about `(dim + 2) eps` (the sum of squares,
//!   the square root and the division);
//! - the singular values come from a backward-stable SVD: each is exact for a matrix within
//!   `c eps ||U||_2` of `U`, so each is off by at most `c eps sqrt(j)` absolutely (Weyl), with
//!   `c` a small multiple of `dim` for Householder bidiagonalization;
//! - GALI_j is their product, every factor at most `sqrt(j)` and the product of any `j - 1` of
//!   them at most `sqrt(e)` (AM-GM with `sum sigma_i^2 = j`), so GALI_j moves by at most
//!   `j sqrt(e) c eps sqrt(j)`.
//!
//! With `c = 4 dim` this gives the absolute tolerance [`gali_tol`], `8 j^1.5 dim eps` (below
//! 1e-12 for every size here). `worst_errors_against_their_tolerances` prints how much of each
//! tolerance the worst of 20000 random sets uses.

use chaoscope_dynamics::indicators::{SIGMA_FLOOR, gali_log10, sali};
use nalgebra::DMatrix;
use proptest::prelude::*;

const EPS: f64 = f64::EPSILON;

/// Absolute tolerance on a GALI_j of unit vectors of dimension `dim` (module doc).
fn gali_tol(j: usize, dim: usize) -> f64 {
    8.0 * (j as f64).powf(1.5) * dim as f64 * EPS
}

/// GALI_2..=k of the vectors (column-major, `dim` values each), as values rather than logs.
fn gali(vectors: &[f64], dim: usize) -> Vec<f64> {
    gali_log10(vectors, dim)
        .into_iter()
        .map(|g| 10f64.powf(g))
        .collect()
}

/// `k` vectors of dimension `dim` with entries in [-1, 1], none shorter than 1e-3 (a zero
/// vector has no direction; the floor tests below build degenerate sets on purpose).
fn vector_set() -> impl Strategy<Value = (usize, Vec<f64>)> {
    (2usize..=8)
        .prop_flat_map(|dim| (Just(dim), 2usize..=dim))
        .prop_flat_map(|(dim, k)| {
            (
                Just(dim),
                proptest::collection::vec(
                    proptest::collection::vec(-1.0f64..1.0, dim)
                        .prop_filter("a direction", |v| norm(v) > 1e-3),
                    k,
                ),
            )
        })
        .prop_map(|(dim, vs)| (dim, vs.concat()))
}

fn norm(v: &[f64]) -> f64 {
    v.iter().map(|x| x * x).sum::<f64>().sqrt()
}

/// Orthonormal columns: the Q of a QR factorization of the given vectors.
fn orthonormalized(vectors: &[f64], dim: usize) -> Vec<f64> {
    let k = vectors.len() / dim;
    let q = DMatrix::from_column_slice(dim, k, vectors).qr().q();
    q.columns(0, k).iter().copied().collect()
}

proptest! {
    #![proptest_config(ProptestConfig {
        cases: 2000,
        failure_persistence: None,
        ..ProptestConfig::default()
    })]

    /// 0 < eps^j <= GALI_j <= 1 (to rounding), never NaN or infinite.
    #[test]
    fn gali_is_in_the_unit_interval((dim, v) in vector_set()) {
        for (i, g) in gali(&v, dim).into_iter().enumerate() {
            let j = i + 2;
            prop_assert!(g.is_finite());
            prop_assert!(g >= SIGMA_FLOOR.powi(j as i32) * (1.0 - 1e-12), "GALI_{} = {:e}", j, g);
            prop_assert!(g <= 1.0 + gali_tol(j, dim), "GALI_{} = {:e}", j, g);
        }
    }

    /// Scaling a vector by a power of two changes no bit; by any positive factor, GALI moves
    /// within rounding (the normalization's relative error is all that changes).
    #[test]
    fn gali_is_invariant_under_positive_scaling(
        (dim, v) in vector_set(),
        exponents in proptest::collection::vec(-40i32..40, 8),
        factors in proptest::collection::vec(1e-6f64..1e6, 8),
    ) {
        let k = v.len() / dim;
        let want = gali(&v, dim);
        let by_two: Vec<f64> = v
            .chunks(dim)
            .zip(&exponents)
            .flat_map(|(c, &e)| c.iter().map(move |x| x * 2f64.powi(e)))
            .collect();
        prop_assert_eq!(
            gali_log10(&by_two, dim).iter().map(|g| g.to_bits()).collect::<Vec<_>>(),
            gali_log10(&v, dim).iter().map(|g| g.to_bits()).collect::<Vec<_>>()
        );
        let scaled: Vec<f64> = v
            .chunks(dim)
            .zip(&factors)
            .flat_map(|(c, &f)| c.iter().map(move |x| x * f))
            .collect();
        for (i, (a, b)) in gali(&scaled, dim).iter().zip(&want).enumerate() {
            prop_assert!((a - b).abs() <= gali_tol(i + 2, dim), "GALI_{}: {:e} vs {:e} (k = {})", i + 2, a, b, k);
        }
        let s = sali(&scaled, dim).unwrap();
        let s0 = sali(&v, dim).unwrap();
        prop_assert!((s - s0).abs() <= 4.0 * (dim as f64 + 2.0) * EPS, "SALI {:e} vs {:e}", s, s0);
    }

    /// GALI_k (all k vectors) is the volume of the set: the order of the vectors does not
    /// matter. (GALI_j for j < k is of the first j vectors, so only GALI_k is a set function.)
    #[test]
    fn gali_k_is_invariant_under_permutation((dim, v) in vector_set(), seed in any::<u64>()) {
        let k = v.len() / dim;
        let mut order: Vec<usize> = (0..k).collect();
        // Fisher-Yates with a xorshift stream.
        let mut s = seed | 1;
        for i in (1..k).rev() {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            order.swap(i, (s % (i as u64 + 1)) as usize);
        }
        let permuted: Vec<f64> = order.iter().flat_map(|&i| v[i * dim..(i + 1) * dim].to_vec()).collect();
        let a = *gali(&v, dim).last().unwrap();
        let b = *gali(&permuted, dim).last().unwrap();
        prop_assert!((a - b).abs() <= gali_tol(k, dim), "GALI_{}: {:e} vs {:e} ({:?})", k, a, b, order);
    }

    /// Orthonormal vectors span a unit volume: every GALI_j is 1; orthogonal vectors of any
    /// lengths too (they are normalized first).
    #[test]
    fn gali_of_orthonormal_vectors_is_one(
        (dim, v) in vector_set(),
        factors in proptest::collection::vec(1e-3f64..1e3, 8),
    ) {
        let q = orthonormalized(&v, dim);
        let orthogonal: Vec<f64> = q
            .chunks(dim)
            .zip(&factors)
            .flat_map(|(c, &f)| c.iter().map(move |x| x * f))
            .collect();
        for set in [&q, &orthogonal] {
            for (i, g) in gali(set, dim).into_iter().enumerate() {
                prop_assert!((g - 1.0).abs() <= gali_tol(i + 2, dim), "GALI_{} = {:e}", i + 2, g);
            }
        }
    }

    /// A vector that is a combination of the previous ones makes the volume vanish: its factor
    /// `|R_kk|` (the smallest singular value, to rounding) is then at most a few eps (rounding
    /// of the combination and the factorization), below which it is reported as `SIGMA_FLOOR`.
    /// So GALI_k is at least `eps^k` (never 0, never -inf in log10) and at most `sqrt(e) c eps`
    /// with the other factors bounded as in the module doc. A vector repeated exactly (up to a
    /// power of two) has bit-identical unit columns: `R_11 = 1` and `R_22` is what is left of
    /// the second after removing its projection on the first, 0 to a few eps (the rounding of
    /// `u.u` and of `u - (u.u) u`), so GALI_2 lies between eps and `4 dim sqrt(2) eps`.
    #[test]
    fn gali_of_dependent_vectors_is_floored(
        (dim, v) in vector_set(),
        coefficients in proptest::collection::vec(-2.0f64..2.0, 8),
        exponent in -20i32..20,
    ) {
        let k = v.len() / dim;
        let mut dependent = v[..(k - 1) * dim].to_vec();
        let combination: Vec<f64> = (0..dim)
            .map(|r| (0..k - 1).map(|c| coefficients[c] * v[c * dim + r]).sum())
            .collect();
        prop_assume!(norm(&combination) > 1e-3);
        dependent.extend(&combination);
        let g = *gali(&dependent, dim).last().unwrap();
        prop_assert!(g >= SIGMA_FLOOR.powi(k as i32) * (1.0 - 1e-12), "GALI_{} = {:e}", k, g);
        // 1.65 >= sqrt(e); 4 dim sqrt(k) eps bounds sigma_min (module doc), which the
        // conditioning of the combination can raise by its coefficients (at most 2 (k - 1)).
        let bound = 1.65 * 4.0 * dim as f64 * (k as f64).sqrt() * EPS * (1.0 + 2.0 * (k - 1) as f64);
        prop_assert!(g <= bound, "GALI_{} = {:e} > {:e}", k, g, bound);

        let u = &v[..dim];
        let twice: Vec<f64> = u.iter().chain(u.iter()).enumerate()
            .map(|(i, x)| if i < dim { *x } else { x * 2f64.powi(exponent) })
            .collect();
        let g2 = gali(&twice, dim)[0];
        let sigma_2_bound = 4.0 * dim as f64 * std::f64::consts::SQRT_2 * EPS;
        prop_assert!(
            g2 >= SIGMA_FLOOR * (1.0 - 1e-12) && g2 <= sigma_2_bound,
            "GALI_2 of a repeated vector = {:e}", g2
        );
    }

    /// SALI and GALI_2 of the same two unit vectors u1, u2 with c = u1.u2:
    /// |u1 + u2| = sqrt(2 + 2c), |u1 - u2| = sqrt(2 - 2c), SALI = the smaller one, and
    /// GALI_2 = |u1 ^ u2| = sqrt(1 - c^2) = |u1 + u2| |u1 - u2| / 2. Since
    /// |u1 + u2|^2 + |u1 - u2|^2 = 4, the larger one is sqrt(4 - SALI^2), so exactly
    /// GALI_2 = SALI sqrt(1 - SALI^2 / 4).
    /// Rounding: SALI is a norm of a difference of unit vectors, off by about (dim + 2) eps
    /// absolutely; f(S) = S sqrt(1 - S^2/4) has |f'| <= 1 on [0, sqrt 2] and costs a few eps
    /// to evaluate; GALI_2 is within gali_tol(2, dim); the floor adds at most sqrt(2) eps.
    #[test]
    fn sali_and_gali_2_obey_their_identity((dim, v) in vector_set()) {
        let s = sali(&v, dim).unwrap();
        prop_assert!((0.0..=std::f64::consts::SQRT_2 * (1.0 + 4.0 * EPS)).contains(&s), "SALI = {:e}", s);
        let g2 = gali(&v, dim)[0];
        let from_sali = s * (1.0 - s * s / 4.0).max(0.0).sqrt();
        let tol = (dim as f64 + 2.0) * EPS + 4.0 * EPS + gali_tol(2, dim) + std::f64::consts::SQRT_2 * EPS;
        prop_assert!((g2 - from_sali).abs() <= tol, "GALI_2 = {:e}, from SALI {:e} (diff {:e}, tol {:e})", g2, from_sali, (g2 - from_sali).abs(), tol);
        // GALI_2 <= SALI <= sqrt(2) GALI_2 away from the floor (the documented factor 1 to 2).
        prop_assert!(g2 <= s + tol);
        if g2 > 1e-6 {
            prop_assert!(s <= std::f64::consts::SQRT_2 * g2 * (1.0 + 1e-9));
        }
    }

    /// Nearly aligned pairs, where SALI and GALI_2 are small and the floor matters: the identity
    /// holds down to the floor.
    #[test]
    fn sali_and_gali_2_agree_for_nearly_aligned_pairs(
        (dim, v) in vector_set(),
        angle_exp in -17.0f64..-1.0,
        sign in prop::bool::ANY,
    ) {
        let u = &v[..dim];
        let w = &v[dim..2 * dim];
        // u2 = u1 + 10^angle_exp * w (or its negative: SALI then takes |u1 + u2|).
        let t = 10f64.powf(angle_exp) * norm(u) / norm(w);
        let mut pair: Vec<f64> = u.to_vec();
        pair.extend(u.iter().zip(w).map(|(a, b)| if sign { a + t * b } else { -(a + t * b) }));
        let s = sali(&pair, dim).unwrap();
        let g2 = gali(&pair, dim)[0];
        let from_sali = s * (1.0 - s * s / 4.0).max(0.0).sqrt();
        let tol = (dim as f64 + 2.0) * EPS + 4.0 * EPS + gali_tol(2, dim) + std::f64::consts::SQRT_2 * EPS;
        prop_assert!((g2 - from_sali).abs() <= tol, "GALI_2 = {:e}, from SALI {:e}", g2, from_sali);
        prop_assert!(g2 >= SIGMA_FLOOR * (1.0 - 1e-12));
    }
}

/// The worst error of 20000 random sets against each tolerance, printed (`--nocapture`) so the
/// margins are known, and checked against the same tolerances.
#[test]
fn worst_errors_against_their_tolerances() {
    let mut state = 0x9E37_79B9_7F4A_7C15u64;
    let mut uniform = move || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        (state >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0
    };
    let (mut identity, mut permutation, mut repeated) = (0.0f64, 0.0f64, 0.0f64);
    for n in 0..20_000 {
        let dim = 2 + n % 7;
        let k = 2 + n % (dim - 1);
        let v: Vec<f64> = (0..dim * k).map(|_| uniform()).collect();
        let s = sali(&v, dim).unwrap();
        let g2 = gali(&v, dim)[0];
        let tol = (dim as f64 + 2.0) * EPS
            + 4.0 * EPS
            + gali_tol(2, dim)
            + std::f64::consts::SQRT_2 * EPS;
        identity = identity.max((g2 - s * (1.0 - s * s / 4.0).max(0.0).sqrt()).abs() / tol);
        let reversed: Vec<f64> = v.chunks(dim).rev().flatten().copied().collect();
        let (a, b) = (
            *gali(&v, dim).last().unwrap(),
            *gali(&reversed, dim).last().unwrap(),
        );
        permutation = permutation.max((a - b).abs() / gali_tol(k, dim));
        let twice: Vec<f64> = v[..dim].iter().chain(&v[..dim]).copied().collect();
        repeated = repeated.max(gali(&twice, dim)[0] / EPS);
    }
    eprintln!(
        "worst of 20000: SALI-GALI_2 identity {identity:.3} of its tolerance, permutation \
         {permutation:.3} of its tolerance, repeated vector R_22 {repeated:.2} eps"
    );
    assert!(
        identity <= 1.0 && permutation <= 1.0 && repeated <= 4.0 * 8.0 * std::f64::consts::SQRT_2
    );
}
