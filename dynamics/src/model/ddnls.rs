//! The disordered discrete nonlinear Schroedinger lattice (DDNLS), 1-D chain or 2-D square
//! lattice with fixed ends (`psi = 0` outside):
//!
//! `H = sum_l [eps_l |psi_l|^2 + (beta/2) |psi_l|^4] - sum_bonds (psi_l psi_m* + c.c.)`, with
//! `psi_l = (q_l + i p_l)/sqrt(2)`, i.e. with `J_l = (q_l^2 + p_l^2)/2`
//! `H = sum_l [eps_l J_l + (beta/2) J_l^2] - sum_bonds (q_l q_m + p_l p_m)`,
//! and the norm `S = sum_l J_l`, a second conserved quantity.
//!
//! It is not separable into `T(p) + V(q)`, but splits into three parts with exact flows
//! (Skokos et al., Phys. Lett. A 378, 1809 (2014)), the [`SplitFlows`] of this model:
//! - `A = sum_l [eps_l J_l + (beta/2) J_l^2]`: each `J_l` is conserved, so every site rotates at
//!   its own constant rate `a_l = eps_l + beta J_l`;
//! - `B = -sum_bonds q_l q_m`: `q` fixed, `p_l += tau sum_nb q`;
//! - `C = -sum_bonds p_l p_m`: `p` fixed, `q_l -= tau sum_nb p`.
//!
//! Sites are numbered row by row in 2-D (site `(i, j)`, both from 0, is `i n + j`); the sum over
//! the neighbours of a site is taken in one fixed order (left, right, then up, down), so every
//! path gives the same bits.

use super::sin_cos::sin_cos_each;
use crate::batch::{Isa, on_isa};
use crate::integrator::composition::SplitFlows;
use crate::vector_field::VectorField;

/// The lattice's geometry.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DdnlsLattice {
    /// A chain of `n` sites.
    Chain { n: usize },
    /// An `n x n` square lattice.
    Square { n: usize },
}

impl DdnlsLattice {
    /// Number of sites `N`.
    pub fn sites(self) -> usize {
        match self {
            DdnlsLattice::Chain { n } => n,
            DdnlsLattice::Square { n } => n * n,
        }
    }
}

/// The DDNLS with its disorder `eps_l` and nonlinearity `beta`.
#[derive(Debug, Clone, PartialEq)]
pub struct Ddnls {
    lattice: DdnlsLattice,
    eps: Vec<f64>,
    beta: f64,
}

impl Ddnls {
    /// The lattice with on-site energies `eps` (one per site).
    pub fn new(lattice: DdnlsLattice, eps: Vec<f64>, beta: f64) -> Self {
        assert_eq!(eps.len(), lattice.sites(), "one eps per site");
        Self { lattice, eps, beta }
    }

    pub fn lattice(&self) -> DdnlsLattice {
        self.lattice
    }

    pub fn eps(&self) -> &[f64] {
        &self.eps
    }

    pub fn beta(&self) -> f64 {
        self.beta
    }

    /// Number of sites `N` (the state has `2N` entries).
    pub fn sites(&self) -> usize {
        self.eps.len()
    }

    /// `out_l = sum over the neighbours m of l of v_m` (fixed ends): the hopping flows' sums,
    /// added to `-0.0` (`-0.0 + s` and `1.0 * s` are `s` for every `s`, zeros' signs included).
    pub fn neighbour_sum(&self, v: &[f64], out: &mut [f64]) {
        out.fill(-0.0);
        self.add_neighbour_sums(v, out, 1.0);
    }

    /// `sum over bonds (each once) of u_l v_m`, as `(1/2) sum_l u_l (sum_nb v)_l` would give it
    /// for `u = v`, summed bond by bond in site order (right, then down neighbour).
    fn bond_sum(&self, u: &[f64], v: &[f64]) -> f64 {
        let mut s = 0.0;
        match self.lattice {
            DdnlsLattice::Chain { n } => {
                for l in 0..n.saturating_sub(1) {
                    s += u[l] * v[l + 1];
                }
            }
            DdnlsLattice::Square { n } => {
                for i in 0..n {
                    for j in 0..n {
                        let l = i * n + j;
                        if j + 1 < n {
                            s += u[l] * v[l + 1];
                        }
                        if i + 1 < n {
                            s += u[l] * v[l + n];
                        }
                    }
                }
            }
        }
        s
    }

