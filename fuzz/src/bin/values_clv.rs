//! AFL target: valid files with hostile values (see `chaoscope_fuzz::values_clv`).
fn main() {
    afl::fuzz!(|data: &[u8]| {
        chaoscope_fuzz::values_clv(data);
    });
}
