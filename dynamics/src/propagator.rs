//! The tangent propagator of a reference orbit in scaled QR form: GALI_k of any number of
//! direction sets at the cost of evolving one basis.
//!
//! With per-vector renormalization, GALI_k of a set `W = (w_1 .. w_k)` depends only on the
//! directions of `M(t) w_a`, where `M(t)` is the tangent propagator. So the `D = dim` basis
//! vectors are evolved once per orbit (by the variational equations, or by `D` nearby orbits as
//! a finite-difference propagator) and renormalized by QR after every window: with the window's
//! evolved basis `Y = M_m Q_old = Q_new R_m`, the propagator is `M(t) = Q(t) R(t)`,
//! `R = R_m ... R_1`. `R` itself over- and underflows, so it is kept scaled:
//! `R = diag(e^{s_i}) U`, `s_i = sum ln R_m,ii` (the QR Lyapunov sums) and `U` unit upper
//! triangular. Row `i` of `R` only holds growth modes `i` and slower, so
//! `U_new[i][j] = sum_{l=i..j} (R_m[i][l] / R_m[i][i]) e^{s_l - s_i} U_old[l][j]` has bounded
//! entries, and a weight `e^{s_l - s_i}` that underflows to 0 is a contribution below rounding.
//!
//! For a set, `V = U W` gives `M W = Q diag(e^s) V`; `Q` is orthogonal, so everything is a
//! function of `s` and `V`, in logs, with no overflow:
//! - `ln |M w_a| = logsumexp_i (s_i + ln |v_ia|)` (and so each vector's stretching over a
//!   window, exactly what per-vector rescaling reports);
//! - `ln vol(M W) = 1/2 logsumexp_I (2 sum_{i in I} s_i + 2 ln |det V_I|)` over the `k`-row
//!   subsets `I` (Cauchy-Binet: a sum of positive terms, so no cancellation; each `det V_I` is a
//!   small LU with partial pivoting on bounded entries); `C(D, k)` terms, capped by
//!   [`MAX_SUBSETS`];
//! - `ln GALI_k = ln vol - sum_a ln |M w_a|`, not floored: per-set VM multiplies nearly parallel
//!   vectors and cannot resolve GALI below about machine epsilon; this form can.
//!
//! # Where the accuracy limit is
//! The accumulated stretching ratio `e^{s_1 - s_D}` is not a limit: it only ever appears as the
//! exponent of a weight, and the triangular structure keeps the errors of fast modes out of the
//! slow rows (`R` is triangular by construction, not by computation). What is resolved is the
//! QR factorization of one window's evolved basis: Gram-Schmidt determines `R_m,ii` to a relative
//! error of about `eps * |y_i| / R_m,ii`, i.e. `eps` times the window's own stretching ratio
//! `kappa = (largest stretching) / (smallest stretching)` within one window (plus the
//! non-normality of the window map). The error is independent from window to window, so after
//! `n` windows `s_i` is off by about `sqrt(n) eps kappa`. The route is exact to rounding while
//! `kappa << 1/eps = 4.5e15` (for the paper's HH maps, `tau = 1`: `kappa ~ e^{0.1..1}`), and
//! the slowest modes are lost once `kappa ~ 1/eps`: there `R_m,DD` is rounding noise.
//! `window_ratio_limit` in the tests shows both sides (a window ratio of `1e6` agrees with the
//! closed form to `1e-9` decades over an accumulated ratio of `e^{3000}`; a window ratio of
//! `1e17` loses `GALI_4` by whole decades). A second, practical limit: `s_i` beyond about
//! `1e300` (never reached by a run) would overflow.

use crate::renormalization::RenormalizationError;

/// The largest number of `k`-row subsets [`Propagator::log10_gali`] sums (`C(D, k)`); e.g.
/// `D = 10` (FPUT N = 5) has at most 252, `D = 40` with `k = 3` has 9880.
pub const MAX_SUBSETS: u64 = 20_000;

