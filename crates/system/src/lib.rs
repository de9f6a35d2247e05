//! `system`: the live visual SLAM system of dwslam (thesis §6.3–6.5): a sensor's frames in,
//! every frame's pose and the map out.
//!
//! It stands on `slam` (the estimation library: the SLAM graph, tracking primitives, the
//! keyframe pipeline's stages, double window optimisation, loop closure), `vision` (the image
//! kernels), `data` (the frames and the outputs) and `geom` (cameras). It adds what only a live
//! system has: sensor front-ends, the per-frame tracker, the keyframe policy, place
//! recognition, and the threads of thesis §6.5.2. It knows no simulator.

#![warn(missing_docs)]

pub mod association;
pub mod config;
pub mod dense_model;
pub mod frame;
pub mod keyframes;
pub mod live;
pub mod loops;
pub mod mono;
pub mod place_recognition;
pub mod search;
pub mod tracker;
