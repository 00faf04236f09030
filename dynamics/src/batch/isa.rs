//! Run-time choice of the instruction set: the same generic kernel compiled for AVX-512, AVX2
//! and baseline x86-64 (or whatever the target has), picked by CPU detection.
//!
//! The chunk width `L` (lanes processed together) grows with the register file. A model whose
//! whole state stays in registers (Henon-Heiles) takes wide chunks, several independent vectors
//! per row in flight (each lane's step is one long dependency chain); a model that streams its
//! rows through the cache (the FPUT chain) takes narrow ones, so a chunk's rows stay in L1/L2.
//! Measured on AVX-512: HH 64 lanes 3.9e8 vs 16 lanes 2.3e8 orbit-steps/s; FPUT N = 101
//! 16 lanes 4.2e6 vs 64 lanes 0.9e6.

use super::lanes::{LaneHamiltonian, StepCoeffs};
use super::soa::{LANE_QUANTUM, Soa};

/// An instruction set the kernel is compiled for.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Isa {
    Avx512,
    Avx2,
    /// The compilation target's baseline (SSE2 on x86-64).
    Portable,
}

/// Calls a kernel's instantiation for `isa` after checking that this CPU has it:
/// `on_isa!(isa, avx512_call, avx2_call, baseline_call)`, the first two calls of
/// `#[target_feature]` functions (x86-64 only; elsewhere the baseline serves every `Isa`).
macro_rules! on_isa {
    ($isa:expr, $avx512:expr, $avx2:expr, $portable:expr $(,)?) => {{
        let isa: $crate::batch::Isa = $isa;
        assert!(
            isa.available(),
            "{} is not supported by this CPU",
            isa.name()
        );
        match isa {
            // SAFETY: the CPU supports the instruction set (checked above).
            #[cfg(target_arch = "x86_64")]
            $crate::batch::Isa::Avx512 => unsafe { $avx512 },
            // SAFETY: as above.
            #[cfg(target_arch = "x86_64")]
            $crate::batch::Isa::Avx2 => unsafe { $avx2 },
            _ => $portable,
        }
    }};
}
pub(crate) use on_isa;

impl Isa {
    pub const ALL: [Isa; 3] = [Isa::Avx512, Isa::Avx2, Isa::Portable];

    /// The widest instruction set this CPU supports.
    pub fn detect() -> Self {
        Self::ALL
            .into_iter()
            .find(|i| i.available())
            .unwrap_or(Isa::Portable)
    }

    pub fn available(self) -> bool {
        match self {
            #[cfg(target_arch = "x86_64")]
            Isa::Avx512 => std::arch::is_x86_feature_detected!("avx512f"),
            #[cfg(target_arch = "x86_64")]
            Isa::Avx2 => {
                std::arch::is_x86_feature_detected!("avx2")
                    && std::arch::is_x86_feature_detected!("fma")
            }
            #[cfg(not(target_arch = "x86_64"))]
            Isa::Avx512 | Isa::Avx2 => false,
            Isa::Portable => true,
        }
    }

    pub fn name(self) -> &'static str {
        match self {
            Isa::Avx512 => "avx512",
            Isa::Avx2 => "avx2",
            Isa::Portable => "portable",
        }
    }

    pub fn from_name(s: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|i| i.name() == s)
    }
}

/// One of a model's step loops, as a chunk loop runs it on each chunk of `L` lanes.
trait ChunkSteps<M: LaneHamiltonian> {
    fn steps<const L: usize>(&self, m: &M, buf: &mut [[f64; L]], force: &mut [[f64; L]]);
}

/// [`LaneHamiltonian::orbit_steps`].
struct Orbits<'a>(&'a StepCoeffs, u64);

impl<M: LaneHamiltonian> ChunkSteps<M> for Orbits<'_> {
    #[inline(always)]
    fn steps<const L: usize>(&self, m: &M, buf: &mut [[f64; L]], force: &mut [[f64; L]]) {
        m.orbit_steps(self.0, buf, force, self.1)
    }
}

