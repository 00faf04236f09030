//! `[model]`: the system a run integrates, one kind per `name`, each kind's keys in its own
//! struct. A key another kind reads is an error naming its line and column, like any unknown
//! key; what the values mean (ranges, expressions, the initial state they need) is checked by
//! the producer's validation of that kind.
//!
//! Kinds: separable Hamiltonians `H = sum p_i^2 / (2 m_i) + V(q)` (`henon-heiles`, `fput-beta`,
//! `potential` with `V` written as an expression), any Hamiltonian `H(q, p)` (`hamiltonian`),
//! the disordered discrete nonlinear Schroedinger lattice (`ddnls`, `config/ddnls.rs`),
//! flows `dx/dt = f(x)` (`ode`) and maps `x -> F(x)` (`map`). A model or system written in Rust
//! (the library route) is named by a `name` of its own ([`CustomModelConfig`]).

use std::collections::BTreeMap;

use schemars::JsonSchema;
use serde::de::value::MapAccessDeserializer;
use serde::de::{self, DeserializeSeed, IntoDeserializer, MapAccess, Visitor};
use serde::{Deserialize, Deserializer, Serialize};

/// The `[model]` table: which system, and its parameters.
#[derive(Debug, Clone, PartialEq, Serialize, JsonSchema)]
#[serde(tag = "name")]
pub enum ModelConfig {
    /// The Henon-Heiles potential (2 degrees of freedom).
    #[serde(rename = "henon-heiles")]
    HenonHeiles(HenonHeilesConfig),
    /// The beta-FPUT chain with fixed ends.
    #[serde(rename = "fput-beta")]
    FputBeta(FputBetaConfig),
    /// A separable Hamiltonian whose potential `V(q)` is an expression.
    #[serde(rename = "potential")]
    Potential(PotentialConfig),
    /// Any Hamiltonian `H(q, p)` written as an expression, integrated by a Runge-Kutta method.
    #[serde(rename = "hamiltonian")]
    Hamiltonian(HamiltonianConfig),
    /// The disordered discrete nonlinear Schroedinger lattice (1-D chain or 2-D square).
    #[serde(rename = "ddnls")]
    Ddnls(super::ddnls::DdnlsConfig),
    /// A flow `dx/dt = f(x)` written as expressions.
    #[serde(rename = "ode")]
    Ode(OdeConfig),
    /// A map `x -> F(x)` written as expressions.
    #[serde(rename = "map")]
    Map(MapModelConfig),
    /// A model or system built in code (`RunSpec::with_model`, `RunSpec::with_system`): its
    /// name, which recordings carry, and the keys its code reads. The command-line tools know
    /// no such name, so the configuration's JSON Schema has no room for it.
    #[serde(untagged)]
    #[schemars(skip)]
    Custom(CustomModelConfig),
}

/// `name = "henon-heiles"`.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct HenonHeilesConfig {
    /// Degrees of freedom: 2 (may be left out).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub n: Option<usize>,
}

/// `name = "fput-beta"`: `H = sum p_i^2/2 + sum (q_{i+1} - q_i)^2/2 + beta (q_{i+1} - q_i)^4/4`.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct FputBetaConfig {
    /// Number of particles `N`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub n: Option<usize>,
    /// Quartic coupling (default 1).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub beta: Option<f64>,
}

/// `name = "potential"`: `H = sum p_i^2 / (2 m_i) + V(q)` with `V` in chaoscope's expression
/// language.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct PotentialConfig {
    /// Number of degrees of freedom (lattice sites) `N`; with `lattice = "square"` the side of
    /// the square (`n^2` sites).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub n: Option<usize>,
    /// `"chain"` (default: `q1..qN`, `q[i]`) or `"square"`: an `n x n` lattice whose sites are
    /// `q[i, j]` (row `i`, column `j`), numbered row by row.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub lattice: Option<String>,
    /// `V(q)` over `q1..qN` (or `q[i]`), `params` and `tables`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub potential: Option<String>,
    /// Parameters the expression names: a number, or an array with one entry per site.
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub params: BTreeMap<String, ParamValue>,
    /// Masses `m_i`: one number for every site or one per site (default 1).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub masses: Option<ParamValue>,
    /// What lattice sums see beyond the ends: `"fixed"` (default: `q[0] = q[N+1] = 0`),
    /// `"periodic"` (`q[N+1] = q[1]`) or `"free"` (terms reaching past an end are left out);
    /// on a square lattice one for both axes or one per axis, `["fixed", "periodic"]` (along
    /// `i`, then along `j`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub boundary: Option<BoundaryConfig>,
    /// Tabulated functions the expression may call by name, e.g. `U = "bond.csv"`.
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub tables: BTreeMap<String, TableConfig>,
    /// Per coordinate of the state `q1..qN, p1..pN` (2N entries), the period it is taken
    /// modulo (e.g. `6.283185307179586` for an angle), or 0 for a coordinate that is not
    /// periodic: as a map's `modulo`. The integration never wraps the state (the exponents are
    /// those of the unwrapped flow); what is read and shown of it (the verdict's extent, the 0-1
    /// test, sections) takes the wrapped value.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub modulo: Option<Vec<f64>>,
}

