//! Double window optimisation (thesis §6.2.3–6.2.4, §6.2.7).
//!
//! From the reference keyframe `V_ref` a weighted breadth-first search
//! ([`SlamGraph::weighted_bfs`]) takes the first `M1` keyframes as the inner window `W1` and
//! the next `M2` as the outer window `W2`. Every point visible from `W1` whose anchor is in the
//! double window, or joined by an edge to the inner-window keyframe that sees it (the anchor
//! then joins `W2`), is optimised (thesis §6.2.4). The cost is thesis eq. 6.4:
//!
//! `χ² = Σ_{z_ik} ‖z_ik − ẑ(T_i·T_a(k)⁻¹·Π(ψ_k))‖²_Σ + Σ_{T_ji} v_jiᵀ Λ_ji v_ji`,
//! `v_ji = log(T_ji·T_i·T_j⁻¹)^∨`,
//!
//! over the observations of the active points from keyframes of `W1 ∪ W2` and the pose-pose
//! constraints of the edges of the double window. A pose-pose constraint summarises the
//! points its two keyframes share, as if they were marginalised; the points that are active
//! are in the optimisation already, so an edge's weight `w_ij` counts only its shared points
//! that are *not* active, and an edge without such points is no constraint (the edges inside
//! `W1`, and in practice those between `W1` and `W2`, are represented by the points). The edge
//! information is, by default, what those points give the relative pose: the Schur complement
//! of the points on `T_j` with `T_i` held ([`ConstraintInformation::Marginal`]); the thesis's
//! coarse one, eq. 6.2, `Λ_ji = w_ij·diag(λ_trans²·I₃, λ_rot²·I₃, λ_rot²)` with both `λ`
//! proportional to the parallax (see [`DwoParams::new`]; `d̄`: median depth of the points seen
//! from `V_j`), is [`ConstraintInformation::Coarse`] — on the simulated spiral it leaves cDWO's
//! inner window 1.17× and gDWO 1.38× BA's error (10 seeds), the marginal one 1.09× and 1.05×
//! (docs/experiments/dwo.md). Nothing is fixed: the gauge is left to the damping of
//! Levenberg-Marquardt.
//!
//! Before optimising, keyframes that newly entered the double window are re-initialised along
//! the BFS spanning tree rooted at `V_ref` (thesis eq. 6.3), `T_j = T_j,parent·T_parent`, and
//! so are all their descendants, so that a loop that does not add up breaks in the periphery;
//! edges whose ends were both in the old inner window but not both in the new one get their
//! relative pose re-computed and are marked marginalised; edges with both ends in the new inner
//! window are un-marginalised; a few structure-only iterations localise the points before
//! the joint iterations.
//!
//! **Poses are similarities** ([`FixedScaleSim3`]): the optimiser updates them by rigid
//! increments `exp((v, ω, 0))·T`, so each keyframe keeps its scale. For stereo every scale is
//! 1 (an SE(3) optimisation); for monocular SLAM a scale other than 1 enters only through a
//! Sim(3) loop-closure constraint and the re-initialisation along the spanning tree (thesis
//! §6.2.7).
//!
//! **Threads** (see [`crate::map`]): [`DoubleWindowOptimiser::optimise_shared`] plans and
//! builds under a read lock, optimises with no lock held and writes back under a short write
//! lock.

use crate::factors::{
    AnchoredLinearization, AnchoredObservation, AnchoredPose, InverseDepthObservation, Projector,
    inverse_depth_to_point, linearize_anchored,
};
use crate::map::{BfsTree, GraphAccess, KeyframeId, PointId, SlamGraph, Version};
use lie::{LieGroup, LogJacobian, Sim3, log_jacobian_factors};
use lsq::{
    Factor, Information, Jacobians, Manifold, Problem, RobustKernel, SolverOptions, Values, Var,
    VarKey,
};
use nalgebra::{SVector, Vector3};
use std::collections::{BTreeMap, BTreeSet};
use std::time::{Duration, Instant};

/// A keyframe pose in the optimisation: a similarity updated by rigid increments
/// `T ← exp((v, ω, 0))·T` (6 degrees of freedom), so its scale stays fixed (thesis §6.2.7).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FixedScaleSim3(pub Sim3);

impl Manifold for FixedScaleSim3 {
    const DIM: usize = 6;
    const NAME: &'static str = "Sim(3) with fixed scale";
    fn retract(&mut self, delta: &[f64]) {
        let d = SVector::<f64, 7>::from_fn(|i, _| if i < 6 { delta[i] } else { 0.0 });
        self.0 = Sim3::exp(&d).compose(&self.0);
    }
    fn is_finite(&self) -> bool {
        LieGroup::<7>::is_finite(&self.0)
    }
}

impl AnchoredPose for FixedScaleSim3 {
    #[inline]
    fn linearize_observation<P: Projector<N>, const N: usize>(
        projector: &P,
        observer_from_world: &Self,
        anchor_from_world: &Self,
        psi: &Vector3<f64>,
    ) -> Option<AnchoredLinearization<N>> {
        linearize_anchored(projector, &observer_from_world.0, &anchor_from_world.0, psi)
    }
}

