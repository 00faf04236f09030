//! `chaoscope map CONFIG --out FILE.mcap [--png FILE.png] [--threads N] [--json] [--shard i/n]`:
//! a phase-space map, one chaos indicator per grid point, recorded to MCAP as points complete.
//!
//! The file is written and resumed as `chaoscope_app::map` says: an existing FILE.mcap (or
//! the FILE.mcap.partial of a killed map) of the same configuration and shard is resumed;
//! anything else there is refused untouched unless `--restart`.
//!
//! Live: every point (resumed ones first) is also published on the iceoryx2 bus under the map's
//! name (`--name`, default: the output file's stem), for `chaoscope map-watch`. That stream is
//! lossy and never slows the map; if it cannot be opened the map runs without it.

use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::{Duration, Instant};

use anyhow::{Context, bail};
use chaoscope_analyzer::map_png;
use chaoscope_app::map::{MapFileError, MapJob, MapObserver, map_to_file, resumable_points};
use chaoscope_bus::frame::status;
use chaoscope_dynamics::batch::Isa;
use chaoscope_dynamics::estimate::RouteChoice;
use chaoscope_dynamics::map::{MapOptions, MapSpec, PointStatus, Shard};
use chaoscope_os::OutputOptions;
use chaoscope_os::termination::Termination;
use chaoscope_producer::map::{MapPublisher, default_map_name};
use chaoscope_schemas::proto::{MapHeader, MapPoint};

/// Longest wait, once the map is done, for live watchers to read its last points.
const LIVE_LINGER: Duration = Duration::from_secs(1);

#[derive(clap::Args)]
pub struct Args {
    /// Run configuration (TOML) with a [map] section; `-` reads it from stdin.
    pub config: PathBuf,
    /// Output MCAP file; resumed when it exists (same config and shard).
    #[arg(long)]
    pub out: PathBuf,
    /// Also render the map as a PNG colour map.
    #[arg(long)]
    pub png: Option<PathBuf>,
    /// Worker threads (default: one per core).
    #[arg(long)]
    pub threads: Option<usize>,
    /// Print a JSON summary on stdout.
    #[arg(long)]
    pub json: bool,
    /// Compute only the points with index % n == i (for job arrays; join with `merge`).
    #[arg(long, default_value = "0/1")]
    pub shard: Shard,
    /// Discard an existing output file instead of resuming it. Without it, an output file that
    /// is not a readable map of this config and shard (another map, another MCAP file, a
    /// damaged first chunk) is refused and left untouched.
    #[arg(long)]
    pub restart: bool,
    /// No progress bar.
    #[arg(long)]
    pub no_progress: bool,
    /// Start even a map estimated to take more than a day or more memory than the machine has.
    #[arg(long)]
    pub force: bool,
    /// Force the kernel's instruction set (avx512, avx2, portable); default: detected.
    #[arg(long)]
    pub isa: Option<String>,
    /// Close the open MCAP chunk at least this often, in seconds (what a kill can lose).
    #[arg(long, default_value = "2", value_parser = super::parse_seconds)]
    pub flush_interval: Duration,
    /// Name of the map's live stream on the bus (default: the output file's stem, plus the
    /// shard); follow it with `chaoscope map-watch NAME`.
    #[arg(long)]
    pub name: Option<String>,
    /// Stop as if interrupted after this many new points (tests of resuming).
    #[arg(long, hide = true)]
    pub stop_after: Option<u64>,
}

