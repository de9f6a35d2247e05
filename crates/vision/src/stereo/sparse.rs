//! Sparse stereo: the disparity of single points of a rectified pair, searched along the row
//! without a disparity image.
//!
//! A live stereo system measures a few hundred points per frame; matching every pixel (the
//! block matcher, [`super::StereoMatcher`]) to read the disparity at those points was half of a
//! KITTI frame's time. Here each point is matched alone, with the block matcher's decisions
//! made at the point (ORB-SLAM3 likewise matches its keypoints only):
//!
//! 1. **Search**: the sum of absolute differences of the `(2r+1)²` block centred at the point
//!    against the right image's blocks on the same row, every disparity `0 ..= max_disparity`;
//!    the lowest cost wins, refined by the V-shaped (equiangular) fit through its neighbours. Raw intensities, not
//!    the block matcher's census: the cost only has to pick the right integer disparity, and the
//!    point's own measurement ([`super::point_disparity`], a zero-mean patch alignment) is
//!    indifferent to a brightness offset between the cameras.
//! 2. **Left-right check**: the right block at the winner searched back along the left row
//!    must find the point again within `max_lr_difference` pixels (occlusions, repetitions).
//! 3. **One surface**: the blocks shifted diagonally by `shift` pixels (the dense matcher's
//!    shiftable windows) must agree with the centred block's disparity within `agreement`
//!    (relative): a point on a depth discontinuity, where the block mixes the foreground with
//!    the surface behind it, is refused — what the live system's depth-edge test did on the
//!    disparity map's `5×5` neighbourhood (`system::frame::depth_off_edges`).
//!
//! The costs of the four shifted blocks come from one pass over the `(2(r+s)+1)²` pixels, each
//! pixel's costs at every disparity added to the blocks that hold it, after the centred block
//! passed the left-right check (most refusals cost one block and its check). With AVX2, 16
//! disparities at a time (the candidates of a pixel are contiguous in the other image's row),
//! the blocks' sums in registers; the scalar code is the reference ([`crate::simd`]): the same
//! integers either way.

use crate::image::GrayImage;
use crate::simd;

/// Parameters of [`point_block_disparity`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SparseParams {
    /// Disparities `0 ..= max_disparity` are searched (at most [`MAX_SPARSE_DISPARITY`]).
    pub max_disparity: usize,
    /// Block radius `r`: the block is `(2r+1)²` pixels (at most 7, so a block's cost fits 16 bits).
    pub block_radius: usize,
    /// The diagonal shift of the four blocks that must agree with the centred one (pixels).
    pub shift: usize,
    /// Largest difference (pixels) between the disparity and the one the left-right check finds.
    pub max_lr_difference: usize,
    /// Largest relative difference between a shifted block's disparity and the centred one's.
    pub agreement: f32,
    /// ... and the smallest tolerance, in pixels: the blocks' sub-pixel estimates on one
    /// smooth surface differ by up to about this much.
    pub agreement_floor: f32,
}

impl Default for SparseParams {
    /// The block matcher's defaults ([`super::StereoParams`]): 64 disparities, 9×9 blocks,
    /// shifts of 2 px, a 1 px left-right tolerance; blocks agreeing to 3 % (the live system's
    /// depth-edge tolerance) or a quarter pixel, whichever is larger. A quarter pixel is the
    /// resolution of a block's sub-pixel disparity (the V-fit through three integer costs);
    /// with 3 % alone, points below 8 px of disparity — the far half of a KITTI scene, the
    /// points that hold rotation — would need two blocks to agree better than they can.
    fn default() -> Self {
        SparseParams {
            max_disparity: 64,
            block_radius: 4,
            shift: 2,
            max_lr_difference: 1,
            agreement: 0.03,
            agreement_floor: 0.25,
        }
    }
}

