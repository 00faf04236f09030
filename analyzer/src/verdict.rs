//! The verdict a newcomer can read: per scheme, is the orbit chaotic, regular (on a torus of
//! which dimension) or undecided at this time, by which criterion and with what confidence; and
//! warnings when the settings or the values leave the region where the indicators are reliable
//! (Many Manda, Hillebrand, Skokos: the error analysis of GALI by VM and MPM).
//!
//! Sans-io and pure: a function of what the analysis already keeps per scheme (its curve of
//! geometric-mean GALI_j and finite-time MLE, the scheme's settings, the energy error).
//!
//! # Criteria
//!
//! The laws (Skokos, Bountis, Antonopoulos 2007, 2008; recalled in the paper, Sect. 2):
//! - chaotic orbit: `GALI_j ~ exp(-(sum_{i=2..j} (l1 - l_i)) t)`, and the finite-time MLE tends
//!   to `l1 > 0`, so the log-stretch `S(t) = t X1(t)` grows linearly in t;
//! - regular orbit on an s-torus (N degrees of freedom): `GALI_j` constant for `j <= s`,
//!   `~ t^-(j-s)` for `s < j <= 2N-s`, `~ t^-2(j-N)` for `j > 2N-s`, and the deviation vectors
//!   grow linearly, so `S(t) ~ ln t` (the finite-time MLE decays like `ln(t)/t`).
//!
//! In a window `[t1, t2]`, the log-log slope `p_j = -d log10 GALI_j / d log10 t` is therefore an
//! integer of the pattern above on a regular orbit (the steepest being `2(j-1)`), and on a
//! chaotic one it grows like `t` (`p_j ~ rate_j * t`); `S(t2) - S(t1)` is at most `~ ln(t2/t1)`
//! (plus the orbit's oscillation) on a regular orbit and `l1 (t2 - t1)` on a chaotic one.
//!
//! - **chaotic** needs both, each seen in some window `[t'/2, t']`, `t' <= t` (once seen, the
//!   evidence stays in the curve: chaos does not undo itself, and a GALI at the floor later
//!   does not erase it; a regular orbit shows neither in any window):
//!   1. MLE: `S(t') - S(t'/2) >= 5` e-folds: the deviation grew over `[t'/2, t']` by `e^5 ~ 150`
//!      where the linear growth of a regular orbit gives `e^ln2 = 2`;
//!   2. GALI: some `GALI_j` away from the rounding floor decayed with a log-log slope
//!      `p_j >= 2(j-1) + 2`, steeper than any power law of a regular orbit, so an exponential.
//! - **regular** needs all of:
//!   1. at least 100 renormalizations (the vectors' early alignment is a transient in which a
//!      chaotic orbit's GALIs can pass for power laws: the HH chaotic orbit at t ~ 25 shows
//!      slopes 0.5, 2.0, 4.0 over [8, 25]);
//!   2. over the last decade `[t/10, t]`, the exponents `p_j` of the GALI_j away from the floor
//!      are within `0.7` of the pattern of some torus dimension `2 <= s <= N`; a chaotic orbit
//!      cannot match it: with `k = 2N`, `p_N ~ l1 t <= 0.7` forces `p_2N = 2N l1 t <= 1.4 N`,
//!      short of `2N - 0.7`;
//!   3. at least one of them decays (`p_j >= 1`): constant GALIs alone are also what a chaotic
//!      orbit shows before its first Lyapunov time, a power law with the torus' exponent is not
//!      (so `k > s` is needed: with `k = 2` a torus is never claimed);
//!   4. the steepest does not steepen more than twofold from `[t/10, t/3.2]` to `[t/3.2, t]`
//!      (an exponential's log-log slope grows 3.2-fold);
//!   5. MLE: `S(t) - S(t/10) <= 2 ln 10 + 2`: no more than linear growth (allowing quadratic,
//!      and the oscillation along the orbit).
//!
//!   The torus dimension is the `s` whose pattern the exponents match within `0.35`, when
//!   exactly one does (`None` otherwise: the orbit's GALIs may still be crossing over).
//! - otherwise **undecided**. Schemes with QR orthonormalization re-orthonormalize the vectors at
//!   every renormalization, so their GALI does not accumulate: they are called chaotic by the
//!   MLE alone at twice the threshold (10 e-folds), and never regular.
//!
//! # Confidence
//!
//! `0` for undecided. For a decided verdict, `1 - 0.5 / x` where `x >= 1` is the weakest
//! criterion's evidence over its threshold (for chaotic: the largest `(S(t') - S(t'/2)) / 5`
//! and `p_j / (2(j-1) + 2)`; for regular: the MLE bound over `S(t) - S(t/10)` and `0.7` over
//! the largest exponent mismatch), capped at 10: `0.5` at the threshold, `0.75` at twice it,
//! `0.95` at ten times. It is halved when a settings warning applies (d0, tau, energy error):
//! the verdict then rests on values the paper does not vouch for.

