//! Stroboscopic sections: the state every `T` time units (`chaoscope section --sample-every
//! T`), the Poincare section of a periodically forced system at a fixed phase of its forcing
//! when `T` is the forcing's period (`2*pi/omega` for a drive `cos(omega t)`): the section of
//! the extended phase space through `t mod T = 0`. The period is chosen by the user (the
//! system does not say which of its terms is the forcing), as an expression over the config's
//! parameters.
//!
//! No interpolation: `T` must be a whole number `m` of the run's steps `h` (to rounding, as
//! `tau` and `t_final` are), and the state after steps `m, 2m, 3m, ...` is taken as it is, at
//! the times `k m h` (computed from the step number, never accumulated), so a sample is the
//! run's own orbit, bit for bit, and its time is `k T` to rounding.

use chaoscope_schemas::config::ModelConfig;

use super::surface::{Crossing, OrbitEnd, SurfaceOrbit, scalar_over_state};
use crate::integrator::Workspace;
use crate::spec::{RunSpec, SpecError, whole_steps};

/// The key errors name.
const KEY: &str = "--sample-every";

/// A stroboscopic sampling: every `steps` steps of the run, `period` time units.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Stroboscopic {
    pub period: f64,
    pub steps: u64,
}

impl Stroboscopic {
    /// The period `source` (an expression over the config's scalar parameters and `pi`, e.g.
    /// `2*pi/omega`, or a number) of `spec`'s system: positive, finite, reading no coordinate,
    /// and a whole number of the run's steps `h`. Errors in one line naming `--sample-every`.
    pub fn new(spec: &RunSpec, model: &ModelConfig, source: &str) -> Result<Self, SpecError> {
        let f = scalar_over_state(spec, model, KEY, source)?;
        if !f.reads().is_empty() {
            return Err(SpecError::new(
                KEY,
                format!(
                    "'{source}' reads the state; the sampling period is a number or an \
                     expression of the parameters (e.g. 2*pi/omega)"
                ),
            ));
        }
        let period = f.value(spec.x0());
        if !(period.is_finite() && period > 0.0) {
            return Err(SpecError::new(
                KEY,
                format!("'{source}' = {period}: the sampling period must be a positive number"),
            ));
        }
        let steps = whole_steps(KEY, period, spec.h())?;
        Ok(Self { period, steps })
    }
}

/// The states of the orbit of `spec`'s system from `x0` after every `every.steps` steps (at
/// times `k * steps * h`, `k = 1, 2, ...`), stepped by the run's integrator for at most
/// `steps` steps, keeping at most `max` samples after skipping the first `skip` (a transient).
/// Every sample is finite: a non-finite state ends the orbit.
pub fn stroboscopic_samples(
    spec: &RunSpec,
    every: Stroboscopic,
    x0: &[f64],
    steps: u64,
    skip: usize,
    max: usize,
) -> SurfaceOrbit {
    let system = spec.system().as_ref();
    let mut x = x0.to_vec();
    let mut prev = x.clone();
    let mut work = Workspace::new();
    let mut samples = Vec::new();
    let mut seen = 0usize;
    if max == 0 {
        return SurfaceOrbit {
            crossings: samples,
            end: OrbitEnd::Crossings,
        };
    }
    for step in 0..steps {
        prev.copy_from_slice(&x);
        let t = spec.time_of(step);
        system.step(&mut x, t, &mut work);
        if !x.iter().all(|v| v.is_finite()) {
            let why = system
                .diagnose_non_finite(&prev, t)
                .unwrap_or_else(|| "the state is not finite".to_string());
            return SurfaceOrbit {
                crossings: samples,
                end: OrbitEnd::NonFinite {
                    t: spec.time_of(step + 1),
                    why,
                },
            };
        }
        if (step + 1).is_multiple_of(every.steps) {
            seen += 1;
            if seen > skip {
                samples.push(Crossing {
                    t: spec.time_of(step + 1),
                    x: x.clone(),
                });
                if samples.len() >= max {
                    return SurfaceOrbit {
                        crossings: samples,
                        end: OrbitEnd::Crossings,
                    };
                }
            }
        }
    }
    SurfaceOrbit {
        crossings: samples,
        end: OrbitEnd::Horizon,
    }
}
