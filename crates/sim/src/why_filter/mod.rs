//! The Monte Carlo comparison of BA-SLAM and filter-SLAM, thesis §4.6: four settings of local
//! camera motion, stereo and monocular, over grids of keyframes `M` and points `N`, with the
//! error measures of eq. 4.27–4.31 and the cost of each pipeline.
//!
//! Camera: 640×480, `f = 500`, principal point at the centre, pixel noise `σ = ½` (as §4.3);
//! stereo baseline 0.1 m. Each trial samples a new scene (uniform points, the candidates of
//! the perfect-association front-end) and new noise. `T_0` is the identity; the settings
//! (thesis §4.6.1, Figure 4.4; the thesis gives no scene dimensions, ours are chosen so that
//! the stated overlaps hold):
//!
//! - (i) 0.5 m sideways; points in the slab `z ∈ [0.9, 1.1]` m visible from every frame (and
//!   from the monocular bootstrap frames), so all points are seen in all frames.
//! - (ii) 1.1 m sideways in front of a slab at 0.9–1.1 m: the first and last frames barely
//!   overlap.
//! - (iii) 0.6 m sideways while yawing 30° towards the direction of motion, slab at 0.9–1.1 m
//!   extended in the direction of motion: partial overlap.
//! - (iv) a sharp 90° forward turn on an arc of radius 0.5 m, with two perpendicular walls
//!   (an indoor corner) 1.4–1.6 m ahead of the start and of the end.
//!
//! Monocular runs are bootstrapped (§4.5.3) from `T_b0`, `T_b1`, 0.1 m and 0.05 m to the
//! camera's left of `T_0` with `T_0`'s orientation; BA-SLAM and filter-SLAM start from the same
//! bootstrap, and both use the same features (same quadtree seeds) and measurements.
//!
//! Error: the end camera's position `t` in the frame of `T_0` (for monocular runs the
//! estimated `T_0`), `Δt = t_true − t_est` (eq. 4.27); for monocular runs `t_est` is first
//! scaled to `|t_true|` (eq. 4.28) and the error projected onto the tangent plane at `t_true`
//! (eq. 4.29), a 2-vector.

use crate::sensor::{MonoSensor, Sensor, StereoSensor};
use crate::trajectory::{centre, forward_turn, pose_looking, sideways, sideways_with_rotation};
use crate::world::planar_slab;
use ba_slam::{BaSlam, BaSlamOptions, TwoViewInverseDepth};
use bootstrap::{Bootstrap, BootstrapOptions, bootstrap};
use features::{ImageArea, find, select_spread};
use filter::{Anchor, GaussNewtonFilter, InverseDepthCamera};
use filter_slam::{FilterSlam, FilterSlamOptions, MotionEstimate};
use geom::PinholeCamera;
use lie::{LieGroup, Se3};
use nalgebra::{DMatrix, DVector, SVector, Vector3};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};
use slam::clock::CpuStopwatch;
use std::time::Duration;

pub mod ba_slam;
pub mod bootstrap;
pub mod features;
pub mod filter;
pub mod filter_slam;
pub mod motion;

/// The four settings of thesis §4.6.1.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Setting {
    /// Sideways 0.5 m, all points visible in all frames.
    I,
    /// Sideways 1.1 m, first and last frames barely overlap.
    II,
    /// Sideways with 30° rotation, partial overlap.
    III,
    /// Sharp 90° forward turn.
    IV,
}

pub use crate::sensor::SensorKind;

/// Focal length (px).
pub const FOCAL: f64 = 500.0;
/// Stereo baseline (m).
pub const BASELINE: f64 = 0.1;
/// Pixel noise σ.
pub const SIGMA: f64 = 0.5;
/// The `N` grid of thesis §4.6.1.
pub const N_GRID: [usize; 5] = [15, 30, 60, 120, 240];
/// The extra `N` run at the smallest `M` (thesis Figure 4.13, bold curves).
pub const N_EXTRA: usize = 480;
/// Offset of the monocular bootstrap frames `T_b1`, `T_b0` (m, to the camera's left of `T_0`).
pub const BOOTSTRAP_STEP: f64 = 0.05;

const AREA: ImageArea = ImageArea {
    width: 640.0,
    height: 480.0,
};

