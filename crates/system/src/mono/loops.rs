//! Large loops and map joins of the monocular system by appearance (thesis ch. 5), the loop
//! closer's stage for one camera: each keyframe's ORB words and map-point depths go into its
//! map's database; a loop is verified by kNN depth regression and a 3-point Sim(3) RANSAC
//! (`place_recognition`, [`Alignment::Sim3`]), its scale is the scale drift between the two
//! places. A keyframe of a map started after a loss is also looked up in the earlier maps'
//! databases: a recognised place of an earlier map joins the two maps
//! (`slam::map::SlamGraph::join_maps`), by the similarity between their worlds.
//!
//! Each loop detection is measured again on the old place's map points
//! ([`MonoLoops::fit_old_place`]: found by guided search where the detection puts them, the
//! pose by P3P on them, the scale from the depths at the same corners) and refused, with its
//! reason, if fewer than Θ of them are found. A loop, like a join, is accepted once
//! `mono.loop_consistency` detections in a row agree through the odometry ([`loops_agree`],
//! `mono.loop_agreement`): a place that only looks like another is seldom found again point by
//! point, and seldom so three times over. The loops accepted go back to the sensor
//! ([`MonoLoopData::Accepted`]), which corrects the map with them at the end of the run (or
//! at once, `mono.correct_live`).

use crate::config::LoopCorrection;
use crate::config::{LoopAgreement, SystemConfig};
use crate::frame::CornerIndex;
use crate::keyframes::KeyframeStore;
use crate::place_recognition::{
    Alignment, KeyframeFeatures, PlaceRecognition, PlaceRecognitionConfig,
};
use crate::result::{LoopEvent, LoopEvidence, RefusedLoop};
use crate::search::{
    CORNER_CELL_PX, PATCH_MARGIN_PX, SAME_CORNER_PX, SearchPoint, SearchScratch, predict, search,
    view_angle,
};
use crate::session::LoopOutput;
use crate::session::backend::Stage;
use geom::PinholeCamera;
use geom::pnp::PnpEstimator;
use geom::ransac::{Estimator, RansacConfig, ransac};
use lie::{LieGroup, Sim3};
use nalgebra::{Vector2, Vector3};
use slam::loop_closure::correction::{EdgeInformation, correct_map};
use slam::loop_closure::{CorrectionGroup, LoopEdge};
use slam::loop_closure::{DriftLimits, LoopDrift};
use slam::map::shared::{read_lock, write_lock};
use slam::map::{KeyframeId, SharedGraph, SlamGraph};
use slam::pose_graph::{PoseGraphJacobian, rigid_from_similarity};
use std::collections::{BTreeMap, BTreeSet};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, RwLock};
use std::time::Instant;
use vision::bow::Vocabulary;
use vision::fast::fast9;
use vision::image::GrayImage;

/// A loop found by place recognition: keyframe `current` sees the place of `old`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct LoopDetection {
    pub current: KeyframeId,
    pub old: KeyframeId,
    /// `x_current = S·x_old` for camera-frame points.
    pub current_from_old: Sim3,
    /// The correction the loop makes to the current keyframe, against the path between the
    /// two (a loop within one map; `None` for a join of two maps).
    pub drift: Option<LoopDrift>,
    /// What a loop rests on: the detection's RANSAC inliers, the old place's points found
    /// again ([`MonoLoops::fit_old_place`]; `None` for a join).
    pub evidence: Option<LoopEvidence>,
    /// The standard error of `ln` of the similarity's scale, from the fit (`None` for a
    /// join, or a loop whose scale is the detection's).
    pub scale_sigma: Option<f64>,
}

/// What the guided search of a detection's old place uses: the tracker's search (radius,
/// correlation, visibility angle, FAST threshold) and the place recognition's pixel noise,
/// χ² gate and RANSAC.
#[derive(Clone, Copy, Debug)]
struct PlaceSearch {
    radius: f64,
    min_ncc: f32,
    max_view_angle: f64,
    fast_threshold: u8,
    pixel_sigma: f64,
    gate: f64,
    ransac_confidence: f64,
    ransac_max_iterations: usize,
    seed: u64,
}

/// A detection measured again on the old place's points ([`MonoLoops::fit_old_place`]).
#[derive(Clone, Copy, Debug)]
struct PlaceFit {
    current_from_old: Sim3,
    /// Old-place points found consistent with the fitted pose, of those predicted visible.
    found: usize,
    predicted: usize,
    scale_sigma: Option<f64>,
}

/// A map point found in an image: its world position and pixel.
type Found = (Vector3<f64>, Vector2<f64>);

/// Whether `found` of the old place's `predicted` points, found consistent with one pose,
/// are at least `min_fraction` of them (`mono.loop_min_found_fraction`): a look-alike place
/// matches its repeated parts, not the rest of the place. The reason if not.
fn enough_of_the_place(found: usize, predicted: usize, min_fraction: f64) -> Result<(), String> {
    let fraction = found as f64 / predicted.max(1) as f64;
    if fraction >= min_fraction {
        return Ok(());
    }
    Err(format!(
        "{found} of the old place's {predicted} points predicted visible found at the loop's \
         pose consistent with one pose ({:.1} %), {:.0} % needed \
         (mono.loop_min_found_fraction): a place that only looks alike",
        100.0 * fraction,
        100.0 * min_fraction
    ))
}

/// What the stage gives back to the monocular sensor.
#[derive(Clone, Debug, PartialEq)]
pub(crate) enum MonoLoopData {
    /// A loop accepted (in the map of its keyframes).
    Accepted(LoopDetection),
    /// The map corrected by its loops accepted so far (`mono.correct_live`), solved in the
    /// loop closer's thread on a snapshot of the graph.
    Corrected(LiveCorrection),
}

