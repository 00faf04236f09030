//! Explicit Runge-Kutta methods for general vector fields `dx/dt = f(x)`: the classical rk4
//! and Dormand-Prince 8(5,3) (`dop853`, Hairer's coefficients), with a fixed step or, for
//! `dop853`, error control on its embedded 5th- and 3rd-order estimates.
//!
//! The tangent map of a step is its exact derivative: each stage's Jacobian `J(X_i)` at the
//! stage state applied to the stage's tangent, `K_i = J(X_i) (w + h sum_j a_ij K_j)`,
//! `w' = w + h sum_i b_i K_i`. So the variational method (VM) sees the linearization of the very
//! map the multi-particle method (MPM) iterates, as for the splittings. The stage states are
//! computed by one function for both, so a tangent step moves its copy of the orbit to exactly
//! the bits of a plain step.
//!
//! Time: stage `i` of a step from time `t` evaluates the field (and, for the tangent, its
//! Jacobian) at `t + c_i h`; an adaptive step's substeps start at `t` plus the substeps before
//! them, summed in order, which is how followers of its plan compute them too. A field that
//! does not read the time gets the same bits whatever it is given.

// The stage loops index several arrays (stage rows, the state, the tableau) by the same
// coordinate; iterators over one of them would hide that symmetry.
#![allow(clippy::needless_range_loop)]

use super::gauss_legendre::{self, ImplicitScratch, ImplicitTableau};
use super::{Integrator, TangentError, Workspace};
use crate::vector_field::VectorField;

/// Which tableau.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum RungeKuttaTableau {
    /// The classical 4-stage method of order 4.
    Rk4,
    /// Dormand-Prince 8(5,3): 12 stages, order 8, embedded error estimates of orders 5 and 3.
    Dop853,
    /// Gauss-Legendre, 2 stages, order 4, implicit and symplectic ([`super::gauss_legendre`]).
    Gl4,
    /// Gauss-Legendre, 3 stages, order 6, implicit and symplectic.
    Gl6,
}

impl RungeKuttaTableau {
    pub fn from_name(name: &str) -> Option<Self> {
        match name {
            "rk4" => Some(Self::Rk4),
            "dop853" => Some(Self::Dop853),
            "gl4" => Some(Self::Gl4),
            "gl6" => Some(Self::Gl6),
            _ => None,
        }
    }

    pub fn name(self) -> &'static str {
        match self {
            Self::Rk4 => "rk4",
            Self::Dop853 => "dop853",
            Self::Gl4 => "gl4",
            Self::Gl6 => "gl6",
        }
    }

    pub fn order(self) -> u32 {
        match self {
            Self::Rk4 => 4,
            Self::Dop853 => 8,
            Self::Gl4 => 4,
            Self::Gl6 => 6,
        }
    }

    /// The tableau of an explicit method; `None` for the implicit ones.
    pub fn tableau(self) -> Option<&'static Tableau> {
        match self {
            Self::Rk4 => Some(&RK4),
            Self::Dop853 => Some(&DOP853),
            Self::Gl4 | Self::Gl6 => None,
        }
    }

    /// The tableau of an implicit (Gauss-Legendre) method.
    pub fn implicit_tableau(self) -> Option<&'static ImplicitTableau> {
        match self {
            Self::Gl4 => Some(&gauss_legendre::GL4),
            Self::Gl6 => Some(&gauss_legendre::GL6),
            Self::Rk4 | Self::Dop853 => None,
        }
    }

    /// Symplectic: the Gauss-Legendre methods.
    pub fn is_symplectic(self) -> bool {
        self.implicit_tableau().is_some()
    }
}

/// An explicit Butcher tableau: `a` row by row (row `i` has `i` entries), weights `b`, nodes
/// `c`; `e5`, `e3` the error weights of an embedded pair (`b - b_hat`), if any.
#[derive(Debug)]
pub struct Tableau {
    pub a: &'static [&'static [f64]],
    pub b: &'static [f64],
    pub c: &'static [f64],
    pub e5: Option<&'static [f64]>,
    pub e3: Option<&'static [f64]>,
}

impl Tableau {
    pub fn stages(&self) -> usize {
        self.b.len()
    }
}

static RK4: Tableau = Tableau {
    a: &[&[], &[0.5], &[0.0, 0.5], &[0.0, 0.0, 1.0]],
    b: &[1.0 / 6.0, 1.0 / 3.0, 1.0 / 3.0, 1.0 / 6.0],
    c: &[0.0, 0.5, 0.5, 1.0],
    e5: None,
    e3: None,
};

