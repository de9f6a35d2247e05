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
                // y_i += B·x_j
                for c in 0..dj {
                    let xc = x[oj + c];
                    let col = &b[c * di..(c + 1) * di];
                    for r in 0..di {
                        y[oi + r] += col[r] * xc;
                    }
                }
                if i != j {
                    // y_j += Bᵀ·x_i
                    for c in 0..dj {
                        let col = &b[c * di..(c + 1) * di];
                        let mut acc = 0.0;
                        for r in 0..di {
                            acc += col[r] * x[oi + r];
                        }
                        y[oj + c] += acc;
                    }
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
