//! The stereo and RGB-D front-end of the live system (thesis §6.3–6.5): a camera that measures
//! depth, by block matching of a rectified pair or from a depth image (RGB-D as a virtual
//! stereo camera).
//!
//! Per frame, in the tracking thread: the frame is prepared ([`crate::frame`]: pyramid, FAST,
//! depth), tracked ([`crate::tracker`]: dense prior, guided search, motion-only BA) and, when
//! no keyframe near it covers its view, made a keyframe by the keyframe pipeline's stages
//! (`slam::mapping`: insertion with local registration, metric loop closure, new points),
//! after which the session's back-end gets it: double window optimisation and appearance loop
//! closure ([`crate::loops`]), each in its thread or inline. A lost frame is looked for among
//! the keyframes by its ORB words and a 3-point RANSAC and tracked again from the pose that
//! gives; a camera lost for `tracker.new_map_after` seconds starts a new map at the motion
//! model's guess, merged into the older map by the loop that later joins them.

use crate::association::KeyframeAssociation;
use crate::config::SystemConfig;
use crate::frame::{FrameData, SensorFrontEnd};
use crate::keyframes::{KeyframeReason, keyframe_reason, nearest_keyframe};
use crate::loops::{LoopCloser, LoopJob};
use crate::place_recognition::{
    KeyframeFeatures, PlaceRecognition, PlaceRecognitionConfig, features,
};
use crate::result::{Relocalisation, RunGraph, SystemError};
use crate::session::{Context, Finished, Found, Optimise, Sensor, Step, StepState};
use crate::tracker::{Tracked, Tracker};
use data::output::TrackingState;
use geom::StereoCamera;
use lie::{LieGroup, Se3, Sim3};
use slam::dwo::{DoubleWindowOptimiser, DwoParams};
use slam::map::shared::{read_lock, write_lock};
use slam::map::{FIRST_MAP, KeyframeId, SlamGraph};
use slam::mapping::Mapper;
use slam::tracking::TrackId;
use std::sync::{Arc, RwLock};
use std::time::{Duration, Instant};

/// The context of the depth sensor's calls.
type Ctx<'a, 'b> = Context<'a, LoopCloser, Optimise<StereoCamera>, 3>;

/// The stereo and RGB-D front-end (see the [module docs](self)).
pub(crate) struct DepthSensor {
    front: SensorFrontEnd,
    tracker: Tracker,
    mapper: Mapper<StereoCamera, 3>,
    /// The double window's parameters (the final optimisation's too).
    dwo: DwoParams,
    /// Keep each keyframe's depth image in the store (only the dense model fuses it).
    keep_depth: bool,
    /// The loop closer's place-recognition database (and its configuration), where a lost
    /// frame is looked for.
    relocaliser: Option<(Arc<RwLock<PlaceRecognition>>, PlaceRecognitionConfig)>,
    /// The tracker's guess for the last frame it lost (where a new map would start).
    guess: Option<Sim3>,
    next_track: TrackId,
    /// Only localise in a loaded map: no keyframe kept, no new map, no final optimisation.
    localise: bool,
    /// Localising: the temporary keyframes made where the map does not cover the view
    /// (removed at the end), and a keyframe of the loaded map every frame is kept relative to.
    temporary: Vec<KeyframeId>,
    loaded_anchor: Option<KeyframeId>,
}

impl DepthSensor {
    /// Report (or stop reporting) each frame's searched points, for a live view.
    pub fn observe(&mut self, on: bool) {
        self.tracker.observe(on);
    }

    /// The front-end for `front`'s camera with `config`; `keep_depth`: keep the keyframes'
    /// depth images.
    pub fn new(front: SensorFrontEnd, config: &SystemConfig, keep_depth: bool) -> Self {
        let camera = *front.camera();
        let sigma = config.pixel_noise;
        let mut tracker = Tracker::new(config.tracker.clone(), camera, sigma);
        tracker.record_findings(config.keyframes.cull_points);
        DepthSensor {
            tracker,
            mapper: Mapper::new(camera, config.keyframe_pipeline(&camera)),
            dwo: config.double_window(camera.pinhole.fx, Some(camera.baseline)),
            keep_depth,
            relocaliser: None,
            guess: None,
            next_track: 0,
            localise: false,
            temporary: Vec::new(),
            loaded_anchor: None,
            front,
        }
    }

