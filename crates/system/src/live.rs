//! The live system (thesis §6.5.2): frames in, every frame's pose and the map out.
//!
//! Per frame, in the calling thread (the tracking thread): the sensor front-end (pyramid, FAST,
//! depth), the tracker (dense prior, guided search, motion-only BA), and, when the frame is a
//! keyframe, the keyframe pipeline's stages (`slam::mapping`: insertion with local
//! registration, metric loop closure, new points). Double window optimisation runs
//!
//! - in its own thread ([`Mode::Threaded`], the default), on the shared graph: it plans under a
//!   read lock, optimises without a lock and writes back under a short write lock, so tracking
//!   never waits for it; a new keyframe wakes it (a bounded channel of one: notifications that
//!   arrive while it works coalesce, it re-plans from the newest graph);
//! - or after every keyframe in the calling thread ([`Mode::Deterministic`]): the same stages
//!   at fixed points of the frame stream, so two runs give identical trajectories.
//!
//! Large-scale loop closure by appearance ([`crate::loops`], once a vocabulary is given with
//! [`LiveSystem::with_loop_closure`]) runs likewise: in a third thread fed by a bounded queue of
//! new keyframes, which wakes the optimisation after closing a loop; or inline after each
//! keyframe, before its optimisation.

use crate::association::KeyframeAssociation;
use crate::config::SystemConfig;
use crate::frame::{FrameData, FrameError, SensorFrontEnd, pixel_depth};
use crate::keyframes::{KeyframeReason, KeyframeStore, keyframe_reason, nearest_keyframe};
use crate::loops::{AppearanceLoop, LoopCloser, LoopEvidence, LoopJob};
use crate::place_recognition::{PlaceRecognition, PlaceRecognitionConfig, features};
use crate::tracker::{Tracked, TrackedThen, Tracker, TrackerStats};
use data::camera::SensorModel;
use data::output::{FrameRecord, KeyframeRecord, MapPoint, RunRecord, StageTimings, TrackingState};
use data::trajectory::Trajectory;
use geom::StereoCamera;
use lie::{LieGroup, Se3, Sim3};
use slam::dwo::{DoubleWindowOptimiser, DwoError, DwoParams, DwoStats};
use slam::loop_closure::LoopDrift;
use slam::map::{FIRST_MAP, KeyframeId, SharedGraph, SlamGraph};
use slam::mapping::{KeyframeReport, Mapper, MappingError};
use slam::tracking::TrackId;
use std::sync::mpsc::{Receiver, SyncSender, TrySendError, sync_channel};
use std::sync::{Arc, Mutex, RwLock};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

/// How the back-end runs.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum Mode {
    /// Double window optimisation in its own thread (the live system of thesis §6.5.2).
    #[default]
    Threaded,
    /// Everything in the calling thread, in a fixed order: identical outputs run to run.
    Deterministic,
}

