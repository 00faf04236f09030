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
use chaoscope_schemas::names::{metadata, topic};
use chaoscope_schemas::proto::DataMessage;
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
    ///
    /// zstd at level 1, not the library's default 3: a recording is mostly doubles of a
    /// chaotic state, which level 3 packs hardly tighter, if at all (the messages of a DKG
    /// chain's run, 3.8 MB: 86.3 % of their size at level 3, 85.9 % at level 1; the whole file
    /// of a more densely sampled run: 0.7 % smaller at level 3), in 1.7x the CPU time, taken
    /// from the run (`docs/src/performance.md`, "The recorder's share").
    pub fn writer<W: Write + Seek>(&self, out: W) -> mcap::McapResult<mcap::Writer<W>> {
        let (compression, level) = match self.compression {
            Compression::Zstd => (Some(mcap::Compression::Zstd), 1),
            // 0: lz4's own default, its fast mode.
            Compression::Lz4 => (Some(mcap::Compression::Lz4), 0),
            Compression::None => (None, 0),
        };
        mcap::WriteOptions::new()
            .profile("")
            .library(format!("chaoscope-recorder {}", env!("CARGO_PKG_VERSION")))
            .compression(compression)
            .compression_level(level)
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
    encoder: Encoder,
    indicators: IndicatorStream,
    recording: u16,
    /// The messages of one write ([`Self::write_with`]), encoded; kept for its capacity.
    batch: EncodedMessages,
    last_log_time: u64,
}

/// The channels of a recording by what they carry: all that encoding a message for the file
/// needs. Encoding is apart from writing so that a recorder can encode on one thread while
/// another compresses and writes (the recorder's write thread); both paths encode here.
#[derive(Debug, Clone)]
pub struct Encoder {
    reference: u16,
    /// Channel of each scheme, by scheme index.
    separations: Vec<u16>,
    /// Indicator channel of each scheme, by scheme index.
    indicators: Vec<u16>,
    end: u16,
}

/// One message of an [`EncodedMessages`].
#[derive(Debug, Clone, Copy)]
struct EncodedMessage {
    channel: u16,
    sequence: u32,
    log_time: u64,
    /// Where its bytes end in the batch's buffer (they start where the previous one's bytes end).
    end: usize,
    /// The run's frame number, for a data message (not for indicators).
    frame: Option<u64>,
}

/// Messages encoded for the file, in file order, all bytes in one buffer (one allocation for a
/// whole batch, not one per message).
#[derive(Debug, Clone, Default)]
pub struct EncodedMessages {
    bytes: Vec<u8>,
    messages: Vec<EncodedMessage>,
}

impl EncodedMessages {
    pub fn is_empty(&self) -> bool {
        self.messages.is_empty()
    }

    /// An empty batch with room for as much as this one holds (the next batch of a stream is
    /// about as large, and grows without copying).
    pub fn empty_like(&self) -> Self {
        Self {
            bytes: Vec::with_capacity(self.bytes.len()),
            messages: Vec::with_capacity(self.messages.len()),
        }
    }

    pub fn clear(&mut self) {
        self.bytes.clear();
        self.messages.clear();
    }

    fn push(
        &mut self,
        channel: u16,
        sequence: u64,
        log_time: u64,
        frame: Option<u64>,
        m: &impl Message,
    ) {
        m.encode(&mut self.bytes).expect("a Vec grows as needed");
        self.messages.push(EncodedMessage {
            channel,
            // MCAP's sequence is 32 bits; the frame number modulo 2^32 (the payload keeps all 64).
            sequence: sequence as u32,
            log_time,
            end: self.bytes.len(),
            frame,
        });
    }

    /// The messages with their bytes.
    fn iter(&self) -> impl Iterator<Item = (&EncodedMessage, &[u8])> {
        let starts = std::iter::once(0).chain(self.messages.iter().map(|m| m.end));
        self.messages
            .iter()
            .zip(starts)
            .map(|(m, start)| (m, &self.bytes[start..m.end]))
    }
}

