//! FAST-9 corners (Rosten & Drummond 2006) with non-maximum suppression, and the Shi-Tomasi /
//! Harris corner scores (thesis §3.4: FAST corners are the candidate locations for the guided
//! patch search).

use crate::image::GrayImage;
use crate::pyramid::Pyramid;

/// A corner at integer pixel `(u, v)` of pyramid level `level`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Corner {
    /// Column (level coordinates).
    pub u: f32,
    /// Row (level coordinates).
    pub v: f32,
    /// Corner score (FAST score, or a replaced score such as Shi-Tomasi).
    pub score: f32,
    /// Pyramid level the corner was detected on.
    pub level: usize,
}

/// The 16 pixels of the Bresenham circle of radius 3, as `(du, dv)`, in circular order.
pub const CIRCLE: [(i32, i32); 16] = [
    (0, -3),
    (1, -3),
    (2, -2),
    (3, -1),
    (3, 0),
    (3, 1),
    (2, 2),
    (1, 3),
    (0, 3),
    (-1, 3),
    (-2, 2),
    (-3, 1),
    (-3, 0),
    (-3, -1),
    (-2, -2),
    (-1, -3),
];

/// True if the 16-bit circular mask has 9 consecutive set bits: with `m' = m | m≪16`, the
/// conjunction of `m' ≫ i` for `i = 0…8` is non-zero.
#[inline(always)]
fn has_arc9(mask: u16) -> bool {
    let m = mask as u32 | ((mask as u32) << 16);
    let a = m & (m >> 1); // 2 consecutive
    let b = a & (a >> 2); // 4
    let c = b & (b >> 4); // 8
    (c & (m >> 8)) != 0 // 9
}

/// The FAST score of a corner as OpenCV defines it: the largest threshold `t` for which the
/// pixel is still a FAST-9 corner, minus one. With `d_k = I_c − I_k` over the circle,
/// `score = max(t₀, max over arcs A of 9 contiguous pixels of max(min_A d_k, min_A −d_k)) − 1`,
/// where `t₀` is the detection threshold.
#[inline(always)]
pub fn fast_score(img: &GrayImage, u: usize, v: usize, threshold: u8) -> i32 {
    let rows: [&[u8]; 7] = std::array::from_fn(|r| &img.row(v + r - 3)[u - 3..u + 4]);
    let mut p = [0u8; 16];
    for (k, &(du, dv)) in CIRCLE.iter().enumerate() {
        p[k] = rows[(dv + 3) as usize][(du + 3) as usize];
    }
    score_from_circle(rows[3][3], &p, threshold)
}

/// The FAST score from the centre value and the 16 circle values (see [`fast_score`]).
#[inline(always)]
fn score_from_circle(centre: u8, p: &[u8; 16], threshold: u8) -> i32 {
    #[cfg(target_arch = "x86_64")]
    if crate::simd::enabled() {
        return simd::score(centre, p, threshold);
    }
    {
        let c = centre as i16;
        let d: [i16; 16] = std::array::from_fn(|k| c - p[k] as i16);
        let mut best = threshold as i16;
        for s in 0..16 {
            let (mut mn, mut mx) = (i16::MAX, i16::MIN);
            for j in 0..9 {
                mn = mn.min(d[(s + j) & 15]);
                mx = mx.max(d[(s + j) & 15]);
            }
            best = best.max(mn).max(-mx);
        }
        best as i32 - 1
    }
}

/// Detects FAST-9 corners: pixel `c` (at least 3 pixels from the border) is a corner if 9
/// contiguous pixels of the radius-3 circle are all brighter than `I_c + t` or all darker than
/// `I_c − t` (strict comparisons, as OpenCV). With `nonmax_suppression`, a corner is kept only if
/// its [`fast_score`] is strictly larger than that of all 8 neighbours (non-corners score 0).
/// Corners are returned in row-major order with their FAST score.
pub fn fast9(img: &GrayImage, threshold: u8, nonmax_suppression: bool) -> Vec<Corner> {
    fast9_level(img, threshold, nonmax_suppression, 0)
}

