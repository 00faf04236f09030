//! The system C compiler: which one and with which flags, the identity of the code it
//! targets, and every run of it in a process group of its own, stopped at a cancel, at
//! SIGINT/SIGTERM of this process or at its deadline.

use std::path::{Path, PathBuf};
use std::process::{Command, ExitStatus, Stdio};
use std::sync::OnceLock;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use super::Mode;
use super::cache::{CacheDir, WorkDir, digest_hex, read_regular};
use crate::jit::JitError;
/// Which C compiler builds the kernels, and where their cache lives.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct CCompiler {
    /// The compiler program (`cc`, `gcc`, `clang`, or a path).
    pub program: PathBuf,
    /// Where compiled kernels are kept by content hash.
    pub cache_dir: PathBuf,
    /// The instruction set the kernels are built for (`-march=`): `native` (the host's), or a
    /// named one such as `x86-64-v3` (AVX2 without AVX-512), for comparing instruction sets on
    /// one machine or for one set of kernels on machines of different CPUs. Checked at the
    /// build ([`CCompiler::flags`]).
    pub march: String,
}

/// The compiler's flags besides `-march` (all part of the cache key). `-O2`: the body is
/// straight-line code, which `-O3` does not improve; `-ffp-contract=off`: no fused
/// multiply-add; `-fno-math-errno`: `sqrt` without the `errno` branch (same result). The
/// instruction set (`-march=native` by default, [`CCompiler::march`]) changes the vector width,
/// never a result: these flags fix the IEEE operations and their order.
const FLAGS: [&str; 7] = [
    "-O2",
    "-ffp-contract=off",
    "-fno-math-errno",
    "-fno-strict-aliasing",
    "-fPIC",
    "-shared",
    "-w",
];

/// The longest `-march` value accepted.
const MAX_MARCH: usize = 64;

impl CCompiler {
    /// The compiler `program` with its cache in `cache_dir`, building for this host
    /// (`-march=native`).
    pub fn new(program: impl Into<PathBuf>, cache_dir: impl Into<PathBuf>) -> CCompiler {
        CCompiler {
            program: program.into(),
            cache_dir: cache_dir.into(),
            march: "native".to_owned(),
        }
    }

    /// `-march=` [`Self::march`]. An instruction set that is not a plain name (letters,
    /// digits, `-`, `_`, `.`, `+`, at most 64, not starting with `-`) is an error of the C
    /// build, said in its one line (the command goes on with the Cranelift kernels), so no
    /// value can smuggle another flag in.
    pub fn march_flag(&self) -> Result<String, JitError> {
        let m = &self.march;
        let plain = |c: char| c.is_ascii_alphanumeric() || "-_.+".contains(c);
        if m.is_empty() || m.len() > MAX_MARCH || !m.chars().all(plain) || m.starts_with('-') {
            return Err(JitError::CCompiler(format!(
                "CHAOSCOPE_CC_MARCH='{m}' is not an instruction set name (such as native, \
                 x86-64-v3 or x86-64-v4)"
            )));
        }
        Ok(format!("-march={m}"))
    }

    /// The build's flags: [`Self::march_flag`] and the fixed ones.
    pub(crate) fn flags(&self) -> Result<Vec<String>, JitError> {
        let mut flags = vec![self.march_flag()?];
        flags.extend(FLAGS.iter().map(|f| (*f).to_owned()));
        Ok(flags)
    }

