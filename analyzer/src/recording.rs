//! Streaming reader of chaoscope MCAP recordings: messages are decoded one at a time from a
//! buffered file, so memory does not depend on the size of the file.
//!
//! The file is read through the recorder's damage-tolerant scanner ([`chaoscope_files::scan`]):
//! each chunk is checked whole before any of its messages is used, and a damaged or truncated
//! file is an error naming the file and where and why it is damaged, after the messages before
//! the damage (an analysis is of a whole recording or of none).

use std::fs::File;
use std::io::BufReader;
use std::path::{Path, PathBuf};

use chaoscope_files::scan::{self, FileError, Messages, Scanner};

use chaoscope_schemas::names::topic;
use chaoscope_schemas::proto::DataMessage;
use chaoscope_schemas::proto::{
    EndOfRun, RecordingSummary, ReferenceState, RunHeader, SeparationSet,
};
use chaoscope_schemas::run::Sample;
use prost::Message;

use crate::analysis::{Analysis, AnalysisOptions};
use crate::assemble::SampleAssembler;
use crate::run_info::{HeaderError, RunInfo};

#[derive(Debug, thiserror::Error)]
pub enum ReadError {
    #[error(transparent)]
    File(#[from] FileError),
    #[error(
        "{path} is damaged or truncated: {why} (`chaoscope recover` salvages the complete \
         chunks before the damage)"
    )]
    Damaged { path: PathBuf, why: String },
    #[error("{path}: message on {topic} is not valid protobuf: {error}")]
    Decode {
        path: PathBuf,
        topic: String,
        error: prost::DecodeError,
    },
    /// A value no producer writes (a time or energy that is not finite, a stretching factor of
    /// zero, a size or index beyond the header's): refused rather than used to index or
    /// allocate, or carried into outputs as NaN or infinity.
    #[error("{path}: message on {topic} holds {what}, which no producer writes")]
    Value {
        path: PathBuf,
        topic: String,
        what: String,
    },
    #[error("{path}: no run header; is it a chaoscope recording?")]
    NoHeader { path: PathBuf },
    // Not named `source`: the message already holds it (an error chain would print it twice).
    #[error("{path}: {header}")]
    Header { path: PathBuf, header: HeaderError },
    /// An analysis option that does not fit this run (`--from T` past its end).
    #[error("{path}: {why}")]
    Option { path: PathBuf, why: String },
}

/// What a recording holds besides its samples.
#[derive(Debug, Clone, Default)]
pub struct RecordingInfo {
    pub end: Option<EndOfRun>,
    /// Where and why a reader opened with [`RecordingReader::open_salvaging`] stopped before the
    /// end of the file (a killed writer's cut chunk, damage); `None` if it read the whole file.
    pub damage: Option<String>,
    pub summary: Option<RecordingSummary>,
    /// File bytes read.
    pub bytes: u64,
}

/// An open recording, positioned after its run header (checked: [`RunInfo::from_header`]).
pub struct RecordingReader {
    path: PathBuf,
    messages: Messages<BufReader<File>>,
    run: RunInfo,
    assembler: SampleAssembler,
    /// Damage ends the file instead of failing ([`RecordingReader::open_salvaging`]).
    salvaging: bool,
    /// What the values read so far allow next ([`SampleCheck`]).
    check: SampleCheck,
    pub info: RecordingInfo,
}

/// What every message of a recording must agree with, besides being finite: sizes and
/// indices within the header's, times those of their steps, steps and sample numbers that
/// increase, and samples as a producer publishes them (a reference state, then each set of
/// every scheme renormalizing at that step, once; only the file's last sample may be cut
/// short). Checked before a value is used, so that a valid file holding values no producer
/// writes is refused naming the field, instead of indexing out of bounds, allocating what a
/// count claims (readers size their outputs by the header's sets) or printing NaN.
#[derive(Debug, Default)]
struct SampleCheck {
    /// Sample number and step of the latest reference state.
    sample: Option<(u64, u64)>,
    /// Step of the sample before it (the renormalizations in between are a sample's earlier
    /// stretching factors).
    previous_step: u64,
    /// (scheme, set) pairs of the current sample's separation sets.
    seen: std::collections::BTreeSet<(u32, u32)>,
}

