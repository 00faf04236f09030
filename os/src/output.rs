//! The one way chaoscope writes a file (recordings, replays, recoveries, maps and merges, CSV
//! tables, plots, charts, sections; the command and the Python package alike).
//!
//! An output `DIR/NAME` is written into its *in-progress file* `DIR/NAME.partial`:
//!
//! - created exclusively (`O_CREAT | O_EXCL`, so never through a symbolic link, dangling or
//!   not), with the mode the umask gives, in the target's own directory (so the final rename
//!   stays on one file system);
//! - locked (`flock`, exclusive) for as long as the writer lives: a second writer of the same
//!   output is refused with one line, whoever started first, and a lock found free means the
//!   file's writer is gone;
//! - renamed onto `DIR/NAME` only when complete ([`Output::commit`]: `fsync` of the file, the
//!   rename, `fsync` of the directory), without replacing an existing file unless asked
//!   (`--force`), and never replacing anything but a regular file or a symbolic link (the link
//!   itself, not what it points to);
//! - on failure removed, or, where its content is worth keeping (a recording's complete
//!   chunks, a map's points), left in place and named in the error ([`Output::keep`]).
//!
//! So `DIR/NAME` only ever holds a complete file, a killed writer leaves `DIR/NAME.partial`
//! (which `chaoscope recover` salvages, and which a map resumes from), and no device, FIFO,
//! directory or file of someone else is ever truncated or unlinked: the only files this module
//! removes are in-progress files it created itself in this process, and in-progress files of
//! a writer that is gone (its lock free) when the caller asks to discard or resume them. An
//! output that is one of the command's inputs (the same device and inode: a hard link, a
//! symbolic link, another path) is refused.
//!
//! What is not promised: a path component that another user can change while the command runs
//! (a directory writable by others without the sticky bit) can still redirect the output; use a
//! directory of your own. Between the last check and the rename, another process of the same
//! user could put a non-regular file at the target; `--force` would then replace it.

use std::ffi::CString;
use std::fs::{File, OpenOptions};
use std::io;
use std::os::unix::ffi::OsStrExt;
use std::os::unix::fs::{MetadataExt, OpenOptionsExt};
use std::os::unix::io::AsRawFd;
use std::path::{Path, PathBuf};

use crate::signals::Cleanup;

/// The suffix of in-progress files.
pub const PARTIAL_SUFFIX: &str = ".partial";

/// How an output is opened.
#[derive(Debug, Clone, Default)]
pub struct OutputOptions {
    /// Replace an existing target (`--force`). Without it an existing target is refused.
    pub replace: bool,
    /// Create the target's directory and its parents when missing.
    pub create_dir: bool,
    /// Files the command reads: the target must not be any of them.
    pub inputs: Vec<PathBuf>,
    /// What to do with an in-progress file whose writer is gone.
    pub leftover: Leftover,
    /// An output not completed (an error, a failed commit, a panic) leaves its in-progress file
    /// in place instead of removing it, unless it is empty: a recording's complete chunks, a
    /// map's points are worth keeping.
    pub keep_failed: bool,
}

/// What to do with the in-progress file of a writer that is gone (killed, or stopped by a
/// failed write), found at `NAME.partial`.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub enum Leftover {
    /// Refuse with one line naming it (it may hold data worth salvaging).
    #[default]
    Refuse,
    /// Discard it and start afresh.
    Discard,
    /// Hand it to the caller to read ([`Output::leftover`]); the caller then starts its new
    /// in-progress file with [`Output::start_fresh`] and either puts it in the leftover's place
    /// with [`Output::adopt_fresh`] once it holds what the leftover held (a map resuming), or
    /// commits it, leaving the leftover as it was (`recover` reading it).
    Resume,
}

#[derive(Debug, thiserror::Error)]
pub enum OutputError {
    #[error("{} already exists (pass --force to replace it)", .0.display())]
    Exists(PathBuf),
    #[error(
        "{} is {kind}, not a regular file: chaoscope writes only regular files and never \
         replaces or removes anything else",
        path.display()
    )]
    NotRegular { path: PathBuf, kind: &'static str },
    #[error("{} is the input {} (the same file): choose another output", target.display(), input.display())]
    IsInput { target: PathBuf, input: PathBuf },
    #[error(
        "{} is being written by another live process ({}holds {} locked); wait for it to \
         finish or choose another output",
        target.display(),
        holder(*pid),
        partial.display()
    )]
    Busy {
        target: PathBuf,
        partial: PathBuf,
        /// The live writer, where the kernel's lock table names it.
        pid: Option<u32>,
    },
    /// The target itself is a file another live process writes (its in-progress file, named
    /// as an output): never written over, renamed over or removed, whatever the options.
    #[error(
        "{} is the in-progress file of another live process ({}holds it locked): chaoscope \
         never replaces or removes a file being written, even with --force; wait for it to \
         finish or choose another output",
        path.display(),
        holder(*pid)
    )]
    Live { path: PathBuf, pid: Option<u32> },
    /// This writer's in-progress file is no longer at its name (renamed over or removed by
    /// another process): what it wrote cannot reach the target, which stays as it was.
    #[error(
        "{} was replaced or removed by another process while this one wrote it: what this \
         process wrote is lost and {} was left as it was",
        partial.display(),
        target.display()
    )]
    Replaced { partial: PathBuf, target: PathBuf },
    #[error(
        "{} holds the unfinished output of a writer that stopped before finishing it{hint}; \
         pass --force to discard it",
        partial.display()
    )]
    Leftover { partial: PathBuf, hint: String },
    #[error(
        "{} is not an in-progress file of chaoscope ({why}); remove it or choose another output",
        partial.display()
    )]
    Foreign { partial: PathBuf, why: &'static str },
    /// The cause is in the message (no error source), so an error chain does not repeat it.
    #[error("{}: {what}: {cause}", path.display())]
    Io {
        path: PathBuf,
        what: &'static str,
        cause: io::Error,
    },
}

