//! FLI, OFLI, MEGNO and the 0-1 test on the paper's orbits and a harmonic oscillator, by VM and
//! MPM, through the analysis of runs computed in process (the path of `analyze` and replay).

use chaoscope_analyzer::analysis::AnalysisOptions;
use chaoscope_analyzer::report::{Report, SchemeReport};
use chaoscope_app::inprocess::analyze_config;
use chaoscope_dynamics::indicators::Named;
use chaoscope_schemas::config::{DeviationsConfig, RunConfig, SchemeConfig, paper};

fn schemes() -> Vec<SchemeConfig> {
    // d0 = 1e-8, tau = 1: inside the region where the paper finds MPM's GALIs on VM's.
    vec![
        SchemeConfig::new("vm", "vm", 1e-8, 1.0),
        SchemeConfig::new("mpm", "mpm", 1e-8, 1.0),
    ]
}

/// The `[[scheme]]` tables of [`schemes`] with renormalization time `tau`, for configs written
/// as TOML.
fn vm_and_mpm(tau: f64) -> String {
    schemes()
        .iter()
        .map(|s| {
            format!(
                "[[scheme]]\nname = \"{}\"\nmethod = \"{}\"\nd0 = {:e}\ntau = {tau:?}\n",
                s.name, s.method, s.d0
            )
        })
        .collect()
}

fn hh(q2: f64, t_final: f64) -> RunConfig {
    paper::henon_heiles(q2, t_final, DeviationsConfig::random(2, 2, 1), schemes())
}

fn over_sets(s: &SchemeReport, name: &str) -> f64 {
    match s.indicators.get(name) {
        Some(Named::OverSets(stat)) => stat.mean,
        other => panic!("{}: {name} is {other:?}", s.name),
    }
}

fn value(s: &SchemeReport, name: &str) -> f64 {
    match s.indicators.get(name) {
        Some(Named::Value(v)) => *v,
        other => panic!("{}: {name} is {other:?}", s.name),
    }
}

/// Reports at `times` (the last one the run's end).
fn reports(cfg: &RunConfig, times: &[f64]) -> Vec<Report> {
    let options = AnalysisOptions {
        at: times.to_vec(),
        ..Default::default()
    };
    let a = analyze_config(cfg, &options, |_| {}).unwrap();
    times.iter().map(|&t| a.report_at(t).unwrap()).collect()
}

#[test]
fn regular_henon_heiles_megno_two_fli_logarithmic_zero_one_small() {
    let r = reports(
        &hh(paper::HH_REGULAR_Q2, 10_000.0),
        &[100.0, 1_000.0, 10_000.0],
    );
    let (early, late) = (&r[0], &r[2]);
    for name in ["vm", "mpm"] {
        let s = late.scheme(name).unwrap();
        // On a torus tangent vectors grow linearly, |w| ~ 1 + t / t0, so Y -> 2 while its
        // running mean carries the start (Y ~ 0 before t0) and approaches 2 only like
        // 2 t0 ln(t / t0) / t (Cincotta and Simo 2000). So: within 0.15 of 2 at t = 1e4, and
        // the distance to 2 shrinking from t = 1e3 to 1e4 by at least 3 (7.5 for that law; a
        // chaotic orbit's would grow instead).
        let mean = over_sets(s, "megno_mean");
        let mean_1000 = over_sets(r[1].scheme(name).unwrap(), "megno_mean");
        assert!(
            (mean - 2.0).abs() < 0.15 && (mean_1000 - 2.0).abs() > 3.0 * (mean - 2.0).abs(),
            "{name}: megno_mean {mean_1000} at 1e3, {mean} at 1e4"
        );
        // FLI from t = 100 to 1e4: ln(100) = 4.6 more for linear growth (the oscillating part
        // of c is of order one: a sup over the run can take up to it, hence the tolerance 1).
        let growth = over_sets(s, "fli") - over_sets(early.scheme(name).unwrap(), "fli");
        assert!(
            (growth - 100f64.ln()).abs() < 1.0,
            "{name}: FLI grew {growth}"
        );
        // OFLI stays below FLI (a component is never longer than its vector).
        assert!(over_sets(s, "ofli") <= over_sets(s, "fli") + 1e-12);
        // The 0-1 test on q1, 1e4 renormalizations thinned to 1250 samples 8 apart.
        let k = value(s, "zero_one_k");
        assert!(k.abs() < 0.1, "{name}: K = {k}");
    }
    // MPM against VM (d0 = 1e-8, tau = 1): the same tangent dynamics up to relative errors
    // ~ eps |x| / d0 = 1e-8 per step, as for the GALIs the paper compares.
    let (vm, mpm) = (late.scheme("vm").unwrap(), late.scheme("mpm").unwrap());
    for name in ["megno_mean", "fli", "ofli"] {
        let (a, b) = (over_sets(vm, name), over_sets(mpm, name));
        assert!(
            (a - b).abs() < 1e-3 * a.abs().max(1.0),
            "{name}: vm {a}, mpm {b}"
        );
    }
}