impl Setting {
    /// All four.
    pub const ALL: [Setting; 4] = [Setting::I, Setting::II, Setting::III, Setting::IV];

    /// Roman numeral.
    pub fn name(self) -> &'static str {
        match self {
            Setting::I => "i",
            Setting::II => "ii",
            Setting::III => "iii",
            Setting::IV => "iv",
        }
    }

    /// Parses `i`, `ii`, `iii`, `iv`.
    pub fn parse(s: &str) -> Option<Setting> {
        Setting::ALL.into_iter().find(|x| x.name() == s)
    }

    /// The `M` grid (thesis §4.6.1).
    pub fn m_grid(self) -> &'static [usize] {
        match self {
            Setting::I => &[1, 2, 4, 8, 16],
            Setting::II | Setting::III => &[2, 4, 8, 16],
            Setting::IV => &[4, 8, 16],
        }
    }

    /// `M_min` (thesis footnote 4).
    pub fn m_min(self) -> usize {
        self.m_grid()[0]
    }

    /// LM iterations of every optimisation: 3 in settings (i, ii), 10 in (iii, iv).
    pub fn iterations(self) -> usize {
        match self {
            Setting::I | Setting::II => 3,
            Setting::III | Setting::IV => 10,
        }
    }

    /// The `(M, N)` cells: the grid, plus `N = 480` at `M_min`.
    pub fn cells(self) -> Vec<(usize, usize)> {
        let mut out = Vec::new();
        for &m in self.m_grid() {
            for n in N_GRID {
                out.push((m, n));
            }
        }
        out.push((self.m_min(), N_EXTRA));
        out
    }

    /// The base cell of the entropy reduction (eq. 4.30): `⟨M_min, 15⟩`, or `⟨4, 15⟩` for the
    /// monocular settings (ii, iii), whose `⟨2, 15⟩` and `⟨2, 30⟩` fail too often (§4.6.2).
    pub fn entropy_base(self, sensor: SensorKind) -> (usize, usize) {
        match (self, sensor) {
            (Setting::II | Setting::III, SensorKind::Mono) => (4, 15),
            _ => (self.m_min(), 15),
        }
    }

    /// True poses `T_0 … T_M` (`T_0` the identity).
    pub fn trajectory(self, m: usize) -> Vec<Se3> {
        match self {
            Setting::I => sideways(0.5, m),
            Setting::II => sideways(1.1, m),
            Setting::III => sideways_with_rotation(0.6, -30f64.to_radians(), m),
            Setting::IV => forward_turn(0.5, std::f64::consts::FRAC_PI_2, m),
        }
    }

    /// True bootstrap poses `T_b0, T_b1`: `T_0` moved to its left by 2 and 1 steps.
    pub fn bootstrap_poses(self) -> [Se3; 2] {
        let t0 = self.trajectory(1)[0];
        let r = t0.rotation().inverse();
        let left = r.act(&Vector3::new(-1.0, 0.0, 0.0));
        let forward = r.act(&Vector3::z());
        let up = r.act(&Vector3::new(0.0, -1.0, 0.0));
        let c0 = centre(&t0);
        [2.0, 1.0].map(|k| pose_looking(&(c0 + left * (k * BOOTSTRAP_STEP)), &forward, &up))
    }

    /// Candidate points of one trial (uniform in the scene regions).
    pub fn scene(self, rng: &mut ChaCha8Rng) -> Vec<Vector3<f64>> {
        match self {
            Setting::I => planar_slab(rng, (0.03, 0.47), (-0.42, 0.42), 1.0, 0.2, 1500),
            Setting::II => planar_slab(rng, (-0.75, 1.85), (-0.5, 0.5), 1.0, 0.2, 3000),
            Setting::III => planar_slab(rng, (-0.75, 2.8), (-0.5, 0.5), 1.0, 0.2, 4000),
            Setting::IV => {
                let mut wall_a = planar_slab(rng, (-1.0, 1.6), (-0.5, 0.5), 1.5, 0.2, 2000);
                // The second wall: the slab rotated to face +x at x = 1.5.
                let wall_b = planar_slab(rng, (-1.0, 1.6), (-0.5, 0.5), 1.5, 0.2, 2000)
                    .into_iter()
                    .map(|p| Vector3::new(p.z, p.y, p.x));
                wall_a.extend(wall_b);
                wall_a
            }
        }
    }
}

