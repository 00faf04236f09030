//! Streaming, damage-tolerant reading of MCAP files: the one way chaoscope reads an MCAP file
//! (`recover`, map files, `analyze` and `replay`), because every input file is hostile.
//!
//! The records are read in file order through the mcap crate's sans-io reader, fed from any
//! [`Read`] (a `BufReader<File>`), so memory is bounded by the largest record (about one chunk
//! in a valid file), not by the file. Each chunk is decompressed and checked whole (the CRC
//! compared, where the writer put one, then every record parsed) before any of its records is
//! handed out, so a damaged chunk is dropped whole rather than half read. Reading stops at the
//! first damaged record and says where and why. No input makes it panic, and no length field
//! makes it buffer more than [`MAX_RECORD_LEN`] bytes (nor more than the file's length): record
//! lengths are bounded by the reader, and every string, array and map length is checked against
//! its record before the record is parsed.
//!
//! Damage is also what would otherwise lose data silently: a first record other than the header,
//! a record of a type chaoscope files never hold, or in the wrong section, a channel or message
//! index record longer than its fields (a chunk whose opcode was hit reads as one of these), a
//! chunk record longer than its data, and a summary that disagrees with the data (a chunk not
//! read where the chunk index says, other message or chunk counts than the statistics).
//!
//! [`Scanner`] hands out records and whole chunks; [`Messages`] on top of it hands out messages
//! with their topics.

use std::collections::HashMap;
use std::fmt::Display;
use std::fs::File;
use std::io::{self, BufReader, Read};
use std::path::{Path, PathBuf};
use std::sync::Arc;

use mcap::McapError;
use mcap::records::{MessageHeader, Record, op};
use mcap::sans_io::{LinearReadEvent, LinearReader, LinearReaderOptions};

/// How many times its compressed size a compressed chunk may decompress to: above zstd's
/// bound (an RLE block of 128 KiB takes 4 bytes) and lz4's (about 255).
const MAX_RATIO: u64 = 1 << 15;

/// The longest record accepted. Chunks are about the writer's chunk size (4 MiB by default);
/// a longer length field is taken as damage, so a corrupted length cannot exhaust memory.
pub const MAX_RECORD_LEN: usize = 1 << 30;

/// At most this many bytes are handed to the reader per read request.
const READ_STEP: usize = 1 << 20;

/// Opcode and length prefix of every record.
const PREFIX_LEN: u64 = 1 + 8;

/// How far a scan got.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Scan {
    /// Records read whole (a chunk counts as one).
    pub records: u64,
    /// Chunks among them.
    pub chunks: u64,
    /// Bytes they and the magic take at the start of the file.
    pub bytes: u64,
    /// Where and why reading stopped; `None` if the file was read to its end (its footer, or
    /// the end of the input after the data end record).
    pub stopped_at: Option<String>,
    /// Reading stopped because the input ends before or inside a record: what a writer that
    /// was killed leaves, as opposed to bytes that do not decode. A damaged length that points
    /// past the end reads the same, so this alone proves no kill: a caller weighs the file's
    /// length too.
    pub cut: bool,
}

