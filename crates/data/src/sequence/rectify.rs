//! Undistortion and stereo rectification as remap tables computed once per sequence.
//!
//! Stereo rectification (Bouguet's construction, as OpenCV's `stereoRectify`): from the
//! extrinsics `x_r = R·x_l + t`, both cameras are rotated so that the baseline becomes the common
//! `x` axis (`vision::undistort::rectify_stereo`: `e₁ = c/‖c‖` with `c = −Rᵀt` the right centre,
//! `e₂ = z̄ × e₁`, `e₃ = e₁ × e₂`). The shared rectified pinhole takes the mean focal length of
//! the two cameras and the principal point OpenCV chooses with `CALIB_ZERO_DISPARITY`: the image
//! centre `((w−1)/2, (h−1)/2)` minus the mean of the four undistorted, rotated and projected
//! image corners of both cameras, so that the rectified images are centred on what both
//! cameras see. Each output pixel `q` samples the raw image at `K_raw·δ(proj(R_rawᵀ·K⁻¹q))`
//! (`vision::undistort::UndistortMap`), bilinearly for intensities and at the nearest pixel for
//! depth (interpolating depths across an occlusion edge would invent surfaces).

use crate::camera::{CameraIntrinsics, RawCamera};
use geom::{PinholeCamera, StereoCamera};
use lie::Se3;
use nalgebra::{Matrix3, Vector2, Vector3};
use vision::image::{GrayImage, Image};
use vision::undistort::{UndistortMap, rectify_stereo};

/// A remap table from an ideal (undistorted, possibly rotated) image to a raw camera's image.
#[derive(Debug, Clone)]
pub struct Remap {
    map: UndistortMap,
}

impl Remap {
    /// The table for output images of `dst` (the raw size) sampling `raw`, rotated by
    /// `raw_from_dst` (identity for plain undistortion).
    pub fn new(
        raw: &CameraIntrinsics,
        dst: &PinholeCamera,
        raw_from_dst: Option<&Matrix3<f64>>,
    ) -> Self {
        let (w, h) = (raw.width, raw.height);
        let map = match RawCamera::of(raw) {
            RawCamera::RadTan(c) => UndistortMap::new(&c, dst, w, h, raw_from_dst),
            RawCamera::Equidistant(c) => UndistortMap::new(&c, dst, w, h, raw_from_dst),
        };
        Remap { map }
    }

    /// The raw image pixel sampled by output pixel `(u, v)` (NaN where none).
    pub fn source(&self, u: usize, v: usize) -> (f32, f32) {
        (self.map.map_u.get(u, v), self.map.map_v.get(u, v))
    }

    /// Remaps an intensity image (bilinear; outside the raw image 0).
    pub fn gray(&self, raw: &GrayImage) -> GrayImage {
        self.map.remap(raw)
    }

    /// Remaps a depth image at the nearest raw pixel (outside the raw image 0 = invalid).
    pub fn depth(&self, raw: &Image<u16>) -> Image<u16> {
        let (w, h) = (self.map.map_u.width(), self.map.map_u.height());
        Image::from_fn(w, h, |u, v| {
            let (x, y) = self.source(u, v);
            if !(x.is_finite() && y.is_finite()) {
                return 0;
            }
            raw.get_checked(x.round() as i64, y.round() as i64)
                .unwrap_or(0)
        })
    }
}

/// A rectified stereo pair: the rectified camera, the rotations and the remap tables.
#[derive(Debug, Clone)]
pub struct StereoRectifier {
    /// The rectified stereo camera (left pinhole and baseline, metres).
    pub camera: StereoCamera,
    /// Rotation from the raw left camera into the rectified left camera.
    pub rect_from_left: Matrix3<f64>,
    /// Rotation from the raw right camera into the rectified right camera.
    pub rect_from_right: Matrix3<f64>,
    /// Left remap table.
    pub left: Remap,
    /// Right remap table.
    pub right: Remap,
}

impl StereoRectifier {
    /// Rectifies the pair (see the [module docs](self)); `None` if the extrinsics have no
    /// baseline (coincident centres).
    pub fn new(
        left: &CameraIntrinsics,
        right: &CameraIntrinsics,
        right_from_left: &Se3,
    ) -> Option<Self> {
        let r = right_from_left.rotation().rotation_matrix();
        let t = *right_from_left.translation();
        if t.norm().is_nan() || t.norm() <= 0.0 {
            return None;
        }
        let first = rectify_stereo(&left.pinhole, &right.pinhole, &r, &t, Vector2::zeros());
        let f = first.pinhole.fx;
        // Bouguet / OpenCV principal point: centre minus the mean projected corner.
        let mut sum = Vector2::zeros();
        let mut n = 0.0;
        for (cam, rect_from) in [(left, first.rect_from_left), (right, first.rect_from_right)] {
            let raw = RawCamera::of(cam);
            let (w, h) = (cam.width as f64 - 1.0, cam.height as f64 - 1.0);
            for corner in [
                Vector2::new(0.0, 0.0),
                Vector2::new(w, 0.0),
                Vector2::new(0.0, h),
                Vector2::new(w, h),
            ] {
                let undistorted = match &raw {
                    RawCamera::RadTan(c) => c.undistort_pixel(&corner),
                    RawCamera::Equidistant(c) => c.undistort_pixel(&corner),
                };
                let Ok(p) = undistorted else { continue };
                let m = cam.pinhole.normalised_from_pixel(&p);
                let x = rect_from * Vector3::new(m.x, m.y, 1.0);
                if x.z > 0.0 {
                    sum += Vector2::new(f * x.x / x.z, f * x.y / x.z);
                    n += 1.0;
                }
            }
        }
        let centre = Vector2::new(
            (left.width as f64 - 1.0) / 2.0,
            (left.height as f64 - 1.0) / 2.0,
        );
        let pp = if n > 0.0 { centre - sum / n } else { centre };
        let pinhole = PinholeCamera::new(f, f, pp.x, pp.y);
        let left_map = Remap::new(left, &pinhole, Some(&first.rect_from_left.transpose()));
        let right_map = Remap::new(right, &pinhole, Some(&first.rect_from_right.transpose()));
        // Sanity of the construction: the right centre lies on the rectified x axis.
        debug_assert!({
            let c = first.rect_from_left * (-(r.transpose() * t));
            c.y.abs() < 1e-9 * c.norm() && c.z.abs() < 1e-9 * c.norm()
        });
        Some(StereoRectifier {
            camera: StereoCamera::new(pinhole, first.baseline),
            rect_from_left: first.rect_from_left,
            rect_from_right: first.rect_from_right,
            left: left_map,
            right: right_map,
        })
    }
}