    /// The double window's parameters.
    pub fn dwo_params(&self) -> &DwoParams {
        &self.dwo
    }

    /// The loop closer for this sensor, sharing its database with the relocalisation of lost
    /// frames.
    pub fn loop_closer(
        &mut self,
        vocabulary: Arc<vision::bow::Vocabulary>,
        config: &SystemConfig,
        store: Arc<RwLock<crate::keyframes::KeyframeStore>>,
    ) -> Result<LoopCloser, SystemError> {
        let closer = LoopCloser::new(
            vocabulary,
            self.front.clone(),
            config,
            self.mapper.config().clone(),
            store,
        )?;
        self.relocaliser = Some(closer.shared_database());
        Ok(closer)
    }

    /// The first keyframe, at the identity.
    fn initialise(&mut self, ctx: &mut Ctx, frame: &Arc<FrameData>) -> Result<Step, SystemError> {
        if frame.depth.is_none() {
            return Ok(Step::untracked(
                StepState::Initialising("no depth image to start the map from".into()),
                Duration::ZERO,
            ));
        }
        let pose = Sim3::identity();
        let (keyframe, _) = self.make_keyframe(ctx, frame, pose, Vec::new(), None, false)?;
        self.tracker.set_pose(frame, Se3::identity(), FIRST_MAP);
        Ok(Step::keyframe_made(
            StepState::Good,
            pose,
            keyframe,
            KeyframeReason::First,
        ))
    }

    /// What follows a frame tracked (or relocalised): the reference for the next frame, the
    /// keyframe decision and, for a new keyframe, the keyframe pipeline; the pose moved with
    /// its map if another thread merged that into an older one meanwhile.
    fn conclude(
        &mut self,
        ctx: &mut Ctx,
        frame: &Arc<FrameData>,
        tracked: Tracked,
        started: Instant,
    ) -> Result<Step, SystemError> {
        let time_tracking = started.elapsed();
        let Tracked {
            camera_from_world,
            state,
            matches,
            reference,
            then,
            median_depth,
            stats,
            observed,
            ..
        } = tracked;
        // The keyframe the pose was tracked against (the reference may change below).
        let tracker_reference = reference;
        // Revisits reuse the map (thesis §6.5.2): the keyframe that sees most of what this frame
        // tracked becomes the reference when it is at least as near as the current one, so a
        // camera browsing a mapped place tracks against its keyframes instead of adding new ones.
        let reference = reuse_reference(ctx, reference, &camera_from_world, &matches);
        let (reason, nearest) = if frame.depth.is_some() {
            let g = ctx.graph.read();
            // The keyframes metric loop closure would search (`N2`, thesis §6.4.1): a view one
            // of them covers is a revisit, not a new place.
            let hood = g.n2(reference, ctx.config.mapping.n2);
            let nearest = nearest_keyframe(
                &ctx.config.keyframes,
                &g,
                &hood,
                &camera_from_world,
                median_depth,
            );
            let reason = nearest.as_ref().and_then(|n| {
                keyframe_reason(&ctx.config.keyframes, n, stats.found, stats.searched)
            });
            (reason, nearest)
        } else {
            (None, None)
        };
        // A revisit: the next frame tracks against the keyframe that covers this view.
        let reference = match (&reason, &nearest) {
            (None, Some(n))
                if n.keyframe != reference
                    && ctx.graph.write().set_reference(n.keyframe).is_ok() =>
            {
                n.keyframe
            }
            _ => reference,
        };
        let keyframe = match reason {
            Some(reason) => {
                let t = Instant::now();
                // Inserted as tracked against `tracker_reference` then: rebased if another
                // thread moved it meanwhile (an optimisation, a merge).
                let tracked_against = Some((tracker_reference, then.reference_pose, then.version));
                let (k, _) = self.make_keyframe(
                    ctx,
                    frame,
                    camera_from_world,
                    matches,
                    tracked_against,
                    false,
                )?;
                ctx.timings.record("keyframe: pipeline", t.elapsed());
                if self.localise {
                    // Localising: a temporary keyframe, removed at the end (`finish`).
                    self.temporary.push(k);
                    None
                } else {
                    Some((k, reason))
                }
            }
            None => None,
        };
        // A pose tracked against a map that was merged into another since (by the loop
        // thread, or by a loop closed inline while the frame became a keyframe) moves with it.
        let pose = ctx
            .graph
            .read()
            .moved_since(then.merges, then.map)
            .map_or(camera_from_world, |(moved, _)| {
                camera_from_world.compose(&moved)
            });
        Ok(Step {
            state: match state {
                TrackingState::Weak(r) => StepState::Weak(r),
                TrackingState::Lost(r) => StepState::Lost(r),
                TrackingState::Good => StepState::Good,
            },
            camera_from_world: Some(pose),
            anchor: Some(match (&keyframe, self.loaded_anchor) {
                (Some((k, _)), _) => (*k, true),
                // Localising nothing moves: the frame is kept relative to a keyframe of the
                // loaded map (temporary ones are removed at the end).
                (None, Some(k)) => (k, false),
                (None, None) => (reference, false),
            }),
            keyframe,
            stats: Some(stats),
            time_tracking,
            relocalised: None,
            earlier_keyframe: None,
            observed,
        })
    }

