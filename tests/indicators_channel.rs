//! The indicators channel of every recording (`/chaoscope/indicators/<scheme>`): one message per
//! scheme and renormalization, equal to `chaoscope analyze --json` at the same time to the last
//! bit (the recorder and the analyzer share `chaoscope-indicators`' tracker), in recorded and in
//! replayed files.

use std::path::Path;

use crate::common::*;
use chaoscope_schemas::config::{DeviationsConfig, SchemeConfig, paper};
use chaoscope_schemas::proto::{Indicators, MeanOverSets};
use serde_json::Value;

/// The paper's chaotic Henon-Heiles orbit, short: k = 4 (GALI_2..4), three sets, VM and MPM
/// rescaled and a QR scheme (the spectrum), tau = 1.
fn hh_run(run: &str) -> String {
    let mut config = paper::henon_heiles(
        paper::HH_CHAOTIC_Q2,
        60.0,
        DeviationsConfig::random(4, 3, 5),
        vec![
            SchemeConfig::new("vm", "vm", 1e-8, 1.0),
            SchemeConfig::new("mpm", "mpm", 1e-8, 1.0),
            SchemeConfig::new("qr", "vm", 1.0, 2.0).with_orthonormalize("qr"),
        ],
    );
    config.run.name = Some(run.to_string());
    config.to_toml()
}

fn analyze_json(file: &Path, at: Option<f64>) -> Value {
    let mut args = vec!["analyze", file.to_str().unwrap(), "--json"];
    let at = at.map(|t| t.to_string());
    if let Some(t) = &at {
        args.extend(["--at", t]);
    }
    let out = chaoscope(&args).output().expect("run chaoscope analyze");
    assert!(out.status.success(), "chaoscope {args:?} failed");
    serde_json::from_slice(&out.stdout).expect("analyze --json prints JSON")
}

fn f(v: &Value) -> f64 {
    v.as_f64().unwrap_or_else(|| panic!("not a number: {v}"))
}

fn assert_same(what: &str, got: f64, want: f64) {
    assert_eq!(
        got.to_bits(),
        want.to_bits(),
        "{what}: indicators channel {got:e}, analyze --json {want:e}"
    );
}

fn assert_mean_equals(what: &str, got: &MeanOverSets, want: &Value) {
    assert_same(&format!("{what}.mean"), got.mean, f(&want["mean"]));
    assert_same(
        &format!("{what}.log10_mean"),
        got.log10_mean,
        f(&want["log10_mean"]),
    );
    // log10 of the arithmetic mean, by the same Rust function on the same bits.
    assert_same(
        &format!("{what}.log10_of_mean"),
        got.log10_of_mean,
        f(&want["mean"]).log10(),
    );
}

/// Every field of one message against the scheme's entry of an `analyze --json` report.
fn assert_equals_report(m: &Indicators, report: &Value) {
    let s = &report["schemes"][m.scheme as usize];
    let name = s["name"].as_str().unwrap();
    assert_same(&format!("{name} t"), m.t, f(&s["t"]));
    assert_eq!(m.sets as u64, s["sets"].as_u64().unwrap(), "{name} sets");
    let gali = s["gali"].as_object().unwrap();
    assert_eq!(m.gali.len(), gali.len(), "{name}: GALI orders");
    for (o, g) in m.gali.iter().enumerate() {
        assert_mean_equals(
            &format!("{name} GALI_{}", o + 2),
            g,
            &gali[&(o + 2).to_string()],
        );
    }
    assert_mean_equals(
        &format!("{name} SALI"),
        m.sali.as_ref().unwrap(),
        &s["sali"],
    );
    assert_same(&format!("{name} mle"), m.mle, f(&s["mle"]));
    if s["orthonormalize"] == "qr" {
        let want: Vec<f64> = s["lyapunov"].as_array().unwrap().iter().map(f).collect();
        assert_eq!(m.spectrum.len(), 4, "{name}: a spectrum of k exponents");
        for (i, (g, w)) in m.spectrum.iter().zip(&want).enumerate() {
            assert_same(&format!("{name} lambda_{}", i + 1), *g, *w);
        }
    } else {
        assert!(
            m.spectrum.is_empty(),
            "{name}: no spectrum for a rescaled scheme"
        );
    }
    // Every registered set indicator, by name, as `analyze --json` names it: the same bits where
    // the channel has a value. OFLI needs the system's vector field, which `analyze` rebuilds
    // from the recording's config and the recorder does not: there the channel says why. The
    // energy distribution needs the model's site energies, likewise (and Henon-Heiles is no
    // lattice, so `analyze` says why too).
    let names: Vec<&str> = m.named.iter().map(|n| n.name.as_str()).collect();
    for contract in ["fli", "ofli", "megno", "megno_mean"] {
        assert!(names.contains(&contract), "{name}: {contract} in {names:?}");
    }
    for n in &m.named {
        assert!(
            s.get(&n.name).is_some(),
            "{name}: {} not in the report",
            n.name
        );
        let what = format!("{name} {}", n.name);
        match (n.mean, n.std) {
            (Some(mean), Some(std)) => {
                assert!(n.unavailable.is_empty(), "{what}");
                assert_same(&format!("{what}.mean"), mean, f(&s[&n.name]["mean"]));
                assert_same(&format!("{what}.std"), std, f(&s[&n.name]["std"]));
            }
            _ if n.name.starts_with("energy_") => {
                assert!(
                    n.unavailable.contains("rebuild"),
                    "{what}: {}",
                    n.unavailable
                );
                assert!(
                    s[&n.name]["unavailable"].is_string(),
                    "{what}: not a lattice"
                );
            }
            // Henon-Heiles conserves no norm `sum (q^2 + p^2) / 2`: the recorder and `analyze`
            // say so alike.
            _ if n.name.starts_with("norm_") => {
                assert!(
                    n.unavailable.contains("conserves the norm"),
                    "{what}: {}",
                    n.unavailable
                );
                assert_eq!(
                    s[&n.name]["unavailable"].as_str(),
                    Some(n.unavailable.as_str()),
                    "{what}"
                );
            }
            _ => {
                assert_eq!(n.name, "ofli", "{what}: only OFLI needs the flow");
                assert!(n.unavailable.contains("vector field"), "{what}");
                assert!(s["ofli"]["mean"].is_f64(), "{what}: analyze gives it");
            }
        }
    }
}

