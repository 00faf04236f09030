//! The splitting step kernels of [`super::step`] written as C and compiled by the system C
//! compiler: the same loops and the same operations in the same order, over vectors as wide as
//! the host has (`-march=native`: four `f64` lanes with AVX2, where Cranelift's x86-64 back end
//! has two).
//!
//! Why a second code generator: the step kernels are throughput-bound on packed floating-point
//! work (the profile of Henon-Heiles and FPUT chains shows the packed multiplies and adds of the
//! force and the drift and kick, not calls, spills or address arithmetic), and at two lanes per
//! instruction they ran 1.6-2.6x behind the built-in models' AVX2 kernels. The same graph as
//! C, each value two 4-lane vectors (two AVX2 registers, two independent chains), closes most
//! of that (the figures: docs/src/performance.md, "Expressions against the built-in models").
//!
//! What keeps the bits those of [`crate::eval`]:
//! - every value is a GCC vector (`vector_size`), whose `+ - * /` are the IEEE operations lane
//!   by lane; the compiler is run with `-ffp-contract=off` (no fused multiply-add; GNU C
//!   contracts by default) and without any fast-math flag (no reassociation, NaN and signed
//!   zeros kept); `-fno-math-errno` only lets `sqrt` be the bare instruction;
//! - constants are written as their bit patterns, so no decimal round trip;
//! - `max`, `min`, `step`, `sign`, `if` are compares and bit selects with the scalar
//!   definitions' NaN and signed-zero behaviour (as the Cranelift lane code);
//! - transcendental functions, `powf`, `atan2` and tables are calls, lane by lane, through a
//!   table of pointers the caller passes in (`env`), to the very Rust callbacks the Cranelift
//!   code calls (`Graph::apply_*`), not to the C library's own functions;
//! - whole powers are left-to-right products, kicks `p - dh * f`, drifts `q + c * p`, as the
//!   generic step loops.
//!
//! The source holds only numbers and identifiers of this module (no user text), so its content
//! hash names the compiled library in a cache directory; a later run with the same kernel, the
//! same compiler and the same CPU features loads it without compiling. The compiler, its flags,
//! its version and the CPU features it targets (`-march=native`'s predefined macros) are part of
//! the hash, so a cache shared by machines with different CPUs never hands one the other's code.
//! Asking the compiler for its macros is a process of its own (about 20 MB), so the answer is
//! remembered in the cache under a fingerprint of the compiler's file and the CPU ([`identity`]):
//! a load from the cache runs no compiler.
//!
//! Loading a library runs its code (its constructors run at `dlopen`), so the cache is trusted
//! only as far as it is provably the user's own ([`CacheDir`]): the directory must be a real
//! directory (not a link) owned by the user and writable by nobody else, checked at every use
//! through one open handle of it; the fallback without `HOME` is a per-user directory
//! (`chaoscope-kernels-<uid>`), never a shared one. Beside each library the build writes the
//! SHA-256 of its bytes (`steps-<hash>.sha256`, renamed into place like the library); a
//! cached library is read whole, checked against that digest, and loaded from the bytes that
//! were checked (a memory file on Linux), so a library swapped in after the check cannot be
//! the one that runs. Anything else is rebuilt, or refused with one line (the caller then runs
//! the Cranelift kernels).
//!
//! The compiler is an optimization, never a requirement: every compiler process (the build,
//! the target query) runs through [`run_compiler`], in a process group of its own that dies
//! with its parent, stopped at a cancel, at SIGINT/SIGTERM of this process, or at its deadline
//! (`CHAOSCOPE_CC_TIMEOUT`, [`DEFAULT_CC_TIMEOUT`]); a lookup that only loads runs none. Cache
//! entries are opened without blocking and only as regular files (a FIFO planted there is
//! refused in one line). A compiler that hangs, crashes or lies thus costs at most its deadline
//! and one line, and the caller runs the Cranelift kernels, which give the same bits.
//!
//! I/O: this module runs the C compiler and reads and writes its cache directory; it is the
//! second exception (after `table`) to the crate's no-I/O rule, and only the batched kernel's
//! lazy construction calls it.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::process::{Command, ExitStatus, Stdio};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, OnceLock};
use std::time::{Duration, Instant};

use sha2::{Digest, Sha256};

use super::{JitError, Layout, Plan, cb_atan2, cb_pow, cb_table, is_leaf};
use super::{outputs_by_node, unary_callback};
use crate::graph::{Binary, Cmp, Graph, Node, NodeId, Tabulated, Unary};

use super::step_spec::{StepSpec, kernel_plan};

/// Lanes per block of the C kernels: one value is two 4-lane vectors (two AVX2 registers, or
/// four SSE2 ones), two independent dependency chains per operation. The batched kernel's chunks (8 or 32 lanes on
/// AVX2) are whole blocks.
pub const C_BLOCK_LANES: usize = 8;

/// The orbit kernel's C signature: [`super::OrbitStepsFnPtr`] plus the callback table.
pub(super) type COrbitFn = unsafe extern "C" fn(
    x: *mut f64,
    stride: usize,
    lanes: usize,
    n_steps: u64,
    drift: *const f64,
    kick: *const f64,
    n_kicks: usize,
    inverse_masses: *const f64,
    scratch: *mut f64,
    env: *const usize,
);

/// The tangent kernel's C signature: [`super::TangentStepsFnPtr`] plus the callback table.
pub(super) type CTangentFn = unsafe extern "C" fn(
    stages: *const f64,
    v: *mut f64,
    stride: usize,
    lanes: usize,
    n_steps: u64,
    drift: *const f64,
    kick: *const f64,
    n_kicks: usize,
    inverse_masses: *const f64,
    scratch: *mut f64,
    env: *const usize,
);

/// The fused one-orbit kernel's C signature ([`super::c_fused`]): the orbit `x` (`2N`), `k`
/// tangent vectors `v` (`k` times `2N`), the splitting's coefficients, the inverse masses
/// (null: unit masses) and the callback table.
pub(super) type CFusedFn = unsafe extern "C" fn(
    x: *mut f64,
    v: *mut f64,
    k: usize,
    n_steps: u64,
    drift: *const f64,
    kick: *const f64,
    n_kicks: usize,
    inverse_masses: *const f64,
    env: *const usize,
);

/// Unary operations called back, in the order of their `env` slots.
const UNARY_CALLED: [Unary; 9] = [
    Unary::Exp,
    Unary::Log,
    Unary::Sin,
    Unary::Cos,
    Unary::Tan,
    Unary::Atan,
    Unary::Tanh,
    Unary::Cosh,
    Unary::Sinh,
];
const ENV_POW: usize = UNARY_CALLED.len();
const ENV_ATAN2: usize = ENV_POW + 1;
const ENV_TABLE: usize = ENV_ATAN2 + 1;
/// `env[ENV_TABLES + t]` is table `t` (a `*const Arc<dyn Tabulated>`); after the tables, the
/// array parameters' values (a `*const f64` each) the lattice loops read.
pub(super) const ENV_TABLES: usize = ENV_TABLE + 1;

/// The callback table the kernels read: the Rust callbacks, then the table pointers (into
/// `tables`, which must outlive every call), then the arrays' (which must too).
pub(super) fn env(tables: &[Arc<dyn Tabulated>], arrays: &[Arc<[f64]>]) -> Box<[usize]> {
    let mut env: Vec<usize> = UNARY_CALLED
        .iter()
        .map(|&op| unary_callback(op).expect("a called-back unary operation"))
        .collect();
    env.push(cb_pow as *const () as usize);
    env.push(cb_atan2 as *const () as usize);
    env.push(cb_table as *const () as usize);
    for t in tables {
        env.push(t as *const Arc<dyn Tabulated> as usize);
    }
    for a in arrays {
        env.push(a.as_ptr() as usize);
    }
    env.into_boxed_slice()
}

/// Which C compiler builds the kernels, and where their cache lives.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct CCompiler {
    /// The compiler program (`cc`, `gcc`, `clang`, or a path).
    pub program: PathBuf,
    /// Where compiled kernels are kept by content hash.
    pub cache_dir: PathBuf,
}

