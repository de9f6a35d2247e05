//! The Gauss-Newton information filter on anchored inverse-depth points (thesis §2.3.4,
//! §4.4.2, §4.5.2): the filter of the "why filter?" comparison.
//!
//! The state is the map `Φ` — inverse-depth points `ψ_j = (u, v, q)` (normalised image
//! coordinates and inverse depth in the anchor frame, thesis §3.4.4), each tied to an anchor
//! pose `T_a(j)` that is either the fixed origin or an anchor pose kept in the state — and the
//! current pose `T_i`. Its uncertainty is held as a dense information matrix `Λ` over
//! `(anchors, points, current)` in this order (6, 3 and 6 scalars per block).
//!
//! One time step (thesis Alg. 5):
//! 1. either the previous pose becomes an anchor ([`GaussNewtonFilter::current_to_anchor`]) and
//!    the points that left the view are marginalised and replaced by new ones anchored there
//!    ([`GaussNewtonFilter::marginalise_points`], [`GaussNewtonFilter::add_point`]), or the
//!    previous pose is marginalised ([`GaussNewtonFilter::marginalise_current`], eq. 4.25);
//! 2. the new pose is predicted from the map, by motion-only BA (eq. 4.15,
//!    [`GaussNewtonFilter::motion_only_ba`]) or from the Gaussian map prior (thesis Alg. 6,
//!    [`GaussNewtonFilter::motion_from_map_prior`]);
//! 3. the new pose enters with zero information (no motion prior, eq. 4.20,
//!    [`GaussNewtonFilter::begin_frame`]) and the joint estimate minimises
//!    `χ²(Φ_i, T_i) = (Φ_i ⊖ Φ_{i−1})ᵀ Λ_{Φ_{i−1}} (Φ_i ⊖ Φ_{i−1}) + Σ_j d_ijᵀ Λ_z d_ij`
//!    (eq. 4.18) by Levenberg-Marquardt ([`GaussNewtonFilter::optimise`]), with `⊖` the
//!    `SE(3)` difference `log(T·T₀⁻¹)` (eq. 4.19) on poses and subtraction on points;
//! 4. the information is updated at the new estimate, `Λ_i = Λ_{i−1} + Dᵀ Σ_z⁻¹ D` (eq. 4.21,
//!    thesis Alg. 4, [`GaussNewtonFilter::propagate`]).
//!
//! The cost is cubic in the number of points: every step factorises the dense `Λ`.

use super::motion::motion_only;
use lie::{LieGroup, Se3};
use lsq::dense::{SpdFactor, cholesky_solve_in_place, marginalise, spd_inverse};
use nalgebra::{DMatrix, DVector, SMatrix, SVector, Vector3, Vector6};
pub use slam::factors::InverseDepthCamera;
use slam::factors::{inverse_depth_to_point, linearize_anchored};
use std::collections::HashMap;

/// The anchor of a point: the filter's fixed origin, or an anchor pose in the state (named by
/// its frame number).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Anchor {
    /// The fixed origin pose of the filter (e.g. `T_0` for stereo, `T_b0` for monocular).
    Origin,
    /// The anchor pose of this frame.
    Frame(usize),
}

/// Why a filter operation failed.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum FilterError {
    /// The measurement does not give a valid inverse-depth point.
    #[error("point {0}: the measurement gives no valid inverse-depth point")]
    InvalidMeasurement(usize),
    /// A point id is used twice.
    #[error("point {0} is already in the filter")]
    DuplicatePoint(usize),
    /// The anchor frame is not in the state.
    #[error("anchor frame {0} is not in the filter state")]
    UnknownAnchor(usize),
    /// An operation needs a current pose, or a new frame needs the old one gone.
    #[error("{0}")]
    CurrentPose(&'static str),
    /// An information block to be marginalised or inverted is not positive definite.
    #[error("information matrix not positive definite ({0})")]
    NotPositiveDefinite(&'static str),
    /// Motion-only BA of a new pose failed.
    #[error(transparent)]
    Tracking(#[from] slam::tracking::TrackingError),
}

#[derive(Clone, Copy, Debug)]
struct AnchorState {
    frame: usize,
    camera_from_world: Se3,
}

#[derive(Clone, Copy, Debug)]
struct PointState {
    id: usize,
    psi: Vector3<f64>,
    anchor: Anchor,
    /// Whether the point's information is full rank on its own (stereo initialisation, or a
    /// monocular point after its first update); a monocular point fresh from eq. 4.26 has
    /// none in depth and no correlation with the rest of the state.
    has_depth: bool,
}

/// Levenberg-Marquardt settings of the joint update (eq. 4.18).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LmSettings {
    /// Maximum number of iterations (linear solves), e.g. 3 or 10 in thesis §4.6.1.
    pub iterations: usize,
    /// Initial damping `λ` of `(H + λ·diag(H))·δ = −g`.
    pub initial_lambda: f64,
    /// Stop when an accepted step reduces `χ²` by less than this fraction.
    pub function_tolerance: f64,
}

impl LmSettings {
    /// `iterations` with the damping and tolerance of `lsq::SolverOptions::default()`.
    pub fn with_iterations(iterations: usize) -> Self {
        LmSettings {
            iterations,
            initial_lambda: 1e-4,
            function_tolerance: 1e-6,
        }
    }
}

/// What one joint update did.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct UpdateSummary {
    /// `χ²` of eq. 4.18 before and after.
    pub initial_chi2: f64,
    /// `χ²` after.
    pub final_chi2: f64,
    /// Linear solves.
    pub iterations: usize,
    /// Accepted steps.
    pub accepted: usize,
    /// Observations whose prediction was undefined (ignored).
    pub invalid: usize,
}

