//! Tracking primitives (thesis §4.5.1 eq. 4.15, §6.2.5): the candidate points of the
//! reference keyframe's neighbourhood, and robust motion-only bundle adjustment — the one
//! pose-from-known-points estimator of the workspace, used by the live tracker, the keyframe
//! pipeline's metric loop closure, monocular exploration and the ch. 4 study.
//!
//! Data association (which measurement belongs to which map point) is the caller's: the live
//! system finds it by guided search in images, the simulator knows it.

use crate::ba::{BaMode, BundleAdjustment, Gauge, Observation};
use crate::factors::Projector;
use crate::map::{GraphError, KeyframeId, PointId, SlamGraph};
use lie::{LieGroup, Se3, Sim3};
use lsq::{RobustKernel, SolverOptions};
use nalgebra::{SVector, Vector3};
use std::collections::BTreeSet;

/// The identity of a feature track: a feature followed from frame to frame by the front-end
/// (in simulation, the world point), so that its measurements in different keyframes can be
/// related before it is a map point.
pub type TrackId = u64;

/// Why a pose could not be estimated.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum TrackingError {
    /// A graph operation failed.
    #[error(transparent)]
    Graph(#[from] GraphError),
    /// Too few matches to estimate a pose.
    #[error("{got} matches are too few to estimate a pose (need {need})")]
    TooFewMatches {
        /// Matches given.
        got: usize,
        /// Matches needed.
        need: usize,
    },
    /// The least-squares problem could not be built or solved.
    #[error("motion-only bundle adjustment failed: {0}")]
    Solver(String),
}

/// Options of [`motion_only_ba`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MotionOnlyOptions {
    /// Measurement noise σ (measurement units): information `I/σ²`.
    pub sigma: f64,
    /// Robust kernel, in units of σ (`None`: least squares).
    pub kernel: Option<RobustKernel>,
    /// Levenberg-Marquardt iterations.
    pub iterations: usize,
    /// Fewer matches than this are an error ([`TrackingError::TooFewMatches`]).
    pub min_matches: usize,
}

impl MotionOnlyOptions {
    /// Robust tracking: Huber at 2σ (residuals beyond twice the noise are outliers more often
    /// than not), ten iterations, at least six matches (a pose has six degrees of freedom and
    /// each match gives two or three equations, so six matches over-determine it twofold).
    pub fn robust(sigma: f64) -> Self {
        MotionOnlyOptions {
            sigma,
            kernel: Some(RobustKernel::Huber(2.0)),
            iterations: 10,
            min_matches: 6,
        }
    }
}

/// The result of motion-only BA.
#[derive(Clone, Debug, PartialEq)]
pub struct PoseFit {
    /// The estimated `camera_from_world`.
    pub camera_from_world: Se3,
    /// Squared whitened reprojection error `‖ẑ − z‖²/σ²` of each match at the estimate, in
    /// input order (∞ where the point does not project).
    pub chi2: Vec<f64>,
}

/// Motion-only bundle adjustment (thesis eq. 4.15): the pose `T` minimising
/// `Σ ρ(‖ẑ(T·yᵢ) − zᵢ‖²/σ²)` over fixed points `yᵢ` (in the frame `T` maps from) measured as
/// `zᵢ`, by Levenberg-Marquardt from `initial` (single-threaded: tracking runs on one core).
pub fn motion_only_ba<P: Projector<N> + Clone, const N: usize>(
    projector: &P,
    initial: &Se3,
    points: &[Vector3<f64>],
    measurements: &[SVector<f64, N>],
    options: &MotionOnlyOptions,
) -> Result<PoseFit, TrackingError> {
    debug_assert_eq!(points.len(), measurements.len());
    if measurements.len() < options.min_matches.max(1) {
        return Err(TrackingError::TooFewMatches {
            got: measurements.len(),
            need: options.min_matches.max(1),
        });
    }
    let observations = Observation::of_one_pose(measurements.iter().copied());
    let mut ba = BundleAdjustment::new(
        projector,
        &[*initial],
        points,
        &observations,
        options.sigma,
        options.kernel,
        BaMode::MotionOnly,
        &Gauge::Damping,
    )
    .map_err(|e| TrackingError::Solver(e.to_string()))?;
    ba.problem
        .optimise(&SolverOptions {
            max_iterations: options.iterations,
            threads: Some(1),
            ..SolverOptions::default()
        })
        .map_err(|e| TrackingError::Solver(e.to_string()))?;
    let camera_from_world = ba.camera_from_world()[0];
    let inv_var = 1.0 / (options.sigma * options.sigma);
    let chi2 = points
        .iter()
        .zip(measurements)
        .map(
            |(y, z)| match projector.project(&camera_from_world.act(y)) {
                Some((z_hat, _)) => (z_hat - z).norm_squared() * inv_var,
                None => f64::INFINITY,
            },
        )
        .collect();
    Ok(PoseFit {
        camera_from_world,
        chi2,
    })
}

