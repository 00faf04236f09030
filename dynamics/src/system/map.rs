//! A discrete map `x -> F(x)` (`[model] name = "map"`): time counts iterations.
//!
//! `F` is a compiled [`VectorFunction`] (`next = [...]`), so the variational method steps the
//! exact tangent map `w -> J(x) w` (the Jacobian by automatic differentiation) and the
//! multi-particle method iterates the nearby orbits with the same `F`.
//!
//! Angles: a coordinate with a period `P > 0` (`modulo`) is taken into `[0, P)` after every
//! iteration, so the state lives on a cylinder or torus. Two consequences the rest of the code
//! sees through this system:
//! - the separation of a nearby orbit from the reference is the *minimal image* of their
//!   difference, in `[-P/2, P/2]` (a nearby orbit that crossed `P` while the reference did not is
//!   `1e-8` away, not `2 pi - 1e-8`): [`DynamicalSystem::separation`];
//! - wrapping has derivative 1 wherever it is continuous, so the tangent map is `J(x)` alone.
//!
//! The map must be well defined on the torus (periodic in every wrapped coordinate, as the
//! standard map is in both); that is the model's business, as in every code that wraps angles.

use chaoscope_expr::VectorFunction;
use chaoscope_schemas::run::SystemClass;

use super::{DynamicalSystem, Time};
use crate::batch::{self, Isa, PointKernel, Soa};
use crate::integrator::{TangentError, Workspace};

/// `x -> F(x)` with optional periods per coordinate.
#[derive(Debug, Clone)]
pub struct Map {
    function: VectorFunction,
    /// Period of each coordinate; `0` for a coordinate that is not wrapped.
    modulo: Vec<f64>,
    wraps: bool,
}

impl Map {
    /// `modulo` has one entry per coordinate: a finite period `> 0`, or `0` for none (an empty
    /// `modulo` wraps nothing).
    pub fn new(function: VectorFunction, modulo: Vec<f64>) -> Result<Self, String> {
        let d = function.dim();
        let modulo = if modulo.is_empty() {
            vec![0.0; d]
        } else {
            modulo
        };
        chaoscope_indicators::periodic::check_periods(&modulo, d)?;
        let wraps = modulo.iter().any(|&p| p > 0.0);
        Ok(Self {
            function,
            modulo,
            wraps,
        })
    }

    pub fn function(&self) -> &VectorFunction {
        &self.function
    }

    /// The period of each coordinate (`0`: not wrapped).
    pub fn modulo(&self) -> &[f64] {
        &self.modulo
    }

    /// Every wrapped coordinate into `[0, P)`. A non-finite value stays non-finite (the run's
    /// check stops on it).
    #[inline]
    pub fn wrap(&self, x: &mut [f64]) {
        if self.wraps {
            batch::wrap(&self.modulo, x);
        }
    }

    /// `ln |det J(x)|`: the map's local phase-space volume expansion per iteration, whose
    /// average along an orbit is the sum of all its Lyapunov exponents. From the `D` columns
    /// `J e_j` and an LU factorization with partial pivoting (`sum ln |U_ii|`, no overflow for
    /// large `D`). `None` when the map has no tangent (see
    /// [`VectorFunction::no_tangent_reason`]); `-inf` for a singular Jacobian.
    pub fn log_abs_det_jacobian(&self, x: &[f64]) -> Option<f64> {
        let d = self.function.dim();
        let mut a = vec![0.0; d * d];
        let mut e = vec![0.0; d];
        let mut column = vec![0.0; d];
        for j in 0..d {
            e[j] = 1.0;
            if !self.function.tangent(x, &e, &mut column) {
                return None;
            }
            e[j] = 0.0;
            for i in 0..d {
                a[i * d + j] = column[i];
            }
        }
        Some(log_abs_det(&mut a, d))
    }
}

