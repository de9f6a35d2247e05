//! Stereo block matching on rectified pairs (thesis §6.3: disparity `d = u_l − u_r` per left
//! pixel) and depth-to-disparity conversion for RGB-D cameras.
//!
//! Matching cost: the Hamming distance between census transforms (Zabih & Woodfill 1994) of a
//! `(2c+1)²` neighbourhood, robust to gain and bias differences between the cameras, summed
//! over a `(2r+1)²` block, optionally with shiftable blocks (a min filter over the aggregated
//! costs). Winner-takes-all (optionally with a uniqueness test), parabolic sub-pixel refinement,
//! a left-right consistency check and a 3×3 median.
//!
//! [`StereoMatcher`] keeps its buffers between calls (the live system holds one per run);
//! [`block_match`] makes one for a single pair. How the matcher streams the rows: `matcher.rs`.

#[cfg(target_arch = "x86_64")]
mod avx2;
#[cfg(target_arch = "x86_64")]
mod avx512;
mod matcher;
mod median;
mod row;
pub mod sparse;

pub use matcher::{StereoMatcher, block_match};
pub use sparse::{SparseParams, point_block_disparity};

use crate::image::{GrayImage, Image, ImageError};
use crate::patch::{refine_along_row, template_with_gradient};

/// The disparity of one point of the left image at `(u, v)`: its 8×8 patch
/// ([`crate::patch`]) aligned along the same row of the right image, starting from disparity
/// `start` (the block matcher's, say). The support is the point's own patch rather than the
/// block matcher's 15×15 (a 7×7 census over 9×9 blocks), which at a corner on an object's
/// boundary takes in the surface behind it. `None` where the patch leaves either image, has no
/// horizontal gradient, or does not align within `max_step` pixels of `start`.
pub fn point_disparity(
    left: &GrayImage,
    right: &GrayImage,
    u: f32,
    v: f32,
    start: f32,
    max_step: f32,
) -> Option<f32> {
    /// Gauss-Newton steps: the start is within a pixel, where a few steps converge.
    const ITERATIONS: usize = 10;
    let template = template_with_gradient(left, u, v, &nalgebra::Matrix2::identity())?;
    let u_r = refine_along_row(&template, right, [u - start, v], ITERATIONS, max_step)?;
    Some(u - u_r)
}

/// Parameters of [`block_match`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StereoParams {
    /// Disparities `0 ..= max_disparity` are searched (at most 65535, and at most `w − 1`).
    pub max_disparity: usize,
    /// Aggregation block radius `r`: the block is `(2r+1)²` pixels.
    pub block_radius: usize,
    /// Census neighbourhood radius `c` (`(2c+1)² − 1 ≤ 64` bits, so `c ≤ 3`).
    pub census_radius: usize,
    /// A match is kept only if the best cost `C₁` and the best cost `C₂` outside `d ± 1` satisfy
    /// `C₁·(1 + uniqueness) < C₂`.
    pub uniqueness: f32,
    /// Maximum difference (pixels) between the left disparity and the right disparity at the
    /// matched pixel (left-right consistency); negative disables the check.
    pub max_lr_difference: f32,
    /// Apply a 3×3 median filter to the valid disparities (removes isolated outliers; a pixel
    /// stays invalid if fewer than 5 of its 9 neighbours are valid).
    pub median_filter: bool,
    /// Shiftable windows (Scharstein & Szeliski 2002, "shiftable windows"): each pixel takes the
    /// lowest cost of the blocks shifted by up to this many pixels in `u` and `v` (0 = centred
    /// blocks only). Reduces foreground fattening at depth discontinuities.
    pub shift_radius: usize,
}

impl Default for StereoParams {
    /// 64 disparities, 9×9 blocks, 7×7 census, no uniqueness test, 1 px left-right tolerance
    /// (the usual SGM/BM choice), 3×3 median, blocks shiftable by half the block radius (2 px,
    /// so the pixel stays in the inner half of its block).
    ///
    /// The left-right check is the outlier test; a uniqueness ratio on top (e.g. 10 %) removed
    /// more correct than wrong matches on all three Middlebury pairs (tsukuba, venus, teddy,
    /// bad-pixel rate with unmatched pixels counted as bad), so it is off by default.
    fn default() -> Self {
        Self {
            max_disparity: 64,
            block_radius: 4,
            census_radius: 3,
            uniqueness: 0.0,
            max_lr_difference: 1.0,
            median_filter: true,
            shift_radius: 2,
        }
    }
}

