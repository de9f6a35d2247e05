//! The Bundler / BAL ("Bundle Adjustment in the Large", Agarwal et al. 2010) camera.

use crate::CameraError;
use nalgebra::{Matrix2x3, Vector2, Vector3};

/// A BAL projection with its Jacobians: `(ẑ, ∂ẑ/∂P, ∂ẑ/∂(f, k₁, k₂))`.
pub type BalProjection = (Vector2<f64>, Matrix2x3<f64>, Matrix2x3<f64>);

/// The Snavely/Bundler camera used by the BAL problems, with intrinsics `(f, k₁, k₂)`.
///
/// Its conventions differ from the rest of this crate (thesis §3.2.1): the camera looks down
/// its **−z** axis, and the measurement origin is the image centre with `y` up. For a
/// camera-frame point `P = R·X + t`:
///
/// `p = −(P_x/P_z, P_y/P_z)`, `r(p) = 1 + k₁‖p‖² + k₂‖p‖⁴`, `ẑ = f·r(p)·p`.
///
/// A point is in front of the camera iff `P_z < 0`; points with `P_z ≥ −`[`MIN_DEPTH`](crate::MIN_DEPTH)
/// are reported as [`CameraError::BehindCamera`] with `depth = −P_z`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BalCamera {
    /// Focal length `f` (pixels).
    pub f: f64,
    /// Radial distortion coefficient `k₁` of `‖p‖²`.
    pub k1: f64,
    /// Radial distortion coefficient `k₂` of `‖p‖⁴`.
    pub k2: f64,
}

impl BalCamera {
    /// Creates a BAL camera from `(f, k₁, k₂)`.
    pub fn new(f: f64, k1: f64, k2: f64) -> Self {
        Self { f, k1, k2 }
    }

    /// Projects a camera-frame point `P` (already `R·X + t`) to the BAL measurement
    /// `ẑ = f·r(p)·p` with `p = −P_{xy}/P_z`.
    pub fn project(&self, p_cam: &Vector3<f64>) -> Result<Vector2<f64>, CameraError> {
        Ok(self.project_with_jacobians(p_cam)?.0)
    }

    /// Projects and returns the Jacobians `∂ẑ/∂P` (2×3) and `∂ẑ/∂(f, k₁, k₂)` (2×3).
    ///
    /// With `n = −P_{xy}/P_z`, `s = ‖n‖²`, `r = 1 + k₁s + k₂s²`:
    /// - `∂n/∂P = [[−1/P_z, 0, P_x/P_z²], [0, −1/P_z, P_y/P_z²]]`,
    /// - `∂ẑ/∂n = f·(r·I + n·(2k₁ + 4k₂s)·nᵀ)`,
    /// - `∂ẑ/∂f = r·n`, `∂ẑ/∂k₁ = f·s·n`, `∂ẑ/∂k₂ = f·s²·n`.
    pub fn project_with_jacobians(
        &self,
        p_cam: &Vector3<f64>,
    ) -> Result<BalProjection, CameraError> {
        let (px, py, pz) = (p_cam.x, p_cam.y, p_cam.z);
        if !(px.is_finite() && py.is_finite() && pz.is_finite()) {
            return Err(CameraError::NotFinite);
        }
        if pz >= -crate::MIN_DEPTH {
            return Err(CameraError::BehindCamera { depth: -pz });
        }
        let n = Vector2::new(-px / pz, -py / pz);
        let s = n.norm_squared();
        let r = 1.0 + s * (self.k1 + self.k2 * s);
        let z = n * (self.f * r);
        let dn_dp = Matrix2x3::new(
            -1.0 / pz,
            0.0,
            px / (pz * pz),
            0.0,
            -1.0 / pz,
            py / (pz * pz),
        );
        let dr_ds = self.k1 + 2.0 * self.k2 * s;
        let dz_dn =
            (nalgebra::Matrix2::identity() * r + n * n.transpose() * (2.0 * dr_ds)) * self.f;
        let j_point = dz_dn * dn_dp;
        let mut j_intr = Matrix2x3::zeros();
        j_intr.set_column(0, &(n * r));
        j_intr.set_column(1, &(n * (self.f * s)));
        j_intr.set_column(2, &(n * (self.f * s * s)));
        Ok((z, j_point, j_intr))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testutil::*;
    use nalgebra::{DMatrix, DVector};

    #[test]
    fn bal_jacobians_match_numeric() {
        let cam = BalCamera::new(399.75, -3.2e-7, 5.9e-13);
        let strong = BalCamera::new(500.0, -0.1, 0.02);
        for c in [cam, strong] {
            for p in [Vector3::new(0.3, -0.4, -2.0), Vector3::new(-1.0, 0.7, -3.5)] {
                let (_, jp, ji) = c.project_with_jacobians(&p).unwrap();
                let num_p = numeric_jacobian(
                    |q| {
                        DVector::from_column_slice(
                            c.project(&Vector3::new(q[0], q[1], q[2]))
                                .unwrap()
                                .as_slice(),
                        )
                    },
                    &DVector::from_column_slice(p.as_slice()),
                    1e-6,
                );
                assert_close(
                    &DMatrix::from_column_slice(2, 3, jp.as_slice()),
                    &num_p,
                    1e-6,
                );
                let num_i = numeric_jacobian(
                    |q| {
                        DVector::from_column_slice(
                            BalCamera::new(q[0], q[1], q[2])
                                .project(&p)
                                .unwrap()
                                .as_slice(),
                        )
                    },
                    &DVector::from_column_slice(&[c.f, c.k1, c.k2]),
                    1e-6,
                );
                assert_close(
                    &DMatrix::from_column_slice(2, 3, ji.as_slice()),
                    &num_i,
                    1e-6,
                );
            }
        }
    }

    #[test]
    fn bal_sign_conventions() {
        let c = BalCamera::new(100.0, 0.0, 0.0);
        // A point on −z with positive x projects to negative-free p = −P/P_z = (+, ·).
        let z = c.project(&Vector3::new(1.0, 2.0, -4.0)).unwrap();
        assert!((z - Vector2::new(25.0, 50.0)).norm() < 1e-12);
        assert!(matches!(
            c.project(&Vector3::new(1.0, 2.0, 4.0)),
            Err(CameraError::BehindCamera { .. })
        ));
        assert!(c.project(&Vector3::new(1.0, f64::INFINITY, -4.0)).is_err());
    }
}
