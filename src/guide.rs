//! The user guide (`docs/src/`), the README and CONTRIBUTING.md checked against the code, so
//! they cannot drift from it (test-only; `cargo test --release -p chaoscope --bin chaoscope
//! guide`):
//!
//! - every ```` ```toml ```` block is a whole configuration that validates as `chaoscope config`
//!   validates it; a block marked ```` ```toml,fragment ```` (keys from the root) or
//!   ```` ```toml,fragment=TABLE ```` (keys of that table) parses as TOML and names only keys
//!   the configuration's JSON Schema has; ```` ```toml,not-a-config ```` (another tool's file)
//!   parses as TOML;
//! - every `chaoscope ...` command line (or `cargo run --release -- ...`) in a ```` ```sh ````,
//!   ```` ```bash ```` or ```` ```console ```` block parses with the binary's own clap
//!   definition, without running anything;
//! - the configuration reference (`docs/src/reference.md`) names exactly the keys of the JSON
//!   Schema that `chaoscope config --schema` prints (generated from the types that parse
//!   configs);
//! - the test command is the same line in the README, the guide and `.ci/run`;
//! - every relative link and image points at a file that exists.

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};

use clap::Parser;
use serde_json::Value;

use crate::Cli;
use chaoscope_schemas::config::{RunConfig, parse_config_bytes};

/// The page of the guide that lists every configuration key.
const REFERENCE: &str = "docs/src/reference.md";

/// The first words of the README's test command (the line `.ci/run` runs verbatim).
const TEST_COMMAND_START: &str = "python3 -m pip install -r tests/python/requirements.txt";

fn root() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

/// README.md, CONTRIBUTING.md and every page under `docs/src/`, as (path from the root, text).
fn documents() -> Vec<(String, String)> {
    let mut paths = vec![PathBuf::from("README.md"), PathBuf::from("CONTRIBUTING.md")];
    let mut pages: Vec<PathBuf> = std::fs::read_dir(root().join("docs/src"))
        .expect("docs/src exists")
        .map(|e| e.expect("a readable entry").path())
        .filter(|p| p.extension().is_some_and(|e| e == "md"))
        .map(|p| p.strip_prefix(root()).unwrap().to_path_buf())
        .collect();
    pages.sort();
    paths.extend(pages);
    paths
        .into_iter()
        .map(|p| {
            let text = std::fs::read_to_string(root().join(&p))
                .unwrap_or_else(|e| panic!("{}: {e}", p.display()));
            (p.display().to_string(), text)
        })
        .collect()
}

/// A fenced code block: where it starts, its info string and its text (indentation of the
/// fence removed, as in a list item).
struct Block {
    place: String,
    info: String,
    text: String,
}

fn code_blocks(file: &str, text: &str) -> Vec<Block> {
    let mut blocks = Vec::new();
    let mut open: Option<(usize, String, usize, String, Vec<String>)> = None;
    for (n, line) in text.lines().enumerate() {
        let trimmed = line.trim_start();
        let indent = line.len() - trimmed.len();
        let ticks = trimmed.chars().take_while(|&c| c == '`').count();
        match &mut open {
            None => {
                // CommonMark: an opening fence's info string has no backtick (so an inline
                // ```` ```toml ```` at the start of a line is not a fence).
                let info = &trimmed[ticks..];
                if ticks >= 3 && !info.contains('`') {
                    open = Some((
                        n + 1,
                        info.trim().to_string(),
                        indent,
                        "`".repeat(ticks),
                        vec![],
                    ));
                }
            }
            Some((start, info, fence_indent, fence, lines)) => {
                if trimmed.starts_with(fence.as_str()) && trimmed.trim_end() == fence.as_str() {
                    blocks.push(Block {
                        place: format!("{file}:{start}"),
                        info: std::mem::take(info),
                        text: lines.join("\n"),
                    });
                    open = None;
                } else {
                    let cut = line
                        .char_indices()
                        .take_while(|&(i, c)| i < *fence_indent && c == ' ')
                        .count();
                    lines.push(line[cut..].to_string());
                }
            }
        }
    }
    assert!(open.is_none(), "{file}: a code block is never closed");
    blocks
}

