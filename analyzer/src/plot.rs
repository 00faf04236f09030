//! The analysis drawn with the paper's axes: GALI_k against t (log10 GALI; log10 t for regular
//! orbits, linear t for chaotic ones) with the expected laws as dashed reference lines, the MLE
//! against t on log-log axes, every registered set indicator's output against t (`fli.png`,
//! `megno_mean.png`, ...: a new indicator is drawn without a change here), the energy error,
//! MPM-VM distances, for sweeps GALI against d0 and tau, and for a lattice the energy and
//! deviation vector distributions over the sites against time (`distributions.png`,
//! [`crate::site_png`]).

use std::path::{Path, PathBuf};

use chaoscope_schemas::run::{Method, Orthonormalization};

use crate::analysis::Analysis;
use crate::chart::{Chart, ChartError, Line, Stroke, render};
use crate::report::Report;
use crate::series::SchemePoint;

/// Time axis of GALI plots.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TimeAxis {
    /// log10 t for regular orbits, t for chaotic ones (decided from the MLE).
    Auto,
    Log,
    Linear,
}

/// A chaotic orbit has stretched its deviations by far more than a power law could:
/// `lambda_1 t > 20` (e^20 ~ 5e8), while a regular orbit's finite-time MLE falls like ln t / t.
pub fn looks_chaotic(mle: f64, t: f64) -> bool {
    mle * t > 20.0
}

/// Rates of `GALI_j ~ exp(-rate_j t)` from a Lyapunov spectrum: `sum_{i=2..j} (l1 - l_i)`.
pub fn chaotic_rates(spectrum: &[f64], k: usize) -> Vec<f64> {
    (2..=k)
        .map(|j| {
            (1..j.min(spectrum.len()))
                .map(|i| spectrum[0] - spectrum[i])
                .sum()
        })
        .collect()
}

/// The Lyapunov spectrum used for reference slopes: a QR scheme's with all 2N exponents if the
/// run has one, else for two degrees of freedom the Hamiltonian form (l1, 0, 0, -l1).
fn reference_spectrum(report: &Report, n: usize, mle: f64) -> Option<Vec<f64>> {
    if let Some(qr) = report
        .schemes
        .iter()
        .find(|s| s.orthonormalize == "qr" && s.lyapunov.len() == 2 * n)
    {
        return Some(qr.lyapunov.clone());
    }
    (n == 2).then(|| vec![mle, 0.0, 0.0, -mle])
}

fn lg(x: f64) -> f64 {
    x.log10()
}

/// The system in words for a title: the run's name and the model's (`hh-regular,
/// Hénon-Heiles system`), never the config's bare key.
pub fn system_words(run: &crate::run_info::RunInfo) -> String {
    let model = match run.header.model.as_str() {
        "henon-heiles" => "Hénon-Heiles system".to_string(),
        "fput-beta" => "FPUT-β chain".to_string(),
        "potential" => "Hamiltonian with a potential".to_string(),
        "hamiltonian" => "Hamiltonian".to_string(),
        "ode" => "flow".to_string(),
        "map" => "map".to_string(),
        other => format!("model {other}"),
    };
    let name = &run.header.run_name;
    if name.is_empty() {
        model
    } else {
        format!("{name}, {model}")
    }
}

/// A scheme in words: `scheme vm (variational method, 4 sets)`.
fn scheme_words(scheme: &crate::report::SchemeReport) -> String {
    let method = match scheme.method.as_str() {
        "vm" => "variational method".to_string(),
        "mpm" => format!(
            "multi-particle method, d0 = {:e}, tau = {}",
            scheme.d0, scheme.tau
        ),
        other => other.to_string(),
    };
    let qr = if scheme.orthonormalize == "qr" {
        ", QR orthonormalization"
    } else {
        ""
    };
    let sets = if scheme.sets == 1 { "set" } else { "sets" };
    format!(
        "scheme {} ({method}{qr}, {} {sets})",
        scheme.name, scheme.sets
    )
}

/// A set indicator's output in the field's notation, for an axis: `FLI`, `MEGNO Y`,
/// `mean MEGNO <Y>`; an output this list does not know by its name with spaces.
pub fn indicator_label(name: &str) -> String {
    match name {
        "fli" => "FLI".into(),
        "ofli" => "OFLI".into(),
        "megno" => "MEGNO Y".into(),
        "megno_mean" => "mean MEGNO ⟨Y⟩".into(),
        "dvd_m2" => "second moment m_2 of the DVD".into(),
        "dvd_participation" => "participation number P of the DVD".into(),
        "energy_m2" => "second moment m_2 of the energy".into(),
        "energy_participation" => "participation number P of the energy".into(),
        other => other.replace('_', " "),
    }
}

