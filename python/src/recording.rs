//! `run`, `open`, `Recording` (its indicators, its analysis report, `replay`).

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

use chaoscope_analyzer::analysis::{Analysis, AnalysisOptions, energy_error};
use chaoscope_analyzer::recording::{RecordingReader, analyze_file};
use chaoscope_analyzer::write::WriteError;
use chaoscope_app::record::Ended;
use chaoscope_app::resume::ResumeOptions;
use chaoscope_app::{ReplayError, ReplayOptions};
use chaoscope_dynamics::estimate::Machine;
use chaoscope_dynamics::header::run_header;
use chaoscope_dynamics::spec::RunSpec;
use chaoscope_indicators::{Named, Output};
use chaoscope_os::{Leftover, OutputOptions};
use chaoscope_producer::resolve_run_name;
use chaoscope_schemas::proto::RunHeader;
use numpy::{PyArray1, PyArrayMethods};
use pyo3::prelude::*;
use pyo3::types::{PyAny, PyDict};

use crate::interrupt::interruptible;
use crate::is_regular_file;

/// `{} already exists` as the command says it, with the keyword argument instead of `--force`.
fn exists_error(path: &Path) -> PyErr {
    crate::message(format!(
        "{} already exists (pass force=True to replace it)",
        path.display()
    ))
}

/// A chaoscope recording (an MCAP file): its run header, how it ended, and readers of its
/// indicators.
#[pyclass(module = "chaoscope", frozen)]
pub struct Recording {
    path: PathBuf,
    header: RunHeader,
    status: String,
    finalized_by: String,
    frames_missing: u64,
}

impl Recording {
    fn open_path(py: Python<'_>, path: PathBuf) -> PyResult<Self> {
        // Reading a long recording to its end takes a while: Ctrl-C ends the wait at once.
        let read = path.clone();
        let (header, summary) = crate::interrupt::abandonable(
            py,
            move || -> Result<_, chaoscope_analyzer::recording::ReadError> {
                let header = RecordingReader::open(&read)?.header().clone();
                let summary = chaoscope_analyzer::summary::summarize(&read)?;
                Ok((header, summary))
            },
        )?
        .map_err(|e| crate::error(&e))?;
        Ok(Self {
            path,
            header,
            status: summary.run_status,
            finalized_by: summary.finalized_by,
            frames_missing: summary.frames_missing,
        })
    }

    fn scheme_index(&self, name: &str) -> PyResult<usize> {
        self.header
            .schemes
            .iter()
            .position(|s| s.name == name)
            .ok_or_else(|| {
                let names: Vec<&str> = self.header.schemes.iter().map(|s| &s.name[..]).collect();
                crate::message(format!(
                    "{}: no scheme '{name}' (schemes: {})",
                    self.path.display(),
                    names.join(", ")
                ))
            })
    }
}

/// Opens a recording written by `chaoscope run`, `chaoscope record`, `chaoscope replay` or
/// `chaoscope.run`. A damaged or truncated file raises `ChaoscopeError` naming where and why.
#[pyfunction]
pub fn open(py: Python<'_>, path: PathBuf) -> PyResult<Recording> {
    Recording::open_path(py, path)
}