use serde::Serialize;

use chaoscope_schemas::run::{Method, Orthonormalization};

use crate::series::SchemePoint;

/// What the orbit is, at this time.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Class {
    Chaotic,
    Regular,
    Undecided,
}

impl Class {
    pub fn word(self) -> &'static str {
        match self {
            Class::Chaotic => "chaotic",
            Class::Regular => "regular",
            Class::Undecided => "undecided",
        }
    }
}

/// The verdict on one scheme's view of the orbit.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Verdict {
    pub class: Class,
    /// Dimension `s` of the torus of a regular orbit, when the GALI pattern fixes it.
    pub torus_dimension: Option<usize>,
    /// The criterion used, with its numbers, in words.
    pub criterion: String,
    /// In [0, 1]; see the module documentation.
    pub confidence: f64,
}

/// A setting or value outside the region where the indicators are reliable.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Warning {
    /// Stable identifier: one of [`D0_FAR_FROM_SQRT_EPS`], [`TAU_ABOVE_ONE`],
    /// [`ENERGY_ERROR_ABOVE_SQRT_EPS`], [`GALI_AT_ROUNDING_FLOOR`].
    pub code: String,
    pub message: String,
}

pub const D0_FAR_FROM_SQRT_EPS: &str = "d0_far_from_sqrt_eps";
pub const TAU_ABOVE_ONE: &str = "tau_above_one";
pub const ENERGY_ERROR_ABOVE_SQRT_EPS: &str = "energy_error_above_sqrt_eps";
pub const GALI_AT_ROUNDING_FLOOR: &str = "gali_at_rounding_floor";

/// Double-precision rounding unit.
pub const EPS: f64 = f64::EPSILON;
/// Decades between an MPM `d0` and `eps^(1/2)` beyond which it is far from optimal: the paper's
/// V-shapes (Figs. 5, 10) are flat within about a decade of 1e-8 and off by orders of magnitude
/// at 1e-5 and 1e-11.
pub const D0_DECADES: f64 = 2.0;

/// e-folds of growth of the log-stretch over `[t/2, t]` for the MLE criterion of chaos.
const CHAOS_STRETCH: f64 = 5.0;
/// Exponent margin beyond the steepest power law of a regular orbit.
const CHAOS_SLOPE_MARGIN: f64 = 2.0;
/// Tolerance on a power-law exponent of a regular orbit.
const REGULAR_TOL: f64 = 0.7;
/// Largest ratio of the log-log slopes of the later to the earlier half-decade on a regular
/// orbit (an exponential gives sqrt(10) ~ 3.2).
const MAX_ACCELERATION: f64 = 2.0;
/// The torus dimension is given when the exponents match its pattern this closely.
const DIMENSION_TOL: f64 = 0.35;
/// Renormalizations before a regular verdict: the vectors' early alignment is a transient, in
/// which a chaotic orbit's GALIs can pass for power laws (HH chaotic at t ~ 25).
const MIN_REGULAR_RENORMALIZATIONS: f64 = 100.0;
/// Least points in a fitted window.
const MIN_POINTS: usize = 5;
/// The thinned curve keeps points at least this factor apart in time (about 40 per decade).
const THIN_FACTOR: f64 = 1.059;

