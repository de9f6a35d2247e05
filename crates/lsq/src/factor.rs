//! Factors: residuals of any arity with analytic Jacobians, their information matrices.

use crate::values::{Values, VarKey};
use nalgebra::{DMatrix, SMatrix};

/// The largest number of variables one factor may connect.
pub const MAX_ARITY: usize = 8;

/// A residual `r(x₁, …, x_k)` of fixed dimension over some variables, with its Jacobians
/// with respect to each variable's update (left perturbation `exp(ε)·x` for groups, thesis
/// eq. 2.102).
///
/// The problem weights the residual with the factor's information matrix `Λ` and a robust
/// kernel given when the factor is added; the cost contributed is `½ρ(rᵀΛr)`.
pub trait Factor: Send + Sync {
    /// The dimension of the residual.
    fn residual_dim(&self) -> usize;

    /// The variables, in the order of the Jacobian blocks. Called once, when the factor is
    /// added to a problem.
    fn variables(&self) -> Vec<VarKey>;

    /// Writes the residual and, if asked, the Jacobian blocks. Returns `false` when the
    /// residual is undefined at these values (e.g. a point behind the camera): the factor then
    /// contributes nothing to this iteration and is counted as rejected.
    fn evaluate(
        &self,
        values: &Values,
        residual: &mut [f64],
        jacobians: Option<&mut Jacobians<'_>>,
    ) -> bool;
}

/// The Jacobian blocks of one factor: block `k` is `residual_dim × dim(x_k)`, column-major.
pub struct Jacobians<'a> {
    data: &'a mut [f64],
    rows: usize,
    offsets: [usize; MAX_ARITY + 1],
    wanted: [bool; MAX_ARITY],
    arity: usize,
}

impl<'a> Jacobians<'a> {
    pub(crate) fn new(
        data: &'a mut [f64],
        rows: usize,
        dims: &[usize],
        wanted: [bool; MAX_ARITY],
    ) -> Self {
        let mut offsets = [0; MAX_ARITY + 1];
        for (k, d) in dims.iter().enumerate() {
            offsets[k + 1] = offsets[k] + rows * d;
        }
        debug_assert!(data.len() >= offsets[dims.len()]);
        Jacobians {
            data,
            rows,
            offsets,
            wanted,
            arity: dims.len(),
        }
    }

    /// Whether block `k` is needed (its variable is free). A factor may skip computing blocks
    /// that are not wanted.
    #[inline]
    pub fn wants(&self, k: usize) -> bool {
        self.wanted[k]
    }

    /// Block `k`, column-major.
    #[inline]
    pub fn block_mut(&mut self, k: usize) -> &mut [f64] {
        assert!(
            k < self.arity,
            "Jacobian block {k} of a factor with {} variables",
            self.arity
        );
        &mut self.data[self.offsets[k]..self.offsets[k + 1]]
    }

    /// Sets block `k` from a fixed-size matrix (its shape must be `residual_dim × dim(x_k)`).
    #[inline]
    pub fn set<const R: usize, const C: usize>(&mut self, k: usize, block: &SMatrix<f64, R, C>) {
        debug_assert_eq!(R, self.rows, "Jacobian block rows");
        self.block_mut(k).copy_from_slice(block.as_slice());
    }
}

/// The information matrix `Λ` of a factor (inverse covariance of its residual).
#[derive(Clone, Debug, PartialEq)]
pub enum Information {
    /// `Λ = I`.
    Identity,
    /// `Λ = I/σ²`, the same standard deviation in every component.
    Isotropic(f64),
    /// A diagonal `Λ`.
    Diagonal(Vec<f64>),
    /// A full symmetric positive-definite `Λ`.
    Full(DMatrix<f64>),
}

