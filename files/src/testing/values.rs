//! Valid files with hostile values: recordings and map files that are well-formed MCAP holding
//! well-formed protobuf messages, written by the recorder's own writers ([`Recording`],
//! [`MapFile`]), whose field values are chosen by a stream of bytes. The structure-aware fuzz
//! target (`fuzz/`, target `values`) feeds it AFL's input, so every mutation AFL makes is a
//! change of a value, never of the file's structure; tests feed it seeded noise.
//!
//! Every field is read through [`Choices`]: a byte below [`Choices::KEEP`] keeps the field's
//! valid value (so an empty input is a valid run or map), a higher one picks a hostile value:
//! NaN, infinities, zero, negative zero, subnormals, values near the limits of f64, huge and
//! off-by-one counts and sizes, empty, long, path-like and multi-line strings, or raw bits.

use std::io::Cursor;

use chaoscope_schemas::proto::{
    DataMessage, EndOfRun, MapAxis, MapHeader, MapPoint, ReferenceState, RunHeader, Scheme,
    SeparationSet, end_of_run, map_point,
};

use super::Noise;
use crate::file::{Compression, FileOptions};
use crate::map_file::MapFile;
use crate::recording::{FinalizedBy, Recording};

/// The choices that make a file: bytes of a fuzzer's input, then (when they run out) zeros, so
/// the rest of the file keeps its valid values.
pub struct Choices<'a> {
    data: &'a [u8],
    at: usize,
}

/// Hostile floating-point values: what no producer writes, and valid values at the edges.
const HOSTILE_F64: [f64; 24] = [
    f64::NAN,
    f64::INFINITY,
    f64::NEG_INFINITY,
    0.0,
    -0.0,
    -1.0,
    1.0,
    2.0,
    0.5,
    5e-324,
    1e-320,
    1e-300,
    f64::MIN_POSITIVE,
    1e-8,
    1e8,
    1e300,
    1e308,
    -1e308,
    f64::MAX,
    f64::MIN,
    1.7976931348623155e308,
    -5e-324,
    4503599627370497.0,
    -f64::NAN,
];

/// Hostile counts, sizes, steps and indices.
const HOSTILE_U64: [u64; 16] = [
    0,
    1,
    2,
    3,
    7,
    1000,
    65_535,
    1 << 31,
    u32::MAX as u64,
    (u32::MAX as u64) + 1,
    1 << 53,
    (1 << 53) + 1,
    1 << 63,
    u64::MAX - 1,
    u64::MAX,
    10_000_000,
];

/// Hostile strings: empty, path-like, multi-line, long, non-ASCII, words of another field.
/// (Not "NaN" or "inf": names are printed as they are, and the readers' tests look for those
/// words in every output.)
const HOSTILE_STR: [&str; 12] = [
    "",
    "../../escaped",
    "/abs/path",
    "a/b",
    "two\nlines",
    "mpm",
    "vm",
    "\u{e9}t\u{e9}",
    "\u{0}nul",
    "qr",
    "hamiltonian",
    "discrete",
];

impl<'a> Choices<'a> {
    /// Bytes below this keep a field's valid value.
    pub const KEEP: u8 = 0xa0;

    pub fn new(data: &'a [u8]) -> Self {
        Self { data, at: 0 }
    }

    /// The next byte (0, "keep", once the input is used up).
    pub fn byte(&mut self) -> u8 {
        let b = self.data.get(self.at).copied().unwrap_or(0);
        self.at += 1;
        b
    }

    /// The next `n` bytes (zeros past the end).
    fn raw<const N: usize>(&mut self) -> [u8; N] {
        let mut out = [0u8; N];
        for b in &mut out {
            *b = self.byte();
        }
        out
    }

    /// A small number below `n` (for counts of things the file holds).
    pub fn below(&mut self, n: u64) -> u64 {
        u64::from(self.byte()) % n.max(1)
    }

