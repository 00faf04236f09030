//! `chaoscope recover BROKEN.mcap --out FIXED.mcap`: salvage a file whose writer was killed.

use std::path::PathBuf;
use std::process::ExitCode;

#[derive(clap::Args)]
pub struct Args {
    /// The damaged MCAP file.
    pub input: PathBuf,
    /// Where to write the salvaged file (never the input itself).
    #[arg(long)]
    pub out: PathBuf,
    /// Replace the output file if it exists.
    #[arg(long)]
    pub force: bool,
}

pub fn main(args: Args) -> anyhow::Result<ExitCode> {
    // Nothing worth finalizing: a signal removes the unfinished output and ends at once.
    chaoscope_bus::signals::install(chaoscope_os::signals::Mode::Exit);
    let report = chaoscope_files::recover(&args.input, &args.out, args.force)?;
    chaoscope_os::errln!(
        "chaoscope recover: {} messages from {} chunks salvaged into {} ({})",
        report.messages,
        report.chunks,
        args.out.display(),
        report.stopped_at.as_deref().unwrap_or("input was complete")
    );
    chaoscope_os::outln!(
        "{}",
        serde_json::json!({
            "messages": report.messages,
            "chunks": report.chunks,
            "metadata": report.metadata,
            "attachments": report.attachments,
            "stopped_at": report.stopped_at,
        })
    )?;
    Ok(ExitCode::SUCCESS)
}
