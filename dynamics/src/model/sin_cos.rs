//! `sin` and `cos` of many angles at once, written so the loop vectorizes: the DDNLS's on-site
//! rotation takes both of every site's angle at every stage, and a call to the C library per
//! angle was half of a DDNLS run's time.
//!
//! The method is the classic one of fdlibm (Sun Microsystems, 1993): the angle is reduced by
//! the nearest multiple `k` of `pi/2` (Cody and Waite's `pi/2` in parts short enough that `k`
//! times each is exact), then the minimax polynomials of fdlibm's `__kernel_sin`
//! and `__kernel_cos` on `[-pi/4, pi/4]`, and the quadrant `k mod 4` swaps and negates them.
//! Branch-free, so the compiler turns it into vector code; the few angles it is not made for
//! (beyond [`FAST_LIMIT`], or not finite) are recomputed by the standard library afterwards.
//!
//! The results are within two units in the last place of the C library's values over the whole
//! range (a test checks it, next to every multiple of `pi/4` as well; measured on glibc 2.36:
//! within one), and only additions,
//! multiplications and bit operations make them, never a fused multiply-add: the same bits on
//! every CPU and with every instruction set the caller is compiled for. (The rare fallback is the
//! C library's, which may pick a variant by CPU.)

// The constants are written as fdlibm publishes them (21 significant digits, more than a double
// holds), so they can be checked against it digit for digit.
#![allow(clippy::excessive_precision)]

use std::f64::consts::FRAC_2_PI;

/// Largest `|x|` the reduction is made for: `k < 2^17`, so `k` times each part of `pi/2` (33
/// significant bits at most) is exact, and the reduced angle keeps its accuracy.
pub const FAST_LIMIT: f64 = 1.0e5;

/// `1.5 * 2^52`: adding it rounds a value below `2^51` to an integer, whose low bits are then
/// the low bits of the sum's significand (so `k mod 4` needs no conversion to an integer).
const ROUNDER: f64 = 6_755_399_441_055_744.0;

// `pi/2` in four parts (fdlibm's `pio2_1`, `pio2_2`, `pio2_3`, `pio2_3t`): the first three
// have 33 significant bits.
const PIO2_1: f64 = 1.570_796_326_734_125_614_17;
const PIO2_2: f64 = 6.077_100_506_303_965_976_60e-11;
const PIO2_3: f64 = 2.022_266_248_711_166_455_80e-21;
const PIO2_3T: f64 = 8.478_427_660_368_899_569_97e-32;

// The polynomials of fdlibm's `__kernel_sin` and `__kernel_cos` on `[-pi/4, pi/4]`:
// `sin x ~ x + x^3 P_S(x^2)` and `cos x ~ 1 - x^2/2 + x^4 P_C(x^2)`, `P(z) = c_1 + z (c_2 + ...)`.
#[rustfmt::skip]
const SIN_POLY: [f64; 6] = [
    -1.666_666_666_666_663_243_48e-1, 8.333_333_333_322_489_461_24e-3, -1.984_126_982_985_794_931_34e-4,
    2.755_731_370_707_006_767_89e-6, -2.505_076_025_340_686_341_95e-8, 1.589_690_995_211_550_102_21e-10,
];
#[rustfmt::skip]
const COS_POLY: [f64; 6] = [
    4.166_666_666_666_660_190_37e-2, -1.388_888_888_887_410_957_49e-3, 2.480_158_728_947_672_941_78e-5,
    -2.755_731_435_139_066_330_35e-7, 2.087_572_321_298_174_827_90e-9, -1.135_964_755_778_819_482_65e-11,
];

/// `c_1 + z (c_2 + z (... + z c_6))`, Horner's rule from the highest power (fdlibm's order).
#[inline(always)]
fn horner(c: &[f64; 6], z: f64) -> f64 {
    c[..5].iter().rev().fold(c[5], |acc, &ci| ci + z * acc)
}

/// `(sin x, cos x)` for `|x| <= FAST_LIMIT`; any value outside (not finite either) gives a
/// meaningless pair, which [`sin_cos_each`] replaces.
#[inline(always)]
fn sin_cos_reduced(x: f64) -> (f64, f64) {
    let rounded = x * FRAC_2_PI + ROUNDER;
    let k = rounded - ROUNDER;
    let quadrant = rounded.to_bits();
    // x - k pi/2 = (x - k PIO2_1) - k PIO2_2 - k PIO2_3 - k PIO2_3T: the first difference and
    // the products are exact; the second difference's rounding error is recovered (Knuth's
    // two-sum) and carried with the last parts, so the reduced angle keeps its relative
    // accuracy when it cancels to a small value next to a multiple of pi/2.
    let head = x - k * PIO2_1;
    let second = -(k * PIO2_2);
    let r0 = head + second;
    let back = r0 - head;
    let rounding = (head - (r0 - back)) + (second - back);
    let r = r0 + ((rounding - k * PIO2_3) - k * PIO2_3T);
    let z = r * r;
    let sin_r = r + (z * r) * horner(&SIN_POLY, z);
    let cos_tail = z * horner(&COS_POLY, z);
    let half_z = 0.5 * z;
    let w = 1.0 - half_z;
    // fdlibm's order: the rounding of `1 - z/2` is given back before the tail is added.
    let cos_r = w + (((1.0 - w) - half_z) + z * cos_tail);
    // sin(r + k pi/2) and cos(r + k pi/2) by k mod 4: odd k swaps the two; sin is negated for
    // k = 2, 3, cos for k = 1, 2.
    let (s, c) = if quadrant & 1 == 0 {
        (sin_r, cos_r)
    } else {
        (cos_r, sin_r)
    };
    let sin_sign = (quadrant & 2) << 62;
    let cos_sign = (quadrant.wrapping_add(1) & 2) << 62;
    (
        f64::from_bits(s.to_bits() ^ sin_sign),
        f64::from_bits(c.to_bits() ^ cos_sign),
    )
}

