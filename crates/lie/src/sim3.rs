//! Sim(3), the group of similarity transformations in 3D (thesis §5.2, app. A.1.2, A.2.2,
//! A.3.4, A.5).

use crate::scalar::{gauss_legendre_01, inverse_w_coefficients, sim3_w_coefficients};
use crate::so3::validate_rotation;
use crate::{LieError, LieGroup, Se3, So3, skew, unskew};
use nalgebra::{Matrix3, Matrix4, SMatrix, SVector, Vector3};
use std::sync::OnceLock;

/// A tangent vector of Sim(3): `(v, ω, σ)` (thesis eq. 5.5–5.6).
pub type Vector7 = SVector<f64, 7>;

/// A similarity transformation `x ↦ s·R·x + t` with scale `s > 0` (thesis eq. 5.4).
///
/// Tangent vectors are `(v, ω, σ)` with `s = e^σ` (thesis eq. 5.5–5.6).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Sim3 {
    rotation: So3,
    translation: Vector3<f64>,
    scale: f64,
}

impl Sim3 {
    /// The similarity `x ↦ s·R·x + t`; the scale must be positive and finite.
    pub fn new(rotation: So3, translation: Vector3<f64>, scale: f64) -> Result<Self, LieError> {
        if !(scale.is_finite() && scale > 0.0) {
            return Err(LieError::InvalidScale { scale });
        }
        if !translation.iter().all(|v| v.is_finite()) {
            return Err(LieError::NonFinite {
                what: "translation",
            });
        }
        Ok(Sim3 {
            rotation,
            translation,
            scale,
        })
    }

    /// The rigid motion `T` as a similarity with `s = 1`.
    pub fn from_se3(rigid: &Se3) -> Self {
        Sim3 {
            rotation: *rigid.rotation(),
            translation: *rigid.translation(),
            scale: 1.0,
        }
    }

    /// The rigid part `(R, t)`, dropping the scale.
    pub fn rigid_part(&self) -> Se3 {
        Se3::new(self.rotation, self.translation)
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

    /// The scale `s > 0`.
    #[inline]
    pub fn scale(&self) -> f64 {
        self.scale
    }

    /// `exp(s·ad_x)` evaluated as `Ad_{exp(s·x)}`, the integrand of the left Jacobian.
    fn left_jacobian_by_quadrature(x: &Vector7) -> SMatrix<f64, 7, 7> {
        static GAUSS_12: OnceLock<([f64; 12], [f64; 12])> = OnceLock::new();
        let (nodes, weights) = GAUSS_12.get_or_init(gauss_legendre_01::<12>);
        // ad_x has eigenvalues 0, ±iθ, σ, σ ± iθ: the integrand is entire and grows like
        // e^{|z|·u} with |z| = √(σ² + θ²). One 12-point panel per length π of |z| keeps the
        // Gauss–Legendre error below 1e-16.
        let z = (x[6] * x[6] + x.fixed_rows::<3>(3).norm_squared()).sqrt();
        let panels = ((z / std::f64::consts::PI).ceil() as usize).max(1);
        let width = 1.0 / panels as f64;
        let mut sum = SMatrix::<f64, 7, 7>::zeros();
        for p in 0..panels {
            for (u, w) in nodes.iter().zip(weights) {
                let s = (p as f64 + u) * width;
                sum += Sim3::exp(&(x * s)).adjoint() * (w * width);
            }
        }
        sum
    }

    /// `J_l(x)⁻¹ = ad_x·(e^{ad_x} − I)⁻¹ = Σ_k B_k/k!·ad_x^k` (the Bernoulli numbers, `B₁ = −½`,
    /// the odd ones beyond it zero; thesis eq. 5.22 is its first three terms), summed until its
    /// terms no longer change the sum; `None` for `|z| > 1`. The series converges for
    /// `|z| < 2π` (the eigenvalues of `ad_x` are `0, ±iθ, σ, σ ± iθ`, and `e^{λ} = 1` only at
    /// `λ = 2πik`); at `|z| ≤ 1` each even term is at most `(1/2π)²` of the one before, so the
    /// twelve coefficients reach rounding.
    fn left_jacobian_inverse_by_series(x: &Vector7) -> Option<SMatrix<f64, 7, 7>> {
        // B_{2k}/(2k)!, k = 1…12.
        const EVEN: [f64; 12] = [
            8.333_333_333_333_333e-2,
            -1.388_888_888_888_889e-3,
            3.306_878_306_878_307e-5,
            -8.267_195_767_195_768e-7,
            2.087_675_698_786_81e-8,
            -5.284_190_138_687_493e-10,
            1.338_253_653_068_468e-11,
            -3.389_680_296_322_583e-13,
            8.586_062_056_277_845e-15,
            -2.174_868_698_558_062e-16,
            5.509_002_828_360_23e-18,
            -1.395_446_468_581_252e-19,
        ];
        let z = (x[6] * x[6] + x.fixed_rows::<3>(3).norm_squared()).sqrt();
        if z > 1.0 {
            return None;
        }
        // ad_x = −∂[y, x]/∂y.
        let ad = -Sim3::d_lie_bracket(x);
        let ad2 = ad * ad;
        let mut sum = SMatrix::<f64, 7, 7>::identity() - ad * 0.5;
        let mut power = ad2;
        for c in EVEN {
            let term = power * c;
            sum += term;
            if term.amax() <= f64::EPSILON * 1e-2 * sum.amax() {
                break;
            }
            power *= ad2;
        }
        Some(sum)
    }
}

impl Default for Sim3 {
    fn default() -> Self {
        Self::identity()
    }
}

impl LieGroup<7> for Sim3 {
    type Point = Vector3<f64>;
    type PointMatrix = Matrix3<f64>;
    type PointJacobian = SMatrix<f64, 3, 7>;
    type Matrix = Matrix4<f64>;
    const NAME: &'static str = "Sim(3)";

