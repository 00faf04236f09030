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
        let mut n = 0usize;
        let (mut sum, mut sum2) = (0.0, 0.0);
        for v in values {
            n += 1;
            sum += v;
            sum2 += v * v;
        }
        if n == 0 {
            return None;
        }
        let mean = sum / n as f64;
        Some(Self {
            mean,
            std: (sum2 / n as f64 - mean * mean).max(0.0).sqrt(),
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
}