/// A correction of one map solved on a snapshot of the graph ([`MonoLoops::correct_live`]):
/// each keyframe of the snapshot's map with its pose before and after. The tracking thread
/// applies it to the graph as it is by then ([`LiveCorrection::apply`]).
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct LiveCorrection {
    /// The map.
    pub map: usize,
    /// `(keyframe, camera_from_world before, after)`, in id order.
    pub poses: Vec<(KeyframeId, Sim3, Sim3)>,
}

impl LiveCorrection {
    /// Writes the correction into `graph`, which may have moved on since the snapshot: each
    /// keyframe of the snapshot takes the correction of its world,
    /// `T_new = T_now · T_before⁻¹ · T_after` (its solved pose if the local optimisation left it
    /// alone meanwhile), and each keyframe of the map made since takes the correction of the
    /// snapshot's last keyframe (it was placed relative to it). Anchored points follow their
    /// keyframes. Keyframes that left the map meanwhile are skipped.
    pub fn apply(&self, graph: &mut SlamGraph<2>) -> Result<(), slam::map::GraphError> {
        let delta = |before: &Sim3, after: &Sim3| before.inverse().compose(after);
        let mut known = BTreeSet::new();
        for (k, before, after) in &self.poses {
            known.insert(*k);
            if let Ok(now) = graph.pose(*k) {
                graph.set_pose(*k, now.compose(&delta(before, after)))?;
            }
        }
        let Some((_, before, after)) = self.poses.last() else {
            return Ok(());
        };
        let last = delta(before, after);
        let newer: Vec<KeyframeId> = graph
            .keyframes()
            .filter(|(k, kf)| kf.map() == self.map && !known.contains(k))
            .filter(|(k, _)| self.poses.last().is_some_and(|(l, _, _)| k > l))
            .map(|(k, _)| k)
            .collect();
        for k in newer {
            let now = graph.pose(k)?;
            graph.set_pose(k, now.compose(&last))?;
        }
        Ok(())
    }
}

/// One keyframe for the loop stage.
#[derive(Clone, Debug)]
pub(crate) struct MonoLoopJob {
    /// The keyframe.
    pub keyframe: KeyframeId,
    /// Its map.
    pub map: usize,
    /// Its image.
    pub image: Arc<GrayImage>,
    /// The frame it was made from.
    pub frame: usize,
}

/// The keyframe databases, one per map (a map's keyframes are recognised by keyframes of its
/// own map as loops, by keyframes of later maps as joins), shared with the tracking thread's
/// relocalisation.
pub(crate) struct MonoPlaces {
    vocabulary: Arc<Vocabulary>,
    config: PlaceRecognitionConfig,
    maps: BTreeMap<usize, PlaceRecognition>,
}

impl MonoPlaces {
    /// No map yet; `config` in Sim(3) mode (`SystemConfig::place_recognition_for`).
    pub fn new(vocabulary: Arc<Vocabulary>, config: PlaceRecognitionConfig) -> Self {
        debug_assert_eq!(config.alignment, Alignment::Sim3);
        MonoPlaces {
            vocabulary,
            config,
            maps: BTreeMap::new(),
        }
    }

    /// The configuration (features are extracted with it).
    pub fn config(&self) -> &PlaceRecognitionConfig {
        &self.config
    }

    /// Map `map`'s database, if it has keyframes.
    pub fn of(&self, map: usize) -> Option<&PlaceRecognition> {
        self.maps.get(&map)
    }

    /// Every map's keyframes' features.
    pub fn entries(&self) -> impl Iterator<Item = (KeyframeId, &KeyframeFeatures)> {
        self.maps.values().flat_map(|p| p.entries())
    }

    /// Adds keyframe `k`'s `features` to map `map`'s database (a loaded map's).
    pub fn insert(
        &mut self,
        map: usize,
        k: KeyframeId,
        features: KeyframeFeatures,
    ) -> Result<(), String> {
        self.of_mut(map)?
            .insert(k, features)
            .map_err(|e| e.to_string())
    }

    /// Map `map`'s database, made if new.
    fn of_mut(&mut self, map: usize) -> Result<&mut PlaceRecognition, String> {
        if !self.maps.contains_key(&map) {
            let place = PlaceRecognition::new(self.vocabulary.clone(), self.config.clone())
                .map_err(|e| e.to_string())?;
            self.maps.insert(map, place);
        }
        Ok(self.maps.get_mut(&map).expect("made above"))
    }
}

/// A place of an earlier map seen from a keyframe of a later one.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Join {
    /// The earlier map.
    other: usize,
    detection: LoopDetection,
    inliers: usize,
}

/// The monocular loop stage (see the [module docs](self)).
pub(crate) struct MonoLoops {
    places: Arc<RwLock<MonoPlaces>>,
    store: Arc<RwLock<KeyframeStore>>,
    camera: PinholeCamera,
    /// `mapping.theta`, `loops.exclusion_recent` and `loops.exclusion_hops`: what is
    /// topologically close.
    theta: usize,
    recent: usize,
    hops: usize,
    /// The guided search of a detection's old place ([`MonoLoops::fit_old_place`]).
    search: PlaceSearch,
    scratch: SearchScratch,
    /// `mono.loop_consistency`, `mono.loop_agreement`, `mono.max_loop_drift` (no cap unless
    /// set), `mono.loop_min_found_fraction`.
    consistency: usize,
    agreement: LoopAgreement,
    limits: Option<DriftLimits>,
    /// `mono.loop_min_found_fraction`.
    min_found_fraction: f64,
    /// `mono.correct_live`, and what the correction needs: the double window's edge
    /// information, `mono.loop_correction`'s group.
    live: Option<(slam::dwo::DwoParams, LoopCorrection)>,
    /// The loops accepted so far, per map (the live correction's loop edges).
    accepted_loops: BTreeMap<usize, Vec<LoopDetection>>,
    /// A live correction of this map is due (loops were accepted since the last one).
    due: Option<usize>,
    /// Live corrections sent, and those the tracking thread has applied (shared with it): a
    /// correction is solved only once the previous one is in the graph, so that each snapshot
    /// holds every earlier correction (one solved on a graph without the previous one would
    /// correct twice).
    sent: usize,
    applied: Arc<AtomicUsize>,
    /// The map of the keyframes of the chains below (a new map starts them anew).
    map: Option<usize>,
    /// The latest run of mutually consistent loop detections, and whether it was accepted.
    chain: Vec<LoopDetection>,
    accepted: bool,
    /// The joins of the current map accepted so far, and its latest run of consistent ones.
    joins: Vec<Join>,
    join_chain: Vec<Join>,
}

