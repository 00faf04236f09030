//! `[model]`: the system a run integrates, one kind per `name`, each kind's keys in its own
//! struct and file (`config/model/KIND.rs`). A key another kind reads is an error naming its
//! line and column, like any unknown key; what the values mean (ranges, expressions, the
//! initial state they need) is checked by the dynamics crate's validation of that kind.
//!
//! Kinds: separable Hamiltonians `H = sum p_i^2 / (2 m_i) + V(q)` (`henon-heiles`, `fput-beta`,
//! `potential` with `V` written as an expression), any Hamiltonian `H(q, p)` (`hamiltonian`),
//! the disordered discrete nonlinear Schroedinger lattice (`ddnls`), flows `dx/dt = f(x)`
//! (`ode`) and maps `x -> F(x)` (`map`). A model or system written in Rust (the library route)
//! is named by a `name` of its own ([`CustomModelConfig`]).

use std::collections::BTreeMap;

use schemars::JsonSchema;
use serde::de::value::MapAccessDeserializer;
use serde::de::{self, DeserializeSeed, IntoDeserializer, MapAccess, Visitor};
use serde::{Deserialize, Deserializer, Serialize};

/// The kinds of `[model]`, one line each: the [`ModelConfig`] variant, the `name` a config
/// writes, the module holding the kind (`config/model/MODULE.rs` here, `spec/MODULE.rs` in the
/// dynamics crate) and its keys' struct. Whatever dispatches on the kind is generated from this
/// one table, which calls `$callback!` with it: here the enum, [`ModelConfig::name`],
/// [`KNOWN_MODELS`], the reader's dispatch and [`ModelConfig::kinds_with_key`]; in the dynamics
/// crate the validation's modules and dispatch. So a new kind is a line here, its file here and
/// its file there.
#[macro_export]
macro_rules! for_each_model_kind {
    ($callback:ident) => {
        $callback! {
            /// The Henon-Heiles potential (2 degrees of freedom).
            HenonHeiles = "henon-heiles" in henon_heiles: HenonHeilesConfig;
            /// The beta-FPUT chain with fixed ends.
            FputBeta = "fput-beta" in fput_beta: FputBetaConfig;
            /// A separable Hamiltonian whose potential `V(q)` is an expression.
            Potential = "potential" in potential: PotentialConfig;
            /// Any Hamiltonian `H(q, p)` written as an expression, integrated by a Runge-Kutta
            /// method.
            Hamiltonian = "hamiltonian" in hamiltonian: HamiltonianConfig;
            /// The disordered discrete nonlinear Schroedinger lattice (1-D chain or 2-D square).
            Ddnls = "ddnls" in ddnls: DdnlsConfig;
            /// A flow `dx/dt = f(x)` written as expressions.
            Ode = "ode" in ode: OdeConfig;
            /// A map `x -> F(x)` written as expressions.
            Map = "map" in map: MapModelConfig;
        }
    };
}

/// What code outside a kind's files asks of its keys, answered in the kind's file; each default
/// is the answer of a kind without the key.
pub trait ModelKind {
    /// `params`: the values its expressions name.
    fn params(&self) -> Option<&BTreeMap<String, ParamValue>> {
        None
    }
    /// `modulo`: the period of each coordinate of the state (0: not periodic).
    fn modulo(&self) -> Option<&[f64]> {
        None
    }
    /// Whether the state is canonical, `q1..qN, p1..pN` (a Hamiltonian), rather than `x1..xD`.
    fn canonical(&self) -> bool {
        false
    }
    /// The side of the square lattice its sites form (`lattice = "square"`).
    fn square_side(&self) -> Option<usize> {
        None
    }
    /// The `boundary` of its lattice, whose periodic axes close a ring, cylinder or torus.
    fn lattice_boundary(&self) -> Option<&BoundaryConfig> {
        None
    }
    /// What lattice sums in its expressions range over: `lattice`, `boundary` and `n`.
    fn summed_sites(&self) -> (Option<&str>, Option<BoundaryConfig>, Option<usize>) {
        (None, None, None)
    }
    /// The tabulated functions its expressions call.
    fn tables(&self) -> Option<&BTreeMap<String, TableConfig>> {
        None
    }
    /// [`ModelKind::tables`], to rewrite their paths or pin their digests.
    fn tables_mut(&mut self) -> Option<&mut BTreeMap<String, TableConfig>> {
        None
    }
}

/// The [`ModelKind`] answers of a kind written as expressions over a chain or a square lattice,
/// from its keys `n`, `lattice`, `boundary`, `params` and `modulo` (`potential`, `hamiltonian`).
macro_rules! lattice_expression_answers {
    () => {
        fn params(&self) -> Option<&BTreeMap<String, ParamValue>> {
            Some(&self.params)
        }
        fn modulo(&self) -> Option<&[f64]> {
            self.modulo.as_deref()
        }
        fn canonical(&self) -> bool {
            true
        }
        fn square_side(&self) -> Option<usize> {
            super::square_side(self.lattice.as_deref(), self.n)
        }
        fn lattice_boundary(&self) -> Option<&BoundaryConfig> {
            self.boundary.as_ref()
        }
        fn summed_sites(&self) -> (Option<&str>, Option<BoundaryConfig>, Option<usize>) {
            (self.lattice.as_deref(), self.boundary.clone(), self.n)
        }
    };
}

/// `"a, b, c"` of the literals given.
macro_rules! comma_separated {
    ($first:literal $(, $rest:literal)*) => {
        concat!($first $(, ", ", $rest)*)
    };
}

