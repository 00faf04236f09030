//! The plan of the fused one-orbit pass of a lattice potential (one orbit and its tangent
//! vectors stepped together, vectorized along the sites; printed as C by [`super::c::fused`]
//! and by Cranelift by [`super::cranelift::fused`]): which sites one vector loop steps, in which order every site takes
//! its contributions, and which sites are written out one by one. Nothing here is C: the plan
//! is the same for any printer, and the printer only spells it.
//!
//! A site adds its contributions in [`crate::lattice::LatticeEvaluator`]'s order: `-0` first,
//! then the expression around the sums, then every sum's terms in increasing `i`, slot by slot.
//! Away from the ends that order is the same at every site (a sum's slots by decreasing shift:
//! the term that reads a site through its largest shift comes first), so one vector loop
//! computes, for each site, each slot's derivative of the term that reads the site through that
//! slot (a term shared by two sites is computed at both: each value is the graph's operations
//! on the same inputs, so the same bits, and nothing goes through memory). The few sites at the
//! ends (a wall, a periodic wrap, the rest's sites) are written out one by one with their own
//! lists.
//!
//! On a square lattice (its sums one per row, [`SiteSum::site`]) the regular sites are those
//! whose contributions are the most shared ones translated by whole rows and columns:
//! rectangles, most often one between the edges, each stepped by a loop over its rows of the
//! chain's loop along the row; the sites at the edges are the ends.
//!
//! The end sites' lists are bounded by the boundary terms, not by `N` (on a square, by its
//! edges). A lattice whose ends would need more sites written out than [`MAX_END_SITES`]
//! ([`max_square_end_sites`] on a square), with fewer than [`MIN_SITES`] sites, or a square of
//! a side over [`MAX_SQUARE_SIDE`], has no plan.

use crate::graph::NodeId;
use crate::lattice::{LatticePotential, SiteSum, split_shift};

/// Most sites written out one by one at the ends.
const MAX_END_SITES: usize = 256;

/// Fewest sites for the kernel: below this the vector loops hardly run.
pub(crate) const MIN_SITES: usize = 16;

/// One contribution to a site: slot `slot` of term `term` of sum `sum`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct Contribution {
    pub(crate) sum: usize,
    pub(crate) term: i64,
    pub(crate) slot: usize,
}

/// The plan: the sites `regular.0..=regular.1` take their contributions in the same
/// order (`order`: per sum, the slots by decreasing shift), every other site has its own list.
pub(crate) struct FusedPlan {
    pub(crate) regular: (usize, usize),
    /// Per sum, its slots in the order a regular site takes them.
    pub(crate) order: Vec<Vec<usize>>,
    /// A regular site's contributions in order, as (sum, slot): on a chain every sum's slots
    /// in `order`; on a square the sums of the rectangle's first site, whose translates the
    /// other regular sites take.
    pub(crate) pattern: Vec<(usize, usize)>,
    /// On a square, the regular sites are rectangles of it (most often one, between its
    /// edges), not a run of the chain of its sites.
    pub(crate) square: Option<Vec<Rectangle>>,
    /// The other sites: (site, its contributions); the rest's, where it has one, comes first.
    pub(crate) ends: Vec<(usize, Vec<Contribution>)>,
}

/// The regular sites of a square of side `side`: rows `rows.0..=rows.1` by columns
/// `columns.0..=columns.1` (0-based), site `r side + c`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct Rectangle {
    pub(crate) side: usize,
    pub(crate) rows: (usize, usize),
    pub(crate) columns: (usize, usize),
}

/// Most rectangles of regular sites on a square (each is a loop of its own).
const MAX_SQUARE_BLOCKS: usize = 16;

/// Most sites written out one by one at the ends of a square of side `side`: its edges (the
/// rows and columns nearest them) are `4 side` sites.
fn max_square_end_sites(side: usize) -> usize {
    MAX_END_SITES.max(8 * side)
}

/// Largest side of a square that gets the kernel. The end sites are one function's straight
/// code, whose compile time grows faster than their number (an Intel Xeon: 1 CPU-s at a side
/// of 64, 18 at 128, beside the step kernels' 17 and 53), and the kernel is built into the
/// square's step-kernel library, which a build past the compiler's time limit would lose.
pub(crate) const MAX_SQUARE_SIDE: usize = 128;

