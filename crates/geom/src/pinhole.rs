//! The pinhole (monocular) camera, thesis §3.2.1.

use crate::{CameraError, CameraModel, check_in_front, proj_jacobian};
use nalgebra::{Matrix2, Matrix2x3, Matrix3, Vector2, Vector3};

/// A pinhole camera with focal lengths `(f_x, f_y)` and principal point `p = (c_x, c_y)`, all in
/// pixels.
///
/// Forward model (thesis eq. 3.3–3.4, with separate focal lengths):
/// `ẑ_mono(x) = (f_x·x₁/x₃ + c_x, f_y·x₂/x₃ + c_y)ᵀ`, i.e. `proj(K·x)` with
/// `K = [[f_x, 0, c_x], [0, f_y, c_y], [0, 0, 1]]`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PinholeCamera {
    /// Horizontal focal length `f_x` in pixels.
    pub fx: f64,
    /// Vertical focal length `f_y` in pixels.
    pub fy: f64,
    /// Principal point `c_x` (= `p₁` in the thesis) in pixels.
    pub cx: f64,
    /// Principal point `c_y` (= `p₂` in the thesis) in pixels.
    pub cy: f64,
}

impl PinholeCamera {
    /// Creates a pinhole camera from `f_x, f_y, c_x, c_y` (pixels).
    pub fn new(fx: f64, fy: f64, cx: f64, cy: f64) -> Self {
        Self { fx, fy, cx, cy }
    }

    /// The calibration matrix `K = [[f_x, 0, c_x], [0, f_y, c_y], [0, 0, 1]]` (thesis eq. 3.3).
    pub fn k_matrix(&self) -> Matrix3<f64> {
        Matrix3::new(self.fx, 0.0, self.cx, 0.0, self.fy, self.cy, 0.0, 0.0, 1.0)
    }

    /// Maps a normalised image point `m = proj(x)` to pixels: `(f_x m₁ + c_x, f_y m₂ + c_y)`.
    pub fn pixel_from_normalised(&self, m: &Vector2<f64>) -> Vector2<f64> {
        Vector2::new(self.fx * m.x + self.cx, self.fy * m.y + self.cy)
    }

    /// Maps a pixel to the normalised image plane: `((u − c_x)/f_x, (v − c_y)/f_y)`.
    pub fn normalised_from_pixel(&self, uv: &Vector2<f64>) -> Vector2<f64> {
        Vector2::new((uv.x - self.cx) / self.fx, (uv.y - self.cy) / self.fy)
    }

    /// The diagonal 2×2 matrix `diag(f_x, f_y)`, the Jacobian of
    /// [`pixel_from_normalised`](Self::pixel_from_normalised).
    pub fn focal_matrix(&self) -> Matrix2<f64> {
        Matrix2::new(self.fx, 0.0, 0.0, self.fy)
    }

    /// Back-projects pixel `(u, v)` at depth `x₃` to the camera-frame point
    /// `x = (x₃/f_x·(u − c_x), x₃/f_y·(v − c_y), x₃)ᵀ` (thesis eq. 3.5, without the pose).
    ///
    /// Depths `x₃ ≤` [`MIN_DEPTH`](crate::MIN_DEPTH) give [`CameraError::BehindCamera`].
    pub fn unproject_depth(
        &self,
        uv: &Vector2<f64>,
        depth: f64,
    ) -> Result<Vector3<f64>, CameraError> {
        if !(uv.x.is_finite() && uv.y.is_finite() && depth.is_finite()) {
            return Err(CameraError::NotFinite);
        }
        if depth <= crate::MIN_DEPTH {
            return Err(CameraError::BehindCamera { depth });
        }
        let m = self.normalised_from_pixel(uv);
        Ok(Vector3::new(m.x * depth, m.y * depth, depth))
    }

    /// The 3×3 Jacobian of [`unproject_depth`](Self::unproject_depth) with respect to
    /// `(u, v, x₃)`:
    /// `[[x₃/f_x, 0, (u − c_x)/f_x], [0, x₃/f_y, (v − c_y)/f_y], [0, 0, 1]]`.
    pub fn unproject_depth_jacobian(&self, uv: &Vector2<f64>, depth: f64) -> Matrix3<f64> {
        Matrix3::new(
            depth / self.fx,
            0.0,
            (uv.x - self.cx) / self.fx,
            0.0,
            depth / self.fy,
            (uv.y - self.cy) / self.fy,
            0.0,
            0.0,
            1.0,
        )
    }

