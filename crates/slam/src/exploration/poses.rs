//! The rigid poses of a monocular map's keyframes.

use crate::map::{KeyframeId, SlamGraph};
use lie::Se3;

/// The rigid pose of keyframe `k` of `graph` (`(R, t/s)` of its similarity, see
/// [`crate::pose_graph::rigid_from_similarity`]): the pose of a monocular keyframe in its map's
/// metric.
pub fn rigid_pose<const N: usize>(graph: &SlamGraph<N>, k: KeyframeId) -> Se3 {
    crate::pose_graph::rigid_from_similarity(
        graph
            .keyframe(k)
            .expect("an exploration's keyframes are never removed")
            .camera_from_world(),
    )
}
