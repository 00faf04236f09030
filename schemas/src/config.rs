//! The run configuration: what a user writes in a TOML file.
//!
//! These types are the contract of the config file (key names are public API: scripts rely on
//! them). They only describe and syntactically validate; turning a config into numerics (solving
//! an initial condition from the energy, drawing directions) is the producer's job.

use std::path::Path;

use schemars::JsonSchema;
use serde::{Deserialize, Serialize};

mod load;
pub mod locate;
mod model;
pub mod paper;
mod parse_error;
mod scheme;
pub mod sweep;

// Every kind's keys (`model/KIND.rs`), re-exported by `model.rs` from its table.
pub use model::*;
pub use scheme::SchemeConfig;

use sweep::{SweepConfig, SweepError};

pub use load::{
    ConfigLoadError, ConfigSource, MAX_CONFIG_BYTES, parse_config_bytes, parse_config_source,
    read_bounded, read_config_file, read_config_source,
};

/// Top level of a run configuration file.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct RunConfig {
    /// Optional human name of the run; the bus service names derive from it.
    #[serde(default)]
    pub run: RunSection,
    pub model: ModelConfig,
    pub orbit: OrbitConfig,
    pub integrator: IntegratorConfig,
    pub deviations: DeviationsConfig,
    /// One or more renormalization schemes evolved around the same reference orbit.
    #[serde(rename = "scheme", default)]
    pub schemes: Vec<SchemeConfig>,
    /// Ranges of schemes (see [`sweep`]), expanded after the explicit schemes.
    #[serde(rename = "sweep", default, skip_serializing_if = "Vec::is_empty")]
    pub sweeps: Vec<SweepConfig>,
    /// Present only for `chaoscope map`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub map: Option<MapConfig>,
    /// How the analysis reads the run (the 0-1 test's observable).
    #[serde(default, skip_serializing_if = "AnalysisSection::is_default")]
    pub analysis: AnalysisSection,
}

/// `[analysis]`: choices of the analysis that the run's recording carries, so `analyze`, replay
/// and the live views of the run read it the same way.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct AnalysisSection {
    /// The observable of the 0-1 test for chaos: an expression of the state (`x1..xD`, or
    /// `q1..qN`, `p1..pN` for a Hamiltonian, with the model's `params`), evaluated on the state
    /// as integrated (a flow's angle continuous). Default: a generic combination of every
    /// coordinate with fixed unequal weights, a periodic coordinate by the sine and cosine of
    /// its angle.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub zero_one_observable: Option<String>,
}

impl AnalysisSection {
    fn is_default(&self) -> bool {
        *self == Self::default()
    }
}

#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct RunSection {
    /// Run name (letters, digits, `-`, `_`); default derived from the process id and time.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub name: Option<String>,
    /// Record a sample (the reference state and every set's separation vectors) every this
    /// much time instead of at every renormalization: a multiple of every scheme's `tau`. The
    /// stretching factors of the renormalizations in between travel with the next sample, so
    /// every indicator accumulated from them (Lyapunov exponents, FLI, MEGNO) stays exact;
    /// GALI, SALI, OFLI and the distributions are computed at the samples. Default: a sample
    /// at every renormalization.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub sample_every: Option<f64>,
}

#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct OrbitConfig {
    /// The initial state `x1..xD` of a general (non-Hamiltonian) system.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub x: Vec<f64>,
    /// Positions q1..qN. May be omitted when `preset` gives them.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub q: Vec<f64>,
    /// Momenta p1..pN. The entry named by `solve_for` is ignored (solved from `energy`); with
    /// `solve_for` and `energy`, `p` may be left out (every other momentum is then 0).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub p: Vec<f64>,
    /// Target energy; requires `solve_for`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub energy: Option<f64>,
    /// Momentum solved from `energy`, e.g. `"p1"` (the positive root is taken).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub solve_for: Option<String>,
    /// Named initial condition generator, e.g. `"spo1"` for the FPUT chain (uses `energy`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub preset: Option<String>,
    /// A lattice at rest but for the momenta of one site or a block of sites, which share an
    /// energy: `excite = { sites = 500, energy = 0.4 }`, `excite = { sites = [490, 510],
    /// energy = 0.4, seed = 3 }` (separable Hamiltonians).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub excite: Option<Excitation>,
}

