//! `[model] name = "henon-heiles"`: the built-in Henon-Heiles model, a separable Hamiltonian
//! with 2 degrees of freedom integrated by a splitting ([`super::separable`]).

use std::sync::Arc;

use chaoscope_schemas::config::HenonHeilesConfig;

use super::{SeparableModel, SpecError};
use crate::model::{HenonHeiles, SeparableHamiltonian};

/// `name = "henon-heiles"`.
fn henon_heiles(cfg: &HenonHeilesConfig) -> Result<Arc<dyn SeparableHamiltonian>, SpecError> {
    if let Some(n) = cfg.n.filter(|&n| n != 2) {
        return Err(SpecError::new(
            "model.n",
            format!("henon-heiles has 2 degrees of freedom, got n = {n}"),
        ));
    }
    Ok(Arc::new(HenonHeiles))
}

impl super::KindSpec for HenonHeilesConfig {
    fn separable(&self) -> Option<Result<SeparableModel, SpecError>> {
        Some(henon_heiles(self).map(|model| (model, Vec::new())))
    }

    fn why_no_parameter_axes(&self, _name: &str) -> String {
        "[model] name = henon-heiles has no parameters to put on an axis".to_string()
    }
}
