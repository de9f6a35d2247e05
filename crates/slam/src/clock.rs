//! CPU time, the cost measure of the experiments (thesis §4.6.4) and of the benchmarks: the
//! one clock of the workspace.
//!
//! Wall-clock time on a shared machine counts the time other processes hold the core; CPU time
//! counts only the work done. The calling *thread's* CPU time (`CLOCK_THREAD_CPUTIME_ID`,
//! [`thread_cpu_time`], [`CpuStopwatch`]) measures a pipeline that runs on one thread; work it
//! hands to other threads (e.g. a multi-threaded rayon pool) is not counted, so measure
//! single-threaded code only (the experiments run each trial in a one-thread pool). The
//! *process's* CPU time (`CLOCK_PROCESS_CPUTIME_ID`, [`process_cpu_time`]) adds up every
//! thread, for multi-threaded work.

use std::time::Duration;

/// `clock_gettime` of `clock`, or `None` if it fails.
#[cfg(unix)]
fn cpu_clock(clock: libc::clockid_t) -> Option<Duration> {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: `ts` is a valid, exclusively borrowed timespec; the call only writes it.
    let rc = unsafe { libc::clock_gettime(clock, &mut ts) };
    (rc == 0).then(|| Duration::new(ts.tv_sec as u64, ts.tv_nsec as u32))
}

/// The CPU time the calling thread has consumed so far; on platforms without a thread CPU
/// clock, the time since the first call (wall clock).
pub fn thread_cpu_time() -> Duration {
    #[cfg(unix)]
    if let Some(t) = cpu_clock(libc::CLOCK_THREAD_CPUTIME_ID) {
        return t;
    }
    static START: std::sync::OnceLock<std::time::Instant> = std::sync::OnceLock::new();
    START.get_or_init(std::time::Instant::now).elapsed()
}

/// The CPU time (user and system, all threads) this process has consumed so far, or `None`
/// on platforms without a process CPU clock.
pub fn process_cpu_time() -> Option<Duration> {
    #[cfg(unix)]
    {
        cpu_clock(libc::CLOCK_PROCESS_CPUTIME_ID)
    }
    #[cfg(not(unix))]
    {
        None
    }
}

/// A stopwatch on the calling thread's CPU time ([`thread_cpu_time`]).
#[derive(Clone, Copy, Debug)]
pub struct CpuStopwatch(Duration);

impl CpuStopwatch {
    /// Starts now.
    pub fn start() -> Self {
        CpuStopwatch(thread_cpu_time())
    }

    /// CPU time of this thread since [`CpuStopwatch::start`].
    pub fn elapsed(&self) -> Duration {
        thread_cpu_time().saturating_sub(self.0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn counts_work_and_not_sleep() {
        let watch = CpuStopwatch::start();
        std::thread::sleep(Duration::from_millis(30));
        let slept = watch.elapsed();
        let mut x = 0u64;
        let busy = std::time::Instant::now();
        while busy.elapsed() < Duration::from_millis(30) {
            x = std::hint::black_box(x.wrapping_add(1));
        }
        let worked = watch.elapsed() - slept;
        assert!(
            slept < Duration::from_millis(15),
            "sleep counted: {slept:?}"
        );
        assert!(
            worked > Duration::from_millis(5),
            "work not counted: {worked:?}"
        );
    }

    #[test]
    fn the_process_clock_adds_up_the_threads() {
        let before = process_cpu_time().expect("a process CPU clock on this platform");
        let spin = || {
            let busy = std::time::Instant::now();
            let mut x = 0u64;
            while busy.elapsed() < Duration::from_millis(40) {
                x = std::hint::black_box(x.wrapping_add(1));
            }
        };
        std::thread::scope(|s| {
            s.spawn(spin);
            s.spawn(spin);
        });
        let used = process_cpu_time().unwrap() - before;
        // Two threads of 40 ms each: at least one thread's worth even on a loaded core.
        assert!(used > Duration::from_millis(30), "{used:?}");
    }
}
