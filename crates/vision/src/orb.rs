//! ORB features (Rublee et al. 2011): oriented FAST on a scale pyramid + rotated BRIEF, 256 bits,
//! with brute-force Hamming matching and Lowe's ratio test. The thesis (§6.4.2) uses SURF for
//! appearance-based loop closure; ORB is the free binary alternative used here.
//!
//! The BRIEF sampling pattern is our own: 256 point pairs drawn (seeded) from an isotropic
//! Gaussian with `σ = S/5` for the patch size `S = 31` (Calonder et al. 2010, pattern G II),
//! clipped to a radius that stays inside the patch after rotation. It is *not* OpenCV's learned
//! pattern, so our descriptors are not bit-compatible with OpenCV/DBoW vocabularies.

use crate::fast::{fast9_level, harris_score};
use crate::image::{GrayImage, ImageError};
use crate::pyramid::{gaussian_blur_radius, resize_bilinear};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};
use std::sync::OnceLock;

/// A 256-bit binary descriptor.
pub type Descriptor = [u64; 4];

/// Hamming distance between two descriptors (`popcount(a ⊕ b)`). Inlined into its callers, so
/// [`match_descriptors`]' POPCNT build uses the instruction.
#[inline(always)]
pub fn hamming(a: &Descriptor, b: &Descriptor) -> u32 {
    (a[0] ^ b[0]).count_ones()
        + (a[1] ^ b[1]).count_ones()
        + (a[2] ^ b[2]).count_ones()
        + (a[3] ^ b[3]).count_ones()
}

/// An oriented keypoint in level-0 pixel coordinates.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct KeyPoint {
    /// Column (level-0 pixels).
    pub u: f32,
    /// Row (level-0 pixels).
    pub v: f32,
    /// Orientation (radians) of the intensity centroid, `atan2(m₀₁, m₁₀)`.
    pub angle: f32,
    /// Harris response (the ranking score).
    pub response: f32,
    /// Pyramid level.
    pub level: usize,
    /// Scale factor of the level (`scale_factor^level`).
    pub scale: f32,
}

/// Parameters of the ORB extractor (defaults as OpenCV's `ORB::create()`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OrbParams {
    /// Number of features to keep in total.
    pub num_features: usize,
    /// Scale ratio between consecutive levels (> 1).
    pub scale_factor: f32,
    /// Number of pyramid levels.
    pub num_levels: usize,
    /// Keypoints closer than this to a level's border are dropped.
    pub edge_threshold: usize,
    /// FAST threshold.
    pub fast_threshold: u8,
}

impl Default for OrbParams {
    /// 500 features, scale 1.2, 8 levels, edge threshold 31, FAST threshold 20.
    fn default() -> Self {
        Self {
            num_features: 500,
            scale_factor: 1.2,
            num_levels: 8,
            edge_threshold: 31,
            fast_threshold: 20,
        }
    }
}

const HALF_PATCH: i32 = 15;

/// The BRIEF test pairs `(x₁, y₁, x₂, y₂)`: 256 pairs, Gaussian `σ = 31/5`, each coordinate
/// rounded and clipped so that the point stays within radius 13 (inside the radius-15 patch
/// after any rotation and rounding).
pub fn brief_pattern() -> &'static [[i8; 4]; 256] {
    static PATTERN: OnceLock<[[i8; 4]; 256]> = OnceLock::new();
    PATTERN.get_or_init(|| {
        let mut rng = ChaCha8Rng::seed_from_u64(0x0b1e_f256);
        let normal = Normal::new(0.0f64, 31.0 / 5.0).expect("valid σ");
        let mut draw = || loop {
            let (x, y) = (
                normal.sample(&mut rng).round(),
                normal.sample(&mut rng).round(),
            );
            if x * x + y * y <= 13.0 * 13.0 {
                return (x as i8, y as i8);
            }
        };
        let mut p = [[0i8; 4]; 256];
        for pair in p.iter_mut() {
            loop {
                let (a, b) = (draw(), draw());
                if a != b {
                    *pair = [a.0, a.1, b.0, b.1];
                    break;
                }
            }
        }
        p
    })
}