/// `boundary`: one condition for every end, or one per axis of a square lattice.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(
    untagged,
    expecting = "a boundary condition (\"fixed\", \"periodic\" or \"free\"), or one per axis of a \
                 square lattice: [\"fixed\", \"periodic\"]"
)]
pub enum BoundaryConfig {
    /// `"fixed"`, `"periodic"` or `"free"`.
    Every(String),
    /// `["fixed", "periodic"]`: along the rows' index `i`, then along the columns' `j`.
    PerAxis(Vec<String>),
}

impl From<&str> for BoundaryConfig {
    fn from(name: &str) -> Self {
        Self::Every(name.to_string())
    }
}

/// `name = "hamiltonian"`: any `H(q, p)`, separable or not.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct HamiltonianConfig {
    /// Degrees of freedom `N`; with `lattice = "square"` the side of the square (`n^2` sites).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub n: Option<usize>,
    /// `"chain"` (default) or `"square"` (`q[i, j]`, `p[i, j]`), as for `potential`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub lattice: Option<String>,
    /// Parameters the expression names: a number, or an array with one entry per degree of
    /// freedom.
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub params: BTreeMap<String, ParamValue>,
    /// What lattice sums see beyond the ends (as for `potential`, also per axis).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub boundary: Option<BoundaryConfig>,
    /// `H(q, p)` over `q1..qN`, `p1..pN` (and `q[i]`, `p[i]`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub hamiltonian: Option<String>,
    /// Per coordinate of the state `q1..qN, p1..pN` (2N entries), the period it is taken
    /// modulo (e.g. `6.283185307179586` for an angle), or 0 for a coordinate that is not
    /// periodic: as a map's `modulo`. The integration never wraps the state (the exponents are
    /// those of the unwrapped flow); what is read and shown of it (the verdict's extent, the 0-1
    /// test, sections) takes the wrapped value.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub modulo: Option<Vec<f64>>,
}

/// `name = "ode"`: `dx/dt = f(x)`.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct OdeConfig {
    /// Parameters the expressions name: a number, or an array with one entry per coordinate.
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub params: BTreeMap<String, ParamValue>,
    /// What lattice sums see beyond the ends (as for `potential`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub boundary: Option<String>,
    /// The right-hand side `f_1(x), ..., f_D(x)`, one expression per coordinate over `x1..xD`
    /// (or `x[i]`) and `params`; `D` is the number of entries.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rhs: Option<Vec<String>>,
    /// Per coordinate of the state `x1..xD` (D entries), the period it is taken
    /// modulo (e.g. `6.283185307179586` for an angle), or 0 for a coordinate that is not
    /// periodic: as a map's `modulo`. The integration never wraps the state (the exponents are
    /// those of the unwrapped flow); what is read and shown of it (the verdict's extent, the 0-1
    /// test, sections) takes the wrapped value.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub modulo: Option<Vec<f64>>,
}

/// `name = "map"`: `x -> F(x)`.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct MapModelConfig {
    /// Parameters the expressions name: a number, or an array with one entry per coordinate.
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub params: BTreeMap<String, ParamValue>,
    /// What lattice sums see beyond the ends (as for `potential`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub boundary: Option<String>,
    /// The map, one expression `F_i(x)` per coordinate over `x1..xD` (or `x[i]`) and `params`;
    /// `D` is the number of entries.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub next: Option<Vec<String>>,
    /// Per coordinate, the period it is taken modulo (e.g. `6.283185307179586` for an angle),
    /// or 0 for a coordinate that is not wrapped. Separations of nearby orbits are measured on
    /// the torus (the minimal image).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub modulo: Option<Vec<f64>>,
}

