//! The streaming analysis core, sans-io: fed with a run header and samples (from the engine in
//! process, from an MCAP file, or from the bus), it keeps O(schemes x sets x k x 2N) state plus
//! bounded time series, so memory does not depend on the length of the run.
//!
//! Per (scheme, set) the indicator tracker of `chaoscope-indicators` keeps the accumulated
//! logarithmic stretching (Lyapunov exponents) and the latest separation vectors; GALI and SALI
//! are computed from those only when a value is asked for (a series point, a report), since they
//! are instantaneous functions of the vectors. The recorder writes the indicators channel of
//! every recording with the same tracker, so the values agree to the last bit.

use std::sync::Arc;

pub use chaoscope_indicators::tracker::ZeroOneObservable;
pub use chaoscope_indicators::zero_one::ObservableFn;
pub use chaoscope_indicators::{FlowField, SiteEnergies};
use chaoscope_indicators::{SchemeIndicators, Tracker};
use chaoscope_schemas::run::{
    Method, Orthonormalization, Sample, SchemeSample, SchemeSpec, SystemClass,
};

pub use chaoscope_indicators::SetValues;

use chaoscope_schemas::proto::{EndOfRun, end_of_run};

use crate::report::{ByOrder, DeltaLog, Report, RunReport, SchemeReport, VsVm};
use crate::run_info::RunInfo;
use crate::series::{SchemePoint, Series};
use crate::site_profiles::SiteProfiles;
use crate::stats::Stat;
use crate::verdict;

/// Resolution of the stored time series.
#[derive(Debug, Clone)]
pub struct AnalysisOptions {
    /// Evenly spaced points kept per series.
    pub series_capacity: usize,
    /// Log-spaced points per decade of time.
    pub per_decade: usize,
    /// Times at which to keep a full report ("values at time T").
    pub at: Vec<f64>,
    /// Where the system's vector field comes from, for the indicators that need the flow
    /// direction (OFLI): the analyzer runs no engine, so the caller that has one (the binary,
    /// Python: `chaoscope_app::flow::flow_field_of_run`) says how to rebuild it from the
    /// run's header. `None`: those indicators report themselves unavailable.
    pub flow_field: Option<FlowSource>,
    /// Where the energy of each site of a lattice Hamiltonian comes from, for the energy
    /// distribution (`energy_m2`, `energy_participation`): as `flow_field`, from the caller
    /// that can rebuild the model (`chaoscope_app::flow::site_energies_of_run`). `None`:
    /// those outputs report themselves unavailable.
    pub site_energies: Option<SiteEnergySource>,
    /// Where a run's `[analysis] zero_one_observable` (an expression of the state) is compiled,
    /// as `flow_field`, by the caller that can rebuild the system
    /// (`chaoscope_app::flow::zero_one_observable_of_run`). `None`, or a run whose system
    /// cannot be rebuilt here: the 0-1 test of such a run says why it is unavailable (never a
    /// value of another observable). A run without the key needs none of it.
    pub zero_one_observable: Option<ObservableSource>,
    /// Keep the distributions over the sites over time (the energy and the first scheme's
    /// first set's DVD weights, [`crate::site_profiles`]) for `analyze --plot`'s
    /// `distributions.png`: bounded, `2N` numbers per kept time.
    pub site_profiles: bool,
    /// `--plane-times`: the times of the pictures over the plane of a run on a square lattice
    /// (with `site_profiles`), checked by [`crate::site_profiles::check_plane_times`]; `None`:
    /// [`crate::site_profiles::default_plane_times`].
    pub plane_times: Option<Vec<f64>>,
    /// `--from T`: the finite-time exponents average the stretching from time T on (a
    /// transient before it is discarded); nothing else changes, and the verdict judges the
    /// whole run. Checked by [`exponents_from_step`].
    pub exponents_from: Option<f64>,
}