impl FusedPlan {
    /// `None` where the kernel does not apply: no Hessian-vector product, fewer than
    /// [`MIN_SITES`] sites, no run of regular sites, or more ends than [`MAX_END_SITES`] ([`max_square_end_sites`] on a square).
    pub(crate) fn new(lattice: &LatticePotential) -> Option<Self> {
        if !lattice.has_hessian() || lattice.n < MIN_SITES {
            return None;
        }
        let n = lattice.n;
        // Every site's contributions in the evaluator's order: sums in turn, terms in
        // increasing `i`, slots in slot order.
        let mut lists: Vec<Vec<Contribution>> = vec![Vec::new(); n];
        for (sum, s) in lattice.sums.iter().enumerate() {
            for term in s.first..=s.last {
                for (slot, &shift) in s.variables.iter().enumerate() {
                    if let Some(j) = s.site(term, shift) {
                        lists[j].push(Contribution { sum, term, slot });
                    }
                }
            }
        }
        let order: Vec<Vec<usize>> = lattice
            .sums
            .iter()
            .map(|s| {
                let mut slots: Vec<usize> = (0..s.variables.len()).collect();
                // Increasing term index at a fixed site is decreasing shift; equal shifts (one
                // term reading a site twice) keep slot order.
                slots.sort_by_key(|&slot| std::cmp::Reverse(s.variables[slot]));
                slots
            })
            .collect();
        let rest: Vec<bool> = {
            let mut r = vec![false; n];
            for &(j, _) in &lattice.rest_gradient {
                r[j as usize] = true;
            }
            if let Some(hv) = &lattice.rest_hessian_vector {
                for &(j, _) in hv {
                    r[j as usize] = true;
                }
            }
            r
        };
        if let Some(side) = lattice.sums.first().and_then(|s| s.side) {
            return Self::square(lattice, side, lists, &rest, order);
        }
        let regular_at = |j: usize| -> bool {
            if rest[j] {
                return false;
            }
            let mut expected = Vec::new();
            for (sum, s) in lattice.sums.iter().enumerate() {
                // Only terms that read inside the lattice (no wall, no wrap) run in the loop.
                let Some((from, to)) = s.interior() else {
                    return false;
                };
                for &slot in &order[sum] {
                    let term = j as i64 + 1 - s.variables[slot];
                    if term < from || term > to {
                        return false;
                    }
                    expected.push(Contribution { sum, term, slot });
                }
            }
            lists[j] == expected
        };
        // The longest run of regular sites.
        let (mut best, mut run_start) = (None::<(usize, usize)>, None::<usize>);
        for j in 0..=n {
            if j < n && regular_at(j) {
                run_start.get_or_insert(j);
                continue;
            }
            if let Some(a) = run_start.take() {
                let len = j - a;
                if best.is_none_or(|(b0, b1)| b1 + 1 - b0 < len) {
                    best = Some((a, j - 1));
                }
            }
        }
        let regular = best?;
        let pattern = order
            .iter()
            .enumerate()
            .flat_map(|(sum, slots)| slots.iter().map(move |&slot| (sum, slot)))
            .collect();
        let ends: Vec<(usize, Vec<Contribution>)> = (0..n)
            .filter(|&j| j < regular.0 || j > regular.1)
            .map(|j| (j, std::mem::take(&mut lists[j])))
            .collect();
        (ends.len() <= MAX_END_SITES).then_some(Self {
            regular,
            order,
            pattern,
            square: None,
            ends,
        })
    }

