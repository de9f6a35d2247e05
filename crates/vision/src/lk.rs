//! Pyramidal Lucas-Kanade sparse tracking, inverse compositional (Baker & Matthews 2004), with a
//! forward-backward check (thesis §3.4.2, §6.3).
//!
//! For a template window `T` around `p` in the previous image and the translation warp
//! `W(x; g) = x + g`, the inverse compositional algorithm minimises
//! `Σ_x [I(W(x; g)) − T(W(x; Δ))]²` over `Δ` and updates `g ← g − Δ`, with
//! `Δ = H⁻¹ Σ_x ∇Tᵀ (I(x + g) − T(x))`, `H = Σ_x ∇Tᵀ∇T` computed once per level.
//! Coarse-to-fine: the displacement found on level `l + 1` (doubled) initialises level `l`.
//!
//! On the finest [`LkParams::affine_levels`] levels the warp is affine,
//! `W(x; c, A) = c + A·(x − p)`, solved inverse compositionally as well (Baker & Matthews 2004,
//! §3.2: the 6×6 Hessian of the template's steepest-descent images once per level, the update
//! composed as `W ← W ∘ W(Δ)⁻¹`). A patch that grows or shears between the frames — the road and
//! the sides of a forward drive — drags a translation-only window towards the patch's texture
//! centre, a lag that grows with the flow (`vision_bench lkroad`); the affine warp follows the
//! deformation instead. The forward-backward check of an affine track starts its backward pass
//! at the inverse warp, so a correct track returns to its start whatever the patch's deformation.

use crate::image::Image;
use crate::pyramid::Pyramid;

/// Parameters of [`track`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LkParams {
    /// Half window size: the window is `(2r + 1)²` pixels (OpenCV's default `winSize` 21 ↔ 10).
    pub window_radius: usize,
    /// Maximum Gauss-Newton iterations per level.
    pub max_iterations: usize,
    /// Stop when the update is shorter than this (pixels of the level).
    pub epsilon: f32,
    /// Reject a window whose structure tensor's smaller eigenvalue (gradients in intensity units
    /// per pixel), divided by the window's pixel count, is below this (OpenCV's
    /// `minEigThreshold`).
    pub min_eigenvalue: f32,
    /// Number of pyramid levels used (≤ the pyramids' depth).
    pub levels: usize,
    /// The finest levels solved with an affine warp instead of a translation (0: translation
    /// on every level, OpenCV's tracker).
    pub affine_levels: usize,
}

impl Default for LkParams {
    /// OpenCV's defaults: 21×21 window, 4 levels (`maxLevel = 3`), 30 iterations, ε = 0.01,
    /// `minEigThreshold = 1e-4`.
    fn default() -> Self {
        Self {
            window_radius: 10,
            max_iterations: 30,
            epsilon: 0.01,
            min_eigenvalue: 1e-4,
            levels: 4,
            affine_levels: 0,
        }
    }
}

/// Samples the `n×n` patch whose top-left sample is at real coordinates `(x, y)` with bilinear
/// interpolation (the weights are the same for all samples); coordinates are clamped to the
/// image (border replication). Writes `n·n` values into `out`; `block` is scratch for the
/// clamped `(n+1)²` source block at the border.
///
/// Every sample is `((w₀₀·I₀₀ + w₁₀·I₁₀) + w₀₁·I₀₁) + w₁₁·I₁₁` in f32, evaluated in this order
/// on both paths, so the AVX2 kernel ([`bilinear_block_avx2`]) gives the scalar path's values
/// bit for bit.
#[inline(always)]
fn sample_patch<const AVX2: bool>(
    img: &Image<u8>,
    x: f32,
    y: f32,
    n: usize,
    out: &mut [f32],
    block: &mut Vec<u8>,
) {
    let xf = x.floor();
    let yf = y.floor();
    let a = x - xf;
    let b = y - yf;
    let wts = [(1.0 - a) * (1.0 - b), a * (1.0 - b), (1.0 - a) * b, a * b];
    let (x0, y0) = (xf as i64, yf as i64);
    let (w, h) = (img.width() as i64, img.height() as i64);
    let (src, stride): (&[u8], usize) =
        if x0 >= 0 && y0 >= 0 && x0 + (n as i64) < w && y0 + (n as i64) < h {
            let st = img.stride();
            (&img.data()[y0 as usize * st + x0 as usize..], st)
        } else {
            // Border: copy the clamped (n+1)² source block once, then sample it as above.
            block.clear();
            // Columns x0 + i for i in 0..=n: clamped to the left for i < lo, copied for
            // lo ≤ i < hi, clamped to the right for i ≥ hi.
            let lo = (-x0).clamp(0, n as i64 + 1) as usize;
            let hi = (w - x0).clamp(lo as i64, n as i64 + 1) as usize;
            for r in 0..=n as i64 {
                let row = img.row((y0 + r).clamp(0, h - 1) as usize);
                block.extend(std::iter::repeat_n(row[0], lo));
                if hi > lo {
                    let c0 = (x0 + lo as i64) as usize;
                    block.extend_from_slice(&row[c0..c0 + (hi - lo)]);
                }
                block.extend(std::iter::repeat_n(row[row.len() - 1], n + 1 - hi));
            }
            (&block[..], n + 1)
        };
    #[cfg(target_arch = "x86_64")]
    if AVX2 && n >= 8 {
        // SAFETY: AVX2 instances are only called after `simd::avx2()`; `src` holds n+1 rows of
        // n+1 pixels at `stride` (checked above for the image, built for the block).
        unsafe { bilinear_block_avx2(src, stride, n, wts, out) };
        return;
    }
    bilinear_block_scalar(src, stride, n, wts, out);
}

