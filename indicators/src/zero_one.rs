//! The 0-1 test for chaos (Gottwald and Melbourne 2004; the implementation of Gottwald and
//! Melbourne 2009, "On the implementation of the 0-1 test for chaos", SIAM J. Appl. Dyn. Syst.
//! 8, 129): `K` near 0 for a regular orbit, near 1 for a chaotic one, from an observable of the
//! orbit alone, no deviation vector.
//!
//! The observable ([`ZeroOneObservable`]) is, by default, [`generic_observable`]: every
//! coordinate of the state with a fixed unequal weight, a periodic coordinate by the sine and
//! cosine of its angle. Why that one: the test needs an observable that sees the whole orbit.
//! A single coordinate does not on a lattice, where `x1` is an end site that the energy may
//! never reach (on the chaotic Klein-Gordon chain of `examples/models/` it reads K = -0.05 at
//! t = 2000 and 0.37 at t = 10^4); every coordinate enters the combination, none dominates.
//! The weights are unequal because an equal-weight sum is often a conserved or slow quantity
//! (the total momentum of a chain); they are `1/2 + frac((i + 1/2) g)`, `g` the golden ratio's
//! fractional part, in `[1/2, 3/2)`, and never change (a number of a run must not depend on
//! anything else). A wrapped coordinate (a map's angle) jumps by its period at the seam, which
//! the test reads as chaos (K = 0.46 on an island of the standard map whose momentum is
//! wrapped); its sine and cosine have no seam. A flow's angle that is not declared periodic is
//! read as integrated, continuous (a declared one gives the same sine and cosine either way).
//! A run's `[analysis] zero_one_observable` replaces it with an expression of the state,
//! compiled by whoever holds the system ([`ZeroOneObservable::Function`]).
//!
//! The observable is sampled at the scheme's renormalizations. The samples are kept bounded:
//! at most [`MAX_SAMPLES`], and when full every other one is dropped and the stride doubled, so
//! the series spans the whole run with between `MAX_SAMPLES / 2` and `MAX_SAMPLES` evenly spaced
//! samples (whatever the run length, and deterministic). The stride growing with the run keeps
//! the sampling from being much finer than the orbit's own times, where the test would read
//! chaos as regular (oversampling, Gottwald and Melbourne 2009, section 5.3). It has the
//! opposite cost on a lattice of many frequencies: a stride that spreads (aliases) the band of
//! its frequencies over the whole range of `c` reads a regular chain as chaotic (the Klein-Gordon
//! chain of 64 sites sampled every 4 time units: K = 0.7 on a regular orbit). [`MAX_SAMPLES`]
//! is therefore large: a run of up to 8192 renormalizations keeps every one.
//!
//! From `N` samples `phi_j`: for each `c`, the translation variables
//! `p_c(n) = sum_{j<=n} phi_j cos(jc)`, `q_c(n) = sum phi_j sin(jc)`, the mean square
//! displacement `M_c(n)` for `n <= n_cut = N/10`, its oscillating term subtracted
//! (`D_c = M_c - (E phi)^2 (1 - cos nc) / (1 - cos c)`), and `K_c` the correlation of `D_c(n)`
//! with `n`; `K` is the median of `K_c` over [`C_VALUES`] values of `c` in `(pi/5, 4 pi/5)`
//! (away from the resonances at 0 and pi; the median removes the rest). The `c` values are a
//! fixed low-discrepancy sequence rather than random ones, so `K` is a function of the samples.
//!
//! The length rule ([`MIN_SAMPLES`] = 1000): `K_c` is the correlation coefficient of the
//! `n_cut` points `D_c(1..n_cut)` with their index. Where `D_c` has no trend (a regular orbit)
//! that coefficient scatters about 0 by about `1 / sqrt(n_cut)`; a reading whose scatter is not
//! well below the margin the test is read with (K < 0.1 regular, K > 0.9 chaotic) tells
//! nothing, so `n_cut >= 100`, `N >= 1000`. The resolution in `c` is then `2 pi / n_cut` =
//! 0.06, a thirtieth of the range of `c`, so a handful of frequencies of a regular orbit cannot
//! make most `c` resonant. Shorter series give no `K` but the length they would need.

use std::sync::Arc;

use rustfft::num_complex::Complex;
use rustfft::{Fft, FftPlannerScalar};

use crate::indicator::{OrbitIndicator, Output};
use crate::periodic::wrap_coordinate;

