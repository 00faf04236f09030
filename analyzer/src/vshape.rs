//! The V shape of MPM GALIs against d0 (paper, Figs. 5 and 10): for every GALI order, the MPM
//! scheme of a d0 sweep whose values lie closest to VM's, set by set, at the same time.

use crate::report::Report;

/// Distance to VM of every swept d0 for one GALI order, and where it is smallest.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct VShape {
    pub order: usize,
    /// `(d0, mean over sets of |log10 GALI_MPM - log10 GALI_VM|)`, ordered by d0.
    pub distances: Vec<(f64, f64)>,
    pub best_d0: f64,
}

/// For MPM schemes with a VM partner and the given `tau`, the distance to VM per d0 and order.
pub fn v_shapes(report: &Report, tau: f64) -> Vec<VShape> {
    let mut mpm: Vec<_> = report
        .schemes
        .iter()
        .filter(|s| s.method == "mpm" && s.tau == tau && s.vs_vm.is_some())
        .collect();
    mpm.sort_by(|a, b| a.d0.total_cmp(&b.d0));
    let Some(first) = mpm.first() else {
        return Vec::new();
    };
    (2..=first.k)
        .map(|j| {
            let distances: Vec<(f64, f64)> = mpm
                .iter()
                .filter_map(|s| {
                    let d = s.vs_vm.as_ref()?.gali.get(j)?.mean_abs_delta_log10;
                    Some((s.d0, d))
                })
                .collect();
            let best_d0 = distances
                .iter()
                .min_by(|a, b| a.1.total_cmp(&b.1))
                .map_or(f64::NAN, |p| p.0);
            VShape {
                order: j,
                distances,
                best_d0,
            }
        })
        .collect()
}
