//! `chaoscope recover` on damaged files: truncated anywhere, followed by zeros or garbage,
//! corrupted inside a chunk, and on arbitrary bytes. What it salvages is always an exact prefix
//! of the original messages: every chunk that ends before the damage, nothing after it.

use std::path::{Path, PathBuf};

use chaoscope_files::file::Compression;
use chaoscope_files::recover::{RecoverError, RecoverReport, recover};
use chaoscope_files::testing::{self as synthetic, Message, Noise, mcap_messages as messages};

/// A small recording of about 15 chunks (the recorder's layout), its messages, and its chunks.
struct Original {
    bytes: Vec<u8>,
    messages: Vec<Message>,
    chunks: Vec<Chunk>,
}

struct Chunk {
    start: u64,
    end: u64,
    messages: usize,
}

impl Original {
    fn new(compression: Compression) -> Self {
        let bytes = synthetic::small_run(compression);
        let messages = messages(&bytes);
        let summary = mcap::Summary::read(&bytes).unwrap().expect("summary");
        let chunks: Vec<Chunk> = summary
            .chunk_indexes
            .iter()
            .map(|c| Chunk {
                start: c.chunk_start_offset,
                end: c.chunk_start_offset + c.chunk_length,
                messages: summary.stream_chunk(&bytes, c).unwrap().count(),
            })
            .collect();
        assert!(chunks.len() > 8, "{} chunks", chunks.len());
        assert_eq!(
            chunks.iter().map(|c| c.messages).sum::<usize>(),
            messages.len(),
            "every message is in a chunk"
        );
        Self {
            bytes,
            messages,
            chunks,
        }
    }

    /// Messages in the chunks that end at or before byte `cut`.
    fn salvageable(&self, cut: usize) -> usize {
        self.chunks
            .iter()
            .filter(|c| c.end <= cut as u64)
            .map(|c| c.messages)
            .sum()
    }
}

struct Files {
    _dir: tempfile::TempDir,
    input: PathBuf,
    output: PathBuf,
}

impl Files {
    fn new() -> Self {
        let dir = chaoscope_files::testing::scratch_dir();
        let input = dir.path().join("broken.mcap");
        let output = dir.path().join("fixed.mcap");
        Self {
            _dir: dir,
            input,
            output,
        }
    }

    /// Recovers `bytes` (with --force) and returns the report and the salvaged messages.
    fn recover(&self, bytes: &[u8]) -> (RecoverReport, Vec<Message>) {
        std::fs::write(&self.input, bytes).unwrap();
        let report = recover(&self.input, &self.output, true).unwrap();
        let out = std::fs::read(&self.output).unwrap();
        assert!(
            mcap::Summary::read(&out).unwrap().is_some(),
            "the salvaged file is indexed"
        );
        let salvaged = messages(&out);
        assert_eq!(salvaged.len() as u64, report.messages);
        (report, salvaged)
    }
}

#[test]
fn a_complete_file_is_copied_whole() {
    let original = Original::new(Compression::Zstd);
    let files = Files::new();
    let (report, salvaged) = files.recover(&original.bytes);
    assert_eq!(report.stopped_at, None);
    assert_eq!(salvaged, original.messages);
    assert_eq!(report.chunks as usize, original.chunks.len());
    assert_eq!(report.metadata, 2, "chaoscope.run and chaoscope.recording");
}

