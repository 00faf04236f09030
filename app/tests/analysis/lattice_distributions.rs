//! The energy distribution and the deviation vector distribution over a lattice's sites
//! (`energy_m2`, `energy_participation`, `dvd_m2`, `dvd_participation`) on real runs of the
//! beta-FPUT chain (built in, and written as a lattice sum) and of disordered Klein-Gordon
//! chains, through the analysis of runs computed in process (the path of `analyze`).

use chaoscope_analyzer::analysis::AnalysisOptions;
use chaoscope_analyzer::report::SchemeReport;
use chaoscope_app::flow::site_energies;
use chaoscope_app::inprocess::analyze_config;
use chaoscope_dynamics::indicators::Named;
use chaoscope_dynamics::indicators::distribution::{mean_site, moments, normalized};
use chaoscope_dynamics::indicators::dvd::site_weights;
use chaoscope_dynamics::spec::RunSpec;
use chaoscope_schemas::config::RunConfig;
use chaoscope_schemas::run::Sample;

const EPS: f64 = f64::EPSILON;

/// A lattice run: `model` (the `[model]` table's keys), the initial state, to `t_final`, one VM
/// set of two vectors renormalized every `tau = 1`.
fn config(model: &str, q: &[f64], p: &[f64], h: f64, t_final: f64) -> RunConfig {
    let text = format!(
        "[run]\nname = \"lattice\"\n[model]\n{model}\n[orbit]\nq = {q:?}\np = {p:?}\n\
         [integrator]\nmethod = \"aba864\"\nh = {h:?}\nt_final = {t_final:?}\n\
         [deviations]\nk = 2\nsets = 1\nseed = 5\n\
         [[scheme]]\nname = \"vm\"\nmethod = \"vm\"\nd0 = 1e-8\ntau = 1.0\n"
    );
    RunConfig::from_toml(&text).unwrap_or_else(|e| panic!("{e}\n{text}"))
}

const FPUT_BUILT_IN: &str = "name = \"fput-beta\"\nn = 15\nbeta = 1.0";
const FPUT_AS_SUM: &str = "name = \"potential\"\nn = 15\nboundary = \"fixed\"\n\
    params = { beta = 1.0 }\n\
    potential = \"sum(i = 0..N, (q[i+1] - q[i])^2/2 + beta/4*(q[i+1] - q[i])^4)\"";

/// A disordered Klein-Gordon chain of `n` sites (Flach, Krimer and Skokos 2009): on-site
/// `eps_l q_l^2 / 2 + q_l^4 / 4`, `eps_l` in [0.5, 1.5] from a fixed sequence, harmonic
/// coupling `1/W`, free ends.
fn kg(n: usize, w: f64) -> String {
    let eps: Vec<f64> = (0..n)
        .map(|l| 0.5 + ((l as f64 * 0.618_033_988_75 + 0.1).fract()))
        .collect();
    format!(
        "name = \"potential\"\nn = {n}\nboundary = \"free\"\nparams = {{ W = {w:?}, eps = {eps:?} }}\n\
         potential = \"sum(i = 1..N, eps[i]/2*q[i]^2 + q[i]^4/4) + sum(i = 1..N, (q[i+1] - q[i])^2/(2*W))\""
    )
}

/// A beta-FPUT state with energy on the middle particles of 15: a localized excitation.
fn fput_state() -> (Vec<f64>, Vec<f64>) {
    let mut q = vec![0.0; 15];
    let mut p = vec![0.0; 15];
    (q[6], q[7], q[8]) = (0.6, -0.9, 0.5);
    (p[5], p[7]) = (0.4, -0.7);
    (q, p)
}

/// Every sample of a run, and its analysis's report at the end.
fn run(cfg: &RunConfig) -> (Vec<Sample>, SchemeReport) {
    let mut samples = Vec::new();
    let a = analyze_config(cfg, &AnalysisOptions::default(), |s| {
        samples.push(s.clone())
    })
    .unwrap();
    let report = a.report();
    (samples, report.schemes[0].clone())
}

fn over_sets(s: &SchemeReport, name: &str) -> f64 {
    match s.indicators.get(name) {
        Some(Named::OverSets(stat)) => stat.mean,
        other => panic!("{name} is {other:?}"),
    }
}

