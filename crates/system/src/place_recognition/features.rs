//! The features a keyframe keeps for place recognition: ORB keypoints and descriptors, and the
//! camera-frame 3D point of each keypoint where the depth is known (stereo or RGB-D), or the
//! `(pixel, depth)` samples of its map points for the depth regression of monocular maps
//! (thesis §5.3.1).

use super::{PlaceRecognitionConfig, PlaceRecognitionError};
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

/// The depth at an image point (a keypoint, a sampled pixel) unless it lies on a depth edge:
/// the depth of the nearest pixel, accepted only if the valid depths
/// of its 3×3 neighbourhood all lie within `edge_ratio` (relative) of it. FAST corners often
/// sit on depth discontinuities, where the pixel's depth may belong to either side (and, with
/// colour and depth not registered exactly, to the wrong one); a relative spread of a few
/// percent over one pixel is what a surface shows even at grazing angles (at 3 m and 80° of
/// slant, 1 px spans 1 % of depth), while a discontinuity shows much more.
pub fn depth_off_edges(
    depth: &impl Fn(usize, usize) -> Option<f64>,
    u: f64,
    v: f64,
    edge_ratio: f64,
) -> Option<f64> {
    if !(u.is_finite() && v.is_finite()) || u < -0.5 || v < -0.5 {
        return None;
    }
    let (pu, pv) = ((u + 0.5) as usize, (v + 0.5) as usize);
    let d = depth(pu, pv).filter(|d| d.is_finite() && *d > 0.0)?;
    for dv in -1i64..=1 {
        for du in -1i64..=1 {
            let (nu, nv) = (pu as i64 + du, pv as i64 + dv);
            if nu < 0 || nv < 0 || (du, dv) == (0, 0) {
                continue;
            }
            if let Some(n) = depth(nu as usize, nv as usize)
                && n.is_finite()
                && n > 0.0
                && (n - d).abs() > edge_ratio * d
            {
                return None;
            }
        }
    }
    Some(d)
}

/// Extracts a keyframe's features: ORB keypoints and descriptors of `image`, each keypoint
/// back-projected through `camera` at its depth (see [`depth_off_edges`]) where `depth`
/// (metres at pixel `(u, v)`, `None` where unknown) has one. A monocular keyframe passes
/// `|_, _| None` and gives its map points' depths as `depth_samples`.
pub fn extract(
    image: &GrayImage,
    depth: impl Fn(usize, usize) -> Option<f64>,
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
            let d = depth_off_edges(&depth, u, v, config.depth_edge_ratio)?;
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
mod tests {
    use super::*;

    #[test]
    fn depth_edges_are_rejected() {
        // A step from 1 m to 2 m between columns 9 and 10.
        let depth =
            |u: usize, v: usize| (u < 40 && v < 40).then_some(if u < 10 { 1.0 } else { 2.0 });
        assert_eq!(depth_off_edges(&depth, 5.0, 5.0, 0.05), Some(1.0));
        assert_eq!(depth_off_edges(&depth, 20.2, 5.4, 0.05), Some(2.0));
        assert_eq!(depth_off_edges(&depth, 9.0, 5.0, 0.05), None);
        assert_eq!(depth_off_edges(&depth, 10.0, 5.0, 0.05), None);
        // Invalid neighbours (outside) do not reject; an invalid centre does.
        assert_eq!(depth_off_edges(&depth, 39.0, 39.0, 0.05), Some(2.0));
        assert_eq!(depth_off_edges(&depth, 45.0, 5.0, 0.05), None);
        assert_eq!(depth_off_edges(&depth, f64::NAN, 5.0, 0.05), None);
        // A slanted plane (1 % per pixel) passes.
        let slant = |u: usize, _v: usize| Some(2.0 * (1.0 + 0.01 * u as f64));
        assert!(depth_off_edges(&slant, 30.0, 3.0, 0.05).is_some());
    }
}
