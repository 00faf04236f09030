//! The 0-1 test for chaos (Gottwald and Melbourne 2004; the implementation of Gottwald and
//! Melbourne 2009, "On the implementation of the 0-1 test for chaos", SIAM J. Appl. Dyn. Syst.
//! 8, 129): `K` near 0 for a regular orbit, near 1 for a chaotic one, from an observable of the
//! orbit alone, no deviation vector.
//!
//! The observable is the first coordinate of the reference state (`q_1`, `x1`), sampled at the
//! scheme's renormalizations. The samples are kept bounded: at most [`MAX_SAMPLES`], and when
//! full every other one is dropped and the stride doubled, so the series spans the whole run with
//! between `MAX_SAMPLES / 2` and `MAX_SAMPLES` evenly spaced samples (whatever the run length,
//! and deterministic). The stride growing with the run also keeps the sampling from being much
//! finer than the orbit's own times, where the test would read chaos as regular (oversampling,
//! Gottwald and Melbourne 2009, section 5.3).
//!
//! From `N` samples `phi_j`: for each `c`, the translation variables
//! `p_c(n) = sum_{j<=n} phi_j cos(jc)`, `q_c(n) = sum phi_j sin(jc)`, the mean square
//! displacement `M_c(n)` for `n <= n_cut = N/10`, its oscillating term subtracted
//! (`D_c = M_c - (E phi)^2 (1 - cos nc) / (1 - cos c)`), and `K_c` the correlation of `D_c(n)`
//! with `n`; `K` is the median of `K_c` over [`C_VALUES`] values of `c` in `(pi/5, 4 pi/5)`
//! (away from the resonances at 0 and pi; the median removes the rest). The `c` values are a
//! fixed low-discrepancy sequence rather than random ones, so `K` is a function of the samples.

use crate::indicator::{OrbitIndicator, Output};

/// Most samples kept (between half of it and all of it once the run is long enough).
pub const MAX_SAMPLES: usize = 2048;
/// Fewest samples the test is computed from (`n_cut` = 10 displacements at least).
pub const MIN_SAMPLES: usize = 100;
/// Values of `c` the median is taken over.
pub const C_VALUES: usize = 100;

#[derive(Debug, Clone)]
pub struct ZeroOneTest {
    samples: Vec<f64>,
    /// Keep one state in `stride`.
    stride: u64,
    /// States offered so far.
    offered: u64,
}

impl Default for ZeroOneTest {
    fn default() -> Self {
        Self {
            samples: Vec::new(),
            stride: 1,
            offered: 0,
        }
    }
}

impl OrbitIndicator for ZeroOneTest {
    fn names(&self) -> &'static [&'static str] {
        &["zero_one_k"]
    }

    fn observe(&mut self, _t: f64, state: &[f64]) {
        let Some(&phi) = state.first() else {
            return;
        };
        if !phi.is_finite() {
            return;
        }
        if self.offered.is_multiple_of(self.stride) {
            self.samples.push(phi);
            if self.samples.len() == MAX_SAMPLES {
                let kept: Vec<f64> = self.samples.iter().copied().step_by(2).collect();
                self.samples = kept;
                self.stride *= 2;
            }
        }
        self.offered += 1;
    }

    fn outputs(&self) -> Vec<Output> {
        vec![match zero_one_k(&self.samples) {
            Some(k) => Output::Value(k),
            None => Output::Unavailable(format!(
                "the 0-1 test needs at least {MIN_SAMPLES} samples of the orbit (renormalizations), \
                 this run has {}",
                self.samples.len()
            )),
        }]
    }

    fn boxed_clone(&self) -> Box<dyn OrbitIndicator> {
        Box::new(self.clone())
    }
}

/// `K` of the 0-1 test from evenly spaced samples of an observable; `None` for fewer than
/// [`MIN_SAMPLES`]. In `[-1, 1]` (a correlation), near 0 regular, near 1 chaotic.
pub fn zero_one_k(phi: &[f64]) -> Option<f64> {
    let n = phi.len();
    if n < MIN_SAMPLES {
        return None;
    }
    let n_cut = n / 10;
    let mean = phi.iter().sum::<f64>() / n as f64;
    // A constant observable (an equilibrium) is regular: no displacement at all.
    if phi.iter().all(|&v| v == phi[0]) {
        return Some(0.0);
    }
    let golden = 0.5 * (5f64.sqrt() - 1.0);
    let pi = std::f64::consts::PI;
    let mut ks: Vec<f64> = (0..C_VALUES)
        .map(|i| {
            let c = pi / 5.0 + (3.0 * pi / 5.0) * ((i as f64 + 0.5) * golden).fract();
            k_of_c(phi, mean, c, n_cut)
        })
        .collect();
    ks.sort_by(f64::total_cmp);
    let median = if C_VALUES % 2 == 1 {
        ks[C_VALUES / 2]
    } else {
        0.5 * (ks[C_VALUES / 2 - 1] + ks[C_VALUES / 2])
    };
    Some(if median.is_finite() { median } else { 0.0 })
}

