//! One row of the census matcher as its kernels see it (module documentation of `matcher.rs`):
//! the shape of the buffers and the constants of their layout, the buffers of a row pass and
//! the offsets of each column's step ([`RowIo`], [`Step`]), and a row's disparities
//! ([`DecideIo`], [`decide_pixel`]). Shared by the scalar kernels (`matcher.rs`) and the
//! vector ones (`avx2`, `avx512`), and uses neither.

use super::StereoParams;

/// Cost of a disparity reaching past the left border (and of the padding lanes): above every
/// Hamming distance of a 7×7 census (≤ 48).
pub(super) const INVALID_COST: u8 = 64;

/// Disparities per vector: 16 `u16` lanes of a 256-bit register. The disparity range of a pixel
/// is padded to a multiple of this.
pub(super) const LANES: usize = 16;

/// The right winners are kept in this many interleaved buffers (column `x` updates way
/// `x mod RIGHT_WAYS`), so that a column's loads never overlap the stores of the column just
/// before (which would stall on store forwarding); the ways are merged per row.
pub(super) const RIGHT_WAYS: usize = 4;

/// Image size and parameters the buffers are made for.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) struct Shape {
    pub w: usize,
    pub h: usize,
    /// Disparities `0..nd`.
    pub nd: usize,
    /// `nd` rounded up to a multiple of [`LANES`].
    pub ndp: usize,
    /// Census radius (≤ 3) and its number of byte planes, `((2c+1)² − 1) / 8`.
    pub census_radius: usize,
    pub planes: usize,
    /// Block and shift radius.
    pub r: usize,
    pub s: usize,
}

impl Shape {
    pub fn new(w: usize, h: usize, params: &StereoParams) -> Self {
        let nd = params.max_disparity.min(w - 1).min(u16::MAX as usize) + 1;
        let c = params.census_radius.min(3);
        Self {
            w,
            h,
            nd,
            ndp: nd.div_ceil(LANES) * LANES,
            census_radius: c,
            planes: ((2 * c + 1) * (2 * c + 1) - 1) / 8,
            r: params.block_radius,
            s: params.shift_radius,
        }
    }

    /// Elements of one row of `[x][d]` values.
    pub fn row_len(&self) -> usize {
        self.w * self.ndp
    }

    /// Columns / rows of a shifted window, `2s + 1`.
    pub fn n(&self) -> usize {
        2 * self.s + 1
    }

    /// The columns of `V` brought up to date before a row's column loop (`A(0 … s − 1)` need
    /// them; column `x` of the loop updates `V(x + s + r)`, the one `A(x + s)` adds).
    pub fn v_prefix(&self) -> usize {
        self.r + self.s.max(1)
    }

    /// [`RowIo::interior`] of a row on which every stage runs (`all_stages`; else empty).
    pub fn interior(&self, all_stages: bool) -> [std::ops::Range<usize>; 2] {
        let Shape { w, nd, r, s, .. } = *self;
        if !all_stages {
            return [0..0, 0..0];
        }
        let lo = r.max((r + 1).saturating_sub(s)).max(1);
        let hi = w.saturating_sub(s + r).max(lo);
        let all = (r + nd - 1).clamp(lo, hi);
        [lo..all, all..hi]
    }

    /// Length of one way of the right winners' buffers (index `w − 1 − x_r`, `x_r` down to
    /// `−(ndp − 1)`).
    pub fn right_len(&self) -> usize {
        self.w + self.ndp
    }
}

/// The buffers of one row pass (see [`row_scalar`](super::matcher::row_scalar)).
pub(super) struct RowIo<'a> {
    pub shape: Shape,
    /// Compute `A` and `H` (rows of the image).
    pub do_h: bool,
    /// Compute `M` and the winners of the output row.
    pub do_m: bool,
    /// The pixel-cost ring and the offsets of the rows entering and leaving the vertical sums
    /// (`None`: `V` is up to date).
    pub costs: &'a mut [u8],
    pub v_rows: Option<(usize, usize)>,
    /// Columns whose entering pixel costs the (AVX2) kernel computes itself, from the census
    /// planes of the new row, instead of reading them (the cost pass skipped them).
    pub fused: Option<Fused<'a>>,
    pub vsum: &'a mut [u16],
    pub blocks: &'a mut [u16],
    pub shifted: &'a mut [u16],
    /// The shift-minimum ring's slot of this row's `H`.
    pub h_slot: usize,
    /// `M` of the output row.
    pub block: &'a mut [u16],
    /// `0, 1, …, ndp − 1` (the disparities of the lanes).
    pub lanes: &'a [u16],
    pub right_cost: &'a mut [u16],
    pub right_index: &'a mut [u16],
    pub left_key: &'a mut [u32],
}

