//! Covariant Lyapunov vectors of a recorded run (`analyze --clv`): the forward pass is the
//! recording (the QR factors of one VM QR scheme's set, recomputed from its separations,
//! `chaoscope_indicators::clv::qr_factors`), the backward pass Ginelli's iteration over the
//! stored `R` factors (`chaoscope_indicators::clv::Backward`), which also gives the CLVs
//! `V_n = Q_n C_n` and, at every renormalization of the kept window, the smallest principal
//! angles between their unstable, neutral and stable subspaces.
//!
//! Memory is bounded: the factors (`R_n` and `Q_n` with the time, one record a
//! renormalization) go into a [`SpillStack`], segments kept in memory up to a budget and the
//! oldest written to an anonymous temporary file beyond it, read back in reverse by the backward
//! pass; the angles' distributions are fixed-size histograms, and their time series (for the
//! CSV) a second stack, popped back into time order.
//!
//! Two transients are discarded: the forward one (the Gram-Schmidt basis converging to the
//! backward Lyapunov vectors: no record is kept before it) and the backward one (the
//! coefficients `C` converging from their arbitrary start at the end of the run: the last
//! renormalizations of the run are stepped through but neither measured nor reported).

use std::collections::{BTreeMap, VecDeque};
use std::fs::File;
use std::io::{Read, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};

use chaoscope_indicators::clv::{self, Backward, ClvError};
use chaoscope_schemas::run::{Method, Orthonormalization, Sample, SystemClass};
use serde::Serialize;

use crate::chart::{Chart, ChartError, Line, Stroke, render};
use crate::recording::{ReadError, RecordingReader};
use crate::run_info::RunInfo;

/// Default memory for the stored factors before they spill to a temporary file.
pub const DEFAULT_MEMORY_BYTES: usize = 256 << 20;

/// Default transients, each a fraction of the run's duration (`t_final`).
pub const DEFAULT_TRANSIENT_FRACTION: f64 = 0.1;

/// What `analyze --clv` is asked.
#[derive(Debug, Clone, PartialEq)]
pub struct ClvOptions {
    /// The scheme (a VM scheme renormalized by QR); `None`: the first such scheme.
    pub scheme: Option<String>,
    /// Which set of the scheme's directions.
    pub set: usize,
    /// Time at the start of the run discarded for the Gram-Schmidt basis to converge;
    /// `None`: [`DEFAULT_TRANSIENT_FRACTION`] of the run.
    pub forward_transient: Option<f64>,
    /// Time at the end of the run discarded for the backward iteration to converge; `None`:
    /// [`DEFAULT_TRANSIENT_FRACTION`] of the run.
    pub backward_transient: Option<f64>,
    /// How many exponents are neutral (the ones nearest zero); `None`: what the dynamics forces
    /// ([`forced_zero_exponents`]).
    pub neutral: Option<usize>,
    /// Memory for the stored factors before they spill to disk (and, with `vectors`, as much
    /// again for the CLVs kept).
    pub memory_bytes: usize,
    /// Keep the CLVs at every renormalization of the window ([`ClvOutput::vectors`]: `analyze
    /// --clv-vectors`, Python's `Recording.clv`).
    pub vectors: bool,
}

impl Default for ClvOptions {
    fn default() -> Self {
        Self {
            scheme: None,
            set: 0,
            forward_transient: None,
            backward_transient: None,
            neutral: None,
            memory_bytes: DEFAULT_MEMORY_BYTES,
            vectors: false,
        }
    }
}

/// The number of Lyapunov exponents among the first `k` of `dim` that the kind of system puts
/// at zero whatever its orbit: none for a map; one for an autonomous flow (along the flow, for a
/// bounded orbit that is not a fixed point), counted only when all `dim` are computed (where
/// it falls among the first `k` depends on the orbit); for an autonomous Hamiltonian the flow
/// direction and, by the symplectic pairing, its partner across the energy shells, exponents
/// `N` and `N + 1` of `2N`, those of them among the first `k`.
pub fn forced_zero_exponents(kind: SystemClass, k: usize, dim: usize) -> usize {
    match kind {
        SystemClass::Map => 0,
        SystemClass::Flow => usize::from(k == dim),
        SystemClass::Hamiltonian => (k + 1).saturating_sub(dim / 2).min(2),
    }
}

/// Why the CLVs of a recording cannot be computed.
#[derive(Debug, thiserror::Error)]
pub enum ClvRunError {
    #[error(transparent)]
    Read(#[from] ReadError),
    #[error("--clv: {0}")]
    Setup(String),
    #[error("--clv: at t = {t}: {error}")]
    Numerics { t: f64, error: ClvError },
    #[error("--clv: the temporary file of the stored QR factors: {0}")]
    Spill(std::io::Error),
    #[error("--clv: stopped")]
    Stopped,
}

/// The distribution of one angle over the kept window (radians).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct AngleStats {
    pub count: u64,
    pub min: f64,
    pub max: f64,
    pub mean: f64,
    /// `(p, angle)`: the angle below which a fraction `p` of the renormalizations lie, from
    /// a histogram of 100 bins per decade (2.3 % relative resolution), within `[min, max]`.
    pub quantiles: Vec<(f64, f64)>,
    /// Counts in bins of 10 per decade of the angle, the first bin starting at
    /// `10^log10_start` (angles below 1e-16 rad, zero included, counted in the first).
    pub histogram: Histogram,
}

