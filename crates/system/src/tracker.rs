//! The per-frame tracker (thesis §6.3): a pose prior from dense photometric alignment against
//! the last frame with depth (eq. 6.7), the candidate points of the reference keyframe's
//! neighbourhood `N1` (§6.2.5) with PTAM's visibility tests, guided patch search in a small
//! radius around their predictions, and robust motion-only BA (eq. 4.15) — with a tracking
//! state per frame.
//!
//! The graph is read under its lock only to copy the candidates out; the search and the
//! optimisation run without it.

use crate::config::TrackerConfig;
use crate::frame::FrameData;
use crate::keyframes::KeyframeStore;
use crate::observed::{Observed, ObservedState};
use crate::search::{SearchPoint, SearchScratch, predict, search, view_angle};
use data::output::TrackingState;
use geom::StereoCamera;
use lie::{LieGroup, Se3, Sim3};
use nalgebra::{SVector, Vector2, Vector3, Vector6};
use slam::map::{KeyframeId, PointId, SharedGraph, SlamGraph, Version};
use slam::tracking::{MotionOnlyOptions, PoseProblem, tracking_candidates};
use std::collections::HashMap;
use std::sync::Arc;
use std::time::{Duration, Instant};
use vision::dense::{DenseParams, align_pyramids};
use vision::quadtree::{QuadPoint, QuadTree};

/// Where the pose prior of a frame came from.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Prior {
    /// Dense photometric alignment (thesis eq. 6.7): good to a pixel or two.
    Dense,
    /// Constant velocity only (dense alignment failed or there was no frame with depth): the
    /// search radius widens.
    ConstantVelocity,
}

/// Counts of one frame's tracking.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct TrackerStats {
    /// Candidate points of `N1`.
    pub candidates: usize,
    /// Candidates passing the visibility tests.
    pub visible: usize,
    /// Candidates searched (at most the configured number, spread over the image).
    pub searched: usize,
    /// Candidates found.
    pub found: usize,
    /// Matches consistent with the pose after motion-only BA.
    pub inliers: usize,
}