#[test]
fn chaotic_henon_heiles_megno_grows_like_half_the_mle_fli_linear_zero_one_near_one() {
    let times: Vec<f64> = (1..=10).map(|i| 1000.0 * f64::from(i)).collect();
    let r = reports(&hh(paper::HH_CHAOTIC_Q2, 10_000.0), &times);
    let last = r.last().unwrap();
    for name in ["vm", "mpm"] {
        let s = last.scheme(name).unwrap();
        let mle = s.mle;
        // megno_mean -> lambda_1 t / 2: least-squares slope over t = 2000..10000 (past the
        // transient where the vector aligns with the unstable direction), against lambda_1 / 2
        // of the same run. The fluctuations of the finite-time exponent on this orbit (a few
        // percent at t ~ 1e4, its sticky episodes) bound the agreement: 10 %.
        let points: Vec<(f64, f64)> = r[1..]
            .iter()
            .map(|rep| {
                (
                    rep.run.t,
                    over_sets(rep.scheme(name).unwrap(), "megno_mean"),
                )
            })
            .collect();
        let n = points.len() as f64;
        let (mt, my) = points
            .iter()
            .fold((0.0, 0.0), |(a, b), (t, y)| (a + t / n, b + y / n));
        let slope = points.iter().map(|(t, y)| (t - mt) * (y - my)).sum::<f64>()
            / points.iter().map(|(t, _)| (t - mt) * (t - mt)).sum::<f64>();
        assert!(
            (slope / (mle / 2.0) - 1.0).abs() < 0.1,
            "{name}: slope {slope}, lambda_1 / 2 = {}",
            mle / 2.0
        );
        // FLI ~ lambda_1 t: it is the sup of the accumulated log-norm, whose value at the end
        // is lambda_1 t; the sup can only exceed it by a fluctuation of that sum (10 %).
        let fli = over_sets(s, "fli");
        assert!(
            fli >= mle * 10_000.0 * (1.0 - 1e-12) && fli < 1.1 * mle * 10_000.0,
            "{name}: FLI {fli}, lambda_1 t {}",
            mle * 10_000.0
        );
        let k = value(s, "zero_one_k");
        assert!(k > 0.9, "{name}: K = {k}");
    }
    let (vm, mpm) = (last.scheme("vm").unwrap(), last.scheme("mpm").unwrap());
    let (a, b) = (over_sets(vm, "megno_mean"), over_sets(mpm, "megno_mean"));
    assert!((a / b - 1.0).abs() < 0.01, "vm {a}, mpm {b}");
}

