//! The scalar C yardstick of the map workload: the paper's pseudo-code (`gali2_mpm.c`, the
//! reference orbit integrated again for every set, k = 2 nearby orbits, renormalization every
//! tau) built at bench time by the system C compiler with `-O3 -march=native`, once without
//! floating-point contraction (`-ffp-contract=off`: chaoscope's arithmetic) and once with it
//! (`-ffp-contract=fast`: FMA where the compiler likes), and timed on initial conditions of the
//! map being measured. Without a C compiler the JSON says why instead of failing the bench.

use std::io::Write;
use std::path::Path;
use std::process::{Command, Stdio};

use anyhow::Context;
use chaoscope_dynamics::batch::StepCoeffs;
use chaoscope_dynamics::map::MapSpec;

const SOURCE: &str = include_str!("gali2_mpm.c");

/// The two builds: name in the JSON and the contraction flag.
const BUILDS: [(&str, &str); 2] = [
    ("no_contraction", "-ffp-contract=off"),
    ("contraction", "-ffp-contract=fast"),
];

/// What one build measured.
pub struct Timing {
    pub cpu_seconds: f64,
    pub mean_log10_gali2: Vec<f64>,
}

/// The C program's input: the splitting, the windows, the sets' directions, the points.
fn input(spec: &MapSpec, coeffs: &StepCoeffs, points: &[Vec<f64>]) -> anyhow::Result<String> {
    let run = &spec.run;
    anyhow::ensure!(
        run.dim() == 4 && run.k() == 2,
        "the C yardstick is HH with k = 2"
    );
    let tau = run.schemes()[0].tau_steps;
    anyhow::ensure!(
        run.total_steps().is_multiple_of(tau),
        "the C yardstick needs whole renormalization windows"
    );
    let mut s = String::new();
    let mut put = |v: f64| s.push_str(&format!("{v:e}\n"));
    put(coeffs.kicks() as f64);
    coeffs.drift.iter().for_each(|&v| put(v));
    coeffs.kick.iter().for_each(|&v| put(v));
    put(tau as f64);
    put((run.total_steps() / tau) as f64);
    put(run.schemes()[0].d0);
    put(run.sets() as f64);
    for d in run.directions() {
        d.vectors.iter().for_each(|&v| put(v));
    }
    put(points.len() as f64);
    for x in points {
        x.iter().for_each(|&v| put(v));
    }
    Ok(s)
}

fn compile(dir: &Path, flag: &str, exe: &Path) -> anyhow::Result<()> {
    let src = dir.join("gali2_mpm.c");
    let out = Command::new("cc")
        .args(["-O3", "-march=native", flag, "-o"])
        .arg(exe)
        .arg(&src)
        .arg("-lm")
        .output()
        .context("running cc")?;
    anyhow::ensure!(
        out.status.success(),
        "cc {flag} failed: {}",
        String::from_utf8_lossy(&out.stderr)
            .lines()
            .next()
            .unwrap_or("")
    );
    Ok(())
}

/// A built C yardstick run on `input` (its stdin): what it printed.
pub fn output_of(exe: &Path, input: &str) -> anyhow::Result<String> {
    let mut child = Command::new(exe)
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .spawn()
        .context("starting the C yardstick")?;
    child
        .stdin
        .take()
        .context("stdin of the C yardstick")?
        .write_all(input.as_bytes())?;
    let out = child.wait_with_output()?;
    anyhow::ensure!(
        out.status.success(),
        "the C yardstick failed ({})",
        out.status
    );
    Ok(String::from_utf8(out.stdout)?)
}

fn run(exe: &Path, input: &str, points: usize) -> anyhow::Result<Timing> {
    let text = output_of(exe, input)?;
    let mut values = Vec::new();
    let mut cpu = None;
    for line in text.lines() {
        match line.strip_prefix("cpu_seconds ") {
            Some(v) => cpu = Some(v.parse::<f64>()?),
            None => values.push(line.parse::<f64>()?),
        }
    }
    anyhow::ensure!(
        values.len() == points,
        "the C yardstick gave {} values",
        values.len()
    );
    Ok(Timing {
        cpu_seconds: cpu.context("the C yardstick printed no time")?,
        mean_log10_gali2: values,
    })
}

/// Builds both variants in a private temporary directory (removed afterwards) and times each
/// on `points` (initial states). `Err` says why there is no C figure.
pub fn measure(
    spec: &MapSpec,
    coeffs: &StepCoeffs,
    points: &[Vec<f64>],
) -> anyhow::Result<Vec<(&'static str, &'static str, Timing)>> {
    let input = input(spec, coeffs, points)?;
    // A fresh directory of a random name, created mode 0700 and removed when dropped: the
    // programs built here are run, so the directory must be nobody else's (a predictable name
    // in the shared temporary directory could be made first by another user).
    let scratch = tempfile::Builder::new()
        .prefix("chaoscope-bench-c-")
        .tempdir()?;
    let dir = scratch.path();
    let result = (|| {
        std::fs::write(dir.join("gali2_mpm.c"), SOURCE)?;
        let mut out = Vec::new();
        for (name, flag) in BUILDS {
            let exe = dir.join(name);
            compile(dir, flag, &exe)?;
            out.push((name, flag, run(&exe, &input, points.len())?));
        }
        Ok(out)
    })();
    drop(scratch);
    result
}

/// The first line of `cc --version` (which compiler the figures are of).
pub fn compiler() -> String {
    Command::new("cc")
        .arg("--version")
        .output()
        .ok()
        .and_then(|o| String::from_utf8(o.stdout).ok())
        .and_then(|t| t.lines().next().map(str::to_string))
        .unwrap_or_else(|| "unknown".into())
}
