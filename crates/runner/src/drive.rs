//! The run: a source of frames through a [`System`], the outputs, the summary and the
//! evaluation; what `dwslam run`, `dwslam demo` and the Python package share.

use crate::summary::{
    FRAME_STATS_FILE, OPTIMISATION_STATS_FILE, evaluate, print_loops, summary_extra,
    write_frame_stats, write_optimisation_stats, write_trajectories,
};
use anyhow::{Context, Result, bail};
use data::camera::SensorModel;
use data::eval::Alignment;
use data::output::{OutputOptions, RunOutput, Summary, TrackingState};
use data::sequence::{Frame, FrameError};
use data::trajectory::Trajectory;
use indicatif::{ProgressBar, ProgressStyle};
use serde_json::json;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;
use system::map_file::MapFile;
use system::vocabulary::{VocabularyOrigin, load_vocabulary};
use system::{LiveRun, Mode, Options, RunGraph, RunResult, System, SystemConfig};

/// The dense model of `--dense-ply`.
pub const DENSE_FILE: &str = "dense.ply";

/// A run's frames, in order (a frame that cannot be read is an error item). `Send`, so that
/// a caller may run the whole loop on another thread (the Python package runs it with the
/// interpreter released).
pub type Frames = Box<dyn Iterator<Item = Result<Frame>> + Send>;

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
    pub stream: Frames,
    /// How the depth images encode depth (an RGB-D recording; frames built elsewhere from
    /// raw depth values need it).
    pub depth: Option<data::camera::DepthCalibration>,
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
    /// Set to stop the run after the frame in hand (Ctrl-C in the binary, a signal seen by
    /// the Python package); the outputs are written for the frames before it.
    pub stop: Arc<AtomicBool>,
}

/// The maps of a run: saved at its end, loaded at its start (`--save-map`, `--load-map`).
#[derive(Default, Clone)]
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

/// Reads a map for `--load-map` (printed: what it holds and how long it took).
pub fn load_map(path: &Path) -> Result<Arc<MapFile>> {
    let t = Instant::now();
    let map = MapFile::read(path)?;
    println!(
        "loaded map {} in {:.2} s: {}",
        path.display(),
        t.elapsed().as_secs_f64(),
        map_line(&map.summary())
    );
    Ok(Arc::new(map))
}

/// One line of what a map holds.
pub fn map_line(s: &system::map_file::MapSummary) -> String {
    format!(
        "{} keyframes, {} points, {} maps, {} edges ({} marginalised), {} keypoints",
        s.keyframes, s.points, s.maps, s.edges, s.marginalised_edges, s.keypoints
    )
}

/// Pictures of a finished run, drawn into its output folder (the binary's report; the
/// Python package draws none): the folder, the result, the ground truth and the alignment
/// the evaluation used.
pub type Report<'a> = &'a dyn Fn(&Path, &RunResult, Option<&Trajectory>, Alignment) -> Result<()>;

/// What a live view sees of a run as it goes (`dwslam run --view`): every frame before the
/// system takes it, what became of it (with the points the front-end looked at: the system
/// reports them when a run has an observer), and the result at the end. Called in the
/// tracking thread: an observer hands its work on (the Rerun SDK batches and writes on its
/// own threads) rather than doing it there.
pub trait Observer {
    /// A frame, before the system processes it.
    fn frame(&mut self, frame: &Frame);
    /// What became of the frame: its report and its record (the pose as tracked), and the
    /// map on request (a copy made under the graph's read lock: ask for it sparingly).
    fn tracked(
        &mut self,
        report: &system::FrameReport,
        record: &data::output::FrameRecord,
        map: &dyn Fn() -> system::MapSnapshot,
    );
    /// The run's result (the map after the final optimisation, the trajectory after the
    /// run), with the ground truth and the alignment the evaluation uses.
    fn finished(
        &mut self,
        result: &RunResult,
        ground_truth: Option<&Trajectory>,
        alignment: Alignment,
    );
}

