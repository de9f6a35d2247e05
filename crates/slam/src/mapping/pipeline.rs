//! The synchronous keyframe pipeline: every stage in order, in one thread.

use super::mapper::{AppearanceMatch, Mapper, MappingError};
use crate::dwo::{DoubleWindowOptimiser, DwoStats};
use crate::factors::InverseDepthCamera;
use crate::loop_closure::{MetricLoopClosure, MetricLoopProblem};
use crate::map::{KeyframeId, PointId, SharedGraph, SlamGraph};
use crate::tracking::{TrackId, tracking_candidates};
use lie::Sim3;
use nalgebra::SVector;
use std::collections::BTreeSet;
use std::time::{Duration, Instant};

/// The front-end's side of the keyframe pipeline: data association for the new keyframe. The
/// live system answers from images (guided patch search, place recognition by bag of words),
/// the simulator from its known world. Called by [`KeyframePipeline::process_keyframe`] in
/// the order of the methods below.
pub trait FrontEnd<const N: usize> {
    /// The new keyframe's measurements of `candidates` (the points visible from `N1` of the
    /// reference keyframe, thesis §6.2.5; empty for the first keyframe).
    fn match_candidates(
        &mut self,
        graph: &SlamGraph<N>,
        candidates: &BTreeSet<PointId>,
    ) -> Vec<(PointId, SVector<f64, N>)>;

    /// The new keyframe's pose when the front-end knows it (the first keyframe; a monocular
    /// bootstrap), instead of tracking it from `matches`.
    fn given_pose(
        &mut self,
        graph: &SlamGraph<N>,
        matches: &[(PointId, SVector<f64, N>)],
    ) -> Option<Sim3>;

    /// For a [`given_pose`](Self::given_pose) tracked before this call (in another thread's
    /// time): the keyframe it was tracked against, that keyframe's pose then, and the graph's
    /// version then. If the keyframe's pose changed since (an optimisation, a map merge), the
    /// pose is rebased onto it before insertion (as [`Mapper::insert_keyframe`] rebases a frame
    /// the mapper tracked). `None` (the default): the given pose is as of the graph now.
    fn given_pose_tracked_against(&self) -> Option<(KeyframeId, Sim3, crate::map::Version)> {
        None
    }

    /// An old keyframe that `keyframe` revisits, found by place recognition (thesis §6.4.2),
    /// with its correspondences.
    fn recognise_place(
        &mut self,
        graph: &SlamGraph<N>,
        keyframe: KeyframeId,
    ) -> Option<AppearanceMatch<N>>;

    /// What the guided search needs of the graph, copied out of it
    /// ([`plan_guided_search`](Self::plan_guided_search)).
    type GuidedSearch;

    /// Guided search (thesis §6.4.1), the part that reads the graph (under its read lock in
    /// the live system): what searching the `predictions` (points and their predicted
    /// measurements) in `keyframe` needs.
    fn plan_guided_search(
        &mut self,
        graph: &SlamGraph<N>,
        keyframe: KeyframeId,
        predictions: &[(PointId, SVector<f64, N>)],
    ) -> Self::GuidedSearch;

    /// Guided search, the part that needs no graph (no lock held): the measurements of the
    /// planned points in the keyframe, in the order they are to be used.
    fn guided_search(&mut self, plan: Self::GuidedSearch) -> Vec<(PointId, SVector<f64, N>)>;

    /// Whether the keyframe is the first of a new map (`SlamGraph::start_map`), started under
    /// the write lock that inserts it, so that no other thread sees the new map without it.
    fn new_map(&self) -> bool {
        false
    }

    /// Every measurement of `keyframe` with its track and whether it is now associated with a
    /// point `keyframe` observes (the others may become new points).
    fn measurements(
        &mut self,
        graph: &SlamGraph<N>,
        keyframe: KeyframeId,
    ) -> Vec<(TrackId, SVector<f64, N>, bool)>;

    /// The points made for tracks by [`Mapper::add_points`], in creation order.
    fn points_created(&mut self, created: &[(TrackId, PointId)]);
}

