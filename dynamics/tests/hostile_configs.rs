//! Every config a user can write either validates or is refused with an error naming a key; a
//! validated run either completes or stops with a run error. Nothing panics, nothing aborts.
//!
//! Mutations: each numeric value of a valid config replaced in turn by hostile numbers, each
//! string by a wrong word, plus hand-written absurd sizes.

use chaoscope_dynamics::engine::Engine;
use chaoscope_dynamics::spec::RunSpec;
use chaoscope_schemas::config::RunConfig;

const BASE: &str = r#"
[model]
name = "fput-beta"
n = 3
beta = 1.0
[orbit]
q = [0.1, -0.2, 0.3]
p = [0.0, 0.1, 0.0]
energy = 0.5
solve_for = "p1"
[integrator]
method = "aba864"
h = 0.05
t_final = 2.0
[deviations]
k = 4
sets = 2
seed = 3
[[scheme]]
name = "a"
method = "vm"
d0 = 1e-8
tau = 0.5
orthonormalize = "qr"
[[scheme]]
name = "b"
method = "mpm"
d0 = 1e-6
tau = 1.0
"#;

const HOSTILE_NUMBERS: [&str; 12] = [
    "0",
    "-1",
    "1e308",
    "-1e308",
    "nan",
    "inf",
    "-inf",
    "1e-320",
    "3.5",
    "18446744073709551615",
    "2",
    "1e6",
];

/// Validate and, if valid, run a few samples; panics only if the code under test panics.
fn exercise(text: &str) -> Result<(), String> {
    let cfg = RunConfig::from_toml(text).map_err(|e| e.to_string())?;
    let spec = RunSpec::from_config(&cfg).map_err(|e| {
        assert!(
            !e.key.is_empty() && !e.message.is_empty(),
            "error without key or message"
        );
        e.to_string()
    })?;
    let mut engine = Engine::new(spec);
    for _ in 0..6 {
        match engine.next_sample() {
            Ok(Some(s)) => {
                assert!(
                    s.state.iter().all(|v| v.is_finite()),
                    "non-finite state in a sample"
                );
                assert!(
                    s.schemes
                        .iter()
                        .all(|d| d.stretch.iter().all(|v| v.is_finite() && *v >= 0.0))
                );
            }
            Ok(None) => break,
            Err(e) => return Err(e.to_string()),
        }
    }
    Ok(())
}

#[test]
fn base_config_is_valid() {
    exercise(BASE).unwrap();
}

#[test]
fn every_numeric_value_replaced_by_hostile_numbers() {
    let (ran, refused) = mutate_numbers(BASE);
    eprintln!("{ran} mutated configs ran, {refused} were refused with an error");
    assert!(refused > 50 && ran > 20);
}

/// Every number of `base` replaced in turn by each hostile number, validated and, if valid, run
/// a few samples: `(ran, refused)`.
fn mutate_numbers(base: &str) -> (usize, usize) {
    // Positions of every number in the document (keys' values and array entries).
    let bytes = base.as_bytes();
    let mut spans = Vec::new();
    let mut i = 0;
    while i < bytes.len() {
        let starts = bytes[i].is_ascii_digit()
            || (bytes[i] == b'-' && bytes.get(i + 1).is_some_and(u8::is_ascii_digit));
        let after_word = i > 0 && (bytes[i - 1].is_ascii_alphanumeric() || bytes[i - 1] == b'_');
        if starts && !after_word {
            let j = i + base[i..]
                .find(|c: char| !(c.is_ascii_alphanumeric() || "-+.".contains(c)))
                .unwrap();
            spans.push((i, j));
            i = j;
        } else {
            i += 1;
        }
    }
    assert!(spans.len() > 15, "found {} numbers", spans.len());
    let (mut refused, mut ran) = (0, 0);
    for (a, b) in spans {
        for v in HOSTILE_NUMBERS {
            let text = format!("{}{}{}", &base[..a], v, &base[b..]);
            match exercise(&text) {
                Ok(()) => ran += 1,
                Err(_) => refused += 1,
            }
        }
    }
    (ran, refused)
}

/// A DDNLS on a 3 x 3 square lattice, a 2 x 2 block excited by its norm.
const DDNLS: &str = r#"
[model]
name = "ddnls"
lattice = "square"
n = 3
W = 4.0
beta = 1.0
seed = 2
[orbit]
excite = { sites = [1, 2], norm = 2.0, seed = 5 }
[integrator]
method = "s9abc6"
h = 0.05
t_final = 1.0
[deviations]
k = 4
sets = 2
seed = 3
[[scheme]]
name = "a"
method = "vm"
d0 = 1e-8
tau = 0.5
orthonormalize = "qr"
[[scheme]]
name = "b"
method = "mpm"
d0 = 1e-6
tau = 1.0
"#;

