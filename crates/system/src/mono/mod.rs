//! The monocular front-end of the live system (thesis ch. 3, §6.2.7): one camera's frames,
//! every frame's pose and the map, at the arbitrary scale a single camera has.
//!
//! Per frame, in the tracking thread:
//!
//! 1. **Corner tracks** ([`tracks::CornerTracks`], the image side): followed by pyramidal LK
//!    and replenished where they thin out.
//! 2. **Map points checked and found again**: every track that measures a map point is checked
//!    against the point's template (`mono.verify_tracks`), and the map points of the keyframes
//!    near the predicted pose that no track measures are searched for (`mono.refind`).
//! 3. **Exploration** (`slam::exploration::MonoExplorer`, the same stage the simulated
//!    scale-drift studies run on simulated tracks), on the session's graph: the two-view
//!    bootstrap with model selection between homography and essential matrix, motion-only BA,
//!    keyframes by coverage, inverse-depth feature filters, and a keyframe BA over the
//!    keyframes sharing most points with the new one, older observers of their points fixed,
//!    the measurements it does not explain removed.
//!
//! A new keyframe's images go into the session's store and the keyframe to the back-end's loop
//! stage ([`loops`]: loops and map joins by appearance, in Sim(3)); the loops accepted correct
//! the map while the run goes on (`mono.correct_live`; off: at the end of the run only) and
//! once more at its end, in `mono.loop_correction`'s group, each map of the graph through the
//! pose graph of its own keyframes, and a map of one graph is then bundle adjusted.
//!
//! When tracking loses the map (the tracks cannot follow into `mono.max_refused` frames in a
//! row, or too few map points are measured), the camera is lost: the session looks for each
//! following frame in the map ([`Sensor::relocalise`]: its ORB words against the keyframe
//! database, P3P RANSAC against the best keyframes' points, the guided search of their
//! neighbourhood around that pose), and starts a new map — a new bootstrap, in a map of its
//! own in the one graph, with its own frame and scale — after `tracker.new_map_after` seconds,
//! or at once where nothing could find it (no vocabulary, a map of fewer than two keyframes). A
//! frame the tracks cannot follow into is looked for in the map at once (a jump to a mapped
//! place is not waited out).

pub(crate) mod loops;
pub(crate) mod tracks;
pub(crate) mod window;

use crate::config::SystemConfig;
use crate::frame::CornerIndex;
use crate::keyframes::{KeyframeImages, KeyframeReason, KeyframeStore};
use crate::observed::{Observed, ObservedState};
use crate::place_recognition::KeyframeFeatures;
use crate::place_recognition::features::extract as extract_features;
use crate::result::{Relocalisation, RunGraph, SystemError};
use crate::search::{
    CORNER_CELL_PX, PATCH_MARGIN_PX, Relocated, SAME_CORNER_PX, SearchPoint, SearchScratch,
    predict, relocate, search, view_angle,
};
use crate::session::{Finished, Found, Sensor, Step, StepState};
use crate::tracker::TrackerStats;
use geom::PinholeCamera;
use lie::{LieGroup, Se3, Sim3};
use loops::{
    LoopDetection, MonoLoopData, MonoLoopJob, MonoLoops, MonoPlaces, correct_loops,
    correction_groups, map_edges,
};
use nalgebra::{Vector2, Vector3};
use slam::exploration::{ExplorationError, FrameOutcome, MonoExplorer, TrackId, rigid_pose};
use slam::loop_closure::CorrectionGroup;
use slam::map::shared::{read_lock, write_lock};
use slam::map::{KeyframeId, SlamGraph};
use slam::pose_graph::rigid_from_similarity;
use std::collections::{BTreeMap, HashSet};
use std::sync::{Arc, RwLock};
use std::time::{Duration, Instant};
use tracks::{CornerTracks, Refused};
use vision::fast::FrameCorners;
use vision::image::GrayImage;

/// The context of the monocular sensor's calls.
use window::{Ctx, Windows};

/// A frame's measurements: `(track, pixel)`.
type Measurements = Vec<(TrackId, Vector2<f64>)>;

/// Where and why tracking was lost in a map that the following frames try to relocalise in.
#[derive(Clone, Debug)]
struct Lost {
    frame: usize,
    why: String,
}

/// What a cached `refind` neighbourhood was computed at: (keyframes, loops, start keyframe).
type NeighbourhoodKey = (usize, usize, Option<KeyframeId>);

/// The monocular front-end (see the [module docs](self)).
pub(crate) struct MonoSensor {
    camera: PinholeCamera,
    tracks: CornerTracks,
    /// Made at the first frame (the exploration needs the image size).
    explorer: Option<MonoExplorer>,
    /// Frames refused in a row by the corner tracks.
    refused: usize,
    /// Tracking lost in the current map.
    lost: Option<Lost>,
    /// The keyframe the last relocalisation found, until the next keyframe is made.
    reference: Option<KeyframeId>,
    /// The neighbourhood searched by `refind`, with the key it was computed at.
    neighbourhood: Option<(NeighbourhoodKey, HashSet<KeyframeId>)>,
    /// The next frame explored is the first of a bootstrap (the first frame, after a new map
    /// or a bootstrap given up).
    bootstrapping: bool,
    /// The first frame of a bootstrap in progress: its images become the first keyframe's.
    bootstrap_first: Option<KeyframeImages>,
    scratch: SearchScratch,
    /// The keyframe databases (with a vocabulary), shared with the loop stage.
    places: Option<Arc<RwLock<MonoPlaces>>>,
    /// The loops accepted, per map.
    accepted: BTreeMap<usize, Vec<LoopDetection>>,
    /// Live loop corrections written into the graph (shared with the loop stage).
    corrections_applied: Arc<std::sync::atomic::AtomicUsize>,
    /// Only localise in a loaded map: no keyframe kept, no new map.
    localise: bool,
    /// Localising: the loaded map's newest keyframe, which the frames are kept relative to.
    loaded_anchor: Option<KeyframeId>,
    /// Report each frame's corner tracks (`Step::observed`), for a live view.
    observe: bool,
    /// Its keyframes' windows in the back-end ([`window`]).
    windows: Windows,
}