    /// Makes `frame` a keyframe at `camera_from_world` with its tracked `matches` (tracked
    /// against `tracked_against`, see `KeyframeAssociation::tracked_against`): the keyframe
    /// pipeline's stages, then the back-end (the loop closer's job, an optimisation). With
    /// `new_map`, the first keyframe of a new map (`slam::map::SlamGraph::start_map`), started
    /// under the same write lock, so that no other thread sees the new map without it (nor the
    /// graph without a reference keyframe, unless the pipeline fails, which stops the run).
    /// Returns the keyframe and the map it was made in.
    fn make_keyframe(
        &mut self,
        ctx: &mut Ctx,
        frame: &Arc<FrameData>,
        camera_from_world: Sim3,
        matches: Vec<(slam::map::PointId, nalgebra::Vector3<f64>)>,
        tracked_against: Option<(KeyframeId, Sim3, slam::map::Version)>,
        new_map: bool,
    ) -> Result<(KeyframeId, usize), SystemError> {
        // The dense model's depth image (`--dense-ply`; with sparse stereo block-matched for the
        // keyframe alone), kept only then.
        let keyframe_depth = if self.keep_depth {
            self.front.keyframe_depth(frame)?
        } else {
            None
        };
        let store_lock = ctx.store.clone();
        let store = read_lock(&store_lock);
        let min_disparity = self.mapper.config().min_disparity;
        let mut association = KeyframeAssociation::new(
            frame,
            &store,
            &self.front,
            camera_from_world,
            matches,
            ctx.config,
            min_disparity,
            &mut self.next_track,
        );
        association.tracked_against = tracked_against;
        association.new_map = new_map;
        let mut images = association.images();
        images.depth = keyframe_depth;
        // The stages of the keyframe pipeline, each under the graph's lock for as short as it
        // can (`slam::mapping::Mapper::map_keyframe`; the optimisation is not among them).
        let report = self
            .mapper
            .map_keyframe(ctx.graph, &mut association)
            .map_err(|source| SystemError::Mapping {
                frame: frame.index,
                source,
            })?;
        let map = ctx
            .graph
            .read()
            .map_of(report.keyframe)
            .unwrap_or(FIRST_MAP);
        let keyframe = report.keyframe;
        for (stage, d) in &report.stage_times {
            ctx.timings.record(stage, *d);
        }
        drop(store);
        write_lock(ctx.store).insert(keyframe, images);
        if self.localise {
            // A temporary keyframe: tracking's alone (no optimisation, no loop closure; its
            // loops with the map are removed with it).
            return Ok((keyframe, map));
        }
        for closure in &report.metric_loops {
            metric_loop(ctx, keyframe, closure.keyframe, "metric");
        }
        self.cull(ctx, keyframe);
        if let Some(old) = report.appearance_loop {
            metric_loop(ctx, keyframe, old, "appearance");
        }
        let job = ctx.backend.loops.as_ref().map(|_| LoopJob {
            keyframe,
            frame: frame.clone(),
        });
        ctx.backend.keyframe(job, Some(()));
        Ok((keyframe, map))
    }

