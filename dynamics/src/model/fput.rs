//! The beta-Fermi-Pasta-Ulam-Tsingou chain with fixed ends (`x_0 = x_{N+1} = 0`):
//! `H = sum p_i^2/2 + sum_{i=0..N} [ r_i^2/2 + beta r_i^4/4 ]`, `r_i = x_{i+1} - x_i`.

use super::{At, SeparableHamiltonian};

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FputBeta {
    n: usize,
    beta: f64,
}

impl FputBeta {
    /// A chain of `n >= 1` moving particles with quartic coupling `beta` (finite).
    pub fn new(n: usize, beta: f64) -> Result<Self, String> {
        if n == 0 {
            return Err("fput-beta needs n >= 1 particles".into());
        }
        if !beta.is_finite() {
            return Err(format!("fput-beta needs a finite beta, got {beta}"));
        }
        Ok(Self { n, beta })
    }

    pub fn beta(&self) -> f64 {
        self.beta
    }

    /// Displacement of site `i` in `0..=N+1`, with the fixed ends.
    #[inline(always)]
    fn site(q: &[f64], i: usize, n: usize) -> f64 {
        if i == 0 || i == n + 1 { 0.0 } else { q[i - 1] }
    }

    /// Amplitude `A` of the SPO1 orbit at energy `h` (`H = (N+1)(A^2/2 + beta A^4/4)`), for odd
    /// `N`. Returns `None` when no real amplitude exists (e.g. `beta < 0` beyond the maximum).
    pub fn spo1_amplitude(&self, energy: f64) -> Option<f64> {
        let e = energy / (self.n as f64 + 1.0);
        if e.is_nan() || e < 0.0 {
            return None;
        }
        if self.beta == 0.0 {
            return Some((2.0 * e).sqrt());
        }
        // beta/4 A^4 + 1/2 A^2 - e = 0  =>  A^2 = (-1/2 + sqrt(1/4 + beta e)) / (beta/2)
        let disc = 0.25 + self.beta * e;
        if disc < 0.0 {
            return None;
        }
        // Written in the cancellation-free form A^2 = 2e / (1/2 + sqrt(disc)).
        let a2 = 2.0 * e / (0.5 + disc.sqrt());
        (a2 >= 0.0 && a2.is_finite()).then(|| a2.sqrt())
    }

    /// The SPO1 initial condition (`x_{2j} = 0`, `x_{2j-1} = -x_{2j+1} = A`, `p = 0`) at the
    /// given energy; odd `N` only.
    pub fn spo1(&self, energy: f64) -> Result<Vec<f64>, String> {
        if self.n.is_multiple_of(2) {
            return Err(format!("SPO1 exists for odd N only, got N = {}", self.n));
        }
        let a = self.spo1_amplitude(energy).ok_or_else(|| {
            format!(
                "no real SPO1 amplitude at energy {energy} (beta = {})",
                self.beta
            )
        })?;
        let mut x = vec![0.0; 2 * self.n];
        // Odd sites 1, 3, 5, ... (indices 0, 2, 4, ...) alternate +A, -A, ...; even sites stay 0.
        for (j, xi) in x[..self.n].iter_mut().step_by(2).enumerate() {
            *xi = if j % 2 == 0 { a } else { -a };
        }
        Ok(x)
    }
}

impl SeparableHamiltonian for FputBeta {
    fn name(&self) -> &str {
        "fput-beta"
    }

    fn dof(&self) -> usize {
        self.n
    }

    fn potential(&self, q: &[f64], _at: At<'_>) -> f64 {
        let n = self.n;
        let mut v = 0.0;
        for i in 0..=n {
            let r = Self::site(q, i + 1, n) - Self::site(q, i, n);
            let r2 = r * r;
            v += 0.5 * r2 + 0.25 * self.beta * r2 * r2;
        }
        v
    }

