//! Undistortion / rectification maps and remapping.

use crate::image::{GrayImage, Image};
use crate::interp::bilinear;
use geom::{CameraModel, PinholeCamera};
use nalgebra::{Matrix3, Vector2, Vector3};

/// A look-up map from each pixel of an ideal (undistorted, optionally rotated) pinhole image to
/// the real-valued pixel of the source (distorted) image that it samples.
///
/// For output pixel `q`: `x = R_src_from_dst · K_dst⁻¹ (q, 1)ᵀ`, `map(q) = ẑ_src(x)` where `ẑ_src` is
/// the distorted source model (`K·δ(proj(x))`). Pixels whose ray is behind the source camera
/// map to `NaN` and are filled with 0 by [`remap`](Self::remap).
#[derive(Debug, Clone)]
pub struct UndistortMap {
    /// Source column of each output pixel.
    pub map_u: Image<f32>,
    /// Source row of each output pixel.
    pub map_v: Image<f32>,
}

impl UndistortMap {
    /// Builds the map for an output image of `width×height` with intrinsics `dst`, optionally
    /// rotated by `src_from_dst` (a rectifying rotation, identity if `None`), sampling the
    /// distorted camera `src` (radial-tangential or equidistant, see [`geom::DistortedCamera`]).
    pub fn new(
        src: &impl CameraModel,
        dst: &PinholeCamera,
        width: usize,
        height: usize,
        src_from_dst: Option<&Matrix3<f64>>,
    ) -> Self {
        let r = src_from_dst.copied().unwrap_or_else(Matrix3::identity);
        let mut map_u = Image::<f32>::filled(width, height, f32::NAN);
        let mut map_v = Image::<f32>::filled(width, height, f32::NAN);
        for v in 0..height {
            for u in 0..width {
                let m = dst.normalised_from_pixel(&Vector2::new(u as f64, v as f64));
                let x = r * Vector3::new(m.x, m.y, 1.0);
                if let Ok(p) = src.project(&x) {
                    map_u.set(u, v, p.x as f32);
                    map_v.set(u, v, p.y as f32);
                }
            }
        }
        Self { map_u, map_v }
    }

    /// Applies the map with bilinear interpolation; samples outside the source are 0.
    pub fn remap(&self, src: &GrayImage) -> GrayImage {
        let (w, h) = (self.map_u.width(), self.map_u.height());
        GrayImage::from_fn(w, h, |u, v| {
            let (x, y) = (self.map_u.get(u, v), self.map_v.get(u, v));
            match bilinear(src, x, y) {
                Some(val) => (val + 0.5).clamp(0.0, 255.0) as u8,
                None => 0,
            }
        })
    }
}

/// An [`UndistortMap`] compiled for sources of one size: per output pixel the top-left source
/// pixel of its bilinear 2×2 and the two weights, computed once as [`bilinear`] computes them
/// per call, and the nearest source pixel (for depth images, where interpolating across an
/// occlusion edge would invent surfaces).
///
/// Why: a remap through the map costs ~15 ns per pixel (two map reads, `bilinear`'s range
/// tests, four bounds-checked reads), which on a 752×480 stereo pair is ~11 ms per frame on
/// one core, a third of a frame's time on EuRoC. With the taps precomputed it is the
/// arithmetic alone, eight pixels at a time by AVX2 gathers; the results are bit for bit
/// [`UndistortMap::remap`]'s (the same f32 operations in the same order, no FMA).
#[derive(Debug, Clone)]
pub struct RemapTable {
    src_width: usize,
    src_height: usize,
    width: usize,
    height: usize,
    /// Per output pixel (row-major) `v0·src_width + u0` of its 2×2 (0 where it has none).
    index: Vec<u32>,
    /// The weights `a = u − u0`, `b = v − v0`; NaN where the pixel samples nothing, which the
    /// arithmetic turns into 0 (`NaN as u8` is 0, as AVX2's `max(NaN, 0)`), without a branch.
    a: Vec<f32>,
    b: Vec<f32>,
    /// The output pixels (and their 2×2's index) whose 2×2 ends within 4 bytes of the source's
    /// end, where a 32-bit gather would read past it: their `index` is 0, and they are done
    /// again one by one.
    near_end: Vec<(u32, u32)>,
    /// Per output pixel the nearest source pixel's index, or [`RemapTable::OUTSIDE`].
    nearest: Vec<u32>,
}

