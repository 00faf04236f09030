//! Errors of the expression language, pointing into the source text.
//!
//! A researcher reads these in a terminal after a run refused to start, often with the
//! expression inside a multi-line TOML string, so every error carries the line and column (in
//! characters, 1-based) and the offending source line with a caret under the span. The first
//! line of the message is self-contained, for logs that keep one line per error.

use std::fmt;

/// A byte range `start..end` of the source text.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub struct Span {
    pub start: usize,
    pub end: usize,
}

impl Span {
    pub fn new(start: usize, end: usize) -> Self {
        Self { start, end }
    }

    /// The smallest span covering both.
    pub fn to(self, other: Span) -> Span {
        Span::new(self.start.min(other.start), self.end.max(other.end))
    }
}

/// An error at a place in the source.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ExprError {
    pub message: String,
    pub span: Span,
    /// 1-based line of `span.start`.
    pub line: usize,
    /// 1-based column of `span.start`, counted in characters (not bytes).
    pub column: usize,
    /// The whole line holding `span.start`, without its line break.
    pub source_line: String,
}

/// Line (1-based), column (1-based, in characters), the line's text and the byte offset where
/// the line starts, for byte `offset` of `source` (clamped to the source and to a char
/// boundary, so any offset is safe).
pub(crate) fn locate(source: &str, offset: usize) -> (usize, usize, &str, usize) {
    let mut offset = offset.min(source.len());
    while !source.is_char_boundary(offset) {
        offset -= 1;
    }
    let line_start = source[..offset].rfind('\n').map_or(0, |k| k + 1);
    let line_end = source[offset..]
        .find('\n')
        .map_or(source.len(), |k| offset + k);
    let text = source[line_start..line_end]
        .strip_suffix('\r')
        .unwrap_or(&source[line_start..line_end]);
    let line = source[..line_start].matches('\n').count() + 1;
    let column = source[line_start..offset].chars().count() + 1;
    (line, column, text, line_start)
}

impl ExprError {
    /// An error at `span` of `source` with `message`.
    pub fn new(source: &str, span: Span, message: impl Into<String>) -> Self {
        let (line, column, text, _) = locate(source, span.start);
        Self {
            message: message.into(),
            span,
            line,
            column,
            source_line: text.to_string(),
        }
    }

    /// The first line of the message only: `line 1, column 12: unknown function 'sinn' ...`.
    pub fn one_line(&self) -> String {
        format!(
            "line {}, column {}: {}",
            self.line, self.column, self.message
        )
    }

    /// The caret line under the span: spaces (tabs where the source line has tabs, so the
    /// carets line up in a terminal) up to the column, then one `^` per character of the
    /// span on this line (at least one, so an error at the end of the input is visible).
    fn caret_line(&self) -> String {
        let before: String = self
            .source_line
            .chars()
            .take(self.column - 1)
            .map(|c| if c == '\t' { '\t' } else { ' ' })
            .collect();
        let len = self.span.end.saturating_sub(self.span.start);
        let width = self
            .source_line
            .chars()
            .skip(self.column - 1)
            .scan(0usize, |bytes, c| {
                *bytes += c.len_utf8();
                Some(*bytes)
            })
            .take_while(|&bytes| bytes <= len)
            .count()
            .max(1);
        format!("{before}{}", "^".repeat(width))
    }
}

impl fmt::Display for ExprError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        writeln!(f, "{}", self.one_line())?;
        writeln!(f, "  {}", self.source_line)?;
        write!(f, "  {}", self.caret_line())
    }
}

impl std::error::Error for ExprError {}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn line_column_and_caret() {
        let src = "a +\n  sinn(x)";
        let start = src.find("sinn").unwrap();
        let e = ExprError::new(src, Span::new(start, start + 4), "unknown function 'sinn'");
        assert_eq!((e.line, e.column), (2, 3));
        assert_eq!(e.source_line, "  sinn(x)");
        assert_eq!(e.one_line(), "line 2, column 3: unknown function 'sinn'");
        assert_eq!(
            e.to_string(),
            "line 2, column 3: unknown function 'sinn'\n    sinn(x)\n    ^^^^"
        );
    }

    #[test]
    fn columns_count_characters_and_end_of_input_is_visible() {
        let src = "αβ + ";
        let e = ExprError::new(src, Span::new(src.len(), src.len()), "unexpected end");
        assert_eq!((e.line, e.column), (1, 6));
        assert!(e.to_string().ends_with("     ^"));
        // Offsets inside a character or past the end do not panic.
        let e = ExprError::new(src, Span::new(1, 99), "x");
        assert_eq!((e.line, e.column), (1, 1));
        let e = ExprError::new("a\r\nb", Span::new(3, 4), "x");
        assert_eq!((e.line, e.column, e.source_line.as_str()), (2, 1, "b"));
    }
}
