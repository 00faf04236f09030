//! `chaoscope map CONFIG --out FILE.mcap [--png FILE.png] [--threads N] [--json] [--shard i/n]`:
//! a phase-space map, one chaos indicator per grid point, recorded to MCAP as points complete.
//!
//! The map is written into FILE.mcap.partial (locked while the map runs, so a second map of the
//! same FILE is refused) and renamed to FILE.mcap when it ends: complete, or stopped by
//! Ctrl-C/SIGTERM with the points done so far (`chaoscope_os::output`).
//!
//! Resuming: the points of FILE.mcap (a map stopped by a signal) and of FILE.mcap.partial (left
//! by a map that was killed or hit a full disk; every complete chunk counts), when they were
//! made from the same configuration and shard, are kept and only the missing ones are
//! computed. The new in-progress file holds all of them before it replaces the old one, so an
//! interruption at any moment loses nothing that was on disk. An existing FILE.mcap that
//! cannot be read as a map of this configuration and shard is refused and left as it is,
//! unless `--restart` says to discard it.
//!
//! Live: every point (resumed ones first) is also published on the iceoryx2 bus under the map's
//! name (`--name`, default: the output file's stem), for `chaoscope map-watch`. That stream is
//! lossy and never slows the map; if it cannot be opened the map runs without it.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::{Duration, Instant};

use anyhow::{Context, bail};
use chaoscope_analyzer::map_png;
use chaoscope_bus::frame::status;
use chaoscope_dynamics::batch::Isa;
use chaoscope_dynamics::estimate::RouteChoice;
use chaoscope_dynamics::map::{MapOptions, MapSpec, PointStatus, Shard, run_map};
use chaoscope_files::file::{Compression, FileOptions};
use chaoscope_files::map_file::{MapFile, read_map_file};
use chaoscope_os::termination::Termination;
use chaoscope_os::{Leftover, Output, OutputOptions};
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
    super::check_estimate(&estimate, &machine, args.force, "map")?;
    super::warn_unused_params("map", &config);
    super::warn_repeated_grid_lines("map", &config);
    let header = spec.header(args.shard);
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
    let mut output = Output::create(
        &args.out,
        &OutputOptions {
            // An existing FILE is this map's earlier part (checked below) or refused untouched.
            replace: true,
            create_dir: false,
            inputs: [&args.config, &args.png.clone().unwrap_or_default()]
                .into_iter()
                .filter(|p| p.as_os_str() != "-" && !p.as_os_str().is_empty())
                .cloned()
                .collect(),
            leftover: if args.restart {
                Leftover::Discard
            } else {
                Leftover::Resume
            },
            // The points of a map stopped by a failed write are resumed.
            keep_failed: true,
        },
    )?;
    let recorded = if args.restart {
        BTreeMap::new()
    } else {
        previous_points(&args.out, output.leftover(), &header)?
    };
    let name = args
        .name
        .clone()
        .unwrap_or_else(|| default_map_name(&args.out, args.shard));
    let mut live = match MapPublisher::open(&name, &header) {
        Ok(p) => Some(p),
        Err(e) => {
            chaoscope_os::errln!("chaoscope map: no live stream ({e}); computing the map anyway");
            None
        }
    };

    let options = FileOptions {
        compression: Compression::Zstd,
        chunk_size: 1 << 20,
    };
    let mut file = MapFile::create(output.start_fresh()?, &header, &options)?;
    for p in recorded.values() {
        file.write_point(p)?;
        if let Some(live) = &mut live {
            live.publish(p);
        }
    }
    file.close_chunk()?;
    // Every point on disk before is in the new file now: it replaces a killed map's.
    output.adopt_fresh()?;

    let todo: Vec<u64> = spec
        .shard_points(args.shard)
        .filter(|i| !recorded.contains_key(i))
        .collect();
    let bar = if args.no_progress {
        indicatif::ProgressBar::hidden()
    } else {
        indicatif::ProgressBar::new(todo.len() as u64)
    };
    bar.set_style(
        indicatif::ProgressStyle::with_template(
            "{spinner} [{elapsed_precise}] {wide_bar} {pos}/{len} points ({per_sec}, ETA {eta})",
        )
        .expect("valid template"),
    );
    let map_options = MapOptions {
        threads: args.threads,
        isa,
        termination: Some(termination.clone()),
        ..MapOptions::default()
    };
    let start = Instant::now();
    let cpu_start = chaoscope_os::cpu_time::process_seconds();
    let mut last_flush = Instant::now();
    let (mut computed, mut orbit_steps) = (0u64, 0u64);
    let mut new_points = Vec::new();
    let mut write_error = None;
    let mut interrupted = false;
    run_map(&spec, &todo, &map_options, |r| {
        let message = MapPoint::from(&r);
        if let Err(e) = file.write_point(&message) {
            write_error = Some(e);
            return false;
        }
        computed += 1;
        orbit_steps += r.orbit_steps;
        if let Some(live) = &mut live {
            live.publish(&message);
        }
        new_points.push(message);
        bar.inc(1);
        if last_flush.elapsed() >= args.flush_interval {
            if let Err(e) = file.close_chunk() {
                write_error = Some(e);
                return false;
            }
            last_flush = Instant::now();
        }
        if termination.requested() || args.stop_after.is_some_and(|n| computed >= n) {
            interrupted = true;
            return false;
        }
        true
    })?;
    // A signal stops the workers within a window, dropping the points in progress.
    interrupted |= termination.requested();
    bar.finish_and_clear();
    let written = match write_error {
        Some(e) => Err(e),
        None => file.close_chunk().and_then(|()| file.finish().map(drop)),
    };
    let finished = match written {
        Ok(()) => output.commit().map(drop).map_err(anyhow::Error::from),
        Err(e) => {
            let kept = output.keep();
            Err(anyhow::Error::from(e).context(format!(
                "writing {}; the points so far are in {} (run the same command again to resume)",
                args.out.display(),
                kept.display()
            )))
        }
    };
    if let Some(live) = &mut live {
        let code = match (&finished, interrupted) {
            (Err(_), _) => status::FAILED,
            (Ok(()), true) => status::INTERRUPTED,
            (Ok(()), false) => status::COMPLETED,
        };
        // Watchers get a moment to read the last points, unless Ctrl-C asked to stop now.
        let linger = if termination.requested() {
            Duration::ZERO
        } else {
            LIVE_LINGER
        };
        live.end(code, linger);
    }
    finished?;
    let seconds = start.elapsed().as_secs_f64();
    let cpu_seconds = chaoscope_os::cpu_time::process_seconds() - cpu_start;

    let mut all: Vec<MapPoint> = recorded.into_values().chain(new_points).collect();
    all.sort_by_key(|p| p.index);
    let count = |s: PointStatus| {
        all.iter()
            .filter(|p| p.status == MapPoint::from_status(s))
            .count()
    };
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
                "live_stream": live.as_ref().map(|l| l.name()),
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
        map_png::render_png(&header, &all, png, &inputs).map_err(anyhow::Error::msg)?;
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