/// A pose-pose constraint of the outer window (thesis eq. 6.1): `v = log(T_ji·T_i·T_j⁻¹)^∨` in
/// the 7-dimensional tangent space of Sim(3), between two [`FixedScaleSim3`] poses (the
/// Jacobians are the first six columns of those of [`crate::pose_graph::BetweenFactor`]).
pub struct WindowBetween {
    /// `T_i`.
    pub from: Var<FixedScaleSim3>,
    /// `T_j`.
    pub to: Var<FixedScaleSim3>,
    /// The stored relative pose `T_ji` (frame `i` into frame `j`).
    pub measured: Sim3,
}

impl Factor for WindowBetween {
    fn residual_dim(&self) -> usize {
        7
    }

    fn variables(&self) -> Vec<VarKey> {
        vec![self.from.key(), self.to.key()]
    }

    fn evaluate(
        &self,
        values: &Values,
        residual: &mut [f64],
        jacobians: Option<&mut Jacobians<'_>>,
    ) -> bool {
        let t_i = values.get(self.from).0;
        let t_j = values.get(self.to).0;
        let d = self.measured.compose(&t_i).compose(&t_j.inverse()).log();
        residual.copy_from_slice(d.as_slice());
        if let Some(j) = jacobians {
            // BetweenFactor's ∂d/∂ε_i = M(d)·Ad_{T_ji}, ∂d/∂ε_j = −M(−d), rigid columns only.
            let (m_plus, m_minus) = log_jacobian_factors::<Sim3, 7>(&d, LogJacobian::Exact);
            if j.wants(0) {
                let full = m_plus * self.measured.adjoint();
                j.set(0, &full.fixed_columns::<6>(0).into_owned());
            }
            if j.wants(1) {
                j.set(1, &(-m_minus.fixed_columns::<6>(0)).into_owned());
            }
        }
        true
    }
}

/// How the information of a pose-pose constraint is computed.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum ConstraintInformation {
    /// Thesis eq. 6.2: diagonal, the rotation and translation precision of
    /// [`DwoParams::edge_precision`] times the weight of the edge's unrepresented points.
    Coarse,
    /// Pair-wise marginalisation: the Schur complement of the edge's unrepresented points
    /// (each observation weighted `2/k` like the coarse weight) on the pose of the edge's
    /// second keyframe with the first held, at the current estimate — the information those
    /// points give the relative pose (full 6×6; the fixed scale keeps the coarse precision).
    /// The default: measured closer to full BA than the coarse information (module docs).
    #[default]
    Marginal,
}

impl ConstraintInformation {
    /// Both kinds.
    pub const ALL: [ConstraintInformation; 2] = [
        ConstraintInformation::Coarse,
        ConstraintInformation::Marginal,
    ];

    /// A lower-case name.
    pub fn name(self) -> &'static str {
        match self {
            ConstraintInformation::Coarse => "coarse",
            ConstraintInformation::Marginal => "marginal",
        }
    }
}

/// Options of double window optimisation.
#[derive(Clone, Debug, PartialEq)]
pub struct DwoParams {
    /// `M1`, the size of the inner window (`usize::MAX`: every keyframe, i.e. full BA).
    pub inner: usize,
    /// `M2`, the size of the outer window (`usize::MAX`: everything else, gDWO).
    pub outer: usize,
    /// Levenberg-Marquardt iterations of the joint optimisation.
    pub iterations: usize,
    /// Structure-only iterations (poses held) before the joint ones.
    pub structure_iterations: usize,
    /// Hold the outer window's poses fixed (the "fixed periphery" variant of thesis §6.5.1).
    pub fix_outer: bool,
    /// Pixel noise σ of the measurements (information `I/σ²`).
    pub sigma: f64,
    /// Angular precision of one measured point, `f/σ` (1/rad): the scale of `λ_rot` and
    /// `λ_trans` of thesis eq. 6.2 (see [`DwoParams::new`]).
    pub angular_precision: f64,
    /// Stereo baseline in map units (0 for a monocular camera): the parallax a single
    /// keyframe has on its points.
    pub baseline: f64,
    /// Floor of the parallax, so that a constraint between keyframes without translation
    /// (monocular) still constrains them a little.
    pub min_parallax: f64,
    /// Robust kernel of the reprojection errors (in units of σ).
    pub kernel: Option<RobustKernel>,
    /// How the pose-pose constraints' information is computed.
    pub information: ConstraintInformation,
}

impl DwoParams {
    /// Windows `M1 = inner`, `M2 = outer` for a monocular camera of focal length `focal`
    /// (pixels) and pixel noise `sigma` (for stereo set [`DwoParams::baseline`], see
    /// [`DwoParams::with_baseline`]); three joint iterations (thesis §6.5.1) after two
    /// structure-only ones.
    ///
    /// **The coarse edge information** (thesis eq. 6.2), per shared point of an edge `ij`
    /// whose keyframe `V_j` sees its points at median depth `d̄`:
    ///
    /// `parallax = max(‖t_ji‖, baseline)/d̄`, `λ_rot = (f/σ)·parallax`, `λ_trans = λ_rot/d̄`.
    ///
    /// A diagonal information must stand for the *marginal* precision of each component, not
    /// the conditional one: a rotation `δθ` about an axis across the optical axis moves the
    /// points by `d̄·δθ` in the image plane, which a lateral translation `d̄·δθ` undoes, so the
    /// two are told apart only through the points' depths, known to `d̄²σ/(f·B)` from a
    /// baseline `B` (the stereo baseline, or the motion between the two keyframes). Over a
    /// lever arm of about `d̄` (the field of view is about 90°) this gives a rotation
    /// precision of `(f/σ)·B/d̄` per point, and translation precision `1/d̄` of it — λ_trans
    /// proportional to the parallax `B/d̄`, as the thesis prescribes. The thesis keeps
    /// `λ_rot` constant and gives no values; the conditional value `λ_rot = f/σ` (what one
    /// point would give if the translation were known) is `d̄/B` ≈ 40× too confident for
    /// stereo at 2 m with a 5 cm baseline and, measured on the simulated spiral, pulled the
    /// inner window towards stale relative poses (inner RMSE 2.8× BA's; docs/experiments/dwo.md).
    pub fn new(inner: usize, outer: usize, focal: f64, sigma: f64) -> Self {
        DwoParams {
            inner,
            outer,
            iterations: 3,
            structure_iterations: 2,
            fix_outer: false,
            sigma,
            angular_precision: focal / sigma,
            baseline: 0.0,
            min_parallax: 1e-3,
            kernel: None,
            information: ConstraintInformation::default(),
        }
    }

