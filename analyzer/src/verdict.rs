//! The verdict a newcomer can read: per scheme, is the orbit chaotic, regular (on a torus of
//! which dimension), escaped or unbounded (since when) or undecided (why) at this time, by which
//! criterion and with what confidence; and warnings when the settings or the values leave the
//! region where the indicators are reliable (Many Manda, Hillebrand, Skokos: the error analysis
//! of GALI by VM and MPM).
//!
//! Sans-io and pure: a function of what the analysis already keeps per scheme (its curve of
//! geometric-mean GALI_j and finite-time exponents, the scheme's settings, the energy error or
//! mean divergence) and of the reference orbit (its extent over time, how the run ended).
//!
//! # Outcomes before chaos and order
//!
//! Chaotic and regular describe a bounded orbit; the first rule that applies decides:
//! 1. **escaped**: the run failed because the reference orbit escaped (the producer's escape
//!    bound on `|x|`) or became non-finite; the end-of-run reason names the time
//!    (`chaoscope_schemas::run::REFERENCE_ESCAPED`). `time` is that time.
//! 2. **unbounded**: the extent `R(t) = max_{t' <= t} |x(t')|` of the reference state (every
//!    sample carries it) grew by a factor 2 over the latest decade `[t/10, t]` and by 1.25 over
//!    each half of it, with at least 10 samples in the decade: a steady drift (`|x| ~ t`: 10
//!    per decade) or diffusion (`|x| ~ t^(1/2)`: 3.2), not a bounded orbit reaching a new
//!    corner once. `time` is the latest sample's. Also a failed run whose extent grew a
//!    hundredfold over its second half (the Henon map at a = 1.6, whose MPM separations drown
//!    in the rounding of `|x| ~ 1e8` before the reference reaches the escape bound).
//! 3. **undecided** (`run_failed`): any other failed run.
//! 4. Otherwise chaotic, regular or undecided as below; a regular verdict also needs the
//!    extent to have grown by at most 1.5 over the latest decade (`extent_growing` otherwise).
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
//!      are within `0.7` of the pattern of some torus dimension `1 <= s <= N` (`N = D/2`; a 2D
//!      map's island orbit is a 1-torus, GALI_2 ~ t^-2; a 4D map's 1-torus gives t^-1, -2, -4); a chaotic orbit
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
//!   MLE alone at twice the threshold (10 e-folds; the criterion states the ratio reached), and
//!   never regular.
//!
//! Undecided verdicts carry a `reason` word ([`Undecided`]) besides the criterion text.
//!
//! # Warnings
//!
//! Settings (they halve the confidence): `d0_far_from_sqrt_eps`, `tau_above_one` (MPM),
//! `energy_error_above_sqrt_eps` (Hamiltonians), `exponent_sum_off_divergence` (flows and maps:
//! a QR scheme with `k = D` whose exponents' sum is off the mean divergence by more than 1e-3
//! of the largest rate; for a map the two are equal to rounding, for a flow they differ by the
//! integration error, ~h^4 for rk4: Lorenz at h = 0.05 gives 7e-3). Values, for rescale
//! schemes not called chaotic (where the floor is expected): `gali_at_rounding_floor`, and for
//! MPM `mpm_departs_from_vm` (more than 1 decade from the VM scheme with the same tau, mean
//! over sets) and, without such a VM scheme, `mpm_leaves_power_law` (a GALI decaying with
//! exponent >= 1 over `[t/10, t/3.2]` keeps less than half of it over `[t/3.2, t]`: the
//! separations' floor).
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

use chaoscope_schemas::run::{Method, Orthonormalization, escape_time, integrator_failure_time};

use crate::series::SchemePoint;

/// What the orbit is, at this time.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Class {
    Chaotic,
    Regular,
    /// The reference orbit left for infinity (or became non-finite): the run ended there.
    Escaped,
    /// The reference orbit's extent in phase space keeps growing.
    Unbounded,
    /// The orbit is attracted to a stable fixed point or cycle: nearby orbits converge
    /// exponentially (largest exponent negative), as on a dissipative system's periodic window.
    Attracting,
    /// The integrator could not go on (the implicit stages stopped converging): the run ended
    /// there, and the orbit did not escape.
    Failed,
    Undecided,
}

impl Class {
    pub fn word(self) -> &'static str {
        match self {
            Class::Chaotic => "chaotic",
            Class::Regular => "regular",
            Class::Escaped => "escaped",
            Class::Unbounded => "unbounded",
            Class::Attracting => "attracting",
            Class::Failed => "failed",
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
    /// Escaped: the time by which the reference orbit escaped; failed: the time of the step
    /// the integrator could not take; unbounded: the time of the latest sample, whose extent
    /// the criterion names; `None` (absent from JSON) otherwise.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub time: Option<f64>,
    /// Undecided: what is missing, as a stable word (see [`Undecided`]); `None` (absent from
    /// JSON) otherwise.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub reason: Option<Undecided>,
}

/// Why a verdict is undecided (the `reason` field: a stable word scripts can test; the
/// criterion text says it with the numbers).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Undecided {
    /// No sample after t = 0 yet, or too few renormalizations for a window of time.
    TooEarly,
    /// The deviation grew exponentially but no GALI decayed faster than a power law (yet).
    NoGaliEvidence,
    /// A QR scheme (exponents only) whose deviation has neither grown nor shrunk by its
    /// threshold.
    QrMleBelowThreshold,
    /// A scheme with one deviation vector (no GALI: the exponent alone decides) whose deviation
    /// has neither grown nor shrunk by its threshold.
    MleBelowThreshold,
    /// GALI_2 is at the rounding floor.
    GaliAtFloor,
    /// The GALI slopes steepen like an exponential, not a power law.
    NotSteady,
    /// The GALI slopes match no torus pattern.
    NoTorusPattern,
    /// Every GALI stays constant: a torus of dimension >= k, or chaos before its Lyapunov time.
    ConstantGali,
    /// GALI power laws, but the deviation grew faster than linearly.
    FastGrowth,
    /// The orbit's extent still grows, too slowly to call it unbounded.
    ExtentGrowing,
    /// The run failed for a reason other than the reference orbit escaping.
    RunFailed,
}

/// A setting or value outside the region where the indicators are reliable.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Warning {
    /// Stable identifier: one of [`D0_FAR_FROM_SQRT_EPS`], [`TAU_ABOVE_ONE`],
    /// [`ENERGY_ERROR_ABOVE_SQRT_EPS`], [`GALI_AT_ROUNDING_FLOOR`], [`MPM_DEPARTS_FROM_VM`],
    /// [`MPM_LEAVES_POWER_LAW`], [`EXPONENT_SUM_OFF_DIVERGENCE`].
    pub code: String,
    pub message: String,
}

