//! Lens distortion on normalised image coordinates, with iterative undistortion.
//!
//! A distorted camera maps a camera-frame point `x` to pixels by
//! `ẑ(x) = K·δ(proj(x))` where `proj` is the perspective division (thesis eq. 3.2), `δ` the
//! distortion on the normalised image plane and `K` the pinhole calibration (thesis eq. 3.3).
//! By the chain rule `∂ẑ/∂x = diag(f_x, f_y) · ∂δ/∂m · ∂proj/∂x` (thesis eq. B.2).

use crate::{CameraError, CameraModel, PinholeCamera, check_in_front, proj, proj_jacobian};
use nalgebra::{Matrix2, Matrix2x3, Vector2, Vector3};

/// Maximum number of Newton iterations used by undistortion.
pub const UNDISTORT_MAX_ITERATIONS: usize = 30;
/// Convergence tolerance of undistortion, in normalised image units (‖δ(m) − m_d‖).
pub const UNDISTORT_TOLERANCE: f64 = 1e-12;

/// A lens distortion model `m_d = δ(m)` acting on normalised image coordinates `m = proj(x)`.
pub trait Distortion {
    /// Applies the distortion: `m_d = δ(m)`.
    fn distort(&self, m: &Vector2<f64>) -> Vector2<f64>;

    /// The 2×2 Jacobian `∂δ(m)/∂m` with respect to the undistorted normalised point.
    fn distort_jacobian(&self, m: &Vector2<f64>) -> Matrix2<f64>;

    /// Inverts the distortion: finds `m` with `δ(m) = m_d` by Gauss-Newton iterations
    /// `m ← m − (∂δ/∂m)⁻¹ (δ(m) − m_d)` started at `m = m_d`, stopping when
    /// ‖δ(m) − m_d‖ < [`UNDISTORT_TOLERANCE`]; returns
    /// [`CameraError::UndistortionDiverged`] if that does not happen within
    /// [`UNDISTORT_MAX_ITERATIONS`] (e.g. outside the invertible domain of the polynomial).
    /// A root on a folded branch of the polynomial (`det ∂δ/∂m ≤ 0` or `m·m_d ≤ 0`) is not a
    /// physical preimage and is rejected the same way.
    fn undistort(&self, m_d: &Vector2<f64>) -> Result<Vector2<f64>, CameraError> {
        if !(m_d.x.is_finite() && m_d.y.is_finite()) {
            return Err(CameraError::NotFinite);
        }
        let mut m = *m_d;
        let mut residual = f64::INFINITY;
        for it in 0..UNDISTORT_MAX_ITERATIONS {
            let r = self.distort(&m) - m_d;
            residual = r.norm();
            if !residual.is_finite() {
                break;
            }
            if residual < UNDISTORT_TOLERANCE {
                return self.check_preimage(m, m_d, residual, it);
            }
            let j = self.distort_jacobian(&m);
            let Some(ji) = j.try_inverse() else {
                return Err(CameraError::UndistortionDiverged {
                    residual,
                    iterations: it,
                });
            };
            m -= ji * r;
        }
        let r = (self.distort(&m) - m_d).norm();
        if r < 1e3 * UNDISTORT_TOLERANCE {
            // Converged to rounding precision (the residual floor of f64 at this radius).
            return self.check_preimage(m, m_d, r, UNDISTORT_MAX_ITERATIONS);
        }
        Err(CameraError::UndistortionDiverged {
            residual: residual.min(r),
            iterations: UNDISTORT_MAX_ITERATIONS,
        })
    }
}

/// Accepts a converged undistortion only on the physical (orientation-preserving) branch.
trait PreimageCheck {
    fn check_preimage(
        &self,
        m: Vector2<f64>,
        m_d: &Vector2<f64>,
        residual: f64,
        iterations: usize,
    ) -> Result<Vector2<f64>, CameraError>;
}

impl<D: Distortion + ?Sized> PreimageCheck for D {
    fn check_preimage(
        &self,
        m: Vector2<f64>,
        m_d: &Vector2<f64>,
        residual: f64,
        iterations: usize,
    ) -> Result<Vector2<f64>, CameraError> {
        if self.distort_jacobian(&m).determinant() > 0.0 && m.dot(m_d) >= 0.0 {
            Ok(m)
        } else {
            Err(CameraError::UndistortionDiverged {
                residual,
                iterations,
            })
        }
    }
}

