//! `map` and `open_map`: a phase-space map computed by the map scheduler of `chaoscope map`,
//! recorded in its file format, returned as numpy grids.

use std::path::{Path, PathBuf};
use std::time::Duration;

use chaoscope_app::map::{MapFileError, MapJob, map_to_file, resumable_points};
use chaoscope_dynamics::batch::Isa;
use chaoscope_dynamics::estimate::{self, Machine};
use chaoscope_dynamics::map::{MapOptions, MapSpec, Shard};
use chaoscope_files::map_file::read_map_file;
use chaoscope_os::termination::Termination;
use chaoscope_schemas::proto::{MapHeader, MapPoint};
use numpy::{PyArray1, PyArrayMethods};
use pyo3::prelude::*;

use crate::interrupt::interruptible;
use crate::is_regular_file;

/// A phase-space map: one indicator value per grid point (numpy arrays indexed [iy, ix]).
#[pyclass(module = "chaoscope", frozen, get_all)]
pub struct Map {
    /// The map file.
    path: PathBuf,
    /// "gali", "gali-time", "sali", "mle", "spectrum", "fli", "megno" or "megno_mean".
    indicator: String,
    /// "vm" or "mpm".
    method: String,
    /// GALI order (or vectors per set for "mle", exponents for "spectrum").
    k: u32,
    sets: u32,
    t_final: f64,
    /// What the axes vary: coordinates such as "q2" and "p2", or a parameter ("K").
    x_coord: String,
    y_coord: String,
    /// Grid coordinates, shapes (nx,) and (ny,).
    x: Py<PyAny>,
    y: Py<PyAny>,
    /// The indicator (mean over the sets), shape (ny, nx); NaN where no point was integrated
    /// (outside the energy surface, escaped) or the map is incomplete.
    value: Py<PyAny>,
    /// Mean over the sets of log10 GALI_k ("gali"), shape (ny, nx).
    mean_log10: Py<PyAny>,
    /// Per point: 1 integrated, 2 outside the energy surface, 3 escaped, 0 not computed.
    status: Py<PyAny>,
    /// Per point and set: log10 GALI_k, the stopping time or the MLE, shape (ny, nx, sets).
    per_set: Py<PyAny>,
    /// "spectrum" maps: lambda_1..lambda_k (each the mean over the sets), shape (ny, nx, k),
    /// NaN where no point was integrated; shape (ny, nx, 0) for every other indicator.
    spectrum: Py<PyAny>,
    /// Points present.
    points: usize,
}

