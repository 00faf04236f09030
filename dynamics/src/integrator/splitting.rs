//! Symplectic splitting methods `A B A ... B A` for `H = A(p) + B(q)`.
//!
//! A drift `A(c)` moves positions `q += c h p`; a kick `B(d)` moves momenta
//! `p -= d h dV/dq(q)`. The tangent map applies the derivative of each split flow exactly:
//! drift `dq += c h dp`, kick `dp -= d h Hess V(q) dq` with `q` the orbit's position at that
//! stage, so the variational method shares the integrator's splitting and order.
//!
//! Time (`V(q, t)`, a non-autonomous potential) is handled in the extended phase space: `t`
//! is one more coordinate, conjugate to a momentum `p_t` (minus the energy), and `H(q, p, t) =
//! T(p) + V(q, t)` becomes the autonomous `K = (T(p) + p_t) + V(q, t)`, split into
//! `A = T(p) + p_t`, whose flow drifts `q` *and* advances `t` by the drift's `a_i h`, and `B =
//! V(q, t)`, whose flow kicks `p` (and `p_t`, which nothing reads) at fixed `q` and `t`. So a
//! kick takes the time the drifts before it accumulated, `t + (a_1 + ... + a_i) h` (the sums
//! fixed once per splitting, [`Splitting::kick_times`]), and the method keeps its order: it is
//! the same splitting of an autonomous Hamiltonian of one more degree of freedom, of the same
//! `T + V` form. The tangent kick takes `Hess V` at the same time. A potential that does not
//! read the time gets the same bits as without this extension.
//!
//! Steps are never merged across step boundaries (the trailing drift of one step with the
//! leading drift of the next): outputs are full steps and the reference orbit is bit-identical
//! whatever the sampling or renormalization period.

use super::composition::{Composition, CompositionScheme};
use super::{Integrator, TangentError, Workspace};
use crate::model::{At, SeparableHamiltonian};

/// The splittings chaoscope ships.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum SplittingScheme {
    /// Second-order Stormer-Verlet, `A(1/2) B(1) A(1/2)`.
    Leapfrog,
    /// Laskar-Robutel SABA2, order 2 (4 for small perturbations).
    Saba2,
    /// Laskar-Robutel SABA3, order 2 (6 for small perturbations).
    Saba3,
    /// Laskar-Robutel SABA4, order 2 (8 for small perturbations).
    Saba4,
    /// Yoshida's fourth-order triple jump of the leapfrog.
    Yoshida4,
    /// Blanes, Casas, Farres, Laskar, Makazaga, Murua (2013), order (8,6,4).
    Aba864,
    /// Blanes et al. (2013), order (10,4).
    Aba104,
    /// Blanes et al. (2013), order (10,6,4).
    Aba1064,
    /// Kahan and Li's `s9odr6a` composition of the leapfrog: order 6, 9 kicks.
    S9odr6,
    /// Sofroniou and Spaletta's 11-stage composition of the leapfrog: order 6.
    S11odr6,
    /// Kahan and Li's `s17odr8a` composition of the leapfrog: order 8, 17 kicks. At the
    /// accuracies GALI needs (energy errors of 1e-10 and below) it takes steps several times
    /// longer than the fourth-order methods for fewer kicks per unit time.
    S17odr8,
}

impl SplittingScheme {
    pub const ALL: [SplittingScheme; 11] = [
        SplittingScheme::Leapfrog,
        SplittingScheme::Saba2,
        SplittingScheme::Saba3,
        SplittingScheme::Saba4,
        SplittingScheme::Yoshida4,
        SplittingScheme::Aba864,
        SplittingScheme::Aba104,
        SplittingScheme::Aba1064,
        SplittingScheme::S9odr6,
        SplittingScheme::S11odr6,
        SplittingScheme::S17odr8,
    ];

