//! Monocular exploration (thesis ch. 3): keyframe-based visual odometry with sliding-window
//! bundle adjustment over measurements whose data association is given (feature tracks from a
//! front-end, or a simulator).
//!
//! For every frame, in order:
//!
//! 1. **Bootstrap** (thesis §3.5): until a map exists, the first frame is paired with each new
//!    one; [`geom::bootstrap::bootstrap_pose`] fits the homography and the essential matrix in
//!    RANSAC, chooses by GRIC, and triangulates the chosen model's inliers (cheirality and
//!    re-projection checked) once the median parallax gives a typical point a relative depth
//!    error below `bootstrap_depth_error` (and at least `min_bootstrap_parallax`); both views
//!    are bundle adjusted with the first pose fixed and the scale left to the damping
//!    (§4.5.3), and the map is scaled so the baseline has unit length — the arbitrary scale
//!    every monocular map invents.
//! 2. **Tracking**: the pose is predicted with constant velocity and refined by motion-only BA
//!    (thesis eq. 4.14) against the active map points measured in this frame, with a Huber
//!    kernel.
//! 3. **Keyframe selection by distance** (§3.3.3): a frame becomes a keyframe when its camera
//!    centre is farther from the last keyframe's than `keyframe_distance` times the median depth
//!    of its tracked points (a ratio, so it does not depend on the drifting map scale), or when
//!    too few map points are tracked.
//! 4. **Feature initialisation** (§3.4.4): every frame updates the inverse-depth filters
//!    ([`crate::feature_init`]) of the tracks it measures; converged features are promoted to
//!    map points with their keyframe measurements. In each keyframe, new features are started
//!    where the feature density is low: candidates are visited in the equi-distributed order of
//!    thesis Alg. 2 ([`vision::quadtree`]) and accepted when no feature lies within
//!    `feature_spacing` pixels (the bounding-box test of Mei et al. 2009, Fig. 3.7), until
//!    `max_features` are tracked. A new filter starts at the median inverse depth of the
//!    keyframe's map points (no depth prior is imposed: `Λ_ψ` has no depth information).
//! 5. **Keyframe BA** (§3.3.3) over a window of `window` keyframes: the last ones (the
//!    thesis's sliding window, [`LocalWindow::Sliding`]) or the new keyframe, the one before it
//!    and those sharing most points with it ([`LocalWindow::Covisible`]: on a revisit the old
//!    keyframes of the place are optimised with the new ones). Up to `fixed_observers` older
//!    keyframes that measure the window's points join as fixed poses; with fewer than two of
//!    them the window's two oldest keyframes are fixed instead. Either anchors the window to
//!    the trajectory and fixes the scale gauge. Points measured at least twice are optimised
//!    (eliminated by the Schur complement); points measured once are held fixed. With
//!    `remove_outliers`, the measurements the optimum does not explain leave the map.
//!
//! A track that is not measured in a frame ends: its map point leaves the active set (and its
//! filter is dropped). A world point seen again later is a new track — only loop closure
//! ([`crate::loop_closure`]) relates it to the old one.
//!
//! The map is a [`SlamGraph`] ([`ExploredMap`]): keyframes with absolute poses (similarities
//! of scale 1 until a loop correction), points anchored in the keyframe their filter started
//! in, by inverse depth. The window BA optimises Euclidean points (the parametrisation of
//! §3.3.3) and writes them back anchored.

mod bootstrap;
mod error;
pub mod feature_init;
mod poses;
mod resume;
mod window;
mod window_job;

pub use error::ExplorationError;
pub use poses::rigid_pose;
use window_job::solver;
pub use window_job::{SolvedWindow, WindowJob};

use crate::ba::{BaMode, BundleAdjustment, Gauge, Observation};
use crate::dwo::DwoStats;
use crate::factors::point_to_inverse_depth;
use crate::map::{GraphAccess, KeyframeId, PointId, SlamGraph};
use crate::tracking::{MotionOnlyOptions, motion_only_ba};
use feature_init::{FeatureFilters, FeatureId, FeatureInitConfig};
use geom::bootstrap::{BootstrapConfig, bootstrap_pose};
use geom::ransac::RansacConfig;
use geom::{CameraModel, PinholeCamera};
use lie::{LieGroup, Se3, Sim3};
use lsq::RobustKernel;
use nalgebra::{Vector2, Vector3};
use std::collections::{HashMap, HashSet};
use vision::quadtree::{QuadPoint, QuadTree};

pub use crate::tracking::TrackId;

