//! Camera files: dwslam's own camera YAML (version 1) and ORB-SLAM3 settings files.
//!
//! # dwslam camera YAML, version 1
//!
//! ```yaml
//! dwslam_camera: 1          # format version (required; this reader reads 1)
//! sensor: stereo            # mono | stereo | rgbd
//! fps: 20                   # optional: frame rate, for image folders without times.txt
//! left:                     # `camera:` for mono and rgbd, `left:` (+ `right:`) for stereo
//!   width: 752
//!   height: 480
//!   fx: 458.654
//!   fy: 457.296
//!   cx: 367.215
//!   cy: 248.375
//!   distortion:             # optional; omitted = ideal pinhole (undistorted images)
//!     model: radtan         # radtan: [k1, k2, p1, p2] or [k1, k2, p1, p2, k3]
//!     coefficients: [-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05]
//!                           # equidistant: [k1, k2, k3, k4]
//! right: { width: 752, height: 480, fx: 457.587, fy: 456.134, cx: 379.999, cy: 255.238 }
//! right_from_left:          # unrectified stereo: x_right = R·x_left + t
//!   rotation: [1, 0, 0, 0, 1, 0, 0, 0, 1]   # row-major 3×3
//!   translation: [-0.11, 0, 0]              # metres
//! # baseline: 0.537         # instead of right/right_from_left: already rectified images
//! # depth:                  # rgbd only
//! #   units_per_metre: 5000 # TUM 5000, millimetres 1000
//! #   max_valid_raw: 65535  # optional (default 65535): raw values ≥ this are invalid; 0 always is
//! #   virtual_baseline: 0.075  # optional, metres (thesis §6.3)
//! ```
//!
//! Unknown keys are errors (a misspelt key must not be silently ignored).
//!
//! # ORB-SLAM3 settings
//!
//! Both styles: the old `Camera.fx … Camera.k3, Camera.bf, DepthMapFactor` (with optional
//! `LEFT.*`/`RIGHT.*` OpenCV rectification matrices) and the version-1.0 `Camera1.fx …`,
//! `Camera2.*`, `Stereo.T_c1_c2` (`!!opencv-matrix`, `c1_from_c2`), `Stereo.b`,
//! `RGBD.DepthMapFactor`, `Camera.type: "PinHole" | "KannalaBrandt8" | "Rectified"`. The
//! `%YAML:1.0` directive of OpenCV files is replaced by a blank line before parsing (YAML 1.2
//! parsers reject it); other keys (ORB extractor, viewer) are ignored, as ORB-SLAM3 does.
//! ORB-SLAM3 files do not say which sensor they are for (its executable does); the folder
//! layout decides.

use crate::camera::{
    Calibration, CameraIntrinsics, DEFAULT_VIRTUAL_BASELINE, DepthCalibration, LensDistortion,
    SensorKind,
};
use crate::error::{DataError, ParseErrorKind};
use crate::text::read_to_string;
use geom::{Equidistant, PinholeCamera, RadTan};
use lie::{LieGroup, Se3};
use nalgebra::{Matrix3, Matrix4, Vector3};
use serde::Deserialize;
use serde::de::DeserializeOwned;
use std::path::Path;

/// The version of dwslam's camera YAML this reader reads.
pub const CAMERA_YAML_VERSION: u32 = 1;

/// Tolerance on `max |RᵀR − I|` for rotations in camera files: the EuRoC `T_BS` matrices are
/// orthonormal to ~1e-9, but hand-written settings files often print 6–7 digits (as KITTI
/// does), which leaves ~1e-5.
pub const CAMERA_ROTATION_TOLERANCE: f64 = 1e-4;

/// Which kind of file a camera file was.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CameraFileStyle {
    /// dwslam's camera YAML (this version).
    Dwslam,
    /// ORB-SLAM3 (and ORB-SLAM2) settings with `Camera.fx` keys.
    OrbSlamCamera,
    /// ORB-SLAM3 1.0 settings with `Camera1.fx` keys.
    OrbSlamCamera1,
}

