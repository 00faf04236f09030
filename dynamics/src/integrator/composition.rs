//! Compositions of `n` exactly solvable flows, for Hamiltonians `H = P_1 + ... + P_n` that are
//! not separable into `T(p) + V(q)` but split into parts whose flows are known in closed form
//! (the disordered discrete nonlinear Schroedinger lattice: the on-site nonlinear rotation and
//! the two hopping parts, Skokos, Gerlach, Bodyfelt, Papamikos, Eggl, Phys. Lett. A 378, 1809
//! (2014)).
//!
//! The base map is the symmetric second-order composition
//! `S(tau) = P_1(tau/2) ... P_{n-1}(tau/2) P_n(tau) P_{n-1}(tau/2) ... P_1(tau/2)`
//! (`ABC^2` for three parts); higher orders compose it, `S(g_1 h) S(g_2 h) ... S(g_m h)`, with the
//! palindromic weights `g_i` of the composition literature the efficiency paper (Danieli, Many
//! Manda, Mithun, Skokos, Math. in Eng. 1, 447 (2019)) takes them from. Neighbouring stages of
//! the first part are merged into one flow of the summed time (`P_1(a) P_1(b) = P_1(a + b)`
//! exactly, the flow of an autonomous Hamiltonian), never across step boundaries, so a step is
//! a function of the state alone and the orbit does not depend on the sampling.
//!
//! The tangent map applies the exact derivative of each part's flow at the state that part
//! starts from ([`SplitFlows::flow_tangent`]), so the variational method shares the
//! composition's order, as the two-part splittings' tangent maps do (`splitting.rs`, whose
//! arithmetic this file leaves alone: it is a separate shape beside it).

/// A Hamiltonian split into `parts()` pieces, each with an exact flow and its exact tangent map.
/// States are `x = (q_1..q_N, p_1..p_N)`.
pub trait SplitFlows: Send + Sync {
    /// Dimension of the state (and of every deviation vector).
    fn dim(&self) -> usize;

    /// Number of parts `n` (at least 2).
    fn parts(&self) -> usize;

    /// `x <- exp(tau X_part) x`: the exact flow of part `part` for time `tau`.
    fn flow(&self, part: usize, x: &mut [f64], tau: f64);

    /// The same flow of `x`, and of every deviation vector stored one after the other in `w`
    /// its exact derivative at the state `x` the flow starts from.
    fn flow_tangent(&self, part: usize, x: &mut [f64], w: &mut [f64], tau: f64);
}

/// The compositions chaoscope ships.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum CompositionScheme {
    /// The symmetric base map itself, `ABC^2` for three parts: order 2.
    Abc2,
    /// Yoshida's triple jump of the base map: order 4, 3 stages.
    Abc4,
    /// Kahan and Li (1997) `s9odr6a`: order 6, 9 stages.
    S9Abc6,
    /// Sofroniou and Spaletta (2005), 11 stages: order 6.
    S11Abc6,
    /// Kahan and Li (1997) `s17odr8a`: order 8, 17 stages.
    S17Abc8,
}

// Kahan, W. and Li, R.-C., "Composition constants for raising the orders of unconventional
// schemes for ordinary differential equations", Math. Comp. 66, 1089 (1997), the method s9odr6a:
// the first half of the palindrome g_1..g_5 (g_6..g_9 mirror g_4..g_1), as published to 26 digits.
#[allow(clippy::excessive_precision)]
const S9ODR6: [f64; 5] = [
    0.39216144400731413927925056,
    0.33259913678935943859974864,
    -0.70624617255763935980996482,
    0.08221359629355080023149045,
    0.79854399093482996339895035,
];

