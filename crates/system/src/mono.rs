//! The monocular live system (issue 20; thesis ch. 3, §6.2.7): one camera's frames in, every
//! frame's pose and the map out, at the arbitrary scale a single camera has.
//!
//! Per frame, in the calling thread:
//!
//! 1. **Corner tracks** ([`CornerTracks`], the image side): the live tracks are followed from
//!    the previous frame by pyramidal LK, forward-backward checked; where they have thinned
//!    out, new FAST corners are selected in the quadtree's equi-distributed order (thesis
//!    Alg. 2) at least `track_spacing` pixels from every live track. Each track keeps its id
//!    while it lives; a lost track never comes back (a corner seen again is a new track).
//! 2. **Exploration** (`slam::exploration::MonoExplorer`, the same stage the simulated
//!    scale-drift studies run on simulated tracks): the two-view bootstrap with model
//!    selection between homography and essential matrix (`geom::bootstrap`), motion-only BA
//!    from a constant-velocity prior, keyframes by distance relative to the scene depth,
//!    inverse-depth feature filters (thesis eq. 3.35–3.37) started at quadtree-selected tracks
//!    of keyframes and promoted when converged, and a keyframe BA over the keyframes sharing
//!    most points with the new one, older keyframes measuring their points held fixed, the
//!    measurements it does not explain removed (map reuse: a revisited place's points, found
//!    again by guided search, hold the new keyframes where the old map has them).
//!
//! When tracking loses the map (the tracks cannot follow into `mono.max_refused` frames in a
//! row, or too few map points are measured), the map is kept and each following frame is
//! relocalised in it if it can be (`MonoSystem::relocalise`: its ORB words against the
//! keyframe database, P3P RANSAC against the best keyframes' points, the guided search of
//! their neighbourhood around that pose): the camera then tracks on in the same map, and
//! `RunResult::relocalisations` lists where. A frame the tracks cannot follow into has its
//! place looked up at once, and is relocalised there if the map has it (a jump to a mapped
//! place is not waited out for `mono.max_refused` frames). A camera not relocalised within
//! `tracker.new_map_after` seconds, or lost before a map exists or without a vocabulary,
//! starts again from the current frame, as when the bootstrap finds no geometry within
//! `max_bootstrap_frames`: the frames in between are `lost` with the reason, and the new map
//! has its own frame and scale. Each keyframe of a later map is also looked up in the earlier
//! maps' keyframe databases (`MonoSystem::join_maps`): three agreeing Sim(3)-verified
//! detections of an earlier map's place join the two maps, by the similarity between their
//! worlds. The maps are not merged for tracking; the outputs hold the group of joined maps with
//! the most keyframes in the world of its largest map (the final trajectory, the keyframes and
//! the points; the live trajectory only that map's frames, as tracked). The other maps' frames
//! have no pose, and their states say which map tracked them (`RunResult::new_maps` lists the
//! maps started after a loss and whether they were joined).

use crate::config::{MonoConfig, SystemConfig};
use crate::frame::CornerIndex;
use crate::keyframes::{KeyframeImages, KeyframeReason, KeyframeStore};
use crate::live::{
    FrameReport, LiveRun, LoopEvent, NewMap, Relocalisation, RunResult, SystemError, largest_map,
    skipped_frame, write_map,
};
use crate::place_recognition::features::extract as extract_features;
use crate::place_recognition::{Alignment, PlaceRecognition, PlaceRecognitionConfig};
use crate::search::{SearchPoint, SearchScratch, predict, relocate, search, view_angle};
use crate::tracker::TrackerStats;
use data::output::{FrameRecord, KeyframeRecord, MapPoint, RunRecord, TrackingState};
use data::trajectory::Trajectory;
use geom::PinholeCamera;
use lie::{LieGroup, Se3, Sim3};
use nalgebra::{Vector2, Vector3};
use slam::exploration::{ExplorationConfig, ExplorationError, LocalWindow, MonoExplorer, TrackId};
use slam::loop_closure::correction::correct_graph;
use slam::loop_closure::{CorrectionGroup, DriftLimits, LoopDrift, LoopEdge};
use slam::map::SlamGraph;
use slam::map::{FIRST_MAP, KeyframeId};
use slam::pose_graph::{PoseGraphJacobian, rigid_from_similarity};
use std::collections::BTreeSet;
use std::time::{Duration, Instant};
use vision::fast::fast9;
use vision::image::{GrayImage, ImageError};
use vision::lk::{LkParams, track_forward_backward};
use vision::pyramid::Pyramid;
use vision::quadtree::select_corners;

/// A live track: its id and its position in the last frame (pixels).
pub type Track = (TrackId, [f32; 2]);

/// The live tracks.
pub type Tracks = Vec<Track>;

/// A frame the tracks could not follow into: `(survived, of)` tracks.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Refused {
    /// Tracks that survived.
    pub survived: usize,
    /// Tracks of the previous frame.
    pub of: usize,
}

/// Corner tracks through an image sequence (module docs, step 1).
#[derive(Debug)]
pub struct CornerTracks {
    config: MonoConfig,
    /// The previous frame's pyramid and its live tracks.
    previous: Option<(Pyramid, Tracks)>,
    next: TrackId,
    /// Scratch of the spacing test: per grid cell, the tracks in it.
    grid: Vec<Vec<[f32; 2]>>,
}

/// A frame in which fewer than this fraction of the previous frame's tracks survive is refused
/// (0.2: between two frames of a moving camera most corners stay in view and LK follows them;
/// losing four fifths at once is a broken frame — black, corrupt, textureless — or a jump);
/// the tracks wait for the next frame in the last good one.
pub const MIN_SURVIVING_FRACTION: f64 = 0.2;

/// Replenish when fewer than this fraction of the wanted tracks live (0.9: the selection costs
/// a FAST pass over the image, a few milliseconds, so it runs every few frames rather than in
/// every one, and the tracks stay within 10 % of their number).
const REPLENISH_FRACTION: f64 = 0.9;

impl CornerTracks {
    /// Tracks with `config`'s parameters.
    pub fn new(config: &MonoConfig) -> Self {
        CornerTracks {
            config: config.clone(),
            previous: None,
            next: 0,
            grid: Vec::new(),
        }
    }

    /// A new track at `p` in the last frame (a map point found there by guided search).
    pub fn adopt(&mut self, p: [f32; 2]) -> Option<TrackId> {
        let (_, live) = self.previous.as_mut()?;
        let id = self.next;
        self.next += 1;
        live.push((id, p));
        Some(id)
    }

    /// Moves track `id` to `p` in the last frame (its measurement re-located on the point's
    /// template): the next frame follows it from there.
    pub fn correct(&mut self, id: TrackId, p: [f32; 2]) {
        if let Some((_, live)) = self.previous.as_mut()
            && let Some(t) = live.iter_mut().find(|t| t.0 == id)
        {
            t.1 = p;
        }
    }

    /// Forgets every track: the next frame starts afresh (ids keep increasing).
    pub fn reset(&mut self) {
        self.previous = None;
    }

    /// Follows the tracks into `image` and replenishes them; returns the live tracks with their
    /// positions (pixels), or `Ok(Err(Refused))` when too few survived
    /// ([`MIN_SURVIVING_FRACTION`]): the frame is refused and the tracks stay in the previous
    /// one.
    pub fn push(&mut self, image: &GrayImage) -> Result<Result<&[Track], Refused>, ImageError> {
        let levels = self.config.levels;
        let pyramid = Pyramid::new(image, levels, 16)?;
        let (w, h) = (image.width() as f32, image.height() as f32);
        let mut live = Vec::new();
        if let Some((previous, tracks)) = &self.previous {
            let from: Vec<[f32; 2]> = tracks.iter().map(|t| t.1).collect();
            let to = track_forward_backward(
                previous,
                &pyramid,
                &from,
                &LkParams {
                    levels,
                    ..LkParams::default()
                },
                self.config.max_forward_backward,
            );
            live.reserve(tracks.len());
            for ((id, _), p) in tracks.iter().zip(to) {
                if let Some(p) = p
                    && p[0] >= 0.0
                    && p[1] >= 0.0
                    && p[0] <= w - 1.0
                    && p[1] <= h - 1.0
                {
                    live.push((*id, p));
                }
            }
            let of = tracks.len();
            if (live.len() as f64) < MIN_SURVIVING_FRACTION * of as f64 {
                return Ok(Err(Refused {
                    survived: live.len(),
                    of,
                }));
            }
        }
        if (live.len() as f64) < REPLENISH_FRACTION * self.config.tracks as f64 {
            self.replenish(image, &mut live);
        }
        let (_, tracks) = self.previous.insert((pyramid, live));
        Ok(Ok(tracks))
    }

    /// New corners, in the quadtree's order, at least `track_spacing` from every track, until
    /// `tracks` live.
    fn replenish(&mut self, image: &GrayImage, live: &mut Tracks) {
        let (_, selected) = select_corners(
            image,
            self.config.fast_threshold,
            self.config.tracks,
            self.config.min_cell,
        );
        let spacing = self.config.track_spacing.max(1.0) as f32;
        let cols = (image.width() as f32 / spacing).ceil() as usize + 1;
        let rows = (image.height() as f32 / spacing).ceil() as usize + 1;
        self.grid.iter_mut().for_each(Vec::clear);
        self.grid.resize(cols * rows, Vec::new());
        let cell = |p: [f32; 2]| ((p[0] / spacing) as usize, (p[1] / spacing) as usize);
        for (_, p) in live.iter() {
            let (c, r) = cell(*p);
            self.grid[r.min(rows - 1) * cols + c.min(cols - 1)].push(*p);
        }
        for q in selected {
            if live.len() >= self.config.tracks {
                break;
            }
            let p = [q.u, q.v];
            let (c, r) = cell(p);
            let free = (r.saturating_sub(1)..=(r + 1).min(rows - 1)).all(|rr| {
                (c.saturating_sub(1)..=(c + 1).min(cols - 1)).all(|cc| {
                    self.grid[rr * cols + cc].iter().all(|o| {
                        let (du, dv) = (o[0] - p[0], o[1] - p[1]);
                        du * du + dv * dv >= spacing * spacing
                    })
                })
            });
            if free {
                self.grid[r.min(rows - 1) * cols + c.min(cols - 1)].push(p);
                live.push((self.next, p));
                self.next += 1;
            }
        }
    }
}

