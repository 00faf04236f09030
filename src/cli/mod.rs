//! One module per subcommand, plus helpers they share.

pub mod analyze;
pub mod bench;
pub mod chart;
pub mod map;
pub mod map_watch;
pub mod merge;
pub mod monitor;
mod monitor_view;
pub mod produce;
pub mod record;
pub mod recover;
pub mod replay;
pub mod run;
pub mod section;

use std::io::Read;
use std::path::Path;
use std::process::ExitCode;

use anyhow::Context;
use chaoscope_schemas::config::RunConfig;

/// Exit code of a run stopped by SIGINT/SIGTERM (128 + SIGINT, the shell convention).
pub const EXIT_INTERRUPTED: u8 = 130;

pub fn exit_interrupted() -> ExitCode {
    ExitCode::from(EXIT_INTERRUPTED)
}

/// Reads a run configuration from a TOML file, or from stdin when `path` is `-`; returns it
/// with its canonical TOML text.
pub fn load_config(path: &Path) -> anyhow::Result<(RunConfig, String)> {
    let text = if path == Path::new("-") {
        let mut text = String::new();
        std::io::stdin()
            .read_to_string(&mut text)
            .context("reading the run configuration from stdin")?;
        text
    } else {
        std::fs::read_to_string(path)
            .with_context(|| format!("reading run configuration {}", path.display()))?
    };
    let config =
        RunConfig::from_file_text(&text, path).with_context(|| format!("in {}", path.display()))?;
    // The canonical text, with table paths joined to the config's directory: the producer
    // child reads it from stdin, where the file's own directory is unknown.
    let text = config.to_toml();
    Ok((config, text))
}

/// Parses a duration in seconds (fractions allowed) for `--*-timeout` style options.
pub fn parse_seconds(s: &str) -> Result<std::time::Duration, String> {
    let v: f64 = s
        .parse()
        .map_err(|_| format!("{s:?} is not a number of seconds"))?;
    std::time::Duration::try_from_secs_f64(v)
        .map_err(|_| format!("{s:?} is not a valid number of seconds"))
}