/// A finished run: what it measured, the live system's result and the summary written to
/// `summary.json`.
pub struct Finished {
    /// What the run measured.
    pub outcome: Outcome,
    /// The live system's result (every frame, the keyframes, the map, the final trajectory).
    pub result: RunResult,
    /// `summary.json`.
    pub summary: Summary,
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

/// Runs the live system on a source of frames and writes the outputs, the summary and
/// `report`'s pictures into `settings.out`.
pub fn execute(
    source: Source,
    settings: &Settings,
    report: Report,
    observer: Option<&mut (dyn Observer + '_)>,
) -> Result<Finished> {
    let Source {
        name,
        sensor,
        frames,
        ground_truth,
        skip_bad_frames,
        stream,
        depth: _,
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
    let stop = settings.stop.clone();
    let run = Run {
        frames,
        ground_truth,
        skip_bad_frames,
        stream,
        stop,
        output,
    };
    let dense_config = match &sensor {
        SensorModel::Stereo(s) => Some((*s, true)),
        SensorModel::Rgbd(r) => Some((r.stereo, false)),
        SensorModel::Mono(_) => None,
    }
    .map(|(camera, stereo)| (camera.pinhole, config.dense_model_for(&camera, stereo)));
    let system = new_system(
        &sensor,
        config,
        SystemSetup {
            mode: settings.mode,
            name,
            maps: settings.maps.clone(),
            keyframe_depth: settings.dense_ply,
            observe: observer.is_some(),
            faults,
        },
    )?;
    let alignment = alignment_of(&system);
    let dense = |result: &RunResult| -> Result<()> {
        match (&dense_config, &result.graph) {
            (Some((camera, config)), RunGraph::Depth(graph)) if settings.dense_ply => {
                write_dense_model(settings, result, graph, camera, config)
            }
            _ => Ok(()),
        }
    };
    drive(system, run, settings, (alignment, dense, report, observer))
}

/// How a run's [`System`] is set up beside its sensor and configuration.
pub struct SystemSetup {
    /// Threaded or deterministic back-end.
    pub mode: Mode,
    /// The input's name, for the outputs and a saved map.
    pub name: String,
    /// Maps saved and loaded.
    pub maps: MapOptions,
    /// Keep each keyframe's depth image (only the dense model needs it).
    pub keyframe_depth: bool,
    /// Report each frame's observed points (a live view).
    pub observe: bool,
    /// Faults for the back-end's threads (tests).
    pub faults: system::Faults,
}

/// The live system of a run, with the vocabulary its configuration asks for (loaded or
/// trained, printed): the one place `dwslam run`, `dwslam demo` and the Python package make
/// it, so that the same inputs give the same system.
pub fn new_system(
    sensor: &SensorModel,
    config: SystemConfig,
    setup: SystemSetup,
) -> Result<System> {
    let vocabulary = if config.loops.enabled {
        Some(vocabulary(&config.loops)?)
    } else {
        None
    };
    let maps = setup.maps;
    Ok(System::new(
        sensor,
        config,
        Options {
            mode: setup.mode,
            sequence: setup.name,
            vocabulary,
            keyframe_depth: setup.keyframe_depth,
            save_map: maps.save,
            load_map: maps.load,
            localise: maps.localise,
            config_text: maps.config_text,
            observe: setup.observe,
            faults: setup.faults,
        },
    )?)
}

/// How a run's trajectory is compared with the ground truth: a monocular map has a scale of
/// its own, so after a similarity; a metric one after a rigid motion.
pub fn alignment_of(system: &System) -> Alignment {
    if system.free_scale() {
        Alignment::Sim3
    } else {
        Alignment::Se3
    }
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
pub fn vocabulary(loops: &system::config::LoopConfig) -> Result<Arc<vision::bow::Vocabulary>> {
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
    stream: Frames,
    stop: Arc<AtomicBool>,
    output: RunOutput,
}

/// The frame loop and everything after it: the progress bar, the outputs (with `extra`
/// writing what only a sensor has), ATE/RPE after `alignment` (`Sim3` for a monocular run,
/// whose scale is its own), the report.
fn drive<'o, S: LiveRun>(
    mut system: S,
    run: Run,
    settings: &Settings,
    (alignment, extra, report, mut observer): (
        Alignment,
        impl FnOnce(&RunResult) -> Result<()>,
        Report,
        Option<&mut (dyn Observer + 'o)>,
    ),
) -> Result<Finished> {
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
        observer.as_deref_mut(),
    )?;
    let seconds = start.elapsed().as_secs_f64();
    let stopped = stop.load(Ordering::SeqCst);
    let result = system.finish(stopped || ended.failure.is_some())?;
    print_result(&result, seconds, stopped);
    let ground_truth = ground_truth.as_ref();
    if let Some(o) = observer {
        o.finished(&result, ground_truth, alignment);
    }
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
        None => Ok(Finished {
            outcome,
            summary: record.summary(),
            result,
        }),
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
fn frame_loop<'o, S: LiveRun>(
    system: &mut S,
    stream: Frames,
    output: &mut RunOutput,
    (frames, skip_bad_frames, quiet): (usize, bool, bool),
    stop: &AtomicBool,
    mut observer: Option<&mut (dyn Observer + 'o)>,
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
        if let (Ok(frame), Some(o)) = (&item, observer.as_deref_mut()) {
            o.frame(frame);
        }
        match item {
            Ok(frame) => match system.process(frame) {
                Ok(report) => {
                    if let (Some(o), Some(record)) =
                        (observer.as_deref_mut(), system.record().frames.last())
                    {
                        o.tracked(&report, record, &|| system.snapshot());
                    }
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