/// An image's FAST-9 corners (non-maximum suppressed), detected once on first use at
/// `threshold` and given to each caller at its own threshold at or above it. A corner's FAST
/// score does not depend on the detection threshold (it is the largest threshold at which the
/// pixel is a corner, minus one), and a neighbour weaker than a corner's threshold never
/// suppresses it, so the corners at `t ≥ threshold` are exactly those scoring at least `t`
/// (a test compares them with [`fast9`] at `t`): one pass over the image serves the monocular
/// front-end's corner selection (threshold 20) and its guided search (12).
pub struct FrameCorners<'a> {
    image: &'a GrayImage,
    threshold: u8,
    corners: std::cell::OnceCell<Vec<Corner>>,
}

impl<'a> FrameCorners<'a> {
    /// The corners of `image`, to be detected at `threshold` when first asked for.
    pub fn new(image: &'a GrayImage, threshold: u8) -> Self {
        FrameCorners {
            image,
            threshold,
            corners: std::cell::OnceCell::new(),
        }
    }

    /// The image.
    pub fn image(&self) -> &'a GrayImage {
        self.image
    }

    /// The corners at `threshold` ([`fast9`] with non-maximum suppression), in row-major
    /// order; below the detection threshold, detected anew.
    pub fn at(&self, threshold: u8) -> Vec<Corner> {
        if threshold < self.threshold {
            return fast9(self.image, threshold, true);
        }
        let all = self
            .corners
            .get_or_init(|| fast9(self.image, self.threshold, true));
        all.iter()
            .filter(|c| c.score >= threshold as f32)
            .copied()
            .collect()
    }
}

/// [`fast9`] tagging corners with a pyramid level.
///
/// On x86-64 CPUs with AVX2 a copy of the detector compiled for AVX2 is used (runtime
/// dispatch, as OpenCV does); results are identical.
pub fn fast9_level(
    img: &GrayImage,
    threshold: u8,
    nonmax_suppression: bool,
    level: usize,
) -> Vec<Corner> {
    if crate::simd::avx2() {
        #[cfg(target_arch = "x86_64")]
        // SAFETY: the CPU supports AVX2 (checked just above).
        return unsafe { fast9_avx2(img, threshold, nonmax_suppression, level) };
    }
    let mode = if cfg!(target_arch = "x86_64") && crate::simd::enabled() {
        Mode::Sse2
    } else {
        Mode::Scalar
    };
    fast9_impl::<16>(img, threshold, nonmax_suppression, level, mode)
}