// Dormand & Prince's DOP853 as published with Hairer's dop853.f (Hairer, Norsett & Wanner,
// Solving ODEs I, 2nd ed.). The digits are those of the Fortran source; each literal is rounded
// to the nearest double by the compiler.
#[allow(clippy::excessive_precision)]
static DOP853: Tableau = Tableau {
    a: &[
        &[],
        &[5.26001519587677318785587544488e-2],
        &[
            1.97250569845378994544595329183e-2,
            5.91751709536136983633785987549e-2,
        ],
        &[
            2.95875854768068491816892993775e-2,
            0.0,
            8.87627564304205475450678981324e-2,
        ],
        &[
            2.41365134159266685502369798665e-1,
            0.0,
            -8.84549479328286085344864962717e-1,
            9.24834003261792003115737966543e-1,
        ],
        &[
            3.7037037037037037037037037037e-2,
            0.0,
            0.0,
            1.70828608729473871279604482173e-1,
            1.25467687566822425016691814123e-1,
        ],
        &[
            3.7109375e-2,
            0.0,
            0.0,
            1.70252211019544039314978060272e-1,
            6.02165389804559606850219397283e-2,
            -1.7578125e-2,
        ],
        &[
            3.70920001185047927108779319836e-2,
            0.0,
            0.0,
            1.70383925712239993810214054705e-1,
            1.07262030446373284651809199168e-1,
            -1.53194377486244017527936158236e-2,
            8.27378916381402288758473766002e-3,
        ],
        &[
            6.24110958716075717114429577812e-1,
            0.0,
            0.0,
            -3.36089262944694129406857109825,
            -8.68219346841726006818189891453e-1,
            2.75920996994467083049415600797e1,
            2.01540675504778934086186788979e1,
            -4.34898841810699588477366255144e1,
        ],
        &[
            4.77662536438264365890433908527e-1,
            0.0,
            0.0,
            -2.48811461997166764192642586468,
            -5.90290826836842996371446475743e-1,
            2.12300514481811942347288949897e1,
            1.52792336328824235832596922938e1,
            -3.32882109689848629194453265587e1,
            -2.03312017085086261358222928593e-2,
        ],
        &[
            -9.3714243008598732571704021658e-1,
            0.0,
            0.0,
            5.18637242884406370830023853209,
            1.09143734899672957818500254654,
            -8.14978701074692612513997267357,
            -1.85200656599969598641566180701e1,
            2.27394870993505042818970056734e1,
            2.49360555267965238987089396762,
            -3.0467644718982195003823669022,
        ],
        &[
            2.27331014751653820792359768449,
            0.0,
            0.0,
            -1.05344954667372501984066689879e1,
            -2.00087205822486249909675718444,
            -1.79589318631187989172765950534e1,
            2.79488845294199600508499808837e1,
            -2.85899827713502369474065508674,
            -8.87285693353062954433549289258,
            1.23605671757943030647266201528e1,
            6.43392746015763530355970484046e-1,
        ],
    ],
    b: &[
        5.42937341165687622380535766363e-2,
        0.0,
        0.0,
        0.0,
        0.0,
        4.45031289275240888144113950566,
        1.89151789931450038304281599044,
        -5.8012039600105847814672114227,
        3.1116436695781989440891606237e-1,
        -1.52160949662516078556178806805e-1,
        2.01365400804030348374776537501e-1,
        4.47106157277725905176885569043e-2,
    ],
    c: &[
        0.0,
        0.526001519587677318785587544488e-1,
        0.789002279381515978178381316732e-1,
        0.118350341907227396726757197510,
        0.281649658092772603273242802490,
        0.333333333333333333333333333333,
        0.25,
        0.307692307692307692307692307692,
        0.651282051282051282051282051282,
        0.6,
        0.857142857142857142857142857142,
        1.0,
    ],
    e5: Some(&[
        0.1312004499419488073250102996e-1,
        0.0,
        0.0,
        0.0,
        0.0,
        -0.1225156446376204440720569753e1,
        -0.4957589496572501915214079952,
        0.1664377182454986536961530415e1,
        -0.3503288487499736816886487290,
        0.3341791187130174790297318841,
        0.8192320648511571246570742613e-1,
        -0.2235530786388629525884427845e-1,
    ]),
    // b minus the 3rd-order weights (bhh1 = 0.244..., bhh2 = 0.733..., bhh3 = 0.0220...).
    e3: Some(&[
        5.42937341165687622380535766363e-2 - 0.244094488188976377952755905512,
        0.0,
        0.0,
        0.0,
        0.0,
        4.45031289275240888144113950566,
        1.89151789931450038304281599044,
        -5.8012039600105847814672114227,
        3.1116436695781989440891606237e-1 - 0.733846688281611857341361741547,
        -1.52160949662516078556178806805e-1,
        2.01365400804030348374776537501e-1,
        4.47106157277725905176885569043e-2 - 0.220588235294117647058823529412e-1,
    ]),
};

