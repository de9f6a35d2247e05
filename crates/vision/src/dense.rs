//! Dense photometric SE(3) alignment (thesis §6.3, eq. 6.7; Newcombe, Lovegrove & Davison
//! 2011): the pose prior of the stereo and RGB-D front-ends.
//!
//! Given a reference image `I_ref` with per-pixel depth (hence points `y_{u,v}` in the reference
//! camera frame, thesis eq. 6.6) and a current image `I_cur`, find `T = cur_from_ref` minimising
//!
//! `χ² = Σ_{u,v} ρ( (I_cur(ẑ_mono(T·y_{u,v})) − I_ref(u, v))² )`   (thesis eq. 6.7)
//!
//! with a Huber kernel `ρ`, by Gauss-Newton (iteratively re-weighted least squares) over a
//! pyramid, coarse to fine, with left-multiplicative updates `T ← exp(δ)·T` (thesis eq. 2.104).
//! The Jacobian of a residual is `∇I_cur · ∂ẑ_mono/∂x · [I | −[x]×]` with `x = T·y`
//! (thesis eq. B.4 and B.12).

use crate::image::{GrayImage, Image, ImageError};
use crate::interp::bilinear;
use crate::pyramid::Pyramid;
use geom::{CameraModel, PinholeCamera};
use lie::{LieGroup, Se3};
use nalgebra::{Matrix6, Vector2, Vector6};

/// Parameters of [`align`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DenseParams {
    /// Number of pyramid levels (coarsest first during the optimisation).
    pub levels: usize,
    /// Maximum Gauss-Newton iterations per level.
    pub max_iterations: usize,
    /// Huber threshold in units of the robust residual scale `σ̂ = 1.4826·median|r|`:
    /// `k = huber_scale·σ̂` (1.345 gives 95 % efficiency on Gaussian noise).
    pub huber_scale: f64,
    /// Pixels whose reference gradient magnitude is below this (intensity units per pixel)
    /// carry no information about the motion and are skipped.
    pub min_gradient: f32,
    /// Stop a level when the update `‖δ‖` is below this.
    pub min_update: f64,
    /// The finest level optimised (0: full resolution). A prior for a guided search needs no
    /// more than the level whose pixel is the search's tolerance.
    pub finest_level: usize,
}

impl Default for DenseParams {
    /// 4 levels, 30 iterations, Huber 1.345σ̂, gradient ≥ 2, ‖δ‖ < 1e-6.
    fn default() -> Self {
        Self {
            levels: 4,
            max_iterations: 30,
            huber_scale: 1.345,
            min_gradient: 2.0,
            min_update: 1e-6,
            finest_level: 0,
        }
    }
}

/// Result of [`align`].
#[derive(Debug, Clone, Copy)]
pub struct DenseResult {
    /// The estimated transformation from the reference camera frame to the current one.
    pub cur_from_ref: Se3,
    /// Final robust cost `Σρ(r²)/N` at the finest level optimised.
    pub final_cost: f64,
    /// Number of residuals used at the finest level in the last iteration.
    pub num_residuals: usize,
    /// Gauss-Newton iterations over all levels.
    pub iterations: usize,
}