/// The Gauss-Newton information filter over anchored inverse-depth points (module docs).
#[derive(Clone, Debug)]
pub struct GaussNewtonFilter<C, const N: usize> {
    camera: C,
    sigma: f64,
    origin_from_world: Se3,
    anchors: Vec<AnchorState>,
    points: Vec<PointState>,
    index: HashMap<usize, usize>,
    current: Option<(usize, Se3)>,
    info: DMatrix<f64>,
}

/// One observation's Jacobian blocks and residual `d = ẑ − z` (thesis Alg. 4).
struct Linearized<const N: usize> {
    point: usize,
    residual: SVector<f64, N>,
    d_current: SMatrix<f64, N, 6>,
    d_anchor: Option<(usize, SMatrix<f64, N, 6>)>,
    d_psi: SMatrix<f64, N, 3>,
}

impl<C: InverseDepthCamera<N>, const N: usize> GaussNewtonFilter<C, N> {
    /// An empty filter whose points may be anchored at the fixed `origin_from_world`, with
    /// isotropic pixel noise `sigma`.
    pub fn new(camera: C, sigma: f64, origin_from_world: Se3) -> Self {
        GaussNewtonFilter {
            camera,
            sigma,
            origin_from_world,
            anchors: Vec::new(),
            points: Vec::new(),
            index: HashMap::new(),
            current: None,
            info: DMatrix::zeros(0, 0),
        }
    }

    /// The camera.
    pub fn camera(&self) -> &C {
        &self.camera
    }

    /// The pixel noise σ.
    pub fn sigma(&self) -> f64 {
        self.sigma
    }

    /// The fixed origin pose.
    pub fn origin_from_world(&self) -> &Se3 {
        &self.origin_from_world
    }

    /// Number of points in the state.
    pub fn num_points(&self) -> usize {
        self.points.len()
    }

    /// Ids of the points in the state, in state order.
    pub fn point_ids(&self) -> Vec<usize> {
        self.points.iter().map(|p| p.id).collect()
    }

    /// Whether point `id` is in the state.
    pub fn contains(&self, id: usize) -> bool {
        self.index.contains_key(&id)
    }

    /// Frames of the anchor poses in the state.
    pub fn anchor_frames(&self) -> Vec<usize> {
        self.anchors.iter().map(|a| a.frame).collect()
    }

    /// `camera_from_world` of an anchor in the state, or of the origin.
    pub fn anchor_pose(&self, anchor: Anchor) -> Option<Se3> {
        match anchor {
            Anchor::Origin => Some(self.origin_from_world),
            Anchor::Frame(f) => self
                .anchors
                .iter()
                .find(|a| a.frame == f)
                .map(|a| a.camera_from_world),
        }
    }

    /// The current pose `(frame, camera_from_world)`, if one is in the state.
    pub fn current(&self) -> Option<(usize, Se3)> {
        self.current
    }

    /// Dimension of the state (and of [`information`](Self::information)).
    pub fn dim(&self) -> usize {
        6 * self.anchors.len() + 3 * self.points.len() + if self.current.is_some() { 6 } else { 0 }
    }

    /// The information matrix over `(anchors, points, current)`.
    pub fn information(&self) -> &DMatrix<f64> {
        &self.info
    }

    /// `ψ` and anchor of point `id`.
    pub fn inverse_depth_point(&self, id: usize) -> Option<(Vector3<f64>, Anchor)> {
        self.index
            .get(&id)
            .map(|&k| (self.points[k].psi, self.points[k].anchor))
    }

    /// Point `id` in world coordinates, `T_a⁻¹·Π(ψ)` (thesis §3.4.4); `None` if unknown or at
    /// infinity.
    pub fn point_world(&self, id: usize) -> Option<Vector3<f64>> {
        let p = &self.points[*self.index.get(&id)?];
        (p.psi.z > slam::factors::MIN_INVERSE_DEPTH).then(|| {
            self.anchor_pose(p.anchor)
                .expect("anchors of points are in the state")
                .inverse()
                .act(&inverse_depth_to_point(&p.psi))
        })
    }

    fn anchor_offset(&self, k: usize) -> usize {
        6 * k
    }

    fn point_offset(&self, k: usize) -> usize {
        6 * self.anchors.len() + 3 * k
    }

    fn current_offset(&self) -> usize {
        6 * self.anchors.len() + 3 * self.points.len()
    }

