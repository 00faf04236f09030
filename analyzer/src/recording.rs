//! Streaming reader of chaoscope MCAP recordings: messages are decoded one at a time from a
//! buffered file, so memory does not depend on the size of the file.

use std::fs::File;
use std::io::BufReader;
use std::path::{Path, PathBuf};

use chaoscope_producer::engine::Sample;
use chaoscope_schemas::convert::DataMessage;
use chaoscope_schemas::names::topic;
use chaoscope_schemas::proto::{
    EndOfRun, RecordingSummary, ReferenceState, RunHeader, SeparationSet,
};
use prost::Message;

use crate::analysis::{Analysis, AnalysisOptions};
use crate::assemble::SampleAssembler;
use crate::run_info::{HeaderError, RunInfo};

#[derive(Debug, thiserror::Error)]
pub enum ReadError {
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("{path}: not a readable MCAP file: {source}")]
    Mcap {
        path: PathBuf,
        source: mcap::McapError,
    },
    #[error("{path}: message on {topic} is not valid protobuf: {source}")]
    Decode {
        path: PathBuf,
        topic: String,
        source: prost::DecodeError,
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
    messages: mcap::io::MessageReader<BufReader<File>>,
    header: RunHeader,
    assembler: SampleAssembler,
    pub info: RecordingInfo,
}

impl RecordingReader {
    pub fn open(path: &Path) -> Result<Self, ReadError> {
        let file = File::open(path).map_err(|source| ReadError::Io {
            path: path.to_path_buf(),
            source,
        })?;
        let bytes = file.metadata().map(|m| m.len()).unwrap_or(0);
        let mut messages = mcap::io::MessageReader::new(BufReader::with_capacity(1 << 20, file));
        // The run header is the first message of every recording.
        let header = loop {
            let Some(m) = messages.next() else {
                return Err(ReadError::NoHeader {
                    path: path.to_path_buf(),
                });
            };
            let m = m.map_err(|source| ReadError::Mcap {
                path: path.to_path_buf(),
                source,
            })?;
            if m.channel.topic == topic::RUN {
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
                bytes,
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
            let Some(m) = self.messages.next() else {
                return Ok(None);
            };
            let m = m.map_err(|source| ReadError::Mcap {
                path: self.path.clone(),
                source,
            })?;
            let t = m.channel.topic.as_str();
            let path = &self.path;
            let decode = |source| ReadError::Decode {
                path: path.clone(),
                topic: t.to_string(),
                source,
            };
            let data = &m.data[..];
            if t == topic::REFERENCE {
                return Ok(Some(DataMessage::Reference(
                    ReferenceState::decode(data).map_err(decode)?,
                )));
            } else if t.starts_with("/chaoscope/separations/") {
                return Ok(Some(DataMessage::Separations(
                    SeparationSet::decode(data).map_err(decode)?,
                )));
            } else if t == topic::END {
                let e = EndOfRun::decode(data).map_err(decode)?;
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