/// One frame's tracking.
#[derive(Clone, Debug)]
pub struct Tracked {
    /// The estimated pose.
    pub camera_from_world: Sim3,
    /// How well it was tracked.
    pub state: TrackingState,
    /// The inlier matches with stereo measurements `(u, v, u_r)` (what a keyframe observes).
    pub matches: Vec<(PointId, Vector3<f64>)>,
    /// The reference keyframe it was tracked against.
    pub reference: KeyframeId,
    /// When it was tracked, as the graph was then: the reference's pose, the graph's version,
    /// the map merges seen and the reference's map. Another thread may move the map before
    /// the pose is recorded or made a keyframe (an optimisation, a merge); the pose is in the
    /// frame of the map as it was then.
    pub then: TrackedThen,
    /// Median depth of the found points (metres), for the keyframe criterion.
    pub median_depth: f64,
    /// Counts.
    pub stats: TrackerStats,
    /// Time per stage.
    pub timings: Vec<(&'static str, Duration)>,
    /// The points searched, found and kept, for a live view ([`Tracker::observe`]; empty
    /// otherwise).
    pub observed: Vec<Observed>,
}

/// The graph as a frame was tracked against it ([`Tracked::then`]).
#[derive(Clone, Copy, Debug)]
pub struct TrackedThen {
    /// The reference keyframe's pose.
    pub reference_pose: Sim3,
    /// The graph's version.
    pub version: Version,
    /// How many map merges the graph had made (`SlamGraph::merges`).
    pub merges: usize,
    /// The reference keyframe's map.
    pub map: usize,
}

/// The last frame with depth: the reference of the next dense alignment.
#[derive(Clone)]
struct DenseReference {
    frame: Arc<FrameData>,
    camera_from_world: Se3,
}

/// The per-frame tracker (see the [module docs](self)).
pub struct Tracker {
    config: TrackerConfig,
    sigma: f64,
    camera: StereoCamera,
    motion: Motion,
    scratch: SearchScratch,
    /// The graph's map merges seen ([`slam::map::SlamGraph::merges`]).
    merges_seen: usize,
    /// Per map point, how often a well-tracked frame searched it and found it (an inlier);
    /// `None` unless they are asked for ([`Tracker::record_findings`]: `keyframes.cull_points`),
    /// so that no frame pays for records nobody reads.
    findings: Option<HashMap<PointId, (u32, u32)>>,
    /// Report each frame's searched points ([`Tracked::observed`]).
    observe: bool,
}

/// The searched candidates `selected` (at their predicted positions) as not found, unless
/// `found` (at the position found), kept by the motion-only BA if among `inliers` (candidate
/// indices all three).
fn observed(
    selected: &[(usize, Vector2<f64>)],
    found: &[(usize, Vector2<f64>)],
    inliers: &[usize],
) -> Vec<Observed> {
    let uv = |u: &Vector2<f64>| [u.x as f32, u.y as f32];
    let found_at: HashMap<usize, &Vector2<f64>> = found.iter().map(|(i, u)| (*i, u)).collect();
    let kept: std::collections::HashSet<usize> = inliers.iter().copied().collect();
    selected
        .iter()
        .map(|(i, predicted)| match found_at.get(i) {
            Some(u) => Observed {
                uv: uv(u),
                state: if kept.contains(i) {
                    ObservedState::Inlier
                } else {
                    ObservedState::Outlier
                },
            },
            None => Observed {
                uv: uv(predicted),
                state: ObservedState::NotFound,
            },
        })
        .collect()
}

/// The one-sided 95 % quantile of the standard normal (the evidence [`Tracker::unfound_points`]
/// asks for).
const Z_95: f64 = 1.645;

/// What the tracker carries from frame to frame: the motion model and the dense reference
/// ([`Tracker::motion`], to try something and go back).
#[derive(Clone)]
pub struct Motion {
    /// The last frame's stamp and pose.
    last: Option<(Stamp, Se3)>,
    /// Motion per second, `log(T_k·T_{k−1}⁻¹)/Δt` ([`Motion::elapsed`]).
    velocity: Vector6<f64>,
    /// Seconds per frame of the sequence, from the last step whose timestamps increased (by
    /// at least [`Motion::MIN_STEP`]; a gap the reader numbered on counts as one long frame);
    /// the time of a step whose timestamps do not.
    period: f64,
    dense_reference: Option<DenseReference>,
    /// The map whose frame the poses are in (`None` before the first frame is tracked after a
    /// restart): a merge of that map into another moves them with it.
    map: Option<usize>,
    /// The last frame was lost: the next must fit the map well (a good frame) to count as
    /// tracked again.
    recovering: bool,
}

/// When a frame was taken: its position in the sequence and its timestamp (seconds).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Stamp {
    /// Position in the sequence.
    pub index: usize,
    /// Seconds.
    pub time: f64,
}

impl Stamp {
    /// `frame`'s stamp.
    pub fn of(frame: &FrameData) -> Self {
        Stamp {
            index: frame.index,
            time: frame.timestamp,
        }
    }
}

impl Motion {
    /// Seconds per frame before a step with increasing timestamps has been seen (a 30 Hz
    /// camera): the time of a step whose timestamps do not increase, until one does.
    const DEFAULT_PERIOD: f64 = 1.0 / 30.0;

    /// The shortest time between two frames taken as a clock reading (seconds): no camera
    /// here runs above 1 kHz; a shorter step is a duplicated or broken timestamp, and dividing
    /// a frame's motion by it would predict the next frame thousands of times too far.
    const MIN_STEP: f64 = 1e-3;

    /// The motion model at rest from `last` (nothing yet: `None`): no velocity, no dense
    /// reference, not recovering.
    fn starting(last: Option<(Stamp, Se3)>) -> Self {
        Motion {
            last,
            velocity: Vector6::zeros(),
            period: Self::DEFAULT_PERIOD,
            dense_reference: None,
            map: None,
            recovering: false,
        }
    }

    /// Moves the poses with their map when it is merged into map `into`, by `moved` (the
    /// transform every keyframe of it took, `T ← T·moved`). The velocity, a motion in the
    /// camera frame, stays.
    fn follow(&mut self, moved: &Sim3, into: usize) {
        let moved = |t: &Se3| Sim3::from_se3(t).compose(moved).rigid_part();
        if let Some((_, last)) = &mut self.last {
            *last = moved(last);
        }
        if let Some(r) = &mut self.dense_reference {
            r.camera_from_world = moved(&r.camera_from_world);
        }
        self.map = Some(into);
    }

