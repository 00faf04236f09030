//! One-line descriptions of TOML errors that name the key.
//!
//! The toml crate renders an error as a five-line snippet with a caret, and names the key only
//! for unknown and missing fields, without its table. A user (and a script reading stderr) wants
//! one line: `integrator.h (line 13, column 5): invalid type: string "0.01", expected f64`.
//! The key path is read back from the document at the error's position: the enclosing
//! `[table]` or `[[array]]` header (array entries numbered from 0, as the validation errors
//! number them: `scheme[1].tau`), the key of the line, and the inner key of an inline table.

/// `err` of parsing `text`, as one line naming the key where one can be told.
pub(super) fn describe(text: &str, err: &toml::de::Error) -> String {
    let message = one_line(err.message());
    let Some(span) = err.span() else {
        return message;
    };
    let start = floor_char_boundary(text, span.start.min(text.len()));
    let line_start = text[..start].rfind('\n').map_or(0, |i| i + 1);
    let line_no = text[..start].matches('\n').count() + 1;
    let column = text[line_start..start].chars().count() + 1;
    let line_end = text[start..].find('\n').map_or(text.len(), |i| start + i);
    let line = &text[line_start..line_end];
    let field = quoted_field(&message);
    if let Some(field) = field
        && message.starts_with("missing field")
        && span.start == 0
        && DOCUMENT_TABLES.contains(&field)
    {
        // A table of the document itself: the error stands at the document's start, whose
        // first line (a comment, or the header of another table) says nothing about it.
        return format!("{field}: the [{field}] table is missing");
    }
    let key = key_path(&text[..line_start], line, start - line_start, field);
    let at = format!("line {line_no}, column {column}");
    let message = match (field.map(str::to_string), key.as_deref()) {
        (Some(field), Some(key)) if key == format!("model.{field}") => {
            with_model_kinds(message, &field)
        }
        _ => message,
    };
    match key {
        Some(key) => format!("{key} ({at}): {message}"),
        None => format!("{at}: {message}"),
    }
}

/// The tables of a configuration document (`RunConfig`'s fields), none of them a key of
/// another table.
const DOCUMENT_TABLES: [&str; 8] = [
    "run",
    "model",
    "orbit",
    "integrator",
    "deviations",
    "scheme",
    "sweep",
    "map",
];

/// An unknown `[model]` key that another kind of model reads: the message says which (a key
/// written under the wrong `name`, or a name written wrong).
fn with_model_kinds(message: String, field: &str) -> String {
    let kinds = super::ModelConfig::kinds_with_key(field);
    if kinds.is_empty() || !message.starts_with("unknown field") {
        return message;
    }
    let names: Vec<String> = kinds.iter().map(|k| format!("name = \"{k}\"")).collect();
    format!("{message}; `{field}` is a key of {}", names.join(", "))
}

/// The message on one line: lines joined with "; ", blank ones dropped.
fn one_line(message: &str) -> String {
    message
        .lines()
        .map(str::trim)
        .filter(|l| !l.is_empty())
        .collect::<Vec<_>>()
        .join("; ")
}

fn floor_char_boundary(text: &str, mut i: usize) -> usize {
    while !text.is_char_boundary(i) {
        i -= 1;
    }
    i
}

/// The field an "unknown field `x`" or "missing field `x`" message names.
fn quoted_field(message: &str) -> Option<&str> {
    let rest = message
        .strip_prefix("unknown field `")
        .or_else(|| message.strip_prefix("missing field `"))?;
    rest.split('`').next()
}

/// The table header a line declares: `[a.b]` gives ("a.b", false), `[[a]]` ("a", true).
fn header(line: &str) -> Option<(&str, bool)> {
    let l = line.trim();
    let l = l.split('#').next().unwrap_or("").trim_end();
    if let Some(inner) = l.strip_prefix("[[").and_then(|s| s.strip_suffix("]]")) {
        return Some((inner.trim(), true));
    }
    l.strip_prefix('[')
        .and_then(|s| s.strip_suffix(']'))
        .map(|inner| (inner.trim(), false))
}

/// The path of the table in force after the lines `before`, with array entries numbered.
fn table_path(before: &str, this_line: Option<(&str, bool)>) -> String {
    let mut counts: Vec<(String, usize)> = Vec::new();
    let mut current = String::new();
    for h in before.lines().filter_map(header).chain(this_line) {
        let (name, array) = h;
        current = if array {
            let n = match counts.iter_mut().find(|(k, _)| k == name) {
                Some((_, n)) => {
                    *n += 1;
                    *n
                }
                None => {
                    counts.push((name.to_string(), 0));
                    0
                }
            };
            format!("{name}[{n}]")
        } else {
            name.to_string()
        };
    }
    current
}

