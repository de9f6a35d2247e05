//! Decoding one frame: image files → checked, undistorted / rectified images.

use super::rectify::{Remap, StereoRectifier};
use super::types::{
    DepthImage, Frame, FrameError, FrameErrorKind, FrameFiles, FrameImages, FrameSpec, RgbPlanes,
};
use crate::camera::{Calibration, DepthCalibration, SensorModel};
use geom::{RgbdCamera, StereoCamera};
use lie::{Se3, So3};
use nalgebra::{Rotation3, UnitQuaternion};
use std::path::Path;
use vision::image::{GrayImage, Image, ImageError, load_gray_u8, load_rgb_planes};

pub(crate) struct Decoder {
    /// The camera of the delivered images.
    pub camera: SensorModel,
    /// Their size.
    pub size: (usize, usize),
    colour: bool,
    depth: Option<DepthCalibration>,
    /// Undistortion of mono / colour images (None: raw images or no distortion).
    undistort: Option<Remap>,
    /// Rectification of a stereo pair (None: raw images or already rectified).
    rectify: Option<StereoRectifier>,
    /// `raw_from_delivered` rotation of rectified stereo.
    raw_from_rect: Option<Se3>,
}

/// Luma as the `image` crate computes it for `into_luma8` (Rec. 709 weights, integer
/// arithmetic), so that the grey image of a colour file equals `vision::image::load_gray_u8`.
pub fn luma(planes: &RgbPlanes) -> GrayImage {
    let [r, g, b] = planes;
    let (w, h) = (r.width(), r.height());
    // Row slices zipped (no per-pixel bounds checks): the reader converts every colour frame.
    let mut data = Vec::with_capacity(w * h);
    for v in 0..h {
        data.extend(
            r.row(v)
                .iter()
                .zip(g.row(v))
                .zip(b.row(v))
                .map(|((&r, &g), &b)| {
                    ((2126 * r as u32 + 7152 * g as u32 + 722 * b as u32) / 10000) as u8
                }),
        );
    }
    GrayImage::from_vec(w, h, w, data).expect("a w×h buffer for a w×h image")
}

/// A decoder error: a read that ended early is a truncated image, other I/O errors are I/O.
fn decode_kind(e: image::ImageError) -> FrameErrorKind {
    match e {
        image::ImageError::IoError(io) if io.kind() == std::io::ErrorKind::UnexpectedEof => {
            FrameErrorKind::Decode(format!("the file is truncated ({io})"))
        }
        image::ImageError::IoError(io) => FrameErrorKind::Io(io.to_string()),
        other => FrameErrorKind::Decode(other.to_string()),
    }
}

impl Decoder {
    pub fn new(calibration: &Calibration, raw: bool, colour: bool) -> Result<Decoder, String> {
        let primary = calibration.primary();
        let size = (primary.width, primary.height);
        let undistort = |c: &crate::camera::CameraIntrinsics| {
            (!raw && !c.distortion.is_identity()).then(|| Remap::new(c, &c.pinhole, None))
        };
        let mut d = Decoder {
            camera: SensorModel::Mono(primary.pinhole),
            size,
            colour,
            depth: None,
            undistort: None,
            rectify: None,
            raw_from_rect: None,
        };
        match calibration {
            Calibration::Mono { camera } => {
                d.undistort = undistort(camera);
            }
            Calibration::Rgbd { camera, depth } => {
                d.camera =
                    SensorModel::Rgbd(RgbdCamera::new(camera.pinhole, depth.virtual_baseline));
                d.depth = Some(*depth);
                d.undistort = undistort(camera);
            }
            Calibration::RectifiedStereo { camera, baseline } => {
                d.camera = SensorModel::Stereo(StereoCamera::new(camera.pinhole, *baseline));
            }
            Calibration::Stereo {
                left,
                right,
                right_from_left,
            } => {
                if (left.width, left.height) != (right.width, right.height) {
                    return Err(format!(
                        "the left ({}×{}) and right ({}×{}) images differ in size",
                        left.width, left.height, right.width, right.height
                    ));
                }
                let r = StereoRectifier::new(left, right, right_from_left)
                    .ok_or("the stereo extrinsics have no baseline (coincident optical centres)")?;
                d.camera = SensorModel::Stereo(r.camera);
                if !raw {
                    let q = UnitQuaternion::from_rotation_matrix(
                        &Rotation3::from_matrix_unchecked(r.rect_from_left.transpose()),
                    );
                    d.raw_from_rect = Some(Se3::from_rotation(So3::from_unit_quaternion(q)));
                    d.rectify = Some(r);
                }
            }
        }
        Ok(d)
    }

    /// `raw_from_delivered` where the delivered camera is rotated (rectified stereo).
    pub fn raw_from_delivered(&self) -> Option<Se3> {
        self.raw_from_rect
    }

    fn err(index: usize, t: f64, path: &Path, kind: FrameErrorKind) -> FrameError {
        FrameError {
            index,
            timestamp: t,
            path: path.to_path_buf(),
            kind,
        }
    }

