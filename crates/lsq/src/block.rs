//! Block-sparse symmetric matrices: the normal equations `H·δ = −g` are assembled block by
//! block (thesis §3.3.4) in a block-compressed-column layout holding the lower triangle.

/// The pattern and values of a symmetric block-sparse matrix, lower triangle stored by block
/// columns. In every block column the diagonal block comes first, then the blocks below it in
/// increasing row order; each block is dense and column-major.
#[derive(Clone, Debug, Default)]
pub struct BlockSymmetric {
    /// Size of each block row/column.
    pub(crate) dims: Vec<usize>,
    /// Scalar offset of each block row/column (`len = blocks + 1`).
    pub(crate) offsets: Vec<usize>,
    /// Start of each block column in `rows`/`value_offsets` (`len = blocks + 1`).
    pub(crate) col_ptr: Vec<usize>,
    /// Block row of each stored block.
    pub(crate) rows: Vec<u32>,
    /// Offset of each stored block in `values`.
    pub(crate) value_offsets: Vec<usize>,
    /// All block entries.
    pub(crate) values: Vec<f64>,
}

impl BlockSymmetric {
    /// A matrix with the given block sizes and, for each block column `j`, the block rows
    /// `i > j` below the diagonal (any order, duplicates allowed). Values are zero.
    pub(crate) fn from_pattern(dims: Vec<usize>, mut below: Vec<Vec<u32>>) -> Self {
        let n = dims.len();
        let mut offsets = Vec::with_capacity(n + 1);
        offsets.push(0);
        for d in &dims {
            offsets.push(offsets.last().unwrap() + d);
        }
        let mut col_ptr = Vec::with_capacity(n + 1);
        col_ptr.push(0);
        let mut rows = Vec::new();
        let mut value_offsets = Vec::new();
        let mut total = 0;
        for (j, col) in below.iter_mut().enumerate() {
            col.sort_unstable();
            col.dedup();
            debug_assert!(col.iter().all(|&i| i as usize > j));
            rows.push(j as u32);
            value_offsets.push(total);
            total += dims[j] * dims[j];
            for &i in col.iter() {
                rows.push(i);
                value_offsets.push(total);
                total += dims[i as usize] * dims[j];
            }
            col_ptr.push(rows.len());
        }
        BlockSymmetric {
            dims,
            offsets,
            col_ptr,
            rows,
            value_offsets,
            values: vec![0.0; total],
        }
    }

    /// Number of block rows/columns.
    pub fn num_blocks(&self) -> usize {
        self.dims.len()
    }

    /// Scalar dimension.
    pub fn dim(&self) -> usize {
        *self.offsets.last().unwrap_or(&0)
    }

    /// Number of stored blocks (lower triangle including the diagonal).
    pub fn num_stored_blocks(&self) -> usize {
        self.rows.len()
    }

    /// Index of the stored block `(i, j)`, `i ≥ j`, if it is in the pattern.
    pub(crate) fn find(&self, i: usize, j: usize) -> Option<usize> {
        let range = self.col_ptr[j]..self.col_ptr[j + 1];
        if i == j {
            return Some(range.start);
        }
        let col = &self.rows[range.start + 1..range.end];
        col.binary_search(&(i as u32))
            .ok()
            .map(|p| range.start + 1 + p)
    }

    /// The contiguous range of `values` holding block column `j` (its blocks are stored one
    /// after another), so that parallel tasks can own whole columns.
    pub(crate) fn column_values(&self, j: usize) -> std::ops::Range<usize> {
        let start = self.value_offsets[self.col_ptr[j]];
        let end = if j + 1 < self.num_blocks() {
            self.value_offsets[self.col_ptr[j + 1]]
        } else {
            self.values.len()
        };
        start..end
    }

    /// The diagonal block of column `j` (column-major, `d×d`).
    pub(crate) fn diagonal_block(&self, j: usize) -> &[f64] {
        let o = self.value_offsets[self.col_ptr[j]];
        &self.values[o..o + self.dims[j] * self.dims[j]]
    }

    /// `y = H·x` using both triangles.
    pub fn multiply(&self, x: &[f64], y: &mut [f64]) {
        y.iter_mut().for_each(|v| *v = 0.0);
        for j in 0..self.num_blocks() {
            let (oj, dj) = (self.offsets[j], self.dims[j]);
            for s in self.col_ptr[j]..self.col_ptr[j + 1] {
                let i = self.rows[s] as usize;
                let (oi, di) = (self.offsets[i], self.dims[i]);
                let b = &self.values[self.value_offsets[s]..self.value_offsets[s] + di * dj];
                // y_i += B·x_j, and for off-diagonal blocks y_j += Bᵀ·x_i.
                crate::kernels::add_a_x(&mut y[oi..oi + di], b, &x[oj..oj + dj], di, dj, 1.0);
                if i != j {
                    crate::kernels::add_at_x(&mut y[oj..oj + dj], b, &x[oi..oi + di], di, dj, 1.0);
                }
            }
        }
    }

    /// The dense symmetric matrix (for small systems and tests).
    pub fn to_dense(&self) -> nalgebra::DMatrix<f64> {
        let n = self.dim();
        let mut m = nalgebra::DMatrix::zeros(n, n);
        for j in 0..self.num_blocks() {
            let (oj, dj) = (self.offsets[j], self.dims[j]);
            for s in self.col_ptr[j]..self.col_ptr[j + 1] {
                let i = self.rows[s] as usize;
                let (oi, di) = (self.offsets[i], self.dims[i]);
                let b = &self.values[self.value_offsets[s]..];
                for c in 0..dj {
                    for r in 0..di {
                        let v = b[c * di + r];
                        m[(oi + r, oj + c)] = v;
                        m[(oj + c, oi + r)] = v;
                    }
                }
            }
        }
        m
    }
}

