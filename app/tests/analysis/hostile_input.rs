//! Every input file is hostile: the recording reader behind `analyze`, `replay` and the run
//! summary never panics (nor aborts on a huge allocation) on a damaged file. It reads the file
//! whole, or fails with an error naming the file and where and why it is damaged; an analysis is
//! never of part of the data or of damaged data.
//!
//! The damage is [`testing::hostile`]'s: cuts, single bit flips, random records after the magic,
//! a short attachment, huge length fields, zero-filled tails.

use std::io::Cursor;
use std::panic::{AssertUnwindSafe, catch_unwind};
use std::path::Path;

use chaoscope_analyzer::analysis::AnalysisOptions;
use chaoscope_analyzer::csv::write_csv;
use chaoscope_analyzer::recording::{ReadError, analyze_file};
use chaoscope_analyzer::write::SampleWriter;
use chaoscope_app::{ReplayOptions, replay};
use chaoscope_dynamics::engine::Engine;
use chaoscope_dynamics::header::run_header;
use chaoscope_dynamics::spec::RunSpec;
use chaoscope_files::file::{Compression, FileOptions};
use chaoscope_files::recording::{FinalizedBy, Recording};
use chaoscope_files::scan::FileError;
use chaoscope_files::testing::{self, Noise};
use chaoscope_schemas::config::RunConfig;
use chaoscope_schemas::proto::DataMessage;
use chaoscope_schemas::proto::{EndOfRun, ReferenceState, RunHeader, Scheme, SeparationSet};

/// The analysis report as JSON, or the error.
fn analyze(path: &Path) -> Result<String, ReadError> {
    analyze_file(path, &AnalysisOptions::default())
        .map(|(analysis, _)| serde_json::to_string(&analysis.report()).unwrap())
}

/// The non-finite floats in `value` once serialized, as paths (`schemes.0.mle`): serde_json
/// writes NaN and infinities as `null`, so comparing JSON text cannot find them.
fn non_finite_floats(value: &impl serde::Serialize) -> Vec<String> {
    let mut walk = FloatWalk::default();
    value.serialize(&mut walk).expect("walks any value");
    walk.found
}

#[derive(Default)]
struct FloatWalk {
    path: Vec<String>,
    found: Vec<String>,
    index: Vec<usize>,
}

#[derive(Debug)]
struct WalkError(String);

impl std::fmt::Display for WalkError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0)
    }
}

impl std::error::Error for WalkError {}

impl serde::ser::Error for WalkError {
    fn custom<T: std::fmt::Display>(msg: T) -> Self {
        WalkError(msg.to_string())
    }
}

impl FloatWalk {
    fn float(&mut self, v: f64) -> Result<(), WalkError> {
        if !v.is_finite() {
            self.found.push(format!("{} = {v}", self.path.join(".")));
        }
        Ok(())
    }

    fn field<T: serde::Serialize + ?Sized>(
        &mut self,
        name: String,
        value: &T,
    ) -> Result<(), WalkError> {
        self.path.push(name);
        value.serialize(&mut *self)?;
        self.path.pop();
        Ok(())
    }

    fn element<T: serde::Serialize + ?Sized>(&mut self, value: &T) -> Result<(), WalkError> {
        let i = self.index.last_mut().expect("inside a sequence");
        let name = i.to_string();
        *i += 1;
        self.field(name, value)
    }
}

macro_rules! ignore {
    ($($f:ident: $t:ty),*) => {
        $(fn $f(self, _: $t) -> Result<(), WalkError> { Ok(()) })*
    };
}

/// Enum variants with fields: their fields are walked as a sequence's or a struct's.
macro_rules! variants {
    ($($method:ident),*) => {
        $(fn $method(
            self,
            _: &'static str,
            _: u32,
            _: &'static str,
            _: usize,
        ) -> Result<Self, WalkError> {
            self.serialize_seq(None)
        })*
    };
}

