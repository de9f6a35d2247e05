//! Solvers of the damped normal equations `(H + D)·δ = −g` (thesis §3.3.4–3.3.6).

use crate::block::{BlockSymmetric, invert_spd_in_place};
use faer::dyn_stack::{MemBuffer, MemStack, StackReq};
use faer::sparse::linalg::cholesky::{
    CholeskySymbolicParams, LltRef, SymbolicCholesky, SymmetricOrdering,
    factorize_symbolic_cholesky,
};
use faer::sparse::linalg::{SupernodalThreshold, amd};
use faer::sparse::{SparseColMatRef, SymbolicSparseColMatRef};
use faer::{Conj, MatMut, Par, Side};

/// How the sparse Cholesky factorisation is organised (faer offers both).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum CholeskyMethod {
    /// Supernodal when the variables are blocks of dimension ≥ 3 on average (poses, points:
    /// every column then sits in a dense block, so supernodes are at least that wide and the
    /// dense kernels pay off even on very sparse graphs), otherwise faer's own choice from the
    /// flop count per non-zero of the factor. faer's rule alone picks the simplicial variant
    /// on sparse pose graphs such as parking-garage, where the supernodal one executes 3.4×
    /// fewer instructions (`bench/README.md`).
    #[default]
    Auto,
    /// Always simplicial (up-looking, scalar).
    Simplicial,
    /// Always supernodal (dense panels of columns with the same pattern; our block rows give
    /// supernodes of at least the variable dimension).
    Supernodal,
}

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

/// Supernodal sparse Cholesky by faer on the scalar lower triangle of `P·H·Pᵀ`, with a
/// fill-reducing AMD ordering `P` computed on the block graph (cheaper than on the scalar graph
/// and as good, since blocks are dense) and the symbolic factorisation computed once per
/// sparsity pattern and reused at every iteration (thesis §3.3.6).
///
/// The permuted lower triangle is gathered directly from the block matrix (each entry's source
/// is precomputed, transposed where the ordering swaps a block above the diagonal), so faer
/// factors it as is, without permuting the matrix again at every factorisation.
pub(crate) struct SparseCholesky {
    n: usize,
    col_ptr: Vec<usize>,
    row_idx: Vec<usize>,
    values: Vec<f64>,
    /// For each scalar entry of the permuted lower triangle, its index in the block matrix's
    /// values.
    gather: Vec<usize>,
    /// For each diagonal element of the permuted matrix, in order: its entry in `values` and
    /// its unpermuted scalar index (where `diag_add` holds it).
    diagonal: Vec<(usize, usize)>,
    /// Scalar permutation: row `k` of `P·H·Pᵀ` is row `perm[k]` of `H`.
    perm: Vec<usize>,
    /// Right-hand side in permuted order.
    permuted: Vec<f64>,
    symbolic: SymbolicCholesky<usize>,
    l_values: Vec<f64>,
    mem: MemBuffer,
}