/// Parameters of [`MonoExplorer`].
#[derive(Clone, Debug)]
pub struct ExplorationConfig {
    /// Pixel noise σ: measurement information `I/σ²`.
    pub sigma: f64,
    /// Keyframes in the sliding BA window (thesis §5.4: 10).
    pub window: usize,
    /// A keyframe when the distance from the last keyframe exceeds this fraction of the median
    /// scene depth ([`KeyframeBaseline::Distance`]), or the median parallax of the tracked
    /// points exceeds this many radians ([`KeyframeBaseline::Parallax`]).
    pub keyframe_distance: f64,
    /// How a keyframe's baseline to the current view is measured against `keyframe_distance`.
    pub keyframe_baseline: KeyframeBaseline,
    /// A keyframe also when fewer map points than this are tracked.
    pub min_tracked_for_keyframe: usize,
    /// `Some(angle)` (radians): a keyframe only where no nearby keyframe covers the view —
    /// within `keyframe_distance` of the scene depth *and* within this angle of its viewing
    /// direction (`MonoExplorer::view_uncovered`); `None`: by distance from the last keyframe
    /// alone (thesis §3.3.3).
    pub keyframe_rotation: Option<f64>,
    /// With `keyframe_rotation`: a nearby keyframe covers the view only if the frame tracks at
    /// least this fraction of the map points that keyframe measures.
    pub keyframe_min_tracked_fraction: f64,
    /// Tracking is lost below this many tracked map points.
    pub min_tracked: usize,
    /// New features are started until this many are tracked (map points and filters).
    pub max_features: usize,
    /// A new feature needs a feature-free box of this half-size (pixels) around it.
    pub feature_spacing: f64,
    /// Image width (pixels).
    pub image_width: f64,
    /// Image height (pixels).
    pub image_height: f64,
    /// The feature-initialisation filters (its `sigma` is set from [`sigma`](Self::sigma)).
    pub feature_init: FeatureInitConfig,
    /// Huber kernel width in units of σ.
    pub huber: f64,
    /// Levenberg-Marquardt iterations of the window BA.
    pub ba_iterations: usize,
    /// Levenberg-Marquardt iterations of motion-only tracking.
    pub tracking_iterations: usize,
    /// Minimum median parallax (radians) for the bootstrap, beyond what
    /// [`bootstrap_depth_error`](Self::bootstrap_depth_error) needs.
    pub min_bootstrap_parallax: f64,
    /// The bootstrap waits for the parallax at which a typical point's relative depth error is
    /// at most this (`geom::bootstrap::BootstrapConfig::max_relative_depth_error`).
    pub bootstrap_depth_error: f64,
    /// `Some(floor)`: the bootstrap's parallax requirement uses the corner noise measured on
    /// the two frames, at least `floor` pixels and at most `sigma`
    /// (`geom::bootstrap::BootstrapConfig::min_pixel_sigma`); `None`: `sigma`.
    pub bootstrap_min_sigma: Option<f64>,
    /// Minimum fraction of the common tracks that must be inliers of the bootstrap's relative
    /// pose (a wrong two-view solution explains only a part of the correspondences).
    pub min_bootstrap_inlier_ratio: f64,
    /// Give up bootstrapping after this many frames.
    pub max_bootstrap_frames: usize,
    /// RANSAC of the bootstrap: its seed and iteration budget (the inlier gates come from
    /// `sigma` and the χ² quantiles at 95 %).
    pub ransac: RansacConfig,
    /// Seed of the quadtree traversal.
    pub seed: u64,
    /// Optimise each new keyframe by double window optimisation (thesis §6.2.7, the monocular
    /// double window: scale fixed, the inner window's points and poses by BA, the outer
    /// window's poses by pose-pose constraints, both found by covisibility from the new
    /// keyframe, so points measured again on a revisit pull old keyframes in) instead of the
    /// sliding window of the last `window` keyframes (`None`, the thesis ch. 3 explorer).
    pub double_window: Option<crate::dwo::DwoParams>,
    /// With the double window: a new keyframe's covisibility edges (local registration,
    /// thesis §6.2.6) go to the keyframes sharing at least this many points with it, and
    /// always to the previous keyframe.
    pub theta: usize,
    /// The window of the keyframe BA: the last `window` keyframes (the thesis ch. 3/5
    /// explorer, [`LocalWindow::Sliding`]) or the keyframes sharing most points with the new one
    /// ([`LocalWindow::Covisible`]).
    pub local_window: LocalWindow,
    /// Keyframes outside the window that measure its points join the BA as fixed poses, at
    /// most this many (those measuring most of them); with two or more the window needs no pose
    /// of its own fixed. 0: none (the window's two oldest keyframes are fixed).
    pub fixed_observers: usize,
    /// After the keyframe BA, the measurements it does not explain (squared re-projection
    /// error beyond the χ² 95 % gate of two degrees of freedom, `5.99·σ²`) leave the map, and a
    /// track whose measurement in the new keyframe is one stops measuring its point (its data
    /// association is suspect: a drifted or jumped corner track, a wrong re-found match).
    /// Off in the thesis's simulated explorations, whose data association is perfect.
    pub remove_outliers: bool,
    /// A feature started in a keyframe also takes in its track's first measurement since the
    /// keyframe before (with that frame's pose; a keyframe's as its window left it): its
    /// filter starts with the parallax the track gathered between the two keyframes instead
    /// of waiting for the frames after the new one (on a forward drive the near points leave
    /// the view within a few frames), and the point it becomes is measured in the keyframe
    /// before too when the track was there. Not further back: a corner track drifts the longer
    /// it lives — on 7-Scenes the track's first measurement ever gave 4.35 cm after the run
    /// (one seed of six 48 cm), since the keyframe before 4.09, none 3.91 (medians).
    pub feature_history: bool,
}

/// How [`MonoExplorer`] measures the baseline between a keyframe and the current view, against
/// [`ExplorationConfig::keyframe_distance`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum KeyframeBaseline {
    /// The distance between the camera centres over the median scene depth (thesis §3.3.3): the
    /// parallax a point straight ahead of a camera moving sideways would have.
    Distance,
    /// The median, over the tracked map points, of the angle between the rays from the two
    /// camera centres to the point (radians): the parallax a new point triangulated between
    /// the two views would have — what a keyframe is for (thesis §6.2.6, "the incremental
    /// translation/parallax"). Equal to [`Distance`](Self::Distance) for a camera moving
    /// sideways; for one moving forward it is the smaller by the sine of the angle between
    /// the motion and the rays (points near the direction of travel gain no parallax), so a
    /// car driving down a road makes a keyframe when the road's points have moved in its
    /// images, not every few metres.
    Parallax,
}

/// Why [`MonoExplorer`] made a frame a keyframe: why the last keyframe (and every other
/// keyframe near the view, with `keyframe_rotation`) does not cover it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum ExplorationKeyframe {
    /// The baseline to the last keyframe, in units of `keyframe_distance` (> 1): the
    /// distance over the scene depth or the tracked points' median parallax
    /// ([`KeyframeBaseline`]).
    Baseline(f64),
    /// The camera turned this many radians from the last keyframe's viewing direction
    /// (more than `keyframe_rotation`).
    Rotation(f64),
    /// The frame tracks this fraction of the map points the last keyframe measures (less than
    /// `keyframe_min_tracked_fraction`): the map thins out.
    Thinning(f64),
    /// Fewer map points than `min_tracked_for_keyframe` tracked: this many.
    FewTracked(usize),
}

/// Which keyframes the keyframe BA of [`MonoExplorer`] optimises.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LocalWindow {
    /// The last `window` keyframes (thesis §3.3.3).
    Sliding,
    /// The new keyframe, the previous one and the keyframes sharing most points with the new
    /// one, `window` in all: on a revisit the old keyframes of the place join the window, so
    /// the points measured again are optimised with their old measurements.
    Covisible,
}

