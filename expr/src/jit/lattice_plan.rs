//! The loop plan of a lattice potential and its derivatives, shared by both back ends
//! (Cranelift in [`super::cranelift::lattice`] and [`super::cranelift::lattice_steps`], C in
//! [`super::c::lattice_steps`] and [`super::c::fused`]): the force's parts in the reference
//! order, which sums keep a window of sites in registers, which sites start at `-0`, and in a
//! step kernel's stage where each row is drifted and kicked. Every printer walks the same
//! parts, so they perform the same operations in the same order.

use std::sync::Arc;

use super::JitError;
use crate::graph::{Graph, Node, NodeId};
use crate::lattice::{ARG_Q, ARG_V, LatticePotential, SiteSum};

/// Refuses lattices whose byte offsets (sites times 8, scratch rows of up to four lanes) do not
/// fit the `i32` immediates of the generated code.
pub(crate) fn check_size(lattice: &LatticePotential) -> Result<(), JitError> {
    let n = lattice.n as u64;
    if n * 32 > i32::MAX as u64 {
        return Err(JitError::TooLarge {
            function: 0,
            index: n,
            count: n,
        });
    }
    Ok(())
}

/// The array parameters the sums read, each once (by name), as `(name, values)`: the compiled
/// loops read them through pointers into these.
pub(crate) fn arrays_of(lattice: &LatticePotential) -> Vec<(String, Arc<[f64]>)> {
    let mut arrays: Vec<(String, Arc<[f64]>)> = Vec::new();
    for p in lattice.sums.iter().flat_map(|s| &s.params) {
        if !arrays.iter().any(|(name, _)| *name == p.name) {
            arrays.push((p.name.clone(), p.values.clone()));
        }
    }
    arrays
}

/// Largest span of a term's variable shifts whose sites' sums a loop keeps in registers (a
/// wider term adds to the output in memory, site by site).
const MAX_WINDOW: i64 = 8;

/// The smallest and largest shift of a term's variable slots.
pub(crate) fn shift_range(shifts: &[i64]) -> (i64, i64) {
    shifts
        .iter()
        .fold((i64::MAX, i64::MIN), |(lo, hi), &k| (lo.min(k), hi.max(k)))
}

/// How a gradient or Hessian-vector product function fills its output: which sums' interior
/// loops keep a window of sites in registers (and whether the sites entering it are fresh, no
/// part having written them before), and which sites must hold `-0` before the parts run
/// (read before a loop writes them first, or never written).
///
/// For a step kernel's stage it also says where the drift and the kick of each row go: a
/// window loop drifts the rows entering it (when no part read them before) and kicks the sites
/// it completes (when no later part adds to them), so a chain made of one sum is one pass over
/// its rows; every other row is drifted before the parts (`pre_drift`) or after them, when the
/// force never reads it (`post_drift`), and kicked after them (`post_kick`). A row is drifted
/// before it is read and before it is kicked (both read its momentum), kicked once its force
/// is complete: the bits of the separate drift, force and kick passes.
pub(crate) struct OutputPlan {
    /// The force's parts in the reference order ([`crate::lattice::LatticeEvaluator`]'s), which
    /// every back end emits one after the other.
    pub parts: Vec<ForcePart>,
    /// Per sum: its interior loop's window, if it keeps one.
    pub window: Vec<Option<WindowPlan>>,
    /// Sites `a..z` (0-based) to set to `-0` first.
    pub init: Vec<(usize, usize)>,
    pub pre_drift: Vec<(usize, usize)>,
    pub post_drift: Vec<(usize, usize)>,
    pub post_kick: Vec<(usize, usize)>,
}

/// One part of a force: the derivatives of the expression around the sums, a sum's boundary
/// term, or a sum's interior loop (its window, if it keeps one, in [`OutputPlan::window`]).
/// Sums that contribute nothing have no part.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum ForcePart {
    Rest,
    /// Term `i` of sum `sum`, its sites resolved (a wall's slot is 0, a periodic one wrapped).
    Term {
        sum: usize,
        i: i64,
    },
    /// Terms `from..=to` of sum `sum` as a loop.
    Loop {
        sum: usize,
        from: i64,
        to: i64,
    },
}

