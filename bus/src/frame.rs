//! What travels on the iceoryx2 bus: `#[repr(C)]` user headers and the payload layout.
//!
//! The data stream is a publish-subscribe service with payload `[u64]` (words) and user header
//! [`FrameHeader`]. What a run publishes is a sequence of *records* (a reference state, a
//! separation set, the end of the run), each numbered by `frame_seq` counting every record of the
//! run from 0, so a receiver proves there is no gap by checking it increments by one; these
//! numbers are the `frame` fields of the recorded messages. A bus frame carries several records
//! (the per-frame cost of the bus, a loan, a send, a wake-up and a receive, is then paid once for
//! many small samples): `frame_seq` is the number of its first record and `records` how many it
//! holds, numbered consecutively.
//!
//! | kind      | payload (u64 words)                                              |
//! |-----------|------------------------------------------------------------------|
//! | `Records` | `records` records, one after another (layout below)              |
//! | `End`     | empty, one record; samples, step, t, status and reason in the header |
//!
//! A record is [`RECORD_HEADER_WORDS`] words, then its values (f64 as their bits):
//!
//! | word | `Reference` record             | `Separations` record                   |
//! |------|--------------------------------|----------------------------------------|
//! | 0    | kind 1                         | kind 2                                 |
//! | 1    | sample number                  | sample number                          |
//! | 2    | step                           | step                                   |
//! | 3    | t                              | t                                      |
//! | 4    | energy                         | scheme index                           |
//! | 5    | mean divergence                | set                                    |
//! | 6    | divergence sum                 | `k` + 2^32 x earlier renormalizations  |
//! | 7    | `dim`                          | `dim`                                  |
//! | then | the state (`dim` values)       | `k` vectors of `dim`, `k` stretches,   |
//! |      |                                | `k` per earlier renormalization        |
//!
//! The layout is the bus protocol [`BUS_PROTOCOL`]; it is part of the header's type name, so
//! processes built with another layout refuse to connect instead of misreading frames.
//!
//! Maps (`chaoscope map`) publish on their own services (`chaoscope/map/<name>/...`, see
//! [`chaoscope_schemas::names`]), with payload `[u8]` and user header [`MapFrameHeader`]:
//!
//! | service  | kind     | payload (bytes)                                        |
//! |----------|----------|--------------------------------------------------------|
//! | `header` | `Header` | protobuf `MapHeader` (history 1, for late subscribers) |
//! | `points` | `Point`  | protobuf `MapPoint`, exactly as recorded to MCAP        |
//! | `points` | `End`    | empty; `seq` = points published, `status` as [`status`] |
//!
//! The point stream is lossy (a slow watcher loses the oldest points, the map never waits):
//! `seq` counts the points published from 0, so a watcher counts what it missed as
//! `end.seq - received`.

use iceoryx2::prelude::*;

use chaoscope_schemas::FORMAT_VERSION;

/// Version of the data frames' layout on the bus (not of the files: [`FORMAT_VERSION`]).
/// 2: several records per frame, payload in words. 3: the reference record's word 6 carries
/// the divergence sum (0 before); a separation record's word 6 the number of earlier
/// renormalizations in its high half, their stretching factors after its own.
pub const BUS_PROTOCOL: u32 = 3;

/// Longest end-of-run reason carried on the bus (longer reasons are cut at a char boundary).
pub const MAX_REASON_LEN: usize = 240;

/// Words of a record's header (see the module docs).
pub const RECORD_HEADER_WORDS: usize = 8;

/// What a data frame contains.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u32)]
pub enum FrameContent {
    Records = 1,
    End = 3,
}

impl FrameContent {
    pub fn from_u32(v: u32) -> Option<Self> {
        match v {
            1 => Some(Self::Records),
            3 => Some(Self::End),
            _ => None,
        }
    }
}

/// What a record of a `Records` frame is (word 0 of its header).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u64)]
pub enum RecordContent {
    Reference = 1,
    Separations = 2,
}

/// End-of-run status codes (same numbers as `proto::end_of_run::Status`).
pub mod status {
    pub const COMPLETED: u32 = 1;
    pub const INTERRUPTED: u32 = 2;
    pub const FAILED: u32 = 3;
}

/// User header of every frame of the data and monitor streams.
#[derive(Debug, Clone, Copy, ZeroCopySend)]
#[repr(C)]
#[type_name("chaoscope.bus2.FrameHeader")]
pub struct FrameHeader {
    pub format_version: u32,
    /// A [`FrameContent`] as u32.
    pub kind: u32,
    /// Number of the frame's first record, counting every record of the run from 0.
    pub frame_seq: u64,
    /// Records in this frame, numbered `frame_seq..frame_seq + records` (1 for `End`).
    pub records: u64,
    /// `End` only: the number of samples published, and the step and time of the last.
    pub sample_seq: u64,
    pub step: u64,
    pub t: f64,
    /// End-of-run status (`End` only), see [`status`].
    pub status: u32,
    pub reason_len: u32,
    pub reason: [u8; MAX_REASON_LEN],
}

