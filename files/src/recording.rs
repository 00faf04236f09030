//! What a recorder does with each message of a run and how it ends (no bus, no file system).

use std::io::{Seek, Write};

use chaoscope_schemas::proto::DataMessage;
use chaoscope_schemas::proto::{EndOfRun, Indicators, RecordingSummary, RunHeader, end_of_run};

use crate::file::{EncodedMessages, Encoder, FileOptions, RecordingFile};
use crate::indicators::IndicatorStream;
use crate::sequence::SequenceTracker;

/// Why the recorder finalized the file.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FinalizedBy {
    /// The producer's end-of-run record arrived.
    EndOfRun,
    /// The recorder got SIGINT or SIGTERM.
    Signal,
    /// The producer's node died (or vanished) without an end-of-run record.
    ProducerDied,
}

impl FinalizedBy {
    pub fn word(self) -> &'static str {
        match self {
            Self::EndOfRun => "end-of-run",
            Self::Signal => "signal",
            Self::ProducerDied => "producer-died",
        }
    }
}

/// A recording in progress: the file plus the sequence accounting.
pub struct Recording<W: Write + Seek> {
    file: RecordingFile<W>,
    sequence: SequenceTracker,
    end: Option<EndOfRun>,
}

impl<W: Write + Seek> Recording<W> {
    pub fn start(out: W, header: &RunHeader, options: &FileOptions) -> mcap::McapResult<Self> {
        Ok(Self {
            file: RecordingFile::create(out, header, options)?,
            sequence: SequenceTracker::new(),
            end: None,
        })
    }

    /// Records one message; returns true once the end-of-run record has been recorded.
    pub fn on_message(&mut self, message: &DataMessage) -> mcap::McapResult<bool> {
        self.on_message_after(&[], message)
    }

    /// Takes the indicator computation out of the file ([`RecordingFile::detach_indicators`]).
    pub fn detach_indicators(&mut self) -> IndicatorStream {
        self.file.detach_indicators()
    }

    /// [`Self::on_message`] with the indicators a detached stream computed for `message`.
    pub fn on_message_after(
        &mut self,
        indicators: &[Indicators],
        message: &DataMessage,
    ) -> mcap::McapResult<bool> {
        let frame = match message {
            DataMessage::Reference(m) => m.frame,
            DataMessage::Separations(m) => m.frame,
            DataMessage::End(m) => m.frame,
        };
        self.sequence.observe(frame);
        self.file.write_after(indicators, message)?;
        if let DataMessage::End(m) = message {
            self.end = Some(m.clone());
        }
        Ok(self.end.is_some())
    }

    /// [`Self::on_message_after`] for messages encoded by the file's [`Encoder`] (indicators
    /// included), `end` the run's end-of-run record if they hold it; true once it is recorded.
    pub fn on_encoded(
        &mut self,
        messages: &EncodedMessages,
        end: Option<EndOfRun>,
    ) -> mcap::McapResult<bool> {
        // The gap before each frame is counted by the tracker; nothing to do with it here.
        let observe = |frame| {
            self.sequence.observe(frame);
        };
        self.file.write_encoded(messages, observe)?;
        if end.is_some() {
            self.end = end;
        }
        Ok(self.end.is_some())
    }

    /// The file's message encoder ([`RecordingFile::encoder`]).
    pub fn encoder(&self) -> Encoder {
        self.file.encoder()
    }

    pub fn sequence(&self) -> &SequenceTracker {
        &self.sequence
    }

    pub fn close_chunk(&mut self) -> mcap::McapResult<()> {
        self.file.close_chunk()
    }

    /// The summary the file will carry if finalized now for `reason`.
    pub fn summary(&self, reason: FinalizedBy) -> RecordingSummary {
        let run_status = match (&self.end, reason) {
            (Some(end), _) => end.status().word(),
            // The run did not end by itself: whatever stopped it, it is incomplete.
            (None, _) => end_of_run::Status::Interrupted.word(),
        };
        RecordingSummary {
            finalized_by: reason.word().to_string(),
            run_status: run_status.to_string(),
            frames_received: self.sequence.received(),
            frames_missing: self.sequence.missing(),
            first_frame: self.sequence.first().unwrap_or(0),
            last_frame: self.sequence.last().unwrap_or(0),
            recorder_version: env!("CARGO_PKG_VERSION").to_string(),
        }
    }

    /// Writes the summary and closes the file.
    pub fn finish(self, reason: FinalizedBy) -> mcap::McapResult<(W, RecordingSummary)> {
        self.finish_after(&[], reason)
    }

    /// [`Self::finish`] after `indicators`, the last ones of a detached stream.
    pub fn finish_after(
        self,
        indicators: &[Indicators],
        reason: FinalizedBy,
    ) -> mcap::McapResult<(W, RecordingSummary)> {
        let summary = self.summary(reason);
        let out = self.file.finish_after(indicators, &summary)?;
        Ok((out, summary))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use chaoscope_schemas::proto::{ReferenceState, Scheme, SeparationSet};
    use std::io::Cursor;

    fn header() -> RunHeader {
        RunHeader {
            run_name: "t".into(),
            dim: 2,
            k: 1,
            sets: 1,
            h: 0.01,
            schemes: vec![Scheme {
                index: 0,
                name: "vm".into(),
                tau_steps: 1,
                ..Default::default()
            }],
            ..Default::default()
        }
    }

    fn read_topics(bytes: &[u8]) -> Vec<String> {
        mcap::MessageStream::new(bytes)
            .unwrap()
            .map(|m| m.unwrap().channel.topic.clone())
            .collect()
    }

    #[test]
    fn interrupted_recording_is_a_valid_file_marked_interrupted() {
        let mut r =
            Recording::start(Cursor::new(Vec::new()), &header(), &FileOptions::default()).unwrap();
        let reference = ReferenceState {
            frame: 0,
            state: vec![1.0, 2.0],
            ..Default::default()
        };
        assert!(!r.on_message(&DataMessage::Reference(reference)).unwrap());
        let sep = SeparationSet {
            frame: 1,
            k: 1,
            dim: 2,
            separations: vec![1e-8, 0.0],
            stretch: vec![1.0],
            earlier_stretch: Vec::new(),
            ..Default::default()
        };
        r.on_message(&DataMessage::Separations(sep)).unwrap();
        let (out, summary) = r.finish(FinalizedBy::ProducerDied).unwrap();
        assert_eq!(
            (summary.finalized_by.as_str(), summary.run_status.as_str()),
            ("producer-died", "interrupted")
        );
        assert_eq!((summary.frames_received, summary.frames_missing), (2, 0));
        let bytes = out.into_inner();
        let topics = read_topics(&bytes);
        assert_eq!(
            topics,
            [
                "/chaoscope/run",
                "/chaoscope/reference",
                "/chaoscope/separations/vm",
                // The sample's indicators, written when the file ends after its last set.
                "/chaoscope/indicators/vm",
                "/chaoscope/recording"
            ]
        );
        let summary = mcap::Summary::read(&bytes)
            .unwrap()
            .expect("indexed file has a summary");
        assert!(!summary.chunk_indexes.is_empty());
    }

    #[test]
    fn unknown_scheme_is_an_error_not_a_panic() {
        let mut r =
            Recording::start(Cursor::new(Vec::new()), &header(), &FileOptions::default()).unwrap();
        let sep = SeparationSet {
            frame: 0,
            scheme: 3,
            ..Default::default()
        };
        assert!(r.on_message(&DataMessage::Separations(sep)).is_err());
    }
}
