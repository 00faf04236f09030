//! `chaoscope section`: Poincare sections.
//!
//! - `chaoscope section CONFIG --vary q2 --from A --to B --count N --plot DIR`: the energy
//!   surface's section of a separable Hamiltonian (crossings of `q_i = 0` with `p_i > 0`,
//!   where `p_i` is the config's `solve_for` momentum) of many orbits of the configured energy,
//!   started along one coordinate.
//! - `chaoscope section CONFIG --surface EXPR [--direction up|down|both] [--vary ...]`: any
//!   flow's (or Hamiltonian's) section through the surface `EXPR = 0`, of the config's orbit or
//!   of many started along one coordinate, crossings located to rounding
//!   (`chaoscope_dynamics::section::surface`).
//! - `chaoscope section CONFIG --sample-every T [--vary ...]`: the stroboscopic section of a
//!   periodically forced system, its state every `T` (the forcing's period, e.g. `2*pi/omega`)
//!   (`chaoscope_dynamics::section::stroboscopic`).
//!
//! The points written and drawn are the states with their periodic coordinates (`[model]
//! modulo`) wrapped into one period, and a plot axis that is a periodic coordinate spans it;
//! `--axes` and `--return-map` are expressions of that wrapped state.

use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::{Context, bail};
use chaoscope_analyzer::chart::{Chart, Line, Stroke, render};
use chaoscope_dynamics::section::crossings;
use chaoscope_dynamics::section::stroboscopic::{Stroboscopic, stroboscopic_samples};
use chaoscope_dynamics::section::surface::{
    Direction, OrbitEnd, ScalarFunction, Surface, SurfaceOrbit, coordinate_names, state_expression,
    surface_crossings,
};
use chaoscope_dynamics::spec::{RunSpec, parse_coordinate};
use chaoscope_os::{Leftover, Output, OutputOptions};
use chaoscope_schemas::config::{ConfigSource, RunConfig};
use chaoscope_schemas::run::SystemClass;

#[derive(clap::Args)]
pub struct Args {
    /// Run configuration: the system, its integrator and h; `t_final` bounds each orbit.
    /// Without --surface: a separable Hamiltonian with energy and `solve_for` (the crossing
    /// plane is q_i = 0 for `solve_for = "p_i"`).
    pub config: PathBuf,
    /// The section's surface EXPR = 0, an expression over the state's coordinates (x1..xD of a
    /// flow, q1..qN and p1..pN of a Hamiltonian) and the config's params, e.g. "x1" or
    /// "x3 - 27"; any flow or Hamiltonian, not a map.
    #[arg(long, allow_hyphen_values = true, conflicts_with = "sample_every")]
    pub surface: Option<String>,
    /// A stroboscopic section: the state every T time units, T a number or an expression of
    /// the config's params (e.g. "2*pi/omega", the period of a forcing cos(omega*t)), which
    /// must be a whole number of steps h; any flow or Hamiltonian. The points are the run's
    /// own states (no interpolation), at the times k*T.
    #[arg(long, visible_alias = "sample_every", allow_hyphen_values = true)]
    pub sample_every: Option<String>,
    /// With --sample-every: samples dropped at the start of each orbit (its transient).
    #[arg(long, requires = "sample_every", default_value_t = 0)]
    pub skip: usize,
    /// With --surface: which crossings count: `up` (EXPR increasing through 0), `down`, or
    /// `both`.
    #[arg(long, requires = "surface", value_parser = ["up", "down", "both"], default_value = "up")]
    pub direction: String,
    /// Coordinate along which orbits are started, from --from to --to (e.g. q2; with --surface
    /// any coordinate of the initial state, e.g. x2). Without --surface its conjugate momentum
    /// is the vertical axis of the plot; with --surface and no --vary, the config's orbit
    /// alone.
    #[arg(long, requires_all = ["from", "to"])]
    pub vary: Option<String>,
    /// The first orbit's value of the --vary coordinate.
    #[arg(long, allow_hyphen_values = true, requires = "vary")]
    pub from: Option<f64>,
    /// The last orbit's value of the --vary coordinate (orbits evenly spaced between).
    #[arg(long, allow_hyphen_values = true, requires = "vary")]
    pub to: Option<f64>,
    /// Orbits started from --from to --to (default 30).
    #[arg(long, requires = "vary")]
    pub count: Option<usize>,
    /// Crossings (or stroboscopic samples) kept per orbit.
    #[arg(long, default_value_t = 400)]
    pub crossings: usize,
    /// With --surface or --sample-every: the two quantities plotted, expressions of the state
    /// separated by a comma, e.g. `x2,x3`, "q1 - q2, p1 + p2" or "sin(x1), x2" (default: for a
    /// Hamiltonian q_j, p_j of the first degree of freedom the surface does not fix; otherwise
    /// the first two coordinates the surface does not fix, a surface fixing a coordinate when
    /// it reads that one alone; with --sample-every, q1, p1 or x1, x2). They read the state
    /// with its periodic coordinates (`[model] modulo`) wrapped.
    #[arg(long, allow_hyphen_values = true)]
    pub axes: Option<String>,
    /// With --surface or --sample-every, and --plot: also draw the first-return map of this
    /// coordinate or expression of the state (its value at crossing n + 1 against crossing n)
    /// as return-map.png / .svg.
    #[arg(long, requires = "plot", allow_hyphen_values = true)]
    pub return_map: Option<String>,
    /// Draw section.png / section.svg into DIR.
    #[arg(long)]
    pub plot: Option<PathBuf>,
    /// Write the crossings as CSV: without --surface, a row per crossing of the orbit number
    /// and the state q1..qN, p1..pN; with --surface or --sample-every, a header row, then the
    /// orbit number, the crossing's (sample's) time and the state.
    #[arg(long)]
    pub csv: Option<PathBuf>,
    /// Start even a section estimated to take more than a day or more memory than the machine
    /// has.
    #[arg(long)]
    pub force: bool,
}

