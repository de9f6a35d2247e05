//! `dwslam run PATH`: the live system on a recorded sequence (thesis §6.3–6.5): every frame's
//! pose and the map, with a progress bar, a clean stop on Ctrl-C, ATE/RPE at the end when the
//! sequence has ground truth, and a report of pictures.

use crate::args;
use anyhow::Result;
use clap::Args;
use data::camera::{SensorKind, SensorModel};
use data::sequence::{BadFramePolicy, SequenceFormat};
use runner::{MapOptions, RequestError, SequenceRequest, Settings};
use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use system::Mode;

/// Options of `dwslam run`.
#[derive(Args, Debug, Clone)]
pub struct RunArgs {
    /// The sequence: a TUM RGB-D / 7-Scenes, EuRoC, KITTI or image folder (see the README's
    /// formats).
    pub path: PathBuf,
    /// The sensor to run (default: the sequence's own; `rgbd` needs depth images, `stereo` a
    /// stereo pair, `mono` runs on the left / colour image of any sequence).
    #[arg(long, value_parser = ["stereo", "rgbd", "mono"])]
    pub sensor: Option<String>,
    /// A YAML file overriding the system's parameters (`system::config::SystemConfig`).
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Output folder (trajectories, map, summary, report).
    #[arg(long, default_value = "out/run")]
    pub out: PathBuf,
    /// Run the back-end at fixed points of the frame stream (identical outputs run to run)
    /// instead of in its own thread.
    #[arg(long)]
    pub deterministic: bool,
    /// Process at most this many frames.
    #[arg(long)]
    pub max_frames: Option<usize>,
    /// Start at this frame of the sequence (0: the first; with --depth-frames-only, of the
    /// frames with depth); the run numbers its frames from there.
    #[arg(long, default_value_t = 0)]
    pub start_frame: usize,
    /// Force the sequence's format instead of detecting it.
    #[arg(long, value_parser = ["tum", "euroc", "kitti", "folder"])]
    pub format: Option<String>,
    /// A camera file (dwslam YAML or ORB-SLAM3 settings) overriding the sequence's
    /// calibration.
    #[arg(long)]
    pub camera: Option<PathBuf>,
    /// A bad frame (missing, corrupt, wrong size): `stop` the run, or `skip` it with a warning.
    #[arg(long, default_value = "stop", value_parser = ["stop", "skip"])]
    pub on_bad_frame: String,
    /// RGB-D: only the frames with a depth image (by default frames without one are tracked
    /// from the colour image against the map).
    #[arg(long)]
    pub depth_frames_only: bool,
    /// Also write the trajectory in KITTI format.
    #[arg(long)]
    pub kitti: bool,
    /// Also fuse the optimised keyframes' depth into one coloured, voxel-filtered point cloud,
    /// `dense.ply` (thesis §6.5.3; `dense` in --config sets the voxel size).
    #[arg(long)]
    pub dense_ply: bool,
    /// Save the map at the end of the run (the whole state needed to go on in it: keyframes,
    /// points, edges, features, the camera, the vocabulary's identity; written atomically).
    /// `dwslam map info FILE` says what a map holds.
    #[arg(long, value_name = "FILE")]
    pub save_map: Option<PathBuf>,
    /// Go on in a map saved by an earlier run (stereo and RGB-D): the frames are found in it
    /// by relocalisation and tracked in it; without --localise the map is extended (a camera
    /// not found in it for `tracker.new_map_after` seconds starts a new map, merged when it
    /// sees the old one).
    #[arg(long, value_name = "FILE")]
    pub load_map: Option<PathBuf>,
    /// Only localise in the map of --load-map: every frame relocalised and tracked against it,
    /// nothing added (a frame the map does not cover is lost, with its reason).
    #[arg(long, requires = "load_map")]
    pub localise: bool,
    /// No progress bar (for logs).
    #[arg(long)]
    pub quiet: bool,
    #[command(flatten)]
    pub view: crate::view::ViewArgs,
}

/// Runs the live system on a sequence.
pub fn run(args: RunArgs) -> Result<()> {
    // Everything the command line says is checked before any work.
    args::input_dir(&args.path, "PATH")?;
    let (config, config_text) = args::system_config(args.config.as_deref())?;
    if let Some(path) = &args.save_map {
        args::output_file(path, "--save-map")?;
    }
    let load_map = match &args.load_map {
        Some(path) => {
            args::input_file(path, "--load-map")?;
            Some(runner::load_map(path)?)
        }
        None => None,
    };
    if let Some(camera) = &args.camera {
        args::input_file(camera, "--camera")?;
    }
    anyhow::ensure!(
        args.max_frames != Some(0),
        "--max-frames must be at least 1"
    );
    let request = SequenceRequest {
        path: args.path.clone(),
        sensor: args.sensor.as_deref().map(|s| match s {
            "stereo" => SensorKind::Stereo,
            "rgbd" => SensorKind::Rgbd,
            _ => SensorKind::Mono,
        }),
        format: args
            .format
            .as_deref()
            .map(str::parse::<SequenceFormat>)
            .transpose()
            .map_err(anyhow::Error::msg)?,
        camera: args.camera.clone(),
        skip_bad_frames: args
            .on_bad_frame
            .parse::<BadFramePolicy>()
            .map_err(anyhow::Error::msg)?
            == BadFramePolicy::Skip,
        depth_frames_only: args.depth_frames_only,
        start_frame: args.start_frame,
        max_frames: args.max_frames,
    };
    let source = runner::open_sequence(&request).map_err(|e| {
        // The option at fault as the command line names it.
        let named = match e.downcast_ref::<RequestError>() {
            Some(RequestError::Sensor { want, .. }) => format!("--sensor {want}"),
            Some(RequestError::StartFrame(_)) => format!("--start-frame {}", args.start_frame),
            Some(RequestError::NoFrames) => "--max-frames".into(),
            None => return e,
        };
        anyhow::anyhow!("{named}: {e}")
    })?;
    anyhow::ensure!(
        !(args.dense_ply && matches!(source.sensor, SensorModel::Mono(_))),
        "--dense-ply fuses depth images or stereo disparities: a monocular run has neither"
    );
    // The output folder is made only once the input is known to be runnable.
    args::output_dir(&args.out, "--out")?;
    let settings = Settings {
        out: args.out.clone(),
        config,
        mode: if args.deterministic {
            Mode::Deterministic
        } else {
            Mode::Threaded
        },
        kitti: args.kitti,
        dense_ply: args.dense_ply,
        quiet: args.quiet,
        maps: MapOptions {
            save: args.save_map.clone(),
            load: load_map,
            localise: args.localise,
            config_text,
        },
        stop: stop_on_ctrl_c(),
    };
    let mut view = crate::view::open(&args.view, &source)?;
    runner::execute(
        source,
        &settings,
        &crate::run_report::report,
        view.as_deref_mut(),
    )?;
    Ok(())
}

/// A flag set by Ctrl-C (the run stops after the frame in hand and writes its outputs); a
/// second Ctrl-C ends the process at once.
pub fn stop_on_ctrl_c() -> Arc<AtomicBool> {
    let stop = Arc::new(AtomicBool::new(false));
    let flag = stop.clone();
    let _ = ctrlc::set_handler(move || {
        if flag.swap(true, Ordering::SeqCst) {
            std::process::exit(130);
        }
    });
    stop
}
