//! Tabulated functions: samples `x, V` read from a CSV file, interpolated by a cubic spline
//! with its first three derivatives (the gradient needs one, the Hessian-vector product two,
//! the smoothness of the third is reported, never relied upon).
//!
//! # Outside the table
//!
//! The spline is NaN outside `[x_first, x_last]`. A trajectory that leaves the tabulated range
//! then produces a NaN force, which stops the run with an error naming the table (see
//! `eval::first_non_finite`) instead of silently extrapolating a cubic that the data never
//! constrained.
//!
//! # Reproducibility
//!
//! [`TableData::digest`] is the SHA-256 of the file's exact bytes. It goes into recordings, so a
//! replay on another machine refuses a table that differs in any byte (even one that would
//! parse to the same numbers: the digest identifies the input, not its interpretation).
//!
//! # Accuracy
//!
//! See [`interpolation_error_bound`]: a clamped spline with exact end slopes interpolates a
//! smooth `f` to `O(dx^4)` in value and `O(dx^3)` in slope. A natural spline forces `s'' = 0`
//! at the ends; unless `f''` vanishes there, the error near the ends is only `O(dx^2)`.

use std::fmt;
use std::io::Read;
use std::path::Path;

use sha2::{Digest, Sha256};

use crate::graph::Tabulated;

/// The largest table file read: far beyond any sensible table, small enough that a wrong path
/// (a trajectory dump, a disk image) fails at once instead of filling memory.
pub const MAX_FILE_BYTES: u64 = 64 << 20;

/// The most samples a table may have. A spline's error falls as `dx^4`: a million samples are
/// far past the point where rounding, not spacing, limits the accuracy.
pub const MAX_SAMPLES: usize = 1_000_000;

/// The fewest samples: a cubic spline needs at least four to be more than a cubic through
/// all of them, and fewer almost always means a truncated or mis-split file.
pub const MIN_SAMPLES: usize = 4;

/// Why a table could not be read or interpolated. Every message names the file (or the
/// config's name of the table), and the line where there is one.
#[derive(Debug, thiserror::Error)]
pub enum TableError {
    #[error("table file `{name}` does not exist")]
    NotFound { name: String },
    #[error("cannot read table file `{name}`: {source}")]
    Unreadable {
        name: String,
        #[source]
        source: std::io::Error,
    },
    #[error("table file `{name}` is larger than {limit} bytes: is it the right file?")]
    TooLarge { name: String, limit: u64 },
    #[error("{name}: line {line}: not UTF-8 text: a table is a text file of two numeric columns")]
    NotText { name: String, line: usize },
    #[error("{name}: no samples (the file is empty or holds only comments and a header)")]
    Empty { name: String },
    #[error(
        "{name}: {count} sample(s), but a cubic spline needs at least {MIN_SAMPLES}: \
         is the file truncated?"
    )]
    TooFewSamples { name: String, count: usize },
    #[error(
        "{name}: more than {MAX_SAMPLES} samples: a coarser table is as accurate (the spline error falls as dx^4)"
    )]
    TooManySamples { name: String },
    #[error(
        "{name}: line {line}: {found} column(s), expected 2 (`x, V`, separated by a comma, \
         a semicolon or whitespace)"
    )]
    Columns {
        name: String,
        line: usize,
        found: usize,
    },
    #[error("{name}: line {line}: `{text}` in column {column} is not a number")]
    NotANumber {
        name: String,
        line: usize,
        column: usize,
        text: String,
    },
    #[error("{name}: line {line}: `{text}` in column {column} is not finite")]
    NonFinite {
        name: String,
        line: usize,
        column: usize,
        text: String,
    },
    #[error(
        "{name}: line {line}: x = {x} is not greater than the previous x = {previous}: \
         samples must be sorted by x with no repeats"
    )]
    NotIncreasing {
        name: String,
        line: usize,
        x: f64,
        previous: f64,
    },
    /// A spline built from numbers rather than from a file (no line to name).
    #[error("table `{name}`: {reason}")]
    Invalid { name: String, reason: String },
}

/// The samples of a table and the digest of the bytes they were read from.
#[derive(Debug, Clone, PartialEq)]
pub struct TableData {
    pub xs: Vec<f64>,
    pub ys: Vec<f64>,
    /// SHA-256 of the file's exact bytes.
    pub digest: [u8; 32],
}

impl TableData {
    /// The digest as 64 lowercase hex digits (as recordings store it).
    pub fn digest_hex(&self) -> String {
        use fmt::Write;
        self.digest
            .iter()
            .fold(String::with_capacity(64), |mut s, b| {
                let _ = write!(s, "{b:02x}");
                s
            })
    }
}