fn unavailable(s: &SchemeReport, name: &str) -> String {
    match s.indicators.get(name) {
        Some(Named::Unavailable(why)) => why.clone(),
        other => panic!("{name} is {other:?}, not unavailable"),
    }
}

/// The site energies of `cfg`'s system at `state`.
fn energies_of(cfg: &RunConfig, states: &[Vec<f64>]) -> Vec<Vec<f64>> {
    let spec = RunSpec::from_config(cfg).unwrap();
    let f = site_energies(spec.system());
    states
        .iter()
        .map(|x| {
            let mut out = vec![0.0; x.len() / 2];
            (f.0)(x, &mut out).unwrap();
            out
        })
        .collect()
}

/// At every sample of the built-in FPUT chain, the FPUT chain written as a lattice sum and a
/// disordered Klein-Gordon chain: the site energies add up to the sample's energy `H` to
/// rounding, and both distributions' weights (energy and DVD) add up to 1 to rounding. Every
/// site energy here is a sum of non-negative terms (kinetic, even powers of bonds and
/// displacements, positive couplings), so each carries at most a few roundings relative to
/// itself and the sum over `N` sites at most `~ N` more relative to `H`: `4 N eps H` bounds both.
#[test]
fn site_energies_add_up_to_h_and_every_distribution_to_one() {
    let (q, p) = fput_state();
    let mut kg_p = vec![0.0; 24];
    (kg_p[10], kg_p[11], kg_p[13]) = (0.6, -0.5, 0.7);
    let cases = [
        ("fput-beta", config(FPUT_BUILT_IN, &q, &p, 0.02, 50.0)),
        ("fput as a sum", config(FPUT_AS_SUM, &q, &p, 0.02, 50.0)),
        ("kg", config(&kg(24, 4.0), &[0.0; 24], &kg_p, 0.05, 50.0)),
    ];
    for (what, cfg) in &cases {
        let (samples, report) = run(cfg);
        assert!(samples.len() > 50, "{what}");
        let states: Vec<Vec<f64>> = samples.iter().map(|s| s.state.clone()).collect();
        for (s, e) in samples.iter().zip(energies_of(cfg, &states)) {
            let n = e.len() as f64;
            let total: f64 = e.iter().sum();
            assert!(
                (total - s.energy).abs() <= 4.0 * n * EPS * s.energy,
                "{what} t = {}: sum h_l = {total}, H = {}",
                s.t,
                s.energy
            );
            assert!(e.iter().all(|h| *h >= 0.0), "{what} t = {}: {e:?}", s.t);
            let weights = normalized(e.iter().copied()).unwrap();
            let sum: f64 = weights.iter().sum();
            assert!((sum - 1.0).abs() <= n * EPS, "{what} t = {}: {sum}", s.t);
            let w = &s.schemes[0].separations[..2 * e.len()];
            let dvd = normalized(site_weights(w, e.len())).unwrap();
            let sum: f64 = dvd.iter().sum();
            assert!(
                (sum - 1.0).abs() <= n * EPS,
                "{what} DVD t = {}: {sum}",
                s.t
            );
        }
        // The report's values are those of the last sample's distribution.
        let last = energies_of(cfg, &states[states.len() - 1..]).remove(0);
        let (m2, p) = moments(last.iter().copied()).unwrap();
        assert_eq!(over_sets(&report, "energy_m2"), m2, "{what}");
        assert_eq!(over_sets(&report, "energy_participation"), p, "{what}");
    }
}