/// Errors of [`align`].
#[derive(Debug, thiserror::Error)]
pub enum DenseError {
    /// Image sizes are inconsistent or too small.
    #[error(transparent)]
    Image(#[from] ImageError),
    /// Too few pixels with valid depth and gradient to estimate a pose.
    #[error("too few usable pixels ({0}) for dense alignment")]
    TooFewPixels(usize),
}

/// Lanes of the residual kernels: residual `i` of a level is computed in lane `i mod 8` on both
/// paths (one AVX2 register of f32), so lane-wise sums agree bit for bit.
const LANES: usize = 8;

/// The normal equations are summed in f32 lanes for this many chunks of [`LANES`] residuals
/// (512 residuals), then added to f64 lane totals: the f32 partial sums stay short (relative
/// rounding ≲ 64·2⁻²⁴ ≈ 4e-6 per block), the totals over a whole level are f64.
const FLUSH_CHUNKS: usize = 64;

/// Number of distinct entries of the symmetric 6×6 `H` (upper triangle, row by row), of `g`,
/// and the cost: the 28 lane accumulators of [`accumulate`].
const H_ENTRIES: usize = 21;
const SUMS: usize = H_ENTRIES + 6 + 1;

/// The reference points of one pyramid level as structure of arrays (f32), padded with `NaN`
/// points to a multiple of [`LANES`] (a `NaN` point fails the depth test on both paths).
#[derive(Debug, Clone, Default)]
struct ReferenceLevel {
    /// The level's camera `(f_x, f_y, c_x, c_y)`.
    camera: [f32; 4],
    x: Vec<f32>,
    y: Vec<f32>,
    z: Vec<f32>,
    intensity: Vec<f32>,
    /// Number of real (unpadded) points.
    count: usize,
}

/// A reference frame prepared for dense alignment: the per-level points `y_{u,v}` (thesis
/// eq. 6.6) and intensities, computed once. The live tracker's reference is the previous frame
/// with depth, so each frame is prepared once and aligned against the next; preparing also
/// checks the input, so [`DenseReference::align`] only fails when the images do not overlap.
#[derive(Debug, Clone)]
pub struct DenseReference {
    /// Levels `0..levels`; those below `finest` are empty.
    levels: Vec<ReferenceLevel>,
    finest: usize,
    params: DenseParams,
}

impl DenseReference {
    /// Prepares `pyramid` (the reference image's) with per-pixel `depth` of level 0 (metres
    /// along the optical axis; `NaN` or ≤ 0 where unknown) and level-0 intrinsics `camera` for
    /// [`align`](Self::align) with `params` (levels, finest level, gradient threshold, and the
    /// iteration settings used later).
    ///
    /// Each level-`l` pixel whose central-difference gradient is at least `min_gradient` takes
    /// the inverse-depth mean of the valid depths in its `2ˡ×2ˡ` block of level 0 (at least
    /// half of them valid), back-projected with the level's camera (thesis eq. 6.6). The block
    /// sums come from a pyramid of 2×2 sums of inverse depths and counts, so every level costs
    /// one pass over its own pixels (the level-0 block of a level-`l` pixel lies inside the
    /// depth image, since level `l` has `⌊w/2ˡ⌋` columns).
    pub fn new(
        pyramid: &Pyramid,
        depth: &Image<f32>,
        camera: &PinholeCamera,
        params: &DenseParams,
    ) -> Result<Self, DenseError> {
        let levels = pyramid.len().min(params.levels.max(1));
        if levels == 0 {
            return Err(DenseError::TooFewPixels(0));
        }
        let base = &pyramid.levels[0];
        if depth.width() != base.width() || depth.height() != base.height() {
            return Err(ImageError::SizeMismatch(
                base.width(),
                base.height(),
                depth.width(),
                depth.height(),
            )
            .into());
        }
        let finest = params.finest_level.min(levels - 1);
        let mut out = vec![ReferenceLevel::default(); levels];
        // Level-l sums of inverse depths and valid counts over 2ˡ×2ˡ blocks of level 0 (level
        // 0 itself only when it is aligned; level 1 then comes straight from the depth image).
        let avx2 = crate::simd::avx2();
        let (mut sum, mut cnt): (Vec<f32>, Vec<f32>) = (Vec::new(), Vec::new());
        let (mut sw, mut sh) = (depth.width(), depth.height());
        for (l, level) in out.iter_mut().enumerate() {
            if l == 0 {
                if finest == 0 {
                    for v in 0..sh {
                        for &d in depth.row(v) {
                            let (s, c) = inverse_depth(d);
                            sum.push(s);
                            cnt.push(c);
                        }
                    }
                }
            } else {
                let (nw, nh) = (sw / 2, sh / 2);
                let (mut s2, mut c2) = (vec![0.0f32; nw * nh], vec![0.0f32; nw * nh]);
                for v in 0..nh {
                    let (so, co) = (&mut s2[v * nw..(v + 1) * nw], &mut c2[v * nw..(v + 1) * nw]);
                    if l == 1 && finest > 0 {
                        depth_block_row(depth.row(2 * v), depth.row(2 * v + 1), so, co, avx2);
                        continue;
                    }
                    let (r0, r1) = (2 * v * sw, (2 * v + 1) * sw);
                    for u in 0..nw {
                        let (a, b) = (r0 + 2 * u, r1 + 2 * u);
                        so[u] = ((sum[a] + sum[a + 1]) + sum[b]) + sum[b + 1];
                        co[u] = ((cnt[a] + cnt[a + 1]) + cnt[b]) + cnt[b + 1];
                    }
                }
                (sum, cnt, sw, sh) = (s2, c2, nw, nh);
            }
            if l < finest {
                continue;
            }
            let img = &pyramid.levels[l];
            debug_assert!(img.width() <= sw && img.height() <= sh);
            *level = level_points(
                img,
                &sum,
                &cnt,
                sw,
                camera.scaled(0.5f64.powi(l as i32)),
                l,
                params.min_gradient,
            );
        }
        if out[finest].count < 6 {
            return Err(DenseError::TooFewPixels(out[finest].count));
        }
        Ok(Self {
            levels: out,
            finest,
            params: *params,
        })
    }

    /// The parameters the reference was prepared with (and [`align`](Self::align) uses).
    pub fn params(&self) -> &DenseParams {
        &self.params
    }

    /// Number of reference points at pyramid level `l` (0 below the finest level).
    pub fn num_points(&self, l: usize) -> usize {
        self.levels.get(l).map_or(0, |d| d.count)
    }