pub fn main(args: Args) -> anyhow::Result<ExitCode> {
    // Nothing worth finalizing: a signal removes the unfinished outputs and ends at once.
    chaoscope_bus::signals::install(chaoscope_os::signals::Mode::Exit);
    let (config, _, source) = super::load_config(&args.config)?;
    for (name, v) in [("--from", args.from), ("--to", args.to)] {
        if v.is_some_and(|v| !v.is_finite()) {
            bail!("{name} must be a finite number");
        }
    }
    if args.surface.is_none() && args.sample_every.is_none() {
        for (flag, given) in [
            ("--axes", args.axes.is_some()),
            ("--return-map", args.return_map.is_some()),
        ] {
            if given {
                bail!("{flag} needs --surface or --sample-every");
            }
        }
        return energy_section(&args, config, &source);
    }
    surface_section(&args, config, &source)
}

/// The CSV output, if asked: it replaces an earlier table, never the config
/// (`chaoscope_os::output`).
fn csv_output(args: &Args) -> anyhow::Result<Option<Output>> {
    args.csv
        .as_ref()
        .map(|p| {
            Output::create(
                p,
                &OutputOptions {
                    replace: true,
                    inputs: vec![args.config.clone()],
                    leftover: Leftover::Discard,
                    ..Default::default()
                },
            )
        })
        .transpose()
        .map_err(Into::into)
}

/// The starting value of orbit `i` of `count` from `from` to `to` (computed, never accumulated).
fn start_value(from: f64, to: f64, i: usize, count: usize) -> f64 {
    if count > 1 {
        from + (to - from) * i as f64 / (count - 1) as f64
    } else {
        from
    }
}