/// The scalar reference of [`sample_patch`]'s inner loops over an `(n+1)²` block.
#[inline(always)]
fn bilinear_block_scalar(src: &[u8], stride: usize, n: usize, wts: [f32; 4], out: &mut [f32]) {
    let [w00, w10, w01, w11] = wts;
    for r in 0..n {
        let ra = &src[r * stride..r * stride + n + 1];
        let rb = &src[(r + 1) * stride..(r + 1) * stride + n + 1];
        let o = &mut out[r * n..(r + 1) * n];
        for i in 0..n {
            o[i] = w00 * ra[i] as f32
                + w10 * ra[i + 1] as f32
                + w01 * rb[i] as f32
                + w11 * rb[i + 1] as f32;
        }
    }
}

/// AVX2 kernel of [`sample_patch`]: eight samples per step (bytes widened to i32, converted to
/// f32, the same four products summed in the same order, no FMA); the last step of a row
/// overlaps the previous one, recomputing identical values. Needs `n ≥ 8`.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn bilinear_block_avx2(src: &[u8], stride: usize, n: usize, wts: [f32; 4], out: &mut [f32]) {
    use std::arch::x86_64::*;
    debug_assert!(n >= 8 && src.len() > n * stride + n && out.len() >= n * n);
    // SAFETY: loads read src[r·stride + i .. + 9] and src[(r+1)·stride + i .. + 9] with
    // i ≤ n − 8, inside the (n+1)² block; stores write out[r·n + i .. + 8] ⊂ out[..n²].
    unsafe {
        let [w00, w10, w01, w11] = wts.map(|v| _mm256_set1_ps(v));
        let p = src.as_ptr();
        let o = out.as_mut_ptr();
        let ld = |q: *const u8| {
            _mm256_cvtepi32_ps(_mm256_cvtepu8_epi32(_mm_loadl_epi64(q as *const __m128i)))
        };
        for r in 0..n {
            let ra = p.add(r * stride);
            let rb = p.add((r + 1) * stride);
            let mut i = 0;
            loop {
                let i0 = i.min(n - 8);
                let v = _mm256_add_ps(
                    _mm256_add_ps(
                        _mm256_add_ps(
                            _mm256_mul_ps(w00, ld(ra.add(i0))),
                            _mm256_mul_ps(w10, ld(ra.add(i0 + 1))),
                        ),
                        _mm256_mul_ps(w01, ld(rb.add(i0))),
                    ),
                    _mm256_mul_ps(w11, ld(rb.add(i0 + 1))),
                );
                _mm256_storeu_ps(o.add(r * n + i0), v);
                i = i0 + 8;
                if i >= n {
                    break;
                }
            }
        }
    }
}

/// `b = Σ_x ∇T(x)ᵀ (I(x + g) − T(x))`, as `(b_x, b_y)`, with 8 lane-wise partial sums (lane `i`
/// accumulates elements `i, i + 8, …`), the lanes then summed in order and the remainder added:
/// the same order on both paths, so the AVX2 kernel matches the scalar one bit for bit.
#[inline(always)]
fn residual_dot<const AVX2: bool>(cur: &[f32], tmpl: &[f32], gx: &[f32], gy: &[f32]) -> (f32, f32) {
    const L: usize = 8;
    let len = cur.len();
    assert!(tmpl.len() == len && gx.len() == len && gy.len() == len);
    let full = len / L * L;
    let mut ax = [0.0f32; L];
    let mut ay = [0.0f32; L];
    #[cfg(target_arch = "x86_64")]
    if AVX2 {
        use std::arch::x86_64::*;
        // SAFETY: AVX2 instances run only after `simd::avx2()`; loads read k..k+8 ≤ full ≤ len
        // of four slices of length len (asserted above).
        unsafe {
            let (mut vx, mut vy) = (_mm256_setzero_ps(), _mm256_setzero_ps());
            for k in (0..full).step_by(L) {
                let e = _mm256_sub_ps(
                    _mm256_loadu_ps(cur.as_ptr().add(k)),
                    _mm256_loadu_ps(tmpl.as_ptr().add(k)),
                );
                vx = _mm256_add_ps(vx, _mm256_mul_ps(_mm256_loadu_ps(gx.as_ptr().add(k)), e));
                vy = _mm256_add_ps(vy, _mm256_mul_ps(_mm256_loadu_ps(gy.as_ptr().add(k)), e));
            }
            _mm256_storeu_ps(ax.as_mut_ptr(), vx);
            _mm256_storeu_ps(ay.as_mut_ptr(), vy);
        }
    }
    if !(cfg!(target_arch = "x86_64") && AVX2) {
        for (((c, t), gx), gy) in cur[..full]
            .chunks_exact(L)
            .zip(tmpl[..full].chunks_exact(L))
            .zip(gx[..full].chunks_exact(L))
            .zip(gy[..full].chunks_exact(L))
        {
            for i in 0..L {
                let e = c[i] - t[i];
                ax[i] += gx[i] * e;
                ay[i] += gy[i] * e;
            }
        }
    }
    let (mut bx, mut by) = (ax.iter().sum::<f32>(), ay.iter().sum::<f32>());
    for i in full..len {
        let e = cur[i] - tmpl[i];
        bx += gx[i] * e;
        by += gy[i] * e;
    }
    (bx, by)
}

