//! Averages over the random sets of a scheme.
//!
//! A GALI spans many decades across sets, so its arithmetic mean is dominated by the few largest
//! values (numerics.md: up to 8x between seeds); the mean of log10 (the geometric mean) is the
//! stable summary, the arithmetic mean is what the paper plots, and the spread says how much to
//! trust either.

use serde::{Deserialize, Serialize};

/// Summary of a positive quantity over sets, given its `log10` per set.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct LogStat {
    /// Arithmetic mean of the values.
    pub mean: f64,
    /// Mean of `log10` of the values (log10 of the geometric mean).
    pub log10_mean: f64,
    /// Standard deviation of `log10` over sets (0 for one set).
    pub log10_std: f64,
    pub log10_min: f64,
    pub log10_max: f64,
}

impl LogStat {
    /// From `log10` values (at least one).
    pub fn from_log10(values: impl IntoIterator<Item = f64>) -> Option<Self> {
        let mut n = 0usize;
        let (mut sum_lin, mut sum, mut sum2) = (0.0, 0.0, 0.0);
        let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
        for v in values {
            n += 1;
            sum_lin += 10f64.powf(v);
            sum += v;
            sum2 += v * v;
            lo = lo.min(v);
            hi = hi.max(v);
        }
        if n == 0 {
            return None;
        }
        let nf = n as f64;
        let mean = sum / nf;
        Some(Self {
            mean: sum_lin / nf,
            log10_mean: mean,
            log10_std: (sum2 / nf - mean * mean).max(0.0).sqrt(),
            log10_min: lo,
            log10_max: hi,
        })
    }
}

/// Mean and standard deviation of a signed quantity over sets.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Stat {
    pub mean: f64,
    pub std: f64,
}

impl Stat {
    pub fn from_values(values: impl IntoIterator<Item = f64>) -> Option<Self> {
        let values: Vec<f64> = values.into_iter().collect();
        if values.is_empty() {
            return None;
        }
        let (mut sum, mut sum2) = (0.0, 0.0);
        for &v in &values {
            sum += v;
            sum2 += v * v;
        }
        let n = values.len() as f64;
        let mean = sum / n;
        let std = (sum2 / n - mean * mean).max(0.0).sqrt();
        if (mean.is_finite() && std.is_finite()) || values.iter().any(|v| !v.is_finite()) {
            return Some(Self { mean, std });
        }
        // Finite values whose sum or sum of squares leaves the range of f64 (exponents near
        // f64::MAX, only from files with hostile values): the same moments with every value
        // scaled by the largest magnitude first, so they stay finite. Never taken for the
        // values of a run, whose results above are bit for bit what they were.
        let scale = values.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        let (mut sum, mut sum2) = (0.0, 0.0);
        for &v in &values {
            sum += v / scale;
            sum2 += (v / scale) * (v / scale);
        }
        let mean = sum / n;
        Some(Self {
            mean: mean * scale,
            std: (sum2 / n - mean * mean).max(0.0).sqrt() * scale,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn geometric_and_arithmetic_means_differ_as_expected() {
        // 1e-2 and 1e-6: arithmetic mean ~5e-3 (dominated by the larger), geometric 1e-4.
        let s = LogStat::from_log10([-2.0, -6.0]).unwrap();
        assert!((s.mean - 0.5 * (1e-2 + 1e-6)).abs() < 1e-15);
        assert_eq!(s.log10_mean, -4.0);
        assert_eq!(s.log10_std, 2.0);
        assert_eq!((s.log10_min, s.log10_max), (-6.0, -2.0));
        assert!(LogStat::from_log10([]).is_none());
    }

    #[test]
    fn signed_stat() {
        let s = Stat::from_values([1.0, 3.0]).unwrap();
        assert_eq!((s.mean, s.std), (2.0, 1.0));
    }

    #[test]
    fn moments_of_huge_finite_values_stay_finite() {
        // Their sum (and squares) overflow; the scaled moments do not: mean 1.5e308, spread
        // 0.5e308 (to rounding of the scaling).
        let s = Stat::from_values([f64::MAX, 0.5 * f64::MAX]).unwrap();
        assert!((s.mean / (0.75 * f64::MAX) - 1.0).abs() < 1e-15, "{s:?}");
        assert!((s.std / (0.25 * f64::MAX) - 1.0).abs() < 1e-15, "{s:?}");
        let s = Stat::from_values([1e200, -1e200]).unwrap();
        assert_eq!(s.mean, 0.0);
        assert!((s.std / 1e200 - 1.0).abs() < 1e-15, "{s:?}");
    }
}