/// A model or system built in code: the name recordings carry, and whatever other keys its
/// code reads (kept as written; the command-line tools refuse the name).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct CustomModelConfig {
    pub name: String,
    #[serde(flatten)]
    pub keys: BTreeMap<String, toml::Value>,
}

/// A parameter value: one number, or one number per site (written out, or drawn at random
/// from a seed: `eps = { uniform = [0.5, 1.5], seed = 7 }`).
#[derive(Debug, Clone, PartialEq, Serialize, JsonSchema)]
#[serde(untagged)]
pub enum ParamValue {
    Scalar(f64),
    Array(Vec<f64>),
    Drawn(DrawnArray),
}

/// By the value's shape, so a wrong one gets a message saying what a parameter may be (and a
/// drawn array's own errors, an unknown or a missing key, name the key) instead of serde's
/// "did not match any variant".
impl<'de> Deserialize<'de> for ParamValue {
    fn deserialize<D: Deserializer<'de>>(deserializer: D) -> Result<Self, D::Error> {
        struct ParamVisitor;
        impl<'de> Visitor<'de> for ParamVisitor {
            type Value = ParamValue;
            fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
                f.write_str(
                    "a number, an array of numbers (one per site), or a drawn array \
                     { uniform = [lo, hi], seed = S }",
                )
            }
            fn visit_f64<E: de::Error>(self, v: f64) -> Result<ParamValue, E> {
                Ok(ParamValue::Scalar(v))
            }
            fn visit_i64<E: de::Error>(self, v: i64) -> Result<ParamValue, E> {
                Ok(ParamValue::Scalar(v as f64))
            }
            fn visit_u64<E: de::Error>(self, v: u64) -> Result<ParamValue, E> {
                Ok(ParamValue::Scalar(v as f64))
            }
            fn visit_seq<A: de::SeqAccess<'de>>(self, mut seq: A) -> Result<ParamValue, A::Error> {
                let mut values = Vec::new();
                while let Some(v) = seq.next_element::<f64>()? {
                    values.push(v);
                }
                Ok(ParamValue::Array(values))
            }
            fn visit_map<A: MapAccess<'de>>(self, map: A) -> Result<ParamValue, A::Error> {
                DrawnArray::deserialize(MapAccessDeserializer::new(map)).map(ParamValue::Drawn)
            }
        }
        deserializer.deserialize_any(ParamVisitor)
    }
}

/// An array parameter drawn at random, one entry per site, from a seed: a disorder realization
/// (`eps_l` uniform in `[1/2, 3/2]` of the disordered Klein-Gordon chain) written in two
/// numbers, the same on every machine and version. How the entries are drawn is the producer's
/// and is documented with the configuration.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct DrawnArray {
    /// `[lo, hi]`: each entry uniform in `[lo, hi)`.
    #[serde(deserialize_with = "two_numbers")]
    pub uniform: [f64; 2],
    /// The realization: another seed, another disorder.
    pub seed: u64,
}

/// A pair `[a, b]` of numbers, every entry read: serde's fixed-size array reads its first two
/// entries and leaves the rest unread, which TOML then drops without a word
/// (`uniform = [0.5, 1.5, "x"]` would pass as `[0.5, 1.5]`).
fn two_numbers<'de, D: Deserializer<'de>>(deserializer: D) -> Result<[f64; 2], D::Error> {
    let values = Vec::<f64>::deserialize(deserializer)?;
    match values[..] {
        [a, b] => Ok([a, b]),
        _ => Err(de::Error::custom(format!(
            "expected two numbers [a, b], not {}",
            values.len()
        ))),
    }
}

/// [`two_numbers`] of an optional key.
fn two_numbers_or_none<'de, D: Deserializer<'de>>(
    deserializer: D,
) -> Result<Option<[f64; 2]>, D::Error> {
    two_numbers(deserializer).map(Some)
}