impl SparseCholesky {
    /// Analyses the pattern of `h`.
    pub(crate) fn new(h: &BlockSymmetric, method: CholeskyMethod) -> Result<Self, LinearError> {
        let n = h.dim();
        let nb = h.num_blocks();
        // AMD on the block graph.
        let mut block_perm = vec![0usize; nb];
        let mut block_perm_inv = vec![0usize; nb];
        if nb > 0 {
            let block_col_ptr: Vec<usize> = h.col_ptr.clone();
            let block_rows: Vec<usize> = h.rows.iter().map(|&r| r as usize).collect();
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
        // Scalar offsets of the permuted blocks, and the scalar permutation.
        let mut new_offsets = Vec::with_capacity(nb + 1);
        new_offsets.push(0);
        let mut perm = Vec::with_capacity(n);
        for &b in &block_perm {
            perm.extend(h.offsets[b]..h.offsets[b] + h.dims[b]);
            new_offsets.push(perm.len());
        }
        // The stored blocks of H by permuted lower-triangle column (counting sort): permuted
        // row block, stored block, and whether the stored block is the transpose of the one
        // needed. Sizes are counted first so that nothing is reallocated while filling.
        let mut column_ptr = vec![0usize; nb + 1];
        let mut nnz = 0usize;
        for j in 0..nb {
            for s in h.col_ptr[j]..h.col_ptr[j + 1] {
                let i = h.rows[s] as usize;
                let (pi, pj) = (block_perm_inv[i], block_perm_inv[j]);
                column_ptr[pi.min(pj) + 1] += 1;
                nnz += if i == j {
                    h.dims[i] * (h.dims[i] + 1) / 2
                } else {
                    h.dims[i] * h.dims[j]
                };
            }
        }
        for k in 0..nb {
            column_ptr[k + 1] += column_ptr[k];
        }
        let mut column_fill = column_ptr.clone();
        let mut entries = vec![(0usize, 0usize, false); h.num_stored_blocks()];
        for j in 0..nb {
            for s in h.col_ptr[j]..h.col_ptr[j + 1] {
                let i = h.rows[s] as usize;
                let (pi, pj) = (block_perm_inv[i], block_perm_inv[j]);
                let (col, entry) = if pi >= pj {
                    (pj, (pi, s, false))
                } else {
                    (pi, (pj, s, true))
                };
                entries[column_fill[col]] = entry;
                column_fill[col] += 1;
            }
        }
        let mut col_ptr = Vec::with_capacity(n + 1);
        let mut row_idx = Vec::with_capacity(nnz);
        let mut gather = Vec::with_capacity(nnz);
        let mut diagonal = Vec::with_capacity(n);
        col_ptr.push(0);
        for pj in 0..nb {
            let column = &mut entries[column_ptr[pj]..column_ptr[pj + 1]];
            column.sort_unstable_by_key(|&(pi, _, _)| pi);
            let dj = h.dims[block_perm[pj]];
            for c in 0..dj {
                for &(pi, s, transposed) in column.iter() {
                    let di = h.dims[block_perm[pi]];
                    let first = if pi == pj { c } else { 0 };
                    let (o_row, o_val) = (new_offsets[pi], h.value_offsets[s]);
                    if pi == pj {
                        diagonal.push((row_idx.len(), perm[new_offsets[pj] + c]));
                    }
                    // Entry (r, c) of the permuted block: H's stored block is di×dj
                    // (column-major) as is, or dj×di when it is the transpose.
                    row_idx.extend(o_row + first..o_row + di);
                    if transposed {
                        gather.extend((first..di).map(|r| o_val + r * dj + c));
                    } else {
                        gather.extend((first..di).map(|r| o_val + c * di + r));
                    }
                }
                col_ptr.push(row_idx.len());
            }
        }
        // faer's symbolic analysis without an ordering reads the upper triangle: give it the
        // transposed pattern (the numeric factorisation then takes the lower one as is).
        let mut upper_col_ptr = vec![0usize; n + 1];
        for &r in &row_idx {
            upper_col_ptr[r + 1] += 1;
        }
        for k in 0..n {
            upper_col_ptr[k + 1] += upper_col_ptr[k];
        }
        let mut upper_row_idx = vec![0usize; row_idx.len()];
        let mut fill = upper_col_ptr.clone();
        for c in 0..n {
            for &r in &row_idx[col_ptr[c]..col_ptr[c + 1]] {
                upper_row_idx[fill[r]] = c;
                fill[r] += 1;
            }
        }
        // Validates the lower pattern that `factorize` passes unchecked.
        let _ = SymbolicSparseColMatRef::new_checked(n, n, &col_ptr, None, &row_idx);
        let upper =
            SymbolicSparseColMatRef::new_checked(n, n, &upper_col_ptr, None, &upper_row_idx);
        let symbolic = factorize_symbolic_cholesky(
            upper,
            Side::Upper,
            SymmetricOrdering::Identity,
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
            perm,
            permuted: vec![0.0; n],
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
        for &(e, k) in &self.diagonal {
            self.values[e] += diag_add[k];
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

    /// Solves `(H + diag(d))·x = rhs` in place with the last factorisation (`rhs` and `x` in
    /// the unpermuted order).
    pub(crate) fn solve_in_place(&mut self, rhs: &mut [f64]) {
        for (p, &k) in self.permuted.iter_mut().zip(&self.perm) {
            *p = rhs[k];
        }
        let llt = LltRef::new(&self.symbolic, &self.l_values);
        let n = self.n;
        llt.solve_in_place_with_conj(
            Conj::No,
            MatMut::from_column_major_slice_mut(&mut self.permuted, n, 1),
            Par::Seq,
            MemStack::new(&mut self.mem),
        );
        for (p, &k) in self.permuted.iter().zip(&self.perm) {
            rhs[k] = *p;
        }
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

#[cfg(test)]
mod tests {
    use super::*;

    /// A block-sparse SPD matrix with mixed block sizes and a pattern whose fill-reducing
    /// ordering moves blocks across the diagonal: the pre-permuted factorisation solves
    /// `(H + diag(d))·x = b` like a dense Cholesky, with every organisation.
    #[test]
    fn permuted_sparse_cholesky_matches_the_dense_solve() {
        let dims = vec![3, 1, 2, 3, 2, 1, 3, 2];
        let nb = dims.len();
        // A star (block 0 linked to all) plus a chain: AMD orders the hub last.
        let mut below: Vec<Vec<u32>> = vec![Vec::new(); nb];
        for j in 1..nb {
            below[0].push(j as u32);
            if j + 1 < nb {
                below[j].push(j as u32 + 1);
            }
        }
        let mut h = BlockSymmetric::from_pattern(dims, below);
        for (k, v) in h.values.iter_mut().enumerate() {
            *v = (k as f64 * 0.71).sin();
        }
        // Symmetric diagonal blocks, made dominant so the whole matrix is SPD.
        let n = h.dim();
        for j in 0..nb {
            let (o, d) = (h.value_offsets[h.col_ptr[j]], h.dims[j]);
            for c in 0..d {
                for r in 0..c {
                    h.values[o + c * d + r] = h.values[o + r * d + c];
                }
                h.values[o + c * d + c] = 2.0 * n as f64;
            }
        }
        let diag_add: Vec<f64> = (0..n).map(|i| 0.1 * i as f64).collect();
        let b: Vec<f64> = (0..n).map(|i| (i as f64 * 1.3).cos()).collect();
        let mut dense = h.to_dense();
        for i in 0..n {
            dense[(i, i)] += diag_add[i];
        }
        let expected = dense
            .cholesky()
            .unwrap()
            .solve(&nalgebra::DVector::from_column_slice(&b));
        for method in [
            CholeskyMethod::Auto,
            CholeskyMethod::Simplicial,
            CholeskyMethod::Supernodal,
        ] {
            let mut chol = SparseCholesky::new(&h, method).unwrap();
            chol.factorize(&h, &diag_add).unwrap();
            let mut x = b.clone();
            chol.solve_in_place(&mut x);
            for i in 0..n {
                assert!((x[i] - expected[i]).abs() < 1e-12, "{method:?} entry {i}");
            }
        }
    }
}
