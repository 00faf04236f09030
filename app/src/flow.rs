//! What the analysis needs from the system itself, from a validated run or rebuilt from the
//! config a recording carries (the analyzer runs no engine, so whoever holds the producer gives
//! it): the vector field, whose OFLI needs the flow direction at the reference state, the
//! energy of each site of a lattice Hamiltonian, for the energy distribution, and the 0-1 test's
//! observable where the config writes one (`[analysis] zero_one_observable`).

use std::sync::Arc;

use chaoscope_analyzer::analysis::{AnalysisOptions, FlowField, ObservableFn, SiteEnergies};
use chaoscope_analyzer::run_info::RunInfo;
use chaoscope_dynamics::spec::RunSpec;
use chaoscope_dynamics::spec::state_function::zero_one_observable;
use chaoscope_dynamics::system::{DynamicalSystem, Time};
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
    flow_field(&system_of_run(run)?)
}

/// The system of a recorded run, rebuilt from the config its header carries as replay rebuilds
/// it; `None` where that config does not validate here or gives another dimension.
fn system_of_run(run: &RunInfo) -> Option<Arc<dyn DynamicalSystem>> {
    rebuild_system(run).ok()
}

/// Why the system of a recorded run cannot be rebuilt from the config its header carries (so
/// the flow field and the site energies are missing from its analysis), `None` when it can.
pub fn why_no_system_of_run(run: &RunInfo) -> Option<String> {
    rebuild_system(run).err()
}

fn rebuild_system(run: &RunInfo) -> Result<Arc<dyn DynamicalSystem>, String> {
    let config = RunConfig::from_toml(&run.header.config_toml)
        .map_err(|e| format!("its recorded configuration does not parse here: {e}"))?
        .with_sweeps_expanded()
        .map_err(|e| format!("its recorded configuration does not validate here: {e}"))?;
    let spec = RunSpec::from_config(&config)
        .map_err(|e| format!("its recorded configuration does not validate here: {e}"))?;
    let dim = spec.system().dim();
    if dim != run.dim {
        return Err(format!(
            "its recorded configuration gives a state of dimension {dim}, the recording {}",
            run.dim
        ));
    }
    Ok(Arc::clone(spec.system()))
}

/// The energy of each site of `system`'s states
/// ([`chaoscope_dynamics::system::DynamicalSystem::site_energies`]: a lattice Hamiltonian's,
/// separable or written as lattice sums); for any other system, the reason why there are none.
pub fn site_energies(system: &Arc<dyn DynamicalSystem>) -> SiteEnergies {
    let system = Arc::clone(system);
    SiteEnergies(Arc::new(move |x: &[f64], out: &mut [f64]| {
        system.site_energies(x, out)
    }))
}

/// The site energies of a recorded run, its system rebuilt as [`flow_field_of_run`] rebuilds
/// it; `None` where it cannot be (the energy distribution then says so).
pub fn site_energies_of_run(run: &RunInfo) -> Option<SiteEnergies> {
    Some(site_energies(&system_of_run(run)?))
}

/// A run's `[analysis] zero_one_observable` compiled over its system rebuilt from the recorded
/// config as [`flow_field_of_run`] rebuilds it: `None` where the run has no such key or its
/// system cannot be rebuilt here, the problem in one line where the expression does not compile.
pub fn zero_one_observable_of_run(run: &RunInfo) -> Option<Result<Arc<ObservableFn>, String>> {
    let config = RunConfig::from_toml(&run.header.config_toml)
        .ok()?
        .with_sweeps_expanded()
        .ok()?;
    config.analysis.zero_one_observable.as_ref()?;
    // The system without the observable, so that an expression this version refuses is the
    // test's reason rather than a system that cannot be rebuilt.
    let mut system_only = config.clone();
    system_only.analysis = Default::default();
    let spec = RunSpec::from_config(&system_only).ok()?;
    if spec.system().dim() != run.dim {
        return None;
    }
    zero_one_observable_of_spec(&spec, &config)
}

/// A run's `[analysis] zero_one_observable` compiled over `spec`'s system (a run in process,
/// replay): `None` without the key, the problem in one line where the expression does not
/// compile (which the validation of a config refuses first).
pub fn zero_one_observable_of_spec(
    spec: &RunSpec,
    config: &RunConfig,
) -> Option<Result<Arc<ObservableFn>, String>> {
    let compiled = match zero_one_observable(spec, config) {
        Ok(compiled) => compiled?,
        Err(e) => return Some(Err(format!("{}: {}", e.key, e.message))),
    };
    let function: Arc<ObservableFn> = Arc::new(move |x: &[f64]| compiled.value(x));
    Some(Ok(function))
}

/// The analysis options that rebuild a recorded run's system from its config (the vector field,
/// the site energies, the 0-1 test's observable), on which every reader of a run builds its own:
/// `chaoscope analyze`, `run`'s summary, the live monitor and Python.
pub fn analysis_options() -> AnalysisOptions {
    AnalysisOptions {
        flow_field: Some(flow_field_of_run),
        site_energies: Some(site_energies_of_run),
        zero_one_observable: Some(zero_one_observable_of_run),
        ..Default::default()
    }
}