/// Largest block size for the stack-based small-matrix routines.
pub(crate) const MAX_BLOCK: usize = 16;

/// Inverts a symmetric positive-definite `d×d` matrix (column-major, `d ≤ MAX_BLOCK`) in place
/// by Cholesky factorisation, without heap allocation. Returns `false` if it is not positive
/// definite.
pub(crate) fn invert_spd_in_place(a: &mut [f64], d: usize) -> bool {
    assert!(d <= MAX_BLOCK, "block of size {d} exceeds {MAX_BLOCK}");
    // L (lower, column-major in l) with A = L·Lᵀ.
    let mut l = [0.0f64; MAX_BLOCK * MAX_BLOCK];
    for j in 0..d {
        let mut diag = a[j * d + j];
        for k in 0..j {
            diag -= l[k * d + j] * l[k * d + j];
        }
        if !(diag > 0.0 && diag.is_finite()) {
            return false;
        }
        let ljj = diag.sqrt();
        l[j * d + j] = ljj;
        for i in j + 1..d {
            let mut v = a[j * d + i];
            for k in 0..j {
                v -= l[k * d + i] * l[k * d + j];
            }
            l[j * d + i] = v / ljj;
        }
    }
    // A⁻¹ column by column: solve L·y = e_c, then Lᵀ·x = y.
    for c in 0..d {
        let mut y = [0.0f64; MAX_BLOCK];
        for i in 0..d {
            let mut v = if i == c { 1.0 } else { 0.0 };
            for k in 0..i {
                v -= l[k * d + i] * y[k];
            }
            y[i] = v / l[i * d + i];
        }
        for i in (0..d).rev() {
            let mut v = y[i];
            for k in i + 1..d {
                v -= l[i * d + k] * a[c * d + k];
            }
            a[c * d + i] = v / l[i * d + i];
        }
    }
    true
}

/// A pointer that may be shared across rayon tasks which write provably disjoint ranges.
#[derive(Clone, Copy)]
pub(crate) struct DisjointMut(*mut f64);

// SAFETY: only used to hand out non-overlapping sub-slices to parallel tasks; every user
// documents why its ranges are disjoint.
unsafe impl Send for DisjointMut {}
unsafe impl Sync for DisjointMut {}

impl DisjointMut {
    pub(crate) fn new(slice: &mut [f64]) -> Self {
        DisjointMut(slice.as_mut_ptr())
    }

    /// # Safety
    /// `start..start + len` must lie inside the slice this was made from, and no other task
    /// may access the range at the same time.
    #[inline]
    pub(crate) unsafe fn slice<'a>(self, start: usize, len: usize) -> &'a mut [f64] {
        unsafe { std::slice::from_raw_parts_mut(self.0.add(start), len) }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn spd_inverse_matches_nalgebra() {
        for d in 1..=9 {
            let b = nalgebra::DMatrix::<f64>::from_fn(d, d, |i, j| {
                ((i * 7 + j * 3) as f64 * 0.61).sin()
            });
            let m = &b * b.transpose() + nalgebra::DMatrix::identity(d, d) * 0.5;
            let mut a = m.as_slice().to_vec();
            assert!(invert_spd_in_place(&mut a, d));
            let inv = m.clone().try_inverse().unwrap();
            for (x, y) in a.iter().zip(inv.as_slice()) {
                assert!((x - y).abs() < 1e-10 * (1.0 + y.abs()));
            }
        }
        let mut indefinite = vec![1.0, 2.0, 2.0, 1.0];
        assert!(!invert_spd_in_place(&mut indefinite, 2));
    }

    #[test]
    fn pattern_lookup_multiply_and_dense_agree() {
        let mut h = BlockSymmetric::from_pattern(vec![2, 3, 1], vec![vec![2, 1], vec![], vec![]]);
        assert_eq!(h.num_stored_blocks(), 5);
        assert!(h.find(1, 0).is_some() && h.find(2, 0).is_some() && h.find(2, 1).is_none());
        for (k, v) in h.values.iter_mut().enumerate() {
            *v = (k as f64 * 0.37).sin();
        }
        // Make diagonal blocks symmetric.
        let dense = {
            let mut d = h.to_dense();
            d = (&d + d.transpose()) * 0.5;
            d
        };
        let mut h_sym = h.clone();
        for j in 0..3 {
            let o = h_sym.value_offsets[h_sym.col_ptr[j]];
            let dj = h_sym.dims[j];
            let oj = h_sym.offsets[j];
            for c in 0..dj {
                for r in 0..dj {
                    h_sym.values[o + c * dj + r] = dense[(oj + r, oj + c)];
                }
            }
        }
        let x: Vec<f64> = (0..6).map(|i| i as f64 - 2.5).collect();
        let mut y = vec![0.0; 6];
        h_sym.multiply(&x, &mut y);
        let expected = h_sym.to_dense() * nalgebra::DVector::from_vec(x);
        for i in 0..6 {
            assert!((y[i] - expected[i]).abs() < 1e-14);
        }
    }
}
