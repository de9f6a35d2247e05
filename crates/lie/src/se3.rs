//! SE(3), the group of rigid-body motions in 3D (thesis §2.4.9, app. A.1.1, A.2.1, A.3.3).

use crate::scalar::HalfAngle;
use crate::so3::validate_rotation;
use crate::{LieError, LieGroup, So3, skew, unskew};
use nalgebra::{Isometry3, Matrix3, Matrix4, SMatrix, Translation3, Vector3, Vector6};

/// A rigid-body transformation `x ↦ R·x + t` (thesis eq. 2.93–2.94).
///
/// Tangent vectors are `(v, ω)`: translational part first, rotation vector second
/// (thesis eq. 2.97).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Se3 {
    rotation: So3,
    translation: Vector3<f64>,
}

impl Se3 {
    /// The transformation `x ↦ R·x + t`.
    #[inline]
    pub fn new(rotation: So3, translation: Vector3<f64>) -> Self {
        Se3 {
            rotation,
            translation,
        }
    }

    /// A pure translation.
    pub fn from_translation(translation: Vector3<f64>) -> Self {
        Se3::new(So3::identity(), translation)
    }

    /// A pure rotation.
    pub fn from_rotation(rotation: So3) -> Self {
        Se3::new(rotation, Vector3::zeros())
    }

    /// From a quaternion `(w, x, y, z)` and a translation, as TUM, g2o and EuRoC files store
    /// poses; see [`So3::from_quaternion`] for the validation.
    pub fn from_quaternion_translation(
        w: f64,
        x: f64,
        y: f64,
        z: f64,
        translation: Vector3<f64>,
    ) -> Result<Self, LieError> {
        if !translation.iter().all(|v| v.is_finite()) {
            return Err(LieError::NonFinite {
                what: "translation",
            });
        }
        Ok(Se3::new(So3::from_quaternion(w, x, y, z)?, translation))
    }

    /// The rotation `R`.
    #[inline]
    pub fn rotation(&self) -> &So3 {
        &self.rotation
    }

    /// The translation `t`.
    #[inline]
    pub fn translation(&self) -> &Vector3<f64> {
        &self.translation
    }

    /// Mutable access to the translation.
    #[inline]
    pub fn translation_mut(&mut self) -> &mut Vector3<f64> {
        &mut self.translation
    }

    /// The same transformation as an `nalgebra::Isometry3`.
    pub fn to_isometry(&self) -> Isometry3<f64> {
        Isometry3::from_parts(
            Translation3::from(self.translation),
            *self.rotation.unit_quaternion(),
        )
    }

    /// The transformation of an `nalgebra::Isometry3`.
    pub fn from_isometry(iso: &Isometry3<f64>) -> Self {
        Se3::new(
            So3::from_unit_quaternion(iso.rotation),
            iso.translation.vector,
        )
    }

    /// The `Q` block of SE(3)'s left Jacobian, `J_l(v, ω) = [[J_l(ω), Q], [0, J_l(ω)]]`:
    ///
    /// `Q = ½V + c₁(ΩV + VΩ + ΩVΩ) + c₂(Ω²V + VΩ² − 3ΩVΩ) + c₃(ΩVΩ² + Ω²VΩ)` with
    /// `V = [v]×`, `Ω = [ω]×`, `c₁ = (θ − sin θ)/θ³`, `c₂ = (θ² + 2cos θ − 2)/(2θ⁴)`,
    /// `c₃ = (2θ − 3sin θ + θcos θ)/(2θ⁵)` (Barfoot, *State Estimation for Robotics*, eq. 7.86).
    fn left_jacobian_q(v: &Vector3<f64>, omega: &Vector3<f64>) -> Matrix3<f64> {
        let angle = HalfAngle::new(omega.norm());
        let theta = angle.theta;
        let t2 = theta * theta;
        let c1 = angle.theta_minus_sin_over_cube();
        let (c2, c3) = if t2 < 0.25 {
            // c₂ = Σ_{k≥2} (−1)ᵏ θ^{2k−4}/(2k)!,  c₃ = ½ Σ_{k≥2} (−1)ᵏ (2k−2) θ^{2k−4}/(2k+1)!.
            let mut c2 = 0.0;
            let mut c3 = 0.0;
            let mut power = 1.0; // (−1)^k θ^{2k−4}
            let mut fact_2k = 24.0; // (2k)!
            for k in 2..12 {
                let kf = k as f64;
                c2 += power / fact_2k;
                c3 += 0.5 * power * (2.0 * kf - 2.0) / (fact_2k * (2.0 * kf + 1.0));
                power *= -t2;
                fact_2k *= (2.0 * kf + 1.0) * (2.0 * kf + 2.0);
            }
            (c2, c3)
        } else {
            let (s, c) = (angle.sin(), angle.cos());
            (
                (t2 + 2.0 * c - 2.0) / (2.0 * t2 * t2),
                (2.0 * theta - 3.0 * s + theta * c) / (2.0 * t2 * t2 * theta),
            )
        };
        let vm = skew(v);
        let om = skew(omega);
        let om_vm = om * vm;
        let vm_om = vm * om;
        let om_vm_om = om_vm * om;
        vm * 0.5
            + (om_vm + vm_om + om_vm_om) * c1
            + (om * om_vm + vm_om * om - om_vm_om * 3.0) * c2
            + (om_vm_om * om + om * om_vm_om) * c3
    }
}