/// The kind table's items in this crate.
macro_rules! model_config {
    ($($(#[doc = $doc:literal])* $variant:ident = $name:literal in $module:ident: $config:ident;)*) => {
        $(
            mod $module;
            pub use $module::$config;
        )*

        /// The `[model]` table: which system, and its parameters.
        #[derive(Debug, Clone, PartialEq, Serialize, JsonSchema)]
        #[serde(tag = "name")]
        pub enum ModelConfig {
            $(
                $(#[doc = $doc])*
                #[serde(rename = $name)]
                $variant($config),
            )*
            /// A model or system built in code (`RunSpec::with_model`, `RunSpec::with_system`):
            /// its name, which recordings carry, and the keys its code reads. The command-line
            /// tools know no such name, so the configuration's JSON Schema has no room for it.
            #[serde(untagged)]
            #[schemars(skip)]
            Custom(CustomModelConfig),
        }

        /// Every `name` the command-line tools know, as error messages list them.
        pub const KNOWN_MODELS: &str = comma_separated!($($name),*);

        impl ModelConfig {
            /// The `name` as written in the config.
            pub fn name(&self) -> &str {
                match self {
                    $(Self::$variant(_) => $name,)*
                    Self::Custom(c) => &c.name,
                }
            }

            /// The kind's answers to what is asked of its keys (none for a model built in code).
            pub fn kind(&self) -> Option<&dyn ModelKind> {
                match self {
                    $(Self::$variant(m) => Some(m),)*
                    Self::Custom(_) => None,
                }
            }

            /// [`ModelConfig::kind`], mutable.
            pub fn kind_mut(&mut self) -> Option<&mut dyn ModelKind> {
                match self {
                    $(Self::$variant(m) => Some(m),)*
                    Self::Custom(_) => None,
                }
            }

            /// The kinds whose `[model]` table takes `key` (for the message of a key given to
            /// another kind), in the order of [`KNOWN_MODELS`].
            pub fn kinds_with_key(key: &str) -> Vec<&'static str> {
                [$(($name, keys::<$config>())),*]
                    .into_iter()
                    .filter(|(_, k)| k.contains(&key))
                    .map(|(name, _)| name)
                    .collect()
            }
        }

        /// The kind `name` names, its struct reading the rest of the table (a name no kind has
        /// is a model built in code, which keeps every key as written).
        fn read_kind<'de, A: MapAccess<'de>>(
            name: String,
            before: &mut Vec<(String, toml::Value)>,
            map: &mut A,
        ) -> Result<ModelConfig, A::Error> {
            Ok(match name.as_str() {
                $($name => ModelConfig::$variant(Deserialize::deserialize(rest(before, map))?),)*
                _ => ModelConfig::Custom(CustomModelConfig {
                    name,
                    keys: Deserialize::deserialize(rest(before, map))?,
                }),
            })
        }
    };
}

for_each_model_kind!(model_config);

/// The side of the square lattice `lattice = "square"` with `n` per side describes.
fn square_side(lattice: Option<&str>, n: Option<usize>) -> Option<usize> {
    (lattice == Some("square")).then_some(n).flatten()
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

    /// The period of each coordinate of the state (`modulo`: `0` for a coordinate that is not
    /// periodic), where the model declares any: maps, flows and the Hamiltonians written as
    /// expressions.
    pub fn modulo(&self) -> Option<&[f64]> {
        self.kind()?.modulo()
    }

    /// The side `L` of the square lattice the model's sites form (`L^2` sites numbered row by
    /// row: `lattice = "square"` with `n = L`), `None` for a chain or a system without sites.
    pub fn square_side(&self) -> Option<usize> {
        self.kind()?.square_side()
    }

    /// Which axes of the model's lattice close on themselves (`boundary = "periodic"`, for
    /// every axis or per axis: along `i`, then `j`; a chain reads the first): a ring, a cylinder
    /// or a torus, around which the distributions' second moments are measured.
    pub fn periodic_axes(&self) -> [bool; 2] {
        let periodic = |b: Option<&String>| b.is_some_and(|b| b == "periodic");
        match self.kind().and_then(|k| k.lattice_boundary()) {
            Some(BoundaryConfig::Every(b)) => [periodic(Some(b)); 2],
            Some(BoundaryConfig::PerAxis(axes)) => [periodic(axes.first()), periodic(axes.get(1))],
            None => [false; 2],
        }
    }

    /// The tables the model reads (only a `potential` has any).
    pub fn tables(&self) -> Option<&BTreeMap<String, TableConfig>> {
        self.kind()?.tables()
    }

    /// [`ModelConfig::tables`], to rewrite their paths or pin their digests.
    pub fn tables_mut(&mut self) -> Option<&mut BTreeMap<String, TableConfig>> {
        self.kind_mut()?.tables_mut()
    }

    /// `params`, of the kinds written as expressions.
    pub fn params(&self) -> Option<&BTreeMap<String, ParamValue>> {
        self.kind()?.params()
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
            return read_kind(name, &mut before, &mut map);
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
    fn every_kind_of_the_table_is_read_by_its_name() {
        let names: Vec<&str> = KNOWN_MODELS.split(", ").collect();
        assert_eq!(names.len(), 7, "{KNOWN_MODELS}");
        for name in names {
            let m = parse(&format!("[model]\nname = \"{name}\"\n")).unwrap();
            assert_eq!(m.name(), name);
            assert!(
                m.kind().is_some(),
                "{name} was read as a model built in code"
            );
            // What is written is read back as the same kind.
            let text = toml::to_string(&m).unwrap();
            assert_eq!(parse(&format!("[model]\n{text}")).unwrap(), m, "{text}");
        }
        assert!(ModelConfig::custom("barbanis").kind().is_none());
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
