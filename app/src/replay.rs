//! Replay: re-run a recorded configuration with the schemes' renormalization settings replaced
//! (other `tau`, other `d0`), on the same reference orbit and the same initial directions, and
//! prove it by comparing every recorded reference state bit for bit with the replay.
//!
//! The reference orbit cannot depend on `tau` or `d0` (integrator steps are never merged across
//! step boundaries; ARCHITECTURE.md), so any difference is a bug or a different build, and the
//! replay says so. By default the original schemes are re-run too: then every recorded sample
//! time is also a replay sample time (every reference state is compared), the original
//! separation vectors are compared bit for bit as well, and `analyze` shows original and
//! replayed schemes side by side.

use std::path::Path;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

use chaoscope_dynamics::engine::{Engine, RunError};
use chaoscope_dynamics::estimate::{self, Machine, Transport};
use chaoscope_dynamics::header::run_header;
use chaoscope_dynamics::spec::{RunSpec, SpecError};
use chaoscope_schemas::config::{RunConfig, SchemeConfig};
use chaoscope_schemas::run::Sample;

use chaoscope_analyzer::analysis::{Analysis, AnalysisOptions};
use chaoscope_analyzer::recording::{ReadError, RecordingReader};
use chaoscope_analyzer::report::{ByOrder, Report};
use chaoscope_analyzer::run_info::RunInfo;
use chaoscope_analyzer::write::{SampleWriter, WriteError};
use chaoscope_os::{Leftover, OutputOptions};
use chaoscope_schemas::proto::{RunHeader, end_of_run};

use crate::flow;

#[derive(Debug, Clone, Default)]
pub struct ReplayOptions {
    /// New renormalization periods (each original scheme is replayed with each).
    pub taus: Vec<f64>,
    /// New distances d0 (likewise).
    pub d0s: Vec<f64>,
    /// Leave the original schemes out of the replay.
    pub without_original: bool,
    /// Set from another thread to stop the replay (the Python binding sets it on Ctrl-C); a
    /// SIGINT/SIGTERM latched by `chaoscope_os::signals` stops it too. The output is then
    /// finalized as an interrupted run: a valid file up to the last sample.
    pub stop: Option<Arc<AtomicBool>>,
    /// `--force`: replace an existing output file, and start even a replay estimated to take
    /// more than a day or more memory than the machine has (as `run` refuses it: the recorded
    /// configuration with the replay's schemes).
    pub force: bool,
    /// What `run` holds in flight besides the numerics, for that estimate: the bus's frames
    /// (`chaoscope_producer::estimate::BUS`) in the command.
    pub transport: Transport,
}

