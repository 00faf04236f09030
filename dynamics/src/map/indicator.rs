//! The indicator of a map: what each deviation set accumulates at its renormalizations, when it
//! may stop, and how the sets' numbers make the point's value.

use chaoscope_schemas::config::{MAP_OWN_INDICATORS, MapConfig};

use chaoscope_indicators::indicator::{
    Output, SetIndicator, SetObservation, flowless_set_outputs, set_indicators,
};
use chaoscope_indicators::sali;

use super::point::{PointResult, PointStatus};
use crate::engine::RunError;
use crate::indicators::volume_log10;
use crate::spec::SpecError;

#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Indicator {
    /// `GALI_k` at `t_final`.
    Gali { k: usize },
    /// First renormalization time at which `GALI_k < threshold`; the set stops there.
    GaliTime { k: usize, threshold: f64 },
    /// log10 of the Smaller Alignment Index of the first two vectors at `t_final`.
    Sali,
    /// Finite-time maximal Lyapunov exponent at `t_final` (from the first vector of each set).
    Mle,
    /// The first `k` finite-time Lyapunov exponents at `t_final`: each set's vectors are
    /// renormalized by QR (validation asks the scheme for `orthonormalize = "qr"`), and
    /// `lambda_j` is the mean of `ln |R_jj|` per unit time.
    Spectrum { k: usize },
    /// An output of a registered set indicator (`chaoscope_indicators::indicator`) at
    /// `t_final`, by its name: `fli`, `megno`, `megno_mean`.
    Set { name: &'static str },
}

/// Every value `[map] indicator` takes: [`MAP_OWN_INDICATORS`] and the registered set indicators'
/// outputs that need nothing but the stretching factors and separations (OFLI needs the flow
/// direction at each point's reference state, which the map's kernels do not compute).
pub fn map_indicators() -> Vec<&'static str> {
    MAP_OWN_INDICATORS
        .into_iter()
        .chain(flowless_set_outputs())
        .collect()
}

impl Indicator {
    pub fn from_config(map: &MapConfig, k: usize) -> Result<Self, SpecError> {
        let need_k = |name: &str| {
            if k < 2 {
                Err(SpecError::new(
                    "map.k",
                    format!("{name} needs k >= 2 deviation vectors, got {k}"),
                ))
            } else {
                Ok(k)
            }
        };
        let ind = match map.indicator.as_str() {
            "gali" => Indicator::Gali { k: need_k("gali")? },
            "sali" => {
                need_k("sali")?;
                Indicator::Sali
            }
            "gali-time" => {
                let threshold = map.threshold.ok_or_else(|| {
                    SpecError::new("map.threshold", "gali-time needs a threshold")
                })?;
                if !(threshold.is_finite() && threshold > 0.0 && threshold < 1.0) {
                    return Err(SpecError::new(
                        "map.threshold",
                        format!("must be between 0 and 1, got {threshold}"),
                    ));
                }
                Indicator::GaliTime {
                    k: need_k("gali-time")?,
                    threshold,
                }
            }
            "mle" => Indicator::Mle,
            "spectrum" => Indicator::Spectrum { k },
            other => match flowless_set_outputs().into_iter().find(|n| *n == other) {
                Some(name) => Indicator::Set { name },
                None => {
                    return Err(SpecError::new(
                        "map.indicator",
                        format!("'{other}' is not {}", map_indicators().join(", ")),
                    ));
                }
            },
        };
        if map.threshold.is_some() && !matches!(ind, Indicator::GaliTime { .. }) {
            return Err(SpecError::new(
                "map.threshold",
                "only gali-time uses a threshold",
            ));
        }
        Ok(ind)
    }

    pub fn name(&self) -> &'static str {
        match self {
            Indicator::Gali { .. } => "gali",
            Indicator::GaliTime { .. } => "gali-time",
            Indicator::Sali => "sali",
            Indicator::Mle => "mle",
            Indicator::Spectrum { .. } => "spectrum",
            Indicator::Set { name } => name,
        }
    }

    pub fn threshold(&self) -> f64 {
        match self {
            Indicator::GaliTime { threshold, .. } => *threshold,
            _ => 0.0,
        }
    }
}

/// What one deviation set has accumulated.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct SetAccumulator {
    /// `sum ln(stretch of vector 1)` (for the MLE).
    log_sum: f64,
    /// The set's number once known (its final value, or its stopping time).
    value: Option<f64>,
    /// `sum ln |R_jj|` of each vector (`spectrum`), then its exponents at the end.
    log_sums: Vec<f64>,
}

/// Per-point bookkeeping shared by the batched and the one-orbit paths, so both form the result
/// with the very same operations.
#[derive(Debug, Clone)]
pub struct PointAccumulator {
    indicator: Indicator,
    dim: usize,
    t_final: f64,
    sets: Vec<SetAccumulator>,
    scratch: Vec<f64>,
    /// Latest stopping time of any set (for `t_end`).
    last_stop: f64,
    /// Per set, the registered set indicators and the time of its previous renormalization
    /// (`Indicator::Set` only).
    set_indicators: Vec<(Vec<Box<dyn SetIndicator>>, f64)>,
}

impl PointAccumulator {
    pub fn new(indicator: Indicator, dim: usize, sets: usize, t_final: f64) -> Self {
        Self {
            indicator,
            dim,
            t_final,
            sets: vec![
                SetAccumulator {
                    log_sums: match indicator {
                        Indicator::Spectrum { k } => vec![0.0; k],
                        _ => Vec::new(),
                    },
                    ..SetAccumulator::default()
                };
                sets
            ],
            scratch: Vec::new(),
            last_stop: 0.0,
            set_indicators: match indicator {
                Indicator::Set { .. } => vec![(set_indicators(), 0.0); sets],
                _ => Vec::new(),
            },
        }
    }