impl MonoLoops {
    /// The stage on `places` (shared with the relocalisation) for `camera`: what is
    /// topologically close by `theta`, `recent` and `hops` (`mapping.theta`,
    /// `loops.exclusion_recent`, `loops.exclusion_hops`), the acceptance by `mono`'s thresholds.
    pub fn new(
        places: Arc<RwLock<MonoPlaces>>,
        store: Arc<RwLock<KeyframeStore>>,
        camera: PinholeCamera,
        config: &SystemConfig,
        applied: Arc<AtomicUsize>,
    ) -> Self {
        let mono = &config.mono;
        let place = read_lock(&places).config.clone();
        MonoLoops {
            places,
            store,
            camera,
            theta: config.mapping.theta,
            recent: config.loops.exclusion_recent,
            hops: config.loops.exclusion_hops,
            search: PlaceSearch {
                radius: config.tracker.wide_search_radius,
                min_ncc: config.tracker.min_ncc,
                max_view_angle: config.tracker.max_view_angle_deg.to_radians(),
                fast_threshold: config.tracker.fast_threshold,
                pixel_sigma: place.pixel_sigma,
                gate: lsq::chi2_quantile(2, place.inlier_probability).sqrt(),
                ransac_confidence: place.ransac_confidence,
                ransac_max_iterations: place.ransac_max_iterations,
                seed: place.seed,
            },
            scratch: SearchScratch::default(),
            consistency: mono.loop_consistency,
            agreement: mono.loop_agreement,
            min_found_fraction: mono.loop_min_found_fraction,
            limits: mono.max_loop_drift.map(|of_path| DriftLimits {
                of_path,
                of_scene_depth: 0.0,
            }),
            live: mono
                .correct_live
                .then(|| (config.double_window(camera.fx, None), mono.loop_correction)),
            accepted_loops: BTreeMap::new(),
            due: None,
            sent: 0,
            applied,
            map: None,
            chain: Vec::new(),
            accepted: false,
            joins: Vec::new(),
            join_chain: Vec::new(),
        }
    }

    /// The same stage on the same databases, its chains started anew (a stage lost with its
    /// thread made again).
    pub fn again(&self) -> Self {
        MonoLoops {
            places: self.places.clone(),
            store: self.store.clone(),
            map: None,
            chain: Vec::new(),
            accepted: false,
            joins: Vec::new(),
            join_chain: Vec::new(),
            scratch: SearchScratch::default(),
            accepted_loops: self.accepted_loops.clone(),
            live: self.live.clone(),
            applied: self.applied.clone(),
            ..*self
        }
    }

    fn frames(&self, a: KeyframeId, b: KeyframeId) -> (usize, usize) {
        let store = read_lock(&self.store);
        let frame_of = |k: KeyframeId| store.get(k).map_or(usize::MAX, |i| i.frame_index);
        (frame_of(a), frame_of(b))
    }

    /// The keyframe into its map's database, and its loop with an old place of that map if
    /// one is verified and agrees with the detections before it.
    fn close_loop(
        &mut self,
        graph: &SharedGraph<2>,
        job: &MonoLoopJob,
        out: &mut Vec<LoopOutput<MonoLoopData>>,
    ) {
        let k = job.keyframe;
        let (samples, excluded) = {
            let g = graph.read();
            (
                slam::loop_closure::constraint::depth_samples(&g, k),
                topologically_close(&g, k, self.theta, self.recent, self.hops),
            )
        };
        let detected = {
            let mut places = write_lock(&self.places);
            let place = match places.of_mut(job.map) {
                Ok(place) => place,
                Err(e) => return out.push(LoopOutput::Warning(e)),
            };
            if let Err(e) = place.add_monocular_keyframe(k, &job.image, samples, &self.camera) {
                return out.push(LoopOutput::Warning(format!(
                    "place recognition at frame {}: {e}",
                    job.frame
                )));
            }
            place.detect(k, &excluded)
        };
        let c = match detected {
            Ok(Some(c)) => c,
            Ok(None) => return,
            Err(e) => {
                return out.push(LoopOutput::Warning(format!(
                    "loop detection at frame {}: {e}",
                    job.frame
                )));
            }
        };
        let fit = self.fit_old_place(graph, job, c.old, &c.query_from_old);
        let g = graph.read();
        let measured = fit
            .as_ref()
            .map_or(c.query_from_old, |f| f.current_from_old);
        let Some(drift) = loop_drift(&g, c.old, k, &measured) else {
            return;
        };
        let refused = |reason: String, allowed: Option<f64>| {
            LoopOutput::Refused(RefusedLoop {
                frames: self.frames(k, c.old),
                drift,
                allowed,
                reason,
            })
        };
        let fit = match fit {
            Ok(fit) => fit,
            Err(reason) => return out.push(refused(reason, None)),
        };
        if let Some(limits) = self.limits.filter(|l| !drift.within(l)) {
            let allowed = drift.allowed(&limits);
            return out.push(refused(
                format!("needs more correction than mono.max_loop_drift allows ({allowed:.2})"),
                Some(allowed),
            ));
        }
        let detection = LoopDetection {
            current: k,
            old: c.old,
            current_from_old: fit.current_from_old,
            drift: Some(drift),
            evidence: Some(LoopEvidence {
                ransac_inliers: c.ransac_inliers,
                old_points_found: fit.found,
                old_points_predicted: fit.predicted,
            }),
            scale_sigma: fit.scale_sigma,
        };
        // Consistent with the last detection, if that was a few keyframes ago.
        let follows = self.chain.last().is_some_and(|last| {
            k.index() - last.current.index() <= self.consistency
                && loops_agree(&g, last, &detection, &self.agreement)
        });
        if !follows {
            self.chain.clear();
            self.accepted = false;
        }
        self.chain.push(detection);
        let newly: Vec<LoopDetection> = if self.accepted {
            vec![detection]
        } else if self.chain.len() >= self.consistency {
            self.accepted = true;
            self.chain.clone()
        } else {
            Vec::new()
        };
        let agreeing = self.chain.len();
        let any = !newly.is_empty();
        for d in newly {
            out.push(LoopOutput::Loop(LoopEvent {
                keyframe: d.current,
                old: d.old,
                frames: self.frames(d.current, d.old),
                kind: "appearance",
                scale: Some(d.current_from_old.scale()),
                scale_sigma: d.scale_sigma,
                agreeing: Some(agreeing),
                correction: d.drift,
                evidence: d.evidence,
            }));
            out.push(LoopOutput::Sensor(MonoLoopData::Accepted(d)));
            self.accepted_loops.entry(job.map).or_default().push(d);
        }
        if any && self.live.is_some() {
            self.due = Some(job.map);
        }
    }