/// Which row test [`fast9_impl`] runs.
#[derive(Clone, Copy, PartialEq, Eq)]
enum Mode {
    /// The portable reference (lane arrays the compiler may vectorise, then the exact test).
    Scalar,
    /// SSE2 pre-test and arc test (x86-64 baseline).
    Sse2,
    /// The same with AVX2, 32 pixels per step.
    Avx2,
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn fast9_avx2(
    img: &GrayImage,
    threshold: u8,
    nonmax_suppression: bool,
    level: usize,
) -> Vec<Corner> {
    fast9_impl::<32>(img, threshold, nonmax_suppression, level, Mode::Avx2)
}

#[inline(always)]
fn fast9_impl<const LANES: usize>(
    img: &GrayImage,
    threshold: u8,
    nonmax_suppression: bool,
    level: usize,
    mode: Mode,
) -> Vec<Corner> {
    let (w, h) = (img.width(), img.height());
    if w < 7 || h < 7 {
        return Vec::new();
    }
    let s = img.stride() as isize;
    let data = img.data();
    let n = w - 6;
    let offsets: [isize; 16] = CIRCLE.map(|(du, dv)| dv as isize * s + du as isize);
    // Scores of the previous two rows and this one (0 = not a corner), for the 3×3 suppression.
    let mut scores = vec![vec![0i32; w]; 3];
    let mut cand: Vec<Vec<usize>> = vec![Vec::new(), Vec::new(), Vec::new()];
    let mut out = Vec::new();
    let mut candidates: Vec<usize> = Vec::with_capacity(n);
    // Columns already known to be corners (SIMD path), processed before `candidates`.
    let mut certain: Vec<usize> = Vec::with_capacity(n);
    for y in 3..h - 3 {
        let base = y * img.stride() + 3;
        let centre = &data[base..base + n];
        let ring = |k: usize| {
            let start = (base as isize + offsets[k]) as usize;
            &data[start..start + n]
        };
        candidates.clear();
        certain.clear();
        #[cfg(target_arch = "x86_64")]
        if mode != Mode::Scalar {
            // SAFETY: AVX2 is used only if the CPU has it; SSE2 is part of x86-64. Loads stay
            // inside the image: the chunk lies in columns 3..w−3 and rows y ± 3 exist.
            unsafe {
                if mode == Mode::Avx2 {
                    simd::row_corners_avx2(
                        data,
                        base,
                        &offsets,
                        n,
                        threshold,
                        &mut certain,
                        &mut candidates,
                    );
                } else {
                    simd::row_corners_sse2(
                        data,
                        base,
                        &offsets,
                        n,
                        threshold,
                        &mut certain,
                        &mut candidates,
                    );
                }
            }
        }
        let rings: [&[u8]; 16] = std::array::from_fn(ring);
        // Quick rejection (vectorised, as OpenCV's scalar pre-test): an arc of 9 contiguous
        // circle pixels contains one pixel of every diametric pair (k, k + 8), so a bright
        // (dark) corner needs, for all k < 8, pixel k or pixel k + 8 bright (dark).
        let mut x = 0;
        while mode == Mode::Scalar && x < n {
            let m = LANES.min(n - x);
            let mut flags = [0u8; LANES];
            if m == LANES {
                let c: &[u8; LANES] = centre[x..x + LANES].try_into().expect("lane chunk");
                let mut hi = [0u8; LANES];
                let mut lo = [0u8; LANES];
                for i in 0..LANES {
                    hi[i] = c[i].saturating_add(threshold);
                    lo[i] = c[i].saturating_sub(threshold);
                }
                let mut ab = [1u8; LANES];
                let mut ad = [1u8; LANES];
                let mut alive = true;
                for (step, k) in [0usize, 4, 2, 6, 1, 3, 5, 7].into_iter().enumerate() {
                    let p: &[u8; LANES] = rings[k][x..x + LANES].try_into().expect("lane chunk");
                    let q: &[u8; LANES] =
                        rings[k + 8][x..x + LANES].try_into().expect("lane chunk");
                    for i in 0..LANES {
                        ab[i] &= ((p[i] > hi[i]) | (q[i] > hi[i])) as u8;
                        ad[i] &= ((p[i] < lo[i]) | (q[i] < lo[i])) as u8;
                    }
                    if step == 1 || step == 3 {
                        for i in 0..LANES {
                            flags[i] = ab[i] | ad[i];
                        }
                        if flags.iter().fold(0u8, |a, &f| a | f) == 0 {
                            alive = false;
                            break;
                        }
                    }
                }
                if !alive {
                    x += LANES;
                    continue;
                }
                for i in 0..LANES {
                    flags[i] = ab[i] | ad[i];
                }
            } else {
                flags[..m].iter_mut().for_each(|f| *f = 1);
            }
            // Scan the flags eight at a time (flags are 0 or 1 per byte).
            for (wi, word) in flags.chunks_exact(8).enumerate() {
                let mut bits = u64::from_le_bytes(word.try_into().expect("8 bytes"));
                while bits != 0 {
                    let i = wi * 8 + (bits.trailing_zeros() / 8) as usize;
                    bits &= bits - 1;
                    if i < m {
                        candidates.push(x + i);
                    }
                }
            }
            x += LANES;
        }
        let slot = y % 3;
        scores[slot].iter_mut().for_each(|x| *x = 0);
        cand[slot].clear();
        let num_certain = certain.len();
        for (idx, &x) in certain.iter().chain(candidates.iter()).enumerate() {
            let is_corner = idx < num_certain || {
                let c = centre[x];
                let hi = c.saturating_add(threshold);
                let lo = c.saturating_sub(threshold);
                let (mut b, mut d) = (0u16, 0u16);
                for (k, &off) in offsets.iter().enumerate() {
                    let p = data[(base as isize + x as isize + off) as usize];
                    b |= ((p > hi) as u16) << k;
                    d |= ((p < lo) as u16) << k;
                }
                has_arc9(b) || has_arc9(d)
            };
            if is_corner {
                let u = x + 3;
                if nonmax_suppression {
                    scores[slot][u] = fast_score(img, u, y, threshold);
                    cand[slot].push(u);
                } else {
                    out.push(Corner {
                        u: u as f32,
                        v: y as f32,
                        score: fast_score(img, u, y, threshold) as f32,
                        level,
                    });
                }
            }
        }
        if nonmax_suppression && y >= 4 {
            // Suppress in the previous row, whose neighbours above and below are now known.
            let py = y - 1;
            let (ps, cs, ns) = ((py + 2) % 3, py % 3, y % 3);
            for &u in &cand[cs] {
                let sc = scores[cs][u];
                let above = &scores[ps];
                let same = &scores[cs];
                let below = &scores[ns];
                let keep = sc > same[u - 1]
                    && sc > same[u + 1]
                    && sc > above[u - 1]
                    && sc > above[u]
                    && sc > above[u + 1]
                    && sc > below[u - 1]
                    && sc > below[u]
                    && sc > below[u + 1];
                if keep {
                    out.push(Corner {
                        u: u as f32,
                        v: py as f32,
                        score: sc as f32,
                        level,
                    });
                }
            }
        }
    }
    if nonmax_suppression {
        // The last detection row h−4 has no corners below it.
        let py = h - 4;
        let (ps, cs) = ((py + 2) % 3, py % 3);
        if h - 3 > 3 {
            for &u in &cand[cs] {
                let sc = scores[cs][u];
                let above = &scores[ps];
                let same = &scores[cs];
                let above_ok = py == 3 || (sc > above[u - 1] && sc > above[u] && sc > above[u + 1]);
                if sc > same[u - 1] && sc > same[u + 1] && above_ok {
                    out.push(Corner {
                        u: u as f32,
                        v: py as f32,
                        score: sc as f32,
                        level,
                    });
                }
            }
        }
    }
    out
}

/// x86-64 SIMD FAST test (as OpenCV's): a pre-test — a FAST-9 corner needs two adjacent compass
/// pixels (0 & 4, 4 & 8, 8 & 12 or 12 & 0) both brighter or both darker, since any arc of 9
/// contiguous circle pixels contains two adjacent compass pixels — then, for chunks with a
/// survivor, the full arc test on all lanes. Corner columns (relative to the first detection
/// column) go to `certain`; the row's last columns are covered by one more vector that overlaps
/// the previous one (only rows shorter than a vector go to `out` for the scalar exact test). Unsigned byte comparisons are done as signed ones after flipping
/// the top bit.
#[cfg(target_arch = "x86_64")]
mod simd {
    use std::arch::x86_64::*;

