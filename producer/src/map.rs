//! The live stream of a map (`chaoscope map`): the map header, then every finished point, then
//! an end record, on the `chaoscope/map/<name>/...` services (layout in
//! [`chaoscope_bus::frame`]).
//!
//! The stream is for watchers and must never slow the map: the point service overwrites the
//! oldest points of a slow watcher, a point that cannot be loaned is dropped, and no call here
//! waits. Every point carries its sequence number, so a watcher counts what it missed.

use std::path::Path;
use std::time::{Duration, Instant};

use chaoscope_bus::frame::{MapFrameContent, MapFrameHeader};
use chaoscope_bus::{self as bus, BusError, MapService, OpenAloneError};
use chaoscope_schemas::names::{self, MAX_RUN_NAME_LEN};
use chaoscope_schemas::proto::{MapHeader, MapPoint};
use iceoryx2::port::publisher::Publisher;
use iceoryx2::port::update_connections::UpdateConnections;
use iceoryx2::prelude::*;
use prost::Message;

use chaoscope_dynamics::map::Shard;

/// The default bus name of a map written to `out`: the file stem with characters outside
/// `[A-Za-z0-9_-]` replaced by `_`, plus `-shard<i>of<n>` for a shard of a split map.
pub fn default_map_name(out: &Path, shard: Shard) -> String {
    let stem = out
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_default();
    let mut name: String = stem
        .chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || c == '-' || c == '_' {
                c
            } else {
                '_'
            }
        })
        .collect();
    if name.is_empty() {
        name.push_str("map");
    }
    let suffix = if shard.count > 1 {
        format!("-shard{}of{}", shard.index, shard.count)
    } else {
        String::new()
    };
    name.truncate(MAX_RUN_NAME_LEN - suffix.len());
    name + &suffix
}

/// Why the live stream of a map could not be opened (the map itself still runs).
#[derive(Debug, thiserror::Error)]
pub enum MapBusError {
    #[error("invalid map name: {0}")]
    Name(String),
    #[error("map {0:?} is already being published by a live process")]
    AlreadyRunning(String),
    #[error(transparent)]
    Bus(#[from] BusError),
}

pub struct MapPublisher {
    name: String,
    _node: Node<ipc::Service>,
    _header_service: MapService,
    points_service: MapService,
    header: Publisher<ipc::Service, [u8], MapFrameHeader>,
    points: Publisher<ipc::Service, [u8], MapFrameHeader>,
    /// Sequence number of the next point.
    seq: u64,
    last_refresh: Instant,
}

impl MapPublisher {
    /// Opens the services of map `name` and publishes its header.
    pub fn open(name: &str, header: &MapHeader) -> Result<Self, MapBusError> {
        names::validate_run_name(name).map_err(MapBusError::Name)?;
        let node_name = names::map_node_name(name);
        bus::open_alone(&node_name, || Self::open_services(name, &node_name, header)).map_err(|e| {
            match e {
                OpenAloneError::Held => MapBusError::AlreadyRunning(name.to_string()),
                OpenAloneError::Bus(e) => MapBusError::Bus(e),
            }
        })
    }

    fn open_services(name: &str, node_name: &str, header: &MapHeader) -> Result<Self, BusError> {
        let node = bus::create_node(node_name)?;
        let header_service = bus::map_header_service(&node, name)?;
        let points_service = bus::map_points_service(&node, name)?;
        let header_publisher = header_service
            .publisher_builder()
            .initial_max_slice_len(4096)
            .allocation_strategy(AllocationStrategy::PowerOfTwo)
            .create()
            .map_err(|e| BusError::new("create map header publisher", e))?;
        let points = points_service
            .publisher_builder()
            .initial_max_slice_len(1024)
            .allocation_strategy(AllocationStrategy::PowerOfTwo)
            .backpressure_strategy(BackpressureStrategy::DiscardData)
            .create()
            .map_err(|e| BusError::new("create map point publisher", e))?;
        send(
            &header_publisher,
            MapFrameHeader::new(MapFrameContent::Header, 0, 0),
            &header.encode_to_vec(),
        )
        .map_err(|e| BusError::new("send map header", e))?;
        Ok(Self {
            name: name.to_string(),
            _node: node,
            _header_service: header_service,
            points_service,
            header: header_publisher,
            points,
            seq: 0,
            last_refresh: Instant::now(),
        })
    }

    /// The map's name on the bus.
    pub fn name(&self) -> &str {
        &self.name
    }

    /// Points published so far (sent or dropped).
    pub fn published(&self) -> u64 {
        self.seq
    }

    /// Publishes one finished point; never waits and never fails (a point that cannot go out
    /// is lost for the watchers, who see the gap in the sequence numbers).
    pub fn publish(&mut self, point: &MapPoint) {
        let seq = self.seq;
        self.seq += 1;
        if self.last_refresh.elapsed() >= bus::POLL_INTERVAL {
            // Watchers that arrived since get the header (history).
            let _ = self.header.update_connections();
            let _ = self.points.update_connections();
            self.last_refresh = Instant::now();
        }
        if self.points_service.dynamic_config().number_of_subscribers() == 0 {
            return;
        }
        let _ = send(
            &self.points,
            MapFrameHeader::new(MapFrameContent::Point, seq, 0),
            &point.encode_to_vec(),
        );
    }

    /// Publishes the end record (`status` as in [`chaoscope_bus::frame::status`]), then
    /// waits up to `linger` (after the map is done) for connected watchers to read it and
    /// leave, so the points still queued for them outlive this publisher.
    pub fn end(&mut self, status: u32, linger: Duration) {
        let _ = self.points.update_connections();
        let _ = send(
            &self.points,
            MapFrameHeader::new(MapFrameContent::End, self.seq, status),
            &[],
        );
        let start = Instant::now();
        while self.points_service.dynamic_config().number_of_subscribers() > 0
            && start.elapsed() < linger
        {
            std::thread::sleep(Duration::from_millis(10));
        }
    }
}

fn send(
    publisher: &Publisher<ipc::Service, [u8], MapFrameHeader>,
    header: MapFrameHeader,
    bytes: &[u8],
) -> Result<(), Box<dyn std::error::Error>> {
    let mut sample = publisher.loan_slice_uninit(bytes.len())?;
    *sample.user_header_mut() = header;
    sample.write_from_slice(bytes).send()?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn default_names_are_valid_run_names() {
        let whole = Shard { index: 0, count: 1 };
        assert_eq!(
            default_map_name(Path::new("/d/hh map.mcap"), whole),
            "hh_map"
        );
        let shard = Shard { index: 2, count: 8 };
        assert_eq!(default_map_name(Path::new("x.mcap"), shard), "x-shard2of8");
        let long = format!("{}.mcap", "a".repeat(100));
        let name = default_map_name(Path::new(&long), shard);
        assert!(names::validate_run_name(&name).is_ok());
        assert!(name.ends_with("-shard2of8"));
        assert_eq!(default_map_name(Path::new("/"), whole), "map");
    }
}