    /// The same with the stereo baseline `baseline` (map units).
    pub fn with_baseline(mut self, baseline: f64) -> Self {
        self.baseline = baseline;
        self
    }

    /// `(λ_trans², λ_rot²)` per shared point for a relative pose with translation
    /// `translation` (map units) between keyframes whose points lie at median depth `depth`.
    pub fn edge_precision(&self, translation: f64, depth: f64) -> (f64, f64) {
        let parallax = (translation.max(self.baseline) / depth).max(self.min_parallax);
        let lambda_rot = self.angular_precision * parallax;
        let lambda_trans = lambda_rot / depth;
        (lambda_trans * lambda_trans, lambda_rot * lambda_rot)
    }
}

/// The membership of the double window.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct DoubleWindow {
    /// `W1`.
    pub inner: BTreeSet<KeyframeId>,
    /// `W2` (including anchor keyframes added for the points of `W1`).
    pub outer: BTreeSet<KeyframeId>,
}

impl DoubleWindow {
    /// Whether `k` is in `W1 ∪ W2`.
    pub fn contains(&self, k: KeyframeId) -> bool {
        self.inner.contains(&k) || self.outer.contains(&k)
    }

    /// Number of keyframes in `W1 ∪ W2`.
    pub fn len(&self) -> usize {
        self.inner.len() + self.outer.len()
    }

    /// Whether the window is empty.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

/// A relative pose-pose constraint of the outer window.
#[derive(Clone, Debug, PartialEq)]
pub struct PoseConstraint {
    /// `i`.
    pub from: KeyframeId,
    /// `j`.
    pub to: KeyframeId,
    /// `T_ji`.
    pub relative: Sim3,
    /// Diagonal of `Λ_ji` (thesis eq. 6.2): translation, rotation, scale.
    pub information: [f64; 7],
    /// The points the constraint stands for (shared, not active) with their weights `2/k`.
    pub points: Vec<(PointId, f64)>,
}

/// Everything one double window optimisation does, decided from the graph before optimising
/// (thesis §6.2.3): the window, the re-initialised poses, the active points, the edge
/// (un-)marginalisations and the pose-pose constraints.
#[derive(Clone, Debug)]
pub struct DwoPlan {
    /// The graph's version when the plan was made: poses and points changed after it are
    /// newer than the optimisation's result (see [`DoubleWindowOptimiser::apply`]).
    pub version: Version,
    /// The reference keyframe.
    pub root: KeyframeId,
    /// The new double window.
    pub window: DoubleWindow,
    /// The BFS spanning tree over the window, rooted at the reference.
    pub tree: BfsTree,
    /// Initial poses of the window's keyframes (after re-initialisation, eq. 6.3).
    pub initial_poses: BTreeMap<KeyframeId, Sim3>,
    /// Keyframes re-initialised along the tree.
    pub reinitialised: Vec<KeyframeId>,
    /// Points optimised.
    pub points: Vec<PointId>,
    /// Edge updates `(a, b, T_ba or None)`: marginalisations and un-marginalisations.
    pub edge_updates: Vec<(KeyframeId, KeyframeId, Option<Sim3>)>,
    /// Pose-pose constraints.
    pub constraints: Vec<PoseConstraint>,
}

/// Counts and timings of one optimisation (thesis Figure 6.10(b)).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct DwoStats {
    /// Keyframes in `W1`.
    pub inner_frames: usize,
    /// Keyframes in `W2`.
    pub outer_frames: usize,
    /// Points optimised.
    pub points: usize,
    /// Point-pose constraints (observations).
    pub point_constraints: usize,
    /// Pose-pose constraints.
    pub pose_constraints: usize,
    /// Keyframes re-initialised.
    pub reinitialised: usize,
    /// Planning and problem construction.
    pub time_setup: Duration,
    /// Structure-only iterations.
    pub time_structure: Duration,
    /// Joint iterations.
    pub time_joint: Duration,
    /// Writing back.
    pub time_apply: Duration,
    /// Cost `½χ²` before and after.
    pub cost_before: f64,
    /// Cost after.
    pub cost_after: f64,
    /// What the write-back did.
    pub write_back: WriteBack,
}

