//! Motion-only BA as the study runs it, the pose step shared by BA-SLAM ([`super::ba_slam`])
//! and the filter ([`super::filter`]); uses neither.

use lie::Se3;
use nalgebra::{SVector, Vector3};
use slam::factors::Projector;
use slam::tracking::{MotionOnlyOptions, TrackingError, motion_only_ba};

/// Motion-only BA of one pose against fixed world points (eq. 4.15) as the study runs it: least
/// squares (no robust kernel: the study's data association is perfect), `iterations` LM
/// iterations from `initial`. A keyframe that measures no map point keeps `initial` (the
/// prediction is all there is); any other failure is an error.
pub fn motion_only<P: Projector<N> + Clone, const N: usize>(
    projector: &P,
    initial: &Se3,
    points_world: &[Vector3<f64>],
    measurements: &[SVector<f64, N>],
    sigma: f64,
    iterations: usize,
) -> Result<Se3, TrackingError> {
    if measurements.is_empty() {
        return Ok(*initial);
    }
    let options = MotionOnlyOptions {
        sigma,
        kernel: None,
        iterations,
        min_matches: 1,
    };
    motion_only_ba(projector, initial, points_world, measurements, &options)
        .map(|fit| fit.camera_from_world)
}
