//! The MCAP layout of a recording, independent of where messages come from.
//!
//! One channel per stream: `/chaoscope/run` (the run header), `/chaoscope/reference`, one
//! `/chaoscope/separations/<scheme>` per scheme, `/chaoscope/end` and `/chaoscope/recording`,
//! and one `/chaoscope/indicators/<scheme>` per scheme, written from the separations (after
//! each sample's last set, [`crate::indicators`]).
//! The run configuration is also stored as the metadata record `chaoscope.run`, and how the file
//! was finalized as `chaoscope.recording`.
//!
//! Crash safety: chunks are assembled in memory and written in one piece (`disable_seeking`), on
//! an unbuffered file, so after `kill -9` every completed chunk is on disk whole and only the open
//! chunk and the summary are lost; `chaoscope recover` rebuilds the rest.

use std::collections::BTreeMap;
use std::io::{Seek, Write};

use chaoscope_schemas::FORMAT_VERSION;
use chaoscope_schemas::convert::DataMessage;
use chaoscope_schemas::names::{metadata, topic};
use chaoscope_schemas::proto::{self, Indicators, RecordingSummary, RunHeader, schema_name};
use mcap::records::{MessageHeader, Metadata};
use prost::Message;

use crate::indicators::IndicatorStream;

/// Compression of MCAP chunks.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Compression {
    Zstd,
    Lz4,
    None,
}

impl std::str::FromStr for Compression {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "zstd" => Ok(Self::Zstd),
            "lz4" => Ok(Self::Lz4),
            "none" => Ok(Self::None),
            _ => Err(format!("unknown compression {s:?}: use zstd, lz4 or none")),
        }
    }
}

/// How the MCAP file is written.
#[derive(Debug, Clone)]
pub struct FileOptions {
    pub compression: Compression,
    /// Target uncompressed chunk size in bytes.
    pub chunk_size: u64,
}

impl FileOptions {
    /// The one place an MCAP writer of chaoscope is configured: chunked, compressed as chosen,
    /// streaming (no seeking back), and compressing on the writing thread only, since the cores
    /// belong to the integrator.
    pub fn writer<W: Write + Seek>(&self, out: W) -> mcap::McapResult<mcap::Writer<W>> {
        let compression = match self.compression {
            Compression::Zstd => Some(mcap::Compression::Zstd),
            Compression::Lz4 => Some(mcap::Compression::Lz4),
            Compression::None => None,
        };
        mcap::WriteOptions::new()
            .profile("")
            .library(format!("chaoscope-recorder {}", env!("CARGO_PKG_VERSION")))
            .compression(compression)
            .compression_threads(0)
            .chunk_size(Some(self.chunk_size))
            .disable_seeking(true)
            .create(out)
    }
}

impl Default for FileOptions {
    fn default() -> Self {
        Self {
            compression: Compression::Zstd,
            chunk_size: 4 << 20,
        }
    }
}

/// An MCAP recording being written.
pub struct RecordingFile<W: Write + Seek> {
    writer: mcap::Writer<W>,
    reference: u16,
    /// Channel of each scheme, by scheme index.
    separations: Vec<u16>,
    /// Indicator channel of each scheme, by scheme index.
    indicator_channels: Vec<u16>,
    indicators: IndicatorStream,
    end: u16,
    recording: u16,
    encoded: Vec<u8>,
    last_log_time: u64,
}

/// Simulation time in nanoseconds, the MCAP log time (so tools plot against t).
pub fn log_time_of(t: f64) -> u64 {
    if t.is_finite() && t > 0.0 {
        (t * 1e9).round().min(u64::MAX as f64) as u64
    } else {
        0
    }
}

fn wall_clock_ns() -> u64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_nanos() as u64)
        .unwrap_or(0)
}

impl<W: Write + Seek> RecordingFile<W> {
    /// Starts a recording of the run described by `header`.
    pub fn create(out: W, header: &RunHeader, options: &FileOptions) -> mcap::McapResult<Self> {
        let mut writer = options.writer(out)?;

        writer.write_metadata(&Metadata {
            name: metadata::RUN.into(),
            metadata: BTreeMap::from([
                ("format_version".to_string(), FORMAT_VERSION.to_string()),
                ("run_name".to_string(), header.run_name.clone()),
                ("config_toml".to_string(), header.config_toml.clone()),
            ]),
        })?;

        let fds = proto::FILE_DESCRIPTOR_SET;
        let enc = proto::SCHEMA_ENCODING;
        let channel =
            |writer: &mut mcap::Writer<W>, schema: &str, topic: &str| -> mcap::McapResult<u16> {
                let schema_id = writer.add_schema(schema, enc, fds)?;
                writer.add_channel(schema_id, topic, proto::MESSAGE_ENCODING, &BTreeMap::new())
            };
        let run = channel(&mut writer, schema_name::RUN_HEADER, topic::RUN)?;
        let reference = channel(&mut writer, schema_name::REFERENCE_STATE, topic::REFERENCE)?;
        let mut separations = Vec::new();
        for s in &header.schemes {
            separations.push(channel(
                &mut writer,
                schema_name::SEPARATION_SET,
                &topic::separations(&s.name),
            )?);
        }
        let mut indicator_channels = Vec::new();
        for s in &header.schemes {
            indicator_channels.push(channel(
                &mut writer,
                schema_name::INDICATORS,
                &topic::indicators(&s.name),
            )?);
        }
        let end = channel(&mut writer, schema_name::END_OF_RUN, topic::END)?;
        let recording = channel(
            &mut writer,
            schema_name::RECORDING_SUMMARY,
            topic::RECORDING,
        )?;

        let mut file = Self {
            writer,
            reference,
            separations,
            indicator_channels,
            indicators: IndicatorStream::new(header),
            end,
            recording,
            encoded: Vec::new(),
            last_log_time: 0,
        };
        file.put(run, 0, 0, header)?;
        Ok(file)
    }