/// What [`Scanner::next`] hands out.
#[derive(Debug)]
pub enum Entry {
    /// A record outside chunks.
    Record(Record<'static>),
    /// The records of a chunk, checked whole, in order.
    Chunk(Vec<Record<'static>>),
}

/// A file that cannot be read at all (as opposed to damage, which [`Scan::stopped_at`] reports).
#[derive(Debug, thiserror::Error)]
pub enum FileError {
    #[error("{path}: {source}")]
    Io { path: PathBuf, source: io::Error },
    #[error("{path} is not an MCAP file (no MCAP magic at the start)")]
    NotMcap { path: PathBuf },
}

impl FileError {
    /// `source`, a failure to read the file at `path`.
    pub fn io(path: &Path, source: io::Error) -> Self {
        Self::Io {
            path: path.into(),
            source,
        }
    }
}

/// Why reading stopped at a record.
#[derive(Debug, thiserror::Error)]
enum Damage {
    #[error(transparent)]
    Mcap(#[from] McapError),
    #[error("invalid opcode 0x00 (zero-filled or overwritten bytes)")]
    ZeroOpcode,
    #[error("{0} record shorter than its own fields")]
    Short(&'static str),
    #[error("the file does not start with a header record")]
    NoHeader,
    #[error("unknown record type 0x{0:02x} (chaoscope files hold none)")]
    UnknownOpcode(u8),
    #[error("a {record} record cannot be in the {section} section")]
    Misplaced {
        record: &'static str,
        section: &'static str,
    },
    #[error("a {0} record longer than its fields")]
    Overlong(&'static str),
    #[error(
        "a message record outside the chunks, after a chunk (chaoscope writes every message into \
         a chunk: a damaged opcode, such as a message index's 0x07 read as 0x05)"
    )]
    MessageAfterChunks,
    #[error("chunk record {0} bytes longer than its data")]
    ChunkPadding(usize),
    #[error("the summary does not match the data: {0}")]
    Summary(String),
    #[error(
        "a record of {len} bytes, but the file ends {left} bytes on (cut short, or a damaged \
         length)"
    )]
    PastEnd { len: u64, left: u64 },
    #[error("a record of {0} bytes, longer than any chaoscope writes (a damaged length)")]
    TooLong(u64),
}

/// The reader's failure to produce a record: the source failed, or the bytes are damaged.
enum Failure {
    Io(io::Error),
    Damage(Damage),
}

/// What the records read so far say the rest of the file may hold.
#[derive(Default)]
struct Layout {
    /// Past the data end record: in the summary section.
    summary: bool,
    /// Start and length of every chunk record read.
    chunks: Vec<(u64, u64)>,
    /// Chunk index records read.
    indexed: usize,
    /// Message records read (in and outside chunks).
    messages: u64,
}

impl Layout {
    /// Checks and parses the record with `opcode` and `body` at byte `at`.
    fn entry(&mut self, at: u64, opcode: u8, body: &[u8]) -> Result<Entry, Damage> {
        self.check_place(at, opcode)?;
        if opcode == op::CHUNK {
            let records = check_chunk(body)?;
            self.messages += records
                .iter()
                .filter(|r| matches!(r, Record::Message { .. }))
                .count() as u64;
            self.chunks.push((at, PREFIX_LEN + body.len() as u64));
            return Ok(Entry::Chunk(records));
        }
        let record = parse(opcode, body)?.into_owned();
        match &record {
            // What a chunk whose opcode was hit can parse as (its times read as lengths).
            Record::MessageIndex(index) if body.len() != 2 + 4 + 16 * index.records.len() => {
                return Err(Damage::Overlong("message index"));
            }
            Record::Channel(c) if body.len() != channel_len(c) => {
                return Err(Damage::Overlong("channel"));
            }
            // A message index whose opcode lost one bit parses as a well-formed message of a
            // real channel (its channel id, then its times and offsets as sequence, times and
            // data): copied, it would add a message the file never had.
            Record::Message { .. } if !self.chunks.is_empty() => {
                return Err(Damage::MessageAfterChunks);
            }
            Record::Message { .. } => self.messages += 1,
            Record::DataEnd(_) => self.summary = true,
            Record::ChunkIndex(index) => {
                let read = self.chunks.get(self.indexed).copied();
                let indexed = (index.chunk_start_offset, index.chunk_length);
                if read != Some(indexed) {
                    return Err(Damage::Summary(format!(
                        "chunk index {} has the chunk at byte {} ({} bytes), but {}",
                        self.indexed,
                        indexed.0,
                        indexed.1,
                        match read {
                            Some((start, len)) =>
                                format!("it was read at byte {start} ({len} bytes)"),
                            None => format!("only {} chunks were read", self.chunks.len()),
                        }
                    )));
                }
                self.indexed += 1;
            }
            Record::Statistics(s) => {
                let counted = (s.message_count, u64::from(s.chunk_count));
                let read = (self.messages, self.chunks.len() as u64);
                if counted != read {
                    return Err(Damage::Summary(format!(
                        "the statistics count {} messages in {} chunks, {} messages in {} chunks \
                         were read",
                        counted.0, counted.1, read.0, read.1
                    )));
                }
            }
            Record::Footer(_) if self.indexed > 0 && self.indexed != self.chunks.len() => {
                return Err(Damage::Summary(format!(
                    "{} chunks are indexed, {} were read",
                    self.indexed,
                    self.chunks.len()
                )));
            }
            _ => {}
        }
        Ok(Entry::Record(record))
    }

