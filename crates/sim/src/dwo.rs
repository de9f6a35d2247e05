//! The double window optimisation experiments of thesis §6.5.1 on simulated data: the spiral
//! (Figures 6.9–6.10) and the monocular double loop with scale drift (Figures 6.11–6.12).
//!
//! A simulated SLAM system runs keyframe by keyframe on a [`SlamGraph`] through the keyframe
//! pipeline of the live system ([`slam::mapping::KeyframePipeline`]: tracking, insertion with
//! local registration, appearance and metric loop closure, new points, double window
//! optimisation). Only the front-end is simulated ([`SimFrontEnd`]): the sensor measures every
//! visible world point with Gaussian noise, and data association is perfect but, as in the
//! live system, *only* among the candidate points of `N1(ref)` (thesis §6.2.5), so that drift
//! accumulates and revisited places need loop closure. The place recogniser of the image
//! front-end is not simulated: a scenario injects its appearance loop closures, with the 3D–3D
//! correspondences of the two keyframes' local maps; metric loop closure finds the points of
//! `N2 \ N1` by a guided search of 10 pixels around their predictions. Monocular runs take
//! the true poses of their first keyframes (the bootstrap of a live system is not simulated).
//! Every method — full BA, cDWO, gDWO or cDWO with a fixed outer window — is an instance of
//! the same double window optimiser ([`DoubleWindowOptimiser`]).
//!
//! Accuracy is the RMSE of relative translations (thesis eq. 6.10) over the graph's edges in
//! the inner window, in both windows, and in the whole graph, the windows being those of
//! cDWO (the weighted BFS from the reference keyframe) for every method; for monocular runs
//! the relative translations are normalised to unit length. As the edges only join covisible
//! keyframes, the RMSE over *all pairs* of keyframes is reported too (it shows the global
//! distortion of scale drift that edges alone cannot see).

use crate::sensor::{MonoSensor, Sensor, StereoSensor};
use crate::trajectory::{centre, circle, helix, spiral};
use crate::world::{box_walls, ring};
use geom::{PinholeCamera, StereoCamera};
use lie::{LieGroup, Se3, Sim3};
use nalgebra::{SVector, Vector3};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};
use slam::dwo::{ConstraintInformation, DoubleWindowOptimiser, DwoParams, DwoStats};
use slam::factors::InverseDepthCamera;
use slam::map::{KeyframeId, PointId, SlamGraph};
use slam::mapping::{
    AppearanceMatch, FrontEnd, KeyframePipeline, KeyframeReport, Mapper, MappingConfig,
    MappingError,
};
use slam::tracking::{self, TrackId};
use std::collections::{BTreeMap, BTreeSet};
use std::time::Duration;

/// The simulated scenarios of thesis §6.5.1.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Scenario {
    /// Loopy motion combined with exploration (Figure 6.9): a helix through a tunnel, every
    /// place seen on two successive loops ([`spiral_world`]).
    Spiral,
    /// Loopy browsing without exploration: a planar coil in a small room whose walls are all
    /// in view from the first loop on ([`room_world`]).
    Room,
    /// Two loops around a large ring of points (Figure 6.11), closed by appearance at the
    /// start of the second loop.
    DoubleLoop,
}

impl Scenario {
    /// Every scenario.
    pub const ALL: [Scenario; 3] = [Scenario::Spiral, Scenario::Room, Scenario::DoubleLoop];

    /// A command-line friendly name.
    pub fn name(self) -> &'static str {
        match self {
            Scenario::Spiral => "spiral",
            Scenario::Room => "room",
            Scenario::DoubleLoop => "double-loop",
        }
    }

    /// One line on what it is.
    pub fn description(self) -> &'static str {
        match self {
            Scenario::Spiral => {
                "500 keyframes on a helix through a tunnel, every place seen on two successive loops: loopy motion with exploration (Figures 6.9–6.10)"
            }
            Scenario::Room => {
                "500 keyframes on a planar coil in a small room, all of it in view from the first loop: loopy browsing without exploration"
            }
            Scenario::DoubleLoop => {
                "two loops of 150 keyframes on a 40 m circle, monocular scale drift (Figures 6.11–6.12)"
            }
        }
    }
}

pub use crate::sensor::SensorKind;

/// The optimisation methods compared in thesis §6.5.1.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Method {
    /// Bundle adjustment over all keyframes and points.
    FullBa,
    /// Constant-time double window optimisation.
    Cdwo,
    /// Double window optimisation whose outer window covers every other keyframe.
    Gdwo,
    /// cDWO with the outer window's poses held fixed.
    CdwoFixedOuter,
}

impl Method {
    /// All methods, in plotting order.
    pub const ALL: [Method; 4] = [
        Method::FullBa,
        Method::Cdwo,
        Method::Gdwo,
        Method::CdwoFixedOuter,
    ];