/// `C(n, k)` saturated at `u64::MAX`.
pub fn subsets(n: usize, k: usize) -> u64 {
    if k > n {
        return 0;
    }
    let k = k.min(n - k) as u64;
    let mut c: u64 = 1;
    for i in 0..k {
        c = match c.checked_mul(n as u64 - i) {
            Some(v) => v / (i + 1),
            None => return u64::MAX,
        };
    }
    c
}

/// The accumulated tangent propagator of one orbit in scaled QR form.
#[derive(Debug, Clone)]
pub struct Propagator {
    dim: usize,
    /// `Q`: basis vector `j` at `[j * dim..(j + 1) * dim]`.
    basis: Vec<f64>,
    /// `s_i`: the accumulated `ln R_ii`.
    log_scales: Vec<f64>,
    /// `U`, row-major `dim x dim`, unit upper triangular.
    u: Vec<f64>,
    r: Vec<f64>,
    u_new: Vec<f64>,
    row: Vec<f64>,
}

impl Propagator {
    /// The propagator at `t = 0`: `Q = I`, `R = I`.
    pub fn new(dim: usize) -> Self {
        let mut eye = vec![0.0; dim * dim];
        for i in 0..dim {
            eye[i * dim + i] = 1.0;
        }
        Self {
            dim,
            basis: eye.clone(),
            log_scales: vec![0.0; dim],
            u: eye,
            r: vec![0.0; dim * dim],
            u_new: vec![0.0; dim * dim],
            row: vec![0.0; dim],
        }
    }

    pub fn dim(&self) -> usize {
        self.dim
    }

    /// The current orthonormal basis `Q` (vector `j` at `[j * dim..(j + 1) * dim]`): what the
    /// next window evolves.
    pub fn basis(&self) -> &[f64] {
        &self.basis
    }

    /// `s_i`, the accumulated `ln R_ii` (divided by `t`: the Lyapunov spectrum's estimates).
    pub fn log_scales(&self) -> &[f64] {
        &self.log_scales
    }

    /// One window: `evolved` holds `scale * M_m q_j` for every basis vector `q_j` (in the basis'
    /// layout; `scale` is `1` for tangent vectors, `d0` for separations of nearby orbits).
    /// Factors it by modified Gram-Schmidt with one re-orthogonalization pass, takes the new
    /// basis and folds `R_m` into `(s, U)`.
    pub fn renormalize(&mut self, evolved: &[f64], scale: f64) -> Result<(), RenormalizationError> {
        let d = self.dim;
        assert_eq!(evolved.len(), d * d, "evolved basis of {d} x {d}");
        self.basis.copy_from_slice(evolved);
        self.r.iter_mut().for_each(|x| *x = 0.0);
        for j in 0..d {
            let (done, rest) = self.basis.split_at_mut(j * d);
            let v = &mut rest[..d];
            let n0 = norm(v);
            if !n0.is_finite() {
                return Err(RenormalizationError::NotFinite { index: j, norm: n0 });
            }
            if n0 == 0.0 {
                return Err(RenormalizationError::Vanished { index: j });
            }
            for _pass in 0..2 {
                for (i, q) in done.chunks_exact(d).enumerate() {
                    let c: f64 = q.iter().zip(v.iter()).map(|(a, b)| a * b).sum();
                    v.iter_mut().zip(q).for_each(|(x, qi)| *x -= c * qi);
                    self.r[i * d + j] += c;
                }
            }
            let rjj = norm(v);
            if rjj == 0.0 {
                return Err(RenormalizationError::Dependent { index: j });
            }
            self.r[j * d + j] = rjj;
            v.iter_mut().for_each(|x| *x /= rjj);
        }
        // U_new = (D_old^-1 R~ D_old) U_old with R~ = D_m^-1 R_m unit upper triangular.
        // Row i's factors (R_m[i][l] / R_m[i][i]) e^{s_l - s_i}, l > i, formed once per row
        // (the exponentials are most of a small basis' renormalization cost).
        let s = &self.log_scales;
        for i in 0..d {
            let rii = self.r[i * d + i];
            for l in i + 1..d {
                self.row[l] = (self.r[i * d + l] / rii) * (s[l] - s[i]).exp();
            }
            for j in i..d {
                let mut acc = self.u[i * d + j];
                for l in i + 1..=j {
                    acc += self.row[l] * self.u[l * d + j];
                }
                self.u_new[i * d + j] = acc;
            }
        }
        std::mem::swap(&mut self.u, &mut self.u_new);
        let ln_scale = scale.ln();
        for i in 0..d {
            self.log_scales[i] += self.r[i * d + i].ln() - ln_scale;
            let bad = self.log_scales[i];
            if !bad.is_finite() || self.u[i * d..(i + 1) * d].iter().any(|x| !x.is_finite()) {
                return Err(RenormalizationError::NotFinite {
                    index: i,
                    norm: bad,
                });
            }
        }
        Ok(())
    }

