//! Patch matching (thesis §3.4.2, PTAM style): warped template patches predicted from a pose,
//! zero-mean SSD, guided search restricted to FAST corners inside a radius, and sub-pixel
//! refinement by inverse-compositional alignment.

use crate::fast::Corner;
use crate::image::{GrayImage, Image};
use crate::interp::{Pixel, bilinear_grid};
use geom::{CameraModel, PinholeCamera};
use lie::{LieGroup, Se3};
use nalgebra::{Matrix2, Vector2};

/// Side length of template patches (8×8, as PTAM).
pub const PATCH_SIZE: usize = 8;
const N: usize = PATCH_SIZE * PATCH_SIZE;

/// An `8×8` template patch (intensities, row-major), with its mean.
#[derive(Debug, Clone, PartialEq)]
pub struct Patch {
    /// Samples; sample `(i, j)` lies at offset `o = (j − 3.5, i − 3.5)` from the patch centre.
    pub data: [f32; N],
    /// Mean intensity.
    pub mean: f32,
}

/// `Σ_k f(k)` over the 64 samples of a patch in eight lanes: lane `l` sums the samples
/// `l, l + 8, …` (column `l`, row by row), then the lanes are added in order. Eight independent
/// chains instead of one (the sequential sum was bound by the add latency), and the order of
/// the AVX2 build, which runs the same code on one register per row: both paths agree bit for
/// bit.
#[inline(always)]
fn lane_sum(f: impl Fn(usize) -> f32) -> f32 {
    let mut acc = [0.0f32; PATCH_SIZE];
    for i in 0..PATCH_SIZE {
        for (l, a) in acc.iter_mut().enumerate() {
            *a += f(i * PATCH_SIZE + l);
        }
    }
    acc.iter().fold(0.0, |s, &x| s + x)
}

/// Runs `$body` (an expression over the arguments) compiled for AVX2 when available
/// ([`crate::simd::avx2`]), else as it is: the same code twice, so the same results.
macro_rules! dispatch_avx2 {
    (fn $name:ident($($arg:ident: $ty:ty),*) -> $ret:ty $body:block) => {{
        #[cfg(target_arch = "x86_64")]
        #[target_feature(enable = "avx2")]
        fn $name($($arg: $ty),*) -> $ret $body
        #[cfg(target_arch = "x86_64")]
        if crate::simd::avx2() {
            // SAFETY: the CPU supports AVX2 (checked just above).
            return unsafe { $name($($arg),*) };
        }
        $body
    }};
}

impl Patch {
    fn from_data(data: [f32; N]) -> Self {
        let mean = lane_sum(|k| data[k]) / N as f32;
        Self { data, mean }
    }

    /// The axis-aligned patch centred at `(u, v)` of `img` (bilinear), or `None` if it leaves
    /// the image.
    pub fn extract<T: Pixel>(img: &Image<T>, u: f32, v: f32) -> Option<Self> {
        Self::extract_warped(img, u, v, &Matrix2::identity())
    }

    /// The warped template: sample at offset `o` is `img(c + A·o)` with `A = ∂(source pixel)/∂(target
    /// pixel)`, so that the patch looks as the region around `c` would look in the target image.
    /// `None` if any sample leaves the image.
    pub fn extract_warped<T: Pixel>(
        img: &Image<T>,
        u: f32,
        v: f32,
        a: &Matrix2<f64>,
    ) -> Option<Self> {
        let mut data = [0.0f32; N];
        let a = [a[(0, 0)], a[(0, 1)], a[(1, 0)], a[(1, 1)]].map(|x| x as f32);
        if !bilinear_grid(img, u, v, a, PATCH_SIZE, &mut data) {
            return None;
        }
        Some(Self::from_data(data))
    }
}

/// Zero-mean sum of squared differences `Σ((a − ā) − (b − b̄))²` (invariant to an intensity
/// offset), summed in lanes (see `lane_sum`).
pub fn zmssd(a: &Patch, b: &Patch) -> f32 {
    dispatch_avx2!(
        fn zmssd_avx2(a: &Patch, b: &Patch) -> f32 {
            let d = a.mean - b.mean;
            lane_sum(|k| {
                let e = a.data[k] - b.data[k] - d;
                e * e
            })
        }
    )
}

