//! Writers of the standard image-sequence layouts, laid out exactly as the real datasets are,
//! so that their readers take written sequences (rendered ones, or any others) unchanged:
//!
//! * [`TumWriter`]: TUM RGB-D — `rgb/<t>.png` (8-bit RGB), `depth/<t>.png` (16-bit, 5000 per
//!   metre, 0 = no depth), `rgb.txt`, `depth.txt`, `groundtruth.txt` (`t tx ty tz qx qy qz qw`,
//!   the colour camera in the world), with `t` in seconds with six decimals as TUM writes
//!   them; TUM publishes no calibration file (its readers take the Freiburg camera the folder
//!   name names, else the ROS default 525/525/319.5/239.5, which is also the renderer's camera
//!   at 640 × 480), so the calibration goes into `camera.yaml` in dwslam's camera YAML
//!   ([`crate::camera_file`]) beside it, for `--camera` when it is another.
//! * [`EurocWriter`]: EuRoC MAV (ASL) — `mav0/cam0` (and `cam1` for stereo) with `data/<ns>.png`
//!   (8-bit grey), `data.csv` (`#timestamp [ns],filename`) and `sensor.yaml` (`T_BS`,
//!   `rate_hz`, `resolution`, `intrinsics`, `distortion_coefficients`), `mav0/body.yaml`, and
//!   `mav0/state_groundtruth_estimate0/` with EuRoC's ground-truth CSV (body position,
//!   quaternion `w x y z`, velocity, zero biases) and its `sensor.yaml`. The body frame is
//!   cam0's (its `T_BS` is the identity; cam1's is the stereo baseline).
//! * [`KittiWriter`]: KITTI odometry — `image_0` (and `image_1`) with `NNNNNN.png` (8-bit grey),
//!   `calib.txt` with the labelled rows `P0:`…`P3:` and `Tr:`, `times.txt` (seconds) and
//!   `poses.txt` (camera 0 in the first frame's camera 0, row-major 3 × 4 per line, the first
//!   the identity). KITTI images are rectified: a distorted camera is refused. A mono sequence
//!   still states its rig's right camera in `P1` (as every KITTI `calib.txt` does); only
//!   `image_0` is written.
//!
//! Index and ground-truth lines are written (and flushed on [`finish`](TumWriter::finish)) as
//! frames arrive, so an interrupted run leaves consistent files up to its last frame. Poses
//! are printed so that they parse back to the same `f64` (Rust's shortest round-trip form).

use crate::camera::{CameraIntrinsics, LensDistortion};
use crate::text::fmt_f64;
use lie::{LieGroup, Se3};
use nalgebra::Vector3;
use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};
use vision::image::Image;

/// Errors of the writers.
#[derive(Debug, thiserror::Error)]
pub enum WriteError {
    /// A file or directory could not be created or written.
    #[error("{}: {source}", path.display())]
    Io {
        /// The file.
        path: PathBuf,
        /// The cause.
        #[source]
        source: std::io::Error,
    },
    /// An image could not be encoded.
    #[error("{}: cannot encode PNG: {source}", path.display())]
    Encode {
        /// The file.
        path: PathBuf,
        /// The encoder's error.
        #[source]
        source: image::ImageError,
    },
    /// The input does not fit the layout (image size, timestamps, calibration).
    #[error("{layout}: {reason}")]
    Invalid {
        /// The layout.
        layout: &'static str,
        /// What was expected.
        reason: String,
    },
}

fn io_err(path: &Path) -> impl FnOnce(std::io::Error) -> WriteError + '_ {
    move |source| WriteError::Io {
        path: path.to_path_buf(),
        source,
    }
}

fn create_dir(path: &Path) -> Result<(), WriteError> {
    std::fs::create_dir_all(path).map_err(io_err(path))
}

fn create_file(path: &Path) -> Result<BufWriter<File>, WriteError> {
    File::create(path).map(BufWriter::new).map_err(io_err(path))
}

fn write_text(path: &Path, text: &str) -> Result<(), WriteError> {
    std::fs::write(path, text).map_err(io_err(path))
}

fn check_size<T>(
    layout: &'static str,
    what: &str,
    img: &Image<T>,
    cal: &CameraIntrinsics,
) -> Result<(), WriteError>
where
    T: Copy + Default,
{
    if img.width() != cal.width || img.height() != cal.height {
        return Err(WriteError::Invalid {
            layout,
            reason: format!(
                "{what} image is {}×{}, the calibration says {}×{}",
                img.width(),
                img.height(),
                cal.width,
                cal.height
            ),
        });
    }
    Ok(())
}

