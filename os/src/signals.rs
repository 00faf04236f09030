//! SIGINT and SIGTERM, latched once per process.
//!
//! Why not iceoryx2's flag: iceoryx2 keeps only the *last* signal of a dozen kinds, forgets it
//! once read (`termination_requested` swaps it out; its own waits read it), and erases it before
//! it zeroes shared memory (`call_and_fetch`). A SIGTERM that arrived while a map opened its
//! live stream, or one followed by a SIGCONT, was lost, and the command ran on until SIGKILL.
//! Here the first SIGINT or SIGTERM is stored by our own handler, chained after iceoryx2's (so
//! its waits still wake), and nothing ever resets it. This crate knows nothing of iceoryx2: a
//! process that can open the bus installs through `chaoscope_bus::signals::install`, which
//! hands [`install_after`] the hook that puts iceoryx2's handlers in first.
//!
//! Two ways to use it ([`install`]):
//! - [`Mode::Finish`]: the command polls [`received`] in its loops, finalizes what it has into a
//!   valid file and exits with [`exit_status`] (run, produce, record, map, replay).
//! - [`Mode::Exit`]: the command has nothing worth finalizing (analyze, merge, recover, section,
//!   chart): the handler removes the in-progress files registered by [`crate::output`] (this
//!   process's own) and ends the process at once with the signal's status. Earlier outputs stay
//!   as they were.
//!
//! Not installed at all inside Python: Ctrl-C stays Python's (the bindings stop the work when
//! Python reports it).
//!
//! A SIGINT that was ignored when the process started stays ignored, from the first instant to
//! the last, in this process and in the processes it starts ([`sigint_ignored_at_start`]): a
//! shell without job control starts a script's background jobs so (`chaoscope run a.toml &`),
//! so that the Ctrl-C meant for the script's foreground does not stop them, and `nohup`-style
//! wrappers do the same on purpose; Python and the GNU tools keep that choice too. Such a
//! command is stopped with SIGTERM. SIGTERM itself is always handled: it is how a parent stops
//! its children.

use std::ffi::CString;
use std::sync::Once;
use std::sync::atomic::{AtomicBool, AtomicI32, AtomicPtr, AtomicU8, AtomicUsize, Ordering};

/// How a command reacts to SIGINT/SIGTERM.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Mode {
    /// Latch the signal; the command stops at its next check and finalizes its files.
    Finish,
    /// Remove this process's unfinished outputs and exit at once.
    Exit,
}

/// The first SIGINT/SIGTERM received (0: none).
static RECEIVED: AtomicI32 = AtomicI32::new(0);
/// Sections during which an exit on a signal waits ([`critical`]): between creating an
/// in-progress file and registering it for removal, between unregistering it and renaming it
/// into place.
static CRITICAL: AtomicUsize = AtomicUsize::new(0);
static MODE: AtomicU8 = AtomicU8::new(0);
static INSTALLED: Once = Once::new();
/// SIGINT's disposition was SIG_IGN when [`install`] first ran (before any handler of ours or of
/// another library replaced it).
static SIGINT_IGNORED: AtomicBool = AtomicBool::new(false);

/// In-progress files of this process, removed by the handler in [`Mode::Exit`]: fixed slots a
/// signal handler can read without allocating or locking (a path is leaked when registered and
/// never freed, so a handler that read a pointer can always use it).
const CLEANUP_SLOTS: usize = 64;
static CLEANUP: [AtomicPtr<libc::c_char>; CLEANUP_SLOTS] =
    [const { AtomicPtr::new(std::ptr::null_mut()) }; CLEANUP_SLOTS];

/// Installs the handlers (once per process; later calls only change the mode), with no other
/// library's handlers before them. A process that can open the bus installs through
/// `chaoscope_bus::signals::install` instead ([`install_after`]).
pub fn install(mode: Mode) {
    install_with(mode, None);
}

/// The handlers of another library that replaces whatever is installed, without chaining, the
/// first time it is asked about signals: `take` makes it install them (its first call) and
/// returns, and forgets, a SIGINT or SIGTERM that reached its handlers alone.
pub type ForeignHandlers = fn() -> Option<i32>;

/// Installs the handlers as [`install`] does, after `foreign`'s: those are installed first and
/// ours chained after them, so the other library's waits still wake; a signal its handlers took
/// before ours were in place is latched here too.
pub fn install_after(mode: Mode, foreign: ForeignHandlers) {
    install_with(mode, Some(foreign));
}