    /// Whether a record with `opcode` may stand at byte `at`, in the current section.
    fn check_place(&self, at: u64, opcode: u8) -> Result<(), Damage> {
        let (record, data, summary) = match opcode {
            0 => return Err(Damage::ZeroOpcode),
            _ if at == mcap::MAGIC.len() as u64 && opcode != op::HEADER => {
                return Err(Damage::NoHeader);
            }
            op::HEADER => ("header", at == mcap::MAGIC.len() as u64, false),
            op::SCHEMA => ("schema", true, true),
            op::CHANNEL => ("channel", true, true),
            op::MESSAGE => ("message", true, false),
            op::CHUNK => ("chunk", true, false),
            op::MESSAGE_INDEX => ("message index", true, false),
            op::ATTACHMENT => ("attachment", true, false),
            op::METADATA => ("metadata", true, false),
            op::DATA_END => ("data end", true, false),
            op::CHUNK_INDEX => ("chunk index", false, true),
            op::ATTACHMENT_INDEX => ("attachment index", false, true),
            op::METADATA_INDEX => ("metadata index", false, true),
            op::STATISTICS => ("statistics", false, true),
            op::SUMMARY_OFFSET => ("summary offset", false, true),
            op::FOOTER => ("footer", false, true),
            opcode => return Err(Damage::UnknownOpcode(opcode)),
        };
        match (self.summary, data, summary) {
            (false, true, _) | (true, _, true) => Ok(()),
            (false, false, _) if opcode == op::HEADER => Err(Damage::Misplaced {
                record,
                section: "data (after its first record)",
            }),
            (false, ..) => Err(Damage::Misplaced {
                record,
                section: "data",
            }),
            (true, ..) => Err(Damage::Misplaced {
                record,
                section: "summary",
            }),
        }
    }
}

/// An MCAP file being read, positioned after its magic.
pub struct Scanner<R> {
    source: R,
    /// Length of the file, if known.
    len: Option<u64>,
    reader: LinearReader,
    layout: Layout,
    scan: Scan,
    /// Length of the entry handed out last and whether it is a chunk, counted into `scan` when
    /// the next one is asked for.
    pending: Option<(u64, bool)>,
    /// The end of the file was reached, or reading failed.
    done: bool,
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
            len,
            reader,
            layout: Layout::default(),
            scan: Scan {
                records: 0,
                chunks: 0,
                bytes: mcap::MAGIC.len() as u64,
                stopped_at: None,
                cut: false,
            },
            pending: None,
            done: false,
        }))
    }

    /// The next record outside chunks, or the next chunk's records; `None` at the end of the
    /// file or at the first damaged record ([`Scanner::scan`] says which). Only a failure of the
    /// source itself is an error.
    #[allow(clippy::should_implement_trait)] // fallible, so not an Iterator
    pub fn next(&mut self) -> io::Result<Option<Entry>> {
        if let Some((len, chunk)) = self.pending.take() {
            self.scan.records += 1;
            self.scan.chunks += u64::from(chunk);
            self.scan.bytes += len;
        }
        if self.done {
            return Ok(None);
        }
        let (layout, at) = (&mut self.layout, self.scan.bytes);
        let step = next_record(&mut self.reader, &mut self.source, |opcode, body| {
            let entry = layout.entry(at, opcode, body);
            (PREFIX_LEN + body.len() as u64, entry)
        });
        match step {
            Ok(Some((len, Ok(entry)))) => {
                self.pending = Some((len, matches!(entry, Entry::Chunk(_))));
                Ok(Some(entry))
            }
            Ok(Some((_, Err(damage)))) => {
                self.stop(damage);
                Ok(None)
            }
            // The reader refused a record's length: past the end of the file, or past any
            // bound; its own words would only say "exceeds limit".
            Err(Failure::Damage(Damage::Mcap(McapError::RecordTooLarge { len, .. }))) => {
                let body_at = at + PREFIX_LEN;
                let damage = match self.len {
                    Some(file) if len <= MAX_RECORD_LEN as u64 && body_at <= file => {
                        self.scan.cut = true;
                        Damage::PastEnd {
                            len,
                            left: file - body_at,
                        }
                    }
                    _ => Damage::TooLong(len),
                };
                self.stop(damage);
                Ok(None)
            }
            Err(Failure::Damage(damage)) => {
                self.scan.cut = matches!(damage, Damage::Mcap(McapError::UnexpectedEof));
                self.stop(damage);
                Ok(None)
            }
            Err(Failure::Io(e)) => {
                self.done = true;
                Err(e)
            }
            Ok(None) if self.layout.summary => {
                self.done = true;
                Ok(None)
            }
            Ok(None) => {
                self.scan.cut = true;
                self.stop(
                    "the file ends here, before its data end record (its writer did not finish \
                     it)",
                );
                Ok(None)
            }
        }
    }

    /// Stops reading at the entry handed out last (or, at the start, at the next record): the
    /// caller found it unusable for the reason `why`, which [`Scan::stopped_at`] reports with
    /// its place.
    pub fn stop(&mut self, why: impl Display) {
        self.pending = None;
        self.done = true;
        self.scan.stopped_at = Some(format!(
            "record {} at byte {}: {why}",
            self.scan.records, self.scan.bytes
        ));
    }

    /// How far reading got: complete once [`Scanner::next`] has returned `None`.
    pub fn scan(&self) -> &Scan {
        &self.scan
    }
}

