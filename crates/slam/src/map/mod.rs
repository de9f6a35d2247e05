//! The map: the SLAM graph of double window optimisation (thesis §6.2.2, Figure 6.3) — the one
//! map model of every pipeline — and its sharing between threads.
//!
//! - [`graph`]: [`SlamGraph`], keyframes with absolute Sim(3) poses, anchored inverse-depth
//!   points, covisibility edges, weighted breadth-first search, invariants, versions.
//! - [`ids`]: the typed ids [`KeyframeId`] and [`PointId`].
//! - [`maps`]: the maps of one graph — started after a loss, merged or joined — and which of
//!   them a run writes.
//! - [`shared`]: [`SharedGraph`], the graph behind a lock held only for short sections.

pub mod graph;
pub mod ids;
pub mod maps;
pub mod shared;

pub use graph::{
    BfsTree, Edge, FIRST_MAP, GraphError, GraphParts, Keyframe, KeyframePart, MapMerge, MapPoint,
    PointPart, SlamGraph, Version,
};
pub use ids::{IdInt, KeyframeId, PointId};
pub use maps::MapJoin;
pub use shared::{GraphAccess, SharedGraph};