#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Histogram {
    pub log10_start: f64,
    pub bins_per_decade: u32,
    pub counts: Vec<u64>,
}

/// What `analyze --clv` reports.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ClvReport {
    pub scheme: String,
    pub set: usize,
    /// CLVs computed (`k`, the scheme's vectors: the first `k` CLVs) and the dimension.
    pub k: usize,
    pub dim: usize,
    pub forward_transient: f64,
    pub backward_transient: f64,
    /// The kept window `[t_start, t_end]`: growth rates over it, angles at its
    /// renormalizations.
    pub t_start: f64,
    pub t_end: f64,
    pub renormalizations: u64,
    /// Each CLV's growth rate over the window.
    pub growth_rates: Vec<f64>,
    /// The QR (Benettin) spectrum over the same window, `sum ln R_jj / (t_end - t_start)`.
    pub qr_spectrum: Vec<f64>,
    /// The QR spectrum of the whole recording, from its recorded stretching factors.
    pub qr_spectrum_run: Vec<f64>,
    /// `unstable`, `neutral` or `stable`, per CLV: the `neutral` exponents nearest zero (of
    /// the QR spectrum after the forward transient) are neutral, the rest by sign.
    pub classes: Vec<&'static str>,
    pub neutral: usize,
    /// Largest relative difference between a recomputed `R_jj` and the recorded stretching
    /// factor (0: the recomputed factorization is the producer's, bit for bit).
    pub stretch_max_relative_difference: f64,
    /// Bytes of factors written to the temporary file (0: all in memory).
    pub spilled_bytes: u64,
    /// Smallest principal angle between subspaces, by name: `unstable_vs_rest` (the unstable
    /// subspace against neutral + stable), `expanding_vs_contracting` (unstable + neutral
    /// against stable, Kuptsov's angle test), and with a neutral subspace
    /// `unstable_vs_neutral`, `unstable_vs_stable`, `neutral_vs_stable`; each present when
    /// both sides are non-empty.
    pub angles: BTreeMap<String, AngleStats>,
}

/// Records of `len` values pushed in order and popped in reverse, kept in memory up to a
/// budget, the oldest segments written to an anonymous temporary file beyond it.
pub struct SpillStack {
    record_len: usize,
    segment_len: usize,
    max_memory_segments: usize,
    memory: VecDeque<Vec<f64>>,
    current: Vec<f64>,
    file: Option<File>,
    /// Byte offsets of the spilled segments, oldest first.
    spilled: Vec<u64>,
    spilled_bytes: u64,
}

impl SpillStack {
    pub fn new(record_len: usize, memory_bytes: usize) -> Self {
        let record_len = record_len.max(1);
        // Segments of about 64 KiB, whole records.
        let records = (8192 / record_len).max(1);
        let segment_len = records * record_len;
        Self {
            record_len,
            segment_len,
            max_memory_segments: (memory_bytes / (8 * segment_len)).max(1),
            memory: VecDeque::new(),
            current: Vec::with_capacity(segment_len),
            file: None,
            spilled: Vec::new(),
            spilled_bytes: 0,
        }
    }

    pub fn push(&mut self, record: &[f64]) -> std::io::Result<()> {
        debug_assert_eq!(record.len(), self.record_len);
        self.current.extend_from_slice(record);
        if self.current.len() >= self.segment_len {
            let full = std::mem::replace(&mut self.current, Vec::with_capacity(self.segment_len));
            self.memory.push_back(full);
            if self.memory.len() > self.max_memory_segments {
                let oldest = self.memory.pop_front().expect("more than one");
                self.spill(&oldest)?;
            }
        }
        Ok(())
    }

    fn spill(&mut self, segment: &[f64]) -> std::io::Result<()> {
        let file = match &mut self.file {
            Some(f) => f,
            None => self.file.insert(tempfile::tempfile()?),
        };
        let offset = file.seek(SeekFrom::End(0))?;
        let bytes: Vec<u8> = segment.iter().flat_map(|x| x.to_le_bytes()).collect();
        file.write_all(&bytes)?;
        self.spilled.push(offset);
        self.spilled_bytes += bytes.len() as u64;
        Ok(())
    }