/// `K_c`: the correlation of the modified mean square displacement `D_c(n)` with `n`.
fn k_of_c(phi: &[f64], mean: f64, c: f64, n_cut: usize) -> f64 {
    let n = phi.len();
    let mut p = Vec::with_capacity(n);
    let mut q = Vec::with_capacity(n);
    let (mut ps, mut qs) = (0.0, 0.0);
    for (j, &v) in phi.iter().enumerate() {
        let a = (j + 1) as f64 * c;
        ps += v * a.cos();
        qs += v * a.sin();
        p.push(ps);
        q.push(qs);
    }
    let d: Vec<f64> = (1..=n_cut)
        .map(|lag| {
            let m = (0..n - lag)
                .map(|j| {
                    let dp = p[j + lag] - p[j];
                    let dq = q[j + lag] - q[j];
                    dp * dp + dq * dq
                })
                .sum::<f64>()
                / (n - lag) as f64;
            m - mean * mean * (1.0 - (lag as f64 * c).cos()) / (1.0 - c.cos())
        })
        .collect();
    correlation_with_index(&d)
}

/// Pearson correlation of `d[i]` with `i`; 0 when `d` does not vary.
fn correlation_with_index(d: &[f64]) -> f64 {
    let m = d.len() as f64;
    let xm = (m + 1.0) / 2.0;
    let dm = d.iter().sum::<f64>() / m;
    let (mut sxy, mut sxx, mut syy) = (0.0, 0.0, 0.0);
    for (i, &v) in d.iter().enumerate() {
        let x = (i + 1) as f64 - xm;
        let y = v - dm;
        sxy += x * y;
        sxx += x * x;
        syy += y * y;
    }
    if syy > 0.0 {
        sxy / (sxx * syy).sqrt()
    } else {
        0.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `n` iterates of the logistic map `x -> r x (1 - x)` after a transient of 1000.
    fn logistic(r: f64, n: usize) -> Vec<f64> {
        let mut x = 0.3;
        for _ in 0..1000 {
            x = r * x * (1.0 - x);
        }
        (0..n)
            .map(|_| {
                x = r * x * (1.0 - x);
                x
            })
            .collect()
    }

    #[test]
    fn logistic_map_regular_and_chaotic() {
        // Gottwald and Melbourne's example: r = 3.55 (period 8) and r = 3.97 (chaotic), 2000
        // samples of x. For a periodic observable D_c is bounded and its correlation with n
        // vanishes like 1/N away from resonant c (the median discards those): K < 0.1. For
        // the chaotic one D_c grows linearly (diffusion of p, q) up to fluctuations of relative
        // size sqrt(n_cut / N) ~ 0.3 around the line, which correlation forgives: K > 0.9.
        let regular = zero_one_k(&logistic(3.55, 2000)).unwrap();
        assert!(regular.abs() < 0.1, "K = {regular}");
        let chaotic = zero_one_k(&logistic(3.97, 2000)).unwrap();
        assert!(chaotic > 0.9, "K = {chaotic}");
        // Quasi-periodic (two incommensurate frequencies), as a regular Hamiltonian orbit.
        let qp: Vec<f64> = (0..2000)
            .map(|j| (0.7 * j as f64).sin() + 0.5 * (0.7 * 2f64.sqrt() * j as f64).cos())
            .collect();
        let k = zero_one_k(&qp).unwrap();
        assert!(k.abs() < 0.1, "K = {k}");
    }

    #[test]
    fn bounded_samples_span_the_run() {
        let mut z = ZeroOneTest::default();
        for j in 0..10_000u32 {
            z.observe(f64::from(j), &[f64::from(j)]);
        }
        // Halved at 2048 (stride 2), at 2048 again (stride 4): 1024 + (10000 - 8192) / 8.
        assert!(z.samples.len() >= MAX_SAMPLES / 2 && z.samples.len() < MAX_SAMPLES);
        assert_eq!(z.samples[1] - z.samples[0], z.stride as f64);
        assert!(matches!(
            ZeroOneTest::default().outputs()[0],
            Output::Unavailable(_)
        ));
    }
}