/// `u_max[dv]`: half-width of the circular patch of radius 15 at row offset `dv`.
fn umax() -> &'static [i32; 16] {
    static U: OnceLock<[i32; 16]> = OnceLock::new();
    U.get_or_init(|| {
        let mut u = [0i32; 16];
        for (dv, x) in u.iter_mut().enumerate() {
            *x = ((HALF_PATCH * HALF_PATCH - (dv * dv) as i32) as f32)
                .sqrt()
                .floor() as i32;
        }
        u
    })
}

/// Orientation by the intensity centroid over the radius-15 disc:
/// `θ = atan2(m₀₁, m₁₀)`, `m_pq = Σ uᵖ vᵠ I(u, v)`.
fn ic_angle(img: &GrayImage, u: usize, v: usize) -> f32 {
    let um = umax();
    let (mut m01, mut m10) = (0i32, 0i32);
    let centre = &img.row(v)[u - 15..u + 16];
    for (k, &p) in centre.iter().enumerate() {
        m10 += (k as i32 - 15) * p as i32;
    }
    for (dv, &d) in um.iter().enumerate().skip(1) {
        let d = d as usize;
        let rp = &img.row(v + dv)[u - d..u + d + 1];
        let rm = &img.row(v - dv)[u - d..u + d + 1];
        let mut vsum = 0i32;
        for (k, (&p, &m)) in rp.iter().zip(rm).enumerate() {
            let (p, m) = (p as i32, m as i32);
            vsum += p - m;
            m10 += (k as i32 - d as i32) * (p + m);
        }
        m01 += dv as i32 * vsum;
    }
    (m01 as f32).atan2(m10 as f32)
}

/// Number of orientation bins of the steered pattern: 30 (12° steps), as in Rublee et al.
/// (2011, §4.2), which precompute the rotated BRIEF pattern for discretised angles.
pub const ANGLE_BINS: usize = 30;

/// The pattern rotated to each angle bin `b` (angle `2πb/30`), rounded to integer offsets
/// `(dx, dy)` for the 512 sample points (pairs interleaved: `p_i` at `2i`, `q_i` at `2i + 1`).
type SteeredTables = [[(i8, i8); 512]; ANGLE_BINS];

fn steered_patterns() -> &'static SteeredTables {
    static P: OnceLock<Box<SteeredTables>> = OnceLock::new();
    P.get_or_init(|| {
        let mut out = Box::new([[(0i8, 0i8); 512]; ANGLE_BINS]);
        for (b, table) in out.iter_mut().enumerate() {
            let a = b as f32 * 2.0 * std::f32::consts::PI / ANGLE_BINS as f32;
            let (s, c) = a.sin_cos();
            for (i, p) in brief_pattern().iter().enumerate() {
                for (j, (x, y)) in [(p[0], p[1]), (p[2], p[3])].into_iter().enumerate() {
                    let (x, y) = (x as f32, y as f32);
                    let rx = (x * c - y * s).round() as i8;
                    let ry = (x * s + y * c).round() as i8;
                    table[2 * i + j] = (rx, ry);
                }
            }
        }
        out
    })
}