    /// Aligns the image whose pyramid is `current` (level 0 the size of the reference's) to
    /// this reference, starting from `initial_cur_from_ref`: Gauss-Newton with the Huber kernel
    /// over the levels coarse to fine (thesis eq. 6.7). `scratch` holds the buffers (reused
    /// across calls; nothing is allocated per iteration).
    pub fn align(
        &self,
        current: &Pyramid,
        initial_cur_from_ref: &Se3,
        scratch: &mut DenseScratch,
    ) -> Result<DenseResult, DenseError> {
        let params = &self.params;
        let levels = self.levels.len().min(current.len());
        if levels == 0 || self.finest >= levels {
            return Err(DenseError::TooFewPixels(0));
        }
        let avx2 = crate::simd::avx2();
        let mut t = *initial_cur_from_ref;
        let mut iterations = 0;
        let mut final_cost = f64::NAN;
        let mut num_residuals = 0;
        for l in (self.finest..levels).rev() {
            let data = &self.levels[l];
            if data.count < 6 {
                continue; // only coarser levels can be this small (checked in `new`)
            }
            scratch.prepare(&current.levels[l], data.x.len());
            let mut last_cost = f64::INFINITY;
            for _ in 0..params.max_iterations {
                iterations += 1;
                let pose = Pose32::new(&t);
                let n = scratch.residuals(data, &pose, avx2);
                if n < 6 {
                    return Err(DenseError::TooFewPixels(n));
                }
                // Robust scale: the (upper) median of |r| over the valid residuals; invalid
                // ones hold +∞ and sort last.
                let med = *scratch
                    .absr
                    .select_nth_unstable_by(n / 2, |a, b| a.total_cmp(b))
                    .1 as f64;
                let k = (params.huber_scale * 1.4826 * med).max(1e-3);
                let sums = scratch.accumulate(k as f32, avx2);
                let (h, g) = normal_equations(&sums);
                let cost = sums[SUMS - 1] / n as f64;
                final_cost = cost;
                num_residuals = n;
                if cost > last_cost * (1.0 + 1e-9) && l == self.finest {
                    // Should not happen often with IRLS; stop rather than diverge.
                    break;
                }
                last_cost = cost;
                let Some(delta) = h.cholesky().map(|c| -c.solve(&g)) else {
                    break;
                };
                t = Se3::exp(&delta).compose(&t);
                if delta.norm() < params.min_update {
                    break;
                }
            }
        }
        Ok(DenseResult {
            cur_from_ref: t,
            final_cost,
            num_residuals,
            iterations,
        })
    }
}

/// `(1/d, 1)` for a valid depth (finite, > 0), else `(0, 0)`.
#[inline(always)]
fn inverse_depth(d: f32) -> (f32, f32) {
    if d.is_finite() && d > 0.0 {
        (1.0 / d, 1.0)
    } else {
        (0.0, 0.0)
    }
}

/// One row of level-1 block sums from depth rows `d0`, `d1`: `s[u]` sums the inverse depths
/// and `c[u]` counts the valid depths of `d0[2u], d0[2u + 1], d1[2u], d1[2u + 1]` (in that
/// order).
fn depth_block_row(d0: &[f32], d1: &[f32], s: &mut [f32], c: &mut [f32], avx2: bool) {
    let n = s.len();
    assert!(c.len() == n && d0.len() >= 2 * n && d1.len() >= 2 * n);
    let mut done = 0;
    #[cfg(target_arch = "x86_64")]
    if avx2 {
        // SAFETY: `avx2` comes from `simd::avx2()`; lengths asserted above.
        done = unsafe { depth_block_row_avx2(d0, d1, s, c) };
    }
    let _ = avx2;
    for u in done..n {
        let [a, b, e, f] = [d0[2 * u], d0[2 * u + 1], d1[2 * u], d1[2 * u + 1]].map(inverse_depth);
        s[u] = ((a.0 + b.0) + e.0) + f.0;
        c[u] = ((a.1 + b.1) + e.1) + f.1;
    }
}

/// AVX2 kernel of [`depth_block_row`] for the first `8·⌊n/8⌋` outputs (returned): 16 depths
/// of each row per step, inverted and masked, split into even and odd columns and summed in
/// the scalar order.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn depth_block_row_avx2(d0: &[f32], d1: &[f32], s: &mut [f32], c: &mut [f32]) -> usize {
    use std::arch::x86_64::*;
    let n = s.len() / LANES * LANES;
    assert!(c.len() >= n && d0.len() >= 2 * n && d1.len() >= 2 * n);
    // SAFETY: reads d0/d1[2u .. 2u + 16] and writes s/c[u .. u + 8] with u + 8 ≤ n (asserted).
    unsafe {
        let one = _mm256_set1_ps(1.0);
        let zero = _mm256_setzero_ps();
        let inf = _mm256_set1_ps(f32::INFINITY);
        // (1/d, 1) masked by d > 0 ∧ d < ∞ (false for NaN), as `inverse_depth`.
        let inv = |p: *const f32| {
            let d = _mm256_loadu_ps(p);
            let ok = _mm256_and_ps(
                _mm256_cmp_ps::<_CMP_GT_OQ>(d, zero),
                _mm256_cmp_ps::<_CMP_LT_OQ>(d, inf),
            );
            (
                _mm256_and_ps(_mm256_div_ps(one, d), ok),
                _mm256_and_ps(one, ok),
            )
        };
        // Even and odd elements of 16 consecutive values, each in order.
        let split = |lo: __m256, hi: __m256| {
            let even = _mm256_shuffle_ps::<0x88>(lo, hi);
            let odd = _mm256_shuffle_ps::<0xDD>(lo, hi);
            let fix =
                |x: __m256| _mm256_castpd_ps(_mm256_permute4x64_pd::<0xD8>(_mm256_castps_pd(x)));
            (fix(even), fix(odd))
        };
        for u in (0..n).step_by(LANES) {
            let (a_lo, ac_lo) = inv(d0.as_ptr().add(2 * u));
            let (a_hi, ac_hi) = inv(d0.as_ptr().add(2 * u + 8));
            let (b_lo, bc_lo) = inv(d1.as_ptr().add(2 * u));
            let (b_hi, bc_hi) = inv(d1.as_ptr().add(2 * u + 8));
            let ((ae, ao), (be, bo)) = (split(a_lo, a_hi), split(b_lo, b_hi));
            let ((ace, aco), (bce, bco)) = (split(ac_lo, ac_hi), split(bc_lo, bc_hi));
            let sum = _mm256_add_ps(_mm256_add_ps(_mm256_add_ps(ae, ao), be), bo);
            let cnt = _mm256_add_ps(_mm256_add_ps(_mm256_add_ps(ace, aco), bce), bco);
            _mm256_storeu_ps(s.as_mut_ptr().add(u), sum);
            _mm256_storeu_ps(c.as_mut_ptr().add(u), cnt);
        }
    }
    n
}