/// Integrates the run described by `config` (a dict, a TOML string or a path) and records it to
/// `out` (default `runs/<run name>.mcap`), with the engine and the file layout of
/// `chaoscope run`; returns the `Recording`.
///
/// The configuration is checked first (one line naming the key on error), then the resource
/// estimate (work beyond a day or the machine's memory is refused unless `force=True`). The GIL
/// is released while it runs; Ctrl-C stops it at the next renormalization, leaves a valid file
/// whose status is "interrupted", and raises `KeyboardInterrupt`.
#[pyfunction]
#[pyo3(signature = (config, *, out = None, run = None, force = false))]
pub fn run(
    py: Python<'_>,
    config: &Bound<'_, PyAny>,
    out: Option<PathBuf>,
    run: Option<String>,
    force: bool,
) -> PyResult<Recording> {
    let config_file = crate::config::config_path(config);
    let config = crate::config::run_config(config)?;
    let spec = RunSpec::from_config(&config)
        .map_err(|e| crate::message(format!("invalid run configuration: {e}")))?;
    let machine = Machine::this_host();
    if let Some(why) = chaoscope_producer::estimate::run(&spec, &machine).refusal(&machine)
        && !force
    {
        return Err(crate::message(crate::keyword_arguments(&why)));
    }
    let name = resolve_run_name(&config, run.as_deref()).map_err(|e| crate::error(&e))?;
    let out = out.unwrap_or_else(|| Path::new("runs").join(format!("{name}.mcap")));
    if !force && is_regular_file(&out) {
        return Err(exists_error(&out));
    }
    let header = run_header(&name, &config, &spec);
    // Written as every chaoscope output is (`chaoscope_os::output`): complete at `out` or not
    // there at all, never through a link, never over a live writer's file.
    let options = OutputOptions {
        replace: force,
        create_dir: true,
        leftover: if force {
            Leftover::Discard
        } else {
            Leftover::Refuse
        },
        inputs: config_file.into_iter().collect(),
        ..Default::default()
    };
    let stop = AtomicBool::new(false);
    let ended = interruptible(
        py,
        || stop.store(true, Ordering::Relaxed),
        || chaoscope_app::record::record(spec, &header, &out, &options, &stop),
    )?
    .map_err(|e| {
        // What a killed run left at `out` is what `resume` continues.
        let e = match e {
            WriteError::Output(o) => WriteError::Output(o.with_leftover_hint(|_| {
                format!(
                    " (`chaoscope.resume({:?})` continues it)",
                    out.display().to_string()
                )
            })),
            e => e,
        };
        crate::message(crate::keyword_arguments(&error_text(&e)))
    })?;
    if let Ended::Failed(why) = ended {
        return Err(crate::message(format!(
            "run {} failed: {why}",
            header.run_name
        )));
    }
    Recording::open_path(py, out)
}

/// Continues a killed, interrupted or finished run from its recording, as `chaoscope resume`
/// does: from its last complete sample into the file the uninterrupted run would have written
/// (in place of `path`, replaced only once complete, or into `out`); `t_final` later than the
/// recorded one extends the run. Returns the resumed `Recording`; a run that fails on the way
/// (an escaped orbit) raises `ChaoscopeError` with the reason, its file saying so. Ctrl-C stops
/// it at the next sample, leaves a recording to resume again, and raises `KeyboardInterrupt`.
#[pyfunction]
#[pyo3(signature = (path, *, t_final = None, out = None, force = false))]
pub fn resume(
    py: Python<'_>,
    path: PathBuf,
    t_final: Option<f64>,
    out: Option<PathBuf>,
    force: bool,
) -> PyResult<Recording> {
    let stop = Arc::new(AtomicBool::new(false));
    let options = ResumeOptions {
        t_final,
        out,
        force,
        config: None,
        stop: Some(Arc::clone(&stop)),
        estimated: false,
        transport: chaoscope_producer::estimate::BUS,
    };
    let outcome = interruptible(
        py,
        || stop.store(true, Ordering::Relaxed),
        || chaoscope_app::resume::resume(&path, &options),
    )?
    .map_err(|e| crate::message(crate::keyword_arguments(&error_text(&e))))?;
    if outcome.status == "failed" {
        return Err(crate::message(format!(
            "the run failed: {}; {} says so",
            outcome.reason.as_deref().unwrap_or("no reason recorded"),
            outcome.output.display()
        )));
    }
    Recording::open_path(py, outcome.output)
}

/// A float or a list of floats, as `tau=` and `d0=` take them.
#[derive(FromPyObject)]
pub enum Floats {
    One(f64),
    Many(Vec<f64>),
}

impl Floats {
    fn into_vec(self) -> Vec<f64> {
        match self {
            Floats::One(v) => vec![v],
            Floats::Many(v) => v,
        }
    }
}

#[pymethods]
impl Recording {
    /// Path of the file.
    #[getter]
    fn path(&self) -> PathBuf {
        self.path.clone()
    }

    /// The run's name.
    #[getter]
    fn run_name(&self) -> &str {
        &self.header.run_name
    }

    /// The run configuration, as canonical TOML (sweeps expanded).
    #[getter]
    fn config(&self) -> &str {
        &self.header.config_toml
    }

    /// Scheme names, in the file's order.
    #[getter]
    fn schemes(&self) -> Vec<String> {
        self.header.schemes.iter().map(|s| s.name.clone()).collect()
    }

    #[getter]
    fn model(&self) -> &str {
        &self.header.model
    }