/// What [`DoubleWindowOptimiser::apply`] wrote into the graph and what it had to leave out
/// because the graph changed since the plan (another thread) or a value was refused.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct WriteBack {
    /// Keyframe poses written.
    pub poses: usize,
    /// Keyframes of the window removed since the plan (nothing to write).
    pub removed_keyframes: usize,
    /// Points written.
    pub points: usize,
    /// Points removed, moved or re-anchored since the plan: their newer state is kept.
    pub superseded_points: usize,
    /// Points the optimisation drove to a non-positive or non-finite inverse depth: they keep
    /// their previous value (they are behind the anchor or at infinity).
    pub rejected_points: usize,
    /// Edge (un-)marginalisations written.
    pub edges: usize,
    /// Edges removed since the plan.
    pub removed_edges: usize,
}

impl DwoStats {
    /// Total time.
    pub fn total(&self) -> Duration {
        self.time_setup + self.time_structure + self.time_joint + self.time_apply
    }
}

/// Why an optimisation failed.
#[derive(Debug, thiserror::Error)]
pub enum DwoError {
    /// The graph has no reference keyframe.
    #[error("the SLAM graph has no reference keyframe")]
    NoReference,
    /// A graph operation failed.
    #[error(transparent)]
    Graph(#[from] crate::map::GraphError),
    /// The least-squares problem refused a factor.
    #[error(transparent)]
    Problem(#[from] lsq::ProblemError),
    /// The solver failed.
    #[error(transparent)]
    Solve(#[from] lsq::SolveError),
    /// The poses of these keyframes of the window changed between the plan and the
    /// write-back (a loop correction): the result, computed from their old poses, was not
    /// written and the graph is as the other writer left it; the next optimisation re-plans.
    #[error("the graph changed during the optimisation (poses of {} keyframes moved since the plan, e.g. {}); nothing was written", .keyframes.len(), .keyframes[0])]
    Superseded {
        /// The keyframes whose poses moved.
        keyframes: Vec<KeyframeId>,
    },
}

/// What [`DoubleWindowOptimiser::build`] needs of the graph beside the plan, copied out of it
/// ([`DoubleWindowOptimiser::inputs`]: under the read lock in a thread, so that the problem is
/// built and solved with no lock held): per active point, its inverse depth, anchor and
/// measurements by the window's keyframes; for the constraints' marginal information, their
/// points' inverse depths and anchors and those anchors' poses.
#[derive(Clone, Debug, Default)]
pub struct DwoInputs<const N: usize> {
    points: Vec<WindowPoint<N>>,
    constraint_points: BTreeMap<PointId, (Vector3<f64>, KeyframeId)>,
    anchor_poses: BTreeMap<KeyframeId, Sim3>,
}

/// An active point of the window as the problem needs it.
#[derive(Clone, Debug)]
struct WindowPoint<const N: usize> {
    id: PointId,
    inverse_depth: Vector3<f64>,
    anchor: KeyframeId,
    /// Its measurements by the window's keyframes, in id order.
    observations: Vec<(KeyframeId, SVector<f64, N>)>,
}

/// The least-squares problem of one double window optimisation, with its variables.
pub struct DwoProblem {
    /// The problem.
    pub problem: Problem,
    poses: BTreeMap<KeyframeId, Var<FixedScaleSim3>>,
    points: Vec<(PointId, Var<Vector3<f64>>)>,
    point_constraints: usize,
}

/// The double window optimiser: its parameters and the previous window (to know which
/// keyframes enter the window and which leave the inner window).
#[derive(Clone, Debug)]
pub struct DoubleWindowOptimiser {
    /// Parameters.
    pub params: DwoParams,
    /// The window of the previous optimisation.
    pub previous: DoubleWindow,
}

/// The median depth of the points seen from `k` (in its frame), or 1 if it sees none.
fn median_depth<const N: usize>(
    graph: &SlamGraph<N>,
    k: KeyframeId,
    poses: &BTreeMap<KeyframeId, Sim3>,
) -> f64 {
    let Some(kf) = graph.keyframe(k) else {
        return 1.0;
    };
    let pose = |id: KeyframeId| poses.get(&id).copied().or_else(|| graph.pose(id).ok());
    let Some(t_k) = pose(k) else { return 1.0 };
    let mut depths: Vec<f64> = kf
        .observations()
        .keys()
        .filter_map(|&p| {
            let pt = graph.point(p)?;
            let t_a = pose(pt.anchor())?;
            let x = t_k
                .compose(&t_a.inverse())
                .act(&inverse_depth_to_point(pt.inverse_depth()));
            (x.z > 0.0).then_some(x.z)
        })
        .collect();
    if depths.is_empty() {
        return 1.0;
    }
    let mid = depths.len() / 2;
    *depths.select_nth_unstable_by(mid, |a, b| a.total_cmp(b)).1
}

impl DoubleWindowOptimiser {
    /// An optimiser with an empty previous window.
    pub fn new(params: DwoParams) -> Self {
        DoubleWindowOptimiser {
            params,
            previous: DoubleWindow::default(),
        }
    }

    /// The optimisations that end a run, from the graph's poses as they are: the double
    /// window with every keyframe in the outer window (gDWO, thesis §6.5.1: the pose graph over
    /// the whole map spreads what the windows left, a loop closed in a window that the rest of
    /// the map did not follow), then a bundle adjustment of every keyframe and point.
    /// `params.iterations` each. "Every keyframe": every one the edges join to the reference
    /// (a map started after a loss and never merged is not among them; make a keyframe of the
    /// map to optimise the reference).
    ///
    /// Neither re-initialises a keyframe along the spanning tree, nor re-computes an edge's
    /// relative pose: every keyframe counts as in the previous outer window. Re-initialisation
    /// (thesis eq. 6.3) is for keyframes entering a window from outside; here it would chain
    /// every keyframe's pose from the reference through the edges' relative poses (stale where
    /// marginalised long ago), and re-computing the relative poses from the poses would take
    /// away what the pose graph measures. A bundle adjustment alone started from the chained
    /// poses (as the run's end did before) stayed in a trajectory broken where the edges
    /// disagreed with the map: the rendered building with windows of 3 / 10 keyframes went
    /// from 1.27 cm live to 70 cm, with steps of up to 2.7 m between neighbouring keyframes;
    /// now 0.41 cm (with the default windows 0.61 → 0.55 cm).
    pub fn finishing<const N: usize>(params: DwoParams, graph: &SlamGraph<N>) -> [Self; 2] {
        let every = DoubleWindow {
            inner: BTreeSet::new(),
            outer: graph.keyframes().map(|(k, _)| k).collect(),
        };
        [
            DoubleWindowOptimiser {
                params: DwoParams {
                    outer: usize::MAX,
                    ..params.clone()
                },
                previous: every.clone(),
            },
            DoubleWindowOptimiser {
                params: DwoParams {
                    inner: usize::MAX,
                    ..params
                },
                previous: every,
            },
        ]
    }

    /// Decides the window, re-initialisations, points, edge updates and constraints around the
    /// graph's reference keyframe (reads the graph only).
    pub fn plan<const N: usize>(&self, graph: &SlamGraph<N>) -> Result<DwoPlan, DwoError> {
        let root = graph.reference().ok_or(DwoError::NoReference)?;
        let p = &self.params;
        let total = p.inner.saturating_add(p.outer);
        let order = graph.weighted_bfs(root, total).order;
        let mut window = DoubleWindow::default();
        for (n, &k) in order.iter().enumerate() {
            if n < p.inner {
                window.inner.insert(k);
            } else {
                window.outer.insert(k);
            }
        }
        // Active points (thesis §6.2.4): visible from W1 and anchored in the double window, or
        // anchored at a keyframe with an edge to the observing inner keyframe (which then joins
        // W2).
        let mut points = BTreeSet::new();
        let mut extra_outer = BTreeSet::new();
        for &k in &window.inner {
            let kf = graph.keyframe(k).expect("visited keyframes exist");
            for &pid in kf.observations().keys() {
                if points.contains(&pid) {
                    continue;
                }
                let anchor = graph.point(pid).expect("observed points exist").anchor();
                if window.contains(anchor) || extra_outer.contains(&anchor) {
                    points.insert(pid);
                } else if graph.edge(k, anchor).is_some() {
                    points.insert(pid);
                    extra_outer.insert(anchor);
                }
            }
        }
        window.outer.extend(extra_outer);
        // The spanning tree over the window, rooted at the reference.
        let tree = graph.weighted_bfs_within(root, usize::MAX, |n| window.contains(n));
        // Re-initialisation (thesis eq. 6.3): keyframes new to the window and their descendants.
        let mut initial_poses = BTreeMap::new();
        let mut marked = BTreeSet::new();
        let mut reinitialised = Vec::new();
        for &k in &tree.order {
            let current = graph.pose(k)?;
            let pose = match tree.parent[&k] {
                Some(parent) if !self.previous.contains(k) || marked.contains(&parent) => {
                    marked.insert(k);
                    reinitialised.push(k);
                    graph
                        .relative_pose(parent, k)?
                        .compose(&initial_poses[&parent])
                }
                _ => current,
            };
            initial_poses.insert(k, pose);
        }
        // Edge updates: un-marginalise inside W1; re-compute the relative pose of edges that
        // leave W1.
        let mut edge_updates = Vec::new();
        for &a in &window.inner {
            for (&b, e) in graph.keyframe(a).expect("exists").edges() {
                if a < b && window.inner.contains(&b) && e.relative.is_some() {
                    edge_updates.push((a, b, None));
                }
            }
        }
        let pose_of = |k: KeyframeId| {
            initial_poses
                .get(&k)
                .copied()
                .map_or_else(|| graph.pose(k), Ok)
        };
        for &a in &self.previous.inner {
            let Some(kf) = graph.keyframe(a) else {
                continue;
            };
            for &b in kf.edges().keys() {
                if a < b
                    && self.previous.inner.contains(&b)
                    && !(window.inner.contains(&a) && window.inner.contains(&b))
                {
                    let t_ba = pose_of(b)?.compose(&pose_of(a)?.inverse());
                    edge_updates.push((a, b, Some(t_ba)));
                }
            }
        }
        let updated: BTreeMap<(KeyframeId, KeyframeId), Option<Sim3>> =
            edge_updates.iter().map(|&(a, b, t)| ((a, b), t)).collect();
        // Pose-pose constraints: edges of the double window with points that are not active.
        let mut depth_cache = BTreeMap::new();
        let mut constraints = Vec::new();
        let members: Vec<KeyframeId> = window.inner.iter().chain(&window.outer).copied().collect();
        for &a in &members {
            for (&b, e) in graph.keyframe(a).expect("exists").edges() {
                if a >= b
                    || !window.contains(b)
                    || (window.inner.contains(&a) && window.inner.contains(&b))
                {
                    continue;
                }
                // A pose-pose constraint stands for the points of the edge that are *not* in
                // the optimisation (it summarises them, as if they were marginalised): its
                // weight is the number of shared points that are not active. Edges with an
                // end in W1 share only active points (all points visible from W1 are), so,
                // like the edges inside W1, they are represented by the points themselves;
                // counting them twice would hold the keyframes at a stale relative pose.
                let (kf_a, kf_b) = (
                    graph.keyframe(a).expect("exists"),
                    graph.keyframe(b).expect("exists"),
                );
                // A point seen by `k` keyframes holds `k − 1` independent relative poses but is
                // shared by `k(k−1)/2` edges, so it counts `2/k` in each (thesis §6.2.3: a
                // landmark marginalised out of `k` frames is one hyper-edge, not `k(k−1)/2`
                // independent binary ones).
                let shared: Vec<(PointId, f64)> = kf_a
                    .observations()
                    .keys()
                    .filter(|pid| kf_b.observations().contains_key(pid) && !points.contains(pid))
                    .filter_map(|pid| {
                        let pt = graph.point(*pid)?;
                        Some((*pid, 2.0 / pt.observers().len().max(2) as f64))
                    })
                    .collect();
                let unrepresented: f64 = shared.iter().map(|(_, w)| w).sum();
                if unrepresented == 0.0 {
                    continue;
                }
                let relative = match updated.get(&(a, b)) {
                    Some(Some(t)) => *t,
                    _ => match e.relative {
                        Some(t) => t,
                        None => pose_of(b)?.compose(&pose_of(a)?.inverse()),
                    },
                };
                let depth = *depth_cache
                    .entry(b)
                    .or_insert_with(|| median_depth(graph, b, &initial_poses));
                let w = unrepresented;
                let (lt2, lr2) =
                    p.edge_precision(relative.translation().norm() / relative.scale(), depth);
                let (t2, r2) = (w * lt2, w * lr2);
                constraints.push(PoseConstraint {
                    from: a,
                    to: b,
                    relative,
                    information: [t2, t2, t2, r2, r2, r2, r2],
                    points: shared,
                });
            }
        }
        Ok(DwoPlan {
            version: graph.version(),
            root,
            window,
            tree,
            initial_poses,
            reinitialised,
            points: points.into_iter().collect(),
            edge_updates,
            constraints,
        })
    }

    /// Builds the least-squares problem of a plan (reads the graph only).
    /// What [`build`](Self::build) needs of `graph` for `plan`, copied out (reads the graph
    /// only).
    pub fn inputs<const N: usize>(
        &self,
        graph: &SlamGraph<N>,
        plan: &DwoPlan,
    ) -> Result<DwoInputs<N>, DwoError> {
        let mut points = Vec::with_capacity(plan.points.len());
        for &pid in &plan.points {
            let pt = graph
                .point(pid)
                .ok_or(crate::map::GraphError::UnknownPoint(pid))?;
            let observations = pt
                .observers()
                .iter()
                .filter(|o| plan.initial_poses.contains_key(o))
                .map(|&o| {
                    let z = graph.keyframe(o).expect("observer exists").observations()[&pid];
                    (o, z)
                })
                .collect();
            points.push(WindowPoint {
                id: pid,
                inverse_depth: *pt.inverse_depth(),
                anchor: pt.anchor(),
                observations,
            });
        }
        let mut constraint_points = BTreeMap::new();
        let mut anchor_poses = BTreeMap::new();
        if self.params.information == ConstraintInformation::Marginal {
            for c in &plan.constraints {
                for &(pid, _) in &c.points {
                    let Some(pt) = graph.point(pid) else { continue };
                    constraint_points.insert(pid, (*pt.inverse_depth(), pt.anchor()));
                    if !plan.initial_poses.contains_key(&pt.anchor())
                        && let Ok(t) = graph.pose(pt.anchor())
                    {
                        anchor_poses.insert(pt.anchor(), t);
                    }
                }
                for k in [c.from, c.to] {
                    if !plan.initial_poses.contains_key(&k)
                        && let Ok(t) = graph.pose(k)
                    {
                        anchor_poses.insert(k, t);
                    }
                }
            }
        }
        Ok(DwoInputs {
            points,
            constraint_points,
            anchor_poses,
        })
    }

    /// The least-squares problem of `plan` from its `inputs` (no graph access): the window's
    /// poses, the active points anchored in it and their measurements, the pose-pose
    /// constraints.
    pub fn build<P: Projector<N> + Clone, const N: usize>(
        &self,
        inputs: &DwoInputs<N>,
        plan: &DwoPlan,
        projector: &P,
    ) -> Result<DwoProblem, DwoError> {
        let mut problem = Problem::new();
        let poses: BTreeMap<KeyframeId, Var<FixedScaleSim3>> = plan
            .initial_poses
            .iter()
            .map(|(&k, t)| (k, problem.add_variable(FixedScaleSim3(*t))))
            .collect();
        let info = Information::Isotropic(self.params.sigma);
        let mut points = Vec::with_capacity(inputs.points.len());
        let mut point_constraints = 0;
        for pt in &inputs.points {
            let psi = problem.add_variable(pt.inverse_depth);
            points.push((pt.id, psi));
            for &(o, z) in &pt.observations {
                let observer = poses[&o];
                point_constraints += 1;
                if o == pt.anchor {
                    problem.add_factor(
                        InverseDepthObservation {
                            observer_from_anchor: None,
                            inverse_depth_point: psi,
                            measurement: z,
                            projector: projector.clone(),
                        },
                        info.clone(),
                        self.params.kernel,
                    )?;
                } else {
                    problem.add_factor(
                        AnchoredObservation {
                            observer_from_world: observer,
                            anchor_from_world: poses[&pt.anchor],
                            inverse_depth_point: psi,
                            measurement: z,
                            projector: projector.clone(),
                        },
                        info.clone(),
                        self.params.kernel,
                    )?;
                }
            }
        }
        for c in &plan.constraints {
            let information = match self.params.information {
                ConstraintInformation::Coarse => None,
                ConstraintInformation::Marginal => {
                    self.marginal_information(inputs, plan, c, projector)
                }
            }
            .unwrap_or_else(|| Information::Diagonal(c.information.to_vec()));
            problem.add_factor(
                WindowBetween {
                    from: poses[&c.from],
                    to: poses[&c.to],
                    measured: c.relative,
                },
                information,
                None,
            )?;
        }
        if self.params.fix_outer {
            for &k in &plan.window.outer {
                problem.set_fixed(poses[&k].key(), true);
            }
        }
        Ok(DwoProblem {
            problem,
            poses,
            points,
            point_constraints,
        })
    }

    /// [`ConstraintInformation::Marginal`] of a constraint `i → j`: with `T_i` held, each of
    /// its points `y` (world coordinates at the current estimate, observed in both keyframes,
    /// weight `w`) contributes `H_jj − H_jy·H_yy⁻¹·H_yj` from its two observations, where `H`
    /// is `w·JᵀJ/σ²` over the rigid left increment of `T_j` and the point (the Schur
    /// complement does not depend on how the point is parametrised). Near the stored relative
    /// pose `∂v/∂ε_j ≈ −I`, so this is the information of the residual's rigid part. `None`
    /// if a point cannot be projected or the result is not positive definite even with a
    /// small ridge (the coarse information is used then).
    fn marginal_information<P: Projector<N>, const N: usize>(
        &self,
        inputs: &DwoInputs<N>,
        plan: &DwoPlan,
        c: &PoseConstraint,
        projector: &P,
    ) -> Option<Information> {
        use nalgebra::{Matrix3, Matrix6, SMatrix};
        let pose = |k: KeyframeId| {
            plan.initial_poses
                .get(&k)
                .copied()
                .or_else(|| inputs.anchor_poses.get(&k).copied())
        };
        let (t_i, t_j) = (pose(c.from)?, pose(c.to)?);
        let inv_var = 1.0 / (self.params.sigma * self.params.sigma);
        let mut info = Matrix6::<f64>::zeros();
        for &(pid, w) in &c.points {
            let (psi, anchor) = inputs.constraint_points.get(&pid)?;
            let y = pose(*anchor)?
                .inverse()
                .act(&crate::factors::inverse_depth_to_point(psi));
            let mut h_yy = Matrix3::<f64>::zeros();
            let mut h_jy = SMatrix::<f64, 6, 3>::zeros();
            let mut h_jj = Matrix6::<f64>::zeros();
            for (t, is_j) in [(&t_i, false), (&t_j, true)] {
                let x = t.act(&y);
                let (_, dx) = projector.project(&x)?;
                let j_y = dx * t.rotation().matrix() * t.scale();
                h_yy += j_y.transpose() * j_y * (w * inv_var);
                if is_j {
                    // ∂x/∂(v, ω) of exp((v, ω, 0))·x at 0: [I | −[x]×].
                    let mut dxe = SMatrix::<f64, 3, 6>::zeros();
                    dxe.fixed_view_mut::<3, 3>(0, 0)
                        .copy_from(&Matrix3::identity());
                    dxe.fixed_view_mut::<3, 3>(0, 3)
                        .copy_from(&(-x.cross_matrix()));
                    let j_pose = dx * dxe;
                    h_jj += j_pose.transpose() * j_pose * (w * inv_var);
                    h_jy += j_pose.transpose() * j_y * (w * inv_var);
                }
            }
            let h_yy_inv = h_yy.try_inverse()?;
            info += h_jj - h_jy * h_yy_inv * h_jy.transpose();
        }
        // A few points constrain only some directions (one stereo point: three): a ridge of
        // 1e-6 of the largest diagonal entry keeps the information positive definite for the
        // whitening without adding information that matters.
        let info = 0.5 * (info + info.transpose());
        let ridge = 1e-6 * info.diagonal().max();
        let info = info + Matrix6::identity() * ridge;
        // Positive definite iff its Cholesky factorisation exists (an eigen-decomposition per
        // constraint was 2 % of a monocular double window run).
        if ridge.is_nan() || ridge <= 0.0 || info.cholesky().is_none() {
            return None;
        }
        let mut full = nalgebra::DMatrix::<f64>::zeros(7, 7);
        full.view_mut((0, 0), (6, 6)).copy_from(&info);
        full[(6, 6)] = c.information[6];
        Some(Information::Full(full))
    }

    /// Structure-only then joint iterations on a built problem (no graph access).
    pub fn solve(&self, dwo: &mut DwoProblem, stats: &mut DwoStats) -> Result<(), DwoError> {
        let options = |iterations| SolverOptions {
            max_iterations: iterations,
            threads: Some(1),
            function_tolerance: 0.0,
            gradient_tolerance: 0.0,
            parameter_tolerance: 0.0,
            ..SolverOptions::default()
        };
        let t = Instant::now();
        if self.params.structure_iterations > 0 && !dwo.points.is_empty() {
            let was_fixed: Vec<bool> = dwo
                .poses
                .values()
                .map(|v| dwo.problem.is_fixed(v.key()))
                .collect();
            for v in dwo.poses.values() {
                dwo.problem.set_fixed(v.key(), true);
            }
            let summary = dwo
                .problem
                .optimise(&options(self.params.structure_iterations))?;
            stats.cost_before = summary.initial_cost;
            for (v, fixed) in dwo.poses.values().zip(was_fixed) {
                dwo.problem.set_fixed(v.key(), fixed);
            }
        }
        stats.time_structure = t.elapsed();
        let t = Instant::now();
        if !dwo.points.is_empty() {
            dwo.problem.set_eliminated::<Vector3<f64>>(true);
        }
        let summary = dwo.problem.optimise(&options(self.params.iterations))?;
        if self.params.structure_iterations == 0 || dwo.points.is_empty() {
            stats.cost_before = summary.initial_cost;
        }
        stats.cost_after = summary.final_cost;
        stats.time_joint = t.elapsed();
        Ok(())
    }

    /// Writes the optimised poses and points and the edge updates back into the graph and
    /// remembers the window.
    ///
    /// The graph may have changed since [`plan`](Self::plan) (another thread held the lock
    /// meanwhile). If the pose of a keyframe of the window changed (a loop correction), the
    /// result is stale: nothing is written and the error is [`DwoError::Superseded`] (the next
    /// optimisation re-plans from the corrected graph). Otherwise keyframes removed meanwhile
    /// are skipped, points removed, moved or re-anchored meanwhile keep their newer state,
    /// points the optimisation pushed behind their anchor keep their old value, and edges
    /// removed meanwhile are skipped — each counted in the returned [`WriteBack`]. In a single
    /// thread (plan, build, solve, apply in a row) nothing is skipped.
    pub fn apply<const N: usize>(
        &mut self,
        graph: &mut SlamGraph<N>,
        plan: &DwoPlan,
        dwo: &DwoProblem,
    ) -> Result<WriteBack, DwoError> {
        let moved: Vec<KeyframeId> = dwo
            .poses
            .keys()
            .copied()
            .filter(|&k| {
                graph
                    .keyframe(k)
                    .is_some_and(|kf| kf.pose_version() > plan.version)
            })
            .collect();
        if !moved.is_empty() {
            return Err(DwoError::Superseded { keyframes: moved });
        }
        let mut report = WriteBack::default();
        for (&k, v) in &dwo.poses {
            match graph.set_pose(k, dwo.problem.value(*v).0) {
                Ok(()) => report.poses += 1,
                Err(_) => report.removed_keyframes += 1,
            }
        }
        for &(pid, v) in &dwo.points {
            if graph.point(pid).is_none_or(|p| p.version() > plan.version) {
                report.superseded_points += 1;
                continue;
            }
            match graph.set_inverse_depth(pid, *dwo.problem.value(v)) {
                Ok(()) => report.points += 1,
                Err(_) => report.rejected_points += 1,
            }
        }
        for &(a, b, t) in &plan.edge_updates {
            if graph.set_edge_relative(a, b, t) {
                report.edges += 1;
            } else {
                report.removed_edges += 1;
            }
        }
        self.previous = plan.window.clone();
        Ok(report)
    }

    fn stats(plan: &DwoPlan, dwo: &DwoProblem) -> DwoStats {
        DwoStats {
            inner_frames: plan.window.inner.len(),
            outer_frames: plan.window.outer.len(),
            points: dwo.points.len(),
            point_constraints: dwo.point_constraints,
            pose_constraints: plan.constraints.len(),
            reinitialised: plan.reinitialised.len(),
            ..DwoStats::default()
        }
    }

    /// One double window optimisation around the graph's reference keyframe: plans and copies
    /// its inputs under a read lock, builds and optimises with no lock held, writes back under a
    /// write lock (of a shared graph; a graph the caller owns is simply read and written, see
    /// [`GraphAccess`]). Between plan and write-back another thread may have changed the
    /// graph; [`apply`](Self::apply) keeps what it changed.
    pub fn optimise<P: Projector<N> + Clone, const N: usize>(
        &mut self,
        mut graph: impl GraphAccess<N>,
        projector: &P,
    ) -> Result<DwoStats, DwoError> {
        let t = Instant::now();
        let (plan, inputs) = {
            let g = graph.read();
            let plan = self.plan(&g)?;
            let inputs = self.inputs(&g, &plan)?;
            (plan, inputs)
        };
        let mut dwo = self.build(&inputs, &plan, projector)?;
        let mut stats = Self::stats(&plan, &dwo);
        stats.time_setup = t.elapsed();
        self.solve(&mut dwo, &mut stats)?;
        let t = Instant::now();
        stats.write_back = self.apply(&mut graph.write(), &plan, &dwo)?;
        stats.time_apply = t.elapsed();
        Ok(stats)
    }
}

#[cfg(test)]
mod tests;

#[cfg(test)]
mod graph_tests;