    /// The image of the set `directions` (`k` vectors of `dim`, one after the other): `V = U W`
    /// and `ln |M w_a|`, into `image` (resized as needed).
    pub fn image(&self, directions: &[f64], image: &mut SetImage) {
        let d = self.dim;
        let k = directions.len() / d;
        image.k = k;
        image.v.resize(d * k, 0.0);
        image.log_norms.resize(k, 0.0);
        for (a, w) in directions.chunks_exact(d).enumerate() {
            let va = &mut image.v[a * d..(a + 1) * d];
            for (i, vi) in va.iter_mut().enumerate() {
                *vi = (i..d).map(|j| self.u[i * d + j] * w[j]).sum();
            }
            image.log_norms[a] = ln_norm(&self.log_scales, va);
        }
    }

    /// `log10 GALI_k` of the set whose [`Self::image`] is `image`, exact in logs (not floored;
    /// `-inf` only for an exactly dependent set).
    pub fn log10_gali(&self, image: &SetImage, scratch: &mut Vec<f64>) -> f64 {
        let (d, k) = (self.dim, image.k);
        let mut rows: Vec<usize> = (0..k).collect();
        let (mut max, mut sum) = (f64::NEG_INFINITY, 0.0);
        scratch.resize(k * k, 0.0);
        loop {
            for (r, &i) in rows.iter().enumerate() {
                for a in 0..k {
                    scratch[r * k + a] = image.v[a * d + i];
                }
            }
            let ln_det = ln_abs_det(scratch, k);
            if ln_det > f64::NEG_INFINITY {
                // Twice the term's log: the sum is of squared volumes.
                let t = 2.0 * (rows.iter().map(|&i| self.log_scales[i]).sum::<f64>() + ln_det);
                if t > max {
                    sum = sum * (max - t).exp() + 1.0;
                    max = t;
                } else {
                    sum += (t - max).exp();
                }
            }
            if !next_subset(&mut rows, d) {
                break;
            }
        }
        let ln_vol = 0.5 * (max + sum.ln());
        (ln_vol - image.log_norms.iter().sum::<f64>()) / std::f64::consts::LN_10
    }

    /// The unit vectors `M w_a / |M w_a|` of the set whose [`Self::image`] is `image`, in phase
    /// space (`k` vectors of `dim`, one after the other): what per-vector rescaling holds.
    pub fn unit_vectors(&self, image: &SetImage, out: &mut [f64]) {
        let d = self.dim;
        for (a, o) in out.chunks_exact_mut(d).take(image.k).enumerate() {
            o.iter_mut().for_each(|x| *x = 0.0);
            let va = &image.v[a * d..(a + 1) * d];
            for (i, q) in self.basis.chunks_exact(d).enumerate() {
                if va[i] == 0.0 {
                    continue;
                }
                let c = va[i].signum()
                    * (self.log_scales[i] + va[i].abs().ln() - image.log_norms[a]).exp();
                if c != 0.0 {
                    o.iter_mut().zip(q).for_each(|(x, qi)| *x += c * qi);
                }
            }
        }
    }
}