/// Normalised SSD `Σ((a − ā)/‖a − ā‖ − (b − b̄)/‖b − b̄‖)² = 2 − 2·NCC`, in `[0, 4]` (invariant
/// to gain and offset); 4 if a patch is constant. Sums in lanes (see `lane_sum`).
pub fn nssd(a: &Patch, b: &Patch) -> f32 {
    dispatch_avx2!(
        fn nssd_avx2(a: &Patch, b: &Patch) -> f32 {
            let sq = |p: &Patch| {
                lane_sum(|k| {
                    let e = p.data[k] - p.mean;
                    e * e
                })
                .sqrt()
            };
            let (na, nb) = (sq(a), sq(b));
            if na < 1e-6 || nb < 1e-6 {
                return 4.0;
            }
            lane_sum(|k| {
                let e = (a.data[k] - a.mean) / na - (b.data[k] - b.mean) / nb;
                e * e
            })
        }
    )
}

/// The affine warp of a reference patch predicted from a relative pose (PTAM): the reference
/// pixel `u_ref` and its neighbours `u_ref + (1, 0)`, `u_ref + (0, 1)` are back-projected at
/// `depth` (a fronto-parallel plane in the reference camera, thesis eq. 3.5), moved by
/// `cur_from_ref` and projected into the current camera (thesis eq. 3.4). Returns the predicted
/// current pixel and `A = ∂u_ref/∂u_cur` (the inverse of the finite-difference Jacobian), ready
/// for [`Patch::extract_warped`] on the reference image. `None` if a point falls behind the
/// camera or the warp is singular.
pub fn affine_from_pose(
    ref_camera: &PinholeCamera,
    cur_camera: &impl CameraModel,
    u_ref: &Vector2<f64>,
    depth: f64,
    cur_from_ref: &Se3,
) -> Option<(Vector2<f64>, Matrix2<f64>)> {
    let proj = |p: Vector2<f64>| -> Option<Vector2<f64>> {
        let y = ref_camera.unproject_depth(&p, depth).ok()?;
        cur_camera.project(&cur_from_ref.act(&y)).ok()
    };
    let c = proj(*u_ref)?;
    let cu = proj(u_ref + Vector2::new(1.0, 0.0))?;
    let cv = proj(u_ref + Vector2::new(0.0, 1.0))?;
    let j = Matrix2::from_columns(&[cu - c, cv - c]);
    Some((c, j.try_inverse()?))
}

/// The best match of a guided search.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PatchMatch {
    /// Matched position (sub-pixel if refined).
    pub u: f32,
    /// Matched row.
    pub v: f32,
    /// ZMSSD of the best corner (before refinement).
    pub zmssd: f32,
    /// Index of the winning corner in the input slice.
    pub corner: usize,
}

/// Guided search (PTAM): among the FAST `corners` of `img` within `radius` of `predicted`, find
/// the one whose axis-aligned patch has the lowest [`zmssd`] to `template`; accept it if below
/// `max_zmssd`.
pub fn guided_search(
    template: &Patch,
    img: &GrayImage,
    corners: &[Corner],
    predicted: [f32; 2],
    radius: f32,
    max_zmssd: f32,
) -> Option<PatchMatch> {
    let mut best: Option<PatchMatch> = None;
    let r2 = radius * radius;
    for (i, c) in corners.iter().enumerate() {
        let (du, dv) = (c.u - predicted[0], c.v - predicted[1]);
        if du * du + dv * dv > r2 {
            continue;
        }
        let Some(p) = Patch::extract(img, c.u, c.v) else {
            continue;
        };
        let s = zmssd(template, &p);
        if s < max_zmssd && best.is_none_or(|b| s < b.zmssd) {
            best = Some(PatchMatch {
                u: c.u,
                v: c.v,
                zmssd: s,
                corner: i,
            });
        }
    }
    best
}

/// Sub-pixel refinement of a match by inverse-compositional Gauss-Newton on the translation,
/// with the mean difference removed (as ZMSSD): minimises
/// `Σ_o ((I(c + o) − Ī) − (T(o) − T̄))²` over `c`, starting at `start`, using the template's
/// gradient (computed from a 10×10 warped sample, see [`template_with_gradient`]).
/// Returns the refined centre, or `None` if it leaves the image or moves more than 2 pixels.
pub fn refine_subpixel(
    tg: &TemplateWithGradient,
    img: &GrayImage,
    start: [f32; 2],
    iterations: usize,
) -> Option<[f32; 2]> {
    let (gx, gy) = (&tg.gx, &tg.gy);
    let hxx = lane_sum(|k| gx[k] * gx[k]);
    let hxy = lane_sum(|k| gx[k] * gy[k]);
    let hyy = lane_sum(|k| gy[k] * gy[k]);
    let det = hxx * hyy - hxy * hxy;
    if det <= 1e-6 {
        return None;
    }
    let mut c = start;
    for _ in 0..iterations {
        let p = Patch::extract(img, c[0], c[1])?;
        let (bx, by) = gradient_dot(tg, &p);
        let dx = (hyy * bx - hxy * by) / det;
        let dy = (hxx * by - hxy * bx) / det;
        c[0] -= dx;
        c[1] -= dy;
        if (c[0] - start[0]).hypot(c[1] - start[1]) > 2.0 {
            return None;
        }
        if dx * dx + dy * dy < 1e-6 {
            break;
        }
    }
    Some(c)
}

