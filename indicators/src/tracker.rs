//! The streaming indicator state of a run, fed one separation set at a time.
//!
//! Per (scheme, set) it feeds every registered set indicator (`crate::set_indicators`: GALI and
//! SALI, the exponents, FLI, MEGNO, ...) each renormalization, and reads a scheme's values
//! (averaged over the sets that reached its latest renormalization) from them when asked for.
//! GALI, SALI and the exponents are read from their registered instances in full (every order,
//! every vector, the SALI unfloored) into fields of their own, the others by name. Memory is
//! O(schemes x sets x k x 2N), independent of the length of the run.

use std::collections::BTreeMap;
use std::sync::Arc;

use serde::ser::{Serialize, SerializeMap, Serializer};

use crate::alignment::{Alignment, SIGMA_FLOOR};
pub use crate::indicator::SiteEnergies;
use crate::indicator::{
    Carried, OrbitIndicator, Output, SetIndicator, SetObservation, SiteEnergyInput,
    orbit_indicators, set_indicators,
};
use crate::stats::{LogStat, Stat};
use crate::stretch::Exponents;
pub use crate::zero_one::ZeroOneObservable;

/// The shape of a run, as its header states it.
#[derive(Debug, Clone, PartialEq)]
pub struct Layout {
    /// Phase-space dimension 2N (entries per vector).
    pub dim: usize,
    /// Deviation vectors per set.
    pub k: usize,
    pub sets: usize,
    /// Time step: the time of step `n` is `n * h`.
    pub h: f64,
    /// Renormalization period of each scheme in steps, in header order.
    pub tau_steps: Vec<u64>,
    /// The sites `N` of a Hamiltonian (`dim = 2N`), for the indicators over a lattice
    /// ([`Layout::with_sites`]); `None` for flows and maps.
    pub sites: Option<usize>,
    /// `Some(L)` when the sites form an `L x L` square lattice numbered row by row
    /// ([`Layout::with_square_side`], [`SetObservation::square_side`]); `None`: a chain.
    pub square_side: Option<usize>,
    /// Which lattice axes are periodic ([`Layout::with_periodic`], [`SetObservation::periodic`]).
    pub periodic: [bool; 2],
    /// The system conserves the norm `sum_l (q_l^2 + p_l^2) / 2` ([`Layout::with_norm`]).
    pub norm_conserved: bool,
    /// The period of each coordinate of the state (`0`: none; empty: no periodic coordinate),
    /// [`Layout::with_periods`], for the readers of a run that show its state wrapped
    /// ([`crate::periodic`]). The orbit indicators observe the state as the system integrates it
    /// (a flow's angle continuous): a wrapped angle is a sawtooth, whose jumps the 0-1 test
    /// reads as chaos (K = 0.70 on a rotating pendulum, against -0.08 on its continuous angle);
    /// its default observable takes a periodic coordinate by its sine and cosine, which have no
    /// seam ([`crate::zero_one::generic_observable`]).
    pub periods: Vec<f64>,
}

impl Layout {
    /// A layout the indicators can be computed for: positive sizes, `k <= dim`, a positive
    /// finite step, no zero period. `None` otherwise.
    pub fn new(dim: usize, k: usize, sets: usize, h: f64, tau_steps: Vec<u64>) -> Option<Self> {
        let ok = dim > 0
            && k > 0
            && k <= dim
            && sets > 0
            && h.is_finite()
            && h > 0.0
            && tau_steps.iter().all(|&t| t > 0);
        ok.then_some(Self {
            dim,
            k,
            sets,
            h,
            tau_steps,
            sites: None,
            square_side: None,
            periodic: [false; 2],
            norm_conserved: false,
            periods: Vec::new(),
        })
    }

    /// The layout with `sites` lattice sites (a Hamiltonian's `dim / 2`, site `l` at `q_l`,
    /// `p_l`), or none.
    pub fn with_sites(self, sites: Option<usize>) -> Self {
        Self { sites, ..self }
    }

