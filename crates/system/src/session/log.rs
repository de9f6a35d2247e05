//! The frames of a run as the session records them: each frame's live pose and state (the
//! run's record and the per-frame reports), and, for the trajectory after the run, each pose
//! relative to a keyframe, re-expressed at the end against the keyframes as the final
//! optimisation leaves them (thesis §6.5.2: a frame is a keyframe's neighbour in the graph).

use crate::result::FrameReport;
use data::output::{FrameRecord, RunRecord, TrackingState};
use lie::{LieGroup, Se3, Sim3};
use slam::map::{FIRST_MAP, KeyframeId, SlamGraph};
use slam::mapping::culling::Retired;
use slam::pose_graph::rigid_from_similarity;
use std::collections::HashMap;

/// A frame's pose relative to a keyframe.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Anchored {
    /// The frame's position in the record.
    pub position: usize,
    /// The keyframe.
    pub keyframe: KeyframeId,
    /// `T·T_k⁻¹`, or `None` where the frame is the keyframe's own (its pose is the keyframe's).
    pub relative: Option<Sim3>,
}

/// A frame tracked in a map other than the first, which has no pose in the first map's world.
#[derive(Clone, Debug)]
pub(crate) struct OffWorld {
    /// The frame's position in the record.
    pub position: usize,
    /// The map.
    pub map: usize,
    /// Its pose in that map.
    pub camera_from_world: Sim3,
    /// Its state as tracked.
    pub state: TrackingState,
}

/// The frames recorded so far (see the [module docs](self)).
#[derive(Default)]
pub(crate) struct FrameLog {
    /// The run's record: every frame's live pose and state, the timings.
    pub record: RunRecord,
    /// Per frame, the report.
    pub reports: Vec<FrameReport>,
    /// Per frame with a pose, where it is relative to a keyframe.
    pub anchored: Vec<Anchored>,
    /// The frames tracked outside the first map.
    pub off_world: Vec<OffWorld>,
    /// Per keyframe, the entries of `anchored` kept relative to it.
    pub by_keyframe: HashMap<KeyframeId, Vec<usize>>,
    /// Keyframes culled so far.
    pub culled: usize,
}

/// The pose of a frame in the world, rigid (a monocular map's keyframes are similarities
/// whose scale changes at a loop correction: a pose in the map is `(R, t/s)`).
pub(crate) fn world_from_camera(camera_from_world: &Sim3) -> Se3 {
    rigid_from_similarity(camera_from_world).inverse()
}

impl FrameLog {
    /// Records a frame: its `report` and, if tracked, its pose `camera_from_world` kept relative
    /// to keyframe `anchor` of `graph` (the frame's own keyframe if `own`). Only a pose in the
    /// first map (or a map merged into it) is a pose in the world: a frame tracked in a map
    /// started after a loss, not merged into the first, has none (its map's place in the world
    /// is unknown while the run goes on) and its state says so; its pose is kept, for the
    /// outputs if its map is the one written. Returns the report as recorded.
    pub fn push<const N: usize>(
        &mut self,
        graph: &SlamGraph<N>,
        timestamp: f64,
        camera_from_world: Option<Sim3>,
        anchor: Option<(KeyframeId, bool)>,
        mut report: FrameReport,
    ) -> FrameReport {
        let position = self.record.frames.len();
        let mut world_pose = camera_from_world;
        if let (Some(pose), Some((k, own))) = (camera_from_world, anchor)
            && let Ok(t_k) = graph.pose(k)
        {
            self.anchor(Anchored {
                position,
                keyframe: k,
                relative: (!own).then(|| pose.compose(&t_k.inverse())),
            });
            if let Ok(map) = graph.map_of(k)
                && map != FIRST_MAP
            {
                world_pose = None;
                self.off_world.push(OffWorld {
                    position,
                    map,
                    camera_from_world: pose,
                    state: report.state.clone(),
                });
                report.state = TrackingState::Weak(match &report.state {
                    TrackingState::Weak(reason) => format!(
                        "{reason}; in map {map}, not joined to the first map: no pose in the world"
                    ),
                    _ => format!(
                        "tracked in map {map}, started after a loss and not merged into the first \
                         map: no pose in the world"
                    ),
                });
            }
        }
        self.record.frames.push(FrameRecord {
            index: report.index,
            timestamp,
            world_from_camera: world_pose.map(|t| world_from_camera(&t)),
            state: report.state.clone(),
        });
        self.record.timings.record("frame: total", report.time);
        self.reports.push(report.clone());
        report
    }