/// The built-in chain and the same chain written as a lattice sum give the same energy
/// distribution: at the same states (the built-in run's), the site energies agree to rounding
/// (the same terms in another order of operations: a few eps relative to `H`), and so do
/// `energy_m2` and `energy_participation`, smooth functions of them (1e-12 relative, a
/// thousandfold margin). The two runs' own reports at t = 0 (the same state) agree likewise.
#[test]
fn the_built_in_fput_chain_and_its_lattice_sum_share_their_energy_distribution() {
    let (q, p) = fput_state();
    let (built_in, as_sum) = (
        config(FPUT_BUILT_IN, &q, &p, 0.02, 20.0),
        config(FPUT_AS_SUM, &q, &p, 0.02, 20.0),
    );
    let (samples, _) = run(&built_in);
    let states: Vec<Vec<f64>> = samples.iter().map(|s| s.state.clone()).collect();
    let (a, b) = (
        energies_of(&built_in, &states),
        energies_of(&as_sum, &states),
    );
    for ((x, y), s) in a.iter().zip(&b).zip(&samples) {
        for (hx, hy) in x.iter().zip(y) {
            assert!(
                (hx - hy).abs() <= 8.0 * EPS * s.energy,
                "t = {}: {hx} vs {hy}",
                s.t
            );
        }
        let ((m2x, px), (m2y, py)) = (
            moments(x.iter().copied()).unwrap(),
            moments(y.iter().copied()).unwrap(),
        );
        assert!(
            (m2x - m2y).abs() <= 1e-12 * m2x,
            "t = {}: m2 {m2x} vs {m2y}",
            s.t
        );
        assert!((px - py).abs() <= 1e-12 * px, "t = {}: P {px} vs {py}", s.t);
    }
    let at_zero = |cfg: &RunConfig| {
        let options = AnalysisOptions {
            at: vec![0.0],
            ..Default::default()
        };
        let a = analyze_config(cfg, &options, |_| {}).unwrap();
        a.report_at(0.0).unwrap().schemes[0].clone()
    };
    let (x, y) = (at_zero(&built_in), at_zero(&as_sum));
    for name in ["energy_m2", "energy_participation"] {
        let (vx, vy) = (over_sets(&x, name), over_sets(&y, name));
        assert!((vx - vy).abs() <= 1e-12 * vx, "{name}: {vx} vs {vy}");
    }
}

/// All the energy on one site (a Klein-Gordon chain at rest but for one momentum: no coupling
/// is stretched, every other site's energy is exactly 0): at t = 0, `P = 1` and `m2 = 0`
/// exactly. Later the energy spreads (the coupling carries it to the neighbours): `P > 1`.
#[test]
fn all_energy_on_one_site_is_one_participating_site_with_no_spread() {
    let mut p = vec![0.0; 12];
    p[4] = 0.5;
    let cfg = config(&kg(12, 4.0), &[0.0; 12], &p, 0.05, 20.0);
    let options = AnalysisOptions {
        at: vec![0.0, 20.0],
        ..Default::default()
    };
    let a = analyze_config(&cfg, &options, |_| {}).unwrap();
    let start = a.report_at(0.0).unwrap().schemes[0].clone();
    assert_eq!(over_sets(&start, "energy_m2"), 0.0);
    assert_eq!(over_sets(&start, "energy_participation"), 1.0);
    let end = a.report_at(20.0).unwrap().schemes[0].clone();
    assert!(over_sets(&end, "energy_participation") > 1.0);
    assert!(over_sets(&end, "energy_m2") > 0.0);
}

/// What is no energy distribution is unavailable with the reason, never a wrong one: a
/// double-well on-site potential (`-q^2/2 + q^4/4`, negative for `0 < |q| < sqrt 2`) whose
/// displaced sites have negative energy; a potential with a part outside its sums that reads
/// two sites (whose share is whose is not written); a model that is no lattice (Henon-Heiles).
/// The DVD needs no energies and stays available.
#[test]
fn negative_or_unattributable_site_energies_are_unavailable_with_the_reason() {
    let mut q = vec![0.0; 8];
    (q[2], q[3]) = (0.5, -0.6);
    let double_well = "name = \"potential\"\nn = 8\nboundary = \"free\"\n\
        potential = \"sum(i = 1..N, -q[i]^2/2 + q[i]^4/4) + sum(i = 1..N, (q[i+1] - q[i])^2/8)\"";
    let (_, report) = run(&config(double_well, &q, &[0.0; 8], 0.05, 5.0));
    let why = unavailable(&report, "energy_participation");
    assert!(why.contains("negative energy"), "{why}");
    assert!(over_sets(&report, "dvd_participation") >= 1.0);

    let rest = "name = \"potential\"\nn = 8\nboundary = \"free\"\n\
        potential = \"sum(i = 1..N, q[i]^2/2 + (q[i+1] - q[i])^2/2) + q[1]*q[2]/10\"";
    let mut p = vec![0.0; 8];
    p[3] = 0.5;
    let (_, report) = run(&config(rest, &[0.0; 8], &p, 0.05, 5.0));
    let why = unavailable(&report, "energy_m2");
    assert!(why.contains("several sites (q1, q2)"), "{why}");

    let hh = chaoscope_schemas::config::paper::henon_heiles(
        chaoscope_schemas::config::paper::HH_CHAOTIC_Q2,
        5.0,
        chaoscope_schemas::config::DeviationsConfig::random(2, 1, 1),
        vec![chaoscope_schemas::config::SchemeConfig::new(
            "vm", "vm", 1e-8, 1.0,
        )],
    );
    let (_, report) = run(&hh);
    let why = unavailable(&report, "energy_m2");
    assert!(why.contains("henon-heiles"), "{why}");
}