/// The step from which the exponents are averaged for `--from T`: `T / h` rounded up, where
/// a `T` on the step grid to rounding (100 / 0.01 = 10000.000000000002) is that step. An error
/// naming the value for a `T` that is negative, not finite, or not before the run's end.
pub fn exponents_from_step(from: f64, h: f64, t_final: f64) -> Result<u64, String> {
    if !from.is_finite() || from < 0.0 {
        return Err(format!("--from {from}: a time from 0 on"));
    }
    if from >= t_final {
        return Err(format!(
            "--from {from}: not before the run's end, t = {t_final}: no exponent would be left"
        ));
    }
    let steps = from / h;
    let near = steps.round();
    let step = if (steps - near).abs() <= 1e-9 * near.max(1.0) {
        near
    } else {
        steps.ceil()
    };
    Ok(step as u64)
}

/// Builds the vector field of a run from its header, if it can.
pub type FlowSource = fn(&RunInfo) -> Option<FlowField>;

/// Builds the site energies of a run's model from its header, if it can.
pub type SiteEnergySource = fn(&RunInfo) -> Option<SiteEnergies>;

/// Compiles a run's `[analysis] zero_one_observable` over its system rebuilt from the header:
/// `None` where the system cannot be rebuilt, the problem in one line where the expression
/// does not compile.
pub type ObservableSource = fn(&RunInfo) -> Option<Result<std::sync::Arc<ObservableFn>, String>>;

impl Default for AnalysisOptions {
    fn default() -> Self {
        Self {
            series_capacity: 2000,
            per_decade: 40,
            at: Vec::new(),
            flow_field: None,
            site_energies: None,
            zero_one_observable: None,
            site_profiles: false,
            plane_times: None,
            exponents_from: None,
        }
    }
}

#[derive(Debug, Clone)]
struct SchemeState {
    /// The VM scheme with the same renormalization steps, for MPM schemes.
    vm_partner: Option<usize>,
    series: Series<SchemePoint>,
    /// The curve the verdict reads: log-spaced at a fixed resolution, so every reader of the
    /// same samples (analyze, monitor, run) reaches the same verdict whatever its display
    /// resolution.
    verdict_series: Series<SchemePoint>,
}

#[derive(Debug, Clone)]
struct Capture {
    step: u64,
    report: Option<Report>,
}

/// Streaming analysis of one run.
#[derive(Debug, Clone)]
pub struct Analysis {
    run: RunInfo,
    tracker: Tracker,
    schemes: Vec<SchemeState>,
    energy_error_max: f64,
    energy_series: Series<f64>,
    /// The initial norm `S(x0)` of a run whose model conserves it (`run::conserves_norm`), and
    /// the largest relative error of the norm of the states seen since.
    norm0: Option<f64>,
    norm_error_max: f64,
    /// The reference orbit's extent `max |x|` since the first state seen (periodic coordinates
    /// wrapped into their period), log-spaced at the verdict's resolution (the verdict's
    /// `unbounded`).
    extent: Series<f64>,
    extent_max: f64,
    /// Time of the latest state seen.
    extent_t: Option<f64>,
    /// The start of the exponents' average (`--from T`, on the step grid), if set.
    exponents_from: Option<f64>,
    /// The distributions over the sites over time, where asked for and the run has sites.
    site_profiles: Option<SiteProfiles>,
    /// The latest mean divergence of the reference orbit (cumulative from t = 0 in the
    /// producer, so a late reader still gets the whole orbit's).
    mean_divergence: f64,
    step: u64,
    t: f64,
    samples: u64,
    /// A reader knows frames were lost (besides the gaps the tracker sees).
    gaps: bool,
    captures: Vec<Capture>,
}

/// The norm `S = sum_i x_i^2 / 2` of a state `(q, p)` (`sum_l (q_l^2 + p_l^2)/2`), summed in
/// the order of the coordinates.
pub fn lattice_norm(x: &[f64]) -> f64 {
    x.iter().map(|v| 0.5 * (v * v)).sum()
}

/// Relative energy error (absolute when `E0 = 0`), of finite energies (the reader refuses
/// others). An error beyond the range of f64 is reported as `f64::MAX`, never as infinity.
pub fn energy_error(e: f64, e0: f64) -> f64 {
    let error = if e0 != 0.0 {
        ((e - e0) / e0).abs()
    } else {
        e.abs()
    };
    error.min(f64::MAX)
}

