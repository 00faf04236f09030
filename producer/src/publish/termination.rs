//! A latched "stop requested" flag: SIGINT/SIGTERM, or a request from the caller.
//!
//! In the `chaoscope` command the signals come from `chaoscope_os::signals`, which latches the
//! first one where no library can reset it. A process that did not install that latch (a
//! program using the library, like `examples/custom-model`) keeps the earlier behaviour: the
//! flag iceoryx2's handler sets, read once and latched here (iceoryx2 forgets it once read, and
//! the publishing loop and the backpressure handler both need to see it). Inside Python neither
//! handler is installed and the bindings call [`Termination::request`] on Ctrl-C.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

use iceoryx2_bb_posix::signal::SignalHandler;

#[derive(Debug, Clone, Default)]
pub struct Termination(Arc<AtomicBool>);

impl Termination {
    pub fn new() -> Self {
        Self::default()
    }

    /// True once SIGINT or SIGTERM arrived (or [`Self::request`] was called).
    pub fn requested(&self) -> bool {
        if self.0.load(Ordering::Relaxed) {
            return true;
        }
        let signalled = if chaoscope_os::signals::installed() {
            chaoscope_os::signals::requested()
        } else {
            SignalHandler::termination_requested()
        };
        if signalled {
            self.request();
        }
        signalled
    }

    pub fn request(&self) {
        self.0.store(true, Ordering::Relaxed);
    }
}
