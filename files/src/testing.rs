//! Test support shared by the workspace's test suites (recorder, analyzer, the binary's
//! end-to-end tests) and benches; no program uses it.
//!
//! - Synthetic recordings written by the recorder's own [`Recording`] (the layout, chunking and
//!   compression of `chaoscope record`), with pseudo-random separation vectors that compress
//!   about as badly as a real run's; small map recordings written by [`MapFile`].
//! - Hostile variants of a file, for the rule that every input file is hostile: cut at many
//!   offsets, single bit flips, random record streams after a valid magic, a short attachment,
//!   huge length fields, zero-filled tails ([`hostile`] chains them all).
//! - Valid files with hostile values ([`values`]): well-formed recordings and map files whose
//!   field values (sizes, times, stretch factors, axes, counts, names) are chosen by a byte
//!   stream, for the structure-aware fuzz target and the tests of every reader.

pub mod values;

use std::io::{Cursor, Seek, Write};

use crate::file::{Compression, FileOptions};
use crate::map_file::MapFile;
use crate::recording::{FinalizedBy, Recording};
use chaoscope_schemas::proto::DataMessage;
use chaoscope_schemas::proto::{
    EndOfRun, MapHeader, MapPoint, ReferenceState, RunHeader, Scheme, SeparationSet, end_of_run,
};

/// What one synthetic run holds: per sample a reference state of `dim` doubles and `sets`
/// separation sets of `k` x `dim` doubles.
pub struct Shape {
    pub dim: u32,
    pub k: u32,
    pub sets: u32,
    pub samples: u64,
}

/// xorshift64*: deterministic noise without a dependency.
pub struct Noise(u64);

impl Noise {
    pub fn new(seed: u64) -> Self {
        Self(seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1)
    }

    pub fn next_u64(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_F491_4F6C_DD1D)
    }

    /// Uniform in [-scale, scale), full 53-bit mantissas.
    pub fn next_f64(&mut self, scale: f64) -> f64 {
        ((self.next_u64() >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0) * scale
    }

    pub fn bytes(&mut self, n: usize) -> Vec<u8> {
        (0..n).map(|_| (self.next_u64() >> 56) as u8).collect()
    }
}

/// A temporary directory in memory (`/dev/shm`, tmpfs) when the machine has one, else in the
/// usual temporary directory. For tests that write an output hundreds of times: every output is
/// synced to its disk before it is renamed into place, which costs milliseconds on a disk and
/// nothing in memory; the bytes written and read back are the same either way.
pub fn scratch_dir() -> tempfile::TempDir {
    // tempdir_in fails where /dev/shm is missing or not writable: then the usual directory.
    tempfile::tempdir_in("/dev/shm")
        .or_else(|_| tempfile::tempdir())
        .expect("a temporary directory")
}

/// Writes a whole run (header, samples, end of run, summary) in the recorder's layout.
pub fn write_run<W: Write + Seek>(
    out: W,
    shape: &Shape,
    options: &FileOptions,
    seed: u64,
) -> mcap::McapResult<W> {
    write_run_with(out, shape, options, seed, |_| {})
}

/// [`write_run`] with the run header changed by `edit` first (hostile headers: names, configs).
pub fn write_run_with<W: Write + Seek>(
    out: W,
    shape: &Shape,
    options: &FileOptions,
    seed: u64,
    edit: impl FnOnce(&mut RunHeader),
) -> mcap::McapResult<W> {
    let (header, messages) = run_messages_with(shape, seed, edit);
    let mut recording = Recording::start(out, &header, options)?;
    for m in &messages {
        recording.on_message(m)?;
    }
    Ok(recording.finish(FinalizedBy::EndOfRun)?.0)
}

/// The header and messages [`write_run`] writes.
pub fn run_messages(shape: &Shape, seed: u64) -> (RunHeader, Vec<DataMessage>) {
    run_messages_with(shape, seed, |_| {})
}

