//! The lane-wise view of a model: derivatives over `L` independent lanes at once, and the step
//! loops built from them.
//!
//! Every expression here repeats, lane by lane, the expression of the one-orbit code it replaces
//! (`Splitting::step`, `Splitting::step_tangent`, the model's `gradient` / `hessian_vector`): same
//! operations, same order, no fused multiply-add. That is what makes the batch bit-identical.

use crate::integrator::Splitting;
use crate::model::{At, SeparableHamiltonian};

/// One step of a splitting with its coefficients already multiplied by `h`: the very products
/// `a_i * h`, `b_i * h` that `Splitting::step` forms at each stage.
#[derive(Debug, Clone, PartialEq)]
pub struct StepCoeffs {
    /// `a_i h`, one more than kicks.
    pub drift: Vec<f64>,
    /// `b_i h`.
    pub kick: Vec<f64>,
}

impl StepCoeffs {
    pub fn new(splitting: &Splitting, h: f64) -> Self {
        Self {
            drift: splitting.drifts().iter().map(|a| a * h).collect(),
            kick: splitting.kicks().iter().map(|b| b * h).collect(),
        }
    }

    pub fn kicks(&self) -> usize {
        self.kick.len()
    }

    /// The last drift (after the last kick).
    #[inline(always)]
    pub fn last_drift(&self) -> f64 {
        self.drift[self.kick.len()]
    }
}

/// `q += c h M^-1 p` row by row, as `Splitting::drift` forms it (`ch * w_i` first).
#[inline(always)]
fn drift_rows<const L: usize>(
    q: &mut [[f64; L]],
    p: &[[f64; L]],
    ch: f64,
    inverse_masses: Option<&[f64]>,
) {
    for (i, (qr, pr)) in q.iter_mut().zip(p).enumerate() {
        let c = inverse_masses.map_or(ch, |w| ch * w[i]);
        for l in 0..L {
            qr[l] += c * pr[l];
        }
    }
}

#[inline(always)]
fn kick_rows<const L: usize>(p: &mut [[f64; L]], force: &[[f64; L]], dh: f64) {
    for (pr, fr) in p.iter_mut().zip(force) {
        for l in 0..L {
            pr[l] -= dh * fr[l];
        }
    }
}

/// A model whose derivatives can be evaluated over `L` lanes (structure of arrays).
///
/// Implementations must give, lane by lane, exactly the bits of the model's scalar `gradient`
/// and `hessian_vector`. The step loops have generic implementations; a model with few degrees
/// of freedom overrides them to keep the whole state in registers for many steps.
pub trait LaneHamiltonian: SeparableHamiltonian {
    /// The whole state of a chunk of lanes fits the vector registers during the step loops
    /// (few degrees of freedom): the kernel then uses wide chunks.
    const REGISTER_RESIDENT: bool = false;

    /// [`Self::REGISTER_RESIDENT`] decided at run time, for models whose size is known only
    /// then (a compiled expression): the kernel takes wide chunks when this holds. The default
    /// is the constant, so for the built-in models the dispatch folds to a constant.
    #[inline(always)]
    fn register_resident(&self) -> bool {
        Self::REGISTER_RESIDENT
    }

    /// Whether [`LaneHamiltonian::orbit_tangent_steps`] costs no more per lane than the model's
    /// separate orbit and tangent steps: true where both go through the same lane functions;
    /// false for a model whose separate steps run compiled step kernels that the generic fused
    /// loops (lane by lane through its scalar functions) would bypass.
    #[inline(always)]
    fn fuses_orbit_tangents(&self) -> bool {
        true
    }

    /// `out[i][l] = dV/dq_i` of lane `l`; `q` and `out` have `N` rows.
    fn gradient_lanes<const L: usize>(&self, q: &[[f64; L]], out: &mut [[f64; L]]);

    /// `out[.][l] = Hess V(q) v[.][l]` at one shared position `q` (the reference orbit).
    fn hessian_vector_lanes<const L: usize>(&self, q: &[f64], v: &[[f64; L]], out: &mut [[f64; L]]);

    /// `out[.][l] = Hess V(q[.][l]) v[.][l]`, each lane at its own position (`q`, `v`, `out`
    /// have `N` rows): the tangent maps of many orbits at once. The default is the scalar
    /// `hessian_vector` lane by lane (the bits every implementation must give).
    #[inline(always)]
    fn hessian_vector_each_lane<const L: usize>(
        &self,
        q: &[[f64; L]],
        v: &[[f64; L]],
        out: &mut [[f64; L]],
    ) {
        let n = self.dof();
        let (mut ql, mut vl, mut ol) = (vec![0.0; n], vec![0.0; n], vec![0.0; n]);
        for l in 0..L {
            for i in 0..n {
                ql[i] = q[i][l];
                vl[i] = v[i][l];
            }
            self.hessian_vector(&ql, At::T0, &vl, &mut ol);
            for i in 0..n {
                out[i][l] = ol[i];
            }
        }
    }

    /// [`orbit_tangent_steps`]: `L` orbits each with tangent vectors around itself. A model
    /// with few degrees of freedom overrides it to keep the state in registers.
    #[inline(always)]
    fn orbit_tangent_steps<const L: usize>(
        &self,
        c: &StepCoeffs,
        x: &mut [[f64; L]],
        force: &mut [[f64; L]],
        n_steps: u64,
    ) where
        Self: Sized,
    {
        orbit_tangent_steps_generic(self, c, x, force, n_steps)
    }