pub const D0_FAR_FROM_SQRT_EPS: &str = "d0_far_from_sqrt_eps";
pub const TAU_ABOVE_ONE: &str = "tau_above_one";
pub const ENERGY_ERROR_ABOVE_SQRT_EPS: &str = "energy_error_above_sqrt_eps";
pub const GALI_AT_ROUNDING_FLOOR: &str = "gali_at_rounding_floor";
pub const MPM_DEPARTS_FROM_VM: &str = "mpm_departs_from_vm";
pub const MPM_LEAVES_POWER_LAW: &str = "mpm_leaves_power_law";
pub const EXPONENT_SUM_OFF_DIVERGENCE: &str = "exponent_sum_off_divergence";

/// Decades between MPM's and VM's log10 GALI_j (mean over sets) beyond which MPM has left VM.
/// MPM's own error at a `d0` of the paper's range is far below it; the paper's regular FPUT
/// N = 5 orbit shows 0.3 decades on GALI_10 by t ~ 700 (a start at the floor, not yet a
/// departure worth a warning), the floor reached takes MPM decades away.
pub const MPM_VM_TOL: f64 = 1.0;
/// Fraction of its log-log exponent over `[t/10, t/3.2]` below which an MPM GALI's exponent
/// over `[t/3.2, t]` tells it has left its power law.
const MPM_SLOPE_KEPT: f64 = 0.5;
/// Relative difference of the sum of a QR spectrum and the mean divergence (relative to the
/// largest of the rates) above which the integration error shows: for Lorenz, rk4 at h = 0.05
/// gives 7e-3, at h = 0.01 (error ~ h^4) about 1e-5.
pub const SUM_DIVERGENCE_TOL: f64 = 1e-3;

/// Double-precision rounding unit.
pub const EPS: f64 = f64::EPSILON;
/// Decades between an MPM `d0` and `eps^(1/2)` beyond which it is far from optimal: the paper's
/// V-shapes (Figs. 5, 10) are flat within about a decade of 1e-8 and off by orders of magnitude
/// at 1e-5 and 1e-11.
pub const D0_DECADES: f64 = 2.0;

/// e-folds of growth of the log-stretch over `[t/2, t]` for the MLE criterion of chaos.
const CHAOS_STRETCH: f64 = 5.0;
/// The same for QR schemes, whose GALI gives no second sign: twice as much.
const QR_CHAOS_STRETCH: f64 = 2.0 * CHAOS_STRETCH;
/// e-folds the deviation must shrink over the latest `[t/2, t]` for `attracting`: the mirror
/// of the exponent-alone threshold (a neutral orbit, regular or at a bifurcation, changes its
/// deviation by at most a power of t: ln 2 per halving for linear growth).
const ATTRACTING_STRETCH: f64 = QR_CHAOS_STRETCH;
/// Largest growth of the extent over the latest decade of an orbit that drifts while chaotic
/// (chaotic diffusion: `t^(1/2)` gives 3.2, a drift `t` 10, an accelerating `t^2` 100); beyond
/// it the orbit runs away faster than any power law, which is an unstable escape, not chaos
/// on a region of phase space.
const DRIFT_POLYNOMIAL: f64 = 100.0;
/// Growth of the orbit's extent over the latest decade of time for `unbounded` ...
const EXTENT_GROWTH: f64 = 2.0;
/// ... and over each half of that decade.
const EXTENT_HALF_GROWTH: f64 = 1.25;
/// Largest growth of the extent over the latest decade for a regular verdict: a quasi-periodic
/// orbit has come close to its largest |x| within the first tenth of its time (at least 10
/// renormalizations).
const EXTENT_BOUNDED: f64 = 1.5;
/// Growth of the extent over the second half of a failed run that tells the orbit was running
/// away when it failed.
const RUNAWAY_GROWTH: f64 = 100.0;
/// Least points of the extent in the latest decade for an extent criterion.
const MIN_EXTENT_POINTS: usize = 10;
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

/// What the verdict knows of the reference orbit itself, besides a scheme's curve.
#[derive(Debug, Clone, Copy, Default)]
pub struct Orbit<'a> {
    /// The orbit's extent `R(t) = max_{t' <= t} |x(t')|` (Euclidean norm of the reference
    /// state, its periodic coordinates wrapped into their period), at log-spaced times in time
    /// order (empty when no state was seen).
    pub extent: &'a [(f64, f64)],
    /// The run's end-of-run reason and the time of its last sample, when the run failed.
    pub failure: Option<(&'a str, f64)>,
}

fn undecided(reason: Undecided, criterion: String) -> Verdict {
    Verdict {
        class: Class::Undecided,
        torus_dimension: None,
        criterion,
        confidence: 0.0,
        time: None,
        reason: Some(reason),
    }
}

/// Growth of the extent over the latest decade of time: `R(t/10)`, `R(t/sqrt 10)`, `R(t)` and
/// `t`, when the decade holds at least [`MIN_EXTENT_POINTS`] points after t = 0.
fn extent_decade(extent: &[(f64, f64)]) -> Option<(f64, f64, f64, f64)> {
    let &(t, r) = extent.last()?;
    let at = |x: f64| extent.iter().rposition(|p| p.0 <= x).map(|i| extent[i].1);
    let in_decade = extent
        .iter()
        .filter(|p| p.0 > 0.0 && p.0 >= t / 10.0)
        .count();
    if t <= 0.0 || in_decade < MIN_EXTENT_POINTS {
        return None;
    }
    Some((at(t / 10.0)?, at(t / 10f64.sqrt())?, r, t))
}

/// The unbounded verdict, when the extent grew by [`EXTENT_GROWTH`] over the latest decade and
/// by [`EXTENT_HALF_GROWTH`] over each of its halves: steady growth, as of an orbit drifting or
/// diffusing away (a drift `|x| ~ t` gives 10 and 3.2, diffusion `|x| ~ t^(1/2)` 3.2 and 1.8),
/// not a bounded orbit reaching a new corner of its region once.
fn unbounded(extent: &[(f64, f64)]) -> Option<Verdict> {
    let (r0, r1, r, t) = extent_decade(extent)?;
    let growing =
        r >= EXTENT_GROWTH * r0 && r1 >= EXTENT_HALF_GROWTH * r0 && r >= EXTENT_HALF_GROWTH * r1;
    growing.then(|| Verdict {
        class: Class::Unbounded,
        torus_dimension: None,
        criterion: format!(
            "the orbit's extent max |x| grew from {r0:.3e} by t = {} to {r1:.3e} by t = {} and \
             {r:.3e} by t = {} (x{:.1} over the decade; a bounded orbit's extent levels off)",
            time(t / 10.0),
            time(t / 10f64.sqrt()),
            time(t),
            r / r0.max(f64::MIN_POSITIVE),
        ),
        confidence: confidence(r / r0.max(f64::MIN_POSITIVE) / EXTENT_GROWTH),
        time: Some(t),
        reason: None,
    })
}

