//! `chaoscope map-watch [NAME] [--json-lines]`: follow a running `chaoscope map` live, one line
//! per finished point (index, status, value), never slowing it.
//!
//! The stream is lossy: points a slow watcher could not keep are counted from the sequence
//! numbers and reported as missed (`received + missed = published`).

use std::process::ExitCode;
use std::time::{Duration, Instant};

use anyhow::{Context, bail};
use chaoscope_bus::frame::{MapFrameContent, status};
use chaoscope_bus::{self as bus, Liveness};
use chaoscope_os::termination::Termination;
use chaoscope_schemas::names;
use chaoscope_schemas::proto::{MapAxis, MapHeader, MapPoint};
use prost::Message;
use serde_json::json;

#[derive(clap::Args)]
pub struct Args {
    /// Map to follow (`chaoscope map --name`, default its output file's stem); default: the
    /// only live map.
    pub name: Option<String>,
    /// One JSON object per line on stdout: a "header", then each "point", then the "end".
    #[arg(long)]
    pub json_lines: bool,
    /// Give up if no map (or no map header) appears within this many seconds.
    #[arg(long, default_value = "30", value_parser = super::parse_seconds)]
    pub wait_timeout: Duration,
}

/// How often the map process's liveness is checked.
const LIVENESS_PERIOD: Duration = Duration::from_millis(200);

fn find_map(timeout: Duration) -> anyhow::Result<String> {
    let start = Instant::now();
    loop {
        let live: Vec<String> = bus::list_maps()
            .into_iter()
            .filter(|m| bus::node_liveness(&names::map_node_name(m)) == Liveness::Alive)
            .collect();
        match live.len() {
            1 => return Ok(live[0].clone()),
            0 if start.elapsed() < timeout => std::thread::sleep(bus::POLL_INTERVAL),
            0 => bail!("no live map appeared within {timeout:?}"),
            _ => bail!("several maps are live ({}); name one", live.join(", ")),
        }
    }
}

fn status_name(p: &MapPoint) -> String {
    p.status().as_str_name().to_ascii_lowercase()
}

fn end_status_name(code: u32) -> &'static str {
    match code {
        status::COMPLETED => "completed",
        status::INTERRUPTED => "interrupted",
        status::FAILED => "failed",
        _ => "unknown",
    }
}

fn axis(a: &Option<MapAxis>) -> serde_json::Value {
    a.as_ref().map_or(serde_json::Value::Null, |a| {
        // A parameter axis names its parameter instead of a coordinate.
        if a.param.is_empty() {
            json!({"coord": a.coord, "min": a.min, "max": a.max, "n": a.n})
        } else {
            json!({"param": a.param, "min": a.min, "max": a.max, "n": a.n})
        }
    })
}

/// Counts received and missed points from the sequence numbers.
#[derive(Default)]
struct Tally {
    next_seq: u64,
    received: u64,
    missed: u64,
}

impl Tally {
    /// Accounts a point; false for a sequence number already seen (never expected).
    fn point(&mut self, seq: u64) -> bool {
        if seq < self.next_seq {
            return false;
        }
        self.missed += seq - self.next_seq;
        self.received += 1;
        self.next_seq = seq + 1;
        true
    }

    fn end(&mut self, published: u64) {
        self.missed += published.saturating_sub(self.next_seq);
        self.next_seq = self.next_seq.max(published);
    }
}

