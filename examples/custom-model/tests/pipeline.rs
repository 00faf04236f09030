//! The hand-written model through engine, recording and analysis: its derivatives agree with its
//! potential, the recording analyzes, and the physics is that of a bounded regular orbit.

use chaoscope_dynamics::model::{At, SeparableHamiltonian};
use chaoscope_example_custom_model::{Barbanis, CONFIG, record, run_spec};

#[test]
fn derivatives_agree_with_the_potential() {
    let m = Barbanis {
        w1: 1.6,
        w2: 0.9,
        eps: 0.08,
    };
    let q = [0.3, -0.4];
    let v = [0.6, 0.8];
    let eps = 1e-6;
    let mut g = [0.0; 2];
    m.gradient(&q, At::T0, &mut g);
    let mut hv = [0.0; 2];
    assert!(m.no_hessian_reason().is_none());
    m.hessian_vector(&q, At::T0, &v, &mut hv);
    for i in 0..2 {
        let mut qp = q;
        let mut qm = q;
        qp[i] += eps;
        qm[i] -= eps;
        // Central differences: truncation ~ eps^2 |V'''| ~ 1e-13, rounding ~ 1e-16 / eps.
        let fd = (m.potential(&qp, At::T0) - m.potential(&qm, At::T0)) / (2.0 * eps);
        assert!((fd - g[i]).abs() < 1e-8, "dV/dq{i}: {fd} vs {}", g[i]);
    }
    let (mut gp, mut gm) = ([0.0; 2], [0.0; 2]);
    let qp = [q[0] + eps * v[0], q[1] + eps * v[1]];
    let qm = [q[0] - eps * v[0], q[1] - eps * v[1]];
    m.gradient(&qp, At::T0, &mut gp);
    m.gradient(&qm, At::T0, &mut gm);
    for i in 0..2 {
        let fd = (gp[i] - gm[i]) / (2.0 * eps);
        assert!((fd - hv[i]).abs() < 1e-8, "Hv[{i}]: {fd} vs {}", hv[i]);
    }
}

#[test]
fn records_and_analyzes_like_a_built_in_model() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("barbanis.mcap");
    let (config, spec) = run_spec(CONFIG).unwrap();
    let report = record(&config, spec, &out).unwrap();
    assert_eq!(report.run.model, "barbanis");
    assert_eq!(report.run.t, 500.0);
    // ABA864 with h = 0.01 on a smooth bounded orbit: energy error at the 1e-10 level.
    let energy_error = report
        .run
        .energy_error_max
        .expect("a Hamiltonian's energy error");
    assert!(energy_error < 1e-8, "{energy_error}");
    let vm = report.scheme("vm").unwrap();
    let mpm = report.scheme("mpm").unwrap();
    // The same orbit, the same directions: MPM at d0 = 1e-8 follows VM closely (the paper's
    // optimal d0), to a few percent in the MLE over this time.
    assert!(vm.mle.is_finite() && mpm.mle.is_finite());
    assert!(
        (vm.mle - mpm.mle).abs() < 0.05 * vm.mle.abs() + 1e-3,
        "{} vs {}",
        vm.mle,
        mpm.mle
    );
    // The file is a regular chaoscope recording: the analysis read every sample.
    assert_eq!(report.run.samples, 501);
}
