//! A hand-written model through the whole chaoscope pipeline: the library route for a system
//! that is easier to write in Rust than as an expression (or that needs code: a lookup, an
//! external library, an iteration).
//!
//! Three steps:
//! 1. implement [`SeparableHamiltonian`] (potential, gradient and the Hessian-vector product, each taking an
//!    [`At`]: the time and lane parameters, which this autonomous model does not read; a model
//!    without second derivatives says why in `no_hessian_reason`);
//! 2. validate a configuration around it with [`RunSpec::with_model`] (everything but `[model]`
//!    is read from the config as usual; `[model] name` is the name the recording carries);
//! 3. run it: [`record`] integrates it with the engine and writes a regular chaoscope recording
//!    that `chaoscope analyze` reads; [`publish`] puts it on the iceoryx2 bus instead, for
//!    `chaoscope record` and `chaoscope monitor` in other processes.
//!
//! The model here is the Barbanis system, `V = (w1^2 q1^2 + w2^2 q2^2)/2 - eps q1 q2^2`, a
//! classic two-degree-of-freedom system with a divided phase space.

use std::path::Path;
use std::sync::Arc;

use chaoscope_analyzer::analysis::AnalysisOptions;
use chaoscope_analyzer::recording::analyze_file;
use chaoscope_analyzer::report::Report;
use chaoscope_analyzer::write::SampleWriter;
use chaoscope_dynamics::engine::Engine;
use chaoscope_dynamics::header::run_header;
use chaoscope_dynamics::model::{At, SeparableHamiltonian};
use chaoscope_dynamics::spec::RunSpec;
use chaoscope_producer::{self as publish, PublishOptions, PublishOutcome};
use chaoscope_schemas::config::RunConfig;

/// The Barbanis potential with frequencies `w1`, `w2` and coupling `eps`.
#[derive(Debug, Clone, Copy)]
pub struct Barbanis {
    pub w1: f64,
    pub w2: f64,
    pub eps: f64,
}

impl SeparableHamiltonian for Barbanis {
    fn name(&self) -> &str {
        "barbanis"
    }

    fn dof(&self) -> usize {
        2
    }

    fn potential(&self, q: &[f64], _at: At<'_>) -> f64 {
        let (x, y) = (q[0], q[1]);
        0.5 * (self.w1 * self.w1 * x * x + self.w2 * self.w2 * y * y) - self.eps * x * y * y
    }

    fn gradient(&self, q: &[f64], _at: At<'_>, out: &mut [f64]) {
        let (x, y) = (q[0], q[1]);
        out[0] = self.w1 * self.w1 * x - self.eps * y * y;
        out[1] = self.w2 * self.w2 * y - 2.0 * self.eps * x * y;
    }

    fn hessian_vector(&self, q: &[f64], _at: At<'_>, v: &[f64], out: &mut [f64]) {
        let (x, y) = (q[0], q[1]);
        out[0] = self.w1 * self.w1 * v[0] - 2.0 * self.eps * y * v[1];
        out[1] = -2.0 * self.eps * y * v[0] + (self.w2 * self.w2 - 2.0 * self.eps * x) * v[1];
    }
}

/// The example's run: everything but the model from a config.
pub const CONFIG: &str = r#"
[run]
name = "barbanis"
[model]
name = "barbanis"
[orbit]
q = [0.0, 0.2]
p = [0.0, 0.0]
energy = 0.06
solve_for = "p1"
[integrator]
method = "aba864"
h = 0.01
t_final = 500.0
[deviations]
k = 4
sets = 2
seed = 1
[[scheme]]
name = "vm"
method = "vm"
d0 = 1e-8
tau = 1.0
[[scheme]]
name = "mpm"
method = "mpm"
d0 = 1e-8
tau = 1.0
"#;

/// The config and the validated run of [`Barbanis`] with `w1 = 1.6, w2 = 0.9, eps = 0.08`.
pub fn run_spec(config_text: &str) -> anyhow::Result<(RunConfig, RunSpec)> {
    let config = RunConfig::from_toml(config_text)?;
    let model = Barbanis {
        w1: 1.6,
        w2: 0.9,
        eps: 0.08,
    };
    let spec = RunSpec::with_model(&config, Arc::new(model))?;
    Ok((config, spec))
}

/// Integrates the run and writes it to `out` as a chaoscope recording; returns the analysis of
/// that file (what `chaoscope analyze out` prints).
pub fn record(config: &RunConfig, spec: RunSpec, out: &Path) -> anyhow::Result<Report> {
    let header = run_header("barbanis", config, &spec);
    let mut writer = SampleWriter::create(out, &header)?;
    let mut engine = Engine::new(spec);
    while let Some(sample) = engine.next_sample()? {
        writer.write(&sample)?;
    }
    writer.finish("custom-model example")?;
    let (analysis, _) = analyze_file(out, &AnalysisOptions::default())?;
    Ok(analysis.report())
}

/// Publishes the run on the bus (start `chaoscope record --run barbanis --out FILE` first).
pub fn publish(config: &RunConfig, spec: RunSpec) -> anyhow::Result<PublishOutcome> {
    Ok(publish::publish(config, spec, &PublishOptions::default())?)
}