/// Most samples kept (between half of it and all of it once the run is long enough).
pub const MAX_SAMPLES: usize = 8192;
/// Fewest samples the test is computed from (`n_cut` = 100 displacements at least; the module
/// documentation says why).
pub const MIN_SAMPLES: usize = 1000;
/// Values of `c` the median is taken over.
pub const C_VALUES: usize = 100;

/// The fractional part of the golden ratio: the weights of [`generic_observable`] and the `c`
/// values of the median are its multiples modulo 1, spread evenly and never repeating.
const GOLDEN: f64 = 0.618_033_988_749_894_9;

/// The weight of entry `i` of [`generic_observable`], in `[1/2, 3/2)`.
fn weight(i: usize) -> f64 {
    0.5 + ((i as f64 + 0.5) * GOLDEN).fract()
}

/// The default observable of the 0-1 test: `sum_i w_i x_i` over the state's coordinates, a
/// coordinate with a period `P = periods[i] > 0` entering as `w_i sin(2 pi x_i / P) + w_{D+i}
/// cos(2 pi x_i / P)` (no seam where it wraps); the weights `w_i` in `[1/2, 3/2)` are fixed
/// and unequal (the module documentation says why).
pub fn generic_observable(periods: &[f64], x: &[f64]) -> f64 {
    let d = x.len();
    let mut sum = 0.0;
    for (i, &v) in x.iter().enumerate() {
        let p = periods.get(i).copied().unwrap_or(0.0);
        if p > 0.0 {
            // Wrapped first: the angle of a flow that turned many times keeps its digits.
            let angle = std::f64::consts::TAU * (wrap_coordinate(v, p) / p);
            sum += weight(i) * angle.sin() + weight(d + i) * angle.cos();
        } else {
            sum += weight(i) * v;
        }
    }
    sum
}

/// A function of the state, as whoever holds the system compiles it.
pub type ObservableFn = dyn Fn(&[f64]) -> f64 + Send + Sync;

/// What the 0-1 test observes of each sampled state.
#[derive(Clone)]
pub enum ZeroOneObservable {
    /// [`generic_observable`] with the periods of the state's coordinates (`[model] modulo`;
    /// empty for none).
    Generic { periods: Vec<f64> },
    /// A function of the state: a run's `[analysis] zero_one_observable`, compiled.
    Function {
        source: String,
        function: Arc<ObservableFn>,
    },
    /// A run asks for an observable this reader cannot evaluate: why (the test then says so).
    Unavailable(String),
}

impl std::fmt::Debug for ZeroOneObservable {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::Generic { periods } => write!(f, "Generic {{ periods: {periods:?} }}"),
            Self::Function { source, .. } => write!(f, "Function({source:?})"),
            Self::Unavailable(why) => write!(f, "Unavailable({why:?})"),
        }
    }
}

impl ZeroOneObservable {
    fn value(&self, state: &[f64]) -> Option<f64> {
        match self {
            Self::Generic { periods } => Some(generic_observable(periods, state)),
            Self::Function { function, .. } => Some(function(state)),
            Self::Unavailable(_) => None,
        }
    }
}

#[derive(Debug, Clone)]
pub struct ZeroOneTest {
    observable: ZeroOneObservable,
    samples: Vec<f64>,
    /// Keep one state in `stride`.
    stride: u64,
    /// States offered so far.
    offered: u64,
    /// Times of the first and the latest sample kept (the length a short series would need).
    first_t: Option<f64>,
    last_t: f64,
    /// States where the observable was not finite (a configured expression's pole), left out.
    not_finite: u64,
}

impl ZeroOneTest {
    pub fn new(observable: ZeroOneObservable) -> Self {
        Self {
            observable,
            samples: Vec::new(),
            stride: 1,
            offered: 0,
            first_t: None,
            last_t: 0.0,
            not_finite: 0,
        }
    }
}

impl Default for ZeroOneTest {
    /// The generic observable of a state with no periodic coordinate.
    fn default() -> Self {
        Self::new(ZeroOneObservable::Generic {
            periods: Vec::new(),
        })
    }
}