/// What one pipeline produced in one trial.
#[derive(Clone, Debug, PartialEq)]
pub struct PipelineResult {
    /// The error `Δt` (3 components for stereo, 2 for monocular), or `None` if the pipeline
    /// failed.
    pub error: Option<Vec<f64>>,
    /// CPU time of the whole pipeline (s, [`slam::clock`]), excluding the shared bootstrap.
    pub cost_total: f64,
    /// CPU time of the joint updates (s): full BA, or marginalisation + joint filter update +
    /// information update (thesis §4.6.5 footnote 5).
    pub cost_joint: f64,
}

/// One trial of one cell.
#[derive(Clone, Debug, PartialEq)]
pub struct TrialResult {
    /// BA-SLAM.
    pub ba: PipelineResult,
    /// Filter-SLAM.
    pub filter: PipelineResult,
}

/// Identifies one trial.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct TrialSpec {
    /// Setting.
    pub setting: Setting,
    /// Sensor.
    pub sensor: SensorKind,
    /// Keyframes after `T_0`.
    pub m: usize,
    /// Points.
    pub n: usize,
    /// Trial number.
    pub trial: usize,
    /// Master seed.
    pub seed: u64,
}

impl TrialSpec {
    /// The trial's own seed (scene, noise, feature selection), a hash of all fields.
    pub fn trial_seed(&self) -> u64 {
        let mut h: u64 = self.seed ^ 0x51_7C_C1_B7_27_22_0A_95;
        for v in [
            self.setting as u64,
            self.sensor as u64,
            self.m as u64,
            self.n as u64,
            self.trial as u64,
        ] {
            h = (h ^ v).wrapping_mul(0x1000_0000_01B3).rotate_left(29) ^ (h >> 17);
        }
        h
    }
}

/// Noisy measurements of every visible candidate from every pose.
fn measure<S: Sensor<N>, const N: usize>(
    sensor: &S,
    poses: &[Se3],
    points: &[Vector3<f64>],
    rng: &mut ChaCha8Rng,
) -> Vec<Vec<(usize, SVector<f64, N>)>> {
    let noise = Normal::new(0.0, sensor.sigma()).expect("σ > 0");
    poses
        .iter()
        .map(|t| {
            points
                .iter()
                .enumerate()
                .filter_map(|(j, y)| {
                    sensor
                        .predict(t, y)
                        .map(|z| (j, z + SVector::<f64, N>::from_fn(|_, _| noise.sample(rng))))
                })
                .collect()
        })
        .collect()
}

fn seconds(d: Duration) -> f64 {
    d.as_secs_f64()
}

/// The end camera's centre in the frame of `t0`.
fn relative_end(t0: &Se3, tm: &Se3) -> Vector3<f64> {
    t0.act(&centre(tm))
}

/// The monocular error (eq. 4.28–4.29): `t_est` scaled to `|t_true|` and projected onto the
/// tangent plane at `t_true`, in an orthonormal basis of that plane.
pub fn mono_error(t_true: &Vector3<f64>, t_est: &Vector3<f64>) -> Option<Vec<f64>> {
    let n = t_est.norm();
    if n.is_nan() || n <= 0.0 || !n.is_finite() {
        return None;
    }
    let scaled = t_est * (t_true.norm() / n);
    let u = t_true.normalize();
    let helper = if u.x.abs() < 0.9 {
        Vector3::x()
    } else {
        Vector3::y()
    };
    let e1 = u.cross(&helper).normalize();
    let e2 = u.cross(&e1);
    let d = scaled - t_true;
    Some(vec![e1.dot(&d), e2.dot(&d)])
}

fn stereo_error(t_true: &Vector3<f64>, t_est: &Vector3<f64>) -> Option<Vec<f64>> {
    let d = t_true - t_est;
    d.iter()
        .all(|x| x.is_finite())
        .then(|| d.iter().copied().collect())
}