    /// Seconds from `from` to `to`: their timestamps' difference, or where that is below
    /// [`Motion::MIN_STEP`] (a broken clock) the frames between them at the last period seen.
    ///
    /// Time rather than frame count: a recording that dropped frames (a driver that fell
    /// behind, a gap cut out of a sequence) keeps its timestamps, and the camera moved for
    /// the whole gap. Counting frames, a car at 12 m/s is predicted 1.2 m ahead after a gap
    /// of a second instead of 13 m, where the guided search can match the wrong stretch of
    /// road (seen on KITTI with ten frames removed: tracked 11 m short, "weak", for the rest
    /// of the run).
    fn elapsed(&self, from: Stamp, to: Stamp) -> f64 {
        let dt = to.time - from.time;
        if dt.is_finite() && dt >= Self::MIN_STEP {
            dt
        } else {
            to.index.saturating_sub(from.index).max(1) as f64 * self.period
        }
    }

    /// The constant-velocity pose at `to`.
    fn predict(&self, to: Stamp) -> Option<Se3> {
        let (from, last) = self.last?;
        Some(Se3::exp(&(self.velocity * self.elapsed(from, to))).compose(&last))
    }

    /// Records `pose` at `to`: the velocity of the step from the last pose, the period.
    fn advance(&mut self, to: Stamp, pose: Se3) {
        if let Some((from, last)) = self.last {
            let dt = self.elapsed(from, to);
            self.velocity = pose.compose(&last.inverse()).log() / dt;
            let frames = to.index.saturating_sub(from.index);
            if to.time - from.time >= Self::MIN_STEP && frames > 0 {
                self.period = (to.time - from.time) / frames as f64;
            }
        }
        self.last = Some((to, pose));
    }
}

impl Tracker {
    /// A tracker for `camera` (the sensor's stereo or virtual stereo camera) with measurement
    /// noise `sigma` pixels.
    pub fn new(config: TrackerConfig, camera: StereoCamera, sigma: f64) -> Self {
        Tracker {
            config,
            sigma,
            camera,
            motion: Motion::starting(None),
            scratch: SearchScratch::default(),
            merges_seen: 0,
            findings: None,
            observe: false,
        }
    }

    /// Records `frame`'s pose in map `map` as known (the first keyframe of a map), the start of
    /// the motion model.
    pub fn set_pose(&mut self, frame: &Arc<FrameData>, camera_from_world: Se3, map: usize) {
        self.motion.last = Some((Stamp::of(frame), camera_from_world));
        self.motion.velocity = Vector6::zeros();
        self.motion.map = Some(map);
        if frame.depth.is_some() {
            self.motion.dense_reference = Some(DenseReference {
                frame: frame.clone(),
                camera_from_world,
            });
        }
    }

    /// The motion model and dense reference as they are now.
    pub fn motion(&self) -> Motion {
        self.motion.clone()
    }

    /// Whether the tracker has had a pose (a run on a loaded map starts without one).
    pub fn has_pose(&self) -> bool {
        self.motion.last.is_some()
    }

    /// Puts back a [`Tracker::motion`].
    pub fn set_motion(&mut self, motion: Motion) {
        self.motion = motion;
    }

    /// Restarts the motion model at `frame` with `camera_from_world` (a relocalisation): no
    /// velocity and no dense reference, so [`Tracker::track`] of that frame searches around
    /// this pose with the wide radius of a constant-velocity prior.
    pub fn restart(&mut self, frame: &FrameData, camera_from_world: Se3) {
        let period = self.motion.period;
        self.motion = Motion::starting(Some((Stamp::of(frame), camera_from_world)));
        self.motion.period = period;
    }

    /// Forgets the velocity (after a relocalisation the motion between frames is unknown: the
    /// last "motion" is the step from the relocalised pose to the tracked one).
    pub fn reset_velocity(&mut self) {
        self.motion.velocity = Vector6::zeros();
    }

    /// Applies the graph's map merges not seen yet to the motion model; returns the transform
    /// its poses took (`T ← T·moved`), if any.
    fn follow_merges(&mut self, graph: &SlamGraph<3>) -> Option<Sim3> {
        let seen = std::mem::replace(&mut self.merges_seen, graph.merges().len());
        let (moved, into) = graph.moved_since(seen, self.motion.map?)?;
        self.motion.follow(&moved, into);
        Some(moved)
    }