#[test]
fn regular_fput_megno_two() {
    let cfg = paper::fput_beta(
        &paper::FPUT_N5_REGULAR_Q,
        &paper::FPUT_N5_REGULAR_P,
        0.05,
        5_000.0,
        DeviationsConfig::random(2, 2, 1),
        schemes(),
    );
    let r = reports(&cfg, &[5_000.0]);
    for name in ["vm", "mpm"] {
        let mean = over_sets(r[0].scheme(name).unwrap(), "megno_mean");
        // As for Henon-Heiles: linear growth on a torus, a few percent at t = 5000.
        assert!((mean - 2.0).abs() < 0.15, "{name}: megno_mean {mean}");
    }
}

#[test]
fn harmonic_oscillator_megno_zero() {
    // V = 2 q^2 (omega = 2): every orbit is periodic with the same period (isochronous), the
    // tangent map is the flow itself, so |w| stays bounded (oscillating by a factor omega):
    // Y oscillates about 0 and its mean decays like ln t / t.
    let cfg = RunConfig::from_toml(&format!(
        r#"
[model]
name = "potential"
n = 1
potential = "2*q1^2"
[orbit]
q = [1.0]
p = [0.0]
[integrator]
method = "aba864"
h = 0.01
t_final = 1000.0
[deviations]
k = 1
sets = 2
seed = 1
{}"#,
        vm_and_mpm(0.1)
    ))
    .unwrap();
    let r = reports(&cfg, &[1000.0]);
    for name in ["vm", "mpm"] {
        let s = r[0].scheme(name).unwrap();
        let mean = over_sets(s, "megno_mean");
        assert!(mean.abs() < 0.02, "{name}: megno_mean {mean}");
        // FLI stays at the bound of the oscillation: ln(omega) = 0.69 at most.
        let fli = over_sets(s, "fli");
        assert!(fli < 2f64.ln() + 1e-6, "{name}: FLI {fli}");
    }
}

/// A two-dimensional discrete map (`x1`, `x2`) from the origin, `t_final` iterations with one
/// renormalization each (so the 0-1 test is offered every iterate), by VM and MPM.
fn discrete_map(next: &str, params: &str, modulo: &str, x: [f64; 2], t_final: f64) -> RunConfig {
    RunConfig::from_toml(&format!(
        r#"
[model]
name = "map"
next = {next}
params = {params}
{modulo}
[orbit]
x = [{}, {}]
[integrator]
h = 1
t_final = {t_final}
[deviations]
k = 1
sets = 1
seed = 1
{}"#,
        x[0],
        x[1],
        vm_and_mpm(1.0)
    ))
    .unwrap()
}

#[test]
fn zero_one_test_on_the_henon_and_standard_maps() {
    // The observable is x1 at every iterate: 2000 iterates and the initial state are 2001
    // samples, below the 2048 at which the series is thinned, n_cut = 200 lags. (Thinned by 2,
    // a period-2 orbit would be seen as a constant after the transient, still regular but
    // closer to the bound: K = 0.08 at 4000 iterates.) For a chaotic orbit the translation
    // variables diffuse: D_c grows linearly up to fluctuations of relative size
    // sqrt(n_cut / N) ~ 0.3, which the correlation with n forgives (K > 0.9, as for the
    // logistic map in the unit test). For a periodic or quasi-periodic orbit D_c is bounded and
    // its correlation with n is O(1) only at resonant c, which the median over c discards
    // (K < 0.1).
    let henon = |a: f64| {
        discrete_map(
            r#"["1 - a*x1^2 + x2", "b*x1"]"#,
            &format!("{{ a = {a:?}, b = 0.3 }}"),
            "",
            [0.0, 0.0],
            2000.0,
        )
    };
    // The classic chaotic attractor (a = 1.4, b = 0.3).
    let chaotic = reports(&henon(1.4), &[2000.0]);
    // a = 0.5: the fixed point is a saddle (eigenvalues 0.26 and -1.14) and the attracting
    // orbit has period 2; the transient from the origin is a few tens of iterates.
    let periodic = reports(&henon(0.5), &[2000.0]);
    // The standard map (K = 0.5) in the island of its elliptic point (pi, 0): (pi, 1) librates
    // on an invariant circle (the separatrix half-width is 2 sqrt(K) = 1.41 > 1), quasi-periodic.
    let island = reports(
        &discrete_map(
            r#"["x1 + x2 + K*sin(x1)", "x2 + K*sin(x1)"]"#,
            "{ K = 0.5 }",
            "modulo = [6.283185307179586, 6.283185307179586]",
            [std::f64::consts::PI, 1.0],
            2000.0,
        ),
        &[2000.0],
    );
    for name in ["vm", "mpm"] {
        let k = value(chaotic[0].scheme(name).unwrap(), "zero_one_k");
        assert!(k > 0.9, "Henon a = 1.4, {name}: K = {k}");
        let k = value(periodic[0].scheme(name).unwrap(), "zero_one_k");
        assert!(k.abs() < 0.1, "Henon a = 0.5, {name}: K = {k}");
        let k = value(island[0].scheme(name).unwrap(), "zero_one_k");
        assert!(k.abs() < 0.1, "standard map island, {name}: K = {k}");
    }
}

