//! MEGNO, the mean exponential growth factor of nearby orbits (Cincotta and Simo 2000).
//!
//! `Y(t) = (2/t) int_0^t s (d'(s)/d(s)) ds` of the first deviation vector of a set, and its
//! running mean `megno_mean = (1/t) int_0^t Y(s) ds`. With renormalization the logarithmic
//! growth is known per interval, `ln alpha_j` (the first vector's stretching factor over
//! `(t_{j-1}, t_j]`, its own growth under rescaling and QR alike), and the integral takes the
//! standard discrete form of Cincotta and Simo for maps, time-weighted sums:
//! `Y(t_n) = (2/t_n) sum_j t_j ln alpha_j`, `megno_mean(t_n) = (1/t_n) sum_j Y(t_j) (t_j - t_{j-1})`
//! (for `tau` = one iteration of a map these are exactly Cincotta and Simo's `Y_N` and its
//! mean). For `ln d = lambda t` they give `Y = lambda (t + tau)`, `megno_mean -> lambda t / 2`;
//! for `ln d = ln t` (a regular orbit: linear growth) `Y -> 2`; for a bounded `d` (an isochronous
//! periodic orbit) `Y` oscillates about 0 and `megno_mean -> 0`.

use crate::indicator::{Declared, Needs, Output, SetIndicator, SetObservation};

#[derive(Debug, Clone, Default)]
pub struct Megno {
    /// `sum_j t_j ln alpha_j`.
    weighted_log: f64,
    /// `Y` at the latest renormalization.
    y: f64,
    /// `sum_j Y(t_j) (t_j - t_{j-1})`.
    y_integral: f64,
    t: f64,
}

impl SetIndicator for Megno {
    fn declared(&self) -> &'static [Declared] {
        const DECLARED: &[Declared] = &[
            Declared::named("megno", Needs::STRETCH),
            Declared::named("megno_mean", Needs::STRETCH),
        ];
        DECLARED
    }

    fn observe(&mut self, obs: &SetObservation<'_>) {
        let Some(&first) = obs.stretch.first() else {
            return;
        };
        if obs.t.is_nan() || obs.t <= 0.0 {
            return;
        }
        self.weighted_log += obs.t * first.ln();
        self.y = 2.0 * self.weighted_log / obs.t;
        self.y_integral += self.y * obs.dt;
        self.t = obs.t;
    }

    fn outputs(&self) -> Vec<Output> {
        let mean = if self.t > 0.0 {
            self.y_integral / self.t
        } else {
            0.0
        };
        // Finite for every run (the producer stops before a vector leaves the range of f64);
        // clamped like the exponents for files with hostile values.
        let clamp = |v: f64| v.clamp(-f64::MAX, f64::MAX);
        vec![Output::Value(clamp(self.y)), Output::Value(clamp(mean))]
    }

    fn boxed_clone(&self) -> Box<dyn SetIndicator> {
        Box::new(self.clone())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn run(log_norm: impl Fn(f64) -> f64, tau: f64, n: usize) -> (f64, f64) {
        let mut m = Megno::default();
        let mut prev = 0.0;
        for j in 0..=n {
            let t = j as f64 * tau;
            let l = log_norm(t);
            let stretch = if j == 0 { 1.0 } else { (l - prev).exp() };
            m.observe(&SetObservation {
                t,
                dt: if j == 0 { 0.0 } else { tau },
                covered: t,
                dim: 1,
                separations: &[1.0],
                stretch: &[stretch],
                flow: None,
                sites: None,
                square_side: None,
                periodic: [false; 2],
                norm_conserved: false,
                state: None,
                site_energies: None,
            });
            prev = l;
        }
        let out = m.outputs();
        match (&out[0], &out[1]) {
            (Output::Value(y), Output::Value(mean)) => (*y, *mean),
            _ => panic!("{out:?}"),
        }
    }

    #[test]
    fn limits_of_the_three_kinds_of_growth() {
        // Exponential growth lambda = 0.5 to t = 1000: Y = lambda (t + tau) exactly (the
        // discrete form), megno_mean = lambda (t + 3 tau) / 2 to rounding.
        let (y, mean) = run(|t| 0.5 * t, 1.0, 1000);
        assert!((y - 0.5 * 1001.0).abs() < 1e-9, "{y}");
        assert!((mean / (0.25 * 1000.0) - 1.0).abs() < 0.01, "{mean}");
        // Linear growth: Y -> 2 (the correction is O(ln t / t) from the first intervals).
        let (y, mean) = run(|t| (1.0 + t).ln(), 1.0, 100_000);
        assert!((y - 2.0).abs() < 1e-3, "{y}");
        assert!((mean - 2.0).abs() < 2e-3, "{mean}");
        // Bounded oscillation: megno_mean -> 0 like 1/t.
        let (_, mean) = run(|t| 0.3 * (0.7 * t).sin(), 0.1, 100_000);
        assert!(mean.abs() < 1e-3, "{mean}");
    }
}