/// An output of a distribution over a lattice's sites (the deviation vector distribution's and
/// the energy distribution's moments): drawn only for at least
/// [`crate::site_png::MIN_SITES`] sites.
fn lattice_output(name: &str) -> bool {
    chaoscope_indicators::indicator::declared_outputs()
        .iter()
        .any(|d| d.name == name && d.needs.sites)
}

/// GALI and SALI say something about the orbit only for a scheme whose vectors evolve freely
/// between rescalings: a QR scheme re-orthonormalizes them (its GALI is 1 by construction), and
/// with k = 1 there is no pair of vectors.
pub fn alignment_meaningful(orthonormalize: Orthonormalization, k: usize) -> bool {
    orthonormalize != Orthonormalization::Qr && k >= 2
}

/// `t^-e` of a guide's label (`constant` for e = 0).
fn power_law(exponent: usize) -> String {
    match exponent {
        0 => "const".into(),
        1 => "t^-1".into(),
        e => format!("t^-{e}"),
    }
}

fn gali_chart(analysis: &Analysis, report: &Report, si: usize, axis: TimeAxis) -> Chart {
    let run = analysis.run();
    let scheme = &report.schemes[si];
    let series: Vec<(f64, SchemePoint)> = analysis
        .series(si)
        .into_iter()
        .filter(|(t, _)| *t > 0.0)
        .collect();
    let t_end = scheme.t;
    let chaotic = looks_chaotic(scheme.mle, t_end);
    let log_t = match axis {
        TimeAxis::Auto => !chaotic,
        TimeAxis::Log => true,
        TimeAxis::Linear => false,
    };
    let x = |t: f64| if log_t { lg(t) } else { t };
    let n = run.dim / 2;
    let mut lines = Vec::new();
    for j in 2..=run.k {
        let pts: Vec<(f64, f64)> = series
            .iter()
            .filter_map(|(t, p)| Some((x(*t), *p.gali_log10_mean.get(j - 2)?)))
            .collect();
        lines.push(Line {
            label: format!("GALI_{j}"),
            points: pts,
            stroke: Stroke::Solid,
            color: j - 1,
        });
    }
    // Reference laws, anchored on each curve.
    let anchor = |j: usize, t_a: f64| -> Option<f64> {
        series
            .iter()
            .find(|(t, _)| *t >= t_a)
            .and_then(|(_, p)| p.gali_log10_mean.get(j - 2).copied())
    };
    if chaotic {
        if let Some(spec) = reference_spectrum(report, n, scheme.mle) {
            let rates = chaotic_rates(&spec, run.k);
            let t_a = (0.05 * t_end).max(run.h);
            for j in 2..=run.k {
                let (Some(g_a), Some(&rate)) = (anchor(j, t_a), rates.get(j - 2)) else {
                    continue;
                };
                // Down to the double-precision floor only.
                let t_b = (t_a + (g_a + 16.0 * (j - 1) as f64) * std::f64::consts::LN_10 / rate)
                    .min(t_end);
                if !(rate > 0.0 && t_b > t_a) {
                    continue;
                }
                let g = |t: f64| g_a - rate * (t - t_a) / std::f64::consts::LN_10;
                lines.push(Line {
                    label: if j == 2 {
                        "exp(-Σ(λ_1-λ_i) t)".into()
                    } else {
                        String::new()
                    },
                    points: vec![(x(t_a), g(t_a)), (x(t_b), g(t_b))],
                    stroke: Stroke::Dashed,
                    color: j - 1,
                });
            }
        }
    } else if let Some(torus) = scheme.verdict.torus_dimension {
        // Regular orbit on an s-torus (the verdict's s): GALI_j constant for j <= s, then
        // ~ t^-(j-s) up to j = 2N - s, ~ t^-2(j-N) beyond (the paper's power laws).
        let t_a = 10f64.powf(0.5 * (lg(t_end) + lg(series.first().map_or(1.0, |p| p.0.max(1.0)))));
        for j in 2..=run.k {
            let Some(g_a) = anchor(j, t_a) else { continue };
            let exponent = crate::verdict::torus_exponent(j, torus, n);
            let g = |t: f64| g_a - exponent as f64 * (lg(t) - lg(t_a));
            lines.push(Line {
                label: format!("GALI_{j} ~ {}", power_law(exponent)),
                points: vec![(x(t_a), g(t_a)), (x(t_end), g(t_end))],
                stroke: Stroke::Dashed,
                color: j - 1,
            });
        }
    }
    let torus = match scheme.verdict.torus_dimension {
        Some(s) if !chaotic => format!("; dashed: the laws of a {s}-torus"),
        _ => String::new(),
    };
    Chart {
        title: format!(
            "GALI_k against time: {}\n{}, geometric mean over sets{torus}",
            system_words(run),
            scheme_words(scheme)
        ),
        x_label: if log_t { "log10 t" } else { "t" }.into(),
        y_label: "log10 GALI_k".into(),
        lines,
        ..Default::default()
    }
}