impl Default for FrameHeader {
    fn default() -> Self {
        Self {
            format_version: FORMAT_VERSION,
            kind: 0,
            frame_seq: 0,
            records: 0,
            sample_seq: 0,
            step: 0,
            t: 0.0,
            status: 0,
            reason_len: 0,
            reason: [0; MAX_REASON_LEN],
        }
    }
}

impl FrameHeader {
    pub fn kind(&self) -> Option<FrameContent> {
        FrameContent::from_u32(self.kind)
    }

    /// Stores `reason`, cut to [`MAX_REASON_LEN`] bytes at a char boundary.
    pub fn set_reason(&mut self, reason: &str) {
        let mut end = reason.len().min(MAX_REASON_LEN);
        while !reason.is_char_boundary(end) {
            end -= 1;
        }
        self.reason[..end].copy_from_slice(&reason.as_bytes()[..end]);
        self.reason_len = end as u32;
    }

    pub fn reason(&self) -> String {
        let len = (self.reason_len as usize).min(MAX_REASON_LEN);
        String::from_utf8_lossy(&self.reason[..len]).into_owned()
    }

    /// Header of a frame of `records` records, the first numbered `frame_seq`.
    pub fn records(frame_seq: u64, records: u64) -> Self {
        Self {
            kind: FrameContent::Records as u32,
            frame_seq,
            records,
            ..Self::default()
        }
    }

    /// Header of the end-of-run frame (empty payload); `samples` = samples published.
    pub fn end(frame_seq: u64, samples: u64, step: u64, t: f64, status: u32, reason: &str) -> Self {
        let mut h = Self {
            kind: FrameContent::End as u32,
            frame_seq,
            records: 1,
            sample_seq: samples,
            step,
            t,
            status,
            ..Self::default()
        };
        h.set_reason(reason);
        h
    }
}

/// Words of a separation-set record of `k` vectors of `dim` values, carrying the stretching
/// factors of `earlier` renormalizations before it.
pub fn separations_record_words(k: usize, dim: usize, earlier: usize) -> usize {
    RECORD_HEADER_WORDS + k * dim + k + earlier * k
}

/// Words of a reference-state record of dimension `dim`.
pub fn reference_record_words(dim: usize) -> usize {
    RECORD_HEADER_WORDS + dim
}

/// Records of one frame being assembled by a producer: the payload of a `Records` frame.
#[derive(Debug, Clone, Default)]
pub struct RecordBatch {
    words: Vec<u64>,
    first: u64,
    records: u64,
    /// Words of values (not of record headers).
    value_words: usize,
}

impl RecordBatch {
    /// An empty batch whose first record will be number `first`.
    pub fn new(first: u64) -> Self {
        Self {
            first,
            ..Self::default()
        }
    }

    /// Empties the batch (keeping its memory); the next record is number `first`.
    pub fn reset(&mut self, first: u64) {
        self.words.clear();
        self.first = first;
        self.records = 0;
        self.value_words = 0;
    }

    pub fn is_empty(&self) -> bool {
        self.records == 0
    }

    /// Number the next record pushed gets.
    pub fn next_frame(&self) -> u64 {
        self.first + self.records
    }

    /// The payload so far.
    pub fn words(&self) -> &[u64] {
        &self.words
    }

    /// Words of values (f64) in the batch, record headers not counted.
    pub fn value_words(&self) -> usize {
        self.value_words
    }

    /// The user header of the frame carrying this batch.
    pub fn header(&self) -> FrameHeader {
        FrameHeader::records(self.first, self.records)
    }

    fn push_record(&mut self, head: [u64; RECORD_HEADER_WORDS], parts: &[&[f64]]) {
        self.words.extend_from_slice(&head);
        for part in parts {
            self.words.extend(part.iter().map(|v| v.to_bits()));
            self.value_words += part.len();
        }
        self.records += 1;
    }

    /// Appends a reference-state record.
    #[allow(clippy::too_many_arguments)]
    pub fn push_reference(
        &mut self,
        sample_seq: u64,
        step: u64,
        t: f64,
        energy: f64,
        mean_divergence: f64,
        divergence_sum: f64,
        state: &[f64],
    ) {
        let head = [
            RecordContent::Reference as u64,
            sample_seq,
            step,
            t.to_bits(),
            energy.to_bits(),
            mean_divergence.to_bits(),
            divergence_sum.to_bits(),
            state.len() as u64,
        ];
        self.push_record(head, &[state]);
    }