    /// The energy `H(q, p)`.
    pub fn energy(&self, x: &[f64]) -> f64 {
        let n = self.sites();
        let (q, p) = x.split_at(n);
        let mut onsite = 0.0;
        for l in 0..n {
            let j = 0.5 * (q[l] * q[l] + p[l] * p[l]);
            onsite += self.eps[l] * j + 0.5 * self.beta * j * j;
        }
        onsite - (self.bond_sum(q, q) + self.bond_sum(p, p))
    }

    /// The norm `S = sum_l (q_l^2 + p_l^2)/2`.
    pub fn norm(&self, x: &[f64]) -> f64 {
        let n = self.sites();
        let (q, p) = x.split_at(n);
        let mut s = 0.0;
        for l in 0..n {
            s += 0.5 * (q[l] * q[l] + p[l] * p[l]);
        }
        s
    }

    /// What made a state non-finite: the first non-finite coordinate.
    pub fn diagnose(&self, x: &[f64]) -> Option<String> {
        let n = self.sites();
        x.iter().position(|v| !v.is_finite()).map(|i| {
            let (c, l) = if i < n {
                ("q", i + 1)
            } else {
                ("p", i - n + 1)
            };
            format!("{c}{l} is not finite (the DDNLS norm or energy escaped double precision)")
        })
    }

    /// `to += tau sum_nb from` on `v`'s halves: from `q` to `p` (the B flow), or `to -=` from
    /// `p` to `q` (the C flow).
    #[inline(always)]
    fn hop(&self, v: &mut [f64], from_q: bool, tau: f64) {
        let n = self.sites();
        let (q, p) = v.split_at_mut(n);
        if from_q {
            self.add_neighbour_sums(q, p, tau);
        } else {
            self.add_neighbour_sums(p, q, -tau);
        }
    }

    /// `to_l += tau (sum over the neighbours m of l of from_m)`, the neighbours of site `l` in
    /// one fixed order (left, right, then up, down), a wall reading 0.
    #[inline(always)]
    fn add_neighbour_sums(&self, from: &[f64], to: &mut [f64], tau: f64) {
        match self.lattice {
            DdnlsLattice::Chain { n } => {
                if n == 0 {
                    return;
                }
                let right = |l: usize| if l + 1 < n { from[l + 1] } else { 0.0 };
                to[0] += tau * (0.0 + right(0));
                // The interior without tests, so the loop vectorizes.
                for l in 1..n.saturating_sub(1) {
                    to[l] += tau * (from[l - 1] + from[l + 1]);
                }
                if n > 1 {
                    to[n - 1] += tau * (from[n - 2] + 0.0);
                }
            }
            DdnlsLattice::Square { n } => {
                for i in 0..n {
                    let row = i * n;
                    // A row beyond a fixed edge reads 0, added as the neighbour_sum adds it.
                    // The four cases are separate loops so each inner loop has no tests.
                    let to = &mut to[row..row + n];
                    match (i > 0, i + 1 < n) {
                        (true, true) => add_row(
                            from,
                            to,
                            row,
                            tau,
                            |j| from[row - n + j],
                            |j| from[row + n + j],
                        ),
                        (false, true) => {
                            add_row(from, to, row, tau, |_| 0.0, |j| from[row + n + j])
                        }
                        (true, false) => {
                            add_row(from, to, row, tau, |j| from[row - n + j], |_| 0.0)
                        }
                        (false, false) => add_row(from, to, row, tau, |_| 0.0, |_| 0.0),
                    }
                }
            }
        }
    }
}

