//! `chaoscope replay FILE.mcap --tau T [--tau T2 ...] [--d0 D ...] --out NEW.mcap`: re-run the
//! recorded configuration with other renormalization settings on the identical reference orbit
//! and initial directions, proving it by a bit-for-bit comparison of every recorded reference
//! state. Exits non-zero if anything differs.

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::bail;
use chaoscope_replay::{ReplayOptions, replay};

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
    /// Replace the output file if it exists.
    #[arg(long)]
    pub force: bool,
    /// Print the comparison as JSON.
    #[arg(long)]
    pub json: bool,
}

pub fn main(args: Args) -> anyhow::Result<ExitCode> {
    if args.out.exists() && !args.force {
        bail!(
            "{} already exists (pass --force to replace it)",
            args.out.display()
        );
    }
    if args.out.canonicalize().ok() == args.file.canonicalize().ok() && args.out.exists() {
        bail!("--out must differ from the input recording");
    }
    let options = ReplayOptions {
        taus: args.taus,
        d0s: args.d0s,
        without_original: args.without_original,
        stop: None,
    };
    let outcome = replay(&args.file, &args.out, &options)?;
    if args.json {
        println!("{}", serde_json::to_string(&outcome)?);
    } else {
        println!(
            "replay: {} ({} samples)",
            args.out.display(),
            outcome.replay_samples
        );
        println!("schemes: {}", outcome.schemes.join(", "));
        println!(
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
        );
        if outcome.separation_sets_compared > 0 {
            println!(
                "original schemes: {} of {} separation sets bit-identical",
                outcome.separation_sets_identical, outcome.separation_sets_compared
            );
        }
    }
    if outcome.identical() {
        Ok(ExitCode::SUCCESS)
    } else {
        eprintln!(
            "chaoscope replay: the replay DIFFERS from the recording (first at step {:?})",
            outcome.first_difference_step
        );
        Ok(ExitCode::from(2))
    }
}
