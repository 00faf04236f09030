//! Arrays of doubles as NumPy's `.npy` files (format version 1.0, NEP 1), which `numpy.load`
//! reads without any other package: the magic string, the header's length, a Python dict
//! literal giving the element type (`<f8`, little-endian doubles), `fortran_order` and the
//! shape, padded with spaces to a multiple of 64 bytes, then the values in C order.

use std::io::Write;

/// The header of a little-endian `f64` array of `shape`, in C order (the last index varies
/// fastest).
pub fn header(shape: &[usize]) -> Vec<u8> {
    let dims: Vec<String> = shape.iter().map(usize::to_string).collect();
    // A one-dimensional shape is a Python tuple of one: `(n,)`.
    let shape = match dims.len() {
        1 => format!("({},)", dims[0]),
        _ => format!("({})", dims.join(", ")),
    };
    let mut dict = format!("{{'descr': '<f8', 'fortran_order': False, 'shape': {shape}, }}");
    // Magic (6) + version (2) + length (2) + dict + newline: a multiple of 64, so the data is
    // aligned as the format asks.
    let unpadded = 10 + dict.len() + 1;
    dict.extend(std::iter::repeat_n(
        ' ',
        unpadded.next_multiple_of(64) - unpadded,
    ));
    dict.push('\n');
    let mut out = Vec::with_capacity(10 + dict.len());
    out.extend_from_slice(b"\x93NUMPY\x01\x00");
    let len = u16::try_from(dict.len()).expect("a shape of a few numbers fits a 64 KiB header");
    out.extend_from_slice(&len.to_le_bytes());
    out.extend_from_slice(dict.as_bytes());
    out
}

/// Writes `values` as little-endian doubles.
pub fn write_values(out: &mut impl Write, values: &[f64]) -> std::io::Result<()> {
    let bytes: Vec<u8> = values.iter().flat_map(|v| v.to_le_bytes()).collect();
    out.write_all(&bytes)
}

#[cfg(test)]
mod tests {
    use super::header;

    #[test]
    fn headers_are_aligned_python_literals() {
        let h = header(&[3, 2, 4]);
        assert_eq!(h.len() % 64, 0);
        assert_eq!(&h[..8], b"\x93NUMPY\x01\x00");
        assert_eq!(u16::from_le_bytes([h[8], h[9]]) as usize, h.len() - 10);
        let dict = std::str::from_utf8(&h[10..]).unwrap();
        assert!(dict.starts_with("{'descr': '<f8', 'fortran_order': False, 'shape': (3, 2, 4), }"));
        assert!(dict.ends_with(" \n"));
        let one = header(&[7]);
        assert!(
            std::str::from_utf8(&one[10..])
                .unwrap()
                .contains("'shape': (7,)")
        );
        assert_eq!(one.len() % 64, 0);
    }
}