#[derive(Debug, thiserror::Error)]
pub enum ReplayError {
    #[error(transparent)]
    Read(#[from] ReadError),
    #[error("the recording's configuration does not parse: {0}")]
    Config(String),
    #[error("replay configuration: {0}")]
    // Not `#[from]`: that would also make it the error's source, and the message (which
    // already includes it) would print twice in an error chain.
    Spec(SpecError),
    #[error(transparent)]
    Run(#[from] RunError),
    #[error("{path}: writing the replay: {source}")]
    Write {
        path: String,
        source: mcap::McapError,
    },
    #[error(transparent)]
    Output(#[from] WriteError),
    #[error("nothing to replay: give --tau and/or --d0")]
    Nothing,
    /// The estimate's refusal (`chaoscope_dynamics::estimate`), one line naming the key.
    #[error("{0}")]
    BeyondTheMachine(String),
}

impl From<SpecError> for ReplayError {
    fn from(e: SpecError) -> Self {
        Self::Spec(e)
    }
}

/// What the comparison with the recording found.
#[derive(Debug, Clone, Default, PartialEq, serde::Serialize)]
pub struct ReplayOutcome {
    pub schemes: Vec<String>,
    /// Recorded reference states compared with the replay (every one, unless
    /// `without_original` left some recorded times out of the replay).
    pub reference_states_compared: u64,
    pub reference_states_identical: u64,
    /// Recorded times the replay did not sample (only with `without_original`).
    pub reference_states_not_sampled: u64,
    /// Recorded separation sets of the original schemes compared bit for bit.
    pub separation_sets_compared: u64,
    pub separation_sets_identical: u64,
    /// Step of the first difference, if any.
    pub first_difference_step: Option<u64>,
    pub replay_samples: u64,
    /// Stopped by a signal (or the caller) before the end: the file holds the samples up to
    /// then and says it was interrupted.
    pub interrupted: bool,
    /// Each new scheme against the original it was made from, at the end of the replay.
    pub comparison: Vec<SchemeComparison>,
    /// Wall-clock seconds the replay took, and its estimate made before it started.
    pub seconds: f64,
    pub estimated_seconds: f64,
}

/// One replayed scheme against the recorded scheme it was made from (the same sets of initial
/// directions on the same orbit), at the latest time both reached, means over the sets.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct SchemeComparison {
    pub scheme: String,
    /// The original scheme's name.
    pub of: String,
    pub tau: f64,
    pub d0: f64,
    /// Time of the values.
    pub t: f64,
    pub mle: f64,
    /// `mle - mle(of)`.
    pub mle_delta: f64,
    /// Per GALI order: `log10 GALI_j` (geometric mean over the sets), and its difference from
    /// the original's.
    pub gali_log10_mean: ByOrder<f64>,
    pub gali_delta_log10: ByOrder<f64>,
}

/// Each scheme of `replay` from index `first_new` on against its origin's entry in `original`
/// (a report of the recording, or the replay itself where it re-ran the originals).
fn comparison(
    replay: &Report,
    original: &Report,
    origins: &[(SchemeConfig, usize)],
    first_new: usize,
) -> Vec<SchemeComparison> {
    origins
        .iter()
        .zip(&replay.schemes)
        .skip(first_new)
        .filter_map(|((_, origin), new)| {
            let old = original.schemes.get(*origin)?;
            let gali = |r: &chaoscope_analyzer::report::SchemeReport| {
                r.gali
                    .0
                    .iter()
                    .map(|(j, g)| (*j, g.log10_mean))
                    .collect::<Vec<_>>()
            };
            let (g_new, g_old) = (gali(new), gali(old));
            Some(SchemeComparison {
                scheme: new.name.clone(),
                of: old.name.clone(),
                tau: new.tau,
                d0: new.d0,
                t: new.t,
                mle: new.mle,
                mle_delta: new.mle - old.mle,
                gali_delta_log10: ByOrder(
                    g_new
                        .iter()
                        .zip(&g_old)
                        .map(|((j, a), (_, b))| (*j, a - b))
                        .collect(),
                ),
                gali_log10_mean: ByOrder(g_new),
            })
        })
        .collect()
}

impl ReplayOutcome {
    pub fn identical(&self) -> bool {
        self.reference_states_compared > 0
            && self.reference_states_compared == self.reference_states_identical
            && self.separation_sets_compared == self.separation_sets_identical
    }
}

fn short(v: f64) -> String {
    let plain = format!("{v}");
    let sci = format!("{v:e}");
    if plain.len() <= sci.len() { plain } else { sci }
}

/// The replay's schemes: the originals (unless left out), then every original scheme with every
/// requested `tau` x `d0` (the unchanged setting when one list is empty), skipping duplicates.
/// A VM scheme takes the `tau`s but not the `d0`s: its tangent vectors evolve linearly, so `d0`
/// only scales them (and changes nothing but rounding), and a copy per `d0` would be noise.
pub fn replay_schemes(original: &[SchemeConfig], options: &ReplayOptions) -> Vec<SchemeConfig> {
    replay_schemes_with_origin(original, options)
        .into_iter()
        .map(|(s, _)| s)
        .collect()
}

/// [`replay_schemes`], each with the index of the original scheme it was made from.
fn replay_schemes_with_origin(
    original: &[SchemeConfig],
    options: &ReplayOptions,
) -> Vec<(SchemeConfig, usize)> {
    let mut out: Vec<(SchemeConfig, usize)> = if options.without_original {
        Vec::new()
    } else {
        original.iter().cloned().zip(0..).collect()
    };
    for (origin, s) in original.iter().enumerate() {
        let taus = if options.taus.is_empty() {
            vec![s.tau]
        } else {
            options.taus.clone()
        };
        let new_d0 = !options.d0s.is_empty() && s.method != "vm";
        let d0s = if new_d0 {
            options.d0s.clone()
        } else {
            vec![s.d0]
        };
        for &tau in &taus {
            for &d0 in &d0s {
                if !options.without_original && tau == s.tau && d0 == s.d0 {
                    continue;
                }
                let mut name = s.name.clone();
                if !options.taus.is_empty() {
                    name += &format!("-tau{}", short(tau));
                }
                if new_d0 {
                    name += &format!("-d0{}", short(d0));
                }
                if out.iter().any(|(o, _)| o.name == name) {
                    continue;
                }
                out.push((
                    SchemeConfig {
                        name,
                        tau,
                        d0,
                        ..s.clone()
                    },
                    origin,
                ));
            }
        }
    }
    out
}

fn bits_equal(a: &[f64], b: &[f64]) -> bool {
    a.len() == b.len() && a.iter().zip(b).all(|(x, y)| x.to_bits() == y.to_bits())
}

/// Replays `input` into `output`.
pub fn replay(
    input: &Path,
    output: &Path,
    options: &ReplayOptions,
) -> Result<ReplayOutcome, ReplayError> {
    if options.taus.is_empty() && options.d0s.is_empty() {
        return Err(ReplayError::Nothing);
    }
    let mut recorded = RecordingReader::open(input)?;
    let header = recorded.header().clone();
    let config = RunConfig::from_toml(&header.config_toml)
        .map_err(|e| ReplayError::Config(e.to_string()))?
        .with_sweeps_expanded()
        .map_err(|e| ReplayError::Config(e.to_string()))?;
    let original_schemes = config.schemes.len();
    let mut new_config = config.clone();
    let origins = replay_schemes_with_origin(&config.schemes, options);
    new_config.schemes = origins.iter().map(|(s, _)| s.clone()).collect();
    let name = format!("{}-replay", header.run_name);
    new_config.run.name = Some(name.clone());
    let spec = RunSpec::from_config(&new_config)?;
    // A recording's run may be one `run` refuses (or was forced): its replay, with more
    // schemes, costs at least as much, so it is estimated like a run before anything is written.
    let started = std::time::Instant::now();
    let machine = Machine::this_host();
    let estimate = estimate::run(&spec, &machine, &options.transport);
    if let Some(why) = estimate.refusal(&machine) {
        if !options.force {
            return Err(ReplayError::BeyondTheMachine(why));
        }
        chaoscope_os::errln!("chaoscope replay: --force: starting although {why}");
    }
    let new_header = run_header(&name, &new_config, &spec);
    let werr = |source| ReplayError::Write {
        path: output.display().to_string(),
        source,
    };
    let output_options = OutputOptions {
        replace: options.force,
        inputs: vec![input.to_path_buf()],
        // A killed replay's file is no use: it is computed again.
        leftover: Leftover::Discard,
        ..Default::default()
    };
    // Dropped on an error (a damaged recording, a full disk), the half-written replay goes.
    let mut writer = SampleWriter::create_with(output, &new_header, &output_options)?;
    let mut outcome = ReplayOutcome {
        schemes: new_config.schemes.iter().map(|s| s.name.clone()).collect(),
        estimated_seconds: estimate.seconds,
        ..Default::default()
    };
    // The comparison's values, by the analysis `analyze` runs: of the replay, and of the
    // recording where the replay leaves its schemes out.
    let analysis_of = |header: RunHeader| {
        RunInfo::from_header(header).map(|run| Analysis::new(run, &AnalysisOptions::default()))
    };
    let mut replay_analysis = analysis_of(new_header.clone()).ok();
    if let (Some(a), Some(field)) = (&mut replay_analysis, flow::flow_field(spec.system())) {
        a.set_flow_field(field);
    }
    if let Some(a) = &mut replay_analysis {
        a.set_site_energies(flow::site_energies(spec.system()));
        a.set_zero_one_observable(flow::zero_one_observable_of_spec(&spec, &new_config));
    }
    let mut recorded_analysis = if options.without_original {
        analysis_of(header.clone()).ok()
    } else {
        None
    };
    if let Some(a) = &mut recorded_analysis {
        a.set_zero_one_observable(flow::zero_one_observable_of_spec(&spec, &new_config));
    }
    let mut engine = Engine::new(spec);
    let mut replayed = || -> Result<(), ReplayError> {
        let mut pending: Option<Sample> = recorded.next_sample()?;
        while let Some(sample) = engine.next_sample()? {
            if options
                .stop
                .as_ref()
                .is_some_and(|s| s.load(Ordering::Relaxed))
                || chaoscope_os::signals::requested()
            {
                outcome.interrupted = true;
                return Ok(());
            }
            writer.write(&sample).map_err(werr)?;
            if let Some(a) = &mut replay_analysis {
                a.feed(&sample);
            }
            outcome.replay_samples += 1;
            while let Some(r) = pending.as_ref().filter(|r| r.step <= sample.step) {
                if r.step < sample.step {
                    outcome.reference_states_not_sampled += 1;
                } else {
                    compare(r, &sample, original_schemes, options, &mut outcome);
                }
                if let (Some(a), Some(r)) = (&mut recorded_analysis, &pending) {
                    a.feed(r);
                }
                pending = recorded.next_sample()?;
            }
        }
        // Recorded samples beyond the replay's end would mean a different run length.
        while pending.is_some() {
            outcome.reference_states_not_sampled += 1;
            pending = recorded.next_sample()?;
        }
        Ok(())
    };
    replayed()?;
    if let Some(replay_report) = replay_analysis.as_ref().map(Analysis::report) {
        let original_report = recorded_analysis.as_ref().map(Analysis::report);
        let (original, first_new) = match &original_report {
            Some(r) => (r, 0),
            None => (&replay_report, original_schemes),
        };
        outcome.comparison = comparison(&replay_report, original, &origins, first_new);
    }
    if outcome.interrupted {
        writer.finish_with(
            "signal",
            end_of_run::Status::Interrupted,
            "interrupted by a signal",
        )?;
    } else {
        writer.finish("replay")?;
    }
    outcome.seconds = started.elapsed().as_secs_f64();
    Ok(outcome)
}

fn compare(
    recorded: &Sample,
    replayed: &Sample,
    original_schemes: usize,
    options: &ReplayOptions,
    outcome: &mut ReplayOutcome,
) {
    let mut same = !recorded.state.is_empty();
    outcome.reference_states_compared += 1;
    same &= bits_equal(&recorded.state, &replayed.state)
        && recorded.energy.to_bits() == replayed.energy.to_bits()
        && recorded.mean_divergence.to_bits() == replayed.mean_divergence.to_bits();
    if same {
        outcome.reference_states_identical += 1;
    }
    let mut all = same;
    if !options.without_original {
        // The originals come first in the replay, with the same indices.
        for r in &recorded.schemes {
            if (r.scheme as usize) >= original_schemes {
                continue;
            }
            outcome.separation_sets_compared += 1;
            let ok = replayed
                .schemes
                .iter()
                .find(|p| p.scheme == r.scheme && p.set == r.set)
                .is_some_and(|p| {
                    bits_equal(&p.separations, &r.separations) && bits_equal(&p.stretch, &r.stretch)
                });
            if ok {
                outcome.separation_sets_identical += 1;
            }
            all &= ok;
        }
    }
    if !all && outcome.first_difference_step.is_none() {
        outcome.first_difference_step = Some(recorded.step);
    }
}
