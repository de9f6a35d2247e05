//! TUM RGB-D layout (`rgb.txt`, `depth.txt`, `groundtruth.txt`) and its 7-Scenes variant
//! (`camera-intrinsics.txt`, depth in millimetres with 65535 = invalid, `groundtruth_tum.txt`).
//!
//! Colour and depth images are associated by timestamp as TUM's `associate.py` does
//! ([`associate_unique`], offset 0, at most 0.02 s apart); colour frames without a depth image
//! are delivered with `depth: None` (7-Scenes ships depth for even frames only). Without a
//! `depth.txt` the sequence is monocular.

use super::common::{calibration_or, check_sorted, image_has_colour, image_size, ordered};
use super::lists;
use super::types::{BadFramePolicy, FrameFiles, FrameSpec, GroundTruth, OpenOptions, Opened};
use crate::camera::{
    Calibration, CameraIntrinsics, DEFAULT_VIRTUAL_BASELINE, DepthCalibration, LensDistortion,
    SensorKind,
};
use crate::camera_file::{CameraFile, read_camera_file};
use crate::error::{DataError, ParseErrorKind};
use crate::text::read_to_string;
use crate::trajectory::{associate_unique, read_tum};
use geom::{PinholeCamera, RadTan};
use std::path::Path;

/// TUM RGB-D depth images store 5000 units per metre.
pub const TUM_DEPTH_UNITS_PER_METRE: f64 = 5000.0;
/// 7-Scenes (Kinect) depth images store millimetres.
const MILLIMETRES_PER_METRE: f64 = 1000.0;
/// `associate.py`'s default `--max_difference`, seconds.
pub const TUM_ASSOCIATION_MAX_DIFFERENCE: f64 = 0.02;

/// The calibrations TUM publishes for its colour cameras.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum TumCamera {
    /// Freiburg 1 (`fr1`).
    Freiburg1,
    /// Freiburg 2 (`fr2`).
    Freiburg2,
    /// Freiburg 3 (`fr3`, factory-undistorted).
    Freiburg3,
    /// The ROS default (`525, 525, 319.5, 239.5`), TUM's advice for unknown cameras.
    RosDefault,
}

/// The colour camera of a TUM sensor (640×480): intrinsics and `d0…d4 = k1 k2 p1 p2 k3`, as
/// listed on the TUM RGB-D "file formats / intrinsic calibration" page.
pub fn tum_camera(camera: TumCamera) -> CameraIntrinsics {
    let (k, d): ([f64; 4], [f64; 5]) = match camera {
        TumCamera::Freiburg1 => (
            [517.3, 516.5, 318.6, 255.3],
            [0.2624, -0.9531, -0.0054, 0.0026, 1.1633],
        ),
        TumCamera::Freiburg2 => (
            [520.9, 521.0, 325.1, 249.7],
            [0.2312, -0.7849, -0.0033, -0.0001, 0.9172],
        ),
        TumCamera::Freiburg3 => ([535.4, 539.2, 320.1, 247.6], [0.0; 5]),
        TumCamera::RosDefault => ([525.0, 525.0, 319.5, 239.5], [0.0; 5]),
    };
    let mut r = RadTan::new(d[0], d[1], d[2], d[3]);
    r.k3 = d[4];
    CameraIntrinsics {
        pinhole: PinholeCamera::new(k[0], k[1], k[2], k[3]),
        distortion: if d == [0.0; 5] {
            LensDistortion::None
        } else {
            LensDistortion::RadTan(r)
        },
        width: 640,
        height: 480,
    }
}

/// The TUM camera a folder name names (`…freiburg1…`, `…fr2…`), token by token.
pub(crate) fn camera_from_name(root: &Path) -> Option<TumCamera> {
    let name = root
        .canonicalize()
        .ok()
        .and_then(|p| p.file_name().map(|n| n.to_string_lossy().to_lowercase()))
        .or_else(|| root.file_name().map(|n| n.to_string_lossy().to_lowercase()))?;
    name.split(|c: char| !c.is_ascii_alphanumeric())
        .find_map(|t| match t {
            "fr1" | "freiburg1" => Some(TumCamera::Freiburg1),
            "fr2" | "freiburg2" => Some(TumCamera::Freiburg2),
            "fr3" | "freiburg3" => Some(TumCamera::Freiburg3),
            _ => None,
        })
}

