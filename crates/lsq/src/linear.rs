//! Solvers of the damped normal equations `(H + D)·δ = −g` (thesis §3.3.4–3.3.6).

use crate::block::{BlockSymmetric, invert_spd_in_place};
use crate::solver::CholeskyMethod;
use faer::dyn_stack::{MemBuffer, MemStack, StackReq};
use faer::sparse::linalg::cholesky::{
    CholeskySymbolicParams, LltRef, SymbolicCholesky, SymmetricOrdering,
    factorize_symbolic_cholesky,
};
use faer::sparse::linalg::{SupernodalThreshold, amd};
use faer::sparse::{SparseColMatRef, SymbolicSparseColMatRef};
use faer::{Conj, MatMut, Par, Side};

/// Why a linear solve failed.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum LinearError {
    /// The (damped) system is not numerically positive definite: an unfixed gauge freedom
    /// without damping, or a degenerate problem.
    #[error("the normal equations are not positive definite (unfixed gauge or degenerate problem)")]
    NotPositiveDefinite,
    /// The symbolic analysis failed (e.g. out of memory).
    #[error("symbolic factorisation failed: {0}")]
    Symbolic(String),
}

/// A factorisation-based or iterative solver of `(H + diag(d))·δ = −g`.
pub(crate) trait LinearSolve: Send {
    /// Solves; returns the number of inner iterations (1 for direct solvers).
    fn solve(
        &mut self,
        h: &BlockSymmetric,
        g: &[f64],
        diag_add: &[f64],
        delta: &mut [f64],
    ) -> Result<usize, LinearError>;
}

/// Supernodal sparse Cholesky by faer on the scalar lower triangle of `H`, with a
/// fill-reducing AMD ordering computed on the block graph (cheaper than on the scalar graph
/// and as good, since blocks are dense) and the symbolic factorisation computed once per
/// sparsity pattern and reused at every iteration (thesis §3.3.6).
pub(crate) struct SparseCholesky {
    n: usize,
    col_ptr: Vec<usize>,
    row_idx: Vec<usize>,
    values: Vec<f64>,
    /// For each scalar entry, its index in the block matrix's values.
    gather: Vec<usize>,
    /// The scalar entry of each diagonal element, in order.
    diagonal: Vec<usize>,
    symbolic: SymbolicCholesky<usize>,
    l_values: Vec<f64>,
    mem: MemBuffer,
}

impl SparseCholesky {
    /// Analyses the pattern of `h`.
    pub(crate) fn new(h: &BlockSymmetric, method: CholeskyMethod) -> Result<Self, LinearError> {
        let n = h.dim();
        let mut col_ptr = Vec::with_capacity(n + 1);
        let mut row_idx = Vec::new();
        let mut gather = Vec::new();
        let mut diagonal = Vec::with_capacity(n);
        col_ptr.push(0);
        for j in 0..h.num_blocks() {
            let dj = h.dims[j];
            for c in 0..dj {
                for s in h.col_ptr[j]..h.col_ptr[j + 1] {
                    let i = h.rows[s] as usize;
                    let di = h.dims[i];
                    let first = if i == j { c } else { 0 };
                    for r in first..di {
                        if i == j && r == c {
                            diagonal.push(row_idx.len());
                        }
                        row_idx.push(h.offsets[i] + r);
                        gather.push(h.value_offsets[s] + c * di + r);
                    }
                }
                col_ptr.push(row_idx.len());
            }
        }
        // AMD on the block graph, expanded to a scalar permutation.
        let nb = h.num_blocks();
        let block_col_ptr: Vec<usize> = h.col_ptr.clone();
        let block_rows: Vec<usize> = h.rows.iter().map(|&r| r as usize).collect();
        let mut block_perm = vec![0usize; nb];
        let mut block_perm_inv = vec![0usize; nb];
        if nb > 0 {
            let pattern =
                SymbolicSparseColMatRef::new_checked(nb, nb, &block_col_ptr, None, &block_rows);
            let mut mem = MemBuffer::new(amd::order_scratch::<usize>(nb, block_rows.len()));
            amd::order(
                &mut block_perm,
                &mut block_perm_inv,
                pattern,
                amd::Control::default(),
                MemStack::new(&mut mem),
            )
            .map_err(|e| LinearError::Symbolic(format!("{e:?}")))?;
        }
        let mut perm = Vec::with_capacity(n);
        for &b in &block_perm {
            perm.extend(h.offsets[b]..h.offsets[b] + h.dims[b]);
        }
        let mut perm_inv = vec![0usize; n];
        for (k, &p) in perm.iter().enumerate() {
            perm_inv[p] = k;
        }
        let pattern = SymbolicSparseColMatRef::new_checked(n, n, &col_ptr, None, &row_idx);
        let symbolic = factorize_symbolic_cholesky(
            pattern,
            Side::Lower,
            SymmetricOrdering::Custom(faer::perm::PermRef::new_checked(&perm, &perm_inv, n)),
            CholeskySymbolicParams {
                supernodal_flop_ratio_threshold: match method {
                    CholeskyMethod::Auto if n >= 3 * nb => SupernodalThreshold::FORCE_SUPERNODAL,
                    CholeskyMethod::Auto => SupernodalThreshold::AUTO,
                    CholeskyMethod::Simplicial => SupernodalThreshold::FORCE_SIMPLICIAL,
                    CholeskyMethod::Supernodal => SupernodalThreshold::FORCE_SUPERNODAL,
                },
                ..CholeskySymbolicParams::default()
            },
        )
        .map_err(|e| LinearError::Symbolic(format!("{e:?}")))?;
        let l_values = vec![0.0; symbolic.len_val()];
        let mem = MemBuffer::new(StackReq::any_of(&[
            symbolic.factorize_numeric_llt_scratch::<f64>(Par::Seq, Default::default()),
            symbolic.solve_in_place_scratch::<f64>(1, Par::Seq),
        ]));
        Ok(SparseCholesky {
            n,
            values: vec![0.0; row_idx.len()],
            col_ptr,
            row_idx,
            gather,
            diagonal,
            symbolic,
            l_values,
            mem,
        })
    }