/// [`refine_subpixel`] along the row only (`v` fixed at `start[1]`): the match of a template on
/// the epipolar line of a rectified stereo pair. Minimises the same zero-mean residual over
/// `u` alone; returns the refined `u`, or `None` if the patch leaves the image, the template
/// has no horizontal gradient, or `u` moves more than `max_step` pixels from `start[0]`.
pub fn refine_along_row(
    tg: &TemplateWithGradient,
    img: &GrayImage,
    start: [f32; 2],
    iterations: usize,
    max_step: f32,
) -> Option<f32> {
    let hxx = lane_sum(|k| tg.gx[k] * tg.gx[k]);
    if hxx <= 1e-6 {
        return None;
    }
    let mut u = start[0];
    for _ in 0..iterations {
        let p = Patch::extract(img, u, start[1])?;
        let (bx, _) = gradient_dot(tg, &p);
        let du = bx / hxx;
        u -= du;
        if (u - start[0]).abs() > max_step {
            return None;
        }
        if du * du < 1e-6 {
            break;
        }
    }
    Some(u)
}

/// `b = Σ ∇T·e` with `e = (I − Ī) − (T − T̄)` over the samples, in lanes (see `lane_sum`).
fn gradient_dot(tg: &TemplateWithGradient, p: &Patch) -> (f32, f32) {
    dispatch_avx2!(
        fn gradient_dot_avx2(tg: &TemplateWithGradient, p: &Patch) -> (f32, f32) {
            let d = p.mean - tg.patch.mean;
            let e = |k: usize| p.data[k] - tg.patch.data[k] - d;
            (lane_sum(|k| tg.gx[k] * e(k)), lane_sum(|k| tg.gy[k] * e(k)))
        }
    )
}

/// A template patch with its central-difference gradients, their means over the patch removed
/// (for [`refine_subpixel`], whose residual is zero-mean).
#[derive(Debug, Clone)]
pub struct TemplateWithGradient {
    /// The template.
    pub patch: Patch,
    /// `∂T/∂u` per sample, minus its mean.
    pub gx: [f32; N],
    /// `∂T/∂v` per sample, minus its mean.
    pub gy: [f32; N],
}

