//! Streaming reader of chaoscope MCAP recordings: messages are decoded one at a time from a
//! buffered file, so memory does not depend on the size of the file.
//!
//! The file is read through the recorder's damage-tolerant scanner ([`chaoscope_recorder::scan`]):
//! each chunk is checked whole before any of its messages is used, and a damaged or truncated
//! file is an error naming the file and where and why it is damaged, after the messages before
//! the damage (an analysis is of a whole recording or of none).

use std::fs::File;
use std::io::BufReader;
use std::path::{Path, PathBuf};

use chaoscope_recorder::scan::{self, FileError, Messages, Scanner};

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
    #[error("{path}: message on {topic} is not valid protobuf: {source}")]
    Decode {
        path: PathBuf,
        topic: String,
        source: prost::DecodeError,
    },
    /// A value no producer writes (a time or energy that is not finite): refused rather than
    /// carried into outputs as NaN or infinity.
    #[error("{path}: message on {topic} holds {what}, which no producer writes")]
    Value {
        path: PathBuf,
        topic: String,
        what: String,
    },
    #[error("{path}: no run header; is it a chaoscope recording?")]
    NoHeader { path: PathBuf },
    #[error("{path}: {source}")]
    Header { path: PathBuf, source: HeaderError },
}

/// What a recording holds besides its samples.
#[derive(Debug, Clone, Default)]
pub struct RecordingInfo {
    pub end: Option<EndOfRun>,
    pub summary: Option<RecordingSummary>,
    /// File bytes read.
    pub bytes: u64,
}

/// An open recording, positioned after its run header.
pub struct RecordingReader {
    path: PathBuf,
    messages: Messages<BufReader<File>>,
    header: RunHeader,
    assembler: SampleAssembler,
    pub info: RecordingInfo,
}

impl RecordingReader {
    pub fn open(path: &Path) -> Result<Self, ReadError> {
        let (scanner, meta) = Scanner::open_file(path)?;
        let mut messages = Messages::new(scanner);
        // The run header is the first message of every recording.
        let header = loop {
            let Some(m) = next(&mut messages, path)? else {
                return Err(ReadError::NoHeader {
                    path: path.to_path_buf(),
                });
            };
            if &*m.topic == topic::RUN {
                break RunHeader::decode(&m.data[..]).map_err(|source| ReadError::Decode {
                    path: path.to_path_buf(),
                    topic: topic::RUN.into(),
                    source,
                })?;
            }
        };
        Ok(Self {
            path: path.to_path_buf(),
            messages,
            header,
            assembler: SampleAssembler::new(),
            info: RecordingInfo {
                bytes: meta.len(),
                ..Default::default()
            },
        })
    }

    pub fn header(&self) -> &RunHeader {
        &self.header
    }

    pub fn path(&self) -> &Path {
        &self.path
    }

    /// The next data message (reference state, separation set, end of run), or `None` at the
    /// end of the file. Recording summaries are collected into [`RecordingReader::info`].
    pub fn next_message(&mut self) -> Result<Option<DataMessage>, ReadError> {
        loop {
            let Some(m) = next(&mut self.messages, &self.path)? else {
                return Ok(None);
            };
            let t = &*m.topic;
            let path = &self.path;
            let decode = |source| ReadError::Decode {
                path: path.clone(),
                topic: t.to_string(),
                source,
            };
            let finite = |name: &str, v: f64| {
                if v.is_finite() {
                    Ok(())
                } else {
                    Err(ReadError::Value {
                        path: path.clone(),
                        topic: t.to_string(),
                        what: format!("{name} = {v}"),
                    })
                }
            };
            let data = &m.data[..];
            if t == topic::REFERENCE {
                let r = ReferenceState::decode(data).map_err(decode)?;
                finite("t", r.t)?;
                finite("energy", r.energy)?;
                finite("mean_divergence", r.mean_divergence)?;
                return Ok(Some(DataMessage::Reference(r)));
            } else if t.starts_with("/chaoscope/separations/") {
                let s = SeparationSet::decode(data).map_err(decode)?;
                finite("t", s.t)?;
                return Ok(Some(DataMessage::Separations(s)));
            } else if t == topic::END {
                let e = EndOfRun::decode(data).map_err(decode)?;
                finite("t", e.t)?;
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

/// The next message of the file at `path`; `None` at its end, an error if it is damaged.
fn next(
    messages: &mut Messages<BufReader<File>>,
    path: &Path,
) -> Result<Option<scan::Message>, ReadError> {
    let m = messages
        .next_message()
        .map_err(|e| FileError::io(path, e))?;
    match (m, &messages.scan().stopped_at) {
        (None, Some(why)) => Err(ReadError::Damaged {
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
    let run =
        RunInfo::from_header(reader.header().clone()).map_err(|source| ReadError::Header {
            path: path.to_path_buf(),
            source,
        })?;
    let mut analysis = Analysis::new(run, options);
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