impl OutputError {
    fn io(path: &Path, what: &'static str, cause: io::Error) -> Self {
        Self::Io {
            path: path.to_path_buf(),
            what,
            cause,
        }
    }

    /// A [`OutputError::Leftover`] with a hint of what its content is good for.
    pub fn with_leftover_hint(self, hint: impl FnOnce(&Path) -> String) -> Self {
        match self {
            Self::Leftover { partial, .. } => {
                let hint = hint(&partial);
                Self::Leftover { partial, hint }
            }
            other => other,
        }
    }
}

/// `process N, which ` for a lock holder the kernel names, else `it `.
fn holder(pid: Option<u32>) -> String {
    match pid {
        Some(pid) => format!("process {pid}, which "),
        None => "it ".to_owned(),
    }
}

/// The process holding a `flock` on the file `meta` describes, from the kernel's lock table
/// (`/proc/locks`: `N: FLOCK ADVISORY WRITE PID MAJ:MIN:INODE ...`, the device in hex).
fn lock_holder(meta: &std::fs::Metadata) -> Option<u32> {
    let text = std::fs::read_to_string("/proc/locks").ok()?;
    let dev = meta.dev() as libc::dev_t;
    let want = format!(
        "{:02x}:{:02x}:{}",
        libc::major(dev),
        libc::minor(dev),
        meta.ino()
    );
    text.lines().find_map(|line| {
        let fields: Vec<&str> = line.split_whitespace().collect();
        // A blocked waiter's line starts `N: ->`; only holders count.
        (fields.len() >= 6 && fields[1] == "FLOCK" && fields[5] == want)
            .then(|| fields[4].parse().ok())
            .flatten()
    })
}

/// Whether another process holds a `flock` on the regular file at `path` (a live writer's
/// in-progress file, whatever its name), and which process if the kernel says. A shared lock
/// is taken for an instant, so two checkers never refuse each other; a file this process
/// cannot open is not an in-progress file of this user.
fn live_writer(path: &Path) -> Result<Option<Option<u32>>, OutputError> {
    let file = match OpenOptions::new()
        .read(true)
        .custom_flags(open_flags())
        .open(path)
    {
        Ok(file) => file,
        Err(_) => return Ok(None),
    };
    let meta = file
        .metadata()
        .map_err(|e| OutputError::io(path, "checking", e))?;
    if !meta.file_type().is_file() {
        return Ok(None);
    }
    // Closing the file releases the lock.
    Ok((!try_lock_shared(&file, path)?).then(|| lock_holder(&meta)))
}

/// The in-progress files this process left in place after a failure (`keep_failed`, or
/// [`Output::keep`]), for the command's error line to name.
static KEPT: std::sync::Mutex<Vec<PathBuf>> = std::sync::Mutex::new(Vec::new());

fn note_kept(path: &Path) {
    if let Ok(mut kept) = KEPT.lock()
        && !kept.iter().any(|k| k == path)
    {
        kept.push(path.to_path_buf());
    }
}

/// The in-progress files a failure of this process kept (what was written, worth salvaging or
/// resuming), each once: a command's error names them, so nothing it leaves is unnamed.
pub fn kept_after_failure() -> Vec<PathBuf> {
    KEPT.lock().map(|k| k.clone()).unwrap_or_default()
}

/// `NAME.partial` beside `target`.
pub fn partial_path(target: &Path) -> PathBuf {
    let mut s = target.as_os_str().to_owned();
    s.push(PARTIAL_SUFFIX);
    PathBuf::from(s)
}

/// What a file that is not a regular file is ([`crate::input::kind_of`]).
fn kind_of(meta: &std::fs::Metadata) -> &'static str {
    crate::input::kind_of(meta.file_type()).unwrap_or("a regular file")
}

fn identity(meta: &std::fs::Metadata) -> (u64, u64) {
    (meta.dev(), meta.ino())
}

/// Refuses a `target` that names no file: `.`, `..`, `/`, and `dir/` or `dir/.`, which have a
/// file name to `Path` (`dir`) but name a directory (the in-progress file would be `dir/.partial`).
fn names_a_file(target: &Path) -> Result<(), OutputError> {
    let bytes = target.as_os_str().as_bytes();
    let why = if bytes.ends_with(b"/") || bytes.ends_with(b"/.") {
        "it names a directory (it ends in '/'), not a file: give the file's name"
    } else if target.file_name().is_none() {
        "not a file name"
    } else {
        return Ok(());
    };
    Err(OutputError::io(
        target,
        "choosing the output",
        io::Error::new(io::ErrorKind::InvalidInput, why),
    ))
}

/// Checks `target` without touching anything: not one of the inputs, a regular file or a
/// symbolic link (or nothing) at that name, and absent unless `replace`. Commands that hand
/// the writing to another process (`run` to its recorder) check here first, so the user hears
/// before anything starts.
pub fn check_target(target: &Path, options: &OutputOptions) -> Result<(), OutputError> {
    names_a_file(target)?;
    let here = match std::fs::symlink_metadata(target) {
        Ok(meta) => Some(meta),
        Err(e) if e.kind() == io::ErrorKind::NotFound => None,
        Err(e) => return Err(OutputError::io(target, "checking the output", e)),
    };
    // The file a link at the target points to counts as the target for the input check.
    let pointed = std::fs::metadata(target).ok();
    for input in &options.inputs {
        let Ok(input_meta) = std::fs::metadata(input) else {
            continue;
        };
        let id = identity(&input_meta);
        if here.iter().chain(&pointed).any(|m| identity(m) == id) {
            return Err(OutputError::IsInput {
                target: target.to_path_buf(),
                input: input.clone(),
            });
        }
    }
    if let Some(meta) = &here {
        let t = meta.file_type();
        if !t.is_file() && !t.is_symlink() {
            return Err(OutputError::NotRegular {
                path: target.to_path_buf(),
                kind: kind_of(meta),
            });
        }
        if t.is_file()
            && let Some(pid) = live_writer(target)?
        {
            return Err(OutputError::Live {
                path: target.to_path_buf(),
                pid,
            });
        }
        if !options.replace {
            return Err(OutputError::Exists(target.to_path_buf()));
        }
    }
    Ok(())
}