/// The candidate points for tracking against `V_ref` (thesis §6.2.5): every point visible from
/// `N1(ref)`.
pub fn tracking_candidates<const N: usize>(
    graph: &SlamGraph<N>,
    reference: KeyframeId,
) -> BTreeSet<PointId> {
    graph.points_visible_from(&graph.n1(reference))
}

/// A pose estimated against the SLAM graph.
#[derive(Clone, Debug, PartialEq)]
pub struct GraphPoseFit {
    /// The absolute pose, with the scale of the keyframe it was estimated in.
    pub camera_from_world: Sim3,
    /// Squared whitened reprojection error of each match, in input order.
    pub chi2: Vec<f64>,
}

/// Motion-only BA of a camera against points of the graph, copied out of it
/// ([`PoseProblem::from_graph`], under a read lock) and solved without it
/// ([`PoseProblem::solve`]): no lock is held across the optimisation.
#[derive(Clone, Debug, PartialEq)]
pub struct PoseProblem<const N: usize> {
    t_frame: Sim3,
    points: Vec<Vector3<f64>>,
    measurements: Vec<SVector<f64, N>>,
    relative: Se3,
}

impl<const N: usize> PoseProblem<N> {
    /// The problem of a camera measuring `matches` (map point and measurement), estimated
    /// rigidly in the metric of keyframe `frame` (the points are expressed in its frame, so the
    /// result keeps `frame`'s scale: `T = T_rel·T_frame`), from `initial`.
    pub fn from_graph(
        graph: &SlamGraph<N>,
        frame: KeyframeId,
        matches: &[(PointId, SVector<f64, N>)],
        initial: &Sim3,
    ) -> Result<Self, TrackingError> {
        let t_frame = graph.pose(frame)?;
        let points: Vec<Vector3<f64>> = matches
            .iter()
            .map(|(p, _)| graph.point_in_frame(*p, frame))
            .collect::<Result<_, _>>()?;
        // Rigid part of T·T_frame⁻¹; the scale of the initial guess relative to the frame is 1
        // by construction of every caller (new keyframes inherit their reference's scale).
        Ok(PoseProblem {
            t_frame,
            points,
            measurements: matches.iter().map(|(_, z)| *z).collect(),
            relative: initial.compose(&t_frame.inverse()).rigid_part(),
        })
    }

    /// The problem of points given in the frame of a keyframe whose pose is `t_frame`, measured
    /// as `measurements`, from `initial` (the live tracker copies the points out of the graph
    /// itself, and measures some frames without depth: `N = 2` against a stereo map).
    pub fn new(
        t_frame: Sim3,
        points: Vec<Vector3<f64>>,
        measurements: Vec<SVector<f64, N>>,
        initial: &Sim3,
    ) -> Self {
        assert_eq!(
            points.len(),
            measurements.len(),
            "one measurement per point"
        );
        PoseProblem {
            t_frame,
            points,
            measurements,
            relative: initial.compose(&t_frame.inverse()).rigid_part(),
        }
    }

    /// Robust motion-only BA ([`motion_only_ba`]).
    pub fn solve<P: Projector<N> + Clone>(
        &self,
        projector: &P,
        options: &MotionOnlyOptions,
    ) -> Result<GraphPoseFit, TrackingError> {
        let fit = motion_only_ba(
            projector,
            &self.relative,
            &self.points,
            &self.measurements,
            options,
        )?;
        Ok(GraphPoseFit {
            camera_from_world: Sim3::from_se3(&fit.camera_from_world).compose(&self.t_frame),
            chi2: fit.chi2,
        })
    }
}

/// Motion-only BA ([`motion_only_ba`]) of a camera measuring `matches` (map point and
/// measurement) of the graph, from `initial`, in the metric of keyframe `frame`
/// ([`PoseProblem`] built and solved in one go).
pub fn estimate_pose<P: Projector<N> + Clone, const N: usize>(
    graph: &SlamGraph<N>,
    frame: KeyframeId,
    matches: &[(PointId, SVector<f64, N>)],
    projector: &P,
    initial: &Sim3,
    options: &MotionOnlyOptions,
) -> Result<GraphPoseFit, TrackingError> {
    if matches.len() < options.min_matches {
        return Err(TrackingError::TooFewMatches {
            got: matches.len(),
            need: options.min_matches,
        });
    }
    PoseProblem::from_graph(graph, frame, matches, initial)?.solve(projector, options)
}