/// What the verdict needs to know of a scheme.
#[derive(Debug, Clone, PartialEq)]
pub struct Settings {
    pub method: Method,
    pub orthonormalize: Orthonormalization,
    pub d0: f64,
    pub tau: f64,
    /// Degrees of freedom N.
    pub dof: usize,
    /// Deviation vectors k (GALI orders 2..=k).
    pub k: usize,
}

impl Settings {
    /// log10 of the rounding floor of one factor of GALI (the height of a vector over the span
    /// of the previous ones): `eps` for VM (unit vectors), `eps / d0` for MPM (a separation is a
    /// difference of two states of size ~1, known to `eps`). One decade of margin above it.
    pub fn floor_log10(&self) -> f64 {
        let floor = match self.method {
            Method::Vm => EPS,
            Method::Mpm => EPS / self.d0.min(1.0),
        };
        floor.log10() + 1.0
    }
}

/// A point of the curve: time, `log10 GALI_j` (`[j - 2]`, geometric means over sets), MLE.
#[derive(Debug, Clone, Copy)]
struct Pt<'a> {
    t: f64,
    gali: &'a [f64],
    /// Log-stretch `t * X1(t)`.
    stretch: f64,
}

impl Pt<'_> {
    /// Orders `j` whose GALI is away from the floor: every factor `GALI_i / GALI_(i-1)`,
    /// `i <= j`, above it. Returns the highest such `j` (1 if none).
    fn top_usable(&self, floor: f64) -> usize {
        let mut prev = 0.0;
        let mut top = 1;
        for (o, &g) in self.gali.iter().enumerate() {
            if !g.is_finite() || g - prev < floor {
                break;
            }
            prev = g;
            top = o + 2;
        }
        top
    }
}

/// Least-squares slope of `y` on `x`, and the root-mean-square residual.
fn fit(xy: impl Iterator<Item = (f64, f64)> + Clone) -> Option<(f64, f64)> {
    let (mut n, mut sx, mut sy) = (0.0, 0.0, 0.0);
    for (x, y) in xy.clone() {
        n += 1.0;
        sx += x;
        sy += y;
    }
    if n < 2.0 {
        return None;
    }
    let (mx, my) = (sx / n, sy / n);
    let (mut sxx, mut sxy) = (0.0, 0.0);
    for (x, y) in xy.clone() {
        sxx += (x - mx) * (x - mx);
        sxy += (x - mx) * (y - my);
    }
    if sxx <= 0.0 {
        return None;
    }
    let slope = sxy / sxx;
    let ss: f64 = xy
        .map(|(x, y)| (y - my - slope * (x - mx)).powi(2))
        .sum::<f64>();
    Some((slope, (ss / n).sqrt()))
}

/// Exponent of `GALI_j` on a regular orbit on an s-torus of a system with N degrees of freedom.
pub fn torus_exponent(j: usize, s: usize, n: usize) -> usize {
    if j <= s {
        0
    } else if j + s <= 2 * n {
        j - s
    } else {
        2 * (j - n)
    }
}

/// Log-spaced points per decade of the curve the analysis keeps for the verdict.
pub const PER_DECADE: usize = 40;

/// The curve thinned to about 40 points per decade (always keeping the latest), positive times.
fn thin<'a>(curve: &[(f64, &'a SchemePoint)]) -> Vec<Pt<'a>> {
    let mut out: Vec<Pt<'a>> = Vec::new();
    let n = curve.len();
    for (i, (t, p)) in curve.iter().enumerate() {
        let t = *t;
        if t <= 0.0 {
            continue;
        }
        let keep = i + 1 == n || out.last().is_none_or(|l| t >= l.t * THIN_FACTOR);
        if keep {
            out.push(Pt {
                t,
                gali: &p.gali_log10_mean,
                stretch: t * p.lyapunov.first().copied().unwrap_or(0.0),
            });
        }
    }
    out
}

/// Index of the last point with `t <= x`.
fn at_or_before(pts: &[Pt], x: f64) -> Option<usize> {
    pts.iter().rposition(|p| p.t <= x)
}