impl ForcePart {
    /// Sum `s`'s parts in the reference order: its boundary terms before the interior, the
    /// interior as a loop, its terms after.
    pub(crate) fn of_sum(sum: &SiteSum, s: usize) -> Vec<ForcePart> {
        let (before, after) = sum.boundary_terms();
        let term = |i| ForcePart::Term { sum: s, i };
        let interior = sum
            .interior()
            .map(|(from, to)| ForcePart::Loop { sum: s, from, to });
        before
            .into_iter()
            .map(term)
            .chain(interior)
            .chain(after.into_iter().map(term))
            .collect()
    }
}

/// The derivatives of the expression around the sums: its gradient, or with `hessian` its
/// Hessian-vector product (none without second derivatives), as (0-based site, node).
pub(crate) fn rest_derivatives(lattice: &LatticePotential, hessian: bool) -> &[(u32, NodeId)] {
    if hessian {
        lattice.rest_hessian_vector.as_deref().unwrap_or(&[])
    } else {
        &lattice.rest_gradient
    }
}

/// A sum's (factor, node) per slot and those nodes.
pub(crate) type SumContributions = (Vec<(f64, NodeId)>, Vec<NodeId>);

/// Per sum, what its derivatives add to the force ([`crate::lattice::SumDerivatives::contributions`]:
/// (factor, node) per slot) and those nodes, the roots a back end emits; every sum's, as a
/// force's parts refer to sums by index.
pub(crate) fn sum_contributions(
    graph: &Graph,
    lattice: &LatticePotential,
    hessian: bool,
) -> Vec<SumContributions> {
    lattice
        .derivatives
        .iter()
        .map(|d| {
            if hessian && d.hessian_vector.is_none() {
                // No second derivatives: the sum has no part.
                return (Vec::new(), Vec::new());
            }
            let c = d.contributions(graph, hessian);
            let roots = c.iter().map(|&(_, id)| id).collect();
            (c, roots)
        })
        .collect()
}

/// A sum's interior loop with its window of sites in registers.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct WindowPlan {
    /// No part wrote the sites entering the window before: their first contribution is taken
    /// as it is.
    pub fresh: bool,
    /// (Step kernels) the loop drifts the rows entering it.
    pub drift: bool,
    /// (Step kernels) the loop kicks the sites it completes.
    pub kick: bool,
}

/// The maximal runs of `true` in `flags`, as `(start, end)` ranges.
fn ranges(flags: &[bool]) -> Vec<(usize, usize)> {
    let mut out = Vec::new();
    let mut j = 0;
    while j < flags.len() {
        if flags[j] {
            let a = j;
            while j < flags.len() && flags[j] {
                j += 1;
            }
            out.push((a, j));
        } else {
            j += 1;
        }
    }
    out
}

