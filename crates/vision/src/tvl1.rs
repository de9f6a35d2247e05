//! Dense optical flow by TV-L1 (Zach, Pock & Bischof 2007) solved with the first-order
//! primal-dual algorithm of Chambolle & Pock (2011), coarse-to-fine with warping (thesis §3.4.2
//! motivates dense flow as the prior for guided search).
//!
//! Energy per flow component pair `u = (u₁, u₂)`:
//! `E(u) = Σ_x ‖∇u₁‖ + ‖∇u₂‖ + λ |ρ(u)|`, with the linearised data term around `u₀`
//! `ρ(u) = I₁(x + u₀) + ∇I₁(x + u₀)·(u − u₀) − I₀(x)`.
//!
//! Iteration (step sizes `τ σ ‖∇‖² ≤ 1`, `‖∇‖² ≤ 8`, `τ = σ = 1/√8`):
//! 1. `p ← Π_{‖·‖≤1}(p + σ∇ū)` (per component, isotropic),
//! 2. `ũ = u + τ div p`, `u ← prox_{τλ|ρ|}(ũ)`: with `g = ∇I₁`,
//!    `u = ũ + τλg` if `ρ(ũ) < −τλ‖g‖²`, `ũ − τλg` if `ρ(ũ) > τλ‖g‖²`, else `ũ − ρ(ũ) g/‖g‖²`,
//! 3. `ū = 2u − u_old`.

use crate::image::{GrayImage, Image, ImageError};
use crate::interp::bilinear_with_gradient;

/// Parameters of [`tvl1_flow`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Tvl1Params {
    /// Data term weight `λ` (intensities in 0–255; OpenCV's DualTVL1 default 0.15).
    pub lambda: f32,
    /// Number of pyramid levels (half-sampling; stops at 16 px).
    pub levels: usize,
    /// Re-linearisations (warps) per level.
    pub warps: usize,
    /// Primal-dual iterations per warp.
    pub iterations: usize,
    /// Apply a 3×3 median filter to the flow after each warp (Wedel et al. 2009).
    pub median_filter: bool,
}

impl Default for Tvl1Params {
    /// λ = 0.15, 5 levels, 5 warps, 50 iterations, median filtering on.
    fn default() -> Self {
        Self {
            lambda: 0.15,
            levels: 5,
            warps: 5,
            iterations: 50,
            median_filter: true,
        }
    }
}

/// A dense flow field: pixel `(u, v)` of the first image moves to `(u + du, v + dv)`.
#[derive(Debug, Clone)]
pub struct Flow {
    /// Horizontal component.
    pub du: Image<f32>,
    /// Vertical component.
    pub dv: Image<f32>,
}

fn half_f32(img: &Image<f32>) -> Image<f32> {
    let (w, h) = (img.width() / 2, img.height() / 2);
    Image::from_fn(w, h, |u, v| {
        0.25 * (img.get(2 * u, 2 * v)
            + img.get(2 * u + 1, 2 * v)
            + img.get(2 * u, 2 * v + 1)
            + img.get(2 * u + 1, 2 * v + 1))
    })
}

fn upsample_flow(f: &Image<f32>, w: usize, h: usize) -> Image<f32> {
    // Nearest-cell upsampling of the half-resolution field, values doubled.
    Image::from_fn(w, h, |u, v| {
        2.0 * f.get((u / 2).min(f.width() - 1), (v / 2).min(f.height() - 1))
    })
}

fn median3(img: &Image<f32>) -> Image<f32> {
    let (w, h) = (img.width() as i64, img.height() as i64);
    Image::from_fn(img.width(), img.height(), |u, v| {
        let mut a = [0.0f32; 9];
        let mut k = 0;
        for dv in -1..=1i64 {
            for du in -1..=1i64 {
                a[k] = img.get(
                    (u as i64 + du).clamp(0, w - 1) as usize,
                    (v as i64 + dv).clamp(0, h - 1) as usize,
                );
                k += 1;
            }
        }
        a.sort_by(|x, y| x.total_cmp(y));
        a[4]
    })
}