fn mle_chart(analysis: &Analysis, report: &Report, schemes: &[usize]) -> Chart {
    let mut lines = Vec::new();
    for (c, &si) in schemes.iter().enumerate() {
        let pts = analysis
            .series(si)
            .into_iter()
            .filter(|(t, p)| *t > 0.0 && p.exponents().first().is_some_and(|l| *l > 0.0))
            .map(|(t, p)| (lg(t), lg(p.exponents()[0])))
            .collect();
        lines.push(Line {
            label: report.schemes[si].name.clone(),
            points: pts,
            stroke: Stroke::Solid,
            color: c,
        });
    }
    // A regular orbit's finite-time MLE decays like 1/t (slope -1).
    if let Some(l) = lines.first().and_then(|l| l.points.first().copied()) {
        let end = lines[0].points.last().unwrap().0;
        lines.push(Line {
            label: "λ_1 ~ t^-1".into(),
            points: vec![l, (end, l.1 - (end - l.0))],
            stroke: Stroke::Dashed,
            color: 7,
        });
    }
    Chart {
        title: format!(
            "Maximal Lyapunov exponent λ_1 against time: {}\nmean over sets; dashed: the t^-1 \
             decay of a regular orbit",
            system_words(analysis.run())
        ),
        x_label: "log10 t".into(),
        y_label: "log10 λ_1".into(),
        lines,
        ..Default::default()
    }
}

fn spectrum_chart(analysis: &Analysis, report: &Report, si: usize) -> Chart {
    let series = analysis.series(si);
    let k = analysis.run().k;
    let lines = (0..k)
        .map(|i| Line {
            label: format!("λ_{}", i + 1),
            points: series
                .iter()
                .filter(|(t, _)| *t > 0.0)
                .filter_map(|(t, p)| Some((lg(*t), *p.exponents().get(i)?)))
                .collect(),
            stroke: Stroke::Solid,
            color: i,
        })
        .collect();
    Chart {
        title: format!(
            "Lyapunov spectrum against time: {}\n{}, mean over sets",
            system_words(analysis.run()),
            scheme_words(&report.schemes[si])
        ),
        x_label: "log10 t".into(),
        y_label: "λ_i".into(),
        lines,
        ..Default::default()
    }
}

/// One registered set indicator's output (FLI, MEGNO, ...: `set_output_names()[i]`) against t,
/// one line per scheme of `schemes`, the mean over the sets; `None` where no scheme has a value
/// (OFLI of a recording analyzed without the system's vector field). Time as the GALI plots
/// take it: log10 t unless the orbit looks chaotic (FLI grows like ln t on regular orbits and
/// like lambda_1 t on chaotic ones; MEGNO's mean tends to 2 or grows like lambda_1 t / 2).
fn named_chart(
    analysis: &Analysis,
    report: &Report,
    schemes: &[usize],
    i: usize,
    name: &str,
    axis: TimeAxis,
) -> Option<Chart> {
    let first = &report.schemes[*schemes.first()?];
    let log_t = match axis {
        TimeAxis::Auto => !looks_chaotic(first.mle, first.t),
        TimeAxis::Log => true,
        TimeAxis::Linear => false,
    };
    let x = |t: f64| if log_t { lg(t) } else { t };
    let lines: Vec<Line> = schemes
        .iter()
        .enumerate()
        .map(|(c, &si)| Line {
            label: report.schemes[si].name.clone(),
            points: analysis
                .series(si)
                .iter()
                .filter(|(t, _)| *t > 0.0)
                .filter_map(|(t, p)| {
                    let v = p.named.get(i).copied().flatten()?;
                    v.is_finite().then_some((x(*t), v))
                })
                .collect(),
            stroke: Stroke::Solid,
            color: c,
        })
        .filter(|l| !l.points.is_empty())
        .collect();
    (!lines.is_empty()).then(|| Chart {
        title: format!(
            "{} against time: {}\nmean over sets",
            indicator_label(name),
            system_words(analysis.run())
        ),
        x_label: if log_t { "log10 t" } else { "t" }.into(),
        y_label: indicator_label(name),
        lines,
        ..Default::default()
    })
}