/// An output being written: the locked in-progress file and where it goes when complete.
/// Dropped without [`Output::commit`] or [`Output::keep`], it removes its in-progress file (one
/// it created, unless `keep_failed` and not empty; a leftover handed over for resuming stays).
#[derive(Debug)]
pub struct Output {
    target: PathBuf,
    partial: PathBuf,
    /// The in-progress file at `partial`, locked.
    file: File,
    /// Whether `file` is ours to remove (created by this process, or emptied leftover).
    ours: bool,
    /// `Leftover::Resume`: the leftover is `file` until `adopt_fresh`.
    leftover: bool,
    /// A fresh in-progress file started beside the leftover (`start_fresh`), its path.
    fresh: Option<(PathBuf, File, Cleanup)>,
    replace: bool,
    keep_failed: bool,
    cleanup: Cleanup,
    done: bool,
}

impl Output {
    /// Opens the in-progress file of `target` (see the module documentation).
    pub fn create(target: &Path, options: &OutputOptions) -> Result<Self, OutputError> {
        let target = target.to_path_buf();
        names_a_file(&target)?;
        if options.create_dir
            && let Some(dir) = target.parent().filter(|d| !d.as_os_str().is_empty())
        {
            std::fs::create_dir_all(dir)
                .map_err(|e| OutputError::io(dir, "creating the directory", e))?;
        }
        let replace = options.replace;
        check_target(&target, options)?;
        let partial = partial_path(&target);
        // A signal between creating the file and registering it would leave it behind.
        let (file, created, cleanup) = crate::signals::critical(|| {
            let (file, created) = lock_partial(&target, &partial)?;
            let cleanup = if created {
                Cleanup::register(&partial)
            } else {
                Cleanup::none()
            };
            Ok::<_, OutputError>((file, created, cleanup))
        })?;
        let mut out = Self {
            cleanup,
            target,
            partial,
            file,
            ours: created,
            leftover: false,
            fresh: None,
            replace,
            keep_failed: options.keep_failed,
            done: false,
        };
        if !created {
            let len = out
                .file
                .metadata()
                .map_err(|e| OutputError::io(&out.partial, "reading", e))?
                .len();
            if len == 0 {
                // Nothing in it (its writer died at once, or another process created it a
                // moment before us and lost the lock race): ours now.
                out.ours = true;
                out.cleanup = Cleanup::register(&out.partial);
            } else {
                match options.leftover {
                    Leftover::Refuse => {
                        return Err(OutputError::Leftover {
                            partial: out.partial.clone(),
                            hint: String::new(),
                        });
                    }
                    Leftover::Discard => {
                        // Never an input (`replay NAME.partial --out NAME --force`).
                        let leftover = identity(
                            &out.file
                                .metadata()
                                .map_err(|e| OutputError::io(&out.partial, "reading", e))?,
                        );
                        if let Some(input) = options
                            .inputs
                            .iter()
                            .find(|i| std::fs::metadata(i).is_ok_and(|m| identity(&m) == leftover))
                        {
                            return Err(OutputError::IsInput {
                                target: out.partial.clone(),
                                input: input.clone(),
                            });
                        }
                        out.start_fresh()?;
                        out.adopt_fresh()?;
                    }
                    Leftover::Resume => out.leftover = true,
                }
            }
        }
        Ok(out)
    }

    /// Where the output goes once complete.
    pub fn target(&self) -> &Path {
        &self.target
    }

    /// The in-progress file (`NAME.partial`).
    pub fn partial(&self) -> &Path {
        &self.partial
    }

    /// Device and inode of the file being written (the one [`Output::commit`] puts at the
    /// target): whoever reads the target later can tell whether it still is this output or was
    /// replaced since.
    pub fn identity(&self) -> Result<(u64, u64), OutputError> {
        let (path, file) = match &self.fresh {
            Some((path, file, _)) => (path, file),
            None => (&self.partial, &self.file),
        };
        file.metadata()
            .map(|m| identity(&m))
            .map_err(|e| OutputError::io(path, "checking", e))
    }

    /// A writer's own handle on the in-progress file (the same open file: the lock and
    /// [`Output::commit`]'s `fsync` cover what it writes). With a leftover being resumed, the
    /// handle is on the fresh file once [`Output::start_fresh`] started it.
    pub fn file(&self) -> Result<File, OutputError> {
        let (path, file) = match &self.fresh {
            Some((path, file, _)) => (path, file),
            None => (&self.partial, &self.file),
        };
        file.try_clone()
            .map_err(|e| OutputError::io(path, "opening", e))
    }

    /// `Leftover::Resume`: the in-progress file of a writer that is gone, to read what it holds
    /// (locked by this process, so nobody else writes it meanwhile).
    pub fn leftover(&self) -> Option<&Path> {
        self.leftover.then_some(self.partial.as_path())
    }

