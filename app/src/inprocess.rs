//! Analysis of a run computed in this process by the engine (tests, sweeps, the paper script's
//! quick paths): no bus, no file.

use chaoscope_dynamics::engine::{Engine, RunError};
use chaoscope_dynamics::header::run_header;
use chaoscope_dynamics::spec::{RunSpec, SpecError};
use chaoscope_schemas::config::RunConfig;
use chaoscope_schemas::run::Sample;

use chaoscope_analyzer::analysis::{Analysis, AnalysisOptions};
use chaoscope_analyzer::run_info::RunInfo;

#[derive(Debug, thiserror::Error)]
pub enum InProcessError {
    #[error("invalid configuration: {0}")]
    // Not `#[from]`: that would also make it the error's source, and the message (which
    // already includes it) would print twice in an error chain.
    Spec(SpecError),
    #[error(transparent)]
    Run(#[from] RunError),
}

impl From<SpecError> for InProcessError {
    fn from(e: SpecError) -> Self {
        Self::Spec(e)
    }
}

/// The analysis' view of a validated config.
pub fn run_info(name: &str, config: &RunConfig, spec: &RunSpec) -> RunInfo {
    RunInfo::from_header(run_header(name, config, spec))
        .expect("a validated spec has a valid header")
}

/// Runs `config` to the end, feeding every sample to an analysis and to `each`.
pub fn analyze_config(
    config: &RunConfig,
    options: &AnalysisOptions,
    each: impl FnMut(&Sample),
) -> Result<Analysis, InProcessError> {
    let spec = RunSpec::from_config(config)?;
    analyze_spec(config, spec, options, each)
}

/// Runs `spec` (validated from `config`, or built around a system in code with
/// [`RunSpec::with_system`]) to the end, feeding every sample to an analysis and to `each`.
pub fn analyze_spec(
    config: &RunConfig,
    spec: RunSpec,
    options: &AnalysisOptions,
    mut each: impl FnMut(&Sample),
) -> Result<Analysis, InProcessError> {
    let mut analysis = Analysis::new(run_info("in-process", config, &spec), options);
    if let Some(field) = crate::flow::flow_field(spec.system()) {
        analysis.set_flow_field(field);
    }
    analysis.set_site_energies(crate::flow::site_energies(spec.system()));
    analysis.set_zero_one_observable(crate::flow::zero_one_observable_of_spec(&spec, config));
    let mut engine = Engine::new(spec);
    while let Some(sample) = engine.next_sample()? {
        analysis.feed(&sample);
        each(&sample);
    }
    Ok(analysis)
}