    /// The latest record not yet popped into `out`; `false` when none is left.
    pub fn pop(&mut self, out: &mut [f64]) -> std::io::Result<bool> {
        if self.current.is_empty() {
            if let Some(segment) = self.memory.pop_back() {
                self.current = segment;
            } else if let Some(offset) = self.spilled.pop() {
                let file = self.file.as_mut().expect("spilled segments have a file");
                file.seek(SeekFrom::Start(offset))?;
                let mut bytes = vec![0u8; 8 * self.segment_len];
                file.read_exact(&mut bytes)?;
                // Give the disk back as the pass goes.
                file.set_len(offset)?;
                self.current = bytes
                    .chunks_exact(8)
                    .map(|b| f64::from_le_bytes(b.try_into().expect("8 bytes")))
                    .collect();
            } else {
                return Ok(false);
            }
        }
        let n = self.current.len();
        out.copy_from_slice(&self.current[n - self.record_len..]);
        self.current.truncate(n - self.record_len);
        Ok(true)
    }

    pub fn spilled_bytes(&self) -> u64 {
        self.spilled_bytes
    }
}

/// Log-binned counts of an angle with its exact extremes and mean.
struct AngleAccumulator {
    counts: Vec<u64>,
    count: u64,
    min: f64,
    max: f64,
    sum: f64,
}

const LOG10_LOW: f64 = -16.0;
const FINE_PER_DECADE: usize = 100;
/// Up to 10^0.2 > pi/2.
const FINE_BINS: usize = (16.2 * FINE_PER_DECADE as f64) as usize;
const QUANTILES: [f64; 8] = [0.001, 0.01, 0.05, 0.25, 0.5, 0.75, 0.95, 0.99];

impl AngleAccumulator {
    fn new() -> Self {
        Self {
            counts: vec![0; FINE_BINS],
            count: 0,
            min: f64::INFINITY,
            max: f64::NEG_INFINITY,
            sum: 0.0,
        }
    }

    fn bin(angle: f64) -> usize {
        if angle <= 0.0 {
            return 0;
        }
        let x = (angle.log10() - LOG10_LOW) * FINE_PER_DECADE as f64;
        (x.max(0.0) as usize).min(FINE_BINS - 1)
    }

    fn add(&mut self, angle: f64) {
        self.counts[Self::bin(angle)] += 1;
        self.count += 1;
        self.min = self.min.min(angle);
        self.max = self.max.max(angle);
        self.sum += angle;
    }

    fn stats(&self) -> AngleStats {
        let edge = |i: usize| 10f64.powf(LOG10_LOW + i as f64 / FINE_PER_DECADE as f64);
        let quantiles = QUANTILES
            .iter()
            .map(|&p| {
                let target = p * self.count as f64;
                let mut below = 0u64;
                let mut value = self.max;
                for (i, &c) in self.counts.iter().enumerate() {
                    if c > 0 && (below + c) as f64 >= target {
                        // Log-linear within the bin.
                        let f = ((target - below as f64) / c as f64).clamp(0.0, 1.0);
                        value = edge(i) * (edge(i + 1) / edge(i)).powf(f);
                        break;
                    }
                    below += c;
                }
                (p, value.clamp(self.min, self.max))
            })
            .collect();
        let coarse = FINE_PER_DECADE / 10;
        let mut counts: Vec<u64> = self.counts.chunks(coarse).map(|c| c.iter().sum()).collect();
        let first = counts.iter().position(|&c| c > 0).unwrap_or(0);
        let last = counts.iter().rposition(|&c| c > 0).map_or(0, |i| i + 1);
        counts = counts[first..last.max(first)].to_vec();
        AngleStats {
            count: self.count,
            min: self.min,
            max: self.max,
            mean: self.sum / self.count as f64,
            quantiles,
            histogram: Histogram {
                log10_start: LOG10_LOW + first as f64 / 10.0,
                bins_per_decade: 10,
                counts,
            },
        }
    }
}

/// The angle time series of the window in time order, for a CSV.
pub struct AngleSeries {
    pub names: Vec<String>,
    /// Rows `t, angle...`, pushed from the end of the window back: popped in time order.
    rows: SpillStack,
}

impl AngleSeries {
    /// Writes `<dir>/clv-angles.csv` (`t` and one column per angle, radians, in time order;
    /// through `chaoscope_os::output`, never over one of `inputs`); returns its path.
    pub fn write_csv(mut self, dir: &Path, inputs: &[PathBuf]) -> std::io::Result<PathBuf> {
        std::fs::create_dir_all(dir)?;
        let options = crate::csv::table_options(inputs);
        let io = crate::csv::io;
        let output =
            chaoscope_os::Output::create(&dir.join("clv-angles.csv"), &options).map_err(io)?;
        let mut f = std::io::BufWriter::new(output.file().map_err(io)?);
        // With one subspace class (every exponent positive, say) there is no angle: the
        // header is `t` alone, never a column without a name.
        let header: Vec<&str> = std::iter::once("t")
            .chain(self.names.iter().map(String::as_str))
            .collect();
        writeln!(f, "{}", header.join(","))?;
        let mut row = vec![0.0; 1 + self.names.len()];
        while self.rows.pop(&mut row)? {
            let cells: Vec<String> = row.iter().map(f64::to_string).collect();
            writeln!(f, "{}", cells.join(","))?;
        }
        f.flush()?;
        drop(f);
        output.commit().map_err(io)
    }