impl Encoder {
    /// Appends the indicator messages `indicators` to `out`.
    pub fn indicators(
        &self,
        indicators: &[Indicators],
        out: &mut EncodedMessages,
    ) -> mcap::McapResult<()> {
        for m in indicators {
            let channel = *self
                .indicators
                .get(m.scheme as usize)
                .ok_or_else(|| mcap::McapError::UnknownChannel(m.seq as u32, m.scheme as u16))?;
            out.push(channel, m.seq, log_time_of(m.t), None, m);
        }
        Ok(())
    }

    /// Appends the data message `message` to `out`. A separation set of an unknown scheme is an
    /// error (the header announced the schemes).
    pub fn message(
        &self,
        message: &DataMessage,
        out: &mut EncodedMessages,
    ) -> mcap::McapResult<()> {
        match message {
            DataMessage::Reference(m) => {
                out.push(self.reference, m.frame, log_time_of(m.t), Some(m.frame), m)
            }
            DataMessage::Separations(m) => {
                let channel = *self.separations.get(m.scheme as usize).ok_or_else(|| {
                    mcap::McapError::UnknownChannel(m.frame as u32, m.scheme as u16)
                })?;
                out.push(channel, m.frame, log_time_of(m.t), Some(m.frame), m)
            }
            DataMessage::End(m) => out.push(self.end, m.frame, log_time_of(m.t), Some(m.frame), m),
        }
        Ok(())
    }
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
            encoder: Encoder {
                reference,
                separations,
                indicators: indicator_channels,
                end,
            },
            indicators: IndicatorStream::new(header),
            recording,
            batch: EncodedMessages::default(),
            last_log_time: 0,
        };
        file.write_with(|_, out| {
            out.push(run, 0, 0, None, header);
            Ok(())
        })?;
        Ok(file)
    }

    /// Encodes with `encode` into the file's batch buffer, then writes what it encoded.
    fn write_with(
        &mut self,
        encode: impl FnOnce(&Encoder, &mut EncodedMessages) -> mcap::McapResult<()>,
    ) -> mcap::McapResult<()> {
        let mut batch = std::mem::take(&mut self.batch);
        batch.clear();
        let written =
            encode(&self.encoder, &mut batch).and_then(|()| self.write_encoded(&batch, drop));
        self.batch = batch;
        written
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

    /// The encoder of this file's messages, for a recorder that encodes on another thread and
    /// hands the result to [`Self::write_encoded`].
    pub fn encoder(&self) -> Encoder {
        self.encoder.clone()
    }

    /// Appends `indicators` (computed by a detached stream for this message), the indicators of
    /// the file's own stream if it has one, then `message`.
    pub fn write_after(
        &mut self,
        indicators: &[Indicators],
        message: &DataMessage,
    ) -> mcap::McapResult<()> {
        let own = self.indicators.before(message);
        self.write_with(|encoder, out| {
            encoder.indicators(indicators, out)?;
            encoder.indicators(&own, out)?;
            encoder.message(message, out)
        })
    }

    /// Appends messages encoded by [`Encoder`], in their order, telling `data_frame` the frame
    /// number of each data message just before it is written. Their MCAP `publish_time`, the
    /// wall-clock time of writing, is read once for all of them (a batch is written within a
    /// fraction of a millisecond).
    pub fn write_encoded(
        &mut self,
        messages: &EncodedMessages,
        mut data_frame: impl FnMut(u64),
    ) -> mcap::McapResult<()> {
        let publish_time = wall_clock_ns();
        for (m, bytes) in messages.iter() {
            if let Some(frame) = m.frame {
                data_frame(frame);
            }
            self.last_log_time = self.last_log_time.max(m.log_time);
            let header = MessageHeader {
                channel_id: m.channel,
                sequence: m.sequence,
                log_time: m.log_time,
                publish_time,
            };
            self.writer.write_to_known_channel(&header, bytes)?;
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
        let own = self.indicators.take();
        self.write_with(|encoder, out| {
            encoder.indicators(indicators, out)?;
            encoder.indicators(&own, out)
        })?;
        // Logged at the latest time written, the indicators' included.
        let (channel, log_time) = (self.recording, self.last_log_time);
        self.write_with(|_, out| {
            out.push(channel, summary.last_frame, log_time, None, summary);
            Ok(())
        })?;
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
