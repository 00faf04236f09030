//! The system's vector field for the analysis, whose OFLI needs the flow direction at the
//! reference state: from a validated run, or rebuilt from the config a recording carries (the
//! analyzer itself runs no engine, so whoever holds the producer gives it the field).

use std::sync::Arc;

use chaoscope_analyzer::analysis::FlowField;
use chaoscope_analyzer::run_info::RunInfo;
use chaoscope_producer::spec::RunSpec;
use chaoscope_producer::system::{DynamicalSystem, Time};
use chaoscope_schemas::config::RunConfig;

/// The vector field of `system`, if it has one (a map has none: its time is discrete).
pub fn flow_field(system: &Arc<dyn DynamicalSystem>) -> Option<FlowField> {
    if matches!(system.time(), Time::Discrete) {
        return None;
    }
    let system = Arc::clone(system);
    let time = system.time();
    Some(FlowField(Arc::new(
        move |step: u64, x: &[f64], out: &mut [f64]| {
            x.len() == system.dim()
                && out.len() == x.len()
                && system.vector_field(x, time.at(step), out)
        },
    )))
}

/// The vector field of a recorded run, its system rebuilt from the config the header carries
/// exactly as replay rebuilds it. `None` where that config does not validate here (a model built
/// in code, a table no longer at its path): the indicators that need it then say so.
pub fn flow_field_of_run(run: &RunInfo) -> Option<FlowField> {
    let config = RunConfig::from_toml(&run.header.config_toml)
        .ok()?
        .with_sweeps_expanded()
        .ok()?;
    let spec = RunSpec::from_config(&config).ok()?;
    if spec.system().dim() != run.dim {
        return None;
    }
    flow_field(spec.system())
}