/// What the pipeline did with one keyframe.
#[derive(Clone, Debug, PartialEq)]
pub struct KeyframeReport {
    /// The new keyframe.
    pub keyframe: KeyframeId,
    /// Map points it was tracked against.
    pub tracked: usize,
    /// The keyframe an appearance loop closure joined it to.
    pub appearance_loop: Option<KeyframeId>,
    /// The metric loop closures.
    pub metric_loops: Vec<MetricLoopClosure>,
    /// Points created.
    pub new_points: usize,
    /// Time of the stages before the optimisation (with the front-end's association).
    pub time_frontend: Duration,
    /// Time of each stage (with the front-end's association for it), in order.
    pub stage_times: Vec<(&'static str, Duration)>,
    /// The optimisation (none for the first keyframe).
    pub optimisation: Option<DwoStats>,
}

/// The keyframe pipeline in its synchronous mode: the stages of [`Mapper`] and double window
/// optimisation, in order, in the calling thread (deterministic: the same input gives the
/// same output).
#[derive(Clone, Debug)]
pub struct KeyframePipeline<C, const N: usize> {
    /// The stages.
    pub mapper: Mapper<C, N>,
    /// The optimiser.
    pub optimiser: DoubleWindowOptimiser,
}

impl<C: InverseDepthCamera<N>, const N: usize> KeyframePipeline<C, N> {
    /// A pipeline of `mapper`'s stages and `optimiser`.
    pub fn new(mapper: Mapper<C, N>, optimiser: DoubleWindowOptimiser) -> Self {
        KeyframePipeline { mapper, optimiser }
    }

    /// One keyframe through every stage: track, insert, appearance loop, metric loop, new
    /// points ([`Mapper::map_keyframe`]), and (from the second keyframe on) double window
    /// optimisation.
    pub fn process_keyframe(
        &mut self,
        graph: &mut SlamGraph<N>,
        front_end: &mut impl FrontEnd<N>,
    ) -> Result<KeyframeReport, MappingError> {
        // The stages take the graph's locks as a thread does; here nobody else holds it.
        let shared = SharedGraph::new(std::mem::take(graph));
        let report = self.mapper.map_keyframe(&shared, front_end);
        *graph = shared.into_inner();
        let mut report = report?;
        // A window needs two keyframes: alone, the first one's points have nothing to be
        // adjusted against.
        if graph.num_keyframes() >= 2 {
            report.optimisation = Some(self.optimiser.optimise(graph, self.mapper.camera())?);
        }
        Ok(report)
    }
}

impl<C: InverseDepthCamera<N>, const N: usize> Mapper<C, N> {
    /// Every stage of the keyframe pipeline but the optimisation, in order: track, insert,
    /// appearance loop, metric loop, new points ([`KeyframePipeline::process_keyframe`] adds
    /// the optimisation; the live system's optimiser runs in its own thread).
    ///
    /// Each stage holds the lock it needs of the shared `graph` for as short as it can (thesis
    /// §6.5.2: the other threads — the optimiser, the loop closer — are never held up by a
    /// search or a solve): the motion-only BA of tracking is prepared under the read lock and
    /// solved with none, the keyframe inserted under a short write lock (rebased if its
    /// reference moved meanwhile); metric loop closure's guided search is planned under the
    /// read lock and run with none, its pose fit set up under the read lock, solved with none
    /// and written (with the poses it was planned on: its edges are relative) under a short
    /// write lock, with the new points.
    pub fn map_keyframe(
        &mut self,
        graph: &SharedGraph<N>,
        front_end: &mut impl FrontEnd<N>,
    ) -> Result<KeyframeReport, MappingError> {
        let start = Instant::now();
        let mut stage_times = Vec::with_capacity(5);
        let mut lap = Instant::now();
        let mut stage = |name: &'static str, times: &mut Vec<(&'static str, Duration)>| {
            times.push((name, lap.elapsed()));
            lap = Instant::now();
        };
        let (keyframe, tracked) = self.track_and_insert(graph, front_end)?;
        stage("keyframe: track", &mut stage_times);
        stage("keyframe: insert and register", &mut stage_times);
        let appearance_loop = self.recognised_loop(graph, front_end, keyframe)?;
        stage("keyframe: appearance loop", &mut stage_times);
        let plan = {
            let g = graph.read();
            let predictions = self.loop_predictions(&g, keyframe)?;
            front_end.plan_guided_search(&g, keyframe, &predictions)
        };
        let found = front_end.guided_search(plan);
        let problem = MetricLoopProblem::from_graph(&graph.read(), keyframe, &found)?;
        let fit = match problem {
            Some(problem) => Some(problem.solve(self.camera(), &self.metric_loop_params())?),
            None => None,
        };
        let mut g = graph.write();
        let metric_loops = match fit {
            Some(fit) => fit.apply(&mut g)?,
            None => Vec::new(),
        };
        stage("keyframe: metric loop", &mut stage_times);
        let measurements = front_end.measurements(&g, keyframe);
        let created = self.add_points(&mut g, keyframe, &measurements)?;
        drop(g);
        front_end.points_created(&created);
        stage("keyframe: new points", &mut stage_times);
        Ok(KeyframeReport {
            keyframe,
            tracked,
            appearance_loop,
            metric_loops,
            new_points: created.len(),
            time_frontend: start.elapsed(),
            stage_times,
            optimisation: None,
        })
    }

