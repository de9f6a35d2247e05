//! SO(2), the circle group of rotations in the plane (thesis eq. 2.47, 2.53, A.22).

use crate::{LieError, LieGroup};
use nalgebra::{Complex, Matrix1, Matrix2, SMatrix, UnitComplex, Vector1, Vector2};

/// A rotation in the plane by an angle `θ`, stored as a unit complex number `cos θ + i·sin θ`.
///
/// The tangent space is one-dimensional: the angle. SO(2) is commutative, so its adjoint is
/// `1` and its Lie bracket vanishes (thesis §2.4.7, A.4).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct So2 {
    complex: UnitComplex<f64>,
}

impl So2 {
    /// The rotation by `angle` radians (anti-clockwise, thesis eq. 2.47).
    pub fn from_angle(angle: f64) -> Self {
        So2 {
            complex: UnitComplex::new(angle),
        }
    }

    /// The rotation of a non-zero complex number `re + i·im` (normalised); zero or non-finite
    /// is an error.
    pub fn from_complex(re: f64, im: f64) -> Result<Self, LieError> {
        if !(re.is_finite() && im.is_finite()) {
            return Err(LieError::NonFinite {
                what: "complex number",
            });
        }
        let norm = re.hypot(im);
        if norm < 1e-10 {
            return Err(LieError::ZeroComplex { norm });
        }
        Ok(So2 {
            complex: UnitComplex::new_unchecked(Complex::new(re / norm, im / norm)),
        })
    }

    /// The angle in `[−π, π]`.
    #[inline]
    pub fn angle(&self) -> f64 {
        self.complex.angle()
    }

    /// The unit complex number.
    #[inline]
    pub fn unit_complex(&self) -> &UnitComplex<f64> {
        &self.complex
    }

    /// The rotation matrix `R(θ)` (thesis eq. 2.47).
    #[inline]
    pub fn rotation_matrix(&self) -> Matrix2<f64> {
        self.complex.to_rotation_matrix().into_inner()
    }
}

impl Default for So2 {
    fn default() -> Self {
        Self::identity()
    }
}

/// `J·x = (−x₂, x₁)`: the generator of SO(2) applied to a point (thesis eq. 2.53).
#[inline]
pub(crate) fn perp(x: &Vector2<f64>) -> Vector2<f64> {
    Vector2::new(-x.y, x.x)
}

impl LieGroup<1> for So2 {
    type Point = Vector2<f64>;
    type PointMatrix = Matrix2<f64>;
    type PointJacobian = SMatrix<f64, 2, 1>;
    type Matrix = Matrix2<f64>;
    const NAME: &'static str = "SO(2)";

    fn identity() -> Self {
        So2 {
            complex: UnitComplex::identity(),
        }
    }

    /// `R(α)·R(β) = R(α + β)` (thesis eq. A.22), re-normalised to first order.
    #[inline]
    fn compose(&self, other: &Self) -> Self {
        let c = self.complex.complex() * other.complex.complex();
        let n2 = c.norm_sqr();
        So2 {
            complex: UnitComplex::new_unchecked(c * (0.5 * (3.0 - n2))),
        }
    }

    fn inverse(&self) -> Self {
        So2 {
            complex: self.complex.inverse(),
        }
    }

    /// `exp(θ) = R(θ)`.
    fn exp(tangent: &Vector1<f64>) -> Self {
        So2::from_angle(tangent[0])
    }

    /// `θ = atan2(sin, cos) ∈ [−π, π]` (thesis §5.3.2).
    fn log(&self) -> Vector1<f64> {
        Vector1::new(self.angle())
    }

    /// `θ·[[0, −1], [1, 0]]` (thesis eq. 2.53).
    fn hat(tangent: &Vector1<f64>) -> Matrix2<f64> {
        Matrix2::new(0.0, -tangent[0], tangent[0], 0.0)
    }

    fn vee(matrix: &Matrix2<f64>) -> Vector1<f64> {
        Vector1::new(0.5 * (matrix[(1, 0)] - matrix[(0, 1)]))
    }

    /// `Ad = 1`: SO(2) is commutative (thesis §2.4.7).
    fn adjoint(&self) -> Matrix1<f64> {
        Matrix1::new(1.0)
    }

    /// `[a, b] = 0`.
    fn lie_bracket(_a: &Vector1<f64>, _b: &Vector1<f64>) -> Vector1<f64> {
        Vector1::zeros()
    }

    fn d_lie_bracket(_b: &Vector1<f64>) -> Matrix1<f64> {
        Matrix1::zeros()
    }

    #[inline]
    fn act(&self, point: &Vector2<f64>) -> Vector2<f64> {
        self.complex * point
    }

    fn d_act_d_point(&self) -> Matrix2<f64> {
        self.rotation_matrix()
    }

    /// `∂(exp(ε)·R·p)/∂ε = J·(R·p)`.
    fn d_act_d_left(&self, point: &Vector2<f64>) -> SMatrix<f64, 2, 1> {
        perp(&self.act(point))
    }

    fn matrix(&self) -> Matrix2<f64> {
        self.rotation_matrix()
    }

    fn from_matrix_with_tolerance(matrix: &Matrix2<f64>, tolerance: f64) -> Result<Self, LieError> {
        if !matrix.iter().all(|x| x.is_finite()) {
            return Err(LieError::NonFinite {
                what: "SO(2) matrix",
            });
        }
        let error = (matrix.transpose() * matrix - Matrix2::identity())
            .abs()
            .max();
        if error > tolerance {
            return Err(LieError::NotOrthonormal { error, tolerance });
        }
        let determinant = matrix.determinant();
        if determinant <= 0.0 {
            return Err(LieError::Reflection { determinant });
        }
        So2::from_complex(
            matrix[(0, 0)] + matrix[(1, 1)],
            matrix[(1, 0)] - matrix[(0, 1)],
        )
    }

    fn normalize(&mut self) {
        self.complex.renormalize();
    }

    fn is_finite(&self) -> bool {
        self.complex.re.is_finite() && self.complex.im.is_finite()
    }

    fn left_jacobian(_tangent: &Vector1<f64>) -> Matrix1<f64> {
        Matrix1::new(1.0)
    }

    fn left_jacobian_inverse(_tangent: &Vector1<f64>) -> Matrix1<f64> {
        Matrix1::new(1.0)
    }
}

crate::impl_group_operators!(So2, 1, Vector2<f64>);
