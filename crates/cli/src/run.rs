//! `dwslam run PATH`: the live system on a recorded sequence (thesis §6.3–6.5): every frame's
//! pose and the map, with a progress bar, a clean stop on Ctrl-C, ATE/RPE at the end when the
//! sequence has ground truth, and a report of pictures.

use crate::args;
use crate::plot::{self, Figure, GREY, PALETTE, Series, Style};
use anyhow::{Context, Result, bail};
use clap::Args;
use data::camera::SensorModel;
use data::eval::{Alignment, KITTI_SEGMENT_LENGTHS, ate, drift, rpe};
use data::output::{OutputOptions, RunOutput, TrackingState};
use data::sequence::{BadFramePolicy, Frame, FrameError, OpenOptions, Sequence, SequenceFormat};
use data::trajectory::{Trajectory, associate, write_tum};
use indicatif::{ProgressBar, ProgressStyle};
use lie::{LieGroup, Se3};
use serde_json::json;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;
use system::map_file::MapFile;
use system::vocabulary::{VocabularyOrigin, load_vocabulary};
use system::{LiveRun, Mode, Options, RunGraph, RunResult, System, SystemConfig};

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
}

/// Per frame: the tracker's counts and times (CSV).
pub const FRAME_STATS_FILE: &str = "frames.csv";

/// Per optimisation (one per keyframe): window sizes, problem size and times (CSV).
pub const OPTIMISATION_STATS_FILE: &str = "optimisations.csv";

/// The dense model of `--dense-ply`.
pub const DENSE_FILE: &str = "dense.ply";

/// The trajectory file of the poses after the run's final optimisation.
pub const FINAL_TRAJECTORY_FILE: &str = "trajectory_final.tum";

