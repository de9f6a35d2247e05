//! The Schur complement (thesis §3.3.5): variables whose Hessian block is block-diagonal
//! (points in bundle adjustment) are eliminated,
//!
//! `(H_cc − H_cp·H_pp⁻¹·H_pc)·δ_c = −g_c + H_cp·H_pp⁻¹·g_p`,   `δ_p = H_pp⁻¹·(−g_p − H_pc·δ_c)`,
//!
//! leaving the reduced ("camera") system, solved by sparse Cholesky after forming it
//! (explicit Schur) or by conjugate gradients without forming it (implicit Schur).
//! Blocks `0..num_reduced` are kept, `num_reduced..` eliminated.

use crate::block::{BlockSymmetric, DisjointMut, invert_spd_in_place};
use crate::kernels;
use crate::linear::{
    CholeskyMethod, LinearError, LinearSolve, SparseCholesky, apply_block_diagonal,
    conjugate_gradients,
};
use rayon::prelude::*;

/// The elimination structure, shared by both variants.
struct Elimination {
    num_reduced: usize,
    /// Per eliminated block `p` (numbered from 0): its observations `(kept block c, index of
    /// the stored block (p, c) of H)`.
    obs_ptr: Vec<usize>,
    obs: Vec<(u32, usize)>,
    /// `H_pp⁻¹` (damped) per eliminated block, column-major.
    hpp_inv: Vec<f64>,
    hpp_inv_offsets: Vec<usize>,
    /// `w_p = H_pp⁻¹·g_p`, at the eliminated blocks' scalar offsets minus the reduced size.
    w: Vec<f64>,
}

impl Elimination {
    fn new(h: &BlockSymmetric, num_reduced: usize) -> Self {
        let nb = h.num_blocks();
        let np = nb - num_reduced;
        let mut count = vec![0usize; np + 1];
        for c in 0..num_reduced {
            for s in h.col_ptr[c] + 1..h.col_ptr[c + 1] {
                let p = h.rows[s] as usize;
                if p >= num_reduced {
                    count[p - num_reduced + 1] += 1;
                }
            }
        }
        for i in 0..np {
            count[i + 1] += count[i];
        }
        let obs_ptr = count.clone();
        let mut fill = count;
        let mut obs = vec![(0u32, 0usize); *obs_ptr.last().unwrap_or(&0)];
        for c in 0..num_reduced {
            for s in h.col_ptr[c] + 1..h.col_ptr[c + 1] {
                let p = h.rows[s] as usize;
                if p >= num_reduced {
                    obs[fill[p - num_reduced]] = (c as u32, s);
                    fill[p - num_reduced] += 1;
                }
            }
        }
        let mut hpp_inv_offsets = Vec::with_capacity(np);
        let mut total = 0;
        for p in num_reduced..nb {
            hpp_inv_offsets.push(total);
            total += h.dims[p] * h.dims[p];
        }
        let reduced_dim = h.offsets[num_reduced];
        Elimination {
            num_reduced,
            obs_ptr,
            obs,
            hpp_inv: vec![0.0; total],
            hpp_inv_offsets,
            w: vec![0.0; h.dim() - reduced_dim],
        }
    }

    /// Inverts every damped `H_pp` and computes `w_p = H_pp⁻¹·g_p`, parallel over points.
    fn invert_points(
        &mut self,
        h: &BlockSymmetric,
        g: &[f64],
        diag_add: &[f64],
    ) -> Result<(), LinearError> {
        let nr = self.num_reduced;
        let reduced_dim = h.offsets[nr];
        let inv_ptr = DisjointMut::new(&mut self.hpp_inv);
        let w_ptr = DisjointMut::new(&mut self.w);
        let offsets = &self.hpp_inv_offsets;
        (nr..h.num_blocks())
            .into_par_iter()
            .with_min_len(256)
            .try_for_each(|b| {
                let d = h.dims[b];
                let o = h.offsets[b];
                // SAFETY: point b owns hpp_inv[offsets[b − nr]..+d²] and w[o − reduced_dim..+d].
                let inv = unsafe { inv_ptr.slice(offsets[b - nr], d * d) };
                inv.copy_from_slice(h.diagonal_block(b));
                for k in 0..d {
                    inv[k * d + k] += diag_add[o + k];
                }
                if !invert_spd_in_place(inv, d) {
                    return Err(LinearError::NotPositiveDefinite);
                }
                let w = unsafe { w_ptr.slice(o - reduced_dim, d) };
                for r in 0..d {
                    w[r] = (0..d).map(|c| inv[c * d + r] * g[o + c]).sum();
                }
                Ok(())
            })
    }