/// Runs one trial: BA-SLAM and filter-SLAM on the same scene and measurements.
pub fn run_trial(spec: &TrialSpec) -> TrialResult {
    let setting = spec.setting;
    let mut rng = ChaCha8Rng::seed_from_u64(spec.trial_seed());
    let iterations = setting.iterations();
    let selection_seed = spec.trial_seed() ^ 0xA5A5;
    let failed = PipelineResult {
        error: None,
        cost_total: 0.0,
        cost_joint: 0.0,
    };
    let ba_options = BaSlamOptions {
        iterations,
        area: AREA,
        seed: selection_seed,
    };
    match spec.sensor {
        SensorKind::Stereo => {
            let scene = setting.scene(&mut rng);
            let truth = setting.trajectory(spec.m);
            let t_true = relative_end(&truth[0], &truth[spec.m]);
            let sensor = StereoSensor::vga(FOCAL, BASELINE, SIGMA);
            let frames = measure(&sensor, &truth, &scene, &mut rng);
            let all: Vec<usize> = frames[0].iter().map(|(id, _)| *id).collect();
            let selected = select_spread(&frames[0], &all, &[], spec.n, AREA, selection_seed);
            let camera = sensor.camera;
            let t0 = truth[0];
            let points: Vec<(usize, Vector3<f64>)> = selected
                .iter()
                .filter_map(|id| {
                    let z = find(&frames[0], *id)?;
                    let psi = camera.inverse_depth_from(&z, 1.0)?;
                    Some((
                        *id,
                        t0.inverse()
                            .act(&slam::factors::inverse_depth_to_point(&psi)),
                    ))
                })
                .collect();
            let ba = run_ba(camera, &t0, &points, &frames, ba_options, None, |t| {
                stereo_error(&t_true, &relative_end(&t0, t))
            });
            let mut filter = GaussNewtonFilter::new(camera, SIGMA, t0);
            for (id, _) in &points {
                let z = find(&frames[0], *id).expect("selected in frame 0");
                filter
                    .add_point(*id, &z, Anchor::Origin, 1.0)
                    .expect("valid stereo measurement");
            }
            let filter = run_filter(
                filter,
                0,
                &frames,
                FilterSlamOptions {
                    iterations,
                    motion: MotionEstimate::MotionOnlyBa,
                    area: AREA,
                    seed: selection_seed,
                },
                |t| stereo_error(&t_true, &relative_end(&t0, t)),
            );
            TrialResult {
                ba: ba.unwrap_or(failed.clone()),
                filter: filter.unwrap_or(failed),
            }
        }
        SensorKind::Mono => {
            let Some(start) = MonoStart::new(spec, &mut rng, selection_seed) else {
                return TrialResult {
                    ba: failed.clone(),
                    filter: failed,
                };
            };
            let MonoStart {
                camera,
                frames,
                boot,
                t0,
                t_true,
            } = start;
            let points: Vec<(usize, Vector3<f64>)> = boot
                .features
                .iter()
                .filter_map(|id| boot.filter.point_world(*id).map(|y| (*id, y)))
                .collect();
            let init = TwoViewInverseDepth { iterations };
            let ba = run_ba(
                camera,
                &t0,
                &points,
                &frames,
                ba_options,
                Some(&init),
                |t| mono_error(&t_true, &relative_end(&t0, t)),
            );
            let filter = run_filter(
                boot.filter,
                2,
                &frames,
                FilterSlamOptions {
                    iterations,
                    motion: MotionEstimate::MapPrior { exact: false },
                    area: AREA,
                    seed: selection_seed,
                },
                |t| mono_error(&t_true, &relative_end(&t0, t)),
            );
            TrialResult {
                ba: ba.unwrap_or(failed.clone()),
                filter: filter.unwrap_or(failed),
            }
        }
    }
}

/// A monocular trial up to `T_0`: the measurements of `T_0 … T_M` and the two-view bootstrap
/// from `T_b0`, `T_b1` (§4.5.3), shared by BA-SLAM and filter-SLAM.
struct MonoStart {
    camera: PinholeCamera,
    /// Measurements of `T_0 … T_M`.
    frames: Vec<Vec<(usize, SVector<f64, 2>)>>,
    boot: Bootstrap,
    /// The bootstrap's estimate of `T_0`.
    t0: Se3,
    /// The true end camera centre in the frame of `T_0`.
    t_true: Vector3<f64>,
}

