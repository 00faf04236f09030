//! The fuzz targets: one function per reader of hostile input, taking arbitrary bytes. A target
//! passes if it returns; a panic, an abort (an allocation the input should not cause) or a hang
//! is a finding.
//!
//! Used twice: by the AFL binaries in `src/bin/` (`cargo afl build`), and by the root test
//! `tests/fuzz_corpus.rs`, which includes this very file and replays `fuzz/corpus/<target>/` and
//! `fuzz/regressions/<target>/` through it, so CI exercises every input found without AFL.
//! Only workspace crates are used here (no AFL), for that second use.
//!
//! Targets:
//! - [`mcap`]: the MCAP scanner in memory (records and messages), the map reader, and through a
//!   file the analyzer's recording reader and analysis, `summary`, the map file reader and
//!   `recover` (whose output must read back, keep every message a reader of the input sees, and
//!   come through a second `recover` unchanged).
//! - [`config`]: `RunConfig::from_toml`, the resource estimate, then `RunSpec::from_config` or
//!   `MapSpec::from_config`, as `chaoscope run`/`map` call them.
//! - [`expr`]: the expression language of user-written potentials: parsing, lowering under
//!   each boundary condition (parameters, an array parameter, a table), smoothness, the
//!   symbolic gradient and Hessian-vector product, the reference evaluator, and, for graphs of
//!   modest size, native compilation.

use std::io::Cursor;

use chaoscope_producer::estimate::{self, Machine};
use chaoscope_producer::map::MapSpec;
use chaoscope_producer::spec::RunSpec;
use chaoscope_recorder::scan::{Entry, Messages, Scanner};
use chaoscope_schemas::config::{ModelConfig, RunConfig};

/// Every MCAP reader over `data`.
pub fn mcap(data: &[u8]) {
    let len = Some(data.len() as u64);
    // The scanner: records and whole chunks, then messages with their topics.
    if let Ok(Some(mut scanner)) = Scanner::open(Cursor::new(data), len) {
        let mut records = 0usize;
        while let Ok(Some(entry)) = scanner.next() {
            if let Entry::Chunk(inside) = entry {
                records += inside.len();
            }
        }
        let _ = (records, scanner.scan());
    }
    if let Ok(Some(scanner)) = Scanner::open(Cursor::new(data), len) {
        let mut messages = Messages::new(scanner);
        while let Ok(Some(m)) = messages.next_message() {
            let _ = (m.topic.len(), m.data.len());
        }
    }
    let _ = chaoscope_recorder::map_file::read_map(Cursor::new(data), len);

    // The readers that open a path.
    // A directory per input, removed when this returns: AFL restarts its workers (new pids)
    // thousands of times a session, and a directory kept per process filled /tmp with them.
    let Ok(scratch) = tempfile::Builder::new().prefix("chaoscope-fuzz-").tempdir() else {
        return;
    };
    let dir = scratch.path();
    let input = dir.join("input.mcap");
    let output = dir.join("recovered.mcap");
    if std::fs::write(&input, data).is_err() {
        return;
    }
    let _ = chaoscope_analyzer::recording::analyze_file(
        &input,
        &chaoscope_analyzer::AnalysisOptions::default(),
    )
    .map(|(analysis, _)| analysis.report());
    let _ = chaoscope_analyzer::summary::summarize(&input);
    let _ = chaoscope_recorder::map_file::read_map_file(&input);
    if let Ok(report) = chaoscope_recorder::recover::recover(&input, &output, true) {
        // What recover writes must read back without damage, and hold every message a reader
        // of the input sees, in order and unchanged, before anything else: recover may keep
        // more (it passes over a message of an undefined channel where a reader stops), never
        // less, never other bytes.
        let (salvaged, damage) = read_messages(&output);
        assert_eq!(damage, None, "recover wrote a file that does not read back");
        assert_eq!(salvaged.len() as u64, report.messages, "recover's count");
        let (seen, _) = read_messages(&input);
        assert!(
            salvaged.len() >= seen.len() && salvaged[..seen.len()] == seen[..],
            "recover lost or changed a message a reader of the input sees"
        );
        // A recovered file is undamaged: recovering it again changes no message.
        let twice = dir.join("recovered-twice.mcap");
        let again = chaoscope_recorder::recover::recover(&output, &twice, true)
            .map(|r| (r.stopped_at, read_messages(&twice).0));
        assert!(
            matches!(&again, Ok((None, m)) if *m == salvaged),
            "recovering a recovered file changed it: {:?}",
            again.map(|(stopped, m)| (stopped, m.len()))
        );
    }
}

/// A message as a reader sees it: topic, (sequence, log time, publish time) and data; not the
/// channel id, which a rewrite renumbers.
type SeenMessage = (String, [u64; 3], Vec<u8>);

/// The messages of the MCAP file at `path`, and where reading stopped at damage.
fn read_messages(path: &std::path::Path) -> (Vec<SeenMessage>, Option<String>) {
    let Ok((scanner, _)) = Scanner::open_file(path) else {
        return (Vec::new(), Some("does not open".into()));
    };
    let mut messages = Messages::new(scanner);
    let mut seen = Vec::new();
    while let Ok(Some(m)) = messages.next_message() {
        let h = m.header;
        let header = [u64::from(h.sequence), h.log_time, h.publish_time];
        seen.push((m.topic.to_string(), header, m.data));
    }
    (seen, messages.scan().stopped_at.clone())
}

