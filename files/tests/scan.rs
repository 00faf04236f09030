//! On a valid file the damage-tolerant reader reads exactly what the mcap crate reads: the
//! same messages, in the same order, bit for bit (so analyses through it are unchanged).

use chaoscope_files::file::Compression;
use chaoscope_files::scan::{Messages, Scanner};
use chaoscope_files::testing::{self, Message};

fn by_scan(bytes: &[u8]) -> Vec<Message> {
    let scanner = Scanner::open(bytes, Some(bytes.len() as u64))
        .unwrap()
        .unwrap();
    let mut messages = Messages::new(scanner);
    let mut out = Vec::new();
    while let Some(m) = messages.next_message().unwrap() {
        let h = m.header;
        out.push((
            m.topic.to_string(),
            h.sequence,
            h.log_time,
            h.publish_time,
            m.data,
        ));
    }
    assert_eq!(messages.scan().stopped_at, None);
    out
}

#[test]
fn valid_files_are_read_exactly_as_the_mcap_crate_reads_them() {
    for compression in [Compression::Zstd, Compression::Lz4, Compression::None] {
        let run = testing::small_run(compression);
        let (map, _, _) = testing::small_map(30, 4, compression);
        for bytes in [run, map] {
            let expected = testing::mcap_messages(&bytes);
            assert!(expected.len() > 30);
            assert_eq!(by_scan(&bytes), expected, "{compression:?}");
        }
    }
}

/// Where and why a scan of `bytes` stopped.
fn stopped_at(bytes: &[u8]) -> String {
    let mut scanner = Scanner::open(bytes, Some(bytes.len() as u64))
        .unwrap()
        .unwrap();
    while scanner.next().unwrap().is_some() {}
    scanner.scan().stopped_at.clone().expect("damage")
}

#[test]
fn a_length_past_the_end_or_past_any_bound_is_named_as_such() {
    let bytes = testing::small_run(Compression::Zstd);
    let first = testing::chunk_offsets(&bytes)[0];
    // Cut 11 bytes into the first chunk's body, a record of about 2 kB.
    let cut = stopped_at(&bytes[..first + 20]);
    assert!(
        cut.contains(&format!("at byte {first}: a record of ")),
        "{cut}"
    );
    assert!(cut.contains("but the file ends 11 bytes on"), "{cut}");
    let mut huge = bytes.clone();
    huge[first + 1..first + 9].copy_from_slice(&(1u64 << 40).to_le_bytes());
    let huge = stopped_at(&huge);
    assert!(
        huge.contains("a record of 1099511627776 bytes, longer than any"),
        "{huge}"
    );
}

/// `body` as a record with `opcode`.
fn record(opcode: u8, body: &[u8]) -> Vec<u8> {
    let mut bytes = vec![opcode];
    bytes.extend((body.len() as u64).to_le_bytes());
    bytes.extend(body);
    bytes
}

/// An uncompressed chunk record of `records`, without CRC.
fn chunk(records: &[u8]) -> Vec<u8> {
    let mut body = [0u64, 0, records.len() as u64]
        .map(u64::to_le_bytes)
        .concat();
    body.extend([0; 4 + 4]); // CRC, compression
    body.extend((records.len() as u64).to_le_bytes());
    body.extend(records);
    record(mcap::records::op::CHUNK, &body)
}

#[test]
fn empty_and_tiny_chunks_are_valid() {
    use chaoscope_files::scan::Entry;
    use mcap::records::{Record, op};
    // A schema of id 1, empty name, encoding and data.
    let schema = record(op::SCHEMA, &[1, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0]);
    let mut bytes = mcap::MAGIC.to_vec();
    bytes.extend(record(op::HEADER, &[0; 8]));
    bytes.extend(chunk(&[]));
    bytes.extend(chunk(&schema));
    bytes.extend(record(op::DATA_END, &[0; 4]));
    let mut scanner = Scanner::open(&bytes[..], Some(bytes.len() as u64))
        .unwrap()
        .unwrap();
    let mut chunks = Vec::new();
    while let Some(entry) = scanner.next().unwrap() {
        if let Entry::Chunk(records) = entry {
            chunks.push(records);
        }
    }
    assert_eq!(scanner.scan().stopped_at, None);
    assert_eq!(chunks.len(), 2);
    assert!(chunks[0].is_empty());
    assert!(matches!(&chunks[1][..], [Record::Schema { header, .. }] if header.id == 1));
}

#[test]
fn a_file_without_a_header_is_damage() {
    let bytes = testing::small_run(Compression::Zstd);
    let first = testing::record_offsets(&bytes)[1];
    let mut headless = bytes[..8].to_vec();
    headless.extend(&bytes[first..]);
    let stopped = stopped_at(&headless);
    assert!(
        stopped.contains("at byte 8: the file does not start with a header record"),
        "{stopped}"
    );
}