    /// `valid`, or a hostile value.
    pub fn f64(&mut self, valid: f64) -> f64 {
        let b = self.byte();
        if b < Self::KEEP {
            return valid;
        }
        match b - Self::KEEP {
            // Raw bits: any double at all.
            0 => f64::from_bits(u64::from_le_bytes(self.raw())),
            1 => -valid,
            2 => valid * (1.0 + f64::EPSILON),
            3 => valid * 1e300,
            4 => valid * 1e-300,
            i => HOSTILE_F64[usize::from(i) % HOSTILE_F64.len()],
        }
    }

    /// `valid`, or a hostile count.
    pub fn u64(&mut self, valid: u64) -> u64 {
        let b = self.byte();
        if b < Self::KEEP {
            return valid;
        }
        match b - Self::KEEP {
            0 => u64::from_le_bytes(self.raw()),
            1 => valid.wrapping_add(1),
            2 => valid.wrapping_sub(1),
            3 => valid.wrapping_mul(2),
            4 => valid.wrapping_mul(1000),
            i => HOSTILE_U64[usize::from(i) % HOSTILE_U64.len()],
        }
    }

    /// `valid`, or a hostile 32-bit count (the low bits of a hostile 64-bit one).
    pub fn u32(&mut self, valid: u32) -> u32 {
        // Truncated: u32::MAX, 2^31 and small values stay what they are.
        self.u64(u64::from(valid)) as u32
    }

    /// A length for a vector whose valid length is `valid`: kept, or another small one (files
    /// stay small: at most a few thousand values).
    pub fn len(&mut self, valid: usize) -> usize {
        let b = self.byte();
        if b < Self::KEEP {
            return valid;
        }
        [0, 1, valid + 1, valid.saturating_sub(1), 2 * valid, 4096][usize::from(b) % 6]
    }

    /// `valid`, or a hostile string.
    pub fn string(&mut self, valid: &str) -> String {
        let b = self.byte();
        if b < Self::KEEP {
            return valid.to_string();
        }
        match b - Self::KEEP {
            0 => "x".repeat(100_000),
            1 => format!("{valid}{valid}"),
            i => HOSTILE_STR[usize::from(i) % HOSTILE_STR.len()].to_string(),
        }
    }
}

/// The configuration of the runs the recordings claim to be (Henon-Heiles, 100 steps, VM and
/// MPM, k = 3, two sets): small enough that `replay` of any of them takes milliseconds.
pub const RUN_CONFIG: &str = r#"[run]
name = "hostile"

[model]
name = "henon-heiles"

[orbit]
q = [0.0, -0.25]
p = [0.0, 0.0]
energy = 0.125
solve_for = "p1"

[integrator]
method = "aba864"
h = 0.01
t_final = 1.0

[deviations]
k = 3
sets = 2
seed = 1

[[scheme]]
name = "vm"
method = "vm"
d0 = 1e-8
tau = 0.1
orthonormalize = "qr"

[[scheme]]
name = "mpm"
method = "mpm"
d0 = 1e-8
tau = 0.1
orthonormalize = "rescale"
"#;

