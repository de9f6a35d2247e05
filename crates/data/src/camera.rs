//! Camera calibrations as datasets state them, and the models of the images a reader delivers.
//!
//! * [`Calibration`]: the sensor as calibrated — one camera with lens distortion (mono,
//!   RGB-D), two cameras with their extrinsics (stereo, rectified by the reader), or an already
//!   rectified pair (KITTI).
//! * [`SensorModel`]: the camera of the images a [`Sequence`](crate::sequence::Sequence)
//!   delivers after undistortion and rectification: a [`PinholeCamera`], a rectified
//!   [`StereoCamera`] or an [`RgbdCamera`] (RGB-D as a virtual stereo camera, thesis §6.3).

use geom::{DistortedCamera, Equidistant, PinholeCamera, RadTan, RgbdCamera, StereoCamera};
use lie::Se3;

/// Lens distortion of a raw camera, on normalised image coordinates (see `geom::Distortion`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum LensDistortion {
    /// An ideal pinhole (or already undistorted images).
    None,
    /// Radial-tangential (OpenCV "plumb bob", EuRoC `radial-tangential`, TUM's `d0…d4`).
    RadTan(RadTan),
    /// Equidistant fisheye (Kannala-Brandt, EuRoC `equidistant`, ORB-SLAM3 `KannalaBrandt8`).
    Equidistant(Equidistant),
}

impl LensDistortion {
    /// `true` for [`LensDistortion::None`] or a model whose coefficients are all zero.
    pub fn is_identity(&self) -> bool {
        match self {
            LensDistortion::None => true,
            LensDistortion::RadTan(d) => [d.k1, d.k2, d.p1, d.p2, d.k3] == [0.0; 5],
            LensDistortion::Equidistant(d) => [d.k1, d.k2, d.k3, d.k4] == [0.0; 4],
        }
    }
}

/// One physical camera: pinhole intrinsics (pixels), lens distortion and image size.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CameraIntrinsics {
    /// `f_x, f_y, c_x, c_y` of the raw images.
    pub pinhole: PinholeCamera,
    /// The lens distortion of the raw images.
    pub distortion: LensDistortion,
    /// Image width in pixels.
    pub width: usize,
    /// Image height in pixels.
    pub height: usize,
}

impl CameraIntrinsics {
    /// A camera without distortion.
    pub fn ideal(pinhole: PinholeCamera, width: usize, height: usize) -> Self {
        CameraIntrinsics {
            pinhole,
            distortion: LensDistortion::None,
            width,
            height,
        }
    }
}

/// How depth images encode depth.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DepthCalibration {
    /// Metres per raw unit: `1/5000` for TUM RGB-D ("depth scale 5000"), `1/1000` for
    /// millimetres (7-Scenes, most Kinect and RealSense recordings).
    pub metres_per_unit: f64,
    /// Raw values `≥` this are invalid (7-Scenes writes 65535 for no measurement); `0` is always
    /// invalid.
    pub max_valid_raw: u16,
    /// Baseline of the virtual stereo camera, metres (thesis §6.3; see [`RgbdCamera`]).
    pub virtual_baseline: f64,
}

/// Baseline of the virtual right camera of an RGB-D sensor, metres: the projector–camera
/// distance of a Kinect-like structured-light sensor (≈ 7.5 cm), so that virtual disparities
/// have the magnitude the sensor's own triangulation has (geom's [`RgbdCamera`] docs).
pub const DEFAULT_VIRTUAL_BASELINE: f64 = 0.075;

/// The sensor as calibrated, before the reader undistorts or rectifies anything.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Calibration {
    /// One camera.
    Mono {
        /// The camera.
        camera: CameraIntrinsics,
    },
    /// Two cameras with their extrinsics: the reader rectifies the pair
    /// ([`crate::sequence::rectify`]).
    Stereo {
        /// The left camera.
        left: CameraIntrinsics,
        /// The right camera.
        right: CameraIntrinsics,
        /// `x_right = right_from_left · x_left`.
        right_from_left: Se3,
    },
    /// An already rectified pair (KITTI): both images share `camera`, the right optical centre
    /// lies `baseline` metres along the left camera's `x` axis.
    RectifiedStereo {
        /// The shared camera (no distortion).
        camera: CameraIntrinsics,
        /// Metres.
        baseline: f64,
    },
    /// A colour camera with a registered depth image of the same size.
    Rgbd {
        /// The colour camera (the depth image is registered to it).
        camera: CameraIntrinsics,
        /// How depth is encoded.
        depth: DepthCalibration,
    },
}

impl Calibration {
    /// The (left, colour) camera.
    pub fn primary(&self) -> &CameraIntrinsics {
        match self {
            Calibration::Mono { camera }
            | Calibration::RectifiedStereo { camera, .. }
            | Calibration::Rgbd { camera, .. } => camera,
            Calibration::Stereo { left, .. } => left,
        }
    }
}

/// The camera of the images a reader delivers (undistorted and, for stereo, rectified).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum SensorModel {
    /// Monocular.
    Mono(PinholeCamera),
    /// Rectified stereo: left image pinhole and baseline.
    Stereo(StereoCamera),
    /// Colour + registered depth, as a virtual stereo camera.
    Rgbd(RgbdCamera),
}

impl SensorModel {
    /// The pinhole of the (left, colour) image.
    pub fn pinhole(&self) -> &PinholeCamera {
        match self {
            SensorModel::Mono(p) => p,
            SensorModel::Stereo(s) => &s.pinhole,
            SensorModel::Rgbd(r) => &r.stereo.pinhole,
        }
    }

    /// `"mono"`, `"stereo"` or `"rgbd"`.
    pub fn kind(&self) -> SensorKind {
        match self {
            SensorModel::Mono(_) => SensorKind::Mono,
            SensorModel::Stereo(_) => SensorKind::Stereo,
            SensorModel::Rgbd(_) => SensorKind::Rgbd,
        }
    }
}

/// Which kind of sensor a sequence or camera file describes.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum SensorKind {
    /// One camera.
    Mono,
    /// Two cameras.
    Stereo,
    /// Colour and depth.
    Rgbd,
}

impl std::fmt::Display for SensorKind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            SensorKind::Mono => "mono",
            SensorKind::Stereo => "stereo",
            SensorKind::Rgbd => "rgbd",
        })
    }
}

/// The distorted camera model of a raw camera, for `vision::undistort::UndistortMap`.
pub(crate) enum RawCamera {
    RadTan(DistortedCamera<RadTan>),
    Equidistant(DistortedCamera<Equidistant>),
}

impl RawCamera {
    pub(crate) fn of(c: &CameraIntrinsics) -> RawCamera {
        match c.distortion {
            LensDistortion::None => RawCamera::RadTan(DistortedCamera::new(
                c.pinhole,
                RadTan::new(0.0, 0.0, 0.0, 0.0),
            )),
            LensDistortion::RadTan(d) => RawCamera::RadTan(DistortedCamera::new(c.pinhole, d)),
            LensDistortion::Equidistant(d) => {
                RawCamera::Equidistant(DistortedCamera::new(c.pinhole, d))
            }
        }
    }
}