    /// Tracks `frame` against the map, in stages: the dense prior, the candidates of `N1`
    /// and their visibility, the guided search, the robust motion-only BA, the state, and the
    /// motion model moved on.
    pub fn track(
        &mut self,
        graph: &SharedGraph<3>,
        store: &KeyframeStore,
        frame: &Arc<FrameData>,
    ) -> Option<Tracked> {
        let mut timings = Vec::new();
        // The constant-velocity prediction over the time since the last frame (dropped frames
        // bridged: Motion::elapsed).
        let predicted = self.motion.predict(Stamp::of(frame))?;
        let t = Instant::now();
        let (mut pose_prior, prior) = self.dense_prior(frame, predicted);
        timings.push(("track: dense prior", t.elapsed()));
        let t = Instant::now();
        let candidates = self.candidates(graph, &mut pose_prior)?;
        let mut stats = TrackerStats {
            candidates: candidates.points.len(),
            ..TrackerStats::default()
        };
        let selected = self.visible(frame, &candidates.points, &pose_prior, &mut stats);
        timings.push(("track: candidates", t.elapsed()));
        let t = Instant::now();
        let found = self.guided_search(
            frame,
            store,
            &candidates.points,
            &selected,
            &pose_prior,
            prior,
        );
        stats.found = found.len();
        timings.push(("track: guided search", t.elapsed()));
        let t = Instant::now();
        let fit = self.motion_only_ba(frame, &candidates, &found, &pose_prior);
        timings.push(("track: motion-only BA", t.elapsed()));
        stats.inliers = fit.inliers.len();
        let state = self.state(&fit, &stats, found.len(), selected.len(), prior);
        let camera_from_world = match state {
            TrackingState::Lost(_) => Sim3::from_se3(&pose_prior),
            _ => fit.pose,
        };
        let points = &candidates.points;
        let stereo_of: std::collections::BTreeMap<usize, Vector3<f64>> =
            fit.stereo.iter().copied().collect();
        let matches: Vec<(PointId, Vector3<f64>)> = fit
            .inliers
            .iter()
            .filter_map(|i| stereo_of.get(i).map(|z| (points[*i].point, *z)))
            .collect();
        let mut depths: Vec<f64> = fit
            .inliers
            .iter()
            .map(|&i| camera_from_world.rigid_part().act(&points[i].world).z)
            .filter(|z| *z > 0.0)
            .collect();
        depths.sort_by(f64::total_cmp);
        let median_depth = depths.get(depths.len() / 2).copied().unwrap_or(f64::NAN);
        if let Some(findings) = self
            .findings
            .as_mut()
            .filter(|_| state == TrackingState::Good)
        {
            for (i, _) in &selected {
                findings.entry(points[*i].point).or_default().0 += 1;
            }
            for i in &fit.inliers {
                findings.entry(points[*i].point).or_default().1 += 1;
            }
        }
        let observed = if self.observe {
            observed(&selected, &found, &fit.inliers)
        } else {
            Vec::new()
        };
        self.advance(frame, &camera_from_world, &state);
        Some(Tracked {
            camera_from_world,
            state,
            matches,
            reference: candidates.reference,
            then: candidates.then,
            median_depth,
            stats,
            timings,
            observed,
        })
    }

    /// Report (or stop reporting) each frame's searched points, where they were found and
    /// whether the motion-only BA kept them ([`Tracked::observed`]), for a live view.
    pub fn observe(&mut self, on: bool) {
        self.observe = on;
    }

    /// Keep (or stop keeping) the records [`Tracker::unfound_points`] judges from.
    pub fn record_findings(&mut self, on: bool) {
        if on != self.findings.is_some() {
            self.findings = on.then(HashMap::new);
        }
    }