    pub fn name(self) -> &'static str {
        match self {
            SplittingScheme::Leapfrog => "leapfrog",
            SplittingScheme::Saba2 => "saba2",
            SplittingScheme::Saba3 => "saba3",
            SplittingScheme::Saba4 => "saba4",
            SplittingScheme::Yoshida4 => "yoshida4",
            SplittingScheme::Aba864 => "aba864",
            SplittingScheme::Aba104 => "aba104",
            SplittingScheme::Aba1064 => "aba1064",
            SplittingScheme::S9odr6 => "s9odr6",
            SplittingScheme::S11odr6 => "s11odr6",
            SplittingScheme::S17odr8 => "s17odr8",
        }
    }

    /// The order for any split `H = A + B` (the energy error of a step falls as `h^order`
    /// times the step count).
    pub fn order(self) -> u32 {
        match self {
            SplittingScheme::Leapfrog
            | SplittingScheme::Saba2
            | SplittingScheme::Saba3
            | SplittingScheme::Saba4 => 2,
            SplittingScheme::Yoshida4
            | SplittingScheme::Aba864
            | SplittingScheme::Aba104
            | SplittingScheme::Aba1064 => 4,
            SplittingScheme::S9odr6 | SplittingScheme::S11odr6 => 6,
            SplittingScheme::S17odr8 => 8,
        }
    }

    /// The orders for a near-integrable split `H = A + eps B` as the literature writes them:
    /// `(r_1, r_2, ...)` means an error `O(eps h^r_1 + eps^2 h^r_2 + ...)`, so at small `eps`
    /// the first one rules (Laskar and Robutel 2001; Blanes et al. 2013). The general order is
    /// the last entry.
    pub fn near_integrable_orders(self) -> &'static [u32] {
        match self {
            SplittingScheme::Leapfrog => &[2],
            SplittingScheme::Saba2 => &[4, 2],
            SplittingScheme::Saba3 => &[6, 2],
            SplittingScheme::Saba4 => &[8, 2],
            SplittingScheme::Yoshida4 => &[4],
            SplittingScheme::Aba864 => &[8, 6, 4],
            SplittingScheme::Aba104 => &[10, 4],
            SplittingScheme::Aba1064 => &[10, 6, 4],
            SplittingScheme::S9odr6 | SplittingScheme::S11odr6 => &[6],
            SplittingScheme::S17odr8 => &[8],
        }
    }

    /// Every splitting with its orders, as error messages and `--help` list them:
    /// `leapfrog (order 2), saba2 (order 2; (4,2) near integrable), ...`.
    pub fn catalogue() -> String {
        Self::ALL
            .iter()
            .map(|k| {
                let near = k.near_integrable_orders();
                if near.len() > 1 {
                    let orders: Vec<String> = near.iter().map(u32::to_string).collect();
                    format!(
                        "{} (order {}; ({}) near integrable)",
                        k.name(),
                        k.order(),
                        orders.join(",")
                    )
                } else {
                    format!("{} (order {})", k.name(), k.order())
                }
            })
            .collect::<Vec<_>>()
            .join(", ")
    }

    pub fn from_name(name: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|k| k.name() == name)
    }
}

/// A palindromic splitting `A(a_1) B(b_1) A(a_2) ... B(b_m) A(a_{m+1})`.
#[derive(Debug, Clone, PartialEq)]
pub struct Splitting {
    kind: SplittingScheme,
    order: u32,
    drifts: Vec<f64>,
    kicks: Vec<f64>,
    /// `c_i = a_1 + ... + a_i`: kick `i` of a step from `t` acts at `t + c_i h`.
    kick_times: Vec<f64>,
}

// ABA864 coefficients, full precision as published (numerics.md; REBOUND `lf8_6_4_a/b`).
#[allow(clippy::excessive_precision)]
const ABA864_A: [f64; 4] = [
    0.0711334264982231177779387300061549964174,
    0.241153427956640098736487795326289649618,
    0.521411761772814789212136078067994229991,
    -0.333698616227678005726562603400438876027,
];
#[allow(clippy::excessive_precision)]
const ABA864_B: [f64; 4] = [
    0.183083687472197221961703757166430291072,
    0.310782859898574869507522291054262796375,
    -0.0265646185119588006972121379164987592663,
    0.0653961422823734184559721793911134363710,
];