impl serde::Serializer for &mut FloatWalk {
    type Ok = ();
    type Error = WalkError;
    type SerializeSeq = Self;
    type SerializeTuple = Self;
    type SerializeTupleStruct = Self;
    type SerializeTupleVariant = Self;
    type SerializeMap = Self;
    type SerializeStruct = Self;
    type SerializeStructVariant = Self;

    ignore!(serialize_bool: bool, serialize_i8: i8, serialize_i16: i16, serialize_i32: i32,
        serialize_i64: i64, serialize_u8: u8, serialize_u16: u16, serialize_u32: u32,
        serialize_u64: u64, serialize_char: char, serialize_str: &str, serialize_bytes: &[u8],
        serialize_unit_struct: &'static str);

    fn serialize_f32(self, v: f32) -> Result<(), WalkError> {
        self.float(v.into())
    }
    fn serialize_f64(self, v: f64) -> Result<(), WalkError> {
        self.float(v)
    }
    fn serialize_none(self) -> Result<(), WalkError> {
        Ok(())
    }
    fn serialize_some<T: serde::Serialize + ?Sized>(self, v: &T) -> Result<(), WalkError> {
        v.serialize(self)
    }
    fn serialize_unit(self) -> Result<(), WalkError> {
        Ok(())
    }
    fn serialize_unit_variant(
        self,
        _: &'static str,
        _: u32,
        _: &'static str,
    ) -> Result<(), WalkError> {
        Ok(())
    }
    fn serialize_newtype_struct<T: serde::Serialize + ?Sized>(
        self,
        _: &'static str,
        v: &T,
    ) -> Result<(), WalkError> {
        v.serialize(self)
    }
    fn serialize_newtype_variant<T: serde::Serialize + ?Sized>(
        self,
        _: &'static str,
        _: u32,
        variant: &'static str,
        v: &T,
    ) -> Result<(), WalkError> {
        self.field(variant.into(), v)
    }
    fn serialize_seq(self, _: Option<usize>) -> Result<Self, WalkError> {
        self.index.push(0);
        Ok(self)
    }
    fn serialize_tuple(self, _: usize) -> Result<Self, WalkError> {
        self.serialize_seq(None)
    }
    fn serialize_tuple_struct(self, _: &'static str, _: usize) -> Result<Self, WalkError> {
        self.serialize_seq(None)
    }
    fn serialize_map(self, _: Option<usize>) -> Result<Self, WalkError> {
        self.index.push(0);
        Ok(self)
    }
    fn serialize_struct(self, _: &'static str, _: usize) -> Result<Self, WalkError> {
        self.index.push(0);
        Ok(self)
    }
    variants!(serialize_tuple_variant, serialize_struct_variant);
}

/// The serde container traits, each with its own methods and the same `end`.
macro_rules! containers {
    (@impl $trait:ident { $($item:tt)* }) => {
        impl serde::ser::$trait for &mut FloatWalk {
            type Ok = ();
            type Error = WalkError;
            $($item)*
            fn end(self) -> Result<(), WalkError> {
                self.index.pop();
                Ok(())
            }
        }
    };
    () => {};
    ([] $body:tt $($more:tt)*) => {
        containers!($($more)*);
    };
    ([$first:ident $(, $rest:ident)*] $body:tt $($more:tt)*) => {
        containers!(@impl $first $body);
        containers!([$($rest),*] $body $($more)*);
    };
}

containers! {
    [SerializeSeq, SerializeTuple] {
        fn serialize_element<T: serde::Serialize + ?Sized>(&mut self, v: &T) -> Result<(), WalkError> {
            self.element(v)
        }
    }
    [SerializeTupleStruct, SerializeTupleVariant] {
        fn serialize_field<T: serde::Serialize + ?Sized>(&mut self, v: &T) -> Result<(), WalkError> {
            self.element(v)
        }
    }
    [SerializeStruct, SerializeStructVariant] {
        fn serialize_field<T: serde::Serialize + ?Sized>(&mut self, key: &'static str, v: &T) -> Result<(), WalkError> {
            self.field(key.into(), v)
        }
    }
    [SerializeMap] {
        fn serialize_key<T: serde::Serialize + ?Sized>(&mut self, _: &T) -> Result<(), WalkError> {
            Ok(())
        }
        fn serialize_value<T: serde::Serialize + ?Sized>(&mut self, v: &T) -> Result<(), WalkError> {
            self.element(v)
        }
    }
}

/// The panic's message.
fn panic_text(payload: &(dyn std::any::Any + Send)) -> String {
    payload
        .downcast_ref::<&str>()
        .map(|s| s.to_string())
        .or_else(|| payload.downcast_ref::<String>().cloned())
        .unwrap_or_default()
}

#[test]
fn damaged_recordings_are_analyzed_whole_or_refused_with_a_clear_error() {
    let dir = testing::scratch_dir();
    let path = dir.path().join("damaged.mcap");
    let name = path.to_str().unwrap();
    let mut panics = Vec::new();
    for compression in [Compression::Zstd, Compression::None] {
        let bytes = testing::small_run(compression);
        std::fs::write(&path, &bytes).unwrap();
        let whole = analyze(&path).expect("the undamaged file");
        let (analysis, _) = analyze_file(&path, &AnalysisOptions::default()).unwrap();
        assert_eq!(non_finite_floats(&analysis.report()), Vec::<String>::new());
        let (mut refused, mut read) = (0, 0);
        for damaged in testing::hostile(&bytes, 5) {
            std::fs::write(&path, &damaged.bytes).unwrap();
            let what = format!("{compression:?}, {}", damaged.what);
            match catch_unwind(AssertUnwindSafe(|| analyze(&path))) {
                Err(payload) => panics.push(format!("{what}: {}", panic_text(&*payload))),
                Ok(Ok(report)) => {
                    read += 1;
                    assert!(report == whole, "{what}: analyzed, differently");
                }
                Ok(Err(e)) => {
                    refused += 1;
                    let message = e.to_string();
                    assert!(message.contains(name), "{what}: {message}");
                    match e {
                        ReadError::Damaged { why, .. } => assert!(
                            why.starts_with("record ") && why.contains(" at byte "),
                            "{what}: {why}"
                        ),
                        ReadError::File(FileError::NotMcap { .. }) => {
                            assert!(!damaged.bytes.starts_with(mcap::MAGIC), "{what}")
                        }
                        // The records before the damage hold no run header (a cut or random
                        // records), or it is not one.
                        ReadError::NoHeader { .. }
                        | ReadError::Header { .. }
                        | ReadError::Decode { .. }
                        | ReadError::Value { .. } => {}
                        ReadError::File(FileError::Io { .. }) => panic!("{what}: {message}"),
                        // No analysis option is given here.
                        ReadError::Option { .. } => panic!("{what}: {message}"),
                    }
                }
            }
        }
        eprintln!("{compression:?}: {refused} damaged files refused, {read} read whole");
        assert!(refused > 3000 && read > 0, "{refused} refused, {read} read");
    }
    assert!(
        panics.is_empty(),
        "{} panics:\n{}",
        panics.len(),
        panics.join("\n")
    );
}

/// A real run (the paper's chaotic Henon-Heiles orbit to t = 10), written as `replay` writes
/// its output.
fn real_recording(path: &Path) {
    let paper = include_str!("../../../examples/paper/configs/hh_chaotic.toml");
    let mut config = RunConfig::from_toml(paper).unwrap();
    config.integrator.t_final = 10.0;
    let spec = RunSpec::from_config(&config).unwrap();
    let mut writer = SampleWriter::create(path, &run_header("hostile", &config, &spec)).unwrap();
    let mut engine = Engine::new(spec);
    while let Some(sample) = engine.next_sample().unwrap() {
        writer.write(&sample).unwrap();
    }
    writer.finish("test").unwrap();
}

#[test]
fn replay_of_a_damaged_recording_fails_clearly_and_leaves_no_output() {
    let dir = testing::scratch_dir();
    let original = dir.path().join("run.mcap");
    real_recording(&original);
    let bytes = std::fs::read(&original).unwrap();
    let path = dir.path().join("damaged.mcap");
    let out = dir.path().join("replay.mcap");
    let options = ReplayOptions {
        taus: vec![0.2],
        ..Default::default()
    };
    let whole = replay(&original, &out, &options).unwrap();
    assert!(whole.identical());
    let timeless = |o: chaoscope_app::ReplayOutcome| chaoscope_app::ReplayOutcome {
        seconds: 0.0,
        estimated_seconds: 0.0,
        ..o
    };
    let damage = testing::cuts(&bytes, 0, bytes.len() / 40)
        .chain(testing::flips(&bytes, 40, 17))
        .chain(testing::huge_lengths(&bytes).step_by(7))
        .chain(testing::zero_tails(&bytes));
    let mut refused = 0;
    for damaged in damage {
        std::fs::write(&path, &damaged.bytes).unwrap();
        let _ = std::fs::remove_file(&out);
        let what = &damaged.what;
        let result = catch_unwind(AssertUnwindSafe(|| replay(&path, &out, &options)))
            .unwrap_or_else(|payload| panic!("{what}: panicked: {}", panic_text(&*payload)));
        match result {
            // The times (taken and estimated) are the machine's, not the replay's result.
            Ok(outcome) => assert_eq!(timeless(outcome), timeless(whole.clone()), "{what}"),
            Err(e) => {
                refused += 1;
                let message = e.to_string();
                assert!(
                    message.contains(path.to_str().unwrap()),
                    "{what}: {message}"
                );
                assert!(!out.exists(), "{what}: a half-written replay is left");
            }
        }
    }
    assert!(refused > 40, "{refused} refused");
}

/// A recording whose messages are valid protobuf with hostile values: header sizes, indices,
/// vector lengths, steps and times no producer writes.
/// Times and energies that are not finite (refused by the reader) only if `non_finite`.
fn hostile_content(header: &RunHeader, noise: &mut Noise, non_finite: bool) -> Vec<u8> {
    let mut recording = Recording::start(Cursor::new(Vec::new()), header, &FileOptions::default())
        .expect("recording");
    let pick = |noise: &mut Noise, values: &[u64]| {
        values[(noise.next_u64() % values.len() as u64) as usize]
    };
    let steps = [0, 1, 2, 3, 10, 7, u64::MAX, u64::MAX - 1, 1 << 53];
    let lens = [0, 1, 2, 3, 4, 8, 9, 100];
    let times = [
        0.0,
        0.01,
        -1.0,
        f64::NAN,
        f64::INFINITY,
        f64::NEG_INFINITY,
        1e308,
    ];
    let times: Vec<f64> = times
        .into_iter()
        .filter(|t| non_finite || t.is_finite())
        .collect();
    for frame in 0..40 {
        let step = pick(noise, &steps);
        let t = times[(noise.next_u64() % times.len() as u64) as usize];
        let message = match noise.next_u64() % 5 {
            0 | 1 => DataMessage::Reference(ReferenceState {
                frame,
                seq: pick(noise, &steps),
                step,
                t,
                energy: times[(noise.next_u64() % times.len() as u64) as usize],
                state: vec![noise.next_f64(1.0); pick(noise, &lens) as usize],
                mean_divergence: 0.0,
                divergence_sum: 0.0,
            }),
            2 | 3 => DataMessage::Separations(SeparationSet {
                frame,
                seq: pick(noise, &steps),
                step,
                t,
                scheme: 0,
                set: pick(noise, &[0, 1, 2, 1000, u32::MAX as u64]) as u32,
                k: pick(noise, &lens) as u32,
                dim: pick(noise, &lens) as u32,
                separations: vec![noise.next_f64(1e-8); pick(noise, &lens) as usize],
                stretch: vec![pick(noise, &[0, 1, 2]) as f64; pick(noise, &lens) as usize],
                earlier_stretch: Vec::new(),
            }),
            _ => DataMessage::End(EndOfRun {
                frame,
                samples: pick(noise, &steps),
                last_step: step,
                t,
                ..Default::default()
            }),
        };
        recording.on_message(&message).expect("message");
    }
    recording
        .finish(FinalizedBy::EndOfRun)
        .expect("finish")
        .0
        .into_inner()
}

#[test]
fn valid_files_with_hostile_values_never_panic() {
    let dir = testing::scratch_dir();
    let path = dir.path().join("hostile.mcap");
    let mut noise = Noise::new(23);
    let scheme = |tau_steps| Scheme {
        index: 0,
        name: "mpm".into(),
        method: "mpm".into(),
        d0: 1e-8,
        tau: 0.01,
        tau_steps,
        orthonormalize: "rescale".into(),
    };
    let (mut refused_headers, mut refused_values, mut analyzed) = (0, 0, 0);
    for case in 0..300 {
        let pick = |noise: &mut Noise, values: &[u32]| {
            values[(noise.next_u64() % values.len() as u64) as usize]
        };
        let header = RunHeader {
            run_name: "hostile".into(),
            dim: pick(&mut noise, &[0, 1, 2, 4, 1 << 20, u32::MAX]),
            k: pick(&mut noise, &[0, 1, 2, 3, 5, u32::MAX]),
            sets: pick(&mut noise, &[0, 1, 3, 1 << 20, u32::MAX]),
            h: [0.01, 0.0, -1.0, f64::NAN, 1e-300][case % 5],
            energy0: [0.125, 0.0, f64::NAN][case % 3],
            schemes: vec![scheme(u64::from(pick(&mut noise, &[0, 1, 3, u32::MAX])))],
            ..Default::default()
        };
        std::fs::write(&path, hostile_content(&header, &mut noise, case % 2 == 1)).unwrap();
        let result = catch_unwind(AssertUnwindSafe(|| {
            analyze_file(&path, &AnalysisOptions::default()).map(|(analysis, _)| {
                let csv = dir.path().join(format!("csv{case}"));
                let files = write_csv(&analysis, &csv, &[]).expect("CSV written");
                (analysis.report(), files)
            })
        }))
        .unwrap_or_else(|payload| panic!("case {case} {header:?}: {}", panic_text(&*payload)));
        match result {
            Ok((report, files)) => {
                let bad = non_finite_floats(&report);
                assert!(bad.is_empty(), "case {case} {header:?}: report has {bad:?}");
                for file in files {
                    let text = std::fs::read_to_string(&file).unwrap().to_lowercase();
                    assert!(
                        !text.contains("nan") && !text.contains("inf"),
                        "case {case} {header:?}: {}:\n{text}",
                        file.display()
                    );
                }
                analyzed += 1;
            }
            Err(e) => match e {
                ReadError::Header { .. } => refused_headers += 1,
                ReadError::Value { .. } => refused_values += 1,
                _ => panic!("case {case}: {e}"),
            },
        }
    }
    eprintln!(
        "300 hostile files: {refused_headers} headers refused, {refused_values} values refused, \
         {analyzed} analyzed"
    );
    assert!(
        (50..300).contains(&refused_headers),
        "{refused_headers} headers refused"
    );
    // The messages are drawn at random, so no file is a coherent run (times of their steps,
    // samples in order, every set once): since the reader checks that, all of them are refused
    // at a value. Files that are analyzed, with finite outputs, are the crafted ones of
    // tests/hostile_files.rs and the corpus of the `values_*` fuzz targets.
    assert!(
        refused_values > 0,
        "{refused_values} refused, {analyzed} analyzed"
    );
}