    #[inline]
    fn identity() -> Self {
        Sim3 {
            rotation: So3::identity(),
            translation: Vector3::zeros(),
            scale: 1.0,
        }
    }

    /// `(s₁s₂, R₁R₂, s₁R₁t₂ + t₁)`.
    #[inline]
    fn compose(&self, other: &Self) -> Self {
        Sim3 {
            rotation: self.rotation.compose(&other.rotation),
            translation: self.rotation.act(&other.translation) * self.scale + self.translation,
            scale: self.scale * other.scale,
        }
    }

    /// `(1/s, Rᵀ, −Rᵀt/s)`.
    #[inline]
    fn inverse(&self) -> Self {
        let r_inv = self.rotation.inverse();
        let s_inv = 1.0 / self.scale;
        Sim3 {
            translation: -r_inv.act(&self.translation) * s_inv,
            rotation: r_inv,
            scale: s_inv,
        }
    }

    /// `(e^σ·exp([ω]×), W·v)` with `W` of thesis eq. 5.7 / A.29, accurate in all four
    /// combinations of `σ → 0` and `θ → 0`.
    #[inline]
    fn exp(tangent: &Vector7) -> Self {
        let v = Vector3::new(tangent[0], tangent[1], tangent[2]);
        let omega = Vector3::new(tangent[3], tangent[4], tangent[5]);
        let sigma = tangent[6];
        let (rotation, angle) = So3::exp_with_angle(&omega);
        let (c, a, b) = sim3_w_coefficients(sigma, &angle);
        let w_v = omega.cross(&v);
        Sim3 {
            rotation,
            translation: v * c + w_v * a + omega.cross(&w_v) * b,
            scale: sigma.exp(),
        }
    }

    /// `(W⁻¹·t, log R, ln s)` (thesis eq. 5.8), with the closed-form inverse of `W`.
    #[inline]
    fn log(&self) -> Vector7 {
        let (omega, angle) = self.rotation.log_with_angle();
        let sigma = self.scale.ln();
        let (c, a, b) = sim3_w_coefficients(sigma, &angle);
        let (x, y, z) = inverse_w_coefficients(c, a, b, angle.theta);
        let t = &self.translation;
        let w_t = omega.cross(t);
        let v = t * x + w_t * y + omega.cross(&w_t) * z;
        Vector7::from_column_slice(&[v.x, v.y, v.z, omega.x, omega.y, omega.z, sigma])
    }

    /// `[[ [ω]× + σI, v ], [0, 0]]` (thesis eq. 5.5).
    fn hat(tangent: &Vector7) -> Matrix4<f64> {
        let mut m = Matrix4::zeros();
        let top = skew(&Vector3::new(tangent[3], tangent[4], tangent[5]))
            + Matrix3::identity() * tangent[6];
        m.fixed_view_mut::<3, 3>(0, 0).copy_from(&top);
        m.fixed_view_mut::<3, 1>(0, 3)
            .copy_from(&Vector3::new(tangent[0], tangent[1], tangent[2]));
        m
    }