impl Default for Se3 {
    fn default() -> Self {
        Self::identity()
    }
}

impl LieGroup<6> for Se3 {
    type Point = Vector3<f64>;
    type PointMatrix = Matrix3<f64>;
    type PointJacobian = SMatrix<f64, 3, 6>;
    type Matrix = Matrix4<f64>;
    const NAME: &'static str = "SE(3)";

    #[inline]
    fn identity() -> Self {
        Se3::new(So3::identity(), Vector3::zeros())
    }

    /// `(R₁R₂, R₁t₂ + t₁)` (thesis eq. 2.95).
    #[inline]
    fn compose(&self, other: &Self) -> Self {
        Se3 {
            rotation: self.rotation.compose(&other.rotation),
            translation: self.rotation.act(&other.translation) + self.translation,
        }
    }

    /// `(Rᵀ, −Rᵀt)` (thesis eq. 2.96).
    #[inline]
    fn inverse(&self) -> Self {
        let r_inv = self.rotation.inverse();
        Se3 {
            translation: -r_inv.act(&self.translation),
            rotation: r_inv,
        }
    }

    /// `(exp([ω]×), V·v)` with `V = I + (1 − cos θ)/θ²·[ω]× + (θ − sin θ)/θ³·[ω]×²`
    /// (thesis eq. 2.99–2.100), applied to `v` with cross products.
    #[inline]
    fn exp(tangent: &Vector6<f64>) -> Self {
        let v = Vector3::new(tangent[0], tangent[1], tangent[2]);
        let omega = Vector3::new(tangent[3], tangent[4], tangent[5]);
        let (rotation, angle) = So3::exp_with_angle(&omega);
        let w_v = omega.cross(&v);
        let translation = v
            + w_v * angle.one_minus_cos_over_sq()
            + omega.cross(&w_v) * angle.theta_minus_sin_over_cube();
        Se3 {
            rotation,
            translation,
        }
    }

    /// `(V⁻¹·t, log R)` with `V⁻¹ = I − ½[ω]× + (1 − (θ/2)cot(θ/2))/θ²·[ω]×²`.
    #[inline]
    fn log(&self) -> Vector6<f64> {
        let (omega, angle) = self.rotation.log_with_angle();
        let t = &self.translation;
        let w_t = omega.cross(t);
        let v = t - w_t * 0.5 + omega.cross(&w_t) * angle.inv_left_jacobian_coeff();
        Vector6::new(v.x, v.y, v.z, omega.x, omega.y, omega.z)
    }

    /// `[[ [ω]×, v ], [0, 0]]` (thesis eq. 2.97).
    fn hat(tangent: &Vector6<f64>) -> Matrix4<f64> {
        let mut m = Matrix4::zeros();
        m.fixed_view_mut::<3, 3>(0, 0)
            .copy_from(&skew(&Vector3::new(tangent[3], tangent[4], tangent[5])));
        m.fixed_view_mut::<3, 1>(0, 3)
            .copy_from(&Vector3::new(tangent[0], tangent[1], tangent[2]));
        m
    }

    fn vee(matrix: &Matrix4<f64>) -> Vector6<f64> {
        let w = unskew(&matrix.fixed_view::<3, 3>(0, 0).into_owned());
        Vector6::new(
            matrix[(0, 3)],
            matrix[(1, 3)],
            matrix[(2, 3)],
            w.x,
            w.y,
            w.z,
        )
    }

    /// `Ad_T = [[R, [t]×R], [0, R]]` (thesis eq. A.3).
    fn adjoint(&self) -> SMatrix<f64, 6, 6> {
        let r = self.rotation.rotation_matrix();
        let mut ad = SMatrix::<f64, 6, 6>::zeros();
        ad.fixed_view_mut::<3, 3>(0, 0).copy_from(&r);
        ad.fixed_view_mut::<3, 3>(0, 3)
            .copy_from(&(skew(&self.translation) * r));
        ad.fixed_view_mut::<3, 3>(3, 3).copy_from(&r);
        ad
    }

    /// `[(v, ω), (τ, φ)] = (ω × τ + v × φ, ω × φ)` (thesis eq. A.16).
    fn lie_bracket(a: &Vector6<f64>, b: &Vector6<f64>) -> Vector6<f64> {
        let (v, w) = (a.fixed_rows::<3>(0), a.fixed_rows::<3>(3));
        let (tau, phi) = (b.fixed_rows::<3>(0), b.fixed_rows::<3>(3));
        let top = w.cross(&tau) + v.cross(&phi);
        let bottom = w.cross(&phi);
        Vector6::new(top.x, top.y, top.z, bottom.x, bottom.y, bottom.z)
    }