/// Census transform: bit `k` of pixel `p` is set iff the `k`-th neighbour (row-major over the
/// `(2c+1)²` window, centre excluded) is darker than `p`. Neighbours outside the image are
/// clamped to the border.
pub fn census_transform(img: &GrayImage, radius: usize) -> Image<u64> {
    let c = radius.min(3);
    Image::from_fn(img.width(), img.height(), |u, v| census_pixel(img, u, v, c))
}

/// One word of [`census_transform`] (`c ≤ 3`).
#[inline]
fn census_pixel(img: &GrayImage, u: usize, v: usize, c: usize) -> u64 {
    let (w, h) = (img.width() as i64, img.height() as i64);
    let r = c as i64;
    let centre = img.get(u, v);
    let mut bits = 0u64;
    let mut k = 0;
    for dv in -r..=r {
        let row = img.row((v as i64 + dv).clamp(0, h - 1) as usize);
        for du in -r..=r {
            if du == 0 && dv == 0 {
                continue;
            }
            let xx = (u as i64 + du).clamp(0, w - 1) as usize;
            bits |= ((row[xx] < centre) as u64) << k;
            k += 1;
        }
    }
    bits
}

/// The pair's size, checked: both images the same size and at least one block.
fn check_pair(
    left: &GrayImage,
    right: &GrayImage,
    params: &StereoParams,
) -> Result<(usize, usize), ImageError> {
    if left.width() != right.width() || left.height() != right.height() {
        return Err(ImageError::SizeMismatch(
            left.width(),
            left.height(),
            right.width(),
            right.height(),
        ));
    }
    let (w, h) = (left.width(), left.height());
    let br = params.block_radius;
    if w < 2 * br + 2 || h < 2 * br + 1 {
        return Err(ImageError::TooSmall {
            width: w,
            height: h,
            what: format!("stereo block matching with {0}×{0} blocks", 2 * br + 1),
        });
    }
    Ok((w, h))
}

/// Converts a depth image (e.g. 16-bit millimetres) to a disparity image of a virtual stereo
/// camera (thesis §6.3): `d = f·b/(s·D)` with depth scale `s` (metres per unit, 0.001 for mm),
/// focal length `f` (pixels) and virtual baseline `b` (metres). Depth 0 and values ≥
/// `max_valid_raw` (e.g. 65535, the 7-Scenes "invalid" code) give `NaN`.
pub fn depth_to_disparity(
    depth: &Image<u16>,
    depth_scale: f64,
    focal: f64,
    baseline: f64,
    max_valid_raw: u16,
) -> Image<f32> {
    depth.map(|d| {
        if d == 0 || d >= max_valid_raw {
            f32::NAN
        } else {
            (focal * baseline / (depth_scale * d as f64)) as f32
        }
    })
}

/// Converts a disparity image back to depth in metres: `D = f·b/d`; invalid or non-positive
/// disparities give `NaN`.
pub fn disparity_to_depth(disparity: &Image<f32>, focal: f64, baseline: f64) -> Image<f32> {
    disparity.map(|d| {
        if d.is_finite() && d > 0.0 {
            (focal * baseline / d as f64) as f32
        } else {
            f32::NAN
        }
    })
}

#[cfg(test)]
mod tests {
    use super::median::{SORT9, median3_valid, median3_valid_slow};
    use super::*;
    use reference::block_match_reference;

    #[test]
    fn the_nine_element_network_sorts() {
        for bits in 0u32..512 {
            let mut p: [u32; 9] = std::array::from_fn(|i| (bits >> i) & 1);
            for (a, b) in SORT9 {
                let (x, y) = (p[a], p[b]);
                p[a] = x.min(y);
                p[b] = x.max(y);
            }
            assert!(p.windows(2).all(|w| w[0] <= w[1]), "{bits:09b} → {p:?}");
        }
    }

    mod reference {
        use super::super::median::median3_valid_slow;
        use super::super::*;