/// Encodes a PNG from tightly packed rows.
fn write_png(
    path: &Path,
    width: usize,
    height: usize,
    bytes: &[u8],
    colour: image::ExtendedColorType,
) -> Result<(), WriteError> {
    let file = File::create(path).map_err(io_err(path))?;
    let encoder = image::codecs::png::PngEncoder::new(BufWriter::new(file));
    image::ImageEncoder::write_image(encoder, bytes, width as u32, height as u32, colour).map_err(
        |source| WriteError::Encode {
            path: path.to_path_buf(),
            source,
        },
    )
}

/// Rows of an image without the stride padding.
fn packed<T: Copy + Default>(img: &Image<T>) -> Vec<T> {
    (0..img.height())
        .flat_map(|v| img.row(v).iter().copied())
        .collect()
}

fn write_grey(path: &Path, img: &Image<u8>) -> Result<(), WriteError> {
    write_png(
        path,
        img.width(),
        img.height(),
        &packed(img),
        image::ExtendedColorType::L8,
    )
}

/// The radial-tangential coefficients of a camera (zero for none); other models are refused.
fn radtan(layout: &'static str, camera: &CameraIntrinsics) -> Result<geom::RadTan, WriteError> {
    match camera.distortion {
        LensDistortion::None => Ok(geom::RadTan::default()),
        LensDistortion::RadTan(d) => Ok(d),
        LensDistortion::Equidistant(_) if camera.distortion.is_identity() => {
            Ok(geom::RadTan::default())
        }
        LensDistortion::Equidistant(_) => Err(WriteError::Invalid {
            layout,
            reason: "writes radial-tangential distortion only, not equidistant".into(),
        }),
    }
}

/// Checks that timestamps increase strictly.
fn check_increasing(layout: &'static str, last: Option<u64>, t: u64) -> Result<(), WriteError> {
    if let Some(l) = last
        && t <= l
    {
        return Err(WriteError::Invalid {
            layout,
            reason: format!("timestamp {t} does not follow {l}"),
        });
    }
    Ok(())
}

/// TUM's time format: seconds with six decimals, from microseconds.
pub fn tum_timestamp(timestamp_us: u64) -> String {
    format!(
        "{}.{:06}",
        timestamp_us / 1_000_000,
        timestamp_us % 1_000_000
    )
}

/// The TUM depth scale: 5000 per metre (a 16-bit value `d` is `d/5000` m; 0 = no depth).
pub const TUM_DEPTH_SCALE: f64 = 5000.0;

/// A TUM depth value for `z` metres: `round(5000 z)`, 0 for no depth, non-finite or beyond the
/// 16-bit range (13.1 m).
pub fn tum_depth_value(z: f32) -> u16 {
    let d = (z as f64 * TUM_DEPTH_SCALE).round();
    if z.is_finite() && z > 0.0 && d <= u16::MAX as f64 {
        d as u16
    } else {
        0
    }
}

fn pose_text(pose: &Se3) -> String {
    let p = pose.translation();
    let q = pose.rotation().unit_quaternion();
    [p.x, p.y, p.z, q.i, q.j, q.k, q.w].map(fmt_f64).join(" ")
}

/// Writes a TUM RGB-D sequence (see the module notes).
pub struct TumWriter {
    dir: PathBuf,
    calibration: CameraIntrinsics,
    rgb: BufWriter<File>,
    depth: BufWriter<File>,
    groundtruth: BufWriter<File>,
    last: Option<u64>,
}

