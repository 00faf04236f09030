//! SIGINT and SIGTERM in a process that can open the bus.
//!
//! iceoryx2 installs its own handlers for SIGINT, SIGTERM and the other non-fatal signals the
//! first time anything asks it about signals, replacing whatever the process had, without
//! chaining. So every process that can open the bus installs [`chaoscope_os::signals`] through
//! [`install`]: iceoryx2's handlers go in first and the latch is chained after them (iceoryx2's
//! waits still wake), and a signal that reached iceoryx2's handlers alone is latched too.

use chaoscope_os::signals::Mode;
use iceoryx2_bb_posix::signal::{NonFatalFetchableSignal, SignalHandler};

/// Installs the SIGINT/SIGTERM latch after iceoryx2's handlers (once per process; later calls
/// only change the mode).
pub fn install(mode: Mode) {
    chaoscope_os::signals::install_after(mode, take_iceoryx2_signal);
}

/// Whether iceoryx2's handlers took SIGINT or SIGTERM since this was last asked (iceoryx2 forgets
/// it once read): the fallback of a [`chaoscope_os::termination::Termination`] in a process
/// that did not [`install`] the latch (a program using the library).
pub fn iceoryx2_termination_requested() -> bool {
    SignalHandler::termination_requested()
}

/// Installs iceoryx2's handlers (its first call) and returns, as iceoryx2 forgets it, the
/// SIGINT or SIGTERM they took.
fn take_iceoryx2_signal() -> Option<i32> {
    match SignalHandler::last_signal() {
        Some(NonFatalFetchableSignal::Interrupt) => Some(libc::SIGINT),
        Some(NonFatalFetchableSignal::Terminate) => Some(libc::SIGTERM),
        _ => None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use chaoscope_os::signals::{received, requested};

    #[test]
    fn a_signal_is_latched_and_stays_latched() {
        install(Mode::Finish);
        assert_eq!(received(), None);
        // SAFETY: raising a signal whose handler is installed above.
        unsafe { libc::raise(libc::SIGTERM) };
        assert_eq!(received(), Some(libc::SIGTERM));
        // iceoryx2 reading (and resetting) its own flag does not reset ours; a later SIGINT
        // does not replace the first signal.
        let _ = SignalHandler::termination_requested();
        unsafe { libc::raise(libc::SIGINT) };
        assert_eq!(received(), Some(libc::SIGTERM));
        assert!(requested());
    }
}