/// A recording (`chaoscope record`'s layout) of the run [`RUN_CONFIG`] describes, with its
/// values chosen by `choices`: the header's every field, each sample's reference state and
/// separation sets, messages left out or repeated, and the end of the run.
pub fn recording(choices: &mut Choices) -> Vec<u8> {
    let (dim, k, sets, h, tau_steps) = (4u32, 3u32, 2u32, 0.01, 10u64);
    let methods = [("vm", "vm", "qr"), ("mpm", "mpm", "rescale")];
    let scheme_count = match choices.byte() {
        b if b < Choices::KEEP => 2,
        b => usize::from(b % 5),
    };
    let schemes: Vec<Scheme> = (0..scheme_count)
        .map(|i| {
            let (name, method, ortho) = methods[i % 2];
            Scheme {
                index: choices.u32(i as u32),
                name: choices.string(&if i < 2 {
                    name.to_string()
                } else {
                    format!("{name}{i}")
                }),
                method: choices.string(method),
                d0: choices.f64(1e-8),
                tau: choices.f64(0.1),
                tau_steps: choices.u64(tau_steps),
                orthonormalize: choices.string(ortho),
            }
        })
        .collect();
    let header = RunHeader {
        format_version: choices.u32(chaoscope_schemas::FORMAT_VERSION),
        run_name: choices.string("hostile"),
        config_toml: choices.string(RUN_CONFIG),
        model: choices.string("henon-heiles"),
        n: choices.u32(dim / 2),
        dim: choices.u32(dim),
        k: choices.u32(k),
        sets: choices.u32(sets),
        integrator: choices.string("aba864"),
        h: choices.f64(h),
        t_final: choices.f64(1.0),
        total_steps: choices.u64(100),
        energy0: choices.f64(0.125),
        x0: (0..choices.len(dim as usize))
            .map(|_| choices.f64(0.1))
            .collect(),
        schemes,
        seed: choices.u64(1),
        producer_version: choices.string("0.1.0"),
        kind: choices.string("hamiltonian"),
        time: choices.string("continuous"),
        lattice_side: choices.u32(0),
    };
    let options = FileOptions {
        compression: [Compression::Zstd, Compression::None, Compression::Lz4]
            [choices.below(3) as usize],
        chunk_size: 1 << (8 + choices.below(8)),
    };
    let mut recording =
        Recording::start(Cursor::new(Vec::new()), &header, &options).expect("writing to memory");
    let mut noise = Noise::new(u64::from(choices.byte()));
    let mut frame = 0u64;
    // A message the writer cannot place (a separation set of a scheme the header does not
    // have: there is no channel for it) is left out; the file stays valid.
    let put = |recording: &mut Recording<_>, m: DataMessage| {
        let _ = recording.on_message(&m);
    };
    let samples = 1 + choices.below(12);
    for seq in 0..samples {
        let step = seq * tau_steps;
        // What the message is: kept (most bytes), left out, or sent twice.
        let presence = |choices: &mut Choices| match choices.byte() {
            0xfe => 0,
            0xff => 2,
            _ => 1,
        };
        for _ in 0..presence(choices) {
            let state = (0..choices.len(dim as usize))
                .map(|_| choices.f64(noise.next_f64(0.5)))
                .collect();
            put(
                &mut recording,
                DataMessage::Reference(ReferenceState {
                    frame: choices.u64(frame),
                    seq: choices.u64(seq),
                    step: choices.u64(step),
                    t: choices.f64(step as f64 * h),
                    energy: choices.f64(0.125 + noise.next_f64(1e-12)),
                    state,
                    mean_divergence: choices.f64(0.0),
                    divergence_sum: 0.0,
                }),
            );
            frame += 1;
        }
        for scheme in 0..2u32 {
            for set in 0..sets {
                for _ in 0..presence(choices) {
                    let len = choices.len((k * dim) as usize);
                    let separations = (0..len)
                        .map(|_| choices.f64(noise.next_f64(1e-8)))
                        .collect();
                    let len = choices.len(k as usize);
                    let stretch = (0..len)
                        .map(|_| {
                            choices.f64(if seq == 0 {
                                1.0
                            } else {
                                1.0 + noise.next_f64(0.5)
                            })
                        })
                        .collect();
                    put(
                        &mut recording,
                        DataMessage::Separations(SeparationSet {
                            frame: choices.u64(frame),
                            seq: choices.u64(seq),
                            step: choices.u64(step),
                            t: choices.f64(step as f64 * h),
                            scheme: choices.u32(scheme),
                            set: choices.u32(set),
                            k: choices.u32(k),
                            dim: choices.u32(dim),
                            separations,
                            stretch,
                            earlier_stretch: Vec::new(),
                        }),
                    );
                    frame += 1;
                }
            }
        }
    }
    let last = (samples - 1) * tau_steps;
    let status = match choices.byte() {
        b if b < Choices::KEEP => end_of_run::Status::Completed as i32,
        b => i32::from(b % 5),
    };
    put(
        &mut recording,
        DataMessage::End(EndOfRun {
            frame: choices.u64(frame),
            status,
            reason: choices.string(""),
            samples: choices.u64(samples),
            last_step: choices.u64(last),
            t: choices.f64(last as f64 * h),
        }),
    );
    recording
        .finish(FinalizedBy::EndOfRun)
        .expect("writing to memory")
        .0
        .into_inner()
}