/// The template (the centre `n×n` of the `(n+2)²` window `big`) and its central-difference
/// gradients, row by row. Every value is `t = m[x+1]`, `gx = 0.5·(m[x+2] − m[x])`,
/// `gy = 0.5·(d[x+1] − u[x+1])` on both paths, so the AVX2 kernel (eight columns per step, the
/// last step of a row overlapping the previous one) gives the scalar values bit for bit. Written
/// out because the compiler left the slice version scalar: a third of the tracker's time was
/// this loop (perf on 7-Scenes mono).
#[inline(always)]
fn template_gradients<const AVX2: bool>(
    big: &[f32],
    n: usize,
    tmpl: &mut [f32],
    gx: &mut [f32],
    gy: &mut [f32],
) {
    let nb = n + 2;
    assert!(big.len() >= nb * nb && tmpl.len() >= n * n && gx.len() >= n * n && gy.len() >= n * n);
    #[cfg(target_arch = "x86_64")]
    if AVX2 && n >= 8 {
        use std::arch::x86_64::*;
        // SAFETY: AVX2 instances run only after `simd::avx2()`. Row y reads big[(y + j)·nb + i
        // .. + 8] for j ≤ 2, i ≤ n − 8 + 2 = nb − 8, inside row y + j < nb of big (asserted
        // length nb²); writes [y·n + x0 .. + 8] with x0 ≤ n − 8, inside the n² outputs.
        unsafe {
            let half = _mm256_set1_ps(0.5);
            let b = big.as_ptr();
            for y in 0..n {
                let (up, mid, down) = (b.add(y * nb), b.add((y + 1) * nb), b.add((y + 2) * nb));
                let mut x = 0;
                loop {
                    let x0 = x.min(n - 8);
                    let o = y * n + x0;
                    _mm256_storeu_ps(tmpl.as_mut_ptr().add(o), _mm256_loadu_ps(mid.add(x0 + 1)));
                    let dx = _mm256_sub_ps(
                        _mm256_loadu_ps(mid.add(x0 + 2)),
                        _mm256_loadu_ps(mid.add(x0)),
                    );
                    _mm256_storeu_ps(gx.as_mut_ptr().add(o), _mm256_mul_ps(half, dx));
                    let dy = _mm256_sub_ps(
                        _mm256_loadu_ps(down.add(x0 + 1)),
                        _mm256_loadu_ps(up.add(x0 + 1)),
                    );
                    _mm256_storeu_ps(gy.as_mut_ptr().add(o), _mm256_mul_ps(half, dy));
                    x = x0 + 8;
                    if x >= n {
                        break;
                    }
                }
            }
        }
        return;
    }
    for y in 0..n {
        let (up, mid, down) = (
            &big[y * nb..(y + 1) * nb],
            &big[(y + 1) * nb..(y + 2) * nb],
            &big[(y + 2) * nb..(y + 3) * nb],
        );
        let t = &mut tmpl[y * n..(y + 1) * n];
        let gxr = &mut gx[y * n..(y + 1) * n];
        let gyr = &mut gy[y * n..(y + 1) * n];
        for x in 0..n {
            t[x] = mid[x + 1];
            gxr[x] = 0.5 * (mid[x + 2] - mid[x]);
            gyr[x] = 0.5 * (down[x + 1] - up[x + 1]);
        }
    }
}

/// The structure tensor `Σ ∇T ∇Tᵀ` as `(hxx, hxy, hyy)`, with 8 lane-wise partial sums (lane
/// `i` accumulates elements `i, i + 8, …`), the lanes summed in order and the remainder added:
/// the same order on both paths (bit for bit, as [`residual_dot`]).
#[inline(always)]
fn structure_tensor<const AVX2: bool>(gx: &[f32], gy: &[f32]) -> (f32, f32, f32) {
    const L: usize = 8;
    let len = gx.len();
    assert!(gy.len() == len);
    let full = len / L * L;
    let (mut axx, mut axy, mut ayy) = ([0.0f32; L], [0.0f32; L], [0.0f32; L]);
    #[cfg(target_arch = "x86_64")]
    if AVX2 {
        use std::arch::x86_64::*;
        // SAFETY: AVX2 instances run only after `simd::avx2()`; loads read k..k+8 ≤ full ≤ len
        // of two slices of length len (asserted above).
        unsafe {
            let (mut vxx, mut vxy, mut vyy) = (
                _mm256_setzero_ps(),
                _mm256_setzero_ps(),
                _mm256_setzero_ps(),
            );
            for k in (0..full).step_by(L) {
                let x = _mm256_loadu_ps(gx.as_ptr().add(k));
                let y = _mm256_loadu_ps(gy.as_ptr().add(k));
                vxx = _mm256_add_ps(vxx, _mm256_mul_ps(x, x));
                vxy = _mm256_add_ps(vxy, _mm256_mul_ps(x, y));
                vyy = _mm256_add_ps(vyy, _mm256_mul_ps(y, y));
            }
            _mm256_storeu_ps(axx.as_mut_ptr(), vxx);
            _mm256_storeu_ps(axy.as_mut_ptr(), vxy);
            _mm256_storeu_ps(ayy.as_mut_ptr(), vyy);
        }
    }
    if !(cfg!(target_arch = "x86_64") && AVX2) {
        for (x, y) in gx[..full].chunks_exact(L).zip(gy[..full].chunks_exact(L)) {
            for i in 0..L {
                axx[i] += x[i] * x[i];
                axy[i] += x[i] * y[i];
                ayy[i] += y[i] * y[i];
            }
        }
    }
    let (mut hxx, mut hxy, mut hyy) = (
        axx.iter().sum::<f32>(),
        axy.iter().sum::<f32>(),
        ayy.iter().sum::<f32>(),
    );
    for i in full..len {
        let (x, y) = (gx[i], gy[i]);
        hxx += x * x;
        hxy += x * y;
        hyy += y * y;
    }
    (hxx, hxy, hyy)
}

