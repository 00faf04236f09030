//! The fast Lyapunov indicator (Froeschle, Lega and Gonczi 1997) and its orthogonal variant
//! OFLI (Fouchard, Lega, Froeschle and Froeschle 2002).
//!
//! `FLI(t) = sup_{0 <= s <= t} ln |w(s)| / |w(0)|` of the first deviation vector of a set, read
//! at the renormalizations: `ln |w(t_j)| / |w(0)|` is the sum of the logarithms of the first
//! vector's stretching factors up to `t_j` (rescaling and QR both keep the first vector's
//! direction and report its own growth), so renormalization does not reset it. It grows like
//! `ln t` on a regular orbit (tangent vectors grow linearly) and like `lambda_1 t` on a chaotic
//! one.
//!
//! `OFLI(t)` is the same sup of `ln |w_perp(s)| / |w(0)|`, `w_perp` the component of `w`
//! orthogonal to the flow direction `f(x(s))`: on a regular orbit the growth along the flow
//! (the shear of neighbouring tori) is taken out, so a periodic orbit's OFLI stays bounded.
//! It needs the vector field at the reference state; a run that does not give it (a map has no
//! flow direction; a recording analyzed without its system) reports OFLI unavailable.

use crate::alignment::SIGMA_FLOOR;
use crate::indicator::{Declared, Needs, Output, SetIndicator, SetObservation};

#[derive(Debug, Clone, Default)]
pub struct Fli {
    /// `ln |w(t)| / |w(0)|` at the latest renormalization.
    log_norm: f64,
    /// The sup of `log_norm` so far (0 from t = 0, where `log_norm` is 0).
    fli: f64,
    /// The sup of the orthogonal log-norm; `None` before it could be computed.
    ofli: Option<f64>,
    /// Some renormalization came without the flow direction.
    flow_missing: bool,
}

impl SetIndicator for Fli {
    fn declared(&self) -> &'static [Declared] {
        const DECLARED: &[Declared] = &[
            Declared::named("fli", Needs::STRETCH),
            Declared::named("ofli", Needs::FLOW),
        ];
        DECLARED
    }

    fn observe(&mut self, obs: &SetObservation<'_>) {
        let Some(&first) = obs.stretch.first() else {
            return;
        };
        if obs.t > 0.0 {
            self.log_norm += first.ln();
        }
        self.fli = self.fli.max(self.log_norm);
        // A renormalization whose vectors were not recorded (between the samples of a run
        // sampled every `sample_every`): OFLI's sup is over the samples.
        if obs.separations.is_empty() {
            return;
        }
        let w = &obs.separations[..obs.dim.min(obs.separations.len())];
        match obs.flow {
            Some(f) if f.len() == w.len() => {
                let ratio = orthogonal_fraction(w, f);
                let value = self.log_norm + ratio.max(SIGMA_FLOOR).ln();
                self.ofli = Some(self.ofli.map_or(value, |o| o.max(value)));
            }
            _ => self.flow_missing = true,
        }
    }

    fn outputs(&self) -> Vec<Output> {
        let ofli = match self.ofli {
            Some(v) if !self.flow_missing => Output::Value(v),
            _ => Output::Unavailable(
                "OFLI needs the vector field at the reference state, which this run does not \
                 give (a map has no flow direction; a recording is analyzed with its system \
                 rebuilt from its config)"
                    .to_string(),
            ),
        };
        vec![Output::Value(self.fli), ofli]
    }

    fn boxed_clone(&self) -> Box<dyn SetIndicator> {
        Box::new(self.clone())
    }
}

/// `|w_perp| / |w|`, `w_perp` the component of `w` orthogonal to `f` (1 when `f` vanishes: at
/// an equilibrium there is no flow direction to take out).
fn orthogonal_fraction(w: &[f64], f: &[f64]) -> f64 {
    let ff: f64 = f.iter().map(|v| v * v).sum();
    let ww: f64 = w.iter().map(|v| v * v).sum();
    if ww == 0.0 || ff.is_nan() || ff <= 0.0 || !ff.is_finite() {
        return 1.0;
    }
    let wf: f64 = w.iter().zip(f).map(|(a, b)| a * b).sum();
    let along = wf / ff;
    let perp2: f64 = w
        .iter()
        .zip(f)
        .map(|(a, b)| {
            let d = a - along * b;
            d * d
        })
        .sum();
    (perp2 / ww).sqrt().min(1.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn obs<'a>(
        t: f64,
        sep: &'a [f64],
        stretch: &'a [f64],
        flow: Option<&'a [f64]>,
    ) -> SetObservation<'a> {
        SetObservation {
            t,
            dt: 1.0,
            covered: t,
            dim: 2,
            separations: sep,
            stretch,
            flow,
            sites: None,
            square_side: None,
            periodic: [false; 2],
            norm_conserved: false,
            state: None,
            site_energies: None,
        }
    }

    #[test]
    fn fli_is_the_sup_of_the_accumulated_log_norm() {
        let mut f = Fli::default();
        let e = std::f64::consts::E;
        f.observe(&obs(0.0, &[1.0, 0.0], &[1.0], Some(&[0.0, 1.0])));
        f.observe(&obs(1.0, &[e, 0.0], &[e], Some(&[0.0, 1.0])));
        f.observe(&obs(2.0, &[e * e, 0.0], &[e * e], Some(&[0.0, 1.0])));
        // Shrinks: the sup keeps 3.
        f.observe(&obs(3.0, &[1.0 / e, 0.0], &[1.0 / e], Some(&[1.0, 1.0])));
        let out = f.outputs();
        assert_eq!(out[0], Output::Value(3.0));
        // At t = 2 the vector is orthogonal to the flow: OFLI = FLI = 3 there; at t = 3 it is at
        // 45 degrees: 2 + ln(1/sqrt 2) < 3.
        let Output::Value(ofli) = out[1] else {
            panic!("{out:?}")
        };
        assert!((ofli - 3.0).abs() < 1e-15, "{ofli}");
        // Along the flow, the orthogonal part is floored at machine epsilon, never -inf.
        let mut g = Fli::default();
        g.observe(&obs(0.0, &[1.0, 0.0], &[1.0], Some(&[1.0, 0.0])));
        assert_eq!(g.outputs()[1], Output::Value(SIGMA_FLOOR.ln()));
        // Without the flow, OFLI says so.
        let mut h = Fli::default();
        h.observe(&obs(0.0, &[1.0, 0.0], &[1.0], None));
        assert!(matches!(h.outputs()[1], Output::Unavailable(_)));
    }
}