/// The configuration of the maps the map files claim to be.
pub const MAP_CONFIG: &str = r#"[model]
name = "henon-heiles"

[orbit]
q = [0.0, 0.0]
p = [0.0, 0.0]
energy = 0.125
solve_for = "p1"

[integrator]
method = "aba864"
h = 0.01
t_final = 1.0

[deviations]
k = 2
sets = 2
seed = 1

[[scheme]]
name = "mpm"
method = "mpm"
d0 = 1e-8
tau = 0.1

[map]
indicator = "gali"
x = { coord = "q2", min = -0.4, max = 0.6, n = 6 }
y = { coord = "p2", min = -0.4, max = 0.4, n = 5 }
"#;

/// A map file (`chaoscope map`'s layout) of shard `shard` of `shards` of the map
/// [`MAP_CONFIG`] describes (6 x 5 points), with its values chosen by `choices`: the header's
/// every field (axes, sizes, shard, indicator, times) and each point's.
pub fn map(choices: &mut Choices, shard: u32, shards: u32) -> Vec<u8> {
    let (nx, ny, sets) = (6u32, 5u32, 2u32);
    let axis = |choices: &mut Choices, coord: &str, min: f64, max: f64, n: u32| MapAxis {
        coord: choices.string(coord),
        param: String::new(),
        min: choices.f64(min),
        max: choices.f64(max),
        n: choices.u32(n),
    };
    let indicators = ["gali", "sali", "gali-time", "mle"];
    let mut indicator = indicators[choices.below(4) as usize];
    // A spectrum map is an MLE map with every exponent: half of the MLE maps (a byte more only
    // for MLE maps, so the inputs of the other indicators keep their meaning).
    if indicator == "mle" && choices.byte() < Choices::KEEP / 2 {
        indicator = "spectrum";
    }
    let header = MapHeader {
        format_version: choices.u32(chaoscope_schemas::FORMAT_VERSION),
        config_toml: choices.string(MAP_CONFIG),
        model: choices.string("henon-heiles"),
        indicator: choices.string(indicator),
        k: choices.u32(2),
        threshold: choices.f64(if indicator == "gali-time" { 1e-8 } else { 0.0 }),
        method: choices.string("mpm"),
        x: (choices.byte() != 0xff).then(|| axis(choices, "q2", -0.4, 0.6, nx)),
        y: (choices.byte() != 0xff).then(|| axis(choices, "p2", -0.4, 0.4, ny)),
        sets: choices.u32(sets),
        t_final: choices.f64(1.0),
        shard_index: choices.u32(shard),
        shard_count: choices.u32(shards),
        grid_points: choices.u64(u64::from(nx * ny)),
        producer_version: choices.string("0.1.0"),
    };
    let options = FileOptions {
        compression: [Compression::Zstd, Compression::None][choices.below(2) as usize],
        chunk_size: 1 << 20,
    };
    let mut file =
        MapFile::create(Cursor::new(Vec::new()), &header, &options).expect("writing to memory");
    let mut noise = Noise::new(u64::from(choices.byte()));
    for index in (0..u64::from(nx * ny)).filter(|i| i % u64::from(shards) == u64::from(shard)) {
        if choices.byte() == 0xfe {
            continue; // not computed
        }
        let (ix, iy) = (
            (index % u64::from(nx)) as u32,
            (index / u64::from(nx)) as u32,
        );
        let x = -0.4 + f64::from(ix) * 0.2;
        let y = -0.4 + f64::from(iy) * 0.2;
        let status = match choices.byte() {
            b if b < 0x80 => map_point::Status::Ok as i32,
            b if b < 0x90 => map_point::Status::Escaped as i32,
            b if b < Choices::KEEP => map_point::Status::OutsideEnergySurface as i32,
            b => i32::from(b % 6) - 1,
        };
        let ok = status == map_point::Status::Ok as i32;
        let value = if ok {
            match indicator {
                "mle" | "spectrum" => noise.next_f64(1.0).abs(),
                "gali-time" => noise.next_f64(1.0).abs(),
                _ => 10f64.powf(-8.0 * noise.next_f64(1.0).abs()),
            }
        } else {
            f64::NAN
        };
        let per_set = (0..choices.len(if ok { sets as usize } else { 0 }))
            .map(|_| choices.f64(value.log10()))
            .collect();
        let point = MapPoint {
            index: choices.u64(index),
            ix: choices.u32(ix),
            iy: choices.u32(iy),
            x: choices.f64(x),
            y: choices.f64(y),
            status,
            value: choices.f64(value),
            per_set,
            mean_log10: choices.f64(if ok { value.log10() } else { 0.0 }),
            t_end: choices.f64(1.0),
            orbit_steps: choices.u64(300),
            reason: choices.string(if ok { "" } else { "escaped" }),
            x0: (0..choices.len(4)).map(|_| choices.f64(0.1)).collect(),
            spectrum: if indicator == "spectrum" {
                (0..choices.len(if ok { 2 } else { 0 }))
                    .map(|j| choices.f64(if j == 0 { value } else { -value }))
                    .collect()
            } else {
                Vec::new()
            },
        };
        file.write_point(&point).expect("writing to memory");
        if choices.byte() == 0xff {
            file.close_chunk().expect("writing to memory");
        }
    }
    file.finish().expect("writing to memory").into_inner()
}

