//! `[[scheme]]`: one renormalization scheme of a run.

use schemars::JsonSchema;
use serde::{Deserialize, Serialize};

/// One `[[scheme]]` table.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct SchemeConfig {
    pub name: String,
    /// `"vm"` or `"mpm"`.
    pub method: String,
    /// Norm of the deviation vectors after each renormalization.
    pub d0: f64,
    /// Renormalization period (a multiple of `h`); also the sample period.
    pub tau: f64,
    /// `"rescale"` (per-vector, for GALI/SALI) or `"qr"` (Lyapunov spectrum).
    #[serde(default = "default_orthonormalize")]
    pub orthonormalize: String,
    /// How a `vm` scheme evolves its sets: `"per-set"` (default, the reference: every set's
    /// `k` tangent vectors) or `"propagator"` (the `D` tangent vectors of a basis evolved over
    /// each renormalization window, the window's tangent propagator, applied to every set).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub route: Option<String>,
}

fn default_orthonormalize() -> String {
    "rescale".to_string()
}

impl SchemeConfig {
    /// A scheme with per-vector rescaling (the default `orthonormalize`).
    pub fn new(name: &str, method: &str, d0: f64, tau: f64) -> Self {
        Self {
            name: name.to_string(),
            method: method.to_string(),
            d0,
            tau,
            orthonormalize: default_orthonormalize(),
            route: None,
        }
    }

    /// The same scheme with `orthonormalize = how` (`"qr"` for the Lyapunov spectrum).
    pub fn with_orthonormalize(self, how: &str) -> Self {
        Self {
            orthonormalize: how.to_string(),
            ..self
        }
    }
}