/// A parsed camera file; [`CameraFile::calibration`] turns it into a [`Calibration`] for the
/// sensor the folder layout shows.
#[derive(Clone, Debug, PartialEq)]
pub struct CameraFile {
    /// The style of the file.
    pub style: CameraFileStyle,
    /// The sensor the file states (dwslam YAML); `None` for ORB-SLAM3 files.
    pub sensor: Option<SensorKind>,
    /// Image size `(width, height)` if the file gives it.
    pub size: Option<(usize, usize)>,
    /// The (left, colour) camera.
    pub left: (PinholeCamera, LensDistortion),
    /// The right camera of an unrectified stereo pair.
    pub right: Option<(PinholeCamera, LensDistortion)>,
    /// Extrinsics of an unrectified stereo pair, `x_right = right_from_left·x_left`.
    pub right_from_left: Option<Se3>,
    /// Baseline of already rectified stereo images (metres).
    pub baseline: Option<f64>,
    /// Depth encoding (RGB-D).
    pub depth: Option<DepthCalibration>,
    /// Frame rate, if given.
    pub fps: Option<f64>,
}

fn file_error(path: &Path, expected: impl Into<String>, found: impl Into<String>) -> DataError {
    DataError::File {
        path: path.to_path_buf(),
        kind: ParseErrorKind::Expected {
            expected: expected.into(),
            found: found.into(),
        },
    }
}

impl CameraFile {
    /// The calibration of a `kind` sensor with images of `size` (used when the file gives no
    /// size); `path` names the file in errors.
    pub fn calibration(
        &self,
        kind: SensorKind,
        size: (usize, usize),
        path: &Path,
    ) -> Result<Calibration, DataError> {
        if let Some(stated) = self.sensor
            && stated != kind
        {
            return Err(file_error(
                path,
                format!("a {kind} camera (the folder holds {kind} images)"),
                format!("sensor: {stated}"),
            ));
        }
        let (width, height) = self.size.unwrap_or(size);
        let camera = |(pinhole, distortion): (PinholeCamera, LensDistortion)| CameraIntrinsics {
            pinhole,
            distortion,
            width,
            height,
        };
        let left = camera(self.left);
        Ok(match kind {
            SensorKind::Mono => Calibration::Mono { camera: left },
            SensorKind::Rgbd => Calibration::Rgbd {
                camera: left,
                depth: self.depth.ok_or_else(|| {
                    file_error(
                        path,
                        "the depth encoding of an RGB-D camera (dwslam: depth.units_per_metre; \
                         ORB-SLAM3: RGBD.DepthMapFactor or DepthMapFactor)",
                        "none",
                    )
                })?,
            },
            SensorKind::Stereo => match (self.right, self.right_from_left, self.baseline) {
                (Some(right), Some(right_from_left), _) => Calibration::Stereo {
                    left,
                    right: camera(right),
                    right_from_left,
                },
                (_, _, Some(baseline)) => {
                    if !left.distortion.is_identity() {
                        return Err(file_error(
                            path,
                            "no distortion for already rectified stereo images (baseline given)",
                            "distortion coefficients",
                        ));
                    }
                    Calibration::RectifiedStereo {
                        camera: left,
                        baseline,
                    }
                }
                _ => {
                    return Err(file_error(
                        path,
                        "a stereo calibration: the right camera and right_from_left (unrectified), \
                         or a baseline (rectified)",
                        "only one camera",
                    ));
                }
            },
        })
    }
}

/// Reads a camera file (dwslam YAML or ORB-SLAM3 settings, told apart by their keys).
pub fn read_camera_file(path: impl AsRef<Path>) -> Result<CameraFile, DataError> {
    let path = path.as_ref();
    parse_camera_file(&read_to_string(path)?, path)
}

/// Parses a camera file's text; `path` only names the source in errors.
pub fn parse_camera_file(text: &str, path: &Path) -> Result<CameraFile, DataError> {
    let body = strip_yaml_directive(text);
    let is_dwslam = body
        .lines()
        .any(|l| l.trim_start().starts_with("dwslam_camera"));
    if is_dwslam {
        parse_dwslam(&body, path)
    } else if body.contains("Camera1.fx") || body.contains("Camera.fx") {
        parse_orb_slam(&body, path)
    } else {
        Err(file_error(
            path,
            "a camera file: dwslam YAML (`dwslam_camera: 1`) or ORB-SLAM3 settings \
             (`Camera.fx` or `Camera1.fx`)",
            "neither key",
        ))
    }
}

