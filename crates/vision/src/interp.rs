//! Bilinear sampling with gradients, and on affine grids (patches).

use crate::image::{GrayImage, Image};

/// A pixel type that can be read as `f32` intensity.
pub trait Pixel: Copy + Default + Send + Sync {
    /// The intensity as `f32`.
    fn to_f32(self) -> f32;

    /// `img` as an 8-bit image if the pixels are `u8` (the kernels with an AVX2 path take
    /// those), else `None`.
    #[inline]
    fn as_gray(img: &Image<Self>) -> Option<&GrayImage>
    where
        Self: Sized,
    {
        let _ = img;
        None
    }
}
impl Pixel for u8 {
    #[inline]
    fn to_f32(self) -> f32 {
        self as f32
    }

    #[inline]
    fn as_gray(img: &Image<Self>) -> Option<&GrayImage> {
        Some(img)
    }
}
impl Pixel for f32 {
    #[inline]
    fn to_f32(self) -> f32 {
        self
    }
}
impl Pixel for u16 {
    #[inline]
    fn to_f32(self) -> f32 {
        self as f32
    }
}

/// Bilinear interpolation at real coordinates `(u, v)` (pixel centres at integers):
/// with `u = u₀ + a`, `v = v₀ + b`,
/// `I(u, v) = (1−a)(1−b) I₀₀ + a(1−b) I₁₀ + (1−a) b I₀₁ + a b I₁₁`.
///
/// Returns `None` unless `0 ≤ u ≤ w − 1` and `0 ≤ v ≤ h − 1`.
#[inline]
pub fn bilinear<T: Pixel>(img: &Image<T>, u: f32, v: f32) -> Option<f32> {
    if !(u >= 0.0 && v >= 0.0 && u <= (img.width() - 1) as f32 && v <= (img.height() - 1) as f32) {
        return None;
    }
    let u0 = (u as usize).min(img.width().saturating_sub(2));
    let v0 = (v as usize).min(img.height().saturating_sub(2));
    let a = u - u0 as f32;
    let b = v - v0 as f32;
    let s = img.stride();
    let d = img.data();
    let i = v0 * s + u0;
    let u1 = if img.width() > 1 { 1 } else { 0 };
    let v1 = if img.height() > 1 { s } else { 0 };
    let i00 = d[i].to_f32();
    let i10 = d[i + u1].to_f32();
    let i01 = d[i + v1].to_f32();
    let i11 = d[i + v1 + u1].to_f32();
    Some((1.0 - b) * ((1.0 - a) * i00 + a * i10) + b * ((1.0 - a) * i01 + a * i11))
}

/// Bilinear samples of `img` on an `n×n` affine grid centred at `(u, v)`: sample `(i, j)`
/// (row-major in `out[..n²]`) is [`bilinear`] at `(u + a₀₀·o_x + a₀₁·o_y, v + a₁₀·o_x + a₁₁·o_y)`
/// with `o = (j − (n−1)/2, i − (n−1)/2)` and `a = [a₀₀, a₀₁, a₁₀, a₁₁]` (the patch warp of
/// [`crate::patch`]). Returns `false` (with `out` unspecified) if any sample leaves the image.
///
/// For 8-bit images and `n ≥ 8` an AVX2 kernel computes eight samples of a row at once (the
/// same coordinates, taps and weights in the same order, so the same values bit for bit).
pub fn bilinear_grid<T: Pixel>(
    img: &Image<T>,
    u: f32,
    v: f32,
    a: [f32; 4],
    n: usize,
    out: &mut [f32],
) -> bool {
    assert!(
        out.len() >= n * n,
        "output of {} for a {n}×{n} grid",
        out.len()
    );
    #[cfg(target_arch = "x86_64")]
    if n >= 8
        && let Some(g) = T::as_gray(img)
        && g.width() >= 2
        && g.height() >= 2
        && crate::simd::avx2()
    {
        // SAFETY: AVX2 is available (checked); the kernel checks its reads (see there).
        return unsafe { bilinear_grid_avx2(g, u, v, a, n, out) };
    }
    bilinear_grid_scalar(img, u, v, a, n, out)
}

