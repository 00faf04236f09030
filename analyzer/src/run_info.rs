//! What the analysis needs to know about a run, read from its header (the protobuf `RunHeader`
//! of the recording or the bus, or built in process from a `RunSpec`).

use chaoscope_indicators::Layout;
use chaoscope_schemas::proto::RunHeader;
use chaoscope_schemas::run::{
    MAX_STATE_VALUES, Method, Orthonormalization, Route, SchemeSpec, SystemClass,
    deviation_state_values,
};

/// A header that cannot describe a run the analysis can follow.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("run header: {0}")]
pub struct HeaderError(pub String);

/// The run being analyzed.
#[derive(Debug, Clone, PartialEq)]
pub struct RunInfo {
    pub header: RunHeader,
    /// What kind of system (an empty header field: a Hamiltonian, recorded before flows).
    pub kind: SystemClass,
    pub dim: usize,
    pub k: usize,
    pub sets: usize,
    pub h: f64,
    /// The run's schemes, in header order (a scheme's index is its position).
    pub schemes: Vec<SchemeSpec>,
    /// The period of each coordinate of the state (`[model] modulo` of the recorded
    /// configuration, `0`: none), empty when none is declared: the analysis reads the state
    /// with these coordinates wrapped (the extent, the orbit indicators).
    pub periods: Vec<f64>,
    /// `[analysis] zero_one_observable` of the recorded configuration: the expression of the
    /// state the 0-1 test observes (`None`: the generic observable).
    pub zero_one_observable: Option<String>,
    /// `Some(L)` when the run's sites form an `L x L` square lattice numbered row by row
    /// ([`chaoscope_schemas::run::square_side`]), `None` for a chain or a system without sites.
    pub square_side: Option<usize>,
    /// Which axes of the run's lattice are periodic
    /// ([`chaoscope_schemas::run::periodic_axes`]).
    pub periodic: [bool; 2],
}

