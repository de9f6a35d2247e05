//! The census block matcher: [`StereoMatcher`] (buffers kept from call to call) and the row
//! driver behind it and [`super::block_match`].
//!
//! # What is computed
//!
//! With the census words `L(x, y)`, `R(x, y)` of the two images (bits in [`census_transform`]'s
//! order), `r` the block radius, `s` the shift radius and coordinates clamped to the image:
//!
//! * pixel costs `C(y, x, d) = popcount(L(x, y) ⊕ R(x − d, y))` for `d ≤ x`, `64` for `d > x`;
//! * vertical sums `V(y, x, d) = Σ_{|j| ≤ r} C(y + j, x, d)`;
//! * block sums `A(y, x, d) = Σ_{|i| ≤ r} V(y, x + i, d)` (the `(2r+1)²` block);
//! * shiftable windows (Scharstein & Szeliski 2002): `H(y, x, d) = min_{|i| ≤ s} A(y, x + i, d)`
//!   and `M(y, x, d) = min_{|j| ≤ s} H(y + j, x, d)`, the best of the blocks shifted by up to
//!   `s` pixels;
//! * the left winner `d_L(x) = argmin_{d ≤ min(x − r, D − 1)} M(y, x, d)` and the right winner
//!   `d_R(x_r) = argmin_d M(y, x_r + d, d)` (both the first minimum: the smallest `d` among
//!   equal costs), a parabola through the three costs around `d_L` for the sub-pixel
//!   disparity, the left-right check `|d_R(x − d_L) − d_L| ≤ max_lr_difference`, then the 3×3
//!   median of the valid disparities.
//!
//! All costs are integers, so the order of the sums does not matter: the result equals the
//! straightforward volume-based computation (the tests' reference) bit for bit.
//!
//! # How (one pass over `x` per row)
//!
//! The disparities of a pixel are stored together (`[x][d]`), padded to a multiple of
//! [`LANES`] = 16 (one 256-bit vector of `u16`), the padding lanes at cost 64: they can only
//! tie with a real disparity, and ties go to the smaller `d`, so they never win.
//!
//! Per image row `y` (running `s` rows ahead of the output row, for the vertical minimum):
//! 1. the census rows of both images as byte planes (plane `b` = bits `8b..8b+8` of every
//!    pixel's word; the right image's reversed, so that `R(x − d)` is contiguous in `d`) and
//!    the pixel costs `C` of row `y + r` into a ring of `2r + 2` rows (`u8`);
//! 2. one loop over the columns (`RowIo`, `row_scalar` / `avx2::row`), each step on one
//!    pixel's disparities: `V(y, x + s + r)` updated in place (`+` the entering cost row, `−`
//!    the leaving one) just before the block sum `A(y, x + s)` needs it (`+` that column of `V`,
//!    `−` the leaving one, into a ring of `2s + 1` columns), `H(y, x)` (the minimum of that
//!    ring) into a ring of `2s + 1` rows (stored column by column, so that a pixel's rows lie
//!    together), `M(y − s, x)` (the minimum of those rows), kept for the row, the left key
//!    `min_d (M ≪ 16) | d` (the first minimum) and the right winners: running `(cost, d)`
//!    minima per diagonal `x_r = x − d`, lane `d` of column `x` at index `w − 1 − x + d` of one
//!    of [`RIGHT_WAYS`] interleaved buffers (so no load waits on the stores of the column
//!    before), merged at the end of the row;
//! 3. the row's disparities (`decide_row`): the parabola through the costs beside the left
//!    winner and the left-right check; the median once all rows are done.
//!
//! The AVX2 kernels specialise the interior columns (every stage, no clamping; `2s + 1` and
//! the padded disparity count known at compile time: constant offsets, unrolled chunks; on a
//! CPU with AVX-512, `avx512`'s kernels, 32 disparities per vector, take these columns), and
//! there, on rows with a new cost row, compute that row's costs in the column step itself
//! (7×7 census), so the byte arithmetic of the costs and the loads of the aggregation share
//! the column instead of a separate pass. The scalar kernels are the reference: same results
//! on every path (tested against the volume-based computation).
//!
//! Memory is `O(w·D·(r + s))` (the rings, `V` and the output row's `M`), kept in the
//! [`StereoMatcher`] between calls, so a frame allocates nothing but its output.
//!
//! [`census_transform`]: super::census_transform

