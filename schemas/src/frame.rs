//! What travels on the iceoryx2 bus: `#[repr(C)]` user headers and the payload layout.
//!
//! The data stream is a publish-subscribe service with payload `[f64]` and user header
//! [`FrameHeader`]. Every frame carries `frame_seq`, counting all frames of the run from 0, so a
//! receiver proves there is no gap by checking it increments by one. Payload layout per kind:
//!
//! | kind          | payload (f64)                                         |
//! |---------------|-------------------------------------------------------|
//! | `Reference`   | state q1..qN, p1..pN (`dim` values)                   |
//! | `Separations` | `k` vectors of `dim` values, then `k` stretch factors |
//! | `End`         | empty; status and reason are in the header            |
//!
//! Maps (`chaoscope map`) publish on their own services (`chaoscope/map/<name>/...`, see
//! [`crate::names`]), with payload `[u8]` and user header [`MapFrameHeader`]:
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

use crate::FORMAT_VERSION;

/// Longest end-of-run reason carried on the bus (longer reasons are cut at a char boundary).
pub const MAX_REASON_LEN: usize = 240;

/// What a data frame contains.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u32)]
pub enum FrameKind {
    Reference = 1,
    Separations = 2,
    End = 3,
}

impl FrameKind {
    pub fn from_u32(v: u32) -> Option<Self> {
        match v {
            1 => Some(Self::Reference),
            2 => Some(Self::Separations),
            3 => Some(Self::End),
            _ => None,
        }
    }
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
#[type_name("chaoscope.v1.FrameHeader")]
pub struct FrameHeader {
    pub format_version: u32,
    /// A [`FrameKind`] as u32.
    pub kind: u32,
    /// Counts every frame of the run from 0 (gap detection).
    pub frame_seq: u64,
    /// Sample number (0 = initial state); for `End`, the number of samples published.
    pub sample_seq: u64,
    pub step: u64,
    pub t: f64,
    /// Energy of the reference state (`Reference` only).
    pub energy: f64,
    /// Mean divergence along the reference orbit up to `t` (`Reference` only; see the
    /// `ReferenceState` message).
    pub mean_divergence: f64,
    /// Scheme index and set (`Separations` only).
    pub scheme: u32,
    pub set: u32,
    /// Vectors per set and their dimension 2N.
    pub k: u32,
    pub dim: u32,
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
            sample_seq: 0,
            step: 0,
            t: 0.0,
            energy: 0.0,
            mean_divergence: 0.0,
            scheme: 0,
            set: 0,
            k: 0,
            dim: 0,
            status: 0,
            reason_len: 0,
            reason: [0; MAX_REASON_LEN],
        }
    }
}

impl FrameHeader {
    pub fn kind(&self) -> Option<FrameKind> {
        FrameKind::from_u32(self.kind)
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

    /// Header of a reference-state frame (payload: the `dim` state values).
    #[allow(clippy::too_many_arguments)]
    pub fn reference(
        frame_seq: u64,
        sample_seq: u64,
        step: u64,
        t: f64,
        energy: f64,
        mean_divergence: f64,
        dim: usize,
    ) -> Self {
        Self {
            kind: FrameKind::Reference as u32,
            frame_seq,
            sample_seq,
            step,
            t,
            energy,
            mean_divergence,
            dim: dim as u32,
            ..Self::default()
        }
    }

    /// Header of a separation-set frame (payload: `k * dim` separations, then `k` stretches).
    #[allow(clippy::too_many_arguments)]
    pub fn separations(
        frame_seq: u64,
        sample_seq: u64,
        step: u64,
        t: f64,
        scheme: u32,
        set: u32,
        k: usize,
        dim: usize,
    ) -> Self {
        Self {
            kind: FrameKind::Separations as u32,
            frame_seq,
            sample_seq,
            step,
            t,
            scheme,
            set,
            k: k as u32,
            dim: dim as u32,
            ..Self::default()
        }
    }

    /// Header of the end-of-run frame (empty payload); `samples` = samples published.
    pub fn end(frame_seq: u64, samples: u64, step: u64, t: f64, status: u32, reason: &str) -> Self {
        let mut h = Self {
            kind: FrameKind::End as u32,
            frame_seq,
            sample_seq: samples,
            step,
            t,
            status,
            ..Self::default()
        };
        h.set_reason(reason);
        h
    }

    /// Number of f64 values the payload of this frame must have.
    pub fn expected_payload_len(&self) -> Option<usize> {
        let (k, dim) = (self.k as usize, self.dim as usize);
        match self.kind()? {
            FrameKind::Reference => Some(dim),
            FrameKind::Separations => Some(k * dim + k),
            FrameKind::End => Some(0),
        }
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
pub enum MapFrameKind {
    Header = 1,
    Point = 2,
    End = 3,
}

impl MapFrameKind {
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
    /// A [`MapFrameKind`] as u32.
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
    pub fn new(kind: MapFrameKind, seq: u64, status: u32) -> Self {
        Self {
            format_version: FORMAT_VERSION,
            kind: kind as u32,
            seq,
            status,
            producer_pid: std::process::id(),
        }
    }

    pub fn kind(&self) -> Option<MapFrameKind> {
        MapFrameKind::from_u32(self.kind)
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
    fn payload_lengths_follow_the_layout() {
        let h = FrameHeader {
            kind: FrameKind::Separations as u32,
            k: 4,
            dim: 4,
            ..Default::default()
        };
        assert_eq!(h.expected_payload_len(), Some(20));
        let bad = FrameHeader {
            kind: 99,
            ..Default::default()
        };
        assert_eq!(bad.expected_payload_len(), None);
    }
}