/// `count` recordings of seeded hostile values, one in four of them with only a few values
/// changed (so most of the file is read before a value is met).
pub fn recordings(count: usize, seed: u64) -> impl Iterator<Item = super::Damaged> {
    seeded(count, seed).map(move |(case, bytes)| super::Damaged {
        what: format!("hostile values, recording case {case} (seed {seed})"),
        bytes: recording(&mut Choices::new(&bytes)),
    })
}

/// `count` whole maps (one shard) of seeded hostile values.
pub fn maps(count: usize, seed: u64) -> impl Iterator<Item = super::Damaged> {
    seeded(count, seed).map(move |(case, bytes)| super::Damaged {
        what: format!("hostile values, map case {case} (seed {seed})"),
        bytes: map(&mut Choices::new(&bytes), 0, 1),
    })
}

/// Choice streams from seeded noise: mostly kept values with a few hostile ones.
fn seeded(count: usize, seed: u64) -> impl Iterator<Item = (usize, Vec<u8>)> {
    let mut noise = Noise::new(seed);
    (0..count).map(move |case| {
        // About one field in `rarity` hostile.
        let rarity = [4, 16, 64, 256][case % 4];
        let bytes = (0..2048)
            .map(|_| {
                let b = (noise.next_u64() >> 56) as u8;
                if noise.next_u64().is_multiple_of(rarity) {
                    b | Choices::KEEP
                } else {
                    b % Choices::KEEP
                }
            })
            .collect();
        (case, bytes)
    })
}

