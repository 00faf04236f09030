//! On a valid file the damage-tolerant reader reads exactly what the mcap crate reads: the
//! same messages, in the same order, bit for bit (so analyses through it are unchanged).

use chaoscope_recorder::file::Compression;
use chaoscope_recorder::scan::{Messages, Scanner};
use chaoscope_recorder::testing::{self, Message};

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