impl TumWriter {
    /// Creates `dir` (and `rgb/`, `depth/`), writes `camera.yaml` and the index headers.
    /// `name` appears in the headers (TUM writes the bag file's name there); `rate_hz` goes into
    /// `camera.yaml`.
    pub fn create(
        dir: impl AsRef<Path>,
        name: &str,
        calibration: &CameraIntrinsics,
        rate_hz: f64,
    ) -> Result<Self, WriteError> {
        let dir = dir.as_ref().to_path_buf();
        create_dir(&dir.join("rgb"))?;
        create_dir(&dir.join("depth"))?;
        let p = &calibration.pinhole;
        let d = radtan("TUM RGB-D", calibration)?;
        let distortion = if calibration.distortion.is_identity() {
            String::new()
        } else {
            format!(
                "  distortion:\n    model: radtan\n    coefficients: [{}, {}, {}, {}, {}]\n",
                yaml_f64(d.k1),
                yaml_f64(d.k2),
                yaml_f64(d.p1),
                yaml_f64(d.p2),
                yaml_f64(d.k3)
            )
        };
        let yaml = [
            "# The calibration of this sequence (dwslam camera YAML; TUM RGB-D publishes its\n"
                .to_string(),
            "# calibrations on its web page, not in the sequences).\n".to_string(),
            "dwslam_camera: 1\nsensor: rgbd\n".to_string(),
            format!("fps: {}\n", yaml_f64(rate_hz)),
            format!(
                "camera:\n  width: {}\n  height: {}\n",
                calibration.width, calibration.height
            ),
            format!("  fx: {}\n  fy: {}\n", yaml_f64(p.fx), yaml_f64(p.fy)),
            format!("  cx: {}\n  cy: {}\n", yaml_f64(p.cx), yaml_f64(p.cy)),
            distortion,
            format!("depth:\n  units_per_metre: {}\n", yaml_f64(TUM_DEPTH_SCALE)),
        ]
        .concat();
        write_text(&dir.join("camera.yaml"), &yaml)?;
        let header =
            |path: &Path, what: &str, columns: &str| -> Result<BufWriter<File>, WriteError> {
                let mut f = create_file(path)?;
                write!(f, "# {what}\n# file: '{name}'\n# {columns}\n").map_err(io_err(path))?;
                Ok(f)
            };
        let rgb = header(&dir.join("rgb.txt"), "color images", "timestamp filename")?;
        let depth = header(&dir.join("depth.txt"), "depth maps", "timestamp filename")?;
        let groundtruth = header(
            &dir.join("groundtruth.txt"),
            "ground truth trajectory",
            "timestamp tx ty tz qx qy qz qw",
        )?;
        Ok(TumWriter {
            dir,
            calibration: *calibration,
            rgb,
            depth,
            groundtruth,
            last: None,
        })
    }

    /// Writes one frame: colour image, depth in metres (0 = none) and the colour camera's
    /// `world_from_camera` at `timestamp_us` (µs; written as seconds with six decimals, the
    /// same string in all three files, so association by timestamp is exact).
    pub fn write(
        &mut self,
        timestamp_us: u64,
        rgb: &Image<[u8; 3]>,
        depth_m: &Image<f32>,
        world_from_camera: &Se3,
    ) -> Result<(), WriteError> {
        check_increasing("TUM RGB-D", self.last, timestamp_us)?;
        check_size("TUM RGB-D", "colour", rgb, &self.calibration)?;
        check_size("TUM RGB-D", "depth", depth_m, &self.calibration)?;
        let t = tum_timestamp(timestamp_us);
        let rgb_name = format!("rgb/{t}.png");
        let depth_name = format!("depth/{t}.png");
        let bytes: Vec<u8> = packed(rgb).into_iter().flatten().collect();
        write_png(
            &self.dir.join(&rgb_name),
            rgb.width(),
            rgb.height(),
            &bytes,
            image::ExtendedColorType::Rgb8,
        )?;
        let depth: Vec<u8> = packed(depth_m)
            .into_iter()
            .flat_map(|z| tum_depth_value(z).to_ne_bytes())
            .collect();
        write_png(
            &self.dir.join(&depth_name),
            depth_m.width(),
            depth_m.height(),
            &depth,
            image::ExtendedColorType::L16,
        )?;
        let (d, dir) = (&mut self.depth, &self.dir);
        writeln!(self.rgb, "{t} {rgb_name}").map_err(io_err(&dir.join("rgb.txt")))?;
        writeln!(d, "{t} {depth_name}").map_err(io_err(&dir.join("depth.txt")))?;
        writeln!(self.groundtruth, "{t} {}", pose_text(world_from_camera))
            .map_err(io_err(&dir.join("groundtruth.txt")))?;
        self.last = Some(timestamp_us);
        Ok(())
    }

    /// Flushes the index files.
    pub fn finish(mut self) -> Result<(), WriteError> {
        let dir = self.dir.clone();
        self.rgb.flush().map_err(io_err(&dir.join("rgb.txt")))?;
        self.depth.flush().map_err(io_err(&dir.join("depth.txt")))?;
        self.groundtruth
            .flush()
            .map_err(io_err(&dir.join("groundtruth.txt")))
    }
}

/// A real number for YAML files: the round-trip form with a decimal point (`1.0`, not `1`), as
/// the datasets write them (some readers take `1` for an integer).
fn yaml_f64(x: f64) -> String {
    let s = fmt_f64(x);
    if s.contains(['.', 'e', 'E', 'n', 'N']) {
        s
    } else {
        format!("{s}.0")
    }
}