/// Every key path of the configuration's JSON Schema: `integrator.h`, `scheme.tau` (arrays of
/// tables are transparent), `map.x.coord`, and `<name>` for a key the user names
/// (`model.params.<name>`, `model.tables.<name>.file`).
fn schema_key_paths() -> BTreeSet<String> {
    let schema = RunConfig::json_schema();
    let mut paths = BTreeSet::new();
    collect_paths(&schema, &schema, "", &mut paths, 0);
    paths
}

fn resolve<'a>(root: &'a Value, schema: &'a Value) -> &'a Value {
    match schema.get("$ref").and_then(Value::as_str) {
        Some(reference) => {
            let pointer = reference.strip_prefix('#').expect("a local $ref");
            resolve(root, root.pointer(pointer).expect("a $ref that resolves"))
        }
        None => schema,
    }
}

/// The schemas a value may match: through `$ref`, `anyOf`/`oneOf`/`allOf` (options, tagged
/// enums) and array `items`.
fn alternatives<'a>(root: &'a Value, schema: &'a Value, out: &mut Vec<&'a Value>) {
    let schema = resolve(root, schema);
    out.push(schema);
    for key in ["anyOf", "oneOf", "allOf"] {
        for sub in schema
            .get(key)
            .and_then(Value::as_array)
            .into_iter()
            .flatten()
        {
            alternatives(root, sub, out);
        }
    }
    if let Some(items) = schema.get("items").filter(|i| i.is_object()) {
        alternatives(root, items, out);
    }
}

fn collect_paths(
    root: &Value,
    schema: &Value,
    prefix: &str,
    out: &mut BTreeSet<String>,
    depth: usize,
) {
    assert!(
        depth < 16,
        "the configuration schema nests deeper than any config"
    );
    let mut options = Vec::new();
    alternatives(root, schema, &mut options);
    for option in options {
        let named = option
            .get("properties")
            .and_then(Value::as_object)
            .into_iter()
            .flatten()
            .map(|(name, sub)| (name.as_str(), sub));
        let user_named = option
            .get("additionalProperties")
            .filter(|a| a.is_object())
            .map(|sub| ("<name>", sub));
        for (name, sub) in named.chain(user_named) {
            let path = if prefix.is_empty() {
                name.to_string()
            } else {
                format!("{prefix}.{name}")
            };
            collect_paths(root, sub, &path, out, depth + 1);
            out.insert(path);
        }
    }
}

/// The key paths of a TOML fragment rooted at `prefix`, each mapped to the schema's path
/// (`model.params.beta` is `model.params.<name>`); keys the schema lacks go to `unknown`.
fn fragment_paths(
    table: &toml::Table,
    prefix: &str,
    schema: &BTreeSet<String>,
    found: &mut usize,
    unknown: &mut Vec<String>,
) {
    for (key, value) in table {
        let join = |k: &str| {
            if prefix.is_empty() {
                k.to_string()
            } else {
                format!("{prefix}.{k}")
            }
        };
        let path = [join(key), join("<name>")]
            .into_iter()
            .find(|p| schema.contains(p));
        let Some(path) = path else {
            unknown.push(join(key));
            continue;
        };
        *found += 1;
        match value {
            toml::Value::Table(t) => fragment_paths(t, &path, schema, found, unknown),
            toml::Value::Array(items) => {
                for item in items {
                    if let toml::Value::Table(t) = item {
                        fragment_paths(t, &path, schema, found, unknown);
                    }
                }
            }
            _ => {}
        }
    }
}

