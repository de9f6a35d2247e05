//! The stages of the keyframe pipeline (see the [module docs](super)).

use super::registration::register_locally;
use crate::dwo::DwoError;
use crate::factors::{InverseDepthCamera, point_to_inverse_depth};
use crate::loop_closure::{
    self, ClosureError, DriftLimits, LoopDrift, MetricLoopClosure, MetricLoopParams,
};
use crate::map::{GraphError, KeyframeId, PointId, SlamGraph, Version};
use crate::pose_graph::rigid_from_similarity;
use crate::tracking::{self, MotionOnlyOptions, TrackId, TrackingError};
use geom::align::{align_se3, align_sim3};
use geom::two_view::triangulate;
use lie::{LieGroup, Sim3};
use nalgebra::{SVector, Vector2, Vector3};
use std::collections::BTreeMap;

/// Parameters of the keyframe pipeline.
#[derive(Clone, Debug, PartialEq)]
pub struct MappingConfig {
    /// `Θ`: covisible points for an edge of local registration and of metric loop closure
    /// (thesis §6.2.6: 15–30).
    pub theta: usize,
    /// Size of `N2`, the neighbourhood searched by metric loop closure (thesis §6.4.1).
    pub n2: usize,
    /// Pixel noise σ of the measurements.
    pub sigma: f64,
    /// Image width and height (pixels), for the spread-of-matches test of metric loop closure.
    pub image_size: (f64, f64),
    /// Motion-only BA of tracking.
    pub tracking: MotionOnlyOptions,
    /// Metric-loop matches whose squared whitened residual after the loop pose fit exceeds
    /// this are pruned.
    pub loop_max_chi2: f64,
    /// A point is made from one stereo or RGB-D measurement only with at least this disparity
    /// (pixels).
    pub min_disparity: f64,
    /// Monocular triangulation needs at least this parallax between the rays (radians).
    pub min_parallax: f64,
    /// A monocular measurement waits at most this many keyframes for a partner with enough
    /// parallax.
    pub pending_age: usize,
    /// 3D–3D correspondences needed to accept an appearance loop closure.
    pub min_appearance_matches: usize,
    /// The largest correction an appearance loop closure may make (loops needing more join
    /// two places that only look alike).
    pub appearance_max_drift: DriftLimits,
}

impl MappingConfig {
    /// The defaults for `N`-dimensional measurements with pixel noise `sigma` on images of
    /// `image_size`, each chosen from a principle:
    ///
    /// - `Θ = 20`, inside the thesis's 15–30, `N2` of 100 keyframes (thesis §6.4.1 gives no
    ///   size; 100 keyframes reach well beyond a double window of 15 + 50);
    /// - tracking by robust motion-only BA ([`MotionOnlyOptions::robust`]);
    /// - loop matches gated at the χ² 95 % quantile of the measurement dimension (the thesis
    ///   prunes at about one pixel);
    /// - points from one measurement need 1 px of disparity: below it the depth error of a
    ///   ½ px disparity error exceeds the depth itself;
    /// - monocular triangulation at 1.5° of parallax: with σ = 1 px at f = 300 the rays'
    ///   angular noise is 0.2°, so 1.5° gives depths to about 15 %, enough for the optimiser
    ///   to refine; a measurement waits 10 keyframes for such a partner;
    /// - 10 correspondences for an appearance loop: a Sim(3) has 7 degrees of freedom and
    ///   each correspondence gives 3 equations, so 10 over-determine it more than fourfold;
    /// - an appearance loop may move the new keyframe by 5 % of the path between the two places in
    ///   the graph ([`LoopDrift::path`]), or a tenth of the old place's scene depth if more: stereo
    ///   and RGB-D odometry drift by 1–2 % of the distance on KITTI's benchmark (0.4 % on the KITTI
    ///   snippet here, mostly its scale), and a tenth of the scene depth is the keyframe
    ///   criterion's coverage, so within it the two views are one place whatever the path (over a
    ///   short path the loop's own pose error is larger than the drift). The rendered courtyard's
    ///   repeated façades gave verified loops needing 20.6 m over a 163 m path (12.6 %), which
    ///   broke the map; the true loops of the rendered room, the courtyard and 7-Scenes needed at
    ///   most 5 % by their RANSAC poses, over paths of 1–7 m, and far less after the refinement.
    pub fn new(sigma: f64, image_size: (f64, f64), measurement_dimension: usize) -> Self {
        MappingConfig {
            theta: 20,
            n2: 100,
            sigma,
            image_size,
            tracking: MotionOnlyOptions::robust(sigma),
            loop_max_chi2: lsq::chi2_quantile(measurement_dimension, 0.95),
            min_disparity: 1.0,
            min_parallax: 1.5f64.to_radians(),
            pending_age: 10,
            min_appearance_matches: 10,
            appearance_max_drift: DriftLimits {
                of_path: 0.05,
                of_scene_depth: 0.1,
            },
        }
    }
}

/// What [`Mapper::close_appearance_loop`] did with a place.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum AppearanceClosure {
    /// The loop joined the new keyframe to the old one `old`, correcting it by `drift`.
    Closed {
        /// The old keyframe.
        old: KeyframeId,
        /// The correction the loop made.
        drift: Option<LoopDrift>,
    },
    /// The new keyframe was in another map than the old one (a map the live system started
    /// after losing its camera, [`SlamGraph::start_map`]): the younger of the two maps was
    /// moved as one body onto the older by the loop's pose ([`SlamGraph::merge_map`]), then
    /// the two joined by the loop's edge. No drift test: the correction is the offset between
    /// two maps, not drift.
    Merged {
        /// The old keyframe.
        old: KeyframeId,
        /// Keyframes moved (the younger map's).
        keyframes: usize,
        /// How far the moved map's keyframe of the loop moved (metres).
        displacement: f64,
    },
    /// Too few matches (or too few consistent with one pose).
    TooFewMatches,
    /// The loop needed more correction than [`MappingConfig::appearance_max_drift`] allows.
    TooMuchDrift(LoopDrift),
}