/// Radial-tangential ("plumb bob", OpenCV/EuRoC `radtan`) distortion:
///
/// `r² = m₁² + m₂²`, `ρ = 1 + k₁r² + k₂r⁴ + k₃r⁶`,
/// `δ(m) = (m₁ρ + 2p₁m₁m₂ + p₂(r² + 2m₁²), m₂ρ + p₁(r² + 2m₂²) + 2p₂m₁m₂)`.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct RadTan {
    /// Radial coefficient `k₁`.
    pub k1: f64,
    /// Radial coefficient `k₂`.
    pub k2: f64,
    /// Tangential coefficient `p₁`.
    pub p1: f64,
    /// Tangential coefficient `p₂`.
    pub p2: f64,
    /// Radial coefficient `k₃` (0 for the four-parameter EuRoC model).
    pub k3: f64,
}

impl RadTan {
    /// The four-parameter model `(k₁, k₂, p₁, p₂)` with `k₃ = 0`, as in EuRoC's `sensor.yaml`.
    pub fn new(k1: f64, k2: f64, p1: f64, p2: f64) -> Self {
        Self {
            k1,
            k2,
            p1,
            p2,
            k3: 0.0,
        }
    }
}

impl Distortion for RadTan {
    fn distort(&self, m: &Vector2<f64>) -> Vector2<f64> {
        let (x, y) = (m.x, m.y);
        let r2 = x * x + y * y;
        let rho = 1.0 + r2 * (self.k1 + r2 * (self.k2 + r2 * self.k3));
        Vector2::new(
            x * rho + 2.0 * self.p1 * x * y + self.p2 * (r2 + 2.0 * x * x),
            y * rho + self.p1 * (r2 + 2.0 * y * y) + 2.0 * self.p2 * x * y,
        )
    }

    /// `∂δ/∂m` with `∂ρ/∂m = (2k₁ + 4k₂r² + 6k₃r⁴)·m`.
    fn distort_jacobian(&self, m: &Vector2<f64>) -> Matrix2<f64> {
        let (x, y) = (m.x, m.y);
        let r2 = x * x + y * y;
        let rho = 1.0 + r2 * (self.k1 + r2 * (self.k2 + r2 * self.k3));
        let drho_dr2 = self.k1 + r2 * (2.0 * self.k2 + 3.0 * self.k3 * r2);
        let drho_dx = 2.0 * x * drho_dr2;
        let drho_dy = 2.0 * y * drho_dr2;
        Matrix2::new(
            rho + x * drho_dx + 2.0 * self.p1 * y + 6.0 * self.p2 * x,
            x * drho_dy + 2.0 * self.p1 * x + 2.0 * self.p2 * y,
            y * drho_dx + 2.0 * self.p1 * x + 2.0 * self.p2 * y,
            rho + y * drho_dy + 6.0 * self.p1 * y + 2.0 * self.p2 * x,
        )
    }
}

/// Equidistant (Kannala-Brandt) fisheye distortion, as in OpenCV's `fisheye` module and
/// EuRoC/Kalibr's `equidistant` model:
///
/// `r = ‖m‖`, `θ = atan(r)`, `θ_d = θ(1 + k₁θ² + k₂θ⁴ + k₃θ⁶ + k₄θ⁸)`, `δ(m) = (θ_d/r)·m`
/// (and `δ(0) = 0`).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Equidistant {
    /// Coefficient `k₁` of `θ³`.
    pub k1: f64,
    /// Coefficient `k₂` of `θ⁵`.
    pub k2: f64,
    /// Coefficient `k₃` of `θ⁷`.
    pub k3: f64,
    /// Coefficient `k₄` of `θ⁹`.
    pub k4: f64,
}

impl Equidistant {
    /// Creates the model from `(k₁, k₂, k₃, k₄)`.
    pub fn new(k1: f64, k2: f64, k3: f64, k4: f64) -> Self {
        Self { k1, k2, k3, k4 }
    }

    /// `θ_d(θ) = θ(1 + k₁θ² + k₂θ⁴ + k₃θ⁶ + k₄θ⁸)` and its derivative `dθ_d/dθ`.
    fn theta_d(&self, theta: f64) -> (f64, f64) {
        let t2 = theta * theta;
        let poly = 1.0 + t2 * (self.k1 + t2 * (self.k2 + t2 * (self.k3 + t2 * self.k4)));
        let dpoly = 1.0
            + t2 * (3.0 * self.k1
                + t2 * (5.0 * self.k2 + t2 * (7.0 * self.k3 + t2 * 9.0 * self.k4)));
        (theta * poly, dpoly)
    }
}

impl Distortion for Equidistant {
    fn distort(&self, m: &Vector2<f64>) -> Vector2<f64> {
        let r = m.norm();
        if r < 1e-12 {
            return *m;
        }
        let (td, _) = self.theta_d(r.atan());
        m * (td / r)
    }

