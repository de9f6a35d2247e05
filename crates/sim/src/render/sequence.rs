//! A rendered sequence: a world, a trajectory through it and a sensor, frame by frame, with the
//! ground-truth pose of the (left) camera at every frame's timestamp.

use super::camera::FOCAL_AT_640;
use super::paths::{BuildingWalk, CameraPath, CourtyardLaps, RoomBrowse, TownDrive};
use super::raycast::ViewOptions;
use super::sensor::{self, FrameImages, SensorKind, SensorModel};
use super::{RenderError, Renderer, worlds};
use data::camera::{DEFAULT_VIRTUAL_BASELINE, SensorModel as DataSensor};
use data::dataset_writer::{TUM_DEPTH_SCALE, tum_depth_value};
use data::sequence::{DepthImage, Frame as SequenceFrame, FrameImages as SequenceImages, luma};
use geom::{RgbdCamera, StereoCamera};
use lie::{LieGroup, Se3};
use vision::image::{GrayImage, Image};

/// The worlds with their trajectories.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SceneKind {
    /// The furnished room, browsed hand-held at 30 Hz (3000 frames, 100 s, by default).
    Room,
    /// The building's corridor loop, walked at 15 Hz (once around and 10 s beyond by default).
    Building,
    /// The courtyard, three laps at 20 Hz by default.
    Courtyard,
    /// The town, a 1.74 km drive with two loops at 10 Hz (as KITTI) from a car's forward
    /// camera with KITTI's image size and focal length.
    Town,
}

impl SceneKind {
    /// All scenes.
    pub const ALL: [SceneKind; 4] = [
        SceneKind::Room,
        SceneKind::Building,
        SceneKind::Courtyard,
        SceneKind::Town,
    ];

    /// The scene's name (`room`, `building`, `courtyard`, `town`).
    pub fn name(&self) -> &'static str {
        match self {
            SceneKind::Room => "room",
            SceneKind::Building => "building",
            SceneKind::Courtyard => "courtyard",
            SceneKind::Town => "town",
        }
    }

    /// Frame rate (Hz): 30 for the hand-held room (as TUM RGB-D); 15 for the building walk (the
    /// middle of the 10–20 Hz of walking and driving datasets: KITTI 10 Hz, EuRoC 20 Hz); 20 for
    /// the courtyard laps, whose default sensor is EuRoC-like stereo (at 15 Hz the ground's
    /// perspective change between frames, 9 cm of walk, pushed the translational LK's median
    /// error against the ground truth to 0.08–0.10 px on some pairs; 0.05–0.08 at 20 Hz); 10 for
    /// the town, KITTI's rate.
    pub fn rate_hz(&self) -> f64 {
        match self {
            SceneKind::Room => 30.0,
            SceneKind::Building => 15.0,
            SceneKind::Courtyard => 20.0,
            SceneKind::Town => 10.0,
        }
    }

    /// The default number of frames: the room 100 s; the building one loop and 10 s more (so the
    /// loop can be closed on the revisited stretch); the courtyard three laps; the town the whole
    /// drive of `seed` (its speeds are the seed's).
    pub fn default_frames(&self, seed: u64) -> usize {
        let rate = self.rate_hz();
        match self {
            SceneKind::Room => 3000,
            SceneKind::Building => {
                ((BuildingWalk::loop_length() / 1.3 + 10.0) * rate).ceil() as usize
            }
            SceneKind::Courtyard => {
                (3.0 * CourtyardLaps::lap_length() / 1.4 * rate).ceil() as usize
            }
            SceneKind::Town => (TownDrive::new(seed).duration() * rate).floor() as usize + 1,
        }
    }

    /// The scene's sensor of `kind` for `width × height` images: [`SensorModel::new`] with the
    /// scene's focal length ([`SceneKind::focal_length`]).
    pub fn sensor(&self, kind: SensorKind, width: usize, height: usize) -> SensorModel {
        let mut sensor = SensorModel::new(kind, width, height);
        let (f, p) = (self.focal_length(width), sensor.camera.pinhole);
        sensor.camera.pinhole = geom::PinholeCamera::new(f, f, p.cx, p.cy);
        sensor
    }

    /// The default image size: 640×480, KITTI's 1241×376 for the town.
    pub fn default_size(&self) -> (usize, usize) {
        match self {
            SceneKind::Town => (1241, 376),
            _ => (640, 480),
        }
    }

    /// The focal length (px) for an image `width` pixels wide: 525 at 640 (see
    /// [`RenderCamera::default_for_size`]) but for the town, KITTI's 707.09 px at 1241 (the
    /// odometry benchmark's sequences 04–10), a 82° horizontal field of view.
    pub fn focal_length(&self, width: usize) -> f64 {
        match self {
            SceneKind::Town => 707.0912 * width as f64 / 1241.0,
            _ => FOCAL_AT_640 * width as f64 / 640.0,
        }
    }
}

