//! The report of `dwslam run`: the trajectory against the ground truth, the keyframe graph with
//! its loop edges, the time per frame and per keyframe, the tracked points (PNG, `crate::plot`).

use crate::plot::{self, Figure, GREY, PALETTE, Series, Style};
use anyhow::Result;
use data::eval::{Alignment, ate};
use data::trajectory::{Trajectory, associate};
use lie::{LieGroup, Se3};
use std::path::Path;
use system::RunResult;

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
pub(crate) fn report(
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