impl Default for ExplorationConfig {
    /// A 640×480 camera with σ = 1 px, a window of 10 keyframes, keyframes every 5 % of the
    /// scene depth, up to 150 features at least 12 px apart, Huber at 2σ, bootstrap at 2° median
    /// parallax (a relative depth error of 10 % needs 1.5° at f = 525 px) with at least 60 %
    /// inliers and RANSAC's default budget.
    fn default() -> Self {
        ExplorationConfig {
            sigma: 1.0,
            window: 10,
            keyframe_distance: 0.05,
            keyframe_baseline: KeyframeBaseline::Distance,
            min_tracked_for_keyframe: 30,
            keyframe_rotation: None,
            keyframe_min_tracked_fraction: 0.5,
            min_tracked: 8,
            max_features: 150,
            feature_spacing: 12.0,
            image_width: 640.0,
            image_height: 480.0,
            feature_init: FeatureInitConfig::default(),
            huber: 2.0,
            ba_iterations: 10,
            tracking_iterations: 10,
            min_bootstrap_parallax: 2f64.to_radians(),
            bootstrap_depth_error: 0.1,
            bootstrap_min_sigma: None,
            min_bootstrap_inlier_ratio: 0.6,
            max_bootstrap_frames: 30,
            ransac: RansacConfig::default(),
            seed: 0,
            double_window: None,
            theta: 20,
            local_window: LocalWindow::Sliding,
            fixed_observers: 0,
            remove_outliers: false,
            feature_history: false,
        }
    }
}

/// The front-end's view of a keyframe: the frame it was made from and every measurement in
/// it, of map points or not (for loop closure).
#[derive(Clone, Debug, PartialEq)]
pub struct KeyframeFrame {
    /// The frame index given to [`MonoExplorer::process`].
    pub frame: usize,
    /// Every measurement of the frame: `(track, z)`.
    pub measurements: Vec<(TrackId, Vector2<f64>)>,
}

/// What an exploration knows of the map it builds in a [`SlamGraph`] besides the graph: the
/// front-end's identities of its keyframes and points.
#[derive(Clone, Debug, Default)]
pub struct ExploredMap {
    /// Per keyframe (indexed by [`KeyframeId::index`]): its frame and measurements.
    pub keyframes: Vec<KeyframeFrame>,
    /// Per point (indexed by [`PointId::index`]): the track it was initialised from.
    pub tracks: Vec<TrackId>,
}

impl ExploredMap {
    /// The frame and measurements of keyframe `k`.
    pub fn keyframe(&self, k: KeyframeId) -> &KeyframeFrame {
        &self.keyframes[k.index()]
    }

    /// The track of point `p`.
    pub fn track(&self, p: PointId) -> TrackId {
        self.tracks[p.index()]
    }

    /// The keyframes in order of creation (of every map the exploration started).
    pub fn keyframe_ids(&self) -> impl Iterator<Item = KeyframeId> + '_ {
        (0..self.keyframes.len()).map(KeyframeId::from_index)
    }

    fn add_keyframe(
        &mut self,
        graph: &mut SlamGraph<2>,
        frame: usize,
        pose: Se3,
        measurements: &[(TrackId, Vector2<f64>)],
    ) -> KeyframeId {
        let k = graph.add_keyframe(Sim3::from_se3(&pose));
        debug_assert_eq!(k.index(), self.keyframes.len());
        self.keyframes.push(KeyframeFrame {
            frame,
            measurements: measurements.to_vec(),
        });
        k
    }

    /// A point of `track` at `point_world`, anchored in `anchor`, which measures it as `z`;
    /// `None` if it is not in front of the anchor.
    fn add_point(
        &mut self,
        graph: &mut SlamGraph<2>,
        track: TrackId,
        anchor: KeyframeId,
        point_world: &Vector3<f64>,
        z: Vector2<f64>,
    ) -> Option<PointId> {
        let t_a = *graph.keyframe(anchor)?.camera_from_world();
        let psi = point_to_inverse_depth(&t_a.act(point_world))?;
        let p = graph.add_point(anchor, psi, z).ok()?;
        debug_assert_eq!(p.index(), self.tracks.len());
        self.tracks.push(track);
        Some(p)
    }
}

/// What [`MonoExplorer::process`] did with a frame.
#[derive(Clone, Debug)]
pub struct FrameOutcome {
    /// The frame's estimated pose, `None` while bootstrapping.
    pub camera_from_world: Option<Se3>,
    /// The keyframe if the frame became one.
    pub keyframe: Option<KeyframeId>,
    /// Why the frame became a keyframe (`None` for the bootstrap's keyframes).
    pub keyframe_reason: Option<ExplorationKeyframe>,
    /// Map points tracked.
    pub tracked: usize,
    /// Features promoted to the map in this frame.
    pub promoted: usize,
    /// Filters started in this frame.
    pub started: usize,
    /// Filters running after this frame.
    pub filters: usize,
    /// While bootstrapping: why this frame did not start the map (e.g. too little parallax).
    pub waiting: Option<String>,
    /// The keyframe's double window optimisation, with `double_window`.
    pub optimisation: Option<DwoStats>,
    /// How long the keyframe's window took (copied out, solved, written back): the part of a
    /// keyframe's time that another thread could take over.
    pub window_time: Option<std::time::Duration>,
    /// A keyframe's window left to the caller (`defer_windows`): solve it
    /// ([`WindowJob::solve`], in any thread) and give it back ([`MonoExplorer::apply_window`])
    /// before the next frame.
    pub window: Option<WindowJob>,
}

enum State {
    Empty,
    Bootstrapping {
        first: usize,
        measurements: Vec<(TrackId, Vector2<f64>)>,
        tried: usize,
    },
    Tracking {
        last_frame: usize,
        last_pose: Se3,
        /// Per-frame motion `T_t·T_{t−1}⁻¹`.
        velocity: Se3,
    },
}

/// The scale of keyframe `k`'s similarity.
fn scale(graph: &SlamGraph<2>, k: KeyframeId) -> f64 {
    graph
        .keyframe(k)
        .expect("an exploration's keyframes are never removed")
        .camera_from_world()
        .scale()
}