impl std::str::FromStr for SceneKind {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        SceneKind::ALL
            .into_iter()
            .find(|k| k.name() == s)
            .ok_or_else(|| {
                format!("unknown scene {s:?} (expected room, building, courtyard or town)")
            })
    }
}

/// What to render.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SequenceConfig {
    /// The world and trajectory.
    pub scene: SceneKind,
    /// The sensor.
    pub sensor: SensorModel,
    /// Seed of the textures, the trajectory's variations and the noise.
    pub seed: u64,
    /// Seed of the trajectory's variations alone, if not `seed`'s: the same world (textures)
    /// along another path — sessions of one place.
    pub path_seed: Option<u64>,
    /// Number of frames (`None`: the scene's default).
    pub frames: Option<usize>,
    /// Scale of the room browse's variation from visit to visit of a view (finite, ≥ 0): 1 is
    /// the default browsing, whose every revisit is about one keyframe-coverage radius from
    /// the last (a map of it keeps growing); smaller returns to nearly the same views, so the
    /// room can be fully mapped (see [`RoomBrowse::with_revisit_jitter`]). Only the room has
    /// it: the other scenes require 1.
    pub revisit_jitter: f64,
}

/// [`SequenceConfig::revisit_jitter`]'s default: the room browse as it was designed.
pub const DEFAULT_REVISIT_JITTER: f64 = 1.0;

/// Timestamp of the first frame (µs since the Unix epoch: 2023-11-14), so that the files look
/// like a recording's.
pub const START_US: u64 = 1_700_000_000_000_000;

/// One rendered frame.
#[derive(Debug, Clone, PartialEq)]
pub struct Frame {
    /// Frame index.
    pub index: usize,
    /// Timestamp (µs since the Unix epoch; the middle of the exposure).
    pub timestamp_us: u64,
    /// Ground truth: the (left) camera's pose at the timestamp, `world_from_camera`.
    pub world_from_camera: Se3,
    /// Exposure gain used.
    pub gain: f64,
    /// The images.
    pub images: FrameImages,
}

impl Frame {
    /// The frame as the sequence readers deliver it (`data::sequence::Frame`), so that the live
    /// system can run on frames rendered on the fly exactly as on the files `dwslam render`
    /// writes: colour as three planes with their luma, depth quantised as the TUM files store it
    /// (`1/5000` m, 0 = none), the timestamp in seconds, the ground truth attached. A frame read
    /// back from a written TUM or EuRoC sequence equals this one.
    pub fn to_sequence_frame(&self) -> SequenceFrame {
        let images = match &self.images {
            FrameImages::Mono(image) => SequenceImages::Mono {
                image: image.clone(),
                colour: None,
            },
            FrameImages::Stereo { left, right } => SequenceImages::Stereo {
                left: left.clone(),
                right: right.clone(),
            },
            FrameImages::Rgbd { rgb, depth } => {
                let planes = [0, 1, 2].map(|c| rgb.map(|p| p[c]));
                SequenceImages::Rgbd {
                    image: luma(&planes),
                    colour: Some(planes),
                    depth: Some(DepthImage {
                        raw: depth.map(tum_depth_value),
                        metres_per_unit: 1.0 / TUM_DEPTH_SCALE,
                        max_valid_raw: u16::MAX,
                    }),
                }
            }
        };
        SequenceFrame {
            index: self.index,
            timestamp: self.timestamp_us as f64 * 1e-6,
            images,
            world_from_camera: Some(self.world_from_camera),
        }
    }
}