/// The exploration's parameters for a `width`×`height` camera from the system's.
pub fn exploration_config(
    config: &SystemConfig,
    focal: f64,
    width: usize,
    height: usize,
) -> ExplorationConfig {
    let m = &config.mono;
    ExplorationConfig {
        sigma: config.pixel_noise,
        window: m.window,
        keyframe_distance: m.keyframe_distance,
        max_features: m.max_features,
        feature_spacing: m.feature_spacing,
        image_width: width as f64,
        image_height: height as f64,
        bootstrap_depth_error: m.bootstrap_depth_error,
        bootstrap_min_sigma: Some(m.bootstrap_min_sigma),
        // The depth error alone decides when the bootstrap has parallax enough.
        min_bootstrap_parallax: 0.0,
        max_bootstrap_frames: m.max_bootstrap_frames,
        double_window: m.double_window.then(|| {
            let mut p = slam::dwo::DwoParams::new(
                config.optimiser.inner,
                config.optimiser.outer,
                focal,
                config.pixel_noise,
            );
            p.iterations = config.optimiser.iterations;
            p
        }),
        theta: config.mapping.theta,
        // Map reuse: the keyframes sharing most points with the new one are optimised, older
        // observers of their points held fixed, and what the optimum does not explain removed
        // (see `MonoConfig::fixed_observers`).
        local_window: LocalWindow::Covisible,
        fixed_observers: m.fixed_observers,
        remove_outliers: true,
        // The stereo system's keyframe criterion of coverage, with the mono distance, and its
        // fraction of points found.
        keyframe_rotation: Some(config.keyframes.rotation_deg.to_radians()),
        keyframe_min_tracked_fraction: config.keyframes.min_found_fraction,
        ..ExplorationConfig::default()
    }
}

/// The monocular live system (see the [module docs](self)).
pub struct MonoSystem {
    config: SystemConfig,
    camera: PinholeCamera,
    tracks: CornerTracks,
    explorer: Option<MonoExplorer>,
    record: RunRecord,
    reports: Vec<FrameReport>,
    /// The maps tracking lost (a new map started after each), with their outputs.
    finished: Vec<MapOutputs>,
    /// Maps lost after their bootstrap (tracking lost, a new map started): the number of the
    /// current map (`slam::map::FIRST_MAP` the first).
    lost_maps: usize,
    /// Frames tracked in a map other than the first, which have no pose in the first map's
    /// world: `(position in the record, map, camera_from_world, state)`, kept for the map
    /// written if it is theirs.
    off_first: Vec<(usize, usize, Se3, TrackingState)>,
    /// Frames refused in a row by the corner tracks.
    refused: usize,
    /// The current map's keyframe images (the templates of the guided search).
    images: std::collections::HashMap<KeyframeId, KeyframeImages>,
    /// The first frame of a bootstrap in progress: its images become the first keyframe's.
    bootstrap_first: Option<KeyframeImages>,
    scratch: SearchScratch,
    warnings: Vec<String>,
    /// Large loops by appearance, once a vocabulary is given.
    loops: Option<MonoLoops>,
    events: Vec<LoopEvent>,
    /// Loops verified by appearance but refused: they needed more drift than the path allows.
    rejected_loops: usize,
    /// Per tracked frame: its position in the record, the last keyframe then, and the frame's
    /// pose relative to it (for the trajectory after the loops' correction).
    relative: Vec<(usize, KeyframeId, Se3)>,
    /// The neighbourhood searched by `refind` — of the last keyframe, or of the keyframe a
    /// relocalisation found until the next keyframe — with the (keyframes, loops, start) it
    /// was computed at.
    neighbourhood: Option<(NeighbourhoodKey, std::collections::HashSet<KeyframeId>)>,
    /// Tracking lost in the current map, which each frame tries to relocalise in.
    lost: Option<Lost>,
    /// The keyframe the last relocalisation found, until the next keyframe is made.
    reference: Option<KeyframeId>,
    /// The relocalisations so far.
    relocalisations: Vec<Relocalisation>,
    /// Earlier maps' places recognised from later maps' keyframes and accepted
    /// ([`MonoSystem::join_maps`]): each joins a later map to an earlier one.
    joins: Vec<MapJoin>,
    /// The current map's latest run of mutually consistent detections of an earlier map's
    /// place, not yet accepted.
    join_chain: Vec<MapJoin>,
}

/// What a cached `refind` neighbourhood was computed at: (keyframes, loops, start keyframe).
type NeighbourhoodKey = (usize, usize, Option<KeyframeId>);

/// A frame's measurements: `(track, pixel)`.
type Measurements = Vec<(TrackId, Vector2<f64>)>;

/// Where and why tracking was lost in a map that the following frames try to relocalise in
/// (`MonoSystem::lose`).
#[derive(Clone, Debug)]
struct Lost {
    frame: usize,
    timestamp: f64,
    why: String,
}

/// Large loops by appearance in a monocular map (thesis ch. 5): each keyframe's ORB words and
/// map-point depths go into the database; a loop is verified by kNN depth regression and a
/// 3-point Sim(3) RANSAC (`place_recognition`, [`Alignment::Sim3`]), its scale is the scale
/// drift between the two places, and the loops correct the map when accepted
/// (`mono.correct_live`) or at the end of the run.
struct MonoLoops {
    place: PlaceRecognition,
    /// Every loop accepted.
    edges: Vec<LoopDetection>,
    /// The latest run of mutually consistent detections, and whether it was accepted.
    chain: Vec<LoopDetection>,
    accepted: bool,
}

/// A loop found by place recognition: keyframe `current` sees the place of `old`.
#[derive(Clone, Copy, Debug, PartialEq)]
struct LoopDetection {
    current: KeyframeId,
    old: KeyframeId,
    /// `x_current = S·x_old` for camera-frame points.
    current_from_old: Sim3,
}

/// A place of an earlier map seen from a keyframe of a later one, started after tracking was
/// lost ([`MonoSystem::join_maps`]). The two maps have worlds and scales of their own; the
/// detection's similarity between the two keyframes gives the similarity between the worlds,
/// as a loop's gives the correction in one map (thesis ch. 5).
#[derive(Clone, Copy, Debug, PartialEq)]
struct MapJoin {
    /// The later map, whose keyframe is `detection.current`.
    map: usize,
    /// The earlier map, whose keyframe is `detection.old`.
    other: usize,
    detection: LoopDetection,
    /// Inliers of its verification.
    inliers: usize,
    /// The frames the two keyframes were made from.
    frames: (usize, usize),
}

impl MapJoin {
    /// `x_map = W·x_other` between the worlds of the later map (`map`, its graph) and the
    /// earlier (`other`): `W = T_k⁻¹·S·T_old` with the keyframes' poses as the graphs have them.
    fn map_from_other(&self, map: &SlamGraph<2>, other: &SlamGraph<2>) -> Option<Sim3> {
        let k = map.pose(self.detection.current).ok()?;
        let old = other.pose(self.detection.old).ok()?;
        Some(
            k.inverse()
                .compose(&self.detection.current_from_old)
                .compose(&old),
        )
    }
}

/// Each map joined to `world` through `links` (`(later, earlier, x_later = W·x_earlier)`), with
/// `x_map = W·x_world`; `world` itself with the identity.
fn joined_to(
    world: usize,
    links: &[(usize, usize, Sim3)],
) -> std::collections::BTreeMap<usize, Sim3> {
    let mut from_world = std::collections::BTreeMap::from([(world, Sim3::identity())]);
    loop {
        let mut grown = false;
        for &(later, earlier, w) in links {
            match (
                from_world.get(&later).copied(),
                from_world.get(&earlier).copied(),
            ) {
                (Some(l), None) => {
                    from_world.insert(earlier, w.inverse().compose(&l));
                    grown = true;
                }
                (None, Some(e)) => {
                    from_world.insert(later, w.compose(&e));
                    grown = true;
                }
                _ => {}
            }
        }
        if !grown {
            return from_world;
        }
    }
}

/// The maps written: of the groups of maps joined together ([`joined_to`]), the one with the
/// most keyframes (the first map's on a tie); its world is its map with the most keyframes
/// ([`largest_map`]). Returns that map and every map of the group with `x_map = W·x_world`.
fn written_maps(
    keyframes: &[(usize, usize)],
    links: &[(usize, usize, Sim3)],
) -> (usize, std::collections::BTreeMap<usize, Sim3>) {
    let mut best: Option<(usize, usize)> = None;
    for &(m, _) in keyframes {
        let group = joined_to(m, links);
        let total: usize = keyframes
            .iter()
            .filter(|(o, _)| group.contains_key(o))
            .map(|(_, n)| n)
            .sum();
        if best.is_none_or(|(_, t)| total > t) {
            best = Some((m, total));
        }
    }
    let Some((m, _)) = best else {
        return (FIRST_MAP, joined_to(FIRST_MAP, links));
    };
    let group = joined_to(m, links);
    let world = largest_map(
        keyframes
            .iter()
            .copied()
            .filter(|(o, _)| group.contains_key(o)),
    );
    (world, joined_to(world, links))
}

