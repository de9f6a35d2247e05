//! Rectified stereo (thesis §3.2.2) and RGB-D as virtual stereo (thesis §6.3).

use crate::{CameraError, CameraModel, PinholeCamera, check_in_front};
use nalgebra::{Matrix3, Vector2, Vector3};

/// A rectified stereo pair: two identical pinhole cameras, the right one displaced by the
/// baseline `b` along the left camera's `x` axis (`T_rl` = translation `(−b, 0, 0)`).
///
/// A stereo measurement is `z = (u_l, v_l, u_r)ᵀ` (thesis §3.2.2). Forward model (thesis eq. 3.8,
/// B.5): `ẑ_stereo(x) = (f_x x₁/x₃ + c_x, f_y x₂/x₃ + c_y, f_x (x₁ − b)/x₃ + c_x)ᵀ`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StereoCamera {
    /// The (left) rectified pinhole camera.
    pub pinhole: PinholeCamera,
    /// The baseline `b > 0` in metres (distance between the two optical centres).
    pub baseline: f64,
}

impl StereoCamera {
    /// Creates a rectified stereo camera.
    pub fn new(pinhole: PinholeCamera, baseline: f64) -> Self {
        Self { pinhole, baseline }
    }

    /// Projects a left-camera-frame point to `(u_l, v_l, u_r)` (thesis eq. 3.8).
    pub fn project(&self, x: &Vector3<f64>) -> Result<Vector3<f64>, CameraError> {
        check_in_front(x)?;
        let c = &self.pinhole;
        Ok(Vector3::new(
            c.fx * x.x / x.z + c.cx,
            c.fy * x.y / x.z + c.cy,
            c.fx * (x.x - self.baseline) / x.z + c.cx,
        ))
    }

    /// Projects and returns the 3×3 Jacobian `∂ẑ_stereo/∂x` (thesis eq. B.6):
    /// `(1/x₃) [[f_x, 0, −f_x x₁/x₃], [0, f_y, −f_y x₂/x₃], [f_x, 0, −f_x (x₁ − b)/x₃]]`.
    pub fn project_with_jacobian(
        &self,
        x: &Vector3<f64>,
    ) -> Result<(Vector3<f64>, Matrix3<f64>), CameraError> {
        let z = self.project(x)?;
        let c = &self.pinhole;
        let iz = 1.0 / x.z;
        let j = Matrix3::new(
            c.fx * iz,
            0.0,
            -c.fx * x.x * iz * iz,
            0.0,
            c.fy * iz,
            -c.fy * x.y * iz * iz,
            c.fx * iz,
            0.0,
            -c.fx * (x.x - self.baseline) * iz * iz,
        );
        Ok((z, j))
    }

    /// Depth from disparity `d = u_l − u_r`: `x₃ = f_x·b/d` (thesis eq. 3.9, 6.6).
    pub fn depth_from_disparity(&self, disparity: f64) -> Result<f64, CameraError> {
        if !disparity.is_finite() {
            return Err(CameraError::NotFinite);
        }
        if disparity <= 0.0 {
            return Err(CameraError::NonPositiveDisparity { disparity });
        }
        Ok(self.pinhole.fx * self.baseline / disparity)
    }

    /// Disparity from depth: `d = f_x·b/x₃`.
    pub fn disparity_from_depth(&self, depth: f64) -> Result<f64, CameraError> {
        if !depth.is_finite() {
            return Err(CameraError::NotFinite);
        }
        if depth <= crate::MIN_DEPTH {
            return Err(CameraError::BehindCamera { depth });
        }
        Ok(self.pinhole.fx * self.baseline / depth)
    }

    /// Inverse model (thesis eq. 3.9): the left-camera-frame point of measurement
    /// `(u_l, v_l, u_r)`, `x = (x₃/f_x (u_l − c_x), x₃/f_y (v_l − c_y), x₃)` with
    /// `x₃ = f_x b/(u_l − u_r)`. Non-positive disparities are rejected.
    pub fn unproject(&self, z: &Vector3<f64>) -> Result<Vector3<f64>, CameraError> {
        let depth = self.depth_from_disparity(z.x - z.z)?;
        self.pinhole.unproject_depth(&Vector2::new(z.x, z.y), depth)
    }

    /// The 3×3 Jacobian of [`unproject`](Self::unproject) with respect to `(u_l, v_l, u_r)`.
    ///
    /// With `d = u_l − u_r`, `x₃ = f_x b/d`, `∂x₃/∂u_l = −x₃/d`, `∂x₃/∂u_r = x₃/d`;
    /// `x₁ = x₃(u_l − c_x)/f_x`, `x₂ = x₃(v_l − c_y)/f_y`.
    pub fn unproject_jacobian(&self, z: &Vector3<f64>) -> Result<Matrix3<f64>, CameraError> {
        let d = z.x - z.z;
        let depth = self.depth_from_disparity(d)?;
        let c = &self.pinhole;
        let mx = (z.x - c.cx) / c.fx;
        let my = (z.y - c.cy) / c.fy;
        let dz_dul = -depth / d;
        let dz_dur = depth / d;
        Ok(Matrix3::new(
            depth / c.fx + mx * dz_dul,
            0.0,
            mx * dz_dur,
            my * dz_dul,
            depth / c.fy,
            my * dz_dur,
            dz_dul,
            0.0,
            dz_dur,
        ))
    }
}

/// An RGB-D camera treated as a virtual stereo camera (thesis §6.3): a depth measurement `x₃` at
/// pixel `(u, v)` becomes the stereo measurement `(u, v, u − f_x b/x₃)` of a virtual right camera
/// with a chosen baseline `b`, so that the stereo machinery (factors, disparity-space
/// uncertainty) applies unchanged.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RgbdCamera {
    /// The equivalent rectified stereo camera (colour camera + virtual right camera).
    pub stereo: StereoCamera,
}

