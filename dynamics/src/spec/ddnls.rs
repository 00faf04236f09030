//! `[model] name = "ddnls"`: the disordered discrete nonlinear Schroedinger lattice, its
//! disorder drawn from `seed`, integrated by a composition of its three parts' exact flows
//! (`abc2` .. `s17abc8`) or, as a reference, by a Runge-Kutta method (`dop853`, `gl6`, ...).
//! The initial state is `[orbit] q`/`p` (or `x`), or `excite`: one site or a block (an `L x L`
//! square in 2-D) sharing a norm or an energy, with phases 0 or drawn from a seed.

use std::sync::Arc;

use chaoscope_schemas::config::{DdnlsConfig, Excitation, OrbitConfig, RunConfig};

use super::flow::runge_kutta_system;
use super::{Built, LaneParam, SpecError, num};
use crate::integrator::RungeKuttaTableau;
use crate::integrator::composition::{Composition, CompositionScheme};
use crate::model::{Ddnls, DdnlsLattice};
use crate::system::{DdnlsSystem, DynamicalSystem};

/// Most sites a lattice may have (2^22: a 2048 x 2048 square), so that the state and the
/// validation's arrays stay far below what the run limits allow to be allocated.
const MAX_SITES: usize = 1 << 22;

/// The lattice of `[model]`, its disorder drawn.
pub fn model_from_config(model: &DdnlsConfig) -> Result<Ddnls, SpecError> {
    let n = model.n.ok_or_else(|| {
        SpecError::new(
            "model.n",
            "needs the number of sites n (of the chain, or per side of the square)",
        )
    })?;
    let lattice = match model.lattice.as_deref() {
        None | Some("chain") => DdnlsLattice::Chain { n },
        Some("square") => DdnlsLattice::Square { n },
        Some(other) => {
            return Err(SpecError::new(
                "model.lattice",
                format!("'{other}' is not chain or square"),
            ));
        }
    };
    let too_many = match lattice {
        DdnlsLattice::Chain { .. } => n > MAX_SITES,
        DdnlsLattice::Square { .. } => n.checked_mul(n).is_none_or(|s| s > MAX_SITES),
    };
    if n == 0 || too_many {
        return Err(SpecError::new(
            "model.n",
            format!(
                "must be between 1 and {} (at most {MAX_SITES} sites), got {n}",
                match lattice {
                    DdnlsLattice::Chain { .. } => MAX_SITES,
                    DdnlsLattice::Square { .. } => 2048,
                }
            ),
        ));
    }
    let w = model
        .w
        .ok_or_else(|| SpecError::new("model.W", "needs the disorder strength W (0: ordered)"))?;
    if !(0.0..=1e150).contains(&w) {
        return Err(SpecError::new(
            "model.W",
            format!("must be finite, >= 0 and at most 1e150, got {}", num(w)),
        ));
    }
    let beta = model
        .beta
        .ok_or_else(|| SpecError::new("model.beta", "needs the nonlinearity beta"))?;
    if !(beta.is_finite() && beta.abs() <= 1e150) {
        return Err(SpecError::new(
            "model.beta",
            format!(
                "must be finite and at most 1e150 in size, got {}",
                num(beta)
            ),
        ));
    }
    let seed = model.seed.ok_or_else(|| {
        SpecError::new(
            "model.seed",
            "needs the seed of the disorder realization (eps_l uniform in [-W/2, W/2])",
        )
    })?;
    let sites = lattice.sites();
    let eps = if w == 0.0 {
        vec![0.0; sites]
    } else {
        super::drawn::uniform(-w / 2.0, w / 2.0, seed, sites)
    };
    Ok(Ddnls::new(lattice, eps, beta))
}

/// `[model] name = "ddnls"` with the integrator and initial state of `cfg`.
impl super::KindSpec for DdnlsConfig {
    fn build(&self, cfg: &RunConfig, lanes: &[LaneParam]) -> Result<Built, SpecError> {
        super::refuse_parameter_axes(cfg, lanes)?;
        let model = self;
    let lattice = Arc::new(model_from_config(model)?);
    let method = cfg.integrator.method.as_str();
    let system: Arc<dyn DynamicalSystem> = if let Some(kind) = CompositionScheme::from_name(method)
    {
        let h = super::time_step(&cfg.integrator)?;
        for (key, given) in [
            ("integrator.rtol", cfg.integrator.rtol.is_some()),
            ("integrator.atol", cfg.integrator.atol.is_some()),
        ] {
            if given {
                return Err(SpecError::new(
                    key,
                    format!("error control is offered by dop853, not {method}"),
                ));
            }
        }
        Arc::new(DdnlsSystem::new(
            lattice.clone(),
            Composition::new(kind, 3),
            h,
        ))
    } else if RungeKuttaTableau::from_name(method).is_some() {
        runge_kutta_system(cfg, lattice.clone())?
    } else {
        return Err(SpecError::new(
            "integrator.method",
            format!(
                "unknown method '{method}' for ddnls (known: {}; and the Runge-Kutta methods \
                 rk4, dop853, gl4, gl6)",
                CompositionScheme::catalogue()
            ),
        ));
    };
    let x = initial_state(&lattice, &cfg.orbit)?;
    let mut with_x = cfg.clone();
    with_x.orbit = OrbitConfig {
        x,
        ..OrbitConfig::default()
    };
    super::state_x(&with_x, system, Vec::new())
    }
}