    /// The plan on a square of side `side`, whose sums run along one row each (a row's index
    /// is a number in its sums, [`SiteSum::site`]). Sums that are one another's translates
    /// by whole rows (the same term, derivatives, boundary and range, slots at the same
    /// offsets from their row) form a family. A site's contributions, in the evaluator's
    /// order, translated to it (family, row and column from it, slot; every term inside its
    /// row, none from the rest) are its pattern; the sites of the pattern most sites share
    /// are regular. Along a row they are runs of a chain's regular sites; consecutive rows
    /// with the same runs make a rectangle, stepped by one loop over its rows of the chain's
    /// loop (each row's run is the previous one's shifted by `side` sites); the others are
    /// ends.
    fn square(
        lattice: &LatticePotential,
        side: usize,
        mut lists: Vec<Vec<Contribution>>,
        rest: &[bool],
        order: Vec<Vec<usize>>,
    ) -> Option<Self> {
        let n = lattice.n;
        let l = side as i64;
        if side > MAX_SQUARE_SIDE
            || n != side * side
            || lattice.sums.iter().any(|s| s.side != Some(side))
        {
            return None;
        }
        // Each sum's row (that of its least shift) and family.
        let row_of = |s: &SiteSum| -> Option<i64> {
            let least = s.variables.iter().copied().min()?;
            Some(split_shift(least, side).0)
        };
        // The derivatives by their nodes and the coefficient's bits (`-0` is not `0` here).
        type Key<'a> = (
            NodeId,
            (u64, &'a [NodeId], Option<&'a [NodeId]>),
            crate::lower::Boundary,
            i64,
            i64,
            Vec<i64>,
            Vec<(&'a str, i64)>,
        );
        let mut families: Vec<Key> = Vec::new();
        let mut family = Vec::with_capacity(lattice.sums.len());
        let mut row = Vec::with_capacity(lattice.sums.len());
        for (s, sum) in lattice.sums.iter().enumerate() {
            let Some(r) = row_of(sum) else {
                // No variable: it reads no site, so no site's list names it.
                family.push(usize::MAX);
                row.push(0);
                continue;
            };
            let d = &lattice.derivatives[s];
            let key: Key = (
                sum.term,
                (
                    d.coefficient.to_bits(),
                    &d.gradient,
                    d.hessian_vector.as_deref(),
                ),
                sum.boundary,
                sum.first,
                sum.last,
                sum.variables.iter().map(|v| v - r * l).collect(),
                sum.params
                    .iter()
                    .map(|p| (p.name.as_str(), p.shift - r * l))
                    .collect(),
            );
            let f = families.iter().position(|k| *k == key).unwrap_or_else(|| {
                families.push(key);
                families.len() - 1
            });
            family.push(f);
            row.push(r);
        }
        // A site's list as (family, row from the site's, term from its column, slot), `None`
        // where a term reads beyond its row's ends (a wall or a wrap) or the rest adds to it.
        let translated = |j: usize| -> Option<Vec<(usize, i64, i64, usize)>> {
            if rest[j] {
                return None;
            }
            let (r, c) = ((j / side) as i64, (j % side) as i64);
            lists[j]
                .iter()
                .map(|&Contribution { sum, term, slot }| {
                    let (from, to) = lattice.sums[sum].interior()?;
                    ((from..=to).contains(&term) && family[sum] != usize::MAX).then_some((
                        family[sum],
                        row[sum] - r,
                        term - c,
                        slot,
                    ))
                })
                .collect()
        };
        // The pattern most sites share (the first of the most shared, so the source is the
        // same every time): the interior's, on any square of a side worth the kernel.
        let translated: Vec<_> = (0..n).map(translated).collect();
        let mut counts: Vec<(usize, usize)> = Vec::new(); // (first site, sites)
        for (j, t) in translated.iter().enumerate() {
            let Some(t) = t else { continue };
            match counts
                .iter()
                .position(|&(f, _)| translated[f].as_ref() == Some(t))
            {
                Some(at) => counts[at].1 += 1,
                None if counts.len() < 64 => counts.push((j, 1)),
                None => {}
            }
        }
        let &(first, _) = counts
            .iter()
            .max_by_key(|&&(f, count)| (count, std::cmp::Reverse(f)))?;
        let want = translated[first].clone();
        let regular = |j: usize| translated[j] == want;
        // Each row's runs of regular columns; consecutive rows with the same runs are one
        // rectangle, stepped by one loop over its rows.
        let mut blocks: Vec<Rectangle> = Vec::new();
        let mut previous: Vec<(usize, usize)> = Vec::new();
        for r in 0..side {
            let mut runs = Vec::new();
            let mut c = 0;
            while c < side {
                if !regular(r * side + c) {
                    c += 1;
                    continue;
                }
                let start = c;
                while c < side && regular(r * side + c) {
                    c += 1;
                }
                runs.push((start, c - 1));
            }
            if !runs.is_empty() && runs == previous {
                let from = blocks.len() - runs.len();
                for b in &mut blocks[from..] {
                    b.rows.1 = r;
                }
            } else {
                blocks.extend(runs.iter().map(|&columns| Rectangle {
                    side,
                    rows: (r, r),
                    columns,
                }));
            }
            previous = runs;
        }
        if blocks.is_empty() || blocks.len() > MAX_SQUARE_BLOCKS {
            return None;
        }
        let pattern = lists[first].iter().map(|c| (c.sum, c.slot)).collect();
        let ends: Vec<(usize, Vec<Contribution>)> = (0..n)
            .filter(|&j| !regular(j))
            .map(|j| (j, std::mem::take(&mut lists[j])))
            .collect();
        (ends.len() <= max_square_end_sites(side)).then_some(Self {
            regular: (first, first),
            order,
            pattern,
            square: Some(blocks),
            ends,
        })
    }
}