/// Largest `max_disparity` of [`SparseParams`] (the costs live on the stack).
pub const MAX_SPARSE_DISPARITY: usize = 511;
/// Largest `block_radius` of [`SparseParams`]: `(2·7+1)² · 255 < 2¹⁶`.
pub const MAX_SPARSE_BLOCK_RADIUS: usize = 7;
/// Largest `shift` of [`SparseParams`].
pub const MAX_SPARSE_SHIFT: usize = 4;

/// Costs of one block at every disparity of the search (index `k`: disparity `D − k`).
type Costs = [u16; MAX_SPARSE_DISPARITY + 1];

/// The disparity of the left image's pixel `(u, v)` in the right image of a rectified pair (the
/// steps in the [module docs](self)), sub-pixel by a V-shaped fit through the block costs; `None`
/// where the blocks leave the image, the best disparity lies at the end of a range the image's
/// border cut short, or the left-right check or the shifted blocks refuse it.
///
/// # Panics
/// If the images differ in size, or the parameters exceed [`MAX_SPARSE_DISPARITY`],
/// [`MAX_SPARSE_BLOCK_RADIUS`] or [`MAX_SPARSE_SHIFT`].
pub fn point_block_disparity(
    left: &GrayImage,
    right: &GrayImage,
    u: usize,
    v: usize,
    params: &SparseParams,
) -> Option<f32> {
    assert_eq!(
        (left.width(), left.height()),
        (right.width(), right.height()),
        "a stereo pair's images differ in size"
    );
    assert!(
        params.max_disparity <= MAX_SPARSE_DISPARITY
            && params.block_radius <= MAX_SPARSE_BLOCK_RADIUS
            && params.shift <= MAX_SPARSE_SHIFT,
        "sparse stereo parameters out of range: {params:?}"
    );
    let (w, h) = (left.width(), left.height());
    let (r, s) = (params.block_radius, params.shift);
    let reach = r + s;
    if u < reach || v < reach || u + reach >= w || v + reach >= h {
        return None;
    }
    // The range the left border leaves: every block's right twin inside the image.
    let range = params.max_disparity.min(u - reach);
    if range == 0 {
        return None;
    }
    let n = range + 1;
    let mut costs = [0u16; MAX_SPARSE_DISPARITY + 1];
    block_costs(
        left,
        right,
        u,
        v,
        range,
        r,
        &[(0, 0)],
        std::slice::from_mut(&mut costs),
    );
    let (k, offset) = best(&costs[..n]);
    // The winner at the cut end of the range may have a better one beyond it.
    if k == 0 && range < params.max_disparity {
        return None;
    }
    let disparity = range - k;
    // Left-right: the right block at the winner finds the point again.
    let x_r = u - disparity;
    let back_range = params.max_disparity.min(w - 1 - r - x_r);
    let mut back = [0u16; MAX_SPARSE_DISPARITY + 1];
    back_costs(left, right, x_r, v, back_range, r, &mut back);
    let (e, _) = best(&back[..back_range + 1]);
    if e.abs_diff(disparity) > params.max_lr_difference {
        return None;
    }
    let d = disparity as f32 - offset;
    // One surface: the shifted blocks agree.
    let s = s as isize;
    let mut shifted = [[0u16; MAX_SPARSE_DISPARITY + 1]; 4];
    block_costs(
        left,
        right,
        u,
        v,
        range,
        r,
        &[(-s, -s), (s, -s), (-s, s), (s, s)],
        &mut shifted,
    );
    let tolerance = (params.agreement * d).max(params.agreement_floor);
    for costs in &shifted {
        let (k, offset) = best(&costs[..n]);
        if ((range - k) as f32 - offset - d).abs() > tolerance {
            return None;
        }
    }
    Some(d)
}

