//! `monitor`: live samples of a running producer from the bus, through the reader and the
//! analysis core of `chaoscope monitor`. The stream is the producer's lossy monitor copy: a
//! slow consumer never slows the run, it misses samples instead, and every sample says how many
//! frames were missed so far.

use std::ops::ControlFlow;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{Receiver, RecvTimeoutError, SyncSender, TrySendError};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::Duration;

use chaoscope_analyzer::analysis::{Analysis, AnalysisOptions};
use chaoscope_analyzer::assemble::SampleAssembler;
use chaoscope_analyzer::run_info::RunInfo;
use chaoscope_bus::monitor::{LiveEvent, LiveRun};
use chaoscope_schemas::run::Sample;
use numpy::PyArray1;
use pyo3::prelude::*;
use pyo3::types::PyDict;

/// Samples buffered between the reader thread and Python.
const QUEUE: usize = 256;
/// How often the reader thread wakes without data (to see a stop request).
const TICK: Duration = Duration::from_millis(100);

/// One scheme's values at a sample, averaged over its sets.
struct SchemeValues {
    name: String,
    t: f64,
    sets: usize,
    gali: Vec<f64>,
    gali_log10_mean: Vec<f64>,
    sali: Option<f64>,
    mle: f64,
}

struct SampleData {
    t: f64,
    step: u64,
    energy: Option<f64>,
    state: Vec<f64>,
    frames_received: u64,
    frames_lost: u64,
    schemes: Vec<SchemeValues>,
}

enum Item {
    Sample(SampleData),
    Failed(String),
}

#[derive(Default)]
struct Final {
    /// "completed", "interrupted", "failed", or None while running or if the producer vanished.
    status: Option<String>,
    frames_received: u64,
    frames_lost: u64,
    report: Option<String>,
}

/// An iterator over the live samples of a run (see `chaoscope.monitor`).
#[pyclass(module = "chaoscope", frozen)]
pub struct Monitor {
    run: String,
    samples: Mutex<Receiver<Item>>,
    stop: Arc<AtomicBool>,
    reader: Mutex<Option<JoinHandle<()>>>,
    end: Arc<Mutex<Final>>,
}

/// One live sample: the reference state and every scheme renormalized at this time.
#[pyclass(module = "chaoscope", frozen, get_all)]
pub struct LiveSample {
    t: f64,
    step: u64,
    /// Energy of the reference state (None if its frame was lost).
    energy: Option<f64>,
    /// Reference state (q1..qN, p1..pN), empty if its frame was lost.
    state: Py<PyAny>,
    /// Frames received and missed (the gap count of the lossy stream) so far.
    frames_received: u64,
    frames_lost: u64,
    /// Per scheme renormalized at this time: {"t", "sets", "gali" (mean GALI_2..k),
    /// "gali_log10_mean", "sali", "mle"}, from the analysis core of `chaoscope monitor`.
    indicators: Py<PyAny>,
}

#[pymethods]
impl LiveSample {
    fn __repr__(&self) -> String {
        format!(
            "LiveSample(t={}, step={}, frames_lost={})",
            self.t, self.step, self.frames_lost
        )
    }
}

/// Sends `item` unless the consumer is gone or a stop is requested; while the queue is full the
/// reader waits, and the producer's lossy monitor stream drops frames meanwhile (counted).
fn send(tx: &SyncSender<Item>, mut item: Item, stop: &AtomicBool) -> bool {
    loop {
        match tx.try_send(item) {
            Ok(()) => return true,
            Err(TrySendError::Disconnected(_)) => return false,
            Err(TrySendError::Full(back)) => {
                if stop.load(Ordering::Relaxed) {
                    return false;
                }
                item = back;
                std::thread::sleep(Duration::from_millis(2));
            }
        }
    }
}