#[test]
fn toml_examples_are_valid_configurations() {
    let schema = schema_key_paths();
    let machine = chaoscope_dynamics::estimate::Machine::this_host();
    // A whole example resolves relative table files as a config in examples/models/ would.
    let base = root().join("examples/models/guide-example.toml");
    let (mut whole, mut fragments, mut keys, mut failures) = (0, 0, 0, Vec::new());
    for (file, text) in documents() {
        for block in code_blocks(&file, &text) {
            let mut parts = block.info.split(',');
            if parts.next() != Some("toml") {
                continue;
            }
            let marker = parts.next();
            let result: Result<(), String> = match marker {
                None => {
                    whole += 1;
                    parse_config_bytes(&block.place, block.text.clone().into_bytes(), &base)
                        .map_err(|e| e.to_string())
                        .and_then(|config| {
                            crate::cli::config::validate(&config, None, &machine)
                                .map(|_| ())
                                .map_err(|e| format!("{e:#}"))
                        })
                }
                Some(m) if m == "fragment" || m.starts_with("fragment=") => {
                    fragments += 1;
                    let prefix = m.strip_prefix("fragment=").unwrap_or("");
                    match block.text.parse::<toml::Table>() {
                        Err(e) => Err(format!("not TOML: {e}")),
                        Ok(table) => {
                            let mut unknown = Vec::new();
                            fragment_paths(&table, prefix, &schema, &mut keys, &mut unknown);
                            if unknown.is_empty() {
                                Ok(())
                            } else {
                                Err(format!("keys the schema lacks: {}", unknown.join(", ")))
                            }
                        }
                    }
                }
                Some("not-a-config") => block
                    .text
                    .parse::<toml::Table>()
                    .map(|_| ())
                    .map_err(|e| format!("not TOML: {e}")),
                Some(other) => Err(format!(
                    "unknown marker toml,{other}: a toml block is a whole configuration, \
                     toml,fragment[=TABLE] or toml,not-a-config"
                )),
            };
            if let Err(e) = result {
                failures.push(format!("{}: {e}", block.place));
            }
        }
    }
    eprintln!("{whole} whole configurations, {fragments} fragments ({keys} keys) checked");
    assert!(
        failures.is_empty(),
        "{} TOML examples fail:\n{}",
        failures.len(),
        failures.join("\n")
    );
    // The guide has examples of every kind of model, a map and a sweep: fewer means the
    // blocks were not found, not that they pass.
    assert!(
        whole >= 3 && fragments >= 10 && keys >= 60,
        "{whole} {fragments} {keys}"
    );
}

/// The command lines of a shell block: continuation lines joined, a console's prompt removed
/// (its other lines are output).
fn shell_lines(info: &str, text: &str) -> Vec<String> {
    let joined = text.replace("\\\n", " ");
    joined
        .lines()
        .filter_map(|line| {
            if info == "console" {
                line.strip_prefix("$ ").map(str::to_string)
            } else {
                Some(line.to_string())
            }
        })
        .collect()
}

/// The argv of every `chaoscope` command in a shell line (split at `&&`, `||`, `;`, `|`, cut
/// at a redirection), `cargo run ... -- ARGS` taken as `chaoscope ARGS`.
fn chaoscope_commands(line: &str) -> Result<Vec<Vec<String>>, String> {
    let words = shlex::split(line).ok_or_else(|| format!("unbalanced quotes in {line:?}"))?;
    let mut commands = Vec::new();
    for segment in words.split(|w| ["&&", "||", ";", "|", "&"].contains(&w.as_str())) {
        let end = segment
            .iter()
            .position(|w| w.starts_with('>') || w.starts_with('<') || w.starts_with("2>"))
            .unwrap_or(segment.len());
        let segment = &segment[..end];
        match segment.first().map(String::as_str) {
            Some("chaoscope") => commands.push(segment.to_vec()),
            Some("cargo") if segment.get(1).is_some_and(|w| w == "run") => {
                if let Some(dashes) = segment.iter().position(|w| w == "--") {
                    let mut argv = vec!["chaoscope".to_string()];
                    argv.extend(segment[dashes + 1..].iter().cloned());
                    commands.push(argv);
                }
            }
            _ => {}
        }
    }
    Ok(commands)
}