/// Why an information matrix was refused.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum InformationError {
    /// The size does not match the residual dimension.
    #[error("information matrix is {got}×{got} but the residual has dimension {expected}")]
    WrongSize {
        /// The residual dimension.
        expected: usize,
        /// The size given.
        got: usize,
    },
    /// Not finite, not symmetric or not positive definite.
    #[error("information matrix is not symmetric positive definite: {reason}")]
    NotPositiveDefinite {
        /// What is wrong.
        reason: String,
    },
}

/// How a residual is whitened: `r̃ = W·r` with `WᵀW = Λ`.
#[derive(Clone, Debug)]
pub(crate) enum Whitening {
    Identity,
    Scale(f64),
    /// Offset into the problem's pool of diagonal entries.
    Diagonal(usize),
    /// Offset into the pool of upper-triangular `W = Lᵀ` (column-major `R×R`), `Λ = L·Lᵀ`.
    Full(usize),
    /// Offset into the pool of a general `W = √D·Qᵀ` (column-major `R×R`) for a singular
    /// positive semi-definite `Λ = Q·D·Qᵀ`, whose Cholesky factorisation does not exist.
    Dense(usize),
}

impl Information {
    /// Validates `Λ` for a residual of dimension `dim` and converts it to a whitening, pushing
    /// any matrix into `pool`.
    pub(crate) fn whitening(
        &self,
        dim: usize,
        pool: &mut Vec<f64>,
    ) -> Result<Whitening, InformationError> {
        let bad = |reason: String| InformationError::NotPositiveDefinite { reason };
        match self {
            Information::Identity => Ok(Whitening::Identity),
            Information::Isotropic(sigma) => {
                if !(sigma.is_finite() && *sigma > 0.0) {
                    return Err(bad(format!("standard deviation {sigma}")));
                }
                Ok(Whitening::Scale(1.0 / sigma))
            }
            Information::Diagonal(d) => {
                if d.len() != dim {
                    return Err(InformationError::WrongSize {
                        expected: dim,
                        got: d.len(),
                    });
                }
                if let Some(x) = d.iter().find(|x| !(x.is_finite() && **x > 0.0)) {
                    return Err(bad(format!("diagonal entry {x}")));
                }
                let offset = pool.len();
                pool.extend(d.iter().map(|x| x.sqrt()));
                Ok(Whitening::Diagonal(offset))
            }
            Information::Full(m) => {
                if m.nrows() != dim || m.ncols() != dim {
                    return Err(InformationError::WrongSize {
                        expected: dim,
                        got: m.nrows(),
                    });
                }
                if !m.iter().all(|x| x.is_finite()) {
                    return Err(bad("non-finite entry".into()));
                }
                let asym = (m - m.transpose()).abs().max();
                if asym > 1e-9 * (1.0 + m.abs().max()) {
                    return Err(bad(format!("asymmetric by {asym:e}")));
                }
                // A diagonal Λ (common: g2o files and unit information write full matrices
                // with zero off-diagonals) is whitened by the cheaper variants. Their `W` is
                // the same as the Cholesky factor's (√Λ_ii on the diagonal, exact zeros off
                // it), so the whitened values are bit for bit those of the full product. Zero
                // entries (a singular Λ: no information on that component) give zero weights.
                let diagonal = (0..dim).all(|c| (0..dim).all(|r| r == c || m[(r, c)] == 0.0));
                if diagonal {
                    if let Some(k) = (0..dim).find(|&k| m[(k, k)] < 0.0) {
                        return Err(bad(format!("negative diagonal entry {}", m[(k, k)])));
                    }
                    let first = m[(0, 0)];
                    if (0..dim).all(|k| m[(k, k)] == first) {
                        return Ok(if first == 1.0 {
                            Whitening::Identity
                        } else {
                            Whitening::Scale(first.sqrt())
                        });
                    }
                    let offset = pool.len();
                    pool.extend((0..dim).map(|k| m[(k, k)].sqrt()));
                    return Ok(Whitening::Diagonal(offset));
                }
                if let Some(chol) = m.clone().cholesky() {
                    let w = chol.l().transpose();
                    let offset = pool.len();
                    pool.extend_from_slice(w.as_slice());
                    return Ok(Whitening::Full(offset));
                }
                // Singular but positive semi-definite (eigenvalues ≥ −tol, tol = 64·R·ε·|λ|max,
                // rounding of a zero eigenvalue): W = √max(D, 0)·Qᵀ, so WᵀW = Λ and the
                // residual's component along the null space carries no weight.
                let eig = nalgebra::SymmetricEigen::new(m.clone());
                let scale = eig.eigenvalues.amax();
                let tol = 64.0 * dim as f64 * f64::EPSILON * scale;
                let min = eig.eigenvalues.min();
                if min < -tol {
                    return Err(bad(format!(
                        "indefinite (smallest eigenvalue {min:e}, largest {scale:e})"
                    )));
                }
                let mut w = eig.eigenvectors.transpose();
                for (mut row, &l) in w.row_iter_mut().zip(eig.eigenvalues.iter()) {
                    row *= l.max(0.0).sqrt();
                }
                let offset = pool.len();
                pool.extend_from_slice(w.as_slice());
                Ok(Whitening::Dense(offset))
            }
        }
    }
}

