//! Shared helpers for the physics tests: run a config in process and keep per-scheme series.
#![allow(dead_code)]

use chaoscope_dynamics::engine::Engine;
use chaoscope_dynamics::indicators::{StretchSums, gali_log10};
use chaoscope_dynamics::spec::RunSpec;
use chaoscope_schemas::config::RunConfig;

/// One renormalization of one scheme, all sets.
#[derive(Debug, Clone)]
pub struct Point {
    pub t: f64,
    /// `[set][j - 2]` = log10 GALI_j.
    pub gali: Vec<Vec<f64>>,
    /// `[set][i]` = finite-time exponent from vector i's accumulated stretching.
    pub exponents: Vec<Vec<f64>>,
    /// Relative energy error of the reference orbit.
    pub energy_error: f64,
}

impl Point {
    /// Mean over sets of log10 GALI_j (the geometric mean, as numerics.md recommends).
    pub fn mean_log_gali(&self, j: usize) -> f64 {
        self.gali.iter().map(|g| g[j - 2]).sum::<f64>() / self.gali.len() as f64
    }

    pub fn mean_exponent(&self, i: usize) -> f64 {
        self.exponents.iter().map(|e| e[i]).sum::<f64>() / self.exponents.len() as f64
    }
}

pub struct Recorded {
    pub spec: RunSpec,
    /// `[scheme]` = series over renormalization times (t > 0).
    pub series: Vec<Vec<Point>>,
}

impl Recorded {
    pub fn scheme(&self, name: &str) -> &[Point] {
        let i = self
            .spec
            .schemes()
            .iter()
            .position(|s| s.name == name)
            .expect("scheme exists");
        &self.series[i]
    }
}

pub fn spec(config: &RunConfig) -> RunSpec {
    RunSpec::from_config(config).expect("config is valid")
}

pub fn run(config: &RunConfig) -> Recorded {
    run_spec(spec(config))
}

pub fn run_spec(spec: RunSpec) -> Recorded {
    let sets = spec.sets();
    let k = spec.k();
    let dim = spec.dim();
    let mut sums = vec![vec![StretchSums::new(k); sets]; spec.schemes().len()];
    let mut series: Vec<Vec<Point>> = vec![Vec::new(); spec.schemes().len()];
    let e0 = spec.e0();
    let engine = Engine::new(spec.clone());
    engine
        .run(|sample| {
            if sample.seq == 0 {
                return;
            }
            let mut current: Vec<Option<Point>> = vec![None; series.len()];
            for s in &sample.schemes {
                let (si, set) = (s.scheme as usize, s.set as usize);
                sums[si][set].add(&s.stretch);
                let p = current[si].get_or_insert_with(|| Point {
                    t: sample.t,
                    gali: vec![Vec::new(); sets],
                    exponents: vec![Vec::new(); sets],
                    energy_error: ((sample.energy - e0) / e0).abs(),
                });
                p.gali[set] = gali_log10(&s.separations, dim);
                p.exponents[set] = sums[si][set].spectrum(sample.t);
            }
            for (si, p) in current.into_iter().enumerate() {
                if let Some(p) = p {
                    series[si].push(p);
                }
            }
        })
        .expect("run completes");
    Recorded { spec, series }
}

/// Least-squares slope of y against x.
pub fn slope(x: &[f64], y: &[f64]) -> f64 {
    let n = x.len() as f64;
    let mx = x.iter().sum::<f64>() / n;
    let my = y.iter().sum::<f64>() / n;
    let sxy: f64 = x.iter().zip(y).map(|(a, b)| (a - mx) * (b - my)).sum();
    let sxx: f64 = x.iter().map(|a| (a - mx) * (a - mx)).sum();
    sxy / sxx
}

/// The largest `|a_i - b_i|`.
pub fn max_difference(a: &[f64], b: &[f64]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f64::max)
}