/// Log-log exponent `p_j` of order `j` over `pts` (all usable), or `None` when too few points.
fn exponent(pts: &[Pt], j: usize) -> Option<(f64, f64)> {
    if pts.len() < MIN_POINTS {
        return None;
    }
    fit(pts.iter().map(|p| (p.t.log10(), p.gali[j - 2]))).map(|(s, r)| (-s, r))
}

fn usable_top(pts: &[Pt], floor: f64) -> usize {
    pts.iter().map(|p| p.top_usable(floor)).min().unwrap_or(1)
}

/// A time for the criterion text: up to three decimals, trailing zeros dropped.
fn time(t: f64) -> String {
    let s = format!("{t:.3}");
    s.trim_end_matches('0').trim_end_matches('.').to_string()
}

fn confidence(x: f64) -> f64 {
    1.0 - 0.5 / x.clamp(1.0, 10.0)
}

/// The verdict from a scheme's curve (time order, ending with the latest sample).
pub fn verdict(settings: &Settings, curve: &[(f64, &SchemePoint)]) -> Verdict {
    let undecided = |criterion: String| Verdict {
        class: Class::Undecided,
        torus_dimension: None,
        criterion,
        confidence: 0.0,
    };
    let pts = thin(curve);
    if pts.is_empty() {
        return undecided("no samples after t = 0 yet".into());
    }
    let floor = settings.floor_log10();
    let qr = settings.orthonormalize == Orthonormalization::Qr;
    let chaos_stretch = if qr {
        2.0 * CHAOS_STRETCH
    } else {
        CHAOS_STRETCH
    };
    let mle = curve
        .last()
        .and_then(|(_, p)| p.lyapunov.first().copied())
        .unwrap_or(0.0);

    // Chaotic: both evidences, each seen in some window up to now (chaos does not undo itself;
    // a regular orbit shows neither in any window).
    let mle_window = stretch_growth(&pts, chaos_stretch);
    if let Some((ds, t_mle)) = mle_window {
        let mle_text = format!(
            "the deviation grew by e^{ds:.1} over [{}, {}] (now MLE {mle:.3e}; a regular orbit \
             grows linearly, e^0.7 per doubling of time, its MLE decays ~ ln(t)/t)",
            time(t_mle / 2.0),
            time(t_mle)
        );
        if qr {
            return Verdict {
                class: Class::Chaotic,
                torus_dimension: None,
                criterion: format!("{mle_text}; QR scheme: MLE alone, at twice the threshold"),
                confidence: confidence(ds / chaos_stretch),
            };
        }
        if let Some((j, p, t_end)) = exponential_decay(&pts, floor, settings.k) {
            let x = (ds / chaos_stretch).min(p / (2.0 * (j - 1) as f64 + CHAOS_SLOPE_MARGIN));
            return Verdict {
                class: Class::Chaotic,
                torus_dimension: None,
                criterion: format!(
                    "{mle_text}; GALI_{j} decayed faster than any power law of a regular orbit \
                     (log-log slope -{p:.1} over [{}, {}], regular orbits at most -{})",
                    time(t_end / 2.0),
                    time(t_end),
                    2 * (j - 1)
                ),
                confidence: confidence(x),
            };
        }
        return undecided(format!(
            "{mle_text}, but no GALI has decayed faster than a power law yet"
        ));
    }
    if qr {
        return undecided(
            "QR scheme: its GALI does not accumulate, and the MLE has not grown exponentially \
             (yet)"
                .into(),
        );
    }

    // Regular.
    match regular(settings, &pts, floor) {
        Ok(v) => v,
        Err(why) => undecided(why),
    }
}