/// On a chaotic orbit the deviation vector sits where the energy is (Senyange, Many
/// Manda and Skokos 2018: the DVD of a disordered Klein-Gordon chain is localized inside the
/// wave packet, on its hottest sites). The physics: a deviation grows through the nonlinear
/// terms, which are large only where the displacements are, i.e. where the energy is; in the
/// cold tails the chain is a harmonic (disordered, Anderson-localized) lattice along which
/// deviations do not grow. So, on `examples/models/klein-gordon-chaotic.toml` (the figure of
/// the guide; 64 sites, energy on the 11 middle ones, chaotic with MLE ~ 0.01), at every
/// renormalization after the DVD's transient (t >= 500, five Lyapunov times):
/// - the sites holding half of the energy (the hot spots: two or three of the 64, 4 % of the
///   sites) carry on average at least 30 % of the DVD's weight and five times their share of
///   the sites (measured: 45 %, eleven times), and
/// - the DVD's mean site lies within two standard deviations `2 sqrt(m2)` of the energy
///   distribution's mean site at nearly every time (90 %: the DVD jumps between hot spots).
///
/// A DVD spread evenly would give the hot sites only their share of the sites, and one
/// localized in the tails would fail both.
#[test]
fn the_dvd_of_a_chaotic_klein_gordon_chain_sits_on_the_energy_hot_spots() {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../examples/models/klein-gordon-chaotic.toml");
    let text = std::fs::read_to_string(&path).unwrap();
    let cfg = RunConfig::from_toml(&text).unwrap();
    let (samples, report) = run(&cfg);
    assert!(
        report.mle > 5e-3,
        "the orbit is chaotic: MLE {}",
        report.mle
    );
    let late: Vec<&Sample> = samples.iter().filter(|s| s.t >= 500.0).collect();
    let states: Vec<Vec<f64>> = late.iter().map(|s| s.state.clone()).collect();
    let energies = energies_of(&cfg, &states);
    let n = energies[0].len();
    let (mut hot_share, mut dvd_on_hot, mut near) = (0.0, 0.0, 0usize);
    for (s, e) in late.iter().zip(&energies) {
        let xi_e = normalized(e.iter().copied()).unwrap();
        let xi_d = normalized(site_weights(&s.schemes[0].separations[..2 * n], n)).unwrap();
        let mut order: Vec<usize> = (0..n).collect();
        order.sort_by(|&a, &b| xi_e[b].total_cmp(&xi_e[a]));
        let (mut held, mut hot) = (0.0, Vec::new());
        for &l in &order {
            if held >= 0.5 {
                break;
            }
            held += xi_e[l];
            hot.push(l);
        }
        hot_share += hot.len() as f64 / n as f64;
        dvd_on_hot += hot.iter().map(|&l| xi_d[l]).sum::<f64>();
        let (m2_e, _) = moments(e.iter().copied()).unwrap();
        let mean_e = mean_site(e.iter().copied()).unwrap();
        let mean_d = mean_site(xi_d.iter().copied()).unwrap();
        if (mean_d - mean_e).abs() <= 2.0 * m2_e.sqrt() {
            near += 1;
        }
    }
    let times = late.len() as f64;
    let (hot_share, dvd_on_hot) = (hot_share / times, dvd_on_hot / times);
    let near = near as f64 / times;
    assert!(
        dvd_on_hot >= 0.3 && dvd_on_hot >= 5.0 * hot_share,
        "hot sites: {hot_share} of the sites, {dvd_on_hot} of the DVD"
    );
    assert!(
        near >= 0.9,
        "DVD mean near the energy's at {near} of the times"
    );
}

