//! SO(3), the group of rotations in 3D (thesis §2.4.3–2.4.7).

use crate::scalar::HalfAngle;
use crate::{LieError, LieGroup, skew, unskew};
use nalgebra::{Matrix3, Quaternion, Rotation3, SMatrix, SVector, UnitQuaternion, Vector3};

/// A rotation in 3D, stored as a unit quaternion.
///
/// Tangent vectors are rotation vectors `ω` (axis times angle, thesis eq. 2.71).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct So3 {
    quaternion: UnitQuaternion<f64>,
}

/// Brings `q` back to unit norm to first order without a square root: `q·(3 − |q|²)/2`.
#[inline]
pub(crate) fn renormalize_first_order(q: Quaternion<f64>) -> UnitQuaternion<f64> {
    let n2 = q.norm_squared();
    UnitQuaternion::new_unchecked(q * (0.5 * (3.0 - n2)))
}

impl So3 {
    /// The rotation of a unit quaternion.
    pub fn from_unit_quaternion(quaternion: UnitQuaternion<f64>) -> Self {
        So3 { quaternion }
    }

    /// The rotation of any non-zero quaternion `(w, x, y, z)`.
    ///
    /// A quaternion `q` rotates by `p ↦ q·p·q⁻¹`, which is invariant to scaling `q`, so a
    /// non-unit quaternion is normalised; a zero or non-finite one is an error.
    pub fn from_quaternion(w: f64, x: f64, y: f64, z: f64) -> Result<Self, LieError> {
        let q = Quaternion::new(w, x, y, z);
        if !(w.is_finite() && x.is_finite() && y.is_finite() && z.is_finite()) {
            return Err(LieError::NonFinite { what: "quaternion" });
        }
        let norm = q.norm();
        if norm < 1e-10 {
            return Err(LieError::ZeroQuaternion { norm });
        }
        Ok(So3 {
            quaternion: UnitQuaternion::new_unchecked(q / norm),
        })
    }

    /// The unit quaternion.
    #[inline]
    pub fn unit_quaternion(&self) -> &UnitQuaternion<f64> {
        &self.quaternion
    }

    /// The rotation matrix `R`.
    #[inline]
    pub fn rotation_matrix(&self) -> Matrix3<f64> {
        self.quaternion.to_rotation_matrix().into_inner()
    }

    /// The rotation about the x axis by `angle` (thesis eq. 2.49).
    pub fn rot_x(angle: f64) -> Self {
        Self::exp(&Vector3::new(angle, 0.0, 0.0))
    }

    /// The rotation about the y axis by `angle`.
    pub fn rot_y(angle: f64) -> Self {
        Self::exp(&Vector3::new(0.0, angle, 0.0))
    }

    /// The rotation about the z axis by `angle`.
    pub fn rot_z(angle: f64) -> Self {
        Self::exp(&Vector3::new(0.0, 0.0, angle))
    }

    /// The rotation angle `θ ∈ [0, π]`.
    pub fn angle(&self) -> f64 {
        let q = self.quaternion.as_ref();
        2.0 * q.imag().norm().atan2(q.w.abs())
    }

    /// `log` together with the angle, whose half-angle sine and cosine are the quaternion's
    /// parts (the SE(3) and Sim(3) logarithms reuse them).
    #[inline]
    pub(crate) fn log_with_angle(&self) -> (Vector3<f64>, HalfAngle) {
        let q = self.quaternion.as_ref();
        // q and −q are the same rotation; choose w ≥ 0 so that θ ∈ [0, π].
        let (w, v) = if q.w < 0.0 {
            (-q.w, -q.imag())
        } else {
            (q.w, q.imag())
        };
        let n = v.norm();
        // θ = 2·atan2(|v|, w) is accurate near 0 and near π (where w → 0).
        let theta = 2.0 * n.atan2(w);
        let scale = if n < 1e-6 {
            // θ/n = (2/w)·(1 − n²/(3w²) + …) for n → 0 (w ≈ 1 there).
            2.0 / w * (1.0 - n * n / (3.0 * w * w))
        } else {
            theta / n
        };
        let angle = HalfAngle {
            theta,
            sin_half: n,
            cos_half: w,
        };
        (v * scale, angle)
    }

    /// `exp(ω)` together with its angle, which the SE(3) and Sim(3) exponentials reuse.
    #[inline]
    pub(crate) fn exp_with_angle(omega: &Vector3<f64>) -> (So3, HalfAngle) {
        let angle = HalfAngle::new(omega.norm());
        // Rodrigues' formula as the quaternion (cos(θ/2), sin(θ/2)/θ·ω).
        let f = 0.5 * angle.sinc_half();
        let q = Quaternion::new(angle.cos_half, f * omega.x, f * omega.y, f * omega.z);
        (
            So3 {
                quaternion: UnitQuaternion::new_unchecked(q),
            },
            angle,
        )
    }

    /// `J_l(ω)` of SO(3): `I + (1 − cos θ)/θ²·[ω]× + (θ − sin θ)/θ³·[ω]×²` (thesis eq. 2.100,
    /// the same matrix as SE(3)'s `V`).
    #[inline]
    pub(crate) fn left_jacobian_matrix(omega: &Vector3<f64>) -> Matrix3<f64> {
        let angle = HalfAngle::new(omega.norm());
        let k = skew(omega);
        Matrix3::identity()
            + k * angle.one_minus_cos_over_sq()
            + k * k * angle.theta_minus_sin_over_cube()
    }

