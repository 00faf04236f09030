//! Poincare sections of any flow: where an orbit crosses a surface `S(x) = 0`, `S` written as
//! an expression over the state's coordinates (`x1..xD` of a flow, `q1..qN`, `p1..pN` of a
//! Hamiltonian), in a chosen direction (`S` increasing, decreasing, or both).
//!
//! Crossings are detected between the run's own steps (its integrator and `h`: the orbit is
//! the one a run follows) and located to rounding: Newton's method on the time of flight `tau`
//! from the last state before the crossing, `phi(tau) = S(x(tau))`, `phi'(tau) = grad S . f`,
//! safeguarded by bisection while the step brackets the root. Each iterate's state `x(tau)` is
//! the flow of the system's vector field from that last state, integrated anew by DOP853 in
//! `m` equal substeps, where `m` is doubled until halving the substeps changes the state over
//! the whole step `h` by less than `1e-12` of its size, and then once more (the method being of
//! order 8, each halving divides the error by about 256: the error is then below rounding). So the located crossing is the
//! exact flow's from the trajectory's last state before it, whatever the run's integrator:
//! its error is rounding, far below the trajectory's own integration error, and a step that
//! ends a little earlier or later near the crossing moves it only in the last bits (the unit
//! tests below).
//!
//! Why not Henon's trick (one integration step with `S` as the independent variable): it
//! needs `dS/dt` to keep its sign between the last step and the crossing, which a step that
//! grazes the surface breaks; Newton on the re-integrated flow needs nothing of the kind, and
//! its iterates cost a few short integrations per crossing, a small part of a section's cost.

/// What a section's surface and axes compile to.
pub use chaoscope_expr::ScalarFunction;
use chaoscope_schemas::config::ModelConfig;
use chaoscope_schemas::run::SystemClass;

use crate::integrator::Workspace;
use crate::integrator::runge_kutta::{RkScratch, RungeKuttaTableau, explicit_step, substep_times};
use crate::spec::state_function::scalar_definition;
pub use crate::spec::state_function::scalar_over_state;
use crate::spec::{RunSpec, SpecError};
use crate::system::{DynamicalSystem, Time};

/// Which crossings of `S = 0` count.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Direction {
    /// `S` increasing: from `S < 0` to `S >= 0`.
    Up,
    /// `S` decreasing: from `S > 0` to `S <= 0`.
    Down,
    /// Both.
    Both,
}

impl Direction {
    pub fn from_name(name: &str) -> Option<Self> {
        match name {
            "up" => Some(Self::Up),
            "down" => Some(Self::Down),
            "both" => Some(Self::Both),
            _ => None,
        }
    }

    pub fn name(self) -> &'static str {
        match self {
            Self::Up => "up",
            Self::Down => "down",
            Self::Both => "both",
        }
    }

    /// Whether a step from `S = before` to `S = after` crosses the surface this way. A state
    /// exactly on the surface ends the crossing that reached it, so it is counted once.
    pub fn crosses(self, before: f64, after: f64) -> bool {
        let up = before < 0.0 && after >= 0.0;
        let down = before > 0.0 && after <= 0.0;
        match self {
            Self::Up => up,
            Self::Down => down,
            Self::Both => up || down,
        }
    }
}

/// The surface `S(x) = 0` of a system's section, and the names of the state's coordinates.
#[derive(Debug)]
pub struct Surface {
    function: ScalarFunction,
    names: Vec<String>,
}

/// The names of a system's coordinates: `q1..qN`, `p1..pN` for any Hamiltonian (as maps name
/// their axes), `x1..xD` for any other system.
pub fn coordinate_names(spec: &RunSpec) -> Vec<String> {
    let dim = spec.dim();
    if spec.system().kind() == SystemClass::Hamiltonian {
        let n = dim / 2;
        (1..=n)
            .map(|i| format!("q{i}"))
            .chain((1..=n).map(|i| format!("p{i}")))
            .collect()
    } else {
        (1..=dim).map(|i| format!("x{i}")).collect()
    }
}

