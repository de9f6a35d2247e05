//! A recorded sequence as a run's [`Source`]: opened, its sensor chosen, its frames read
//! ahead on the reader's thread.

use crate::Source;
use anyhow::Result;
use data::camera::{Calibration, SensorKind, SensorModel};
use data::sequence::{BadFramePolicy, OpenOptions, Sequence, SequenceFormat};
use std::path::PathBuf;

/// What to run of a recorded sequence (`dwslam run`'s input options; the Python package's
/// `dwslam.run`).
#[derive(Clone, Debug, Default)]
pub struct SequenceRequest {
    /// The sequence: a TUM RGB-D / 7-Scenes, EuRoC, KITTI or image folder.
    pub path: PathBuf,
    /// The sensor (default: the sequence's own; a stereo or RGB-D sequence runs monocular on
    /// its left / colour image).
    pub sensor: Option<SensorKind>,
    /// Force the format instead of detecting it.
    pub format: Option<SequenceFormat>,
    /// A camera file overriding the sequence's calibration.
    pub camera: Option<PathBuf>,
    /// A bad frame (missing, corrupt, wrong size) is skipped with a warning instead of ending
    /// the run.
    pub skip_bad_frames: bool,
    /// RGB-D: only the frames with a depth image.
    pub depth_frames_only: bool,
    /// Start at this frame.
    pub start_frame: usize,
    /// At most this many frames (`None`: all).
    pub max_frames: Option<usize>,
}

/// A request the sequence cannot serve; each front-end names the option at fault its own way
/// (`--sensor` on the command line, `sensor=` in Python).
#[derive(Debug, thiserror::Error)]
pub enum RequestError {
    /// The sensor asked for is not one the sequence has.
    #[error("{path} is a {have} sequence")]
    Sensor {
        /// The sensor asked for.
        want: SensorKind,
        /// What the sequence is (`"monocular"`, `"stereo"`, `"RGB-D"`).
        have: &'static str,
        /// The sequence.
        path: String,
    },
    /// The start frame is past the sequence's end.
    #[error("{0}")]
    StartFrame(String),
    /// No frame to run.
    #[error("the number of frames to run must be at least 1")]
    NoFrames,
}

/// Frames a sequence's reader decodes ahead of the system.
const READ_AHEAD: usize = 8;

/// Opens the sequence of `request` (printed: what it is) as a source of frames.
pub fn open_sequence(request: &SequenceRequest) -> Result<Source> {
    if request.max_frames == Some(0) {
        return Err(RequestError::NoFrames.into());
    }
    let options = OpenOptions {
        format: request.format,
        camera_file: request.camera.clone(),
        on_bad_frame: if request.skip_bad_frames {
            BadFramePolicy::Skip
        } else {
            BadFramePolicy::Stop
        },
        require_depth: request.depth_frames_only,
        no_depth: request.sensor == Some(SensorKind::Mono),
        ..OpenOptions::default()
    };
    let sequence = Sequence::open(&request.path, &options)?
        .starting_at(request.start_frame)
        .map_err(|e| RequestError::StartFrame(e.to_string()))?;
    let info = sequence.info().clone();
    let sensor = match (request.sensor, &info.camera) {
        (None | Some(SensorKind::Stereo), SensorModel::Stereo(_))
        | (None | Some(SensorKind::Rgbd), SensorModel::Rgbd(_)) => info.camera,
        // A stereo or RGB-D sequence runs monocular on its left / colour image alone.
        (None | Some(SensorKind::Mono), _) => SensorModel::Mono(*info.camera.pinhole()),
        (Some(want), have) => {
            return Err(RequestError::Sensor {
                want,
                have: sensor_name(have),
                path: request.path.display().to_string(),
            }
            .into());
        }
    };
    let frames = request
        .max_frames
        .map_or(info.frame_count, |m| m.min(info.frame_count));
    println!(
        "{} ({}, {} frames, {}×{}, {}){}",
        request.path.display(),
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
    let reader = sequence.into_reader(READ_AHEAD);
    Ok(Source {
        name: request.path.display().to_string(),
        sensor,
        frames,
        ground_truth: info.ground_truth.map(|g| g.trajectory),
        skip_bad_frames: request.skip_bad_frames,
        stream: Box::new(reader.take(frames).map(|r| r.map_err(anyhow::Error::new))),
        depth: match info.calibration {
            Calibration::Rgbd { depth, .. } => Some(depth),
            _ => None,
        },
    })
}

/// `"monocular"`, `"stereo"` or `"RGB-D"`.
pub fn sensor_name(s: &SensorModel) -> &'static str {
    match s.kind() {
        SensorKind::Mono => "monocular",
        SensorKind::Stereo => "stereo",
        SensorKind::Rgbd => "RGB-D",
    }
}
