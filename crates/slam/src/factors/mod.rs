//! Factors of the estimation problems (thesis §3.3.1, ch. 4, app. B.4–B.5): the measurement
//! models ([`Projector`]), reprojection errors of Euclidean and anchored inverse-depth points
//! for monocular, stereo and RGB-D cameras ([`reprojection`]), and the BAL/Bundler camera with
//! its intrinsics ([`bal`]). The pose-graph constraints are in [`crate::pose_graph`], the
//! constraints of the double window in [`crate::dwo`].
//!
//! Residuals are predicted minus measured, `r = ẑ(x) − z`; the cost is `½ρ(rᵀΛr)`. Poses are
//! `camera_from_world: Se3` updated by `exp(ε)·T` (thesis eq. 2.104).

pub mod bal;
pub mod reprojection;

mod camera;

pub use bal::{BalCameraState, BalObservationFactor};
pub use camera::InverseDepthCamera;
pub use reprojection::{
    AnchoredLinearization, AnchoredObservation, AnchoredPose, InverseDepthObservation,
    MIN_INVERSE_DEPTH, PointObservation, d_inverse_depth_to_point, inverse_depth_to_point,
    linearize_anchored, point_to_inverse_depth, predict_inverse_depth,
};

use geom::{CameraModel, StereoCamera};
use lie::skew;
use nalgebra::{Matrix3, SMatrix, SVector, Vector2, Vector3};
/// A measurement model from camera-frame points to `N` measurement coordinates with its
/// Jacobian (thesis eq. 3.4, 3.9, B.4, B.6): `(u, v)` for monocular cameras, `(u_l, v_l, u_r)`
/// for stereo and RGB-D (virtual stereo).
pub trait Projector<const N: usize>: Send + Sync + 'static {
    /// `(ẑ(x), ∂ẑ/∂x)`, or `None` when `x` is behind the camera (or otherwise not projectable).
    fn project(&self, x: &Vector3<f64>) -> Option<(SVector<f64, N>, SMatrix<f64, N, 3>)>;
}

impl<C: CameraModel + Send + Sync + 'static> Projector<2> for C {
    #[inline]
    fn project(&self, x: &Vector3<f64>) -> Option<(Vector2<f64>, SMatrix<f64, 2, 3>)> {
        self.project_with_jacobian(x).ok()
    }
}

impl Projector<3> for StereoCamera {
    #[inline]
    fn project(&self, x: &Vector3<f64>) -> Option<(Vector3<f64>, Matrix3<f64>)> {
        self.project_with_jacobian(x).ok()
    }
}

impl Projector<3> for geom::RgbdCamera {
    #[inline]
    fn project(&self, x: &Vector3<f64>) -> Option<(Vector3<f64>, Matrix3<f64>)> {
        self.project_with_jacobian(x).ok()
    }
}

/// `∂(exp(ε)·x)/∂ε = [I | −[x]×]` for a camera-frame point `x` (thesis eq. B.12).
#[inline]
pub(crate) fn d_point_d_pose(x: &Vector3<f64>) -> SMatrix<f64, 3, 6> {
    let mut j = SMatrix::<f64, 3, 6>::zeros();
    j.fixed_view_mut::<3, 3>(0, 0)
        .copy_from(&Matrix3::identity());
    j.fixed_view_mut::<3, 3>(0, 3).copy_from(&(-skew(x)));
    j
}

#[cfg(test)]
pub(crate) mod test_support {
    //! Random poses and points for the Jacobian tests of the factors.
    use lie::{LieGroup, Se3};
    use lsq::numeric::check_jacobians;
    use lsq::{Factor, Values};
    use nalgebra::{Vector3, Vector6};
    use rand::Rng;
    use rand_chacha::ChaCha8Rng;

    pub fn random_pose(rng: &mut ChaCha8Rng) -> Se3 {
        Se3::exp(&Vector6::from_fn(|i, _| {
            if i < 3 {
                rng.random_range(-0.5..0.5)
            } else {
                rng.random_range(-0.3..0.3)
            }
        }))
    }

    /// A world point in front of `camera_from_world`, at depth 2–8.
    pub fn point_in_front(rng: &mut ChaCha8Rng, camera_from_world: &Se3) -> Vector3<f64> {
        let x = Vector3::new(
            rng.random_range(-1.0..1.0),
            rng.random_range(-1.0..1.0),
            rng.random_range(2.0..8.0),
        );
        camera_from_world.inverse().act(&x)
    }

    pub fn assert_jacobians(factor: &dyn Factor, values: &Values, what: &str) {
        let check = check_jacobians(factor, values, 1e-5)
            .unwrap_or_else(|| panic!("{what}: undefined at the test point"));
        assert!(check.passes(1e-6), "{what}: {check:?}");
    }
}