pub fn main(args: Args) -> anyhow::Result<ExitCode> {
    chaoscope_bus::signals::install(chaoscope_os::signals::Mode::Finish);
    let termination = Termination::new();
    let name = match args.name {
        Some(n) => {
            names::validate_run_name(&n).map_err(anyhow::Error::msg)?;
            n
        }
        None => find_map(args.wait_timeout)?,
    };
    let node = bus::create_node(&names::map_watcher_node_name(&name))?;
    // Unlike monitors, a watcher started before its map creates the map's services, so that it
    // receives every point from the first (the map's points are not kept as history, and a
    // small map is over in a fraction of a second). A watcher killed while creating them leaves
    // them hanging in creation: `chaoscope map` then removes them once it finds the watcher
    // dead, and creates them anew (`bus::map_header_service`, `tests/load.rs`).
    let header_service = bus::map_header_service(&node, &name)?;
    let points_service = bus::map_points_service(&node, &name)?;
    let header_sub = header_service
        .subscriber_builder()
        .create()
        .map_err(|e| bus::BusError::new("create map header subscriber", e))?;
    let points_sub = points_service
        .subscriber_builder()
        .buffer_size(bus::MAP_POINTS_BUFFER)
        .create()
        .map_err(|e| bus::BusError::new("create map point subscriber", e))?;
    chaoscope_os::errln!("chaoscope map-watch: following map {name}");

    let map_node = names::map_node_name(&name);
    let start = Instant::now();
    let mut header: Option<MapHeader> = None;
    let mut seen_alive = false;
    let mut tally = Tally::default();
    let mut end_code = None;
    let mut last_check = Instant::now() - LIVENESS_PERIOD;
    let mut gone = false;
    // A closed pipe ends the watcher quietly, a failed write with one line (`main`).
    let out = |line: String| chaoscope_os::outln!("{line}");
    loop {
        if termination.requested() {
            chaoscope_os::errln!("chaoscope map-watch: interrupted");
            return Ok(super::exit_interrupted());
        }
        // Liveness before draining: whatever the map sent before it went away is read below.
        if last_check.elapsed() >= LIVENESS_PERIOD {
            last_check = Instant::now();
            match bus::node_liveness(&map_node) {
                Liveness::Alive => seen_alive = true,
                _ => gone = seen_alive || header.is_some(),
            }
        }
        let mut got = false;
        while let Some(sample) = header_sub
            .receive()
            .map_err(|e| bus::BusError::new("receive map header", e))?
        {
            got = true;
            if sample.user_header().kind() != Some(MapFrameContent::Header) || header.is_some() {
                continue;
            }
            let h = MapHeader::decode(sample.payload()).context("decoding the map header")?;
            if args.json_lines {
                out(json!({
                    "type": "header",
                    "map": name,
                    "model": h.model,
                    "indicator": h.indicator,
                    "method": h.method,
                    "k": h.k,
                    "x": axis(&h.x),
                    "y": axis(&h.y),
                    "grid_points": h.grid_points,
                    "shard": format!("{}/{}", h.shard_index, h.shard_count),
                })
                .to_string())?;
            } else {
                out(format!(
                    "# map {name}: {} of {}, {} points, shard {}/{}; index ix iy status value",
                    h.indicator, h.model, h.grid_points, h.shard_index, h.shard_count
                ))?;
            }
            header = Some(h);
        }
        while let Some(sample) = points_sub
            .receive()
            .map_err(|e| bus::BusError::new("receive map point", e))?
        {
            got = true;
            let frame = *sample.user_header();
            match frame.kind() {
                Some(MapFrameContent::Point) => {
                    if !tally.point(frame.seq) {
                        continue;
                    }
                    let p = MapPoint::decode(sample.payload()).context("decoding a map point")?;
                    if args.json_lines {
                        out(json!({
                            "type": "point",
                            "seq": frame.seq,
                            "index": p.index,
                            "ix": p.ix,
                            "iy": p.iy,
                            "x": p.x,
                            "y": p.y,
                            "status": status_name(&p),
                            "value": p.value,
                        })
                        .to_string())?;
                    } else {
                        // A point that has no value (outside the energy surface, escaped)
                        // carries NaN: shown as `-`, never as NaN.
                        let value = if p.value.is_finite() {
                            p.value.to_string()
                        } else {
                            "-".to_string()
                        };
                        out(format!(
                            "{} {} {} {} {value}",
                            p.index,
                            p.ix,
                            p.iy,
                            status_name(&p),
                        ))?;
                    }
                }
                Some(MapFrameContent::End) => {
                    tally.end(frame.seq);
                    end_code = Some(frame.status);
                }
                _ => {}
            }
            if end_code.is_some() {
                break;
            }
        }
        if end_code.is_some() || gone {
            break;
        }
        if !seen_alive && header.is_none() && start.elapsed() > args.wait_timeout {
            bail!("map {name} did not start within {:?}", args.wait_timeout);
        }
        if !got {
            std::thread::sleep(Duration::from_millis(10));
        }
    }
    let how = end_code.map_or("lost (the map process ended without an end record)", |c| {
        end_status_name(c)
    });
    let published = tally.next_seq;
    if args.json_lines {
        out(json!({
            "type": "end",
            "status": end_code.map_or("lost", end_status_name),
            "published": end_code.map(|_| published),
            "received": tally.received,
            "missed": tally.missed,
        })
        .to_string())?;
    }
    chaoscope_os::errln!(
        "chaoscope map-watch: map {name} {how}; {} points received, {} missed",
        tally.received,
        tally.missed
    );
    Ok(if end_code.is_some() {
        ExitCode::SUCCESS
    } else {
        ExitCode::FAILURE
    })
}

#[cfg(test)]
mod tests {
    use super::Tally;

    #[test]
    fn received_plus_missed_is_published() {
        let mut t = Tally::default();
        for seq in [0, 1, 4, 5, 5, 9] {
            t.point(seq);
        }
        t.end(12);
        assert_eq!((t.received, t.missed), (5, 7));
        assert_eq!(t.received + t.missed, 12);
    }
}