impl RemapTable {
    const OUTSIDE: u32 = u32::MAX;

    /// The table of `map` for sources of `src_width×src_height`; `None` (use
    /// [`UndistortMap::remap`]) for sources narrower or lower than 2 pixels, so small that the
    /// gathers at pixel 0 would leave them (`src_width + 4` pixels or fewer), or of `2³¹ − 4`
    /// pixels or more (the gathers' offsets are signed 32-bit).
    pub fn new(map: &UndistortMap, src_width: usize, src_height: usize) -> Option<Self> {
        let len = src_width * src_height;
        if src_width < 2 || src_height < 2 || len < src_width + 4 || len + 4 > i32::MAX as usize {
            return None;
        }
        let (width, height) = (map.map_u.width(), map.map_u.height());
        let (wl, hl) = ((src_width - 1) as f32, (src_height - 1) as f32);
        let n = width * height;
        let mut table = Self {
            src_width,
            src_height,
            width,
            height,
            index: Vec::with_capacity(n),
            a: Vec::with_capacity(n),
            b: Vec::with_capacity(n),
            near_end: Vec::new(),
            nearest: Vec::with_capacity(n),
        };
        for v in 0..height {
            for (&x, &y) in map.map_u.row(v).iter().zip(map.map_v.row(v)) {
                // bilinear's range test and its clamped top-left pixel.
                let (i, a, b) = if x >= 0.0 && y >= 0.0 && x <= wl && y <= hl {
                    let u0 = (x as usize).min(src_width - 2);
                    let v0 = (y as usize).min(src_height - 2);
                    (v0 * src_width + u0, x - u0 as f32, y - v0 as f32)
                } else {
                    (0, f32::NAN, f32::NAN)
                };
                if i + src_width + 4 > len {
                    table.near_end.push((table.index.len() as u32, i as u32));
                    table.index.push(0);
                } else {
                    table.index.push(i as u32);
                }
                table.a.push(a);
                table.b.push(b);
                // Remap::depth's rounding (NaN and out-of-range rays: outside).
                let (xr, yr) = (x.round(), y.round());
                table
                    .nearest
                    .push(if xr >= 0.0 && yr >= 0.0 && xr <= wl && yr <= hl {
                        (yr as usize * src_width + xr as usize) as u32
                    } else {
                        Self::OUTSIDE
                    });
            }
        }
        Some(table)
    }

    /// The source size the table was compiled for.
    pub fn source_size(&self) -> (usize, usize) {
        (self.src_width, self.src_height)
    }

    /// [`UndistortMap::remap`] of `src`, which must have the table's source size.
    pub fn remap(&self, src: &GrayImage) -> GrayImage {
        let data = self.contiguous(src);
        let mut out = vec![0u8; self.index.len()];
        let mut done = 0;
        #[cfg(target_arch = "x86_64")]
        if crate::simd::avx2() {
            // SAFETY: AVX2 is present; every index + src_width + 4 ≤ data.len() (new).
            done = unsafe { self.remap_avx2(&data, &mut out) };
        }
        for (k, o) in out.iter_mut().enumerate().skip(done) {
            *o = self.sample(&data, k, self.index[k] as usize);
        }
        for &(k, i) in &self.near_end {
            out[k as usize] = self.sample(&data, k as usize, i as usize);
        }
        Image::from_vec(self.width, self.height, self.width, out).expect("the table's size")
    }

    /// Output pixel `k` of [`RemapTable::remap`], one by one, its 2×2 at `i`.
    #[inline]
    fn sample(&self, data: &[u8], k: usize, i: usize) -> u8 {
        let (a, b) = (self.a[k], self.b[k]);
        let w = self.src_width;
        let (i00, i10) = (data[i] as f32, data[i + 1] as f32);
        let (i01, i11) = (data[i + w] as f32, data[i + w + 1] as f32);
        let val = (1.0 - b) * ((1.0 - a) * i00 + a * i10) + b * ((1.0 - a) * i01 + a * i11);
        (val + 0.5).clamp(0.0, 255.0) as u8
    }