    fn anchor_index(&self, frame: usize) -> Option<usize> {
        self.anchors.iter().position(|a| a.frame == frame)
    }

    fn rebuild_index(&mut self) {
        self.index = self
            .points
            .iter()
            .enumerate()
            .map(|(k, p)| (p.id, k))
            .collect();
    }

    /// Adds point `id` measured `z` in its anchor frame, with its prior
    /// `Λ_ψ = (∂ẑ/∂ψ)ᵀ Σ_z⁻¹ (∂ẑ/∂ψ)` — for stereo exactly eq. 4.24, for a monocular camera
    /// `diag(f²/σ², f²/σ², 0)`, infinite depth uncertainty (eq. 4.26). The anchor must be the
    /// origin or an anchor in the state; monocular points start at inverse depth
    /// `default_inverse_depth`. The new point is uncorrelated with the rest of the state.
    pub fn add_point(
        &mut self,
        id: usize,
        z: &SVector<f64, N>,
        anchor: Anchor,
        default_inverse_depth: f64,
    ) -> Result<(), FilterError> {
        self.add_points(&[(id, *z)], anchor, default_inverse_depth)
    }

    /// [`add_point`](Self::add_point) for several points with one anchor, growing the
    /// information matrix once; all or none are added.
    pub fn add_points(
        &mut self,
        points: &[(usize, SVector<f64, N>)],
        anchor: Anchor,
        default_inverse_depth: f64,
    ) -> Result<(), FilterError> {
        if let Anchor::Frame(f) = anchor
            && self.anchor_index(f).is_none()
        {
            return Err(FilterError::UnknownAnchor(f));
        }
        let mut new = Vec::with_capacity(points.len());
        for (k, (id, z)) in points.iter().enumerate() {
            if self.index.contains_key(id) || points[..k].iter().any(|(i, _)| i == id) {
                return Err(FilterError::DuplicatePoint(*id));
            }
            let psi = self
                .camera
                .inverse_depth_from(z, default_inverse_depth)
                .filter(|p| {
                    p.iter().all(|x| x.is_finite()) && p.z > slam::factors::MIN_INVERSE_DEPTH
                })
                .ok_or(FilterError::InvalidMeasurement(*id))?;
            let lin = linearize_anchored(&self.camera, &Se3::identity(), &Se3::identity(), &psi)
                .ok_or(FilterError::InvalidMeasurement(*id))?;
            let j = lin.d_inverse_depth;
            let prior = j.transpose() * j / (self.sigma * self.sigma);
            let has_depth = prior.determinant() > 1e-12 * prior.trace().powi(3);
            new.push((*id, psi, prior, has_depth));
        }
        let at = self.current_offset();
        let k = 3 * new.len();
        let mut info = std::mem::replace(&mut self.info, DMatrix::zeros(0, 0))
            .insert_rows(at, k, 0.0)
            .insert_columns(at, k, 0.0);
        for (q, (id, psi, prior, has_depth)) in new.into_iter().enumerate() {
            info.fixed_view_mut::<3, 3>(at + 3 * q, at + 3 * q)
                .copy_from(&prior);
            self.points.push(PointState {
                id,
                psi,
                anchor,
                has_depth,
            });
            self.index.insert(id, self.points.len() - 1);
        }
        self.info = info;
        Ok(())
    }

    /// Adds the pose of a new frame with zero information (no motion prior, eq. 4.20). The
    /// previous current pose must have been marginalised or made an anchor.
    pub fn begin_frame(&mut self, frame: usize, camera_from_world: Se3) -> Result<(), FilterError> {
        if self.current.is_some() {
            return Err(FilterError::CurrentPose(
                "begin_frame: the previous pose is still in the state",
            ));
        }
        let n = self.info.nrows();
        self.info = std::mem::replace(&mut self.info, DMatrix::zeros(0, 0))
            .insert_rows(n, 6, 0.0)
            .insert_columns(n, 6, 0.0);
        self.current = Some((frame, camera_from_world));
        Ok(())
    }

    /// Marginalises the current pose out of the state (eq. 4.25).
    pub fn marginalise_current(&mut self) -> Result<(), FilterError> {
        if self.current.is_none() {
            return Err(FilterError::CurrentPose("no current pose to marginalise"));
        }
        let o = self.current_offset();
        let remove: Vec<usize> = (o..o + 6).collect();
        self.info = marginalise(&self.info, &remove)
            .ok_or(FilterError::NotPositiveDefinite("current pose"))?;
        self.current = None;
        Ok(())
    }

    /// Keeps the current pose as an anchor pose (thesis Alg. 5: "old pose is a new anchor
    /// pose"); it can then anchor new points.
    pub fn current_to_anchor(&mut self) -> Result<(), FilterError> {
        let (frame, pose) = self.current.ok_or(FilterError::CurrentPose(
            "no current pose to make an anchor",
        ))?;
        let a = 6 * self.anchors.len();
        let c = self.current_offset();
        let n = self.info.nrows();
        // New order: anchors, current (as the last anchor), points.
        let order: Vec<usize> = (0..a).chain(c..c + 6).chain(a..c).collect();
        debug_assert_eq!(order.len(), n);
        self.info = self.info.select_rows(&order).select_columns(&order);
        self.anchors.push(AnchorState {
            frame,
            camera_from_world: pose,
        });
        self.current = None;
        Ok(())
    }

