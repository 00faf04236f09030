//! Producer, recorder and a checker as three real processes; every sample
//! arrives exactly once, bit-identical to an in-process computation; standard Python tools
//! decode the file and `pymcap-cli doctor` accepts it.

use std::ops::ControlFlow;
use std::process::{Command, Stdio};
use std::time::Duration;

use crate::common::*;
use chaoscope_recorder::subscription::{BusEvent, Ended, RunSubscription};
use chaoscope_schemas::proto::DataMessage;
use chaoscope_schemas::proto::end_of_run::Status;

const CHECKER_RUN: &str = "CHAOSCOPE_CHECKER_RUN";

/// The checker process: this test binary re-executed with `CHAOSCOPE_CHECKER_RUN` set. It
/// subscribes losslessly, recomputes the run from the config in the run header, and panics
/// (non-zero exit) on any gap, repeat or differing bit. Without the variable it does nothing.
#[test]
fn checker_process() {
    let Ok(run) = std::env::var(CHECKER_RUN) else {
        return;
    };
    let sub = RunSubscription::open(&run, &format!("chaoscope-checker/{run}")).unwrap();
    let header = sub
        .wait_header(Some(Duration::from_secs(60)))
        .unwrap()
        .unwrap();
    let expected = compute(&header.config_toml, None);
    let mut next_frame = 0u64;
    let mut sample = 0usize;
    let mut scheme_index = 0usize;
    let mut end = None;
    let ended = sub
        .receive(|event| {
            let BusEvent::Message(m) = event else {
                return ControlFlow::Continue(());
            };
            let frame = match &m {
                DataMessage::Reference(r) => {
                    let want = &expected[sample];
                    assert_eq!((r.seq, r.step), (want.seq, want.step));
                    assert_eq!(
                        bits(&r.state),
                        bits(&want.state),
                        "state of sample {sample}"
                    );
                    assert_eq!(r.energy.to_bits(), want.energy.to_bits());
                    scheme_index = 0;
                    r.frame
                }
                DataMessage::Separations(s) => {
                    let want = &expected[sample].schemes[scheme_index];
                    assert_eq!((s.scheme, s.set), (want.scheme, want.set));
                    assert_eq!(
                        bits(&s.separations),
                        bits(&want.separations),
                        "sample {sample}"
                    );
                    assert_eq!(bits(&s.stretch), bits(&want.stretch), "sample {sample}");
                    scheme_index += 1;
                    if scheme_index == expected[sample].schemes.len() {
                        sample += 1;
                    }
                    s.frame
                }
                DataMessage::End(e) => {
                    end = Some(e.clone());
                    e.frame
                }
            };
            assert_eq!(frame, next_frame, "gap or repeat on the bus");
            next_frame += 1;
            if end.is_some() {
                ControlFlow::Break(())
            } else {
                ControlFlow::Continue(())
            }
        })
        .unwrap();
    assert_eq!(ended, Ended::Stopped);
    let end = end.expect("end-of-run record");
    assert_eq!(end.status(), Status::Completed);
    assert_eq!(end.samples as usize, expected.len());
    assert_eq!(sample, expected.len(), "every sample checked");
    println!(
        "checker: {} samples, {next_frame} frames verified",
        expected.len()
    );
}

#[test]
fn producer_recorder_checker_record_every_sample_bit_identical() {
    let dir = tempfile::tempdir().unwrap();
    let text = hh_config(20.0, 0.05).to_toml();
    let config = write_config(dir.path(), &text);
    let out = dir.path().join("run.mcap");
    let run = unique_run("e2e");

    let mut recorder = Proc::spawn(record_cmd(&run, &out, &[]));
    let mut checker_cmd = Command::new(std::env::current_exe().unwrap());
    checker_cmd
        .args([
            "--exact",
            "pipeline_end_to_end::checker_process",
            "--nocapture",
            "--test-threads",
            "1",
        ])
        .env(CHECKER_RUN, &run);
    checker_cmd.stdout(std::process::Stdio::piped());
    let mut checker = Proc::spawn(checker_cmd);
    let mut producer = Proc::spawn(chaoscope(&[
        "produce",
        config.to_str().unwrap(),
        "--run",
        &run,
        "--recorders",
        "2",
        "--wait-timeout",
        "60",
        "--no-progress",
    ]));

    let limit = Duration::from_secs(120);
    assert!(producer.wait(limit).success(), "producer failed");
    assert!(recorder.wait(limit).success(), "recorder failed");
    let checker_status = checker.wait(limit);
    let checker_out = checker.stdout();
    assert!(checker_status.success(), "checker failed: {checker_out}");
    assert!(
        checker_out.contains("checker: 401 samples"),
        "checker did not run: {checker_out}"
    );

    let rec = read_recording(&out);
    let expected = compute(&text, None);
    assert_eq!(rec.references.len(), expected.len());
    assert_eq!(
        rec.separations.len(),
        expected.iter().map(|s| s.schemes.len()).sum::<usize>()
    );
    assert_bit_identical(&rec, &expected);
    assert_contiguous(&rec.frames);
    let summary = rec.recording.expect("recording summary");
    assert_eq!(
        (summary.finalized_by.as_str(), summary.run_status.as_str()),
        ("end-of-run", "completed")
    );
    assert_eq!(summary.frames_missing, 0);
    let header = rec.header.expect("run header");
    assert_eq!(
        header.config_toml,
        chaoscope_schemas::config::RunConfig::from_toml(&text)
            .unwrap()
            .to_toml()
    );

    if python_checks_enabled() {
        // header + data frames (incl. end) + indicators + summary
        let total = 1 + rec.frames.len() + rec.indicators.len() + 1;
        let status = Command::new("python3")
            .arg(python_script("check_mcap.py"))
            .arg(&out)
            .arg(total.to_string())
            .status()
            .expect("python3 (set CHAOSCOPE_SKIP_PYTHON=1 to skip)");
        assert!(
            status.success(),
            "Python mcap + mcap-protobuf-support could not decode the file"
        );
        let doctor = Command::new("pymcap-cli")
            .arg("doctor")
            .arg(&out)
            .output()
            .expect("pymcap-cli installed");
        assert!(
            doctor.status.success(),
            "pymcap-cli doctor rejected the file: {}",
            String::from_utf8_lossy(&doctor.stdout)
        );
    }
}

