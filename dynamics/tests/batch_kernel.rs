//! The batched kernel against the one-orbit integrator: bit for bit, on every instruction set
//! this CPU has, for Henon-Heiles, the FPUT chain, the same models written as expressions
//! (compiled step kernels) and the generic fallback.

use std::sync::Arc;

use chaoscope_dynamics::batch::{
    self, AnyLaneModel, DynLanes, Isa, LaneHamiltonian, Soa, StepCoeffs, record_reference_stages,
};
use chaoscope_dynamics::integrator::{Integrator, Splitting, SplittingScheme, Workspace};
use chaoscope_dynamics::model::{ExpressionModel, FputBeta, HenonHeiles};
use chaoscope_dynamics::with_lane_model;
use chaoscope_schemas::config::{ModelConfig, ParamValue, PotentialConfig};

/// Deterministic pseudo-random numbers in [-1, 1) (no dependency needed).
fn noise(seed: u64, i: usize) -> f64 {
    let mut z = seed.wrapping_add(0x9e37_79b9_7f4a_7c15u64.wrapping_mul(i as u64 + 1));
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^= z >> 31;
    (z >> 11) as f64 / (1u64 << 52) as f64 - 1.0
}

fn bits(v: &[f64]) -> Vec<u64> {
    v.iter().map(|x| x.to_bits()).collect()
}

fn check_orbits<M: LaneHamiltonian>(model: &M, lanes: usize, scale: f64, n_steps: u64) {
    let dim = 2 * model.dof();
    let split = Splitting::new(SplittingScheme::Aba864);
    let h = 0.01;
    let coeffs = StepCoeffs::new(&split, h);
    let start: Vec<Vec<f64>> = (0..lanes)
        .map(|l| (0..dim).map(|i| scale * noise(l as u64, i)).collect())
        .collect();
    // One orbit at a time through Splitting::step (the engine's path).
    let mut work = Workspace::new();
    let want: Vec<Vec<f64>> = start
        .iter()
        .map(|x0| {
            let mut x = x0.clone();
            for _ in 0..n_steps {
                split.step(model, &mut x, 0.0, h, &mut work);
            }
            x
        })
        .collect();
    for isa in Isa::ALL.into_iter().filter(|i| i.available()) {
        let mut soa = Soa::new(dim, lanes);
        for (l, x) in start.iter().enumerate() {
            soa.write_lane(l, x);
        }
        // Two calls of half the steps: a renormalization window boundary must not matter.
        batch::orbit_steps(isa, model, &coeffs, &mut soa, n_steps / 2);
        batch::orbit_steps(isa, model, &coeffs, &mut soa, n_steps - n_steps / 2);
        let mut got = vec![0.0; dim];
        for (l, w) in want.iter().enumerate() {
            soa.read_lane(l, &mut got);
            assert_eq!(
                bits(&got),
                bits(w),
                "{} lane {l} on {}",
                model.name(),
                isa.name()
            );
        }
    }
}

fn check_tangents<M: LaneHamiltonian>(model: &M, lanes: usize, scale: f64, n_steps: u64) {
    let n = model.dof();
    let dim = 2 * n;
    let split = Splitting::new(SplittingScheme::Aba864);
    let h = 0.01;
    let coeffs = StepCoeffs::new(&split, h);
    let x0: Vec<f64> = (0..dim).map(|i| scale * noise(99, i)).collect();
    let vectors: Vec<f64> = (0..lanes * dim).map(|i| noise(7, i)).collect();
    // Engine path: step_tangent on the orbit and all vectors.
    let mut work = Workspace::new();
    let (mut x, mut w) = (x0.clone(), vectors.clone());
    for _ in 0..n_steps {
        split
            .step_tangent(model, &mut x, &mut w, 0.0, h, &mut work)
            .unwrap();
    }
    for isa in Isa::ALL.into_iter().filter(|i| i.available()) {
        let mut soa = Soa::new(dim, lanes);
        for (l, v) in vectors.chunks_exact(dim).enumerate() {
            soa.write_lane(l, v);
        }
        let mut reference = x0.clone();
        let (mut stages, mut force) = (Vec::new(), vec![0.0; n]);
        record_reference_stages(
            model,
            &coeffs,
            &mut reference,
            n_steps,
            &mut stages,
            &mut force,
        );
        assert_eq!(
            bits(&reference),
            bits(&x),
            "reference orbit on {}",
            isa.name()
        );
        batch::tangent_steps(isa, model, &coeffs, &stages, &mut soa, n_steps);
        let mut got = vec![0.0; dim];
        for (l, want) in w.chunks_exact(dim).enumerate() {
            soa.read_lane(l, &mut got);
            assert_eq!(
                bits(&got),
                bits(want),
                "{} vector {l} on {}",
                model.name(),
                isa.name()
            );
        }
    }
}

