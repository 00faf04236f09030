//! What a run is made of, as recordings carry it: its samples, its schemes (method, route,
//! orthonormalization), the kind of system, and the limits of the state a run may hold, which
//! every reader of a run header checks as the producer does.
//!
//! The producer computes these and the analysis reads them; neither owns them.

/// What kind of system a run integrates: decides what the report carries beside the
/// indicators (the energy error of a Hamiltonian, the mean divergence of a flow or map).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SystemClass {
    /// Conserves its energy and phase-space volume.
    Hamiltonian,
    /// `dx/dt = f(x)`, in general neither.
    Flow,
    /// `x -> F(x)`.
    Map,
}

impl SystemClass {
    /// As recordings name it (`RunHeader.kind`).
    pub fn name(self) -> &'static str {
        match self {
            SystemClass::Hamiltonian => "hamiltonian",
            SystemClass::Flow => "flow",
            SystemClass::Map => "map",
        }
    }

    /// The kind a recording names; an empty name is a recording from before flows and maps,
    /// all of which were Hamiltonian.
    pub fn from_name(name: &str) -> Option<Self> {
        match name {
            "" | "hamiltonian" => Some(SystemClass::Hamiltonian),
            "flow" => Some(SystemClass::Flow),
            "map" => Some(SystemClass::Map),
            _ => None,
        }
    }

    /// The sites of a lattice indicator (the deviation vector distribution) in a state of
    /// `dim` entries: a Hamiltonian's `N = dim / 2` degrees of freedom (site `l` at `q_l`,
    /// `p_l`); flows and maps have none. The one decision the recorder and the analyzer share,
    /// so the recording's indicators equal `analyze`'s.
    pub fn lattice_sites(self, dim: usize) -> Option<usize> {
        match self {
            SystemClass::Hamiltonian if dim.is_multiple_of(2) => Some(dim / 2),
            _ => None,
        }
    }
}

/// The side `L` of the square lattice a run's sites form (`N = L^2`, numbered row by row), or
/// `None` for a chain or a system without sites: the header's `lattice_side`, or, in a recording
/// made before that field existed, the recorded configuration's `[model] lattice = "square"`
/// and `n`. A side whose square is not the header's `N = dim / 2` is an error naming both.
pub fn square_side(header: &crate::proto::RunHeader) -> Result<Option<usize>, String> {
    let sites =
        SystemClass::from_name(&header.kind).and_then(|k| k.lattice_sites(header.dim as usize));
    let side = if header.lattice_side > 0 {
        header.lattice_side as usize
    } else {
        match recorded_square_side(header) {
            Some(side) => side,
            None => return Ok(None),
        }
    };
    match sites {
        Some(n) if side.checked_mul(side) == Some(n) => Ok(Some(side)),
        _ => Err(format!(
            "lattice_side {side} does not fit the run's state: a {side} x {side} lattice has \
             {} sites, the state (dim {}, kind {:?}) {}",
            side.saturating_mul(side),
            header.dim,
            header.kind,
            sites.map_or("has none".to_string(), |n| format!("has {n}"))
        )),
    }
}

/// The side of a recorded configuration's square lattice (`[model] name = "ddnls"`, `lattice =
/// "square"`, `n`), where the header carries a configuration that says so.
fn recorded_square_side(header: &crate::proto::RunHeader) -> Option<usize> {
    if header.model != "ddnls" || header.config_toml.is_empty() {
        return None;
    }
    let config = crate::config::RunConfig::from_toml(&header.config_toml).ok()?;
    config.model.square_side()
}

/// Which axes of a run's lattice are periodic ([`crate::config::ModelConfig::periodic_axes`]),
/// from the recorded configuration; none where the header carries none that parses.
pub fn periodic_axes(header: &crate::proto::RunHeader) -> [bool; 2] {
    if header.config_toml.is_empty() {
        return [false; 2];
    }
    crate::config::RunConfig::from_toml(&header.config_toml)
        .map_or([false; 2], |config| config.model.periodic_axes())
}

/// The models whose states conserve the norm `S = sum_l (q_l^2 + p_l^2)/2` beside the energy
/// (the disordered discrete nonlinear Schroedinger lattice): the report carries the norm's
/// relative error beside the energy error for them.
pub fn conserves_norm(model: &str) -> bool {
    model == "ddnls"
}

/// How deviation vectors are renormalized.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Orthonormalization {
    Rescale,
    Qr,
}

impl Orthonormalization {
    pub fn name(self) -> &'static str {
        match self {
            Orthonormalization::Rescale => "rescale",
            Orthonormalization::Qr => "qr",
        }
    }

    pub fn from_name(s: &str) -> Option<Self> {
        match s {
            "rescale" => Some(Self::Rescale),
            "qr" => Some(Self::Qr),
            _ => None,
        }
    }
}

