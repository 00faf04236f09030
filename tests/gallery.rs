//! The guide's gallery (`docs/src/gallery.md`): one figure of each kind chaoscope draws,
//! regenerated here from small deterministic runs with the commands the page names, and compared
//! byte for byte with the committed files, so the page cannot drift from what the tool draws.
//! `CHAOSCOPE_UPDATE_GALLERY=1` rewrites the committed files instead (CONTRIBUTING.md).
//!
//! Text is set in DejaVu Sans (`CHAOSCOPE_FONT`): glyph shapes and the text widths that place
//! titles and ticks come from the font file, so another font draws other bytes. Without DejaVu
//! Sans on the machine the comparison is skipped (said on stderr); the labels are checked anyway.

use crate::common;

use std::path::{Path, PathBuf};

use chaoscope_analyzer::chart::svg_texts;

const FONT: &str = "/usr/share/fonts/truetype/dejavu/DejaVuSans.ttf";

fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// `chaoscope ARGS` in `dir`'s private bus domain with the gallery's font, to success.
fn run(bus: &Path, font: Option<&str>, args: &[&str]) {
    let mut c = common::chaoscope_captured(args);
    c.env("CHAOSCOPE_BUS_DIR", bus).current_dir(repo());
    if let Some(f) = font {
        c.env("CHAOSCOPE_FONT", f);
    }
    let out = c.output().expect("chaoscope runs");
    assert!(
        out.status.success(),
        "chaoscope {args:?}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
}

fn texts(path: &Path) -> Vec<String> {
    svg_texts(&std::fs::read_to_string(path).unwrap())
}

/// What a reader of the figure must see written, and code names nobody should.
fn assert_labels(path: &Path, expected: &[&str]) {
    let t = texts(path);
    let all = t.join(" | ");
    for want in expected {
        assert!(
            t.iter().any(|s| s == want || s.contains(want)),
            "{}: no {want:?} in {all}",
            path.display()
        );
    }
    for code in [
        "megno_mean",
        "l_i",
        "lambda",
        "potential vm:",
        "xi_l",
        "sum h",
    ] {
        assert!(
            !t.iter().any(|s| s.contains(code)),
            "{}: code name {code:?} in {all}",
            path.display()
        );
    }
    // Clean ticks: a number written as a whole number where it is one, never a negative zero.
    for s in &t {
        if s.parse::<f64>().is_ok() {
            assert!(
                !s.ends_with(".0") && s != "-0",
                "{}: tick {s:?}",
                path.display()
            );
        }
    }
}

#[test]
fn gallery_figures_are_what_the_tool_draws() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let bus = d.join("bus");
    std::fs::create_dir(&bus).unwrap();
    let font = Path::new(FONT).exists().then_some(FONT);
    let p = |name: &str| d.join(name).to_str().unwrap().to_string();

    // The commands of docs/src/gallery.md, run from the repository's root.
    let hh = p("hh.mcap");
    run(
        &bus,
        font,
        &["run", "docs/src/gallery/hh-regular.toml", "--out", &hh],
    );
    run(&bus, font, &["analyze", &hh, "--plot", &p("hh")]);
    let fput = p("fput.mcap");
    run(
        &bus,
        font,
        &["run", "docs/src/gallery/fput-chain.toml", "--out", &fput],
    );
    run(&bus, font, &["analyze", &fput, "--plot", &p("fput")]);
    run(
        &bus,
        font,
        &[
            "map",
            "docs/src/gallery/hh-map.toml",
            "--out",
            &p("map.mcap"),
            "--png",
            &p("map.png"),
        ],
    );
    run(
        &bus,
        font,
        &[
            "section",
            "examples/models/henon-heiles.toml",
            "--surface",
            "q1",
            "--vary",
            "q2",
            "--from",
            "-0.4",
            "--to",
            "0.6",
            "--count",
            "8",
            "--crossings",
            "300",
            "--plot",
            &p("section"),
        ],
    );
    run(
        &bus,
        font,
        &[
            "chart",
            "docs/src/gallery/power-laws.json",
            "--out",
            &p("chart"),
        ],
    );
    let lorenz = p("lorenz.mcap");
    run(
        &bus,
        font,
        &["run", "docs/src/gallery/lorenz-clv.toml", "--out", &lorenz],
    );
    run(
        &bus,
        font,
        &["analyze", &lorenz, "--clv", "--plot", &p("clv")],
    );
    assert!(common::close_private_bus(&bus).is_empty());

    // Only meaningful panels: no GALI for the QR scheme, no lattice picture nor lattice
    // indicators for the two-degree-of-freedom Henon-Heiles system, both for the 8-site chain.
    let hh_dir = d.join("hh");
    for absent in [
        "gali_vm-qr.svg",
        "distributions.png",
        "dvd_m2.svg",
        "energy_m2.svg",
    ] {
        assert!(
            !hh_dir.join(absent).exists(),
            "{absent} drawn for hh-regular"
        );
    }
    for present in [
        "distributions.png",
        "dvd_m2.svg",
        "energy_participation.svg",
    ] {
        assert!(d.join("fput").join(present).exists(), "{present} missing");
    }

    // Generated file -> gallery file, with the words each must show.
    let figures: [(&str, &str, &[&str]); 12] = [
        (
            "hh/gali_vm.svg",
            "gali.svg",
            &[
                "GALI_k against time: hh-regular, Hénon-Heiles system",
                "log10 GALI_k",
                "log10 t",
                // The verdict's 2-torus: GALI_2 constant, GALI_3 ~ t^-2, GALI_4 ~ t^-4.
                "GALI_2 ~ const",
                "GALI_3 ~ t^-2",
                "GALI_4 ~ t^-4",
                "the laws of a 2-torus",
            ],
        ),
        (
            "hh/spectrum_vm-qr.svg",
            "spectrum.svg",
            &[
                "Lyapunov spectrum against time",
                "λ_i",
                "λ_1",
                "λ_4",
                "log10 t",
            ],
        ),
        (
            "hh/mle.svg",
            "mle.svg",
            &["Maximal Lyapunov exponent λ_1", "log10 λ_1", "λ_1 ~ t^-1"],
        ),
        (
            "hh/megno_mean.svg",
            "megno-mean.svg",
            &["mean MEGNO ⟨Y⟩ against time", "mean MEGNO ⟨Y⟩", "log10 t"],
        ),
        (
            "hh/energy_error.svg",
            "energy-error.svg",
            &["Relative energy error against time", "log10 E_r"],
        ),
        (
            "hh/vs_vm_mpm.svg",
            "mpm-vs-vm.svg",
            &["log10 |Δ log10 GALI_k|", "t", "GALI_2"],
        ),
        (
            "hh/sweep_gali_vs_d0_tau1e0.svg",
            "sweep-d0.svg",
            &[
                "against the multi-particle method's d_0",
                "τ = 1",
                "log10 d_0",
                "VM",
            ],
        ),
        ("fput/distributions.png", "distributions.png", &[]),
        ("map.png", "map.png", &[]),
        (
            "section/section.svg",
            "section.svg",
            &["Poincaré section q1 = 0", "q2", "p2"],
        ),
        (
            "clv/clv-angle-expanding_vs_contracting.svg",
            "clv-angle.svg",
            &[
                "Angle between the expanding and contracting CLV subspaces (scheme vm, set 0)",
                "log10 angle (rad)",
                "renormalizations per bin",
            ],
        ),
        (
            "chart.svg",
            "chart.svg",
            &["The power laws of GALI_k on a 2-torus", "GALI_3 ~ t^-2"],
        ),
    ];
    for (made, _, expected) in &figures {
        let path = d.join(made);
        assert!(path.exists(), "{made} not drawn");
        if made.ends_with(".svg") {
            assert_labels(&path, expected);
        }
    }

    let gallery = repo().join("docs/src/gallery");
    let update = std::env::var_os("CHAOSCOPE_UPDATE_GALLERY").is_some_and(|v| v == "1");
    if font.is_none() {
        eprintln!("gallery: {FONT} not found: the figures are not compared with the gallery's");
        return;
    }
    let mut drifted = Vec::new();
    for (made, committed, _) in &figures {
        let new = std::fs::read(d.join(made)).unwrap();
        let target = gallery.join(committed);
        if update {
            std::fs::write(&target, &new).unwrap();
        } else if std::fs::read(&target).ok().as_deref() != Some(&new[..]) {
            drifted.push(*committed);
        }
    }
    assert!(
        drifted.is_empty(),
        "docs/src/gallery/{drifted:?} differ from what chaoscope draws now: look at them, then \
         rewrite them with CHAOSCOPE_UPDATE_GALLERY=1 cargo test --release --test end_to_end gallery::"
    );
}