    /// Degrees of freedom N (phase space has 2N dimensions).
    #[getter]
    fn n(&self) -> u32 {
        self.header.dim / 2
    }

    /// Deviation vectors per set.
    #[getter]
    fn k(&self) -> u32 {
        self.header.k
    }

    /// Independent sets of deviation vectors.
    #[getter]
    fn sets(&self) -> u32 {
        self.header.sets
    }

    #[getter]
    fn t_final(&self) -> f64 {
        self.header.t_final
    }

    /// Energy of the initial condition.
    #[getter]
    fn energy0(&self) -> f64 {
        self.header.energy0
    }

    /// How the run ended: "completed", "interrupted", "failed", or "unknown".
    #[getter]
    fn status(&self) -> &str {
        &self.status
    }

    /// Who finalized the file: "end-of-run", "signal", "producer-died", "replay", ...
    #[getter]
    fn finalized_by(&self) -> &str {
        &self.finalized_by
    }

    /// Frames the recorder missed (zero unless a process was killed).
    #[getter]
    fn frames_missing(&self) -> u64 {
        self.frames_missing
    }

    fn __repr__(&self) -> String {
        format!(
            "Recording({:?}, run={:?}, schemes={:?}, status={:?})",
            self.path.display().to_string(),
            self.header.run_name,
            self.schemes(),
            self.status
        )
    }