    /// A short name.
    pub fn name(self) -> &'static str {
        match self {
            Method::FullBa => "BA",
            Method::Cdwo => "cDWO",
            Method::Gdwo => "gDWO",
            Method::CdwoFixedOuter => "cDWO fixed outer",
        }
    }

    /// A file-name and command-line friendly name.
    pub fn slug(self) -> &'static str {
        match self {
            Method::FullBa => "ba",
            Method::Cdwo => "cdwo",
            Method::Gdwo => "gdwo",
            Method::CdwoFixedOuter => "cdwo-fixed",
        }
    }
}

/// A simulated world: true keyframe poses, points and the injected appearance loop closures.
#[derive(Clone, Debug)]
pub struct World {
    /// True `camera_from_world` of each keyframe.
    pub camera_from_world: Vec<Se3>,
    /// World points.
    pub points: Vec<Vector3<f64>>,
    /// `(query keyframe, matched old keyframe)`: the place recogniser's detections.
    pub appearance_closures: Vec<(usize, usize)>,
}

/// The spiral of thesis §6.5.1 (Figure 6.9), loopy local motion combined with exploration:
/// `keyframes` poses on a helix of radius 0.5 m, 50 per loop, rising 1.5 m per loop (500
/// keyframes make 10 loops and 15 m), looking outwards at the wall of a tunnel of radius
/// 2.5 m around the helix's axis (15 points per m², reaching 2.5 m beyond both ends).
///
/// The rise is half the height of wall the camera sees straight ahead at 2 m (±38.7°
/// vertically for f = 300 and 480 rows: 3.2 m), so every place is seen on two successive
/// loops (each loop revisits the previous one's places; the image corners, where the wall
/// is farther, on a third) and is then left behind for good (exploration). A camera on the helix never looks along the tunnel, so it cannot
/// see far ahead; compare [`room_world`], where everything is in view from the first loop.
pub fn spiral_world(seed: u64, keyframes: usize) -> World {
    const PER_LOOP: usize = 50;
    const RISE: f64 = 1.5;
    const TUNNEL_RADIUS: f64 = 2.5;
    const MARGIN: f64 = 2.5;
    const DENSITY: f64 = 15.0;
    let loops = keyframes.div_ceil(PER_LOOP);
    let mut camera_from_world = helix(0.5, PER_LOOP, loops, RISE);
    camera_from_world.truncate(keyframes);
    let top = RISE * keyframes as f64 / PER_LOOP as f64;
    let (z_min, z_max) = (-MARGIN, top + MARGIN);
    let area = std::f64::consts::TAU * TUNNEL_RADIUS * (z_max - z_min);
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    World {
        camera_from_world,
        points: ring(
            &mut rng,
            TUNNEL_RADIUS,
            z_min,
            z_max,
            (area * DENSITY) as usize,
        ),
        appearance_closures: Vec::new(),
    }
}

/// Loopy browsing in a room: `keyframes` poses on a planar coil, 50 per loop (radius 0.5 m,
/// advancing 0.5 m per loop; 500 keyframes = 10 loops), looking outwards at the walls of a
/// room 4 m wide and 3 m high reaching 2.5 m beyond both ends of the coil (15 points per
/// m²). Looking along the room the camera sees its far end, so the whole room is in view
/// from the first loop on: the map stops growing and every keyframe is covisible with the
/// keyframes of every earlier loop at the same place (docs/experiments/dwo.md).
pub fn room_world(seed: u64, keyframes: usize) -> World {
    let loops = keyframes as f64 / 50.0;
    let advance = 0.5;
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let camera_from_world = spiral(keyframes, 0.5, loops, advance);
    let points = box_walls(
        &mut rng,
        Vector3::new(-2.5, -2.0, -1.5),
        Vector3::new(2.5 + advance * loops, 2.0, 1.5),
        15.0,
    );
    World {
        camera_from_world,
        points,
        appearance_closures: Vec::new(),
    }
}

/// The double loop of thesis §6.5.1 (Figure 6.11): two loops of `per_loop` keyframes on a
/// large circle of radius 40 m, the camera looking outwards at the wall of a ring-shaped
/// building 3 m away (radius 43 m, 4 m high, 5 points per m²). Between keyframes the camera
/// moves 1.7 m for `per_loop = 150`, so a point stays in view for only a few keyframes: the
/// monocular map drifts in scale along the loop (thesis §5.1). The place recogniser (not
/// simulated) matches the first keyframe of the second loop with the first keyframe.
pub fn double_loop_world(seed: u64, per_loop: usize) -> World {
    const CIRCLE_RADIUS: f64 = 40.0;
    const WALL_DISTANCE: f64 = 3.0;
    const HALF_HEIGHT: f64 = 2.0;
    const DENSITY: f64 = 5.0;
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let radius = CIRCLE_RADIUS + WALL_DISTANCE;
    let n = (std::f64::consts::TAU * radius * 2.0 * HALF_HEIGHT * DENSITY) as usize;
    World {
        camera_from_world: circle(CIRCLE_RADIUS, per_loop, 2, true),
        points: ring(&mut rng, radius, -HALF_HEIGHT, HALF_HEIGHT, n),
        appearance_closures: vec![(per_loop, 0)],
    }
}