/// Replaces an OpenCV `%YAML:1.0` (or `%YAML 1.0`) directive on the first line by a blank line,
/// keeping line numbers; YAML 1.2 parsers reject the 1.0 directive.
pub(crate) fn strip_yaml_directive(text: &str) -> String {
    let text = text.strip_prefix('\u{feff}').unwrap_or(text);
    match text.split_once('\n') {
        Some((first, rest)) if first.trim_start().starts_with("%YAML") => format!("\n{rest}"),
        None if text.trim_start().starts_with("%YAML") => String::new(),
        _ => text.to_string(),
    }
}

/// Deserialises YAML text (already stripped of its directive) into `T`, turning the parser's
/// error into a [`DataError`] at its line.
pub(crate) fn from_yaml<T: DeserializeOwned>(body: &str, path: &Path) -> Result<T, DataError> {
    serde_saphyr::from_str(body).map_err(|e| {
        let location = e.location();
        let text = e.without_snippet().to_string();
        let first = text.lines().next().unwrap_or("").trim();
        let first = first.strip_prefix("error:").unwrap_or(first).trim();
        // "line L column C: message" → "column C: message" (the line goes into the error).
        let message = match first.strip_prefix("line ").and_then(|r| r.split_once(' ')) {
            Some((_, rest)) if location.is_some() => rest.trim().to_string(),
            _ => first.to_string(),
        };
        match location {
            Some(loc) if loc.line() > 0 => DataError::Parse {
                path: path.to_path_buf(),
                line: loc.line() as usize,
                kind: ParseErrorKind::Yaml { message },
            },
            _ => DataError::File {
                path: path.to_path_buf(),
                kind: ParseErrorKind::Yaml { message },
            },
        }
    })
}

fn finite(path: &Path, what: &str, v: f64) -> Result<f64, DataError> {
    if v.is_finite() {
        Ok(v)
    } else {
        Err(DataError::File {
            path: path.to_path_buf(),
            kind: ParseErrorKind::NotFinite {
                field: what.into(),
                text: v.to_string(),
            },
        })
    }
}

fn positive(path: &Path, what: &str, v: f64) -> Result<f64, DataError> {
    finite(path, what, v)?;
    if v > 0.0 {
        Ok(v)
    } else {
        Err(file_error(path, format!("{what} > 0"), v.to_string()))
    }
}

fn pinhole(path: &Path, prefix: &str, v: [f64; 4]) -> Result<PinholeCamera, DataError> {
    Ok(PinholeCamera::new(
        positive(path, &format!("{prefix}fx"), v[0])?,
        positive(path, &format!("{prefix}fy"), v[1])?,
        finite(path, &format!("{prefix}cx"), v[2])?,
        finite(path, &format!("{prefix}cy"), v[3])?,
    ))
}

/// `x_b = R·x_a + t` from a row-major 3×3 rotation and a translation, validated.
pub(crate) fn se3_from_parts(
    path: &Path,
    what: &str,
    rotation: &[f64],
    translation: &[f64],
) -> Result<Se3, DataError> {
    if rotation.len() != 9 || translation.len() != 3 {
        return Err(file_error(
            path,
            format!("{what}: 9 rotation entries and 3 translation entries"),
            format!("{} and {}", rotation.len(), translation.len()),
        ));
    }
    let mut m = Matrix4::identity();
    m.fixed_view_mut::<3, 3>(0, 0)
        .copy_from(&Matrix3::from_row_slice(rotation));
    m.fixed_view_mut::<3, 1>(0, 3)
        .copy_from(&Vector3::from_row_slice(translation));
    se3_from_matrix(path, what, &m)
}

pub(crate) fn se3_from_matrix(path: &Path, what: &str, m: &Matrix4<f64>) -> Result<Se3, DataError> {
    Se3::from_matrix_with_tolerance(m, CAMERA_ROTATION_TOLERANCE).map_err(|source| {
        DataError::File {
            path: path.to_path_buf(),
            kind: ParseErrorKind::InvalidRotation {
                what: what.into(),
                source,
            },
        }
    })
}

