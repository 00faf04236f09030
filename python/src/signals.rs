//! Ctrl-C stays Python's.
//!
//! iceoryx2 installs, the first time any bus code asks whether a termination signal came, its
//! own handlers for SIGINT, SIGTERM and the other non-fatal signals, replacing whatever the
//! process had, and never installs them again. In the `chaoscope` command that is the point;
//! inside Python it would silently turn Ctrl-C into a flag nobody reads, and `KeyboardInterrupt`
//! would never come. So the module triggers that installation once at import and puts the
//! process's previous handlers (Python's) back; stopping long calls is then done by the
//! calling thread, which sees Ctrl-C through Python and asks the work to stop
//! ([`crate::interrupt`]).

/// Lets iceoryx2 install its signal handlers now, then restores the previous ones.
pub fn keep_python_handlers() {
    let signals: Vec<i32> = (1..32)
        .filter(|&s| s != libc::SIGKILL && s != libc::SIGSTOP)
        .collect();
    let mut saved = Vec::with_capacity(signals.len());
    for &signal in &signals {
        // SAFETY: querying a disposition into a zeroed sigaction, which is a valid value.
        unsafe {
            let mut old: libc::sigaction = std::mem::zeroed();
            if libc::sigaction(signal, std::ptr::null(), &mut old) == 0 {
                saved.push((signal, old));
            }
        }
    }
    // The first call creates iceoryx2's handler singleton (and its handlers); nothing can be
    // pending yet, so reading the last signal loses nothing.
    let _ = iceoryx2_bb_posix::signal::SignalHandler::last_signal();
    for (signal, old) in saved {
        // SAFETY: restoring a disposition read above for the same signal.
        unsafe {
            libc::sigaction(signal, &old, std::ptr::null_mut());
        }
    }
}
