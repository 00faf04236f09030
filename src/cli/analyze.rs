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
    /// Evenly spaced points kept per curve (plus 40 log-spaced per decade).
    #[arg(long, default_value_t = 2000)]
    pub points: usize,
}

/// The human-readable table.
pub fn print_table(report: &Report) {
    let r = &report.run;
    let size = if r.kind == "hamiltonian" {
        format!("N = {}", r.n)
    } else {
        format!("{}, D = {}", r.kind, r.dim)
    };
    // What applies: the energy error of a Hamiltonian, the contraction rate of anything else.
    let conserved = match (r.energy_error_max, r.mean_divergence) {
        (Some(e), _) => format!("max energy error {e:.2e}"),
        (None, Some(d)) => format!("mean divergence {d:.6}"),
        (None, None) => String::new(),
    };
    println!(
        "run {} ({}, {size}, {} with h = {}): t = {} of {}, {} samples, k = {}, {} sets, \
         {conserved}{}",
        r.name,
        r.model,
        r.integrator,
        r.h,
        r.t,
        r.t_final,
        r.samples,
        r.k,
        r.sets,
        if r.complete {
            ""
        } else {
            " (INCOMPLETE: frames missing)"
        }
    );
    if let Some(end) = r.end.as_ref().filter(|e| e.status != "completed") {
        println!("the run {}: {}", end.status, end.reason);
    }
    let k = r.k;
    let mut head = format!(
        "{:<22} {:>4} {:>8} {:>7} {:>5} {:>9}",
        "scheme", "meth", "d0", "tau", "sets", "t"
    );
    for j in 2..=k {
        head += &format!(" {:>9}", format!("lgGALI{j}"));
    }
    head += &format!(" {:>9} {:>10}  {}", "lgSALI", "MLE", "MPM-VM |dlg GALI_j|");
    println!("{head}");
    for s in &report.schemes {
        let mut line = format!(
            "{:<22} {:>4} {:>8.0e} {:>7} {:>5} {:>9}",
            s.name, s.method, s.d0, s.tau, s.sets, s.t
        );
        for j in 2..=k {
            line += &format!(" {:>9.3}", s.gali.get(j).map_or(f64::NAN, |g| g.log10_mean));
        }
        line += &format!(
            " {:>9.3} {:>10.6}",
            s.sali.map_or(f64::NAN, |v| v.log10_mean),
            s.mle
        );
        if let Some(v) = &s.vs_vm {
            let d: Vec<String> = v
                .gali
                .0
                .iter()
                .map(|(_, d)| format!("{:.1e}", d.mean_abs_delta_log10))
                .collect();
            line += &format!("  vs {}: {}", v.scheme, d.join(" "));
        }
        if s.lyapunov.len() > 1 {
            let l: Vec<String> = s.lyapunov.iter().map(|l| format!("{l:.6}")).collect();
            line += &format!("  spectrum: {}", l.join(" "));
        }
        if let Some(sum) = s.lyapunov_sum {
            line += &format!(" (sum {sum:.6})");
        }
        println!("{line}");
    }
    for s in &report.schemes {
        let v = &s.verdict;
        let class = match v.torus_dimension {
            Some(d) => format!("{} (on a {d}-torus)", v.class.word()),
            None => v.class.word().to_string(),
        };
        println!(
            "{}: {class}, confidence {:.2}: {}",
            s.name, v.confidence, v.criterion
        );
        for w in &s.warnings {
            println!("{}: warning {}: {}", s.name, w.code, w.message);
        }
    }
}

pub fn main(args: Args) -> anyhow::Result<ExitCode> {
    let axis = match args.time_axis.as_str() {
        "auto" => TimeAxis::Auto,
        "log" => TimeAxis::Log,
        "linear" => TimeAxis::Linear,
        other => anyhow::bail!("--time-axis {other:?}: use auto, log or linear"),
    };
    let options = AnalysisOptions {
        series_capacity: args.points,
        at: args.at.into_iter().collect(),
        ..Default::default()
    };
    let (analysis, info) = analyze_file(&args.file, &options)?;
    let report = match args.at {
        Some(t) => analysis.report_at(t).expect("requested time is captured"),
        None => analysis.report_ended(info.end.as_ref()),
    };
    if args.json {
        use std::io::Write;
        // A closed pipe (`| head`) is not an error worth a panic.
        let _ = writeln!(
            std::io::stdout().lock(),
            "{}",
            serde_json::to_string(&report)?
        );
    } else {
        print_table(&report);
    }
    if let Some(dir) = &args.csv {
        let files = chaoscope_analyzer::csv::write_csv(&analysis, dir)
            .with_context(|| format!("writing CSV into {}", dir.display()))?;
        eprintln!(
            "chaoscope analyze: {} CSV files in {}",
            files.len(),
            dir.display()
        );
    }
    if let Some(dir) = &args.plot {
        let files = plot_all(&analysis, &report, dir, axis)?;
        eprintln!(
            "chaoscope analyze: {} plot files in {}",
            files.len(),
            dir.display()
        );
    }
    Ok(ExitCode::SUCCESS)
}