pub(crate) fn distortion_from(
    path: &Path,
    model: &str,
    c: &[f64],
) -> Result<LensDistortion, DataError> {
    for (i, v) in c.iter().enumerate() {
        finite(path, &format!("distortion coefficient {}", i + 1), *v)?;
    }
    match (model, c.len()) {
        ("radtan" | "radial-tangential" | "plumb_bob" | "pinhole", 4) => {
            Ok(LensDistortion::RadTan(RadTan::new(c[0], c[1], c[2], c[3])))
        }
        ("radtan" | "radial-tangential" | "plumb_bob" | "pinhole", 5) => {
            let mut d = RadTan::new(c[0], c[1], c[2], c[3]);
            d.k3 = c[4];
            Ok(LensDistortion::RadTan(d))
        }
        ("equidistant" | "kannala-brandt" | "fisheye", 4) => Ok(LensDistortion::Equidistant(
            Equidistant::new(c[0], c[1], c[2], c[3]),
        )),
        ("none", 0) => Ok(LensDistortion::None),
        _ => Err(file_error(
            path,
            "distortion model radtan with 4 or 5 coefficients (k1 k2 p1 p2 [k3]), equidistant \
             with 4 (k1 k2 k3 k4), or none",
            format!("{model} with {} coefficients", c.len()),
        )),
    }
}