/// The compiler's flags (part of the cache key). `-O2`: the body is straight-line code, which
/// `-O3` does not improve; `-march=native`: the host's vector width; `-ffp-contract=off`: no
/// fused multiply-add; `-fno-math-errno`: `sqrt` without the `errno` branch (same result).
const FLAGS: [&str; 8] = [
    "-O2",
    "-march=native",
    "-ffp-contract=off",
    "-fno-math-errno",
    "-fno-strict-aliasing",
    "-fPIC",
    "-shared",
    "-w",
];

impl CCompiler {
    /// From the environment: `CHAOSCOPE_CC` names the compiler (`none` or empty: no C
    /// kernels, Cranelift's are used), else `cc`; `CHAOSCOPE_KERNEL_CACHE` the cache directory,
    /// else `$XDG_CACHE_HOME/chaoscope/kernels`, `$HOME/.cache/chaoscope/kernels`, or
    /// `chaoscope-kernels-<uid>` in the temporary directory (one per user: a directory
    /// another user could create first is refused by [`CacheDir::open`], never shared). `None`
    /// when C kernels are switched off.
    pub fn from_env() -> Option<CCompiler> {
        let program = match std::env::var_os("CHAOSCOPE_CC") {
            Some(p) if p.is_empty() || p == "none" => return None,
            Some(p) => PathBuf::from(p),
            None => PathBuf::from("cc"),
        };
        let cache_dir = if let Some(d) = std::env::var_os("CHAOSCOPE_KERNEL_CACHE") {
            PathBuf::from(d)
        } else if let Some(d) = std::env::var_os("XDG_CACHE_HOME").filter(|d| !d.is_empty()) {
            PathBuf::from(d).join("chaoscope").join("kernels")
        } else if let Some(d) = std::env::var_os("HOME").filter(|d| !d.is_empty()) {
            PathBuf::from(d)
                .join(".cache")
                .join("chaoscope")
                .join("kernels")
        } else {
            // SAFETY: geteuid(2) cannot fail.
            let uid = unsafe { libc::geteuid() };
            std::env::temp_dir().join(format!("chaoscope-kernels-{uid}"))
        };
        Some(CCompiler { program, cache_dir })
    }

    /// What the compiler and these flags target: its predefined macros (version, ISA
    /// features of `-march=native`), hashed into every cache key. Runs the compiler once
    /// ([`run_compiler`]: a deadline, a cancel), its answer written to a file of the build
    /// directory `work` (a pipe left unread would stall a compiler with much to say).
    fn target_identity(&self, work: &WorkDir, cancel: &AtomicBool) -> Result<String, JitError> {
        let macros_path = work.0.join("macros");
        let log_path = work.0.join("target-messages");
        let create = |p: &Path| {
            std::fs::File::create(p)
                .map_err(|e| JitError::CCompiler(format!("cannot write {}: {e}", p.display())))
        };
        let mut command = Command::new(&self.program);
        command
            .args(["-march=native", "-ffp-contract=off", "-E", "-dM", "-x", "c"])
            .arg("/dev/null")
            .stdin(Stdio::null())
            .stdout(create(&macros_path)?)
            .stderr(create(&log_path)?);
        let status = run_compiler(self, &mut command, cancel, "reporting its target")?;
        if !status.success() {
            return Err(JitError::CCompiler(format!(
                "the C compiler '{}' failed to report its target ({status}): {}",
                self.program.display(),
                first_lines(&read_regular(&log_path).unwrap_or_default())
            )));
        }
        let out = read_regular(&macros_path).map_err(|e| {
            JitError::CCompiler(format!(
                "the C compiler '{}' reported its target in {}: {e}",
                self.program.display(),
                macros_path.display()
            ))
        })?;
        let mut macros: Vec<&str> = std::str::from_utf8(&out)
            .unwrap_or_default()
            .lines()
            .collect();
        macros.sort_unstable();
        Ok(digest_hex(macros.join("\n").as_bytes()))
    }

    /// What [`Self::target_identity`] depends on, where it can be read without running the
    /// compiler: the compiler's file as the `PATH` search finds it (its real path, device,
    /// inode, size and change times: a new version or another program is another file), the
    /// variables that change which compiler passes it runs, and the CPU (`-march=native` is
    /// derived from the CPU identification instructions alone, so the same answers give the
    /// same macros). `None` where any of it cannot be read (a compiler not found: running it
    /// says why) or on a CPU other than x86-64, where the compiler is always asked.
    fn target_fingerprint(&self) -> Option<String> {
        use std::os::unix::fs::MetadataExt;
        let cpu = cpu_identity()?;
        let found = if self.program.components().count() > 1 {
            self.program.clone()
        } else {
            let path = std::env::var_os("PATH")?;
            std::env::split_paths(&path)
                .map(|dir| dir.join(&self.program))
                .find(|p| {
                    std::fs::metadata(p).is_ok_and(|m| m.is_file() && m.mode() & 0o111 != 0)
                })?
        };
        let real = std::fs::canonicalize(&found).ok()?;
        let m = std::fs::metadata(&real).ok()?;
        let mut f = format!(
            "{}\n{}\n{} {} {} {}.{} {}.{}\n{cpu}",
            found.display(),
            real.display(),
            m.dev(),
            m.ino(),
            m.size(),
            m.mtime(),
            m.mtime_nsec(),
            m.ctime(),
            m.ctime_nsec()
        );
        for var in [
            "GCC_EXEC_PREFIX",
            "COMPILER_PATH",
            "CPATH",
            "C_INCLUDE_PATH",
        ] {
            if let Some(v) = std::env::var_os(var) {
                f.push_str(&format!("\n{var}={}", v.to_string_lossy()));
            }
        }
        Some(f)
    }
}

/// The answers of the CPU identification instruction that `-march=native` reads (vendor,
/// family and model, feature leaves, brand string), without the per-core fields (APIC
/// identifiers, topology, hybrid core types), and which wide registers the operating system
/// enables: equal on every core of one machine and on machines of one CPU model.
#[cfg(target_arch = "x86_64")]
fn cpu_identity() -> Option<String> {
    use std::arch::x86_64::__cpuid_count;
    // CPUID exists on every x86-64 CPU and only reads (safe to call since Rust 1.87).
    let max = __cpuid_count(0, 0).eax;
    let max_ext = __cpuid_count(0x8000_0000, 0).eax;
    let mut id = String::new();
    let leaves = [
        (0, 0),
        (1, 0),
        (7, 0),
        (7, 1),
        (0xd, 0),
        (0xd, 1),
        (0x14, 0),
        (0x19, 0),
        (0x24, 0),
    ];
    for (leaf, sub) in leaves.into_iter().filter(|&(l, _)| l <= max) {
        let r = __cpuid_count(leaf, sub);
        // Leaf 1's EBX holds the core's APIC identifier in its top byte; leaf 0xd's EBX the
        // save area of the features this process has enabled.
        let ebx = match leaf {
            1 => r.ebx & 0x00ff_ffff,
            0xd => 0,
            _ => r.ebx,
        };
        id.push_str(&format!(
            "{leaf:x}.{sub}:{:x},{ebx:x},{:x},{:x};",
            r.eax, r.ecx, r.edx
        ));
    }
    for leaf in [
        0x8000_0001u32,
        0x8000_0002,
        0x8000_0003,
        0x8000_0004,
        0x8000_0008,
    ] {
        if leaf <= max_ext {
            let r = __cpuid_count(leaf, 0);
            id.push_str(&format!(
                "{leaf:x}:{:x},{:x},{:x},{:x};",
                r.eax, r.ebx, r.ecx, r.edx
            ));
        }
    }
    // The operating system's part: which register states it saves (AVX, AVX-512).
    for (name, on) in [
        ("avx", std::arch::is_x86_feature_detected!("avx")),
        ("avx512f", std::arch::is_x86_feature_detected!("avx512f")),
    ] {
        id.push_str(&format!("{name}={on};"));
    }
    Some(id)
}

#[cfg(not(target_arch = "x86_64"))]
fn cpu_identity() -> Option<String> {
    None
}

/// Whether [`build`] may compile or only load from the cache.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Mode {
    Build,
    /// Load a cached library or fail with [`JitError::NotCached`]; the cache is not created and
    /// no compiler runs.
    Load,
}