impl SampleCheck {
    /// `t` is the time of `step` (as the producer computes it: `step * h`, never accumulated).
    fn time(run: &RunInfo, step: u64, t: f64) -> Result<(), String> {
        let expected = run.time_of(step);
        // A relative slack of a few ulps, for writers that compute it another way.
        if t.is_finite() && (t - expected).abs() <= 4.0 * f64::EPSILON * expected.abs() {
            Ok(())
        } else {
            Err(format!(
                "t = {t:?}, but step {step} with h = {:?} is at t = {expected:?}",
                run.h
            ))
        }
    }

    fn finite(field: &str, values: &[f64]) -> Result<(), String> {
        match values.iter().position(|v| !v.is_finite()) {
            Some(i) => Err(format!("{field}[{i}] = {:?}", values[i])),
            None => Ok(()),
        }
    }

    /// The separation sets sample `seq` at `step` holds: `sets` of each scheme renormalizing
    /// there (every one at step 0 and at the last step).
    fn expected_sets(run: &RunInfo, step: u64) -> usize {
        let last = run.header.total_steps;
        run.schemes
            .iter()
            .filter(|s| step.is_multiple_of(s.tau_steps) || step == last)
            .count()
            * run.sets
    }

    /// The sample before the next one (or the end of the run) is whole.
    fn finish_sample(&self, run: &RunInfo) -> Result<(), String> {
        if let Some((seq, step)) = self.sample {
            let expected = Self::expected_sets(run, step);
            if self.seen.len() != expected {
                return Err(format!(
                    "sample {seq} (step {step}) with {} separation sets, but {expected} of the \
                     header's schemes and sets renormalize there",
                    self.seen.len()
                ));
            }
        }
        Ok(())
    }

    fn reference(&mut self, run: &RunInfo, r: &ReferenceState) -> Result<(), String> {
        for (field, v) in [
            ("energy", r.energy),
            ("mean_divergence", r.mean_divergence),
            ("divergence_sum", r.divergence_sum),
        ] {
            if !v.is_finite() {
                return Err(format!("{field} = {v:?}"));
            }
        }
        Self::time(run, r.step, r.t)?;
        if r.state.len() != run.dim {
            return Err(format!(
                "a state of {} values, but the run's dimension is {}",
                r.state.len(),
                run.dim
            ));
        }
        Self::finite("state", &r.state)?;
        if let Some((seq, step)) = self.sample
            && (r.seq <= seq || r.step <= step)
        {
            return Err(format!(
                "sample {} at step {} after sample {seq} at step {step} (they must increase)",
                r.seq, r.step
            ));
        }
        self.finish_sample(run)?;
        self.previous_step = self.sample.map_or(0, |(_, step)| step);
        self.sample = Some((r.seq, r.step));
        self.seen.clear();
        Ok(())
    }

