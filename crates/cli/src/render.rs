//! `dwslam render`: a rendered image sequence with exact ground truth (issue 17), written in a
//! standard layout (TUM RGB-D, EuRoC MAV, KITTI odometry) that the sequence readers take.

use anyhow::{Context, Result, bail};
use clap::{Args, ValueEnum};
use data::camera::{CameraIntrinsics, LensDistortion};
use data::dataset_writer::{EurocWriter, KittiWriter, TumWriter};
use geom::RadTan;
use nalgebra::Vector3;
use sim::render::sensor::{ExposureChanges, MotionBlur};
use sim::render::{Frame, FrameImages, SceneKind, SensorKind, Sequence, SequenceConfig};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

/// The worlds.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum SceneArg {
    /// A furnished room, browsed hand-held at 30 Hz with revisits (3000 frames by default).
    Room,
    /// A building's 212 m corridor loop, walked once at 15 Hz (≈ 2570 frames by default).
    Building,
    /// A courtyard between façades, three laps at 20 Hz (≈ 3480 frames by default).
    Courtyard,
    /// A town of street blocks, a 1.74 km drive with two loops at 10 Hz (≈ 1700 frames by
    /// default; KITTI's image size, focal length and stereo baseline by default).
    Town,
}

/// The sensors.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum SensorArg {
    /// One grey camera (KITTI layout by default).
    Mono,
    /// A rectified grey stereo pair (EuRoC layout by default).
    Stereo,
    /// Colour and registered depth (TUM layout by default).
    Rgbd,
}

/// The output layouts.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum LayoutArg {
    /// TUM RGB-D (rgb/, depth/, rgb.txt, depth.txt, groundtruth.txt): RGB-D only.
    Tum,
    /// EuRoC MAV (mav0/cam0, cam1, state_groundtruth_estimate0): mono or stereo.
    Euroc,
    /// KITTI odometry (image_0, image_1, calib.txt, times.txt, poses.txt): mono or stereo,
    /// no distortion.
    Kitti,
}

/// Options of `dwslam render`.
#[derive(Args, Debug)]
pub struct RenderArgs {
    /// The world: room, building, courtyard or town.
    #[arg(value_enum)]
    pub scene: SceneArg,
    /// The sensor.
    #[arg(long, value_enum)]
    pub sensor: SensorArg,
    /// Number of frames (default: the scene's full run).
    #[arg(long)]
    pub frames: Option<usize>,
    /// Seed of the textures, the trajectory's variations and the noise.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Seed of the trajectory's variations alone (default: --seed): the same world, with the
    /// same textures, along another path — the sessions of one place (`dwslam run --load-map`).
    #[arg(long)]
    pub path_seed: Option<u64>,
    /// Room only: scale of how far each revisit of a view strays from the last (1 = the default
    /// browsing, each visit within ±0.15 m of position and ±0.25 m of gaze target, about one
    /// keyframe-coverage radius, so every lap makes new views; 0 = exactly the same views).
    /// Use e.g. 0.25 for a browsing where each revisit returns to nearly the same view, so the
    /// room can be fully mapped and the keyframe count should stop growing (thesis §6.5.2).
    /// The order of the views, the hand's shake and the roll are unchanged.
    #[arg(long, value_name = "F", allow_negative_numbers = true)]
    pub revisit_jitter: Option<f64>,
    /// Output layout (default: tum for rgbd, euroc for stereo, kitti for mono; kitti for the
    /// town's mono and stereo).
    #[arg(long, value_enum)]
    pub layout: Option<LayoutArg>,
    /// Image size WIDTHxHEIGHT (default 640x480, the town's 1241x376); the focal length scales
    /// with the width: 525 px at 640, the town's 707.09 px at 1241 (KITTI's).
    #[arg(long)]
    pub size: Option<String>,
    /// Output directory (created; must be empty if it exists).
    #[arg(long)]
    pub out: PathBuf,
    /// Stereo baseline in metres (default EuRoC's VI-sensor: 0.11; the town KITTI's 0.54); for
    /// mono KITTI output, the rig's right camera stated in calib.txt's P1.
    #[arg(long)]
    pub baseline: Option<f64>,
    /// Radial-tangential distortion K1,K2,P1,P2 of the rendered images (EuRoC cam0:
    /// -0.2834,0.0740,0.0002,0.00002).
    #[arg(long, value_name = "K1,K2,P1,P2", allow_hyphen_values = true)]
    pub radtan: Option<String>,
    /// No image noise (and exact depth for rgbd).
    #[arg(long)]
    pub no_noise: bool,
    /// Exact depth for rgbd (no Kinect-like noise or holes), image noise unchanged.
    #[arg(long)]
    pub exact_depth: bool,
    /// Slow exposure changes (±30 %, an auto-exposure hunting).
    #[arg(long)]
    pub exposure_changes: bool,
    /// Motion blur over an exposure of this many milliseconds (5 sub-frames).
    #[arg(long, value_name = "MS")]
    pub motion_blur: Option<f64>,
    /// Supersampling grid per axis at silhouettes (1 = no anti-aliasing of edges).
    #[arg(long, default_value_t = 3)]
    pub supersampling: usize,
    /// Worker threads (default: all cores).
    #[arg(long)]
    pub threads: Option<usize>,
    /// Also time the front-end's kernels on the rendered (left) images, as the consumer the
    /// renderer must keep up with: a 4-level pyramid, FAST-9 at threshold 20, the quadtree's
    /// 300 features and pyramidal LK (21×21) from the previous frame (bench/render).
    #[arg(long)]
    pub frontend_timing: bool,
}

