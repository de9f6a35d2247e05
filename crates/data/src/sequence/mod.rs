//! Image sequences: a dataset folder on disk → frames in time order, with the camera model and,
//! where the dataset has it, ground truth.
//!
//! Formats ([`SequenceFormat`], detected from the folder's layout by [`detect_format`]):
//!
//! | format | layout | sensor |
//! |---|---|---|
//! | TUM RGB-D | `rgb.txt`, `depth.txt`, `groundtruth.txt` (7-Scenes: `+ camera-intrinsics.txt`, `groundtruth_tum.txt`; a `camera.yaml` beside them is the calibration) | RGB-D |
//! | EuRoC MAV | `mav0/cam0/data.csv`, `mav0/cam1/data.csv`, `sensor.yaml`s, `mav0/state_groundtruth_estimate0/data.csv` | stereo |
//! | KITTI odometry | `calib.txt`, `image_0/` + `image_1/` (or `image_l/` + `image_r/`), `times.txt`, `poses.txt` | stereo |
//! | image folder | a camera file (`camera.yaml` or one `*.yaml`) + images (`images/` or the folder itself), `left/` + `right/`, or `rgb/` + `depth/` | mono, stereo, RGB-D |
//!
//! [`Sequence::open`] reads and checks every list and calibration file up front; frames are
//! decoded later, either on demand ([`Sequence::read`]) or ahead of the consumer on their own
//! thread through a bounded queue ([`Sequence::into_reader`], [`Reader`]). Delivered images are
//! undistorted (and stereo pairs rectified) with remap tables computed once at open, so that
//! [`SequenceInfo::camera`] is an ideal [`SensorModel`]; `raw_images` in [`OpenOptions`] keeps
//! them as stored. Ground truth is given per frame as `world_from_camera` of the delivered
//! (rectified left / colour) camera.

mod decode;
mod euroc;
mod folder;
mod kitti;
pub mod lists;
mod reader;
pub mod rectify;
mod tum;

pub use decode::luma;
pub use reader::{DEFAULT_QUEUE_LENGTH, Reader, ReaderStats};
pub use tum::{TUM_DEPTH_UNITS_PER_METRE, TumCamera, tum_camera};

use crate::camera::{Calibration, SensorModel};
use crate::camera_file::{CameraFile, read_camera_file};
use crate::error::{DataError, ParseErrorKind};
use crate::trajectory::Trajectory;
use decode::Decoder;
use lie::{LieGroup, Se3, So3};
use std::path::{Path, PathBuf};
use std::sync::Arc;
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
    /// Metres per raw unit (see [`DepthCalibration::metres_per_unit`]).
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

/// An opened sequence: checked lists and calibration; frames are decoded on demand.
pub struct Sequence {
    info: SequenceInfo,
    frames: Vec<FrameSpec>,
    decoder: Arc<Decoder>,
    policy: BadFramePolicy,
}

/// Ground truth is interpolated between two samples at most this far apart, seconds: motion
/// capture runs at 100–200 Hz and 7-Scenes/EuRoC ground truth at the camera rate (20–30 Hz), so
/// 0.1 s bridges a dropped sample or two; linear/slerp interpolation over 0.1 s of hand-held or
/// MAV motion (accelerations ≲ 1 m/s²) errs by ≲ a·Δt²/8 ≈ 1 mm.
pub const GROUND_TRUTH_MAX_GAP: f64 = 0.1;

/// Which format the folder's layout shows (see the [module docs](self)).
pub fn detect_format(root: &Path) -> Result<SequenceFormat, DataError> {
    if !root.is_dir() {
        return Err(DataError::File {
            path: root.to_path_buf(),
            kind: ParseErrorKind::Expected {
                expected: "a sequence folder".into(),
                found: if root.exists() {
                    "a file".into()
                } else {
                    "nothing (it does not exist)".into()
                },
            },
        });
    }
    if euroc::mav_dir(root).is_some() {
        return Ok(SequenceFormat::Euroc);
    }
    if root.join("rgb.txt").is_file() {
        return Ok(SequenceFormat::Tum);
    }
    if root.join("calib.txt").is_file() && kitti::image_dirs(root).is_some() {
        return Ok(SequenceFormat::Kitti);
    }
    if folder::camera_file_in(root).is_some() {
        return Ok(SequenceFormat::Folder);
    }
    let mut names: Vec<String> = std::fs::read_dir(root)
        .map(|d| {
            d.filter_map(|e| e.ok())
                .map(|e| e.file_name().to_string_lossy().into_owned())
                .collect()
        })
        .unwrap_or_default();
    names.sort();
    let shown = if names.is_empty() {
        "an empty folder".to_string()
    } else if names.len() > 8 {
        format!("{}, … ({} entries)", names[..8].join(", "), names.len())
    } else {
        names.join(", ")
    };
    Err(DataError::File {
        path: root.to_path_buf(),
        kind: ParseErrorKind::Expected {
            expected: "a known layout: TUM RGB-D (rgb.txt), EuRoC (mav0/cam0/data.csv), KITTI \
                       (calib.txt + image_0/ or image_l/), or images with a camera file \
                       (camera.yaml)"
                .into(),
            found: shown,
        },
    })
}

