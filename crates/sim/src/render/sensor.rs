//! Sensors: how radiance becomes the images a real camera delivers — pinhole mono, rectified
//! stereo, RGB-D — with photon and read noise, optional exposure changes, motion blur along the
//! motion during the exposure, vignetting, and for RGB-D a depth image with Kinect-like noise
//! growing with depth² and holes at grazing angles and beyond the range.
//!
//! Image formation: `I = 255 · g(t) · v(u, v) · L` where `L` is the rendered radiance (the
//! average of the exposure's sub-frames under motion blur), `g(t)` the exposure gain and
//! `v(u, v) = 1 − k·r²/r²_max` the vignetting; then noise of variance `σ_r² + κ·I` (read
//! noise and shot noise, the affine noise model of machine-vision sensors, EMVA 1288) and
//! rounding to `u8` with saturation.

use super::RenderError;
use super::camera::RenderCamera;
use super::procedural::{hash1, mix64, unit};
use super::raycast::Pixel;
use lie::Se3;
use nalgebra::Vector3;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};
use rayon::prelude::*;
use vision::image::{GrayImage, Image};

/// Which images a sensor delivers.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum SensorKind {
    /// One grey camera.
    Mono,
    /// A rectified grey stereo pair: the right camera is the left one moved by `baseline`
    /// metres along its `x` axis (disparity `u_l − u_r = f_x·b/z`).
    Stereo {
        /// Baseline (m).
        baseline: f64,
    },
    /// A colour camera with a registered depth image (TUM convention: depth `z` along the
    /// optical axis, in metres here; 0 = no measurement).
    Rgbd,
}

/// Photon and read noise: variance `σ_r² + κ·I` in grey levels².
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ImageNoise {
    /// Read noise `σ_r` (grey levels).
    pub read_sigma: f64,
    /// Shot-noise factor `κ` (grey levels per grey level).
    pub shot: f64,
}

impl Default for ImageNoise {
    /// `σ_r = 1`, `κ = 0.02`: σ ≈ 1.9 grey levels at mid grey, the noise of a VGA machine-vision
    /// camera at moderate gain (EuRoC's MT9V034 shows 1.5–2.5 levels in flat regions).
    fn default() -> Self {
        ImageNoise {
            read_sigma: 1.0,
            shot: 0.02,
        }
    }
}

/// Kinect-like depth errors.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DepthNoise {
    /// `σ_z = k·z²` (m), `k` in 1/m: 1.425·10⁻³ for the Kinect v1 (Khoshelham & Elberink 2012:
    /// 1.4 mm at 1 m, 3.6 cm at 5 m).
    pub sigma_per_m2: f64,
    /// No depth where the ray meets the surface more obliquely than this (degrees from the
    /// normal): the projected pattern is too stretched there.
    pub max_incidence_deg: f64,
    /// No depth beyond this range (m).
    pub max_range: f64,
}

impl Default for DepthNoise {
    fn default() -> Self {
        DepthNoise {
            sigma_per_m2: 1.425e-3,
            max_incidence_deg: 78.0,
            max_range: 8.0,
        }
    }
}

/// Slow changes of the exposure gain (an auto-exposure hunting):
/// `g(t) = exp(a·(0.6 sin(2πt/11 s + φ₁) + 0.4 sin(2πt/4.3 s + φ₂)))`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ExposureChanges {
    /// `a`: the gain varies within `exp(±a)`.
    pub amplitude: f64,
}

impl Default for ExposureChanges {
    /// ±30 %.
    fn default() -> Self {
        ExposureChanges {
            amplitude: 0.3f64.ln_1p(),
        }
    }
}

/// Motion blur: the image is the mean of `steps` sub-frames at poses spread evenly over the
/// exposure time, centred on the frame's timestamp.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MotionBlur {
    /// Exposure time (s).
    pub exposure: f64,
    /// Number of sub-frames (odd, so that the middle one is at the timestamp; depth comes from
    /// it).
    pub steps: usize,
}

impl Default for MotionBlur {
    /// 10 ms (indoor hand-held exposures are 5–20 ms), 5 sub-frames.
    fn default() -> Self {
        MotionBlur {
            exposure: 0.01,
            steps: 5,
        }
    }
}

/// The default stereo baseline, metres: EuRoC's VI-sensor (0.11 m), a typical small rig, so
/// that a room's 1–4 m give disparities of 14–58 px at f = 525 px.
pub const DEFAULT_STEREO_BASELINE: f64 = 0.11;