/// Points already recorded for this map and shard, from the output file (a map stopped by a
/// signal) and from the in-progress file a killed map left (`leftover`). A file that cannot be
/// read as a map of this configuration and shard is refused, never discarded (that takes
/// `--restart`).
fn previous_points(
    out: &Path,
    leftover: Option<&Path>,
    header: &MapHeader,
) -> anyhow::Result<BTreeMap<u64, MapPoint>> {
    let shard = Shard {
        index: header.shard_index,
        count: header.shard_count,
    };
    let mut points = BTreeMap::new();
    let files = leftover
        .map(|p| (p, true))
        .into_iter()
        .chain(out.exists().then_some((out, false)));
    for (path, is_leftover) in files {
        let contents = read_map_file(path)?;
        if let Some(d) = &contents.damaged {
            chaoscope_os::errln!(
                "chaoscope map: {} is damaged or cut short ({d}); {} points before that are \
                 readable",
                path.display(),
                contents.points.len()
            );
        }
        let Some(h) = contents.header else {
            if is_leftover {
                // Killed before it wrote its first chunk: nothing in it.
                continue;
            }
            bail!(
                "{} holds no readable map header (not a `chaoscope map` recording, or its first \
                 chunk is damaged); it was left untouched. Pass --restart to overwrite it or \
                 choose another --out",
                path.display()
            );
        };
        if let Some(why) = table_difference(&h.config_toml, &header.config_toml) {
            bail!(
                "{} was computed with another table: {why}; pass --restart to recompute it \
                 with the table as it is now, or restore the table",
                path.display()
            );
        }
        if h.config_toml != header.config_toml
            || (h.shard_index, h.shard_count) != (header.shard_index, header.shard_count)
        {
            bail!(
                "{} holds a different map (configuration or shard differ); pass --restart to \
                 overwrite it or choose another --out",
                path.display()
            );
        }
        for p in contents.points {
            if p.index >= header.grid_points || !shard.contains(p.index) {
                bail!("{}: point {} is not in its shard", path.display(), p.index);
            }
            // Its values are this map's own (this configuration's header) or the file is
            // refused: they go into the new file and the PNG as they are.
            chaoscope_files::map_file::check_point(header, &p).map_err(|e| {
                anyhow::anyhow!(
                    "{}: {e}; pass --restart to recompute it or choose another --out",
                    path.display()
                )
            })?;
            points.insert(p.index, p);
        }
    }
    Ok(points)
}

/// A table whose content differs between a map file's recorded configuration and this one
/// (both carry each table's SHA-256), described for the user; `None` if every table agrees.
fn table_difference(recorded: &str, now: &str) -> Option<String> {
    let recorded = chaoscope_schemas::config::RunConfig::from_toml(recorded).ok()?;
    let now = chaoscope_schemas::config::RunConfig::from_toml(now).ok()?;
    now.model.tables()?.iter().find_map(|(name, table)| {
        let (was, is) = (recorded.model.tables()?.get(name)?.spec(), table.spec());
        match (&was.sha256, &is.sha256) {
            (Some(a), Some(b)) if a != b => Some(format!(
                "table '{name}' ({}) has SHA-256 {b}, the map was made with {a}",
                is.file
            )),
            _ => None,
        }
    })
}

/// Protobuf status of a point status.
trait FromStatus {
    fn from_status(s: PointStatus) -> i32;
}

impl FromStatus for MapPoint {
    fn from_status(s: PointStatus) -> i32 {
        use chaoscope_schemas::proto::map_point::Status;
        (match s {
            PointStatus::Ok => Status::Ok,
            PointStatus::OutsideEnergySurface => Status::OutsideEnergySurface,
            PointStatus::Escaped => Status::Escaped,
        }) as i32
    }
}