/// The largest growth of the log-stretch over a window `[t'/2, t']` of at least
/// [`MIN_POINTS`] points, if it reaches `threshold`: (growth, t').
fn stretch_growth(pts: &[Pt], threshold: f64) -> Option<(f64, f64)> {
    let mut best: Option<(f64, f64)> = None;
    for end in MIN_POINTS..pts.len() {
        let t_end = pts[end].t;
        let Some(start) = at_or_before(pts, t_end / 2.0) else {
            continue;
        };
        if end - start + 1 < MIN_POINTS {
            continue;
        }
        let ds = pts[end].stretch - pts[start].stretch;
        if ds >= threshold && best.is_none_or(|b| ds > b.0) {
            best = Some((ds, t_end));
        }
    }
    best
}

/// The steepest evidence of exponential decay in some window `[t'/2, t']`: (order, exponent,
/// t') with the largest ratio of exponent to the regular bound `2(j-1) + margin`.
fn exponential_decay(pts: &[Pt], floor: f64, k: usize) -> Option<(usize, f64, f64)> {
    let mut best: Option<(usize, f64, f64, f64)> = None;
    for end in 0..pts.len() {
        let t_end = pts[end].t;
        let Some(start) = pts.iter().position(|p| p.t >= t_end / 2.0) else {
            continue;
        };
        let w = &pts[start..=end];
        let top = usable_top(w, floor).min(k);
        for j in 2..=top {
            let Some((p, _)) = exponent(w, j) else {
                continue;
            };
            let bound = 2.0 * (j - 1) as f64 + CHAOS_SLOPE_MARGIN;
            if p >= bound && best.is_none_or(|b| p / bound > b.3) {
                best = Some((j, p, t_end, p / bound));
            }
        }
    }
    best.map(|(j, p, t, _)| (j, p, t))
}

fn regular(settings: &Settings, pts: &[Pt], floor: f64) -> Result<Verdict, String> {
    let last = *pts.last().expect("non-empty");
    let t = last.t;
    let n = settings.dof;
    let split = t / 10f64.sqrt();
    let (Some(a), Some(b)) = (
        pts.iter().position(|p| p.t >= t / 10.0),
        pts.iter().position(|p| p.t >= split),
    ) else {
        return Err("too early for a power law over a decade of time".into());
    };
    let (w1, w2) = (&pts[a..b], &pts[b..]);
    if w1.len() < MIN_POINTS || w2.len() < MIN_POINTS {
        return Err("too early for a power law over a decade of time".into());
    }
    let top = usable_top(&pts[a..], floor).min(settings.k);
    if top < 2 {
        return Err("GALI_2 is at the rounding floor".into());
    }
    let (mut p1, mut p2, mut pd) = (Vec::new(), Vec::new(), Vec::new());
    for j in 2..=top {
        let (Some((x1, _)), Some((x2, _)), Some((xd, _))) =
            (exponent(w1, j), exponent(w2, j), exponent(&pts[a..], j))
        else {
            return Err("too few points for a power law".into());
        };
        p1.push(x1);
        p2.push(x2);
        pd.push(xd);
    }
    let fmt = |v: &[f64]| {
        v.iter()
            .map(|x| format!("{:.1}", -x))
            .collect::<Vec<_>>()
            .join(", ")
    };
    // Torus dimensions whose pattern the decade matches within REGULAR_TOL.
    let mut matches = Vec::new();
    for s in 2..=n.max(2) {
        let dev = (2..=top)
            .enumerate()
            .map(|(i, j)| (pd[i] - torus_exponent(j, s, n) as f64).abs())
            .fold(0.0f64, f64::max);
        if dev <= REGULAR_TOL {
            matches.push((s, dev));
        }
    }
    // No acceleration: an exponential triples its log-log slope from one half-decade to the
    // next, a power law keeps it.
    let (steep, &p_steep) = pd
        .iter()
        .enumerate()
        .max_by(|a, b| a.1.total_cmp(b.1))
        .expect("at least GALI_2");
    if p_steep >= 1.0 && p2[steep] > MAX_ACCELERATION * p1[steep].max(0.5) {
        return Err(format!(
            "GALI_{} steepens from t^-{:.1} over [t/10, t/3.2] to t^-{:.1} over [t/3.2, t]: \
             not a steady power law",
            steep + 2,
            p1[steep],
            p2[steep]
        ));
    }
    if t < MIN_REGULAR_RENORMALIZATIONS * settings.tau {
        return Err(format!(
            "too early: a regular verdict needs t >= {MIN_REGULAR_RENORMALIZATIONS} tau"
        ));
    }
    if matches.is_empty() {
        return Err(format!(
            "GALI_2..{top} log-log slopes over [t/10, t/3.2], [t/3.2, t] and [t/10, t]: ({}), \
             ({}), ({}) match no torus pattern",
            fmt(&p1),
            fmt(&p2),
            fmt(&pd)
        ));
    }
    if pd.iter().all(|&p| p < 1.0) {
        return Err(format!(
            "GALI_2..{top} stay constant (slopes {}): consistent with a torus of dimension >= \
             {top}, but also with chaos before its first Lyapunov time; no GALI decays by a \
             power law (k = 2N vectors decide)",
            fmt(&pd)
        ));
    }
    let ds = last.stretch - pts[a].stretch;
    let bound = 2.0 * 10f64.ln() + 2.0;
    if ds > bound {
        return Err(format!(
            "GALI power laws, but the deviation grew by e^{ds:.1} over [t/10, t], more than \
             the linear growth of a regular orbit"
        ));
    }
    let worst = matches.iter().map(|m| m.1).fold(f64::INFINITY, f64::min);
    let torus_dimension =
        (matches.len() == 1 && matches[0].1 <= DIMENSION_TOL).then(|| matches[0].0);
    let dim_text = match torus_dimension {
        Some(s) => format!("the exponents of a {s}-torus"),
        None => format!(
            "the exponents of a torus within {worst:.2} (its dimension is fixed when they are \
             within {DIMENSION_TOL} of one torus' integers)"
        ),
    };
    let x = (bound / ds.max(1e-9)).min(REGULAR_TOL / worst.max(1e-9));
    Ok(Verdict {
        class: Class::Regular,
        torus_dimension,
        criterion: format!(
            "GALI_2..{top} follow power laws t^({}) over [t/10, t], {dim_text}; the deviation \
             grew by e^{ds:.1} over [t/10, t] (linear growth, MLE ~ ln(t)/t)",
            fmt(&pd)
        ),
        confidence: confidence(x),
    })
}