    /// The live correction (`mono.correct_live`; thesis ch. 5, "both ends of the graph
    /// attached" while the run goes on): the map's pose graph with every loop accepted so far
    /// ([`map_edges`]) solved on a snapshot of the graph — the graph's lock held only to copy
    /// it — and given to the tracking thread, which writes it into the graph as it is by then
    /// ([`LiveCorrection::apply`]) and carries the exploration over.
    /// Whether a correction was sent.
    fn correct_live(
        &mut self,
        graph: &SharedGraph<2>,
        map: usize,
        out: &mut Vec<LoopOutput<MonoLoopData>>,
    ) -> bool {
        let Some((dwo, correction)) = &self.live else {
            return false;
        };
        let t = Instant::now();
        let loops = self.accepted_loops.get(&map).map_or(&[][..], Vec::as_slice);
        let mut snapshot = graph.snapshot();
        let before: Vec<(KeyframeId, Sim3)> = snapshot
            .keyframes()
            .filter(|(_, kf)| kf.map() == map)
            .map(|(k, kf)| (k, *kf.camera_from_world()))
            .collect();
        let (edges, chain) = map_edges(&snapshot, map, loops, self.theta, dwo);
        let group = correction_groups(*correction).0;
        if let Err(e) = correct_loops(
            &mut snapshot,
            map,
            (&edges, &chain),
            group,
            lie::LogJacobian::Cbh3,
        ) {
            out.push(LoopOutput::Warning(format!(
                "live loop correction in {group:?}: {e}"
            )));
            return false;
        }
        let poses = before
            .into_iter()
            .filter_map(|(k, b)| Some((k, b, snapshot.pose(k).ok()?)))
            .collect();
        out.push(LoopOutput::Sensor(MonoLoopData::Corrected(
            LiveCorrection { map, poses },
        )));
        out.push(LoopOutput::Timing("loop: live correction", t.elapsed()));
        true
    }

    /// Detection `current_from_old` (keyframe `job.keyframe` sees the place of `old`) measured
    /// again on the old place's map points, as ORB-SLAM's loop closer re-measures its
    /// similarity on map points (Mur-Artal et al. 2015, §VI-B) — the detection's own similarity
    /// rests on ORB keypoints whose depths are regressed from the keyframes' young points, its
    /// scale good to ±10–20 % on a drive (bench/README, the rendered town):
    ///
    /// 1. The map points of the old place (`old` and the keyframes sharing at least Θ points
    ///    with it) are searched in the new keyframe's image at the pose the detection implies
    ///    (the tracker's guided search: each point's template warped from its anchor, the
    ///    tracker's radius and correlation); those the new keyframe measures already count as
    ///    found where it measures them.
    /// 2. The new keyframe's pose in the old place's frame and units by P3P RANSAC and
    ///    Gauss-Newton on the found points' reprojections (`geom::pnp`), the place's pixel noise
    ///    and χ² gate: the old place's points themselves, matured over many keyframes, fix the
    ///    rotation and the translation.
    /// 3. The scale between the two places from the points the new keyframe measures at the
    ///    same corner as a found old point (its own, young point there, or the old point
    ///    itself): the median of `ln(depth in the new keyframe's map / depth at the fitted
    ///    pose)`, its standard error `1.2533·1.4826·MAD/√n` reported (the Sim(3)'s scale
    ///    uncertainty). With fewer than three such points the detection's scale is kept.
    ///
    /// The evidence a loop is accepted on: a look-alike place is seldom found again point by
    /// point where the loop says it is. Refused, with the reason, if fewer than Θ of the old
    /// place's points are found consistent with one pose — Θ, the points that make two
    /// keyframes neighbours in the map (`mapping.theta`) — or fewer than
    /// `mono.loop_min_found_fraction` of those predicted visible (a large place offers Θ
    /// chance matches; a look-alike matches only its repeated parts).
    fn fit_old_place(
        &mut self,
        graph: &SharedGraph<2>,
        job: &MonoLoopJob,
        old: KeyframeId,
        current_from_old: &Sim3,
    ) -> Result<PlaceFit, String> {
        let k = job.keyframe;
        let (old_pose, implied, samples) = {
            let g = graph.read();
            let old_pose = g.pose(old).map_err(|e| e.to_string())?;
            (
                old_pose,
                rigid_from_similarity(&current_from_old.compose(&old_pose)),
                slam::loop_closure::constraint::depth_samples(&g, k),
            )
        };
        let (found, predicted) = self.search_place(graph, job, old, &implied)?;
        let too_few = |consistent: usize| {
            format!(
                "{} of the old place's {predicted} points predicted visible found at the loop's \
                 pose, {consistent} consistent with one pose; {} needed",
                found.len(),
                self.theta
            )
        };
        let Some((pose, inliers)) = self.consistent(&found, k, old) else {
            return Err(too_few(0));
        };
        if inliers.len() < self.theta {
            return Err(too_few(inliers.len()));
        }
        enough_of_the_place(inliers.len(), predicted, self.min_found_fraction)?;
        // The scale: the new keyframe's own depth at the corner of each consistent point.
        let mut ratios: Vec<f64> = inliers
            .iter()
            .filter_map(|&i| {
                let (world, z) = found[i];
                let (_, own) = samples
                    .iter()
                    .map(|(p, d)| ((p - z).norm(), *d))
                    .filter(|&(dist, _)| dist < SAME_CORNER_PX)
                    .min_by(|a, b| a.0.total_cmp(&b.0))?;
                let at_pose = pose.act(&world).z;
                (own > 0.0 && at_pose > 0.0).then(|| (own / at_pose).ln())
            })
            .collect();
        let (scale, scale_sigma) = if ratios.len() >= 3 {
            let median = median_of(&mut ratios);
            let mut deviations: Vec<f64> = ratios.iter().map(|r| (r - median).abs()).collect();
            let mad = median_of(&mut deviations);
            (
                median.exp(),
                Some(1.2533 * 1.4826 * mad / (ratios.len() as f64).sqrt()),
            )
        } else {
            (current_from_old.scale(), None)
        };
        let scaled =
            Sim3::new(lie::So3::identity(), Vector3::zeros(), scale).map_err(|e| e.to_string())?;
        Ok(PlaceFit {
            current_from_old: scaled
                .compose(&Sim3::from_se3(&pose))
                .compose(&old_pose.inverse()),
            found: inliers.len(),
            predicted,
            scale_sigma,
        })
    }