    /// The layout whose `L^2` sites form an `L x L` square lattice (`Some(L)`), or a chain.
    pub fn with_square_side(self, square_side: Option<usize>) -> Self {
        Self {
            square_side,
            ..self
        }
    }

    /// The layout whose lattice closes on itself along the axes `periodic` says (along `i`,
    /// then `j`; a chain reads the first).
    pub fn with_periodic(self, periodic: [bool; 2]) -> Self {
        Self { periodic, ..self }
    }

    /// The layout of a system that conserves the norm `sum_l (q_l^2 + p_l^2) / 2` (or not).
    pub fn with_norm(self, norm_conserved: bool) -> Self {
        Self {
            norm_conserved,
            ..self
        }
    }

    /// The layout with the periods of the state's coordinates (one per coordinate, `0` for
    /// none, as [`crate::periodic::check_periods`] accepts; empty for none).
    pub fn with_periods(self, periods: Vec<f64>) -> Self {
        Self { periods, ..self }
    }

    /// Time of step `step`, computed as the producer does (`step * h`, never accumulated).
    pub fn time_of(&self, step: u64) -> f64 {
        step as f64 * self.h
    }

    /// Step of the renormalization of `scheme` preceding the one at `step`.
    pub fn previous_renormalization(&self, scheme: usize, step: u64) -> u64 {
        let tau = self.tau_steps[scheme];
        if step == 0 {
            0
        } else {
            // The last renormalization may fall at t_final, off the tau grid.
            ((step - 1) / tau) * tau
        }
    }
}

/// The values of one set at its latest renormalization.
#[derive(Debug, Clone, PartialEq)]
pub struct SetValues {
    pub t: f64,
    /// `[j - 2]` = log10 GALI_j.
    pub gali_log10: Vec<f64>,
    pub sali: Option<f64>,
    /// Finite-time exponent per vector (from the transient's end where one is set,
    /// [`Tracker::set_exponents_from`]).
    pub exponents: Vec<f64>,
    /// The same over the whole run, where a transient is set (`None` otherwise: then
    /// `exponents` are the whole run's).
    pub exponents_whole: Option<Vec<f64>>,
    /// The outputs of every set indicator, by name, in registration order.
    pub outputs: Vec<(&'static str, Output)>,
}

/// One named output of a scheme: averaged over its sets (set indicators), one value (orbit
/// indicators), or unavailable with the reason.
#[derive(Debug, Clone, PartialEq)]
pub enum Named {
    /// Mean and spread over the sets, as the exponents.
    OverSets(Stat),
    /// One value for the scheme (an indicator of the reference orbit).
    Value(f64),
    /// Cannot be computed from what this run gives.
    Unavailable(String),
}

/// Named outputs in order, serialized as map entries `name: value` (a set indicator's
/// `{"mean", "std"}`, an orbit indicator's number, or `{"unavailable": reason}`), so a report
/// carries every registered indicator under its own name without knowing it.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct NamedOutputs(pub Vec<(&'static str, Named)>);

impl NamedOutputs {
    pub fn get(&self, name: &str) -> Option<&Named> {
        self.0.iter().find(|(n, _)| *n == name).map(|(_, v)| v)
    }

    /// The value of an output (the mean over the sets for a set indicator), if available.
    pub fn value(&self, name: &str) -> Option<f64> {
        match self.get(name)? {
            Named::OverSets(s) => Some(s.mean),
            Named::Value(v) => Some(*v),
            Named::Unavailable(_) => None,
        }
    }
}

impl Serialize for Named {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        match self {
            Named::OverSets(stat) => stat.serialize(s),
            Named::Value(v) => s.serialize_f64(*v),
            Named::Unavailable(reason) => {
                let mut m = s.serialize_map(Some(1))?;
                m.serialize_entry("unavailable", reason)?;
                m.end()
            }
        }
    }
}

impl Serialize for NamedOutputs {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        let mut m = s.serialize_map(Some(self.0.len()))?;
        for (name, v) in &self.0 {
            m.serialize_entry(name, v)?;
        }
        m.end()
    }
}