/// The grey (left) image of a frame (RGB converted with the Rec. 601 weights).
fn grey_of(frame: &Frame) -> vision::image::GrayImage {
    match &frame.images {
        FrameImages::Mono(g) | FrameImages::Stereo { left: g, .. } => g.clone(),
        FrameImages::Rgbd { rgb, .. } => rgb.map(|[r, g, b]| {
            (0.299 * r as f32 + 0.587 * g as f32 + 0.114 * b as f32).round() as u8
        }),
    }
}

/// The front-end's kernels on one frame (see `--frontend-timing`): returns the pyramid and the
/// selected features for the next frame.
fn frontend(
    img: &vision::image::GrayImage,
    previous: Option<&(vision::pyramid::Pyramid, Vec<[f32; 2]>)>,
) -> Result<(vision::pyramid::Pyramid, Vec<[f32; 2]>)> {
    let params = vision::lk::LkParams::default();
    let pyramid = vision::pyramid::Pyramid::new(img, params.levels, 8).context("pyramid")?;
    let (_, chosen) = sim::render::quality::select_features(&pyramid.levels[0]);
    if let Some((prev, features)) = previous {
        let _ = vision::lk::track(prev, &pyramid, features, None, &params);
    }
    Ok((pyramid, chosen.iter().map(|q| [q.u, q.v]).collect()))
}

/// Parses `WIDTHxHEIGHT`.
fn parse_size(spec: &str) -> Result<(usize, usize)> {
    let (w, h) = spec
        .split_once(['x', 'X'])
        .with_context(|| format!("--size expects WIDTHxHEIGHT, got {spec:?}"))?;
    let parse = |s: &str, what: &str| -> Result<usize> {
        s.trim()
            .parse::<usize>()
            .with_context(|| format!("--size: the {what} {s:?} is not a whole number"))
    };
    let (w, h) = (parse(w, "width")?, parse(h, "height")?);
    if !(16..=8192).contains(&w) || !(16..=8192).contains(&h) {
        bail!("--size {w}x{h}: width and height must be 16…8192 pixels");
    }
    Ok((w, h))
}

fn parse_radtan(spec: &str) -> Result<RadTan> {
    let v: Vec<f64> = spec
        .split(',')
        .map(|s| {
            s.trim()
                .parse::<f64>()
                .ok()
                .filter(|x| x.is_finite())
                .with_context(|| format!("--radtan: {s:?} is not a finite number"))
        })
        .collect::<Result<_>>()?;
    let [k1, k2, p1, p2] = v.as_slice() else {
        bail!("--radtan expects four numbers K1,K2,P1,P2, got {}", v.len());
    };
    Ok(RadTan::new(*k1, *k2, *p1, *p2))
}

/// `--revisit-jitter`: finite, ≥ 0, and for the room only (the default otherwise).
fn revisit_jitter(scene: SceneArg, value: Option<f64>) -> Result<f64> {
    let Some(j) = value else {
        return Ok(sim::render::DEFAULT_REVISIT_JITTER);
    };
    if !(j.is_finite() && j >= 0.0) {
        bail!("--revisit-jitter expects a finite scale of at least 0, got {j}");
    }
    if scene != SceneArg::Room {
        bail!("--revisit-jitter scales the room's browsing: it needs the room scene");
    }
    Ok(j)
}

