//! What a run writes: the trajectory of every frame with its tracking state, the keyframe
//! trajectory, the map points, and a summary — as library types the live system fills
//! ([`RunRecord`]) and writers into a run folder ([`RunOutput`]).
//!
//! # The run folder
//!
//! | file | content |
//! |---|---|
//! | `trajectory.tum` | every frame with a pose: `timestamp tx ty tz qx qy qz qw`, `world_from_camera` (evo's TUM format) |
//! | `trajectory.kitti` | the same poses as KITTI 3×4 rows (on request, [`OutputOptions::kitti`]) |
//! | `keyframes.tum` | the keyframes' poses, TUM format |
//! | `map.ply` | map points in the world frame (metres), with colour where the images have it; binary little-endian or ASCII |
//! | `summary.json` | frame / keyframe / point counts, per-stage timings, every frame's tracking state ([`Summary`]) |
//! | `ground_truth.tum` | the sequence's ground truth in the same camera frame, if it has one (so `dwslam eval RUN` needs nothing else) |
//! | `tracking_log.txt` | appended frame by frame while the run goes ([`RunOutput::log_frame`]): survives a crash |
//!
//! Every file but the log is written whole to `NAME.tmp` and renamed into place, so a run
//! interrupted while writing (Ctrl-C, kill) leaves the previous complete version, never half a
//! file; [`RunOutput::write`] can be called as often as wanted (at every keyframe, at the end, on
//! Ctrl-C).

use crate::error::{DataError, ParseErrorKind};
use crate::text::fmt_f64;
use crate::trajectory::{Trajectory, write_kitti, write_tum};
use lie::Se3;
use nalgebra::Vector3;
use serde::{Deserialize, Serialize};
use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};
use std::time::Duration;

/// Every frame's trajectory, TUM format.
pub const TRAJECTORY_FILE: &str = "trajectory.tum";
/// Every frame's trajectory, KITTI format (on request).
pub const TRAJECTORY_KITTI_FILE: &str = "trajectory.kitti";
/// The keyframe trajectory, TUM format.
pub const KEYFRAMES_FILE: &str = "keyframes.tum";
/// The map points.
pub const MAP_FILE: &str = "map.ply";
/// The summary.
pub const SUMMARY_FILE: &str = "summary.json";
/// The sequence's ground truth, TUM format.
pub const GROUND_TRUTH_FILE: &str = "ground_truth.tum";
/// The incremental per-frame log.
pub const TRACKING_LOG_FILE: &str = "tracking_log.txt";
/// Version of the summary's schema.
pub const SUMMARY_VERSION: u32 = 1;

/// How well a frame was tracked.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(tag = "state", content = "reason", rename_all = "lowercase")]
pub enum TrackingState {
    /// Tracked with enough support.
    Good,
    /// Tracked, but with little support (the reason says what was short).
    Weak(String),
    /// Not tracked (the reason says why); the pose, if any, is a prediction.
    Lost(String),
}

impl TrackingState {
    /// `"good"`, `"weak"` or `"lost"`.
    pub fn name(&self) -> &'static str {
        match self {
            TrackingState::Good => "good",
            TrackingState::Weak(_) => "weak",
            TrackingState::Lost(_) => "lost",
        }
    }

    /// The reason, for weak and lost frames.
    pub fn reason(&self) -> Option<&str> {
        match self {
            TrackingState::Good => None,
            TrackingState::Weak(r) | TrackingState::Lost(r) => Some(r),
        }
    }
}

/// One frame of a run.
#[derive(Clone, Debug, PartialEq)]
pub struct FrameRecord {
    /// The frame's index in the sequence.
    pub index: usize,
    /// Its timestamp, seconds.
    pub timestamp: f64,
    /// The estimated pose, if the frame has one (none before initialisation).
    pub world_from_camera: Option<Se3>,
    /// The tracking state.
    pub state: TrackingState,
}

/// One keyframe.
#[derive(Clone, Debug, PartialEq)]
pub struct KeyframeRecord {
    /// The keyframe's id.
    pub id: usize,
    /// The frame it was made from.
    pub frame_index: usize,
    /// That frame's timestamp.
    pub timestamp: f64,
    /// Its (optimised) pose.
    pub world_from_camera: Se3,
}

/// One map point.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MapPoint {
    /// Position in the world frame, metres.
    pub position: Vector3<f64>,
    /// Colour, where the images have it.
    pub colour: Option<[u8; 3]>,
}

/// Durations of the pipeline's stages, collected per call.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct StageTimings {
    stages: Vec<(String, Vec<f64>)>,
}

