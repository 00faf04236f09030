//! The yardstick of `chaoscope bench`'s kernel cases: the ABA864 step of Henon-Heiles and of the
//! FPUT chain written as the plain structure-of-arrays loops one writes by hand, with no
//! abstraction (one flat array per coordinate row, every stage a loop over all lanes; no chunks,
//! no traits, no lane model), compiled for the same instruction set as the kernel beside it.
//!
//! Two arithmetics, chosen by the const parameter `FMA`:
//! - `false`: exactly the operations of the kernel and of the one-orbit engine in their order,
//!   so it gives the same bits (tested below): the fair yardstick of the kernel's overhead.
//! - `true`: every multiply-add fused (`mul_add`), what the step would cost if chaoscope gave up
//!   its no-FMA invariant (different bits; tested to agree to rounding).
//!
//! MPM advances independent orbits; VM records the reference orbit (scalar, as the kernel case
//! does with `record_reference_stages`) and advances tangent vectors around it.

use chaoscope_dynamics::batch::{Isa, StepCoeffs};

/// A model the plain loops are written for (unit masses).
#[derive(Debug, Clone, Copy)]
pub enum PlainModel {
    HenonHeiles,
    /// The beta-FPUT chain with fixed ends, `n >= 2` moving sites.
    Fput {
        n: usize,
        beta: f64,
    },
}

impl PlainModel {
    fn dof(self) -> usize {
        match self {
            PlainModel::HenonHeiles => 2,
            PlainModel::Fput { n, .. } => n,
        }
    }
}

/// Padding of every row, in numbers: one cache line. Rows of a power-of-two number of lanes
/// would otherwise sit a multiple of 4 KiB apart, and the CPU would take a store to one row
/// for a store to the next row's load at the same index (4K aliasing), stalling the loop on
/// false dependencies: the yardstick must not be slowed by its layout.
const ROW_PAD: usize = 8;

/// The state of one plain-loop case: `rows` rows of `lanes` numbers, `data[row * stride +
/// lane]` with `stride = lanes + ROW_PAD`, and for VM the reference orbit with its recorded
/// stage positions.
#[derive(Debug, Clone)]
pub struct PlainState {
    pub lanes: usize,
    stride: usize,
    data: Vec<f64>,
    /// The VM reference orbit (`2N` numbers); unused by MPM.
    pub reference: Vec<f64>,
    stages: Vec<f64>,
    scratch: Vec<f64>,
}

impl PlainState {
    /// `rows` is `data[row * lanes + lane]` (the layout of `Soa`), `2N` rows.
    pub fn new(model: PlainModel, lanes: usize, rows: &[f64], reference: Vec<f64>) -> Self {
        let n = model.dof();
        assert_eq!(rows.len(), 2 * n * lanes, "2N rows of `lanes` numbers");
        let stride = lanes + ROW_PAD;
        let mut data = vec![0.0; 2 * n * stride];
        for (d, r) in data.chunks_exact_mut(stride).zip(rows.chunks_exact(lanes)) {
            d[..lanes].copy_from_slice(r);
        }
        assert!(
            matches!(model, PlainModel::HenonHeiles) || n >= 2,
            "the plain FPUT loop needs N >= 2"
        );
        Self {
            lanes,
            stride,
            data,
            reference,
            stages: Vec::new(),
            // FPUT: the N + 1 bond forces of every lane.
            scratch: vec![0.0; (n + 1) * stride],
        }
    }

    /// The state as `data[row * lanes + lane]`.
    #[cfg(test)]
    pub fn rows(&self) -> Vec<f64> {
        let rows = self.data.chunks_exact(self.stride);
        rows.flat_map(|r| r[..self.lanes].iter().copied()).collect()
    }
}

/// The first `lanes` numbers of every row of `stride` numbers.
#[inline(always)]
fn rows_mut(x: &mut [f64], lanes: usize, stride: usize) -> impl Iterator<Item = &mut [f64]> {
    x.chunks_exact_mut(stride).map(move |r| &mut r[..lanes])
}

