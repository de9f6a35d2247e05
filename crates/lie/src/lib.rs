//! Lie groups for SLAM: SO(2), SE(2), SO(3), SE(3) and Sim(3) over `f64`.
//!
//! This crate is the group maths of the dwslam system and nothing else (thesis ch. 2.4, ch. 5.2,
//! appendices A and B). Every group implements [`LieGroup`]: identity, composition, inverse, the
//! exponential and logarithm maps, hat and vee, the adjoint, the Lie bracket and its derivative,
//! the action on points with Jacobians, matrix conversions with validation and the left Jacobian
//! of the exponential map.
//!
//! # Conventions
//!
//! * Tangent vectors are ordered as in the thesis: SE(3) `(v, ω)` (eq. 2.97), Sim(3)
//!   `(v, ω, σ)` (eq. 5.5), SE(2) `(v₁, v₂, θ)`, SO(3) `ω`, SO(2) `θ`.
//! * Updates are left-multiplicative, `T ← exp(δ)·T` (thesis eq. 2.104); every Jacobian "with
//!   respect to the group element" in this crate is with respect to such a left perturbation
//!   `exp(ε)·T` at `ε = 0` (thesis eq. 2.102).
//! * `log` returns rotation angles in `[0, π]` (thesis §5.3.2), so elements close to the identity
//!   map to tangent vectors close to zero; SO(2) angles lie in `[−π, π]`.
//! * A stored transformation is named after what it maps, e.g. `camera_from_world: Se3`
//!   maps world coordinates into the camera frame (the thesis's `T_cw`).
//!
//! # Pose-graph log Jacobians
//!
//! [`LieGroup::d_log_left`] computes `J_A^B = ∂ log(A·exp(ε)·B)^∨ / ∂ε |_{ε=0}` (thesis eq. 5.20)
//! exactly (inverse left Jacobian) or with the first-, second- or third-order
//! Campbell-Baker-Hausdorff approximations of thesis eq. 5.22 / A.48–A.50.

#![warn(missing_docs)]

use nalgebra::{SMatrix, SVector};
use std::fmt::Debug;

mod error;
pub mod numeric;
mod scalar;
mod se2;
mod se3;
mod sim3;
mod so2;
mod so3;

pub use error::LieError;
pub use se2::Se2;
pub use se3::Se3;
pub use sim3::Sim3;
pub use so2::So2;
pub use so3::So3;

/// Default tolerance for [`LieGroup::from_matrix`]: the largest accepted entry of `RᵀR − I`.
///
/// Poses read from text files carry rounding errors of about `1e-6` to `1e-9`; anything above
/// `1e-5` is not a rotation that was merely printed with few digits.
pub const DEFAULT_ORTHONORMALITY_TOLERANCE: f64 = 1e-5;

/// How to compute the log Jacobian `J_A^B = ∂ log(A·exp(ε)·B)^∨ / ∂ε` (thesis eq. 5.20).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum LogJacobian {
    /// Exact: `J_l(d)⁻¹ · Ad_A` with `d = log(A·B)` and `J_l` the left Jacobian of `exp`.
    Exact,
    /// First-order CBH: `Ad_A` (thesis eq. A.49).
    Cbh1,
    /// Second-order CBH: `(I + ½ ∂[y,d]/∂y) · Ad_A` (thesis eq. A.50).
    Cbh2,
    /// Third-order CBH: `(I + ½ ∂[y,d]/∂y + 1/12 (∂[y,d]/∂y)²) · Ad_A` (thesis eq. 5.22, A.48).
    Cbh3,
}

impl LogJacobian {
    /// All four methods, most accurate first.
    pub const ALL: [LogJacobian; 4] = [
        LogJacobian::Exact,
        LogJacobian::Cbh3,
        LogJacobian::Cbh2,
        LogJacobian::Cbh1,
    ];

    /// A short name: `exact`, `cbh1`, `cbh2`, `cbh3`.
    pub fn name(self) -> &'static str {
        match self {
            LogJacobian::Exact => "exact",
            LogJacobian::Cbh1 => "cbh1",
            LogJacobian::Cbh2 => "cbh2",
            LogJacobian::Cbh3 => "cbh3",
        }
    }
}

