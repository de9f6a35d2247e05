//! Large-scale loop closure of the live system (thesis §6.4.2, the third thread of §6.5.2).
//!
//! Each new keyframe is handed to the loop closer, which
//!
//! 1. describes it for place recognition (ORB words and the 3D point of each keypoint with a
//!    depth) and adds it to the database;
//! 2. asks the database for a revisit among the keyframes that are **not** topologically close
//!    (thesis: never between topologically close keyframes, where local registration and
//!    metric loop closure join the graph): those within [`LoopConfig::exclusion_hops`] edges of
//!    the keyframe graph and the last [`LoopConfig::exclusion_recent`] keyframes
//!    ([`recent_keyframes`]); the database verifies the best hypotheses by a 3-point RANSAC in
//!    SE(3) (eq. 6.9) and guided ORB matching;
//! 3. **guided matching into the map**: the map points of the old place (the old keyframe's and
//!    its covisible neighbours') are projected into the new keyframe at the pose the verified
//!    loop implies, `T_new = T_new,old·T_old`, and searched there by the same patch search as
//!    metric loop closure ([`GuidedSearch`]);
//! 4. closes the loop through the graph (`slam::mapping::Mapper::close_appearance_loop`: the
//!    found old points become observations of the new keyframe, the edge `E_old,new` is added
//!    with the pose the matches give as its measurement), under a short write lock — unless the
//!    loop moves the new keyframe by more than the odometry's drift since the old place
//!    explains (`slam::loop_closure::LoopDrift`; such loops are kept in
//!    [`LoopCloser::refused`]). The double
//!    window optimisation then corrects the poses; in the threaded system the loop closer
//!    wakes it.
//!
//! The same [`LoopCloser::process`] runs in the loop-closure thread ([`crate::Mode::Threaded`],
//! a stage of the session's back-end, `crate::session::backend`) and inline after each
//! keyframe (deterministic mode).

use crate::association::{GuidedSearch, search_points};
use crate::config::SystemConfig;
use crate::frame::{FrameData, SensorFrontEnd};
use crate::keyframes::KeyframeStore;
use crate::place_recognition::{
    LoopCandidate, PlaceRecognition, PlaceRecognitionConfig, PlaceRecognitionError, features,
};
pub use crate::result::LoopEvidence;
use crate::search::SearchScratch;
use geom::StereoCamera;
use lie::LieGroup;
use slam::loop_closure::LoopDrift;
use slam::map::shared::{read_lock, write_lock};
use slam::map::{KeyframeId, PointId, SharedGraph, SlamGraph};
use slam::mapping::{AppearanceClosure, AppearanceMatch, Mapper, MappingConfig, MappingError};
use std::collections::BTreeSet;
use std::sync::mpsc::SyncSender;
use std::sync::{Arc, RwLock};
use std::time::{Duration, Instant};
use vision::bow::Vocabulary;

/// One keyframe for the loop closer.
#[derive(Clone, Debug)]
pub struct LoopJob {
    /// The keyframe.
    pub keyframe: KeyframeId,
    /// The frame it was made from (its image, corners and depth).
    pub frame: Arc<FrameData>,
}

/// An appearance-based loop the closer closed.
#[derive(Clone, Debug, PartialEq)]
pub struct AppearanceLoop {
    /// The new keyframe.
    pub keyframe: KeyframeId,
    /// The old keyframe it sees the place of.
    pub old: KeyframeId,
    /// What it rests on: the RANSAC inliers of the ORB matches, and the old map points the
    /// guided matching found in the new keyframe of those predicted visible there.
    pub evidence: LoopEvidence,
    /// The correction the loop made to the new keyframe, against the path since the old one.
    pub drift: Option<LoopDrift>,
    /// The loop joined two maps (the new keyframe's, started after a loss, moved onto the
    /// old one's): the keyframes moved and how far the new keyframe moved (metres).
    pub merged: Option<(usize, f64)>,
}