/// Samples the warped template around `(u, v)` of `img` (see [`Patch::extract_warped`]) together
/// with its gradient in target-pixel units, from a 10×10 sampling (one extra ring).
pub fn template_with_gradient<T: Pixel>(
    img: &Image<T>,
    u: f32,
    v: f32,
    a: &Matrix2<f64>,
) -> Option<TemplateWithGradient> {
    const M: usize = PATCH_SIZE + 2;
    let mut big = [0.0f32; M * M];
    let a = [a[(0, 0)], a[(0, 1)], a[(1, 0)], a[(1, 1)]].map(|x| x as f32);
    if !bilinear_grid(img, u, v, a, M, &mut big) {
        return None;
    }
    let mut data = [0.0f32; N];
    let mut gx = [0.0f32; N];
    let mut gy = [0.0f32; N];
    for i in 0..PATCH_SIZE {
        for j in 0..PATCH_SIZE {
            let c = (i + 1) * M + j + 1;
            data[i * PATCH_SIZE + j] = big[c];
            gx[i * PATCH_SIZE + j] = 0.5 * (big[c + 1] - big[c - 1]);
            gy[i * PATCH_SIZE + j] = 0.5 * (big[c + M] - big[c - M]);
        }
    }
    // The residual of `refine_subpixel` has its mean removed, and so has its Jacobian: the
    // gradient minus its mean over the patch. With the raw gradient the Gauss-Newton
    // matrix overstates every direction in which the gradient has a mean (a patch on an
    // intensity ramp), and the steps fall short: 50 iterations instead of a few.
    for g in [&mut gx, &mut gy] {
        let mean = g.iter().sum::<f32>() / N as f32;
        g.iter_mut().for_each(|x| *x -= mean);
    }
    Some(TemplateWithGradient {
        patch: Patch::from_data(data),
        gx,
        gy,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fast::fast9;
    use nalgebra::{Vector3, Vector6};

    fn texture(w: usize, h: usize, f: impl Fn(f32, f32) -> (f32, f32)) -> GrayImage {
        GrayImage::from_fn(w, h, |u, v| {
            let (x, y) = f(u as f32, v as f32);
            let s = 128.0
                + 70.0 * (x * 0.35).sin() * (y * 0.29).cos()
                + 50.0 * ((x * 0.13 + y * 0.21).sin() > 0.3) as i32 as f32;
            s.clamp(0.0, 255.0) as u8
        })
    }

    #[test]
    fn guided_search_and_refinement_find_a_shifted_point() {
        let a = texture(120, 100, |x, y| (x, y));
        // b(x) = a(x − t): content moves by t = (2.3, −1.6).
        let b = texture(120, 100, |x, y| (x - 2.3, y + 1.6));
        let corners_a = fast9(&a, 15, true);
        let corners_b = fast9(&b, 15, true);
        assert!(!corners_a.is_empty());
        let mut ok = 0;
        let mut tried = 0;
        for c in corners_a
            .iter()
            .filter(|c| c.u > 15.0 && c.v > 15.0 && c.u < 105.0 && c.v < 85.0)
            .take(20)
        {
            tried += 1;
            let tg = template_with_gradient(&a, c.u, c.v, &Matrix2::identity()).unwrap();
            let pred = [c.u + 2.0, c.v - 2.0];
            if let Some(m) = guided_search(&tg.patch, &b, &corners_b, pred, 4.0, 1e9)
                && let Some(r) = refine_subpixel(&tg, &b, [m.u, m.v], 20)
                && (r[0] - c.u - 2.3).abs() < 0.2
                && (r[1] - c.v + 1.6).abs() < 0.2
            {
                ok += 1;
            }
        }
        assert!(ok as f32 >= 0.7 * tried as f32, "{ok}/{tried}");
    }

    #[test]
    fn warped_template_matches_a_zoomed_view() {
        // The current image is the reference zoomed by 1.25 about (60, 50): u_cur − c = 1.25 (u_ref − c).
        let reference = texture(120, 100, |x, y| (x, y));
        let current = texture(120, 100, |x, y| {
            (60.0 + (x - 60.0) / 1.25, 50.0 + (y - 50.0) / 1.25)
        });
        let a = Matrix2::identity() / 1.25; // ∂u_ref/∂u_cur
        let (ur, vr) = (70.0f32, 58.0f32);
        let (uc, vc) = (60.0 + (ur - 60.0) * 1.25, 50.0 + (vr - 50.0) * 1.25);
        let warped = Patch::extract_warped(&reference, ur, vr, &a).unwrap();
        let plain = Patch::extract(&reference, ur, vr).unwrap();
        let target = Patch::extract(&current, uc, vc).unwrap();
        assert!(zmssd(&warped, &target) < 0.5 * zmssd(&plain, &target));
        assert!(nssd(&warped, &target) < nssd(&plain, &target));
        assert!((nssd(&target, &target)).abs() < 1e-5);
    }

    #[test]
    fn affine_from_pose_matches_pure_scale() {
        let cam = PinholeCamera::new(300.0, 300.0, 160.0, 120.0);
        // Moving 1 m towards a plane at 4 m magnifies by 4/3.
        let cur_from_ref = Se3::exp(&Vector6::new(0.0, 0.0, -1.0, 0.0, 0.0, 0.0));
        let (c, a) =
            affine_from_pose(&cam, &cam, &Vector2::new(160.0, 120.0), 4.0, &cur_from_ref).unwrap();
        assert!((c - Vector2::new(160.0, 120.0)).norm() < 1e-9);
        assert!((a - Matrix2::identity() * 0.75).norm() < 1e-9);
        let behind = Se3::exp(&Vector6::new(0.0, 0.0, -5.0, 0.0, 0.0, 0.0));
        assert!(affine_from_pose(&cam, &cam, &Vector2::new(160.0, 120.0), 4.0, &behind).is_none());
        let _ = Vector3::<f64>::zeros();
    }

    #[test]
    fn row_refinement_finds_a_horizontal_shift_and_keeps_v() {
        // A rectified pair: the right image is the left one moved by a disparity of 3.37 px.
        let left = texture(120, 100, |x, y| (x, y));
        let right = texture(120, 100, |x, y| (x + 3.37, y));
        let (mut ok, mut tried) = (0, 0);
        for c in fast9(&left, 15, true)
            .iter()
            .filter(|c| c.u > 15.0 && c.v > 15.0 && c.u < 105.0 && c.v < 85.0)
        {
            tried += 1;
            let tg = template_with_gradient(&left, c.u, c.v, &Matrix2::identity()).unwrap();
            // From the integer disparity 3 (a block matcher's winner).
            if let Some(u_r) = refine_along_row(&tg, &right, [c.u - 3.0, c.v], 10, 1.0)
                && (c.u - u_r - 3.37).abs() < 0.05
            {
                ok += 1;
            }
            // A start more than the allowed step away is refused, not followed.
            assert_eq!(
                refine_along_row(&tg, &right, [c.u - 3.0, c.v], 10, 0.2),
                None
            );
        }
        assert!(
            tried >= 10 && ok as f32 >= 0.9 * tried as f32,
            "{ok}/{tried}"
        );
        // No horizontal gradient (horizontal stripes): no disparity.
        let stripes = GrayImage::from_fn(40, 40, |_, v| if v % 4 < 2 { 50 } else { 200 });
        let tg = template_with_gradient(&stripes, 20.0, 20.0, &Matrix2::identity()).unwrap();
        assert_eq!(refine_along_row(&tg, &stripes, [18.0, 20.0], 10, 1.0), None);
    }

    #[test]
    fn simd_and_scalar_paths_agree_bit_for_bit() {
        // Every kernel of the guided search on both paths: templates (plain, warped, with
        // gradient), NSSD, ZMSSD and the sub-pixel refinement, at sub-pixel positions over a
        // texture of an odd size, including positions where the patch leaves the image.
        let a = texture(121, 97, |x, y| (x, y));
        let b = texture(121, 97, |x, y| (x - 1.3, y + 0.8));
        let warps = [
            Matrix2::identity(),
            Matrix2::new(1.04, -0.09, 0.09, 1.04),
            Matrix2::new(0.8, 0.2, -0.1, 1.2),
        ];
        let run = || {
            let mut out = Vec::new();
            for k in 0..400 {
                let (u, v) = (
                    (k * 37 % 1250) as f32 * 0.1 - 2.0,
                    (k * 53 % 1010) as f32 * 0.1 - 2.0,
                );
                let w = &warps[k % 3];
                let t = Patch::extract_warped(&a, u, v, w);
                let p = Patch::extract(&b, u + 1.3, v - 0.8);
                let tg = template_with_gradient(&a, u, v, w);
                let scores = match (&t, &p) {
                    (Some(t), Some(p)) => Some((nssd(t, p).to_bits(), zmssd(t, p).to_bits())),
                    _ => None,
                };
                let refined = tg
                    .as_ref()
                    .and_then(|tg| refine_subpixel(tg, &b, [u + 1.0, v - 1.0], 10));
                let along_row = tg
                    .as_ref()
                    .and_then(|tg| refine_along_row(tg, &b, [u + 1.0, v - 0.8], 10, 2.0));
                let bits = |x: &[f32]| x.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
                out.push(format!(
                    "{:?} {:?} {:?} {:?} {:?} {:?}",
                    t.map(|t| (bits(&t.data), t.mean.to_bits())),
                    p.map(|p| bits(&p.data)),
                    tg.map(|g| (bits(&g.gx), bits(&g.gy), bits(&g.patch.data))),
                    scores,
                    refined.map(|r| bits(&r)),
                    along_row.map(f32::to_bits),
                ));
            }
            out
        };
        let (fast, reference) = (run(), crate::simd::scalar_only(run));
        assert_eq!(fast, reference);
        let found = fast.iter().filter(|l| !l.starts_with("None")).count();
        assert!(found > 200 && found < 400, "{found} of 400 inside");
        // A constant patch scores 4 on both paths.
        let flat = Patch::extract(&GrayImage::filled(20, 20, 9), 10.0, 10.0).unwrap();
        assert_eq!(nssd(&flat, &flat), 4.0);
        assert_eq!(crate::simd::scalar_only(|| nssd(&flat, &flat)), 4.0);
    }

    #[test]
    fn patches_near_the_border_are_none() {
        let img = GrayImage::filled(5, 5, 1);
        assert!(Patch::extract(&img, 2.0, 2.0).is_none());
        assert!(
            template_with_gradient(&GrayImage::new(1, 1), 0.0, 0.0, &Matrix2::identity()).is_none()
        );
    }
}