    /// The map points of the place of keyframe `place_of` (it and the keyframes sharing at
    /// least Θ points with it) that a camera at `implied` would see, searched in `job`'s
    /// keyframe image there: `(found: (point, pixel), predicted)`. Those the new keyframe
    /// measures already count as found where it measures them.
    fn search_place(
        &mut self,
        graph: &SharedGraph<2>,
        job: &MonoLoopJob,
        place_of: KeyframeId,
        implied: &lie::Se3,
    ) -> Result<(Vec<Found>, usize), String> {
        let image = &*job.image;
        let (w, h) = (image.width(), image.height());
        // Copied out under the graph's read lock; the search with no lock held.
        let (points, measured) = {
            let g = graph.read();
            let own = g
                .keyframe(job.keyframe)
                .ok_or("the keyframe left the map")?
                .observations()
                .clone();
            let place: Vec<KeyframeId> = shared_points(&g, place_of)
                .into_iter()
                .filter(|&(o, n)| o == place_of || n >= self.theta)
                .map(|(o, _)| o)
                .collect();
            let mut points = Vec::new();
            let mut measured = Vec::new();
            for p in g.points_visible_from(&place) {
                let Some(sp) = SearchPoint::from_graph(&g, p) else {
                    continue;
                };
                if let Some(z) = own.get(&p) {
                    measured.push((sp.world, Vector2::new(z[0], z[1])));
                } else if view_angle(implied, &sp) <= self.search.max_view_angle
                    && predict(&self.camera, implied, &sp, w, h, PATCH_MARGIN_PX).is_some()
                {
                    points.push(sp);
                }
            }
            (points, measured)
        };
        let predicted = points.len() + measured.len();
        let store = read_lock(&self.store).clone();
        let corners = CornerIndex::new(
            fast9(image, self.search.fast_threshold, true),
            w,
            h,
            CORNER_CELL_PX,
        );
        let mut found = measured;
        for sp in &points {
            let Some(anchor) = store.get(sp.anchor) else {
                continue;
            };
            if let Some(z) = search(
                &self.camera,
                implied,
                sp,
                anchor,
                image,
                &corners,
                self.search.radius,
                self.search.min_ncc,
                &mut self.scratch,
            ) {
                found.push((sp.world, z));
            }
        }
        Ok((found, predicted))
    }

    /// Keyframe `k`'s pose from the points `found` in its image by P3P RANSAC and Gauss-Newton
    /// (the place's pixel noise and χ² gate), with the indices of the points consistent with
    /// it; `None` with fewer than three points or no consensus.
    fn consistent(
        &self,
        found: &[Found],
        k: KeyframeId,
        old: KeyframeId,
    ) -> Option<(lie::Se3, Vec<usize>)> {
        if found.len() < self.theta.max(3) {
            return None;
        }
        let f = 0.5 * (self.camera.fx + self.camera.fy);
        let normalised: Vec<Vector2<f64>> = found
            .iter()
            .map(|(_, z)| self.camera.normalised_from_pixel(z))
            .collect();
        let world: Vec<Vector3<f64>> = found.iter().map(|(x, _)| *x).collect();
        let sigma = vec![self.search.pixel_sigma / f; found.len()];
        let estimator = PnpEstimator {
            normalised: &normalised,
            points: &world,
            sigma: &sigma,
        };
        let config = RansacConfig {
            threshold: self.search.gate,
            confidence: self.search.ransac_confidence,
            max_iterations: self.search.ransac_max_iterations,
            min_iterations: 10,
            seed: self
                .search
                .seed
                .wrapping_add(((k.index() as u64) << 32) | old.index() as u64),
        };
        let result = ransac(&estimator, &config).ok()?;
        let pose = estimator
            .refine(&result.model, &result.inliers, 10)
            .unwrap_or(result.model);
        let inliers = (0..found.len())
            .filter(|&i| estimator.error(&pose, i) <= self.search.gate)
            .collect();
        Some((pose, inliers))
    }