/// Crossings of `q_i = 0` with `p_i > 0` of many orbits on the configured energy surface.
fn energy_section(
    args: &Args,
    mut config: RunConfig,
    source: &ConfigSource,
) -> anyhow::Result<ExitCode> {
    let (Some(vary_name), Some(from), Some(to)) = (&args.vary, args.from, args.to) else {
        bail!(
            "--vary, --from and --to are needed: the coordinate along which orbits are started \
             (or --surface for the section of any flow)"
        );
    };
    let count = args.count.unwrap_or(30);
    let solve = config.orbit.solve_for.clone().context(
        "the config needs orbit.solve_for (the momentum crossing the plane) and orbit.energy \
         (or use --surface)",
    )?;
    let base =
        RunSpec::from_config(&config).map_err(|e| super::invalid_config(source, "run", e))?;
    if base.system().separable().is_none() {
        bail!(
            "model.name: sections of an energy surface are drawn for separable Hamiltonians, \
             not for '{}'; --surface draws one of any flow",
            config.model.name()
        );
    }
    let n = base.dim() / 2;
    let Some((true, plane)) = parse_coordinate(&solve, n) else {
        bail!("orbit.solve_for must be a momentum, got {solve}");
    };
    let Some((false, vary)) = parse_coordinate(vary_name, n) else {
        bail!("--vary must be a position q1..q{n}, got {vary_name}");
    };
    if config.orbit.q.len() != n {
        bail!("--vary {vary_name}: the config's orbit.q must give the {n} positions");
    }
    let machine = super::machine();
    let estimate = chaoscope_dynamics::estimate::section(&base, count, args.crossings, &machine);
    super::check_estimate(&estimate, &machine, args.force, "section")?;
    let steps = base.total_steps();
    let mut lines = Vec::new();
    let csv_output = csv_output(args)?;
    let mut csv = match &csv_output {
        Some(out) => Some(std::io::BufWriter::new(out.file()?)),
        None => None,
    };
    let mut orbits = 0;
    for i in 0..count {
        config.orbit.q[vary] = start_value(from, to, i, count);
        // Starting points off the energy surface are skipped.
        let Ok(spec) = RunSpec::from_config(&config) else {
            continue;
        };
        // Written and drawn with the angles wrapped into their period.
        let pts: Vec<Vec<f64>> = crossings(&spec, spec.x0(), plane, steps, args.crossings)
            .iter()
            .map(|x| chaoscope_dynamics::indicators::periodic::wrap_state(base.periods(), x))
            .collect();
        if let Some(f) = csv.as_mut() {
            for p in &pts {
                let row: Vec<String> = p.iter().map(f64::to_string).collect();
                writeln!(f, "{orbits},{}", row.join(","))?;
            }
        }
        lines.push(Line {
            label: String::new(),
            points: pts.iter().map(|p| (p[vary], p[n + vary])).collect(),
            stroke: Stroke::Dots,
            color: orbits,
        });
        orbits += 1;
    }
    if let (Some(mut f), Some(out)) = (csv, csv_output) {
        f.flush()?;
        drop(f);
        out.commit()?;
    }
    let total: usize = lines.iter().map(|l| l.points.len()).sum();
    chaoscope_os::errln!("chaoscope section: {orbits} orbits, {total} crossings");
    if let Some(dir) = &args.plot {
        let title = format!(
            "Poincaré section q{} = 0, p{} > 0 at H = {}: {}",
            plane + 1,
            plane + 1,
            base.e0(),
            config.run.name.as_deref().unwrap_or(config.model.name()),
        );
        let period = base.periods().get(vary).copied().filter(|&p| p > 0.0);
        let chart = Chart {
            title,
            x_label: format!("q{}", vary + 1),
            y_label: format!("p{}", vary + 1),
            lines,
            x_range: period.map(|p| (0.0, p)),
            y_range: None,
        };
        draw_chart(dir, "section", chart, &args.config)?;
    }
    Ok(ExitCode::SUCCESS)
}

/// Draw `chart` into `dir/stem.png` and `.svg`.
fn draw_chart(dir: &Path, stem: &str, chart: Chart, config: &Path) -> anyhow::Result<()> {
    std::fs::create_dir_all(dir)?;
    render(&chart, &dir.join(stem), &[config.to_path_buf()])?;
    Ok(())
}

/// One plotted quantity of a section: an expression of the state (its angles wrapped), e.g.
/// `q1`, `q1 - q2` or `sin(x1)`.
struct Axis {
    /// The expression as written (trimmed): the axis label.
    label: String,
    function: ScalarFunction,
    /// The coordinate the expression is, when it is one name alone.
    coordinate: Option<usize>,
}

impl Axis {
    /// `source` compiled over the state of `spec`'s system; an error names `flag` and the
    /// expression, with a caret under the fault.
    fn new(
        spec: &RunSpec,
        model: &chaoscope_schemas::config::ModelConfig,
        names: &[String],
        flag: &str,
        source: &str,
    ) -> anyhow::Result<Self> {
        let label = source.trim().to_string();
        if label.is_empty() {
            bail!(
                "{flag}: an empty expression (give an expression of the state, e.g. {})",
                names[0]
            );
        }
        let function = state_expression(spec, model, flag, &label).map_err(|e| {
            // `--axes: line 1, column 5: ...` and the expression with a caret under the fault.
            let detail = e
                .strip_prefix(&format!("{flag}: "))
                .unwrap_or(&e)
                .to_string();
            anyhow::anyhow!(
                "{flag}: '{label}' is not a coordinate or an expression of the state ({}..{}): \
                 {detail}",
                names[0],
                names[names.len() - 1]
            )
        })?;
        if function.reads().is_empty() {
            bail!(
                "{flag} '{label}' reads no coordinate of the state ({}..{})",
                names[0],
                names[names.len() - 1]
            );
        }
        Ok(Self {
            coordinate: names.iter().position(|n| *n == label),
            label,
            function,
        })
    }