// ABA(10,4) and ABA(10,6,4) of Blanes et al. (2013), Table 3, as published: the drifts
// `a_1..a_4` (`a_5` of ABA(10,6,4)) and kicks `b_1..b_4` of the first half of the palindrome.
#[allow(clippy::excessive_precision)]
const ABA104_A: [f64; 4] = [
    0.04706710064597250612947887637243678556564,
    0.1847569354170881069247376193702560968574,
    0.2827060056798362053243616565541452479160,
    -0.01453004174289681837857815229683813033908,
];
#[allow(clippy::excessive_precision)]
const ABA104_B: [f64; 4] = [
    0.1188819173681970199453503950853885936957,
    0.2410504605515015657441667865901651105675,
    -0.2732866667053238060543113981664559460630,
    0.8267085775712504407295884329818044835997,
];
#[allow(clippy::excessive_precision)]
const ABA1064_A: [f64; 5] = [
    0.03809449742241219545697532230863756534060,
    0.1452987161169137492940200726606637497442,
    0.2076276957255412507162056113249882065158,
    0.4359097036515261592231548624010651844006,
    -0.6538612258327867093807117373907094120024,
];
#[allow(clippy::excessive_precision)]
const ABA1064_B: [f64; 4] = [
    0.09585888083707521061077150377145884776921,
    0.2044461531429987806805077839164344779763,
    0.2170703479789911017143385924306336714532,
    -0.01737538195906509300561788011852699719871,
];

// SABA3 and SABA4 (Laskar and Robutel 2001): kicks at the Gauss-Legendre nodes of [0, 1] with
// their weights; the drifts are the gaps between the nodes. Written out to 40 digits (the closed
// forms `1/2 - sqrt(15)/10`, `1/2 - sqrt(3/7 + 2/7 sqrt(6/5))/2`, ... evaluated in high
// precision), so no coefficient carries an f64 square root's rounding.
#[allow(clippy::excessive_precision)]
const SABA3_A: [f64; 2] = [
    0.1127016653792583114820734600217600389167,
    0.3872983346207416885179265399782399610833,
];
const SABA3_B: [f64; 2] = [5.0 / 18.0, 4.0 / 9.0];
#[allow(clippy::excessive_precision)]
const SABA4_A: [f64; 3] = [
    0.06943184420297371238802675555359524745214,
    0.2605776340045981552106403648947824089476,
    0.3399810435848562648026657591032446872006,
];
#[allow(clippy::excessive_precision)]
const SABA4_B: [f64; 2] = [
    0.1739274225687269286865319746109997036177,
    0.3260725774312730713134680253890002963823,
];

/// The drifts and kicks of a composition of the leapfrog `A(g/2) B(g) A(g/2)` with the
/// composition's weights `g`: the three-part compositions' constants on two parts, consecutive
/// drifts merged.
fn leapfrog_composition(kind: CompositionScheme) -> (Vec<f64>, Vec<f64>) {
    let stages = Composition::new(kind, 2);
    let part = |p: usize| {
        stages
            .stages()
            .iter()
            .filter(move |(q, _)| *q == p)
            .map(|&(_, c)| c)
            .collect::<Vec<f64>>()
    };
    (part(0), part(1))
}