    /// `∂δ/∂m = s·I + (ds/dr)·m mᵀ/r` with `s = θ_d/r` and
    /// `ds/dr = (θ_d'(θ)/(1 + r²) − s)/r`.
    fn distort_jacobian(&self, m: &Vector2<f64>) -> Matrix2<f64> {
        let r = m.norm();
        if r < 1e-9 {
            // δ(m) = m + O(r³) near the centre.
            return Matrix2::identity();
        }
        let theta = r.atan();
        let (td, dtd) = self.theta_d(theta);
        let s = td / r;
        let ds_dr = (dtd / (1.0 + r * r) - s) / r;
        Matrix2::identity() * s + (m * m.transpose()) * (ds_dr / r)
    }

    /// Radial Newton inversion: solves `θ_d(θ) = ‖m_d‖` for `θ` (monotone where
    /// `dθ_d/dθ > 0`), then `m = tan(θ)·m_d/‖m_d‖`. Fails if `θ` leaves `[0, π/2)` or does not
    /// converge.
    fn undistort(&self, m_d: &Vector2<f64>) -> Result<Vector2<f64>, CameraError> {
        if !(m_d.x.is_finite() && m_d.y.is_finite()) {
            return Err(CameraError::NotFinite);
        }
        let rd = m_d.norm();
        if rd < 1e-12 {
            return Ok(*m_d);
        }
        let mut theta = rd.min(1.5);
        let mut residual = f64::INFINITY;
        for _ in 0..UNDISTORT_MAX_ITERATIONS {
            let (td, dtd) = self.theta_d(theta);
            residual = (td - rd).abs();
            if residual < UNDISTORT_TOLERANCE {
                break;
            }
            if dtd.abs() < 1e-12 {
                break;
            }
            theta -= (td - rd) / dtd;
            if !theta.is_finite() {
                break;
            }
        }
        if residual.is_nan()
            || residual >= 1e3 * UNDISTORT_TOLERANCE
            || !(0.0..std::f64::consts::FRAC_PI_2).contains(&theta)
        {
            return Err(CameraError::UndistortionDiverged {
                residual,
                iterations: UNDISTORT_MAX_ITERATIONS,
            });
        }
        Ok(m_d * (theta.tan() / rd))
    }
}

/// A pinhole camera with lens distortion: `ẑ(x) = K·δ(proj(x))`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DistortedCamera<D: Distortion> {
    /// Pinhole intrinsics `K` (thesis eq. 3.3).
    pub pinhole: PinholeCamera,
    /// Lens distortion `δ` on normalised coordinates.
    pub distortion: D,
}

impl<D: Distortion> DistortedCamera<D> {
    /// Combines pinhole intrinsics with a distortion model.
    pub fn new(pinhole: PinholeCamera, distortion: D) -> Self {
        Self {
            pinhole,
            distortion,
        }
    }

    /// Distorts an ideal (undistorted) pixel: `K·δ(K⁻¹·uv)`.
    pub fn distort_pixel(&self, uv: &Vector2<f64>) -> Vector2<f64> {
        let m = self.pinhole.normalised_from_pixel(uv);
        self.pinhole
            .pixel_from_normalised(&self.distortion.distort(&m))
    }

    /// Undistorts a pixel: `K·δ⁻¹(K⁻¹·uv)` (iterative, see [`Distortion::undistort`]).
    pub fn undistort_pixel(&self, uv: &Vector2<f64>) -> Result<Vector2<f64>, CameraError> {
        let m = self.pinhole.normalised_from_pixel(uv);
        Ok(self
            .pinhole
            .pixel_from_normalised(&self.distortion.undistort(&m)?))
    }
}

impl<D: Distortion> CameraModel for DistortedCamera<D> {
    fn project(&self, x: &Vector3<f64>) -> Result<Vector2<f64>, CameraError> {
        let m = proj(x)?;
        Ok(self
            .pinhole
            .pixel_from_normalised(&self.distortion.distort(&m)))
    }

    /// `∂ẑ/∂x = diag(f_x, f_y) · ∂δ/∂m · ∂proj/∂x` (thesis eq. B.2 for the last factor).
    fn project_with_jacobian(
        &self,
        x: &Vector3<f64>,
    ) -> Result<(Vector2<f64>, Matrix2x3<f64>), CameraError> {
        check_in_front(x)?;
        let m = proj(x)?;
        let uv = self
            .pinhole
            .pixel_from_normalised(&self.distortion.distort(&m));
        let j =
            self.pinhole.focal_matrix() * self.distortion.distort_jacobian(&m) * proj_jacobian(x);
        Ok((uv, j))
    }