/// The lowest cost's index (the first of equals) and the equiangular fit's sub-pixel offset from it
/// (in index units, within ±0.5; 0 at either end).
fn best(costs: &[u16]) -> (usize, f32) {
    // Two passes (the minimum, then its first index): each vectorises, one fused loop does not.
    let lowest = costs.iter().copied().min().unwrap_or(0);
    let k = costs.iter().position(|&c| c == lowest).unwrap_or(0);
    if k == 0 || k + 1 == costs.len() {
        return (k, 0.0);
    }
    // Equiangular (V-shaped) interpolation: a sum of absolute differences grows linearly away
    // from its minimum, where a parabola pulls sub-pixel values towards whole pixels.
    let (a, b, c) = (costs[k - 1] as f32, costs[k] as f32, costs[k + 1] as f32);
    let slope = (a - b).max(c - b);
    let offset = if slope > 0.0 {
        (0.5 * (a - c) / slope).clamp(-0.5, 0.5)
    } else {
        0.0
    };
    (k, offset)
}

/// One pixel of a block search: its intensity `a`, the other image's row from the pixel's first
/// candidate on (`a` is compared with `row[k]` for the `k`-th candidate), and the blocks (bits of
/// `blocks`) that hold it. The kernel takes the taps grouped by `blocks`.
#[derive(Clone, Copy)]
struct Tap<'a> {
    a: u8,
    row: &'a [u8],
    blocks: u8,
}

/// Most taps of one search: the union of the shifted blocks at the largest radius and shift.
const MAX_TAPS: usize = (2 * (MAX_SPARSE_BLOCK_RADIUS + MAX_SPARSE_SHIFT) + 1).pow(2);

/// Room for the taps of one search, on the stack and not initialised (a few kilobytes, filled
/// tap by tap: zeroing them would cost as much as a small search).
struct Taps<'a> {
    taps: [std::mem::MaybeUninit<Tap<'a>>; MAX_TAPS],
    count: usize,
    written: usize,
}

impl<'a> Taps<'a> {
    /// Room for `count` taps, to be written by [`Taps::put`] (each index once) or in order by
    /// [`Taps::push`].
    fn new(count: usize) -> Self {
        assert!(count <= MAX_TAPS);
        Taps {
            taps: [const { std::mem::MaybeUninit::uninit() }; MAX_TAPS],
            count,
            written: 0,
        }
    }

    /// Writes tap `index`.
    ///
    /// # Safety
    /// Each index below `count` is written exactly once before [`Taps::as_slice`] (`count`
    /// writes to distinct indices).
    unsafe fn put(&mut self, index: usize, tap: Tap<'a>) {
        assert!(index < self.count);
        self.taps[index].write(tap);
        self.written += 1;
    }

    /// Writes the next tap in order.
    fn push(&mut self, tap: Tap<'a>) {
        // SAFETY: `push` alone writes 0, 1, 2, … (a `Taps` is filled by `put` or by `push`).
        unsafe { self.put(self.written, tap) };
    }