/// A simulated camera: the sensor and its measurement model.
pub trait SimCamera<const N: usize>: Sensor<N> {
    /// The measurement model.
    type Camera: InverseDepthCamera<N>;
    /// The measurement model.
    fn camera(&self) -> Self::Camera;
    /// Focal length (pixels).
    fn focal(&self) -> f64;
    /// Stereo baseline (m; 0 for monocular).
    fn baseline(&self) -> f64;
}

impl SimCamera<3> for StereoSensor {
    type Camera = StereoCamera;
    fn camera(&self) -> StereoCamera {
        self.camera
    }
    fn focal(&self) -> f64 {
        self.camera.pinhole.fx
    }
    fn baseline(&self) -> f64 {
        self.camera.baseline
    }
}

impl SimCamera<2> for MonoSensor {
    type Camera = PinholeCamera;
    fn camera(&self) -> PinholeCamera {
        self.camera
    }
    fn focal(&self) -> f64 {
        self.camera.fx
    }
    fn baseline(&self) -> f64 {
        0.0
    }
}

/// Parameters of a run.
#[derive(Clone, Debug, PartialEq)]
pub struct RunConfig {
    /// `M1` of cDWO (also the evaluation's inner window).
    pub inner: usize,
    /// `M2` of cDWO (also the evaluation's outer window).
    pub outer: usize,
    /// Joint iterations per keyframe (thesis: 3).
    pub iterations: usize,
    /// `Θ`, covisible points for an edge (thesis: 15–30).
    pub theta: usize,
    /// Size of `N2` for metric loop closure.
    pub n2: usize,
    /// Guided-search radius (pixels) of metric loop closure (thesis: e.g. 10).
    pub guided_radius: f64,
    /// Evaluate the all-pairs RMSE every this many keyframes (it is quadratic).
    pub all_pairs_every: usize,
    /// Noise seed.
    pub seed: u64,
    /// How the pose-pose constraints' information is computed (default: marginal; the
    /// thesis's coarse eq. 6.2 is the option).
    pub information: ConstraintInformation,
}

impl RunConfig {
    /// Windows of the spiral and the room (inner 15, outer 50) or the double loop (30, 100).
    pub fn for_scenario(scenario: Scenario, seed: u64) -> Self {
        let (inner, outer) = match scenario {
            Scenario::Spiral | Scenario::Room => (15, 50),
            Scenario::DoubleLoop => (30, 100),
        };
        RunConfig {
            inner,
            outer,
            iterations: 3,
            theta: 20,
            n2: 100,
            guided_radius: 10.0,
            all_pairs_every: 5,
            seed,
            information: ConstraintInformation::default(),
        }
    }

    /// The optimiser parameters of `method`.
    /// `baseline`: the stereo baseline (0 for monocular).
    pub fn dwo_params(&self, method: Method, focal: f64, baseline: f64, sigma: f64) -> DwoParams {
        let (inner, outer, fix) = match method {
            Method::FullBa => (usize::MAX, 0, false),
            Method::Cdwo => (self.inner, self.outer, false),
            Method::Gdwo => (self.inner, usize::MAX, false),
            Method::CdwoFixedOuter => (self.inner, self.outer, true),
        };
        let mut p = DwoParams::new(inner, outer, focal, sigma).with_baseline(baseline);
        p.iterations = self.iterations;
        p.fix_outer = fix;
        p.information = self.information;
        p
    }

    /// The keyframe pipeline's parameters for `N`-dimensional measurements with noise `sigma`
    /// on 640×480 images (the simulated cameras'), with this run's `Θ` and `N2`.
    pub fn mapping(&self, sigma: f64, measurement_dimension: usize) -> MappingConfig {
        MappingConfig {
            theta: self.theta,
            n2: self.n2,
            ..MappingConfig::new(sigma, (640.0, 480.0), measurement_dimension)
        }
    }
}

