//! CPU time as the kernel counts it: of this thread, of this process, of its waited-for
//! children. A timing of work on a shared machine should count these, not the wall clock (with
//! two cores and a load of 20, most of a wall-clock timing is other processes').

use std::time::Duration;

/// CPU time this thread has run; `None` where the system has no such clock.
pub fn thread() -> Option<Duration> {
    clock(libc::CLOCK_THREAD_CPUTIME_ID)
}

/// CPU time of the whole process (every thread); `None` where the system has no such clock.
pub fn process() -> Option<Duration> {
    clock(libc::CLOCK_PROCESS_CPUTIME_ID)
}

/// CPU time (user and system) of the children this process has waited for: a compiler, a
/// command run to completion.
pub fn children() -> Duration {
    // SAFETY: getrusage writes the struct it is given.
    let mut usage: libc::rusage = unsafe { std::mem::zeroed() };
    if unsafe { libc::getrusage(libc::RUSAGE_CHILDREN, &mut usage) } != 0 {
        return Duration::ZERO;
    }
    let time = |t: libc::timeval| {
        Duration::new(t.tv_sec.max(0) as u64, 0)
            + Duration::from_micros(t.tv_usec.clamp(0, 999_999) as u64)
    };
    time(usage.ru_utime) + time(usage.ru_stime)
}

/// [`thread`] in seconds, NaN without the clock (a figure that says it is missing).
pub fn thread_seconds() -> f64 {
    thread().map_or(f64::NAN, |d| d.as_secs_f64())
}

/// [`process`] in seconds, NaN without the clock.
pub fn process_seconds() -> f64 {
    process().map_or(f64::NAN, |d| d.as_secs_f64())
}

/// [`children`] in seconds.
pub fn children_seconds() -> f64 {
    children().as_secs_f64()
}

fn clock(id: libc::clockid_t) -> Option<Duration> {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: `ts` is a valid timespec to write into; the clock ids are POSIX constants.
    let ok = unsafe { libc::clock_gettime(id, &mut ts) } == 0;
    (ok && ts.tv_sec >= 0 && (0..1_000_000_000).contains(&ts.tv_nsec))
        .then(|| Duration::new(ts.tv_sec as u64, ts.tv_nsec as u32))
}

#[cfg(test)]
mod tests {
    #[test]
    fn work_on_this_thread_moves_its_clock_and_the_process_clock() {
        let (t0, p0) = (super::thread().unwrap(), super::process().unwrap());
        let mut x = 1.0f64;
        let start = std::time::Instant::now();
        while start.elapsed() < std::time::Duration::from_millis(50) {
            x = std::hint::black_box(x * 1.000_000_1);
        }
        let (t1, p1) = (super::thread().unwrap(), super::process().unwrap());
        // 50 ms of spinning: at least some of it on the CPU whatever the load.
        assert!(t1 > t0 && p1 > p0, "{t0:?} -> {t1:?}, {p0:?} -> {p1:?}");
        assert!(p1 - p0 >= (t1 - t0).saturating_sub(std::time::Duration::from_millis(1)));
    }
}