    /// Starts a fresh in-progress file beside a leftover (`NAME.partial.<pid>`, created
    /// exclusively and locked) and returns a handle on it; the leftover stays where it is,
    /// untouched, until [`Output::adopt_fresh`]. Without a leftover, the current file is
    /// returned.
    pub fn start_fresh(&mut self) -> Result<File, OutputError> {
        if !self.leftover && self.ours {
            return self.file();
        }
        if self.fresh.is_none() {
            remove_dead_fresh(&self.partial);
            self.fresh = Some(crate::signals::critical(|| {
                let (path, file) = create_unique(&self.partial)?;
                let cleanup = Cleanup::register(&path);
                Ok::<_, OutputError>((path, file, cleanup))
            })?);
        }
        self.file()
    }

    /// Puts the fresh file started by [`Output::start_fresh`] in the leftover's place
    /// (`fsync`, then an atomic rename over it): call it once the fresh file holds everything
    /// the leftover held, so a kill at any moment loses nothing.
    pub fn adopt_fresh(&mut self) -> Result<(), OutputError> {
        let Some((path, file, mut cleanup)) = self.fresh.take() else {
            return Ok(());
        };
        file.sync_all()
            .map_err(|e| OutputError::io(&path, "syncing", e))?;
        let partial = self.partial.clone();
        let renamed = crate::signals::critical(|| {
            cleanup.clear();
            std::fs::rename(&path, &partial)?;
            Ok(Cleanup::register(&partial))
        });
        let registered = renamed
            .map_err(|e| OutputError::io(&self.partial, "replacing the in-progress file", e))?;
        // The old file (now unlinked) and its lock go; the fresh one is locked already.
        self.file = file;
        self.ours = true;
        self.leftover = false;
        self.cleanup = registered;
        Ok(())
    }

    /// Completes the output: `fsync`, rename onto the target (replacing it only with
    /// `replace`, and only if it is a regular file or a link), `fsync` of the directory. On an
    /// error the in-progress file is removed, as when dropped. A fresh file started beside a
    /// leftover and not adopted is itself the output: it goes to the target and the leftover
    /// stays as it was (`recover` of a killed recorder's `NAME.partial` into `NAME`).
    pub fn commit(mut self) -> Result<PathBuf, OutputError> {
        let (from, file, mut cleanup) = match self.fresh.take() {
            Some(fresh) => fresh,
            None => (
                self.partial.clone(),
                self.file
                    .try_clone()
                    .map_err(|e| OutputError::io(&self.partial, "syncing", e))?,
                std::mem::replace(&mut self.cleanup, Cleanup::none()),
            ),
        };
        let keep_failed = self.keep_failed;
        let removing = |e: OutputError, from: &Path, file: &File| {
            if !(keep_failed && file.metadata().is_ok_and(|m| m.len() > 0)) {
                remove_if_same(from, file);
            } else if still_at(from, file) {
                note_kept(from);
            }
            e
        };
        file.sync_all()
            .map_err(|e| removing(OutputError::io(&from, "syncing", e), &from, &file))?;
        // Unregistered and renamed as one step: a signal in between would leave it behind.
        let target = self.target.clone();
        let replace = self.replace;
        crate::signals::critical(|| {
            cleanup.clear();
            rename_into_place(&from, &file, &target, replace)
        })
        .map_err(|e| removing(e, &from, &file))?;
        // What was at the in-progress name (ours, renamed; or a leftover left alone) is no
        // longer this output's to remove.
        self.done = true;
        if let Some(dir) = self.target.parent() {
            let dir = if dir.as_os_str().is_empty() {
                Path::new(".")
            } else {
                dir
            };
            // Makes the rename itself durable; some file systems cannot sync a directory.
            if let Ok(d) = File::open(dir) {
                let _ = d.sync_all();
            }
        }
        Ok(self.target.clone())
    }

    /// Leaves the in-progress file where it is (a failed write whose content is worth
    /// keeping: complete chunks to salvage, map points to resume from) and returns its path.
    pub fn keep(mut self) -> PathBuf {
        if let Some((path, file, _)) = self.fresh.take() {
            // A fresh file never adopted holds nothing the leftover does not.
            remove_if_same(&path, &file);
        }
        self.done = true;
        self.cleanup.clear();
        note_kept(&self.partial);
        self.partial.clone()
    }

    /// Removes the in-progress file (what dropping does).
    pub fn discard(mut self) {
        self.remove();
    }

    /// Removes the in-progress file even where a failed write would keep it (`keep_failed`):
    /// its content is known to be of no use (a resume stopped before it held more than its
    /// input).
    pub fn abandon(mut self) {
        self.keep_failed = false;
        self.remove();
    }

    fn remove(&mut self) {
        if self.done {
            return;
        }
        self.done = true;
        self.cleanup.clear();
        if let Some((path, file, mut cleanup)) = self.fresh.take() {
            cleanup.clear();
            remove_if_same(&path, &file);
        }
        let kept = self.keep_failed && self.file.metadata().is_ok_and(|m| m.len() > 0);
        if self.ours && !kept {
            remove_if_same(&self.partial, &self.file);
        } else if self.ours && still_at(&self.partial, &self.file) {
            note_kept(&self.partial);
        }
    }
}

impl Drop for Output {
    fn drop(&mut self) {
        self.remove();
    }
}

/// Unlinks `path` if it still is `file`: never someone else's file that took the name
/// meanwhile.
fn remove_if_same(path: &Path, file: &File) {
    let Ok(here) = std::fs::symlink_metadata(path) else {
        return;
    };
    let same = file
        .metadata()
        .is_ok_and(|ours| identity(&ours) == identity(&here));
    if same {
        let _ = std::fs::remove_file(path);
    }
}

