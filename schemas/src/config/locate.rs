//! Where a key named by a validation error is written in the config's text.
//!
//! The validation works on the parsed config and names keys as paths (`model.rhs`,
//! `integrator.h`, `scheme[1].tau`, `deviations.vectors[2]`); a user wants the line too, as a
//! TOML error gives it. The text is parsed once more with the TOML parser's spans
//! (`toml::de::DeTable`, the parser `toml` itself uses) and the path walked down to its last
//! part that is written: a key the user left out (its default applied) is located at its
//! table, and a key the file does not hold at all (a scheme expanded from a `[[sweep]]`) has
//! no position.

use std::ops::Range;

use toml::de::{DeTable, DeValue};

/// The 1-based line and column of the key `path` in `text`, or of the nearest enclosing table
/// written in it; `None` when not even that is written (or the text does not parse).
pub fn key_position(text: &str, path: &str) -> Option<(usize, usize)> {
    let span = key_span(text, path)?;
    let start = span.start.min(text.len());
    let start = (0..=start).rev().find(|&i| text.is_char_boundary(i))?;
    let line_start = text[..start].rfind('\n').map_or(0, |i| i + 1);
    let line = text[..start].matches('\n').count() + 1;
    let before = &text[line_start..start];
    // A table located at its `[name]` header is placed at the header, as a TOML error is.
    let column = if before.trim_start().starts_with('[') {
        before.len() - before.trim_start().len() + 1
    } else {
        before.chars().count() + 1
    };
    Some((line, column))
}

/// `message` about the key `path` of the config `text`, in the form of a TOML error:
/// `model.rhs (line 7, column 1): message`, or `model.rhs: message` where it cannot be located.
pub fn describe_key(text: &str, path: &str, message: &str) -> String {
    match key_position(text, path) {
        Some((line, column)) => format!("{path} (line {line}, column {column}): {message}"),
        None => format!("{path}: {message}"),
    }
}

/// The span of the deepest part of `path` written in `text`.
fn key_span(text: &str, path: &str) -> Option<Range<usize>> {
    let document = DeTable::parse(text).ok()?;
    let mut table: Option<&DeTable> = Some(document.get_ref());
    let mut value: Option<&DeValue> = None;
    let mut found = None;
    for part in path.split('.') {
        let (name, indices) = split_indices(part)?;
        if !name.is_empty() {
            // A key of the current table (or of an inline table value).
            let current = table.or(match value {
                Some(DeValue::Table(t)) => Some(t),
                _ => None,
            })?;
            let Some((key, v)) = current.iter().find(|(k, _)| k.get_ref().as_ref() == name) else {
                break;
            };
            found = Some(key.span());
            value = Some(v.get_ref());
            table = None;
        }
        let mut complete = true;
        for index in indices {
            let Some(DeValue::Array(items)) = value else {
                complete = false;
                break;
            };
            let Some(item) = items.get(index) else {
                complete = false;
                break;
            };
            value = Some(item.get_ref());
            // An entry of an array of tables is located at its own `[[name]]` header (its
            // span), an entry of an inline array at its value.
            found = Some(item.span());
        }
        if !complete {
            // `scheme[3]` of a config with two `[[scheme]]` (the rest came from sweeps) is not
            // written, and the array's first header would point at the wrong entry; an entry
            // past the end of an inline array is located at its key.
            let of_tables = matches!(value, Some(DeValue::Array(items))
                if items.iter().all(|i| matches!(i.get_ref(), DeValue::Table(_))));
            return if of_tables { None } else { found };
        }
    }
    found
}

/// `scheme[1]` into ("scheme", [1]); `vectors[2][0]` into ("vectors", [2, 0]).
fn split_indices(part: &str) -> Option<(&str, Vec<usize>)> {
    let Some(open) = part.find('[') else {
        return Some((part, Vec::new()));
    };
    let mut indices = Vec::new();
    let mut rest = &part[open..];
    while let Some(inner) = rest.strip_prefix('[') {
        let close = inner.find(']')?;
        indices.push(inner[..close].parse().ok()?);
        rest = &inner[close + 1..];
    }
    rest.is_empty().then_some((&part[..open], indices))
}

#[cfg(test)]
mod tests {
    use super::{describe_key, key_position};

    const TEXT: &str = "[model]\nname = \"ode\"\nrhs = [\"x2\", \"-x1\"]\nparams = { a = 1.0 }\n\n\
        [integrator]\nmethod = \"rk4\"\nh = 0.01\nt_final = 1.0\n\n[deviations]\nk = 2\n\
        vectors = [[1.0, 0.0], [0.0, 1.0]]\n\n[[scheme]]\nname = \"a\"\ntau = 1.0\n\n\
        [[scheme]]\nname = \"b\"\n  tau = 2.0\n";

    #[test]
    fn keys_are_located_at_their_line_and_column() {
        let cases = [
            ("model.rhs", Some((3, 1))),
            ("model.params.a", Some((4, 12))),
            ("integrator.h", Some((8, 1))),
            ("deviations.vectors[1]", Some((13, 24))),
            ("scheme[1].tau", Some((21, 3))),
            // Left out: its table.
            ("integrator.rtol", Some((6, 1))),
            ("model.params.b", Some((4, 1))),
            ("scheme[1].d0", Some((19, 1))),
            ("model", Some((1, 1))),
            // Not written at all (a scheme from a sweep), or no such table.
            ("scheme[2].tau", None),
            ("map.x", None),
        ];
        for (path, want) in cases {
            assert_eq!(key_position(TEXT, path), want, "{path}");
        }
        assert_eq!(
            describe_key(TEXT, "model.rhs", "bad"),
            "model.rhs (line 3, column 1): bad"
        );
        assert_eq!(describe_key(TEXT, "map.x", "bad"), "map.x: bad");
        // Text that does not parse, and paths no key can have: no position, no panic.
        assert_eq!(key_position("[model\n", "model"), None);
        for path in [
            "",
            "a[",
            "a[x]",
            "a]b",
            "scheme[99999999999999999999]",
            "...",
        ] {
            let _ = key_position(TEXT, path);
        }
    }
}
