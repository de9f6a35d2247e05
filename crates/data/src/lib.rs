//! `data`: dataset readers and writers, and trajectory evaluation.
//!
//! * [`paths`]: where the real datasets are (`DWSLAM_DATA` or `../shared/data`), and the
//!   skip-or-fail helper [`paths::require`] for tests;
//! * [`g2o`]: g2o pose-graph files (reader, writer, spanning-tree initialisation), into a
//!   [`PoseGraph`] over `lie::Se2` or `lie::Se3` (thesis §5.3.2, eq. 5.15–5.16);
//! * [`isam`]: the noise-free ground truth of iSAM's pose-graph datasets (`EDGE2`/`EDGE3`);
//! * [`bal`]: "Bundle Adjustment in the Large" problems, plain or `.bz2`;
//! * [`trajectory`]: TUM, KITTI and EuRoC trajectory files and timestamp association;
//! * [`camera`], [`camera_file`]: calibrations as datasets state them, dwslam's camera YAML
//!   and ORB-SLAM3 settings files;
//! * [`sequence`]: image sequences (TUM RGB-D / 7-Scenes, EuRoC, KITTI, image folders) read
//!   ahead on their own thread, undistorted and rectified, with ground truth;
//! * [`output`]: what a run writes (every frame's pose and tracking state, keyframes, map
//!   points as PLY, `summary.json`);
//! * [`dataset_writer`]: writers of the TUM RGB-D, EuRoC MAV and KITTI odometry layouts;
//! * [`eval`]: absolute trajectory error (after SE(3) or Sim(3) alignment, thesis eq.
//!   5.11–5.14) and relative pose error.
//!
//! Every reader returns a [`DataError`] naming the file, the line and what was expected; no
//! input panics.

#![warn(missing_docs)]

pub mod bal;
pub mod camera;
pub mod camera_file;
pub mod dataset_writer;
mod error;
pub mod eval;
pub mod g2o;
pub mod isam;
pub mod output;
pub mod paths;
mod pose_graph;
pub mod sequence;
mod text;
pub mod trajectory;

pub use error::{DataError, ParseErrorKind};
pub use pose_graph::{Edge, PoseGraph, PoseGraph2, PoseGraph3, Vertex, check_information};