/// What happened at one keyframe.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct KeyframeRecord {
    /// Keyframe index.
    pub index: usize,
    /// Optimisation time (set-up, structure-only and joint iterations, write-back), seconds.
    pub time_optimise: f64,
    /// Of which problem set-up (planning and building the least-squares problem), seconds.
    pub time_setup: f64,
    /// Simulated front end (tracking, registration, loop closure, new points), seconds.
    pub time_frontend: f64,
    /// Eq. 6.10 over the edges inside the inner window.
    pub rmse_inner: f64,
    /// Eq. 6.10 over the edges inside both windows.
    pub rmse_both: f64,
    /// Eq. 6.10 over all edges.
    pub rmse_global: f64,
    /// Eq. 6.10 over all pairs of keyframes (every `all_pairs_every` keyframes, else NaN).
    pub rmse_all_pairs: f64,
    /// Optimisation statistics (window sizes, constraints).
    pub stats: DwoStatsRecord,
    /// Metric loop-closure edges added at this keyframe.
    pub metric_loop_edges: usize,
    /// Whether an appearance loop closure was inserted at this keyframe.
    pub appearance_closure: bool,
    /// Estimated over true distance between the camera centres of this keyframe and the one
    /// five keyframes earlier (the local scale; 1 for a perfect estimate).
    pub local_scale: f64,
    /// Keyframes, points and edges in the graph.
    pub graph_size: (usize, usize, usize),
}

/// The counts of [`DwoStats`] (durations are in [`KeyframeRecord`]).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct DwoStatsRecord {
    /// Keyframes in `W1`.
    pub inner_frames: usize,
    /// Keyframes in `W2`.
    pub outer_frames: usize,
    /// Points optimised.
    pub points: usize,
    /// Point-pose constraints.
    pub point_constraints: usize,
    /// Pose-pose constraints.
    pub pose_constraints: usize,
}

impl From<&DwoStats> for DwoStatsRecord {
    fn from(s: &DwoStats) -> Self {
        DwoStatsRecord {
            inner_frames: s.inner_frames,
            outer_frames: s.outer_frames,
            points: s.points,
            point_constraints: s.point_constraints,
            pose_constraints: s.pose_constraints,
        }
    }
}

/// The result of one run.
#[derive(Clone, Debug)]
pub struct RunResult {
    /// The method.
    pub method: Method,
    /// One record per keyframe.
    pub records: Vec<KeyframeRecord>,
    /// Final estimated keyframe poses.
    pub camera_from_world: Vec<Sim3>,
}

/// Why a run failed.
#[derive(Debug, thiserror::Error)]
pub enum RunError {
    /// A stage of the keyframe pipeline failed.
    #[error("keyframe {keyframe}: {source}")]
    Pipeline {
        /// Keyframe index.
        keyframe: usize,
        /// The cause.
        source: MappingError,
    },
    /// The world has fewer than two keyframes.
    #[error("a run needs at least two keyframes")]
    TooShort,
}

/// Per keyframe, the noisy measurements `(world point index, z)`.
pub type Measurements<const N: usize> = Vec<Vec<(usize, SVector<f64, N>)>>;

/// Noisy measurements of each keyframe: `(world point, z)`, the same for every method.
pub fn measure<S: Sensor<N>, const N: usize>(
    sensor: &S,
    world: &World,
    seed: u64,
) -> Measurements<N> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let noise = Normal::new(0.0, sensor.sigma().max(0.0)).expect("σ ≥ 0");
    world
        .camera_from_world
        .iter()
        .map(|t| {
            world
                .points
                .iter()
                .enumerate()
                .filter_map(|(w, p)| sensor.predict(t, p).map(|z| (w, z)))
                .map(|(w, z)| {
                    (
                        w,
                        z + SVector::<f64, N>::from_fn(|_, _| noise.sample(&mut rng)),
                    )
                })
                .collect()
        })
        .collect()
}

/// RMSE of relative translations (thesis eq. 6.10) over `pairs`, optionally normalised to unit
/// length (monocular).
pub fn relative_translation_rmse(
    estimate: &[Sim3],
    truth: &[Se3],
    pairs: impl Iterator<Item = (usize, usize)>,
    normalise: bool,
) -> f64 {
    let (mut sum, mut n) = (0.0, 0usize);
    for (i, j) in pairs {
        let mut est = *estimate[i].compose(&estimate[j].inverse()).translation();
        let mut tru = *truth[i].compose(&truth[j].inverse()).translation();
        if normalise {
            if est.norm() < 1e-12 || tru.norm() < 1e-12 {
                continue;
            }
            est.normalize_mut();
            tru.normalize_mut();
        }
        sum += (est - tru).norm_squared();
        n += 1;
    }
    if n == 0 {
        f64::NAN
    } else {
        (sum / n as f64).sqrt()
    }
}

fn edges_within<const N: usize>(
    graph: &SlamGraph<N>,
    set: &BTreeSet<KeyframeId>,
) -> Vec<(usize, usize)> {
    let mut out = Vec::new();
    for &a in set {
        if let Some(k) = graph.keyframe(a) {
            out.extend(
                k.edges()
                    .keys()
                    .filter(|&&b| a < b && set.contains(&b))
                    .map(|&b| (a.index(), b.index())),
            );
        }
    }
    out
}

