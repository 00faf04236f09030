//! Writes samples computed in this process (replays, sweeps run without the bus) as a regular
//! chaoscope recording, through the recorder's MCAP layout so every reader sees the same file
//! format as from `chaoscope record`.

use std::fs::File;
use std::io::BufWriter;
use std::path::{Path, PathBuf};

use chaoscope_os::{Leftover, Output, OutputError, OutputOptions};

use chaoscope_files::file::{FileOptions, RecordingFile};
use chaoscope_schemas::proto::DataMessage;
use chaoscope_schemas::proto::{
    EndOfRun, RecordingSummary, ReferenceState, RunHeader, SeparationSet, end_of_run,
};
use chaoscope_schemas::run::Sample;

/// Why a recording could not be written.
#[derive(Debug, thiserror::Error)]
pub enum WriteError {
    #[error(transparent)]
    Output(#[from] OutputError),
    /// The whole cause in the message and no error source, so a chain printer does not repeat
    /// it.
    #[error("{}: MCAP: {}", path.display(), chaoscope_files::file::error_chain(error))]
    Mcap {
        path: PathBuf,
        error: mcap::McapError,
    },
}

/// A recording being written from samples, into its in-progress file until
/// [`SampleWriter::finish`] puts it in place (`chaoscope_os::output`); dropped unfinished, the
/// in-progress file goes.
pub struct SampleWriter {
    file: RecordingFile<BufWriter<File>>,
    output: Output,
    frame: u64,
    samples: u64,
    last: (u64, f64),
    dim: u32,
    k: u32,
}

impl SampleWriter {
    /// A new recording at `path`, replacing an earlier file of that name (benches, examples).
    pub fn create(path: &Path, header: &RunHeader) -> Result<Self, WriteError> {
        let options = OutputOptions {
            replace: true,
            leftover: Leftover::Discard,
            ..Default::default()
        };
        Self::create_with(path, header, &options)
    }

    /// A new recording at `path`, opened with `options` (`--force`, the inputs it must not be).
    pub fn create_with(
        path: &Path,
        header: &RunHeader,
        options: &OutputOptions,
    ) -> Result<Self, WriteError> {
        let output = Output::create(path, options)?;
        let out = BufWriter::with_capacity(1 << 20, output.file()?);
        let file =
            RecordingFile::create(out, header, &FileOptions::default()).map_err(|error| {
                WriteError::Mcap {
                    path: path.to_path_buf(),
                    error,
                }
            })?;
        Ok(Self {
            file,
            output,
            frame: 0,
            samples: 0,
            last: (0, 0.0),
            dim: header.dim,
            k: header.k,
        })
    }

    /// A new recording written into `output` as it stands: its in-progress file, or the fresh
    /// file beside a leftover that [`Output::start_fresh`] started (a run resumed from it).
    pub fn create_in(output: Output, header: &RunHeader) -> Result<Self, WriteError> {
        let path = output.target().to_path_buf();
        let out = BufWriter::with_capacity(1 << 20, output.file()?);
        let file = RecordingFile::create(out, header, &FileOptions::default())
            .map_err(|error| WriteError::Mcap { path, error })?;
        Ok(Self {
            file,
            output,
            frame: 0,
            samples: 0,
            last: (0, 0.0),
            dim: header.dim,
            k: header.k,
        })
    }

    /// Removes the file being written (a resume stopped before it held more than its input),
    /// whatever `keep_failed` says.
    pub fn abandon(self) {
        self.output.abandon();
    }

    /// Puts what was written so far on disk in whole chunks (what a kill can lose is bounded
    /// by the time since).
    pub fn checkpoint(&mut self) -> Result<(), WriteError> {
        let path = self.output.target().to_path_buf();
        self.file
            .close_chunk()
            .map_err(|error| WriteError::Mcap { path, error })
    }

    /// Once the file holds everything the leftover it continues held: on disk, and put in the
    /// leftover's place ([`Output::adopt_fresh`]).
    pub fn adopt_fresh(&mut self) -> Result<(), WriteError> {
        self.checkpoint()?;
        self.output.adopt_fresh()?;
        Ok(())
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
            divergence_sum: s.divergence_sum,
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
                earlier_stretch: set.earlier_stretch.clone(),
            }))?;
            self.frame += 1;
        }
        self.samples = s.seq + 1;
        self.last = (s.step, s.t);
        Ok(())
    }

    /// Writes the end-of-run record of a completed run and the summary (`finalized_by` says
    /// who wrote the file).
    pub fn finish(self, finalized_by: &str) -> Result<(), WriteError> {
        self.finish_with(finalized_by, end_of_run::Status::Completed, "")
    }

    /// Writes the end-of-run record with the run's `status` (and the `reason` of a failure), and
    /// the summary: a run stopped early still leaves a valid file saying how it ended.
    pub fn finish_with(
        mut self,
        finalized_by: &str,
        status: end_of_run::Status,
        reason: &str,
    ) -> Result<(), WriteError> {
        let path = self.output.target().to_path_buf();
        let mcap = |error| WriteError::Mcap {
            path: path.clone(),
            error,
        };
        self.file
            .write(&DataMessage::End(EndOfRun {
                frame: self.frame,
                status: status as i32,
                reason: reason.to_string(),
                samples: self.samples,
                last_step: self.last.0,
                t: self.last.1,
            }))
            .map_err(mcap)?;
        let summary = RecordingSummary {
            finalized_by: finalized_by.to_string(),
            run_status: status.word().into(),
            frames_received: self.frame + 1,
            frames_missing: 0,
            first_frame: 0,
            last_frame: self.frame,
            recorder_version: env!("CARGO_PKG_VERSION").to_string(),
        };
        let mut out = self.file.finish(&summary).map_err(mcap)?;
        std::io::Write::flush(&mut out).map_err(|e| mcap(e.into()))?;
        drop(out);
        self.output.commit()?;
        Ok(())
    }
}