impl MonoSensor {
    /// Bundle adjustment of a corrected map (`slam::loop_closure::correction::refine_graph`):
    /// the exploration's pixel noise and Huber width, ten iterations, one thread.
    fn refine(
        &self,
        graph: &mut SlamGraph<2>,
    ) -> Result<(), slam::loop_closure::correction::CorrectionError> {
        // No explorer: no frame was explored, there is no map to adjust.
        let Some(config) = self.explorer.as_ref().map(|e| e.config()) else {
            return Ok(());
        };
        let (sigma, huber) = (config.sigma, config.huber);
        let options = lsq::SolverOptions {
            max_iterations: 10,
            threads: Some(1),
            ..lsq::SolverOptions::default()
        };
        slam::loop_closure::correction::refine_graph(
            graph,
            &self.camera,
            sigma,
            huber,
            true,
            &options,
        )
        .map(|_| ())
    }

    /// The front-end for `camera` with `config`.
    pub fn new(camera: PinholeCamera, config: &SystemConfig) -> Self {
        MonoSensor {
            tracks: CornerTracks::new(&config.mono),
            camera,
            explorer: None,
            refused: 0,
            lost: None,
            reference: None,
            neighbourhood: None,
            bootstrapping: true,
            bootstrap_first: None,
            scratch: SearchScratch::default(),
            places: None,
            accepted: BTreeMap::new(),
            corrections_applied: Default::default(),
            localise: false,
            loaded_anchor: None,
            observe: false,
            windows: Windows::default(),
        }
    }

    /// Report (or stop reporting) each frame's corner tracks, map points among them, for a
    /// live view.
    pub fn observe(&mut self, on: bool) {
        self.observe = on;
    }

    /// The loop stage for this sensor with `vocabulary`, sharing its keyframe databases with
    /// the relocalisation of lost frames.
    pub fn loop_stage(
        &mut self,
        vocabulary: Arc<vision::bow::Vocabulary>,
        config: &SystemConfig,
        store: Arc<RwLock<KeyframeStore>>,
    ) -> MonoLoops {
        let place = config.place_recognition_for(None);
        let places = Arc::new(RwLock::new(MonoPlaces::new(vocabulary, place)));
        self.places = Some(places.clone());
        MonoLoops::new(
            places,
            store,
            self.camera,
            config,
            self.corrections_applied.clone(),
        )
    }

    /// Whether a lost camera looks for its place in the current map: a map of two keyframes
    /// or more, a vocabulary to recognise its places, and `tracker.new_map_after` > 0.
    fn relocalisable(&self, config: &SystemConfig) -> bool {
        self.places.is_some()
            && config.tracker.new_map_after > 0.0
            && self
                .explorer
                .as_ref()
                .is_some_and(|e| e.map_keyframes().nth(1).is_some())
    }

    /// Tracking is lost at `frame` for `why`: the tracks are dropped, the following frames are
    /// looked for in the map. Returns the reason the frame's state gives.
    fn lose(&mut self, frame: usize, why: String) -> String {
        self.refused = 0;
        self.lost.get_or_insert(Lost {
            frame,
            why: why.clone(),
        });
        self.tracks.reset();
        self.reference = None;
        why
    }

    /// The frame's corner tracks, or why the frame is not used.
    fn follow_tracks(
        &mut self,
        ctx: &mut Ctx,
        frame: &data::sequence::Frame,
        corners: &FrameCorners,
    ) -> Result<Result<Measurements, StepState>, SystemError> {
        let t = Instant::now();
        let followed: Result<Measurements, Refused> = self
            .tracks
            .push(corners)
            .map_err(|e| SystemError::Frame(e.into()))?
            .map(|tracks| {
                tracks
                    .iter()
                    .map(|&(id, p)| (id, Vector2::new(p[0] as f64, p[1] as f64)))
                    .collect()
            });
        ctx.timings.record("frame: pyramid, LK tracks", t.elapsed());
        match followed {
            Ok(m) => {
                self.refused = 0;
                Ok(Ok(m))
            }
            Err(Refused { survived, of }) => {
                self.refused += 1;
                let why = format!(
                    "only {survived} of {of} corner tracks followed into this frame: refused"
                );
                // A black frame or a short glitch is waited out against the last good frame
                // (the session looks for the frame's place meanwhile: a jump to a mapped place
                // is relocalised at once); after `mono.max_refused` in a row, the camera is lost.
                if self.refused >= ctx.config.mono.max_refused {
                    let refused = self.refused;
                    let lost = self.lose(frame.index, format!("{refused} frames in a row refused"));
                    return Ok(Err(StepState::Lost(format!("{why}; {lost}"))));
                }
                Ok(Err(StepState::Waiting(why)))
            }
        }
    }

