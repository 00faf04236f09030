//! The MCAP layout of a map recording (`chaoscope map`, `chaoscope merge`).
//!
//! Two channels: `/chaoscope/map/header` (one `MapHeader`, first) and `/chaoscope/map/points`
//! (one `MapPoint` per grid point, in completion order). The configuration is also stored as
//! the metadata record `chaoscope.map`. Chunks are written whole, as in run recordings, so a
//! killed map loses at most its open chunk, and [`read_map_file`] reads every complete chunk of a
//! truncated or damaged file (streaming, through [`crate::scan`]): that is what resuming builds
//! on.

use std::collections::BTreeMap;
use std::io::{Read, Seek, Write};
use std::path::Path;

use chaoscope_schemas::FORMAT_VERSION;
use chaoscope_schemas::names::{metadata, topic};
use chaoscope_schemas::proto::{self, MapHeader, MapPoint, schema_name};
use mcap::records::{MessageHeader, Metadata};
use prost::Message;

use crate::file::FileOptions;
use crate::scan::{FileError, Messages, Scanner};

/// A map recording being written.
pub struct MapFile<W: Write + Seek> {
    writer: mcap::Writer<W>,
    points: u16,
    sequence: u32,
    encoded: Vec<u8>,
}

impl<W: Write + Seek> MapFile<W> {
    pub fn create(out: W, header: &MapHeader, options: &FileOptions) -> mcap::McapResult<Self> {
        let mut writer = options.writer(out)?;
        writer.write_metadata(&Metadata {
            name: metadata::MAP.into(),
            metadata: BTreeMap::from([
                ("format_version".to_string(), FORMAT_VERSION.to_string()),
                ("config_toml".to_string(), header.config_toml.clone()),
                (
                    "shard".to_string(),
                    format!("{}/{}", header.shard_index, header.shard_count),
                ),
            ]),
        })?;
        let fds = proto::FILE_DESCRIPTOR_SET;
        let mut channel = |schema: &str, topic: &str| -> mcap::McapResult<u16> {
            let id = writer.add_schema(schema, proto::SCHEMA_ENCODING, fds)?;
            writer.add_channel(id, topic, proto::MESSAGE_ENCODING, &BTreeMap::new())
        };
        let head = channel(schema_name::MAP_HEADER, topic::MAP_HEADER)?;
        let points = channel(schema_name::MAP_POINT, topic::MAP_POINTS)?;
        let mut file = Self {
            writer,
            points,
            sequence: 0,
            encoded: Vec::new(),
        };
        file.put(head, header)?;
        Ok(file)
    }

    fn put(&mut self, channel_id: u16, message: &impl Message) -> mcap::McapResult<()> {
        self.encoded.clear();
        message
            .encode(&mut self.encoded)
            .expect("a Vec grows as needed");
        let now = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map(|d| d.as_nanos() as u64)
            .unwrap_or(0);
        let header = MessageHeader {
            channel_id,
            sequence: self.sequence,
            // Map points have no simulation time; the wall clock orders them.
            log_time: now,
            publish_time: now,
        };
        self.sequence = self.sequence.wrapping_add(1);
        self.writer.write_to_known_channel(&header, &self.encoded)
    }

    pub fn write_point(&mut self, point: &MapPoint) -> mcap::McapResult<()> {
        self.put(self.points, point)
    }

    /// Puts the open chunk on disk whole (bounds what a crash can lose).
    pub fn close_chunk(&mut self) -> mcap::McapResult<()> {
        self.writer.flush()
    }

    pub fn finish(mut self) -> mcap::McapResult<W> {
        self.writer.finish()?;
        Ok(self.writer.into_inner())
    }
}

/// What [`read_map`] found.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct MapContents {
    pub header: Option<MapHeader>,
    pub points: Vec<MapPoint>,
    /// Where and why reading stopped in a damaged (e.g. killed) file; `None` when it was
    /// complete.
    pub damaged: Option<String>,
}

/// Reads the map recording at `path`, streaming (memory of about one chunk besides the
/// points), tolerating a damaged or truncated tail: every complete chunk before the damage is
/// read, and [`MapContents::damaged`] says where and why reading stopped.
pub fn read_map_file(path: &Path) -> Result<MapContents, FileError> {
    let (scanner, _) = Scanner::open_file(path)?;
    read_messages(Messages::new(scanner)).map_err(|e| FileError::io(path, e))
}