    /// The next row `t, angle...` in time order into `row` (`1 + names.len()` values); `false`
    /// when none is left.
    pub fn next_row(&mut self, row: &mut [f64]) -> std::io::Result<bool> {
        self.rows.pop(row)
    }
}

/// The CLVs at every renormalization of the window, in time order (at the times of the angle
/// series, row for row), for `analyze --clv-vectors` and Python.
pub struct VectorSeries {
    k: usize,
    dim: usize,
    len: usize,
    /// Rows `t, v_1 (dim values), ..., v_k`, pushed from the end of the window back.
    rows: SpillStack,
}

impl VectorSeries {
    /// CLVs per row.
    pub fn k(&self) -> usize {
        self.k
    }

    /// Entries per vector (the phase-space dimension).
    pub fn dim(&self) -> usize {
        self.dim
    }

    /// Rows left.
    pub fn len(&self) -> usize {
        self.len
    }

    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// The next row in time order: its time, and into `vectors` the `k` unit CLVs one after
    /// the other (`k * dim` values); `None` when none is left.
    pub fn next_row(&mut self, vectors: &mut [f64]) -> std::io::Result<Option<f64>> {
        let mut row = vec![0.0; 1 + self.k * self.dim];
        if !self.rows.pop(&mut row)? {
            return Ok(None);
        }
        self.len -= 1;
        vectors.copy_from_slice(&row[1..]);
        Ok(Some(row[0]))
    }

    /// Writes `<dir>/clv-vectors.npy` (doubles of shape `(rows, k, dim)`: `[n, j]` is CLV `j +
    /// 1` at row `n`, a unit vector) and `<dir>/clv-times.npy` (shape `(rows,)`, the rows'
    /// times, those of `clv-angles.csv`), NumPy's own format, each complete or not at all,
    /// never over one of `inputs`; returns their paths.
    pub fn write_npy(mut self, dir: &Path, inputs: &[PathBuf]) -> std::io::Result<Vec<PathBuf>> {
        // Said plainly rather than as the "File exists" of creating it.
        if dir.exists() && !dir.is_dir() {
            return Err(std::io::Error::other("not a directory"));
        }
        std::fs::create_dir_all(dir)?;
        let options = crate::csv::table_options(inputs);
        let io = crate::csv::io;
        let (rows, k, dim) = (self.len, self.k, self.dim);
        let output =
            chaoscope_os::Output::create(&dir.join("clv-vectors.npy"), &options).map_err(io)?;
        let mut f = std::io::BufWriter::new(output.file().map_err(io)?);
        f.write_all(&crate::npy::header(&[rows, k, dim]))?;
        let mut times = Vec::with_capacity(rows);
        let mut v = vec![0.0; k * dim];
        while let Some(t) = self.next_row(&mut v)? {
            times.push(t);
            crate::npy::write_values(&mut f, &v)?;
        }
        f.flush()?;
        drop(f);
        let vectors = output.commit().map_err(io)?;
        let output =
            chaoscope_os::Output::create(&dir.join("clv-times.npy"), &options).map_err(io)?;
        let mut f = std::io::BufWriter::new(output.file().map_err(io)?);
        f.write_all(&crate::npy::header(&[times.len()]))?;
        crate::npy::write_values(&mut f, &times)?;
        f.flush()?;
        drop(f);
        Ok(vec![vectors, output.commit().map_err(io)?])
    }
}

/// What the CLV analysis of a run gives: the report, the angle series, and where asked for
/// ([`ClvOptions::vectors`]) the vectors.
pub struct ClvOutput {
    pub report: ClvReport,
    pub angles: AngleSeries,
    pub vectors: Option<VectorSeries>,
}

/// The stream of one scheme's set: fed samples in order ([`ClvAnalysis::feed`]), then the
/// backward pass ([`ClvAnalysis::finish`]).
pub struct ClvAnalysis {
    scheme: usize,
    scheme_name: String,
    set: u32,
    dim: usize,
    k: usize,
    d0: f64,
    kind: SystemClass,
    neutral: Option<usize>,
    forward_transient: f64,
    backward_transient: f64,
    memory_bytes: usize,
    keep_vectors: bool,
    factors: SpillStack,
    /// Time of the scheme's first renormalization, and its latest.
    t_first: Option<f64>,
    t_last: f64,
    /// Recorded `sum ln stretch` after the first renormalization.
    run_log_sums: Vec<f64>,
    /// `sum ln R_jj` over the stored factors after the first one.
    kept_log_sums: Vec<f64>,
    t_kept: Option<f64>,
    stored: u64,
    stretch_difference: f64,
}