    /// `rhs_c = −g_c + Σ_p H_pcᵀ·w_p`, parallel over kept blocks.
    fn reduced_rhs(&self, h: &BlockSymmetric, g: &[f64], rhs: &mut [f64]) {
        let nr = self.num_reduced;
        let reduced_dim = h.offsets[nr];
        let rhs_ptr = DisjointMut::new(rhs);
        (0..nr).into_par_iter().with_min_len(16).for_each(|c| {
            let (oc, dc) = (h.offsets[c], h.dims[c]);
            // SAFETY: block c owns rhs[oc..oc+dc].
            let out = unsafe { rhs_ptr.slice(oc, dc) };
            for k in 0..dc {
                out[k] = -g[oc + k];
            }
            for s in h.col_ptr[c] + 1..h.col_ptr[c + 1] {
                let p = h.rows[s] as usize;
                if p < nr {
                    continue;
                }
                let dp = h.dims[p];
                let b = &h.values[h.value_offsets[s]..h.value_offsets[s] + dp * dc];
                let w = &self.w[h.offsets[p] - reduced_dim..h.offsets[p] - reduced_dim + dp];
                kernels::add_at_x(out, b, w, dp, dc, 1.0);
            }
        });
    }

    /// `δ_p = −w_p − H_pp⁻¹·Σ_c H_pc·δ_c`, parallel over points.
    fn back_substitute(&self, h: &BlockSymmetric, delta: &mut [f64]) {
        let nr = self.num_reduced;
        let reduced_dim = h.offsets[nr];
        let (reduced, eliminated) = delta.split_at_mut(reduced_dim);
        let reduced: &[f64] = reduced;
        let e_ptr = DisjointMut::new(eliminated);
        (nr..h.num_blocks())
            .into_par_iter()
            .with_min_len(256)
            .for_each(|b| {
                let (o, d) = (h.offsets[b] - reduced_dim, h.dims[b]);
                let mut t = [0.0f64; 16];
                let t = &mut t[..d];
                for &(c, s) in &self.obs[self.obs_ptr[b - nr]..self.obs_ptr[b - nr + 1]] {
                    let c = c as usize;
                    let (oc, dc) = (h.offsets[c], h.dims[c]);
                    let blk = &h.values[h.value_offsets[s]..h.value_offsets[s] + d * dc];
                    kernels::add_a_x(t, blk, &reduced[oc..oc + dc], d, dc, 1.0);
                }
                let inv = &self.hpp_inv
                    [self.hpp_inv_offsets[b - nr]..self.hpp_inv_offsets[b - nr] + d * d];
                // SAFETY: point b owns delta_p[o..o+d].
                let out = unsafe { e_ptr.slice(o, d) };
                for r in 0..d {
                    out[r] = -self.w[o + r];
                }
                kernels::add_a_x(out, inv, t, d, d, -1.0);
            });
    }
}

/// Explicit Schur complement: forms the reduced system `S` and solves it by sparse Cholesky.
pub(crate) struct SchurCholesky {
    elim: Elimination,
    /// The reduced system's pattern and values.
    s: BlockSymmetric,
    /// For each stored block of `S`, the stored block of `H` it starts from (`H_cc` part).
    s_from_h: Vec<Option<usize>>,
    /// For each stored block `(c1, c2)` of `S`: pairs of stored blocks `((p, c1), (p, c2))`
    /// of `H` over the points `p` seen by both.
    contrib_ptr: Vec<usize>,
    contrib: Vec<(usize, usize)>,
    /// `E_pc = H_pp⁻¹·H_pc`, at the value offsets of the blocks `(p, c)` of `H`.
    e: Vec<f64>,
    cholesky: SparseCholesky,
    zeros: Vec<f64>,
    rhs: Vec<f64>,
}