impl RgbdCamera {
    /// Creates an RGB-D camera with the given pinhole intrinsics and virtual baseline (metres).
    /// For a Kinect-like sensor, the projector–camera distance (≈ 0.075 m) is a natural choice.
    pub fn new(pinhole: PinholeCamera, virtual_baseline: f64) -> Self {
        Self {
            stereo: StereoCamera::new(pinhole, virtual_baseline),
        }
    }

    /// Disparity of a depth measurement: `d = f_x b/x₃`.
    pub fn disparity_from_depth(&self, depth: f64) -> Result<f64, CameraError> {
        self.stereo.disparity_from_depth(depth)
    }

    /// Depth of a disparity: `x₃ = f_x b/d`.
    pub fn depth_from_disparity(&self, disparity: f64) -> Result<f64, CameraError> {
        self.stereo.depth_from_disparity(disparity)
    }

    /// The virtual stereo measurement `(u, v, u − f_x b/x₃)` of a depth pixel.
    pub fn stereo_measurement(
        &self,
        uv: &Vector2<f64>,
        depth: f64,
    ) -> Result<Vector3<f64>, CameraError> {
        if !(uv.x.is_finite() && uv.y.is_finite()) {
            return Err(CameraError::NotFinite);
        }
        let d = self.disparity_from_depth(depth)?;
        Ok(Vector3::new(uv.x, uv.y, uv.x - d))
    }

    /// Projects a camera-frame point to its virtual stereo measurement (thesis eq. 3.8).
    pub fn project(&self, x: &Vector3<f64>) -> Result<Vector3<f64>, CameraError> {
        self.stereo.project(x)
    }

    /// Projection with its 3×3 Jacobian (thesis eq. B.6).
    pub fn project_with_jacobian(
        &self,
        x: &Vector3<f64>,
    ) -> Result<(Vector3<f64>, Matrix3<f64>), CameraError> {
        self.stereo.project_with_jacobian(x)
    }

    /// Back-projects a pixel with depth `x₃` (thesis eq. 3.5).
    pub fn unproject_depth(
        &self,
        uv: &Vector2<f64>,
        depth: f64,
    ) -> Result<Vector3<f64>, CameraError> {
        self.stereo.pinhole.unproject_depth(uv, depth)
    }

    /// The monocular projection of the colour camera (thesis eq. 3.4).
    pub fn project_mono(&self, x: &Vector3<f64>) -> Result<Vector2<f64>, CameraError> {
        self.stereo.pinhole.project(x)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testutil::*;
    use nalgebra::{DMatrix, DVector};

    fn stereo() -> StereoCamera {
        StereoCamera::new(PinholeCamera::new(435.2, 435.2, 367.4, 252.2), 0.11)
    }

    #[test]
    fn stereo_projection_jacobian_matches_numeric() {
        let s = stereo();
        for x in [Vector3::new(0.3, -0.7, 2.1), Vector3::new(-2.0, 1.0, 6.0)] {
            let (_, ana) = s.project_with_jacobian(&x).unwrap();
            let num = numeric_jacobian(
                |p| {
                    DVector::from_column_slice(
                        s.project(&Vector3::new(p[0], p[1], p[2]))
                            .unwrap()
                            .as_slice(),
                    )
                },
                &DVector::from_column_slice(x.as_slice()),
                1e-6,
            );
            assert_close(
                &DMatrix::from_column_slice(3, 3, ana.as_slice()),
                &num,
                1e-6,
            );
        }
    }

    #[test]
    fn stereo_unprojection_round_trip_and_jacobian() {
        let s = stereo();
        let x = Vector3::new(0.5, -0.3, 4.0);
        let z = s.project(&x).unwrap();
        let back = s.unproject(&z).unwrap();
        assert!((back - x).norm() < 1e-10, "{back} vs {x}");
        let ana = s.unproject_jacobian(&z).unwrap();
        let num = numeric_jacobian(
            |p| {
                DVector::from_column_slice(
                    s.unproject(&Vector3::new(p[0], p[1], p[2]))
                        .unwrap()
                        .as_slice(),
                )
            },
            &DVector::from_column_slice(z.as_slice()),
            1e-5,
        );
        assert_close(
            &DMatrix::from_column_slice(3, 3, ana.as_slice()),
            &num,
            1e-6,
        );
    }

    #[test]
    fn stereo_rejects_bad_input() {
        let s = stereo();
        assert!(s.project(&Vector3::new(0.0, 0.0, -1.0)).is_err());
        assert!(matches!(
            s.unproject(&Vector3::new(100.0, 100.0, 100.0)),
            Err(CameraError::NonPositiveDisparity { .. })
        ));
        assert!(s.unproject(&Vector3::new(100.0, 100.0, 110.0)).is_err());
        assert!(s.depth_from_disparity(f64::NAN).is_err());
    }

    #[test]
    fn rgbd_virtual_stereo_is_consistent() {
        let r = RgbdCamera::new(PinholeCamera::new(585.0, 585.0, 320.0, 240.0), 0.075);
        let x = Vector3::new(0.2, 0.1, 1.7);
        let uv = r.project_mono(&x).unwrap();
        let z = r.stereo_measurement(&uv, x.z).unwrap();
        let projected = r.project(&x).unwrap();
        assert!((z - projected).norm() < 1e-9);
        assert!((r.stereo.unproject(&z).unwrap() - x).norm() < 1e-9);
        let d = r.disparity_from_depth(1.7).unwrap();
        assert!((r.depth_from_disparity(d).unwrap() - 1.7).abs() < 1e-12);
        assert!(r.disparity_from_depth(0.0).is_err());
    }
}
