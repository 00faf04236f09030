//! AFL target: the configuration parser and validators (see `chaoscope_fuzz::config`).
fn main() {
    afl::fuzz!(|data: &[u8]| chaoscope_fuzz::config(data));
}
