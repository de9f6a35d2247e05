//! `geom`: camera models, projections and their analytic Jacobians.
//!
//! Conventions (thesis §3.2.1): image coordinates have their origin at the top-left pixel, `u`
//! to the right, `v` down; the camera frame has `x` right, `y` down and `z` forward (along the
//! optical axis). A point `x` in the camera frame is obtained from a world point `y` by
//! `x = T_cw · y` (thesis eq. 3.1); this crate works on camera-frame points only, the pose part
//! of a measurement function lives with the factors.
//!
//! Contents:
//! - [`proj`] / [`proj_jacobian`]: the perspective division `proj(x) = (x₁/x₃, x₂/x₃)` (thesis
//!   eq. 3.2, B.1, B.2),
//! - [`PinholeCamera`]: the monocular forward model `ẑ_mono = K·proj(x)` (thesis eq. 3.3–3.4,
//!   B.3–B.4) and its inverse (eq. 3.5),
//! - [`StereoCamera`]: rectified stereo `(u_l, v_l, u_r)` (thesis eq. 3.8–3.9, B.5–B.6),
//! - [`RgbdCamera`]: an RGB-D camera treated as a virtual stereo camera (depth → disparity with
//!   a chosen baseline, thesis §6.3),
//! - [`RadTan`] and [`Equidistant`]: lens distortion on normalised coordinates with iterative
//!   undistortion, and [`DistortedCamera`] combining either with a pinhole,
//! - [`BalCamera`]: the Bundler / "Bundle Adjustment in the Large" camera `(f, k₁, k₂)` with its
//!   sign conventions (looks down `−z`).
//!
//! - [`ransac`]: seeded RANSAC generic over minimal solvers, with the 3-point similarity of
//!   thesis eq. 5.9–5.14;
//! - [`two_view`]: normalised 8-point essential matrix, pose recovery with the cheirality
//!   check, triangulation, 8-point RANSAC relative pose (thesis §3.5);
//! - [`homography`]: the normalised DLT, transfer and Sampson errors, 4-point RANSAC and the
//!   decomposition into `(R, t/d, n)`;
//! - [`pnp`]: the minimal three-point absolute pose (P3P), the re-projection refinement and
//!   PnP RANSAC (relocalising a monocular camera against its map);
//! - [`bootstrap`]: the monocular two-view bootstrap choosing between the homography and the
//!   essential matrix by Torr's GRIC, with typed "too little parallax" / "ambiguous" states.
//!
//! Points behind a camera are reported as [`CameraError::BehindCamera`], never projected.

#![warn(missing_docs)]

pub mod align;
mod bal;
pub mod bootstrap;
mod distortion;
pub mod homography;
mod pinhole;
pub mod pnp;
pub mod ransac;
mod stereo;
pub mod two_view;

pub use bal::{BalCamera, BalProjection};
pub use distortion::{DistortedCamera, Distortion, Equidistant, RadTan};
pub use pinhole::PinholeCamera;
pub use stereo::{RgbdCamera, StereoCamera};

use nalgebra::{Matrix2x3, Vector2, Vector3};

/// Smallest depth `x₃` (in the camera's units) for which a point counts as in front of the
/// camera. Points with `x₃ ≤ MIN_DEPTH` are reported as behind the camera.
pub const MIN_DEPTH: f64 = 1e-9;

/// Errors of the camera models.
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
pub enum CameraError {
    /// The point lies behind (or on) the camera's image plane: `x₃ ≤` [`MIN_DEPTH`] (for the BAL
    /// camera, which looks down `−z`: `P_z ≥ −MIN_DEPTH`). Its depth is given.
    #[error("point is behind the camera (depth {depth})")]
    BehindCamera {
        /// The depth `x₃` of the offending point along the optical axis.
        depth: f64,
    },
    /// An input coordinate is NaN or infinite.
    #[error("non-finite input coordinate")]
    NotFinite,
    /// A stereo disparity `u_l − u_r` (or a depth) is not positive, so the point would lie at
    /// or beyond infinity.
    #[error("disparity {disparity} is not positive")]
    NonPositiveDisparity {
        /// The offending disparity `u_l − u_r` in pixels.
        disparity: f64,
    },
    /// Iterative undistortion did not converge to the requested tolerance.
    #[error("undistortion did not converge (residual {residual} after {iterations} iterations)")]
    UndistortionDiverged {
        /// Remaining residual ‖distort(p) − p_d‖ in normalised units.
        residual: f64,
        /// Number of iterations performed.
        iterations: usize,
    },
}