/// The simulated front-end (see the module docs): data association by world point, the
/// injected appearance loop closures, the guided search of metric loop closure, and the true
/// poses of a monocular run's first keyframes.
pub struct SimFrontEnd<'a, const N: usize> {
    measurements: &'a [Vec<(usize, SVector<f64, N>)>],
    truth: &'a [Se3],
    closures: BTreeMap<usize, usize>,
    guided_radius: f64,
    monocular: bool,
    /// The world point of each graph point (dense: points are never removed here).
    world_of: Vec<usize>,
    /// The keyframe being processed.
    k: usize,
}

impl<'a, const N: usize> SimFrontEnd<'a, N> {
    /// A front-end measuring `measurements[k]` at keyframe `k` of `world`.
    pub fn new(
        world: &'a World,
        measurements: &'a [Vec<(usize, SVector<f64, N>)>],
        guided_radius: f64,
        monocular: bool,
    ) -> Self {
        SimFrontEnd {
            measurements,
            truth: &world.camera_from_world,
            closures: world.appearance_closures.iter().copied().collect(),
            guided_radius,
            monocular,
            world_of: Vec::new(),
            k: 0,
        }
    }

    /// Starts keyframe `k`.
    pub fn begin(&mut self, k: usize) {
        self.k = k;
    }

    fn world_point(&self, p: PointId) -> usize {
        self.world_of[p.index()]
    }

    /// The visible local map of `keyframe` (points seen from its `N1`) by world point, the
    /// lowest point id first when a world point has several.
    fn local_map(&self, graph: &SlamGraph<N>, keyframe: KeyframeId) -> BTreeMap<usize, PointId> {
        let mut m = BTreeMap::new();
        for p in tracking::tracking_candidates(graph, keyframe) {
            m.entry(self.world_point(p)).or_insert(p);
        }
        m
    }

    /// The world points `keyframe` observes.
    fn observed(&self, graph: &SlamGraph<N>, keyframe: KeyframeId) -> BTreeSet<usize> {
        graph.keyframe(keyframe).map_or_else(BTreeSet::new, |kf| {
            kf.observations()
                .keys()
                .map(|&p| self.world_point(p))
                .collect()
        })
    }
}

impl<const N: usize> FrontEnd<N> for SimFrontEnd<'_, N> {
    fn match_candidates(
        &mut self,
        _: &SlamGraph<N>,
        candidates: &BTreeSet<PointId>,
    ) -> Vec<(PointId, SVector<f64, N>)> {
        let mut by_world: BTreeMap<usize, PointId> = BTreeMap::new();
        for &p in candidates {
            by_world.entry(self.world_point(p)).or_insert(p);
        }
        self.measurements[self.k]
            .iter()
            .filter_map(|(w, z)| by_world.get(w).map(|&p| (p, *z)))
            .collect()
    }

    fn given_pose(
        &mut self,
        graph: &SlamGraph<N>,
        matches: &[(PointId, SVector<f64, N>)],
    ) -> Option<Sim3> {
        let bootstrap = self.k == 0
            || (self.monocular && (self.k == 1 || (matches.len() < 6 && graph.num_points() < 30)));
        bootstrap.then(|| Sim3::from_se3(&self.truth[self.k]))
    }

    fn recognise_place(
        &mut self,
        graph: &SlamGraph<N>,
        keyframe: KeyframeId,
    ) -> Option<AppearanceMatch<N>> {
        let old = KeyframeId::from_index(*self.closures.get(&self.k)?);
        // The local maps of both places as the place recogniser's correspondences (§6.4.2).
        let (own, old_points) = (self.local_map(graph, keyframe), self.local_map(graph, old));
        let correspondences = self.measurements[self.k]
            .iter()
            .filter_map(|(w, z)| {
                let p_old = *old_points.get(w)?;
                match own.get(w) {
                    Some(&p_new) if p_new == p_old => None,
                    here => Some((p_old, *z, here.copied())),
                }
            })
            .collect();
        Some(AppearanceMatch {
            old,
            correspondences,
        })
    }

    /// The world points the keyframe observes, and the predictions.
    type GuidedSearch = (BTreeSet<usize>, Vec<(PointId, SVector<f64, N>)>);

    fn plan_guided_search(
        &mut self,
        graph: &SlamGraph<N>,
        keyframe: KeyframeId,
        predictions: &[(PointId, SVector<f64, N>)],
    ) -> Self::GuidedSearch {
        (self.observed(graph, keyframe), predictions.to_vec())
    }

    fn guided_search(
        &mut self,
        (observed, predictions): Self::GuidedSearch,
    ) -> Vec<(PointId, SVector<f64, N>)> {
        let wanted: BTreeMap<usize, SVector<f64, N>> = self.measurements[self.k]
            .iter()
            .filter(|(w, _)| !observed.contains(w))
            .map(|(w, z)| (*w, *z))
            .collect();
        let mut found: BTreeMap<usize, (PointId, SVector<f64, N>)> = BTreeMap::new();
        for (p, z_hat) in &predictions {
            let w = self.world_point(*p);
            if let Some(z) = wanted.get(&w)
                && !found.contains_key(&w)
                && (z_hat.fixed_rows::<2>(0) - z.fixed_rows::<2>(0)).norm() <= self.guided_radius
            {
                found.insert(w, (*p, *z));
            }
        }
        found.into_values().collect()
    }

    fn measurements(
        &mut self,
        graph: &SlamGraph<N>,
        keyframe: KeyframeId,
    ) -> Vec<(TrackId, SVector<f64, N>, bool)> {
        let observed = self.observed(graph, keyframe);
        self.measurements[self.k]
            .iter()
            .map(|(w, z)| (*w as TrackId, *z, observed.contains(w)))
            .collect()
    }

    fn points_created(&mut self, created: &[(TrackId, PointId)]) {
        for &(track, p) in created {
            debug_assert_eq!(p.index(), self.world_of.len(), "points are created densely");
            self.world_of.push(track as usize);
        }
    }
}

