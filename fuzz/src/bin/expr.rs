//! AFL target: the expression language (see `chaoscope_fuzz::expr`).
fn main() {
    afl::fuzz!(|data: &[u8]| chaoscope_fuzz::expr(data));
}