/// Computes the TV-L1 flow from `i0` to `i1` (same size, at least 2×2).
pub fn tvl1_flow(i0: &GrayImage, i1: &GrayImage, params: &Tvl1Params) -> Result<Flow, ImageError> {
    if i0.width() != i1.width() || i0.height() != i1.height() {
        return Err(ImageError::SizeMismatch(
            i0.width(),
            i0.height(),
            i1.width(),
            i1.height(),
        ));
    }
    if i0.width() < 2 || i0.height() < 2 {
        return Err(ImageError::TooSmall {
            width: i0.width(),
            height: i0.height(),
            what: "TV-L1 flow needs at least 2×2 pixels".into(),
        });
    }
    let mut p0 = vec![i0.to_f32()];
    let mut p1 = vec![i1.to_f32()];
    while p0.len() < params.levels.max(1) {
        let last = p0.last().expect("non-empty");
        if last.width() / 2 < 16 || last.height() / 2 < 16 {
            break;
        }
        let n0 = half_f32(last);
        let n1 = half_f32(p1.last().expect("non-empty"));
        p0.push(n0);
        p1.push(n1);
    }
    let coarsest = p0.len() - 1;
    let mut du = Image::<f32>::new(p0[coarsest].width(), p0[coarsest].height());
    let mut dv = du.clone();
    for l in (0..=coarsest).rev() {
        let (a, b) = (&p0[l], &p1[l]);
        let (w, h) = (a.width(), a.height());
        if l != coarsest {
            du = upsample_flow(&du, w, h);
            dv = upsample_flow(&dv, w, h);
        }
        #[cfg(target_arch = "x86_64")]
        if crate::simd::avx2() {
            // SAFETY: the CPU supports AVX2 (checked just above).
            unsafe { solve_level_avx2(a, b, &mut du, &mut dv, params) };
            continue;
        }
        solve_level(a, b, &mut du, &mut dv, params);
    }
    Ok(Flow { du, dv })
}

/// [`solve_level`] compiled for AVX2 (eight lanes for the row loops; no FMA, so the values are
/// the scalar build's bit for bit).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn solve_level_avx2(
    i0: &Image<f32>,
    i1: &Image<f32>,
    du: &mut Image<f32>,
    dv: &mut Image<f32>,
    params: &Tvl1Params,
) {
    solve_level(i0, i1, du, dv, params)
}