    /// The analysis of the whole recording, or as of time `at`: the object that
    /// `chaoscope analyze --json [--at T] [--from T0]` prints (GALI, SALI, exponents, energy
    /// error, the verdict and the warnings of every scheme), as a dict. `from_t` discards a
    /// transient: the finite-time exponents average the stretching from that time on, and
    /// nothing else changes.
    #[pyo3(signature = (at = None, from_t = None))]
    fn report<'py>(
        &self,
        py: Python<'py>,
        at: Option<f64>,
        from_t: Option<f64>,
    ) -> PyResult<Bound<'py, PyAny>> {
        let options = AnalysisOptions {
            at: at.into_iter().collect(),
            exponents_from: from_t,
            ..chaoscope_app::flow::analysis_options()
        };
        // Read-only, so on its own thread: Ctrl-C raises at once and the analysis of a long
        // recording is left to end unseen (nothing to finalize).
        let path = self.path.clone();
        let json = crate::interrupt::abandonable(py, move || -> Result<String, String> {
            let (analysis, info) = analyze_file(&path, &options).map_err(|e| error_text(&e))?;
            // As `chaoscope analyze --json`: the final report says how the run ended.
            let report = match at {
                Some(t) => analysis.report_at(t).expect("requested time is captured"),
                None => analysis.report_ended(info.end.as_ref()),
            };
            serde_json::to_string(&report).map_err(|e| e.to_string())
        })?
        .map_err(crate::message)?;
        py.import("json")?.call_method1("loads", (json,))
    }

    /// The same as [`Recording::report`], under the command's name: `analyze(from_t=100.0)` is
    /// `chaoscope analyze FILE --json --from 100`.
    #[pyo3(signature = (at = None, from_t = None))]
    fn analyze<'py>(
        &self,
        py: Python<'py>,
        at: Option<f64>,
        from_t: Option<f64>,
    ) -> PyResult<Bound<'py, PyAny>> {
        self.report(py, at, from_t)
    }

    /// The recorded orbit: the reference state at every recorded sample, and with `scheme` (an
    /// MPM scheme) the nearby orbits too, each the reference plus its separation before
    /// renormalization, at that scheme's renormalizations. Streams the file with the GIL
    /// released; Ctrl-C stops it.
    #[pyo3(signature = (scheme = None))]
    fn orbit(&self, py: Python<'_>, scheme: Option<&str>) -> PyResult<Orbit> {
        let si = match scheme {
            None => None,
            Some(name) => {
                let si = self.scheme_index(name)?;
                if self.header.schemes[si].method != "mpm" {
                    return Err(crate::message(format!(
                        "{}: scheme '{name}' is {}: its deviation vectors are tangent vectors, \
                         not nearby orbits (only an mpm scheme records nearby orbits)",
                        self.path.display(),
                        self.header.schemes[si].method
                    )));
                }
                Some(si)
            }
        };
        let stop = AtomicBool::new(false);
        let orbit = interruptible(
            py,
            || stop.store(true, Ordering::Relaxed),
            || read_orbit(&self.path, si, &stop),
        )?
        .map_err(crate::message)?;
        let (dim, n) = (self.header.dim as usize, orbit.t.len());
        let (sets, k, m) = (
            self.header.sets as usize,
            self.header.k as usize,
            orbit.nearby_t.len(),
        );
        Ok(Orbit {
            scheme: scheme.map(str::to_string),
            t: array(py, orbit.t, &[n])?,
            states: array(py, orbit.states, &[n, dim])?,
            nearby_t: si.map(|_| array(py, orbit.nearby_t, &[m])).transpose()?,
            nearby: si
                .map(|_| array(py, orbit.nearby, &[m, sets, k, dim]))
                .transpose()?,
        })
    }

    /// The indicators of scheme `scheme` at each of its renormalizations, computed by the same
    /// analysis core as `chaoscope analyze` (so the last row equals `analyze --json`, and the
    /// row at time T equals `analyze --json --at T`, to the last bit). Streams the file with the
    /// GIL released; Ctrl-C stops it.
    fn indicators(&self, py: Python<'_>, scheme: &str) -> PyResult<Indicators> {
        let si = self.scheme_index(scheme)?;
        let stop = AtomicBool::new(false);
        let series = interruptible(
            py,
            || stop.store(true, Ordering::Relaxed),
            || read_series(&self.path, si, &stop),
        )?
        .map_err(crate::message)?;
        Indicators::new(py, &self.header, si, series)
    }

    /// The covariant Lyapunov vectors (Ginelli) of a VM scheme renormalized by QR, as
    /// `chaoscope analyze --clv` computes them, with the same arguments: `scheme`
    /// (`--clv-scheme`, default the first such scheme), `set` (`--clv-set`),
    /// `forward_transient` and `backward_transient` (times discarded at the start and the end,
    /// default a tenth of the run each), `neutral` (`--clv-neutral`), `memory` (MiB of stored
    /// factors before they spill to a temporary file, `--clv-memory`). Returns a `Clv`: the
    /// growth rates, the angles between the subspaces at every renormalization of the window,
    /// and (unless `vectors=False`) the vectors themselves, shape (m, k, dim), in memory. Reads
    /// the file with the GIL released; Ctrl-C raises at once.
    #[pyo3(signature = (scheme = None, *, set = 0, forward_transient = None, backward_transient = None, neutral = None, memory = 256, vectors = true))]
    #[allow(clippy::too_many_arguments)]
    fn clv(
        &self,
        py: Python<'_>,
        scheme: Option<String>,
        set: usize,
        forward_transient: Option<f64>,
        backward_transient: Option<f64>,
        neutral: Option<usize>,
        memory: usize,
        vectors: bool,
    ) -> PyResult<crate::clv::Clv> {
        let options = chaoscope_analyzer::clv::ClvOptions {
            scheme,
            set,
            forward_transient,
            backward_transient,
            neutral,
            memory_bytes: memory.saturating_mul(1 << 20),
            vectors,
        };
        crate::clv::clv(py, self.path.clone(), options)
    }

    /// Re-runs the recorded configuration with other renormalization periods `tau` and/or
    /// distances `d0` (a number or a list each) on the bit-identical reference orbit, like
    /// `chaoscope replay`, into `out` (default: `<stem>-replay.mcap` beside this file). The
    /// original schemes are re-run too unless `without_original=True`; the new schemes are
    /// named `<scheme>-tau<T>` / `-d0<D>` (VM schemes take no other `d0`: it only scales their
    /// linearly evolving tangent vectors). Raises `ChaoscopeError` if the replayed orbit differs
    /// from the recorded one in any bit.
    #[pyo3(signature = (*, tau = None, d0 = None, out = None, without_original = false, force = false))]
    fn replay(
        &self,
        py: Python<'_>,
        tau: Option<Floats>,
        d0: Option<Floats>,
        out: Option<PathBuf>,
        without_original: bool,
        force: bool,
    ) -> PyResult<Recording> {
        let out = out.unwrap_or_else(|| {
            let stem = self
                .path
                .file_stem()
                .map_or("recording".into(), |s| s.to_string_lossy().into_owned());
            self.path.with_file_name(format!("{stem}-replay.mcap"))
        });
        if !force && is_regular_file(&out) {
            return Err(exists_error(&out));
        }
        let stop = Arc::new(AtomicBool::new(false));
        let options = ReplayOptions {
            taus: tau.map(Floats::into_vec).unwrap_or_default(),
            d0s: d0.map(Floats::into_vec).unwrap_or_default(),
            without_original,
            stop: Some(Arc::clone(&stop)),
            force,
            transport: chaoscope_producer::estimate::BUS,
        };
        let outcome = interruptible(
            py,
            || stop.store(true, Ordering::Relaxed),
            || chaoscope_app::replay(&self.path, &out, &options),
        )?;
        let outcome = match outcome {
            Ok(o) => o,
            Err(ReplayError::Nothing) => {
                return Err(crate::message("nothing to replay: give tau and/or d0"));
            }
            Err(e) => return Err(crate::message(crate::keyword_arguments(&error_text(&e)))),
        };
        if !outcome.identical() {
            return Err(crate::message(format!(
                "the replay DIFFERS from the recording (first at step {:?})",
                outcome.first_difference_step
            )));
        }
        Recording::open_path(py, out)
    }
}