impl OrbitIndicator for ZeroOneTest {
    fn names(&self) -> &'static [&'static str] {
        &["zero_one_k"]
    }

    fn observe(&mut self, t: f64, state: &[f64]) {
        let Some(phi) = self.observable.value(state) else {
            return;
        };
        if !phi.is_finite() {
            self.not_finite += 1;
            return;
        }
        if self.offered.is_multiple_of(self.stride) {
            self.samples.push(phi);
            self.first_t.get_or_insert(t);
            self.last_t = t;
            if self.samples.len() == MAX_SAMPLES {
                let kept: Vec<f64> = self.samples.iter().copied().step_by(2).collect();
                self.samples = kept;
                self.stride *= 2;
            }
        }
        self.offered += 1;
    }

    fn outputs(&self) -> Vec<Output> {
        if let ZeroOneObservable::Unavailable(why) = &self.observable {
            return vec![Output::Unavailable(why.clone())];
        }
        vec![match zero_one_k(&self.samples) {
            Some(k) => Output::Value(k),
            None => Output::Unavailable(self.too_short()),
        }]
    }

    fn boxed_clone(&self) -> Box<dyn OrbitIndicator> {
        Box::new(self.clone())
    }
}

impl ZeroOneTest {
    /// Why a series shorter than [`MIN_SAMPLES`] gives no `K`, and how long it would need to be.
    fn too_short(&self) -> String {
        let n = self.samples.len();
        let needed = match self.first_t {
            // Below MIN_SAMPLES < MAX_SAMPLES nothing was thinned: the samples are the
            // renormalizations, evenly spaced.
            Some(first) if n >= 2 => {
                let dt = (self.last_t - first) / (n - 1) as f64;
                let t = first + (MIN_SAMPLES - 1) as f64 * dt;
                format!(", to t = {t} at this scheme's sampling")
            }
            _ => String::new(),
        };
        let left_out = match self.not_finite {
            0 => String::new(),
            m => format!(" ({m} states where the observable is not finite left out)"),
        };
        format!(
            "the series is too short for the 0-1 test: {n} samples of the orbit \
             (renormalizations){left_out}; it needs at least {MIN_SAMPLES}{needed}"
        )
    }
}

/// `K` of the 0-1 test from evenly spaced samples of an observable; `None` for fewer than
/// [`MIN_SAMPLES`]. In `[-1, 1]` (a correlation), near 0 regular, near 1 chaotic.
pub fn zero_one_k(phi: &[f64]) -> Option<f64> {
    let n = phi.len();
    if n < MIN_SAMPLES {
        return None;
    }
    let n_cut = n / 10;
    let mean = phi.iter().sum::<f64>() / n as f64;
    // A constant observable (an equilibrium) is regular: no displacement at all.
    if phi.iter().all(|&v| v == phi[0]) {
        return Some(0.0);
    }
    let golden = GOLDEN;
    let pi = std::f64::consts::PI;
    let mut sums = DisplacementSums::new(n, n_cut);
    let mut ks: Vec<f64> = (0..C_VALUES)
        .map(|i| {
            let c = pi / 5.0 + (3.0 * pi / 5.0) * ((i as f64 + 0.5) * golden).fract();
            k_of_c(phi, mean, c, n_cut, &mut sums)
        })
        .collect();
    ks.sort_by(f64::total_cmp);
    let median = if C_VALUES % 2 == 1 {
        ks[C_VALUES / 2]
    } else {
        0.5 * (ks[C_VALUES / 2 - 1] + ks[C_VALUES / 2])
    };
    Some(if median.is_finite() { median } else { 0.0 })
}