impl MonoStart {
    /// `None` if the bootstrap fails.
    fn new(spec: &TrialSpec, rng: &mut ChaCha8Rng, selection_seed: u64) -> Option<MonoStart> {
        let truth = spec.setting.trajectory(spec.m);
        let sensor = MonoSensor::vga(FOCAL, SIGMA);
        let scene = spec.setting.scene(rng);
        let mut poses = spec.setting.bootstrap_poses().to_vec();
        poses.extend_from_slice(&truth);
        let mut frames = measure(&sensor, &poses, &scene, rng);
        let boot_frames: Vec<_> = frames.drain(..2).collect();
        let boot = bootstrap(
            sensor.camera,
            SIGMA,
            [&boot_frames[0], &boot_frames[1], &frames[0]],
            &BootstrapOptions {
                num_points: spec.n,
                iterations: 20,
                pose_iterations: 10,
                min_parallax: 0.5f64.to_radians(),
                area: AREA,
                seed: selection_seed,
            },
        )
        .ok()?;
        let (_, t0) = boot.filter.current().expect("bootstrap ends at T_0");
        Some(MonoStart {
            camera: sensor.camera,
            frames,
            boot,
            t0,
            t_true: relative_end(&truth[0], &truth[spec.m]),
        })
    }
}

fn run_ba<C: InverseDepthCamera<N>, const N: usize>(
    camera: C,
    t0: &Se3,
    points: &[(usize, Vector3<f64>)],
    frames: &[Vec<(usize, SVector<f64, N>)>],
    options: BaSlamOptions,
    initialiser: Option<&dyn ba_slam::PointInitialiser<C>>,
    error: impl Fn(&Se3) -> Option<Vec<f64>>,
) -> Option<PipelineResult> {
    let start = CpuStopwatch::start();
    let mut ba = BaSlam::with_map(camera, SIGMA, options, *t0, points, &frames[0]);
    for i in 1..frames.len() {
        ba.step(&frames[i - 1], &frames[i], initialiser).ok()?;
    }
    let total = start.elapsed();
    Some(PipelineResult {
        error: error(&ba.current()),
        cost_total: seconds(total),
        cost_joint: seconds(ba.cost.full),
    })
}

fn run_filter<C: InverseDepthCamera<N>, const N: usize>(
    filter: GaussNewtonFilter<C, N>,
    first_frame: usize,
    frames: &[Vec<(usize, SVector<f64, N>)>],
    options: FilterSlamOptions,
    error: impl Fn(&Se3) -> Option<Vec<f64>>,
) -> Option<PipelineResult> {
    let start = CpuStopwatch::start();
    let mut slam = FilterSlam::new(filter, options, first_frame);
    for i in 1..frames.len() {
        slam.step(&frames[i - 1], &frames[i]).ok()?;
    }
    let total = start.elapsed();
    Some(PipelineResult {
        error: error(&slam.current()),
        cost_total: seconds(total),
        cost_joint: seconds(slam.cost.joint()),
    })
}

/// The pose predictions of monocular filter-SLAM compared in thesis §4.6.3 (Fig. 4.10), in
/// this order: motion-only BA against the map's mean, Alg. 6 in its approximate form (the
/// thesis's choice for the filter experiments, and what the pipeline continues with), Alg. 6
/// exact.
pub const MOTION_ESTIMATES: [MotionEstimate; 3] = [
    MotionEstimate::MotionOnlyBa,
    MotionEstimate::MapPrior { exact: false },
    MotionEstimate::MapPrior { exact: true },
];

/// A short name of a pose prediction, for tables and file columns.
pub fn motion_estimate_name(estimate: MotionEstimate) -> &'static str {
    match estimate {
        MotionEstimate::MotionOnlyBa => "motion_only_ba",
        MotionEstimate::MapPrior { exact: false } => "map_prior_approx",
        MotionEstimate::MapPrior { exact: true } => "map_prior_exact",
    }
}

/// Specs of the pose-prediction study: setting (i), monocular, its `(M, N)` cells. The trial
/// seeds are those of the same cells of the main study, so the scenes and the noise are the
/// same.
pub fn motion_specs(trials: usize, seed: u64) -> Vec<TrialSpec> {
    trial_specs(&[Setting::I], &[SensorKind::Mono], trials, seed)
}