impl OutputPlan {
    /// The plan of the gradient (or with `hessian` the Hessian-vector product); with `stage`,
    /// of a step kernel's stage (drifts and kicks in the loops), else of a function.
    pub(crate) fn new(
        graph: &Graph,
        lattice: &LatticePotential,
        hessian: bool,
        stage: bool,
    ) -> Self {
        let n = lattice.n;
        // Per site: its output written or read by a part so far, and read before any write;
        // its row drifted, and drifted before the parts.
        let mut touched = vec![false; n];
        let mut init = vec![false; n];
        let mut drifted = vec![false; n];
        let mut pre = vec![false; n];
        let read = |touched: &mut [bool], init: &mut [bool], j: usize| {
            if !touched[j] {
                init[j] = true;
                touched[j] = true;
            }
        };
        let read_row = |drifted: &mut [bool], pre: &mut [bool], j: usize| {
            if !drifted[j] {
                drifted[j] = true;
                pre[j] = true;
            }
        };
        let rest = rest_derivatives(lattice, hessian);
        for &(j, _) in rest {
            read(&mut touched, &mut init, j as usize);
        }
        let mut parts = Vec::new();
        if !rest.is_empty() {
            parts.push(ForcePart::Rest);
            let roots: Vec<NodeId> = rest.iter().map(|&(_, id)| id).collect();
            let mut need = Vec::new();
            crate::eval::mark_needed(graph, &roots, &mut need);
            for (v, &needed) in need.iter().enumerate() {
                if let (
                    true,
                    Node::Input {
                        arg: ARG_Q | ARG_V,
                        index,
                    },
                ) = (needed, graph.node(v as NodeId))
                {
                    read_row(&mut drifted, &mut pre, *index as usize);
                }
            }
        }
        let used = |d: &crate::lattice::SumDerivatives| {
            if hessian {
                d.hessian_vector.as_ref().map_or(0, Vec::len)
            } else {
                d.gradient.len()
            }
        };
        let mut window = vec![None; lattice.sums.len()];
        for (s, (sum, d)) in lattice.sums.iter().zip(&lattice.derivatives).enumerate() {
            if used(d) > 0 {
                parts.extend(ForcePart::of_sum(sum, s));
            }
        }
        for part in &parts {
            let sum = match *part {
                ForcePart::Rest => continue,
                ForcePart::Term { sum, .. } | ForcePart::Loop { sum, .. } => &lattice.sums[sum],
            };
            let sites = |i: i64| sum.variables.iter().filter_map(move |&k| sum.site(i, k));
            let (from, to) = match *part {
                ForcePart::Loop { sum: s, from, to } => {
                    let (kmin, kmax) = shift_range(&sum.variables);
                    if kmax - kmin < MAX_WINDOW {
                        let incoming = (from + kmax - 1) as usize..(to + kmax) as usize;
                        let fresh = !touched[incoming.clone()].iter().any(|&t| t);
                        let drift = stage && !drifted[incoming.clone()].iter().any(|&d| d);
                        // The window's first sites and rows are read at the loop's entry.
                        for j in (from + kmin - 1) as usize..(from + kmax - 1) as usize {
                            read(&mut touched, &mut init, j);
                            read_row(&mut drifted, &mut pre, j);
                        }
                        for j in incoming {
                            if fresh {
                                touched[j] = true;
                            } else {
                                read(&mut touched, &mut init, j);
                            }
                            if drift {
                                drifted[j] = true;
                            } else {
                                read_row(&mut drifted, &mut pre, j);
                            }
                        }
                        window[s] = Some(WindowPlan {
                            fresh,
                            drift,
                            kick: false,
                        });
                        continue;
                    }
                    (from, to)
                }
                ForcePart::Term { i, .. } => (i, i),
                ForcePart::Rest => unreachable!(),
            };
            for i in from..=to {
                for j in sites(i) {
                    read(&mut touched, &mut init, j);
                    read_row(&mut drifted, &mut pre, j);
                }
            }
        }
        // Kicks in a window loop: the sites it completes, when no later part adds to them.
        let mut kicked = vec![false; n];
        if stage {
            let mut later = vec![false; n];
            for part in parts.iter().rev() {
                match *part {
                    ForcePart::Rest => {}
                    ForcePart::Term { sum, i } => {
                        let sum = &lattice.sums[sum];
                        for j in sum.variables.iter().filter_map(|&k| sum.site(i, k)) {
                            later[j] = true;
                        }
                    }
                    ForcePart::Loop { sum: s, from, to } => {
                        let (kmin, kmax) = shift_range(&lattice.sums[s].variables);
                        let done = (from + kmin - 1) as usize..(to + kmin) as usize;
                        if let Some(w) = window[s].as_mut()
                            && !later[done.clone()].iter().any(|&l| l)
                        {
                            w.kick = true;
                            kicked[done].fill(true);
                        }
                        later[(from + kmin - 1) as usize..(to + kmax) as usize].fill(true);
                    }
                }
            }
        }
        // Never written: -0.
        let init: Vec<bool> = init.iter().zip(&touched).map(|(&i, &t)| i || !t).collect();
        let undrifted: Vec<bool> = drifted.iter().map(|&d| !d).collect();
        let unkicked: Vec<bool> = kicked.iter().map(|&k| !k).collect();
        OutputPlan {
            parts,
            window,
            init: ranges(&init),
            pre_drift: ranges(&pre),
            post_drift: ranges(&undrifted),
            post_kick: ranges(&unkicked),
        }
    }
}
