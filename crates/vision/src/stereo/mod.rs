//! Stereo block matching on rectified pairs (thesis §6.3: disparity `d = u_l − u_r` per left
//! pixel) and depth-to-disparity conversion for RGB-D cameras.
//!
//! Matching cost: the Hamming distance between census transforms (Zabih & Woodfill 1994) of a
//! `(2c+1)²` neighbourhood, robust to gain and bias differences between the cameras, summed
//! over a `(2r+1)²` block, optionally with shiftable blocks (a min filter over the aggregated
//! costs). Winner-takes-all (optionally with a uniqueness test), parabolic sub-pixel refinement,
//! a left-right consistency check and a 3×3 median.

use crate::image::{GrayImage, Image, ImageError};

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
    let (w, h) = (img.width() as i64, img.height() as i64);
    let r = radius.min(3) as i64;
    Image::from_fn(img.width(), img.height(), |u, v| {
        let c = img.get(u, v);
        let mut bits = 0u64;
        let mut k = 0;
        for dv in -r..=r {
            let yy = (v as i64 + dv).clamp(0, h - 1) as usize;
            let row = img.row(yy);
            for du in -r..=r {
                if du == 0 && dv == 0 {
                    continue;
                }
                let xx = (u as i64 + du).clamp(0, w - 1) as usize;
                bits |= ((row[xx] < c) as u64) << k;
                k += 1;
            }
        }
        bits
    })
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

/// Computes the left disparity image of a rectified pair (`u_r = u_l − d`); invalid pixels
/// (no unique match, failed left-right check, or no candidate) are `NaN`.
///
/// Row-streaming implementation: pixel costs of the `2r + 2` rows a vertical box sum needs are
/// kept in a ring, the block sums are updated incrementally (`+` the entering row / column, `−`
/// the leaving one), the shiftable-window minima of `2s + 1` rows in a second ring, so memory
/// is `O(w·D·(r + s))` instead of `O(h·w·D)`. All costs are integers, so the result does not
/// depend on the order of the sums: it equals the straightforward volume-based computation
/// bit for bit (tested). Census and Hamming costs have AVX2 kernels (runtime dispatch) beside
/// their scalar references.
///
/// Errors if the images differ in size or are smaller than one block.
pub fn block_match(
    left: &GrayImage,
    right: &GrayImage,
    params: &StereoParams,
) -> Result<Image<f32>, ImageError> {
    check_pair(left, right, params)?;
    #[cfg(target_arch = "x86_64")]
    if crate::simd::avx2() {
        // SAFETY: the CPU supports AVX2 (checked just above).
        return Ok(unsafe { stream_avx2(left, right, params) });
    }
    Ok(stream::<false>(left, right, params))
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn stream_avx2(left: &GrayImage, right: &GrayImage, params: &StereoParams) -> Image<f32> {
    stream::<true>(left, right, params)
}

/// Census in the matcher's internal layout: bit `8·(dv + c) + (du + c)` is set iff neighbour
/// `(du, dv)` is darker than the centre (borders clamped), bits of the centre and of column
/// `du = c + 1…` unused (zero). The Hamming distance between two such words equals that of
/// [`census_transform`]'s packed words (the same bits, placed differently), which lets the
/// AVX2 kernel build a word from two byte-compare masks.
#[inline(always)]
fn census_spread_row<const AVX2: bool>(img: &GrayImage, radius: usize, v: usize, o: &mut [u64]) {
    let (w, h) = (img.width(), img.height());
    let c = radius.min(3);
    // Interior rows and columns with an 8-byte load per window row (x − 3 … x + 4) for c = 3.
    let simd_ok = AVX2 && c == 3 && w >= 8 && h >= 7;
    let interior_row = v >= 3 && v + 3 < h;
    let (x0, x1) = if simd_ok && interior_row {
        (3, w - 4)
    } else {
        (0, 0)
    };
    #[cfg(target_arch = "x86_64")]
    if x1 > x0 {
        // SAFETY: AVX2 instances run after `simd::avx2()`; rows v − 3 … v + 3 exist and
        // columns x − 3 … x + 4 lie in 0..w for x in 3..w − 4.
        unsafe { census_row_avx2(img, v, x0, x1, o) };
    }
    for (x, word) in o.iter_mut().enumerate() {
        if x >= x0 && x < x1 {
            continue;
        }
        *word = census_spread_pixel(img, x, v, c);
    }
}

/// The scalar reference of one [`census_spread_row`] word.
#[inline(always)]
fn census_spread_pixel(img: &GrayImage, u: usize, v: usize, c: usize) -> u64 {
    let (w, h) = (img.width() as i64, img.height() as i64);
    let r = c as i64;
    let centre = img.get(u, v);
    let mut bits = 0u64;
    for dv in -r..=r {
        let row = img.row((v as i64 + dv).clamp(0, h - 1) as usize);
        for du in -r..=r {
            if du == 0 && dv == 0 {
                continue;
            }
            let p = row[(u as i64 + du).clamp(0, w - 1) as usize];
            bits |= ((p < centre) as u64) << (8 * (dv + r) + (du + r));
        }
    }
    bits
}

/// AVX2 census of row `v`, columns `x0..x1` (radius 3): the 7 window rows' 8-byte loads in two
/// vectors, one signed compare against the broadcast centre (after flipping the top bit), two
/// `movemask`s; column 7 and the centre bit masked off.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn census_row_avx2(img: &GrayImage, v: usize, x0: usize, x1: usize, out: &mut [u64]) {
    use std::arch::x86_64::*;
    const KEEP: u64 = 0x007f_7f7f_777f_7f7f;
    let st = img.stride();
    let data = img.data();
    // SAFETY: see the caller; every 8-byte load starts at (v + dv)·st + x − 3 with dv ∈ −3..=3
    // and reads up to column x + 4 < w.
    unsafe {
        let flip = _mm256_set1_epi8(i8::MIN);
        for x in x0..x1 {
            let at = |dv: isize| {
                let i = ((v as isize + dv) * st as isize + x as isize - 3) as usize;
                (data.as_ptr().add(i) as *const i64).read_unaligned()
            };
            let a = _mm256_set_epi64x(at(0), at(-1), at(-2), at(-3));
            let b = _mm256_set_epi64x(0, at(3), at(2), at(1));
            let centre = _mm256_set1_epi8((data[v * st + x] ^ 0x80) as i8);
            let ma = _mm256_movemask_epi8(_mm256_cmpgt_epi8(centre, _mm256_xor_si256(a, flip)));
            let mb = _mm256_movemask_epi8(_mm256_cmpgt_epi8(centre, _mm256_xor_si256(b, flip)));
            out[x] = ((ma as u32 as u64) | ((mb as u32 as u64) << 32)) & KEEP;
        }
    }
}

