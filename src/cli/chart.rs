//! `chaoscope chart SPEC.json --out STEM`: draw a chart described in JSON (title, axis labels,
//! lines of points) as STEM.png and STEM.svg, with the same renderer as `analyze --plot`.
//! Scripts use it for derived figures (GALI against h, E_r against h).

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::Context;
use chaoscope_analyzer::chart::{Chart, render};

#[derive(clap::Args)]
pub struct Args {
    /// Chart description (JSON); `-` reads stdin.
    pub spec: PathBuf,
    /// Output path without extension.
    #[arg(long)]
    pub out: PathBuf,
}

pub fn main(args: Args) -> anyhow::Result<ExitCode> {
    // Nothing worth finalizing: a signal removes the unfinished outputs and ends at once.
    chaoscope_bus::signals::install(chaoscope_os::signals::Mode::Exit);
    let text = if args.spec.as_os_str() == "-" {
        std::io::read_to_string(std::io::stdin())?
    } else {
        chaoscope_os::open_regular(&args.spec)
            .and_then(std::io::read_to_string)
            .with_context(|| format!("reading {}", args.spec.display()))?
    };
    let chart: Chart = serde_json::from_str(&text).context("chart description")?;
    chart
        .check()
        .map_err(|e| anyhow::anyhow!("{}: {e}", args.spec.display()))?;
    if let Some(dir) = args.out.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir)?;
    }
    // STEM.png and STEM.svg; an --out that already names one of them stands for its stem.
    let stem = match args.out.extension().and_then(|e| e.to_str()) {
        Some("png" | "svg") => args.out.with_extension(""),
        _ => args.out.clone(),
    };
    render(&chart, &stem, std::slice::from_ref(&args.spec))?;
    Ok(ExitCode::SUCCESS)
}