impl Scanner<BufReader<File>> {
    /// Opens the regular file at `path` for scanning, buffered, no record longer than the
    /// file; a FIFO, device or socket is refused without waiting on it
    /// ([`chaoscope_os::open_regular`]). Also returns the opened file's metadata.
    pub fn open_file(path: &Path) -> Result<(Self, std::fs::Metadata), FileError> {
        let file = chaoscope_os::open_regular(path).map_err(|e| FileError::io(path, e))?;
        let meta = file.metadata().map_err(|e| FileError::io(path, e))?;
        let len = Some(meta.len());
        let scanner = Self::open(BufReader::with_capacity(1 << 20, file), len)
            .map_err(|e| FileError::io(path, e))?
            .ok_or_else(|| FileError::NotMcap { path: path.into() })?;
        Ok((scanner, meta))
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

/// Decompresses and parses every record of a chunk (its record body) and checks its CRC.
fn check_chunk(body: &[u8]) -> Result<Vec<Record<'static>>, Damage> {
    let (header, data) = match parse(op::CHUNK, body)? {
        Record::Chunk { header, data } => (header, data),
        // parse_record makes a chunk of every chunk record.
        _ => return Err(McapError::UnexpectedEoc.into()),
    };
    // The chunk alone, as a record stream, read by a reader of its own (a sans-io reader enters
    // chunks only from a record stream). Fields before the data: start and end time,
    // uncompressed size and CRC, compression (length-prefixed), compressed size.
    let chunk_len = 8 + 8 + 8 + 4 + 4 + header.compression.len() + 8 + data.len();
    let chunk = body.get(..chunk_len).ok_or(McapError::BadChunkLength {
        header: chunk_len as u64,
        available: body.len() as u64,
    })?;
    // Writers put nothing after the data; bytes there are a damaged length that swallowed
    // what follows.
    if body.len() > chunk_len {
        return Err(Damage::ChunkPadding(body.len() - chunk_len));
    }
    let mut prefix = [op::CHUNK; PREFIX_LEN as usize];
    prefix[1..].copy_from_slice(&(chunk_len as u64).to_le_bytes());
    let mut source = prefix.as_slice().chain(chunk);
    // The limit bounds the chunk record itself (it passes through the reader), its
    // decompressed data and each record in it. A compressed chunk decompresses to at most
    // MAX_RATIO times its compressed size, so a damaged uncompressed size beyond that is refused
    // before anything is decompressed.
    let uncompressed = if header.compression.is_empty() {
        header.uncompressed_size
    } else {
        header
            .uncompressed_size
            .min(header.compressed_size.saturating_mul(MAX_RATIO))
    };
    let limit = usize::try_from(uncompressed.max(PREFIX_LEN + chunk_len as u64))
        .unwrap_or(usize::MAX)
        .min(MAX_RECORD_LEN);
    // The CRC (where the writer put one: non-zero) is checked over the whole decompressed data
    // before any record in it is parsed.
    let mut reader = LinearReader::new_with_options(
        LinearReaderOptions::default()
            .with_skip_start_magic(true)
            .with_skip_end_magic(true)
            .with_prevalidate_chunk_crcs(true)
            .with_record_length_limit(limit),
    );
    let mut records = Vec::new();
    loop {
        let step = next_record(&mut reader, &mut source, |opcode, body| {
            parse(opcode, body).map(Record::into_owned)
        });
        match step {
            Ok(Some(Ok(record))) => records.push(record),
            Ok(Some(Err(damage))) | Err(Failure::Damage(damage)) => return Err(damage),
            Err(Failure::Io(e)) => return Err(McapError::Io(e).into()),
            Ok(None) => return Ok(records),
        }
    }
}

/// The length of a channel record's body: id, schema id, topic and message encoding
/// (length-prefixed), metadata (byte length, then length-prefixed keys and values).
fn channel_len(c: &mcap::records::Channel) -> usize {
    let metadata: usize = c
        .metadata
        .iter()
        .map(|(k, v)| 4 + k.len() + 4 + v.len())
        .sum();
    2 + 2 + 4 + c.topic.len() + 4 + c.message_encoding.len() + 4 + metadata
}

/// `mcap::parse_record`, refusing what it would mishandle: opcode 0 (never valid; what zeroed
/// bytes read as) and records whose length-prefixed fields run past their end (mcap 0.26 reserves
/// memory for a string's whole length before reading it, up to 4 GiB for a damaged length, and
/// slices attachments by their own lengths and panics).
fn parse(opcode: u8, body: &[u8]) -> Result<Record<'_>, Damage> {
    if opcode == 0 {
        return Err(Damage::ZeroOpcode);
    }
    let (record, fields) = fields(opcode);
    if !fields_fit(fields, body) {
        return Err(Damage::Short(record));
    }
    Ok(mcap::parse_record(opcode, body)?)
}