/// The reference points of level `l` (see [`DenseReference::new`]) from the level image `img`
/// and the level's block sums `sum`, `cnt` (row stride `stride`).
fn level_points(
    img: &GrayImage,
    sum: &[f32],
    cnt: &[f32],
    stride: usize,
    cam: PinholeCamera,
    l: usize,
    min_gradient: f32,
) -> ReferenceLevel {
    let half = ((1usize << l) * (1usize << l)) as f32 * 0.5;
    let [fx, fy, cx, cy] = [cam.fx as f32, cam.fy as f32, cam.cx as f32, cam.cy as f32];
    let mut out = ReferenceLevel {
        camera: [fx, fy, cx, cy],
        ..Default::default()
    };
    let mg2 = min_gradient * min_gradient;
    let (w, h) = (img.width(), img.height());
    for v in 1..h.saturating_sub(1) {
        let (up, row, down) = (img.row(v - 1), img.row(v), img.row(v + 1));
        let (srow, crow) = (&sum[v * stride..], &cnt[v * stride..]);
        for u in 1..w.saturating_sub(1) {
            let gx = 0.5 * (row[u + 1] as f32 - row[u - 1] as f32);
            let gy = 0.5 * (down[u] as f32 - up[u] as f32);
            let n = crow[u];
            if gx * gx + gy * gy < mg2 || n < half || n == 0.0 {
                continue;
            }
            let z = n / srow[u];
            if !(z.is_finite() && z > geom::MIN_DEPTH as f32) {
                continue;
            }
            out.x.push((u as f32 - cx) / fx * z);
            out.y.push((v as f32 - cy) / fy * z);
            out.z.push(z);
            out.intensity.push(row[u] as f32);
        }
    }
    out.count = out.z.len();
    let padded = out.count.div_ceil(LANES) * LANES;
    for c in [&mut out.x, &mut out.y, &mut out.z, &mut out.intensity] {
        c.resize(padded, f32::NAN);
    }
    out
}

/// `cur_from_ref` in f32 for the residual kernels: `R` row-major and `t`.
#[derive(Debug, Clone, Copy)]
struct Pose32 {
    r: [f32; 9],
    t: [f32; 3],
}

impl Pose32 {
    fn new(t: &Se3) -> Self {
        let m = t.rotation().rotation_matrix();
        let tr = t.translation();
        Self {
            r: std::array::from_fn(|i| m[(i / 3, i % 3)] as f32),
            t: [tr.x as f32, tr.y as f32, tr.z as f32],
        }
    }
}

/// Buffers of [`DenseReference::align`]: the current level's intensities and gradients, and
/// per residual `r`, its Jacobian (six planes) and `|r|` for the median. Grown when needed,
/// never shrunk, so a tracker that keeps one allocates only on its first frames.
#[derive(Debug, Clone, Default)]
pub struct DenseScratch {
    /// Current level, per pixel (row stride `width`) `[I, ∂I/∂u, ∂I/∂v, 0]` (central
    /// differences, 0 on the border): one 256-bit load reads a pixel and its right neighbour.
    taps: Vec<f32>,
    width: usize,
    height: usize,
    r: Vec<f32>,
    j: [Vec<f32>; 6],
    absr: Vec<f32>,
}

impl DenseScratch {
    /// Fills the taps from `img` and sizes the residual buffers for `n` (padded) points.
    fn prepare(&mut self, img: &GrayImage, n: usize) {
        let (w, h) = (img.width(), img.height());
        (self.width, self.height) = (w, h);
        self.taps.clear();
        self.taps.resize(4 * w * h, 0.0);
        for v in 0..h {
            let row = img.row(v);
            let out = &mut self.taps[4 * v * w..4 * (v + 1) * w];
            for (o, &p) in out.chunks_exact_mut(4).zip(row) {
                o[0] = p as f32;
            }
            if v == 0 || v + 1 >= h || w < 3 {
                continue;
            }
            let (up, down) = (img.row(v - 1), img.row(v + 1));
            for u in 1..w - 1 {
                out[4 * u + 1] = 0.5 * (row[u + 1] as f32 - row[u - 1] as f32);
                out[4 * u + 2] = 0.5 * (down[u] as f32 - up[u] as f32);
            }
        }
        self.r.resize(n, 0.0);
        self.absr.resize(n, 0.0);
        for j in &mut self.j {
            j.resize(n, 0.0);
        }
    }

    /// Residuals `r = I_cur(ẑ(T·y)) − I_ref` and Jacobians of every point of `data` (zero for
    /// points that leave the image or fall behind the camera, `|r| = ∞` for those); returns the
    /// number of valid residuals.
    fn residuals(&mut self, data: &ReferenceLevel, pose: &Pose32, avx2: bool) -> usize {
        let n = data.x.len();
        debug_assert!(self.r.len() == n && n.is_multiple_of(LANES));
        if self.width < 3 || self.height < 3 {
            self.r.fill(0.0);
            self.absr.fill(f32::INFINITY);
            self.j.iter_mut().for_each(|j| j.fill(0.0));
            return 0;
        }
        #[cfg(target_arch = "x86_64")]
        if avx2 {
            // SAFETY: `avx2` comes from `simd::avx2()`; the buffers have n entries (prepare),
            // the taps 4·width·height with width, height ≥ 3.
            return unsafe { residuals_avx2(self, data, pose) };
        }
        let _ = avx2;
        residuals_scalar(self, data, pose)
    }

    /// The lane sums of `w·J·Jᵀ` (upper triangle), `w·J·r` and `ρ(r)` with the Huber weights
    /// for threshold `k` (see [`accumulate`]).
    fn accumulate(&self, k: f32, avx2: bool) -> [f64; SUMS] {
        #[cfg(target_arch = "x86_64")]
        if avx2 {
            // SAFETY: `avx2` comes from `simd::avx2()`; all buffers have the same length, a
            // multiple of LANES.
            return unsafe { accumulate_avx2(&self.r, &self.j, k) };
        }
        let _ = avx2;
        accumulate_scalar(&self.r, &self.j, k)
    }
}