/// Reads a map recording from `source` (of length `len`, if known) as [`read_map_file`] does;
/// `Ok(None)` if it is not MCAP. Only a failure of `source` itself is an error.
pub fn read_map(source: impl Read, len: Option<u64>) -> std::io::Result<Option<MapContents>> {
    match Scanner::open(source, len)? {
        Some(scanner) => read_messages(Messages::new(scanner)).map(Some),
        None => Ok(None),
    }
}

fn read_messages(mut messages: Messages<impl Read>) -> std::io::Result<MapContents> {
    let mut contents = MapContents::default();
    // What the chunk (or record) being read holds, kept only once it is read whole: a message
    // that does not decode drops its chunk.
    let (mut header, mut points, mut entry) = (None, Vec::new(), 0);
    while let Some(m) = messages.next_message()? {
        if messages.entry() != entry {
            entry = messages.entry();
            contents.header = header.take().or(contents.header.take());
            contents.points.append(&mut points);
        }
        let decoded = match &*m.topic {
            topic::MAP_HEADER => MapHeader::decode(&m.data[..]).map(|h| header = Some(h)),
            topic::MAP_POINTS => MapPoint::decode(&m.data[..]).map(|p| points.push(p)),
            _ => Ok(()),
        };
        if let Err(e) = decoded {
            (header, points) = (None, Vec::new());
            messages.stop(format!("message on {} is not valid protobuf: {e}", m.topic));
        }
    }
    contents.header = header.or(contents.header);
    contents.points.append(&mut points);
    contents.damaged = messages.scan().stopped_at.clone();
    Ok(contents)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::file::Compression;

    #[test]
    fn points_survive_truncation_of_the_open_chunk() {
        // Chunks of six points and four.
        let (bytes, header, _) = crate::testing::small_map(10, 6, Compression::Zstd);
        let full = read_map(&bytes[..], None).unwrap().unwrap();
        assert_eq!(full.header.unwrap(), header);
        assert_eq!(full.points.len(), 10);
        assert!(full.damaged.is_none());
        // Every cut keeps whole chunks only: 0, 6 (the first chunk) or all 10 points.
        let mut seen_first_chunk_only = false;
        for cut in 8..bytes.len() {
            let part = read_map(&bytes[..cut], None).unwrap().unwrap();
            let n = part.points.len();
            assert!([0, 6, 10].contains(&n), "cut {cut}: {n} points");
            seen_first_chunk_only |= n == 6 && part.damaged.is_some();
        }
        assert!(seen_first_chunk_only);
    }

    #[test]
    fn a_point_that_does_not_decode_drops_its_whole_chunk() {
        // Chunks of six points and four, uncompressed.
        let (mut bytes, header, points) = crate::testing::small_map(10, 6, Compression::None);
        let second = crate::testing::chunk_offsets(&bytes)[1];
        let body = second + 9;
        // No CRC, so the chunk's records are read as they are.
        bytes[body + 24..body + 28].fill(0);
        // Its records: after start and end time, uncompressed size and CRC, compression (empty)
        // and compressed size.
        let compressed = u64::from_le_bytes(bytes[body + 32..body + 40].try_into().unwrap());
        let (mut at, end) = (body + 40, body + 40 + compressed as usize);
        let mut messages = Vec::new();
        while at < end {
            let len = u64::from_le_bytes(bytes[at + 1..at + 9].try_into().unwrap()) as usize;
            if bytes[at] == mcap::records::op::MESSAGE {
                messages.push(at);
            }
            at += 9 + len;
        }
        assert_eq!(messages.len(), 4);
        // The second point's payload starts with wire type 7, which protobuf does not have.
        bytes[messages[1] + 9 + 22] = 0xff;
        let read = read_map(&bytes[..], None).unwrap().unwrap();
        assert_eq!(read.header.unwrap(), header);
        assert_eq!(read.points, points[..6]);
        let damaged = read.damaged.unwrap();
        assert!(damaged.contains("not valid protobuf"), "{damaged}");
    }
}