/// The statistics of one stage's durations, milliseconds.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct StageTiming {
    /// Stage name.
    pub stage: String,
    /// Number of calls.
    pub count: usize,
    /// Sum.
    pub total_ms: f64,
    /// Mean.
    pub mean_ms: f64,
    /// Median.
    pub median_ms: f64,
    /// Largest.
    pub max_ms: f64,
}

impl StageTimings {
    /// Records one call of `stage` (stages keep the order of their first record).
    pub fn record(&mut self, stage: &str, duration: Duration) {
        let ms = duration.as_secs_f64() * 1e3;
        match self.stages.iter_mut().find(|(s, _)| s == stage) {
            Some((_, v)) => v.push(ms),
            None => self.stages.push((stage.to_string(), vec![ms])),
        }
    }

    /// Adds every call recorded in `other` (e.g. by another thread).
    pub fn extend(&mut self, other: &StageTimings) {
        for (stage, ms) in &other.stages {
            match self.stages.iter_mut().find(|(s, _)| s == stage) {
                Some((_, v)) => v.extend_from_slice(ms),
                None => self.stages.push((stage.clone(), ms.clone())),
            }
        }
    }

    /// Per-stage statistics.
    pub fn summary(&self) -> Vec<StageTiming> {
        self.stages
            .iter()
            .map(|(stage, v)| {
                let mut s = v.clone();
                s.sort_by(f64::total_cmp);
                let n = s.len();
                let total: f64 = s.iter().sum();
                let median = if n % 2 == 1 {
                    s[n / 2]
                } else {
                    0.5 * (s[n / 2 - 1] + s[n / 2])
                };
                StageTiming {
                    stage: stage.clone(),
                    count: n,
                    total_ms: total,
                    mean_ms: total / n as f64,
                    median_ms: median,
                    max_ms: s[n - 1],
                }
            })
            .collect()
    }
}

/// Everything a run produced so far; the live system fills it and hands it to
/// [`RunOutput::write`].
#[derive(Clone, Debug, Default, PartialEq)]
pub struct RunRecord {
    /// The sequence (its folder, as given).
    pub sequence: String,
    /// `"mono"`, `"stereo"` or `"rgbd"`.
    pub sensor: String,
    /// Every frame so far.
    pub frames: Vec<FrameRecord>,
    /// The keyframes.
    pub keyframes: Vec<KeyframeRecord>,
    /// The map points.
    pub points: Vec<MapPoint>,
    /// Per-stage durations.
    pub timings: StageTimings,
    /// `true` when the run was stopped before the end of the sequence.
    pub interrupted: bool,
    /// Further sections of the summary (the run's evaluation, loop closures, …), written as
    /// top-level keys of `summary.json`.
    pub extra: serde_json::Map<String, serde_json::Value>,
}

/// Counts of tracking states.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct TrackingCounts {
    /// Good frames.
    pub good: usize,
    /// Weak frames.
    pub weak: usize,
    /// Lost frames.
    pub lost: usize,
}

/// One frame's state in the summary.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct FrameState {
    /// Frame index.
    pub index: usize,
    /// Timestamp, seconds.
    pub timestamp: f64,
    /// State and reason.
    #[serde(flatten)]
    pub state: TrackingState,
}

/// `summary.json`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Summary {
    /// [`SUMMARY_VERSION`].
    pub version: u32,
    /// The sequence.
    pub sequence: String,
    /// The sensor.
    pub sensor: String,
    /// The run was interrupted.
    pub interrupted: bool,
    /// Frames processed.
    pub frames: usize,
    /// Frames with a pose.
    pub frames_with_pose: usize,
    /// Keyframes.
    pub keyframes: usize,
    /// Map points.
    pub points: usize,
    /// Counts of tracking states.
    pub tracking: TrackingCounts,
    /// Per-stage timings.
    pub timings: Vec<StageTiming>,
    /// Every frame's state.
    pub frame_states: Vec<FrameState>,
    /// Further sections ([`RunRecord::extra`]).
    #[serde(flatten)]
    pub extra: serde_json::Map<String, serde_json::Value>,
}

impl RunRecord {
    /// The poses of every frame that has one.
    pub fn trajectory(&self) -> Trajectory {
        let (timestamps, world_from_body) = self
            .frames
            .iter()
            .filter_map(|f| f.world_from_camera.map(|p| (f.timestamp, p)))
            .unzip();
        Trajectory {
            timestamps,
            world_from_body,
        }
    }

