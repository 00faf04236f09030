//! Structure-of-arrays storage of many phase-space points (or deviation vectors).

/// Lane counts are rounded up to a multiple of this: the narrowest kernel chunk.
pub const LANE_QUANTUM: usize = 8;

/// `rows` coordinates of `lanes` independent points: `data[row * lanes + lane]`.
///
/// The lane capacity is a multiple of [`LANE_QUANTUM`]; lanes beyond the ones in use are padding
/// that the kernel advances along (they hold a harmless state, e.g. zeros) and nobody reads.
#[derive(Debug, Clone, PartialEq)]
pub struct Soa {
    rows: usize,
    lanes: usize,
    data: Vec<f64>,
}

impl Soa {
    /// Zeroed storage for at least `lanes` lanes.
    pub fn new(rows: usize, lanes: usize) -> Self {
        let lanes = lanes.div_ceil(LANE_QUANTUM).max(1) * LANE_QUANTUM;
        Self {
            rows,
            lanes,
            data: vec![0.0; rows * lanes],
        }
    }

    /// Storage for exactly `lanes` lanes, without padding: for steppers that go lane by lane
    /// (the engine's), never for the batched kernels, which step whole chunks.
    pub fn unpadded(rows: usize, lanes: usize) -> Self {
        Self {
            rows,
            lanes,
            data: vec![0.0; rows * lanes],
        }
    }

    pub fn rows(&self) -> usize {
        self.rows
    }

    /// Lane capacity (a multiple of [`LANE_QUANTUM`]).
    pub fn lanes(&self) -> usize {
        self.lanes
    }

    pub fn get(&self, row: usize, lane: usize) -> f64 {
        self.data[row * self.lanes + lane]
    }

    pub fn set(&mut self, row: usize, lane: usize, v: f64) {
        self.data[row * self.lanes + lane] = v;
    }

    /// Copy lane `lane` out into `out` (length `rows`).
    pub fn read_lane(&self, lane: usize, out: &mut [f64]) {
        for (r, o) in out.iter_mut().enumerate() {
            *o = self.data[r * self.lanes + lane];
        }
    }

    /// Overwrite lane `lane` with `x` (length `rows`).
    pub fn write_lane(&mut self, lane: usize, x: &[f64]) {
        for (r, v) in x.iter().enumerate() {
            self.data[r * self.lanes + lane] = *v;
        }
    }

    /// The whole storage, `data[row * lanes + lane]` (padding lanes included): what a compiled
    /// lane function reads with `lanes == stride == self.lanes()`.
    pub(crate) fn data(&self) -> &[f64] {
        &self.data
    }

    pub(crate) fn data_mut(&mut self) -> &mut [f64] {
        &mut self.data
    }

    /// Lanes `offset..offset + L` of every row, copied into `out` (one array per row).
    #[inline(always)]
    pub(crate) fn gather<const L: usize>(&self, offset: usize, out: &mut [[f64; L]]) {
        for (r, o) in out.iter_mut().enumerate() {
            let start = r * self.lanes + offset;
            o.copy_from_slice(&self.data[start..start + L]);
        }
    }

    #[inline(always)]
    pub(crate) fn scatter<const L: usize>(&mut self, offset: usize, src: &[[f64; L]]) {
        for (r, s) in src.iter().enumerate() {
            let start = r * self.lanes + offset;
            self.data[start..start + L].copy_from_slice(s);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lanes_round_up_and_round_trip() {
        let mut s = Soa::new(3, 5);
        assert_eq!(s.lanes(), 8);
        s.write_lane(4, &[1.0, 2.0, 3.0]);
        let mut out = [0.0; 3];
        s.read_lane(4, &mut out);
        assert_eq!(out, [1.0, 2.0, 3.0]);
        let mut chunk = [[0.0; 8]; 3];
        s.gather(0, &mut chunk);
        assert_eq!(chunk[2][4], 3.0);
        chunk[0][7] = 9.0;
        s.scatter(0, &chunk);
        assert_eq!(s.get(0, 7), 9.0);
    }
}