/// `[orbit]` of a DDNLS: `excite`, or `q` and `p`, or `x`.
fn initial_state(model: &Ddnls, orbit: &OrbitConfig) -> Result<Vec<f64>, SpecError> {
    let n = model.sites();
    for (key, present) in [
        ("orbit.energy", orbit.energy.is_some()),
        ("orbit.solve_for", orbit.solve_for.is_some()),
        ("orbit.preset", orbit.preset.is_some()),
    ] {
        if present {
            return Err(SpecError::new(
                key,
                "the initial state of a ddnls is excite = { sites, norm or energy }, or q and p",
            ));
        }
    }
    let explicit = !(orbit.q.is_empty() && orbit.p.is_empty() && orbit.x.is_empty());
    if let Some(excite) = &orbit.excite {
        if explicit {
            return Err(SpecError::new(
                "orbit.excite",
                "gives the whole initial state: leave q, p and x out",
            ));
        }
        return excited_state(model, excite);
    }
    let x: Vec<f64> = match (orbit.q.is_empty() && orbit.p.is_empty(), orbit.x.is_empty()) {
        (false, true) => {
            for (key, v) in [("orbit.q", &orbit.q), ("orbit.p", &orbit.p)] {
                if v.len() != n {
                    return Err(SpecError::new(
                        key,
                        format!("needs {n} values (one per site), got {}", v.len()),
                    ));
                }
            }
            orbit.q.iter().chain(&orbit.p).copied().collect()
        }
        (true, false) => orbit.x.clone(),
        (false, false) => {
            return Err(SpecError::new(
                "orbit.x",
                "give either q and p or x = [q1..qN, p1..pN], not both",
            ));
        }
        (true, true) => {
            return Err(SpecError::new(
                "orbit.excite",
                "needs the initial state: excite = { sites, norm or energy }, or q and p",
            ));
        }
    };
    if x.len() != 2 * n {
        return Err(SpecError::new(
            "orbit.x",
            format!("needs {} values q1..qN, p1..pN, got {}", 2 * n, x.len()),
        ));
    }
    Ok(x)
}

/// The sites (from 0) of an excitation (see [`super::lattice_shape::excited_sites`]).
fn excited_sites(model: &Ddnls, excite: &Excitation) -> Result<Vec<usize>, SpecError> {
    let (chain, side) = match model.lattice() {
        DdnlsLattice::Chain { n } => (n, None),
        DdnlsLattice::Square { n } => (n * n, Some(n)),
    };
    super::lattice_shape::excited_sites(excite.sites.range(), chain, side)
}