/// The verdict from a scheme's curve (time order, ending with the latest sample) and what is
/// known of the reference orbit. In order: an escaped reference orbit is `escaped`, a growing
/// extent `unbounded`, a run failed otherwise `undecided`; only then chaotic or regular.
pub fn verdict(settings: &Settings, curve: &[(f64, &SchemePoint)], orbit: &Orbit) -> Verdict {
    if let Some((reason, t_last)) = orbit.failure
        && let Some(t) = integrator_failure_time(reason)
    {
        return Verdict {
            class: Class::Failed,
            torus_dimension: None,
            criterion: format!(
                "the integrator failed in the step to t = {} (last sample at t = {}): \
                 {reason}; the orbit did not escape, and a run stopped there is neither chaotic \
                 nor regular",
                time(t),
                time(t_last)
            ),
            confidence: 1.0,
            time: Some(t),
            reason: None,
        };
    }
    if let Some((reason, t_last)) = orbit.failure
        && let Some(t) = escape_time(reason)
    {
        return Verdict {
            class: Class::Escaped,
            torus_dimension: None,
            criterion: format!(
                "the reference orbit escaped by t = {} (last sample at t = {}): {reason}",
                time(t),
                time(t_last)
            ),
            confidence: 1.0,
            time: Some(t),
            reason: None,
        };
    }
    let pts = thin(curve);
    let floor = settings.floor_log10();
    if let Some(v) = unbounded(orbit.extent) {
        // Chaotic diffusion: a drift (at most polynomial) with nearby orbits diverging
        // exponentially beyond doubt is chaos on an unbounded region, not a drift alone.
        if orbit.failure.is_none()
            && let Some((r0, _, r, _)) = extent_decade(orbit.extent)
            && r <= DRIFT_POLYNOMIAL * r0
            && let Some((ds, t_mle)) = stretch_growth(&pts, QR_CHAOS_STRETCH)
            && let Chaos::Chaotic(mut c) = chaos(settings, &pts, floor, curve)
        {
            c.criterion = format!(
                "{}; the orbit drifts (its extent max |x| grew x{:.1} over the latest decade), \
                 but nearby orbits diverge exponentially beyond doubt (e^{ds:.1} over [{}, {}], \
                 at least e^{QR_CHAOS_STRETCH}): chaotic diffusion",
                c.criterion,
                r / r0.max(f64::MIN_POSITIVE),
                time(t_mle / 2.0),
                time(t_mle)
            );
            return c;
        }
        return v;
    }
    if let Some((reason, t_last)) = orbit.failure {
        // Running away when the run stopped: the extent grew a hundredfold over the last half
        // of the run (the Henon map at a = 1.6 squares |x| every iteration, and its MPM
        // separations vanish in the rounding of |x| ~ 1e8 before the escape bound).
        if let Some(&(t, r)) = orbit.extent.last()
            && let Some(i) = orbit.extent.iter().rposition(|p| p.0 <= t / 2.0)
            && r >= RUNAWAY_GROWTH * orbit.extent[i].1
        {
            let r0 = orbit.extent[i].1;
            return Verdict {
                class: Class::Unbounded,
                torus_dimension: None,
                criterion: format!(
                    "the run failed after t = {} ({reason}) while the orbit ran away: its extent \
                     max |x| grew from {r0:.3e} by t = {} to {r:.3e} by t = {}",
                    time(t_last),
                    time(orbit.extent[i].0),
                    time(t)
                ),
                confidence: confidence(r / r0.max(f64::MIN_POSITIVE) / RUNAWAY_GROWTH),
                time: Some(t),
                reason: None,
            };
        }
        return undecided(
            Undecided::RunFailed,
            format!(
                "the run failed after t = {}: {reason}; a failed run is neither chaotic nor \
                 regular",
                time(t_last)
            ),
        );
    }
    if pts.is_empty() {
        return undecided(Undecided::TooEarly, "no samples after t = 0 yet".into());
    }
    if let Some(v) = attracting(&pts) {
        return v;
    }
    match chaos(settings, &pts, floor, curve) {
        Chaos::Chaotic(v) | Chaos::Undecided(v) => return v,
        Chaos::NoEvidence => {}
    }
    if settings.orthonormalize == Orthonormalization::Qr {
        return undecided(
            Undecided::QrMleBelowThreshold,
            format!(
                "QR scheme (exponents only): the deviation has neither grown nor shrunk by \
                 e^{QR_CHAOS_STRETCH} over any [t'/2, t'] (yet)"
            ),
        );
    }
    if settings.k < 2 {
        return undecided(
            Undecided::MleBelowThreshold,
            format!(
                "one deviation vector (the exponent alone decides): the deviation has neither \
                 grown nor shrunk by e^{QR_CHAOS_STRETCH} over any [t'/2, t'] (yet)"
            ),
        );
    }

    // Regular: never while the orbit's extent still grows.
    if let Some((r0, _, r, _)) = extent_decade(orbit.extent)
        && r > EXTENT_BOUNDED * r0
    {
        return undecided(
            Undecided::ExtentGrowing,
            format!(
                "the orbit's extent max |x| still grows ({r0:.3e} at t/10, {r:.3e} at t): not \
                 on a torus"
            ),
        );
    }
    match regular(settings, &pts, floor) {
        Ok(v) => v,
        Err((reason, why)) => undecided(reason, why),
    }
}

/// The outcome of the chaos criteria.
enum Chaos {
    Chaotic(Verdict),
    /// The deviation grew exponentially, but the second sign is missing.
    Undecided(Verdict),
    /// No exponential growth of the deviation.
    NoEvidence,
}