/// A matrix Lie group with `DOF` degrees of freedom acting on points.
///
/// `DOF` is the dimension of the tangent space (the Lie algebra `𝔤`, thesis §2.4.4). Tangent
/// vectors are `SVector<f64, DOF>`; adjoint matrices and Jacobians of tangent-valued functions
/// are `SMatrix<f64, DOF, DOF>`.
pub trait LieGroup<const DOF: usize>:
    Copy + Clone + Debug + PartialEq + Send + Sync + Sized + 'static
{
    /// A point the group acts on (`Vector2` or `Vector3`).
    type Point: Copy + Debug;
    /// The Jacobian of the action with respect to the point (`P×P`).
    type PointMatrix: Copy + Debug;
    /// The Jacobian of the action with respect to a left perturbation of the group (`P×DOF`).
    type PointJacobian: Copy + Debug;
    /// The matrix representation (`2×2`, `3×3` or `4×4`), and of the Lie algebra under hat.
    type Matrix: Copy + Debug;

    /// The group's name as the thesis writes it, e.g. `"SE(3)"`.
    const NAME: &'static str;

    /// The neutral element `id` (thesis eq. 2.41).
    fn identity() -> Self;

    /// The group operation `self ⊗ other` (matrix product, thesis eq. 2.95).
    fn compose(&self, other: &Self) -> Self;

    /// The inverse element (thesis eq. 2.43, 2.96).
    fn inverse(&self) -> Self;

    /// The exponential map `exp(x̂)` from the tangent space onto the group (thesis §2.4.5).
    fn exp(tangent: &SVector<f64, DOF>) -> Self;

    /// The logarithm `log(·)^∨`, the inverse of [`exp`](Self::exp) with rotation angles in
    /// `[0, π]` (thesis eq. 2.74, 5.8, §5.3.2).
    fn log(&self) -> SVector<f64, DOF>;

    /// The hat operator `x ↦ x̂ = Σ xᵢ Gᵢ` into the matrix Lie algebra (thesis eq. 2.59).
    fn hat(tangent: &SVector<f64, DOF>) -> Self::Matrix;

    /// The vee operator, the inverse of [`hat`](Self::hat) (thesis eq. 2.61). Entries outside
    /// the algebra's pattern are ignored (skew parts are averaged).
    fn vee(matrix: &Self::Matrix) -> SVector<f64, DOF>;

    /// The adjoint matrix `Ad_T` with `(Ad_T·x)^ = T·x̂·T⁻¹` (thesis eq. 2.77, A.3, A.6).
    fn adjoint(&self) -> SMatrix<f64, DOF, DOF>;

    /// The Lie bracket `[a, b] = (â·b̂ − b̂·â)^∨` (thesis eq. 2.83, A.14, A.16, A.18).
    fn lie_bracket(a: &SVector<f64, DOF>, b: &SVector<f64, DOF>) -> SVector<f64, DOF>;

    /// The derivative of the Lie bracket in its first argument, `∂[y, b]/∂y`, a constant
    /// matrix for fixed `b` (thesis eq. A.15, A.17, A.19). It equals `−ad_b`.
    fn d_lie_bracket(b: &SVector<f64, DOF>) -> SMatrix<f64, DOF, DOF>;

    /// The group action on a point, `T·p` (thesis eq. 2.93, B.7).
    fn act(&self, point: &Self::Point) -> Self::Point;

    /// `∂(T·p)/∂p`: `R` for rigid motions, `sR` for similarities (thesis eq. B.9, B.13).
    fn d_act_d_point(&self) -> Self::PointMatrix;

    /// `∂(exp(ε)·T·p)/∂ε` at `ε = 0`, e.g. `[I | −[x]×]` with `x = T·p` for SE(3)
    /// (thesis eq. B.12, B.14).
    fn d_act_d_left(&self, point: &Self::Point) -> Self::PointJacobian;

    /// The matrix representation of this element.
    fn matrix(&self) -> Self::Matrix;

    /// The element represented by `matrix`, validated: a matrix that is not in the group
    /// (not orthonormal within `tolerance`, a reflection, a non-positive scale, a wrong last
    /// row, a non-finite entry) is an error, not silently fixed.
    fn from_matrix_with_tolerance(matrix: &Self::Matrix, tolerance: f64) -> Result<Self, LieError>;

    /// [`from_matrix_with_tolerance`](Self::from_matrix_with_tolerance) with
    /// [`DEFAULT_ORTHONORMALITY_TOLERANCE`].
    fn from_matrix(matrix: &Self::Matrix) -> Result<Self, LieError> {
        Self::from_matrix_with_tolerance(matrix, DEFAULT_ORTHONORMALITY_TOLERANCE)
    }

    /// Re-normalises the rotation part (unit quaternion or unit complex number) after rounding
    /// errors have accumulated. Composition already keeps the norm at 1 to first order.
    fn normalize(&mut self);

    /// `true` when every stored number is finite.
    fn is_finite(&self) -> bool;

    /// The left Jacobian of the exponential map, `J_l(x) = Σₙ ad_xⁿ/(n+1)!`, defined by
    /// `exp(x + δ) ≈ exp(J_l(x)·δ)·exp(x)` for small `δ`.
    fn left_jacobian(tangent: &SVector<f64, DOF>) -> SMatrix<f64, DOF, DOF>;

    /// The inverse left Jacobian `J_l(x)⁻¹`: `log(exp(δ)·exp(x)) ≈ x + J_l(x)⁻¹·δ`.
    fn left_jacobian_inverse(tangent: &SVector<f64, DOF>) -> SMatrix<f64, DOF, DOF>;

    /// The optimiser's update `exp(δ)·T` (thesis eq. 2.104).
    fn retract_left(&self, delta: &SVector<f64, DOF>) -> Self {
        Self::exp(delta).compose(self)
    }

    /// The log Jacobian `J_A^B = ∂ log(A·exp(ε)·B)^∨ / ∂ε |_{ε=0}` (thesis eq. 5.20–5.22,
    /// A.40–A.50).
    ///
    /// With `d = log(A·B)` and `D = ∂[y, d]/∂y` (thesis eq. A.15–A.19):
    /// * [`LogJacobian::Cbh1`]: `Ad_A` (eq. A.49);
    /// * [`LogJacobian::Cbh2`]: `(I + ½D)·Ad_A` (eq. A.50);
    /// * [`LogJacobian::Cbh3`]: `(I + ½D + D²/12)·Ad_A` (eq. 5.22, A.48);
    /// * [`LogJacobian::Exact`]: `J_l(d)⁻¹·Ad_A`, of which the CBH forms are the truncations.
    fn d_log_left(a: &Self, b: &Self, method: LogJacobian) -> SMatrix<f64, DOF, DOF> {
        let ad_a = a.adjoint();
        if method == LogJacobian::Cbh1 {
            return ad_a;
        }
        let d = a.compose(b).log();
        d_log_from_parts::<Self, DOF>(&d, &ad_a, method)
    }
}