/// One trial of the pose-prediction study (thesis §4.6.3, Fig. 4.10) on a monocular `spec`:
/// filter-SLAM runs as in [`run_trial`] (approximate Alg. 6), and at every keyframe all of
/// [`MOTION_ESTIMATES`] predict the new pose from the same filter state. Per estimate, in that
/// order: `error` of the *predicted* end pose (eq. 4.28–4.29, before the joint update), and
/// `cost_total` the CPU time of its `M` predictions (`cost_joint` unused, 0). `None` errors if
/// the bootstrap or the filter failed.
pub fn run_motion_trial(spec: &TrialSpec) -> [PipelineResult; 3] {
    assert_eq!(spec.sensor, SensorKind::Mono, "the study is monocular");
    let mut rng = ChaCha8Rng::seed_from_u64(spec.trial_seed());
    let selection_seed = spec.trial_seed() ^ 0xA5A5;
    let mut out = MOTION_ESTIMATES.map(|_| PipelineResult {
        error: None,
        cost_total: 0.0,
        cost_joint: 0.0,
    });
    let Some(start) = MonoStart::new(spec, &mut rng, selection_seed) else {
        return out;
    };
    let options = FilterSlamOptions {
        iterations: spec.setting.iterations(),
        motion: MotionEstimate::MapPrior { exact: false },
        area: AREA,
        seed: selection_seed,
    };
    let mut slam = FilterSlam::new(start.boot.filter, options, 2);
    let mut end = [None; 3];
    let mut costs = [Duration::ZERO; 3];
    for i in 1..start.frames.len() {
        let Ok(obs) = slam.prepare(&start.frames[i - 1], &start.frames[i]) else {
            return out;
        };
        let mut predicted = [Se3::identity(); 3];
        for (k, estimate) in MOTION_ESTIMATES.into_iter().enumerate() {
            let clock = CpuStopwatch::start();
            let Ok(t) = slam.predict(&obs, estimate) else {
                return out;
            };
            predicted[k] = t;
            costs[k] += clock.elapsed();
        }
        if slam.update(&obs, predicted[1]).is_err() {
            return out;
        }
        end = predicted.map(Some);
    }
    for k in 0..3 {
        out[k].error = end[k].and_then(|t| mono_error(&start.t_true, &relative_end(&start.t0, &t)));
        out[k].cost_total = seconds(costs[k]);
    }
    out
}

/// The statistics of one `M, N` cell of the pose-prediction study.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct MotionCellStats {
    /// Keyframes.
    pub m: usize,
    /// Points.
    pub n: usize,
    /// Per estimate of [`MOTION_ESTIMATES`]: error statistics of the predicted end pose;
    /// `cost_total` is the mean CPU time of the `M` predictions of a trial (s).
    pub estimates: [PipelineStats; 3],
}

/// Aggregates the pose-prediction study into cells.
pub fn summarize_motion(results: &[(TrialSpec, [PipelineResult; 3])]) -> Vec<MotionCellStats> {
    let mut keys: Vec<(usize, usize)> = results.iter().map(|(s, _)| (s.m, s.n)).collect();
    keys.sort();
    keys.dedup();
    keys.into_iter()
        .map(|(m, n)| {
            let these: Vec<&[PipelineResult; 3]> = results
                .iter()
                .filter(|(s, _)| (s.m, s.n) == (m, n))
                .map(|(_, r)| r)
                .collect();
            MotionCellStats {
                m,
                n,
                estimates: std::array::from_fn(|k| {
                    let mut stats =
                        pipeline_stats(&these.iter().map(|r| &r[k]).collect::<Vec<_>>());
                    stats.entropy_reduction = f64::NAN;
                    stats
                }),
            }
        })
        .collect()
}

/// Statistics of one pipeline over the trials of one cell.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize)]
pub struct PipelineStats {
    /// Trials that produced an estimate.
    pub successes: usize,
    /// Trials that failed (no estimate).
    pub failures: usize,
    /// RMSE of `|Δt|` over the successful trials (eq. 4.31), metres.
    pub rmse: f64,
    /// Median of `|Δt|` over the successful trials, metres (robust to the occasional gross
    /// failure that dominates the RMSE).
    pub median_error: f64,
    /// `ln det` of the sample covariance of `Δt`.
    pub ln_det_covariance: f64,
    /// Entropy reduction in bits against the setting's base cell (eq. 4.30); filled by
    /// [`summarize`].
    pub entropy_reduction: f64,
    /// Mean cost of the whole pipeline (s).
    pub cost_total: f64,
    /// Mean cost of the joint updates (s).
    pub cost_joint: f64,
}