    fn unproject(&self, uv: &Vector2<f64>) -> Result<Vector3<f64>, CameraError> {
        let m = self
            .distortion
            .undistort(&self.pinhole.normalised_from_pixel(uv))?;
        Ok(Vector3::new(m.x, m.y, 1.0))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testutil::*;
    use nalgebra::{DMatrix, DVector};

    fn euroc_radtan() -> RadTan {
        RadTan::new(-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05)
    }

    fn strong_radtan() -> RadTan {
        RadTan {
            k1: -0.3,
            k2: 0.1,
            p1: 0.001,
            p2: -0.002,
            k3: -0.01,
        }
    }

    fn fisheye() -> Equidistant {
        // Typical Kalibr equidistant values (EuRoC/TUM-VI style).
        Equidistant::new(0.0034, 0.0007, -0.0044, 0.0011)
    }

    fn points() -> Vec<Vector2<f64>> {
        vec![
            Vector2::new(0.0, 0.0),
            Vector2::new(0.1, -0.05),
            Vector2::new(-0.4, 0.3),
            Vector2::new(0.6, 0.45),
            Vector2::new(-0.2, -0.5),
        ]
    }

    fn check_jacobian<D: Distortion>(d: &D) {
        for m in points() {
            let ana = d.distort_jacobian(&m);
            let num = numeric_jacobian(
                |p| DVector::from_column_slice(d.distort(&Vector2::new(p[0], p[1])).as_slice()),
                &DVector::from_column_slice(m.as_slice()),
                1e-6,
            );
            assert_close(
                &DMatrix::from_column_slice(2, 2, ana.as_slice()),
                &num,
                1e-7,
            );
        }
    }

    fn check_round_trip<D: Distortion>(d: &D) {
        for m in points() {
            let md = d.distort(&m);
            let back = d.undistort(&md).unwrap();
            assert!((back - m).norm() < 1e-9, "{m} -> {md} -> {back}");
        }
    }

    #[test]
    fn radtan_jacobians_match_numeric() {
        check_jacobian(&euroc_radtan());
        check_jacobian(&strong_radtan());
    }

    #[test]
    fn equidistant_jacobian_matches_numeric() {
        check_jacobian(&fisheye());
        check_jacobian(&Equidistant::new(-0.05, 0.01, 0.002, -0.001));
    }

    #[test]
    fn undistortion_inverts_distortion() {
        check_round_trip(&euroc_radtan());
        check_round_trip(&strong_radtan());
        check_round_trip(&fisheye());
    }

    #[test]
    fn undistortion_reports_failure() {
        // Far outside the monotone domain of a strongly barrel-distorting polynomial there is
        // no preimage: the residual cannot vanish.
        let d = RadTan::new(-0.9, 0.0, 0.0, 0.0);
        assert!(matches!(
            d.undistort(&Vector2::new(3.0, 3.0)),
            Err(CameraError::UndistortionDiverged { .. })
        ));
        assert!(d.undistort(&Vector2::new(f64::NAN, 0.0)).is_err());
        let e = Equidistant::new(-0.5, 0.0, 0.0, 0.0);
        assert!(e.undistort(&Vector2::new(5.0, 0.0)).is_err());
    }

    #[test]
    fn distorted_camera_jacobian_and_unprojection() {
        let pin = PinholeCamera::new(458.654, 457.296, 367.215, 248.375);
        let cam = DistortedCamera::new(pin, euroc_radtan());
        let fish = DistortedCamera::new(pin, fisheye());
        for x in [Vector3::new(0.3, -0.2, 1.5), Vector3::new(-0.8, 0.5, 2.0)] {
            for (uv, ana, f) in [
                {
                    let (uv, j) = cam.project_with_jacobian(&x).unwrap();
                    (uv, j, &cam as &dyn CameraModel)
                },
                {
                    let (uv, j) = fish.project_with_jacobian(&x).unwrap();
                    (uv, j, &fish as &dyn CameraModel)
                },
            ] {
                let num = numeric_jacobian(
                    |p| {
                        DVector::from_column_slice(
                            f.project(&Vector3::new(p[0], p[1], p[2]))
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
                let ray = f.unproject(&uv).unwrap();
                assert!((ray * x.z - x).norm() < 1e-8);
            }
        }
        assert!(cam.project(&Vector3::new(0.0, 0.0, -1.0)).is_err());
        let uv = Vector2::new(100.0, 50.0);
        let und = cam.undistort_pixel(&uv).unwrap();
        assert!((cam.distort_pixel(&und) - uv).norm() < 1e-8);
    }
}