#[test]
fn bad_config_is_a_clear_error_not_a_panic() {
    let dir = tempfile::tempdir().unwrap();
    let mut unknown_method = hh_config(10.0, 0.05);
    unknown_method.integrator.method = "rk4".to_string();
    let mut negative_step = hh_config(10.0, 0.05);
    negative_step.integrator.h = Some(-1.0);
    let cases = [
        ("[model]\nname = 'henon-heiles'\n", "orbit"),
        (&unknown_method.to_toml() as &str, "rk4"),
        (&negative_step.to_toml() as &str, "h"),
        ("not toml at all [", "invalid"),
    ];
    for (text, needle) in cases {
        let config = write_config(dir.path(), text);
        let output = Command::new(CHAOSCOPE)
            .args(["produce", config.to_str().unwrap(), "--recorders", "0"])
            .output()
            .unwrap();
        let stderr = String::from_utf8_lossy(&output.stderr);
        assert_eq!(output.status.code(), Some(1), "{stderr}");
        assert!(
            stderr.contains(needle),
            "error should name {needle:?}: {stderr}"
        );
        assert!(!stderr.contains("panicked"), "{stderr}");
    }
    let missing = Command::new(CHAOSCOPE)
        .args(["run", "/nonexistent/run.toml"])
        .output()
        .unwrap();
    assert_eq!(missing.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&missing.stderr).contains("/nonexistent/run.toml"));
}

/// Two producers of one run: the second is refused with an error that names the run and the
/// other producer. Started while the first waits for its recorder, it is refused by the
/// liveness check; started at the same moment, both pass that check, and the one that opens
/// the bus second finds the other's publishers in place (never iceoryx2's slot error is shown).
/// A producer that has the bus and no recorder gives up after its wait.
#[test]
fn a_second_producer_of_a_run_is_refused_by_name() {
    let dir = tempfile::tempdir().unwrap();
    let config = write_config(dir.path(), &hh_config(10.0, 0.05).to_toml());
    let producer = |run: &str, wait_seconds: &str| {
        let mut c = Command::new(CHAOSCOPE);
        c.args(["produce", config.to_str().unwrap(), "--run", run])
            .args(["--recorders", "1", "--wait-timeout", wait_seconds])
            .arg("--no-progress")
            .stdout(Stdio::null())
            .stderr(Stdio::piped());
        c
    };
    let outcome = |child: std::process::Child| {
        let out = child.wait_with_output().unwrap();
        assert!(!out.status.success());
        String::from_utf8_lossy(&out.stderr).into_owned()
    };
    let refused =
        |err: &str, run: &str| err.contains("already being produced") && err.contains(run);
    let waited = |err: &str| err.contains("no recorder subscribed");

    // One after the other: the first is on the bus, waiting for its recorder.
    let run = unique_run("twice");
    let first = producer(&run, "5").spawn().unwrap();
    wait_for_node(&chaoscope_schemas::names::producer_node_name(&run));
    let err = outcome(producer(&run, "5").spawn().unwrap());
    assert!(refused(&err, &run), "{err}");
    let err = outcome(first);
    assert!(waited(&err), "{err}");

    // At the same moment: each is refused by name or waits; when both meet on the bus, one
    // of each.
    let mut met = 0;
    for _ in 0..4 {
        let run = unique_run("together");
        let (a, b) = (
            producer(&run, "1").spawn().unwrap(),
            producer(&run, "1").spawn().unwrap(),
        );
        let errors = [outcome(a), outcome(b)];
        for err in &errors {
            assert!(refused(err, &run) || waited(err), "{errors:?}");
        }
        if errors.iter().any(|e| refused(e, &run)) {
            assert!(errors.iter().any(|e| waited(e)), "{errors:?}");
            met += 1;
        }
    }
    eprintln!("{met} of 4 pairs started together met on the bus");
}
