//! `slam`: the back-end of dwslam — factors for bundle adjustment and pose graphs (thesis
//! ch. 3, 5, app. B), and, as the system grows, the SLAM graph, double window optimisation and
//! loop closure (thesis ch. 6).

#![warn(missing_docs)]

pub mod ba;
pub mod ba_slam;
pub mod bootstrap;
pub mod clock;
pub mod dwo;
pub mod exploration;
pub mod feature_init;
pub mod features;
pub mod filter;
pub mod filter_slam;
pub mod graph;
pub mod loop_closure;
pub mod pose_graph;
pub mod registration;