/// The messages of one scheme's channel, checked to be one per renormalization in time order.
fn channel<'a>(rec: &'a Recorded, name: &str, every: f64, t_final: f64) -> Vec<&'a Indicators> {
    let topic = format!("/chaoscope/indicators/{name}");
    let ms: Vec<&Indicators> = rec
        .indicators
        .iter()
        .filter(|(t, _)| *t == topic)
        .map(|(_, m)| m)
        .collect();
    // t = 0 and every renormalization up to t_final.
    assert_eq!(ms.len(), (t_final / every).round() as usize + 1, "{topic}");
    for (i, m) in ms.iter().enumerate() {
        assert!(
            (m.t - i as f64 * every).abs() < 1e-9,
            "{topic}[{i}] at t = {}",
            m.t
        );
        assert_eq!(m.sets, 3, "{topic}[{i}]: every set contributes");
    }
    ms
}

#[test]
fn recorded_and_replayed_indicators_equal_analyze_json_to_the_last_bit() {
    let dir = tempfile::tempdir().unwrap();
    let run = unique_run("indicators");
    let config = write_config(dir.path(), &hh_run(&run));
    let file = dir.path().join("run.mcap");
    let out = chaoscope(&[
        "run",
        config.to_str().unwrap(),
        "--out",
        file.to_str().unwrap(),
    ])
    .output()
    .expect("chaoscope run");
    assert!(out.status.success(), "chaoscope run failed");

    let rec = read_recording(&file);
    let (vm, mpm, qr) = (
        channel(&rec, "vm", 1.0, 60.0),
        channel(&rec, "mpm", 1.0, 60.0),
        channel(&rec, "qr", 2.0, 60.0),
    );
    // At the end of the run, and as of t = 30 (`--at`, the values after the renormalization at
    // t = 30 of every scheme).
    let end = analyze_json(&file, None);
    for m in [vm[60], mpm[60], qr[30]] {
        assert_equals_report(m, &end);
    }
    let mid = analyze_json(&file, Some(30.0));
    for m in [vm[30], mpm[30], qr[15]] {
        assert_equals_report(m, &mid);
    }
    // The run is chaotic (MLE about 0.05 on this orbit, numerics.md): by t = 60 GALI_4 has
    // decayed well below its start at 1 (log10 0), so the channel carries moving curves, not
    // constants.
    assert!(vm[0].gali[2].log10_mean.abs() < 1e-12);
    assert!(vm[60].gali[2].log10_mean < -1.0, "{:?}", vm[60].gali[2]);

    // A replay writes the channel from its own samples, through the same file layout.
    let replayed = dir.path().join("replayed.mcap");
    let out = chaoscope(&[
        "replay",
        file.to_str().unwrap(),
        "--tau",
        "0.5",
        "--out",
        replayed.to_str().unwrap(),
    ])
    .output()
    .expect("chaoscope replay");
    assert!(out.status.success(), "chaoscope replay failed");
    let rec = read_recording(&replayed);
    let report = analyze_json(&replayed, None);
    let schemes = report["schemes"].as_array().unwrap();
    assert!(!schemes.is_empty());
    for (si, s) in schemes.iter().enumerate() {
        let name = s["name"].as_str().unwrap();
        let topic = format!("/chaoscope/indicators/{name}");
        let last = rec
            .indicators
            .iter()
            .filter(|(t, _)| *t == topic)
            .map(|(_, m)| m)
            .next_back()
            .unwrap_or_else(|| panic!("replay has no indicators for {name}"));
        assert_eq!(last.scheme as usize, si);
        assert_equals_report(last, &report);
    }
}

#[test]
fn a_run_sampled_every_few_renormalizations_records_its_indicators_exactly() {
    // Sampled every 4 (tau 1, 1 and 2): the recorder's tracker accumulates the stretching
    // factors each sample carries for the renormalizations in between, so the channel holds one
    // message per sample and its last one equals analyze --json to the last bit.
    let dir = tempfile::tempdir().unwrap();
    let run = unique_run("indicators-thinned");
    let text = format!(
        "[run]\nsample_every = 4.0\n{}",
        hh_run(&run).replacen("[run]\n", "", 1)
    );
    let config = write_config(dir.path(), &text);
    let file = dir.path().join("run.mcap");
    let out = chaoscope(&[
        "run",
        config.to_str().unwrap(),
        "--out",
        file.to_str().unwrap(),
    ])
    .output()
    .expect("chaoscope run");
    assert!(out.status.success(), "chaoscope run failed");
    let rec = read_recording(&file);
    let end = analyze_json(&file, None);
    for name in ["vm", "mpm", "qr"] {
        let ms = channel(&rec, name, 4.0, 60.0);
        assert_equals_report(ms[15], &end);
    }
}
