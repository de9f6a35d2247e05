//! Trajectory files: TUM (`timestamp tx ty tz qx qy qz qw`), KITTI poses (a row-major 3×4
//! matrix per line), EuRoC ground-truth CSV, plain timestamp lists; and timestamp association.
//!
//! Every pose is `world_from_body` (TUM and EuRoC: the body/IMU in the world; KITTI: camera 0
//! in the first camera's frame). Lines starting with `#` and blank lines are skipped; anything
//! malformed is a [`DataError`] naming the file and the line.

use crate::error::{DataError, ParseErrorKind};
use crate::text::{At, fmt_f64, read_to_string};
use lie::{LieGroup, Se3};
use nalgebra::{Matrix4, Vector3};
use std::io::Write;
use std::path::Path;

/// Tolerance on `max |RᵀR − I|` for KITTI rotation blocks, which are printed with about 6–7
/// significant digits (and, for estimates, sometimes re-orthonormalised less carefully).
pub const KITTI_ORTHONORMALITY_TOLERANCE: f64 = 1e-4;

/// A timestamped trajectory.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Trajectory {
    /// Timestamps in seconds, one per pose.
    pub timestamps: Vec<f64>,
    /// The poses, `world_from_body`.
    pub world_from_body: Vec<Se3>,
}

impl Trajectory {
    /// Poses with timestamps `0, 1, 2, …` (for KITTI files, which carry none).
    pub fn from_poses(world_from_body: Vec<Se3>) -> Self {
        let timestamps = (0..world_from_body.len()).map(|i| i as f64).collect();
        Trajectory {
            timestamps,
            world_from_body,
        }
    }

    /// Number of poses.
    pub fn len(&self) -> usize {
        self.world_from_body.len()
    }

    /// `true` when there are no poses.
    pub fn is_empty(&self) -> bool {
        self.world_from_body.is_empty()
    }

    /// The body positions in the world (the translations of `world_from_body`).
    pub fn positions(&self) -> Vec<Vector3<f64>> {
        self.world_from_body
            .iter()
            .map(|p| *p.translation())
            .collect()
    }
}

fn words(line: &str) -> Option<Vec<&str>> {
    let trimmed = line.trim();
    if trimmed.is_empty() || trimmed.starts_with('#') {
        return None;
    }
    Some(trimmed.split_whitespace().collect())
}

fn empty_error(path: &Path, what: &str) -> DataError {
    DataError::File {
        path: path.to_path_buf(),
        kind: ParseErrorKind::Empty {
            expected: what.into(),
        },
    }
}

/// Reads a TUM trajectory file: `timestamp tx ty tz qx qy qz qw` per line.
pub fn read_tum(path: impl AsRef<Path>) -> Result<Trajectory, DataError> {
    let path = path.as_ref();
    parse_tum(&read_to_string(path)?, path)
}

/// Parses TUM text; `path` only names the source in errors.
pub fn parse_tum(text: &str, path: &Path) -> Result<Trajectory, DataError> {
    const NAMES: [&str; 8] = ["timestamp", "tx", "ty", "tz", "qx", "qy", "qz", "qw"];
    let mut trajectory = Trajectory::default();
    for (i, line) in text.lines().enumerate() {
        let at = At { path, line: i + 1 };
        let Some(w) = words(line) else { continue };
        at.field_count("TUM pose (timestamp tx ty tz qx qy qz qw)", &w, 8)?;
        let mut v = [0.0; 8];
        for k in 0..8 {
            v[k] = at.number(w[k], NAMES[k])?;
        }
        let pose = Se3::from_quaternion_translation(
            v[7],
            v[4],
            v[5],
            v[6],
            Vector3::new(v[1], v[2], v[3]),
        )
        .map_err(|source| {
            at.err(ParseErrorKind::InvalidRotation {
                what: "quaternion (qx qy qz qw)".into(),
                source,
            })
        })?;
        trajectory.timestamps.push(v[0]);
        trajectory.world_from_body.push(pose);
    }
    if trajectory.is_empty() {
        return Err(empty_error(path, "TUM poses"));
    }
    Ok(trajectory)
}