/// The key of `line` (`k = ...`), then the keys of the inline tables still open at byte `col`
/// (nested ones too: `params = { eps = { seed = 1, normal = 2 } }` gives `params`, `eps`), then
/// the key whose value is being written there, if any.
fn keys_before(line: &str, col: usize) -> Vec<&str> {
    let head = &line[..floor_char_boundary(line, col.min(line.len()))];
    let mut keys = Vec::new();
    let Some(first_eq) = line.find('=') else {
        return keys;
    };
    let own = line[..first_eq].trim().trim_matches('"');
    if !own.is_empty() {
        keys.push(own);
    }
    let rest = head.get(first_eq + 1..).unwrap_or("");
    // The keys of the open inline tables (an empty one for a table opened where no key was
    // pending, as the line's own value is), and the key of the latest `=` at the current depth.
    let mut open: Vec<&str> = Vec::new();
    let mut pending: Option<&str> = None;
    let mut in_string = false;
    for (i, c) in rest.char_indices() {
        match c {
            '"' => in_string = !in_string,
            _ if in_string => {}
            '=' => {
                let before = rest[..i].trim_end();
                // Past the last character that cannot be in a key (which may be several bytes).
                let start = before
                    .char_indices()
                    .rfind(|&(_, c)| !(c.is_ascii_alphanumeric() || c == '_' || c == '-'))
                    .map_or(0, |(i, c)| i + c.len_utf8());
                pending = Some(before[start..].trim_matches('"')).filter(|k| !k.is_empty());
            }
            '{' => open.push(pending.take().unwrap_or("")),
            '}' => {
                open.pop();
                pending = None;
            }
            ',' => pending = None,
            _ => {}
        }
    }
    keys.extend(open.into_iter().filter(|k| !k.is_empty()));
    keys.extend(pending);
    keys
}

fn join(table: &str, key: &str) -> String {
    if table.is_empty() {
        key.to_string()
    } else {
        format!("{table}.{key}")
    }
}

fn key_path(before: &str, line: &str, col: usize, field: Option<&str>) -> Option<String> {
    if let Some((name, array)) = header(line) {
        // An error at a header: the table itself is unknown (header paths are absolute), or one
        // of its keys is missing.
        let last = name.rsplit('.').next().unwrap_or(name);
        if field == Some(last) || field.is_none() {
            return Some(name.to_string());
        }
        let table = table_path(before, Some((name, array)));
        return field.map(|f| join(&table, f));
    }
    let table = table_path(before, None);
    let mut path = table.clone();
    for key in keys_before(line, col) {
        path = join(&path, key);
    }
    if let Some(f) = field
        && !path.ends_with(f)
    {
        path = join(&path, f);
    }
    (!path.is_empty()).then_some(path)
}

#[cfg(test)]
mod tests {
    use crate::config::RunConfig;

    const BASE: &str = "[model]\nname = \"henon-heiles\"\n\n[orbit]\nq = [0.0, -0.25]\n\
        p = [0.0, 0.0]\n\n[integrator]\nmethod = \"aba864\"\nh = 0.01\nt_final = 1.0\n\n\
        [deviations]\nk = 2\n\n[[scheme]]\nname = \"a\"\nmethod = \"vm\"\nd0 = 1e-8\ntau = 1.0\n\n\
        [[scheme]]\nname = \"b\"\nmethod = \"vm\"\nd0 = 1e-8\ntau = 1.0\n";

    fn error(from: &str, to: &str) -> String {
        assert!(BASE.contains(from), "{from}");
        RunConfig::from_toml(&BASE.replacen(from, to, 1))
            .unwrap_err()
            .0
    }

    #[test]
    fn errors_are_one_line_naming_the_key() {
        RunConfig::from_toml(BASE).unwrap();
        let cases = [
            (
                "h = 0.01",
                "h = \"x\"",
                "integrator.h (line 10, column 5): invalid type",
            ),
            (
                "t_final = 1.0\n",
                "",
                "integrator.t_final (line 8, column 1): missing field `t_final`",
            ),
            (
                "[orbit]\nq = [0.0, -0.25]\np = [0.0, 0.0]\n",
                "",
                "orbit: the [orbit] table is missing",
            ),
            ("k = 2", "k = -2", "deviations.k (line 14"),
            ("h = 0.01", "h = 0.01\ndt = 1", "integrator.dt (line 11"),
            ("[deviations]", "[output]\n[deviations]", "output (line 13"),
            (
                "tau = 1.0\n\n[[",
                "tau = 1.0\nx = 1\n\n[[",
                "scheme[0].x (line 21",
            ),
            (
                "\"b\"\nmethod = \"vm\"\nd0 = 1e-8",
                "\"b\"\nmethod = \"vm\"\nd0 = \"y\"",
                "scheme[1].d0 (line 25",
            ),
            ("q = [0.0, -0.25]", "q = [0.0, \"a\"]", "orbit.q (line 5"),
            ("h = 0.01", "h = 0.01\nh = 0.02", "integrator.h (line 11"),
            ("[model]", "[[model]]", "model (line 1"),
        ];
        for (from, to, want) in cases {
            let e = error(from, to);
            assert!(!e.contains('\n'), "{e}");
            assert!(e.starts_with(want), "{e:?} does not start with {want:?}");
        }
        // Multi-byte characters before a key or a value (found by fuzzing: a slice inside '充').
        for text in [
            "[model]\nname = { \"充\" = 1 }\n",
            "[model]\n\u{85}n = \"x\" = 2\n",
        ] {
            let e = RunConfig::from_toml(text).unwrap_err().0;
            assert!(!e.contains('\n'), "{e}");
        }
        let empty = RunConfig::from_toml("").unwrap_err().0;
        assert!(empty.starts_with("model"), "{empty}");
        let inline = RunConfig::from_toml(&format!(
            "{BASE}[map]\nx = {{ coord = \"q2\", min = 0.0, max = 1.0, n = -3 }}\n"
        ))
        .unwrap_err()
        .0;
        assert!(inline.starts_with("map.x.n (line"), "{inline}");
        // A key of another kind of model: named with its position and the kinds that read it.
        let foreign = error(
            "name = \"henon-heiles\"",
            "name = \"henon-heiles\"\nrhs = [\"x1\"]",
        );
        assert!(
            foreign.starts_with("model.rhs (line 3, column 1): unknown field `rhs`")
                && foreign.ends_with("`rhs` is a key of name = \"ode\""),
            "{foreign}"
        );
    }
}