impl SchurCholesky {
    pub(crate) fn new(
        h: &BlockSymmetric,
        num_reduced: usize,
        method: CholeskyMethod,
    ) -> Result<Self, LinearError> {
        let elim = Elimination::new(h, num_reduced);
        let nr = num_reduced;
        // Pattern of S: H_cc plus every pair of kept blocks sharing an eliminated one.
        let mut below: Vec<Vec<u32>> = vec![Vec::new(); nr];
        for c in 0..nr {
            for s in h.col_ptr[c] + 1..h.col_ptr[c + 1] {
                if (h.rows[s] as usize) < nr {
                    below[c].push(h.rows[s]);
                }
            }
        }
        let np = h.num_blocks() - nr;
        for p in 0..np {
            let obs = &elim.obs[elim.obs_ptr[p]..elim.obs_ptr[p + 1]];
            for &(c1, _) in obs {
                for &(c2, _) in obs {
                    if c1 > c2 {
                        below[c2 as usize].push(c1);
                    }
                }
            }
        }
        let s = BlockSymmetric::from_pattern(h.dims[..nr].to_vec(), below);
        let s_from_h: Vec<Option<usize>> = (0..nr)
            .flat_map(|j| (s.col_ptr[j]..s.col_ptr[j + 1]).map(move |k| (k, j)))
            .map(|(k, j)| h.find(s.rows[k] as usize, j))
            .collect();
        let mut count = vec![0usize; s.num_stored_blocks() + 1];
        let mut entries = Vec::new();
        for p in 0..np {
            let obs = &elim.obs[elim.obs_ptr[p]..elim.obs_ptr[p + 1]];
            for &(c1, s1) in obs {
                for &(c2, s2) in obs {
                    if c1 >= c2 {
                        let k = s.find(c1 as usize, c2 as usize).expect("pattern of S");
                        count[k + 1] += 1;
                        entries.push((k, (s1, s2)));
                    }
                }
            }
        }
        for i in 0..s.num_stored_blocks() {
            count[i + 1] += count[i];
        }
        let contrib_ptr = count.clone();
        let mut fill = count;
        let mut contrib = vec![(0usize, 0usize); entries.len()];
        for (k, pair) in entries {
            contrib[fill[k]] = pair;
            fill[k] += 1;
        }
        let cholesky = SparseCholesky::new(&s, method)?;
        Ok(SchurCholesky {
            zeros: vec![0.0; s.dim()],
            rhs: vec![0.0; s.dim()],
            e: vec![0.0; h.values.len()],
            elim,
            s,
            s_from_h,
            contrib_ptr,
            contrib,
            cholesky,
        })
    }
}

impl LinearSolve for SchurCholesky {
    fn solve(
        &mut self,
        h: &BlockSymmetric,
        g: &[f64],
        diag_add: &[f64],
        delta: &mut [f64],
    ) -> Result<usize, LinearError> {
        let nr = self.elim.num_reduced;
        self.elim.invert_points(h, g, diag_add)?;
        // E_pc = H_pp⁻¹·H_pc for every observation, parallel over points.
        {
            let e_ptr = DisjointMut::new(&mut self.e);
            let elim = &self.elim;
            (nr..h.num_blocks())
                .into_par_iter()
                .with_min_len(256)
                .for_each(|b| {
                    let dp = h.dims[b];
                    let inv = &elim.hpp_inv
                        [elim.hpp_inv_offsets[b - nr]..elim.hpp_inv_offsets[b - nr] + dp * dp];
                    for &(c, s) in &elim.obs[elim.obs_ptr[b - nr]..elim.obs_ptr[b - nr + 1]] {
                        let dc = h.dims[c as usize];
                        let o = h.value_offsets[s];
                        let src = &h.values[o..o + dp * dc];
                        // SAFETY: the block (p, c) of H belongs to point p alone.
                        let dst = unsafe { e_ptr.slice(o, dp * dc) };
                        kernels::square_times(dst, inv, src, dp, dc);
                    }
                });
        }
        // S = H_cc + D_c − Σ_p H_pc1ᵀ·E_pc2, parallel over block columns of S.
        {
            let s_ptr = DisjointMut::new(&mut self.s.values);
            let s: &BlockSymmetric = &self.s;
            let (col_ptr, rows, vo, dims, offsets) =
                (&s.col_ptr, &s.rows, &s.value_offsets, &s.dims, &s.offsets);
            let (s_from_h, cp, contrib, e) =
                (&self.s_from_h, &self.contrib_ptr, &self.contrib, &self.e);
            (0..nr).into_par_iter().with_min_len(4).for_each(|j| {
                let dj = dims[j];
                let range = s.column_values(j);
                let start = range.start;
                // SAFETY: block column j of S owns its contiguous value range.
                let col_vals = unsafe { s_ptr.slice(start, range.len()) };
                for k in col_ptr[j]..col_ptr[j + 1] {
                    let i = rows[k] as usize;
                    let di = dims[i];
                    let o = vo[k] - start;
                    let block = &mut col_vals[o..o + di * dj];
                    match s_from_h[k] {
                        Some(hk) => block.copy_from_slice(
                            &h.values[h.value_offsets[hk]..h.value_offsets[hk] + di * dj],
                        ),
                        None => block.iter_mut().for_each(|x| *x = 0.0),
                    }
                    if i == j {
                        for t in 0..dj {
                            block[t * dj + t] += diag_add[offsets[j] + t];
                        }
                    }
                    for &(s1, s2) in &contrib[cp[k]..cp[k + 1]] {
                        let dp = h.dims[h.rows[s1] as usize];
                        let a = &h.values[h.value_offsets[s1]..h.value_offsets[s1] + dp * di];
                        let b = &e[h.value_offsets[s2]..h.value_offsets[s2] + dp * dj];
                        kernels::add_at_b(block, a, b, dp, di, dj, -1.0);
                    }
                }
            });
        }
        self.elim.reduced_rhs(h, g, &mut self.rhs);
        self.cholesky.factorize(&self.s, &self.zeros)?;
        self.cholesky.solve_in_place(&mut self.rhs);
        let reduced_dim = h.offsets[nr];
        delta[..reduced_dim].copy_from_slice(&self.rhs);
        self.elim.back_substitute(h, delta);
        Ok(1)
    }
}

