//! `dwslam run PATH`: the live system on a recorded sequence (thesis §6.3–6.5): every frame's
//! pose and the map, with a progress bar, a clean stop on Ctrl-C, ATE/RPE at the end when the
//! sequence has ground truth, and a report of pictures.

use crate::args;
use anyhow::{Context, Result, bail};
use clap::Args;
use data::camera::SensorModel;
use data::eval::{Alignment, KITTI_SEGMENT_LENGTHS, ate, drift, rpe};
use data::output::{OutputOptions, RunOutput, TrackingState};
use data::sequence::{BadFramePolicy, Frame, FrameError, OpenOptions, Sequence, SequenceFormat};
use data::trajectory::{Trajectory, associate, write_tum};
use indicatif::{ProgressBar, ProgressStyle};
use lie::Se3;
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
    let (config, config_text) = args::system_config(args.config.as_deref())?;
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
                crate::map::map_line(&map.summary())
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
        maps: crate::map::MapOptions {
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
    pub maps: crate::map::MapOptions,
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
    crate::run_report::report(&settings.out, &result, ground_truth, alignment)?;
    println!("wrote {}", settings.out.display());
    match &result.saved_map {
        Some(Ok(m)) => println!(
            "saved map {} ({:.1} MB in {:.2} s): {}",
            m.path.display(),
            m.bytes as f64 / 1e6,
            m.seconds,
            crate::map::map_line(&m.summary)
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
    extra.insert("keyframes_culled".into(), json!(result.culled));
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