/// One row of a square's `to_j += tau (((left + right) + up) + down)` (the row starting at site
/// `row`; `up` and `down` give the neighbours in the rows above and below, or 0).
#[inline(always)]
fn add_row(
    from: &[f64],
    to: &mut [f64],
    row: usize,
    tau: f64,
    up: impl Fn(usize) -> f64,
    down: impl Fn(usize) -> f64,
) {
    let n = to.len();
    let here = &from[row..row + n];
    let left = |j: usize| if j > 0 { here[j - 1] } else { 0.0 };
    let right = |j: usize| if j + 1 < n { here[j + 1] } else { 0.0 };
    for j in [0, n - 1] {
        to[j] += tau * (((left(j) + right(j)) + up(j)) + down(j));
        if n == 1 {
            return;
        }
    }
    for j in 1..n - 1 {
        to[j] += tau * (((here[j - 1] + here[j + 1]) + up(j)) + down(j));
    }
}

/// Sites the A flow takes at a time: their angles, sines and cosines stay in L1.
const ROTATE_CHUNK: usize = 64;

/// The A flow on `x`, and on each deviation vector of `w` (chunks of `2N`) its derivative: per
/// chunk of sites, the angles `a_l tau`, their
/// sines and cosines, the state's and every vector's rotation.
#[inline(always)]
fn rotate_sites(m: &Ddnls, x: &mut [f64], w: &mut [f64], tau: f64) {
    let n = m.sites();
    let dim = 2 * n;
    let beta = m.beta;
    let (q, p) = x.split_at_mut(n);
    let mut angle = [0.0; ROTATE_CHUNK];
    let mut sin = [0.0; ROTATE_CHUNK];
    let mut cos = [0.0; ROTATE_CHUNK];
    for first in (0..n).step_by(ROTATE_CHUNK) {
        let len = ROTATE_CHUNK.min(n - first);
        let (q, p, eps) = (
            &mut q[first..first + len],
            &mut p[first..first + len],
            &m.eps[first..first + len],
        );
        for i in 0..len {
            angle[i] = (eps[i] + beta * (0.5 * (q[i] * q[i] + p[i] * p[i]))) * tau;
        }
        sin_cos_each(&angle[..len], &mut sin[..len], &mut cos[..len]);
        // The rate depends on J_l: da = beta (q dq + p dp), and d(q', p') gains tau da (p', -q')
        // beside the rotation of (dq, dp). The vectors first, while (q, p) is the old point.
        for v in w.chunks_exact_mut(dim) {
            let (vq, vp) = v.split_at_mut(n);
            let (vq, vp) = (&mut vq[first..first + len], &mut vp[first..first + len]);
            for i in 0..len {
                let (s, c) = (sin[i], cos[i]);
                let (ql, pl) = (q[i], p[i]);
                let qn = ql * c + pl * s;
                let pn = pl * c - ql * s;
                let (dq, dp) = (vq[i], vp[i]);
                let td = tau * (beta * (ql * dq + pl * dp));
                vq[i] = (dq * c + dp * s) + td * pn;
                vp[i] = (dp * c - dq * s) - td * qn;
            }
        }
        for i in 0..len {
            let (s, c) = (sin[i], cos[i]);
            let (ql, pl) = (q[i], p[i]);
            q[i] = ql * c + pl * s;
            p[i] = pl * c - ql * s;
        }
    }
}