/// Every site at rest but the excited ones, `psi_l = sqrt(s) e^{i phi_l}` with the same norm
/// `s = |psi_l|^2` each: `s = norm / L`, or the `s` whose energy is `energy` (the positive root
/// of `H(s) = s A + s^2 beta L / 2`, `A = sum_l eps_l - 2 sum_bonds cos(phi_l - phi_m)` over the
/// block), phases 0 or uniform in `[0, 2 pi)` from the seed.
fn excited_state(model: &Ddnls, excite: &Excitation) -> Result<Vec<f64>, SpecError> {
    let sites = excited_sites(model, excite)?;
    let count = sites.len() as f64;
    let phases = match excite.seed {
        Some(seed) => super::drawn::uniform(0.0, std::f64::consts::TAU, seed, sites.len()),
        None => vec![0.0; sites.len()],
    };
    let n = model.sites();
    // The state with unit norm per excited site: H(s) follows from two evaluations of it.
    let unit = |s: f64| {
        let mut x = vec![0.0; 2 * n];
        let amplitude = (2.0 * s).sqrt();
        for (&l, &phi) in sites.iter().zip(&phases) {
            x[l] = amplitude * phi.cos();
            x[n + l] = amplitude * phi.sin();
        }
        x
    };
    let per_site = match (excite.norm, excite.energy) {
        (Some(_), Some(_)) => {
            return Err(SpecError::new(
                "orbit.excite.energy",
                "give norm or energy, not both: at a given norm the block's phases and the \
                 disorder fix the energy",
            ));
        }
        (None, None) => {
            return Err(SpecError::new(
                "orbit.excite.norm",
                "missing: the norm (or the energy) the excited sites share",
            ));
        }
        (Some(norm), None) => {
            if !(norm.is_finite() && norm > 0.0 && norm <= 1e150) {
                return Err(SpecError::new(
                    "orbit.excite.norm",
                    format!(
                        "must be positive, finite and at most 1e150, got {}",
                        num(norm)
                    ),
                ));
            }
            norm / count
        }
        (None, Some(e)) => {
            if !e.is_finite() {
                return Err(SpecError::new(
                    "orbit.excite.energy",
                    format!("must be finite, got {}", num(e)),
                ));
            }
            // H(s) = s A + s^2 B: A from the state of unit norm per site, B = beta L / 2.
            let b = 0.5 * model.beta() * count;
            let a = model.energy(&unit(1.0)) - b;
            let s = if b == 0.0 {
                e / a
            } else {
                let disc = a * a + 4.0 * b * e;
                if disc < 0.0 {
                    f64::NAN
                } else {
                    // The root of smallest size with s > 0, written to avoid cancellation (and
                    // `2 e` overflowing: `e / d * 2` is the same number).
                    let r = disc.sqrt();
                    let roots = if a >= 0.0 {
                        [(-a - r) / (2.0 * b), e / (a + r) * 2.0]
                    } else {
                        [e / (a - r) * 2.0, (r - a) / (2.0 * b)]
                    };
                    roots
                        .into_iter()
                        .filter(|s| s.is_finite() && *s > 0.0)
                        .fold(f64::NAN, |m: f64, s| if m.is_nan() { s } else { m.min(s) })
                }
            };
            // Beyond double precision, or beyond the norm's limit: said as such, not as an
            // energy no excitation has.
            let beyond = !(a * a + 4.0 * b * e).is_finite() || s * count > 1e150;
            if beyond {
                return Err(SpecError::new(
                    "orbit.excite.energy",
                    format!(
                        "{} needs a norm beyond 1e150 (the largest orbit.excite.norm): too large \
                         for double precision",
                        num(e)
                    ),
                ));
            }
            if !(s.is_finite() && s > 0.0) {
                return Err(SpecError::new(
                    "orbit.excite.energy",
                    format!(
                        "no excitation of these sites and phases has energy {}: H(s) = {} s + {} \
                         s^2 for norm s per site",
                        num(e),
                        num(a),
                        num(b)
                    ),
                ));
            }
            s
        }
    };
    let x = unit(per_site);
    if !model.energy(&x).is_finite() {
        return Err(SpecError::new(
            "orbit.excite",
            "the energy of the excitation is not finite in double precision",
        ));
    }
    Ok(x)
}

#[cfg(test)]
mod tests {
    use super::*;
    use chaoscope_schemas::config::ExcitedSites;

    fn chain(beta: f64) -> Ddnls {
        model_from_config(&DdnlsConfig {
            lattice: None,
            n: Some(9),
            w: Some(4.0),
            beta: Some(beta),
            seed: Some(3),
        })
        .unwrap()
    }

    fn excite(sites: ExcitedSites, norm: Option<f64>, energy: Option<f64>) -> Excitation {
        Excitation {
            sites,
            energy,
            norm,
            seed: Some(5),
        }
    }

    /// A block set by its norm has that norm; one set by its energy has that energy (to a few
    /// roundings of the quadratic's solution), for either sign of the root's coefficients.
    #[test]
    fn excitations_hit_their_norm_or_energy() {
        for beta in [0.0, 0.72, 3.6, -1.0] {
            let m = chain(beta);
            let x =
                excited_state(&m, &excite(ExcitedSites::Block([3, 7]), Some(5.0), None)).unwrap();
            assert!((m.norm(&x) - 5.0).abs() < 1e-14);
            let e = m.energy(&x);
            let y = excited_state(&m, &excite(ExcitedSites::Block([3, 7]), None, Some(e))).unwrap();
            assert!(
                (m.energy(&y) - e).abs() < 1e-12 * e.abs().max(1.0),
                "beta {beta}"
            );
            // One positive root where e and beta have one sign (the product of the roots is
            // -e / (beta L / 2)), or beta = 0: it is the norm the block had.
            if beta == 0.0 || e * beta > 0.0 {
                assert!(
                    (m.norm(&y) - 5.0).abs() < 1e-11,
                    "beta {beta}: {}",
                    m.norm(&y)
                );
            }
        }
        let sq = Ddnls::new(DdnlsLattice::Square { n: 5 }, vec![0.0; 25], 1.0);
        let x = excited_state(&sq, &excite(ExcitedSites::Block([2, 4]), Some(9.0), None)).unwrap();
        assert_eq!(x[..25].iter().filter(|v| **v != 0.0).count(), 9);
        assert!(x[6] != 0.0 && x[18] != 0.0 && x[5] == 0.0);
        assert!(
            excited_state(&sq, &excite(ExcitedSites::One(6), Some(1.0), None))
                .unwrap_err()
                .to_string()
                .contains("1 <= first <= last <= 5")
        );
    }
}