    fn vee(matrix: &Matrix4<f64>) -> Vector7 {
        let top = matrix.fixed_view::<3, 3>(0, 0).into_owned();
        let w = unskew(&top);
        let sigma = top.trace() / 3.0;
        Vector7::from_column_slice(&[
            matrix[(0, 3)],
            matrix[(1, 3)],
            matrix[(2, 3)],
            w.x,
            w.y,
            w.z,
            sigma,
        ])
    }

    /// `Ad_S = [[sR, [t]×R, −t], [0, R, 0], [0, 0, 1]]` (thesis eq. A.6).
    fn adjoint(&self) -> SMatrix<f64, 7, 7> {
        let r = self.rotation.rotation_matrix();
        let mut ad = SMatrix::<f64, 7, 7>::zeros();
        ad.fixed_view_mut::<3, 3>(0, 0).copy_from(&(r * self.scale));
        ad.fixed_view_mut::<3, 3>(0, 3)
            .copy_from(&(skew(&self.translation) * r));
        ad.fixed_view_mut::<3, 1>(0, 6)
            .copy_from(&(-self.translation));
        ad.fixed_view_mut::<3, 3>(3, 3).copy_from(&r);
        ad[(6, 6)] = 1.0;
        ad
    }

    /// `[(v, ω, σ), (τ, φ, ς)] = (ω × τ + v × φ + στ − ςv, ω × φ, 0)` (thesis eq. A.18).
    fn lie_bracket(a: &Vector7, b: &Vector7) -> Vector7 {
        let (v, w, sigma) = (a.fixed_rows::<3>(0), a.fixed_rows::<3>(3), a[6]);
        let (tau, phi, varsigma) = (b.fixed_rows::<3>(0), b.fixed_rows::<3>(3), b[6]);
        let top = w.cross(&tau) + v.cross(&phi) + tau * sigma - v * varsigma;
        let mid = w.cross(&phi);
        Vector7::from_column_slice(&[top.x, top.y, top.z, mid.x, mid.y, mid.z, 0.0])
    }

    /// `∂[u, (τ, φ, ς)]/∂u = [[−[φ]× − ςI, −[τ]×, τ], [0, −[φ]×, 0], [0, 0, 0]]`
    /// (thesis eq. A.19).
    fn d_lie_bracket(b: &Vector7) -> SMatrix<f64, 7, 7> {
        let tau = Vector3::new(b[0], b[1], b[2]);
        let phi = Vector3::new(b[3], b[4], b[5]);
        let varsigma = b[6];
        let sp = -skew(&phi);
        let mut d = SMatrix::<f64, 7, 7>::zeros();
        d.fixed_view_mut::<3, 3>(0, 0)
            .copy_from(&(sp - Matrix3::identity() * varsigma));
        d.fixed_view_mut::<3, 3>(0, 3).copy_from(&(-skew(&tau)));
        d.fixed_view_mut::<3, 1>(0, 6).copy_from(&tau);
        d.fixed_view_mut::<3, 3>(3, 3).copy_from(&sp);
        d
    }

    #[inline]
    fn act(&self, point: &Vector3<f64>) -> Vector3<f64> {
        self.rotation.act(point) * self.scale + self.translation
    }

    /// `∂(sR·p + t)/∂p = sR` (thesis eq. B.13).
    fn d_act_d_point(&self) -> Matrix3<f64> {
        self.rotation.rotation_matrix() * self.scale
    }

    /// `[I | −[x]× | x]` with `x = S·p` (thesis eq. B.14).
    fn d_act_d_left(&self, point: &Vector3<f64>) -> SMatrix<f64, 3, 7> {
        let x = self.act(point);
        let mut j = SMatrix::<f64, 3, 7>::zeros();
        j.fixed_view_mut::<3, 3>(0, 0)
            .copy_from(&Matrix3::identity());
        j.fixed_view_mut::<3, 3>(0, 3).copy_from(&(-skew(&x)));
        j.fixed_view_mut::<3, 1>(0, 6).copy_from(&x);
        j
    }

    /// `[[sR, t], [0, 1]]` (thesis eq. 5.4).
    fn matrix(&self) -> Matrix4<f64> {
        let mut m = Matrix4::identity();
        m.fixed_view_mut::<3, 3>(0, 0)
            .copy_from(&(self.rotation.rotation_matrix() * self.scale));
        m.fixed_view_mut::<3, 1>(0, 3).copy_from(&self.translation);
        m
    }