/// Computes the steered BRIEF descriptor at `(u, v)` of a smoothed level image with angle `θ`
/// (discretised to [`ANGLE_BINS`] bins): bit `i` is `I(R_θ p_i) < I(R_θ q_i)` for the pattern
/// pair `(p_i, q_i)`.
fn describe(img: &GrayImage, u: usize, v: usize, angle: f32) -> Descriptor {
    let turns = angle / (2.0 * std::f32::consts::PI);
    let bin = ((turns - turns.floor()) * ANGLE_BINS as f32).round() as usize % ANGLE_BINS;
    let table = &steered_patterns()[bin];
    // Flat offsets from the keypoint: every steered point lies within radius 15, inside the
    // image since keypoints keep at least 16 pixels from the border.
    let st = img.stride() as isize;
    let data = &img.data()[(v - 15) * img.stride() + u - 15..(v + 15) * img.stride() + u + 16];
    let centre = 15 * st + 15;
    let mut a = [0u8; 256];
    let mut b = [0u8; 256];
    for i in 0..256 {
        let (px, py) = table[2 * i];
        let (qx, qy) = table[2 * i + 1];
        a[i] = data[(centre + py as isize * st + px as isize) as usize];
        b[i] = data[(centre + qy as isize * st + qx as isize) as usize];
    }
    let mut d = [0u64; 4];
    for (w, dw) in d.iter_mut().enumerate() {
        let mut bits = 0u64;
        for k in 0..64 {
            bits |= ((a[w * 64 + k] < b[w * 64 + k]) as u64) << k;
        }
        *dw = bits;
    }
    d
}

/// Detects ORB keypoints and computes their descriptors.
///
/// Per level `l` (image resized by `1/scale_factorˡ`): FAST-9 with non-maximum suppression,
/// keypoints within `edge_threshold` of the border dropped, the best `2·n_l` by FAST score
/// re-ranked by Harris response (7×7 window, `k = 0.04`), the best `n_l` kept, where
/// `n_l ∝ scale_factor^{−l}` sums to `num_features`; then the intensity-centroid orientation and
/// the steered BRIEF descriptor (30 angle bins) on the level smoothed with a 7×7 Gaussian
/// (`σ = 2`).
pub fn detect_and_describe(
    img: &GrayImage,
    params: &OrbParams,
) -> Result<(Vec<KeyPoint>, Vec<Descriptor>), ImageError> {
    if img.is_empty() {
        return Err(ImageError::Empty {
            path: "<orb input>".into(),
            width: img.width(),
            height: img.height(),
        });
    }
    let nl = params.num_levels.max(1);
    let sf = params.scale_factor.max(1.0001);
    let inv = 1.0 / sf;
    let total_weight: f32 = (0..nl).map(|l| inv.powi(l as i32)).sum();
    let mut kps = Vec::new();
    let mut descs = Vec::new();
    let mut assigned = 0usize;
    let mut prev_level: Option<GrayImage> = None;
    let border = params.edge_threshold.max(HALF_PATCH as usize + 1);
    for l in 0..nl {
        let scale = sf.powi(l as i32);
        let (w, h) = (
            (img.width() as f32 / scale).round() as usize,
            (img.height() as f32 / scale).round() as usize,
        );
        if w <= 2 * border || h <= 2 * border {
            break;
        }
        let n_l = if l == nl - 1 {
            params.num_features.saturating_sub(assigned)
        } else {
            ((params.num_features as f32 * inv.powi(l as i32) / total_weight).round() as usize)
                .min(params.num_features - assigned)
        };
        // Each level is resized from the previous one (as OpenCV's ORB does).
        let level = if l == 0 {
            img.clone()
        } else {
            resize_bilinear(prev_level.as_ref().unwrap_or(img), w, h)?
        };
        let mut corners: Vec<_> = fast9_level(&level, params.fast_threshold, true, l)
            .into_iter()
            .filter(|c| {
                let (u, v) = (c.u as usize, c.v as usize);
                u >= border && v >= border && u + border < w && v + border < h
            })
            .collect();
        corners.sort_by(|a, b| b.score.total_cmp(&a.score));
        corners.truncate(2 * n_l);
        for c in corners.iter_mut() {
            c.score = harris_score(&level, c.u as usize, c.v as usize, 3, 0.04).unwrap_or(f32::MIN);
        }
        corners.sort_by(|a, b| b.score.total_cmp(&a.score));
        corners.truncate(n_l);
        let blurred = gaussian_blur_radius(&level, 2.0, 3);
        for c in &corners {
            let (u, v) = (c.u as usize, c.v as usize);
            let angle = ic_angle(&level, u, v);
            descs.push(describe(&blurred, u, v, angle));
            kps.push(KeyPoint {
                u: (c.u + 0.5) * scale - 0.5,
                v: (c.v + 0.5) * scale - 0.5,
                angle,
                response: c.score,
                level: l,
                scale,
            });
        }
        assigned += corners.len();
        prev_level = Some(level);
    }
    Ok((kps, descs))
}