fn open_flags() -> i32 {
    // O_NONBLOCK: opening an existing name must never hang on a FIFO put there.
    libc::O_NOFOLLOW | libc::O_CLOEXEC | libc::O_NONBLOCK
}

/// Creates `path` exclusively (mode 0666 less the umask), never through a link.
fn create_exclusive(path: &Path) -> io::Result<File> {
    OpenOptions::new()
        .read(true)
        .write(true)
        .create_new(true)
        .mode(0o666)
        .custom_flags(libc::O_NOFOLLOW | libc::O_CLOEXEC)
        .open(path)
}

/// Takes the exclusive lock of `file` without waiting; false if another process holds it.
fn try_lock(file: &File, path: &Path) -> Result<bool, OutputError> {
    try_flock(file, path, libc::LOCK_EX)
}

/// Takes a shared lock of `file` without waiting; false if another process holds it
/// exclusively (a live writer). Checkers share it, so they never refuse one another.
fn try_lock_shared(file: &File, path: &Path) -> Result<bool, OutputError> {
    try_flock(file, path, libc::LOCK_SH)
}

fn try_flock(file: &File, path: &Path, operation: i32) -> Result<bool, OutputError> {
    // SAFETY: flock(2) on a file descriptor we own.
    if unsafe { libc::flock(file.as_raw_fd(), operation | libc::LOCK_NB) } == 0 {
        return Ok(true);
    }
    let e = io::Error::last_os_error();
    if e.raw_os_error() == Some(libc::EWOULDBLOCK) {
        Ok(false)
    } else {
        Err(OutputError::io(path, "locking", e))
    }
}

/// Opens and locks `partial`: created anew (true), or an existing one whose writer is gone
/// (false). Refuses one another process holds, and anything that is not a plain regular file
/// of this user with one link.
fn lock_partial(target: &Path, partial: &Path) -> Result<(File, bool), OutputError> {
    loop {
        let (file, created) = match create_exclusive(partial) {
            Ok(file) => (file, true),
            Err(e) if e.kind() == io::ErrorKind::AlreadyExists => {
                let here = match std::fs::symlink_metadata(partial) {
                    Ok(meta) => meta,
                    // Removed meanwhile (its writer finished): try again.
                    Err(e) if e.kind() == io::ErrorKind::NotFound => continue,
                    Err(e) => return Err(OutputError::io(partial, "checking", e)),
                };
                check_partial(partial, &here)?;
                let file = match OpenOptions::new()
                    .read(true)
                    .write(true)
                    .custom_flags(open_flags())
                    .open(partial)
                {
                    Ok(file) => file,
                    Err(e) if e.kind() == io::ErrorKind::NotFound => continue,
                    Err(e) if e.raw_os_error() == Some(libc::ELOOP) => {
                        return Err(OutputError::Foreign {
                            partial: partial.to_path_buf(),
                            why: "a symbolic link",
                        });
                    }
                    Err(e) => return Err(OutputError::io(partial, "opening", e)),
                };
                let meta = file
                    .metadata()
                    .map_err(|e| OutputError::io(partial, "checking", e))?;
                check_partial(partial, &meta)?;
                (file, false)
            }
            Err(e) => return Err(OutputError::io(partial, "creating", e)),
        };
        if !try_lock(&file, partial)? {
            return Err(OutputError::Busy {
                target: target.to_path_buf(),
                partial: partial.to_path_buf(),
                pid: file.metadata().ok().and_then(|m| lock_holder(&m)),
            });
        }
        // The name may have moved on between our open and our lock (its writer renamed it into
        // place, or replaced it): the lock counts only if the name is still this file.
        let still = std::fs::symlink_metadata(partial)
            .ok()
            .zip(file.metadata().ok())
            .is_some_and(|(here, ours)| identity(&here) == identity(&ours));
        if still {
            return Ok((file, created));
        }
    }
}

fn check_partial(partial: &Path, meta: &std::fs::Metadata) -> Result<(), OutputError> {
    let foreign = |why| {
        Err(OutputError::Foreign {
            partial: partial.to_path_buf(),
            why,
        })
    };
    if meta.file_type().is_symlink() {
        return foreign("a symbolic link");
    }
    if !meta.file_type().is_file() {
        return foreign("not a regular file");
    }
    if meta.nlink() != 1 {
        return foreign("it has other names (hard links)");
    }
    // SAFETY: geteuid(2) cannot fail.
    if meta.uid() != unsafe { libc::geteuid() } {
        return foreign("it belongs to another user");
    }
    Ok(())
}

/// Creates `PARTIAL.<pid>[.<n>]` exclusively and locks it.
/// Removes the fresh files (`NAME.partial.<pid>[.<n>]`, [`create_unique`]) that writers killed
/// before adopting or committing them left beside the in-progress file `partial`, whose
/// leftover this process holds locked: a fresh file never adopted holds nothing the leftover
/// does not. Only regular files of a process that is gone (no process has its pid, and nobody
/// holds the file's lock); anything else stays.
fn remove_dead_fresh(partial: &Path) {
    let (Some(dir), Some(name)) = (partial.parent(), partial.file_name()) else {
        return;
    };
    let dir = if dir.as_os_str().is_empty() {
        Path::new(".")
    } else {
        dir
    };
    let Ok(entries) = std::fs::read_dir(dir) else {
        return;
    };
    let prefix = format!("{}.", name.to_string_lossy());
    for entry in entries.flatten() {
        let file_name = entry.file_name();
        let file_name = file_name.to_string_lossy();
        let Some(rest) = file_name.strip_prefix(&prefix) else {
            continue;
        };
        let mut parts = rest.split('.');
        let pid = parts.next().and_then(|p| p.parse::<i32>().ok());
        let numbered = parts.all(|p| !p.is_empty() && p.bytes().all(|b| b.is_ascii_digit()));
        let Some(pid) = pid.filter(|&p| p > 0 && numbered) else {
            continue;
        };
        // SAFETY: kill(2) with signal 0 only asks whether the process exists.
        let alive = unsafe { libc::kill(pid, 0) } == 0
            || io::Error::last_os_error().raw_os_error() == Some(libc::EPERM);
        if alive || pid as u32 == std::process::id() {
            continue;
        }
        let path = entry.path();
        let Ok(file) = OpenOptions::new()
            .read(true)
            .custom_flags(open_flags())
            .open(&path)
        else {
            continue;
        };
        if file.metadata().is_ok_and(|m| m.file_type().is_file())
            && matches!(try_lock(&file, &path), Ok(true))
        {
            remove_if_same(&path, &file);
        }
    }
}