    /// Marginalises the given points out of the state (ids not in the state are ignored).
    pub fn marginalise_points(&mut self, ids: &[usize]) -> Result<(), FilterError> {
        let mut remove_points: Vec<usize> = ids
            .iter()
            .filter_map(|id| self.index.get(id))
            .copied()
            .collect();
        if remove_points.is_empty() {
            return Ok(());
        }
        remove_points.sort_unstable();
        remove_points.dedup();
        let remove: Vec<usize> = remove_points
            .iter()
            .flat_map(|&k| {
                let o = self.point_offset(k);
                o..o + 3
            })
            .collect();
        self.info =
            marginalise(&self.info, &remove).ok_or(FilterError::NotPositiveDefinite("points"))?;
        let mut k = 0;
        self.points.retain(|_| {
            let keep = remove_points.binary_search(&k).is_err();
            k += 1;
            keep
        });
        self.rebuild_index();
        Ok(())
    }

    /// Marginalises anchor poses that no point uses any more.
    pub fn marginalise_unused_anchors(&mut self) -> Result<(), FilterError> {
        let unused: Vec<usize> = (0..self.anchors.len())
            .filter(|&k| {
                let f = self.anchors[k].frame;
                !self.points.iter().any(|p| p.anchor == Anchor::Frame(f))
            })
            .collect();
        if unused.is_empty() {
            return Ok(());
        }
        let remove: Vec<usize> = unused
            .iter()
            .flat_map(|&k| {
                let o = self.anchor_offset(k);
                o..o + 6
            })
            .collect();
        self.info =
            marginalise(&self.info, &remove).ok_or(FilterError::NotPositiveDefinite("anchors"))?;
        let mut k = 0;
        self.anchors.retain(|_| {
            let keep = !unused.contains(&k);
            k += 1;
            keep
        });
        Ok(())
    }

    /// Linearises the observations of the current pose at the current estimate (the blocks of
    /// thesis Alg. 4); undefined ones (unknown point, behind the camera) are skipped.
    fn linearize(&self, observations: &[(usize, SVector<f64, N>)], out: &mut Vec<Linearized<N>>) {
        out.clear();
        let Some((_, current)) = self.current else {
            return;
        };
        for (id, z) in observations {
            let Some(&k) = self.index.get(id) else {
                continue;
            };
            let p = &self.points[k];
            let (anchor_pose, anchor_state) = match p.anchor {
                Anchor::Origin => (self.origin_from_world, None),
                Anchor::Frame(f) => {
                    let a = self
                        .anchor_index(f)
                        .expect("anchors of points are in the state");
                    (self.anchors[a].camera_from_world, Some(a))
                }
            };
            let Some(lin) = linearize_anchored(&self.camera, &current, &anchor_pose, &p.psi) else {
                continue;
            };
            out.push(Linearized {
                point: k,
                residual: lin.predicted - z,
                d_current: lin.d_observer,
                d_anchor: anchor_state.map(|a| (a, lin.d_anchor)),
                d_psi: lin.d_inverse_depth,
            });
        }
    }

    /// `Σ_j d_jᵀ Λ_z d_j` at the current estimate and the number of undefined observations.
    fn data_chi2(&self, observations: &[(usize, SVector<f64, N>)]) -> (f64, usize) {
        let Some((_, current)) = self.current else {
            return (0.0, 0);
        };
        let w = 1.0 / (self.sigma * self.sigma);
        let mut chi2 = 0.0;
        let mut invalid = 0;
        for (id, z) in observations {
            let Some(&k) = self.index.get(id) else {
                continue;
            };
            let p = &self.points[k];
            let anchor = self.anchor_pose(p.anchor).expect("in state");
            match linearize_anchored(&self.camera, &current, &anchor, &p.psi) {
                Some(lin) => chi2 += (lin.predicted - z).norm_squared() * w,
                None => invalid += 1,
            }
        }
        (chi2, invalid)
    }

    /// The state difference `x ⊖ x₀` (eq. 4.19 on poses, subtraction on points).
    fn prior_error(&self, prior: &(Vec<Se3>, Vec<Vector3<f64>>, Option<Se3>)) -> DVector<f64> {
        let mut e = DVector::zeros(self.dim());
        for (k, a) in self.anchors.iter().enumerate() {
            let d = a.camera_from_world.compose(&prior.0[k].inverse()).log();
            e.rows_mut(self.anchor_offset(k), 6).copy_from(&d);
        }
        for (k, p) in self.points.iter().enumerate() {
            e.rows_mut(self.point_offset(k), 3)
                .copy_from(&(p.psi - prior.1[k]));
        }
        if let (Some((_, t)), Some(t0)) = (self.current, prior.2) {
            let o = self.current_offset();
            e.rows_mut(o, 6).copy_from(&t.compose(&t0.inverse()).log());
        }
        e
    }