/// Reads a table file: see [`parse_csv`] for the format. Errors name the file by `path`.
pub fn read_csv(path: impl AsRef<Path>) -> Result<TableData, TableError> {
    let path = path.as_ref();
    let name = path.display().to_string();
    let unreadable = |e| TableError::Unreadable {
        name: name.clone(),
        source: e,
    };
    let file = chaoscope_os::open_regular(path).map_err(|e| match e.kind() {
        std::io::ErrorKind::NotFound => TableError::NotFound { name: name.clone() },
        _ => unreadable(e),
    })?;
    let len = file.metadata().map_err(unreadable)?.len();
    if len > MAX_FILE_BYTES {
        return Err(too_large(&name));
    }
    // Read at most one byte past the limit, in case the file grows while being read.
    let mut bytes = Vec::with_capacity(len as usize);
    file.take(MAX_FILE_BYTES + 1)
        .read_to_end(&mut bytes)
        .map_err(unreadable)?;
    if bytes.len() as u64 > MAX_FILE_BYTES {
        return Err(too_large(&name));
    }
    let text = std::str::from_utf8(&bytes).map_err(|e| TableError::NotText {
        name: name.clone(),
        line: 1 + bytes[..e.valid_up_to()]
            .iter()
            .filter(|&&b| b == b'\n')
            .count(),
    })?;
    parse_csv(text, &name)
}

fn too_large(name: &str) -> TableError {
    TableError::TooLarge {
        name: name.to_string(),
        limit: MAX_FILE_BYTES,
    }
}

/// Parses table text: two numeric columns `x, V` per line, separated by a comma, a semicolon
/// or whitespace; `#` starts a comment; blank lines are skipped; the first data line may be a
/// header of non-numeric names (`x, V`). `x` must be strictly increasing (a table is a
/// function); there must be at least [`MIN_SAMPLES`] and at most [`MAX_SAMPLES`] samples, all
/// finite. `name` names the table in messages (the file's path). The digest is the SHA-256 of
/// `text`'s bytes.
pub fn parse_csv(text: &str, name: &str) -> Result<TableData, TableError> {
    if text.len() as u64 > MAX_FILE_BYTES {
        return Err(too_large(name));
    }
    let name_s = || name.to_string();
    let mut xs = Vec::new();
    let mut ys = Vec::new();
    let mut seen_data_line = false;
    // A byte-order mark (spreadsheet exports) is not part of the first field; the digest
    // still covers it.
    let body = text.strip_prefix('\u{feff}').unwrap_or(text);
    for (k, raw) in body.split('\n').enumerate() {
        let line = k + 1;
        let content = raw.split('#').next().unwrap_or("").trim();
        if content.is_empty() {
            continue;
        }
        let fields: Vec<&str> = if content.contains(',') {
            content.split(',').map(str::trim).collect()
        } else if content.contains(';') {
            content.split(';').map(str::trim).collect()
        } else {
            content.split_whitespace().collect()
        };
        let first = !seen_data_line;
        seen_data_line = true;
        // Data and a header alike have the two columns.
        if fields.len() != 2 {
            return Err(TableError::Columns {
                name: name_s(),
                line,
                found: fields.len(),
            });
        }
        let parsed: Vec<Option<f64>> = fields.iter().map(|f| f.parse::<f64>().ok()).collect();
        if first && parsed.iter().all(Option::is_none) && fields.iter().all(|f| !f.is_empty()) {
            // A header of names.
            continue;
        }
        let mut vals = [0.0; 2];
        for (c, (f, p)) in fields.iter().zip(&parsed).enumerate() {
            let v = p.ok_or_else(|| TableError::NotANumber {
                name: name_s(),
                line,
                column: c + 1,
                text: f.to_string(),
            })?;
            if !v.is_finite() {
                return Err(TableError::NonFinite {
                    name: name_s(),
                    line,
                    column: c + 1,
                    text: f.to_string(),
                });
            }
            vals[c] = v;
        }
        let [x, y] = vals;
        if let Some(&previous) = xs.last()
            && x <= previous
        {
            return Err(TableError::NotIncreasing {
                name: name_s(),
                line,
                x,
                previous,
            });
        }
        if xs.len() == MAX_SAMPLES {
            return Err(TableError::TooManySamples { name: name_s() });
        }
        xs.push(x);
        ys.push(y);
    }
    if xs.is_empty() {
        return Err(TableError::Empty { name: name_s() });
    }
    if xs.len() < MIN_SAMPLES {
        return Err(TableError::TooFewSamples {
            name: name_s(),
            count: xs.len(),
        });
    }
    Ok(TableData {
        xs,
        ys,
        digest: Sha256::digest(text.as_bytes()).into(),
    })
}

