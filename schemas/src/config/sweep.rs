//! Sweeps: one `[[sweep]]` table expands into many `[[scheme]]`s, e.g. every `d0` from 1e-14 to
//! 1e-2 per decade times several `tau`, all around the same reference orbit and the same sets of
//! initial directions.
//!
//! ```toml
//! [[sweep]]
//! name = "mpm"                                        # prefix of the scheme names
//! method = "mpm"
//! d0 = { from = 1e-14, to = 1e-2, per_decade = 1 }    # log-spaced, ends included
//! tau = [0.1, 1.0, 10.0]                              # or a single number, or a range
//! orthonormalize = "rescale"
//! ```
//!
//! A pure transformation of the configuration; the expanded schemes are validated like any
//! other (`RunSpec::from_config` applies the expansion first).

use schemars::JsonSchema;
use serde::{Deserialize, Serialize};

use super::scheme::SchemeConfig;

/// Values of one swept parameter.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(untagged)]
pub enum Values {
    One(f64),
    List(Vec<f64>),
    Range(Range),
}

/// `from` to `to` inclusive, either `per_decade` log-spaced values or `count` evenly spaced.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct Range {
    pub from: f64,
    pub to: f64,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub per_decade: Option<u32>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub count: Option<u32>,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct SweepConfig {
    /// Prefix of the generated scheme names (`<name>-d0<d0>-tau<tau>`); default: the method.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub name: Option<String>,
    pub method: String,
    pub d0: Values,
    pub tau: Values,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub orthonormalize: Option<String>,
}

/// A sweep that cannot be expanded, naming the key.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{key}: {message}")]
pub struct SweepError {
    pub key: String,
    pub message: String,
}

/// More schemes than this from one config is surely a typo (each scheme x set is a task).
pub const MAX_SWEEP_SCHEMES: usize = 10_000;

/// Rounds to 12 significant digits, so `1e-14 * 10^(6/1)` prints and compares as `1e-8`.
fn clean(v: f64) -> f64 {
    format!("{v:.11e}").parse().unwrap_or(v)
}

impl Values {
    /// The values in order; `key` names the parameter in errors.
    pub fn expand(&self, key: &str) -> Result<Vec<f64>, SweepError> {
        let err = |message: String| SweepError {
            key: key.to_string(),
            message,
        };
        let values = match self {
            Values::One(v) => vec![*v],
            Values::List(v) if v.is_empty() => return Err(err("an empty list".into())),
            Values::List(v) => v.clone(),
            Values::Range(r) => {
                if !(r.from.is_finite() && r.to.is_finite() && r.from > 0.0 && r.to >= r.from) {
                    return Err(err(format!(
                        "range needs 0 < from <= to, got from = {}, to = {}",
                        r.from, r.to
                    )));
                }
                match (r.per_decade, r.count) {
                    (Some(pd), None) if pd > 0 => {
                        let decades = r.to.log10() - r.from.log10();
                        let n = (decades * pd as f64 + 1e-9).floor();
                        if n + 1.0 > MAX_SWEEP_SCHEMES as f64 {
                            return Err(err(format!("{} values are too many", n + 1.0)));
                        }
                        let n = n as usize;
                        let lo = r.from.log10();
                        (0..=n)
                            .map(|i| clean(10f64.powf(lo + i as f64 / pd as f64)))
                            .collect()
                    }
                    (None, Some(c)) if c >= 2 => {
                        if c as usize > MAX_SWEEP_SCHEMES {
                            return Err(err(format!("{c} values are too many")));
                        }
                        let c = c as usize;
                        (0..c)
                            .map(|i| clean(r.from + (r.to - r.from) * i as f64 / (c - 1) as f64))
                            .collect()
                    }
                    _ => {
                        return Err(err(
                            "range needs exactly one of per_decade >= 1 or count >= 2".into(),
                        ));
                    }
                }
            }
        };
        if let Some(v) = values.iter().find(|v| !(v.is_finite() && **v > 0.0)) {
            return Err(err(format!("{v} is not a finite positive number")));
        }
        Ok(values)
    }
}

/// Compact number for a scheme name: `1e-8`, `0.1`, `10`.
fn short(v: f64) -> String {
    let plain = format!("{v}");
    let sci = format!("{v:e}");
    if plain.len() <= sci.len() { plain } else { sci }
}

impl SweepConfig {
    /// The schemes of this sweep: every `tau` times every `d0`.
    pub fn expand(&self, index: usize) -> Result<Vec<SchemeConfig>, SweepError> {
        let key = |k: &str| format!("sweep[{index}].{k}");
        let d0s = self.d0.expand(&key("d0"))?;
        let taus = self.tau.expand(&key("tau"))?;
        if d0s.len() * taus.len() > MAX_SWEEP_SCHEMES {
            return Err(SweepError {
                key: key("d0"),
                message: format!(
                    "{} x {} schemes exceed the limit of {MAX_SWEEP_SCHEMES}",
                    d0s.len(),
                    taus.len()
                ),
            });
        }
        let prefix = self.name.clone().unwrap_or_else(|| self.method.clone());
        let mut out = Vec::with_capacity(d0s.len() * taus.len());
        for &tau in &taus {
            for &d0 in &d0s {
                out.push(SchemeConfig {
                    name: format!("{prefix}-d0{}-tau{}", short(d0), short(tau)),
                    method: self.method.clone(),
                    d0,
                    tau,
                    orthonormalize: self
                        .orthonormalize
                        .clone()
                        .unwrap_or_else(|| "rescale".into()),
                    route: None,
                });
            }
        }
        Ok(out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn two_per_decade_and_linear_counts() {
        let v = Values::Range(Range {
            from: 1e-4,
            to: 1e-2,
            per_decade: Some(2),
            count: None,
        })
        .expand("x")
        .unwrap();
        assert_eq!(v.len(), 5);
        assert_eq!((v[0], v[2], v[4]), (1e-4, 1e-3, 1e-2));
        assert!((v[1] - 10f64.powf(-3.5)).abs() < 1e-15);
        let v = Values::Range(Range {
            from: 0.5,
            to: 2.0,
            per_decade: None,
            count: Some(4),
        })
        .expand("x")
        .unwrap();
        assert_eq!(v, vec![0.5, 1.0, 1.5, 2.0]);
    }
}
