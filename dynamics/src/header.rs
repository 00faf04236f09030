//! The run header a producer announces: the validated run plus its configuration text; and
//! [`non_finite`], the check every sample passes before it goes on the bus or into a file.

use chaoscope_schemas::FORMAT_VERSION;
use chaoscope_schemas::config::RunConfig;
use chaoscope_schemas::proto::{RunHeader, Scheme};
use chaoscope_schemas::run::Sample;

use crate::spec::RunSpec;

/// Describes `spec` (validated from `config`) as the protobuf header of run `run_name`.
pub fn run_header(run_name: &str, config: &RunConfig, spec: &RunSpec) -> RunHeader {
    let schemes = spec
        .schemes()
        .iter()
        .enumerate()
        .map(|(i, s)| Scheme {
            index: i as u32,
            name: s.name.clone(),
            method: s.method.name().to_string(),
            d0: s.d0,
            tau: s.tau,
            tau_steps: s.tau_steps,
            orthonormalize: s.orthonormalize.name().to_string(),
        })
        .collect();
    RunHeader {
        format_version: FORMAT_VERSION,
        run_name: run_name.to_string(),
        config_toml: spec.pinned_config(config).to_toml(),
        model: config.model.name().to_string(),
        // N of a separable Hamiltonian; 0 for every other kind (`dim` says their size).
        n: spec
            .system()
            .separable()
            .map_or(0, |s| s.model().dof() as u32),
        dim: spec.dim() as u32,
        k: spec.k() as u32,
        sets: spec.sets() as u32,
        integrator: config.integrator.method.clone(),
        h: spec.h(),
        t_final: spec.t_final(),
        total_steps: spec.total_steps(),
        energy0: spec.e0(),
        x0: spec.x0().to_vec(),
        schemes,
        seed: spec.seed(),
        producer_version: env!("CARGO_PKG_VERSION").to_string(),
        kind: spec.system().kind().name().to_string(),
        time: spec.system().time().name().to_string(),
        lattice_side: config
            .model
            .square_side()
            .map_or(0, |n| u32::try_from(n).unwrap_or(0)),
    }
}

/// The first non-finite value of a sample, described (NaN never goes on the bus or into files).
pub fn non_finite(sample: &Sample) -> Option<String> {
    if !sample.state.iter().all(|v| v.is_finite()) || !sample.energy.is_finite() {
        return Some(format!("non-finite reference state at t = {}", sample.t));
    }
    sample
        .schemes
        .iter()
        .find(|s| {
            !s.separations
                .iter()
                .chain(&s.stretch)
                .chain(&s.earlier_stretch)
                .all(|v| v.is_finite())
        })
        .map(|s| {
            format!(
                "non-finite deviation vectors (scheme {}, set {}) at t = {}",
                s.scheme, s.set, sample.t
            )
        })
}
