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
use vision::undistort::{RemapTable, UndistortMap, rectify_stereo};

/// A remap table from an ideal (undistorted, possibly rotated) image to a raw camera's image.
#[derive(Debug, Clone)]
pub struct Remap {
    map: UndistortMap,
    /// The map compiled for the raw size (`None` for images under 2×2 pixels).
    table: Option<RemapTable>,
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
        let table = RemapTable::new(&map, w, h);
        Remap { map, table }
    }

    /// The raw image pixel sampled by output pixel `(u, v)` (NaN where none).
    pub fn source(&self, u: usize, v: usize) -> (f32, f32) {
        (self.map.map_u.get(u, v), self.map.map_v.get(u, v))
    }

    /// The compiled table, if `raw` has the size it was compiled for.
    fn table_for<T: Copy + Default>(&self, raw: &Image<T>) -> Option<&RemapTable> {
        self.table
            .as_ref()
            .filter(|t| t.source_size() == (raw.width(), raw.height()))
    }

    /// Remaps an intensity image (bilinear; outside the raw image 0).
    pub fn gray(&self, raw: &GrayImage) -> GrayImage {
        match self.table_for(raw) {
            Some(t) => t.remap(raw),
            None => self.map.remap(raw),
        }
    }

    /// Remaps a depth image at the nearest raw pixel (outside the raw image 0 = invalid).
    pub fn depth(&self, raw: &Image<u16>) -> Image<u16> {
        match self.table_for(raw) {
            Some(t) => t.remap_nearest(raw, 0),
            None => self.depth_through_map(raw),
        }
    }

    /// [`Remap::depth`] through the map, pixel by pixel (images the table was not compiled for).
    fn depth_through_map(&self, raw: &Image<u16>) -> Image<u16> {
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::LensDistortion;

    /// The compiled table samples the same raw pixels as the map, bit for bit, for intensities
    /// (bilinear) and depths (nearest), on a strongly distorted, rotated camera whose view
    /// leaves the raw image at the corners.
    #[test]
    fn the_compiled_table_remaps_as_the_map() {
        let (w, h) = (97, 61);
        let raw = CameraIntrinsics {
            width: w,
            height: h,
            pinhole: PinholeCamera::new(60.0, 62.0, 47.3, 29.8),
            distortion: LensDistortion::RadTan(geom::RadTan::new(-0.3, 0.09, 0.001, -0.0005)),
        };
        let rot = nalgebra::Rotation3::from_euler_angles(0.02, -0.03, 0.01).into_inner();
        let remap = Remap::new(
            &raw,
            &PinholeCamera::new(55.0, 55.0, 48.0, 30.0),
            Some(&rot),
        );
        let gray = GrayImage::from_fn(w, h, |u, v| ((u * 37 + v * 91 + u * v) % 251) as u8);
        let depth = Image::<u16>::from_fn(w, h, |u, v| (1000 + u * 13 + v * 7) as u16);
        assert!(remap.table.is_some());
        let (a, b) = (remap.gray(&gray), remap.map.remap(&gray));
        assert_eq!(a.data(), b.data());
        let (a, b) = (remap.depth(&depth), remap.depth_through_map(&depth));
        assert_eq!(a.data(), b.data());
        // Both kinds of pixel occur: inside and outside the raw image.
        assert!(b.data().contains(&0) && b.data().iter().any(|&d| d > 0));
        // An image of another size goes through the map.
        let small = GrayImage::from_fn(w - 1, h, |u, _| u as u8);
        assert_eq!(remap.gray(&small).data(), remap.map.remap(&small).data());
    }
}