    /// The map points tracking no longer finds: searched `n` times by well-tracked frames and
    /// found `f` times, with `f < q·n − z·√(n·q·(1 − q))` — a binomial test at 95 % that the
    /// point is found in fewer than `q` of the frames that look for it, `q` the fraction of its
    /// points a view must find not to call for a keyframe (`keyframes.min_found_fraction`): such
    /// a point fails more often than the map is allowed to fail as a whole (a duplicate, an
    /// occluded or unstable corner). Forgotten here once returned; the records of points gone
    /// from `graph` are dropped.
    pub fn unfound_points(&mut self, graph: &SlamGraph<3>, q: f64) -> Vec<PointId> {
        let mut out = Vec::new();
        let Some(findings) = self.findings.as_mut() else {
            return out;
        };
        findings.retain(|&p, &mut (n, f)| {
            if graph.point(p).is_none() {
                return false;
            }
            let n = n as f64;
            let failing = (f as f64) < q * n - Z_95 * (n * q * (1.0 - q)).sqrt();
            if failing {
                out.push(p);
            }
            !failing
        });
        out.sort();
        out
    }

    /// The pose prior (thesis eq. 6.7): dense alignment against the last frame with depth,
    /// from the constant-velocity `predicted` pose; that prediction where alignment fails.
    fn dense_prior(&self, frame: &FrameData, predicted: Se3) -> (Se3, Prior) {
        let Some(reference) = &self.motion.dense_reference else {
            return (predicted, Prior::ConstantVelocity);
        };
        let params = DenseParams {
            levels: self.config.pyramid_levels,
            finest_level: self.config.dense_finest_level,
            max_iterations: self.config.dense_iterations,
            ..DenseParams::default()
        };
        let initial = predicted.compose(&reference.camera_from_world.inverse());
        if let Some(depth) = &reference.frame.depth
            && let Ok(r) = align_pyramids(
                &reference.frame.pyramid,
                depth,
                &frame.pyramid,
                &self.camera.pinhole,
                &initial,
                &params,
            )
            && r.num_residuals >= 100
            && r.final_cost.is_finite()
        {
            return (
                r.cur_from_ref.compose(&reference.camera_from_world),
                Prior::Dense,
            );
        }
        (predicted, Prior::ConstantVelocity)
    }

    /// The candidate points of `N1(ref)`, copied out under the graph's read lock with the
    /// reference and the graph as it was. Poses whose map was merged into another since the
    /// last frame (or meanwhile, by the loop-closure thread) move with it, `pose_prior` too.
    fn candidates(&mut self, graph: &SharedGraph<3>, pose_prior: &mut Se3) -> Option<Candidates> {
        let g = graph.read();
        if let Some(moved) = self.follow_merges(&g) {
            *pose_prior = Sim3::from_se3(pose_prior).compose(&moved).rigid_part();
        }
        let reference = g.reference()?;
        let map = g.map_of(reference).ok()?;
        self.motion.map = Some(map);
        let t_ref = g.pose(reference).ok()?;
        let points: Vec<SearchPoint> = tracking_candidates(&g, reference)
            .into_iter()
            .filter_map(|p| SearchPoint::from_graph(&g, p))
            .collect();
        let then = TrackedThen {
            reference_pose: t_ref,
            version: g.version(),
            merges: g.merges().len(),
            map,
        };
        Some(Candidates {
            reference,
            t_ref,
            points,
            then,
        })
    }

    /// The candidates that pass PTAM's visibility tests at `pose_prior` (in the image, in
    /// front, not seen from too different a view), at most `max_searched` of them spread over
    /// the image (thesis Alg. 2): `(candidate, predicted pixel)`.
    fn visible(
        &self,
        frame: &FrameData,
        points: &[SearchPoint],
        pose_prior: &Se3,
        stats: &mut TrackerStats,
    ) -> Vec<(usize, Vector2<f64>)> {
        let (w, h) = (frame.gray().width(), frame.gray().height());
        let max_angle = self.config.max_view_angle_deg.to_radians();
        let visible: Vec<(usize, Vector2<f64>)> = points
            .iter()
            .enumerate()
            .filter_map(|(i, p)| {
                let (u, _) = predict(&self.camera.pinhole, pose_prior, p, w, h, 6.0)?;
                (view_angle(pose_prior, p) < max_angle).then_some((i, u))
            })
            .collect();
        stats.visible = visible.len();
        let selected = if visible.len() > self.config.max_searched {
            let quad: Vec<QuadPoint> = visible
                .iter()
                .enumerate()
                .map(|(k, (_, u))| QuadPoint {
                    u: u.x as f32,
                    v: u.y as f32,
                    score: 0.0,
                    index: k,
                })
                .collect();
            QuadTree::from_points(w as f32, h as f32, 2.0, &quad)
                .select(self.config.max_searched, frame.index as u64)
                .into_iter()
                .map(|q| visible[q.index])
                .collect()
        } else {
            visible
        };
        stats.searched = selected.len();
        selected
    }