    /// Removes the points tracking no longer finds (`keyframes.cull_points`) and culls the new
    /// `keyframe`'s redundant neighbours (`slam::mapping::culling`), with their images and
    /// place-recognition entries. Not the reference keyframe, the keyframes the
    /// next keyframe's prediction starts from, or a keyframe the loop closer has not added to
    /// its database yet (its job is queued, or running: it must find the keyframe there).
    fn cull(&mut self, ctx: &mut Ctx, keyframe: KeyframeId) {
        let config = ctx.config.keyframes.culling();
        let t = Instant::now();
        if ctx.config.keyframes.cull_points {
            let unfound = {
                let g = ctx.graph.read();
                self.tracker
                    .unfound_points(&g, ctx.config.keyframes.min_found_fraction)
            };
            if !unfound.is_empty() {
                // Only points no other keyframe measures: a point two keyframes measure still
                // ties their poses in the optimisations, found by tracking or not.
                let mut g = ctx.graph.write();
                for p in unfound {
                    if g.point(p).is_some_and(|pt| pt.observers().len() <= 1) {
                        let _ = g.remove_point(p);
                    }
                }
            }
        }
        if !config.enabled {
            ctx.timings.record("keyframe: culling", t.elapsed());
            return;
        }
        let database = self.relocaliser.as_ref().map(|(d, _)| d.clone());
        let recent = self.mapper.recent().to_vec();
        let retired = {
            // The database's lock first, then the graph's (the loop closer takes them one at
            // a time): a keyframe it holds is in its database, and stays until culled here.
            let mut database = database.as_ref().map(|d| write_lock(d));
            let mut g = ctx.graph.write();
            let reference = g.reference();
            let protected = |k: KeyframeId| {
                Some(k) == reference
                    || recent.contains(&k)
                    || database.as_ref().is_some_and(|d| !d.contains(k))
            };
            let retired = slam::mapping::culling::cull(&mut g, keyframe, protected, &config);
            let retired = match retired {
                Ok(r) => r,
                Err(e) => {
                    ctx.warnings
                        .push(format!("culling around keyframe {keyframe}: {e}"));
                    Vec::new()
                }
            };
            if let Some(d) = database.as_mut() {
                for r in &retired {
                    d.remove(r.keyframe);
                }
            }
            retired
        };
        if !retired.is_empty() {
            let mut store = write_lock(ctx.store);
            for r in &retired {
                store.remove(r.keyframe);
            }
        }
        ctx.retired.extend(retired);
        ctx.timings.record("keyframe: culling", t.elapsed());
    }