/// The non-zero coefficients of an explicit tableau, row by row and then the weights `b`, as
/// (stage, coefficient) in order: the terms every stage combination of this file sums (a zero
/// coefficient adds no term).
#[derive(Debug, Default, Clone)]
struct Terms {
    /// The tableau they are of: the addresses of its `a` and `b`, `'static` data that no other
    /// tableau can come to occupy.
    of: (usize, usize),
    terms: Vec<(usize, f64)>,
    /// Row `i`'s terms are `terms[bounds[i]..bounds[i + 1]]`; row `stages` holds `b`'s.
    bounds: Vec<usize>,
}

impl Terms {
    fn ensure(&mut self, t: &Tableau) {
        let of = (t.a.as_ptr() as usize, t.b.as_ptr() as usize);
        if self.of == of && !self.bounds.is_empty() {
            return;
        }
        self.of = of;
        self.terms.clear();
        self.bounds.clear();
        self.bounds.push(0);
        for row in t.a.iter().copied().chain([t.b]) {
            let nonzero = row.iter().enumerate().filter(|(_, a)| **a != 0.0);
            self.terms.extend(nonzero.map(|(j, &a)| (j, a)));
            self.bounds.push(self.terms.len());
        }
    }

    /// Row `i`'s terms (`i = stages`: the weights').
    #[inline(always)]
    fn row(&self, i: usize) -> &[(usize, f64)] {
        &self.terms[self.bounds[i]..self.bounds[i + 1]]
    }
}

/// `acc = sum_j a_j k_j` over the `n = acc.len()` values of the blocks of `k` the terms name
/// (block `j` is `k[j * n..(j + 1) * n]`): each value summed from `0.0` over the terms in
/// order. The one way every stage combination of this file sums; the blocks of several
/// deviation vectors side by side are summed as one longer block, value by value the same
/// operations.
#[inline(always)]
fn weighted_sum(terms: &[(usize, f64)], k: &[f64], acc: &mut [f64]) {
    // Blocks of a few values at a time, held in registers across the terms: the same sums,
    // value by value, in any blocking.
    match acc.len() {
        n if n.is_multiple_of(4) => weighted_sum_by::<4>(terms, k, acc),
        n if n.is_multiple_of(3) => weighted_sum_by::<3>(terms, k, acc),
        n if n.is_multiple_of(2) => weighted_sum_by::<2>(terms, k, acc),
        _ => weighted_sum_by::<1>(terms, k, acc),
    }
}

/// [`weighted_sum`] `N` values at a time (`acc.len()` a multiple of `N`).
#[inline(always)]
fn weighted_sum_by<const N: usize>(terms: &[(usize, f64)], k: &[f64], acc: &mut [f64]) {
    let n = acc.len();
    // The terms name their stages in increasing order, so the last names the highest block:
    // one check covers every read below.
    if let Some(&(last, _)) = terms.last() {
        assert!((last + 1) * n <= k.len(), "stage {last} of blocks of {n}");
    }
    for (c, out) in acc.chunks_exact_mut(N).enumerate() {
        let mut sum = [0.0; N];
        for &(j, a) in terms {
            for e in 0..N {
                // SAFETY: j <= last and c * N + e < n, so the index is below (last + 1) * n,
                // which the assertion above keeps within `k`.
                sum[e] += a * unsafe { *k.get_unchecked(j * n + c * N + e) };
            }
        }
        out.copy_from_slice(&sum);
    }
}

/// `out = base + h * out` value by value (`out` holding a [`weighted_sum`]).
#[inline(always)]
fn add_scaled(base: &[f64], h: f64, out: &mut [f64]) {
    for (o, &b) in out.iter_mut().zip(base) {
        *o = b + h * *o;
    }
}

