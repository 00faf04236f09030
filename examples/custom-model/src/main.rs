//! `cargo run -p chaoscope-example-custom-model --release -- [--publish] [OUT.mcap]`: records the
//! Barbanis run to OUT (default `runs/barbanis.mcap`) and prints its analysis as JSON, or with
//! `--publish` puts it on the bus for a `chaoscope record` started beforehand.

use std::path::PathBuf;

use chaoscope_example_custom_model::{CONFIG, publish, record, run_spec};

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let (config, spec) = run_spec(CONFIG)?;
    if args.iter().any(|a| a == "--publish") {
        let outcome = publish(&config, spec)?;
        println!(
            "{} samples published, status {:?}",
            outcome.samples, outcome.status
        );
        return Ok(());
    }
    let out = args
        .first()
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from("runs/barbanis.mcap"));
    if let Some(dir) = out.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir)?;
    }
    let report = record(&config, spec, &out)?;
    println!("{}", serde_json::to_string_pretty(&report)?);
    eprintln!(
        "recorded {}; `chaoscope analyze {}` reads it",
        out.display(),
        out.display()
    );
    Ok(())
}