/// Detections in a row that must agree before a loop is accepted (3: a repetitive place —
/// the same façade, a corridor like another — can pass the appearance and 3-point checks
/// once or twice, but its successive detections jump between unrelated old places; a real
/// revisit keeps finding the old trajectory where the odometry since the last detection says
/// it should be).
const LOOP_CONSISTENCY: usize = 3;

/// Two detections agree when the second's similarity matches the first's carried by the
/// odometry on both sides within these: 5° of rotation, 10 % of scale, and a tenth of the old
/// keyframe's median scene depth of translation (the keyframe criterion's 10 %).
const LOOP_AGREEMENT: (f64, f64, f64) = (5.0, 0.1, 0.1);

/// A loop may move the current keyframe by at most this fraction of the path travelled since
/// the old keyframe (0.1: monocular odometry drifts by a few per cent of the distance — 1.7 %
/// on the rendered building loop, 1–3 % in the literature — so a loop that needs ten per cent
/// joins two places that only look alike, as the corridors of a building do).
const MAX_DRIFT_FRACTION: f64 = 0.1;

/// Whether the loop `k_from_old` between keyframes `old` and `k` moves `k` by no more than
/// the drift the path between them allows ([`MAX_DRIFT_FRACTION`]).
fn loop_within_drift(
    graph: &SlamGraph<2>,
    old: KeyframeId,
    k: KeyframeId,
    k_from_old: &Sim3,
) -> bool {
    let limits = DriftLimits {
        of_path: MAX_DRIFT_FRACTION,
        of_scene_depth: 0.0,
    };
    graph.pose(old).ok().is_some_and(|t_old| {
        LoopDrift::of(graph, old, k, &k_from_old.compose(&t_old)).is_some_and(|d| d.within(&limits))
    })
}