    /// A keyframe `k` of a map started after tracking was lost, against the keyframe
    /// databases of the earlier maps (monocular map joining; ORB-SLAM3's Atlas merges its maps
    /// on such a detection): its ORB words scored against each earlier map's keyframes, the best
    /// verified by the 3-point Sim(3) RANSAC on regressed depths as a loop is
    /// ([`PlaceRecognition::relocalise`] with the keyframe's features and depth samples). As a
    /// loop, a join is accepted once `mono.loop_consistency` detections in a row agree. After that,
    /// each later detection that agrees with the last accepted one is kept too: the outputs take
    /// the similarity between the two worlds from the one with the most inliers, the best
    /// measured (`slam::map::maps::map_links`). The maps stay apart while the run goes on.
    fn join_maps(
        &mut self,
        graph: &SharedGraph<2>,
        job: &MonoLoopJob,
        out: &mut Vec<LoopOutput<MonoLoopData>>,
    ) {
        let k = job.keyframe;
        let places = read_lock(&self.places);
        let Some(features) = places.of(job.map).and_then(|p| p.features(k)) else {
            return;
        };
        let mut accepted = Vec::new();
        for (&other, place) in places.maps.range(..job.map) {
            let last = self.joins.iter().rfind(|j| j.other == other).copied();
            let Some(c) = place.relocalise(k.index() as u32, features) else {
                continue;
            };
            let join = Join {
                other,
                detection: LoopDetection {
                    current: k,
                    old: c.old,
                    current_from_old: c.query_from_old,
                    drift: None,
                    evidence: None,
                    scale_sigma: None,
                },
                inliers: c.inliers.len(),
            };
            let g = graph.read();
            if let Some(last) = last {
                if loops_agree(&g, &last.detection, &join.detection, &self.agreement) {
                    accepted.push(join);
                }
                continue;
            }
            let follows = self.join_chain.last().is_some_and(|last| {
                last.other == join.other
                    && k.index() - last.detection.current.index() <= self.consistency
                    && loops_agree(&g, &last.detection, &join.detection, &self.agreement)
            });
            if !follows {
                self.join_chain.clear();
            }
            self.join_chain.push(join);
            if self.join_chain.len() >= self.consistency {
                accepted.append(&mut self.join_chain);
            }
            break;
        }
        drop(places);
        for j in accepted {
            let d = j.detection;
            if let Err(e) = graph
                .write()
                .join_maps(d.current, d.old, d.current_from_old, j.inliers)
            {
                out.push(LoopOutput::Warning(format!("map join: {e}")));
                continue;
            }
            out.push(LoopOutput::Loop(LoopEvent {
                keyframe: d.current,
                old: d.old,
                frames: self.frames(d.current, d.old),
                kind: "merge",
                scale: Some(d.current_from_old.scale()),
                scale_sigma: None,
                agreeing: None,
                correction: None,
                evidence: None,
            }));
            self.joins.push(j);
        }
    }
}

impl Stage<2> for MonoLoops {
    type Job = MonoLoopJob;
    type Output = LoopOutput<MonoLoopData>;

    fn run(&mut self, graph: &SharedGraph<2>, job: &MonoLoopJob, out: &mut Vec<Self::Output>) {
        if self.map != Some(job.map) {
            // A new map numbers nothing anew, but its loops and joins are its own.
            self.map = Some(job.map);
            self.chain.clear();
            self.accepted = false;
            self.joins.clear();
            self.join_chain.clear();
        }
        let t = Instant::now();
        self.close_loop(graph, job, out);
        if let Some(map) = self.due
            && self.applied.load(Ordering::Acquire) == self.sent
        {
            self.due = None;
            if self.correct_live(graph, map, out) {
                self.sent += 1;
            }
        }
        out.push(LoopOutput::Timing(
            "keyframe: place recognition",
            t.elapsed(),
        ));
        let earlier = {
            let places = read_lock(&self.places);
            places.maps.range(..job.map).next().is_some()
        };
        if earlier {
            let t = Instant::now();
            self.join_maps(graph, job, out);
            out.push(LoopOutput::Timing(
                "keyframe: join earlier maps",
                t.elapsed(),
            ));
        }
    }
}

/// The median of `values` (reordered; not empty; the upper one of an even count).
fn median_of(values: &mut [f64]) -> f64 {
    let mid = values.len() / 2;
    *values.select_nth_unstable_by(mid, f64::total_cmp).1
}

/// The correction the loop `k_from_old` between keyframes `old` and `k` makes to `k`, against
/// the path between them.
fn loop_drift(
    graph: &SlamGraph<2>,
    old: KeyframeId,
    k: KeyframeId,
    k_from_old: &Sim3,
) -> Option<LoopDrift> {
    let t_old = graph.pose(old).ok()?;
    LoopDrift::of(graph, old, k, &k_from_old.compose(&t_old))
}

/// For every keyframe sharing map points with `k` (`k` included), how many, in id order. The
/// monocular explorer adds no graph edges outside its double-window mode, so the covisibility
/// weights are counted from the points' observers here rather than read from `SlamGraph`'s
/// edges: the observers collected, sorted and counted in runs (a map keyed by keyframe cost 4 %
/// of a monocular KITTI run: the `N2` search counts it for a hundred keyframes at each one).
pub(crate) fn shared_points(graph: &SlamGraph<2>, k: KeyframeId) -> Vec<(KeyframeId, usize)> {
    let mut observers: Vec<KeyframeId> = Vec::new();
    if let Some(kf) = graph.keyframe(k) {
        for p in kf.observations().keys() {
            if let Some(pt) = graph.point(*p) {
                observers.extend(pt.observers().iter().copied());
            }
        }
    }
    observers.sort_unstable();
    let mut shared: Vec<(KeyframeId, usize)> = Vec::new();
    for o in observers {
        match shared.last_mut() {
            Some((last, n)) if *last == o => *n += 1,
            _ => shared.push((o, 1)),
        }
    }
    shared
}

