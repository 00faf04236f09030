//! Which part of a function of a lattice's state belongs to which site: the energy
//! distribution of the lattice literature for potentials and Hamiltonians whose lattice sums are
//! unrolled (for sums compiled as loops, [`crate::lattice::LatticeEvaluator::site_potentials`]
//! gives the same shares).

use crate::eval;
use crate::graph::{Graph, Node, NodeId};
use crate::lower::Parts;

/// A function's parts as lowered, and their sites once first asked for (most runs never ask).
pub(crate) struct SiteShares {
    parts: Parts,
    arg: u8,
    sites: usize,
    built: std::sync::OnceLock<SiteParts>,
}

impl SiteShares {
    /// The parts of a function whose argument `arg` holds the state, entry `k` belonging to
    /// site `k % sites`.
    pub(crate) fn new(parts: Parts, arg: u8, sites: usize) -> Self {
        Self {
            parts,
            arg,
            sites,
            built: std::sync::OnceLock::new(),
        }
    }

    /// Whether the function adds no lattice sums (its parts belong to no known site).
    pub(crate) fn has_no_sums(&self) -> bool {
        self.parts.terms.is_empty()
    }

    /// [`SiteParts::shares`].
    pub(crate) fn shares(
        &self,
        graph: &Graph,
        args: &[&[f64]],
        out: &mut [f64],
    ) -> Result<(), String> {
        self.built
            .get_or_init(|| SiteParts::new(graph, &self.parts, self.arg, self.sites))
            .shares(graph, args, out)
    }
}

/// A function's parts ([`crate::lower::Lowered::parts`]): each term of its top-level lattice
/// sums and each other part, its coefficient, and the distinct sites (0-based) it reads.
struct SiteParts {
    terms: Vec<(NodeId, f64, Vec<u32>)>,
    rest: Vec<(NodeId, f64, Vec<u32>)>,
}

impl SiteParts {
    /// The parts of a function whose argument `arg` holds the state, entry `k` belonging to
    /// site `k % sites` (a potential's `q`; a Hamiltonian's `q` then `p`).
    fn new(graph: &Graph, parts: &Parts, arg: u8, sites: usize) -> Self {
        let with_sites = |list: &[(NodeId, f64)]| {
            list.iter()
                .map(|&(id, c)| (id, c, sites_read(graph, id, arg, sites)))
                .collect()
        };
        Self {
            terms: with_sites(&parts.terms),
            rest: with_sites(&parts.rest),
        }
    }

    /// Each term of a sum times its coefficient shared equally by the distinct sites it reads
    /// (a wall is no site); the rest, as a whole and where it is not zero, to the one site it
    /// reads. `args` are the function's argument arrays; `out` has one entry per site.
    fn shares(&self, graph: &Graph, args: &[&[f64]], out: &mut [f64]) -> Result<(), String> {
        let outputs: Vec<NodeId> = self.terms.iter().chain(&self.rest).map(|p| p.0).collect();
        let mut values = vec![0.0; outputs.len()];
        eval::Evaluator::new().eval(graph, args, &outputs, &mut values);
        out.fill(0.0);
        let (terms, rest) = values.split_at(self.terms.len());
        for (k, ((_, c, sites), v)) in self.terms.iter().zip(terms).enumerate() {
            let value = c * v;
            if sites.is_empty() {
                if value != 0.0 {
                    return Err(format!(
                        "term {} of V's lattice sums reads no site but is {value}, which \
                         belongs to no site",
                        k + 1
                    ));
                }
                continue;
            }
            let share = value / sites.len() as f64;
            for &j in sites {
                out[j as usize] += share;
            }
        }
        // The rest as a whole, as for loops: where it is not zero, to the one site it reads.
        let value: f64 = self.rest.iter().zip(rest).map(|((_, c, _), v)| c * v).sum();
        let mut sites: Vec<u32> = self.rest.iter().flat_map(|r| r.2.iter().copied()).collect();
        sites.sort_unstable();
        sites.dedup();
        match sites[..] {
            _ if value == 0.0 => {}
            [j] => out[j as usize] += value,
            [] => {
                return Err(format!(
                    "V has a constant part {value} outside its lattice sums, which belongs to \
                     no site"
                ));
            }
            _ => {
                let names: Vec<String> = sites.iter().map(|j| format!("q{}", j + 1)).collect();
                return Err(format!(
                    "the part of V outside its lattice sums reads several sites ({}), so which \
                     share is whose is not written down: write it as lattice sums",
                    names.join(", ")
                ));
            }
        }
        Ok(())
    }
}

/// The distinct sites (`index % sites` of the inputs of argument `arg`, sorted) node `id`
/// depends on.
fn sites_read(graph: &Graph, id: NodeId, arg: u8, sites: usize) -> Vec<u32> {
    let mut seen = std::collections::HashSet::new();
    let mut stack = vec![id];
    let mut read = Vec::new();
    while let Some(top) = stack.pop() {
        if !seen.insert(top) {
            continue;
        }
        let node = graph.node(top);
        if let Node::Input { arg: a, index } = *node
            && a == arg
        {
            read.push(index % sites.max(1) as u32);
        }
        stack.extend(node.operands());
    }
    read.sort_unstable();
    read.dedup();
    read
}