fn create_unique(partial: &Path) -> Result<(PathBuf, File), OutputError> {
    for n in 0..1000u32 {
        let mut s = partial.as_os_str().to_owned();
        s.push(format!(".{}", std::process::id()));
        if n > 0 {
            s.push(format!(".{n}"));
        }
        let path = PathBuf::from(s);
        match create_exclusive(&path) {
            Ok(file) => {
                try_lock(&file, &path)?;
                return Ok((path, file));
            }
            Err(e) if e.kind() == io::ErrorKind::AlreadyExists => continue,
            Err(e) => return Err(OutputError::io(&path, "creating", e)),
        }
    }
    Err(OutputError::io(
        partial,
        "creating a fresh in-progress file",
        io::Error::from(io::ErrorKind::AlreadyExists),
    ))
}

/// Whether the name `path` still is the open file `file`.
fn still_at(path: &Path, file: &File) -> bool {
    std::fs::symlink_metadata(path)
        .ok()
        .zip(file.metadata().ok())
        .is_some_and(|(here, ours)| identity(&here) == identity(&ours))
}

/// Renames the in-progress file `from` (open as `file`) onto `to`, as [`Output::commit`] says:
/// only if `from` still is `file` (a file another process put at that name is never renamed
/// for it), never over anything but a regular file or a symbolic link, over an existing one
/// only with `replace`, and never over a file another live process writes: a shared lock of
/// it is taken and held across the rename, so a live writer's file (locked exclusively) is
/// refused and no writer can take it up meanwhile.
fn rename_into_place(
    from: &Path,
    file: &File,
    to: &Path,
    replace: bool,
) -> Result<(), OutputError> {
    let replaced = || {
        Err(OutputError::Replaced {
            partial: from.to_path_buf(),
            target: to.to_path_buf(),
        })
    };
    // The target may change meanwhile (another writer's commit): look again, a few times.
    for _ in 0..64 {
        let here = match std::fs::symlink_metadata(to) {
            Ok(meta) => meta,
            Err(e) if e.kind() == io::ErrorKind::NotFound => {
                if !still_at(from, file) {
                    return replaced();
                }
                // Atomically refuses a file that appeared meanwhile: look at it again.
                match rename(from, to, false) {
                    Err(OutputError::Exists(_)) if replace => continue,
                    done => return done,
                }
            }
            Err(e) => return Err(OutputError::io(to, "checking the output", e)),
        };
        let t = here.file_type();
        if !t.is_file() && !t.is_symlink() {
            return Err(OutputError::NotRegular {
                path: to.to_path_buf(),
                kind: kind_of(&here),
            });
        }
        // A link is replaced itself, never followed: what it points to is not touched.
        let held = if t.is_file() {
            let held = match OpenOptions::new()
                .read(true)
                .custom_flags(open_flags())
                .open(to)
            {
                Ok(held) => Some(held),
                Err(e) if e.kind() == io::ErrorKind::NotFound => continue,
                Err(e) if e.raw_os_error() == Some(libc::ELOOP) => continue,
                // Unreadable to this user: not an in-progress file of this user's writers.
                Err(e) if e.kind() == io::ErrorKind::PermissionDenied => None,
                Err(e) => return Err(OutputError::io(to, "checking the output", e)),
            };
            if let Some(held) = &held {
                if !still_at(to, held) {
                    continue;
                }
                if !try_lock_shared(held, to)? {
                    return Err(OutputError::Live {
                        path: to.to_path_buf(),
                        pid: held.metadata().ok().and_then(|m| lock_holder(&m)),
                    });
                }
                if !still_at(to, held) {
                    continue;
                }
            }
            held
        } else {
            None
        };
        if !replace {
            return Err(OutputError::Exists(to.to_path_buf()));
        }
        if !still_at(from, file) {
            return replaced();
        }
        let renamed = rename(from, to, true);
        drop(held);
        return renamed;
    }
    Err(OutputError::io(
        to,
        "renaming into place",
        io::Error::other("the output kept changing under other writers"),
    ))
}