/// Pixel costs of one row, `[x][d]` (`nd` per pixel): `popcount(L(x) ⊕ R(x − d))` for `d ≤ x`,
/// `INVALID_COST` for `d > x`. `rev` is the right census row reversed (`rev[w−1−x] = R(x)`) and
/// padded with `nd` zeros, so that `R(x − d) = rev[w − 1 − x + d]` is contiguous in `d`.
#[inline(always)]
fn cost_row<const AVX2: bool>(lrow: &[u64], rev: &[u64], nd: usize, out: &mut [u8]) {
    let w = lrow.len();
    let mut done = 0;
    #[cfg(target_arch = "x86_64")]
    if AVX2 {
        // SAFETY: AVX2 instances run after `simd::avx2()`; bounds in the kernel's comment.
        done = unsafe { cost_row_avx2(lrow, rev, nd, out) };
    }
    for x in 0..w {
        let l = lrow[x];
        let base = w - 1 - x;
        let o = &mut out[x * nd..(x + 1) * nd];
        for d in done..nd {
            o[d] = (l ^ rev[base + d]).count_ones() as u8;
        }
    }
    // Disparities reaching past the left border.
    for x in 0..w.min(nd) {
        out[x * nd + x + 1..(x + 1) * nd].fill(INVALID_COST);
    }
}

