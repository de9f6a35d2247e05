//! The synchronous keyframe pipeline: every stage in order, in one thread.

use super::mapper::{AppearanceMatch, Mapper, MappingError};
use crate::dwo::{DoubleWindowOptimiser, DwoStats};
use crate::factors::InverseDepthCamera;
use crate::loop_closure::MetricLoopClosure;
use crate::map::{KeyframeId, PointId, SlamGraph};
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

    /// Guided search (thesis §6.4.1): the measurements in `keyframe` of the `predictions`
    /// (points and their predicted measurements), in the order they are to be used.
    fn guided_search(
        &mut self,
        graph: &SlamGraph<N>,
        keyframe: KeyframeId,
        predictions: &[(PointId, SVector<f64, N>)],
    ) -> Vec<(PointId, SVector<f64, N>)>;

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
        let mut report = self.mapper.map_keyframe(graph, front_end)?;
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
    pub fn map_keyframe(
        &mut self,
        graph: &mut SlamGraph<N>,
        front_end: &mut impl FrontEnd<N>,
    ) -> Result<KeyframeReport, MappingError> {
        let start = Instant::now();
        let mut stage_times = Vec::with_capacity(5);
        let mut lap = Instant::now();
        let mut stage = |name: &'static str, times: &mut Vec<(&'static str, Duration)>| {
            times.push((name, lap.elapsed()));
            lap = Instant::now();
        };
        let candidates = graph
            .reference()
            .map(|r| tracking_candidates(graph, r))
            .unwrap_or_default();
        let matches = front_end.match_candidates(graph, &candidates);
        let given = front_end.given_pose(graph, &matches);
        let tracked = matches.len();
        let mut frame = self.track(graph, matches, given)?;
        // A given pose tracked against a keyframe that moved since (another thread): rebased
        // onto it (as `insert_keyframe` rebases a frame tracked here). The keyframe's edges are
        // made as for any given pose.
        if given.is_some()
            && let Some((reference, then, version)) = front_end.given_pose_tracked_against()
        {
            frame.camera_from_world =
                super::mapper::rebased(graph, frame.camera_from_world, reference, &then, version);
        }
        stage("keyframe: track", &mut stage_times);
        let (keyframe, _) = self.insert_keyframe(graph, frame)?;
        stage("keyframe: insert and register", &mut stage_times);
        let appearance_loop = match front_end.recognise_place(graph, keyframe) {
            Some(place) => self
                .close_appearance_loop(graph, keyframe, &place)?
                .closed(),
            None => None,
        };
        stage("keyframe: appearance loop", &mut stage_times);
        let predictions = self.loop_predictions(graph, keyframe)?;
        let found = front_end.guided_search(graph, keyframe, &predictions);
        let metric_loops = self.close_metric_loops(graph, keyframe, &found)?;
        stage("keyframe: metric loop", &mut stage_times);
        let measurements = front_end.measurements(graph, keyframe);
        let created = self.add_points(graph, keyframe, &measurements)?;
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
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mapping::MappingConfig;
    use geom::{PinholeCamera, StereoCamera};
    use lie::{LieGroup, Se3, So3};
    use nalgebra::Vector3;

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
        fn guided_search(
            &mut self,
            _: &SlamGraph<3>,
            _: KeyframeId,
            _: &[(PointId, SVector<f64, 3>)],
        ) -> Vec<(PointId, SVector<f64, 3>)> {
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
        let first = mapper
            .map_keyframe(
                &mut g,
                &mut Given {
                    pose: Sim3::identity(),
                    against: None,
                },
            )
            .unwrap()
            .keyframe;
        let (then, version) = (g.pose(first).unwrap(), g.version());
        let tracked = pose(0.3, 0.1);
        // Unmoved: inserted as given.
        let k = mapper
            .map_keyframe(
                &mut g,
                &mut Given {
                    pose: tracked,
                    against: Some((first, then, version)),
                },
            )
            .unwrap()
            .keyframe;
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
        let k = mapper
            .map_keyframe(
                &mut h,
                &mut Given {
                    pose: tracked,
                    against: Some((first, then, version)),
                },
            )
            .unwrap()
            .keyframe;
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
            mapper
                .map_keyframe(
                    g,
                    &mut Given {
                        pose,
                        against: None,
                    },
                )
                .unwrap()
                .keyframe
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