/// [`SplitFlows::flow_tangent`] for one instruction set (`w` empty for the orbit alone).
#[inline(always)]
fn flow_tangent_with(m: &Ddnls, part: usize, x: &mut [f64], w: &mut [f64], tau: f64) {
    let dim = 2 * m.sites();
    if dim == 0 {
        return;
    }
    match part {
        0 => rotate_sites(m, x, w, tau),
        // The hopping flows are linear: their tangent map is the flow itself.
        1 | 2 => {
            let from_q = part == 1;
            m.hop(x, from_q, tau);
            for v in w.chunks_exact_mut(dim) {
                m.hop(v, from_q, tau);
            }
        }
        _ => unreachable!("the DDNLS has three parts"),
    }
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
fn flow_tangent_avx512(m: &Ddnls, part: usize, x: &mut [f64], w: &mut [f64], tau: f64) {
    flow_tangent_with(m, part, x, w, tau)
}

// `fma` beside AVX2 as everywhere else; Rust never fuses a separate multiply and add.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
fn flow_tangent_avx2(m: &Ddnls, part: usize, x: &mut [f64], w: &mut [f64], tau: f64) {
    flow_tangent_with(m, part, x, w, tau)
}

impl SplitFlows for Ddnls {
    fn dim(&self) -> usize {
        2 * self.sites()
    }

    fn parts(&self) -> usize {
        3
    }

    fn flow(&self, part: usize, x: &mut [f64], tau: f64) {
        self.flow_tangent(part, x, &mut [], tau)
    }

    /// Compiled for the widest instruction set of the CPU.
    fn flow_tangent(&self, part: usize, x: &mut [f64], w: &mut [f64], tau: f64) {
        self.flow_tangent_on(Isa::detect(), part, x, w, tau)
    }
}

impl Ddnls {
    /// [`SplitFlows::flow_tangent`] compiled for `isa` (which this CPU must have), with the same
    /// bits for every instruction set: no fused multiply-adds, and the fast sine and cosine are
    /// made of correctly rounded additions and multiplications.
    pub fn flow_tangent_on(&self, isa: Isa, part: usize, x: &mut [f64], w: &mut [f64], tau: f64) {
        on_isa!(
            isa,
            flow_tangent_avx512(self, part, x, w, tau),
            flow_tangent_avx2(self, part, x, w, tau),
            flow_tangent_with(self, part, x, w, tau),
        )
    }
}

/// The equations of motion, for the Runge-Kutta integrators (a reference for the compositions,
/// and `integrator.method = "dop853"` or `"gl6"` on a DDNLS): with `a_l = eps_l + beta J_l`,
/// `dq_l/dt = a_l p_l - sum_nb p`, `dp_l/dt = -a_l q_l + sum_nb q`.
impl VectorField for Ddnls {
    fn dim(&self) -> usize {
        2 * self.sites()
    }

    fn value(&self, x: &[f64], _t: f64, out: &mut [f64]) {
        let n = self.sites();
        let (q, p) = x.split_at(n);
        let (dq, dp) = out.split_at_mut(n);
        self.neighbour_sum(p, dq);
        self.neighbour_sum(q, dp);
        for l in 0..n {
            let a = self.eps[l] + self.beta * (0.5 * (q[l] * q[l] + p[l] * p[l]));
            dq[l] = a * p[l] - dq[l];
            dp[l] -= a * q[l];
        }
    }

    /// `d(dq)/dt = beta q p dq + (a + beta p^2) dp - sum_nb dp`,
    /// `d(dp)/dt = -(a + beta q^2) dq - beta q p dp + sum_nb dq`.
    fn tangent(&self, x: &[f64], _t: f64, v: &[f64], out: &mut [f64]) {
        let n = self.sites();
        let (q, p) = x.split_at(n);
        let (vq, vp) = v.split_at(n);
        let (dq, dp) = out.split_at_mut(n);
        self.neighbour_sum(vp, dq);
        self.neighbour_sum(vq, dp);
        for l in 0..n {
            let a = self.eps[l] + self.beta * (0.5 * (q[l] * q[l] + p[l] * p[l]));
            let bqp = self.beta * q[l] * p[l];
            dq[l] = (bqp * vq[l] + (a + self.beta * p[l] * p[l]) * vp[l]) - dq[l];
            dp[l] -= (a + self.beta * q[l] * q[l]) * vq[l] + bqp * vp[l];
        }
    }

    fn divergence(&self, _x: &[f64], _t: f64) -> f64 {
        0.0
    }

    fn no_tangent_reason(&self) -> Option<String> {
        None
    }

    fn diagnose_non_finite(&self, x: &[f64], _t: f64) -> Option<String> {
        self.diagnose(x)
    }

    fn energy(&self, x: &[f64], _t: f64) -> Option<f64> {
        Some(Ddnls::energy(self, x))
    }

    fn is_hamiltonian(&self) -> bool {
        true
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn chain() -> Ddnls {
        Ddnls::new(DdnlsLattice::Chain { n: 4 }, vec![0.3, -0.2, 0.1, 0.4], 1.5)
    }

    /// Every instruction set the CPU has gives the bits of the baseline one, for the three parts,
    /// on a chain longer than a chunk of the A flow and on a square (angles beyond the fast
    /// sine's range included: a site with a large norm).
    #[test]
    fn every_instruction_set_gives_the_same_bits() {
        for model in [
            Ddnls::new(
                DdnlsLattice::Chain { n: 150 },
                (0..150)
                    .map(|l| ((l * 7) % 13) as f64 / 3.0 - 2.0)
                    .collect(),
                0.9,
            ),
            Ddnls::new(
                DdnlsLattice::Square { n: 9 },
                (0..81).map(|l| ((l * 5) % 11) as f64 / 2.5 - 2.0).collect(),
                1.7,
            ),
        ] {
            let dim = 2 * model.sites();
            let mut x0: Vec<f64> = (0..dim).map(|i| (i as f64 * 0.37).sin()).collect();
            x0[3] = 3.0e3;
            let w0: Vec<f64> = (0..2 * dim).map(|i| (i as f64 * 0.11).cos()).collect();
            let run = |isa: Isa| {
                let (mut x, mut w) = (x0.clone(), w0.clone());
                for stage in 0..30 {
                    let tau = 0.05 + 0.01 * stage as f64;
                    model.flow_tangent_on(isa, stage % 3, &mut x, &mut w, tau);
                }
                x.iter().chain(&w).map(|v| v.to_bits()).collect::<Vec<_>>()
            };
            let baseline = run(Isa::Portable);
            for isa in Isa::ALL.into_iter().filter(|i| i.available()) {
                assert!(
                    run(isa) == baseline,
                    "{} differs from the baseline",
                    isa.name()
                );
            }
        }
    }

    /// The A flow on a chain of several chunks (and a last partial one) is each site's rotation
    /// by `(eps_l + beta J_l) tau` with the C library's sine and cosine, to rounding (the fast
    /// sine is within an ulp or two of it), and each vector moves by the rotation's derivative.
    #[test]
    fn the_on_site_flow_rotates_every_site_of_every_chunk() {
        let n = 2 * ROTATE_CHUNK + 13;
        let model = Ddnls::new(
            DdnlsLattice::Chain { n },
            (0..n).map(|l| ((l * 7) % 13) as f64 / 3.0 - 2.0).collect(),
            0.9,
        );
        let x0: Vec<f64> = (0..2 * n).map(|i| 1.5 * (i as f64 * 0.37).sin()).collect();
        let w0: Vec<f64> = (0..4 * n).map(|i| (i as f64 * 0.11).cos()).collect();
        let tau = 0.7;
        let (mut x, mut w) = (x0.clone(), w0.clone());
        model.flow_tangent(0, &mut x, &mut w, tau);
        for l in 0..n {
            let (q, p) = (x0[l], x0[n + l]);
            let a = model.eps[l] + model.beta * 0.5 * (q * q + p * p);
            let (s, c) = (a * tau).sin_cos();
            let (qn, pn) = (q * c + p * s, p * c - q * s);
            assert!(
                (x[l] - qn).abs() < 1e-14 && (x[n + l] - pn).abs() < 1e-14,
                "site {l}"
            );
            for v in 0..2 {
                let (dq, dp) = (w0[2 * n * v + l], w0[2 * n * v + n + l]);
                let td = tau * model.beta * (q * dq + p * dp);
                let want = (dq * c + dp * s + td * pn, dp * c - dq * s - td * qn);
                let got = (w[2 * n * v + l], w[2 * n * v + n + l]);
                assert!(
                    (got.0 - want.0).abs() < 1e-13 && (got.1 - want.1).abs() < 1e-13,
                    "vector {v}, site {l}"
                );
            }
        }
    }

    /// The neighbour sums written the plain way: each site's neighbours in the fixed order,
    /// a wall read as 0.
    fn naive_neighbour_sum(lattice: DdnlsLattice, v: &[f64]) -> Vec<f64> {
        match lattice {
            DdnlsLattice::Chain { n } => (0..n)
                .map(|l| {
                    let left = if l > 0 { v[l - 1] } else { 0.0 };
                    let right = if l + 1 < n { v[l + 1] } else { 0.0 };
                    left + right
                })
                .collect(),
            DdnlsLattice::Square { n } => (0..n * n)
                .map(|l| {
                    let (i, j) = (l / n, l % n);
                    let left = if j > 0 { v[l - 1] } else { 0.0 };
                    let right = if j + 1 < n { v[l + 1] } else { 0.0 };
                    let up = if i > 0 { v[l - n] } else { 0.0 };
                    let down = if i + 1 < n { v[l + n] } else { 0.0 };
                    ((left + right) + up) + down
                })
                .collect(),
        }
    }

    /// The hopping flows add the plain neighbour sums bit for bit, and `neighbour_sum` (what the
    /// equations of motion read) is them, on chains and squares with every edge case of size.
    #[test]
    fn hopping_adds_the_neighbour_sums_bit_for_bit() {
        for lattice in [1, 2, 3, 70].into_iter().flat_map(|n| {
            [
                DdnlsLattice::Chain { n },
                DdnlsLattice::Square { n: n.min(9) },
            ]
        }) {
            let sites = lattice.sites();
            let model = Ddnls::new(lattice, vec![0.0; sites], 1.0);
            let from: Vec<f64> = (0..sites).map(|l| (l as f64 * 0.77).sin() - 0.1).collect();
            let to0: Vec<f64> = (0..sites).map(|l| (l as f64 * 0.31).cos()).collect();
            let tau = 0.173;
            let sums = naive_neighbour_sum(lattice, &from);
            let mut out = vec![1.0; sites];
            model.neighbour_sum(&from, &mut out);
            assert!(
                out.iter()
                    .zip(&sums)
                    .all(|(a, b)| a.to_bits() == b.to_bits())
            );
            let want: Vec<u64> = to0
                .iter()
                .zip(&sums)
                .map(|(t, s)| (t + tau * s).to_bits())
                .collect();
            let mut to = to0.clone();
            model.add_neighbour_sums(&from, &mut to, tau);
            assert!(to.iter().map(|v| v.to_bits()).eq(want), "{lattice:?}");
        }
    }

    /// The energy's gradient is the field: `dq/dt = dH/dp`, `dp/dt = -dH/dq`, checked by
    /// central differences (error ~ d^2 |H'''| ~ 1e-10 with d = 1e-5, rounding ~ eps/d ~ 1e-11).
    #[test]
    fn the_field_is_the_energy_gradient() {
        for model in [
            chain(),
            Ddnls::new(
                DdnlsLattice::Square { n: 3 },
                (0..9).map(|l| 0.1 * l as f64 - 0.4).collect(),
                0.7,
            ),
        ] {
            let dim = 2 * model.sites();
            let n = model.sites();
            let x: Vec<f64> = (0..dim).map(|i| 0.3 * (i as f64 * 1.3).sin()).collect();
            let mut f = vec![0.0; dim];
            model.value(&x, 0.0, &mut f);
            for i in 0..dim {
                let d = 1e-5;
                let mut xp = x.clone();
                xp[i] += d;
                let mut xm = x.clone();
                xm[i] -= d;
                let g = (model.energy(&xp) - model.energy(&xm)) / (2.0 * d);
                // dH/dq_l = -dp_l/dt, dH/dp_l = dq_l/dt.
                let want = if i < n { -f[i + n] } else { f[i - n] };
                assert!((g - want).abs() < 1e-8, "coordinate {i}: {g} vs {want}");
            }
        }
    }
}
