//! SE(2), the group of rigid motions in the plane, for 2D pose graphs.

use crate::scalar::HalfAngle;
use crate::so2::perp;
use crate::{LieError, LieGroup, So2};
use nalgebra::{Matrix2, Matrix3, SMatrix, Vector2, Vector3};

/// A rigid motion in the plane, `x ↦ R(θ)·x + t`.
///
/// Tangent vectors are `(v₁, v₂, θ)`: translational part first, angle last, as for SE(3).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Se2 {
    rotation: So2,
    translation: Vector2<f64>,
}

impl Se2 {
    /// The motion `x ↦ R·x + t`.
    pub fn new(rotation: So2, translation: Vector2<f64>) -> Self {
        Se2 {
            rotation,
            translation,
        }
    }

    /// The motion `(x, y, θ)` as g2o's `VERTEX_SE2` and `EDGE_SE2` store it.
    pub fn from_xy_angle(x: f64, y: f64, angle: f64) -> Self {
        Se2::new(So2::from_angle(angle), Vector2::new(x, y))
    }

    /// The rotation.
    pub fn rotation(&self) -> &So2 {
        &self.rotation
    }

    /// The translation.
    pub fn translation(&self) -> &Vector2<f64> {
        &self.translation
    }

    /// The angle in `[−π, π]`.
    pub fn angle(&self) -> f64 {
        self.rotation.angle()
    }

    /// `(sinc θ, (1 − cos θ)/θ)`: `V(θ) = sinc θ·I + (1 − cos θ)/θ·J` maps `v` to the
    /// translation of `exp(v, θ)`.
    #[inline]
    fn v_coefficients(theta: f64) -> (f64, f64) {
        let angle = HalfAngle::new(theta);
        (angle.sinc(), theta * angle.one_minus_cos_over_sq())
    }

    /// `V(θ)` as a matrix.
    fn v_matrix(theta: f64) -> Matrix2<f64> {
        let (a, b) = Se2::v_coefficients(theta);
        Matrix2::new(a, -b, b, a)
    }

    /// `V(θ)⁻¹ = [[a, b], [−b, a]]/(a² + b²)`, with `a² + b² = 2(1 − cos θ)/θ² > 0` for
    /// `|θ| < 2π`.
    fn v_inverse_matrix(theta: f64) -> Matrix2<f64> {
        let (a, b) = Se2::v_coefficients(theta);
        let d = a * a + b * b;
        Matrix2::new(a, b, -b, a) / d
    }

    /// The last column's top block of `J_l(v, θ)`:
    /// `((θ − sin θ)/θ²)·v − ((1 − cos θ)/θ²)·J·v`.
    fn left_jacobian_column(v: &Vector2<f64>, theta: f64) -> Vector2<f64> {
        let angle = HalfAngle::new(theta);
        v * (theta * angle.theta_minus_sin_over_cube()) - perp(v) * angle.one_minus_cos_over_sq()
    }
}

impl Default for Se2 {
    fn default() -> Self {
        Self::identity()
    }
}

impl LieGroup<3> for Se2 {
    type Point = Vector2<f64>;
    type PointMatrix = Matrix2<f64>;
    type PointJacobian = SMatrix<f64, 2, 3>;
    type Matrix = Matrix3<f64>;
    const NAME: &'static str = "SE(2)";

    fn identity() -> Self {
        Se2::new(So2::identity(), Vector2::zeros())
    }

    #[inline]
    fn compose(&self, other: &Self) -> Self {
        Se2 {
            rotation: self.rotation.compose(&other.rotation),
            translation: self.rotation.act(&other.translation) + self.translation,
        }
    }

    fn inverse(&self) -> Self {
        let r_inv = self.rotation.inverse();
        Se2 {
            translation: -r_inv.act(&self.translation),
            rotation: r_inv,
        }
    }

    /// `(R(θ), V(θ)·v)`.
    fn exp(tangent: &Vector3<f64>) -> Self {
        let theta = tangent[2];
        let v = Vector2::new(tangent[0], tangent[1]);
        let (a, b) = Se2::v_coefficients(theta);
        Se2 {
            rotation: So2::from_angle(theta),
            translation: v * a + perp(&v) * b,
        }
    }

    /// `(V(θ)⁻¹·t, θ)` with `θ ∈ [−π, π]`.
    fn log(&self) -> Vector3<f64> {
        let theta = self.rotation.angle();
        let v = Se2::v_inverse_matrix(theta) * self.translation;
        Vector3::new(v.x, v.y, theta)
    }

    /// `[[θJ, v], [0, 0]]` with `J = [[0, −1], [1, 0]]`.
    fn hat(tangent: &Vector3<f64>) -> Matrix3<f64> {
        Matrix3::new(
            0.0,
            -tangent[2],
            tangent[0],
            tangent[2],
            0.0,
            tangent[1],
            0.0,
            0.0,
            0.0,
        )
    }