#[test]
fn command_examples_parse_with_the_real_command_line() {
    let (mut parsed, mut failures) = (0, Vec::new());
    for (file, text) in documents() {
        for block in code_blocks(&file, &text) {
            if !["sh", "bash", "console", "shell"].contains(&block.info.as_str()) {
                continue;
            }
            for line in shell_lines(&block.info, &block.text) {
                let commands = match chaoscope_commands(&line) {
                    Ok(c) => c,
                    Err(e) => {
                        failures.push(format!("{}: {e}", block.place));
                        continue;
                    }
                };
                for argv in commands {
                    parsed += 1;
                    if let Err(e) = Cli::try_parse_from(&argv) {
                        use clap::error::ErrorKind;
                        if !matches!(e.kind(), ErrorKind::DisplayHelp | ErrorKind::DisplayVersion) {
                            let first = e.to_string().lines().next().unwrap_or("").to_string();
                            failures.push(format!(
                                "{}: `{}`: {first}",
                                block.place,
                                argv.join(" ")
                            ));
                        }
                    }
                }
            }
        }
    }
    eprintln!("{parsed} chaoscope command lines parsed");
    assert!(
        failures.is_empty(),
        "{} command examples do not parse:\n{}",
        failures.len(),
        failures.join("\n")
    );
    assert!(parsed >= 15, "only {parsed} command lines found");
}

/// The keys a table row of the reference documents: the code span of its first cell, when it
/// is a key path (`integrator.h`).
fn reference_key_paths(text: &str, tables: &BTreeSet<String>) -> BTreeSet<String> {
    text.lines()
        .filter_map(|line| line.strip_prefix("| `"))
        .filter_map(|rest| rest.split('`').next())
        .filter(|key| {
            key.split_once('.')
                .is_some_and(|(table, _)| tables.contains(table))
        })
        .map(str::to_string)
        .collect()
}

#[test]
fn reference_names_every_configuration_key_and_no_other() {
    let schema = schema_key_paths();
    let (tables, keys): (BTreeSet<String>, BTreeSet<String>) =
        schema.iter().cloned().partition(|p| !p.contains('.'));
    let text = std::fs::read_to_string(root().join(REFERENCE)).unwrap();
    let documented = reference_key_paths(&text, &tables);
    let missing: Vec<_> = keys.difference(&documented).collect();
    let unknown: Vec<_> = documented.difference(&keys).collect();
    eprintln!(
        "{} keys in the schema, {} in {REFERENCE}",
        keys.len(),
        documented.len()
    );
    assert!(
        missing.is_empty(),
        "{REFERENCE} does not document these keys of the configuration: {missing:?}"
    );
    assert!(
        unknown.is_empty(),
        "{REFERENCE} documents keys no configuration has: {unknown:?}"
    );
    // Every table of a config and more keys than the five tables alone have.
    assert!(
        tables.len() >= 8 && keys.len() >= 50,
        "{tables:?} {}",
        keys.len()
    );
}

#[test]
fn the_test_command_is_the_same_line_everywhere() {
    // `.ci/run` runs the README's test command verbatim; the guide and CONTRIBUTING.md quote it.
    let docs = documents();
    let readme = &docs[0].1;
    let line = readme
        .lines()
        .find(|l| l.starts_with(TEST_COMMAND_START))
        .expect("the README has the test command");
    let ci = std::fs::read_to_string(root().join(".ci/run")).unwrap();
    assert!(
        ci.lines().any(|l| l.trim() == line),
        ".ci/run does not run the README's test command {line:?}"
    );
    for (file, text) in &docs {
        for other in text.lines().filter(|l| l.starts_with(TEST_COMMAND_START)) {
            assert_eq!(other, line, "{file} quotes another test command");
        }
    }
    // And the README keeps the line that runs the built-in default.
    assert!(readme.lines().any(|l| l == "cargo run --release -- run"));
}

#[test]
fn relative_links_point_at_files_that_exist() {
    let (mut checked, mut broken) = (0, Vec::new());
    for (file, text) in documents() {
        let dir = root().join(&file);
        let dir = dir.parent().unwrap();
        for (n, line) in text.lines().enumerate() {
            for piece in line.split("](").skip(1) {
                let Some(target) = piece.split(')').next() else {
                    continue;
                };
                let target = target.split('#').next().unwrap_or("");
                if target.is_empty() || target.contains("://") || target.starts_with("mailto:") {
                    continue;
                }
                checked += 1;
                if !dir.join(target).exists() {
                    broken.push(format!("{file}:{}: {target}", n + 1));
                }
            }
        }
    }
    assert!(checked >= 40, "only {checked} links found");
    assert!(broken.is_empty(), "broken links:\n{}", broken.join("\n"));
}