#[test]
fn a_file_cut_anywhere_keeps_exactly_the_chunks_before_the_cut() {
    for compression in [Compression::Zstd, Compression::None] {
        let original = Original::new(compression);
        let files = Files::new();
        let len = original.bytes.len();
        // Every byte through the magic, header and first chunk, every 29th byte after, and a
        // few bytes either side of every chunk end.
        let mut cuts: Vec<usize> = (0..400.min(len)).chain((400..len).step_by(29)).collect();
        for chunk in &original.chunks {
            let end = chunk.end as usize;
            cuts.extend(end.saturating_sub(2)..(end + 3).min(len + 1));
        }
        cuts.sort_unstable();
        cuts.dedup();
        let mut previous = 0;
        let mut partial = 0;
        for cut in cuts {
            std::fs::write(&files.input, &original.bytes[..cut]).unwrap();
            let result = recover(&files.input, &files.output, true);
            if cut < mcap::MAGIC.len() {
                assert!(
                    matches!(result, Err(RecoverError::NotMcap { .. })),
                    "cut {cut}: {result:?}"
                );
                continue;
            }
            let report = result.unwrap_or_else(|e| panic!("cut {cut}: {e}"));
            let salvaged = messages(&std::fs::read(&files.output).unwrap());
            let n = salvaged.len();
            assert_eq!(n as u64, report.messages);
            assert_eq!(n, original.salvageable(cut), "cut {cut}: {report:?}");
            assert!(n >= previous, "cut {cut}: {n} < {previous}");
            assert!(
                salvaged[..] == original.messages[..n],
                "cut {cut}: not a prefix"
            );
            if cut as u64 <= original.chunks.last().unwrap().end {
                assert!(report.stopped_at.is_some(), "cut {cut} is damage");
            }
            previous = n;
            partial += usize::from(0 < n && n < original.messages.len());
        }
        assert!(partial > 100, "{partial} cuts with a partial salvage");
    }
}

#[test]
fn where_and_why_it_stopped_is_named() {
    let original = Original::new(Compression::Zstd);
    let files = Files::new();
    let (first_end, first) = (original.chunks[0].end, original.chunks[0].messages);
    let second = &original.chunks[1];
    // Exactly after the first chunk: nothing damaged, but no data end record.
    let (report, salvaged) = files.recover(&original.bytes[..first_end as usize]);
    assert_eq!(salvaged.len(), first);
    let stopped = report.stopped_at.unwrap();
    assert!(
        stopped.contains(&format!("at byte {first_end}")) && stopped.contains("data end"),
        "{stopped}"
    );
    // Inside the second chunk: the cut chunk is named by its offset.
    let mid = (second.start + second.end) as usize / 2;
    let (report, _) = files.recover(&original.bytes[..mid]);
    let stopped = report.stopped_at.unwrap();
    assert!(
        stopped.contains("record") && stopped.contains("at byte"),
        "{stopped}"
    );
}

#[test]
fn zeros_or_garbage_after_a_valid_prefix_are_not_salvaged() {
    let original = Original::new(Compression::Zstd);
    let files = Files::new();
    let boundary = original.chunks[3].end as usize;
    let inside = (original.chunks[4].start + original.chunks[4].end) as usize / 2;
    for cut in [boundary, inside] {
        let expected = original.salvageable(cut);
        let mut tails = vec![("zeros", vec![0u8; 64 << 10])];
        for seed in 0..16 {
            tails.push((
                "garbage",
                Noise::new(seed).bytes(1 + (seed as usize * 997) % 5000),
            ));
        }
        for (what, tail) in tails {
            let mut bytes = original.bytes[..cut].to_vec();
            bytes.extend_from_slice(&tail);
            let (report, salvaged) = files.recover(&bytes);
            assert!(
                salvaged[..] == original.messages[..expected],
                "{what} after byte {cut}: {} messages, expected {expected}",
                salvaged.len()
            );
            let stopped = report.stopped_at.expect("damage is reported");
            if what == "zeros" && cut == boundary {
                assert!(stopped.contains("0x00"), "{stopped}");
            }
        }
    }
}

#[test]
fn a_corrupted_chunk_is_dropped_whole_and_reading_stops_there() {
    for compression in [Compression::Zstd, Compression::None] {
        let original = Original::new(compression);
        let files = Files::new();
        let (start, end) = (original.chunks[5].start, original.chunks[5].end);
        // In the compressed data, the middle, the last bytes.
        for at in [start + 60, (start + end) / 2, end - 5] {
            let mut bytes = original.bytes.clone();
            bytes[at as usize] ^= 0x40;
            let (report, salvaged) = files.recover(&bytes);
            let expected = original.salvageable(start as usize);
            assert!(
                salvaged[..] == original.messages[..expected],
                "flip at {at}: {} messages, expected {expected}",
                salvaged.len()
            );
            assert!(report.stopped_at.is_some());
        }
    }
}