/// A tabulated function: samples `x, f(x)` in a CSV file, interpolated by a cubic spline.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(untagged)]
pub enum TableConfig {
    /// Just the file (natural spline).
    File(String),
    Detailed(TableSpec),
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct TableSpec {
    /// CSV file with two columns `x, f(x)`; a relative path is taken from the config file's
    /// directory.
    pub file: String,
    /// `"natural"` (default; zero second derivative at the ends) or `"clamped"` (with `slopes`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub spline: Option<String>,
    /// `[f'(x_first), f'(x_last)]` for a clamped spline.
    #[serde(
        default,
        skip_serializing_if = "Option::is_none",
        deserialize_with = "two_numbers_or_none"
    )]
    pub slopes: Option<[f64; 2]>,
    /// SHA-256 of the file's bytes. Recordings and map files carry it (the producer fills it
    /// in), so a replay or a resumed map refuses a table that differs from the one the run used;
    /// a user may pin it too.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub sha256: Option<String>,
}

impl TableConfig {
    /// The detailed form (a bare file name becomes a natural spline of that file).
    pub fn spec(&self) -> TableSpec {
        match self {
            TableConfig::File(file) => TableSpec {
                file: file.clone(),
                spline: None,
                slopes: None,
                sha256: None,
            },
            TableConfig::Detailed(spec) => spec.clone(),
        }
    }
}

/// Every `name` the command-line tools know, as error messages list them.
pub const KNOWN_MODELS: &str = "henon-heiles, fput-beta, potential, hamiltonian, ddnls, ode, map";

impl ModelConfig {
    /// `name = "potential"` with `V(q) = potential` on `n` sites.
    pub fn potential(n: usize, potential: &str) -> Self {
        Self::Potential(PotentialConfig {
            n: Some(n),
            potential: Some(potential.to_string()),
            ..PotentialConfig::default()
        })
    }

    /// A model built in code, named `name` (the library route).
    pub fn custom(name: &str) -> Self {
        Self::Custom(CustomModelConfig {
            name: name.to_string(),
            keys: BTreeMap::new(),
        })
    }

    /// The `name` as written in the config.
    pub fn name(&self) -> &str {
        match self {
            Self::HenonHeiles(_) => "henon-heiles",
            Self::FputBeta(_) => "fput-beta",
            Self::Potential(_) => "potential",
            Self::Hamiltonian(_) => "hamiltonian",
            Self::Ddnls(_) => "ddnls",
            Self::Ode(_) => "ode",
            Self::Map(_) => "map",
            Self::Custom(c) => &c.name,
        }
    }

    /// The period of each coordinate of the state (`modulo`: `0` for a coordinate that is not
    /// periodic), where the model declares any: maps, flows and the Hamiltonians written as
    /// expressions.
    pub fn modulo(&self) -> Option<&[f64]> {
        match self {
            Self::Potential(m) => m.modulo.as_deref(),
            Self::Hamiltonian(m) => m.modulo.as_deref(),
            Self::Ode(m) => m.modulo.as_deref(),
            Self::Map(m) => m.modulo.as_deref(),
            _ => None,
        }
    }

    /// The side `L` of the square lattice the model's sites form (`L^2` sites numbered row by
    /// row: `lattice = "square"` with `n = L`), `None` for a chain or a system without sites.
    pub fn square_side(&self) -> Option<usize> {
        let (lattice, n) = match self {
            Self::Ddnls(m) => (&m.lattice, m.n),
            Self::Potential(m) => (&m.lattice, m.n),
            Self::Hamiltonian(m) => (&m.lattice, m.n),
            _ => return None,
        };
        (lattice.as_deref() == Some("square"))
            .then_some(n)
            .flatten()
    }

    /// Which axes of the model's lattice close on themselves (`boundary = "periodic"`, for
    /// every axis or per axis: along `i`, then `j`; a chain reads the first): a ring, a cylinder
    /// or a torus, around which the distributions' second moments are measured.
    pub fn periodic_axes(&self) -> [bool; 2] {
        let boundary = match self {
            Self::Potential(m) => m.boundary.as_ref(),
            Self::Hamiltonian(m) => m.boundary.as_ref(),
            _ => None,
        };
        let periodic = |b: Option<&String>| b.is_some_and(|b| b == "periodic");
        match boundary {
            Some(BoundaryConfig::Every(b)) => [periodic(Some(b)); 2],
            Some(BoundaryConfig::PerAxis(axes)) => [periodic(axes.first()), periodic(axes.get(1))],
            None => [false; 2],
        }
    }