/// Runs the live system on a sequence.
pub fn run(args: RunArgs) -> Result<()> {
    // Everything the command line says is checked before any work.
    args::input_dir(&args.path, "PATH")?;
    let (config, config_text) = match &args.config {
        Some(path) => {
            args::input_file(path, "--config")?;
            let text = std::fs::read_to_string(path)
                .with_context(|| format!("--config {}", path.display()))?;
            (SystemConfig::from_file(path)?, text)
        }
        None => (SystemConfig::default(), String::new()),
    };
    if let Some(path) = &args.save_map {
        args::output_file(path, "--save-map")?;
    }
    let load_map = match &args.load_map {
        Some(path) => {
            args::input_file(path, "--load-map")?;
            let t = Instant::now();
            let map = MapFile::read(path)?;
            println!(
                "loaded map {} in {:.2} s: {}",
                path.display(),
                t.elapsed().as_secs_f64(),
                map_line(&map.summary())
            );
            Some(Arc::new(map))
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
    let options = OpenOptions {
        format: args
            .format
            .as_deref()
            .map(str::parse::<SequenceFormat>)
            .transpose()
            .map_err(anyhow::Error::msg)?,
        camera_file: args.camera.clone(),
        on_bad_frame: args
            .on_bad_frame
            .parse::<BadFramePolicy>()
            .map_err(anyhow::Error::msg)?,
        require_depth: args.depth_frames_only,
        no_depth: args.sensor.as_deref() == Some("mono"),
        ..OpenOptions::default()
    };
    let sequence = Sequence::open(&args.path, &options)?
        .starting_at(args.start_frame)
        .map_err(|e| anyhow::anyhow!("--start-frame {}: {e}", args.start_frame))?;
    let info = sequence.info().clone();
    let sensor = match (args.sensor.as_deref(), &info.camera) {
        (None | Some("stereo"), SensorModel::Stereo(_))
        | (None | Some("rgbd"), SensorModel::Rgbd(_)) => info.camera,
        // A stereo or RGB-D sequence runs monocular on its left / colour image alone.
        (None | Some("mono"), _) => SensorModel::Mono(*info.camera.pinhole()),
        (Some(want), have) => bail!(
            "--sensor {want}: {} is a {} sequence",
            args.path.display(),
            sensor_name(have)
        ),
    };
    anyhow::ensure!(
        !(args.dense_ply && matches!(sensor, SensorModel::Mono(_))),
        "--dense-ply fuses depth images or stereo disparities: a monocular run has neither"
    );
    // The output folder is made only once the input is known to be runnable.
    args::output_dir(&args.out, "--out")?;
    let mode = if args.deterministic {
        Mode::Deterministic
    } else {
        Mode::Threaded
    };
    let frames = args
        .max_frames
        .map_or(info.frame_count, |m| m.min(info.frame_count));
    println!(
        "{} ({}, {} frames, {}×{}, {}){}",
        args.path.display(),
        info.format.name(),
        info.frame_count,
        info.size.0,
        info.size.1,
        sensor_name(&sensor),
        if info.ground_truth.is_some() {
            ", with ground truth"
        } else {
            ""
        }
    );
    for w in &info.warnings {
        println!("  note: {w}");
    }
    let reader = sequence.into_reader(8);
    let source = Source {
        name: args.path.display().to_string(),
        sensor,
        frames,
        ground_truth: info.ground_truth.map(|g| g.trajectory),
        skip_bad_frames: options.on_bad_frame == BadFramePolicy::Skip,
        stream: Box::new(reader.take(frames).map(|r| r.map_err(anyhow::Error::new))),
    };
    let settings = Settings {
        out: args.out.clone(),
        config,
        mode,
        kitti: args.kitti,
        dense_ply: args.dense_ply,
        quiet: args.quiet,
        maps: MapOptions {
            save: args.save_map.clone(),
            load: load_map,
            localise: args.localise,
            config_text,
        },
    };
    execute(source, &settings).map(|_| ())
}

/// Where the frames come from: a recorded sequence's reader (`dwslam run`) or frames rendered
/// on the fly (`dwslam demo`); the live system and everything after it is the same.
pub struct Source {
    /// What is run (printed, and the run record's name).
    pub name: String,
    /// The camera.
    pub sensor: SensorModel,
    /// The number of frames the stream will deliver (the progress bar's length).
    pub frames: usize,
    /// The ground truth, when there is one (ATE/RPE and the report's trajectory picture).
    pub ground_truth: Option<Trajectory>,
    /// A bad frame (a [`data::sequence::FrameError`]) is skipped with a warning instead of
    /// stopping the run.
    pub skip_bad_frames: bool,
    /// The frames, in order.
    pub stream: Box<dyn Iterator<Item = Result<Frame>>>,
}

/// How to run and what to write.
pub struct Settings {
    /// Output folder (made by the caller once the input is known to be runnable).
    pub out: PathBuf,
    /// The system's parameters.
    pub config: SystemConfig,
    /// Threaded or deterministic back-end.
    pub mode: Mode,
    /// Also write the trajectory in KITTI format.
    pub kitti: bool,
    /// Also fuse and write the dense model.
    pub dense_ply: bool,
    /// No progress bar.
    pub quiet: bool,
    /// Maps saved and loaded.
    pub maps: MapOptions,
}

/// The maps of a run: saved at its end, loaded at its start (`--save-map`, `--load-map`).
#[derive(Default)]
pub struct MapOptions {
    /// Save the map here at the end.
    pub save: Option<PathBuf>,
    /// Go on in this map.
    pub load: Option<Arc<MapFile>>,
    /// Only localise in it.
    pub localise: bool,
    /// The configuration overrides (YAML), kept in a saved map.
    pub config_text: String,
}

/// One line of what a map holds.
pub fn map_line(s: &system::map_file::MapSummary) -> String {
    format!(
        "{} keyframes, {} points, {} maps, {} edges ({} marginalised), {} keypoints",
        s.keyframes, s.points, s.maps, s.edges, s.marginalised_edges, s.keypoints
    )
}

/// What a run measured (the demo prints it).
#[derive(Debug, Clone)]
pub struct Outcome {
    /// Frames processed.
    pub frames: usize,
    /// Wall-clock seconds of the frame loop.
    pub seconds: f64,
    /// Frames whose tracking was lost.
    pub lost: usize,
    /// Keyframes in the map at the end.
    pub keyframes: usize,
    /// Loop closures.
    pub loops: usize,
    /// ATE RMSE (m) of the every-frame trajectory and of the final one, where evaluated.
    pub ate: Option<(f64, f64)>,
}

/// Runs the live system on a source of frames and writes the outputs, the summary and the
/// report into `settings.out`.
pub fn execute(source: Source, settings: &Settings) -> Result<Outcome> {
    let Source {
        name,
        sensor,
        frames,
        ground_truth,
        skip_bad_frames,
        stream,
    } = source;
    let config = settings.config.clone();
    // The test switch is checked before any output is written.
    let faults = test_faults()?;
    let output = RunOutput::create(
        &settings.out,
        OutputOptions {
            kitti: settings.kitti,
            ..OutputOptions::default()
        },
    )?;
    let stop = Arc::new(AtomicBool::new(false));
    {
        let stop = stop.clone();
        // A second Ctrl-C ends the process at once.
        let _ = ctrlc::set_handler(move || {
            if stop.swap(true, Ordering::SeqCst) {
                std::process::exit(130);
            }
        });
    }
    let run = Run {
        frames,
        ground_truth,
        skip_bad_frames,
        stream,
        stop,
        output,
    };
    let vocabulary = if config.loops.enabled {
        Some(vocabulary(&config.loops)?)
    } else {
        None
    };
    let dense_config = match &sensor {
        SensorModel::Stereo(s) => Some((*s, true)),
        SensorModel::Rgbd(r) => Some((r.stereo, false)),
        SensorModel::Mono(_) => None,
    }
    .map(|(camera, stereo)| (camera.pinhole, config.dense_model_for(&camera, stereo)));
    let system = System::new(
        &sensor,
        config,
        Options {
            mode: settings.mode,
            sequence: name,
            vocabulary,
            // The keyframes' depth images only serve the dense model.
            keyframe_depth: settings.dense_ply,
            save_map: settings.maps.save.clone(),
            load_map: settings.maps.load.clone(),
            localise: settings.maps.localise,
            config_text: settings.maps.config_text.clone(),
            faults,
        },
    )?;
    // A monocular map has a scale of its own: it is compared after a similarity.
    let alignment = if system.free_scale() {
        Alignment::Sim3
    } else {
        Alignment::Se3
    };
    let dense = |result: &RunResult| -> Result<()> {
        match (&dense_config, &result.graph) {
            (Some((camera, config)), RunGraph::Depth(graph)) if settings.dense_ply => {
                write_dense_model(settings, result, graph, camera, config)
            }
            _ => Ok(()),
        }
    };
    drive(system, run, settings, alignment, dense)
}

/// The faults of `DWSLAM_TEST_FAULT` for the back-end's threads (the tests of a worker that
/// dies): `optimiser:panic:N`, `loops:disconnect:N`, … (after N jobs), comma-separated.
fn test_faults() -> Result<system::Faults> {
    let mut faults = system::Faults::default();
    let Ok(spec) = std::env::var("DWSLAM_TEST_FAULT") else {
        return Ok(faults);
    };
    for item in spec.split(',').filter(|s| !s.is_empty()) {
        let parts: Vec<&str> = item.split(':').collect();
        let [stage, kind, after] = parts[..] else {
            bail!("DWSLAM_TEST_FAULT: {item} is not STAGE:KIND:JOBS");
        };
        let after: usize = after
            .parse()
            .with_context(|| format!("DWSLAM_TEST_FAULT: {item}: JOBS"))?;
        let fault = match kind {
            "panic" => system::Fault::Panic { after },
            "disconnect" => system::Fault::Disconnect { after },
            _ => bail!("DWSLAM_TEST_FAULT: {item}: KIND is panic or disconnect"),
        };
        match stage {
            "optimiser" => faults.optimiser = Some(fault),
            "loops" => faults.loops = Some(fault),
            _ => bail!("DWSLAM_TEST_FAULT: {item}: STAGE is optimiser or loops"),
        }
    }
    Ok(faults)
}

/// The dense model of a depth sensor's run, `dense.ply` in the output folder.
fn write_dense_model(
    settings: &Settings,
    result: &RunResult,
    graph: &slam::map::SlamGraph<3>,
    camera: &geom::PinholeCamera,
    config: &system::config::DenseModelConfig,
) -> Result<()> {
    let t = Instant::now();
    let model =
        system::dense_model::fuse(graph, result.world_map, &result.keyframes, camera, config)?;
    let path = settings.out.join(DENSE_FILE);
    let file =
        std::fs::File::create(&path).with_context(|| format!("creating {}", path.display()))?;
    model
        .write_ply(std::io::BufWriter::new(file))
        .with_context(|| format!("writing {}", path.display()))?;
    println!(
        "dense model: {} points from {} keyframes ({:.1} cm voxels, seen from ≥ {}) in {:.1} s",
        model.points().len(),
        model.views(),
        config.voxel_size * 100.0,
        config.min_views,
        t.elapsed().as_secs_f64()
    );
    Ok(())
}

/// The vocabulary of appearance-based loop closure (printed: where it came from).
fn vocabulary(loops: &system::config::LoopConfig) -> Result<Arc<vision::bow::Vocabulary>> {
    let orb = loops.place_recognition.orb.params();
    let root = data::paths::dataset_root();
    let voc = load_vocabulary(loops.vocabulary.as_deref(), root.as_deref(), &orb)
        .context("the vocabulary of appearance-based loop closure (loops.vocabulary in --config; loops.enabled: false runs without)")?;
    println!(
        "  loop closure: vocabulary of {} words, {}",
        voc.vocabulary.num_words(),
        match &voc.origin {
            VocabularyOrigin::File(p) => format!("from {}", p.display()),
            VocabularyOrigin::Shipped => "the shipped default".into(),
            VocabularyOrigin::Cache(p) => format!("cached in {}", p.display()),
            VocabularyOrigin::Trained { seconds, .. } =>
                format!("trained in {seconds:.1} s on the default training images"),
        }
    );
    Ok(voc.vocabulary)
}

/// The stream and where its outputs go, for [`drive`].
struct Run {
    frames: usize,
    ground_truth: Option<Trajectory>,
    skip_bad_frames: bool,
    stream: Box<dyn Iterator<Item = Result<Frame>>>,
    stop: Arc<AtomicBool>,
    output: RunOutput,
}

/// The frame loop and everything after it: the progress bar, the outputs (with `extra`
/// writing what only a sensor has), ATE/RPE after `alignment` (`Sim3` for a monocular run,
/// whose scale is its own), the report.
fn drive<S: LiveRun>(
    mut system: S,
    run: Run,
    settings: &Settings,
    alignment: Alignment,
    extra: impl FnOnce(&RunResult) -> Result<()>,
) -> Result<Outcome> {
    let Run {
        frames,
        ground_truth,
        skip_bad_frames,
        stream,
        stop,
        mut output,
    } = run;
    let start = Instant::now();
    let ended = frame_loop(
        &mut system,
        stream,
        &mut output,
        (frames, skip_bad_frames, settings.quiet),
        &stop,
    )?;
    let seconds = start.elapsed().as_secs_f64();
    let stopped = stop.load(Ordering::SeqCst);
    let result = system.finish(stopped || ended.failure.is_some())?;
    print_result(&result, seconds, stopped);
    let ground_truth = ground_truth.as_ref();
    let evaluation = ground_truth.map(|gt| evaluate(gt, &result, alignment));
    let mut record = result.record.clone();
    record.extra.extend(summary_extra(
        &result,
        settings.mode,
        seconds,
        evaluation.as_ref(),
    ));
    // The map's size and the process's memory every hundred frames (bounded memory on
    // revisits, issue 43).
    record
        .extra
        .insert("over_time".into(), json!(ended.over_time));
    output.write(&record, ground_truth)?;
    if let Some(e) = &evaluation {
        for line in &e.lines {
            println!("{line}");
        }
    }
    write_trajectories(&settings.out, &result, ground_truth, alignment)?;
    print_loops(&result);
    write_frame_stats(&settings.out.join(FRAME_STATS_FILE), &result)?;
    write_optimisation_stats(&settings.out.join(OPTIMISATION_STATS_FILE), &result)?;
    extra(&result)?;
    report(&settings.out, &result, ground_truth, alignment)?;
    println!("wrote {}", settings.out.display());
    match &result.saved_map {
        Some(Ok(m)) => println!(
            "saved map {} ({:.1} MB in {:.2} s): {}",
            m.path.display(),
            m.bytes as f64 / 1e6,
            m.seconds,
            map_line(&m.summary)
        ),
        Some(Err(e)) => bail!("the run's outputs are written, but its map is not: {e}"),
        None => {}
    }
    let outcome = Outcome {
        frames: result.record.frames.len(),
        seconds,
        lost: ended.lost,
        keyframes: result.record.keyframes.len(),
        loops: result.loops.len(),
        ate: evaluation.as_ref().and_then(|e| e.ate),
    };
    match ended.failure {
        Some(e) => Err(e),
        None => Ok(outcome),
    }
}

/// How the frame loop ended: what stopped it early, how many frames were lost, and the map's
/// size and the process's memory over the run.
struct LoopEnd {
    failure: Option<anyhow::Error>,
    lost: usize,
    over_time: Vec<serde_json::Value>,
}

/// Frames between two samples of `summary.json`'s `over_time`.
const SAMPLE_EVERY: usize = 100;

/// The process's resident memory in MB (Linux: `/proc/self/statm`), if known.
fn resident_mb() -> Option<f64> {
    let statm = std::fs::read_to_string("/proc/self/statm").ok()?;
    let pages: f64 = statm.split_whitespace().nth(1)?.parse().ok()?;
    // SAFETY: sysconf has no preconditions.
    let page = unsafe { libc::sysconf(libc::_SC_PAGESIZE) };
    (page > 0).then(|| pages * page as f64 / 1e6)
}

/// Every frame of `stream` through `system` (a bad frame skipped or the end of the run, as
/// `--on-bad-frame` says), each frame's line into the log, with a progress bar (`frames`
/// long, hidden if `quiet`); until the stream ends, a frame fails or `stop` (Ctrl-C).
fn frame_loop<S: LiveRun>(
    system: &mut S,
    stream: Box<dyn Iterator<Item = Result<Frame>>>,
    output: &mut RunOutput,
    (frames, skip_bad_frames, quiet): (usize, bool, bool),
    stop: &AtomicBool,
) -> Result<LoopEnd> {
    let bar = if quiet {
        ProgressBar::hidden()
    } else {
        ProgressBar::new(frames as u64)
    };
    bar.set_style(
        ProgressStyle::with_template(
            "[{bar:30}] {pos}/{len} frames {per_sec} {elapsed_precise} {msg}",
        )
        .expect("valid template")
        .progress_chars("=> "),
    );
    let mut failure: Option<anyhow::Error> = None;
    let (mut lost, mut weak, mut keyframes) = (0usize, 0usize, 0usize);
    let mut over_time = Vec::new();
    let mut processed = 0usize;
    let started = Instant::now();
    let sample = |processed: usize, system: &S| {
        let p = system.progress();
        json!({"frames": processed, "seconds": started.elapsed().as_secs_f64(),
               "keyframes": p.keyframes, "points": p.points, "resident_mb": resident_mb()})
    };
    let mut waited = Instant::now();
    for item in stream {
        system.record_timing("reader: wait", waited.elapsed());
        if stop.load(Ordering::SeqCst) {
            break;
        }
        match item {
            Ok(frame) => match system.process(frame) {
                Ok(report) => {
                    match report.state {
                        TrackingState::Lost(_) => lost += 1,
                        TrackingState::Weak(_) => weak += 1,
                        TrackingState::Good => {}
                    }
                    keyframes += report.keyframe.is_some() as usize;
                }
                Err(e) => {
                    failure = Some(e.into());
                    break;
                }
            },
            Err(e) => match e.downcast_ref::<FrameError>() {
                Some(bad) if skip_bad_frames => {
                    bar.println(format!("warning: skipped {bad}"));
                    system.skip_frame(bad.index, bad.timestamp, format!("skipped: {}", bad.kind));
                }
                Some(_) => {
                    failure = Some(e.context(
                        "stopped at a bad frame (--on-bad-frame skip reads past it); the outputs hold the frames before it",
                    ));
                    break;
                }
                None => {
                    failure = Some(e);
                    break;
                }
            },
        }
        if let Some(f) = system.record().frames.last() {
            output.log_frame(f)?;
        }
        bar.inc(1);
        processed += 1;
        if processed.is_multiple_of(SAMPLE_EVERY) {
            over_time.push(sample(processed, system));
        }
        let progress = system.progress();
        bar.set_message(format!(
            "{keyframes} keyframes, {} points, {} loops, {weak} weak, {lost} lost",
            progress.points, progress.loops
        ));
        waited = Instant::now();
    }
    bar.finish_and_clear();
    if !processed.is_multiple_of(SAMPLE_EVERY) {
        over_time.push(sample(processed, system));
    }
    Ok(LoopEnd {
        failure,
        lost,
        over_time,
    })
}

/// The run's warnings and its one-line summary (`interrupted` by Ctrl-C).
fn print_result(result: &RunResult, seconds: f64, interrupted: bool) {
    let processed = result.record.frames.len();
    for w in &result.warnings {
        println!("warning: {w}");
    }
    println!(
        "{processed} frames in {seconds:.1} s ({:.1} frames per second), {} keyframes, {} points, {} loop closure{}{}{}",
        processed as f64 / seconds.max(1e-9),
        result.record.keyframes.len(),
        result.record.points.len(),
        result.loops.len(),
        if result.loops.len() == 1 { "" } else { "s" },
        match result.relocalisations.len() {
            0 => String::new(),
            1 => ", 1 relocalisation".into(),
            n => format!(", {n} relocalisations"),
        } + &match (
            result.new_maps.len(),
            result.new_maps.iter().filter(|m| m.joined).count(),
        ) {
            (0, _) => String::new(),
            (1, 1) => ", 1 new map after a loss (in the map written)".into(),
            (1, _) => ", 1 new map after a loss".into(),
            (n, j) => format!(", {n} new maps after losses ({j} in the map written)"),
        },
        if interrupted { " — interrupted" } else { "" }
    );
}

/// What `summary.json` says beside the run's record: how it ran, why keyframes were made,
/// the warnings, loops, relocalisations, new maps, refused loops, optimisations, the tracking
/// thread's lock waits, and the evaluation.
fn summary_extra(
    result: &RunResult,
    mode: Mode,
    seconds: f64,
    evaluation: Option<&Evaluation>,
) -> serde_json::Map<String, serde_json::Value> {
    let mut extra = serde_json::Map::new();
    let processed = result.record.frames.len();
    extra.insert(
        "run".into(),
        json!({
            "mode": match mode { Mode::Threaded => "threaded", Mode::Deterministic => "deterministic" },
            "seconds": seconds,
            "frames_per_second": processed as f64 / seconds.max(1e-9),
        }),
    );
    let mut reasons = std::collections::BTreeMap::<&str, usize>::new();
    for f in &result.frames {
        if let Some((_, r)) = &f.keyframe {
            *reasons.entry(r.name()).or_default() += 1;
        }
    }
    extra.insert("keyframe_reasons".into(), json!(reasons));
    extra.insert(
        "keyframes_made".into(),
        json!(
            result
                .frames
                .iter()
                .filter(|f| f.keyframe.is_some())
                .count()
        ),
    );
    if let Some(saved) = &result.saved_map {
        extra.insert(
            "saved_map".into(),
            match saved {
                Ok(m) => json!({"path": m.path, "bytes": m.bytes, "seconds": m.seconds,
                    "holds": m.summary}),
                Err(e) => json!({"error": e}),
            },
        );
    }
    extra.insert("warnings".into(), json!(result.warnings));
    extra.insert(
        "loops".into(),
        json!(
            result
                .loops
                .iter()
                .map(|l| json!({
        "keyframe": l.keyframe.index(), "old": l.old.index(),
        "frame": l.frames.0, "old_frame": l.frames.1, "kind": l.kind, "scale": l.scale,
        "scale_log_sigma": l.scale_sigma, "detections_agreeing": l.agreeing,
        "correction_m": l.correction.map(|d| d.displacement),
        "path_m": l.correction.map(|d| d.path),
        "ransac_inliers": l.evidence.map(|e| e.ransac_inliers),
        "old_points_found": l.evidence.map(|e| e.old_points_found),
        "old_points_predicted": l.evidence.map(|e| e.old_points_predicted)}))
                .collect::<Vec<_>>()
        ),
    );
    extra.insert(
        "relocalisations".into(),
        json!(
            result
                .relocalisations
                .iter()
                .map(|r| json!({
        "frame": r.frame, "keyframe": r.keyframe.index(),
        "keyframe_frame": r.keyframe_frame, "ransac_inliers": r.ransac_inliers,
        "tracked": r.tracked}))
                .collect::<Vec<_>>()
        ),
    );
    extra.insert(
        "new_maps".into(),
        json!(
            result
                .new_maps
                .iter()
                .map(|m| json!({
        "frame": m.frame, "lost_s": m.lost_for, "map": m.map,
        "joined": m.joined, "frames": m.frames}))
                .collect::<Vec<_>>()
        ),
    );
    extra.insert(
        "refused_loops".into(),
        json!(
            result
                .refused_loops
                .iter()
                .map(|r| json!({
        "frame": r.frames.0, "old_frame": r.frames.1,
        "correction_m": r.drift.displacement, "path_m": r.drift.path,
        "scene_depth_m": r.drift.scene_depth, "allowed_m": r.allowed, "reason": r.reason}))
                .collect::<Vec<_>>()
        ),
    );
    let dwo: Vec<f64> = result
        .optimisations
        .iter()
        .map(|s| s.total().as_secs_f64() * 1e3)
        .collect();
    extra.insert(
        "optimisation".into(),
        json!({"count": dwo.len(), "median_ms": median(&dwo), "max_ms": dwo.iter().copied().fold(0.0, f64::max)}),
    );
    let waits = &result.lock_waits;
    let ms = |d: std::time::Duration| d.as_secs_f64() * 1e3;
    extra.insert(
        "tracking_lock_waits".into(),
        json!({"locks": waits.count, "median_ms": ms(waits.median), "p99_ms": ms(waits.p99),
            "max_ms": ms(waits.max), "frames_over_1ms": waits.frames_over_1ms}),
    );
    if let Some(e) = evaluation {
        extra.insert("evaluation".into(), e.json.clone());
    }
    extra
}

/// The trajectory after the run (`trajectory_final.tum`) and the alternatives (each with its
/// ATE against `ground_truth`, printed).
fn write_trajectories(
    out: &Path,
    result: &RunResult,
    ground_truth: Option<&Trajectory>,
    alignment: Alignment,
) -> Result<()> {
    let tum = |t: &Trajectory| -> Result<Vec<u8>> {
        let mut buf = Vec::new();
        write_tum(t, &mut buf)?;
        Ok(buf)
    };
    let final_path = out.join(FINAL_TRAJECTORY_FILE);
    std::fs::write(&final_path, tum(&result.final_trajectory)?)
        .with_context(|| format!("writing {}", final_path.display()))?;
    for (stem, trajectory) in &result.alternatives {
        let path = out.join(format!("{stem}.tum"));
        std::fs::write(&path, tum(trajectory)?)
            .with_context(|| format!("writing {}", path.display()))?;
        if let Some(gt) = ground_truth {
            let (r, e) = data::trajectory::associate_trajectories(gt, trajectory, 0.02, 0.0);
            if let Ok(a) = ate(&r, &e, alignment) {
                println!(
                    "{stem}: ATE RMSE {:.2} cm ({} poses, {} alignment)",
                    a.translation.rmse * 100.0,
                    r.len(),
                    alignment_name(alignment)
                );
            }
        }
    }
    Ok(())
}

/// The monocular loops and map joins, with their scales.
fn print_loops(result: &RunResult) {
    for l in result.loops.iter().filter(|l| l.scale.is_some()) {
        if l.kind == "merge" {
            // Two monocular maps: the scale is that of one map's world in the other's.
            println!(
                "map join: frame {} sees the place of frame {} of an earlier map, scale {:.3} \
                 between the two maps",
                l.frames.0,
                l.frames.1,
                l.scale.unwrap_or(1.0)
            );
        } else {
            println!(
                "loop: frame {} sees the place of frame {}, scale drift {:.3}",
                l.frames.0,
                l.frames.1,
                l.scale.unwrap_or(1.0)
            );
        }
    }
}

fn write_frame_stats(path: &Path, result: &RunResult) -> Result<()> {
    use std::fmt::Write as _;
    let mut text = String::from(
        "frame,state,keyframe,candidates,visible,searched,found,inliers,tracking_ms,frame_ms\n",
    );
    for f in &result.frames {
        let s = f.stats.clone().unwrap_or_default();
        let _ = writeln!(
            text,
            "{},{},{},{},{},{},{},{},{:.3},{:.3}",
            f.index,
            f.state.name(),
            f.keyframe.as_ref().map_or(String::new(), |(k, r)| format!(
                "{}:{}",
                k.index(),
                r.name()
            )),
            s.candidates,
            s.visible,
            s.searched,
            s.found,
            s.inliers,
            f.time_tracking.as_secs_f64() * 1e3,
            f.time.as_secs_f64() * 1e3
        );
    }
    std::fs::write(path, text).with_context(|| format!("writing {}", path.display()))
}

fn write_optimisation_stats(path: &Path, result: &RunResult) -> Result<()> {
    use std::fmt::Write as _;
    let mut text = String::from(
        "optimisation,inner_keyframes,outer_keyframes,points,point_constraints,pose_constraints,setup_ms,structure_ms,joint_ms,apply_ms,total_ms\n",
    );
    let ms = |d: std::time::Duration| d.as_secs_f64() * 1e3;
    for (i, s) in result.optimisations.iter().enumerate() {
        let _ = writeln!(
            text,
            "{i},{},{},{},{},{},{:.3},{:.3},{:.3},{:.3},{:.3}",
            s.inner_frames,
            s.outer_frames,
            s.points,
            s.point_constraints,
            s.pose_constraints,
            ms(s.time_setup),
            ms(s.time_structure),
            ms(s.time_joint),
            ms(s.time_apply),
            ms(s.total())
        );
    }
    std::fs::write(path, text).with_context(|| format!("writing {}", path.display()))
}

fn alignment_name(a: Alignment) -> &'static str {
    match a {
        Alignment::None => "none",
        Alignment::Se3 => "se3",
        Alignment::Sim3 => "sim3",
    }
}

fn sensor_name(s: &SensorModel) -> &'static str {
    match s {
        SensorModel::Mono(_) => "monocular",
        SensorModel::Stereo(_) => "stereo",
        SensorModel::Rgbd(_) => "RGB-D",
    }
}