    /// The same camera for an image scaled by `s` (e.g. `s = 0.5` for the next pyramid level
    /// with half-sampling, where pixel centres map as `u' = s·(u + ½) − ½`).
    pub fn scaled(&self, s: f64) -> Self {
        Self {
            fx: self.fx * s,
            fy: self.fy * s,
            cx: (self.cx + 0.5) * s - 0.5,
            cy: (self.cy + 0.5) * s - 0.5,
        }
    }
}

impl CameraModel for PinholeCamera {
    /// `ẑ_mono(x) = K·proj(x)` (thesis eq. 3.4).
    fn project(&self, x: &Vector3<f64>) -> Result<Vector2<f64>, CameraError> {
        check_in_front(x)?;
        Ok(Vector2::new(
            self.fx * x.x / x.z + self.cx,
            self.fy * x.y / x.z + self.cy,
        ))
    }

    /// Jacobian (thesis eq. B.4, with separate focal lengths):
    /// `∂ẑ/∂x = (1/x₃) [[f_x, 0, −f_x x₁/x₃], [0, f_y, −f_y x₂/x₃]]`.
    fn project_with_jacobian(
        &self,
        x: &Vector3<f64>,
    ) -> Result<(Vector2<f64>, Matrix2x3<f64>), CameraError> {
        let uv = self.project(x)?;
        Ok((uv, self.focal_matrix() * proj_jacobian(x)))
    }

    fn unproject(&self, uv: &Vector2<f64>) -> Result<Vector3<f64>, CameraError> {
        self.unproject_depth(uv, 1.0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testutil::*;
    use nalgebra::{DMatrix, DVector};

    fn cam() -> PinholeCamera {
        PinholeCamera::new(458.654, 457.296, 367.215, 248.375)
    }

    #[test]
    fn projection_jacobian_matches_numeric() {
        let c = cam();
        for x in [
            Vector3::new(0.3, -0.7, 2.1),
            Vector3::new(-1.5, 0.2, 0.5),
            Vector3::new(0.0, 0.0, 10.0),
        ] {
            let (_, ana) = c.project_with_jacobian(&x).unwrap();
            let num = numeric_jacobian(
                |p| {
                    DVector::from_column_slice(
                        c.project(&Vector3::new(p[0], p[1], p[2]))
                            .unwrap()
                            .as_slice(),
                    )
                },
                &DVector::from_column_slice(x.as_slice()),
                1e-6,
            );
            assert_close(
                &DMatrix::from_column_slice(2, 3, ana.as_slice()),
                &num,
                1e-6,
            );
        }
    }

    #[test]
    fn unprojection_round_trip_and_jacobian() {
        let c = cam();
        let x = Vector3::new(0.4, -0.2, 3.0);
        let uv = c.project(&x).unwrap();
        let back = c.unproject_depth(&uv, 3.0).unwrap();
        assert!((back - x).norm() < 1e-12);
        let ana = c.unproject_depth_jacobian(&uv, 3.0);
        let num = numeric_jacobian(
            |p| {
                DVector::from_column_slice(
                    c.unproject_depth(&Vector2::new(p[0], p[1]), p[2])
                        .unwrap()
                        .as_slice(),
                )
            },
            &DVector::from_column_slice(&[uv.x, uv.y, 3.0]),
            1e-5,
        );
        assert_close(
            &DMatrix::from_column_slice(3, 3, ana.as_slice()),
            &num,
            1e-7,
        );
        let ray = c.unproject(&uv).unwrap();
        assert!((ray * 3.0 - x).norm() < 1e-12);
    }

    #[test]
    fn behind_camera_is_reported() {
        let c = cam();
        assert!(matches!(
            c.project(&Vector3::new(0.1, 0.1, -2.0)),
            Err(CameraError::BehindCamera { .. })
        ));
        assert!(c.unproject_depth(&Vector2::new(1.0, 1.0), -1.0).is_err());
        assert!(
            c.unproject_depth(&Vector2::new(f64::NAN, 1.0), 1.0)
                .is_err()
        );
    }

    #[test]
    fn scaled_camera_matches_half_sampling() {
        // A pixel centre u in the full image lies at (u + 0.5)/2 − 0.5 at half resolution.
        let c = cam();
        let h = c.scaled(0.5);
        let x = Vector3::new(0.3, 0.1, 2.0);
        let full = c.project(&x).unwrap();
        let half = h.project(&x).unwrap();
        assert!((half.x - ((full.x + 0.5) * 0.5 - 0.5)).abs() < 1e-12);
        assert!((half.y - ((full.y + 0.5) * 0.5 - 0.5)).abs() < 1e-12);
    }
}