    /// The frame's `measurements` through the exploration (after a relocalisation,
    /// `relocalised`): its pose, and a keyframe's images into the store and the keyframe to
    /// the loop stage.
    fn explore(
        &mut self,
        ctx: &mut Ctx,
        frame: &data::sequence::Frame,
        measurements: Measurements,
        refound: usize,
        relocalised: Option<Relocalisation>,
        start: Instant,
    ) -> Result<Step, SystemError> {
        let n_tracks = measurements.len();
        let t = Instant::now();
        if std::mem::take(&mut self.bootstrapping) {
            self.bootstrap_first = Some(keyframe_images(frame));
        }
        if self.explorer.is_none() {
            let image = frame.gray();
            let config = ctx
                .config
                .exploration(self.camera.fx, image.width(), image.height());
            let mut explorer = MonoExplorer::new(self.camera, config);
            explorer.defer_windows(true);
            self.explorer = Some(explorer);
        }
        let mut outcome = {
            let explorer = self.explorer.as_mut().expect("made above");
            explorer.process(&**ctx.graph, frame.index, &measurements)
        };
        // A keyframe's window BA goes to the back-end (`window`): inline, it is solved and
        // written back now; in its thread, while the next frame's tracks are followed.
        if let Ok(o) = &mut outcome
            && let Some(job) = o.window.take()
        {
            let explorer = self.explorer.as_mut().expect("explored");
            if let Some(pose) = self.windows.solve(ctx, explorer, job) {
                o.camera_from_world = Some(pose);
            }
        }
        let explored = t.elapsed();
        ctx.timings.record("mono: exploration", explored);
        // Tracking ends with the exploration (its window BA included); place recognition of
        // a new keyframe is not tracking.
        let time_tracking = start.elapsed();
        let observed = match (&self.explorer, self.observe) {
            (Some(explorer), true) => measurements
                .iter()
                .map(|(id, u)| Observed {
                    uv: [u.x as f32, u.y as f32],
                    state: if explorer.active().contains_key(id) {
                        ObservedState::Inlier
                    } else {
                        ObservedState::Track
                    },
                })
                .collect(),
            _ => Vec::new(),
        };
        match outcome {
            Ok(o) => {
                let step = self.outcome(ctx, frame, o, n_tracks, refound, relocalised, explored);
                Ok(Step {
                    time_tracking,
                    observed,
                    ..step
                })
            }
            Err(e @ ExplorationError::BootstrapFailed { .. }) => {
                // A bootstrap given up starts again from the next frame, in the same map.
                if let Some(explorer) = self.explorer.as_mut() {
                    explorer.start_map(&mut ctx.graph.write());
                }
                self.tracks.reset();
                self.bootstrapping = true;
                Ok(Step::untracked(
                    StepState::Initialising(format!("{e}: initialising again")),
                    time_tracking,
                ))
            }
            Err(e) => {
                let why = self.lose(frame.index, e.to_string());
                Ok(Step::untracked(StepState::Lost(why), time_tracking))
            }
        }
    }

    /// The step of an exploration's outcome `o`.
    #[allow(clippy::too_many_arguments)]
    fn outcome(
        &mut self,
        ctx: &mut Ctx,
        frame: &data::sequence::Frame,
        o: FrameOutcome,
        n_tracks: usize,
        refound: usize,
        relocalised: Option<Relocalisation>,
        explored: Duration,
    ) -> Step {
        let explorer = self.explorer.as_ref().expect("explored");
        let first = explorer.map_keyframes().count() <= 2;
        let last = explorer.map_keyframes().last();
        let mut earlier_keyframe = None;
        // Localising, a keyframe is temporary (`MonoExplorer::resume`): its images are the
        // templates of its points; it goes to no back-end and is removed at the end.
        let temporary = o.keyframe.filter(|_| self.localise);
        if let Some(k) = temporary {
            write_lock(ctx.store).insert(k, keyframe_images(frame));
            ctx.timings
                .record("keyframe: temporary (localising)", explored);
        } else if let Some(k) = o.keyframe {
            earlier_keyframe = self.keyframe(ctx, frame, k);
            let threaded = ctx.backend.optimiser.as_ref().is_some_and(|w| w.threaded());
            ctx.timings.record(
                match (first, threaded) {
                    (true, _) => "keyframe: bootstrap",
                    (false, false) => "keyframe: exploration with window BA",
                    (false, true) => "keyframe: exploration (window BA in its thread)",
                },
                explored,
            );
            self.reference = None;
        }
        if o.camera_from_world.is_some() {
            self.lost = None;
            if self.localise {
                // No keyframe follows the camera: the map points are searched around the
                // keyframe that measures most of what this frame tracked (the depth sensor's
                // reference reuse on revisits).
                let graph = ctx.graph.read();
                let mut seen: BTreeMap<KeyframeId, usize> = BTreeMap::new();
                let explorer = self.explorer.as_ref().expect("explored");
                for p in explorer.active().values() {
                    for &k in graph.point(*p).map(|p| p.observers()).into_iter().flatten() {
                        *seen.entry(k).or_default() += 1;
                    }
                }
                if let Some((k, _)) = seen
                    .into_iter()
                    .max_by_key(|&(k, n)| (n, std::cmp::Reverse(k)))
                {
                    self.reference = Some(k);
                }
            }
        }
        let state = match o.camera_from_world {
            None => StepState::Initialising(format!(
                "initialising: {n_tracks} corner tracks, {}",
                o.waiting.as_deref().unwrap_or("waiting")
            )),
            Some(_) if o.tracked < ctx.config.tracker.min_good => {
                StepState::Weak(format!("{} map points tracked", o.tracked))
            }
            Some(_) => StepState::Good,
        };
        // The bootstrap's two keyframes have no reason of the exploration's.
        let reason = match o.keyframe_reason.filter(|_| !first) {
            Some(r) => KeyframeReason::of_exploration(r, ctx.config.mono.keyframe_distance),
            None => KeyframeReason::First,
        };
        Step {
            state,
            camera_from_world: o.camera_from_world.map(|t| Sim3::from_se3(&t)),
            // Localising, frames are kept relative to a keyframe of the loaded map (nothing
            // moves it; the temporary ones are removed at the end).
            anchor: match self.loaded_anchor.filter(|_| self.localise) {
                Some(k) => Some((k, false)),
                None => last.map(|k| (k, o.keyframe == Some(k))),
            },
            keyframe: o
                .keyframe
                .filter(|_| temporary.is_none())
                .map(|k| (k, reason)),
            // The tracks are the candidates; the map points among them are measured (by LK,
            // or found again by guided search) and the motion-only BA keeps them all (Huber).
            stats: o.camera_from_world.map(|_| TrackerStats {
                candidates: n_tracks,
                visible: n_tracks,
                searched: o.tracked,
                found: o.tracked.max(refound),
                inliers: o.tracked,
            }),
            time_tracking: Duration::ZERO,
            relocalised: relocalised
                .filter(|_| o.camera_from_world.is_some())
                .map(|r| Relocalisation {
                    tracked: o.tracked,
                    ..r
                }),
            earlier_keyframe,
            // Set by the caller, which has the frame's tracks.
            observed: Vec::new(),
        }
    }