/// Scratch buffers for one point.
struct Work {
    big: Vec<f32>,
    tmpl: Vec<f32>,
    gx: Vec<f32>,
    gy: Vec<f32>,
    cur: Vec<f32>,
    block: Vec<u8>,
    /// The affine levels' steepest-descent images, six values per template pixel.
    sd: Vec<f32>,
}

impl Work {
    fn new(n: usize) -> Self {
        Self {
            big: vec![0.0; (n + 2) * (n + 2)],
            tmpl: vec![0.0; n * n],
            gx: vec![0.0; n * n],
            gy: vec![0.0; n * n],
            cur: vec![0.0; n * n],
            block: Vec::with_capacity((n + 3) * (n + 3)),
            sd: vec![0.0; 6 * n * n],
        }
    }
}

/// Samples the template window centred at `p` in `prev` and its gradients into `wk`; returns
/// the structure tensor `(hxx, hxy, hyy)`, or `None` if the window is untextured (its smaller
/// eigenvalue per pixel below `params.min_eigenvalue`, or a singular tensor).
#[inline(always)]
fn prepare_template<const AVX2: bool>(
    prev: &Image<u8>,
    p: [f32; 2],
    params: &LkParams,
    wk: &mut Work,
) -> Option<(f32, f32, f32)> {
    let r = params.window_radius;
    let n = 2 * r + 1;
    let rf = r as f32;
    sample_patch::<AVX2>(
        prev,
        p[0] - rf - 1.0,
        p[1] - rf - 1.0,
        n + 2,
        &mut wk.big,
        &mut wk.block,
    );
    template_gradients::<AVX2>(&wk.big, n, &mut wk.tmpl, &mut wk.gx, &mut wk.gy);
    let (hxx, hxy, hyy) = structure_tensor::<AVX2>(&wk.gx, &wk.gy);
    let npx = (n * n) as f32;
    let min_eig = 0.5 * (hxx + hyy - ((hxx - hyy) * (hxx - hyy) + 4.0 * hxy * hxy).sqrt()) / npx;
    (min_eig >= params.min_eigenvalue && hxx * hyy - hxy * hxy > f32::EPSILON)
        .then_some((hxx, hxy, hyy))
}

/// Tracks one point on one level: template centred at `p` in `prev`, initial displacement `g`.
/// Returns the refined displacement or `None` if the window is untextured.
#[inline(always)]
fn track_level<const AVX2: bool>(
    prev: &Image<u8>,
    next: &Image<u8>,
    p: [f32; 2],
    g: [f32; 2],
    params: &LkParams,
    wk: &mut Work,
) -> Option<[f32; 2]> {
    let tensor = prepare_template::<AVX2>(prev, p, params, wk)?;
    solve_translation::<AVX2>(next, p, g, tensor, params, wk)
}

/// [`track_level`]'s Gauss-Newton iterations, on the template and its structure tensor already
/// in `wk` ([`prepare_template`]; an affine level that falls back to translation reuses them).
#[inline(always)]
fn solve_translation<const AVX2: bool>(
    next: &Image<u8>,
    p: [f32; 2],
    g: [f32; 2],
    (hxx, hxy, hyy): (f32, f32, f32),
    params: &LkParams,
    wk: &mut Work,
) -> Option<[f32; 2]> {
    let r = params.window_radius;
    let n = 2 * r + 1;
    let rf = r as f32;
    let det = hxx * hyy - hxy * hxy;
    let (ixx, ixy, iyy) = (hyy / det, -hxy / det, hxx / det);
    let mut g = g;
    let mut prev_step = [f32::NAN, f32::NAN];
    for _ in 0..params.max_iterations {
        let (qx, qy) = (p[0] + g[0], p[1] + g[1]);
        if !(qx > -rf
            && qy > -rf
            && qx < next.width() as f32 + rf
            && qy < next.height() as f32 + rf)
        {
            return None;
        }
        sample_patch::<AVX2>(next, qx - rf, qy - rf, n, &mut wk.cur, &mut wk.block);
        let (bx, by) = residual_dot::<AVX2>(&wk.cur, &wk.tmpl, &wk.gx, &wk.gy);
        let dx = ixx * bx + ixy * by;
        let dy = ixy * bx + iyy * by;
        if dx * dx + dy * dy < params.epsilon * params.epsilon {
            g[0] -= dx;
            g[1] -= dy;
            break;
        }
        // Oscillation between two positions (as OpenCV): step back half way and stop.
        if (dx + prev_step[0]).abs() < params.epsilon && (dy + prev_step[1]).abs() < params.epsilon
        {
            g[0] -= 0.5 * dx;
            g[1] -= 0.5 * dy;
            break;
        }
        g[0] -= dx;
        g[1] -= dy;
        prev_step = [dx, dy];
    }
    if g[0].is_finite() && g[1].is_finite() {
        Some(g)
    } else {
        None
    }
}

