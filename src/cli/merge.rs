//! `chaoscope merge SHARD.mcap... --out FILE.mcap [--png FILE.png]`: join the recordings of
//! `chaoscope map --shard i/n` (i = 0..n-1) into the recording of the whole map.
//!
//! The shards must come from the same configuration, cover every shard index once and, unless
//! `--allow-incomplete`, every grid point. The merged file holds the points in index order with
//! the header of shard 0/1: exactly what an unsharded run would have computed.

use std::collections::BTreeMap;
use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::{Context, bail};
use chaoscope_analyzer::map_png;
use chaoscope_dynamics::map::Shard;
use chaoscope_files::file::{Compression, FileOptions};
use chaoscope_files::map_file::{MapFile, read_map_file};
use chaoscope_os::{Leftover, Output, OutputOptions};
use chaoscope_schemas::proto::{MapHeader, MapPoint};

/// Missing shards named in the error of an incomplete merge.
const MISSING_SHARDS_LISTED: usize = 32;

#[derive(clap::Args)]
pub struct Args {
    /// Shard recordings (from `chaoscope map --shard i/n`).
    #[arg(required = true)]
    pub shards: Vec<PathBuf>,
    /// Merged MCAP file.
    #[arg(long)]
    pub out: PathBuf,
    /// Also render the merged map as a PNG.
    #[arg(long)]
    pub png: Option<PathBuf>,
    /// Replace the output file if it exists.
    #[arg(long)]
    pub force: bool,
    /// Write the merge even if grid points are missing (they stay blank in the PNG).
    #[arg(long)]
    pub allow_incomplete: bool,
    /// Print a JSON summary on stdout.
    #[arg(long)]
    pub json: bool,
}

pub fn main(args: Args) -> anyhow::Result<ExitCode> {
    // Nothing worth finalizing: a signal removes the unfinished output and ends at once.
    chaoscope_bus::signals::install(chaoscope_os::signals::Mode::Exit);
    let output_options = OutputOptions {
        replace: args.force,
        inputs: args.shards.clone(),
        // A killed merge's file is no use: it is merged again.
        leftover: Leftover::Discard,
        ..Default::default()
    };
    // Before reading shards for minutes: an output that cannot be written is said at once.
    chaoscope_os::output::check_target(&args.out, &output_options)?;
    if let Some(png) = &args.png {
        let mut inputs = args.shards.clone();
        inputs.push(args.out.clone());
        chaoscope_os::output::check_target(
            png,
            &OutputOptions {
                replace: true,
                inputs,
                ..Default::default()
            },
        )?;
    }
    let mut header: Option<MapHeader> = None;
    let mut seen_shards = BTreeMap::new();
    let mut points: BTreeMap<u64, MapPoint> = BTreeMap::new();
    for path in &args.shards {
        let contents = read_map_file(path)?;
        if let Some(d) = contents.damaged {
            bail!(
                "{} is damaged or cut short ({d}); if its `chaoscope map` was interrupted, resume \
                 it with the same command first",
                path.display()
            );
        }
        // Every value used below (sizes, shard, grid positions) and by the PNG, checked first.
        contents
            .check()
            .map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
        let h = contents
            .header
            .with_context(|| format!("{} has no map header", path.display()))?;
        if h.shard_count == 0 || h.shard_index >= h.shard_count {
            bail!(
                "{}: its header says shard {}/{}, which no `chaoscope map --shard` writes",
                path.display(),
                h.shard_index,
                h.shard_count
            );
        }
        if let Some(first) = &header
            && !chaoscope_files::map_file::same_map(first, &h)
        {
            bail!(
                "{} belongs to a different map or shard split than {}",
                path.display(),
                args.shards[0].display()
            );
        }
        if let Some(other) = seen_shards.insert(h.shard_index, path.clone()) {
            bail!(
                "shard {}/{} given twice: {} and {}",
                h.shard_index,
                h.shard_count,
                other.display(),
                path.display()
            );
        }
        let shard = Shard {
            index: h.shard_index,
            count: h.shard_count,
        };
        for p in contents.points {
            if !shard.contains(p.index) || p.index >= h.grid_points {
                bail!("{}: point {} is not in its shard", path.display(), p.index);
            }
            points.insert(p.index, p);
        }
        header = Some(h);
    }
    let mut header = header.expect("at least one shard");
    // The first few (a header may claim billions of shards).
    let missing_shards: Vec<u32> = (0..header.shard_count)
        .filter(|i| !seen_shards.contains_key(i))
        .take(MISSING_SHARDS_LISTED)
        .collect();
    let more_shards =
        (header.shard_count as usize - seen_shards.len()).saturating_sub(missing_shards.len());
    let missing = header.grid_points - points.len() as u64;
    if (!missing_shards.is_empty() || missing > 0) && !args.allow_incomplete {
        let more = match more_shards {
            0 => String::new(),
            n => format!(" and {n} more"),
        };
        bail!(
            "incomplete map: {missing} of {} points missing (shards missing: \
             {missing_shards:?}{more}); finish the shards or pass --allow-incomplete",
            header.grid_points
        );
    }
    header.shard_index = 0;
    header.shard_count = 1;
    let output = Output::create(&args.out, &output_options)?;
    // The map writer's errors are the bare I/O error ("File too large", "No space left on
    // device"): named here with the file they were writing (the output's name; its unfinished
    // in-progress file goes with the error).
    let writing = || format!("{}: writing the merged map", args.out.display());
    let mut file = MapFile::create(
        output.file()?,
        &header,
        &FileOptions {
            compression: Compression::Zstd,
            chunk_size: 1 << 20,
        },
    )
    .with_context(writing)?;
    for p in points.values() {
        file.write_point(p).with_context(writing)?;
    }
    file.finish().with_context(writing)?;
    output.commit()?;
    let all: Vec<MapPoint> = points.into_values().collect();
    if let Some(png) = &args.png {
        let mut inputs = args.shards.clone();
        inputs.push(args.out.clone());
        map_png::render_png(&header, &all, png, &inputs).map_err(anyhow::Error::msg)?;
    }
    if args.json {
        chaoscope_os::outln!(
            "{}",
            serde_json::json!({
                "out": args.out,
                "shards": seen_shards.len(),
                "points": all.len(),
                "grid_points": header.grid_points,
                "missing": missing,
            })
        )?;
    }
    Ok(ExitCode::SUCCESS)
}