pub(crate) fn open(
    root: &Path,
    options: &OpenOptions,
    override_: Option<(&Path, &CameraFile)>,
) -> Result<Opened, DataError> {
    let mut warnings = Vec::new();
    let rgb_list = root.join("rgb.txt");
    let policy: BadFramePolicy = options.on_bad_frame;
    let rgb = ordered(
        lists::parse_tum_list(&read_to_string(&rgb_list)?, &rgb_list)?,
        &rgb_list,
        policy,
        &mut warnings,
    )?;
    let depth_list = root.join("depth.txt");
    let depth = if depth_list.is_file() {
        Some(ordered(
            lists::parse_tum_list(&read_to_string(&depth_list)?, &depth_list)?,
            &depth_list,
            policy,
            &mut warnings,
        )?)
    } else {
        None
    };
    let first = rgb
        .iter()
        .map(|e| root.join(&e.file))
        .find(|p| p.is_file())
        .ok_or_else(|| DataError::File {
            path: rgb_list.clone(),
            kind: ParseErrorKind::Expected {
                expected: "at least one listed image that exists".into(),
                found: "none of them".into(),
            },
        })?;
    let size = image_size(&first)?;
    let colour = image_has_colour(&first);
    let seven_scenes = root.join("camera-intrinsics.txt");
    let kind = if depth.is_some() {
        SensorKind::Rgbd
    } else {
        SensorKind::Mono
    };
    // A `camera.yaml` beside `rgb.txt` (what `dwslam render` writes; TUM itself publishes its
    // calibrations on its web page) is the sequence's own calibration; `--camera` overrides it.
    let own_file = match override_ {
        Some(_) => None,
        None => {
            let p = root.join("camera.yaml");
            if p.is_file() {
                let c = read_camera_file(&p)?;
                Some((p, c))
            } else {
                None
            }
        }
    };
    let override_ = override_.or(own_file.as_ref().map(|(p, c)| (p.as_path(), c)));
    let calibration = calibration_or(override_, kind, size, || {
        let (camera, units_per_metre) = if seven_scenes.is_file() {
            let k = lists::parse_intrinsics_matrix(&read_to_string(&seven_scenes)?, &seven_scenes)?;
            (
                CameraIntrinsics::ideal(k, size.0, size.1),
                MILLIMETRES_PER_METRE,
            )
        } else {
            let which = camera_from_name(root).unwrap_or_else(|| {
                warnings.push(format!(
                    "{}: the folder name names no Freiburg camera (fr1, fr2, fr3): using TUM's \
                     ROS-default intrinsics 525/525/319.5/239.5 (give --camera to override)",
                    root.display()
                ));
                TumCamera::RosDefault
            });
            let mut c = tum_camera(which);
            (c.width, c.height) = size;
            (c, TUM_DEPTH_UNITS_PER_METRE)
        };
        Ok(match kind {
            SensorKind::Rgbd => Calibration::Rgbd {
                camera,
                depth: DepthCalibration {
                    metres_per_unit: 1.0 / units_per_metre,
                    max_valid_raw: u16::MAX,
                    virtual_baseline: DEFAULT_VIRTUAL_BASELINE,
                },
            },
            _ => Calibration::Mono { camera },
        })
    })?;
    let frames: Vec<FrameSpec> = match &depth {
        None => rgb
            .iter()
            .map(|e| FrameSpec {
                timestamp: e.timestamp,
                files: FrameFiles::Mono(root.join(&e.file)),
                world_from_camera: None,
            })
            .collect(),
        Some(depth) => {
            let a: Vec<f64> = rgb.iter().map(|e| e.timestamp).collect();
            let b: Vec<f64> = depth.iter().map(|e| e.timestamp).collect();
            let mut paired = vec![None; rgb.len()];
            for (i, j) in associate_unique(&a, &b, 0.0, TUM_ASSOCIATION_MAX_DIFFERENCE) {
                paired[i] = Some(root.join(&depth[j].file));
            }
            rgb.iter()
                .zip(paired)
                .map(|(e, d)| FrameSpec {
                    timestamp: e.timestamp,
                    files: FrameFiles::Rgbd(root.join(&e.file), d),
                    world_from_camera: None,
                })
                .collect()
        }
    };
    let gt_path = ["groundtruth.txt", "groundtruth_tum.txt"]
        .iter()
        .map(|n| root.join(n))
        .find(|p| p.is_file());
    let ground_truth = match gt_path {
        None => None,
        Some(p) => {
            let t = read_tum(&p)?;
            check_sorted(&t, &p)?;
            if seven_scenes.is_file() {
                warnings.push(
                    "7-Scenes ground truth is the depth camera's pose (KinectFusion); the colour \
                     camera sits a few centimetres away"
                        .into(),
                );
            }
            Some(GroundTruth {
                trajectory: t,
                source: p,
            })
        }
    };
    Ok(Opened {
        calibration,
        frames,
        ground_truth,
        colour,
        warnings,
    })
}