/// The vector field `f(x, t)` of the run's system, for the indicators that need the flow direction
/// at the reference state (OFLI): writes `f(x)` into `out` and returns true, or false where the
/// system has none (a map). Given by whoever holds the system (the engine's side); the tracker
/// itself stays a pure function of what it is fed.
#[derive(Clone)]
pub struct FlowField(pub Arc<FlowFn>);

/// `f(x, t)` into `out` at the time of step `step` (a non-autonomous system's field depends on
/// it; the system knows its time step), false where there is none.
pub type FlowFn = dyn Fn(u64, &[f64], &mut [f64]) -> bool + Send + Sync;

impl std::fmt::Debug for FlowField {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("FlowField")
    }
}

/// One scheme's indicators averaged over the sets at its latest renormalization.
#[derive(Debug, Clone, PartialEq)]
pub struct SchemeIndicators {
    /// Step and time of the scheme's latest renormalization (0 before any).
    pub step: u64,
    pub t: f64,
    /// Sets contributing (all of them unless frames were lost).
    pub sets: usize,
    /// `[j - 2]`: GALI_j over the sets, j = 2..k (empty when no set contributes).
    pub gali: Vec<LogStat>,
    /// SALI (floored at [`SIGMA_FLOOR`]) over the sets; `None` for k < 2 or no set.
    pub sali: Option<LogStat>,
    /// Finite-time exponent of each vector, mean and spread over the sets: the spectrum for QR
    /// schemes, an estimate of the maximal exponent per vector for rescaled ones. Averaged
    /// from the transient's end where one is set ([`Tracker::set_exponents_from`]).
    pub exponents: Vec<Stat>,
    /// The same over the whole run, where a transient is set (`None` otherwise).
    pub exponents_whole: Option<Vec<Stat>>,
    /// Every set indicator's outputs over the sets, by name (FLI, OFLI, MEGNO, ...).
    pub named: NamedOutputs,
}

impl SchemeIndicators {
    /// The finite-time maximal Lyapunov exponent (of the first vector), mean over the sets; 0
    /// when no set contributes.
    pub fn mle(&self) -> f64 {
        self.exponents.first().map_or(0.0, |s| s.mean)
    }
}

#[derive(Debug, Clone)]
struct SetState {
    /// Steps covered by the stretching factors received (equals the step when none was missed).
    covered_steps: u64,
    /// The steps after the transient (intervals beginning at or after
    /// `Tracker::exponents_from`) covered, and the exponents of those intervals alone.
    late_covered_steps: u64,
    late: Option<Exponents>,
    /// Step of the latest renormalization.
    step: Option<u64>,
    /// Every registered set indicator, in registration order.
    indicators: Vec<Box<dyn SetIndicator>>,
}

impl SetState {
    /// The registered indicator of type `T` (GALI and SALI, the exponents), which the registry
    /// holds once.
    fn registered<T: SetIndicator>(&self) -> &T {
        self.indicators
            .iter()
            .find_map(|i| (i.as_ref() as &dyn std::any::Any).downcast_ref::<T>())
            .expect("a built-in indicator is registered")
    }
}

#[derive(Debug, Clone)]
struct SchemeState {
    /// The sets that have arrived, by index (up to the layout's count): a map, not a vector
    /// grown to the index, so that neither a header's claim nor a message's set index (one
    /// set numbered 4 billion in a file once asked for 343 GB) allocates more than what came.
    sets: BTreeMap<usize, SetState>,
    step: Option<u64>,
    /// The indicators of the reference orbit sampled at this scheme's renormalizations.
    orbit: Vec<Box<dyn OrbitIndicator>>,
}

/// The latest reference state seen, with the vector field there when known.
#[derive(Debug, Clone)]
struct Reference {
    step: u64,
    state: Vec<f64>,
    flow: Option<Vec<f64>>,
}

/// The indicator state of one run.
#[derive(Debug, Clone)]
pub struct Tracker {
    layout: Layout,
    schemes: Vec<SchemeState>,
    /// Some stretching factor was never seen (late attach, lost frames).
    gaps: bool,
    reference: Option<Reference>,
    flow_field: Option<FlowField>,
    site_energies: Option<SiteEnergies>,
    /// First step of the exponents' average: a transient before it is discarded (`None`: the
    /// whole run).
    exponents_from: Option<u64>,
}

