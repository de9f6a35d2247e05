//! `runner`: a run of the live system — a source of frames (a recorded sequence, or frames
//! rendered on the fly) through [`system::System`], every frame's line in the tracking log,
//! the outputs, `summary.json`, the evaluation against the ground truth — shared by the
//! binary (`dwslam run`, `dwslam demo`) and the Python package (`dwslam.run`), so that both
//! run the same loop and write the same files.
//!
//! It sits above `system` and `data` and below the front-ends; like the binary it reports
//! errors with `anyhow` (each names the file or option at fault), which the Python package
//! turns into exceptions with the same message.

#![warn(missing_docs)]

mod drive;
mod sequence;
mod summary;

pub use drive::{
    DENSE_FILE, Finished, Frames, MapOptions, Observer, Outcome, Report, Settings, Source,
    SystemSetup, alignment_of, execute, load_map, map_line, new_system, vocabulary,
};
pub use sequence::{RequestError, SequenceRequest, open_sequence, sensor_name};
pub use summary::{FINAL_TRAJECTORY_FILE, FRAME_STATS_FILE, OPTIMISATION_STATS_FILE, summary_of};