/// The scalar reference of [`bilinear_grid`].
fn bilinear_grid_scalar<T: Pixel>(
    img: &Image<T>,
    u: f32,
    v: f32,
    a: [f32; 4],
    n: usize,
    out: &mut [f32],
) -> bool {
    let h = (n as f32 - 1.0) / 2.0;
    let [a00, a01, a10, a11] = a;
    for i in 0..n {
        for j in 0..n {
            let (ox, oy) = (j as f32 - h, i as f32 - h);
            match bilinear(img, u + a00 * ox + a01 * oy, v + a10 * ox + a11 * oy) {
                Some(x) => out[i * n + j] = x,
                None => return false,
            }
        }
    }
    true
}

/// AVX2 kernel of [`bilinear_grid`] for 8-bit images of at least 2×2 pixels and `n ≥ 8`: per
/// grid row, steps of eight samples (the last step overlapping the previous one and recomputing
/// identical values); the two horizontal taps of each row pair come from one dword gather at
/// `v₀·stride + u₀` and one at the row below, or, when the eight `(u₀, v₀)` are consecutive
/// pixels of one row, from two 16-byte row loads (2.4× faster than the gathers here). A step whose dwords would reach past the image
/// buffer (the last pixels of the last row) falls back to [`bilinear`] for its samples.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn bilinear_grid_avx2(
    img: &GrayImage,
    u: f32,
    v: f32,
    a: [f32; 4],
    n: usize,
    out: &mut [f32],
) -> bool {
    use std::arch::x86_64::*;
    let (w, hh, stride) = (img.width(), img.height(), img.stride());
    let data = img.data();
    assert!(n >= 8 && w >= 2 && hh >= 2 && out.len() >= n * n);
    let half = (n as f32 - 1.0) / 2.0;
    // SAFETY: stores write out[i·n + j0 .. + 8] with j0 + 8 ≤ n; gathers read the dwords at
    // byte offsets idx and idx + stride for lanes inside the image (all lanes are checked before
    // the gathers), whose last byte idx + stride + 3 is checked against the buffer length; the
    // row loads read data[idx₀ .. idx₀ + stride + 16], checked against it too.
    unsafe {
        let [a00, a01, a10, a11] = a.map(|x| _mm256_set1_ps(x));
        let (uv, vv) = (_mm256_set1_ps(u), _mm256_set1_ps(v));
        let zero = _mm256_setzero_ps();
        let one = _mm256_set1_ps(1.0);
        let (umax, vmax) = (
            _mm256_set1_ps((w - 1) as f32),
            _mm256_set1_ps((hh - 1) as f32),
        );
        let (u0max, v0max) = (
            _mm256_set1_epi32(w as i32 - 2),
            _mm256_set1_epi32(hh as i32 - 2),
        );
        let sv = _mm256_set1_epi32(stride as i32);
        let last = _mm256_set1_epi32(data.len() as i32 - 1);
        let byte = _mm256_set1_epi32(0xFF);
        let base = data.as_ptr() as *const i32;
        let iota = _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7);
        let steps = n.div_ceil(8);
        // Column steps outside, rows inside: the offsets o_x of a step are formed once.
        for s in 0..steps {
            let j0 = (8 * s).min(n - 8);
            let ox = _mm256_setr_ps(
                j0 as f32 - half,
                (j0 + 1) as f32 - half,
                (j0 + 2) as f32 - half,
                (j0 + 3) as f32 - half,
                (j0 + 4) as f32 - half,
                (j0 + 5) as f32 - half,
                (j0 + 6) as f32 - half,
                (j0 + 7) as f32 - half,
            );
            let (uo, vo) = (
                _mm256_add_ps(uv, _mm256_mul_ps(a00, ox)),
                _mm256_add_ps(vv, _mm256_mul_ps(a10, ox)),
            );
            for i in 0..n {
                let oy = _mm256_set1_ps(i as f32 - half);
                let us = _mm256_add_ps(uo, _mm256_mul_ps(a01, oy));
                let vs = _mm256_add_ps(vo, _mm256_mul_ps(a11, oy));
                let inside = _mm256_and_ps(
                    _mm256_and_ps(
                        _mm256_cmp_ps::<_CMP_GE_OQ>(us, zero),
                        _mm256_cmp_ps::<_CMP_GE_OQ>(vs, zero),
                    ),
                    _mm256_and_ps(
                        _mm256_cmp_ps::<_CMP_LE_OQ>(us, umax),
                        _mm256_cmp_ps::<_CMP_LE_OQ>(vs, vmax),
                    ),
                );
                if _mm256_movemask_ps(inside) != 0xFF {
                    return false;
                }
                let u0 = _mm256_min_epi32(_mm256_cvttps_epi32(us), u0max);
                let v0 = _mm256_min_epi32(_mm256_cvttps_epi32(vs), v0max);
                let idx = _mm256_add_epi32(_mm256_mullo_epi32(v0, sv), u0);
                let below = _mm256_add_epi32(idx, sv);
                let o = out.as_mut_ptr().add(i * n + j0);
                let end = _mm256_add_epi32(below, _mm256_set1_epi32(3));
                if _mm256_movemask_epi8(_mm256_cmpgt_epi32(end, last)) != 0 {
                    let mut us_a = [0.0f32; 8];
                    let mut vs_a = [0.0f32; 8];
                    _mm256_storeu_ps(us_a.as_mut_ptr(), us);
                    _mm256_storeu_ps(vs_a.as_mut_ptr(), vs);
                    for k in 0..8 {
                        match bilinear(img, us_a[k], vs_a[k]) {
                            Some(x) => *o.add(k) = x,
                            None => return false,
                        }
                    }
                    continue;
                }
                // The taps: when the eight samples start at consecutive pixels of one row (an
                // axis-aligned or mildly warped patch), two 16-byte row loads; else gathers.
                let first = _mm256_broadcastd_epi32(_mm256_castsi256_si128(idx));
                let idx0 = _mm256_cvtsi256_si32(idx) as usize;
                let (i00, i10, i01, i11) =
                    if _mm256_movemask_epi8(_mm256_cmpeq_epi32(idx, _mm256_add_epi32(first, iota)))
                        == -1
                        && idx0 + stride + 16 <= data.len()
                    {
                        let p = data.as_ptr().add(idx0);
                        let r0 = _mm_loadu_si128(p as *const __m128i);
                        let r1 = _mm_loadu_si128(p.add(stride) as *const __m128i);
                        let widen = |r: __m128i| _mm256_cvtepi32_ps(_mm256_cvtepu8_epi32(r));
                        (
                            widen(r0),
                            widen(_mm_srli_si128::<1>(r0)),
                            widen(r1),
                            widen(_mm_srli_si128::<1>(r1)),
                        )
                    } else {
                        let g0 = _mm256_i32gather_epi32::<1>(base, idx);
                        let g1 = _mm256_i32gather_epi32::<1>(base, below);
                        let tap = |g: __m256i| _mm256_cvtepi32_ps(_mm256_and_si256(g, byte));
                        let tap_right = |g: __m256i| {
                            _mm256_cvtepi32_ps(_mm256_and_si256(_mm256_srli_epi32::<8>(g), byte))
                        };
                        (tap(g0), tap_right(g0), tap(g1), tap_right(g1))
                    };
                let fa = _mm256_sub_ps(us, _mm256_cvtepi32_ps(u0));
                let fb = _mm256_sub_ps(vs, _mm256_cvtepi32_ps(v0));
                let (na, nb) = (_mm256_sub_ps(one, fa), _mm256_sub_ps(one, fb));
                // (1−b)((1−a)I₀₀ + a I₁₀) + b((1−a)I₀₁ + a I₁₁), as `bilinear`.
                let top = _mm256_add_ps(_mm256_mul_ps(na, i00), _mm256_mul_ps(fa, i10));
                let bottom = _mm256_add_ps(_mm256_mul_ps(na, i01), _mm256_mul_ps(fa, i11));
                let val = _mm256_add_ps(_mm256_mul_ps(nb, top), _mm256_mul_ps(fb, bottom));
                _mm256_storeu_ps(o, val);
            }
        }
    }
    true
}

