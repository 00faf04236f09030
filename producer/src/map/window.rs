//! Renormalization windows of a map point, exactly as the engine schedules them.

use crate::spec::RunSpec;

/// Beyond this norm a state counts as escaped (the engine's criterion).
pub const ESCAPE_NORM: f64 = 1e100;

pub fn norm(v: &[f64]) -> f64 {
    v.iter().map(|v| v * v).sum::<f64>().sqrt()
}

/// One window: advance `steps` steps, then renormalize at time `t`.
#[derive(Debug, Clone, Copy)]
pub struct Window {
    pub steps: u64,
    pub t: f64,
    /// The run's final step.
    pub last: bool,
}

/// Windows of `tau_steps` steps, the last one cut at `total_steps` (Engine::next_stop with one
/// scheme).
pub struct Windows<'a> {
    run: &'a RunSpec,
    step: u64,
}

impl<'a> Windows<'a> {
    pub fn new(run: &'a RunSpec) -> Self {
        Self { run, step: 0 }
    }
}

impl Iterator for Windows<'_> {
    type Item = Window;
    fn next(&mut self) -> Option<Window> {
        let total = self.run.total_steps;
        if self.step >= total {
            return None;
        }
        let tau = self.run.schemes[0].tau_steps;
        let target = ((self.step / tau + 1) * tau).min(total);
        let w = Window {
            steps: target - self.step,
            t: self.run.time_of(target),
            last: target == total,
        };
        self.step = target;
        Some(w)
    }
}
