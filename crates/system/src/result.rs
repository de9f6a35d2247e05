//! What a run gives its caller: per frame a report, at the end the [`RunResult`] — every
//! frame's pose and state, the keyframes and the map, the loops, relocalisations and new maps,
//! the optimisations, the warnings — whatever the sensor.

use crate::keyframes::{KeyframeReason, KeyframeStore};
use crate::tracker::TrackerStats;
use data::output::{RunRecord, TrackingState};
use data::trajectory::Trajectory;
use slam::dwo::{DwoError, DwoStats};
use slam::loop_closure::LoopDrift;
use slam::map::KeyframeId;
use slam::mapping::MappingError;
use std::time::Duration;

pub use crate::run_graph::{KeyframeNode, RunGraph};

/// How the back-end runs.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum Mode {
    /// Double window optimisation and loop closure in threads of their own (the live system of
    /// thesis §6.5.2).
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
    Frame(#[from] crate::frame::FrameError),
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
    /// A loaded map cannot be used by this run.
    #[error(transparent)]
    Map(#[from] crate::map_file::MapFileError),
    /// What this build cannot do yet.
    #[error("{0}")]
    Unsupported(String),
}

impl SystemError {
    /// A map loaded into a run without a vocabulary: its keyframes are found by their words.
    pub(crate) fn map_without_vocabulary() -> Self {
        SystemError::Unsupported(
            "a loaded map is found by its keyframes' words: this run has no vocabulary \
             (loops.enabled: false)"
                .into(),
        )
    }
}

/// The map a run saved (`Options::save_map`).
#[derive(Clone, Debug, PartialEq)]
pub struct SavedMap {
    /// The file.
    pub path: std::path::PathBuf,
    /// Its size.
    pub bytes: u64,
    /// Time to assemble and write it.
    pub seconds: f64,
    /// What it holds.
    pub summary: crate::map_file::MapSummary,
}

/// What an appearance loop of the stereo and RGB-D system rests on: a person reading the run
/// tells a strong loop from a weak one by it (a place that only looks like another — repeated
/// façades — gives a few RANSAC inliers and finds a few per cent of the old place's points).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct LoopEvidence {
    /// Inliers of the 3-point RANSAC on the ORB matches (thesis eq. 6.9).
    pub ransac_inliers: usize,
    /// Old-place map points found by the guided matching at the pose the loop implies.
    pub old_points_found: usize,
    /// Old-place map points predicted visible there (searched).
    pub old_points_predicted: usize,
}

pub use crate::observed::{Observed, ObservedState};

/// What happened to one frame.
#[derive(Clone, Debug)]
pub struct FrameReport {
    /// The frame.
    pub index: usize,
    /// Its state.
    pub state: TrackingState,
    /// The keyframe it became, and why.
    pub keyframe: Option<(KeyframeId, KeyframeReason)>,
    /// The tracker's counts (none for a frame that was not tracked).
    pub stats: Option<TrackerStats>,
    /// Time of the whole frame in the tracking thread.
    pub time: Duration,
    /// Time of the tracking stages (the keyframe pipeline excluded).
    pub time_tracking: Duration,
    /// The points the front-end looked at, with `Options::observe` (empty otherwise, and in
    /// the reports a run's result keeps).
    pub observed: Vec<Observed>,
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
    /// `"metric"`, `"appearance"`, or `"merge"` (a loop into another map: the stereo and RGB-D
    /// system merges the younger map into the older, the monocular system joins two maps of
    /// their own scales).
    pub kind: &'static str,
    /// The scale of the loop's similarity (monocular: the scale drift between the two
    /// places, thesis ch. 5, or between two joined maps; `None` for a rigid loop).
    pub scale: Option<f64>,
    /// The standard error of the scale's logarithm, from the fit of a monocular loop's
    /// similarity on the old place's points.
    pub scale_sigma: Option<f64>,
    /// The detections in a row that agreed when the loop was accepted (monocular).
    pub agreeing: Option<usize>,
    /// The correction an appearance loop made (stereo and RGB-D) or asks (monocular, corrected
    /// later) to the new keyframe, against the path since the old one.
    pub correction: Option<LoopDrift>,
    /// What an appearance loop rests on.
    pub evidence: Option<LoopEvidence>,
}

/// A lost frame found again in the map by appearance and tracked from there.
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
    /// Map points tracked after it.
    pub tracked: usize,
}

/// A map started after the camera was lost for `tracker.new_map_after` seconds (or at once
/// where nothing could find it again: a monocular camera without a vocabulary).
#[derive(Clone, Debug, PartialEq)]
pub struct NewMap {
    /// The frame it started at (its index in the sequence).
    pub frame: usize,
    /// Seconds the camera had been lost.
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
    /// The largest correction allowed for that path and scene (map units), if the loop was
    /// refused for needing more.
    pub allowed: Option<f64>,
    /// Why it was refused.
    pub reason: String,
}

