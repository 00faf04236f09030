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
use chaoscope_schemas::proto::{self, MapHeader, MapPoint, map_point, schema_name};
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
    /// The file ends before its first chunk is whole: what a writer killed before its first
    /// chunk reached the disk leaves, with no point in it to keep.
    pub cut_before_any_chunk: bool,
    /// The file describes itself as a map (its `chaoscope.map` metadata record was read), even
    /// where its header was not.
    pub described_as_map: bool,
}

/// Most grid points per axis a map file may describe (what `[map] x.n` and `y.n` accept).
pub const MAX_AXIS_POINTS: u32 = 100_000;

/// A map header whose values no `chaoscope map` writes, as `field: problem`: every value the
/// readers use to index, allocate, loop or draw (axes, sizes, shard, indicator, times) is
/// checked here before they use it.
pub fn check_header(h: &MapHeader) -> Result<(), String> {
    for (name, axis) in [("x", &h.x), ("y", &h.y)] {
        let Some(a) = axis else {
            return Err(format!("{name}: no axis"));
        };
        if a.n == 0 || a.n > MAX_AXIS_POINTS {
            return Err(format!(
                "{name}.n = {}: an axis has 1 to {MAX_AXIS_POINTS} points",
                a.n
            ));
        }
        if !(a.min.is_finite()
            && a.max.is_finite()
            && a.min <= a.max
            && (a.max - a.min).is_finite())
        {
            return Err(format!(
                "{name}.min, {name}.max = {:?}, {:?}: need finite min <= max, their distance finite",
                a.min, a.max
            ));
        }
    }
    let (x, y) = (
        h.x.as_ref().expect("checked"),
        h.y.as_ref().expect("checked"),
    );
    if h.grid_points != u64::from(x.n) * u64::from(y.n) {
        return Err(format!(
            "grid_points = {}, but x.n * y.n = {} * {}",
            h.grid_points, x.n, y.n
        ));
    }
    if h.shard_count == 0 || h.shard_index >= h.shard_count {
        return Err(format!(
            "shard {}/{}, which no `chaoscope map --shard` writes",
            h.shard_index, h.shard_count
        ));
    }
    let indicators = chaoscope_indicators::indicator::map_indicators();
    if !indicators.contains(&h.indicator.as_str()) {
        return Err(format!(
            "indicator {:?} is none of {}",
            h.indicator,
            indicators.join(", ")
        ));
    }
    if h.sets == 0 || h.sets as usize > MAX_SETS || h.k == 0 {
        return Err(format!(
            "sets = {}, k = {}: need 1 to {MAX_SETS} sets and k >= 1",
            h.sets, h.k
        ));
    }
    if !(h.t_final.is_finite() && h.t_final >= 0.0) {
        return Err(format!(
            "t_final = {:?}: a final time is finite and not negative",
            h.t_final
        ));
    }
    if !h.threshold.is_finite() {
        return Err(format!("threshold = {:?}", h.threshold));
    }
    Ok(())
}

/// Whether two map headers describe shards of one map: equal in every field but the shard's
/// index (and the version of the program that wrote it). `merge` joins only such shards, and
/// reads each point under one header, so a shard whose header says another indicator, order,
/// grid or split is refused, never drawn or merged under the first one's.
pub fn same_map(a: &MapHeader, b: &MapHeader) -> bool {
    let whole = |h: &MapHeader| MapHeader {
        shard_index: 0,
        producer_version: String::new(),
        ..h.clone()
    };
    whole(a) == whole(b)
}

/// Most sets of a map point (`[deviations] sets`'s limit).
const MAX_SETS: usize = 1_000_000;

