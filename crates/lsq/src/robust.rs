//! Robust kernels `ρ(s)` of the squared whitened residual `s = ‖r‖²_Λ` (thesis §3.3.7).
//!
//! The cost of a factor is `½ρ(s)`; the optimiser uses iteratively re-weighted least squares:
//! the whitened residual and Jacobian are scaled by `√ρ'(s)`, which gives the exact gradient
//! `ρ'(s)·Jᵀ Λ r` and the Gauss-Newton Hessian `ρ'(s)·Jᵀ Λ J` (as g2o does; the thesis's
//! eq. 3.29 weights).

/// A robust kernel with its width `b` (in units of the whitened residual, i.e. standard
/// deviations when the information matrix is the inverse covariance).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum RobustKernel {
    /// Huber (thesis eq. 3.27–3.28): `ρ(s) = s` for `s ≤ b²`, `2b·√s − b²` beyond — quadratic
    /// near zero, linear in `‖r‖` for outliers.
    Huber(f64),
    /// Cauchy: `ρ(s) = b²·ln(1 + s/b²)`.
    Cauchy(f64),
    /// Tukey's biweight: `ρ(s) = b²/3·(1 − (1 − s/b²)³)` for `s ≤ b²`, `b²/3` beyond: outliers
    /// get zero weight.
    Tukey(f64),
}

impl RobustKernel {
    /// `(ρ(s), ρ'(s))`.
    #[inline]
    pub fn evaluate(&self, s: f64) -> (f64, f64) {
        match *self {
            RobustKernel::Huber(b) => {
                let b2 = b * b;
                if s <= b2 {
                    (s, 1.0)
                } else {
                    let r = s.sqrt();
                    (2.0 * b * r - b2, b / r)
                }
            }
            RobustKernel::Cauchy(b) => {
                let b2 = b * b;
                (b2 * (s / b2).ln_1p(), 1.0 / (1.0 + s / b2))
            }
            RobustKernel::Tukey(b) => {
                let b2 = b * b;
                if s <= b2 {
                    let a = 1.0 - s / b2;
                    (b2 / 3.0 * (1.0 - a * a * a), a * a)
                } else {
                    (b2 / 3.0, 0.0)
                }
            }
        }
    }

    /// Whether the width is positive and finite.
    pub fn is_valid(&self) -> bool {
        let b = match *self {
            RobustKernel::Huber(b) | RobustKernel::Cauchy(b) | RobustKernel::Tukey(b) => b,
        };
        b.is_finite() && b > 0.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn kernels_are_quadratic_near_zero_and_their_derivatives_are_right() {
        for kernel in [
            RobustKernel::Huber(1.5),
            RobustKernel::Cauchy(2.0),
            RobustKernel::Tukey(3.0),
        ] {
            let (rho0, d0) = kernel.evaluate(0.0);
            assert_eq!(rho0, 0.0);
            assert!((d0 - 1.0).abs() < 1e-15);
            for &s in &[0.01, 0.5, 2.0, 7.0, 20.0] {
                let h = 1e-6;
                let numeric = (kernel.evaluate(s + h).0 - kernel.evaluate(s - h).0) / (2.0 * h);
                let (_, d) = kernel.evaluate(s);
                assert!(
                    (numeric - d).abs() < 1e-6,
                    "{kernel:?} at {s}: {numeric} vs {d}"
                );
            }
        }
        // Huber grows linearly in |r| for outliers.
        let (rho, _) = RobustKernel::Huber(1.0).evaluate(100.0);
        assert!((rho - 19.0).abs() < 1e-12);
        // Tukey saturates.
        assert_eq!(RobustKernel::Tukey(2.0).evaluate(1e6), (4.0 / 3.0, 0.0));
    }
}
