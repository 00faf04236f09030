//! The batched form of a discrete [`Map`]: many orbits (or tangent vectors) iterated at once
//! through the compiled lane functions of its vector function.
//!
//! Lane by lane these are the bits of [`Map`]'s `step` / `step_tangent`: the compiled lane
//! function of `F` (or of `J v` around one shared reference state) gives, per lane, exactly
//! the scalar function's result, and the wrap into `[0, P)` is the same function of each
//! value. The SIMD lives inside the compiled code (two or four lanes per vector instruction),
//! so there is no per-ISA instantiation here.

use super::Soa;
use crate::system::Map;

/// Iterate every lane of `x` (rows = coordinates) `n_steps` times; `scratch` is reused.
pub fn map_orbit_steps(map: &Map, x: &mut Soa, n_steps: u64, scratch: &mut Vec<f64>) {
    let lanes = x.lanes();
    let d = x.rows();
    scratch.resize(d * lanes, 0.0);
    for _ in 0..n_steps {
        map.function().value_lanes(x.data(), scratch, lanes);
        x.data_mut().copy_from_slice(scratch);
        wrap_rows(map, x.data_mut(), lanes);
    }
}

/// Iterate one reference orbit `x` `n_steps` times exactly as `Map::step` does, writing the
/// state before every iteration to `stages` (`n_steps * D` numbers): where the tangent map of
/// each iteration is taken.
pub fn record_map_reference(map: &Map, x: &mut [f64], n_steps: u64, stages: &mut Vec<f64>) {
    let mut next = vec![0.0; x.len()];
    stages.clear();
    for _ in 0..n_steps {
        stages.extend_from_slice(x);
        map.function().value(x, &mut next);
        x.copy_from_slice(&next);
        map.wrap(x);
    }
}

/// Advance every lane of `v` (tangent vectors) by `n_steps` iterations of the tangent map
/// around the reference states `stages` (from [`record_map_reference`]). `false` when the map
/// has no tangent (the variational method was refused at validation already).
pub fn map_tangent_steps(
    map: &Map,
    stages: &[f64],
    v: &mut Soa,
    n_steps: u64,
    scratch: &mut Vec<f64>,
) -> bool {
    let lanes = v.lanes();
    let d = v.rows();
    scratch.resize(d * lanes, 0.0);
    for x in stages.chunks_exact(d).take(n_steps as usize) {
        if !map.function().tangent_lanes(x, v.data(), scratch, lanes) {
            return false;
        }
        v.data_mut().copy_from_slice(scratch);
    }
    true
}

fn wrap_rows(map: &Map, data: &mut [f64], lanes: usize) {
    for (row, &p) in data.chunks_exact_mut(lanes).zip(map.modulo()) {
        if p > 0.0 {
            for v in row {
                *v = crate::system::wrap_coordinate(*v, p);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::integrator::Workspace;
    use crate::system::DynamicalSystem;
    use chaoscope_expr::{Boundary, ParamValue, VectorDefinition, VectorFunction};

    fn standard_map() -> Map {
        let f = VectorFunction::new(VectorDefinition {
            key: "next".into(),
            components: vec!["x1 + x2 + K * sin(x1)".into(), "x2 + K * sin(x1)".into()],
            params: [("K".to_string(), ParamValue::Scalar(1.2))].into(),
            boundary: Boundary::Fixed,
            tables: Vec::new(),
        })
        .unwrap();
        let p = std::f64::consts::TAU;
        Map::new(f, vec![p, p]).unwrap()
    }

    /// Every lane of the batch equals the one-orbit `step` / `step_tangent` bit for bit, lane
    /// counts that are and are not multiples of the compiled block.
    #[test]
    fn lanes_match_the_one_orbit_steps_bit_for_bit() {
        let m = standard_map();
        for used in [1usize, 3, 8, 13] {
            let starts: Vec<Vec<f64>> = (0..used)
                .map(|l| vec![0.1 + 0.37 * l as f64, 6.0 - 0.41 * l as f64])
                .collect();
            let mut soa = Soa::new(2, used);
            for (l, x) in starts.iter().enumerate() {
                soa.write_lane(l, x);
            }
            let mut scratch = Vec::new();
            map_orbit_steps(&m, &mut soa, 50, &mut scratch);
            let mut w = Workspace::new();
            for (l, x0) in starts.iter().enumerate() {
                let mut x = x0.clone();
                for _ in 0..50 {
                    m.step(&mut x, &mut w);
                }
                let mut got = vec![0.0; 2];
                soa.read_lane(l, &mut got);
                assert_eq!(got, x, "lane {l} of {used}");
            }

            // Tangent vectors around the first start.
            let mut x = starts[0].clone();
            let mut stages = Vec::new();
            record_map_reference(&m, &mut x, 50, &mut stages);
            let mut v = Soa::new(2, used);
            let dirs: Vec<Vec<f64>> = (0..used)
                .map(|l| vec![(l as f64).cos(), (l as f64).sin()])
                .collect();
            for (l, d) in dirs.iter().enumerate() {
                v.write_lane(l, d);
            }
            assert!(map_tangent_steps(&m, &stages, &mut v, 50, &mut scratch));
            for (l, d) in dirs.iter().enumerate() {
                let (mut y, mut w1) = (starts[0].clone(), d.clone());
                for _ in 0..50 {
                    m.step_tangent(&mut y, &mut w1, &mut w).unwrap();
                }
                assert_eq!(y, x, "reference copy");
                let mut got = vec![0.0; 2];
                v.read_lane(l, &mut got);
                assert_eq!(got, w1, "tangent lane {l} of {used}");
            }
        }
    }
}