// ---------------------------------------------------------------------------------------------
// dwslam YAML

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct DwslamYaml {
    dwslam_camera: u32,
    sensor: SensorKind,
    fps: Option<f64>,
    camera: Option<DwslamCamera>,
    left: Option<DwslamCamera>,
    right: Option<DwslamCamera>,
    right_from_left: Option<DwslamPose>,
    baseline: Option<f64>,
    depth: Option<DwslamDepth>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct DwslamCamera {
    width: usize,
    height: usize,
    fx: f64,
    fy: f64,
    cx: f64,
    cy: f64,
    distortion: Option<DwslamDistortion>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct DwslamDistortion {
    model: String,
    coefficients: Vec<f64>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct DwslamPose {
    rotation: Vec<f64>,
    translation: Vec<f64>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct DwslamDepth {
    units_per_metre: f64,
    max_valid_raw: Option<u16>,
    virtual_baseline: Option<f64>,
}

fn parse_dwslam(body: &str, path: &Path) -> Result<CameraFile, DataError> {
    let y: DwslamYaml = from_yaml(body, path)?;
    if y.dwslam_camera != CAMERA_YAML_VERSION {
        return Err(file_error(
            path,
            format!("dwslam_camera: {CAMERA_YAML_VERSION} (the version this dwslam reads)"),
            format!("dwslam_camera: {}", y.dwslam_camera),
        ));
    }
    let (key, primary) = match (y.sensor, y.camera, y.left) {
        (SensorKind::Stereo, None, Some(l)) => ("left.", l),
        (SensorKind::Mono | SensorKind::Rgbd, Some(c), None) => ("camera.", c),
        (s, _, _) => {
            let want = if s == SensorKind::Stereo {
                "`left:` (and no `camera:`)"
            } else {
                "`camera:` (and no `left:`)"
            };
            return Err(file_error(
                path,
                format!("for sensor {s} the camera under {want}"),
                "another arrangement",
            ));
        }
    };
    let camera =
        |key: &str, c: &DwslamCamera| -> Result<(PinholeCamera, LensDistortion), DataError> {
            let p = pinhole(path, key, [c.fx, c.fy, c.cx, c.cy])?;
            let d = match &c.distortion {
                None => LensDistortion::None,
                Some(d) => distortion_from(path, &d.model, &d.coefficients)?,
            };
            if c.width == 0 || c.height == 0 {
                return Err(file_error(
                    path,
                    format!("{key}width and {key}height > 0"),
                    format!("{}×{}", c.width, c.height),
                ));
            }
            Ok((p, d))
        };
    let left = camera(key, &primary)?;
    let right = y.right.as_ref().map(|c| camera("right.", c)).transpose()?;
    if let Some(r) = &y.right
        && (r.width, r.height) != (primary.width, primary.height)
    {
        return Err(file_error(
            path,
            format!(
                "right image size = left ({}×{})",
                primary.width, primary.height
            ),
            format!("{}×{}", r.width, r.height),
        ));
    }
    let right_from_left = y
        .right_from_left
        .as_ref()
        .map(|p| se3_from_parts(path, "right_from_left", &p.rotation, &p.translation))
        .transpose()?;
    let baseline = y
        .baseline
        .map(|b| positive(path, "baseline", b))
        .transpose()?;
    let depth = match y.depth {
        None => None,
        Some(d) => Some(DepthCalibration {
            metres_per_unit: 1.0 / positive(path, "depth.units_per_metre", d.units_per_metre)?,
            max_valid_raw: d.max_valid_raw.unwrap_or(u16::MAX),
            virtual_baseline: d
                .virtual_baseline
                .map(|b| positive(path, "depth.virtual_baseline", b))
                .transpose()?
                .unwrap_or(DEFAULT_VIRTUAL_BASELINE),
        }),
    };
    if y.sensor == SensorKind::Rgbd && depth.is_none() {
        return Err(file_error(
            path,
            "a `depth:` section for sensor rgbd",
            "none",
        ));
    }
    if y.sensor == SensorKind::Stereo
        && baseline.is_none()
        && (right.is_none() || right_from_left.is_none())
    {
        return Err(file_error(
            path,
            "for sensor stereo: `right:` and `right_from_left:`, or `baseline:`",
            "neither",
        ));
    }
    Ok(CameraFile {
        style: CameraFileStyle::Dwslam,
        sensor: Some(y.sensor),
        size: Some((primary.width, primary.height)),
        left,
        right,
        right_from_left,
        baseline,
        depth,
        fps: y.fps.map(|f| positive(path, "fps", f)).transpose()?,
    })
}

// ---------------------------------------------------------------------------------------------
// ORB-SLAM3 settings

#[derive(Deserialize)]
struct CvMatrix {
    rows: usize,
    cols: usize,
    data: Vec<f64>,
}

macro_rules! orb_settings {
    ($($field:ident = $key:literal),* $(,)?) => {
        #[derive(Deserialize, Default)]
        struct OrbSettings {
            $(#[serde(rename = $key, default)] $field: Option<f64>,)*
            #[serde(rename = "Camera.type", default)]
            camera_type: Option<String>,
            #[serde(rename = "Stereo.T_c1_c2", default)]
            t_c1_c2: Option<CvMatrix>,
            #[serde(rename = "LEFT.K", default)]
            left_k: Option<CvMatrix>,
            #[serde(rename = "LEFT.D", default)]
            left_d: Option<CvMatrix>,
            #[serde(rename = "LEFT.R", default)]
            left_r: Option<CvMatrix>,
            #[serde(rename = "RIGHT.K", default)]
            right_k: Option<CvMatrix>,
            #[serde(rename = "RIGHT.D", default)]
            right_d: Option<CvMatrix>,
            #[serde(rename = "RIGHT.R", default)]
            right_r: Option<CvMatrix>,
            #[serde(rename = "RIGHT.P", default)]
            right_p: Option<CvMatrix>,
        }
    };
}

orb_settings! {
    fx = "Camera.fx", fy = "Camera.fy", cx = "Camera.cx", cy = "Camera.cy",
    k1 = "Camera.k1", k2 = "Camera.k2", p1 = "Camera.p1", p2 = "Camera.p2", k3 = "Camera.k3",
    k4 = "Camera.k4",
    c1_fx = "Camera1.fx", c1_fy = "Camera1.fy", c1_cx = "Camera1.cx", c1_cy = "Camera1.cy",
    c1_k1 = "Camera1.k1", c1_k2 = "Camera1.k2", c1_p1 = "Camera1.p1", c1_p2 = "Camera1.p2",
    c1_k3 = "Camera1.k3", c1_k4 = "Camera1.k4",
    c2_fx = "Camera2.fx", c2_fy = "Camera2.fy", c2_cx = "Camera2.cx", c2_cy = "Camera2.cy",
    c2_k1 = "Camera2.k1", c2_k2 = "Camera2.k2", c2_p1 = "Camera2.p1", c2_p2 = "Camera2.p2",
    c2_k3 = "Camera2.k3", c2_k4 = "Camera2.k4",
    width = "Camera.width", height = "Camera.height", fps = "Camera.fps", bf = "Camera.bf",
    stereo_b = "Stereo.b", depth_factor = "DepthMapFactor", rgbd_depth_factor = "RGBD.DepthMapFactor",
    left_width = "LEFT.width", left_height = "LEFT.height",
}

fn cv_matrix(
    path: &Path,
    key: &str,
    m: &CvMatrix,
    rows: usize,
    cols: usize,
) -> Result<Vec<f64>, DataError> {
    if m.rows != rows || m.cols != cols || m.data.len() != rows * cols {
        return Err(file_error(
            path,
            format!("{key}: a {rows}×{cols} matrix with {} entries", rows * cols),
            format!("{}×{} with {} entries", m.rows, m.cols, m.data.len()),
        ));
    }
    for v in &m.data {
        finite(path, key, *v)?;
    }
    Ok(m.data.clone())
}

fn orb_camera(
    path: &Path,
    prefix: &str,
    camera_type: &str,
    v: [Option<f64>; 10],
) -> Result<(PinholeCamera, LensDistortion), DataError> {
    let need = |i: usize, name: &str| {
        v[i].ok_or_else(|| file_error(path, format!("{prefix}{name}"), "missing"))
    };
    let p = pinhole(
        path,
        prefix,
        [
            need(0, "fx")?,
            need(1, "fy")?,
            need(2, "cx")?,
            need(3, "cy")?,
        ],
    )?;
    let c = |i: usize| v[i].unwrap_or(0.0);
    let d = match camera_type {
        "KannalaBrandt8" => {
            let k: Vec<f64> = [4, 5, 8, 9].iter().map(|&i| c(i)).collect();
            distortion_from(path, "equidistant", &k)?
        }
        "Rectified" => LensDistortion::None,
        _ => {
            let k: Vec<f64> = [4, 5, 6, 7, 8].iter().map(|&i| c(i)).collect();
            distortion_from(path, "radtan", &k)?
        }
    };
    Ok((p, d))
}

fn parse_orb_slam(body: &str, path: &Path) -> Result<CameraFile, DataError> {
    let s: OrbSettings = from_yaml(body, path)?;
    let camera_type = s.camera_type.clone().unwrap_or_else(|| "PinHole".into());
    if !["PinHole", "KannalaBrandt8", "Rectified"].contains(&camera_type.as_str()) {
        return Err(file_error(
            path,
            "Camera.type PinHole, KannalaBrandt8 or Rectified",
            camera_type,
        ));
    }
    let new_style = s.c1_fx.is_some();
    let (left, right) = if new_style {
        let left = orb_camera(
            path,
            "Camera1.",
            &camera_type,
            [
                s.c1_fx, s.c1_fy, s.c1_cx, s.c1_cy, s.c1_k1, s.c1_k2, s.c1_p1, s.c1_p2, s.c1_k3,
                s.c1_k4,
            ],
        )?;
        let right = s
            .c2_fx
            .map(|_| {
                orb_camera(
                    path,
                    "Camera2.",
                    &camera_type,
                    [
                        s.c2_fx, s.c2_fy, s.c2_cx, s.c2_cy, s.c2_k1, s.c2_k2, s.c2_p1, s.c2_p2,
                        s.c2_k3, s.c2_k4,
                    ],
                )
            })
            .transpose()?;
        (left, right)
    } else {
        let left = orb_camera(
            path,
            "Camera.",
            &camera_type,
            [s.fx, s.fy, s.cx, s.cy, s.k1, s.k2, s.p1, s.p2, s.k3, s.k4],
        )?;
        (left, None)
    };
    let size = match (s.width.or(s.left_width), s.height.or(s.left_height)) {
        (Some(w), Some(h)) => {
            let ok = |v: f64| v >= 1.0 && v.fract() == 0.0 && v < 1e6;
            if !ok(w) || !ok(h) {
                return Err(file_error(
                    path,
                    "Camera.width and Camera.height: positive integers",
                    format!("{w}×{h}"),
                ));
            }
            Some((w as usize, h as usize))
        }
        _ => None,
    };
    let mut right_from_left = None;
    let mut right = right;
    let mut left = left;
    if let Some(t) = &s.t_c1_c2 {
        let m = Matrix4::from_row_slice(&cv_matrix(path, "Stereo.T_c1_c2", t, 4, 4)?);
        right_from_left = Some(se3_from_matrix(path, "Stereo.T_c1_c2", &m)?.inverse());
    } else if let (Some(lk), Some(ld), Some(lr), Some(rk), Some(rd), Some(rr), Some(rp)) = (
        &s.left_k, &s.left_d, &s.left_r, &s.right_k, &s.right_d, &s.right_r, &s.right_p,
    ) {
        // ORB-SLAM2-style precomputed OpenCV rectification: R_l, R_r rotate each camera into
        // the rectified frame, P_r = K'[I | (−f·b, 0, 0)]. The pair's extrinsics follow:
        // x_r = R_rᵀ(R_l·x_l − (b, 0, 0)); dwslam recomputes its own rectification from them.
        let k = |key: &str, m: &CvMatrix| cv_matrix(path, key, m, 3, 3);
        let d = |key: &str, m: &CvMatrix| -> Result<LensDistortion, DataError> {
            let n = m.rows * m.cols;
            if m.data.len() != n || !(n == 4 || n == 5) {
                return Err(file_error(
                    path,
                    format!("{key}: 4 or 5 coefficients"),
                    n.to_string(),
                ));
            }
            distortion_from(path, "radtan", &m.data)
        };
        let (lk, rk) = (k("LEFT.K", lk)?, k("RIGHT.K", rk)?);
        left = (
            pinhole(path, "LEFT.K ", [lk[0], lk[4], lk[2], lk[5]])?,
            d("LEFT.D", ld)?,
        );
        right = Some((
            pinhole(path, "RIGHT.K ", [rk[0], rk[4], rk[2], rk[5]])?,
            d("RIGHT.D", rd)?,
        ));
        let rl = Matrix3::from_row_slice(&k("LEFT.R", lr)?);
        let rr = Matrix3::from_row_slice(&k("RIGHT.R", rr)?);
        let p = cv_matrix(path, "RIGHT.P", rp, 3, 4)?;
        let b = -p[3] / positive(path, "RIGHT.P[0,0]", p[0])?;
        let rotation = rr.transpose() * rl;
        let translation = -(rr.transpose() * Vector3::new(b, 0.0, 0.0));
        let r: Vec<f64> = (0..9).map(|i| rotation[(i / 3, i % 3)]).collect();
        right_from_left = Some(se3_from_parts(
            path,
            "RIGHT.R·LEFT.Rᵀ",
            &r,
            translation.as_slice(),
        )?);
    }
    let fx = left.0.fx;
    let baseline = match (s.stereo_b, s.bf) {
        (Some(b), _) => Some(positive(path, "Stereo.b", b)?),
        (None, Some(bf)) => Some(positive(path, "Camera.bf", bf)? / fx),
        _ => None,
    };
    let depth = match s.rgbd_depth_factor.or(s.depth_factor) {
        None => None,
        Some(f) => Some(DepthCalibration {
            metres_per_unit: 1.0 / positive(path, "DepthMapFactor", f)?,
            max_valid_raw: u16::MAX,
            virtual_baseline: baseline.unwrap_or(DEFAULT_VIRTUAL_BASELINE),
        }),
    };
    Ok(CameraFile {
        style: if new_style {
            CameraFileStyle::OrbSlamCamera1
        } else {
            CameraFileStyle::OrbSlamCamera
        },
        sensor: None,
        size,
        left,
        right,
        right_from_left,
        baseline,
        depth,
        fps: s.fps.map(|f| positive(path, "Camera.fps", f)).transpose()?,
    })
}