fn run_messages_with(
    shape: &Shape,
    seed: u64,
    edit: impl FnOnce(&mut RunHeader),
) -> (RunHeader, Vec<DataMessage>) {
    let mut header = RunHeader {
        run_name: "synthetic".into(),
        model: "fput-beta".into(),
        n: shape.dim / 2,
        dim: shape.dim,
        k: shape.k,
        sets: shape.sets,
        h: 0.01,
        schemes: vec![Scheme {
            index: 0,
            name: "mpm".into(),
            method: "mpm".into(),
            d0: 1e-8,
            tau: 0.01,
            tau_steps: 1,
            orthonormalize: "rescale".into(),
        }],
        ..Default::default()
    };
    edit(&mut header);
    let mut noise = Noise::new(seed);
    let mut messages = Vec::new();
    let mut frame = 0;
    for step in 0..shape.samples {
        let t = step as f64 * 0.01;
        let state = (0..shape.dim).map(|_| noise.next_f64(1.0)).collect();
        messages.push(DataMessage::Reference(ReferenceState {
            frame,
            seq: step,
            step,
            t,
            energy: 1.0 + noise.next_f64(1e-12),
            state,
            mean_divergence: 0.0,
            divergence_sum: 0.0,
        }));
        frame += 1;
        for set in 0..shape.sets {
            let separations = (0..shape.k * shape.dim)
                .map(|_| noise.next_f64(1e-8))
                .collect();
            let stretch = (0..shape.k).map(|_| 1.0 + noise.next_f64(1e-3)).collect();
            messages.push(DataMessage::Separations(SeparationSet {
                frame,
                seq: step,
                step,
                t,
                scheme: 0,
                set,
                k: shape.k,
                dim: shape.dim,
                separations,
                stretch,
                earlier_stretch: Vec::new(),
            }));
            frame += 1;
        }
    }
    messages.push(DataMessage::End(EndOfRun {
        frame,
        status: end_of_run::Status::Completed as i32,
        samples: shape.samples,
        ..Default::default()
    }));
    (header, messages)
}

/// A small recording of about 15 chunks (dim 4, k = 2, three sets, 60 samples, chunks of
/// 2 KiB), for the damage tests.
pub fn small_run(compression: Compression) -> Vec<u8> {
    let shape = Shape {
        dim: 4,
        k: 2,
        sets: 3,
        samples: 60,
    };
    let options = FileOptions {
        compression,
        chunk_size: 2048,
    };
    write_run(Cursor::new(Vec::new()), &shape, &options, 7)
        .expect("writing to memory")
        .into_inner()
}

/// A map recording (`chaoscope map`'s layout) of `points` points, a chunk closed after every
/// `per_chunk`; its bytes, header and points.
pub fn small_map(
    points: u64,
    per_chunk: u64,
    compression: Compression,
) -> (Vec<u8>, MapHeader, Vec<MapPoint>) {
    let header = MapHeader {
        config_toml: "[map]".into(),
        grid_points: points,
        shard_count: 1,
        indicator: "gali".into(),
        ..Default::default()
    };
    let options = FileOptions {
        compression,
        chunk_size: 1 << 20,
    };
    let mut file = MapFile::create(Cursor::new(Vec::new()), &header, &options).expect("map");
    let points: Vec<MapPoint> = (0..points)
        .map(|index| MapPoint {
            index,
            value: (index as f64).sqrt(),
            ..Default::default()
        })
        .collect();
    for p in &points {
        file.write_point(p).expect("writing to memory");
        if (p.index + 1) % per_chunk == 0 {
            file.close_chunk().expect("writing to memory");
        }
    }
    let bytes = file.finish().expect("writing to memory").into_inner();
    (bytes, header, points)
}

/// Start (opcode byte) of every chunk record, as [`record_offsets`].
pub fn chunk_offsets(bytes: &[u8]) -> Vec<usize> {
    record_offsets(bytes)
        .into_iter()
        .filter(|&at| bytes[at] == mcap::records::op::CHUNK)
        .collect()
}

/// A message as a reader sees it: topic, sequence, log and publish time, payload.
pub type Message = (String, u32, u64, u64, Vec<u8>);

/// The messages of a valid file as the mcap crate reads them.
pub fn mcap_messages(bytes: &[u8]) -> Vec<Message> {
    mcap::MessageStream::new(bytes)
        .expect("an MCAP file")
        .map(|m| {
            let m = m.expect("a valid message");
            let data = m.data.into_owned();
            (
                m.channel.topic.clone(),
                m.sequence,
                m.log_time,
                m.publish_time,
                data,
            )
        })
        .collect()
}