/// `Σ aᵢ·bᵢ` in eight lane-wise partial sums (lane `i` accumulates elements `i, i + 8, …`), the
/// lanes then summed in order and the remainder added: vectorised in the AVX2 instance, the
/// same order on both paths.
#[inline(always)]
fn lane_dot(a: &[f32], b: &[f32]) -> f32 {
    const L: usize = 8;
    assert_eq!(a.len(), b.len());
    let full = a.len() / L * L;
    let mut acc = [0.0f32; L];
    for (x, y) in a[..full].chunks_exact(L).zip(b[..full].chunks_exact(L)) {
        for i in 0..L {
            acc[i] += x[i] * y[i];
        }
    }
    let mut s = acc.iter().sum::<f32>();
    for i in full..a.len() {
        s += a[i] * b[i];
    }
    s
}

/// The 2×2 part of an affine warp, row-major: offset `o` from the template's centre maps to
/// `(a₀·o_x + a₁·o_y, a₂·o_x + a₃·o_y)` (the layout of [`crate::interp::bilinear_grid`]).
pub type Affine = [f32; 4];

/// The identity [`Affine`].
pub const IDENTITY: Affine = [1.0, 0.0, 0.0, 1.0];

/// The inverse of `a`, `None` if it is singular.
fn invert(a: Affine) -> Option<Affine> {
    let det = a[0] * a[3] - a[1] * a[2];
    (det.abs() > f32::EPSILON).then(|| [a[3] / det, -a[1] / det, -a[2] / det, a[0] / det])
}

/// Samples `next` on the `n×n` grid of the warp (centre `c`, part `a`) into `out`, replicating
/// the border for samples outside the image (as [`sample_patch`]); [`bilinear_grid`]'s fast path
/// when the whole grid is inside.
///
/// [`bilinear_grid`]: crate::interp::bilinear_grid
fn sample_warped(next: &Image<u8>, c: [f32; 2], a: Affine, n: usize, out: &mut [f32]) {
    if crate::interp::bilinear_grid(next, c[0], c[1], a, n, out) {
        return;
    }
    // The border: each sample clamped into the image (a window that reaches over the border
    // is common on the coarser levels), its taps read directly.
    let (w, h) = (next.width(), next.height());
    let (wm, hm) = ((w - 1) as f32, (h - 1) as f32);
    let (st, data) = (next.stride(), next.data());
    let half = (n as f32 - 1.0) / 2.0;
    for i in 0..n {
        let oy = i as f32 - half;
        for j in 0..n {
            let ox = j as f32 - half;
            let u = (c[0] + a[0] * ox + a[1] * oy).clamp(0.0, wm);
            let v = (c[1] + a[2] * ox + a[3] * oy).clamp(0.0, hm);
            let (u0, v0) = (u as usize, v as usize);
            let (fu, fv) = (u - u0 as f32, v - v0 as f32);
            let (u1, v1) = ((u0 + 1).min(w - 1), (v0 + 1).min(h - 1));
            let (r0, r1) = (&data[v0 * st..], &data[v1 * st..]);
            let top = (1.0 - fu) * f32::from(r0[u0]) + fu * f32::from(r0[u1]);
            let bottom = (1.0 - fu) * f32::from(r1[u0]) + fu * f32::from(r1[u1]);
            out[i * n + j] = (1.0 - fv) * top + fv * bottom;
        }
    }
}

