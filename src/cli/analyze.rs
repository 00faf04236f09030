//! `chaoscope analyze FILE.mcap`: GALI_2..k, SALI, the MLE and Lyapunov spectrum, the energy
//! error and VM-versus-MPM differences of a recording, streamed (memory independent of the
//! length of the run); with `--clv`, the covariant Lyapunov vectors of a VM QR scheme instead
//! (growth rates and the angles between their subspaces, `chaoscope_analyzer::clv`).

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::Context;
use chaoscope_analyzer::analysis::AnalysisOptions;
use chaoscope_analyzer::clv::{
    ClvOptions, ClvOutput, clv_of_file, plot_angle_histograms, summary as clv_summary,
};
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
    /// With --plot, for a run on a square lattice: the times T1,T2,... of the pictures of the
    /// norm (or energy) distribution and the deviation vector distribution over the plane,
    /// DIR/plane-tT.png, each of the latest renormalization at or before T (default: four, a
    /// decade apart, ending at the run's end).
    #[arg(
        long,
        value_name = "T1,T2,...",
        value_delimiter = ',',
        requires = "plot"
    )]
    pub plane_times: Option<Vec<f64>>,
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
    /// Covariant Lyapunov vectors (Ginelli) of a VM scheme renormalized by QR, instead of the
    /// table: their growth rates beside the QR spectrum, and the distributions of the smallest
    /// angles between their unstable, neutral and stable subspaces (with --csv DIR, also their
    /// time series in DIR/clv-angles.csv; with --plot DIR, their histograms in
    /// DIR/clv-angle-NAME.png and .svg).
    #[arg(long)]
    pub clv: bool,
    /// Write the CLVs at every renormalization between the transients into DIR as NumPy files:
    /// DIR/clv-vectors.npy, shape (rows, k, dim), and their times DIR/clv-times.npy (those of
    /// clv-angles.csv).
    #[arg(long, value_name = "DIR", requires = "clv")]
    pub clv_vectors: Option<PathBuf>,
    /// The scheme of --clv (default: the first VM scheme with orthonormalize = "qr").
    #[arg(long, value_name = "NAME", requires = "clv")]
    pub clv_scheme: Option<String>,
    /// The set of directions of --clv (0-based).
    #[arg(long, value_name = "J", default_value_t = 0, requires = "clv")]
    pub clv_set: usize,
    /// Time discarded at the start for the QR basis to converge (default: a tenth of the run).
    #[arg(long, value_name = "T", requires = "clv")]
    pub clv_forward_transient: Option<f64>,
    /// Time discarded at the end for the backward iteration to converge (default: a tenth of
    /// the run).
    #[arg(long, value_name = "T", requires = "clv")]
    pub clv_backward_transient: Option<f64>,
    /// How many exponents count as neutral, the ones nearest zero (default: those the dynamics
    /// puts at zero: 0 for a map, 1 for a flow, 2 for a Hamiltonian; with k < dim, a flow's 0
    /// and a Hamiltonian's exponents N and N+1 of 2N among the first k).
    #[arg(long, value_name = "N", requires = "clv")]
    pub clv_neutral: Option<usize>,
    /// Memory for the stored QR factors before they spill to a temporary file, in MiB.
    #[arg(long, value_name = "MIB", default_value_t = 256, requires = "clv")]
    pub clv_memory: usize,
}

/// The human-readable table.
pub fn print_table(report: &Report) -> Result<(), StdoutError> {
    let table = chaoscope_analyzer::table::table(report);
    outln!("{}", table.trim_end_matches('\n'))?;
    Ok(())
}

pub fn main(args: Args) -> anyhow::Result<ExitCode> {
    // Nothing worth finalizing: a signal removes the unfinished outputs and ends at once.
    chaoscope_bus::signals::install(chaoscope_os::signals::Mode::Exit);
    let axis = match args.time_axis.as_str() {
        "auto" => TimeAxis::Auto,
        "log" => TimeAxis::Log,
        "linear" => TimeAxis::Linear,
        other => anyhow::bail!("--time-axis {other:?}: use auto, log or linear"),
    };
    if args.clv {
        return clv(&args);
    }
    // Refused before the file is read, as --from and --plane-times are: a NaN or a negative
    // time would report t = 0 as if it were asked for.
    if let Some(t) = args.at
        && !(t.is_finite() && t >= 0.0)
    {
        anyhow::bail!("--at {t}: a time from 0 on");
    }
    let options = AnalysisOptions {
        series_capacity: args.points,
        at: args.at.into_iter().collect(),
        site_profiles: args.plot.is_some(),
        plane_times: args.plane_times.clone(),
        exponents_from: args.from,
        ..chaoscope_app::flow::analysis_options()
    };
    let (analysis, info) = analyze_file(&args.file, &options)?;
    // What the analysis leaves out when the run's system cannot be rebuilt here (a table now
    // unreadable, a configuration this version refuses): said, not fatal.
    if let Some(why) = chaoscope_app::flow::why_no_system_of_run(analysis.run()) {
        chaoscope_os::errln!(
            "chaoscope analyze: warning: {}: no flow field and no site energies (the system is \
             rebuilt from the run's configuration): {why}",
            args.file.display()
        );
    }
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
        for skipped in chaoscope_analyzer::plane_png::planes(&analysis).1 {
            chaoscope_os::errln!("chaoscope analyze: {}: {skipped}", args.file.display());
        }
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

/// `analyze --clv`.
fn clv(args: &Args) -> anyhow::Result<ExitCode> {
    if args.at.is_some() || args.from.is_some() {
        anyhow::bail!(
            "--clv takes neither --at nor --from (its transients are \
             --clv-forward-transient and --clv-backward-transient)"
        );
    }
    if args.plane_times.is_some() {
        anyhow::bail!("--plane-times draws the distributions over a plane, which --clv does not");
    }
    let options = ClvOptions {
        scheme: args.clv_scheme.clone(),
        set: args.clv_set,
        forward_transient: args.clv_forward_transient,
        backward_transient: args.clv_backward_transient,
        neutral: args.clv_neutral,
        memory_bytes: args.clv_memory.saturating_mul(1 << 20),
        vectors: args.clv_vectors.is_some(),
    };
    let ClvOutput {
        report,
        angles,
        vectors,
    } = clv_of_file(&args.file, &options)?;
    if args.json {
        outln!("{}", serde_json::json!({ "clv": report }))?;
    } else {
        outln!("{}", clv_summary(&report).trim_end_matches('\n'))?;
    }
    let inputs = std::slice::from_ref(&args.file);
    if let Some(dir) = &args.csv {
        let file = angles
            .write_csv(dir, inputs)
            .with_context(|| format!("writing CSV into {}", dir.display()))?;
        chaoscope_os::errln!("chaoscope analyze: {}", file.display());
    }
    if let (Some(dir), Some(vectors)) = (&args.clv_vectors, vectors) {
        let files = vectors
            .write_npy(dir, inputs)
            .with_context(|| format!("writing the CLVs into {}", dir.display()))?;
        for file in files {
            chaoscope_os::errln!("chaoscope analyze: {}", file.display());
        }
    }
    if let Some(dir) = &args.plot {
        let files = plot_angle_histograms(&report, dir, inputs)?;
        chaoscope_os::errln!(
            "chaoscope analyze: {} plot files in {}",
            files.len(),
            dir.display()
        );
    }
    Ok(ExitCode::SUCCESS)
}
