//! Issue 4, must-show 5: the paper script's reduced mode runs in CI and checks the key numbers
//! (V-shape minima, MLE band, GALI slopes, energy-error order, tau flatness); it exits non-zero
//! when one is off. About half a minute in release on two cores.

use std::process::Command;

#[test]
fn paper_script_reduced_mode_checks_the_key_numbers() {
    let dir = tempfile::tempdir().unwrap();
    let script = concat!(env!("CARGO_MANIFEST_DIR"), "/examples/paper/run.py");
    let status = Command::new("python3")
        .args([
            script,
            "--reduced",
            "--chaoscope",
            env!("CARGO_BIN_EXE_chaoscope"),
            "--out",
        ])
        .arg(dir.path())
        .status()
        .expect("python3 runs the paper script");
    assert!(
        status.success(),
        "examples/paper/run.py --reduced failed: {status}"
    );
    let numbers = std::fs::read_to_string(dir.path().join("numbers.json")).unwrap();
    assert!(numbers.contains("hh_d0_best"), "{numbers}");
}
