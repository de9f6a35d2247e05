//! Large loops and map joins of the monocular system by appearance (thesis ch. 5), the loop
//! closer's stage for one camera: each keyframe's ORB words and map-point depths go into its
//! map's database; a loop is verified by kNN depth regression and a 3-point Sim(3) RANSAC
//! (`place_recognition`, [`Alignment::Sim3`]), its scale is the scale drift between the two
//! places. A keyframe of a map started after a loss is also looked up in the earlier maps'
//! databases: a recognised place of an earlier map joins the two maps
//! (`slam::map::SlamGraph::join_maps`), by the similarity between their worlds.
//!
//! A loop, like a join, is accepted once `mono.loop_consistency` detections in a row agree
//! through the odometry ([`loops_agree`], `mono.loop_agreement`): a place that only looks like
//! another is seldom seen so three times over; and a loop that needs more correction than
//! `mono.max_loop_drift` of the path is refused. The loops accepted go back to the sensor
//! ([`MonoLoopData::Accepted`]), which corrects the map with them at the end of the run (or
//! at once, `mono.correct_live`).

use crate::config::{LoopAgreement, MonoConfig};
use crate::keyframes::KeyframeStore;
use crate::place_recognition::{Alignment, PlaceRecognition, PlaceRecognitionConfig};
use crate::result::{LoopEvent, RefusedLoop};
use crate::session::LoopOutput;
use crate::session::backend::Stage;
use geom::PinholeCamera;
use lie::{LieGroup, Sim3};
use slam::loop_closure::{DriftLimits, LoopDrift};
use slam::map::shared::{read_lock, write_lock};
use slam::map::{KeyframeId, SharedGraph, SlamGraph};
use std::collections::{BTreeMap, BTreeSet};
use std::sync::{Arc, RwLock};
use std::time::Instant;
use vision::bow::Vocabulary;
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
}

