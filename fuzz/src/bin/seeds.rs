//! Writes the starting corpus of each target into `corpus/<target>/` (run once from `fuzz/`:
//! `cargo run --release --bin seeds`; AFL then grows the corpus, and `cargo afl cmin` keeps it
//! small).
//!
//! MCAP seeds are small files in the recorder's layout, with their CRCs set to 0 ("not
//! computed", which the format allows), so that mutations inside a chunk reach the record and
//! protobuf parsers instead of stopping at the CRC check every time.

use std::io::Cursor;
use std::path::Path;

use chaoscope_files::file::{Compression, FileOptions};
use chaoscope_files::testing::{self, Shape};

/// Zeroes the chunk, data-section and summary CRCs of an MCAP file.
fn without_crcs(mut bytes: Vec<u8>) -> Vec<u8> {
    for at in testing::record_offsets(&bytes) {
        let field = match bytes[at] {
            mcap::records::op::CHUNK => 1 + 8 + 8 + 8 + 8,
            mcap::records::op::DATA_END => 1 + 8,
            mcap::records::op::FOOTER => 1 + 8 + 8 + 8,
            _ => continue,
        };
        if let Some(crc) = bytes.get_mut(at + field..at + field + 4) {
            crc.fill(0);
        }
    }
    bytes
}

fn run(shape: &Shape, compression: Compression, chunk_size: u64) -> Vec<u8> {
    let options = FileOptions {
        compression,
        chunk_size,
    };
    testing::write_run(Cursor::new(Vec::new()), shape, &options, 3)
        .expect("writing to memory")
        .into_inner()
}

fn main() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mcap_dir = root.join("corpus/mcap");
    std::fs::create_dir_all(&mcap_dir).unwrap();
    let tiny = Shape {
        dim: 4,
        k: 2,
        sets: 1,
        samples: 3,
    };
    let mut seeds: Vec<(String, Vec<u8>)> = vec![
        (
            "run-plain".into(),
            without_crcs(run(&tiny, Compression::None, 256)),
        ),
        (
            "run-zstd".into(),
            without_crcs(run(&tiny, Compression::Zstd, 256)),
        ),
        (
            "run-lz4".into(),
            without_crcs(run(&tiny, Compression::Lz4, 256)),
        ),
        ("run-crc".into(), run(&tiny, Compression::None, 1 << 20)),
        (
            "map-plain".into(),
            without_crcs(testing::small_map(4, 2, Compression::None).0),
        ),
        ("magic-only".into(), mcap::MAGIC.to_vec()),
        ("short-attachment".into(), {
            let mut b = mcap::MAGIC.to_vec();
            b.extend(testing::short_attachment());
            b
        }),
    ];
    let plain = without_crcs(run(&tiny, Compression::None, 256));
    for (i, d) in testing::huge_lengths(&plain).take(4).enumerate() {
        seeds.push((format!("huge-length-{i}"), d.bytes));
    }
    seeds.push(("cut-half".into(), plain[..plain.len() / 2].to_vec()));
    for (name, bytes) in seeds {
        std::fs::write(mcap_dir.join(name), bytes).unwrap();
    }

    let config_dir = root.join("corpus/config");
    std::fs::create_dir_all(&config_dir).unwrap();
    let repo = root.parent().unwrap();
    let mut n = 0;
    for dir in ["examples/paper/configs", "examples/maps", "src/cli"] {
        for e in std::fs::read_dir(repo.join(dir)).unwrap() {
            let p = e.unwrap().path();
            if p.extension().is_some_and(|x| x == "toml") {
                let name = p.file_name().unwrap().to_string_lossy().into_owned();
                std::fs::copy(&p, config_dir.join(name)).unwrap();
                n += 1;
            }
        }
    }
    for target in ["values_resume", "values_clv", "values_map_header"] {
        let dir = root.join("corpus").join(target);
        std::fs::create_dir_all(&dir).unwrap();
        for (name, bytes) in chaoscope_fuzz::values_seeds(target) {
            std::fs::write(dir.join(name), bytes).unwrap();
        }
    }
    println!("{n} config seeds, MCAP seeds in {}", mcap_dir.display());
}