// Sofroniou, M. and Spaletta, G., "Derivation of symmetric composition constants for symmetric
// integrators", Optim. Methods Softw. 20, 597 (2005), the sixth-order method of 11 stages:
// g_1..g_6 (g_7..g_11 mirror g_5..g_1), as published to 32 digits.
#[allow(clippy::excessive_precision)]
const S11ODR6: [f64; 6] = [
    0.21375583945878254555518066964857,
    0.18329381407425713911385974425217,
    0.17692819473098943794898811709929,
    -0.44329082681170215849622829626258,
    0.11728560432865935385403585669136,
    0.50405474843802736404832781714239,
];

// Kahan and Li (1997), the method s17odr8a: g_1..g_9 (g_10..g_17 mirror g_8..g_1), as
// published to 26 digits.
#[allow(clippy::excessive_precision)]
const S17ODR8: [f64; 9] = [
    0.13020248308889008087881763,
    0.56116298177510838456196441,
    -0.38947496264484728640807860,
    0.15884190655515560089621075,
    -0.39590389413323757733623154,
    0.18453964097831570709183254,
    0.25837438768632204729397911,
    0.29501172360931029887096624,
    -0.60550853383003451169892108,
];

/// The full palindrome `g_1..g_m` from its first half (middle entry included).
fn palindrome(half: &[f64]) -> Vec<f64> {
    let mut g = half.to_vec();
    g.extend(half[..half.len() - 1].iter().rev());
    g
}

impl CompositionScheme {
    pub const ALL: [CompositionScheme; 5] = [
        CompositionScheme::Abc2,
        CompositionScheme::Abc4,
        CompositionScheme::S9Abc6,
        CompositionScheme::S11Abc6,
        CompositionScheme::S17Abc8,
    ];

    /// Name as written in configs (`integrator.method`).
    pub fn name(self) -> &'static str {
        match self {
            CompositionScheme::Abc2 => "abc2",
            CompositionScheme::Abc4 => "abc4",
            CompositionScheme::S9Abc6 => "s9abc6",
            CompositionScheme::S11Abc6 => "s11abc6",
            CompositionScheme::S17Abc8 => "s17abc8",
        }
    }

    pub fn from_name(name: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|k| k.name() == name)
    }

    /// Order of the global error in `h`.
    pub fn order(self) -> u32 {
        match self {
            CompositionScheme::Abc2 => 2,
            CompositionScheme::Abc4 => 4,
            CompositionScheme::S9Abc6 | CompositionScheme::S11Abc6 => 6,
            CompositionScheme::S17Abc8 => 8,
        }
    }

    /// The weights `g_1..g_m` of the base map's stages (summing to 1).
    pub fn weights(self) -> Vec<f64> {
        match self {
            CompositionScheme::Abc2 => vec![1.0],
            CompositionScheme::Abc4 => {
                let cbrt2 = 2f64.cbrt();
                let w1 = 1.0 / (2.0 - cbrt2);
                let w0 = -cbrt2 / (2.0 - cbrt2);
                vec![w1, w0, w1]
            }
            CompositionScheme::S9Abc6 => palindrome(&S9ODR6),
            CompositionScheme::S11Abc6 => palindrome(&S11ODR6),
            CompositionScheme::S17Abc8 => palindrome(&S17ODR8),
        }
    }

    /// Every composition with its order, as error messages list them.
    pub fn catalogue() -> String {
        Self::ALL
            .iter()
            .map(|k| format!("{} (order {})", k.name(), k.order()))
            .collect::<Vec<_>>()
            .join(", ")
    }
}

/// One step of a composition: the flows `(part, c)` in order, part `part` for time `c h`.
#[derive(Debug, Clone, PartialEq)]
pub struct Composition {
    kind: CompositionScheme,
    stages: Vec<(usize, f64)>,
}