/// Why the loop closer failed (a keyframe without a loop is not a failure).
#[derive(Debug, thiserror::Error)]
pub enum LoopError {
    /// Place recognition refused the keyframe.
    #[error(transparent)]
    PlaceRecognition(#[from] PlaceRecognitionError),
    /// The graph refused the loop.
    #[error("closing an appearance loop: {0}")]
    Mapping(#[from] MappingError),
}

/// The loop closer: the place-recognition database and the stages that close a loop.
pub struct LoopCloser {
    /// The database, shared with the tracking thread's relocalisation (read-locked there and
    /// while a loop is detected; write-locked only to insert a keyframe's features).
    recogniser: Arc<RwLock<PlaceRecognition>>,
    /// Its configuration (to extract features outside the lock).
    place: PlaceRecognitionConfig,
    mapper: Mapper<StereoCamera, 3>,
    sensor: SensorFrontEnd,
    exclusion_hops: usize,
    exclusion_recent: usize,
    radius: f64,
    min_ncc: f32,
    max_view_angle: f64,
    scratch: SearchScratch,
    /// The keyframes' images (templates of the guided matching, the keyframes' frames).
    store: Arc<RwLock<KeyframeStore>>,
    /// Wakes the optimiser's thread after a loop is closed (threaded: the optimisation
    /// corrects the poses; inline the optimisation follows anyway).
    wake: Option<SyncSender<(u64, ())>>,
    /// Time of each stage of the job in hand.
    timings: Vec<(&'static str, Duration)>,
    /// Loops verified by appearance but refused for the correction they needed: (new
    /// keyframe, old keyframe, the correction against the path), of the job in hand.
    refused: Vec<(KeyframeId, KeyframeId, LoopDrift)>,
}

impl LoopCloser {
    /// A loop closer with `vocabulary` for the sensor `sensor` and the system's `config`;
    /// `mapping` are the keyframe pipeline's parameters (the loop needs as many matches as a
    /// loop of the pipeline); `store` holds the keyframes' images.
    pub fn new(
        vocabulary: Arc<Vocabulary>,
        sensor: SensorFrontEnd,
        config: &SystemConfig,
        mapping: MappingConfig,
        store: Arc<RwLock<KeyframeStore>>,
    ) -> Result<Self, PlaceRecognitionError> {
        let place =
            config.place_recognition_for(Some((sensor.camera(), sensor.measures_disparity())));
        Ok(LoopCloser {
            recogniser: Arc::new(RwLock::new(PlaceRecognition::new(
                vocabulary,
                place.clone(),
            )?)),
            place,
            mapper: Mapper::new(*sensor.camera(), mapping),
            sensor,
            exclusion_hops: config.loops.exclusion_hops,
            exclusion_recent: config.loops.exclusion_recent,
            radius: config.mapping.loop_search_radius,
            min_ncc: config.tracker.min_ncc,
            max_view_angle: config.tracker.max_view_angle_deg.to_radians(),
            scratch: SearchScratch::default(),
            store,
            wake: None,
            timings: Vec::new(),
            refused: Vec::new(),
        })
    }

    /// The same closer on the same database (a closer lost with its thread made again).
    pub fn again(&self) -> Self {
        LoopCloser {
            recogniser: self.recogniser.clone(),
            place: self.place.clone(),
            mapper: self.mapper.clone(),
            sensor: self.sensor.clone(),
            exclusion_hops: self.exclusion_hops,
            exclusion_recent: self.exclusion_recent,
            radius: self.radius,
            min_ncc: self.min_ncc,
            max_view_angle: self.max_view_angle,
            scratch: SearchScratch::default(),
            store: self.store.clone(),
            wake: self.wake.clone(),
            timings: Vec::new(),
            refused: Vec::new(),
        }
    }

    /// Wakes the optimiser's thread through `wake` after each loop closed.
    pub fn waking(mut self, wake: Option<SyncSender<(u64, ())>>) -> Self {
        self.wake = wake;
        self
    }

    /// The place-recognition database (shared: see [`LoopCloser::shared_database`]).
    fn database(&self) -> std::sync::RwLockReadGuard<'_, PlaceRecognition> {
        read_lock(&self.recogniser)
    }

    /// The database, for relocalising lost frames from another thread
    /// ([`PlaceRecognition::relocalise`]), with its configuration.
    pub fn shared_database(&self) -> (Arc<RwLock<PlaceRecognition>>, PlaceRecognitionConfig) {
        (self.recogniser.clone(), self.place.clone())
    }

    /// Adds `job`'s keyframe to the database and closes its loop, if it has one (see the
    /// [module docs](self)). Holds the graph's read lock to plan and match, its write lock
    /// only to insert the loop.
    pub fn process(
        &mut self,
        graph: &SharedGraph<3>,
        store: &RwLock<KeyframeStore>,
        job: &LoopJob,
    ) -> Result<Option<AppearanceLoop>, LoopError> {
        let t = Instant::now();
        let frame = &job.frame;
        let edge_ratio = self.place.depth_edge_ratio;
        let depth = |u, v| frame.keypoint_depth(u, v, edge_ratio);
        let features = features::extract(
            frame.gray(),
            depth,
            Vec::new(),
            self.sensor.pinhole(),
            &self.place,
        )?;
        write_lock(&self.recogniser).insert(job.keyframe, features)?;
        self.timings.push(("loop: ORB features", t.elapsed()));
        let t = Instant::now();
        let excluded = {
            let g = graph.read();
            if g.keyframe(job.keyframe).is_none() {
                return Ok(None);
            }
            let mut close = topological_neighbourhood(&g, job.keyframe, self.exclusion_hops);
            close.extend(recent_keyframes(job.keyframe, self.exclusion_recent));
            close
        };
        let candidate = self.database().detect(job.keyframe, &excluded)?;
        self.timings.push(("loop: detect and verify", t.elapsed()));
        let Some(candidate) = candidate else {
            return Ok(None);
        };
        let t = Instant::now();
        let place = {
            // What the search needs, copied under the graph's read lock, and the keyframes'
            // images (shared, cheap to copy) under the store's; the search with neither held
            // (the tracking thread writes the store at every keyframe).
            let planned = self.plan_map_matches(&graph.read(), job, &candidate);
            let store = read_lock(store).clone();
            planned.map(|plan| self.map_matches(&store, job, &candidate, plan))
        };
        self.timings.push(("loop: guided matching", t.elapsed()));
        let Some((place, map_predicted)) = place else {
            return Ok(None);
        };
        let t = Instant::now();
        let evidence = LoopEvidence {
            ransac_inliers: candidate.ransac_inliers,
            old_points_found: place.correspondences.len(),
            old_points_predicted: map_predicted,
        };
        // Planned under a read lock, fitted with none, written under a short write lock (the
        // loop's measurement is relative: the graph may move in between).
        let plan = self
            .mapper
            .plan_appearance_loop(&graph.read(), job.keyframe, &place)?;
        let closure = match self.mapper.fit_appearance_loop(plan) {
            Some(fit) => self
                .mapper
                .apply_appearance_loop(&mut graph.write(), &fit)?,
            None => AppearanceClosure::TooFewMatches,
        };
        self.timings.push(("loop: close", t.elapsed()));
        Ok(match closure {
            AppearanceClosure::Closed { old, drift } => Some(AppearanceLoop {
                keyframe: job.keyframe,
                old,
                evidence,
                drift,
                merged: None,
            }),
            AppearanceClosure::Merged {
                old,
                keyframes,
                displacement,
            } => Some(AppearanceLoop {
                keyframe: job.keyframe,
                old,
                evidence,
                drift: None,
                merged: Some((keyframes, displacement)),
            }),
            AppearanceClosure::TooMuchDrift(drift) => {
                self.refused.push((job.keyframe, candidate.old, drift));
                None
            }
            AppearanceClosure::TooFewMatches => None,
        })
    }

    /// What the guided matching of the old place needs of the graph: the pose the loop
    /// implies, the old place's map points the new keyframe does not observe, and the new
    /// keyframe's observations.
    fn plan_map_matches(
        &self,
        graph: &SlamGraph<3>,
        job: &LoopJob,
        candidate: &LoopCandidate,
    ) -> Option<MatchPlan> {
        let old_pose = graph.pose(candidate.old).ok()?;
        let implied = candidate.query_from_old.compose(&old_pose).rigid_part();
        let own = graph.keyframe(job.keyframe)?.observations().clone();
        let mut place: Vec<KeyframeId> = graph.n1(candidate.old);
        place.push(candidate.old);
        let points = search_points(
            graph,
            graph
                .points_visible_from(&place)
                .into_iter()
                .filter(|p| !own.contains_key(p)),
        );
        Some(MatchPlan {
            implied,
            points,
            own,
        })
    }

    /// The old place's map points found in the new keyframe at the pose the loop implies,
    /// and how many were predicted visible there.
    fn map_matches(
        &mut self,
        store: &KeyframeStore,
        job: &LoopJob,
        candidate: &LoopCandidate,
        plan: MatchPlan,
    ) -> (AppearanceMatch<3>, usize) {
        let MatchPlan {
            implied,
            points,
            own,
        } = plan;
        let (found, predicted) = GuidedSearch {
            frame: &job.frame,
            store,
            sensor: &self.sensor,
            radius: self.radius,
            min_ncc: self.min_ncc,
            max_view_angle: self.max_view_angle,
            min_disparity: self.mapper.config().min_disparity,
        }
        .run_counted(&implied, &points, &mut self.scratch);
        // The new keyframe's own point at a found pixel, if it has one there (then its
        // position, not the measurement's depth, enters the alignment).
        let same_pixel = 1.5f64;
        let correspondences = found
            .into_iter()
            .map(|(p, z)| {
                let here = own
                    .iter()
                    .find(|(_, o)| (o.x - z.x).hypot(o.y - z.y) < same_pixel)
                    .map(|(q, _)| *q);
                (p, z, here)
            })
            .collect();
        (
            AppearanceMatch {
                old: candidate.old,
                correspondences,
            },
            predicted,
        )
    }
}

impl crate::session::backend::Stage<3> for LoopCloser {
    type Job = LoopJob;
    type Output = crate::session::LoopOutput<()>;

    /// [`LoopCloser::process`]: the loop it closed (with the frames of its keyframes), the
    /// loops it refused, the failure as a warning, the time of each stage.
    fn run(&mut self, graph: &SharedGraph<3>, job: &LoopJob, out: &mut Vec<Self::Output>) {
        use crate::result::{LoopEvent, RefusedLoop};
        use crate::session::LoopOutput;
        let store = self.store.clone();
        let result = self.process(graph, &store, job);
        let frames = |a: KeyframeId, b: KeyframeId| {
            let store = read_lock(&store);
            let frame_of = |k: KeyframeId| store.get(k).map_or(usize::MAX, |i| i.frame_index);
            (frame_of(a), frame_of(b))
        };
        match result {
            Ok(Some(event)) => {
                out.push(LoopOutput::Loop(LoopEvent {
                    keyframe: event.keyframe,
                    old: event.old,
                    frames: frames(event.keyframe, event.old),
                    kind: if event.merged.is_some() {
                        "merge"
                    } else {
                        "appearance"
                    },
                    scale: None,
                    scale_sigma: None,
                    agreeing: None,
                    correction: event.drift,
                    evidence: Some(event.evidence),
                }));
                // The optimisation corrects the poses; a pending wake-up will see the loop
                // too.
                if let Some(wake) = &self.wake {
                    let _ = wake.try_send((u64::MAX, ()));
                }
            }
            Ok(None) => {}
            Err(e) => out.push(LoopOutput::Warning(format!(
                "loop closure at {}: {e}",
                job.keyframe
            ))),
        }
        let limits = self.mapper.config().appearance_max_drift;
        for (k, old, drift) in self.refused.drain(..) {
            out.push(LoopOutput::Refused(RefusedLoop {
                frames: frames(k, old),
                drift,
                allowed: Some(drift.allowed(&limits)),
                reason: "needs more correction than loops.max_drift_of_path and \
                         loops.max_drift_of_scene_depth allow"
                    .into(),
            }));
        }
        out.extend(
            self.timings
                .drain(..)
                .map(|(stage, d)| LoopOutput::Timing(stage, d)),
        );
    }
}

/// The guided matching of an appearance loop, planned ([`LoopCloser`]'s `plan_map_matches`).
struct MatchPlan {
    implied: lie::Se3,
    points: Vec<crate::search::SearchPoint>,
    own: std::collections::BTreeMap<PointId, nalgebra::Vector3<f64>>,
}

/// `k` and the `n` keyframes made just before it (keyframe ids count up in the order the
/// keyframes are made): topologically close through the tracker's chain.
pub fn recent_keyframes(k: KeyframeId, n: usize) -> impl Iterator<Item = KeyframeId> {
    (k.index().saturating_sub(n)..=k.index()).map(KeyframeId::from_index)
}

/// The keyframes within `hops` edges of `root` in the keyframe graph (root included): the
/// topological neighbourhood appearance-based loops never join.
pub fn topological_neighbourhood<const N: usize>(
    graph: &SlamGraph<N>,
    root: KeyframeId,
    hops: usize,
) -> BTreeSet<KeyframeId> {
    within_hops(root, hops, |k| {
        graph
            .keyframe(k)
            .map(|kf| kf.edges().keys().copied().collect())
            .unwrap_or_default()
    })
}

/// The keyframes within `hops` steps of `root` (root included), a step from `k` leading to each
/// of `neighbours(k)`.
pub(crate) fn within_hops(
    root: KeyframeId,
    hops: usize,
    neighbours: impl Fn(KeyframeId) -> Vec<KeyframeId>,
) -> BTreeSet<KeyframeId> {
    let mut seen = BTreeSet::from([root]);
    let mut frontier = vec![root];
    for _ in 0..hops {
        let mut next = Vec::new();
        for k in frontier {
            for n in neighbours(k) {
                if seen.insert(n) {
                    next.push(n);
                }
            }
        }
        frontier = next;
    }
    seen
}

#[cfg(test)]
mod tests {
    use super::*;
    use lie::Sim3;

    #[test]
    fn the_neighbourhood_follows_edges_for_the_given_hops() {
        let mut g = SlamGraph::<3>::new();
        let k: Vec<KeyframeId> = (0..6).map(|_| g.add_keyframe(Sim3::identity())).collect();
        // A chain 0-1-2-3-4 and a loop edge 4-0; keyframe 5 is alone.
        for w in k[..5].windows(2) {
            g.add_edge(w[0], w[1], None).unwrap();
        }
        g.add_edge(k[4], k[0], None).unwrap();
        let n = |root: usize, hops| {
            topological_neighbourhood(&g, k[root], hops)
                .into_iter()
                .map(|x| x.index())
                .collect::<Vec<_>>()
        };
        assert_eq!(n(2, 0), vec![2]);
        assert_eq!(n(2, 1), vec![1, 2, 3]);
        assert_eq!(n(2, 2), vec![0, 1, 2, 3, 4]);
        assert_eq!(n(0, 1), vec![0, 1, 4]);
        assert_eq!(n(5, 3), vec![5]);
        let recent = |k: usize, n| {
            recent_keyframes(KeyframeId::from_index(k), n)
                .map(|x| x.index())
                .collect::<Vec<_>>()
        };
        assert_eq!(recent(12, 3), vec![9, 10, 11, 12]);
        assert_eq!(recent(1, 3), vec![0, 1]);
    }
}