    /// A new keyframe `k` made from `frame`: its images (and the bootstrap's first frame's)
    /// into the store, the keyframe to the back-end.
    fn keyframe(
        &mut self,
        ctx: &mut Ctx,
        frame: &data::sequence::Frame,
        k: KeyframeId,
    ) -> Option<(usize, KeyframeId)> {
        let mut earlier = None;
        {
            let mut store = write_lock(ctx.store);
            if let Some(first) = self.bootstrap_first.take() {
                // The bootstrap makes its two keyframes one after the other.
                let k0 = KeyframeId::from_index(k.index() - 1);
                earlier = Some((first.frame_index, k0));
                store.insert(k0, first);
            }
            store.insert(k, keyframe_images(frame));
        }
        let map = ctx.graph.read().map_of(k).unwrap_or_default();
        let job = ctx.backend.loops.as_ref().map(|_| MonoLoopJob {
            keyframe: k,
            map,
            image: Arc::new(frame.gray().clone()),
            frame: frame.index,
        });
        self.windows.loop_job(ctx, job);
        earlier
    }

    /// The place of `frame` in the current map, changing nothing: its ORB words scored against
    /// the keyframe database, the best keyframes verified 2D–3D by P3P RANSAC against their
    /// points (depths regressed from their map points; `PlaceRecognition::relocalise`).
    /// Returns the frame's pose `camera_from_world` and what it was found by.
    fn verified_place(
        &self,
        ctx: &Ctx,
        frame: &data::sequence::Frame,
    ) -> Result<(Se3, Relocalisation), String> {
        let (Some(places), Some(explorer)) = (self.places.as_ref(), self.explorer.as_ref()) else {
            return Err("no map or no vocabulary".into());
        };
        let map = ctx.graph.read().current_map();
        let places = read_lock(places);
        let place = places.of(map).ok_or("no keyframe in the database")?;
        let features = extract_features(
            frame.gray(),
            |_, _| None,
            Vec::new(),
            &self.camera,
            places.config(),
        )
        .map_err(|e| e.to_string())?;
        let candidate = place
            .relocalise(frame.index as u32, &features)
            .ok_or("no keyframe's place verified")?;
        let old = ctx
            .graph
            .read()
            .pose(candidate.old)
            .map_err(|_| "the keyframe found is not in the map")?;
        // The verification's pose is rigid in the old keyframe's camera units, which are its
        // similarity's: composed with it, then made rigid as every mono pose.
        let pose = rigid_from_similarity(&candidate.query_from_old.compose(&old));
        Ok((
            pose,
            Relocalisation {
                frame: frame.index,
                keyframe: candidate.old,
                keyframe_frame: explorer.map().keyframe(candidate.old).frame,
                ransac_inliers: candidate.ransac_inliers,
                tracked: 0,
            },
        ))
    }

    /// Relocalises `frame` at `pose` ([`MonoSensor::verified_place`]): new corner tracks from
    /// this frame and the map points of the found keyframe's neighbourhood searched for around
    /// that pose (the guided search of `refind`, as on any frame). Accepted with at least
    /// `tracker.min_good` points found: the exploration goes on from the pose
    /// (`MonoExplorer::relocalise`) and the caller explores the frame's measurements.
    fn relocalise_at(
        &mut self,
        ctx: &mut Ctx,
        frame: &data::sequence::Frame,
        pose: Se3,
        relocalisation: &Relocalisation,
    ) -> Result<(Measurements, usize), String> {
        let Some(explorer) = self.explorer.as_mut() else {
            return Err("no map".into());
        };
        explorer.relocalise(frame.index, pose);
        self.reference = Some(relocalisation.keyframe);
        self.tracks.reset();
        let corners = frame_corners(ctx.config, frame.gray());
        let mut measurements: Measurements = match self.tracks.push(&corners) {
            Ok(Ok(tracks)) => tracks
                .iter()
                .map(|&(id, p)| (id, Vector2::new(p[0] as f64, p[1] as f64)))
                .collect(),
            _ => return Err("no corner tracks in this frame".into()),
        };
        let found = self.refind(ctx, frame.index, &corners, &mut measurements);
        if found < ctx.config.tracker.min_good {
            self.tracks.reset();
            self.reference = None;
            return Err(format!(
                "keyframe {} (frame {}) verified with {} inliers, but only {found} of its \
                 neighbourhood's map points found around the pose",
                relocalisation.keyframe.index(),
                relocalisation.keyframe_frame,
                relocalisation.ransac_inliers
            ));
        }
        Ok((measurements, found))
    }