    /// The indicator reads the sets at every renormalization (`gali-time`, `mle`, `spectrum`,
    /// the set indicators), not only at the last one.
    pub fn observes_every_window(&self) -> bool {
        matches!(
            self.indicator,
            Indicator::GaliTime { .. }
                | Indicator::Mle
                | Indicator::Spectrum { .. }
                | Indicator::Set { .. }
        )
    }

    /// The stretching factors must be QR's `|R_jj|` (`spectrum`), not each vector's own.
    pub fn needs_qr(&self) -> bool {
        matches!(self.indicator, Indicator::Spectrum { .. })
    }

    pub fn is_stopped(&self, set: usize) -> bool {
        self.sets[set].value.is_some()
    }

    /// Every set has its number.
    pub fn is_done(&self) -> bool {
        self.sets.iter().all(|s| s.value.is_some())
    }

    /// One renormalization of `set` at time `t`: its separation vectors before renormalization
    /// and their stretching factors. `last` marks the final step of the run. Returns true when
    /// the set is finished (stopped early or at the end).
    pub fn observe(
        &mut self,
        set: usize,
        t: f64,
        separations: &[f64],
        stretch: &[f64],
        last: bool,
    ) -> bool {
        let acc = &mut self.sets[set];
        if acc.value.is_some() {
            return true;
        }
        match self.indicator {
            Indicator::Gali { k } => {
                if last {
                    acc.value = Some(volume_log10(separations, self.dim, k, &mut self.scratch));
                }
            }
            Indicator::GaliTime { k, threshold } => {
                let g = volume_log10(separations, self.dim, k, &mut self.scratch);
                if g < threshold.log10() {
                    acc.value = Some(t);
                    self.last_stop = self.last_stop.max(t);
                } else if last {
                    // Never crossed: censored at the horizon.
                    acc.value = Some(self.t_final);
                }
            }
            Indicator::Sali => {
                if last {
                    // Floored at eps like GALI's singular values: below it the two directions
                    // are not resolved in double precision (and log10 0 is no number).
                    let sali = sali(separations, self.dim).unwrap_or(0.0);
                    acc.value = Some(sali.max(f64::EPSILON).log10());
                }
            }
            Indicator::Mle => {
                acc.log_sum += stretch[0].ln();
                if last {
                    acc.value = Some(acc.log_sum / t);
                }
            }
            Indicator::Spectrum { .. } => {
                for (sum, s) in acc.log_sums.iter_mut().zip(stretch) {
                    *sum += s.ln();
                }
                if last {
                    acc.log_sums.iter_mut().for_each(|sum| *sum /= t);
                    acc.value = Some(acc.log_sums[0]);
                }
            }
            Indicator::Set { name } => {
                let (indicators, previous) = &mut self.set_indicators[set];
                let observation = SetObservation {
                    t,
                    dt: t - *previous,
                    dim: self.dim,
                    separations,
                    stretch,
                    flow: None,
                    // The map indicators are the outputs that need no sites either.
                    sites: None,
                    site_energies: None,
                };
                *previous = t;
                for i in indicators.iter_mut() {
                    i.observe(&observation);
                }
                if last {
                    acc.value = indicators
                        .iter()
                        .flat_map(|i| i.names().iter().copied().zip(i.outputs()))
                        .find_map(|(n, o)| match o {
                            Output::Value(v) if n == name => Some(v),
                            _ => None,
                        });
                }
            }
        }
        if last {
            self.last_stop = self.t_final;
        }
        acc.value.is_some()
    }

    /// The point's result (status `Ok`) after `orbit_steps` orbit-steps of work; every set must
    /// be finished.
    pub fn finish(&self, base: PointResult, orbit_steps: u64) -> PointResult {
        let per_set: Vec<f64> = self
            .sets
            .iter()
            .map(|s| s.value.expect("every set finished"))
            .collect();
        let m = per_set.len() as f64;
        let (value, mean_log10) = match self.indicator {
            Indicator::Gali { .. } | Indicator::Sali => (
                per_set.iter().map(|g| 10f64.powf(*g)).sum::<f64>() / m,
                per_set.iter().sum::<f64>() / m,
            ),
            _ => (per_set.iter().sum::<f64>() / m, 0.0),
        };
        // lambda_j averaged over the sets, in the sets' order (as `value` is).
        let spectrum = match self.indicator {
            Indicator::Spectrum { k } => (0..k)
                .map(|j| self.sets.iter().map(|s| s.log_sums[j]).sum::<f64>() / m)
                .collect(),
            _ => Vec::new(),
        };
        PointResult {
            status: PointStatus::Ok,
            value,
            per_set,
            mean_log10,
            spectrum,
            t_end: self.last_stop,
            orbit_steps,
            reason: String::new(),
            ..base
        }
    }
}

/// A point that was not integrated to a value.
pub fn failed(base: PointResult, status: PointStatus, t_end: f64, reason: String) -> PointResult {
    PointResult {
        status,
        value: f64::NAN,
        per_set: Vec::new(),
        mean_log10: 0.0,
        spectrum: Vec::new(),
        t_end,
        reason,
        ..base
    }
}

/// A point whose integration broke off at `t` (an orbit escaped or a renormalization failed),
/// after `orbit_steps` orbit-steps of work.
pub fn broke_off(base: PointResult, t: f64, error: &RunError, orbit_steps: u64) -> PointResult {
    PointResult {
        orbit_steps,
        ..failed(base, PointStatus::Escaped, t, error.to_string())
    }
}