/// A 6 x 6 DDNLS square lattice (W = 10, beta = 1) from a 2 x 2 block of norm 1 per site
/// (rows and columns 3..4), the distributions' second moments taken over its plane.
fn ddnls_square(lattice_side: usize, t_final: f64) -> RunConfig {
    let text = format!(
        "[run]\nname = \"square\"\n[model]\nname = \"ddnls\"\nlattice = \"square\"\n\
         n = {lattice_side}\nW = 10.0\nbeta = 1.0\nseed = 3\n\
         [orbit]\nexcite = {{ sites = [3, 4], norm = 4.0, seed = 2 }}\n\
         [integrator]\nmethod = \"s11abc6\"\nh = 0.05\nt_final = {t_final:?}\n\
         [deviations]\nk = 1\nsets = 1\nseed = 5\n\
         [[scheme]]\nname = \"vm\"\nmethod = \"vm\"\nd0 = 1e-8\ntau = 1.0\n"
    );
    RunConfig::from_toml(&text).unwrap_or_else(|e| panic!("{e}\n{text}"))
}

/// `(m2, P)` of the weights `w` of a `side x side` lattice over its plane, written out here
/// from the definition: `m2 = sum_l z_l ((i_l - ibar)^2 + (j_l - jbar)^2)`, `P = 1 / sum z_l^2`.
fn plane_moments(w: &[f64], side: usize) -> (f64, f64) {
    let total: f64 = w.iter().sum();
    let z: Vec<f64> = w.iter().map(|x| x / total).collect();
    let at = |l: usize| ((l / side) as f64, (l % side) as f64);
    let ibar: f64 = z.iter().enumerate().map(|(l, z)| at(l).0 * z).sum();
    let jbar: f64 = z.iter().enumerate().map(|(l, z)| at(l).1 * z).sum();
    let m2 = z
        .iter()
        .enumerate()
        .map(|(l, z)| {
            let (i, j) = at(l);
            z * ((i - ibar).powi(2) + (j - jbar).powi(2))
        })
        .sum();
    (m2, 1.0 / z.iter().map(|z| z * z).sum::<f64>())
}

/// On a square lattice the second moments are over the plane, not over the
/// flattened site index. At t = 0 the norm sits evenly on a 2 x 2 block: each site sqrt(1/2)
/// from the block's centre, so `norm_m2 = 1/2` and `norm_participation = 4` (to the rounding of
/// `cos^2 + sin^2` of the random phases). At the end, `dvd_m2`, `norm_m2` and
/// `norm_participation` are the plane's moments of the last sample's distributions written out
/// from the definition (1e-12 relative: the same sums in another order), and the flattened
/// index's `m2` is far larger (a step down a column is 6 sites there: ~18 times the plane's
/// for an even spread, more than twice for any packet spread over more than one row). The DDNLS
/// gives no site energies (its on-site terms take either sign): `energy_m2` says why.
#[test]
fn a_square_lattice_s_distributions_are_over_its_plane() {
    let side = 6;
    let cfg = ddnls_square(side, 20.0);
    let options = AnalysisOptions {
        at: vec![0.0],
        ..Default::default()
    };
    let start = analyze_config(&cfg, &options, |_| {}).unwrap();
    let start = start.report_at(0.0).unwrap().schemes[0].clone();
    assert!((over_sets(&start, "norm_m2") - 0.5).abs() < 1e-14);
    assert!((over_sets(&start, "norm_participation") - 4.0).abs() < 1e-13);

    let (samples, report) = run(&cfg);
    let last = samples.last().unwrap();
    let n = side * side;
    let norm: Vec<f64> = (0..n)
        .map(|l| last.state[l].powi(2) + last.state[n + l].powi(2))
        .collect();
    let dvd: Vec<f64> = site_weights(&last.schemes[0].separations[..2 * n], n).collect();
    for (name, weights, participation) in [
        ("dvd", &dvd, "dvd_participation"),
        ("norm", &norm, "norm_participation"),
    ] {
        let (m2, p) = plane_moments(weights, side);
        let got = over_sets(&report, &format!("{name}_m2"));
        assert!((got - m2).abs() <= 1e-12 * m2, "{name}_m2 {got} vs {m2}");
        let got_p = over_sets(&report, participation);
        assert!(
            (got_p - p).abs() <= 1e-12 * p,
            "{participation} {got_p} vs {p}"
        );
        let (flat, _) = moments(weights.iter().copied()).unwrap();
        assert!(flat > 2.0 * m2, "{name}: flattened {flat}, plane {m2}");
    }
    let why = unavailable(&report, "energy_m2");
    assert!(why.contains("'ddnls' is not one"), "{why}");
}