    /// Checks every track that measures a map point against the point's template
    /// (`mono.verify_tracks`, [`relocate`]): the measurement moves to where the template aligns,
    /// within `tracker.search_radius` of the track, and the track with it; a track that no
    /// longer shows its point leaves the frame's measurements (the exploration then drops the
    /// association, the track goes on as a plain corner track); one the template cannot judge
    /// ([`Relocated::Unaligned`]) stays on probation for the frame's pose to judge
    /// (`MonoExplorer::suspect`), or leaves too with `mono.refuse_unaligned`. Returns
    /// how many were dropped.
    fn verify(
        &mut self,
        ctx: &Ctx,
        frame: usize,
        image: &GrayImage,
        measurements: &mut Measurements,
    ) -> usize {
        if !ctx.config.mono.verify_tracks {
            return 0;
        }
        let Some(explorer) = self.explorer.as_ref() else {
            return 0;
        };
        let Some(pose) = explorer.predicted_pose(frame) else {
            return 0;
        };
        let graph = ctx.graph.read();
        let store = read_lock(ctx.store);
        let active = explorer.active();
        let (radius, min_ncc) = (ctx.config.tracker.search_radius, ctx.config.tracker.min_ncc);
        let max_scale = ctx.config.mono.verify_within_scale;
        let refuse_unaligned = ctx.config.mono.refuse_unaligned;
        let before = measurements.len();
        let mut moved: Vec<(TrackId, [f32; 2])> = Vec::new();
        let mut suspects: Vec<TrackId> = Vec::new();
        measurements.retain_mut(|(track, z)| {
            let Some(&p) = active.get(track) else {
                return true;
            };
            // Without a template (its anchor's images are not kept) the track stands as is.
            let Some((sp, anchor)) = SearchPoint::from_graph(&graph, p)
                .and_then(|sp| store.get(sp.anchor).map(|a| (sp, a)))
            else {
                return true;
            };
            match relocate(
                &self.camera,
                &pose,
                &sp,
                anchor,
                image,
                *z,
                radius,
                min_ncc,
                max_scale,
            ) {
                Relocated::At(u) => {
                    *z = u;
                    moved.push((*track, [u.x as f32, u.y as f32]));
                    true
                }
                Relocated::Unaligned if !refuse_unaligned => {
                    suspects.push(*track);
                    true
                }
                Relocated::Unaligned | Relocated::Refused => false,
            }
        });
        drop((graph, store));
        for (track, p) in moved {
            self.tracks.correct(track, p);
        }
        if let Some(explorer) = self.explorer.as_mut() {
            suspects.into_iter().for_each(|t| explorer.suspect(t));
        }
        before - measurements.len()
    }

    /// The map points of the keyframes near the predicted pose that no track measures, with
    /// their predicted pixels (of the last keyframe's neighbourhood, or of the relocalisation's
    /// keyframe until the next keyframe).
    fn refind_candidates(
        &mut self,
        ctx: &Ctx,
        pose: &Se3,
        width: usize,
        height: usize,
    ) -> Vec<SearchPoint> {
        let config = ctx.config;
        let explorer = self.explorer.as_ref().expect("a map to refind in");
        let graph = ctx.graph.read();
        let max_angle = config.tracker.max_view_angle_deg.to_radians();
        let centre = |t: &Se3| t.inverse().act(&Vector3::zeros());
        let axis = |t: &Se3| t.rotation().inverse().act(&Vector3::z());
        let (c, a) = (centre(pose), axis(pose));
        // A scan of every keyframe of the neighbourhood (a few hundred here: microseconds); a
        // map of thousands would want a spatial index. A place revisited after a longer path
        // is a loop, closed by appearance and the Sim(3) correction.
        let map = graph.current_map();
        let edges: Vec<(KeyframeId, KeyframeId)> = self
            .accepted
            .get(&map)
            .map(|l| l.iter().map(|d| (d.current, d.old)).collect())
            .unwrap_or_default();
        let key = (explorer.map().keyframes.len(), edges.len(), self.reference);
        if self.neighbourhood.as_ref().is_none_or(|(k, _)| *k != key) {
            let start = self.reference.or_else(|| explorer.map_keyframes().last());
            let hood = covisible_neighbourhood(
                &graph,
                start,
                config.mapping.theta,
                config.mapping.n2,
                &edges,
            );
            self.neighbourhood = Some((key, hood));
        }
        let hood = &self.neighbourhood.as_ref().expect("set above").1;
        let mut near: Vec<(f64, KeyframeId)> = explorer
            .map_keyframes()
            .filter(|k| hood.contains(k))
            .filter_map(|k| {
                let t = rigid_pose(&graph, k);
                (axis(&t).angle(&a) <= max_angle).then(|| ((centre(&t) - c).norm(), k))
            })
            .collect();
        near.sort_by(|x, y| x.0.total_cmp(&y.0).then(x.1.cmp(&y.1)));
        near.truncate(config.mono.refind_keyframes);
        let keyframes: Vec<KeyframeId> = near.into_iter().map(|(_, k)| k).collect();
        let active: HashSet<_> = explorer.active().values().copied().collect();
        graph
            .points_visible_from(&keyframes)
            .into_iter()
            .filter(|p| !active.contains(p))
            .filter_map(|p| SearchPoint::from_graph(&graph, p))
            .filter(|sp| view_angle(pose, sp) <= max_angle)
            .filter(|sp| predict(&self.camera, pose, sp, width, height, PATCH_MARGIN_PX).is_some())
            .take(config.mono.max_refind)
            .collect()
    }

