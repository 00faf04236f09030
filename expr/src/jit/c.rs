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
//! remembered in the cache under a fingerprint of the compiler's file and the CPU (`compiler::identity`):
//! a load from the cache runs no compiler.
//!
//! Loading a library runs its code (its constructors run at `dlopen`), so the cache is trusted
//! only as far as it is provably the user's own (`cache::CacheDir`): the directory must be a real
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
//! the target query) runs through `compiler::run_compiler`, in a process group of its own that dies
//! with its parent, stopped at a cancel, at SIGINT/SIGTERM of this process, or at its deadline
//! (`CHAOSCOPE_CC_TIMEOUT`, [`compiler::DEFAULT_CC_TIMEOUT`]); a lookup that only loads runs none. Cache
//! entries are opened without blocking and only as regular files (a FIFO planted there is
//! refused in one line). A compiler that hangs, crashes or lies thus costs at most its deadline
//! and one line, and the caller runs the Cranelift kernels, which give the same bits.
//!
//! I/O: the C compiler runs in `compiler`, the cache directory is read and written in `cache`
//! and `load`: the second exception (after `table`) to the crate's no-I/O rule, and only the
//! batched kernel's lazy construction calls it.

pub(crate) mod cache;
pub(crate) mod compiler;
pub(crate) mod emit;
pub(crate) mod fused;
pub(crate) mod lattice_steps;
pub(crate) mod load;
pub(crate) mod taylor;

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use sha2::{Digest, Sha256};

use super::{JitError, cb_table};
use crate::graph::Tabulated;

use cache::{CacheDir, WorkDir, digest_hex, read_regular, remove_abandoned_builds};
pub use compiler::CCompiler;
use compiler::{first_lines, identity, run_compiler};
pub(crate) use emit::{emit_nodes, konst, prelude, source, vector_helpers};
use load::{open_checked, step_kernels};

/// Lanes per block of the C kernels: one value is two 4-lane vectors (two AVX2 registers, or
/// four SSE2 ones), two independent dependency chains per operation. The batched kernel's chunks (8 or 32 lanes on
/// AVX2) are whole blocks.
pub const C_BLOCK_LANES: usize = 8;

/// The orbit kernel's C signature: [`super::OrbitStepsFnPtr`] plus the callback table.
pub(crate) type COrbitFn = unsafe extern "C" fn(
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
pub(crate) type CTangentFn = unsafe extern "C" fn(
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

/// The fused one-orbit kernel's C signature ([`fused`]): the orbit `x` (`2N`), `k`
/// tangent vectors `v` (`k` times `2N`), the splitting's coefficients, the inverse masses
/// (null: unit masses) and the callback table.
pub(crate) type CFusedFn = unsafe extern "C" fn(
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

/// `env[0..ENV_BINARY]` are the unary operations called back ([`crate::ops::called`]).
pub(crate) const ENV_BINARY: usize = crate::ops::UNARY_CALLS;
/// `env[ENV_BINARY..ENV_TABLE]` are the binary operations called back
/// ([`crate::ops::called_binary`]).
pub(crate) const ENV_TABLE: usize = ENV_BINARY + crate::ops::BINARY_CALLS;
/// `env[ENV_TABLES + t]` is table `t` (a `*const Arc<dyn Tabulated>`); after the tables, the
/// array parameters' values (a `*const f64` each) the lattice loops read.
pub(crate) const ENV_TABLES: usize = ENV_TABLE + 1;

/// The callback table the kernels read: the Rust callbacks, then the table pointers (into
/// `tables`, which must outlive every call), then the arrays' (which must too).
pub(crate) fn env(tables: &[Arc<dyn Tabulated>], arrays: &[Arc<[f64]>]) -> Box<[usize]> {
    let mut env: Vec<usize> = crate::ops::called().map(|d| d.eval as usize).collect();
    env.extend(crate::ops::called_binary().map(|d| d.eval as usize));
    env.push(cb_table as *const () as usize);
    for t in tables {
        env.push(t as *const Arc<dyn Tabulated> as usize);
    }
    for a in arrays {
        env.push(a.as_ptr() as usize);
    }
    env.into_boxed_slice()
}

/// Whether [`build`] may compile or only load from the cache.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Mode {
    Build,
    /// Load a cached library or fail with [`JitError::NotCached`]; the cache is not created and
    /// no compiler runs.
    Load,
}

/// Prefix of the target records in the cache: `target-<hash of the fingerprint>` holds the
/// A loaded C kernel library.
pub(crate) struct CKernels {
    /// Keeps the code mapped while the function pointers are in use.
    pub _library: libloading::Library,
    /// The memory file the library was loaded from, open while it is loaded (after it in
    /// drop order; see `open_library`).
    pub _memory_file: Option<std::fs::File>,
    pub orbit: COrbitFn,
    pub tangent: Option<CTangentFn>,
    /// The fused one-orbit kernel, where the source has one ([`fused`]).
    pub fused: Option<CFusedFn>,
    /// Whether the library came from the cache (no compilation in this call).
    pub cached: bool,
    pub path: PathBuf,
}

/// Compiles (or loads from the cache) the C kernels of the source `src` (with a tangent kernel
/// when `tangent`); stops the compiler and returns [`JitError::Cancelled`] once `cancel` is set.
pub(crate) fn build(
    src: &str,
    tangent: bool,
    cc: &CCompiler,
    cancel: &AtomicBool,
    mode: Mode,
) -> Result<(CKernels, Duration), JitError> {
    build_with(src, cc, cancel, mode, |library, memory, path, cached| {
        step_kernels(library, memory, path, tangent, cached)
    })
}

/// Compiles (or loads from the cache) the library of the source `src`, opened and checked to
/// be that source's, and hands it to `make` (with its cache path and whether it was cached)
/// for the symbols its caller needs.
pub(crate) fn build_with<T>(
    src: &str,
    cc: &CCompiler,
    cancel: &AtomicBool,
    mode: Mode,
    make: impl Fn(libloading::Library, Option<std::fs::File>, &Path, bool) -> Result<T, JitError>,
) -> Result<(T, Duration), JitError> {
    let start = Instant::now();
    if mode == Mode::Load && !cc.cache_dir.exists() {
        return Err(JitError::NotCached);
    }
    let flags = cc.flags()?;
    let cache = CacheDir::open(&cc.cache_dir)?;
    let identity = identity(cc, &cache, cancel, mode)?;
    let mut h = Sha256::new();
    h.update(cc.program.to_string_lossy().as_bytes());
    h.update([0]);
    h.update(flags.join(" ").as_bytes());
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
        && let Ok(k) = open_checked(&bytes, &lib_path, &hash)
            .and_then(|(library, memory)| make(library, memory, &lib_path, true))
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
        .args(&flags)
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
    let (library, memory) = open_checked(&bytes, &lib_path, &hash)?;
    let k = make(library, memory, &lib_path, false)?;
    Ok((k, start.elapsed()))
}