/// The layout a sensor is written in by default, and whether a layout fits a sensor.
fn layout_for(
    scene: SceneArg,
    sensor: SensorArg,
    layout: Option<LayoutArg>,
    distorted: bool,
) -> Result<LayoutArg> {
    let layout = layout.unwrap_or(match sensor {
        SensorArg::Rgbd => LayoutArg::Tum,
        SensorArg::Stereo if scene != SceneArg::Town || distorted => LayoutArg::Euroc,
        SensorArg::Stereo | SensorArg::Mono => LayoutArg::Kitti,
    });
    match (layout, sensor) {
        (LayoutArg::Tum, SensorArg::Rgbd) => {}
        (LayoutArg::Tum, _) => bail!(
            "--layout tum holds RGB-D sequences: use --sensor rgbd, or --layout euroc or kitti"
        ),
        (LayoutArg::Euroc | LayoutArg::Kitti, SensorArg::Rgbd) => {
            bail!(
                "--layout {layout:?} holds grey mono or stereo images, not RGB-D: use --layout tum"
            )
        }
        _ => {}
    }
    if layout == LayoutArg::Kitti && distorted {
        bail!(
            "--layout kitti holds rectified images: --radtan needs --layout euroc (or tum for rgbd)"
        );
    }
    Ok(layout)
}

/// Checks that `out` holds no earlier output, then that it can be written (creates it).
fn prepare_out(out: &Path) -> Result<()> {
    if out.is_dir()
        && std::fs::read_dir(out)
            .with_context(|| format!("--out {}: cannot list the folder", out.display()))?
            .next()
            .is_some()
    {
        bail!(
            "--out {}: not empty (remove it or pick another folder)",
            out.display()
        );
    }
    crate::args::output_dir(out, "--out")
}

enum Writer {
    Tum(TumWriter),
    Euroc(EurocWriter),
    Kitti(KittiWriter),
}

impl Writer {
    fn write(&mut self, frame: &Frame, velocity: &Vector3<f64>) -> Result<()> {
        let k = frame.index;
        let pose = &frame.world_from_camera;
        match (self, &frame.images) {
            (Writer::Tum(w), FrameImages::Rgbd { rgb, depth }) => {
                w.write(frame.timestamp_us, rgb, depth, pose)
            }
            (Writer::Euroc(w), FrameImages::Mono(img)) => {
                w.write(frame.timestamp_us * 1000, &[img], pose, velocity)
            }
            (Writer::Euroc(w), FrameImages::Stereo { left, right }) => {
                w.write(frame.timestamp_us * 1000, &[left, right], pose, velocity)
            }
            (Writer::Kitti(w), FrameImages::Mono(img)) => w.write(frame.timestamp_us, &[img], pose),
            (Writer::Kitti(w), FrameImages::Stereo { left, right }) => {
                w.write(frame.timestamp_us, &[left, right], pose)
            }
            _ => unreachable!("the layout was checked against the sensor"),
        }
        .with_context(|| format!("writing frame {k}"))
    }

    fn finish(self) -> Result<()> {
        match self {
            Writer::Tum(w) => w.finish(),
            Writer::Euroc(w) => w.finish(),
            Writer::Kitti(w) => w.finish(),
        }
        .context("finishing the index files")
    }
}