    /// Searches the map points of nearby keyframes that no track measures (`mono.refind`);
    /// each one found joins the frame's measurements — on the track already following that
    /// corner if it is not a feature, else on a new track — and is associated with its point in
    /// the exploration. Returns how many were found.
    fn refind(
        &mut self,
        ctx: &Ctx,
        frame: usize,
        corners: &FrameCorners,
        measurements: &mut Measurements,
    ) -> usize {
        let image = corners.image();
        let config = ctx.config;
        if !config.mono.refind {
            return 0;
        }
        let Some(pose) = self.explorer.as_ref().and_then(|e| e.predicted_pose(frame)) else {
            return 0;
        };
        let (w, h) = (image.width(), image.height());
        let todo = self.refind_candidates(ctx, &pose, w, h);
        if todo.is_empty() {
            return 0;
        }
        let corners = CornerIndex::new(
            corners.at(config.tracker.fast_threshold),
            w,
            h,
            CORNER_CELL_PX,
        );
        let radius = config.tracker.wide_search_radius;
        let store = read_lock(ctx.store);
        let graph = ctx.graph.read();
        let explorer = self.explorer.as_mut().expect("predicted above");
        let mut found = 0;
        for sp in todo {
            let Some(anchor) = store.get(sp.anchor) else {
                continue;
            };
            let Some(m) = search(
                &self.camera,
                &pose,
                &sp,
                anchor,
                image,
                &corners,
                radius,
                config.tracker.min_ncc,
                &mut self.scratch,
            ) else {
                continue;
            };
            // The corner may already be followed by a track: reuse it unless it is a feature
            // (then it measures another point or a filter, and this match is ambiguous).
            let existing = measurements
                .iter()
                .find(|(_, z)| (z - m).norm() < SAME_CORNER_PX)
                .map(|(t, _)| *t);
            let track = match existing {
                Some(t) if explorer.is_feature(t) => continue,
                Some(t) => t,
                None => {
                    let Some(t) = self.tracks.adopt([m.x as f32, m.y as f32]) else {
                        continue;
                    };
                    measurements.push((t, m));
                    t
                }
            };
            if explorer.associate(&graph, track, sp.point) {
                found += 1;
            }
        }
        found
    }
}

/// A mono keyframe's images: the grey image (the search's templates) and the colour.
fn keyframe_images(frame: &data::sequence::Frame) -> KeyframeImages {
    KeyframeImages {
        frame_index: frame.index,
        timestamp: frame.timestamp,
        gray: frame.gray().clone(),
        depth: None,
        colour: frame.colour().cloned(),
    }
}

/// A frame's FAST corners, detected once for both the corner selection
/// (`mono.fast_threshold`) and the guided search (`tracker.fast_threshold`).
fn frame_corners<'a>(config: &SystemConfig, image: &'a GrayImage) -> FrameCorners<'a> {
    FrameCorners::new(
        image,
        config
            .mono
            .fast_threshold
            .min(config.tracker.fast_threshold),
    )
}

/// The keyframes within the first `limit` of a breadth-first search from `start` over the
/// covisibility graph (keyframes sharing at least `theta` points, and consecutive ones of one
/// map) and the accepted `loops`: the monocular `N2` (thesis §6.4.1).
fn covisible_neighbourhood(
    graph: &SlamGraph<2>,
    start: Option<KeyframeId>,
    theta: usize,
    limit: usize,
    loops: &[(KeyframeId, KeyframeId)],
) -> HashSet<KeyframeId> {
    let mut seen = HashSet::new();
    let Some(last) = start.filter(|&k| graph.keyframe(k).is_some()) else {
        return seen;
    };
    let map = graph.map_of(last).ok();
    let mut queue = std::collections::VecDeque::from([last]);
    seen.insert(last);
    while let Some(k) = queue.pop_front() {
        if graph.keyframe(k).is_none() {
            continue;
        }
        let mut next: Vec<(usize, KeyframeId)> = loops::shared_points(graph, k)
            .into_iter()
            .filter(|&(o, n)| o != k && n >= theta)
            .map(|(o, n)| (n, o))
            .collect();
        for j in [k.index().checked_sub(1), Some(k.index() + 1)]
            .into_iter()
            .flatten()
            .map(KeyframeId::from_index)
            .filter(|&j| graph.map_of(j).ok() == map)
        {
            next.push((usize::MAX, j));
        }
        for &(a, b) in loops {
            if a == k {
                next.push((usize::MAX, b));
            } else if b == k {
                next.push((usize::MAX, a));
            }
        }
        next.sort_by(|x, y| y.cmp(x));
        for (_, o) in next {
            if seen.len() >= limit {
                return seen;
            }
            if seen.insert(o) {
                queue.push_back(o);
            }
        }
    }
    seen
}

impl Sensor<2> for MonoSensor {
    type Frame = data::sequence::Frame;
    type OptimiserData = slam::exploration::SolvedWindow;
    type Optimiser = window::MonoWindow;
    type LoopData = MonoLoopData;
    type Loops = MonoLoops;

    fn prepare(
        &mut self,
        _: &mut Ctx,
        frame: data::sequence::Frame,
    ) -> Result<data::sequence::Frame, SystemError> {
        Ok(frame)
    }