/// Implicit Schur complement: conjugate gradients on the reduced system using only products
/// `S·x = (H_cc + D_c)·x − H_cp·H_pp⁻¹·(H_pc·x)`, preconditioned by the inverse block diagonal
/// of `S` (Schur-Jacobi).
pub(crate) struct SchurPcg {
    elim: Elimination,
    max_iterations: usize,
    tolerance: f64,
    preconditioner: Vec<f64>,
    preconditioner_offsets: Vec<usize>,
    reduced: BlockSymmetric,
    zeros: Vec<f64>,
    /// Per-chunk accumulators of the implicit product (reduced dimension each).
    partial: Vec<Vec<f64>>,
    rhs: Vec<f64>,
    x: Vec<f64>,
    r: Vec<f64>,
    z: Vec<f64>,
    p: Vec<f64>,
    q: Vec<f64>,
}

impl SchurPcg {
    pub(crate) fn new(
        h: &BlockSymmetric,
        num_reduced: usize,
        max_iterations: usize,
        tolerance: f64,
    ) -> Self {
        let elim = Elimination::new(h, num_reduced);
        let reduced = BlockSymmetric::from_pattern(
            h.dims[..num_reduced].to_vec(),
            vec![Vec::new(); num_reduced],
        );
        SchurPcg {
            partial: vec![vec![0.0; h.offsets[num_reduced]]; PRODUCT_CHUNKS],
            rhs: vec![0.0; h.offsets[num_reduced]],
            x: vec![0.0; h.offsets[num_reduced]],
            elim,
            max_iterations,
            tolerance,
            preconditioner: Vec::new(),
            preconditioner_offsets: Vec::new(),
            zeros: vec![0.0; h.offsets[num_reduced]],
            reduced,
            r: Vec::new(),
            z: Vec::new(),
            p: Vec::new(),
            q: Vec::new(),
        }
    }
}

/// Number of point chunks of the implicit Schur product: fixed, so that the order of the
/// floating-point sums (and so the result) does not depend on the thread count.
const PRODUCT_CHUNKS: usize = 16;

/// `y = (H_cc + D_c)·x − H_cp·H_pp⁻¹·(H_pc·x)` in one pass over the points: each of
/// [`PRODUCT_CHUNKS`] chunks of points gathers `t_p = H_pp⁻¹·Σ_c H_pc·x_c` and scatters
/// `−H_pcᵀ·t_p` into its own buffer over the (small) reduced system; the buffers are added in
/// order.
fn schur_product(
    elim: &Elimination,
    h: &BlockSymmetric,
    diag_add: &[f64],
    x: &[f64],
    partial: &mut [Vec<f64>],
    y: &mut [f64],
) {
    let nr = elim.num_reduced;
    let np = h.num_blocks() - nr;
    let chunks = partial.len();
    partial.par_iter_mut().enumerate().for_each(|(k, buf)| {
        buf.iter_mut().for_each(|v| *v = 0.0);
        let (first, last) = (nr + k * np / chunks, nr + (k + 1) * np / chunks);
        for b in first..last {
            let d = h.dims[b];
            let mut acc = [0.0f64; 16];
            let obs = &elim.obs[elim.obs_ptr[b - nr]..elim.obs_ptr[b - nr + 1]];
            for &(c, s) in obs {
                let (oc, dc) = (h.offsets[c as usize], h.dims[c as usize]);
                let blk = &h.values[h.value_offsets[s]..h.value_offsets[s] + d * dc];
                kernels::add_a_x(&mut acc[..d], blk, &x[oc..oc + dc], d, dc, 1.0);
            }
            let inv =
                &elim.hpp_inv[elim.hpp_inv_offsets[b - nr]..elim.hpp_inv_offsets[b - nr] + d * d];
            let mut t = [0.0f64; 16];
            kernels::add_a_x(&mut t[..d], inv, &acc[..d], d, d, 1.0);
            for &(c, s) in obs {
                let (oc, dc) = (h.offsets[c as usize], h.dims[c as usize]);
                let blk = &h.values[h.value_offsets[s]..h.value_offsets[s] + d * dc];
                kernels::add_at_x(&mut buf[oc..oc + dc], blk, &t[..d], d, dc, -1.0);
            }
        }
    });
    // (H_cc + D_c)·x from the kept blocks (both triangles), then the chunk sums in order.
    for (yi, (di, xi)) in y.iter_mut().zip(diag_add.iter().zip(x)) {
        *yi = di * xi;
    }
    for c in 0..nr {
        let (oc, dc) = (h.offsets[c], h.dims[c]);
        for s in h.col_ptr[c]..h.col_ptr[c + 1] {
            let i = h.rows[s] as usize;
            if i >= nr {
                continue;
            }
            let (oi, di) = (h.offsets[i], h.dims[i]);
            let blk = &h.values[h.value_offsets[s]..h.value_offsets[s] + di * dc];
            // Block (i, c): y_c += H_icᵀ·x_i, and for i ≠ c also y_i += H_ic·x_c.
            kernels::add_at_x(&mut y[oc..oc + dc], blk, &x[oi..oi + di], di, dc, 1.0);
            if i != c {
                kernels::add_a_x(&mut y[oi..oi + di], blk, &x[oc..oc + dc], di, dc, 1.0);
            }
        }
    }
    for buf in partial.iter() {
        for (yi, v) in y.iter_mut().zip(buf) {
            *yi += v;
        }
    }
}

