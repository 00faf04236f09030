//! Streaming, damage-tolerant reading of an MCAP file's records, for salvaging files whose writer
//! died.
//!
//! The records are read in file order through the mcap crate's sans-io reader, fed from any
//! [`Read`] (a `BufReader<File>`), so memory is bounded by the largest record (about one chunk),
//! never by the file. Each chunk is decompressed and checked whole (every record parsed, the CRC
//! compared) before any of its records is handed out, so a damaged chunk is dropped whole rather
//! than half copied. Reading stops at the first damaged record and says where and why. No input
//! makes it panic, and no length field makes it buffer more than [`MAX_RECORD_LEN`] bytes.

use std::io::{self, Read};

use mcap::McapError;
use mcap::records::{Record, op};
use mcap::sans_io::{LinearReadEvent, LinearReader, LinearReaderOptions};

/// The longest record accepted. Chunks are about the writer's chunk size (4 MiB by default);
/// a longer length field is taken as damage, so a corrupted length cannot exhaust memory.
pub const MAX_RECORD_LEN: usize = 1 << 30;

/// At most this many bytes are handed to the reader per read request.
const READ_STEP: usize = 1 << 20;

/// Opcode and length prefix of every record.
const PREFIX_LEN: u64 = 1 + 8;

/// Receives the records that survive, in file order.
pub trait Visit {
    /// A record outside chunks, or one of a chunk's records once the whole chunk was checked.
    /// An error stops the scan there, and is reported as where and why it stopped.
    fn record(&mut self, record: Record<'_>) -> mcap::McapResult<()>;
    /// Called after the records of one chunk.
    fn chunk_done(&mut self) -> mcap::McapResult<()> {
        Ok(())
    }
}

/// How far a scan got.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Scan {
    /// Records read whole (a chunk counts as one).
    pub records: u64,
    /// Bytes they and the magic take at the start of the file.
    pub bytes: u64,
    /// Where and why reading stopped; `None` if the file was read to its end (its footer, or
    /// the end of the input after the data end record).
    pub stopped_at: Option<String>,
}

/// Why reading stopped at a record.
#[derive(Debug, thiserror::Error)]
enum Damage {
    #[error(transparent)]
    Mcap(#[from] McapError),
    #[error("invalid opcode 0x00 (zero-filled or overwritten bytes)")]
    ZeroOpcode,
    #[error("attachment record shorter than its own fields")]
    ShortAttachment,
}

/// The reader's failure to produce a record: the source failed, or the bytes are damaged.
enum Failure {
    Io(io::Error),
    Damage(Damage),
}

/// An MCAP file being read, positioned after its magic.
pub struct Scanner<R> {
    source: R,
    reader: LinearReader,
    /// Records of the chunk being checked, reused from chunk to chunk.
    chunk: Vec<Record<'static>>,
}

impl<R: Read> Scanner<R> {
    /// Checks the magic at the start of `source`; `Ok(None)` if it is not there (not MCAP).
    /// `len` is the length of the file, if known: no record is longer.
    pub fn open(mut source: R, len: Option<u64>) -> io::Result<Option<Self>> {
        let mut magic = [0u8; 8];
        let mut have = 0;
        while have < magic.len() {
            match source.read(&mut magic[have..]) {
                Ok(0) => return Ok(None),
                Ok(n) => have += n,
                Err(e) if e.kind() == io::ErrorKind::Interrupted => {}
                Err(e) => return Err(e),
            }
        }
        if magic[..] != mcap::MAGIC[..] {
            return Ok(None);
        }
        let limit = len
            .and_then(|len| usize::try_from(len).ok())
            .map_or(MAX_RECORD_LEN, |len| len.min(MAX_RECORD_LEN));
        let reader = LinearReader::new_with_options(
            LinearReaderOptions::default()
                .with_skip_start_magic(true)
                .with_skip_end_magic(true)
                .with_emit_chunks(true)
                .with_record_length_limit(limit),
        );
        Ok(Some(Self {
            source,
            reader,
            chunk: Vec::new(),
        }))
    }