fn median(v: &[f64]) -> f64 {
    let mut v: Vec<f64> = v.iter().copied().filter(|x| x.is_finite()).collect();
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

/// ATE and RPE of the live and the final trajectory against the ground truth.
struct Evaluation {
    json: serde_json::Value,
    lines: Vec<String>,
    /// ATE RMSE (m) of the live and the final trajectory, when both were evaluated.
    ate: Option<(f64, f64)>,
}

fn evaluate(gt: &Trajectory, result: &RunResult, alignment: Alignment) -> Evaluation {
    let live = result.record.trajectory();
    let mut json = serde_json::Map::new();
    let mut lines = Vec::new();
    for (name, est) in [("live", &live), ("final", &result.final_trajectory)] {
        let pairs = associate(&gt.timestamps, &est.timestamps, 0.02, 0.0);
        if pairs.len() < 3 {
            lines.push(format!(
                "{name} trajectory: {} poses overlap the ground truth in time: not evaluated",
                pairs.len()
            ));
            continue;
        }
        let r: Vec<Se3> = pairs.iter().map(|&(i, _)| gt.world_from_body[i]).collect();
        let e: Vec<Se3> = pairs.iter().map(|&(_, j)| est.world_from_body[j]).collect();
        let Ok(a) = ate(&r, &e, alignment) else {
            continue;
        };
        let rp = rpe(&r, &e, 1, false, alignment).ok();
        // KITTI's drift per distance, on paths long enough for a 100 m segment.
        let dr = drift(&r, &e, &KITTI_SEGMENT_LENGTHS, 10, alignment).ok();
        lines.push(format!(
            "{name} trajectory ({} of {} frames with ground truth): ATE RMSE {:.2} cm (median {:.2}, max {:.2}), RPE {}",
            pairs.len(),
            result.record.frames.len(),
            a.translation.rmse * 100.0,
            a.translation.median * 100.0,
            a.translation.max * 100.0,
            rp.as_ref().map_or("—".into(), |p| format!(
                "{:.2} mm, {:.3}° per frame",
                p.translation.rmse * 1e3,
                p.rotation_rad.rmse.to_degrees()
            ))
        ) + &dr.as_ref().map_or(String::new(), |d| format!(
            ", drift {:.2} % and {:.3}°/100 m (KITTI's relative error over {}–{} m)",
            d.translation_percent,
            d.rotation_deg_per_100m,
            d.per_length[0].0,
            d.per_length[d.per_length.len() - 1].0
        )));
        json.insert(
            name.into(),
            json!({
                "poses": pairs.len(),
                "ate_rmse_m": a.translation.rmse,
                "ate_median_m": a.translation.median,
                "ate_max_m": a.translation.max,
                "rpe_translation_rmse_m": rp.as_ref().map(|p| p.translation.rmse),
                "rpe_rotation_rmse_deg": rp.as_ref().map(|p| p.rotation_rad.rmse.to_degrees()),
                "drift_translation_percent": dr.as_ref().map(|d| d.translation_percent),
                "drift_rotation_deg_per_100m": dr.as_ref().map(|d| d.rotation_deg_per_100m),
                "alignment": alignment_name(alignment),
            }),
        );
    }
    let rmse = |name: &str| json.get(name).and_then(|v| v["ate_rmse_m"].as_f64());
    let ate = rmse("live").zip(rmse("final"));
    Evaluation {
        json: serde_json::Value::Object(json),
        lines,
        ate,
    }
}

const AXES: [&str; 3] = ["x", "y", "z"];

/// The two axes (in order) along which `points` spread most: the plane of a top view.
fn top_axes(points: impl Iterator<Item = nalgebra::Vector3<f64>>) -> (usize, usize) {
    let (mut n, mut sum, mut sq) = (0.0, nalgebra::Vector3::zeros(), nalgebra::Vector3::zeros());
    for p in points {
        n += 1.0;
        sum += p;
        sq += p.component_mul(&p);
    }
    if n < 2.0 {
        return (0, 2);
    }
    let var = sq / n - (sum / n).component_mul(&(sum / n));
    let least = (0..3)
        .min_by(|&i, &j| var[i].total_cmp(&var[j]))
        .unwrap_or(1);
    match least {
        0 => (1, 2),
        1 => (0, 2),
        _ => (0, 1),
    }
}

/// The points of `(timestamp, point)` samples in time order, with a break (a `NaN` point,
/// which [`plot::plot`] does not join across) where two samples are more than `gap` seconds
/// apart.
fn broken_at_gaps(
    samples: impl IntoIterator<Item = (f64, (f64, f64))>,
    gap: f64,
) -> Vec<(f64, f64)> {
    let mut out = Vec::new();
    let mut last: Option<f64> = None;
    for (t, p) in samples {
        if last.is_some_and(|l| t - l > gap) {
            out.push((f64::NAN, f64::NAN));
        }
        out.push(p);
        last = Some(t);
    }
    out
}

/// The report: trajectory against ground truth (top view), the keyframe graph with its loop
/// edges, time per frame and per keyframe, tracked points per frame.
fn report(
    out: &Path,
    result: &RunResult,
    ground_truth: Option<&Trajectory>,
    alignment: Alignment,
) -> Result<()> {
    trajectory_plot(out, result, ground_truth, alignment)?;
    keyframe_graph_plot(out, result)?;
    timing_plots(out, result)?;
    tracked_points_plot(out, result)
}

/// `trajectory.png`: the live trajectory and the one after the run against the ground truth,
/// aligned to it (top view), the relocalised frames marked.
fn trajectory_plot(
    out: &Path,
    result: &RunResult,
    ground_truth: Option<&Trajectory>,
    alignment: Alignment,
) -> Result<()> {
    let live = result.record.trajectory();
    // The top view: the plane of the two axes along which the path spreads most (a hand-held
    // or driven camera moves little vertically, whichever axis a dataset calls up: y down in
    // TUM and KITTI, z up in EuRoC and the renderer).
    let (a, b) = top_axes(
        ground_truth
            .map_or(&live.world_from_body, |g| &g.world_from_body)
            .iter()
            .map(|p| *p.translation()),
    );
    let xz = |p: &Se3| {
        let t = p.translation();
        (t[a], t[b])
    };
    // Trajectories, aligned to the ground truth where there is one, as (timestamp, point).
    let mut series = Vec::new();
    let aligned = |traj: &Trajectory| -> Vec<(f64, (f64, f64))> {
        let unaligned = || {
            traj.timestamps
                .iter()
                .zip(&traj.world_from_body)
                .map(|(t, p)| (*t, xz(p)))
                .collect()
        };
        let Some(gt) = ground_truth else {
            return unaligned();
        };
        let pairs = associate(&gt.timestamps, &traj.timestamps, 0.02, 0.0);
        let r: Vec<Se3> = pairs.iter().map(|&(i, _)| gt.world_from_body[i]).collect();
        let e: Vec<Se3> = pairs
            .iter()
            .map(|&(_, j)| traj.world_from_body[j])
            .collect();
        match ate(&r, &e, alignment) {
            Ok(al) => pairs
                .iter()
                .zip(&e)
                .map(|(&(_, j), p)| {
                    let t = al.reference_from_estimate.act(p.translation());
                    (traj.timestamps[j], (t[a], t[b]))
                })
                .collect(),
            Err(_) => unaligned(),
        }
    };
    // Lines break where the frames in between have no pose (lost, or not in the sequence):
    // more than three frame intervals between two samples.
    let mut intervals: Vec<f64> = result
        .record
        .frames
        .windows(2)
        .map(|w| w[1].timestamp - w[0].timestamp)
        .filter(|d| *d > 0.0)
        .collect();
    intervals.sort_by(f64::total_cmp);
    let gap = 3.0
        * intervals
            .get(intervals.len() / 2)
            .copied()
            .unwrap_or(f64::INFINITY);
    if let Some(gt) = ground_truth {
        let samples = gt
            .timestamps
            .iter()
            .copied()
            .zip(gt.world_from_body.iter().map(xz));
        series.push(Series {
            label: "ground truth".into(),
            points: broken_at_gaps(samples, gap),
            color: GREY,
            style: Style::Line,
        });
    }
    let live_points = aligned(&live);
    series.push(Series {
        label: "every frame, live".into(),
        points: broken_at_gaps(live_points.iter().copied(), gap),
        color: PALETTE[0],
        style: Style::Line,
    });
    series.push(Series {
        label: "every frame, after the final optimisation".into(),
        points: broken_at_gaps(aligned(&result.final_trajectory), gap),
        color: PALETTE[1],
        style: Style::Dashed,
    });
    series.extend(relocalisation_markers(result, &live_points));
    plot::plot(
        &out.join("trajectory.png"),
        &Figure {
            title: &format!(
                "trajectory (top view, {}–{}), aligned to the ground truth",
                AXES[a], AXES[b]
            ),
            x_label: &format!("{} (m)", AXES[a]),
            y_label: &format!("{} (m)", AXES[b]),
            equal_aspect: true,
            log_y: false,
        },
        &series,
    )?;
    Ok(())
}

/// The relocalised frames' positions on the live trajectory (`live_points`, as plotted).
fn relocalisation_markers(result: &RunResult, live_points: &[(f64, (f64, f64))]) -> Option<Series> {
    if result.relocalisations.is_empty() {
        return None;
    }
    let stamp = |index: usize| {
        let f = result.record.frames.iter().find(|f| f.index == index)?;
        Some(f.timestamp)
    };
    Some(Series {
        label: format!("relocalised ({})", result.relocalisations.len()),
        points: result
            .relocalisations
            .iter()
            .filter_map(|r| {
                let t = stamp(r.frame)?;
                live_points
                    .iter()
                    .find(|(s, _)| (s - t).abs() < 1e-6)
                    .map(|(_, p)| *p)
            })
            .collect(),
        color: PALETTE[2],
        style: Style::Markers,
    })
}

/// `keyframe_graph.png`: the keyframes' centres, their covisibility edges and the loops (top
/// view, in the map's frame).
fn keyframe_graph_plot(out: &Path, result: &RunResult) -> Result<()> {
    // The keyframe graph: keyframe centres, covisibility edges, loop edges (in the map's
    // frame, the first keyframe's).
    let nodes: std::collections::BTreeMap<slam::map::KeyframeId, nalgebra::Vector3<f64>> = result
        .graph
        .keyframes()
        .into_iter()
        .map(|k| {
            (
                k.id,
                k.camera_from_world
                    .inverse()
                    .act(&nalgebra::Vector3::zeros()),
            )
        })
        .collect();
    let centre3 = |k| nodes.get(&k).copied();
    let (ga, gb) = top_axes(nodes.values().copied());
    let centre = |k| centre3(k).map(|c| (c[ga], c[gb]));
    let mut edges = Vec::new();
    for (a, b) in result.graph.edges() {
        if let (Some(p), Some(q)) = (centre(a), centre(b)) {
            edges.push(p);
            edges.push(q);
        }
    }
    let mut loop_edges = Vec::new();
    for l in &result.loops {
        if let (Some(p), Some(q)) = (centre(l.keyframe), centre(l.old)) {
            loop_edges.push(p);
            loop_edges.push(q);
        }
    }
    plot::plot(
        &out.join("keyframe_graph.png"),
        &Figure {
            title: "keyframe graph (top view): covisibility edges, loop closures",
            x_label: &format!("{} (m)", AXES[ga]),
            y_label: &format!("{} (m)", AXES[gb]),
            equal_aspect: true,
            log_y: false,
        },
        &[
            Series {
                label: "covisibility edges".into(),
                points: edges,
                color: GREY,
                style: Style::Segments,
            },
            Series {
                label: format!("loop closures ({})", result.loops.len()),
                points: loop_edges,
                color: PALETTE[1],
                style: Style::Segments,
            },
            Series {
                label: format!("keyframes ({})", nodes.len()),
                points: nodes.keys().filter_map(|&k| centre(k)).collect(),
                color: PALETTE[0],
                style: Style::Points,
            },
        ],
    )?;
    Ok(())
}

/// `time_per_frame.png` (the tracking thread's time per frame) and `time_per_keyframe.png`
/// (the double window optimisations).
fn timing_plots(out: &Path, result: &RunResult) -> Result<()> {
    // Time per frame (tracking thread) and per optimisation.
    let frame_ms: Vec<(f64, f64)> = result
        .frames
        .iter()
        .map(|f| (f.index as f64, f.time.as_secs_f64() * 1e3))
        .collect();
    let tracking_ms: Vec<(f64, f64)> = result
        .frames
        .iter()
        .map(|f| (f.index as f64, f.time_tracking.as_secs_f64() * 1e3))
        .collect();
    plot::plot(
        &out.join("time_per_frame.png"),
        &Figure {
            title: "time per frame in the tracking thread",
            x_label: "frame",
            y_label: "ms",
            equal_aspect: false,
            log_y: false,
        },
        &[
            Series {
                label: "whole frame (with keyframe stages)".into(),
                points: frame_ms,
                color: PALETTE[0],
                style: Style::Points,
            },
            Series {
                label: "tracking".into(),
                points: tracking_ms,
                color: PALETTE[2],
                style: Style::Points,
            },
        ],
    )?;
    plot::plot(
        &out.join("time_per_keyframe.png"),
        &Figure {
            title: "double window optimisation per keyframe",
            x_label: "optimisation",
            y_label: "ms",
            equal_aspect: false,
            log_y: false,
        },
        &[Series {
            label: "set-up, structure and joint iterations, write-back".into(),
            points: result
                .optimisations
                .iter()
                .enumerate()
                .map(|(i, s)| (i as f64, s.total().as_secs_f64() * 1e3))
                .collect(),
            color: PALETTE[3],
            style: Style::Points,
        }],
    )?;
    Ok(())
}

/// `tracked_points.png`: per frame, the candidates visible, searched, found and inliers.
fn tracked_points_plot(out: &Path, result: &RunResult) -> Result<()> {
    let stat = |f: fn(&system::TrackerStats) -> usize| -> Vec<(f64, f64)> {
        result
            .frames
            .iter()
            .filter_map(|r| r.stats.as_ref().map(|s| (r.index as f64, f(s) as f64)))
            .collect()
    };
    plot::plot(
        &out.join("tracked_points.png"),
        &Figure {
            title: "points per frame",
            x_label: "frame",
            y_label: "points",
            equal_aspect: false,
            log_y: false,
        },
        &[
            Series {
                label: "visible candidates".into(),
                points: stat(|s| s.visible),
                color: GREY,
                style: Style::Line,
            },
            Series {
                label: "searched".into(),
                points: stat(|s| s.searched),
                color: PALETTE[0],
                style: Style::Line,
            },
            Series {
                label: "found".into(),
                points: stat(|s| s.found),
                color: PALETTE[2],
                style: Style::Line,
            },
            Series {
                label: "inliers".into(),
                points: stat(|s| s.inliers),
                color: PALETTE[1],
                style: Style::Line,
            },
        ],
    )?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A line breaks (a `NaN` point) exactly where two samples are more than the gap apart.
    #[test]
    fn trajectories_break_at_gaps_in_time() {
        let samples = [0.0, 0.1, 0.2, 0.9, 1.0, 1.35]
            .into_iter()
            .map(|t| (t, (t, 2.0 * t)));
        let points = broken_at_gaps(samples, 0.3);
        let breaks: Vec<usize> = points
            .iter()
            .enumerate()
            .filter(|(_, p)| p.0.is_nan())
            .map(|(i, _)| i)
            .collect();
        assert_eq!(breaks, vec![3, 6]);
        assert_eq!(points.len(), 8);
        assert_eq!(points[4], (0.9, 1.8));
    }
}