impl AppearanceClosure {
    /// The old keyframe, if the loop was closed.
    pub fn closed(&self) -> Option<KeyframeId> {
        match self {
            AppearanceClosure::Closed { old, .. } | AppearanceClosure::Merged { old, .. } => {
                Some(*old)
            }
            _ => None,
        }
    }
}

/// Why a stage of the keyframe pipeline failed.
#[derive(Debug, thiserror::Error)]
pub enum MappingError {
    /// A graph operation failed.
    #[error(transparent)]
    Graph(#[from] GraphError),
    /// Tracking failed.
    #[error(transparent)]
    Tracking(#[from] TrackingError),
    /// Inserting a loop closure failed.
    #[error(transparent)]
    Closure(#[from] ClosureError),
    /// The double window optimisation failed.
    #[error(transparent)]
    Optimisation(#[from] DwoError),
    /// The graph has no keyframe to track against and the front-end gave no pose.
    #[error(
        "the first keyframe needs its pose from the front-end (there is nothing to track against)"
    )]
    NoPose,
}

/// A tracked frame on its way into the graph ([`Mapper::track`] → [`Mapper::insert_keyframe`]).
#[derive(Clone, Debug, PartialEq)]
pub struct TrackedFrame<const N: usize> {
    /// The estimated pose.
    pub camera_from_world: Sim3,
    /// The matched map points and their measurements.
    pub matches: Vec<(PointId, SVector<f64, N>)>,
    /// The keyframe it was tracked against and that keyframe's pose at the time, if any.
    pub reference: Option<(KeyframeId, Sim3)>,
    /// The graph's version when it was tracked: if the reference's pose changed after it, the
    /// pose is rebased onto the moved reference at insertion.
    pub version: Version,
}

/// A frame prepared for tracking ([`Mapper::prepare_track`]): what motion-only BA needs,
/// copied out of the graph.
#[derive(Clone, Debug)]
pub struct PreparedFrame<const N: usize> {
    given: Option<Sim3>,
    problem: Option<tracking::PoseProblem<N>>,
    matches: Vec<(PointId, SVector<f64, N>)>,
    reference: Option<(KeyframeId, Sim3)>,
    version: Version,
}

impl<const N: usize> PreparedFrame<N> {
    /// Robust motion-only BA of the frame (no graph access), or the given pose.
    pub fn solve<P: crate::factors::Projector<N> + Clone>(
        self,
        projector: &P,
        options: &MotionOnlyOptions,
    ) -> Result<TrackedFrame<N>, MappingError> {
        let camera_from_world = match (self.given, &self.problem) {
            (Some(pose), _) => pose,
            (None, Some(problem)) => problem.solve(projector, options)?.camera_from_world,
            (None, None) => return Err(MappingError::NoPose),
        };
        Ok(TrackedFrame {
            camera_from_world,
            matches: self.matches,
            reference: self.reference,
            version: self.version,
        })
    }
}

/// A revisit found by the front-end's place recognition (thesis §6.4.2): the old keyframe and,
/// per correspondence, an old map point, its measurement in the new keyframe, and where the
/// new keyframe has the point — one of its own map points, or `None` for the measurement's
/// own depth (stereo, RGB-D).
#[derive(Clone, Debug, PartialEq)]
pub struct AppearanceMatch<const N: usize> {
    /// The revisited keyframe.
    pub old: KeyframeId,
    /// `(old point, measurement in the new keyframe, the new keyframe's own point for it)`.
    pub correspondences: Vec<(PointId, SVector<f64, N>, Option<PointId>)>,
}

/// An appearance loop copied out of the graph ([`Mapper::plan_appearance_loop`]): per
/// correspondence the old point in the old keyframe's frame (`source`) and where the new
/// keyframe has it (`target`), and the old keyframe's pose.
#[derive(Clone, Debug)]
pub struct AppearancePlan<const N: usize> {
    keyframe: KeyframeId,
    old: KeyframeId,
    old_pose: Sim3,
    target: Vec<Vector3<f64>>,
    source: Vec<Vector3<f64>>,
    matches: Vec<(PointId, SVector<f64, N>)>,
}

/// An appearance loop fitted ([`Mapper::fit_appearance_loop`]): its measurement and the
/// matches one pose explains.
#[derive(Clone, Debug, PartialEq)]
pub struct AppearanceFit<const N: usize> {
    /// The new keyframe.
    pub keyframe: KeyframeId,
    /// The old keyframe.
    pub old: KeyframeId,
    /// `T_new,old`: the loop's measurement.
    pub query_from_matched: Sim3,
    /// The matches kept: old points and their measurements in the new keyframe.
    pub matches: Vec<(PointId, SVector<f64, N>)>,
}

/// The stages of the keyframe pipeline for a camera `C` with `N`-dimensional measurements;
/// holds what the stages remember between keyframes (the last keyframes for the motion
/// model, the monocular measurements waiting for parallax).
#[derive(Clone, Debug)]
pub struct Mapper<C, const N: usize> {
    camera: C,
    config: MappingConfig,
    /// The last two keyframes inserted, the newest last.
    last: Vec<KeyframeId>,
    /// Monocular measurements waiting for a partner with enough parallax, by track.
    pending: BTreeMap<TrackId, Vec<(KeyframeId, SVector<f64, N>)>>,
    inserted: usize,
}

/// `pose`, tracked against keyframe `reference` when that keyframe was at `then` (graph
/// version `version`), rebased onto where the keyframe is now if its pose changed since
/// (another thread's optimisation or map merge): `T ← T·T_ref,then⁻¹·T_ref,now`, the tracked
/// pose relative to the keyframe kept. Unchanged otherwise (or if the keyframe is gone).
pub(crate) fn rebased<const N: usize>(
    graph: &SlamGraph<N>,
    pose: Sim3,
    reference: KeyframeId,
    then: &Sim3,
    version: Version,
) -> Sim3 {
    match graph.keyframe(reference) {
        Some(kf) if kf.pose_version() > version => pose
            .compose(&then.inverse())
            .compose(kf.camera_from_world()),
        _ => pose,
    }
}

impl<C: InverseDepthCamera<N>, const N: usize> Mapper<C, N> {
    /// The stages for `camera` with `config`.
    pub fn new(camera: C, config: MappingConfig) -> Self {
        Mapper {
            camera,
            config,
            last: Vec::new(),
            pending: BTreeMap::new(),
            inserted: 0,
        }
    }

    /// The camera.
    pub fn camera(&self) -> &C {
        &self.camera
    }

    /// The parameters.
    pub fn config(&self) -> &MappingConfig {
        &self.config
    }

    /// The last keyframes inserted (at most two, the newest last), which the next keyframe's
    /// prediction starts from: not to be culled.
    pub fn recent(&self) -> &[KeyframeId] {
        &self.last
    }

    /// The constant-velocity prediction of the next keyframe's pose from the last two
    /// (`T_{k−1}·T_{k−2}⁻¹·T_{k−1}`; the last pose alone after one keyframe), with the scale of
    /// the reference keyframe: the motion is estimated in its metric (thesis §6.2.7).
    pub fn predict_pose(&self, graph: &SlamGraph<N>) -> Result<Option<Sim3>, GraphError> {
        let (Some(reference), Some(&last)) = (graph.reference(), self.last.last()) else {
            return Ok(None);
        };
        let prev = graph.pose(last)?;
        let guess = match self
            .last
            .len()
            .checked_sub(2)
            .and_then(|i| graph.pose(self.last[i]).ok())
        {
            Some(prev2) => prev.compose(&prev2.inverse()).compose(&prev),
            None => prev,
        };
        let t_ref = graph.pose(reference)?;
        Ok(Some(
            Sim3::from_se3(&guess.compose(&t_ref.inverse()).rigid_part()).compose(&t_ref),
        ))
    }

    /// Tracking (thesis §6.2.5): the pose of a frame that measures `matches` (points visible
    /// from `N1` of the reference), by robust motion-only BA from the constant-velocity
    /// prediction — or `given`, when the front-end knows the pose (the first keyframe, a
    /// monocular bootstrap). [`prepare_track`](Self::prepare_track) then
    /// [`PreparedFrame::solve`].
    pub fn track(
        &self,
        graph: &SlamGraph<N>,
        matches: Vec<(PointId, SVector<f64, N>)>,
        given: Option<Sim3>,
    ) -> Result<TrackedFrame<N>, MappingError> {
        self.prepare_track(graph, matches, given)?
            .solve(&self.camera, &self.config.tracking)
    }

    /// The part of [`track`](Self::track) that reads the graph (under a read lock in the live
    /// system): the prediction and the points; the optimisation runs in
    /// [`PreparedFrame::solve`], with no lock held.
    pub fn prepare_track(
        &self,
        graph: &SlamGraph<N>,
        matches: Vec<(PointId, SVector<f64, N>)>,
        given: Option<Sim3>,
    ) -> Result<PreparedFrame<N>, MappingError> {
        let reference = match graph.reference() {
            Some(r) => Some((r, graph.pose(r)?)),
            None => None,
        };
        let problem = match (given, reference) {
            (Some(_), _) => None,
            (None, None) => return Err(MappingError::NoPose),
            (None, Some((r, t_r))) => {
                let need = self.config.tracking.min_matches;
                if matches.len() < need {
                    return Err(TrackingError::TooFewMatches {
                        got: matches.len(),
                        need,
                    }
                    .into());
                }
                let guess = self.predict_pose(graph)?.unwrap_or(t_r);
                Some(tracking::PoseProblem::from_graph(
                    graph, r, &matches, &guess,
                )?)
            }
        };
        Ok(PreparedFrame {
            given,
            problem,
            matches,
            reference,
            version: graph.version(),
        })
    }

    /// Inserts a tracked frame as a keyframe (thesis §6.2.6): its matched observations, an
    /// edge to every keyframe sharing `Θ` points and to the previous reference, and it becomes
    /// the reference. If the reference's pose changed since the frame was tracked, the pose is
    /// rebased onto it (`T ← T·T_ref,then⁻¹·T_ref,now`: the tracked relative pose is kept).
    /// Matches of points removed meanwhile are skipped. Returns the keyframe and the number
    /// of matches skipped.
    pub fn insert_keyframe(
        &mut self,
        graph: &mut SlamGraph<N>,
        frame: TrackedFrame<N>,
    ) -> Result<(KeyframeId, usize), MappingError> {
        let pose = match frame.reference {
            Some((r, then)) => rebased(graph, frame.camera_from_world, r, &then, frame.version),
            None => frame.camera_from_world,
        };
        let kf = graph.add_keyframe(pose);
        let mut skipped = 0;
        for (p, z) in &frame.matches {
            match graph.add_observation(kf, *p, *z) {
                Ok(()) => {}
                Err(GraphError::UnknownPoint(_)) => skipped += 1,
                Err(e) => return Err(e.into()),
            }
        }
        register_locally(
            graph,
            kf,
            self.config.theta,
            frame.reference.map(|(r, _)| r),
        )?;
        graph.set_reference(kf)?;
        self.last.push(kf);
        if self.last.len() > 2 {
            self.last.remove(0);
        }
        Ok((kf, skipped))
    }

    /// The inverse-depth point `ψ` of one measurement, if its disparity is at least
    /// [`MappingConfig::min_disparity`] (stereo, RGB-D; never for a monocular camera).
    pub fn depth_point(&self, z: &SVector<f64, N>) -> Option<Vector3<f64>> {
        let d = self.camera.disparity(z)?;
        if d < self.config.min_disparity {
            return None;
        }
        self.camera.inverse_depth_from(z, 0.0)
    }

    /// Appearance loop closure (thesis §6.4.2): aligns the old keyframe's points with where the
    /// new keyframe `keyframe` has them (Sim(3) for a monocular camera, whose map drifts in
    /// scale; SE(3) otherwise; eq. 5.11–5.14, 6.9), keeps the matches one pose of the new
    /// keyframe explains (a robust motion-only fit, which is also the loop's measurement with
    /// a depth-measuring camera) and, with enough correspondences, inserts
    /// the edge and the matched observations — unless the loop needs more correction than the
    /// drift over the path between the two places explains
    /// ([`MappingConfig::appearance_max_drift`]).
    ///
    /// In one go: [`plan_appearance_loop`](Self::plan_appearance_loop) (reads the graph: a
    /// thread holds its read lock), [`fit_appearance_loop`](Self::fit_appearance_loop) (no
    /// graph: no lock), [`apply_appearance_loop`](Self::apply_appearance_loop) (writes: a
    /// short write lock).
    pub fn close_appearance_loop(
        &self,
        graph: &mut SlamGraph<N>,
        keyframe: KeyframeId,
        place: &AppearanceMatch<N>,
    ) -> Result<AppearanceClosure, MappingError> {
        let plan = self.plan_appearance_loop(graph, keyframe, place)?;
        match self.fit_appearance_loop(plan) {
            Some(fit) => self.apply_appearance_loop(graph, &fit),
            None => Ok(AppearanceClosure::TooFewMatches),
        }
    }

    /// The part of [`close_appearance_loop`](Self::close_appearance_loop) that reads the graph:
    /// each correspondence's point in the old keyframe's frame and where the new keyframe has
    /// it, and the old keyframe's pose.
    pub fn plan_appearance_loop(
        &self,
        graph: &SlamGraph<N>,
        keyframe: KeyframeId,
        place: &AppearanceMatch<N>,
    ) -> Result<AppearancePlan<N>, MappingError> {
        if graph.keyframe(place.old).is_none() {
            return Err(GraphError::UnknownKeyframe(place.old).into());
        }
        let (mut target, mut source, mut matches) = (Vec::new(), Vec::new(), Vec::new());
        for &(p_old, z, own) in &place.correspondences {
            let here = match own {
                Some(p_new) => graph.point_in_frame(p_new, keyframe).ok(),
                None => self
                    .depth_point(&z)
                    .map(|psi| crate::factors::inverse_depth_to_point(&psi)),
            };
            if let (Some(x), Ok(y)) = (here, graph.point_in_frame(p_old, place.old)) {
                target.push(x);
                source.push(y);
                matches.push((p_old, z));
            }
        }
        Ok(AppearancePlan {
            keyframe,
            old: place.old,
            old_pose: graph.pose(place.old)?,
            target,
            source,
            matches,
        })
    }

    /// The part of [`close_appearance_loop`](Self::close_appearance_loop) that computes (no
    /// graph): the alignment, the robust fit that keeps the matches one pose explains, and
    /// the loop's measurement `query_from_matched`; `None` with too few matches.
    pub fn fit_appearance_loop(&self, plan: AppearancePlan<N>) -> Option<AppearanceFit<N>> {
        let AppearancePlan {
            keyframe,
            old,
            old_pose: t_old,
            target,
            source,
            matches,
        } = plan;
        let align = |target: &[Vector3<f64>], source: &[Vector3<f64>]| {
            if C::MEASURES_DEPTH {
                align_se3(target, source).ok().map(|t| Sim3::from_se3(&t))
            } else {
                align_sim3(target, source).ok()
            }
        };
        if matches.len() < self.config.min_appearance_matches {
            return None;
        }
        let first = align(&target, &source)?;
        // The matches must be explained by one pose of the new keyframe in the old place, as
        // those of a metric loop (thesis §6.4.1): a robust motion-only fit from the pose the
        // alignment implies, and the matches above the χ² gate dropped. The guided matching
        // finds them by patch correlation alone; one wrong match in the alignment (no robust
        // cost there) bends the loop's edge, and it would also become an observation.
        let initial = Sim3::from_se3(&rigid_from_similarity(&first)).compose(&t_old);
        let fit = tracking::PoseProblem::new(
            t_old,
            source.clone(),
            matches.iter().map(|m| m.1).collect(),
            &initial,
        )
        .solve(&self.camera, &MotionOnlyOptions::robust(self.config.sigma))
        .ok()?;
        let keep: Vec<bool> = fit
            .chi2
            .iter()
            .map(|&c| c <= self.config.loop_max_chi2)
            .collect();
        let pick = |v: Vec<Vector3<f64>>| -> Vec<Vector3<f64>> {
            v.into_iter()
                .zip(&keep)
                .filter(|(_, k)| **k)
                .map(|(x, _)| x)
                .collect()
        };
        let (target, source) = (pick(target), pick(source));
        let matches: Vec<(PointId, SVector<f64, N>)> = matches
            .into_iter()
            .zip(&keep)
            .filter(|(_, k)| **k)
            .map(|(m, _)| m)
            .collect();
        if matches.len() < self.config.min_appearance_matches {
            return None;
        }
        // The loop's measurement: with depth, the motion-only fit on the kept matches (pixel
        // residuals weighted by the measurement noise, as metric loop closure measures its
        // loops); the rigid 3D alignment weighs every point's depth alike, and stereo depth
        // errors grow with the square of the depth (on the rendered room the corrections of
        // true loops, whose drift is about a millimetre, were up to 8 cm from the alignment
        // and at most 8 mm from the fit). Without depth, the similarity alignment (the scale).
        let query_from_matched = if C::MEASURES_DEPTH {
            let refit = tracking::PoseProblem::new(
                t_old,
                source.clone(),
                matches.iter().map(|m| m.1).collect(),
                &fit.camera_from_world,
            )
            .solve(&self.camera, &MotionOnlyOptions::robust(self.config.sigma))
            .ok()?;
            refit.camera_from_world.compose(&t_old.inverse())
        } else {
            align(&target, &source)?
        };
        Some(AppearanceFit {
            keyframe,
            old,
            query_from_matched,
            matches,
        })
    }

    /// The part of [`close_appearance_loop`](Self::close_appearance_loop) that writes: with
    /// the poses as they are now (the loop's measurement is relative, so the graph may have
    /// moved since the plan), two maps are merged, or the drift test decides, and the loop's
    /// edge and observations go in (those of points removed meanwhile are skipped).
    pub fn apply_appearance_loop(
        &self,
        graph: &mut SlamGraph<N>,
        fit: &AppearanceFit<N>,
    ) -> Result<AppearanceClosure, MappingError> {
        let AppearanceFit {
            keyframe,
            old,
            query_from_matched,
            ref matches,
        } = *fit;
        let t_old = graph.pose(old)?;
        let implied = query_from_matched.compose(&t_old);
        let (map_new, map_old) = (graph.map_of(keyframe)?, graph.map_of(old)?);
        let matches: Vec<(PointId, SVector<f64, N>)> = matches
            .iter()
            .filter(|(p, _)| graph.point(*p).is_some())
            .copied()
            .collect();
        if map_new != map_old {
            let centre = |t: &Sim3| t.inverse().act(&Vector3::zeros());
            // The younger map moves onto the older (the first map, the world, never moves): the
            // new keyframe's, to where the loop puts it; or the old keyframe's (a camera found
            // again in the first map that sees a map started after a loss), to where the loop
            // puts that one.
            let (moving, target, into) = if map_new > map_old {
                (keyframe, implied, old)
            } else {
                let t_query = graph.pose(keyframe)?;
                (
                    old,
                    query_from_matched.inverse().compose(&t_query),
                    keyframe,
                )
            };
            let displacement = (centre(&target) - centre(&graph.pose(moving)?)).norm();
            let keyframes = graph.merge_map(moving, &target, into)?;
            loop_closure::close_appearance_loop(
                graph,
                keyframe,
                old,
                query_from_matched,
                &matches,
            )?;
            return Ok(AppearanceClosure::Merged {
                old,
                keyframes,
                displacement,
            });
        }
        let drift = LoopDrift::of(graph, old, keyframe, &implied);
        if let Some(drift) = drift
            && !drift.within(&self.config.appearance_max_drift)
        {
            return Ok(AppearanceClosure::TooMuchDrift(drift));
        }
        loop_closure::close_appearance_loop(graph, keyframe, old, query_from_matched, &matches)?;
        Ok(AppearanceClosure::Closed { old, drift })
    }

    /// The candidates of metric loop closure (thesis §6.4.1): the points of `N2 \ N1` of
    /// `keyframe` with their predicted measurements in it, for the front-end's guided search.
    pub fn loop_predictions(
        &self,
        graph: &SlamGraph<N>,
        keyframe: KeyframeId,
    ) -> Result<Vec<(PointId, SVector<f64, N>)>, GraphError> {
        let t_kf = graph.pose(keyframe)?;
        Ok(
            loop_closure::loop_candidates(graph, keyframe, self.config.n2)
                .into_iter()
                .filter_map(|p| {
                    let x = graph.point_world(p).ok()?;
                    let (z, _) = self.camera.project(&t_kf.act(&x))?;
                    Some((p, z))
                })
                .collect(),
        )
    }

    /// Metric loop closure (thesis §6.4.1) with the points the front-end found again.
    pub fn close_metric_loops(
        &self,
        graph: &mut SlamGraph<N>,
        keyframe: KeyframeId,
        found: &[(PointId, SVector<f64, N>)],
    ) -> Result<Vec<MetricLoopClosure>, MappingError> {
        Ok(loop_closure::close_metric_loops(
            graph,
            keyframe,
            found,
            &self.camera,
            &self.metric_loop_params(),
        )?)
    }

    /// The parameters of metric loop closure.
    pub fn metric_loop_params(&self) -> MetricLoopParams {
        MetricLoopParams {
            theta: self.config.theta,
            max_chi2: self.config.loop_max_chi2,
            sigma: self.config.sigma,
            image_size: self.config.image_size,
        }
    }

    /// New points for the measurements of `keyframe` that are not associated with a map
    /// point (`(track, z, associated)`, in the front-end's order): from the measurement's
    /// disparity (stereo, RGB-D), or by midpoint triangulation with the track's oldest waiting
    /// measurement once their rays have [`MappingConfig::min_parallax`] (monocular, and stereo
    /// points too far for their disparity; the point is anchored in that older keyframe and
    /// observed by every waiting keyframe). Returns the
    /// points created, with their tracks, in creation order.
    pub fn add_points(
        &mut self,
        graph: &mut SlamGraph<N>,
        keyframe: KeyframeId,
        measurements: &[(TrackId, SVector<f64, N>, bool)],
    ) -> Result<Vec<(TrackId, PointId)>, MappingError> {
        let age = self.config.pending_age;
        let young = |j: KeyframeId| j.index() + age >= keyframe.index();
        let t_kf = graph.pose(keyframe)?;
        let mut created = Vec::new();
        for &(track, z, associated) in measurements {
            if associated {
                self.pending.remove(&track);
                continue;
            }
            if let Some(psi) = self.depth_point(&z) {
                created.push((track, graph.add_point(keyframe, psi, z)?));
                continue;
            }
            let entry = self.pending.entry(track).or_default();
            entry.retain(|(j, _)| young(*j));
            let ray = self.camera.ray(&z);
            let triangulated = entry.first().and_then(|&(j, z_j)| {
                let t_j = graph.pose(j).ok()?;
                let ray_j = self.camera.ray(&z_j);
                let t = triangulate(
                    &rigid_from_similarity(&t_kf.compose(&t_j.inverse())),
                    &Vector2::new(ray_j.x, ray_j.y),
                    &Vector2::new(ray.x, ray.y),
                )?;
                (t.parallax >= self.config.min_parallax && t.depth_a > 0.0 && t.depth_b > 0.0)
                    .then_some((j, z_j, point_to_inverse_depth(&t.point_a)?))
            });
            match triangulated {
                Some((j, z_j, psi)) => {
                    let p = graph.add_point(j, psi, z_j)?;
                    for &(i, z_i) in entry.iter().skip(1) {
                        graph.add_observation(i, p, z_i)?;
                    }
                    graph.add_observation(keyframe, p, z)?;
                    self.pending.remove(&track);
                    created.push((track, p));
                }
                None => entry.push((keyframe, z)),
            }
        }
        // Forget measurements that can no longer find a partner (memory only: stale ones are
        // also dropped before every use).
        self.inserted += 1;
        if self.inserted.is_multiple_of(50) {
            self.pending
                .retain(|_, v| v.last().is_some_and(|(j, _)| young(*j)));
        }
        Ok(created)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use geom::{PinholeCamera, StereoCamera};
    use lie::Se3;

    fn mapper() -> Mapper<StereoCamera, 3> {
        let camera = StereoCamera::new(PinholeCamera::new(300.0, 300.0, 320.0, 240.0), 0.1);
        Mapper::new(camera, MappingConfig::new(1.0, (640.0, 480.0), 3))
    }

    #[test]
    fn a_frame_tracked_before_its_reference_moved_is_rebased_onto_it() {
        let mut mapper = mapper();
        let mut g = SlamGraph::<3>::new();
        let first = mapper
            .track(&g, Vec::new(), Some(Sim3::identity()))
            .unwrap();
        let (r, _) = mapper.insert_keyframe(&mut g, first).unwrap();
        let tracked = Sim3::from_se3(&Se3::from_translation(Vector3::new(-0.1, 0.0, 0.0)));
        // Unmoved reference: the pose goes in as tracked, bit for bit.
        let frame = mapper.track(&g, Vec::new(), Some(tracked)).unwrap();
        let (k, _) = mapper.insert_keyframe(&mut g, frame.clone()).unwrap();
        assert_eq!(*g.keyframe(k).unwrap().camera_from_world(), tracked);
        // A frame tracked against `r`, then `r` moves (a loop correction) before insertion.
        let frame = TrackedFrame {
            reference: Some((r, g.pose(r).unwrap())),
            version: g.version(),
            ..frame
        };
        let moved = Sim3::new(lie::So3::rot_y(0.1), Vector3::new(0.2, 0.0, 0.05), 1.0)
            .unwrap()
            .compose(&g.pose(r).unwrap());
        g.set_pose(r, moved).unwrap();
        let (k2, _) = mapper.insert_keyframe(&mut g, frame).unwrap();
        // The relative pose to the reference is what tracking measured.
        let relative = g.pose(k2).unwrap().compose(&g.pose(r).unwrap().inverse());
        let expected = tracked; // the reference was the identity when tracked
        assert!(
            relative.compose(&expected.inverse()).log().norm() < 1e-12,
            "{relative:?}"
        );
        g.check_invariants().unwrap();
    }

    /// 40 points spread over a scene 2–4 m in front of keyframe `old` (in its frame), anchored
    /// and observed there: the old place of the appearance-loop tests.
    fn old_place_points(
        g: &mut SlamGraph<3>,
        old: KeyframeId,
        camera: &StereoCamera,
    ) -> Vec<(PointId, Vector3<f64>)> {
        (0..40)
            .map(|i| {
                let x = Vector3::new(
                    -1.0 + 0.05 * i as f64,
                    -0.6 + 0.03 * ((i * 7) % 40) as f64,
                    2.0 + 0.05 * ((i * 13) % 40) as f64,
                );
                let p = g
                    .add_point(
                        old,
                        point_to_inverse_depth(&x).unwrap(),
                        camera.project(&x).unwrap(),
                    )
                    .unwrap();
                (p, x)
            })
            .collect()
    }

    #[test]
    fn wrong_matches_of_an_appearance_loop_are_dropped_before_the_alignment() {
        let mapper = mapper();
        let camera = *mapper.camera();
        let mut g = SlamGraph::<3>::new();
        let old = g.add_keyframe(Sim3::identity());
        // The new keyframe truly sits at `truth` from the old one; the graph has it drifted.
        let truth = Se3::new(lie::So3::rot_y(0.08), Vector3::new(0.3, -0.05, 0.1));
        let drifted = Sim3::from_se3(&Se3::from_translation(Vector3::new(0.05, 0.02, 0.0)))
            .compose(&Sim3::from_se3(&truth));
        let new = g.add_keyframe(drifted);
        let mut correspondences = Vec::new();
        let mut wrong = Vec::new();
        for (i, (p, x)) in old_place_points(&mut g, old, &camera)
            .into_iter()
            .enumerate()
        {
            let mut z = camera.project(&truth.act(&x)).unwrap();
            if i % 10 == 3 {
                // A wrong patch match: 25 px off, with the disparity of a surface behind it.
                z += Vector3::new(25.0, 0.0, 20.0);
                wrong.push(p);
            }
            correspondences.push((p, z, None));
        }
        let place = AppearanceMatch {
            old,
            correspondences,
        };
        assert_eq!(
            mapper
                .close_appearance_loop(&mut g, new, &place)
                .unwrap()
                .closed(),
            Some(old)
        );
        // The edge carries the true relative pose (the four wrong matches would bend it by
        // centimetres), and the wrong matches are no observations of the new keyframe.
        let relative = g.relative_pose(old, new).unwrap();
        let error = relative
            .compose(&Sim3::from_se3(&truth).inverse())
            .log()
            .norm();
        assert!(error < 1e-6, "relative pose error {error}");
        let seen = g.keyframe(new).unwrap().observations();
        assert_eq!(seen.len(), 36);
        assert!(wrong.iter().all(|p| !seen.contains_key(p)));
    }

    #[test]
    fn an_appearance_loop_needing_more_than_the_drift_allows_is_refused() {
        let mapper = mapper();
        let camera = *mapper.camera();
        // The loop says the new keyframe sits at `truth` from the old one, a short path
        // (0.3 m) over a scene about 3 m deep: it may move the keyframe by a tenth of that
        // depth. The graph has it `offset` away from there.
        let truth = Se3::new(lie::So3::rot_y(0.08), Vector3::new(0.3, -0.05, 0.1));
        for (offset, closed) in [(0.2, true), (2.0, false)] {
            let mut g = SlamGraph::<3>::new();
            let old = g.add_keyframe(Sim3::identity());
            let graph_pose = Sim3::from_se3(&Se3::from_translation(Vector3::new(offset, 0.0, 0.0)))
                .compose(&Sim3::from_se3(&truth));
            let new = g.add_keyframe(graph_pose);
            let correspondences: Vec<_> = old_place_points(&mut g, old, &camera)
                .into_iter()
                .map(|(p, x)| (p, camera.project(&truth.act(&x)).unwrap(), None))
                .collect();
            let place = AppearanceMatch {
                old,
                correspondences,
            };
            let version = g.version();
            match mapper.close_appearance_loop(&mut g, new, &place).unwrap() {
                AppearanceClosure::Closed { old: k, drift } => {
                    assert!(closed && k == old, "offset {offset}");
                    assert!((drift.unwrap().displacement - offset).abs() < 1e-6);
                }
                AppearanceClosure::TooMuchDrift(d) => {
                    assert!(!closed, "offset {offset}");
                    assert!((d.displacement - offset).abs() < 1e-6, "{d:?}");
                    // Nothing entered the graph.
                    assert_eq!(g.version(), version);
                    assert!(g.keyframe(new).unwrap().observations().is_empty());
                }
                other => panic!("offset {offset}: {other:?}"),
            }
        }
    }

    /// Closes `place`'s loop from `new`: a merge of `place.old`'s map and `new`'s, moving the
    /// younger map's two keyframes by more than 4 m.
    fn assert_merges_two_keyframes_5m(
        mapper: &Mapper<StereoCamera, 3>,
        g: &mut SlamGraph<3>,
        new: KeyframeId,
        place: &AppearanceMatch<3>,
    ) {
        match mapper.close_appearance_loop(g, new, place).unwrap() {
            AppearanceClosure::Merged {
                old: k,
                keyframes,
                displacement,
            } => {
                assert_eq!((k, keyframes), (place.old, 2));
                assert!(displacement > 4.0, "{displacement}");
            }
            other => panic!("{other:?}"),
        }
    }

    /// The same loop with the new keyframe in a map of its own (started after a loss), 5 m
    /// off: no drift test; its map (with a second keyframe and a point) moves onto the old
    /// one by the loop's pose, and the two are one map, joined by the loop's edge.
    #[test]
    fn an_appearance_loop_into_another_map_merges_the_maps() {
        let mapper = mapper();
        let camera = *mapper.camera();
        let truth = Se3::new(lie::So3::rot_y(0.08), Vector3::new(0.3, -0.05, 0.1));
        let mut g = SlamGraph::<3>::new();
        let old = g.add_keyframe(Sim3::identity());
        assert_eq!(g.start_map(), 1);
        let offset = Sim3::from_se3(&Se3::new(lie::So3::rot_z(0.4), Vector3::new(5.0, 1.0, 0.0)));
        let new = g.add_keyframe(offset.compose(&Sim3::from_se3(&truth)));
        let other = g.add_keyframe(offset);
        let p = g
            .add_point(other, Vector3::new(0.1, 0.2, 0.5), Vector3::zeros())
            .unwrap();
        g.add_edge(new, other, None).unwrap();
        let relative = g.relative_pose(new, other).unwrap();
        let x_before = g.point_in_frame(p, other).unwrap();
        let correspondences: Vec<_> = old_place_points(&mut g, old, &camera)
            .into_iter()
            .map(|(p, x)| (p, camera.project(&truth.act(&x)).unwrap(), None))
            .collect();
        let place = AppearanceMatch {
            old,
            correspondences,
        };
        assert_merges_two_keyframes_5m(&mapper, &mut g, new, &place);
        // The new keyframe where the loop puts it, its map moved with it, one map now.
        let error = g
            .pose(new)
            .unwrap()
            .compose(&g.pose(old).unwrap().inverse())
            .compose(&Sim3::from_se3(&truth).inverse())
            .log()
            .norm();
        assert!(error < 1e-6, "{error}");
        let r = g
            .relative_pose(new, other)
            .unwrap()
            .compose(&relative.inverse());
        assert!(r.log().norm() < 1e-9);
        assert!((g.point_in_frame(p, other).unwrap() - x_before).norm() < 1e-9);
        assert_eq!([g.map_of(new).unwrap(), g.map_of(other).unwrap()], [0, 0]);
        assert_eq!(g.current_map(), 0);
        assert!(g.edge(old, new).is_some());
    }

    /// The other way round: a keyframe of the first map (the camera found again there) sees a
    /// place of a map started after a loss, 5 m off. The first map stays where it is; the
    /// younger map moves so that its keyframe comes where the loop puts it.
    #[test]
    fn the_first_map_never_moves_in_a_merge() {
        let mapper = mapper();
        let camera = *mapper.camera();
        let truth = Se3::new(lie::So3::rot_y(0.08), Vector3::new(0.3, -0.05, 0.1));
        let mut g = SlamGraph::<3>::new();
        let first = g.add_keyframe(Sim3::identity());
        assert_eq!(g.start_map(), 1);
        let offset = Sim3::from_se3(&Se3::new(lie::So3::rot_z(0.4), Vector3::new(5.0, 1.0, 0.0)));
        let old = g.add_keyframe(offset);
        let other = g.add_keyframe(offset.compose(&Sim3::from_se3(&truth)));
        let correspondences: Vec<_> = old_place_points(&mut g, old, &camera)
            .into_iter()
            .map(|(p, x)| (p, camera.project(&truth.act(&x)).unwrap(), None))
            .collect();
        g.add_edge(old, other, None).unwrap();
        let relative = g.relative_pose(old, other).unwrap();
        // Found again in the first map: the new keyframe joins it, where the old place's
        // keyframe truly is at the identity.
        g.set_reference(first).unwrap();
        let new = g.add_keyframe(Sim3::from_se3(&truth));
        assert_eq!(g.map_of(new).unwrap(), 0);
        let place = AppearanceMatch {
            old,
            correspondences,
        };
        assert_merges_two_keyframes_5m(&mapper, &mut g, new, &place);
        assert_eq!(g.pose(first).unwrap().log(), Sim3::identity().log());
        assert!((g.pose(new).unwrap().log() - Sim3::from_se3(&truth).log()).norm() < 1e-12);
        assert!(
            g.pose(old).unwrap().log().norm() < 1e-6,
            "the old place at the identity"
        );
        let r = g
            .relative_pose(old, other)
            .unwrap()
            .compose(&relative.inverse());
        assert!(r.log().norm() < 1e-9, "the younger map moved as one body");
        assert_eq!([g.map_of(old).unwrap(), g.map_of(other).unwrap()], [0, 0]);
        assert_eq!(g.merges()[0].from, 1);
        assert!(g.edge(old, new).is_some());
    }

    #[test]
    fn points_come_from_disparity_or_wait_for_parallax() {
        let mut mapper = mapper();
        let mut g = SlamGraph::<3>::new();
        let frame = mapper
            .track(&g, Vec::new(), Some(Sim3::identity()))
            .unwrap();
        let (k0, _) = mapper.insert_keyframe(&mut g, frame).unwrap();
        let near = Vector3::new(320.0, 240.0, 300.0); // 20 px of disparity: 1.5 m
        let far = Vector3::new(100.0, 240.0, 99.5); // 0.5 px: too far for one measurement
        let created = mapper
            .add_points(
                &mut g,
                k0,
                &[(1, near, false), (2, far, false), (3, near, true)],
            )
            .unwrap();
        assert_eq!(created.len(), 1, "{created:?}");
        assert_eq!(created[0].0, 1);
        let y = g.point_in_frame(created[0].1, k0).unwrap();
        assert!((y.z - 1.5).abs() < 1e-12, "{y}");
        // The far point waits; a keyframe 5 m to the side gives the parallax to triangulate it
        // (74 m away: 3.2°).
        let frame = mapper
            .track(
                &g,
                Vec::new(),
                Some(Sim3::from_se3(&Se3::from_translation(Vector3::new(
                    -5.0, 0.0, 0.0,
                )))),
            )
            .unwrap();
        let (k1, _) = mapper.insert_keyframe(&mut g, frame).unwrap();
        // The same world point (60 m ahead, 44 m left) seen from 5 m further right.
        let x0 = Vector3::new((100.0 - 320.0) / 300.0 * 60.0, 0.0, 60.0);
        let x1 = x0 + Vector3::new(-5.0, 0.0, 0.0);
        let z1 = Vector3::new(320.0 + 300.0 * x1.x / x1.z, 240.0, 0.0);
        let created = mapper
            .add_points(
                &mut g,
                k1,
                &[(2, Vector3::new(z1.x, z1.y, z1.x - 0.3), false)],
            )
            .unwrap();
        assert_eq!(created.len(), 1);
        let p = created[0].1;
        assert_eq!(
            g.point(p).unwrap().anchor(),
            k0,
            "anchored where first seen"
        );
        let y = g.point_world(p).unwrap();
        assert!((y - x0).norm() < 1e-6 * x0.norm(), "{y} vs {x0}");
        g.check_invariants().unwrap();
    }
}