/// Recordings of a small run (dim 4, k = 3, two schemes of two sets, 12 samples) each holding
/// one hostile value of the kinds met in the wild, with what it is: stretching factors of NaN,
/// zero and infinity, non-finite separations, states of the wrong length, set indices beyond
/// the header's, times that are not those of their steps, steps that go back, header values
/// (d0, tau, t_final, sets) no producer writes, and rates beyond the range of f64.
pub fn crafted_recordings() -> Vec<(String, Vec<u8>)> {
    // (what, header edit, message edit applied to every message)
    type HeaderEdit = fn(&mut RunHeader);
    type MessageEdit = fn(&mut DataMessage);
    fn none(_: &mut RunHeader) {}
    fn keep(_: &mut DataMessage) {}
    // The first separation set of sample 3 (scheme 0, set 0).
    fn target(m: &mut DataMessage) -> Option<&mut SeparationSet> {
        match m {
            DataMessage::Separations(s) if s.seq == 3 && s.scheme == 0 && s.set == 0 => Some(s),
            _ => None,
        }
    }
    fn reference(m: &mut DataMessage) -> Option<&mut ReferenceState> {
        match m {
            DataMessage::Reference(r) if r.seq == 5 => Some(r),
            _ => None,
        }
    }
    let cases: [(&str, HeaderEdit, MessageEdit); 16] = [
        ("stretch factor NaN", none, |m| {
            if let Some(s) = target(m) {
                s.stretch[0] = f64::NAN;
            }
        }),
        ("stretch factor 0", none, |m| {
            if let Some(s) = target(m) {
                s.stretch[1] = 0.0;
            }
        }),
        ("stretch factor infinite", none, |m| {
            if let Some(s) = target(m) {
                s.stretch[2] = f64::INFINITY;
            }
        }),
        ("stretch factor negative", none, |m| {
            if let Some(s) = target(m) {
                s.stretch[0] = -2.0;
            }
        }),
        ("separation NaN", none, |m| {
            if let Some(s) = target(m) {
                s.separations[5] = f64::NAN;
            }
        }),
        ("separations of another k", none, |m| {
            if let Some(s) = target(m) {
                s.k = 2;
                s.separations.truncate(8);
                s.stretch.truncate(2);
            }
        }),
        ("state of 3 values", none, |m| {
            if let Some(r) = reference(m) {
                r.state.truncate(3);
            }
        }),
        ("set index beyond the sets", none, |m| {
            if let Some(s) = target(m) {
                s.set = 1_000_000;
            }
        }),
        ("time 1e308", none, |m| {
            if let Some(r) = reference(m) {
                r.t = 1e308;
            }
        }),
        ("step that goes back", none, |m| {
            if let Some(r) = reference(m) {
                r.step = 10;
                r.t = 0.1;
            }
        }),
        ("header d0 NaN", |h| h.schemes[1].d0 = f64::NAN, keep),
        (
            "header tau infinite",
            |h| h.schemes[0].tau = f64::INFINITY,
            keep,
        ),
        ("header t_final -1e308", |h| h.t_final = -1e308, keep),
        ("header of a million sets", |h| h.sets = 1_000_000, keep),
        (
            "header x0 infinite",
            |h| h.x0 = vec![f64::INFINITY; 4],
            keep,
        ),
        // Valid, at the edge: the largest stretching factors over the smallest step. Every
        // rate exceeds f64 (reported as +-f64::MAX); nothing may be infinite or NaN.
        (
            "rates beyond f64",
            |h| h.h = 5e-324,
            |m| match m {
                DataMessage::Reference(r) => r.t = r.step as f64 * 5e-324,
                DataMessage::Separations(s) => {
                    s.t = s.step as f64 * 5e-324;
                    if s.seq > 0 {
                        s.stretch.fill(1e308);
                    }
                }
                DataMessage::End(e) => e.t = e.last_step as f64 * 5e-324,
            },
        ),
    ];
    cases
        .into_iter()
        .map(|(what, header_edit, message_edit)| {
            (what.to_string(), crafted(header_edit, message_edit))
        })
        .collect()
}