/// [`scalar_over_state`] for an expression a user reads back in a message (a section's
/// `--axes`): an error in the expression is its first line `key: line L, column C: problem`
/// followed by the expression and a caret under the fault.
pub fn state_expression(
    spec: &RunSpec,
    model: &ModelConfig,
    key: &str,
    source: &str,
) -> Result<ScalarFunction, String> {
    let definition = scalar_definition(spec, model, key, source)
        .map_err(|e| format!("{}: {}", e.key, e.message))?;
    ScalarFunction::new(definition).map_err(|e| e.to_string())
}

impl Surface {
    /// `source` (the `--surface` expression) over the coordinates of `spec`'s system, with
    /// the scalar parameters and arrays of `model` (the config's `params`, `boundary`). Maps
    /// are refused (their time is discrete: they have no crossings to locate), as is an
    /// expression that reads no coordinate. Errors name `--surface` in one line.
    pub fn new(spec: &RunSpec, model: &ModelConfig, source: &str) -> Result<Self, SpecError> {
        const KEY: &str = "--surface";
        let system = spec.system();
        if system.time() == Time::Discrete
            || !system.vector_field(spec.x0(), 0.0, &mut vec![0.0; spec.dim()])
        {
            return Err(SpecError::new(
                KEY,
                format!(
                    "sections through a surface are drawn for flows; '{}' is a map (its \
                     iterates are already a section)",
                    model.name()
                ),
            ));
        }
        let function = scalar_over_state(spec, model, KEY, source)?;
        if function.reads().is_empty() {
            return Err(SpecError::new(
                KEY,
                format!("'{source}' reads no coordinate, so no orbit ever crosses it"),
            ));
        }
        Ok(Self {
            function,
            names: coordinate_names(spec),
        })
    }

    /// `S(x)`.
    pub fn value(&self, x: &[f64]) -> f64 {
        self.function.value(x)
    }

    /// The compiled `S` with its gradient.
    pub fn function(&self) -> &ScalarFunction {
        &self.function
    }

    /// The state's coordinate names, in the state's order.
    pub fn names(&self) -> &[String] {
        &self.names
    }

    /// The 0-based index of a coordinate by name (`x2`, `q1`, `p3`).
    pub fn index_of(&self, name: &str) -> Option<usize> {
        self.names.iter().position(|n| n == name)
    }

    /// The default plotted pair: for a Hamiltonian, `(q_j, p_j)` of the first degree of
    /// freedom whose position the surface does not fix (the surface fixes a coordinate when it
    /// reads that one alone); for any other system the first two coordinates the surface does
    /// not fix; the first two coordinates otherwise.
    pub fn default_axes(&self, canonical: bool) -> (usize, usize) {
        let dim = self.names.len();
        let fixed = match self.function.reads() {
            [k] => Some(*k),
            _ => None,
        };
        if canonical {
            let n = dim / 2;
            let j = (0..n)
                .find(|&j| fixed.is_none_or(|k| k % n != j))
                .unwrap_or(0);
            (j, n + j)
        } else {
            let mut free = (0..dim).filter(|&i| Some(i) != fixed);
            match (free.next(), free.next()) {
                (Some(a), Some(b)) => (a, b),
                _ => (0, 1.min(dim - 1)),
            }
        }
    }
}

/// A located crossing: its time and the state there.
#[derive(Debug, Clone, PartialEq)]
pub struct Crossing {
    pub t: f64,
    pub x: Vec<f64>,
}

/// Why a crossing detected between two steps could not be located.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum LocateError {
    #[error("the vector field or the surface is not finite between the two steps")]
    NonFinite,
    #[error("Newton's method on the time of the crossing did not converge")]
    NoConvergence,
}

/// Most substep doublings of the re-integration over one step (4096 substeps).
const MAX_DOUBLINGS: u32 = 12;
/// Most Newton (or bisection) iterations: bisection alone gets to rounding of `h` in 53.
const MAX_ITERATIONS: usize = 100;
/// Relative change below which halving the substeps counts as converged (see the module
/// documentation).
const SUBSTEP_TOLERANCE: f64 = 1e-12;