/// Renames `from` onto `to`; without `replace`, atomically refuses an existing `to`.
fn rename(from: &Path, to: &Path, replace: bool) -> Result<(), OutputError> {
    if replace {
        return std::fs::rename(from, to)
            .map_err(|e| OutputError::io(to, "renaming into place", e));
    }
    let c = |p: &Path| {
        CString::new(p.as_os_str().as_bytes()).map_err(|_| {
            OutputError::io(
                p,
                "renaming into place",
                io::Error::from(io::ErrorKind::InvalidInput),
            )
        })
    };
    let (cf, ct) = (c(from)?, c(to)?);
    // SAFETY: renameat2(2) with two NUL-terminated paths relative to the working directory.
    let r = unsafe {
        libc::renameat2(
            libc::AT_FDCWD,
            cf.as_ptr(),
            libc::AT_FDCWD,
            ct.as_ptr(),
            libc::RENAME_NOREPLACE,
        )
    };
    if r == 0 {
        return Ok(());
    }
    let e = io::Error::last_os_error();
    match e.raw_os_error() {
        Some(libc::EEXIST) => Err(OutputError::Exists(to.to_path_buf())),
        // A file system without RENAME_NOREPLACE: a hard link is just as exclusive.
        Some(libc::EINVAL) | Some(libc::ENOSYS) => match std::fs::hard_link(from, to) {
            Ok(()) => {
                let _ = std::fs::remove_file(from);
                Ok(())
            }
            Err(e) if e.kind() == io::ErrorKind::AlreadyExists => {
                Err(OutputError::Exists(to.to_path_buf()))
            }
            Err(e) => Err(OutputError::io(to, "renaming into place", e)),
        },
        _ => Err(OutputError::io(to, "renaming into place", e)),
    }
}