/// A damaged copy of a file, and what was done to it (for assertion messages).
pub struct Damaged {
    pub what: String,
    pub bytes: Vec<u8>,
}

/// Opcode and length prefix of every record.
const PREFIX: usize = 1 + 8;

/// Start (opcode byte) of every top-level record after the magic, following the length fields,
/// up to the first record that runs past the end.
pub fn record_offsets(bytes: &[u8]) -> Vec<usize> {
    records_from(bytes, mcap::MAGIC.len())
}

/// Start of every record from `at` on, as [`record_offsets`].
fn records_from(bytes: &[u8], mut at: usize) -> Vec<usize> {
    let mut offsets = Vec::new();
    while let Some(prefix) = bytes.get(at..at + PREFIX) {
        let len = u64::from_le_bytes(prefix[1..].try_into().expect("8 bytes"));
        let Some(next) = usize::try_from(len)
            .ok()
            .and_then(|len| (at + PREFIX).checked_add(len))
            .filter(|&next| next <= bytes.len())
        else {
            break;
        };
        offsets.push(at);
        at = next;
    }
    offsets
}

/// The file cut at every byte of its first `dense` bytes, every `step`-th byte after, and two
/// bytes either side of every record boundary.
pub fn cuts(bytes: &[u8], dense: usize, step: usize) -> impl Iterator<Item = Damaged> + '_ {
    let len = bytes.len();
    let mut at: Vec<usize> = (0..dense.min(len))
        .chain((dense..len).step_by(step))
        .collect();
    for start in record_offsets(bytes) {
        at.extend(start.saturating_sub(2)..(start + 3).min(len));
    }
    at.sort_unstable();
    at.dedup();
    at.into_iter().map(move |cut| Damaged {
        what: format!("cut at byte {cut} of {len}"),
        bytes: bytes[..cut].to_vec(),
    })
}

/// `count` copies of the file with one random bit flipped each.
pub fn flips(bytes: &[u8], count: usize, seed: u64) -> impl Iterator<Item = Damaged> + '_ {
    let mut noise = Noise::new(seed);
    (0..count).map(move |_| {
        let at = (noise.next_u64() % bytes.len() as u64) as usize;
        let bit = noise.next_u64() % 8;
        let mut copy = bytes.to_vec();
        copy[at] ^= 1 << bit;
        Damaged {
            what: format!("bit {bit} of byte {at} flipped"),
            bytes: copy,
        }
    })
}

/// `count` streams of up to five random records after a valid magic: opcodes of every record
/// type (and a few unknown ones), short lengths, bodies sometimes shorter than their length.
pub fn random_records(count: usize, seed: u64) -> impl Iterator<Item = Damaged> {
    let mut noise = Noise::new(seed);
    (0..count).map(move |case| {
        let mut bytes = mcap::MAGIC.to_vec();
        for _ in 0..(noise.next_u64() % 6) {
            let opcode = (noise.next_u64() % 18) as u8;
            let len = noise.next_u64() % 80;
            bytes.push(opcode);
            bytes.extend_from_slice(&len.to_le_bytes());
            let body = len + noise.next_u64() % 3; // sometimes short of its length
            bytes.extend(noise.bytes(body as usize));
        }
        Damaged {
            what: format!("random records, case {case}"),
            bytes,
        }
    })
}

/// An attachment record too short for its own fields: log and create time, empty name and
/// media type, data length; no data and no CRC (mcap 0.26's `parse_record` panics on it).
pub fn short_attachment() -> Vec<u8> {
    let body = [0u8; 8 + 8 + 4 + 4 + 8];
    let mut record = vec![mcap::records::op::ATTACHMENT];
    record.extend_from_slice(&(body.len() as u64).to_le_bytes());
    record.extend_from_slice(&body);
    record
}

