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
//! - [`values_recording`], [`values_replay`], [`values_map`]: structure-aware, for valid files
//!   with hostile values (`chaoscope_files::testing::values` writes a well-formed recording
//!   or map file whose every value the input chooses): every reader and output of a recording
//!   (analyze's report, table, CSV files and charts, the run summary), replay, and the map
//!   readers with the map PNG. Besides panics, a NaN or infinity in any output is a finding.
//! - [`values_resume`], [`values_clv`], [`values_map_header`]: structure-aware likewise, for
//!   the paths that trust a file's values most: a recording resumed and extended (the
//!   configuration it carries rebuilt into a run, its last sample into the engine's state), its
//!   covariant Lyapunov vectors (QR factors, transients, subspace classes, the angle CSV), and a
//!   map's header (checked, its configuration rebuilt as `map` resuming compares it, drawn).
//! - [`expr`]: the expression language of user-written potentials: parsing, lowering under
//!   each boundary condition (parameters, an array parameter, a table), smoothness, the
//!   symbolic gradient and Hessian-vector product, the reference evaluator, and, for graphs of
//!   modest size, native compilation.

use std::io::Cursor;

use chaoscope_dynamics::estimate::{self, Machine};
use chaoscope_dynamics::map::MapSpec;
use chaoscope_dynamics::spec::RunSpec;
use chaoscope_files::scan::{Entry, Messages, Scanner};
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
    let _ = chaoscope_files::map_file::read_map(Cursor::new(data), len);

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
    let _ = chaoscope_files::map_file::read_map_file(&input);
    if let Ok(report) = chaoscope_files::recover::recover(&input, &output, true) {
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
        let again = chaoscope_files::recover::recover(&output, &twice, true)
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
        ModelConfig::FputBeta(m) => dof(m.n),
        // A square lattice has n^2 sites.
        ModelConfig::Potential(_) | ModelConfig::Hamiltonian(_) | ModelConfig::Ddnls(_)
            if model.square_side().is_some() =>
        {
            let side = model.square_side().unwrap_or(1);
            dof(Some(side)).saturating_mul(side as u128)
        }
        ModelConfig::Potential(m) => dof(m.n),
        ModelConfig::Hamiltonian(m) => dof(m.n),
        ModelConfig::Ddnls(m) => dof(m.n),
        ModelConfig::Ode(m) => len(&m.rhs),
        ModelConfig::Map(m) => len(&m.next),
        // Henon-Heiles, a model built in code, and any kind of a size of its own.
        _ => 4,
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
    let checked = |e: &chaoscope_dynamics::spec::SpecError| {
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
                let _ = chaoscope_producer::estimate::run(&spec, &machine).refusal(&machine);
            }
            Err(e) => checked(&e),
        }
    }
}