#[test]
fn a_chunk_whose_opcode_is_hit_stops_the_salvage_there() {
    // Every single bit flip of a chunk's opcode: unknown record types, summary records, a
    // footer, a channel, a message index; none may make the chunk vanish silently.
    for compression in [Compression::Zstd, Compression::None] {
        let original = Original::new(compression);
        let files = Files::new();
        // The first chunk starts at time 0: its fields read as the fewest entries.
        for (chunk, bit) in [&original.chunks[0], &original.chunks[5]]
            .into_iter()
            .flat_map(|chunk| (0..8).map(move |bit| (chunk, bit)))
        {
            let mut bytes = original.bytes.clone();
            bytes[chunk.start as usize] ^= 1 << bit;
            let (report, salvaged) = files.recover(&bytes);
            let expected = original.salvageable(chunk.start as usize);
            assert!(
                salvaged[..] == original.messages[..expected],
                "{compression:?}, opcode 0x{:02x}: {} messages, expected {expected}",
                bytes[chunk.start as usize],
                salvaged.len()
            );
            let stopped = report.stopped_at.expect("damage is reported");
            assert!(
                stopped.contains(&format!("at byte {}", chunk.start)),
                "{stopped}"
            );
        }
    }
}

#[test]
fn a_message_index_read_as_a_message_is_damage_not_a_message() {
    // 0x07 with bit 1 flipped is 0x05: the message index after a chunk then parses as a
    // well-formed message of a real channel. Every message index of both layouts, one at a
    // time: the salvage stops there and keeps exactly the chunks before it. (Seen once in CI,
    // where the randomly placed flips of `every_kind_of_damage_leaves_an_exact_prefix` fall
    // on other bytes from one run to the next: the file holds wall-clock publish times.)
    for compression in [Compression::Zstd, Compression::None] {
        let original = Original::new(compression);
        let files = Files::new();
        let indexes: Vec<usize> = synthetic::record_offsets(&original.bytes)
            .into_iter()
            .filter(|&at| original.bytes[at] == mcap::records::op::MESSAGE_INDEX)
            .collect();
        assert!(indexes.len() >= original.chunks.len(), "{compression:?}");
        for at in indexes {
            let mut bytes = original.bytes.clone();
            bytes[at] = mcap::records::op::MESSAGE;
            let (report, salvaged) = files.recover(&bytes);
            let expected = original.salvageable(at);
            assert!(
                salvaged[..] == original.messages[..expected],
                "{compression:?}, message index at byte {at}: {} messages, expected {expected}",
                salvaged.len()
            );
            let stopped = report.stopped_at.expect("damage is reported");
            assert!(
                stopped.contains(&format!("at byte {at}"))
                    && stopped.contains("outside the chunks"),
                "{stopped}"
            );
        }
    }
}

#[test]
fn any_single_corrupted_byte_leaves_an_exact_prefix() {
    let original = Original::new(Compression::Zstd);
    let files = Files::new();
    for damaged in synthetic::flips(&original.bytes, 300, 99) {
        std::fs::write(&files.input, &damaged.bytes).unwrap();
        let what = &damaged.what;
        match recover(&files.input, &files.output, true) {
            Ok(_) => {
                let salvaged = messages(&std::fs::read(&files.output).unwrap());
                let n = salvaged.len();
                assert!(salvaged[..] == original.messages[..n], "{what}");
            }
            Err(RecoverError::NotMcap { .. }) => assert!(!damaged.bytes.starts_with(mcap::MAGIC)),
            Err(e) => panic!("{what}: {e}"),
        }
    }
}

