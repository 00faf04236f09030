//! Replays every input the fuzzer kept (`fuzz/corpus/<target>/`) and every crash reproducer
//! (`fuzz/regressions/<target>/`) through the same target functions AFL runs (`fuzz/src/lib.rs`,
//! included here), so CI exercises them without AFL: a panic in a target fails this test, and a
//! reproducer stays fixed.

#[path = "../fuzz/src/lib.rs"]
mod targets;

use std::path::Path;
use std::time::Instant;

/// Inputs of one target, corpus then regressions, in name order.
fn inputs(target: &str) -> Vec<std::path::PathBuf> {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("fuzz");
    let mut all = Vec::new();
    for dir in ["corpus", "regressions"] {
        let Ok(entries) = std::fs::read_dir(root.join(dir).join(target)) else {
            continue;
        };
        let mut files: Vec<_> = entries
            .map(|e| e.unwrap().path())
            .filter(|p| p.is_file() && !p.file_name().unwrap().to_string_lossy().starts_with('.'))
            .collect();
        files.sort();
        all.extend(files);
    }
    all
}

fn replay(target: &str, run: fn(&[u8])) {
    let files = inputs(target);
    assert!(
        files.len() >= 5,
        "fuzz/corpus/{target}/ holds {} inputs",
        files.len()
    );
    let start = Instant::now();
    for f in &files {
        let data = std::fs::read(f).unwrap();
        let result = std::panic::catch_unwind(|| run(&data));
        assert!(result.is_ok(), "{target}: {} fails", f.display());
    }
    eprintln!(
        "{target}: {} inputs replayed in {:?}",
        files.len(),
        start.elapsed()
    );
}

#[test]
fn mcap_corpus_and_regressions_replay() {
    replay("mcap", targets::mcap);
}

#[test]
fn config_corpus_and_regressions_replay() {
    replay("config", targets::config);
}

#[test]
fn expr_corpus_and_regressions_replay() {
    replay("expr", targets::expr);
}

/// Replays a `values_*` target's corpus (AFL's kept inputs and the reproducers of what it
/// found), then `seeded` inputs of seeded noise (a few hostile values among valid ones), and
/// reports how many files were read with their outputs checked and how many were refused.
fn replay_values(target: &str, run: fn(&[u8]) -> targets::Outcome, seeded: usize) {
    let files = inputs(target);
    assert!(
        files.len() >= 5,
        "fuzz/corpus/{target}/ holds {} inputs",
        files.len()
    );
    let mut noise = chaoscope_files::testing::Noise::new(41);
    let generated = (0..seeded).map(|case| {
        // About one value in 4, 16, 64 or 256 hostile.
        let rarity = [4u64, 16, 64, 256][case % 4];
        let bytes: Vec<u8> = (0..2048)
            .map(|_| {
                let b = (noise.next_u64() >> 56) as u8;
                if noise.next_u64().is_multiple_of(rarity) {
                    b | 0xa0
                } else {
                    b % 0xa0
                }
            })
            .collect();
        (format!("seeded case {case}"), bytes)
    });
    let start = Instant::now();
    let (mut read, mut refused, mut outputs) = (0, 0, 0);
    let all = files
        .iter()
        .map(|f| (f.display().to_string(), std::fs::read(f).unwrap()))
        .chain(generated);
    for (name, data) in all {
        match std::panic::catch_unwind(|| run(&data)) {
            Ok(o) if o.read => {
                read += 1;
                outputs += o.outputs;
            }
            Ok(_) => refused += 1,
            Err(_) => panic!("{target}: {name} fails"),
        }
    }
    eprintln!(
        "{target}: {} corpus inputs and {seeded} seeded: {read} files read with {outputs} \
         outputs free of NaN and infinity, {refused} refused in one line naming the file; \
         {:?}",
        files.len(),
        start.elapsed()
    );
    // Both kinds of outcome, or the corpus and the generator have lost their reach.
    assert!(read > 0 && refused > 0, "{read} read, {refused} refused");
}

#[test]
fn hostile_values_in_valid_recordings_corpus_replays() {
    replay_values("values_recording", targets::values_recording, 200);
}

#[test]
fn hostile_values_replayed_corpus_replays() {
    replay_values("values_replay", targets::values_replay, 100);
}

#[test]
fn hostile_values_in_valid_maps_corpus_replays() {
    replay_values("values_map", targets::values_map, 200);
}

#[test]
fn hostile_values_resumed_corpus_replays() {
    replay_values("values_resume", targets::values_resume, 60);
}

#[test]
fn hostile_values_in_clvs_corpus_replays() {
    replay_values("values_clv", targets::values_clv, 100);
}

#[test]
fn hostile_map_headers_corpus_replays() {
    replay_values("values_map_header", targets::values_map_header, 200);
}

/// The committed seeds of the resume, CLV and map-header targets are the generated ones
/// (`targets::values_seeds`, which `fuzz/src/bin/seeds.rs` writes): a change to the generator
/// without new files, or a lost file, fails here. `CHAOSCOPE_WRITE_FUZZ_SEEDS=1` writes them.
#[test]
fn the_values_seeds_are_committed() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("fuzz/corpus");
    let write = std::env::var_os("CHAOSCOPE_WRITE_FUZZ_SEEDS").is_some();
    for target in ["values_resume", "values_clv", "values_map_header"] {
        let dir = root.join(target);
        for (name, bytes) in targets::values_seeds(target) {
            let path = dir.join(&name);
            if write {
                std::fs::create_dir_all(&dir).unwrap();
                std::fs::write(&path, &bytes).unwrap();
            }
            assert_eq!(
                std::fs::read(&path).ok(),
                Some(bytes),
                "{} is not the generated seed",
                path.display()
            );
        }
    }
}