/// The stages of one explicit step of tableau `t` from `x` at time `time` with step `h` of the
/// field `f` (`f(y, ti, out)` writes `f(y, ti)`; stage `i` at `ti = time + c_i h`): stage
/// states into `s.xs`, derivatives into `s.k`, the new state into `s.next`. The one definition
/// of the arithmetic of an explicit step.
fn explicit_stages(
    t: &Tableau,
    mut f: impl FnMut(&[f64], f64, &mut [f64]),
    x: &[f64],
    time: f64,
    h: f64,
    s: &mut RkScratch,
) {
    let dim = x.len();
    s.ensure(t.stages(), dim, 0);
    s.terms.ensure(t);
    for i in 0..t.stages() {
        let (done, rest) = s.k.split_at_mut(i * dim);
        let xi = &mut s.xs[i * dim..(i + 1) * dim];
        weighted_sum(s.terms.row(i), done, xi);
        add_scaled(x, h, xi);
        f(xi, time + t.c[i] * h, &mut rest[..dim]);
    }
    let next = &mut s.next[..dim];
    weighted_sum(s.terms.row(t.stages()), &s.k, next);
    add_scaled(x, h, next);
}

/// One step of size `h` from time `time` of the explicit tableau `t` for a field given as a
/// function (`f(y, ti, out)` writes `f(y, ti)`), with the arithmetic of
/// [`RungeKutta::advance`]: for callers that hold a vector field but no [`VectorField`] (a
/// Poincare section's crossing locator steps a system's field through
/// `DynamicalSystem::vector_field`).
pub fn explicit_step(
    t: &Tableau,
    f: impl FnMut(&[f64], f64, &mut [f64]),
    x: &mut [f64],
    time: f64,
    h: f64,
    s: &mut RkScratch,
) {
    explicit_stages(t, f, x, time, h, s);
    x.copy_from_slice(&s.next[..x.len()]);
}

/// The start times of the substeps `plan` of a step from time `time`: `time + done`, `done` the
/// substeps before, summed in order, exactly as [`RungeKutta::step_adaptive`] timed them.
pub fn substep_times(time: f64, plan: &[f64]) -> impl Iterator<Item = (f64, f64)> + '_ {
    plan.iter().scan(0.0, move |done: &mut f64, &h| {
        let start = time + *done;
        *done += h;
        Some((start, h))
    })
}

/// Error control of an adaptive step.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Tolerances {
    pub rtol: f64,
    pub atol: f64,
}

/// Scratch of the stages, reused across steps (one per orbit being stepped).
#[derive(Debug, Default, Clone)]
pub struct RkScratch {
    /// Stage derivatives `k_i = f(X_i)`, `s * D`.
    k: Vec<f64>,
    /// Stage states `X_i`, `s * D` (the tangent map evaluates `J` there).
    xs: Vec<f64>,
    /// Stage tangents `K_i` of the `m` deviation vectors, stage by stage: `s * m * D`, stage
    /// `i`'s `K_i` of vector `v` at `(i * m + v) * D`.
    kt: Vec<f64>,
    /// One stage's tangent arguments of the `m` vectors, `m * D`.
    wt: Vec<f64>,
    /// The state after the step (adaptive steps keep `x` until accepted).
    next: Vec<f64>,
    /// The step size the controller proposes next (adaptive only); `None` before the first.
    pub(crate) proposal: Option<f64>,
    /// The stages of the implicit methods.
    implicit: ImplicitScratch,
    /// The explicit tableau's non-zero terms.
    terms: Terms,
}

impl RkScratch {
    /// Room for `stages` stages of a state of `dim` values and of `vectors` deviation vectors
    /// (the tangent buffers only grow: a step of the state alone keeps them).
    fn ensure(&mut self, stages: usize, dim: usize, vectors: usize) {
        let n = stages * dim;
        if self.k.len() != n {
            self.k = vec![0.0; n];
            self.xs = vec![0.0; n];
            self.next = vec![0.0; dim];
            self.kt.clear();
            self.wt.clear();
        }
        let m = vectors * dim;
        if self.wt.len() < m || self.kt.len() < stages * m {
            self.kt = vec![0.0; stages * m];
            self.wt = vec![0.0; m];
        }
    }
}

/// A Runge-Kutta method.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RungeKutta {
    pub kind: RungeKuttaTableau,
}

/// Most accepted or rejected substeps an adaptive method may take within one grid step: beyond
/// it the solution is taken to blow up (finite-time singularities make the step shrink without
/// end).
pub const MAX_SUBSTEPS: usize = 1_000_000;