pub fn main(args: Args) -> anyhow::Result<ExitCode> {
    let (config, _, source) = super::load_config(&args.config)?;
    let mut spec =
        MapSpec::from_config(&config).map_err(|e| super::invalid_config(&source, "map", e))?;
    let machine = super::machine();
    let threads = args.threads.unwrap_or(machine.cores);
    let (total, count) = (spec.grid_points(), u64::from(args.shard.count));
    let points = total / count + u64::from(total % count > u64::from(args.shard.index));
    let isa = match &args.isa {
        None => Isa::detect(),
        Some(name) => {
            let isa = Isa::from_name(name)
                .with_context(|| format!("unknown --isa {name:?} (avx512, avx2, portable)"))?;
            if !isa.available() {
                bail!("this CPU does not support {name}");
            }
            isa
        }
    };
    // Threads beyond the cores share them: the estimate spreads the work over the fewer. A
    // map that names no route takes the cheaper of two that give its numbers.
    let (estimate, route_choice) = chaoscope_dynamics::estimate::map_choosing_route(
        &mut spec,
        points,
        &machine,
        threads.min(machine.cores),
        isa,
    );
    // A resumed map computes only the points its earlier file lacks.
    let header = spec.header(args.shard);
    let resumable = if args.restart {
        0
    } else {
        resumable_points(&args.out, &header)
    };
    let todo = points.saturating_sub(resumable);
    let estimate = estimate.narrowed_to(todo, points);
    super::check_estimate(&estimate, &machine, args.force, "map")?;
    super::warn_unused_params("map", &config);
    super::warn_repeated_grid_lines("map", &config);
    chaoscope_bus::signals::install(chaoscope_os::signals::Mode::Finish);
    let termination = Termination::new();

    // The colour map is drawn at the end: what would refuse it is said now.
    if let Some(png) = &args.png {
        let inputs = vec![args.out.clone(), args.config.clone()];
        chaoscope_os::output::check_target(
            png,
            &OutputOptions {
                replace: true,
                inputs,
                ..Default::default()
            },
        )?;
    }
    let name = args
        .name
        .clone()
        .unwrap_or_else(|| default_map_name(&args.out, args.shard));
    let bar = if args.no_progress {
        indicatif::ProgressBar::hidden()
    } else {
        indicatif::ProgressBar::new(0)
    };
    bar.set_style(
        indicatif::ProgressStyle::with_template(
            "{spinner} [{elapsed_precise}] {wide_bar} {pos}/{len} points ({per_sec}, ETA {eta})",
        )
        .expect("valid template"),
    );
    let job = MapJob {
        spec: &spec,
        shard: args.shard,
        out: &args.out,
        restart: args.restart,
        // An existing FILE is this map's earlier part (checked before anything is computed)
        // or refused untouched.
        replace: true,
        create_dir: false,
        inputs: [&args.config, &args.png.clone().unwrap_or_default()]
            .into_iter()
            .filter(|p| p.as_os_str() != "-" && !p.as_os_str().is_empty())
            .cloned()
            .collect(),
        flush_interval: args.flush_interval,
        options: MapOptions {
            threads: args.threads,
            isa,
            termination: Some(termination.clone()),
            ..MapOptions::default()
        },
    };
    let mut watch = Watch {
        name,
        header: header.clone(),
        live: None,
        opened: false,
        bar,
        stop_after: args.stop_after,
        computed: 0,
    };
    let start = Instant::now();
    let cpu_start = chaoscope_os::cpu_time::process_seconds();
    let finished = map_to_file(&job, &mut watch);
    watch.bar.finish_and_clear();
    if let Some(live) = &mut watch.live {
        let code = match &finished {
            Err(_) => status::FAILED,
            Ok(outcome) if outcome.interrupted => status::INTERRUPTED,
            Ok(_) => status::COMPLETED,
        };
        // Watchers get a moment to read the last points, unless Ctrl-C asked to stop now.
        let linger = if termination.requested() {
            Duration::ZERO
        } else {
            LIVE_LINGER
        };
        live.end(code, linger);
    }
    let outcome = finished.map_err(|e| match e {
        MapFileError::Refused(why) => {
            anyhow::anyhow!("{why}. Pass --restart to overwrite it or choose another --out")
        }
        e => e.into(),
    })?;
    let seconds = start.elapsed().as_secs_f64();
    let cpu_seconds = chaoscope_os::cpu_time::process_seconds() - cpu_start;

    let (all, computed, interrupted) = (&outcome.points, outcome.computed, outcome.interrupted);
    let orbit_steps = outcome.orbit_steps;
    let count = |s: PointStatus| outcome.count(s);
    let expected = spec.shard_points(args.shard).count();
    if args.json {
        chaoscope_os::outln!(
            "{}",
            serde_json::json!({
                "out": args.out,
                "shard": args.shard.to_string(),
                "indicator": spec.indicator.name(),
                "method": header.method,
                "route": spec.route.name(),
                "route_reason": route_reason(&spec, route_choice.as_ref()),
                "estimated_seconds": estimate.seconds,
                "estimated_points": todo,
                "points": all.len(),
                "points_expected": expected,
                "computed": computed,
                "resumed": all.len() as u64 - computed,
                "outside_energy_surface": count(PointStatus::OutsideEnergySurface),
                "escaped": count(PointStatus::Escaped),
                "complete": all.len() == expected,
                "interrupted": interrupted,
                "isa": isa.name(),
                "threads": args.threads.unwrap_or_else(rayon_threads),
                "seconds": seconds,
                "cpu_seconds": cpu_seconds,
                "orbit_steps": orbit_steps,
                "orbit_steps_per_cpu_second": orbit_steps as f64 / cpu_seconds.max(1e-9),
                "live_stream": watch.live.as_ref().map(|l| l.name()),
                "expression_kernels": expression_kernels(&spec),
            })
        )?;
    }
    if !args.json {
        chaoscope_os::errln!(
            "chaoscope map: {computed} points in {} (estimated {}, {} CPU); {}",
            super::seconds(seconds),
            super::seconds(estimate.seconds),
            super::seconds(cpu_seconds),
            route_reason(&spec, route_choice.as_ref())
        );
    }
    if interrupted {
        chaoscope_os::errln!(
            "chaoscope map: interrupted with {} of {expected} points in {}; run the same \
             command again to resume",
            all.len(),
            args.out.display()
        );
        return Ok(super::exit_interrupted());
    }
    if let Some(png) = &args.png {
        let inputs = vec![args.out.clone(), args.config.clone()];
        map_png::render_png(&header, all, png, &inputs).map_err(anyhow::Error::msg)?;
    }
    Ok(ExitCode::SUCCESS)
}