    /// Guided search (thesis §6.3) of the `selected` candidates around `pose_prior`, in the
    /// small radius after a dense prior, the wide one after constant velocity only.
    fn guided_search(
        &mut self,
        frame: &FrameData,
        store: &KeyframeStore,
        points: &[SearchPoint],
        selected: &[(usize, Vector2<f64>)],
        pose_prior: &Se3,
        prior: Prior,
    ) -> Vec<(usize, Vector2<f64>)> {
        let radius = match prior {
            Prior::Dense => self.config.search_radius,
            Prior::ConstantVelocity => self.config.wide_search_radius,
        };
        let mut found: Vec<(usize, Vector2<f64>)> = Vec::with_capacity(selected.len());
        for (i, _) in selected {
            let p = &points[*i];
            let Some(anchor) = store.get(p.anchor) else {
                continue;
            };
            if let Some(u) = search(
                &self.camera.pinhole,
                pose_prior,
                p,
                anchor,
                frame.gray(),
                &frame.corners,
                radius,
                self.config.min_ncc,
                &mut self.scratch,
            ) {
                found.push((*i, u));
            }
        }
        found
    }

    /// Robust motion-only BA (eq. 4.15) from the prior: stereo measurements where the frame
    /// has depth for at least `min_tracked` of the matches, else pixels only; the matches
    /// within the χ² 95 % gate of the fit are its inliers.
    fn motion_only_ba(
        &self,
        frame: &FrameData,
        candidates: &Candidates,
        found: &[(usize, Vector2<f64>)],
        pose_prior: &Se3,
    ) -> Fit {
        let points = &candidates.points;
        let t_ref = candidates.t_ref;
        let prior_sim3 = Sim3::from_se3(pose_prior);
        let in_ref = |i: usize| t_ref.act(&points[i].world);
        let stereo: Vec<(usize, Vector3<f64>)> = found
            .iter()
            .filter_map(|(i, u)| Some((*i, frame.stereo_measurement(*u, &self.camera)?)))
            .collect();
        let options = MotionOnlyOptions {
            min_matches: 6,
            ..MotionOnlyOptions::robust(self.sigma)
        };
        let use_stereo = stereo.len() >= self.config.min_tracked;
        let (fit, matches_used): (Option<(Sim3, Vec<f64>)>, Vec<usize>) = if use_stereo {
            let problem = PoseProblem::new(
                t_ref,
                stereo.iter().map(|(i, _)| in_ref(*i)).collect(),
                stereo
                    .iter()
                    .map(|(_, z)| *z)
                    .collect::<Vec<SVector<f64, 3>>>(),
                &prior_sim3,
            );
            (
                problem
                    .solve(&self.camera, &options)
                    .ok()
                    .map(|f| (f.camera_from_world, f.chi2)),
                stereo.iter().map(|(i, _)| *i).collect(),
            )
        } else {
            let problem = PoseProblem::new(
                t_ref,
                found.iter().map(|(i, _)| in_ref(*i)).collect(),
                found.iter().map(|(_, u)| *u).collect::<Vec<Vector2<f64>>>(),
                &prior_sim3,
            );
            (
                problem
                    .solve(&self.camera.pinhole, &options)
                    .ok()
                    .map(|f| (f.camera_from_world, f.chi2)),
                found.iter().map(|(i, _)| *i).collect(),
            )
        };
        let gate = lsq::chi2_quantile(if use_stereo { 3 } else { 2 }, 0.95);
        let (pose, inliers) = match &fit {
            Some((pose, chi2)) => (
                *pose,
                matches_used
                    .iter()
                    .zip(chi2)
                    .filter(|&(_, &c)| c <= gate)
                    .map(|(&i, _)| i)
                    .collect::<Vec<usize>>(),
            ),
            None => (prior_sim3, Vec::new()),
        };
        Fit {
            pose,
            inliers,
            stereo,
        }
    }