impl Whitening {
    /// `x ← W·x` for a column of length `dim`.
    #[inline]
    pub(crate) fn apply(&self, pool: &[f64], dim: usize, x: &mut [f64]) {
        match *self {
            Whitening::Identity => {}
            Whitening::Scale(s) => x.iter_mut().for_each(|v| *v *= s),
            Whitening::Diagonal(o) => {
                for (v, w) in x.iter_mut().zip(&pool[o..o + dim]) {
                    *v *= w;
                }
            }
            Whitening::Full(o) => {
                let w = &pool[o..o + dim * dim];
                match dim {
                    3 => upper_triangular_times::<3>(w, x),
                    6 => upper_triangular_times::<6>(w, x),
                    7 => upper_triangular_times::<7>(w, x),
                    _ => {
                        for i in 0..dim {
                            let mut acc = 0.0;
                            for j in i..dim {
                                acc += w[j * dim + i] * x[j];
                            }
                            x[i] = acc;
                        }
                    }
                }
            }
            Whitening::Dense(o) => {
                let w = &pool[o..o + dim * dim];
                let (mut small, mut large) = ([0.0f64; 16], Vec::new());
                let input: &mut [f64] = if dim <= 16 {
                    &mut small[..dim]
                } else {
                    large.resize(dim, 0.0);
                    &mut large
                };
                input.copy_from_slice(&x[..dim]);
                for (i, xi) in x.iter_mut().enumerate().take(dim) {
                    *xi = (0..dim).map(|j| w[j * dim + i] * input[j]).sum();
                }
            }
        }
    }
}