/// A descriptor match: `query` index into the first set, `train` into the second.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct DMatch {
    /// Index in the query set.
    pub query: usize,
    /// Index in the train set.
    pub train: usize,
    /// Hamming distance.
    pub distance: u32,
}

/// Brute-force Hamming matching with Lowe's ratio test: the nearest train descriptor is
/// accepted if `d₁ < ratio·d₂` (second nearest `d₂`) and `d₁ ≤ max_distance`; with
/// `cross_check`, only if the query is also the train descriptor's nearest neighbour.
pub fn match_descriptors(
    query: &[Descriptor],
    train: &[Descriptor],
    max_distance: u32,
    ratio: f32,
    cross_check: bool,
) -> Vec<DMatch> {
    #[cfg(target_arch = "x86_64")]
    if cross_check && avx512_popcount() {
        // SAFETY: the CPU has AVX-512 F and VPOPCNTDQ (checked just above).
        let (fwd, back) = unsafe { avx512::nearest_both_ways(query, train) };
        return accept(&fwd, &back, max_distance, ratio, cross_check);
    }
    #[cfg(target_arch = "x86_64")]
    if crate::simd::enabled() && std::arch::is_x86_feature_detected!("popcnt") {
        // SAFETY: the CPU has POPCNT (checked just above).
        return unsafe { match_popcnt(query, train, max_distance, ratio, cross_check) };
    }
    match_impl(query, train, max_distance, ratio, cross_check)
}

/// Whether [`avx512::nearest_both_ways`] may run: the AVX-512 kernels are on
/// ([`crate::simd::avx512`]) and the CPU counts bits in 64-bit lanes (VPOPCNTDQ).
#[cfg(target_arch = "x86_64")]
fn avx512_popcount() -> bool {
    crate::simd::avx512() && std::arch::is_x86_feature_detected!("avx512vpopcntdq")
}

/// Cross-checked matching's distance matrix, eight train descriptors per vector (AVX-512 F
/// and VPOPCNTDQ): the place recognition's verification matches every ORB keypoint of one
/// keyframe against every one of another, a million distances per hypothesis on a KITTI
/// image, 11 % of a monocular KITTI run with one POPCNT per 64-bit word. Same results as
/// [`nearest_both_ways`] (ties to the lower index both ways; a test compares them).
#[cfg(target_arch = "x86_64")]
mod avx512 {
    use super::{Descriptor, Nearest, nearer};
    use std::arch::x86_64::*;

