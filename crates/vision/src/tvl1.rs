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
        solve_level(a, b, &mut du, &mut dv, params);
    }
    Ok(Flow { du, dv })
}

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
            // Dual ascent with forward differences (zero at the far border).
            for v in 0..h {
                for u in 0..w {
                    let i = v * w + u;
                    let (d1x, d2x) = if u + 1 < w {
                        (b1[i + 1] - b1[i], b2[i + 1] - b2[i])
                    } else {
                        (0.0, 0.0)
                    };
                    let (d1y, d2y) = if v + 1 < h {
                        (b1[i + w] - b1[i], b2[i + w] - b2[i])
                    } else {
                        (0.0, 0.0)
                    };
                    let (ax, ay) = (p1x[i] + sigma * d1x, p1y[i] + sigma * d1y);
                    let s = (ax * ax + ay * ay).sqrt().max(1.0);
                    p1x[i] = ax / s;
                    p1y[i] = ay / s;
                    let (cx, cy) = (p2x[i] + sigma * d2x, p2y[i] + sigma * d2y);
                    let s = (cx * cx + cy * cy).sqrt().max(1.0);
                    p2x[i] = cx / s;
                    p2y[i] = cy / s;
                }
            }
            // Primal descent with the divergence (negative adjoint of the forward gradient).
            for v in 0..h {
                for u in 0..w {
                    let i = v * w + u;
                    let div = |px: &[f32], py: &[f32]| -> f32 {
                        let dx = if u + 1 < w { px[i] } else { 0.0 }
                            - if u > 0 { px[i - 1] } else { 0.0 };
                        let dy = if v + 1 < h { py[i] } else { 0.0 }
                            - if v > 0 { py[i - w] } else { 0.0 };
                        dx + dy
                    };
                    let t1 = u1[i] + tau * div(&p1x, &p1y);
                    let t2 = u2[i] + tau * div(&p2x, &p2y);
                    let rho = rho0[i] + gx[i] * t1 + gy[i] * t2;
                    let th = tl * g2[i];
                    let (n1, n2) = if rho < -th {
                        (t1 + tl * gx[i], t2 + tl * gy[i])
                    } else if rho > th {
                        (t1 - tl * gx[i], t2 - tl * gy[i])
                    } else if g2[i] > 1e-9 {
                        (t1 - rho * gx[i] / g2[i], t2 - rho * gy[i] / g2[i])
                    } else {
                        (t1, t2)
                    };
                    b1[i] = 2.0 * n1 - u1[i];
                    b2[i] = 2.0 * n2 - u2[i];
                    u1[i] = n1;
                    u2[i] = n2;
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