    fn track(&mut self, ctx: &mut Ctx, frame: &data::sequence::Frame) -> Result<Step, SystemError> {
        let start = Instant::now();
        if let Some(lost) = &self.lost {
            return Ok(Step::untracked(
                StepState::Lost(format!("lost at frame {} ({})", lost.frame, lost.why)),
                Duration::ZERO,
            ));
        }
        let corners = frame_corners(ctx.config, frame.gray());
        let followed = self.follow_tracks(ctx, frame, &corners)?;
        // The last keyframe's window, solved meanwhile, into the map this frame reads.
        self.windows.settle(ctx, self.explorer.as_mut());
        let mut measurements = match followed {
            Ok(m) => m,
            Err(state) => return Ok(Step::untracked(state, start.elapsed())),
        };
        let t = Instant::now();
        self.verify(ctx, frame.index, frame.gray(), &mut measurements);
        if self.explorer.is_some() && ctx.config.mono.verify_tracks {
            ctx.timings.record("mono: verify tracks", t.elapsed());
        }
        let t = Instant::now();
        let refound = self.refind(ctx, frame.index, &corners, &mut measurements);
        if self.explorer.is_some() && ctx.config.mono.refind {
            ctx.timings.record("mono: re-find map points", t.elapsed());
        }
        self.explore(ctx, frame, measurements, refound, None, start)
    }

    /// ORB-SLAM's relocalisation (Mur-Artal et al. 2015) with this system's stages:
    /// [`MonoSensor::verified_place`], then [`MonoSensor::relocalise_at`] its pose, then the
    /// exploration of the frame from there.
    fn relocalise(
        &mut self,
        ctx: &mut Ctx,
        frame: &data::sequence::Frame,
    ) -> Result<Found, SystemError> {
        self.windows.settle(ctx, self.explorer.as_mut());
        if !self.relocalisable(ctx.config) {
            return Ok(Found::Nothing(String::new()));
        }
        let start = Instant::now();
        let (pose, relocalisation) = match self.verified_place(ctx, frame) {
            Ok(found) => found,
            Err(why) => return Ok(Found::Nothing(why)),
        };
        // A frame waited out that shows a mapped place: the camera jumped there.
        if self.lost.is_none() {
            self.lose(
                frame.index,
                "the camera jumped to another place of the map".into(),
            );
        }
        let (measurements, found) = match self.relocalise_at(ctx, frame, pose, &relocalisation) {
            Ok(m) => m,
            Err(why) => return Ok(Found::Nothing(why)),
        };
        let step = self.explore(ctx, frame, measurements, found, Some(relocalisation), start)?;
        Ok(Found::Place(Box::new(Step {
            time_tracking: Duration::ZERO,
            ..step
        })))
    }

    fn can_recover(&self) -> bool {
        self.places.is_some()
            && self
                .explorer
                .as_ref()
                .is_some_and(|e| e.map_keyframes().nth(1).is_some())
    }

    /// A new map, in a map of its own (`MonoExplorer::start_map`): its bootstrap starts at the
    /// next frame (the corner tracks start there afresh; this frame, lost, is one they could
    /// not follow into more often than not).
    fn start_map(
        &mut self,
        ctx: &mut Ctx,
        _frame: &data::sequence::Frame,
        lost_for: f64,
    ) -> Result<Option<Step>, SystemError> {
        self.windows.settle(ctx, self.explorer.as_mut());
        if self.localise {
            return Ok(None);
        }
        if let Some(explorer) = self.explorer.as_mut() {
            explorer.start_map(&mut ctx.graph.write());
        }
        self.tracks.reset();
        self.lost = None;
        self.refused = 0;
        self.reference = None;
        self.neighbourhood = None;
        self.bootstrapping = true;
        Ok(Some(Step::untracked(
            StepState::Initialising(format!(
                "lost for {lost_for:.1} s: a new map starts at the next frame"
            )),
            Duration::ZERO,
        )))
    }

    /// A keyframe's window BA solved in the back-end's thread, polled by the session: written
    /// back at once ([`window`]).
    fn optimised(&mut self, ctx: &mut Ctx, solved: slam::exploration::SolvedWindow) {
        self.windows.solved(ctx, self.explorer.as_mut(), solved);
    }

    /// An accepted loop joins the map's loops (the `refind` neighbourhood, the correction at
    /// the end); a live correction (`mono.correct_live`) is written into the graph, and the
    /// exploration goes on in the corrected map (`MonoExplorer::correct_map`: the motion
    /// model and the last pose follow the last keyframe).
    fn loop_data(&mut self, ctx: &mut Ctx, data: MonoLoopData) {
        // A loop's correction moves the keyframes a window being solved reads.
        self.windows.settle(ctx, self.explorer.as_mut());
        match data {
            MonoLoopData::Accepted(d) => {
                let map = ctx.graph.read().map_of(d.current).unwrap_or_default();
                self.accepted.entry(map).or_default().push(d);
            }
            MonoLoopData::Corrected(correction) => {
                let t = Instant::now();
                let mut graph = ctx.graph.write();
                let result = match self.explorer.as_mut() {
                    Some(explorer) if graph.current_map() == correction.map => {
                        explorer.correct_map(&mut graph, |g| correction.apply(g))
                    }
                    _ => correction.apply(&mut graph),
                };
                if let Err(e) = result {
                    ctx.warnings.push(format!("live loop correction: {e}"));
                }
                // Counted applied even if it failed: the loop stage may solve the next one.
                self.corrections_applied
                    .fetch_add(1, std::sync::atomic::Ordering::Release);
                ctx.timings
                    .record("loop: live correction applied", t.elapsed());
            }
        }
    }