    fn snapshot(&self) -> (Vec<Se3>, Vec<Vector3<f64>>, Option<Se3>) {
        (
            self.anchors.iter().map(|a| a.camera_from_world).collect(),
            self.points.iter().map(|p| p.psi).collect(),
            self.current.map(|c| c.1),
        )
    }

    fn restore(&mut self, s: &(Vec<Se3>, Vec<Vector3<f64>>, Option<Se3>)) {
        for (a, t) in self.anchors.iter_mut().zip(&s.0) {
            a.camera_from_world = *t;
        }
        for (p, psi) in self.points.iter_mut().zip(&s.1) {
            p.psi = *psi;
        }
        if let (Some(c), Some(t)) = (self.current.as_mut(), s.2) {
            c.1 = t;
        }
    }

    fn retract(&mut self, delta: &DVector<f64>) {
        for k in 0..self.anchors.len() {
            let d = Vector6::from_iterator(delta.rows(self.anchor_offset(k), 6).iter().copied());
            let a = &mut self.anchors[k];
            a.camera_from_world = Se3::exp(&d).compose(&a.camera_from_world);
        }
        for k in 0..self.points.len() {
            let o = self.point_offset(k);
            let d = Vector3::new(delta[o], delta[o + 1], delta[o + 2]);
            self.points[k].psi += d;
        }
        let o = self.current_offset();
        if let Some(c) = self.current.as_mut() {
            let d = Vector6::from_iterator(delta.rows(o, 6).iter().copied());
            c.1 = Se3::exp(&d).compose(&c.1);
        }
    }

    /// Adds `Σ JᵀΛ_zJ` of the linearised observations into `h` (and `JᵀΛ_z d` into `g`).
    fn accumulate(
        &self,
        lins: &[Linearized<N>],
        h: &mut DMatrix<f64>,
        mut g: Option<&mut DVector<f64>>,
    ) {
        let w = 1.0 / (self.sigma * self.sigma);
        let c = self.current_offset();
        for l in lins {
            let p = self.point_offset(l.point);
            let (jc, jp) = (&l.d_current, &l.d_psi);
            add_block(h, c, c, &(jc.transpose() * jc * w));
            let cp = jc.transpose() * jp * w;
            add_block(h, c, p, &cp);
            add_block(h, p, c, &cp.transpose());
            add_block(h, p, p, &(jp.transpose() * jp * w));
            if let Some((a, ja)) = &l.d_anchor {
                let ao = self.anchor_offset(*a);
                add_block(h, ao, ao, &(ja.transpose() * ja * w));
                let ap = ja.transpose() * jp * w;
                add_block(h, ao, p, &ap);
                add_block(h, p, ao, &ap.transpose());
                let ac = ja.transpose() * jc * w;
                add_block(h, ao, c, &ac);
                add_block(h, c, ao, &ac.transpose());
                if let Some(g) = g.as_deref_mut() {
                    let mut v = g.fixed_rows_mut::<6>(ao);
                    v += ja.transpose() * l.residual * w;
                }
            }
            if let Some(g) = g.as_deref_mut() {
                let mut v = g.fixed_rows_mut::<6>(c);
                v += jc.transpose() * l.residual * w;
                let mut v = g.fixed_rows_mut::<3>(p);
                v += jp.transpose() * l.residual * w;
            }
        }
    }

    /// The joint estimate of map and current pose (eq. 4.18) by Levenberg-Marquardt with
    /// Marquardt damping, starting from and regularised towards the current state; the
    /// information is not changed (see [`propagate`](Self::propagate)).
    pub fn optimise(
        &mut self,
        observations: &[(usize, SVector<f64, N>)],
        settings: &LmSettings,
    ) -> Result<UpdateSummary, FilterError> {
        if self.current.is_none() {
            return Err(FilterError::CurrentPose("optimise needs a current pose"));
        }
        let prior = self.snapshot();
        let n = self.dim();
        let cost = |f: &Self| -> (f64, usize) {
            let e = f.prior_error(&prior);
            let (d, invalid) = f.data_chi2(observations);
            ((&f.info * &e).dot(&e) + d, invalid)
        };
        let (mut chi2, mut invalid) = cost(self);
        let mut summary = UpdateSummary {
            initial_chi2: chi2,
            final_chi2: chi2,
            invalid,
            ..Default::default()
        };
        let mut lambda = settings.initial_lambda;
        let mut nu = 2.0;
        let mut lins = Vec::new();
        let mut h = DMatrix::zeros(n, n);
        let mut g = DVector::zeros(n);
        let mut relinearize = true;
        for _ in 0..settings.iterations {
            if relinearize {
                self.linearize(observations, &mut lins);
                let e = self.prior_error(&prior);
                h.copy_from(&self.info);
                g = &self.info * e;
                self.accumulate(&lins, &mut h, Some(&mut g));
                relinearize = false;
            }
            summary.iterations += 1;
            let mut a = h.clone();
            for i in 0..n {
                a[(i, i)] += lambda * h[(i, i)].clamp(1e-6, 1e32);
            }
            let mut delta = DMatrix::from_column_slice(n, 1, (-&g).as_slice());
            if !cholesky_solve_in_place(&a, &mut delta) {
                lambda *= nu;
                nu *= 2.0;
                continue;
            }
            let delta = DVector::from_column_slice(delta.as_slice());
            // Predicted decrease of χ² (= 2× the ½-cost model): −(2gᵀδ + δᵀHδ).
            let predicted = -(2.0 * g.dot(&delta) + (&h * &delta).dot(&delta));
            let saved = self.snapshot();
            self.retract(&delta);
            let (new_chi2, new_invalid) = cost(self);
            let gain = if predicted > 0.0 {
                (chi2 - new_chi2) / predicted
            } else {
                f64::NEG_INFINITY
            };
            if new_chi2.is_finite() && new_invalid <= invalid && gain > 1e-3 {
                let relative = (chi2 - new_chi2) / chi2.max(f64::MIN_POSITIVE);
                chi2 = new_chi2;
                invalid = new_invalid;
                summary.accepted += 1;
                lambda *= (1.0 - (2.0 * gain - 1.0).powi(3)).max(1.0 / 3.0);
                nu = 2.0;
                relinearize = true;
                if relative < settings.function_tolerance {
                    break;
                }
            } else {
                self.restore(&saved);
                lambda *= nu;
                nu *= 2.0;
            }
        }
        summary.final_chi2 = chi2;
        summary.invalid = invalid;
        Ok(summary)
    }