/// What the 0-1 test of a run with `[analysis] zero_one_observable` observes: the compiled
/// expression, or why there is none (never another observable in its place).
fn configured_observable(
    run: &RunInfo,
    function: Option<Result<Arc<ObservableFn>, String>>,
) -> ZeroOneObservable {
    let source = run.zero_one_observable.clone().unwrap_or_default();
    match function {
        Some(Ok(function)) => ZeroOneObservable::Function { source, function },
        Some(Err(why)) => ZeroOneObservable::Unavailable(format!(
            "[analysis] zero_one_observable = {source:?}: {why}"
        )),
        None => ZeroOneObservable::Unavailable(format!(
            "[analysis] zero_one_observable = {source:?} needs the run's system, which this \
             reader cannot rebuild from the recorded configuration"
        )),
    }
}

impl Analysis {
    pub fn new(run: RunInfo, options: &AnalysisOptions) -> Self {
        let schemes = run
            .schemes
            .iter()
            .map(|s| SchemeState {
                vm_partner: (s.method == Method::Mpm)
                    .then(|| {
                        let same =
                            |o: &SchemeSpec| o.method == Method::Vm && o.tau_steps == s.tau_steps;
                        // Prefer the same orthonormalization, else any VM with the same tau.
                        run.schemes
                            .iter()
                            .position(|o| same(o) && o.orthonormalize == s.orthonormalize)
                            .or_else(|| run.schemes.iter().position(same))
                    })
                    .flatten(),
                series: Series::new(options.series_capacity, options.per_decade),
                verdict_series: Series::new(2, verdict::PER_DECADE),
            })
            .collect();
        let captures = options
            .at
            .iter()
            .map(|&t| Capture {
                // "As of time T": every renormalization at t <= T (to rounding) counts.
                step: (t / run.h + 1e-6).floor().max(0.0) as u64,
                report: None,
            })
            .collect();
        let mut tracker = Tracker::new(run.layout());
        if let Some(field) = options.flow_field.and_then(|source| source(&run)) {
            tracker.set_flow_field(field);
        }
        if let Some(energies) = options.site_energies.and_then(|source| source(&run)) {
            tracker.set_site_energies(energies);
        }
        if run.zero_one_observable.is_some() {
            let function = options.zero_one_observable.and_then(|build| build(&run));
            tracker.set_zero_one_observable(configured_observable(&run, function));
        }
        // The caller checked T against the run's end (`exponents_from_step`, one line naming
        // the value); here only a usable T takes effect.
        let exponents_from = options
            .exponents_from
            .and_then(|t| exponents_from_step(t, run.h, f64::INFINITY).ok());
        if let Some(step) = exponents_from {
            tracker.set_exponents_from(step);
        }
        Self {
            exponents_from: exponents_from.map(|step| run.time_of(step)),
            site_profiles: run
                .layout()
                .sites
                .filter(|_| options.site_profiles)
                .map(|sites| SiteProfiles::for_run(&run, sites, options.plane_times.as_deref())),
            tracker,
            schemes,
            energy_error_max: 0.0,
            energy_series: Series::new(options.series_capacity, options.per_decade),
            norm0: (run.kind == SystemClass::Hamiltonian
                && chaoscope_schemas::run::conserves_norm(&run.header.model))
            .then(|| lattice_norm(&run.header.x0)),
            norm_error_max: 0.0,
            extent: Series::new(2, verdict::PER_DECADE),
            extent_max: 0.0,
            extent_t: None,
            mean_divergence: 0.0,
            step: 0,
            t: 0.0,
            samples: 0,
            gaps: false,
            captures,
            run,
        }
    }

    pub fn run(&self) -> &RunInfo {
        &self.run
    }

    pub fn t(&self) -> f64 {
        self.t
    }

    pub fn step(&self) -> u64 {
        self.step
    }

    pub fn samples(&self) -> u64 {
        self.samples
    }