/// Why an adaptive step could not be completed.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum AdaptiveError {
    #[error("the adaptive step size fell to {h:e} at t + {at:e} within the step")]
    StepUnderflow { h: f64, at: f64 },
    #[error("more than {MAX_SUBSTEPS} substeps within one step of the time grid")]
    TooManySubsteps,
    #[error("the vector field became non-finite at t + {at:e} within the step")]
    NonFinite { at: f64 },
}

impl RungeKutta {
    pub fn new(kind: RungeKuttaTableau) -> Self {
        Self { kind }
    }

    /// Stages from `x` at time `time` with step `h`: stage states into `xs`, derivatives into
    /// `k`, the new state into `next`.
    fn stages(&self, f: &dyn VectorField, x: &[f64], time: f64, h: f64, s: &mut RkScratch) {
        let t = self.kind.tableau().expect("an explicit method");
        explicit_stages(t, |y, ti, out| f.value(y, ti, out), x, time, h, s);
    }

    /// One step of size `h` from time `time`.
    ///
    /// An implicit step whose stages do not converge leaves `x` NaN: the engine stops the run
    /// there and asks the system why (`RkFlow::diagnose_non_finite` names the solver).
    pub fn advance(
        &self,
        f: &dyn VectorField,
        x: &mut [f64],
        time: f64,
        h: f64,
        s: &mut RkScratch,
    ) {
        if let Some(t) = self.kind.implicit_tableau() {
            if gauss_legendre::advance(t, f, x, time, h, &mut s.implicit).is_err() {
                x.fill(f64::NAN);
            }
            return;
        }
        self.stages(f, x, time, h, s);
        x.copy_from_slice(&s.next[..x.len()]);
    }

    /// Whether one implicit step from `x` at time `time` fails to converge (for diagnosis;
    /// `false` for the explicit methods).
    pub fn implicit_step_fails(
        &self,
        f: &dyn VectorField,
        x: &[f64],
        time: f64,
        h: f64,
    ) -> Option<String> {
        let t = self.kind.implicit_tableau()?;
        let mut y = x.to_vec();
        gauss_legendre::advance(t, f, &mut y, time, h, &mut ImplicitScratch::default())
            .err()
            .map(|e| e.to_string())
    }

    /// One step from time `time` of `x` and of the deviation vectors in `w` (one after the
    /// other) by the exact derivative of the step (each stage's Jacobian at its stage time).
    pub fn advance_tangent(
        &self,
        f: &dyn VectorField,
        x: &mut [f64],
        w: &mut [f64],
        time: f64,
        h: f64,
        s: &mut RkScratch,
    ) -> Result<(), TangentError> {
        if let Some(reason) = f.no_tangent_reason() {
            return Err(TangentError::NoHessian(reason));
        }
        if let Some(t) = self.kind.implicit_tableau() {
            if gauss_legendre::advance_tangent(t, f, x, w, time, h, &mut s.implicit).is_err() {
                // As in `advance`: the engine stops at the non-finite state.
                x.fill(f64::NAN);
                w.fill(f64::NAN);
            }
            return Ok(());
        }
        let t = self.kind.tableau().expect("an explicit method");
        let dim = x.len();
        self.stages(f, x, time, h, s);
        // The vectors stage by stage, side by side: each stage's combination runs over all of
        // them as one block (value by value the sums of one vector alone), and its Jacobian
        // at the stage state is applied to all of them in one call.
        let m = w.len();
        s.ensure(t.stages(), dim, m / dim);
        let (kt, wt) = (&mut s.kt[..t.stages() * m], &mut s.wt[..m]);
        for i in 0..t.stages() {
            let (done, rest) = kt.split_at_mut(i * m);
            weighted_sum(s.terms.row(i), done, wt);
            add_scaled(w, h, wt);
            let xs = &s.xs[i * dim..(i + 1) * dim];
            f.tangents(xs, time + t.c[i] * h, wt, &mut rest[..m]);
        }
        weighted_sum(s.terms.row(t.stages()), kt, wt);
        for (v, &sum) in w.iter_mut().zip(wt.iter()) {
            *v += h * sum;
        }
        x.copy_from_slice(&s.next[..dim]);
        Ok(())
    }