    /// The vector part of [`RemapTable::remap`]: eight output pixels per step, each 2×2 read
    /// by two 32-bit gathers (its top and bottom pairs); returns how many pixels it did.
    ///
    /// # Safety
    /// AVX2; `data` has the table's source size, so that every 4-byte read at `index + w` fits
    /// (`near_end` holds the others, read at 0 here).
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    unsafe fn remap_avx2(&self, data: &[u8], out: &mut [u8]) -> usize {
        use std::arch::x86_64::*;
        let n = self.index.len() / 8 * 8;
        assert!(data.len() == self.src_width * self.src_height && out.len() >= n);
        // SAFETY: the loads are within the tables (k + 8 ≤ n), the gathers within `data`
        // (index + w + 4 ≤ len by construction), the store within `out`.
        unsafe {
            let base = data.as_ptr() as *const i32;
            let w = _mm256_set1_epi32(self.src_width as i32);
            let byte = _mm256_set1_epi32(0xff);
            let (one, half) = (_mm256_set1_ps(1.0), _mm256_set1_ps(0.5));
            let (zero, top) = (_mm256_setzero_ps(), _mm256_set1_ps(255.0));
            // Dwords 0 and 4 (each holding four packed bytes) to the low 64 bits.
            let gather_bytes = _mm256_setr_epi32(0, 4, 0, 0, 0, 0, 0, 0);
            let mut k = 0;
            while k < n {
                let i = _mm256_loadu_si256(self.index.as_ptr().add(k) as *const __m256i);
                let a = _mm256_loadu_ps(self.a.as_ptr().add(k));
                let b = _mm256_loadu_ps(self.b.as_ptr().add(k));
                let upper = _mm256_i32gather_epi32::<1>(base, i);
                let lower = _mm256_i32gather_epi32::<1>(base, _mm256_add_epi32(i, w));
                let f = |v: __m256i| _mm256_cvtepi32_ps(_mm256_and_si256(v, byte));
                let (i00, i10) = (f(upper), f(_mm256_srli_epi32::<8>(upper)));
                let (i01, i11) = (f(lower), f(_mm256_srli_epi32::<8>(lower)));
                // (1 − b)·((1 − a)·i00 + a·i10) + b·((1 − a)·i01 + a·i11), as `sample`.
                let na = _mm256_sub_ps(one, a);
                let t = _mm256_add_ps(_mm256_mul_ps(na, i00), _mm256_mul_ps(a, i10));
                let u = _mm256_add_ps(_mm256_mul_ps(na, i01), _mm256_mul_ps(a, i11));
                let val =
                    _mm256_add_ps(_mm256_mul_ps(_mm256_sub_ps(one, b), t), _mm256_mul_ps(b, u));
                // clamp(0, 255) (max(NaN, 0) is 0, as `NaN as u8`), then truncation.
                let c = _mm256_min_ps(_mm256_max_ps(_mm256_add_ps(val, half), zero), top);
                let v = _mm256_cvttps_epi32(c);
                let v16 = _mm256_packus_epi32(v, v);
                let v8 = _mm256_packus_epi16(v16, v16);
                let packed = _mm256_permutevar8x32_epi32(v8, gather_bytes);
                _mm_storel_epi64(
                    out.as_mut_ptr().add(k) as *mut __m128i,
                    _mm256_castsi256_si128(packed),
                );
                k += 8;
            }
        }
        n
    }

    /// The source pixel nearest each output pixel's sample (`outside` where it has none): a
    /// remap for depth images.
    pub fn remap_nearest<T: Copy + Default>(&self, src: &Image<T>, outside: T) -> Image<T> {
        let data = self.contiguous(src);
        let out = self
            .nearest
            .iter()
            .map(|&i| {
                if i == Self::OUTSIDE {
                    outside
                } else {
                    data[i as usize]
                }
            })
            .collect();
        Image::from_vec(self.width, self.height, self.width, out).expect("the table's size")
    }