    /// Whether every stretching factor since t = 0 was seen.
    pub fn complete(&self) -> bool {
        !self.gaps && self.tracker.complete()
    }

    /// Marks the analysis as incomplete (a reader that knows frames were lost).
    pub fn mark_gap(&mut self) {
        self.gaps = true;
    }

    /// Feeds the next sample. Samples must come in increasing step order; sets or the reference
    /// state may be missing (a lossy live stream): what arrives is used.
    pub fn feed(&mut self, sample: &Sample) {
        // A sample whose time is not finite cannot be placed on any curve (the file reader
        // refuses it; a live stream's is left out as a lost one).
        if !sample.t.is_finite() {
            self.gaps = true;
            return;
        }
        // The captures this sample passes get the values as of the previous one.
        let due = |c: &Capture| c.report.is_none() && sample.step > c.step;
        if self.samples > 0 && self.captures.iter().any(due) {
            let report = self.report();
            for c in self.captures.iter_mut().filter(|c| due(c)) {
                c.report = Some(report.clone());
            }
        }
        self.samples += 1;
        self.step = sample.step;
        self.t = sample.t;
        // Energies and divergences that are not finite (never written by a producer, which
        // stops first) are left out rather than carried into every report.
        if !sample.state.is_empty() {
            // A periodic coordinate counts with its wrapped value: an angle that keeps turning
            // is no drift.
            let norm = self
                .run
                .wrapped(&sample.state)
                .iter()
                .map(|v| v * v)
                .sum::<f64>()
                .sqrt();
            if norm.is_finite() {
                self.extent_max = self.extent_max.max(norm);
            }
            let extent = self.extent_max;
            self.extent.offer(sample.t, || extent);
            self.extent_t = Some(sample.t);
        }
        if !sample.state.is_empty() {
            self.tracker.observe_reference(sample.step, &sample.state);
        }
        if !sample.state.is_empty()
            && sample.energy.is_finite()
            && sample.mean_divergence.is_finite()
        {
            if self.run.kind == SystemClass::Hamiltonian {
                let err = energy_error(sample.energy, self.run.header.energy0);
                self.energy_error_max = self.energy_error_max.max(err);
                self.energy_series.offer(sample.t, || err);
                if let Some(s0) = self.norm0 {
                    let s = lattice_norm(&sample.state);
                    if s.is_finite() {
                        self.norm_error_max = self.norm_error_max.max(energy_error(s, s0));
                    }
                }
            } else {
                self.mean_divergence = sample.mean_divergence;
            }
        }
        let mut touched = Vec::new();
        for s in &sample.schemes {
            if self.apply(sample.step, s) && touched.last() != Some(&(s.scheme as usize)) {
                touched.push(s.scheme as usize);
            }
        }
        if let Some(profiles) = &mut self.site_profiles {
            let tracker = &self.tracker;
            profiles.offer(sample, || tracker.reference_site_energies());
        }
        for si in touched {
            let t = sample.t;
            let scheme = &self.schemes[si];
            let point =
                (scheme.series.wants(t) || scheme.verdict_series.wants(t)).then(|| self.point(si));
            let scheme = &mut self.schemes[si];
            scheme
                .series
                .offer(t, || point.clone().expect("a wanted point"));
            scheme
                .verdict_series
                .offer(t, || point.expect("a wanted point"));
        }
    }

    /// Gives the analysis the system's vector field (from whoever holds the system: replay, a
    /// run in process, `analyze` rebuilding it from the recording's config), for the
    /// indicators that need the flow direction (OFLI). Before the first sample.
    pub fn set_flow_field(&mut self, field: FlowField) {
        self.tracker.set_flow_field(field);
    }

    /// Gives the analysis the energy of each site of the system's states (from whoever holds
    /// the system, as [`Analysis::set_flow_field`]), for the energy distribution. Before the
    /// first sample.
    pub fn set_site_energies(&mut self, energies: SiteEnergies) {
        self.tracker.set_site_energies(energies);
    }