impl SensorModel {
    /// The camera the live system is given for this sensor, as the sequence readers would
    /// report it for the written files (an RGB-D sensor as virtual stereo with the default
    /// baseline). `None` for a distorted camera: rendered frames are not undistorted on the
    /// fly (write them with `dwslam render` and read them back, which undistorts).
    pub fn sequence_camera(&self) -> Option<DataSensor> {
        if self.camera.distortion.is_some() {
            return None;
        }
        let pinhole = self.camera.pinhole;
        Some(match self.kind {
            SensorKind::Mono => DataSensor::Mono(pinhole),
            SensorKind::Stereo { baseline } => {
                DataSensor::Stereo(StereoCamera::new(pinhole, baseline))
            }
            SensorKind::Rgbd => {
                DataSensor::Rgbd(RgbdCamera::new(pinhole, DEFAULT_VIRTUAL_BASELINE))
            }
        })
    }
}

/// A sequence being rendered (see the module notes). Frames can be rendered in any order; the
/// result of frame `k` depends only on the configuration.
pub struct Sequence {
    config: SequenceConfig,
    renderer: Renderer,
    path: Box<dyn CameraPath>,
    frames: usize,
}

impl std::fmt::Debug for Sequence {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Sequence")
            .field("config", &self.config)
            .field("frames", &self.frames)
            .finish()
    }
}

/// Takes the images of frame `index` at time `t` (s) with `sensor`, the (left) camera moving
/// along `world_from_camera(t)`: every view (one, or two for stereo) rendered at the poses of
/// the exposure's sub-frames, averaged, exposed with the gain at `t` and the frame's noise
/// (seeded by `seed` and `index`). Returns the images and the gain used. The renderer's cache
/// is told the frame ended.
pub fn capture(
    renderer: &mut Renderer,
    sensor: &SensorModel,
    seed: u64,
    index: usize,
    t: f64,
    world_from_camera: &dyn Fn(f64) -> Se3,
) -> Result<(FrameImages, f64), RenderError> {
    sensor.validate()?;
    let gain = sensor.gain_at(seed, t);
    let (w, h) = (sensor.camera.width, sensor.camera.height);
    let colour = sensor.kind == SensorKind::Rgbd;
    let opts = ViewOptions {
        supersampling: sensor.supersampling,
        colour,
        depth: colour,
    };
    let (steps, exposure) = sensor
        .motion_blur
        .map_or((1, 0.0), |b| (b.steps, b.exposure));
    let views: Vec<Se3> = match sensor.kind {
        SensorKind::Stereo { baseline } => {
            vec![Se3::identity(), SensorModel::right_from_left(baseline)]
        }
        _ => vec![Se3::identity()],
    };
    let mut images = Vec::new();
    let mut depth = None;
    for (vi, right_from_left) in views.iter().enumerate() {
        let mut acc = vec![[0f32; 3]; w * h];
        for step in 0..steps {
            let ts = t + ((step as f64 + 0.5) / steps as f64 - 0.5) * exposure;
            let camera_from_world = right_from_left.compose(&world_from_camera(ts).inverse());
            let pixels = renderer.render(&sensor.camera, &camera_from_world, &opts)?;
            for (a, p) in acc.iter_mut().zip(&pixels) {
                for (x, r) in a.iter_mut().zip(&p.radiance) {
                    *x += r;
                }
            }
            if colour && step == steps / 2 {
                depth = Some(sensor::depth_image(sensor, &pixels, seed, index));
            }
        }
        if steps > 1 {
            let inv = 1.0 / steps as f32;
            for a in &mut acc {
                for c in a.iter_mut() {
                    *c *= inv;
                }
            }
        }
        let channels = if colour { 3 } else { 1 };
        images.push(sensor::expose(
            sensor, &acc, channels, gain, seed, index, vi as u64,
        ));
    }
    renderer.end_frame();
    let grey = |b: Vec<u8>| GrayImage::from_vec(w, h, w, b).expect("sized");
    let images = match sensor.kind {
        SensorKind::Mono => FrameImages::Mono(grey(images.remove(0))),
        SensorKind::Stereo { .. } => {
            let right = grey(images.remove(1));
            FrameImages::Stereo {
                left: grey(images.remove(0)),
                right,
            }
        }
        SensorKind::Rgbd => {
            let b = images.remove(0);
            let rgb: Vec<[u8; 3]> = b.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect();
            FrameImages::Rgbd {
                rgb: Image::from_vec(w, h, w, rgb).expect("sized"),
                depth: depth.expect("rendered at the middle step"),
            }
        }
    };
    Ok((images, gain))
}