    /// Validates `[[sR, t], [0, 1]]`: `s = det(sR)^{1/3} > 0`, `R = sR/s` orthonormal within
    /// `tolerance`.
    fn from_matrix_with_tolerance(matrix: &Matrix4<f64>, tolerance: f64) -> Result<Self, LieError> {
        if !matrix.iter().all(|x| x.is_finite()) {
            return Err(LieError::NonFinite {
                what: "Sim(3) matrix",
            });
        }
        crate::check_last_row(matrix, tolerance)?;
        let sr = matrix.fixed_view::<3, 3>(0, 0).into_owned();
        let determinant = sr.determinant();
        if determinant <= 0.0 {
            if determinant < 0.0 {
                return Err(LieError::Reflection { determinant });
            }
            return Err(LieError::InvalidScale { scale: 0.0 });
        }
        let scale = determinant.cbrt();
        let r = sr / scale;
        validate_rotation(&r, tolerance)?;
        Sim3::new(
            So3::from_matrix_with_tolerance(&r, tolerance)?,
            matrix.fixed_view::<3, 1>(0, 3).into_owned(),
            scale,
        )
    }

    fn normalize(&mut self) {
        self.rotation.normalize();
    }

    fn is_finite(&self) -> bool {
        self.rotation.is_finite()
            && self.translation.iter().all(|x| x.is_finite())
            && self.scale.is_finite()
    }

    /// `J_l(x) = ∫₀¹ exp(u·ad_x) du = ∫₀¹ Ad_{exp(u·x)} du`, evaluated by composite
    /// Gauss–Legendre quadrature (exact to rounding; Sim(3) has no compact closed form).
    fn left_jacobian(tangent: &Vector7) -> SMatrix<f64, 7, 7> {
        Sim3::left_jacobian_by_quadrature(tangent)
    }

    /// The inverse of [`left_jacobian`](Self::left_jacobian) by LU decomposition. `J_l(x)` is
    /// singular only where `ad_x` has an eigenvalue `2πik`, `k ≠ 0` (rotation angles that are
    /// non-zero multiples of `2π`, which [`log`](Self::log) never returns); there the result
    /// is NaN.
    ///
    /// Near the identity (`|z| ≤ 1`, the residuals of a pose graph or a double window's
    /// pose-pose constraints) it is summed as its series instead
    /// ([`Sim3::left_jacobian_inverse_by_series`]): a few 7×7 products in place of 24
    /// exponentials and adjoints and an LU decomposition — a tenth of a double window's time
    /// went to the quadrature.
    fn left_jacobian_inverse(tangent: &Vector7) -> SMatrix<f64, 7, 7> {
        if let Some(j) = Sim3::left_jacobian_inverse_by_series(tangent) {
            return j;
        }
        Sim3::left_jacobian_by_quadrature(tangent)
            .try_inverse()
            .unwrap_or_else(|| SMatrix::from_element(f64::NAN))
    }
}

crate::impl_group_operators!(Sim3, 7, Vector3<f64>);

#[cfg(test)]
mod tests {
    use super::*;

    /// The series of `J_l⁻¹` against the inverse of the quadrature's `J_l`, from the identity to
    /// the series' limit `|z| = 1`, with translations of up to 100 units.
    #[test]
    fn the_inverse_left_jacobian_by_series_is_the_quadratures_inverse() {
        let mut state = 0x2545_f491_4f6c_dd1du64;
        let mut uniform = move || {
            state = state
                .wrapping_mul(6_364_136_223_846_793_005)
                .wrapping_add(1_442_695_040_888_963_407);
            (state >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0
        };
        let mut tried = 0;
        for &z in &[1e-9, 1e-5, 1e-3, 0.05, 0.3, 0.7, 0.999] {
            for &v in &[0.0, 1e-3, 1.0, 100.0] {
                for _ in 0..20 {
                    let mut x = Vector7::from_fn(|_, _| uniform());
                    let wz = (x[6] * x[6] + x.fixed_rows::<3>(3).norm_squared()).sqrt();
                    for i in 3..7 {
                        x[i] *= z / wz;
                    }
                    for i in 0..3 {
                        x[i] *= v;
                    }
                    let series = Sim3::left_jacobian_inverse_by_series(&x).expect("|z| ≤ 1");
                    let quadrature = Sim3::left_jacobian_by_quadrature(&x).try_inverse().unwrap();
                    let error = (series - quadrature).amax();
                    assert!(
                        error <= 1e-13 * (1.0 + quadrature.amax()),
                        "|z| = {z}, |v| ≈ {v}: {error:e}"
                    );
                    tried += 1;
                }
            }
        }
        assert_eq!(tried, 7 * 4 * 20);
        let far = Vector7::from_column_slice(&[0.0, 0.0, 0.0, 0.9, 0.0, 0.0, 0.5]);
        assert!(Sim3::left_jacobian_inverse_by_series(&far).is_none());
    }
}
