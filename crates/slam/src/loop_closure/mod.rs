//! Loop closure (thesis ch. 5, §6.4).
//!
//! - [`metric`]: metric loop closure in the SLAM graph (§6.4.1): points of `N2 \ N1` found
//!   again in the reference keyframe join it to old keyframes, with the spread-of-matches test.
//! - [`appearance`]: a large loop found by appearance (§6.4.2) inserted as a graph edge.
//! - [`drift`]: whether a loop's correction is one the odometry's drift over the path since
//!   the old place explains (else the two places only look alike).
//! - [`constraint`]: the loop similarity of monocular SLAM from matched features, with depths
//!   from the map or by kNN regression, 3-point RANSAC and robust refinement (§5.3.1).
//! - [`correction`]: correcting the keyframes and points through the SE(3) or Sim(3) pose
//!   graph (§5.3.2–5.3.3).

pub mod appearance;
pub mod constraint;
pub mod correction;
pub mod drift;
pub mod metric;

pub use appearance::close_appearance_loop;
pub use constraint::{
    LoopClosureConfig, LoopClosureError, LoopConstraint, LoopView, LoopViewMeasurement,
    estimate_loop_constraint, knn_depth,
};
pub use correction::{Correction, CorrectionError, CorrectionGroup, LoopEdge};
pub use drift::{DriftLimits, LoopDrift};
pub use metric::{
    MetricLoopClosure, MetricLoopFit, MetricLoopParams, MetricLoopProblem, close_metric_loops,
    loop_candidates,
};

use crate::map::GraphError;
use crate::tracking::TrackingError;

/// Why inserting a loop closure into the graph failed.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ClosureError {
    /// A graph operation failed.
    #[error(transparent)]
    Graph(#[from] GraphError),
    /// The pose of the loop could not be estimated.
    #[error(transparent)]
    Tracking(#[from] TrackingError),
}