/// A point of the map `h` describes (checked by [`check_header`]) whose values no `chaoscope
/// map` writes, as `field: problem`: its index and grid position within the grid and agreeing
/// with each other, its coordinates those of its grid position, a known status, and for an
/// integrated point a finite value per set.
pub fn check_point(h: &MapHeader, p: &MapPoint) -> Result<(), String> {
    let (Some(x), Some(y)) = (&h.x, &h.y) else {
        return Err("the header has no axes".into());
    };
    let at = |what: String| format!("point {}: {what}", p.index);
    if p.ix >= x.n || p.iy >= y.n || p.index != u64::from(p.iy) * u64::from(x.n) + u64::from(p.ix) {
        return Err(at(format!(
            "(ix, iy) = ({}, {}) on a {} x {} grid, which is point {}",
            p.ix,
            p.iy,
            x.n,
            y.n,
            u64::from(p.iy) * u64::from(x.n) + u64::from(p.ix)
        )));
    }
    if p.index % u64::from(h.shard_count) != u64::from(h.shard_index) {
        return Err(at(format!(
            "not in shard {}/{}",
            h.shard_index, h.shard_count
        )));
    }
    for (name, axis, i, v) in [("x", x, p.ix, p.x), ("y", y, p.iy, p.y)] {
        let expected = if axis.n > 1 {
            axis.min + (axis.max - axis.min) * f64::from(i) / f64::from(axis.n - 1)
        } else {
            axis.min
        };
        let slack = 1e-9 * (axis.max - axis.min).max(axis.min.abs().max(axis.max.abs()));
        if !(v.is_finite() && (v - expected).abs() <= slack) {
            return Err(at(format!(
                "{name} = {v:?}, but grid position {i} of {:?}..{:?} is {expected:?}",
                axis.min, axis.max
            )));
        }
    }
    let status = map_point::Status::try_from(p.status).ok();
    let ok = match status {
        Some(map_point::Status::Ok) => true,
        Some(map_point::Status::OutsideEnergySurface | map_point::Status::Escaped) => false,
        _ => return Err(at(format!("status {} is not a point status", p.status))),
    };
    if p.per_set.len() > h.sets as usize || (ok && p.per_set.len() != h.sets as usize) {
        return Err(at(format!(
            "{} values per set, but the map has {} sets",
            p.per_set.len(),
            h.sets
        )));
    }
    if ok {
        for (field, v) in [("value", p.value), ("mean_log10", p.mean_log10)] {
            if !v.is_finite() {
                return Err(at(format!("{field} = {v:?} of an integrated point")));
            }
        }
        if let Some(i) = p.per_set.iter().position(|v| !v.is_finite()) {
            return Err(at(format!("per_set[{i}] = {:?}", p.per_set[i])));
        }
        if let Some(i) = p.spectrum.iter().position(|v| !v.is_finite()) {
            return Err(at(format!("spectrum[{i}] = {:?}", p.spectrum[i])));
        }
    }
    // lambda_1..lambda_k of an integrated point of a spectrum map, nothing otherwise.
    let exponents = if ok && h.indicator == "spectrum" {
        h.k as usize
    } else {
        0
    };
    if p.spectrum.len() != exponents {
        return Err(at(format!(
            "{} exponents in spectrum, but a {} point of this {} map has {exponents}",
            p.spectrum.len(),
            if ok { "computed" } else { "failed" },
            h.indicator
        )));
    }
    if !(p.t_end.is_finite() && p.t_end >= 0.0) {
        return Err(at(format!("t_end = {:?}", p.t_end)));
    }
    Ok(())
}

impl MapContents {
    /// The header ([`check_header`]) and every point ([`check_point`]), as `header: field:
    /// problem` or `point N: field: problem`; a file without a header passes (its readers
    /// refuse it for that).
    pub fn check(&self) -> Result<(), String> {
        let Some(h) = &self.header else {
            return Ok(());
        };
        check_header(h).map_err(|e| format!("map header: {e}"))?;
        self.points.iter().try_for_each(|p| check_point(h, p))
    }
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
    contents.described_as_map = messages
        .metadata_names()
        .iter()
        .any(|name| name == metadata::MAP);
    let scan = messages.scan();
    contents.damaged = scan.stopped_at.clone();
    contents.cut_before_any_chunk = scan.cut && scan.chunks == 0;
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
    fn only_a_file_cut_before_its_first_chunk_holds_nothing() {
        let (bytes, _, _) = crate::testing::small_map(10, 6, Compression::Zstd);
        let first = crate::testing::chunk_offsets(&bytes)[0];
        let len = u64::from_le_bytes(bytes[first + 1..first + 9].try_into().unwrap());
        let first_chunk_end = first + 9 + len as usize;
        let read = |b: &[u8]| read_map(b, Some(b.len() as u64)).unwrap().unwrap();
        for cut in 8..bytes.len() {
            let part = read(&bytes[..cut]);
            // Cut before the first chunk is whole: no header, no point, nothing to keep.
            assert_eq!(
                part.cut_before_any_chunk,
                cut < first_chunk_end,
                "cut {cut}"
            );
            assert_eq!(part.header.is_none(), cut < first_chunk_end, "cut {cut}");
            // What the file is, it says before its first chunk: a killed map's leftover is
            // known as a map (and refused as a run's recording) even with no header read.
            if cut >= first {
                assert!(part.described_as_map, "cut {cut}");
            }
        }
        assert!(!read(&bytes).cut_before_any_chunk);
        // A damaged first chunk in a whole file is damage, not a cut: its later chunks are
        // worth keeping.
        let mut flipped = bytes.clone();
        flipped[first_chunk_end - 20] ^= 0x10;
        let part = read(&flipped);
        assert!(part.header.is_none() && part.damaged.is_some());
        assert!(!part.cut_before_any_chunk);
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
