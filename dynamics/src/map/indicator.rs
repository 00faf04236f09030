//! The indicator of a map: what each deviation set accumulates at its renormalizations, when it
//! may stop, and how the sets' numbers make the point's value.

use chaoscope_schemas::config::MapConfig;

use chaoscope_indicators::indicator::{
    Declared, GALI_TIME, Output, SetIndicator, SetObservation, map_indicators, set_indicator_of,
};

use super::point::{PointResult, PointStatus};
use crate::engine::RunError;
use crate::indicators::volume_log10;
use crate::spec::SpecError;

/// `[map] indicator`: an output of a registered set indicator (`chaoscope_indicators::indicator`)
/// at `t_final`, or the map's own stopping rule on GALI.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Indicator {
    /// The output `declared` of a registered set indicator (`gali`, `sali`, `mle`, `spectrum`,
    /// `fli`, `megno`, ...), at output `at` of it, each set's value read at `t_final`.
    Registered { declared: Declared, at: usize },
    /// First renormalization time at which `GALI_k < threshold`; the set stops there.
    GaliTime { k: usize, threshold: f64 },
}

impl Indicator {
    pub fn from_config(map: &MapConfig, k: usize) -> Result<Self, SpecError> {
        let name = map.indicator.as_str();
        let unknown = || {
            SpecError::new(
                "map.indicator",
                format!("'{name}' is not {}", map_indicators().join(", ")),
            )
        };
        let (needs, ind) = if name == GALI_TIME {
            let threshold = map
                .threshold
                .ok_or_else(|| SpecError::new("map.threshold", "gali-time needs a threshold"))?;
            if !(threshold.is_finite() && threshold > 0.0 && threshold < 1.0) {
                return Err(SpecError::new(
                    "map.threshold",
                    format!("must be between 0 and 1, got {threshold}"),
                ));
            }
            let (_, gali, _) = set_indicator_of("gali").expect("GALI is registered");
            (gali.needs, Indicator::GaliTime { k, threshold })
        } else {
            let (_, declared, at) = set_indicator_of(name)
                .filter(|(_, d, _)| d.on_maps())
                .ok_or_else(unknown)?;
            (declared.needs, Indicator::Registered { declared, at })
        };
        if k < needs.vectors {
            return Err(SpecError::new(
                "map.k",
                format!(
                    "{name} needs k >= {} deviation vectors, got {k}",
                    needs.vectors
                ),
            ));
        }
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
            Indicator::Registered { declared, .. } => declared.name,
            Indicator::GaliTime { .. } => GALI_TIME,
        }
    }

    pub fn threshold(&self) -> f64 {
        match self {
            Indicator::GaliTime { threshold, .. } => *threshold,
            Indicator::Registered { .. } => 0.0,
        }
    }

    /// The stretching factors must be QR's `|R_jj|` (`spectrum`), not each vector's own.
    pub fn needs_qr(&self) -> bool {
        matches!(self, Indicator::Registered { declared, .. } if declared.needs.qr)
    }
}

/// Per-point bookkeeping shared by the batched and the one-orbit paths, so both form the result
/// with the very same operations.
#[derive(Debug, Clone)]
pub struct PointAccumulator {
    indicator: Indicator,
    dim: usize,
    t_final: f64,
    /// Per set: its number once known (its final value, or its stopping time).
    values: Vec<Option<f64>>,
    scratch: Vec<f64>,
    /// Latest stopping time of any set (for `t_end`).
    last_stop: f64,
    /// Per set, the registered indicator and the time of its previous renormalization
    /// (`Indicator::Registered` only).
    set_indicators: Vec<(Box<dyn SetIndicator>, f64)>,
}