    /// Reads records into `visit` to the end of the file (its footer) or up to the first damaged
    /// record. Only a failure of the source itself is an error.
    pub fn run(mut self, visit: &mut impl Visit) -> io::Result<Scan> {
        let mut scan = Scan {
            records: 0,
            bytes: mcap::MAGIC.len() as u64,
            stopped_at: None,
        };
        let mut data_end = false;
        let chunk = &mut self.chunk;
        let damage = loop {
            let step = next_record(&mut self.reader, &mut self.source, |opcode, body| {
                let result = if opcode == op::CHUNK {
                    check_chunk(body, chunk).and_then(|()| {
                        for record in chunk.drain(..) {
                            visit.record(record)?;
                        }
                        Ok(visit.chunk_done()?)
                    })
                } else {
                    parse(opcode, body).and_then(|r| Ok(visit.record(r)?))
                };
                (opcode, PREFIX_LEN + body.len() as u64, result)
            });
            match step {
                Ok(Some((opcode, len, Ok(())))) => {
                    scan.records += 1;
                    scan.bytes += len;
                    data_end |= opcode == op::DATA_END;
                }
                Ok(Some((_, _, Err(damage)))) | Err(Failure::Damage(damage)) => {
                    break damage.to_string();
                }
                Err(Failure::Io(e)) => return Err(e),
                Ok(None) if data_end => return Ok(scan),
                Ok(None) => {
                    break "the file ends here, before its data end record (its writer did not \
                           finish it)"
                        .to_string();
                }
            }
        };
        scan.stopped_at = Some(format!(
            "record {} at byte {}: {damage}",
            scan.records, scan.bytes
        ));
        Ok(scan)
    }
}

/// Feeds `reader` from `source` until it yields a record, and returns what `f` makes of it;
/// `Ok(None)` at a clean end.
fn next_record<T>(
    reader: &mut LinearReader,
    source: &mut impl Read,
    f: impl FnOnce(u8, &[u8]) -> T,
) -> Result<Option<T>, Failure> {
    loop {
        match reader.next_event() {
            None => return Ok(None),
            Some(Err(e)) => return Err(Failure::Damage(e.into())),
            Some(Ok(LinearReadEvent::Record { opcode, data })) => return Ok(Some(f(opcode, data))),
            Some(Ok(LinearReadEvent::ReadRequest(need))) => {
                // Never more than a step at once: the request may come from a damaged length.
                let buf = reader.insert(need.clamp(1, READ_STEP));
                let read = loop {
                    match source.read(buf) {
                        Ok(n) => break n,
                        Err(e) if e.kind() == io::ErrorKind::Interrupted => {}
                        Err(e) => return Err(Failure::Io(e)),
                    }
                };
                reader.notify_read(read); // 0 is the end of the input
            }
        }
    }
}

/// Decompresses and parses every record of a chunk (its record body) into `records` and checks
/// its CRC; on damage `records` is left empty.
fn check_chunk(body: &[u8], records: &mut Vec<Record<'static>>) -> Result<(), Damage> {
    records.clear();
    let (header, data) = match parse(op::CHUNK, body)? {
        Record::Chunk { header, data } => (header, data),
        // parse_record makes a chunk of every chunk record.
        _ => return Err(McapError::UnexpectedEoc.into()),
    };
    // The chunk alone, as a record stream without any padding after its data, read by a reader
    // of its own (a sans-io reader enters chunks only from a record stream). Fields before the
    // data: start and end time, uncompressed size and CRC, compression (length-prefixed),
    // compressed size.
    let chunk_len = 8 + 8 + 8 + 4 + 4 + header.compression.len() + 8 + data.len();
    let chunk = body.get(..chunk_len).ok_or(McapError::BadChunkLength {
        header: chunk_len as u64,
        available: body.len() as u64,
    })?;
    let mut prefix = [op::CHUNK; PREFIX_LEN as usize];
    prefix[1..].copy_from_slice(&(chunk_len as u64).to_le_bytes());
    let mut source = prefix.as_slice().chain(chunk);
    let limit = usize::try_from(header.uncompressed_size.max(header.compressed_size))
        .unwrap_or(usize::MAX)
        .min(MAX_RECORD_LEN);
    let mut reader = LinearReader::new_with_options(
        LinearReaderOptions::default()
            .with_skip_start_magic(true)
            .with_skip_end_magic(true)
            .with_validate_chunk_crcs(true)
            .with_record_length_limit(limit),
    );
    let result = loop {
        let step = next_record(&mut reader, &mut source, |opcode, body| {
            parse(opcode, body).map(Record::into_owned)
        });
        match step {
            Ok(Some(Ok(record))) => records.push(record),
            Ok(Some(Err(damage))) | Err(Failure::Damage(damage)) => break Err(damage),
            Err(Failure::Io(e)) => break Err(McapError::Io(e).into()),
            Ok(None) => break Ok(()),
        }
    };
    if result.is_err() {
        records.clear();
    }
    result
}

/// `mcap::parse_record`, refusing what it would mishandle: opcode 0 (never valid; what zeroed
/// bytes read as) and attachments too short for their fields (mcap 0.26 slices those by their own
/// lengths and panics).
fn parse(opcode: u8, body: &[u8]) -> Result<Record<'_>, Damage> {
    match opcode {
        0 => Err(Damage::ZeroOpcode),
        op::ATTACHMENT if !attachment_fits(body) => Err(Damage::ShortAttachment),
        _ => Ok(mcap::parse_record(opcode, body)?),
    }
}

/// Whether an attachment body holds its fixed fields and CRC: log and create time, name and
/// media type (length-prefixed), data length, ..., CRC.
fn attachment_fits(body: &[u8]) -> bool {
    let u32_at = |at: usize| -> Option<usize> {
        let bytes = body.get(at..at.checked_add(4)?)?;
        Some(u32::from_le_bytes(bytes.try_into().ok()?) as usize)
    };
    let name = 16;
    let fields_end = u32_at(name)
        .and_then(|n| (name + 4).checked_add(n))
        .and_then(|media| u32_at(media).and_then(|n| (media + 4).checked_add(n)))
        .and_then(|data_len| data_len.checked_add(8 + 4));
    fields_end.is_some_and(|end| end <= body.len())
}