    /// Tracking and insertion: the keyframe made and how many matches it was tracked with. A
    /// given pose (no solve) of a new map is tracked and inserted under one write lock with
    /// the new map's start; otherwise prepared under the read lock, solved with none, and
    /// inserted under a short write lock.
    fn track_and_insert(
        &mut self,
        graph: &SharedGraph<N>,
        front_end: &mut impl FrontEnd<N>,
    ) -> Result<(KeyframeId, usize), MappingError> {
        if front_end.new_map() {
            let mut g = graph.write();
            g.start_map();
            let (prepared, tracked, given) = self.prepare(&g, front_end)?;
            let frame = prepared.solve(self.camera(), &self.config().tracking)?;
            return Ok((self.insert(&mut g, front_end, frame, given)?, tracked));
        }
        let (prepared, tracked, given) = self.prepare(&graph.read(), front_end)?;
        let frame = prepared.solve(self.camera(), &self.config().tracking)?;
        Ok((
            self.insert(&mut graph.write(), front_end, frame, given)?,
            tracked,
        ))
    }

    /// Inserts the tracked `frame`: a given pose tracked against a keyframe that moved since
    /// (another thread) is rebased onto it first (as `insert_keyframe` rebases a frame tracked
    /// here); the keyframe's edges are made as for any given pose.
    fn insert(
        &mut self,
        graph: &mut SlamGraph<N>,
        front_end: &mut impl FrontEnd<N>,
        mut frame: super::mapper::TrackedFrame<N>,
        given: bool,
    ) -> Result<KeyframeId, MappingError> {
        if given && let Some((reference, then, version)) = front_end.given_pose_tracked_against() {
            frame.camera_from_world =
                super::mapper::rebased(graph, frame.camera_from_world, reference, &then, version);
        }
        Ok(self.insert_keyframe(graph, frame)?.0)
    }

    /// The front-end's matches and pose of the new keyframe, its tracking prepared: with the
    /// number of matches and whether the pose was given.
    fn prepare(
        &self,
        graph: &SlamGraph<N>,
        front_end: &mut impl FrontEnd<N>,
    ) -> Result<(super::mapper::PreparedFrame<N>, usize, bool), MappingError> {
        let candidates = graph
            .reference()
            .map(|r| tracking_candidates(graph, r))
            .unwrap_or_default();
        let matches = front_end.match_candidates(graph, &candidates);
        let given = front_end.given_pose(graph, &matches);
        let tracked = matches.len();
        Ok((
            self.prepare_track(graph, matches, given)?,
            tracked,
            given.is_some(),
        ))
    }