impl Tracker {
    pub fn new(layout: Layout) -> Self {
        let zero_one = ZeroOneObservable::Generic {
            periods: layout.periods.clone(),
        };
        let schemes = layout
            .tau_steps
            .iter()
            .map(|_| SchemeState {
                sets: BTreeMap::new(),
                step: None,
                orbit: orbit_indicators(&zero_one),
            })
            .collect();
        Self {
            layout,
            schemes,
            gaps: false,
            reference: None,
            flow_field: None,
            site_energies: None,
            exponents_from: None,
        }
    }

    /// Discards a transient from the finite-time exponents: they average the stretching of the
    /// renormalization intervals that begin at or after step `from` (time `from * h`), over the
    /// time those intervals cover, as every Lyapunov code's transient option does. Nothing else
    /// changes (GALI, SALI, FLI, MEGNO, the 0-1 test, and the whole run's exponents in
    /// `exponents_whole`, which the verdict reads). Before the first sample.
    pub fn set_exponents_from(&mut self, from: u64) {
        self.exponents_from = Some(from);
    }

    /// Sets what the 0-1 test observes (a run's `[analysis] zero_one_observable`, compiled by
    /// whoever holds the system, or why it cannot be), in place of the generic observable of
    /// the layout's coordinates. Before the first sample.
    pub fn set_zero_one_observable(&mut self, observable: ZeroOneObservable) {
        for scheme in &mut self.schemes {
            scheme.orbit = orbit_indicators(&observable);
        }
    }

    /// Gives the tracker the system's vector field, for the indicators that need the flow
    /// direction (OFLI); without it they report themselves unavailable.
    pub fn set_flow_field(&mut self, field: FlowField) {
        self.flow_field = Some(field);
    }

    /// Gives the tracker the energy of each site of the system's states, for the energy
    /// distribution; without it that reports itself unavailable.
    pub fn set_site_energies(&mut self, energies: SiteEnergies) {
        self.site_energies = Some(energies);
    }

    /// The reference state at `step` (before the separation sets of that step are applied):
    /// the orbit indicators sample it at each scheme's renormalizations, and the set indicators
    /// read the flow direction there. A state that does not fit the layout or is not finite is
    /// ignored (those renormalizations then see no state).
    pub fn observe_reference(&mut self, step: u64, state: &[f64]) {
        if state.len() != self.layout.dim || !state.iter().all(|v| v.is_finite()) {
            self.reference = None;
            return;
        }
        let flow = self.flow_field.as_ref().and_then(|field| {
            let mut out = vec![0.0; state.len()];
            ((field.0)(step, state, &mut out) && out.iter().all(|v| v.is_finite())).then_some(out)
        });
        self.reference = Some(Reference {
            step,
            state: state.to_vec(),
            flow,
        });
    }

    /// The energy of each site at the latest reference state (computed now), or why there is
    /// none; `None` without [`SiteEnergies`], sites or a reference state.
    pub fn reference_site_energies(&self) -> Option<Result<Vec<f64>, String>> {
        let (f, n, r) = (
            self.site_energies.as_ref()?,
            self.layout.sites?,
            self.reference.as_ref()?,
        );
        let mut out = vec![0.0; n];
        Some((f.0)(&r.state, &mut out).map(|()| out))
    }

    pub fn layout(&self) -> &Layout {
        &self.layout
    }

    /// Whether every stretching factor since t = 0 was seen.
    pub fn complete(&self) -> bool {
        !self.gaps
    }

