//! `Recording.clv`: the covariant Lyapunov vectors of a recording, by the analysis of
//! `chaoscope analyze --clv` (`chaoscope_analyzer::clv`), as numpy arrays.

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

use chaoscope_analyzer::clv::{ClvOptions, ClvReport, clv_of_file_until};
use pyo3::prelude::*;
use pyo3::types::{PyAny, PyDict};

use crate::recording::array;

/// What the worker thread hands back: the report and the series, drained in time order.
struct Computed {
    report: ClvReport,
    json: String,
    names: Vec<String>,
    t: Vec<f64>,
    /// `names.len()` angles a row.
    angles: Vec<f64>,
    /// `k * dim` values a row.
    vectors: Option<Vec<f64>>,
}

fn compute(path: &Path, options: &ClvOptions, stop: &AtomicBool) -> Result<Computed, String> {
    let text = |e: &(dyn std::error::Error + 'static)| chaoscope_files::file::error_chain(e);
    let output =
        clv_of_file_until(path, options, &|| stop.load(Ordering::Relaxed)).map_err(|e| text(&e))?;
    let spill = |e: std::io::Error| format!("--clv: the temporary file of the series: {e}");
    let mut angles = output.angles;
    let names = angles.names.clone();
    let rows = output.report.renormalizations as usize;
    let (mut t, mut values) = (Vec::with_capacity(rows), Vec::new());
    let mut row = vec![0.0; 1 + names.len()];
    while angles.next_row(&mut row).map_err(spill)? {
        t.push(row[0]);
        values.extend_from_slice(&row[1..]);
    }
    let vectors = match output.vectors {
        None => None,
        Some(mut series) => {
            let mut all = Vec::with_capacity(series.len() * series.k() * series.dim());
            let mut v = vec![0.0; series.k() * series.dim()];
            while series.next_row(&mut v).map_err(spill)?.is_some() {
                all.extend_from_slice(&v);
            }
            Some(all)
        }
    };
    Ok(Computed {
        json: serde_json::to_string(&output.report).map_err(|e| e.to_string())?,
        report: output.report,
        names,
        t,
        angles: values,
        vectors,
    })
}

/// The CLVs of the recording at `path` (read-only: on a thread of its own, Ctrl-C raises at
/// once and the reading stops at its next sample).
pub fn clv(py: Python<'_>, path: PathBuf, options: ClvOptions) -> PyResult<Clv> {
    let stop = Arc::new(AtomicBool::new(false));
    let flag = Arc::clone(&stop);
    let computed = match crate::interrupt::abandonable(py, move || compute(&path, &options, &flag))
    {
        Ok(result) => result.map_err(crate::message)?,
        Err(interrupted) => {
            stop.store(true, Ordering::Relaxed);
            return Err(interrupted);
        }
    };
    let Computed {
        report: r,
        json,
        names,
        t,
        angles,
        vectors,
    } = computed;
    let m = t.len();
    let by_name = PyDict::new(py);
    for (i, name) in names.iter().enumerate() {
        let column: Vec<f64> = (0..m).map(|row| angles[row * names.len() + i]).collect();
        by_name.set_item(name, array(py, column, &[m])?)?;
    }
    Ok(Clv {
        t: array(py, t, &[m])?,
        angles: by_name.into_any().unbind(),
        vectors: vectors
            .map(|v| array(py, v, &[m, r.k, r.dim]))
            .transpose()?,
        growth_rates: array(py, r.growth_rates.clone(), &[r.k])?,
        qr_spectrum: array(py, r.qr_spectrum.clone(), &[r.k])?,
        qr_spectrum_run: array(py, r.qr_spectrum_run.clone(), &[r.k])?,
        classes: r.classes.iter().map(|c| c.to_string()).collect(),
        report: py.import("json")?.call_method1("loads", (json,))?.unbind(),
        scheme: r.scheme,
        set: r.set,
        k: r.k,
        dim: r.dim,
        forward_transient: r.forward_transient,
        backward_transient: r.backward_transient,
        t_start: r.t_start,
        t_end: r.t_end,
        renormalizations: r.renormalizations,
        neutral: r.neutral,
        stretch_max_relative_difference: r.stretch_max_relative_difference,
        spilled_bytes: r.spilled_bytes,
    })
}

/// The covariant Lyapunov vectors of one VM QR scheme's set over the window between the
/// transients (numpy arrays): what `chaoscope analyze --clv` reports and exports.
#[pyclass(module = "chaoscope", frozen, get_all)]
pub struct Clv {
    /// The scheme and the set of its directions.
    scheme: String,
    set: usize,
    /// CLVs computed (the scheme's k) and their dimension.
    k: usize,
    dim: usize,
    forward_transient: f64,
    backward_transient: f64,
    /// The window: growth rates over it, angles and vectors at its renormalizations.
    t_start: f64,
    t_end: f64,
    renormalizations: u64,
    /// Each CLV's growth rate over the window (its Lyapunov exponent), shape (k,).
    growth_rates: Py<PyAny>,
    /// The QR (Benettin) spectrum over the same window, shape (k,).
    qr_spectrum: Py<PyAny>,
    /// The QR spectrum of the whole recording, shape (k,).
    qr_spectrum_run: Py<PyAny>,
    /// "unstable", "neutral" or "stable", per CLV.
    classes: Vec<String>,
    /// How many exponents count as neutral.
    neutral: usize,
    stretch_max_relative_difference: f64,
    spilled_bytes: u64,
    /// What `analyze --clv --json` prints under "clv" (with the angles' distributions).
    report: Py<PyAny>,
    /// Times of the window's renormalizations, shape (m,): the rows of `angles` and `vectors`.
    t: Py<PyAny>,
    /// The smallest principal angle between subspaces by name (`unstable_vs_rest`, ...: the
    /// columns of `clv-angles.csv`), radians, shape (m,) each.
    angles: Py<PyAny>,
    /// The CLVs, shape (m, k, dim): `vectors[n, j]` is CLV j + 1 at `t[n]`, a unit vector;
    /// None when asked not to keep them (`vectors=False`).
    vectors: Option<Py<PyAny>>,
}

#[pymethods]
impl Clv {
    fn __repr__(&self) -> String {
        format!(
            "Clv(scheme={:?}, set={}, k={}, dim={}, rows={}, classes={:?})",
            self.scheme, self.set, self.k, self.dim, self.renormalizations, self.classes
        )
    }
}
