//! AFL target: valid files with hostile values (see `chaoscope_fuzz::values_resume`).
fn main() {
    afl::fuzz!(|data: &[u8]| {
        chaoscope_fuzz::values_resume(data);
    });
}