    /// Gives the analysis the run's `[analysis] zero_one_observable` compiled (from whoever
    /// holds the system, as [`Analysis::set_flow_field`]; `None`: it cannot be here, and the
    /// 0-1 test says so). Nothing changes for a run without the key. Before the first sample.
    pub fn set_zero_one_observable(&mut self, function: Option<Result<Arc<ObservableFn>, String>>) {
        if self.run.zero_one_observable.is_some() {
            self.tracker
                .set_zero_one_observable(configured_observable(&self.run, function));
        }
    }

    /// Applies one set's separations; false if it does not fit the header (ignored).
    fn apply(&mut self, step: u64, s: &SchemeSample) -> bool {
        self.tracker.apply(
            s.scheme as usize,
            s.set as usize,
            step,
            &s.separations,
            &s.stretch,
            &s.earlier_stretch,
        )
    }

    /// The latest values of one set (`None` before its first sample).
    pub fn set_values(&self, scheme: usize, set: usize) -> Option<SetValues> {
        self.tracker.set_values(scheme, set)
    }

    /// The indicators of scheme `si` at its latest renormalization, averaged over its sets: what
    /// the report and the recording's indicators channel carry.
    pub fn indicators(&self, si: usize) -> SchemeIndicators {
        self.tracker.indicators(si)
    }

    fn point(&self, si: usize) -> SchemePoint {
        let ind = self.tracker.indicators(si);
        SchemePoint {
            gali_log10_mean: ind.gali.iter().map(|g| g.log10_mean).collect(),
            gali_log10_of_mean: ind.gali.iter().map(|g| g.mean.log10()).collect(),
            sali_log10_mean: ind.sali.map(|s| s.log10_mean),
            lyapunov: ind
                .exponents_whole
                .as_ref()
                .unwrap_or(&ind.exponents)
                .iter()
                .map(|e| e.mean)
                .collect(),
            lyapunov_from: ind
                .exponents_whole
                .is_some()
                .then(|| ind.exponents.iter().map(|e| e.mean).collect()),
            vs_vm_abs_delta: self.vs_vm_of(si).filter(|d| !d.gali.0.is_empty()).map(|d| {
                d.gali
                    .0
                    .iter()
                    .map(|(_, x)| x.mean_abs_delta_log10)
                    .collect()
            }),
            named: chaoscope_indicators::indicator::set_output_names()
                .iter()
                .map(|name| ind.named.value(name))
                .collect(),
        }
    }

    /// An MPM scheme's distance to its VM partner at its latest renormalization (`None` for a
    /// scheme without one, or before both reach the same step): what the report's `vs_vm` and
    /// the CSV's `gali<j>_vs_vm_mean_abs_delta_log10` carry.
    pub fn vs_vm(&self, si: usize) -> Option<VsVm> {
        self.vs_vm_of(si)
    }

    fn vs_vm_of(&self, si: usize) -> Option<VsVm> {
        let (run, tracker) = (&self.run, &self.tracker);
        let vi = self.schemes[si].vm_partner?;
        let step = tracker.scheme_step(si)?;
        let pairs: Vec<(SetValues, SetValues)> = (0..run.sets)
            .filter(|&set| {
                tracker.set_step(si, set) == Some(step) && tracker.set_step(vi, set) == Some(step)
            })
            .filter_map(|set| Some((tracker.set_values(si, set)?, tracker.set_values(vi, set)?)))
            .collect();
        if pairs.is_empty() {
            return None;
        }
        let n = pairs.len() as f64;
        // A QR scheme's vectors are orthonormal at every renormalization: its GALI is 1 by
        // construction, so GALI differences with it say nothing (only the exponents compare).
        let qr = |i: usize| run.schemes[i].orthonormalize == Orthonormalization::Qr;
        let orders = if qr(si) || qr(vi) {
            0
        } else {
            run.k.saturating_sub(1)
        };
        let gali = (0..orders)
            .map(|o| {
                let d: Vec<f64> = pairs
                    .iter()
                    .map(|(a, b)| a.gali_log10[o] - b.gali_log10[o])
                    .collect();
                (
                    o + 2,
                    DeltaLog {
                        mean_delta_log10: d.iter().sum::<f64>() / n,
                        mean_abs_delta_log10: d.iter().map(|x| x.abs()).sum::<f64>() / n,
                    },
                )
            })
            .collect();
        let mle_delta = pairs
            .iter()
            .map(|(a, b)| a.exponents[0] - b.exponents[0])
            .sum::<f64>()
            / n;
        Some(VsVm {
            scheme: run.schemes[vi].name.clone(),
            t: run.time_of(step),
            sets: pairs.len(),
            gali: ByOrder(gali),
            mle_delta,
        })
    }