impl RunInfo {
    pub fn from_header(header: RunHeader) -> Result<Self, HeaderError> {
        let err = |m: String| HeaderError(m);
        let kind = SystemClass::from_name(&header.kind)
            .ok_or_else(|| err(format!("unknown kind of system {:?}", header.kind)))?;
        if !matches!(header.time.as_str(), "" | "continuous" | "discrete") {
            return Err(err(format!("unknown kind of time {:?}", header.time)));
        }
        if header.dim == 0 || header.k == 0 || header.sets == 0 {
            return Err(err(format!(
                "dim = {}, k = {}, sets = {} must all be positive",
                header.dim, header.k, header.sets
            )));
        }
        if header.k > header.dim {
            return Err(err(format!(
                "k = {} deviation vectors exceed the dimension {}",
                header.k, header.dim
            )));
        }
        // What the producer accepts (`spec`): a header claiming more state than any run holds
        // is refused here rather than aborting the analysis on allocation.
        let state_values = deviation_state_values(
            header.schemes.len(),
            header.sets.into(),
            header.k.into(),
            header.dim.into(),
        );
        if state_values > MAX_STATE_VALUES {
            return Err(err(format!(
                "{} schemes x {} sets x k = {} x dimension {} exceed the deviation state any run \
                 holds",
                header.schemes.len(),
                header.sets,
                header.k,
                header.dim
            )));
        }
        if !header.energy0.is_finite() {
            return Err(err(format!(
                "initial energy E0 = {} is not finite",
                header.energy0
            )));
        }
        if !(header.h.is_finite() && header.h > 0.0) {
            return Err(err(format!("time step h = {} is not positive", header.h)));
        }
        // Values every report carries: finite, or the header is refused (a NaN here would be
        // printed as NaN, or as null in JSON).
        if !(header.t_final.is_finite() && header.t_final >= 0.0) {
            return Err(err(format!(
                "t_final = {:?}: a final time is finite and not negative",
                header.t_final
            )));
        }
        if let Some(x) = header.x0.iter().find(|x| !x.is_finite()) {
            return Err(err(format!("initial state x0 holds {x:?}")));
        }
        let mut schemes: Vec<SchemeSpec> = Vec::with_capacity(header.schemes.len());
        for s in &header.schemes {
            // Scheme names become file names (`analyze --csv/--plot`): a recording from anyone
            // must not name a path out of the user's directory.
            chaoscope_schemas::names::validate_scheme_name(&s.name)
                .map_err(|problem| err(format!("scheme name {problem}")))?;
            if schemes.iter().any(|o| o.name == s.name) {
                return Err(err(format!("scheme name '{}' is used twice", s.name)));
            }
            let method = Method::from_name(&s.method)
                .ok_or_else(|| err(format!("scheme {}: unknown method {:?}", s.name, s.method)))?;
            let orthonormalize =
                Orthonormalization::from_name(&s.orthonormalize).ok_or_else(|| {
                    err(format!(
                        "scheme {}: unknown orthonormalization {:?}",
                        s.name, s.orthonormalize
                    ))
                })?;
            if s.tau_steps == 0 {
                return Err(err(format!("scheme {}: tau_steps = 0", s.name)));
            }
            for (field, v) in [("d0", s.d0), ("tau", s.tau)] {
                if !(v.is_finite() && v > 0.0) {
                    return Err(err(format!(
                        "scheme {}: {field} = {v:?} is not a positive number",
                        s.name
                    )));
                }
            }
            schemes.push(SchemeSpec {
                name: s.name.clone(),
                method,
                d0: s.d0,
                tau: s.tau,
                tau_steps: s.tau_steps,
                orthonormalize,
                // The header does not say; the separations it holds are the same quantity
                // either way (replay reruns the recorded configuration, which says).
                route: Route::PerSet,
            });
        }
        let square_side = chaoscope_schemas::run::square_side(&header).map_err(err)?;
        let recorded = recorded_config(&header.config_toml);
        let periods = recorded
            .as_ref()
            .and_then(|c| c.model.modulo().map(<[f64]>::to_vec))
            .unwrap_or_default();
        let periodic = recorded
            .as_ref()
            .map_or([false; 2], |c| c.model.periodic_axes());
        let zero_one_observable = recorded.and_then(|c| c.analysis.zero_one_observable);
        chaoscope_indicators::periodic::check_periods(&periods, header.dim as usize)
            .map_err(|problem| err(format!("model.modulo {problem}")))?;
        Ok(Self {
            periods,
            zero_one_observable,
            square_side,
            periodic,
            kind,
            dim: header.dim as usize,
            k: header.k as usize,
            sets: header.sets as usize,
            h: header.h,
            schemes,
            header,
        })
    }

    /// `state` with its periodic coordinates wrapped into one period (a copy).
    pub fn wrapped(&self, state: &[f64]) -> Vec<f64> {
        chaoscope_indicators::periodic::wrap_state(&self.periods, state)
    }

    /// Time of step `step`, computed as the producer does (`step * h`, never accumulated).
    pub fn time_of(&self, step: u64) -> f64 {
        step as f64 * self.h
    }

    /// The run's shape for the indicator tracker (valid: `from_header` checked every field it
    /// reads).
    pub fn layout(&self) -> Layout {
        Layout::new(
            self.dim,
            self.k,
            self.sets,
            self.h,
            self.schemes.iter().map(|s| s.tau_steps).collect(),
        )
        .map(|layout| {
            layout
                .with_sites(self.kind.lattice_sites(self.dim))
                .with_square_side(self.square_side)
                .with_periodic(self.periodic)
                .with_norm(
                    self.kind == SystemClass::Hamiltonian
                        && chaoscope_schemas::run::conserves_norm(&self.header.model),
                )
                .with_periods(self.periods.clone())
        })
        .expect("a validated header has a valid layout")
    }

    pub fn scheme_index(&self, name: &str) -> Option<usize> {
        self.schemes.iter().position(|s| s.name == name)
    }
}

/// The recorded configuration, where the header carries one the reader understands (not a
/// header built in code, nor a recording of a model written in Rust): its `[model] modulo` and
/// `[analysis]` say how the states are read; without it they are read as they are.
fn recorded_config(config_toml: &str) -> Option<chaoscope_schemas::config::RunConfig> {
    if config_toml.is_empty() {
        return None;
    }
    chaoscope_schemas::config::RunConfig::from_toml(config_toml).ok()
}
