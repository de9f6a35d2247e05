//! Bundle adjustment problems (thesis §3.3, eq. 4.14–4.16): full, motion-only and
//! structure-only BA over `camera_from_world` poses and Euclidean world points, and BAL
//! problems, built from the factors of [`crate::factors`].

use crate::factors::{BalCameraState, BalObservationFactor, PointObservation, Projector};
use lie::Se3;
use lsq::Var;
use nalgebra::{SVector, Vector2, Vector3};

/// Which variables a bundle adjustment optimises (thesis eq. 4.14–4.16).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum BaMode {
    /// Poses and points (eq. 4.14).
    Full,
    /// Poses only, points held fixed (eq. 4.15): tracking against a known map.
    MotionOnly,
    /// Points only, poses held fixed (eq. 4.16): refining structure for known motion.
    StructureOnly,
}

/// How the gauge freedom of full BA is removed (thesis §3.3.2–3.3.3, §4.5.3).
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Gauge {
    /// Hold these poses fixed (e.g. the first one for stereo, the first two for monocular BA,
    /// which also fixes the scale).
    FixPoses(Vec<usize>),
    /// Fix nothing; Levenberg-Marquardt's damping regularises the null space (§6.2.3).
    Damping,
}

/// One observation of point `point` from pose `pose`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Observation<const N: usize> {
    /// Index of the observing pose.
    pub pose: usize,
    /// Index of the observed point.
    pub point: usize,
    /// The measurement.
    pub measurement: SVector<f64, N>,
}

impl<const N: usize> Observation<N> {
    /// The observations of one pose (index 0) seeing points `0, 1, …` in the order of
    /// `measurements` (the input of motion-only BA).
    pub fn of_one_pose(measurements: impl IntoIterator<Item = SVector<f64, N>>) -> Vec<Self> {
        measurements
            .into_iter()
            .enumerate()
            .map(|(point, measurement)| Observation {
                pose: 0,
                point,
                measurement,
            })
            .collect()
    }
}

/// Why a bundle adjustment could not be built.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum BaError {
    /// An observation refers to a missing pose or point.
    #[error("observation {observation} refers to {what} {index}, but there are only {count}")]
    OutOfRange {
        /// Index of the observation.
        observation: usize,
        /// "pose" or "point".
        what: &'static str,
        /// The index used.
        index: usize,
        /// How many exist.
        count: usize,
    },
    /// The least-squares problem refused a factor.
    #[error(transparent)]
    Problem(#[from] lsq::ProblemError),
}

/// A bundle-adjustment problem over `camera_from_world` poses and Euclidean world points,
/// ready to optimise; points are eliminated by the Schur complement unless they are fixed.
pub struct BundleAdjustment {
    /// The least-squares problem.
    pub problem: lsq::Problem,
    /// Pose variables in input order.
    pub poses: Vec<Var<Se3>>,
    /// Point variables in input order.
    pub points: Vec<Var<Vector3<f64>>>,
}