/// EuRoC's 4 × 4 `T_BS` block of a `sensor.yaml`.
fn t_bs_yaml(body_from_sensor: &Se3) -> String {
    let m = body_from_sensor.matrix();
    let row = |r: usize| {
        (0..4)
            .map(|c| yaml_f64(m[(r, c)]))
            .collect::<Vec<_>>()
            .join(", ")
    };
    format!(
        "T_BS:\n  cols: 4\n  rows: 4\n  data: [{},\n         {},\n         {},\n         {}]\n",
        row(0),
        row(1),
        row(2),
        row(3)
    )
}

struct EurocCamera {
    dir: PathBuf,
    csv: BufWriter<File>,
}

/// Writes a EuRoC MAV sequence, mono (`cam0`) or stereo (`cam0`, `cam1`), see the module notes.
pub struct EurocWriter {
    mav0: PathBuf,
    calibration: CameraIntrinsics,
    cameras: Vec<EurocCamera>,
    groundtruth: BufWriter<File>,
    last: Option<u64>,
}

impl EurocWriter {
    /// Creates `dir/mav0` with the camera folders, their `sensor.yaml` and `data.csv` headers,
    /// `body.yaml` and the ground-truth folder. `baseline`: the stereo baseline (m) of `cam1`
    /// (rectified: the same intrinsics, moved along cam0's `x`); `None` for mono.
    pub fn create(
        dir: impl AsRef<Path>,
        calibration: &CameraIntrinsics,
        baseline: Option<f64>,
        rate_hz: f64,
    ) -> Result<Self, WriteError> {
        let d = radtan("EuRoC", calibration)?;
        if d.k3 != 0.0 {
            return Err(WriteError::Invalid {
                layout: "EuRoC",
                reason: format!(
                    "EuRoC's radial-tangential model has four coefficients, k3 = {} is not 0",
                    d.k3
                ),
            });
        }
        let mav0 = dir.as_ref().join("mav0");
        create_dir(&mav0)?;
        write_text(
            &mav0.join("body.yaml"),
            "%YAML:1.0\ncomment: dwslam rendered sequence; the body frame is cam0's\n",
        )?;
        let mut extrinsics = vec![Se3::identity()];
        if let Some(b) = baseline {
            extrinsics.push(Se3::from_translation(Vector3::new(b, 0.0, 0.0)));
        }
        let p = &calibration.pinhole;
        let mut cameras = Vec::new();
        for (i, body_from_cam) in extrinsics.iter().enumerate() {
            let cam = mav0.join(format!("cam{i}"));
            create_dir(&cam.join("data"))?;
            let yaml = format!(
                "%YAML:1.0\n# General sensor definitions.\nsensor_type: camera\ncomment: dwslam rendered cam{i}\n\n\
                 # Sensor extrinsics wrt. the body-frame.\n{}\n\
                 # Camera specific definitions.\nrate_hz: {}\nresolution: [{}, {}]\ncamera_model: pinhole\n\
                 intrinsics: [{}, {}, {}, {}] #fu, fv, cu, cv\ndistortion_model: radial-tangential\n\
                 distortion_coefficients: [{}, {}, {}, {}]\n",
                t_bs_yaml(body_from_cam),
                yaml_f64(rate_hz),
                calibration.width,
                calibration.height,
                yaml_f64(p.fx),
                yaml_f64(p.fy),
                yaml_f64(p.cx),
                yaml_f64(p.cy),
                yaml_f64(d.k1),
                yaml_f64(d.k2),
                yaml_f64(d.p1),
                yaml_f64(d.p2),
            );
            write_text(&cam.join("sensor.yaml"), &yaml)?;
            let csv_path = cam.join("data.csv");
            let mut csv = create_file(&csv_path)?;
            writeln!(csv, "#timestamp [ns],filename").map_err(io_err(&csv_path))?;
            cameras.push(EurocCamera { dir: cam, csv });
        }
        let gt = mav0.join("state_groundtruth_estimate0");
        create_dir(&gt)?;
        write_text(
            &gt.join("sensor.yaml"),
            &format!(
                "%YAML:1.0\n# General sensor definitions.\nsensor_type: visual-inertial\n\
                 comment: The exact pose of the body (cam0) of the rendered sequence.\n\n\
                 # Sensor extrinsics wrt. the body-frame.\n{}",
                t_bs_yaml(&Se3::identity())
            ),
        )?;
        let gt_path = gt.join("data.csv");
        let mut groundtruth = create_file(&gt_path)?;
        writeln!(
            groundtruth,
            "#timestamp, p_RS_R_x [m], p_RS_R_y [m], p_RS_R_z [m], q_RS_w [], q_RS_x [], q_RS_y [], q_RS_z [], \
             v_RS_R_x [m s^-1], v_RS_R_y [m s^-1], v_RS_R_z [m s^-1], b_w_RS_S_x [rad s^-1], b_w_RS_S_y [rad s^-1], \
             b_w_RS_S_z [rad s^-1], b_a_RS_S_x [m s^-2], b_a_RS_S_y [m s^-2], b_a_RS_S_z [m s^-2]"
        )
        .map_err(io_err(&gt_path))?;
        Ok(EurocWriter {
            mav0,
            calibration: *calibration,
            cameras,
            groundtruth,
            last: None,
        })
    }