    /// `n_steps` steps of the splitting for `L` orbits; `x` has `2N` rows, `force` `N` rows.
    #[inline(always)]
    fn orbit_steps<const L: usize>(
        &self,
        c: &StepCoeffs,
        x: &mut [[f64; L]],
        force: &mut [[f64; L]],
        n_steps: u64,
    ) {
        orbit_steps_generic(self, c, x, force, n_steps)
    }

    /// `n_steps` steps of the tangent map for `L` deviation vectors around one reference orbit
    /// whose positions before each kick are `stages[(step * kicks + i) * N ..][..N]`.
    #[inline(always)]
    fn tangent_steps<const L: usize>(
        &self,
        c: &StepCoeffs,
        stages: &[f64],
        v: &mut [[f64; L]],
        force: &mut [[f64; L]],
        n_steps: u64,
    ) {
        tangent_steps_generic(self, c, stages, v, force, n_steps)
    }
}

/// [`LaneHamiltonian::orbit_steps`]'s generic loops: drift, the model's lane gradient, kick.
#[inline(always)]
pub(crate) fn orbit_steps_generic<M: LaneHamiltonian + ?Sized, const L: usize>(
    m: &M,
    c: &StepCoeffs,
    x: &mut [[f64; L]],
    force: &mut [[f64; L]],
    n_steps: u64,
) {
    let n = m.dof();
    let w = m.inverse_masses();
    let (q, p) = x.split_at_mut(n);
    for _ in 0..n_steps {
        for (&ch, &dh) in c.drift.iter().zip(&c.kick) {
            drift_rows(q, p, ch, w);
            m.gradient_lanes(q, force);
            kick_rows(p, force, dh);
        }
        drift_rows(q, p, c.last_drift(), w);
    }
}

/// [`LaneHamiltonian::tangent_steps`]'s generic loops: drift, the model's lane Hessian-vector product
/// at the recorded stage, kick.
#[inline(always)]
pub(crate) fn tangent_steps_generic<M: LaneHamiltonian + ?Sized, const L: usize>(
    m: &M,
    c: &StepCoeffs,
    stages: &[f64],
    v: &mut [[f64; L]],
    force: &mut [[f64; L]],
    n_steps: u64,
) {
    let n = m.dof();
    let w = m.inverse_masses();
    let (dq, dp) = v.split_at_mut(n);
    let mut stage = stages.chunks_exact(n);
    for _ in 0..n_steps {
        for (&ch, &dh) in c.drift.iter().zip(&c.kick) {
            drift_rows(dq, dp, ch, w);
            let q = stage.next().expect("one recorded position per kick");
            m.hessian_vector_lanes(q, dq, force);
            kick_rows(dp, force, dh);
        }
        drift_rows(dq, dp, c.last_drift(), w);
    }
}

/// Advance one reference orbit `x` by `n_steps` steps exactly as `Splitting::step` does, writing
/// its position before every kick to `stages` (`n_steps * kicks * N` numbers): what the tangent
/// map of all the point's deviation vectors needs.
pub fn record_reference_stages<M: SeparableHamiltonian + ?Sized>(
    model: &M,
    c: &StepCoeffs,
    x: &mut [f64],
    n_steps: u64,
    stages: &mut Vec<f64>,
    force: &mut [f64],
) {
    let n = model.dof();
    let w = model.inverse_masses();
    stages.clear();
    let drift = |x: &mut [f64], ch: f64| Splitting::drift(x, n, ch, w);
    for _ in 0..n_steps {
        for (&ch, &dh) in c.drift.iter().zip(&c.kick) {
            drift(x, ch);
            stages.extend_from_slice(&x[..n]);
            let (q, p) = x.split_at_mut(n);
            model.gradient(q, At::T0, force);
            for (pi, fi) in p.iter_mut().zip(force.iter()) {
                *pi -= dh * fi;
            }
        }
        drift(x, c.last_drift());
    }
}

/// `n_steps` steps of the splitting for `L` orbits, each with `vectors` tangent vectors around
/// itself: `x` has `2N` rows of orbit, then `2N` rows per tangent vector; `force` has `N` rows.
/// Lane by lane the bits of [`record_reference_stages`] followed by
/// [`LaneHamiltonian::tangent_steps`]: the tangent map of a kick is taken at the position the orbit
/// has before it, as the recorded stages hold it.
#[inline(always)]
pub(super) fn orbit_tangent_steps_generic<M: LaneHamiltonian, const L: usize>(
    m: &M,
    c: &StepCoeffs,
    x: &mut [[f64; L]],
    force: &mut [[f64; L]],
    n_steps: u64,
) {
    let n = m.dof();
    let w = m.inverse_masses();
    let (orbit, tangents) = x.split_at_mut(2 * n);
    for _ in 0..n_steps {
        for (&ch, &dh) in c.drift.iter().zip(&c.kick) {
            let (q, p) = orbit.split_at_mut(n);
            drift_rows(q, p, ch, w);
            for v in tangents.chunks_exact_mut(2 * n) {
                let (dq, dp) = v.split_at_mut(n);
                drift_rows(dq, dp, ch, w);
                m.hessian_vector_each_lane(q, dq, force);
                kick_rows(dp, force, dh);
            }
            m.gradient_lanes(q, force);
            kick_rows(p, force, dh);
        }
        let (q, p) = orbit.split_at_mut(n);
        drift_rows(q, p, c.last_drift(), w);
        for v in tangents.chunks_exact_mut(2 * n) {
            let (dq, dp) = v.split_at_mut(n);
            drift_rows(dq, dp, c.last_drift(), w);
        }
    }
}
