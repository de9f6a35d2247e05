//! Numeric differentiation through the optimiser's left update, the reference every analytic
//! Jacobian in dwslam is tested against.
//!
//! Derivatives are central differences `(f(x + h) − f(x − h))/2h` refined by one Richardson
//! extrapolation step, `(4·D(h/2) − D(h))/3`, which cancels the `O(h²)` error: with the default
//! `h = 1e-3` the truncation error is `O(h⁴) ≈ 1e-12` and rounding `≈ ε/h ≈ 1e-13` for
//! functions of unit scale.

use crate::LieGroup;
use nalgebra::{SMatrix, SVector};

/// Default step of [`jacobian_left`] and [`jacobian_vector`].
pub const DEFAULT_STEP: f64 = 1e-3;

#[inline]
fn richardson<const M: usize>(
    f_plus: impl Fn(f64) -> SVector<f64, M>,
    f_minus: impl Fn(f64) -> SVector<f64, M>,
    h: f64,
) -> SVector<f64, M> {
    let d_h = (f_plus(h) - f_minus(h)) / (2.0 * h);
    let half = 0.5 * h;
    let d_half = (f_plus(half) - f_minus(half)) / h;
    (d_half * 4.0 - d_h) / 3.0
}

/// `∂f(exp(ε)·x)/∂ε` at `ε = 0` for `f: G → ℝᴹ`: the Jacobian with respect to the left
/// perturbation the optimiser applies (thesis eq. 2.102–2.104).
pub fn jacobian_left<G, const D: usize, const M: usize>(
    x: &G,
    f: impl Fn(&G) -> SVector<f64, M>,
) -> SMatrix<f64, M, D>
where
    G: LieGroup<D>,
{
    jacobian_left_with_step(x, f, DEFAULT_STEP)
}

/// [`jacobian_left`] with an explicit step `h`.
pub fn jacobian_left_with_step<G, const D: usize, const M: usize>(
    x: &G,
    f: impl Fn(&G) -> SVector<f64, M>,
    h: f64,
) -> SMatrix<f64, M, D>
where
    G: LieGroup<D>,
{
    let mut jac = SMatrix::<f64, M, D>::zeros();
    for k in 0..D {
        let eval = |t: f64| {
            let mut e = SVector::<f64, D>::zeros();
            e[k] = t;
            f(&x.retract_left(&e))
        };
        let col = richardson(eval, |t| eval(-t), h);
        jac.set_column(k, &col);
    }
    jac
}

/// `∂f(x)/∂x` for `f: ℝᴺ → ℝᴹ`.
pub fn jacobian_vector<const N: usize, const M: usize>(
    x: &SVector<f64, N>,
    f: impl Fn(&SVector<f64, N>) -> SVector<f64, M>,
) -> SMatrix<f64, M, N> {
    jacobian_vector_with_step(x, f, DEFAULT_STEP)
}

/// [`jacobian_vector`] with an explicit step `h`.
pub fn jacobian_vector_with_step<const N: usize, const M: usize>(
    x: &SVector<f64, N>,
    f: impl Fn(&SVector<f64, N>) -> SVector<f64, M>,
    h: f64,
) -> SMatrix<f64, M, N> {
    let mut jac = SMatrix::<f64, M, N>::zeros();
    for k in 0..N {
        let eval = |t: f64| {
            let mut y = *x;
            y[k] += t;
            f(&y)
        };
        let col = richardson(eval, |t| eval(-t), h);
        jac.set_column(k, &col);
    }
    jac
}

/// The numeric log Jacobian `∂ log(A·exp(ε)·B)^∨ / ∂ε` at `ε = 0` (thesis eq. 5.20), the
/// reference `J_num` of thesis Table 5.1.
pub fn d_log_left<G, const D: usize>(a: &G, b: &G) -> SMatrix<f64, D, D>
where
    G: LieGroup<D>,
{
    let mut jac = SMatrix::<f64, D, D>::zeros();
    for k in 0..D {
        let eval = |t: f64| {
            let mut e = SVector::<f64, D>::zeros();
            e[k] = t;
            a.compose(&G::exp(&e)).compose(b).log()
        };
        let col = richardson(eval, |t| eval(-t), DEFAULT_STEP);
        jac.set_column(k, &col);
    }
    jac
}