    /// An appearance loop the front-end recognises for `keyframe` (the simulator's; the live
    /// system's loop closer runs in its own thread): planned under the read lock, fitted with
    /// none, written under a short write lock.
    fn recognised_loop(
        &self,
        graph: &SharedGraph<N>,
        front_end: &mut impl FrontEnd<N>,
        keyframe: KeyframeId,
    ) -> Result<Option<KeyframeId>, MappingError> {
        let place = front_end.recognise_place(&graph.read(), keyframe);
        let Some(place) = place else {
            return Ok(None);
        };
        let plan = self.plan_appearance_loop(&graph.read(), keyframe, &place)?;
        Ok(match self.fit_appearance_loop(plan) {
            Some(fit) => self
                .apply_appearance_loop(&mut graph.write(), &fit)?
                .closed(),
            None => None,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mapping::MappingConfig;
    use geom::{PinholeCamera, StereoCamera};
    use lie::{LieGroup, Se3, So3};
    use nalgebra::Vector3;

    /// The keyframe `mapper` makes in `graph` at `pose` tracked against `against` (a [`Given`]
    /// front-end), through the stages of the shared graph.
    fn map(
        mapper: &mut Mapper<StereoCamera, 3>,
        graph: &mut SlamGraph<3>,
        pose: Sim3,
        against: Option<(KeyframeId, Sim3, crate::map::Version)>,
    ) -> KeyframeId {
        let shared = SharedGraph::new(std::mem::take(graph));
        let report = mapper.map_keyframe(&shared, &mut Given { pose, against });
        *graph = shared.into_inner();
        report.unwrap().keyframe
    }

    /// A front-end that gives the pose (tracked against `against` in another thread's time)
    /// and nothing else.
    struct Given {
        pose: Sim3,
        against: Option<(KeyframeId, Sim3, crate::map::Version)>,
    }

    impl FrontEnd<3> for Given {
        fn match_candidates(
            &mut self,
            _: &SlamGraph<3>,
            _: &BTreeSet<PointId>,
        ) -> Vec<(PointId, SVector<f64, 3>)> {
            Vec::new()
        }
        fn given_pose(
            &mut self,
            _: &SlamGraph<3>,
            _: &[(PointId, SVector<f64, 3>)],
        ) -> Option<Sim3> {
            Some(self.pose)
        }
        fn given_pose_tracked_against(&self) -> Option<(KeyframeId, Sim3, crate::map::Version)> {
            self.against
        }
        fn recognise_place(
            &mut self,
            _: &SlamGraph<3>,
            _: KeyframeId,
        ) -> Option<AppearanceMatch<3>> {
            None
        }
        type GuidedSearch = ();
        fn plan_guided_search(
            &mut self,
            _: &SlamGraph<3>,
            _: KeyframeId,
            _: &[(PointId, SVector<f64, 3>)],
        ) {
        }
        fn guided_search(&mut self, _: ()) -> Vec<(PointId, SVector<f64, 3>)> {
            Vec::new()
        }
        fn measurements(
            &mut self,
            _: &SlamGraph<3>,
            _: KeyframeId,
        ) -> Vec<(TrackId, SVector<f64, 3>, bool)> {
            Vec::new()
        }
        fn points_created(&mut self, _: &[(TrackId, PointId)]) {}
    }

    /// A pose tracked against a keyframe that another thread then moved (here by a map merge
    /// of 5 m) keeps its pose relative to that keyframe; one tracked against the graph as it
    /// is is inserted as given.
    #[test]
    fn a_given_pose_tracked_before_its_reference_moved_is_rebased() {
        let camera = StereoCamera::new(PinholeCamera::new(300.0, 300.0, 320.0, 240.0), 0.1);
        let mut mapper = Mapper::new(camera, MappingConfig::new(1.0, (640.0, 480.0), 3));
        let mut g = SlamGraph::<3>::new();
        let pose = |x: f64, yaw: f64| {
            Sim3::from_se3(&Se3::new(So3::rot_y(yaw), Vector3::new(x, 0.0, 0.0)))
        };
        let first = map(&mut mapper, &mut g, Sim3::identity(), None);
        let (then, version) = (g.pose(first).unwrap(), g.version());
        let tracked = pose(0.3, 0.1);
        // Unmoved: inserted as given.
        let k = map(&mut mapper, &mut g, tracked, Some((first, then, version)));
        assert!((g.pose(k).unwrap().log() - tracked.log()).norm() < 1e-12);
        // Moved meanwhile: `first`'s map merged into an older one, 5 m away.
        let mut h = SlamGraph::<3>::new();
        let old = h.add_keyframe(Sim3::identity());
        h.start_map();
        let first = h.add_keyframe(Sim3::identity());
        h.set_reference(first).unwrap();
        let (then, version) = (h.pose(first).unwrap(), h.version());
        let target = pose(5.0, 0.4);
        h.merge_map(first, &target, old).unwrap();
        let k = map(&mut mapper, &mut h, tracked, Some((first, then, version)));
        let relative = h
            .pose(k)
            .unwrap()
            .compose(&h.pose(first).unwrap().inverse());
        let expected = tracked.compose(&then.inverse());
        assert!(
            (relative.log() - expected.log()).norm() < 1e-12,
            "the pose relative to its reference kept"
        );
        assert!(
            (h.pose(k).unwrap().log() - tracked.log()).norm() > 1.0,
            "moved with the map"
        );
    }

    /// A keyframe given after the camera was lost goes into the new map joined to no keyframe
    /// of the old one: the graph has no reference after `start_map`, so the keyframe is not
    /// registered to the old reference by an edge that would measure the guessed offset
    /// between the two maps' frames (and pull the new map back there once a loop merges it).
    #[test]
    fn the_first_keyframe_of_a_new_map_has_no_edge_to_the_old_map() {
        let camera = StereoCamera::new(PinholeCamera::new(300.0, 300.0, 320.0, 240.0), 0.1);
        let mut mapper = Mapper::new(camera, MappingConfig::new(1.0, (640.0, 480.0), 3));
        let mut g = SlamGraph::<3>::new();
        let mut given = |g: &mut SlamGraph<3>, x: f64| {
            let pose = Sim3::from_se3(&Se3::new(So3::identity(), Vector3::new(x, 0.0, 0.0)));
            map(&mut mapper, g, pose, None)
        };
        let a = given(&mut g, 0.0);
        let b = given(&mut g, 0.2);
        // In one map, a keyframe without shared points is registered to the reference.
        assert!(g.keyframe(b).unwrap().edges().contains_key(&a));
        assert_eq!(g.start_map(), 1);
        assert_eq!(g.reference(), None);
        let c = given(&mut g, 3.0);
        assert_eq!(g.map_of(c).unwrap(), 1);
        assert!(g.keyframe(c).unwrap().edges().is_empty());
        assert!(!g.keyframe(b).unwrap().edges().contains_key(&c));
        assert_eq!(g.reference(), Some(c));
        let d = given(&mut g, 3.2);
        assert_eq!(g.map_of(d).unwrap(), 1);
        assert!(g.keyframe(d).unwrap().edges().contains_key(&c));
    }
}