/// Prefix of the target records in the cache: `target-<hash of the fingerprint>` holds the
/// compiler's target identity for that fingerprint.
const TARGET_RECORD: &str = "target-";

/// The compiler's target identity ([`CCompiler::target_identity`]), asked once per process and
/// remembered in the cache under its fingerprint ([`CCompiler::target_fingerprint`]), so a
/// later run that loads its kernels from the cache runs no compiler at all (it would cost a
/// process of about 20 MB, more than a short chain's whole run). The record is read through
/// the checked cache handle like the libraries; a record that is missing, foreign or not a
/// digest is replaced by asking the compiler, one that is not a regular file refused.
///
/// In [`Mode::Load`] the compiler is never run: without a record the lookup is a miss
/// ([`JitError::NotCached`]; a library can only be in the cache if a build wrote the record
/// beside it), so a command that only loads never waits for a compiler.
fn identity(
    cc: &CCompiler,
    cache: &CacheDir,
    cancel: &AtomicBool,
    mode: Mode,
) -> Result<String, JitError> {
    static IDENTITY: OnceLock<std::sync::Mutex<Vec<(CCompiler, String)>>> = OnceLock::new();
    let known = IDENTITY.get_or_init(Default::default);
    if let Some(id) = known
        .lock()
        .ok()
        .and_then(|k| k.iter().find(|(c, _)| c == cc).map(|(_, id)| id.clone()))
    {
        return Ok(id);
    }
    let record = cc
        .target_fingerprint()
        .map(|f| format!("{TARGET_RECORD}{}", &digest_hex(f.as_bytes())[..40]));
    let remembered = match record.as_deref() {
        Some(name) => cache.read(name)?.and_then(|bytes| {
            let id = std::str::from_utf8(bytes.trim_ascii()).ok()?;
            (id.len() == 64 && id.bytes().all(|b| b.is_ascii_hexdigit())).then(|| id.to_string())
        }),
        None => None,
    };
    let id = match remembered {
        Some(id) => id,
        None if mode == Mode::Load => return Err(JitError::NotCached),
        None => {
            if cancel.load(Ordering::Relaxed) {
                return Err(JitError::Cancelled);
            }
            let work = WorkDir::new(&cc.cache_dir)?;
            let id = cc.target_identity(&work, cancel)?;
            if let Some(name) = &record {
                // Best effort, renamed into place whole: without it the next run asks again.
                let tmp = work.0.join("target");
                if std::fs::write(&tmp, &id).is_ok() {
                    let _ = std::fs::rename(&tmp, cc.cache_dir.join(name));
                }
            }
            id
        }
    };
    if let Ok(mut k) = known.lock() {
        k.push((cc.clone(), id.clone()));
    }
    Ok(id)
}

fn first_lines(bytes: &[u8]) -> String {
    let text = String::from_utf8_lossy(bytes);
    let lines: Vec<&str> = text
        .lines()
        .filter(|l| !l.trim().is_empty())
        .take(3)
        .collect();
    if lines.is_empty() {
        "no message".into()
    } else {
        lines.join(" | ")
    }
}

/// A loaded C kernel library.
pub(super) struct CKernels {
    /// Keeps the code mapped while the function pointers are in use.
    pub _library: libloading::Library,
    /// The memory file the library was loaded from, open while it is loaded (after it in
    /// drop order; see `open_library`).
    pub _memory_file: Option<std::fs::File>,
    pub orbit: COrbitFn,
    pub tangent: Option<CTangentFn>,
    /// The fused one-orbit kernel, where the source has one ([`super::c_fused`]).
    pub fused: Option<CFusedFn>,
    /// Whether the library came from the cache (no compilation in this call).
    pub cached: bool,
    pub path: PathBuf,
}

/// Writes the C source of the kernels of `spec`.
pub(super) fn source(graph: &Graph, spec: &StepSpec) -> Result<String, JitError> {
    let n = spec.n;
    let check =
        |f: usize, outputs: &[NodeId], args: Vec<Layout>| kernel_plan(graph, n, f, outputs, args);
    let mut src = String::with_capacity(64 * graph.len() + 4096);
    src.push_str(&prelude());
    let orbit = check(0, &spec.gradient, vec![Layout::Lanes])?;
    Kernel {
        graph,
        plan: &orbit,
        n,
        tangent: false,
    }
    .write(&mut src);
    if let Some(hv) = &spec.hessian_vector {
        let plan = check(1, hv, vec![Layout::Scalar, Layout::Lanes])?;
        Kernel {
            graph,
            plan: &plan,
            n,
            tangent: true,
        }
        .write(&mut src);
    }
    Ok(src)
}

/// Compiles (or loads from the cache) the C kernels of the source `src` (with a tangent kernel
/// when `tangent`); stops the compiler and returns [`JitError::Cancelled`] once `cancel` is set.
pub(super) fn build(
    src: &str,
    tangent: bool,
    cc: &CCompiler,
    cancel: &AtomicBool,
    mode: Mode,
) -> Result<(CKernels, Duration), JitError> {
    let start = Instant::now();
    if mode == Mode::Load && !cc.cache_dir.exists() {
        return Err(JitError::NotCached);
    }
    let cache = CacheDir::open(&cc.cache_dir)?;
    let identity = identity(cc, &cache, cancel, mode)?;
    let mut h = Sha256::new();
    h.update(cc.program.to_string_lossy().as_bytes());
    h.update([0]);
    h.update(FLAGS.join(" ").as_bytes());
    h.update([0]);
    h.update(identity.as_bytes());
    h.update([0]);
    h.update(src.as_bytes());
    let hash: String = h
        .finalize()
        .iter()
        .take(20)
        .map(|b| format!("{b:02x}"))
        .collect();
    let io = |what: &str, path: &Path, e: std::io::Error| {
        JitError::CCompiler(format!("{what} {}: {e}", path.display()))
    };
    let lib_name = format!("steps-{hash}.so");
    let digest_name = format!("steps-{hash}.sha256");
    let lib_path = cc.cache_dir.join(&lib_name);
    if let Some(bytes) = cache.verified(&lib_name, &digest_name)?
        && let Ok(k) = load(&bytes, &lib_path, &hash, tangent, true)
    {
        return Ok((k, start.elapsed()));
    }
    if mode == Mode::Load {
        return Err(JitError::NotCached);
    }
    if cancel.load(Ordering::Relaxed) {
        return Err(JitError::Cancelled);
    }
    remove_abandoned_builds(&cc.cache_dir);
    // Everything of this build (the source, the compiler's own temporary files through
    // `TMPDIR`, its messages, the library before its rename) lives in one directory of this
    // process, removed when the build ends however it ends; the library is renamed into place,
    // so a concurrent run that builds or reads the same kernel never sees a half-written file.
    let work = WorkDir::new(&cc.cache_dir)?;
    let src_path = work.0.join("steps.c");
    let tmp_path = work.0.join("steps.so");
    let log_path = work.0.join("messages");
    let src = src.replace("@HASH@", &hash);
    std::fs::write(&src_path, &src).map_err(|e| io("cannot write", &src_path, e))?;
    let log = std::fs::File::create(&log_path).map_err(|e| io("cannot write", &log_path, e))?;
    let mut command = Command::new(&cc.program);
    command
        .args(FLAGS)
        .arg("-o")
        .arg(&tmp_path)
        .arg(&src_path)
        .env("TMPDIR", &work.0)
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(log);
    let status = run_compiler(cc, &mut command, cancel, "compiling the step kernels")?;
    if !status.success() {
        let messages = read_regular(&log_path).unwrap_or_default();
        return Err(JitError::CCompiler(format!(
            "the C compiler '{}' failed on the step kernels ({status}): {}",
            cc.program.display(),
            first_lines(&messages)
        )));
    }
    // The library's digest beside it, both renamed into place (the library first: a reader
    // that finds a digest of an older library rebuilds rather than trusting it).
    // Read without blocking and only as a regular file: a compiler that lies could leave a
    // FIFO there, whose open would wait for a writer for ever.
    let bytes = read_regular(&tmp_path).map_err(|e| {
        JitError::CCompiler(format!(
            "the C compiler '{}' left no library: {}: {e}",
            cc.program.display(),
            tmp_path.display()
        ))
    })?;
    let digest_tmp = work.0.join("steps.sha256");
    let digest_path = cc.cache_dir.join(&digest_name);
    std::fs::write(&digest_tmp, digest_hex(&bytes))
        .map_err(|e| io("cannot write", &digest_tmp, e))?;
    std::fs::rename(&tmp_path, &lib_path)
        .map_err(|e| io("cannot move the compiled kernels to", &lib_path, e))?;
    std::fs::rename(&digest_tmp, &digest_path)
        .map_err(|e| io("cannot move the kernels' digest to", &digest_path, e))?;
    drop(work);
    // Loaded from the bytes just read, not from the cache path.
    let k = load(&bytes, &lib_path, &hash, tangent, false)?;
    Ok((k, start.elapsed()))
}