        /// The first implementation of [`block_match`], kept as the reference of the streaming one:
        /// full `h·w·D` cost and aggregate volumes, one step after the other. Same results.
        pub(crate) fn block_match_reference(
            left: &GrayImage,
            right: &GrayImage,
            params: &StereoParams,
        ) -> Result<Image<f32>, ImageError> {
            let (w, h) = check_pair(left, right, params)?;
            let br = params.block_radius;
            let nd = params.max_disparity.min(w - 1) + 1;
            let cl = census_transform(left, params.census_radius);
            let cr = census_transform(right, params.census_radius);
            const INVALID_COST: u8 = 64;
            // Per-pixel costs, [y][x][d].
            let mut cost = vec![INVALID_COST; h * w * nd];
            for y in 0..h {
                let (lr, rr) = (cl.row(y), cr.row(y));
                for x in 0..w {
                    let c = &mut cost[(y * w + x) * nd..(y * w + x + 1) * nd];
                    let l = lr[x];
                    for (d, cd) in c.iter_mut().enumerate().take(x + 1) {
                        *cd = (l ^ rr[x - d]).count_ones() as u8;
                    }
                }
            }
            // Vertical box sums (clamped rows), then horizontal sums, row by row.
            let mut vsum = vec![0u16; w * nd];
            let row_slice = |y: i64| -> &[u8] {
                let yy = y.clamp(0, h as i64 - 1) as usize;
                &cost[yy * w * nd..(yy + 1) * w * nd]
            };
            for dy in -(br as i64)..=br as i64 {
                for (s, &c) in vsum.iter_mut().zip(row_slice(dy)) {
                    *s += c as u16;
                }
            }
            // Aggregated costs of every row, [y][x][d].
            let mut aggv = vec![0u16; h * w * nd];
            let mut disp = Image::<f32>::filled(w, h, f32::NAN);
            let mut right_best = vec![0usize; w];
            let mut right_cost = vec![u32::MAX; w];
            for y in 0..h {
                if y > 0 {
                    let add = row_slice(y as i64 + br as i64);
                    let sub = row_slice(y as i64 - br as i64 - 1);
                    for ((s, &a), &b) in vsum.iter_mut().zip(add).zip(sub) {
                        *s = *s + a as u16 - b as u16;
                    }
                }
                let agg = &mut aggv[y * w * nd..(y + 1) * w * nd];
                // Horizontal sums with clamped columns.
                let col = |x: i64| -> &[u16] {
                    let xx = x.clamp(0, w as i64 - 1) as usize;
                    &vsum[xx * nd..(xx + 1) * nd]
                };
                {
                    let a0 = &mut agg[0..nd];
                    a0.iter_mut().for_each(|a| *a = 0);
                    for dx in -(br as i64)..=br as i64 {
                        for (a, &s) in a0.iter_mut().zip(col(dx)) {
                            *a += s;
                        }
                    }
                }
                for x in 1..w {
                    let (prev, cur) = agg.split_at_mut(x * nd);
                    let prev = &prev[(x - 1) * nd..];
                    let cur = &mut cur[..nd];
                    let add = col(x as i64 + br as i64);
                    let sub = col(x as i64 - br as i64 - 1);
                    for d in 0..nd {
                        cur[d] = prev[d] + add[d] - sub[d];
                    }
                }
            }
            // Shiftable windows: the cost of a pixel is the best of the blocks shifted by up to
            // `shift` pixels around it (a min filter over the aggregated costs), which keeps a block
            // from straddling a depth discontinuity when a neighbouring block does not.
            let sr = params.shift_radius;
            if sr > 0 {
                let mut tmp = vec![0u16; w * nd];
                for y in 0..h {
                    let row = &mut aggv[y * w * nd..(y + 1) * w * nd];
                    for x in 0..w {
                        let (x0, x1) = (x.saturating_sub(sr), (x + sr).min(w - 1));
                        let t = &mut tmp[x * nd..(x + 1) * nd];
                        t.copy_from_slice(&row[x0 * nd..(x0 + 1) * nd]);
                        for xx in x0 + 1..=x1 {
                            for (a, &b) in t.iter_mut().zip(&row[xx * nd..(xx + 1) * nd]) {
                                *a = (*a).min(b);
                            }
                        }
                    }
                    row.copy_from_slice(&tmp);
                }
            }
            let mut vmin = vec![0u16; w * nd];
            for y in 0..h {
                let agg: &[u16] = if sr > 0 {
                    let (y0, y1) = (y.saturating_sub(sr), (y + sr).min(h - 1));
                    vmin.copy_from_slice(&aggv[y0 * w * nd..(y0 + 1) * w * nd]);
                    for yy in y0 + 1..=y1 {
                        for (a, &b) in vmin.iter_mut().zip(&aggv[yy * w * nd..(yy + 1) * w * nd]) {
                            *a = (*a).min(b);
                        }
                    }
                    &vmin
                } else {
                    &aggv[y * w * nd..(y + 1) * w * nd]
                };
                // Right-image winners for the left-right check: d_R(x_r) = argmin_d agg(x_r + d, d).
                right_best.iter_mut().for_each(|b| *b = 0);
                right_cost.iter_mut().for_each(|c| *c = u32::MAX);
                for x in 0..w {
                    let a = &agg[x * nd..(x + 1) * nd];
                    for (d, &c) in a.iter().enumerate().take(x + 1) {
                        let xr = x - d;
                        if (c as u32) < right_cost[xr] {
                            right_cost[xr] = c as u32;
                            right_best[xr] = d;
                        }
                    }
                }
                let out = disp.row_mut(y);
                for x in 0..w {
                    // Only disparities whose whole right block lies inside the image.
                    let dmax = (x.saturating_sub(br)).min(nd - 1);
                    if x < br {
                        continue;
                    }
                    let a = &agg[x * nd..(x + 1) * nd];
                    let (mut best, mut bd) = (u16::MAX, 0usize);
                    for (d, &c) in a.iter().enumerate().take(dmax + 1) {
                        if c < best {
                            best = c;
                            bd = d;
                        }
                    }
                    let mut second = u16::MAX;
                    for (d, &c) in a.iter().enumerate().take(dmax + 1) {
                        if (d + 1 < bd || d > bd + 1) && c < second {
                            second = c;
                        }
                    }
                    if params.uniqueness > 0.0
                        && second != u16::MAX
                        && (best as f32) * (1.0 + params.uniqueness) >= second as f32
                    {
                        continue;
                    }
                    let mut dsub = bd as f32;
                    if bd > 0 && bd < dmax {
                        let (c0, c1, c2) = (a[bd - 1] as f32, best as f32, a[bd + 1] as f32);
                        let den = c0 - 2.0 * c1 + c2;
                        if den > 0.0 {
                            dsub += ((c0 - c2) / (2.0 * den)).clamp(-0.5, 0.5);
                        }
                    }
                    if params.max_lr_difference >= 0.0 {
                        let xr = x - bd;
                        if (right_best[xr] as f32 - bd as f32).abs() > params.max_lr_difference {
                            continue;
                        }
                    }
                    out[x] = dsub;
                }
            }
            if params.median_filter {
                disp = median3_valid_slow(&disp);
            }
            Ok(disp)
        }
    }