/// The perspective division `proj(x) = (x₁/x₃, x₂/x₃)ᵀ` (thesis eq. 3.2 and B.1).
///
/// Returns [`CameraError::BehindCamera`] if `x₃ ≤` [`MIN_DEPTH`] and
/// [`CameraError::NotFinite`] for NaN/∞ input.
pub fn proj(x: &Vector3<f64>) -> Result<Vector2<f64>, CameraError> {
    check_in_front(x)?;
    Ok(Vector2::new(x.x / x.z, x.y / x.z))
}

/// The Jacobian of [`proj`] (thesis eq. B.2):
/// `∂proj(x)/∂x = (1/x₃) [[1, 0, −x₁/x₃], [0, 1, −x₂/x₃]]`.
///
/// Evaluated without a depth check; call it only for points accepted by [`proj`].
pub fn proj_jacobian(x: &Vector3<f64>) -> Matrix2x3<f64> {
    let iz = 1.0 / x.z;
    Matrix2x3::new(iz, 0.0, -x.x * iz * iz, 0.0, iz, -x.y * iz * iz)
}

/// Checks that a camera-frame point is finite and strictly in front of the camera.
pub(crate) fn check_in_front(x: &Vector3<f64>) -> Result<(), CameraError> {
    if !(x.x.is_finite() && x.y.is_finite() && x.z.is_finite()) {
        return Err(CameraError::NotFinite);
    }
    if x.z <= MIN_DEPTH {
        return Err(CameraError::BehindCamera { depth: x.z });
    }
    Ok(())
}

/// A monocular camera model mapping camera-frame points to pixels; implemented by
/// [`PinholeCamera`] and [`DistortedCamera`].
pub trait CameraModel {
    /// Projects a camera-frame point `x` to pixel coordinates `(u, v)`; points behind the camera
    /// give [`CameraError::BehindCamera`].
    fn project(&self, x: &Vector3<f64>) -> Result<Vector2<f64>, CameraError>;

    /// Projects `x` and returns the 2×3 Jacobian `∂(u, v)/∂x` of the projection.
    fn project_with_jacobian(
        &self,
        x: &Vector3<f64>,
    ) -> Result<(Vector2<f64>, Matrix2x3<f64>), CameraError>;

    /// Back-projects a pixel to the camera-frame ray through it, scaled to `x₃ = 1`
    /// (thesis eq. 3.5 with `x₃ = 1`).
    fn unproject(&self, uv: &Vector2<f64>) -> Result<Vector3<f64>, CameraError>;
}

#[cfg(test)]
pub(crate) mod testutil {
    use nalgebra::{DMatrix, DVector};

    /// Central-difference Jacobian of `f` at `x` with step `h`.
    pub fn numeric_jacobian(
        f: impl Fn(&DVector<f64>) -> DVector<f64>,
        x: &DVector<f64>,
        h: f64,
    ) -> DMatrix<f64> {
        let y0 = f(x);
        let mut j = DMatrix::zeros(y0.len(), x.len());
        for k in 0..x.len() {
            let mut xp = x.clone();
            let mut xm = x.clone();
            xp[k] += h;
            xm[k] -= h;
            let d = (f(&xp) - f(&xm)) / (2.0 * h);
            j.set_column(k, &d);
        }
        j
    }

    /// Asserts that two matrices agree to a relative-absolute tolerance.
    pub fn assert_close(a: &DMatrix<f64>, b: &DMatrix<f64>, tol: f64) {
        assert_eq!(a.shape(), b.shape());
        let scale = 1.0 + b.amax();
        let err = (a - b).amax();
        assert!(
            err <= tol * scale,
            "matrices differ by {err} (tol {tol}·{scale}):\n{a}\nvs numeric\n{b}"
        );
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testutil::*;
    use nalgebra::DVector;

    #[test]
    fn proj_jacobian_matches_numeric() {
        let x = Vector3::new(0.3, -0.7, 2.1);
        let f = |p: &DVector<f64>| {
            let r = proj(&Vector3::new(p[0], p[1], p[2])).unwrap();
            DVector::from_column_slice(r.as_slice())
        };
        let num = numeric_jacobian(f, &DVector::from_column_slice(x.as_slice()), 1e-6);
        let ana = proj_jacobian(&x);
        assert_close(
            &nalgebra::DMatrix::from_column_slice(2, 3, ana.as_slice()),
            &num,
            1e-8,
        );
    }

    #[test]
    fn proj_rejects_behind_and_nan() {
        assert!(matches!(
            proj(&Vector3::new(1.0, 1.0, -1.0)),
            Err(CameraError::BehindCamera { .. })
        ));
        assert!(matches!(
            proj(&Vector3::new(1.0, 1.0, 0.0)),
            Err(CameraError::BehindCamera { .. })
        ));
        assert_eq!(
            proj(&Vector3::new(f64::NAN, 1.0, 1.0)),
            Err(CameraError::NotFinite)
        );
    }
}