impl ClvAnalysis {
    pub fn new(run: &RunInfo, options: &ClvOptions) -> Result<Self, ClvRunError> {
        let setup = |m: String| ClvRunError::Setup(m);
        let is_vm_qr = |s: &chaoscope_schemas::run::SchemeSpec| {
            s.method == Method::Vm && s.orthonormalize == Orthonormalization::Qr
        };
        let scheme = match &options.scheme {
            Some(name) => {
                let i = run.scheme_index(name).ok_or_else(|| {
                    setup(format!(
                        "no scheme '{name}' in the recording (it has {})",
                        run.schemes
                            .iter()
                            .map(|s| s.name.as_str())
                            .collect::<Vec<_>>()
                            .join(", ")
                    ))
                })?;
                if !is_vm_qr(&run.schemes[i]) {
                    return Err(setup(format!(
                        "scheme '{name}' is {} with {}: the CLVs need a variational (vm) scheme \
                         renormalized by QR (orthonormalize = \"qr\")",
                        run.schemes[i].method.name(),
                        run.schemes[i].orthonormalize.name()
                    )));
                }
                i
            }
            None => run.schemes.iter().position(is_vm_qr).ok_or_else(|| {
                setup(
                    "the recording has no variational (vm) scheme renormalized by QR \
                     (orthonormalize = \"qr\"), which the CLVs are computed from"
                        .into(),
                )
            })?,
        };
        if options.set >= run.sets {
            return Err(setup(format!(
                "--clv-set {}: the run has {} sets",
                options.set, run.sets
            )));
        }
        if let Some(n) = options.neutral
            && n > run.k
        {
            return Err(setup(format!(
                "--clv-neutral {n}: only k = {} exponents are computed",
                run.k
            )));
        }
        let duration = run.header.t_final;
        let transient = |given: Option<f64>, flag: &str| match given {
            Some(t) if t.is_finite() && t >= 0.0 => Ok(t),
            Some(t) => Err(setup(format!(
                "{flag} {t}: a transient is a time, finite and not negative"
            ))),
            None => Ok(DEFAULT_TRANSIENT_FRACTION * duration),
        };
        let forward_transient = transient(options.forward_transient, "--clv-forward-transient")?;
        let backward_transient = transient(options.backward_transient, "--clv-backward-transient")?;
        let (dim, k) = (run.dim, run.k);
        Ok(Self {
            scheme,
            scheme_name: run.schemes[scheme].name.clone(),
            set: options.set as u32,
            dim,
            k,
            d0: run.schemes[scheme].d0,
            kind: run.kind,
            neutral: options.neutral,
            forward_transient,
            backward_transient,
            memory_bytes: options.memory_bytes,
            keep_vectors: options.vectors,
            factors: SpillStack::new(1 + clv::packed_len(k) + dim * k, options.memory_bytes),
            t_first: None,
            t_last: f64::NAN,
            run_log_sums: vec![0.0; k],
            kept_log_sums: vec![0.0; k],
            t_kept: None,
            stored: 0,
            stretch_difference: 0.0,
        })
    }

    /// Takes the next sample of the run (in order); samples where the scheme does not
    /// renormalize are passed over.
    pub fn feed(&mut self, sample: &Sample) -> Result<(), ClvRunError> {
        let Some(s) = sample
            .schemes
            .iter()
            .find(|s| s.scheme as usize == self.scheme && s.set == self.set)
        else {
            return Ok(());
        };
        let t = sample.t;
        // The backward pass needs every renormalization's factors, which a recording sampled
        // every `sample_every` keeps only at its samples.
        if !s.earlier_stretch.is_empty() {
            return Err(ClvRunError::Setup(format!(
                "the recording is sampled every [run] sample_every (at t = {t} it carries {} \
                 renormalizations only as stretching factors): covariant vectors need every \
                 renormalization's vectors; run it without sample_every",
                s.earlier_stretch.len() / self.k.max(1)
            )));
        }
        let numerics = |error| ClvRunError::Numerics { t, error };
        let (q, r) =
            clv::qr_factors(&s.separations, self.dim, self.k, self.d0).map_err(numerics)?;
        let diag = clv::diagonal(&r, self.k);
        let t_first = *self.t_first.get_or_insert(t);
        // The first renormalization (step 0) records the initial directions with a unit
        // stretching by convention, not a factorization.
        if t > t_first {
            for (d, recorded) in diag.iter().zip(&s.stretch) {
                let rel = (d - recorded).abs() / recorded.abs();
                self.stretch_difference = self.stretch_difference.max(rel);
            }
            for (sum, f) in self.run_log_sums.iter_mut().zip(&s.stretch) {
                *sum += f.ln();
            }
        }
        self.t_last = t;
        if t - t_first < self.forward_transient {
            return Ok(());
        }
        if self.t_kept.is_some() {
            for (sum, d) in self.kept_log_sums.iter_mut().zip(&diag) {
                *sum += d.ln();
            }
        } else {
            self.t_kept = Some(t);
        }
        let mut record = Vec::with_capacity(1 + r.len() + q.len());
        record.push(t);
        record.extend_from_slice(&r);
        record.extend_from_slice(&q);
        self.factors.push(&record).map_err(ClvRunError::Spill)?;
        self.stored += 1;
        Ok(())
    }