/// The scalar reference of the residual kernel: per point `x = R·y + t`,
/// `(u, v) = (f_x·x₁/x₃ + c_x, f_y·x₂/x₃ + c_y)`, the bilinear intensity and gradient of the
/// current level at `(u, v)` (the same samples as [`bilinear_with_gradient`](crate::interp::bilinear_with_gradient)), `r = I − I_ref`
/// and `J = ∇I·∂ẑ/∂x·[I | −[x]×]` (thesis eq. B.4, B.12), written as
/// `J_v = (a, b, −(a·x₁ + b·x₂)/x₃)` with `a = ∂I/∂u·f_x/x₃`, `b = ∂I/∂v·f_y/x₃` and
/// `J_ω = x × J_v`. The AVX2 kernel performs the same operations in the same order.
fn residuals_scalar(s: &mut DenseScratch, data: &ReferenceLevel, pose: &Pose32) -> usize {
    let [fx, fy, cx, cy] = data.camera;
    let (w, h) = (s.width, s.height);
    let (umax, vmax) = ((w - 2) as f32, (h - 2) as f32);
    let taps = &s.taps[..];
    let [r0, r1, r2, r3, r4, r5, r6, r7, r8] = pose.r;
    let [t0, t1, t2] = pose.t;
    let mut count = 0;
    for k in 0..data.x.len() {
        let (px, py, pz) = (data.x[k], data.y[k], data.z[k]);
        let x = ((r0 * px + r1 * py) + r2 * pz) + t0;
        let y = ((r3 * px + r4 * py) + r5 * pz) + t1;
        let z = ((r6 * px + r7 * py) + r8 * pz) + t2;
        let iz = 1.0 / z;
        let u = fx * (x * iz) + cx;
        let v = fy * (y * iz) + cy;
        if !(z > geom::MIN_DEPTH as f32 && u >= 1.0 && v >= 1.0 && u <= umax && v <= vmax) {
            s.r[k] = 0.0;
            s.absr[k] = f32::INFINITY;
            s.j.iter_mut().for_each(|j| j[k] = 0.0);
            continue;
        }
        count += 1;
        let u0 = (u as usize).min(w - 3);
        let v0 = (v as usize).min(h - 3);
        let a = u - u0 as f32;
        let b = v - v0 as f32;
        let w00 = (1.0 - a) * (1.0 - b);
        let w10 = a * (1.0 - b);
        let w01 = (1.0 - a) * b;
        let w11 = a * b;
        let i = 4 * (v0 * w + u0);
        let mix = |c: usize| {
            w00 * taps[i + c]
                + w10 * taps[i + 4 + c]
                + w01 * taps[i + 4 * w + c]
                + w11 * taps[i + 4 * w + 4 + c]
        };
        let (ic, gu, gv) = (mix(0), mix(1), mix(2));
        let r = ic - data.intensity[k];
        let ja = (gu * fx) * iz;
        let jb = (gv * fy) * iz;
        let jc = -((ja * x + jb * y) * iz);
        s.r[k] = r;
        s.absr[k] = r.abs();
        s.j[0][k] = ja;
        s.j[1][k] = jb;
        s.j[2][k] = jc;
        s.j[3][k] = y * jc - z * jb;
        s.j[4][k] = z * ja - x * jc;
        s.j[5][k] = x * jb - y * ja;
    }
    count
}