use super::median::{MedianScratch, median3_valid_into};
use super::row::{
    DecideIo, Fused, INVALID_COST, LANES, RIGHT_WAYS, RowIo, Shape, Step, decide_pixel,
};
use super::{StereoParams, census_pixel, check_pair};
use crate::image::{GrayImage, Image, ImageError};

/// A census matcher with its buffers: [`StereoMatcher::compute`] gives the same disparities as
/// [`super::block_match`] without allocating (or faulting in) its working memory on every
/// call. Keep one per stream of equally sized pairs (the buffers are re-made when the image
/// size changes). A clone has the same parameters and buffers of its own, made on its first
/// call.
pub struct StereoMatcher {
    params: StereoParams,
    buffers: Option<Buffers>,
    /// The matchers of the other bands of [`StereoMatcher::compute_in_bands`].
    bands: Vec<StereoMatcher>,
}

impl Clone for StereoMatcher {
    fn clone(&self) -> Self {
        Self::new(self.params)
    }
}

impl std::fmt::Debug for StereoMatcher {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("StereoMatcher")
            .field("params", &self.params)
            .field(
                "buffers_for",
                &self.buffers.as_ref().map(|b| (b.shape.w, b.shape.h)),
            )
            .finish()
    }
}

impl StereoMatcher {
    /// A matcher with `params`; buffers are allocated by the first [`compute`](Self::compute).
    pub fn new(params: StereoParams) -> Self {
        Self {
            params,
            buffers: None,
            bands: Vec::new(),
        }
    }

    /// The parameters.
    pub fn params(&self) -> &StereoParams {
        &self.params
    }

    /// The left disparity image of a rectified pair (`u_r = u_l − d`); invalid pixels (no
    /// unique match, failed left-right check, or no candidate) are `NaN`. See
    /// [`super::block_match`].
    ///
    /// Errors if the images differ in size or are smaller than one block.
    pub fn compute(
        &mut self,
        left: &GrayImage,
        right: &GrayImage,
    ) -> Result<Image<f32>, ImageError> {
        let (w, h) = check_pair(left, right, &self.params)?;
        let shape = Shape::new(w, h, &self.params);
        if self.buffers.as_ref().map(|b| b.shape) != Some(shape) {
            self.buffers = Some(Buffers::new(shape));
        }
        let buffers = self.buffers.as_mut().expect("buffers made above");
        let mut out = Image::filled(w, h, f32::NAN);
        #[cfg(target_arch = "x86_64")]
        if crate::simd::avx2() {
            // SAFETY: the CPU supports AVX2 (checked just above).
            unsafe { run_avx2(buffers, left, right, &self.params, &mut out) };
            return Ok(out);
        }
        run::<false>(buffers, left, right, &self.params, &mut out);
        Ok(out)
    }
}

impl StereoMatcher {
    /// Rows above and below a band of output rows that their disparities depend on: the
    /// census (`c`), the block (`r`) and the shifted windows (`s`) reach that far, and the 3×3
    /// median one row more.
    fn band_margin(&self) -> usize {
        self.params.census_radius.min(3) + self.params.block_radius + self.params.shift_radius + 1
    }

