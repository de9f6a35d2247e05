//! Dense symmetric positive-definite algebra (used by the Gauss-Newton filter of thesis §4.4.2): Cholesky solves,
//! inverses and Schur-complement marginalisation on `nalgebra` matrices, factorised by faer's
//! blocked Cholesky (single-threaded).

use faer::linalg::solvers::Solve;
use faer::{MatMut, MatRef, Side};
use nalgebra::DMatrix;

/// Solves `A·X = B` in place (`B` becomes `X`) for symmetric positive-definite `A`; false if
/// `A` is not positive definite.
pub fn cholesky_solve_in_place(a: &DMatrix<f64>, b: &mut DMatrix<f64>) -> bool {
    let n = a.nrows();
    debug_assert_eq!(a.ncols(), n);
    debug_assert_eq!(b.nrows(), n);
    if n == 0 {
        return true;
    }
    let a_ref = MatRef::from_column_major_slice(a.as_slice(), n, n);
    let Ok(llt) = a_ref.llt(Side::Lower) else {
        return false;
    };
    let k = b.ncols();
    llt.solve_in_place(MatMut::from_column_major_slice_mut(b.as_mut_slice(), n, k));
    b.iter().all(|x| x.is_finite())
}

/// The Cholesky factor of a symmetric positive-definite matrix, for repeated solves.
pub struct SpdFactor {
    llt: faer::linalg::solvers::Llt<f64>,
    n: usize,
}

impl SpdFactor {
    /// Factorises `a`; `None` if it is not positive definite.
    pub fn new(a: &DMatrix<f64>) -> Option<Self> {
        let n = a.nrows();
        let a_ref = MatRef::from_column_major_slice(a.as_slice(), n, n);
        a_ref.llt(Side::Lower).ok().map(|llt| SpdFactor { llt, n })
    }

    /// Solves `A·X = B` in place; false if the result is not finite.
    pub fn solve_in_place(&self, b: &mut DMatrix<f64>) -> bool {
        debug_assert_eq!(b.nrows(), self.n);
        let k = b.ncols();
        if self.n > 0 {
            self.llt.solve_in_place(MatMut::from_column_major_slice_mut(
                b.as_mut_slice(),
                self.n,
                k,
            ));
        }
        b.iter().all(|x| x.is_finite())
    }
}

/// `A⁻¹` of a symmetric positive-definite `A`, or `None`.
pub fn spd_inverse(a: &DMatrix<f64>) -> Option<DMatrix<f64>> {
    let mut x = DMatrix::identity(a.nrows(), a.nrows());
    cholesky_solve_in_place(a, &mut x).then(|| {
        // Symmetrise against round-off.
        let t = x.transpose();
        (x + t) * 0.5
    })
}

/// Marginalises the scalar indices `remove` out of the information matrix `lambda`
/// (thesis eq. 4.25): `Λ_rr − Λ_rm·Λ_mm⁻¹·Λ_mr` over the kept indices in their order. `None`
/// if `Λ_mm` is not positive definite.
pub fn marginalise(lambda: &DMatrix<f64>, remove: &[usize]) -> Option<DMatrix<f64>> {
    let n = lambda.nrows();
    let mut removed = vec![false; n];
    for &r in remove {
        removed[r] = true;
    }
    let keep: Vec<usize> = (0..n).filter(|i| !removed[*i]).collect();
    let lrr = lambda.select_rows(&keep).select_columns(&keep);
    if remove.is_empty() {
        return Some(lrr);
    }
    let lmm = lambda.select_rows(remove).select_columns(remove);
    let mut x = lambda.select_rows(remove).select_columns(&keep); // Λ_mr
    let lmr = x.clone();
    if !cholesky_solve_in_place(&lmm, &mut x) {
        return None;
    }
    let mut out = lrr;
    // out −= Λ_rm·(Λ_mm⁻¹Λ_mr)
    out.gemm_tr(-1.0, &lmr, &x, 1.0);
    let t = out.transpose();
    Some((out + t) * 0.5)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn spd(n: usize, seed: u64) -> DMatrix<f64> {
        let mut s = seed;
        let a = DMatrix::from_fn(n, n, |_, _| {
            s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            ((s >> 33) as f64 / (1u64 << 31) as f64) - 0.5
        });
        &a * a.transpose() + DMatrix::identity(n, n) * 0.1
    }

    #[test]
    fn marginalisation_equals_the_inverse_of_the_covariance_block() {
        let l = spd(9, 3);
        let keep = [0usize, 2, 3, 5, 8];
        let remove = [1usize, 4, 6, 7];
        let m = marginalise(&l, &remove).unwrap();
        let cov = spd_inverse(&l).unwrap();
        let cov_kept = cov.select_rows(&keep).select_columns(&keep);
        let expected = spd_inverse(&cov_kept).unwrap();
        assert!((m - expected).amax() < 1e-9);
        let mut b = DMatrix::from_fn(9, 2, |i, j| (i + j) as f64);
        let b0 = b.clone();
        assert!(cholesky_solve_in_place(&l, &mut b));
        assert!((&l * b - b0).amax() < 1e-9);
        let not_pd = -DMatrix::<f64>::identity(3, 3);
        assert!(spd_inverse(&not_pd).is_none());
    }
}