    macro_rules! pretest {
        ($lanes:expr, $ty:ty, $load:ident, $set1:ident, $xor:ident, $adds:ident, $subs:ident,
         $cmpgt:ident, $and:ident, $or:ident, $movemask:ident, $sub:ident, $max:ident,
         $data:ident, $base:ident, $offsets:ident, $n:ident, $threshold:ident, $certain:ident,
         $out:ident) => {{
            let delta = $set1(i8::MIN);
            let t = $set1($threshold as i8);
            let p = $data.as_ptr();
            let full: u32 = if $lanes == 32 {
                u32::MAX
            } else {
                (1u32 << $lanes) - 1
            };
            let mut x = 0usize;
            loop {
                // The row's last columns (fewer than a vector) are covered by one more vector
                // ending at column n, overlapping the previous one; `keep` drops the lanes
                // already tested, so every column is tested once and `certain` stays sorted.
                let (xc, keep) = if x + $lanes <= $n {
                    (x, full)
                } else if x < $n && $n >= $lanes {
                    let xc = $n - $lanes;
                    (xc, full & !((1u32 << (x - xc)) - 1))
                } else {
                    break;
                };
                x = xc + $lanes;
                let at = (p as isize + ($base + xc) as isize) as *const u8;
                let c = $load(at as *const $ty);
                let v1 = $xor($adds(c, t), delta);
                let v0 = $xor($subs(c, t), delta);
                let x0 = $xor($load(at.offset($offsets[0]) as *const $ty), delta);
                let x1 = $xor($load(at.offset($offsets[4]) as *const $ty), delta);
                let x2 = $xor($load(at.offset($offsets[8]) as *const $ty), delta);
                let x3 = $xor($load(at.offset($offsets[12]) as *const $ty), delta);
                let mut dark = $and($cmpgt(v0, x0), $cmpgt(v0, x1));
                let mut bright = $and($cmpgt(x0, v1), $cmpgt(x1, v1));
                dark = $or(dark, $and($cmpgt(v0, x1), $cmpgt(v0, x2)));
                bright = $or(bright, $and($cmpgt(x1, v1), $cmpgt(x2, v1)));
                dark = $or(dark, $and($cmpgt(v0, x2), $cmpgt(v0, x3)));
                bright = $or(bright, $and($cmpgt(x2, v1), $cmpgt(x3, v1)));
                dark = $or(dark, $and($cmpgt(v0, x3), $cmpgt(v0, x0)));
                bright = $or(bright, $and($cmpgt(x3, v1), $cmpgt(x0, v1)));
                let pre = keep & $movemask($or(dark, bright)) as u32;
                if pre == 0 {
                    continue;
                }
                // Full test for all lanes: lengths of runs of consecutive dark / bright pixels
                // over the circle walked 25 times (16 + 8 to close the wrap-around); a corner
                // has a run of at least 9.
                let zero = $set1(0);
                let (mut c0, mut c1, mut m0, mut m1) = (zero, zero, zero, zero);
                for k in 0..25 {
                    let xk = $xor($load(at.offset($offsets[k % 16]) as *const $ty), delta);
                    let d0 = $cmpgt(v0, xk);
                    let d1 = $cmpgt(xk, v1);
                    c0 = $and($sub(c0, d0), d0);
                    c1 = $and($sub(c1, d1), d1);
                    m0 = $max(m0, c0);
                    m1 = $max(m1, c1);
                }
                let k8 = $set1(8);
                let mut mask = pre & $movemask($or($cmpgt(m0, k8), $cmpgt(m1, k8))) as u32;
                while mask != 0 {
                    $certain.push(xc + mask.trailing_zeros() as usize);
                    mask &= mask - 1;
                }
            }
            // Rows shorter than a vector go straight to the exact test.
            $out.extend(x..$n);
        }};
    }