/// How long a thread waited for the locks it shares with the other threads (the graph, the
/// keyframe store, the place-recognition database), over a run.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct LockWaits {
    /// Locks taken.
    pub count: usize,
    /// Median wait of one lock.
    pub median: Duration,
    /// 99th percentile of one lock's wait.
    pub p99: Duration,
    /// The longest wait.
    pub max: Duration,
    /// Frames (a back-end thread's jobs) whose locks together waited more than a millisecond.
    pub frames_over_1ms: usize,
}

/// Everything a run produced.
#[derive(Clone, Debug)]
pub struct RunResult {
    /// Every frame with its live pose (as tracked), the keyframes and the map after the final
    /// optimisation, per-stage timings.
    pub record: RunRecord,
    /// Every frame re-expressed relative to its keyframe after the final optimisation
    /// (`T = T_rel·T_k`): the trajectory a user gets after the run.
    pub final_trajectory: Trajectory,
    /// Per frame: the tracker's counts and times.
    pub frames: Vec<FrameReport>,
    /// The loop closures.
    pub loops: Vec<LoopEvent>,
    /// The lost frames found again by appearance.
    pub relocalisations: Vec<Relocalisation>,
    /// The maps started after a loss.
    pub new_maps: Vec<NewMap>,
    /// The map written (its trajectories, keyframes and points; with the maps joined to it,
    /// monocular): the one with the most keyframes, `slam::map::FIRST_MAP` unless a camera
    /// lost early went on in a new map for longer.
    pub world_map: usize,
    /// Appearance loops refused by the drift test.
    pub refused_loops: Vec<RefusedLoop>,
    /// The optimisations (time and window sizes of each).
    pub optimisations: Vec<DwoStats>,
    /// The final graph.
    pub graph: RunGraph,
    /// The keyframes' images.
    pub keyframes: KeyframeStore,
    /// What went wrong without stopping the run (an optimisation or a loop closure that
    /// failed, a worker thread that died, keyframes the loop closer had no room for).
    pub warnings: Vec<String>,
    /// Further trajectories after the run worth comparing with [`final_trajectory`]
    /// (monocular: the loops corrected in SE(3) instead of Sim(3)), by file stem.
    ///
    /// [`final_trajectory`]: Self::final_trajectory
    pub alternatives: Vec<(&'static str, Trajectory)>,
    /// How long the tracking thread waited for locks.
    pub lock_waits: LockWaits,
    /// How long each back-end thread waited for the locks it shares with the tracking thread
    /// (`frames_over_1ms`: its jobs), by the thread's name; threads only (inline, a stage's
    /// waits are the tracking thread's).
    pub backend_lock_waits: Vec<(&'static str, LockWaits)>,
    /// The map saved at the end (`Options::save_map`), or why it could not be: the run's
    /// outputs are written either way.
    pub saved_map: Option<Result<SavedMap, String>>,
    /// Keyframes culled during the run (`slam::mapping::culling`: redundant on revisits).
    pub culled: usize,
}

/// The map as it is while a run goes on, in the world of the maps that will be written (a
/// live view draws it): the keyframes, the points (coloured from their anchor's image), the
/// keyframes' covisibility edges and the loops closed.
#[derive(Clone, Debug, Default)]
pub struct MapSnapshot {
    /// The keyframes, by timestamp.
    pub keyframes: Vec<data::output::KeyframeRecord>,
    /// The map points.
    pub points: Vec<data::output::MapPoint>,
    /// Covisibility edges between keyframes (their ids, the smaller first), and whether the
    /// edge is marginalised (a pose constraint of the outer window).
    pub edges: Vec<(usize, usize, bool)>,
    /// The loops closed: the new keyframe, the old one, and the scale drift corrected
    /// (monocular).
    pub loops: Vec<(usize, usize, Option<f64>)>,
}

/// What the progress bar shows of the map while a run goes on.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Progress {
    /// Keyframes in the graph (every map of the run, a loaded one's included).
    pub keyframes: usize,
    /// Points in the map.
    pub points: usize,
    /// Loop closures so far (metric and by appearance).
    pub loops: usize,
}

/// A live system as a run loop drives it: frames in order, then the result
/// ([`crate::System`]).
pub trait LiveRun {
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
    fn finish(self, interrupted: bool) -> Result<RunResult, SystemError>;
    /// The map's size and the loops closed so far, for the progress bar.
    fn progress(&self) -> Progress;
    /// The map as it is now, for a live view (a copy made under the graph's read lock).
    fn snapshot(&self) -> MapSnapshot;
}