/// How deviation vectors are evolved.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Method {
    /// Variational method: the integrator's tangent map.
    Vm,
    /// Multi-particle method: nearby orbits integrated with the full equations of motion.
    Mpm,
}

impl Method {
    pub fn name(self) -> &'static str {
        match self {
            Method::Vm => "vm",
            Method::Mpm => "mpm",
        }
    }

    pub fn from_name(s: &str) -> Option<Self> {
        match s {
            "vm" => Some(Method::Vm),
            "mpm" => Some(Method::Mpm),
            _ => None,
        }
    }
}

/// One renormalization scheme evolved around the shared reference orbit.
#[derive(Debug, Clone, PartialEq)]
pub struct SchemeSpec {
    pub name: String,
    pub method: Method,
    /// Norm of every deviation vector right after a renormalization.
    pub d0: f64,
    /// Renormalization period, an exact multiple of the time step.
    pub tau: f64,
    /// `tau / h`.
    pub tau_steps: u64,
    pub orthonormalize: Orthonormalization,
    pub route: Route,
}

/// How a scheme of a run evolves its deviation sets (`[[scheme]] route`). A phase-space map's
/// routes are another thing (`[map] route`, the producer's `map::MapRoute`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Route {
    /// `"per-set"`: every set's own `k` tangent vectors or nearby orbits (the reference).
    PerSet,
    /// `"propagator"` (VM only): `D` tangent vectors evolved from the identity over each
    /// renormalization window, the window's tangent propagator `M`, applied to every set's
    /// vectors at the renormalization (`M w`, then renormalized as per set).
    WindowPropagator,
}

impl Route {
    /// As configs write it.
    pub fn name(self) -> &'static str {
        match self {
            Route::PerSet => "per-set",
            Route::WindowPropagator => "propagator",
        }
    }

    pub fn from_name(s: &str) -> Option<Self> {
        match s {
            "per-set" => Some(Route::PerSet),
            "propagator" => Some(Route::WindowPropagator),
            _ => None,
        }
    }
}

/// Most numbers of deviation state a run may hold (2^30 doubles = 8 GiB): a typo such as
/// `sets = 1000000` with a long chain must be refused with a message, not abort on allocation.
pub const MAX_STATE_VALUES: u128 = 1 << 30;

/// Most random sets of directions one run may draw.
pub const MAX_SETS: usize = 1_000_000;

/// Deviation state values (f64) a run holds: `sets` sets of `k` deviation vectors of dimension
/// `dim`, per scheme (at least one) plus the reference; compare with [`MAX_STATE_VALUES`].
pub fn deviation_state_values(schemes: usize, sets: u64, k: u64, dim: u64) -> u128 {
    (schemes.max(1) as u128 + 1) * u128::from(sets) * u128::from(k) * u128::from(dim)
}

/// Most schemes one run may have, explicit and swept together: each is a channel of the
/// recording and a task of every sample (the limit of one `[[sweep]]`).
pub const MAX_SCHEMES: usize = crate::config::sweep::MAX_SWEEP_SCHEMES;

/// Everything known at one renormalization time.
#[derive(Debug, Clone, PartialEq)]
pub struct Sample {
    /// 0, 1, 2, ... without gaps: receivers use it to prove nothing was lost.
    pub seq: u64,
    /// Integration step; `t = step * h`.
    pub step: u64,
    pub t: f64,
    /// Reference state `(q, p)`.
    pub state: Vec<f64>,
    /// Energy of the reference state (0 for systems without an invariant).
    pub energy: f64,
    /// Mean of the system's divergence along the reference orbit from t = 0 to `t` (its value
    /// at the initial state for t = 0; 0 for systems that conserve volume), see
    /// the system's divergence.
    pub mean_divergence: f64,
    /// The integral (flows) or sum (maps) of the divergence from t = 0 to `t`, as the engine
    /// accumulates it (`mean_divergence` is it over `t`): a resumed run continues from it, as
    /// the mean alone cannot give it back to the bit. 0 for systems that conserve volume.
    pub divergence_sum: f64,
    /// The schemes renormalized at this step, ordered by (scheme, set).
    pub schemes: Vec<SchemeSample>,
}

/// One set of one scheme at a renormalization.
#[derive(Debug, Clone, PartialEq)]
pub struct SchemeSample {
    pub scheme: u32,
    pub set: u32,
    /// `k` separation vectors of length `2N`, one after the other, before renormalization.
    pub separations: Vec<f64>,
    /// Stretching factor of each vector since the previous renormalization (`|d|/d0`, or
    /// `|R_ii|` in QR mode).
    pub stretch: Vec<f64>,
    /// A run sampled every `[run] sample_every`: the stretching factors of this set's
    /// renormalizations since the previous sample (not this one), `k` per renormalization,
    /// oldest first. Empty when every renormalization is a sample.
    pub earlier_stretch: Vec<f64>,
}