/// Hamming costs of [`cost_row`] for the first `nd / 16 · 16` disparities of every pixel, 16 per
/// step: XOR of four words per vector, byte popcounts by the `pshufb` nibble table, `psadbw`
/// sums per word, reordered and packed to bytes. Returns the number of disparities done per pixel.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn cost_row_avx2(lrow: &[u64], rev: &[u64], nd: usize, out: &mut [u8]) -> usize {
    use std::arch::x86_64::*;
    let w = lrow.len();
    let n16 = nd / 16 * 16;
    assert!(rev.len() >= w + nd && out.len() >= w * nd);
    // SAFETY: word loads read rev[w − 1 − x + d .. + 4] with d + 4 ≤ n16 ≤ nd, inside
    // rev[..w + nd]; stores write out[x·nd + d .. + 16] with d + 16 ≤ n16 ≤ nd.
    unsafe {
        let lut = _mm256_setr_epi8(
            0, 1, 1, 2, 1, 2, 2, 3, 1, 2, 2, 3, 2, 3, 3, 4, 0, 1, 1, 2, 1, 2, 2, 3, 1, 2, 2, 3, 2,
            3, 3, 4,
        );
        let low = _mm256_set1_epi8(0x0f);
        let zero = _mm256_setzero_si256();
        let order = _mm256_setr_epi32(0, 2, 4, 6, 1, 3, 5, 7);
        let pop4 = |l: __m256i, p: *const u64| {
            let v = _mm256_xor_si256(l, _mm256_loadu_si256(p as *const __m256i));
            let c = _mm256_add_epi8(
                _mm256_shuffle_epi8(lut, _mm256_and_si256(v, low)),
                _mm256_shuffle_epi8(lut, _mm256_and_si256(_mm256_srli_epi16::<4>(v), low)),
            );
            _mm256_sad_epu8(c, zero)
        };
        for (x, &lw) in lrow.iter().enumerate() {
            let l = _mm256_set1_epi64x(lw as i64);
            let p = rev.as_ptr().add(w - 1 - x);
            let o = out.as_mut_ptr().add(x * nd);
            let mut d = 0;
            while d < n16 {
                // Eight costs as u32 in order: [a0 b0 a1 b1 a2 b2 a3 b3] → [a0..a3 b0..b3].
                let eight = |d: usize| {
                    let (a, b) = (pop4(l, p.add(d)), pop4(l, p.add(d + 4)));
                    _mm256_permutevar8x32_epi32(
                        _mm256_or_si256(a, _mm256_slli_epi64::<32>(b)),
                        order,
                    )
                };
                let (lo, hi) = (eight(d), eight(d + 8));
                let w16 = _mm256_permute4x64_epi64::<0b11_01_10_00>(_mm256_packus_epi32(lo, hi));
                // 16 u16 → 16 bytes (costs ≤ 48).
                let b = _mm256_packus_epi16(w16, w16);
                let b = _mm256_castsi256_si128(_mm256_permute4x64_epi64::<0b00_00_10_00>(b));
                _mm_storeu_si128(o.add(d) as *mut __m128i, b);
                d += 16;
            }
        }
    }
    n16
}

const INVALID_COST: u8 = 64;

