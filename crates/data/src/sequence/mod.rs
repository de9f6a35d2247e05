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
//! [`SequenceInfo::camera`] is an ideal [`SensorModel`](crate::camera::SensorModel);
//! `raw_images` in [`OpenOptions`] keeps them as stored. Ground truth is given per frame as
//! `world_from_camera` of the delivered (rectified left / colour) camera.

mod common;
mod decode;
mod euroc;
mod folder;
mod kitti;
pub mod lists;
mod reader;
pub mod rectify;
mod tum;
mod types;

pub use decode::luma;
pub use reader::{DEFAULT_QUEUE_LENGTH, Reader, ReaderStats};
pub use tum::{TUM_DEPTH_UNITS_PER_METRE, TumCamera, tum_camera};
pub use types::{
    BadFramePolicy, DepthImage, Frame, FrameError, FrameErrorKind, FrameImages, GroundTruth,
    OpenOptions, RgbPlanes, SequenceFormat, SequenceInfo,
};

use crate::camera_file::read_camera_file;
use crate::error::{DataError, ParseErrorKind};
use crate::trajectory::Trajectory;
use common::expected;
use decode::Decoder;
use lie::{LieGroup, Se3, So3};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use types::{FrameFiles, FrameSpec};

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

    /// The sequence from frame `first` on (frames are numbered from there, 0 first); an
    /// error if it has no frame `first`.
    pub fn starting_at(mut self, first: usize) -> Result<Self, String> {
        if first >= self.frames.len() {
            return Err(format!(
                "it has {} frames, so no frame {first} to start at",
                self.frames.len()
            ));
        }
        self.frames.drain(..first);
        self.info.frame_count = self.frames.len();
        Ok(self)
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
