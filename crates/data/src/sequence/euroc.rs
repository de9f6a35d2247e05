//! EuRoC MAV (ASL) layout: `mav0/cam0/{data.csv, data/, sensor.yaml}`, the same for `cam1`,
//! ground truth in `mav0/state_groundtruth_estimate0/data.csv`.
//!
//! Left and right images are paired by equal timestamps (the cameras are hardware-triggered).
//! The stereo extrinsics are `right_from_left = T_BS(cam1)⁻¹ · T_BS(cam0)` (each `T_BS` is
//! `body_from_sensor`). Ground truth is the body (IMU) pose `world_from_body` (after removing the
//! ground-truth sensor's own `T_BS`); the left camera's is `world_from_body · T_BS(cam0)`, and
//! the reader rotates it into the rectified left camera.

use super::common::{calibration_or, check_sorted, ordered};
use super::lists;
use super::types::{FrameFiles, FrameSpec, GroundTruth, OpenOptions, Opened};
use crate::camera::{Calibration, CameraIntrinsics, SensorKind};
use crate::camera_file::CameraFile;
use crate::error::DataError;
use crate::text::read_to_string;
use crate::trajectory::read_euroc_groundtruth;
use lie::LieGroup;
use std::collections::HashMap;
use std::path::{Path, PathBuf};

/// The `mav0` folder: `root/mav0` or `root` itself.
pub(crate) fn mav_dir(root: &Path) -> Option<PathBuf> {
    [root.join("mav0"), root.to_path_buf()]
        .into_iter()
        .find(|m| m.join("cam0").join("data.csv").is_file())
}

fn camera(dir: &Path) -> Result<(CameraIntrinsics, lie::Se3), DataError> {
    let p = dir.join("sensor.yaml");
    let y = lists::parse_euroc_camera_yaml(&read_to_string(&p)?, &p)?;
    Ok((
        CameraIntrinsics {
            pinhole: y.pinhole,
            distortion: y.distortion,
            width: y.resolution.0,
            height: y.resolution.1,
        },
        y.body_from_sensor,
    ))
}

pub(crate) fn open(
    root: &Path,
    options: &OpenOptions,
    override_: Option<(&Path, &CameraFile)>,
) -> Result<Opened, DataError> {
    let mav = mav_dir(root).ok_or_else(|| DataError::File {
        path: root.to_path_buf(),
        kind: crate::ParseErrorKind::Expected {
            expected: "a EuRoC layout: mav0/cam0/data.csv".into(),
            found: "no such file".into(),
        },
    })?;
    let mut warnings = Vec::new();
    let list =
        |cam: &str, warnings: &mut Vec<String>| -> Result<Vec<lists::ListEntry>, DataError> {
            let p = mav.join(cam).join("data.csv");
            ordered(
                lists::parse_euroc_image_list(&read_to_string(&p)?, &p)?,
                &p,
                options.on_bad_frame,
                warnings,
            )
        };
    let left = list("cam0", &mut warnings)?;
    let stereo = mav.join("cam1").join("data.csv").is_file();
    let (cam0, body_from_cam0) = camera(&mav.join("cam0"))?;
    let size = (cam0.width, cam0.height);
    let mut frames = Vec::new();
    let calibration;
    if stereo {
        let right = list("cam1", &mut warnings)?;
        let (cam1, body_from_cam1) = camera(&mav.join("cam1"))?;
        let right_from_left = body_from_cam1.inverse().compose(&body_from_cam0);
        calibration = calibration_or(override_, SensorKind::Stereo, size, || {
            Ok(Calibration::Stereo {
                left: cam0,
                right: cam1,
                right_from_left,
            })
        })?;
        // EuRoC rows carry nanosecond stamps; compare them as printed in seconds exactly
        // (both lists went through the same ns → s conversion).
        let by_time: HashMap<u64, &lists::ListEntry> =
            right.iter().map(|e| (e.timestamp.to_bits(), e)).collect();
        let mut unpaired = 0;
        for e in &left {
            match by_time.get(&e.timestamp.to_bits()) {
                Some(r) => frames.push(FrameSpec {
                    timestamp: e.timestamp,
                    files: FrameFiles::Stereo(
                        mav.join("cam0").join("data").join(&e.file),
                        mav.join("cam1").join("data").join(&r.file),
                    ),
                    world_from_camera: None,
                }),
                None => unpaired += 1,
            }
        }
        if unpaired > 0 {
            warnings.push(format!(
                "{unpaired} cam0 rows have no cam1 row with the same timestamp and were left out"
            ));
        }
    } else {
        calibration = calibration_or(override_, SensorKind::Mono, size, || {
            Ok(Calibration::Mono { camera: cam0 })
        })?;
        frames = left
            .iter()
            .map(|e| FrameSpec {
                timestamp: e.timestamp,
                files: FrameFiles::Mono(mav.join("cam0").join("data").join(&e.file)),
                world_from_camera: None,
            })
            .collect();
    }
    let gt_dir = mav.join("state_groundtruth_estimate0");
    let gt_path = gt_dir.join("data.csv");
    let ground_truth = if gt_path.is_file() {
        let mut t = read_euroc_groundtruth(&gt_path)?;
        check_sorted(&t, &gt_path)?;
        let sensor_yaml = gt_dir.join("sensor.yaml");
        let body_from_gt = if sensor_yaml.is_file() {
            lists::parse_euroc_body_from_sensor(&read_to_string(&sensor_yaml)?, &sensor_yaml)?
        } else {
            lie::Se3::identity()
        };
        // world_from_cam0 = world_from_gt · gt_from_body · body_from_cam0
        let gt_from_cam0 = body_from_gt.inverse().compose(&body_from_cam0);
        for p in &mut t.world_from_body {
            *p = p.compose(&gt_from_cam0);
        }
        Some(GroundTruth {
            trajectory: t,
            source: gt_path,
        })
    } else {
        None
    };
    Ok(Opened {
        calibration,
        frames,
        ground_truth,
        colour: false,
        warnings,
    })
}