/// The streaming matcher (see [`block_match`]); `AVX2` selects the census and cost kernels, the
/// rest is plain integer code that the compiler vectorises in either instance.
#[inline(always)]
fn stream<const AVX2: bool>(
    left: &GrayImage,
    right: &GrayImage,
    params: &StereoParams,
) -> Image<f32> {
    let (w, h) = (left.width(), left.height());
    let br = params.block_radius;
    let sr = params.shift_radius;
    // (Disparities fit the low 16 bits of the packed minima of `decide_row`.)
    let nd = params.max_disparity.min(w - 1).min(u16::MAX as usize) + 1;
    let row_len = w * nd;
    // Census rows are made when their cost row is (one row of each image at a time: whole
    // census images cost page faults on every call).
    let (mut cl, mut cr) = (vec![0u64; w], vec![0u64; w]);
    // Ring of pixel-cost rows (row y in slot y mod (2r + 2)).
    let cost_slots = 2 * br + 2;
    let mut costs = vec![0u8; cost_slots * row_len];
    let mut rev = vec![0u64; w + nd];
    let mut computed = 0usize; // cost rows 0..computed are (or were) in the ring
    let mut ensure = |y: usize, costs: &mut Vec<u8>| {
        while computed <= y {
            let yy = computed;
            census_spread_row::<AVX2>(left, params.census_radius, yy, &mut cl);
            census_spread_row::<AVX2>(right, params.census_radius, yy, &mut cr);
            for (j, r) in rev[..w].iter_mut().enumerate() {
                *r = cr[w - 1 - j];
            }
            let slot = yy % cost_slots;
            cost_row::<AVX2>(
                &cl,
                &rev,
                nd,
                &mut costs[slot * row_len..(slot + 1) * row_len],
            );
            computed += 1;
        }
    };
    let crow = |y: usize| -> std::ops::Range<usize> {
        let slot = y % cost_slots;
        slot * row_len..(slot + 1) * row_len
    };
    let clamp_y = |y: i64| y.clamp(0, h as i64 - 1) as usize;
    let mut vsum = vec![0u16; row_len];
    let mut agg = vec![0u16; row_len];
    let min_slots = 2 * sr + 1;
    let mut hmin = vec![0u16; min_slots * row_len];
    let mut vmin = vec![0u16; row_len];
    let mut right_packed = vec![0u32; w];
    let mut disp = Image::<f32>::filled(w, h, f32::NAN);
    for ya in 0..h + sr {
        if ya < h {
            // Vertical box sums of row ya.
            if ya == 0 {
                ensure(br.min(h - 1), &mut costs);
                vsum.iter_mut().for_each(|s| *s = 0);
                for dy in -(br as i64)..=br as i64 {
                    let r = crow(clamp_y(dy));
                    for (s, &c) in vsum.iter_mut().zip(&costs[r]) {
                        *s += c as u16;
                    }
                }
            } else {
                let add = clamp_y(ya as i64 + br as i64);
                let sub = clamp_y(ya as i64 - br as i64 - 1);
                ensure(add, &mut costs);
                let (ra, rs) = (crow(add), crow(sub));
                for ((s, &a), &b) in vsum.iter_mut().zip(&costs[ra]).zip(&costs[rs]) {
                    *s = *s + a as u16 - b as u16;
                }
            }
            // Horizontal box sums (clamped columns), incrementally.
            let col = |x: i64| {
                let xx = x.clamp(0, w as i64 - 1) as usize;
                xx * nd..(xx + 1) * nd
            };
            agg[..nd].iter_mut().for_each(|a| *a = 0);
            for dx in -(br as i64)..=br as i64 {
                for (a, &s) in agg[..nd].iter_mut().zip(&vsum[col(dx)]) {
                    *a += s;
                }
            }
            for x in 1..w {
                let (prev, cur) = agg.split_at_mut(x * nd);
                let prev = &prev[(x - 1) * nd..];
                let add = &vsum[col(x as i64 + br as i64)];
                let sub = &vsum[col(x as i64 - br as i64 - 1)];
                for (((c, &p), &a), &s) in cur[..nd].iter_mut().zip(prev).zip(add).zip(sub) {
                    *c = p + a - s;
                }
            }
            // Horizontal minimum over shifted blocks, into the ring.
            let slot = ya % min_slots;
            let hm = &mut hmin[slot * row_len..(slot + 1) * row_len];
            if sr == 0 {
                hm.copy_from_slice(&agg);
            } else {
                for x in 0..w {
                    let (x0, x1) = (x.saturating_sub(sr), (x + sr).min(w - 1));
                    min_of_rows(
                        &mut hm[x * nd..(x + 1) * nd],
                        &agg[x0 * nd..(x1 + 1) * nd],
                        nd,
                    );
                }
            }
        }
        if ya < sr {
            continue;
        }
        // Output row y: vertical minimum over the rows y − s … y + s that exist.
        let y = ya - sr;
        let (y0, y1) = (y.saturating_sub(sr), (y + sr).min(h - 1));
        let row = |i: usize| {
            let s = (y0 + i).min(y1) % min_slots;
            &hmin[s * row_len..(s + 1) * row_len]
        };
        min_of(&mut vmin, row(0), row(1), row(2), row(3), row(4));
        for i in 5..=y1 - y0 {
            for (o, &x) in vmin.iter_mut().zip(row(i)) {
                *o = (*o).min(x);
            }
        }
        decide_row(&vmin, w, nd, params, &mut right_packed, disp.row_mut(y));
    }
    if params.median_filter {
        disp = median3_valid(&disp);
    }
    disp
}