    /// The frame of index `frame`, recorded earlier without a pose, is keyframe `keyframe`'s
    /// own (a monocular bootstrap's first frame): it has the keyframe's pose after the run.
    pub fn anchor_earlier(&mut self, frame: usize, keyframe: KeyframeId) {
        if let Some(position) = self.record.frames.iter().rposition(|f| f.index == frame) {
            self.anchor(Anchored {
                position,
                keyframe,
                relative: None,
            });
        }
    }

    fn anchor(&mut self, a: Anchored) {
        self.by_keyframe
            .entry(a.keyframe)
            .or_default()
            .push(self.anchored.len());
        self.anchored.push(a);
    }

    /// Keyframe `r.keyframe` was culled: the frames kept relative to it are kept relative to
    /// its heir (`T = R·T_k = R·(T_k·T_h⁻¹)·T_h`), so their poses after the run follow the map
    /// as before.
    pub fn reanchor(&mut self, r: &Retired) {
        self.culled += 1;
        let Some(moved) = self.by_keyframe.remove(&r.keyframe) else {
            return;
        };
        for &i in &moved {
            let a = &mut self.anchored[i];
            a.relative = Some(match a.relative {
                None => r.keyframe_from_heir,
                Some(relative) => relative.compose(&r.keyframe_from_heir),
            });
            a.keyframe = r.heir;
        }
        self.by_keyframe.entry(r.heir).or_default().extend(moved);
    }

    /// Records a frame that could not be read: no pose, lost for `reason`.
    pub fn skip(&mut self, index: usize, timestamp: f64, reason: String) {
        let state = TrackingState::Lost(reason);
        self.record.frames.push(FrameRecord {
            index,
            timestamp,
            world_from_camera: None,
            state: state.clone(),
        });
        self.reports.push(FrameReport {
            index,
            state,
            keyframe: None,
            stats: None,
            time: std::time::Duration::ZERO,
            time_tracking: std::time::Duration::ZERO,
            observed: Vec::new(),
        });
    }

    /// Makes the live trajectory hold map `world`, not the first: the frames with a pose (the
    /// first map's) lose it, their state saying why, and the frames tracked in `world` get
    /// theirs. Returns how many frames lost their pose.
    pub fn write_map(&mut self, world: usize) -> usize {
        let mut dropped = 0;
        for (f, r) in self.record.frames.iter_mut().zip(self.reports.iter_mut()) {
            if f.world_from_camera.take().is_some() {
                dropped += 1;
                f.state = TrackingState::Weak(format!(
                    "tracked in the first map, which is not the map written (map {world} holds \
                     more keyframes): no pose in the world"
                ));
                r.state = f.state.clone();
            }
        }
        for o in self.off_world.iter().filter(|o| o.map == world) {
            let f = &mut self.record.frames[o.position];
            f.world_from_camera = Some(world_from_camera(&o.camera_from_world));
            f.state = o.state.clone();
            if let Some(r) = self.reports.get_mut(o.position) {
                r.state = o.state.clone();
            }
        }
        dropped
    }

    /// Every anchored frame's pose after the run: against its keyframe in `graph` (its own
    /// keyframe's pose, or `T_rel·T_k`), then into the world of the maps written (`from_world`:
    /// per map, `x_map = W·x_world`); frames of other maps are left out. `(frame position,
    /// camera_from_world)` in record order.
    pub fn reexpressed<const N: usize>(
        &self,
        graph: &SlamGraph<N>,
        from_world: &std::collections::BTreeMap<usize, Sim3>,
    ) -> Vec<(usize, Se3)> {
        let mut anchored = self.anchored.clone();
        anchored.sort_by_key(|a| a.position);
        anchored
            .iter()
            .filter_map(|a| {
                let t_k = graph.pose(a.keyframe).ok()?;
                let w = from_world.get(&graph.map_of(a.keyframe).ok()?)?;
                let in_map = match a.relative {
                    None => rigid_from_similarity(&t_k),
                    Some(rel) => rigid_from_similarity(&rel.compose(&t_k)),
                };
                Some((a.position, in_world(w, &in_map)))
            })
            .collect()
    }
}

/// A rigid pose in a map, in the world of `W` (`x_map = W·x_world`).
pub(crate) fn in_world(w: &Sim3, camera_from_map: &Se3) -> Se3 {
    if *w == Sim3::identity() {
        return *camera_from_map;
    }
    rigid_from_similarity(&Sim3::from_se3(camera_from_map).compose(w))
}
