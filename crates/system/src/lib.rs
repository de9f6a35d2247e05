//! `system`: the live visual SLAM system of dwslam (thesis §6.3–6.5): a sensor's frames in,
//! every frame's pose and the map out.
//!
//! It stands on `slam` (the estimation library: the SLAM graph, tracking primitives, the
//! keyframe pipeline's stages, double window optimisation, loop closure), `vision` (the image
//! kernels), `data` (the frames and the outputs) and `geom` (cameras). It adds what only a live
//! system has: sensor front-ends, the per-frame tracker, the keyframe policy, place
//! recognition, and the threads of thesis §6.5.2. It knows no simulator.
//!
//! The caller's part: a [`System`] made for a sensor with a [`SystemConfig`] and [`Options`],
//! driven frame by frame through [`LiveRun`], ending in a [`RunResult`].

#![warn(missing_docs)]

pub mod config;
pub mod dense_model;
pub mod map_file;
mod result;
mod system;

pub(crate) mod association;
pub(crate) mod depth;
pub(crate) mod frame;
pub(crate) mod keyframes;
pub(crate) mod loops;
pub(crate) mod mono;
pub(crate) mod observed;
pub(crate) mod place_recognition;
pub(crate) mod run_graph;
pub(crate) mod search;
pub(crate) mod session;
pub(crate) mod tracker;

#[cfg(test)]
mod tests;

pub use config::SystemConfig;
pub use keyframes::{KeyframeImages, KeyframeReason, KeyframeStore};
/// The vocabulary of place recognition: loading it, training it (`dwslam vocabulary`).
pub use place_recognition::vocabulary;
pub use place_recognition::{Alignment, OrbConfig, PlaceRecognitionConfig};
pub use result::{
    FrameReport, KeyframeNode, LiveRun, LockWaits, LoopEvent, LoopEvidence, MapSnapshot, Mode,
    NewMap, Observed, ObservedState, Progress, RefusedLoop, Relocalisation, RunGraph, RunResult,
    SavedMap, SystemError,
};
pub use session::backend::Fault;
pub use session::sensor::Faults;
pub use system::{Options, System};
pub use tracker::TrackerStats;