    /// Writes one frame: cam0 (and cam1) images at `timestamp_ns`, and the ground truth: the
    /// body's (cam0's) `world_from_body` and its velocity in the world (m/s).
    pub fn write(
        &mut self,
        timestamp_ns: u64,
        images: &[&Image<u8>],
        world_from_body: &Se3,
        velocity: &Vector3<f64>,
    ) -> Result<(), WriteError> {
        check_increasing("EuRoC", self.last, timestamp_ns)?;
        if images.len() != self.cameras.len() {
            return Err(WriteError::Invalid {
                layout: "EuRoC",
                reason: format!("{} images for {} cameras", images.len(), self.cameras.len()),
            });
        }
        for (cam, img) in self.cameras.iter_mut().zip(images) {
            check_size("EuRoC", "camera", img, &self.calibration)?;
            let name = format!("{timestamp_ns}.png");
            write_grey(&cam.dir.join("data").join(&name), img)?;
            writeln!(cam.csv, "{timestamp_ns},{name}")
                .map_err(io_err(&cam.dir.join("data.csv")))?;
        }
        let p = world_from_body.translation();
        let q = world_from_body.rotation().unit_quaternion();
        let values = [
            p.x, p.y, p.z, q.w, q.i, q.j, q.k, velocity.x, velocity.y, velocity.z, 0.0, 0.0, 0.0,
            0.0, 0.0, 0.0,
        ];
        let text: Vec<String> = values.iter().map(|v| fmt_f64(*v)).collect();
        let gt_path = self.mav0.join("state_groundtruth_estimate0/data.csv");
        writeln!(self.groundtruth, "{timestamp_ns},{}", text.join(","))
            .map_err(io_err(&gt_path))?;
        self.last = Some(timestamp_ns);
        Ok(())
    }

    /// Flushes the CSV files.
    pub fn finish(mut self) -> Result<(), WriteError> {
        for cam in &mut self.cameras {
            cam.csv.flush().map_err(io_err(&cam.dir.join("data.csv")))?;
        }
        let gt_path = self.mav0.join("state_groundtruth_estimate0/data.csv");
        self.groundtruth.flush().map_err(io_err(&gt_path))
    }
}

/// C's `%.{digits}e` (KITTI's number format): `7.070912000000e+02`.
fn c_exp(x: f64, digits: usize) -> String {
    let x = if x == 0.0 { 0.0 } else { x }; // no "-0.000e+00"
    let s = format!("{x:.digits$e}");
    let (mantissa, exponent) = s.split_once('e').expect("exponent form");
    let e: i32 = exponent.parse().expect("an integer exponent");
    format!("{mantissa}e{}{:02}", if e < 0 { '-' } else { '+' }, e.abs())
}

/// Writes a KITTI odometry sequence, mono (`image_0`) or stereo (`image_0`, `image_1`), see the
/// module notes.
pub struct KittiWriter {
    dir: PathBuf,
    calibration: CameraIntrinsics,
    cameras: usize,
    times: BufWriter<File>,
    poses: BufWriter<File>,
    first: Option<Se3>,
    start_us: Option<u64>,
    last: Option<u64>,
    frames: usize,
}