    /// Applies one set's separations (the `k` vectors of `dim` entries one after another) and
    /// stretching factors at `step`, after the stretching factors `earlier` of its
    /// renormalizations since its previous sample (`k` each, oldest first: a run sampled every
    /// `sample_every`; empty otherwise), each accumulated as at its own renormalization. False,
    /// and nothing changed, if they do not fit the layout, or a stretching factor is not
    /// positive and finite, or a separation not finite.
    /// Steps of one (scheme, set) must increase; a missed renormalization is a gap.
    pub fn apply(
        &mut self,
        scheme: usize,
        set: usize,
        step: u64,
        separations: &[f64],
        stretch: &[f64],
        earlier: &[f64],
    ) -> bool {
        let (k, dim) = (self.layout.k, self.layout.dim);
        let positive = |s: &[f64]| s.iter().all(|s| s.is_finite() && *s > 0.0);
        if scheme >= self.schemes.len()
            || set >= self.layout.sets
            || separations.len() != k * dim
            || stretch.len() != k
            || !earlier.len().is_multiple_of(k)
            // Values no producer sends (the producer stops before a vector vanishes or leaves
            // the range of f64): their logarithms and alignments would be NaN or infinite.
            || !positive(stretch)
            || !positive(earlier)
            || !separations.iter().all(|v| v.is_finite())
        {
            return false;
        }
        // The earlier renormalizations, at the tau grid's points before this one's.
        let tau = self.layout.tau_steps[scheme];
        let prev = self.layout.previous_renormalization(scheme, step);
        let count = (earlier.len() / k) as u64;
        let first = match count {
            0 => prev,
            _ => match (count - 1)
                .checked_mul(tau)
                .and_then(|back| prev.checked_sub(back))
            {
                Some(first) if first > 0 => first,
                // More renormalizations than fit before this step: none a producer sends.
                _ => return false,
            },
        };
        for (i, stretch) in earlier.chunks_exact(k).enumerate() {
            self.accumulate(scheme, set, first + i as u64 * tau, &[], stretch);
        }
        self.accumulate(scheme, set, step, separations, stretch);
        true
    }

    /// One renormalization of one set at `step` (its separations empty where they were not
    /// recorded): the stretching sums, the set indicators, and the orbit indicators at the
    /// scheme's first set of a new step.
    fn accumulate(
        &mut self,
        scheme: usize,
        set: usize,
        step: u64,
        separations: &[f64],
        stretch: &[f64],
    ) {
        let (k, dim) = (self.layout.k, self.layout.dim);
        let prev = self.layout.previous_renormalization(scheme, step);
        let transient = self.exponents_from.is_some();
        let st = self.schemes[scheme]
            .sets
            .entry(set)
            .or_insert_with(|| SetState {
                covered_steps: 0,
                late_covered_steps: 0,
                late: transient.then(|| Exponents::for_vectors(k)),
                step: None,
                indicators: set_indicators(),
            });
        // A stretching factor covers the interval since the scheme's previous renormalization;
        // if that one was not seen, the sum has a hole.
        let expected_prev = st.step.unwrap_or(0);
        if step > 0 && expected_prev != prev {
            self.gaps = true;
        }
        let late = step > 0 && self.exponents_from.is_some_and(|from| prev >= from);
        if step > 0 {
            st.covered_steps += step - prev;
            if late {
                st.late_covered_steps += step - prev;
            }
        }
        // Only a sample (with separations) comes with the reference state of its step.
        let reference = self
            .reference
            .as_ref()
            .filter(|r| r.step == step && !separations.is_empty());
        let t = self.layout.time_of(step);
        let observation = SetObservation {
            t,
            dt: t - st.step.map_or(0.0, |s| self.layout.time_of(s)),
            covered: self.layout.time_of(st.covered_steps),
            dim,
            separations,
            stretch,
            flow: reference.and_then(|r| r.flow.as_deref()),
            sites: self.layout.sites,
            square_side: self.layout.square_side,
            periodic: self.layout.periodic,
            norm_conserved: self.layout.norm_conserved,
            state: reference.map(|r| r.state.as_slice()),
            site_energies: self.site_energies.as_ref().map(|energies| match reference {
                Some(r) => SiteEnergyInput::At {
                    energies,
                    state: &r.state,
                },
                None => SiteEnergyInput::Unavailable(
                    "no reference state came with this renormalization",
                ),
            }),
        };
        for indicator in &mut st.indicators {
            indicator.observe(&observation);
        }
        if late && let Some(exponents) = &mut st.late {
            exponents.observe(&SetObservation {
                covered: self.layout.time_of(st.late_covered_steps),
                ..observation
            });
        }
        st.step = Some(step);
        let state = &mut self.schemes[scheme];
        // The first set of a new renormalization of the scheme samples the orbit.
        if state.step.is_none_or(|s| s < step)
            && let Some(r) = reference
        {
            for indicator in &mut state.orbit {
                indicator.observe(t, &r.state);
            }
        }
        state.step = Some(state.step.map_or(step, |x| x.max(step)));
    }