/// A field of a record body, as the MCAP spec lays it out.
#[derive(Clone, Copy)]
enum Field {
    /// This many bytes.
    Fixed(usize),
    /// A u32 length, then that many bytes: a string or byte array.
    Bytes,
    /// A u32 byte length, then that many bytes of fixed-width entries: an array or integer map.
    Array,
    /// A u32 byte length, then pairs of strings within it: a string map.
    StringMap,
}

/// The name of the record with `opcode` and its fields up to its last length-prefixed one (or,
/// for an attachment, up to its CRC, which mcap slices from the end); the fixed fields after
/// them are left to `parse_record`, which reads them without allocating.
fn fields(opcode: u8) -> (&'static str, &'static [Field]) {
    use Field::*;
    match opcode {
        op::HEADER => ("header", &[Bytes, Bytes]),
        // id; name, encoding, data
        op::SCHEMA => ("schema", &[Fixed(2), Bytes, Bytes, Bytes]),
        // id, schema id; topic, message encoding, metadata
        op::CHANNEL => ("channel", &[Fixed(4), Bytes, Bytes, StringMap]),
        // start and end time, uncompressed size and CRC; compression
        op::CHUNK => ("chunk", &[Fixed(28), Bytes]),
        // channel id; records
        op::MESSAGE_INDEX => ("message index", &[Fixed(2), Array]),
        // start and end time, chunk start and length; message index offsets, message index
        // length, compression
        op::CHUNK_INDEX => ("chunk index", &[Fixed(32), Array, Fixed(8), Bytes]),
        // log and create time; name, media type, data length and CRC
        op::ATTACHMENT => ("attachment", &[Fixed(16), Bytes, Bytes, Fixed(8 + 4)]),
        // offset, length, log and create time, data size; name, media type
        op::ATTACHMENT_INDEX => ("attachment index", &[Fixed(40), Bytes, Bytes]),
        // message count, schema count, channel, attachment, metadata and chunk counts, start and
        // end time; channel message counts
        op::STATISTICS => ("statistics", &[Fixed(8 + 2 + 4 * 4 + 8 + 8), Array]),
        // name, metadata
        op::METADATA => ("metadata", &[Bytes, StringMap]),
        // offset, length; name
        op::METADATA_INDEX => ("metadata index", &[Fixed(16), Bytes]),
        // message, footer, summary offset, data end: fixed fields only; unknown: not parsed
        _ => ("", &[]),
    }
}