/// `J_A^B` from `d = log(A·B)` and `Ad_A` (see [`LieGroup::d_log_left`]); useful when the caller
/// already has both, as a pose-graph residual does.
pub fn d_log_from_parts<G: LieGroup<DOF>, const DOF: usize>(
    d: &SVector<f64, DOF>,
    ad_a: &SMatrix<f64, DOF, DOF>,
    method: LogJacobian,
) -> SMatrix<f64, DOF, DOF> {
    match method {
        LogJacobian::Cbh1 => *ad_a,
        LogJacobian::Cbh2 => {
            let d_bracket = G::d_lie_bracket(d);
            ad_a + (d_bracket * ad_a) * 0.5
        }
        LogJacobian::Cbh3 => {
            let d_bracket = G::d_lie_bracket(d);
            let half = d_bracket * ad_a;
            ad_a + half * 0.5 + (d_bracket * half) * (1.0 / 12.0)
        }
        LogJacobian::Exact => G::left_jacobian_inverse(d) * ad_a,
    }
}

/// The left factors `(M(d), M(−d))` of the log Jacobians, `J_A^B = M(d)·Ad_A` (see
/// [`LieGroup::d_log_left`]): with `D = ∂[y, d]/∂y`, `M = I` ([`LogJacobian::Cbh1`]),
/// `I + ½D` ([`LogJacobian::Cbh2`]), `I + ½D + D²/12` ([`LogJacobian::Cbh3`], thesis eq. 5.22)
/// or `J_l(d)⁻¹` ([`LogJacobian::Exact`]).
///
/// Both signs come together because a relative-pose residual `d = log(A·X·Y⁻¹)` needs both:
/// `∂d/∂X = M(d)·Ad_A` and `∂d/∂Y = −M(−d)` (thesis eq. 5.18–5.21). `D` is linear in `d`, so
/// the CBH forms share `D` and `D²` (`M(±d) = I ± ½D + D²/12`): one matrix product for both
/// instead of one per term and sign.
pub fn log_jacobian_factors<G: LieGroup<DOF>, const DOF: usize>(
    d: &SVector<f64, DOF>,
    method: LogJacobian,
) -> (SMatrix<f64, DOF, DOF>, SMatrix<f64, DOF, DOF>) {
    let identity = SMatrix::<f64, DOF, DOF>::identity();
    match method {
        LogJacobian::Cbh1 => (identity, identity),
        LogJacobian::Cbh2 | LogJacobian::Cbh3 => {
            let d_bracket = G::d_lie_bracket(d);
            let mut even = identity;
            if method == LogJacobian::Cbh3 {
                even += (d_bracket * d_bracket) * (1.0 / 12.0);
            }
            let half = d_bracket * 0.5;
            (even + half, even - half)
        }
        LogJacobian::Exact => (G::left_jacobian_inverse(d), G::left_jacobian_inverse(&(-d))),
    }
}