    /// The value at a (wrapped) state.
    fn value(&self, x: &[f64]) -> f64 {
        self.function.value(x)
    }

    /// The axis range: one whole period `[0, P)` for a periodic coordinate, else from the
    /// data.
    fn range(&self, periods: &[f64]) -> Option<(f64, f64)> {
        let p = periods.get(self.coordinate?).copied()?;
        (p > 0.0).then_some((0.0, p))
    }
}

/// The points whose both values are finite (an axis expression like `log(x1)` may not be
/// everywhere), counting those left out.
fn finite_points(points: Vec<(f64, f64)>, dropped: &mut usize) -> Vec<(f64, f64)> {
    let before = points.len();
    let kept: Vec<(f64, f64)> = points
        .into_iter()
        .filter(|(a, b)| a.is_finite() && b.is_finite())
        .collect();
    *dropped += before - kept.len();
    kept
}

/// `text` split at its commas outside parentheses (`atan2(q1, p1), p2` is two expressions).
fn split_top_level(text: &str) -> Vec<&str> {
    let mut parts = Vec::new();
    let (mut depth, mut start) = (0i64, 0);
    for (i, c) in text.char_indices() {
        match c {
            '(' | '[' => depth += 1,
            ')' | ']' => depth -= 1,
            ',' if depth == 0 => {
                parts.push(&text[start..i]);
                start = i + 1;
            }
            _ => {}
        }
    }
    parts.push(&text[start..]);
    parts
}

/// Where orbit `i` starts: the config's initial state with the `--vary` coordinate set (the
/// config is validated anew, so a Hamiltonian's `solve_for` momentum is solved again).
fn set_start(config: &mut RunConfig, canonical: bool, vary: usize, dim: usize, v: f64) {
    if canonical {
        let n = dim / 2;
        if vary < n {
            config.orbit.q[vary] = v;
        } else {
            config.orbit.p[vary - n] = v;
        }
    } else {
        config.orbit.x[vary] = v;
    }
}

/// How a section samples an orbit: crossings of a surface, or a stroboscope.
enum Sampling {
    Surface {
        surface: Box<Surface>,
        direction: Direction,
        source: String,
    },
    Every(Stroboscopic, String),
}

impl Sampling {
    fn orbit(&self, spec: &RunSpec, steps: u64, max: usize, skip: usize) -> SurfaceOrbit {
        match self {
            Sampling::Surface {
                surface, direction, ..
            } => surface_crossings(spec, surface, *direction, spec.x0(), steps, max),
            Sampling::Every(every, _) => {
                stroboscopic_samples(spec, *every, spec.x0(), steps, skip, max)
            }
        }
    }

    /// What the samples are, for titles: `x1 = 0 (up)`, `t = k * 2*pi/omega`.
    fn describe(&self) -> String {
        match self {
            Sampling::Surface {
                direction, source, ..
            } => format!("{source} = 0 ({})", direction.name()),
            Sampling::Every(_, period) => format!("t = k * {period}"),
        }
    }

    /// What a sample is, for messages: `crossing of x1 = 0 (up)`, `sample at t = k * T`.
    fn sample(&self) -> String {
        match self {
            Sampling::Surface { .. } => format!("crossing of {}", self.describe()),
            Sampling::Every(..) => format!("sample at {}", self.describe()),
        }
    }
}