    /// The loops correct each map through the pose graph of its keyframe chain, the loops and
    /// the covisibility edges ([`map_edges`]), in `mono.loop_correction`'s group; the other
    /// group's correction is an alternative (unless corrected live: the map holds the primary
    /// group's correction already, and the other's would start from it). A graph of one map is
    /// then bundle adjusted ([`MonoSensor::refine`]).
    fn finish(&mut self, ctx: &mut Ctx, _interrupted: bool) -> Result<Finished<2>, SystemError> {
        self.windows.settle(ctx, self.explorer.as_mut());
        if let Some(explorer) = self.explorer.as_mut().filter(|_| self.localise) {
            let removed = explorer.remove_temporary(&mut ctx.graph.write());
            if !removed.is_empty() {
                let mut store = write_lock(ctx.store);
                for k in &removed {
                    store.remove(*k);
                }
                ctx.warnings.push(format!(
                    "localising: {} temporary keyframes bridged views the map does not cover \
                     (removed at the end: the map is as loaded)",
                    removed.len()
                ));
            }
        }
        let graph = ctx.graph.snapshot();
        let (primary, other) = correction_groups(ctx.config.mono.loop_correction);
        let maps: Vec<usize> = graph
            .keyframes_per_map()
            .into_iter()
            .map(|(m, _)| m)
            .collect();
        let single_map = maps.len() == 1;
        let mut corrected = graph.clone();
        let mut alternative = (!ctx.config.mono.correct_live).then(|| graph.clone());
        let mut any = false;
        for map in maps {
            let Some(loops) = self.accepted.get(&map).filter(|l| !l.is_empty()) else {
                continue;
            };
            any = true;
            let dwo = ctx.config.double_window(self.camera.fx, None);
            let (edges, chain) = map_edges(&graph, map, loops, ctx.config.mapping.theta, &dwo);
            let t = Instant::now();
            if let Err(e) = correct_loops(
                &mut corrected,
                map,
                (&edges, &chain),
                primary,
                lie::LogJacobian::Exact,
            ) {
                ctx.warnings
                    .push(format!("loop correction of map {map} in {primary:?}: {e}"));
                // The map stays as it was.
                for (k, kf) in graph.keyframes().filter(|(_, kf)| kf.map() == map) {
                    let _ = corrected.set_pose(k, *kf.camera_from_world());
                }
            }
            if let Some(g) = alternative.as_mut()
                && let Err(e) =
                    correct_loops(g, map, (&edges, &chain), other, lie::LogJacobian::Exact)
            {
                ctx.warnings
                    .push(format!("loop correction of map {map} in {other:?}: {e}"));
            }
            ctx.timings
                .record("loop: correction at the end", t.elapsed());
        }
        // The thesis's loop closure ends in bundle adjustment (ch. 5: the Sim(3) pose graph
        // brings the map near its optimum, BA on the points' measurements finishes; ORB-SLAM's
        // global BA after a loop does the same): structure-only, then full BA of the map, the
        // first two keyframes fixed, ten iterations, one thread. After the run it took
        // 0.7–1.8 s and gave the rendered building 9.15 → 8.20 cm (SE(3) corrected and
        // adjusted alike: 18.8 cm), the courtyard 3.38 → 2.56 cm, the town 60.5 → 59.9 cm and
        // 98.8 → 98.9 cm (bench/README, eighteenth session). Only a graph of one map: maps not
        // joined each have a gauge of their own.
        if any && single_map {
            let t = Instant::now();
            for (graph, what) in std::iter::once((&mut corrected, primary))
                .chain(alternative.as_mut().map(|g| (g, other)))
            {
                if let Err(e) = self.refine(graph) {
                    ctx.warnings.push(format!(
                        "bundle adjustment after the {what:?} correction: {e}"
                    ));
                }
            }
            ctx.timings
                .record("loop: bundle adjustment at the end", t.elapsed());
        }
        let name = match other {
            CorrectionGroup::Sim3 => "trajectory_final_sim3",
            CorrectionGroup::Se3 => "trajectory_final_se3",
        };
        Ok(Finished {
            graph: corrected,
            alternatives: alternative
                .filter(|_| any)
                .map(|g| vec![(name, g)])
                .unwrap_or_default(),
        })
    }

    fn run_graph(graph: SlamGraph<2>) -> RunGraph {
        RunGraph::Mono(graph)
    }

    fn place_features(&self) -> Vec<(KeyframeId, KeyframeFeatures)> {
        self.places.as_ref().map_or_else(Vec::new, |places| {
            let mut all: Vec<_> = read_lock(places)
                .entries()
                .map(|(k, f)| (k, f.clone()))
                .collect();
            all.sort_by_key(|(k, _)| *k);
            all
        })
    }

    /// A loaded map: its keyframes' features into their maps' databases, the exploration
    /// resumed on its graph (`MonoExplorer::resume`), the camera lost until relocalised there.
    fn restore(
        &mut self,
        ctx: &mut Ctx,
        features: Vec<(KeyframeId, KeyframeFeatures)>,
        localise: bool,
    ) -> Result<(), SystemError> {
        let Some(places) = &self.places else {
            return Err(SystemError::map_without_vocabulary());
        };
        let graph = ctx.graph.read();
        let store = read_lock(ctx.store);
        {
            let mut places = write_lock(places);
            for (k, f) in features {
                let map = graph.map_of(k).unwrap_or_default();
                places.insert(map, k, f).map_err(SystemError::Unsupported)?;
            }
        }
        let Some((_, first)) = store.iter().next() else {
            return Ok(());
        };
        let config =
            ctx.config
                .exploration(self.camera.fx, first.gray.width(), first.gray.height());
        let frame_of = |k: KeyframeId| store.get(k).map_or(usize::MAX, |i| i.frame_index);
        self.explorer = Some(MonoExplorer::resume(
            self.camera,
            config,
            &graph,
            frame_of,
            localise,
        ));
        self.localise = localise;
        let current = graph.current_map();
        self.loaded_anchor = graph
            .keyframes()
            .filter(|(_, kf)| kf.map() == current)
            .map(|(k, _)| k)
            .last();
        self.bootstrapping = false;
        self.lost = Some(Lost {
            frame: 0,
            why: "not found in the loaded map yet".into(),
        });
        Ok(())
    }
}
