//! The end-of-run summary printed by `chaoscope run`: per scheme and set, the final GALI_k, SALI
//! and maximal Lyapunov exponent, read back from the recording.
//!
//! A thin view of the streaming analysis core ([`crate::analysis`]), per set.

use std::fmt;
use std::path::Path;

use crate::analysis::AnalysisOptions;
use crate::recording::analyze_file;

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

/// A recording that could not be summarized.
pub type SummaryError = crate::recording::ReadError;

/// Reads a recording (streaming, through the analysis core) and computes its summary.
pub fn summarize(path: &Path) -> Result<RunSummary, SummaryError> {
    let (analysis, info) = analyze_file(path, &AnalysisOptions::default())?;
    let run = analysis.run();
    let mut summary = RunSummary {
        run_name: run.header.run_name.clone(),
        model: run.header.model.clone(),
        samples: info.end.as_ref().map_or(analysis.samples(), |e| e.samples),
        ..Default::default()
    };
    if let Some(r) = &info.summary {
        summary.run_status = r.run_status.clone();
        summary.finalized_by = r.finalized_by.clone();
        summary.frames_missing = r.frames_missing;
    }
    for (si, scheme) in run.schemes.iter().enumerate() {
        let alignment = crate::plot::alignment_meaningful(scheme.orthonormalize, run.k);
        for set in 0..run.sets {
            let Some(v) = analysis.set_values(si, set) else {
                continue;
            };
            summary.sets.push(SetSummary {
                scheme: scheme.name.clone(),
                set: set as u32,
                t: v.t,
                // GALI and SALI of a QR scheme (orthonormal vectors: 1 and sqrt 2 by
                // construction) or of a single vector say nothing about the orbit: `n/a`.
                gali_k_log10: v.gali_log10.last().copied().filter(|_| alignment),
                sali: v.sali.filter(|_| alignment),
                mle: v.exponents.first().copied().unwrap_or(0.0),
            });
        }
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
