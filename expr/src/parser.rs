//! Tokens to the syntax tree: recursive descent with a nesting limit.
//!
//! Grammar (lowest precedence first):
//! ```text
//! expr     := additive [ ("<" | "<=" | ">" | ">=") additive ]
//! additive := term { ("+" | "-") term }
//! term     := unary { ("*" | "/") unary }
//! unary    := ("-" | "+") unary | power
//! power    := primary [ ("^" | "**") unary ]        (right-associative)
//! primary  := number | name | name "[" expr "]" | name "(" [ expr { "," expr } ] ")"
//!           | "sum" "(" name "=" expr ".." expr "," expr ")" | "(" expr ")"
//! ```
//! So `-x^2 = -(x^2)`, `2^3^2 = 2^9`, `2^-1` is allowed, and `a - b - c = (a - b) - c`.

use crate::ast::{BinOp, Expr, ExprKind};
use crate::error::{ExprError, Span};
use crate::lexer::{Tok, Token, lex};

/// Deepest nesting of parentheses, brackets, calls, prefix signs and exponents. Deep enough
/// for any physical expression; bounded so hostile input (`((((...`) gives an error instead of
/// overflowing the stack here or in the recursive passes over the tree.
pub const MAX_DEPTH: usize = 200;

/// Stack for parsing and lowering. The passes recurse once per nesting level; at
/// [`MAX_DEPTH`] an unoptimized build needs a few MB, more than a worker thread may have (2 MB
/// by default). Only the pages actually used are committed.
const STACK_BYTES: usize = 64 << 20;

/// Run `f` on a thread of its own with a stack of [`STACK_BYTES`], so the depth limit is safe
/// whatever thread the caller is on (a rayon worker, a test thread). Costs one thread spawn,
/// negligible next to lowering a system. If no thread can be spawned, runs `f` here.
pub(crate) fn on_big_stack<T: Send, F: FnOnce() -> T + Send>(f: F) -> T {
    let mut slot = Some(f);
    let ran = std::thread::scope(|s| {
        std::thread::Builder::new()
            .name("chaoscope-expr".into())
            .stack_size(STACK_BYTES)
            .spawn_scoped(s, || slot.take().map(|f| f()))
            .ok()
            .and_then(|h| h.join().unwrap_or_else(|p| std::panic::resume_unwind(p)))
    });
    match (ran, slot.take()) {
        (Some(v), _) => v,
        (None, Some(f)) => f(),
        // The closure either ran (and returned `Some`) or was dropped unrun with the failed
        // spawn (leaving `f` in the slot).
        (None, None) => unreachable!("the parse closure neither ran nor stayed in its slot"),
    }
}

/// Parse `source` into a syntax tree (syntax only: names are not resolved).
pub fn parse(source: &str) -> Result<Expr, ExprError> {
    on_big_stack(|| parse_here(source))
}

/// [`parse`] on the current thread's stack (the caller provides a big enough one).
pub(crate) fn parse_here(source: &str) -> Result<Expr, ExprError> {
    let tokens = lex(source)?;
    let mut p = Parser {
        src: source,
        tokens,
        pos: 0,
        depth: 0,
    };
    if p.peek().tok == Tok::Eof {
        return Err(p.err(Span::new(0, source.len()), "empty expression"));
    }
    let e = p.expr()?;
    let t = p.peek();
    match t.tok {
        Tok::Eof => Ok(e),
        Tok::RParen | Tok::RBracket => Err(p.err(
            t.span,
            format!("unmatched '{}' (no opening bracket)", p.text(t)),
        )),
        Tok::Ident | Tok::Num(_) | Tok::LParen => Err(p.err(
            t.span,
            format!(
                "unexpected '{}' after a complete expression (missing operator? a product is written a*b)",
                p.text(t)
            ),
        )),
        _ => Err(p.err(
            t.span,
            format!("unexpected '{}' after a complete expression", p.text(t)),
        )),
    }
}

