//! Writes samples computed in this process (replays, sweeps run without the bus) as a regular
//! chaoscope recording, through the recorder's MCAP layout so every reader sees the same file
//! format as from `chaoscope record`.

use std::fs::File;
use std::io::BufWriter;
use std::path::Path;

use chaoscope_recorder::file::{FileOptions, RecordingFile};
use chaoscope_schemas::proto::DataMessage;
use chaoscope_schemas::proto::{
    EndOfRun, RecordingSummary, ReferenceState, RunHeader, SeparationSet, end_of_run,
};
use chaoscope_schemas::run::Sample;

/// A recording being written from samples.
pub struct SampleWriter {
    file: RecordingFile<BufWriter<File>>,
    frame: u64,
    samples: u64,
    last: (u64, f64),
    dim: u32,
    k: u32,
}

impl SampleWriter {
    pub fn create(path: &Path, header: &RunHeader) -> mcap::McapResult<Self> {
        let out = BufWriter::with_capacity(1 << 20, File::create(path)?);
        Ok(Self {
            file: RecordingFile::create(out, header, &FileOptions::default())?,
            frame: 0,
            samples: 0,
            last: (0, 0.0),
            dim: header.dim,
            k: header.k,
        })
    }

    pub fn write(&mut self, s: &Sample) -> mcap::McapResult<()> {
        self.file.write(&DataMessage::Reference(ReferenceState {
            frame: self.frame,
            seq: s.seq,
            step: s.step,
            t: s.t,
            energy: s.energy,
            state: s.state.clone(),
            mean_divergence: s.mean_divergence,
        }))?;
        self.frame += 1;
        for set in &s.schemes {
            self.file.write(&DataMessage::Separations(SeparationSet {
                frame: self.frame,
                seq: s.seq,
                step: s.step,
                t: s.t,
                scheme: set.scheme,
                set: set.set,
                k: self.k,
                dim: self.dim,
                separations: set.separations.clone(),
                stretch: set.stretch.clone(),
            }))?;
            self.frame += 1;
        }
        self.samples = s.seq + 1;
        self.last = (s.step, s.t);
        Ok(())
    }

    /// Writes the end-of-run record of a completed run and the summary (`finalized_by` says
    /// who wrote the file).
    pub fn finish(self, finalized_by: &str) -> mcap::McapResult<()> {
        self.finish_with(finalized_by, end_of_run::Status::Completed, "")
    }

    /// Writes the end-of-run record with the run's `status` (and the `reason` of a failure), and
    /// the summary: a run stopped early still leaves a valid file saying how it ended.
    pub fn finish_with(
        mut self,
        finalized_by: &str,
        status: end_of_run::Status,
        reason: &str,
    ) -> mcap::McapResult<()> {
        self.file.write(&DataMessage::End(EndOfRun {
            frame: self.frame,
            status: status as i32,
            reason: reason.to_string(),
            samples: self.samples,
            last_step: self.last.0,
            t: self.last.1,
        }))?;
        let summary = RecordingSummary {
            finalized_by: finalized_by.to_string(),
            run_status: status.word().into(),
            frames_received: self.frame + 1,
            frames_missing: 0,
            first_frame: 0,
            last_frame: self.frame,
            recorder_version: env!("CARGO_PKG_VERSION").to_string(),
        };
        let mut out = self.file.finish(&summary)?;
        std::io::Write::flush(&mut out)?;
        Ok(())
    }
}