    /// The keyframe trajectory.
    pub fn keyframe_trajectory(&self) -> Trajectory {
        Trajectory {
            timestamps: self.keyframes.iter().map(|k| k.timestamp).collect(),
            world_from_body: self.keyframes.iter().map(|k| k.world_from_camera).collect(),
        }
    }

    /// The summary.
    pub fn summary(&self) -> Summary {
        let mut tracking = TrackingCounts::default();
        for f in &self.frames {
            match f.state {
                TrackingState::Good => tracking.good += 1,
                TrackingState::Weak(_) => tracking.weak += 1,
                TrackingState::Lost(_) => tracking.lost += 1,
            }
        }
        Summary {
            version: SUMMARY_VERSION,
            sequence: self.sequence.clone(),
            sensor: self.sensor.clone(),
            interrupted: self.interrupted,
            frames: self.frames.len(),
            frames_with_pose: self
                .frames
                .iter()
                .filter(|f| f.world_from_camera.is_some())
                .count(),
            keyframes: self.keyframes.len(),
            points: self.points.len(),
            tracking,
            timings: self.timings.summary(),
            frame_states: self
                .frames
                .iter()
                .map(|f| FrameState {
                    index: f.index,
                    timestamp: f.timestamp,
                    state: f.state.clone(),
                })
                .collect(),
            extra: self.extra.clone(),
        }
    }
}

/// PLY encodings.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum PlyFormat {
    /// `binary_little_endian` (compact; the default).
    #[default]
    Binary,
    /// `ascii` (readable).
    Ascii,
}

/// Writes points as PLY: `float x y z` (metres, world frame) and, if any point has a colour,
/// `uchar red green blue` (grey 128 for points without).
pub fn write_ply(
    points: &[MapPoint],
    format: PlyFormat,
    mut out: impl Write,
) -> std::io::Result<()> {
    let colour = points.iter().any(|p| p.colour.is_some());
    let name = match format {
        PlyFormat::Binary => "binary_little_endian",
        PlyFormat::Ascii => "ascii",
    };
    writeln!(
        out,
        "ply\nformat {name} 1.0\ncomment dwslam map points, world frame, metres"
    )?;
    writeln!(out, "element vertex {}", points.len())?;
    writeln!(out, "property float x\nproperty float y\nproperty float z")?;
    if colour {
        writeln!(
            out,
            "property uchar red\nproperty uchar green\nproperty uchar blue"
        )?;
    }
    writeln!(out, "end_header")?;
    for p in points {
        let x = p.position.map(|v| v as f32);
        let c = p.colour.unwrap_or([128; 3]);
        match format {
            PlyFormat::Binary => {
                for v in x.iter() {
                    out.write_all(&v.to_le_bytes())?;
                }
                if colour {
                    out.write_all(&c)?;
                }
            }
            PlyFormat::Ascii => {
                write!(out, "{} {} {}", x.x, x.y, x.z)?;
                if colour {
                    write!(out, " {} {} {}", c[0], c[1], c[2])?;
                }
                writeln!(out)?;
            }
        }
    }
    out.flush()
}

/// What to write besides the defaults.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct OutputOptions {
    /// Also write `trajectory.kitti`.
    pub kitti: bool,
    /// PLY encoding of the map.
    pub ply: PlyFormat,
}

/// A run folder being written.
pub struct RunOutput {
    dir: PathBuf,
    options: OutputOptions,
    log: Option<BufWriter<File>>,
}

fn io_error(path: &Path, source: std::io::Error) -> DataError {
    DataError::Io {
        path: path.to_path_buf(),
        source,
    }
}

/// Writes `path` whole through `path.tmp` and a rename.
fn write_atomically(
    path: &Path,
    write: impl FnOnce(&mut BufWriter<File>) -> std::io::Result<()>,
) -> Result<(), DataError> {
    let mut tmp = path.as_os_str().to_owned();
    tmp.push(".tmp");
    let tmp = PathBuf::from(tmp);
    let file = File::create(&tmp).map_err(|e| io_error(&tmp, e))?;
    let mut w = BufWriter::new(file);
    write(&mut w).map_err(|e| io_error(&tmp, e))?;
    w.into_inner()
        .map_err(|e| io_error(&tmp, e.into_error()))?
        .sync_all()
        .map_err(|e| io_error(&tmp, e))?;
    std::fs::rename(&tmp, path).map_err(|e| io_error(path, e))
}