    /// Step of the latest renormalization of `scheme` seen (`None` before any).
    pub fn scheme_step(&self, scheme: usize) -> Option<u64> {
        self.schemes[scheme].step
    }

    /// Step of the latest separations of one set (`None` before any).
    pub fn set_step(&self, scheme: usize, set: usize) -> Option<u64> {
        self.schemes[scheme].sets.get(&set)?.step
    }

    fn values_of(&self, st: &SetState) -> Option<SetValues> {
        let step = st.step?;
        let alignment = st.registered::<Alignment>();
        let whole = st.registered::<Exponents>().per_vector();
        let (exponents, exponents_whole) = match &st.late {
            None => (whole, None),
            Some(late) => (late.per_vector(), Some(whole)),
        };
        Some(SetValues {
            t: self.layout.time_of(step),
            gali_log10: alignment.gali_log10().to_vec(),
            sali: alignment.sali(),
            exponents,
            exponents_whole,
            outputs: st
                .indicators
                .iter()
                .flat_map(|i| i.declared().iter().zip(i.outputs()))
                .filter(|(d, _)| d.carried == Carried::Named)
                .map(|(d, o)| (d.name, o))
                .collect(),
        })
    }

    /// The latest values of one set (`None` before its first sample).
    pub fn set_values(&self, scheme: usize, set: usize) -> Option<SetValues> {
        self.values_of(self.schemes[scheme].sets.get(&set)?)
    }

    /// The sets of `scheme` at its latest step, with their values, in set order.
    pub fn current_sets(&self, scheme: usize) -> Vec<(usize, SetValues)> {
        let state = &self.schemes[scheme];
        let Some(step) = state.step else {
            return Vec::new();
        };
        state
            .sets
            .iter()
            .filter(|(_, st)| st.step == Some(step))
            .filter_map(|(&i, st)| self.values_of(st).map(|v| (i, v)))
            .collect()
    }

    /// The indicators of `scheme` at its latest renormalization, averaged over its sets there.
    pub fn indicators(&self, scheme: usize) -> SchemeIndicators {
        let sets = self.current_sets(scheme);
        let step = self.schemes[scheme].step.unwrap_or(0);
        let gali = (0..self.layout.k.saturating_sub(1))
            .filter_map(|o| LogStat::from_log10(sets.iter().map(|(_, v)| v.gali_log10[o])))
            .collect();
        let sali = LogStat::from_log10(
            sets.iter()
                .filter_map(|(_, v)| v.sali.map(|s| s.max(SIGMA_FLOOR).log10())),
        );
        // Each vector's exponent over the sets, from `rates` of each set's values.
        let over_sets = |rates: &dyn Fn(&SetValues) -> Option<&Vec<f64>>| -> Vec<Stat> {
            (0..sets.first().map_or(0, |(_, v)| v.exponents.len()))
                .filter_map(|i| {
                    Stat::from_values(
                        sets.iter()
                            .filter_map(|(_, v)| rates(v).and_then(|r| r.get(i).copied())),
                    )
                })
                .collect()
        };
        let exponents = over_sets(&|v| Some(&v.exponents));
        let exponents_whole = self
            .exponents_from
            .map(|_| over_sets(&|v| v.exponents_whole.as_ref()));
        let named = NamedOutputs(
            (0..sets.first().map_or(0, |(_, v)| v.outputs.len()))
                .map(|i| {
                    let name = sets[0].1.outputs[i].0;
                    let unavailable = sets.iter().find_map(|(_, v)| match &v.outputs[i].1 {
                        Output::Unavailable(reason) => Some(reason.clone()),
                        Output::Value(_) => None,
                    });
                    let value = match unavailable {
                        Some(reason) => Named::Unavailable(reason),
                        None => Stat::from_values(sets.iter().map(|(_, v)| match v.outputs[i].1 {
                            Output::Value(x) => x,
                            Output::Unavailable(_) => 0.0,
                        }))
                        .map_or(Named::Unavailable("no set".to_string()), Named::OverSets),
                    };
                    (name, value)
                })
                .collect(),
        );
        SchemeIndicators {
            step,
            t: self.layout.time_of(step),
            sets: sets.len(),
            gali,
            sali,
            exponents,
            exponents_whole,
            named,
        }
    }

