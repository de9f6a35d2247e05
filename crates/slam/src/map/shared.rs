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
use std::sync::{RwLock, RwLockReadGuard, RwLockWriteGuard};

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
        self.graph.read().unwrap_or_else(|e| e.into_inner())
    }

    /// A write guard (hold it briefly).
    pub fn write(&self) -> RwLockWriteGuard<'_, SlamGraph<N>> {
        self.graph.write().unwrap_or_else(|e| e.into_inner())
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
