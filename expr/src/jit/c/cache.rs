//! The on-disk kernel cache: a directory provably the user's own, read through one checked
//! handle, entries regular files checked against their SHA-256 digests, build directories
//! that clean up after themselves.

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

use sha2::{Digest, Sha256};

use crate::jit::JitError;
/// SHA-256 of `bytes` in hexadecimal: what the digest file beside a library holds.
pub(crate) fn digest_hex(bytes: &[u8]) -> String {
    Sha256::digest(bytes)
        .iter()
        .map(|b| format!("{b:02x}"))
        .collect()
}

/// The kernel cache directory, opened once per build and checked through that handle: a real
/// directory (a symbolic link is refused, not followed) owned by this user and writable by no
/// one else. Files are read relative to the handle, so the directory checked is the one read,
/// even if its path is renamed meanwhile.
pub(crate) struct CacheDir {
    path: PathBuf,
    #[cfg(unix)]
    fd: std::os::fd::OwnedFd,
}

/// Why a cache directory is refused, for the one-line error.
pub(crate) const FOREIGN_CODE: &str = "a library someone else put there would run as you";

impl CacheDir {
    pub(crate) fn open(path: &Path) -> Result<CacheDir, JitError> {
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
    pub(crate) fn stat(&self, file: Option<&std::fs::File>) -> std::io::Result<libc::stat> {
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
    pub(crate) fn read(&self, name: &str) -> Result<Option<Vec<u8>>, JitError> {
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
    pub(crate) fn verified(&self, lib: &str, digest: &str) -> Result<Option<Vec<u8>>, JitError> {
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
pub(crate) fn file_kind(mode: libc::mode_t) -> &'static str {
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
pub(crate) fn read_regular(path: &Path) -> Result<Vec<u8>, String> {
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

/// Owned by this user and writable by no one else; else why not.
#[cfg(unix)]
pub(crate) fn check_owner(meta: &libc::stat) -> Result<(), String> {
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
pub(crate) const BUILD_DIR: &str = "build-";

/// A build directory of this process, removed with its contents when dropped.
pub(crate) struct WorkDir(pub(crate) PathBuf);

impl WorkDir {
    pub(crate) fn new(cache_dir: &Path) -> Result<WorkDir, JitError> {
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

pub(crate) fn remove_abandoned_builds(cache_dir: &Path) {
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

pub(crate) fn process_exists(pid: i32) -> bool {
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
