//! What a run leaves (the session's end, [`super::Session::finish`]): the maps written — the
//! group of maps joined together with the most keyframes, in the world of its largest map
//! (`slam::map::maps`) — with every frame's live pose, the trajectory after the run, the
//! keyframes and points of those maps, and the warnings a person reading the run needs.

use super::log::{FrameLog, in_world};
use super::sensor::Finished;
use crate::keyframes::KeyframeStore;
use crate::result::{
    LockWaits, LoopEvent, MapSnapshot, NewMap, RefusedLoop, Relocalisation, RunGraph, RunResult,
};
use data::output::{KeyframeRecord, MapPoint};
use data::trajectory::Trajectory;
use lie::{LieGroup, Sim3};
use slam::dwo::DwoStats;
use slam::map::{FIRST_MAP, SlamGraph};
use slam::pose_graph::rigid_from_similarity;
use std::collections::BTreeMap;

/// What the session has at its end, for the outputs.
pub(super) struct Ended {
    /// The frames recorded.
    pub log: FrameLog,
    /// The keyframes' images.
    pub store: KeyframeStore,
    /// The maps started after a loss: `(frame, seconds lost before it, map)`.
    pub new_maps: Vec<(usize, f64, usize)>,
    pub relocalisations: Vec<Relocalisation>,
    pub loops: Vec<LoopEvent>,
    pub refused: Vec<RefusedLoop>,
    pub optimisations: Vec<DwoStats>,
    pub warnings: Vec<String>,
    /// Keyframes that found the loop closer's queue full, its length, the most that waited.
    pub loop_queue_full: (usize, usize, usize),
    pub lock_waits: LockWaits,
    pub backend_lock_waits: Vec<(&'static str, LockWaits)>,
}

/// The run's result from what the session ended with and the sensor's final graphs
/// (`run_graph` makes the result's graph of the sensor's).
pub(super) fn assemble<const N: usize>(
    ended: Ended,
    finished: Finished<N>,
    run_graph: impl FnOnce(SlamGraph<N>) -> RunGraph,
) -> RunResult {
    let Ended {
        mut log,
        store,
        new_maps,
        relocalisations,
        mut loops,
        refused,
        optimisations,
        mut warnings,
        loop_queue_full,
        lock_waits,
        backend_lock_waits,
    } = ended;
    let Finished {
        graph,
        alternatives,
    } = finished;
    let (world, from_world) = graph.written_maps();
    if world != FIRST_MAP {
        let dropped = log.write_map(world);
        warnings.push(world_warning(&graph, world, dropped, &from_world));
    }
    let new_maps = new_map_records(&new_maps, &log, &graph, &from_world, &store);
    warnings.extend(join_warnings(&graph, &from_world));
    warnings.extend(new_maps.iter().map(|m| new_map_warning(m, world)));
    warnings.extend(refused_loop_warnings(&refused));
    if loop_queue_full.0 > 0 {
        warnings.push(format!(
            "{} keyframes found the loop closer's queue full (loops.queue: {}) and waited for \
             room in the tracking thread, at most {} at once",
            loop_queue_full.0, loop_queue_full.1, loop_queue_full.2
        ));
    }
    log.record.keyframes = keyframe_records(&graph, &from_world, &store);
    log.record.points = map_points(&graph, &from_world, &store);
    let final_trajectory = trajectory(&log, &graph, &from_world);
    let alternatives = alternatives
        .into_iter()
        .map(|(name, g)| (name, trajectory(&log, &g, &from_world)))
        .collect();
    loops.sort_by_key(|l| l.frames.0);
    RunResult {
        culled: log.culled,
        record: log.record,
        final_trajectory,
        frames: log.reports,
        loops,
        relocalisations,
        new_maps,
        world_map: world,
        refused_loops: refused,
        optimisations,
        graph: run_graph(graph),
        keyframes: store,
        warnings,
        alternatives,
        lock_waits,
        backend_lock_waits,
        saved_map: None,
    }
}

impl RunResult {
    /// The map after the run as a [`MapSnapshot`] (what a live view draws at the end).
    pub fn snapshot(&self) -> MapSnapshot {
        match &self.graph {
            RunGraph::Depth(g) => snapshot(g, &self.keyframes, &self.loops),
            RunGraph::Mono(g) => snapshot(g, &self.keyframes, &self.loops),
        }
    }
}

/// The map of `graph` as it is now, in the world of the maps that would be written (see
/// [`MapSnapshot`]), with the `loops` closed so far.
pub(crate) fn snapshot<const N: usize>(
    graph: &SlamGraph<N>,
    store: &KeyframeStore,
    loops: &[LoopEvent],
) -> MapSnapshot {
    let (_, from_world) = graph.written_maps();
    let keyframes = keyframe_records(graph, &from_world, store);
    let mut edges = Vec::new();
    for (k, kf) in graph.keyframes() {
        if !from_world.contains_key(&kf.map()) {
            continue;
        }
        for (other, edge) in kf.edges() {
            if k < *other {
                edges.push((k.index(), other.index(), edge.relative.is_some()));
            }
        }
    }
    MapSnapshot {
        points: map_points(graph, &from_world, store),
        keyframes,
        edges,
        loops: loops
            .iter()
            .map(|l| (l.keyframe.index(), l.old.index(), l.scale))
            .collect(),
    }
}

/// Every frame's pose after the run (its keyframe's in `graph`), in the world of the maps
/// written; a frame of another map has none.
fn trajectory<const N: usize>(
    log: &FrameLog,
    graph: &SlamGraph<N>,
    from_world: &BTreeMap<usize, Sim3>,
) -> Trajectory {
    let mut t = Trajectory::default();
    for (position, camera_from_world) in log.reexpressed(graph, from_world) {
        t.timestamps.push(log.record.frames[position].timestamp);
        t.world_from_body.push(camera_from_world.inverse());
    }
    t
}

/// The keyframes of the maps written, in the world, by timestamp.
fn keyframe_records<const N: usize>(
    graph: &SlamGraph<N>,
    from_world: &BTreeMap<usize, Sim3>,
    store: &KeyframeStore,
) -> Vec<KeyframeRecord> {
    let mut records: Vec<KeyframeRecord> = graph
        .keyframes()
        .filter_map(|(k, kf)| {
            let w = from_world.get(&kf.map())?;
            let images = store.get(k)?;
            let camera_from_map = rigid_from_similarity(kf.camera_from_world());
            Some(KeyframeRecord {
                id: k.index(),
                frame_index: images.frame_index,
                timestamp: images.timestamp,
                world_from_camera: in_world(w, &camera_from_map).inverse(),
            })
        })
        .collect();
    records.sort_by(|a, b| a.timestamp.total_cmp(&b.timestamp));
    records
}

/// The points of the maps written, in the world, coloured from their anchor keyframe's image
/// where it is kept.
fn map_points<const N: usize>(
    graph: &SlamGraph<N>,
    from_world: &BTreeMap<usize, Sim3>,
    store: &KeyframeStore,
) -> Vec<MapPoint> {
    graph
        .points()
        .filter_map(|(p, pt)| {
            let map = graph.map_of(pt.anchor()).ok()?;
            let world_from_map = from_world.get(&map)?.inverse();
            let position = world_from_map.act(&graph.point_world(p).ok()?);
            let z = graph.keyframe(pt.anchor())?.observations().get(&p)?;
            let colour = store.get(pt.anchor()).map(|i| i.colour_at(z[0], z[1]));
            Some(MapPoint { position, colour })
        })
        .collect()
}

/// The maps started after a loss (`(frame, seconds lost, map)`), with whether they are among
/// the maps written. A map starts at the frame of its first keyframe (a monocular map's
/// bootstrap may take frames; one that never made a keyframe, at the frame it was started).
fn new_map_records<const N: usize>(
    new_maps: &[(usize, f64, usize)],
    log: &FrameLog,
    graph: &SlamGraph<N>,
    from_world: &BTreeMap<usize, Sim3>,
    store: &KeyframeStore,
) -> Vec<NewMap> {
    new_maps
        .iter()
        .map(|&(started, lost_for, map)| {
            // A map merged into another is that one now.
            let now = graph.moved_since(0, map).map_or(map, |(_, m)| m);
            let first = graph
                .keyframes()
                .filter(|(k, _)| store.get(*k).is_some_and(|i| i.frame_index >= started))
                .find(|(_, kf)| kf.map() == now)
                .and_then(|(k, _)| store.get(k))
                .map_or(started, |i| i.frame_index);
            NewMap {
                frame: first,
                lost_for,
                map,
                joined: from_world.contains_key(&now),
                frames: log.off_world.iter().filter(|o| o.map == map).count(),
            }
        })
        .collect()
}

/// The warning that the map written is not the first (whose `dropped` frames lost their live
/// pose).
fn world_warning<const N: usize>(
    graph: &SlamGraph<N>,
    world: usize,
    dropped: usize,
    from_world: &BTreeMap<usize, Sim3>,
) -> String {
    let count = |m: usize| {
        graph
            .keyframes_per_map()
            .into_iter()
            .find(|(o, _)| *o == m)
            .map_or(0, |(_, n)| n)
    };
    format!(
        "the map written is map {world}, which holds more keyframes ({}) than the first ({}): \
         the first map's {dropped} frames have no pose in the {}",
        count(world),
        count(FIRST_MAP),
        if from_world.contains_key(&FIRST_MAP) {
            "live trajectory (the first map is joined to it: they are in the final one)"
        } else {
            "trajectories"
        }
    )
}

/// One line per pair of maps joined by place recognition (the monocular system's joins).
fn join_warnings<const N: usize>(
    graph: &SlamGraph<N>,
    from_world: &BTreeMap<usize, Sim3>,
) -> Vec<String> {
    let mut seen = Vec::new();
    let mut lines = Vec::new();
    for j in graph.joins() {
        let (Ok(map), Ok(other)) = (graph.map_of(j.current), graph.map_of(j.old)) else {
            continue;
        };
        if seen.contains(&(map, other)) {
            continue;
        }
        seen.push((map, other));
        lines.push(format!(
            "keyframe {}: map {map} recognised a place of map {other} (keyframe {}; Sim(3) \
             scale {:.3}, {} inliers): the two maps are joined in the outputs{}",
            j.current,
            j.old,
            j.current_from_old.scale(),
            j.inliers,
            if from_world.contains_key(&map) {
                ""
            } else {
                " (not the maps written)"
            }
        ));
    }
    lines
}

/// What became of a map started after a loss.
fn new_map_warning(m: &NewMap, world: usize) -> String {
    let NewMap {
        frame,
        lost_for,
        map,
        frames,
        joined,
    } = m;
    let started = format!(
        "frame {frame}: lost for {lost_for:.1} s, not found again in the map; a new map (map \
         {map}) was started there"
    );
    if *map == world {
        format!("{started}: the map written")
    } else if *joined {
        format!(
            "{started} and a loop (kind \"merge\") later joined it to the map written: its \
             frames have poses in the final trajectory (and in the live one from the merge on, \
             where the maps were merged: stereo and RGB-D)"
        )
    } else {
        format!(
            "{started}, which no loop joined to the map written: its {frames} frames have no \
             pose in the trajectories, and its keyframes and points are not in the map written"
        )
    }
}

/// The warnings that sum up the refused appearance loops: those refused for the correction
/// they needed (how many, the range of corrections and the largest one next to what its path
/// allowed), and those refused on their evidence (how many, and the first one's reason).
pub(crate) fn refused_loop_warnings(refused: &[RefusedLoop]) -> Vec<String> {
    let (by_drift, by_evidence): (Vec<&RefusedLoop>, Vec<&RefusedLoop>) =
        refused.iter().partition(|r| r.allowed.is_some());
    let plural = |n: usize| {
        if n == 1 { ("", "was") } else { ("s", "were") }
    };
    let mut warnings = Vec::new();
    if let Some(worst) = by_drift
        .iter()
        .max_by(|a, b| a.drift.displacement.total_cmp(&b.drift.displacement))
    {
        let least = by_drift
            .iter()
            .map(|r| r.drift.displacement)
            .fold(f64::INFINITY, f64::min);
        let (s, was) = plural(by_drift.len());
        warnings.push(format!(
            "{} loop{s} by appearance {was} refused, each needing more correction than the \
             drift the path between the two places allows (a place that looks like another): \
             {least:.2}–{:.2} m, the largest from frame {} to frame {} against {:.2} m allowed \
             over {:.1} m of path (all in summary.json, refused_loops)",
            by_drift.len(),
            worst.drift.displacement,
            worst.frames.0,
            worst.frames.1,
            worst.allowed.unwrap_or_default(),
            worst.drift.path,
        ));
    }
    if let Some(first) = by_evidence.first() {
        let (s, was) = plural(by_evidence.len());
        warnings.push(format!(
            "{} loop detection{s} by appearance {was} refused on {} evidence; the first, from \
             frame {} to frame {}: {} (all in summary.json, refused_loops)",
            by_evidence.len(),
            if by_evidence.len() == 1 {
                "its"
            } else {
                "their"
            },
            first.frames.0,
            first.frames.1,
            first.reason,
        ));
    }
    warnings
}

#[cfg(test)]
mod tests {
    use super::*;
    use slam::loop_closure::LoopDrift;

