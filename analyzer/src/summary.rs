//! The end-of-run summary printed by `chaoscope run`: per scheme and set, the final GALI_k, SALI
//! and maximal Lyapunov exponent, read back from the recording.
//!
//! Deliberately small; the full analysis (time series, thresholds, plots) grows elsewhere in this
//! crate.

use std::collections::BTreeMap;
use std::fmt;
use std::path::Path;

use chaoscope_producer::indicators::{self, StretchSums};
use chaoscope_schemas::names::topic;
use chaoscope_schemas::proto::{EndOfRun, RecordingSummary, RunHeader, SeparationSet};
use prost::Message;

/// Final indicators of one (scheme, set).
#[derive(Debug, Clone, PartialEq)]
pub struct SetSummary {
    pub scheme: String,
    pub set: u32,
    pub t: f64,
    /// log10 GALI_k of the last sample (k = number of vectors); `None` if k < 2 or the
    /// vectors are malformed.
    pub gali_k_log10: Option<f64>,
    pub sali: Option<f64>,
    pub mle: f64,
}

#[derive(Debug, Clone, Default)]
pub struct RunSummary {
    pub run_name: String,
    pub model: String,
    pub samples: u64,
    pub run_status: String,
    pub finalized_by: String,
    pub frames_missing: u64,
    pub sets: Vec<SetSummary>,
}

#[derive(Debug, thiserror::Error)]
pub enum SummaryError {
    #[error("{path}: {source}")]
    Io {
        path: String,
        source: std::io::Error,
    },
    #[error("{path}: not a readable MCAP file: {source}")]
    Mcap {
        path: String,
        source: mcap::McapError,
    },
    #[error("{path}: message on {topic} is not valid protobuf: {source}")]
    Decode {
        path: String,
        topic: String,
        source: prost::DecodeError,
    },
    #[error("{path}: no run header; is it a chaoscope recording?")]
    NoHeader { path: String },
}

struct Accumulator {
    last: SeparationSet,
    stretch: StretchSums,
}

/// Reads a recording and computes its summary.
pub fn summarize(path: &Path) -> Result<RunSummary, SummaryError> {
    let p = path.display().to_string();
    let bytes = std::fs::read(path).map_err(|source| SummaryError::Io {
        path: p.clone(),
        source,
    })?;
    let mut header: Option<RunHeader> = None;
    let mut summary = RunSummary::default();
    let mut sets: BTreeMap<(u32, u32), Accumulator> = BTreeMap::new();
    let stream = mcap::MessageStream::new(&bytes).map_err(|source| SummaryError::Mcap {
        path: p.clone(),
        source,
    })?;
    for message in stream {
        let message = message.map_err(|source| SummaryError::Mcap {
            path: p.clone(),
            source,
        })?;
        let topic_name = message.channel.topic.as_str();
        let decode_err = |source| SummaryError::Decode {
            path: p.clone(),
            topic: topic_name.to_string(),
            source,
        };
        match topic_name {
            topic::RUN => header = Some(RunHeader::decode(&message.data[..]).map_err(decode_err)?),
            topic::END => {
                summary.samples = EndOfRun::decode(&message.data[..])
                    .map_err(decode_err)?
                    .samples
            }
            topic::RECORDING => {
                let r = RecordingSummary::decode(&message.data[..]).map_err(decode_err)?;
                summary.run_status = r.run_status;
                summary.finalized_by = r.finalized_by;
                summary.frames_missing = r.frames_missing;
            }
            t if t.starts_with("/chaoscope/separations/") => {
                let s = SeparationSet::decode(&message.data[..]).map_err(decode_err)?;
                let acc = sets
                    .entry((s.scheme, s.set))
                    .or_insert_with(|| Accumulator {
                        last: s.clone(),
                        stretch: StretchSums::new(s.k as usize),
                    });
                acc.stretch.add(&s.stretch);
                acc.last = s;
            }
            _ => {}
        }
    }
    let header = header.ok_or(SummaryError::NoHeader { path: p })?;
    summary.run_name = header.run_name.clone();
    summary.model = header.model.clone();
    for ((scheme, set), acc) in sets {
        let dim = acc.last.dim.max(1) as usize;
        let v = &acc.last.separations;
        // A hostile or damaged file must not crash the summary.
        let well_formed = v.len() >= 2 * dim && v.len() % dim == 0;
        let gali = if well_formed {
            indicators::gali_log10(v, dim).last().copied()
        } else {
            None
        };
        summary.sets.push(SetSummary {
            scheme: header
                .schemes
                .get(scheme as usize)
                .map(|s| s.name.clone())
                .unwrap_or_else(|| scheme.to_string()),
            set,
            t: acc.last.t,
            gali_k_log10: gali,
            sali: well_formed.then(|| indicators::sali(v, dim)).flatten(),
            mle: acc.stretch.mle(acc.last.t),
        });
    }
    Ok(summary)
}

impl fmt::Display for RunSummary {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        writeln!(
            f,
            "run {} ({}): {} samples, status {}, finalized by {}, {} frames missing",
            self.run_name,
            self.model,
            self.samples,
            self.run_status,
            self.finalized_by,
            self.frames_missing
        )?;
        writeln!(
            f,
            "{:<12} {:>4} {:>10} {:>14} {:>12} {:>12}",
            "scheme", "set", "t", "log10 GALI_k", "SALI", "MLE"
        )?;
        for s in &self.sets {
            let gali = s.gali_k_log10.map_or("n/a".into(), |g| format!("{g:.4}"));
            let sali = s.sali.map_or("n/a".into(), |v| format!("{v:.4e}"));
            writeln!(
                f,
                "{:<12} {:>4} {:>10.2} {:>14} {:>12} {:>12.6}",
                s.scheme, s.set, s.t, gali, sali, s.mle
            )?;
        }
        Ok(())
    }
}