/// Whether `lattice` gets the kernel (the C back end writes it into its step kernels' library).
pub fn applies(lattice: &LatticePotential) -> bool {
    FusedPlan::new(lattice).is_some()
}

/// Farthest a regular site's term reads a position from the site, in sites, for the sweep:
/// its shifted vectors are two of the registers' neighbours joined, which the narrower
/// vectors (4 lanes) reach up to 4 sites away.
pub(crate) const MAX_HELD_OFFSET: i64 = 4;

/// The sweep's last vector of regular sites at `LANES` = `lanes`: the one the loop (from
/// the regular run's first site `ja` to its last `jb`, in an `n`-site chain) stops at because
/// its next vector would run past the end, if it is whole.
pub(crate) struct TailIteration {
    /// Its first site.
    pub(crate) at: i64,
    /// Sites from the chain's last vector (`n - lanes ..`) that the loop drifted already
    /// (`lanes`: all, the chain ends with this vector's next).
    pub(crate) reach: i64,
}

/// [`TailIteration`] where there is one: the loop ran (its first vector), and stopped at a whole
/// vector of regular sites.
pub(crate) fn tail_iteration(n: i64, ja: i64, jb: i64, lanes: i64) -> Option<TailIteration> {
    let runs = |j: i64| j + lanes - 1 <= jb && j + 2 * lanes <= n;
    if !runs(ja) {
        return None;
    }
    let mut j = ja + lanes;
    while runs(j) {
        j += lanes;
    }
    (j + lanes - 1 <= jb).then_some(TailIteration {
        at: j,
        reach: j + 2 * lanes - n,
    })
}