#[inline(always)]
fn solve_level(
    i0: &Image<f32>,
    i1: &Image<f32>,
    du: &mut Image<f32>,
    dv: &mut Image<f32>,
    params: &Tvl1Params,
) {
    let (w, h) = (i0.width(), i0.height());
    let n = w * h;
    let tau = 1.0 / 8f32.sqrt();
    let sigma = 1.0 / 8f32.sqrt();
    let tl = tau * params.lambda;
    // Dual variables: p1 = (p1x, p1y) for du, p2 for dv.
    let mut p1x = vec![0.0f32; n];
    let mut p1y = vec![0.0f32; n];
    let mut p2x = vec![0.0f32; n];
    let mut p2y = vec![0.0f32; n];
    let mut gx = vec![0.0f32; n];
    let mut gy = vec![0.0f32; n];
    let mut g2 = vec![0.0f32; n];
    let mut rho0 = vec![0.0f32; n];
    for _ in 0..params.warps {
        // Linearise the data term at the current flow.
        for v in 0..h {
            for u in 0..w {
                let i = v * w + u;
                let (fu, fv) = (du.data()[i], dv.data()[i]);
                let x = u as f32 + fu;
                let y = v as f32 + fv;
                match bilinear_with_gradient(i1, x, y) {
                    Some((val, ix, iy)) => {
                        gx[i] = ix;
                        gy[i] = iy;
                        g2[i] = ix * ix + iy * iy;
                        rho0[i] = val - ix * fu - iy * fv - i0.data()[i];
                    }
                    None => {
                        gx[i] = 0.0;
                        gy[i] = 0.0;
                        g2[i] = 0.0;
                        rho0[i] = 0.0;
                    }
                }
            }
        }
        let mut u1 = du.data().to_vec();
        let mut u2 = dv.data().to_vec();
        let mut b1 = u1.clone();
        let mut b2 = u2.clone();
        for _ in 0..params.iterations {
            // Dual ascent with forward differences (zero at the far border), row by row so
            // that the loops vectorise; per pixel the same arithmetic as written in the docs.
            for v in 0..h {
                let r = v * w..(v + 1) * w;
                let down = (v + 1 < h).then(|| (v + 1) * w..(v + 2) * w);
                dual_row(
                    &b1,
                    r.clone(),
                    down.clone(),
                    &mut p1x[r.clone()],
                    &mut p1y[r.clone()],
                    sigma,
                );
                dual_row(
                    &b2,
                    r.clone(),
                    down,
                    &mut p2x[r.clone()],
                    &mut p2y[r],
                    sigma,
                );
            }
            // Primal descent with the divergence (negative adjoint of the forward gradient).
            let k = Primal { tau, tl };
            for v in 0..h {
                let i0 = v * w;
                let pixel = |u: usize, st: &mut PrimalState| {
                    let i = i0 + u;
                    let div = |px: &[f32], py: &[f32]| -> f32 {
                        let dx = if u + 1 < w { px[i] } else { 0.0 }
                            - if u > 0 { px[i - 1] } else { 0.0 };
                        let dy = if v + 1 < h { py[i] } else { 0.0 }
                            - if v > 0 { py[i - w] } else { 0.0 };
                        dx + dy
                    };
                    let (d1, d2) = (div(&p1x, &p1y), div(&p2x, &p2y));
                    k.update(i, d1, d2, st);
                };
                let mut st = PrimalState {
                    u1: &mut u1,
                    u2: &mut u2,
                    b1: &mut b1,
                    b2: &mut b2,
                    gx: &gx,
                    gy: &gy,
                    g2: &g2,
                    rho0: &rho0,
                };
                pixel(0, &mut st);
                if w > 2 && v > 0 && v + 1 < h {
                    // Interior: all four neighbours of the divergence exist; equal-length
                    // slices so that the loop has no bounds checks and vectorises.
                    let (a, n) = (i0 + 1, w - 2);
                    let (p1xc, p1xl, p1yc, p1yu) = (
                        &p1x[a..a + n],
                        &p1x[a - 1..a - 1 + n],
                        &p1y[a..a + n],
                        &p1y[a - w..a - w + n],
                    );
                    let (p2xc, p2xl, p2yc, p2yu) = (
                        &p2x[a..a + n],
                        &p2x[a - 1..a - 1 + n],
                        &p2y[a..a + n],
                        &p2y[a - w..a - w + n],
                    );
                    let mut row = PrimalState {
                        u1: &mut st.u1[a..a + n],
                        u2: &mut st.u2[a..a + n],
                        b1: &mut st.b1[a..a + n],
                        b2: &mut st.b2[a..a + n],
                        gx: &st.gx[a..a + n],
                        gy: &st.gy[a..a + n],
                        g2: &st.g2[a..a + n],
                        rho0: &st.rho0[a..a + n],
                    };
                    for j in 0..n {
                        let d1 = (p1xc[j] - p1xl[j]) + (p1yc[j] - p1yu[j]);
                        let d2 = (p2xc[j] - p2xl[j]) + (p2yc[j] - p2yu[j]);
                        k.update(j, d1, d2, &mut row);
                    }
                } else {
                    for u in 1..w.saturating_sub(1) {
                        pixel(u, &mut st);
                    }
                }
                if w > 1 {
                    pixel(w - 1, &mut st);
                }
            }
        }
        *du = Image::from_vec(w, h, w, u1).expect("sizes match");
        *dv = Image::from_vec(w, h, w, u2).expect("sizes match");
        if params.median_filter {
            *du = median3(du);
            *dv = median3(dv);
        }
    }
}

/// One row of the dual ascent for one flow component: `p ← Π(p + σ∇b)` with forward
/// differences of `b` (`b[r]` this row, `b[down]` the next one, zero past the last column/row).
#[inline(always)]
fn dual_row(
    b: &[f32],
    r: std::ops::Range<usize>,
    down: Option<std::ops::Range<usize>>,
    px: &mut [f32],
    py: &mut [f32],
    sigma: f32,
) {
    let row = &b[r];
    let w = row.len();
    let step = |dx: f32, dy: f32, px: &mut f32, py: &mut f32| {
        let (ax, ay) = (*px + sigma * dx, *py + sigma * dy);
        let s = (ax * ax + ay * ay).sqrt().max(1.0);
        *px = ax / s;
        *py = ay / s;
    };
    match down {
        Some(d) => {
            let next = &b[d];
            for u in 0..w - 1 {
                step(
                    row[u + 1] - row[u],
                    next[u] - row[u],
                    &mut px[u],
                    &mut py[u],
                );
            }
            step(
                0.0,
                next[w - 1] - row[w - 1],
                &mut px[w - 1],
                &mut py[w - 1],
            );
        }
        None => {
            for u in 0..w - 1 {
                step(row[u + 1] - row[u], 0.0, &mut px[u], &mut py[u]);
            }
            step(0.0, 0.0, &mut px[w - 1], &mut py[w - 1]);
        }
    }
}

/// The primal step's constants: `τ` and `τλ`.
#[derive(Clone, Copy)]
struct Primal {
    tau: f32,
    tl: f32,
}