fn pipeline_stats(results: &[&PipelineResult]) -> PipelineStats {
    let ok: Vec<&Vec<f64>> = results.iter().filter_map(|r| r.error.as_ref()).collect();
    let k = ok.len();
    let mut s = PipelineStats {
        successes: k,
        failures: results.len() - k,
        ..Default::default()
    };
    let costs: Vec<&PipelineResult> = results
        .iter()
        .copied()
        .filter(|r| r.error.is_some())
        .collect();
    if !costs.is_empty() {
        s.cost_total = costs.iter().map(|r| r.cost_total).sum::<f64>() / costs.len() as f64;
        s.cost_joint = costs.iter().map(|r| r.cost_joint).sum::<f64>() / costs.len() as f64;
    }
    if k == 0 {
        s.rmse = f64::NAN;
        s.median_error = f64::NAN;
        s.ln_det_covariance = f64::NAN;
        return s;
    }
    let dim = ok[0].len();
    let mut norms: Vec<f64> = ok
        .iter()
        .map(|e| e.iter().map(|x| x * x).sum::<f64>().sqrt())
        .collect();
    norms.sort_by(f64::total_cmp);
    s.median_error = if k % 2 == 1 {
        norms[k / 2]
    } else {
        0.5 * (norms[k / 2 - 1] + norms[k / 2])
    };
    s.rmse = (ok
        .iter()
        .map(|e| e.iter().map(|x| x * x).sum::<f64>())
        .sum::<f64>()
        / k as f64)
        .sqrt();
    let mean = ok.iter().fold(DVector::zeros(dim), |a, e| {
        a + DVector::from_column_slice(e)
    }) / k as f64;
    let mut cov = DMatrix::zeros(dim, dim);
    for e in &ok {
        let d = DVector::from_column_slice(e) - &mean;
        cov += &d * d.transpose();
    }
    cov /= (k.max(2) - 1) as f64;
    s.ln_det_covariance = cov.determinant().abs().ln();
    s
}

/// The statistics of one `(setting, sensor, M, N)` cell.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct CellStats {
    /// Setting name.
    pub setting: &'static str,
    /// Sensor name.
    pub sensor: &'static str,
    /// Keyframes.
    pub m: usize,
    /// Points.
    pub n: usize,
    /// BA-SLAM.
    pub ba: PipelineStats,
    /// Filter-SLAM.
    pub filter: PipelineStats,
}

/// Aggregates trials into cells and fills the entropy reductions against each
/// (setting, sensor)'s base cell (eq. 4.30).
pub fn summarize(results: &[(TrialSpec, TrialResult)]) -> Vec<CellStats> {
    let mut keys: Vec<(Setting, SensorKind, usize, usize)> = results
        .iter()
        .map(|(s, _)| (s.setting, s.sensor, s.m, s.n))
        .collect();
    keys.sort();
    keys.dedup();
    let mut cells: Vec<CellStats> = keys
        .iter()
        .map(|&(setting, sensor, m, n)| {
            let these: Vec<&TrialResult> = results
                .iter()
                .filter(|(s, _)| (s.setting, s.sensor, s.m, s.n) == (setting, sensor, m, n))
                .map(|(_, r)| r)
                .collect();
            CellStats {
                setting: setting.name(),
                sensor: sensor.name(),
                m,
                n,
                ba: pipeline_stats(&these.iter().map(|r| &r.ba).collect::<Vec<_>>()),
                filter: pipeline_stats(&these.iter().map(|r| &r.filter).collect::<Vec<_>>()),
            }
        })
        .collect();
    let bits = 1.0 / (2.0 * std::f64::consts::LN_2);
    for k in 0..cells.len() {
        let setting = Setting::parse(cells[k].setting).expect("own name");
        let sensor = if cells[k].sensor == "mono" {
            SensorKind::Mono
        } else {
            SensorKind::Stereo
        };
        let (bm, bn) = setting.entropy_base(sensor);
        let base = cells
            .iter()
            .find(|c| {
                c.setting == cells[k].setting
                    && c.sensor == cells[k].sensor
                    && c.m == bm
                    && c.n == bn
            })
            .map(|c| (c.ba.ln_det_covariance, c.filter.ln_det_covariance));
        if let Some((b_ba, b_f)) = base {
            cells[k].ba.entropy_reduction = (b_ba - cells[k].ba.ln_det_covariance) * bits;
            cells[k].filter.entropy_reduction = (b_f - cells[k].filter.ln_det_covariance) * bits;
        } else {
            cells[k].ba.entropy_reduction = f64::NAN;
            cells[k].filter.entropy_reduction = f64::NAN;
        }
    }
    cells
}