/// Runs `dwslam render`.
pub fn run(args: RenderArgs) -> Result<()> {
    // Everything is checked before any work starts.
    let scene = match args.scene {
        SceneArg::Room => SceneKind::Room,
        SceneArg::Building => SceneKind::Building,
        SceneArg::Courtyard => SceneKind::Courtyard,
        SceneArg::Town => SceneKind::Town,
    };
    let (width, height) = match &args.size {
        Some(size) => parse_size(size)?,
        None => scene.default_size(),
    };
    let distortion = args.radtan.as_deref().map(parse_radtan).transpose()?;
    let layout = layout_for(args.scene, args.sensor, args.layout, distortion.is_some())?;
    let baseline = args.baseline.unwrap_or(match scene {
        SceneKind::Town => 0.54,
        _ => sim::render::sensor::DEFAULT_STEREO_BASELINE,
    });
    if args.frames == Some(0) {
        bail!("--frames must be at least 1");
    }
    if let Some(t) = args.threads
        && t == 0
    {
        bail!("--threads must be at least 1");
    }
    crate::args::positive(baseline, "--baseline (metres)")?;
    let revisit_jitter = revisit_jitter(args.scene, args.revisit_jitter)?;
    let kind = match args.sensor {
        SensorArg::Mono => SensorKind::Mono,
        SensorArg::Stereo => SensorKind::Stereo { baseline },
        SensorArg::Rgbd => SensorKind::Rgbd,
    };
    let mut sensor = scene.sensor(kind, width, height);
    sensor.camera.distortion = distortion;
    sensor.supersampling = args.supersampling;
    if args.no_noise {
        sensor.noise = None;
        sensor.depth_noise = None;
    }
    if args.exact_depth {
        sensor.depth_noise = None;
    }
    if args.exposure_changes {
        sensor.exposure_changes = Some(ExposureChanges::default());
    }
    if let Some(ms) = args.motion_blur {
        if !(ms > 0.0 && ms < 1000.0) {
            bail!("--motion-blur expects an exposure of 0–1000 ms, got {ms}");
        }
        sensor.motion_blur = Some(MotionBlur {
            exposure: ms * 1e-3,
            ..MotionBlur::default()
        });
    }
    let mut sequence = Sequence::new(SequenceConfig {
        scene,
        sensor,
        seed: args.seed,
        path_seed: args.path_seed,
        frames: args.frames,
        revisit_jitter,
    })
    .context("setting up the sequence")?;
    prepare_out(&args.out)?;
    let pool = {
        let mut b = rayon::ThreadPoolBuilder::new();
        if let Some(t) = args.threads {
            b = b.num_threads(t);
        }
        b.build().context("starting the worker threads")?
    };

    let calibration = CameraIntrinsics {
        pinhole: sensor.camera.pinhole,
        distortion: distortion.map_or(LensDistortion::None, LensDistortion::RadTan),
        width,
        height,
    };
    let rate = scene.rate_hz();
    let name = format!(
        "dwslam render {} --sensor {:?} --seed {}{}{}",
        scene.name(),
        args.sensor,
        args.seed,
        args.path_seed
            .map_or(String::new(), |p| format!(" --path-seed {p}")),
        args.revisit_jitter
            .map_or(String::new(), |j| format!(" --revisit-jitter {j}"))
    )
    .to_lowercase();
    let mut writer = match layout {
        LayoutArg::Tum => Writer::Tum(TumWriter::create(&args.out, &name, &calibration, rate)?),
        LayoutArg::Euroc => {
            let baseline = matches!(kind, SensorKind::Stereo { .. }).then_some(baseline);
            Writer::Euroc(EurocWriter::create(
                &args.out,
                &calibration,
                baseline,
                rate,
            )?)
        }
        LayoutArg::Kitti => Writer::Kitti(KittiWriter::create(
            &args.out,
            &calibration,
            baseline,
            matches!(kind, SensorKind::Stereo { .. }),
        )?),
    };
    let n = sequence.len();
    println!(
        "rendering {} ({} frames at {rate} Hz, {:.1} s) with a {:?} {width}×{height} camera (f = {} px), seed {}, into {} ({layout:?} layout)",
        scene.name(),
        n,
        n as f64 / rate,
        args.sensor,
        sensor.camera.pinhole.fx,
        args.seed,
        args.out.display()
    );
    let bar = crate::experiment::progress(n, "rendering");
    let (mut render_time, mut write_time, mut frontend_time) =
        (Duration::ZERO, Duration::ZERO, Duration::ZERO);
    let mut frontend_state = None;
    let start = Instant::now();
    // Rendering frame k + 1 overlaps encoding frame k (PNG encoding is single-threaded).
    let mut pending: Option<(Frame, Vector3<f64>)> = None;
    pool.install(|| -> Result<()> {
        for k in 0..=n {
            let seq = &mut sequence;
            let (rendered, written) = rayon::join(
                || -> Result<Option<(Frame, Vector3<f64>, Duration)>> {
                    if k == n {
                        return Ok(None);
                    }
                    let t0 = Instant::now();
                    let frame = seq
                        .render_frame(k)
                        .with_context(|| format!("rendering frame {k}"))?;
                    let t = seq.time(k);
                    let velocity = velocity(seq.path(), t);
                    Ok(Some((frame, velocity, t0.elapsed())))
                },
                || -> Result<Duration> {
                    let t0 = Instant::now();
                    if let Some((frame, velocity)) = pending.take() {
                        writer.write(&frame, &velocity)?;
                    }
                    Ok(t0.elapsed())
                },
            );
            write_time += written?;
            if let Some((frame, velocity, took)) = rendered? {
                render_time += took;
                if args.frontend_timing {
                    let img = grey_of(&frame);
                    let t0 = Instant::now();
                    frontend_state = Some(frontend(&img, frontend_state.as_ref())?);
                    frontend_time += t0.elapsed();
                }
                pending = Some((frame, velocity));
                bar.inc(1);
            }
        }
        Ok(())
    })?;
    bar.finish();
    writer.finish()?;
    let cache = sequence.renderer().cache();
    println!(
        "{n} frames in {:.1} s: rendering {:.1} ms per frame (texture tiles: {} generated, {:.1} ms per frame, {} MB cached), writing {:.1} ms per frame, {} threads",
        start.elapsed().as_secs_f64(),
        1e3 * render_time.as_secs_f64() / n as f64,
        cache.generated(),
        1e3 * cache.generation_seconds() / n as f64,
        cache.bytes() >> 20,
        1e3 * write_time.as_secs_f64() / n as f64,
        pool.current_num_threads()
    );
    if args.frontend_timing {
        println!(
            "front-end on the rendered images (pyramid, FAST, quadtree, LK of 300 features): {:.1} ms per frame; rendering / front-end = {:.2}",
            1e3 * frontend_time.as_secs_f64() / n as f64,
            render_time.as_secs_f64() / frontend_time.as_secs_f64()
        );
    }
    println!("wrote {}", args.out.display());
    Ok(())
}

