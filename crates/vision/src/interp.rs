//! Bilinear sampling with gradients.

use crate::image::Image;

/// A pixel type that can be read as `f32` intensity.
pub trait Pixel: Copy + Default + Send + Sync {
    /// The intensity as `f32`.
    fn to_f32(self) -> f32;
}
impl Pixel for u8 {
    #[inline]
    fn to_f32(self) -> f32 {
        self as f32
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