    /// The scaled error norm of the step just computed by `stages` (Hairer's DOP853 estimate:
    /// the 5th-order error damped by the 3rd-order one); `<= 1` accepts the step.
    fn error_norm(&self, x: &[f64], h: f64, tol: Tolerances, s: &RkScratch) -> f64 {
        let t = self.kind.tableau().expect("an explicit method");
        let (Some(e5), Some(e3)) = (t.e5, t.e3) else {
            return 0.0;
        };
        let dim = x.len();
        let (mut err5, mut err3) = (0.0, 0.0);
        for d in 0..dim {
            let scale = tol.atol + tol.rtol * x[d].abs().max(s.next[d].abs());
            let (mut a5, mut a3) = (0.0, 0.0);
            for i in 0..t.stages() {
                let k = s.k[i * dim + d];
                a5 += e5[i] * k;
                a3 += e3[i] * k;
            }
            err5 += (a5 / scale).powi(2);
            err3 += (a3 / scale).powi(2);
        }
        if err5 == 0.0 && err3 == 0.0 {
            return 0.0;
        }
        let denominator = err5 + 0.01 * err3;
        h.abs() * err5 / (denominator * dim as f64).sqrt()
    }

    /// Advance `x` from time `time` by exactly `span` with error-controlled substeps, appending
    /// each accepted substep's size to `plan`; `s.proposal` carries the controller's next step
    /// size from one call to the next. A substep that would pass the end is cut to land on it
    /// exactly (so the trajectory is the same whatever the sampling), without lowering the
    /// proposal. A substep starts at `time + done`, `done` the sum of the accepted substeps
    /// before it in order (what [`substep_times`] gives a follower of the plan).
    #[allow(clippy::too_many_arguments)]
    pub fn step_adaptive(
        &self,
        f: &dyn VectorField,
        x: &mut [f64],
        time: f64,
        span: f64,
        tol: Tolerances,
        plan: &mut Vec<f64>,
        s: &mut RkScratch,
    ) -> Result<(), AdaptiveError> {
        // Controller of Hairer's DOP853: safety 0.9, factor limits 0.2 .. 10, exponent 1/8.
        const SAFETY: f64 = 0.9;
        const MIN_FACTOR: f64 = 0.2;
        const MAX_FACTOR: f64 = 10.0;
        let dim = x.len();
        let mut done = 0.0;
        let mut proposal = s.proposal.unwrap_or(span);
        for _ in 0..MAX_SUBSTEPS {
            let remaining = span - done;
            // Within 1 % of the end, land on it: never leave a sliver of a step behind.
            let last = proposal * 1.01 >= remaining;
            let h = if last { remaining } else { proposal };
            if h.is_nan() || h <= span * 1e-14 {
                return Err(AdaptiveError::StepUnderflow { h, at: done });
            }
            self.stages(f, x, time + done, h, s);
            let err = self.error_norm(x, h, tol, s);
            if !err.is_finite() || s.next[..dim].iter().any(|v| !v.is_finite()) {
                // Treated as a rejection with the smallest factor: a step into a region where
                // f overflows is retried shorter.
                proposal = h * MIN_FACTOR;
                if !proposal.is_finite() || proposal <= span * 1e-14 {
                    return Err(AdaptiveError::NonFinite { at: done });
                }
                continue;
            }
            if err <= 1.0 {
                x.copy_from_slice(&s.next[..dim]);
                plan.push(h);
                let factor = if err == 0.0 {
                    MAX_FACTOR
                } else {
                    (SAFETY * err.powf(-1.0 / 8.0)).clamp(MIN_FACTOR, MAX_FACTOR)
                };
                // A step cut to land on the grid keeps the proposal it was cut from.
                proposal = (h * factor).max(if last { proposal } else { 0.0 });
                if last {
                    s.proposal = Some(proposal);
                    return Ok(());
                }
                done += h;
            } else {
                let factor = (SAFETY * err.powf(-1.0 / 8.0)).clamp(MIN_FACTOR, 1.0);
                proposal = h * factor;
            }
        }
        Err(AdaptiveError::TooManySubsteps)
    }
}

impl Integrator<dyn VectorField> for RungeKutta {
    fn name(&self) -> &str {
        self.kind.name()
    }

    fn order(&self) -> u32 {
        self.kind.order()
    }

    fn step(&self, system: &dyn VectorField, x: &mut [f64], t: f64, h: f64, work: &mut Workspace) {
        self.advance(system, x, t, h, &mut work.rk)
    }

    fn step_tangent(
        &self,
        system: &dyn VectorField,
        x: &mut [f64],
        w: &mut [f64],
        t: f64,
        h: f64,
        work: &mut Workspace,
    ) -> Result<(), TangentError> {
        self.advance_tangent(system, x, w, t, h, &mut work.rk)
    }
}