    /// [`super::nearest_both_ways`] with the train descriptors in structure-of-arrays blocks
    /// of eight (word `k` of train `8·b + l` at `(4·b + k)·8 + l`): one query's distances to a
    /// block are four XORs, four lane popcounts and three additions. A block whose smallest
    /// distance is not below the query's second-nearest so far changes nothing forward and
    /// is skipped; the backward minima are kept per lane with masked stores.
    #[target_feature(enable = "avx512f,avx512vpopcntdq")]
    pub(super) unsafe fn nearest_both_ways(
        a: &[Descriptor],
        b: &[Descriptor],
    ) -> (Vec<Nearest>, Vec<(usize, u32)>) {
        let blocks = b.len().div_ceil(8);
        let mut soa = vec![0u64; blocks * 32];
        for (j, t) in b.iter().enumerate() {
            let (block, lane) = (j / 8, j % 8);
            for (k, &w) in t.iter().enumerate() {
                soa[(4 * block + k) * 8 + lane] = w;
            }
        }
        // Lanes past the end of `b` in the last block: their distance is u64::MAX.
        let tail = match b.len() % 8 {
            0 => 0xffu8,
            r => (1u8 << r) - 1,
        };
        let mut back_d = vec![u64::MAX; blocks * 8];
        let mut back_i = vec![u64::MAX; blocks * 8];
        let mut lanes = [0u64; 8];
        let mut out = Vec::with_capacity(a.len());
        // SAFETY (all loads and stores below): `soa` holds `32·blocks` words and `back_d`,
        // `back_i` `8·blocks`, and every offset is `32·block + 8·k` or `8·block` with
        // `block < blocks`, `k < 4`: each 8-word access is in bounds. Unaligned accesses.
        unsafe {
            let max = _mm512_set1_epi64(-1);
            for (i, q) in a.iter().enumerate() {
                let qw = q.map(|w| _mm512_set1_epi64(w as i64));
                let index = _mm512_set1_epi64(i as i64);
                let mut n: Nearest = (usize::MAX, u32::MAX, u32::MAX);
                for block in 0..blocks {
                    let base = soa.as_ptr().add(32 * block);
                    let mut d = _mm512_setzero_si512();
                    for (k, w) in qw.iter().enumerate() {
                        let t = _mm512_loadu_si512(base.add(8 * k).cast());
                        d = _mm512_add_epi64(d, _mm512_popcnt_epi64(_mm512_xor_si512(t, *w)));
                    }
                    let valid = if block + 1 == blocks { tail } else { 0xff };
                    let d = _mm512_mask_mov_epi64(max, valid, d);
                    let bd = back_d.as_mut_ptr().add(8 * block);
                    let closer = _mm512_cmplt_epu64_mask(d, _mm512_loadu_si512(bd.cast()));
                    if closer != 0 {
                        _mm512_mask_storeu_epi64(bd.cast(), closer, d);
                        _mm512_mask_storeu_epi64(
                            back_i.as_mut_ptr().add(8 * block).cast(),
                            closer,
                            index,
                        );
                    }
                    if _mm512_reduce_min_epu64(d) < n.2 as u64 {
                        _mm512_storeu_si512(lanes.as_mut_ptr().cast(), d);
                        for (lane, &d) in lanes.iter().enumerate() {
                            let j = 8 * block + lane;
                            if j >= b.len() {
                                break;
                            }
                            nearer(&mut n, j, d as u32);
                        }
                    }
                }
                out.push(n);
            }
        }
        let back = (0..b.len())
            .map(|j| match back_i[j] {
                u64::MAX => (usize::MAX, u32::MAX),
                i => (i as usize, back_d[j] as u32),
            })
            .collect();
        (out, back)
    }
}

/// [`match_impl`] compiled with the POPCNT instruction: `count_ones` of a u64 becomes one
/// instruction instead of the baseline x86-64 bit-trick sequence (same results).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "popcnt")]
unsafe fn match_popcnt(
    query: &[Descriptor],
    train: &[Descriptor],
    max_distance: u32,
    ratio: f32,
    cross_check: bool,
) -> Vec<DMatch> {
    match_impl(query, train, max_distance, ratio, cross_check)
}

#[inline(always)]
fn match_impl(
    query: &[Descriptor],
    train: &[Descriptor],
    max_distance: u32,
    ratio: f32,
    cross_check: bool,
) -> Vec<DMatch> {
    let (fwd, back) = if cross_check {
        nearest_both_ways(query, train)
    } else {
        (nearest(query, train), Vec::new())
    };
    accept(&fwd, &back, max_distance, ratio, cross_check)
}

/// The matches of the nearest neighbours `fwd` (and, cross-checked, the train side's nearest
/// `back`) that pass the distance, ratio and cross-check tests.
#[inline(always)]
fn accept(
    fwd: &[Nearest],
    back: &[(usize, u32)],
    max_distance: u32,
    ratio: f32,
    cross_check: bool,
) -> Vec<DMatch> {
    fwd.iter()
        .enumerate()
        .filter_map(|(i, &(j, d1, d2))| {
            if j == usize::MAX || d1 > max_distance {
                return None;
            }
            if d2 != u32::MAX && (d1 as f32) >= ratio * d2 as f32 {
                return None;
            }
            if cross_check && back[j].0 != i {
                return None;
            }
            Some(DMatch {
                query: i,
                train: j,
                distance: d1,
            })
        })
        .collect()
}