    /// Rotates the 16 i16 lanes held in `(lo, hi)` (lanes 0–7, 8–15) by `N` lanes towards
    /// lane 0: lane `k` receives lane `(k + N) mod 16`. `B = 2N` bytes, `R = 16 − 2N`.
    macro_rules! rot {
        ($lo:expr, $hi:expr, $b:literal, $r:literal) => {{
            let (lo, hi) = ($lo, $hi);
            (
                _mm_or_si128(_mm_srli_si128::<$b>(lo), _mm_slli_si128::<$r>(hi)),
                _mm_or_si128(_mm_srli_si128::<$b>(hi), _mm_slli_si128::<$r>(lo)),
            )
        }};
    }

    /// FAST score with SSE2 (part of x86-64): `d_k = I_c − I_k` as 16 i16 lanes; minima and
    /// maxima over the 16 circular arcs of 9 by doubling (runs of 2, 4, 8, then 9), then the
    /// horizontal maximum of `max(min, −max)` (see `fast_score`).
    #[inline(always)]
    pub(super) fn score(centre: u8, p: &[u8; 16], threshold: u8) -> i32 {
        // SAFETY: SSE2 is part of the x86-64 baseline; the load reads exactly 16 bytes.
        unsafe {
            let zero = _mm_setzero_si128();
            let px = _mm_loadu_si128(p.as_ptr() as *const __m128i);
            let c = _mm_set1_epi16(centre as i16);
            let d_lo = _mm_sub_epi16(c, _mm_unpacklo_epi8(px, zero));
            let d_hi = _mm_sub_epi16(c, _mm_unpackhi_epi8(px, zero));
            let (mut mn_lo, mut mn_hi, mut mx_lo, mut mx_hi) = (d_lo, d_hi, d_lo, d_hi);
            let (a, b) = rot!(mn_lo, mn_hi, 2, 14);
            mn_lo = _mm_min_epi16(mn_lo, a);
            mn_hi = _mm_min_epi16(mn_hi, b);
            let (a, b) = rot!(mx_lo, mx_hi, 2, 14);
            mx_lo = _mm_max_epi16(mx_lo, a);
            mx_hi = _mm_max_epi16(mx_hi, b);
            let (a, b) = rot!(mn_lo, mn_hi, 4, 12);
            mn_lo = _mm_min_epi16(mn_lo, a);
            mn_hi = _mm_min_epi16(mn_hi, b);
            let (a, b) = rot!(mx_lo, mx_hi, 4, 12);
            mx_lo = _mm_max_epi16(mx_lo, a);
            mx_hi = _mm_max_epi16(mx_hi, b);
            let (a, b) = rot!(mn_lo, mn_hi, 8, 8);
            mn_lo = _mm_min_epi16(mn_lo, a);
            mn_hi = _mm_min_epi16(mn_hi, b);
            let (a, b) = rot!(mx_lo, mx_hi, 8, 8);
            mx_lo = _mm_max_epi16(mx_lo, a);
            mx_hi = _mm_max_epi16(mx_hi, b);
            // Runs of 9: combine with d rotated by 8 (the two halves swapped).
            mn_lo = _mm_min_epi16(mn_lo, d_hi);
            mn_hi = _mm_min_epi16(mn_hi, d_lo);
            mx_lo = _mm_max_epi16(mx_lo, d_hi);
            mx_hi = _mm_max_epi16(mx_hi, d_lo);
            let neg = |x| _mm_sub_epi16(zero, x);
            let mut best = _mm_max_epi16(
                _mm_max_epi16(mn_lo, mn_hi),
                _mm_max_epi16(neg(mx_lo), neg(mx_hi)),
            );
            best = _mm_max_epi16(best, _mm_srli_si128::<8>(best));
            best = _mm_max_epi16(best, _mm_srli_si128::<4>(best));
            best = _mm_max_epi16(best, _mm_srli_si128::<2>(best));
            let b = _mm_cvtsi128_si32(best) as i16;
            b.max(threshold as i16) as i32 - 1
        }
    }