    /// Looks for a lost frame in the map by appearance: the keyframe whose place it shows
    /// (verified by the 3-point RANSAC of loop closure, [`PlaceRecognition::relocalise`]), the
    /// pose that gives, and the frame tracked again from there against that keyframe's
    /// neighbourhood (guided search with the wide radius, motion-only BA). Accepted only if the
    /// tracking is good; else the tracker and the reference keyframe are left as they were.
    /// A frame without depth (an RGB-D frame with no depth image) is verified 2D–3D instead,
    /// by P3P RANSAC against the keyframe's points ([`verify::verify_absolute`]).
    ///
    /// [`verify::verify_absolute`]: crate::place_recognition::verify::verify_absolute
    fn find(&mut self, ctx: &mut Ctx, frame: &Arc<FrameData>) -> Option<(Tracked, Relocalisation)> {
        let (database, config) = self.relocaliser.as_ref()?;
        let features = features::extract(
            frame.gray(),
            |u, v| frame.keypoint_depth(u, v, config.depth_edge_ratio),
            Vec::new(),
            self.front.pinhole(),
            config,
        )
        .ok()?;
        let candidate = read_lock(database).relocalise(frame.index as u32, &features)?;
        let (pose, before) = {
            let g = ctx.graph.read();
            let old = g.pose(candidate.old).ok()?;
            (
                candidate.query_from_old.compose(&old).rigid_part(),
                g.reference(),
            )
        };
        let motion = self.tracker.motion();
        ctx.graph.write().set_reference(candidate.old).ok()?;
        let store_lock = ctx.store.clone();
        let store = read_lock(&store_lock);
        let keyframe_frame = store
            .get(candidate.old)
            .map_or(usize::MAX, |i| i.frame_index);
        // Tracked from the verified pose, and once more from the pose that gives if it was
        // weak: the appearance matches' pose is good to centimetres, the map's to millimetres,
        // and a better prior finds more of the map (ORB-SLAM refines a relocalisation alike).
        let mut tracked = None;
        let mut prior = pose;
        for _ in 0..2 {
            self.tracker.restart(frame, prior);
            tracked = self.tracker.track(ctx.graph, &store, frame);
            match &tracked {
                Some(t) if matches!(t.state, TrackingState::Weak(_)) => {
                    prior = t.camera_from_world.rigid_part();
                }
                _ => break,
            }
        }
        drop(store);
        match tracked {
            Some(t) if t.state == TrackingState::Good => {
                self.tracker.reset_velocity();
                let r = Relocalisation {
                    frame: frame.index,
                    keyframe: candidate.old,
                    keyframe_frame,
                    ransac_inliers: candidate.ransac_inliers,
                    tracked: t.stats.inliers,
                };
                Some((t, r))
            }
            _ => {
                self.tracker.set_motion(motion);
                if let Some(r) = before {
                    let _ = ctx.graph.write().set_reference(r);
                }
                None
            }
        }
    }
}

/// A loop the keyframe pipeline closed, into the run's loops.
fn metric_loop(ctx: &mut Ctx, keyframe: KeyframeId, old: KeyframeId, kind: &'static str) {
    let frames = ctx.frames_of(keyframe, old);
    ctx.loops.push(crate::result::LoopEvent {
        keyframe,
        old,
        frames,
        kind,
        scale: None,
        scale_sigma: None,
        agreeing: None,
        correction: None,
        evidence: None,
    });
}

/// The keyframe to track the next frame against: of the keyframes observing this frame's
/// matched points, the one observing most of them, if it is no farther from the camera than
/// the current reference (else the current reference). Made the graph's reference.
fn reuse_reference(
    ctx: &mut Ctx,
    reference: KeyframeId,
    camera_from_world: &Sim3,
    matches: &[(slam::map::PointId, nalgebra::Vector3<f64>)],
) -> KeyframeId {
    let best = {
        let g = ctx.graph.read();
        let mut seen: std::collections::BTreeMap<KeyframeId, usize> = Default::default();
        for (p, _) in matches {
            if let Some(pt) = g.point(*p) {
                for &o in pt.observers() {
                    *seen.entry(o).or_default() += 1;
                }
            }
        }
        let centre = |t: &Sim3| t.inverse().act(&nalgebra::Vector3::zeros());
        let here = centre(camera_from_world);
        let distance = |k: KeyframeId| {
            g.pose(k)
                .map_or(f64::INFINITY, |t| (centre(&t) - here).norm())
        };
        let own = seen.get(&reference).copied().unwrap_or(0);
        seen.into_iter()
            .filter(|&(k, n)| k != reference && n > own && distance(k) <= distance(reference))
            .max_by_key(|&(k, n)| (n, std::cmp::Reverse(k)))
            .map(|(k, _)| k)
    };
    match best {
        Some(k) if ctx.graph.write().set_reference(k).is_ok() => k,
        _ => reference,
    }
}

impl Sensor<3> for DepthSensor {
    type Frame = Arc<FrameData>;
    type OptimiserData = std::convert::Infallible;
    type Optimiser = Optimise<StereoCamera>;
    type LoopData = ();
    type Loops = LoopCloser;