impl PointAccumulator {
    pub fn new(indicator: Indicator, dim: usize, sets: usize, t_final: f64) -> Self {
        let set_indicators = match indicator {
            Indicator::Registered { declared, .. } => {
                let (one, _, _) = set_indicator_of(declared.name).expect("validated");
                vec![(one, 0.0); sets]
            }
            Indicator::GaliTime { .. } => Vec::new(),
        };
        Self {
            indicator,
            dim,
            t_final,
            values: vec![None; sets],
            scratch: Vec::new(),
            last_stop: 0.0,
            set_indicators,
        }
    }

    /// The indicator reads the sets at every renormalization, not only at the last one.
    pub fn observes_every_window(&self) -> bool {
        match self.indicator {
            Indicator::Registered { declared, .. } => declared.needs.every_renormalization,
            Indicator::GaliTime { .. } => true,
        }
    }

    /// The stretching factors must be QR's `|R_jj|` (`spectrum`), not each vector's own.
    pub fn needs_qr(&self) -> bool {
        self.indicator.needs_qr()
    }

    pub fn is_stopped(&self, set: usize) -> bool {
        self.values[set].is_some()
    }

    /// Every set has its number.
    pub fn is_done(&self) -> bool {
        self.values.iter().all(Option::is_some)
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
        if self.values[set].is_some() {
            return true;
        }
        match self.indicator {
            Indicator::GaliTime { k, threshold } => {
                let g = volume_log10(separations, self.dim, k, &mut self.scratch);
                if g < threshold.log10() {
                    self.values[set] = Some(t);
                    self.last_stop = self.last_stop.max(t);
                } else if last {
                    // Never crossed: censored at the horizon.
                    self.values[set] = Some(self.t_final);
                }
            }
            Indicator::Registered { declared, at } => {
                let (indicator, previous) = &mut self.set_indicators[set];
                // An output of the vectors at the end reads them once, not every window.
                if last || declared.needs.every_renormalization {
                    indicator.observe(&SetObservation {
                        t,
                        dt: t - *previous,
                        // A map sees every renormalization of its sets.
                        covered: t,
                        dim: self.dim,
                        separations,
                        stretch,
                        // A map's outputs need no flow direction and no sites (`on_maps`).
                        flow: None,
                        sites: None,
                        square_side: None,
                        periodic: [false; 2],
                        norm_conserved: false,
                        state: None,
                        site_energies: None,
                    });
                    *previous = t;
                }
                if last {
                    self.values[set] = match indicator.outputs().swap_remove(at) {
                        Output::Value(v) => Some(v),
                        Output::Unavailable(_) => None,
                    };
                }
            }
        }
        if last {
            self.last_stop = self.t_final;
        }
        self.values[set].is_some()
    }

    /// The point's result (status `Ok`) after `orbit_steps` orbit-steps of work; every set must
    /// be finished.
    pub fn finish(&self, base: PointResult, orbit_steps: u64) -> PointResult {
        let per_set: Vec<f64> = self
            .values
            .iter()
            .map(|v| v.expect("every set finished"))
            .collect();
        let m = per_set.len() as f64;
        let declared = match self.indicator {
            Indicator::Registered { declared, .. } => Some(declared),
            Indicator::GaliTime { .. } => None,
        };
        let (value, mean_log10) = if declared.is_some_and(|d| d.log10) {
            (
                per_set.iter().map(|g| 10f64.powf(*g)).sum::<f64>() / m,
                per_set.iter().sum::<f64>() / m,
            )
        } else {
            (per_set.iter().sum::<f64>() / m, 0.0)
        };
        // The per-vector values (lambda_j) averaged over the sets, in the sets' order (as
        // `value` is).
        let spectrum = if declared.is_some_and(|d| d.per_vector) {
            let per_vector: Vec<Vec<f64>> = self
                .set_indicators
                .iter()
                .map(|(i, _)| i.per_vector())
                .collect();
            (0..per_vector[0].len())
                .map(|j| per_vector.iter().map(|s| s[j]).sum::<f64>() / m)
                .collect()
        } else {
            Vec::new()
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