/// The keyframes topologically close to `k`, never a loop's old place (thesis §6.4.2): the
/// last `recent` keyframes and every keyframe within `hops` steps of `k` in the covisibility
/// graph, a step joining two keyframes that share at least `theta` points (the graph's sense of
/// connected, as the stereo system's edges and its `loops.exclusion_hops`). A handful of shared
/// points does not close a loop: after a drifted revisit the guided search finds a few of the
/// old place's points from the drifted pose, too few to hold the map, and excluding every
/// keyframe that shares one of them hid the old place from detection for the rest of the
/// revisit (rendered building, 2026-12-02: the last 45 keyframes shared 1–10 points each with
/// the first ones, and no loop was detected after the first three). One step was too few on a
/// drive: keyframes 20–40 frames back on the same street see the same far façades, and their
/// detections, redundant with the chain that joins them through the keyframes between, were
/// accepted as loops and bent the chain in the correction (rendered town, bench/README).
fn topologically_close(
    graph: &SlamGraph<2>,
    k: KeyframeId,
    theta: usize,
    recent: usize,
    hops: usize,
) -> BTreeSet<KeyframeId> {
    let mut close = crate::loops::within_hops(k, hops, |a| {
        shared_points(graph, a)
            .into_iter()
            .filter(|&(o, n)| o != a && n >= theta)
            .map(|(o, _)| o)
            .collect()
    });
    close.extend(crate::loops::recent_keyframes(k, recent));
    close
}

/// Whether detection `b` agrees with the earlier `a` through the map's relative poses (the
/// odometry is locally accurate on both sides of a loop; for a join, on each side in its own
/// map), within `agreement`.
fn loops_agree(
    graph: &SlamGraph<2>,
    a: &LoopDetection,
    b: &LoopDetection,
    agreement: &LoopAgreement,
) -> bool {
    let rel = |x: KeyframeId, y: KeyframeId| -> Option<Sim3> {
        Some(graph.pose(x).ok()?.compose(&graph.pose(y).ok()?.inverse()))
    };
    let (Some(cur), Some(old)) = (rel(b.current, a.current), rel(a.old, b.old)) else {
        return false;
    };
    // x_kb = T_kb,ka · S_a · T_olda,oldb · x_oldb.
    let predicted = cur.compose(&a.current_from_old).compose(&old);
    let delta = predicted.inverse().compose(&b.current_from_old);
    let mut depths: Vec<f64> = slam::loop_closure::constraint::depth_samples(graph, b.old)
        .into_iter()
        .map(|(_, d)| d)
        .collect();
    if depths.is_empty() {
        return false;
    }
    depths.sort_by(f64::total_cmp);
    let depth = depths[depths.len() / 2];
    delta.rotation().log().norm().to_degrees() <= agreement.rotation_deg
        && delta.scale().ln().abs() <= agreement.scale
        && delta.translation().norm() <= agreement.translation * depth
}

/// `mono.loop_correction`'s group and the other one.
pub(crate) fn correction_groups(correction: LoopCorrection) -> (CorrectionGroup, CorrectionGroup) {
    match correction {
        LoopCorrection::Se3 => (CorrectionGroup::Se3, CorrectionGroup::Sim3),
        LoopCorrection::Sim3 => (CorrectionGroup::Sim3, CorrectionGroup::Se3),
    }
}

