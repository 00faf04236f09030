//! One module per subcommand, plus helpers they share.

pub mod analyze;
pub mod chart;
pub mod config;
pub mod map;
pub mod map_watch;
pub mod merge;
pub mod monitor;
mod monitor_foxglove;
mod monitor_view;
pub mod produce;
pub mod record;
pub mod recover;
pub mod replay;
pub mod resume;
pub mod run;
pub mod section;

use std::path::Path;
use std::process::ExitCode;

use anyhow::Context;
use chaoscope_dynamics::estimate::{Estimate, Machine};
use chaoscope_dynamics::spec::SpecError;
use chaoscope_schemas::config::{ConfigSource, RunConfig};

/// Writes the one JSON summary line of `produce` and `record` to stdout. Its reader (`chaoscope
/// run`) may have been killed: the run's files are complete by then, so a closed pipe (or any
/// failure to print it) is not an error of this process.
pub fn print_summary(line: &serde_json::Value) {
    let _ = chaoscope_os::outln!("{line}");
}

/// Exit status of a command stopped by SIGINT (130) or SIGTERM (143): 128 + the signal, as a
/// shell reports a process killed by it. A stop without a signal (`map --stop-after`) counts
/// as SIGINT.
pub fn exit_interrupted() -> ExitCode {
    let signal = chaoscope_os::signals::received().unwrap_or(libc::SIGINT);
    ExitCode::from(chaoscope_os::signals::exit_status(signal))
}

/// Reads a run configuration from a TOML file, or from stdin when `path` is `-`; returns it
/// with its canonical TOML text, and the text as read (which [`invalid_config`] places the
/// keys of validation errors in).
pub fn load_config(path: &Path) -> anyhow::Result<(RunConfig, String, ConfigSource)> {
    let (config, source) = if path == Path::new("-") {
        // Standard input may never end (a terminal, a pipe no one closes): a signal ends the
        // command during the read even where it would otherwise finalize first.
        let bytes = chaoscope_os::signals::exit_on_signal_while(|| {
            chaoscope_schemas::config::read_bounded(std::io::stdin())
        })
        .context("reading the run configuration from stdin")?;
        chaoscope_schemas::config::parse_config_source("stdin", bytes, path)?
    } else {
        chaoscope_schemas::config::read_config_source(path)?
    };
    // The canonical text, with table paths joined to the config's directory: the producer
    // child reads it from stdin, where the file's own directory is unknown.
    let text = config.to_toml();
    Ok((config, text, source))
}

/// A validation error of the config read from `source`, with the file and the line and column
/// of the key it names, as a TOML error of the file is written (`what`: `run` or `map`).
pub fn invalid_config(source: &ConfigSource, what: &str, e: SpecError) -> anyhow::Error {
    anyhow::anyhow!(source.describe(what, &e.key, &e.message))
}

/// Says on stderr which parameters of an expression model no expression reads: a warning, not
/// an error (a user comments expressions in and out), once the config is valid.
pub fn warn_unused_params(command: &str, config: &RunConfig) {
    for unused in chaoscope_dynamics::spec::unused_params(&config.model) {
        chaoscope_os::errln!("chaoscope {command}: warning: {unused}");
    }
}

/// Says on stderr which axes of a valid map grid a periodic coordinate over a whole period,
/// so that their last line repeats the first (`map::spec::repeated_grid_lines`).
pub fn warn_repeated_grid_lines(command: &str, config: &RunConfig) {
    for repeated in chaoscope_dynamics::map::spec::repeated_grid_lines(config) {
        chaoscope_os::errln!("chaoscope {command}: warning: {repeated}");
    }
}

/// This machine's cores and memory, for the resource estimate.
pub fn machine() -> Machine {
    Machine::this_host()
}

/// Refuses, before it starts, work estimated to take more than a day or more memory than the
/// machine has, unless `force`; with `force` it says so and goes on.
pub fn check_estimate(
    estimate: &Estimate,
    machine: &Machine,
    force: bool,
    command: &str,
) -> anyhow::Result<()> {
    if let Some(why) = estimate.refusal(machine) {
        if !force {
            anyhow::bail!("{why}");
        }
        chaoscope_os::errln!("chaoscope {command}: --force: starting although {why}");
    }
    Ok(())
}

/// A duration for a summary, beside its estimate: `0.42 s`, `12.3 s`, `1.5e4 s`.
pub fn seconds(s: f64) -> String {
    if s < 1.0 {
        format!("{s:.2} s")
    } else if s < 1e4 {
        format!("{s:.1} s")
    } else {
        format!("{s:.1e} s")
    }
}

/// Parses a duration in seconds (fractions allowed) for `--*-timeout` style options.
pub fn parse_seconds(s: &str) -> Result<std::time::Duration, String> {
    let v: f64 = s
        .parse()
        .map_err(|_| format!("{s:?} is not a number of seconds"))?;
    std::time::Duration::try_from_secs_f64(v)
        .map_err(|_| format!("{s:?} is not a valid number of seconds"))
}