fn error_text(e: &(dyn std::error::Error + 'static)) -> String {
    chaoscope_files::file::error_chain(e)
}

/// The recorded orbit, as flat rows.
#[derive(Default)]
struct OrbitRows {
    t: Vec<f64>,
    states: Vec<f64>,
    nearby_t: Vec<f64>,
    nearby: Vec<f64>,
}

/// Reads the reference state of every sample, and for scheme `si` the nearby orbits
/// (reference + separation) of every set at its renormalizations; a set missing at a time
/// (lost frames) is NaN there, as in `Indicators`. Returns early once `stop` is set.
fn read_orbit(path: &Path, si: Option<usize>, stop: &AtomicBool) -> Result<OrbitRows, String> {
    let mut reader = RecordingReader::open(path).map_err(|e| error_text(&e))?;
    let run = reader.run();
    let (dim, sets, k) = (run.dim, run.sets, run.k);
    let mut rows = OrbitRows::default();
    while let Some(sample) = reader.next_sample().map_err(|e| error_text(&e))? {
        if stop.load(Ordering::Relaxed) {
            return Err("interrupted".into());
        }
        // A sample whose reference state was lost (frames missing) has none to give.
        if sample.state.len() != dim {
            continue;
        }
        rows.t.push(sample.t);
        rows.states.extend_from_slice(&sample.state);
        let Some(si) = si else { continue };
        let mine: Vec<_> = sample
            .schemes
            .iter()
            .filter(|s| s.scheme as usize == si)
            .collect();
        if mine.is_empty() {
            continue;
        }
        rows.nearby_t.push(sample.t);
        let start = rows.nearby.len();
        rows.nearby.resize(start + sets * k * dim, f64::NAN);
        for s in mine {
            let at = start + s.set as usize * k * dim;
            for (j, d) in s.separations.chunks_exact(dim).enumerate().take(k) {
                for (i, (x, dx)) in sample.state.iter().zip(d).enumerate() {
                    rows.nearby[at + j * dim + i] = x + dx;
                }
            }
        }
    }
    Ok(rows)
}

/// One scheme's indicators at each of its renormalizations, row by row.
struct Series {
    sets: usize,
    orders: usize,
    vectors: usize,
    t: Vec<f64>,
    contributing: Vec<u64>,
    gali: Vec<f64>,
    gali_log10_mean: Vec<f64>,
    gali_log10_sets: Vec<f64>,
    sali: Vec<f64>,
    sali_log10_mean: Vec<f64>,
    sali_sets: Vec<f64>,
    exponents: Vec<f64>,
    exponents_sets: Vec<f64>,
    energy_error: Vec<f64>,
    /// Every registered set indicator's outputs (`set_output_names()`), per row: the mean over
    /// the sets (`names` values a row), and per set (`sets * names` values a row); NaN where
    /// unavailable.
    names: &'static [&'static str],
    named: Vec<f64>,
    named_sets: Vec<f64>,
    /// The outputs unavailable at the latest row, with the reason.
    unavailable: Vec<(&'static str, String)>,
    /// An MPM scheme's mean |log10 GALI_j - log10 GALI_j(VM)| per row (`orders` values a row,
    /// NaN where its VM partner is not at the same step); `None` without a partner.
    vs_vm: Option<Vec<f64>>,
}

/// Streams the recording through the analysis core (the reader and feed of
/// `chaoscope analyze`) and keeps scheme `si`'s values after each of its samples.
/// Returns early (the caller raises the pending `KeyboardInterrupt`) once `stop` is set.
fn read_series(path: &Path, si: usize, stop: &AtomicBool) -> Result<Series, String> {
    let mut reader = RecordingReader::open(path).map_err(|e| error_text(&e))?;
    let run = reader.run().clone();
    let (sets, k, energy0) = (run.sets, run.k, run.header.energy0);
    let orders = k.saturating_sub(1);
    // The options of `chaoscope analyze` that change an indicator's value: the system rebuilt
    // from the recording's config for OFLI's flow direction and the site energies.
    let options = AnalysisOptions {
        flow_field: Some(chaoscope_app::flow::flow_field_of_run),
        site_energies: Some(chaoscope_app::flow::site_energies_of_run),
        ..Default::default()
    };
    let mut analysis = Analysis::new(run, &options);
    let names = chaoscope_indicators::indicator::set_output_names();
    let mut s = Series {
        sets,
        orders,
        vectors: k,
        t: Vec::new(),
        contributing: Vec::new(),
        gali: Vec::new(),
        gali_log10_mean: Vec::new(),
        gali_log10_sets: Vec::new(),
        sali: Vec::new(),
        sali_log10_mean: Vec::new(),
        sali_sets: Vec::new(),
        exponents: Vec::new(),
        exponents_sets: Vec::new(),
        energy_error: Vec::new(),
        names,
        named: Vec::new(),
        named_sets: Vec::new(),
        unavailable: Vec::new(),
        vs_vm: None,
    };
    while let Some(sample) = reader.next_sample().map_err(|e| error_text(&e))? {
        if stop.load(Ordering::Relaxed) {
            return Err("interrupted".into());
        }
        analysis.feed(&sample);
        if !sample.schemes.iter().any(|x| x.scheme as usize == si) {
            continue;
        }
        let ind = analysis.indicators(si);
        s.t.push(ind.t);
        s.contributing.push(ind.sets as u64);
        for o in 0..orders {
            let g = ind.gali.get(o);
            s.gali.push(g.map_or(f64::NAN, |g| g.mean));
            s.gali_log10_mean.push(g.map_or(f64::NAN, |g| g.log10_mean));
        }
        s.sali.push(ind.sali.map_or(f64::NAN, |v| v.mean));
        s.sali_log10_mean
            .push(ind.sali.map_or(f64::NAN, |v| v.log10_mean));
        for i in 0..k {
            s.exponents
                .push(ind.exponents.get(i).map_or(f64::NAN, |e| e.mean));
        }
        // As the CSV's columns: the mean over the sets of each output.
        s.named.extend(
            names
                .iter()
                .map(|name| ind.named.value(name).unwrap_or(f64::NAN)),
        );
        s.unavailable = ind
            .named
            .0
            .iter()
            .filter_map(|(name, v)| match v {
                Named::Unavailable(reason) => Some((*name, reason.clone())),
                _ => None,
            })
            .collect();
        let rows = s.t.len();
        match (analysis.vs_vm(si), &mut s.vs_vm) {
            (Some(d), vs_vm) => {
                let all = vs_vm.get_or_insert_with(|| vec![f64::NAN; (rows - 1) * orders]);
                all.extend((0..orders).map(|o| {
                    d.gali
                        .0
                        .get(o)
                        .map_or(f64::NAN, |(_, x)| x.mean_abs_delta_log10)
                }));
            }
            (None, Some(all)) => all.extend((0..orders).map(|_| f64::NAN)),
            (None, None) => {}
        }
        for set in 0..sets {
            // A set whose latest values are not of this sample (lost frames) is missing here.
            let v = analysis
                .set_values(si, set)
                .filter(|v| v.t.to_bits() == ind.t.to_bits());
            for o in 0..orders {
                s.gali_log10_sets.push(
                    v.as_ref()
                        .and_then(|v| v.gali_log10.get(o).copied())
                        .unwrap_or(f64::NAN),
                );
            }
            s.sali_sets
                .push(v.as_ref().and_then(|v| v.sali).unwrap_or(f64::NAN));
            for i in 0..k {
                s.exponents_sets.push(
                    v.as_ref()
                        .and_then(|v| v.exponents.get(i).copied())
                        .unwrap_or(f64::NAN),
                );
            }
            for name in names {
                s.named_sets.push(
                    v.as_ref()
                        .and_then(|v| v.outputs.iter().find(|(n, _)| n == name))
                        .and_then(|(_, o)| match o {
                            Output::Value(x) => Some(*x),
                            Output::Unavailable(_) => None,
                        })
                        .unwrap_or(f64::NAN),
                );
            }
        }
        s.energy_error.push(if sample.state.is_empty() {
            f64::NAN
        } else {
            energy_error(sample.energy, energy0)
        });
    }
    Ok(s)
}

/// The indicators of one scheme, one row per renormalization (numpy arrays). Column `j - 2` of
/// the GALI arrays is GALI_j, j = 2..k. Averages are over the sets present at that time. Every
/// registered set indicator's output (FLI, OFLI, MEGNO, ...) is in `named` under its report
/// name, and an attribute of that name.
#[pyclass(module = "chaoscope", frozen, get_all)]
pub struct Indicators {
    /// Scheme name.
    scheme: String,
    /// "vm" or "mpm".
    method: String,
    /// "rescale" or "qr" (Lyapunov spectrum).
    orthonormalize: String,
    d0: f64,
    tau: f64,
    /// GALI orders of the columns: [2, ..., k].
    orders: Vec<usize>,
    /// Times of the renormalizations, shape (n,).
    t: Py<PyAny>,
    /// Sets contributing at each time, shape (n,).
    sets: Py<PyAny>,
    /// Arithmetic mean of GALI_j over the sets, shape (n, k - 1).
    gali: Py<PyAny>,
    /// Mean over the sets of log10 GALI_j (log10 of the geometric mean), shape (n, k - 1).
    gali_log10_mean: Py<PyAny>,
    /// log10 GALI_j of each set, shape (n, sets, k - 1).
    gali_log10_sets: Py<PyAny>,
    /// Arithmetic mean of SALI over the sets, shape (n,).
    sali: Py<PyAny>,
    /// Mean over the sets of log10 SALI, shape (n,).
    sali_log10_mean: Py<PyAny>,
    /// SALI of each set, shape (n, sets).
    sali_sets: Py<PyAny>,
    /// Finite-time exponent of each vector, mean over the sets, shape (n, k): the spectrum for
    /// QR schemes, the MLE estimate of each vector for rescaled ones.
    exponents: Py<PyAny>,
    /// The same per set, shape (n, sets, k).
    exponents_sets: Py<PyAny>,
    /// Finite-time maximal Lyapunov exponent (the first vector's), shape (n,).
    mle: Py<PyAny>,
    /// Relative energy error of the reference orbit at each time, shape (n,).
    energy_error: Py<PyAny>,
    /// The names of every registered set indicator's outputs, in report order: `fli`, `ofli`,
    /// `megno`, `megno_mean`, `dvd_m2`, `dvd_participation`, `energy_m2`,
    /// `energy_participation`, `norm_m2`, `norm_participation` (the columns of `analyze --csv`).
    names: Vec<&'static str>,
    /// Each output's mean over the sets by name, shape (n,), NaN where unavailable (each is also
    /// an attribute: `ind.fli`).
    named: Py<PyAny>,
    /// Each output of each set by name, shape (n, sets).
    named_sets: Py<PyAny>,
    /// The outputs this run cannot give (at its latest row), with the reason.
    unavailable: Py<PyAny>,
    /// For an MPM scheme, the mean over the sets of |log10 GALI_j - log10 GALI_j(VM)| against the
    /// VM scheme of the same tau, shape (n, k - 1); None for a scheme without one.
    gali_vs_vm_mean_abs_delta_log10: Option<Py<PyAny>>,
}

pub(crate) fn array(py: Python<'_>, data: Vec<f64>, shape: &[usize]) -> PyResult<Py<PyAny>> {
    Ok(PyArray1::from_vec(py, data)
        .reshape(shape)?
        .into_any()
        .unbind())
}

impl Indicators {
    fn new(py: Python<'_>, header: &RunHeader, si: usize, s: Series) -> PyResult<Self> {
        let info = &header.schemes[si];
        let n = s.t.len();
        let mle: Vec<f64> = (0..n).map(|r| s.exponents[r * s.vectors]).collect();
        let width = s.names.len();
        let named = PyDict::new(py);
        let named_sets = PyDict::new(py);
        for (i, name) in s.names.iter().enumerate() {
            let mean: Vec<f64> = (0..n).map(|r| s.named[r * width + i]).collect();
            named.set_item(name, array(py, mean, &[n])?)?;
            let sets: Vec<f64> = (0..n * s.sets)
                .map(|rs| s.named_sets[rs * width + i])
                .collect();
            named_sets.set_item(name, array(py, sets, &[n, s.sets])?)?;
        }
        let unavailable = PyDict::new(py);
        for (name, reason) in &s.unavailable {
            unavailable.set_item(name, reason)?;
        }
        Ok(Self {
            scheme: info.name.clone(),
            method: info.method.clone(),
            orthonormalize: info.orthonormalize.clone(),
            d0: info.d0,
            tau: info.tau,
            orders: (2..s.orders + 2).collect(),
            t: array(py, s.t, &[n])?,
            sets: PyArray1::from_vec(py, s.contributing).into_any().unbind(),
            gali: array(py, s.gali, &[n, s.orders])?,
            gali_log10_mean: array(py, s.gali_log10_mean, &[n, s.orders])?,
            gali_log10_sets: array(py, s.gali_log10_sets, &[n, s.sets, s.orders])?,
            sali: array(py, s.sali, &[n])?,
            sali_log10_mean: array(py, s.sali_log10_mean, &[n])?,
            sali_sets: array(py, s.sali_sets, &[n, s.sets])?,
            exponents: array(py, s.exponents, &[n, s.vectors])?,
            exponents_sets: array(py, s.exponents_sets, &[n, s.sets, s.vectors])?,
            mle: array(py, mle, &[n])?,
            energy_error: array(py, s.energy_error, &[n])?,
            names: s.names.to_vec(),
            named: named.into_any().unbind(),
            named_sets: named_sets.into_any().unbind(),
            unavailable: unavailable.into_any().unbind(),
            gali_vs_vm_mean_abs_delta_log10: s
                .vs_vm
                .map(|d| array(py, d, &[n, s.orders]))
                .transpose()?,
        })
    }
}

/// The recorded orbit (numpy arrays): `t` and `states` of the reference at every recorded
/// sample; for an MPM scheme, `nearby_t` and `nearby`, its nearby orbits at its
/// renormalizations (the state each nearby orbit reached before it was pulled back to `d0`).
#[pyclass(module = "chaoscope", frozen, get_all)]
pub struct Orbit {
    /// The MPM scheme whose nearby orbits are given, or None.
    scheme: Option<String>,
    /// Times of the recorded samples, shape (n,).
    t: Py<PyAny>,
    /// The reference state at those times (q1..qN, p1..pN or x1..xD), shape (n, dim).
    states: Py<PyAny>,
    /// Times of the scheme's renormalizations, shape (m,); None without a scheme.
    nearby_t: Option<Py<PyAny>>,
    /// Nearby orbit `j` of set `s` at those times, shape (m, sets, k, dim): the reference plus
    /// the separation before renormalization. None without a scheme.
    nearby: Option<Py<PyAny>>,
}

#[pymethods]
impl Orbit {
    fn __repr__(&self, py: Python<'_>) -> PyResult<String> {
        let n = self.t.bind(py).len()?;
        Ok(format!("Orbit(samples={n}, scheme={:?})", self.scheme))
    }
}

#[pymethods]
impl Indicators {
    /// Every registered output by name as an attribute (`ind.fli`, `ind.megno_mean`): its mean
    /// over the sets, from `named`.
    fn __getattr__(&self, py: Python<'_>, name: &str) -> PyResult<Py<PyAny>> {
        match self.named.bind(py).get_item(name) {
            Ok(value) => Ok(value.unbind()),
            Err(_) => Err(pyo3::exceptions::PyAttributeError::new_err(format!(
                "'Indicators' object has no attribute '{name}'"
            ))),
        }
    }

    fn __repr__(&self, py: Python<'_>) -> PyResult<String> {
        let n = self.t.bind(py).len()?;
        Ok(format!(
            "Indicators(scheme={:?}, method={:?}, rows={n}, orders={:?})",
            self.scheme, self.method, self.orders
        ))
    }
}