/// The table of `chaoscope analyze` shows every indicator of the interface by name, for every
/// scheme, a value or `n/a` (here the 0-1 test of a run with fewer than 100 renormalizations),
/// and never NaN.
#[test]
fn the_table_shows_every_named_indicator() {
    let r = reports(&hh(paper::HH_CHAOTIC_Q2, 50.0), &[50.0]);
    let table = chaoscope_analyzer::table::table(&r[0]);
    eprintln!("{table}");
    for scheme in ["vm", "mpm"] {
        let line = table
            .lines()
            .find(|l| l.starts_with(&format!("{scheme}: fli ")))
            .unwrap_or_else(|| panic!("no indicator line for {scheme}:\n{table}"));
        for (name, _) in &r[0].scheme(scheme).unwrap().indicators.0 {
            assert!(line.contains(&format!("{name} ")), "{name} missing: {line}");
        }
        assert!(line.contains("zero_one_k n/a"), "{line}");
        // Too short a series for the 0-1 test: a line says so and how long it would need to
        // be (51 renormalizations every 1 from t = 0: 1000 of them reach t = 999).
        let notice = format!(
            "{scheme}: zero_one_k n/a: the series is too short for the 0-1 test: 51 samples of \
             the orbit (renormalizations); it needs at least 1000, to t = 999 "
        );
        assert!(table.contains(&notice), "{notice:?} is not in\n{table}");
    }
    let not_finite = table
        .split(|c: char| c.is_whitespace() || c == ',')
        .any(|w| matches!(w, "NaN" | "inf" | "-inf"));
    assert!(!not_finite, "{table}");
}