/// The census planes of a new cost row and the columns `x'` (of `V`) whose costs the row kernel
/// computes (see [`RowIo::fused`]).
pub(super) struct Fused<'a> {
    pub left_planes: &'a [u8],
    pub right_planes: &'a [u8],
    pub right_stride: usize,
    pub columns: std::ops::Range<usize>,
}

impl RowIo<'_> {
    /// The sizes the kernels rely on (every offset of a [`Step`] lies inside them).
    pub fn check(&self) {
        let sh = &self.shape;
        let (row, n, ndp) = (sh.row_len(), sh.n(), sh.ndp);
        assert!(ndp.is_multiple_of(LANES) && ndp >= LANES && sh.nd <= ndp && sh.w >= 1);
        assert!(self.vsum.len() >= row && self.blocks.len() >= n * ndp);
        assert!(self.shifted.len() >= n * row && self.h_slot < n);
        if let Some((a, s)) = self.v_rows {
            assert!(a.max(s) + row <= self.costs.len() && a.abs_diff(s) >= row);
        }
        if let Some(f) = &self.fused {
            // (The fused kernel is the 7×7 census's: six planes.)
            assert!(sh.planes == 6 && self.v_rows.is_some() && f.columns.end <= sh.w);
            assert!(f.left_planes.len() >= 6 * sh.w && f.right_stride >= sh.w + ndp + 32);
            assert!(f.right_planes.len() >= 5 * f.right_stride + sh.w + ndp + 32);
        }
        assert!(self.block.len() >= row && self.lanes.len() >= ndp);
        let right = RIGHT_WAYS * sh.right_len();
        assert!(self.right_cost.len() >= right && self.right_index.len() >= right);
        assert!(self.left_key.len() >= sh.w);
    }

    /// The columns whose steps differ only in where they read and write: every stage runs (a
    /// row with new cost rows, `s ≤ y < h`), `V(x + s + r)` is updated and is inside the image,
    /// the leaving column `x + s − r − 1` too, and the left winner is decided (`x ≥ r`). Split
    /// at `x = r + nd − 1`: before it the disparities above `x − r` do not compete (masked),
    /// from it on all do. Both empty on the other rows.
    pub fn interior(&self) -> [std::ops::Range<usize>; 2] {
        self.shape
            .interior(self.do_h && self.do_m && self.v_rows.is_some())
    }

    /// Before the column loop: the vertical sums of columns `0 … v_prefix − 1` (the later ones
    /// are updated in the loop, just before their first use) and the block sums of columns
    /// `−s … s − 1` (clamped) into their ring slots: `A(0)` from its `2r + 1` columns of `V`,
    /// copied to the slots of columns `−s … −1`, then one step per column.
    #[inline(always)]
    pub fn prepare(&mut self) {
        let Shape { w, ndp, r, s, .. } = self.shape;
        if !self.do_h {
            return;
        }
        let row = self.shape.row_len();
        if let Some((a, s)) = self.v_rows {
            let (add, sub) = (&self.costs[a..a + row], &self.costs[s..s + row]);
            let end = self.shape.v_prefix().min(w) * ndp;
            for ((v, &a), &u) in self.vsum[..end].iter_mut().zip(add).zip(sub) {
                *v = v.wrapping_add(a as u16).wrapping_sub(u as u16);
            }
        }
        let vsum = &*self.vsum;
        let (zero, rest) = self.blocks.split_at_mut(s * ndp);
        let a0 = &mut rest[..ndp];
        a0.fill(0);
        for i in 0..=2 * r {
            let c = i.saturating_sub(r).min(w - 1) * ndp;
            for (a, &v) in a0.iter_mut().zip(&vsum[c..c + ndp]) {
                *a = a.wrapping_add(v);
            }
        }
        for z in zero.chunks_exact_mut(ndp) {
            z.copy_from_slice(a0);
        }
        for j in 1..s {
            let (done, next) = self.blocks.split_at_mut((j + s) * ndp);
            let prev = &done[(j + s - 1) * ndp..];
            let a = &mut next[..ndp];
            let (add, sub) = if j < w {
                ((j + r).min(w - 1) * ndp, j.saturating_sub(r + 1) * ndp)
            } else {
                (0, 0)
            };
            for d in 0..ndp {
                a[d] = prev[d]
                    .wrapping_add(vsum[add + d])
                    .wrapping_sub(vsum[sub + d]);
            }
        }
    }
}