impl FusedPlan {
    /// The offsets from a regular site `j` at which its terms read positions (`j + offset`),
    /// where every one is at most [`MAX_HELD_OFFSET`] away (the sweep's registers reach them);
    /// `None` otherwise (the printer then writes the stage-by-stage kernel).
    pub(crate) fn held_offsets(&self, lattice: &LatticePotential) -> Option<Vec<i64>> {
        // A square's neighbours in the next row are `side` sites away, and its regular sites
        // are not one run.
        if self.square.is_some() {
            return None;
        }
        let mut offsets = vec![0];
        for sum in &lattice.sums {
            for &slot_shift in &sum.variables {
                for &shift in &sum.variables {
                    let offset = shift - slot_shift;
                    if offset.abs() > MAX_HELD_OFFSET {
                        return None;
                    }
                    offsets.push(offset);
                }
            }
        }
        offsets.sort_unstable();
        offsets.dedup();
        Some(offsets)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::lattice::tests::lattice_of;
    use crate::lower::{Boundary, ParamValue, Shape};

    const DKG: &str =
        "sum(i = 1..N, k[i]/2*q[i]^2 + q[i]^4/4) + sum(i = 0..N, (q[i+1] - q[i])^2/(2*W))";

    fn dkg(n: usize, boundary: Boundary) -> LatticePotential {
        let k = ParamValue::Array((0..n).map(|j| 0.5 + 0.01 * j as f64).collect());
        lattice_of(
            n,
            boundary,
            Shape::Chain,
            &[("k", k), ("W", ParamValue::Scalar(4.0))],
            DKG,
        )
    }

    const KG_SQUARE: &str = "sum(i = 1..N, sum(j = 1..N, k[i, j]/2*q[i, j]^2 + q[i, j]^4/4)) \
        + sum(i = 0..N, sum(j = 1..N, (q[i+1, j] - q[i, j])^2/40)) \
        + sum(i = 1..N, sum(j = 0..N, (q[i, j+1] - q[i, j])^2/40))";

    fn square(side: usize, boundary: Boundary) -> LatticePotential {
        let k = ParamValue::Array((0..side * side).map(|j| 0.5 + 0.01 * j as f64).collect());
        let shape = Shape::Square { columns: boundary };
        lattice_of(side, boundary, shape, &[("k", k)], KG_SQUARE)
    }

    /// Every site exactly once: in the regular run (a chain) or a rectangle (a square), or
    /// among the ends.
    fn assert_covers(plan: &FusedPlan, n: usize) {
        let mut seen = vec![0; n];
        match &plan.square {
            None => (plan.regular.0..=plan.regular.1).for_each(|j| seen[j] += 1),
            Some(blocks) => {
                for b in blocks {
                    for r in b.rows.0..=b.rows.1 {
                        (b.columns.0..=b.columns.1).for_each(|c| seen[r * b.side + c] += 1);
                    }
                }
            }
        }
        plan.ends.iter().for_each(|(j, _)| seen[*j] += 1);
        assert!(seen.iter().all(|&s| s == 1), "{seen:?}");
    }

    /// A nearest-neighbour chain: every site but the two at the ends takes its on-site term,
    /// then the bond to its left (term `j - 1`, reading the site through the larger shift),
    /// then the bond to its right (term `j`): the evaluator's increasing `i`, all in one loop;
    /// the ends are two sites at any length, each with its own list: the on-site
    /// term and the two bonds (one of them to a wall) when fixed, the bond beyond a free end
    /// missing, and the wrap's bond besides (`sum(i = 0..N)` names it twice) when periodic.
    /// The sweep reaches one site either way.
    #[test]
    fn a_chain_is_one_loop_between_two_end_sites_at_any_length() {
        for (boundary, end_contributions) in [
            (Boundary::Fixed, 3),
            (Boundary::Free, 2),
            (Boundary::Periodic, 4),
        ] {
            for n in [MIN_SITES, 64, 1000] {
                let lattice = dkg(n, boundary);
                let plan = FusedPlan::new(&lattice).expect("a plan");
                assert_eq!(plan.regular, (1, n - 2), "{boundary:?} {n}");
                assert_eq!(plan.order, [vec![0], vec![0, 1]]);
                assert_eq!(plan.pattern, [(0, 0), (1, 0), (1, 1)]);
                let ends: Vec<(usize, usize)> =
                    plan.ends.iter().map(|(j, list)| (*j, list.len())).collect();
                assert_eq!(ends, [(0, end_contributions), (n - 1, end_contributions)]);
                assert!(plan.square.is_none());
                assert_covers(&plan, n);
                assert_eq!(plan.held_offsets(&lattice), Some(vec![-1, 0, 1]));
            }
        }
        // Too short for the vector loops.
        assert!(FusedPlan::new(&dkg(MIN_SITES - 1, Boundary::Fixed)).is_none());
    }

    /// A term reading six sites away is out of the sweep's reach: the stage-by-stage kernel.
    #[test]
    fn terms_beyond_the_sweeps_reach_are_stepped_stage_by_stage() {
        let far = "sum(i = 1..N, q[i]^4/4) + sum(i = 1..N, (q[i+6] - q[i])^2/2)";
        let lattice = lattice_of(64, Boundary::Periodic, Shape::Chain, &[], far);
        let plan = FusedPlan::new(&lattice).expect("a plan");
        assert_eq!(plan.held_offsets(&lattice), None);
        assert_covers(&plan, 64);
    }

    /// The Klein-Gordon square: its interior, the five-point stencil (the on-site term and
    /// four bonds), is one rectangle inside the edges on every boundary; the `4 (side - 1)`
    /// sites of the edges are the ends, up to a side of 128; beyond it, no plan. A square's
    /// neighbours in the next row are out of the sweep's reach.
    #[test]
    fn a_square_is_one_rectangle_inside_its_edges_up_to_a_side_of_128() {
        for boundary in [Boundary::Fixed, Boundary::Free, Boundary::Periodic] {
            for side in [4, 32, MAX_SQUARE_SIDE] {
                let lattice = square(side, boundary);
                let plan = FusedPlan::new(&lattice).expect("a plan");
                let inside = (1, side - 2);
                assert_eq!(
                    plan.square,
                    Some(vec![Rectangle {
                        side,
                        rows: inside,
                        columns: inside,
                    }]),
                    "{boundary:?} {side}"
                );
                assert_eq!(plan.pattern.len(), 5);
                assert_eq!(plan.ends.len(), 4 * (side - 1));
                assert_covers(&plan, side * side);
                assert_eq!(plan.held_offsets(&lattice), None);
            }
            assert!(FusedPlan::new(&square(MAX_SQUARE_SIDE + 1, boundary)).is_none());
        }
    }
}