/// `out = min` of the consecutive length-`n` rows of `src` (element-wise).
#[inline(always)]
fn min_of_rows(out: &mut [u16], src: &[u16], n: usize) {
    let k = src.len() / n;
    let r = |i: usize| &src[i * n..(i + 1) * n];
    match k {
        1 => min_of(out, r(0), r(0), r(0), r(0), r(0)),
        2 => min_of(out, r(0), r(1), r(1), r(1), r(1)),
        3 => min_of(out, r(0), r(1), r(2), r(2), r(2)),
        4 => min_of(out, r(0), r(1), r(2), r(3), r(3)),
        _ => {
            min_of(out, r(0), r(1), r(2), r(3), r(4));
            for i in 5..k {
                for (o, &x) in out.iter_mut().zip(r(i)) {
                    *o = (*o).min(x);
                }
            }
        }
    }
}

/// `out[i] = min(a[i], b[i], c[i], d[i], e[i])` in one vectorisable pass.
#[inline(always)]
fn min_of(out: &mut [u16], a: &[u16], b: &[u16], c: &[u16], d: &[u16], e: &[u16]) {
    let n = out.len();
    let (a, b, c, d, e) = (&a[..n], &b[..n], &c[..n], &d[..n], &e[..n]);
    for i in 0..n {
        out[i] = a[i].min(b[i]).min(c[i]).min(d[i]).min(e[i]);
    }
}

/// Winner-takes-all of one row of aggregated costs `[x][d]`, with the uniqueness test,
/// parabolic sub-pixel refinement and the left-right check (as [`block_match_reference`]).
/// Minima are taken over `(cost ≪ 16) | d`, which orders by cost and then by the smaller `d`:
/// the first minimum of an ascending scan, as the reference's strict comparisons keep.
#[inline(always)]
fn decide_row(
    agg: &[u16],
    w: usize,
    nd: usize,
    params: &StereoParams,
    right_packed: &mut [u32],
    out: &mut [f32],
) {
    let br = params.block_radius;
    // Right-image winners, stored reversed (index w − 1 − x_r) so that x_r = x − d is
    // contiguous in d.
    right_packed.iter_mut().for_each(|c| *c = u32::MAX);
    for x in 0..w {
        let a = &agg[x * nd..(x + 1) * nd];
        let n = (x + 1).min(nd);
        let base = w - 1 - x;
        for (d, (rp, &c)) in right_packed[base..base + n]
            .iter_mut()
            .zip(&a[..n])
            .enumerate()
        {
            *rp = (*rp).min(((c as u32) << 16) | d as u32);
        }
    }
    for x in br..w {
        let dmax = (x - br).min(nd - 1);
        let a = &agg[x * nd..(x + 1) * nd];
        let packed = a[..=dmax]
            .iter()
            .enumerate()
            .fold(u32::MAX, |m, (d, &c)| m.min(((c as u32) << 16) | d as u32));
        let (best, bd) = ((packed >> 16) as u16, (packed & 0xffff) as usize);
        if params.uniqueness > 0.0 {
            let mut second = u16::MAX;
            for (d, &c) in a.iter().enumerate().take(dmax + 1) {
                if (d + 1 < bd || d > bd + 1) && c < second {
                    second = c;
                }
            }
            if second != u16::MAX && (best as f32) * (1.0 + params.uniqueness) >= second as f32 {
                continue;
            }
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
            let right_best = (right_packed[w - 1 - xr] & 0xffff) as f32;
            if (right_best - bd as f32).abs() > params.max_lr_difference {
                continue;
            }
        }
        out[x] = dsub;
    }
}

/// A sorting network for 9 elements (25 compare-exchanges): the three rows sorted, then the
/// three columns, then the remaining inversions; checked on all 2⁹ 0-1 inputs in the tests
/// (a network sorting every 0-1 sequence sorts every sequence).
/// (`median3_valid` performs these exchanges written out, in this order.)
#[cfg_attr(not(test), allow(dead_code))]
const SORT9: [(usize, usize); 25] = [
    (0, 1),
    (3, 4),
    (6, 7),
    (1, 2),
    (4, 5),
    (7, 8),
    (0, 1),
    (3, 4),
    (6, 7),
    (0, 3),
    (3, 6),
    (0, 3),
    (1, 4),
    (4, 7),
    (1, 4),
    (2, 5),
    (5, 8),
    (2, 5),
    (1, 3),
    (5, 7),
    (2, 6),
    (4, 6),
    (2, 4),
    (2, 3),
    (5, 6),
];