/// A sensor: kind, camera, image formation and its imperfections.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SensorModel {
    /// Mono, stereo or RGB-D.
    pub kind: SensorKind,
    /// The (left) camera.
    pub camera: RenderCamera,
    /// Supersampling grid per axis at silhouettes (1 turns anti-aliasing of edges off;
    /// textures stay mip-mapped).
    pub supersampling: usize,
    /// Nominal exposure gain: grey level `255·gain` for radiance 1.
    pub gain: f64,
    /// Vignetting `k`: brightness falls by `k` at the image corners.
    pub vignetting: f64,
    /// Image noise (`None`: noise-free).
    pub noise: Option<ImageNoise>,
    /// Depth noise and holes for RGB-D (`None`: exact depth everywhere a surface is hit).
    pub depth_noise: Option<DepthNoise>,
    /// Exposure changes (`None`: constant gain).
    pub exposure_changes: Option<ExposureChanges>,
    /// Motion blur (`None`: instantaneous exposure).
    pub motion_blur: Option<MotionBlur>,
}

impl SensorModel {
    /// A sensor of `kind` with the default camera for `width × height`, 3×3 supersampling at
    /// silhouettes, gain 0.85, 10 % vignetting, default image noise, default depth noise for
    /// RGB-D, no exposure changes, no motion blur.
    pub fn new(kind: SensorKind, width: usize, height: usize) -> Self {
        SensorModel {
            kind,
            camera: RenderCamera::default_for_size(width, height),
            supersampling: 3,
            gain: 0.85,
            vignetting: 0.1,
            noise: Some(ImageNoise::default()),
            depth_noise: (kind == SensorKind::Rgbd).then(DepthNoise::default),
            exposure_changes: None,
            motion_blur: None,
        }
    }

    /// The same sensor with every imperfection off: no noise, exact depth, constant gain, no
    /// blur, no vignetting (for the geometric tests).
    pub fn ideal(mut self) -> Self {
        self.noise = None;
        self.depth_noise = None;
        self.exposure_changes = None;
        self.motion_blur = None;
        self.vignetting = 0.0;
        self
    }

    /// Checks the parameters' ranges.
    pub fn validate(&self) -> Result<(), RenderError> {
        self.camera.validate()?;
        let bad = |name, reason: String| Err(RenderError::InvalidParameter { name, reason });
        if let SensorKind::Stereo { baseline } = self.kind
            && !(baseline > 0.0 && baseline.is_finite())
        {
            return bad("baseline", format!("must be positive, got {baseline}"));
        }
        if !(1..=8).contains(&self.supersampling) {
            return bad(
                "supersampling",
                format!("must be 1…8, got {}", self.supersampling),
            );
        }
        if !(self.gain > 0.0 && self.gain.is_finite()) {
            return bad("gain", format!("must be positive, got {}", self.gain));
        }
        if !(0.0..1.0).contains(&self.vignetting) {
            return bad(
                "vignetting",
                format!("must be in [0, 1), got {}", self.vignetting),
            );
        }
        if let Some(n) = self.noise
            && !(n.read_sigma >= 0.0 && n.shot >= 0.0)
        {
            return bad("noise", format!("σ and κ must be ≥ 0, got {n:?}"));
        }
        if let Some(b) = self.motion_blur
            && (b.steps == 0
                || b.steps.is_multiple_of(2)
                || !(b.exposure >= 0.0 && b.exposure < 1.0))
        {
            return bad(
                "motion blur",
                format!("needs an odd number of steps and an exposure in [0, 1) s, got {b:?}"),
            );
        }
        if let Some(d) = self.depth_noise
            && !(d.sigma_per_m2 >= 0.0
                && d.max_range > 0.0
                && (0.0..=90.0).contains(&d.max_incidence_deg))
        {
            return bad("depth noise", format!("out of range: {d:?}"));
        }
        Ok(())
    }

    /// The exposure gain at time `t` for a sequence of seed `seed`.
    pub fn gain_at(&self, seed: u64, t: f64) -> f64 {
        let Some(e) = self.exposure_changes else {
            return self.gain;
        };
        let (p1, p2) = (
            std::f64::consts::TAU * unit(hash1(seed, 0xe1)),
            std::f64::consts::TAU * unit(hash1(seed, 0xe2)),
        );
        let tau = std::f64::consts::TAU;
        self.gain
            * (e.amplitude * (0.6 * (tau * t / 11.0 + p1).sin() + 0.4 * (tau * t / 4.3 + p2).sin()))
                .exp()
    }

    /// `camera_from_world` of the right camera of a stereo pair whose left camera is at
    /// `left_camera_from_world`: `T_rw = T_rl·T_lw` with `T_rl` the translation `(−b, 0, 0)`.
    pub fn right_from_left(baseline: f64) -> Se3 {
        Se3::from_translation(Vector3::new(-baseline, 0.0, 0.0))
    }
}

/// The images of one frame.
#[derive(Debug, Clone, PartialEq)]
pub enum FrameImages {
    /// One grey image.
    Mono(GrayImage),
    /// A rectified grey stereo pair.
    Stereo {
        /// Left image.
        left: GrayImage,
        /// Right image.
        right: GrayImage,
    },
    /// Colour and registered depth (`z` in metres, 0 = no measurement).
    Rgbd {
        /// Colour image.
        rgb: Image<[u8; 3]>,
        /// Depth image.
        depth: Image<f32>,
    },
}

