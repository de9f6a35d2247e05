//! `dwslam demo`: the live system (`dwslam run`'s, unchanged) on a sequence rendered on the fly
//! — the furnished room browsed hand-held with revisits, as RGB-D or stereo — so that a fresh
//! clone shows the product without a download. The frames come from `sim::render` through
//! `Frame::to_sequence_frame`, exactly what the sequence readers would deliver for the files
//! `dwslam render` writes; the ground truth is the renderer's.

use crate::args;
use anyhow::{Context, Result};
use clap::{Args, ValueEnum};
use data::trajectory::Trajectory;
use runner::{Outcome, Settings, Source, execute};
use sim::render::sensor::DEFAULT_STEREO_BASELINE;
use sim::render::{SceneKind, SensorKind, SensorModel, Sequence, SequenceConfig};
use std::path::PathBuf;
use std::sync::mpsc::sync_channel;
use system::Mode;

/// The demo's sensors.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum DemoSensor {
    /// Colour and registered depth (a Kinect-like sensor with its depth noise and holes).
    Rgbd,
    /// A rectified grey stereo pair (11 cm baseline), disparity by block matching.
    Stereo,
}

/// Options of `dwslam demo`.
#[derive(Args, Debug, Clone)]
pub struct DemoArgs {
    /// The sensor.
    #[arg(long, value_enum, default_value = "rgbd")]
    pub sensor: DemoSensor,
    /// Number of frames (30 Hz). The default, 900 (30 s of browsing, half of the first lap
    /// around the room), takes about 30 s on two cores, rendering included; 1560 complete the
    /// lap back to the start, where the run closes its loop (about a minute); the full
    /// browse (3000 frames) revisits the room.
    #[arg(long, default_value_t = 900)]
    pub frames: usize,
    /// Seed of the room's textures, the trajectory's variations and the noise.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Scale of how far each revisit of a view strays from the last (1: the default browsing;
    /// 0.25: nearly the same views; see `dwslam render --revisit-jitter`).
    #[arg(long, default_value_t = sim::render::DEFAULT_REVISIT_JITTER)]
    pub revisit_jitter: f64,
    /// A YAML file overriding the system's parameters (as `dwslam run --config`).
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Output folder (trajectories, map, summary, report, as `dwslam run` writes them).
    #[arg(long, default_value = "dwslam-demo")]
    pub out: PathBuf,
    /// Run the back-end at fixed points of the frame stream (identical outputs run to run).
    #[arg(long)]
    pub deterministic: bool,
    /// No progress bar.
    #[arg(long)]
    pub quiet: bool,
    #[command(flatten)]
    pub view: crate::view::ViewArgs,
}

/// Frames rendered ahead of the live system (bounded: the renderer waits when it is ahead).
const RENDER_QUEUE: usize = 4;

/// Runs the demo.
pub fn run(args: DemoArgs) -> Result<()> {
    anyhow::ensure!(args.frames >= 2, "--frames must be at least 2");
    anyhow::ensure!(
        args.revisit_jitter.is_finite() && args.revisit_jitter >= 0.0,
        "--revisit-jitter expects a finite scale of at least 0, got {}",
        args.revisit_jitter
    );
    let (config, _) = args::system_config(args.config.as_deref())?;
    let kind = match args.sensor {
        DemoSensor::Rgbd => SensorKind::Rgbd,
        DemoSensor::Stereo => SensorKind::Stereo {
            baseline: DEFAULT_STEREO_BASELINE,
        },
    };
    let sensor = SensorModel::new(kind, 640, 480);
    let camera = sensor
        .sequence_camera()
        .expect("the default camera has no distortion");
    let mut sequence = Sequence::new(SequenceConfig {
        scene: SceneKind::Room,
        sensor,
        seed: args.seed,
        path_seed: None,
        frames: Some(args.frames),
        revisit_jitter: args.revisit_jitter,
    })
    .context("setting up the rendered room")?;
    args::output_dir(&args.out, "--out")?;
    let ground_truth = Trajectory {
        timestamps: (0..args.frames)
            .map(|k| sequence.timestamp_us(k) as f64 * 1e-6)
            .collect(),
        world_from_body: (0..args.frames)
            .map(|k| sequence.world_from_camera(k))
            .collect(),
    };
    println!(
        "dwslam demo: the live system on a furnished room rendered on the fly ({} frames at {} Hz, {} 640×480, seed {}), against the renderer's exact ground truth",
        args.frames,
        SceneKind::Room.rate_hz(),
        match args.sensor {
            DemoSensor::Rgbd => "RGB-D",
            DemoSensor::Stereo => "stereo",
        },
        args.seed
    );
    // The renderer runs on its own thread (its rayon pool), a few frames ahead.
    let (tx, rx) = sync_channel(RENDER_QUEUE);
    let frames = args.frames;
    std::thread::Builder::new()
        .name("render".into())
        .spawn(move || {
            for k in 0..frames {
                let frame = sequence
                    .render_frame(k)
                    .map(|f| f.to_sequence_frame())
                    .with_context(|| format!("rendering frame {k}"));
                let failed = frame.is_err();
                if tx.send(frame).is_err() || failed {
                    break;
                }
            }
        })
        .context("starting the render thread")?;
    let source = Source {
        name: format!("dwslam demo (rendered room, seed {})", args.seed),
        sensor: camera,
        frames,
        ground_truth: Some(ground_truth),
        skip_bad_frames: false,
        stream: Box::new(rx.into_iter()),
        // The rendered frames carry their depth images already decoded.
        depth: None,
    };
    let settings = Settings {
        out: args.out.clone(),
        config,
        mode: if args.deterministic {
            Mode::Deterministic
        } else {
            Mode::Threaded
        },
        kitti: false,
        dense_ply: args.sensor == DemoSensor::Rgbd,
        quiet: args.quiet,
        maps: Default::default(),
        stop: crate::run::stop_on_ctrl_c(),
    };
    let mut view = crate::view::open(&args.view, &source)?;
    let outcome = execute(
        source,
        &settings,
        &crate::run_report::report,
        view.as_deref_mut(),
    )?
    .outcome;
    print_summary(&outcome, &args);
    Ok(())
}

fn print_summary(outcome: &Outcome, args: &DemoArgs) {
    let fps = outcome.frames as f64 / outcome.seconds.max(1e-9);
    println!();
    println!(
        "demo: {} frames ({} lost) in {:.1} s, {:.0} frames per second with rendering; {} keyframes, {} loop closure{}",
        outcome.frames,
        outcome.lost,
        outcome.seconds,
        fps,
        outcome.keyframes,
        outcome.loops,
        if outcome.loops == 1 { "" } else { "s" }
    );
    if let Some((live, last)) = outcome.ate {
        println!(
            "demo: ATE RMSE {:.2} cm for every frame as tracked live, {:.2} cm after the final optimisation",
            live * 100.0,
            last * 100.0
        );
    }
    println!(
        "demo: the report's pictures are in {}/ (trajectory.png, keyframe_graph.png, …); run a recording with `dwslam run PATH`",
        args.out.display()
    );
}