    fn image_error(index: usize, t: f64, path: &Path, e: ImageError) -> FrameError {
        let kind = if !path.exists() {
            FrameErrorKind::Missing
        } else {
            match e {
                ImageError::Decode { source, .. } => decode_kind(source),
                ImageError::Empty { width, height, .. } => {
                    FrameErrorKind::Decode(format!("the image is empty ({width}×{height})"))
                }
                other => FrameErrorKind::Decode(other.to_string()),
            }
        };
        Self::err(index, t, path, kind)
    }

    fn check_size(
        &self,
        index: usize,
        t: f64,
        path: &Path,
        what: &str,
        w: usize,
        h: usize,
    ) -> Result<(), FrameError> {
        if (w, h) != self.size {
            return Err(Self::err(
                index,
                t,
                path,
                FrameErrorKind::Size {
                    what: what.into(),
                    width: self.size.0,
                    height: self.size.1,
                    found_width: w,
                    found_height: h,
                },
            ));
        }
        Ok(())
    }

    fn intensity(
        &self,
        index: usize,
        t: f64,
        path: &Path,
        what: &str,
        colour: bool,
    ) -> Result<(GrayImage, Option<RgbPlanes>), FrameError> {
        if !path.exists() {
            return Err(Self::err(index, t, path, FrameErrorKind::Missing));
        }
        let (gray, planes) = if colour && self.colour {
            let planes = load_rgb_planes(path).map_err(|e| Self::image_error(index, t, path, e))?;
            (luma(&planes), Some(planes))
        } else {
            (
                load_gray_u8(path).map_err(|e| Self::image_error(index, t, path, e))?,
                None,
            )
        };
        self.check_size(index, t, path, what, gray.width(), gray.height())?;
        Ok((gray, planes))
    }

    fn depth(&self, index: usize, t: f64, path: &Path) -> Result<DepthImage, FrameError> {
        if !path.exists() {
            return Err(Self::err(index, t, path, FrameErrorKind::Missing));
        }
        // Decoded here rather than with `vision::image::load_u16`, which widens 8-bit files
        // silently: an 8-bit "depth" image is an error, not depths ×257.
        let img = image::ImageReader::open(path)
            .and_then(|r| r.with_guessed_format())
            .map_err(|e| Self::err(index, t, path, FrameErrorKind::Io(e.to_string())))?
            .decode()
            .map_err(|e| Self::err(index, t, path, decode_kind(e)))?;
        let (w, h) = (img.width() as usize, img.height() as usize);
        let raw = match img {
            image::DynamicImage::ImageLuma16(buf) => Image::from_vec(w, h, w, buf.into_raw())
                .map_err(|e| Self::err(index, t, path, FrameErrorKind::Decode(e.to_string())))?,
            other => {
                return Err(Self::err(
                    index,
                    t,
                    path,
                    FrameErrorKind::PixelFormat {
                        what: "depth image".into(),
                        expected: "16-bit single-channel".into(),
                        found: format!("{:?}", other.color()),
                    },
                ));
            }
        };
        self.check_size(index, t, path, "depth image", w, h)?;
        let cal = self
            .depth
            .expect("an RGB-D decoder has a depth calibration");
        let raw = match &self.undistort {
            Some(m) => m.depth(&raw),
            None => raw,
        };
        Ok(DepthImage {
            raw,
            metres_per_unit: cal.metres_per_unit,
            max_valid_raw: cal.max_valid_raw,
        })
    }

    fn undistorted(
        &self,
        gray: GrayImage,
        colour: Option<RgbPlanes>,
    ) -> (GrayImage, Option<RgbPlanes>) {
        match &self.undistort {
            None => (gray, colour),
            Some(m) => (m.gray(&gray), colour.map(|p| p.map(|c| m.gray(&c)))),
        }
    }

    pub fn decode(&self, index: usize, spec: &FrameSpec) -> Result<Frame, FrameError> {
        let t = spec.timestamp;
        let images = match &spec.files {
            FrameFiles::Mono(p) => {
                let (g, c) = self.intensity(index, t, p, "image", true)?;
                let (image, colour) = self.undistorted(g, c);
                FrameImages::Mono { image, colour }
            }
            FrameFiles::Stereo(l, r) => {
                let (left, _) = self.intensity(index, t, l, "left image", false)?;
                let (right, _) = self.intensity(index, t, r, "right image", false)?;
                match &self.rectify {
                    None => FrameImages::Stereo { left, right },
                    Some(rect) => FrameImages::Stereo {
                        left: rect.left.gray(&left),
                        right: rect.right.gray(&right),
                    },
                }
            }
            FrameFiles::Rgbd(c, d) => {
                let (g, col) = self.intensity(index, t, c, "colour image", true)?;
                let depth = d.as_ref().map(|d| self.depth(index, t, d)).transpose()?;
                let (image, colour) = self.undistorted(g, col);
                FrameImages::Rgbd {
                    image,
                    colour,
                    depth,
                }
            }
        };
        Ok(Frame {
            index,
            timestamp: t,
            images,
            world_from_camera: spec.world_from_camera,
        })
    }
}