    /// Information update at the current estimate: `Λ ← Λ + Dᵀ Σ_z⁻¹ D` (eq. 4.21, thesis
    /// Alg. 4), `D` the Jacobian of the observations with respect to the current pose, the
    /// points and their anchors. Points observed get depth information.
    pub fn propagate(&mut self, observations: &[(usize, SVector<f64, N>)]) {
        let mut lins = Vec::new();
        self.linearize(observations, &mut lins);
        let mut info = std::mem::replace(&mut self.info, DMatrix::zeros(0, 0));
        self.accumulate(&lins, &mut info, None);
        self.info = info;
        for l in &lins {
            self.points[l.point].has_depth = true;
        }
    }

    /// The joint filter update: [`optimise`](Self::optimise) then
    /// [`propagate`](Self::propagate).
    pub fn update(
        &mut self,
        observations: &[(usize, SVector<f64, N>)],
        settings: &LmSettings,
    ) -> Result<UpdateSummary, FilterError> {
        let s = self.optimise(observations, settings)?;
        self.propagate(observations);
        Ok(s)
    }

    /// Scales the map and the poses in the state by `s` about the world origin (a similarity
    /// gauge change: points `y → s·y`, so `q → q/s`, and translations `t → s·t`); the origin
    /// must be the identity. Information of the points' inverse depths is rescaled
    /// accordingly is not attempted: call before [`propagate`](Self::propagate).
    fn scale(&mut self, s: f64) {
        for a in &mut self.anchors {
            *a.camera_from_world.translation_mut() *= s;
        }
        for p in &mut self.points {
            p.psi.z /= s;
        }
        if let Some(c) = self.current.as_mut() {
            *c.1.translation_mut() *= s;
        }
    }

    /// Rescales the state so that the current pose's translation has unit length and
    /// returns the factor applied; `None` for a zero translation or a non-identity origin.
    pub fn normalize_scale_to_current(&mut self) -> Option<f64> {
        let (_, t) = self.current?;
        let o = &self.origin_from_world;
        if o.log().norm() > 1e-12 {
            return None;
        }
        let len = t.translation().norm();
        (len > 1e-12 && len.is_finite()).then(|| {
            self.scale(1.0 / len);
            1.0 / len
        })
    }

    /// Replaces the current pose's 6-DoF information by that of the 5-DoF pose with unit
    /// translation `|t| = 1` and marginalises it out (thesis §4.5.3, bootstrapping): with
    /// `exp(ε)·T` and `ε = B·ξ`, `B = [[b₁ b₂ 0], [0 0 I₃]]` for an orthonormal basis `b₁, b₂` of
    /// `t^⊥` (to first order `|exp(ε)·t| = 1 ⇔ v ⊥ t`), `D₅ = D₆·B`, so the blocks become
    /// `Bᵀ·Λ_cc·B` and `Λ_xc·B`. The remaining map information has full rank and carries the
    /// scale prior `|t| = 1`.
    pub fn marginalise_current_unit_translation(&mut self) -> Result<(), FilterError> {
        let (_, t) = self
            .current
            .ok_or(FilterError::CurrentPose("no current pose to marginalise"))?;
        let dir = t.translation().normalize();
        let helper = if dir.x.abs() < 0.9 {
            Vector3::x()
        } else {
            Vector3::y()
        };
        let b1 = dir.cross(&helper).normalize();
        let b2 = dir.cross(&b1);
        let mut basis = SMatrix::<f64, 6, 5>::zeros();
        basis.fixed_view_mut::<3, 1>(0, 0).copy_from(&b1);
        basis.fixed_view_mut::<3, 1>(0, 1).copy_from(&b2);
        basis
            .fixed_view_mut::<3, 3>(3, 2)
            .copy_from(&nalgebra::Matrix3::identity());
        let n = self.info.nrows();
        let c = self.current_offset();
        // T = blockdiag(I, B): Λ₅ = Tᵀ·Λ·T.
        let mut tr = DMatrix::<f64>::zeros(n, n - 1);
        for i in 0..c {
            tr[(i, i)] = 1.0;
        }
        tr.view_mut((c, c), (6, 5)).copy_from(&basis);
        let reduced = tr.transpose() * &self.info * &tr;
        let remove: Vec<usize> = (c..c + 5).collect();
        self.info =
            marginalise(&reduced, &remove).ok_or(FilterError::NotPositiveDefinite("5-DoF pose"))?;
        self.current = None;
        Ok(())
    }