    /// The backward pass: growth rates, classes, angle distributions, the angle series, and
    /// where asked for the vectors.
    pub fn finish(mut self) -> Result<ClvOutput, ClvRunError> {
        let setup = |m: String| ClvRunError::Setup(m);
        let (Some(t_first), Some(t_kept)) = (self.t_first, self.t_kept) else {
            return Err(setup(format!(
                "scheme '{}' has no renormalization after the forward transient ({}); \
                 record longer or pass a shorter --clv-forward-transient",
                self.scheme_name, self.forward_transient
            )));
        };
        let t_end_limit = self.t_last - self.backward_transient;
        if self.stored < 3 || t_end_limit <= t_kept {
            return Err(setup(format!(
                "too few renormalizations of scheme '{}' between the transients (forward {} \
                 from t = {t_first}, backward {} from t = {}): record longer or shorten them \
                 (--clv-forward-transient, --clv-backward-transient)",
                self.scheme_name, self.forward_transient, self.backward_transient, self.t_last
            )));
        }
        let (k, dim) = (self.k, self.dim);
        // Classes from the QR spectrum after the forward transient (the CLVs' growth rates
        // are its values, which the backward pass only yields at its end).
        let kept_spectrum: Vec<f64> = self
            .kept_log_sums
            .iter()
            .map(|s| s / (self.t_last - t_kept))
            .collect();
        let neutral = self
            .neutral
            .unwrap_or_else(|| forced_zero_exponents(self.kind, k, dim));
        let mut by_size: Vec<usize> = (0..k).collect();
        by_size.sort_by(|&a, &b| kept_spectrum[a].abs().total_cmp(&kept_spectrum[b].abs()));
        let mut classes = vec![""; k];
        for (rank, &j) in by_size.iter().enumerate() {
            classes[j] = if rank < neutral {
                "neutral"
            } else if kept_spectrum[j] > 0.0 {
                "unstable"
            } else {
                "stable"
            };
        }
        let members =
            |class: &str| -> Vec<usize> { (0..k).filter(|&j| classes[j] == class).collect() };
        let (unstable, neutral_set, stable) =
            (members("unstable"), members("neutral"), members("stable"));
        let union = |a: &[usize], b: &[usize]| -> Vec<usize> {
            let mut u: Vec<usize> = a.iter().chain(b).copied().collect();
            u.sort_unstable();
            u
        };
        // Kuptsov's angle test compares the expanding subspace (the CLVs of the positive and
        // zero exponents: for a flow the flow direction belongs to it) with the contracting
        // one; without a neutral subspace it is `unstable_vs_rest` again.
        let mut pairs: Vec<(&str, Vec<usize>, Vec<usize>)> = vec![
            (
                "unstable_vs_rest",
                unstable.clone(),
                union(&neutral_set, &stable),
            ),
            (
                "expanding_vs_contracting",
                union(&unstable, &neutral_set),
                stable.clone(),
            ),
        ];
        if !neutral_set.is_empty() {
            pairs.push(("unstable_vs_neutral", unstable.clone(), neutral_set.clone()));
            pairs.push(("unstable_vs_stable", unstable.clone(), stable.clone()));
            pairs.push(("neutral_vs_stable", neutral_set.clone(), stable.clone()));
        }
        pairs.retain(|(_, a, b)| !a.is_empty() && !b.is_empty());
        let names: Vec<String> = pairs.iter().map(|(n, _, _)| n.to_string()).collect();
        let mut accumulators: Vec<AngleAccumulator> =
            pairs.iter().map(|_| AngleAccumulator::new()).collect();
        let mut series = SpillStack::new(1 + pairs.len(), self.memory_bytes / 8);
        let mut vectors = self
            .keep_vectors
            .then(|| SpillStack::new(1 + dim * k, self.memory_bytes));

        let mut backward = Backward::new(k);
        let mut record = vec![0.0; 1 + clv::packed_len(k) + dim * k];
        let mut window_log_sums = vec![0.0; k];
        let mut t_end = None;
        let mut count = 0u64;
        let gather = |v: &[f64], idx: &[usize]| -> Vec<f64> {
            idx.iter()
                .flat_map(|&j| v[j * dim..(j + 1) * dim].iter().copied())
                .collect()
        };
        let mut remaining = self.stored;
        while self.factors.pop(&mut record).map_err(ClvRunError::Spill)? {
            remaining -= 1;
            let t = record[0];
            let r = &record[1..1 + clv::packed_len(k)];
            let q = &record[1 + clv::packed_len(k)..];
            let in_window = t <= t_end_limit;
            if in_window {
                t_end.get_or_insert(t);
                count += 1;
                let v = backward.vectors(q, dim);
                let mut row = vec![t];
                for ((_, a, b), acc) in pairs.iter().zip(&mut accumulators) {
                    let angle = clv::min_principal_angle(&gather(&v, a), &gather(&v, b), dim);
                    acc.add(angle);
                    row.push(angle);
                }
                series.push(&row).map_err(ClvRunError::Spill)?;
                if let Some(stack) = &mut vectors {
                    row.clear();
                    row.push(t);
                    row.extend_from_slice(&v);
                    stack.push(&row).map_err(ClvRunError::Spill)?;
                }
            }
            // The window from the previous record to this one: stepped back through unless this
            // is the first record kept (t_kept), measured when it lies in [t_kept, t_end].
            if remaining > 0 {
                backward
                    .step(r, in_window)
                    .map_err(|error| ClvRunError::Numerics { t, error })?;
                if in_window {
                    for (sum, d) in window_log_sums.iter_mut().zip(clv::diagonal(r, k)) {
                        *sum += d.ln();
                    }
                }
            }
        }
        let t_end = t_end.expect("t_end_limit > t_kept: a record lies in the window");
        let span = t_end - t_kept;
        if span.partial_cmp(&0.0) != Some(std::cmp::Ordering::Greater) {
            return Err(setup(format!(
                "the window between the transients holds a single renormalization (t = \
                 {t_end}); shorten --clv-forward-transient or --clv-backward-transient"
            )));
        }
        let rate = |s: &f64| s / span;
        let report = ClvReport {
            scheme: self.scheme_name,
            set: self.set as usize,
            k,
            dim,
            forward_transient: self.forward_transient,
            backward_transient: self.backward_transient,
            t_start: t_kept,
            t_end,
            renormalizations: count,
            growth_rates: backward.log_growth().iter().map(rate).collect(),
            qr_spectrum: window_log_sums.iter().map(rate).collect(),
            qr_spectrum_run: self
                .run_log_sums
                .iter()
                .map(|s| s / (self.t_last - t_first))
                .collect(),
            classes,
            neutral,
            stretch_max_relative_difference: self.stretch_difference,
            spilled_bytes: self.factors.spilled_bytes(),
            angles: names
                .iter()
                .cloned()
                .zip(accumulators.iter().map(AngleAccumulator::stats))
                .collect(),
        };
        Ok(ClvOutput {
            report,
            angles: AngleSeries {
                names,
                rows: series,
            },
            vectors: vectors.map(|rows| VectorSeries {
                k,
                dim,
                len: count as usize,
                rows,
            }),
        })
    }
}