/// Tracks one point on one level with an affine warp: the template centred at `p` already in
/// `wk` ([`prepare_template`]), initial displacement `g` of the centre and initial part `a`.
/// Returns the refined pair, or `None` if the warp degenerates (its area changes more than 4×),
/// the window leaves the image or the solve does not converge.
///
/// Inverse compositional: with the template's gradients `∇T` and offsets `o`, the
/// steepest-descent images are `∇T·∂W/∂(d, D) = (g_x, g_y, g_x o_x, g_x o_y, g_y o_x, g_y o_y)`
/// for the update warp `W(o; d, D) = (I + D)·o + d`; their Hessian is built and factored once, and
/// each step composes `W ← W ∘ W(Δ)⁻¹`, i.e. `A ← A·(I + D)⁻¹`, `c ← c − A·d`.
#[inline(always)]
fn track_level_affine<const AVX2: bool>(
    next: &Image<u8>,
    p: [f32; 2],
    g: [f32; 2],
    a: Affine,
    params: &LkParams,
    wk: &mut Work,
) -> Option<([f32; 2], Affine)> {
    let r = params.window_radius;
    let n = 2 * r + 1;
    let rf = r as f32;
    // Steepest-descent images, one plane per parameter, and their Hessian: 21 dot products
    // summed in f32 lanes (as `residual_dot`), factored in f64 (the affine columns reach r²
    // times the translation ones).
    let nn = n * n;
    for i in 0..n {
        let oy = i as f32 - rf;
        for j in 0..n {
            let ox = j as f32 - rf;
            let k = i * n + j;
            let (gx, gy) = (wk.gx[k], wk.gy[k]);
            wk.sd[k] = gx;
            wk.sd[nn + k] = gy;
            wk.sd[2 * nn + k] = gx * ox;
            wk.sd[3 * nn + k] = gx * oy;
            wk.sd[4 * nn + k] = gy * ox;
            wk.sd[5 * nn + k] = gy * oy;
        }
    }
    let mut hess = nalgebra::SMatrix::<f64, 6, 6>::zeros();
    for r0 in 0..6 {
        for c0 in r0..6 {
            let v = f64::from(lane_dot(
                &wk.sd[r0 * nn..(r0 + 1) * nn],
                &wk.sd[c0 * nn..(c0 + 1) * nn],
            ));
            hess[(r0, c0)] = v;
            hess[(c0, r0)] = v;
        }
    }
    let chol = hess.cholesky()?;
    let (mut c, mut a) = ([p[0] + g[0], p[1] + g[1]], a);
    for _ in 0..params.max_iterations {
        if !(c[0] > -rf
            && c[1] > -rf
            && c[0] < next.width() as f32 + rf
            && c[1] < next.height() as f32 + rf)
        {
            return None;
        }
        sample_warped(next, c, a, n, &mut wk.cur);
        for (e, t) in wk.cur.iter_mut().zip(&wk.tmpl) {
            *e -= t;
        }
        // A plain loop (a closure would not inline into the AVX2 instance).
        let mut b = [0.0f32; 6];
        for (m, bm) in b.iter_mut().enumerate() {
            *bm = lane_dot(&wk.sd[m * nn..(m + 1) * nn], &wk.cur);
        }
        let delta = chol.solve(&nalgebra::SVector::<f64, 6>::from(b.map(f64::from)));
        let d = [delta[0] as f32, delta[1] as f32];
        let inc = invert([
            1.0 + delta[2] as f32,
            delta[3] as f32,
            delta[4] as f32,
            1.0 + delta[5] as f32,
        ])?;
        a = [
            a[0] * inc[0] + a[1] * inc[2],
            a[0] * inc[1] + a[1] * inc[3],
            a[2] * inc[0] + a[3] * inc[2],
            a[2] * inc[1] + a[3] * inc[3],
        ];
        let step = [a[0] * d[0] + a[1] * d[1], a[2] * d[0] + a[3] * d[1]];
        c = [c[0] - step[0], c[1] - step[1]];
        let det = a[0] * a[3] - a[1] * a[2];
        if !(0.25..=4.0).contains(&det) || !c[0].is_finite() || !c[1].is_finite() {
            return None;
        }
        // Converged when the window's centre and its corners move less than ε.
        let corner =
            rf * (delta[2].abs() + delta[3].abs()).max(delta[4].abs() + delta[5].abs()) as f32;
        if step[0].hypot(step[1]) < params.epsilon && corner < params.epsilon {
            return Some(([c[0] - p[0], c[1] - p[1]], a));
        }
    }
    // Not converged: a warp sliding along a valley of the cost (an edge's aperture, a blurred
    // or self-similar patch), not a measurement of the patch's deformation.
    None
}

/// Tracks `points` (level-0 pixel coordinates in `prev`) into `next`, coarse to fine over
/// `params.levels` levels of the two pyramids (built with [`Pyramid::new`], same depth).
/// `initial` optionally gives predicted positions in `next`. Returns the tracked positions;
/// `None` for points that are untextured or leave the image.
pub fn track(
    prev: &Pyramid,
    next: &Pyramid,
    points: &[[f32; 2]],
    initial: Option<&[[f32; 2]]>,
    params: &LkParams,
) -> Vec<Option<[f32; 2]>> {
    track_warps(prev, next, points, initial, None, params)
        .into_iter()
        .map(|t| t.map(|(q, _)| q))
        .collect()
}

/// [`track`], with each track's final warp part (the [`IDENTITY`] when `params.affine_levels`
/// is 0) and optionally the affine levels' initial parts.
fn track_warps(
    prev: &Pyramid,
    next: &Pyramid,
    points: &[[f32; 2]],
    initial: Option<&[[f32; 2]]>,
    initial_affine: Option<&[Affine]>,
    params: &LkParams,
) -> Vec<Option<([f32; 2], Affine)>> {
    #[cfg(target_arch = "x86_64")]
    {
        if crate::simd::avx2() {
            // SAFETY: the CPU supports AVX2 (checked just above).
            return unsafe { track_avx2(prev, next, points, initial, initial_affine, params) };
        }
    }
    track_impl::<false>(prev, next, points, initial, initial_affine, params)
}

/// [`track_impl`] compiled for AVX2 (runtime dispatch; identical arithmetic, wider vectors).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn track_avx2(
    prev: &Pyramid,
    next: &Pyramid,
    points: &[[f32; 2]],
    initial: Option<&[[f32; 2]]>,
    initial_affine: Option<&[Affine]>,
    params: &LkParams,
) -> Vec<Option<([f32; 2], Affine)>> {
    track_impl::<true>(prev, next, points, initial, initial_affine, params)
}