    fn put(
        &mut self,
        channel_id: u16,
        sequence: u64,
        log_time: u64,
        message: &impl Message,
    ) -> mcap::McapResult<()> {
        self.encoded.clear();
        message
            .encode(&mut self.encoded)
            .expect("a Vec grows as needed");
        self.last_log_time = self.last_log_time.max(log_time);
        let header = MessageHeader {
            channel_id,
            sequence: sequence as u32,
            log_time,
            publish_time: wall_clock_ns(),
        };
        self.writer.write_to_known_channel(&header, &self.encoded)
    }

    /// Appends one data message, preceded by the indicators of the sample it completes. A
    /// separation set of an unknown scheme is an error (the header announced the schemes).
    pub fn write(&mut self, message: &DataMessage) -> mcap::McapResult<()> {
        self.write_after(&[], message)
    }

    /// Takes the indicator computation out of the file, for a recorder that runs it on another
    /// thread: from now on the file writes only the indicator messages given to
    /// [`Self::write_after`] and [`Self::finish_after`], which the returned stream computes
    /// (`IndicatorStream::before`, then `take` at the end), so the file is the same.
    pub fn detach_indicators(&mut self) -> IndicatorStream {
        std::mem::replace(&mut self.indicators, IndicatorStream::disabled())
    }

    /// Appends `indicators` (computed by a detached stream for this message), the indicators of
    /// the file's own stream if it has one, then `message`.
    pub fn write_after(
        &mut self,
        indicators: &[Indicators],
        message: &DataMessage,
    ) -> mcap::McapResult<()> {
        let own = self.indicators.before(message);
        self.put_indicators(indicators)?;
        self.put_indicators(&own)?;
        match message {
            DataMessage::Reference(m) => self.put(self.reference, m.frame, log_time_of(m.t), m),
            DataMessage::Separations(m) => {
                let channel = *self.separations.get(m.scheme as usize).ok_or_else(|| {
                    mcap::McapError::UnknownChannel(m.frame as u32, m.scheme as u16)
                })?;
                self.put(channel, m.frame, log_time_of(m.t), m)
            }
            DataMessage::End(m) => self.put(self.end, m.frame, log_time_of(m.t), m),
        }
    }

    fn put_indicators(&mut self, indicators: &[Indicators]) -> mcap::McapResult<()> {
        for m in indicators {
            let channel = *self
                .indicator_channels
                .get(m.scheme as usize)
                .ok_or_else(|| mcap::McapError::UnknownChannel(m.seq as u32, m.scheme as u16))?;
            self.put(channel, m.seq, log_time_of(m.t), m)?;
        }
        Ok(())
    }

    /// Closes the open chunk so it is on disk whole (bounds what a crash can lose).
    pub fn close_chunk(&mut self) -> mcap::McapResult<()> {
        self.writer.flush()
    }

    /// Writes the recording summary message and metadata, then the MCAP summary and footer.
    pub fn finish(self, summary: &RecordingSummary) -> mcap::McapResult<W> {
        self.finish_after(&[], summary)
    }

    /// [`Self::finish`] after `indicators`, the last ones of a detached stream.
    pub fn finish_after(
        mut self,
        indicators: &[Indicators],
        summary: &RecordingSummary,
    ) -> mcap::McapResult<W> {
        self.put_indicators(indicators)?;
        let own = self.indicators.take();
        self.put_indicators(&own)?;
        self.put(
            self.recording,
            summary.last_frame,
            self.last_log_time,
            summary,
        )?;
        self.writer.write_metadata(&Metadata {
            name: metadata::RECORDING.into(),
            metadata: BTreeMap::from([
                ("finalized_by".to_string(), summary.finalized_by.clone()),
                ("run_status".to_string(), summary.run_status.clone()),
                (
                    "frames_received".to_string(),
                    summary.frames_received.to_string(),
                ),
                (
                    "frames_missing".to_string(),
                    summary.frames_missing.to_string(),
                ),
            ]),
        })?;
        self.writer.finish()?;
        Ok(self.writer.into_inner())
    }
}

/// `error` and its sources, joined by ": " (the mcap crate's I/O errors keep the OS error, such
/// as "File too large", as their source).
pub fn error_chain(error: &dyn std::error::Error) -> String {
    let mut text = error.to_string();
    let mut source = error.source();
    while let Some(e) = source {
        let more = e.to_string();
        if !text.ends_with(&more) {
            text.push_str(": ");
            text.push_str(&more);
        }
        source = e.source();
    }
    text
}