/// SHA-256 of `bytes` in hexadecimal: what the digest file beside a library holds.
fn digest_hex(bytes: &[u8]) -> String {
    Sha256::digest(bytes)
        .iter()
        .map(|b| format!("{b:02x}"))
        .collect()
}

/// The kernel cache directory, opened once per build and checked through that handle: a real
/// directory (a symbolic link is refused, not followed) owned by this user and writable by no
/// one else. Files are read relative to the handle, so the directory checked is the one read,
/// even if its path is renamed meanwhile.
struct CacheDir {
    path: PathBuf,
    #[cfg(unix)]
    fd: std::os::fd::OwnedFd,
}

/// Why a cache directory is refused, for the one-line error.
const FOREIGN_CODE: &str = "a library someone else put there would run as you";

impl CacheDir {
    fn open(path: &Path) -> Result<CacheDir, JitError> {
        let fail = |what: String| {
            JitError::CCompiler(format!("the kernel cache {}: {what}", path.display()))
        };
        let mut builder = std::fs::DirBuilder::new();
        builder.recursive(true);
        #[cfg(unix)]
        std::os::unix::fs::DirBuilderExt::mode(&mut builder, 0o700);
        builder.create(path).map_err(|e| {
            JitError::CCompiler(format!(
                "cannot create the kernel cache {}: {e}",
                path.display()
            ))
        })?;
        #[cfg(unix)]
        {
            use std::os::fd::FromRawFd;
            use std::os::unix::ffi::OsStrExt;
            let c_path = std::ffi::CString::new(path.as_os_str().as_bytes())
                .map_err(|_| fail("the path holds a NUL byte".into()))?;
            // SAFETY: a NUL-terminated path; the descriptor is owned below.
            let raw = unsafe {
                libc::open(
                    c_path.as_ptr(),
                    libc::O_RDONLY | libc::O_DIRECTORY | libc::O_NOFOLLOW | libc::O_CLOEXEC,
                )
            };
            if raw < 0 {
                let e = std::io::Error::last_os_error();
                return Err(fail(match e.raw_os_error() {
                    Some(libc::ELOOP) | Some(libc::ENOTDIR) => format!(
                        "not a directory but a link or a file, refused ({FOREIGN_CODE} through it); remove it or set CHAOSCOPE_KERNEL_CACHE to a directory of yours"
                    ),
                    _ => e.to_string(),
                }));
            }
            // SAFETY: `raw` is a descriptor this call just opened and nothing else owns.
            let fd = unsafe { std::os::fd::OwnedFd::from_raw_fd(raw) };
            let dir = CacheDir {
                path: path.to_path_buf(),
                fd,
            };
            let meta = dir.stat(None).map_err(|e| fail(e.to_string()))?;
            check_owner(&meta).map_err(|why| {
                fail(format!(
                    "{why}: {FOREIGN_CODE}; remove it, or set CHAOSCOPE_KERNEL_CACHE to a directory of yours"
                ))
            })?;
            Ok(dir)
        }
        #[cfg(not(unix))]
        {
            let _ = fail;
            Ok(CacheDir {
                path: path.to_path_buf(),
            })
        }
    }

    /// `fstat` of the directory (`file` `None`) or of the open file `file`.
    #[cfg(unix)]
    fn stat(&self, file: Option<&std::fs::File>) -> std::io::Result<libc::stat> {
        use std::os::fd::AsRawFd;
        let fd = file.map_or(self.fd.as_raw_fd(), |f| f.as_raw_fd());
        // SAFETY: `stat` is plain data, filled by fstat(2) on a descriptor we hold.
        let mut st: libc::stat = unsafe { std::mem::zeroed() };
        // SAFETY: as above.
        if unsafe { libc::fstat(fd, &mut st) } != 0 {
            return Err(std::io::Error::last_os_error());
        }
        Ok(st)
    }

    /// The bytes of file `name` of the directory, if it is a regular file (not a link) owned
    /// by this user and writable by no one else; `None` otherwise (missing, a link, foreign,
    /// unreadable: a build replaces it). An entry that is there but not a regular file (a
    /// FIFO, a device, a socket, a directory) is refused ([`JitError::CacheEntry`]) without
    /// being opened for reading: a FIFO's open or read would wait for a writer for ever, a
    /// device's could do anything. It is checked before the open and again through the
    /// descriptor (opened non-blocking), so one swapped in between is refused too.
    fn read(&self, name: &str) -> Result<Option<Vec<u8>>, JitError> {
        #[cfg(unix)]
        {
            use std::io::Read;
            use std::os::fd::{AsRawFd, FromRawFd};
            let refuse = |mode: libc::mode_t| {
                JitError::CacheEntry(format!(
                    "the kernel cache entry {} is {}, not a regular file: refused (nothing \
                     read from it); remove it",
                    self.path.join(name).display(),
                    file_kind(mode)
                ))
            };
            let Ok(c_name) = std::ffi::CString::new(name) else {
                return Ok(None);
            };
            // SAFETY: `stat` is plain data, filled by fstatat(2) relative to a descriptor we
            // hold, of a NUL-terminated name, not following a link.
            let mut st: libc::stat = unsafe { std::mem::zeroed() };
            // SAFETY: as above.
            let found = unsafe {
                libc::fstatat(
                    self.fd.as_raw_fd(),
                    c_name.as_ptr(),
                    &mut st,
                    libc::AT_SYMLINK_NOFOLLOW,
                )
            } == 0;
            if !found || st.st_mode & libc::S_IFMT == libc::S_IFLNK {
                return Ok(None);
            }
            if st.st_mode & libc::S_IFMT != libc::S_IFREG {
                return Err(refuse(st.st_mode));
            }
            // SAFETY: a NUL-terminated name relative to a directory descriptor we hold.
            let raw = unsafe {
                libc::openat(
                    self.fd.as_raw_fd(),
                    c_name.as_ptr(),
                    libc::O_RDONLY | libc::O_NOFOLLOW | libc::O_NONBLOCK | libc::O_CLOEXEC,
                )
            };
            if raw < 0 {
                return Ok(None);
            }
            // SAFETY: `raw` was just opened and is owned by the file from here on.
            let mut file = unsafe { std::fs::File::from_raw_fd(raw) };
            let Ok(meta) = self.stat(Some(&file)) else {
                return Ok(None);
            };
            if meta.st_mode & libc::S_IFMT != libc::S_IFREG {
                return Err(refuse(meta.st_mode));
            }
            if check_owner(&meta).is_err() {
                return Ok(None);
            }
            let mut bytes = Vec::new();
            Ok(file.read_to_end(&mut bytes).ok().map(|_| bytes))
        }
        #[cfg(not(unix))]
        {
            Ok(std::fs::read(self.path.join(name)).ok())
        }
    }

    /// The library `lib` if its bytes have the SHA-256 the digest file `digest` holds.
    fn verified(&self, lib: &str, digest: &str) -> Result<Option<Vec<u8>>, JitError> {
        let Some(expected) = self.read(digest)? else {
            return Ok(None);
        };
        let Some(bytes) = self.read(lib)? else {
            return Ok(None);
        };
        Ok((digest_hex(&bytes).as_bytes() == expected.trim_ascii()).then_some(bytes))
    }
}