fn install_with(mode: Mode, foreign: Option<ForeignHandlers>) {
    MODE.store(
        match mode {
            Mode::Finish => 0,
            Mode::Exit => 1,
        },
        Ordering::SeqCst,
    );
    INSTALLED.call_once(|| {
        // SIGINT and SIGTERM wait, blocked, until every handler is in place: iceoryx2 keeps
        // only the last signal it took, so a SIGTERM followed by a SIGINT between its handlers
        // and ours would otherwise be lost to the SIGINT that is meant to be ignored. A pending
        // SIGINT is discarded when its disposition is set back to SIG_IGN; anything else
        // pending reaches our handlers when unblocked at the end.
        let blocked = BlockedSignals::new();
        // Read before anything replaces it.
        let sigint_ignored = disposition_is_ignore(libc::SIGINT);
        SIGINT_IGNORED.store(sigint_ignored, Ordering::SeqCst);
        // The foreign handlers first: they replace whatever is installed, without chaining.
        // Nothing is pending this early; a signal that was is kept.
        let take_foreign_signal = || {
            if let Some(signal) = foreign.and_then(|take| take()) {
                // A SIGINT the foreign handler took in the instant it had replaced SIG_IGN was
                // meant to be ignored.
                if !(sigint_ignored && signal == libc::SIGINT) {
                    latch(signal);
                }
            }
        };
        take_foreign_signal();
        if sigint_ignored {
            // The foreign library replaced SIG_IGN: put it back.
            // SAFETY: setting a standard signal's disposition to SIG_IGN.
            unsafe { libc::signal(libc::SIGINT, libc::SIG_IGN) };
        }
        let handled: &[i32] = if sigint_ignored {
            &[libc::SIGTERM]
        } else {
            &[libc::SIGINT, libc::SIGTERM]
        };
        for &signal in handled {
            // SAFETY: the action only does async-signal-safe things: atomics, unlink(2) of
            // leaked C strings and _exit(2). signal-hook's registry calls the previous handler
            // (the foreign one) after it, so the foreign library's waits still wake.
            let registered = unsafe { signal_hook_registry::register(signal, move || on(signal)) };
            if let Err(e) = registered {
                // Only if the signal number were invalid; the command then keeps the default
                // disposition (the signal ends it at once).
                crate::errln!("chaoscope: warning: cannot handle signal {signal}: {e}");
            }
        }
        // A signal between the foreign handlers and ours reached the foreign ones alone
        // (iceoryx2's next shared-memory operation erases it): taken from there too. (A
        // `chaoscope record` started by `run` once lost its parent-death SIGTERM so, and waited
        // for its producer for ever; that signal comes once.)
        take_foreign_signal();
        drop(blocked);
    });
}

/// SIGINT and SIGTERM blocked in this thread while it lives; the previous mask restored when
/// dropped.
struct BlockedSignals(libc::sigset_t);

impl BlockedSignals {
    fn new() -> Self {
        // SAFETY: sigset_t is plain data filled by sigemptyset/sigaddset; pthread_sigmask only
        // changes this thread's mask and writes the previous one into `old`.
        unsafe {
            let mut set: libc::sigset_t = std::mem::zeroed();
            let mut old: libc::sigset_t = std::mem::zeroed();
            libc::sigemptyset(&mut set);
            libc::sigaddset(&mut set, libc::SIGINT);
            libc::sigaddset(&mut set, libc::SIGTERM);
            libc::pthread_sigmask(libc::SIG_BLOCK, &set, &mut old);
            Self(old)
        }
    }
}

impl Drop for BlockedSignals {
    fn drop(&mut self) {
        // SAFETY: restores the mask read in `new`.
        unsafe { libc::pthread_sigmask(libc::SIG_SETMASK, &self.0, std::ptr::null_mut()) };
    }
}

/// Whether `signal`'s current disposition is SIG_IGN.
fn disposition_is_ignore(signal: i32) -> bool {
    // SAFETY: sigaction(2) with a null new action only reads the current one into `current`.
    unsafe {
        let mut current: libc::sigaction = std::mem::zeroed();
        libc::sigaction(signal, std::ptr::null(), &mut current) == 0
            && current.sa_sigaction == libc::SIG_IGN
    }
}

/// Whether SIGINT was ignored when this process started (and so still is: see the module's
/// docs). A process this one starts is given the same disposition.
pub fn sigint_ignored_at_start() -> bool {
    SIGINT_IGNORED.load(Ordering::SeqCst)
}

fn latch(signal: i32) {
    let _ = RECEIVED.compare_exchange(0, signal, Ordering::SeqCst, Ordering::SeqCst);
}

fn on(signal: i32) {
    latch(signal);
    // In a critical section the section's end exits instead (see `critical`: of the handler's
    // store of RECEIVED and the section's decrement, at least one sees the other).
    if MODE.load(Ordering::SeqCst) == 1 && CRITICAL.load(Ordering::SeqCst) == 0 {
        exit_now();
    }
}

/// Removes the registered in-progress files and ends the process with the signal's status
/// (async-signal-safe).
fn exit_now() -> ! {
    for slot in &CLEANUP {
        let path = slot.load(Ordering::SeqCst);
        if !path.is_null() {
            // SAFETY: a NUL-terminated string leaked by `Cleanup::register`, never freed.
            unsafe { libc::unlink(path) };
        }
    }
    let first = RECEIVED.load(Ordering::SeqCst);
    // SAFETY: _exit is async-signal-safe; nothing of this process needs to run after it.
    unsafe { libc::_exit(exit_status(first) as i32) }
}