/// The end conditions that close the spline's system.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum SplineEnds {
    /// `s'' = 0` at both ends: no information beyond the samples, but only `O(dx^2)` accurate
    /// near the ends unless the function's own `f''` vanishes there.
    Natural,
    /// Given slopes `s'(x_first) = left`, `s'(x_last) = right`: with the exact slopes the
    /// spline is `O(dx^4)` accurate everywhere, and reproduces cubics exactly.
    Clamped { left: f64, right: f64 },
}

/// A C^2 cubic spline through strictly increasing (possibly non-uniform) knots.
///
/// Each interval `[x_i, x_{i+1}]` holds the cubic in its local coordinate `t = x - x_i`,
/// `y_i + t (b_i + t (c_i + t d_i))`, evaluated by Horner's rule: `t` stays within one
/// interval, so no cancellation between large powers of `x`. Derivatives 1 to 3 are the
/// derivatives of that cubic (the third is piecewise constant, taken from the interval on the
/// right at a knot). NaN outside `[x_first, x_last]` (see the module documentation).
#[derive(Debug, Clone)]
pub struct Spline {
    name: String,
    xs: Vec<f64>,
    ys: Vec<f64>,
    b: Vec<f64>,
    c: Vec<f64>,
    d: Vec<f64>,
    /// `1 / spacing` when the knots are (nearly) uniform: the interval is then guessed in
    /// O(1) and corrected by at most a step, else found by binary search.
    inv_spacing: Option<f64>,
}

impl Spline {
    /// The spline through `(xs[i], ys[i])`. `name` is the config's name of the table (for
    /// messages). Needs at least [`MIN_SAMPLES`] finite samples with strictly increasing `xs`
    /// and finite clamped slopes.
    pub fn new(name: &str, xs: &[f64], ys: &[f64], kind: SplineEnds) -> Result<Self, TableError> {
        let invalid = |reason: String| TableError::Invalid {
            name: name.to_string(),
            reason,
        };
        if xs.len() != ys.len() {
            return Err(invalid(format!(
                "{} x values but {} values",
                xs.len(),
                ys.len()
            )));
        }
        let n = xs.len();
        if n < MIN_SAMPLES {
            return Err(invalid(format!(
                "{n} sample(s), but a cubic spline needs at least {MIN_SAMPLES}"
            )));
        }
        if let Some(i) = (0..n).find(|&i| !xs[i].is_finite() || !ys[i].is_finite()) {
            return Err(invalid(format!("sample {i} is not finite")));
        }
        if let Some(i) = (1..n).find(|&i| xs[i] <= xs[i - 1]) {
            return Err(invalid(format!(
                "x = {} (sample {i}) is not greater than the previous x = {}",
                xs[i],
                xs[i - 1]
            )));
        }
        // Spacings must be representable and non-zero after subtraction (subnormal gaps are
        // not a table).
        let h: Vec<f64> = xs.windows(2).map(|w| w[1] - w[0]).collect();
        if h.iter().any(|h| !(h.is_normal() && *h > 0.0)) {
            return Err(invalid(
                "knot spacings must be normal positive numbers".into(),
            ));
        }
        if let SplineEnds::Clamped { left, right } = kind
            && !(left.is_finite() && right.is_finite())
        {
            return Err(invalid("clamped end slopes must be finite".into()));
        }
        let m = second_derivatives(&h, ys, kind);
        let mut b = Vec::with_capacity(n - 1);
        let mut c = Vec::with_capacity(n - 1);
        let mut d = Vec::with_capacity(n - 1);
        for i in 0..n - 1 {
            let hi = h[i];
            b.push((ys[i + 1] - ys[i]) / hi - hi * (2.0 * m[i] + m[i + 1]) / 6.0);
            c.push(m[i] / 2.0);
            d.push((m[i + 1] - m[i]) / (6.0 * hi));
        }
        let (span, mean) = (xs[n - 1] - xs[0], (xs[n - 1] - xs[0]) / (n - 1) as f64);
        let uniform = h.iter().all(|&hi| (hi - mean).abs() <= 1e-9 * mean) && span.is_finite();
        Ok(Self {
            name: name.to_string(),
            xs: xs.to_vec(),
            ys: ys.to_vec(),
            b,
            c,
            d,
            inv_spacing: uniform.then(|| 1.0 / mean),
        })
    }

    /// The spline through a table's samples.
    pub fn from_table(name: &str, data: &TableData, kind: SplineEnds) -> Result<Self, TableError> {
        Self::new(name, &data.xs, &data.ys, kind)
    }

    /// `[x_first, x_last]`: where the spline is defined.
    pub fn domain(&self) -> (f64, f64) {
        (self.xs[0], self.xs[self.xs.len() - 1])
    }

    /// The knots.
    pub fn knots(&self) -> &[f64] {
        &self.xs
    }