/// Bilinear interpolation of the intensity and of its central-difference gradient
/// `∂I/∂u ≈ (I(u+1, v) − I(u−1, v))/2`, `∂I/∂v ≈ (I(u, v+1) − I(u, v−1))/2`.
///
/// Returns `(I, ∂I/∂u, ∂I/∂v)`, or `None` unless `1 ≤ u ≤ w − 2` and `1 ≤ v ≤ h − 2`.
#[inline]
pub fn bilinear_with_gradient<T: Pixel>(img: &Image<T>, u: f32, v: f32) -> Option<(f32, f32, f32)> {
    if !(u >= 1.0
        && v >= 1.0
        && u <= (img.width() as f32 - 2.0)
        && v <= (img.height() as f32 - 2.0))
    {
        return None;
    }
    let u0 = (u as usize).min(img.width() - 3);
    let v0 = (v as usize).min(img.height() - 3);
    let a = u - u0 as f32;
    let b = v - v0 as f32;
    let s = img.stride();
    let d = img.data();
    let p = |du: isize, dv: isize| -> f32 {
        d[((v0 as isize + dv) as usize) * s + (u0 as isize + du) as usize].to_f32()
    };
    let val = |du: isize, dv: isize| p(du, dv);
    let gu = |du: isize, dv: isize| 0.5 * (p(du + 1, dv) - p(du - 1, dv));
    let gv = |du: isize, dv: isize| 0.5 * (p(du, dv + 1) - p(du, dv - 1));
    let w00 = (1.0 - a) * (1.0 - b);
    let w10 = a * (1.0 - b);
    let w01 = (1.0 - a) * b;
    let w11 = a * b;
    let mix = |f: &dyn Fn(isize, isize) -> f32| {
        w00 * f(0, 0) + w10 * f(1, 0) + w01 * f(0, 1) + w11 * f(1, 1)
    };
    Some((mix(&val), mix(&gu), mix(&gv)))
}