/// `[orbit] excite`: every `q = 0` and every momentum 0 except those of the excited sites, each
/// carrying the kinetic energy `energy / L` of a block of `L` sites (`p_l = +-sqrt(2 m_l
/// energy / L)`): the single-site and block excitations of the disordered-lattice literature.
/// The energy of the state is `energy + V(0)`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct Excitation {
    /// One site `l`, or the block `[first, last]` (sites numbered from 1, ends included).
    pub sites: ExcitedSites,
    /// The energy the excited sites share (positive). Required by separable Hamiltonians; a
    /// `ddnls` takes `norm` or `energy`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub energy: Option<f64>,
    /// The norm `S = sum |psi_l|^2` the excited sites share (`ddnls` only).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub norm: Option<f64>,
    /// With a seed, the momenta's signs are drawn from it (the "random phases" of a block;
    /// a `ddnls` draws each site's phase uniform in `[0, 2 pi)`); without, every momentum is
    /// positive (a `ddnls`: every phase 0).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub seed: Option<u64>,
}

/// The sites of an excitation: one, or a block.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, JsonSchema)]
#[serde(untagged)]
pub enum ExcitedSites {
    One(usize),
    Block([usize; 2]),
}

/// By the value's shape, so a wrong one (`-3`, `[1, 2, 3]`) is told what a site may be rather
/// than serde's "did not match any variant".
impl<'de> Deserialize<'de> for ExcitedSites {
    fn deserialize<D: serde::Deserializer<'de>>(deserializer: D) -> Result<Self, D::Error> {
        use serde::de::{Error, SeqAccess, Visitor};
        struct SitesVisitor;
        impl<'de> Visitor<'de> for SitesVisitor {
            type Value = ExcitedSites;
            fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
                f.write_str("a site number (from 1) or a block [first, last]")
            }
            fn visit_u64<E: Error>(self, v: u64) -> Result<ExcitedSites, E> {
                usize::try_from(v)
                    .map(ExcitedSites::One)
                    .map_err(|_| E::custom(format!("site {v} is out of range")))
            }
            fn visit_i64<E: Error>(self, v: i64) -> Result<ExcitedSites, E> {
                u64::try_from(v)
                    .map_err(|_| {
                        E::custom(format!(
                            "sites are numbered from 1, got {v}; expected {}",
                            "a site number (from 1) or a block [first, last]"
                        ))
                    })
                    .and_then(|v| self.visit_u64(v))
            }
            fn visit_seq<A: SeqAccess<'de>>(self, mut seq: A) -> Result<ExcitedSites, A::Error> {
                let mut ends = Vec::new();
                while let Some(v) = seq.next_element::<usize>()? {
                    ends.push(v);
                }
                match ends[..] {
                    [first, last] => Ok(ExcitedSites::Block([first, last])),
                    _ => Err(A::Error::custom(format!(
                        "a block is [first, last], got {} entries",
                        ends.len()
                    ))),
                }
            }
        }
        deserializer.deserialize_any(SitesVisitor)
    }
}