impl Splitting {
    pub fn new(kind: SplittingScheme) -> Self {
        let (drifts, kicks) = match kind {
            SplittingScheme::Leapfrog => (vec![0.5, 0.5], vec![1.0]),
            SplittingScheme::Saba2 => {
                let a1 = 0.5 - 3f64.sqrt() / 6.0;
                let a2 = 3f64.sqrt() / 3.0;
                (vec![a1, a2, a1], vec![0.5, 0.5])
            }
            SplittingScheme::Saba3 => {
                let [a1, a2] = SABA3_A;
                let [b1, b2] = SABA3_B;
                (vec![a1, a2, a2, a1], vec![b1, b2, b1])
            }
            SplittingScheme::Saba4 => {
                let [a1, a2, a3] = SABA4_A;
                let [b1, b2] = SABA4_B;
                (vec![a1, a2, a3, a2, a1], vec![b1, b2, b2, b1])
            }
            SplittingScheme::Yoshida4 => {
                let cbrt2 = 2f64.cbrt();
                let w1 = 1.0 / (2.0 - cbrt2);
                let w0 = -cbrt2 / (2.0 - cbrt2);
                (
                    vec![w1 / 2.0, (w0 + w1) / 2.0, (w0 + w1) / 2.0, w1 / 2.0],
                    vec![w1, w0, w1],
                )
            }
            SplittingScheme::Aba864 => {
                let [a1, a2, a3, a4] = ABA864_A;
                let [b1, b2, b3, b4] = ABA864_B;
                (
                    vec![a1, a2, a3, a4, a4, a3, a2, a1],
                    vec![b1, b2, b3, b4, b3, b2, b1],
                )
            }
            SplittingScheme::Aba104 => {
                let [a1, a2, a3, a4] = ABA104_A;
                let [b1, b2, b3, b4] = ABA104_B;
                (
                    vec![a1, a2, a3, a4, a4, a3, a2, a1],
                    vec![b1, b2, b3, b4, b3, b2, b1],
                )
            }
            SplittingScheme::Aba1064 => {
                let [a1, a2, a3, a4, a5] = ABA1064_A;
                let [b1, b2, b3, b4] = ABA1064_B;
                (
                    vec![a1, a2, a3, a4, a5, a4, a3, a2, a1],
                    vec![b1, b2, b3, b4, b4, b3, b2, b1],
                )
            }
            SplittingScheme::S9odr6 => leapfrog_composition(CompositionScheme::S9Abc6),
            SplittingScheme::S11odr6 => leapfrog_composition(CompositionScheme::S11Abc6),
            SplittingScheme::S17odr8 => leapfrog_composition(CompositionScheme::S17Abc8),
        };
        let order = kind.order();
        debug_assert_eq!(drifts.len(), kicks.len() + 1);
        let kick_times = drifts[..kicks.len()]
            .iter()
            .scan(0.0, |c: &mut f64, &a| {
                *c += a;
                Some(*c)
            })
            .collect();
        Self {
            kind,
            order,
            drifts,
            kicks,
            kick_times,
        }
    }

    pub fn kind(&self) -> SplittingScheme {
        self.kind
    }

    /// Drift coefficients `a_i` (one more than kicks).
    pub fn drifts(&self) -> &[f64] {
        &self.drifts
    }

    /// Kick coefficients `b_i`.
    pub fn kicks(&self) -> &[f64] {
        &self.kicks
    }

    /// The time of each kick within a step, in units of `h`: `c_i = a_1 + ... + a_i`, the time
    /// the drifts before it advanced the extended phase space's `t` (see the module header).
    pub fn kick_times(&self) -> &[f64] {
        &self.kick_times
    }

    /// `q += c h M^-1 p`. With masses the coefficient of site `i` is `(c h) / m_i` formed first
    /// (`ch * w_i`), so unit masses give exactly the bits of the mass-free drift.
    #[inline(always)]
    pub(crate) fn drift(x: &mut [f64], n: usize, ch: f64, inverse_masses: Option<&[f64]>) {
        let (q, p) = x.split_at_mut(n);
        match inverse_masses {
            None => {
                for (qi, pi) in q.iter_mut().zip(p.iter()) {
                    *qi += ch * pi;
                }
            }
            Some(w) => {
                for ((qi, pi), wi) in q.iter_mut().zip(p.iter()).zip(w) {
                    *qi += (ch * wi) * pi;
                }
            }
        }
    }

    #[inline(always)]
    fn kick<M: SeparableHamiltonian + ?Sized>(
        model: &M,
        x: &mut [f64],
        n: usize,
        t: f64,
        dh: f64,
        force: &mut [f64],
    ) {
        let (q, p) = x.split_at_mut(n);
        model.gradient(q, At::time(t), force);
        for (pi, fi) in p.iter_mut().zip(force.iter()) {
            *pi -= dh * fi;
        }
    }
}

impl<M: SeparableHamiltonian + ?Sized> Integrator<M> for Splitting {
    fn name(&self) -> &str {
        self.kind.name()
    }

    fn order(&self) -> u32 {
        self.order
    }

    fn step(&self, model: &M, x: &mut [f64], t: f64, h: f64, work: &mut Workspace) {
        let n = model.dof();
        let w = model.inverse_masses();
        let force = work.force(n);
        for (i, &d) in self.kicks.iter().enumerate() {
            Self::drift(x, n, self.drifts[i] * h, w);
            Self::kick(model, x, n, t + self.kick_times[i] * h, d * h, force);
        }
        Self::drift(x, n, self.drifts[self.kicks.len()] * h, w);
    }