    /// [`compute`](Self::compute) with the rows split into `bands` horizontal bands, each
    /// matched on its own thread together with [`band_margin`](Self::band_margin) rows on either
    /// side (so that its rows see exactly the pixels they see in the whole image): the same
    /// disparities bit for bit, in about `1/bands` of the time on as many free cores. Each band
    /// keeps its own buffers between calls. Fewer bands where the image is too short for them.
    pub fn compute_in_bands(
        &mut self,
        left: &GrayImage,
        right: &GrayImage,
        bands: usize,
    ) -> Result<Image<f32>, ImageError> {
        let (w, h) = check_pair(left, right, &self.params)?;
        let margin = self.band_margin();
        // Bands at least four margins high: the margins add at most half a band's work.
        let bands = bands.min(h / (4 * margin).max(1)).max(1);
        if bands == 1 {
            return self.compute(left, right);
        }
        let rows = |b: usize| (b * h / bands, (b + 1) * h / bands);
        let with_margin =
            |(y0, y1): (usize, usize)| (y0.saturating_sub(margin), (y1 + margin).min(h));
        let crop = |img: &GrayImage, (y0, y1): (usize, usize)| {
            let mut data = Vec::with_capacity(w * (y1 - y0));
            for y in y0..y1 {
                data.extend_from_slice(img.row(y));
            }
            GrayImage::from_vec(w, y1 - y0, w, data).expect("whole rows")
        };
        let params = self.params;
        let mut others = std::mem::take(&mut self.bands);
        others.resize_with(bands - 1, || StereoMatcher::new(params));
        let results = std::thread::scope(|scope| {
            let handles: Vec<_> = others
                .iter_mut()
                .enumerate()
                .map(|(i, m)| {
                    let span = with_margin(rows(i + 1));
                    let (l, r) = (crop(left, span), crop(right, span));
                    scope.spawn(move || m.compute(&l, &r))
                })
                .collect();
            let span = with_margin(rows(0));
            let first = self.compute(&crop(left, span), &crop(right, span));
            std::iter::once(first)
                .chain(
                    handles
                        .into_iter()
                        .map(|h| h.join().expect("a band does not panic")),
                )
                .collect::<Vec<_>>()
        });
        self.bands = others;
        let mut out = Image::filled(w, h, f32::NAN);
        for (b, band) in results.into_iter().enumerate() {
            let band = band?;
            let ((y0, y1), (top, _)) = (rows(b), with_margin(rows(b)));
            for y in y0..y1 {
                out.row_mut(y).copy_from_slice(band.row(y - top));
            }
        }
        Ok(out)
    }
}

/// Computes the left disparity image of a rectified pair (`u_r = u_l − d`); invalid pixels
/// (no unique match, failed left-right check, or no candidate) are `NaN`.
///
/// A [`StereoMatcher`] made for this one call: a caller matching a stream of pairs keeps one
/// (same results, no buffers allocated per pair). The matcher streams the rows with
/// `O(w·D·(r + s))` memory; all costs are integers, so the result does not depend on the order
/// of the sums: it equals the straightforward volume-based computation bit for bit (tested).
/// Census, costs and the aggregation loop have AVX2 kernels (runtime dispatch) beside their
/// scalar references.
///
/// Errors if the images differ in size or are smaller than one block.
pub fn block_match(
    left: &GrayImage,
    right: &GrayImage,
    params: &StereoParams,
) -> Result<Image<f32>, ImageError> {
    StereoMatcher::new(*params).compute(left, right)
}

/// A zeroed buffer of `len` elements starting on a 32-byte boundary (so that the vectors of a
/// `[x][d]` row, `ndp` elements apart, are aligned).
struct Aligned<T> {
    buf: Vec<T>,
    off: usize,
    len: usize,
}

impl<T: Copy + Default> Aligned<T> {
    fn new(len: usize) -> Self {
        let extra = 32 / std::mem::size_of::<T>();
        let buf = vec![T::default(); len + extra];
        let off = buf.as_ptr().align_offset(32).min(extra);
        Self { buf, off, len }
    }

    fn get(&self) -> &[T] {
        &self.buf[self.off..self.off + self.len]
    }