/// A descriptor's nearest neighbour: its index and distance, and the second-nearest distance.
type Nearest = (usize, u32, u32);

/// Takes train descriptor `j` at distance `d` into the two nearest so far (a tie keeps the
/// earlier, lower index).
#[inline(always)]
fn nearer(n: &mut Nearest, j: usize, d: u32) {
    if d < n.1 {
        *n = (j, d, n.1);
    } else if d < n.2 {
        n.2 = d;
    }
}

/// [`nearest`] from `a` into `b`, and the nearest of `a` for each of `b` (its index), from one
/// pass over the distance matrix: cross-checked matching computes each distance once, not
/// twice. Ties go to the lower index both ways, as [`nearest`]'s.
#[inline(always)]
fn nearest_both_ways(a: &[Descriptor], b: &[Descriptor]) -> (Vec<Nearest>, Vec<(usize, u32)>) {
    let mut out = Vec::with_capacity(a.len());
    let mut back = vec![(usize::MAX, u32::MAX); b.len()];
    for (i, q) in a.iter().enumerate() {
        let mut n: Nearest = (usize::MAX, u32::MAX, u32::MAX);
        for j in 0..b.len() {
            let d = hamming(q, &b[j]);
            nearer(&mut n, j, d);
            if d < back[j].1 {
                back[j] = (i, d);
            }
        }
        out.push(n);
    }
    (out, back)
}

