//! Resume and extend: a run continued from its recording, into the file an uninterrupted run
//! would have written.
//!
//! A recording holds, at every sample at which every scheme renormalized, all the engine
//! carries from one window to the next (the reference state, each set's separations, the step,
//! the divergence sum; the random directions are drawn only at t = 0), so
//! [`Engine::resume`] continues from the last such sample bit for bit. The output is the
//! recording's samples up to that point, copied, then the engine's: the file the uninterrupted
//! run gives, every indicator included (the recording's indicators channel is computed from the
//! samples as they are written, by the one tracker).
//!
//! What can be resumed: a run killed (`kill -9`: its recorder's in-progress `NAME.partial`,
//! read up to its last complete chunk), interrupted (a signal: a finalized file whose run
//! ended early) or finished (extended with a later `t_final`). In place, the recording is
//! replaced only by a longer one: a killed recorder's leftover once the new file reaches as
//! far, a finished file once the new one is complete; a signal before the new file reaches the
//! recording's end abandons it. So a kill of the resume at any moment loses nothing and can be
//! resumed again.

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use chaoscope_analyzer::recording::{ReadError, RecordingReader};
use chaoscope_analyzer::write::{SampleWriter, WriteError};
use chaoscope_dynamics::engine::{Engine, ResumeError, RunError};
use chaoscope_dynamics::estimate::{Machine, Transport};
use chaoscope_dynamics::header::run_header;
use chaoscope_dynamics::spec::{RunSpec, SpecError};
use chaoscope_os::{Leftover, Output, OutputError, OutputOptions};
use chaoscope_schemas::config::RunConfig;
use chaoscope_schemas::proto::{RunHeader, end_of_run};
use chaoscope_schemas::run::Sample;

#[derive(Debug, Clone, Default)]
pub struct ResumeOptions {
    /// The new end of the run (`--t-final`): later than the recorded one extends it. Default:
    /// the recorded `t_final`.
    pub t_final: Option<f64>,
    /// Where the resumed recording goes (`--out`); default: in place of the recording.
    pub out: Option<PathBuf>,
    /// Replace an existing `out` (never needed in place).
    pub force: bool,
    /// The run's configuration as given again (a requeued `chaoscope run`): refused unless it
    /// describes the recorded run (its `t_final` aside, which is then the new end).
    pub config: Option<RunConfig>,
    /// Set from another thread to stop; a SIGINT/SIGTERM latched by `chaoscope_os::signals`
    /// stops it too. The output is then finalized as an interrupted run, to be resumed again.
    pub stop: Option<Arc<AtomicBool>>,
    /// The run to its new end was estimated by the caller already (a requeued `run`, which
    /// estimated its configuration before continuing it); otherwise it is estimated here as
    /// `run` estimates it, and refused beyond a day or the machine's memory unless `force`.
    pub estimated: bool,
    /// What `run` holds in flight besides the numerics, for that estimate: the bus's frames
    /// (`chaoscope_producer::estimate::BUS`) in the command.
    pub transport: Transport,
}