    fn vee(matrix: &Matrix3<f64>) -> Vector3<f64> {
        Vector3::new(
            matrix[(0, 2)],
            matrix[(1, 2)],
            0.5 * (matrix[(1, 0)] - matrix[(0, 1)]),
        )
    }

    /// `Ad_T = [[R, (t₂, −t₁)ᵀ], [0, 1]]`, from `T·x̂·T⁻¹ = [[θJ, R·v − θJ·t], [0, 0]]`.
    fn adjoint(&self) -> Matrix3<f64> {
        let r = self.rotation.rotation_matrix();
        let t = &self.translation;
        Matrix3::new(
            r[(0, 0)],
            r[(0, 1)],
            t.y,
            r[(1, 0)],
            r[(1, 1)],
            -t.x,
            0.0,
            0.0,
            1.0,
        )
    }

    /// `[(v, θ), (τ, φ)] = (θ·J·τ − φ·J·v, 0)`.
    fn lie_bracket(a: &Vector3<f64>, b: &Vector3<f64>) -> Vector3<f64> {
        let v = Vector2::new(a[0], a[1]);
        let tau = Vector2::new(b[0], b[1]);
        let top = perp(&tau) * a[2] - perp(&v) * b[2];
        Vector3::new(top.x, top.y, 0.0)
    }

    /// `∂[u, (τ, φ)]/∂u = [[−φJ, J·τ], [0, 0]]`.
    fn d_lie_bracket(b: &Vector3<f64>) -> Matrix3<f64> {
        let phi = b[2];
        let jt = perp(&Vector2::new(b[0], b[1]));
        Matrix3::new(0.0, phi, jt.x, -phi, 0.0, jt.y, 0.0, 0.0, 0.0)
    }

    #[inline]
    fn act(&self, point: &Vector2<f64>) -> Vector2<f64> {
        self.rotation.act(point) + self.translation
    }

    fn d_act_d_point(&self) -> Matrix2<f64> {
        self.rotation.rotation_matrix()
    }

    /// `[I | J·x]` with `x = T·p`.
    fn d_act_d_left(&self, point: &Vector2<f64>) -> SMatrix<f64, 2, 3> {
        let jx = perp(&self.act(point));
        SMatrix::<f64, 2, 3>::new(1.0, 0.0, jx.x, 0.0, 1.0, jx.y)
    }

    fn matrix(&self) -> Matrix3<f64> {
        let r = self.rotation.rotation_matrix();
        let t = &self.translation;
        Matrix3::new(
            r[(0, 0)],
            r[(0, 1)],
            t.x,
            r[(1, 0)],
            r[(1, 1)],
            t.y,
            0.0,
            0.0,
            1.0,
        )
    }

    fn from_matrix_with_tolerance(matrix: &Matrix3<f64>, tolerance: f64) -> Result<Self, LieError> {
        if !matrix.iter().all(|x| x.is_finite()) {
            return Err(LieError::NonFinite {
                what: "SE(2) matrix",
            });
        }
        crate::check_last_row(matrix, tolerance)?;
        let r = matrix.fixed_view::<2, 2>(0, 0).into_owned();
        Ok(Se2::new(
            So2::from_matrix_with_tolerance(&r, tolerance)?,
            Vector2::new(matrix[(0, 2)], matrix[(1, 2)]),
        ))
    }

    fn normalize(&mut self) {
        self.rotation.normalize();
    }

    fn is_finite(&self) -> bool {
        self.rotation.is_finite() && self.translation.iter().all(|x| x.is_finite())
    }

    /// `[[V(θ), u], [0, 1]]`, `u = ((θ − sin θ)/θ²)·v − ((1 − cos θ)/θ²)·J·v`.
    fn left_jacobian(tangent: &Vector3<f64>) -> Matrix3<f64> {
        let v = Vector2::new(tangent[0], tangent[1]);
        let theta = tangent[2];
        let m = Se2::v_matrix(theta);
        let u = Se2::left_jacobian_column(&v, theta);
        Matrix3::new(
            m[(0, 0)],
            m[(0, 1)],
            u.x,
            m[(1, 0)],
            m[(1, 1)],
            u.y,
            0.0,
            0.0,
            1.0,
        )
    }

    /// `[[V(θ)⁻¹, −V(θ)⁻¹·u], [0, 1]]`.
    fn left_jacobian_inverse(tangent: &Vector3<f64>) -> Matrix3<f64> {
        let v = Vector2::new(tangent[0], tangent[1]);
        let theta = tangent[2];
        let m = Se2::v_inverse_matrix(theta);
        let u = -(m * Se2::left_jacobian_column(&v, theta));
        Matrix3::new(
            m[(0, 0)],
            m[(0, 1)],
            u.x,
            m[(1, 0)],
            m[(1, 1)],
            u.y,
            0.0,
            0.0,
            1.0,
        )
    }
}

crate::impl_group_operators!(Se2, 3, Vector2<f64>);
