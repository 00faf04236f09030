//! `chaoscope replay FILE.mcap --tau T [--tau T2 ...] [--d0 D ...] --out NEW.mcap`: re-run the
//! recorded configuration with other renormalization settings on the identical reference orbit
//! and initial directions, proving it by a bit-for-bit comparison of every recorded reference
//! state. Exits non-zero if anything differs.

use std::path::PathBuf;
use std::process::ExitCode;

use chaoscope_app::{ReplayOptions, replay};
use chaoscope_os::outln;

#[derive(clap::Args)]
pub struct Args {
    /// The recording to replay.
    pub file: PathBuf,
    /// New renormalization period (repeatable).
    #[arg(long = "tau")]
    pub taus: Vec<f64>,
    /// New deviation distance d0 (repeatable).
    #[arg(long = "d0")]
    pub d0s: Vec<f64>,
    /// Output recording.
    #[arg(long)]
    pub out: PathBuf,
    /// Do not re-run the original schemes (then only common sample times are compared).
    #[arg(long)]
    pub without_original: bool,
    /// Replace the output file if it exists, and start even a replay estimated to take more
    /// than a day or more memory than the machine has.
    #[arg(long)]
    pub force: bool,
    /// Print the comparison as JSON.
    #[arg(long)]
    pub json: bool,
}

pub fn main(args: Args) -> anyhow::Result<ExitCode> {
    chaoscope_bus::signals::install(chaoscope_os::signals::Mode::Finish);
    let options = ReplayOptions {
        taus: args.taus,
        d0s: args.d0s,
        without_original: args.without_original,
        stop: None,
        force: args.force,
        transport: chaoscope_producer::estimate::BUS,
    };
    let outcome = replay(&args.file, &args.out, &options)?;
    if args.json {
        outln!("{}", serde_json::to_string(&outcome)?)?;
    } else {
        outln!(
            "replay: {} ({} samples{}) in {} (estimated {})",
            args.out.display(),
            outcome.replay_samples,
            if outcome.interrupted {
                ", interrupted"
            } else {
                ""
            },
            super::seconds(outcome.seconds),
            super::seconds(outcome.estimated_seconds)
        )?;
        outln!("schemes: {}", outcome.schemes.join(", "))?;
        outln!(
            "reference states: {} of {} recorded states bit-identical{}",
            outcome.reference_states_identical,
            outcome.reference_states_compared,
            if outcome.reference_states_not_sampled > 0 {
                format!(
                    " ({} recorded times not sampled by the replay)",
                    outcome.reference_states_not_sampled
                )
            } else {
                String::new()
            }
        )?;
        if outcome.separation_sets_compared > 0 {
            outln!(
                "original schemes: {} of {} separation sets bit-identical",
                outcome.separation_sets_identical,
                outcome.separation_sets_compared
            )?;
        }
        if !outcome.comparison.is_empty() {
            outln!(
                "against the original schemes at the end (log10 GALI: geometric mean over the sets):"
            )?;
            for c in &outcome.comparison {
                let gali: Vec<String> = c
                    .gali_delta_log10
                    .0
                    .iter()
                    .map(|(j, d)| format!("GALI_{j} {d:+.3}"))
                    .collect();
                outln!(
                    "  {} vs {}: t = {}, MLE {:.6} ({:+.2e}){}{}",
                    c.scheme,
                    c.of,
                    c.t,
                    c.mle,
                    c.mle_delta,
                    if gali.is_empty() { "" } else { ", " },
                    gali.join(", ")
                )?;
            }
        }
    }
    if outcome.first_difference_step.is_some() || !outcome.interrupted && !outcome.identical() {
        chaoscope_os::errln!(
            "chaoscope replay: the replay DIFFERS from the recording (first at step {:?})",
            outcome.first_difference_step
        );
        return Ok(ExitCode::from(2));
    }
    if outcome.interrupted {
        return Ok(super::exit_interrupted());
    }
    Ok(ExitCode::SUCCESS)
}