#[derive(Debug, thiserror::Error)]
pub enum ResumeFailure {
    #[error("{}: no such recording, and no in-progress file {} of a killed one", .0.display(), chaoscope_os::output::partial_path(.0).display())]
    Missing(PathBuf),
    #[error(transparent)]
    Read(#[from] ReadError),
    #[error("{path}: the recorded configuration does not parse: {why}")]
    Config { path: String, why: String },
    #[error("{path}: the recorded configuration is no longer valid: {source}")]
    Spec { path: String, source: SpecError },
    #[error("{path}: {why}")]
    Mismatch { path: String, why: String },
    #[error("{path}: {why}")]
    Nothing { path: String, why: String },
    #[error(
        "{path}: it holds no complete sample to resume from (the run was killed before its first \
         chunk with one reached the disk): run it again"
    )]
    NoSample { path: String },
    #[error(
        "{path}: the run is complete at t_final = {t_final:?}: pass --t-final with a later time to \
         extend it"
    )]
    Complete { path: String, t_final: f64 },
    /// The estimate's refusal (`chaoscope_dynamics::estimate`), one line naming the key.
    #[error("{path}: {why}")]
    BeyondTheMachine { path: String, why: String },
    #[error("{path}: cannot resume: {source}")]
    Engine { path: String, source: ResumeError },
    #[error(transparent)]
    Output(#[from] OutputError),
    #[error(transparent)]
    Write(#[from] WriteError),
    #[error("{path}: writing the resumed recording: {source}")]
    Mcap {
        path: String,
        source: mcap::McapError,
    },
}

/// What a resume did.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct ResumeOutcome {
    /// The recording read (the file, or the in-progress file of a killed run).
    pub input: PathBuf,
    /// The resumed recording.
    pub output: PathBuf,
    /// Time and sample number of the sample it resumed from.
    pub resumed_from_t: f64,
    pub resumed_from_seq: u64,
    /// Samples copied from the recording (up to and including that one) and computed after it.
    pub samples_copied: u64,
    pub samples_computed: u64,
    /// The run's end now: `t_final`, and how it ended ("completed", "interrupted", "failed").
    pub t_final: f64,
    pub status: String,
    /// The time of the last sample the resumed recording holds (`t_final` when completed).
    pub t_reached: f64,
    /// Why the run failed (an escaped orbit), if it did.
    pub reason: Option<String>,
    /// Where reading the input stopped before its end (a killed writer's cut chunk), if it did.
    pub input_damage: Option<String>,
    /// Wall-clock seconds the resume took, and the estimate of its computed part made before
    /// it started (the run's estimate times the share of its steps after the sample resumed
    /// from).
    pub seconds: f64,
    pub estimated_seconds: f64,
}

/// The recording `path` names and the file to read it from: the file itself, or the
/// in-progress file a killed writer left (`NAME.partial`, also when named directly).
fn locate(path: &Path) -> Result<(PathBuf, PathBuf), ResumeFailure> {
    let name = path.to_string_lossy();
    if let Some(target) = name.strip_suffix(".partial")
        && std::fs::symlink_metadata(path).is_ok()
    {
        return Ok((PathBuf::from(target), path.to_path_buf()));
    }
    let partial = chaoscope_os::output::partial_path(path);
    let (has_partial, has_file) = (
        std::fs::symlink_metadata(&partial).is_ok(),
        std::fs::symlink_metadata(path).is_ok(),
    );
    // A killed writer's in-progress file (of a run never completed, or of a resume killed
    // after it passed its input) or the file, whichever reaches further: a resume killed early
    // leaves an in-progress file shorter than the recording it continues.
    let use_partial = match (has_partial, has_file) {
        (true, true) => last_step(&partial) > last_step(path),
        (has_partial, _) => has_partial,
    };
    if use_partial {
        return Ok((path.to_path_buf(), partial));
    }
    if has_file {
        return Ok((path.to_path_buf(), path.to_path_buf()));
    }
    Err(ResumeFailure::Missing(path.to_path_buf()))
}

/// The step of the last sample of the recording at `path` (read up to any damage), `None` if
/// it holds none or cannot be read.
fn last_step(path: &Path) -> Option<u64> {
    let mut reader = RecordingReader::open_salvaging(path).ok()?;
    let mut last = None;
    while let Ok(Some(sample)) = reader.next_sample() {
        last = Some(sample.step);
    }
    last
}

/// How long a writer's lock is waited for: a killed run's processes release their locks only
/// as the kernel tears them down, which a resume started right after the kill can precede.
const DYING_WRITER_GRACE: Duration = Duration::from_secs(3);

