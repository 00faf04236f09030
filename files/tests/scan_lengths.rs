//! A damaged length prefix (a string, byte array or map length turned to 0xFFFFFFFF) in any
//! record, in or outside a chunk, is damage the scanner reports, and never makes it allocate
//! more than the file (mcap 0.26 would reserve the whole 4 GiB for a string before reading it,
//! which aborts a host without overcommit). The largest single allocation is measured by a
//! counting global allocator, so this test fails where overcommit would hide the reservation.

use std::alloc::{GlobalAlloc, Layout, System};
use std::borrow::Cow;
use std::collections::BTreeMap;
use std::io::Cursor;
use std::sync::atomic::{AtomicUsize, Ordering};

use chaoscope_files::scan::Scanner;
use mcap::records::{MessageHeader, Metadata, op};

/// The system allocator, remembering the largest allocation asked of it.
struct Largest;

static LARGEST: AtomicUsize = AtomicUsize::new(0);

unsafe impl GlobalAlloc for Largest {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        LARGEST.fetch_max(layout.size(), Ordering::Relaxed);
        // SAFETY: forwarded as is.
        unsafe { System.alloc(layout) }
    }
    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        LARGEST.fetch_max(layout.size(), Ordering::Relaxed);
        // SAFETY: forwarded as is.
        unsafe { System.alloc_zeroed(layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        LARGEST.fetch_max(new_size, Ordering::Relaxed);
        // SAFETY: forwarded as is.
        unsafe { System.realloc(ptr, layout, new_size) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: forwarded as is.
        unsafe { System.dealloc(ptr, layout) }
    }
}

#[global_allocator]
static ALLOCATOR: Largest = Largest;

/// Strings and byte arrays of the file, each found by its bytes (its length prefix just before).
const NAMED: [&str; 12] = [
    "profile_q",
    "library_q",
    "schema_name_q",
    "schema_enc_q",
    "schema_data_q",
    "topic_q",
    "msg_enc_q",
    "chkey_q",
    "chvalue_q",
    "att_name_q",
    "att_media_q",
    "meta_name_q",
];

/// A file of every record type chaoscope files hold, chunks uncompressed (so the records in
/// them can be found), with a full summary.
fn every_record() -> Vec<u8> {
    let mut w = mcap::WriteOptions::new()
        .compression(None)
        .profile("profile_q")
        .library("library_q")
        .create(Cursor::new(Vec::new()))
        .unwrap();
    let schema = w
        .add_schema("schema_name_q", "schema_enc_q", b"schema_data_q")
        .unwrap();
    let metadata = BTreeMap::from([("chkey_q".to_string(), "chvalue_q".to_string())]);
    let channel = w
        .add_channel(schema, "topic_q", "msg_enc_q", &metadata)
        .unwrap();
    for sequence in 0..3 {
        let header = MessageHeader {
            channel_id: channel,
            sequence,
            log_time: u64::from(sequence),
            publish_time: u64::from(sequence),
        };
        w.write_to_known_channel(&header, b"payload").unwrap();
    }
    w.attach(&mcap::Attachment {
        log_time: 1,
        create_time: 2,
        name: "att_name_q".into(),
        media_type: "att_media_q".into(),
        data: Cow::Borrowed(b"attached"),
    })
    .unwrap();
    w.write_metadata(&Metadata {
        name: "meta_name_q".into(),
        metadata: BTreeMap::from([("mdkey_q".to_string(), "mdvalue_q".to_string())]),
    })
    .unwrap();
    w.finish().unwrap();
    w.into_inner().into_inner()
}

/// Every offset of a u32 length prefix in `bytes` (strings, byte arrays, maps), found from the
/// named strings and the fixed layout of chunks and summary records.
fn length_prefixes(bytes: &[u8]) -> Vec<usize> {
    let u32_at = |at: usize| u32::from_le_bytes(bytes[at..at + 4].try_into().unwrap()) as usize;
    let mut found = Vec::new();
    let maps = ["chkey_q", "mdkey_q"];
    for name in NAMED.iter().chain(&maps) {
        let hits: Vec<usize> = (0..bytes.len() - name.len())
            .filter(|&at| bytes[at..].starts_with(name.as_bytes()))
            .collect();
        assert!(!hits.is_empty(), "{name} not found");
        for at in hits {
            assert_eq!(u32_at(at - 4), name.len(), "{name}");
            found.push(at - 4);
            if maps.contains(name) {
                // The map's byte length before its first key.
                found.push(at - 8);
            }
        }
    }
    let mut kinds = BTreeMap::new();
    for at in chaoscope_files::testing::record_offsets(bytes) {
        let body = at + 9;
        *kinds.entry(bytes[at]).or_insert(0) += 1;
        match bytes[at] {
            op::CHUNK => found.push(body + 28),
            op::MESSAGE_INDEX => found.push(body + 2),
            op::CHUNK_INDEX => {
                found.push(body + 32);
                found.push(body + 32 + 4 + u32_at(body + 32) + 8);
            }
            op::STATISTICS => found.push(body + 42),
            _ => {}
        }
    }
    for opcode in [
        op::CHUNK,
        op::MESSAGE_INDEX,
        op::CHUNK_INDEX,
        op::STATISTICS,
        op::ATTACHMENT_INDEX,
        op::METADATA_INDEX,
    ] {
        assert!(kinds.contains_key(&opcode), "no record 0x{opcode:02x}");
    }
    found.sort_unstable();
    found.dedup();
    found
}

/// Scans `bytes` to its end; returns where it stopped and the largest allocation meanwhile.
fn scan(bytes: &[u8]) -> (Option<String>, usize) {
    LARGEST.store(0, Ordering::Relaxed);
    let Some(mut scanner) = Scanner::open(bytes, Some(bytes.len() as u64)).unwrap() else {
        return (Some("no magic".into()), LARGEST.load(Ordering::Relaxed));
    };
    while scanner.next().unwrap().is_some() {}
    let stopped = scanner.scan().stopped_at.clone();
    (stopped, LARGEST.load(Ordering::Relaxed))
}

/// `bytes` with its chunks' CRCs zeroed (no CRC: valid, and the records in them are parsed
/// unchecked).
fn without_chunk_crcs(bytes: &[u8]) -> Vec<u8> {
    let mut bytes = bytes.to_vec();
    for at in chaoscope_files::testing::chunk_offsets(&bytes) {
        bytes[at + 9 + 24..at + 9 + 28].fill(0);
    }
    bytes
}

#[test]
fn a_damaged_length_prefix_is_damage_and_allocates_nothing_large() {
    let file = every_record();
    let bound = 4 * file.len() + (64 << 10);
    for bytes in [file.clone(), without_chunk_crcs(&file)] {
        assert_eq!(scan(&bytes).0, None);
        let prefixes = length_prefixes(&bytes);
        assert!(prefixes.len() > 20, "{prefixes:?}");
        for &at in &prefixes {
            let mut damaged = bytes.clone();
            damaged[at..at + 4].fill(0xff);
            let (stopped, largest) = scan(&damaged);
            assert!(stopped.is_some(), "length at byte {at} not found damaged");
            assert!(
                largest <= bound,
                "length at byte {at}: {largest} bytes allocated"
            );
        }
        // Any four bytes: never a panic, never a large allocation.
        for at in 0..bytes.len() - 4 {
            let mut damaged = bytes.clone();
            damaged[at..at + 4].fill(0xff);
            let (_, largest) = scan(&damaged);
            assert!(largest <= bound, "bytes {at}..: {largest} bytes allocated");
        }
    }
}
