//! The MCAP layout of a map recording (`chaoscope map`, `chaoscope merge`).
//!
//! Two channels: `/chaoscope/map/header` (one `MapHeader`, first) and `/chaoscope/map/points`
//! (one `MapPoint` per grid point, in completion order). The configuration is also stored as
//! the metadata record `chaoscope.map`. Chunks are written whole, as in run recordings, so a
//! killed map loses at most its open chunk, and [`read_map`] reads every complete chunk of a
//! truncated file: that is what resuming builds on.

use std::collections::BTreeMap;
use std::io::{Seek, Write};

use chaoscope_schemas::FORMAT_VERSION;
use chaoscope_schemas::names::{metadata, topic};
use chaoscope_schemas::proto::{self, MapHeader, MapPoint, schema_name};
use mcap::read::{ChunkReader, LinearReader, Options};
use mcap::records::{MessageHeader, Metadata, Record};
use prost::Message;

use crate::file::FileOptions;

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
    /// Where reading stopped in a damaged (e.g. killed) file; `None` when it was complete.
    pub damaged: Option<String>,
}

/// Reads a map recording, tolerating a truncated tail (every complete chunk is read).
pub fn read_map(bytes: &[u8]) -> Result<MapContents, String> {
    if !bytes.starts_with(mcap::MAGIC) {
        return Err("not an MCAP file".into());
    }
    let mut contents = MapContents::default();
    let mut topics: BTreeMap<u16, String> = BTreeMap::new();
    let records = LinearReader::new_with_options(bytes, Options::IgnoreEndMagic.into())
        .map_err(|e| e.to_string())?;
    for (index, record) in records.enumerate() {
        let result = record.and_then(|r| visit(r, &mut topics, &mut contents));
        if let Err(e) = result {
            contents.damaged = Some(format!("record {index}: {e}"));
            break;
        }
    }
    Ok(contents)
}

fn visit(
    record: Record<'_>,
    topics: &mut BTreeMap<u16, String>,
    contents: &mut MapContents,
) -> mcap::McapResult<()> {
    match record {
        Record::Channel(c) => {
            topics.insert(c.id, c.topic.clone());
        }
        Record::Message { header, data } => {
            let decode_err = |e: prost::DecodeError| {
                mcap::McapError::UnexpectedEof.to_string() + &format!(" ({e})")
            };
            match topics.get(&header.channel_id).map(String::as_str) {
                Some(topic::MAP_HEADER) => {
                    let h = MapHeader::decode(&data[..]).map_err(|e| {
                        mcap::McapError::UnknownSchema(decode_err(e), header.channel_id)
                    })?;
                    contents.header = Some(h);
                }
                Some(topic::MAP_POINTS) => {
                    let p = MapPoint::decode(&data[..]).map_err(|e| {
                        mcap::McapError::UnknownSchema(decode_err(e), header.channel_id)
                    })?;
                    contents.points.push(p);
                }
                _ => {}
            }
        }
        Record::Chunk { header, data } => {
            // A damaged chunk is dropped whole.
            let records = ChunkReader::new(header, &data)?.collect::<mcap::McapResult<Vec<_>>>()?;
            for r in records {
                visit(r, topics, contents)?;
            }
        }
        _ => {}
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::file::Compression;
    use std::io::Cursor;

    #[test]
    fn points_survive_truncation_of_the_open_chunk() {
        let header = MapHeader {
            config_toml: "x".into(),
            shard_count: 1,
            ..Default::default()
        };
        let options = FileOptions {
            compression: Compression::Zstd,
            chunk_size: 1 << 20,
        };
        let mut f = MapFile::create(Cursor::new(Vec::new()), &header, &options).unwrap();
        for i in 0..10 {
            f.write_point(&MapPoint {
                index: i,
                value: i as f64,
                ..Default::default()
            })
            .unwrap();
            if i == 5 {
                f.close_chunk().unwrap();
            }
        }
        f.close_chunk().unwrap();
        let bytes = f.finish().unwrap().into_inner();
        let full = read_map(&bytes).unwrap();
        assert_eq!(full.header.unwrap().config_toml, "x");
        assert_eq!(full.points.len(), 10);
        assert!(full.damaged.is_none());
        // Every cut keeps whole chunks only: 0, 6 (the first chunk) or all 10 points.
        let mut seen_first_chunk_only = false;
        for cut in 8..bytes.len() {
            let part = read_map(&bytes[..cut]).unwrap();
            let n = part.points.len();
            assert!([0, 6, 10].contains(&n), "cut {cut}: {n} points");
            seen_first_chunk_only |= n == 6 && part.damaged.is_some();
        }
        assert!(seen_first_chunk_only);
    }
}