/// What a file of mode `mode` is, for a refusal.
#[cfg(unix)]
fn file_kind(mode: libc::mode_t) -> &'static str {
    match mode & libc::S_IFMT {
        libc::S_IFIFO => "a FIFO",
        libc::S_IFCHR => "a character device",
        libc::S_IFBLK => "a block device",
        libc::S_IFSOCK => "a socket",
        libc::S_IFDIR => "a directory",
        libc::S_IFLNK => "a symbolic link",
        _ => "a special file",
    }
}

/// The bytes of the file at `path` if it is a regular file, opened without blocking and
/// without following a link (what the compiler left in the build directory: a compiler that
/// lies could leave a FIFO, whose open or read would wait for ever).
fn read_regular(path: &Path) -> Result<Vec<u8>, String> {
    use std::io::Read;
    let mut options = std::fs::OpenOptions::new();
    options.read(true);
    #[cfg(unix)]
    std::os::unix::fs::OpenOptionsExt::custom_flags(
        &mut options,
        libc::O_NONBLOCK | libc::O_NOFOLLOW,
    );
    let mut file = options.open(path).map_err(|e| e.to_string())?;
    let meta = file.metadata().map_err(|e| e.to_string())?;
    if !meta.is_file() {
        #[cfg(unix)]
        {
            use std::os::unix::fs::MetadataExt;
            return Err(format!(
                "{}, not a regular file: refused",
                file_kind(meta.mode() as libc::mode_t)
            ));
        }
        #[cfg(not(unix))]
        return Err("not a regular file: refused".into());
    }
    let mut bytes = Vec::new();
    file.read_to_end(&mut bytes).map_err(|e| e.to_string())?;
    Ok(bytes)
}

/// Longest a compiler process may run when `CHAOSCOPE_CC_TIMEOUT` does not say: far beyond a
/// normal build (0.15-0.5 s for the kernels of a chain on an AMD EPYC Zen 5; 2.7-3.4 s from
/// the first call to the kernels loaded, target query included, for a 16-site chain's on 2 of
/// its vCPUs at a load average of 14; tens of seconds for the unrolled derivatives of a
/// thousand-site chain whose terms do not fold into one loop), so only a compiler that hangs (a stalled licence server or
/// network mount) meets it. Meanwhile the command runs on the Cranelift kernels (a build runs
/// in the background; a lookup that only loads runs no compiler at all).
pub const DEFAULT_CC_TIMEOUT: Duration = Duration::from_secs(300);

/// How long one compiler process may run: `CHAOSCOPE_CC_TIMEOUT` (seconds, a positive
/// number), else [`DEFAULT_CC_TIMEOUT`]. A value that is not a positive number is an error of
/// the C build (said in its one line; the command goes on without C kernels).
pub fn compiler_deadline() -> Result<Duration, JitError> {
    let Some(v) = std::env::var_os("CHAOSCOPE_CC_TIMEOUT") else {
        return Ok(DEFAULT_CC_TIMEOUT);
    };
    v.to_str()
        .and_then(|t| t.trim().parse::<f64>().ok())
        .filter(|t| t.is_finite() && *t > 0.0 && *t < 1e9)
        .map(Duration::from_secs_f64)
        .ok_or_else(|| {
            JitError::CCompiler(format!(
                "CHAOSCOPE_CC_TIMEOUT='{}' is not a positive number of seconds",
                v.to_string_lossy()
            ))
        })
}

/// A compiler process and its process group, killed when dropped unless it was reaped (a
/// panic or an early return never leaves a compiler running).
struct CompilerProcess(Option<std::process::Child>);

impl Drop for CompilerProcess {
    fn drop(&mut self) {
        if let Some(child) = &mut self.0 {
            kill_group(child);
        }
    }
}

/// Runs one compiler process (`command`, its input and output already set) to its end:
///
/// - in a process group of its own, so that a stop kills the driver and every pass it started
///   (cc1, as, ld), and a Ctrl-C at the terminal, meant for chaoscope, does not reach it
///   (chaoscope decides what happens to it);
/// - with the parent-death signal SIGKILL (Linux), so that a chaoscope killed outright (SIGKILL,
///   a crash) leaves no compiler waiting for ever (the signal follows the thread that started
///   it, which waits here until the compiler has ended);
/// - stopped (its group killed) once `cancel` is set, once this process has received SIGINT or
///   SIGTERM (the command then ends on its own path), or at its deadline
///   ([`compiler_deadline`]), polled every 10 ms.
///
/// `what` names the step for the error. A compiler that hangs thus costs at most its deadline,
/// in the background, and one line; the caller goes on without C kernels.
fn run_compiler(
    cc: &CCompiler,
    command: &mut Command,
    cancel: &AtomicBool,
    what: &str,
) -> Result<ExitStatus, JitError> {
    let deadline = compiler_deadline()?;
    let stop_wanted = || cancel.load(Ordering::Relaxed) || chaoscope_os::signals::requested();
    if stop_wanted() {
        return Err(JitError::Cancelled);
    }
    #[cfg(unix)]
    {
        use std::os::unix::process::CommandExt;
        command.process_group(0);
    }
    #[cfg(target_os = "linux")]
    {
        use std::os::unix::process::CommandExt;
        // SAFETY: getpid(2) cannot fail.
        let parent = unsafe { libc::getpid() };
        // SAFETY: the closure runs in the forked child before exec and calls only
        // async-signal-safe functions (prctl, getppid), allocating nothing.
        unsafe {
            command.pre_exec(move || {
                if libc::prctl(libc::PR_SET_PDEATHSIG, libc::SIGKILL as libc::c_ulong) != 0 {
                    return Err(std::io::Error::last_os_error());
                }
                // The parent may have ended before the line above: then nothing would ever
                // send the signal.
                if libc::getppid() != parent {
                    return Err(std::io::Error::from_raw_os_error(libc::ESRCH));
                }
                Ok(())
            });
        }
    }
    let start = Instant::now();
    let child = command.spawn().map_err(|e| {
        JitError::CCompiler(format!(
            "cannot run the C compiler '{}': {e}",
            cc.program.display()
        ))
    })?;
    let mut process = CompilerProcess(Some(child));
    loop {
        let child = process.0.as_mut().expect("reaped only on the way out");
        match child.try_wait() {
            Ok(Some(status)) => {
                process.0 = None;
                return Ok(status);
            }
            Ok(None) if stop_wanted() => return Err(JitError::Cancelled),
            Ok(None) if start.elapsed() >= deadline => {
                return Err(JitError::CCompiler(format!(
                    "the C compiler '{}' did not finish {what} within {} s (stopped; \
                     CHAOSCOPE_CC_TIMEOUT sets the limit)",
                    cc.program.display(),
                    deadline.as_secs_f64()
                )));
            }
            Ok(None) => std::thread::sleep(Duration::from_millis(10)),
            Err(e) => {
                return Err(JitError::CCompiler(format!(
                    "waiting for the C compiler '{}': {e}",
                    cc.program.display()
                )));
            }
        }
    }
}

/// Owned by this user and writable by no one else; else why not.
#[cfg(unix)]
fn check_owner(meta: &libc::stat) -> Result<(), String> {
    // SAFETY: geteuid(2) cannot fail.
    let uid = unsafe { libc::geteuid() };
    if meta.st_uid != uid {
        return Err(format!(
            "belongs to uid {}, not to you (uid {uid})",
            meta.st_uid
        ));
    }
    let mode = meta.st_mode & 0o7777;
    if mode & 0o022 != 0 {
        return Err(format!("is writable by others (mode {mode:o})"));
    }
    Ok(())
}

/// Prefix of the build directories in the cache: `build-<pid>-<n>`.
const BUILD_DIR: &str = "build-";

/// A build directory of this process, removed with its contents when dropped.
struct WorkDir(PathBuf);

impl WorkDir {
    fn new(cache_dir: &Path) -> Result<WorkDir, JitError> {
        static NEXT: AtomicU64 = AtomicU64::new(0);
        let n = NEXT.fetch_add(1, Ordering::Relaxed);
        let path = cache_dir.join(format!("{BUILD_DIR}{}-{n}", std::process::id()));
        // A directory of this name can only be left by an earlier process of the same pid.
        let _ = std::fs::remove_dir_all(&path);
        let mut builder = std::fs::DirBuilder::new();
        #[cfg(unix)]
        std::os::unix::fs::DirBuilderExt::mode(&mut builder, 0o700);
        builder
            .create(&path)
            .map_err(|e| JitError::CCompiler(format!("cannot create {}: {e}", path.display())))?;
        Ok(WorkDir(path))
    }
}