    fn get_mut(&mut self) -> &mut [T] {
        let (o, l) = (self.off, self.len);
        &mut self.buf[o..o + l]
    }
}

/// The working memory of one matcher (see the module documentation for the names).
struct Buffers {
    shape: Shape,
    /// Both images with `c` columns replicated on either side and the top bit of every pixel
    /// flipped (AVX2 census): row `y` at `y·padded_stride`.
    padded: [Vec<u8>; 2],
    padded_stride: usize,
    /// Census byte planes of the current left row: plane `b` at `b·w`.
    left_planes: Vec<u8>,
    /// Census byte planes of the current right row, reversed (`R(x)` at `w − 1 − x`) and
    /// followed by `ndp + 32` zeros: plane `b` at `b·right_stride`.
    right_planes: Vec<u8>,
    right_stride: usize,
    /// Ring of `2r + 2` pixel-cost rows `C` (`[x][d]`, `u8`; row `y` in slot `y mod (2r+2)`),
    /// each `cost_stride` long (a row and room for a 32-byte store past its end).
    costs: Aligned<u8>,
    cost_stride: usize,
    /// Vertical sums `V` of the current row.
    vsum: Aligned<u16>,
    /// Ring of the `2s + 1` columns of block sums `A` around the current pixel (column `j`,
    /// clamped to the image, in slot `(j + s) mod (2s+1)`).
    blocks: Aligned<u16>,
    /// Ring of the `2s + 1` rows of horizontal shift minima `H` around the output row (row `j`,
    /// clamped, in slot `(j + s) mod (2s+1)`), column by column: `H(j, x, d)` at
    /// `(x·(2s+1) + slot)·ndp + d`, so that the rows a pixel's `M` needs are together.
    shifted: Aligned<u16>,
    /// `M` of the output row (`[x][d]`; the sub-pixel fit and the uniqueness test read it).
    block: Aligned<u16>,
    /// `0, 1, …, ndp − 1`.
    lanes: Aligned<u16>,
    /// The right winners' running minima and their disparities, [`RIGHT_WAYS`] buffers of
    /// [`Shape::right_len`].
    right_cost: Aligned<u16>,
    right_index: Aligned<u16>,
    /// Per column of the output row: the left key `(M ≪ 16) | d_L` (`u32::MAX`: no decision)
    /// and the right winners (`d_R(x_r)` at `w − 1 − x_r`; one element of room at the end for
    /// the 32-bit gathers reading them).
    left_key: Vec<u32>,
    right_best: Vec<u16>,
    /// Disparities before the median.
    raw: Image<f32>,
    median: MedianScratch,
}