/// Largest deviation state (sets x k x dimension values) the `config` target validates: a
/// larger system is legitimately slow to build (a long chain's compiled potential, a valid
/// config, not a finding), and would only make the fuzzer report hangs.
const MAX_FUZZ_STATE: u128 = 1 << 16;

/// The dimension a `[model]` claims, before anything is built.
fn claimed_dim(model: &ModelConfig) -> u128 {
    let dof = |n: Option<usize>| n.unwrap_or(1).saturating_mul(2) as u128;
    let len = |v: &Option<Vec<String>>| v.as_ref().map_or(1, Vec::len) as u128;
    match model {
        ModelConfig::HenonHeiles(_) | ModelConfig::Custom(_) => 4,
        ModelConfig::FputBeta(m) => dof(m.n),
        ModelConfig::Potential(m) => dof(m.n),
        ModelConfig::Hamiltonian(m) => dof(m.n),
        ModelConfig::Ode(m) => len(&m.rhs),
        ModelConfig::Map(m) => len(&m.next),
    }
}

/// The configuration parser and validators over `data`.
pub fn config(data: &[u8]) {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    let cfg = match RunConfig::from_toml(text) {
        Ok(cfg) => cfg,
        Err(e) => {
            assert!(!e.0.contains('\n'), "a parse error of several lines: {e}");
            return;
        }
    };
    let _ = cfg.to_toml();
    let machine = Machine {
        cores: 2,
        memory_bytes: Some(24 << 30),
    };
    let schemes = cfg.expanded_schemes().map_or(1, |s| s.len().max(1));
    let dim = claimed_dim(&cfg.model);
    let state = schemes as u128 * cfg.deviations.sets.max(1) as u128 * cfg.deviations.k as u128;
    if state.saturating_mul(dim) > MAX_FUZZ_STATE {
        return;
    }
    let checked = |e: &chaoscope_producer::spec::SpecError| {
        assert!(
            !e.key.is_empty() && !e.message.is_empty() && !e.to_string().contains('\n'),
            "an error without key or message, or of several lines: {e:?}"
        );
    };
    if cfg.map.is_some() {
        match MapSpec::from_config(&cfg) {
            Ok(spec) => {
                let e = estimate::map(&spec, spec.grid_points(), 2);
                let _ = e.refusal(&machine);
            }
            Err(e) => checked(&e),
        }
    } else {
        match RunSpec::from_config(&cfg) {
            Ok(spec) => {
                let _ = estimate::run(&spec, &machine).refusal(&machine);
            }
            Err(e) => checked(&e),
        }
    }
}

/// The expression language over `data` read as text: what `[model] potential` goes through.
pub fn expr(data: &[u8]) {
    use chaoscope_expr::graph::Tabulated;
    use chaoscope_expr::jit::{self, FunctionSpec, Layout};
    use chaoscope_expr::{Boundary, Family, Graph, ParamValue, Scope, Spline, SplineKind};
    use std::collections::BTreeMap;
    use std::sync::Arc;

    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    let _ = chaoscope_expr::parse(text);
    let n = 4;
    let families = [Family {
        name: "q".to_string(),
        len: n,
        arg: 0,
        offset: 0,
    }];
    let mut params = BTreeMap::new();
    params.insert("beta".to_string(), ParamValue::Scalar(1.5));
    params.insert(
        "k".to_string(),
        ParamValue::Array(vec![1.0, 2.0, 0.5, -1.0]),
    );
    let xs = [-2.0, -1.0, 0.0, 1.0, 2.0];
    let ys = [4.0, 1.0, 0.0, 1.0, 4.0];
    let spline = Spline::new("U", &xs, &ys, SplineKind::Natural).expect("a valid table");
    for boundary in [Boundary::Fixed, Boundary::Periodic, Boundary::Free] {
        let mut g = Graph::new();
        let table = g.add_table(Arc::new(spline.clone()) as Arc<dyn Tabulated>);
        let tables = [("U".to_string(), table)];
        let scope = Scope {
            families: &families,
            params: &params,
            tables: &tables,
            n,
            boundary,
        };
        let Ok(lowered) = chaoscope_expr::lower(text, &scope, &mut g) else {
            continue;
        };
        let _ = lowered.smoothness.require(2, "vm");
        let Ok(gradient) = chaoscope_expr::gradient(&mut g, lowered.root, 0, n) else {
            continue;
        };
        let Ok(hv) = chaoscope_expr::jacobian_vector(&mut g, &gradient, 0, 1) else {
            continue;
        };
        let q = [0.3, -0.2, 0.1, 0.05];
        let v = [1.0, 0.5, -0.25, 0.125];
        let mut out = vec![0.0; n];
        chaoscope_expr::Evaluator::new().eval(&g, &[&q, &v], &hv, &mut out);
        let _ = chaoscope_expr::first_non_finite(&g, &[&q], lowered.root);
        if g.len() <= 2000 {
            let specs = [
                FunctionSpec {
                    args: vec![Layout::Scalar],
                    outputs: gradient.clone(),
                },
                FunctionSpec {
                    args: vec![Layout::Scalar, Layout::Lanes],
                    outputs: hv.clone(),
                },
            ];
            if let Ok(compiled) = jit::compile(&g, &specs) {
                let mut grad = vec![0.0; n];
                compiled.call(0, &[&q], &mut grad);
            }
        }
    }
}