impl Drop for WorkDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

/// Kills the compiler's process group (the driver and the compiler passes, assembler and
/// linker it started) and reaps the driver.
fn kill_group(child: &mut std::process::Child) {
    #[cfg(unix)]
    if let Ok(pid) = libc::pid_t::try_from(child.id()) {
        // SAFETY: a plain system call on the group this module created for the child (its
        // pid is the group id and stays reserved until the `wait` below reaps it).
        unsafe {
            libc::kill(-pid, libc::SIGKILL);
        }
    }
    let _ = child.kill();
    let _ = child.wait();
}

/// Removes build directories whose process no longer exists (a chaoscope killed by SIGKILL
/// cannot clean up after itself; the next build does).
fn remove_abandoned_builds(cache_dir: &Path) {
    let Ok(entries) = std::fs::read_dir(cache_dir) else {
        return;
    };
    for entry in entries.flatten() {
        let name = entry.file_name();
        let Some(pid) = name
            .to_str()
            .and_then(|n| n.strip_prefix(BUILD_DIR))
            .and_then(|n| n.split('-').next())
            .and_then(|p| p.parse::<i32>().ok())
        else {
            continue;
        };
        if pid != std::process::id() as i32 && !process_exists(pid) {
            let _ = std::fs::remove_dir_all(entry.path());
        }
    }
}

fn process_exists(pid: i32) -> bool {
    #[cfg(unix)]
    {
        // SAFETY: signal 0 only checks that the process exists (no signal is sent).
        let r = unsafe { libc::kill(pid, 0) };
        r == 0 || std::io::Error::last_os_error().raw_os_error() == Some(libc::EPERM)
    }
    #[cfg(not(unix))]
    {
        let _ = pid;
        true
    }
}

/// Loads a compiled library from `bytes` (those of `path`, already checked against their
/// digest) and checks that it is the one its name says (it carries its hash).
fn load(
    bytes: &[u8],
    path: &Path,
    hash: &str,
    tangent: bool,
    cached: bool,
) -> Result<CKernels, JitError> {
    let fail = |e: String| {
        JitError::CCompiler(format!(
            "cannot load the compiled kernels {}: {e}",
            path.display()
        ))
    };
    let (library, memory_file) = open_library(bytes, path).map_err(fail)?;
    // SAFETY: the symbol is a NUL-terminated `char` array in the generated source.
    let stamp = unsafe { library.get::<*const std::ffi::c_char>(b"chaoscope_kernel_hash\0") }
        .map_err(|e| fail(e.to_string()))?;
    // SAFETY: `get` on a data symbol yields its address, a NUL-terminated array.
    let stamp = unsafe { std::ffi::CStr::from_ptr(*stamp) };
    if stamp.to_bytes() != hash.as_bytes() {
        return Err(fail("it was compiled from another source".into()));
    }
    // SAFETY: the generated source defines these functions with exactly these signatures.
    let orbit = *unsafe { library.get::<COrbitFn>(b"chaoscope_orbit_steps\0") }
        .map_err(|e| fail(e.to_string()))?;
    let tangent = if tangent {
        // SAFETY: as above.
        Some(
            *unsafe { library.get::<CTangentFn>(b"chaoscope_tangent_steps\0") }
                .map_err(|e| fail(e.to_string()))?,
        )
    } else {
        None
    };
    // SAFETY: as above; the symbol is there only where the source wrote the kernel.
    let fused = unsafe { library.get::<CFusedFn>(super::c_fused::SYMBOL) }
        .ok()
        .map(|f| *f);
    Ok(CKernels {
        _library: library,
        _memory_file: memory_file,
        orbit,
        tangent,
        fused,
        cached,
        path: path.to_path_buf(),
    })
}

/// `dlopen` of exactly `bytes`: on Linux through an anonymous memory file, so what runs is
/// what was checked whatever happens to the cache meanwhile; elsewhere from `path`.
///
/// On Linux the memory file stays open as long as the library is loaded (the caller keeps the
/// returned file beside it): `dlopen` knows a library by the name it was opened by, and
/// `/proc/self/fd/N` names whatever descriptor `N` is now, so a library opened once the
/// descriptor of another, still loaded, had been closed and its number reused would be handed
/// that other library (seen as "compiled from another source" when two threads loaded
/// kernels at once).
fn open_library(
    bytes: &[u8],
    path: &Path,
) -> Result<(libloading::Library, Option<std::fs::File>), String> {
    #[cfg(target_os = "linux")]
    {
        use std::io::Write;
        use std::os::fd::{AsRawFd, FromRawFd};
        let _ = path;
        // SAFETY: a NUL-terminated name; the descriptor is owned below.
        let raw = unsafe { libc::memfd_create(c"chaoscope-kernels".as_ptr(), libc::MFD_CLOEXEC) };
        if raw < 0 {
            return Err(format!("memfd_create: {}", std::io::Error::last_os_error()));
        }
        // SAFETY: `raw` was just created and is owned by the file from here on.
        let mut file = unsafe { std::fs::File::from_raw_fd(raw) };
        file.write_all(bytes).map_err(|e| e.to_string())?;
        let at = format!("/proc/self/fd/{}", file.as_raw_fd());
        // SAFETY: a library this module compiled from its own source and whose bytes match
        // the digest written when it was built: no constructors, no global state; its symbols
        // are checked before any is called.
        let library = unsafe { libloading::Library::new(at) }.map_err(|e| e.to_string())?;
        Ok((library, Some(file)))
    }
    #[cfg(not(target_os = "linux"))]
    {
        let _ = bytes;
        // SAFETY: as above (the file was checked just before; between the check and this
        // call only its owner, this user, could change it).
        let library = unsafe { libloading::Library::new(path) }.map_err(|e| e.to_string())?;
        Ok((library, None))
    }
}

/// Helpers of every generated file. `vd` is one vector of `LANES` lanes (a block is two); compares give `vi`
/// masks (all ones where true, false when either side is NaN).
pub(super) fn prelude() -> String {
    let mut src = String::from(
        r#"/* chaoscope step kernels, generated; see expr/src/jit/c_step.rs. */
#include <stddef.h>
#include <stdint.h>
#include <string.h>
#define LANES 4
#define BLOCK 8
typedef double vd __attribute__((vector_size(LANES * 8)));
typedef int64_t vi __attribute__((vector_size(LANES * 8)));
typedef double (*fn1)(double);
typedef double (*fn2)(double, double);
typedef double (*fntab)(uintptr_t, uint64_t, double);
const char chaoscope_kernel_hash[] = "@HASH@";
static inline double K(uint64_t bits) { double d; memcpy(&d, &bits, 8); return d; }
"#,
    );
    src.push_str(&vector_helpers("", "vd", "vi", "LANES"));
    src.push_str(
        r#"static inline double SABS(double a) { uint64_t b; memcpy(&b, &a, 8); b &= 0x7fffffffffffffffull; memcpy(&a, &b, 8); return a; }
static inline double SSTEP(double x) { return x != x ? x : (x > 0.0 ? 1.0 : 0.0); }
static inline double SSIGN(double x) { return x != x ? x : (x > 0.0 ? 1.0 : (x < 0.0 ? -1.0 : 0.0)); }
static inline double SMAX(double a, double b) { return (a != a || b != b) ? K(0x7ff8000000000000ull) : (a >= b ? a : b); }
static inline double SMIN(double a, double b) { return (a != a || b != b) ? K(0x7ff8000000000000ull) : (a <= b ? a : b); }
"#,
    );
    src
}