impl Buffers {
    fn new(shape: Shape) -> Self {
        let Shape {
            w,
            h,
            ndp,
            census_radius: c,
            planes,
            r,
            ..
        } = shape;
        let (row, n) = (shape.row_len(), shape.n());
        let right_stride = w + ndp + 32;
        let cost_stride = (row + 32).div_ceil(32) * 32;
        let padded_stride = w + 2 * c;
        let mut lanes = Aligned::new(ndp);
        for (d, l) in lanes.get_mut().iter_mut().enumerate() {
            *l = d as u16;
        }
        Self {
            shape,
            padded: [vec![0; h * padded_stride], vec![0; h * padded_stride]],
            padded_stride,
            left_planes: vec![0; planes * w],
            right_planes: vec![0; planes * right_stride],
            right_stride,
            costs: Aligned::new((2 * r + 2) * cost_stride),
            cost_stride,
            vsum: Aligned::new(row),
            blocks: Aligned::new(n * ndp),
            shifted: Aligned::new(n * row),
            block: Aligned::new(row + 2),
            lanes,
            right_cost: Aligned::new(RIGHT_WAYS * shape.right_len()),
            right_index: Aligned::new(RIGHT_WAYS * shape.right_len()),
            left_key: vec![u32::MAX; w],
            right_best: vec![0; w + 1],
            raw: Image::filled(w, h, f32::NAN),
            median: MedianScratch::default(),
        }
    }
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn run_avx2(
    b: &mut Buffers,
    left: &GrayImage,
    right: &GrayImage,
    params: &StereoParams,
    out: &mut Image<f32>,
) {
    run::<true>(b, left, right, params, out)
}

/// The matcher (module documentation); `AVX2` selects the kernels.
#[inline(always)]
fn run<const AVX2: bool>(
    b: &mut Buffers,
    left: &GrayImage,
    right: &GrayImage,
    params: &StereoParams,
    out: &mut Image<f32>,
) {
    let shape = b.shape;
    let Shape { w, h, .. } = shape;
    let (r, s, n) = (shape.r, shape.s, shape.n());
    let row_len = shape.row_len();
    let cost_slots = 2 * r + 2;
    let cs = b.cost_stride;
    // The AVX-512 interior kernels where the CPU has them (same results).
    let wide = AVX2 && crate::simd::avx512();
    if AVX2 {
        let c = shape.census_radius;
        for (img, pad) in [left, right].into_iter().zip(&mut b.padded) {
            for (y, p) in pad.chunks_exact_mut(b.padded_stride).enumerate() {
                // (Top bit flipped: signed byte compares order them as unsigned.)
                let row = img.row(y);
                p[..c].fill(row[0] ^ 0x80);
                for (q, &v) in p[c..c + w].iter_mut().zip(row) {
                    *q = v ^ 0x80;
                }
                p[c + w..].fill(row[w - 1] ^ 0x80);
            }
        }
    }
    // Cost rows 0..computed are (or were) in the ring.
    let mut computed = 0usize;
    for ya in 0..h + s {
        let h_slot = (ya + s) % n;
        // The cost rows entering and leaving this row's vertical sums (none for row 0, whose
        // sums are made here whole).
        let mut v_rows = None;
        let mut fused = None;
        if ya == 0 {
            computed = r.min(h - 1) + 1;
            for yy in 0..computed {
                cost_row::<AVX2>(b, left, right, yy, yy % cost_slots, 0..0);
            }
            let costs = b.costs.get();
            let vsum = b.vsum.get_mut();
            vsum.fill(0);
            for j in 0..=2 * r {
                let yy = j.saturating_sub(r).min(h - 1);
                let c = &costs[(yy % cost_slots) * cs..][..row_len];
                for (v, &c) in vsum.iter_mut().zip(c) {
                    *v = v.wrapping_add(c as u16);
                }
            }
        } else if ya < h {
            let add = (ya + r).min(h - 1);
            let sub = ya.saturating_sub(r + 1);
            if add == computed {
                // A new cost row: the row kernel computes the costs of the interior columns
                // itself where it can (AVX2, 7×7 census), the cost pass the others.
                let plain = shape.interior(ya >= s)[1].clone();
                if AVX2
                    && shape.planes == 6
                    && fusable(&shape)
                    && !plain.is_empty()
                    && plain.start + s + r >= shape.nd
                {
                    fused = Some(plain.start + s + r..plain.end + s + r);
                }
                let skip = fused.clone().unwrap_or(0..0);
                cost_row::<AVX2>(b, left, right, add, add % cost_slots, skip);
                computed += 1;
            }
            v_rows = Some((add % cost_slots * cs, sub % cost_slots * cs));
        } else {
            // Rows below the image are copies of the last one.
            let last = (h - 1 + s) % n;
            let ndp = shape.ndp;
            for col in b.shifted.get_mut().chunks_exact_mut(n * ndp) {
                col.copy_within(last * ndp..(last + 1) * ndp, h_slot * ndp);
            }
        }
        let do_h = ya < h;
        let do_m = ya >= s;
        if do_m {
            b.right_cost.get_mut().fill(u16::MAX);
            b.right_index.get_mut().fill(0);
        }
        let io = RowIo {
            shape,
            do_h,
            do_m,
            costs: b.costs.get_mut(),
            v_rows,
            fused: fused.map(|columns| Fused {
                left_planes: &b.left_planes,
                right_planes: &b.right_planes,
                right_stride: b.right_stride,
                columns,
            }),
            vsum: b.vsum.get_mut(),
            blocks: b.blocks.get_mut(),
            shifted: b.shifted.get_mut(),
            h_slot,
            block: b.block.get_mut(),
            lanes: b.lanes.get(),
            right_cost: b.right_cost.get_mut(),
            right_index: b.right_index.get_mut(),
            left_key: &mut b.left_key,
        };
        #[cfg(target_arch = "x86_64")]
        if AVX2 {
            // SAFETY: AVX2 instances run after `simd::avx2()`; sizes checked inside.
            unsafe { super::avx2::row(io, wide) };
        } else {
            row_scalar(io);
        }
        #[cfg(not(target_arch = "x86_64"))]
        row_scalar(io);
        if ya == 0 {
            // Rows above the image are copies of row 0.
            let ndp = shape.ndp;
            for col in b.shifted.get_mut().chunks_exact_mut(n * ndp) {
                for i in 0..s {
                    col.copy_within(s * ndp..(s + 1) * ndp, i * ndp);
                }
            }
        }
        if !do_m {
            continue;
        }
        merge_right(
            &shape,
            b.right_cost.get(),
            b.right_index.get(),
            &mut b.right_best,
        );
        let y = ya - s;
        let Buffers {
            raw,
            left_key,
            block,
            right_best,
            ..
        } = b;
        if params.uniqueness > 0.0 {
            uniqueness_test(&shape, left_key, block.get(), params.uniqueness);
        }
        let dst = if params.median_filter {
            raw.row_mut(y)
        } else {
            out.row_mut(y)
        };
        let io = DecideIo {
            shape,
            left_key,
            block: block.get(),
            right_best,
            max_lr_difference: params.max_lr_difference,
            dst,
        };
        #[cfg(target_arch = "x86_64")]
        if AVX2 {
            // SAFETY: AVX2 instances run after `simd::avx2()`; sizes checked inside.
            unsafe { super::avx2::decide_row(io) };
        } else {
            decide_row(io);
        }
        #[cfg(not(target_arch = "x86_64"))]
        decide_row(io);
    }
    if params.median_filter {
        median3_valid_into(&b.raw, &mut b.median, out);
    }
}

/// Whether the AVX2 row kernel has an instance computing the interior's costs itself (`2s + 1`
/// and the padded disparity count among the specialised ones; not for 16 disparities, whose
/// cost pass does two pixels per vector).
pub(super) fn fusable(shape: &Shape) -> bool {
    matches!(shape.n(), 1 | 3 | 5) && (2..=9).contains(&(shape.ndp / LANES))
}

/// Census planes of row `y` of both images and the pixel costs `C(y)` into ring slot `slot`,
/// except the pixels `skip` (the row kernel computes those).
#[inline(always)]
fn cost_row<const AVX2: bool>(
    b: &mut Buffers,
    left: &GrayImage,
    right: &GrayImage,
    y: usize,
    slot: usize,
    skip: std::ops::Range<usize>,
) {
    let Shape {
        w,
        h,
        nd,
        ndp,
        census_radius: c,
        planes,
        ..
    } = b.shape;
    let sides = [
        (left, &mut b.left_planes, w, false, &b.padded[0]),
        (
            right,
            &mut b.right_planes,
            b.right_stride,
            true,
            &b.padded[1],
        ),
    ];
    for (img, out, stride, reversed, padded) in sides {
        #[cfg(target_arch = "x86_64")]
        if AVX2 && planes > 0 && w >= 32 {
            // SAFETY: AVX2 instances run after `simd::avx2()`; bounds checked inside.
            unsafe {
                super::avx2::census_row(
                    padded,
                    b.padded_stride,
                    w,
                    h,
                    c,
                    y,
                    planes,
                    out,
                    stride,
                    reversed,
                )
            };
            continue;
        }
        let _ = padded;
        for x in 0..w {
            let word = census_pixel(img, x, y, c);
            let at = if reversed { w - 1 - x } else { x };
            for p in 0..planes {
                out[p * stride + at] = (word >> (8 * p)) as u8;
            }
        }
    }
    let cs = b.cost_stride;
    let out = &mut b.costs.get_mut()[slot * cs..(slot + 1) * cs];
    #[cfg(target_arch = "x86_64")]
    if AVX2 {
        // SAFETY: AVX2 instances run after `simd::avx2()`; the buffers' sizes are checked
        // inside.
        unsafe {
            super::avx2::costs(
                &b.left_planes,
                &b.right_planes,
                b.right_stride,
                planes,
                w,
                nd,
                ndp,
                out,
                skip.clone(),
            )
        };
    }
    if !AVX2 {
        assert!(skip.is_empty(), "only the AVX2 row kernel computes costs");
        costs_scalar(
            &b.left_planes,
            &b.right_planes,
            b.right_stride,
            planes,
            w,
            nd,
            ndp,
            out,
        );
    }
}

/// The scalar reference of `avx2::costs`: `C(x, d)` for `d ≤ x`, `d < nd`; [`INVALID_COST`]
/// for the other `d < ndp` (past the left border, padding).
#[allow(clippy::too_many_arguments)]
fn costs_scalar(
    lp: &[u8],
    rp: &[u8],
    rs: usize,
    planes: usize,
    w: usize,
    nd: usize,
    ndp: usize,
    out: &mut [u8],
) {
    for x in 0..w {
        let base = w - 1 - x;
        let o = &mut out[x * ndp..(x + 1) * ndp];
        for (d, c) in o.iter_mut().enumerate() {
            *c = if d >= nd || d > x {
                INVALID_COST
            } else {
                (0..planes)
                    .map(|p| (lp[p * w + x] ^ rp[p * rs + base + d]).count_ones() as u8)
                    .sum()
            };
        }
    }
}

/// One row pass (the module documentation's step 2), scalar: per column `x`, the vertical sums
/// of column `x + s + r` updated, the block sums `A(x + s)` into their ring and `H(y, x)` (the
/// ring's minimum) into the shift-minimum ring (`do_h`); then (`do_m`) `M(y − s, x)` (the
/// minimum of that ring's rows) into the output row's `block`, the right winners' lanes
/// (diagonal `x_r = x − d` in lane `d`) updated where `M` is strictly lower, and the left key
/// `min_{d ≤ dmax} (M ≪ 16) | d` (`u32::MAX` when there is no decision). `avx2::row` is the
/// same with vectors.
pub(super) fn row_scalar(mut io: RowIo) {
    io.check();
    io.prepare();
    let Shape { w, ndp, s, .. } = io.shape;
    let n = io.shape.n();
    let mut a_slot = 2 * s % n;
    for x in 0..w {
        let st = Step::new(&io, x, a_slot);
        a_slot = if a_slot + 1 == n { 0 } else { a_slot + 1 };
        if io.do_h {
            if st.update_v {
                let (a, s) = io.v_rows.expect("update_v");
                let (add, sub) = (
                    &io.costs[a + st.v_col..a + st.v_col + ndp],
                    &io.costs[s + st.v_col..s + st.v_col + ndp],
                );
                for ((v, &a), &s) in io.vsum[st.v_col..st.v_col + ndp]
                    .iter_mut()
                    .zip(add)
                    .zip(sub)
                {
                    *v = v.wrapping_add(a as u16).wrapping_sub(s as u16);
                }
            }
            for d in 0..ndp {
                io.blocks[st.a_out + d] = io.blocks[st.a_prev + d]
                    .wrapping_add(io.vsum[st.v_add + d])
                    .wrapping_sub(io.vsum[st.v_sub + d]);
            }
            for d in 0..ndp {
                io.shifted[st.h_at + d] = (0..n).map(|i| io.blocks[i * ndp + d]).min().unwrap();
            }
        }
        if !io.do_m {
            continue;
        }
        let block = &mut io.block[st.x_at..st.x_at + ndp];
        for (d, m) in block.iter_mut().enumerate() {
            *m = (0..n)
                .map(|i| io.shifted[st.h_column + i * ndp + d])
                .min()
                .unwrap();
        }
        for (d, &m) in block.iter().enumerate() {
            let (c, i) = (
                &mut io.right_cost[st.right_at + d],
                &mut io.right_index[st.right_at + d],
            );
            if m < *c {
                *c = m;
                *i = d as u16;
            }
        }
        io.left_key[x] = if st.decide {
            let top = if st.mask { st.dmax + 1 } else { ndp };
            (0..top)
                .map(|d| ((block[d] as u32) << 16) | d as u32)
                .min()
                .unwrap()
        } else {
            u32::MAX
        };
    }
}

/// The uniqueness test of the row's left winners (keys `(C₁ ≪ 16) | d`): the best cost `C₂`
/// outside `d ± 1` must exceed `C₁·(1 + uniqueness)`, else the key becomes `u32::MAX`.
fn uniqueness_test(shape: &Shape, left_key: &mut [u32], block: &[u16], uniqueness: f32) {
    let Shape { nd, ndp, r, .. } = *shape;
    for (x, key) in left_key.iter_mut().enumerate() {
        if *key == u32::MAX {
            continue;
        }
        let (best, bd) = ((*key >> 16) as u16, (*key & 0xffff) as usize);
        let dmax = (x - r).min(nd - 1);
        let mut second = u16::MAX;
        for (d, &c) in block[x * ndp..].iter().enumerate().take(dmax + 1) {
            if (d + 1 < bd || d > bd + 1) && c < second {
                second = c;
            }
        }
        if second != u16::MAX && (best as f32) * (1.0 + uniqueness) >= second as f32 {
            *key = u32::MAX;
        }
    }
}

/// The right winners of a row, `best[w − 1 − x_r] = d_R(x_r)`: the lowest `(cost, d)` over the
/// [`RIGHT_WAYS`] ways (each holding its lowest cost with the smallest `d`).
#[inline(always)]
fn merge_right(shape: &Shape, cost: &[u16], index: &[u16], best: &mut [u16]) {
    let (w, len) = (shape.w, shape.right_len());
    let ways: [(&[u16], &[u16]); RIGHT_WAYS] =
        std::array::from_fn(|k| (&cost[k * len..k * len + w], &index[k * len..k * len + w]));
    for (i, b) in best[..w].iter_mut().enumerate() {
        let mut m = u32::MAX;
        for (c, d) in ways {
            m = m.min(((c[i] as u32) << 16) | d[i] as u32);
        }
        *b = m as u16;
    }
}

/// The disparities of one output row from the left keys: the parabolic sub-pixel disparity
/// through the costs at `d_L − 1, d_L, d_L + 1` (when both neighbours are candidates and the
/// parabola opens upwards), then the left-right check against `d_R(x − d_L)`; `NaN` where
/// there is no key or the check fails. `avx2::decide_row` does eight pixels per step with the
/// same floating-point operations.
pub(super) fn decide_row(io: DecideIo) {
    for (x, o) in io.dst.iter_mut().enumerate() {
        let key = io.left_key[x];
        *o = decide_pixel(
            &io.shape,
            x,
            key,
            io.block,
            io.right_best,
            io.max_lr_difference,
        );
    }
}