#[inline(always)]
fn rows(x: &[f64], lanes: usize, stride: usize) -> impl Iterator<Item = &[f64]> {
    x.chunks_exact(stride).map(move |r| &r[..lanes])
}

/// The four rows of a Henon-Heiles state.
#[inline(always)]
fn four_rows(x: &mut [f64], lanes: usize, stride: usize) -> [&mut [f64]; 4] {
    let mut r = rows_mut(x, lanes, stride);
    let mut next = || r.next().expect("four rows");
    [next(), next(), next(), next()]
}

/// `a * b + c`, rounded once (`FMA`) or twice (the kernel's arithmetic).
#[inline(always)]
fn madd<const FMA: bool>(a: f64, b: f64, c: f64) -> f64 {
    if FMA { a.mul_add(b, c) } else { a * b + c }
}

/// `n_steps` steps of every lane of `st` (MPM orbits, or VM tangent vectors when `tangent`).
#[inline(always)]
fn run<const FMA: bool>(
    model: PlainModel,
    tangent: bool,
    c: &StepCoeffs,
    st: &mut PlainState,
    n_steps: u64,
) {
    match (model, tangent) {
        (PlainModel::HenonHeiles, false) => {
            hh_orbits::<FMA>(c, four_rows(&mut st.data, st.lanes, st.stride), n_steps)
        }
        (PlainModel::HenonHeiles, true) => {
            hh_reference::<FMA>(c, &mut st.reference, &mut st.stages, n_steps);
            let v = four_rows(&mut st.data, st.lanes, st.stride);
            hh_tangents::<FMA>(c, &st.stages, v, n_steps)
        }
        (PlainModel::Fput { n, beta }, false) => {
            let x = (&mut st.data[..], &mut st.scratch[..], st.lanes, st.stride);
            fput_orbits::<FMA>(n, beta, c, x, n_steps)
        }
        (PlainModel::Fput { n, beta }, true) => {
            fput_reference::<FMA>(n, beta, c, &mut st.reference, &mut st.stages, n_steps);
            let v = (&mut st.data[..], st.lanes, st.stride);
            fput_tangents::<FMA>(n, beta, c, &st.stages, v, n_steps)
        }
    }
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,fma")]
fn run_avx512<const FMA: bool>(
    m: PlainModel,
    t: bool,
    c: &StepCoeffs,
    st: &mut PlainState,
    n: u64,
) {
    run::<FMA>(m, t, c, st, n)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
fn run_avx2<const FMA: bool>(m: PlainModel, t: bool, c: &StepCoeffs, st: &mut PlainState, n: u64) {
    run::<FMA>(m, t, c, st, n)
}

/// Whether the fused loop exists for `isa`: it needs the FMA instructions (the portable build
/// would call a library `fma` per operation, not a yardstick of anything).
pub fn has_fused(isa: Isa) -> bool {
    matches!(isa, Isa::Avx512 | Isa::Avx2) && isa.available()
}

/// Advances `st` by `n_steps` steps on `isa`, fused or not. Panics if the CPU lacks `isa`, or
/// if `fused` is asked where [`has_fused`] is false.
pub fn steps(
    isa: Isa,
    fused: bool,
    model: PlainModel,
    tangent: bool,
    c: &StepCoeffs,
    st: &mut PlainState,
    n_steps: u64,
) {
    assert!(
        isa.available(),
        "{} is not supported by this CPU",
        isa.name()
    );
    assert!(!fused || has_fused(isa), "no fused loop on {}", isa.name());
    match (isa, fused) {
        // SAFETY: the CPU supports the instruction set (checked above); every AVX2 and AVX-512
        // CPU has FMA (`Isa::available` checks it for AVX2).
        #[cfg(target_arch = "x86_64")]
        (Isa::Avx512, false) => unsafe { run_avx512::<false>(model, tangent, c, st, n_steps) },
        #[cfg(target_arch = "x86_64")]
        (Isa::Avx512, true) => unsafe { run_avx512::<true>(model, tangent, c, st, n_steps) },
        #[cfg(target_arch = "x86_64")]
        (Isa::Avx2, false) => unsafe { run_avx2::<false>(model, tangent, c, st, n_steps) },
        #[cfg(target_arch = "x86_64")]
        (Isa::Avx2, true) => unsafe { run_avx2::<true>(model, tangent, c, st, n_steps) },
        _ => run::<false>(model, tangent, c, st, n_steps),
    }
}

/// Henon-Heiles orbits: rows q1, q2, p1, p2.
#[inline(always)]
fn hh_orbits<const FMA: bool>(c: &StepCoeffs, x: [&mut [f64]; 4], n_steps: u64) {
    let [q1, q2, p1, p2] = x;
    let last = c.last_drift();
    for _ in 0..n_steps {
        for (&ch, &dh) in c.drift.iter().zip(&c.kick) {
            for (((a, b), u), v) in q1
                .iter_mut()
                .zip(q2.iter_mut())
                .zip(p1.iter_mut())
                .zip(p2.iter_mut())
            {
                *a = madd::<FMA>(ch, *u, *a);
                *b = madd::<FMA>(ch, *v, *b);
                let (a, b) = (*a, *b);
                // dV/dq1 = a + 2ab, dV/dq2 = b + a^2 - b^2.
                let g0 = madd::<FMA>(2.0 * a, b, a);
                let g1 = madd::<FMA>(-b, b, madd::<FMA>(a, a, b));
                *u = madd::<FMA>(-dh, g0, *u);
                *v = madd::<FMA>(-dh, g1, *v);
            }
        }
        for (((a, b), u), v) in q1
            .iter_mut()
            .zip(q2.iter_mut())
            .zip(p1.iter())
            .zip(p2.iter())
        {
            *a = madd::<FMA>(last, *u, *a);
            *b = madd::<FMA>(last, *v, *b);
        }
    }
}

/// The Henon-Heiles reference orbit (q1, q2, p1, p2), its position before every kick recorded.
#[inline(always)]
fn hh_reference<const FMA: bool>(
    c: &StepCoeffs,
    x: &mut [f64],
    stages: &mut Vec<f64>,
    n_steps: u64,
) {
    stages.clear();
    let last = c.last_drift();
    for _ in 0..n_steps {
        for (&ch, &dh) in c.drift.iter().zip(&c.kick) {
            x[0] = madd::<FMA>(ch, x[2], x[0]);
            x[1] = madd::<FMA>(ch, x[3], x[1]);
            let (a, b) = (x[0], x[1]);
            stages.extend_from_slice(&[a, b]);
            let g0 = madd::<FMA>(2.0 * a, b, a);
            let g1 = madd::<FMA>(-b, b, madd::<FMA>(a, a, b));
            x[2] = madd::<FMA>(-dh, g0, x[2]);
            x[3] = madd::<FMA>(-dh, g1, x[3]);
        }
        x[0] = madd::<FMA>(last, x[2], x[0]);
        x[1] = madd::<FMA>(last, x[3], x[1]);
    }
}

/// Henon-Heiles tangent vectors (rows dq1, dq2, dp1, dp2) around the recorded reference.
#[inline(always)]
fn hh_tangents<const FMA: bool>(c: &StepCoeffs, stages: &[f64], v: [&mut [f64]; 4], n_steps: u64) {
    let [u1, u2, w1, w2] = v;
    let last = c.last_drift();
    let mut stage = stages.chunks_exact(2);
    for _ in 0..n_steps {
        for (&ch, &dh) in c.drift.iter().zip(&c.kick) {
            let q = stage.next().expect("one recorded position per kick");
            let (h11, h12, h22) = (1.0 + 2.0 * q[1], 2.0 * q[0], 1.0 - 2.0 * q[1]);
            for (((a, b), s), t) in u1
                .iter_mut()
                .zip(u2.iter_mut())
                .zip(w1.iter_mut())
                .zip(w2.iter_mut())
            {
                *a = madd::<FMA>(ch, *s, *a);
                *b = madd::<FMA>(ch, *t, *b);
                let f0 = madd::<FMA>(h11, *a, h12 * *b);
                let f1 = madd::<FMA>(h12, *a, h22 * *b);
                *s = madd::<FMA>(-dh, f0, *s);
                *t = madd::<FMA>(-dh, f1, *t);
            }
        }
        for (((a, b), s), t) in u1
            .iter_mut()
            .zip(u2.iter_mut())
            .zip(w1.iter())
            .zip(w2.iter())
        {
            *a = madd::<FMA>(last, *s, *a);
            *b = madd::<FMA>(last, *t, *b);
        }
    }
}

/// The FPUT bond force `f(r) = r + beta r^3`, formed as `((beta r) r) r + r`.
#[inline(always)]
fn bond<const FMA: bool>(beta: f64, r: f64) -> f64 {
    madd::<FMA>(beta * r * r, r, r)
}

/// The FPUT bond stiffness `f'(r) = 1 + 3 beta r^2`, formed as `((3 beta) r) r + 1`.
#[inline(always)]
fn stiffness<const FMA: bool>(beta: f64, r: f64) -> f64 {
    madd::<FMA>(3.0 * beta * r, r, 1.0)
}

/// `q += c p` row by row (q and p are the two halves of the state).
#[inline(always)]
fn drift<const FMA: bool>(q: &mut [f64], p: &[f64], ch: f64, lanes: usize, stride: usize) {
    for (qr, pr) in rows_mut(q, lanes, stride).zip(rows(p, lanes, stride)) {
        for (a, u) in qr.iter_mut().zip(pr) {
            *a = madd::<FMA>(ch, *u, *a);
        }
    }
}

/// FPUT orbits: rows q_1..q_N, p_1..p_N; `bonds` holds the N + 1 bond forces of every lane.
#[inline(always)]
fn fput_orbits<const FMA: bool>(
    n: usize,
    beta: f64,
    c: &StepCoeffs,
    (x, bonds, lanes, stride): (&mut [f64], &mut [f64], usize, usize),
    n_steps: u64,
) {
    let (q, p) = x.split_at_mut(n * stride);
    for _ in 0..n_steps {
        for (&ch, &dh) in c.drift.iter().zip(&c.kick) {
            drift::<FMA>(q, p, ch, lanes, stride);
            // Bond j joins sites j - 1 and j (site -1 and site N are the fixed ends).
            let mut b = rows_mut(bonds, lanes, stride);
            let first = b.next().expect("N + 1 bonds");
            for (b, a) in first.iter_mut().zip(&q[..lanes]) {
                *b = bond::<FMA>(beta, *a);
            }
            let pairs = rows(q, lanes, stride).zip(rows(&q[stride..], lanes, stride));
            for (b, (lo, hi)) in b.by_ref().take(n - 1).zip(pairs) {
                for ((b, a), c) in b.iter_mut().zip(lo).zip(hi) {
                    *b = bond::<FMA>(beta, c - a);
                }
            }
            let end = b.next().expect("N + 1 bonds");
            for (b, a) in end.iter_mut().zip(&q[(n - 1) * stride..][..lanes]) {
                *b = bond::<FMA>(beta, -a);
            }
            drop(b);
            // Kick: dV/dq_i = f(bond i) - f(bond i + 1).
            let pairs = rows(bonds, lanes, stride).zip(rows(&bonds[stride..], lanes, stride));
            for (pr, (left, right)) in rows_mut(p, lanes, stride).zip(pairs) {
                for ((u, l), r) in pr.iter_mut().zip(left).zip(right) {
                    *u = madd::<FMA>(-dh, l - r, *u);
                }
            }
        }
        drift::<FMA>(q, p, c.last_drift(), lanes, stride);
    }
}

/// The FPUT reference orbit, its positions before every kick recorded; the force of each site
/// from its two bonds, as `FputBeta::gradient` forms it.
#[inline(always)]
fn fput_reference<const FMA: bool>(
    n: usize,
    beta: f64,
    c: &StepCoeffs,
    x: &mut [f64],
    stages: &mut Vec<f64>,
    n_steps: u64,
) {
    stages.clear();
    let (q, p) = x.split_at_mut(n);
    for _ in 0..n_steps {
        for (&ch, &dh) in c.drift.iter().zip(&c.kick) {
            drift::<FMA>(q, p, ch, n, n);
            stages.extend_from_slice(q);
            for i in 0..n {
                let left = if i == 0 { q[0] } else { q[i] - q[i - 1] };
                let right = if i + 1 < n { q[i + 1] - q[i] } else { -q[i] };
                let g = bond::<FMA>(beta, left) - bond::<FMA>(beta, right);
                p[i] = madd::<FMA>(-dh, g, p[i]);
            }
        }
        drift::<FMA>(q, p, c.last_drift(), n, n);
    }
}

/// FPUT tangent vectors (rows dq_1..dq_N, dp_1..dp_N) around the recorded reference: per stage
/// the N + 1 bond stiffnesses at the reference, then `Hess V dq` site by site.
#[inline(always)]
fn fput_tangents<const FMA: bool>(
    n: usize,
    beta: f64,
    c: &StepCoeffs,
    stages: &[f64],
    (v, lanes, stride): (&mut [f64], usize, usize),
    n_steps: u64,
) {
    let (dq, dp) = v.split_at_mut(n * stride);
    let mut k = vec![0.0; n + 1];
    let mut stage = stages.chunks_exact(n);
    for _ in 0..n_steps {
        for (&ch, &dh) in c.drift.iter().zip(&c.kick) {
            drift::<FMA>(dq, dp, ch, lanes, stride);
            let q = stage.next().expect("one recorded position per kick");
            k[0] = stiffness::<FMA>(beta, q[0]);
            for j in 1..n {
                k[j] = stiffness::<FMA>(beta, q[j] - q[j - 1]);
            }
            k[n] = stiffness::<FMA>(beta, -q[n - 1]);
            let row = |i: usize| &dq[i * stride..][..lanes];
            let mut w = rows_mut(dp, lanes, stride);
            let first = w.next().expect("N rows");
            for ((w, a), b) in first.iter_mut().zip(row(0)).zip(row(1)) {
                let f = madd::<FMA>(-k[1], b - a, k[0] * a);
                *w = madd::<FMA>(-dh, f, *w);
            }
            for (i, w) in w.by_ref().take(n - 2).enumerate() {
                let i = i + 1;
                let (left, right) = (k[i], k[i + 1]);
                for (((w, a), b), c) in w.iter_mut().zip(row(i - 1)).zip(row(i)).zip(row(i + 1)) {
                    let f = madd::<FMA>(-right, c - b, left * (b - a));
                    *w = madd::<FMA>(-dh, f, *w);
                }
            }
            let last = w.next().expect("N rows");
            for ((w, a), b) in last.iter_mut().zip(row(n - 2)).zip(row(n - 1)) {
                let f = madd::<FMA>(-k[n], -b, k[n - 1] * (b - a));
                *w = madd::<FMA>(-dh, f, *w);
            }
        }
        drift::<FMA>(dq, dp, c.last_drift(), lanes, stride);
    }
}

#[cfg(test)]
mod tests {
    use chaoscope_dynamics::batch::{self, LaneHamiltonian, Soa, record_reference_stages};
    use chaoscope_dynamics::integrator::{Splitting, SplittingScheme};
    use chaoscope_dynamics::model::{FputBeta, HenonHeiles};

    use super::*;

    /// Deterministic numbers in [-1, 1).
    fn noise(i: usize) -> f64 {
        let z = (i as u64 + 1).wrapping_mul(0x9e37_79b9_7f4a_7c15);
        let z = (z ^ (z >> 29)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        (z >> 11) as f64 / (1u64 << 52) as f64 - 1.0
    }

    /// The kernel (on `isa`) and the plain loops from the same start, `windows` windows of 100
    /// steps. Returns (kernel lanes, kernel reference, plain no-FMA, plain FMA if any).
    fn both<M: LaneHamiltonian>(
        isa: Isa,
        model: &M,
        plain: PlainModel,
        tangent: bool,
        lanes: usize,
        scale: f64,
        windows: usize,
    ) -> (Vec<f64>, Vec<f64>, PlainState, Option<PlainState>) {
        let dim = 2 * model.dof();
        let c = StepCoeffs::new(&Splitting::new(SplittingScheme::Aba864), 0.01);
        let data: Vec<f64> = (0..dim * lanes).map(|i| scale * noise(i)).collect();
        let x0: Vec<f64> = (0..dim).map(|r| scale * noise(7919 + r)).collect();
        let mut soa = Soa::new(dim, lanes);
        for r in 0..dim {
            for l in 0..lanes {
                soa.set(r, l, data[r * lanes + l]);
            }
        }
        let (mut x, mut stages, mut force) = (x0.clone(), Vec::new(), vec![0.0; model.dof()]);
        let mut st = PlainState::new(plain, lanes, &data, x0);
        let mut fused = has_fused(isa).then(|| st.clone());
        for _ in 0..windows {
            if tangent {
                record_reference_stages(model, &c, &mut x, 100, &mut stages, &mut force);
                batch::tangent_steps(isa, model, &c, &stages, &mut soa, 100);
            } else {
                batch::orbit_steps(isa, model, &c, &mut soa, 100);
            }
            steps(isa, false, plain, tangent, &c, &mut st, 100);
            if let Some(f) = fused.as_mut() {
                steps(isa, true, plain, tangent, &c, f, 100);
            }
        }
        let mut kernel = vec![0.0; dim * lanes];
        for r in 0..dim {
            for l in 0..lanes {
                kernel[r * lanes + l] = soa.get(r, l);
            }
        }
        (kernel, x, st, fused)
    }

    fn bits(v: &[f64]) -> Vec<u64> {
        v.iter().map(|x| x.to_bits()).collect()
    }

    /// The plain no-FMA loop is the kernel's arithmetic: the same bits, lanes and reference.
    /// The FMA loop rounds differently but integrates the same equations: over 300 steps of
    /// these bounded regular-scale states (|x| <= 0.05 for HH, 0.5 for FPUT) one rounding per
    /// operation of ~1e-17 grows at most linearly-to-mildly in a bounded orbit, far below 1e-9
    /// relative to the state's scale; a wrong coefficient or sign would move it by ~h = 1e-2.
    fn check<M: LaneHamiltonian>(
        model: &M,
        plain: PlainModel,
        tangent: bool,
        lanes: usize,
        scale: f64,
    ) {
        for isa in Isa::ALL.into_iter().filter(|i| i.available()) {
            let (kernel, x, st, fused) = both(isa, model, plain, tangent, lanes, scale, 3);
            assert_eq!(bits(&kernel), bits(&st.rows()), "{} {tangent}", isa.name());
            if tangent {
                assert_eq!(bits(&x), bits(&st.reference), "{} reference", isa.name());
            }
            if let Some(f) = fused {
                let size = kernel.iter().fold(0.0f64, |m, v| m.max(v.abs()));
                let diff = kernel
                    .iter()
                    .zip(&f.rows())
                    .fold(0.0f64, |m, (a, b)| m.max((a - b).abs()));
                assert!(
                    diff <= 1e-9 * size,
                    "{}: fused differs by {diff}",
                    isa.name()
                );
                assert!(
                    diff > 0.0 || kernel.iter().all(|v| *v == 0.0),
                    "FMA changes no bit?"
                );
            }
        }
    }

    #[test]
    fn henon_heiles_plain_loop_is_the_kernel() {
        check(&HenonHeiles, PlainModel::HenonHeiles, false, 64, 0.05);
        check(&HenonHeiles, PlainModel::HenonHeiles, true, 64, 0.05);
    }

    #[test]
    fn fput_plain_loop_is_the_kernel() {
        for n in [2, 5, 101] {
            let m = FputBeta::new(n, 1.0).unwrap();
            let plain = PlainModel::Fput { n, beta: 1.0 };
            check(&m, plain, false, 24, 0.5);
            check(&m, plain, true, 24, 0.5);
        }
    }
}