    fn prepare(
        &mut self,
        ctx: &mut Ctx,
        frame: data::sequence::Frame,
    ) -> Result<Arc<FrameData>, SystemError> {
        let t = Instant::now();
        let frame = Arc::new(self.front.prepare(frame)?);
        ctx.timings
            .record("frame: pyramid, FAST, depth", t.elapsed());
        Ok(frame)
    }

    fn track(&mut self, ctx: &mut Ctx, frame: &Arc<FrameData>) -> Result<Step, SystemError> {
        if ctx.graph.read().num_keyframes() == 0 {
            return self.initialise(ctx, frame);
        }
        let t = Instant::now();
        let tracked = {
            let store = read_lock(ctx.store);
            self.tracker.track(ctx.graph, &store, frame)
        };
        let Some(tracked) = tracked else {
            // No pose yet in a map loaded from a file (the session relocalises the frame), or
            // no reference keyframe.
            let why = if !self.tracker.has_pose() {
                "not found in the loaded map yet"
            } else {
                "no reference keyframe to track against"
            };
            return Ok(Step::untracked(StepState::Lost(why.into()), t.elapsed()));
        };
        for (stage, d) in &tracked.timings {
            ctx.timings.record(stage, *d);
        }
        if let TrackingState::Lost(reason) = &tracked.state {
            self.guess = Some(tracked.camera_from_world);
            return Ok(Step::untracked(
                StepState::Lost(reason.clone()),
                t.elapsed(),
            ));
        }
        self.conclude(ctx, frame, tracked, t)
    }

    fn relocalise(&mut self, ctx: &mut Ctx, frame: &Arc<FrameData>) -> Result<Found, SystemError> {
        let t = Instant::now();
        match self.find(ctx, frame) {
            Some((tracked, relocalisation)) => {
                let step = self.conclude(ctx, frame, tracked, t)?;
                Ok(Found::Place(Box::new(Step {
                    relocalised: Some(relocalisation),
                    time_tracking: Duration::ZERO,
                    ..step
                })))
            }
            None => Ok(Found::Nothing(String::new())),
        }
    }

    fn can_recover(&self) -> bool {
        // The tracker keeps searching the map around its motion model's guess.
        true
    }

    /// Starts a new map at `frame`, lost for `lost_for` seconds, at the pose the tracker
    /// guessed (its constant-velocity prediction): its first keyframe, in a map of its own
    /// (`slam::map::SlamGraph::start_map`), from which the next frames are tracked. An
    /// appearance loop from the new map into an older one later merges the two
    /// (`AppearanceClosure::Merged`). Not for a frame with too few corners with depth for the
    /// next frames to track (fewer than a good frame's inliers: a black or blurred frame).
    fn start_map(
        &mut self,
        ctx: &mut Ctx,
        frame: &Arc<FrameData>,
        lost_for: f64,
    ) -> Result<Option<Step>, SystemError> {
        if self.localise {
            return Ok(None);
        }
        // A camera never found in a loaded map starts its map at the identity: it is a map of
        // its own until a loop merges it.
        let guess = match (self.guess, ctx.graph.read().num_keyframes()) {
            (Some(guess), _) => guess,
            (None, n) if n > 0 && !self.tracker.has_pose() => Sim3::identity(),
            (None, _) => return Ok(None),
        };
        if frame.depth.is_none() {
            return Ok(None);
        }
        let with_depth = frame
            .corners
            .corners()
            .iter()
            .filter(|c| frame.depth_at(c.u as f64, c.v as f64).is_some())
            .take(ctx.config.tracker.min_good)
            .count();
        if with_depth < ctx.config.tracker.min_good {
            return Ok(None);
        }
        let (keyframe, map) = self.make_keyframe(ctx, frame, guess, Vec::new(), None, true)?;
        // Where the keyframe is now: a loop closed inline (deterministic) may have merged the
        // new map into the old one already.
        let (pose, now_in) = {
            let g = ctx.graph.read();
            (
                g.pose(keyframe).unwrap_or(guess),
                g.map_of(keyframe).unwrap_or(map),
            )
        };
        self.tracker.set_pose(frame, pose.rigid_part(), now_in);
        // A weak state: the map goes on, but its place relative to the old one is a guess.
        Ok(Some(Step::keyframe_made(
            StepState::Weak(format!(
                "lost for {lost_for:.1} s: new map {map} started at the constant-velocity guess"
            )),
            pose,
            keyframe,
            KeyframeReason::NewMap,
        )))
    }

