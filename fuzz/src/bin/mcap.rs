//! AFL target: every MCAP reader path over arbitrary bytes (see `chaoscope_fuzz::mcap`).
fn main() {
    afl::fuzz!(|data: &[u8]| chaoscope_fuzz::mcap(data));
}
