//! The CPU time of the calling thread: the cost measure of the experiments (thesis §4.6.4).
//!
//! Wall-clock time on a shared machine counts the time other processes hold the core; the
//! thread's CPU time (`CLOCK_THREAD_CPUTIME_ID`) counts only the work of the thread itself, so
//! the measured cost of a pipeline that runs on one thread does not depend on the machine's
//! load. Work a thread hands to other threads (e.g. a multi-threaded rayon pool) is not counted:
//! measure single-threaded code only (the experiments run each trial in a one-thread pool).

use std::time::Duration;

/// The CPU time the calling thread has consumed so far; on platforms without a thread CPU
/// clock, the time since the first call (wall clock).
pub fn thread_cpu_time() -> Duration {
    #[cfg(unix)]
    {
        let mut ts = libc::timespec {
            tv_sec: 0,
            tv_nsec: 0,
        };
        // SAFETY: `ts` is a valid, exclusively borrowed timespec; the call only writes it.
        let rc = unsafe { libc::clock_gettime(libc::CLOCK_THREAD_CPUTIME_ID, &mut ts) };
        if rc == 0 {
            return Duration::new(ts.tv_sec as u64, ts.tv_nsec as u32);
        }
    }
    static START: std::sync::OnceLock<std::time::Instant> = std::sync::OnceLock::new();
    START.get_or_init(std::time::Instant::now).elapsed()
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
}