/// The chaos criteria (module documentation): the growth of the log-stretch over some
/// `[t'/2, t']` and, where the scheme has GALIs, their decay faster than any power law; the
/// exponent alone at twice the threshold where the scheme has no GALI (QR, one vector) or
/// where its GALIs reached the rounding floor between the recorded samples.
fn chaos(settings: &Settings, pts: &[Pt], floor: f64, curve: &[(f64, &SchemePoint)]) -> Chaos {
    let qr = settings.orthonormalize == Orthonormalization::Qr;
    let exponents_only = qr || settings.k < 2;
    let chaos_stretch = if exponents_only {
        QR_CHAOS_STRETCH
    } else {
        CHAOS_STRETCH
    };
    let mle = curve
        .last()
        .and_then(|(_, p)| p.lyapunov.first().copied())
        .unwrap_or(0.0);
    // Both evidences, each seen in some window up to now (chaos does not undo itself; a
    // regular orbit shows neither in any window).
    let Some((ds, t_mle)) = stretch_growth(pts, chaos_stretch) else {
        return Chaos::NoEvidence;
    };
    let mle_text = format!(
        "the deviation grew by e^{ds:.1} over [{}, {}] (now MLE {mle:.3e}; a regular orbit \
         grows linearly, e^0.7 per doubling of time, its MLE decays ~ ln(t)/t)",
        time(t_mle / 2.0),
        time(t_mle)
    );
    let alone = |why: &str| {
        Chaos::Chaotic(Verdict {
            class: Class::Chaotic,
            torus_dimension: None,
            criterion: format!(
                "{mle_text}; {why}: the exponent alone, {:.1} times its threshold of \
                 e^{QR_CHAOS_STRETCH}",
                ds / QR_CHAOS_STRETCH
            ),
            confidence: confidence(ds / QR_CHAOS_STRETCH),
            time: None,
            reason: None,
        })
    };
    if qr {
        return alone("QR scheme (exponents only)");
    }
    if settings.k < 2 {
        return alone("one deviation vector (its exponent only)");
    }
    if let Some((j, p, t_end)) = exponential_decay(pts, floor, settings.k) {
        let x = (ds / chaos_stretch).min(p / (2.0 * (j - 1) as f64 + CHAOS_SLOPE_MARGIN));
        return Chaos::Chaotic(Verdict {
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
            time: None,
            reason: None,
        });
    }
    // GALI_2 at the floor at the latest sample, with too few samples above it for a window
    // (`[run] sample_every` records a sample every few Lyapunov times): the GALIs fell
    // between the samples, which only the exponent saw.
    if let Some(last) = pts.last()
        && last.top_usable(floor) < 2
        && ds >= QR_CHAOS_STRETCH
    {
        let since = pts
            .iter()
            .position(|p| p.top_usable(floor) < 2)
            .map_or(last.t, |i| pts[i].t);
        let v = alone(&format!(
            "GALI_2 has been at the rounding floor since the sample at t = {} (it fell between \
             the recorded samples, too fast for a window of them; a regular orbit's GALI_2 \
             decays at most like t^-2)",
            time(since)
        ));
        return v;
    }
    Chaos::Undecided(undecided(
        Undecided::NoGaliEvidence,
        format!("{mle_text}, but no GALI has decayed faster than a power law yet"),
    ))
}

/// `attracting` when the deviation shrank by at least [`ATTRACTING_STRETCH`] e-folds over the
/// latest `[t/2, t]` (with at least [`MIN_POINTS`] points): nearby orbits converge, so the orbit
/// is on (or falling onto) a stable fixed point or cycle. Judged on the latest window only: a
/// transient chaos that settles on a cycle is attracting now.
fn attracting(pts: &[Pt]) -> Option<Verdict> {
    let last = pts.last()?;
    let start = at_or_before(pts, last.t / 2.0)?;
    if pts.len() - start < MIN_POINTS {
        return None;
    }
    let ds = last.stretch - pts[start].stretch;
    (ds <= -ATTRACTING_STRETCH).then(|| Verdict {
        class: Class::Attracting,
        torus_dimension: None,
        criterion: format!(
            "the deviation shrank by e^{:.1} over [{}, {}] (MLE {:.3e} < 0): nearby orbits \
             converge, the orbit is attracted to a stable fixed point or cycle; not chaotic",
            -ds,
            time(pts[start].t),
            time(last.t),
            last.stretch / last.t
        ),
        confidence: confidence(-ds / ATTRACTING_STRETCH),
        time: None,
        reason: None,
    })
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

fn regular(settings: &Settings, pts: &[Pt], floor: f64) -> Result<Verdict, (Undecided, String)> {
    let last = *pts.last().expect("non-empty");
    let t = last.t;
    let n = settings.dof;
    let split = t / 10f64.sqrt();
    let (Some(a), Some(b)) = (
        pts.iter().position(|p| p.t >= t / 10.0),
        pts.iter().position(|p| p.t >= split),
    ) else {
        return Err((
            Undecided::TooEarly,
            "too early for a power law over a decade of time".into(),
        ));
    };
    let (w1, w2) = (&pts[a..b], &pts[b..]);
    if w1.len() < MIN_POINTS || w2.len() < MIN_POINTS {
        return Err((
            Undecided::TooEarly,
            "too early for a power law over a decade of time".into(),
        ));
    }
    let top = usable_top(&pts[a..], floor).min(settings.k);
    if top < 2 {
        return Err((
            Undecided::GaliAtFloor,
            "GALI_2 is at the rounding floor".into(),
        ));
    }
    let (mut p1, mut p2, mut pd) = (Vec::new(), Vec::new(), Vec::new());
    for j in 2..=top {
        let (Some((x1, _)), Some((x2, _)), Some((xd, _))) =
            (exponent(w1, j), exponent(w2, j), exponent(&pts[a..], j))
        else {
            return Err((Undecided::TooEarly, "too few points for a power law".into()));
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
    // s = 1 included: a 2D map's island orbit (N = 1) is a 1-torus, GALI_2 ~ t^-2.
    for s in 1..=n.max(1) {
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
        return Err((
            Undecided::NotSteady,
            format!(
                "GALI_{} steepens from t^-{:.1} over [t/10, t/3.2] to t^-{:.1} over [t/3.2, t]: \
             not a steady power law",
                steep + 2,
                p1[steep],
                p2[steep]
            ),
        ));
    }
    if t < MIN_REGULAR_RENORMALIZATIONS * settings.tau {
        return Err((
            Undecided::TooEarly,
            format!("too early: a regular verdict needs t >= {MIN_REGULAR_RENORMALIZATIONS} tau"),
        ));
    }
    if matches.is_empty() {
        return Err((
            Undecided::NoTorusPattern,
            format!(
                "GALI_2..{top} log-log slopes over [t/10, t/3.2], [t/3.2, t] and [t/10, t]: ({}), \
             ({}), ({}) match no torus pattern",
                fmt(&p1),
                fmt(&p2),
                fmt(&pd)
            ),
        ));
    }
    if pd.iter().all(|&p| p < 1.0) {
        return Err((
            Undecided::ConstantGali,
            format!(
                "GALI_2..{top} stay constant (slopes {}): consistent with a torus of dimension >= \
             {top}, but also with chaos before its first Lyapunov time; no GALI decays by a \
             power law (k = 2N vectors decide)",
                fmt(&pd)
            ),
        ));
    }
    let ds = last.stretch - pts[a].stretch;
    let bound = 2.0 * 10f64.ln() + 2.0;
    if ds > bound {
        return Err((
            Undecided::FastGrowth,
            format!(
                "GALI power laws, but the deviation grew by e^{ds:.1} over [t/10, t], more than \
             the linear growth of a regular orbit"
            ),
        ));
    }
    let worst = matches.iter().map(|m| m.1).fold(f64::INFINITY, f64::min);
    // Two tori's patterns differ by a whole power somewhere, so at most one is within
    // DIMENSION_TOL (< 0.5) of the exponents; with s = 1 included, the neighbouring pattern is
    // often within REGULAR_TOL too.
    let best = matches
        .iter()
        .min_by(|a, b| a.1.total_cmp(&b.1))
        .expect("a match");
    let torus_dimension = (best.1 <= DIMENSION_TOL).then_some(best.0);
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
        time: None,
        reason: None,
    })
}

/// What the warnings need to know of the run as a whole.
#[derive(Debug, Clone, Copy, Default)]
pub struct RunValues {
    /// Largest relative energy error of the reference orbit (0 for systems without energy).
    pub energy_error_max: f64,
    /// Mean divergence of the reference orbit from t = 0 (flows and maps).
    pub mean_divergence: Option<f64>,
    /// Every stretching factor from t = 0 was seen (so a scheme's exponents cover the same
    /// time as the mean divergence).
    pub complete: bool,
    /// Dimension of the state.
    pub dim: usize,
    /// The initial energy `E0`, and the initial norm of a system that conserves one (the
    /// DDNLS): with `E0` near zero against the norm, the energy error is judged against the
    /// norm ([`energy_error_of_norm`]).
    pub energy0: f64,
    pub norm0: Option<f64>,
}

/// The largest energy error of a run whose initial energy `E0` is near zero against its
/// conserved norm `S0` (`|E0| < eps^(1/2) S0`, a DDNLS block solved to `E = 0`), as a fraction of
/// `S0`: `max |E - E0| / S0`, from the largest relative error `max |E - E0| / |E0|` (absolute
/// when `E0 = 0`). `None` for any other run, whose relative error means what it says. Why: a
/// relative error divides by `E0`, so at `E0 = -5.6e-16` an integration that keeps the norm to
/// `1.5e-10` reported an energy error of `3.5e5` and a warning to lower `h`.
pub fn energy_error_of_norm(
    energy_error_max: f64,
    energy0: f64,
    norm0: Option<f64>,
) -> Option<f64> {
    let s0 = norm0.filter(|s| s.is_finite() && *s > 0.0)?;
    if energy0.abs() >= EPS.sqrt() * s0 {
        return None;
    }
    let absolute = if energy0 == 0.0 {
        energy_error_max
    } else {
        energy_error_max * energy0.abs()
    };
    Some(absolute / s0)
}

/// Warnings for a scheme: settings outside the paper's reliable region, GALIs at the rounding
/// floor (from the latest point of the curve), an MPM scheme leaving VM or its own power law,
/// and the exponents' sum off the mean divergence.
pub fn warnings(
    settings: &Settings,
    run: &RunValues,
    curve: &[(f64, &SchemePoint)],
    verdict: &Verdict,
) -> Vec<Warning> {
    let latest = curve.last().map(|(_, p)| *p);
    let mut out = Vec::new();
    let sqrt_eps = EPS.sqrt();
    let energy_error_max = run.energy_error_max;
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
    if let Some(of_norm) = energy_error_of_norm(energy_error_max, run.energy0, run.norm0) {
        if of_norm > sqrt_eps {
            out.push(Warning {
                code: ENERGY_ERROR_ABOVE_SQRT_EPS.into(),
                message: format!(
                    "energy error {of_norm:.1e} of the norm (E0 = {:.1e} is near zero, so the \
                     error is measured against the norm S0 = {:.4}) above eps^(1/2) ~ 1.5e-8: \
                     the integration error dominates GALI; use a smaller h",
                    run.energy0,
                    run.norm0.unwrap_or(0.0)
                ),
            });
        }
    } else if energy_error_max > sqrt_eps {
        out.push(Warning {
            code: ENERGY_ERROR_ABOVE_SQRT_EPS.into(),
            message: format!(
                "relative energy error {energy_error_max:.1e} above eps^(1/2) ~ 1.5e-8: the \
                 integration error dominates GALI (the paper: E_r <= 1e-8); use a smaller h"
            ),
        });
    }
    if let Some(w) = exponent_sum_off_divergence(settings, run, latest) {
        out.push(w);
    }
    // GALI values of QR schemes mean nothing (re-orthonormalized vectors); past an escape or a
    // growing extent, or once chaos is decided, values at the floor are expected.
    let gali_judged = settings.orthonormalize == Orthonormalization::Rescale
        && matches!(verdict.class, Class::Regular | Class::Undecided);
    if let Some(p) = latest
        && gali_judged
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
                    "{orders} at the rounding floor (a factor below {}, the {} precision of \
                     a separation): their values are not meaningful",
                    power_of_ten(settings.floor_log10()),
                    match settings.method {
                        Method::Vm => "eps",
                        Method::Mpm => "eps/d0",
                    }
                ),
            });
        }
    }
    if settings.method == Method::Mpm && gali_judged {
        // With a VM scheme beside it, the distance says it; without, the slopes.
        match latest.and_then(|p| p.vs_vm_abs_delta.as_ref()) {
            Some(_) => out.extend(mpm_off_vm(latest)),
            None => out.extend(mpm_leaves_power_law(settings, curve)),
        }
    }
    out
}

