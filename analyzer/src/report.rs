//! The analysis results as data: what `analyze --json` prints and `monitor --json-lines`
//! streams. Field names are a public contract (scripts read them).

use serde::ser::SerializeMap;
use serde::{Serialize, Serializer};

use chaoscope_indicators::NamedOutputs;

use crate::stats::LogStat;
use crate::verdict::{Verdict, Warning};

/// Values keyed by GALI order, serialized as a JSON object `{"2": ..., "3": ...}` in order.
#[derive(Debug, Clone, PartialEq)]
pub struct ByOrder<V>(pub Vec<(usize, V)>);

impl<V> ByOrder<V> {
    pub fn get(&self, j: usize) -> Option<&V> {
        self.0.iter().find(|(o, _)| *o == j).map(|(_, v)| v)
    }
}

impl<V: Serialize> Serialize for ByOrder<V> {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        let mut m = s.serialize_map(Some(self.0.len()))?;
        for (j, v) in &self.0 {
            m.serialize_entry(&j.to_string(), v)?;
        }
        m.end()
    }
}

/// The run as a whole.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct RunReport {
    pub name: String,
    pub model: String,
    /// `"hamiltonian"`, `"flow"` or `"map"`.
    pub kind: String,
    /// `"continuous"` or `"discrete"` (t counts iterations).
    pub time: String,
    /// Degrees of freedom N of a Hamiltonian (phase space has 2N dimensions); 0 otherwise.
    pub n: usize,
    /// Dimension D of the state.
    pub dim: usize,
    pub k: usize,
    pub sets: usize,
    pub integrator: String,
    pub h: f64,
    pub t_final: f64,
    pub total_steps: u64,
    pub seed: u64,
    pub energy0: f64,
    /// Samples analyzed (renormalization times, including t = 0).
    pub samples: u64,
    /// Time of the latest sample analyzed.
    pub t: f64,
    /// Largest relative energy error `|E - E0| / |E0|` of the reference orbit so far
    /// (Hamiltonians only: absent for systems without an energy).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub energy_error_max: Option<f64>,
    /// The initial norm `S = sum_l (q_l^2 + p_l^2)/2` of a model that conserves it beside the
    /// energy (`ddnls`); absent for every other.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub norm0: Option<f64>,
    /// Largest relative error `|S - S0| / S0` of that norm over the reference orbit's samples;
    /// absent where `norm0` is.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub norm_error_max: Option<f64>,
    /// For a model that conserves a norm whose `E0` is near zero against it
    /// (`|E0| < 1.5e-8 S0`), where a relative error only divides by a rounding: the largest
    /// energy error as a fraction of the norm, `max |E - E0| / S0`, by which the warnings judge
    /// it ([`crate::verdict::energy_error_of_norm`]); absent for every other run.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub energy_error_of_norm: Option<f64>,
    /// Phase-space contraction rate: the mean of `div f` along the reference orbit from t = 0
    /// (flows), the mean of `ln |det DF|` per iteration (maps); compare with the sum of the
    /// Lyapunov exponents of a QR scheme with k = D (`lyapunov_sum`). Absent for Hamiltonians,
    /// whose volume is conserved.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub mean_divergence: Option<f64>,
    /// True when every stretching factor from t = 0 on was seen (always for a complete
    /// recording; a live monitor that attached late or lost frames reports false, and its
    /// Lyapunov exponents are then averages over the intervals it saw).
    pub complete: bool,
    /// How the producer ended the run, when the recording holds its last message (`analyze` of
    /// a file; absent live and for files cut before the end).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub end: Option<EndReport>,
    /// `--from T`: the finite-time exponents (`mle`, `lyapunov`, `lyapunov_sum`, the MPM-VM
    /// `mle_delta`) average the stretching from this time on (T on the step grid); absent
    /// when they cover the whole run. Nothing else depends on it: the verdict judges the
    /// whole run.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub exponents_from: Option<f64>,
}

/// The producer's last message: `status` is `"completed"`, `"interrupted"` or `"failed"`;
/// `reason` says why a run did not complete (a failed orbit names its time or iteration).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct EndReport {
    pub status: String,
    pub reason: String,
    /// Samples the producer published.
    pub samples: u64,
    /// Time of the last sample published.
    pub t: f64,
}

