//! `chaoscope analyze FILE.mcap`: GALI_2..k, SALI, the MLE and Lyapunov spectrum, the energy
//! error and VM-versus-MPM differences of a recording, streamed (memory independent of the
//! length of the run).

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::Context;
use chaoscope_analyzer::analysis::AnalysisOptions;
use chaoscope_analyzer::plot::{TimeAxis, plot_all};
use chaoscope_analyzer::recording::analyze_file;
use chaoscope_analyzer::report::Report;
use chaoscope_os::outln;
use chaoscope_os::stdout::StdoutError;

#[derive(clap::Args)]
pub struct Args {
    /// Recording to analyze.
    pub file: PathBuf,
    /// Report values as of time T (the latest renormalization at t <= T of each scheme).
    #[arg(long)]
    pub at: Option<f64>,
    /// Print one JSON object instead of the table.
    #[arg(long)]
    pub json: bool,
    /// Write the curves as CSV files into DIR.
    #[arg(long, value_name = "DIR")]
    pub csv: Option<PathBuf>,
    /// Draw the curves (PNG and SVG) into DIR.
    #[arg(long, value_name = "DIR")]
    pub plot: Option<PathBuf>,
    /// Time axis of GALI plots: auto (log t for regular orbits, t for chaotic), log, linear.
    #[arg(long, default_value = "auto")]
    pub time_axis: String,
    /// Discard a transient: the finite-time Lyapunov exponents average the stretching from
    /// time T on (nothing else changes; the verdict judges the whole run).
    #[arg(long, value_name = "T")]
    pub from: Option<f64>,
    /// Evenly spaced points kept per curve (plus 40 log-spaced per decade).
    #[arg(long, default_value_t = 2000)]
    pub points: usize,
}

/// The human-readable table.
pub fn print_table(report: &Report) -> Result<(), StdoutError> {
    let table = chaoscope_analyzer::table::table(report);
    outln!("{}", table.trim_end_matches('\n'))?;
    Ok(())
}

pub fn main(args: Args) -> anyhow::Result<ExitCode> {
    // Nothing worth finalizing: a signal removes the unfinished outputs and ends at once.
    chaoscope_os::signals::install(chaoscope_os::signals::Mode::Exit);
    let axis = match args.time_axis.as_str() {
        "auto" => TimeAxis::Auto,
        "log" => TimeAxis::Log,
        "linear" => TimeAxis::Linear,
        other => anyhow::bail!("--time-axis {other:?}: use auto, log or linear"),
    };
    let options = AnalysisOptions {
        series_capacity: args.points,
        at: args.at.into_iter().collect(),
        flow_field: Some(chaoscope_replay::flow::flow_field_of_run),
        exponents_from: args.from,
        ..Default::default()
    };
    let (analysis, info) = analyze_file(&args.file, &options)?;
    let report = match args.at {
        Some(t) => analysis.report_at(t).expect("requested time is captured"),
        None => analysis.report_ended(info.end.as_ref()),
    };
    if args.json {
        outln!("{}", serde_json::to_string(&report)?)?;
    } else {
        print_table(&report)?;
    }
    if let Some(dir) = &args.csv {
        let files =
            chaoscope_analyzer::csv::write_csv(&analysis, dir, std::slice::from_ref(&args.file))
                .with_context(|| format!("writing CSV into {}", dir.display()))?;
        chaoscope_os::errln!(
            "chaoscope analyze: {} CSV files in {}",
            files.len(),
            dir.display()
        );
    }
    if let Some(dir) = &args.plot {
        let files = plot_all(
            &analysis,
            &report,
            dir,
            axis,
            std::slice::from_ref(&args.file),
        )?;
        chaoscope_os::errln!(
            "chaoscope analyze: {} plot files in {}",
            files.len(),
            dir.display()
        );
    }
    Ok(ExitCode::SUCCESS)
}