    fn random_texture(w: usize, h: usize, seed: u64) -> GrayImage {
        let mut x = seed;
        let noise = GrayImage::from_fn(w, h, |_, _| {
            x = x
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (x >> 56) as u8
        });
        crate::pyramid::gaussian_blur(&noise, 0.8)
    }

    /// A `w × h` rectified pair of a slanted textured plane: disparity `⌊u·slope/w⌋` (0 at the
    /// left edge, just under `slope` at the right), both images crops of a texture `pad`
    /// (> `slope`) pixels wider.
    fn slanted_pair(
        w: usize,
        h: usize,
        seed: u64,
        pad: usize,
        slope: usize,
    ) -> (GrayImage, GrayImage) {
        let texture = random_texture(w + pad, h, seed);
        let left = GrayImage::from_fn(w, h, |u, v| texture.get(u + (u * slope / w), v));
        let right = GrayImage::from_fn(w, h, |u, v| texture.get(u, v));
        (left, right)
    }

    #[test]
    fn recovers_constant_disparity() {
        let right = random_texture(120, 60, 1);
        let d = 7usize;
        // left(x) = right(x − d): a fronto-parallel plane at disparity 7.
        let left = GrayImage::from_fn(120, 60, |u, v| right.get(u.saturating_sub(d), v));
        let disp = block_match(
            &left,
            &right,
            &StereoParams {
                max_disparity: 16,
                ..Default::default()
            },
        )
        .unwrap();
        let mut good = 0;
        let mut total = 0;
        for v in 5..55 {
            for u in 20..115 {
                total += 1;
                let x = disp.get(u, v);
                if x.is_finite() && (x - 7.0).abs() < 0.5 {
                    good += 1;
                }
            }
        }
        assert!(good as f64 > 0.95 * total as f64, "{good}/{total}");
    }