    /// The tracking state from the fit's inliers (`found` matches of `searched`). After a loss
    /// the prior is not to be trusted, and a weak fit is more likely a few chance matches around
    /// a wrong pose than the map found again (a kidnapped camera on 7-Scenes: 12–15 "inliers"
    /// of 400 points searched, 1.5 m off, from which new keyframes grew a displaced map): the
    /// map counts as found again only with a good frame (or a relocalisation, which restarts
    /// the tracker).
    fn state(
        &mut self,
        fit: &Fit,
        stats: &TrackerStats,
        found: usize,
        searched: usize,
        prior: Prior,
    ) -> TrackingState {
        let inliers = fit.inliers.len();
        let state = if inliers >= self.config.min_good {
            TrackingState::Good
        } else if inliers >= self.config.min_tracked {
            TrackingState::Weak(format!(
                "{inliers} inliers of {found} matches ({searched} searched)"
            ))
        } else {
            TrackingState::Lost(format!(
                "{inliers} inliers of {found} matches ({searched} searched, {} visible) around the {}",
                stats.visible,
                match prior {
                    Prior::Dense => "dense prior",
                    Prior::ConstantVelocity => "constant-velocity prediction",
                }
            ))
        };
        let state = match state {
            TrackingState::Weak(reason) if self.motion.recovering => TrackingState::Lost(format!(
                "{reason} after a loss: not trusted until a good frame"
            )),
            state => state,
        };
        self.motion.recovering = matches!(state, TrackingState::Lost(_));
        state
    }

    /// The motion model and the next dense reference after `frame` at `camera_from_world`.
    fn advance(&mut self, frame: &Arc<FrameData>, camera_from_world: &Sim3, state: &TrackingState) {
        let rigid = camera_from_world.rigid_part();
        self.motion.advance(Stamp::of(frame), rigid);
        if frame.depth.is_some() && !matches!(state, TrackingState::Lost(_)) {
            self.motion.dense_reference = Some(DenseReference {
                frame: frame.clone(),
                camera_from_world: rigid,
            });
        }
    }
}

/// The candidates of a frame ([`Tracker::track`]): the reference keyframe, its pose, the
/// points of its `N1` and the graph as it was.
struct Candidates {
    reference: KeyframeId,
    t_ref: Sim3,
    points: Vec<SearchPoint>,
    then: TrackedThen,
}

/// The motion-only BA's result: the pose, the inliers (indices of candidates) and the stereo
/// measurements of the matches.
struct Fit {
    pose: Sim3,
    inliers: Vec<usize>,
    stereo: Vec<(usize, Vector3<f64>)>,
}

#[cfg(test)]
mod tests {
    use super::*;

    fn stamp(index: usize, time: f64) -> Stamp {
        Stamp { index, time }
    }

    /// The prediction runs on time: a step of 0.1 s at 12 m/s, then a gap of 1.1 s predicts
    /// 13.2 m ahead; where the timestamps stop increasing, each frame counts the last period.
    #[test]
    fn the_motion_model_bridges_time() {
        let at = |z: f64| Se3::from_translation(Vector3::new(0.0, 0.0, -z));
        let mut m = Motion::starting(Some((stamp(0, 0.0), at(0.0))));
        m.advance(stamp(1, 0.1), at(1.2));
        let z = |p: Se3| -p.translation().z;
        assert!((z(m.predict(stamp(2, 0.2)).unwrap()) - 2.4).abs() < 1e-9);
        assert!((z(m.predict(stamp(2, 1.2)).unwrap()) - 14.4).abs() < 1e-9);
        // A broken clock: frame 3 stamped as frame 1, two frames of 0.1 s later.
        assert!((z(m.predict(stamp(3, 0.1)).unwrap()) - 3.6).abs() < 1e-9);
        // Frames with the same timestamp (or a microsecond apart): the period observed, frame
        // by frame, not a division by (almost) zero.
        let mut m = Motion::starting(Some((stamp(0, 5.0), at(0.0))));
        m.advance(stamp(1, 5.000001), at(0.5));
        assert!((m.period - Motion::DEFAULT_PERIOD).abs() < 1e-15);
        assert!((z(m.predict(stamp(2, 5.0)).unwrap()) - 1.0).abs() < 1e-9);
    }
}