/// 3×3 median over the valid (finite) values of the neighbourhood; invalid pixels with at least
/// 5 valid neighbours are filled, pixels with fewer valid neighbours become invalid.
///
/// Interior pixels take the median from a sorting network on the values' total-order keys (the
/// order `f32::total_cmp` sorts by; invalid values last), which vectorises across the row; the
/// border pixels go through [`median3_valid_pixel`]. Identical results.
/// Inlined into the matcher's instances, so the AVX2 one compares with `vpminud`/`vpmaxud`
/// (the baseline x86-64 build has no unsigned 32-bit min/max and emulates them).
#[inline(always)]
fn median3_valid(d: &Image<f32>) -> Image<f32> {
    let (w, h) = (d.width(), d.height());
    if w < 3 || h < 3 {
        return median3_valid_slow(d);
    }
    // total_cmp's key: flip the magnitude bits of negative values; invalid (NaN, ±∞: not
    // finite) → u32::MAX, after every valid key.
    let key = |x: f32| {
        let b = x.to_bits();
        if x.is_finite() {
            b ^ ((((b as i32) >> 31) as u32) >> 1) ^ 0x8000_0000
        } else {
            u32::MAX
        }
    };
    let unkey = |k: u32| {
        let b = k ^ 0x8000_0000;
        f32::from_bits(b ^ ((((b as i32) >> 31) as u32) >> 1))
    };
    let keys: Vec<u32> = d.data().iter().map(|&x| key(x)).collect();
    let valid: Vec<u8> = d.data().iter().map(|x| x.is_finite() as u8).collect();
    let st = d.stride();
    let mut out = Image::<f32>::filled(w, h, f32::NAN);
    let mut med = vec![0u32; w];
    let mut cnt = vec![0u8; w];
    for v in 0..h {
        let o = out.row_mut(v);
        if v == 0 || v == h - 1 {
            for (u, px) in o.iter_mut().enumerate() {
                *px = median3_valid_pixel(d, u, v);
            }
            continue;
        }
        let rows: [&[u32]; 3] =
            std::array::from_fn(|r| &keys[(v + r - 1) * st..(v + r - 1) * st + w]);
        let vrows: [&[u8]; 3] =
            std::array::from_fn(|r| &valid[(v + r - 1) * st..(v + r - 1) * st + w]);
        for u in 1..w - 1 {
            let mut p = [
                rows[0][u - 1],
                rows[0][u],
                rows[0][u + 1],
                rows[1][u - 1],
                rows[1][u],
                rows[1][u + 1],
                rows[2][u - 1],
                rows[2][u],
                rows[2][u + 1],
            ];
            // A 25-exchange sorting network of 9 (invalid keys are u32::MAX, so they sort
            // last): the valid values come first, in total order, and the median of the `n`
            // valid ones is element `n / 2` — index 2, 3 or 4 for n = 5 … 9, picked without a
            // branch so the loop stays vectorised.
            macro_rules! s {
                ($a:expr, $b:expr) => {{
                    let (x, y) = (p[$a], p[$b]);
                    p[$a] = x.min(y);
                    p[$b] = x.max(y);
                }};
            }
            // SORT9, written out (a loop over the table keeps `p` in memory, unvectorised).
            s!(0, 1);
            s!(3, 4);
            s!(6, 7);
            s!(1, 2);
            s!(4, 5);
            s!(7, 8);
            s!(0, 1);
            s!(3, 4);
            s!(6, 7);
            s!(0, 3);
            s!(3, 6);
            s!(0, 3);
            s!(1, 4);
            s!(4, 7);
            s!(1, 4);
            s!(2, 5);
            s!(5, 8);
            s!(2, 5);
            s!(1, 3);
            s!(5, 7);
            s!(2, 6);
            s!(4, 6);
            s!(2, 4);
            s!(2, 3);
            s!(5, 6);
            let n = vrows[0][u - 1]
                + vrows[0][u]
                + vrows[0][u + 1]
                + vrows[1][u - 1]
                + vrows[1][u]
                + vrows[1][u + 1]
                + vrows[2][u - 1]
                + vrows[2][u]
                + vrows[2][u + 1];
            med[u] = if n >= 8 {
                p[4]
            } else if n >= 6 {
                p[3]
            } else {
                p[2]
            };
            cnt[u] = n;
        }
        for u in 0..w {
            o[u] = if u > 0 && u + 1 < w {
                if cnt[u] >= 5 { unkey(med[u]) } else { f32::NAN }
            } else {
                median3_valid_pixel(d, u, v)
            };
        }
    }
    out
}

