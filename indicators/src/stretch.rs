//! Accumulated logarithmic stretching of deviation vectors: finite-time Lyapunov exponents.

use crate::indicator::{Declared, Needs, Output, SetIndicator, SetObservation};

/// Largest finite-time exponent reported (in magnitude): rates beyond are reported as this.
pub const MAX_RATE: f64 = 1e300;

/// Accumulated logarithmic stretching of `k` vectors: the finite-time Lyapunov exponents.
///
/// With per-vector rescaling every vector's sum estimates the maximal exponent (the first one is
/// reported, as in the standard single-vector method); with QR the sums give the spectrum
/// (Benettin et al. 1980).
#[derive(Debug, Clone, PartialEq)]
pub struct StretchSums {
    log_sums: Vec<f64>,
    renormalizations: u64,
}

impl StretchSums {
    pub fn new(k: usize) -> Self {
        Self {
            log_sums: vec![0.0; k],
            renormalizations: 0,
        }
    }

    /// Add one renormalization's stretching factors (`|d(t_j)| / d0`, or `|R_ii|`).
    pub fn add(&mut self, stretch: &[f64]) {
        for (s, f) in self.log_sums.iter_mut().zip(stretch) {
            *s += f.ln();
        }
        self.renormalizations += 1;
    }

    /// `sum ln(stretch_i)` so far, one per vector.
    pub fn log_sums(&self) -> &[f64] {
        &self.log_sums
    }

    pub fn renormalizations(&self) -> u64 {
        self.renormalizations
    }

    /// Finite-time maximal Lyapunov exponent `lambda_1(t)` (0 at `t = 0`).
    pub fn mle(&self, t: f64) -> f64 {
        rate(self.log_sums[0], t)
    }

    /// Finite-time exponents `lambda_i(t) = (1/t) sum ln |R_ii|` (meaningful for QR schemes).
    pub fn spectrum(&self, t: f64) -> Vec<f64> {
        self.log_sums.iter().map(|&s| rate(s, t)).collect()
    }
}

/// `sum / t` (0 at `t = 0`), at most [`MAX_RATE`] in magnitude: a time step near the smallest
/// double with stretching factors near the largest (only in a file with hostile values) would
/// overflow to infinity, and differences and sums of rates (MPM against VM, a spectrum's sum)
/// must stay finite too. A run comes near it only with a step below 1e-297.
fn rate(sum: f64, t: f64) -> f64 {
    if t > 0.0 {
        (sum / t).clamp(-MAX_RATE, MAX_RATE)
    } else {
        0.0
    }
}

/// The finite-time exponents of a set as a registered indicator: `mle`, the first vector's
/// `(1/t) sum ln stretch`, and `spectrum`, the same for every vector of a QR scheme (reported as
/// `lambda_1`, with `lambda_1..k` per vector). `t` is the time the factors observed cover
/// ([`SetObservation::covered`]): a reader that missed renormalizations (a live monitor's lost
/// frames) divides by the time of those it saw. The tracker keeps a second one fed only the
/// intervals after a transient ([`crate::tracker::Tracker::set_exponents_from`]).
#[derive(Debug, Clone, Default)]
pub struct Exponents {
    log_sums: Vec<f64>,
    covered: f64,
}

impl Exponents {
    /// Exponents of `k` vectors, all 0 until a factor covering some time is observed.
    pub fn for_vectors(k: usize) -> Self {
        Self {
            log_sums: vec![0.0; k],
            covered: 0.0,
        }
    }
}

impl SetIndicator for Exponents {
    fn declared(&self) -> &'static [Declared] {
        const DECLARED: &[Declared] = &[
            Declared::own("mle", Needs::STRETCH),
            Declared::own("spectrum", Needs::QR).with_per_vector(),
        ];
        DECLARED
    }

    fn observe(&mut self, obs: &SetObservation<'_>) {
        if self.log_sums.len() < obs.stretch.len() {
            self.log_sums.resize(obs.stretch.len(), 0.0);
        }
        // The initial vectors (t = 0) cover no time: their factors are no stretching.
        if obs.covered > 0.0 {
            for (sum, s) in self.log_sums.iter_mut().zip(obs.stretch) {
                *sum += s.ln();
            }
        }
        self.covered = obs.covered;
    }

    fn outputs(&self) -> Vec<Output> {
        let first = rate(self.log_sums.first().copied().unwrap_or(0.0), self.covered);
        vec![Output::Value(first), Output::Value(first)]
    }

    fn per_vector(&self) -> Vec<f64> {
        self.log_sums
            .iter()
            .map(|&s| rate(s, self.covered))
            .collect()
    }

    fn boxed_clone(&self) -> Box<dyn SetIndicator> {
        Box::new(self.clone())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stretch_sums_give_rates() {
        let mut s = StretchSums::new(2);
        for _ in 0..10 {
            s.add(&[std::f64::consts::E, 1.0 / std::f64::consts::E]);
        }
        let sp = s.spectrum(10.0);
        assert!((sp[0] - 1.0).abs() < 1e-14 && (sp[1] + 1.0).abs() < 1e-14);
        assert_eq!(s.renormalizations(), 10);
    }
}
