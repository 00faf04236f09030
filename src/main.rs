//! `chaoscope`: the front door. Each subcommand lives in `cli/<command>.rs` with an `Args`
//! struct and a `main(args) -> anyhow::Result<ExitCode>`; this file only dispatches.

mod cli;
#[cfg(test)]
mod guide;

use std::io::Write;
use std::process::ExitCode;

use chaoscope_os::stdout::StdoutError;
use clap::{Parser, Subcommand};

#[derive(Parser)]
#[command(
    name = "chaoscope",
    version,
    about = "Chaos indicators (GALI, SALI, Lyapunov exponents) streamed to MCAP"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Run producer and recorder as separate processes, then print the analysis summary.
    Run(cli::run::Args),
    /// Integrate a run and publish it on the iceoryx2 bus.
    Produce(cli::produce::Args),
    /// Record a run from the bus into an MCAP file.
    Record(cli::record::Args),
    /// Analyze a recording: GALI, SALI, Lyapunov exponents, energy error (table, JSON, CSV, plots).
    Analyze(cli::analyze::Args),
    /// Follow a running producer live (terminal view or --json-lines), never slowing it.
    Monitor(cli::monitor::Args),
    /// Poincare section: of many orbits of one energy (q_i = 0), or of any flow through a
    /// surface written as an expression (--surface).
    Section(cli::section::Args),
    /// Draw a chart described in JSON (PNG and SVG).
    Chart(cli::chart::Args),
    /// Re-run a recording with other tau/d0 on the bit-identical reference orbit.
    Replay(cli::replay::Args),
    /// Continue a killed, interrupted or finished run from its recording (--t-final extends it).
    Resume(cli::resume::Args),
    /// Salvage an MCAP file whose writer was killed.
    Recover(cli::recover::Args),
    /// Compute a phase-space map (one chaos indicator per grid point) into MCAP and PNG.
    Map(cli::map::Args),
    /// Follow a running `map` live, one line per finished point (or --json-lines).
    MapWatch(cli::map_watch::Args),
    /// Join the shard recordings of `map --shard i/n` into one map.
    Merge(cli::merge::Args),
    /// Throughput of the batched kernel and the paper's GALI_2 map workload, as JSON.
    Bench(chaoscope_bench::Args),
    /// Validate a configuration without running it, or print the JSON Schema of configurations
    /// (--schema) for TOML editors.
    Config(cli::config::Args),
}

/// The exit status of a command line that does not parse (an unknown option, a value of the
/// wrong type: `replay --tau abc`): sysexits' `EX_USAGE`. clap's own 2 is a result status here
/// (`replay`: the replayed orbit differs), and a script must tell a mistyped command from a
/// finding; 64 is outside every result status (0 to 3) and the signals' 128 + n.
const USAGE_STATUS: u8 = 64;

fn main() -> ExitCode {
    // A write past RLIMIT_FSIZE (a file-size quota) must fail with EFBIG, reported with the file
    // it was for and handled like any failed write (complete chunks kept), instead of killing
    // the process with SIGXFSZ and no message.
    // SAFETY: setting a signal's disposition to SIG_IGN before any thread starts.
    unsafe { libc::signal(libc::SIGXFSZ, libc::SIG_IGN) };
    // SIGINT/SIGTERM from the first instant: until a command says it finalizes its files
    // (`Mode::Finish`), a signal removes this process's unfinished outputs and exits with
    // 128 + the signal (130, 143).
    chaoscope_bus::signals::install(chaoscope_os::signals::Mode::Exit);
    let cli = match Cli::try_parse() {
        Ok(cli) => cli,
        Err(e) => {
            // `--help` and `--version` (clap's status 0, on stdout) are answers, not errors.
            let _ = e.print();
            return if e.exit_code() == 0 {
                ExitCode::SUCCESS
            } else {
                ExitCode::from(USAGE_STATUS)
            };
        }
    };
    let result = match cli.command {
        Command::Run(args) => cli::run::main(args),
        Command::Produce(args) => cli::produce::main(args),
        Command::Record(args) => cli::record::main(args),
        Command::Recover(args) => cli::recover::main(args),
        Command::Analyze(args) => cli::analyze::main(args),
        Command::Replay(args) => cli::replay::main(args),
        Command::Resume(args) => cli::resume::main(args),
        Command::Monitor(args) => cli::monitor::main(args),
        Command::Map(args) => cli::map::main(args),
        Command::MapWatch(args) => cli::map_watch::main(args),
        Command::Merge(args) => cli::merge::main(args),
        Command::Bench(args) => chaoscope_bench::main(args),
        Command::Section(args) => cli::section::main(args),
        Command::Chart(args) => cli::chart::main(args),
        Command::Config(args) => cli::config::main(args),
    };
    // What `print!` left buffered, and whether stdout took it (a full disk fails here).
    let result = result.and_then(|code| Ok(chaoscope_os::stdout::flush().map(|()| code)?));
    result.unwrap_or_else(|e| {
        // A reader that went away (`| head`) ends the command quietly, as SIGPIPE would.
        if let Some(StdoutError::Closed) = e.downcast_ref::<StdoutError>() {
            return ExitCode::from(chaoscope_os::stdout::CLOSED_STATUS);
        }
        // Not `eprintln!`, which panics when stderr is closed or full.
        let _ = writeln!(
            std::io::stderr().lock(),
            "chaoscope: error: {}",
            with_kept_files(one_line(&e))
        );
        ExitCode::FAILURE
    })
}

/// The error line, naming every in-progress file the failure kept (what was written, left for
/// the next attempt, which says how to continue or discard it) that it does not name yet.
fn with_kept_files(mut line: String) -> String {
    for kept in chaoscope_os::output::kept_after_failure() {
        let kept = kept.display().to_string();
        if !line.contains(&kept) {
            line.push_str(&format!("; what was written is kept in {kept}"));
        }
    }
    line
}

/// The error and its causes on one line, each cause once: many errors quote their cause in
/// their own message (`FILE: No such file or directory`), and `{:#}` would repeat it.
fn one_line(e: &anyhow::Error) -> String {
    let mut line = String::new();
    for cause in e.chain() {
        let text = cause.to_string();
        if line.contains(&text) {
            continue;
        }
        if !line.is_empty() {
            line.push_str(": ");
        }
        line.push_str(&text);
    }
    line
}