    /// From the environment: `CHAOSCOPE_CC` names the compiler (`none` or empty: no C
    /// kernels, Cranelift's are used), else `cc`; `CHAOSCOPE_CC_MARCH` the instruction set
    /// ([`Self::march`]), else `native`; `CHAOSCOPE_KERNEL_CACHE` the cache directory,
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
        let march = std::env::var_os("CHAOSCOPE_CC_MARCH")
            .map_or_else(|| "native".to_owned(), |m| m.to_string_lossy().into_owned());
        Some(CCompiler {
            program,
            cache_dir,
            march,
        })
    }

    /// What the compiler and these flags target: its predefined macros (version, ISA
    /// features of its `-march`), hashed into every cache key. Runs the compiler once
    /// ([`run_compiler`]: a deadline, a cancel), its answer written to a file of the build
    /// directory `work` (a pipe left unread would stall a compiler with much to say).
    ///
    /// A named instruction set (not `native`) is checked against the host's: code for features
    /// this CPU lacks would die of an illegal instruction, so every feature macro its `-march`
    /// defines (`__AVX512F__`, `__FMA__`, ...) must be defined by `-march=native` too, else the
    /// build is refused in one line naming the missing ones. This also keeps a cache shared by
    /// machines of different CPUs safe: the identity of a named set is the same on all of them,
    /// and only a machine that has its features gets one.
    fn target_identity(&self, work: &WorkDir, cancel: &AtomicBool) -> Result<String, JitError> {
        let macros = self.macros(&self.march, work, cancel)?;
        if self.march != "native" {
            let host = self.macros("native", work, cancel)?;
            let missing: Vec<&str> = feature_macros(&macros)
                .filter(|m| !feature_macros(&host).any(|h| h == *m))
                .map(|m| m.trim_matches('_'))
                .collect();
            if !missing.is_empty() {
                return Err(JitError::CCompiler(format!(
                    "CHAOSCOPE_CC_MARCH='{}' asks for {}, which this CPU does not have (its code \
                     would stop at an illegal instruction); name an instruction set of this \
                     CPU, or native",
                    self.march,
                    missing.join(", ")
                )));
            }
        }
        let mut macros: Vec<&str> = macros.lines().collect();
        macros.sort_unstable();
        Ok(digest_hex(macros.join("\n").as_bytes()))
    }

    /// Runs [`Self::target_identity`]'s check of [`Self::march`] against this CPU in a private
    /// directory under `scratch` (the compiler's answers are written there): for a program
    /// beside the kernels (the bench's C yardsticks) built for the same instruction set. Ok
    /// with the `-march` flag to use.
    pub fn checked_march_flag(&self, scratch: &Path) -> Result<String, JitError> {
        let flag = self.march_flag()?;
        let work = WorkDir::new(scratch)?;
        self.target_identity(&work, &AtomicBool::new(false))?;
        Ok(flag)
    }

    /// The compiler's predefined macros with `-march=march`.
    fn macros(&self, march: &str, work: &WorkDir, cancel: &AtomicBool) -> Result<String, JitError> {
        let macros_path = work.0.join("macros");
        let log_path = work.0.join("target-messages");
        let create = |p: &Path| {
            std::fs::File::create(p)
                .map_err(|e| JitError::CCompiler(format!("cannot write {}: {e}", p.display())))
        };
        let mut command = Command::new(&self.program);
        command
            .arg(format!("-march={march}"))
            .args(["-ffp-contract=off", "-E", "-dM", "-x", "c"])
            .arg("/dev/null")
            .stdin(Stdio::null())
            .stdout(create(&macros_path)?)
            .stderr(create(&log_path)?);
        let status = run_compiler(self, &mut command, cancel, "reporting its target")?;
        if !status.success() {
            return Err(JitError::CCompiler(format!(
                "the C compiler '{}' failed to report its target for -march={march} ({status}): {}",
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
        Ok(String::from_utf8_lossy(&out).into_owned())
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
            "{}\n{}\n{} {} {} {}.{} {}.{}\n{cpu}\n-march={} (features checked)",
            found.display(),
            real.display(),
            m.dev(),
            m.ino(),
            m.size(),
            m.mtime(),
            m.mtime_nsec(),
            m.ctime(),
            m.ctime_nsec(),
            self.march
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

/// The instruction set features among the predefined `macros`: on x86 the names of the form
/// `__NAME__` defined as 1 with an upper-case letter in `NAME` (`__AVX2__`, `__3dNOW__`; not
/// the CPU and tuning names such as `__haswell__`, which differ between sets without being
/// features), on Arm `__ARM_NEON` and the `__ARM_FEATURE_*` names. The compiler's other macros
/// are the same whatever `-march` says.
fn feature_macros(macros: &str) -> impl Iterator<Item = &str> {
    macros.lines().filter_map(|line| {
        let mut words = line.strip_prefix("#define ")?.split_whitespace();
        let (name, value) = (words.next()?, words.next());
        if name == "__ARM_NEON" || name.starts_with("__ARM_FEATURE_") {
            return Some(name);
        }
        let inner = name.strip_prefix("__")?.strip_suffix("__")?;
        let feature = value == Some("1")
            && inner.chars().any(|c| c.is_ascii_uppercase())
            && inner.chars().all(|c| c.is_ascii_alphanumeric() || c == '_')
            && ![
                "STDC",
                "STDC_HOSTED",
                "LP64",
                "ELF",
                "PIC",
                "PIE",
                "OPTIMIZE",
            ]
            .contains(&inner);
        feature.then_some(name)
    })
}

/// The answers of the CPU identification instruction that `-march=native` reads (vendor,
/// family and model, feature leaves, brand string), without the per-core fields (APIC
/// identifiers, topology, hybrid core types), and which wide registers the operating system
/// enables: equal on every core of one machine and on machines of one CPU model.
#[cfg(target_arch = "x86_64")]
pub(crate) fn cpu_identity() -> Option<String> {
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
pub(crate) fn cpu_identity() -> Option<String> {
    None
}

/// compiler's target identity for that fingerprint.
pub(crate) const TARGET_RECORD: &str = "target-";

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
pub(crate) fn identity(
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

pub(crate) fn first_lines(bytes: &[u8]) -> String {
    let text = String::from_utf8_lossy(bytes);
    let lines: Vec<&str> = text
        .lines()
        .filter(|l| !l.trim().is_empty())
        .take(3)
        .collect();
    // A compiler that lists what it would have accepted (gcc's valid `-march` names) says a
    // thousand characters; one line of the command's output keeps the start.
    const MAX: usize = 400;
    let joined = lines.join(" | ");
    match joined.char_indices().nth(MAX) {
        _ if lines.is_empty() => "no message".into(),
        Some((cut, _)) => format!("{} ...", &joined[..cut]),
        None => joined,
    }
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
pub(crate) struct CompilerProcess(Option<std::process::Child>);

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
pub(crate) fn run_compiler(
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
/// Kills the compiler's process group (the driver and the compiler passes, assembler and
/// linker it started) and reaps the driver.
pub(crate) fn kill_group(child: &mut std::process::Child) {
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

#[cfg(test)]
mod tests {
    use super::feature_macros;

    /// The features of a named instruction set are what the host must have: x86's `__NAME__`
    /// macros (`__3dNOW__` too), Arm's `__ARM_NEON` and `__ARM_FEATURE_*` whatever their value;
    /// never a CPU or tuning name (`__haswell__`) or a macro every target has.
    #[test]
    fn feature_macros_are_the_instruction_set_features_of_x86_and_arm() {
        let macros = "#define __AVX2__ 1\n#define __3dNOW__ 1\n#define __haswell__ 1\n\
                      #define __tune_haswell__ 1\n#define __STDC_HOSTED__ 1\n#define __LP64__ 1\n\
                      #define __GNUC__ 12\n#define __SSE4_2__ 1\n#define __ARM_NEON 1\n\
                      #define __ARM_FEATURE_SVE 1\n#define __ARM_FEATURE_SVE_BITS 0\n\
                      #define __ARM_ARCH 8\n#define __k8 1\n";
        let found: Vec<&str> = feature_macros(macros).collect();
        assert_eq!(
            found,
            [
                "__AVX2__",
                "__3dNOW__",
                "__SSE4_2__",
                "__ARM_NEON",
                "__ARM_FEATURE_SVE",
                "__ARM_FEATURE_SVE_BITS"
            ]
        );
    }
}
