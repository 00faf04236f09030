//! Loading a compiled kernel library from the bytes checked against its digest.

use std::path::Path;

use super::{CFusedFn, CKernels, COrbitFn, CTangentFn};
use crate::jit::JitError;
/// Loads a compiled library from `bytes` (those of `path`, already checked against their
/// digest) and checks that it is the one its name says (it carries its hash).
pub(crate) fn open_checked(
    bytes: &[u8],
    path: &Path,
    hash: &str,
) -> Result<(libloading::Library, Option<std::fs::File>), JitError> {
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
    Ok((library, memory_file))
}

/// The step kernels of a library [`open_checked`] opened.
pub(crate) fn step_kernels(
    library: libloading::Library,
    memory_file: Option<std::fs::File>,
    path: &Path,
    tangent: bool,
    cached: bool,
) -> Result<CKernels, JitError> {
    let fail = |e: String| {
        JitError::CCompiler(format!(
            "cannot load the compiled kernels {}: {e}",
            path.display()
        ))
    };
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
    let fused = unsafe { library.get::<CFusedFn>(super::fused::SYMBOL) }
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
pub(crate) fn open_library(
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