    /// Values now (at the latest sample).
    pub fn report(&self) -> Report {
        self.report_with(None)
    }

    /// The report, with the verdict of a run that ended as `end` says (a failed run is never
    /// chaotic or regular; an escaped reference orbit is `escaped`).
    fn report_with(&self, end: Option<&EndOfRun>) -> Report {
        let (run, schemes, tracker) = (&self.run, &self.schemes[..], &self.tracker);
        // Ending with the latest state's, whether the thinning kept it or not.
        let mut extent = self.extent.points();
        if self
            .extent_t
            .is_some_and(|t| extent.last().is_none_or(|p| p.0 < t))
        {
            extent.push((self.extent_t.unwrap_or(0.0), self.extent_max));
        }
        let (energy_error_max, samples, t, complete) =
            (self.energy_error_max, self.samples, self.t, self.complete());
        let hamiltonian = run.kind == SystemClass::Hamiltonian;
        let reported_energy_error = hamiltonian.then_some(energy_error_max);
        let reported_norm_error = self.norm0.map(|_| self.norm_error_max);
        let h = &run.header;
        let scheme_reports = run
            .schemes
            .iter()
            .zip(schemes)
            .enumerate()
            .map(|(si, (info, state))| {
                let ind = tracker.indicators(si);
                let scheme_step = tracker.scheme_step(si);
                let gali = ByOrder(
                    ind.gali
                        .iter()
                        .enumerate()
                        .map(|(o, s)| (o + 2, *s))
                        .collect(),
                );
                let (mut lyapunov, mut lyapunov_std): (Vec<f64>, Vec<f64>) =
                    ind.exponents.iter().map(|e| (e.mean, e.std)).unzip();
                if info.orthonormalize == Orthonormalization::Rescale {
                    // Every rescaled vector estimates the MLE; the first is the reported one.
                    lyapunov.truncate(1);
                    lyapunov_std.truncate(1);
                }
                let latest;
                let mut curve = state.verdict_series.points_ref();
                if let Some(step) = scheme_step {
                    let t = run.time_of(step);
                    if curve.last().is_none_or(|p| p.0 < t) {
                        latest = self.point(si);
                        curve.push((t, &latest));
                    }
                }
                let settings = verdict::Settings {
                    method: info.method,
                    orthonormalize: info.orthonormalize,
                    d0: info.d0,
                    tau: info.tau,
                    dof: run.dim / 2,
                    k: run.k,
                };
                let run_values = verdict::RunValues {
                    energy_error_max: reported_energy_error.unwrap_or(0.0),
                    mean_divergence: (!hamiltonian).then_some(self.mean_divergence),
                    complete,
                    dim: run.dim,
                    energy0: run.header.energy0,
                    norm0: self.norm0,
                };
                let orbit = verdict::Orbit {
                    extent: &extent,
                    failure: end
                        .filter(|e| e.status == end_of_run::Status::Failed as i32)
                        .map(|e| (e.reason.as_str(), if e.t.is_finite() { e.t } else { t })),
                };
                let (verdict, warnings) = verdict::assess(&settings, &curve, &run_values, &orbit);
                SchemeReport {
                    name: info.name.clone(),
                    method: info.method.name().to_string(),
                    orthonormalize: info.orthonormalize.name().to_string(),
                    k: run.k,
                    d0: info.d0,
                    tau: info.tau,
                    sets: ind.sets,
                    t: scheme_step.map_or(0.0, |s| run.time_of(s)),
                    gali,
                    sali: ind.sali,
                    mle: lyapunov.first().copied().unwrap_or(0.0),
                    lyapunov_sum: (info.orthonormalize == Orthonormalization::Qr
                        && run.k == run.dim
                        && !lyapunov.is_empty())
                    .then(|| lyapunov.iter().sum()),
                    lyapunov,
                    lyapunov_std,
                    energy_error_max: reported_energy_error,
                    norm_error_max: reported_norm_error,
                    vs_vm: self.vs_vm_of(si),
                    indicators: {
                        let mut named = ind.named.clone();
                        named.0.extend(tracker.orbit_indicators(si).0);
                        named
                    },
                    verdict,
                    warnings,
                }
            })
            .collect();
        Report {
            run: RunReport {
                name: h.run_name.clone(),
                model: h.model.clone(),
                kind: run.kind.name().to_string(),
                time: if h.time.is_empty() {
                    "continuous".to_string()
                } else {
                    h.time.clone()
                },
                n: if hamiltonian { run.dim / 2 } else { 0 },
                dim: run.dim,
                k: run.k,
                sets: run.sets,
                integrator: h.integrator.clone(),
                h: run.h,
                t_final: h.t_final,
                total_steps: h.total_steps,
                seed: h.seed,
                energy0: h.energy0,
                samples,
                t,
                energy_error_max: reported_energy_error,
                norm0: self.norm0,
                norm_error_max: reported_norm_error,
                energy_error_of_norm: reported_energy_error
                    .and_then(|e| verdict::energy_error_of_norm(e, h.energy0, self.norm0)),
                mean_divergence: (!hamiltonian).then_some(self.mean_divergence),
                complete,
                end: None,
                exponents_from: self.exponents_from,
            },
            schemes: scheme_reports,
        }
    }