#[test]
fn henon_heiles_lanes_equal_one_orbit_steps() {
    // 45 lanes: full 32-lane chunks, 8-lane remainders and padding all get exercised.
    check_orbits(&HenonHeiles, 45, 0.3, 301);
    check_tangents(&HenonHeiles, 45, 0.3, 301);
}

#[test]
fn fput_lanes_equal_one_orbit_steps() {
    for n in [1, 2, 5, 11] {
        let m = FputBeta::new(n, 1.0).unwrap();
        check_orbits(&m, 19, 0.8, 57);
        check_tangents(&m, 19, 0.8, 57);
    }
}

#[test]
fn generic_fallback_equals_one_orbit_steps() {
    let m = DynLanes::new(Arc::new(FputBeta::new(4, 0.7).unwrap()));
    check_orbits(&m, 9, 0.8, 23);
    check_tangents(&m, 9, 0.8, 23);
    // The dispatcher picks the concrete implementations for the shipped models.
    let any = AnyLaneModel::new(Arc::new(HenonHeiles));
    with_lane_model!(&any, |m| check_orbits(m, 8, 0.3, 11));
}

fn expression(config: &ModelConfig) -> ExpressionModel {
    let (model, _) = chaoscope_dynamics::spec::model_from_config(config).unwrap();
    let any: &dyn std::any::Any = model.as_ref();
    any.downcast_ref::<ExpressionModel>()
        .expect("a potential compiles to an ExpressionModel")
        .clone()
}

#[test]
fn compiled_expression_lanes_equal_one_orbit_steps() {
    // The step kernels (drift, inline force and kick in native code) against the one-orbit
    // engine, which runs the scalar compiled gradient and Hessian-vector product.
    let hh = expression(&ModelConfig::potential(
        2,
        "(q1^2 + q2^2)/2 + q1^2*q2 - q2^3/3",
    ));
    check_orbits(&hh, 45, 0.3, 301);
    check_tangents(&hh, 45, 0.3, 301);
    let mut fput = PotentialConfig {
        n: Some(5),
        potential: Some("sum(i = 0..N, (q[i+1] - q[i])^2/2 + beta/4*(q[i+1] - q[i])^4)".into()),
        ..PotentialConfig::default()
    };
    fput.params.insert("beta".into(), ParamValue::Scalar(1.0));
    let m = expression(&ModelConfig::Potential(fput.clone()));
    check_orbits(&m, 19, 0.8, 57);
    check_tangents(&m, 19, 0.8, 57);
    // Unequal masses: the drift's `(ch / m_i) * p` per row.
    fput.masses = Some(ParamValue::Array(vec![1.0, 2.0, 0.5, 3.0, 1.5]));
    let m = expression(&ModelConfig::Potential(fput));
    check_orbits(&m, 19, 0.8, 57);
    check_tangents(&m, 19, 0.8, 57);
    // Through the dispatcher, as the map kernels pick it.
    let any = AnyLaneModel::new(Arc::new(hh));
    assert!(matches!(any, AnyLaneModel::Expression(_)));
    with_lane_model!(&any, |m| check_orbits(m, 8, 0.3, 11));
}