    /// `J_l(ω)⁻¹ = I − ½[ω]× + (1 − (θ/2)cot(θ/2))/θ²·[ω]×²`.
    #[inline]
    pub(crate) fn left_jacobian_inverse_matrix(omega: &Vector3<f64>) -> Matrix3<f64> {
        let k = skew(omega);
        let c = HalfAngle::new(omega.norm()).inv_left_jacobian_coeff();
        Matrix3::identity() - k * 0.5 + k * k * c
    }
}

impl Default for So3 {
    fn default() -> Self {
        Self::identity()
    }
}

impl LieGroup<3> for So3 {
    type Point = Vector3<f64>;
    type PointMatrix = Matrix3<f64>;
    type PointJacobian = Matrix3<f64>;
    type Matrix = Matrix3<f64>;
    const NAME: &'static str = "SO(3)";

    #[inline]
    fn identity() -> Self {
        So3 {
            quaternion: UnitQuaternion::identity(),
        }
    }

    /// `R₁·R₂` as a quaternion product, re-normalised to first order.
    #[inline]
    fn compose(&self, other: &Self) -> Self {
        So3 {
            quaternion: renormalize_first_order(
                self.quaternion.as_ref() * other.quaternion.as_ref(),
            ),
        }
    }

    /// `R⁻¹ = Rᵀ`, the conjugate quaternion.
    #[inline]
    fn inverse(&self) -> Self {
        So3 {
            quaternion: self.quaternion.inverse(),
        }
    }

    /// Rodrigues' formula (thesis eq. 2.71) as the quaternion `(cos(θ/2), sin(θ/2)/θ·ω)`.
    #[inline]
    fn exp(omega: &SVector<f64, 3>) -> Self {
        So3::exp_with_angle(omega).0
    }

    /// `ω = θ·u` with `θ = 2·atan2(|q_v|, |q_w|) ∈ [0, π]` (equivalent to thesis eq. 2.74, but
    /// accurate near `θ = π`, where `arccos` of the trace loses half the digits).
    #[inline]
    fn log(&self) -> SVector<f64, 3> {
        self.log_with_angle().0
    }

    /// `[ω]×` (thesis eq. 2.60).
    fn hat(omega: &SVector<f64, 3>) -> Matrix3<f64> {
        skew(omega)
    }

    /// Thesis eq. 2.61.
    fn vee(matrix: &Matrix3<f64>) -> SVector<f64, 3> {
        unskew(matrix)
    }

    /// `Ad_R = R` (thesis eq. 2.79).
    fn adjoint(&self) -> SMatrix<f64, 3, 3> {
        self.rotation_matrix()
    }

    /// `[ω, φ] = ω × φ` (thesis eq. A.14).
    fn lie_bracket(a: &SVector<f64, 3>, b: &SVector<f64, 3>) -> SVector<f64, 3> {
        a.cross(b)
    }

    /// `∂(ω × φ)/∂ω = −[φ]×` (thesis eq. A.15).
    fn d_lie_bracket(b: &SVector<f64, 3>) -> SMatrix<f64, 3, 3> {
        -skew(b)
    }

    #[inline]
    fn act(&self, point: &Vector3<f64>) -> Vector3<f64> {
        self.quaternion * point
    }

    /// `∂(R·p)/∂p = R` (thesis eq. B.9).
    fn d_act_d_point(&self) -> Matrix3<f64> {
        self.rotation_matrix()
    }

    /// `∂(exp(ε)·R·p)/∂ε = −[R·p]×`.
    fn d_act_d_left(&self, point: &Vector3<f64>) -> Matrix3<f64> {
        -skew(&self.act(point))
    }

    fn matrix(&self) -> Matrix3<f64> {
        self.rotation_matrix()
    }

    fn from_matrix_with_tolerance(matrix: &Matrix3<f64>, tolerance: f64) -> Result<Self, LieError> {
        validate_rotation(matrix, tolerance)?;
        let rotation = Rotation3::from_matrix_unchecked(*matrix);
        let mut q = UnitQuaternion::from_rotation_matrix(&rotation);
        q.renormalize();
        Ok(So3 { quaternion: q })
    }

    fn normalize(&mut self) {
        self.quaternion.renormalize();
    }

    fn is_finite(&self) -> bool {
        self.quaternion.coords.iter().all(|x| x.is_finite())
    }

    fn left_jacobian(omega: &SVector<f64, 3>) -> SMatrix<f64, 3, 3> {
        Self::left_jacobian_matrix(omega)
    }

    fn left_jacobian_inverse(omega: &SVector<f64, 3>) -> SMatrix<f64, 3, 3> {
        Self::left_jacobian_inverse_matrix(omega)
    }
}

/// Checks that `matrix` is a rotation: finite, `max |RᵀR − I| ≤ tolerance`, `det R > 0`.
pub(crate) fn validate_rotation(matrix: &Matrix3<f64>, tolerance: f64) -> Result<(), LieError> {
    if !matrix.iter().all(|x| x.is_finite()) {
        return Err(LieError::NonFinite {
            what: "rotation matrix",
        });
    }
    let error = (matrix.transpose() * matrix - Matrix3::identity())
        .abs()
        .max();
    if error > tolerance {
        return Err(LieError::NotOrthonormal { error, tolerance });
    }
    let determinant = matrix.determinant();
    if determinant <= 0.0 {
        return Err(LieError::Reflection { determinant });
    }
    Ok(())
}

crate::impl_group_operators!(So3, 3, Vector3<f64>);
