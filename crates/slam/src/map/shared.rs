//! The SLAM graph shared between threads (the live system's tracking, double window
//! optimisation and loop closure; thesis §6.5.2).
//!
//! Readers and writers hold the lock only for short, bounded sections, never during an
//! optimisation: an optimiser *plans* under a read lock (copying what it needs), *optimises*
//! with no lock held and *writes back* under a short write lock. Between plan and write-back
//! the graph may change; every pose and point carries the [`Version`](super::Version) of its
//! last change, so a writer detects that what it planned on moved ([`SlamGraph::version`]) and
//! rebases or re-plans instead of overwriting newer state.

use super::SlamGraph;
use std::cell::RefCell;
use std::sync::{RwLock, RwLockReadGuard, RwLockWriteGuard, TryLockError};
use std::time::{Duration, Instant};

/// A SLAM graph shared between the tracking thread and the optimiser (see the module docs):
/// readers and writers hold the lock only for short sections, never during an optimisation.
#[derive(Debug, Default)]
pub struct SharedGraph<const N: usize> {
    graph: RwLock<SlamGraph<N>>,
}

impl<const N: usize> SharedGraph<N> {
    /// Wraps a graph.
    pub fn new(graph: SlamGraph<N>) -> Self {
        SharedGraph {
            graph: RwLock::new(graph),
        }
    }

    /// A read guard (hold it briefly). A poisoned lock (a panicking writer) is recovered: the
    /// graph's mutations keep its invariants at every step that can panic.
    pub fn read(&self) -> RwLockReadGuard<'_, SlamGraph<N>> {
        read_lock(&self.graph)
    }

    /// A write guard (hold it briefly).
    pub fn write(&self) -> RwLockWriteGuard<'_, SlamGraph<N>> {
        write_lock(&self.graph)
    }

    /// A copy of the whole graph (for a consistent view without holding the lock).
    pub fn snapshot(&self) -> SlamGraph<N> {
        self.read().clone()
    }

    /// The wrapped graph.
    pub fn into_inner(self) -> SlamGraph<N> {
        self.graph.into_inner().unwrap_or_else(|e| e.into_inner())
    }
}

/// A graph that a stage reads and changes step by step: a [`SlamGraph`] one thread owns, or a
/// [`SharedGraph`] whose lock is taken for each step and released between them — so that a
/// stage that solves (a window's bundle adjustment, a double window) holds no lock while it
/// solves, and the one code path serves both (the simulations and tests own their graph, the
/// live system shares it). `&mut G` is one too.
pub trait GraphAccess<const N: usize> {
    /// The graph to read (a read guard for a shared graph: hold it briefly).
    fn read(&mut self) -> impl std::ops::Deref<Target = SlamGraph<N>> + '_;
    /// The graph to change (a write guard for a shared graph: hold it briefly).
    fn write(&mut self) -> impl std::ops::DerefMut<Target = SlamGraph<N>> + '_;
}

impl<const N: usize> GraphAccess<N> for SlamGraph<N> {
    fn read(&mut self) -> impl std::ops::Deref<Target = SlamGraph<N>> + '_ {
        &*self
    }

    fn write(&mut self) -> impl std::ops::DerefMut<Target = SlamGraph<N>> + '_ {
        self
    }
}

impl<const N: usize> GraphAccess<N> for &SharedGraph<N> {
    fn read(&mut self) -> impl std::ops::Deref<Target = SlamGraph<N>> + '_ {
        SharedGraph::read(self)
    }

    fn write(&mut self) -> impl std::ops::DerefMut<Target = SlamGraph<N>> + '_ {
        SharedGraph::write(self)
    }
}

impl<const N: usize, G: GraphAccess<N>> GraphAccess<N> for &mut G {
    fn read(&mut self) -> impl std::ops::Deref<Target = SlamGraph<N>> + '_ {
        (**self).read()
    }

    fn write(&mut self) -> impl std::ops::DerefMut<Target = SlamGraph<N>> + '_ {
        (**self).write()
    }
}