/// [`Output::create`], waiting up to [`DYING_WRITER_GRACE`] for a writer that holds the
/// in-progress file to be gone; a live one is refused after that, as by `create`.
fn create_waiting(path: &Path, options: &OutputOptions) -> Result<Output, OutputError> {
    let start = Instant::now();
    loop {
        match Output::create(path, options) {
            Err(OutputError::Busy { .. })
                if start.elapsed() < DYING_WRITER_GRACE && !chaoscope_os::signals::requested() =>
            {
                std::thread::sleep(Duration::from_millis(50));
            }
            other => return other,
        }
    }
}

/// Whether every scheme renormalizes at `step` (a sample a run can resume from).
fn every_scheme_renormalizes(spec: &RunSpec, step: u64) -> bool {
    spec.schemes()
        .iter()
        .all(|s| step.is_multiple_of(s.tau_steps))
}

/// Resumes the recording `recording` (see the module documentation).
pub fn resume(recording: &Path, options: &ResumeOptions) -> Result<ResumeOutcome, ResumeFailure> {
    let start = Instant::now();
    let mut outcome = resume_untimed(recording, options)?;
    outcome.seconds = start.elapsed().as_secs_f64();
    Ok(outcome)
}

fn resume_untimed(
    recording: &Path,
    options: &ResumeOptions,
) -> Result<ResumeOutcome, ResumeFailure> {
    let (target, input) = locate(recording)?;
    let shown = input.display().to_string();
    let in_place = options.out.as_ref().is_none_or(|o| o == &target);
    let out_path = options.out.clone().unwrap_or_else(|| target.clone());

    // The output first: a live writer of that name (the run still going) is refused before
    // anything is read, and a killed one's leftover is locked for us while we read it.
    let output_options = if in_place {
        OutputOptions {
            // The recording itself, replaced only by the complete longer one.
            replace: true,
            leftover: Leftover::Resume,
            // A failed write keeps what it holds: it is resumed again.
            keep_failed: true,
            ..Default::default()
        }
    } else {
        OutputOptions {
            replace: options.force,
            inputs: vec![input.clone()],
            // The leftover of an earlier resume into OUT, which `--force` discards as its
            // refusal says.
            leftover: if options.force {
                Leftover::Discard
            } else {
                Leftover::Refuse
            },
            keep_failed: true,
            ..Default::default()
        }
    };
    let mut output = create_waiting(&out_path, &output_options).map_err(|e| {
        e.with_leftover_hint(|_| {
            format!(" (`chaoscope resume {}` continues it)", out_path.display())
        })
    })?;
    let resuming_leftover = output.leftover().is_some();
    // The in-progress file located above was finished and put in place while its writer (a
    // resume of the same recording) was waited for: the recording to read is the file it became,
    // not the fresh in-progress file just created at its name.
    let (input, shown) = if in_place
        && input != target
        && !resuming_leftover
        && std::fs::symlink_metadata(&target).is_ok()
    {
        (target.clone(), target.display().to_string())
    } else {
        (input, shown)
    };
    // Read from elsewhere, a killed writer's leftover is still locked for the time we read it,
    // so a live run (whose file this is) is refused, not continued beside itself.
    let _leftover_lock = if !in_place && input != target {
        let lock = OutputOptions {
            replace: true,
            leftover: Leftover::Resume,
            keep_failed: true,
            ..Default::default()
        };
        Some(create_waiting(&target, &lock)?)
    } else {
        None
    };

    // The recorded run, rebuilt from its header's configuration with the new end. A file cut
    // before its run header reached the disk holds nothing of the run.
    let mut reader = match RecordingReader::open_salvaging(&input) {
        Err(ReadError::NoHeader { .. } | ReadError::Damaged { .. })
            if chaoscope_files::map_file::read_map_file(&input)
                .is_ok_and(|m| m.header.is_some() || m.described_as_map) =>
        {
            // A killed map's leftover describes itself as a map before its first chunk (and
            // its header) is whole.
            return Err(ResumeFailure::Nothing {
                path: shown,
                why: format!(
                    "a map file, not a run's recording: a map is resumed by computing the same \
                     map into it again (`chaoscope map CONFIG --out {}`)",
                    target.display()
                ),
            });
        }
        Err(ReadError::Damaged { .. } | ReadError::NoHeader { .. }) => {
            return Err(ResumeFailure::NoSample { path: shown });
        }
        r => r?,
    };
    let recorded = reader.header().clone();
    let config_err = |why: String| ResumeFailure::Config {
        path: shown.clone(),
        why,
    };
    let mut config =
        RunConfig::from_toml(&recorded.config_toml).map_err(|e| config_err(e.to_string()))?;
    let spec_err = |source| ResumeFailure::Spec {
        path: shown.clone(),
        source,
    };
    let recorded_spec = RunSpec::from_config(&config).map_err(spec_err)?;
    let same = run_header(&recorded.run_name, &config, &recorded_spec);
    if let Some(why) = header_difference(&recorded, &same) {
        return Err(ResumeFailure::Mismatch {
            path: shown,
            why: format!(
                "the recorded run header differs from the one its configuration gives now \
                 ({why}): it was recorded by another version or its inputs changed, so a \
                 continuation would not be that run's"
            ),
        });
    }
    if let Some(given) = &options.config {
        let mut given = given.clone();
        given.integrator.t_final = recorded.t_final;
        let spec = RunSpec::from_config(&given).map_err(spec_err)?;
        let header = run_header(&recorded.run_name, &given, &spec);
        if let Some(why) = header_difference(&recorded, &header) {
            return Err(ResumeFailure::Mismatch {
                path: shown,
                why: format!(
                    "the configuration is not the recorded run's ({why} differs): this run \
                     would not continue it; choose another output, or remove the recording to \
                     start afresh"
                ),
            });
        }
    }
    let t_final = options
        .t_final
        .or(options.config.as_ref().map(|c| c.integrator.t_final))
        .unwrap_or(recorded.t_final);
    if !(t_final.is_finite() && t_final > 0.0) {
        return Err(ResumeFailure::Nothing {
            path: shown,
            why: format!("--t-final {t_final:?} is not a positive time"),
        });
    }
    config.integrator.t_final = t_final;
    let spec = RunSpec::from_config(&config).map_err(|source| match options.t_final {
        // The flag's value is what fails, not the recording (1000.01 off the step grid).
        Some(t) => ResumeFailure::Nothing {
            path: shown.clone(),
            why: format!("--t-final {t:?}: {source}"),
        },
        None => spec_err(source),
    })?;
    // The run to its new end costs what `run` of it would (the recorded part is copied, a
    // small share of any run long enough to be refused): estimated as `run` estimates it,
    // before a sample is read or written, so `--t-final 1e12` is refused as `run` refuses it.
    let machine = Machine::this_host();
    let mut estimate = chaoscope_dynamics::estimate::run(&spec, &machine, &options.transport);
    if !options.estimated {
        if options.t_final.is_some() {
            estimate.time_key = "--t-final";
        }
        if let Some(why) = estimate.refusal(&machine) {
            if !options.force {
                return Err(ResumeFailure::BeyondTheMachine { path: shown, why });
            }
            chaoscope_os::errln!("chaoscope resume: --force: starting although {why}");
        }
    }
    let header = run_header(&recorded.run_name, &config, &spec);

    // The last sample to resume from: complete, every scheme renormalizing there, not past the
    // new end. The samples of the new run up to it are exactly the recorded ones: every scheme
    // renormalizes at its multiples of tau whatever the end (a run's last step, where all
    // renormalize, is one only if it stays the last).
    let total = spec.total_steps();
    let mut from: Option<Sample> = None;
    let mut ended_failed = None;
    let mut ended_complete = false;
    // The furthest the recording got (a sample cut short included).
    let mut input_last = (0, 0.0);
    while let Some(sample) = reader.next_sample()? {
        input_last = (sample.step, sample.t);
        if sample.step <= total
            && every_scheme_renormalizes(&spec, sample.step)
            && (sample.step == 0 || spec.is_sample_step(sample.step))
            && sample.schemes.len() == spec.schemes().len() * spec.sets()
            && !sample.state.is_empty()
        {
            from = Some(sample);
        }
    }
    if let Some(end) = &reader.info.end
        && end.status == end_of_run::Status::Failed as i32
    {
        ended_failed = Some(end.reason.clone());
    }
    if let Some(end) = &reader.info.end {
        ended_complete =
            end.status == end_of_run::Status::Completed as i32 && recorded.total_steps == total;
    }
    let damage = reader.info.damage.clone();
    drop(reader);
    if let Some(reason) = ended_failed {
        return Err(ResumeFailure::Nothing {
            path: shown,
            why: format!("the run failed ({reason}); a continuation would fail the same way"),
        });
    }
    let Some(from) = from else {
        return Err(ResumeFailure::NoSample { path: shown });
    };
    // In place, the recording is only ever replaced by a longer one.
    if in_place && total < input_last.0 {
        // Named as the user gave it: the flag, or the configuration given again (a requeue).
        let end = match (options.t_final, &options.config) {
            (Some(_), _) => format!("--t-final {t_final:?}"),
            (None, Some(_)) => format!("the configuration's t_final = {t_final:?}"),
            (None, None) => format!("the recorded t_final = {t_final:?}"),
        };
        return Err(ResumeFailure::Nothing {
            path: shown,
            why: format!(
                "{end} is before the recording's end (t = {}): in place that would cut it; \
                 write the shorter run elsewhere with --out",
                input_last.1
            ),
        });
    }
    // The leftover must be what was read: a shorter one beside a complete file (a resume of
    // it killed while copying) is not the run.
    if ended_complete && resuming_leftover && in_place && input != target && damage.is_none() {
        // A recorder killed after it finished the file and before it renamed it: the leftover
        // is the complete recording, put in place as it is.
        output.commit()?;
        return Ok(ResumeOutcome {
            input: input.clone(),
            output: out_path.clone(),
            resumed_from_t: from.t,
            resumed_from_seq: from.seq,
            samples_copied: 0,
            samples_computed: 0,
            t_final,
            status: "completed".into(),
            t_reached: input_last.1,
            reason: None,
            input_damage: None,
            seconds: 0.0,
            estimated_seconds: 0.0,
        });
    }
    if ended_complete && let Some(asked) = options.t_final {
        return Err(ResumeFailure::Nothing {
            path: shown,
            why: format!(
                "--t-final {asked} ends on the recording's last step (t = {}, steps of {}): \
                 give a time at least one step later to extend it",
                spec.t_final(),
                spec.h()
            ),
        });
    }
    if ended_complete {
        return Err(ResumeFailure::Complete {
            path: shown,
            t_final: spec.t_final(),
        });
    }
    let engine = Engine::resume(spec, &from).map_err(|source| ResumeFailure::Engine {
        path: shown.clone(),
        source,
    })?;

    // The new file: the recording's samples up to `from`, then the engine's.
    if resuming_leftover {
        output.start_fresh()?;
    }
    let mut writer = SampleWriter::create_in(output, &header)?;
    let werr = |source| ResumeFailure::Mcap {
        path: out_path.display().to_string(),
        source,
    };
    let mut copied = 0;
    let mut reader = RecordingReader::open_salvaging(&input)?;
    while let Some(sample) = reader.next_sample()? {
        if sample.seq > from.seq {
            break;
        }
        writer.write(&sample).map_err(werr)?;
        copied += 1;
    }
    drop(reader);
    // In place, the new file replaces the recording only once it reaches as far: until then a
    // kill leaves the recording (or the killed writer's leftover) as it was, and a signal
    // abandons the new file.
    let mut passed_input = !in_place || from.step >= input_last.0;
    if resuming_leftover && passed_input {
        writer.adopt_fresh()?;
    }
    let mut outcome = ResumeOutcome {
        input: input.clone(),
        output: out_path.clone(),
        resumed_from_t: from.t,
        resumed_from_seq: from.seq,
        samples_copied: copied,
        samples_computed: 0,
        t_final,
        status: "completed".into(),
        t_reached: from.t,
        reason: None,
        input_damage: damage,
        seconds: 0.0,
        estimated_seconds: estimate.seconds * total.saturating_sub(from.step) as f64
            / total.max(1) as f64,
    };
    let stopped = || {
        options
            .stop
            .as_ref()
            .is_some_and(|s| s.load(Ordering::Relaxed))
            || chaoscope_os::signals::requested()
    };
    let mut engine = engine;
    let mut last_checkpoint = Instant::now();
    let ended = loop {
        if stopped() {
            break Some((
                end_of_run::Status::Interrupted,
                "interrupted by a signal".to_string(),
            ));
        }
        match engine.next_sample() {
            Ok(Some(sample)) => {
                // No NaN or infinity goes into a file: the run fails there, as the producer's.
                if let Some(problem) = chaoscope_dynamics::header::non_finite(&sample) {
                    break Some((end_of_run::Status::Failed, problem));
                }
                writer.write(&sample).map_err(werr)?;
                outcome.samples_computed += 1;
                outcome.t_reached = sample.t;
                if !passed_input && sample.step >= input_last.0 {
                    passed_input = true;
                    if resuming_leftover {
                        writer.adopt_fresh()?;
                    }
                }
                if last_checkpoint.elapsed() >= crate::CHECKPOINT_EVERY {
                    writer.checkpoint()?;
                    last_checkpoint = Instant::now();
                }
            }
            Ok(None) => break None,
            Err(e @ RunError::Escaped { .. }) => {
                break Some((end_of_run::Status::Failed, e.to_string()));
            }
            Err(e) => break Some((end_of_run::Status::Failed, e.to_string())),
        }
    };
    // Stopped before the new file reached the recording's end, or in place of a finalized
    // recording before computing anything (the new file would be that recording again): the
    // recording stays as it was.
    let nothing_new = outcome.samples_computed == 0 && in_place && input == target;
    let stopped_early = matches!(&ended, Some((end_of_run::Status::Interrupted, _)));
    if !passed_input || (stopped_early && nothing_new) {
        writer.abandon();
        outcome.status = "interrupted".into();
        outcome.output = input.clone();
        outcome.t_reached = input_last.1;
        return Ok(outcome);
    }
    match ended {
        None => writer.finish("resume")?,
        Some((status, reason)) => {
            outcome.status = status.word().to_string();
            if status == end_of_run::Status::Failed {
                outcome.reason = Some(reason.clone());
            }
            writer.finish_with("resume", status, &reason)?;
        }
    }
    Ok(outcome)
}