/// Writes a whole small output at once (a CSV table, an SVG, a PNG): `write` fills the
/// in-progress file, which is then committed.
pub fn write_whole(
    target: &Path,
    options: &OutputOptions,
    write: impl FnOnce(&mut File) -> io::Result<()>,
) -> Result<PathBuf, OutputError> {
    let output = Output::create(target, options)?;
    let mut file = output.file()?;
    write(&mut file).map_err(|e| OutputError::io(target, "writing", e))?;
    drop(file);
    output.commit()
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::io::{Read, Write};

    fn opts(replace: bool) -> OutputOptions {
        OutputOptions {
            replace,
            ..Default::default()
        }
    }

    fn write(target: &Path, options: &OutputOptions, text: &str) -> Result<PathBuf, OutputError> {
        write_whole(target, options, |f| f.write_all(text.as_bytes()))
    }

    fn read(path: &Path) -> String {
        let mut s = String::new();
        File::open(path).unwrap().read_to_string(&mut s).unwrap();
        s
    }

    #[test]
    fn a_directory_is_not_an_output_name() {
        let d = tempfile::tempdir().unwrap();
        let create_dir = OutputOptions {
            create_dir: true,
            ..Default::default()
        };
        for name in ["sub/", "sub/dir/", "sub/.", "."] {
            let t = PathBuf::from(format!("{}/{name}", d.path().display()));
            for options in [&opts(true), &create_dir] {
                let e = write(&t, options, "x").unwrap_err().to_string();
                assert!(
                    e.contains("names a directory") || e.contains("not a file name"),
                    "{name}: {e}"
                );
                assert!(check_target(&t, options).is_err(), "{name}");
            }
        }
        // Nothing was created: no `sub`, no `.partial`.
        assert_eq!(std::fs::read_dir(d.path()).unwrap().count(), 0);
    }

    #[test]
    fn a_complete_output_lands_at_its_name_and_nothing_else_stays() {
        let d = tempfile::tempdir().unwrap();
        let t = d.path().join("a.csv");
        write(&t, &opts(false), "x").unwrap();
        assert_eq!(read(&t), "x");
        assert_eq!(std::fs::read_dir(d.path()).unwrap().count(), 1);
        // Without --force an existing file stays; with it, it is replaced.
        assert!(matches!(
            write(&t, &opts(false), "y"),
            Err(OutputError::Exists(_))
        ));
        assert_eq!(read(&t), "x");
        write(&t, &opts(true), "y").unwrap();
        assert_eq!(read(&t), "y");
    }

    #[test]
    fn nothing_but_regular_files_and_links_is_replaced() {
        let d = tempfile::tempdir().unwrap();
        let fifo = d.path().join("fifo");
        let c = CString::new(fifo.as_os_str().as_bytes()).unwrap();
        // SAFETY: mkfifo(3) on a NUL-terminated path.
        assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o600) }, 0);
        let e = write(&fifo, &opts(true), "x").unwrap_err();
        assert!(e.to_string().contains("is a FIFO"), "{e}");
        assert!(
            std::fs::symlink_metadata(&fifo)
                .unwrap()
                .file_type()
                .is_fifo_like()
        );
        let e = write(d.path(), &opts(true), "x").unwrap_err();
        assert!(matches!(e, OutputError::NotRegular { .. }), "{e}");
        // A dangling link is not followed: without --force it exists, with it the link
        // itself is replaced and nothing appears where it pointed.
        let link = d.path().join("link");
        let aim = d.path().join("aim");
        std::os::unix::fs::symlink(&aim, &link).unwrap();
        assert!(matches!(
            write(&link, &opts(false), "x"),
            Err(OutputError::Exists(_))
        ));
        write(&link, &opts(true), "x").unwrap();
        assert!(!aim.exists());
        assert!(std::fs::symlink_metadata(&link).unwrap().is_file());
    }

    trait FifoLike {
        fn is_fifo_like(&self) -> bool;
    }
    impl FifoLike for std::fs::FileType {
        fn is_fifo_like(&self) -> bool {
            use std::os::unix::fs::FileTypeExt;
            self.is_fifo()
        }
    }

    #[test]
    fn an_input_is_never_the_output() {
        let d = tempfile::tempdir().unwrap();
        let input = d.path().join("in.mcap");
        std::fs::write(&input, "data").unwrap();
        let hard = d.path().join("hard.mcap");
        std::fs::hard_link(&input, &hard).unwrap();
        let soft = d.path().join("soft.mcap");
        std::os::unix::fs::symlink(&input, &soft).unwrap();
        for target in [&input, &hard, &soft] {
            let options = OutputOptions {
                replace: true,
                inputs: vec![input.clone()],
                ..Default::default()
            };
            let e = write(target, &options, "x").unwrap_err();
            assert!(matches!(e, OutputError::IsInput { .. }), "{e}");
        }
        assert_eq!(read(&input), "data");
    }

    #[test]
    fn a_second_writer_is_refused_while_the_first_lives_and_a_dead_ones_file_is_reported() {
        let d = tempfile::tempdir().unwrap();
        let t = d.path().join("m.mcap");
        let first = Output::create(&t, &opts(false)).unwrap();
        first.file().unwrap().write_all(b"first").unwrap();
        let e = Output::create(&t, &opts(true)).unwrap_err();
        assert!(matches!(e, OutputError::Busy { .. }), "{e}");
        // The first completes untouched.
        first.commit().unwrap();
        assert_eq!(read(&t), "first");

        // A writer that "died" (its lock released, file left): refused, discarded, resumed.
        let partial = partial_path(&t);
        std::fs::write(&partial, "left").unwrap();
        let e = Output::create(&t, &opts(true)).unwrap_err();
        assert!(matches!(e, OutputError::Leftover { .. }), "{e}");
        // The first writer's complete file is at the name: a resuming writer replaces it when
        // it commits, as `map` does with its earlier part.
        let resume = OutputOptions {
            replace: true,
            leftover: Leftover::Resume,
            ..Default::default()
        };
        let mut out = Output::create(&t, &resume).unwrap();
        assert_eq!(read(out.leftover().unwrap()), "left");
        // Dropped before adopting anything: the leftover stays.
        out.start_fresh().unwrap().write_all(b"left+").unwrap();
        drop(out);
        assert_eq!(read(&partial), "left");
        let mut out = Output::create(&t, &resume).unwrap();
        out.start_fresh().unwrap().write_all(b"left+new").unwrap();
        out.adopt_fresh().unwrap();
        assert_eq!(read(&partial), "left+new");
        out.commit().unwrap();
        assert_eq!(read(&t), "left+new");
        assert!(!partial.exists());
        let discard = OutputOptions {
            replace: true,
            leftover: Leftover::Discard,
            ..Default::default()
        };
        std::fs::write(&partial, "left").unwrap();
        write(&t, &discard, "again").unwrap();
        assert_eq!(read(&t), "again");
        assert_eq!(std::fs::read_dir(d.path()).unwrap().count(), 1);
    }

    #[test]
    fn a_planted_in_progress_name_is_never_used() {
        let d = tempfile::tempdir().unwrap();
        let t = d.path().join("x.mcap");
        let victim = d.path().join("victim");
        std::fs::write(&victim, "keep").unwrap();
        let partial = partial_path(&t);
        std::os::unix::fs::symlink(&victim, &partial).unwrap();
        let discard = OutputOptions {
            replace: true,
            leftover: Leftover::Discard,
            ..Default::default()
        };
        let e = write(&t, &discard, "x").unwrap_err();
        assert!(matches!(e, OutputError::Foreign { .. }), "{e}");
        std::fs::remove_file(&partial).unwrap();
        std::fs::hard_link(&victim, &partial).unwrap();
        let e = write(&t, &discard, "x").unwrap_err();
        assert!(matches!(e, OutputError::Foreign { .. }), "{e}");
        assert_eq!(read(&victim), "keep");
    }

    #[test]
    fn a_live_writers_file_is_never_replaced_and_a_replaced_partial_never_renamed() {
        let d = tempfile::tempdir().unwrap();
        let t = d.path().join("live.mcap");
        let partial = partial_path(&t);
        // A writer aiming at `live.mcap.partial`, begun before the live writer of `live.mcap`.
        let early = Output::create(&partial, &opts(true)).unwrap();
        early.file().unwrap().write_all(b"early").unwrap();
        let live = Output::create(&t, &opts(false)).unwrap();
        live.file().unwrap().write_all(b"live").unwrap();
        // Refused at the start and at the commit, even with --force (flock is per open file,
        // so this process's own second open is refused as another process's would be).
        let e = write(&partial, &opts(true), "x").unwrap_err();
        assert!(matches!(e, OutputError::Live { .. }), "{e}");
        let e = early.commit().unwrap_err();
        assert!(matches!(e, OutputError::Live { .. }), "{e}");
        assert_eq!(read(&partial), "live");
        live.commit().unwrap();
        assert_eq!(read(&t), "live");

        // An in-progress file renamed over behind its writer's back: nothing is renamed.
        let y = d.path().join("y.mcap");
        let out = Output::create(&y, &opts(false)).unwrap();
        out.file().unwrap().write_all(b"ours").unwrap();
        let stranger = d.path().join("stranger");
        std::fs::write(&stranger, "stranger").unwrap();
        std::fs::rename(&stranger, partial_path(&y)).unwrap();
        let e = out.commit().unwrap_err();
        assert!(matches!(e, OutputError::Replaced { .. }), "{e}");
        assert!(!y.exists());
        assert_eq!(read(&partial_path(&y)), "stranger");
    }

    #[test]
    fn a_failed_write_leaves_nothing_and_keep_leaves_the_partial() {
        let d = tempfile::tempdir().unwrap();
        let t = d.path().join("x.csv");
        let e = write_whole(&t, &opts(false), |_| Err(io::Error::other("disk full"))).unwrap_err();
        assert!(e.to_string().contains("disk full"), "{e}");
        assert_eq!(std::fs::read_dir(d.path()).unwrap().count(), 0);
        let out = Output::create(&t, &opts(false)).unwrap();
        out.file().unwrap().write_all(b"chunks").unwrap();
        let kept = out.keep();
        assert_eq!(read(&kept), "chunks");
        assert!(!t.exists());
        assert!(kept_after_failure().contains(&kept));
    }
}