/// Reusable work of [`locate`].
#[derive(Debug, Default)]
pub struct LocateScratch {
    rk: RkScratch,
    y: Vec<f64>,
    coarse: Vec<f64>,
    f: Vec<f64>,
    grad: Vec<f64>,
}

/// The flow of `system`'s vector field over `tau` from `x` at time `t0`, in `m` DOP853
/// substeps (substep `j` from `t0 + j tau / m`), into `out`; false if it is not finite.
fn flow(
    system: &dyn DynamicalSystem,
    x: &[f64],
    t0: f64,
    tau: f64,
    m: u32,
    out: &mut Vec<f64>,
    rk: &mut RkScratch,
) -> bool {
    let tableau = RungeKuttaTableau::Dop853
        .tableau()
        .expect("dop853 is an explicit method");
    out.clear();
    out.extend_from_slice(x);
    let sub = tau / f64::from(m);
    for j in 0..m {
        explicit_step(
            tableau,
            |y, t, f| {
                system.vector_field(y, t, f);
            },
            out,
            t0 + f64::from(j) * sub,
            sub,
            rk,
        );
    }
    out.iter().all(|v| v.is_finite())
}

/// The crossing of `surface` by the flow of `system` from `before` at time `t0` (where `S =
/// s_before`, not 0), within about one step `h` (the run's step that went from `before` across
/// the surface): the time of flight `tau` and the state there, located to rounding (module
/// documentation).
#[allow(clippy::too_many_arguments)]
pub fn locate(
    system: &dyn DynamicalSystem,
    surface: &ScalarFunction,
    before: &[f64],
    t0: f64,
    s_before: f64,
    h: f64,
    scratch: &mut LocateScratch,
) -> Result<(f64, Vec<f64>), LocateError> {
    let LocateScratch {
        rk,
        y,
        coarse,
        f,
        grad,
    } = scratch;
    let dim = before.len();
    f.resize(dim, 0.0);
    grad.resize(dim, 0.0);
    // Substeps: doubled until the whole step no longer changes beyond SUBSTEP_TOLERANCE.
    let mut m = 1;
    let mut converged = false;
    let mut coarse_ok = flow(system, before, t0, h, m, coarse, rk);
    for _ in 0..MAX_DOUBLINGS {
        let fine_ok = flow(system, before, t0, h, 2 * m, y, rk);
        m *= 2;
        if coarse_ok && fine_ok {
            let size = y.iter().fold(1.0f64, |a, v| a.max(v.abs()));
            let change = y
                .iter()
                .zip(coarse.iter())
                .fold(0.0f64, |a, (p, q)| a.max((p - q).abs()));
            if change <= SUBSTEP_TOLERANCE * size {
                converged = true;
                break;
            }
        }
        std::mem::swap(y, coarse);
        coarse_ok = fine_ok;
    }
    if !converged && !y.iter().all(|v| v.is_finite()) {
        return Err(LocateError::NonFinite);
    }
    // Once converged, one more halving: the change of `1e-12` bounds the finer state's error by
    // about `4e-15` of its size, and another factor 256 puts it below rounding. A field that
    // is not smooth converges more slowly: the finest substeps are used as they are (still
    // far finer than the run's step).
    if converged {
        m *= 2;
    }
    let (mut lo, mut s_lo, mut hi) = (0.0, s_before, h);
    let s_end = surface.value(y);
    // The exact flow may reach the surface a little after the step that crossed it (within
    // the trajectory's integration error): then Newton runs without a bracket.
    let bracketed = s_end.is_finite() && (s_lo < 0.0) != (s_end < 0.0);
    let mut tau = if bracketed {
        h * s_lo / (s_lo - s_end)
    } else {
        h
    };
    let small = 2.0 * f64::EPSILON * h;
    // The iterate nearest the surface, and the last Newton correction: once `S` is down to
    // its rounding (`|x| eps` times its slope, e.g. `sin(x3)` at a large `x3`), the
    // corrections stop shrinking and the nearest iterate is the crossing.
    let mut best = (f64::INFINITY, tau);
    let mut last_newton = f64::INFINITY;
    for _ in 0..MAX_ITERATIONS {
        if !flow(system, before, t0, tau, m, y, rk) {
            return Err(LocateError::NonFinite);
        }
        let s = surface.value(y);
        if !s.is_finite() {
            return Err(LocateError::NonFinite);
        }
        if s == 0.0 {
            return Ok((tau, y.clone()));
        }
        if s.abs() < best.0 {
            best = (s.abs(), tau);
        }
        if bracketed {
            if (s < 0.0) == (s_lo < 0.0) {
                (lo, s_lo) = (tau, s);
            } else {
                hi = tau;
            }
        }
        system.vector_field(y, t0 + tau, f);
        surface.gradient(y, grad);
        // dS/dt along the flow, summed in coordinate order.
        let rate: f64 = grad.iter().zip(f.iter()).map(|(g, v)| g * v).sum();
        let newton = tau - s / rate;
        let mut next = newton;
        if bracketed {
            if !(next > lo && next < hi) {
                next = 0.5 * (lo + hi);
            }
        } else if !(next.is_finite() && next.abs() <= 4.0 * h) {
            return Err(LocateError::NoConvergence);
        }
        let correction = (next - tau).abs();
        // Only a correction already below sqrt(eps) of the step is taken for rounding noise
        // (Newton's own first steps may shrink slowly).
        let stalled = next == newton
            && correction >= 0.5 * last_newton
            && correction <= f64::EPSILON.sqrt() * h;
        if next == newton {
            last_newton = correction;
        }
        let done = correction <= small || (bracketed && hi - lo <= small);
        if stalled {
            tau = best.1;
        } else {
            tau = next;
        }
        if done || stalled {
            if !flow(system, before, t0, tau, m, y, rk) {
                return Err(LocateError::NonFinite);
            }
            return Ok((tau, y.clone()));
        }
    }
    Err(LocateError::NoConvergence)
}