    /// Appends a separation-set record: `separations` are `stretch.len()` vectors of `dim`;
    /// `earlier_stretch` the stretching factors of the renormalizations since the previous
    /// sample, `stretch.len()` per renormalization (empty unless the run is sampled every
    /// `sample_every`).
    #[allow(clippy::too_many_arguments)]
    pub fn push_separations(
        &mut self,
        sample_seq: u64,
        step: u64,
        t: f64,
        scheme: u32,
        set: u32,
        dim: usize,
        separations: &[f64],
        stretch: &[f64],
        earlier_stretch: &[f64],
    ) {
        let k = stretch.len();
        let earlier = earlier_stretch.len().checked_div(k).unwrap_or(0);
        let head = [
            RecordContent::Separations as u64,
            sample_seq,
            step,
            t.to_bits(),
            scheme as u64,
            set as u64,
            k as u64 | (earlier as u64) << 32,
            dim as u64,
        ];
        self.push_record(head, &[separations, stretch, earlier_stretch]);
    }
}

/// User header of the run-header stream, whose payload is a protobuf `RunHeader`.
#[derive(Debug, Clone, Copy, ZeroCopySend)]
#[repr(C)]
#[type_name("chaoscope.v1.RunAnnouncement")]
pub struct RunAnnouncement {
    pub format_version: u32,
    /// Process id of the producer (informational; liveness goes through iceoryx2 nodes).
    pub producer_pid: u32,
}

impl Default for RunAnnouncement {
    fn default() -> Self {
        Self {
            format_version: FORMAT_VERSION,
            producer_pid: 0,
        }
    }
}

/// What a map frame contains.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u32)]
pub enum MapFrameContent {
    Header = 1,
    Point = 2,
    End = 3,
}

impl MapFrameContent {
    pub fn from_u32(v: u32) -> Option<Self> {
        match v {
            1 => Some(Self::Header),
            2 => Some(Self::Point),
            3 => Some(Self::End),
            _ => None,
        }
    }
}

/// User header of the map services (payload: protobuf bytes, see the module docs).
#[derive(Debug, Clone, Copy, ZeroCopySend)]
#[repr(C)]
#[type_name("chaoscope.v1.MapFrameHeader")]
pub struct MapFrameHeader {
    pub format_version: u32,
    /// A [`MapFrameContent`] as u32.
    pub kind: u32,
    /// `Point`: its number among the points published, from 0. `End`: points published.
    pub seq: u64,
    /// End-of-map status (`End` only), see [`status`].
    pub status: u32,
    /// Process id of the map process (informational).
    pub producer_pid: u32,
}

impl Default for MapFrameHeader {
    fn default() -> Self {
        Self {
            format_version: FORMAT_VERSION,
            kind: 0,
            seq: 0,
            status: 0,
            producer_pid: 0,
        }
    }
}

impl MapFrameHeader {
    pub fn new(kind: MapFrameContent, seq: u64, status: u32) -> Self {
        Self {
            format_version: FORMAT_VERSION,
            kind: kind as u32,
            seq,
            status,
            producer_pid: std::process::id(),
        }
    }

    pub fn kind(&self) -> Option<MapFrameContent> {
        MapFrameContent::from_u32(self.kind)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reason_is_cut_at_a_char_boundary() {
        let mut h = FrameHeader::default();
        h.set_reason(&"é".repeat(200));
        assert!(h.reason_len as usize <= MAX_REASON_LEN);
        assert!(h.reason().chars().all(|c| c == 'é'));
    }

    #[test]
    fn a_batch_numbers_its_records_from_its_first() {
        let mut b = RecordBatch::new(5);
        assert!(b.is_empty());
        b.push_reference(0, 0, 0.0, 0.125, 0.0, 0.0, &[1.0, 2.0]);
        b.push_separations(0, 0, 0.0, 1, 0, 2, &[0.5, 0.25], &[1.0], &[]);
        assert_eq!((b.next_frame(), b.value_words()), (7, 5));
        assert_eq!(
            b.words().len(),
            reference_record_words(2) + separations_record_words(1, 2, 0)
        );
        let h = b.header();
        assert_eq!(
            (h.kind(), h.frame_seq, h.records),
            (Some(FrameContent::Records), 5, 2)
        );
        b.reset(7);
        assert!(b.is_empty() && b.words().is_empty());
        assert_eq!(b.next_frame(), 7);
    }
}