    fn separations(&mut self, run: &RunInfo, m: &SeparationSet) -> Result<(), String> {
        if m.scheme as usize >= run.schemes.len() || m.set as usize >= run.sets {
            return Err(format!(
                "scheme {} set {}, but the run has {} schemes of {} sets",
                m.scheme,
                m.set,
                run.schemes.len(),
                run.sets
            ));
        }
        if (m.k as usize, m.dim as usize) != (run.k, run.dim)
            || m.separations.len() != run.k * run.dim
            || m.stretch.len() != run.k
        {
            return Err(format!(
                "k = {}, dim = {}, {} separation values and {} stretching factors, but the run \
                 has k = {} vectors of dimension {}",
                m.k,
                m.dim,
                m.separations.len(),
                m.stretch.len(),
                run.k,
                run.dim
            ));
        }
        Self::time(run, m.step, m.t)?;
        Self::finite("separations", &m.separations)?;
        for (field, values) in [
            ("stretch", &m.stretch),
            ("earlier_stretch", &m.earlier_stretch),
        ] {
            if let Some(i) = values.iter().position(|s| !(s.is_finite() && *s > 0.0)) {
                return Err(format!(
                    "{field}[{i}] = {:?} (a stretching factor |w| / d0 is positive and finite)",
                    values[i]
                ));
            }
        }
        let Some((seq, step)) = self.sample.filter(|(seq, _)| *seq == m.seq) else {
            return Err(format!(
                "a separation set of sample {} that does not follow its reference state",
                m.seq
            ));
        };
        if m.step != step {
            return Err(format!(
                "step {} in sample {seq}, whose reference state is at step {step}",
                m.step
            ));
        }
        let tau = run.schemes[m.scheme as usize].tau_steps;
        if !(step.is_multiple_of(tau) || step == run.header.total_steps) {
            return Err(format!(
                "scheme {} renormalizes every {tau} steps, not at step {step}",
                m.scheme
            ));
        }
        // The scheme's renormalizations since the previous sample in the file, before this one
        // (the previous sample may be lost: then fewer are carried, and the tracker counts the
        // gap).
        let between = (step.max(1) - 1) / tau - self.previous_step / tau;
        let carried = m.earlier_stretch.len() as u64;
        if !carried.is_multiple_of(run.k as u64) || carried / run.k as u64 > between {
            return Err(format!(
                "{carried} earlier stretching factors in sample {seq}, but scheme {} renormalized \
                 {between} times with k = {} since the previous sample",
                m.scheme, run.k
            ));
        }
        if !self.seen.insert((m.scheme, m.set)) {
            return Err(format!(
                "scheme {} set {} twice in sample {seq}",
                m.scheme, m.set
            ));
        }
        Ok(())
    }
}

impl RecordingReader {
    pub fn open(path: &Path) -> Result<Self, ReadError> {
        Self::open_with(path, false)
    }

    /// Opens a recording whose writer may have been killed: it reads every complete chunk up to
    /// the first damage and ends there (saying where in [`RecordingInfo::damage`]), as
    /// `chaoscope recover` would salvage it; values no producer writes are still refused.
    pub fn open_salvaging(path: &Path) -> Result<Self, ReadError> {
        Self::open_with(path, true)
    }

    fn open_with(path: &Path, salvaging: bool) -> Result<Self, ReadError> {
        let (scanner, meta) = Scanner::open_file(path)?;
        let mut messages = Messages::new(scanner);
        // The run header is the first message of every recording.
        let header = loop {
            let Some(m) = next(&mut messages, path, false)? else {
                return Err(ReadError::NoHeader {
                    path: path.to_path_buf(),
                });
            };
            if &*m.topic == topic::RUN {
                break RunHeader::decode(&m.data[..]).map_err(|error| ReadError::Decode {
                    path: path.to_path_buf(),
                    topic: topic::RUN.into(),
                    error,
                })?;
            }
        };
        let run = RunInfo::from_header(header).map_err(|header| ReadError::Header {
            path: path.to_path_buf(),
            header,
        })?;
        Ok(Self {
            path: path.to_path_buf(),
            messages,
            run,
            assembler: SampleAssembler::new(),
            salvaging,
            check: SampleCheck::default(),
            info: RecordingInfo {
                bytes: meta.len(),
                ..Default::default()
            },
        })
    }

    pub fn header(&self) -> &RunHeader {
        &self.run.header
    }

    /// The run the header describes (checked when the file was opened).
    pub fn run(&self) -> &RunInfo {
        &self.run
    }

    pub fn path(&self) -> &Path {
        &self.path
    }