/// How an orbit of a section ended.
#[derive(Debug, Clone, PartialEq)]
pub enum OrbitEnd {
    /// It gave the crossings asked for.
    Crossings,
    /// It reached the run's final time.
    Horizon,
    /// Its state, or the surface on it, stopped being finite at time `t` (the orbit escaped or
    /// blew up; `why` names the operation where the system or the surface knows it).
    NonFinite { t: f64, why: String },
    /// A crossing after time `t` could not be located.
    Unlocated { t: f64, error: LocateError },
}

/// The crossings of one orbit, and how it ended.
#[derive(Debug, Clone, PartialEq)]
pub struct SurfaceOrbit {
    pub crossings: Vec<Crossing>,
    pub end: OrbitEnd,
}

/// The crossings of `surface` in `direction` by the orbit of `spec`'s system from `x0`, stepped
/// by the run's integrator and step for at most `steps` steps, keeping at most `max`
/// crossings. Every crossing is finite.
pub fn surface_crossings(
    spec: &RunSpec,
    surface: &Surface,
    direction: Direction,
    x0: &[f64],
    steps: u64,
    max: usize,
) -> SurfaceOrbit {
    let system = spec.system().as_ref();
    let h = spec.h();
    let mut x = x0.to_vec();
    let mut prev = x.clone();
    let mut work = Workspace::new();
    let mut scratch = LocateScratch::default();
    let mut crossings = Vec::new();
    let non_finite_surface = |x: &[f64], t: f64| OrbitEnd::NonFinite {
        t,
        why: surface
            .function()
            .diagnose_non_finite(x)
            .unwrap_or_else(|| "--surface is not finite".to_string()),
    };
    let mut s = surface.value(&x);
    if !s.is_finite() {
        return SurfaceOrbit {
            crossings,
            end: non_finite_surface(&x, 0.0),
        };
    }
    if max == 0 {
        return SurfaceOrbit {
            crossings,
            end: OrbitEnd::Crossings,
        };
    }
    // A system that chooses substeps within a step (adaptive dop853, Taylor's method, whose
    // steps may span many turns of the orbit on a coarse grid) is walked substep by substep,
    // each substep the very one the run takes (the same bits as the whole step), so no
    // crossing between two of them is missed.
    let mut plan = Vec::new();
    let mut probe = x.clone();
    let mut segments: Vec<(f64, f64)> = Vec::new();
    for step in 0..steps {
        let t_step = spec.time_of(step);
        plan.clear();
        probe.copy_from_slice(&x);
        system.step_reference(&mut probe, t_step, &mut plan, &mut work);
        segments.clear();
        if plan.is_empty() || !probe.iter().all(|v| v.is_finite()) {
            segments.push((t_step, h));
        } else {
            segments.extend(substep_times(t_step, &plan));
        }
        for (i, &(t0, span)) in segments.iter().enumerate() {
            prev.copy_from_slice(&x);
            if segments.len() == 1 {
                x.copy_from_slice(&probe);
            } else {
                system.step_along(&mut x, t0, &plan[i..=i], &mut work);
            }
            let t = if i + 1 == segments.len() {
                spec.time_of(step + 1)
            } else {
                segments[i + 1].0
            };
            if !x.iter().all(|v| v.is_finite()) {
                let why = system
                    .diagnose_non_finite(&prev, t0)
                    .unwrap_or_else(|| "the state is not finite".to_string());
                return SurfaceOrbit {
                    crossings,
                    end: OrbitEnd::NonFinite { t, why },
                };
            }
            let s_next = surface.value(&x);
            if !s_next.is_finite() {
                return SurfaceOrbit {
                    crossings,
                    end: non_finite_surface(&x, t),
                };
            }
            if direction.crosses(s, s_next) {
                match locate(system, surface.function(), &prev, t0, s, span, &mut scratch) {
                    Ok((tau, state)) => {
                        crossings.push(Crossing {
                            t: t0 + tau,
                            x: state,
                        });
                        if crossings.len() >= max {
                            return SurfaceOrbit {
                                crossings,
                                end: OrbitEnd::Crossings,
                            };
                        }
                    }
                    Err(error) => {
                        return SurfaceOrbit {
                            crossings,
                            end: OrbitEnd::Unlocated { t: t0, error },
                        };
                    }
                }
            }
            s = s_next;
        }
    }
    SurfaceOrbit {
        crossings,
        end: OrbitEnd::Horizon,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use chaoscope_schemas::config::RunConfig;
    use std::f64::consts::{FRAC_PI_2, PI};

    /// `x1' = x2, x2' = -x1` from `(1, 0)`: `x1 = cos t`, `x2 = -sin t`.
    fn oscillator(method: &str, h: f64, t_final: f64) -> (RunSpec, RunConfig) {
        let text = format!(
            "[model]\nname = \"ode\"\nrhs = [\"x2\", \"-x1\"]\n[orbit]\nx = [1.0, 0.0]\n\
             [integrator]\nmethod = \"{method}\"\nh = {h}\nt_final = {t_final}\n\
             [deviations]\nk = 1\n[[scheme]]\nname = \"vm\"\nmethod = \"vm\"\nd0 = 1e-8\n\
             tau = 1.0\n"
        );
        let cfg = RunConfig::from_toml(&text).unwrap();
        (RunSpec::from_config(&cfg).unwrap(), cfg)
    }

    #[test]
    fn locate_finds_the_exact_crossing_whatever_the_last_step() {
        // x1 = cos t falls through 0 at t = pi/2 with x2 = -1. Started on the exact solution at
        // several distances before the crossing, with several step lengths: every located
        // crossing is the exact one to a few units of rounding (|t| ~ 1.6, eps ~ 2.2e-16), so
        // the location does not depend on where the last step ended.
        let (spec, cfg) = oscillator("dop853", 0.1, 1.0);
        let surface = Surface::new(&spec, &cfg.model, "x1").unwrap();
        let system = spec.system().as_ref();
        let mut scratch = LocateScratch::default();
        for h in [0.01, 0.1, 0.5, 1.0] {
            for fraction in [0.999, 0.7, 0.5, 0.3, 1e-3] {
                let t0 = FRAC_PI_2 - fraction * h;
                let before = [t0.cos(), -t0.sin()];
                let s = surface.value(&before);
                let (tau, x) =
                    locate(system, surface.function(), &before, t0, s, h, &mut scratch).unwrap();
                let t = t0 + tau;
                assert!(
                    (t - FRAC_PI_2).abs() < 2e-15,
                    "h {h}, fraction {fraction}: t = {t}"
                );
                assert!(x[0].abs() < 1e-15, "x1 = {}", x[0]);
                assert!((x[1] + 1.0).abs() < 1e-15, "x2 = {}", x[1]);
            }
        }
    }

    #[test]
    fn an_oscillator_crosses_at_half_periods_in_the_chosen_direction() {
        // With dop853 at h = 0.01 the trajectory's own error over t = 40 is at rounding
        // (local error ~ h^9), so the crossings are those of cos t: down at pi/2 + 2k pi, up at
        // 3 pi/2 + 2k pi, to about 1e-13 (rounding accumulated over 4000 steps).
        let (spec, cfg) = oscillator("dop853", 0.01, 40.0);
        let up = Surface::new(&spec, &cfg.model, "x1").unwrap();
        let steps = spec.total_steps();
        let orbit = surface_crossings(&spec, &up, Direction::Up, spec.x0(), steps, 100);
        assert_eq!(orbit.end, OrbitEnd::Horizon);
        // 3 pi/2 + 2k pi < 40: k = 0..5.
        assert_eq!(orbit.crossings.len(), 6);
        for (k, c) in orbit.crossings.iter().enumerate() {
            let exact = 1.5 * PI + 2.0 * PI * k as f64;
            assert!((c.t - exact).abs() < 1e-12, "crossing {k}: t = {}", c.t);
            assert!(
                c.x[0].abs() < 1e-13 && (c.x[1] - 1.0).abs() < 1e-12,
                "{:?}",
                c.x
            );
        }
        let both = surface_crossings(&spec, &up, Direction::Both, spec.x0(), steps, 100);
        assert_eq!(both.crossings.len(), 13); // pi/2 + k pi < 40: k = 0..12
        for (k, c) in both.crossings.iter().enumerate() {
            let exact = FRAC_PI_2 + PI * k as f64;
            assert!((c.t - exact).abs() < 1e-12, "crossing {k}: t = {}", c.t);
        }
        let down = surface_crossings(&spec, &up, Direction::Down, spec.x0(), steps, 3);
        assert_eq!(down.end, OrbitEnd::Crossings);
        assert_eq!(down.crossings.len(), 3);
        assert!((down.crossings[2].t - (FRAC_PI_2 + 4.0 * PI)).abs() < 1e-12);
    }

    #[test]
    fn a_coarse_low_order_trajectory_still_locates_on_the_surface() {
        // rk4 at h = 0.2: the trajectory itself is off by ~1e-5 after a few periods, but every
        // crossing is located on the surface to rounding and at the time the exact flow from
        // the last step gives (a nonlinear surface: x1^2 + x2 - 0.5).
        let (spec, cfg) = oscillator("rk4", 0.2, 30.0);
        let surface = Surface::new(&spec, &cfg.model, "x1 * x1 + x2 - 0.5").unwrap();
        let orbit = surface_crossings(
            &spec,
            &surface,
            Direction::Both,
            spec.x0(),
            spec.total_steps(),
            1000,
        );
        assert!(orbit.crossings.len() >= 9, "{}", orbit.crossings.len());
        for c in &orbit.crossings {
            assert!(
                surface.value(&c.x).abs() < 1e-15,
                "S = {}",
                surface.value(&c.x)
            );
        }
    }

    #[test]
    fn hostile_surfaces_and_orbits() {
        let (spec, cfg) = oscillator("dop853", 0.01, 10.0);
        let e = Surface::new(&spec, &cfg.model, "x3").unwrap_err();
        assert_eq!(e.key, "--surface");
        assert!(
            e.message.contains("variable 'x3' does not exist"),
            "{}",
            e.message
        );
        assert!(!e.message.contains('\n'));
        let e = Surface::new(&spec, &cfg.model, "2 * c").unwrap_err();
        assert!(e.message.contains("unknown name 'c'"), "{}", e.message);
        let e = Surface::new(&spec, &cfg.model, "1").unwrap_err();
        assert!(e.message.contains("reads no coordinate"), "{}", e.message);
        // Never crossed: |x1| <= 1 < 2.
        let far = Surface::new(&spec, &cfg.model, "x1 - 2").unwrap();
        let orbit = surface_crossings(&spec, &far, Direction::Both, spec.x0(), 1000, 10);
        assert_eq!(
            orbit,
            SurfaceOrbit {
                crossings: vec![],
                end: OrbitEnd::Horizon
            }
        );
        // A surface not finite on the orbit stops it naming the operation and the time.
        let log = Surface::new(&spec, &cfg.model, "log(x1 + 0.5)").unwrap();
        let orbit = surface_crossings(&spec, &log, Direction::Up, spec.x0(), 1000, 10);
        match orbit.end {
            OrbitEnd::NonFinite { t, why } => {
                // x1 = cos t reaches -0.5 at t = 2 pi / 3.
                assert!((t - 2.0 * PI / 3.0).abs() < 0.011, "t = {t}");
                assert!(why.contains("log"), "{why}");
            }
            other => panic!("{other:?}"),
        }
    }

    #[test]
    fn maps_are_refused() {
        let text = "[model]\nname = \"map\"\nnext = [\"x2\", \"-x1\"]\n[orbit]\nx = [1.0, 0.0]\n\
             [integrator]\nh = 1.0\nt_final = 10.0\n[deviations]\nk = 1\n[[scheme]]\n\
             name = \"vm\"\nmethod = \"vm\"\nd0 = 1e-8\ntau = 1.0\n";
        let cfg = RunConfig::from_toml(text).unwrap();
        let spec = RunSpec::from_config(&cfg).unwrap();
        let e = Surface::new(&spec, &cfg.model, "x1").unwrap_err();
        assert!(e.message.contains("is a map"), "{}", e.message);
    }

    #[test]
    fn hamiltonians_name_q_and_p_and_default_axes_avoid_the_fixed_coordinate() {
        let cfg = chaoscope_schemas::config::paper::henon_heiles(
            chaoscope_schemas::config::paper::HH_REGULAR_Q2,
            1.0,
            chaoscope_schemas::config::DeviationsConfig::random(1, 1, 0),
            vec![chaoscope_schemas::config::SchemeConfig::new(
                "vm", "vm", 1e-8, 1.0,
            )],
        );
        let spec = RunSpec::from_config(&cfg).unwrap();
        let surface = Surface::new(&spec, &cfg.model, "q1").unwrap();
        assert_eq!(surface.names(), ["q1", "q2", "p1", "p2"]);
        assert_eq!(surface.default_axes(true), (1, 3)); // (q2, p2)
        let orbit = surface_crossings(&spec, &surface, Direction::Up, spec.x0(), 200_000, 50);
        assert_eq!(orbit.crossings.len(), 50);
        let model = spec.system().separable().unwrap().model();
        for c in &orbit.crossings {
            // On the plane to rounding, crossing upward (p1 > 0), on the energy surface to the
            // splitting's energy error (ABA864 at the paper's h: ~1e-10 and below).
            assert!(c.x[0].abs() < 1e-15, "q1 = {}", c.x[0]);
            assert!(c.x[2] > 0.0);
            assert!((model.energy(&c.x, crate::model::At::T0) - spec.e0()).abs() < 1e-9);
        }
        // The flows' default: the first two coordinates the surface does not fix.
        let (spec, cfg) = oscillator("dop853", 0.01, 1.0);
        let s = Surface::new(&spec, &cfg.model, "x1").unwrap();
        assert_eq!(s.default_axes(false), (0, 1)); // two coordinates: no pair without x1
        let s = Surface::new(&spec, &cfg.model, "x1 + x2").unwrap();
        assert_eq!(s.default_axes(false), (0, 1));
    }
}