    /// The tables the model reads (only a `potential` has any).
    pub fn tables(&self) -> Option<&BTreeMap<String, TableConfig>> {
        match self {
            Self::Potential(p) => Some(&p.tables),
            _ => None,
        }
    }

    /// [`ModelConfig::tables`], to rewrite their paths or pin their digests.
    pub fn tables_mut(&mut self) -> Option<&mut BTreeMap<String, TableConfig>> {
        match self {
            Self::Potential(p) => Some(&mut p.tables),
            _ => None,
        }
    }

    /// The kinds whose `[model]` table takes `key` (for the message of a key given to another
    /// kind), in the order of [`KNOWN_MODELS`].
    pub fn kinds_with_key(key: &str) -> Vec<&'static str> {
        [
            ("henon-heiles", keys::<HenonHeilesConfig>()),
            ("fput-beta", keys::<FputBetaConfig>()),
            ("potential", keys::<PotentialConfig>()),
            ("hamiltonian", keys::<HamiltonianConfig>()),
            ("ddnls", keys::<super::ddnls::DdnlsConfig>()),
            ("ode", keys::<OdeConfig>()),
            ("map", keys::<MapModelConfig>()),
        ]
        .into_iter()
        .filter(|(_, k)| k.contains(&key))
        .map(|(name, _)| name)
        .collect()
    }
}

/// The keys a kind's struct reads, as its derived `Deserialize` states them (so they are
/// written once, in the struct).
fn keys<'de, T: Deserialize<'de>>() -> &'static [&'static str] {
    /// A deserializer that only records the field list a derived struct asks for.
    struct Fields(&'static [&'static str]);
    #[derive(Debug)]
    struct Recorded;
    impl std::fmt::Display for Recorded {
        fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
            f.write_str("field list recorded")
        }
    }
    impl std::error::Error for Recorded {}
    impl de::Error for Recorded {
        fn custom<M: std::fmt::Display>(_: M) -> Self {
            Recorded
        }
    }
    impl<'de> Deserializer<'de> for &mut Fields {
        type Error = Recorded;
        fn deserialize_any<V: Visitor<'de>>(self, _: V) -> Result<V::Value, Recorded> {
            Err(Recorded)
        }
        fn deserialize_struct<V: Visitor<'de>>(
            self,
            _: &'static str,
            fields: &'static [&'static str],
            _: V,
        ) -> Result<V::Value, Recorded> {
            self.0 = fields;
            Err(Recorded)
        }
        serde::forward_to_deserialize_any! {
            bool i8 i16 i32 i64 i128 u8 u16 u32 u64 u128 f32 f64 char str string bytes
            byte_buf option unit unit_struct newtype_struct seq tuple tuple_struct map enum
            identifier ignored_any
        }
    }
    let mut fields = Fields(&[]);
    let _ = T::deserialize(&mut fields);
    fields.0
}

/// Reads `[model]` entry by entry, so that every error of a kind's keys is raised while the
/// TOML reader stands at that key (and names its line and column): the entries before `name`
/// (rarely any: `name` comes first in every example) are kept aside, then the kind's own
/// struct reads them and the rest of the table.
impl<'de> Deserialize<'de> for ModelConfig {
    fn deserialize<D: Deserializer<'de>>(deserializer: D) -> Result<Self, D::Error> {
        deserializer.deserialize_map(ModelVisitor)
    }
}

struct ModelVisitor;

impl<'de> Visitor<'de> for ModelVisitor {
    type Value = ModelConfig;

    fn expecting(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("a [model] table with a name")
    }

    fn visit_map<A: MapAccess<'de>>(self, mut map: A) -> Result<ModelConfig, A::Error> {
        let mut before = Vec::new();
        while let Some(key) = map.next_key::<String>()? {
            if key != "name" {
                before.push((key, map.next_value::<toml::Value>()?));
                continue;
            }
            let name: String = map.next_value()?;
            return Ok(match name.as_str() {
                "henon-heiles" => {
                    ModelConfig::HenonHeiles(Deserialize::deserialize(rest(&mut before, &mut map))?)
                }
                "fput-beta" => {
                    ModelConfig::FputBeta(Deserialize::deserialize(rest(&mut before, &mut map))?)
                }
                "potential" => {
                    ModelConfig::Potential(Deserialize::deserialize(rest(&mut before, &mut map))?)
                }
                "hamiltonian" => {
                    ModelConfig::Hamiltonian(Deserialize::deserialize(rest(&mut before, &mut map))?)
                }
                "ddnls" => {
                    ModelConfig::Ddnls(Deserialize::deserialize(rest(&mut before, &mut map))?)
                }
                "ode" => ModelConfig::Ode(Deserialize::deserialize(rest(&mut before, &mut map))?),
                "map" => ModelConfig::Map(Deserialize::deserialize(rest(&mut before, &mut map))?),
                _ => ModelConfig::Custom(CustomModelConfig {
                    name,
                    keys: Deserialize::deserialize(rest(&mut before, &mut map))?,
                }),
            });
        }
        Err(de::Error::missing_field("name"))
    }
}