    #[inline]
    fn gradient(&self, q: &[f64], _at: At<'_>, out: &mut [f64]) {
        // dV/dq_i = f(r_{i-1}) - f(r_i) with f(r) = r + beta r^3, r_i = x_{i+1} - x_i. Each bond
        // force is evaluated for both of its sites: twice the arithmetic, but no loop-carried
        // value, so the interior loop vectorizes (and every expression, hence every bit, is the
        // same as with a carried value).
        let beta = self.beta;
        let f = |r: f64| r + beta * r * r * r;
        let n = self.n;
        if n == 1 {
            out[0] = f(q[0]) - f(-q[0]);
            return;
        }
        out[0] = f(q[0]) - f(q[1] - q[0]);
        for (o, w) in out[1..n - 1].iter_mut().zip(q.windows(3)) {
            *o = f(w[1] - w[0]) - f(w[2] - w[1]);
        }
        out[n - 1] = f(q[n - 1] - q[n - 2]) - f(-q[n - 1]);
    }

    #[inline]
    fn hessian_vector(&self, q: &[f64], _at: At<'_>, v: &[f64], out: &mut [f64]) {
        // Each bond contributes f'(r) = 1 + 3 beta r^2 times the bond's stretch of v; evaluated
        // per site as in `gradient`, for the same reason.
        let beta = self.beta;
        let g = |r: f64, dv: f64| (1.0 + 3.0 * beta * r * r) * dv;
        let n = self.n;
        if n == 1 {
            out[0] = g(q[0], v[0]) - g(-q[0], -v[0]);
            return;
        }
        out[0] = g(q[0], v[0]) - g(q[1] - q[0], v[1] - v[0]);
        for ((o, w), u) in out[1..n - 1].iter_mut().zip(q.windows(3)).zip(v.windows(3)) {
            *o = g(w[1] - w[0], u[1] - u[0]) - g(w[2] - w[1], u[2] - u[1]);
        }
        out[n - 1] = g(q[n - 1] - q[n - 2], v[n - 1] - v[n - 2]) - g(-q[n - 1], -v[n - 1]);
    }

    /// The orbit and its tangent vectors stage by stage in one call: the drifts, then the
    /// orbit's force and every vector's `Hess V dq` as [`SeparableHamiltonian::gradient`] and
    /// [`SeparableHamiltonian::hessian_vector`] form them (the same expressions, site by site), each kicked as
    /// it is formed; the vectors read the stage's positions where they are. So the bits of the
    /// splitting's `step` and `step_tangent`, without a second copy of the orbit or a buffer
    /// per force (the engine's carrier takes the orbit from here).
    fn reference_tangent_steps(
        &self,
        x: &mut [f64],
        v: &mut [f64],
        n_steps: u64,
        drift: &[f64],
        kick: &[f64],
    ) -> bool {
        let n = self.n;
        let dim = 2 * n;
        if n < 2 || x.len() != dim || !v.len().is_multiple_of(dim) || drift.len() != kick.len() + 1
        {
            return false;
        }
        let args = (self.beta, x, v, n_steps, drift, kick);
        // The same loops compiled for the widest instruction set the CPU has (as the batched
        // kernels): vectors of 8 or 4 sites where the baseline has 2. Rust never fuses a
        // multiply and an add, so every instruction set gives the same bits.
        crate::batch::on_isa!(
            crate::batch::Isa::detect(),
            fused_avx512(args),
            fused_avx2(args),
            fused(args),
        )
    }

    /// Bond `i` (`r_i = x_{i+1} - x_i`, `i = 0..N`) half to each of its particles; the bonds to
    /// the fixed walls whole to the end particle (a wall is no site). In bond order, as the
    /// same chain written as a `potential` lattice sum attributes it, so both give the same
    /// distribution to rounding.
    fn site_potentials(&self, q: &[f64], out: &mut [f64]) -> Result<(), String> {
        let n = self.n;
        if q.len() != n || out.len() != n {
            return Err(format!("{n} sites expected"));
        }
        out.fill(0.0);
        for i in 0..=n {
            let r = Self::site(q, i + 1, n) - Self::site(q, i, n);
            let r2 = r * r;
            let u = 0.5 * r2 + 0.25 * self.beta * r2 * r2;
            if i == 0 {
                out[0] += u;
            } else if i == n {
                out[n - 1] += u;
            } else {
                out[i - 1] += 0.5 * u;
                out[i] += 0.5 * u;
            }
        }
        Ok(())
    }

