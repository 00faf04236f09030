//! Bus frames to the protobuf messages stored in MCAP (the recorder's one translation step).

use chaoscope_schemas::FORMAT_VERSION;
use chaoscope_schemas::proto::{
    DataMessage, EndOfRun, ReferenceState, RunHeader, SeparationSet, end_of_run,
};
use prost::Message;

use crate::frame::{
    FrameContent, FrameHeader, RECORD_HEADER_WORDS, RecordContent, RunAnnouncement, status,
};

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
    Kind { frame: u64, kind: u64 },
    #[error("frame {frame}: {problem}")]
    Layout { frame: u64, problem: String },
}

fn f64s(words: &[u64]) -> Vec<f64> {
    words.iter().map(|w| f64::from_bits(*w)).collect()
}

/// Checks a frame against the layout and converts its records, in order, into `out`. A frame
/// that breaks the layout anywhere is refused whole (nothing is added to `out`): its records
/// then show as a gap in the numbering.
pub fn decode_frame(
    h: &FrameHeader,
    payload: &[u64],
    out: &mut Vec<DataMessage>,
) -> Result<(), FrameError> {
    let frame = h.frame_seq;
    if h.format_version != FORMAT_VERSION {
        return Err(FrameError::Version {
            frame,
            found: h.format_version,
        });
    }
    let layout = |problem: String| FrameError::Layout { frame, problem };
    match h.kind() {
        Some(FrameContent::End) => {
            if !payload.is_empty() || h.records != 1 {
                return Err(layout(format!(
                    "end of run with {} records and {} payload words",
                    h.records,
                    payload.len()
                )));
            }
            out.push(DataMessage::End(EndOfRun {
                frame,
                status: end_status(h.status) as i32,
                reason: h.reason(),
                samples: h.sample_seq,
                last_step: h.step,
                t: h.t,
            }));
            Ok(())
        }
        Some(FrameContent::Records) => {
            let start = out.len();
            let result = decode_records(h, payload, out);
            if result.is_err() {
                out.truncate(start);
            }
            result
        }
        None => Err(FrameError::Kind {
            frame,
            kind: h.kind as u64,
        }),
    }
}