/// `V = U W` of one set and `ln |M w_a|`.
#[derive(Debug, Clone, Default)]
pub struct SetImage {
    k: usize,
    /// Column `a` at `[a * dim..(a + 1) * dim]`.
    v: Vec<f64>,
    log_norms: Vec<f64>,
}

impl SetImage {
    /// `ln |M(t) w_a|`: differences between two times are the vectors' stretching.
    pub fn log_norms(&self) -> &[f64] {
        &self.log_norms
    }
}

/// `ln |diag(e^s) v|`, by logsumexp.
fn ln_norm(s: &[f64], v: &[f64]) -> f64 {
    let terms = || {
        s.iter()
            .zip(v)
            .filter(|(_, v)| **v != 0.0)
            .map(|(s, v)| s + v.abs().ln())
    };
    let m = terms().fold(f64::NEG_INFINITY, f64::max);
    if m == f64::NEG_INFINITY {
        return m;
    }
    m + 0.5 * terms().map(|t| (2.0 * (t - m)).exp()).sum::<f64>().ln()
}

/// `ln |det A|` of the row-major `k x k` matrix `a` (overwritten), LU with partial pivoting.
fn ln_abs_det(a: &mut [f64], k: usize) -> f64 {
    let mut ln = 0.0;
    for c in 0..k {
        let p = (c..k)
            .max_by(|&x, &y| a[x * k + c].abs().total_cmp(&a[y * k + c].abs()))
            .expect("c < k");
        let pivot = a[p * k + c];
        if pivot == 0.0 {
            return f64::NEG_INFINITY;
        }
        if p != c {
            for j in 0..k {
                a.swap(p * k + j, c * k + j);
            }
        }
        ln += pivot.abs().ln();
        for r in c + 1..k {
            let m = a[r * k + c] / pivot;
            if m != 0.0 {
                for j in c + 1..k {
                    a[r * k + j] -= m * a[c * k + j];
                }
            }
        }
    }
    ln
}

/// The next `k`-subset of `0..n` in lexicographic order; false after the last.
fn next_subset(rows: &mut [usize], n: usize) -> bool {
    let k = rows.len();
    for i in (0..k).rev() {
        if rows[i] < n - k + i {
            rows[i] += 1;
            for j in i + 1..k {
                rows[j] = rows[j - 1] + 1;
            }
            return true;
        }
    }
    false
}