/// `ln |det A|` of the row-major `d x d` matrix `a` (overwritten) by Gaussian elimination with
/// partial pivoting.
fn log_abs_det(a: &mut [f64], d: usize) -> f64 {
    let mut sum = 0.0;
    for k in 0..d {
        let pivot = (k..d)
            .max_by(|&i, &j| a[i * d + k].abs().total_cmp(&a[j * d + k].abs()))
            .expect("k < d");
        if pivot != k {
            for c in 0..d {
                a.swap(k * d + c, pivot * d + c);
            }
        }
        let u = a[k * d + k];
        if u == 0.0 {
            return f64::NEG_INFINITY;
        }
        sum += u.abs().ln();
        for i in k + 1..d {
            let l = a[i * d + k] / u;
            for c in k + 1..d {
                a[i * d + c] -= l * a[k * d + c];
            }
        }
    }
    sum
}

impl DynamicalSystem for Map {
    fn name(&self) -> &str {
        "map"
    }

    fn kind(&self) -> SystemClass {
        SystemClass::Map
    }

    fn dim(&self) -> usize {
        self.function.dim()
    }

    fn time(&self) -> Time {
        Time::Discrete
    }

    /// Its compiled lane functions ([`MapKernel`]).
    fn batched(&self, _isa: Isa) -> Option<Box<dyn PointKernel + '_>> {
        Some(Box::new(MapKernel {
            map: self,
            stages: Vec::new(),
            scratch: Vec::new(),
        }))
    }

    /// (A map's `next` cannot read the time: `t` is ignored, here and below.)
    #[inline]
    fn step(&self, x: &mut [f64], _t: f64, work: &mut Workspace) {
        let d = self.function.dim();
        let next = work.force(d);
        self.function.value(x, next);
        x[..d].copy_from_slice(next);
        self.wrap(x);
    }

    /// `w_i -> J(x) w_i` for each of the vectors in `w`, at the state before the iteration, then
    /// the iteration of `x` itself.
    fn step_tangent(
        &self,
        x: &mut [f64],
        w: &mut [f64],
        _t: f64,
        work: &mut Workspace,
    ) -> Result<(), TangentError> {
        let d = self.function.dim();
        let buf = work.force(2 * d);
        let (next, jw) = buf.split_at_mut(d);
        for wi in w.chunks_exact_mut(d) {
            if !self.function.tangent(x, wi, jw) {
                return Err(TangentError::NoHessian(
                    self.function
                        .no_tangent_reason()
                        .unwrap_or_else(|| "the map has no tangent".to_string()),
                ));
            }
            wi.copy_from_slice(jw);
        }
        self.function.value(x, next);
        x[..d].copy_from_slice(next);
        self.wrap(x);
        Ok(())
    }

    fn no_tangent_reason(&self) -> Option<String> {
        self.function.no_tangent_reason()
    }

    fn invariant(&self, _x: &[f64]) -> Option<f64> {
        None
    }

    /// `ln |det DF(x)|`: the sum of the exponents per iteration equals its orbit average. A
    /// singular Jacobian (a map that collapses a direction, legitimately) counts as the
    /// smallest normal `|det|`, ln = -708, rather than -inf: the run goes on, and no infinity
    /// reaches an output.
    fn divergence(&self, x: &[f64], _t: f64) -> Option<f64> {
        self.log_abs_det_jacobian(x).map(|l| {
            if l == f64::NEG_INFINITY {
                f64::MIN_POSITIVE.ln()
            } else {
                l
            }
        })
    }

    fn diagnose_non_finite(&self, x: &[f64], _t: f64) -> Option<String> {
        self.function.diagnose_non_finite(x)
    }

    /// The minimal image of `y - x` in every wrapped coordinate.
    #[inline]
    fn separation(&self, y: &[f64], x: &[f64], out: &mut [f64]) {
        for (((o, &a), &b), &p) in out.iter_mut().zip(y).zip(x).zip(&self.modulo) {
            let d = a - b;
            *o = if p > 0.0 && d.abs() > 0.5 * p {
                d - p * (d / p).round()
            } else {
                d
            };
        }
    }
}

/// The batched form of a map: its compiled lane functions (the SIMD is inside the compiled
/// code, so there is no instruction-set choice here).
struct MapKernel<'a> {
    map: &'a Map,
    /// States before every iteration of the last reference steps.
    stages: Vec<f64>,
    scratch: Vec<f64>,
}