/// AVX2 kernel of [`residuals_scalar`]: eight points per step, no FMA. The 12 bilinear taps of
/// a point are two 256-bit loads (pixels `(u₀, v₀), (u₀ + 1, v₀)` and the row below, each
/// `[I, ∂I/∂u, ∂I/∂v, 0]`), transposed to one vector per tap across the eight points: 16 loads
/// and 40 shuffles where gathers took 12 `vgatherdps` (measured 1.6× slower in total). Lanes
/// that fail the tests read pixel (1, 1) and are zeroed after.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn residuals_avx2(s: &mut DenseScratch, data: &ReferenceLevel, pose: &Pose32) -> usize {
    use std::arch::x86_64::*;
    let [fx, fy, cx, cy] = data.camera.map(|c| _mm256_set1_ps(c));
    let (w, h) = (s.width, s.height);
    let n = data.x.len();
    assert!(
        data.y.len() == n
            && data.z.len() == n
            && data.intensity.len() == n
            && s.r.len() == n
            && s.absr.len() == n
            && s.j.iter().all(|j| j.len() == n)
            && s.taps.len() == 4 * w * h
            && w >= 3
            && h >= 3
            && n.is_multiple_of(LANES)
    );
    // SAFETY: loads and stores touch [k, k + 8) with k + 8 ≤ n of slices of length n (asserted);
    // tap loads read taps[4·idx .. 4·idx + 8] and taps[4·(idx + w) .. + 8] with
    // idx = v0·w + u0, 0 ≤ u0 ≤ w − 3 and 0 ≤ v0 ≤ h − 3 (valid lanes: 1 ≤ u ≤ w − 2 truncated
    // and clamped; invalid lanes: u = 1), so idx + w + 1 < w·h: inside the 4·w·h taps.
    unsafe {
        let one = _mm256_set1_ps(1.0);
        let sign = _mm256_set1_ps(-0.0);
        let inf = _mm256_set1_ps(f32::INFINITY);
        let min_z = _mm256_set1_ps(geom::MIN_DEPTH as f32);
        let (umax, vmax) = (
            _mm256_set1_ps((w - 2) as f32),
            _mm256_set1_ps((h - 2) as f32),
        );
        let (u0max, v0max) = (
            _mm256_set1_epi32(w as i32 - 3),
            _mm256_set1_epi32(h as i32 - 3),
        );
        let wv = _mm256_set1_epi32(w as i32);
        let rm = pose.r.map(|c| _mm256_set1_ps(c));
        let [t0, t1, t2] = pose.t.map(|c| _mm256_set1_ps(c));
        let taps = s.taps.as_ptr();
        let mut lane_idx = [0i32; LANES];
        let mut count = 0u32;
        for k in (0..n).step_by(LANES) {
            let px = _mm256_loadu_ps(data.x.as_ptr().add(k));
            let py = _mm256_loadu_ps(data.y.as_ptr().add(k));
            let pz = _mm256_loadu_ps(data.z.as_ptr().add(k));
            let x = _mm256_add_ps(
                _mm256_add_ps(
                    _mm256_add_ps(_mm256_mul_ps(rm[0], px), _mm256_mul_ps(rm[1], py)),
                    _mm256_mul_ps(rm[2], pz),
                ),
                t0,
            );
            let y = _mm256_add_ps(
                _mm256_add_ps(
                    _mm256_add_ps(_mm256_mul_ps(rm[3], px), _mm256_mul_ps(rm[4], py)),
                    _mm256_mul_ps(rm[5], pz),
                ),
                t1,
            );
            let z = _mm256_add_ps(
                _mm256_add_ps(
                    _mm256_add_ps(_mm256_mul_ps(rm[6], px), _mm256_mul_ps(rm[7], py)),
                    _mm256_mul_ps(rm[8], pz),
                ),
                t2,
            );
            let iz = _mm256_div_ps(one, z);
            let u = _mm256_add_ps(_mm256_mul_ps(fx, _mm256_mul_ps(x, iz)), cx);
            let v = _mm256_add_ps(_mm256_mul_ps(fy, _mm256_mul_ps(y, iz)), cy);
            let valid = _mm256_and_ps(
                _mm256_and_ps(
                    _mm256_cmp_ps::<_CMP_GT_OQ>(z, min_z),
                    _mm256_and_ps(
                        _mm256_cmp_ps::<_CMP_GE_OQ>(u, one),
                        _mm256_cmp_ps::<_CMP_GE_OQ>(v, one),
                    ),
                ),
                _mm256_and_ps(
                    _mm256_cmp_ps::<_CMP_LE_OQ>(u, umax),
                    _mm256_cmp_ps::<_CMP_LE_OQ>(v, vmax),
                ),
            );
            let bits = _mm256_movemask_ps(valid);
            if bits == 0 {
                let zero = _mm256_setzero_ps();
                _mm256_storeu_ps(s.r.as_mut_ptr().add(k), zero);
                _mm256_storeu_ps(s.absr.as_mut_ptr().add(k), inf);
                for j in &mut s.j {
                    _mm256_storeu_ps(j.as_mut_ptr().add(k), zero);
                }
                continue;
            }
            count += bits.count_ones();
            let us = _mm256_blendv_ps(one, u, valid);
            let vs = _mm256_blendv_ps(one, v, valid);
            let u0 = _mm256_min_epi32(_mm256_cvttps_epi32(us), u0max);
            let v0 = _mm256_min_epi32(_mm256_cvttps_epi32(vs), v0max);
            let a = _mm256_sub_ps(us, _mm256_cvtepi32_ps(u0));
            let b = _mm256_sub_ps(vs, _mm256_cvtepi32_ps(v0));
            let (na, nb) = (_mm256_sub_ps(one, a), _mm256_sub_ps(one, b));
            let (w00, w10, w01, w11) = (
                _mm256_mul_ps(na, nb),
                _mm256_mul_ps(a, nb),
                _mm256_mul_ps(na, b),
                _mm256_mul_ps(a, b),
            );
            let idx = _mm256_add_epi32(_mm256_mullo_epi32(v0, wv), u0);
            _mm256_storeu_si256(lane_idx.as_mut_ptr() as *mut __m256i, idx);
            let top: [__m256; LANES] =
                std::array::from_fn(|l| _mm256_loadu_ps(taps.add(4 * lane_idx[l] as usize)));
            let bottom: [__m256; LANES] =
                std::array::from_fn(|l| _mm256_loadu_ps(taps.add(4 * (lane_idx[l] as usize + w))));
            // [I, ∂u, ∂v] at (u₀, v₀) and (u₀ + 1, v₀), then the row below.
            let [i00, gu00, gv00, i10, gu10, gv10] = transpose_taps(top);
            let [i01, gu01, gv01, i11, gu11, gv11] = transpose_taps(bottom);
            let mix = |f00, f10, f01, f11| {
                _mm256_add_ps(
                    _mm256_add_ps(
                        _mm256_add_ps(_mm256_mul_ps(w00, f00), _mm256_mul_ps(w10, f10)),
                        _mm256_mul_ps(w01, f01),
                    ),
                    _mm256_mul_ps(w11, f11),
                )
            };
            let ic = mix(i00, i10, i01, i11);
            let gu = mix(gu00, gu10, gu01, gu11);
            let gv = mix(gv00, gv10, gv01, gv11);
            let r = _mm256_sub_ps(ic, _mm256_loadu_ps(data.intensity.as_ptr().add(k)));
            let ja = _mm256_mul_ps(_mm256_mul_ps(gu, fx), iz);
            let jb = _mm256_mul_ps(_mm256_mul_ps(gv, fy), iz);
            let jc = _mm256_xor_ps(
                _mm256_mul_ps(
                    _mm256_add_ps(_mm256_mul_ps(ja, x), _mm256_mul_ps(jb, y)),
                    iz,
                ),
                sign,
            );
            let js = [
                ja,
                jb,
                jc,
                _mm256_sub_ps(_mm256_mul_ps(y, jc), _mm256_mul_ps(z, jb)),
                _mm256_sub_ps(_mm256_mul_ps(z, ja), _mm256_mul_ps(x, jc)),
                _mm256_sub_ps(_mm256_mul_ps(x, jb), _mm256_mul_ps(y, ja)),
            ];
            _mm256_storeu_ps(s.r.as_mut_ptr().add(k), _mm256_and_ps(r, valid));
            _mm256_storeu_ps(
                s.absr.as_mut_ptr().add(k),
                _mm256_blendv_ps(inf, _mm256_andnot_ps(sign, r), valid),
            );
            for (j, v) in s.j.iter_mut().zip(js) {
                _mm256_storeu_ps(j.as_mut_ptr().add(k), _mm256_and_ps(v, valid));
            }
        }
        count as usize
    }
}