fn norm(v: &[f64]) -> f64 {
    v.iter().map(|x| x * x).sum::<f64>().sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::indicators::gali_log10;

    const D: usize = 4;

    /// A fixed orthogonal matrix (columns at `[j * D..]`): Gram-Schmidt of fixed numbers.
    fn rotation() -> Vec<f64> {
        let mut p = Propagator::new(D);
        let a = [
            0.8, -0.3, 0.5, 0.1, 0.2, 0.9, -0.4, 0.3, -0.6, 0.1, 0.7, 0.5, 0.3, 0.4, 0.2, -0.9,
        ];
        p.renormalize(&a, 1.0).unwrap();
        p.basis().to_vec()
    }

    /// Three sets of unit directions (k = 4 vectors each; GALI_2..4 use the first 2..4).
    fn sets() -> Vec<Vec<f64>> {
        let raw = [
            [
                0.3, -0.2, 0.7, 0.1, 0.5, 0.5, -0.1, 0.2, -0.3, 0.8, 0.1, 0.4, 0.1, 0.1, 0.9, -0.3,
            ],
            [
                1.0, 0.2, 0.0, 0.0, 0.0, 1.0, 0.1, 0.0, 0.0, 0.0, 1.0, 0.3, 0.2, 0.0, 0.0, 1.0,
            ],
            [
                0.5, 0.5, 0.5, 0.5, 0.5, -0.5, 0.5, -0.5, 0.9, 0.1, -0.2, 0.3, -0.1, 0.4, 0.4, 0.6,
            ],
        ];
        raw.iter()
            .map(|s| {
                let mut v = s.to_vec();
                for c in v.chunks_exact_mut(D) {
                    let n = norm(c);
                    c.iter_mut().for_each(|x| *x /= n);
                }
                v
            })
            .collect()
    }

    /// `A = O diag(lambda) O^T` applied to the vectors of `x` (one after the other).
    fn apply(o: &[f64], ln_lambda: &[f64; D], x: &[f64]) -> Vec<f64> {
        let mut out = vec![0.0; x.len()];
        for (v, y) in x.chunks_exact(D).zip(out.chunks_exact_mut(D)) {
            for (i, oi) in o.chunks_exact(D).enumerate() {
                let c: f64 = oi.iter().zip(v).map(|(a, b)| a * b).sum::<f64>() * ln_lambda[i].exp();
                y.iter_mut().zip(oi).for_each(|(y, o)| *y += c * o);
            }
        }
        out
    }

    /// The closed form after `n` windows: `M W = O diag(lambda^n) (O^T W)`, GALI_k in logs by
    /// the eigenbasis (`U = O^T` taken as given, no QR anywhere).
    fn closed_form(o: &[f64], ln_lambda: &[f64; D], n: f64, w: &[f64], k: usize) -> f64 {
        let exact = Propagator {
            dim: D,
            basis: o.to_vec(),
            log_scales: ln_lambda.iter().map(|l| n * l).collect(),
            u: vec![0.0; D * D],
            r: Vec::new(),
            u_new: Vec::new(),
            row: Vec::new(),
        };
        let mut img = SetImage {
            k,
            v: vec![0.0; D * k],
            log_norms: vec![0.0; k],
        };
        for a in 0..k {
            for i in 0..D {
                img.v[a * D + i] = o[i * D..(i + 1) * D]
                    .iter()
                    .zip(&w[a * D..(a + 1) * D])
                    .map(|(x, y)| x * y)
                    .sum();
            }
            img.log_norms[a] = ln_norm(&exact.log_scales, &img.v[a * D..(a + 1) * D]);
        }
        exact.log10_gali(&img, &mut Vec::new())
    }

    /// Evolves the basis `windows` times through `A` with the window ratio
    /// `lambda_1 / lambda_4 = kappa`; returns the largest deviation (decades) of log10 GALI_k,
    /// k = 2, 3, 4, from the closed form, per k, over all windows and sets; and checks against
    /// explicitly multiplied vectors (per-set VM) while they still resolve GALI.
    fn worst_error(kappa: f64, windows: usize) -> [f64; 3] {
        let a = kappa.ln() / 2.0;
        let ln_lambda = [a, a / 3.0, -a / 3.0, -a];
        let o = rotation();
        let mut p = Propagator::new(D);
        let mut worst = [0.0f64; 3];
        let mut explicit: Vec<Vec<f64>> = sets();
        let (mut img, mut scratch) = (SetImage::default(), Vec::new());
        for n in 1..=windows {
            let y = apply(&o, &ln_lambda, p.basis());
            p.renormalize(&y, 1.0).unwrap();
            for (w, e) in sets().iter().zip(explicit.iter_mut()) {
                *e = apply(&o, &ln_lambda, e);
                for v in e.chunks_exact_mut(D) {
                    let nv = norm(v);
                    v.iter_mut().for_each(|x| *x /= nv);
                }
                let svd = gali_log10(e, D);
                for k in 2..=D {
                    p.image(&w[..k * D], &mut img);
                    let got = p.log10_gali(&img, &mut scratch);
                    let want = closed_form(&o, &ln_lambda, n as f64, w, k);
                    worst[k - 2] = worst[k - 2].max((got - want).abs());
                    // Per-vector rescaling of explicit vectors resolves GALI to about eps / GALI
                    // relative: 1e-6 decades while GALI > 1e-8.
                    if svd[k - 2] > -8.0 && kappa < 1e8 {
                        assert!(
                            (got - svd[k - 2]).abs() < 1e-6,
                            "kappa {kappa} window {n} k {k}: {got} vs per-set {}",
                            svd[k - 2]
                        );
                    }
                }
            }
        }
        worst
    }

    #[test]
    fn agrees_with_the_closed_form_far_beyond_per_set_resolution() {
        // 400 windows of ratio 1e6: accumulated ln(lambda_1 / lambda_4) = 400 ln 1e6 = 5526,
        // GALI_4 ~ 1e-2400, far below what per-set VM (floored at eps) can resolve. Expected
        // error: sqrt(400) eps kappa ~ 4e-9 in ln, so 1e-6 decades has a margin of 100.
        let worst = worst_error(1e6, 400);
        for (k, e) in worst.iter().enumerate() {
            assert!(*e < 1e-6, "GALI_{}: {e} decades off", k + 2);
        }
    }

    #[test]
    fn window_ratio_limit() {
        // The error per window is about eps * kappa (module doc): measured over 50 windows,
        // worst over k = 2, 3, 4 (decades):
        for kappa in [1e3, 1e6, 1e9, 1e12, 1e15, 1e17] {
            eprintln!("kappa {kappa:e}: {:?}", worst_error(kappa, 50));
        }
        // Below the limit: a window ratio of 1e12 (eps kappa = 2e-4 per window) still gives every
        // GALI to better than 1e-2 decades over 50 windows.
        let below = worst_error(1e12, 50);
        assert!(below.iter().all(|e| *e < 1e-2), "kappa 1e12: {below:?}");
        // Beyond it: with a window ratio of 1e17 > 1/eps, Gram-Schmidt of the window's basis
        // leaves only rounding in the slowest direction, R_44 is noise, and GALI_4 (which
        // depends on it) is lost (0.7 decades after 50 windows, growing with their number);
        // GALI_2 depends on the two fastest modes only, which the window still resolves.
        let beyond = worst_error(1e17, 50);
        assert!(
            beyond[2] > 0.1,
            "kappa 1e17: GALI_4 still resolved {beyond:?}"
        );
        assert!(beyond[0] < 1e-6, "kappa 1e17: GALI_2 {beyond:?}");
    }

    #[test]
    fn subsets_count() {
        assert_eq!(subsets(4, 2), 6);
        assert_eq!(subsets(10, 5), 252);
        assert_eq!(subsets(3, 4), 0);
        assert_eq!(subsets(10_000, 5000), u64::MAX);
    }

    #[test]
    fn unit_vectors_are_the_normalized_images() {
        let o = rotation();
        let ln_lambda = [0.3, 0.1, -0.1, -0.3];
        let mut p = Propagator::new(D);
        let mut e = sets()[0].clone();
        for _ in 0..20 {
            let y = apply(&o, &ln_lambda, p.basis());
            p.renormalize(&y, 1.0).unwrap();
            e = apply(&o, &ln_lambda, &e);
        }
        let mut img = SetImage::default();
        p.image(&sets()[0], &mut img);
        let mut u = vec![0.0; 4 * D];
        p.unit_vectors(&img, &mut u);
        for (a, (got, want)) in u.chunks_exact(D).zip(e.chunks_exact(D)).enumerate() {
            let n = norm(want);
            assert!((img.log_norms()[a] - n.ln()).abs() < 1e-12);
            for (g, w) in got.iter().zip(want) {
                assert!((g - w / n).abs() < 1e-13, "{got:?} vs {want:?}");
            }
        }
    }
}