    /// [`Analysis::report`] with how the producer ended the run (`run.end`), for a stream whose
    /// end-of-run record was seen (a finished recording, a monitor at the end).
    pub fn report_ended(&self, end: Option<&EndOfRun>) -> Report {
        let mut report = self.report_with(end);
        report.run.end = end.map(crate::report::EndReport::from_message);
        report
    }

    /// Values as of time `t`, if `t` was among [`AnalysisOptions::at`]. Before the stream has
    /// passed `t` (or if it ended earlier) this is the latest report.
    pub fn report_at(&self, t: f64) -> Option<Report> {
        let step = (t / self.run.h + 1e-6).floor().max(0.0) as u64;
        let c = self.captures.iter().find(|c| c.step == step)?;
        Some(c.report.clone().unwrap_or_else(|| self.report()))
    }

    /// Whether every requested time has been captured (a reader may stop early).
    pub fn captures_done(&self) -> bool {
        !self.captures.is_empty() && self.captures.iter().all(|c| c.report.is_some())
    }

    /// The stored curve of scheme `si`.
    /// Ends with the latest sample, whether the thinning kept it or not.
    /// The distributions over the sites kept over time (`AnalysisOptions::site_profiles` on a
    /// run with sites), `None` otherwise.
    pub fn site_profiles(&self) -> Option<&SiteProfiles> {
        self.site_profiles.as_ref()
    }

    pub fn series(&self, si: usize) -> Vec<(f64, SchemePoint)> {
        let mut points = self.schemes[si].series.points();
        if let Some(step) = self.tracker.scheme_step(si) {
            let t = self.run.time_of(step);
            if points.last().is_none_or(|p| p.0 < t) {
                points.push((t, self.point(si)));
            }
        }
        points
    }

    /// Relative energy error of the reference orbit over time.
    pub fn energy_series(&self) -> Vec<(f64, f64)> {
        self.energy_series.points()
    }
}

/// Mean over sets of signed values (convenience for readers of [`SetValues`]).
pub fn mean(values: impl IntoIterator<Item = f64>) -> f64 {
    Stat::from_values(values).map_or(f64::NAN, |s| s.mean)
}
