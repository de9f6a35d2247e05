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