thread_local! {
    /// This thread's waits for shared locks while it records them ([`record_lock_waits`]).
    static WAITS: RefCell<Option<Vec<Duration>>> = const { RefCell::new(None) };
}

/// Starts (`true`) or stops recording, in the calling thread, how long each lock it takes
/// through a [`SharedGraph`], [`read_lock`] or [`write_lock`] waits for another thread (a live
/// system's tracking thread must never wait long: thesis §6.5.2).
pub fn record_lock_waits(on: bool) {
    WAITS.with(|w| {
        let mut w = w.borrow_mut();
        match (on, w.is_some()) {
            (true, false) => *w = Some(Vec::new()),
            (false, _) => *w = None,
            _ => {}
        }
    });
}

/// The waits the calling thread recorded since the last call, in the order taken (a lock
/// free at once waited zero).
pub fn take_lock_waits() -> Vec<Duration> {
    WAITS.with(|w| {
        w.borrow_mut()
            .as_mut()
            .map(std::mem::take)
            .unwrap_or_default()
    })
}

fn record(wait: Duration) {
    WAITS.with(|w| {
        if let Some(w) = w.borrow_mut().as_mut() {
            w.push(wait);
        }
    });
}

/// A read guard of `lock`, its wait recorded ([`record_lock_waits`]). A poisoned lock (a
/// panicking writer) is recovered: its holders keep their data consistent at every step that
/// can panic.
pub fn read_lock<T>(lock: &RwLock<T>) -> RwLockReadGuard<'_, T> {
    timed(lock.try_read(), || lock.read())
}

/// A write guard of `lock`, its wait recorded ([`record_lock_waits`]; poisoning as
/// [`read_lock`]).
pub fn write_lock<T>(lock: &RwLock<T>) -> RwLockWriteGuard<'_, T> {
    timed(lock.try_write(), || lock.write())
}

/// The guard of a lock taken at once (`tried`), or after waiting for it (`block`), the wait
/// recorded; a poisoned lock recovered.
fn timed<G>(
    tried: std::sync::TryLockResult<G>,
    block: impl FnOnce() -> std::sync::LockResult<G>,
) -> G {
    match tried {
        Ok(guard) => {
            record(Duration::ZERO);
            guard
        }
        Err(TryLockError::Poisoned(e)) => {
            record(Duration::ZERO);
            e.into_inner()
        }
        Err(TryLockError::WouldBlock) => {
            let t = Instant::now();
            let guard = block().unwrap_or_else(|e| e.into_inner());
            record(t.elapsed());
            guard
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A lock held by another thread for 20 ms is waited for (and recorded, in the thread
    /// that records); a free one waits zero; a thread that does not record records nothing.
    #[test]
    fn lock_waits_are_recorded_in_the_thread_that_asks() {
        let lock = std::sync::Arc::new(RwLock::new(0u32));
        record_lock_waits(true);
        drop(read_lock(&lock));
        let held = {
            let other = lock.clone();
            let (tx, rx) = std::sync::mpsc::channel();
            let h = std::thread::spawn(move || {
                let _g = write_lock(&other);
                tx.send(()).unwrap();
                std::thread::sleep(Duration::from_millis(20));
                take_lock_waits()
            });
            rx.recv().unwrap();
            *write_lock(&lock) += 1;
            h.join().unwrap()
        };
        assert!(held.is_empty(), "the other thread does not record");
        let waits = take_lock_waits();
        assert_eq!(waits.len(), 2);
        assert_eq!(waits[0], Duration::ZERO);
        assert!(waits[1] >= Duration::from_millis(10), "{waits:?}");
        assert!(take_lock_waits().is_empty());
        record_lock_waits(false);
        drop(read_lock(&lock));
        assert!(take_lock_waits().is_empty());
    }
}