impl ExcitedSites {
    /// `(first, last)`, numbered from 1.
    pub fn range(self) -> (usize, usize) {
        match self {
            ExcitedSites::One(l) => (l, l),
            ExcitedSites::Block([a, b]) => (a, b),
        }
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct IntegratorConfig {
    /// Splittings of separable Hamiltonians: `"aba864"`, `"leapfrog"`, `"saba2"`, `"saba3"`,
    /// `"saba4"`, `"yoshida4"`, `"aba104"`, `"aba1064"`, `"s9odr6"`, `"s11odr6"`, `"s17odr8"`.
    /// Runge-Kutta methods of flows: `"rk4"`, `"dop853"` (implicit symplectic: `"gl4"`,
    /// `"gl6"`); Taylor's method of flows written as expressions: `"taylor"`. Three-part
    /// compositions of the DDNLS: `"abc2"`, `"abc4"`, `"s9abc6"`, `"s11abc6"`, `"s17abc8"`.
    /// Maps: `"iterate"` or left out.
    #[serde(default, skip_serializing_if = "String::is_empty")]
    pub method: String,
    /// Time step. Fixed-step methods take exactly this step; adaptive `dop853` (with `rtol` /
    /// `atol`) lands every accepted step on the grid of multiples of `h`, so `h` is the time
    /// grid that `tau` and `t_final` are multiples of. Required, except for a map, whose time
    /// counts iterations: there `h` may be left out (it is 1, one iteration; any other value is
    /// refused).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub h: Option<f64>,
    /// Final time (the horizon of a map).
    pub t_final: f64,
    /// Relative tolerance of adaptive `dop853` (error control on; needs `atol` too).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rtol: Option<f64>,
    /// Absolute tolerance of adaptive `dop853`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub atol: Option<f64>,
    /// Tolerance of `"taylor"` (absolute below |x| = 1, relative above; its order follows
    /// from it). Default: double precision's epsilon, 2.220446049250313e-16.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub tol: Option<f64>,
}

impl IntegratorConfig {
    /// A fixed-step method with step `h` up to `t_final`.
    pub fn fixed(method: &str, h: f64, t_final: f64) -> Self {
        Self {
            method: method.to_string(),
            h: Some(h),
            t_final,
            rtol: None,
            atol: None,
            tol: None,
        }
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct DeviationsConfig {
    /// Number of deviation vectors per set, 2..=2N.
    pub k: usize,
    /// Number of independent random sets.
    #[serde(default = "default_sets")]
    pub sets: usize,
    /// Seed of the direction generator.
    #[serde(default)]
    pub seed: u64,
    /// Explicit directions (k rows of length 2N, order q1..qN, p1..pN); replaces the random
    /// draw and implies `sets = 1`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub vectors: Option<Vec<Vec<f64>>>,
}

fn default_sets() -> usize {
    1
}

impl DeviationsConfig {
    /// `sets` sets of `k` Haar-random directions drawn from `seed`.
    pub fn random(k: usize, sets: usize, seed: u64) -> Self {
        Self {
            k,
            sets,
            seed,
            vectors: None,
        }
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct MapAxis {
    /// Coordinate name such as `"q2"` or `"p2"` (a coordinate axis; empty for a parameter
    /// axis).
    #[serde(default, skip_serializing_if = "String::is_empty")]
    pub coord: String,
    /// A parameter axis: the name of a scalar of `[model] params` (`"K"`), whose value each
    /// grid line sets; the coordinates keep the config's initial state. Either `coord` or
    /// `param`, never both.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub param: Option<String>,
    pub min: f64,
    pub max: f64,
    pub n: usize,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct MapConfig {
    pub x: MapAxis,
    pub y: MapAxis,
    /// `"gali"`, `"gali-time"`, `"sali"`, `"mle"`, `"spectrum"` (the first `k` Lyapunov
    /// exponents, with QR renormalization), or an output of a registered set indicator
    /// that needs no flow direction: `"fli"`, `"megno"` or `"megno_mean"` (`ofli` is not one).
    pub indicator: String,
    /// Order of the GALI (for `gali` and `gali-time`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub k: Option<usize>,
    /// Threshold under which `gali-time` stops an orbit.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub threshold: Option<f64>,
    /// How the sets are evolved: `"per-set"` (the reference: every set's `k` vectors or nearby
    /// orbits) or `"basis"` (one basis of `D` tangent vectors (VM) or nearby orbits (MPM) per
    /// point, accumulated over the orbit, every set's vectors formed from it; `"propagator"`,
    /// its former name, is read too). Absent: the cheaper of the two where both give the same
    /// numbers (VM, not `spectrum` or `gali-time`), else `"per-set"`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub route: Option<String>,
}

impl MapAxis {
    pub fn new(coord: &str, min: f64, max: f64, n: usize) -> Self {
        Self {
            coord: coord.to_string(),
            param: None,
            min,
            max,
            n,
        }
    }

    /// An axis over the parameter `name` of `[model] params`.
    pub fn param(name: &str, min: f64, max: f64, n: usize) -> Self {
        Self {
            coord: String::new(),
            param: Some(name.to_string()),
            min,
            max,
            n,
        }
    }
}

impl MapConfig {
    /// A map of `indicator` over the grid `x` by `y`, without `k` or `threshold`.
    pub fn new(x: MapAxis, y: MapAxis, indicator: &str) -> Self {
        Self {
            x,
            y,
            indicator: indicator.to_string(),
            k: None,
            threshold: None,
            route: None,
        }
    }
}

/// A config that failed to parse; one line naming the offending key, line and column.
#[derive(Debug, thiserror::Error)]
#[error("invalid run configuration: {0}")]
pub struct ConfigParseError(pub String);

impl RunConfig {
    /// Parse a TOML document. Unknown keys are errors (a typo must not silently fall back to a
    /// default).
    pub fn from_toml(text: &str) -> Result<Self, ConfigParseError> {
        toml::from_str(text).map_err(|e| ConfigParseError(parse_error::describe(text, &e)))
    }

    /// Read a config file; relative table paths are taken from the file's directory (so a
    /// config and its tables move together), and written back as the joined paths.
    pub fn from_file_text(text: &str, path: &Path) -> Result<Self, ConfigParseError> {
        let mut config = Self::from_toml(text)?;
        let dir = path.parent().unwrap_or(Path::new(""));
        for table in config
            .model
            .tables_mut()
            .into_iter()
            .flat_map(|t| t.values_mut())
        {
            let mut spec = table.spec();
            if Path::new(&spec.file).is_relative() && !dir.as_os_str().is_empty() {
                spec.file = dir.join(&spec.file).to_string_lossy().into_owned();
                *table = TableConfig::Detailed(spec);
            }
        }
        Ok(config)
    }

    /// The JSON Schema of a configuration file, derived from the types that parse it (every
    /// key, its type and documentation; unknown keys refused): what TOML editors that take a
    /// schema (taplo, Even Better TOML) check and complete a config with.
    pub fn json_schema() -> serde_json::Value {
        let mut schema = serde_json::to_value(schemars::schema_for!(RunConfig))
            .expect("a JSON Schema serializes");
        schema["title"] = "chaoscope run configuration".into();
        schema
    }

    /// Canonical TOML text (stored in recordings so a run can be replayed).
    pub fn to_toml(&self) -> String {
        toml::to_string(self).expect("a RunConfig always serializes")
    }
}

impl RunConfig {
    /// The `[[scheme]]` entries followed by the expansion of every `[[sweep]]`, in order.
    pub fn expanded_schemes(&self) -> Result<Vec<SchemeConfig>, SweepError> {
        let mut all = self.schemes.clone();
        for (i, s) in self.sweeps.iter().enumerate() {
            all.extend(s.expand(i)?);
        }
        Ok(all)
    }

    /// The same run with every sweep expanded into explicit schemes.
    pub fn with_sweeps_expanded(&self) -> Result<RunConfig, SweepError> {
        let mut c = self.clone();
        c.schemes = self.expanded_schemes()?;
        c.sweeps.clear();
        Ok(c)
    }
}

/// A number as the user would write it: `1e-300` rather than three hundred zeros (and `1e308`
/// rather than 309 digits), for the messages that quote a value.
pub fn num(v: f64) -> String {
    let plain = format!("{v}");
    let sci = format!("{v:e}");
    if plain.len() <= sci.len() { plain } else { sci }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The paper's Henon-Heiles run with one VM scheme and `sweeps` as a user writes them.
    fn sweep_config(sweeps: &str) -> RunConfig {
        let base = paper::henon_heiles(
            paper::HH_CHAOTIC_Q2,
            10.0,
            DeviationsConfig::random(2, 1, 0),
            vec![SchemeConfig::new("vm", "vm", 1e-8, 1.0)],
        );
        RunConfig::from_toml(&(base.to_toml() + sweeps)).unwrap()
    }

    #[test]
    fn per_decade_range_gives_clean_decades_and_names() {
        let c = sweep_config(
            "[[sweep]]\nmethod = \"mpm\"\nd0 = { from = 1e-14, to = 1e-2, per_decade = 1 }\ntau = [0.1, 1.0]\n",
        );
        let s = c.expanded_schemes().unwrap();
        assert_eq!(s.len(), 1 + 13 * 2);
        assert_eq!(s[0].name, "vm");
        let d0s: Vec<f64> = s[1..14].iter().map(|s| s.d0).collect();
        assert_eq!(d0s[0], 1e-14);
        assert_eq!(d0s[6], 1e-8);
        assert_eq!(d0s[12], 1e-2);
        assert_eq!(s[7].name, "mpm-d01e-8-tau0.1");
        assert_eq!(s[14].tau, 1.0);
        assert!(s.iter().all(|s| s.orthonormalize == "rescale"));
        // The config with the sweep round-trips through TOML (recordings store it).
        assert_eq!(RunConfig::from_toml(&c.to_toml()).unwrap(), c);
        let e = c.with_sweeps_expanded().unwrap();
        assert!(e.sweeps.is_empty());
        assert_eq!(e.schemes, s);
    }

    #[test]
    fn bad_sweeps_name_their_key() {
        let cases = [
            (
                "d0 = { from = 1e-2, to = 1e-4, per_decade = 1 }\ntau = 1.0",
                "sweep[0].d0",
            ),
            ("d0 = 1e-8\ntau = []", "sweep[0].tau"),
            ("d0 = { from = 1e-8, to = 1e-2 }\ntau = 1.0", "sweep[0].d0"),
            ("d0 = -1.0\ntau = 1.0", "sweep[0].d0"),
            (
                "d0 = { from = 1e-300, to = 1e300, per_decade = 100 }\ntau = 1.0",
                "sweep[0].d0",
            ),
        ];
        for (body, key) in cases {
            let c = sweep_config(&format!("[[sweep]]\nmethod = \"mpm\"\n{body}\n"));
            assert_eq!(c.expanded_schemes().unwrap_err().key, key, "{body}");
        }
    }

    #[test]
    fn issue_keys_parse_and_round_trip() {
        let text = r#"
[model]
name = "henon-heiles"
[orbit]
q = [0.0, -0.25]
p = [0.0, 0.0]
energy = 0.125
solve_for = "p1"
[integrator]
method = "aba864"
h = 0.01
t_final = 1000.0
[deviations]
k = 4
sets = 3
seed = 7
[[scheme]]
name = "vm"
method = "vm"
d0 = 1e-8
tau = 1.0
orthonormalize = "rescale"
[[scheme]]
name = "mpm"
method = "mpm"
d0 = 1e-8
tau = 1.0
"#;
        let c = RunConfig::from_toml(text).unwrap();
        assert_eq!(c.schemes.len(), 2);
        assert_eq!(c.schemes[1].orthonormalize, "rescale");
        assert_eq!(c.deviations.sets, 3);
        let again = RunConfig::from_toml(&c.to_toml()).unwrap();
        assert_eq!(c, again);
        // The typed paper run is this very config.
        let typed = paper::henon_heiles(
            paper::HH_CHAOTIC_Q2,
            1000.0,
            DeviationsConfig::random(4, 3, 7),
            vec![
                SchemeConfig::new("vm", "vm", 1e-8, 1.0),
                SchemeConfig::new("mpm", "mpm", 1e-8, 1.0),
            ],
        );
        assert_eq!(c, typed);
    }

    #[test]
    fn unknown_key_is_named() {
        let err = RunConfig::from_toml("[model]\nname='henon-heiles'\nbta=1\n").unwrap_err();
        assert!(err.to_string().contains("bta"), "{err}");
    }
}