fn sample_data(analysis: &Analysis, sample: &Sample, live: &LiveRun) -> SampleData {
    let mut touched: Vec<usize> = sample.schemes.iter().map(|s| s.scheme as usize).collect();
    touched.dedup();
    let schemes = touched
        .into_iter()
        .filter(|&si| si < analysis.run().schemes.len())
        .map(|si| {
            let ind = analysis.indicators(si);
            SchemeValues {
                name: analysis.run().schemes[si].name.clone(),
                t: ind.t,
                sets: ind.sets,
                gali: ind.gali.iter().map(|g| g.mean).collect(),
                gali_log10_mean: ind.gali.iter().map(|g| g.log10_mean).collect(),
                sali: ind.sali.map(|s| s.mean),
                mle: ind.mle(),
            }
        })
        .collect();
    SampleData {
        t: sample.t,
        step: sample.step,
        energy: (!sample.state.is_empty()).then_some(sample.energy),
        state: sample.state.clone(),
        frames_received: live.frames_received(),
        frames_lost: live.frames_lost(),
        schemes,
    }
}

/// The reader thread: connects, feeds every assembled sample to the analysis and the queue.
fn read(
    run: String,
    timeout: Duration,
    tx: SyncSender<Item>,
    stop: Arc<AtomicBool>,
    end: Arc<Mutex<Final>>,
) {
    let fail = |why: String| {
        let _ = tx.send(Item::Failed(why));
    };
    let (live, header) = match LiveRun::connect(&run, timeout) {
        Ok(Some(connected)) => connected,
        Ok(None) => return fail(format!("run {run:?}: interrupted before its header came")),
        Err(e) => return fail(chaoscope_files::file::error_chain(&e)),
    };
    let info = match RunInfo::from_header(header) {
        Ok(info) => info,
        Err(e) => {
            return fail(format!(
                "run header: {}",
                chaoscope_files::file::error_chain(&e)
            ));
        }
    };
    let mut analysis = Analysis::new(
        info,
        &AnalysisOptions {
            series_capacity: 2,
            per_decade: 1,
            ..chaoscope_app::flow::analysis_options()
        },
    );
    let mut assembler = SampleAssembler::new();
    let mut status = None;
    let mut consumer_gone = false;
    let received = live.receive(TICK, |event| {
        if stop.load(Ordering::Relaxed) {
            return ControlFlow::Break(());
        }
        if let LiveEvent::Message(m) = event {
            let (sample, e) = assembler.push(m);
            if let Some(s) = sample {
                analysis.feed(&s);
                if live.missed_any() {
                    analysis.mark_gap();
                }
                if !send(&tx, Item::Sample(sample_data(&analysis, &s, &live)), &stop) {
                    consumer_gone = true;
                    return ControlFlow::Break(());
                }
            }
            if let Some(e) = e {
                status = Some(e.status().word().to_string());
                return ControlFlow::Break(());
            }
        }
        ControlFlow::Continue(())
    });
    if let Err(e) = received {
        return fail(chaoscope_files::file::error_chain(&e));
    }
    if !consumer_gone
        && !stop.load(Ordering::Relaxed)
        && let Some(s) = assembler.finish()
    {
        analysis.feed(&s);
        send(&tx, Item::Sample(sample_data(&analysis, &s, &live)), &stop);
    }
    if live.missed_any() {
        analysis.mark_gap();
    }
    let mut end = end.lock().unwrap_or_else(|e| e.into_inner());
    end.status = status;
    end.frames_received = live.frames_received();
    end.frames_lost = live.frames_lost();
    end.report = serde_json::to_string(&analysis.report()).ok();
}

/// Follows the run named `run` live from the bus (started by `chaoscope run`, `chaoscope
/// produce` or any producer on this machine), waiting up to `timeout` seconds for it to appear.
/// Iterating yields a `LiveSample` per renormalization received and ends when the run ends.
/// Samples come from the producer's lossy monitor stream: a consumer that falls behind never
/// slows the run, it misses frames, counted in `frames_lost`.
#[pyfunction]
#[pyo3(signature = (run, *, timeout = 30.0))]
pub fn monitor(run: String, timeout: f64) -> PyResult<Monitor> {
    let timeout = Duration::try_from_secs_f64(timeout)
        .map_err(|_| crate::message(format!("timeout: {timeout} is not a number of seconds")))?;
    chaoscope_schemas::names::validate_run_name(&run)
        .map_err(|e| crate::message(format!("invalid run name: {e}")))?;
    let (tx, rx) = std::sync::mpsc::sync_channel(QUEUE);
    let stop = Arc::new(AtomicBool::new(false));
    let end = Arc::new(Mutex::new(Final::default()));
    let reader = {
        let (run, stop, end) = (run.clone(), Arc::clone(&stop), Arc::clone(&end));
        std::thread::Builder::new()
            .name("chaoscope-monitor".into())
            .spawn(move || read(run, timeout, tx, stop, end))
            .map_err(|e| crate::message(format!("starting the monitor thread: {e}")))?
    };
    Ok(Monitor {
        run,
        samples: Mutex::new(rx),
        stop,
        reader: Mutex::new(Some(reader)),
        end,
    })
}