impl LinearSolve for SchurPcg {
    fn solve(
        &mut self,
        h: &BlockSymmetric,
        g: &[f64],
        diag_add: &[f64],
        delta: &mut [f64],
    ) -> Result<usize, LinearError> {
        let nr = self.elim.num_reduced;
        self.elim.invert_points(h, g, diag_add)?;
        self.elim.reduced_rhs(h, g, &mut self.rhs);
        // Schur-Jacobi: the diagonal blocks S_cc = H_cc + D_c − Σ_p H_pcᵀ·H_pp⁻¹·H_pc.
        {
            let red = &mut self.reduced;
            let elim = &self.elim;
            let vo = red.value_offsets.clone();
            let ptr = DisjointMut::new(&mut red.values);
            (0..nr).into_par_iter().with_min_len(16).for_each(|c| {
                let dc = h.dims[c];
                // SAFETY: the reduced matrix stores only diagonal blocks; block c is its own.
                let block = unsafe { ptr.slice(vo[c], dc * dc) };
                block.copy_from_slice(h.diagonal_block(c));
                for t in 0..dc {
                    block[t * dc + t] += diag_add[h.offsets[c] + t];
                }
                for s in h.col_ptr[c] + 1..h.col_ptr[c + 1] {
                    let p = h.rows[s] as usize;
                    if p < nr {
                        continue;
                    }
                    let dp = h.dims[p];
                    let hpc = &h.values[h.value_offsets[s]..h.value_offsets[s] + dp * dc];
                    let inv = &elim.hpp_inv
                        [elim.hpp_inv_offsets[p - nr]..elim.hpp_inv_offsets[p - nr] + dp * dp];
                    let mut tmp = [0.0f64; crate::block::MAX_BLOCK * crate::block::MAX_BLOCK];
                    let tmp = &mut tmp[..dp * dc];
                    kernels::square_times(tmp, inv, hpc, dp, dc);
                    kernels::add_at_b(block, hpc, tmp, dp, dc, dc, -1.0);
                }
            });
        }
        crate::linear::invert_diagonal_blocks(
            &self.reduced,
            &self.zeros,
            &mut self.preconditioner,
            &mut self.preconditioner_offsets,
        )?;
        let (elim, pre, pre_off, reduced) = (
            &self.elim,
            &self.preconditioner,
            &self.preconditioner_offsets,
            &self.reduced,
        );
        let partial = &mut self.partial;
        let iterations = conjugate_gradients(
            |x, y| schur_product(elim, h, diag_add, x, partial, y),
            |r, z| apply_block_diagonal(reduced, pre, pre_off, r, z),
            &self.rhs,
            &mut self.x,
            &mut self.r,
            &mut self.z,
            &mut self.p,
            &mut self.q,
            self.max_iterations,
            self.tolerance,
        );
        let reduced_dim = h.offsets[nr];
        delta[..reduced_dim].copy_from_slice(&self.x);
        self.elim.back_substitute(h, delta);
        Ok(iterations)
    }
}