    /// `∂[u, (τ, φ)]/∂u = [[−[φ]×, −[τ]×], [0, −[φ]×]]` (thesis eq. A.17).
    fn d_lie_bracket(b: &Vector6<f64>) -> SMatrix<f64, 6, 6> {
        let tau = Vector3::new(b[0], b[1], b[2]);
        let phi = Vector3::new(b[3], b[4], b[5]);
        let mut d = SMatrix::<f64, 6, 6>::zeros();
        let sp = -skew(&phi);
        d.fixed_view_mut::<3, 3>(0, 0).copy_from(&sp);
        d.fixed_view_mut::<3, 3>(0, 3).copy_from(&(-skew(&tau)));
        d.fixed_view_mut::<3, 3>(3, 3).copy_from(&sp);
        d
    }

    #[inline]
    fn act(&self, point: &Vector3<f64>) -> Vector3<f64> {
        self.rotation.act(point) + self.translation
    }

    /// `∂(R·p + t)/∂p = R` (thesis eq. B.9).
    fn d_act_d_point(&self) -> Matrix3<f64> {
        self.rotation.rotation_matrix()
    }

    /// `[I | −[x]×]` with `x = T·p` (thesis eq. B.12).
    fn d_act_d_left(&self, point: &Vector3<f64>) -> SMatrix<f64, 3, 6> {
        let x = self.act(point);
        let mut j = SMatrix::<f64, 3, 6>::zeros();
        j.fixed_view_mut::<3, 3>(0, 0)
            .copy_from(&Matrix3::identity());
        j.fixed_view_mut::<3, 3>(0, 3).copy_from(&(-skew(&x)));
        j
    }

    /// `[[R, t], [0, 1]]` (thesis eq. 2.94).
    fn matrix(&self) -> Matrix4<f64> {
        let mut m = Matrix4::identity();
        m.fixed_view_mut::<3, 3>(0, 0)
            .copy_from(&self.rotation.rotation_matrix());
        m.fixed_view_mut::<3, 1>(0, 3).copy_from(&self.translation);
        m
    }

    fn from_matrix_with_tolerance(matrix: &Matrix4<f64>, tolerance: f64) -> Result<Self, LieError> {
        if !matrix.iter().all(|x| x.is_finite()) {
            return Err(LieError::NonFinite {
                what: "SE(3) matrix",
            });
        }
        crate::check_last_row(matrix, tolerance)?;
        let r = matrix.fixed_view::<3, 3>(0, 0).into_owned();
        validate_rotation(&r, tolerance)?;
        Ok(Se3::new(
            So3::from_matrix_with_tolerance(&r, tolerance)?,
            matrix.fixed_view::<3, 1>(0, 3).into_owned(),
        ))
    }

    fn normalize(&mut self) {
        self.rotation.normalize();
    }

    fn is_finite(&self) -> bool {
        self.rotation.is_finite() && self.translation.iter().all(|x| x.is_finite())
    }

    /// `[[J_l(ω), Q(v, ω)], [0, J_l(ω)]]`.
    fn left_jacobian(tangent: &Vector6<f64>) -> SMatrix<f64, 6, 6> {
        let v = Vector3::new(tangent[0], tangent[1], tangent[2]);
        let omega = Vector3::new(tangent[3], tangent[4], tangent[5]);
        let j = So3::left_jacobian_matrix(&omega);
        let mut out = SMatrix::<f64, 6, 6>::zeros();
        out.fixed_view_mut::<3, 3>(0, 0).copy_from(&j);
        out.fixed_view_mut::<3, 3>(0, 3)
            .copy_from(&Se3::left_jacobian_q(&v, &omega));
        out.fixed_view_mut::<3, 3>(3, 3).copy_from(&j);
        out
    }

    /// `[[J⁻¹, −J⁻¹·Q·J⁻¹], [0, J⁻¹]]` with `J = J_l(ω)` of SO(3).
    fn left_jacobian_inverse(tangent: &Vector6<f64>) -> SMatrix<f64, 6, 6> {
        let v = Vector3::new(tangent[0], tangent[1], tangent[2]);
        let omega = Vector3::new(tangent[3], tangent[4], tangent[5]);
        let j_inv = So3::left_jacobian_inverse_matrix(&omega);
        let q = Se3::left_jacobian_q(&v, &omega);
        let mut out = SMatrix::<f64, 6, 6>::zeros();
        out.fixed_view_mut::<3, 3>(0, 0).copy_from(&j_inv);
        out.fixed_view_mut::<3, 3>(0, 3)
            .copy_from(&(-(j_inv * q * j_inv)));
        out.fixed_view_mut::<3, 3>(3, 3).copy_from(&j_inv);
        out
    }
}

crate::impl_group_operators!(Se3, 6, Vector3<f64>);