impl PointKernel for MapKernel<'_> {
    fn orbit_steps(&mut self, x: &mut Soa, _from: u64, steps: u64) {
        let map = self.map;
        batch::map_orbit_steps(&map.function, &map.modulo, x, steps, &mut self.scratch);
    }

    fn reference_steps(&mut self, x: &mut [f64], _from: u64, steps: u64) {
        let map = self.map;
        batch::record_map_reference(&map.function, &map.modulo, x, steps, &mut self.stages);
    }

    fn tangent_steps(&mut self, v: &mut Soa, _from: u64, steps: u64) -> Result<(), TangentError> {
        let f = &self.map.function;
        if batch::map_tangent_steps(f, &self.stages, v, steps, &mut self.scratch) {
            Ok(())
        } else {
            // Validation refuses VM for a map without a tangent; this is the same error the
            // engine would raise, should that ever be bypassed.
            Err(TangentError::NoHessian(
                f.no_tangent_reason()
                    .unwrap_or_else(|| "the map's Jacobian".into()),
            ))
        }
    }

    #[inline]
    fn separation(&self, y: &[f64], x: &[f64], out: &mut [f64]) {
        self.map.separation(y, x, out);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::batch::wrap_coordinate;
    use chaoscope_expr::{Boundary, ParamValue, VectorDefinition};

    fn map(components: &[&str], params: &[(&str, f64)], modulo: Vec<f64>) -> Map {
        let f = VectorFunction::new(VectorDefinition {
            key: "next".into(),
            components: components.iter().map(|s| s.to_string()).collect(),
            params: params
                .iter()
                .map(|(n, v)| (n.to_string(), ParamValue::Scalar(*v)))
                .collect(),
            boundary: Boundary::Fixed,
            tables: Vec::new(),
            time: false,
        })
        .unwrap();
        Map::new(f, modulo).unwrap()
    }

    #[test]
    fn wrap_lands_in_the_period() {
        let p = std::f64::consts::TAU;
        for x in [
            0.0,
            -0.0,
            1.0,
            p,
            -1e-300,
            -1e-17,
            7.0 * p + 0.5,
            -3.0 * p - 0.25,
        ] {
            let r = wrap_coordinate(x, p);
            assert!((0.0..p).contains(&r), "{x} -> {r}");
        }
        assert_eq!(wrap_coordinate(-1e-17, p), 0.0);
        assert!(
            wrap_coordinate(f64::NAN, p).is_nan() && wrap_coordinate(f64::INFINITY, p).is_nan()
        );
    }

    #[test]
    fn standard_map_wraps_and_measures_separations_on_the_torus() {
        let p = std::f64::consts::TAU;
        let m = map(
            &["x1 + x2 + K * sin(x1)", "x2 + K * sin(x1)"],
            &[("K", 1.0)],
            vec![p, p],
        );
        let mut x = vec![6.0, 6.2];
        let mut w = Workspace::new();
        for _ in 0..100 {
            m.step(&mut x, 0.0, &mut w);
            assert!(x.iter().all(|v| (0.0..p).contains(v)), "{x:?}");
        }
        // Across the seam: 1e-8 apart, not 2 pi - 1e-8.
        let mut d = [0.0; 2];
        m.separation(&[1e-9, 3.0], &[p - 9e-9, 3.0], &mut d);
        assert!((d[0] - 1e-8).abs() < 1e-15, "{d:?}");
        m.separation(&[p - 9e-9, 3.0], &[1e-9, 3.0 + 1e-8], &mut d);
        assert!(
            (d[0] + 1e-8).abs() < 1e-15 && (d[1] + 1e-8).abs() < 1e-15,
            "{d:?}"
        );
        // Area-preserving: ln |det J| = 0 to rounding.
        assert!(m.log_abs_det_jacobian(&x).unwrap().abs() < 1e-15);
    }

    #[test]
    fn henon_tangent_and_determinant() {
        let m = map(
            &["1 - a * x1^2 + x2", "b * x1"],
            &[("a", 1.4), ("b", 0.3)],
            vec![],
        );
        let mut x = vec![0.1, 0.2];
        let mut v = vec![1.0, 0.0, 0.0, 1.0];
        let mut w = Workspace::new();
        m.step_tangent(&mut x, &mut v, 0.0, &mut w).unwrap();
        assert_eq!(x, vec![1.0 - 1.4 * 0.1 * 0.1 + 0.2, 0.3 * 0.1]);
        assert_eq!(v, vec![-2.8 * 0.1, 0.3, 1.0, 0.0]);
        for x in [[0.1, 0.2], [1.2, -0.3], [0.0, 0.0]] {
            let l = m.log_abs_det_jacobian(&x).unwrap();
            assert!((l - 0.3f64.ln()).abs() < 1e-15, "{l}");
        }
        let mut d = [0.0; 2];
        m.separation(&[10.0, -5.0], &[-10.0, 5.0], &mut d);
        assert_eq!(d, [20.0, -10.0]);
        assert_eq!(m.time(), Time::Discrete);
    }

    #[test]
    fn bad_modulo_is_refused() {
        let f = map(&["x1", "x2"], &[], vec![]).function().clone();
        assert!(Map::new(f.clone(), vec![1.0]).unwrap_err().contains("2"));
        assert!(
            Map::new(f.clone(), vec![1.0, -1.0])
                .unwrap_err()
                .contains("entry 2")
        );
        assert!(
            Map::new(f, vec![f64::NAN, 0.0])
                .unwrap_err()
                .contains("entry 1")
        );
    }

    fn standard_map() -> Map {
        let f = VectorFunction::new(VectorDefinition {
            key: "next".into(),
            components: vec!["x1 + x2 + K * sin(x1)".into(), "x2 + K * sin(x1)".into()],
            params: [("K".to_string(), ParamValue::Scalar(1.2))].into(),
            boundary: Boundary::Fixed,
            tables: Vec::new(),
            time: false,
        })
        .unwrap();
        let p = std::f64::consts::TAU;
        Map::new(f, vec![p, p]).unwrap()
    }

    /// Every lane of the batched form equals the one-orbit `step` / `step_tangent` bit for bit,
    /// lane counts that are and are not multiples of the compiled block.
    #[test]
    fn batched_lanes_match_the_one_orbit_steps_bit_for_bit() {
        let m = standard_map();
        let mut kernel = m.batched(Isa::detect()).unwrap();
        for used in [1usize, 3, 8, 13] {
            let starts: Vec<Vec<f64>> = (0..used)
                .map(|l| vec![0.1 + 0.37 * l as f64, 6.0 - 0.41 * l as f64])
                .collect();
            let mut soa = Soa::new(2, used);
            for (l, x) in starts.iter().enumerate() {
                soa.write_lane(l, x);
            }
            kernel.orbit_steps(&mut soa, 0, 50);
            let mut w = Workspace::new();
            for (l, x0) in starts.iter().enumerate() {
                let mut x = x0.clone();
                for _ in 0..50 {
                    m.step(&mut x, 0.0, &mut w);
                }
                let mut got = vec![0.0; 2];
                soa.read_lane(l, &mut got);
                assert_eq!(got, x, "lane {l} of {used}");
            }

            // Tangent vectors around the first start.
            let mut x = starts[0].clone();
            kernel.reference_steps(&mut x, 0, 50);
            let mut v = Soa::new(2, used);
            let dirs: Vec<Vec<f64>> = (0..used)
                .map(|l| vec![(l as f64).cos(), (l as f64).sin()])
                .collect();
            for (l, d) in dirs.iter().enumerate() {
                v.write_lane(l, d);
            }
            kernel.tangent_steps(&mut v, 0, 50).unwrap();
            for (l, d) in dirs.iter().enumerate() {
                let (mut y, mut w1) = (starts[0].clone(), d.clone());
                for _ in 0..50 {
                    m.step_tangent(&mut y, &mut w1, 0.0, &mut w).unwrap();
                }
                assert_eq!(y, x, "reference copy");
                let mut got = vec![0.0; 2];
                v.read_lane(l, &mut got);
                assert_eq!(got, w1, "tangent lane {l} of {used}");
            }
        }
    }
}