impl EndReport {
    pub fn from_message(end: &chaoscope_schemas::proto::EndOfRun) -> Self {
        use chaoscope_schemas::proto::end_of_run::Status;
        let status = match Status::try_from(end.status).unwrap_or(Status::Unspecified) {
            Status::Completed => "completed",
            Status::Interrupted => "interrupted",
            Status::Failed => "failed",
            Status::Unspecified => "unspecified",
        };
        Self {
            status: status.to_string(),
            reason: end.reason.clone(),
            samples: end.samples,
            t: if end.t.is_finite() { end.t } else { 0.0 },
        }
    }
}

/// Difference of an MPM scheme from the VM scheme with the same `tau`, over the sets both have
/// at the same time (same initial directions, so set by set).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct VsVm {
    pub scheme: String,
    pub t: f64,
    pub sets: usize,
    /// Per order: mean over sets of `log10 GALI_mpm - log10 GALI_vm`, and of its absolute value.
    pub gali: ByOrder<DeltaLog>,
    /// `MLE_mpm - MLE_vm`, mean over sets.
    pub mle_delta: f64,
}

#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct DeltaLog {
    pub mean_delta_log10: f64,
    pub mean_abs_delta_log10: f64,
}

/// One scheme, averaged over its sets.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct SchemeReport {
    pub name: String,
    pub method: String,
    pub orthonormalize: String,
    pub k: usize,
    pub d0: f64,
    pub tau: f64,
    /// Sets contributing to the values (all of them unless frames were lost).
    pub sets: usize,
    /// Time of the scheme's latest renormalization.
    pub t: f64,
    /// GALI_j, j = 2..k, over sets: `mean` (arithmetic), `log10_mean` (geometric), spread.
    pub gali: ByOrder<LogStat>,
    pub sali: Option<LogStat>,
    /// Finite-time maximal Lyapunov exponent, mean over sets.
    pub mle: f64,
    /// Finite-time exponents, mean over sets: the spectrum lambda_1..lambda_k for QR schemes;
    /// for rescaled schemes only the MLE (the first vector's growth rate: the other vectors'
    /// rates are each an estimate of the MLE, not a spectrum; the CSV names them
    /// `growth_rate1..k`).
    pub lyapunov: Vec<f64>,
    pub lyapunov_std: Vec<f64>,
    /// Sum of the spectrum of a QR scheme with k = D: the rate of phase-space volume change the
    /// exponents measure (compare `run.mean_divergence`). Absent otherwise.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub lyapunov_sum: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub energy_error_max: Option<f64>,
    /// As `run.norm_error_max`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub norm_error_max: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub vs_vm: Option<VsVm>,
    /// Every registered indicator's outputs by name, as fields of the scheme: `fli`, `ofli`,
    /// `megno`, `megno_mean` (mean and spread over the sets, `{"mean", "std"}`) and
    /// `zero_one_k` (one value: the 0-1 test on an observable of the reference orbit, the
    /// generic one or `[analysis] zero_one_observable`, sampled at the scheme's
    /// renormalizations); `{"unavailable": reason}` where the run does not give what an
    /// indicator needs (for the 0-1 test also a series too short, with the length it needs).
    #[serde(flatten)]
    pub indicators: NamedOutputs,
    /// `class`: `chaotic`, `regular` (with `torus_dimension`), `attracting` (the largest
    /// exponent negative: a stable fixed point or cycle), `escaped`, `failed` (the integrator
    /// stopped; `time` of its failed step) or `unbounded` (with `time`), or `undecided` (with
    /// `reason`) at this time, with the `criterion` in words and a `confidence`.
    pub verdict: Verdict,
    /// Settings or values outside the region where the indicators are reliable.
    pub warnings: Vec<Warning>,
}

/// Everything, at one time.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Report {
    pub run: RunReport,
    pub schemes: Vec<SchemeReport>,
}

impl Report {
    pub fn scheme(&self, name: &str) -> Option<&SchemeReport> {
        self.schemes.iter().find(|s| s.name == name)
    }
}
