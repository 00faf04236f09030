//! Long calls: the work runs on a worker thread while the calling thread, with the GIL released
//! between checks, looks for Ctrl-C (and other Python signal handlers' exceptions) every few
//! milliseconds. On an exception it asks the work to stop (each call passes how: a flag the
//! engine loop reads, the map's termination request), waits for it to wind down cleanly (files
//! finalized as the command does on SIGINT), and raises the exception.

use std::sync::{Arc, Condvar, Mutex};
use std::time::Duration;

use pyo3::prelude::*;

/// How often the calling thread checks for signals while the work runs.
const CHECK_INTERVAL: Duration = Duration::from_millis(50);

/// Runs `work` on a worker thread; on a Python exception from a signal handler calls `stop`,
/// waits for `work` to return and raises the exception.
pub fn interruptible<T: Send>(
    py: Python<'_>,
    stop: impl Fn() + Sync,
    work: impl FnOnce() -> T + Send,
) -> PyResult<T> {
    let done = Arc::new((Mutex::new(false), Condvar::new()));
    std::thread::scope(|scope| {
        let signal_done = Arc::clone(&done);
        let handle = scope.spawn(move || {
            // Signals the waiter even if `work` panics.
            struct Notify(Arc<(Mutex<bool>, Condvar)>);
            impl Drop for Notify {
                fn drop(&mut self) {
                    let (lock, cv) = &*self.0;
                    *lock.lock().unwrap_or_else(|e| e.into_inner()) = true;
                    cv.notify_all();
                }
            }
            let _notify = Notify(signal_done);
            work()
        });
        let wait = |limit: Option<Duration>| {
            let (lock, cv) = &*done;
            let mut finished = lock.lock().unwrap_or_else(|e| e.into_inner());
            match limit {
                Some(limit) => {
                    if !*finished {
                        finished = cv
                            .wait_timeout(finished, limit)
                            .unwrap_or_else(|e| e.into_inner())
                            .0;
                    }
                }
                None => {
                    while !*finished {
                        finished = cv.wait(finished).unwrap_or_else(|e| e.into_inner());
                    }
                }
            }
            *finished
        };
        let mut raised = None;
        while !py.detach(|| wait(Some(CHECK_INTERVAL))) {
            if let Err(e) = py.check_signals() {
                stop();
                py.detach(|| wait(None));
                raised = Some(e);
                break;
            }
        }
        let result = match handle.join() {
            Ok(value) => value,
            Err(panic) => std::panic::resume_unwind(panic),
        };
        match raised {
            Some(e) => Err(e),
            None => Ok(result),
        }
    })
}

/// Runs `work`, which only reads (it has no file of its own to finalize and no way to be asked
/// to stop), on a thread of its own while the calling thread looks for Ctrl-C as
/// [`interruptible`] does; on a Python exception from a signal handler the exception is raised
/// at once and the work is left to end by itself, its result dropped.
pub fn abandonable<T: Send + 'static>(
    py: Python<'_>,
    work: impl FnOnce() -> T + Send + 'static,
) -> PyResult<T> {
    use std::sync::mpsc::{RecvTimeoutError, channel};
    let (done, result) = channel();
    std::thread::spawn(move || {
        let _ = done.send(std::panic::catch_unwind(std::panic::AssertUnwindSafe(work)));
    });
    // Held by this thread alone; the lock only lets the wait move to where the GIL is released.
    let result = Mutex::new(result);
    loop {
        let received = py.detach(|| {
            result
                .lock()
                .unwrap_or_else(|e| e.into_inner())
                .recv_timeout(CHECK_INTERVAL)
        });
        match received {
            Ok(Ok(value)) => return Ok(value),
            Ok(Err(panic)) => std::panic::resume_unwind(panic),
            Err(RecvTimeoutError::Timeout) => py.check_signals()?,
            Err(RecvTimeoutError::Disconnected) => {
                unreachable!("the worker sends its result before it ends")
            }
        }
    }
}