fn energy_chart(analysis: &Analysis) -> Chart {
    let pts = analysis
        .energy_series()
        .into_iter()
        .filter(|(t, e)| *t > 0.0 && *e > 0.0)
        .map(|(t, e)| (lg(t), lg(e)))
        .collect();
    Chart {
        title: format!(
            "Relative energy error against time: {}",
            system_words(analysis.run())
        ),
        x_label: "log10 t".into(),
        y_label: "log10 E_r".into(),
        lines: vec![Line {
            label: String::new(),
            points: pts,
            stroke: Stroke::Solid,
            color: 0,
        }],
        ..Default::default()
    }
}

fn vs_vm_chart(analysis: &Analysis, report: &Report, si: usize) -> Option<Chart> {
    let series = analysis.series(si);
    let k = analysis.run().k;
    let vm = report.schemes[si].vs_vm.as_ref()?;
    let lines = (2..=k)
        .map(|j| Line {
            label: format!("GALI_{j}"),
            points: series
                .iter()
                .filter_map(|(t, p)| {
                    let d = *p.vs_vm_abs_delta.as_ref()?.get(j - 2)?;
                    (*t > 0.0).then(|| (*t, lg(d.max(1e-16))))
                })
                .collect(),
            stroke: Stroke::Solid,
            color: j - 1,
        })
        .collect();
    Some(Chart {
        title: format!(
            "GALI of the multi-particle method against the variational method: {}\nscheme {} \
             against scheme {}, mean over sets of |Δ log10 GALI_k|",
            system_words(analysis.run()),
            report.schemes[si].name,
            vm.scheme
        ),
        x_label: "t".into(),
        y_label: "log10 |Δ log10 GALI_k|".into(),
        lines,
        ..Default::default()
    })
}

/// The symbol of an MPM parameter: `d_0`, `τ`.
fn symbol(param: &str) -> &'static str {
    if param == "d0" { "d_0" } else { "τ" }
}

/// GALI_j at the end against `log10 d0` (one curve per order; schemes grouped by tau) or
/// against `log10 tau` (grouped by d0), with the VM value as a dashed line.
fn sweep_charts(report: &Report) -> Vec<(String, Chart)> {
    let mpm: Vec<_> = report
        .schemes
        .iter()
        .filter(|s| s.method == "mpm" && s.orthonormalize != "qr")
        .collect();
    let mut out = Vec::new();
    for (param, other) in [("d0", "tau"), ("tau", "d0")] {
        let value = |s: &crate::report::SchemeReport, p: &str| if p == "d0" { s.d0 } else { s.tau };
        let mut groups: Vec<f64> = mpm.iter().map(|s| value(s, other)).collect();
        groups.sort_by(f64::total_cmp);
        groups.dedup();
        for g in groups {
            let mut members: Vec<_> = mpm.iter().filter(|s| value(s, other) == g).collect();
            members.sort_by(|a, b| value(a, param).total_cmp(&value(b, param)));
            let distinct = {
                let mut v: Vec<f64> = members.iter().map(|s| value(s, param)).collect();
                v.dedup();
                v.len()
            };
            if distinct < 3 {
                continue;
            }
            let k = members[0].k;
            let mut lines = Vec::new();
            for j in 2..=k {
                lines.push(Line {
                    label: format!("GALI_{j}"),
                    points: members
                        .iter()
                        .filter_map(|s| Some((lg(value(s, param)), lg(s.gali.get(j)?.mean))))
                        .collect(),
                    stroke: Stroke::Solid,
                    color: j - 1,
                });
                // The VM partner (d0-independent) as reference.
                if let Some(vm) = members[0]
                    .vs_vm
                    .as_ref()
                    .and_then(|v| report.scheme(&v.scheme))
                    .and_then(|vm| vm.gali.get(j))
                {
                    let x0 = lg(value(members[0], param));
                    let x1 = lg(value(members.last().unwrap(), param));
                    lines.push(Line {
                        label: if j == 2 { "VM".into() } else { String::new() },
                        points: vec![(x0, lg(vm.mean)), (x1, lg(vm.mean))],
                        stroke: Stroke::Dashed,
                        color: j - 1,
                    });
                }
            }
            let t = members[0].t;
            out.push((
                format!("sweep_gali_vs_{param}_{other}{g:e}"),
                Chart {
                    title: format!(
                        "GALI_k at t = {t} against the multi-particle method's {}\n{} = {g}, \
                         arithmetic mean over sets; dashed: the variational method",
                        symbol(param),
                        symbol(other)
                    ),
                    x_label: format!("log10 {}", symbol(param)),
                    y_label: "log10 GALI_k".into(),
                    lines,
                    ..Default::default()
                },
            ));
        }
    }
    out
}

