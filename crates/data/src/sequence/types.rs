//! The types of image sequences: formats and options, frames and why one could not be read,
//! ground truth and what an opened sequence is, and what a format's opener hands back
//! (`FrameSpec`, `FrameFiles`, `Opened`). Shared by the format readers (`tum`, `euroc`, `kitti`,
//! `folder`), the decoder and the reader, and a leaf: it imports none of them. The public types
//! are re-exported as `data::sequence::…`.

use crate::camera::{Calibration, SensorModel};
use crate::trajectory::Trajectory;
use lie::Se3;
use std::path::PathBuf;
use vision::image::{GrayImage, Image};

/// The layouts a sequence can have.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SequenceFormat {
    /// TUM RGB-D (and the 7-Scenes variant).
    Tum,
    /// EuRoC MAV (ASL `mav0/` layout).
    Euroc,
    /// KITTI odometry.
    Kitti,
    /// A folder of images with a camera file.
    Folder,
}

impl SequenceFormat {
    /// The name used on the command line.
    pub fn name(&self) -> &'static str {
        match self {
            SequenceFormat::Tum => "tum",
            SequenceFormat::Euroc => "euroc",
            SequenceFormat::Kitti => "kitti",
            SequenceFormat::Folder => "folder",
        }
    }
}

impl std::str::FromStr for SequenceFormat {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "tum" => Ok(SequenceFormat::Tum),
            "euroc" => Ok(SequenceFormat::Euroc),
            "kitti" => Ok(SequenceFormat::Kitti),
            "folder" => Ok(SequenceFormat::Folder),
            _ => Err(format!(
                "unknown format {s:?}: expected tum, euroc, kitti or folder"
            )),
        }
    }
}

/// What to do with a frame that cannot be read (missing, truncated or undecodable image, wrong
/// size) or a list entry out of time order.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum BadFramePolicy {
    /// Report it and end the sequence there (the default: a bad frame usually means a broken
    /// dataset, and tracking across a silent gap hides it).
    #[default]
    Stop,
    /// Report it as a warning and go on with the next frame.
    Skip,
}

impl std::str::FromStr for BadFramePolicy {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "stop" => Ok(BadFramePolicy::Stop),
            "skip" => Ok(BadFramePolicy::Skip),
            _ => Err(format!("unknown policy {s:?}: expected skip or stop")),
        }
    }
}

/// How to open a sequence.
#[derive(Clone, Debug, Default)]
pub struct OpenOptions {
    /// Force a format instead of detecting it.
    pub format: Option<SequenceFormat>,
    /// A camera file (dwslam YAML or ORB-SLAM3 settings) overriding the dataset's calibration.
    pub camera_file: Option<PathBuf>,
    /// Bad frames and out-of-order list entries: stop (default) or skip with a warning.
    pub on_bad_frame: BadFramePolicy,
    /// Deliver images as stored (no undistortion or rectification); [`SequenceInfo::camera`]
    /// then still describes the rectified images and [`SequenceInfo::calibration`] the
    /// delivered ones.
    pub raw_images: bool,
    /// Do not decode colour planes (colour is decoded where images have it, for coloured
    /// maps).
    pub no_colour: bool,
    /// RGB-D: drop frames without an associated depth image (by default they are delivered
    /// with `depth: None`).
    pub require_depth: bool,
    /// RGB-D: do not decode the depth images (frames are delivered with `depth: None`; a
    /// monocular run of an RGB-D sequence, whose reader would otherwise decode a 16-bit PNG per
    /// frame for nothing).
    pub no_depth: bool,
}

/// A depth image with its encoding.
#[derive(Clone, Debug, PartialEq)]
pub struct DepthImage {
    /// Raw values as stored.
    pub raw: Image<u16>,
    /// Metres per raw unit (see
    /// [`DepthCalibration::metres_per_unit`](crate::camera::DepthCalibration::metres_per_unit)).
    pub metres_per_unit: f64,
    /// Raw values `≥` this are invalid, as is 0.
    pub max_valid_raw: u16,
}

impl DepthImage {
    /// Depth at `(u, v)` in metres, `None` where invalid or outside the image.
    pub fn metres_at(&self, u: usize, v: usize) -> Option<f64> {
        let d = self.raw.get_checked(u as i64, v as i64)?;
        (d != 0 && d < self.max_valid_raw).then_some(d as f64 * self.metres_per_unit)
    }

    /// The whole image in metres as `f32`, NaN where invalid.
    pub fn to_metres(&self) -> Image<f32> {
        let s = self.metres_per_unit;
        let max = self.max_valid_raw;
        self.raw.map(|d| {
            if d == 0 || d >= max {
                f32::NAN
            } else {
                (d as f64 * s) as f32
            }
        })
    }
}

/// Three 8-bit planes `[red, green, blue]` (as `vision::image::load_rgb_planes`).
pub type RgbPlanes = [GrayImage; 3];

/// The images of one frame.
#[derive(Clone, Debug, PartialEq)]
pub enum FrameImages {
    /// One camera.
    Mono {
        /// Grey image.
        image: GrayImage,
        /// Colour planes, where the images have colour.
        colour: Option<RgbPlanes>,
    },
    /// A rectified stereo pair.
    Stereo {
        /// Left grey image.
        left: GrayImage,
        /// Right grey image.
        right: GrayImage,
    },
    /// Colour with registered depth.
    Rgbd {
        /// Grey image (luma of the colour image).
        image: GrayImage,
        /// Colour planes.
        colour: Option<RgbPlanes>,
        /// The associated depth image, if one was associated with this frame.
        depth: Option<DepthImage>,
    },
}

