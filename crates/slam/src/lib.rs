//! `slam`: the estimation library of dwslam (thesis ch. 3–6, app. B).
//!
//! - [`factors`]: measurement models and reprojection factors; [`ba`] and [`pose_graph`]: the
//!   bundle adjustment and pose-graph problems built from them.
//! - [`map`]: the SLAM graph — keyframes with absolute Sim(3) poses, anchored inverse-depth
//!   points, covisibility edges — shared between threads.
//! - [`tracking`]: candidate points and robust motion-only BA.
//! - [`mapping`]: the keyframe pipeline's stages (registration, new points, the synchronous
//!   pipeline).
//! - [`loop_closure`]: metric and appearance loop closure in the graph, the monocular loop
//!   constraint and the SE(3)/Sim(3) pose-graph correction.
//! - [`dwo`]: double window optimisation.
//! - [`exploration`]: monocular exploration with inverse-depth feature initialisation.
//! - [`clock`]: CPU time for timing.
//!
//! `slam` knows no threads of its own, no files and no command line (DESIGN.md).

#![warn(missing_docs)]

pub mod ba;
pub mod clock;
pub mod dwo;
pub mod exploration;
pub mod factors;
pub mod loop_closure;
pub mod map;
pub mod mapping;
pub mod pose_graph;
pub mod tracking;