/// Central-difference gradient images `(∂I/∂u, ∂I/∂v)` as `f32` (one-sided at the border).
pub fn gradient_images<T: Pixel>(img: &Image<T>) -> (Image<f32>, Image<f32>) {
    let (w, h) = (img.width(), img.height());
    let mut gx = Image::<f32>::new(w, h);
    let mut gy = Image::<f32>::new(w, h);
    if w == 0 || h == 0 {
        return (gx, gy);
    }
    for v in 0..h {
        for u in 0..w {
            let (ul, ur) = (u.saturating_sub(1), (u + 1).min(w - 1));
            let (vu, vd) = (v.saturating_sub(1), (v + 1).min(h - 1));
            let dx = if ur > ul {
                (img.get(ur, v).to_f32() - img.get(ul, v).to_f32()) / (ur - ul) as f32
            } else {
                0.0
            };
            let dy = if vd > vu {
                (img.get(u, vd).to_f32() - img.get(u, vu).to_f32()) / (vd - vu) as f32
            } else {
                0.0
            };
            gx.set(u, v, dx);
            gy.set(u, v, dy);
        }
    }
    (gx, gy)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bilinear_reproduces_planes_and_their_gradients() {
        let img = Image::<f32>::from_fn(9, 7, |u, v| 3.0 * u as f32 - 2.0 * v as f32 + 5.0);
        let val = bilinear(&img, 3.3, 2.7).unwrap();
        assert!((val - (3.0 * 3.3 - 2.0 * 2.7 + 5.0)).abs() < 1e-4);
        let (i, gx, gy) = bilinear_with_gradient(&img, 6.9, 4.2).unwrap();
        assert!((i - (3.0 * 6.9 - 2.0 * 4.2 + 5.0)).abs() < 1e-4);
        assert!((gx - 3.0).abs() < 1e-5 && (gy + 2.0).abs() < 1e-5);
        // Exactly at the last pixel is allowed; beyond is not.
        assert!(bilinear(&img, 8.0, 6.0).is_some());
        assert!(bilinear(&img, 8.01, 6.0).is_none());
        assert!(bilinear(&img, -0.01, 0.0).is_none());
        assert!(bilinear(&img, f32::NAN, 0.0).is_none());
        assert!(bilinear_with_gradient(&img, 0.5, 3.0).is_none());
    }

    #[test]
    fn grid_simd_and_scalar_agree_bit_for_bit() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        // Odd sizes, one with a row stride larger than the width (the padding bytes are
        // garbage the samples must not see), and random sub-pixel centres and warps; many
        // centres near the borders (some grids leave the image, some reach the last pixels of
        // the last row where the AVX2 kernel falls back to `bilinear`).
        let tight = Image::<u8>::from_fn(37, 29, |u, v| ((u * 31 + v * 17) ^ (u * v)) as u8);
        let mut padded = vec![0u8; 45 * 28 + 33];
        for (k, p) in padded.iter_mut().enumerate() {
            *p = (k * 97 % 251) as u8;
        }
        let padded = Image::from_vec(33, 29, 45, padded).unwrap();
        let (mut inside, mut outside) = (0, 0);
        for img in [&tight, &padded] {
            for trial in 0..3000 {
                let n = [8, 10, 9, 16][trial % 4];
                let (w, h) = (img.width() as f32, img.height() as f32);
                let (u, v) = if trial % 3 == 0 {
                    (rng.random_range(0.0..w), rng.random_range(0.0..h))
                } else {
                    // Near the bottom-right corner.
                    (
                        w - rng.random_range(3.0..9.0f32),
                        h - rng.random_range(3.0..9.0f32),
                    )
                };
                let a = if trial % 2 == 0 {
                    [1.0, 0.0, 0.0, 1.0]
                } else {
                    std::array::from_fn(|i| {
                        rng.random_range(-0.3..0.3f32) + if i % 3 == 0 { 1.0 } else { 0.0 }
                    })
                };
                let mut fast = vec![0.0f32; n * n];
                let mut reference = vec![0.0f32; n * n];
                let ok = bilinear_grid(img, u, v, a, n, &mut fast);
                let ok_ref =
                    crate::simd::scalar_only(|| bilinear_grid(img, u, v, a, n, &mut reference));
                assert_eq!(ok, ok_ref, "grid {n} at ({u}, {v}), warp {a:?}");
                if ok {
                    inside += 1;
                    let bits = |x: &[f32]| x.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
                    assert_eq!(
                        bits(&fast),
                        bits(&reference),
                        "grid {n} at ({u}, {v}), warp {a:?}"
                    );
                } else {
                    outside += 1;
                }
            }
        }
        assert!(
            inside > 500 && outside > 500,
            "{inside} inside, {outside} outside"
        );
        // Other pixel types take the scalar path with the same definition.
        let f = tight.map(|p| p as f32);
        let (mut a, mut b) = (vec![0.0; 64], vec![0.0; 64]);
        assert!(bilinear_grid(
            &f,
            12.3,
            10.7,
            [1.0, 0.1, -0.1, 1.0],
            8,
            &mut a
        ));
        assert!(bilinear_grid(
            &tight,
            12.3,
            10.7,
            [1.0, 0.1, -0.1, 1.0],
            8,
            &mut b
        ));
        assert_eq!(a, b);
    }

    #[test]
    fn tiny_images_do_not_panic() {
        let one = Image::<u8>::filled(1, 1, 42);
        assert_eq!(bilinear(&one, 0.0, 0.0), Some(42.0));
        assert!(bilinear_with_gradient(&one, 0.0, 0.0).is_none());
        let (gx, _) = gradient_images(&one);
        assert_eq!(gx.get(0, 0), 0.0);
        let row = Image::<u8>::from_fn(4, 1, |u, _| u as u8);
        assert_eq!(bilinear(&row, 2.5, 0.0), Some(2.5));
    }
}