/// Writes a TUM trajectory (numbers round-trip exactly).
pub fn write_tum(trajectory: &Trajectory, mut out: impl Write) -> std::io::Result<()> {
    for (t, pose) in trajectory
        .timestamps
        .iter()
        .zip(&trajectory.world_from_body)
    {
        let p = pose.translation();
        let q = pose.rotation().unit_quaternion();
        let v = [*t, p.x, p.y, p.z, q.i, q.j, q.k, q.w];
        let text: Vec<String> = v.iter().map(|x| fmt_f64(*x)).collect();
        writeln!(out, "{}", text.join(" "))?;
    }
    out.flush()
}

/// Reads a KITTI pose file: 12 numbers per line, the first three rows of `world_from_camera`
/// row by row.
pub fn read_kitti(path: impl AsRef<Path>) -> Result<Vec<Se3>, DataError> {
    let path = path.as_ref();
    parse_kitti(&read_to_string(path)?, path)
}

/// Parses KITTI pose text; `path` only names the source in errors.
pub fn parse_kitti(text: &str, path: &Path) -> Result<Vec<Se3>, DataError> {
    parse_kitti_rows(text, path)?
        .into_iter()
        .map(|(line, m)| {
            Se3::from_matrix_with_tolerance(&m, KITTI_ORTHONORMALITY_TOLERANCE).map_err(|source| {
                At { path, line }.err(ParseErrorKind::InvalidRotation {
                    what: "rotation block".into(),
                    source,
                })
            })
        })
        .collect()
}

/// Reads a KITTI pose file as the 4×4 matrices it stores, not re-orthonormalised (KITTI prints
/// 7 digits, so the rotation blocks are orthonormal to ~1e-7); evo computes with these, and
/// so does [`crate::eval::rpe_matrices`] to agree with it.
pub fn read_kitti_matrices(path: impl AsRef<Path>) -> Result<Vec<Matrix4<f64>>, DataError> {
    let path = path.as_ref();
    let rows = parse_kitti_rows(&read_to_string(path)?, path)?;
    // Validated as poses like `read_kitti` does.
    parse_kitti(&read_to_string(path)?, path)?;
    Ok(rows.into_iter().map(|(_, m)| m).collect())
}

fn parse_kitti_rows(text: &str, path: &Path) -> Result<Vec<(usize, Matrix4<f64>)>, DataError> {
    let mut poses = Vec::new();
    for (i, line) in text.lines().enumerate() {
        let at = At { path, line: i + 1 };
        let Some(w) = words(line) else { continue };
        at.field_count("KITTI pose (3×4 matrix, row-major)", &w, 12)?;
        let mut m = Matrix4::identity();
        for k in 0..12 {
            m[(k / 4, k % 4)] =
                at.number(w[k], &format!("entry ({}, {})", k / 4 + 1, k % 4 + 1))?;
        }
        poses.push((i + 1, m));
    }
    if poses.is_empty() {
        return Err(empty_error(path, "KITTI poses"));
    }
    Ok(poses)
}

/// Writes KITTI poses (numbers round-trip exactly).
pub fn write_kitti(world_from_camera: &[Se3], mut out: impl Write) -> std::io::Result<()> {
    for pose in world_from_camera {
        let m = pose.matrix();
        let text: Vec<String> = (0..12).map(|k| fmt_f64(m[(k / 4, k % 4)])).collect();
        writeln!(out, "{}", text.join(" "))?;
    }
    out.flush()
}

/// Reads a EuRoC ground-truth CSV (`state_groundtruth_estimate0/data.csv`): columns
/// `timestamp [ns], p_x, p_y, p_z, q_w, q_x, q_y, q_z, …` (further columns — velocities and
/// biases — are ignored); timestamps are converted to seconds (`ns / 1e9`, as evo does).
pub fn read_euroc_groundtruth(path: impl AsRef<Path>) -> Result<Trajectory, DataError> {
    let path = path.as_ref();
    parse_euroc_groundtruth(&read_to_string(path)?, path)
}