impl Map {
    fn new(
        py: Python<'_>,
        path: PathBuf,
        header: &MapHeader,
        points: &[MapPoint],
    ) -> PyResult<Self> {
        let (xa, ya) = (
            header.x.clone().unwrap_or_default(),
            header.y.clone().unwrap_or_default(),
        );
        let (nx, ny, sets) = (xa.n as usize, ya.n as usize, header.sets as usize);
        let exponents = if header.indicator == "spectrum" {
            header.k as usize
        } else {
            0
        };
        // The grids are dense (a value for every grid point and set, NaN where none was
        // computed): a header may describe up to 10^10 points and a million sets, far beyond any
        // file it comes in, so their size is checked against the machine before allocating.
        let bytes =
            (nx as u128 * ny as u128) * (8 * 3 + 4 + 8 * sets as u128 + 8 * exponents as u128);
        if let Some(memory) = Machine::this_host().memory_bytes
            && bytes > u128::from(memory / 2)
        {
            return Err(crate::message(format!(
                "{}: the map's grid ({nx} x {ny} points, {sets} sets) would take {:.1} GiB as \
                 arrays, more than half of this machine's memory",
                path.display(),
                bytes as f64 / (1u64 << 30) as f64
            )));
        }
        let mut x = vec![f64::NAN; nx];
        let mut y = vec![f64::NAN; ny];
        let mut value = vec![f64::NAN; nx * ny];
        let mut mean_log10 = vec![f64::NAN; nx * ny];
        let mut status = vec![0i32; nx * ny];
        let mut per_set = vec![f64::NAN; nx * ny * sets];
        let mut spectrum = vec![f64::NAN; nx * ny * exponents];
        for p in points {
            let (ix, iy) = (p.ix as usize, p.iy as usize);
            if ix >= nx || iy >= ny {
                continue;
            }
            x[ix] = p.x;
            y[iy] = p.y;
            let i = iy * nx + ix;
            value[i] = p.value;
            mean_log10[i] = p.mean_log10;
            status[i] = p.status;
            for (s, v) in p.per_set.iter().take(sets).enumerate() {
                per_set[i * sets + s] = *v;
            }
            for (j, v) in p.spectrum.iter().take(exponents).enumerate() {
                spectrum[i * exponents + j] = *v;
            }
        }
        let grid = |v: Vec<f64>, shape: &[usize]| -> PyResult<Py<PyAny>> {
            Ok(PyArray1::from_vec(py, v)
                .reshape(shape)?
                .into_any()
                .unbind())
        };
        Ok(Self {
            path,
            indicator: header.indicator.clone(),
            method: header.method.clone(),
            k: header.k,
            sets: header.sets,
            t_final: header.t_final,
            x_coord: xa.name().to_string(),
            y_coord: ya.name().to_string(),
            x: grid(x, &[nx])?,
            y: grid(y, &[ny])?,
            value: grid(value, &[ny, nx])?,
            mean_log10: grid(mean_log10, &[ny, nx])?,
            status: PyArray1::from_vec(py, status)
                .reshape([ny, nx])?
                .into_any()
                .unbind(),
            per_set: grid(per_set, &[ny, nx, sets])?,
            spectrum: grid(spectrum, &[ny, nx, exponents])?,
            points: points.len(),
        })
    }
}

#[pymethods]
impl Map {
    fn __repr__(&self) -> String {
        format!(
            "Map({:?}, indicator={:?}, {} x {}, points={})",
            self.path.display().to_string(),
            self.indicator,
            self.x_coord,
            self.y_coord,
            self.points
        )
    }
}