/// Why the system stopped.
#[derive(Debug, thiserror::Error)]
pub enum SystemError {
    /// A frame could not be prepared.
    #[error(transparent)]
    Frame(#[from] FrameError),
    /// The keyframe pipeline failed.
    #[error("keyframe from frame {frame}: {source}")]
    Mapping {
        /// The frame.
        frame: usize,
        /// The cause.
        source: MappingError,
    },
    /// The double window optimisation failed.
    #[error("double window optimisation: {0}")]
    Optimisation(#[from] DwoError),
    /// The configuration is invalid.
    #[error(transparent)]
    Config(#[from] crate::config::ConfigError),
    /// Place recognition could not be set up.
    #[error(transparent)]
    PlaceRecognition(#[from] crate::place_recognition::PlaceRecognitionError),
}

/// What happened to one frame.
#[derive(Clone, Debug)]
pub struct FrameReport {
    /// The frame.
    pub index: usize,
    /// Its state.
    pub state: TrackingState,
    /// The keyframe it became, and why.
    pub keyframe: Option<(KeyframeId, KeyframeReason)>,
    /// The tracker's counts (none for the first frame).
    pub stats: Option<TrackerStats>,
    /// Time of the whole frame in the tracking thread.
    pub time: Duration,
    /// Time of the tracking stages (the keyframe pipeline excluded).
    pub time_tracking: Duration,
}

/// A loop closure the run made.
#[derive(Clone, Debug, PartialEq)]
pub struct LoopEvent {
    /// The new keyframe.
    pub keyframe: KeyframeId,
    /// The old keyframe it was joined to.
    pub old: KeyframeId,
    /// The frames the two keyframes were made from.
    pub frames: (usize, usize),
    /// `"metric"`, `"appearance"`, or `"merge"` (an appearance loop that joined a map started
    /// after a loss to the older one, moving the newer map onto it).
    pub kind: &'static str,
    /// The scale of the loop's similarity (monocular: the scale drift between the two
    /// places, thesis ch. 5; `None` for a rigid loop).
    pub scale: Option<f64>,
    /// The correction an appearance loop made to the new keyframe, against the path since
    /// the old one (stereo and RGB-D).
    pub correction: Option<LoopDrift>,
    /// What an appearance loop rests on (stereo and RGB-D).
    pub evidence: Option<LoopEvidence>,
}

/// A lost frame found again in the map by appearance ([`PlaceRecognition::relocalise`]) and
/// tracked from there.
#[derive(Clone, Debug, PartialEq)]
pub struct Relocalisation {
    /// The frame (its index in the sequence).
    pub frame: usize,
    /// The keyframe whose place it recognised.
    pub keyframe: KeyframeId,
    /// The frame that keyframe was made from.
    pub keyframe_frame: usize,
    /// Inliers of the appearance matches' RANSAC.
    pub ransac_inliers: usize,
    /// Map points tracked after it (motion-only BA inliers).
    pub tracked: usize,
}

/// A map started after the camera was lost for `tracker.new_map_after` seconds
/// ([`LiveSystem::start_map`]); monocular: a map bootstrapped again after tracking failed
/// (`crate::mono`), joined to an earlier one when a later keyframe recognises its place.
#[derive(Clone, Debug, PartialEq)]
pub struct NewMap {
    /// The frame it started at (its index in the sequence; monocular: the first frame of its
    /// bootstrap).
    pub frame: usize,
    /// Seconds the camera had been lost (monocular: since the last pose in the map before).
    pub lost_for: f64,
    /// Its number (`slam::map::SlamGraph::start_map`).
    pub map: usize,
    /// A loop (kind `"merge"`) joined it to the map written ([`RunResult::world_map`]),
    /// directly or through other maps, or it is that map: its frames are in the final
    /// trajectory.
    pub joined: bool,
    /// Frames tracked in it while it was not the first map's (these have no live pose unless it
    /// is the map written).
    pub frames: usize,
}

/// A loop found by appearance and verified, but refused: it would have moved its keyframe by
/// more than the drift the path between the two places allows (a place that looks like
/// another; `slam::loop_closure::LoopDrift`).
#[derive(Clone, Debug, PartialEq)]
pub struct RefusedLoop {
    /// The frames of the new and the old keyframe.
    pub frames: (usize, usize),
    /// The correction it needed, the path it was measured against and what that allows.
    pub drift: LoopDrift,
    /// The largest correction allowed for that path and scene (map units).
    pub allowed: f64,
}

/// Everything a run produced; `N` is the dimension of a measurement (3: stereo and RGB-D, 2:
/// monocular).
#[derive(Clone, Debug)]
pub struct RunResult<const N: usize = 3> {
    /// Every frame with its live pose (as tracked), the keyframes and the map after the final
    /// optimisation, per-stage timings.
    pub record: RunRecord,
    /// Every frame re-expressed relative to its reference keyframe after the final
    /// optimisation (`T = T_rel·T_ref`): the trajectory a user gets after the run.
    pub final_trajectory: Trajectory,
    /// Per frame: the tracker's counts and times.
    pub frames: Vec<FrameReport>,
    /// The loop closures.
    pub loops: Vec<LoopEvent>,
    /// The lost frames found again by appearance (stereo and RGB-D).
    pub relocalisations: Vec<Relocalisation>,
    /// The maps started after a loss.
    pub new_maps: Vec<NewMap>,
    /// The map written (its trajectories, keyframes and points): the one with the most
    /// keyframes, `slam::map::FIRST_MAP` unless a camera lost early went on in a new map for
    /// longer.
    pub world_map: usize,
    /// Appearance loops refused by the drift test (stereo and RGB-D; the monocular system
    /// counts its own in a warning).
    pub refused_loops: Vec<RefusedLoop>,
    /// The optimisations (time and window sizes of each).
    pub optimisations: Vec<DwoStats>,
    /// The final graph.
    pub graph: SlamGraph<N>,
    /// The keyframes' images.
    pub keyframes: KeyframeStore,
    /// What went wrong without stopping the run (an optimisation or a loop closure that
    /// failed, keyframes the loop closer had no room for).
    pub warnings: Vec<String>,
    /// Further trajectories after the run worth comparing with [`final_trajectory`]
    /// (monocular: the loops corrected in SE(3) instead of Sim(3)), by file stem.
    ///
    /// [`final_trajectory`]: Self::final_trajectory
    pub alternatives: Vec<(&'static str, Trajectory)>,
}

/// A live system as the run loop drives it: frames in order, then the result. The stereo /
/// RGB-D [`LiveSystem`] (`N = 3`) and the monocular [`crate::mono::MonoSystem`] (`N = 2`).
pub trait LiveRun<const N: usize> {
    /// Processes one frame.
    fn process(&mut self, frame: data::sequence::Frame) -> Result<FrameReport, SystemError>;
    /// Records a frame that could not be read: it has no pose; the state says why.
    fn skip_frame(&mut self, index: usize, timestamp: f64, reason: String);
    /// The record so far (for writing outputs while the run goes on).
    fn record(&self) -> &RunRecord;
    /// Records a stage's time measured outside (e.g. the reader's wait).
    fn record_timing(&mut self, stage: &str, d: Duration);
    /// Ends the run (`interrupted`: stopped before the end of the sequence) and collects the
    /// outputs.
    fn finish(self, interrupted: bool) -> Result<RunResult<N>, SystemError>;
    /// The map's size and the loops closed so far, for the progress bar.
    fn progress(&self) -> Progress;
}

/// What the progress bar shows of the map while a run goes on.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Progress {
    /// Points in the map.
    pub points: usize,
    /// Loop closures so far (metric and by appearance).
    pub loops: usize,
}

impl LiveRun<3> for LiveSystem {
    fn process(&mut self, frame: data::sequence::Frame) -> Result<FrameReport, SystemError> {
        LiveSystem::process(self, frame)
    }
    fn skip_frame(&mut self, index: usize, timestamp: f64, reason: String) {
        LiveSystem::skip_frame(self, index, timestamp, reason)
    }
    fn record(&self) -> &RunRecord {
        LiveSystem::record(self)
    }
    fn record_timing(&mut self, stage: &str, d: Duration) {
        LiveSystem::record_timing(self, stage, d)
    }
    fn finish(self, interrupted: bool) -> Result<RunResult<3>, SystemError> {
        LiveSystem::finish(self, interrupted)
    }
    fn progress(&self) -> Progress {
        Progress {
            points: self.graph.read().num_points(),
            // Metric loops, and the appearance loops (closed inline or by the loop-closure
            // thread), which join the list at the end of the run.
            loops: self.loops.len()
                + self
                    .appearance_loops
                    .lock()
                    .unwrap_or_else(|e| e.into_inner())
                    .len(),
        }
    }
}

/// The record and the report of a frame that could not be read (both systems'
/// [`LiveRun::skip_frame`]): no pose, lost for `reason`.
pub(crate) fn skipped_frame(
    index: usize,
    timestamp: f64,
    reason: String,
) -> (FrameRecord, FrameReport) {
    (
        FrameRecord {
            index,
            timestamp,
            world_from_camera: None,
            state: TrackingState::Lost(reason.clone()),
        },
        FrameReport {
            index,
            state: TrackingState::Lost(reason),
            keyframe: None,
            stats: None,
            time: Duration::ZERO,
            time_tracking: Duration::ZERO,
        },
    )
}

/// The double window optimisation thread.
struct Worker {
    wake: SyncSender<()>,
    handle: JoinHandle<DoubleWindowOptimiser>,
}

/// Where large-scale loop closure runs.
enum LoopStage {
    /// No vocabulary was given, or loop closure is disabled.
    Off,
    /// After each keyframe, in the calling thread (deterministic mode).
    Inline(Box<LoopCloser>),
    /// In its own thread, fed by a bounded queue.
    Thread {
        jobs: SyncSender<LoopJob>,
        handle: JoinHandle<LoopCloser>,
    },
}

/// The live stereo / RGB-D SLAM system.
pub struct LiveSystem {
    config: SystemConfig,
    mode: Mode,
    sensor: SensorFrontEnd,
    tracker: Tracker,
    graph: Arc<SharedGraph<3>>,
    store: Arc<RwLock<KeyframeStore>>,
    mapper: Mapper<StereoCamera, 3>,
    /// The optimiser while it runs in this thread (deterministic mode, and after the run).
    optimiser: Option<DoubleWindowOptimiser>,
    worker: Option<Worker>,
    optimisations: Arc<Mutex<Vec<DwoStats>>>,
    background_errors: Arc<Mutex<Vec<String>>>,
    loop_stage: LoopStage,
    appearance_loops: Arc<Mutex<Vec<AppearanceLoop>>>,
    /// Keyframes the loop closer's queue had no room for.
    loop_queue_full: usize,
    /// The loop closer's place-recognition database (and its configuration), where a lost
    /// frame is looked for.
    relocaliser: Option<(Arc<RwLock<PlaceRecognition>>, PlaceRecognitionConfig)>,
    /// Keep each keyframe's depth image in the store ([`LiveSystem::keyframe_depth`]).
    keep_depth: bool,
    relocalisations: Vec<Relocalisation>,
    /// The timestamp of the first of the lost frames up to now (`None` while tracked).
    lost_since: Option<f64>,
    /// The maps started after a loss: `(frame, seconds lost before it, map)`.
    new_maps: Vec<(usize, f64, usize)>,
    /// The frames tracked in a map other than the first, with no pose in the world then:
    /// `(position in record.frames, map, pose in that map, state as tracked)` — their live pose
    /// if that map turns out to be the world after all ([`LiveSystem::finish`]).
    off_first: Vec<(usize, usize, Sim3, TrackingState)>,
    next_track: TrackId,
    record: RunRecord,
    /// Per frame with a pose: `(frame position in record.frames, reference, T·T_ref⁻¹)`.
    relative: Vec<(usize, KeyframeId, Sim3)>,
    reports: Vec<FrameReport>,
    loops: Vec<LoopEvent>,
}

impl LiveSystem {
    /// A system for `sensor` (stereo or RGB-D) with `config`; `sequence` names the input in the
    /// outputs.
    pub fn new(
        sensor: &SensorModel,
        config: SystemConfig,
        mode: Mode,
        sequence: &str,
    ) -> Result<Self, SystemError> {
        config.validate()?;
        let front = SensorFrontEnd::new(sensor, &config)?;
        let camera = *front.camera();
        let sigma = config.pixel_noise;
        let tracker = Tracker::new(config.tracker.clone(), camera, sigma);
        let mapping = slam::mapping::MappingConfig {
            theta: config.mapping.theta,
            n2: config.mapping.n2,
            appearance_max_drift: slam::loop_closure::DriftLimits {
                of_path: config.loops.max_drift_of_path,
                of_scene_depth: config.loops.max_drift_of_scene_depth,
            },
            ..slam::mapping::MappingConfig::new(
                sigma,
                (2.0 * camera.pinhole.cx + 1.0, 2.0 * camera.pinhole.cy + 1.0),
                3,
            )
        };
        let mut params = DwoParams::new(
            config.optimiser.inner,
            config.optimiser.outer,
            camera.pinhole.fx,
            sigma,
        )
        .with_baseline(camera.baseline);
        params.iterations = config.optimiser.iterations;
        let graph = Arc::new(SharedGraph::new(SlamGraph::new()));
        let optimisations = Arc::new(Mutex::new(Vec::new()));
        let background_errors = Arc::new(Mutex::new(Vec::new()));
        let optimiser = DoubleWindowOptimiser::new(params);
        let (optimiser, worker) = match mode {
            Mode::Deterministic => (Some(optimiser), None),
            Mode::Threaded => (
                None,
                Some(spawn_worker(
                    optimiser,
                    graph.clone(),
                    camera,
                    optimisations.clone(),
                    background_errors.clone(),
                )),
            ),
        };
        Ok(LiveSystem {
            mode,
            sensor: front,
            tracker,
            graph,
            store: Arc::new(RwLock::new(KeyframeStore::new())),
            mapper: Mapper::new(camera, mapping),
            optimiser,
            worker,
            optimisations,
            background_errors,
            loop_stage: LoopStage::Off,
            appearance_loops: Arc::new(Mutex::new(Vec::new())),
            loop_queue_full: 0,
            relocaliser: None,
            keep_depth: true,
            relocalisations: Vec::new(),
            lost_since: None,
            new_maps: Vec::new(),
            off_first: Vec::new(),
            next_track: 0,
            record: RunRecord {
                sequence: sequence.to_string(),
                sensor: match sensor {
                    SensorModel::Stereo(_) => "stereo",
                    SensorModel::Rgbd(_) => "rgbd",
                    SensorModel::Mono(_) => "mono",
                }
                .to_string(),
                ..RunRecord::default()
            },
            relative: Vec::new(),
            reports: Vec::new(),
            loops: Vec::new(),
            config,
        })
    }

    /// Whether the keyframe store keeps each keyframe's depth image (the default): only the
    /// dense model fuses it (`crate::dense_model::fuse`, `dwslam run --dense-ply`), and at 4
    /// bytes a pixel it is half of what a keyframe's images take (a 640×480 RGB-D keyframe:
    /// 1.2 of 2.4 MB), which a long exploration holds for every keyframe. The grey image (the
    /// search's templates) and the colour (the map points' colours) stay.
    pub fn keyframe_depth(mut self, keep: bool) -> Self {
        self.keep_depth = keep;
        self
    }

    /// Closes large loops by appearance with `vocabulary` (see [`crate::loops`]), unless the
    /// configuration disables it: in its own thread in threaded mode, inline in deterministic
    /// mode. Call before the first frame.
    pub fn with_loop_closure(
        mut self,
        vocabulary: Arc<vision::bow::Vocabulary>,
    ) -> Result<Self, SystemError> {
        if !self.config.loops.enabled {
            return Ok(self);
        }
        let closer = LoopCloser::new(
            vocabulary,
            self.sensor.clone(),
            &self.config,
            self.mapper.config().clone(),
        )?;
        self.relocaliser = Some(closer.shared_database());
        self.loop_stage = match self.mode {
            Mode::Deterministic => LoopStage::Inline(Box::new(closer)),
            Mode::Threaded => {
                let (jobs, queue) = sync_channel::<LoopJob>(self.config.loops.queue);
                let (graph, store) = (self.graph.clone(), self.store.clone());
                let events = self.appearance_loops.clone();
                let errors = self.background_errors.clone();
                let wake = self.worker.as_ref().map(|w| w.wake.clone());
                let mut closer = closer;
                let handle = std::thread::Builder::new()
                    .name("loop closure".into())
                    .spawn(move || {
                        while let Ok(job) = queue.recv() {
                            match closer.process(&graph, &store, &job) {
                                Ok(Some(event)) => {
                                    events.lock().unwrap_or_else(|e| e.into_inner()).push(event);
                                    // The optimisation corrects the poses; a pending wake-up
                                    // will see the loop too.
                                    if let Some(wake) = &wake {
                                        let _ = wake.try_send(());
                                    }
                                }
                                Ok(None) => {}
                                Err(e) => errors
                                    .lock()
                                    .unwrap_or_else(|e| e.into_inner())
                                    .push(format!("loop closure at {}: {e}", job.keyframe)),
                            }
                        }
                        closer
                    })
                    .expect("a thread can be spawned");
                LoopStage::Thread { jobs, handle }
            }
        };
        Ok(self)
    }

    /// The shared graph (for viewers; hold its lock briefly).
    pub fn graph(&self) -> &Arc<SharedGraph<3>> {
        &self.graph
    }

    /// The record so far (for writing outputs while the run goes on).
    pub fn record(&self) -> &RunRecord {
        &self.record
    }

    /// Processes one frame.
    pub fn process(&mut self, frame: data::sequence::Frame) -> Result<FrameReport, SystemError> {
        let start = Instant::now();
        let index = frame.index;
        let t = Instant::now();
        let frame = Arc::new(self.sensor.prepare(frame)?);
        self.record
            .timings
            .record("frame: pyramid, FAST, depth", t.elapsed());
        let empty = self.graph.read().num_keyframes() == 0;
        let report = if empty {
            self.initialise(&frame)?
        } else {
            self.track(&frame)?
        };
        let report = FrameReport {
            time: start.elapsed(),
            ..report
        };
        self.record.timings.record("frame: total", report.time);
        debug_assert_eq!(self.record.frames.last().map(|f| f.index), Some(index));
        self.reports.push(report.clone());
        Ok(report)
    }

    /// Records a frame that could not be read (the reader's `--on-bad-frame skip`): it has no
    /// pose; the state says why.
    pub fn skip_frame(&mut self, index: usize, timestamp: f64, reason: String) {
        let (record, report) = skipped_frame(index, timestamp, reason);
        self.record.frames.push(record);
        self.reports.push(report);
    }

    fn initialise(&mut self, frame: &Arc<FrameData>) -> Result<FrameReport, SystemError> {
        if frame.depth.is_none() {
            return Ok(self.lost(
                frame,
                "no depth image to start the map from",
                Duration::ZERO,
            ));
        }
        let pose = Sim3::identity();
        let (keyframe, _) = self.make_keyframe(frame, pose, Vec::new(), None, false)?;
        self.tracker.set_pose(frame, Se3::identity(), 0);
        let state = TrackingState::Good;
        let state = self.push_frame(frame, Some(pose), state, Some(keyframe));
        Ok(FrameReport {
            index: frame.index,
            state,
            keyframe: Some((keyframe, KeyframeReason::First)),
            stats: None,
            time: Duration::ZERO,
            time_tracking: Duration::ZERO,
        })
    }

    fn track(&mut self, frame: &Arc<FrameData>) -> Result<FrameReport, SystemError> {
        let t = Instant::now();
        let store_lock = self.store.clone();
        let store = store_lock.read().unwrap_or_else(|e| e.into_inner());
        let tracked = self.tracker.track(&self.graph, &store, frame);
        drop(store);
        let Some(mut tracked) = tracked else {
            return Ok(self.lost(frame, "no reference keyframe to track against", t.elapsed()));
        };
        for (stage, d) in &tracked.timings {
            self.record.timings.record(stage, *d);
        }
        if matches!(tracked.state, TrackingState::Lost(_)) {
            let t = Instant::now();
            if let Some(found) = self.relocalise(frame) {
                tracked = found;
            }
            self.record.timings.record("track: relocalise", t.elapsed());
        }
        if matches!(tracked.state, TrackingState::Lost(_)) {
            let lost_for = frame.timestamp - *self.lost_since.get_or_insert(frame.timestamp);
            if lost_for >= self.config.tracker.new_map_after
                && let Some(report) =
                    self.start_map(frame, tracked.camera_from_world, lost_for, t)?
            {
                return Ok(report);
            }
        } else {
            self.lost_since = None;
        }
        let time_tracking = t.elapsed();
        self.record.timings.record("track: total", time_tracking);
        let Tracked {
            camera_from_world,
            state,
            matches,
            reference,
            then,
            median_depth,
            stats,
            ..
        } = tracked;
        // The keyframe the pose was tracked against (the reference may change below).
        let tracker_reference = reference;
        // Revisits reuse the map (thesis §6.5.2): the keyframe that sees most of what this frame
        // tracked becomes the reference when it is at least as near as the current one, so a
        // camera browsing a mapped place tracks against its keyframes instead of adding new ones.
        let reference = if matches!(state, TrackingState::Lost(_)) {
            reference
        } else {
            self.reuse_reference(reference, &camera_from_world, &matches)
        };
        let (reason, nearest) = if frame.depth.is_some() && !matches!(state, TrackingState::Lost(_))
        {
            let g = self.graph.read();
            // The keyframes metric loop closure would search (`N2`, thesis §6.4.1): a view one
            // of them covers is a revisit, not a new place.
            let hood = g.n2(reference, self.config.mapping.n2);
            let nearest = nearest_keyframe(
                &self.config.keyframes,
                &g,
                &hood,
                &camera_from_world,
                median_depth,
            );
            let reason = nearest.as_ref().and_then(|n| {
                keyframe_reason(&self.config.keyframes, n, stats.found, stats.searched)
            });
            (reason, nearest)
        } else {
            (None, None)
        };
        // A revisit: the next frame tracks against the keyframe that covers this view.
        let reference = match (&reason, &nearest) {
            (None, Some(n))
                if n.keyframe != reference
                    && self.graph.write().set_reference(n.keyframe).is_ok() =>
            {
                n.keyframe
            }
            _ => reference,
        };
        let keyframe = match reason {
            Some(reason) => {
                let t = Instant::now();
                // Inserted as tracked against `tracker_reference` then: rebased if another
                // thread moved it meanwhile (an optimisation, a merge).
                let tracked_against = Some((tracker_reference, then.reference_pose, then.version));
                let (k, _) =
                    self.make_keyframe(frame, camera_from_world, matches, tracked_against, false)?;
                self.record
                    .timings
                    .record("keyframe: pipeline", t.elapsed());
                Some((k, reason))
            }
            None => None,
        };
        // A lost frame has no pose: the prior it was searched around is a guess (after a jump,
        // metres off), not an estimate, and the trajectory holds estimates only.
        let lost = matches!(state, TrackingState::Lost(_));
        let state = self.push_frame_tracked(
            frame,
            (!lost).then_some(camera_from_world),
            state,
            keyframe.as_ref().map(|(k, _)| *k).or(Some(reference)),
            Some(&then),
        );
        Ok(FrameReport {
            index: frame.index,
            state,
            keyframe,
            stats: Some(stats),
            time: Duration::ZERO,
            time_tracking,
        })
    }

    /// Starts a new map at `frame`, lost for `lost_for` seconds, at the pose `guess` (the
    /// tracker's constant-velocity prediction): its first keyframe, in a map of its own
    /// (`slam::map::SlamGraph::start_map`), from which the next frames are tracked. An
    /// appearance loop from the new map into an older one later merges the two
    /// (`AppearanceClosure::Merged`). Not for a frame with too few corners with depth for the
    /// next frames to track (fewer than a good frame's inliers: a black or blurred frame);
    /// `None` then.
    fn start_map(
        &mut self,
        frame: &Arc<FrameData>,
        guess: Sim3,
        lost_for: f64,
        started: Instant,
    ) -> Result<Option<FrameReport>, SystemError> {
        if frame.depth.is_none() {
            return Ok(None);
        }
        let with_depth = frame
            .corners
            .corners()
            .iter()
            .filter(|c| frame.depth_at(c.u as f64, c.v as f64).is_some())
            .count();
        if with_depth < self.config.tracker.min_good {
            return Ok(None);
        }
        let (keyframe, map) = self.make_keyframe(frame, guess, Vec::new(), None, true)?;
        // Where the keyframe is now: a loop closed inline (deterministic) may have merged the
        // new map into the old one already.
        let (pose, now_in) = {
            let g = self.graph.read();
            (
                g.pose(keyframe).unwrap_or(guess),
                g.map_of(keyframe).unwrap_or(map),
            )
        };
        self.tracker.set_pose(frame, pose.rigid_part(), now_in);
        self.lost_since = None;
        self.new_maps.push((frame.index, lost_for, map));
        let time_tracking = started.elapsed();
        self.record.timings.record("track: total", time_tracking);
        // A weak state: the map goes on, but its place relative to the old one is a guess.
        let state = TrackingState::Weak(format!(
            "lost for {lost_for:.1} s: new map {map} started at the constant-velocity guess"
        ));
        let state = self.push_frame(frame, Some(pose), state, Some(keyframe));
        Ok(Some(FrameReport {
            index: frame.index,
            state,
            keyframe: Some((keyframe, KeyframeReason::NewMap)),
            stats: None,
            time: Duration::ZERO,
            time_tracking,
        }))
    }

    /// Looks for a lost frame in the map by appearance: the keyframe whose place it shows
    /// (verified by the 3-point RANSAC of loop closure, [`PlaceRecognition::relocalise`]), the
    /// pose that gives, and the frame tracked again from there against that keyframe's
    /// neighbourhood (guided search with the wide radius, motion-only BA). Accepted only if the
    /// tracking is good; else the tracker and the reference keyframe are left as they were.
    /// A frame without depth (an RGB-D frame with no depth image) is verified 2D–3D instead,
    /// by P3P RANSAC against the keyframe's points ([`verify::verify_absolute`]).
    ///
    /// [`verify::verify_absolute`]: crate::place_recognition::verify::verify_absolute
    fn relocalise(&mut self, frame: &Arc<FrameData>) -> Option<Tracked> {
        let (database, config) = self.relocaliser.as_ref()?;
        let depth = frame.depth.as_ref();
        let features = features::extract(
            frame.gray(),
            |u, v| depth.and_then(|d| pixel_depth(d, u, v)),
            Vec::new(),
            self.sensor.pinhole(),
            config,
        )
        .ok()?;
        let candidate = database
            .read()
            .unwrap_or_else(|e| e.into_inner())
            .relocalise(frame.index as u32, &features)?;
        let (pose, before) = {
            let g = self.graph.read();
            let old = g.pose(candidate.old).ok()?;
            (
                candidate.query_from_old.compose(&old).rigid_part(),
                g.reference(),
            )
        };
        let motion = self.tracker.motion();
        self.graph.write().set_reference(candidate.old).ok()?;
        let store_lock = self.store.clone();
        let store = store_lock.read().unwrap_or_else(|e| e.into_inner());
        let keyframe_frame = store
            .get(candidate.old)
            .map_or(usize::MAX, |i| i.frame_index);
        // Tracked from the verified pose, and once more from the pose that gives if it was
        // weak: the appearance matches' pose is good to centimetres, the map's to millimetres,
        // and a better prior finds more of the map (ORB-SLAM refines a relocalisation alike).
        let mut tracked = None;
        let mut prior = pose;
        for _ in 0..2 {
            self.tracker.restart(frame, prior);
            tracked = self.tracker.track(&self.graph, &store, frame);
            match &tracked {
                Some(t) if matches!(t.state, TrackingState::Weak(_)) => {
                    prior = t.camera_from_world.rigid_part();
                }
                _ => break,
            }
        }
        drop(store);
        match tracked {
            Some(t) if t.state == TrackingState::Good => {
                self.tracker.reset_velocity();
                self.relocalisations.push(Relocalisation {
                    frame: frame.index,
                    keyframe: candidate.old,
                    keyframe_frame,
                    ransac_inliers: candidate.ransac_inliers,
                    tracked: t.stats.inliers,
                });
                Some(t)
            }
            _ => {
                self.tracker.set_motion(motion);
                if let Some(r) = before {
                    let _ = self.graph.write().set_reference(r);
                }
                None
            }
        }
    }

    /// The keyframe to track the next frame against: of the keyframes observing this frame's
    /// matched points, the one observing most of them, if it is no farther from the camera than
    /// the current reference (else the current reference). Made the graph's reference.
    fn reuse_reference(
        &mut self,
        reference: KeyframeId,
        camera_from_world: &Sim3,
        matches: &[(slam::map::PointId, nalgebra::Vector3<f64>)],
    ) -> KeyframeId {
        let best = {
            let g = self.graph.read();
            let mut seen: std::collections::BTreeMap<KeyframeId, usize> = Default::default();
            for (p, _) in matches {
                if let Some(pt) = g.point(*p) {
                    for &o in pt.observers() {
                        *seen.entry(o).or_default() += 1;
                    }
                }
            }
            let centre = |t: &Sim3| t.inverse().act(&nalgebra::Vector3::zeros());
            let here = centre(camera_from_world);
            let distance = |k: KeyframeId| {
                g.pose(k)
                    .map_or(f64::INFINITY, |t| (centre(&t) - here).norm())
            };
            let own = seen.get(&reference).copied().unwrap_or(0);
            seen.into_iter()
                .filter(|&(k, n)| k != reference && n > own && distance(k) <= distance(reference))
                .max_by_key(|&(k, n)| (n, std::cmp::Reverse(k)))
                .map(|(k, _)| k)
        };
        match best {
            Some(k) if self.graph.write().set_reference(k).is_ok() => k,
            _ => reference,
        }
    }

    /// Records a frame without a pose, lost for `reason`, and its report.
    fn lost(&mut self, frame: &FrameData, reason: &str, time_tracking: Duration) -> FrameReport {
        let state = self.push_frame(frame, None, TrackingState::Lost(reason.into()), None);
        FrameReport {
            index: frame.index,
            state,
            keyframe: None,
            stats: None,
            time: Duration::ZERO,
            time_tracking,
        }
    }

    /// Records a frame's pose and state; `reference` is the keyframe its pose is kept relative
    /// to for the final trajectory. Returns the state recorded.
    ///
    /// Only a pose in the first map (or a map merged into it) is a pose in the world: a frame
    /// tracked in a map started after a loss ([`LiveSystem::start_map`]) that no loop has
    /// joined to the first yet has none (the new map's place in the world is the motion
    /// model's guess, not an estimate), and its state says so; its pose relative to its
    /// keyframe is kept, so that the final trajectory has it once the maps are merged.
    fn push_frame(
        &mut self,
        frame: &FrameData,
        camera_from_world: Option<Sim3>,
        state: TrackingState,
        reference: Option<KeyframeId>,
    ) -> TrackingState {
        self.push_frame_tracked(frame, camera_from_world, state, reference, None)
    }

    /// [`push_frame`](Self::push_frame) of a pose tracked against the graph as it was `then`:
    /// if its map was merged into another since (moved by the loop-closure thread, or by a loop
    /// closed inline while the frame became a keyframe), the pose moves with it.
    fn push_frame_tracked(
        &mut self,
        frame: &FrameData,
        camera_from_world: Option<Sim3>,
        state: TrackingState,
        reference: Option<KeyframeId>,
        then: Option<&TrackedThen>,
    ) -> TrackingState {
        let mut state = state;
        let g = self.graph.read();
        let camera_from_world = match (camera_from_world, then) {
            (Some(pose), Some(then)) => Some(
                g.moved_since(then.merges, then.map)
                    .map_or(pose, |(moved, _)| pose.compose(&moved)),
            ),
            (pose, _) => pose,
        };
        let mut world_pose = camera_from_world;
        if let (Some(pose), Some(r)) = (camera_from_world, reference) {
            if let Ok(t_r) = g.pose(r) {
                self.relative
                    .push((self.record.frames.len(), r, pose.compose(&t_r.inverse())));
            }
            if let Ok(map) = g.map_of(r)
                && map != FIRST_MAP
            {
                world_pose = None;
                self.off_first
                    .push((self.record.frames.len(), map, pose, state.clone()));
                state = TrackingState::Weak(match state {
                    TrackingState::Weak(reason) => format!(
                        "{reason}; in map {map}, not joined to the first map yet: no pose in the world"
                    ),
                    _ => format!(
                        "tracked in map {map}, which no loop has joined to the first map yet: no pose in the world"
                    ),
                });
            }
        }
        self.record.frames.push(FrameRecord {
            index: frame.index,
            timestamp: frame.timestamp,
            world_from_camera: world_pose.map(|t| t.rigid_part().inverse()),
            state: state.clone(),
        });
        state
    }

    /// Makes `frame` a keyframe at `camera_from_world` with its tracked `matches` (tracked
    /// against `tracked_against`, see `KeyframeAssociation::tracked_against`): the keyframe
    /// pipeline's stages, then the optimisation (inline, or by waking its thread). With
    /// `new_map`, the first keyframe of a new map (`slam::map::SlamGraph::start_map`), started
    /// under the same write lock, so that no other thread sees the new map without it (nor the
    /// graph without a reference keyframe, unless the pipeline fails, which stops the run).
    /// Returns the keyframe and the map it was made in.
    fn make_keyframe(
        &mut self,
        frame: &Arc<FrameData>,
        camera_from_world: Sim3,
        matches: Vec<(slam::map::PointId, nalgebra::Vector3<f64>)>,
        tracked_against: Option<(KeyframeId, Sim3, slam::map::Version)>,
        new_map: bool,
    ) -> Result<(KeyframeId, usize), SystemError> {
        let store_lock = self.store.clone();
        let store = store_lock.read().unwrap_or_else(|e| e.into_inner());
        let min_disparity = self.mapper.config().min_disparity;
        let mut association = KeyframeAssociation::new(
            frame,
            &store,
            &self.sensor,
            camera_from_world,
            matches,
            &self.config,
            min_disparity,
            &mut self.next_track,
        );
        association.tracked_against = tracked_against;
        let mut images = association.images();
        if !self.keep_depth {
            images.depth = None;
        }
        // The stages of the keyframe pipeline under the graph's write lock (they take a few
        // milliseconds; the optimisation is not among them).
        let (report, map) = {
            let mut graph = self.graph.write();
            if new_map {
                graph.start_map();
            }
            let report: KeyframeReport = self
                .mapper
                .map_keyframe(&mut graph, &mut association)
                .map_err(|source| SystemError::Mapping {
                    frame: frame.index,
                    source,
                })?;
            let map = graph.map_of(report.keyframe).unwrap_or(FIRST_MAP);
            (report, map)
        };
        let keyframe = report.keyframe;
        for (stage, d) in &report.stage_times {
            self.record.timings.record(stage, *d);
        }
        drop(store);
        self.store
            .write()
            .unwrap_or_else(|e| e.into_inner())
            .insert(keyframe, images);
        for closure in &report.metric_loops {
            self.loop_event(keyframe, closure.keyframe, "metric", None, None);
        }
        if let Some(old) = report.appearance_loop {
            self.loop_event(keyframe, old, "appearance", None, None);
        }
        self.close_large_loop(keyframe, frame);
        self.optimise()?;
        Ok((keyframe, map))
    }

    /// Hands a new keyframe to the loop closer: closes its loop now (inline) or queues it.
    fn close_large_loop(&mut self, keyframe: KeyframeId, frame: &Arc<FrameData>) {
        let job = LoopJob {
            keyframe,
            frame: frame.clone(),
        };
        match &mut self.loop_stage {
            LoopStage::Off => {}
            LoopStage::Inline(closer) => match closer.process(&self.graph, &self.store, &job) {
                Ok(Some(event)) => self
                    .appearance_loops
                    .lock()
                    .unwrap_or_else(|e| e.into_inner())
                    .push(event),
                Ok(None) => {}
                Err(e) => self
                    .background_errors
                    .lock()
                    .unwrap_or_else(|e| e.into_inner())
                    .push(format!("loop closure at {keyframe}: {e}")),
            },
            LoopStage::Thread { jobs, .. } => match jobs.try_send(job) {
                Ok(()) => {}
                Err(TrySendError::Full(_)) => self.loop_queue_full += 1,
                Err(TrySendError::Disconnected(_)) => {}
            },
        }
    }

    fn loop_event(
        &mut self,
        keyframe: KeyframeId,
        old: KeyframeId,
        kind: &'static str,
        correction: Option<LoopDrift>,
        evidence: Option<LoopEvidence>,
    ) {
        let store = self.store.read().unwrap_or_else(|e| e.into_inner());
        let frame_of = |k: KeyframeId| store.get(k).map_or(usize::MAX, |i| i.frame_index);
        self.loops.push(LoopEvent {
            keyframe,
            old,
            frames: (frame_of(keyframe), frame_of(old)),
            kind,
            scale: None,
            correction,
            evidence,
        });
    }

    /// One double window optimisation: now (deterministic) or in the worker (threaded).
    fn optimise(&mut self) -> Result<(), SystemError> {
        if self.graph.read().num_keyframes() < 2 {
            return Ok(());
        }
        match (&mut self.optimiser, &self.worker) {
            (Some(optimiser), _) => {
                let stats = match optimiser.optimise_shared(&self.graph, self.sensor.camera()) {
                    Ok(stats) => stats,
                    // A new map whose first keyframe failed (the run then stops): nothing to
                    // optimise around, and the outputs are still written.
                    Err(DwoError::NoReference) => return Ok(()),
                    Err(e) => return Err(e.into()),
                };
                self.record
                    .timings
                    .record("optimise: double window", stats.total());
                self.optimisations
                    .lock()
                    .unwrap_or_else(|e| e.into_inner())
                    .push(stats);
            }
            (None, Some(worker)) => match worker.wake.try_send(()) {
                // A wake-up is pending: the worker will see this keyframe too.
                Ok(()) | Err(TrySendError::Full(())) => {}
                Err(TrySendError::Disconnected(())) => {}
            },
            (None, None) => {}
        }
        Ok(())
    }

    /// Ends the run: stops the optimisation thread, runs a last optimisation, and collects the
    /// outputs (keyframes and map after it, every frame's final pose).
    pub fn finish(mut self, interrupted: bool) -> Result<RunResult, SystemError> {
        // The loop closer first (it may still wake the optimiser), then the optimiser.
        let closer = match std::mem::replace(&mut self.loop_stage, LoopStage::Off) {
            LoopStage::Off => None,
            LoopStage::Inline(closer) => Some(*closer),
            LoopStage::Thread { jobs, handle } => {
                drop(jobs);
                Some(
                    handle
                        .join()
                        .expect("the loop-closure thread does not panic"),
                )
            }
        };
        let mut refused_loops = Vec::new();
        if let Some(closer) = &closer {
            self.record.timings.extend(&closer.timings);
            let store = self.store.read().unwrap_or_else(|e| e.into_inner());
            let frame_of = |k: KeyframeId| store.get(k).map_or(usize::MAX, |i| i.frame_index);
            refused_loops = closer
                .refused
                .iter()
                .map(|(k, old, d)| RefusedLoop {
                    frames: (frame_of(*k), frame_of(*old)),
                    drift: *d,
                    allowed: d.allowed(&self.mapper.config().appearance_max_drift),
                })
                .collect();
        }
        // One line for all of them (a corridor of repeated textures refuses dozens); the list
        // is in the run's summary.
        let refused = refused_loop_warning(&refused_loops);
        let appearance = std::mem::take(
            &mut *self
                .appearance_loops
                .lock()
                .unwrap_or_else(|e| e.into_inner()),
        );
        for event in appearance {
            let kind = if event.merged.is_some() {
                "merge"
            } else {
                "appearance"
            };
            self.loop_event(
                event.keyframe,
                event.old,
                kind,
                event.drift,
                Some(event.evidence),
            );
        }
        if let Some(worker) = self.worker.take() {
            drop(worker.wake);
            let optimiser = worker
                .handle
                .join()
                .expect("the optimisation thread does not panic");
            self.optimiser = Some(optimiser);
        }
        self.optimise()?;
        // The world: the map with the most keyframes, the first on a tie (ORB-SLAM3 saves its
        // biggest map). The first unless a camera lost early and never found again went on in
        // a new map for longer. Frames, keyframes and points of another map have no place in it
        // (only the motion model's guess).
        let mut keyframes_in = std::collections::BTreeMap::<usize, usize>::new();
        {
            let g = self.graph.read();
            for (k, _) in g.keyframes() {
                if let Ok(m) = g.map_of(k) {
                    *keyframes_in.entry(m).or_default() += 1;
                }
            }
        }
        let world = largest_map(keyframes_in.iter().map(|(&m, &n)| (m, n)));
        // The optimisations that end the run, around the map written: its newest keyframe the
        // reference (the windows grow from the reference through the edges, which do not join
        // maps never merged).
        {
            let mut g = self.graph.write();
            let newest = g
                .keyframes()
                .map(|(k, _)| k)
                .filter(|&k| g.map_of(k) == Ok(world))
                .last();
            if let Some(k) = newest
                && g.reference().is_none_or(|r| g.map_of(r) != Ok(world))
            {
                let _ = g.set_reference(k);
            }
        }
        // Then the double window with every keyframe in its outer window (the pose graph of the
        // whole map) and the bundle adjustment over every keyframe and point, both from the
        // poses as they are (`DoubleWindowOptimiser::finishing`), unless the run was
        // interrupted (Ctrl-C stops promptly). The bundle adjustment alone, on eleven sequences
        // (2026-12-03, 5 iterations): the trajectory after the run got better or stayed —
        // rendered courtyard seeds 1–3 0.61 / 0.80 / 1.19 → 0.51 / 0.65 / 0.75 cm, room stereo
        // 0.12 / 0.12 / 0.14 → 0.09 cm, room RGB-D 0.10 → 0.08 cm, 7-Scenes 4.63 → 4.57 cm,
        // KITTI 5.29 → 5.27 cm, EuRoC 0.06 cm; 0.03–0.9 s. The pose graph before it and the
        // start from the poses: see `finishing` (the rendered building 0.61 → 0.55 cm, and no
        // longer broken with small windows).
        let final_iterations = self.config.optimiser.final_iterations;
        if !interrupted
            && final_iterations > 0
            && let Some(optimiser) = &self.optimiser
            && self.graph.read().num_keyframes() >= 2
            && self.graph.read().reference().is_some()
        {
            let [mut global, mut full] = DoubleWindowOptimiser::finishing(
                DwoParams {
                    iterations: final_iterations,
                    ..optimiser.params.clone()
                },
                &self.graph.read(),
            );
            let stats = global.optimise_shared(&self.graph, self.sensor.camera())?;
            self.record
                .timings
                .record("optimise: final pose graph (gDWO)", stats.total());
            let stats = full.optimise_shared(&self.graph, self.sensor.camera())?;
            self.record
                .timings
                .record("optimise: final bundle adjustment", stats.total());
        }
        let mut warnings = std::mem::take(
            &mut *self
                .background_errors
                .lock()
                .unwrap_or_else(|e| e.into_inner()),
        );
        warnings.extend(refused);
        let graph = self.graph.snapshot();
        if world != FIRST_MAP {
            let dropped = write_map(
                world,
                &mut self.record.frames,
                &mut self.reports,
                self.off_first
                    .iter()
                    .map(|(i, m, pose, state)| (*i, *m, pose.rigid_part(), state)),
            );
            warnings.push(format!(
                "the map written is map {world}, which holds more keyframes ({}) than the first \
                 ({}), never joined to it: the first map's {dropped} frames have no pose in the \
                 trajectories",
                keyframes_in[&world],
                keyframes_in.get(&FIRST_MAP).copied().unwrap_or(0)
            ));
        }
        let in_world = |k: KeyframeId| graph.map_of(k) == Ok(world);
        let frames_in = |map: usize| self.off_first.iter().filter(|f| f.1 == map).count();
        let new_maps: Vec<NewMap> = self
            .new_maps
            .iter()
            .map(|&(frame, lost_for, map)| {
                let now = graph.moved_since(0, map).map_or(map, |(_, m)| m);
                NewMap {
                    frame,
                    lost_for,
                    map,
                    joined: now == world,
                    frames: frames_in(map),
                }
            })
            .collect();
        for m in &new_maps {
            let NewMap {
                frame,
                lost_for,
                map,
                frames,
                ..
            } = m;
            warnings.push(if *map == world {
                format!(
                    "frame {frame}: lost for {lost_for:.1} s, not found again in the map; a new map \
                     (map {map}) was started there: the map written"
                )
            } else if m.joined {
                format!(
                    "frame {frame}: lost for {lost_for:.1} s, not found again in the map; a new map \
                     (map {map}) was started there and a loop (kind \"merge\") later joined it to \
                     the map written: its frames have poses in the final trajectory, and in the \
                     live one from the merge on"
                )
            } else {
                format!(
                    "frame {frame}: lost for {lost_for:.1} s, not found again in the map; a new map \
                     (map {map}) was started there, which no loop joined to the map written: its \
                     {frames} frames have no pose in the trajectories, and its keyframes and \
                     points are not in the map written"
                )
            });
        }
        if self.loop_queue_full > 0 {
            warnings.push(format!(
                "{} keyframes found the loop closer's queue full and were not entered into \
                 place recognition (loops.queue: {})",
                self.loop_queue_full, self.config.loops.queue
            ));
        }
        let store = self.store.read().unwrap_or_else(|e| e.into_inner()).clone();
        self.record.interrupted = interrupted;
        self.record.keyframes = graph
            .keyframes()
            .filter(|&(k, _)| in_world(k))
            .filter_map(|(k, kf)| {
                let images = store.get(k)?;
                Some(KeyframeRecord {
                    id: k.index(),
                    frame_index: images.frame_index,
                    timestamp: images.timestamp,
                    world_from_camera: kf.camera_from_world().rigid_part().inverse(),
                })
            })
            .collect();
        self.record.points = graph
            .points()
            .filter(|(_, pt)| in_world(pt.anchor()))
            .filter_map(|(p, pt)| {
                let position = graph.point_world(p).ok()?;
                let z = graph.keyframe(pt.anchor())?.observations().get(&p)?;
                let colour = store.get(pt.anchor()).map(|i| i.colour_at(z.x, z.y));
                Some(MapPoint { position, colour })
            })
            .collect();
        let mut final_trajectory = Trajectory::default();
        for &(i, r, rel) in &self.relative {
            let Ok(t_r) = graph.pose(r) else { continue };
            if !in_world(r) {
                continue;
            }
            final_trajectory
                .timestamps
                .push(self.record.frames[i].timestamp);
            final_trajectory
                .world_from_body
                .push(rel.compose(&t_r).rigid_part().inverse());
        }
        let optimisations = self
            .optimisations
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .clone();
        Ok(RunResult {
            record: self.record,
            final_trajectory,
            frames: self.reports,
            loops: self.loops,
            relocalisations: self.relocalisations,
            new_maps,
            world_map: world,
            refused_loops,
            optimisations,
            graph,
            keyframes: store,
            warnings,
            alternatives: Vec::new(),
        })
    }

    /// The mode.
    pub fn mode(&self) -> Mode {
        self.mode
    }

    /// Record a stage's time measured outside (e.g. the reader's wait).
    pub fn record_timing(&mut self, stage: &str, d: Duration) {
        self.record.timings.record(stage, d);
    }

    /// Timings so far.
    pub fn timings(&self) -> &StageTimings {
        &self.record.timings
    }
}

/// The warning that sums up the refused appearance loops: how many, the range of corrections
/// they needed and the largest one next to what its path allowed; `None` if there were none.
fn refused_loop_warning(refused: &[RefusedLoop]) -> Option<String> {
    let worst = refused
        .iter()
        .max_by(|a, b| a.drift.displacement.total_cmp(&b.drift.displacement))?;
    let least = refused
        .iter()
        .map(|r| r.drift.displacement)
        .fold(f64::INFINITY, f64::min);
    Some(format!(
        "{} loop{} by appearance {} refused, each needing more correction than the drift \
         the path between the two places allows (a place that looks like another): \
         {least:.2}–{:.2} m, the largest from frame {} to frame {} against {:.2} m allowed over \
         {:.1} m of path (all in summary.json, refused_loops)",
        refused.len(),
        if refused.len() == 1 { "" } else { "s" },
        if refused.len() == 1 { "was" } else { "were" },
        worst.drift.displacement,
        worst.frames.0,
        worst.frames.1,
        worst.allowed,
        worst.drift.path,
    ))
}

/// The map written: the one with the most keyframes of `(map, keyframes)`, the first on a
/// tie (ORB-SLAM3 saves its biggest map); `FIRST_MAP` if there is none.
pub(crate) fn largest_map(keyframes: impl IntoIterator<Item = (usize, usize)>) -> usize {
    keyframes
        .into_iter()
        .max_by(|a, b| a.1.cmp(&b.1).then(b.0.cmp(&a.0)))
        .map_or(FIRST_MAP, |(m, _)| m)
}

/// Makes the record (and the per-frame reports, which frames.csv writes) hold map `world`,
/// not the first: the frames with a pose (the first map's) lose it, their state saying why,
/// and the frames tracked in `world` (`(position in the record, map, camera_from_world,
/// state)` of `off_first`, kept while they had no pose in the first map's world) get theirs.
/// Returns how many frames lost their pose.
pub(crate) fn write_map<'a>(
    world: usize,
    frames: &mut [FrameRecord],
    reports: &mut [FrameReport],
    off_first: impl Iterator<Item = (usize, usize, Se3, &'a TrackingState)>,
) -> usize {
    let mut dropped = 0;
    for (f, r) in frames.iter_mut().zip(reports.iter_mut()) {
        if f.world_from_camera.take().is_some() {
            dropped += 1;
            f.state = TrackingState::Weak(format!(
                "tracked in the first map, which is not the map written (map {world} holds more keyframes): no pose in the world"
            ));
            r.state = f.state.clone();
        }
    }
    for (i, map, pose, state) in off_first {
        if map == world {
            let f = &mut frames[i];
            f.world_from_camera = Some(pose.inverse());
            f.state = state.clone();
            if let Some(r) = reports.get_mut(i) {
                r.state = state.clone();
            }
        }
    }
    dropped
}

/// The optimisation thread: woken by each new keyframe, it optimises the shared graph; a result
/// superseded by a change to the window's poses meanwhile is re-planned at once.
fn spawn_worker(
    mut optimiser: DoubleWindowOptimiser,
    graph: Arc<SharedGraph<3>>,
    camera: StereoCamera,
    stats: Arc<Mutex<Vec<DwoStats>>>,
    errors: Arc<Mutex<Vec<String>>>,
) -> Worker {
    let (wake, wakes): (SyncSender<()>, Receiver<()>) = sync_channel(1);
    let handle = std::thread::Builder::new()
        .name("double window optimisation".into())
        .spawn(move || {
            while wakes.recv().is_ok() {
                for _attempt in 0..3 {
                    match optimiser.optimise_shared(&graph, &camera) {
                        Ok(s) => {
                            stats.lock().unwrap_or_else(|e| e.into_inner()).push(s);
                            break;
                        }
                        Err(DwoError::Superseded { .. }) => continue,
                        Err(e) => {
                            errors
                                .lock()
                                .unwrap_or_else(|e| e.into_inner())
                                .push(e.to_string());
                            break;
                        }
                    }
                }
            }
            optimiser
        })
        .expect("a thread can be spawned");
    Worker { wake, handle }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn refused(frames: (usize, usize), displacement: f64, path: f64) -> RefusedLoop {
        RefusedLoop {
            frames,
            drift: LoopDrift {
                displacement,
                path,
                scene_depth: 3.0,
            },
            allowed: (0.05 * path).max(0.3),
        }
    }

    #[test]
    fn refused_loops_are_summed_up_in_one_warning() {
        assert_eq!(refused_loop_warning(&[]), None);
        let one = refused_loop_warning(&[refused((90, 10), 2.5, 20.0)]).unwrap();
        assert!(one.starts_with("1 loop by appearance was refused"), "{one}");
        let many = refused_loop_warning(&[
            refused((90, 10), 2.5, 20.0),
            refused((400, 120), 12.25, 60.0),
            refused((410, 300), 0.75, 8.0),
        ])
        .unwrap();
        assert!(
            many.starts_with("3 loops by appearance were refused"),
            "{many}"
        );
        // The range of the corrections, and the largest with its frames, allowance and path.
        assert!(many.contains("0.75–12.25 m"), "{many}");
        assert!(
            many.contains("from frame 400 to frame 120 against 3.00 m allowed over 60.0 m"),
            "{many}"
        );
    }
}
