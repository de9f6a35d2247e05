//! What the format readers share when they open a sequence: the error of a file that is not
//! what was expected ([`expected`]), the calibration override ([`calibration_or`]), image
//! headers ([`image_size`], [`image_has_colour`]), time order of lists and ground truth
//! ([`ordered`], [`check_sorted`]), and image folders ([`list_images`], [`stem_time`]). A leaf:
//! it imports none of the format readers.

use super::lists;
use super::types::BadFramePolicy;
use crate::camera::Calibration;
use crate::camera_file::CameraFile;
use crate::error::{DataError, ParseErrorKind};
use crate::trajectory::Trajectory;
use std::path::{Path, PathBuf};

pub(crate) fn expected(
    path: &Path,
    expected: impl Into<String>,
    found: impl Into<String>,
) -> DataError {
    DataError::File {
        path: path.to_path_buf(),
        kind: ParseErrorKind::Expected {
            expected: expected.into(),
            found: found.into(),
        },
    }
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

pub(crate) fn check_sorted(t: &Trajectory, path: &Path) -> Result<(), DataError> {
    for k in 1..t.timestamps.len() {
        if t.timestamps[k] <= t.timestamps[k - 1] {
            return Err(DataError::File {
                path: path.to_path_buf(),
                kind: ParseErrorKind::Expected {
                    expected: format!(
                        "increasing timestamps (pose {} at {} s)",
                        k - 1,
                        t.timestamps[k - 1]
                    ),
                    found: format!("pose {k} at {} s", t.timestamps[k]),
                },
            });
        }
    }
    Ok(())
}

/// Image file extensions read.
const IMAGE_EXTENSIONS: [&str; 6] = ["png", "jpg", "jpeg", "pgm", "ppm", "pnm"];

pub(crate) fn is_image(p: &Path) -> bool {
    p.is_file()
        && p.extension()
            .and_then(|e| e.to_str())
            .is_some_and(|e| IMAGE_EXTENSIONS.contains(&e.to_ascii_lowercase().as_str()))
}

/// Seconds encoded in a file stem, if it is a time (see the `folder` module docs).
pub(crate) fn stem_time(p: &Path) -> Option<f64> {
    let v: f64 = p.file_stem()?.to_str()?.parse().ok()?;
    if !v.is_finite() || v < 1e9 {
        return None;
    }
    Some(if v >= 1e15 { v / 1e9 } else { v })
}

pub(crate) fn list_images(dir: &Path) -> Result<Vec<PathBuf>, DataError> {
    let mut v: Vec<PathBuf> = std::fs::read_dir(dir)
        .map_err(|source| DataError::Io {
            path: dir.to_path_buf(),
            source,
        })?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| is_image(p))
        .collect();
    if v.iter().all(|p| stem_time(p).is_some()) {
        v.sort_by(|a, b| {
            stem_time(a)
                .unwrap_or(0.0)
                .total_cmp(&stem_time(b).unwrap_or(0.0))
        });
    } else {
        v.sort();
    }
    if v.is_empty() {
        return Err(DataError::File {
            path: dir.to_path_buf(),
            kind: ParseErrorKind::Empty {
                expected: "image files (.png, .jpg, .pgm, .ppm)".into(),
            },
        });
    }
    Ok(v)
}
