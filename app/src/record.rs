//! A run computed in this process and written to a recording, in the layout the recorder writes
//! (Python's `chaoscope.run`; `chaoscope run` goes through the bus instead).
//!
//! The file is complete at its name or not there at all (`chaoscope_os::output`); a killed run
//! leaves its in-progress file with the samples up to its last checkpoint, which `resume`
//! continues. No NaN or infinity goes into it: the run fails at the first non-finite value and
//! the file says so, as the recorder's file of a failed run does.

use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

use chaoscope_analyzer::write::{SampleWriter, WriteError};
use chaoscope_dynamics::engine::Engine;
use chaoscope_dynamics::header::non_finite;
use chaoscope_dynamics::spec::RunSpec;
use chaoscope_os::OutputOptions;
use chaoscope_schemas::proto::{RunHeader, end_of_run};

/// How a recorded run ended; its file is finalized with this status in every case.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Ended {
    Completed,
    /// `stop` was set.
    Interrupted,
    /// The run could not go on: an integrator failure, an escape, a non-finite value.
    Failed(String),
}

/// Integrates `spec` and writes every sample into `out` under `header` (the run header of this
/// spec), until the end of the run, a failure, or `stop`. `Err` is a failed write: then no
/// file is left at `out`.
pub fn record(
    spec: RunSpec,
    header: &RunHeader,
    out: &Path,
    options: &OutputOptions,
    stop: &AtomicBool,
) -> Result<Ended, WriteError> {
    let mut writer = SampleWriter::create_with(out, header, options)?;
    let written = |error| WriteError::Mcap {
        path: out.to_path_buf(),
        error,
    };
    let mut engine = Engine::new(spec);
    let mut last_checkpoint = Instant::now();
    let ended = loop {
        if stop.load(Ordering::Relaxed) {
            break Ended::Interrupted;
        }
        match engine.next_sample() {
            Ok(Some(sample)) => {
                if let Some(why) = non_finite(&sample) {
                    break Ended::Failed(why);
                }
                writer.write(&sample).map_err(written)?;
                // A killed run leaves its samples up to the last checkpoint for `resume`.
                if last_checkpoint.elapsed() >= crate::CHECKPOINT_EVERY {
                    writer.checkpoint()?;
                    last_checkpoint = Instant::now();
                }
            }
            Ok(None) => break Ended::Completed,
            Err(e) => break Ended::Failed(e.to_string()),
        }
    };
    match &ended {
        Ended::Completed => writer.finish("end-of-run")?,
        Ended::Interrupted => {
            writer.finish_with("signal", end_of_run::Status::Interrupted, "interrupted")?
        }
        Ended::Failed(why) => writer.finish_with("end-of-run", end_of_run::Status::Failed, why)?,
    }
    Ok(ended)
}
