//! Progress of a live run: time, steps per second (smoothed), ETA. Pure: fed with (step, wall
//! time) observations.

use std::time::Duration;

#[derive(Debug, Clone, Default)]
pub struct Progress {
    total_steps: u64,
    last: Option<(u64, Duration)>,
    /// Smoothed steps per second.
    rate: Option<f64>,
}

impl Progress {
    pub fn new(total_steps: u64) -> Self {
        Self {
            total_steps,
            ..Default::default()
        }
    }

    /// Records that `step` was reached at `elapsed` (wall time since any fixed origin).
    pub fn observe(&mut self, step: u64, elapsed: Duration) {
        if let Some((s0, e0)) = self.last {
            let dt = (elapsed - e0).as_secs_f64();
            if dt >= 0.2 && step > s0 {
                let r = (step - s0) as f64 / dt;
                // Exponential smoothing over ~5 observations.
                self.rate = Some(self.rate.map_or(r, |old| 0.8 * old + 0.2 * r));
                self.last = Some((step, elapsed));
            }
        } else {
            self.last = Some((step, elapsed));
        }
    }

    pub fn steps_per_second(&self) -> Option<f64> {
        self.rate
    }

    pub fn fraction(&self, step: u64) -> f64 {
        if self.total_steps == 0 {
            1.0
        } else {
            (step as f64 / self.total_steps as f64).min(1.0)
        }
    }

    /// Seconds to the end at the current rate.
    pub fn eta_seconds(&self, step: u64) -> Option<f64> {
        let r = self.rate?;
        (r > 0.0).then(|| self.total_steps.saturating_sub(step) as f64 / r)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rate_and_eta() {
        let mut p = Progress::new(10_000);
        p.observe(0, Duration::ZERO);
        assert!(p.eta_seconds(0).is_none());
        p.observe(1000, Duration::from_secs(1));
        assert_eq!(p.steps_per_second(), Some(1000.0));
        assert_eq!(p.eta_seconds(1000), Some(9.0));
        assert_eq!(p.fraction(5000), 0.5);
    }
}