impl Composition {
    /// The composition `kind` of the symmetric base map of `parts` parts (at least 2).
    pub fn new(kind: CompositionScheme, parts: usize) -> Self {
        assert!(parts >= 2, "a composition needs at least two parts");
        let mut stages: Vec<(usize, f64)> = Vec::new();
        for g in kind.weights() {
            let half = g / 2.0;
            let base = (0..parts - 1)
                .map(|i| (i, half))
                .chain(std::iter::once((parts - 1, g)))
                .chain((0..parts - 1).rev().map(|i| (i, half)));
            for (part, c) in base {
                match stages.last_mut() {
                    // The outer part of consecutive base maps: one flow of the summed time.
                    Some((last, sum)) if *last == part => *sum += c,
                    _ => stages.push((part, c)),
                }
            }
        }
        Self { kind, stages }
    }

    pub fn kind(&self) -> CompositionScheme {
        self.kind
    }

    pub fn name(&self) -> &'static str {
        self.kind.name()
    }

    pub fn order(&self) -> u32 {
        self.kind.order()
    }

    /// The flows of one step, `(part, coefficient of h)`.
    pub fn stages(&self) -> &[(usize, f64)] {
        &self.stages
    }

    /// The stages times `h`: `(part, time)`, what a system of fixed step `h` steps.
    pub fn times(&self, h: f64) -> Vec<(usize, f64)> {
        self.stages.iter().map(|&(p, c)| (p, c * h)).collect()
    }

    /// One step of `system` along the flows `times` ([`Composition::times`]).
    #[inline]
    pub fn step<S: SplitFlows + ?Sized>(system: &S, times: &[(usize, f64)], x: &mut [f64]) {
        for &(part, tau) in times {
            system.flow(part, x, tau);
        }
    }

    /// One step of `x` and its deviation vectors `w` by the exact tangent map of
    /// [`Composition::step`].
    #[inline]
    pub fn step_tangent<S: SplitFlows + ?Sized>(
        system: &S,
        times: &[(usize, f64)],
        x: &mut [f64],
        w: &mut [f64],
    ) {
        for &(part, tau) in times {
            system.flow_tangent(part, x, w, tau);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The weights of each composition sum to one (to a few roundings of their ~10 entries),
    /// and every part's stage times sum to one step: the consistency condition of order 1.
    #[test]
    fn weights_and_stage_times_sum_to_one() {
        for kind in CompositionScheme::ALL {
            let g = kind.weights();
            let sum: f64 = g.iter().sum();
            assert!((sum - 1.0).abs() < 1e-15, "{kind:?}: weights sum {sum}");
            for parts in [2, 3] {
                let c = Composition::new(kind, parts);
                for part in 0..parts {
                    let s: f64 = c
                        .stages()
                        .iter()
                        .filter(|(p, _)| *p == part)
                        .map(|(_, c)| c)
                        .sum();
                    assert!((s - 1.0).abs() < 1e-14, "{kind:?} part {part}: {s}");
                }
                // Palindromic, and no two neighbouring stages of one part.
                let st = c.stages();
                for i in 0..st.len() {
                    assert_eq!(st[i].0, st[st.len() - 1 - i].0);
                    assert!((st[i].1 - st[st.len() - 1 - i].1).abs() < 1e-15);
                }
                assert!(st.windows(2).all(|w| w[0].0 != w[1].0));
            }
        }
        // ABC^2: A(1/2) B(1/2) C(1) B(1/2) A(1/2).
        assert_eq!(
            Composition::new(CompositionScheme::Abc2, 3).stages(),
            [(0, 0.5), (1, 0.5), (2, 1.0), (1, 0.5), (0, 0.5)]
        );
        // s17: 17 base maps of 4 flows each plus the last A.
        assert_eq!(
            Composition::new(CompositionScheme::S17Abc8, 3)
                .stages()
                .len(),
            17 * 4 + 1
        );
    }

    #[test]
    fn names_round_trip() {
        for kind in CompositionScheme::ALL {
            assert_eq!(CompositionScheme::from_name(kind.name()), Some(kind));
        }
        assert_eq!(
            CompositionScheme::catalogue(),
            "abc2 (order 2), abc4 (order 4), s9abc6 (order 6), s11abc6 (order 6), s17abc8 (order 8)"
        );
    }
}