/// Whether `fields` fit in `body`: every length-prefixed field (and every string in a string
/// map) within it.
fn fields_fit(fields: &[Field], body: &[u8]) -> bool {
    // The end of the field of length prefix at `at` that must end by `end`.
    let prefixed = |at: usize, end: usize| -> Option<usize> {
        let bytes = body.get(at..at.checked_add(4)?)?;
        let to = (at + 4).checked_add(u32::from_le_bytes(bytes.try_into().ok()?) as usize)?;
        (to <= end).then_some(to)
    };
    let mut at = 0usize;
    for field in fields {
        let next = match *field {
            Field::Fixed(n) => at.checked_add(n).filter(|&to| to <= body.len()),
            Field::Bytes | Field::Array => prefixed(at, body.len()),
            Field::StringMap => prefixed(at, body.len()).filter(|&end| {
                let mut entry = at + 4;
                while entry < end {
                    match prefixed(entry, end).and_then(|value| prefixed(value, end)) {
                        Some(next) => entry = next,
                        None => return false,
                    }
                }
                true
            }),
        };
        match next {
            Some(next) => at = next,
            None => return false,
        }
    }
    true
}

/// A message as [`Messages`] reads it.
#[derive(Debug, Clone, PartialEq)]
pub struct Message {
    /// Its channel's topic.
    pub topic: Arc<str>,
    pub header: MessageHeader,
    pub data: Vec<u8>,
}

/// The messages of an MCAP file in file order, with their channels' topics, read by a
/// [`Scanner`]: each chunk checked whole before any of its messages is handed out, reading
/// stopped at the first damage. A message on a channel not defined before it, or a channel
/// redefined with another topic, is damage too.
pub struct Messages<R> {
    scanner: Scanner<R>,
    topics: HashMap<u16, Arc<str>>,
    /// The rest of the chunk being handed out.
    chunk: std::vec::IntoIter<Record<'static>>,
    /// Entries (records and chunks) read from the scanner.
    entries: u64,
    /// The names of the metadata records read so far, in order.
    metadata: Vec<String>,
}

impl<R: Read> Messages<R> {
    pub fn new(scanner: Scanner<R>) -> Self {
        Self {
            scanner,
            topics: HashMap::new(),
            chunk: Vec::new().into_iter(),
            entries: 0,
            metadata: Vec::new(),
        }
    }

    /// The names of the metadata records read so far. A writer puts its file's description
    /// there before any chunk, so it is read even where no chunk was whole.
    pub fn metadata_names(&self) -> &[String] {
        &self.metadata
    }

    /// Which entry of the file (record or chunk, counted from 1) the message handed out last
    /// came from: messages of one chunk share it.
    pub fn entry(&self) -> u64 {
        self.entries
    }

    /// The next message; `None` at the end of the file or at the first damage
    /// ([`Messages::scan`] says which). Only a failure of the source itself is an error.
    pub fn next_message(&mut self) -> io::Result<Option<Message>> {
        loop {
            let record = match self.chunk.next() {
                Some(record) => record,
                None => match self.scanner.next()?.inspect(|_| self.entries += 1) {
                    None => return Ok(None),
                    Some(Entry::Chunk(records)) => {
                        self.chunk = records.into_iter();
                        continue;
                    }
                    Some(Entry::Record(record)) => record,
                },
            };
            match record {
                Record::Channel(channel) => match self.topics.get(&channel.id) {
                    Some(topic) if **topic != *channel.topic => {
                        let why = format!(
                            "channel {} redefined from {topic} to {}",
                            channel.id, channel.topic
                        );
                        self.stop(why);
                        return Ok(None);
                    }
                    Some(_) => {}
                    None => {
                        self.topics.insert(channel.id, channel.topic.into());
                    }
                },
                Record::Message { header, data } => {
                    let Some(topic) = self.topics.get(&header.channel_id) else {
                        let why = format!("message on undefined channel {}", header.channel_id);
                        self.stop(why);
                        return Ok(None);
                    };
                    return Ok(Some(Message {
                        topic: topic.clone(),
                        header,
                        data: data.into_owned(),
                    }));
                }
                Record::Metadata(m) => self.metadata.push(m.name),
                _ => {}
            }
        }
    }

    /// Stops reading at the message handed out last (its record, or its chunk): the caller
    /// found it unusable for the reason `why` (e.g. not the protobuf message its topic carries).
    pub fn stop(&mut self, why: impl Display) {
        self.chunk = Vec::new().into_iter();
        self.scanner.stop(why);
    }

    /// How far reading got: complete once [`Messages::next_message`] has returned `None`.
    pub fn scan(&self) -> &Scan {
        self.scanner.scan()
    }
}