/// [`LaneHamiltonian::tangent_steps`] along the recorded stages.
struct Tangents<'a>(&'a StepCoeffs, &'a [f64], u64);

impl<M: LaneHamiltonian> ChunkSteps<M> for Tangents<'_> {
    #[inline(always)]
    fn steps<const L: usize>(&self, m: &M, buf: &mut [[f64; L]], force: &mut [[f64; L]]) {
        m.tangent_steps(self.0, self.1, buf, force, self.2)
    }
}

/// [`LaneHamiltonian::orbit_tangent_steps`].
struct OrbitTangents<'a>(&'a StepCoeffs, u64);

impl<M: LaneHamiltonian> ChunkSteps<M> for OrbitTangents<'_> {
    #[inline(always)]
    fn steps<const L: usize>(&self, m: &M, buf: &mut [[f64; L]], force: &mut [[f64; L]]) {
        m.orbit_tangent_steps(self.0, buf, force, self.1)
    }
}

/// Every lane of `x`, chunk by chunk: `L` lanes at a time, the remainder by `LANE_QUANTUM`.
#[inline(always)]
fn chunks<M: LaneHamiltonian, S: ChunkSteps<M>, const L: usize>(m: &M, x: &mut Soa, step: &S) {
    let mut o = 0;
    if L > LANE_QUANTUM {
        let mut buf = vec![[0.0; L]; x.rows()];
        let mut force = vec![[0.0; L]; m.dof()];
        while o + L <= x.lanes() {
            x.gather(o, &mut buf);
            step.steps(m, &mut buf, &mut force);
            x.scatter(o, &buf);
            o += L;
        }
    }
    let mut buf = vec![[0.0; LANE_QUANTUM]; x.rows()];
    let mut force = vec![[0.0; LANE_QUANTUM]; m.dof()];
    while o < x.lanes() {
        x.gather(o, &mut buf);
        step.steps(m, &mut buf, &mut force);
        x.scatter(o, &buf);
        o += LANE_QUANTUM;
    }
}

#[inline(always)]
fn orbit_chunks<M: LaneHamiltonian, const L: usize>(m: &M, c: &StepCoeffs, x: &mut Soa, n: u64) {
    chunks::<M, _, L>(m, x, &Orbits(c, n))
}

#[inline(always)]
fn tangent_chunks<M: LaneHamiltonian, const L: usize>(
    m: &M,
    c: &StepCoeffs,
    stages: &[f64],
    v: &mut Soa,
    n: u64,
) {
    chunks::<M, _, L>(m, v, &Tangents(c, stages, n))
}

// The instantiations. `fma` is enabled with AVX2 because every AVX2 CPU has it; it changes
// nothing here, since Rust never fuses a separate multiply and add.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
fn orbits_avx512<M: LaneHamiltonian>(m: &M, c: &StepCoeffs, x: &mut Soa, n: u64) {
    if m.register_resident() {
        orbit_chunks::<M, 64>(m, c, x, n)
    } else if m.dof() < LONG_CHAIN {
        orbit_chunks::<M, 16>(m, c, x, n)
    } else {
        orbit_chunks::<M, 8>(m, c, x, n)
    }
}