/// The expression language over `data` read as text: what `[model] potential` goes through.
pub fn expr(data: &[u8]) {
    use chaoscope_expr::graph::Tabulated;
    use chaoscope_expr::jit::{self, FunctionSpec, Layout};
    use chaoscope_expr::{Boundary, Family, Graph, ParamValue, Scope, Shape, Spline, SplineEnds};
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
    let spline = Spline::new("U", &xs, &ys, SplineEnds::Natural).expect("a valid table");
    // The four sites as a chain, and as a 2 x 2 square (`q[i, j]`) with periodic columns.
    let shapes = [
        (n, Shape::Chain),
        (
            2,
            Shape::Square {
                columns: Boundary::Periodic,
            },
        ),
    ];
    for (boundary, (value_of_n, shape)) in [Boundary::Fixed, Boundary::Periodic, Boundary::Free]
        .into_iter()
        .flat_map(|b| shapes.map(|s| (b, s)))
    {
        let mut g = Graph::new();
        let table = g.add_table(Arc::new(spline.clone()) as Arc<dyn Tabulated>);
        let tables = [("U".to_string(), table)];
        let scope = Scope {
            families: &families,
            params: &params,
            tables: &tables,
            n: value_of_n,
            boundary,
            shape,
            time: None,
        };
        lattice_loops(text, &scope, &spline);
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

/// The potential model's path: lattice sums lowered as loops, their derivatives, the compiled
/// loops against the lattice's reference evaluation (the same bits, any NaN equal to any other),
/// and the same refusals as the unrolled lowering.
fn lattice_loops(text: &str, scope: &chaoscope_expr::Scope, spline: &chaoscope_expr::Spline) {
    use chaoscope_expr::Graph;
    use chaoscope_expr::graph::Tabulated;
    use chaoscope_expr::jit;
    use chaoscope_expr::lattice::{LatticeEvaluator, LatticePotential};
    use std::sync::Arc;

    // Each lowering in its own graph holding the same table, so that the table's id in `scope`
    // names it in both.
    let with_table = || {
        let mut g = Graph::new();
        g.add_table(Arc::new(spline.clone()) as Arc<dyn Tabulated>);
        g
    };
    let unrolled = chaoscope_expr::lower(text, scope, &mut with_table()).map(|_| ());
    let mut g = with_table();
    let lowered = chaoscope_expr::lower_with_loops(text, scope, &mut g);
    assert_eq!(
        unrolled.map_err(|e| e.to_string()),
        lowered.as_ref().map(|_| ()).map_err(|e| e.to_string()),
        "loops refuse what the unrolled lowering refuses, with its message"
    );
    let Ok(lowered) = lowered else {
        return;
    };
    if lowered.sums.is_empty() {
        return;
    }
    let Some(n) = scope.shape.sites(scope.n) else {
        return;
    };
    let q = [0.3, -0.2, 0.1, 0.05];
    let v = [1.0, 0.5, -0.25, 0.125];
    let Ok(Some(lattice)) = LatticePotential::new(&mut g, lowered.root, lowered.sums, n, true)
    else {
        return;
    };
    let Ok(compiled) = jit::compile_lattice(&g, &lattice, &jit::Options::default()) else {
        return;
    };
    let mut e = LatticeEvaluator::new(&g, &lattice);
    let (mut got, mut want) = (vec![0.0; n], vec![0.0; n]);
    let same = |a: &[f64], b: &[f64]| {
        a.iter()
            .zip(b)
            .all(|(x, y)| x.to_bits() == y.to_bits() || (x.is_nan() && y.is_nan()))
    };
    compiled.call(jit::LATTICE_GRADIENT, &[&q], &mut got);
    e.gradient(&q, &mut want);
    assert!(
        same(&got, &want),
        "compiled loops: the gradient {got:?} vs {want:?}"
    );
    compiled.call(jit::LATTICE_HESSIAN_VECTOR, &[&q, &v], &mut got);
    e.hessian_vector(&q, &v, &mut want);
    assert!(same(&got, &want), "compiled loops: Hv {got:?} vs {want:?}");
    let mut p = [0.0];
    compiled.call(jit::LATTICE_POTENTIAL, &[&q], &mut p);
    assert!(
        same(&p, &[e.potential(&q)]),
        "compiled loops: the potential"
    );
    let _ = e.first_non_finite(&q);
}

// ---- Valid files with hostile values (structure-aware) ------------------------------------

use chaoscope_files::testing::values::{self as hostile, Choices};

/// What a `values_*` target did with its input, for the corpus replay's counts.
#[derive(Debug, Default, Clone, Copy, PartialEq, Eq)]
pub struct Outcome {
    /// The file was read and its outputs made (else it was refused with one line naming it).
    pub read: bool,
    /// Outputs checked for NaN and infinity (reports, tables, CSV files, charts, images).
    pub outputs: usize,
}

/// Words a non-finite number prints as (Rust's `Display` of f64 and the usual spellings).
const NON_FINITE_WORDS: [&str; 8] = [
    "NaN", "-NaN", "nan", "inf", "-inf", "+inf", "infinity", "Infinity",
];

/// Panics if `text` (an output: a table, a CSV file, an SVG) holds a non-finite number as a
/// word of its own.
pub fn assert_finite_text(what: &str, text: &str) {
    let word = |c: char| c.is_ascii_alphanumeric() || matches!(c, '.' | '+' | '-' | '_');
    if let Some(bad) = text
        .split(|c: char| !word(c))
        .find(|w| NON_FINITE_WORDS.contains(w))
    {
        let at = text.find(bad).unwrap_or(0);
        let boundary = |i: usize| {
            (0..=i)
                .rev()
                .find(|&b| text.is_char_boundary(b))
                .unwrap_or(0)
        };
        let context = &text[boundary(at.saturating_sub(80))..boundary((at + 80).min(text.len()))];
        panic!("{what} holds '{bad}': ...{context}...");
    }
}

/// Panics if `value` holds a non-finite f64 anywhere once serialized (serde_json would print
/// NaN and infinities as `null`, so the JSON text cannot show them).
pub fn assert_finite_serialized(what: &str, value: &impl serde::Serialize) {
    let mut walk = floats::Walk::default();
    value.serialize(&mut walk).expect("walks any value");
    assert!(walk.found.is_empty(), "{what} holds {:?}", walk.found);
}

/// A refusal: one line naming the file.
fn assert_refusal(what: &str, error: &str, path: &std::path::Path) {
    assert!(
        !error.contains('\n'),
        "{what}: an error of several lines: {error}"
    );
    assert!(
        error.contains(&path.display().to_string()),
        "{what}: the error does not name the file: {error}"
    );
}

/// A valid recording with hostile values (its values chosen by `data`, its structure always
/// the recorder's), through every reader and output of a recording as `chaoscope analyze`
/// (report as JSON, table, CSV files, every chart as SVG) and the run summary make them: the
/// file is analyzed with only finite numbers in every output, or refused with one line naming
/// it. No panic, no hang, no huge allocation.
pub fn values_recording(data: &[u8]) -> Outcome {
    use chaoscope_analyzer::plot::{TimeAxis, charts};
    let bytes = hostile::recording(&mut Choices::new(data));
    let Ok(scratch) = tempfile::Builder::new().prefix("chaoscope-fuzz-").tempdir() else {
        return Outcome::default();
    };
    let input = scratch.path().join("input.mcap");
    if std::fs::write(&input, &bytes).is_err() {
        return Outcome::default();
    }
    let options = chaoscope_analyzer::AnalysisOptions::default();
    let (analysis, info) = match chaoscope_analyzer::recording::analyze_file(&input, &options) {
        Ok(read) => read,
        Err(e) => {
            assert_refusal("analyze", &e.to_string(), &input);
            let summary = chaoscope_analyzer::summary::summarize(&input);
            assert!(summary.is_err(), "the summary reads what analyze refused");
            return Outcome::default();
        }
    };
    let mut outputs = 0;
    let mut report_check = |what: &str, report: &chaoscope_analyzer::Report| {
        assert_finite_serialized(what, report);
        let json = serde_json::to_string(report).expect("a report serializes");
        assert_finite_text(what, &json);
        assert_finite_text(what, &chaoscope_analyzer::table::table(report));
        outputs += 2;
    };
    let report = analysis.report_ended(info.end.as_ref());
    report_check("the report", &report);
    // `analyze --at 0.5`: reads up to that time only.
    let at = chaoscope_analyzer::AnalysisOptions {
        at: vec![0.5],
        ..Default::default()
    };
    let (early, _) = chaoscope_analyzer::recording::analyze_file(&input, &at)
        .unwrap_or_else(|e| panic!("the start of a file that reads whole is refused: {e}"));
    report_check(
        "the report at t = 0.5",
        &early.report_at(0.5).expect("the time asked for"),
    );
    let csv = scratch.path().join("csv");
    let files = chaoscope_analyzer::csv::write_csv(&analysis, &csv, &[]).expect("CSV written");
    for f in &files {
        let text = std::fs::read_to_string(f).expect("CSV text");
        assert_finite_text(&f.display().to_string(), &text);
        outputs += 1;
    }
    for axis in [TimeAxis::Auto, TimeAxis::Linear] {
        for (name, chart) in charts(&analysis, &report, axis) {
            let svg = chaoscope_analyzer::chart::render_svg(&chart)
                .unwrap_or_else(|e| panic!("chart {name}: {e}"));
            assert_finite_text(&format!("chart {name}"), &svg);
            outputs += 1;
        }
    }
    let summary = chaoscope_analyzer::summary::summarize(&input).expect("the summary reads it");
    assert_finite_text("the run summary", &summary.to_string());
    Outcome {
        read: true,
        outputs: outputs + 1,
    }
}

/// A valid recording with hostile values replayed with another `tau`: the replay runs the
/// recorded configuration and compares every recorded value, so it either completes (its
/// output reads back, with finite numbers in its report) or fails with one line naming the
/// recording, leaving no output.
pub fn values_replay(data: &[u8]) -> Outcome {
    use chaoscope_app::{ReplayError, ReplayOptions, replay};
    let bytes = hostile::recording(&mut Choices::new(data));
    let Ok(scratch) = tempfile::Builder::new().prefix("chaoscope-fuzz-").tempdir() else {
        return Outcome::default();
    };
    let input = scratch.path().join("input.mcap");
    let output = scratch.path().join("replay.mcap");
    if std::fs::write(&input, &bytes).is_err() {
        return Outcome::default();
    }
    let options = ReplayOptions {
        taus: vec![0.2],
        transport: chaoscope_producer::estimate::BUS,
        ..Default::default()
    };
    match replay(&input, &output, &options) {
        Ok(outcome) => {
            assert_finite_serialized("the replay outcome", &outcome);
            let (analysis, info) = chaoscope_analyzer::recording::analyze_file(
                &output,
                &chaoscope_analyzer::AnalysisOptions::default(),
            )
            .unwrap_or_else(|e| panic!("the replay does not read back: {e}"));
            let report = analysis.report_ended(info.end.as_ref());
            assert_finite_serialized("the replay's report", &report);
            Outcome {
                read: true,
                outputs: 2,
            }
        }
        Err(e) => {
            // A recording refused names it; a configuration refused is the recording's too.
            let text = e.to_string();
            assert!(!text.contains('\n'), "an error of several lines: {text}");
            if matches!(e, ReplayError::Read(_)) {
                assert_refusal("replay", &text, &input);
            }
            assert!(!output.exists(), "a failed replay left its output");
            Outcome::default()
        }
    }
}

/// Valid map files (one or two shards) with hostile values, through the map readers as
/// `chaoscope merge --png`, `map` resuming and the Python `open_map` use them: the header and
/// every point are checked, and a map that passes is drawn as a PNG without error; one that
/// does not is refused with one line. No panic, no hang, no image or array of absurd size.
pub fn values_map(data: &[u8]) -> Outcome {
    use chaoscope_files::map_file::read_map_file;
    let mut choices = Choices::new(data);
    let shards = 1 + u32::from(choices.byte() % 2);
    let Ok(scratch) = tempfile::Builder::new().prefix("chaoscope-fuzz-").tempdir() else {
        return Outcome::default();
    };
    let mut header = None;
    let mut points = Vec::new();
    for shard in 0..shards {
        let path = scratch.path().join(format!("shard{shard}.mcap"));
        if std::fs::write(&path, hostile::map(&mut choices, shard, shards)).is_err() {
            return Outcome::default();
        }
        let contents = read_map_file(&path).expect("a file written just now opens");
        assert!(
            contents.damaged.is_none(),
            "a valid map file read as damaged"
        );
        if let Err(e) = contents.check() {
            assert!(!e.contains('\n'), "an error of several lines: {e}");
            return Outcome::default();
        }
        let Some(h) = contents.header else {
            return Outcome::default();
        };
        // `merge` refuses shards of different maps (another indicator, order, grid).
        if header
            .as_ref()
            .is_some_and(|first| !chaoscope_files::map_file::same_map(first, &h))
        {
            return Outcome::default();
        }
        points.extend(contents.points);
        header = Some(h);
    }
    let mut header = header.expect("at least one shard");
    // Merged as `chaoscope merge` does: the points of every shard under a whole map's header.
    header.shard_index = 0;
    header.shard_count = 1;
    points.sort_by_key(|p| p.index);
    points.dedup_by_key(|p| p.index);
    let png = scratch.path().join("map.png");
    chaoscope_analyzer::map_png::render_png(&header, &points, &png, &[])
        .unwrap_or_else(|e| panic!("a checked map does not draw: {e}"));
    Outcome {
        read: true,
        outputs: 1,
    }
}

/// A serializer that only looks at floats: the paths of the non-finite ones.
mod floats {
    use serde::ser::{self, Serialize};

    #[derive(Default)]
    pub struct Walk {
        path: Vec<String>,
        pub found: Vec<String>,
    }

    #[derive(Debug)]
    pub struct Never;
    impl std::fmt::Display for Never {
        fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
            f.write_str("never")
        }
    }
    impl std::error::Error for Never {}
    impl ser::Error for Never {
        fn custom<T: std::fmt::Display>(_: T) -> Self {
            Never
        }
    }

    impl Walk {
        fn float(&mut self, v: f64) -> Result<(), Never> {
            if !v.is_finite() {
                self.found.push(format!("{} = {v}", self.path.join(".")));
            }
            Ok(())
        }
        fn nested<T: Serialize + ?Sized>(&mut self, key: &str, v: &T) -> Result<(), Never> {
            self.path.push(key.to_string());
            v.serialize(&mut *self)?;
            self.path.pop();
            Ok(())
        }
    }

    macro_rules! ignore {
        ($($f:ident: $t:ty),*) => {
            $(fn $f(self, _: $t) -> Result<(), Never> { Ok(()) })*
        };
    }

    impl ser::Serializer for &mut Walk {
        type Ok = ();
        type Error = Never;
        type SerializeSeq = Self;
        type SerializeTuple = Self;
        type SerializeTupleStruct = Self;
        type SerializeTupleVariant = Self;
        type SerializeMap = Self;
        type SerializeStruct = Self;
        type SerializeStructVariant = Self;
        ignore!(serialize_bool: bool, serialize_i8: i8, serialize_i16: i16, serialize_i32: i32,
            serialize_i64: i64, serialize_u8: u8, serialize_u16: u16, serialize_u32: u32,
            serialize_u64: u64, serialize_char: char, serialize_str: &str,
            serialize_bytes: &[u8], serialize_unit_struct: &'static str);
        fn serialize_f32(self, v: f32) -> Result<(), Never> {
            self.float(f64::from(v))
        }
        fn serialize_f64(self, v: f64) -> Result<(), Never> {
            self.float(v)
        }
        fn serialize_none(self) -> Result<(), Never> {
            Ok(())
        }
        fn serialize_some<T: Serialize + ?Sized>(self, v: &T) -> Result<(), Never> {
            v.serialize(self)
        }
        fn serialize_unit(self) -> Result<(), Never> {
            Ok(())
        }
        fn serialize_unit_variant(
            self,
            _: &'static str,
            _: u32,
            _: &'static str,
        ) -> Result<(), Never> {
            Ok(())
        }
        fn serialize_newtype_struct<T: Serialize + ?Sized>(
            self,
            _: &'static str,
            v: &T,
        ) -> Result<(), Never> {
            v.serialize(self)
        }
        fn serialize_newtype_variant<T: Serialize + ?Sized>(
            self,
            _: &'static str,
            _: u32,
            variant: &'static str,
            v: &T,
        ) -> Result<(), Never> {
            self.nested(variant, v)
        }
        fn serialize_seq(self, _: Option<usize>) -> Result<Self, Never> {
            self.path.push("0".into());
            Ok(self)
        }
        fn serialize_tuple(self, _: usize) -> Result<Self, Never> {
            self.serialize_seq(None)
        }
        fn serialize_tuple_struct(self, _: &'static str, _: usize) -> Result<Self, Never> {
            self.serialize_seq(None)
        }
        fn serialize_tuple_variant(
            self,
            _: &'static str,
            _: u32,
            _: &'static str,
            _: usize,
        ) -> Result<Self, Never> {
            self.serialize_seq(None)
        }
        fn serialize_map(self, _: Option<usize>) -> Result<Self, Never> {
            self.path.push("key".into());
            Ok(self)
        }
        fn serialize_struct(self, _: &'static str, _: usize) -> Result<Self, Never> {
            self.path.push(String::new());
            Ok(self)
        }
        fn serialize_struct_variant(
            self,
            _: &'static str,
            _: u32,
            _: &'static str,
            _: usize,
        ) -> Result<Self, Never> {
            self.serialize_struct("", 0)
        }
    }

    /// Elements of sequences and tuples: the last path part counts them.
    fn element<T: Serialize + ?Sized>(w: &mut Walk, v: &T) -> Result<(), Never> {
        v.serialize(&mut *w)?;
        if let Some(i) = w.path.last_mut().and_then(|p| p.parse::<usize>().ok()) {
            *w.path.last_mut().expect("a path part") = (i + 1).to_string();
        }
        Ok(())
    }

    macro_rules! sequence {
        ($($trait:ident::$method:ident),*) => {$(
            impl ser::$trait for &mut Walk {
                type Ok = ();
                type Error = Never;
                fn $method<T: Serialize + ?Sized>(&mut self, v: &T) -> Result<(), Never> {
                    element(self, v)
                }
                fn end(self) -> Result<(), Never> {
                    self.path.pop();
                    Ok(())
                }
            }
        )*};
    }
    sequence!(
        SerializeSeq::serialize_element,
        SerializeTuple::serialize_element,
        SerializeTupleStruct::serialize_field,
        SerializeTupleVariant::serialize_field
    );

    impl ser::SerializeMap for &mut Walk {
        type Ok = ();
        type Error = Never;
        fn serialize_key<T: Serialize + ?Sized>(&mut self, _: &T) -> Result<(), Never> {
            Ok(())
        }
        fn serialize_value<T: Serialize + ?Sized>(&mut self, v: &T) -> Result<(), Never> {
            v.serialize(&mut **self)
        }
        fn end(self) -> Result<(), Never> {
            self.path.pop();
            Ok(())
        }
    }

    macro_rules! structure {
        ($($trait:ident),*) => {$(
            impl ser::$trait for &mut Walk {
                type Ok = ();
                type Error = Never;
                fn serialize_field<T: Serialize + ?Sized>(&mut self, key: &'static str, v: &T) -> Result<(), Never> {
                    if let Some(last) = self.path.last_mut() {
                        *last = key.to_string();
                    }
                    v.serialize(&mut **self)
                }
                fn end(self) -> Result<(), Never> {
                    self.path.pop();
                    Ok(())
                }
            }
        )*};
    }
    structure!(SerializeStruct, SerializeStructVariant);
}

// ---- Resume, CLVs and map headers with hostile values --------------------------------------

/// The new end a `values_resume` input asks for (its first byte): the recorded end (resume a
/// cut run), a later one (extend it), an earlier one, or a hostile one; all within a few
/// hundred steps of the recorded run, so no input is a long computation.
const RESUME_ENDS: [Option<f64>; 8] = [
    None,
    Some(1.0),
    Some(2.0),
    Some(0.5),
    Some(0.0),
    Some(f64::NAN),
    Some(-1.0),
    Some(1e-300),
];

/// A valid recording with hostile values resumed (and extended) into a new file, as
/// `chaoscope resume RECORDING --t-final T --out OUT` does: the resume either completes (its
/// output reads back whole, its report finite) or is refused in one line (naming the recording
/// when it is the file that is refused). No panic, no hang, no NaN in the new file.
pub fn values_resume(data: &[u8]) -> Outcome {
    use chaoscope_app::resume::{ResumeFailure, ResumeOptions, resume};
    let mut choices = Choices::new(data);
    let t_final = RESUME_ENDS[usize::from(choices.byte()) % RESUME_ENDS.len()];
    let Ok(scratch) = tempfile::Builder::new().prefix("chaoscope-fuzz-").tempdir() else {
        return Outcome::default();
    };
    let input = scratch.path().join("input.mcap");
    let output = scratch.path().join("resumed.mcap");
    if !computed_recording(&mut choices, &input) {
        return Outcome::default();
    }
    let options = ResumeOptions {
        t_final,
        out: Some(output.clone()),
        // The ends above are a few hundred steps at most: nothing the estimate would refuse,
        // and its calibration (tens of milliseconds) would dominate every input.
        estimated: true,
        ..Default::default()
    };
    match resume(&input, &options) {
        Ok(outcome) => {
            assert_finite_serialized("the resume outcome", &outcome);
            let (analysis, info) = chaoscope_analyzer::recording::analyze_file(
                &output,
                &chaoscope_analyzer::AnalysisOptions::default(),
            )
            .unwrap_or_else(|e| panic!("the resumed recording does not read back: {e}"));
            assert!(
                info.damage.is_none(),
                "the resumed recording is damaged: {:?}",
                info.damage
            );
            let report = analysis.report_ended(info.end.as_ref());
            assert_finite_serialized("the resumed recording's report", &report);
            Outcome {
                read: true,
                outputs: 2,
            }
        }
        Err(e) => {
            let text = e.to_string();
            assert!(!text.contains('\n'), "an error of several lines: {text}");
            if matches!(e, ResumeFailure::Read(_)) {
                assert_refusal("resume", &text, &input);
            }
            assert!(!output.exists(), "a refused resume took its output's name");
            Outcome::default()
        }
    }
}

/// A valid recording with hostile values through `analyze --clv` (the first byte chooses the
/// options: the set, the transients, the neutral count, a memory small enough that the stored
/// factors spill to disk): the report and its text are finite, the angle CSV has a named
/// column for each of its values, finite, in time order, and the CLVs' `.npy` holds a finite
/// row of vectors per angle row; or the file is refused in one line.
pub fn values_clv(data: &[u8]) -> Outcome {
    use chaoscope_analyzer::clv::{ClvOptions, ClvRunError, clv_of_file, summary};
    let mut choices = Choices::new(data);
    let pick = choices.byte();
    let transients = [
        None,
        Some(0.0),
        Some(0.1),
        Some(0.45),
        Some(2.0),
        Some(f64::NAN),
    ];
    let options = ClvOptions {
        scheme: None,
        set: usize::from(pick & 1),
        forward_transient: transients[usize::from(pick >> 1) % transients.len()],
        backward_transient: transients[usize::from(pick >> 3) % transients.len()],
        neutral: [None, Some(0), Some(1), Some(3)][usize::from(pick >> 5) % 4],
        memory_bytes: if pick & 0x80 != 0 { 512 } else { 1 << 20 },
        vectors: true,
    };
    let Ok(scratch) = tempfile::Builder::new().prefix("chaoscope-fuzz-").tempdir() else {
        return Outcome::default();
    };
    let input = scratch.path().join("input.mcap");
    if !computed_recording(&mut choices, &input) {
        return Outcome::default();
    }
    match clv_of_file(&input, &options) {
        Ok(output) => {
            let (report, series) = (output.report, output.angles);
            let vectors = output.vectors.expect("asked for");
            let rows = vectors.len() as u64;
            let files = vectors
                .write_npy(&scratch.path().join("npy"), std::slice::from_ref(&input))
                .expect("the CLVs are written");
            let bytes = std::fs::read(&files[0]).expect("clv-vectors.npy");
            let header = 10 + usize::from(u16::from_le_bytes([bytes[8], bytes[9]]));
            assert_eq!(rows, report.renormalizations, "a CLV row per angle row");
            assert_eq!(
                (bytes.len() - header) as u64,
                8 * rows * (report.k * report.dim) as u64,
                "clv-vectors.npy: its size is not its shape's"
            );
            for value in bytes[header..].chunks_exact(8) {
                let v = f64::from_le_bytes(value.try_into().expect("8 bytes"));
                assert!(v.is_finite(), "clv-vectors.npy: {v}");
            }
            assert_finite_serialized("the CLV report", &report);
            let text = summary(&report);
            assert_finite_text("the CLV summary", &text);
            let csv = series
                .write_csv(&scratch.path().join("csv"), std::slice::from_ref(&input))
                .expect("the angle CSV is written");
            let text = std::fs::read_to_string(&csv).expect("CSV text");
            assert_finite_text("clv-angles.csv", &text);
            let mut lines = text.lines();
            let header: Vec<&str> = lines.next().expect("a header").split(',').collect();
            assert!(
                header[0] == "t" && header.iter().all(|c| !c.is_empty()),
                "clv-angles.csv: a column without a name: {header:?}"
            );
            let mut last_t = f64::NEG_INFINITY;
            for line in lines {
                let cells: Vec<&str> = line.split(',').collect();
                assert_eq!(cells.len(), header.len(), "clv-angles.csv: row {line:?}");
                let t: f64 = cells[0].parse().expect("a time");
                assert!(t >= last_t, "clv-angles.csv: times out of order at {t}");
                last_t = t;
            }
            Outcome {
                read: true,
                outputs: 5,
            }
        }
        Err(e) => {
            let text = e.to_string();
            assert!(!text.contains('\n'), "an error of several lines: {text}");
            if matches!(e, ClvRunError::Read(_)) {
                assert_refusal("analyze --clv", &text, &input);
            }
            Outcome::default()
        }
    }
}

/// Writes at `path` a recording of the run [`hostile::RUN_CONFIG`] describes as the producer
/// computes it and the recorder writes it (the producer's own run header, so `resume` and the
/// CLVs take it as that run's), with values made hostile by `choices`: how many samples it
/// keeps, then each kept sample's time, step, state, divergence sum, separations and
/// stretching factors, then how the run ended. False if it could not be written.
fn computed_recording(choices: &mut Choices, path: &std::path::Path) -> bool {
    use chaoscope_analyzer::write::SampleWriter;
    use chaoscope_dynamics::engine::Engine;
    use chaoscope_schemas::proto::end_of_run::Status;
    let config = RunConfig::from_toml(hostile::RUN_CONFIG).expect("the hostile runs' config");
    let spec = RunSpec::from_config(&config).expect("the hostile runs' config is valid");
    let header = chaoscope_dynamics::header::run_header("hostile", &config, &spec);
    let mut engine = Engine::new(spec);
    // 0 to 11 of the run's 11 samples (t = 0, 0.1, ..., 1).
    let keep = choices.below(13);
    let Ok(mut writer) = SampleWriter::create(path, &header) else {
        return false;
    };
    let mut kept = 0;
    while kept < keep
        && let Ok(Some(mut sample)) = engine.next_sample()
    {
        kept += 1;
        sample.t = choices.f64(sample.t);
        sample.step = choices.u64(sample.step);
        for v in &mut sample.state {
            *v = choices.f64(*v);
        }
        sample.divergence_sum = choices.f64(sample.divergence_sum);
        for set in &mut sample.schemes {
            for v in set.separations.iter_mut().chain(set.stretch.iter_mut()) {
                *v = choices.f64(*v);
            }
        }
        if writer.write(&sample).is_err() {
            return false;
        }
    }
    let status =
        [Status::Interrupted, Status::Completed, Status::Failed][choices.below(3) as usize];
    writer.finish_with("fuzz", status, "").is_ok()
}

/// A map file whose header's every value the input chooses (axes, indicator, sizes, shard,
/// times, its configuration), through what reads a map header: the header check, the
/// configuration it carries rebuilt into a map whose own header must pass that check and is
/// compared with the file's (as `map` does before resuming a file), and the PNG of whichever
/// points the header admits. A header that passes the check is drawn without
/// error; one that does not is refused in one line.
pub fn values_map_header(data: &[u8]) -> Outcome {
    use chaoscope_files::map_file::{check_header, read_map_file, same_map};
    let mut choices = Choices::new(data);
    let shards = 1 + u32::from(choices.byte() % 2);
    let bytes = hostile::map(&mut choices, 0, shards);
    let Ok(scratch) = tempfile::Builder::new().prefix("chaoscope-fuzz-").tempdir() else {
        return Outcome::default();
    };
    let path = scratch.path().join("map.mcap");
    if std::fs::write(&path, &bytes).is_err() {
        return Outcome::default();
    }
    let contents = read_map_file(&path).expect("a file written just now opens");
    let Some(header) = contents.header.clone() else {
        return Outcome::default();
    };
    if let Err(e) = check_header(&header) {
        assert!(!e.contains('\n'), "an error of several lines: {e}");
        return Outcome::default();
    }
    assert!(same_map(&header, &header), "a header is not its own map");
    // `map` resuming this file: the configuration it carries, rebuilt, gives the header a map
    // of it writes, or is refused with a key.
    if let Ok(cfg) = RunConfig::from_toml(&header.config_toml)
        && claimed_dim(&cfg.model) <= 64
    {
        match MapSpec::from_config(&cfg) {
            Ok(spec) => {
                let shard = chaoscope_dynamics::map::Shard {
                    index: header.shard_index,
                    count: header.shard_count,
                };
                let own = spec.header(shard);
                check_header(&own)
                    .unwrap_or_else(|e| panic!("a map's own header fails the check: {e}"));
                let _ = same_map(&own, &header);
            }
            Err(e) => assert!(
                !e.key.is_empty() && !e.to_string().contains('\n'),
                "an error without a key, or of several lines: {e:?}"
            ),
        }
    }
    // Its points, those the header admits, drawn under it as `merge --png` draws them.
    let points: Vec<_> = contents
        .points
        .into_iter()
        .filter(|p| chaoscope_files::map_file::check_point(&header, p).is_ok())
        .collect();
    let png = scratch.path().join("map.png");
    chaoscope_analyzer::map_png::render_png(&header, &points, &png, &[])
        .unwrap_or_else(|e| panic!("a checked map header does not draw: {e}"));
    Outcome {
        read: true,
        outputs: 1,
    }
}

/// The starting corpus of the `values_resume`, `values_clv` and `values_map_header` targets:
/// the valid file (all bytes "keep"), each option byte's values, and single hostile values at
/// the positions that feed the paths these targets are for (the leading option bytes, the
/// header's first fields, the first samples). `fuzz/src/bin/seeds.rs` writes them;
/// `tests/fuzz_corpus.rs` checks that `fuzz/corpus/` holds them.
pub fn values_seeds(target: &str) -> Vec<(String, Vec<u8>)> {
    let keep = Choices::KEEP;
    let hostile_at = |lead: &[u8], at: usize, value: u8| {
        let mut bytes = lead.to_vec();
        bytes.resize(lead.len() + at, 0);
        bytes.push(value);
        bytes
    };
    let mut seeds = Vec::new();
    let leads: Vec<Vec<u8>> = match target {
        // Every end of RESUME_ENDS.
        "values_resume" => (0..RESUME_ENDS.len() as u8).map(|b| vec![b, 12]).collect(),
        // The options' bits: set, transients, neutral count, spilling.
        "values_clv" => [0u8, 1, 0x02, 0x0c, 0x12, 0x20, 0x40, 0x60, 0x80, 0xff]
            .iter()
            .map(|&b| vec![b, 12])
            .collect(),
        // One shard or two.
        "values_map_header" => vec![vec![0], vec![1]],
        other => panic!("no seeds for {other}"),
    };
    for lead in &leads {
        seeds.push((
            format!(
                "valid-{}",
                lead.iter().map(|b| format!("{b:02x}")).collect::<String>()
            ),
            lead.clone(),
        ));
    }
    // Hostile values at the first 40 choices after the lead (the first samples' values, or the
    // map header's fields, in the order the writers read them), each a different kind.
    let lead = &leads[leads.len() / 2];
    for at in 0..40 {
        let value = keep + ((at * 7) % usize::from(0xff - keep)) as u8;
        seeds.push((format!("hostile-{at:02}"), hostile_at(lead, at, value)));
    }
    seeds
}
