//! `chaoscope section CONFIG --vary q2 --from A --to B --count N --plot DIR`: a Poincare
//! surface of section (crossings of `q_i = 0` with `p_i > 0`, where `p_i` is the config's
//! `solve_for` momentum) of many orbits of the configured energy, started along one coordinate.

use std::io::Write;
use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::{Context, bail};
use chaoscope_analyzer::chart::{Chart, Line, Stroke, render};
use chaoscope_os::{Leftover, Output, OutputOptions};
use chaoscope_producer::section::crossings;
use chaoscope_producer::spec::{RunSpec, parse_coordinate};

#[derive(clap::Args)]
pub struct Args {
    /// Run configuration: model, energy and `solve_for` (the crossing plane is q_i = 0 for
    /// `solve_for = "p_i"`), integrator and h; `t_final` bounds each orbit.
    pub config: PathBuf,
    /// Coordinate along which orbits are started (e.g. q2); its conjugate momentum is the
    /// vertical axis of the plot.
    #[arg(long)]
    pub vary: String,
    #[arg(long, allow_hyphen_values = true)]
    pub from: f64,
    #[arg(long, allow_hyphen_values = true)]
    pub to: f64,
    #[arg(long, default_value_t = 30)]
    pub count: usize,
    /// Crossings kept per orbit.
    #[arg(long, default_value_t = 400)]
    pub crossings: usize,
    /// Draw section.png / section.svg into DIR.
    #[arg(long)]
    pub plot: Option<PathBuf>,
    /// Write the crossings as CSV (orbit, then the state q1..qN, p1..pN).
    #[arg(long)]
    pub csv: Option<PathBuf>,
    /// Start even a section estimated to take more than a day or more memory than the machine
    /// has.
    #[arg(long)]
    pub force: bool,
}

pub fn main(args: Args) -> anyhow::Result<ExitCode> {
    // Nothing worth finalizing: a signal removes the unfinished outputs and ends at once.
    chaoscope_os::signals::install(chaoscope_os::signals::Mode::Exit);
    let (mut config, _) = super::load_config(&args.config)?;
    let solve = config.orbit.solve_for.clone().context(
        "the config needs orbit.solve_for (the momentum crossing the plane) and orbit.energy",
    )?;
    let base = RunSpec::from_config(&config).context("invalid run configuration")?;
    if base.system().separable().is_none() {
        bail!(
            "model.name: sections are drawn for separable Hamiltonians, not for '{}'",
            config.model.name()
        );
    }
    let n = base.dim() / 2;
    let Some((true, plane)) = parse_coordinate(&solve, n) else {
        bail!("orbit.solve_for must be a momentum, got {solve}");
    };
    let Some((false, vary)) = parse_coordinate(&args.vary, n) else {
        bail!("--vary must be a position q1..q{n}, got {}", args.vary);
    };
    let machine = super::machine();
    let estimate =
        chaoscope_producer::estimate::section(&base, args.count, args.crossings, &machine);
    super::check_estimate(&estimate, &machine, args.force, "section")?;
    let steps = base.total_steps();
    let mut lines = Vec::new();
    // The CSV table replaces an earlier one, never the config (`chaoscope_os::output`).
    let csv_output = match &args.csv {
        Some(p) => Some(Output::create(
            p,
            &OutputOptions {
                replace: true,
                inputs: vec![args.config.clone()],
                leftover: Leftover::Discard,
                ..Default::default()
            },
        )?),
        None => None,
    };
    let mut csv = match &csv_output {
        Some(out) => Some(std::io::BufWriter::new(out.file()?)),
        None => None,
    };
    let mut orbits = 0;
    for i in 0..args.count {
        let v = if args.count > 1 {
            args.from + (args.to - args.from) * i as f64 / (args.count - 1) as f64
        } else {
            args.from
        };
        config.orbit.q[vary] = v;
        // Starting points off the energy surface are skipped.
        let Ok(spec) = RunSpec::from_config(&config) else {
            continue;
        };
        let pts = crossings(&spec, spec.x0(), plane, steps, args.crossings);
        if let Some(f) = csv.as_mut() {
            for p in &pts {
                let row: Vec<String> = p.iter().map(f64::to_string).collect();
                writeln!(f, "{orbits},{}", row.join(","))?;
            }
        }
        lines.push(Line {
            label: String::new(),
            points: pts.iter().map(|p| (p[vary], p[n + vary])).collect(),
            stroke: Stroke::Dots,
            color: orbits,
        });
        orbits += 1;
    }
    if let (Some(mut f), Some(out)) = (csv, csv_output) {
        f.flush()?;
        drop(f);
        out.commit()?;
    }
    let total: usize = lines.iter().map(|l| l.points.len()).sum();
    chaoscope_os::errln!("chaoscope section: {orbits} orbits, {total} crossings");
    if let Some(dir) = &args.plot {
        std::fs::create_dir_all(dir)?;
        let chart = Chart {
            title: format!(
                "{}: section q{} = 0, p{} > 0, H = {}",
                config.model.name(),
                plane + 1,
                plane + 1,
                base.e0()
            ),
            x_label: format!("q{}", vary + 1),
            y_label: format!("p{}", vary + 1),
            lines,
            ..Default::default()
        };
        render(
            &chart,
            &dir.join("section"),
            std::slice::from_ref(&args.config),
        )?;
    }
    Ok(ExitCode::SUCCESS)
}