/// Huge values put in length fields: of each of the first top-level records, of the first
/// chunk's header (uncompressed and compressed size, length of the compression name) and, if
/// that chunk is uncompressed, of each record inside it.
pub fn huge_lengths(bytes: &[u8]) -> impl Iterator<Item = Damaged> + '_ {
    const HUGE: [u64; 5] = [u64::MAX, 1 << 63, 1 << 40, 1 << 32, (1 << 31) + 7];
    let mut fields: Vec<(String, usize, usize)> = Vec::new(); // what, offset, width
    let offsets = record_offsets(bytes);
    for &start in offsets.iter().take(12) {
        fields.push((
            format!("length of the record at byte {start}"),
            start + 1,
            8,
        ));
    }
    if let Some(&chunk) = chunk_offsets(bytes).first() {
        // Start and end time, uncompressed size and CRC, compression (length-prefixed),
        // compressed size, records.
        let body = chunk + PREFIX;
        let name_at = body + 8 + 8 + 8 + 4;
        let name_len = u32::from_le_bytes(bytes[name_at..name_at + 4].try_into().unwrap());
        let size_at = name_at + 4 + name_len as usize;
        fields.push(("uncompressed size of the first chunk".into(), body + 16, 8));
        fields.push(("length of the first chunk's compression".into(), name_at, 4));
        fields.push(("compressed size of the first chunk".into(), size_at, 8));
        if name_len == 0 {
            let records = size_at + 8;
            let size = u64::from_le_bytes(bytes[size_at..records].try_into().unwrap()) as usize;
            for at in records_from(&bytes[..(records + size).min(bytes.len())], records) {
                fields.push((
                    format!("length of the chunk record at byte {at}"),
                    at + 1,
                    8,
                ));
            }
        }
    }
    fields.into_iter().flat_map(move |(what, at, width)| {
        HUGE.iter().map(move |&value| {
            let mut copy = bytes.to_vec();
            copy[at..at + width].copy_from_slice(&value.to_le_bytes()[..width]);
            Damaged {
                what: format!("{what} set to {value:#x}"),
                bytes: copy,
            }
        })
    })
}

/// The file cut at record boundaries and in the middle of records, followed by 64 KiB of zeros,
/// and with its tail zeroed in place (a preallocated file whose writer died).
pub fn zero_tails(bytes: &[u8]) -> impl Iterator<Item = Damaged> + '_ {
    let offsets = record_offsets(bytes);
    let mut at: Vec<usize> = offsets.iter().step_by(3).copied().collect();
    at.extend(offsets.windows(2).step_by(4).map(|w| (w[0] + w[1]) / 2));
    at.into_iter().flat_map(move |cut| {
        let mut appended = bytes[..cut].to_vec();
        appended.resize(cut + (64 << 10), 0);
        let mut zeroed = bytes.to_vec();
        zeroed[cut..].fill(0);
        [
            Damaged {
                what: format!("cut at byte {cut}, 64 KiB of zeros after"),
                bytes: appended,
            },
            Damaged {
                what: format!("zeroed from byte {cut} on"),
                bytes: zeroed,
            },
        ]
    })
}

/// Every kind of damage above, of `bytes` (a valid file of a few dozen chunks): cuts, 300
/// seeded single bit flips, random record streams, a short attachment (alone, and after the
/// first chunk), huge length fields, zero-filled tails.
pub fn hostile(bytes: &[u8], seed: u64) -> impl Iterator<Item = Damaged> + '_ {
    // The record after the first chunk.
    let first_chunk_end = chunk_offsets(bytes).first().map_or(bytes.len(), |&chunk| {
        record_offsets(bytes)
            .into_iter()
            .find(|&at| at > chunk)
            .unwrap_or(bytes.len())
    });
    let attachments = [
        (mcap::MAGIC.len(), "a short attachment after the magic"),
        (first_chunk_end, "a short attachment after the first chunk"),
    ]
    .map(|(at, what)| {
        let mut copy = bytes[..at].to_vec();
        copy.extend(short_attachment());
        copy.extend_from_slice(&bytes[at..]);
        Damaged {
            what: what.into(),
            bytes: copy,
        }
    });
    cuts(bytes, 300, 37)
        .chain(flips(bytes, 300, seed))
        .chain(random_records(300, seed))
        .chain(attachments)
        .chain(huge_lengths(bytes))
        .chain(zero_tails(bytes))
}