/// The vector helpers over the vector type `vd` of `lanes` lanes and its mask type `vi`, each
/// name with `prefix` (the step kernels' four-lane ones without, the fused kernel's host-wide
/// ones with `F`): one definition of what each operation does lane by lane (NaN and signed
/// zeros as the scalar definitions), whatever the width.
pub(super) fn vector_helpers(prefix: &str, vd: &str, vi: &str, lanes: &str) -> String {
    let p = prefix;
    format!(
        r#"static inline {vd} {p}B(double x) {{ {vd} r; for (int l = 0; l < {lanes}; l++) r[l] = x; return r; }}
static inline {vd} {p}LD(const double *p) {{ {vd} r; memcpy(&r, p, sizeof r); return r; }}
static inline void {p}ST(double *p, {vd} v) {{ memcpy(p, &v, sizeof v); }}
static inline {vd} {p}SEL({vi} m, {vd} t, {vd} e) {{ return ({vd})((m & ({vi})t) | (~m & ({vi})e)); }}
static inline {vd} {p}VABS({vd} a) {{ {vi} m; for (int l = 0; l < {lanes}; l++) m[l] = INT64_MAX; return ({vd})(({vi})a & m); }}
static inline {vd} {p}VSQRT({vd} a) {{ {vd} r; for (int l = 0; l < {lanes}; l++) r[l] = __builtin_sqrt(a[l]); return r; }}
static inline {vd} {p}VSTEP({vd} x) {{ {vd} r = {p}SEL(x > {p}B(0.0), {p}B(1.0), {p}B(0.0)); return {p}SEL(x != x, x, r); }}
static inline {vd} {p}VSIGN({vd} x) {{ {vd} r = {p}SEL(x < {p}B(0.0), {p}B(-1.0), {p}B(0.0)); r = {p}SEL(x > {p}B(0.0), {p}B(1.0), r); return {p}SEL(x != x, x, r); }}
static inline {vd} {p}VMAX({vd} a, {vd} b) {{ {vd} r = {p}SEL(a >= b, a, b); return {p}SEL((a != a) | (b != b), {p}B(K(0x7ff8000000000000ull)), r); }}
static inline {vd} {p}VMIN({vd} a, {vd} b) {{ {vd} r = {p}SEL(a <= b, a, b); return {p}SEL((a != a) | (b != b), {p}B(K(0x7ff8000000000000ull)), r); }}
static inline {vd} {p}V1(uintptr_t f, {vd} a) {{ {vd} r; for (int l = 0; l < {lanes}; l++) r[l] = ((fn1)f)(a[l]); return r; }}
static inline {vd} {p}V2(uintptr_t f, {vd} a, {vd} b) {{ {vd} r; for (int l = 0; l < {lanes}; l++) r[l] = ((fn2)f)(a[l], b[l]); return r; }}
static inline {vd} {p}VT(uintptr_t f, uintptr_t t, uint64_t d, {vd} a) {{ {vd} r; for (int l = 0; l < {lanes}; l++) r[l] = ((fntab)f)(t, d, a[l]); return r; }}
"#
    )
}

/// One kernel (orbit or tangent) being written.
struct Kernel<'a> {
    graph: &'a Graph,
    plan: &'a Plan,
    n: usize,
    tangent: bool,
}

fn cmp_op(cmp: Cmp) -> &'static str {
    match cmp {
        Cmp::Lt => "<",
        Cmp::Le => "<=",
        Cmp::Gt => ">",
        Cmp::Ge => ">=",
    }
}

fn unary_slot(op: Unary) -> usize {
    UNARY_CALLED
        .iter()
        .position(|&u| u == op)
        .expect("a called-back unary operation")
}

/// A constant by its bits (no decimal round trip; NaN payloads and signed zeros kept).
pub(super) fn konst(c: f64) -> String {
    format!("K(0x{:016x}ull)", c.to_bits())
}

/// `x^n` as [`Graph::apply_powi`]: a left-to-right product (C's `*` is left-associative).
fn powi(x: &str, n: i32, one: &str) -> String {
    if n == 0 {
        return one.to_string();
    }
    let product = vec![x; n.unsigned_abs() as usize].join(" * ");
    if n < 0 {
        format!("{one} / ({product})")
    } else {
        format!("({product})")
    }
}

/// The C lines computing `roots`, operands first (in [`super::schedule`]'s order): each leaf's
/// expression and whether it is lane code from `leaf`; a node with a lane operand becomes
/// `const vd NAME = ...;` (its scalar operands broadcast), any other `const double NAME = ...;`,
/// named by `name(id, lane)` and handed to `line(lane, text)`. Returns every emitted node's
/// (name or expression, lane).
pub(super) fn emit_nodes(
    graph: &Graph,
    roots: &[NodeId],
    leaf: &mut dyn FnMut(&Node) -> (String, bool),
    name: &dyn Fn(NodeId, bool) -> String,
    line: &mut dyn FnMut(bool, String),
) -> Vec<Option<(String, bool)>> {
    let mut vals: Vec<Option<(String, bool)>> = vec![None; graph.len()];
    for id in super::schedule(graph, roots, |_| true) {
        let node = graph.node(id);
        if is_leaf(node) {
            vals[id as usize] = Some(leaf(node));
            continue;
        }
        let lane = node
            .operands()
            .any(|o| vals[o as usize].as_ref().is_some_and(|v| v.1));
        let e = if lane {
            vector_expr(node, &mut |o| {
                let (x, lane) = vals[o as usize].clone().expect("operands first");
                if lane { x } else { format!("B({x})") }
            })
        } else {
            scalar_expr(node, &mut |o| {
                vals[o as usize].clone().expect("operands first").0
            })
        };
        let n = name(id, lane);
        let ty = if lane { "vd" } else { "double" };
        line(lane, format!("const {ty} {n} = {e};"));
        vals[id as usize] = Some((n, lane));
    }
    vals
}

/// A scalar node as a C expression of its operands (`o` names them).
pub(super) fn scalar_expr(node: &Node, o: &mut dyn FnMut(NodeId) -> String) -> String {
    c_expr(node, o, Lanes::Scalar)
}

/// A vector node (`vd` values) as a C expression of its operands (`o` names them, as vectors).
pub(super) fn vector_expr(node: &Node, o: &mut dyn FnMut(NodeId) -> String) -> String {
    c_expr(node, o, Lanes::Vector)
}

/// Whether C code computes one value (plain `double`) or `vd` lanes at once (the vector type
/// and its helper macros): the two spell only calls, branches and the non-arithmetic
/// operations differently.
#[derive(Clone, Copy, PartialEq, Eq)]
enum Lanes {
    Scalar,
    Vector,
}

impl Lanes {
    /// The helper macro for an operation the prelude defines in both flavours (`SABS`/`VABS`).
    fn helper(self, name: &str) -> String {
        match self {
            Lanes::Scalar => format!("S{name}"),
            Lanes::Vector => format!("V{name}"),
        }
    }

    /// A call of the unary function in environment slot `slot`.
    fn call1(self, slot: usize, a: &str) -> String {
        match self {
            Lanes::Scalar => format!("((fn1)env[{slot}])({a})"),
            Lanes::Vector => format!("V1(env[{slot}], {a})"),
        }
    }

    /// A call of the binary function in environment slot `slot`.
    fn call2(self, slot: usize, a: &str, b: &str) -> String {
        match self {
            Lanes::Scalar => format!("((fn2)env[{slot}])({a}, {b})"),
            Lanes::Vector => format!("V2(env[{slot}], {a}, {b})"),
        }
    }
}