/// Runs the simulated SLAM system with one method over `world`; `progress` is called after
/// each keyframe.
pub fn run<C: SimCamera<N>, const N: usize>(
    camera: &C,
    world: &World,
    measurements: &[Vec<(usize, SVector<f64, N>)>],
    method: Method,
    config: &RunConfig,
    mut progress: impl FnMut(usize),
) -> Result<RunResult, RunError> {
    let n = world.camera_from_world.len().min(measurements.len());
    if n < 2 {
        return Err(RunError::TooShort);
    }
    let sigma = camera.sigma();
    let monocular = !C::Camera::MEASURES_DEPTH;
    let optimiser = DoubleWindowOptimiser::new(config.dwo_params(
        method,
        camera.focal(),
        camera.baseline(),
        sigma,
    ));
    let mapper = Mapper::new(camera.camera(), config.mapping(sigma, N));
    let mut pipeline = KeyframePipeline::new(mapper, optimiser);
    let mut front_end = SimFrontEnd::new(world, measurements, config.guided_radius, monocular);
    let mut graph = SlamGraph::<N>::new();
    let mut records = Vec::with_capacity(n);
    for k in 0..n {
        front_end.begin(k);
        let report = pipeline
            .process_keyframe(&mut graph, &mut front_end)
            .map_err(|source| RunError::Pipeline {
                keyframe: k,
                source,
            })?;
        records.push(evaluate(&graph, world, &report, config, k, n));
        progress(k);
    }
    let camera_from_world = graph
        .keyframes()
        .map(|(_, kf)| *kf.camera_from_world())
        .collect();
    Ok(RunResult {
        method,
        records,
        camera_from_world,
    })
}

/// The record of keyframe `k` (of `n`) after the pipeline processed it: the accuracy of the
/// windows of cDWO around it and, every `all_pairs_every` keyframes and around injected loop
/// closures, of all pairs of keyframes.
fn evaluate<const N: usize>(
    graph: &SlamGraph<N>,
    world: &World,
    report: &KeyframeReport,
    config: &RunConfig,
    k: usize,
    n: usize,
) -> KeyframeRecord {
    let truth = &world.camera_from_world;
    // The run never removes keyframes: keyframe i is the i-th.
    let estimate: Vec<Sim3> = graph
        .keyframes()
        .map(|(_, kf)| *kf.camera_from_world())
        .collect();
    let normalise = N == 2;
    let tree = graph.weighted_bfs(report.keyframe, config.inner + config.outer);
    let inner: BTreeSet<KeyframeId> = tree.order.iter().take(config.inner).copied().collect();
    let both: BTreeSet<KeyframeId> = tree.order.iter().copied().collect();
    let all: BTreeSet<KeyframeId> = graph.keyframes().map(|(id, _)| id).collect();
    let rmse = |set: &BTreeSet<KeyframeId>| {
        relative_translation_rmse(
            &estimate,
            truth,
            edges_within(graph, set).into_iter(),
            normalise,
        )
    };
    let closure_near = |i: usize| world.appearance_closures.iter().any(|&(q, _)| q == i);
    let rmse_all_pairs = if k.is_multiple_of(config.all_pairs_every.max(1))
        || closure_near(k)
        || closure_near(k + 1)
        || k + 1 == n
    {
        relative_translation_rmse(
            &estimate,
            truth,
            (0..=k).flat_map(|i| (i + 1..=k).map(move |j| (i, j))),
            normalise,
        )
    } else {
        f64::NAN
    };
    let local_scale = if k >= 5 {
        let est = (estimate[k].inverse().act(&Vector3::zeros())
            - estimate[k - 5].inverse().act(&Vector3::zeros()))
        .norm();
        let tru = (centre(&truth[k]) - centre(&truth[k - 5])).norm();
        est / tru
    } else {
        1.0
    };
    let stats = report.optimisation.clone().unwrap_or_default();
    KeyframeRecord {
        index: k,
        time_optimise: stats.total().as_secs_f64(),
        time_setup: stats.time_setup.as_secs_f64(),
        time_frontend: report.time_frontend.as_secs_f64(),
        rmse_inner: rmse(&inner),
        rmse_both: rmse(&both),
        rmse_global: rmse(&all),
        rmse_all_pairs,
        stats: DwoStatsRecord::from(&stats),
        metric_loop_edges: report.metric_loops.len(),
        appearance_closure: report.appearance_loop.is_some(),
        local_scale,
        graph_size: (graph.num_keyframes(), graph.num_points(), graph.num_edges()),
    }
}

