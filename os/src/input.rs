//! The one way a file named by a user (an argument, a path inside a config or a recording) is
//! opened for reading.
//!
//! Why not `File::open`: opening a FIFO for reading blocks until some process opens it for
//! writing, and the blocked `open(2)` is restarted after every signal, so a command handed a
//! FIFO (a recording whose config names its table at one, say: anyone can send such a file)
//! hung deaf to SIGINT and SIGTERM. A character device can block the same way or never end,
//! a socket cannot be opened at all, and a directory reads as an error far from its cause.
//! [`open_regular`] refuses every kind of file but a regular one without waiting: it looks at
//! the path first (so no device is ever opened: opening some has effects), then opens it
//! `O_NONBLOCK` (a FIFO swapped in after the look opens at once) and checks the opened file
//! itself, which is what is read.

use std::fmt;
use std::fs::{File, OpenOptions};
use std::io;
use std::os::unix::fs::{FileTypeExt, OpenOptionsExt};
use std::os::unix::io::AsRawFd;
use std::path::Path;

/// A path that names something other than a regular file, refused by [`open_regular`]; the
/// source of its [`io::Error`] (kind [`io::ErrorKind::InvalidInput`]), whose message reads
/// "a FIFO, not a regular file" after the caller's naming of the path.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct NotRegularFile {
    /// What the path is: "a FIFO", "a character device", "a block device", "a socket",
    /// "a directory" or "a special file" (an unknown type), as [`kind_of`] names it.
    pub kind: &'static str,
}

impl fmt::Display for NotRegularFile {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}, not a regular file", self.kind)
    }
}

impl std::error::Error for NotRegularFile {}

impl NotRegularFile {
    /// The refusal carried by `e`, if `e` is one of [`open_regular`]'s.
    pub fn of(e: &io::Error) -> Option<Self> {
        e.get_ref()?.downcast_ref::<Self>().copied()
    }

    fn into_io(self) -> io::Error {
        io::Error::new(io::ErrorKind::InvalidInput, self)
    }
}

/// What a file of type `t` is, in the words of an error; `None` for a regular file. The one
/// naming of file types for readers and writers alike (a writer's `t` comes from `lstat`, so it
/// can be a link).
pub fn kind_of(t: std::fs::FileType) -> Option<&'static str> {
    if t.is_file() {
        return None;
    }
    Some(if t.is_fifo() {
        "a FIFO"
    } else if t.is_char_device() {
        "a character device"
    } else if t.is_block_device() {
        "a block device"
    } else if t.is_socket() {
        "a socket"
    } else if t.is_dir() {
        "a directory"
    } else if t.is_symlink() {
        "a symbolic link"
    } else {
        "a special file"
    })
}

/// Opens the regular file at `path` (links followed) for reading, close-on-exec, without ever
/// waiting on a FIFO or a device: anything else is refused with a [`NotRegularFile`] error.
/// The file returned reads blocking, as any regular file does.
pub fn open_regular(path: &Path) -> io::Result<File> {
    // The look first: no device is opened, no socket gets an ENXIO that says nothing.
    if let Some(kind) = kind_of(std::fs::metadata(path)?.file_type()) {
        return Err(NotRegularFile { kind }.into_io());
    }
    // Rust opens with O_CLOEXEC; O_NOCTTY in case a terminal was put at the path since.
    let file = OpenOptions::new()
        .read(true)
        .custom_flags(libc::O_NONBLOCK | libc::O_NOCTTY)
        .open(path)?;
    // The opened file is what gets read, whatever sits at the path now.
    if let Some(kind) = kind_of(file.metadata()?.file_type()) {
        return Err(NotRegularFile { kind }.into_io());
    }
    let fd = file.as_raw_fd();
    // SAFETY: fcntl on a descriptor this function owns, with integer arguments only.
    let flags = unsafe { libc::fcntl(fd, libc::F_GETFL) };
    if flags < 0 || unsafe { libc::fcntl(fd, libc::F_SETFL, flags & !libc::O_NONBLOCK) } < 0 {
        return Err(io::Error::last_os_error());
    }
    Ok(file)
}

/// The whole of the regular file at `path` ([`open_regular`]).
pub fn read_regular(path: &Path) -> io::Result<Vec<u8>> {
    let mut bytes = Vec::new();
    io::Read::read_to_end(&mut open_regular(path)?, &mut bytes)?;
    Ok(bytes)
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::ffi::CString;
    use std::io::Read;
    use std::os::unix::ffi::OsStrExt;

    fn mkfifo(path: &Path) {
        let c = CString::new(path.as_os_str().as_bytes()).unwrap();
        // SAFETY: a NUL-terminated path.
        assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o600) }, 0);
    }

    fn refusal(path: &Path) -> (NotRegularFile, String) {
        let e = open_regular(path).unwrap_err();
        assert_eq!(e.kind(), io::ErrorKind::InvalidInput, "{e}");
        (NotRegularFile::of(&e).unwrap(), e.to_string())
    }

    #[test]
    fn regular_files_open_and_read_blocking() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("a.toml");
        std::fs::write(&path, "x = 1\n").unwrap();
        let link = dir.path().join("link.toml");
        std::os::unix::fs::symlink(&path, &link).unwrap();
        for p in [&path, &link] {
            let mut file = open_regular(p).unwrap();
            // SAFETY: F_GETFL/F_GETFD on an open descriptor.
            let flags = unsafe { libc::fcntl(file.as_raw_fd(), libc::F_GETFL) };
            assert_eq!(flags & libc::O_NONBLOCK, 0, "O_NONBLOCK left set");
            let fd_flags = unsafe { libc::fcntl(file.as_raw_fd(), libc::F_GETFD) };
            assert_ne!(fd_flags & libc::FD_CLOEXEC, 0, "not close-on-exec");
            let mut s = String::new();
            file.read_to_string(&mut s).unwrap();
            assert_eq!(s, "x = 1\n");
        }
    }

    #[test]
    fn special_files_are_refused_without_waiting() {
        let dir = tempfile::tempdir().unwrap();
        // No writer ever opens this FIFO: a blocking open would never return.
        let fifo = dir.path().join("table.csv");
        mkfifo(&fifo);
        let (r, message) = refusal(&fifo);
        assert_eq!(r.kind, "a FIFO");
        assert_eq!(message, "a FIFO, not a regular file");
        // Through a link too.
        let link = dir.path().join("link.csv");
        std::os::unix::fs::symlink(&fifo, &link).unwrap();
        assert_eq!(refusal(&link).0.kind, "a FIFO");

        assert_eq!(refusal(dir.path()).0.kind, "a directory");
        assert_eq!(refusal(Path::new("/dev/null")).0.kind, "a character device");

        let socket = dir.path().join("s.sock");
        let _listener = std::os::unix::net::UnixListener::bind(&socket).unwrap();
        assert_eq!(refusal(&socket).0.kind, "a socket");

        let missing = open_regular(&dir.path().join("missing")).unwrap_err();
        assert_eq!(missing.kind(), io::ErrorKind::NotFound);
        assert!(NotRegularFile::of(&missing).is_none());
    }
}
