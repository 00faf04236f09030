//! Synthetic recordings for the recover tests and the recover memory bench: written by the
//! recorder's own [`Recording`] (the layout, chunking and compression of `chaoscope record`),
//! with pseudo-random separation vectors that compress about as badly as a real run's.

use std::io::{Seek, Write};

use chaoscope_recorder::file::FileOptions;
use chaoscope_recorder::recording::{FinalizedBy, Recording};
use chaoscope_schemas::convert::DataMessage;
use chaoscope_schemas::proto::{
    EndOfRun, ReferenceState, RunHeader, Scheme, SeparationSet, end_of_run,
};

/// What one synthetic run holds: per sample a reference state of `dim` doubles and `sets`
/// separation sets of `k` x `dim` doubles.
pub struct Shape {
    pub dim: u32,
    pub k: u32,
    pub sets: u32,
    pub samples: u64,
}

/// xorshift64*: deterministic noise without a dependency.
pub struct Noise(u64);

impl Noise {
    pub fn new(seed: u64) -> Self {
        Self(seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1)
    }

    pub fn next_u64(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_F491_4F6C_DD1D)
    }

    /// Uniform in [-scale, scale), full 53-bit mantissas.
    pub fn next_f64(&mut self, scale: f64) -> f64 {
        ((self.next_u64() >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0) * scale
    }

    pub fn bytes(&mut self, n: usize) -> Vec<u8> {
        (0..n).map(|_| (self.next_u64() >> 56) as u8).collect()
    }
}

/// Writes a whole run (header, samples, end of run, summary) in the recorder's layout.
pub fn write_run<W: Write + Seek>(
    out: W,
    shape: &Shape,
    options: &FileOptions,
    seed: u64,
) -> mcap::McapResult<W> {
    let header = RunHeader {
        run_name: "synthetic".into(),
        model: "fput-beta".into(),
        n: shape.dim / 2,
        dim: shape.dim,
        k: shape.k,
        sets: shape.sets,
        h: 0.01,
        schemes: vec![Scheme {
            index: 0,
            name: "mpm".into(),
            method: "mpm".into(),
            d0: 1e-8,
            tau: 0.01,
            tau_steps: 1,
            orthonormalize: "rescale".into(),
        }],
        ..Default::default()
    };
    let mut noise = Noise::new(seed);
    let mut recording = Recording::start(out, &header, options)?;
    let mut frame = 0;
    for step in 0..shape.samples {
        let t = step as f64 * 0.01;
        let state = (0..shape.dim).map(|_| noise.next_f64(1.0)).collect();
        recording.on_message(&DataMessage::Reference(ReferenceState {
            frame,
            seq: step,
            step,
            t,
            energy: 1.0 + noise.next_f64(1e-12),
            state,
        }))?;
        frame += 1;
        for set in 0..shape.sets {
            let separations = (0..shape.k * shape.dim)
                .map(|_| noise.next_f64(1e-8))
                .collect();
            let stretch = (0..shape.k).map(|_| 1.0 + noise.next_f64(1e-3)).collect();
            recording.on_message(&DataMessage::Separations(SeparationSet {
                frame,
                seq: step,
                step,
                t,
                scheme: 0,
                set,
                k: shape.k,
                dim: shape.dim,
                separations,
                stretch,
            }))?;
            frame += 1;
        }
    }
    recording.on_message(&DataMessage::End(EndOfRun {
        frame,
        status: end_of_run::Status::Completed as i32,
        samples: shape.samples,
        ..Default::default()
    }))?;
    Ok(recording.finish(FinalizedBy::EndOfRun)?.0)
}
