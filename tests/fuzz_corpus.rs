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