/// [`median3_valid`] pixel by pixel (the reference; also its border and partial cases).
fn median3_valid_slow(d: &Image<f32>) -> Image<f32> {
    Image::from_fn(d.width(), d.height(), |u, v| median3_valid_pixel(d, u, v))
}

/// One pixel of [`median3_valid`]: sort the valid neighbours, take the middle one.
fn median3_valid_pixel(d: &Image<f32>, u: usize, v: usize) -> f32 {
    let (w, h) = (d.width() as i64, d.height() as i64);
    let mut a = [0.0f32; 9];
    let mut n = 0;
    for dv in -1..=1i64 {
        for du in -1..=1i64 {
            let (x, y) = (u as i64 + du, v as i64 + dv);
            if x >= 0 && y >= 0 && x < w && y < h {
                let val = d.get(x as usize, y as usize);
                if val.is_finite() {
                    a[n] = val;
                    n += 1;
                }
            }
        }
    }
    if n < 5 {
        return f32::NAN;
    }
    a[..n].sort_by(|x, y| x.total_cmp(y));
    a[n / 2]
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

    #[test]
    fn streaming_simd_and_scalar_equal_the_reference() {
        for (seed, (w, h, nd, br, sr, uniq)) in [
            (40, 20, 16, 4, 2, 0.0),
            (57, 31, 33, 2, 0, 0.1),
            (13, 11, 100, 2, 1, 0.0),
            (80, 25, 64, 3, 3, 0.0),
            (23, 9, 5, 4, 2, 0.0),
        ]
        .into_iter()
        .enumerate()
        {
            let right = random_texture(w + 5, h, seed as u64);
            let left = GrayImage::from_fn(w, h, |u, v| right.get(u + (u * 3 / w), v));
            let right = GrayImage::from_fn(w, h, |u, v| right.get(u, v));
            let params = StereoParams {
                max_disparity: nd,
                block_radius: br,
                shift_radius: sr,
                uniqueness: uniq,
                ..Default::default()
            };
            let want = block_match_reference(&left, &right, &params).unwrap();
            let fast = block_match(&left, &right, &params).unwrap();
            let scalar = crate::simd::scalar_only(|| block_match(&left, &right, &params)).unwrap();
            let bits = |i: &Image<f32>| i.data().iter().map(|x| x.to_bits()).collect::<Vec<_>>();
            assert_eq!(bits(&fast), bits(&want), "case {seed}");
            assert_eq!(bits(&scalar), bits(&want), "case {seed}");
            assert!(want.data().iter().any(|x| x.is_finite()));
        }
        // The two census layouts have the same Hamming distances.
        let img = random_texture(30, 20, 9);
        let packed = census_transform(&img, 3);
        let whole = |avx2: bool| {
            let mut out = vec![0u64; img.width() * img.height()];
            for (v, row) in out.chunks_exact_mut(img.width()).enumerate() {
                if avx2 {
                    census_spread_row::<true>(&img, 3, v, row);
                } else {
                    census_spread_row::<false>(&img, 3, v, row);
                }
            }
            out
        };
        let spread = whole(false);
        if crate::simd::avx2() {
            assert_eq!(whole(true), spread);
        }
        for i in 0..spread.len() {
            assert_eq!(spread[i].count_ones(), packed.data()[i].count_ones());
            let j = (i * 7 + 3) % spread.len();
            assert_eq!(
                (spread[i] ^ spread[j]).count_ones(),
                (packed.data()[i] ^ packed.data()[j]).count_ones()
            );
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
