//! Map recordings are hostile input too (`chaoscope map` resumes them, `merge` joins them):
//! reading one never panics, and whatever the damage, what it returns is an exact prefix of the
//! map's points in whole chunks, with `damaged` saying where and why reading stopped.

use std::panic::{AssertUnwindSafe, catch_unwind};

use chaoscope_files::file::Compression;
use chaoscope_files::map_file::{MapContents, read_map, read_map_file};
use chaoscope_files::scan::FileError;
use chaoscope_files::testing;
use chaoscope_schemas::proto::{MapHeader, MapPoint};

/// Points per chunk of [`map`].
const PER_CHUNK: usize = 5;

/// A map of 60 points in chunks of five.
fn map(compression: Compression) -> (Vec<u8>, MapHeader, Vec<MapPoint>) {
    testing::small_map(60, PER_CHUNK as u64, compression)
}

#[test]
fn damaged_maps_keep_an_exact_prefix_of_whole_chunks() {
    for compression in [Compression::Zstd, Compression::None] {
        let (bytes, header, points) = map(compression);
        let whole = read_map(&bytes[..], None).unwrap().unwrap();
        assert_eq!(
            whole,
            MapContents {
                header: Some(header.clone()),
                points: points.clone(),
                damaged: None,
                cut_before_any_chunk: false,
                described_as_map: true,
            }
        );
        let (mut partial, mut complete) = (0, 0);
        for damaged in testing::hostile(&bytes, 11) {
            let what = format!("{compression:?}, {}", damaged.what);
            let len = Some(damaged.bytes.len() as u64);
            let read = catch_unwind(AssertUnwindSafe(|| read_map(&damaged.bytes[..], len)))
                .unwrap_or_else(|_| panic!("{what}: panicked"))
                .unwrap();
            let Some(contents) = read else {
                assert!(!damaged.bytes.starts_with(mcap::MAGIC), "{what}");
                continue;
            };
            let n = contents.points.len();
            assert!(contents.points[..] == points[..n], "{what}: not a prefix");
            assert!(n % PER_CHUNK == 0, "{what}: {n} points, not whole chunks");
            if n > 0 {
                assert_eq!(contents.header.as_ref(), Some(&header), "{what}");
            }
            match &contents.damaged {
                // Read to its end: the map, or a file of its own (random records).
                None => {
                    complete += 1;
                    let empty = contents.header.is_none() && n == 0;
                    assert!(contents == whole || empty, "{what}: {contents:?}");
                }
                Some(why) => {
                    partial += usize::from(n > 0);
                    assert!(
                        why.starts_with("record ") && why.contains(" at byte "),
                        "{what}: {why}"
                    );
                }
            }
        }
        assert!(
            partial > 100 && complete > 0,
            "{partial} partial, {complete} complete"
        );
    }
}

#[test]
fn map_files_are_read_streaming_and_errors_name_the_file() {
    let (bytes, _, points) = map(Compression::Zstd);
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("map.mcap");
    std::fs::write(&path, &bytes).unwrap();
    assert_eq!(read_map_file(&path).unwrap().points, points);

    // Inside the fourth chunk.
    let chunk = testing::chunk_offsets(&bytes)[3];
    std::fs::write(&path, &bytes[..chunk + 20]).unwrap();
    let cut = read_map_file(&path).unwrap();
    assert_eq!(cut.points, points[..3 * PER_CHUNK]);
    assert!(cut.damaged.unwrap().contains(&format!("at byte {chunk}")));

    std::fs::write(&path, "not a map").unwrap();
    let e = read_map_file(&path).unwrap_err();
    assert!(matches!(e, FileError::NotMcap { .. }));
    assert!(e.to_string().contains(path.to_str().unwrap()), "{e}");
    let missing = dir.path().join("missing.mcap");
    let e = read_map_file(&missing).unwrap_err();
    assert!(matches!(e, FileError::Io { .. }));
    assert!(e.to_string().contains(missing.to_str().unwrap()), "{e}");
}
