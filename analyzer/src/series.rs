//! Time series at bounded resolution, so memory does not grow with the length of a run.
//!
//! Two thinnings are kept side by side: log-spaced times (a fixed number per decade, which is
//! what log-time plots of GALI need: the early decay is as visible as the late one) and evenly
//! spaced samples whose stride doubles whenever the buffer fills (what linear-time plots and CSV
//! need). Together at most `capacity + decades * per_decade` points per series.
//!
//! A scheme's curve is a series of [`SchemePoint`]s, which the verdict and the plots read.

/// Means over the sets of one scheme at one time: a point of a plotted curve.
#[derive(Debug, Clone, PartialEq)]
pub struct SchemePoint {
    /// `[j - 2]`: mean over sets of log10 GALI_j.
    pub gali_log10_mean: Vec<f64>,
    /// `[j - 2]`: log10 of the arithmetic mean of GALI_j.
    pub gali_log10_of_mean: Vec<f64>,
    pub sali_log10_mean: Option<f64>,
    /// Mean over sets of the finite-time exponents (one per vector), over the whole run: what
    /// the verdict judges.
    pub lyapunov: Vec<f64>,
    /// The same averaged from the end of a discarded transient (`analyze --from T`), where one
    /// is set: what the CSV and the plots show. See [`SchemePoint::exponents`].
    pub lyapunov_from: Option<Vec<f64>>,
    /// `[j - 2]`: mean over sets of |log10 GALI_j - log10 GALI_j(VM)|, for MPM schemes.
    pub vs_vm_abs_delta: Option<Vec<f64>>,
    /// Every registered set indicator's output (`set_output_names()` order: FLI, OFLI, MEGNO,
    /// ...), mean over the sets; `None` where the run cannot give it (OFLI without the flow).
    pub named: Vec<Option<f64>>,
}

impl SchemePoint {
    /// The finite-time exponents as reported: from the transient's end where one is set, else
    /// over the whole run.
    pub fn exponents(&self) -> &[f64] {
        self.lyapunov_from.as_deref().unwrap_or(&self.lyapunov)
    }
}

/// Decides which samples a series keeps and stores them.
#[derive(Debug, Clone)]
pub struct Series<P> {
    capacity: usize,
    per_decade: f64,
    /// Next time accepted by the log thinning.
    next_log_t: f64,
    log_points: Vec<(f64, P)>,
    /// Evenly thinned: every `stride`-th offered sample.
    stride: u64,
    offered: u64,
    even_points: Vec<(u64, f64, P)>,
}

impl<P: Clone> Series<P> {
    /// `capacity` >= 2 evenly spaced points, `per_decade` log-spaced points per decade of time.
    pub fn new(capacity: usize, per_decade: usize) -> Self {
        Self {
            capacity: capacity.max(2),
            per_decade: per_decade.max(1) as f64,
            next_log_t: 0.0,
            log_points: Vec::new(),
            stride: 1,
            offered: 0,
            even_points: Vec::new(),
        }
    }

    /// Whether a sample at time `t` (offered in increasing time order) would be kept. Pure: call
    /// [`Series::push`] afterwards with the same `t` if it is.
    pub fn wants(&self, t: f64) -> bool {
        self.offered.is_multiple_of(self.stride) || t >= self.next_log_t
    }

    /// Offers the sample at time `t`; `make` is called only if it is kept. Every sample must be
    /// offered (kept or not) so the even thinning counts right.
    pub fn offer(&mut self, t: f64, make: impl FnOnce() -> P) {
        let even = self.offered.is_multiple_of(self.stride);
        let log = t >= self.next_log_t;
        if even || log {
            let p = make();
            if log {
                self.log_points.push((t, p.clone()));
                // t = 0 is kept; the next log point is one step of 10^(1/per_decade) above t.
                let factor = 10f64.powf(1.0 / self.per_decade);
                self.next_log_t = if t > 0.0 {
                    t * factor
                } else {
                    f64::MIN_POSITIVE
                };
            }
            if even {
                self.even_points.push((self.offered, t, p));
                if self.even_points.len() > self.capacity {
                    self.stride *= 2;
                    let stride = self.stride;
                    self.even_points
                        .retain(|(i, _, _)| i.is_multiple_of(stride));
                }
            }
        }
        self.offered += 1;
    }

    /// Every kept point in time order, each time once.
    pub fn points(&self) -> Vec<(f64, P)> {
        let mut all: Vec<(f64, P)> = self
            .log_points
            .iter()
            .cloned()
            .chain(self.even_points.iter().map(|(_, t, p)| (*t, p.clone())))
            .collect();
        all.sort_by(|a, b| a.0.total_cmp(&b.0));
        all.dedup_by(|a, b| a.0 == b.0);
        all
    }

    /// Every kept point in time order, each time once, by reference.
    pub fn points_ref(&self) -> Vec<(f64, &P)> {
        let mut all: Vec<(f64, &P)> = self
            .log_points
            .iter()
            .map(|(t, p)| (*t, p))
            .chain(self.even_points.iter().map(|(_, t, p)| (*t, p)))
            .collect();
        all.sort_by(|a, b| a.0.total_cmp(&b.0));
        all.dedup_by(|a, b| a.0 == b.0);
        all
    }

    #[cfg(test)]
    pub fn len_bound(&self) -> usize {
        self.log_points.len() + self.even_points.len()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn memory_is_bounded_and_both_ends_are_covered() {
        let mut s = Series::new(100, 10);
        let n = 1_000_000u64;
        for i in 0..=n {
            let t = i as f64 * 0.01;
            s.offer(t, || t);
        }
        // Even: <= 101 points; log: times 0.01 .. 1e4 are 6 decades, 10 per decade.
        assert!(s.len_bound() <= 101 + 6 * 10 + 2, "{}", s.len_bound());
        let pts = s.points();
        assert_eq!(pts[0].0, 0.0);
        assert!(
            pts.iter().any(|p| p.0 > 0.0 && p.0 <= 0.02),
            "early times kept"
        );
        // The evenly spaced part reaches the end within one stride.
        let last = pts.last().unwrap().0;
        assert!(last > 0.98 * n as f64 * 0.01, "{last}");
        assert!(pts.windows(2).all(|w| w[0].0 < w[1].0));
        // Log spacing: consecutive log points differ by at least the factor 10^(1/10).
        let logs: Vec<f64> = s
            .log_points
            .iter()
            .map(|p| p.0)
            .filter(|&t| t > 0.0)
            .collect();
        assert!(
            logs.windows(2)
                .all(|w| w[1] / w[0] >= 10f64.powf(0.1) - 1e-12)
        );
    }
}