/// `K_c`: the correlation of the modified mean square displacement `D_c(n)` with `n`.
///
/// `D_c` without its cancellation: with `phi_j = E phi + psi_j`, the translation variables are
/// `z = (E phi) w + y`, `w_j = sum_{i<=j} e^{i(i+1)c}` known in closed form and `y` those of
/// `psi` alone. Every displacement of `w` over `n` steps has the same modulus, so the square
/// displacement is `|dy|^2 + 2 E phi Re(conj(dw) dy) + (E phi)^2 (1 - cos nc) / (1 - cos c)`,
/// whose last term is the one `D_c` subtracts: `D_c(n)` is the mean of the first two, summed
/// here without ever adding that term (which dwarfs the others where `E phi` is large against the
/// spread of `phi`). The same number as `M_c - (E phi)^2 (1 - cos nc) / (1 - cos c)`.
fn k_of_c(phi: &[f64], mean: f64, c: f64, n_cut: usize, sums: &mut DisplacementSums) -> f64 {
    let n = phi.len();
    let (mut ps, mut qs) = (0.0, 0.0);
    // e^{-i(j+2)c}, from the same cosine and sine, for the cross term's sums.
    let mut back = Vec::with_capacity(n);
    let unit = Complex::new(c.cos(), c.sin());
    let step_back = unit.conj();
    for (j, (z, &v)) in sums.z.iter_mut().zip(phi).enumerate() {
        let a = (j + 1) as f64 * c;
        let (sin, cos) = a.sin_cos();
        ps += (v - mean) * cos;
        qs += (v - mean) * sin;
        *z = Complex::new(ps, qs);
        back.push(Complex::new(cos, -sin) * step_back);
    }
    // y shifted by its mean (no displacement sees it), then Q_k = sum_{j<k} e^{-i(j+2)c} y_j.
    sums.center(n);
    let mut q = Vec::with_capacity(n + 1);
    q.push(Complex::new(0.0, 0.0));
    let mut acc = Complex::new(0.0, 0.0);
    for (z, b) in sums.z[..n].iter().zip(&back) {
        acc += *z * b;
        q.push(acc);
    }
    let s = sums.square_displacements(n, n_cut);
    let one_step = Complex::new(1.0, 0.0) - unit;
    let d: Vec<f64> = (1..=n_cut)
        .map(|lag| {
            let turn = Complex::new((lag as f64 * c).cos(), (lag as f64 * c).sin());
            // dw_j = e^{i(j+2)c} g; sum_j e^{-i(j+2)c} dy_j from the prefix sums of Q.
            let g = (Complex::new(1.0, 0.0) - turn) / one_step;
            let x = turn * (q[n] - q[lag]) - q[n - lag];
            let cross = 2.0 * mean * (g.conj() * x).re;
            (s[lag - 1] + cross) / (n - lag) as f64
        })
        .collect();
    correlation_with_index(&d)
}

/// `S(lag) = sum_j |z_{j+lag} - z_j|^2` of a series `z = p + i q` for every lag up to `n_cut`
/// at once, by the autocorrelation through the FFT: `S(lag) = A(lag) + B(lag) - 2 Re C(lag)`,
/// `A` and `B` sums of `|z_j|^2` over the two ranges, `C(lag) = sum_j z_{j+lag} conj(z_j)`.
/// `O(N log N)` for the `n_cut = N / 10` lags where the direct sums cost `O(N^2 / 10)`, which
/// every live report of a long run would pay (`docs/decisions/0019-zero-one-test-by-the-fft.md`).
///
/// Why it keeps its digits: `z` is centered first (`S` does not see a constant), and
/// `k_of_c` gives it the translation variables of the observable less its mean (the mean's
/// part is summed in closed form), so `A`, `B` and `C` are of the size of the spread of `z`,
/// and their difference of the size of `S`, except for the smallest lags of a series that
/// drifts far (a chaotic one: `z` a random walk). There the error is about
/// `eps log2(m) N / lag` of `S`, `1e-11` at `N = 8192`, far below the correlation's own
/// scatter; the test below measures it against the direct sums (an estimate, not a bound: the
/// FFT's error is one of norms). The FFT is rustfft's scalar one: no instruction
/// set chooses its algorithm, so the bits are the same on every machine.
struct DisplacementSums {
    /// The series, then its transform, padded with zeros to `m >= N + n_cut` (no lag up to
    /// `n_cut` wraps around).
    z: Vec<Complex<f64>>,
    forward: Arc<dyn Fft<f64>>,
    inverse: Arc<dyn Fft<f64>>,
    scratch: Vec<Complex<f64>>,
}

/// The least `2^a 3^b >= len`: a length rustfft transforms by its fast radix-2 and radix-3
/// steps, at most 1.5 times `len` where the next power of two can be twice it.
fn smooth_length(len: usize) -> usize {
    let mut best = len.next_power_of_two();
    let mut three = 1;
    while three < best {
        let mut m = three;
        while m < len {
            m *= 2;
        }
        best = best.min(m);
        three *= 3;
    }
    best
}

impl DisplacementSums {
    fn new(n: usize, n_cut: usize) -> Self {
        let m = smooth_length(n + n_cut);
        let mut planner = FftPlannerScalar::new();
        let forward = planner.plan_fft_forward(m);
        let inverse = planner.plan_fft_inverse(m);
        let scratch_len = forward
            .get_inplace_scratch_len()
            .max(inverse.get_inplace_scratch_len());
        Self {
            z: vec![Complex::new(0.0, 0.0); m],
            forward,
            inverse,
            scratch: vec![Complex::new(0.0, 0.0); scratch_len],
        }
    }