fn expected(path: &Path, expected: impl Into<String>, found: impl Into<String>) -> DataError {
    DataError::File {
        path: path.to_path_buf(),
        kind: ParseErrorKind::Expected {
            expected: expected.into(),
            found: found.into(),
        },
    }
}

impl Sequence {
    /// Opens the sequence in `root`: detects (or takes) the format, reads and checks every list
    /// and calibration file, associates images (and ground truth) by time, and prepares the
    /// remap tables. Frames are not decoded yet.
    pub fn open(root: impl AsRef<Path>, options: &OpenOptions) -> Result<Sequence, DataError> {
        let root = root.as_ref();
        let format = match options.format {
            Some(f) => {
                if !root.is_dir() {
                    detect_format(root)?;
                }
                f
            }
            None => detect_format(root)?,
        };
        let camera_file = options
            .camera_file
            .as_ref()
            .map(|p| read_camera_file(p).map(|c| (p.clone(), c)))
            .transpose()?;
        let override_ = camera_file.as_ref().map(|(p, c)| (p.as_path(), c));
        let mut opened = match format {
            SequenceFormat::Tum => tum::open(root, options, override_)?,
            SequenceFormat::Euroc => euroc::open(root, options, override_)?,
            SequenceFormat::Kitti => kitti::open(root, options, override_)?,
            SequenceFormat::Folder => folder::open(root, options, override_)?,
        };
        if opened.frames.is_empty() {
            return Err(expected(root, "at least one frame", "none"));
        }
        if options.require_depth {
            let before = opened.frames.len();
            opened
                .frames
                .retain(|f| !matches!(f.files, FrameFiles::Rgbd(_, None)));
            if opened.frames.len() < before {
                opened.warnings.push(format!(
                    "{} frames without an associated depth image were dropped",
                    before - opened.frames.len()
                ));
            }
        }
        if options.no_depth {
            for f in &mut opened.frames {
                if let FrameFiles::Rgbd(_, depth) = &mut f.files {
                    *depth = None;
                }
            }
        }
        let decoder = Decoder::new(
            &opened.calibration,
            options.raw_images,
            opened.colour && !options.no_colour,
        )
        .map_err(|e| expected(root, "a usable calibration", e))?;
        let camera = decoder.camera;
        // Ground truth into the delivered camera: rectified frames are rotated by
        // `rect_from_raw`, so world_from_rect = world_from_raw · raw_from_rect.
        let ground_truth = opened.ground_truth.map(|mut gt| {
            if let Some(raw_from_rect) = decoder.raw_from_delivered() {
                for p in &mut gt.trajectory.world_from_body {
                    *p = p.compose(&raw_from_rect);
                }
            }
            gt
        });
        let mut frames = opened.frames;
        if let Some(gt) = &ground_truth {
            for f in &mut frames {
                f.world_from_camera =
                    interpolate(&gt.trajectory, f.timestamp, GROUND_TRUTH_MAX_GAP);
            }
        }
        let info = SequenceInfo {
            root: root.to_path_buf(),
            format,
            calibration: opened.calibration,
            camera,
            size: decoder.size,
            frame_count: frames.len(),
            ground_truth,
            warnings: opened.warnings,
        };
        Ok(Sequence {
            info,
            frames,
            decoder: Arc::new(decoder),
            policy: options.on_bad_frame,
        })
    }

    /// What the sequence is.
    pub fn info(&self) -> &SequenceInfo {
        &self.info
    }

    /// Number of frames.
    pub fn len(&self) -> usize {
        self.frames.len()
    }

    /// `true` when there are no frames (never, for an opened sequence).
    pub fn is_empty(&self) -> bool {
        self.frames.is_empty()
    }

    /// Timestamp of frame `index`.
    pub fn timestamp(&self, index: usize) -> Option<f64> {
        self.frames.get(index).map(|f| f.timestamp)
    }