impl Monitor {
    fn close_reader(&self) {
        self.stop.store(true, Ordering::Relaxed);
        let handle = self.reader.lock().unwrap_or_else(|e| e.into_inner()).take();
        if let Some(h) = handle {
            let _ = h.join();
        }
    }

    fn end(&self) -> std::sync::MutexGuard<'_, Final> {
        self.end.lock().unwrap_or_else(|e| e.into_inner())
    }
}

impl Drop for Monitor {
    fn drop(&mut self) {
        self.close_reader();
    }
}

#[pymethods]
impl Monitor {
    fn __iter__(slf: PyRef<'_, Self>) -> PyRef<'_, Self> {
        slf
    }

    fn __next__(&self, py: Python<'_>) -> PyResult<Option<LiveSample>> {
        loop {
            let item = py.detach(|| {
                self.samples
                    .lock()
                    .unwrap_or_else(|e| e.into_inner())
                    .recv_timeout(Duration::from_millis(50))
            });
            match item {
                Ok(Item::Sample(s)) => return live_sample(py, s).map(Some),
                Ok(Item::Failed(why)) => return Err(crate::message(why)),
                Err(RecvTimeoutError::Timeout) => py.check_signals()?,
                Err(RecvTimeoutError::Disconnected) => {
                    py.detach(|| self.close_reader());
                    return Ok(None);
                }
            }
        }
    }

    /// Stops following the run (the run itself goes on).
    fn close(&self, py: Python<'_>) {
        py.detach(|| self.close_reader());
    }

    fn __enter__(slf: PyRef<'_, Self>) -> PyRef<'_, Self> {
        slf
    }

    fn __exit__(
        &self,
        py: Python<'_>,
        _exc_type: Option<&Bound<'_, PyAny>>,
        _exc: Option<&Bound<'_, PyAny>>,
        _tb: Option<&Bound<'_, PyAny>>,
    ) {
        self.close(py);
    }

    /// The run followed.
    #[getter]
    fn run(&self) -> &str {
        &self.run
    }

    /// How the run ended ("completed", "interrupted", "failed"), once the iteration is over;
    /// None before, or if the producer vanished without an end record.
    #[getter]
    fn status(&self) -> Option<String> {
        self.end().status.clone()
    }

    /// Frames received from the bus (known once the iteration is over).
    #[getter]
    fn frames_received(&self) -> u64 {
        self.end().frames_received
    }

    /// Frames missed by this monitor (the lossy stream's gap count; known once the iteration
    /// is over, and on every sample while it runs).
    #[getter]
    fn frames_lost(&self) -> u64 {
        self.end().frames_lost
    }

    /// The analysis of what was received, as `chaoscope monitor --json-lines` prints it last
    /// (the `run` and `schemes` of `chaoscope analyze --json`); None before the iteration ends.
    fn report<'py>(&self, py: Python<'py>) -> PyResult<Option<Bound<'py, PyAny>>> {
        let json = self.end().report.clone();
        json.map(|j| py.import("json")?.call_method1("loads", (j,)))
            .transpose()
    }
}

fn live_sample(py: Python<'_>, s: SampleData) -> PyResult<LiveSample> {
    let indicators = PyDict::new(py);
    for v in s.schemes {
        let d = PyDict::new(py);
        d.set_item("t", v.t)?;
        d.set_item("sets", v.sets)?;
        d.set_item("gali", v.gali)?;
        d.set_item("gali_log10_mean", v.gali_log10_mean)?;
        d.set_item("sali", v.sali)?;
        d.set_item("mle", v.mle)?;
        indicators.set_item(v.name, d)?;
    }
    Ok(LiveSample {
        t: s.t,
        step: s.step,
        energy: s.energy,
        state: PyArray1::from_vec(py, s.state).into_any().unbind(),
        frames_received: s.frames_received,
        frames_lost: s.frames_lost,
        indicators: indicators.into_any().unbind(),
    })
}