#[inline(always)]
fn track_impl<const AVX2: bool>(
    prev: &Pyramid,
    next: &Pyramid,
    points: &[[f32; 2]],
    initial: Option<&[[f32; 2]]>,
    initial_affine: Option<&[Affine]>,
    params: &LkParams,
) -> Vec<Option<([f32; 2], Affine)>> {
    let levels = params.levels.min(prev.len()).min(next.len()).max(1);
    let (prev_f, next_f) = (&prev.levels, &next.levels);
    let mut wk = Work::new(2 * params.window_radius + 1);
    let (w0, h0) = (
        next.levels[0].width() as f32,
        next.levels[0].height() as f32,
    );
    // A plain loop (no closures) so that everything inlines into the AVX2 instance.
    let mut out = Vec::with_capacity(points.len());
    'points: for (i, p) in points.iter().enumerate() {
        if !(p[0].is_finite() && p[1].is_finite()) {
            out.push(None);
            continue;
        }
        let pred = match initial {
            Some(v) if i < v.len() => v[i],
            _ => *p,
        };
        let mut a = match initial_affine {
            Some(v) if i < v.len() => v[i],
            _ => IDENTITY,
        };
        let top = levels - 1;
        let s = (1u32 << top) as f32;
        let mut g = [(pred[0] - p[0]) / s, (pred[1] - p[1]) / s];
        for l in (0..levels).rev() {
            let s = (1u32 << l) as f32;
            let pl = [(p[0] + 0.5) / s - 0.5, (p[1] + 0.5) / s - 0.5];
            // An affine level that finds no deformation it can trust tracks the translation
            // (with the part it started from), as the translation-only tracker would, on the
            // template already prepared.
            let tracked = if l < params.affine_levels {
                match prepare_template::<AVX2>(&prev_f[l], pl, params, &mut wk) {
                    Some(tensor) => {
                        match track_level_affine::<AVX2>(&next_f[l], pl, g, a, params, &mut wk) {
                            Some(x) => Some(x),
                            None => solve_translation::<AVX2>(
                                &next_f[l], pl, g, tensor, params, &mut wk,
                            )
                            .map(|g| (g, a)),
                        }
                    }
                    None => None,
                }
            } else {
                track_level::<AVX2>(&prev_f[l], &next_f[l], pl, g, params, &mut wk).map(|g| (g, a))
            };
            match tracked {
                Some(x) => (g, a) = x,
                None => {
                    out.push(None);
                    continue 'points;
                }
            }
            if l > 0 {
                g = [g[0] * 2.0, g[1] * 2.0];
            }
        }
        let q = [p[0] + g[0], p[1] + g[1]];
        if q[0] < 0.0 || q[1] < 0.0 || q[0] > w0 - 1.0 || q[1] > h0 - 1.0 {
            out.push(None);
        } else {
            out.push(Some((q, a)));
        }
    }
    out
}

/// [`track`] followed by tracking the results back from `next` to `prev`, started at the
/// points and, on the affine levels, at the inverse of the forward warp; a track is kept only if
/// the backward track returns within `max_fb_error` pixels of its start.
pub fn track_forward_backward(
    prev: &Pyramid,
    next: &Pyramid,
    points: &[[f32; 2]],
    params: &LkParams,
    max_fb_error: f32,
) -> Vec<Option<[f32; 2]>> {
    track_forward_backward_warps(prev, next, points, None, params, max_fb_error)
        .into_iter()
        .map(|t| t.map(|(q, _)| q))
        .collect()
}