/// Runs `f` with an exit on a signal ([`Mode::Exit`]) held back until it returns, so that an
/// in-progress file is never created without being registered for removal, nor unregistered
/// without being renamed into place.
pub(crate) fn critical<T>(f: impl FnOnce() -> T) -> T {
    CRITICAL.fetch_add(1, Ordering::SeqCst);
    let result = f();
    if CRITICAL.fetch_sub(1, Ordering::SeqCst) == 1
        && MODE.load(Ordering::SeqCst) == 1
        && RECEIVED.load(Ordering::SeqCst) != 0
    {
        exit_now();
    }
    result
}

/// Whether [`install`] ran in this process.
pub fn installed() -> bool {
    INSTALLED.is_completed()
}

/// The first SIGINT or SIGTERM this process received since [`install`], if any.
pub fn received() -> Option<i32> {
    match RECEIVED.load(Ordering::SeqCst) {
        0 => None,
        s => Some(s),
    }
}

/// Whether SIGINT or SIGTERM arrived.
pub fn requested() -> bool {
    received().is_some()
}

/// Runs `f`, a wait on something no deadline bounds (standard input a user may never close),
/// with SIGINT/SIGTERM ending the process at once as in [`Mode::Exit`], whatever the mode; the
/// mode is restored after. Why: a read blocked in the kernel is restarted after our handler
/// returns, so in [`Mode::Finish`] a latched signal would be seen only once the read ends.
/// For waits before a command has anything to finalize. Without [`install`] (inside Python)
/// it only runs `f`.
pub fn exit_on_signal_while<T>(f: impl FnOnce() -> T) -> T {
    if !installed() {
        return f();
    }
    let previous = MODE.swap(1, Ordering::SeqCst);
    // A signal latched before the swap found the old mode.
    if RECEIVED.load(Ordering::SeqCst) != 0 && CRITICAL.load(Ordering::SeqCst) == 0 {
        exit_now();
    }
    let result = f();
    MODE.store(previous, Ordering::SeqCst);
    result
}

/// The exit status of a command ended by `signal`: 128 + the signal number, as a shell reports
/// a process killed by it (130 for SIGINT, 143 for SIGTERM).
pub fn exit_status(signal: i32) -> u8 {
    128u8.saturating_add(signal.clamp(0, 127) as u8)
}

/// A registration of an in-progress file for removal on a signal in [`Mode::Exit`].
#[derive(Debug)]
pub(crate) struct Cleanup(Option<usize>);

impl Cleanup {
    /// No registration.
    pub(crate) fn none() -> Self {
        Self(None)
    }

    /// Registers `path` (when a slot is free; with all 64 in use the file is simply not removed
    /// by a signal, and stays as `NAME.partial`).
    pub(crate) fn register(path: &std::path::Path) -> Self {
        use std::os::unix::ffi::OsStrExt;
        let Ok(c) = CString::new(path.as_os_str().as_bytes()) else {
            return Self(None);
        };
        let ptr = c.into_raw();
        for (i, slot) in CLEANUP.iter().enumerate() {
            if slot
                .compare_exchange(
                    std::ptr::null_mut(),
                    ptr,
                    Ordering::SeqCst,
                    Ordering::SeqCst,
                )
                .is_ok()
            {
                return Self(Some(i));
            }
        }
        // SAFETY: `ptr` came from `into_raw` above and was published nowhere.
        drop(unsafe { CString::from_raw(ptr) });
        Self(None)
    }

    /// Unregisters (before the file is renamed or removed by the process itself). The string
    /// is leaked: a handler running now may still hold its pointer.
    pub(crate) fn clear(&mut self) {
        if let Some(i) = self.0.take() {
            CLEANUP[i].store(std::ptr::null_mut(), Ordering::SeqCst);
        }
    }
}

impl Drop for Cleanup {
    fn drop(&mut self) {
        self.clear();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn exit_statuses_are_the_shells() {
        assert_eq!(exit_status(libc::SIGINT), 130);
        assert_eq!(exit_status(libc::SIGTERM), 143);
    }

    #[test]
    fn a_signal_is_latched_and_stays_latched() {
        install(Mode::Finish);
        assert_eq!(received(), None);
        // SAFETY: raising a signal whose handler is installed above.
        unsafe { libc::raise(libc::SIGTERM) };
        assert_eq!(received(), Some(libc::SIGTERM));
        // A later SIGINT does not replace the first signal (with iceoryx2's handlers before
        // ours: `chaoscope_bus::signals`' test).
        unsafe { libc::raise(libc::SIGINT) };
        assert_eq!(received(), Some(libc::SIGTERM));
        assert!(requested());
    }
}
