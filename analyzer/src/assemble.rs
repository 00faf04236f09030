//! Messages (from MCAP or the bus) back into [`Sample`]s: a reference state followed by the
//! separation sets of the same sample number.

use chaoscope_schemas::proto::DataMessage;
use chaoscope_schemas::proto::{EndOfRun, ReferenceState, SeparationSet};
use chaoscope_schemas::run::{Sample, SchemeSample};

/// Groups consecutive messages of one sample number.
#[derive(Debug, Default)]
pub struct SampleAssembler {
    current: Option<Sample>,
}

fn empty_sample(seq: u64, step: u64, t: f64) -> Sample {
    Sample {
        seq,
        step,
        t,
        state: Vec::new(),
        energy: f64::NAN,
        mean_divergence: f64::NAN,
        divergence_sum: f64::NAN,
        schemes: Vec::new(),
    }
}

impl SampleAssembler {
    pub fn new() -> Self {
        Self::default()
    }

    /// Takes a reference state; returns the previous sample if this one starts a new one.
    pub fn reference(&mut self, m: ReferenceState) -> Option<Sample> {
        let done = self.current.take();
        self.current = Some(Sample {
            seq: m.seq,
            step: m.step,
            t: m.t,
            state: m.state,
            energy: m.energy,
            mean_divergence: m.mean_divergence,
            divergence_sum: m.divergence_sum,
            schemes: Vec::new(),
        });
        done
    }

    /// Takes a separation set; returns the previous sample if this one belongs to a new one
    /// (its reference state was lost).
    pub fn separations(&mut self, m: SeparationSet) -> Option<Sample> {
        let done = match &self.current {
            Some(c) if c.seq == m.seq => None,
            _ => self.current.replace(empty_sample(m.seq, m.step, m.t)),
        };
        let current = self.current.as_mut().expect("set above");
        current.schemes.push(SchemeSample {
            scheme: m.scheme,
            set: m.set,
            separations: m.separations,
            stretch: m.stretch,
            earlier_stretch: m.earlier_stretch,
        });
        done
    }

    /// The sample in progress, if any (at the end of the stream).
    pub fn finish(&mut self) -> Option<Sample> {
        self.current.take()
    }

    /// Dispatches a data message; returns a completed sample and the end-of-run record if any.
    pub fn push(&mut self, m: DataMessage) -> (Option<Sample>, Option<EndOfRun>) {
        match m {
            DataMessage::Reference(r) => (self.reference(r), None),
            DataMessage::Separations(s) => (self.separations(s), None),
            DataMessage::End(e) => (self.finish(), Some(e)),
        }
    }
}
