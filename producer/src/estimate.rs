//! A run's estimate with the bus's frames in flight: the memory of `chaoscope run` counts the
//! frames a recorder's buffer and the monitors hold besides the numerics'.

use chaoscope_bus as bus;
use chaoscope_dynamics::estimate::{self, Estimate, Machine, Transport};
use chaoscope_dynamics::spec::RunSpec;

/// What the bus holds in flight for a run.
pub const BUS: Transport = Transport {
    buffered_frames: bus::DATA_BUFFER,
    monitor_bytes: bus::MONITOR_MEMORY,
    frame_words,
};

/// A bus frame gathers records up to a target size (small systems) or holds one.
fn frame_words(k: usize, dim: usize) -> usize {
    bus::max_frame_words(k * dim + k + bus::frame::RECORD_HEADER_WORDS)
}

/// Estimate of a validated run published on the bus ([`estimate::run`] with [`BUS`]).
pub fn run(spec: &RunSpec, machine: &Machine) -> Estimate {
    estimate::run(spec, machine, &BUS)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_bus_transport_is_the_bus() {
        // The values the numerics' own tests of the estimate assume (dynamics/src/estimate.rs).
        assert_eq!(BUS.buffered_frames, 64);
        assert_eq!(BUS.monitor_bytes, 64 << 20);
        assert_eq!((BUS.frame_words)(1, 4), 1024);
        assert_eq!((BUS.frame_words)(4, 1000), 4 * 1000 + 4 + 8);
    }
}
