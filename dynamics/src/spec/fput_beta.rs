//! `[model] name = "fput-beta"`: the built-in beta-FPUT chain with fixed ends, a separable
//! Hamiltonian integrated by a splitting ([`super::separable`]).

use std::sync::Arc;

use chaoscope_schemas::config::FputBetaConfig;

use super::{SeparableModel, SpecError};
use crate::model::{FputBeta, SeparableHamiltonian};

/// Most particles of the built-in FPUT chain.
pub const MAX_FPUT_SITES: usize = 1_000_000;

/// `name = "fput-beta"`.
fn fput_beta(cfg: &FputBetaConfig) -> Result<Arc<dyn SeparableHamiltonian>, SpecError> {
    let n = cfg
        .n
        .ok_or_else(|| SpecError::new("model.n", "fput-beta needs the number of particles n"))?;
    if n == 0 || n > MAX_FPUT_SITES {
        return Err(SpecError::new(
            "model.n",
            format!("must be between 1 and {MAX_FPUT_SITES}, got {n}"),
        ));
    }
    let beta = cfg.beta.unwrap_or(1.0);
    FputBeta::new(n, beta)
        .map(|m| Arc::new(m) as Arc<dyn SeparableHamiltonian>)
        .map_err(|e| SpecError::new("model.beta", e))
}

impl super::KindSpec for FputBetaConfig {
    fn separable(&self) -> Option<Result<SeparableModel, SpecError>> {
        Some(fput_beta(self).map(|model| (model, Vec::new())))
    }

    fn why_no_parameter_axes(&self, _name: &str) -> String {
        "the built-in fput-beta chain takes no parameter axis: write the chain as [model] \
         name = \"potential\" (a lattice sum with beta in params), which does"
            .to_string()
    }
}