/// Which route the map runs and why: named by the configuration, chosen by cost between two
/// that give the same numbers, or the only one that gives them.
pub fn route_reason(spec: &MapSpec, choice: Option<&RouteChoice>) -> String {
    match choice {
        Some(c) => c.reason(),
        None if spec.route_named => {
            format!("route {} (named by the configuration)", spec.route.name())
        }
        None => format!(
            "route {} (the only route that gives this map's numbers)",
            spec.route.name()
        ),
    }
}

/// For a user-written potential, which step kernels the batched kernel ran: the C build's state
/// when the map ended (a build still running is cancelled as the map exits), how long after
/// the first batched call the C kernels were ready, and the kernel calls (windows times
/// batches) each backend ran. `null` for the built-in models.
fn expression_kernels(spec: &MapSpec) -> serde_json::Value {
    let Some(model) = spec.expression_model() else {
        return serde_json::Value::Null;
    };
    let status = model.c_step_status();
    serde_json::json!({
        "c_build": status.state.name(),
        "c_unavailable": status.reason,
        "c_ready_after_seconds": status.ready_after.map(|d| d.as_secs_f64()),
        "cranelift_calls": status.cranelift_calls,
        "c_calls": status.c_calls,
    })
}

fn rayon_threads() -> usize {
    std::thread::available_parallelism()
        .map(|n| n.get())
        .unwrap_or(1)
}

/// What the command shows of a map as it runs: the live stream, the progress bar, and the stop
/// after `--stop-after` new points.
struct Watch {
    name: String,
    header: MapHeader,
    live: Option<MapPublisher>,
    /// The stream is opened once the map is known to run (its file locked, an earlier part
    /// accepted): a refused map never shows up to watchers.
    opened: bool,
    bar: indicatif::ProgressBar,
    stop_after: Option<u64>,
    computed: u64,
}

impl Watch {
    fn live(&mut self) -> Option<&mut MapPublisher> {
        if !self.opened {
            self.opened = true;
            self.live = match MapPublisher::open(&self.name, &self.header) {
                Ok(p) => Some(p),
                Err(e) => {
                    chaoscope_os::errln!(
                        "chaoscope map: no live stream ({e}); computing the map anyway"
                    );
                    None
                }
            };
        }
        self.live.as_mut()
    }
}

impl MapObserver for Watch {
    fn damaged(&mut self, path: &Path, why: &str, readable: usize) {
        chaoscope_os::errln!(
            "chaoscope map: {} is damaged or cut short ({why}); {readable} points before that \
             are readable",
            path.display()
        );
    }

    fn resumed(&mut self, point: &MapPoint) {
        if let Some(live) = self.live() {
            live.publish(point);
        }
    }

    fn started(&mut self, todo: usize) {
        self.live();
        self.bar.set_length(todo as u64);
    }

    fn computed(&mut self, point: &MapPoint, _orbit_steps: u64) -> bool {
        self.computed += 1;
        if let Some(live) = &mut self.live {
            live.publish(point);
        }
        self.bar.inc(1);
        self.stop_after.is_none_or(|n| self.computed < n)
    }
}