/// From this many degrees of freedom on, a streamed model's AVX-512 orbit chunks are one
/// vector wide: the sites of one stage already give the out-of-order core enough independent
/// vectors, and the narrower chunk halves what each stage streams. A short chain needs two
/// vectors per row to hide the latency of a stage (drift, force, kick). Measured on Zen 5
/// (a loaded 2-core VM; `chaoscope bench --kernel-only --isa avx512`), FPUT kernel over the
/// plain loop: N = 5: 16 lanes 2.07, 8 lanes 0.36; N = 101: 16 lanes 0.77, 8 lanes 2.3;
/// N = 501: 1.48 and 1.14. (Only the x86-64 AVX-512 instantiation reads it.)
#[cfg(target_arch = "x86_64")]
const LONG_CHAIN: usize = 32;

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
fn orbits_avx2<M: LaneHamiltonian>(m: &M, c: &StepCoeffs, x: &mut Soa, n: u64) {
    if m.register_resident() {
        orbit_chunks::<M, 32>(m, c, x, n)
    } else {
        orbit_chunks::<M, 8>(m, c, x, n)
    }
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
fn tangents_avx512<M: LaneHamiltonian>(m: &M, c: &StepCoeffs, s: &[f64], v: &mut Soa, n: u64) {
    // Tangent chunks are wide for every model: the shared reference's per-stage work
    // (Hessian entries) is amortized over all lanes of a chunk.
    tangent_chunks::<M, 64>(m, c, s, v, n)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
fn tangents_avx2<M: LaneHamiltonian>(m: &M, c: &StepCoeffs, s: &[f64], v: &mut Soa, n: u64) {
    // Tangent chunks are wide for every model: the shared reference's per-stage work
    // (Hessian entries) is amortized over all lanes of a chunk.
    tangent_chunks::<M, 32>(m, c, s, v, n)
}

pub(super) fn dispatch_orbits<M: LaneHamiltonian>(
    isa: Isa,
    m: &M,
    c: &StepCoeffs,
    x: &mut Soa,
    n: u64,
) {
    on_isa!(
        isa,
        orbits_avx512(m, c, x, n),
        orbits_avx2(m, c, x, n),
        orbit_chunks::<M, LANE_QUANTUM>(m, c, x, n)
    )
}

pub(super) fn dispatch_tangents<M: LaneHamiltonian>(
    isa: Isa,
    m: &M,
    c: &StepCoeffs,
    stages: &[f64],
    v: &mut Soa,
    n: u64,
) {
    on_isa!(
        isa,
        tangents_avx512(m, c, stages, v, n),
        tangents_avx2(m, c, stages, v, n),
        tangent_chunks::<M, LANE_QUANTUM>(m, c, stages, v, n)
    )
}

/// Every lane of `x` (orbit and tangent vectors, [`LaneHamiltonian::orbit_tangent_steps`]), `L` lanes
/// at a time, the remainder by `LANE_QUANTUM`.
#[inline(always)]
fn orbit_tangent_chunks<M: LaneHamiltonian, const L: usize>(
    m: &M,
    c: &StepCoeffs,
    x: &mut Soa,
    n: u64,
) {
    chunks::<M, _, L>(m, x, &OrbitTangents(c, n))
}

/// Most rows a register-resident model's orbit-and-tangents chunk is two AVX-512 vectors wide
/// for: an orbit with one or two tangent vectors of a two-degree-of-freedom system (8 or 12
/// rows, 16 or 24 of the 32 registers). One vector per row leaves each stage a chain of
/// dependent operations the core waits on; two give it independent work. A basis (20 rows)
/// stays one vector wide: two would spill.
#[cfg(target_arch = "x86_64")]
const WIDE_ORBIT_TANGENT_ROWS: usize = 12;

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
fn orbit_tangents_avx512<M: LaneHamiltonian>(m: &M, c: &StepCoeffs, x: &mut Soa, n: u64) {
    if m.register_resident() && x.rows() <= WIDE_ORBIT_TANGENT_ROWS {
        orbit_tangent_chunks::<M, 16>(m, c, x, n)
    } else {
        orbit_tangent_chunks::<M, LANE_QUANTUM>(m, c, x, n)
    }
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
fn orbit_tangents_avx2<M: LaneHamiltonian>(m: &M, c: &StepCoeffs, x: &mut Soa, n: u64) {
    orbit_tangent_chunks::<M, LANE_QUANTUM>(m, c, x, n)
}

pub(super) fn dispatch_orbit_tangents<M: LaneHamiltonian>(
    isa: Isa,
    m: &M,
    c: &StepCoeffs,
    x: &mut Soa,
    n: u64,
) {
    on_isa!(
        isa,
        orbit_tangents_avx512(m, c, x, n),
        orbit_tangents_avx2(m, c, x, n),
        orbit_tangent_chunks::<M, LANE_QUANTUM>(m, c, x, n)
    )
}
