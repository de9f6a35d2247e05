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
pub fn fast_score(img: &GrayImage, u: usize, v: usize, threshold: u8) -> i32 {
    let data = img.data();
    let centre = v * img.stride() + u;
    let c = data[centre] as i32;
    let s = img.stride() as isize;
    let mut d = [0i32; 32];
    for (k, &(du, dv)) in CIRCLE.iter().enumerate() {
        d[k] = c - data[(centre as isize + dv as isize * s + du as isize) as usize] as i32;
        d[k + 16] = d[k];
    }
    // Sliding minima / maxima over 9 contiguous values by doubling: 2, 4, 8, then 9.
    let mut mn2 = [0i32; 31];
    let mut mx2 = [0i32; 31];
    for k in 0..31 {
        mn2[k] = d[k].min(d[k + 1]);
        mx2[k] = d[k].max(d[k + 1]);
    }
    let mut best = threshold as i32;
    for k in 0..16 {
        let mn = mn2[k]
            .min(mn2[k + 2])
            .min(mn2[k + 4].min(mn2[k + 6]))
            .min(d[k + 8]);
        let mx = mx2[k]
            .max(mx2[k + 2])
            .max(mx2[k + 4].max(mx2[k + 6]))
            .max(d[k + 8]);
        best = best.max(mn).max(-mx);
    }
    best - 1
}

/// Detects FAST-9 corners: pixel `c` (at least 3 pixels from the border) is a corner if 9
/// contiguous pixels of the radius-3 circle are all brighter than `I_c + t` or all darker than
/// `I_c − t` (strict comparisons, as OpenCV). With `nonmax_suppression`, a corner is kept only if
/// its [`fast_score`] is strictly larger than that of all 8 neighbours (non-corners score 0).
/// Corners are returned in row-major order with their FAST score.
pub fn fast9(img: &GrayImage, threshold: u8, nonmax_suppression: bool) -> Vec<Corner> {
    fast9_level(img, threshold, nonmax_suppression, 0)
}

/// [`fast9`] tagging corners with a pyramid level.
pub fn fast9_level(
    img: &GrayImage,
    threshold: u8,
    nonmax_suppression: bool,
    level: usize,
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
    const LANES: usize = 16;
    for y in 3..h - 3 {
        let base = y * img.stride() + 3;
        let centre = &data[base..base + n];
        let ring = |k: usize| {
            let start = (base as isize + offsets[k]) as usize;
            &data[start..start + n]
        };
        let rings: [&[u8]; 16] = std::array::from_fn(ring);
        // Quick rejection (vectorised, as OpenCV's scalar pre-test): an arc of 9 contiguous
        // circle pixels contains one pixel of every diametric pair (k, k + 8), so a bright
        // (dark) corner needs, for all k < 8, pixel k or pixel k + 8 bright (dark).
        candidates.clear();
        let mut x = 0;
        while x < n {
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
                        if u128::from_ne_bytes(flags) == 0 {
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
            let mut bits = 0u32;
            for (i, &f) in flags.iter().enumerate() {
                bits |= ((f != 0) as u32) << i;
            }
            while bits != 0 {
                let i = bits.trailing_zeros() as usize;
                bits &= bits - 1;
                if i < m {
                    candidates.push(x + i);
                }
            }
            x += LANES;
        }
        let slot = y % 3;
        scores[slot].iter_mut().for_each(|x| *x = 0);
        cand[slot].clear();
        for &x in &candidates {
            let c = centre[x];
            let hi = c.saturating_add(threshold);
            let lo = c.saturating_sub(threshold);
            let (mut b, mut d) = (0u16, 0u16);
            for (k, &off) in offsets.iter().enumerate() {
                let p = data[(base as isize + x as isize + off) as usize];
                b |= ((p > hi) as u16) << k;
                d |= ((p < lo) as u16) << k;
            }
            if has_arc9(b) || has_arc9(d) {
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