    #[target_feature(enable = "avx2")]
    pub(super) unsafe fn row_corners_avx2(
        data: &[u8],
        base: usize,
        offsets: &[isize; 16],
        n: usize,
        threshold: u8,
        certain: &mut Vec<usize>,
        out: &mut Vec<usize>,
    ) {
        unsafe {
            pretest!(
                32,
                __m256i,
                _mm256_loadu_si256,
                _mm256_set1_epi8,
                _mm256_xor_si256,
                _mm256_adds_epu8,
                _mm256_subs_epu8,
                _mm256_cmpgt_epi8,
                _mm256_and_si256,
                _mm256_or_si256,
                _mm256_movemask_epi8,
                _mm256_sub_epi8,
                _mm256_max_epu8,
                data,
                base,
                offsets,
                n,
                threshold,
                certain,
                out
            )
        }
    }

    pub(super) unsafe fn row_corners_sse2(
        data: &[u8],
        base: usize,
        offsets: &[isize; 16],
        n: usize,
        threshold: u8,
        certain: &mut Vec<usize>,
        out: &mut Vec<usize>,
    ) {
        unsafe {
            pretest!(
                16,
                __m128i,
                _mm_loadu_si128,
                _mm_set1_epi8,
                _mm_xor_si128,
                _mm_adds_epu8,
                _mm_subs_epu8,
                _mm_cmpgt_epi8,
                _mm_and_si128,
                _mm_or_si128,
                _mm_movemask_epi8,
                _mm_sub_epi8,
                _mm_max_epu8,
                data,
                base,
                offsets,
                n,
                threshold,
                certain,
                out
            )
        }
    }
}

/// FAST-9 on every level of a pyramid (coordinates of each level).
pub fn fast9_pyramid(
    pyramid: &Pyramid,
    threshold: u8,
    nonmax_suppression: bool,
) -> Vec<Vec<Corner>> {
    pyramid
        .levels
        .iter()
        .enumerate()
        .map(|(l, img)| fast9_level(img, threshold, nonmax_suppression, l))
        .collect()
}

/// The 2×2 structure tensor `M = Σ_W [g_u², g_u g_v; g_u g_v, g_v²]` over the
/// `(2r+1)×(2r+1)` window around `(u, v)`, with central-difference gradients; `None` if the window
/// (plus one pixel for the gradient) leaves the image. Returns `(Σg_u², Σg_u g_v, Σg_v²)`.
pub fn structure_tensor(img: &GrayImage, u: usize, v: usize, r: usize) -> Option<(f32, f32, f32)> {
    if u < r + 1 || v < r + 1 || u + r + 1 >= img.width() || v + r + 1 >= img.height() {
        return None;
    }
    let (mut a, mut b, mut c) = (0.0f32, 0.0f32, 0.0f32);
    for y in v - r..=v + r {
        let rm = img.row(y - 1);
        let r0 = img.row(y);
        let rp = img.row(y + 1);
        for x in u - r..=u + r {
            let gx = 0.5 * (r0[x + 1] as f32 - r0[x - 1] as f32);
            let gy = 0.5 * (rp[x] as f32 - rm[x] as f32);
            a += gx * gx;
            b += gx * gy;
            c += gy * gy;
        }
    }
    Some((a, b, c))
}

/// The Shi-Tomasi score: the smaller eigenvalue of the structure tensor (see
/// [`structure_tensor`]) divided by the window's pixel count,
/// `λ_min = ½(a + c − √((a − c)² + 4b²))/|W|`. `None` near the border.
pub fn shi_tomasi_score(img: &GrayImage, u: usize, v: usize, r: usize) -> Option<f32> {
    let (a, b, c) = structure_tensor(img, u, v, r)?;
    let n = ((2 * r + 1) * (2 * r + 1)) as f32;
    Some(0.5 * (a + c - ((a - c) * (a - c) + 4.0 * b * b).sqrt()) / n)
}

/// The Harris score `det M − k (tr M)²` of the structure tensor (see [`structure_tensor`]),
/// normalised by the squared window size. `None` near the border.
pub fn harris_score(img: &GrayImage, u: usize, v: usize, r: usize, k: f32) -> Option<f32> {
    let (a, b, c) = structure_tensor(img, u, v, r)?;
    let n = ((2 * r + 1) * (2 * r + 1)) as f32;
    Some((a * c - b * b - k * (a + c) * (a + c)) / (n * n))
}

/// Replaces each corner's score by its Shi-Tomasi score (window radius `r`), dropping corners
/// too close to the border for the window.
pub fn with_shi_tomasi(img: &GrayImage, corners: &[Corner], r: usize) -> Vec<Corner> {
    corners
        .iter()
        .filter_map(|c| {
            shi_tomasi_score(img, c.u as usize, c.v as usize, r).map(|s| Corner { score: s, ..*c })
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Brute-force reference: corner test by scanning all arcs.
    fn is_corner_ref(img: &GrayImage, u: usize, v: usize, t: u8) -> bool {
        let c = img.get(u, v) as i32;
        let p: Vec<i32> = CIRCLE
            .iter()
            .map(|&(du, dv)| img.get((u as i32 + du) as usize, (v as i32 + dv) as usize) as i32)
            .collect();
        (0..16).any(|s| (0..9).all(|j| p[(s + j) % 16] > c + t as i32))
            || (0..16).any(|s| (0..9).all(|j| p[(s + j) % 16] < c - t as i32))
    }

    fn noise_image(w: usize, h: usize, seed: u64) -> GrayImage {
        let mut x = seed;
        GrayImage::from_fn(w, h, |_, _| {
            x = x
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (x >> 56) as u8
        })
    }

    /// The corners at a threshold are those of a lower threshold scoring at least it, the
    /// non-maximum suppression included ([`FrameCorners`]), with SIMD and on the scalar path.
    #[test]
    fn corners_at_a_threshold_are_those_of_a_lower_one_scoring_at_least_it() {
        for seed in [1, 2, 3] {
            let img = noise_image(160, 120, seed);
            let check = || {
                let corners = FrameCorners::new(&img, 12);
                for t in [12u8, 13, 20, 27, 40] {
                    assert_eq!(corners.at(t), fast9(&img, t, true), "seed {seed}, t {t}");
                }
                assert_eq!(corners.at(8), fast9(&img, 8, true));
            };
            check();
            crate::simd::scalar_only(check);
        }
    }

    #[test]
    fn circle_is_a_closed_ring_of_radius_3() {
        for k in 0..16 {
            let (a, b) = (CIRCLE[k], CIRCLE[(k + 1) % 16]);
            assert!(
                (a.0 - b.0).abs() <= 1 && (a.1 - b.1).abs() <= 1,
                "gap at {k}"
            );
            let r2 = a.0 * a.0 + a.1 * a.1;
            assert!((8..=10).contains(&r2));
        }
    }

    #[test]
    fn detection_matches_brute_force() {
        for seed in 0..3 {
            let img = noise_image(41, 33, seed);
            let t = 20;
            let got: Vec<(usize, usize)> = fast9(&img, t, false)
                .iter()
                .map(|c| (c.u as usize, c.v as usize))
                .collect();
            let mut want = Vec::new();
            for v in 3..30 {
                for u in 3..38 {
                    if is_corner_ref(&img, u, v, t) {
                        want.push((u, v));
                    }
                }
            }
            assert_eq!(got, want);
            // Non-max suppression keeps a subset with strict local maxima.
            let nms = fast9(&img, t, true);
            for c in &nms {
                assert!(want.contains(&(c.u as usize, c.v as usize)));
            }
            assert!(nms.len() <= want.len());
        }
    }

    #[test]
    fn scalar_sse2_and_avx2_paths_agree() {
        // Widths around the vector lengths exercise the overlapped last vector of a row.
        for (seed, (w, h)) in [(97, 41), (38, 9), (39, 12), (45, 20), (70, 17), (131, 30)]
            .into_iter()
            .enumerate()
        {
            let img = noise_image(w, h, seed as u64);
            for t in [5, 25] {
                for nms in [false, true] {
                    let scalar = fast9_impl::<16>(&img, t, nms, 0, Mode::Scalar);
                    assert_eq!(fast9_impl::<16>(&img, t, nms, 0, Mode::Sse2), scalar);
                    assert_eq!(crate::simd::scalar_only(|| fast9(&img, t, nms)), scalar);
                    assert_eq!(fast9_level(&img, t, nms, 0), scalar, "{w}×{h} t={t}");
                    if crate::simd::avx2() {
                        // SAFETY: the CPU supports AVX2 (checked just above).
                        let avx2 = unsafe { fast9_avx2(&img, t, nms, 0) };
                        assert_eq!(avx2, scalar);
                    }
                }
            }
        }
    }

    #[test]
    fn score_is_largest_threshold_minus_one() {
        let img = noise_image(30, 30, 7);
        for c in fast9(&img, 10, false) {
            let (u, v) = (c.u as usize, c.v as usize);
            let s = c.score as i32;
            assert!(is_corner_ref(&img, u, v, s as u8));
            assert!(s + 1 > 254 || !is_corner_ref(&img, u, v, (s + 1) as u8));
        }
    }

    #[test]
    fn tiny_and_flat_images_give_no_corners() {
        assert!(fast9(&GrayImage::new(1, 1), 10, true).is_empty());
        assert!(fast9(&GrayImage::new(0, 0), 10, true).is_empty());
        assert!(fast9(&GrayImage::filled(50, 9, 3), 10, true).is_empty());
        assert!(shi_tomasi_score(&GrayImage::new(1, 1), 0, 0, 3).is_none());
    }

    #[test]
    fn shi_tomasi_prefers_corners_over_edges() {
        let corner = GrayImage::from_fn(21, 21, |u, v| if u > 10 && v > 10 { 200 } else { 20 });
        let edge = GrayImage::from_fn(21, 21, |u, _| if u > 10 { 200 } else { 20 });
        let sc = shi_tomasi_score(&corner, 10, 10, 3).unwrap();
        let se = shi_tomasi_score(&edge, 10, 10, 3).unwrap();
        assert!(sc > 100.0 && se.abs() < 1e-3, "{sc} {se}");
    }
}