/// `a * b` for composition and `g * p` for the action on a point, by value and by reference,
/// for a group implementing [`LieGroup`].
#[macro_export]
#[doc(hidden)]
macro_rules! impl_group_operators {
    ($g:ty, $dof:literal, $point:ty) => {
        impl ::std::ops::Mul for $g {
            type Output = $g;
            #[inline]
            fn mul(self, rhs: $g) -> $g {
                $crate::LieGroup::<$dof>::compose(&self, &rhs)
            }
        }
        impl ::std::ops::Mul<&$g> for &$g {
            type Output = $g;
            #[inline]
            fn mul(self, rhs: &$g) -> $g {
                $crate::LieGroup::<$dof>::compose(self, rhs)
            }
        }
        impl ::std::ops::Mul<$point> for $g {
            type Output = $point;
            #[inline]
            fn mul(self, rhs: $point) -> $point {
                $crate::LieGroup::<$dof>::act(&self, &rhs)
            }
        }
        impl ::std::ops::Mul<&$point> for &$g {
            type Output = $point;
            #[inline]
            fn mul(self, rhs: &$point) -> $point {
                $crate::LieGroup::<$dof>::act(self, rhs)
            }
        }
    };
}

/// The largest deviation of a homogeneous matrix's last row from `(0, …, 0, 1)`; an error if
/// it exceeds `tolerance`.
pub(crate) fn check_last_row<const N: usize>(
    matrix: &nalgebra::SMatrix<f64, N, N>,
    tolerance: f64,
) -> Result<(), LieError> {
    let last = N - 1;
    let deviation = (0..N)
        .map(|c| (matrix[(last, c)] - if c == last { 1.0 } else { 0.0 }).abs())
        .fold(0.0, f64::max);
    if deviation > tolerance {
        return Err(LieError::NotHomogeneous { deviation });
    }
    Ok(())
}

/// The skew-symmetric cross-product matrix `[ω]×` with `[ω]×·b = ω × b` (thesis eq. 2.60).
#[inline]
pub fn skew(w: &nalgebra::Vector3<f64>) -> nalgebra::Matrix3<f64> {
    nalgebra::Matrix3::new(0.0, -w.z, w.y, w.z, 0.0, -w.x, -w.y, w.x, 0.0)
}

/// The vector of a skew-symmetric matrix, `(Ω₃₂, Ω₁₃, Ω₂₁)` averaged with the negated
/// transposed entries (thesis eq. 2.61).
#[inline]
pub fn unskew(m: &nalgebra::Matrix3<f64>) -> nalgebra::Vector3<f64> {
    nalgebra::Vector3::new(
        0.5 * (m[(2, 1)] - m[(1, 2)]),
        0.5 * (m[(0, 2)] - m[(2, 0)]),
        0.5 * (m[(1, 0)] - m[(0, 1)]),
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// `log_jacobian_factors` gives the same log Jacobians as `d_log_from_parts`: `M(d)·Ad_A`
    /// and `M(−d) = ∂ log(I·exp(ε)·exp(−d))/∂ε`, for every method and group with a bracket.
    fn factors_match<G: LieGroup<D>, const D: usize>(seed: u64) {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        for _ in 0..20 {
            let mut tangent = || SVector::<f64, D>::from_fn(|_, _| rng.random_range(-0.7..0.7));
            let d = tangent();
            let ad = G::exp(&tangent()).adjoint();
            let identity = SMatrix::<f64, D, D>::identity();
            for method in [
                LogJacobian::Cbh1,
                LogJacobian::Cbh2,
                LogJacobian::Cbh3,
                LogJacobian::Exact,
            ] {
                let (plus, minus) = log_jacobian_factors::<G, D>(&d, method);
                let ref_plus = d_log_from_parts::<G, D>(&d, &ad, method);
                let ref_minus = d_log_from_parts::<G, D>(&(-d), &identity, method);
                assert!((plus * ad - ref_plus).abs().max() < 1e-12, "{method:?}");
                assert!((minus - ref_minus).abs().max() < 1e-12, "{method:?}");
            }
        }
    }

    #[test]
    fn log_jacobian_factors_match_the_log_jacobians() {
        factors_match::<Se2, 3>(1);
        factors_match::<Se3, 6>(2);
        factors_match::<Sim3, 7>(3);
    }
}