/// The CSV and the plots of `analyze` carry every set indicator of the interface over time,
/// under its report name, from the same series the report reads: on the paper's chaotic orbit
/// FLI is the accumulated log stretch of the first vector, so at the last row FLI / t is the
/// finite-time MLE there (within 10 %: the FLI is the largest value so far, the MLE the latest
/// one, which differ by the oscillation of the stretch, a few percent at t = 500); MEGNO's mean
/// is above 2 (a chaotic orbit's grows like lambda_1 t / 2). Every name has its chart.
#[test]
fn the_csv_and_the_plots_carry_every_named_indicator_over_time() {
    let cfg = hh(paper::HH_CHAOTIC_Q2, 500.0);
    let options = AnalysisOptions {
        at: vec![500.0],
        ..Default::default()
    };
    let a = analyze_config(&cfg, &options, |_| {}).unwrap();
    let report = a.report_at(500.0).unwrap();
    let dir = tempfile::tempdir().unwrap();
    chaoscope_analyzer::csv::write_csv(&a, dir.path(), &[]).unwrap();
    let names = chaoscope_dynamics::indicators::indicator::set_output_names();
    for name in ["vm", "mpm"] {
        let text = std::fs::read_to_string(dir.path().join(format!("{name}.csv"))).unwrap();
        assert!(
            !text.contains("NaN") && !text.contains("inf"),
            "{name}.csv has a non-finite value"
        );
        let mut lines = text.lines();
        let head: Vec<&str> = lines.next().unwrap().split(',').collect();
        let column = |n: &str| {
            head.iter()
                .position(|h| *h == n)
                .unwrap_or_else(|| panic!("{name}.csv: no column {n} in {head:?}"))
        };
        for n in names {
            column(n);
        }
        let rows: Vec<Vec<&str>> = lines.map(|l| l.split(',').collect()).collect();
        assert!(rows.len() > 100, "{name}.csv: {} rows", rows.len());
        let last = rows.last().unwrap();
        let at = |n: &str| last[column(n)].parse::<f64>().unwrap();
        let (t, fli, megno_mean) = (at("t"), at("fli"), at("megno_mean"));
        let mle = report.scheme(name).unwrap().mle;
        assert!(
            (fli / t - mle).abs() < 0.1 * mle,
            "{name}: FLI {fli} at t = {t}, MLE {mle}"
        );
        assert!(
            megno_mean > 2.5,
            "{name}: megno_mean {megno_mean} at t = {t}"
        );
        // OFLI is in the CSV too (the in-process run gives the vector field): FLI plus the log
        // of the deviation's part across the flow, ln(|w_perp| / |w|) <= 0, which on a chaotic
        // orbit is O(1) while FLI is ~ 50 here.
        let ofli = at("ofli");
        assert!(
            ofli <= fli + 1e-9 && ofli > 0.8 * fli,
            "{name}: OFLI {ofli}, FLI {fli}"
        );
        // The DVD over HH's two sites (q1, p1) and (q2, p2): a participation number between
        // one site and both, a second moment between none and two sites' half-and-half
        // (1/4), and on a chaotic orbit both sites carry deviation (neither limit is held).
        let (m2, p) = (at("dvd_m2"), at("dvd_participation"));
        assert!(
            (1.0..=2.0).contains(&p) && (0.0..=0.25).contains(&m2),
            "{name}: DVD m2 {m2}, P {p}"
        );
        assert!(p > 1.0 && m2 > 0.0, "{name}: DVD m2 {m2}, P {p}");
    }
    let charts =
        chaoscope_analyzer::plot::charts(&a, &report, chaoscope_analyzer::plot::TimeAxis::Auto);
    // Henon-Heiles is no lattice: its energy distribution is unavailable (with the reason,
    // `lattice_distributions.rs`), so it has no curve to draw, nor has its norm distribution (it
    // conserves no norm); and a distribution over two degrees of freedom is no picture of a
    // lattice, so its DVD moments (computed above) are not charted either.
    assert!(
        !charts
            .iter()
            .any(|(stem, _)| ["energy_m", "energy_p", "dvd_", "norm_"]
                .iter()
                .any(|p| stem.starts_with(p))),
        "a distribution chart for Henon-Heiles"
    );
    for n in names
        .iter()
        .filter(|n| !n.starts_with("energy_") && !n.starts_with("dvd_") && !n.starts_with("norm_"))
    {
        let (_, chart) = charts
            .iter()
            .find(|(stem, _)| stem == n)
            .unwrap_or_else(|| panic!("no chart {n}"));
        assert_eq!(chart.lines.len(), 2, "{n}: one line per scheme");
        assert!(chart.lines.iter().all(|l| l.points.len() > 100), "{n}");
    }
}