/// `x ← W·x` for an upper-triangular `W` (column-major `D×D`): `(W·x)_i = Σ_{j ≥ i} W_ij x_j`,
/// with constant bounds so the loops unroll (the pose sizes of pose graphs and BA).
#[inline(always)]
fn upper_triangular_times<const D: usize>(w: &[f64], x: &mut [f64]) {
    let w = &w[..D * D];
    let x: &mut [f64; D] = x.try_into().expect("vector of length D");
    for i in 0..D {
        let mut acc = 0.0;
        for j in i..D {
            acc += w[j * D + i] * x[j];
        }
        x[i] = acc;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Singular positive semi-definite information (a zero diagonal entry; a full matrix with a
    /// null direction) is whitened with `WᵀW = Λ`; an indefinite one is refused.
    #[test]
    fn singular_semidefinite_information_is_whitened_and_indefinite_refused() {
        let mut pool = Vec::new();
        let d = DMatrix::from_diagonal(&nalgebra::DVector::from_vec(vec![4.0, 0.0, 9.0]));
        let w = Information::Full(d).whitening(3, &mut pool).unwrap();
        assert!(matches!(w, Whitening::Diagonal(_)));
        let mut y = [1.0, 5.0, 1.0];
        w.apply(&pool, 3, &mut y);
        assert_eq!(y, [2.0, 0.0, 3.0]);
        // Λ = A·Aᵀ with A of rank 4 (6×4): singular, Cholesky fails.
        let a = DMatrix::from_fn(6, 4, |r, c| ((r * 7 + c * 3) % 5) as f64 - 1.5);
        let m = &a * a.transpose();
        assert!(m.clone().cholesky().is_none());
        let mut pool = Vec::new();
        let w = Information::Full(m.clone())
            .whitening(6, &mut pool)
            .unwrap();
        assert!(matches!(w, Whitening::Dense(_)));
        let x = [0.3, -1.2, 2.5, 0.7, -0.4, 1.1];
        let mut y = x;
        w.apply(&pool, 6, &mut y);
        let xv = nalgebra::DVector::from_column_slice(&x);
        let want = (xv.transpose() * &m * &xv)[0];
        let got: f64 = y.iter().map(|v| v * v).sum();
        assert!(
            (got - want).abs() < 1e-12 * want.abs().max(1.0),
            "{got} vs {want}"
        );
        let mut ind = DMatrix::<f64>::identity(3, 3);
        ind[(2, 2)] = -1.0;
        assert!(Information::Full(ind).whitening(3, &mut pool).is_err());
        let mut ind = DMatrix::<f64>::identity(3, 3);
        ind[(0, 1)] = 2.0;
        ind[(1, 0)] = 2.0;
        assert!(Information::Full(ind).whitening(3, &mut pool).is_err());
    }

    /// A full information matrix that happens to be diagonal is whitened by the cheap
    /// variants, with the same values as the Cholesky factor's product; a non-diagonal one
    /// keeps the full product.
    #[test]
    fn diagonal_full_information_is_whitened_like_the_full_product() {
        let x = [0.3, -1.2, 2.5, 0.7, -0.4, 1.1, 0.9];
        let cases = [
            (DMatrix::<f64>::identity(7, 7), "identity"),
            (DMatrix::<f64>::identity(7, 7) * 4.0, "isotropic"),
            (
                DMatrix::from_diagonal(&nalgebra::DVector::from_vec(vec![
                    1.0, 4.0, 9.0, 0.25, 2.0, 3.0, 5.0,
                ])),
                "diagonal",
            ),
        ];
        for (m, name) in cases {
            let mut pool = Vec::new();
            let w = Information::Full(m.clone())
                .whitening(7, &mut pool)
                .unwrap();
            match (name, &w) {
                ("identity", Whitening::Identity)
                | ("isotropic", Whitening::Scale(_))
                | ("diagonal", Whitening::Diagonal(_)) => {}
                _ => panic!("{name}: {w:?}"),
            }
            let mut y = x;
            w.apply(&pool, 7, &mut y);
            let expected =
                m.cholesky().unwrap().l().transpose() * nalgebra::DVector::from_column_slice(&x);
            for k in 0..7 {
                assert_eq!(y[k], expected[k], "{name} entry {k}");
            }
        }
        let mut m = DMatrix::<f64>::identity(7, 7) * 3.0;
        m[(1, 4)] = 0.5;
        m[(4, 1)] = 0.5;
        let mut pool = Vec::new();
        let w = Information::Full(m.clone())
            .whitening(7, &mut pool)
            .unwrap();
        assert!(matches!(w, Whitening::Full(_)));
        let mut y = x;
        w.apply(&pool, 7, &mut y);
        let expected =
            m.cholesky().unwrap().l().transpose() * nalgebra::DVector::from_column_slice(&x);
        for k in 0..7 {
            assert!((y[k] - expected[k]).abs() < 1e-14);
        }
    }
}