/// Monocular exploration over feature tracks (see the [module docs](self)), building its map
/// in a [`SlamGraph`] the caller keeps and passes to every call that reads or changes it (the
/// live system shares it between threads). Several maps can be explored one after the other in
/// one graph ([`MonoExplorer::start_map`]).
pub struct MonoExplorer {
    camera: PinholeCamera,
    config: ExplorationConfig,
    map: ExploredMap,
    /// The first keyframe of the current map (its index): keyframes before it belong to maps
    /// explored before.
    map_start: usize,
    /// Tracks with a map point that were measured in the last frame.
    active: HashMap<TrackId, PointId>,
    filters: FeatureFilters<PinholeCamera, 2>,
    filter_of_track: HashMap<TrackId, FeatureId>,
    keyframe_of_frame: HashMap<usize, KeyframeId>,
    frame_poses: Vec<(usize, Se3)>,
    state: State,
    double_window: Option<crate::dwo::DoubleWindowOptimiser>,
    /// Only localise: track the map's points; where they do not cover the view, temporary
    /// keyframes with their own points ([`MonoExplorer::resume`]).
    localise: bool,
    /// Localising: the keyframes made where the map does not cover the view, oldest first
    /// ([`MonoExplorer::remove_temporary`]).
    temporary: Vec<KeyframeId>,
    /// A keyframe's window is left to the caller ([`MonoExplorer::defer_windows`]).
    defer_windows: bool,
    /// Tracks whose measurement in the next frame is on probation ([`MonoExplorer::suspect`]).
    suspects: HashSet<TrackId>,
    /// With `feature_history`: per live track that is not a feature, its first measurement
    /// since the last keyframe, `(frame, camera_from_world, z)` — one per corner track at most.
    history: HashMap<TrackId, (usize, Se3, Vector2<f64>)>,
}

fn median(values: &mut [f64]) -> Option<f64> {
    if values.is_empty() {
        return None;
    }
    values.sort_by(f64::total_cmp);
    Some(values[values.len() / 2])
}

impl MonoExplorer {
    /// A new explorer for a pinhole camera.
    pub fn new(camera: PinholeCamera, config: ExplorationConfig) -> Self {
        let fi = FeatureInitConfig {
            sigma: config.sigma,
            ..config.feature_init
        };
        MonoExplorer {
            camera,
            double_window: config
                .double_window
                .clone()
                .map(crate::dwo::DoubleWindowOptimiser::new),
            filters: FeatureFilters::new(camera, fi),
            config,
            map: ExploredMap::default(),
            map_start: 0,
            active: HashMap::new(),
            filter_of_track: HashMap::new(),
            keyframe_of_frame: HashMap::new(),
            frame_poses: Vec::new(),
            state: State::Empty,
            localise: false,
            temporary: Vec::new(),
            defer_windows: false,
            suspects: HashSet::new(),
            history: HashMap::new(),
        }
    }

    /// Leaves each new keyframe's window — its BA or the double window — to the caller
    /// (`FrameOutcome::window`): a live system solves it in a back-end thread while the next
    /// frame's tracks are followed, and gives it back before the next frame is explored
    /// ([`MonoExplorer::apply_window`]).
    pub fn defer_windows(&mut self, defer: bool) {
        self.defer_windows = defer;
    }

    /// The keyframes' and points' records so far (the map itself is the caller's graph).
    pub fn map(&self) -> &ExploredMap {
        &self.map
    }