/// Seeds of the noise streams: per frame, view and row, so rows can be processed in parallel
/// with the same result.
fn row_rng(seed: u64, frame: usize, view: u64, row: usize) -> ChaCha8Rng {
    ChaCha8Rng::seed_from_u64(row_seed(seed, frame, view, row))
}

fn row_seed(seed: u64, frame: usize, view: u64, row: usize) -> u64 {
    hash1(hash1(hash1(seed, frame as u64), view), row as u64)
}

/// An approximately standard-normal number from a 64-bit hash: the Irwin–Hall sum of four
/// 16-bit uniforms, centred and scaled to unit variance (kurtosis 2.7 instead of 3, tails cut
/// at ±3.46σ) — a third of the cost of a ziggurat draw from a stream cipher, which matters
/// at 10⁶ pixels per frame; image noise needs no more.
#[inline(always)]
fn normal_from_hash(h: u64) -> f32 {
    let sum = (h & 0xffff) + ((h >> 16) & 0xffff) + ((h >> 32) & 0xffff) + (h >> 48);
    // Each uniform has mean 0.5 and variance 1/12 (in units of 65536): the sum of four has
    // mean 2 and variance 1/3.
    ((sum as f32 + 2.0) * (1.0 / 65536.0) - 2.0) * 3f32.sqrt()
}

/// Turns radiance into `channels`-channel 8-bit pixels (see the module notes).
pub(crate) fn expose(
    sensor: &SensorModel,
    radiance: &[[f32; 3]],
    channels: usize,
    gain: f64,
    seed: u64,
    frame: usize,
    view: u64,
) -> Vec<u8> {
    let (w, h) = (sensor.camera.width, sensor.camera.height);
    let mut out = vec![0u8; w * h * channels];
    let (cx, cy) = ((w as f64 - 1.0) / 2.0, (h as f64 - 1.0) / 2.0);
    let r2_max = cx * cx + cy * cy;
    // σ of the noise per grey level (a table instead of a square root per pixel; the variance
    // follows the noise-free level rounded to an integer).
    let sigma: Vec<f32> = (0..=255)
        .map(|i| {
            sensor.noise.map_or(0.0, |n| {
                (n.read_sigma * n.read_sigma + n.shot * i as f64).sqrt() as f32
            })
        })
        .collect();
    out.par_chunks_mut(w * channels)
        .enumerate()
        .for_each(|(v, row)| {
            let row_key = row_seed(seed, frame, view, v);
            let dy = v as f64 - cy;
            for u in 0..w {
                let dx = u as f64 - cx;
                let vig = 1.0 - sensor.vignetting * (dx * dx + dy * dy) / r2_max;
                let k = (255.0 * gain * vig) as f32;
                for c in 0..channels {
                    let mut i = radiance[v * w + u][c] * k;
                    if sensor.noise.is_some() {
                        let z = normal_from_hash(mix64(row_key ^ ((u * channels + c) as u64)));
                        i += sigma[i.clamp(0.0, 255.0) as usize] * z;
                    }
                    // Round half up (no libm call): clamp, then truncate i + ½.
                    row[u * channels + c] = (i.clamp(0.0, 255.0) + 0.5) as u8;
                }
            }
        });
    out
}

/// The depth image of an RGB-D frame from the centre hits, with the sensor's noise and holes.
pub(crate) fn depth_image(
    sensor: &SensorModel,
    pixels: &[Pixel],
    seed: u64,
    frame: usize,
) -> Image<f32> {
    let (w, h) = (sensor.camera.width, sensor.camera.height);
    let mut out = vec![0f32; w * h];
    out.par_chunks_mut(w).enumerate().for_each(|(v, row)| {
        let mut rng = row_rng(seed, frame, 0xde, v);
        for u in 0..w {
            let p = &pixels[v * w + u];
            let z = p.depth;
            row[u] = match sensor.depth_noise {
                None => z,
                Some(d) => {
                    let grazing = (p.cos_incidence as f64) < d.max_incidence_deg.to_radians().cos();
                    if z <= 0.0 || grazing || z as f64 > d.max_range {
                        0.0
                    } else {
                        let zn: f64 = StandardNormal.sample(&mut rng);
                        (z as f64 + d.sigma_per_m2 * (z as f64).powi(2) * zn).max(0.0) as f32
                    }
                }
            };
        }
    });
    Image::from_vec(w, h, w, out).expect("sized above")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hashed_normals_have_unit_variance() {
        let n = 200_000u64;
        let (mut sum, mut sq) = (0.0f64, 0.0f64);
        for i in 0..n {
            let z = normal_from_hash(mix64(i)) as f64;
            sum += z;
            sq += z * z;
        }
        assert!((sum / n as f64).abs() < 0.01);
        assert!((sq / n as f64 - 1.0).abs() < 0.01, "{}", sq / n as f64);
    }
}