    /// Shifts the first `n` entries of `self.z` by their mean: `S` does not see it, and the sums
    /// of [`DisplacementSums::square_displacements`] keep their digits only without it.
    fn center(&mut self, n: usize) {
        let shift = self.z[..n].iter().sum::<Complex<f64>>() / n as f64;
        for z in &mut self.z[..n] {
            *z -= shift;
        }
    }

    /// `S(1..=n_cut)` of the first `n` entries of `self.z`, centered ([`DisplacementSums::center`]),
    /// which it overwrites.
    fn square_displacements(&mut self, n: usize, n_cut: usize) -> Vec<f64> {
        let m = self.z.len();
        for z in &mut self.z[n..] {
            *z = Complex::new(0.0, 0.0);
        }
        // prefix[j] = sum_{i < j} |z_i|^2.
        let mut prefix = Vec::with_capacity(n + 1);
        prefix.push(0.0);
        let mut acc = 0.0;
        for z in &self.z[..n] {
            acc += z.norm_sqr();
            prefix.push(acc);
        }
        self.forward
            .process_with_scratch(&mut self.z, &mut self.scratch);
        for z in &mut self.z {
            *z = Complex::new(z.norm_sqr(), 0.0);
        }
        self.inverse
            .process_with_scratch(&mut self.z, &mut self.scratch);
        (1..=n_cut)
            .map(|lag| {
                // A: j from lag to n - 1; B: j from 0 to n - 1 - lag; C unnormalized by m.
                let a = prefix[n] - prefix[lag];
                let b = prefix[n - lag];
                let cross = self.z[lag].re / m as f64;
                (a + b - 2.0 * cross).max(0.0)
            })
            .collect()
    }
}

