//! Source text to tokens.

use crate::error::{ExprError, Span};
use crate::graph::Cmp;

#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Tok {
    Num(f64),
    Ident,
    Plus,
    Minus,
    Star,
    Slash,
    /// `^` or `**`.
    Caret,
    LParen,
    RParen,
    LBracket,
    RBracket,
    Comma,
    /// `=` (only in `sum(i = a..b, ...)`).
    Assign,
    /// `..` (only in `sum(i = a..b, ...)`).
    DotDot,
    Cmp(Cmp),
    Eof,
}

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Token {
    pub tok: Tok,
    pub span: Span,
}

/// The operators and punctuation, each a fixed text; where one is a prefix of another, the
/// longer comes first (`**` before `*`, `<=` before `<`).
const PUNCTUATION: &[(&str, Tok)] = &[
    ("..", Tok::DotDot),
    ("+", Tok::Plus),
    ("-", Tok::Minus),
    ("**", Tok::Caret),
    ("*", Tok::Star),
    ("/", Tok::Slash),
    ("^", Tok::Caret),
    ("(", Tok::LParen),
    (")", Tok::RParen),
    ("[", Tok::LBracket),
    ("]", Tok::RBracket),
    (",", Tok::Comma),
    ("<=", Tok::Cmp(Cmp::Le)),
    ("<", Tok::Cmp(Cmp::Lt)),
    (">=", Tok::Cmp(Cmp::Ge)),
    (">", Tok::Cmp(Cmp::Gt)),
    ("=", Tok::Assign),
];

/// All tokens of `src`, ending with [`Tok::Eof`] (whose span is the empty span at the end).
pub fn lex(src: &str) -> Result<Vec<Token>, ExprError> {
    let b = src.as_bytes();
    let at = |k: usize| b.get(k).copied().unwrap_or(0);
    let mut out = Vec::new();
    let mut i = 0;
    while i < b.len() {
        let start = i;
        let tok = match b[i] {
            b' ' | b'\t' | b'\n' | b'\r' => {
                i += 1;
                continue;
            }
            c if c.is_ascii_digit() || (c == b'.' && at(i + 1).is_ascii_digit()) => {
                let (v, end) = number(src, i)?;
                i = end;
                Tok::Num(v)
            }
            c if c.is_ascii_alphabetic() || c == b'_' => {
                while at(i).is_ascii_alphanumeric() || at(i) == b'_' {
                    i += 1;
                }
                Tok::Ident
            }
            b'=' | b'!' if at(i + 1) == b'=' => {
                return Err(ExprError::new(
                    src,
                    Span::new(i, i + 2),
                    format!(
                        "'{}' is not supported: conditions of if compare with <, <=, > or >=",
                        &src[i..i + 2]
                    ),
                ));
            }
            _ => match PUNCTUATION
                .iter()
                .find(|(text, _)| b[i..].starts_with(text.as_bytes()))
            {
                Some(&(text, tok)) => {
                    i += text.len();
                    tok
                }
                None => {
                    let c = src[i..].chars().next().unwrap_or('?');
                    // Other whitespace (a no-break space pasted from a paper or a web page).
                    if c.is_whitespace() {
                        i += c.len_utf8();
                        continue;
                    }
                    let what = if c == '.' {
                        "unexpected '.' (a number needs a digit after its decimal point, a range is a..b)"
                            .to_string()
                    } else {
                        format!("unexpected character '{c}'")
                    };
                    return Err(ExprError::new(src, Span::new(i, i + c.len_utf8()), what));
                }
            },
        };
        out.push(Token {
            tok,
            span: Span::new(start, i),
        });
    }
    out.push(Token {
        tok: Tok::Eof,
        span: Span::new(src.len(), src.len()),
    });
    Ok(out)
}

/// The number starting at `start`: `digits [. digits] [(e|E) [+|-] digits]`, or `. digits ...`.
/// A `.` followed by another `.` is not part of the number, so `1..N` is `1`, `..`, `N`.
fn number(src: &str, start: usize) -> Result<(f64, usize), ExprError> {
    let b = src.as_bytes();
    let at = |k: usize| b.get(k).copied().unwrap_or(0);
    let mut i = start;
    while at(i).is_ascii_digit() {
        i += 1;
    }
    if at(i) == b'.' && at(i + 1) != b'.' {
        i += 1;
        while at(i).is_ascii_digit() {
            i += 1;
        }
    }
    let mut exponent_ok = true;
    if matches!(at(i), b'e' | b'E') {
        i += 1;
        if matches!(at(i), b'+' | b'-') {
            i += 1;
        }
        exponent_ok = at(i).is_ascii_digit();
        while at(i).is_ascii_digit() {
            i += 1;
        }
    }
    // A letter, digit or a second decimal point right after the number: report the whole run
    // as one bad number (`2x`, `1.5.2`) rather than as a confusing second token.
    let glued = |c: u8| c.is_ascii_alphanumeric() || c == b'_' || c == b'.';
    let mut end = i;
    while glued(at(end)) && !(at(end) == b'.' && at(end + 1) == b'.') {
        end += 1;
    }
    let text = &src[start..end];
    let bad = |msg: String| Err(ExprError::new(src, Span::new(start, end), msg));
    if end > i {
        let rest = &src[i..end];
        if rest.starts_with(|c: char| c.is_ascii_alphabetic() || c == '_') && exponent_ok {
            return bad(format!(
                "bad number '{text}' (for a product write {}*{rest})",
                &src[start..i]
            ));
        }
        return bad(format!("bad number '{text}'"));
    }
    if !exponent_ok {
        return bad(format!("bad number '{text}': the exponent has no digits"));
    }
    match text.parse::<f64>() {
        Ok(v) if v.is_finite() => Ok((v, i)),
        Ok(_) => bad(format!("number '{text}' is too large for a 64-bit float")),
        Err(_) => bad(format!("bad number '{text}'")),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn toks(s: &str) -> Vec<Tok> {
        lex(s).unwrap().into_iter().map(|t| t.tok).collect()
    }

    #[test]
    fn numbers_and_ranges() {
        for (s, v) in [
            ("1", 1.0),
            ("1.5", 1.5),
            ("1e-3", 1e-3),
            (".5", 0.5),
            ("2.5E+3", 2500.0),
            ("3.", 3.0),
        ] {
            assert_eq!(toks(s), vec![Tok::Num(v), Tok::Eof], "{s}");
        }
        assert_eq!(
            toks("0..N"),
            vec![Tok::Num(0.0), Tok::DotDot, Tok::Ident, Tok::Eof]
        );
        assert_eq!(
            toks("a**2^3"),
            vec![
                Tok::Ident,
                Tok::Caret,
                Tok::Num(2.0),
                Tok::Caret,
                Tok::Num(3.0),
                Tok::Eof
            ]
        );
    }

    #[test]
    fn bad_numbers() {
        for (s, msg) in [
            ("1e", "exponent has no digits"),
            ("2x", "for a product write 2*x"),
            ("1.5.2", "bad number '1.5.2'"),
            ("1e999", "too large"),
            ("q1 + 3$", "unexpected character '$'"),
            ("a == b", "'==' is not supported"),
        ] {
            let e = lex(s).unwrap_err();
            assert!(e.message.contains(msg), "{s}: {}", e.message);
        }
        assert_eq!(
            toks("a\u{a0}+\tb"),
            vec![Tok::Ident, Tok::Plus, Tok::Ident, Tok::Eof]
        );
        let e = lex("1 + 2x").unwrap_err();
        assert_eq!((e.column, e.span), (5, Span::new(4, 6)));
    }
}
