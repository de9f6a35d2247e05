//! Pyramidal Lucas-Kanade sparse tracking, inverse compositional (Baker & Matthews 2004), with a
//! forward-backward check (thesis §3.4.2, §6.3).
//!
//! For a template window `T` around `p` in the previous image and the translation warp
//! `W(x; g) = x + g`, the inverse compositional algorithm minimises
//! `Σ_x [I(W(x; g)) − T(W(x; Δ))]²` over `Δ` and updates `g ← g − Δ`, with
//! `Δ = H⁻¹ Σ_x ∇Tᵀ (I(x + g) − T(x))`, `H = Σ_x ∇Tᵀ∇T` computed once per level.
//! Coarse-to-fine: the displacement found on level `l + 1` (doubled) initialises level `l`.

use crate::image::Image;
use crate::interp::Pixel;
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
        }
    }
}

/// Samples the `n×n` patch whose top-left sample is at real coordinates `(x, y)` with bilinear
/// interpolation (the weights are the same for all samples); coordinates are clamped to the
/// image (border replication). Writes `n·n` values into `out`.
#[inline(always)]
fn sample_patch<T: Pixel>(img: &Image<T>, x: f32, y: f32, n: usize, out: &mut [f32]) {
    let xf = x.floor();
    let yf = y.floor();
    let a = x - xf;
    let b = y - yf;
    let (w00, w10, w01, w11) = ((1.0 - a) * (1.0 - b), a * (1.0 - b), (1.0 - a) * b, a * b);
    let (x0, y0) = (xf as i64, yf as i64);
    let (w, h) = (img.width() as i64, img.height() as i64);
    if x0 >= 0 && y0 >= 0 && x0 + (n as i64) < w && y0 + (n as i64) < h {
        let x0 = x0 as usize;
        for r in 0..n {
            let ra = &img.row(y0 as usize + r)[x0..x0 + n + 1];
            let rb = &img.row(y0 as usize + r + 1)[x0..x0 + n + 1];
            let o = &mut out[r * n..(r + 1) * n];
            for i in 0..n {
                o[i] = w00 * ra[i].to_f32()
                    + w10 * ra[i + 1].to_f32()
                    + w01 * rb[i].to_f32()
                    + w11 * rb[i + 1].to_f32();
            }
        }
    } else {
        // Border: clamp the column indices once, then gather row by row.
        let mut small = [0usize; 64];
        let mut large = Vec::new();
        let cols: &mut [usize] = if n < 64 {
            &mut small[..n + 1]
        } else {
            large.resize(n + 1, 0);
            &mut large
        };
        for (i, c) in cols.iter_mut().enumerate() {
            *c = (x0 + i as i64).clamp(0, w - 1) as usize;
        }
        for r in 0..n {
            let ra = img.row((y0 + r as i64).clamp(0, h - 1) as usize);
            let rb = img.row((y0 + r as i64 + 1).clamp(0, h - 1) as usize);
            let o = &mut out[r * n..(r + 1) * n];
            for i in 0..n {
                let (c0, c1) = (cols[i], cols[i + 1]);
                o[i] = w00 * ra[c0].to_f32()
                    + w10 * ra[c1].to_f32()
                    + w01 * rb[c0].to_f32()
                    + w11 * rb[c1].to_f32();
            }
        }
    }
}

/// Scratch buffers for one point.
struct Work {
    big: Vec<f32>,
    tmpl: Vec<f32>,
    gx: Vec<f32>,
    gy: Vec<f32>,
    cur: Vec<f32>,
}

impl Work {
    fn new(n: usize) -> Self {
        Self {
            big: vec![0.0; (n + 2) * (n + 2)],
            tmpl: vec![0.0; n * n],
            gx: vec![0.0; n * n],
            gy: vec![0.0; n * n],
            cur: vec![0.0; n * n],
        }
    }
}

