//! `chaoscope config --schema`: the JSON Schema of a run configuration (for TOML editors that
//! check and complete a file against one: taplo, Even Better TOML), derived from the types that
//! parse configs. `chaoscope config FILE`: validate a config as `run` or `map` would, without
//! running it, and say what it is and what it would cost.

use std::io::Write;
use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::{Context, bail};
use chaoscope_dynamics::estimate;
use chaoscope_dynamics::map::MapSpec;
use chaoscope_dynamics::spec::{RunSpec, SpecError};
use chaoscope_schemas::config::{ConfigSource, RunConfig};

#[derive(clap::Args)]
pub struct Args {
    /// A run configuration (TOML) to validate; `-` reads it from stdin.
    pub config: Option<PathBuf>,
    /// Print the JSON Schema of run configurations instead.
    #[arg(long, conflicts_with = "config")]
    pub schema: bool,
}

pub fn main(args: Args) -> anyhow::Result<ExitCode> {
    if args.schema {
        let schema = serde_json::to_string_pretty(&RunConfig::json_schema())?;
        writeln!(std::io::stdout().lock(), "{schema}").context("writing the schema")?;
        return Ok(ExitCode::SUCCESS);
    }
    let Some(path) = args.config else {
        bail!("give a configuration file to validate, or --schema");
    };
    let (config, _, source) = super::load_config(&path)?;
    let machine = super::machine();
    let (what, estimate) = validate(&config, Some(&source), &machine)?;
    super::warn_unused_params("config", &config);
    super::warn_repeated_grid_lines("config", &config);
    let refusal = estimate.refusal(&machine);
    super::print_summary(&serde_json::json!({
        "config": path.display().to_string(),
        "valid": true,
        "what": what,
        "seconds": estimate.seconds,
        "bytes": estimate.bytes,
        "orbit_steps": estimate.orbit_steps,
        "cores": estimate.cores,
        // What the time comes from, measured on this machine (a few milliseconds): nanoseconds
        // per orbit-step and per tangent vector's step.
        "calibration": estimate.calibration.map(|c| serde_json::json!({
            "ns_per_orbit_step": c.ns_per_orbit_step,
            "ns_per_tangent_step": c.ns_per_tangent_step,
            "ns_per_fused_lane_step": c.ns_per_fused_lane_step,
            "seconds_spent": c.seconds_spent,
        })),
        "refused_without_force": refusal,
    }));
    Ok(ExitCode::SUCCESS)
}

/// Validates a configuration as `run` (or `map`, when it has a `[map]` table) would, and says
/// what it is and what it would cost on `machine`. The guide's test validates its examples
/// through this too.
pub fn validate(
    config: &RunConfig,
    source: Option<&ConfigSource>,
    machine: &estimate::Machine,
) -> anyhow::Result<(String, estimate::Estimate)> {
    // Errors name the file and the key's line where the config was read from one.
    let invalid = |what: &str, e: SpecError| match source {
        Some(source) => super::invalid_config(source, what, e),
        None => anyhow::Error::new(e).context(format!("invalid {what} configuration")),
    };
    Ok(if config.map.is_some() {
        let mut spec = MapSpec::from_config(config).map_err(|e| invalid("map", e))?;
        let points = spec.grid_points();
        let (e, choice) = estimate::map_choosing_route(
            &mut spec,
            points,
            machine,
            machine.cores,
            chaoscope_dynamics::batch::Isa::detect(),
        );
        let route = super::map::route_reason(&spec, choice.as_ref());
        (format!("a map of {points} points, {route}"), e)
    } else {
        let spec = RunSpec::from_config(config).map_err(|e| invalid("run", e))?;
        let e = chaoscope_producer::estimate::run(&spec, machine);
        (
            format!(
                "a run of a {} of dimension {}",
                spec.system().kind().name(),
                spec.dim()
            ),
            e,
        )
    })
}