/// One frame of a sequence.
#[derive(Clone, Debug, PartialEq)]
pub struct Frame {
    /// Position in the sequence (0-based; kept across skipped frames).
    pub index: usize,
    /// Seconds (dataset clock).
    pub timestamp: f64,
    /// The images.
    pub images: FrameImages,
    /// Ground truth: the delivered (rectified left / colour) camera in the ground-truth world
    /// frame, if the dataset has ground truth at this time.
    pub world_from_camera: Option<Se3>,
}

impl Frame {
    /// The grey image tracking uses (mono, left, or the luma of the colour image).
    pub fn gray(&self) -> &GrayImage {
        match &self.images {
            FrameImages::Mono { image, .. } | FrameImages::Rgbd { image, .. } => image,
            FrameImages::Stereo { left, .. } => left,
        }
    }

    /// The colour planes, where the images have colour.
    pub fn colour(&self) -> Option<&RgbPlanes> {
        match &self.images {
            FrameImages::Mono { colour, .. } | FrameImages::Rgbd { colour, .. } => colour.as_ref(),
            FrameImages::Stereo { .. } => None,
        }
    }

    /// Bytes of pixel data held by this frame.
    pub fn pixel_bytes(&self) -> usize {
        let g = |i: &GrayImage| i.data().len();
        let c = |c: &Option<RgbPlanes>| c.as_ref().map_or(0, |p| p.iter().map(g).sum());
        match &self.images {
            FrameImages::Mono { image, colour } => g(image) + c(colour),
            FrameImages::Stereo { left, right } => g(left) + g(right),
            FrameImages::Rgbd {
                image,
                colour,
                depth,
            } => g(image) + c(colour) + depth.as_ref().map_or(0, |d| 2 * d.raw.data().len()),
        }
    }
}

/// Why a frame could not be read.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
#[error("frame {index} (t = {timestamp} s), {}: {kind}", path.display())]
pub struct FrameError {
    /// The frame's position in the sequence.
    pub index: usize,
    /// Its timestamp.
    pub timestamp: f64,
    /// The file that failed.
    pub path: PathBuf,
    /// What was wrong.
    pub kind: FrameErrorKind,
}

/// What is wrong with a frame's file.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum FrameErrorKind {
    /// The file does not exist.
    #[error("image file does not exist")]
    Missing,
    /// The file exists but cannot be read.
    #[error("cannot read the file: {0}")]
    Io(String),
    /// The file is truncated, corrupt or not an image.
    #[error("cannot decode the image: {0}")]
    Decode(String),
    /// The image has another size than the camera.
    #[error(
        "{what} is {found_width}×{found_height}, expected {width}×{height} (the camera's size)"
    )]
    Size {
        /// Which image.
        what: String,
        /// Expected width.
        width: usize,
        /// Expected height.
        height: usize,
        /// Found width.
        found_width: usize,
        /// Found height.
        found_height: usize,
    },
    /// The image has the wrong pixel format (e.g. an 8-bit depth image).
    #[error("{what}: expected {expected}, found {found}")]
    PixelFormat {
        /// Which image.
        what: String,
        /// Expected format.
        expected: String,
        /// Found format.
        found: String,
    },
}

/// Ground truth of a sequence.
#[derive(Clone, Debug, PartialEq)]
pub struct GroundTruth {
    /// `world_from_camera` of the delivered camera (stored in the trajectory's
    /// `world_from_body` field), at the ground truth's own times.
    pub trajectory: Trajectory,
    /// The file it was read from.
    pub source: PathBuf,
}

/// What an opened sequence is.
#[derive(Clone, Debug)]
pub struct SequenceInfo {
    /// The folder.
    pub root: PathBuf,
    /// Its format.
    pub format: SequenceFormat,
    /// The sensor as calibrated (the raw images).
    pub calibration: Calibration,
    /// The camera of the delivered (undistorted, rectified) images.
    pub camera: SensorModel,
    /// `(width, height)` of the delivered images.
    pub size: (usize, usize),
    /// Number of frames.
    pub frame_count: usize,
    /// Ground truth, if the dataset has it.
    pub ground_truth: Option<GroundTruth>,
    /// Facts the user should know (calibration chosen by default, frames dropped at open, …).
    pub warnings: Vec<String>,
}

/// One frame's files and times, as listed.
#[derive(Clone, Debug)]
pub(crate) struct FrameSpec {
    pub timestamp: f64,
    pub files: FrameFiles,
    pub world_from_camera: Option<Se3>,
}

#[derive(Clone, Debug)]
pub(crate) enum FrameFiles {
    Mono(PathBuf),
    Stereo(PathBuf, PathBuf),
    Rgbd(PathBuf, Option<PathBuf>),
}

/// What a format's opener found.
pub(crate) struct Opened {
    pub calibration: Calibration,
    pub frames: Vec<FrameSpec>,
    /// In the raw (left / colour) camera's frame, `world_from_camera`.
    pub ground_truth: Option<GroundTruth>,
    pub colour: bool,
    pub warnings: Vec<String>,
}