    fn step_tangent(
        &self,
        model: &M,
        x: &mut [f64],
        w: &mut [f64],
        t: f64,
        h: f64,
        work: &mut Workspace,
    ) -> Result<(), TangentError> {
        if let Some(reason) = model.no_hessian_reason() {
            return Err(TangentError::NoHessian(reason));
        }
        let n = model.dof();
        let dim = 2 * n;
        let masses = model.inverse_masses();
        let force = work.force(n);
        let drift_all = |x: &mut [f64], w: &mut [f64], ch: f64| {
            Self::drift(x, n, ch, masses);
            for v in w.chunks_exact_mut(dim) {
                Self::drift(v, n, ch, masses);
            }
        };
        for (i, &d) in self.kicks.iter().enumerate() {
            drift_all(x, w, self.drifts[i] * h);
            let dh = d * h;
            let tk = t + self.kick_times[i] * h;
            // Tangent kicks use the position before the orbit's own kick (same stage), at the
            // kick's time.
            for v in w.chunks_exact_mut(dim) {
                let (dq, dp) = v.split_at_mut(n);
                model.hessian_vector(&x[..n], At::time(tk), dq, force);
                for (pi, fi) in dp.iter_mut().zip(force.iter()) {
                    *pi -= dh * fi;
                }
            }
            Self::kick(model, x, n, tk, dh, force);
        }
        drift_all(x, w, self.drifts[self.kicks.len()] * h);
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn coefficients_are_consistent() {
        for kind in SplittingScheme::ALL {
            let s = Splitting::new(kind);
            let sa: f64 = s.drifts().iter().sum();
            let sb: f64 = s.kicks().iter().sum();
            assert!((sa - 1.0).abs() < 1e-15, "{kind:?} drifts sum {sa}");
            assert!((sb - 1.0).abs() < 1e-15, "{kind:?} kicks sum {sb}");
            let n = s.drifts().len();
            for i in 0..n {
                assert_eq!(
                    s.drifts()[i],
                    s.drifts()[n - 1 - i],
                    "{kind:?} not palindromic"
                );
            }
        }
        let a = ABA864_A;
        let b = ABA864_B;
        assert!((2.0 * (a[0] + a[1] + a[2] + a[3]) - 1.0).abs() < 1e-15);
        assert!((2.0 * (b[0] + b[1] + b[2]) + b[3] - 1.0).abs() < 1e-15);
    }

    /// The SABA literals are the Gauss-Legendre nodes and weights of [0, 1] (to the last bit
    /// an f64 evaluation of the closed forms can check, a few ulps).
    #[test]
    fn saba_coefficients_are_the_gauss_legendre_nodes() {
        let close = |x: f64, y: f64| (x - y).abs() <= 4.0 * f64::EPSILON * y.abs().max(1.0);
        let r15 = 15f64.sqrt() / 10.0;
        assert!(close(SABA3_A[0], 0.5 - r15) && close(SABA3_A[1], r15));
        let inner = (6.0f64 / 5.0).sqrt() * 2.0 / 7.0;
        let x1 = 0.5 - (3.0 / 7.0 + inner).sqrt() / 2.0;
        let x2 = 0.5 - (3.0 / 7.0 - inner).sqrt() / 2.0;
        assert!(close(SABA4_A[0], x1));
        assert!(close(SABA4_A[1], x2 - x1));
        assert!(close(SABA4_A[2], 1.0 - 2.0 * x2));
        let r30 = 30f64.sqrt();
        assert!(close(SABA4_B[0], (18.0 - r30) / 72.0));
        assert!(close(SABA4_B[1], (18.0 + r30) / 72.0));
    }

    #[test]
    fn every_splitting_is_listed_with_its_orders() {
        let list = SplittingScheme::catalogue();
        assert!(list.starts_with("leapfrog (order 2), saba2 (order 2; (4,2) near integrable)"));
        assert!(list.contains("aba1064 (order 4; (10,6,4) near integrable)"));
        for kind in SplittingScheme::ALL {
            assert_eq!(SplittingScheme::from_name(kind.name()), Some(kind));
            assert_eq!(kind.near_integrable_orders().last(), Some(&kind.order()));
        }
    }
}
