//! A latched "stop requested" flag: SIGINT/SIGTERM, or a request from the caller.
//!
//! In the `chaoscope` command the signals come from [`crate::signals`], which latches the first
//! one where no library can reset it. A process that did not install that latch (a program
//! using the library, like `examples/custom-model`) may name another source of signals
//! ([`Termination::with_fallback`]: the producer process reads the flag iceoryx2's handler
//! sets), read once and latched here (iceoryx2 forgets it once read, and the publishing loop
//! and the backpressure handler both need to see it). Inside Python neither handler is
//! installed and the bindings call [`Termination::request`] on Ctrl-C.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

#[derive(Debug, Clone, Default)]
pub struct Termination {
    flag: Arc<AtomicBool>,
    /// Whether a signal arrived, asked when [`crate::signals`] is not installed.
    fallback: Option<fn() -> bool>,
}

impl Termination {
    pub fn new() -> Self {
        Self::default()
    }

    /// A flag that, in a process without [`crate::signals`] installed, also asks `signalled`
    /// whether SIGINT or SIGTERM arrived.
    pub fn with_fallback(signalled: fn() -> bool) -> Self {
        Self {
            flag: Arc::default(),
            fallback: Some(signalled),
        }
    }

    /// True once SIGINT or SIGTERM arrived (or [`Self::request`] was called).
    pub fn requested(&self) -> bool {
        if self.flag.load(Ordering::Relaxed) {
            return true;
        }
        let signalled = if crate::signals::installed() {
            crate::signals::requested()
        } else {
            self.fallback.is_some_and(|signalled| signalled())
        };
        if signalled {
            self.request();
        }
        signalled
    }

    pub fn request(&self) {
        self.flag.store(true, Ordering::Relaxed);
    }
}