/// The least-squares slope `b` of `ln y = a + b·ln x` (the cost exponent), or NaN with fewer
/// than two usable points.
pub fn log_log_slope(points: &[(f64, f64)]) -> f64 {
    let p: Vec<(f64, f64)> = points
        .iter()
        .filter(|(x, y)| *x > 0.0 && *y > 0.0 && x.is_finite() && y.is_finite())
        .map(|(x, y)| (x.ln(), y.ln()))
        .collect();
    if p.len() < 2 {
        return f64::NAN;
    }
    let n = p.len() as f64;
    let (mx, my) = (
        p.iter().map(|q| q.0).sum::<f64>() / n,
        p.iter().map(|q| q.1).sum::<f64>() / n,
    );
    let sxy: f64 = p.iter().map(|q| (q.0 - mx) * (q.1 - my)).sum();
    let sxx: f64 = p.iter().map(|q| (q.0 - mx).powi(2)).sum();
    sxy / sxx
}

/// All trial specs of the given settings and sensors, `trials` per cell.
pub fn trial_specs(
    settings: &[Setting],
    sensors: &[SensorKind],
    trials: usize,
    seed: u64,
) -> Vec<TrialSpec> {
    let mut out = Vec::new();
    for &setting in settings {
        for &sensor in sensors {
            for (m, n) in setting.cells() {
                for trial in 0..trials {
                    out.push(TrialSpec {
                        setting,
                        sensor,
                        m,
                        n,
                        trial,
                        seed,
                    });
                }
            }
        }
    }
    out
}

/// Runs `specs` on `workers` threads, each with its own single-threaded rayon pool (so a
/// trial's timings are single-threaded and unaffected by the other trials' work), the most
/// expensive first; `on_done` is called after each trial. Results are in `specs` order.
pub fn run_trials(
    specs: &[TrialSpec],
    workers: usize,
    on_done: &(dyn Fn() + Sync),
) -> Vec<(TrialSpec, TrialResult)> {
    run_parallel(specs, workers, run_trial, on_done)
}

/// Runs `run` on every spec as [`run_trials`] does (same scheduling and one-thread pools).
pub fn run_parallel<R: Send>(
    specs: &[TrialSpec],
    workers: usize,
    run: impl Fn(&TrialSpec) -> R + Sync,
    on_done: &(dyn Fn() + Sync),
) -> Vec<(TrialSpec, R)> {
    use std::sync::Mutex;
    use std::sync::atomic::{AtomicUsize, Ordering};
    let mut order: Vec<usize> = (0..specs.len()).collect();
    // Expected cost grows like N³·M (filter): schedule the big ones first.
    order.sort_by_key(|&k| std::cmp::Reverse(specs[k].n.pow(3) * specs[k].m));
    let next = AtomicUsize::new(0);
    let results: Mutex<Vec<Option<R>>> = Mutex::new((0..specs.len()).map(|_| None).collect());
    std::thread::scope(|scope| {
        for _ in 0..workers.max(1) {
            scope.spawn(|| {
                let pool = rayon::ThreadPoolBuilder::new()
                    .num_threads(1)
                    .build()
                    .expect("a one-thread pool");
                pool.install(|| {
                    loop {
                        let k = next.fetch_add(1, Ordering::Relaxed);
                        let Some(&idx) = order.get(k) else {
                            break;
                        };
                        let r = run(&specs[idx]);
                        results.lock().expect("no panics while locked")[idx] = Some(r);
                        on_done();
                    }
                });
            });
        }
    });
    specs
        .iter()
        .copied()
        .zip(
            results
                .into_inner()
                .expect("no panics while locked")
                .into_iter()
                .map(|r| r.expect("every trial ran")),
        )
        .collect()
}

#[cfg(test)]
mod tests;

#[cfg(test)]
mod diagnose;