    fn as_slice(&self) -> &[Tap<'a>] {
        assert_eq!(self.written, self.count, "every tap written");
        // SAFETY: `count` writes to distinct indices below `count` (the contract of `put`).
        unsafe { std::slice::from_raw_parts(self.taps.as_ptr() as *const Tap<'a>, self.count) }
    }
}

/// The costs of the blocks of the left image centred at `(u, v) + centres[i]` against the right
/// image at disparities `range − k`, `k = 0 ..= range`, into `blocks[i]`.
#[allow(clippy::too_many_arguments)]
fn block_costs(
    left: &GrayImage,
    right: &GrayImage,
    u: usize,
    v: usize,
    range: usize,
    r: usize,
    centres: &[(isize, isize)],
    blocks: &mut [Costs],
) {
    let r = r as isize;
    let reach = centres
        .iter()
        .map(|&(cu, cv)| cu.abs().max(cv.abs()))
        .max()
        .unwrap_or(0)
        + r;
    // The taps grouped by the blocks that hold them (the kernel sums a group once, then adds
    // the group's sum to each of its blocks): a counting sort by the blocks' bits.
    let side = (2 * reach + 1) as usize;
    // Block b holds (du, dv) iff it holds column du and row dv.
    let axis = |d: isize, pick: fn(&(isize, isize)) -> isize| {
        centres.iter().enumerate().fold(0u8, |m, (b, c)| {
            m | ((((d - pick(c)).abs() <= r) as u8) << b)
        })
    };
    let mut columns = [0u8; 2 * (MAX_SPARSE_BLOCK_RADIUS + MAX_SPARSE_SHIFT) + 1];
    let mut rows = columns;
    for (i, d) in (-reach..=reach).enumerate() {
        columns[i] = axis(d, |c| c.0);
        rows[i] = axis(d, |c| c.1);
    }
    let mut start = [0usize; 17];
    for &row in &rows[..side] {
        for &column in &columns[..side] {
            start[(row & column) as usize + 1] += 1;
        }
    }
    // Taps of no block are left out: the groups start after them.
    start[1] = 0;
    for g in 1..16 {
        start[g + 1] += start[g];
    }
    // Each group's end, for the kernel.
    let mut groups = [(0u8, 0usize); 15];
    let mut count = 0;
    for g in 1..16u8 {
        if start[g as usize + 1] > start[g as usize] {
            groups[count] = (g, start[g as usize + 1]);
            count += 1;
        }
    }
    let mut taps = Taps::new(start[16]);
    for (j, dv) in (-reach..=reach).enumerate() {
        let y = (v as isize + dv) as usize;
        let (l_row, r_row) = (left.row(y), right.row(y));
        for (i, du) in (-reach..=reach).enumerate() {
            let m = rows[j] & columns[i];
            if m != 0 {
                let x = (u as isize + du) as usize;
                // Right pixels x − d for d = range … 0: contiguous, x − range ≥ 0.
                // SAFETY: `start[m]` runs through group m's own indices (the counting sort's
                // prefix sums), one tap each: every index below the total once.
                unsafe {
                    taps.put(
                        start[m as usize],
                        Tap {
                            a: l_row[x],
                            row: &r_row[x - range..=x],
                            blocks: m,
                        },
                    )
                };
                start[m as usize] += 1;
            }
        }
    }
    sums_of_differences(taps.as_slice(), &groups[..count], range + 1, blocks);
}

/// The costs of the right image's block centred at `(x_r, v)` against the left image's blocks
/// at `x_r + e`, `e = 0 ..= range`.
fn back_costs(
    left: &GrayImage,
    right: &GrayImage,
    x_r: usize,
    v: usize,
    range: usize,
    r: usize,
    costs: &mut Costs,
) {
    let mut taps = Taps::new((2 * r + 1) * (2 * r + 1));
    for y in v - r..=v + r {
        let (l_row, r_row) = (left.row(y), right.row(y));
        for x in x_r - r..=x_r + r {
            taps.push(Tap {
                a: r_row[x],
                row: &l_row[x..=x + range],
                blocks: 1,
            });
        }
    }
    let all = [(1, taps.as_slice().len())];
    sums_of_differences(
        taps.as_slice(),
        &all,
        range + 1,
        std::slice::from_mut(costs),
    );
}

/// `blocks[i][k] = Σ |tap.a − tap.row[k]|` over the taps held by block `i`, `k < n` (every
/// tap's row holds `n` values). `groups`: the taps' groups in order, each as its blocks' bits
/// and the end of its taps.
fn sums_of_differences(taps: &[Tap], groups: &[(u8, usize)], n: usize, blocks: &mut [Costs]) {
    debug_assert!(taps.iter().all(|t| t.row.len() >= n) && blocks.len() <= 8);
    #[cfg(target_arch = "x86_64")]
    if simd::avx2() {
        // SAFETY: the CPU has AVX2 (`simd::avx2`); rows hold n values (asserted by the callers'
        // slicing).
        unsafe { sums_of_differences_avx2(taps, groups, n, blocks) };
        return;
    }
    sums_of_differences_scalar(taps, 0, n, blocks);
}

/// The scalar reference of [`sums_of_differences`] for `k` in `from..n`.
fn sums_of_differences_scalar(taps: &[Tap], from: usize, n: usize, blocks: &mut [Costs]) {
    for costs in blocks.iter_mut() {
        costs[from..n].fill(0);
    }
    for t in taps {
        for (i, costs) in blocks.iter_mut().enumerate() {
            if t.blocks & (1 << i) != 0 {
                for (c, &b) in costs[from..n].iter_mut().zip(&t.row[from..n]) {
                    *c += t.a.abs_diff(b) as u16;
                }
            }
        }
    }
}

/// [`sums_of_differences`] 16 candidates at a time: `|a − b|` of bytes by two saturating
/// subtractions, widened to 16 bits, summed over each group of taps with the same blocks (the
/// taps come grouped) and added to the group's blocks, the sums in registers. The last chunk
/// ends at `n` (overlapping the one before: the sums are written, not added); fewer than 16
/// candidates go to the scalar code.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn sums_of_differences_avx2(
    taps: &[Tap],
    groups: &[(u8, usize)],
    n: usize,
    blocks: &mut [Costs],
) {
    use std::arch::x86_64::*;
    if n < 16 {
        sums_of_differences_scalar(taps, 0, n, blocks);
        return;
    }
    let nb = blocks.len();
    let mut k = 0;
    loop {
        let mut sums = [_mm256_setzero_si256(); 8];
        let mut from = 0;
        for &(held, end) in groups {
            let mut g = _mm256_setzero_si256();
            for t in &taps[from..end] {
                // SAFETY: k + 16 ≤ n ≤ t.row.len().
                let b = unsafe { _mm_loadu_si128(t.row.as_ptr().add(k) as *const __m128i) };
                let a = _mm_set1_epi8(t.a as i8);
                let d = _mm_or_si128(_mm_subs_epu8(a, b), _mm_subs_epu8(b, a));
                g = _mm256_add_epi16(g, _mm256_cvtepu8_epi16(d));
            }
            from = end;
            for (i, sum) in sums[..nb].iter_mut().enumerate() {
                if held & (1 << i) != 0 {
                    *sum = _mm256_add_epi16(*sum, g);
                }
            }
        }
        for (costs, sum) in blocks.iter_mut().zip(&sums) {
            // SAFETY: k + 16 ≤ n ≤ costs.len().
            unsafe { _mm256_storeu_si256(costs.as_mut_ptr().add(k) as *mut __m256i, *sum) };
        }
        if k + 16 == n {
            return;
        }
        k = (k + 16).min(n - 16);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A textured pair whose right image is the left shifted by `disparity(u, v)` (a smooth
    /// surface), with a step to the background at column `step` where asked.
    fn pair(w: usize, h: usize, disparity: impl Fn(f32, f32) -> f32) -> (GrayImage, GrayImage) {
        let texture = |x: f32, y: f32| {
            (128.0
                + 60.0 * (x * 0.31).sin() * (y * 0.23).cos()
                + 40.0 * ((x * 0.11 + y * 0.17).sin() > 0.2) as u8 as f32) as u8
        };
        let left = GrayImage::from_fn(w, h, |u, v| texture(u as f32, v as f32));
        let right = GrayImage::from_fn(w, h, |u, v| {
            // The right pixel u shows the left pixel u + d (d at that left pixel, by a few fixed
            // point steps: d varies slowly).
            let (uf, vf) = (u as f32, v as f32);
            let mut x = uf;
            for _ in 0..5 {
                x = uf + disparity(x, vf);
            }
            texture(x, vf)
        });
        (left, right)
    }

    #[test]
    fn finds_the_disparity_of_a_slanted_plane() {
        let disparity = |u: f32, _v: f32| 6.0 + 0.04 * u;
        let (left, right) = pair(200, 60, disparity);
        let params = SparseParams {
            max_disparity: 32,
            ..SparseParams::default()
        };
        let (mut errors, mut missed) = (Vec::new(), 0);
        for u in (40..190).step_by(3) {
            for v in [10, 30, 49] {
                match point_block_disparity(&left, &right, u, v, &params) {
                    Some(d) => errors.push((d - disparity(u as f32, v as f32)).abs()),
                    None => missed += 1,
                }
            }
        }
        let worst = errors.iter().cloned().fold(0.0, f32::max);
        assert!(worst < 0.5, "worst error {worst} px");
        assert!(
            missed * 20 < errors.len(),
            "{missed} missed, {} measured",
            errors.len()
        );
    }

    #[test]
    fn refuses_points_on_a_depth_step_and_at_borders() {
        // Foreground (12 px) left of column 100, a differently textured background (4 px) right
        // of it and behind it: the right camera sees the foreground at u < 88, then the
        // background, columns 92–99 of which the left camera does not see.
        let disparity = |u: f32, _v: f32| if u < 100.0 { 12.0 } else { 4.0 };
        let fore = |x: f32, y: f32| 128.0 + 60.0 * (x * 0.31).sin() * (y * 0.23).cos();
        let back = |x: f32, y: f32| 120.0 + 50.0 * (x * 0.47 + 1.0).cos() * (y * 0.19 + 0.5).sin();
        let left = GrayImage::from_fn(200, 60, |u, v| {
            let (x, y) = (u as f32, v as f32);
            (if u < 100 { fore(x, y) } else { back(x, y) }) as u8
        });
        let right = GrayImage::from_fn(200, 60, |u, v| {
            let (x, y) = (u as f32, v as f32);
            (if u < 88 {
                fore(x + 12.0, y)
            } else {
                back(x + 4.0, y)
            }) as u8
        });
        let params = SparseParams {
            max_disparity: 32,
            ..SparseParams::default()
        };
        // Near the step a block mixes the two surfaces: what is measured there is one of them.
        let mut refused = 0;
        for u in 90..=110 {
            match point_block_disparity(&left, &right, u, 30, &params) {
                Some(d) => {
                    let truth = disparity(u as f32, 30.0);
                    assert!((d - truth).abs() < 0.5, "column {u}: {d} for {truth}");
                }
                None => refused += 1,
            }
        }
        assert!(refused >= 3, "{refused} refused at the step");
        let far = point_block_disparity(&left, &right, 150, 30, &params).unwrap();
        assert!((far - 4.0).abs() < 0.25, "{far}");
        let near = point_block_disparity(&left, &right, 60, 30, &params).unwrap();
        assert!((near - 12.0).abs() < 0.25, "{near}");
        // Blocks leaving the image; a range cut short by the border with its best at the cut.
        assert_eq!(point_block_disparity(&left, &right, 3, 30, &params), None);
        assert_eq!(point_block_disparity(&left, &right, 60, 2, &params), None);
        assert_eq!(point_block_disparity(&left, &right, 16, 30, &params), None);
    }

    #[test]
    fn avx2_and_scalar_agree() {
        let (left, right) = pair(240, 50, |u, v| 5.0 + 0.05 * u + 0.02 * v);
        let params = SparseParams {
            max_disparity: 40,
            ..SparseParams::default()
        };
        let all = || -> Vec<Option<f32>> {
            (10..230)
                .flat_map(|u| {
                    [8, 25, 41].map(|v| point_block_disparity(&left, &right, u, v, &params))
                })
                .collect()
        };
        let (fast, slow) = (all(), simd::scalar_only(all));
        assert_eq!(fast, slow);
        assert!(fast.iter().filter(|d| d.is_some()).count() > 400);
    }
}