/// The primal variables and the linearised data term of one warp.
struct PrimalState<'a> {
    u1: &'a mut [f32],
    u2: &'a mut [f32],
    b1: &'a mut [f32],
    b2: &'a mut [f32],
    gx: &'a [f32],
    gy: &'a [f32],
    g2: &'a [f32],
    rho0: &'a [f32],
}

impl Primal {
    /// `ũ = u + τ div p`, `u ← prox_{τλ|ρ|}(ũ)`, `ū = 2u − u_old` at pixel `i` (module docs),
    /// given the two divergences.
    #[inline(always)]
    fn update(self, i: usize, d1: f32, d2: f32, st: &mut PrimalState) {
        let (tau, tl) = (self.tau, self.tl);
        let t1 = st.u1[i] + tau * d1;
        let t2 = st.u2[i] + tau * d2;
        let (gx, gy, g2) = (st.gx[i], st.gy[i], st.g2[i]);
        let rho = st.rho0[i] + gx * t1 + gy * t2;
        let th = tl * g2;
        // All candidates first, then selects (branch-free, so the loop vectorises; the
        // division of an unused candidate by g2 = 0 is harmless).
        let (lo1, lo2) = (t1 + tl * gx, t2 + tl * gy);
        let (hi1, hi2) = (t1 - tl * gx, t2 - tl * gy);
        let (mid1, mid2) = (t1 - rho * gx / g2, t2 - rho * gy / g2);
        let (c_lo, c_hi, c_mid) = (rho < -th, rho > th, g2 > 1e-9);
        let pick = |lo: f32, hi: f32, mid: f32, t: f32| {
            let m = if c_mid { mid } else { t };
            let h = if c_hi { hi } else { m };
            if c_lo { lo } else { h }
        };
        let (n1, n2) = (pick(lo1, hi1, mid1, t1), pick(lo2, hi2, mid2, t2));
        st.b1[i] = 2.0 * n1 - st.u1[i];
        st.b2[i] = 2.0 * n2 - st.u2[i];
        st.u1[i] = n1;
        st.u2[i] = n2;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn texture(w: usize, h: usize, dx: f32, dy: f32) -> GrayImage {
        GrayImage::from_fn(w, h, |u, v| {
            let x = u as f32 - dx;
            let y = v as f32 - dy;
            (128.0
                + 60.0 * (x * 0.3).sin() * (y * 0.23).cos()
                + 40.0 * ((x + 2.0 * y) * 0.11).sin())
            .clamp(0.0, 255.0) as u8
        })
    }

    #[test]
    fn recovers_a_translation() {
        let a = texture(96, 80, 0.0, 0.0);
        let b = texture(96, 80, 2.5, -1.5);
        let f = tvl1_flow(
            &a,
            &b,
            &Tvl1Params {
                iterations: 30,
                ..Default::default()
            },
        )
        .unwrap();
        let mut errs = Vec::new();
        for v in 10..70 {
            for u in 10..86 {
                errs.push(((f.du.get(u, v) - 2.5).powi(2) + (f.dv.get(u, v) + 1.5).powi(2)).sqrt());
            }
        }
        errs.sort_by(|a, b| a.total_cmp(b));
        let median = errs[errs.len() / 2];
        assert!(median < 0.1, "median endpoint error {median}");
    }

    #[test]
    fn simd_and_scalar_builds_agree_bit_for_bit() {
        let a = texture(70, 45, 0.0, 0.0);
        let b = texture(70, 45, 1.3, -0.7);
        let params = Tvl1Params {
            levels: 3,
            warps: 2,
            iterations: 10,
            ..Default::default()
        };
        let fast = tvl1_flow(&a, &b, &params).unwrap();
        let scalar = crate::simd::scalar_only(|| tvl1_flow(&a, &b, &params)).unwrap();
        let bits = |i: &Image<f32>| i.data().iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        assert_eq!(bits(&fast.du), bits(&scalar.du));
        assert_eq!(bits(&fast.dv), bits(&scalar.dv));
    }

    #[test]
    fn bad_inputs() {
        let a = GrayImage::new(1, 1);
        assert!(tvl1_flow(&a, &a, &Tvl1Params::default()).is_err());
        assert!(
            tvl1_flow(
                &GrayImage::new(4, 4),
                &GrayImage::new(5, 4),
                &Tvl1Params::default()
            )
            .is_err()
        );
        let odd = texture(17, 9, 0.0, 0.0);
        let f = tvl1_flow(&odd, &odd, &Tvl1Params::default()).unwrap();
        assert_eq!((f.du.width(), f.du.height()), (17, 9));
        assert!(f.du.data().iter().all(|x| x.abs() < 1e-3));
    }
}