impl KittiWriter {
    /// Creates `dir` with `image_0` (and `image_1` if `stereo`), writes `calib.txt`:
    /// `P0 = K[I | 0]`, `P1 = K[I | (−b, 0, 0)]` (`P1[0][3] = −f_x·b`, the rig's right camera,
    /// stated also for a mono sequence as KITTI does), `P2 = P0`, `P3 = P1` (these sequences
    /// have no separate colour cameras) and `Tr = [I | 0]` (no lidar), in KITTI's `%.12e`
    /// format.
    pub fn create(
        dir: impl AsRef<Path>,
        calibration: &CameraIntrinsics,
        baseline: f64,
        stereo: bool,
    ) -> Result<Self, WriteError> {
        if !(baseline > 0.0 && baseline.is_finite()) {
            return Err(WriteError::Invalid {
                layout: "KITTI",
                reason: format!("the baseline must be positive, got {baseline}"),
            });
        }
        if !calibration.distortion.is_identity() {
            return Err(WriteError::Invalid {
                layout: "KITTI",
                reason: "KITTI images are rectified: a distorted camera cannot be written (use the EuRoC layout)".into(),
            });
        }
        let dir = dir.as_ref().to_path_buf();
        let cameras = if stereo { 2 } else { 1 };
        for i in 0..cameras {
            create_dir(&dir.join(format!("image_{i}")))?;
        }
        let p = &calibration.pinhole;
        let b = baseline;
        let projection = |tx: f64| {
            [
                p.fx, 0.0, p.cx, tx, 0.0, p.fy, p.cy, 0.0, 0.0, 0.0, 1.0, 0.0,
            ]
        };
        let line =
            |label: &str, m: [f64; 12]| format!("{label}: {}\n", m.map(|x| c_exp(x, 12)).join(" "));
        let (p0, p1) = (projection(0.0), projection(-p.fx * b));
        let identity = [1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0];
        let calib = [
            line("P0", p0),
            line("P1", p1),
            line("P2", p0),
            line("P3", p1),
            line("Tr", identity),
        ]
        .concat();
        write_text(&dir.join("calib.txt"), &calib)?;
        let times = create_file(&dir.join("times.txt"))?;
        let poses = create_file(&dir.join("poses.txt"))?;
        Ok(KittiWriter {
            dir,
            calibration: *calibration,
            cameras,
            times,
            poses,
            first: None,
            start_us: None,
            last: None,
            frames: 0,
        })
    }

    /// Writes one frame: `image_0` (and `image_1`) images, the time (µs; `times.txt` counts
    /// seconds from the first frame) and camera 0's `world_from_camera` (`poses.txt` holds it
    /// relative to the first frame's camera 0).
    pub fn write(
        &mut self,
        timestamp_us: u64,
        images: &[&Image<u8>],
        world_from_camera: &Se3,
    ) -> Result<(), WriteError> {
        check_increasing("KITTI", self.last, timestamp_us)?;
        if images.len() != self.cameras {
            return Err(WriteError::Invalid {
                layout: "KITTI",
                reason: format!("{} images for {} cameras", images.len(), self.cameras),
            });
        }
        if self.frames >= 1_000_000 {
            return Err(WriteError::Invalid {
                layout: "KITTI",
                reason: "at most 1 000 000 frames (six-digit file names)".into(),
            });
        }
        for (i, img) in images.iter().enumerate() {
            check_size("KITTI", "camera", img, &self.calibration)?;
            write_grey(
                &self.dir.join(format!("image_{i}/{:06}.png", self.frames)),
                img,
            )?;
        }
        let start = *self.start_us.get_or_insert(timestamp_us);
        let first = *self.first.get_or_insert(*world_from_camera);
        let t = (timestamp_us - start) as f64 * 1e-6;
        writeln!(self.times, "{}", c_exp(t, 9)).map_err(io_err(&self.dir.join("times.txt")))?;
        let relative = first.inverse().compose(world_from_camera);
        let m = relative.matrix();
        let text: Vec<String> = (0..12).map(|k| fmt_f64(m[(k / 4, k % 4)])).collect();
        writeln!(self.poses, "{}", text.join(" ")).map_err(io_err(&self.dir.join("poses.txt")))?;
        self.last = Some(timestamp_us);
        self.frames += 1;
        Ok(())
    }