/// An MPM scheme whose GALI_j is, averaged over the sets, more than [`MPM_VM_TOL`] decades from
/// the VM scheme's with the same tau and directions. Away from the floor MPM differs from VM
/// by `O((d0 tau)^k) + O((eps/d0)^k)`, far below a decade at any `d0` within the paper's
/// range; a larger distance is the floor the rounding of `x + d` sets under the small singular
/// values (numerics: GALI_4 of the HH chaotic orbit departs at t ~ 115 with d0 = 1e-8).
fn mpm_off_vm(latest: Option<&SchemePoint>) -> Option<Warning> {
    let d = latest?.vs_vm_abs_delta.as_ref()?;
    let off: Vec<usize> = d
        .iter()
        .enumerate()
        .filter(|(_, x)| **x > MPM_VM_TOL)
        .map(|(o, _)| o + 2)
        .collect();
    let (&first, &last) = (off.first()?, off.last()?);
    let worst = d.iter().copied().fold(0.0f64, f64::max);
    let orders = if first == last {
        format!("GALI_{first} is")
    } else {
        format!("GALI_{first}..{last} are")
    };
    Some(Warning {
        code: MPM_DEPARTS_FROM_VM.into(),
        message: format!(
            "MPM {orders} more than {MPM_VM_TOL} decades from VM's (up to {worst:.1} decades, \
             mean over sets): beyond what d0 allows, the nearby orbits' rounding (eps/d0) has \
             reached these GALIs; read VM's values"
        ),
    })
}