/// The entries `before` the name and what `map` has left, for a kind's struct to read.
fn rest<'a, 'de, A: MapAccess<'de>>(
    before: &mut Vec<(String, toml::Value)>,
    map: &'a mut A,
) -> MapAccessDeserializer<Rest<'a, A>> {
    MapAccessDeserializer::new(Rest {
        before: std::mem::take(before).into_iter(),
        value: None,
        map,
    })
}

/// The entries of a `[model]` table after `name`: first those read before it, then the rest
/// straight from the reader (whose errors carry their position).
struct Rest<'a, A> {
    before: std::vec::IntoIter<(String, toml::Value)>,
    value: Option<toml::Value>,
    map: &'a mut A,
}

impl<'de, A: MapAccess<'de>> MapAccess<'de> for Rest<'_, A> {
    type Error = A::Error;

    fn next_key_seed<K: DeserializeSeed<'de>>(
        &mut self,
        seed: K,
    ) -> Result<Option<K::Value>, A::Error> {
        match self.before.next() {
            Some((key, value)) => {
                self.value = Some(value);
                seed.deserialize(key.into_deserializer()).map(Some)
            }
            None => self.map.next_key_seed(seed),
        }
    }

    fn next_value_seed<V: DeserializeSeed<'de>>(&mut self, seed: V) -> Result<V::Value, A::Error> {
        match self.value.take() {
            Some(value) => seed
                .deserialize(value)
                .map_err(|e| de::Error::custom(e.message())),
            None => self.map.next_value_seed(seed),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(text: &str) -> Result<ModelConfig, String> {
        #[derive(Deserialize)]
        struct Doc {
            model: ModelConfig,
        }
        toml::from_str::<Doc>(text)
            .map(|d| d.model)
            .map_err(|e| format!("{:?}: {}", e.span(), e.message()))
    }

    #[test]
    fn each_kind_reads_its_own_keys() {
        let m = parse("[model]\nname = \"fput-beta\"\nn = 5\nbeta = 2.0\n").unwrap();
        assert_eq!(
            m,
            ModelConfig::FputBeta(FputBetaConfig {
                n: Some(5),
                beta: Some(2.0)
            })
        );
        // Keys before the name are read as well.
        let m = parse("[model]\nrhs = [\"x2\", \"-x1\"]\nname = \"ode\"\n").unwrap();
        assert_eq!(m.name(), "ode");
        // A key of another kind is refused at its position (line 3, byte 30).
        let text = "[model]\nname = \"potential\"\nrhs = [\"x1\"]\n";
        let e = parse(text).unwrap_err();
        assert!(e.contains("unknown field `rhs`"), "{e}");
        assert!(
            e.starts_with(&format!("Some({}..", text.find("rhs").unwrap())),
            "{e}"
        );
        assert_eq!(ModelConfig::kinds_with_key("rhs"), ["ode"]);
        assert_eq!(
            ModelConfig::kinds_with_key("params"),
            ["potential", "hamiltonian", "ode", "map"]
        );
    }

    #[test]
    fn a_name_alone_is_a_model_built_in_code() {
        let m = parse("[model]\nname = \"barbanis\"\n").unwrap();
        assert_eq!(m, ModelConfig::custom("barbanis"));
        // Its keys are its code's (the validation of a config refuses the name itself).
        let m = parse("[model]\nname = \"barbanis\"\neps = 0.08\n").unwrap();
        let ModelConfig::Custom(c) = &m else {
            panic!("{m:?}")
        };
        assert_eq!(c.keys["eps"].as_float(), Some(0.08));
        assert!(
            parse("[model]\nn = 2\n")
                .unwrap_err()
                .contains("missing field `name`")
        );
    }
}