/// What the stage gives back to the monocular sensor.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) enum MonoLoopData {
    /// A loop accepted (in the map of its keyframes).
    Accepted(LoopDetection),
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
    /// `mono.loop_consistency`, `mono.loop_agreement`, `mono.max_loop_drift`.
    consistency: usize,
    agreement: LoopAgreement,
    limits: DriftLimits,
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
        (theta, recent, hops): (usize, usize, usize),
        mono: &MonoConfig,
    ) -> Self {
        MonoLoops {
            places,
            store,
            camera,
            theta,
            recent,
            hops,
            consistency: mono.loop_consistency,
            agreement: mono.loop_agreement,
            limits: DriftLimits {
                of_path: mono.max_loop_drift,
                of_scene_depth: 0.0,
            },
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
        let g = graph.read();
        let drift = match loop_drift(&g, c.old, k, &c.query_from_old) {
            Some(drift) if drift.within(&self.limits) => drift,
            Some(drift) => {
                return out.push(LoopOutput::Refused(RefusedLoop {
                    frames: self.frames(k, c.old),
                    drift,
                    allowed: drift.allowed(&self.limits),
                }));
            }
            None => return,
        };
        let detection = LoopDetection {
            current: k,
            old: c.old,
            current_from_old: c.query_from_old,
            drift: Some(drift),
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
        for d in newly {
            out.push(LoopOutput::Loop(LoopEvent {
                keyframe: d.current,
                old: d.old,
                frames: self.frames(d.current, d.old),
                kind: "appearance",
                scale: Some(d.current_from_old.scale()),
                correction: d.drift,
                evidence: None,
            }));
            out.push(LoopOutput::Sensor(MonoLoopData::Accepted(d)));
        }
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

/// For every keyframe sharing map points with `k` (`k` included), how many. The monocular
/// explorer adds no graph edges outside its double-window mode, so the covisibility weights
/// are counted from the points' observers here rather than read from `SlamGraph`'s edges.
pub(crate) fn shared_points(graph: &SlamGraph<2>, k: KeyframeId) -> BTreeMap<KeyframeId, usize> {
    let mut shared: BTreeMap<KeyframeId, usize> = Default::default();
    if let Some(kf) = graph.keyframe(k) {
        for p in kf.observations().keys() {
            if let Some(pt) = graph.point(*p) {
                for &o in pt.observers() {
                    *shared.entry(o).or_default() += 1;
                }
            }
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

#[cfg(test)]
mod tests {
    use super::*;
    use lie::Se3;
    use nalgebra::{Vector2, Vector3};

    /// Keyframes every metre along x, looking along z, one point 5 m ahead of each.
    pub(crate) fn corridor(n: usize) -> SlamGraph<2> {
        let mut g = SlamGraph::default();
        for i in 0..n {
            let world_from_camera =
                Se3::new(lie::So3::identity(), Vector3::new(i as f64, 0.0, 0.0));
            let k = g.add_keyframe(Sim3::from_se3(&world_from_camera.inverse()));
            g.add_point(k, Vector3::new(0.0, 0.0, 0.2), Vector2::new(320.0, 240.0))
                .unwrap();
        }
        g
    }

    #[test]
    fn only_covisible_and_recent_keyframes_are_topologically_close() {
        let mut g = corridor(31);
        let id = KeyframeId::from_index;
        let z = Vector2::new(320.0, 240.0);
        // Keyframe 30 measures 25 points of keyframe 15 (covisible, θ = 20) and 3 of keyframe
        // 2 (a drifted revisit's few re-found points); keyframe 15 measures 25 of keyframe 8.
        for (old, new, n) in [(15, 30, 25), (2, 30, 3), (8, 15, 25)] {
            for _ in 0..n {
                let p = g
                    .add_point(id(old), Vector3::new(0.0, 0.0, 0.2), z)
                    .unwrap();
                g.add_observation(id(new), p, z).unwrap();
            }
        }
        let close = topologically_close(&g, id(30), 20, 10, 1);
        let expected: BTreeSet<KeyframeId> = (20..=30).chain([15]).map(id).collect();
        assert_eq!(close, expected);
        // Two steps: keyframe 8 through 15, never the revisit's keyframe 2.
        let close = topologically_close(&g, id(30), 20, 10, 2);
        let expected: BTreeSet<KeyframeId> = (20..=30).chain([15, 8]).map(id).collect();
        assert_eq!(close, expected);
        // With θ = 3 the revisit's keyframe counts as connected.
        assert!(topologically_close(&g, id(30), 3, 10, 1).contains(&id(2)));
    }

    #[test]
    fn a_loop_needing_more_drift_than_the_path_allows_is_refused() {
        let g = corridor(41);
        let (old, k) = (KeyframeId::from_index(0), KeyframeId::from_index(40));
        let pose = |k: KeyframeId| g.pose(k).unwrap();
        // The loop says keyframe 40 is 2 m from where the map has it (5 % of the 40 m path):
        // accepted; 6 m (15 %): refused.
        for (offset, accepted) in [(2.0, true), (6.0, false)] {
            let truth = Se3::new(lie::So3::identity(), Vector3::new(40.0 + offset, 0.0, 0.0));
            let k_from_old = Sim3::from_se3(&truth.inverse()).compose(&pose(old).inverse());
            let drift = loop_drift(&g, old, k, &k_from_old).unwrap();
            let limits = DriftLimits {
                of_path: MonoConfig::default().max_loop_drift,
                of_scene_depth: 0.0,
            };
            assert_eq!(drift.within(&limits), accepted, "offset {offset}");
        }
    }

    #[test]
    fn successive_detections_agree_only_when_the_odometry_carries_one_into_the_other() {
        let g = corridor(20);
        let id = KeyframeId::from_index;
        let pose = |k: usize| g.pose(id(k)).unwrap();
        // Keyframes 15 and 16 see the places of 2 and 3, 0.5 m off in x (drift).
        let shift = Sim3::from_se3(&Se3::new(
            lie::So3::identity(),
            Vector3::new(-0.5, 0.0, 0.0),
        ));
        let s = |k: usize, old: usize| shift.compose(&pose(k)).compose(&pose(old).inverse());
        let detection = |current: usize, old: usize, current_from_old: Sim3| LoopDetection {
            current: id(current),
            old: id(old),
            current_from_old,
            drift: None,
        };
        let a = detection(15, 2, s(15, 2));
        assert!(loops_agree(
            &g,
            &a,
            &detection(16, 3, s(16, 3)),
            &LoopAgreement::default()
        ));
        // A second detection that jumps to an unrelated place (keyframe 9) does not agree.
        assert!(!loops_agree(
            &g,
            &a,
            &detection(16, 9, s(16, 3)),
            &LoopAgreement::default()
        ));
        // Nor one whose scale differs by 30 %.
        let scaled = Sim3::new(lie::So3::identity(), Vector3::zeros(), 1.3)
            .unwrap()
            .compose(&s(16, 3));
        assert!(!loops_agree(
            &g,
            &a,
            &detection(16, 3, scaled),
            &LoopAgreement::default()
        ));
    }
}
