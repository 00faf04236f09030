//! `chaoscope resume RECORDING [--t-final T] [--out OUT]`: continue a killed, interrupted or
//! finished run from its last complete sample, into the file the uninterrupted run would have
//! written (`chaoscope_app::resume`).

use std::path::PathBuf;
use std::process::ExitCode;

use chaoscope_app::resume::{ResumeOptions, ResumeOutcome, resume};
use chaoscope_os::outln;

#[derive(clap::Args)]
pub struct Args {
    /// The recording (a killed run's in-progress `NAME.partial` is found from `NAME`).
    pub recording: PathBuf,
    /// The run's new end: later than the recorded `t_final` extends a finished run.
    #[arg(long)]
    pub t_final: Option<f64>,
    /// Where the resumed recording goes; default: in place of RECORDING, replaced only once
    /// the resumed one is complete.
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Replace OUT if it exists, and start even a resumed run estimated (to its new end) to
    /// take more than a day or more memory than the machine has, as `run --force` does.
    #[arg(long)]
    pub force: bool,
    /// Print what was done as JSON.
    #[arg(long)]
    pub json: bool,
}

pub fn main(args: Args) -> anyhow::Result<ExitCode> {
    chaoscope_bus::signals::install(chaoscope_os::signals::Mode::Finish);
    let options = ResumeOptions {
        t_final: args.t_final,
        out: args.out,
        force: args.force,
        config: None,
        stop: None,
        estimated: false,
        transport: chaoscope_producer::estimate::BUS,
    };
    let outcome = resume(&args.recording, &options)?;
    report(&outcome, args.json)
}

/// Prints what a resume did and gives the exit status: 0 when the run completed, the signal's
/// status when interrupted, 3 when the run failed (an escaped orbit: the file says so), as
/// `run` exits.
pub fn report(outcome: &ResumeOutcome, json: bool) -> anyhow::Result<ExitCode> {
    if json {
        outln!("{}", serde_json::to_string(outcome)?)?;
    } else {
        outln!(
            "resume: {} from t = {} (sample {}): {} samples copied, {} computed, {} at t = {} \
             of t_final = {} in {} (estimated {})",
            outcome.output.display(),
            outcome.resumed_from_t,
            outcome.resumed_from_seq,
            outcome.samples_copied,
            outcome.samples_computed,
            outcome.status,
            outcome.t_reached,
            outcome.t_final,
            super::seconds(outcome.seconds),
            super::seconds(outcome.estimated_seconds)
        )?;
        if let Some(damage) = &outcome.input_damage {
            outln!(
                "read {} up to its last complete chunk ({damage})",
                outcome.input.display()
            )?;
        }
    }
    Ok(match outcome.status.as_str() {
        "completed" => ExitCode::SUCCESS,
        "interrupted" => super::exit_interrupted(),
        _ => {
            chaoscope_os::errln!(
                "chaoscope resume: the run failed: {}",
                outcome.reason.as_deref().unwrap_or("")
            );
            ExitCode::from(3)
        }
    })
}