/// Warnings for a scheme: settings outside the paper's reliable region, and GALIs at the
/// rounding floor (from the latest point of the curve).
pub fn warnings(
    settings: &Settings,
    energy_error_max: f64,
    latest: Option<&SchemePoint>,
    verdict: &Verdict,
) -> Vec<Warning> {
    let mut out = Vec::new();
    let sqrt_eps = EPS.sqrt();
    if settings.method == Method::Mpm && (settings.d0 / sqrt_eps).log10().abs() > D0_DECADES {
        out.push(Warning {
            code: D0_FAR_FROM_SQRT_EPS.into(),
            message: format!(
                "MPM d0 = {:.0e} is more than {D0_DECADES} decades from eps^(1/2) ~ 1.5e-8: the \
                 MPM error O((d0 tau)^k) + O((eps/d0)^k) is smallest near d0 ~ 1e-8",
                settings.d0
            ),
        });
    }
    if settings.method == Method::Mpm && settings.tau > 1.0 {
        out.push(Warning {
            code: TAU_ABOVE_ONE.into(),
            message: format!(
                "MPM tau = {} above 1: the error grows like (d0 tau^2)^k and the paper finds \
                 GALI values roughen and grow for tau > 1; use tau <= 1",
                settings.tau
            ),
        });
    }
    if energy_error_max > sqrt_eps {
        out.push(Warning {
            code: ENERGY_ERROR_ABOVE_SQRT_EPS.into(),
            message: format!(
                "relative energy error {energy_error_max:.1e} above eps^(1/2) ~ 1.5e-8: the \
                 integration error dominates GALI (the paper: E_r <= 1e-8); use a smaller h"
            ),
        });
    }
    if let Some(p) = latest
        && verdict.class != Class::Chaotic
    {
        let pt = Pt {
            t: 0.0,
            gali: &p.gali_log10_mean,
            stretch: 0.0,
        };
        let top = pt.top_usable(settings.floor_log10());
        let k = p.gali_log10_mean.len() + 1;
        if top < k {
            let orders = if top + 1 == k {
                format!("GALI_{k} is")
            } else {
                format!("GALI_{}..{k} are", top + 1)
            };
            out.push(Warning {
                code: GALI_AT_ROUNDING_FLOOR.into(),
                message: format!(
                    "{orders} at the rounding floor (a factor below {:.0e}, the {} precision of \
                     a separation): their values are not meaningful",
                    10f64.powf(settings.floor_log10()),
                    match settings.method {
                        Method::Vm => "eps",
                        Method::Mpm => "eps/d0",
                    }
                ),
            });
        }
    }
    out
}