    /// The interval `i` with `x_i <= x < x_{i+1}` (the last interval also takes `x_last`), or
    /// `None` outside the domain or for NaN.
    fn interval(&self, x: f64) -> Option<usize> {
        let (lo, hi) = self.domain();
        if !(lo..=hi).contains(&x) {
            return None;
        }
        let last = self.xs.len() - 2;
        let i = match self.inv_spacing {
            Some(inv) => {
                // A guess from the uniform spacing, then exact against the knots.
                let mut i = (((x - lo) * inv) as usize).min(last);
                while i > 0 && x < self.xs[i] {
                    i -= 1;
                }
                while i < last && x >= self.xs[i + 1] {
                    i += 1;
                }
                i
            }
            None => self
                .xs
                .partition_point(|&k| k <= x)
                .saturating_sub(1)
                .min(last),
        };
        Some(i)
    }

    /// Derivative `deriv` of interval `i`'s cubic at `x` (not checked against the interval).
    fn piece(&self, i: usize, deriv: u8, x: f64) -> f64 {
        let t = x - self.xs[i];
        let (b, c, d) = (self.b[i], self.c[i], self.d[i]);
        match deriv {
            0 => self.ys[i] + t * (b + t * (c + t * d)),
            1 => b + t * (2.0 * c + t * (3.0 * d)),
            2 => 2.0 * c + t * (6.0 * d),
            3 => 6.0 * d,
            _ => f64::NAN,
        }
    }
}

impl Tabulated for Spline {
    /// Derivative `deriv` (0 to 3) at `x`; NaN outside `[x_first, x_last]`, for NaN `x`, and for
    /// `deriv > 3`.
    fn eval(&self, deriv: u8, x: f64) -> f64 {
        match self.interval(x) {
            // The last sample exactly (the cubic of the last interval reaches it only to
            // rounding; every other knot starts its interval, where `t = 0`).
            Some(i) if deriv == 0 && x == self.xs[i + 1] => self.ys[i + 1],
            Some(i) => self.piece(i, deriv, x),
            None => f64::NAN,
        }
    }

    fn name(&self) -> &str {
        &self.name
    }
}

/// The knots' second derivatives `M_i`, from the continuity of `s'` at interior knots plus
/// the end conditions: a symmetric, strictly diagonally dominant tridiagonal system, solved by
/// elimination without pivoting (stable for such systems).
fn second_derivatives(h: &[f64], y: &[f64], kind: SplineEnds) -> Vec<f64> {
    let n = y.len();
    let slope = |i: usize| (y[i + 1] - y[i]) / h[i];
    // Row i: sub[i] M_{i-1} + diag[i] M_i + sup[i] M_{i+1} = rhs[i].
    let mut sub = vec![0.0; n];
    let mut diag = vec![0.0; n];
    let mut sup = vec![0.0; n];
    let mut rhs = vec![0.0; n];
    for i in 1..n - 1 {
        sub[i] = h[i - 1];
        diag[i] = 2.0 * (h[i - 1] + h[i]);
        sup[i] = h[i];
        rhs[i] = 6.0 * (slope(i) - slope(i - 1));
    }
    match kind {
        SplineEnds::Natural => {
            diag[0] = 1.0;
            diag[n - 1] = 1.0;
        }
        SplineEnds::Clamped { left, right } => {
            diag[0] = 2.0 * h[0];
            sup[0] = h[0];
            rhs[0] = 6.0 * (slope(0) - left);
            sub[n - 1] = h[n - 2];
            diag[n - 1] = 2.0 * h[n - 2];
            rhs[n - 1] = 6.0 * (right - slope(n - 2));
        }
    }
    // Forward elimination, back substitution (Thomas).
    for i in 1..n {
        let w = sub[i] / diag[i - 1];
        diag[i] -= w * sup[i - 1];
        rhs[i] -= w * rhs[i - 1];
    }
    let mut m = vec![0.0; n];
    m[n - 1] = rhs[n - 1] / diag[n - 1];
    for i in (0..n - 1).rev() {
        m[i] = (rhs[i] - sup[i] * m[i + 1]) / diag[i];
    }
    m
}

/// Worst-case interpolation errors of a clamped cubic spline, by derivative.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ErrorBound {
    /// Bound on `|f - s|`.
    pub value: f64,
    /// Bound on `|f' - s'|`.
    pub first_derivative: f64,
    /// Bound on `|f'' - s''|`.
    pub second_derivative: f64,
}