/// For every keyframe sharing map points with `k` (`k` included), how many. The monocular
/// explorer adds no graph edges outside its double-window mode, so the covisibility weights
/// are counted from the points' observers here rather than read from `SlamGraph`'s edges.
fn shared_points(
    graph: &SlamGraph<2>,
    k: KeyframeId,
) -> std::collections::BTreeMap<KeyframeId, usize> {
    let mut shared: std::collections::BTreeMap<KeyframeId, usize> = Default::default();
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
/// last `recent` keyframes and every keyframe covisible with `k`, sharing at least `theta`
/// points (the graph's sense of connected, as the stereo system's edges). A handful of shared
/// points does not close a loop: after a drifted revisit the guided search finds a few of the
/// old place's points from the drifted pose, too few to hold the map, and excluding every
/// keyframe that shares one of them hid the old place from detection for the rest of the
/// revisit (rendered building, 2026-12-02: the last 45 keyframes shared 1–10 points each with
/// the first ones, and no loop was detected after the first three).
fn topologically_close(
    graph: &SlamGraph<2>,
    k: KeyframeId,
    theta: usize,
    recent: usize,
) -> BTreeSet<KeyframeId> {
    let mut close: BTreeSet<KeyframeId> = crate::loops::recent_keyframes(k, recent).collect();
    close.extend(
        shared_points(graph, k)
            .into_iter()
            .filter(|&(o, n)| o != k && n >= theta)
            .map(|(o, _)| o),
    );
    close
}

/// The accepted loops as edges of the keyframe chain (thesis §5.3.2).
fn loop_edges(detections: &[LoopDetection]) -> Vec<LoopEdge> {
    detections
        .iter()
        .map(|d| LoopEdge {
            old: d.old.index(),
            current: d.current.index(),
            old_from_current: d.current_from_old.inverse(),
        })
        .collect()
}

/// The pose graph's constraints besides the chain and the loops (thesis §5.3.2 uses the chain
/// alone): every pair of keyframes sharing at least `theta` map points, not consecutive,
/// constrained to their relative pose in the map as it is (scale 1). With map reuse the map
/// holds keyframes far apart on the path that measure the same points (a revisited place whose
/// points were found again): the loop there is already closed, and these edges keep it closed
/// where a chain alone would let a loop edge's noise — its scale from the regressed depths is
/// good to a few per cent — bend it open again.
fn covisibility_edges(graph: &SlamGraph<2>, theta: usize) -> Vec<LoopEdge> {
    let mut shared: std::collections::BTreeMap<(KeyframeId, KeyframeId), usize> =
        Default::default();
    for (_, point) in graph.points() {
        let observers: Vec<KeyframeId> = point.observers().iter().copied().collect();
        for (i, &a) in observers.iter().enumerate() {
            for &b in &observers[i + 1..] {
                *shared.entry((a.min(b), a.max(b))).or_default() += 1;
            }
        }
    }
    shared
        .into_iter()
        .filter(|&((a, b), n)| n >= theta && b.index() > a.index() + 1)
        .filter_map(|((a, b), _)| {
            Some(LoopEdge {
                old: a.index(),
                current: b.index(),
                old_from_current: graph.pose(a).ok()?.compose(&graph.pose(b).ok()?.inverse()),
            })
        })
        .collect()
}

/// The keyframes within the first `limit` of a breadth-first search from `start` (the last
/// keyframe if `None`: where the camera tracks, except just after a relocalisation) over
/// the covisibility graph (keyframes sharing at least `theta` points, and consecutive ones) and
/// the accepted `loops`: the monocular `N2` (thesis §6.4.1).
fn covisible_neighbourhood(
    graph: &SlamGraph<2>,
    start: Option<KeyframeId>,
    theta: usize,
    limit: usize,
    loops: &[(KeyframeId, KeyframeId)],
) -> std::collections::HashSet<KeyframeId> {
    let mut seen = std::collections::HashSet::new();
    let Some(last) = start
        .filter(|&k| graph.keyframe(k).is_some())
        .or_else(|| graph.keyframes().last().map(|(k, _)| k))
    else {
        return seen;
    };
    let mut queue = std::collections::VecDeque::from([last]);
    seen.insert(last);
    while let Some(k) = queue.pop_front() {
        if graph.keyframe(k).is_none() {
            continue;
        }
        let mut next: Vec<(usize, KeyframeId)> = shared_points(graph, k)
            .into_iter()
            .filter(|&(o, n)| o != k && n >= theta)
            .map(|(o, n)| (n, o))
            .collect();
        for j in [k.index().checked_sub(1), Some(k.index() + 1)]
            .into_iter()
            .flatten()
            .filter(|&j| j < graph.keyframe_id_bound())
        {
            next.push((usize::MAX, KeyframeId::from_index(j)));
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

/// `mono.loop_correction`'s group and the other one.
fn correction_groups(name: &str) -> (CorrectionGroup, CorrectionGroup) {
    if name == "se3" {
        (CorrectionGroup::Se3, CorrectionGroup::Sim3)
    } else {
        (CorrectionGroup::Sim3, CorrectionGroup::Se3)
    }
}

/// Corrects `graph` through the pose graph of its keyframe chain and the `loops` in `group`
/// (`slam::loop_closure::correction::correct_graph`, 50 Levenberg-Marquardt iterations, one
/// thread, exact Jacobians).
fn correct_loops(
    graph: &mut SlamGraph<2>,
    loops: &[LoopEdge],
    group: CorrectionGroup,
) -> Result<(), slam::loop_closure::correction::CorrectionError> {
    let options = lsq::SolverOptions {
        max_iterations: 50,
        threads: Some(1),
        ..lsq::SolverOptions::default()
    };
    let jacobian = PoseGraphJacobian::Analytic(lie::LogJacobian::Exact);
    correct_graph(graph, loops, group, jacobian, &options).map(|_| ())
}

/// Whether detection `b` agrees with the earlier `a` through the map's relative poses (the
/// odometry is locally accurate on both sides of a loop). `graph` holds the current keyframes
/// and `old_graph` the old ones: the same map for a loop, an earlier map for a join
/// ([`MapJoin`]).
fn loops_agree(
    graph: &SlamGraph<2>,
    old_graph: &SlamGraph<2>,
    a: &LoopDetection,
    b: &LoopDetection,
) -> bool {
    let rel = |g: &SlamGraph<2>, x: KeyframeId, y: KeyframeId| -> Option<Sim3> {
        Some(g.pose(x).ok()?.compose(&g.pose(y).ok()?.inverse()))
    };
    let (Some(cur), Some(old)) = (
        rel(graph, b.current, a.current),
        rel(old_graph, a.old, b.old),
    ) else {
        return false;
    };
    // x_kb = T_kb,ka · S_a · T_olda,oldb · x_oldb.
    let predicted = cur.compose(&a.current_from_old).compose(&old);
    let delta = predicted.inverse().compose(&b.current_from_old);
    let mut depths: Vec<f64> = slam::loop_closure::constraint::depth_samples(old_graph, b.old)
        .into_iter()
        .map(|(_, d)| d)
        .collect();
    if depths.is_empty() {
        return false;
    }
    depths.sort_by(f64::total_cmp);
    let depth = depths[depths.len() / 2];
    let (rotation_deg, scale, translation) = LOOP_AGREEMENT;
    delta.rotation().log().norm().to_degrees() <= rotation_deg
        && delta.scale().ln().abs() <= scale
        && delta.translation().norm() <= translation * depth
}

impl MonoSystem {
    /// A system for `camera` with `config`; `sequence` names the input in the outputs.
    pub fn new(
        camera: PinholeCamera,
        config: SystemConfig,
        sequence: &str,
    ) -> Result<Self, SystemError> {
        config.validate()?;
        Ok(MonoSystem {
            tracks: CornerTracks::new(&config.mono),
            camera,
            config,
            explorer: None,
            record: RunRecord {
                sequence: sequence.to_string(),
                sensor: "mono".into(),
                ..RunRecord::default()
            },
            reports: Vec::new(),
            finished: Vec::new(),
            lost_maps: 0,
            off_first: Vec::new(),
            refused: 0,
            images: Default::default(),
            bootstrap_first: None,
            scratch: SearchScratch::default(),
            loops: None,
            events: Vec::new(),
            rejected_loops: 0,
            relative: Vec::new(),
            neighbourhood: None,
            lost: None,
            reference: None,
            relocalisations: Vec::new(),
            joins: Vec::new(),
            join_chain: Vec::new(),
            warnings: Vec::new(),
        })
    }

    /// Closes large loops by appearance with `vocabulary` (unless `loops.enabled` is false).
    /// Call before the first frame.
    pub fn with_loop_closure(
        mut self,
        vocabulary: std::sync::Arc<vision::bow::Vocabulary>,
    ) -> Result<Self, SystemError> {
        if !self.config.loops.enabled {
            return Ok(self);
        }
        let config = PlaceRecognitionConfig {
            alignment: Alignment::Sim3,
            pixel_sigma: self.config.pixel_noise,
            ..self.config.loops.place_recognition.clone()
        };
        self.loops = Some(MonoLoops {
            place: PlaceRecognition::new(vocabulary, config)?,
            edges: Vec::new(),
            chain: Vec::new(),
            accepted: false,
        });
        Ok(self)
    }

    /// A new keyframe into place recognition, and its loop with an old place if one is
    /// verified (recorded, and with `mono.correct_live` the map corrected at once).
    fn close_loop(&mut self, k: KeyframeId, image: &GrayImage, frame: usize) {
        let (Some(loops), Some(explorer)) = (self.loops.as_mut(), self.explorer.as_ref()) else {
            return;
        };
        let map = explorer.map();
        let samples = slam::loop_closure::constraint::depth_samples(&map.graph, k);
        if let Err(e) = loops
            .place
            .add_monocular_keyframe(k, image, samples, &self.camera)
        {
            self.warnings
                .push(format!("place recognition at frame {frame}: {e}"));
            return;
        }
        let excluded = topologically_close(
            &map.graph,
            k,
            self.config.mapping.theta,
            self.config.loops.exclusion_recent,
        );
        let mut accepted_now = false;
        match loops.place.detect(k, &excluded) {
            Ok(Some(c)) if !loop_within_drift(&map.graph, c.old, k, &c.query_from_old) => {
                self.rejected_loops += 1;
            }
            Ok(Some(c)) => {
                let detection = LoopDetection {
                    current: k,
                    old: c.old,
                    current_from_old: c.query_from_old,
                };
                // Consistent with the last detection, if that was a few keyframes ago.
                let follows = loops.chain.last().is_some_and(|last| {
                    k.index() - last.current.index() <= LOOP_CONSISTENCY
                        && loops_agree(&map.graph, &map.graph, last, &detection)
                });
                if !follows {
                    loops.chain.clear();
                    loops.accepted = false;
                }
                loops.chain.push(detection);
                let newly: Vec<LoopDetection> = if loops.accepted {
                    vec![detection]
                } else if loops.chain.len() >= LOOP_CONSISTENCY {
                    loops.accepted = true;
                    loops.chain.clone()
                } else {
                    Vec::new()
                };
                accepted_now = !newly.is_empty();
                for d in newly {
                    loops.edges.push(d);
                    self.events.push(LoopEvent {
                        keyframe: d.current,
                        old: d.old,
                        frames: (map.keyframe(d.current).frame, map.keyframe(d.old).frame),
                        kind: "appearance",
                        scale: Some(d.current_from_old.scale()),
                        correction: None,
                        evidence: None,
                    });
                }
            }
            Ok(None) => {}
            Err(e) => self
                .warnings
                .push(format!("loop detection at frame {frame}: {e}")),
        }
        if accepted_now && self.config.mono.correct_live {
            self.correct_live(frame);
        }
    }

    /// A new keyframe `k` of a map started after tracking was lost, against the keyframe
    /// databases of the earlier maps (monocular map joining; ORB-SLAM3's Atlas merges its maps
    /// on such a detection): its ORB words scored against each earlier map's keyframes, the best
    /// verified by the 3-point Sim(3) RANSAC on regressed depths as a loop is
    /// ([`PlaceRecognition::relocalise`] with the keyframe's features and depth samples). As a
    /// loop, a join is accepted once [`LOOP_CONSISTENCY`] detections in a row agree
    /// ([`loops_agree`], across the two maps): a place that only looks like one of the earlier
    /// map's is seldom seen so three times over. After that, each later detection that agrees
    /// with the last accepted one is kept too: the outputs take the similarity between the
    /// two worlds from the one with the most inliers, the best measured. The maps stay apart
    /// while the run goes on; the outputs hold the joined maps in one world
    /// ([`written_maps`]).
    fn join_maps(&mut self, k: KeyframeId) {
        let current = self.lost_maps;
        let (Some(loops), Some(explorer)) = (self.loops.as_ref(), self.explorer.as_ref()) else {
            return;
        };
        let Some(features) = loops.place.features(k) else {
            return;
        };
        let map = explorer.map();
        for earlier in &self.finished {
            let accepted = self
                .joins
                .iter()
                .rfind(|j| j.map == current && j.other == earlier.map)
                .copied();
            let Some(place) = &earlier.place else {
                continue;
            };
            let Some(c) = place.relocalise(k.index() as u32, features) else {
                continue;
            };
            let join = MapJoin {
                map: current,
                other: earlier.map,
                detection: LoopDetection {
                    current: k,
                    old: c.old,
                    current_from_old: c.query_from_old,
                },
                inliers: c.inliers.len(),
                frames: (
                    map.keyframe(k).frame,
                    earlier
                        .keyframes
                        .iter()
                        .find(|r| r.id == c.old.index())
                        .map_or(usize::MAX, |r| r.frame_index),
                ),
            };
            if let Some(last) = accepted {
                if loops_agree(&map.graph, &earlier.graph, &last.detection, &join.detection) {
                    self.joins.push(join);
                }
                continue;
            }
            let follows = self.join_chain.last().is_some_and(|last| {
                last.other == join.other
                    && k.index() - last.detection.current.index() <= LOOP_CONSISTENCY
                    && loops_agree(&map.graph, &earlier.graph, &last.detection, &join.detection)
            });
            if !follows {
                self.join_chain.clear();
            }
            self.join_chain.push(join);
            if self.join_chain.len() >= LOOP_CONSISTENCY {
                for j in self.join_chain.drain(..) {
                    self.events.push(LoopEvent {
                        keyframe: j.detection.current,
                        old: j.detection.old,
                        frames: j.frames,
                        kind: "merge",
                        scale: Some(j.detection.current_from_old.scale()),
                        correction: None,
                        evidence: None,
                    });
                    self.joins.push(j);
                }
            }
            return;
        }
    }

    /// The loops accepted so far correct the current map now (`mono.correct_live`), in
    /// `mono.loop_correction`'s group, and the exploration goes on in the corrected map.
    fn correct_live(&mut self, frame: usize) {
        let (Some(loops), Some(explorer)) = (self.loops.as_ref(), self.explorer.as_mut()) else {
            return;
        };
        let t = Instant::now();
        let mut edges = loop_edges(&loops.edges);
        edges.extend(covisibility_edges(
            &explorer.map().graph,
            self.config.mapping.theta,
        ));
        let group = correction_groups(&self.config.mono.loop_correction).0;
        if let Err(e) = explorer.correct_map(|g| correct_loops(g, &edges, group)) {
            self.warnings.push(format!(
                "loop correction at frame {frame} in {group:?}: {e}"
            ));
        }
        self.record.timings.record("loop: correction", t.elapsed());
    }

    /// Tracking is lost at `frame` for the reason `why`. A map worth returning to (bootstrapped,
    /// with a vocabulary to recognise its places, `tracker.new_map_after` > 0) is kept, and
    /// the following frames try to relocalise in it ([`MonoSystem::relocalise`]); else a new
    /// map starts at the next frame. Returns what the frame's state says of it.
    fn lose(&mut self, frame: &data::sequence::Frame, why: String) -> String {
        self.refused = 0;
        if !self.relocalisable() {
            let reason = format!("{why}: a new map starts");
            self.restart(format!("frame {}: {reason}", frame.index));
            return reason;
        }
        // A failed relocalisation's frame keeps the loss it tried to end.
        self.lost.get_or_insert_with(|| Lost {
            frame: frame.index,
            timestamp: frame.timestamp,
            why: why.clone(),
        });
        self.tracks.reset();
        self.reference = None;
        format!("{why}: relocalising in the map")
    }

    /// Whether a lost camera looks for its place in the current map ([`MonoSystem::lose`]): a
    /// bootstrapped map, a vocabulary to recognise its places, and `tracker.new_map_after` > 0.
    fn relocalisable(&self) -> bool {
        self.loops.is_some()
            && self.config.tracker.new_map_after > 0.0
            && self
                .explorer
                .as_ref()
                .is_some_and(|e| e.map().keyframes.len() >= 2)
    }

    /// Looks for a lost frame in the current map (ORB-SLAM's relocalisation, Mur-Artal et al.
    /// 2015, with this system's stages): [`MonoSystem::verified_place`], then
    /// [`MonoSystem::relocalise_at`] its pose. `Err` says why not.
    fn relocalise(
        &mut self,
        frame: &data::sequence::Frame,
    ) -> Result<(Measurements, Relocalisation), String> {
        let (pose, relocalisation) = self.verified_place(frame)?;
        self.relocalise_at(frame, pose, relocalisation)
    }

    /// The place of `frame` in the current map, changing nothing: its ORB words scored against
    /// the keyframe database, the best keyframes verified 2D–3D by P3P RANSAC against their
    /// points (depths regressed from their map points; [`PlaceRecognition::relocalise`]).
    /// Returns the frame's pose `camera_from_world` and what it was found by.
    fn verified_place(
        &self,
        frame: &data::sequence::Frame,
    ) -> Result<(Se3, Relocalisation), String> {
        let image = frame.gray();
        let (Some(loops), Some(explorer)) = (self.loops.as_ref(), self.explorer.as_ref()) else {
            return Err("no map or no vocabulary".into());
        };
        let features = extract_features(
            image,
            |_, _| None,
            Vec::new(),
            &self.camera,
            loops.place.config(),
        )
        .map_err(|e| e.to_string())?;
        let candidate = loops
            .place
            .relocalise(frame.index as u32, &features)
            .ok_or("no keyframe's place verified")?;
        let map = explorer.map();
        let old = map
            .graph
            .keyframe(candidate.old)
            .ok_or("the keyframe found is not in the map")?
            .camera_from_world();
        // The verification's pose is rigid in the old keyframe's camera units, which are its
        // similarity's: composed with it, then made rigid as every mono pose.
        let pose = rigid_from_similarity(&candidate.query_from_old.compose(old));
        let relocalisation = Relocalisation {
            frame: frame.index,
            keyframe: candidate.old,
            keyframe_frame: map.keyframe(candidate.old).frame,
            ransac_inliers: candidate.ransac_inliers,
            tracked: 0,
        };
        Ok((pose, relocalisation))
    }

    /// Relocalises `frame` at `pose` ([`MonoSystem::verified_place`]): new corner tracks from
    /// this frame and the map points of the found keyframe's neighbourhood searched for around
    /// that pose (the guided search of `refind`, as on any frame). Accepted with at least
    /// `tracker.min_good` points found: the exploration goes on from the pose
    /// (`MonoExplorer::relocalise`) and the caller processes the frame's measurements.
    fn relocalise_at(
        &mut self,
        frame: &data::sequence::Frame,
        pose: Se3,
        relocalisation: Relocalisation,
    ) -> Result<(Measurements, Relocalisation), String> {
        let image = frame.gray();
        let Some(explorer) = self.explorer.as_mut() else {
            return Err("no map".into());
        };
        explorer.relocalise(frame.index, pose);
        self.reference = Some(relocalisation.keyframe);
        self.tracks.reset();
        let mut measurements: Measurements = match self.tracks.push(image) {
            Ok(Ok(tracks)) => tracks
                .iter()
                .map(|&(id, p)| (id, Vector2::new(p[0] as f64, p[1] as f64)))
                .collect(),
            _ => return Err("no corner tracks in this frame".into()),
        };
        let found = self.refind(frame.index, image, &mut measurements);
        if found < self.config.tracker.min_good {
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
        Ok((
            measurements,
            Relocalisation {
                tracked: found,
                ..relocalisation
            },
        ))
    }

    /// Ends the current map and starts again at the next frame.
    fn restart(&mut self, why: String) {
        let mut closed = false;
        if let Some(explorer) = self.explorer.take() {
            if !explorer.map().keyframes.is_empty() {
                let outputs = self.close_map(explorer);
                self.finished.push(outputs);
                self.lost_maps += 1;
                closed = true;
            }
            self.warnings.push(why);
        }
        self.join_chain.clear();
        self.tracks.reset();
        self.images.clear();
        self.neighbourhood = None;
        self.bootstrap_first = None;
        // A new map numbers its keyframes anew: the database starts empty, and the loops
        // found in the old map are gone with it. The old map keeps its database, for the
        // later maps to join it by (`join_maps`).
        if let Some(loops) = self.loops.as_mut()
            && let Ok(place) = PlaceRecognition::new(
                loops.place.vocabulary().clone(),
                loops.place.config().clone(),
            )
        {
            let old = std::mem::replace(&mut loops.place, place);
            if closed && let Some(outputs) = self.finished.last_mut() {
                outputs.place = Some(old);
            }
            loops.edges.clear();
            loops.chain.clear();
            loops.accepted = false;
        }
        self.events.clear();
        self.relative.clear();
    }

    /// Records `frame` as lost for the reason `why`, with no pose; returns its report.
    fn lost_frame(
        &mut self,
        frame: &data::sequence::Frame,
        why: String,
        start: Instant,
    ) -> FrameReport {
        let report = FrameReport {
            index: frame.index,
            state: TrackingState::Lost(why),
            keyframe: None,
            stats: None,
            time: start.elapsed(),
            time_tracking: start.elapsed(),
        };
        self.push(report, frame, None)
    }

    /// Records a frame's pose and state and its report; returns the report as recorded.
    ///
    /// Only a pose in the first map is a pose in the world: a map started after tracking was
    /// lost (and not relocalised in time) has a frame and a scale of its own, and nothing joins
    /// it to the first (there is no merge of monocular maps yet). Such a frame's state says so and
    /// its pose is kept, for the outputs if its map is the one written
    /// ([`RunResult::world_map`]).
    fn push(
        &mut self,
        mut report: FrameReport,
        frame: &data::sequence::Frame,
        pose: Option<Se3>,
    ) -> FrameReport {
        if let (Some(pose), Some(explorer)) = (pose, &self.explorer)
            && let Some(last) = explorer.map().keyframe_ids().last()
        {
            let rel = pose.compose(&explorer.map().rigid_pose(last).inverse());
            self.relative.push((self.record.frames.len(), last, rel));
        }
        let map = self.lost_maps;
        let world_pose = match pose {
            Some(pose) if map != FIRST_MAP => {
                self.off_first
                    .push((self.record.frames.len(), map, pose, report.state.clone()));
                report.state = TrackingState::Weak(format!(
                    "tracked in map {map}, started after tracking was lost: a monocular map of \
                     its own frame and scale, no pose in the first map's world"
                ));
                None
            }
            pose => pose,
        };
        self.record.frames.push(FrameRecord {
            index: frame.index,
            timestamp: frame.timestamp,
            world_from_camera: world_pose.map(|t| t.inverse()),
            state: report.state.clone(),
        });
        self.record.timings.record("frame: total", report.time);
        self.reports.push(report.clone());
        report
    }

    /// Every recorded frame's timestamp, by frame index.
    fn timestamps(&self) -> std::collections::HashMap<usize, f64> {
        self.record
            .frames
            .iter()
            .map(|f| (f.index, f.timestamp))
            .collect()
    }

    /// The outputs of a map (the current one at the end of the run, or one tracking lost): its
    /// frames' poses after the loops' correction, its keyframes and points, its graph. The
    /// loops are corrected in `mono.loop_correction`'s group (the other one as an
    /// alternative trajectory, unless corrected live).
    fn close_map(&mut self, explorer: MonoExplorer) -> MapOutputs {
        let timestamp = self.timestamps();
        let mut trajectories: Vec<(&'static str, Vec<(usize, Se3)>)> = Vec::new();
        let poses = explorer.frame_poses();
        let map = explorer.into_map();
        let mut edges: Vec<LoopEdge> = self
            .loops
            .as_ref()
            .map(|l| loop_edges(&l.edges))
            .unwrap_or_default();
        let loops_found = !edges.is_empty();
        edges.extend(covisibility_edges(&map.graph, self.config.mapping.theta));
        let (primary, other) = correction_groups(&self.config.mono.loop_correction);
        // Corrected live, the map holds the primary group's correction already; the other
        // group's would start from it, so it is not written (run again with the other
        // `mono.loop_correction` for the thesis's comparison).
        let groups = match (!loops_found, self.config.mono.correct_live) {
            (true, _) => vec![],
            (false, true) => vec![primary],
            (false, false) => vec![primary, other],
        };
        let keyframe_of: std::collections::HashMap<usize, KeyframeId> = map
            .keyframe_ids()
            .map(|k| (map.keyframe(k).frame, k))
            .collect();
        let relative: std::collections::HashMap<usize, (KeyframeId, Se3)> = self
            .relative
            .iter()
            .map(|&(i, k, rel)| (self.record.frames[i].index, (k, rel)))
            .collect();
        // Every frame of the map in a corrected graph: a keyframe as corrected, another
        // frame relative to its keyframe.
        let reexpress = |g: &SlamGraph<2>| -> Vec<(usize, Se3)> {
            poses
                .iter()
                .map(|&(f, tracked)| {
                    let pose = match (keyframe_of.get(&f), relative.get(&f)) {
                        (Some(&k), _) => g.pose(k).ok().map(|s| rigid_from_similarity(&s)),
                        (None, Some(&(k, rel))) => g
                            .pose(k)
                            .ok()
                            .map(|s| rigid_from_similarity(&Sim3::from_se3(&rel).compose(&s))),
                        _ => None,
                    };
                    (f, pose.unwrap_or(tracked))
                })
                .collect()
        };
        let mut corrected_graph = map.graph.clone();
        for (i, &group) in groups.iter().enumerate() {
            let mut g = map.graph.clone();
            match correct_loops(&mut g, &edges, group) {
                Ok(()) => {
                    let name = match group {
                        CorrectionGroup::Sim3 => "trajectory_final_sim3",
                        CorrectionGroup::Se3 => "trajectory_final_se3",
                    };
                    trajectories.push((name, reexpress(&g)));
                    if i == 0 {
                        corrected_graph = g;
                    }
                }
                Err(e) => self
                    .warnings
                    .push(format!("loop correction in {group:?}: {e}")),
            }
        }
        if trajectories.is_empty() {
            trajectories.push(("trajectory_final", reexpress(&map.graph)));
        }
        let graph = corrected_graph;
        let keyframes = map
            .keyframe_ids()
            .filter_map(|k| {
                let frame = map.keyframe(k).frame;
                Some(KeyframeRecord {
                    id: k.index(),
                    frame_index: frame,
                    timestamp: timestamp.get(&frame).copied().unwrap_or(f64::NAN),
                    world_from_camera: rigid_from_similarity(&graph.pose(k).ok()?).inverse(),
                })
            })
            .collect();
        let points = graph
            .points()
            .filter_map(|(p, _)| {
                Some(MapPoint {
                    position: graph.point_world(p).ok()?,
                    colour: None,
                })
            })
            .collect();
        MapOutputs {
            map: self.lost_maps,
            trajectories,
            keyframes,
            points,
            graph,
            loops: std::mem::take(&mut self.events),
            place: None,
        }
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

impl MonoSystem {
    /// Checks every track that measures a map point against the point's template (config
    /// `mono.verify_tracks`, [`relocate`]): the measurement moves to where the template aligns,
    /// within `tracker.search_radius` of the track, and the track with it; a track that no longer
    /// shows its point leaves the frame's measurements (the exploration then drops the
    /// association, the track goes on as a plain corner track). Returns how many were dropped.
    fn verify(
        &mut self,
        frame: usize,
        image: &GrayImage,
        measurements: &mut Vec<(TrackId, Vector2<f64>)>,
    ) -> usize {
        if !self.config.mono.verify_tracks {
            return 0;
        }
        let Some(explorer) = self.explorer.as_ref() else {
            return 0;
        };
        let Some(pose) = explorer.predicted_pose(frame) else {
            return 0;
        };
        let graph = &explorer.map().graph;
        let active = explorer.active();
        let (radius, min_ncc) = (
            self.config.tracker.search_radius,
            self.config.tracker.min_ncc,
        );
        let before = measurements.len();
        let mut moved: Vec<(TrackId, [f32; 2])> = Vec::new();
        measurements.retain_mut(|(track, z)| {
            let Some(&p) = active.get(track) else {
                return true;
            };
            // Without a template (its anchor's images are not kept) the track stands as is.
            let Some((sp, anchor)) = SearchPoint::from_graph(graph, p)
                .and_then(|sp| self.images.get(&sp.anchor).map(|a| (sp, a)))
            else {
                return true;
            };
            match relocate(&self.camera, &pose, &sp, anchor, image, *z, radius, min_ncc) {
                Some(u) => {
                    *z = u;
                    moved.push((*track, [u.x as f32, u.y as f32]));
                    true
                }
                None => false,
            }
        });
        for (track, p) in moved {
            self.tracks.correct(track, p);
        }
        before - measurements.len()
    }

    /// Searches the map points of the keyframes near the predicted pose that no track measures
    /// (config `mono.refind`); each one found joins the frame's measurements — on the track
    /// already following that corner if it is not a feature, else on a new track — and is
    /// associated with its point in the exploration. Returns how many were found.
    fn refind(
        &mut self,
        frame: usize,
        image: &GrayImage,
        measurements: &mut Vec<(TrackId, Vector2<f64>)>,
    ) -> usize {
        let config = &self.config;
        if !config.mono.refind {
            return 0;
        }
        let Some(explorer) = self.explorer.as_mut() else {
            return 0;
        };
        let Some(pose) = explorer.predicted_pose(frame) else {
            return 0;
        };
        let (w, h) = (image.width(), image.height());
        let max_angle = config.tracker.max_view_angle_deg.to_radians();
        let todo: Vec<(SearchPoint, Vector2<f64>)> = {
            let map = explorer.map();
            let centre = |t: &Se3| t.inverse().act(&Vector3::zeros());
            let axis = |t: &Se3| t.rotation().inverse().act(&Vector3::z());
            let (c, a) = (centre(&pose), axis(&pose));
            // A scan of every keyframe (a few hundred here: microseconds); a map of thousands
            // would want a spatial index.
            // Only keyframes of the last keyframe's neighbourhood (of the relocalisation's
            // keyframe until the next keyframe): a place revisited after a longer path is a
            // loop, closed by appearance and the Sim(3) correction.
            let loops = self.loops.as_ref().map_or(0, |l| l.edges.len());
            let key = (map.keyframes.len(), loops, self.reference);
            if self.neighbourhood.as_ref().is_none_or(|(k, _)| *k != key) {
                let edges: Vec<(KeyframeId, KeyframeId)> = self
                    .loops
                    .as_ref()
                    .map(|l| l.edges.iter().map(|d| (d.current, d.old)).collect())
                    .unwrap_or_default();
                let hood = covisible_neighbourhood(
                    &map.graph,
                    self.reference,
                    config.mapping.theta,
                    config.mapping.n2,
                    &edges,
                );
                self.neighbourhood = Some((key, hood));
            }
            let hood = &self.neighbourhood.as_ref().expect("set above").1;
            let mut near: Vec<(f64, KeyframeId)> = map
                .keyframe_ids()
                .filter(|k| hood.contains(k))
                .filter_map(|k| {
                    let t = map.rigid_pose(k);
                    (axis(&t).angle(&a) <= max_angle).then(|| ((centre(&t) - c).norm(), k))
                })
                .collect();
            near.sort_by(|x, y| x.0.total_cmp(&y.0).then(x.1.cmp(&y.1)));
            near.truncate(config.mono.refind_keyframes);
            let keyframes: Vec<KeyframeId> = near.into_iter().map(|(_, k)| k).collect();
            let active: std::collections::HashSet<_> =
                explorer.active().values().copied().collect();
            map.graph
                .points_visible_from(&keyframes)
                .into_iter()
                .filter(|p| !active.contains(p))
                .filter_map(|p| SearchPoint::from_graph(&map.graph, p))
                .filter(|sp| view_angle(&pose, sp) <= max_angle)
                .filter_map(|sp| {
                    predict(&self.camera, &pose, &sp, w, h, PATCH_MARGIN_PX).map(|(u, _)| (sp, u))
                })
                .take(config.mono.max_refind)
                .collect()
        };
        if todo.is_empty() {
            return 0;
        }
        let corners = CornerIndex::new(
            fast9(image, config.tracker.fast_threshold, true),
            w,
            h,
            CORNER_CELL_PX,
        );
        let radius = config.tracker.wide_search_radius;
        let mut found = 0;
        for (sp, _) in todo {
            let Some(anchor) = self.images.get(&sp.anchor) else {
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
            if explorer.associate(track, sp.point) {
                found += 1;
            }
        }
        found
    }
}

/// A point is searched only if its prediction lies this far inside the image (8 px: an 8×8
/// patch and its sub-pixel refinement stay inside).
const PATCH_MARGIN_PX: f64 = 8.0;

/// Cell of the corner index the search queries (16 px: about the wide search radius, so a
/// query reads a handful of cells).
const CORNER_CELL_PX: f32 = 16.0;

/// A match this close to a track's position is the corner the track follows (2 px: LK and the
/// sub-pixel refinement each localise a corner to a fraction of a pixel).
const SAME_CORNER_PX: f64 = 2.0;

impl LiveRun<2> for MonoSystem {
    fn process(&mut self, frame: data::sequence::Frame) -> Result<FrameReport, SystemError> {
        let start = Instant::now();
        let image = frame.gray();
        let (width, height) = (image.width(), image.height());
        // Lost in the current map: relocalise this frame, or start a new map once
        // `tracker.new_map_after` has passed.
        let mut relocalised = None;
        if let Some(lost) = self.lost.clone() {
            if frame.timestamp - lost.timestamp > self.config.tracker.new_map_after {
                self.lost = None;
                self.restart(format!(
                    "frame {}: lost at frame {} ({}) and not relocalised within {} s: a new map \
                     starts",
                    frame.index, lost.frame, lost.why, self.config.tracker.new_map_after
                ));
            } else {
                let t = Instant::now();
                let found = self.relocalise(&frame);
                self.record.timings.record("track: relocalise", t.elapsed());
                match found {
                    Ok(found) => relocalised = Some(found),
                    Err(why) => {
                        return Ok(self.lost_frame(
                            &frame,
                            format!(
                                "lost at frame {} ({}); relocalisation: {why}",
                                lost.frame, lost.why
                            ),
                            start,
                        ));
                    }
                }
            }
        }
        let (measurements, refound, relocalisation) = match relocalised {
            Some((measurements, relocalisation)) => {
                (measurements, relocalisation.tracked, Some(relocalisation))
            }
            None => 'tracked: {
                let t = Instant::now();
                let measurements: Result<Vec<(TrackId, Vector2<f64>)>, _> = self
                    .tracks
                    .push(image)
                    .map_err(|e| SystemError::Frame(e.into()))?
                    .map(|tracks| {
                        tracks
                            .iter()
                            .map(|&(id, p)| (id, Vector2::new(p[0] as f64, p[1] as f64)))
                            .collect()
                    });
                self.record
                    .timings
                    .record("frame: pyramid, LK tracks", t.elapsed());
                let mut measurements = match measurements {
                    Ok(m) => {
                        self.refused = 0;
                        m
                    }
                    Err(Refused { survived, of }) => {
                        self.refused += 1;
                        let mut why = format!(
                            "only {survived} of {of} corner tracks followed into this frame: refused"
                        );
                        // The camera may have jumped to another part of the map (a gap in the
                        // recording, a kidnap): the frame's place is looked up at once, as the
                        // stereo and RGB-D system and ORB-SLAM look up a lost frame's. Found,
                        // the camera is lost from here and relocalised there; else the tracks
                        // wait in the last frame they followed into, as before (a black or
                        // blurred frame finds no place).
                        if self.relocalisable() {
                            let t = Instant::now();
                            let place = self.verified_place(&frame);
                            self.record
                                .timings
                                .record("track: refused frame's place", t.elapsed());
                            if let Ok((pose, relocalisation)) = place {
                                let lost = self.lose(&frame, why.clone());
                                let t = Instant::now();
                                let found = self.relocalise_at(&frame, pose, relocalisation);
                                self.record.timings.record("track: relocalise", t.elapsed());
                                match found {
                                    Ok((measurements, r)) => {
                                        break 'tracked (measurements, r.tracked, Some(r));
                                    }
                                    Err(e) => {
                                        return Ok(self.lost_frame(
                                            &frame,
                                            format!("{lost}; relocalisation: {e}"),
                                            start,
                                        ));
                                    }
                                }
                            }
                        }
                        if self.refused >= self.config.mono.max_refused {
                            let refused = self.refused;
                            let lost =
                                self.lose(&frame, format!("{refused} frames in a row refused"));
                            why.push_str(&format!("; {lost}"));
                        }
                        return Ok(self.lost_frame(&frame, why, start));
                    }
                };
                let t = Instant::now();
                self.verify(frame.index, image, &mut measurements);
                if self.explorer.is_some() && self.config.mono.verify_tracks {
                    self.record
                        .timings
                        .record("mono: verify tracks", t.elapsed());
                }
                let t = Instant::now();
                let refound = self.refind(frame.index, image, &mut measurements);
                if self.explorer.is_some() && self.config.mono.refind {
                    self.record
                        .timings
                        .record("mono: re-find map points", t.elapsed());
                }
                (measurements, refound, None)
            }
        };
        let n_tracks = measurements.len();
        let t = Instant::now();
        if self.explorer.is_none() {
            self.bootstrap_first = Some(keyframe_images(&frame));
            let config = exploration_config(&self.config, self.camera.fx, width, height);
            self.explorer = Some(MonoExplorer::new(self.camera, config));
        }
        let explorer = self.explorer.as_mut().expect("made above");
        let outcome = explorer.process(frame.index, &measurements);
        let explored = t.elapsed();
        self.record.timings.record("mono: exploration", explored);
        // Tracking ends with the exploration (its window BA included); place recognition of
        // a new keyframe is not tracking.
        let time_tracking = start.elapsed();
        if let Ok(o) = &outcome
            && let Some(k) = o.keyframe
        {
            if let Some(first) = self.bootstrap_first.take() {
                self.images.insert(KeyframeId::from_index(0), first);
            }
            self.images.insert(k, keyframe_images(&frame));
            let t = Instant::now();
            self.close_loop(k, frame.gray(), frame.index);
            if self.loops.is_some() {
                self.record
                    .timings
                    .record("keyframe: place recognition", t.elapsed());
            }
            if !self.finished.is_empty() {
                let t = Instant::now();
                self.join_maps(k);
                self.record
                    .timings
                    .record("keyframe: join earlier maps", t.elapsed());
            }
        }
        let (state, pose, keyframe, stats) = match outcome {
            Ok(o) => {
                if o.camera_from_world.is_some() {
                    self.lost = None;
                    if let Some(r) = relocalisation {
                        self.relocalisations.push(Relocalisation {
                            tracked: o.tracked,
                            ..r
                        });
                    }
                }
                if o.keyframe.is_some() {
                    self.reference = None;
                }
                let state = match o.camera_from_world {
                    None => TrackingState::Lost(format!(
                        "initialising: {n_tracks} corner tracks, {}",
                        o.waiting.as_deref().unwrap_or("waiting")
                    )),
                    Some(_) if o.tracked < self.config.tracker.min_good => {
                        TrackingState::Weak(format!("{} map points tracked", o.tracked))
                    }
                    Some(_) => TrackingState::Good,
                };
                let reason = if self
                    .explorer
                    .as_ref()
                    .is_some_and(|e| e.map().keyframes.len() <= 2)
                {
                    KeyframeReason::First
                } else {
                    KeyframeReason::Exploration
                };
                let stats = o.camera_from_world.map(|_| TrackerStats {
                    // The tracks are the candidates; the map points among them are measured
                    // (by LK, or found again by guided search) and the motion-only BA keeps
                    // them all (Huber).
                    candidates: n_tracks,
                    visible: n_tracks,
                    searched: o.tracked,
                    found: o.tracked.max(refound),
                    inliers: o.tracked,
                });
                (
                    state,
                    o.camera_from_world,
                    o.keyframe.map(|k| (k, reason)),
                    stats,
                )
            }
            Err(e @ ExplorationError::BootstrapFailed { .. }) => {
                let reason = format!("{e}: initialising again");
                self.restart(format!("frame {}: {reason}", frame.index));
                (TrackingState::Lost(reason), None, None, None)
            }
            Err(e) => {
                let reason = self.lose(&frame, e.to_string());
                (TrackingState::Lost(reason), None, None, None)
            }
        };
        if let Some((_, r)) = &keyframe {
            self.record.timings.record(
                match r {
                    KeyframeReason::First => "keyframe: bootstrap",
                    _ => "keyframe: exploration with window BA",
                },
                explored,
            );
        }
        let report = FrameReport {
            index: frame.index,
            state,
            keyframe,
            stats,
            time: start.elapsed(),
            time_tracking,
        };
        self.record.timings.record("track: total", time_tracking);
        Ok(self.push(report, &frame, pose))
    }

    fn skip_frame(&mut self, index: usize, timestamp: f64, reason: String) {
        let (record, report) = skipped_frame(index, timestamp, reason);
        self.record.frames.push(record);
        self.reports.push(report);
    }

    fn record(&self) -> &RunRecord {
        &self.record
    }

    fn progress(&self) -> crate::live::Progress {
        crate::live::Progress {
            points: self
                .explorer
                .as_ref()
                .map_or(0, |e| e.map().graph.num_points()),
            loops: self.events.len(),
        }
    }

    fn record_timing(&mut self, stage: &str, d: Duration) {
        self.record.timings.record(stage, d);
    }

    fn finish(mut self, interrupted: bool) -> Result<RunResult<2>, SystemError> {
        self.record.interrupted = interrupted;
        let timestamp = self.timestamps();
        let mut maps = std::mem::take(&mut self.finished);
        if let Some(explorer) = self.explorer.take()
            && !explorer.map().keyframes.is_empty()
        {
            let outputs = self.close_map(explorer);
            maps.push(outputs);
        }
        let mut warnings = std::mem::take(&mut self.warnings);
        // The maps written: the group of maps joined together with the most keyframes, in the
        // world of its map with the most keyframes (a lone map: the one with the most
        // keyframes, the first on a tie, as the stereo and RGB-D system's, and ORB-SLAM3's
        // biggest map). Another map's frames have no pose in its world: each map has its own
        // frame and scale. A join's similarity is taken from its detection with the most
        // inliers, with the two maps' keyframe poses as they are at the end.
        let mut links: Vec<(usize, usize, Sim3)> = Vec::new();
        for j in &self.joins {
            if links.iter().any(|l| (l.0, l.1) == (j.map, j.other)) {
                continue;
            }
            let best = self
                .joins
                .iter()
                .filter(|o| (o.map, o.other) == (j.map, j.other))
                .max_by_key(|o| o.inliers)
                .expect("j itself");
            let graph = |m: usize| maps.iter().find(|o| o.map == m).map(|o| &o.graph);
            if let (Some(later), Some(earlier)) = (graph(best.map), graph(best.other))
                && let Some(w) = best.map_from_other(later, earlier)
            {
                links.push((best.map, best.other, w));
            }
        }
        let keyframe_counts: Vec<(usize, usize)> =
            maps.iter().map(|m| (m.map, m.keyframes.len())).collect();
        let (world, joined) = written_maps(&keyframe_counts, &links);
        if world != FIRST_MAP {
            let dropped = write_map(
                world,
                &mut self.record.frames,
                &mut self.reports,
                self.off_first
                    .iter()
                    .map(|(i, m, pose, state)| (*i, *m, *pose, state)),
            );
            let keyframes_of = |m: usize| {
                maps.iter()
                    .find(|o| o.map == m)
                    .map_or(0, |o| o.keyframes.len())
            };
            warnings.push(format!(
                "the map written is map {world}, which holds more keyframes ({}) than the first \
                 ({}): the first map's {dropped} frames have no pose in the {}",
                keyframes_of(world),
                keyframes_of(FIRST_MAP),
                if joined.contains_key(&FIRST_MAP) {
                    "live trajectory (the first map is joined to it: they are in the final one)"
                } else {
                    "trajectories"
                }
            ));
        }
        // The maps started after a loss: where, how long after the last pose, how many frames.
        let mut new_maps = Vec::new();
        // Each map starts after the last frame of the one before (maps follow one another).
        for pair in maps.windows(2) {
            let (before, m) = (&pair[0], &pair[1]);
            let (Some(&(first, _)), Some(&(last, _))) =
                (m.trajectories[0].1.first(), before.trajectories[0].1.last())
            else {
                continue;
            };
            let at = |f: usize| timestamp.get(&f).copied().unwrap_or(f64::NAN);
            new_maps.push(NewMap {
                frame: first,
                lost_for: at(first) - at(last),
                map: m.map,
                joined: joined.contains_key(&m.map),
                frames: self.off_first.iter().filter(|o| o.1 == m.map).count(),
            });
        }
        for j in &self.joins {
            if let Some(first) = self
                .joins
                .iter()
                .find(|o| (o.map, o.other) == (j.map, j.other))
                && first == j
            {
                warnings.push(format!(
                    "frame {}: map {} recognised a place of map {} (frame {}; Sim(3) scale {:.3}, \
                     {} inliers, {LOOP_CONSISTENCY} agreeing detections): the two maps are \
                     joined in the outputs{}",
                    j.frames.0,
                    j.map,
                    j.other,
                    j.frames.1,
                    j.detection.current_from_old.scale(),
                    j.inliers,
                    if joined.contains_key(&j.map) {
                        ""
                    } else {
                        " (not the maps written)"
                    }
                ));
            }
        }
        for m in &new_maps {
            let NewMap {
                frame,
                lost_for,
                map,
                frames,
                ..
            } = m;
            warnings.push(if *map == world {
                format!(
                    "frame {frame}: tracking lost {lost_for:.1} s before; a new map (map {map}) \
                     was initialised there: the map written"
                )
            } else if joined.contains_key(map) {
                format!(
                    "frame {frame}: tracking lost {lost_for:.1} s before; a new map (map {map}) \
                     was initialised there and later joined to map {world}: its {frames} frames \
                     are in the final trajectory (not in the live one), its keyframes and points \
                     in the map written"
                )
            } else {
                format!(
                    "frame {frame}: tracking lost {lost_for:.1} s before; a new map (map {map}) \
                     was initialised there, with a frame and a scale of its own, and no place \
                     of it was recognised from the maps written or theirs from it: its {frames} \
                     frames have no pose in the trajectories, and its keyframes and points are \
                     not in the map written"
                )
            });
        }
        let to_trajectory = |poses: &[(usize, Se3)]| {
            let mut t = Trajectory::default();
            for (frame, camera_from_world) in poses {
                if let Some(&ts) = timestamp.get(frame) {
                    t.timestamps.push(ts);
                    t.world_from_body.push(camera_from_world.inverse());
                }
            }
            t
        };
        // The maps written, the world's first, each with `x_map = W·x_world`.
        let mut written: Vec<MapOutputs> = maps
            .into_iter()
            .filter(|m| joined.contains_key(&m.map))
            .collect();
        written.sort_by_key(|m| (m.map != world, m.map));
        let (final_trajectory, alternatives, graph, loops) = if written.is_empty() {
            (
                Trajectory::default(),
                Vec::new(),
                SlamGraph::default(),
                std::mem::take(&mut self.events),
            )
        } else {
            let in_world = |w: &Sim3, camera_from_map: &Se3| {
                rigid_from_similarity(&Sim3::from_se3(camera_from_map).compose(w))
            };
            // Each trajectory of the world's map, with the joined maps' frames in its world
            // (their trajectory of the same name, else their final one).
            let names: Vec<&'static str> =
                written[0].trajectories.iter().map(|(n, _)| *n).collect();
            let mut trajectories: Vec<(&'static str, Trajectory)> = Vec::new();
            for name in names {
                let mut poses: Vec<(usize, Se3)> = Vec::new();
                for m in &written {
                    let w = joined[&m.map];
                    let own = m
                        .trajectories
                        .iter()
                        .find(|(n, _)| *n == name)
                        .unwrap_or(&m.trajectories[0]);
                    poses.extend(own.1.iter().map(|(f, t)| (*f, in_world(&w, t))));
                }
                poses.sort_by_key(|(f, _)| *f);
                trajectories.push((name, to_trajectory(&poses)));
            }
            let mut keyframes = Vec::new();
            let mut points = Vec::new();
            let mut loops = Vec::new();
            let mut graph = SlamGraph::default();
            for m in written {
                let w = joined[&m.map];
                let world_from_map = w.inverse();
                // Keyframe ids follow on from the maps before (each map numbers its own).
                let offset = keyframes
                    .iter()
                    .map(|k: &KeyframeRecord| k.id + 1)
                    .max()
                    .unwrap_or(0);
                keyframes.extend(m.keyframes.into_iter().map(|k| KeyframeRecord {
                    id: k.id + offset,
                    world_from_camera: in_world(&w, &k.world_from_camera.inverse()).inverse(),
                    ..k
                }));
                points.extend(m.points.into_iter().map(|p| MapPoint {
                    position: world_from_map.act(&p.position),
                    ..p
                }));
                loops.extend(m.loops);
                if m.map == world {
                    graph = m.graph;
                }
            }
            keyframes.sort_by(|a, b| a.timestamp.total_cmp(&b.timestamp));
            loops.sort_by_key(|l| l.frames.0);
            self.record.keyframes = keyframes;
            self.record.points = points;
            let mut trajectories = trajectories.into_iter();
            let (_, final_trajectory) = trajectories.next().expect("a trajectory per map");
            (final_trajectory, trajectories.collect(), graph, loops)
        };
        if self.rejected_loops > 0 {
            warnings.push(format!(
                "{} loops found by appearance were refused: each needed more than {:.0} % of \
                 the path between the two places as drift (a place that looks like another)",
                self.rejected_loops,
                MAX_DRIFT_FRACTION * 100.0
            ));
        }
        Ok(RunResult {
            record: self.record,
            final_trajectory,
            frames: self.reports,
            loops,
            relocalisations: self.relocalisations,
            new_maps,
            world_map: world,
            refused_loops: Vec::new(),
            optimisations: Vec::new(),
            graph,
            keyframes: KeyframeStore::new(),
            warnings,
            alternatives,
        })
    }
}

/// A monocular map's outputs ([`MonoSystem::close_map`]).
struct MapOutputs {
    /// Its number (`slam::map::FIRST_MAP` the first).
    map: usize,
    /// Its frames' poses `(frame, camera_from_world)` after the loops' correction, by file
    /// stem: the final trajectory first, then the alternatives.
    trajectories: Vec<(&'static str, Vec<(usize, Se3)>)>,
    keyframes: Vec<KeyframeRecord>,
    points: Vec<MapPoint>,
    /// The corrected graph.
    graph: SlamGraph<2>,
    /// Its loops (keyframe ids are the map's own: each map numbers its keyframes anew).
    loops: Vec<LoopEvent>,
    /// Its keyframe database, once the map is closed (for the later maps to join it by).
    place: Option<PlaceRecognition>,
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Keyframes every metre along x, looking along z, one point 5 m ahead of each.
    fn corridor(n: usize) -> SlamGraph<2> {
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
        // 2 (a drifted revisit's few re-found points).
        for (old, n) in [(15, 25), (2, 3)] {
            for _ in 0..n {
                let p = g
                    .add_point(id(old), Vector3::new(0.0, 0.0, 0.2), z)
                    .unwrap();
                g.add_observation(id(30), p, z).unwrap();
            }
        }
        let close = topologically_close(&g, id(30), 20, 10);
        let expected: BTreeSet<KeyframeId> = (20..=30).chain([15]).map(id).collect();
        assert_eq!(close, expected);
        // With θ = 3 the revisit's keyframe counts as connected.
        assert!(topologically_close(&g, id(30), 3, 10).contains(&id(2)));
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
            assert_eq!(
                loop_within_drift(&g, old, k, &k_from_old),
                accepted,
                "offset {offset}"
            );
        }
    }

    #[test]
    fn the_maps_written_are_the_joined_group_with_the_most_keyframes() {
        let sim = |x: f64, s: f64| {
            Sim3::new(
                lie::So3::exp(&Vector3::new(0.1, -0.2, x)),
                Vector3::new(x, 1.0, -2.0),
                s,
            )
            .unwrap()
        };
        // Map 1 joined to 0, map 2 to 1; map 3 alone.
        let (w10, w21) = (sim(0.3, 0.8), sim(-0.5, 1.7));
        let links = [(1, 0, w10), (2, 1, w21)];
        let (world, group) = written_maps(&[(0, 20), (1, 45), (2, 10), (3, 30)], &links);
        assert_eq!(world, 1);
        assert_eq!(group.keys().copied().collect::<Vec<_>>(), vec![0, 1, 2]);
        // x_map = W·x_world for each, composed through the links.
        let x = Vector3::new(0.4, -1.2, 3.0);
        let close = |a: Vector3<f64>, b: Vector3<f64>| (a - b).norm() < 1e-9;
        assert!(close(group[&1].act(&x), x));
        assert!(close(w10.act(&group[&0].act(&x)), x));
        assert!(close(group[&2].act(&x), w21.act(&x)));
        // A lone map with more keyframes than the joined group is written alone.
        let (world, group) = written_maps(&[(0, 20), (1, 20), (2, 50)], &[(1, 0, w10)]);
        assert_eq!((world, group.len()), (2, 1));
        // Without links: the largest map, the first on a tie.
        let (world, _) = written_maps(&[(0, 20), (1, 20)], &[]);
        assert_eq!(world, 0);
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
        };
        let a = detection(15, 2, s(15, 2));
        assert!(loops_agree(&g, &g, &a, &detection(16, 3, s(16, 3))));
        // A second detection that jumps to an unrelated place (keyframe 9) does not agree.
        assert!(!loops_agree(&g, &g, &a, &detection(16, 9, s(16, 3))));
        // Nor one whose scale differs by 30 %.
        let scaled = Sim3::new(lie::So3::identity(), Vector3::zeros(), 1.3)
            .unwrap()
            .compose(&s(16, 3));
        assert!(!loops_agree(&g, &g, &a, &detection(16, 3, scaled)));
    }
}