/// A node as a C expression of its operands, in scalar or vector code.
fn c_expr(node: &Node, o: &mut dyn FnMut(NodeId) -> String, lanes: Lanes) -> String {
    match *node {
        Node::Const(_) | Node::Input { .. } => unreachable!("leaves are operands"),
        Node::Unary(op, a) => {
            let a = o(a);
            match op {
                Unary::Neg => format!("-{a}"),
                Unary::Abs => format!("{}({a})", lanes.helper("ABS")),
                Unary::Sqrt if lanes == Lanes::Scalar => format!("__builtin_sqrt({a})"),
                Unary::Sqrt => format!("VSQRT({a})"),
                Unary::Step => format!("{}({a})", lanes.helper("STEP")),
                Unary::Sign => format!("{}({a})", lanes.helper("SIGN")),
                _ => lanes.call1(unary_slot(op), &a),
            }
        }
        Node::Binary(op, a, b) => {
            let (a, b) = (o(a), o(b));
            match op {
                Binary::Add => format!("{a} + {b}"),
                Binary::Sub => format!("{a} - {b}"),
                Binary::Mul => format!("{a} * {b}"),
                Binary::Div => format!("{a} / {b}"),
                Binary::Pow => lanes.call2(ENV_POW, &a, &b),
                Binary::Atan2 => lanes.call2(ENV_ATAN2, &a, &b),
                Binary::Max => format!("{}({a}, {b})", lanes.helper("MAX")),
                Binary::Min => format!("{}({a}, {b})", lanes.helper("MIN")),
            }
        }
        Node::Powi(a, n) => {
            let one = match lanes {
                Lanes::Scalar => "1.0",
                Lanes::Vector => "B(1.0)",
            };
            powi(&o(a), n, one)
        }
        Node::Select {
            cmp,
            a,
            b,
            then,
            otherwise,
        } => {
            let (a, b) = (o(a), o(b));
            let (t, e) = (o(then), o(otherwise));
            match lanes {
                Lanes::Scalar => format!("({a} {} {b}) ? {t} : {e}", cmp_op(cmp)),
                Lanes::Vector => format!("SEL({a} {} {b}, {t}, {e})", cmp_op(cmp)),
            }
        }
        Node::Table { table, deriv, arg } => {
            let data = ENV_TABLES + table as usize;
            let arg = o(arg);
            match lanes {
                Lanes::Scalar => {
                    format!("((fntab)env[{ENV_TABLE}])(env[{data}], {deriv}, {arg})")
                }
                Lanes::Vector => format!("VT(env[{ENV_TABLE}], env[{data}], {deriv}, {arg})"),
            }
        }
    }
}

impl Kernel<'_> {
    /// The lane argument: the orbit's positions (0) or the tangent's `dq` (1).
    fn lane_arg(&self) -> u8 {
        u8::from(self.tangent)
    }

    /// A scalar operand in the uniform code (computed once per call or per stage).
    fn scalar_operand(&self, id: NodeId) -> String {
        match *self.graph.node(id) {
            Node::Const(c) => konst(c),
            Node::Input { index, .. } => format!("qs[{index}]"),
            _ => format!("u{id}"),
        }
    }

    fn scalar_node(&self, node: &Node) -> String {
        scalar_expr(node, &mut |id| self.scalar_operand(id))
    }

    /// A vector operand in the block code; drifts row `j` on its first use.
    fn operand(&self, out: &mut String, drifted: &mut [bool], id: NodeId) -> String {
        match *self.graph.node(id) {
            Node::Const(c) => format!("B({})", konst(c)),
            Node::Input { arg, index } if arg == self.lane_arg() => {
                self.drift(out, drifted, index as usize);
                format!("q{index}_@")
            }
            Node::Input { index, .. } => format!("B(qs[{index}])"),
            _ if self.plan.uniform[id as usize] => format!("B(u{id})"),
            _ => format!("v{id}_@"),
        }
    }

    /// `q_j += c_j p_j` in the block, once per stage (`p_j` kept for the kick).
    fn drift(&self, out: &mut String, drifted: &mut [bool], j: usize) {
        if drifted[j] {
            return;
        }
        drifted[j] = true;
        let n = self.n;
        let _ = writeln!(
            out,
            "  vd p{j}_@ = LD(xb + {p} * stride + @O); vd q{j}_@ = LD(xb + {j} * stride + @O) + B(c[{j}]) * p{j}_@; ST(xb + {j} * stride + @O, q{j}_@);",
            p = n + j
        );
    }

    fn kick(&self, out: &mut String, drifted: &mut [bool], j: usize, f: &str) {
        self.drift(out, drifted, j);
        let _ = writeln!(
            out,
            "  ST(xb + {} * stride + @O, p{j}_@ - dh * {f});",
            self.n + j
        );
    }

    fn vector_node(&self, out: &mut String, drifted: &mut [bool], node: &Node) -> String {
        vector_expr(node, &mut |id| self.operand(out, drifted, id))
    }

    /// The uniform values: scalar code, once per call (orbit) or per stage (tangent).
    fn uniforms(&self, out: &mut String) {
        for &id in &self.plan.uniform_order {
            let e = self.scalar_node(self.graph.node(id));
            let _ = writeln!(out, "      const double u{id} = {e};");
        }
    }

    /// Drift, force and kick of one block within one stage, in the Cranelift kernel's order
    /// (rows drifted on first use, each row's kick after its drift).
    ///
    /// A block is two units of `LANES` lanes (two vectors per value, independent chains):
    /// each statement is written once with the placeholders `_@` (name suffix) and `@O` (lane
    /// offset) and emitted once per unit, interleaved.
    fn block(&self, out: &mut String) {
        let mut body = String::new();
        self.block_statements(&mut body);
        for line in body.lines() {
            for (suffix, offset) in [("_0", "0"), ("_1", "LANES")] {
                let _ = writeln!(out, "{}", line.replace("_@", suffix).replace("@O", offset));
            }
        }
    }

    fn block_statements(&self, out: &mut String) {
        let (graph, plan) = (self.graph, self.plan);
        let outs = outputs_by_node(plan, graph.len());
        let mut drifted = vec![false; self.n];
        for &id in &plan.varying_order {
            let e = self.vector_node(out, &mut drifted, graph.node(id));
            let _ = writeln!(out, "  const vd v{id}_@ = {e};");
            for &j in &outs[id as usize] {
                self.kick(out, &mut drifted, j, &format!("v{id}_@"));
            }
        }
        for (j, &o) in plan.outputs.iter().enumerate() {
            if plan.uniform[o as usize] || is_leaf(graph.node(o)) {
                self.drift(out, &mut drifted, j);
                let f = self.operand(out, &mut drifted, o);
                self.kick(out, &mut drifted, j, &f);
            }
        }
        for j in 0..self.n {
            self.drift(out, &mut drifted, j);
        }
    }

    fn write(&self, out: &mut String) {
        let n = self.n;
        let (name, lead) = if self.tangent {
            ("chaoscope_tangent_steps", "const double *stages, ")
        } else {
            ("chaoscope_orbit_steps", "")
        };
        let _ = writeln!(
            out,
            "void {name}({lead}double *restrict x, size_t stride, size_t lanes, uint64_t n_steps, \
             const double *drift, const double *kick, size_t n_kicks, const double *w, \
             double *scratch, const uintptr_t *env) {{"
        );
        let _ = writeln!(
            out,
            "  const size_t end = lanes - lanes % BLOCK;\n  if (end == 0 || n_steps == 0) return;\n  double c[{n}];"
        );
        if !self.tangent {
            let _ = writeln!(out, "  const double *qs = 0; (void)qs;");
            self.uniforms(out);
        }
        let _ = writeln!(
            out,
            "  for (uint64_t s = 0; s < n_steps; s++) {{\n    for (size_t i = 0; i < n_kicks; i++) {{\n      const double ch = drift[i];\n      const vd dh = B(kick[i]);\n      if (w) {{ for (size_t j = 0; j < {n}; j++) c[j] = ch * w[j]; }} else {{ for (size_t j = 0; j < {n}; j++) c[j] = ch; }}"
        );
        if self.tangent {
            let _ = writeln!(
                out,
                "      const double *qs = stages + (s * n_kicks + i) * {n}; (void)qs;"
            );
            self.uniforms(out);
        }
        let _ = writeln!(
            out,
            "      for (size_t o = 0; o < end; o += BLOCK) {{\n  double *xb = x + o; (void)dh;"
        );
        self.block(out);
        let _ = writeln!(
            out,
            "      }}\n    }}\n    {{\n      const double ch = drift[n_kicks];\n      if (w) {{ for (size_t j = 0; j < {n}; j++) c[j] = ch * w[j]; }} else {{ for (size_t j = 0; j < {n}; j++) c[j] = ch; }}\n      for (size_t o = 0; o < end; o += LANES) {{\n        double *xb = x + o;\n        for (size_t j = 0; j < {n}; j++) ST(xb + j * stride, LD(xb + j * stride) + B(c[j]) * LD(xb + ({n} + j) * stride));\n      }}\n    }}\n  }}\n}}"
        );
    }
}