/// For each descriptor of `a`, the index of its nearest in `b` and the two smallest distances.
/// Plain loops, no closures or iterator adaptors: `#[inline(always)]` then puts the Hamming
/// distances inside [`match_popcnt`]'s POPCNT instance (as a `map(..).collect()` they were
/// compiled in the generic `Vec::from_iter`, without POPCNT: 5 % of a 7-Scenes mono run).
#[inline(always)]
fn nearest(a: &[Descriptor], b: &[Descriptor]) -> Vec<Nearest> {
    let mut out = Vec::with_capacity(a.len());
    for q in a {
        let mut n: Nearest = (usize::MAX, u32::MAX, u32::MAX);
        for (j, t) in b.iter().enumerate() {
            nearer(&mut n, j, hamming(q, t));
        }
        out.push(n);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::pyramid::gaussian_blur;

    fn textured(w: usize, h: usize, seed: u64) -> GrayImage {
        let mut x = seed;
        let noise = GrayImage::from_fn(w, h, |_, _| {
            x = x
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (x >> 56) as u8
        });
        gaussian_blur(&noise, 1.5)
    }

    #[test]
    fn pattern_fits_patch_after_rotation() {
        for p in brief_pattern() {
            for (x, y) in [(p[0], p[1]), (p[2], p[3])] {
                assert!(((x as f32).powi(2) + (y as f32).powi(2)).sqrt() <= 13.0);
            }
        }
        assert_eq!(brief_pattern(), brief_pattern());
    }

    #[test]
    fn matches_a_shifted_image() {
        let a = textured(320, 240, 11);
        let b =
            crate::image::Image::from_fn(320, 240, |u, v| a.get((u + 313) % 320, (v + 235) % 240));
        // b(u, v) = a(u − 7, v − 5) (cyclic), so keypoints move by (+7, +5).
        let p = OrbParams {
            num_features: 300,
            ..Default::default()
        };
        let (ka, da) = detect_and_describe(&a, &p).unwrap();
        let (kb, db) = detect_and_describe(&b, &p).unwrap();
        assert!(ka.len() > 100, "{}", ka.len());
        let m = match_descriptors(&da, &db, 64, 0.8, true);
        assert!(m.len() > 50, "{}", m.len());
        let good = m
            .iter()
            .filter(|m| {
                let (x, y) = (&ka[m.query], &kb[m.train]);
                ((y.u - x.u - 7.0).powi(2) + (y.v - x.v - 5.0).powi(2)).sqrt() < 2.0
            })
            .count();
        assert!(good as f32 > 0.9 * m.len() as f32, "{good}/{}", m.len());
    }

    /// `n` pseudo-random descriptors from the LCG state `x`, each word passed through `bits`.
    fn descriptors(x: &mut u64, n: usize, bits: impl Fn(u64) -> u64) -> Vec<Descriptor> {
        (0..n)
            .map(|_| {
                std::array::from_fn(|_| {
                    *x = x
                        .wrapping_mul(6364136223846793005)
                        .wrapping_add(1442695040888963407);
                    bits(*x)
                })
            })
            .collect()
    }

    #[test]
    fn popcnt_and_scalar_matching_agree() {
        let mut x = 3u64;
        let q = descriptors(&mut x, 60, |w| w);
        let mut t = descriptors(&mut x, 80, |w| w);
        t[7] = q[3];
        t[9] = [q[5][0] ^ 1, q[5][1], q[5][2], q[5][3]];
        let fast = match_descriptors(&q, &t, 100, 0.9, true);
        let scalar = crate::simd::scalar_only(|| match_descriptors(&q, &t, 100, 0.9, true));
        assert_eq!(fast, scalar);
        assert!(
            fast.iter()
                .any(|m| m.query == 3 && m.train == 7 && m.distance == 0)
        );
    }

    /// The AVX-512 distance matrix gives the POPCNT build's matches and nearest neighbours,
    /// ties included (sparse descriptors: many equal distances), for train sets that fill
    /// their last block of eight and for those that do not, and for empty sets.
    #[test]
    fn avx512_and_popcnt_matching_agree() {
        #[cfg(target_arch = "x86_64")]
        {
            if !avx512_popcount() {
                println!("no AVX-512 VPOPCNTDQ here: nothing to compare");
                return;
            }
            let sparse = |w: u64| w & (w >> 17) & (w >> 31);
            let mut x = 5u64;
            for (nq, nt) in [(70, 90), (33, 8), (9, 1), (0, 12), (12, 0), (200, 257)] {
                for dense in [false, true] {
                    let bits = |w: u64| if dense { w } else { sparse(w) };
                    let q = descriptors(&mut x, nq, bits);
                    let t = descriptors(&mut x, nt, bits);
                    // SAFETY: checked above.
                    let simd = unsafe { avx512::nearest_both_ways(&q, &t) };
                    assert_eq!(simd, nearest_both_ways(&q, &t), "{nq}×{nt}, dense {dense}");
                    let fast = match_descriptors(&q, &t, 100, 0.9, true);
                    let without =
                        crate::simd::without_avx512(|| match_descriptors(&q, &t, 100, 0.9, true));
                    assert_eq!(fast, without);
                }
            }
        }
    }

    #[test]
    fn one_pass_cross_check_equals_two_passes() {
        // Sparse descriptors (a few bits each): many equal distances, so the ties count.
        let mut x = 11u64;
        let sparse = |w: u64| w & (w >> 17) & (w >> 31) & (w >> 45);
        let q = descriptors(&mut x, 70, sparse);
        let t = descriptors(&mut x, 90, sparse);
        let (fwd, back) = nearest_both_ways(&q, &t);
        assert_eq!(fwd, nearest(&q, &t));
        let reference: Vec<usize> = nearest(&t, &q).iter().map(|n| n.0).collect();
        assert_eq!(back.iter().map(|b| b.0).collect::<Vec<_>>(), reference);
    }

    #[test]
    fn small_images_give_no_features_not_panics() {
        for (w, h) in [(1, 1), (31, 40), (63, 63), (64, 64)] {
            let (k, d) = detect_and_describe(&textured(w, h, 1), &OrbParams::default()).unwrap();
            assert_eq!(k.len(), d.len());
        }
        assert!(detect_and_describe(&GrayImage::new(0, 5), &OrbParams::default()).is_err());
    }
}
