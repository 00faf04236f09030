//! The paper's reference runs as typed configs: its Henon-Heiles and beta-FPUT (N = 5) orbits
//! and integration settings, and its window on the Henon-Heiles section.
//!
//! One definition for the tests, the benchmarks and `chaoscope bench`, so each of them states
//! only what it varies (horizon, sets, schemes, a `[map]`); a field set after construction
//! overrides a paper value. [`RunConfig::to_toml`] gives the text a user would write, for the
//! command-line tools.

use super::{
    DeviationsConfig, FputBetaConfig, IntegratorConfig, MapAxis, MapConfig, ModelConfig,
    OrbitConfig, RunConfig, RunSection, SchemeConfig,
};

/// Energy of the paper's Henon-Heiles orbits.
pub const HH_ENERGY: f64 = 0.125;
/// `q2` of the paper's chaotic Henon-Heiles orbit.
pub const HH_CHAOTIC_Q2: f64 = -0.25;
/// `q2` of the paper's regular Henon-Heiles orbit.
pub const HH_REGULAR_Q2: f64 = 0.558;
/// The paper's ABA864 time step for Henon-Heiles.
pub const HH_STEP: f64 = 0.01;

/// Henon-Heiles from `q = (0, q2)`, `p2 = 0` and `p1 > 0` solved from `H = HH_ENERGY`,
/// integrated by ABA864 with `h = HH_STEP` up to `t_final`.
pub fn henon_heiles(
    q2: f64,
    t_final: f64,
    deviations: DeviationsConfig,
    schemes: Vec<SchemeConfig>,
) -> RunConfig {
    let model = ModelConfig::HenonHeiles(Default::default());
    let orbit = OrbitConfig {
        q: vec![0.0, q2],
        p: vec![0.0, 0.0],
        energy: Some(HH_ENERGY),
        solve_for: Some("p1".to_string()),
        ..OrbitConfig::default()
    };
    aba864_run(model, orbit, HH_STEP, t_final, deviations, schemes)
}

/// The paper's window on the Henon-Heiles section `q1 = 0`: `q2` in [-0.45, 0.65], `p2` in
/// [-0.45, 0.45], on an `nx` by `ny` grid.
pub fn hh_section_map(nx: usize, ny: usize, indicator: &str) -> MapConfig {
    MapConfig::new(
        MapAxis::new("q2", -0.45, 0.65, nx),
        MapAxis::new("p2", -0.45, 0.45, ny),
        indicator,
    )
}

/// The paper's regular orbit of the beta-FPUT chain with N = 5 (`H ~ 5`).
pub const FPUT_N5_REGULAR_Q: [f64; 5] = [1.03003, 0.0, -1.04003, 0.0, 1.04003];
pub const FPUT_N5_REGULAR_P: [f64; 5] = [0.29284, 0.0, 0.0, 0.0, 0.0];
/// The paper's chaotic orbit of the beta-FPUT chain with N = 5 (`H ~ 10`), written with the
/// digits the paper gives (more than a double holds; the nearest double is the same).
#[allow(clippy::excessive_precision)]
pub const FPUT_N5_CHAOTIC_Q: [f64; 5] = [
    -1.151344372237934177,
    -0.000000000000007443,
    1.151344372237925295,
    0.000000000000006056,
    -1.151344372237918634,
];
#[allow(clippy::excessive_precision)]
pub const FPUT_N5_CHAOTIC_P: [f64; 5] = [
    1.502757415151290132,
    0.000000000000014786,
    -1.502757415151279696,
    -0.000000000000017280,
    1.502757415151272147,
];

/// The beta-FPUT chain (`beta = 1`, `N = q.len()` sites) from the state `(q, p)`, integrated by
/// ABA864 with step `h` up to `t_final`.
pub fn fput_beta(
    q: &[f64],
    p: &[f64],
    h: f64,
    t_final: f64,
    deviations: DeviationsConfig,
    schemes: Vec<SchemeConfig>,
) -> RunConfig {
    let model = ModelConfig::FputBeta(FputBetaConfig {
        n: Some(q.len()),
        beta: Some(1.0),
    });
    let orbit = OrbitConfig {
        q: q.to_vec(),
        p: p.to_vec(),
        ..OrbitConfig::default()
    };
    aba864_run(model, orbit, h, t_final, deviations, schemes)
}

/// The paper integrates every run with ABA864.
fn aba864_run(
    model: ModelConfig,
    orbit: OrbitConfig,
    h: f64,
    t_final: f64,
    deviations: DeviationsConfig,
    schemes: Vec<SchemeConfig>,
) -> RunConfig {
    RunConfig {
        run: RunSection::default(),
        model,
        orbit,
        integrator: IntegratorConfig::fixed("aba864", h, t_final),
        deviations,
        schemes,
        sweeps: Vec::new(),
        map: None,
        analysis: Default::default(),
    }
}
