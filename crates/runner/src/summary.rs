//! What a run writes beside its record: `summary.json`'s sections, the evaluation against
//! the ground truth, the trajectories after the run and the per-frame and per-optimisation
//! tables.

use anyhow::{Context, Result};
use data::eval::{Alignment, KITTI_SEGMENT_LENGTHS, ate, drift, rpe};
use data::trajectory::{Trajectory, associate, write_tum};
use lie::Se3;
use serde_json::json;
use std::path::Path;
use system::{Mode, RunResult};

/// Per frame: the tracker's counts and times (CSV).
pub const FRAME_STATS_FILE: &str = "frames.csv";

/// Per optimisation (one per keyframe): window sizes, problem size and times (CSV).
pub const OPTIMISATION_STATS_FILE: &str = "optimisations.csv";

/// The trajectory file of the poses after the run's final optimisation.
pub const FINAL_TRAJECTORY_FILE: &str = "trajectory_final.tum";

/// What `summary.json` says beside the run's record: how it ran, why keyframes were made,
/// the warnings, loops, relocalisations, new maps, refused loops, optimisations, the tracking
/// thread's lock waits, and the evaluation.
pub(crate) fn summary_extra(
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
    let ms = |d: std::time::Duration| d.as_secs_f64() * 1e3;
    let waits = &result.lock_waits;
    extra.insert(
        "tracking_lock_waits".into(),
        json!({"locks": waits.count, "median_ms": ms(waits.median), "p99_ms": ms(waits.p99),
            "max_ms": ms(waits.max), "frames_over_1ms": waits.frames_over_1ms}),
    );
    let backend: serde_json::Map<String, serde_json::Value> = result
        .backend_lock_waits
        .iter()
        .map(|(thread, w)| {
            let v = json!({"locks": w.count, "median_ms": ms(w.median), "p99_ms": ms(w.p99),
                "max_ms": ms(w.max), "jobs_over_1ms": w.frames_over_1ms});
            (thread.to_string(), v)
        })
        .collect();
    extra.insert("backend_lock_waits".into(), backend.into());
    if let Some(e) = evaluation {
        extra.insert("evaluation".into(), e.json.clone());
    }
    extra
}

/// The trajectory after the run (`trajectory_final.tum`) and the alternatives (each with its
/// ATE against `ground_truth`, printed).
pub(crate) fn write_trajectories(
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
pub(crate) fn print_loops(result: &RunResult) {
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

pub(crate) fn write_frame_stats(path: &Path, result: &RunResult) -> Result<()> {
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

pub(crate) fn write_optimisation_stats(path: &Path, result: &RunResult) -> Result<()> {
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

fn median(v: &[f64]) -> f64 {
    let mut v: Vec<f64> = v.iter().copied().filter(|x| x.is_finite()).collect();
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

/// ATE and RPE of the live and the final trajectory against the ground truth.
pub(crate) struct Evaluation {
    pub(crate) json: serde_json::Value,
    pub(crate) lines: Vec<String>,
    /// ATE RMSE (m) of the live and the final trajectory, when both were evaluated.
    pub(crate) ate: Option<(f64, f64)>,
}

pub(crate) fn evaluate(gt: &Trajectory, result: &RunResult, alignment: Alignment) -> Evaluation {
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

/// `summary.json` of a run driven frame by frame (the Python package's `System`): the
/// record's summary with the sections [`summary_extra`] adds, without an evaluation (a
/// stream brings no ground truth).
pub fn summary_of(result: &RunResult, mode: Mode, seconds: f64) -> data::output::Summary {
    let mut record = result.record.clone();
    record
        .extra
        .extend(summary_extra(result, mode, seconds, None));
    record.summary()
}