    fn refused(frames: (usize, usize), displacement: f64, path: f64) -> RefusedLoop {
        RefusedLoop {
            frames,
            drift: LoopDrift {
                displacement,
                path,
                scene_depth: 3.0,
            },
            allowed: Some((0.05 * path).max(0.3)),
            reason: "too much drift".into(),
        }
    }

    #[test]
    fn refused_loops_are_summed_up_in_one_warning() {
        assert!(refused_loop_warnings(&[]).is_empty());
        let one = refused_loop_warnings(&[refused((90, 10), 2.5, 20.0)]).remove(0);
        assert!(one.starts_with("1 loop by appearance was refused"), "{one}");
        let mut weak = refused((500, 20), 1.0, 90.0);
        weak.allowed = None;
        weak.reason = "3 of the old place's 90 points found".into();
        let warnings = refused_loop_warnings(&[
            refused((90, 10), 2.5, 20.0),
            refused((400, 120), 12.25, 60.0),
            weak.clone(),
            refused((410, 300), 0.75, 8.0),
        ]);
        assert_eq!(warnings.len(), 2, "{warnings:?}");
        let many = &warnings[0];
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
        // The one refused on its evidence, with its reason.
        assert_eq!(
            warnings[1],
            "1 loop detection by appearance was refused on its evidence; the first, from frame \
             500 to frame 20: 3 of the old place's 90 points found (all in summary.json, \
             refused_loops)"
        );
    }
}
