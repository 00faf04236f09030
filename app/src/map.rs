//! A phase-space map computed to a map file (`chaoscope map`, Python's `chaoscope.map`).
//!
//! The map is written into `FILE.partial` (locked while the map runs, so a second map of the
//! same FILE is refused) and renamed to FILE when it ends: complete, or stopped with the points
//! done so far (`chaoscope_os::output`).
//!
//! Resuming: the points of FILE (a map that was stopped) and of `FILE.partial` (left by a map
//! that was killed or hit a full disk; every complete chunk counts), when they were made from
//! the same configuration and shard, are kept and only the missing ones are computed. The new
//! in-progress file holds all of them before it replaces the old one, so an interruption at any
//! moment loses nothing that was on disk. An existing FILE that cannot be read as a map of this
//! configuration and shard is refused and left as it is, unless `restart` says to discard it.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use chaoscope_dynamics::map::{MapOptions, MapSpec, PointStatus, Shard, run_map};
use chaoscope_files::file::{Compression, FileOptions, error_chain};
use chaoscope_files::map_file::{MapFile, check_point, read_map_file};
use chaoscope_files::scan::FileError;
use chaoscope_os::{Leftover, Output, OutputError, OutputOptions};
use chaoscope_schemas::config::RunConfig;
use chaoscope_schemas::proto::{MapHeader, MapPoint};

/// The chunk size of map files: a chunk is closed once it holds this many bytes.
const CHUNK_SIZE: u64 = 1 << 20;

/// Longest file a map killed before its first chunk was whole can have left: the file's start,
/// and a first chunk of at most about [`CHUNK_SIZE`] (closed after the point that passes it).
const FIRST_CHUNK_BOUND: u64 = 2 * CHUNK_SIZE;

/// What to compute and where: the map of `spec`'s `shard` into `out`.
pub struct MapJob<'a> {
    pub spec: &'a MapSpec,
    pub shard: Shard,
    pub out: &'a Path,
    /// Discard an existing output instead of resuming it.
    pub restart: bool,
    /// The finished map may replace a file at `out`: the command's own earlier part of this
    /// map, which it resumes; without it a file that appears at `out` meanwhile (or a link
    /// there) is refused when the map ends, its points kept in `out.partial`.
    pub replace: bool,
    /// Create `out`'s directory when it is missing.
    pub create_dir: bool,
    /// Files the map reads (its configuration, ...), which `out` must not be.
    pub inputs: Vec<PathBuf>,
    /// Close the open chunk at least this often: what a kill can lose.
    pub flush_interval: Duration,
    /// Threads, instruction set and the stop flag of the computation.
    pub options: MapOptions,
}

/// What a map to a file reports along the way. Every method has a default that does nothing.
pub trait MapObserver {
    /// An earlier file damaged or cut short (`why`): its first `readable` points are resumed.
    fn damaged(&mut self, _path: &Path, _why: &str, _readable: usize) {}
    /// A point of an earlier file, carried into the new one before any point is computed.
    fn resumed(&mut self, _point: &MapPoint) {}
    /// The computation starts with `todo` points.
    fn started(&mut self, _todo: usize) {}
    /// A point computed and written; `false` stops the map as if interrupted.
    fn computed(&mut self, _point: &MapPoint, _orbit_steps: u64) -> bool {
        true
    }
}

/// The observer of a map nobody watches.
impl MapObserver for () {}

/// How a map to a file ended.
pub struct MapOutcome {
    /// Every point in the file, resumed and computed, by index.
    pub points: Vec<MapPoint>,
    /// Points computed by this call.
    pub computed: u64,
    /// Steps of the reference orbits they took.
    pub orbit_steps: u64,
    /// Stopped by the stop flag or the observer before every point was computed.
    pub interrupted: bool,
}

impl MapOutcome {
    /// Points of the file with this status.
    pub fn count(&self, status: PointStatus) -> usize {
        let code = status_code(status);
        self.points.iter().filter(|p| p.status == code).count()
    }
}