    /// Numeric factorisation of `H + diag(d)`.
    pub(crate) fn factorize(
        &mut self,
        h: &BlockSymmetric,
        diag_add: &[f64],
    ) -> Result<(), LinearError> {
        for (v, &g) in self.values.iter_mut().zip(&self.gather) {
            *v = h.values[g];
        }
        for (&e, &d) in self.diagonal.iter().zip(diag_add) {
            self.values[e] += d;
        }
        // SAFETY: the pattern was validated by `new_checked` in `new` and is unchanged.
        let pattern = unsafe {
            SymbolicSparseColMatRef::new_unchecked(
                self.n,
                self.n,
                &self.col_ptr,
                None,
                &self.row_idx,
            )
        };
        let a = SparseColMatRef::new(pattern, &self.values);
        self.symbolic
            .factorize_numeric_llt(
                &mut self.l_values,
                a,
                Side::Lower,
                Default::default(),
                Par::Seq,
                MemStack::new(&mut self.mem),
                Default::default(),
            )
            .map(|_| ())
            .map_err(|_| LinearError::NotPositiveDefinite)
    }

    /// Solves `L·Lᵀ·x = rhs` in place with the last factorisation.
    pub(crate) fn solve_in_place(&mut self, rhs: &mut [f64]) {
        let llt = LltRef::new(&self.symbolic, &self.l_values);
        let n = self.n;
        llt.solve_in_place_with_conj(
            Conj::No,
            MatMut::from_column_major_slice_mut(rhs, n, 1),
            Par::Seq,
            MemStack::new(&mut self.mem),
        );
    }
}

impl LinearSolve for SparseCholesky {
    fn solve(
        &mut self,
        h: &BlockSymmetric,
        g: &[f64],
        diag_add: &[f64],
        delta: &mut [f64],
    ) -> Result<usize, LinearError> {
        self.factorize(h, diag_add)?;
        for (d, gi) in delta.iter_mut().zip(g) {
            *d = -gi;
        }
        self.solve_in_place(delta);
        Ok(1)
    }
}

/// Dense Cholesky, for small systems.
pub(crate) struct DenseCholesky;

impl LinearSolve for DenseCholesky {
    fn solve(
        &mut self,
        h: &BlockSymmetric,
        g: &[f64],
        diag_add: &[f64],
        delta: &mut [f64],
    ) -> Result<usize, LinearError> {
        let mut m = h.to_dense();
        for (i, d) in diag_add.iter().enumerate() {
            m[(i, i)] += d;
        }
        let chol = m.cholesky().ok_or(LinearError::NotPositiveDefinite)?;
        let rhs = nalgebra::DVector::from_iterator(g.len(), g.iter().map(|x| -x));
        let x = chol.solve(&rhs);
        delta.copy_from_slice(x.as_slice());
        Ok(1)
    }
}

/// Inverts the damped diagonal blocks of `h` (block-Jacobi preconditioner) into `out`
/// (column-major, at the block's diagonal value offsets relative to `h`'s layout).
pub(crate) fn invert_diagonal_blocks(
    h: &BlockSymmetric,
    diag_add: &[f64],
    out: &mut Vec<f64>,
    out_offsets: &mut Vec<usize>,
) -> Result<(), LinearError> {
    out.clear();
    out_offsets.clear();
    for j in 0..h.num_blocks() {
        let d = h.dims[j];
        let start = out.len();
        out_offsets.push(start);
        out.extend_from_slice(h.diagonal_block(j));
        let block = &mut out[start..start + d * d];
        for k in 0..d {
            block[k * d + k] += diag_add[h.offsets[j] + k];
        }
        if !invert_spd_in_place(block, d) {
            return Err(LinearError::NotPositiveDefinite);
        }
    }
    Ok(())
}