/// How a run's end-of-run reason begins when the reference orbit escaped (its norm passed the
/// producer's escape bound) or became non-finite: the producer writes it, the verdict reads it
/// (`escaped`, never chaotic or regular). The reason goes on `" by t = <time> ..."`.
pub const REFERENCE_ESCAPED: &str = "the reference orbit escaped or became non-finite";

/// The time named by an end-of-run reason of an escaped reference orbit
/// ([`REFERENCE_ESCAPED`]), `None` for any other reason (or a reason without a readable time).
pub fn escape_time(reason: &str) -> Option<f64> {
    let rest = reason.strip_prefix(REFERENCE_ESCAPED)?;
    let rest = rest.strip_prefix(" by t = ")?;
    let end = rest.find([' ', ',', ':', ')']).unwrap_or(rest.len());
    rest[..end].parse::<f64>().ok().filter(|t| t.is_finite())
}

/// How a run's end-of-run reason begins when the integrator could not take a step from a finite
/// state within the escape bound (the implicit Gauss-Legendre stages stopped converging, at a
/// close approach or with a step too long for the vector field there): the producer writes it,
/// the verdict reads it (`failed`, never `escaped`: the orbit did not leave, the integrator
/// stopped). The reason goes on `" by t = <time>: <the integrator's reason>"`.
pub const INTEGRATOR_FAILED: &str = "the integrator failed";

/// How the implicit integrators' own error begins. A recording written before
/// [`INTEGRATOR_FAILED`] existed carries it inside an escape reason; the verdict reads such a
/// reason as an integrator failure too.
pub const IMPLICIT_NOT_CONVERGED: &str = "the implicit Gauss-Legendre stages did not converge";

/// How the reason of an adaptive step that could not be completed begins (its step size fell
/// below what the time can resolve, it took too many substeps, or its error estimate stayed
/// non-finite) when the state did not run away within that step: the integrator failed there
/// (the vector field is not smooth enough for the tolerances), the orbit did not escape. A
/// collapse while the state grows without bound is the solution's blow-up: an escape.
pub const ADAPTIVE_STEP_FAILED: &str = "the adaptive step size control failed";

/// The time named by an end-of-run reason of an integrator failure ([`INTEGRATOR_FAILED`],
/// or an escape reason whose cause is [`IMPLICIT_NOT_CONVERGED`]), `None` for any other reason.
pub fn integrator_failure_time(reason: &str) -> Option<f64> {
    if let Some(rest) = reason.strip_prefix(INTEGRATOR_FAILED) {
        let rest = rest.strip_prefix(" by t = ")?;
        let end = rest.find([' ', ',', ':', ')']).unwrap_or(rest.len());
        return rest[..end].parse::<f64>().ok().filter(|t| t.is_finite());
    }
    if reason.contains(IMPLICIT_NOT_CONVERGED) {
        return escape_time(reason);
    }
    None
}

#[cfg(test)]
mod escape_tests {
    use super::*;

    #[test]
    fn the_escape_time_is_read_back_from_the_reason() {
        let r = format!("{REFERENCE_ESCAPED} by t = 14.5 (|x| = 1e100): |x| passed 1e100");
        assert_eq!(escape_time(&r), Some(14.5));
        assert_eq!(
            escape_time(&format!("{REFERENCE_ESCAPED} by t = 3")),
            Some(3.0)
        );
        assert_eq!(escape_time("scheme 'mpm', set 0, t = 5: zero vector"), None);
        assert_eq!(
            escape_time(&format!("{REFERENCE_ESCAPED} by t = nan")),
            None
        );
    }

    #[test]
    fn an_integrator_failure_is_read_back_and_is_not_an_escape() {
        let r = format!("{INTEGRATOR_FAILED} by t = 135.2: {IMPLICIT_NOT_CONVERGED} (h = 0.1)");
        assert_eq!(integrator_failure_time(&r), Some(135.2));
        assert_eq!(escape_time(&r), None);
        // A recording of the earlier format: the same failure inside an escape reason.
        let old = format!("{REFERENCE_ESCAPED} by t = 135 (|x| = NaN): {IMPLICIT_NOT_CONVERGED}");
        assert_eq!(integrator_failure_time(&old), Some(135.0));
        let escape = format!("{REFERENCE_ESCAPED} by t = 3 (|x| = 1e100): |x| passed 1e100");
        assert_eq!(integrator_failure_time(&escape), None);
    }
}