    /// The keyframes of the current map, oldest first.
    pub fn map_keyframes(&self) -> impl Iterator<Item = KeyframeId> + '_ {
        (self.map_start..self.map.keyframes.len()).map(KeyframeId::from_index)
    }

    /// `(frame, camera_from_world)` of every tracked frame (keyframe poses as last optimised in
    /// `graph`).
    pub fn frame_poses(&self, graph: &SlamGraph<2>) -> Vec<(usize, Se3)> {
        self.frame_poses
            .iter()
            .map(|(f, t)| match self.keyframe_of_frame.get(f) {
                Some(&k) => (*f, rigid_pose(graph, k)),
                None => (*f, *t),
            })
            .collect()
    }

    /// The pose predicted for `frame` by constant velocity from the last tracked frame (`None`
    /// before the bootstrap, or for a frame not after the last one).
    pub fn predicted_pose(&self, frame: usize) -> Option<Se3> {
        match &self.state {
            State::Tracking {
                last_frame,
                last_pose,
                velocity,
            } if frame > *last_frame => {
                let steps = (frame - last_frame) as f64;
                Some(Se3::exp(&(velocity.log() * steps)).compose(last_pose))
            }
            _ => None,
        }
    }

    /// The map points measured in the last frame, by track.
    pub fn active(&self) -> &HashMap<TrackId, PointId> {
        &self.active
    }

    /// Whether `track` is a feature: it measures a map point or runs an inverse-depth filter.
    pub fn is_feature(&self, track: TrackId) -> bool {
        self.active.contains_key(&track) || self.filter_of_track.contains_key(&track)
    }

    /// Declares that `track` measures the map point `point` from the next processed frame on:
    /// a point the front-end found again (guided search on a revisit, thesis §6.2.5) rejoins
    /// tracking, the keyframes' measurements and the window BA. A filter the track had is
    /// dropped. `false` if the point does not exist or another track already measures it.
    pub fn associate(&mut self, graph: &SlamGraph<2>, track: TrackId, point: PointId) -> bool {
        if graph.point(point).is_none() || self.active.values().any(|&p| p == point) {
            return false;
        }
        if let Some(id) = self.filter_of_track.remove(&track) {
            self.filters.remove(id);
        }
        self.active.insert(track, point);
        true
    }

    /// Puts `track`'s measurement in the next processed frame on probation: the front-end
    /// could not confirm that the track still shows its map point (its template did not align
    /// to the image), nor that it does not. The measurement keeps its point only if its
    /// squared re-projection error at the motion-only pose of the frame's other measurements
    /// (or of all of them, where fewer than `min_tracked` others are left) is within the χ²
    /// 95 % gate of two degrees of freedom, `5.99·σ²` (the keyframe BA's outlier gate,
    /// [`ExplorationConfig::remove_outliers`]); beyond it the association ends — the track goes
    /// on as a plain corner track, the point can be found again. The frame's pose is then
    /// solved with every measurement that kept its point. A track not on probation is never
    /// dropped by its residual between keyframes: on a real hand-held sequence the frame's
    /// corner tracks are noisier than σ, and dropping every measurement beyond the gate (even
    /// the 99.9 % one) cuts the map's tracks short and loses the camera (7-Scenes: 4.8 cm →
    /// 45 cm, bench/README.md, "Tracks the template cannot judge").
    pub fn suspect(&mut self, track: TrackId) {
        self.suspects.insert(track);
    }

    /// Restarts tracking in the existing map at `frame` from `camera_from_world` (a lost
    /// camera found again, e.g. by P3P against a keyframe's points): the next
    /// [`process`](Self::process)ed frame, which must come after `frame − 1`, is predicted
    /// at that pose with no motion. The tracks of before the loss are gone, so their
    /// associations and the running feature filters are dropped; the front-end
    /// [`associate`](Self::associate)s the map points it finds around the pose before
    /// processing the frame. `false` (nothing changed) before the bootstrap: there is no map
    /// to return to.
    pub fn relocalise(&mut self, frame: usize, camera_from_world: Se3) -> bool {
        if self.map_keyframes().next().is_none() {
            return false;
        }
        self.active.clear();
        self.filters.retain(|_, _| false);
        self.filter_of_track.clear();
        self.history.clear();
        self.state = State::Tracking {
            last_frame: frame.saturating_sub(1),
            last_pose: camera_from_world,
            velocity: Se3::identity(),
        };
        true
    }

    /// Ends the current map: the next [`process`](Self::process)ed frame is the first of a new
    /// bootstrap, in a map of its own in `graph` ([`SlamGraph::start_map`]: a frame and a scale
    /// of its own; the keyframes and points of the maps before stay). The tracks' associations
    /// and the running filters are dropped. A map that has no keyframe yet (a bootstrap given
    /// up) is not ended, only started again. Returns the map the next keyframes join.
    pub fn start_map(&mut self, graph: &mut SlamGraph<2>) -> usize {
        self.active.clear();
        self.filters.retain(|_, _| false);
        self.filter_of_track.clear();
        self.history.clear();
        self.state = State::Empty;
        if self.map_keyframes().next().is_some() {
            self.map_start = self.map.keyframes.len();
            graph.start_map()
        } else {
            graph.current_map()
        }
    }

    /// Corrects the map by `correct` — a loop correction that moves and rescales keyframes
    /// (thesis ch. 5, [`crate::loop_closure::correction::correct_graph`]; anchored points
    /// follow their keyframes) — and carries the exploration with it: the last frame's pose
    /// and the motion model follow the last keyframe (its translation rescaled by the
    /// keyframe's change of scale), and the running feature filters are dropped (their
    /// depths are in the metric before the correction; new ones start at the next keyframe).
    /// Nothing changes if `correct` fails.
    pub fn correct_map<E>(
        &mut self,
        graph: &mut SlamGraph<2>,
        correct: impl FnOnce(&mut SlamGraph<2>) -> Result<(), E>,
    ) -> Result<(), E> {
        let last = self.map_keyframes().last();
        let before = last.map(|k| (rigid_pose(graph, k), scale(graph, k)));
        let mut corrected = graph.clone();
        correct(&mut corrected)?;
        *graph = corrected;
        if let (Some(k), Some((pose_before, scale_before))) = (last, before)
            && let pose_after = rigid_pose(graph, k)
            && let factor = scale_before / scale(graph, k)
            && let State::Tracking {
                last_pose,
                velocity,
                ..
            } = &mut self.state
        {
            // A camera-frame length keeps its keyframe-metric value; in world units it
            // changes by s_before/s_after (rigid poses are (R, t/s)).
            let rescale = |t: &Se3| Se3::new(*t.rotation(), t.translation() * factor);
            let relative = rescale(&last_pose.compose(&pose_before.inverse()));
            *last_pose = relative.compose(&pose_after);
            *velocity = rescale(velocity);
        }
        self.filters.retain(|_, _| false);
        self.filter_of_track.clear();
        // The history's poses are in the metric before the correction too.
        self.history.clear();
        Ok(())
    }

    /// The configuration.
    pub fn config(&self) -> &ExplorationConfig {
        &self.config
    }

    /// Number of running feature filters.
    pub fn num_filters(&self) -> usize {
        self.filters.len()
    }

    /// Consumes the explorer, returning its map.
    pub fn into_map(self) -> ExploredMap {
        self.map
    }

    /// Processes one frame's measurements `(track, z)` (pixels) in `graph` — a graph the
    /// caller owns, or a shared one whose lock is held for each step and not while a keyframe's
    /// window is solved ([`GraphAccess`]).
    pub fn process(
        &mut self,
        mut graph: impl GraphAccess<2>,
        frame: usize,
        measurements: &[(TrackId, Vector2<f64>)],
    ) -> Result<FrameOutcome, ExplorationError> {
        let measurements: Vec<(TrackId, Vector2<f64>)> = measurements
            .iter()
            .filter(|(_, z)| z.iter().all(|v| v.is_finite()))
            .copied()
            .collect();
        // On probation for this frame only, whatever becomes of it.
        let suspects = std::mem::take(&mut self.suspects);
        match std::mem::replace(&mut self.state, State::Empty) {
            State::Empty => {
                self.state = State::Bootstrapping {
                    first: frame,
                    measurements,
                    tried: 0,
                };
                Ok(FrameOutcome {
                    camera_from_world: None,
                    keyframe: None,
                    keyframe_reason: None,
                    tracked: 0,
                    promoted: 0,
                    started: 0,
                    filters: 0,
                    waiting: Some("the first frame".into()),
                    optimisation: None,
                    window_time: None,
                    window: None,
                })
            }
            State::Bootstrapping {
                first,
                measurements: first_measurements,
                tried,
            } => {
                if frame <= first {
                    self.state = State::Bootstrapping {
                        first,
                        measurements: first_measurements,
                        tried,
                    };
                    return Err(ExplorationError::FrameOrder { frame, last: first });
                }
                let bootstrapped = self.bootstrap(
                    &mut graph.write(),
                    first,
                    &first_measurements,
                    frame,
                    &measurements,
                );
                match bootstrapped {
                    Ok(outcome) => Ok(outcome),
                    Err(reason) => {
                        if tried + 1 >= self.config.max_bootstrap_frames {
                            return Err(ExplorationError::BootstrapFailed {
                                frames: tried + 1,
                                reason,
                            });
                        }
                        self.state = State::Bootstrapping {
                            first,
                            measurements: first_measurements,
                            tried: tried + 1,
                        };
                        Ok(FrameOutcome {
                            camera_from_world: None,
                            keyframe: None,
                            keyframe_reason: None,
                            tracked: 0,
                            promoted: 0,
                            started: 0,
                            filters: 0,
                            waiting: Some(reason),
                            optimisation: None,
                            window_time: None,
                            window: None,
                        })
                    }
                }
            }
            State::Tracking {
                last_frame,
                last_pose,
                velocity,
            } => {
                if frame <= last_frame {
                    self.state = State::Tracking {
                        last_frame,
                        last_pose,
                        velocity,
                    };
                    return Err(ExplorationError::FrameOrder {
                        frame,
                        last: last_frame,
                    });
                }
                self.track(
                    &mut graph,
                    frame,
                    (&measurements, &suspects),
                    last_frame,
                    last_pose,
                    velocity,
                )
            }
        }
    }

    /// A frame tracked: steps 1–4 and a keyframe's registration under one write lock, then its
    /// window's optimisation with the lock taken per step — the keyframe BA (read under a read
    /// lock, solved with none) or the double window (its own read and write), written back
    /// under a write lock ([`WindowJob::solve`], [`MonoExplorer::apply_window`]) — unless the
    /// caller solves it (`defer_windows`: the outcome's `window`).
    fn track(
        &mut self,
        graph: &mut impl GraphAccess<2>,
        frame: usize,
        measurements: (&[(TrackId, Vector2<f64>)], &HashSet<TrackId>),
        last_frame: usize,
        last_pose: Se3,
        velocity: Se3,
    ) -> Result<FrameOutcome, ExplorationError> {
        let mut tracked = self.track_frame(
            &mut graph.write(),
            frame,
            measurements,
            last_frame,
            last_pose,
            velocity,
        )?;
        if self.defer_windows {
            return Ok(tracked);
        }
        let Some(job) = tracked.window.take() else {
            return Ok(tracked);
        };
        let started = std::time::Instant::now();
        let solved = job.solve(&mut *graph)?;
        tracked.optimisation = solved.double_window_stats();
        // Stale only if another thread moved the window's keyframes meanwhile.
        let pose = self.apply_window(&mut graph.write(), solved)?;
        tracked.window_time = Some(started.elapsed());
        if pose.is_some() {
            tracked.camera_from_world = pose;
        }
        Ok(tracked)
    }

    /// `measurements`: the frame's measurements and the tracks among them on probation
    /// ([`MonoExplorer::suspect`]).
    fn track_frame(
        &mut self,
        graph: &mut SlamGraph<2>,
        frame: usize,
        (measurements, suspects): (&[(TrackId, Vector2<f64>)], &HashSet<TrackId>),
        last_frame: usize,
        last_pose: Se3,
        velocity: Se3,
    ) -> Result<FrameOutcome, ExplorationError> {
        // 1. Predict with constant velocity, refine by motion-only BA.
        let steps = (frame - last_frame) as f64;
        let mut predicted = last_pose;
        if steps > 0.0 {
            predicted = Se3::exp(&(velocity.log() * steps)).compose(&last_pose);
        }
        let mut tracked: Vec<(PointId, Vector2<f64>)> = measurements
            .iter()
            .filter_map(|(t, z)| self.active.get(t).map(|&p| (p, *z)))
            .collect();
        if tracked.len() < self.config.min_tracked {
            return Err(ExplorationError::TrackingLost {
                frame,
                tracked: tracked.len(),
            });
        }
        // 1b. The measurements on probation that the pose does not explain leave their points.
        // The judge is the pose of the trusted measurements when there are enough of them: a
        // pose solved with the suspects in it is pulled by the wrong ones, which then pass
        // its gate (after a relocalisation, when many templates do not align, they are a
        // large share). The explained suspects then count in the pose like the others.
        let trusted: Option<Vec<(PointId, Vector2<f64>)>> = (!suspects.is_empty())
            .then(|| {
                measurements
                    .iter()
                    .filter(|(t, _)| !suspects.contains(t))
                    .filter_map(|(t, z)| self.active.get(t).map(|&p| (p, *z)))
                    .collect::<Vec<_>>()
            })
            .filter(|t| t.len() < tracked.len() && t.len() >= self.config.min_tracked);
        let judge = self.motion_only(graph, predicted, trusted.as_deref().unwrap_or(&tracked))?;
        let dropped = self.drop_unexplained(graph, &judge, (measurements, suspects), tracked.len());
        tracked.retain(|(p, _)| !dropped.contains(p));
        let pose = if trusted.is_some() || !dropped.is_empty() {
            self.motion_only(graph, judge, &tracked)?
        } else {
            judge
        };
        let new_velocity = Se3::exp(&(pose.compose(&last_pose.inverse()).log() / steps));
        // 2. Keyframe decision by the baseline relative to the scene depth.
        let world: Vec<Vector3<f64>> = tracked
            .iter()
            .filter_map(|(p, _)| graph.point_world(*p).ok())
            .collect();
        let mut depths: Vec<f64> = world
            .iter()
            .map(|y| pose.act(y).z)
            .filter(|d| *d > 0.0)
            .collect();
        let median_depth = median(&mut depths).unwrap_or(1.0);
        let last_kf = KeyframeId::from_index(self.map.keyframes.len() - 1);
        let keyframe_reason = self
            .view_uncovered(graph, &pose, last_kf, &tracked, &world, median_depth)
            .or_else(|| {
                (tracked.len() < self.config.min_tracked_for_keyframe)
                    .then_some(ExplorationKeyframe::FewTracked(tracked.len()))
            });
        let keyframe = keyframe_reason.is_some().then(|| {
            let k = self.map.add_keyframe(graph, frame, pose, measurements);
            self.keyframe_of_frame.insert(frame, k);
            if self.localise {
                self.temporary.push(k);
            }
            for (p, z) in &tracked {
                add_observation(graph, k, *p, *z);
            }
            k
        });
        // 3. Update the filters with this frame; promote converged features.
        let filter_measurements: Vec<(FeatureId, Vector2<f64>)> = measurements
            .iter()
            .filter_map(|(t, z)| self.filter_of_track.get(t).map(|id| (*id, *z)))
            .collect();
        self.filters.update(frame, &pose, &filter_measurements);
        let promoted = self.promote(graph);
        // 4. Drop tracks not measured in this frame.
        let seen: HashSet<TrackId> = measurements.iter().map(|(t, _)| *t).collect();
        self.active.retain(|t, _| seen.contains(t));
        let before = self.filter_of_track.len();
        self.filter_of_track.retain(|t, _| seen.contains(t));
        if self.filter_of_track.len() != before {
            let keep: HashSet<FeatureId> = self.filter_of_track.values().copied().collect();
            self.filters.retain(|id, _| keep.contains(&id));
        }
        // 5. In a keyframe: new features (its window is optimised next, `track`), and for
        // the double window its place in the covisibility graph, as the reference.
        let mut started = 0;
        let mut window = None;
        if let Some(k) = keyframe {
            started = self.start_features(graph, k, frame, measurements);
            if self.double_window.is_some() && !self.localise {
                let previous = KeyframeId::from_index(k.index().saturating_sub(1));
                crate::mapping::register_locally(graph, k, self.config.theta, Some(previous))
                    .and_then(|_| graph.set_reference(k))
                    .map_err(|e| ExplorationError::Optimisation(e.to_string()))?;
            }
            window = Some(self.window_job(graph, k));
        }
        // 6. The first measurement since the last keyframe of each track that is not a
        // feature, for the features the next keyframe starts.
        if self.config.feature_history {
            let (active, filters) = (&self.active, &self.filter_of_track);
            let plain = |t: &TrackId| !active.contains_key(t) && !filters.contains_key(t);
            if keyframe.is_some() {
                self.history.clear();
            }
            self.history.retain(|t, _| seen.contains(t) && plain(t));
            for (t, z) in measurements.iter().filter(|(t, _)| plain(t)) {
                self.history.entry(*t).or_insert((frame, pose, *z));
            }
        }
        self.frame_poses.push((frame, pose));
        self.state = State::Tracking {
            last_frame: frame,
            last_pose: pose,
            velocity: new_velocity,
        };
        Ok(FrameOutcome {
            camera_from_world: Some(pose),
            keyframe,
            keyframe_reason,
            tracked: tracked.len(),
            promoted,
            started,
            filters: self.filters.len(),
            waiting: None,
            optimisation: None,
            window_time: None,
            window,
        })
    }

    /// Why no keyframe covers the view of a camera at `pose` looking at a scene
    /// `median_depth` away (thesis §3.3.3), `None` if one does. Without `keyframe_rotation`:
    /// the camera moved more than `keyframe_distance` of the scene depth from the last
    /// keyframe. With it, a keyframe covers the view when the camera is within
    /// `keyframe_distance` of the scene depth of it *and* within `keyframe_rotation` of its
    /// viewing direction, and the keyframes tried are the last one and those measuring the
    /// `tracked` points: a camera turning on the spot gets keyframes (their filters start the
    /// points of what comes into view), one browsing a mapped place gets none where its old
    /// keyframes look. The reason given is the last keyframe's (every keyframe tried fails to
    /// cover the view, the last one among them).
    fn view_uncovered(
        &self,
        graph: &SlamGraph<2>,
        pose: &Se3,
        last: KeyframeId,
        tracked: &[(PointId, Vector2<f64>)],
        world: &[Vector3<f64>],
        median_depth: f64,
    ) -> Option<ExplorationKeyframe> {
        let depth = median_depth.max(1e-9);
        let here = centre(pose);
        // The baseline to keyframe `k` in units of `keyframe_distance`.
        let mut angles = Vec::with_capacity(world.len());
        let mut distance = |k: KeyframeId| {
            let there = centre(&rigid_pose(graph, k));
            let baseline = match self.config.keyframe_baseline {
                KeyframeBaseline::Distance => (here - there).norm() / depth,
                KeyframeBaseline::Parallax => {
                    angles.clear();
                    angles.extend(world.iter().map(|y| (y - here).angle(&(y - there))));
                    median(&mut angles).unwrap_or(0.0)
                }
            };
            baseline / self.config.keyframe_distance
        };
        let Some(rotation) = self.config.keyframe_rotation else {
            let d = distance(last);
            return (d > 1.0).then_some(ExplorationKeyframe::Baseline(d));
        };
        let mut near: HashSet<KeyframeId> = HashSet::from([last]);
        for (p, _) in tracked {
            if let Some(point) = graph.point(*p) {
                near.extend(point.observers().iter().copied());
            }
        }
        // A keyframe covers the view only if this frame measures at least
        // `keyframe_min_tracked_fraction` of the points it does: where the map thins out (its
        // points leave the view, the tracks die) new points are needed although the place is
        // known.
        let mut uncovered_by = |k: KeyframeId| {
            let turned = pose
                .rotation()
                .compose(&rigid_pose(graph, k).rotation().inverse())
                .log()
                .norm();
            if turned > rotation {
                return Some(ExplorationKeyframe::Rotation(turned));
            }
            let measured = graph.keyframe(k).map_or(0, |kf| kf.observations().len()) as f64;
            if (tracked.len() as f64) < measured * self.config.keyframe_min_tracked_fraction {
                return Some(ExplorationKeyframe::Thinning(
                    tracked.len() as f64 / measured,
                ));
            }
            // The baseline last: with parallax it is the costly test.
            let d = distance(k);
            (d > 1.0).then_some(ExplorationKeyframe::Baseline(d))
        };
        near.remove(&last);
        let reason = uncovered_by(last)?;
        near.into_iter()
            .all(|k| uncovered_by(k).is_some())
            .then_some(reason)
    }

    /// The map points of the `suspects`' measurements beyond the outlier gate at `pose`
    /// ([`MonoExplorer::suspect`]), their associations ended — none if that would leave fewer
    /// than `min_tracked` of the frame's `tracked` points (the pose is then no judge of its
    /// measurements).
    fn drop_unexplained(
        &mut self,
        graph: &SlamGraph<2>,
        pose: &Se3,
        (measurements, suspects): (&[(TrackId, Vector2<f64>)], &HashSet<TrackId>),
        tracked: usize,
    ) -> HashSet<PointId> {
        if suspects.is_empty() {
            return HashSet::new();
        }
        let gate = lsq::chi2_quantile(2, 0.95) * self.config.sigma * self.config.sigma;
        let unexplained: Vec<(TrackId, PointId)> = measurements
            .iter()
            .filter(|(t, _)| suspects.contains(t))
            .filter_map(|(t, z)| self.active.get(t).map(|&p| (*t, p, *z)))
            .filter(|(_, p, z)| {
                graph
                    .point_world(*p)
                    .ok()
                    .and_then(|y| CameraModel::project(&self.camera, &pose.act(&y)).ok())
                    .is_none_or(|u| (u - z).norm_squared() > gate)
            })
            .map(|(t, p, _)| (t, p))
            .collect();
        if tracked - unexplained.len() < self.config.min_tracked {
            return HashSet::new();
        }
        for (t, _) in &unexplained {
            self.active.remove(t);
        }
        unexplained.into_iter().map(|(_, p)| p).collect()
    }

    fn motion_only(
        &self,
        graph: &SlamGraph<2>,
        predicted: Se3,
        tracked: &[(PointId, Vector2<f64>)],
    ) -> Result<Se3, ExplorationError> {
        let (points, measurements): (Vec<Vector3<f64>>, Vec<Vector2<f64>>) = tracked
            .iter()
            .map(|(p, z)| {
                let y = graph
                    .point_world(*p)
                    .map_err(|e| ExplorationError::Optimisation(e.to_string()))?;
                Ok((y, *z))
            })
            .collect::<Result<Vec<_>, ExplorationError>>()?
            .into_iter()
            .unzip();
        let options = MotionOnlyOptions {
            sigma: self.config.sigma,
            kernel: Some(RobustKernel::Huber(self.config.huber)),
            iterations: self.config.tracking_iterations,
            min_matches: self.config.min_tracked,
        };
        motion_only_ba(&self.camera, &predicted, &points, &measurements, &options)
            .map(|fit| fit.camera_from_world)
            .map_err(|e| ExplorationError::Optimisation(e.to_string()))
    }

    /// Promotes converged filters to map points with their keyframe measurements.
    fn promote(&mut self, graph: &mut SlamGraph<2>) -> usize {
        let converged = self.filters.take_converged();
        let n = converged.len();
        let track_of: HashMap<FeatureId, TrackId> =
            self.filter_of_track.iter().map(|(t, f)| (*f, *t)).collect();
        for (id, f) in converged {
            let Some(&track) = track_of.get(&id) else {
                continue;
            };
            self.filter_of_track.remove(&track);
            let anchor = self.keyframe_of_frame[&f.anchor_frame];
            // The filter's anchor frame is a keyframe (filters start in keyframes), which
            // measures the feature first.
            let Some(&(_, z_anchor)) = f.observations.iter().find(|(fr, _)| *fr == f.anchor_frame)
            else {
                continue;
            };
            let Some(point) = self
                .map
                .add_point(graph, track, anchor, &f.point_world(), z_anchor)
            else {
                continue;
            };
            for (frame, z) in &f.observations {
                if let Some(&k) = self.keyframe_of_frame.get(frame)
                    && k != anchor
                {
                    add_observation(graph, k, point, *z);
                }
            }
            self.active.insert(track, point);
        }
        n
    }

    /// Starts filters in keyframe `k` where the feature density is low (thesis §3.4.3).
    fn start_features(
        &mut self,
        graph: &SlamGraph<2>,
        k: KeyframeId,
        frame: usize,
        measurements: &[(TrackId, Vector2<f64>)],
    ) -> usize {
        let (w, h) = (
            self.config.image_width as f32,
            self.config.image_height as f32,
        );
        let min_cell = (self.config.feature_spacing as f32 * 0.5).max(1.0);
        let mut existing = QuadTree::new(w, h, min_cell);
        let mut count = 0;
        let mut candidates = Vec::new();
        for (i, (t, z)) in measurements.iter().enumerate() {
            if self.active.contains_key(t) || self.filter_of_track.contains_key(t) {
                existing.insert(QuadPoint {
                    u: z.x as f32,
                    v: z.y as f32,
                    score: 0.0,
                    index: i,
                });
                count += 1;
            } else {
                candidates.push(QuadPoint {
                    u: z.x as f32,
                    v: z.y as f32,
                    score: 0.0,
                    index: i,
                });
            }
        }
        if count >= self.config.max_features || candidates.is_empty() {
            return 0;
        }
        let anchor = rigid_pose(graph, k);
        let mut inverse_depths: Vec<f64> = graph
            .keyframe(k)
            .expect("a keyframe of the map")
            .observations()
            .keys()
            .filter_map(|&p| graph.point_world(p).ok())
            .map(|y| 1.0 / anchor.act(&y).z)
            .filter(|q| q.is_finite() && *q > 0.0)
            .collect();
        let q0 = median(&mut inverse_depths).unwrap_or(1.0);
        let tree = QuadTree::from_points(w, h, min_cell, &candidates);
        let seed = self.config.seed ^ (frame as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15);
        let r = self.config.feature_spacing as f32;
        let mut started = 0;
        for c in tree.traverse(seed) {
            if count >= self.config.max_features {
                break;
            }
            if existing.count_in_box(c.u - r, c.v - r, c.u + r, c.v + r) > 0 {
                continue;
            }
            let (track, z) = measurements[c.index];
            let Ok(ray) = self.camera.unproject(&z) else {
                continue;
            };
            if let Some(id) = self
                .filters
                .add(frame, anchor, z, Vector3::new(ray.x, ray.y, q0))
            {
                if let Some((first, live, z_first)) = self.history.remove(&track)
                    && first < frame
                {
                    // A keyframe's pose as its window left it, as the anchor's.
                    let pose = self
                        .keyframe_of_frame
                        .get(&first)
                        .map_or(live, |&k| rigid_pose(graph, k));
                    self.filters.update(first, &pose, &[(id, z_first)]);
                }
                self.filter_of_track.insert(track, id);
                existing.insert(c);
                count += 1;
                started += 1;
            }
        }
        started
    }
}

/// Adds the measurement `z` of `point` in `keyframe` (both the explorer's).
fn add_observation(
    graph: &mut SlamGraph<2>,
    keyframe: KeyframeId,
    point: PointId,
    z: Vector2<f64>,
) {
    graph
        .add_observation(keyframe, point, z)
        .expect("the explorer's keyframes and points exist");
}

/// The camera centre `−Rᵀt` of a `camera_from_world` pose.
fn centre(camera_from_world: &Se3) -> Vector3<f64> {
    *camera_from_world.inverse().translation()
}

#[cfg(test)]
mod tests;