/// The run of [`crafted_recordings`] with `header_edit` and `message_edit` applied.
fn crafted(header_edit: fn(&mut RunHeader), message_edit: fn(&mut DataMessage)) -> Vec<u8> {
    let (dim, k, sets, tau_steps, h) = (4u32, 3u32, 2u32, 10u64, 0.01);
    let mut header = RunHeader {
        format_version: chaoscope_schemas::FORMAT_VERSION,
        run_name: "crafted".into(),
        config_toml: RUN_CONFIG.into(),
        model: "henon-heiles".into(),
        n: 2,
        dim,
        k,
        sets,
        integrator: "aba864".into(),
        h,
        t_final: 1.1,
        total_steps: 110,
        energy0: 0.125,
        x0: vec![0.1, -0.25, 0.3, 0.0],
        schemes: vec![
            Scheme {
                index: 0,
                name: "vm".into(),
                method: "vm".into(),
                d0: 1e-8,
                tau: 0.1,
                tau_steps,
                orthonormalize: "qr".into(),
            },
            Scheme {
                index: 1,
                name: "mpm".into(),
                method: "mpm".into(),
                d0: 1e-8,
                tau: 0.1,
                tau_steps,
                orthonormalize: "rescale".into(),
            },
        ],
        seed: 1,
        producer_version: "0.1.0".into(),
        kind: "hamiltonian".into(),
        time: "continuous".into(),
        lattice_side: 0,
    };
    header_edit(&mut header);
    let mut noise = Noise::new(5);
    let mut messages = Vec::new();
    let mut frame = 0;
    for seq in 0..12u64 {
        let step = seq * tau_steps;
        let t = step as f64 * h;
        messages.push(DataMessage::Reference(ReferenceState {
            frame,
            seq,
            step,
            t,
            energy: 0.125 + noise.next_f64(1e-12),
            state: (0..dim).map(|_| noise.next_f64(0.5)).collect(),
            mean_divergence: 0.0,
            divergence_sum: 0.0,
        }));
        frame += 1;
        for scheme in 0..2 {
            for set in 0..sets {
                // Vectors that contract or stretch a little each window, as an orbit's do.
                messages.push(DataMessage::Separations(SeparationSet {
                    frame,
                    seq,
                    step,
                    t,
                    scheme,
                    set,
                    k,
                    dim,
                    separations: (0..k * dim).map(|_| noise.next_f64(1e-8)).collect(),
                    stretch: (0..k)
                        .map(|i| {
                            if seq == 0 {
                                1.0
                            } else {
                                1.0 + 0.3 / f64::from(i + 1) + noise.next_f64(0.01)
                            }
                        })
                        .collect(),
                    earlier_stretch: Vec::new(),
                }));
                frame += 1;
            }
        }
    }
    messages.push(DataMessage::End(EndOfRun {
        frame,
        status: end_of_run::Status::Completed as i32,
        samples: 12,
        last_step: 110,
        t: 1.1,
        ..Default::default()
    }));
    let mut recording = Recording::start(Cursor::new(Vec::new()), &header, &FileOptions::default())
        .expect("writing to memory");
    for mut m in messages {
        message_edit(&mut m);
        let _ = recording.on_message(&m);
    }
    recording
        .finish(FinalizedBy::EndOfRun)
        .expect("writing to memory")
        .0
        .into_inner()
}