/// The CLVs of the recording at `path` (one pass through the file, then the backward pass).
pub fn clv_of_file(path: &Path, options: &ClvOptions) -> Result<ClvOutput, ClvRunError> {
    clv_of_file_until(path, options, &|| false)
}

/// [`clv_of_file`], given up (as [`ClvRunError::Stopped`]) at the first sample read once `stop`
/// says so (Python's Ctrl-C).
pub fn clv_of_file_until(
    path: &Path,
    options: &ClvOptions,
    stop: &dyn Fn() -> bool,
) -> Result<ClvOutput, ClvRunError> {
    let mut reader = RecordingReader::open(path)?;
    let mut analysis = ClvAnalysis::new(reader.run(), options)?;
    while let Some(sample) = reader.next_sample()? {
        if stop() {
            return Err(ClvRunError::Stopped);
        }
        analysis.feed(&sample)?;
    }
    analysis.finish()
}

/// The chart of one angle's distribution over the window: the fraction of the renormalizations
/// in each bin of its histogram (10 bins per decade of the angle, log10 on the x axis, drawn as
/// steps), with the median as a dashed line.
pub fn angle_histogram_chart(report: &ClvReport, name: &str, stats: &AngleStats) -> Chart {
    let h = &stats.histogram;
    let width = 1.0 / f64::from(h.bins_per_decade);
    let edge = |i: usize| h.log10_start + i as f64 * width;
    let total = stats.count.max(1) as f64;
    let mut steps = vec![(edge(0), 0.0)];
    for (i, &c) in h.counts.iter().enumerate() {
        let fraction = c as f64 / total;
        steps.push((edge(i), fraction));
        steps.push((edge(i + 1), fraction));
    }
    steps.push((edge(h.counts.len()), 0.0));
    let peak = steps.iter().map(|p| p.1).fold(0.0, f64::max);
    // Unlabelled (no legend box over the bins, which crowd the right end for angles near
    // pi/2): the title names the angle and the dashed line.
    let mut lines = vec![Line {
        label: String::new(),
        points: steps,
        stroke: Stroke::Solid,
        color: 2,
    }];
    let median = stats
        .quantiles
        .iter()
        .find(|(p, _)| *p == 0.5)
        .map(|&(_, m)| m)
        .filter(|m| *m > 0.0);
    if let Some(median) = median {
        lines.push(Line {
            label: String::new(),
            points: vec![(median.log10(), 0.0), (median.log10(), peak)],
            stroke: Stroke::Dashed,
            color: 1,
        });
    }
    Chart {
        title: format!(
            "Angle between the {} CLV subspaces (scheme {}, set {}){}",
            angle_words(name),
            report.scheme,
            report.set,
            median.map_or(String::new(), |m| format!(
                ", dashed: median {} rad",
                crate::chart::tick_label(m, (0.0, m))
            ))
        ),
        x_label: "log10 angle (rad)".into(),
        y_label: format!("fraction of {} renormalizations per bin", stats.count),
        lines,
        ..Default::default()
    }
}

