//! What the benchmarks share: the binary under test and the size knob.

pub const CHAOSCOPE: &str = env!("CARGO_BIN_EXE_chaoscope");

/// `CHAOSCOPE_BENCH_SCALE` (default 1): every benchmark scales its work by it, so a quick run
/// sets e.g. 0.1.
pub fn scale() -> f64 {
    std::env::var("CHAOSCOPE_BENCH_SCALE")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(1.0)
}