/// An MPM scheme (without a VM scheme to compare with) whose GALI_j decayed by a power law
/// over `[t/10, t/3.2]` (exponent >= 1) and decays by less than half that exponent over
/// `[t/3.2, t]`: a regular orbit's power laws keep their exponents (the crossovers between
/// tori patterns seen on FPUT change them by about one power) and a chaotic orbit's GALIs
/// steepen, so a slope that gives way is the floor of the MPM's separations, reached before
/// the eps/d0 factor check sees it.
fn mpm_leaves_power_law(settings: &Settings, curve: &[(f64, &SchemePoint)]) -> Option<Warning> {
    let pts = thin(curve);
    let t = pts.last()?.t;
    let a = pts.iter().position(|p| p.t >= t / 10.0)?;
    let b = pts.iter().position(|p| p.t >= t / 10f64.sqrt())?;
    let (w1, w2) = (&pts[a..b], &pts[b..]);
    if t < MIN_REGULAR_RENORMALIZATIONS * settings.tau {
        return None;
    }
    let k = pts.last()?.gali.len() + 1;
    let mut off = Vec::new();
    for j in 2..=k.min(settings.k) {
        let (Some((p1, _)), Some((p2, _))) = (exponent(w1, j), exponent(w2, j)) else {
            continue;
        };
        if p1 >= 1.0 && p2 < MPM_SLOPE_KEPT * p1 {
            off.push((j, p1, p2));
        }
    }
    let (j, p1, p2) = *off.first()?;
    let others = if off.len() > 1 {
        format!(" (and GALI_{})", {
            off[1..]
                .iter()
                .map(|o| o.0.to_string())
                .collect::<Vec<_>>()
                .join(", ")
        })
    } else {
        String::new()
    };
    Some(Warning {
        code: MPM_LEAVES_POWER_LAW.into(),
        message: format!(
            "MPM GALI_{j}{others} left its power law: log-log slope -{p1:.1} over [t/10, \
             t/3.2], -{p2:.1} over [t/3.2, t]; the separations' rounding floor (eps/d0 = \
             {:.0e}) has been reached: use a VM scheme for these orders",
            EPS / settings.d0.min(1.0)
        ),
    })
}

/// A QR scheme with `k = D` on a flow or map: the sum of its exponents is the mean
/// `ln |det|` of the step's derivative, which for a map is the mean divergence (`ln |det DF|`)
/// to rounding and for a flow approximates the mean of `div f` to the integrator's order.
/// A relative difference above [`SUM_DIVERGENCE_TOL`] is the integration error (a step too
/// large) or an inexact tangent: the exponents carry it too.
fn exponent_sum_off_divergence(
    settings: &Settings,
    run: &RunValues,
    latest: Option<&SchemePoint>,
) -> Option<Warning> {
    let div = run.mean_divergence?;
    let p = latest?;
    if settings.orthonormalize != Orthonormalization::Qr
        || settings.k != run.dim
        || p.lyapunov.len() != run.dim
        || !run.complete
    {
        return None;
    }
    let sum: f64 = p.lyapunov.iter().sum();
    let scale = p
        .lyapunov
        .iter()
        .fold(div.abs(), |m, l| m.max(l.abs()))
        .max(f64::MIN_POSITIVE);
    let rel = (sum - div).abs() / scale;
    (rel > SUM_DIVERGENCE_TOL).then(|| Warning {
        code: EXPONENT_SUM_OFF_DIVERGENCE.into(),
        message: format!(
            "the exponents sum to {sum:.6} but the mean divergence is {div:.6} (difference \
             {:.1e}, {rel:.1e} of the largest rate, above {SUM_DIVERGENCE_TOL:.0e}): the \
             integration error shows in the exponents; use a smaller h",
            sum - div
        ),
    })
}

/// Whether a warning is about the settings (lowers the confidence) rather than the values.
pub fn is_settings_warning(w: &Warning) -> bool {
    matches!(
        w.code.as_str(),
        D0_FAR_FROM_SQRT_EPS
            | TAU_ABOVE_ONE
            | ENERGY_ERROR_ABOVE_SQRT_EPS
            | EXPONENT_SUM_OFF_DIVERGENCE
    )
}

/// The verdict with its confidence lowered by the settings warnings that apply, and the
/// warnings.
pub fn assess(
    settings: &Settings,
    curve: &[(f64, &SchemePoint)],
    run: &RunValues,
    orbit: &Orbit,
) -> (Verdict, Vec<Warning>) {
    let mut v = verdict(settings, curve, orbit);
    let w = warnings(settings, run, curve, &v);
    if w.iter().any(is_settings_warning) {
        v.confidence *= 0.5;
    }
    (v, w)
}