/// Map files of a 6 x 5 map ([`MAP_CONFIG`]) each holding hostile values of the kinds met in
/// the wild, with what they are: a header claiming 10^7 points per axis (a 39 KB file that drove
/// `merge --png` to 3.3 GB), axes near +-1e308 or reversed or NaN, a grid count that disagrees
/// with the axes, an impossible shard, unknown indicators, and points whose index, grid
/// position, coordinates, status or values no map writes.
pub fn crafted_maps() -> Vec<(String, Vec<u8>)> {
    type Edit = fn(&mut MapHeader, &mut Vec<MapPoint>);
    let cases: [(&str, Edit); 14] = [
        ("x.n = 10^7", |h, _| h.x.as_mut().unwrap().n = 10_000_000),
        ("a 100000 x 100000 grid", |h, _| {
            h.x.as_mut().unwrap().n = 100_000;
            h.y.as_mut().unwrap().n = 100_000;
            h.grid_points = 10_000_000_000;
        }),
        ("axes near 1e308", |h, points| {
            let x = h.x.as_mut().unwrap();
            (x.min, x.max) = (-1.7e308, 1.7e308);
            for p in points {
                p.x = -1.7e308 + 6.8e307 * f64::from(p.ix);
            }
        }),
        ("axis of width beyond f64", |h, _| {
            let y = h.y.as_mut().unwrap();
            (y.min, y.max) = (-1e308, 1e308);
        }),
        ("axis reversed", |h, _| {
            let x = h.x.as_mut().unwrap();
            (x.min, x.max) = (0.6, -0.4);
        }),
        ("axis NaN", |h, _| h.y.as_mut().unwrap().max = f64::NAN),
        ("grid points disagree", |h, _| h.grid_points = 31),
        ("shard 3 of 2", |h, _| {
            (h.shard_index, h.shard_count) = (3, 2)
        }),
        ("unknown indicator", |h, _| h.indicator = "lyapunov".into()),
        ("t_final NaN", |h, _| h.t_final = f64::NAN),
        ("point off its grid position", |_, points| points[4].ix = 7),
        ("point at 1e308", |_, points| points[2].y = 1e308),
        ("integrated point with value NaN", |_, points| {
            points[3].value = f64::NAN
        }),
        ("point of status 9", |_, points| points[1].status = 9),
    ];
    cases
        .into_iter()
        .map(|(what, edit)| {
            let (mut header, mut points) = valid_map();
            edit(&mut header, &mut points);
            let mut file =
                MapFile::create(Cursor::new(Vec::new()), &header, &FileOptions::default())
                    .expect("writing to memory");
            for p in &points {
                file.write_point(p).expect("writing to memory");
            }
            let bytes = file.finish().expect("writing to memory").into_inner();
            (what.to_string(), bytes)
        })
        .collect()
}

/// The whole map of [`MAP_CONFIG`] (6 x 5 points, GALI_2 of two sets) as `chaoscope map`
/// writes it: header and points.
pub fn valid_map() -> (MapHeader, Vec<MapPoint>) {
    let (nx, ny, sets) = (6u32, 5u32, 2u32);
    let header = MapHeader {
        format_version: chaoscope_schemas::FORMAT_VERSION,
        config_toml: MAP_CONFIG.into(),
        model: "henon-heiles".into(),
        indicator: "gali".into(),
        k: 2,
        threshold: 0.0,
        method: "mpm".into(),
        x: Some(MapAxis {
            coord: "q2".into(),
            param: String::new(),
            min: -0.4,
            max: 0.6,
            n: nx,
        }),
        y: Some(MapAxis {
            coord: "p2".into(),
            param: String::new(),
            min: -0.4,
            max: 0.4,
            n: ny,
        }),
        sets,
        t_final: 1.0,
        shard_index: 0,
        shard_count: 1,
        grid_points: u64::from(nx * ny),
        producer_version: "0.1.0".into(),
    };
    let mut noise = Noise::new(9);
    let points = (0..u64::from(nx * ny))
        .map(|index| {
            let (ix, iy) = (
                (index % u64::from(nx)) as u32,
                (index / u64::from(nx)) as u32,
            );
            let per_set: Vec<f64> = (0..sets)
                .map(|_| -8.0 * noise.next_f64(1.0).abs())
                .collect();
            MapPoint {
                index,
                ix,
                iy,
                x: -0.4 + 1.0 * f64::from(ix) / 5.0,
                y: -0.4 + 0.8 * f64::from(iy) / 4.0,
                status: map_point::Status::Ok as i32,
                value: per_set.iter().map(|g| 10f64.powf(*g)).sum::<f64>() / 2.0,
                mean_log10: per_set.iter().sum::<f64>() / 2.0,
                per_set,
                t_end: 1.0,
                orbit_steps: 300,
                reason: String::new(),
                x0: vec![0.0, -0.4 + f64::from(ix) * 0.2, 0.3, 0.0],
                spectrum: Vec::new(),
            }
        })
        .collect();
    (header, points)
}