/// Parses EuRoC ground-truth CSV text; `path` only names the source in errors.
pub fn parse_euroc_groundtruth(text: &str, path: &Path) -> Result<Trajectory, DataError> {
    const NAMES: [&str; 8] = ["timestamp", "p_x", "p_y", "p_z", "q_w", "q_x", "q_y", "q_z"];
    let mut trajectory = Trajectory::default();
    for (i, line) in text.lines().enumerate() {
        let at = At { path, line: i + 1 };
        let trimmed = line.trim();
        if trimmed.is_empty() || trimmed.starts_with('#') {
            continue;
        }
        let w: Vec<&str> = trimmed.split(',').map(str::trim).collect();
        if w.len() < 8 {
            return Err(at.err(ParseErrorKind::FieldCount {
                record: "EuRoC ground truth (timestamp, p, q, …)".into(),
                expected: "at least 8".into(),
                found: w.len(),
            }));
        }
        let mut v = [0.0; 8];
        for k in 0..8 {
            v[k] = at.number(w[k], NAMES[k])?;
        }
        let pose = Se3::from_quaternion_translation(
            v[4],
            v[5],
            v[6],
            v[7],
            Vector3::new(v[1], v[2], v[3]),
        )
        .map_err(|source| {
            at.err(ParseErrorKind::InvalidRotation {
                what: "quaternion (q_w q_x q_y q_z)".into(),
                source,
            })
        })?;
        trajectory.timestamps.push(v[0] / 1e9);
        trajectory.world_from_body.push(pose);
    }
    if trajectory.is_empty() {
        return Err(empty_error(path, "EuRoC ground-truth rows"));
    }
    Ok(trajectory)
}

/// Reads a list of timestamps, one number per line (KITTI's `times.txt`).
pub fn read_timestamps(path: impl AsRef<Path>) -> Result<Vec<f64>, DataError> {
    let path = path.as_ref();
    let text = read_to_string(path)?;
    let mut stamps = Vec::new();
    for (i, line) in text.lines().enumerate() {
        let at = At { path, line: i + 1 };
        let Some(w) = words(line) else { continue };
        at.field_count("timestamp", &w, 1)?;
        stamps.push(at.number(w[0], "timestamp")?);
    }
    if stamps.is_empty() {
        return Err(empty_error(path, "timestamps"));
    }
    Ok(stamps)
}

/// Associates two lists of timestamps as `evo` does (`evo.core.sync.associate_trajectories`,
/// nearest-time method): starting from the *shorter* list, each of its timestamps is paired with
/// the nearest timestamp of the longer list (shifted by `offset`, which applies to
/// `estimate`) if they differ by at most `max_difference` seconds; on a tie the earlier one is
/// taken. A timestamp of the longer list may be used more than once. Returns
/// `(reference index, estimate index)` pairs in increasing order of the shorter list's index.
/// The longer list is expected sorted (as evo's binary search does; evo falls back to a linear
/// search otherwise, which gives the same pairs).
pub fn associate(
    reference: &[f64],
    estimate: &[f64],
    max_difference: f64,
    offset: f64,
) -> Vec<(usize, usize)> {
    let estimate_longer = estimate.len() > reference.len();
    let (short, long, long_offset): (Vec<f64>, Vec<f64>, f64) = if estimate_longer {
        (reference.to_vec(), estimate.to_vec(), offset)
    } else {
        (estimate.to_vec(), reference.to_vec(), -offset)
    };
    let long: Vec<f64> = long.iter().map(|t| t + long_offset).collect();
    let sorted = long.windows(2).all(|w| w[1] >= w[0]);
    let mut pairs = Vec::new();
    for (i, &stamp) in short.iter().enumerate() {
        let best = if sorted {
            if long.is_empty()
                || stamp < long[0] - max_difference
                || stamp > long[long.len() - 1] + max_difference
            {
                continue;
            }
            // first index with long[index] > stamp ("searchsorted right"), clamped
            let upper = long.partition_point(|&t| t <= stamp).min(long.len() - 1);
            let diff_upper = long[upper] - stamp;
            let diff_lower = if upper > 0 {
                stamp - long[upper - 1]
            } else {
                f64::INFINITY
            };
            if diff_upper <= max_difference && diff_upper < diff_lower {
                upper
            } else if diff_lower <= max_difference && diff_lower <= diff_upper {
                upper - 1
            } else {
                continue;
            }
        } else {
            let Some((j, d)) = long
                .iter()
                .map(|t| (t - stamp).abs())
                .enumerate()
                .min_by(|a, b| a.1.total_cmp(&b.1))
            else {
                continue;
            };
            if d > max_difference {
                continue;
            }
            j
        };
        pairs.push(if estimate_longer {
            (i, best)
        } else {
            (best, i)
        });
    }
    pairs
}

/// The poses of `reference` and `estimate` at associated timestamps ([`associate`]), in
/// matching order.
pub fn associate_trajectories(
    reference: &Trajectory,
    estimate: &Trajectory,
    max_difference: f64,
    offset: f64,
) -> (Vec<Se3>, Vec<Se3>) {
    associate(
        &reference.timestamps,
        &estimate.timestamps,
        max_difference,
        offset,
    )
    .into_iter()
    .map(|(r, e)| (reference.world_from_body[r], estimate.world_from_body[e]))
    .unzip()
}

