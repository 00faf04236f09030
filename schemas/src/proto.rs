//! Protobuf messages of the MCAP recordings (generated from `proto/chaoscope/v1/chaoscope.proto`).

#![allow(clippy::all, missing_docs)]

include!(concat!(env!("OUT_DIR"), "/chaoscope.v1.rs"));

/// Serialized `google.protobuf.FileDescriptorSet` of the contract: the data of every MCAP schema
/// record, so `mcap-protobuf-support`, Foxglove and friends decode the messages.
pub static FILE_DESCRIPTOR_SET: &[u8] =
    include_bytes!(concat!(env!("OUT_DIR"), "/chaoscope_v1.fds.bin"));

/// MCAP schema encoding of all chaoscope schemas.
pub const SCHEMA_ENCODING: &str = "protobuf";
/// MCAP message encoding of all chaoscope channels.
pub const MESSAGE_ENCODING: &str = "protobuf";

/// Fully qualified protobuf names: the MCAP schema names.
pub mod schema_name {
    pub const RUN_HEADER: &str = "chaoscope.v1.RunHeader";
    pub const REFERENCE_STATE: &str = "chaoscope.v1.ReferenceState";
    pub const SEPARATION_SET: &str = "chaoscope.v1.SeparationSet";
    pub const END_OF_RUN: &str = "chaoscope.v1.EndOfRun";
    pub const RECORDING_SUMMARY: &str = "chaoscope.v1.RecordingSummary";
    pub const INDICATORS: &str = "chaoscope.v1.Indicators";
    pub const MAP_HEADER: &str = "chaoscope.v1.MapHeader";
    pub const MAP_POINT: &str = "chaoscope.v1.MapPoint";
}

impl MapAxis {
    /// What the axis varies: the parameter of a parameter axis, else the coordinate (axis
    /// labels, column names).
    pub fn name(&self) -> &str {
        if self.param.is_empty() {
            &self.coord
        } else {
            &self.param
        }
    }
}

impl end_of_run::Status {
    /// Lower-case word used in metadata and summaries.
    pub fn word(self) -> &'static str {
        match self {
            Self::Unspecified => "unknown",
            Self::Completed => "completed",
            Self::Interrupted => "interrupted",
            Self::Failed => "failed",
        }
    }
}

/// One record of a run as the protobuf message a recording stores it in: what the bus's
/// frames decode to and what files are written from.
#[derive(Debug, Clone, PartialEq)]
pub enum DataMessage {
    Reference(ReferenceState),
    Separations(SeparationSet),
    End(EndOfRun),
}

impl DataMessage {
    /// The record's number (`frame_seq`), the recorded `frame` field.
    pub fn frame(&self) -> u64 {
        match self {
            Self::Reference(m) => m.frame,
            Self::Separations(m) => m.frame,
            Self::End(m) => m.frame,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use prost::Message;

    #[test]
    fn descriptor_set_names_every_schema() {
        let text = String::from_utf8_lossy(FILE_DESCRIPTOR_SET);
        for name in [
            "RunHeader",
            "ReferenceState",
            "SeparationSet",
            "EndOfRun",
            "RecordingSummary",
            "Indicators",
            "MapHeader",
            "MapPoint",
        ] {
            assert!(
                text.contains(name),
                "{name} missing from the descriptor set"
            );
        }
    }

    #[test]
    fn repeated_double_is_packed() {
        let m = ReferenceState {
            state: vec![1.0, 2.0],
            ..Default::default()
        };
        let bytes = m.encode_to_vec();
        // tag 6 wire type 2 (length-delimited), length 16, then the raw doubles
        let i = bytes.iter().position(|&b| b == (6 << 3 | 2)).unwrap();
        assert_eq!(bytes[i + 1], 16);
        assert_eq!(&bytes[i + 2..i + 10], &1.0f64.to_le_bytes());
    }
}