/// Transposes the tap loads of eight points (`rows[k]` = point `k`'s
/// `[I, ∂u, ∂v, 0, I', ∂u', ∂v', 0]` of two neighbouring pixels) into six vectors across the
/// points: `[I, ∂u, ∂v, I', ∂u', ∂v']` (the two zero columns are not formed).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[inline]
fn transpose_taps(rows: [std::arch::x86_64::__m256; LANES]) -> [std::arch::x86_64::__m256; 6] {
    use std::arch::x86_64::*;
    let [r0, r1, r2, r3, r4, r5, r6, r7] = rows;
    // Pairs of points: [a0 b0 a1 b1 | a4 b4 a5 b5] and [a2 b2 a3 b3 | a6 b6 a7 b7].
    let (t0, t1) = (_mm256_unpacklo_ps(r0, r1), _mm256_unpackhi_ps(r0, r1));
    let (t2, t3) = (_mm256_unpacklo_ps(r2, r3), _mm256_unpackhi_ps(r2, r3));
    let (t4, t5) = (_mm256_unpacklo_ps(r4, r5), _mm256_unpackhi_ps(r4, r5));
    let (t6, t7) = (_mm256_unpacklo_ps(r6, r7), _mm256_unpackhi_ps(r6, r7));
    // Quads of points: columns (0 | 4), (1 | 5), (2 | 6) for points 0–3 and 4–7.
    let s0 = _mm256_shuffle_ps::<0x44>(t0, t2);
    let s1 = _mm256_shuffle_ps::<0xEE>(t0, t2);
    let s2 = _mm256_shuffle_ps::<0x44>(t1, t3);
    let s4 = _mm256_shuffle_ps::<0x44>(t4, t6);
    let s5 = _mm256_shuffle_ps::<0xEE>(t4, t6);
    let s6 = _mm256_shuffle_ps::<0x44>(t5, t7);
    [
        _mm256_permute2f128_ps::<0x20>(s0, s4),
        _mm256_permute2f128_ps::<0x20>(s1, s5),
        _mm256_permute2f128_ps::<0x20>(s2, s6),
        _mm256_permute2f128_ps::<0x31>(s0, s4),
        _mm256_permute2f128_ps::<0x31>(s1, s5),
        _mm256_permute2f128_ps::<0x31>(s2, s6),
    ]
}

/// The Huber-weighted sums over all residuals, lane by lane: residual `i` goes to lane
/// `i mod 8`, with `w = 1, ρ = r²` for `|r| ≤ k` and `w = k/|r|, ρ = 2k|r| − k²` beyond
/// (IRLS for the Huber kernel), entries `0..21` of `Σ w·J·Jᵀ` (upper triangle, row by row),
/// `21..27` of `Σ w·J·r` and `27` of `Σ ρ`. f32 lane sums are moved into f64 lane totals every
/// [`FLUSH_CHUNKS`] chunks; the lanes are summed in order at the end. Invalid residuals have
/// `r = 0`, `J = 0` and add exact zeros.
#[allow(clippy::needless_range_loop)] // lane and entry indices as in the AVX2 kernel
fn accumulate_scalar(r: &[f32], j: &[Vec<f32>; 6], k: f32) -> [f64; SUMS] {
    let (two_k, kk) = (2.0 * k, k * k);
    let mut acc = [[0.0f32; LANES]; SUMS];
    let mut tot = [[0.0f64; LANES]; SUMS];
    let chunks = r.len() / LANES;
    for c in 0..chunks {
        for l in 0..LANES {
            let i = c * LANES + l;
            let ri = r[i];
            let a = ri.abs();
            let (wt, rho) = if a <= k {
                (1.0, ri * ri)
            } else {
                (k / a, two_k * a - kk)
            };
            let ji: [f32; 6] = std::array::from_fn(|m| j[m][i]);
            let wj = ji.map(|x| wt * x);
            let mut e = 0;
            for p in 0..6 {
                for q in p..6 {
                    acc[e][l] += wj[p] * ji[q];
                    e += 1;
                }
            }
            for p in 0..6 {
                acc[H_ENTRIES + p][l] += wj[p] * ri;
            }
            acc[SUMS - 1][l] += rho;
        }
        if (c + 1) % FLUSH_CHUNKS == 0 || c + 1 == chunks {
            for (t, a) in tot.iter_mut().zip(acc.iter_mut()) {
                for l in 0..LANES {
                    t[l] += a[l] as f64;
                    a[l] = 0.0;
                }
            }
        }
    }
    reduce_lanes(&tot)
}