impl Sequence {
    /// Builds the world and the trajectory; checks the configuration.
    pub fn new(config: SequenceConfig) -> Result<Self, RenderError> {
        config.sensor.validate()?;
        let frames = config
            .frames
            .unwrap_or_else(|| config.scene.default_frames(config.seed));
        if frames == 0 {
            return Err(RenderError::InvalidParameter {
                name: "frames",
                reason: "must be at least 1".into(),
            });
        }
        if config.scene != SceneKind::Room && config.revisit_jitter != DEFAULT_REVISIT_JITTER {
            return Err(RenderError::InvalidParameter {
                name: "revisit_jitter",
                reason: format!(
                    "only the room's browsing has revisit variation to scale; the {} needs {}",
                    config.scene.name(),
                    DEFAULT_REVISIT_JITTER
                ),
            });
        }
        let rate = config.scene.rate_hz();
        let duration = frames as f64 / rate;
        let path_seed = config.path_seed.unwrap_or(config.seed);
        let (scene, path): (_, Box<dyn CameraPath>) = match config.scene {
            SceneKind::Room => (
                worlds::room(config.seed),
                // Planned for the default length, so that frame k is the same whatever the
                // number of frames asked for (longer runs extend the plan).
                Box::new(RoomBrowse::with_revisit_jitter(
                    path_seed,
                    duration.max(100.0),
                    config.revisit_jitter,
                )?),
            ),
            SceneKind::Building => (
                worlds::building(config.seed),
                Box::new(BuildingWalk::new(path_seed)),
            ),
            SceneKind::Courtyard => (
                worlds::courtyard(config.seed),
                Box::new(CourtyardLaps::new(path_seed)),
            ),
            SceneKind::Town => (
                worlds::town(config.seed),
                Box::new(TownDrive::new(path_seed)),
            ),
        };
        Ok(Sequence {
            config,
            renderer: Renderer::new(scene),
            path,
            frames,
        })
    }

    /// The configuration.
    pub fn config(&self) -> &SequenceConfig {
        &self.config
    }

    /// Number of frames.
    pub fn len(&self) -> usize {
        self.frames
    }

    /// `true` for an empty sequence (never: at least one frame).
    pub fn is_empty(&self) -> bool {
        self.frames == 0
    }

    /// The renderer (scene and cache statistics).
    pub fn renderer(&self) -> &Renderer {
        &self.renderer
    }

    /// Timestamp of frame `k` (µs): `START_US + round(k·10⁶/rate)`.
    pub fn timestamp_us(&self, k: usize) -> u64 {
        START_US + (k as f64 * 1e6 / self.config.scene.rate_hz()).round() as u64
    }

    /// Seconds from the start of frame `k`'s timestamp (what the trajectory is evaluated at).
    pub fn time(&self, k: usize) -> f64 {
        (self.timestamp_us(k) - START_US) as f64 * 1e-6
    }

    /// Ground truth of frame `k`: the (left) camera's `world_from_camera` at its timestamp.
    pub fn world_from_camera(&self, k: usize) -> Se3 {
        self.path.world_from_camera(self.time(k))
    }

    /// The camera path.
    pub fn path(&self) -> &dyn CameraPath {
        self.path.as_ref()
    }

    /// Renders frame `k`.
    pub fn render_frame(&mut self, k: usize) -> Result<Frame, RenderError> {
        let t = self.time(k);
        let path = self.path.as_ref();
        let (images, gain) = capture(
            &mut self.renderer,
            &self.config.sensor,
            self.config.seed,
            k,
            t,
            &|ts| path.world_from_camera(ts),
        )?;
        Ok(Frame {
            index: k,
            timestamp_us: self.timestamp_us(k),
            world_from_camera: self.world_from_camera(k),
            gain,
            images,
        })
    }
}