/// The section of any flow through `EXPR = 0`, or its stroboscopic section.
fn surface_section(
    args: &Args,
    mut config: RunConfig,
    config_source: &ConfigSource,
) -> anyhow::Result<ExitCode> {
    if args.crossings == 0 || args.count == Some(0) {
        bail!("--crossings and --count must be at least 1");
    }
    let base = RunSpec::from_config(&config)
        .map_err(|e| super::invalid_config(config_source, "run", e))?;
    let one_line =
        |e: chaoscope_dynamics::spec::SpecError| anyhow::anyhow!("{}: {}", e.key, e.message);
    let sampling = match (&args.surface, &args.sample_every) {
        (Some(source), _) => Sampling::Surface {
            surface: Box::new(Surface::new(&base, &config.model, source).map_err(one_line)?),
            direction: Direction::from_name(&args.direction)
                .with_context(|| format!("--direction: unknown '{}'", args.direction))?,
            source: source.clone(),
        },
        (None, Some(period)) => Sampling::Every(
            Stroboscopic::new(&base, &config.model, period).map_err(one_line)?,
            period.trim().to_string(),
        ),
        (None, None) => unreachable!("main sends these to the energy section"),
    };
    let dim = base.dim();
    let canonical = base.system().kind() == SystemClass::Hamiltonian;
    let names = coordinate_names(&base);
    let known = || format!("{}..{}", names[0], names[dim - 1]);
    let coordinate = |flag: &str, name: &str| {
        names
            .iter()
            .position(|n| n == name.trim())
            .with_context(|| {
                let all = if canonical {
                    let n = dim / 2;
                    format!("q1..q{n}, p1..p{n}")
                } else {
                    known()
                };
                format!("{flag}: '{name}' is not a coordinate of the state ({all})")
            })
    };
    let default_axes = || match &sampling {
        Sampling::Surface { surface, .. } => surface.default_axes(canonical),
        Sampling::Every(..) if canonical => (0, dim / 2),
        Sampling::Every(..) => (0, 1.min(dim - 1)),
    };
    let (ax, ay) = match &args.axes {
        Some(spec) => {
            let parts = split_top_level(spec);
            let [a, b] = parts.as_slice() else {
                bail!(
                    "--axes '{spec}': give two expressions of the state separated by a comma,                      e.g. x2,x3 or \"q1 - q2, p1 + p2\""
                );
            };
            (
                Axis::new(&base, &config.model, &names, "--axes", a)?,
                Axis::new(&base, &config.model, &names, "--axes", b)?,
            )
        }
        None => {
            let (a, b) = default_axes();
            (
                Axis::new(&base, &config.model, &names, "--axes", &names[a])?,
                Axis::new(&base, &config.model, &names, "--axes", &names[b])?,
            )
        }
    };
    let return_map = args
        .return_map
        .as_deref()
        .map(|c| Axis::new(&base, &config.model, &names, "--return-map", c))
        .transpose()?;
    let periods = base.periods().to_vec();
    let mut dropped = 0usize;
    // The orbits: the config's own, or `count` started along `--vary`.
    let (vary, count) = match (&args.vary, args.from, args.to) {
        (Some(name), Some(_), Some(_)) => {
            let vary = coordinate("--vary", name)?;
            if let (Some(solve), Some(_)) = (&config.orbit.solve_for, config.orbit.energy)
                && solve == &names[vary]
            {
                bail!("--vary {name}: orbit.solve_for solves it from orbit.energy");
            }
            let have = if canonical {
                let n = dim / 2;
                if vary < n {
                    config.orbit.q.len() == n
                } else {
                    config.orbit.p.len() == n
                }
            } else {
                config.orbit.x.len() == dim
            };
            if !have {
                bail!(
                    "--vary {name}: the config's orbit must give the coordinate (orbit.{})",
                    if canonical { &names[vary][..1] } else { "x" }
                );
            }
            (Some(vary), args.count.unwrap_or(30))
        }
        _ => (None, 1),
    };
    let machine = super::machine();
    let estimate = chaoscope_dynamics::estimate::section(&base, count, args.crossings, &machine);
    super::check_estimate(&estimate, &machine, args.force, "section")?;
    let steps = base.total_steps();
    let csv_output = csv_output(args)?;
    let mut csv = match &csv_output {
        Some(out) => Some(std::io::BufWriter::new(out.file()?)),
        None => None,
    };
    if let Some(f) = csv.as_mut() {
        writeln!(f, "orbit,t,{}", names.join(","))?;
    }
    let (mut section, mut returns) = (Vec::new(), Vec::new());
    let (mut orbits, mut total, mut failed) = (0usize, 0usize, 0usize);
    for i in 0..count {
        let (spec, label) = match vary {
            Some(k) => {
                let v = start_value(args.from.unwrap_or(0.0), args.to.unwrap_or(0.0), i, count);
                set_start(&mut config, canonical, k, dim, v);
                let label = format!("{} = {v}", names[k]);
                match RunSpec::from_config(&config) {
                    Ok(spec) => (spec, label),
                    Err(e) => {
                        // A start off the energy surface, as in the energy section: skipped.
                        chaoscope_os::errln!("chaoscope section: warning: {label} skipped: {e}");
                        continue;
                    }
                }
            }
            None => (base.clone(), "the config's orbit".to_string()),
        };
        let orbit = sampling.orbit(&spec, steps, args.crossings, args.skip);
        match &orbit.end {
            OrbitEnd::Crossings | OrbitEnd::Horizon if orbit.crossings.is_empty() => {
                chaoscope_os::errln!(
                    "chaoscope section: warning: {label}: no {} up to t = {}",
                    sampling.sample(),
                    spec.t_final()
                );
            }
            OrbitEnd::Crossings | OrbitEnd::Horizon => {}
            OrbitEnd::NonFinite { t, why } => {
                failed += 1;
                chaoscope_os::errln!(
                    "chaoscope section: warning: {label} stopped at t = {t} after {} crossings: \
                     {why}",
                    orbit.crossings.len()
                );
            }
            OrbitEnd::Unlocated { t, error } => {
                failed += 1;
                chaoscope_os::errln!(
                    "chaoscope section: warning: {label} stopped after t = {t} after {} \
                     crossings: {error}",
                    orbit.crossings.len()
                );
            }
        }
        // What is written and drawn is the state with its angles wrapped into their period
        // (the integration itself never wraps it).
        let states: Vec<Vec<f64>> = orbit
            .crossings
            .iter()
            .map(|c| chaoscope_dynamics::indicators::periodic::wrap_state(&periods, &c.x))
            .collect();
        if let Some(f) = csv.as_mut() {
            for (c, x) in orbit.crossings.iter().zip(&states) {
                let row: Vec<String> = x.iter().map(f64::to_string).collect();
                writeln!(f, "{orbits},{},{}", c.t, row.join(","))?;
            }
        }
        let points: Vec<(f64, f64)> = states.iter().map(|x| (ax.value(x), ay.value(x))).collect();
        section.push(Line {
            label: String::new(),
            points: finite_points(points, &mut dropped),
            stroke: Stroke::Dots,
            color: orbits,
        });
        if let Some(r) = &return_map {
            let values: Vec<f64> = states.iter().map(|x| r.value(x)).collect();
            let points = values.iter().copied().zip(values.iter().copied().skip(1));
            returns.push(Line {
                label: String::new(),
                points: finite_points(points.collect(), &mut dropped),
                stroke: Stroke::Dots,
                color: orbits,
            });
        }
        total += orbit.crossings.len();
        orbits += 1;
    }
    if total == 0 {
        // Nothing to show: no output is left behind (the CSV's unfinished file is removed).
        let until = if failed > 0 {
            format!("before {failed} of {orbits} orbits stopped early (said above)")
        } else {
            format!("up to t = {}", base.t_final())
        };
        let what = match &sampling {
            Sampling::Surface { .. } => format!("crossing of the surface {}", sampling.describe()),
            Sampling::Every(..) => sampling.sample(),
        };
        bail!(
            "no {what} by {} {until}",
            if vary.is_some() {
                "any orbit"
            } else {
                "the orbit"
            },
        );
    }
    if let (Some(mut f), Some(out)) = (csv, csv_output) {
        f.flush()?;
        drop(f);
        out.commit()?;
    }
    chaoscope_os::errln!("chaoscope section: {orbits} orbits, {total} crossings");
    if dropped > 0 {
        chaoscope_os::errln!(
            "chaoscope section: warning: {dropped} points left out of the plots: an axis \
             expression is not finite there"
        );
    }
    if let Some(dir) = &args.plot {
        // The run's name where the config gives one ("rossler"), else the model's ("ode").
        let system = config.run.name.as_deref().unwrap_or(config.model.name());
        let title = format!("Poincaré section {}: {system}", sampling.describe());
        let chart = Chart {
            title,
            x_label: ax.label.clone(),
            y_label: ay.label.clone(),
            lines: section,
            x_range: ax.range(&periods),
            y_range: ay.range(&periods),
        };
        draw_chart(dir, "section", chart, &args.config)?;
        if let Some(r) = &return_map {
            let title = format!(
                "First-return map of {} on the section {}: {system}",
                r.label,
                sampling.describe()
            );
            let chart = Chart {
                title,
                x_label: format!("{} (crossing n)", r.label),
                y_label: format!("{} (crossing n + 1)", r.label),
                lines: returns,
                x_range: r.range(&periods),
                y_range: r.range(&periods),
            };
            draw_chart(dir, "return-map", chart, &args.config)?;
        }
    }
    if failed > 0 {
        bail!(
            "{failed} of {orbits} orbits stopped before t = {} (said above); the outputs hold \
             their crossings before that",
            base.t_final()
        );
    }
    Ok(ExitCode::SUCCESS)
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f64::consts::TAU;

    /// Two coupled pendulums, both angles periodic.
    fn coupled_pendulums() -> (RunSpec, RunConfig) {
        let config = RunConfig::from_toml(
            r#"
[model]
name = "hamiltonian"
n = 2
hamiltonian = "(p1^2 + p2^2)/2 - cos(q1) - cos(q2) + c*cos(q1 - q2)"
params = { c = 0.1 }
modulo = [6.283185307179586, 6.283185307179586, 0, 0]
[orbit]
x = [0.1, 0.2, 2.5, 0.0]
[integrator]
method = "dop853"
h = 0.05
t_final = 10.0
[deviations]
k = 1
sets = 1
seed = 1
[[scheme]]
name = "vm"
method = "vm"
d0 = 1e-8
tau = 1.0
"#,
        )
        .unwrap();
        (RunSpec::from_config(&config).unwrap(), config)
    }

    #[test]
    fn axes_are_expressions_of_the_wrapped_state() {
        let (spec, config) = coupled_pendulums();
        let names = coordinate_names(&spec);
        let axis = |source: &str| Axis::new(&spec, &config.model, &names, "--axes", source);
        // A state whose angles left their period: 7 = 2 pi + 0.717, -1 = -2 pi + 5.283.
        let x = chaoscope_dynamics::indicators::periodic::wrap_state(
            spec.periods(),
            &[7.0, -1.0, 0.3, -0.4],
        );
        let (q1, q2) = (7.0 - TAU, -1.0 + TAU);
        assert_eq!(x, vec![q1, q2, 0.3, -0.4]);
        // The compiled expressions compute what their operations compute on these values: a
        // difference and a sum exactly, a sine to its last bit or two (the compiled sine against
        // the platform's).
        assert_eq!(axis("q1 - q2").unwrap().value(&x), q1 - q2);
        assert_eq!(axis(" p1 + p2 ").unwrap().value(&x), 0.3 + -0.4);
        assert!((axis("sin(q1)").unwrap().value(&x) - q1.sin()).abs() <= 2.0 * f64::EPSILON);
        assert_eq!(axis("q2").unwrap().value(&x), q2);
        let coupling = axis("c*cos(q1 - q2)").unwrap().value(&x);
        assert!((coupling - 0.1 * (q1 - q2).cos()).abs() <= 1e-16);
        // A periodic coordinate's axis spans its period; anything else spans its data.
        assert_eq!(axis("q1").unwrap().range(spec.periods()), Some((0.0, TAU)));
        assert_eq!(axis("p1").unwrap().range(spec.periods()), None);
        assert_eq!(axis("q1 - q2").unwrap().range(spec.periods()), None);
        // A fault is named with the expression and a caret under it.
        let err = axis("q1 - qq2").err().unwrap().to_string();
        assert!(
            err.starts_with(
                "--axes: 'q1 - qq2' is not a coordinate or an expression of the state \
                 (q1..p2): line 1, column 6"
            ),
            "{err}"
        );
        assert!(err.ends_with("\n  q1 - qq2\n       ^^^"), "{err}");
        assert!(
            axis("2 * c")
                .err()
                .unwrap()
                .to_string()
                .contains("reads no coordinate")
        );
        assert!(axis("  ").is_err());
    }

    #[test]
    fn axes_split_at_commas_outside_parentheses() {
        assert_eq!(split_top_level("x2,x3"), vec!["x2", "x3"]);
        assert_eq!(
            split_top_level("atan2(q1, p1), max(p2, 0)"),
            vec!["atan2(q1, p1)", " max(p2, 0)"]
        );
        assert_eq!(split_top_level("x1"), vec!["x1"]);
        assert_eq!(split_top_level("x1,x2,x3").len(), 3);
    }
}