/// An angle's name in words for a title: `unstable_vs_rest` is "unstable and
/// neutral + stable".
fn angle_words(name: &str) -> String {
    match name {
        "unstable_vs_rest" => "unstable and neutral + stable".into(),
        "expanding_vs_contracting" => "expanding and contracting".into(),
        other => other.replace("_vs_", " and ").replace('_', " "),
    }
}

/// Draws the distribution of every angle of `report` ([`angle_histogram_chart`]) as
/// `<dir>/clv-angle-<name>.png` and `.svg`, as every chart is written (never over one of
/// `inputs`); returns the files written.
pub fn plot_angle_histograms(
    report: &ClvReport,
    dir: &Path,
    inputs: &[PathBuf],
) -> Result<Vec<PathBuf>, ChartError> {
    std::fs::create_dir_all(dir).map_err(|e| ChartError::Draw {
        path: dir.to_path_buf(),
        message: e.to_string(),
    })?;
    let mut files = Vec::new();
    for (name, stats) in &report.angles {
        let chart = angle_histogram_chart(report, name, stats);
        files.extend(render(
            &chart,
            &dir.join(format!("clv-angle-{name}")),
            inputs,
        )?);
    }
    Ok(files)
}

/// The report as text, for `analyze --clv`.
pub fn summary(r: &ClvReport) -> String {
    let mut s = format!(
        "covariant Lyapunov vectors of scheme {} (set {}): {} of dimension {}, over t = {} .. {} \
         ({} renormalizations; transients {} forward, {} backward)\n",
        r.scheme,
        r.set,
        r.k,
        r.dim,
        r.t_start,
        r.t_end,
        r.renormalizations,
        r.forward_transient,
        r.backward_transient
    );
    s.push_str("  CLV  class      growth rate     QR spectrum     difference\n");
    for j in 0..r.k {
        s.push_str(&format!(
            "  {:<4} {:<10} {:>14.6e} {:>14.6e} {:>14.3e}\n",
            j + 1,
            r.classes[j],
            r.growth_rates[j],
            r.qr_spectrum[j],
            r.growth_rates[j] - r.qr_spectrum[j]
        ));
    }
    s.push_str(&format!(
        "  recomputed R_jj against the recorded stretching: max relative difference {:e}{}\n",
        r.stretch_max_relative_difference,
        if r.spilled_bytes > 0 {
            format!("; {} bytes of factors spilled to disk", r.spilled_bytes)
        } else {
            String::new()
        }
    ));
    s.push_str("  smallest principal angles (rad):\n");
    s.push_str(&format!(
        "    {:<28} {:>10} {:>10} {:>10} {:>10} {:>10} {:>10}\n",
        "", "min", "q0.001", "q0.01", "q0.05", "median", "max"
    ));
    for (name, a) in &r.angles {
        let q = |p: f64| {
            a.quantiles
                .iter()
                .find(|(x, _)| *x == p)
                .map_or(f64::NAN, |(_, v)| *v)
        };
        s.push_str(&format!(
            "    {:<28} {:>10.3e} {:>10.3e} {:>10.3e} {:>10.3e} {:>10.3e} {:>10.3e}\n",
            name,
            a.min,
            q(0.001),
            q(0.01),
            q(0.05),
            q(0.5),
            a.max
        ));
    }
    s
}

#[cfg(test)]
mod angle_csv_tests {
    use super::*;

    fn written(names: &[&str], rows: &[Vec<f64>]) -> String {
        let dir = std::env::temp_dir().join(format!(
            "chaoscope-clv-csv-{}-{}",
            std::process::id(),
            names.len()
        ));
        let _ = std::fs::remove_dir_all(&dir);
        let mut stack = SpillStack::new(1 + names.len(), 1 << 20);
        // Pushed from the end back, as the backward pass does.
        for row in rows.iter().rev() {
            stack.push(row).unwrap();
        }
        let series = AngleSeries {
            names: names.iter().map(|n| n.to_string()).collect(),
            rows: stack,
        };
        let path = series.write_csv(&dir, &[]).unwrap();
        let text = std::fs::read_to_string(path).unwrap();
        std::fs::remove_dir_all(&dir).unwrap();
        text
    }

    #[test]
    fn every_column_of_the_angle_csv_has_a_name() {
        // One subspace class: no angle, and the header is `t` alone, one column as every row.
        let text = written(&[], &[vec![1.0], vec![2.0]]);
        assert_eq!(text, "t\n1\n2\n");
        let text = written(&["unstable_vs_rest"], &[vec![1.0, 0.5]]);
        assert_eq!(text, "t,unstable_vs_rest\n1,0.5\n");
        for line in text.lines() {
            assert!(line.split(',').all(|cell| !cell.is_empty()), "{text}");
        }
    }
}
