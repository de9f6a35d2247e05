//! KITTI odometry layout: `calib.txt` (`P0:`… labelled or not), grey images in `image_0/` +
//! `image_1/` (or the `image_l/` + `image_r/` of the shared snippet; a left folder alone is
//! monocular), `times.txt` (optional: without it frames are 0.1 s apart, KITTI's 10 Hz), and
//! ground truth `poses.txt` in the folder (or `../../poses/<name>.txt` of the official tree):
//! line `i` is `world_from_camera` of the left camera at frame `i`.

use super::common::{calibration_or, image_size, list_images};
use super::lists;
use super::types::{FrameFiles, FrameSpec, GroundTruth, OpenOptions, Opened};
use crate::camera::{Calibration, CameraIntrinsics, SensorKind};
use crate::camera_file::CameraFile;
use crate::error::{DataError, ParseErrorKind};
use crate::text::read_to_string;
use crate::trajectory::{Trajectory, read_kitti, read_timestamps};
use std::path::{Path, PathBuf};

/// KITTI's camera rate: frames are 0.1 s apart when `times.txt` is absent.
pub const KITTI_FRAME_INTERVAL: f64 = 0.1;

/// The left and (optional) right image folders.
pub(crate) fn image_dirs(root: &Path) -> Option<(PathBuf, Option<PathBuf>)> {
    for (l, r) in [("image_0", "image_1"), ("image_l", "image_r")] {
        let (l, r) = (root.join(l), root.join(r));
        if l.is_dir() {
            return Some((l, r.is_dir().then_some(r)));
        }
    }
    None
}

pub(crate) fn open(
    root: &Path,
    _options: &OpenOptions,
    override_: Option<(&Path, &CameraFile)>,
) -> Result<Opened, DataError> {
    let (left_dir, right_dir) = image_dirs(root).ok_or_else(|| DataError::File {
        path: root.to_path_buf(),
        kind: ParseErrorKind::Expected {
            expected: "a KITTI layout: image_0/ (+ image_1/) or image_l/ (+ image_r/)".into(),
            found: "neither folder".into(),
        },
    })?;
    let mut warnings = Vec::new();
    let left = list_images(&left_dir)?;
    let size = image_size(&left[0])?;
    let calib_path = root.join("calib.txt");
    let kind = if right_dir.is_some() {
        SensorKind::Stereo
    } else {
        SensorKind::Mono
    };
    let calibration = calibration_or(override_, kind, size, || {
        let p = lists::parse_kitti_calib(&read_to_string(&calib_path)?, &calib_path)?;
        let (pinhole, baseline) = lists::kitti_stereo(&p, &calib_path)?;
        let camera = CameraIntrinsics::ideal(pinhole, size.0, size.1);
        Ok(match kind {
            SensorKind::Stereo => Calibration::RectifiedStereo { camera, baseline },
            _ => Calibration::Mono { camera },
        })
    })?;
    // Frames are named by index: the right image of frame i has the left one's file name.
    let frames_files: Vec<FrameFiles> = match &right_dir {
        None => left.iter().cloned().map(FrameFiles::Mono).collect(),
        Some(r) => left
            .iter()
            .map(|l| FrameFiles::Stereo(l.clone(), r.join(l.file_name().expect("a file"))))
            .collect(),
    };
    let times_path = root.join("times.txt");
    let times = if times_path.is_file() {
        let t = read_timestamps(&times_path)?;
        if t.len() != left.len() {
            return Err(DataError::File {
                path: times_path,
                kind: ParseErrorKind::CountMismatch {
                    what: "timestamps vs images in the left folder".into(),
                    expected: left.len(),
                    found: t.len(),
                },
            });
        }
        for k in 1..t.len() {
            if t[k] <= t[k - 1] {
                return Err(DataError::File {
                    path: times_path,
                    kind: ParseErrorKind::Expected {
                        expected: format!("increasing times (time {} is {} s)", k, t[k - 1]),
                        found: format!("time {} is {} s", k + 1, t[k]),
                    },
                });
            }
        }
        t
    } else {
        warnings.push(format!(
            "{}: no times.txt: frames are taken {KITTI_FRAME_INTERVAL} s apart (KITTI's 10 Hz)",
            root.display()
        ));
        (0..left.len())
            .map(|i| i as f64 * KITTI_FRAME_INTERVAL)
            .collect()
    };
    let frames: Vec<FrameSpec> = frames_files
        .into_iter()
        .zip(&times)
        .map(|(files, &timestamp)| FrameSpec {
            timestamp,
            files,
            world_from_camera: None,
        })
        .collect();
    let mut gt_candidates = vec![root.join("poses.txt")];
    if let (Some(name), Some(up)) = (root.file_name(), root.parent().and_then(Path::parent)) {
        gt_candidates.push(
            up.join("poses")
                .join(format!("{}.txt", name.to_string_lossy())),
        );
    }
    let ground_truth = match gt_candidates.into_iter().find(|p| p.is_file()) {
        None => None,
        Some(p) => {
            let poses = read_kitti(&p)?;
            if poses.len() != frames.len() {
                return Err(DataError::File {
                    path: p,
                    kind: ParseErrorKind::CountMismatch {
                        what: "poses vs frames".into(),
                        expected: frames.len(),
                        found: poses.len(),
                    },
                });
            }
            Some(GroundTruth {
                trajectory: Trajectory {
                    timestamps: times,
                    world_from_body: poses,
                },
                source: p,
            })
        }
    };
    Ok(Opened {
        calibration,
        frames,
        ground_truth,
        colour: false,
        warnings,
    })
}