fn decode_records(
    h: &FrameHeader,
    payload: &[u64],
    out: &mut Vec<DataMessage>,
) -> Result<(), FrameError> {
    let layout = |problem: String| FrameError::Layout {
        frame: h.frame_seq,
        problem,
    };
    let mut rest = payload;
    for i in 0..h.records {
        let frame = h.frame_seq.wrapping_add(i);
        let Some((head, values)) = rest.split_first_chunk::<RECORD_HEADER_WORDS>() else {
            return Err(layout(format!(
                "record {i} of {} is cut short ({} words left)",
                h.records,
                rest.len()
            )));
        };
        let [kind, seq, step, t, a, b, word6, dim] = *head;
        // A separation record's word 6: k, and the renormalizations before it in the high half.
        let (k, earlier) = (word6 & u64::from(u32::MAX), word6 >> 32);
        let t = f64::from_bits(t);
        // Sizes from another process are checked before they size anything.
        let len = match kind {
            1 => Some(dim),
            2 => k
                .checked_mul(dim)
                .and_then(|n| n.checked_add(k))
                .and_then(|n| n.checked_add(earlier.checked_mul(k)?)),
            _ => return Err(FrameError::Kind { frame, kind }),
        };
        let Some(len) = len
            .filter(|&n| n <= values.len() as u64)
            .map(|n| n as usize)
        else {
            return Err(layout(format!(
                "record {i} announces more values than the frame holds (k = {k}, dim = {dim})"
            )));
        };
        let (body, next) = values.split_at(len);
        rest = next;
        out.push(if kind == RecordContent::Reference as u64 {
            DataMessage::Reference(ReferenceState {
                frame,
                seq,
                step,
                t,
                energy: f64::from_bits(a),
                state: f64s(body),
                mean_divergence: f64::from_bits(b),
                divergence_sum: f64::from_bits(word6),
            })
        } else {
            let (Ok(scheme), Ok(set), Ok(k32), Ok(dim32)) = (
                u32::try_from(a),
                u32::try_from(b),
                u32::try_from(k),
                u32::try_from(dim),
            ) else {
                return Err(layout(format!("record {i}: a field beyond 32 bits")));
            };
            let (separations, rest) = body.split_at((k * dim) as usize);
            let (stretch, earlier_stretch) = rest.split_at(k as usize);
            DataMessage::Separations(SeparationSet {
                frame,
                seq,
                step,
                t,
                scheme,
                set,
                k: k32,
                dim: dim32,
                separations: f64s(separations),
                stretch: f64s(stretch),
                earlier_stretch: f64s(earlier_stretch),
            })
        });
    }
    if !rest.is_empty() {
        return Err(layout(format!(
            "{} words after the {} records",
            rest.len(),
            h.records
        )));
    }
    Ok(())
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

    use crate::frame::RecordBatch;

    fn decode(h: &FrameHeader, words: &[u64]) -> Result<Vec<DataMessage>, FrameError> {
        let mut out = vec![DataMessage::End(EndOfRun::default())];
        let r = decode_frame(h, words, &mut out);
        // What was in `out` stays; a refused frame adds nothing.
        assert_eq!(out.remove(0), DataMessage::End(EndOfRun::default()));
        r.map(|_| out)
    }

    #[test]
    fn records_come_back_numbered_with_every_bit() {
        let mut b = RecordBatch::new(7);
        // Values whose bits a conversion through decimal or arithmetic could change.
        let state = [-0.0, f64::MIN_POSITIVE / 4.0, 1.0 / 3.0, -2.5e300];
        b.push_reference(3, 300, 3.0, 0.125, -1e-17, -3e-17, &state);
        let earlier = [0.9, 1.1, 2.0, 0.75];
        b.push_separations(
            3,
            300,
            3.0,
            1,
            2,
            2,
            &[1.0, 2.0, 3.0, 4.0],
            &[0.5, 0.25],
            &earlier,
        );
        let out = decode(&b.header(), b.words()).unwrap();
        let DataMessage::Reference(r) = &out[0] else {
            panic!()
        };
        assert_eq!((r.frame, r.seq, r.step, r.t), (7, 3, 300, 3.0));
        assert_eq!(
            (r.energy, r.mean_divergence, r.divergence_sum),
            (0.125, -1e-17, -3e-17)
        );
        let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        assert_eq!(bits(&r.state), bits(&state));
        let DataMessage::Separations(m) = &out[1] else {
            panic!()
        };
        assert_eq!(m.separations, vec![1.0, 2.0, 3.0, 4.0]);
        assert_eq!(m.stretch, vec![0.5, 0.25]);
        assert_eq!(m.earlier_stretch, earlier);
        assert_eq!(
            (m.frame, m.seq, m.scheme, m.set, m.k, m.dim),
            (8, 3, 1, 2, 2, 2)
        );
        assert_eq!(
            out.iter().map(DataMessage::frame).collect::<Vec<_>>(),
            [7, 8]
        );
    }

    #[test]
    fn a_frame_breaking_the_layout_is_refused_whole() {
        let mut b = RecordBatch::new(0);
        b.push_reference(0, 0, 0.0, 0.1, 0.0, 0.0, &[1.0; 4]);
        b.push_separations(0, 0, 0.0, 0, 0, 2, &[1.0; 4], &[1.0; 2], &[]);
        let words = b.words().to_vec();
        let h = b.header();
        // Cut short, one word too many, more records announced than sent, fewer.
        assert!(decode(&h, &words[..words.len() - 1]).is_err());
        let mut long = words.clone();
        long.push(0);
        assert!(decode(&h, &long).is_err());
        assert!(decode(&FrameHeader::records(0, 3), &words).is_err());
        assert!(decode(&FrameHeader::records(0, 1), &words).is_err());
        // Sizes that overflow, and an unknown record kind.
        let mut huge = words.clone();
        huge[RECORD_HEADER_WORDS + 4 + 6] = u64::MAX;
        assert!(decode(&h, &huge).is_err());
        let mut kind = words.clone();
        kind[0] = 9;
        assert!(matches!(
            decode(&h, &kind),
            Err(FrameError::Kind { kind: 9, .. })
        ));
        let bad = FrameHeader { kind: 99, ..h };
        assert!(decode(&bad, &words).is_err());
        assert_eq!(decode(&h, &words).unwrap().len(), 2);
    }

    #[test]
    fn end_carries_status_and_reason() {
        let h = FrameHeader::end(9, 5, 500, 5.0, status::FAILED, "energy drift");
        let out = decode(&h, &[]).unwrap();
        let DataMessage::End(m) = &out[0] else {
            panic!()
        };
        assert_eq!(m.status(), end_of_run::Status::Failed);
        assert_eq!(
            (m.reason.as_str(), m.frame, m.samples),
            ("energy drift", 9, 5)
        );
        assert!(decode(&h, &[0]).is_err());
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