/// The run header carries the lattice side to every reader: the producer's header says 6 for
/// a 6 x 6 square and 0 for a chain; a recording made before the field existed (0, with the
/// configuration that says `lattice = "square"`) is read as the same square; a side whose
/// square is not the state's number of sites is refused, naming both.
#[test]
fn the_header_carries_the_lattice_side_and_old_recordings_keep_theirs() {
    use chaoscope_analyzer::run_info::RunInfo;
    let cfg = ddnls_square(6, 1.0);
    let spec = RunSpec::from_config(&cfg).unwrap();
    let info = chaoscope_app::inprocess::run_info("square", &cfg, &spec);
    assert_eq!(info.header.lattice_side, 6);
    assert_eq!(info.square_side, Some(6));
    assert_eq!(info.layout().square_side, Some(6));
    assert!(info.layout().norm_conserved);

    let mut old = info.header.clone();
    old.lattice_side = 0;
    assert_eq!(
        RunInfo::from_header(old.clone()).unwrap().square_side,
        Some(6)
    );
    // Without a configuration to say so, an old header is a chain's.
    old.config_toml.clear();
    assert_eq!(RunInfo::from_header(old).unwrap().square_side, None);

    let mut hostile = info.header.clone();
    hostile.lattice_side = 5;
    let why = RunInfo::from_header(hostile).unwrap_err().to_string();
    assert!(
        why.contains("lattice_side 5") && why.contains("25 sites") && why.contains("has 36"),
        "{why}"
    );

    let chain = RunConfig::from_toml(
        &std::fs::read_to_string(
            std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
                .join("../examples/models/ddnls-block.toml"),
        )
        .unwrap(),
    )
    .unwrap();
    let spec = RunSpec::from_config(&chain).unwrap();
    let info = chaoscope_app::inprocess::run_info("chain", &chain, &spec);
    assert_eq!((info.header.lattice_side, info.square_side), (0, None));
}

/// On a ring the energy distribution's second moment is measured around it, through the whole
/// analysis (the periodic boundary read from the run's configuration): an ordered
/// Klein-Gordon ring excited at site 1, astride the seam, has the second moment of the same
/// ring excited at site 20 (the same dynamics shifted, to the rounding of the sums' order), a
/// few sites squared, where the distance along the index made it hundreds.
#[test]
fn a_ring_s_second_moment_does_not_see_the_seam() {
    let n = 40;
    let ring = format!(
        "name = \"potential\"\nn = {n}\nboundary = \"periodic\"\nparams = {{ W = 4.0 }}\n\
         potential = \"sum(i = 1..N, q[i]^2/2 + q[i]^4/4 + (q[i+1] - q[i])^2/(2*W))\""
    );
    let m2_at = |site: usize| {
        let mut q = vec![0.0; n];
        q[site - 1] = 1.2;
        let (_, report) = run(&config(&ring, &q, &vec![0.0; n], 0.05, 20.0));
        over_sets(&report, "energy_m2")
    };
    let (seam, middle) = (m2_at(1), m2_at(20));
    assert!(middle > 0.1 && middle < 20.0, "{middle}");
    assert!((seam - middle).abs() < 1e-9 * middle, "{seam} vs {middle}");
}