/// Worst-case error of the clamped cubic spline ([`SplineEnds::Clamped`] with the exact end
/// slopes `f'(x_first)`, `f'(x_last)`) interpolating `f` in C^4 on knots no farther apart
/// than `max_spacing`, where `max_fourth_derivative >= max |f''''|` over the table:
///
/// - `|f - s|   <= 5/384 · max|f''''| · dx^4`
/// - `|f' - s'| <= 1/24  · max|f''''| · dx^3`
/// - `|f'' - s''| <= 3/8 · max|f''''| · dx^2`
///
/// (C. A. Hall and W. W. Meyer, "Optimal error bounds for cubic spline interpolation",
/// J. Approx. Theory 16 (1976) 105-122); the paper shows the constants cannot be lowered.
/// Hence the rates a test may rely on: halving `dx` divides the value error by 16 and the
/// slope error by 8, and a tolerance of the bound plus rounding is never too tight.
///
/// These bounds hold for exact arithmetic; evaluation adds a rounding error of a few ulps of
/// the values involved (the Horner form keeps it there). A natural spline satisfies them only
/// when `f''` vanishes at both ends; otherwise its error near the ends is
/// `O(|f''(end)| · dx^2)`.
pub fn interpolation_error_bound(max_fourth_derivative: f64, max_spacing: f64) -> ErrorBound {
    let k = max_fourth_derivative.abs();
    let h = max_spacing;
    ErrorBound {
        value: 5.0 / 384.0 * k * h.powi(4),
        first_derivative: k * h.powi(3) / 24.0,
        second_derivative: 3.0 / 8.0 * k * h * h,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testing::uniform01;

    fn uniform_knots(a: f64, b: f64, n: usize) -> Vec<f64> {
        (0..n)
            .map(|i| a + (b - a) * i as f64 / (n - 1) as f64)
            .collect()
    }

    /// Increasing knots on [a, b] with spacings varying by a factor of up to 10.
    fn random_knots(a: f64, b: f64, n: usize, seed: u64) -> Vec<f64> {
        let w: Vec<f64> = uniform01(n - 1, seed).iter().map(|u| 0.1 + u).collect();
        let total: f64 = w.iter().sum();
        let mut xs = vec![a];
        let mut acc = 0.0;
        for wi in &w[..n - 2] {
            acc += wi;
            xs.push(a + (b - a) * acc / total);
        }
        xs.push(b);
        xs
    }

    /// Points spread over the domain, knots and ends included.
    fn probe_points(xs: &[f64]) -> Vec<f64> {
        let mut p = Vec::new();
        for w in xs.windows(2) {
            for k in 0..8 {
                p.push(w[0] + (w[1] - w[0]) * k as f64 / 8.0);
            }
        }
        p.push(xs[xs.len() - 1]);
        p
    }

    #[test]
    fn clamped_spline_reproduces_cubics_with_all_derivatives() {
        let (a, b, c, d) = (0.7, -1.3, 0.4, 2.1);
        let f = [
            |x: f64, k: &[f64; 4]| k[0] + x * (k[1] + x * (k[2] + x * k[3])),
            |x: f64, k: &[f64; 4]| k[1] + x * (2.0 * k[2] + x * 3.0 * k[3]),
            |x: f64, k: &[f64; 4]| 2.0 * k[2] + 6.0 * k[3] * x,
            |_: f64, k: &[f64; 4]| 6.0 * k[3],
        ];
        let coef = [a, b, c, d];
        for xs in [
            uniform_knots(-1.0, 2.0, 13),
            random_knots(-1.0, 2.0, 17, 5),
            random_knots(-1.0, 2.0, 4, 9),
        ] {
            let ys: Vec<f64> = xs.iter().map(|&x| f[0](x, &coef)).collect();
            let kind = SplineEnds::Clamped {
                left: f[1](xs[0], &coef),
                right: f[1](xs[xs.len() - 1], &coef),
            };
            let s = Spline::new("cubic", &xs, &ys, kind).unwrap();
            for x in probe_points(&xs) {
                for k in 0..4u8 {
                    let want = f[k as usize](x, &coef);
                    let got = s.eval(k, x);
                    // Rounding of O(10) values, amplified by 1/h^k for the k-th derivative.
                    assert!(
                        (got - want).abs() <= 1e-12 * 10f64.powi(k as i32 + 1),
                        "derivative {k} at {x}: {got} vs {want}"
                    );
                }
            }
        }
    }

    #[test]
    fn natural_spline_reproduces_lines_and_is_straight_at_the_ends() {
        for xs in [uniform_knots(0.0, 5.0, 6), random_knots(-3.0, 4.0, 30, 2)] {
            let ys: Vec<f64> = xs.iter().map(|&x| 1.5 - 0.25 * x).collect();
            let s = Spline::new("line", &xs, &ys, SplineEnds::Natural).unwrap();
            for x in probe_points(&xs) {
                assert!((s.eval(0, x) - (1.5 - 0.25 * x)).abs() <= 1e-15 * 8.0);
                assert!((s.eval(1, x) + 0.25).abs() <= 1e-14);
                // Rounding in the slopes, divided by spacings of ~0.2.
                assert!(s.eval(2, x).abs() <= 1e-13, "{} {}", x, s.eval(2, x));
                assert!(s.eval(3, x).abs() <= 1e-12);
            }
            // Arbitrary data: s'' = 0 at both ends.
            let ys = uniform01(xs.len(), 4);
            let s = Spline::new("noise", &xs, &ys, SplineEnds::Natural).unwrap();
            let (lo, hi) = s.domain();
            assert_eq!(s.eval(2, lo), 0.0);
            assert!(s.eval(2, hi).abs() <= 1e-12, "{}", s.eval(2, hi));
        }
    }

    #[test]
    fn value_and_two_derivatives_are_continuous_across_knots() {
        let xs = random_knots(-2.0, 3.0, 40, 8);
        let ys: Vec<f64> = uniform01(xs.len(), 1)
            .iter()
            .map(|u| 4.0 * u - 2.0)
            .collect();
        for kind in [
            SplineEnds::Natural,
            SplineEnds::Clamped {
                left: 3.0,
                right: -1.0,
            },
        ] {
            let s = Spline::new("noise", &xs, &ys, kind).unwrap();
            // Interpolates the samples.
            for (i, (&x, &y)) in xs.iter().zip(&ys).enumerate() {
                assert_eq!(s.eval(0, x), y, "knot {i}");
            }
            for (k, &x) in xs.iter().enumerate().take(xs.len() - 1).skip(1) {
                for deriv in 0..3u8 {
                    let left = s.piece(k - 1, deriv, x);
                    let right = s.piece(k, deriv, x);
                    let scale = 1.0 + left.abs().max(right.abs());
                    assert!(
                        (left - right).abs() <= 1e-11 * scale,
                        "derivative {deriv} jumps at knot {k}: {left} vs {right}"
                    );
                }
            }
            if let SplineEnds::Clamped { left, right } = kind {
                assert!((s.eval(1, xs[0]) - left).abs() <= 1e-12);
                assert!((s.eval(1, xs[xs.len() - 1]) - right).abs() <= 1e-11);
            }
        }
    }

    /// Least-squares slope of log(err) against log(dx).
    fn rate(dx: &[f64], err: &[f64]) -> f64 {
        let lx: Vec<f64> = dx.iter().map(|d| d.ln()).collect();
        let ly: Vec<f64> = err.iter().map(|e| e.ln()).collect();
        let n = lx.len() as f64;
        let (mx, my) = (lx.iter().sum::<f64>() / n, ly.iter().sum::<f64>() / n);
        let sxy: f64 = lx.iter().zip(&ly).map(|(x, y)| (x - mx) * (y - my)).sum();
        let sxx: f64 = lx.iter().map(|x| (x - mx) * (x - mx)).sum();
        sxy / sxx
    }

    #[test]
    fn fput_bond_error_falls_as_dx4_and_slope_error_as_dx3_within_the_bounds() {
        // f(r) = r^2/2 + r^4/4: f' = r + r^3, f'''' = 6.
        let f = |r: f64| r * r / 2.0 + r * r * r * r / 4.0;
        let fp = |r: f64| r + r * r * r;
        let (a, b) = (-1.5, 1.5);
        let mut dxs = Vec::new();
        let (mut e0, mut e1) = (Vec::new(), Vec::new());
        for n in [12usize, 24, 48, 96] {
            let xs = uniform_knots(a, b, n + 1);
            let ys: Vec<f64> = xs.iter().map(|&x| f(x)).collect();
            let kind = SplineEnds::Clamped {
                left: fp(a),
                right: fp(b),
            };
            let s = Spline::new("fput", &xs, &ys, kind).unwrap();
            let (mut m0, mut m1) = (0.0f64, 0.0f64);
            for k in 0..=n * 40 {
                let x = a + (b - a) * k as f64 / (n * 40) as f64;
                m0 = m0.max((s.eval(0, x) - f(x)).abs());
                m1 = m1.max((s.eval(1, x) - fp(x)).abs());
            }
            let dx = (b - a) / n as f64;
            let bound = interpolation_error_bound(6.0, dx);
            assert!(m0 <= bound.value + 1e-15, "dx {dx}: {m0} > {}", bound.value);
            assert!(m1 <= bound.first_derivative + 1e-14, "dx {dx}: {m1}");
            dxs.push(dx);
            e0.push(m0);
            e1.push(m1);
        }
        let (r0, r1) = (rate(&dxs, &e0), rate(&dxs, &e1));
        assert!((r0 - 4.0).abs() <= 0.3, "value error ~ dx^{r0}: {e0:?}");
        assert!((r1 - 3.0).abs() <= 0.3, "slope error ~ dx^{r1}: {e1:?}");
    }

    #[test]
    fn nan_outside_the_table() {
        let xs = uniform_knots(0.0, 1.0, 5);
        let s = Spline::new("t", &xs, &[0.0, 1.0, 0.0, 1.0, 0.0], SplineEnds::Natural).unwrap();
        for deriv in 0..4 {
            assert!(s.eval(deriv, -1e-12).is_nan());
            assert!(s.eval(deriv, 1.0 + 1e-12).is_nan());
            assert!(s.eval(deriv, f64::NAN).is_nan());
            assert!(s.eval(deriv, f64::INFINITY).is_nan());
            assert!(s.eval(deriv, 0.0).is_finite());
            assert!(s.eval(deriv, 1.0).is_finite());
        }
        assert_eq!(s.eval(0, 1.0), 0.0);
        assert!(s.eval(4, 0.5).is_nan());
        assert_eq!(s.name(), "t");
    }

    #[test]
    fn uniform_lookup_agrees_with_binary_search() {
        let xs: Vec<f64> = (0..=1000).map(|i| -1.0 + 0.002 * i as f64).collect();
        let ys: Vec<f64> = xs.iter().map(|x| (3.0 * x).sin()).collect();
        let fast = Spline::new("u", &xs, &ys, SplineEnds::Natural).unwrap();
        assert!(fast.inv_spacing.is_some());
        let mut slow = fast.clone();
        slow.inv_spacing = None;
        let mut probes = probe_points(&xs);
        probes.extend(uniform01(5000, 3).iter().map(|u| -1.0 + 2.0 * u));
        for x in probes {
            assert_eq!(fast.interval(x), slow.interval(x), "at {x}");
            let i = fast.interval(x).unwrap();
            assert!(xs[i] <= x && (x < xs[i + 1] || i == xs.len() - 2));
        }
        let nonuniform = Spline::new(
            "n",
            &random_knots(0.0, 1.0, 9, 1),
            &[0.0; 9],
            SplineEnds::Natural,
        );
        assert!(nonuniform.unwrap().inv_spacing.is_none());
    }

    #[test]
    fn spline_rejects_bad_samples() {
        let ok = [0.0, 1.0, 2.0, 3.0];
        let msg =
            |xs: &[f64], ys: &[f64], kind| Spline::new("t", xs, ys, kind).unwrap_err().to_string();
        assert!(msg(&ok, &ok[..3], SplineEnds::Natural).contains("4 x values but 3"));
        assert!(msg(&ok[..3], &ok[..3], SplineEnds::Natural).contains("at least 4"));
        assert!(msg(&[0.0, 1.0, 1.0, 3.0], &ok, SplineEnds::Natural).contains("not greater"));
        assert!(msg(&ok, &[0.0, f64::NAN, 0.0, 0.0], SplineEnds::Natural).contains("not finite"));
        let inf = SplineEnds::Clamped {
            left: f64::INFINITY,
            right: 0.0,
        };
        assert!(msg(&ok, &ok, inf).contains("slopes must be finite"));
    }

    fn err(text: &str) -> String {
        parse_csv(text, "pot.csv").unwrap_err().to_string()
    }

    #[test]
    fn csv_formats() {
        let want = TableData {
            xs: vec![0.0, 0.5, 1.0, 1.5],
            ys: vec![1.0, -2.0, 3e-3, 4.0],
            digest: [0; 32],
        };
        for text in [
            "x, V\n0, 1\n0.5, -2\n1.0, 3e-3\n1.5, 4\n",
            "# a table\n\nx;V\n0;1\n0.5;-2 # inline comment\n\n1.0;3e-3\n1.5;+4",
            "0 1\r\n0.5\t-2\r\n  1.0   3e-3\r\n1.5 4\r\n",
            "r,potential\n0,1\n0.5,-2\n1.0,0.003\n1.5,4.0\n#end\n",
            "\u{feff}0,1\n0.5,-2\n1.0,0.003\n1.5,4.0\n",
        ] {
            let d = parse_csv(text, "pot.csv").unwrap();
            assert_eq!((&d.xs, &d.ys), (&want.xs, &want.ys), "{text:?}");
            assert_eq!(d.digest, <[u8; 32]>::from(Sha256::digest(text.as_bytes())));
        }
    }

    #[test]
    fn csv_digest_is_sha256_of_the_bytes() {
        let text = "0,0\n1,1\n2,4\n3,9\n";
        let d = parse_csv(text, "t").unwrap();
        // Computed independently: printf '0,0\n1,1\n2,4\n3,9\n' | sha256sum
        assert_eq!(
            d.digest_hex(),
            "f3d736ab2bbdb2515bbdce4c6d49527063ad5c4cade2760a25cf488fca7f655a"
        );
        // Same numbers, different bytes: a different table for a replay.
        let d2 = parse_csv("0,0\n1,1\n2,4\n3,9.0\n", "t").unwrap();
        assert_eq!(d.xs, d2.xs);
        assert_ne!(d.digest, d2.digest);
    }

    #[test]
    fn csv_errors_name_the_file_and_line() {
        assert_eq!(
            err(""),
            "pot.csv: no samples (the file is empty or holds only comments and a header)"
        );
        assert!(err("# only\n\nx,V\n").contains("no samples"));
        assert_eq!(
            err("x,V\n0,1\n1,2\n2,3\n"),
            "pot.csv: 3 sample(s), but a cubic spline needs at least 4: is the file truncated?"
        );
        assert_eq!(
            err("0,1\n1,2\n2,3,4\n3,4\n"),
            "pot.csv: line 3: 3 column(s), expected 2 (`x, V`, separated by a comma, a semicolon or whitespace)"
        );
        assert!(err("0 1\n1\n2 3\n3 4\n").starts_with("pot.csv: line 2: 1 column(s)"));
        assert!(err("x,V,W\n0,1\n").starts_with("pot.csv: line 1: 3 column(s)"));
        assert_eq!(
            err("0,1\n1,2\n2,abc\n3,4\n"),
            "pot.csv: line 3: `abc` in column 2 is not a number"
        );
        // A header is only allowed before the data.
        assert_eq!(
            err("0,1\nx,V\n"),
            "pot.csv: line 2: `x` in column 1 is not a number"
        );
        assert_eq!(
            err("0,1\n1,\n"),
            "pot.csv: line 2: `` in column 2 is not a number"
        );
        assert_eq!(
            err("0,1\n1,inf\n"),
            "pot.csv: line 2: `inf` in column 2 is not finite"
        );
        assert_eq!(
            err("0,1\nNaN,2\n"),
            "pot.csv: line 2: `NaN` in column 1 is not finite"
        );
        assert!(err("0,1\n1e400,2\n").contains("`1e400` in column 1 is not finite"));
        let mut text = String::from("# x, V\n");
        for i in 1..=15 {
            text.push_str(&format!("{},{}\n", i as f64 * 0.02, i));
        }
        text.push_str("0.3,1\n");
        assert_eq!(
            err(&text),
            "pot.csv: line 17: x = 0.3 is not greater than the previous x = 0.3: samples must be sorted by x with no repeats"
        );
        assert!(
            err("0,1\n2,1\n1,1\n3,1\n")
                .contains("line 3: x = 1 is not greater than the previous x = 2")
        );
        let many: String = (0..=MAX_SAMPLES).map(|i| format!("{i} 0\n")).collect();
        assert!(err(&many).contains(&format!("more than {MAX_SAMPLES} samples")));
    }

    #[test]
    fn csv_file_errors() {
        let dir = tempfile::tempdir().unwrap();
        let missing = dir.path().join("missing.csv");
        let e = read_csv(&missing).unwrap_err();
        assert!(matches!(e, TableError::NotFound { .. }));
        assert_eq!(
            e.to_string(),
            format!("table file `{}` does not exist", missing.display())
        );

        // A directory opens but does not read.
        let e = read_csv(dir.path()).unwrap_err();
        assert!(matches!(e, TableError::Unreadable { .. }), "{e:?}");
        assert!(e.to_string().starts_with("cannot read table file"));

        let big = dir.path().join("big.csv");
        std::fs::File::create(&big)
            .unwrap()
            .set_len(MAX_FILE_BYTES + 1)
            .unwrap();
        let e = read_csv(&big).unwrap_err();
        assert!(
            e.to_string().contains("is larger than 67108864 bytes"),
            "{e}"
        );

        let latin1 = dir.path().join("latin1.csv");
        std::fs::write(&latin1, b"x,V\n0,1\n1,2 # \xb5m\n2,3\n3,4\n").unwrap();
        let e = read_csv(&latin1).unwrap_err().to_string();
        assert!(
            e.ends_with("line 3: not UTF-8 text: a table is a text file of two numeric columns"),
            "{e}"
        );

        let good = dir.path().join("good.csv");
        let bytes = b"x,V\n0,1\n1,2\n2,3\n3,5\n";
        std::fs::write(&good, bytes).unwrap();
        let d = read_csv(&good).unwrap();
        assert_eq!(d.ys, [1.0, 2.0, 3.0, 5.0]);
        assert_eq!(d.digest, <[u8; 32]>::from(Sha256::digest(bytes)));
        let bad = dir.path().join("bad.csv");
        std::fs::write(&bad, b"x,V\n0,1\n1,2\n1,3\n").unwrap();
        let e = read_csv(&bad).unwrap_err().to_string();
        assert!(
            e.starts_with(&format!("{}: line 4: x = 1", bad.display())),
            "{e}"
        );
        // A spline straight from the file's samples.
        let s = Spline::from_table("good", &d, SplineEnds::Natural).unwrap();
        assert_eq!(s.eval(0, 3.0), 5.0);
        assert_eq!(s.knots(), &d.xs[..]);
    }
}