/// The (left) camera's velocity in the world at `t` (central difference over ±1 ms).
fn velocity(path: &dyn sim::render::paths::CameraPath, t: f64) -> Vector3<f64> {
    let h = 1e-3;
    let (a, b) = (
        path.world_from_camera((t - h).max(0.0)),
        path.world_from_camera(t + h),
    );
    let dt = t + h - (t - h).max(0.0);
    (b.translation() - a.translation()) / dt
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn arguments_are_checked() {
        assert_eq!(parse_size("320x240").unwrap(), (320, 240));
        assert!(parse_size("320").is_err());
        assert!(parse_size("8x8").is_err());
        assert!(parse_size("axb").is_err());
        assert!(parse_radtan("-0.28,0.07,0.0002,0.00002").is_ok());
        assert!(parse_radtan("1,2,3").is_err());
        assert!(parse_radtan("1,2,3,nan").is_err());
        assert_eq!(revisit_jitter(SceneArg::Room, None).unwrap(), 1.0);
        assert_eq!(revisit_jitter(SceneArg::Room, Some(0.25)).unwrap(), 0.25);
        assert_eq!(revisit_jitter(SceneArg::Room, Some(0.0)).unwrap(), 0.0);
        assert!(revisit_jitter(SceneArg::Room, Some(-0.1)).is_err());
        assert!(revisit_jitter(SceneArg::Room, Some(f64::NAN)).is_err());
        assert!(revisit_jitter(SceneArg::Room, Some(f64::INFINITY)).is_err());
        assert!(revisit_jitter(SceneArg::Courtyard, Some(0.25)).is_err());
        assert_eq!(revisit_jitter(SceneArg::Building, None).unwrap(), 1.0);
        assert_eq!(
            layout_for(SceneArg::Room, SensorArg::Rgbd, None, false).unwrap(),
            LayoutArg::Tum
        );
        assert_eq!(
            layout_for(SceneArg::Room, SensorArg::Stereo, None, false).unwrap(),
            LayoutArg::Euroc
        );
        assert_eq!(
            layout_for(SceneArg::Room, SensorArg::Mono, None, false).unwrap(),
            LayoutArg::Kitti
        );
        assert!(layout_for(SceneArg::Room, SensorArg::Mono, Some(LayoutArg::Tum), false).is_err());
        assert!(
            layout_for(
                SceneArg::Room,
                SensorArg::Rgbd,
                Some(LayoutArg::Kitti),
                false
            )
            .is_err()
        );
        assert!(
            layout_for(
                SceneArg::Room,
                SensorArg::Stereo,
                Some(LayoutArg::Kitti),
                true
            )
            .is_err()
        );
        assert!(layout_for(SceneArg::Room, SensorArg::Mono, None, true).is_err());
        assert_eq!(
            layout_for(
                SceneArg::Room,
                SensorArg::Mono,
                Some(LayoutArg::Euroc),
                true
            )
            .unwrap(),
            LayoutArg::Euroc
        );
        // The town's stereo rig is KITTI's, written in KITTI's layout.
        assert_eq!(
            layout_for(SceneArg::Town, SensorArg::Stereo, None, false).unwrap(),
            LayoutArg::Kitti
        );
    }
}