    /// The observations usable for pose estimation from the map: points with depth
    /// information, as Euclidean world points.
    fn map_observations(
        &self,
        observations: &[(usize, SVector<f64, N>)],
    ) -> Vec<(usize, SVector<f64, N>)> {
        observations
            .iter()
            .filter(|(id, _)| {
                self.index
                    .get(id)
                    .is_some_and(|&k| self.points[k].has_depth)
            })
            .copied()
            .collect()
    }

    /// Motion-only BA of a new pose against the map's mean (eq. 4.15): the observed points
    /// with depth information as fixed world points, `iterations` LM iterations from
    /// `initial` ([`motion_only`]: `initial` itself when no such point is observed).
    pub fn motion_only_ba(
        &self,
        observations: &[(usize, SVector<f64, N>)],
        initial: &Se3,
        iterations: usize,
    ) -> Result<Se3, FilterError> {
        let (points, measurements): (Vec<Vector3<f64>>, Vec<SVector<f64, N>>) = self
            .map_observations(observations)
            .iter()
            .filter_map(|(id, z)| self.point_world(*id).map(|y| (y, *z)))
            .unzip();
        Ok(motion_only(
            &self.camera,
            initial,
            &points,
            &measurements,
            self.sigma,
            iterations,
        )?)
    }

