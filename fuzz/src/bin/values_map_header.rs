//! AFL target: valid files with hostile values (see `chaoscope_fuzz::values_map_header`).
fn main() {
    afl::fuzz!(|data: &[u8]| {
        chaoscope_fuzz::values_map_header(data);
    });
}