    /// Flushes `times.txt` and `poses.txt`.
    pub fn finish(mut self) -> Result<(), WriteError> {
        self.times
            .flush()
            .map_err(io_err(&self.dir.join("times.txt")))?;
        self.poses
            .flush()
            .map_err(io_err(&self.dir.join("poses.txt")))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::trajectory::{parse_euroc_groundtruth, parse_kitti, parse_tum, read_timestamps};
    use geom::{PinholeCamera, RadTan};

    fn calibration() -> CameraIntrinsics {
        CameraIntrinsics::ideal(PinholeCamera::new(525.0, 524.5, 3.5, 2.5), 8, 6)
    }

    fn pose(k: usize) -> Se3 {
        let x = k as f64;
        Se3::exp(&nalgebra::Vector6::new(
            0.1 * x,
            -0.2,
            0.3 * x.sin(),
            0.01 * x,
            0.5,
            -0.3 * x,
        ))
    }

    fn temp(name: &str) -> PathBuf {
        let d = std::env::temp_dir().join(format!("dwslam-writer-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        d
    }

    #[test]
    fn formats_match_the_datasets() {
        assert_eq!(tum_timestamp(1_305_031_102_211_214), "1305031102.211214");
        assert_eq!(tum_timestamp(1_700_000_000_000_001), "1700000000.000001");
        assert_eq!(c_exp(707.0912, 12), "7.070912000000e+02");
        assert_eq!(c_exp(-379.8145, 12), "-3.798145000000e+02");
        assert_eq!(c_exp(0.0, 12), "0.000000000000e+00");
        assert_eq!(c_exp(-0.0, 12), "0.000000000000e+00");
        assert_eq!(c_exp(0.1036602, 6), "1.036602e-01");
        assert_eq!(tum_depth_value(1.0), 5000);
        assert_eq!(tum_depth_value(0.0), 0);
        assert_eq!(tum_depth_value(20.0), 0);
        assert_eq!(tum_depth_value(f32::NAN), 0);
    }

    #[test]
    fn tum_round_trip() {
        let dir = temp("tum");
        let cal = calibration();
        let mut w = TumWriter::create(&dir, "test", &cal, 30.0).unwrap();
        let rgb = Image::from_fn(8, 6, |u, v| [u as u8, v as u8, 7]);
        let depth = Image::from_fn(8, 6, |u, v| 0.5 + 0.1 * (u + v) as f32);
        for k in 0..3 {
            w.write(
                1_700_000_000_000_000 + 33_333 * k as u64,
                &rgb,
                &depth,
                &pose(k),
            )
            .unwrap();
        }
        assert!(
            w.write(1_700_000_000_000_000, &rgb, &depth, &pose(0))
                .is_err()
        );
        w.finish().unwrap();
        let gt_path = dir.join("groundtruth.txt");
        let gt = parse_tum(&std::fs::read_to_string(&gt_path).unwrap(), &gt_path).unwrap();
        assert_eq!(gt.len(), 3);
        for k in 0..3 {
            let d = gt.world_from_body[k].inverse().compose(&pose(k)).log();
            assert!(d.norm() < 1e-12);
        }
        let rgb_txt = std::fs::read_to_string(dir.join("rgb.txt")).unwrap();
        let depth_txt = std::fs::read_to_string(dir.join("depth.txt")).unwrap();
        assert!(rgb_txt.starts_with("# color images\n"));
        assert!(rgb_txt.contains("1700000000.033333 rgb/1700000000.033333.png"));
        assert!(depth_txt.contains("1700000000.066666 depth/1700000000.066666.png"));
        let img = vision::image::load_u16(dir.join("depth/1700000000.033333.png")).unwrap();
        assert_eq!(img.get(4, 2), 5500);
        let c = vision::image::load_rgb_planes(dir.join("rgb/1700000000.000000.png")).unwrap();
        assert_eq!((c[0].get(5, 1), c[1].get(5, 1), c[2].get(5, 1)), (5, 1, 7));
        // The camera file reads back as the same calibration.
        let file = crate::camera_file::read_camera_file(dir.join("camera.yaml")).unwrap();
        match file
            .calibration(crate::camera::SensorKind::Rgbd, (8, 6), &dir)
            .unwrap()
        {
            crate::camera::Calibration::Rgbd { camera, depth } => {
                assert_eq!(camera, cal);
                assert_eq!(depth.metres_per_unit, 1.0 / 5000.0);
            }
            other => panic!("{other:?}"),
        }
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn euroc_round_trip() {
        let dir = temp("euroc");
        let mut cal = calibration();
        cal.distortion = LensDistortion::RadTan(RadTan::new(-0.28, 0.07, 2e-4, 2e-5));
        let mut w = EurocWriter::create(&dir, &cal, Some(0.11), 20.0).unwrap();
        let img = Image::from_fn(8, 6, |u, v| (u * 10 + v) as u8);
        for k in 0..3 {
            w.write(
                1_700_000_000_000_000_000 + 50_000_000 * k as u64,
                &[&img, &img],
                &pose(k),
                &Vector3::new(0.1, 0.2, 0.3),
            )
            .unwrap();
        }
        assert!(
            w.write(
                1_800_000_000_000_000_000,
                &[&img],
                &pose(0),
                &Vector3::zeros()
            )
            .is_err()
        );
        w.finish().unwrap();
        let gt_path = dir.join("mav0/state_groundtruth_estimate0/data.csv");
        let gt =
            parse_euroc_groundtruth(&std::fs::read_to_string(&gt_path).unwrap(), &gt_path).unwrap();
        assert_eq!(gt.len(), 3);
        for k in 0..3 {
            assert!(
                gt.world_from_body[k]
                    .inverse()
                    .compose(&pose(k))
                    .log()
                    .norm()
                    < 1e-12
            );
        }
        let csv = std::fs::read_to_string(dir.join("mav0/cam1/data.csv")).unwrap();
        assert_eq!(
            csv.lines().nth(2).unwrap(),
            "1700000000050000000,1700000000050000000.png"
        );
        let yaml = std::fs::read_to_string(dir.join("mav0/cam1/sensor.yaml")).unwrap();
        assert!(yaml.contains("data: [1.0, 0.0, 0.0, 0.11,"), "{yaml}");
        assert!(yaml.contains("intrinsics: [525.0, 524.5, 3.5, 2.5] #fu, fv, cu, cv"));
        assert!(
            yaml.contains("distortion_coefficients: [-0.28, 0.07, 0.0002, 2e-5]"),
            "{yaml}"
        );
        assert!(yaml.contains("resolution: [8, 6]"));
        let back = vision::image::load_gray_u8(dir.join("mav0/cam0/data/1700000000100000000.png"))
            .unwrap();
        assert_eq!(back, img);
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn kitti_round_trip_and_refusals() {
        let dir = temp("kitti");
        let cal = calibration();
        let mut w = KittiWriter::create(&dir, &cal, 0.5, true).unwrap();
        let img = Image::from_fn(8, 6, |u, v| (u + 3 * v) as u8);
        for k in 0..3 {
            w.write(2_000_000 + 100_000 * k as u64, &[&img, &img], &pose(k))
                .unwrap();
        }
        w.finish().unwrap();
        let calib = std::fs::read_to_string(dir.join("calib.txt")).unwrap();
        let lines: Vec<&str> = calib.lines().collect();
        assert_eq!(lines.len(), 5);
        assert_eq!(
            lines[1],
            "P1: 5.250000000000e+02 0.000000000000e+00 3.500000000000e+00 -2.625000000000e+02 \
             0.000000000000e+00 5.245000000000e+02 2.500000000000e+00 0.000000000000e+00 \
             0.000000000000e+00 0.000000000000e+00 1.000000000000e+00 0.000000000000e+00"
        );
        assert!(lines[4].starts_with("Tr: 1.000000000000e+00 "));
        let poses_path = dir.join("poses.txt");
        let poses =
            parse_kitti(&std::fs::read_to_string(&poses_path).unwrap(), &poses_path).unwrap();
        assert_eq!(poses.len(), 3);
        assert!(poses[0].log().norm() < 1e-15);
        for (k, p) in poses.iter().enumerate().skip(1) {
            let truth = pose(0).inverse().compose(&pose(k));
            assert!(p.inverse().compose(&truth).log().norm() < 1e-12);
        }
        let times = read_timestamps(dir.join("times.txt")).unwrap();
        assert_eq!(times, vec![0.0, 0.1, 0.2]);
        assert!(dir.join("image_1/000002.png").exists());
        std::fs::remove_dir_all(&dir).unwrap();
        // Distortion and wrong sizes are refused.
        let mut bad = calibration();
        bad.distortion = LensDistortion::RadTan(RadTan::new(0.1, 0.0, 0.0, 0.0));
        assert!(KittiWriter::create(temp("kitti-bad"), &bad, 0.5, false).is_err());
        assert!(KittiWriter::create(temp("kitti-bad"), &cal, 0.0, false).is_err());
        let dir = temp("kitti-size");
        let mut w = KittiWriter::create(&dir, &cal, 0.5, false).unwrap();
        assert!(w.write(0, &[&Image::<u8>::new(4, 4)], &pose(0)).is_err());
        assert!(w.write(0, &[&img, &img], &pose(0)).is_err());
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn unwritable_directories_are_errors() {
        let file = temp("not-a-dir");
        std::fs::write(&file, "x").unwrap();
        let err = TumWriter::create(file.join("sub"), "x", &calibration(), 30.0)
            .err()
            .unwrap();
        assert!(err.to_string().contains("not-a-dir"), "{err}");
        std::fs::remove_file(&file).unwrap();
    }
}