/// Pearson correlation of `d[i]` with `i`; 0 when `d` does not vary.
fn correlation_with_index(d: &[f64]) -> f64 {
    let m = d.len() as f64;
    let xm = (m + 1.0) / 2.0;
    let dm = d.iter().sum::<f64>() / m;
    let (mut sxy, mut sxx, mut syy) = (0.0, 0.0, 0.0);
    for (i, &v) in d.iter().enumerate() {
        let x = (i + 1) as f64 - xm;
        let y = v - dm;
        sxy += x * y;
        sxx += x * x;
        syy += y * y;
    }
    if syy > 0.0 {
        sxy / (sxx * syy).sqrt()
    } else {
        0.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `n` iterates of the logistic map `x -> r x (1 - x)` after a transient of 1000.
    fn logistic(r: f64, n: usize) -> Vec<f64> {
        let mut x = 0.3;
        for _ in 0..1000 {
            x = r * x * (1.0 - x);
        }
        (0..n)
            .map(|_| {
                x = r * x * (1.0 - x);
                x
            })
            .collect()
    }

    #[test]
    fn logistic_map_regular_and_chaotic() {
        // Gottwald and Melbourne's example: r = 3.55 (period 8) and r = 3.97 (chaotic), 2000
        // samples of x. For a periodic observable D_c is bounded and its correlation with n
        // vanishes like 1/N away from resonant c (the median discards those): K < 0.1. For
        // the chaotic one D_c grows linearly (diffusion of p, q) up to fluctuations of relative
        // size sqrt(n_cut / N) ~ 0.3 around the line, which correlation forgives: K > 0.9.
        let regular = zero_one_k(&logistic(3.55, 2000)).unwrap();
        assert!(regular.abs() < 0.1, "K = {regular}");
        let chaotic = zero_one_k(&logistic(3.97, 2000)).unwrap();
        assert!(chaotic > 0.9, "K = {chaotic}");
        // Quasi-periodic (two incommensurate frequencies), as a regular Hamiltonian orbit.
        let qp: Vec<f64> = (0..2000)
            .map(|j| (0.7 * j as f64).sin() + 0.5 * (0.7 * 2f64.sqrt() * j as f64).cos())
            .collect();
        let k = zero_one_k(&qp).unwrap();
        assert!(k.abs() < 0.1, "K = {k}");
    }

    /// `sum_j |z_{j+lag} - z_j|^2` summed directly, term by term.
    fn direct_square_displacement(z: &[Complex<f64>], lag: usize) -> f64 {
        z.windows(lag + 1).map(|w| (w[lag] - w[0]).norm_sqr()).sum()
    }

    #[test]
    fn displacement_sums_by_the_fft_are_the_direct_sums() {
        // Three series as the test meets them: a random walk far from its start (a chaotic
        // orbit's p, q; the worst case for the cancellation in A + B - 2 Re C), a bounded
        // quasi-periodic one around a large offset (a regular orbit's), and a drift. Each
        // difference is compared with an estimate of the rounding (not a bound): about
        // eps log2(m) times the series' squared spread per term, summed over N - lag terms,
        // times 4; the differences measured are 0.02 to 0.2 of it.
        let n = 4000;
        let walk = {
            let mut x = 0.3f64;
            let (mut p, mut q) = (1.0e3, -2.0e3);
            (0..n)
                .map(|j| {
                    x = 3.97 * x * (1.0 - x);
                    p += x * (0.9 * j as f64).cos();
                    q += x * (0.9 * j as f64).sin();
                    Complex::new(p, q)
                })
                .collect::<Vec<_>>()
        };
        let bounded: Vec<Complex<f64>> = (0..n)
            .map(|j| {
                let t = j as f64;
                Complex::new(
                    5.0e4 + (0.7 * t).sin() + 0.5 * (0.7 * 2f64.sqrt() * t).cos(),
                    -3.0e4 + (1.3 * t).cos(),
                )
            })
            .collect();
        let drift: Vec<Complex<f64>> = (0..n)
            .map(|j| Complex::new(0.01 * j as f64, (0.2 * j as f64).sin()))
            .collect();
        let n_cut = n / 10;
        for (name, z) in [("walk", walk), ("bounded", bounded), ("drift", drift)] {
            let mut sums = DisplacementSums::new(n, n_cut);
            sums.z[..n].copy_from_slice(&z);
            sums.center(n);
            let fft = sums.square_displacements(n, n_cut);
            let mean = z.iter().sum::<Complex<f64>>() / n as f64;
            let spread = z.iter().map(|v| (v - mean).norm_sqr()).fold(0.0, f64::max);
            for lag in [1, 2, 7, 100, n_cut] {
                let direct = direct_square_displacement(&z, lag);
                let allowed = 1e-16 * 13.0 * spread * (n - lag) as f64 * 4.0;
                let diff = (fft[lag - 1] - direct).abs();
                assert!(
                    diff <= allowed,
                    "{name}, lag {lag}: {} against {direct} (allowed {allowed:e})",
                    fft[lag - 1]
                );
            }
        }
    }

    #[test]
    fn transform_lengths_are_the_least_products_of_twos_and_threes() {
        assert_eq!(smooth_length(1000), 1024);
        assert_eq!(smooth_length(1100), 1152);
        assert_eq!(smooth_length(8192 + 819), 9216);
        assert_eq!(smooth_length(4096), 4096);
        for len in 1..5000 {
            let m = smooth_length(len);
            let mut r = m;
            for p in [2, 3] {
                while r.is_multiple_of(p) {
                    r /= p;
                }
            }
            assert!(m >= len && r == 1 && 2 * m <= 3 * len.max(2), "{len}: {m}");
        }
    }

    #[test]
    fn k_by_the_fft_is_k_by_the_direct_sums() {
        // The whole test both ways, the direct way as written in the literature, on the regular
        // and chaotic logistic series: K changes only in digits far below the margins it is
        // read with (measured 4e-15). With a constant added to the observable (10, 1000), which
        // `k_of_c` keeps out of the displacements, the direct sums' own rounding grows with its
        // square (measured 1e-12 and 8e-12).
        for (r, offset) in [(3.55, 0.0), (3.97, 0.0), (3.55, 10.0), (3.97, 1000.0)] {
            let phi: Vec<f64> = logistic(r, 3000).iter().map(|x| x + offset).collect();
            let n = phi.len();
            let n_cut = n / 10;
            let mean = phi.iter().sum::<f64>() / n as f64;
            let golden = GOLDEN;
            let pi = std::f64::consts::PI;
            let mut ks: Vec<f64> = (0..C_VALUES)
                .map(|i| {
                    let c = pi / 5.0 + (3.0 * pi / 5.0) * ((i as f64 + 0.5) * golden).fract();
                    let (mut ps, mut qs) = (0.0, 0.0);
                    let z: Vec<Complex<f64>> = phi
                        .iter()
                        .enumerate()
                        .map(|(j, &v)| {
                            let a = (j + 1) as f64 * c;
                            ps += v * a.cos();
                            qs += v * a.sin();
                            Complex::new(ps, qs)
                        })
                        .collect();
                    let d: Vec<f64> = (1..=n_cut)
                        .map(|lag| {
                            direct_square_displacement(&z, lag) / (n - lag) as f64
                                - mean * mean * (1.0 - (lag as f64 * c).cos()) / (1.0 - c.cos())
                        })
                        .collect();
                    correlation_with_index(&d)
                })
                .collect();
            ks.sort_by(f64::total_cmp);
            let direct = 0.5 * (ks[C_VALUES / 2 - 1] + ks[C_VALUES / 2]);
            let fft = zero_one_k(&phi).unwrap();
            assert!(
                (fft - direct).abs() < 1e-9,
                "r = {r}, offset {offset}: {fft} against {direct}"
            );
        }
    }

    #[test]
    fn bounded_samples_span_the_run() {
        let mut z = ZeroOneTest::new(ZeroOneObservable::Function {
            source: "x1".to_string(),
            function: Arc::new(|x: &[f64]| x[0]),
        });
        for j in 0..10_000u32 {
            z.observe(f64::from(j), &[f64::from(j)]);
        }
        // Halved at 8192 (stride 2): 4096 + (10000 - 8192) / 2.
        assert!(z.samples.len() >= MAX_SAMPLES / 2 && z.samples.len() < MAX_SAMPLES);
        assert_eq!(z.samples[1] - z.samples[0], z.stride as f64);
        assert!(matches!(
            ZeroOneTest::default().outputs()[0],
            Output::Unavailable(_)
        ));
    }

    #[test]
    fn a_short_series_says_how_long_it_would_need_to_be() {
        // 500 renormalizations every 0.5 from t = 0: 1000 samples reach t = 499.5.
        let mut z = ZeroOneTest::default();
        for j in 0..500u32 {
            let t = 0.5 * f64::from(j);
            z.observe(t, &[t.sin(), t.cos()]);
        }
        let [Output::Unavailable(why)] = &z.outputs()[..] else {
            panic!("{:?}", z.outputs())
        };
        assert!(why.contains("too short"), "{why}");
        assert!(why.contains("500 samples"), "{why}");
        assert!(why.contains("at least 1000, to t = 499.5 "), "{why}");
        // An observable that is never finite (a configured expression's pole) says so.
        let mut z = ZeroOneTest::new(ZeroOneObservable::Function {
            source: "1/0".to_string(),
            function: Arc::new(|_: &[f64]| f64::INFINITY),
        });
        z.observe(0.0, &[1.0]);
        let [Output::Unavailable(why)] = &z.outputs()[..] else {
            panic!("{:?}", z.outputs())
        };
        assert!(
            why.contains(
                "0 samples of the orbit (renormalizations) (1 states where the \
                 observable is not finite left out); it needs at least 1000"
            ),
            "{why}"
        );
    }

    #[test]
    fn the_generic_observable_weighs_every_coordinate_and_has_no_seam() {
        // Every weight in [1/2, 3/2), no two equal among the first thousand.
        let w: Vec<f64> = (0..1000).map(weight).collect();
        assert!(w.iter().all(|w| (0.5..1.5).contains(w)));
        let mut sorted = w.clone();
        sorted.sort_by(f64::total_cmp);
        assert!(sorted.windows(2).all(|p| p[0] < p[1]));
        // A periodic coordinate reads the same on both sides of its seam and a period apart.
        let tau = std::f64::consts::TAU;
        let periods = [tau, 0.0];
        let below = generic_observable(&periods, &[tau - 1e-12, 0.3]);
        let above = generic_observable(&periods, &[1e-12, 0.3]);
        assert!((below - above).abs() < 1e-11, "{below} {above}");
        let turned = generic_observable(&periods, &[1.0 + 40.0 * tau, 0.3]);
        assert!((turned - generic_observable(&periods, &[1.0, 0.3])).abs() < 1e-12);
        // Without periods it is the weighted sum.
        assert_eq!(generic_observable(&[], &[2.0, 0.0]), 2.0 * weight(0));
    }
}