    /// The outputs of the orbit indicators of `scheme` (the 0-1 test), by name: computed only
    /// when asked, since they read the whole sampled series.
    pub fn orbit_indicators(&self, scheme: usize) -> NamedOutputs {
        NamedOutputs(
            self.schemes[scheme]
                .orbit
                .iter()
                .flat_map(|i| {
                    i.names().iter().copied().zip(i.outputs()).map(|(n, o)| {
                        let v = match o {
                            Output::Value(x) => Named::Value(x),
                            Output::Unavailable(r) => Named::Unavailable(r),
                        };
                        (n, v)
                    })
                })
                .collect(),
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn layout() -> Layout {
        Layout::new(2, 2, 2, 0.5, vec![2]).unwrap()
    }

    #[test]
    fn layouts_that_cannot_be_tracked_are_refused() {
        assert!(Layout::new(0, 1, 1, 0.1, vec![1]).is_none());
        assert!(Layout::new(2, 3, 1, 0.1, vec![1]).is_none());
        assert!(Layout::new(2, 2, 0, 0.1, vec![1]).is_none());
        assert!(Layout::new(2, 2, 1, f64::NAN, vec![1]).is_none());
        assert!(Layout::new(2, 2, 1, 0.1, vec![1, 0]).is_none());
    }

    #[test]
    fn averages_the_sets_at_the_latest_step_and_counts_gaps() {
        let mut t = Tracker::new(layout());
        let e = std::f64::consts::E;
        // Set 0: orthogonal vectors (GALI_2 = 1), stretched by e per tau = 1 (two steps of 0.5).
        assert!(t.apply(0, 0, 0, &[1.0, 0.0, 0.0, 1.0], &[1.0, 1.0], &[]));
        assert!(t.apply(0, 0, 2, &[2.0, 0.0, 0.0, 3.0], &[e, e], &[]));
        // Set 1 at the same step: vectors at 90 degrees too, stretched by e^3.
        assert!(t.apply(0, 1, 0, &[1.0, 0.0, 0.0, 1.0], &[1.0, 1.0], &[]));
        assert!(t.apply(0, 1, 2, &[1.0, 1.0, 1.0, -1.0], &[e * e * e, 1.0], &[]));
        let ind = t.indicators(0);
        assert_eq!((ind.step, ind.t, ind.sets), (2, 1.0, 2));
        assert!(ind.gali[0].log10_mean.abs() < 1e-15);
        // Mean of the exponents 1 and 3 (ln e / 1 and ln e^3 / 1), to rounding of ln.
        assert!((ind.mle() - 2.0).abs() < 1e-15, "{}", ind.mle());
        assert!(t.complete());
        // Set 0 skips the renormalization at step 4: the sum has a hole.
        assert!(t.apply(0, 0, 6, &[1.0, 0.0, 0.0, 1.0], &[1.0, 1.0], &[]));
        assert!(!t.complete());
        // Only set 0 is at step 6 now.
        assert_eq!(t.indicators(0).sets, 1);
        // Frames that do not fit are ignored.
        assert!(!t.apply(1, 0, 2, &[0.0; 4], &[1.0, 1.0], &[]));
        assert!(!t.apply(0, 2, 2, &[0.0; 4], &[1.0, 1.0], &[]));
        assert!(!t.apply(0, 0, 8, &[0.0; 3], &[1.0, 1.0], &[]));
    }

    #[test]
    fn registered_alignment_and_exponents_are_the_direct_computations_bit_for_bit() {
        use crate::alignment::{gali_log10, sali};
        use crate::stretch::StretchSums;
        // k = 3 vectors in 4 dimensions, renormalized every 2 steps of 0.25, the exponents
        // from step 4 on. Step 6 is a sample after two renormalizations between samples (steps
        // 2 and 4: their factors only), step 8 is never seen (a lost frame), step 10 is a
        // sample again.
        let mut t = Tracker::new(Layout::new(4, 3, 1, 0.25, vec![2]).unwrap());
        t.set_exponents_from(4);
        let value = |i: usize| ((i as f64 + 0.5) * 0.618_033_988_749_894_9).fract() - 0.5;
        let seps = |at: usize| (0..12).map(|i| value(at * 12 + i)).collect::<Vec<f64>>();
        let stretch = |at: usize| {
            (0..3)
                .map(|i| 1.0 + 3.0 * value(at * 3 + i).abs())
                .collect()
        };
        let (s2, s4, s6, s10): (Vec<f64>, Vec<f64>, Vec<f64>, Vec<f64>) =
            (stretch(2), stretch(4), stretch(6), stretch(10));
        assert!(t.apply(0, 0, 0, &seps(0), &[1.0; 3], &[]));
        assert!(t.apply(0, 0, 6, &seps(6), &s6, &[s2.clone(), s4.clone()].concat()));
        assert!(t.apply(0, 0, 10, &seps(10), &s10, &[]));
        assert!(!t.complete());
        let (mut whole, mut late) = (StretchSums::new(3), StretchSums::new(3));
        for s in [&s2, &s4, &s6, &s10] {
            whole.add(s);
        }
        // The intervals that begin at step 4 or later: (4, 6] and (8, 10].
        late.add(&s6);
        late.add(&s10);
        let v = t.set_values(0, 0).unwrap();
        let bits = |x: &[f64]| x.iter().map(|v| v.to_bits()).collect::<Vec<u64>>();
        // Covered: 8 steps of 0.25 (step 8's interval missed), 4 after the transient.
        assert_eq!(bits(&v.exponents), bits(&late.spectrum(1.0)));
        assert_eq!(
            bits(v.exponents_whole.as_deref().unwrap()),
            bits(&whole.spectrum(2.0))
        );
        assert_eq!(bits(&v.gali_log10), bits(&gali_log10(&seps(10), 4)));
        assert_eq!(
            v.sali.map(f64::to_bits),
            sali(&seps(10), 4).map(f64::to_bits)
        );
        // The scheme's means of them, and the named outputs without the own fields' names.
        let ind = t.indicators(0);
        assert_eq!(ind.mle().to_bits(), late.mle(1.0).to_bits());
        assert_eq!(
            ind.sali.unwrap().log10_mean.to_bits(),
            sali(&seps(10), 4)
                .unwrap()
                .max(SIGMA_FLOOR)
                .log10()
                .to_bits()
        );
        let names: Vec<&str> = ind.named.0.iter().map(|(n, _)| *n).collect();
        assert_eq!(names, crate::indicator::set_output_names());
    }

    #[test]
    fn a_set_numbered_near_the_header_claim_allocates_one_set() {
        // A header claiming 2^32 - 1 sets and one separation set numbered 2^32 - 2 (a valid
        // file with hostile values, found by the `values_recording` fuzz target): a vector
        // grown to that index asked for 343 GB and aborted; one set is kept.
        let sets = u32::MAX as usize;
        let mut t = Tracker::new(Layout::new(2, 2, sets, 0.5, vec![2]).unwrap());
        assert!(t.apply(0, sets - 1, 0, &[1.0, 0.0, 0.0, 1.0], &[1.0, 1.0], &[]));
        assert_eq!(t.current_sets(0).len(), 1);
        assert_eq!(t.current_sets(0)[0].0, sets - 1);
        assert_eq!(t.set_step(0, sets - 1), Some(0));
        assert_eq!(t.set_step(0, 0), None);
    }
}