/// A Sun and two planets with the potential written `-G m_i m_j / sqrt(r_ij^2)`
/// (examples/models/sun-two-planets.toml): the variational method accepts the square root (a
/// pole at each collision, the guide's smoothness rule), and the orbit, two circular planets
/// at a = 1 and 2.5 (period ratio 3.95, far from the 2:1 and 3:1 resonances, Hill-stable by a
/// wide margin), is quasi-periodic, so MEGNO's running mean tends to 2. REBOUND's variational
/// MEGNO on such a configuration is 2.0009 at t = 3000; its approach to 2 goes as 1/t with
/// oscillations of the synodic period, well inside 0.1 by t = 3000 (a chaotic orbit grows
/// without bound, lambda t / 2).
#[test]
fn sun_and_two_planets_written_with_sqrt_megno_two() {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../examples/models/sun-two-planets.toml");
    let text = std::fs::read_to_string(&path).unwrap();
    assert!(text.contains("m1/sqrt((q3 - q1)^2"), "the sqrt spelling");
    let cfg = RunConfig::from_toml(&text).unwrap();
    let r = reports(&cfg, &[3000.0]);
    let mean = over_sets(r[0].scheme("vm").unwrap(), "megno_mean");
    assert!((mean - 2.0).abs() < 0.1, "megno_mean {mean}");
}

/// The chaotic Klein-Gordon chain of `examples/models/` (64 sites, the 11 middle ones excited,
/// MLE ~ 0.01) run to `t_final`, one VM scheme (tau = 1), its momenta scaled by `scale` and
/// `[analysis]` lines `analysis` added.
fn klein_gordon(t_final: f64, scale: f64, analysis: &str) -> RunConfig {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../examples/models/klein-gordon-chaotic.toml");
    let text = std::fs::read_to_string(path).unwrap() + analysis;
    let mut cfg = RunConfig::from_toml(&text).unwrap();
    cfg.integrator.t_final = t_final;
    for p in &mut cfg.orbit.p {
        *p *= scale;
    }
    cfg
}

#[test]
fn zero_one_test_on_klein_gordon_chains_chaotic_and_regular() {
    // The length, t = 5000 at tau = 1: 5001 samples, every one kept (below 8192), n_cut = 500.
    // The chain's frequencies fill a band of about [0.7, 1.5] per unit time; sampled every
    // time unit that band covers less than half of the range of c, (pi/5, 4 pi/5), and the
    // median reads the rest, where a regular orbit has no line and a chaotic one a continuous
    // spectrum. The chaos is weak (MLE ~ 0.01): its D_c outgrows the lines' bounded
    // oscillations only after some hundred Lyapunov times, K = 0.86 at t = 2000, 0.92 at 3000,
    // 0.96 at 5000, 0.98 at 10^4 (the regular orbit: -0.002, -0.013, -0.02, 0.005). So t = 5000
    // is where both readings sit well beyond their bounds, a run of about a second.
    let chaotic = reports(&klein_gordon(5000.0, 1.0, ""), &[5000.0]);
    let k = value(chaotic[0].scheme("vm").unwrap(), "zero_one_k");
    assert!(k > 0.9, "chaotic Klein-Gordon chain: K = {k}");
    // The same chain with its momenta divided by 20 (energy 7.5e-4 per excited site, 400
    // times less): the quartic term is 1e-3 of the harmonic one, the chain nearly linear and
    // its disorder localizes it (Anderson modes): a regular, quasi-periodic orbit of 64
    // frequencies.
    let regular = reports(&klein_gordon(5000.0, 0.05, ""), &[5000.0]);
    let k = value(regular[0].scheme("vm").unwrap(), "zero_one_k");
    assert!(k.abs() < 0.1, "regular Klein-Gordon chain: K = {k}");
    // `[analysis] zero_one_observable` replaces the generic observable: the cold end site q1
    // of the chaotic chain, which the energy barely reaches, reads K = 0.02 where every site
    // together reads 0.96; a reading below 0.5 says it is that observable the test took.
    let end_site = reports(
        &klein_gordon(5000.0, 1.0, "[analysis]\nzero_one_observable = \"q1\"\n"),
        &[5000.0],
    );
    let k = value(end_site[0].scheme("vm").unwrap(), "zero_one_k");
    assert!(k < 0.5, "the end site q1: K = {k}");
}