/// `10^x` for a message: as a number where it is one (`2e-8`), and as `1e<x>` where it is
/// beyond the range of f64 (a recording's hostile `d0` of 1e-320 puts MPM's floor eps/d0 there),
/// never `inf`.
fn power_of_ten(x: f64) -> String {
    let v = 10f64.powf(x);
    if v.is_finite() && v > 0.0 {
        format!("{v:.0e}")
    } else {
        format!("1e{}", x.round())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_floor_beyond_the_doubles_is_written_as_a_power_never_inf() {
        assert_eq!(power_of_ten((2.2e-16f64 / 1e-8).log10()), "2e-8");
        // eps / d0 with a hostile d0 of 1e-320 (a fuzzed recording).
        assert_eq!(power_of_ten(304.3), "2e304");
        assert_eq!(power_of_ten(400.2), "1e400");
        assert_eq!(power_of_ten(-400.0), "1e-400");
    }

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
                        named: Vec::new(),
                        lyapunov_from: None,
                    },
                )
            })
            .collect()
    }

    fn judge(s: &Settings, c: &[(f64, SchemePoint)]) -> Verdict {
        let refs: Vec<(f64, &SchemePoint)> = c.iter().map(|(t, p)| (*t, p)).collect();
        verdict(s, &refs, &Orbit::default())
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

    /// A DDNLS block solved to `E = 0` (`E0 = -5.6e-16`, norm 3.63) whose energy moved by
    /// `2e-10`: relative error 3.5e5, which warned "use a smaller h"; against the norm, 5.4e-11,
    /// no warning. The same run at `E0 = 0` exactly (absolute error), and one with a real error.
    /// Away from zero (`E0` of the order of the norm) the relative error is kept.
    #[test]
    fn an_energy_near_zero_is_judged_against_the_norm() {
        let v = undecided(Undecided::TooEarly, String::new());
        let s = Settings {
            method: Method::Vm,
            orthonormalize: Orthonormalization::Rescale,
            d0: 1e-8,
            tau: 1.0,
            dof: 50,
            k: 2,
        };
        let run = |error: f64, energy0: f64| RunValues {
            energy_error_max: error,
            energy0,
            norm0: Some(3.63),
            ..RunValues::default()
        };
        let warned = |r: &RunValues| {
            warnings(&s, r, &[], &v)
                .iter()
                .any(|w| w.code == ENERGY_ERROR_ABOVE_SQRT_EPS)
        };
        let e0: f64 = -5.55e-16;
        let of_norm = energy_error_of_norm(2e-10 / e0.abs(), e0, Some(3.63)).unwrap();
        assert!((of_norm - 2e-10 / 3.63).abs() < 1e-22, "{of_norm}");
        assert!(!warned(&run(2e-10 / e0.abs(), e0)));
        assert!(!warned(&run(2e-10, 0.0)));
        assert!(warned(&run(1e-3 / e0.abs(), e0)));
        assert_eq!(energy_error_of_norm(1e-9, -11.2, Some(21.0)), None);
        assert!(warned(&run(1e-6, -11.2)));
        assert_eq!(energy_error_of_norm(1e-9, 0.0, None), None);
    }

    #[test]
    fn settings_warnings_follow_the_paper_region() {
        let v = undecided(Undecided::TooEarly, String::new());
        let run = |e: f64| RunValues {
            energy_error_max: e,
            ..RunValues::default()
        };
        let codes = |s: &Settings, e: f64| -> Vec<String> {
            warnings(s, &run(e), &[], &v)
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
            named: Vec::new(),
            lyapunov_from: None,
        };
        let w = warnings(
            &settings(Method::Vm, 1e-8, 1.0, 2, 4),
            &run(0.0),
            &[(1.0, &p)],
            &v,
        );
        assert_eq!(w.len(), 1);
        assert_eq!(w[0].code, GALI_AT_ROUNDING_FLOOR);
        assert!(w[0].message.contains("GALI_3..4"), "{}", w[0].message);
    }

    /// `R(t)` at t = 0, 1, .. t_final.
    fn extent(t_final: usize, r: impl Fn(f64) -> f64) -> Vec<(f64, f64)> {
        (0..=t_final).map(|i| (i as f64, r(i as f64))).collect()
    }

    fn judge_orbit(s: &Settings, c: &[(f64, SchemePoint)], orbit: &Orbit) -> Verdict {
        let refs: Vec<(f64, &SchemePoint)> = c.iter().map(|(t, p)| (*t, p)).collect();
        verdict(s, &refs, orbit)
    }

    #[test]
    fn a_1_torus_of_a_2d_map_is_regular() {
        // N = 1, k = 2: GALI_2 ~ t^-2 (s = 1: 2(j - N)), linear growth of the deviation.
        let s = settings(Method::Vm, 1e-8, 1.0, 1, 2);
        let c = curve(
            3000,
            2,
            |_, t| -0.2 - 2.0 * t.max(1.0).log10(),
            |t| (1.0 + 0.5 * t).ln() / t.max(1.0),
        );
        let v = judge(&s, &c);
        assert_eq!(v.class, Class::Regular, "{v:?}");
        assert_eq!(v.torus_dimension, Some(1));
        // N = 2 on a 1-torus: t^-1, -2, -4.
        let s = settings(Method::Vm, 1e-8, 1.0, 2, 4);
        let c = curve(
            3000,
            4,
            |j, t| -0.2 - (torus_exponent(j, 1, 2) as f64) * t.max(1.0).log10(),
            |t| (1.0 + 0.5 * t).ln() / t.max(1.0),
        );
        let v = judge(&s, &c);
        assert_eq!(v.class, Class::Regular, "{v:?}");
        assert_eq!(v.torus_dimension, Some(1));
    }

    #[test]
    fn escapes_growing_extents_and_failures_are_neither_chaotic_nor_regular() {
        let s = settings(Method::Vm, 1e-8, 1.0, 2, 4);
        let l1 = 0.05;
        let chaotic = curve(
            1500,
            4,
            |j, t| -((j - 1) as f64) * l1 * t / 10f64.ln(),
            |_| l1,
        );
        let regular = curve(
            2000,
            4,
            |j, t| -0.3 - (torus_exponent(j, 2, 2) as f64) * t.max(1.0).log10(),
            |t| (1.0 + 0.5 * t).ln() / t.max(1.0),
        );
        let bounded = extent(2000, |t| 1.0 - 0.5 / (1.0 + t));
        assert_eq!(
            judge_orbit(
                &s,
                &chaotic,
                &Orbit {
                    extent: &bounded,
                    failure: None
                }
            )
            .class,
            Class::Chaotic
        );
        // The producer's reason for an escape: escaped, with its time, whatever the curve.
        let reason = format!(
            "{} by t = 14 (|x| = 1e100)",
            chaoscope_schemas::run::REFERENCE_ESCAPED
        );
        let v = judge_orbit(
            &s,
            &chaotic,
            &Orbit {
                extent: &bounded,
                failure: Some((&reason, 13.0)),
            },
        );
        assert_eq!((v.class, v.time), (Class::Escaped, Some(14.0)), "{v:?}");
        // Any other failure: undecided.
        let v = judge_orbit(
            &s,
            &regular,
            &Orbit {
                extent: &bounded,
                failure: Some(("scheme 'mpm', set 0: zero", 2000.0)),
            },
        );
        assert_eq!(
            (v.class, v.reason),
            (Class::Undecided, Some(Undecided::RunFailed)),
            "{v:?}"
        );
        // A linear drift: unbounded; a square-root diffusion too; a bounded orbit is not.
        for r in [|t: f64| 1.0 + 4.0 * t, |t: f64| 1.0 + t.sqrt()] {
            let e = extent(2000, r);
            let v = judge_orbit(
                &s,
                &regular,
                &Orbit {
                    extent: &e,
                    failure: None,
                },
            );
            assert_eq!((v.class, v.time), (Class::Unbounded, Some(2000.0)), "{v:?}");
        }
        let v = judge_orbit(
            &s,
            &regular,
            &Orbit {
                extent: &bounded,
                failure: None,
            },
        );
        assert_eq!(v.class, Class::Regular, "{v:?}");
        // A slow growth (t^0.2: 1.6 per decade) is not unbounded, but not regular either.
        let e = extent(2000, |t| (1.0 + t).powf(0.2));
        let v = judge_orbit(
            &s,
            &regular,
            &Orbit {
                extent: &e,
                failure: None,
            },
        );
        assert_eq!(
            (v.class, v.reason),
            (Class::Undecided, Some(Undecided::ExtentGrowing))
        );
        // One jump to a new region (x2 at t = 1500) is not a steady growth.
        let e = extent(2000, |t| if t < 1500.0 { 1.0 } else { 2.5 });
        let v = judge_orbit(
            &s,
            &chaotic,
            &Orbit {
                extent: &e,
                failure: None,
            },
        );
        assert_eq!(v.class, Class::Chaotic, "{v:?}");
    }

    #[test]
    fn one_vector_is_decided_by_its_exponent_alone() {
        // k = 1 (a 1-D map): no GALI. MLE ln 2 (the logistic map at r = 4): the deviation grows
        // by 0.69 * 50 = 35 e-folds over [50, 100], 3.5 times the exponent-alone threshold.
        let s = settings(Method::Vm, 1e-8, 1.0, 0, 1);
        let v = judge(&s, &curve(100, 1, |_, _| 0.0, |_| 2f64.ln()));
        assert_eq!(v.class, Class::Chaotic, "{v:?}");
        assert!(!v.criterion.contains("GALI"), "{}", v.criterion);
        // MLE -0.1 (an attracting cycle): it shrinks by e^10 over [t/2, t] from t = 200 on.
        let v = judge(&s, &curve(400, 1, |_, _| 0.0, |_| -0.1));
        assert_eq!(v.class, Class::Attracting, "{v:?}");
        assert!(v.criterion.contains("MLE -1.000e-1"), "{}", v.criterion);
        let v = judge(&s, &curve(100, 1, |_, _| 0.0, |_| -0.1));
        assert_eq!(
            (v.class, v.reason),
            (Class::Undecided, Some(Undecided::MleBelowThreshold)),
            "{v:?}"
        );
        assert!(!v.criterion.contains("GALI"), "{}", v.criterion);
        // A neutral orbit (MLE ~ ln(t)/t) is never decided by the exponent alone.
        let v = judge(
            &s,
            &curve(3000, 1, |_, _| 0.0, |t| (1.0 + t).ln() / t.max(1.0)),
        );
        assert_eq!(v.class, Class::Undecided, "{v:?}");
    }

    /// The curve of `curve` recorded at every `every`-th time only (`[run] sample_every`).
    fn sampled(c: Vec<(f64, SchemePoint)>, every: usize) -> Vec<(f64, SchemePoint)> {
        c.into_iter().step_by(every).collect()
    }

    #[test]
    fn gali_falling_to_the_floor_between_samples_with_the_exponent_beyond_doubt_is_chaotic() {
        // The standard map at K = 1.2 in its chaotic sea: GALI_2 ~ exp(-2 l1 t) with l1 ~ 0.3
        // over the first tens of iterations reaches VM's floor by t = 60 (measured: -11.7 at
        // t = 50, the floor at 60); sampled every 10 iterations, no window [t'/2, t'] holds 5
        // samples above it.
        let s = settings(Method::Vm, 1e-8, 1.0, 1, 2);
        let l1 = 0.3;
        let c = sampled(
            curve(
                2000,
                2,
                |_, t| (-2.0 * l1 * t / 10f64.ln()).max(-15.65),
                |_| l1,
            ),
            10,
        );
        let v = judge(&s, &c);
        assert_eq!(v.class, Class::Chaotic, "{v:?}");
        assert!(v.criterion.contains("rounding floor"), "{}", v.criterion);
        // A regular orbit's GALI_2 at the floor (MPM on an island, eps/d0 reached) with linear
        // growth of the deviation is not chaotic.
        let c = sampled(
            curve(
                2000,
                2,
                |_, t| (-2.0 * t.max(1.0).log10()).max(-15.65),
                |t| (1.0 + 0.5 * t).ln() / t.max(1.0),
            ),
            10,
        );
        assert_ne!(judge(&s, &c).class, Class::Chaotic);
    }

    #[test]
    fn a_chaotic_drift_is_chaotic_and_a_regular_drift_unbounded() {
        // Chaotic diffusion: the extent grows like t^(1/2) (x3.2 per decade) while nearby
        // orbits diverge at l1 = 0.05: chaotic. The same drift with linear growth of the
        // deviation, or an extent running away faster than any power law (e^(t/100): x10^7.8
        // over the latest decade), is unbounded.
        let s = settings(Method::Vm, 1e-8, 1.0, 2, 4);
        let l1 = 0.05;
        let chaotic = curve(
            2000,
            4,
            |j, t| -((j - 1) as f64) * (l1 * t / 10f64.ln()).min(15.0),
            |_| l1,
        );
        let regular = curve(
            2000,
            4,
            |j, t| -0.3 - (torus_exponent(j, 2, 2) as f64) * t.max(1.0).log10(),
            |t| (1.0 + 0.5 * t).ln() / t.max(1.0),
        );
        let diffusing = extent(2000, |t| 1.0 + t.sqrt());
        let orbit = Orbit {
            extent: &diffusing,
            failure: None,
        };
        let v = judge_orbit(&s, &chaotic, &orbit);
        assert_eq!(v.class, Class::Chaotic, "{v:?}");
        assert!(v.criterion.contains("chaotic diffusion"), "{}", v.criterion);
        assert_eq!(judge_orbit(&s, &regular, &orbit).class, Class::Unbounded);
        let runaway = extent(2000, |t| (t / 100.0).exp());
        let v = judge_orbit(
            &s,
            &chaotic,
            &Orbit {
                extent: &runaway,
                failure: None,
            },
        );
        assert_eq!(v.class, Class::Unbounded, "{v:?}");
    }

    #[test]
    fn an_integrator_failure_is_failed_not_escaped() {
        let s = settings(Method::Vm, 1e-8, 1.0, 2, 4);
        let c = curve(200, 4, |_, _| -0.3, |_| 0.01);
        let bounded = extent(200, |_| 1.0);
        let reason = format!(
            "{} by t = 135.5: {} within 64 sweeps",
            chaoscope_schemas::run::INTEGRATOR_FAILED,
            chaoscope_schemas::run::IMPLICIT_NOT_CONVERGED
        );
        let v = judge_orbit(
            &s,
            &c,
            &Orbit {
                extent: &bounded,
                failure: Some((&reason, 135.0)),
            },
        );
        assert_eq!((v.class, v.time), (Class::Failed, Some(135.5)), "{v:?}");
        assert!(v.criterion.contains("did not converge"), "{}", v.criterion);
    }

    #[test]
    fn the_qr_criterion_states_its_ratio_and_the_exponent_sum_is_checked() {
        let mut s = settings(Method::Vm, 1e-8, 1.0, 1, 3);
        s.orthonormalize = Orthonormalization::Qr;
        let c = curve(200, 3, |_, _| 0.0, |_| 0.9);
        let v = judge(&s, &c);
        assert_eq!(v.class, Class::Chaotic);
        // The thinned curve (about 40 points per decade) has t = 95 as its last point at or
        // before 100: the deviation grew by e^(0.9 * 105) = e^94.5, 9.4 times e^10.
        assert!(
            v.criterion.contains("9.4 times its threshold"),
            "{}",
            v.criterion
        );
        // A QR scheme has exponents only: its criterion names no GALI.
        assert!(!v.criterion.contains("GALI"), "{}", v.criterion);
        let point = |sum_off: f64| SchemePoint {
            gali_log10_mean: vec![0.0, 0.0],
            gali_log10_of_mean: Vec::new(),
            sali_log10_mean: None,
            lyapunov: vec![0.906, 0.0, -14.573 + sum_off],
            vs_vm_abs_delta: None,
            named: Vec::new(),
            lyapunov_from: None,
        };
        let run = RunValues {
            energy_error_max: 0.0,
            mean_divergence: Some(-13.667),
            complete: true,
            dim: 3,
            ..RunValues::default()
        };
        let codes = |p: &SchemePoint| -> Vec<String> {
            warnings(&s, &run, &[(100.0, p)], &v)
                .into_iter()
                .map(|w| w.code)
                .collect()
        };
        assert!(codes(&point(0.0)).is_empty());
        assert_eq!(codes(&point(0.1)), [EXPONENT_SUM_OFF_DIVERGENCE]);
    }
}