/// What column `x` of a row pass reads and writes (offsets into [`RowIo`]'s buffers), the same
/// for both kernels.
#[derive(Debug, Clone, Copy)]
pub(super) struct Step {
    /// `V`'s column entering the block sums here (`v_col·ndp`), updated from the cost rows
    /// first (`update_v`).
    pub update_v: bool,
    pub v_col: usize,
    /// `A(x + s) = A(x + s − 1) + V(v_add) − V(v_sub)` (ring slots `a_prev`, `a_out`; at column
    /// 0 and beyond the right border `v_add = v_sub`: the block sums are already there).
    pub a_prev: usize,
    pub a_out: usize,
    pub v_add: usize,
    pub v_sub: usize,
    /// Where `H(y, x)` goes in the shift-minimum ring; `M(y − s, x)` reads its rows from
    /// `h_column` on (`2s + 1` slots of `ndp`) and goes to `block[x_at..]`.
    pub h_at: usize,
    pub h_column: usize,
    pub x_at: usize,
    /// The left key over `d ≤ dmax` (`mask`: `dmax < nd − 1`; else over all `ndp` lanes, the
    /// padding never winning).
    pub decide: bool,
    pub dmax: usize,
    pub mask: bool,
    /// Where the right winners' lanes start: way `x mod RIGHT_WAYS`, index `w − 1 − x`.
    pub right_at: usize,
}

impl Step {
    /// Column `x`'s step, with `a_slot` the ring slot of column `x + s` (`(x + 2s) mod n`).
    #[inline(always)]
    pub fn new(io: &RowIo, x: usize, a_slot: usize) -> Self {
        let Shape {
            w, nd, ndp, r, s, ..
        } = io.shape;
        let n = io.shape.n();
        let j = x + s;
        let (v_add, v_sub) = if j == 0 || j >= w {
            (0, 0)
        } else {
            ((j + r).min(w - 1) * ndp, j.saturating_sub(r + 1) * ndp)
        };
        let v_col = j + r;
        let decide = io.do_m && x >= r;
        let dmax = if decide { (x - r).min(nd - 1) } else { 0 };
        Self {
            update_v: io.do_h && io.v_rows.is_some() && v_col >= io.shape.v_prefix() && v_col < w,
            v_col: v_col * ndp,
            a_prev: (if a_slot == 0 { n - 1 } else { a_slot - 1 }) * ndp,
            a_out: a_slot * ndp,
            v_add,
            v_sub,
            h_at: (x * n + io.h_slot) * ndp,
            h_column: x * n * ndp,
            x_at: x * ndp,
            decide,
            dmax,
            mask: dmax + 1 < nd,
            right_at: (x % RIGHT_WAYS) * io.shape.right_len() + (w - 1 - x),
        }
    }
}

/// The buffers of [`decide_row`](super::matcher::decide_row).
pub(super) struct DecideIo<'a> {
    pub shape: Shape,
    pub left_key: &'a [u32],
    /// `M` of the row (`[x][d]`).
    pub block: &'a [u16],
    /// `d_R(x_r)` at `w − 1 − x_r`.
    pub right_best: &'a [u16],
    pub max_lr_difference: f32,
    pub dst: &'a mut [f32],
}

/// One pixel of [`decide_row`](super::matcher::decide_row).
#[inline(always)]
pub(super) fn decide_pixel(
    shape: &Shape,
    x: usize,
    key: u32,
    block: &[u16],
    right_best: &[u16],
    max_lr_difference: f32,
) -> f32 {
    let Shape { w, nd, ndp, r, .. } = *shape;
    if key == u32::MAX {
        return f32::NAN;
    }
    let (best, bd) = ((key >> 16) as u16, (key & 0xffff) as usize);
    let dmax = (x - r).min(nd - 1);
    let mut dsub = bd as f32;
    if bd > 0 && bd < dmax {
        let m = &block[x * ndp..(x + 1) * ndp];
        let (c0, c1, c2) = (m[bd - 1] as f32, best as f32, m[bd + 1] as f32);
        let den = c0 - 2.0 * c1 + c2;
        if den > 0.0 {
            dsub += ((c0 - c2) / (2.0 * den)).clamp(-0.5, 0.5);
        }
    }
    // x_r = x − d_L is at w − 1 − x_r.
    if max_lr_difference >= 0.0
        && (right_best[w - 1 - x + bd] as f32 - bd as f32).abs() > max_lr_difference
    {
        return f32::NAN;
    }
    dsub
}