/// Conjugate gradients on `(H + diag(d))·δ = −g` with a block-Jacobi preconditioner
/// (thesis §3.3.6), stopped when `‖residual‖ ≤ tolerance·‖g‖` or after `max_iterations`.
pub(crate) struct Pcg {
    pub(crate) max_iterations: usize,
    pub(crate) tolerance: f64,
    b: Vec<f64>,
    preconditioner: Vec<f64>,
    preconditioner_offsets: Vec<usize>,
    r: Vec<f64>,
    z: Vec<f64>,
    p: Vec<f64>,
    q: Vec<f64>,
}

impl Pcg {
    pub(crate) fn new(max_iterations: usize, tolerance: f64) -> Self {
        Pcg {
            max_iterations,
            tolerance,
            b: Vec::new(),
            preconditioner: Vec::new(),
            preconditioner_offsets: Vec::new(),
            r: Vec::new(),
            z: Vec::new(),
            p: Vec::new(),
            q: Vec::new(),
        }
    }
}

/// `z = M⁻¹·r` for a block-diagonal `M⁻¹`.
pub(crate) fn apply_block_diagonal(
    h: &BlockSymmetric,
    inv: &[f64],
    inv_offsets: &[usize],
    r: &[f64],
    z: &mut [f64],
) {
    for j in 0..h.num_blocks() {
        let (o, d) = (h.offsets[j], h.dims[j]);
        let m = &inv[inv_offsets[j]..inv_offsets[j] + d * d];
        for row in 0..d {
            let mut acc = 0.0;
            for c in 0..d {
                acc += m[c * d + row] * r[o + c];
            }
            z[o + row] = acc;
        }
    }
}

/// Preconditioned conjugate gradients for `A·x = b` with `A` given as a product, `M⁻¹` as an
/// application; `x` starts at zero. Returns the iterations used.
#[allow(clippy::too_many_arguments)]
pub(crate) fn conjugate_gradients(
    mut apply_a: impl FnMut(&[f64], &mut [f64]),
    mut apply_m_inv: impl FnMut(&[f64], &mut [f64]),
    b: &[f64],
    x: &mut [f64],
    r: &mut Vec<f64>,
    z: &mut Vec<f64>,
    p: &mut Vec<f64>,
    q: &mut Vec<f64>,
    max_iterations: usize,
    tolerance: f64,
) -> usize {
    let n = b.len();
    for v in [&mut *r, &mut *z, &mut *p, &mut *q] {
        v.clear();
        v.resize(n, 0.0);
    }
    x.iter_mut().for_each(|v| *v = 0.0);
    r.copy_from_slice(b);
    let b_norm = b.iter().map(|v| v * v).sum::<f64>().sqrt();
    if b_norm == 0.0 {
        return 0;
    }
    apply_m_inv(r, z);
    p.copy_from_slice(z);
    let mut rz: f64 = r.iter().zip(z.iter()).map(|(a, b)| a * b).sum();
    for it in 1..=max_iterations {
        apply_a(p, q);
        let pq: f64 = p.iter().zip(q.iter()).map(|(a, b)| a * b).sum();
        if pq <= 0.0 {
            return it;
        }
        let alpha = rz / pq;
        for i in 0..n {
            x[i] += alpha * p[i];
            r[i] -= alpha * q[i];
        }
        let r_norm = r.iter().map(|v| v * v).sum::<f64>().sqrt();
        if r_norm <= tolerance * b_norm {
            return it;
        }
        apply_m_inv(r, z);
        let rz_new: f64 = r.iter().zip(z.iter()).map(|(a, b)| a * b).sum();
        let beta = rz_new / rz;
        rz = rz_new;
        for i in 0..n {
            p[i] = z[i] + beta * p[i];
        }
    }
    max_iterations
}

impl LinearSolve for Pcg {
    fn solve(
        &mut self,
        h: &BlockSymmetric,
        g: &[f64],
        diag_add: &[f64],
        delta: &mut [f64],
    ) -> Result<usize, LinearError> {
        invert_diagonal_blocks(
            h,
            diag_add,
            &mut self.preconditioner,
            &mut self.preconditioner_offsets,
        )?;
        self.b.clear();
        self.b.extend(g.iter().map(|x| -x));
        let (pre, pre_off) = (&self.preconditioner, &self.preconditioner_offsets);
        let iterations = conjugate_gradients(
            |x, y| {
                h.multiply(x, y);
                for i in 0..x.len() {
                    y[i] += diag_add[i] * x[i];
                }
            },
            |r, z| apply_block_diagonal(h, pre, pre_off, r, z),
            &self.b,
            delta,
            &mut self.r,
            &mut self.z,
            &mut self.p,
            &mut self.q,
            self.max_iterations,
            self.tolerance,
        );
        Ok(iterations)
    }
}