/// The DDNLS's numbers (sizes, W, beta, seeds, the excitation's sites and norm) replaced by
/// hostile ones, as the FPUT config's: each refused naming a key, or run without a panic or a
/// non-finite sample; its wrong words and impossible excitations refused by key.
#[test]
fn hostile_ddnls_configs_are_refused_by_key_or_run() {
    exercise(DDNLS).unwrap();
    let (ran, refused) = mutate_numbers(DDNLS);
    eprintln!("ddnls: {ran} mutated configs ran, {refused} were refused with an error");
    assert!(refused > 50 && ran > 20);
    let cases = [
        (
            "lattice = \"square\"",
            "lattice = \"cube\"",
            "model.lattice",
        ),
        (
            "method = \"s9abc6\"",
            "method = \"abc3\"",
            "integrator.method",
        ),
        ("n = 3", "n = 0", "model.n"),
        ("n = 3", "n = 100000", "model.n"),
        ("W = 4.0", "W = -1.0", "model.W"),
        ("W = 4.0", "W = nan", "model.W"),
        ("beta = 1.0", "beta = inf", "model.beta"),
        ("seed = 2\n", "\n", "model.seed"),
        ("sites = [1, 2]", "sites = [2, 4]", "orbit.excite.sites"),
        ("norm = 2.0", "norm = 0.0", "orbit.excite.norm"),
        (
            "norm = 2.0",
            "norm = 2.0, energy = 1.0",
            "orbit.excite.energy",
        ),
        ("norm = 2.0", "energy = -1e300", "orbit.excite.energy"),
        (
            "excite = { sites = [1, 2], norm = 2.0, seed = 5 }",
            "q = [0.0, 1.0]\np = [0.0, 1.0]",
            "orbit.q",
        ),
        (
            "h = 0.05",
            "h = 0.05\nrtol = 1e-9\natol = 1e-9",
            "integrator.rtol",
        ),
    ];
    for (from, to, key) in cases {
        let text = DDNLS.replacen(from, to, 1);
        let cfg = RunConfig::from_toml(&text).unwrap();
        let err = RunSpec::from_config(&cfg).unwrap_err();
        assert_eq!(err.key, key, "{to}: {err}");
        assert!(!err.message.contains('\n'), "{to}: {err}");
    }
    // An energy whose norm is past the limit says so (it was "no excitation has energy 1e308").
    let text = DDNLS.replacen("norm = 2.0", "energy = 1e308", 1);
    let err = RunSpec::from_config(&RunConfig::from_toml(&text).unwrap()).unwrap_err();
    assert!(err.message.contains("needs a norm beyond 1e150"), "{err}");
    // A key of another kind is refused by the parser, naming it.
    let e = RunConfig::from_toml(&DDNLS.replace("seed = 2", "seed = 2\npotential = \"q1\""))
        .unwrap_err()
        .to_string();
    assert!(e.contains("potential"), "{e}");
}

#[test]
fn wrong_words_and_absurd_sizes_are_refused_by_key() {
    let cases = [
        ("name = \"fput-beta\"", "name = \"fput\"", "model.name"),
        (
            "method = \"aba864\"",
            "method = \"euler\"",
            "integrator.method",
        ),
        (
            "solve_for = \"p1\"",
            "solve_for = \"p9\"",
            "orbit.solve_for",
        ),
        (
            "orthonormalize = \"qr\"",
            "orthonormalize = \"gram\"",
            "scheme[0].orthonormalize",
        ),
        ("n = 3", "n = 0", "model.n"),
        ("sets = 2", "sets = 1000001", "deviations.sets"),
        ("energy = 0.5", "energy = -5.0", "orbit.energy"),
        ("q = [0.1, -0.2, 0.3]", "q = [0.1, -0.2]", "orbit.q"),
    ];
    for (from, to, key) in cases {
        let text = BASE.replace(from, to);
        let cfg = RunConfig::from_toml(&text).unwrap();
        let err = RunSpec::from_config(&cfg).unwrap_err();
        assert_eq!(err.key, key, "{to}: {err}");
    }
    // A long chain with a million sets: refused for its size, before any allocation.
    let huge = BASE
        .replace("n = 3", "n = 100000")
        .replace("sets = 2", "sets = 100000");
    let text = huge
        .replace(
            "q = [0.1, -0.2, 0.3]\np = [0.0, 0.1, 0.0]\nenergy = 0.5\nsolve_for = \"p1\"",
            "preset = \"spo1\"\nenergy = 1.0",
        )
        .replace("n = 100000", "n = 100001");
    let err = RunSpec::from_config(&RunConfig::from_toml(&text).unwrap()).unwrap_err();
    assert!(err.message.contains("GiB"), "{err}");
    // Unknown keys and wrong types are refused by the parser, naming the key.
    assert!(
        RunConfig::from_toml(&BASE.replace("seed = 3", "sead = 3"))
            .unwrap_err()
            .to_string()
            .contains("sead")
    );
    assert!(RunConfig::from_toml(&BASE.replace("k = 4", "k = \"four\"")).is_err());
}