/// The median of `values` (NaN if empty).
pub fn median(values: &[f64]) -> f64 {
    let mut v: Vec<f64> = values.iter().copied().filter(|x| x.is_finite()).collect();
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort_by(f64::total_cmp);
    let m = v.len() / 2;
    if v.len() % 2 == 1 {
        v[m]
    } else {
        0.5 * (v[m - 1] + v[m])
    }
}

/// The mean of the finite `values` (NaN if none).
pub fn mean(values: &[f64]) -> f64 {
    let v: Vec<f64> = values.iter().copied().filter(|x| x.is_finite()).collect();
    if v.is_empty() {
        f64::NAN
    } else {
        v.iter().sum::<f64>() / v.len() as f64
    }
}

/// Median optimisation time per keyframe over keyframes `range` (seconds).
pub fn median_time(records: &[KeyframeRecord], range: std::ops::Range<usize>) -> f64 {
    let t: Vec<f64> = records
        .iter()
        .filter(|r| range.contains(&r.index))
        .map(|r| r.time_optimise)
        .collect();
    median(&t)
}

/// A wall-clock duration in seconds (helper for reports).
pub fn seconds(d: Duration) -> f64 {
    d.as_secs_f64()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn stereo(world: World, seed: u64) -> (StereoSensor, World, Measurements<3>) {
        let sensor = StereoSensor::vga(300.0, 0.05, 1.0);
        let meas = measure(&sensor, &world, seed);
        (sensor, world, meas)
    }

    #[test]
    fn spiral_and_room_worlds_are_well_observed() {
        for world in [spiral_world(1, 500), room_world(1, 500)] {
            let (_, world, meas) = stereo(world, 1);
            let counts: Vec<usize> = meas.iter().map(Vec::len).collect();
            let min = *counts.iter().min().unwrap();
            assert!(min >= 60, "too few points visible: {min}");
            assert!(world.points.len() > 1000);
        }
    }

    #[test]
    fn the_spiral_revisits_the_previous_loop_and_leaves_older_ones_behind() {
        let (_, _, meas) = stereo(spiral_world(1, 500), 1);
        let seen = |lp: usize| -> BTreeSet<usize> {
            meas[50 * lp..50 * (lp + 1)]
                .iter()
                .flatten()
                .map(|(w, _)| *w)
                .collect()
        };
        for lp in 0..7 {
            let (a, b, c, d) = (seen(lp), seen(lp + 1), seen(lp + 2), seen(lp + 3));
            let share = |x: &BTreeSet<usize>| a.intersection(x).count() as f64 / a.len() as f64;
            eprintln!(
                "loop {lp}: {:.2} {:.2} {:.2}",
                share(&b),
                share(&c),
                share(&d)
            );
            // Loopy: most of a loop's places are seen again on the next loop...
            assert!(share(&b) > 0.3, "loop {lp}: {}", share(&b));
            // ... exploring: a few at the image corners two loops later, none three later.
            assert!(share(&c) < 0.25, "loop {lp}: {}", share(&c));
            assert!(share(&d) < 0.01, "loop {lp}: {}", share(&d));
        }
    }

    #[test]
    fn cdwo_is_accurate_locally_bounded_and_deterministic_on_a_short_spiral() {
        // 1.6 loops of the room in stereo.
        let (sensor, world, meas) = stereo(room_world(3, 500), 3);
        let world = World {
            camera_from_world: world.camera_from_world[..80].to_vec(),
            ..world
        };
        let config = RunConfig {
            inner: 10,
            outer: 20,
            ..RunConfig::for_scenario(Scenario::Room, 3)
        };
        let ba = run(&sensor, &world, &meas, Method::FullBa, &config, |_| {}).unwrap();
        let cdwo = run(&sensor, &world, &meas, Method::Cdwo, &config, |_| {}).unwrap();
        let again = run(&sensor, &world, &meas, Method::Cdwo, &config, |_| {}).unwrap();
        let inner =
            |r: &RunResult| mean(&r.records.iter().map(|x| x.rmse_inner).collect::<Vec<_>>());
        let (e_ba, e_dwo) = (inner(&ba), inner(&cdwo));
        assert!(
            e_ba < 0.05 && e_dwo < 0.05,
            "inner RMSE BA {e_ba}, cDWO {e_dwo}"
        );
        // The thesis finds cDWO as accurate as BA in the inner window; in stereo ours is not
        // yet (1.41× BA on the 500-keyframe spiral, docs/experiments/dwo.md), so this only
        // guards against it getting much worse.
        assert!(e_dwo < 2.5 * e_ba, "inner RMSE BA {e_ba}, cDWO {e_dwo}");
        // Metric loop closure accepts no edge here (nor on the 500-keyframe spiral): see
        // `revisits_of_the_spiral_reuse_the_map_instead_of_duplicating_it`.
        // Same seed, same numbers.
        for (a, b) in cdwo.records.iter().zip(&again.records) {
            assert_eq!(a.rmse_global.to_bits(), b.rmse_global.to_bits());
            assert_eq!(a.stats, b.stats);
        }
        // Windows of cDWO stay bounded.
        let last = cdwo.records.last().unwrap();
        assert_eq!(last.stats.inner_frames, 10);
        assert!(last.stats.outer_frames >= 20);
    }

    #[test]
    fn cdwo_windows_stay_bounded_while_the_spiral_explores() {
        // Three loops of the helix with windows 10/20: the map keeps growing, cDWO's window
        // contents (what its time per keyframe is made of) do not.
        let (sensor, world, meas) = stereo(spiral_world(2, 150), 2);
        let config = RunConfig {
            inner: 10,
            outer: 20,
            ..RunConfig::for_scenario(Scenario::Spiral, 2)
        };
        let r = run(&sensor, &world, &meas, Method::Cdwo, &config, |_| {}).unwrap();
        let block = |range: std::ops::Range<usize>| {
            let rs = &r.records[range];
            let n = rs.len() as f64;
            let obs = rs
                .iter()
                .map(|x| x.stats.point_constraints as f64)
                .sum::<f64>()
                / n;
            let points = rs.last().unwrap().graph_size.1;
            (obs, points)
        };
        let (early, late) = (block(50..75), block(125..150));
        eprintln!("point-pose constraints {early:?} → {late:?}");
        assert!(
            late.1 as f64 > 1.3 * early.1 as f64,
            "the map grows: {early:?} → {late:?}"
        );
        assert!(
            late.0 < 1.3 * early.0,
            "window contents: {early:?} → {late:?}"
        );
    }

    #[test]
    fn revisits_of_the_spiral_reuse_the_map_instead_of_duplicating_it() {
        // Two turns of the spiral in stereo. The first revisit (keyframes ~39–42) fails the
        // spread-of-matches test — the old wall enters the image from one side, so all matches
        // lie in one half — but its verified matches become observations of the reference,
        // tracking continues on the old points and local registration joins the old
        // keyframes; from then on N2 \ N1 has no point in view (every old keyframe of the place
        // is in N1), so metric loop closure has nothing left to find and the map stops
        // growing: the second turn adds (almost) no points.
        let (sensor, world, meas) = stereo(room_world(1, 500), 1);
        let world = World {
            camera_from_world: world.camera_from_world[..100].to_vec(),
            ..world
        };
        let config = RunConfig {
            inner: 10,
            outer: 20,
            ..RunConfig::for_scenario(Scenario::Room, 1)
        };
        let r = run(&sensor, &world, &meas, Method::Cdwo, &config, |_| {}).unwrap();
        let points = |k: usize| r.records[k].graph_size.1;
        let seen: BTreeSet<usize> = meas[..100].iter().flatten().map(|(w, _)| *w).collect();
        eprintln!(
            "graph points at keyframes 49 / 99: {} / {}; world points seen: {}; metric loop edges: {}",
            points(49),
            points(99),
            seen.len(),
            r.records.iter().map(|x| x.metric_loop_edges).sum::<usize>()
        );
        assert!(
            points(99) <= points(49) + 20,
            "{} → {}",
            points(49),
            points(99)
        );
        // At most 20 % more graph points than world points seen (duplicates of the first
        // revisit, before its matches are verified).
        assert!(
            5 * points(99) <= 6 * seen.len(),
            "{} points for {} seen",
            points(99),
            seen.len()
        );
    }
}
