//! A latched "stop requested" flag fed by iceoryx2's SIGINT/SIGTERM handler.
//!
//! iceoryx2's `termination_requested()` forgets the signal once read; the publishing loop and
//! the backpressure handler (which runs inside a blocked `send`) both need to see it, so the
//! first reader latches it here.

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
        if SignalHandler::termination_requested() {
            self.request();
            return true;
        }
        false
    }

    pub fn request(&self) {
        self.0.store(true, Ordering::Relaxed);
    }
}