    /// The next data message (reference state, separation set, end of run), or `None` at the
    /// end of the file. Recording summaries are collected into [`RecordingReader::info`].
    pub fn next_message(&mut self) -> Result<Option<DataMessage>, ReadError> {
        loop {
            let Some(m) = next(&mut self.messages, &self.path, self.salvaging)? else {
                if self.salvaging {
                    self.info
                        .damage
                        .clone_from(&self.messages.scan().stopped_at);
                }
                return Ok(None);
            };
            let t = &*m.topic;
            let path = &self.path;
            let decode = |error| ReadError::Decode {
                path: path.clone(),
                topic: t.to_string(),
                error,
            };
            let value = |what: String| ReadError::Value {
                path: path.clone(),
                topic: t.to_string(),
                what,
            };
            let finite = |name: &str, v: f64| {
                if v.is_finite() {
                    Ok(())
                } else {
                    Err(value(format!("{name} = {v:?}")))
                }
            };
            let data = &m.data[..];
            if t == topic::REFERENCE {
                let r = ReferenceState::decode(data).map_err(decode)?;
                finite("t", r.t)?;
                self.check.reference(&self.run, &r).map_err(value)?;
                return Ok(Some(DataMessage::Reference(r)));
            } else if t.starts_with("/chaoscope/separations/") {
                let s = SeparationSet::decode(data).map_err(decode)?;
                finite("t", s.t)?;
                self.check.separations(&self.run, &s).map_err(value)?;
                return Ok(Some(DataMessage::Separations(s)));
            } else if t == topic::END {
                let e = EndOfRun::decode(data).map_err(decode)?;
                finite("t", e.t)?;
                self.check.finish_sample(&self.run).map_err(value)?;
                self.info.end = Some(e.clone());
                return Ok(Some(DataMessage::End(e)));
            } else if t == topic::RECORDING {
                self.info.summary = Some(RecordingSummary::decode(data).map_err(decode)?);
            }
        }
    }

    /// The next complete sample, or `None` at the end of the file.
    pub fn next_sample(&mut self) -> Result<Option<Sample>, ReadError> {
        loop {
            match self.next_message()? {
                None => return Ok(self.assembler.finish()),
                Some(m) => {
                    if let (Some(sample), _) = self.assembler.push(m) {
                        return Ok(Some(sample));
                    }
                }
            }
        }
    }

    /// Reads the rest of the file (the recording summary comes after the end of run).
    pub fn drain(&mut self) -> Result<(), ReadError> {
        while self.next_message()?.is_some() {}
        Ok(())
    }
}

/// The next message of the file at `path`; `None` at its end, an error if it is damaged
/// (unless `salvaging`: then damage ends it too).
fn next(
    messages: &mut Messages<BufReader<File>>,
    path: &Path,
    salvaging: bool,
) -> Result<Option<scan::Message>, ReadError> {
    let m = messages
        .next_message()
        .map_err(|e| FileError::io(path, e))?;
    match (m, &messages.scan().stopped_at) {
        (None, Some(why)) if !salvaging => Err(ReadError::Damaged {
            path: path.to_path_buf(),
            why: why.clone(),
        }),
        (m, _) => Ok(m),
    }
}

/// Analyzes a whole recording (or up to the last `options.at` time).
pub fn analyze_file(
    path: &Path,
    options: &AnalysisOptions,
) -> Result<(Analysis, RecordingInfo), ReadError> {
    let mut reader = RecordingReader::open(path)?;
    if let Some(from) = options.exponents_from {
        let run = reader.run();
        crate::analysis::exponents_from_step(from, run.h, run.header.t_final).map_err(|why| {
            ReadError::Option {
                path: path.to_path_buf(),
                why,
            }
        })?;
    }
    if let Some(times) = options
        .plane_times
        .as_deref()
        .filter(|_| options.site_profiles)
    {
        crate::site_profiles::check_plane_times(times, reader.run()).map_err(|why| {
            ReadError::Option {
                path: path.to_path_buf(),
                why,
            }
        })?;
    }
    let mut analysis = Analysis::new(reader.run().clone(), options);
    while let Some(sample) = reader.next_sample()? {
        analysis.feed(&sample);
        if analysis.captures_done() {
            break;
        }
    }
    if !analysis.captures_done() {
        reader.drain()?;
    }
    if reader
        .info
        .summary
        .as_ref()
        .is_some_and(|s| s.frames_missing > 0)
    {
        analysis.mark_gap();
    }
    Ok((analysis, reader.info))
}