    /// Pose estimation given the Gaussian map prior `⟨Φ, Σ_Φ⟩` (thesis Alg. 6, Eade 2008):
    /// minimises `dᵀ S⁻¹ d` over the pose with `S = J_Φ Σ_Φ J_Φᵀ + Σ_z`, the innovation
    /// covariance, by Levenberg-damped Gauss-Newton. `exact = false` is the approximate
    /// version used in the thesis's experiments: `S` is computed and factorised once at
    /// `initial` (step 7 skipped). Only points with depth information are used (fresh
    /// monocular points have an infinite innovation covariance). Cubic in the number of points
    /// (`Σ_Φ = Λ_Φ⁻¹` and the factorisation of `S`). The map must have no current pose.
    pub fn motion_from_map_prior(
        &self,
        observations: &[(usize, SVector<f64, N>)],
        initial: &Se3,
        iterations: usize,
        exact: bool,
    ) -> Result<Se3, FilterError> {
        if self.current.is_some() {
            return Err(FilterError::CurrentPose(
                "motion_from_map_prior: marginalise the previous pose first",
            ));
        }
        let obs = self.map_observations(observations);
        if obs.is_empty() {
            return Ok(*initial);
        }
        // Σ over the anchors and the points with depth (fresh points are uncorrelated with
        // them, so this block of Λ⁻¹ is the inverse of this block of Λ).
        let mut sub: Vec<usize> = (0..6 * self.anchors.len()).collect();
        let mut sub_of_point = vec![usize::MAX; self.points.len()];
        for (k, p) in self.points.iter().enumerate() {
            if p.has_depth {
                sub_of_point[k] = sub.len();
                let o = self.point_offset(k);
                sub.extend(o..o + 3);
            }
        }
        let sigma_phi = spd_inverse(&self.info.select_rows(&sub).select_columns(&sub))
            .ok_or(FilterError::NotPositiveDefinite("map"))?;
        let m = sigma_phi.nrows();
        let rows = N * obs.len();
        let w = self.sigma * self.sigma;
        // J_Φ (dense rows × m; sparse in practice), J_T and d at a pose.
        // J_Φ is sparse: per observation a 3-column block at the point and, for a point
        // anchored in the state, a 6-column block at its anchor.
        type SparseRow<const N: usize> = (
            usize,
            SMatrix<f64, N, 3>,
            Option<(usize, SMatrix<f64, N, 6>)>,
        );
        let linearize_at = |t: &Se3| -> Option<(Vec<SparseRow<N>>, DMatrix<f64>, DVector<f64>)> {
            let mut j_phi = Vec::with_capacity(obs.len());
            let mut j_t = DMatrix::zeros(rows, 6);
            let mut d = DVector::zeros(rows);
            for (r, (id, z)) in obs.iter().enumerate() {
                let k = self.index[id];
                let p = &self.points[k];
                let anchor = self.anchor_pose(p.anchor).expect("in state");
                let lin = linearize_anchored(&self.camera, t, &anchor, &p.psi)?;
                let r0 = N * r;
                d.rows_mut(r0, N).copy_from(&(lin.predicted - z));
                j_t.view_mut((r0, 0), (N, 6)).copy_from(&lin.d_observer);
                let a = match p.anchor {
                    Anchor::Frame(f) => {
                        Some((6 * self.anchor_index(f).expect("in state"), lin.d_anchor))
                    }
                    Anchor::Origin => None,
                };
                j_phi.push((sub_of_point[k], lin.d_inverse_depth, a));
            }
            Some((j_phi, j_t, d))
        };
        // S = J_Φ Σ_Φ J_Φᵀ + Σ_z, through Y = Σ_Φ J_Φᵀ (m × rows).
        let innovation = |j_phi: &[SparseRow<N>]| -> DMatrix<f64> {
            let mut y = DMatrix::<f64>::zeros(m, rows);
            for (r, (so, jp, ja)) in j_phi.iter().enumerate() {
                let mut block = y.columns_mut(N * r, N);
                block.gemm(1.0, &sigma_phi.columns(*so, 3), &jp.transpose(), 0.0);
                if let Some((ao, ja)) = ja {
                    block.gemm(1.0, &sigma_phi.columns(*ao, 6), &ja.transpose(), 1.0);
                }
            }
            let mut s = DMatrix::<f64>::zeros(rows, rows);
            for (r, (so, jp, ja)) in j_phi.iter().enumerate() {
                let mut block = s.rows_mut(N * r, N);
                block.gemm(1.0, jp, &y.rows(*so, 3), 0.0);
                if let Some((ao, ja)) = ja {
                    block.gemm(1.0, ja, &y.rows(*ao, 6), 1.0);
                }
            }
            for i in 0..rows {
                s[(i, i)] += w;
            }
            s
        };
        // S⁻¹[J_T | d], and χ² = dᵀS⁻¹d from its last column.
        let solve = |s: &SpdFactor, j_t: &DMatrix<f64>, d: &DVector<f64>| {
            let mut rhs = DMatrix::zeros(rows, 7);
            rhs.view_mut((0, 0), (rows, 6)).copy_from(j_t);
            rhs.column_mut(6).copy_from(d);
            s.solve_in_place(&mut rhs).then_some(rhs)
        };
        let mut t = *initial;
        let Some((j_phi, mut j_t, d)) = linearize_at(&t) else {
            return Ok(t);
        };
        let mut s =
            SpdFactor::new(&innovation(&j_phi)).ok_or(FilterError::NotPositiveDefinite("S"))?;
        let mut sinv = solve(&s, &j_t, &d).ok_or(FilterError::NotPositiveDefinite("S"))?;
        let mut chi2 = d.dot(&sinv.column(6));
        let mut mu: Option<f64> = None;
        for _ in 0..iterations {
            let jts = j_t.transpose() * &sinv; // 6 × 7: [JᵀS⁻¹J | JᵀS⁻¹d]
            let a = jts.view((0, 0), (6, 6)).into_owned();
            let b = -jts.column(6).into_owned();
            let mu_now = *mu.get_or_insert(1e-4 * (a.trace() / 6.0).max(1e-12));
            let mut improved = false;
            let mut damping = mu_now;
            for _attempt in 0..10 {
                let mut ad = a.clone();
                for i in 0..6 {
                    ad[(i, i)] += damping;
                }
                let mut delta = DMatrix::from_column_slice(6, 1, b.as_slice());
                if !cholesky_solve_in_place(&ad, &mut delta) {
                    damping *= 10.0;
                    continue;
                }
                let t_new = Se3::exp(&Vector6::from_column_slice(delta.as_slice())).compose(&t);
                let Some((j_phi_new, j_t_new, d_new)) = linearize_at(&t_new) else {
                    damping *= 10.0;
                    continue;
                };
                let s_new = if exact {
                    match SpdFactor::new(&innovation(&j_phi_new)) {
                        Some(f) => Some(f),
                        None => {
                            damping *= 10.0;
                            continue;
                        }
                    }
                } else {
                    None
                };
                let Some(sinv_new) = solve(s_new.as_ref().unwrap_or(&s), &j_t_new, &d_new) else {
                    damping *= 10.0;
                    continue;
                };
                let chi2_new = d_new.dot(&sinv_new.column(6));
                if chi2_new < chi2 {
                    t = t_new;
                    chi2 = chi2_new;
                    j_t = j_t_new;
                    if let Some(f) = s_new {
                        s = f;
                    }
                    sinv = sinv_new;
                    improved = true;
                    break;
                }
                damping *= 10.0;
            }
            if !improved {
                break;
            }
            mu = Some(damping / 10.0);
        }
        Ok(t)
    }
}

/// `h[r.., c..] += m`.
#[inline]
fn add_block<const R: usize, const C: usize>(
    h: &mut DMatrix<f64>,
    r: usize,
    c: usize,
    m: &SMatrix<f64, R, C>,
) {
    let mut v = h.fixed_view_mut::<R, C>(r, c);
    v += m;
}