/// The pose graph of map `map` (positions in its chain of keyframes, id order): its loop
/// edges — the accepted `loops` (thesis §5.3.2) and the covisibility edges, every pair of
/// keyframes sharing at least `theta` map points, not consecutive, constrained to their
/// relative pose in the map as it is (scale 1) — and the informations of its consecutive
/// constraints. With map reuse the map holds keyframes far apart on the path that measure the
/// same points (a revisited place whose points were found again): the loop there is already
/// closed, and the covisibility edges keep it closed.
///
/// **Information** (thesis eq. 6.2, the double window's coarse information,
/// `slam::dwo::DwoParams::edge_precision`): an edge between keyframes `i` and `j` that share
/// `w` points seen by `j` at median depth `d̄` is worth `w·diag(λ_trans²·I₃, λ_rot²·I₃,
/// λ_scale²)`: as the thesis has it, `λ_rot = f/σ` constant (two views fix their relative
/// rotation through the points' directions alone, whatever the baseline) and `λ_trans`
/// proportional to the parallax, `λ_trans = (f/σ)·(‖t_ji‖/d̄)/d̄`; the scale, which a monocular
/// map carries from keyframe to keyframe through the depths of points triangulated over that
/// parallax, `λ_scale = (f/σ)·‖t_ji‖/d̄`. With the identity instead, bending the chain by small
/// rotations was the cheapest way to absorb a loop's correction on a drive, and the correction
/// made the trajectory worse than the live one (rendered town); with the rotation's precision
/// scaled by the parallax as well (the double window's `edge_precision`), the chain bent where
/// the camera moved little: rendered building 13.7 cm after the run against 11.5 cm, town
/// 0.98 / 0.59 m against 0.91 / 0.50 m (bench/README, seventeenth session). A loop edge's relative
/// pose is measured against the old place's points, whose positions the map already holds
/// (no parallax needed): `w` the points found, `λ_rot = f/σ`, its scale's precision
/// `1/(σ_s² + 1/(w·λ_rot²))` from the fit's standard error `σ_s`
/// (`loops::MonoLoops::fit_old_place`); a loop without it has the same scale precision as its
/// rotation.
pub(crate) fn map_edges(
    graph: &SlamGraph<2>,
    map: usize,
    loops: &[LoopDetection],
    theta: usize,
    dwo: &slam::dwo::DwoParams,
) -> (Vec<LoopEdge>, Vec<EdgeInformation>) {
    let chain: Vec<KeyframeId> = graph
        .keyframes()
        .filter(|(_, kf)| kf.map() == map)
        .map(|(k, _)| k)
        .collect();
    let position: BTreeMap<KeyframeId, usize> =
        chain.iter().enumerate().map(|(i, &k)| (k, i)).collect();
    let mut shared: BTreeMap<(KeyframeId, KeyframeId), usize> = Default::default();
    for (_, point) in graph.points() {
        let observers: Vec<KeyframeId> = point
            .observers()
            .iter()
            .copied()
            .filter(|k| position.contains_key(k))
            .collect();
        for (i, &a) in observers.iter().enumerate() {
            for &b in &observers[i + 1..] {
                *shared.entry((a.min(b), a.max(b))).or_default() += 1;
            }
        }
    }
    let depth: BTreeMap<KeyframeId, f64> = chain
        .iter()
        .filter_map(|&k| {
            let mut d: Vec<f64> = slam::loop_closure::constraint::depth_samples(graph, k)
                .into_iter()
                .map(|(_, d)| d)
                .collect();
            (!d.is_empty()).then(|| {
                let mid = d.len() / 2;
                (k, *d.select_nth_unstable_by(mid, f64::total_cmp).1)
            })
        })
        .collect();
    // The pose graph's vertices are the keyframes' rigid poses `(R, t/s)`
    // (`correct_map`), a keyframe's stored similarity `T_k = S(s_k)·V_k`; a relative pose
    // `a_from_b` measured between the stored (keyframe-local) frames is the edge
    // `V_a·V_b⁻¹ = S(s_a)⁻¹·a_from_b·S(s_b)`. Once a correction has given the keyframes
    // scales other than 1 (a live correction, a map join), an edge taken between the stored
    // frames instead would carry their scale ratio into the next correction, which then
    // compounded it: the threaded live correction's graph reached keyframe scales of 1e-20 and
    // 1e13 after eleven corrections (rendered town, seventeenth session).
    let stored_scale = |k: KeyframeId| graph.pose(k).ok().map(|p| p.scale());
    let between_vertices = |a: KeyframeId, a_from_b: &Sim3, b: KeyframeId| -> Option<Sim3> {
        let scaling = |s: f64| Sim3::new(lie::So3::identity(), Vector3::zeros(), s).ok();
        Some(
            scaling(1.0 / stored_scale(a)?)?
                .compose(a_from_b)
                .compose(&scaling(stored_scale(b)?)?),
        )
    };
    let relative = |a: KeyframeId, b: KeyframeId| -> Option<Sim3> {
        let rigid = |k: KeyframeId| graph.pose(k).ok().map(|p| rigid_from_similarity(&p));
        Some(Sim3::from_se3(&rigid(a)?.compose(&rigid(b)?.inverse())))
    };
    // Edge `a → b` (`b` the younger): `w` shared points at `b`'s median depth (in the
    // vertices' units: a stored frame's depths are `s_b` times the world's).
    let information = |a: KeyframeId, b: KeyframeId, w: usize| -> Option<EdgeInformation> {
        let d = *depth.get(&b)? / stored_scale(b)?;
        let t = relative(a, b)?.translation().norm();
        let (trans, parallax_rot) = dwo.edge_precision(t, d);
        let w = w.max(1) as f64;
        Some(EdgeInformation {
            translation: w * trans,
            rotation: w * dwo.angular_precision.powi(2),
            scale: w * parallax_rot,
        })
    };
    let chain_information: Vec<EdgeInformation> = chain
        .windows(2)
        .map(|p| {
            let w = shared.get(&(p[0], p[1])).copied().unwrap_or(0);
            information(p[0], p[1], w).unwrap_or(EdgeInformation {
                translation: 1.0,
                rotation: 1.0,
                scale: 1.0,
            })
        })
        .collect();
    let mut edges: Vec<LoopEdge> = loops
        .iter()
        .filter_map(|d| {
            let w = d.evidence.map_or(theta, |e| e.old_points_found).max(1) as f64;
            let rot = w * dwo.angular_precision.powi(2);
            let scale = d.scale_sigma.map_or(rot, |s| 1.0 / (s * s + 1.0 / rot));
            let depth_old = depth.get(&d.old)? / stored_scale(d.old)?;
            Some(LoopEdge {
                old: *position.get(&d.old)?,
                current: *position.get(&d.current)?,
                // Measured between the keyframes' stored frames, whose points keep their
                // local coordinates through a correction.
                old_from_current: between_vertices(
                    d.old,
                    &d.current_from_old.inverse(),
                    d.current,
                )?,
                information: Some(EdgeInformation {
                    translation: rot / depth_old.powi(2),
                    rotation: rot,
                    scale,
                }),
            })
        })
        .collect();
    edges.extend(
        shared
            .iter()
            .filter(|&(&(a, b), &n)| n >= theta && position[&b] > position[&a] + 1)
            .filter_map(|(&(a, b), &n)| {
                Some(LoopEdge {
                    old: position[&a],
                    current: position[&b],
                    old_from_current: relative(a, b)?,
                    information: information(a, b, n),
                })
            }),
    );
    (edges, chain_information)
}

/// Corrects map `map` of `graph` through the pose graph of its keyframe chain and `edges` in
/// `group` (`slam::loop_closure::correction::correct_map`, 50 Levenberg-Marquardt iterations,
/// one thread), with the Jacobians `log` (the exact ones at the end of the run; the thesis's
/// third-order CBH while the run goes on, eq. 5.22: the exact Sim(3) one integrates `Ad` by
/// quadrature per residual, and took minutes per correction of a drive's graph).
pub(crate) fn correct_loops(
    graph: &mut SlamGraph<2>,
    map: usize,
    (edges, chain): (&[LoopEdge], &[EdgeInformation]),
    group: CorrectionGroup,
    log: lie::LogJacobian,
) -> Result<(), slam::loop_closure::correction::CorrectionError> {
    let options = lsq::SolverOptions {
        max_iterations: 50,
        threads: Some(1),
        ..lsq::SolverOptions::default()
    };
    let jacobian = PoseGraphJacobian::Analytic(log);
    correct_map(graph, map, (edges, chain), group, jacobian, &options).map(|_| ())
}

#[cfg(test)]
mod tests;
