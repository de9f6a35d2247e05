//! The features a keyframe keeps for place recognition: ORB keypoints and descriptors, and the
//! camera-frame 3D point of each keypoint where the depth is known (stereo or RGB-D), or the
//! `(pixel, depth)` samples of its map points for the depth regression of monocular maps
//! (thesis §5.3.1).

use super::types::{PlaceRecognitionConfig, PlaceRecognitionError};
use geom::PinholeCamera;
use nalgebra::{Vector2, Vector3};
use vision::image::GrayImage;
use vision::orb::{Descriptor, KeyPoint, detect_and_describe};

/// One keyframe's place-recognition features.
#[derive(Clone, Debug, PartialEq)]
pub struct KeyframeFeatures {
    /// ORB keypoints (level-0 pixels).
    pub keypoints: Vec<KeyPoint>,
    /// Their descriptors.
    pub descriptors: Vec<Descriptor>,
    /// Each keypoint's point in the camera frame, where its depth is known (metres).
    pub points: Vec<Option<Vector3<f64>>>,
    /// Monocular maps: `(pixel, depth)` samples of the keyframe's map points, from which the
    /// keypoints' depths are regressed (`slam::loop_closure::knn_depth`); empty otherwise.
    pub depth_samples: Vec<(Vector2<f64>, f64)>,
    /// The camera.
    pub camera: PinholeCamera,
}

impl KeyframeFeatures {
    /// Number of keypoints with a 3D point.
    pub fn with_depth(&self) -> usize {
        self.points.iter().filter(|p| p.is_some()).count()
    }
}

/// Extracts a keyframe's features: ORB keypoints and descriptors of `image`, each keypoint
/// back-projected through `camera` at its depth where `depth` (metres at the keypoint `(u, v)`,
/// off depth edges: [`FrameData::keypoint_depth`], [`off_edges`] for a depth image; `None`
/// where unknown) has one. A monocular keyframe passes `|_, _| None` and gives its map points'
/// depths as `depth_samples`.
///
/// [`FrameData::keypoint_depth`]: crate::frame::FrameData::keypoint_depth
pub fn extract(
    image: &GrayImage,
    depth: impl Fn(f64, f64) -> Option<f64>,
    depth_samples: Vec<(Vector2<f64>, f64)>,
    camera: &PinholeCamera,
    config: &PlaceRecognitionConfig,
) -> Result<KeyframeFeatures, PlaceRecognitionError> {
    let (keypoints, descriptors) = detect_and_describe(image, &config.orb.params())
        .map_err(|e| PlaceRecognitionError::Image(e.to_string()))?;
    let points = keypoints
        .iter()
        .map(|kp| {
            let (u, v) = (kp.u as f64, kp.v as f64);
            let d = depth(u, v)?;
            camera.unproject_depth(&Vector2::new(u, v), d).ok()
        })
        .collect();
    Ok(KeyframeFeatures {
        keypoints,
        descriptors,
        points,
        depth_samples,
        camera: *camera,
    })
}

#[cfg(test)]
/// The keypoint depth of [`extract`] from per-pixel depths `depth(u, v)` (metres): the nearest
/// pixel's where its 3×3 neighbours agree to `edge_ratio` ([`crate::frame::depth_off_edges`]).
pub fn off_edges(
    depth: impl Fn(usize, usize) -> Option<f64>,
    edge_ratio: f64,
) -> impl Fn(f64, f64) -> Option<f64> {
    move |u, v| crate::frame::depth_off_edges(&depth, u, v, 1, edge_ratio)
}