#[test]
fn every_kind_of_damage_leaves_an_exact_prefix() {
    for compression in [Compression::Zstd, Compression::None] {
        let original = Original::new(compression);
        let files = Files::new();
        for damaged in synthetic::hostile(&original.bytes, 1) {
            std::fs::write(&files.input, &damaged.bytes).unwrap();
            let what = format!("{compression:?}, {}", damaged.what);
            match recover(&files.input, &files.output, true) {
                Ok(report) => {
                    let salvaged = messages(&std::fs::read(&files.output).unwrap());
                    let n = salvaged.len();
                    assert_eq!(n as u64, report.messages, "{what}");
                    if damaged.what.starts_with("random records") {
                        continue; // not the original's bytes
                    }
                    assert!(
                        n <= original.messages.len() && salvaged[..] == original.messages[..n],
                        "{what}: not a prefix ({n} messages of {})",
                        original.messages.len()
                    );
                    if report.stopped_at.is_none() {
                        assert_eq!(n, original.messages.len(), "{what}: complete, but short");
                    }
                }
                Err(RecoverError::NotMcap { .. }) => {
                    assert!(!damaged.bytes.starts_with(mcap::MAGIC), "{what}")
                }
                Err(e) => panic!("{what}: {e}"),
            }
        }
    }
}

#[test]
fn arbitrary_bytes_after_the_magic_never_panic() {
    let files = Files::new();
    for damaged in synthetic::random_records(400, 3) {
        std::fs::write(&files.input, &damaged.bytes).unwrap();
        if let Err(e) = recover(&files.input, &files.output, true) {
            panic!("{}: {e}", damaged.what);
        }
    }
}

#[test]
fn a_short_attachment_record_is_damage_not_a_panic() {
    let mut bytes = mcap::MAGIC.to_vec();
    // A header record (empty profile and library), then the attachment.
    bytes.push(mcap::records::op::HEADER);
    bytes.extend(8u64.to_le_bytes());
    bytes.extend([0; 8]);
    bytes.extend(synthetic::short_attachment());
    let files = Files::new();
    let (report, salvaged) = files.recover(&bytes);
    assert!(salvaged.is_empty());
    assert!(report.stopped_at.unwrap().contains("attachment"));
}

#[test]
fn the_output_is_never_the_input() {
    let original = Original::new(Compression::Zstd);
    let files = Files::new();
    let cut = &original.bytes[..original.bytes.len() / 2];
    std::fs::write(&files.input, cut).unwrap();
    let dir = files.input.parent().unwrap();
    let link = dir.join("link.mcap");
    std::os::unix::fs::symlink(&files.input, &link).unwrap();
    let hard = dir.join("hard.mcap");
    std::fs::hard_link(&files.input, &hard).unwrap();
    let spelled = dir.join(".").join("broken.mcap");
    for output in [&files.input, &link, &hard, &spelled] {
        for force in [false, true] {
            let result = recover(&files.input, output, force);
            assert!(
                matches!(&result, Err(RecoverError::SameFile { .. })),
                "{}: {result:?}",
                output.display()
            );
            let message = result.unwrap_err().to_string();
            assert!(message.contains("input"), "{message}");
        }
    }
    assert_eq!(std::fs::read(&files.input).unwrap(), cut, "input untouched");
}

#[test]
fn existing_output_needs_force_and_other_inputs_are_refused() {
    let original = Original::new(Compression::Zstd);
    let files = Files::new();
    std::fs::write(&files.input, &original.bytes).unwrap();
    std::fs::write(&files.output, b"keep me").unwrap();
    assert!(matches!(
        recover(&files.input, &files.output, false),
        Err(RecoverError::Output(chaoscope_os::OutputError::Exists(_)))
    ));
    assert_eq!(std::fs::read(&files.output).unwrap(), b"keep me");
    assert!(recover(&files.input, &files.output, true).is_ok());

    let text = files.input.with_file_name("notes.txt");
    std::fs::write(&text, "not an mcap file at all").unwrap();
    assert!(matches!(
        recover(&text, &files.output, true),
        Err(RecoverError::NotMcap { .. })
    ));
    let missing = Path::new("/nonexistent/chaoscope/broken.mcap");
    assert!(matches!(
        recover(missing, &files.output, true),
        Err(RecoverError::Io { .. })
    ));
}