struct Parser<'s> {
    src: &'s str,
    tokens: Vec<Token>,
    pos: usize,
    depth: usize,
}

type R<T> = Result<T, ExprError>;

/// The left-associative binary operator `t` stands for, with its precedence level: `+ -` bind
/// loosest (0), `* /` tightest ([`TIGHTEST`]).
fn binary_op(t: Tok) -> Option<(usize, BinOp)> {
    match t {
        Tok::Plus => Some((0, BinOp::Add)),
        Tok::Minus => Some((0, BinOp::Sub)),
        Tok::Star => Some((TIGHTEST, BinOp::Mul)),
        Tok::Slash => Some((TIGHTEST, BinOp::Div)),
        _ => None,
    }
}

/// The precedence level of the operators that bind tightest ([`binary_op`]).
const TIGHTEST: usize = 1;

impl<'s> Parser<'s> {
    fn peek(&self) -> Token {
        self.tokens[self.pos.min(self.tokens.len() - 1)]
    }

    fn next(&mut self) -> Token {
        let t = self.peek();
        if t.tok != Tok::Eof {
            self.pos += 1;
        }
        t
    }

    fn text(&self, t: Token) -> &'s str {
        if t.tok == Tok::Eof {
            "end of input"
        } else {
            &self.src[t.span.start..t.span.end]
        }
    }

    fn err(&self, span: Span, msg: impl Into<String>) -> ExprError {
        ExprError::new(self.src, span, msg)
    }

    /// What was found, for "expected X, found Y" messages.
    fn found(&self, t: Token) -> String {
        if t.tok == Tok::Eof {
            "the end of the expression".into()
        } else {
            format!("'{}'", self.text(t))
        }
    }

    fn enter(&mut self, span: Span) -> R<()> {
        self.depth += 1;
        if self.depth > MAX_DEPTH {
            return Err(self.err(
                span,
                format!("expression nested too deeply (more than {MAX_DEPTH} levels)"),
            ));
        }
        Ok(())
    }

    fn leave(&mut self) {
        self.depth -= 1;
    }

    fn expr(&mut self) -> R<Expr> {
        let lhs = self.chain(0)?;
        let Tok::Cmp(op) = self.peek().tok else {
            return Ok(lhs);
        };
        let op_span = self.next().span;
        let rhs = self.chain(0)?;
        if let Tok::Cmp(_) = self.peek().tok {
            let t = self.peek();
            return Err(self.err(
                t.span,
                "comparisons cannot be chained (a < b < c): use a single comparison",
            ));
        }
        let span = lhs.span.to(rhs.span);
        Ok(Expr {
            kind: ExprKind::Compare {
                op,
                op_span,
                lhs: Box::new(lhs),
                rhs: Box::new(rhs),
            },
            span,
        })
    }

    /// A left-associative chain of the operators of precedence `level` (see [`binary_op`]),
    /// whose operands are chains of the next level, or unary expressions above the last.
    fn chain(&mut self, level: usize) -> R<Expr> {
        let operand = |p: &mut Self| {
            if level == TIGHTEST {
                p.unary()
            } else {
                p.chain(level + 1)
            }
        };
        let first = operand(self)?;
        let mut rest = Vec::new();
        while let Some((l, op)) = binary_op(self.peek().tok)
            && l == level
        {
            let op_span = self.next().span;
            rest.push((op, op_span, operand(self)?));
        }
        if rest.is_empty() {
            return Ok(first);
        }
        let span = first
            .span
            .to(rest.last().map_or(first.span, |(_, _, x)| x.span));
        Ok(Expr {
            kind: ExprKind::Chain {
                first: Box::new(first),
                rest,
            },
            span,
        })
    }

    fn unary(&mut self) -> R<Expr> {
        let t = self.peek();
        match t.tok {
            Tok::Minus | Tok::Plus => {
                self.next();
                self.enter(t.span)?;
                let arg = self.unary()?;
                self.leave();
                if t.tok == Tok::Plus {
                    return Ok(arg);
                }
                let span = t.span.to(arg.span);
                Ok(Expr {
                    kind: ExprKind::Neg {
                        op_span: t.span,
                        arg: Box::new(arg),
                    },
                    span,
                })
            }
            _ => self.power(),
        }
    }

    fn power(&mut self) -> R<Expr> {
        let base = self.primary()?;
        if self.peek().tok != Tok::Caret {
            return Ok(base);
        }
        let op_span = self.next().span;
        self.enter(op_span)?;
        let exp = self.unary()?;
        self.leave();
        let span = base.span.to(exp.span);
        Ok(Expr {
            kind: ExprKind::Pow {
                op_span,
                base: Box::new(base),
                exp: Box::new(exp),
            },
            span,
        })
    }

    /// Consume the closing `close` of the bracket opened at `open`, or explain what is missing.
    fn close(&mut self, close: Tok, open: Token, what: &str) -> R<Token> {
        let t = self.peek();
        if t.tok == close {
            return Ok(self.next());
        }
        let (o, c) = match close {
            Tok::RBracket => ("[", "]"),
            _ => ("(", ")"),
        };
        if t.tok == Tok::Eof {
            return Err(self.err(
                open.span,
                format!("unclosed '{o}'{what}: no matching '{c}' before the end"),
            ));
        }
        let (line, column, _, _) = crate::error::locate(self.src, open.span.start);
        Err(self.err(
            t.span,
            format!(
                "expected '{c}' to close the '{o}'{what} at line {line}, column {column}, found {}",
                self.found(t)
            ),
        ))
    }

    /// One expression inside the bracket `open`, and the closing `close`.
    fn bracketed(&mut self, open: Token, close: Tok, what: &str) -> R<(Expr, Token)> {
        self.enter(open.span)?;
        let e = self.expr()?;
        let end = self.close(close, open, what)?;
        self.leave();
        Ok((e, end))
    }

    fn primary(&mut self) -> R<Expr> {
        let t = self.next();
        match t.tok {
            Tok::Num(v) => Ok(Expr {
                kind: ExprKind::Number(v),
                span: t.span,
            }),
            Tok::LParen => {
                let (e, _) = self.bracketed(t, Tok::RParen, "")?;
                // The inner span is kept: carets point at the content, and an error in `(a)`
                // reads the same as in `a`.
                Ok(e)
            }
            Tok::Ident => {
                let name = self.text(t).to_string();
                match self.peek().tok {
                    Tok::LParen if name == "sum" => self.sum(t),
                    Tok::LParen => self.call(name, t),
                    Tok::LBracket => {
                        let open = self.next();
                        let what = format!(" of '{name}['");
                        self.enter(open.span)?;
                        let index = self.expr()?;
                        // `q[i, j]`: a site of a square lattice by row and column.
                        let column = if self.peek().tok == Tok::Comma {
                            self.next();
                            Some(Box::new(self.expr()?))
                        } else {
                            None
                        };
                        let end = self.close(Tok::RBracket, open, &what)?;
                        self.leave();
                        Ok(Expr {
                            kind: ExprKind::Index {
                                name,
                                name_span: t.span,
                                index: Box::new(index),
                                column,
                            },
                            span: t.span.to(end.span),
                        })
                    }
                    _ => Ok(Expr {
                        kind: ExprKind::Name(name),
                        span: t.span,
                    }),
                }
            }
            Tok::Eof => Err(self.err(
                t.span,
                "unexpected end of the expression (expected a number, a name or '(')",
            )),
            Tok::RParen => {
                Err(self.err(t.span, "unexpected ')' (expected a number, a name or '(')"))
            }
            _ => Err(self.err(
                t.span,
                format!(
                    "unexpected '{}' (expected a number, a name or '(')",
                    self.text(t)
                ),
            )),
        }
    }

    fn call(&mut self, name: String, name_tok: Token) -> R<Expr> {
        let open = self.next();
        self.enter(open.span)?;
        let mut args = Vec::new();
        let what = format!(" of '{name}('");
        if self.peek().tok != Tok::RParen {
            loop {
                args.push(self.expr()?);
                let t = self.peek();
                match t.tok {
                    Tok::Comma => {
                        self.next();
                    }
                    Tok::RParen => break,
                    Tok::Eof => {
                        self.close(Tok::RParen, open, &what)?;
                    }
                    _ => {
                        return Err(self.err(
                            t.span,
                            format!(
                                "expected ',' or ')' in the arguments of '{name}', found {}",
                                self.found(t)
                            ),
                        ));
                    }
                }
            }
        }
        let end = self.close(Tok::RParen, open, &what)?;
        self.leave();
        Ok(Expr {
            kind: ExprKind::Call {
                name,
                name_span: name_tok.span,
                args,
            },
            span: name_tok.span.to(end.span),
        })
    }

    /// The next token, which must be `tok` (`what` describes it) inside a sum.
    fn expect(&mut self, tok: Tok, what: &str) -> R<Token> {
        let t = self.next();
        if t.tok == tok {
            return Ok(t);
        }
        Err(self.err(
            t.span,
            format!(
                "expected {what}, found {} (write sum(i = 1..N, term))",
                self.found(t)
            ),
        ))
    }

    /// `sum(i = a..b, term)`; `sum` and `(` are next.
    fn sum(&mut self, sum_tok: Token) -> R<Expr> {
        let open = self.next();
        self.enter(open.span)?;
        let index_tok = self.expect(Tok::Ident, "the name of the sum's index")?;
        self.expect(Tok::Assign, "'=' after the sum's index")?;
        let from = self.expr()?;
        self.expect(Tok::DotDot, "'..' in the range of the sum")?;
        let to = self.expr()?;
        self.expect(Tok::Comma, "',' after the range of the sum")?;
        let body = self.expr()?;
        let end = self.close(Tok::RParen, open, " of 'sum('")?;
        self.leave();
        Ok(Expr {
            kind: ExprKind::Sum {
                index: self.text(index_tok).to_string(),
                index_span: index_tok.span,
                from: Box::new(from),
                to: Box::new(to),
                body: Box::new(body),
            },
            span: sum_tok.span.to(end.span),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The tree in a fully parenthesized prefix form.
    fn show(e: &Expr) -> String {
        match &e.kind {
            ExprKind::Number(v) => format!("{v}"),
            ExprKind::Name(n) => n.clone(),
            ExprKind::Index {
                name,
                index,
                column: None,
                ..
            } => format!("{name}[{}]", show(index)),
            ExprKind::Index {
                name,
                index,
                column: Some(column),
                ..
            } => format!("{name}[{}, {}]", show(index), show(column)),
            ExprKind::Neg { arg, .. } => format!("(neg {})", show(arg)),
            ExprKind::Chain { first, rest } => {
                let mut s = show(first);
                for (op, _, x) in rest {
                    s = format!("({} {s} {})", op.symbol(), show(x));
                }
                s
            }
            ExprKind::Pow { base, exp, .. } => format!("(^ {} {})", show(base), show(exp)),
            ExprKind::Call { name, args, .. } => format!(
                "({name} {})",
                args.iter().map(show).collect::<Vec<_>>().join(" ")
            ),
            ExprKind::Compare { op, lhs, rhs, .. } => {
                format!("({op:?} {} {})", show(lhs), show(rhs))
            }
            ExprKind::Sum {
                index,
                from,
                to,
                body,
                ..
            } => format!("(sum {index} {} {} {})", show(from), show(to), show(body)),
        }
    }

    fn p(s: &str) -> String {
        show(&parse(s).unwrap_or_else(|e| panic!("{s}: {e}")))
    }

    #[test]
    fn precedence_and_associativity() {
        assert_eq!(p("-x^2"), "(neg (^ x 2))");
        assert_eq!(p("2^3^2"), "(^ 2 (^ 3 2))");
        assert_eq!(p("2**3**2"), "(^ 2 (^ 3 2))");
        assert_eq!(p("a+b+c"), "(+ (+ a b) c)");
        assert_eq!(p("a*b*c"), "(* (* a b) c)");
        assert_eq!(p("a-b*c/d+e"), "(+ (- a (/ (* b c) d)) e)");
        assert_eq!(p("2^-x"), "(^ 2 (neg x))");
        assert_eq!(p("+x - -y"), "(- x (neg y))");
        assert_eq!(p("(a+b)*c"), "(* (+ a b) c)");
        assert_eq!(p("-a*b"), "(* (neg a) b)");
    }

    #[test]
    fn calls_indices_sums_comparisons() {
        assert_eq!(p("max(0, d)^(5/2)"), "(^ (max 0 d) (/ 5 2))");
        assert_eq!(p("q[2*i-1]"), "q[(- (* 2 i) 1)]");
        assert_eq!(p("sum(i = 1..N-1, q[i+1])"), "(sum i 1 (- N 1) q[(+ i 1)])");
        assert_eq!(p("if(x <= 0, 1, 2)"), "(if (Le x 0) 1 2)");
        assert_eq!(p("f()"), "(f )");
        assert_eq!(
            p("sum(i = 0..N,\n  sum(j = i..N, q[j]))"),
            "(sum i 0 N (sum j i N q[j]))"
        );
    }

    fn err(s: &str) -> ExprError {
        match parse(s) {
            Ok(e) => panic!("{s} parsed as {}", show(&e)),
            Err(e) => e,
        }
    }

    #[test]
    fn syntax_errors_point_at_the_problem() {
        let cases: &[(&str, &str, usize, usize)] = &[
            ("", "empty expression", 1, 1),
            ("  \n ", "empty expression", 1, 1),
            ("q1 + * q2", "unexpected '*'", 1, 6),
            ("(q1 + q2", "unclosed '('", 1, 1),
            ("q1 + (q2\n  * 3", "unclosed '('", 1, 6),
            ("max(q1, q2", "unclosed '(' of 'max('", 1, 4),
            (
                "(q1 q2)",
                "expected ')' to close the '(' at line 1, column 1",
                1,
                5,
            ),
            (
                "q1 q2",
                "after a complete expression (missing operator",
                1,
                4,
            ),
            ("q1 + q2)", "unmatched ')'", 1, 8),
            ("q1 +", "unexpected end", 1, 5),
            ("1.5e", "bad number", 1, 1),
            ("a < b < c", "cannot be chained", 1, 7),
            ("sum(i 1..N, q[i])", "expected '='", 1, 7),
            ("sum(i = 1, q[i])", "expected '..'", 1, 10),
            ("sum(1 = 1..N, q[i])", "name of the sum's index", 1, 5),
            ("q[1", "unclosed '[' of 'q['", 1, 2),
            ("max(1 2)", "expected ',' or ')'", 1, 7),
            ("x^\n\n   )", "unexpected ')'", 3, 4),
        ];
        for &(s, msg, line, column) in cases {
            let e = err(s);
            assert!(e.message.contains(msg), "{s:?}: {}", e.message);
            assert_eq!((e.line, e.column), (line, column), "{s:?}: {e}");
        }
    }

    #[test]
    fn deep_nesting_is_an_error_not_a_crash() {
        for s in [
            "(".repeat(100_000),
            format!("{}x{}", "(".repeat(100_000), ")".repeat(100_000)),
            "-".repeat(100_000) + "x",
            "x^".repeat(100_000) + "x",
            "sin(".repeat(100_000),
            "q[".repeat(100_000),
        ] {
            let e = err(&s);
            assert!(e.message.contains("nested too deeply"), "{}", e.message);
        }
        // 200 levels are fine, and long flat chains are not nesting.
        let ok = format!("{}x{}", "(".repeat(MAX_DEPTH), ")".repeat(MAX_DEPTH));
        parse(&ok).unwrap();
        parse(&vec!["q1"; 100_000].join(" + ")).unwrap();
    }
}