/// The first field in which two run headers differ, apart from those a resume may change or
/// that do not describe the computation (the end of the run, the writer's version).
fn header_difference(recorded: &RunHeader, now: &RunHeader) -> Option<String> {
    let mut a = recorded.clone();
    let mut b = now.clone();
    for h in [&mut a, &mut b] {
        h.producer_version.clear();
    }
    if a == b {
        return None;
    }
    let fields: [(&str, bool); 10] = [
        ("config_toml", a.config_toml != b.config_toml),
        ("model", a.model != b.model),
        ("dim", a.dim != b.dim),
        ("k", a.k != b.k),
        ("sets", a.sets != b.sets),
        ("integrator", a.integrator != b.integrator),
        ("h", a.h.to_bits() != b.h.to_bits()),
        (
            "x0",
            a.x0.len() != b.x0.len()
                || a.x0
                    .iter()
                    .zip(&b.x0)
                    .any(|(x, y)| x.to_bits() != y.to_bits()),
        ),
        ("schemes", a.schemes != b.schemes),
        ("energy0", a.energy0.to_bits() != b.energy0.to_bits()),
    ];
    Some(
        fields
            .iter()
            .find(|(_, differs)| *differs)
            .map_or("another field", |(name, _)| name)
            .to_string(),
    )
}