/// Tracks one point on one level: template centred at `p` in `prev`, initial displacement `g`.
/// Returns the refined displacement or `None` if the window is untextured.
#[inline(always)]
fn track_level<T: Pixel>(
    prev: &Image<T>,
    next: &Image<T>,
    p: [f32; 2],
    g: [f32; 2],
    params: &LkParams,
    wk: &mut Work,
) -> Option<[f32; 2]> {
    let r = params.window_radius;
    let n = 2 * r + 1;
    let nb = n + 2;
    let rf = r as f32;
    sample_patch(prev, p[0] - rf - 1.0, p[1] - rf - 1.0, nb, &mut wk.big);
    let (mut hxx, mut hxy, mut hyy) = (0.0f32, 0.0f32, 0.0f32);
    for y in 0..n {
        for x in 0..n {
            let c = (y + 1) * nb + x + 1;
            let gx = 0.5 * (wk.big[c + 1] - wk.big[c - 1]);
            let gy = 0.5 * (wk.big[c + nb] - wk.big[c - nb]);
            let i = y * n + x;
            wk.tmpl[i] = wk.big[c];
            wk.gx[i] = gx;
            wk.gy[i] = gy;
            hxx += gx * gx;
            hxy += gx * gy;
            hyy += gy * gy;
        }
    }
    let npx = (n * n) as f32;
    let min_eig = 0.5 * (hxx + hyy - ((hxx - hyy) * (hxx - hyy) + 4.0 * hxy * hxy).sqrt()) / npx;
    let det = hxx * hyy - hxy * hxy;
    if min_eig < params.min_eigenvalue || det <= f32::EPSILON {
        return None;
    }
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
        sample_patch(next, qx - rf, qy - rf, n, &mut wk.cur);
        // Lane-wise accumulators so that the reduction vectorises.
        const L: usize = 8;
        let mut ax = [0.0f32; L];
        let mut ay = [0.0f32; L];
        let full = wk.cur.len() / L * L;
        for (((c, t), gx), gy) in wk.cur[..full]
            .chunks_exact(L)
            .zip(wk.tmpl[..full].chunks_exact(L))
            .zip(wk.gx[..full].chunks_exact(L))
            .zip(wk.gy[..full].chunks_exact(L))
        {
            for i in 0..L {
                let e = c[i] - t[i];
                ax[i] += gx[i] * e;
                ay[i] += gy[i] * e;
            }
        }
        let (mut bx, mut by) = (ax.iter().sum::<f32>(), ay.iter().sum::<f32>());
        for i in full..wk.cur.len() {
            let e = wk.cur[i] - wk.tmpl[i];
            bx += wk.gx[i] * e;
            by += wk.gy[i] * e;
        }
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
    #[cfg(target_arch = "x86_64")]
    {
        if crate::simd::avx2() {
            // SAFETY: the CPU supports AVX2 (checked just above).
            return unsafe { track_avx2(prev, next, points, initial, params) };
        }
    }
    track_impl(prev, next, points, initial, params)
}

/// [`track_impl`] compiled for AVX2 (runtime dispatch; identical arithmetic, wider vectors).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn track_avx2(
    prev: &Pyramid,
    next: &Pyramid,
    points: &[[f32; 2]],
    initial: Option<&[[f32; 2]]>,
    params: &LkParams,
) -> Vec<Option<[f32; 2]>> {
    track_impl(prev, next, points, initial, params)
}

#[inline(always)]
fn track_impl(
    prev: &Pyramid,
    next: &Pyramid,
    points: &[[f32; 2]],
    initial: Option<&[[f32; 2]]>,
    params: &LkParams,
) -> Vec<Option<[f32; 2]>> {
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
        let top = levels - 1;
        let s = (1u32 << top) as f32;
        let mut g = [(pred[0] - p[0]) / s, (pred[1] - p[1]) / s];
        for l in (0..levels).rev() {
            let s = (1u32 << l) as f32;
            let pl = [(p[0] + 0.5) / s - 0.5, (p[1] + 0.5) / s - 0.5];
            match track_level(&prev_f[l], &next_f[l], pl, g, params, &mut wk) {
                Some(x) => g = x,
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
            out.push(Some(q));
        }
    }
    out
}

/// [`track`] followed by tracking the results back from `next` to `prev`; a track is kept only
/// if the backward track returns within `max_fb_error` pixels of its start.
pub fn track_forward_backward(
    prev: &Pyramid,
    next: &Pyramid,
    points: &[[f32; 2]],
    params: &LkParams,
    max_fb_error: f32,
) -> Vec<Option<[f32; 2]>> {
    let fwd = track(prev, next, points, None, params);
    let valid: Vec<[f32; 2]> = fwd
        .iter()
        .map(|q| q.unwrap_or([f32::NAN, f32::NAN]))
        .collect();
    let back = track(next, prev, &valid, Some(points), params);
    fwd.into_iter()
        .zip(back)
        .zip(points)
        .map(|((f, b), p)| match (f, b) {
            (Some(f), Some(b)) if (b[0] - p[0]).hypot(b[1] - p[1]) <= max_fb_error => Some(f),
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