impl BundleAdjustment {
    /// Builds the problem: one [`PointObservation`] per observation, with information
    /// `I/σ²` (`sigma` in measurement units) and an optional robust kernel (in units of σ).
    #[allow(clippy::too_many_arguments)]
    pub fn new<P: Projector<N> + Clone, const N: usize>(
        projector: &P,
        camera_from_world: &[Se3],
        points_world: &[Vector3<f64>],
        observations: &[Observation<N>],
        sigma: f64,
        kernel: Option<lsq::RobustKernel>,
        mode: BaMode,
        gauge: &Gauge,
    ) -> Result<Self, BaError> {
        let mut problem = lsq::Problem::new();
        let poses: Vec<Var<Se3>> = camera_from_world
            .iter()
            .map(|t| problem.add_variable(*t))
            .collect();
        let points: Vec<Var<Vector3<f64>>> = points_world
            .iter()
            .map(|p| problem.add_variable(*p))
            .collect();
        for (k, o) in observations.iter().enumerate() {
            if o.pose >= poses.len() {
                return Err(BaError::OutOfRange {
                    observation: k,
                    what: "pose",
                    index: o.pose,
                    count: poses.len(),
                });
            }
            if o.point >= points.len() {
                return Err(BaError::OutOfRange {
                    observation: k,
                    what: "point",
                    index: o.point,
                    count: points.len(),
                });
            }
            problem.add_factor(
                PointObservation {
                    camera_from_world: poses[o.pose],
                    point_world: points[o.point],
                    measurement: o.measurement,
                    projector: projector.clone(),
                },
                lsq::Information::Isotropic(sigma),
                kernel,
            )?;
        }
        match mode {
            BaMode::MotionOnly => points.iter().for_each(|p| problem.set_fixed(p.key(), true)),
            BaMode::StructureOnly => poses.iter().for_each(|t| problem.set_fixed(t.key(), true)),
            BaMode::Full => {
                if let Gauge::FixPoses(fixed) = gauge {
                    for &i in fixed {
                        if let Some(t) = poses.get(i) {
                            problem.set_fixed(t.key(), true);
                        }
                    }
                }
            }
        }
        if mode != BaMode::MotionOnly && !points.is_empty() {
            problem.set_eliminated::<Vector3<f64>>(true);
        }
        Ok(BundleAdjustment {
            problem,
            poses,
            points,
        })
    }

    /// The current poses.
    pub fn camera_from_world(&self) -> Vec<Se3> {
        self.poses.iter().map(|v| *self.problem.value(*v)).collect()
    }

    /// The current points.
    pub fn points_world(&self) -> Vec<Vector3<f64>> {
        self.points
            .iter()
            .map(|v| *self.problem.value(*v))
            .collect()
    }
}

/// A BAL bundle adjustment: [`BalCameraState`] cameras and world points, points eliminated by
/// the Schur complement, nothing fixed (the gauge is left to the damping, as Ceres does on
/// these problems).
pub struct BalAdjustment {
    /// The least-squares problem.
    pub problem: lsq::Problem,
    /// Camera variables in input order.
    pub cameras: Vec<Var<BalCameraState>>,
    /// Point variables in input order.
    pub points: Vec<Var<Vector3<f64>>>,
    /// Observations whose point is behind its camera at the initial values: not added.
    pub rejected: Vec<usize>,
}

impl BalAdjustment {
    /// Builds the problem from cameras, points and `(camera, point, measurement)`
    /// observations; observations that cannot be projected at the initial values (point
    /// behind the camera, non-finite) are left out and listed in `rejected`.
    pub fn new(
        cameras: &[BalCameraState],
        points_world: &[Vector3<f64>],
        observations: &[(usize, usize, Vector2<f64>)],
        kernel: Option<lsq::RobustKernel>,
    ) -> Result<Self, BaError> {
        let mut problem = lsq::Problem::new();
        let cams: Vec<_> = cameras.iter().map(|c| problem.add_variable(*c)).collect();
        let points: Vec<_> = points_world
            .iter()
            .map(|p| problem.add_variable(*p))
            .collect();
        let mut rejected = Vec::new();
        for (k, &(c, p, z)) in observations.iter().enumerate() {
            if c >= cams.len() {
                return Err(BaError::OutOfRange {
                    observation: k,
                    what: "camera",
                    index: c,
                    count: cams.len(),
                });
            }
            if p >= points.len() {
                return Err(BaError::OutOfRange {
                    observation: k,
                    what: "point",
                    index: p,
                    count: points.len(),
                });
            }
            if BalObservationFactor::residual_at(&cameras[c], &points_world[p], &z).is_err()
                || !z.iter().all(|v| v.is_finite())
            {
                rejected.push(k);
                continue;
            }
            problem.add_factor(
                BalObservationFactor {
                    camera: cams[c],
                    point_world: points[p],
                    measurement: z,
                },
                lsq::Information::Identity,
                kernel,
            )?;
        }
        problem.set_eliminated::<Vector3<f64>>(true);
        Ok(BalAdjustment {
            problem,
            cameras: cams,
            points,
            rejected,
        })
    }
}
