//! A map point computed by the one-orbit [`Engine`]: the definition the batched kernel must
//! reproduce bit for bit. Slow (every set runs to `t_final`, one orbit at a time); used by tests
//! and available for cross-checks.

use super::indicator::failed;
use super::point::{PointResult, PointStatus};
use super::spec::MapSpec;
use crate::engine::Engine;

pub fn point(spec: &MapSpec, index: u64) -> PointResult {
    let (base, x0) = match spec.start_point(index) {
        Ok(start) => start,
        Err(outside) => return *outside,
    };
    let run = spec.point_run(&x0);
    let total = run.total_steps();
    let mut acc = spec.accumulator();
    let mut engine = Engine::one_orbit(run);
    let mut steps = 0;
    loop {
        match engine.next_sample() {
            Ok(Some(sample)) => {
                steps = sample.step;
                if sample.seq == 0 {
                    continue;
                }
                for s in &sample.schemes {
                    acc.observe(
                        s.set as usize,
                        sample.t,
                        &s.separations,
                        &s.stretch,
                        sample.step == total,
                    );
                }
            }
            Ok(None) => break,
            Err(e) => {
                return failed(base, PointStatus::Escaped, e.t(), e.to_string());
            }
        }
    }
    acc.finish(base, steps * (1 + (spec.sets() * spec.run.k()) as u64))
}