/// Computes the phase-space map described by `config` (a run configuration with a `[map]`
/// section: a dict, a TOML string or a path) with the batched kernel and the scheduler of
/// `chaoscope map`, records it to `out` (default `maps/<run name or "map">.mcap`), and returns
/// the grid. `threads` defaults to one per core. The GIL is released while it runs; Ctrl-C
/// stops it within a renormalization window, leaves a valid file with the points finished so
/// far, and raises `KeyboardInterrupt`. What a killed map of the same configuration left in
/// `out.partial` is resumed; anything else there is refused untouched unless `force=True`.
/// `resume=True` also continues a map of the same configuration at `out` (a map stopped by
/// Ctrl-C), computing only its missing points, as `chaoscope map` does; with it, `force=True`
/// only starts a map the estimate would refuse.
#[pyfunction]
#[pyo3(signature = (config, *, out = None, threads = None, force = false, resume = false))]
pub fn map(
    py: Python<'_>,
    config: &Bound<'_, PyAny>,
    out: Option<PathBuf>,
    threads: Option<usize>,
    force: bool,
    resume: bool,
) -> PyResult<Map> {
    let config_file = crate::config::config_path(config);
    let config = crate::config::run_config(config)?;
    let mut spec = MapSpec::from_config(&config)
        .map_err(|e| crate::message(format!("invalid map configuration: {e}")))?;
    let machine = Machine::this_host();
    let whole = Shard { index: 0, count: 1 };
    let out = out.unwrap_or_else(|| {
        let name = config.run.name.clone().unwrap_or_else(|| "map".into());
        Path::new("maps").join(format!("{name}.mcap"))
    });
    if !force && !resume && is_regular_file(&out) {
        return Err(crate::message(format!(
            "{} already exists (pass resume=True to complete it, force=True to replace it)",
            out.display()
        )));
    }
    // A map that names no route takes the cheaper of two that give its numbers, as `chaoscope
    // map` does.
    let points = spec.grid_points();
    let (estimate, _) = estimate::map_choosing_route(
        &mut spec,
        points,
        &machine,
        threads.unwrap_or(machine.cores).min(machine.cores),
        chaoscope_dynamics::batch::Isa::detect(),
    );
    // A resumed map (or one completing what a killed map left) computes only the points its
    // earlier files lack.
    let resumable = if force && !resume {
        0
    } else {
        // Reading a large earlier map takes a while: Ctrl-C ends the wait at once.
        let (earlier, header) = (out.clone(), spec.header(whole));
        crate::interrupt::abandonable(py, move || resumable_points(&earlier, &header))?
    };
    let estimate = estimate.narrowed_to(points.saturating_sub(resumable), points);
    if let Some(why) = estimate.refusal(&machine)
        && !force
    {
        return Err(crate::message(crate::keyword_arguments(&why)));
    }
    let termination = Termination::new();
    let job = MapJob {
        spec: &spec,
        shard: whole,
        out: &out,
        // `force` replaces what is there (with `resume`, it only starts a map the estimate
        // would refuse); without it, what a killed map left is resumed.
        restart: force && !resume,
        // `resume`: a file at `out` now is this map's earlier part (checked before anything is
        // computed) or refused untouched, as by `chaoscope map`; a file that appears there
        // meanwhile is not replaced.
        replace: (force && !resume) || (resume && out.symlink_metadata().is_ok()),
        create_dir: true,
        inputs: config_file.into_iter().collect(),
        flush_interval: Duration::from_secs(2),
        options: MapOptions {
            threads,
            isa: Isa::detect(),
            termination: Some(termination.clone()),
            ..MapOptions::default()
        },
    };
    let outcome = interruptible(py, || termination.request(), || map_to_file(&job, &mut ()))?
        .map_err(|e| {
            let text = match e {
                MapFileError::Refused(why) => format!("{why}; pass force=True to replace it"),
                e => crate::keyword_arguments(&e.to_string()),
            };
            // What a failed map kept on disk (to be resumed) is named, however it failed.
            let partial = chaoscope_os::output::partial_path(&out);
            let shown = partial.display().to_string();
            if chaoscope_os::output::kept_after_failure().contains(&partial)
                && partial.exists()
                && !text.contains(&shown)
            {
                crate::message(format!("{text}; what was written is kept in {shown}"))
            } else {
                crate::message(text)
            }
        })?;
    Map::new(py, out, &spec.header(whole), &outcome.points)
}

/// Reads a map file written by `chaoscope map`, `chaoscope merge` or `chaoscope.map`; a
/// damaged file raises `ChaoscopeError` naming where it is damaged.
#[pyfunction]
pub fn open_map(py: Python<'_>, path: PathBuf) -> PyResult<Map> {
    // Reading a large map takes a while: Ctrl-C ends the wait at once.
    let read = path.clone();
    let contents = crate::interrupt::abandonable(py, move || read_map_file(&read))?
        .map_err(|e| crate::error(&e))?;
    if let Some(why) = &contents.damaged {
        return Err(crate::message(format!(
            "{}: damaged or cut short ({why}); `chaoscope map` resumes it",
            path.display()
        )));
    }
    // Every value the arrays are sized and indexed by, checked before they are allocated.
    contents
        .check()
        .map_err(|e| crate::message(format!("{}: {e}", path.display())))?;
    let header = contents.header.ok_or_else(|| {
        crate::message(format!(
            "{} holds no readable map header (not a `chaoscope map` recording?)",
            path.display()
        ))
    })?;
    Map::new(py, path, &header, &contents.points)
}