/// AVX2 kernel of [`accumulate_scalar`] (same operations and order, no FMA).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[allow(clippy::needless_range_loop)] // entry indices as in the scalar path
unsafe fn accumulate_avx2(r: &[f32], j: &[Vec<f32>; 6], k: f32) -> [f64; SUMS] {
    use std::arch::x86_64::*;
    let n = r.len();
    assert!(n.is_multiple_of(LANES) && j.iter().all(|j| j.len() == n));
    let chunks = n / LANES;
    let mut tot = [[0.0f64; LANES]; SUMS];
    // SAFETY: loads read [c·8, c·8 + 8) ⊂ [0, n) of slices of length n (asserted); stores
    // write the 8 f64 of one `tot` row.
    unsafe {
        let kv = _mm256_set1_ps(k);
        let two_k = _mm256_set1_ps(2.0 * k);
        let kk = _mm256_set1_ps(k * k);
        let one = _mm256_set1_ps(1.0);
        let sign = _mm256_set1_ps(-0.0);
        let mut acc = [_mm256_setzero_ps(); SUMS];
        let mut acc64 = [[_mm256_setzero_pd(); 2]; SUMS];
        for c in 0..chunks {
            let o = c * LANES;
            let ri = _mm256_loadu_ps(r.as_ptr().add(o));
            let a = _mm256_andnot_ps(sign, ri);
            let inside = _mm256_cmp_ps::<_CMP_LE_OQ>(a, kv);
            let wt = _mm256_blendv_ps(_mm256_div_ps(kv, a), one, inside);
            let rho = _mm256_blendv_ps(
                _mm256_sub_ps(_mm256_mul_ps(two_k, a), kk),
                _mm256_mul_ps(ri, ri),
                inside,
            );
            let ji: [__m256; 6] = std::array::from_fn(|m| _mm256_loadu_ps(j[m].as_ptr().add(o)));
            let wj = ji.map(|x| _mm256_mul_ps(wt, x));
            let mut e = 0;
            for p in 0..6 {
                for q in p..6 {
                    acc[e] = _mm256_add_ps(acc[e], _mm256_mul_ps(wj[p], ji[q]));
                    e += 1;
                }
            }
            for p in 0..6 {
                acc[H_ENTRIES + p] = _mm256_add_ps(acc[H_ENTRIES + p], _mm256_mul_ps(wj[p], ri));
            }
            acc[SUMS - 1] = _mm256_add_ps(acc[SUMS - 1], rho);
            if (c + 1) % FLUSH_CHUNKS == 0 || c + 1 == chunks {
                for (t, a) in acc64.iter_mut().zip(acc.iter_mut()) {
                    t[0] = _mm256_add_pd(t[0], _mm256_cvtps_pd(_mm256_castps256_ps128(*a)));
                    t[1] = _mm256_add_pd(t[1], _mm256_cvtps_pd(_mm256_extractf128_ps::<1>(*a)));
                    *a = _mm256_setzero_ps();
                }
            }
        }
        for (t, a) in tot.iter_mut().zip(&acc64) {
            _mm256_storeu_pd(t.as_mut_ptr(), a[0]);
            _mm256_storeu_pd(t.as_mut_ptr().add(4), a[1]);
        }
    }
    reduce_lanes(&tot)
}

/// Sums each accumulator's lanes in lane order (both paths).
fn reduce_lanes(tot: &[[f64; LANES]; SUMS]) -> [f64; SUMS] {
    std::array::from_fn(|e| tot[e].iter().fold(0.0, |s, &x| s + x))
}

/// `H` (symmetric, from its upper triangle) and `g` from the sums of [`accumulate_scalar`].
fn normal_equations(sums: &[f64; SUMS]) -> (Matrix6<f64>, Vector6<f64>) {
    let mut h = Matrix6::zeros();
    let mut e = 0;
    for p in 0..6 {
        for q in p..6 {
            h[(p, q)] = sums[e];
            h[(q, p)] = sums[e];
            e += 1;
        }
    }
    (h, Vector6::from_fn(|p, _| sums[H_ENTRIES + p]))
}

/// Aligns `current` to `reference` whose per-pixel depth (metres along the optical axis; `NaN`
/// or ≤ 0 where unknown) is `depth`, with intrinsics `camera` (of level 0), starting from
/// `initial_cur_from_ref`.
pub fn align(
    reference: &GrayImage,
    depth: &Image<f32>,
    current: &GrayImage,
    camera: &PinholeCamera,
    initial_cur_from_ref: &Se3,
    params: &DenseParams,
) -> Result<DenseResult, DenseError> {
    if reference.width() != current.width() || reference.height() != current.height() {
        return Err(ImageError::SizeMismatch(
            reference.width(),
            reference.height(),
            current.width(),
            current.height(),
        )
        .into());
    }
    if depth.width() != reference.width() || depth.height() != reference.height() {
        return Err(ImageError::SizeMismatch(
            reference.width(),
            reference.height(),
            depth.width(),
            depth.height(),
        )
        .into());
    }
    let pr = Pyramid::new(reference, params.levels.max(1), 16)?;
    let pc = Pyramid::new(current, params.levels.max(1), 16)?;
    align_pyramids(&pr, depth, &pc, camera, initial_cur_from_ref, params)
}

/// [`align`] on pyramids built already: level 0 of `reference` and `depth` have the same size,
/// `camera` is level 0's. Prepares a [`DenseReference`] and aligns once; a tracker that aligns
/// each frame against the previous one keeps the reference (and a [`DenseScratch`]) instead.
pub fn align_pyramids(
    pr: &Pyramid,
    depth: &Image<f32>,
    pc: &Pyramid,
    camera: &PinholeCamera,
    initial_cur_from_ref: &Se3,
    params: &DenseParams,
) -> Result<DenseResult, DenseError> {
    DenseReference::new(pr, depth, camera, params)?.align(
        pc,
        initial_cur_from_ref,
        &mut DenseScratch::default(),
    )
}

/// The photometric residual image `I_cur(ẑ(T·y_{u,v})) − I_ref(u, v)` at level 0 (NaN where the
/// depth is unknown or the point leaves the current image), for inspection (thesis Fig. 6.6c).
pub fn residual_image(
    reference: &GrayImage,
    depth: &Image<f32>,
    current: &GrayImage,
    camera: &PinholeCamera,
    cur_from_ref: &Se3,
) -> Image<f32> {
    Image::from_fn(reference.width(), reference.height(), |u, v| {
        let d = depth.get_checked(u as i64, v as i64).unwrap_or(f32::NAN);
        if !(d.is_finite() && d > 0.0) {
            return f32::NAN;
        }
        let Ok(y) = camera.unproject_depth(&Vector2::new(u as f64, v as f64), d as f64) else {
            return f32::NAN;
        };
        let Ok(uv) = camera.project(&cur_from_ref.act(&y)) else {
            return f32::NAN;
        };
        match bilinear(current, uv.x as f32, uv.y as f32) {
            Some(i) => i - reference.get(u, v) as f32,
            None => f32::NAN,
        }
    })
}

#[cfg(test)]
mod tests;