    /// `src`'s pixels row after row without padding (copied only if its rows are padded).
    fn contiguous<'a, T: Copy + Default>(&self, src: &'a Image<T>) -> std::borrow::Cow<'a, [T]> {
        assert_eq!(
            (src.width(), src.height()),
            (self.src_width, self.src_height),
            "a remap table applied to an image of another size"
        );
        if src.stride() == src.width() {
            std::borrow::Cow::Borrowed(&src.data()[..src.width() * src.height()])
        } else {
            (0..src.height())
                .flat_map(|v| src.row(v).iter().copied())
                .collect()
        }
    }
}

/// The result of rectifying a calibrated stereo pair: rotations into the common rectified
/// frame, the shared rectified pinhole and the baseline.
#[derive(Debug, Clone, Copy)]
pub struct StereoRectification {
    /// Rotation taking left-camera coordinates into the rectified left frame.
    pub rect_from_left: Matrix3<f64>,
    /// Rotation taking right-camera coordinates into the rectified right frame.
    pub rect_from_right: Matrix3<f64>,
    /// Intrinsics shared by both rectified images.
    pub pinhole: PinholeCamera,
    /// Distance between the optical centres (units of the input translation).
    pub baseline: f64,
}

/// Rectifies a calibrated stereo pair (a Bouguet-style construction with the translation as new
/// `x` axis): given `right_from_left = (R, t)` mapping left-camera points to right-camera points
/// (`x_r = R x_l + t`), the right centre in the left frame is `c = −Rᵀt`; the rectified axes
/// (rows of `rect_from_left`) are `e₁ = c/‖c‖`, `e₂ = z̄ × e₁/‖·‖` with `z̄` the mean optical
/// axis, `e₃ = e₁ × e₂`; `rect_from_right = rect_from_left · Rᵀ`. The shared intrinsics take the
/// mean focal length of both cameras and principal point `pp` (in pixels; e.g. the left one).
pub fn rectify_stereo(
    left: &PinholeCamera,
    right: &PinholeCamera,
    right_from_left_rotation: &Matrix3<f64>,
    right_from_left_translation: &Vector3<f64>,
    pp: Vector2<f64>,
) -> StereoRectification {
    let r = right_from_left_rotation;
    let c = -r.transpose() * right_from_left_translation;
    let baseline = c.norm();
    let e1 = c / baseline;
    let zbar = (Vector3::z() + r.transpose() * Vector3::z()).normalize();
    let e2 = zbar.cross(&e1).normalize();
    let e3 = e1.cross(&e2);
    let rect_from_left = Matrix3::from_rows(&[e1.transpose(), e2.transpose(), e3.transpose()]);
    let rect_from_right = rect_from_left * r.transpose();
    let f = 0.25 * (left.fx + left.fy + right.fx + right.fy);
    StereoRectification {
        rect_from_left,
        rect_from_right,
        pinhole: PinholeCamera::new(f, f, pp.x, pp.y),
        baseline,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use geom::{DistortedCamera, Distortion, Equidistant, RadTan};

    #[test]
    fn undistort_map_inverts_distortion() {
        let pin = PinholeCamera::new(200.0, 200.0, 40.0, 30.0);
        for (cam, dist) in [
            (
                &DistortedCamera::new(pin, RadTan::new(-0.28, 0.07, 0.0002, 0.00002))
                    as &dyn CameraModel,
                0,
            ),
            (
                &DistortedCamera::new(pin, Equidistant::new(0.0034, 0.0007, -0.0044, 0.0011)),
                1,
            ),
        ] {
            let map = UndistortMap::new(&Wrap(cam), &pin, 80, 60, None);
            for (u, v) in [(10usize, 10usize), (70, 50), (40, 30)] {
                let m = pin.normalised_from_pixel(&Vector2::new(u as f64, v as f64));
                let md = if dist == 0 {
                    RadTan::new(-0.28, 0.07, 0.0002, 0.00002).distort(&m)
                } else {
                    Equidistant::new(0.0034, 0.0007, -0.0044, 0.0011).distort(&m)
                };
                let p = pin.pixel_from_normalised(&md);
                assert!((map.map_u.get(u, v) as f64 - p.x).abs() < 1e-3);
                assert!((map.map_v.get(u, v) as f64 - p.y).abs() < 1e-3);
            }
        }
    }

    struct Wrap<'a>(&'a dyn CameraModel);
    impl CameraModel for Wrap<'_> {
        fn project(&self, x: &Vector3<f64>) -> Result<Vector2<f64>, geom::CameraError> {
            self.0.project(x)
        }
        fn project_with_jacobian(
            &self,
            x: &Vector3<f64>,
        ) -> Result<(Vector2<f64>, nalgebra::Matrix2x3<f64>), geom::CameraError> {
            self.0.project_with_jacobian(x)
        }
        fn unproject(&self, uv: &Vector2<f64>) -> Result<Vector3<f64>, geom::CameraError> {
            self.0.unproject(uv)
        }
    }

    /// The compiled table's remap, vector and scalar, against the map's, bit for bit, on a
    /// distorted, rotated view that leaves the source at the corners; sizes that are not a
    /// multiple of 8, and the bottom-right 2×2 (the pixels a gather would read past the end).
    #[test]
    fn the_compiled_table_remaps_bit_for_bit() {
        let pin = PinholeCamera::new(60.0, 62.0, 47.3, 29.8);
        let cam = DistortedCamera::new(pin, RadTan::new(-0.3, 0.09, 0.001, -0.0005));
        let rot = nalgebra::Rotation3::from_euler_angles(0.02, -0.03, 0.01).into_inner();
        let (w, h) = (97, 61);
        let mut map = UndistortMap::new(
            &cam,
            &PinholeCamera::new(55.0, 55.0, 48.0, 30.0),
            w,
            h,
            Some(&rot),
        );
        // Three pixels sample the source's last 2×2 (the last one exactly its corner pixel).
        for (u, x, y) in [(0usize, 95.5f32, 59.5f32), (1, 95.0, 59.5), (2, 96.0, 60.0)] {
            map.map_u.set(u, 0, x);
            map.map_v.set(u, 0, y);
        }
        let src = GrayImage::from_fn(w, h, |u, v| ((u * 37 + v * 91 + u * v) % 251) as u8);
        let table = RemapTable::new(&map, w, h).unwrap();
        assert!(table.near_end.len() >= 3);
        let expected = map.remap(&src);
        let fast = table.remap(&src);
        let scalar = crate::simd::scalar_only(|| table.remap(&src));
        assert_eq!(fast.data(), expected.data());
        assert_eq!(scalar.data(), expected.data());
        assert_ne!(expected.get(0, 0), 0);
        assert!(expected.data().contains(&0), "some pixels sample nothing");
        // A source with padded rows is read row by row.
        let padded = Image::from_vec(w, h, w + 3, {
            let mut d = vec![0u8; (w + 3) * h];
            for v in 0..h {
                d[v * (w + 3)..][..w].copy_from_slice(src.row(v));
            }
            d
        })
        .unwrap();
        assert_eq!(table.remap(&padded).data(), expected.data());
        // Sources too small for the gathers go through the map.
        assert!(RemapTable::new(&map, 1, 5).is_none());
        assert!(RemapTable::new(&map, 3, 2).is_none());
    }

    #[test]
    fn rectification_aligns_rows() {
        // A right camera displaced mostly along x, slightly rotated.
        let rot = nalgebra::Rotation3::from_euler_angles(0.01, -0.02, 0.005).into_inner();
        let t = Vector3::new(-0.11, 0.002, 0.001);
        let pin = PinholeCamera::new(450.0, 450.0, 370.0, 250.0);
        let rect = rectify_stereo(&pin, &pin, &rot, &t, Vector2::new(370.0, 250.0));
        assert!((rect.baseline - t.norm()).abs() < 1e-12);
        // A world point seen by both rectified cameras lands on the same row.
        let xl = Vector3::new(0.5, -0.3, 3.0);
        let xr = rot * xl + t;
        let pl = rect.pinhole.project(&(rect.rect_from_left * xl)).unwrap();
        let pr = rect.pinhole.project(&(rect.rect_from_right * xr)).unwrap();
        assert!((pl.y - pr.y).abs() < 1e-9, "{pl} {pr}");
        // And the disparity gives the depth: f b / d.
        let depth = (rect.rect_from_left * xl).z;
        assert!((rect.pinhole.fx * rect.baseline / (pl.x - pr.x) - depth).abs() < 1e-9);
    }
}
