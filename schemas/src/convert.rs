//! Bus frames to the protobuf messages stored in MCAP (the recorder's one translation step).

use prost::Message;

use crate::FORMAT_VERSION;
use crate::frame::{FrameHeader, FrameKind, RunAnnouncement, status};
use crate::proto::{EndOfRun, ReferenceState, RunHeader, SeparationSet, end_of_run};

/// A run header announcement that this build cannot read.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum HeaderError {
    #[error("run {run:?} uses format version {found}; this build reads version {FORMAT_VERSION}")]
    Version { run: String, found: u32 },
    #[error("run {run:?}: the run header is not valid protobuf: {source}")]
    Decode {
        run: String,
        source: prost::DecodeError,
    },
}

/// Checks the format version of a run announcement and decodes its header: the one place every
/// receiver (recorder, checker, monitor) reads a run header from the bus.
pub fn decode_run_header(
    run: &str,
    announcement: &RunAnnouncement,
    payload: &[u8],
) -> Result<RunHeader, HeaderError> {
    if announcement.format_version != FORMAT_VERSION {
        return Err(HeaderError::Version {
            run: run.to_string(),
            found: announcement.format_version,
        });
    }
    RunHeader::decode(payload).map_err(|source| HeaderError::Decode {
        run: run.to_string(),
        source,
    })
}

/// A frame that does not follow the layout of [`crate::frame`].
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum FrameError {
    #[error("frame {frame}: format version {found}, this build reads version {FORMAT_VERSION}")]
    Version { frame: u64, found: u32 },
    #[error("frame {frame}: unknown kind {kind}")]
    Kind { frame: u64, kind: u32 },
    #[error("frame {frame}: payload has {found} values, the header announces {expected}")]
    PayloadLength {
        frame: u64,
        expected: usize,
        found: usize,
    },
}

/// A validated data frame as a protobuf message.
#[derive(Debug, Clone, PartialEq)]
pub enum DataMessage {
    Reference(ReferenceState),
    Separations(SeparationSet),
    End(EndOfRun),
}

/// Checks a frame against the layout and converts it.
pub fn decode_frame(h: &FrameHeader, payload: &[f64]) -> Result<DataMessage, FrameError> {
    let frame = h.frame_seq;
    if h.format_version != FORMAT_VERSION {
        return Err(FrameError::Version {
            frame,
            found: h.format_version,
        });
    }
    let kind = h.kind().ok_or(FrameError::Kind {
        frame,
        kind: h.kind,
    })?;
    let expected = h.expected_payload_len().unwrap_or(0);
    if payload.len() != expected {
        return Err(FrameError::PayloadLength {
            frame,
            expected,
            found: payload.len(),
        });
    }
    Ok(match kind {
        FrameKind::Reference => DataMessage::Reference(ReferenceState {
            frame,
            seq: h.sample_seq,
            step: h.step,
            t: h.t,
            energy: h.energy,
            state: payload.to_vec(),
            mean_divergence: h.mean_divergence,
        }),
        FrameKind::Separations => {
            let split = h.k as usize * h.dim as usize;
            DataMessage::Separations(SeparationSet {
                frame,
                seq: h.sample_seq,
                step: h.step,
                t: h.t,
                scheme: h.scheme,
                set: h.set,
                k: h.k,
                dim: h.dim,
                separations: payload[..split].to_vec(),
                stretch: payload[split..].to_vec(),
            })
        }
        FrameKind::End => DataMessage::End(EndOfRun {
            frame,
            status: end_status(h.status) as i32,
            reason: h.reason(),
            samples: h.sample_seq,
            last_step: h.step,
            t: h.t,
        }),
    })
}

/// Protobuf status of a bus status code (unknown codes map to `Unspecified`).
pub fn end_status(code: u32) -> end_of_run::Status {
    match code {
        status::COMPLETED => end_of_run::Status::Completed,
        status::INTERRUPTED => end_of_run::Status::Interrupted,
        status::FAILED => end_of_run::Status::Failed,
        _ => end_of_run::Status::Unspecified,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn separations_split_vectors_and_stretch() {
        let h = FrameHeader::separations(7, 3, 300, 3.0, 1, 0, 2, 2);
        let payload = [1.0, 2.0, 3.0, 4.0, 0.5, 0.25];
        let DataMessage::Separations(m) = decode_frame(&h, &payload).unwrap() else {
            panic!()
        };
        assert_eq!(m.separations, vec![1.0, 2.0, 3.0, 4.0]);
        assert_eq!(m.stretch, vec![0.5, 0.25]);
        assert_eq!((m.frame, m.seq, m.scheme), (7, 3, 1));
    }

    #[test]
    fn wrong_payload_length_is_an_error() {
        let h = FrameHeader::reference(0, 0, 0, 0.0, 0.1, 0.0, 4);
        let err = decode_frame(&h, &[0.0; 3]).unwrap_err();
        assert_eq!(
            err,
            FrameError::PayloadLength {
                frame: 0,
                expected: 4,
                found: 3
            }
        );
    }

    #[test]
    fn end_carries_status_and_reason() {
        let h = FrameHeader::end(9, 5, 500, 5.0, status::FAILED, "energy drift");
        let DataMessage::End(m) = decode_frame(&h, &[]).unwrap() else {
            panic!()
        };
        assert_eq!(m.status(), end_of_run::Status::Failed);
        assert_eq!(m.reason, "energy drift");
    }
}

#[cfg(test)]
mod run_header_tests {
    use super::*;

    #[test]
    fn run_header_is_decoded_once_checked() {
        let header = RunHeader {
            run_name: "r".into(),
            format_version: FORMAT_VERSION,
            ..Default::default()
        };
        let bytes = header.encode_to_vec();
        let ok = RunAnnouncement::default();
        assert_eq!(decode_run_header("r", &ok, &bytes).unwrap(), header);
        let old = RunAnnouncement {
            format_version: FORMAT_VERSION + 1,
            ..Default::default()
        };
        assert!(matches!(
            decode_run_header("r", &old, &bytes),
            Err(HeaderError::Version { found, .. }) if found == FORMAT_VERSION + 1
        ));
        let err = decode_run_header("r", &ok, &[0xff, 0xff, 0xff]).unwrap_err();
        assert!(err.to_string().contains("not valid protobuf"), "{err}");
    }
}
