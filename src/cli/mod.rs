//! One module per subcommand, plus helpers they share.

pub mod analyze;
pub mod bench;
pub mod chart;
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
pub mod run;
pub mod section;

use std::io::Read;
use std::path::Path;
use std::process::ExitCode;

use anyhow::Context;
use chaoscope_producer::estimate::{Estimate, Machine};
use chaoscope_schemas::config::RunConfig;

/// Exit code of a run stopped by SIGINT/SIGTERM (128 + SIGINT, the shell convention).
pub const EXIT_INTERRUPTED: u8 = 130;

/// Writes the one JSON summary line of `produce` and `record` to stdout. Its reader (`chaoscope
/// run`) may have been killed: the run's files are complete by then, so a closed pipe is not an
/// error of this process (and `println!` would panic on it).
pub fn print_summary(line: &serde_json::Value) {
    use std::io::Write;
    let _ = writeln!(std::io::stdout().lock(), "{line}");
}

pub fn exit_interrupted() -> ExitCode {
    ExitCode::from(EXIT_INTERRUPTED)
}

/// Largest configuration file read: far above any real config (a 10000-scheme config is about
/// 1 MiB), far below what would strain memory when a wrong file is given by mistake.
pub const MAX_CONFIG_BYTES: u64 = 16 << 20;

/// Reads a run configuration from a TOML file, or from stdin when `path` is `-`; returns it
/// with its canonical TOML text.
pub fn load_config(path: &Path) -> anyhow::Result<(RunConfig, String)> {
    let (name, bytes) = if path == Path::new("-") {
        let mut bytes = Vec::new();
        std::io::stdin()
            .take(MAX_CONFIG_BYTES + 1)
            .read_to_end(&mut bytes)
            .context("reading the run configuration from stdin")?;
        ("stdin".to_string(), bytes)
    } else {
        let file = std::fs::File::open(path)
            .with_context(|| format!("reading run configuration {}", path.display()))?;
        let mut bytes = Vec::new();
        file.take(MAX_CONFIG_BYTES + 1)
            .read_to_end(&mut bytes)
            .with_context(|| format!("reading run configuration {}", path.display()))?;
        (path.display().to_string(), bytes)
    };
    if bytes.len() as u64 > MAX_CONFIG_BYTES {
        anyhow::bail!(
            "{name}: larger than {} MiB, which no run configuration is (is it the right file?)",
            MAX_CONFIG_BYTES >> 20
        );
    }
    let text = String::from_utf8(bytes).map_err(|e| {
        anyhow::anyhow!(
            "{name}: not a text file (invalid UTF-8 at byte {}); a run configuration is TOML",
            e.utf8_error().valid_up_to()
        )
    })?;
    let config = RunConfig::from_file_text(&text, path).with_context(|| format!("in {name}"))?;
    // The canonical text, with table paths joined to the config's directory: the producer
    // child reads it from stdin, where the file's own directory is unknown.
    let text = config.to_toml();
    Ok((config, text))
}

/// This machine's cores and memory (`MemTotal` of /proc/meminfo), for the resource estimate.
pub fn machine() -> Machine {
    let memory_bytes = std::fs::read_to_string("/proc/meminfo").ok().and_then(|m| {
        let line = m.lines().find(|l| l.starts_with("MemTotal:"))?;
        let kib: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
        kib.checked_mul(1024)
    });
    Machine {
        cores: std::thread::available_parallelism().map_or(1, |n| n.get()),
        memory_bytes,
    }
}

/// Refuses, before it starts, work estimated to take more than a day or more memory than the
/// machine has, unless `force`; with `force` it says so and goes on.
pub fn check_estimate(
    estimate: Option<&Estimate>,
    machine: &Machine,
    force: bool,
    command: &str,
) -> anyhow::Result<()> {
    if let Some(why) = estimate.and_then(|e| e.refusal(machine)) {
        if !force {
            anyhow::bail!("{why}");
        }
        eprintln!("chaoscope {command}: --force: starting although {why}");
    }
    Ok(())
}

/// Parses a duration in seconds (fractions allowed) for `--*-timeout` style options.
pub fn parse_seconds(s: &str) -> Result<std::time::Duration, String> {
    let v: f64 = s
        .parse()
        .map_err(|_| format!("{s:?} is not a number of seconds"))?;
    std::time::Duration::try_from_secs_f64(v)
        .map_err(|_| format!("{s:?} is not a valid number of seconds"))
}
