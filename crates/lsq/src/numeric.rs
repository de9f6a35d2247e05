//! Checking a factor's analytic Jacobians against numeric differentiation through the same
//! update the optimiser applies (`exp(ε)·x` for groups, `x + ε` for vectors).

use crate::factor::{Factor, Jacobians, MAX_ARITY};
use crate::values::Values;

/// The largest discrepancy found by [`check_jacobians`].
#[derive(Clone, Debug)]
pub struct JacobianCheck {
    /// `max |J_analytic − J_numeric|` over all blocks.
    pub max_abs_error: f64,
    /// `max |J_numeric|`, for judging the error relative to the Jacobian's scale.
    pub max_abs_numeric: f64,
    /// Which variable slot had the largest error.
    pub worst_variable: usize,
}

impl JacobianCheck {
    /// Whether `max_abs_error ≤ tolerance·(1 + max_abs_numeric)`.
    pub fn passes(&self, tolerance: f64) -> bool {
        self.max_abs_error <= tolerance * (1.0 + self.max_abs_numeric)
    }
}

/// Evaluates `factor`'s analytic Jacobians at `values` and compares them with central
/// differences (step `h`, one Richardson extrapolation). Returns `None` when the factor's
/// residual is undefined at `values`.
pub fn check_jacobians(factor: &dyn Factor, values: &Values, h: f64) -> Option<JacobianCheck> {
    let keys = factor.variables();
    let rows = factor.residual_dim();
    let dims: Vec<usize> = keys.iter().map(|k| values.dim(*k)).collect();
    let width: usize = dims.iter().sum();
    let mut residual = vec![0.0; rows];
    let mut analytic = vec![0.0; rows * width];
    {
        let mut jac = Jacobians::new(&mut analytic, rows, &dims, [true; MAX_ARITY]);
        if !factor.evaluate(values, &mut residual, Some(&mut jac)) {
            return None;
        }
    }
    let eval = |k: usize, c: usize, t: f64| -> Option<Vec<f64>> {
        let mut v = values.clone();
        let mut delta = vec![0.0; dims[k]];
        delta[c] = t;
        v.retract(keys[k], &delta);
        let mut r = vec![0.0; rows];
        factor.evaluate(&v, &mut r, None).then_some(r)
    };
    let mut check = JacobianCheck {
        max_abs_error: 0.0,
        max_abs_numeric: 0.0,
        worst_variable: 0,
    };
    let mut offset = 0;
    for k in 0..keys.len() {
        for c in 0..dims[k] {
            let d = |step: f64| -> Option<Vec<f64>> {
                let plus = eval(k, c, step)?;
                let minus = eval(k, c, -step)?;
                Some(
                    plus.iter()
                        .zip(&minus)
                        .map(|(a, b)| (a - b) / (2.0 * step))
                        .collect(),
                )
            };
            let (d_h, d_half) = (d(h)?, d(0.5 * h)?);
            for r in 0..rows {
                let numeric = (4.0 * d_half[r] - d_h[r]) / 3.0;
                let a = analytic[offset + c * rows + r];
                let err = (a - numeric).abs();
                check.max_abs_numeric = check.max_abs_numeric.max(numeric.abs());
                if err > check.max_abs_error {
                    check.max_abs_error = err;
                    check.worst_variable = k;
                }
            }
        }
        offset += rows * dims[k];
    }
    Some(check)
}