#[derive(Debug, thiserror::Error)]
pub enum MapFileError {
    #[error(transparent)]
    Output(#[from] OutputError),
    /// An earlier file could not be read.
    #[error(transparent)]
    Read(#[from] FileError),
    /// An existing file this map cannot resume, left untouched (the caller says how to replace
    /// it).
    #[error("{0}")]
    Refused(String),
    #[error("starting the map's threads: {0}")]
    Threads(#[from] rayon::ThreadPoolBuildError),
    /// A write failed; what was written so far is kept (`kept`) for the next map of this file
    /// to resume, once the computation has started.
    #[error("writing {}: {error}{}", out.display(), kept_note(kept.as_deref()))]
    Write {
        out: PathBuf,
        kept: Option<PathBuf>,
        error: String,
    },
}

fn kept_note(kept: Option<&Path>) -> String {
    kept.map(|k| {
        format!(
            "; the points so far are in {} (computing the same map again resumes them)",
            k.display()
        )
    })
    .unwrap_or_default()
}

/// Computes `job`'s map into its file, resuming what an earlier map of the same configuration
/// and shard left; `observer` sees every point. A stopped map is a valid file with the points
/// done so far.
pub fn map_to_file(
    job: &MapJob<'_>,
    observer: &mut impl MapObserver,
) -> Result<MapOutcome, MapFileError> {
    let header = job.spec.header(job.shard);
    let mut output = Output::create(
        job.out,
        &OutputOptions {
            replace: job.replace,
            create_dir: job.create_dir,
            inputs: job.inputs.clone(),
            leftover: if job.restart {
                Leftover::Discard
            } else {
                Leftover::Resume
            },
            // The points of a map stopped by a failed write are resumed.
            keep_failed: true,
        },
    )?;
    let recorded = if job.restart {
        BTreeMap::new()
    } else {
        previous_points(job.out, output.leftover(), &header, observer)?
    };
    let file_options = FileOptions {
        compression: Compression::Zstd,
        chunk_size: CHUNK_SIZE,
    };
    // Until the fresh file is adopted, a failed write leaves what was on disk as it was.
    let unchanged = |e: mcap::McapError| MapFileError::Write {
        out: job.out.to_path_buf(),
        kept: None,
        error: error_chain(&e),
    };
    let mut file =
        MapFile::create(output.start_fresh()?, &header, &file_options).map_err(unchanged)?;
    for p in recorded.values() {
        file.write_point(p).map_err(unchanged)?;
        observer.resumed(p);
    }
    file.close_chunk().map_err(unchanged)?;
    // Every point on disk before is in the new file now: it replaces a killed map's.
    output.adopt_fresh()?;

    let todo: Vec<u64> = job
        .spec
        .shard_points(job.shard)
        .filter(|i| !recorded.contains_key(i))
        .collect();
    observer.started(todo.len());
    let mut last_flush = Instant::now();
    let (mut computed, mut orbit_steps) = (0u64, 0u64);
    let mut new_points = Vec::new();
    let mut write_error = None;
    let mut interrupted = false;
    run_map(job.spec, &todo, &job.options, |r| {
        let message = MapPoint::from(&r);
        if let Err(e) = file.write_point(&message) {
            write_error = Some(e);
            return false;
        }
        computed += 1;
        orbit_steps += r.orbit_steps;
        let go_on = observer.computed(&message, r.orbit_steps);
        new_points.push(message);
        if last_flush.elapsed() >= job.flush_interval {
            if let Err(e) = file.close_chunk() {
                write_error = Some(e);
                return false;
            }
            last_flush = Instant::now();
        }
        let stop = job
            .options
            .termination
            .as_ref()
            .is_some_and(|t| t.requested());
        if stop || !go_on {
            interrupted = true;
            return false;
        }
        true
    })?;
    // A stop ends the workers within a window, dropping the points in progress.
    interrupted |= job
        .options
        .termination
        .as_ref()
        .is_some_and(|t| t.requested());
    let written = match write_error {
        Some(e) => Err(e),
        None => file.close_chunk().and_then(|()| file.finish().map(drop)),
    };
    if let Err(e) = written {
        return Err(MapFileError::Write {
            out: job.out.to_path_buf(),
            kept: Some(output.keep()),
            error: error_chain(&e),
        });
    }
    output.commit()?;
    let mut points: Vec<MapPoint> = recorded.into_values().chain(new_points).collect();
    points.sort_by_key(|p| p.index);
    Ok(MapOutcome {
        points,
        computed,
        orbit_steps,
        interrupted,
    })
}

/// The point status a map file carries.
pub fn status_code(status: PointStatus) -> i32 {
    use chaoscope_schemas::proto::map_point::Status;
    (match status {
        PointStatus::Ok => Status::Ok,
        PointStatus::OutsideEnergySurface => Status::OutsideEnergySurface,
        PointStatus::Escaped => Status::Escaped,
    }) as i32
}

/// How many of this map's points (`header`: its configuration and shard) an earlier map left
/// in `out` and in its in-progress file, which [`map_to_file`] resumes rather than computes: a
/// resumed map is estimated for the rest. Files that are not regular, or that the map would
/// refuse, count none (the map refuses them itself before it computes anything).
pub fn resumable_points(out: &Path, header: &MapHeader) -> u64 {
    let regular = |p: &Path| std::fs::metadata(p).is_ok_and(|m| m.is_file());
    let partial = chaoscope_os::output::partial_path(out);
    // An empty in-progress file holds nothing (the map takes it over as its own).
    let leftover = std::fs::metadata(&partial)
        .is_ok_and(|m| m.is_file() && m.len() > 0)
        .then_some(partial.as_path());
    if out.exists() && !regular(out) {
        return 0;
    }
    previous_points(out, leftover, header, &mut ()).map_or(0, |points| points.len() as u64)
}

/// Points already recorded for this map and shard, from the output file (a map that was
/// stopped) and from the in-progress file a killed map left (`leftover`). A file that cannot be
/// read as a map of this configuration and shard is refused, never discarded (that takes a
/// restart).
fn previous_points(
    out: &Path,
    leftover: Option<&Path>,
    header: &MapHeader,
    observer: &mut impl MapObserver,
) -> Result<BTreeMap<u64, MapPoint>, MapFileError> {
    let shard = Shard {
        index: header.shard_index,
        count: header.shard_count,
    };
    let refused = |path: &Path, why: String| {
        MapFileError::Refused(format!("{}: {why}; it was left untouched", path.display()))
    };
    let mut points = BTreeMap::new();
    let files = leftover
        .map(|p| (p, true))
        .into_iter()
        .chain(out.exists().then_some((out, false)));
    for (path, is_leftover) in files {
        let contents = read_map_file(path).map_err(|e| match e {
            // Refused as any other file that is not this map, so the caller's way out is named.
            FileError::NotMcap { .. } => refused(
                path,
                "is not an MCAP file (no MCAP magic at the start)".into(),
            ),
            e => e.into(),
        })?;
        if let Some(d) = &contents.damaged {
            observer.damaged(path, d, contents.points.len());
        }
        let Some(h) = contents.header else {
            // Killed before it wrote its first chunk: nothing in it. The first chunk is closed
            // at about the chunk size, so a longer file cut "before" it is a damaged length,
            // not a kill: refused with the rest.
            let short = std::fs::metadata(path).is_ok_and(|m| m.len() <= FIRST_CHUNK_BOUND);
            if is_leftover && contents.cut_before_any_chunk && short {
                continue;
            }
            return Err(refused(
                path,
                "holds no readable map header (not a `chaoscope map` recording, or its first \
                 chunk is damaged)"
                    .into(),
            ));
        };
        if let Some(why) = table_difference(&h.config_toml, &header.config_toml) {
            return Err(refused(
                path,
                format!(
                    "was computed with another table: {why} (restore the table, or compute the map again)"
                ),
            ));
        }
        if h.config_toml != header.config_toml
            || (h.shard_index, h.shard_count) != (header.shard_index, header.shard_count)
        {
            return Err(refused(
                path,
                "holds a different map (configuration or shard differ)".into(),
            ));
        }
        for p in contents.points {
            if p.index >= header.grid_points || !shard.contains(p.index) {
                return Err(refused(
                    path,
                    format!("point {} is not in its shard", p.index),
                ));
            }
            // Its values are this map's own (this configuration's header) or the file is
            // refused: they go into the new file and the PNG as they are.
            check_point(header, &p).map_err(|e| refused(path, e))?;
            points.insert(p.index, p);
        }
    }
    Ok(points)
}

/// A table whose content differs between a map file's recorded configuration and this one
/// (both carry each table's SHA-256), described for the user; `None` if every table agrees.
fn table_difference(recorded: &str, now: &str) -> Option<String> {
    let recorded = RunConfig::from_toml(recorded).ok()?;
    let now = RunConfig::from_toml(now).ok()?;
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