    fn preset(&self, name: &str, energy: f64) -> Option<Result<Vec<f64>, String>> {
        (name == "spo1").then(|| self.spo1(energy))
    }
}

/// The arguments of [`fused`]: `beta`, the orbit, the vectors, the steps, the splitting.
type FusedArgs<'a> = (f64, &'a mut [f64], &'a mut [f64], u64, &'a [f64], &'a [f64]);

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
fn fused_avx512(args: FusedArgs<'_>) -> bool {
    fused(args)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
fn fused_avx2(args: FusedArgs<'_>) -> bool {
    fused(args)
}

/// `FputBeta::reference_tangent_steps`' loops (the lengths checked by the caller).
#[inline(always)]
fn fused((beta, x, v, n_steps, drift, kick): FusedArgs<'_>) -> bool {
    let n = x.len() / 2;
    let dim = 2 * n;
    let f = |r: f64| r + beta * r * r * r;
    let g = |r: f64, dv: f64| (1.0 + 3.0 * beta * r * r) * dv;
    let drift_state = |y: &mut [f64], ch: f64| {
        let (q, p) = y.split_at_mut(n);
        for (qi, pi) in q.iter_mut().zip(p.iter()) {
            *qi += ch * pi;
        }
    };
    for _ in 0..n_steps {
        for (&ch, &dh) in drift.iter().zip(kick) {
            drift_state(x, ch);
            for y in v.chunks_exact_mut(dim) {
                drift_state(y, ch);
            }
            let (q, p) = x.split_at_mut(n);
            p[0] -= dh * (f(q[0]) - f(q[1] - q[0]));
            for (pi, w) in p[1..n - 1].iter_mut().zip(q.windows(3)) {
                *pi -= dh * (f(w[1] - w[0]) - f(w[2] - w[1]));
            }
            p[n - 1] -= dh * (f(q[n - 1] - q[n - 2]) - f(-q[n - 1]));
            for y in v.chunks_exact_mut(dim) {
                let (dq, dp) = y.split_at_mut(n);
                dp[0] -= dh * (g(q[0], dq[0]) - g(q[1] - q[0], dq[1] - dq[0]));
                for ((pi, w), u) in dp[1..n - 1].iter_mut().zip(q.windows(3)).zip(dq.windows(3)) {
                    *pi -= dh * (g(w[1] - w[0], u[1] - u[0]) - g(w[2] - w[1], u[2] - u[1]));
                }
                dp[n - 1] -=
                    dh * (g(q[n - 1] - q[n - 2], dq[n - 1] - dq[n - 2]) - g(-q[n - 1], -dq[n - 1]));
            }
        }
        let ch = drift[kick.len()];
        drift_state(x, ch);
        for y in v.chunks_exact_mut(dim) {
            drift_state(y, ch);
        }
    }
    true
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::check;

    #[test]
    fn derivatives_agree_with_potential() {
        for n in [1, 2, 5, 11] {
            let m = FputBeta::new(n, 1.3).unwrap();
            let q: Vec<f64> = (0..n).map(|i| 0.3 * ((i as f64) * 1.7).sin()).collect();
            let v: Vec<f64> = (0..n).map(|i| ((i as f64) * 0.9).cos()).collect();
            check::gradient_matches_potential(&m, &q);
            check::hessian_matches_gradient(&m, &q, &v);
        }
    }

    /// The fused pass is the splitting's `step` and `step_tangent`, bit for bit: chains of 2
    /// to 33 particles, 1 to 3 vectors, 1 to 7 steps of ABA864 (a chaotic amplitude, so a
    /// wrong last bit would grow); a single particle has no fused pass.
    #[test]
    fn fused_steps_are_the_splittings_bit_for_bit() {
        use crate::batch::StepCoeffs;
        use crate::integrator::{Integrator, Splitting, SplittingScheme, Workspace};
        let splitting = Splitting::new(SplittingScheme::Aba864);
        let h = 0.05;
        let c = StepCoeffs::new(&splitting, h);
        for n in [2usize, 3, 8, 33] {
            let m = FputBeta::new(n, 1.3).unwrap();
            for k in 1..=3 {
                for steps in [1u64, 7] {
                    let x0: Vec<f64> = (0..2 * n)
                        .map(|i| 0.9 * ((i as f64) * 1.37 + 0.2).sin())
                        .collect();
                    let v0: Vec<f64> = (0..k * 2 * n)
                        .map(|i| 1e-3 * ((i as f64) * 0.71).cos())
                        .collect();
                    let (mut x, mut v) = (x0.clone(), v0.clone());
                    let mut work = Workspace::new();
                    for s in 0..steps {
                        splitting
                            .step_tangent(&m, &mut x, &mut v, s as f64 * h, h, &mut work)
                            .unwrap();
                    }
                    let bits = |a: &[f64]| a.iter().map(|y| y.to_bits()).collect::<Vec<_>>();
                    // Every instruction set's instantiation the CPU has gives the same bits.
                    let (mut px, mut pv) = (x0.clone(), v0.clone());
                    assert!(fused((1.3, &mut px, &mut pv, steps, &c.drift, &c.kick)));
                    #[cfg(target_arch = "x86_64")]
                    for isa in [crate::batch::Isa::Avx2, crate::batch::Isa::Avx512] {
                        if !isa.available() {
                            continue;
                        }
                        let (mut ix, mut iv) = (x0.clone(), v0.clone());
                        let a = (
                            1.3,
                            &mut ix[..],
                            &mut iv[..],
                            steps,
                            &c.drift[..],
                            &c.kick[..],
                        );
                        // SAFETY: the CPU has the instruction set (checked above).
                        assert!(unsafe {
                            match isa {
                                crate::batch::Isa::Avx2 => fused_avx2(a),
                                _ => fused_avx512(a),
                            }
                        });
                        assert_eq!((bits(&ix), bits(&iv)), (bits(&px), bits(&pv)), "{isa:?}");
                    }
                    let (mut fx, mut fv) = (x0, v0);
                    assert!(m.reference_tangent_steps(&mut fx, &mut fv, steps, &c.drift, &c.kick));
                    assert_eq!((bits(&fx), bits(&fv)), (bits(&px), bits(&pv)), "portable");
                    assert_eq!(
                        bits(&fx),
                        bits(&x),
                        "N = {n}, k = {k}, {steps} steps: orbit"
                    );
                    assert_eq!(
                        bits(&fv),
                        bits(&v),
                        "N = {n}, k = {k}, {steps} steps: vectors"
                    );
                    // The one-orbit step moves the orbit alike.
                    let mut y = fx.clone();
                    let mut z = x.clone();
                    splitting.step(&m, &mut y, 0.0, h, &mut work);
                    let mut none = Vec::new();
                    splitting
                        .step_tangent(&m, &mut z, &mut none, 0.0, h, &mut work)
                        .unwrap();
                    assert_eq!(bits(&y), bits(&z));
                }
            }
        }
        let single = FputBeta::new(1, 1.0).unwrap();
        let c1 = StepCoeffs::new(&splitting, h);
        assert!(!single.reference_tangent_steps(
            &mut [0.1, 0.2],
            &mut [1.0, 0.0],
            1,
            &c1.drift,
            &c1.kick
        ));
    }

    #[test]
    fn spo1_has_the_requested_energy() {
        for (n, e) in [(5, 7.4), (11, 1.98), (101, 1.515)] {
            let m = FputBeta::new(n, 1.0).unwrap();
            let x = m.spo1(e).unwrap();
            assert!((m.energy(&x, At::T0) - e).abs() < 1e-13 * e, "N = {n}");
            assert_eq!(x[1], 0.0);
            assert_eq!(x[0], -x[2]);
        }
        assert!(FputBeta::new(4, 1.0).unwrap().spo1(1.0).is_err());
        assert!(FputBeta::new(5, -1.0).unwrap().spo1(100.0).is_err());
    }
}