/// `sin[i] = sin(x[i])`, `cos[i] = cos(x[i])` for every `i` (the three slices as long as each
/// other).
#[inline(always)]
pub fn sin_cos_each(x: &[f64], sin: &mut [f64], cos: &mut [f64]) {
    let n = x.len();
    let (sin, cos) = (&mut sin[..n], &mut cos[..n]);
    for i in 0..n {
        (sin[i], cos[i]) = sin_cos_reduced(x[i]);
    }
    for i in 0..n {
        // A NaN takes this path too.
        if x[i].abs() > FAST_LIMIT || x[i].is_nan() {
            (sin[i], cos[i]) = x[i].sin_cos();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The error in units in the last place of `want` (the spacing of doubles at `|want|`).
    fn ulps(got: f64, want: f64) -> f64 {
        let a = want.abs().max(f64::MIN_POSITIVE);
        (got - want).abs() / (a.next_up() - a)
    }

    fn worst(x: &[f64]) -> (f64, f64) {
        let (mut s, mut c) = (vec![0.0; x.len()], vec![0.0; x.len()]);
        sin_cos_each(x, &mut s, &mut c);
        let mut w = (0.0f64, 0.0f64);
        for i in 0..x.len() {
            w.0 = w.0.max(ulps(s[i], x[i].sin()));
            w.1 = w.1.max(ulps(c[i], x[i].cos()));
        }
        w
    }

    /// Within two units in the last place of the C library's values (themselves within one of
    /// the correctly rounded ones) over the range the reduction is made for: random angles on
    /// every scale, and the angles next to multiples of `pi/4` and `pi/2`, where the reduction
    /// cancels or the quadrant changes.
    #[test]
    fn within_two_ulps_of_the_c_library() {
        let mut state = 0x9e37_79b9_7f4a_7c15u64;
        let mut uniform = || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 11) as f64 / (1u64 << 53) as f64
        };
        let mut x = Vec::new();
        for _ in 0..200_000 {
            let scale = 10f64.powf(-8.0 + 13.0 * uniform());
            x.push((2.0 * uniform() - 1.0) * scale.min(FAST_LIMIT));
        }
        // Every multiple of pi/4 within the limit (127 323 pi/4 < 1e5), of either sign.
        for k in -127_323i32..=127_323 {
            let c = k as f64 * std::f64::consts::FRAC_PI_4;
            let mut y = c;
            for _ in 0..4 {
                x.push(y);
                y = y.next_up();
            }
            y = c;
            for _ in 0..4 {
                y = y.next_down();
                x.push(y);
            }
        }
        let (s, c) = worst(&x);
        assert!(s <= 2.0 && c <= 2.0, "worst sin {s} ulp, cos {c} ulp");
    }

    /// The premise of the reduction: the first three parts of `pi/2` have at most 33 significant
    /// bits (so `k` times each is exact for `k < 2^20`), and the four parts add up to `pi/2`.
    #[test]
    fn the_parts_of_pi_over_2_are_short_and_add_up() {
        for part in [PIO2_1, PIO2_2, PIO2_3] {
            let significand = part.to_bits() & ((1u64 << 52) - 1);
            assert!(significand.trailing_zeros() >= 20, "{part:e}");
        }
        let sum = ((PIO2_3T + PIO2_3) + PIO2_2) + PIO2_1;
        assert_eq!(sum, std::f64::consts::FRAC_PI_2);
        assert!(FAST_LIMIT * FRAC_2_PI < (1u64 << 20) as f64);
    }

    /// Past the limit, and for values that are not numbers, the standard library's answer.
    #[test]
    fn the_rest_is_the_standard_library() {
        let x = [
            1.0e5 + 1.0,
            -3.0e7,
            1.0e300,
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::NAN,
            0.0,
            -0.0,
        ];
        let (mut s, mut c) = ([0.0; 8], [0.0; 8]);
        sin_cos_each(&x, &mut s, &mut c);
        for i in 0..5 {
            assert_eq!(s[i].to_bits(), x[i].sin().to_bits(), "sin {}", x[i]);
            assert_eq!(c[i].to_bits(), x[i].cos().to_bits(), "cos {}", x[i]);
        }
        assert!(s[5].is_nan() && c[5].is_nan());
        // Zero of either sign: sine zero (its sign is not kept), cosine one.
        assert_eq!((s[6], s[7], c[6], c[7]), (0.0, 0.0, 1.0, 1.0));
    }
}
