//! Image folders with a camera file (dwslam YAML or ORB-SLAM3 settings, see
//! [`crate::camera_file`]): the camera file is `camera.yaml` in the folder, the only `*.yaml` /
//! `*.yml` file there, or the one given with `--camera`.
//!
//! * stereo: `left/` and `right/`, paired by file name;
//! * RGB-D: `rgb/` and `depth/`, paired by equal file names, or by timestamp
//!   (`associate.py`'s rule) when the names are timestamps;
//! * mono: `images/`, or the images in the folder itself.
//!
//! Timestamps: `times.txt` (one per frame); else file names that are times (numbers ≥ 1e9:
//! seconds, or nanoseconds from 1e15 on, as ROS and EuRoC exports name them); else frame
//! `i / fps` with `fps` from the camera file; else `i` seconds (with a warning).

use super::common::{image_has_colour, image_size, list_images, stem_time};
use super::types::{FrameFiles, FrameSpec, OpenOptions, Opened};
use crate::camera::SensorKind;
use crate::camera_file::{CameraFile, read_camera_file};
use crate::error::{DataError, ParseErrorKind};
use crate::trajectory::{associate_unique, read_timestamps};
use std::path::{Path, PathBuf};

/// The folder's camera file, if it has one.
pub(crate) fn camera_file_in(root: &Path) -> Option<PathBuf> {
    let named = root.join("camera.yaml");
    if named.is_file() {
        return Some(named);
    }
    let yamls: Vec<PathBuf> = std::fs::read_dir(root)
        .ok()?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| {
            p.is_file()
                && p.extension()
                    .and_then(|e| e.to_str())
                    .is_some_and(|e| e == "yaml" || e == "yml")
        })
        .collect();
    (yamls.len() == 1).then(|| yamls[0].clone())
}

pub(crate) fn open(
    root: &Path,
    _options: &OpenOptions,
    override_: Option<(&Path, &CameraFile)>,
) -> Result<Opened, DataError> {
    let own;
    let (camera_path, camera): (&Path, &CameraFile) = match override_ {
        Some(c) => c,
        None => {
            let p = camera_file_in(root).ok_or_else(|| DataError::File {
                path: root.to_path_buf(),
                kind: ParseErrorKind::Expected {
                    expected: "a camera file (camera.yaml, a single *.yaml, or --camera)".into(),
                    found: "none".into(),
                },
            })?;
            own = (p.clone(), read_camera_file(&p)?);
            (own.0.as_path(), &own.1)
        }
    };
    let mut warnings = Vec::new();
    let dir = |n: &str| Some(root.join(n)).filter(|p| p.is_dir());
    let (kind, files): (SensorKind, Vec<FrameFiles>) = if let (Some(l), Some(r)) =
        (dir("left"), dir("right"))
    {
        let left = list_images(&l)?;
        let files = left
            .iter()
            .map(|p| FrameFiles::Stereo(p.clone(), r.join(p.file_name().expect("a file"))))
            .collect();
        (SensorKind::Stereo, files)
    } else if let (Some(c), Some(d)) = (dir("rgb"), dir("depth")) {
        let rgb = list_images(&c)?;
        let depth = list_images(&d)?;
        let mut paired: Vec<Option<PathBuf>> = vec![None; rgb.len()];
        let times = |v: &[PathBuf]| v.iter().map(|p| stem_time(p)).collect::<Option<Vec<f64>>>();
        if let (Some(a), Some(b)) = (times(&rgb), times(&depth)) {
            for (i, j) in associate_unique(&a, &b, 0.0, super::tum::TUM_ASSOCIATION_MAX_DIFFERENCE)
            {
                paired[i] = Some(depth[j].clone());
            }
        } else {
            for (i, p) in rgb.iter().enumerate() {
                let stem = p.file_stem();
                paired[i] = depth.iter().find(|q| q.file_stem() == stem).cloned();
            }
        }
        let files = rgb
            .into_iter()
            .zip(paired)
            .map(|(c, d)| FrameFiles::Rgbd(c, d))
            .collect();
        (SensorKind::Rgbd, files)
    } else {
        let images = dir("images").unwrap_or_else(|| root.to_path_buf());
        let files = list_images(&images)?
            .into_iter()
            .map(FrameFiles::Mono)
            .collect();
        (SensorKind::Mono, files)
    };
    let first = match &files[0] {
        FrameFiles::Mono(p) | FrameFiles::Stereo(p, _) | FrameFiles::Rgbd(p, _) => p.clone(),
    };
    let size = image_size(&first)?;
    let colour = image_has_colour(&first);
    let calibration = camera.calibration(kind, size, camera_path)?;
    let primary = |f: &FrameFiles| match f {
        FrameFiles::Mono(p) | FrameFiles::Stereo(p, _) | FrameFiles::Rgbd(p, _) => p.clone(),
    };
    let times_path = root.join("times.txt");
    let times: Vec<f64> = if times_path.is_file() {
        let t = read_timestamps(&times_path)?;
        if t.len() != files.len() {
            return Err(DataError::File {
                path: times_path,
                kind: ParseErrorKind::CountMismatch {
                    what: "timestamps vs images".into(),
                    expected: files.len(),
                    found: t.len(),
                },
            });
        }
        t
    } else if let Some(t) = files
        .iter()
        .map(|f| stem_time(&primary(f)))
        .collect::<Option<Vec<f64>>>()
    {
        t
    } else if let Some(fps) = camera.fps {
        (0..files.len()).map(|i| i as f64 / fps).collect()
    } else {
        warnings.push(format!(
            "{}: no times.txt, no timestamps in the file names and no fps in the camera file: \
             frame i is taken at i seconds",
            root.display()
        ));
        (0..files.len()).map(|i| i as f64).collect()
    };
    for k in 1..times.len() {
        if times[k] <= times[k - 1] {
            return Err(DataError::File {
                path: if times_path.is_file() {
                    times_path
                } else {
                    root.to_path_buf()
                },
                kind: ParseErrorKind::Expected {
                    expected: format!("increasing times (frame {} at {} s)", k - 1, times[k - 1]),
                    found: format!("frame {k} at {} s", times[k]),
                },
            });
        }
    }
    let frames = files
        .into_iter()
        .zip(times)
        .map(|(files, timestamp)| FrameSpec {
            timestamp,
            files,
            world_from_camera: None,
        })
        .collect();
    Ok(Opened {
        calibration,
        frames,
        ground_truth: None,
        colour,
        warnings,
    })
}