/// Whether a warning is about the settings (lowers the confidence) rather than the values.
pub fn is_settings_warning(w: &Warning) -> bool {
    w.code != GALI_AT_ROUNDING_FLOOR
}

/// The verdict with its confidence lowered by the settings warnings that apply, and the
/// warnings.
pub fn assess(
    settings: &Settings,
    curve: &[(f64, &SchemePoint)],
    energy_error_max: f64,
) -> (Verdict, Vec<Warning>) {
    let mut v = verdict(settings, curve);
    let w = warnings(
        settings,
        energy_error_max,
        curve.last().map(|(_, p)| *p),
        &v,
    );
    if w.iter().any(is_settings_warning) {
        v.confidence *= 0.5;
    }
    (v, w)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn settings(method: Method, d0: f64, tau: f64, dof: usize, k: usize) -> Settings {
        Settings {
            method,
            orthonormalize: Orthonormalization::Rescale,
            d0,
            tau,
            dof,
            k,
        }
    }

    /// A curve at t = 1, 2, .. t_final from per-order log10 GALI and the MLE as functions of t.
    fn curve(
        t_final: usize,
        k: usize,
        gali: impl Fn(usize, f64) -> f64,
        mle: impl Fn(f64) -> f64,
    ) -> Vec<(f64, SchemePoint)> {
        (0..=t_final)
            .map(|i| {
                let t = i as f64;
                (
                    t,
                    SchemePoint {
                        gali_log10_mean: (2..=k).map(|j| gali(j, t)).collect(),
                        gali_log10_of_mean: Vec::new(),
                        sali_log10_mean: None,
                        lyapunov: vec![mle(t)],
                        vs_vm_abs_delta: None,
                    },
                )
            })
            .collect()
    }

    fn judge(s: &Settings, c: &[(f64, SchemePoint)]) -> Verdict {
        let refs: Vec<(f64, &SchemePoint)> = c.iter().map(|(t, p)| (*t, p)).collect();
        verdict(s, &refs)
    }

    #[test]
    fn torus_exponents_are_the_skokos_pattern() {
        // N = 2 on a 2-torus: GALI_2 constant, GALI_3 ~ t^-2, GALI_4 ~ t^-4.
        let hh: Vec<usize> = (2..=4).map(|j| torus_exponent(j, 2, 2)).collect();
        assert_eq!(hh, [0, 2, 4]);
        // FPUT N = 5 regular orbit (paper): GALI_2, 4 constant, GALI_6, 8, 10 ~ t^-2, -6, -10,
        // which a 4-torus (and a 5-torus) gives.
        let s4: Vec<usize> = (2..=10).map(|j| torus_exponent(j, 4, 5)).collect();
        assert_eq!(s4, [0, 0, 0, 1, 2, 4, 6, 8, 10]);
        let s5: Vec<usize> = (2..=10).map(|j| torus_exponent(j, 5, 5)).collect();
        assert_eq!(s5, [0, 0, 0, 0, 2, 4, 6, 8, 10]);
    }

    #[test]
    fn power_laws_with_linear_growth_are_regular_on_their_torus() {
        let s = settings(Method::Vm, 1e-8, 1.0, 2, 4);
        let c = curve(
            2000,
            4,
            |j, t| -0.3 - (torus_exponent(j, 2, 2) as f64) * t.max(1.0).log10(),
            |t| (1.0 + 0.5 * t).ln() / t.max(1.0),
        );
        let v = judge(&s, &c);
        assert_eq!(v.class, Class::Regular, "{v:?}");
        assert_eq!(v.torus_dimension, Some(2));
        assert!(v.confidence > 0.5 && v.confidence < 1.0);
        // Too early for a decade of power law after 100 renormalizations.
        let v = judge(&s, &c[..60]);
        assert_eq!(v.class, Class::Undecided, "{v:?}");
    }

    #[test]
    fn exponential_decay_with_a_positive_mle_is_chaotic_and_stays_so_at_the_floor() {
        let s = settings(Method::Vm, 1e-8, 1.0, 2, 4);
        let l1 = 0.05;
        // GALI_j ~ exp(-(j-1) l1 t) down to the floor of each factor.
        let gali = |j: usize, t: f64| {
            (2..=j)
                .map(|_| (-l1 * t / 10f64.ln()).max(-15.6))
                .sum::<f64>()
        };
        let c = curve(1500, 4, gali, |_| l1);
        let v = judge(&s, &c);
        assert_eq!(v.class, Class::Chaotic, "{v:?}");
        assert!(v.confidence > 0.5);
        // Early (a few Lyapunov times): undecided.
        let v = judge(&s, &c[..40]);
        assert_eq!(v.class, Class::Undecided, "{v:?}");
        // A positive MLE alone (GALI constant) is not enough.
        let c = curve(1500, 4, |_, _| -0.5, |_| l1);
        assert_eq!(judge(&s, &c).class, Class::Undecided);
    }

    #[test]
    fn constant_gali_alone_is_not_regular() {
        // With k <= s nothing decays: also what chaos looks like before its Lyapunov time.
        let s = settings(Method::Vm, 1e-8, 1.0, 5, 3);
        let c = curve(3000, 3, |_, _| -0.4, |t| (1.0 + t).ln() / t.max(1.0));
        let v = judge(&s, &c);
        assert_eq!(v.class, Class::Undecided, "{v:?}");
    }

    #[test]
    fn settings_warnings_follow_the_paper_region() {
        let v = Verdict {
            class: Class::Undecided,
            torus_dimension: None,
            criterion: String::new(),
            confidence: 0.0,
        };
        let codes = |s: &Settings, e: f64| -> Vec<String> {
            warnings(s, e, None, &v)
                .into_iter()
                .map(|w| w.code)
                .collect()
        };
        assert!(codes(&settings(Method::Mpm, 1e-8, 1.0, 2, 4), 1e-11).is_empty());
        assert!(codes(&settings(Method::Mpm, 1e-9, 0.5, 2, 4), 1e-9).is_empty());
        assert_eq!(
            codes(&settings(Method::Mpm, 1e-5, 1.0, 2, 4), 0.0),
            [D0_FAR_FROM_SQRT_EPS]
        );
        assert_eq!(
            codes(&settings(Method::Mpm, 1e-8, 5.0, 2, 4), 0.0),
            [TAU_ABOVE_ONE]
        );
        assert!(codes(&settings(Method::Vm, 1e-3, 5.0, 2, 4), 0.0).is_empty());
        assert_eq!(
            codes(&settings(Method::Vm, 1e-8, 1.0, 2, 4), 1e-7),
            [ENERGY_ERROR_ABOVE_SQRT_EPS]
        );
        // GALI_3 a factor 1e-15 below GALI_2: VM's floor.
        let p = SchemePoint {
            gali_log10_mean: vec![-1.0, -16.0, -31.0],
            gali_log10_of_mean: Vec::new(),
            sali_log10_mean: None,
            lyapunov: vec![0.0],
            vs_vm_abs_delta: None,
        };
        let w = warnings(&settings(Method::Vm, 1e-8, 1.0, 2, 4), 0.0, Some(&p), &v);
        assert_eq!(w.len(), 1);
        assert_eq!(w[0].code, GALI_AT_ROUNDING_FLOOR);
        assert!(w[0].message.contains("GALI_3..4"), "{}", w[0].message);
    }
}