/// Relative pose `a⁻¹·b` (pose of `b` in the frame of `a`).
pub fn relative(a: &Se3, b: &Se3) -> Se3 {
    a.inverse().compose(b)
}

/// One-to-one association of two timestamp lists as TUM RGB-D's `associate.py` does it: every
/// pair `(a, b)` with `|a − (b + offset)| < max_difference` is a candidate; candidates are taken
/// in increasing order of that difference (ties by `a`, then `b`), each timestamp of either list
/// at most once. Returns `(index in first, index in second)` pairs sorted by the first index.
/// Both lists are expected sorted (candidates are found by a sliding window; unsorted lists
/// give a subset of `associate.py`'s pairs).
pub fn associate_unique(
    first: &[f64],
    second: &[f64],
    offset: f64,
    max_difference: f64,
) -> Vec<(usize, usize)> {
    let mut candidates: Vec<(f64, usize, usize)> = Vec::new();
    let mut start = 0;
    for (i, &a) in first.iter().enumerate() {
        while start < second.len() && second[start] + offset <= a - max_difference {
            start += 1;
        }
        let mut j = start;
        while j < second.len() && second[j] + offset < a + max_difference {
            let d = (a - (second[j] + offset)).abs();
            if d < max_difference {
                candidates.push((d, i, j));
            }
            j += 1;
        }
    }
    candidates.sort_by(|x, y| {
        x.0.total_cmp(&y.0)
            .then(first[x.1].total_cmp(&first[y.1]))
            .then(second[x.2].total_cmp(&second[y.2]))
    });
    let mut used_first = vec![false; first.len()];
    let mut used_second = vec![false; second.len()];
    let mut pairs = Vec::new();
    for (_, i, j) in candidates {
        if !used_first[i] && !used_second[j] {
            used_first[i] = true;
            used_second[j] = true;
            pairs.push((i, j));
        }
    }
    pairs.sort();
    pairs
}

/// The trajectory file formats [`read_trajectory`] tells apart.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum TrajectoryFormat {
    /// `timestamp tx ty tz qx qy qz qw`.
    Tum,
    /// 12 numbers per line, no timestamps.
    Kitti,
    /// EuRoC ground-truth CSV (nanoseconds, comma-separated).
    Euroc,
}

/// The format of trajectory text from its first data line: comma-separated with ≥ 8 fields is
/// EuRoC, 8 fields TUM, 12 fields KITTI.
pub fn detect_trajectory_format(text: &str, path: &Path) -> Result<TrajectoryFormat, DataError> {
    for (i, line) in text.lines().enumerate() {
        let t = line.trim();
        if t.is_empty() || t.starts_with('#') {
            continue;
        }
        let commas = t.split(',').count();
        let words = t.split_whitespace().count();
        return match (commas, words) {
            (c, _) if c >= 8 => Ok(TrajectoryFormat::Euroc),
            (_, 8) => Ok(TrajectoryFormat::Tum),
            (_, 12) => Ok(TrajectoryFormat::Kitti),
            _ => Err(DataError::Parse {
                path: path.to_path_buf(),
                line: i + 1,
                kind: ParseErrorKind::Expected {
                    expected: "a trajectory line: TUM (8 numbers), KITTI (12) or EuRoC CSV (≥ 8 \
                               comma-separated)"
                        .into(),
                    found: format!("{words} space-separated fields"),
                },
            }),
        };
    }
    Err(empty_error(path, "trajectory lines"))
}

/// Reads a trajectory in any of the [`TrajectoryFormat`]s (KITTI poses get timestamps
/// `0, 1, 2, …`, i.e. they associate by index, as evo's `kitti` mode).
pub fn read_trajectory(
    path: impl AsRef<Path>,
) -> Result<(Trajectory, TrajectoryFormat), DataError> {
    let path = path.as_ref();
    let text = read_to_string(path)?;
    let format = detect_trajectory_format(&text, path)?;
    let t = match format {
        TrajectoryFormat::Tum => parse_tum(&text, path)?,
        TrajectoryFormat::Kitti => Trajectory::from_poses(parse_kitti(&text, path)?),
        TrajectoryFormat::Euroc => parse_euroc_groundtruth(&text, path)?,
    };
    Ok((t, format))
}
