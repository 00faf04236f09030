//! The result of one grid point.

/// What happened to a point.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum PointStatus {
    Ok,
    /// The energy equation has no real solution there: not integrated.
    OutsideEnergySurface,
    /// The reference orbit or a deviation escaped / became non-finite.
    Escaped,
}

#[derive(Debug, Clone, PartialEq)]
pub struct PointResult {
    /// `iy * nx + ix`.
    pub index: u64,
    pub ix: u32,
    pub iy: u32,
    /// Grid coordinates.
    pub x: f64,
    pub y: f64,
    pub status: PointStatus,
    /// Mean over the sets (NaN unless `Ok`).
    pub value: f64,
    /// One number per set (empty unless `Ok`).
    pub per_set: Vec<f64>,
    /// Mean of log10 GALI_k over the sets for `gali`, else 0.
    pub mean_log10: f64,
    /// `spectrum`: `lambda_1..lambda_k`, each the mean over the sets (empty otherwise).
    pub spectrum: Vec<f64>,
    /// Time the point finished.
    pub t_end: f64,
    /// Orbit-steps integrated (reference plus nearby orbits or tangent vectors).
    pub orbit_steps: u64,
    /// Why the point is not `Ok`.
    pub reason: String,
    /// The initial condition (empty when outside the energy surface).
    pub x0: Vec<f64>,
}

impl PointResult {
    /// Everything but the work accounting (`orbit_steps`): what two computation paths of the
    /// same point must agree on bit for bit.
    pub fn same_numbers(&self, other: &Self) -> bool {
        let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        self.index == other.index
            && self.status == other.status
            && self.value.to_bits() == other.value.to_bits()
            && bits(&self.per_set) == bits(&other.per_set)
            && self.mean_log10.to_bits() == other.mean_log10.to_bits()
            && bits(&self.spectrum) == bits(&other.spectrum)
            && self.t_end.to_bits() == other.t_end.to_bits()
            && bits(&self.x0) == bits(&other.x0)
    }
}