impl RunOutput {
    /// Creates (or reuses) the run folder and checks that it is writable, before any work.
    pub fn create(dir: impl AsRef<Path>, options: OutputOptions) -> Result<RunOutput, DataError> {
        let dir = dir.as_ref().to_path_buf();
        std::fs::create_dir_all(&dir).map_err(|e| io_error(&dir, e))?;
        let log_path = dir.join(TRACKING_LOG_FILE);
        let mut log = BufWriter::new(File::create(&log_path).map_err(|e| io_error(&log_path, e))?);
        writeln!(log, "# index timestamp state tx ty tz qx qy qz qw reason")
            .and_then(|_| log.flush())
            .map_err(|e| io_error(&log_path, e))?;
        Ok(RunOutput {
            dir,
            options,
            log: Some(log),
        })
    }

    /// The folder.
    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// Appends one frame to `tracking_log.txt` and flushes it (the pose as tracked at that
    /// moment; `nan` for frames without one).
    pub fn log_frame(&mut self, frame: &FrameRecord) -> Result<(), DataError> {
        let path = self.dir.join(TRACKING_LOG_FILE);
        let Some(log) = self.log.as_mut() else {
            return Ok(());
        };
        let pose = match &frame.world_from_camera {
            Some(p) => {
                let t = p.translation();
                let q = p.rotation().unit_quaternion();
                [t.x, t.y, t.z, q.i, q.j, q.k, q.w]
                    .iter()
                    .map(|v| fmt_f64(*v))
                    .collect::<Vec<_>>()
                    .join(" ")
            }
            None => ["nan"; 7].join(" "),
        };
        let reason = frame
            .state
            .reason()
            .unwrap_or("")
            .replace(['\n', '\r'], " ");
        writeln!(
            log,
            "{} {} {} {pose} {reason}",
            frame.index,
            fmt_f64(frame.timestamp),
            frame.state.name()
        )
        .and_then(|_| log.flush())
        .map_err(|e| io_error(&path, e))
    }

    /// Writes every file of the run folder from `record` (and the sequence's ground truth, if
    /// given), each atomically.
    pub fn write(
        &self,
        record: &RunRecord,
        ground_truth: Option<&Trajectory>,
    ) -> Result<(), DataError> {
        let trajectory = record.trajectory();
        write_atomically(&self.dir.join(TRAJECTORY_FILE), |w| {
            write_tum(&trajectory, w)
        })?;
        if self.options.kitti {
            write_atomically(&self.dir.join(TRAJECTORY_KITTI_FILE), |w| {
                write_kitti(&trajectory.world_from_body, w)
            })?;
        }
        let keyframes = record.keyframe_trajectory();
        write_atomically(&self.dir.join(KEYFRAMES_FILE), |w| write_tum(&keyframes, w))?;
        write_atomically(&self.dir.join(MAP_FILE), |w| {
            write_ply(&record.points, self.options.ply, w)
        })?;
        if let Some(gt) = ground_truth {
            write_atomically(&self.dir.join(GROUND_TRUTH_FILE), |w| write_tum(gt, w))?;
        }
        let summary = record.summary();
        write_atomically(&self.dir.join(SUMMARY_FILE), |w| {
            serde_json::to_writer_pretty(&mut *w, &summary).map_err(std::io::Error::other)?;
            writeln!(w)
        })
    }
}

/// Reads a `summary.json`.
pub fn read_summary(path: impl AsRef<Path>) -> Result<Summary, DataError> {
    let path = path.as_ref();
    let text = crate::text::read_to_string(path)?;
    serde_json::from_str(&text).map_err(|e| DataError::Parse {
        path: path.to_path_buf(),
        line: e.line(),
        kind: ParseErrorKind::Expected {
            expected: "a dwslam summary.json".into(),
            found: e.to_string(),
        },
    })
}

/// The files of a run folder that exist.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct RunFiles {
    /// `trajectory.tum`.
    pub trajectory: Option<PathBuf>,
    /// `keyframes.tum`.
    pub keyframes: Option<PathBuf>,
    /// `ground_truth.tum`.
    pub ground_truth: Option<PathBuf>,
    /// `summary.json`.
    pub summary: Option<PathBuf>,
}

/// The run files in `dir` (`None` if `dir` has none of them: not a run folder).
pub fn find_run_files(dir: &Path) -> Option<RunFiles> {
    let f = |n: &str| Some(dir.join(n)).filter(|p| p.is_file());
    let files = RunFiles {
        trajectory: f(TRAJECTORY_FILE),
        keyframes: f(KEYFRAMES_FILE),
        ground_truth: f(GROUND_TRUTH_FILE),
        summary: f(SUMMARY_FILE),
    };
    (files != RunFiles::default()).then_some(files)
}