    /// The image files of frame `index` (left/colour first).
    pub fn files(&self, index: usize) -> Vec<PathBuf> {
        match self.frames.get(index).map(|f| &f.files) {
            Some(FrameFiles::Mono(p)) => vec![p.clone()],
            Some(FrameFiles::Stereo(l, r)) => vec![l.clone(), r.clone()],
            Some(FrameFiles::Rgbd(c, d)) => std::iter::once(c.clone()).chain(d.clone()).collect(),
            None => vec![],
        }
    }

    /// Decodes frame `index` now, on this thread (`None` past the end).
    pub fn read(&self, index: usize) -> Option<Result<Frame, FrameError>> {
        let spec = self.frames.get(index)?;
        Some(self.decoder.decode(index, spec))
    }

    /// Starts decoding on its own thread, at most `queue_length` frames ahead of the consumer
    /// (≥ 1; see [`DEFAULT_QUEUE_LENGTH`]).
    pub fn into_reader(self, queue_length: usize) -> Reader {
        Reader::start(
            self.info,
            self.frames,
            self.decoder,
            self.policy,
            queue_length,
        )
    }
}

/// The pose at time `t`: a sample within 1 µs of `t`, else the interpolation (linear in
/// translation, geodesic in rotation) between the samples bracketing `t` if they are at most
/// `max_gap` apart; `None` outside. `trajectory` must be sorted by time.
pub fn interpolate(trajectory: &Trajectory, t: f64, max_gap: f64) -> Option<Se3> {
    let ts = &trajectory.timestamps;
    let k = ts.partition_point(|&s| s < t);
    for j in [k.wrapping_sub(1), k] {
        if let Some(&s) = ts.get(j)
            && (s - t).abs() <= 1e-6
        {
            return Some(trajectory.world_from_body[j]);
        }
    }
    if k == 0 || k >= ts.len() {
        return None;
    }
    let (t0, t1) = (ts[k - 1], ts[k]);
    if t1 - t0 > max_gap {
        return None;
    }
    let s = (t - t0) / (t1 - t0);
    let (a, b) = (
        &trajectory.world_from_body[k - 1],
        &trajectory.world_from_body[k],
    );
    let delta = a.rotation().inverse().compose(b.rotation()).log();
    let rotation = a.rotation().compose(&So3::exp(&(delta * s)));
    let translation = a.translation() * (1.0 - s) + b.translation() * s;
    Some(Se3::new(rotation, translation))
}

/// The calibration override, or the dataset's own.
pub(crate) fn calibration_or(
    override_: Option<(&Path, &CameraFile)>,
    kind: crate::camera::SensorKind,
    size: (usize, usize),
    own: impl FnOnce() -> Result<Calibration, DataError>,
) -> Result<Calibration, DataError> {
    match override_ {
        Some((path, file)) => file.calibration(kind, size, path),
        None => own(),
    }
}

/// `(width, height)` of an image file from its header (no decoding), naming the file.
pub(crate) fn image_size(path: &Path) -> Result<(usize, usize), DataError> {
    let r = image::ImageReader::open(path)
        .and_then(|r| r.with_guessed_format())
        .map_err(|source| DataError::Io {
            path: path.to_path_buf(),
            source,
        })?;
    let (w, h) = r.into_dimensions().map_err(|e| {
        expected(
            path,
            "an image (PNG, JPEG, PNM)",
            format!("undecodable: {e}"),
        )
    })?;
    Ok((w as usize, h as usize))
}

/// `true` if the image file has colour channels (from its header).
pub(crate) fn image_has_colour(path: &Path) -> bool {
    use image::ImageDecoder;
    image::ImageReader::open(path)
        .and_then(|r| r.with_guessed_format())
        .ok()
        .and_then(|r| r.into_decoder().ok())
        .is_some_and(|d| d.color_type().has_color())
}

/// Drops entries out of time order under [`BadFramePolicy::Skip`] (with a warning) or fails
/// under [`BadFramePolicy::Stop`].
pub(crate) fn ordered(
    mut entries: Vec<lists::ListEntry>,
    path: &Path,
    policy: BadFramePolicy,
    warnings: &mut Vec<String>,
) -> Result<Vec<lists::ListEntry>, DataError> {
    loop {
        match lists::check_increasing(&entries, path) {
            Ok(()) => return Ok(entries),
            Err((k, e)) => match policy {
                BadFramePolicy::Stop => return Err(e),
                BadFramePolicy::Skip => {
                    warnings.push(format!("skipped: {e}"));
                    entries.remove(k);
                }
            },
        }
    }
}