    fn optimised(&mut self, _: &mut Ctx, data: std::convert::Infallible) {
        match data {}
    }

    fn loop_data(&mut self, _: &mut Ctx, _: ()) {}

    /// The optimisations that end the run, around the map written (its newest keyframe the
    /// reference: the windows grow from the reference through the edges, which do not join
    /// maps never merged): the double window with every keyframe in its outer window (the pose
    /// graph of the whole map), then the bundle adjustment over every keyframe and point, both
    /// from the poses as they are (`DoubleWindowOptimiser::finishing`), unless the run was
    /// interrupted (Ctrl-C stops promptly).
    ///
    /// The bundle adjustment alone, on eleven sequences (bench/README.md, 2026-12-03): the
    /// trajectory after the run got better or stayed, at 0.03–0.9 s.
    fn finish(&mut self, ctx: &mut Ctx, interrupted: bool) -> Result<Finished<3>, SystemError> {
        if !self.temporary.is_empty() {
            let mut g = ctx.graph.write();
            let mut store = write_lock(ctx.store);
            for &k in self.temporary.iter().rev() {
                let _ = g.remove_keyframe(k);
                store.remove(k);
            }
            if let Some(k) = self.loaded_anchor {
                let _ = g.set_reference(k);
            }
            ctx.warnings.push(format!(
                "localising: {} temporary keyframes bridged views the map does not cover \
                 (removed at the end: the map is as loaded)",
                self.temporary.len()
            ));
        }
        let (world, _) = ctx.graph.read().written_maps();
        {
            let mut g = ctx.graph.write();
            let newest = g
                .keyframes()
                .map(|(k, _)| k)
                .filter(|&k| g.map_of(k) == Ok(world))
                .last();
            if let Some(k) = newest
                && g.reference().is_none_or(|r| g.map_of(r) != Ok(world))
            {
                let _ = g.set_reference(k);
            }
        }
        let final_iterations = ctx.config.optimiser.final_iterations;
        if !interrupted
            && !self.localise
            && final_iterations > 0
            && ctx.graph.read().num_keyframes() >= 2
            && ctx.graph.read().reference().is_some()
        {
            let [mut global, mut full] = DoubleWindowOptimiser::finishing(
                DwoParams {
                    iterations: final_iterations,
                    ..self.dwo.clone()
                },
                &ctx.graph.read(),
            );
            let camera = *self.front.camera();
            let stats = global.optimise(&**ctx.graph, &camera)?;
            ctx.timings
                .record("optimise: final pose graph (gDWO)", stats.total());
            let stats = full.optimise(&**ctx.graph, &camera)?;
            ctx.timings
                .record("optimise: final bundle adjustment", stats.total());
        }
        Ok(Finished {
            graph: ctx.graph.snapshot(),
            alternatives: Vec::new(),
        })
    }

    fn run_graph(graph: SlamGraph<3>) -> RunGraph {
        RunGraph::Depth(graph)
    }

    fn place_features(&self) -> Vec<(KeyframeId, KeyframeFeatures)> {
        self.relocaliser
            .as_ref()
            .map_or_else(Vec::new, |(database, _)| {
                read_lock(database)
                    .entries()
                    .map(|(k, f)| (k, f.clone()))
                    .collect()
            })
    }

    fn restore(
        &mut self,
        ctx: &mut Ctx,
        features: Vec<(KeyframeId, KeyframeFeatures)>,
        localise: bool,
    ) -> Result<(), SystemError> {
        self.localise = localise;
        self.loaded_anchor = localise
            .then(|| ctx.graph.read().keyframes().map(|(k, _)| k).next())
            .flatten();
        let Some((database, _)) = &self.relocaliser else {
            return Err(SystemError::map_without_vocabulary());
        };
        let mut database = write_lock(database);
        for (k, f) in features {
            database.insert(k, f)?;
        }
        Ok(())
    }
}
