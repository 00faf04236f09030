//! `chaoscope section`: Poincare sections.
//!
//! - `chaoscope section CONFIG --vary q2 --from A --to B --count N --plot DIR`: the energy
//!   surface's section of a separable Hamiltonian (crossings of `q_i = 0` with `p_i > 0`,
//!   where `p_i` is the config's `solve_for` momentum) of many orbits of the configured energy,
//!   started along one coordinate.
//! - `chaoscope section CONFIG --surface EXPR [--direction up|down|both] [--vary ...]`: any
//!   flow's (or Hamiltonian's) section through the surface `EXPR = 0`, of the config's orbit or
//!   of many started along one coordinate, crossings located to rounding
//!   (`chaoscope_producer::section::surface`).
//! - `chaoscope section CONFIG --sample-every T [--vary ...]`: the stroboscopic section of a
//!   periodically forced system, its state every `T` (the forcing's period, e.g. `2*pi/omega`)
//!   (`chaoscope_producer::section::stroboscopic`).

use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::{Context, bail};
use chaoscope_analyzer::chart::{Chart, Line, Stroke, render};
use chaoscope_os::{Leftover, Output, OutputOptions};
use chaoscope_producer::section::crossings;
use chaoscope_producer::section::stroboscopic::{Stroboscopic, stroboscopic_samples};
use chaoscope_producer::section::surface::{
    Direction, OrbitEnd, Surface, SurfaceOrbit, coordinate_names, surface_crossings,
};
use chaoscope_producer::spec::{RunSpec, parse_coordinate};
use chaoscope_schemas::config::{ConfigSource, RunConfig};
use chaoscope_schemas::run::SystemKind;

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
    /// With --surface or --sample-every: the two coordinates plotted, e.g. `x2,x3` (default:
    /// for a Hamiltonian q_j, p_j of the first degree of freedom the surface does not fix;
    /// otherwise the first two coordinates the surface does not fix, a surface fixing a
    /// coordinate when it reads that one alone; with --sample-every, q1, p1 or x1, x2).
    #[arg(long)]
    pub axes: Option<String>,
    /// With --surface or --sample-every, and --plot: also draw the first-return map of this
    /// coordinate (its value at crossing n + 1 against crossing n) as return-map.png / .svg.
    #[arg(long, requires = "plot")]
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
    chaoscope_os::signals::install(chaoscope_os::signals::Mode::Exit);
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
    let estimate = chaoscope_producer::estimate::section(&base, count, args.crossings, &machine);
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
        let pts = crossings(&spec, spec.x0(), plane, steps, args.crossings);
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
            "{}: section q{} = 0, p{} > 0, H = {}",
            config.model.name(),
            plane + 1,
            plane + 1,
            base.e0()
        );
        let labels = (format!("q{}", vary + 1), format!("p{}", vary + 1));
        draw(dir, "section", title, labels, lines, &args.config)?;
    }
    Ok(ExitCode::SUCCESS)
}

/// Draw `lines` as dots into `dir/stem.png` and `.svg`.
fn draw(
    dir: &Path,
    stem: &str,
    title: String,
    (x_label, y_label): (String, String),
    lines: Vec<Line>,
    config: &Path,
) -> anyhow::Result<()> {
    std::fs::create_dir_all(dir)?;
    let chart = Chart {
        title,
        x_label,
        y_label,
        lines,
        ..Default::default()
    };
    render(&chart, &dir.join(stem), &[config.to_path_buf()])?;
    Ok(())
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
        |e: chaoscope_producer::spec::SpecError| anyhow::anyhow!("{}: {}", e.key, e.message);
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
    let canonical = base.system().kind() == SystemKind::Hamiltonian;
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
    let (ax, ay) = match &args.axes {
        Some(spec) => {
            let Some((a, b)) = spec.split_once(',') else {
                bail!("--axes: give two coordinates separated by a comma, e.g. x2,x3");
            };
            (coordinate("--axes", a)?, coordinate("--axes", b)?)
        }
        None => match &sampling {
            Sampling::Surface { surface, .. } => surface.default_axes(canonical),
            Sampling::Every(..) if canonical => (0, dim / 2),
            Sampling::Every(..) => (0, 1.min(dim - 1)),
        },
    };
    let return_map = args
        .return_map
        .as_deref()
        .map(|c| coordinate("--return-map", c))
        .transpose()?;
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
    let estimate = chaoscope_producer::estimate::section(&base, count, args.crossings, &machine);
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
        if let Some(f) = csv.as_mut() {
            for c in &orbit.crossings {
                let row: Vec<String> = c.x.iter().map(f64::to_string).collect();
                writeln!(f, "{orbits},{},{}", c.t, row.join(","))?;
            }
        }
        let at = |k: usize| orbit.crossings.iter().map(move |c| c.x[k]);
        section.push(Line {
            label: String::new(),
            points: at(ax).zip(at(ay)).collect(),
            stroke: Stroke::Dots,
            color: orbits,
        });
        if let Some(k) = return_map {
            returns.push(Line {
                label: String::new(),
                points: at(k).zip(at(k).skip(1)).collect(),
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
    if let Some(dir) = &args.plot {
        // The run's name where the config gives one ("rossler"), else the model's ("ode").
        let system = config.run.name.as_deref().unwrap_or(config.model.name());
        let title = format!("{system}: section {}", sampling.describe());
        let labels = (names[ax].clone(), names[ay].clone());
        draw(dir, "section", title, labels, section, &args.config)?;
        if let Some(k) = return_map {
            let title = format!(
                "{system}: first-return map of {} on {}",
                names[k],
                sampling.describe()
            );
            let labels = (
                format!("{} (crossing n)", names[k]),
                format!("{} (crossing n + 1)", names[k]),
            );
            draw(dir, "return-map", title, labels, returns, &args.config)?;
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