    /// Matching in horizontal bands on threads gives the whole image's disparities bit for
    /// bit (NaNs included): every band sees the rows its disparities depend on. Several
    /// parameter sets (margins 3 to 10 rows), band counts that do and do not divide the height,
    /// more bands than the image has room for, and a second call reusing the bands' buffers.
    #[test]
    fn matching_in_bands_equals_the_whole_image() {
        for (seed, (w, h, nd, br, sr, cr, median)) in [
            (160, 97, 32, 4, 2, 3, true),
            (100, 290, 24, 4, 2, 3, true),
            (120, 64, 16, 2, 0, 3, true),
            (90, 50, 20, 3, 1, 1, false),
            (70, 23, 8, 4, 2, 3, true),
        ]
        .into_iter()
        .enumerate()
        {
            let (left, right) = slanted_pair(w, h, 10 + seed as u64, 4, 4);
            let params = StereoParams {
                max_disparity: nd,
                block_radius: br,
                shift_radius: sr,
                census_radius: cr,
                median_filter: median,
                ..StereoParams::default()
            };
            let want = block_match(&left, &right, &params).unwrap();
            let bits = |d: &Image<f32>| -> Vec<u32> {
                (0..h)
                    .flat_map(|y| d.row(y).iter().map(|x| x.to_bits()).collect::<Vec<_>>())
                    .collect()
            };
            let mut matcher = StereoMatcher::new(params);
            for bands in [1, 2, 3, 4, 7, 50, 3] {
                let got = matcher.compute_in_bands(&left, &right, bands).unwrap();
                assert_eq!(bits(&got), bits(&want), "{w}×{h}, {bands} bands");
            }
        }
    }

    #[test]
    fn streaming_simd_and_scalar_equal_the_reference() {
        // (w, h, max disparity, block radius, shift radius, census radius, uniqueness,
        // left-right tolerance, median): padded and unpadded disparity ranges (nd = 16·k + 1
        // pads 15 lanes; 16 disparities, two pixels per cost vector, with and without padding),
        // ranges wider than the image, images narrower than one census step (32), every census
        // radius, shift radius 0 … 3, the uniqueness test, no left-right check, no median.
        let cases = [
            (40, 20, 16, 4, 2, 3, 0.0, 1.0, true),
            (57, 31, 33, 2, 0, 3, 0.1, 1.0, true),
            (13, 11, 100, 2, 1, 3, 0.0, 1.0, true),
            (80, 25, 64, 3, 3, 3, 0.0, 1.0, true),
            (23, 9, 5, 4, 2, 3, 0.0, 1.0, true),
            (97, 40, 31, 4, 2, 2, 0.0, 1.0, true),
            (70, 30, 47, 3, 1, 1, 0.0, -1.0, true),
            (64, 33, 128, 4, 2, 3, 0.0, 1.0, false),
            (129, 37, 48, 4, 2, 0, 0.0, 2.0, true),
            (150, 45, 79, 2, 2, 3, 0.05, 0.0, true),
            (71, 30, 15, 4, 2, 3, 0.0, 1.0, true),
            (66, 24, 11, 3, 2, 3, 0.0, 1.0, true),
            (90, 20, 40, 1, 2, 3, 0.0, 1.0, true),
            (60, 26, 20, 0, 0, 3, 0.0, 1.0, true),
            // Shapes of the AVX-512 interior kernels (an even number of 16-lane chunks, the
            // fused costs in 64-lane groups and a 32-lane one), wide enough for an interior.
            (300, 40, 63, 4, 2, 3, 0.0, 1.0, true),
            (330, 30, 95, 4, 2, 3, 0.0, 1.0, true),
            (400, 30, 118, 4, 2, 3, 0.0, 1.0, true),
            (150, 30, 30, 4, 1, 3, 0.0, 1.0, true),
            (200, 30, 61, 2, 0, 3, 0.1, 1.0, true),
            (260, 20, 90, 3, 2, 2, 0.0, 1.0, true),
        ];
        for (seed, (w, h, nd, br, sr, cr, uniq, lr, median)) in cases.into_iter().enumerate() {
            let (left, right) = slanted_pair(w, h, seed as u64, 5, 3);
            let params = StereoParams {
                max_disparity: nd,
                block_radius: br,
                shift_radius: sr,
                census_radius: cr,
                uniqueness: uniq,
                max_lr_difference: lr,
                median_filter: median,
            };
            let want = block_match_reference(&left, &right, &params).unwrap();
            let fast = block_match(&left, &right, &params).unwrap();
            let scalar = crate::simd::scalar_only(|| block_match(&left, &right, &params)).unwrap();
            let avx2 = crate::simd::without_avx512(|| block_match(&left, &right, &params)).unwrap();
            let bits = |i: &Image<f32>| i.data().iter().map(|x| x.to_bits()).collect::<Vec<_>>();
            assert_eq!(bits(&fast), bits(&want), "case {seed}");
            assert_eq!(bits(&scalar), bits(&want), "case {seed}");
            assert_eq!(bits(&avx2), bits(&want), "case {seed}");
            assert!(want.data().iter().any(|x| x.is_finite()), "case {seed}");
        }
    }

