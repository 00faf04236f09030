//! The paper script's reduced mode runs in CI and checks the key numbers
//! (V-shape minima, MLE band, GALI slopes, energy-error order, tau flatness); it exits non-zero
//! when one is off. About half a minute in release on two cores.

use crate::common;

#[test]
fn paper_script_reduced_mode_checks_the_key_numbers() {
    let dir = tempfile::tempdir().unwrap();
    common::run_reduced_example("examples/paper/run.py", dir.path());
    let numbers = std::fs::read_to_string(dir.path().join("numbers.json")).unwrap();
    assert!(numbers.contains("hh_d0_best"), "{numbers}");
}
