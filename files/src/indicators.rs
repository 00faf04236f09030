//! The indicators channel of a recording: per scheme, at each of its renormalizations, GALI_2..k,
//! SALI and the finite-time exponents averaged over the sets (`chaoscope.v1.Indicators` on
//! `/chaoscope/indicators/<scheme>`), so plotting tools draw GALI(t) from the file alone.
//!
//! Computed by `chaoscope-indicators`' tracker, the one `chaoscope analyze` reports from, fed the
//! same separation sets in the same order: the values equal `analyze --json`'s to the last bit.
//! No bus and no file here: the file layout ([`crate::file`]) asks for the messages when a sample
//! is complete, and `chaoscope monitor --foxglove` streams them live.

use chaoscope_indicators::{Layout, LogStat, Named, SchemeIndicators, Tracker};
use chaoscope_schemas::proto::DataMessage;
use chaoscope_schemas::proto::{
    Indicators, MeanOverSets, NamedIndicator, RunHeader, SeparationSet,
};

/// The indicator state of one run and the schemes whose indicators are due.
#[derive(Debug, Clone)]
pub struct IndicatorStream {
    /// `None` when the header describes nothing the indicators can be computed for (no sets,
    /// no vectors): the run is still recorded, without indicators.
    tracker: Option<Tracker>,
    /// Per scheme: whether its exponents are a spectrum (QR) rather than k MLE estimates.
    spectrum: Vec<bool>,
    /// Schemes that received separations since the last [`IndicatorStream::take`], with the
    /// sample number of the latest.
    pending: Vec<(usize, u64)>,
}

impl IndicatorStream {
    pub fn new(header: &RunHeader) -> Self {
        let layout = Layout::new(
            header.dim as usize,
            header.k as usize,
            header.sets as usize,
            header.h,
            header.schemes.iter().map(|s| s.tau_steps).collect(),
        )
        .map(|layout| {
            let kind = chaoscope_schemas::run::SystemClass::from_name(&header.kind);
            layout
                .with_sites(kind.and_then(|k| k.lattice_sites(header.dim as usize)))
                // A side that does not fit the state is the analyzer's error to report; the
                // recorder then takes the sites as a chain's.
                .with_square_side(chaoscope_schemas::run::square_side(header).unwrap_or(None))
                .with_periodic(chaoscope_schemas::run::periodic_axes(header))
                .with_norm(
                    kind == Some(chaoscope_schemas::run::SystemClass::Hamiltonian)
                        && chaoscope_schemas::run::conserves_norm(&header.model),
                )
        });
        Self {
            tracker: layout.map(Tracker::new),
            spectrum: header
                .schemes
                .iter()
                .map(|s| s.orthonormalize == "qr")
                .collect(),
            pending: Vec::new(),
        }
    }

    /// A stream that computes nothing (the indicators are computed elsewhere).
    pub fn disabled() -> Self {
        Self {
            tracker: None,
            spectrum: Vec::new(),
            pending: Vec::new(),
        }
    }

    /// The indicator messages to be written just before `message` (those of the sample it
    /// completes: a sample's messages end where the next reference state or the end of the run
    /// begins), and `message` taken into the state. This is the one place that decides where
    /// indicators go in a file, whichever thread computes them.
    pub fn before(&mut self, message: &DataMessage) -> Vec<Indicators> {
        match message {
            DataMessage::Reference(_) | DataMessage::End(_) => self.take(),
            DataMessage::Separations(m) => {
                self.observe(m);
                Vec::new()
            }
        }
    }

    /// Takes one separation set (ignored if it does not fit the header).
    pub fn observe(&mut self, m: &SeparationSet) {
        let Some(tracker) = &mut self.tracker else {
            return;
        };
        let si = m.scheme as usize;
        if tracker.apply(
            si,
            m.set as usize,
            m.step,
            &m.separations,
            &m.stretch,
            &m.earlier_stretch,
        ) {
            match self.pending.iter_mut().find(|p| p.0 == si) {
                Some(p) => p.1 = m.seq,
                None => self.pending.push((si, m.seq)),
            }
        }
    }

    /// The indicators of every scheme that received separations since the last call, in scheme
    /// order. Called when a sample is complete (the next sample's reference state, the end of
    /// the run, the end of the file).
    pub fn take(&mut self) -> Vec<Indicators> {
        let Some(tracker) = &self.tracker else {
            return Vec::new();
        };
        self.pending.sort_unstable();
        self.pending
            .drain(..)
            .map(|(si, seq)| message(si as u32, seq, &tracker.indicators(si), self.spectrum[si]))
            .collect()
    }
}

fn mean_over_sets(s: &LogStat) -> MeanOverSets {
    MeanOverSets {
        mean: s.mean,
        log10_of_mean: s.mean.log10(),
        log10_mean: s.log10_mean,
    }
}

/// The message of one scheme's indicators (`spectrum`: a QR scheme, whose exponents are the
/// Lyapunov spectrum).
pub fn message(scheme: u32, seq: u64, ind: &SchemeIndicators, spectrum: bool) -> Indicators {
    Indicators {
        scheme,
        seq,
        step: ind.step,
        t: ind.t,
        sets: ind.sets as u32,
        gali: ind.gali.iter().map(mean_over_sets).collect(),
        sali: ind.sali.as_ref().map(mean_over_sets),
        mle: ind.mle(),
        spectrum: if spectrum {
            ind.exponents.iter().map(|e| e.mean).collect()
        } else {
            Vec::new()
        },
        named: ind
            .named
            .0
            .iter()
            .map(|(name, value)| {
                let (mean, std, unavailable) = match value {
                    Named::OverSets(s) => (Some(s.mean), Some(s.std), String::new()),
                    Named::Value(v) => (Some(*v), None, String::new()),
                    Named::Unavailable(reason) => (None, None, reason.clone()),
                };
                NamedIndicator {
                    name: name.to_string(),
                    mean,
                    std,
                    unavailable,
                }
            })
            .collect(),
    }
}