/// [`track_forward_backward`] with the affine levels started from `initial_affine` (per point;
/// the [`IDENTITY`] where not given — a track's warp in the previous frame predicts the next
/// one's, and a warm start saves most of the affine iterations), returning each kept track's
/// final warp part with its position.
pub fn track_forward_backward_warps(
    prev: &Pyramid,
    next: &Pyramid,
    points: &[[f32; 2]],
    initial_affine: Option<&[Affine]>,
    params: &LkParams,
    max_fb_error: f32,
) -> Vec<Option<([f32; 2], Affine)>> {
    let fwd = track_warps(prev, next, points, None, initial_affine, params);
    let (valid, inverse): (Vec<[f32; 2]>, Vec<Affine>) = fwd
        .iter()
        .map(|t| match t {
            Some((q, a)) => (*q, invert(*a).unwrap_or(IDENTITY)),
            None => ([f32::NAN, f32::NAN], IDENTITY),
        })
        .unzip();
    let back = track_warps(next, prev, &valid, Some(points), Some(&inverse), params);
    fwd.into_iter()
        .zip(back)
        .zip(points)
        .map(|((f, b), p)| match (f, b) {
            (Some(f), Some((b, _))) if (b[0] - p[0]).hypot(b[1] - p[1]) <= max_fb_error => Some(f),
            _ => None,
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::image::GrayImage;

    /// A smooth textured test image, shifted by `(dx, dy)`.
    fn texture(w: usize, h: usize, dx: f32, dy: f32) -> GrayImage {
        GrayImage::from_fn(w, h, |u, v| {
            let x = u as f32 - dx;
            let y = v as f32 - dy;
            let val = 128.0
                + 60.0 * (x * 0.21).sin() * (y * 0.17).cos()
                + 40.0 * ((x + 2.0 * y) * 0.07).sin();
            val.clamp(0.0, 255.0) as u8
        })
    }

    #[test]
    fn recovers_a_known_translation() {
        let a = texture(160, 120, 0.0, 0.0);
        let b = texture(160, 120, 3.4, -2.2);
        let pa = Pyramid::new(&a, 4, 8).unwrap();
        let pb = Pyramid::new(&b, 4, 8).unwrap();
        let pts = [[60.0, 50.0], [100.0, 70.0], [80.0, 40.0]];
        let params = LkParams {
            levels: 3,
            ..Default::default()
        };
        let out = track_forward_backward(&pa, &pb, &pts, &params, 0.5);
        for (p, q) in pts.iter().zip(&out) {
            let q = q.expect("tracked");
            assert!(
                (q[0] - p[0] - 3.4).abs() < 0.15 && (q[1] - p[1] + 2.2).abs() < 0.15,
                "{p:?} -> {q:?}"
            );
        }
    }

    /// A smooth texture seen by a camera that moved towards it: `b(x) = a(c + (x − c)/zoom)`,
    /// so that `a`'s point `p` is at `c + zoom·(p − c)` in `b`.
    fn zoomed(w: usize, h: usize, zoom: f32, c: [f32; 2]) -> (GrayImage, GrayImage) {
        let f = |x: f32, y: f32| {
            let val = 128.0
                + 50.0 * (x * 0.23).sin() * (y * 0.19).cos()
                + 35.0 * ((x - 1.7 * y) * 0.09).sin()
                + 25.0 * ((0.6 * x + y) * 0.31).cos();
            val.clamp(0.0, 255.0) as u8
        };
        let a = GrayImage::from_fn(w, h, |u, v| f(u as f32, v as f32));
        let b = GrayImage::from_fn(w, h, |u, v| {
            f(
                c[0] + (u as f32 - c[0]) / zoom,
                c[1] + (v as f32 - c[1]) / zoom,
            )
        });
        (a, b)
    }

    /// On a patch that grows by 8 % between the frames, a translation-only window lags the
    /// flow (it is pulled towards the texture it still sees); the affine finest level follows
    /// the growth and finds the point.
    #[test]
    fn the_affine_level_follows_a_growing_patch_that_translation_lags() {
        let (c, zoom) = ([120.0, 90.0], 1.08);
        let (a, b) = zoomed(240, 180, zoom, c);
        let pa = Pyramid::new(&a, 3, 8).unwrap();
        let pb = Pyramid::new(&b, 3, 8).unwrap();
        let pts: Vec<[f32; 2]> = [[60.0, 50.0], [180.0, 60.0], [70.0, 130.0], [175.0, 125.0]]
            .into_iter()
            .collect();
        let truth: Vec<[f32; 2]> = pts
            .iter()
            .map(|p| [c[0] + zoom * (p[0] - c[0]), c[1] + zoom * (p[1] - c[1])])
            .collect();
        let worst = |affine_levels: usize| {
            let params = LkParams {
                levels: 3,
                affine_levels,
                ..Default::default()
            };
            track(&pa, &pb, &pts, None, &params)
                .iter()
                .zip(&truth)
                .map(|(q, t)| {
                    let q = q.expect("tracked");
                    (q[0] - t[0]).hypot(q[1] - t[1])
                })
                .fold(0.0f32, f32::max)
        };
        let (translation, affine) = (worst(0), worst(1));
        assert!(affine < 0.05, "affine error {affine} px");
        assert!(
            translation > 4.0 * affine,
            "translation {translation} vs affine {affine} px"
        );
        // The forward-backward check keeps the affine tracks (their backward pass starts at the
        // inverse warp) within a tight gate.
        let params = LkParams {
            levels: 3,
            affine_levels: 1,
            ..Default::default()
        };
        let kept = track_forward_backward(&pa, &pb, &pts, &params, 0.1);
        assert!(kept.iter().all(Option::is_some), "{kept:?}");
    }

    #[test]
    fn simd_and_scalar_paths_agree_bit_for_bit() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand::rngs::StdRng::seed_from_u64(11);
        // Random texture (noise, half-sampled once for some smoothness) and a shifted copy;
        // points everywhere, including at and beyond the border (clamped block path).
        for (w, h) in [(97, 61), (160, 45)] {
            let noise = GrayImage::from_fn(2 * w, 2 * h, |_, _| rng.random());
            let a = crate::pyramid::half_sample(&noise).unwrap();
            let b = GrayImage::from_fn(w, h, |u, v| a.get((u + 1).min(w - 1), v.saturating_sub(2)));
            let pa = Pyramid::new(&a, 3, 8).unwrap();
            let pb = Pyramid::new(&b, 3, 8).unwrap();
            let pts: Vec<[f32; 2]> = (0..200)
                .map(|_| {
                    [
                        rng.random_range(-3.0..w as f32 + 3.0),
                        rng.random_range(-3.0..h as f32 + 3.0),
                    ]
                })
                .collect();
            let params = LkParams {
                levels: 3,
                ..Default::default()
            };
            let fast = track(&pa, &pb, &pts, None, &params);
            let scalar = crate::simd::scalar_only(|| track(&pa, &pb, &pts, None, &params));
            assert_eq!(fast, scalar);
            let affine = LkParams {
                affine_levels: 2,
                ..params
            };
            let fast_affine = track_forward_backward(&pa, &pb, &pts, &affine, 1.0);
            let scalar_affine =
                crate::simd::scalar_only(|| track_forward_backward(&pa, &pb, &pts, &affine, 1.0));
            assert_eq!(fast_affine, scalar_affine);
            assert!(
                fast.iter().filter(|t| t.is_some()).count() > 50,
                "tracks something"
            );
        }
    }

    #[test]
    fn flat_regions_and_bad_points_are_rejected() {
        let flat = GrayImage::filled(64, 64, 90);
        let p = Pyramid::new(&flat, 3, 8).unwrap();
        let out = track(
            &p,
            &p,
            &[[30.0, 30.0], [f32::NAN, 1.0]],
            None,
            &LkParams::default(),
        );
        assert_eq!(out, vec![None, None]);
        let tiny = Pyramid::new(&GrayImage::filled(1, 1, 3), 3, 1).unwrap();
        assert_eq!(
            track(&tiny, &tiny, &[[0.0, 0.0]], None, &LkParams::default()),
            vec![None]
        );
    }
}
