//! `chaoscope produce CONFIG`: integrate a run and publish it on the bus.

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Duration;

use chaoscope_dynamics::spec::RunSpec;
use chaoscope_producer::{self as publish, PublishOptions, RunStatus};

#[derive(clap::Args)]
pub struct Args {
    /// Run configuration (TOML); `-` reads it from stdin.
    pub config: PathBuf,
    /// Run name (bus service names derive from it); default: `[run] name` or generated.
    #[arg(long)]
    pub run: Option<String>,
    /// Lossless subscribers (recorders) to wait for before the first sample; 0 starts at once.
    #[arg(long, default_value_t = 1)]
    pub recorders: usize,
    /// Give up if the recorders have not subscribed after this many seconds.
    #[arg(long, value_parser = super::parse_seconds)]
    pub wait_timeout: Option<Duration>,
    /// No progress bar.
    #[arg(long)]
    pub no_progress: bool,
    /// Start even a run estimated to take more than a day or more memory than the machine has.
    #[arg(long)]
    pub force: bool,
    /// Started by `chaoscope run`: say `open` on stdout once the run's services are open, and
    /// leave reporting a failed recorder to `run` (the recorder says why).
    #[arg(long, hide = true)]
    pub under_run: bool,
}

/// The line `chaoscope run` waits for before it starts the recorder.
pub const OPEN_LINE: &str = "open";

fn say_open() {
    use std::io::Write;
    let mut out = std::io::stdout().lock();
    let _ = writeln!(out, "{OPEN_LINE}");
    let _ = out.flush();
}

pub fn main(args: Args) -> anyhow::Result<ExitCode> {
    chaoscope_bus::signals::install(chaoscope_os::signals::Mode::Finish);
    let (config, _, source) = super::load_config(&args.config)?;
    let spec =
        RunSpec::from_config(&config).map_err(|e| super::invalid_config(&source, "run", e))?;
    // Under `run` the text on stdin is the one `run` estimated and let start (with `--force`
    // passed on): a second calibration would only add its CPU time to every run.
    if !args.under_run {
        let machine = super::machine();
        let estimate = chaoscope_producer::estimate::run(&spec, &machine);
        super::check_estimate(&estimate, &machine, args.force, "produce")?;
    }
    let options = PublishOptions {
        run_name: args.run,
        recorders: args.recorders,
        wait_timeout: args.wait_timeout,
        progress: !args.no_progress,
        on_open: args.under_run.then_some(say_open as fn()),
        ..PublishOptions::default()
    };
    let outcome = publish::publish(&config, spec, &options)?;
    let (status, reason) = match &outcome.status {
        RunStatus::Completed => ("completed", ""),
        RunStatus::Interrupted => ("interrupted", ""),
        RunStatus::Failed(r) => ("failed", r.as_str()),
    };
    let secs = outcome.elapsed.as_secs_f64();
    // One JSON line on stdout: `chaoscope run` and the benchmarks read it.
    super::print_summary(&serde_json::json!({
        "role": "producer",
        "run": outcome.run,
        "status": status,
        "reason": reason,
        "samples": outcome.samples,
        "frames": outcome.frames,
        "payload_bytes": outcome.payload_bytes,
        "seconds": secs,
        "streaming_seconds": outcome.streaming.as_secs_f64(),
    }));
    Ok(match outcome.status {
        RunStatus::Completed => ExitCode::SUCCESS,
        RunStatus::Interrupted => super::exit_interrupted(),
        RunStatus::Failed(reason) => {
            if !(args.under_run && reason == publish::RECORDERS_LEFT) {
                chaoscope_os::errln!("chaoscope produce: run {} failed: {reason}", outcome.run);
            }
            ExitCode::from(3)
        }
    })
}