/// Every chart of `analysis`, with the file stem it is drawn to.
pub fn charts(analysis: &Analysis, report: &Report, axis: TimeAxis) -> Vec<(String, Chart)> {
    let run = analysis.run();
    let mut out = Vec::new();
    // Per-scheme time plots only for a readable number of schemes (sweeps get sweep charts).
    let time_schemes: Vec<usize> = (0..run.schemes.len()).take(12).collect();
    for &si in &time_schemes {
        let name = &run.schemes[si].name;
        if alignment_meaningful(run.schemes[si].orthonormalize, run.k) {
            out.push((
                format!("gali_{name}"),
                gali_chart(analysis, report, si, axis),
            ));
        }
        if run.schemes[si].orthonormalize == Orthonormalization::Qr {
            out.push((
                format!("spectrum_{name}"),
                spectrum_chart(analysis, report, si),
            ));
        }
        if run.schemes[si].method == Method::Mpm
            && alignment_meaningful(run.schemes[si].orthonormalize, run.k)
            && let Some(c) = vs_vm_chart(analysis, report, si)
        {
            out.push((format!("vs_vm_{name}"), c));
        }
    }
    let shown = &time_schemes[..time_schemes.len().min(8)];
    out.push(("mle".into(), mle_chart(analysis, report, shown)));
    for (i, name) in chaoscope_indicators::indicator::set_output_names()
        .iter()
        .enumerate()
    {
        let sites = run.kind.lattice_sites(run.dim).unwrap_or(0);
        if lattice_output(name) && sites < crate::site_png::MIN_SITES {
            continue;
        }
        if let Some(c) = named_chart(analysis, report, shown, i, name, axis) {
            out.push((name.to_string(), c));
        }
    }
    if analysis.run().kind == chaoscope_schemas::run::SystemClass::Hamiltonian {
        out.push(("energy_error".into(), energy_chart(analysis)));
    }
    out.extend(sweep_charts(report));
    out
}

/// Draws every chart of `analysis` into `dir` (PNG and SVG); returns the files written.
/// (Each file complete or not at all, never one of `inputs`: `chaoscope_os::output`.)
pub fn plot_all(
    analysis: &Analysis,
    report: &Report,
    dir: &Path,
    axis: TimeAxis,
    inputs: &[PathBuf],
) -> Result<Vec<PathBuf>, ChartError> {
    std::fs::create_dir_all(dir).map_err(|e| ChartError::Draw {
        path: dir.to_path_buf(),
        message: e.to_string(),
    })?;
    let mut files = Vec::new();
    for (name, chart) in charts(analysis, report, axis) {
        files.extend(render(&chart, &dir.join(name), inputs)?);
    }
    // A lattice's distributions over the sites against time (kept where the analysis was
    // asked to, `AnalysisOptions::site_profiles`): for a chain; a square lattice's flattened
    // site index would put neighbours in a column `L` sites apart, so it gets its pictures
    // over the plane at chosen times instead (those it cannot draw: `plane_png::planes`).
    if let Some(profiles) = analysis.site_profiles()
        && let Some(side) = profiles.square_side()
    {
        for plane in crate::plane_png::planes(analysis).0 {
            let path = crate::plane_png::plane_path(dir, plane.asked);
            crate::plane_png::render_png(&plane, side, &path, inputs).map_err(|message| {
                ChartError::Draw {
                    path: path.clone(),
                    message,
                }
            })?;
            files.push(path);
        }
    } else if let Some(profiles) = analysis.site_profiles()
        && profiles.points().len() >= 2
        && profiles.sites() >= crate::site_png::MIN_SITES
    {
        let path = dir.join("distributions.png");
        crate::site_png::render_png(profiles, &path, inputs).map_err(|message| {
            ChartError::Draw {
                path: path.clone(),
                message,
            }
        })?;
        files.push(path);
    }
    Ok(files)
}