    #[test]
    fn a_kept_matcher_gives_the_same_results() {
        // One matcher over pairs of two sizes and back (its buffers re-made on a size change,
        // kept otherwise), against fresh ones.
        let mut matcher = StereoMatcher::new(StereoParams {
            max_disparity: 24,
            ..Default::default()
        });
        let pair = |w: usize, h: usize, seed: u64| {
            let r = random_texture(w + 4, h, seed);
            (
                GrayImage::from_fn(w, h, |u, v| r.get(u + 4, v)),
                GrayImage::from_fn(w, h, |u, v| r.get(u, v)),
            )
        };
        for (w, h, seed) in [(60, 30, 1), (60, 30, 2), (75, 28, 3), (60, 30, 4)] {
            let (l, r) = pair(w, h, seed);
            let kept = matcher.compute(&l, &r).unwrap();
            let fresh = block_match(&l, &r, matcher.params()).unwrap();
            let bits = |i: &Image<f32>| i.data().iter().map(|x| x.to_bits()).collect::<Vec<_>>();
            assert_eq!(bits(&kept), bits(&fresh), "{w}×{h} seed {seed}");
        }
    }

    #[test]
    fn fast_median_equals_the_sorting_one() {
        let mut x = 5u64;
        let mut next = || {
            x = x
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (x >> 40) as u32
        };
        for (w, h) in [(1, 1), (2, 5), (3, 3), (17, 9), (40, 12)] {
            let img = Image::<f32>::from_fn(w, h, |_, _| match next() % 10 {
                0 | 1 => f32::NAN,
                2 => -0.0,
                3 => 0.0,
                5 => f32::INFINITY,
                k => (next() % 64) as f32 * 0.25 - if k == 4 { 3.0 } else { 0.0 },
            });
            let bits = |i: &Image<f32>| i.data().iter().map(|x| x.to_bits()).collect::<Vec<_>>();
            assert_eq!(
                bits(&median3_valid(&img)),
                bits(&median3_valid_slow(&img)),
                "{w}×{h}"
            );
        }
    }

    #[test]
    fn rejects_bad_sizes() {
        let a = GrayImage::new(10, 10);
        let b = GrayImage::new(11, 10);
        assert!(block_match(&a, &b, &StereoParams::default()).is_err());
        let t = GrayImage::new(1, 1);
        assert!(block_match(&t, &t, &StereoParams::default()).is_err());
        // Odd sizes and disparity ranges wider than the image work.
        let o = random_texture(13, 11, 3);
        let r = block_match(
            &o,
            &o,
            &StereoParams {
                max_disparity: 100,
                block_radius: 2,
                ..Default::default()
            },
        )
        .unwrap();
        assert_eq!((r.width(), r.height()), (13, 11));
    }

    #[test]
    fn depth_disparity_round_trip() {
        let depth = Image::<u16>::from_vec(3, 1, 3, vec![0, 1500, 65535]).unwrap();
        let d = depth_to_disparity(&depth, 0.001, 585.0, 0.075, 65535);
        assert!(d.get(0, 0).is_nan() && d.get(2, 0).is_nan());
        assert!((d.get(1, 0) - (585.0 * 0.075 / 1.5) as f32).abs() < 1e-4);
        let back = disparity_to_depth(&d, 585.0, 0.075);
        assert!((back.get(1, 0) - 1.5).abs() < 1e-5);
    }
}
