//! Two-view geometry of a calibrated camera: the essential matrix by the normalised 8-point
//! algorithm, its decomposition into a relative pose with the cheirality check, triangulation,
//! and the robust relative pose by 8-point RANSAC used to bootstrap monocular SLAM (thesis §3.2.1
//! eq. 3.6–3.7, §3.5; Hartley & Zisserman 2004, §9.6, §11.2, §12).
//!
//! Points are *normalised image coordinates* `m = proj(x) = (x₁/x₃, x₂/x₃)` (pixels mapped
//! through `K⁻¹`, e.g. by [`crate::PinholeCamera::normalised_from_pixel`]), written
//! homogeneously `m̃ = (m₁, m₂, 1)`. For the relative pose `T_ba = (R, t)` (`x_b = R·x_a + t`)
//! the epipolar constraint (thesis eq. 3.7) is
//!
//! `m̃_bᵀ · E · m̃_a = 0`, `E = [t]×·R`.
//!
//! It is invariant to the scale of `t` (thesis Fig. 3.2): the translation is recovered with
//! unit length, and is undefined for `t = 0` (pure rotation), which shows as few points passing
//! the cheirality check and a small triangulation angle.

use crate::ransac::{Estimator, RansacConfig, RansacError, ransac};
use lie::{LieGroup, Se3, So3};
use nalgebra::{DMatrix, Matrix3, Rotation3, UnitQuaternion, Vector2, Vector3};

/// Why a two-view problem could not be solved.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum TwoViewError {
    /// Fewer correspondences than the solver needs (8 for the essential matrix, 4 for a
    /// homography).
    #[error("the solver needs at least {needed} correspondences, got {count}")]
    TooFewPoints {
        /// Number given.
        count: usize,
        /// Number needed.
        needed: usize,
    },
    /// The two point lists differ in length.
    #[error("{a} points in the first view but {b} in the second")]
    LengthMismatch {
        /// Points in view a.
        a: usize,
        /// Points in view b.
        b: usize,
    },
    /// A coordinate is not finite.
    #[error("correspondence {index} is not finite")]
    NotFinite {
        /// Its index.
        index: usize,
    },
    /// The points do not determine `E` (all coincident, or the null space of the constraint
    /// matrix is more than one-dimensional, e.g. too few distinct points).
    #[error("degenerate configuration: {0}")]
    Degenerate(&'static str),
    /// RANSAC failed.
    #[error(transparent)]
    Ransac(#[from] RansacError),
    /// No decomposition of `E` puts enough points in front of both cameras.
    #[error("no relative pose puts the points in front of both cameras ({in_front} of {total})")]
    Cheirality {
        /// Most points in front of both cameras over the four candidates.
        in_front: usize,
        /// Points tested.
        total: usize,
    },
    /// The rays of the two views are too close to parallel for a reliable structure: the
    /// median angle between them is below the required one (pure rotation or too short a
    /// baseline). A live system keeps tracking and tries again with a later frame.
    #[error(
        "too little parallax: median ray angle {:.2}°, need {:.2}°",
        median_parallax.to_degrees(),
        required.to_degrees()
    )]
    TooLittleParallax {
        /// The median parallax of the inliers (radians).
        median_parallax: f64,
        /// The required median parallax (radians).
        required: f64,
    },
    /// A configuration value is unusable (named in the message).
    #[error("invalid two-view configuration: {0}")]
    InvalidConfig(&'static str),
    /// Two candidate motions explain the correspondences almost equally well (the two-fold
    /// ambiguity of a homography seen from afar, or noise at a weak baseline): no choice is
    /// safe.
    #[error("ambiguous motion: the two best candidates triangulate {best} and {second} points")]
    Ambiguous {
        /// Well triangulated points of the best candidate.
        best: usize,
        /// Well triangulated points of the runner-up.
        second: usize,
    },
}

/// The similarity `T` of the plane (translation to the centroid, isotropic scaling to mean
/// distance `√2`) of Hartley's normalisation, as a 3×3 matrix on homogeneous points.
pub(crate) fn hartley_normalisation(points: &[Vector2<f64>]) -> Option<Matrix3<f64>> {
    let n = points.len() as f64;
    let c = points.iter().sum::<Vector2<f64>>() / n;
    let mean_dist = points.iter().map(|p| (p - c).norm()).sum::<f64>() / n;
    if mean_dist.is_nan() || mean_dist <= 1e-12 * (1.0 + c.norm()) {
        return None;
    }
    let s = std::f64::consts::SQRT_2 / mean_dist;
    Some(Matrix3::new(
        s,
        0.0,
        -s * c.x,
        0.0,
        s,
        -s * c.y,
        0.0,
        0.0,
        1.0,
    ))
}

/// The closest essential matrix (singular values `(1, 1, 0)`) to `m` in the Frobenius sense,
/// up to scale.
fn project_to_essential(m: &Matrix3<f64>) -> Matrix3<f64> {
    let svd = m.svd(true, true);
    let (u, v_t) = (svd.u.expect("requested"), svd.v_t.expect("requested"));
    let mut order = [0usize, 1, 2];
    order.sort_by(|&a, &b| svd.singular_values[b].total_cmp(&svd.singular_values[a]));
    let mut d = Matrix3::zeros();
    d[(order[0], order[0])] = 1.0;
    d[(order[1], order[1])] = 1.0;
    u * d * v_t
}

/// The essential matrix of at least 8 correspondences `m_a[i] ↔ m_b[i]` (normalised image
/// coordinates) by the normalised 8-point algorithm: Hartley's normalisation of each view, the
/// least-squares null vector of the constraint matrix `A·vec(Ê) = 0` by SVD, de-normalisation
/// `E = T_bᵀ·Ê·T_a`, and projection onto the essential matrices (singular values `(1, 1, 0)`).
pub fn essential_eight_point(
    m_a: &[Vector2<f64>],
    m_b: &[Vector2<f64>],
) -> Result<Matrix3<f64>, TwoViewError> {
    check_correspondences(m_a, m_b, 8)?;
    weighted_eight_point(m_a, m_b, None)
}

/// Checks that `m_a` and `m_b` pair up, hold at least `needed` correspondences and are finite.
pub(crate) fn check_correspondences(
    m_a: &[Vector2<f64>],
    m_b: &[Vector2<f64>],
    needed: usize,
) -> Result<(), TwoViewError> {
    if m_a.len() != m_b.len() {
        return Err(TwoViewError::LengthMismatch {
            a: m_a.len(),
            b: m_b.len(),
        });
    }
    if m_a.len() < needed {
        return Err(TwoViewError::TooFewPoints {
            count: m_a.len(),
            needed,
        });
    }
    for (index, (a, b)) in m_a.iter().zip(m_b).enumerate() {
        if !(a.iter().chain(b.iter()).all(|v| v.is_finite())) {
            return Err(TwoViewError::NotFinite { index });
        }
    }
    Ok(())
}

fn weighted_eight_point(
    m_a: &[Vector2<f64>],
    m_b: &[Vector2<f64>],
    weights: Option<&[f64]>,
) -> Result<Matrix3<f64>, TwoViewError> {
    let ta = hartley_normalisation(m_a).ok_or(TwoViewError::Degenerate("coincident points"))?;
    let tb = hartley_normalisation(m_b).ok_or(TwoViewError::Degenerate("coincident points"))?;
    // The weights are for the de-normalised constraint; scaling a row keeps its null space.
    let w_scale = weights.map(|w| w.iter().copied().fold(0.0_f64, f64::max));
    // At least 9 rows so that the SVD returns the full right singular basis.
    let rows = m_a.len().max(9);
    let mut a = DMatrix::<f64>::zeros(rows, 9);
    for (i, (pa, pb)) in m_a.iter().zip(m_b).enumerate() {
        let w = match (weights, w_scale) {
            (Some(w), Some(m)) if m > 0.0 => w[i] / m,
            _ => 1.0,
        };
        let xa = ta * Vector3::new(pa.x, pa.y, 1.0);
        let xb = tb * Vector3::new(pb.x, pb.y, 1.0);
        for r in 0..3 {
            for c in 0..3 {
                a[(i, 3 * r + c)] = w * xb[r] * xa[c];
            }
        }
    }
    let e_hat = null_matrix(a, "the epipolar constraints do not determine E")?;
    let e = tb.transpose() * e_hat * ta;
    Ok(project_to_essential(&e))
}

/// The least-squares null vector of a constraint matrix `a` (at least 9 rows, 9 columns: the
/// SVD then returns the full right singular basis) as a 3×3 matrix in row-major order, or
/// [`TwoViewError::Degenerate`] with `what` when the null space is not one-dimensional (the
/// second smallest singular value vanishes).
pub(crate) fn null_matrix(
    a: DMatrix<f64>,
    what: &'static str,
) -> Result<Matrix3<f64>, TwoViewError> {
    let svd = a.svd(false, true);
    let v_t = svd.v_t.expect("requested");
    let sv = &svd.singular_values;
    let mut order: Vec<usize> = (0..sv.len()).collect();
    order.sort_by(|&x, &y| sv[x].total_cmp(&sv[y]));
    if sv[order[1]] <= 1e-10 * sv[order[sv.len() - 1]] {
        return Err(TwoViewError::Degenerate(what));
    }
    let f = v_t.row(order[0]);
    Ok(Matrix3::new(
        f[0], f[1], f[2], f[3], f[4], f[5], f[6], f[7], f[8],
    ))
}

fn sampson_denominator(e: &Matrix3<f64>, m_a: &Vector2<f64>, m_b: &Vector2<f64>) -> f64 {
    let ea = e * Vector3::new(m_a.x, m_a.y, 1.0);
    let etb = e.transpose() * Vector3::new(m_b.x, m_b.y, 1.0);
    ea.x * ea.x + ea.y * ea.y + etb.x * etb.x + etb.y * etb.y
}

/// The Sampson distance of a correspondence to the epipolar constraint (first-order geometric
/// error, in normalised image units): `(m̃_bᵀEm̃_a)² / ((Em̃_a)₁² + (Em̃_a)₂² + (Eᵀm̃_b)₁² +
/// (Eᵀm̃_b)₂²)`, square-rooted.
pub fn sampson_distance(e: &Matrix3<f64>, m_a: &Vector2<f64>, m_b: &Vector2<f64>) -> f64 {
    let xa = Vector3::new(m_a.x, m_a.y, 1.0);
    let xb = Vector3::new(m_b.x, m_b.y, 1.0);
    let num = xb.dot(&(e * xa));
    let den = sampson_denominator(e, m_a, m_b);
    if den <= 0.0 {
        return if num == 0.0 { 0.0 } else { f64::INFINITY };
    }
    num.abs() / den.sqrt()
}

fn so3_from_matrix(m: &Matrix3<f64>) -> So3 {
    So3::from_unit_quaternion(UnitQuaternion::from_rotation_matrix(
        &Rotation3::from_matrix_unchecked(*m),
    ))
}

/// The four relative poses `T_ba = (R, t)` with `|t| = 1` whose `[t]×R` is `E` up to scale
/// (Hartley & Zisserman Result 9.19): `R ∈ {U·W·Vᵀ, U·Wᵀ·Vᵀ}`, `t = ±u₃`.
pub fn decompose_essential(e: &Matrix3<f64>) -> [Se3; 4] {
    let svd = e.svd(true, true);
    let (mut u, mut v_t) = (svd.u.expect("requested"), svd.v_t.expect("requested"));
    // Order so that the zero singular value is last.
    let smallest = (0..3)
        .min_by(|&a, &b| svd.singular_values[a].total_cmp(&svd.singular_values[b]))
        .expect("three values");
    if smallest != 2 {
        u.swap_columns(smallest, 2);
        v_t.swap_rows(smallest, 2);
    }
    if u.determinant() < 0.0 {
        u.column_mut(2).neg_mut();
    }
    if v_t.determinant() < 0.0 {
        v_t.row_mut(2).neg_mut();
    }
    let w = Matrix3::new(0.0, -1.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0);
    let r1 = so3_from_matrix(&(u * w * v_t));
    let r2 = so3_from_matrix(&(u * w.transpose() * v_t));
    let t: Vector3<f64> = u.column(2).into();
    [
        Se3::new(r1, t),
        Se3::new(r1, -t),
        Se3::new(r2, t),
        Se3::new(r2, -t),
    ]
}

/// Signed Sampson residuals `m̃_bᵀEm̃_a / √((Em̃_a)₁² + (Em̃_a)₂² + (Eᵀm̃_b)₁² + (Eᵀm̃_b)₂²)`.
fn sampson_residuals(
    e: &Matrix3<f64>,
    m_a: &[Vector2<f64>],
    m_b: &[Vector2<f64>],
    indices: &[usize],
    out: &mut Vec<f64>,
) {
    out.clear();
    for &i in indices {
        let num =
            Vector3::new(m_b[i].x, m_b[i].y, 1.0).dot(&(e * Vector3::new(m_a[i].x, m_a[i].y, 1.0)));
        let den = sampson_denominator(e, &m_a[i], &m_b[i]);
        out.push(if den > 0.0 { num / den.sqrt() } else { 0.0 });
    }
}

/// `[t]×·R` with the translation along `t_dir` perturbed by `α` in the plane orthogonal to it
/// and the rotation by `exp(ω)`: the 5-DoF essential manifold around `(R, t_dir)`.
fn essential_from(r: &So3, t_dir: &Vector3<f64>, delta: &[f64; 5]) -> (So3, Vector3<f64>) {
    let r = So3::exp(&Vector3::new(delta[0], delta[1], delta[2])).compose(r);
    let helper = if t_dir.x.abs() < 0.9 {
        Vector3::x()
    } else {
        Vector3::y()
    };
    let b1 = t_dir.cross(&helper).normalize();
    let b2 = t_dir.cross(&b1);
    let t = (t_dir + b1 * delta[3] + b2 * delta[4]).normalize();
    (r, t)
}

/// Refines an essential matrix by minimising the sum of squared Sampson distances of the given
/// correspondences over the 5-DoF essential manifold `E = [t]×·R`, `|t| = 1` (Levenberg-
/// Marquardt with central-difference Jacobians; updates `R ← exp(ω)·R`, `t ← normalise(t + Bα)`
/// with `B` a basis of the plane orthogonal to `t`). Unlike re-fitting the linear 8-point
/// algorithm, this keeps the essential constraint throughout, which matters for the nearly
/// planar scenes where the 8-point algorithm is ill-conditioned (Hartley & Zisserman §11.4–11.5).
/// `None` if there are fewer than 5 correspondences.
pub fn refine_essential(
    e: &Matrix3<f64>,
    m_a: &[Vector2<f64>],
    m_b: &[Vector2<f64>],
    indices: &[usize],
    iterations: usize,
) -> Option<Matrix3<f64>> {
    if indices.len() < 5 {
        return None;
    }
    let start = decompose_essential(e)[0];
    let (mut r, mut t) = (*start.rotation(), start.translation().normalize());
    let essential = |r: &So3, t: &Vector3<f64>| lie::skew(t) * r.rotation_matrix();
    let mut res = Vec::with_capacity(indices.len());
    sampson_residuals(&essential(&r, &t), m_a, m_b, indices, &mut res);
    let mut cost: f64 = res.iter().map(|v| v * v).sum();
    let n = indices.len();
    let mut jac = DMatrix::<f64>::zeros(n, 5);
    let (mut plus, mut minus) = (Vec::with_capacity(n), Vec::with_capacity(n));
    let mut lambda = 1e-3;
    let h = 1e-7;
    for _ in 0..iterations {
        for k in 0..5 {
            let mut d = [0.0; 5];
            d[k] = h;
            let (rp, tp) = essential_from(&r, &t, &d);
            d[k] = -h;
            let (rm, tm) = essential_from(&r, &t, &d);
            sampson_residuals(&essential(&rp, &tp), m_a, m_b, indices, &mut plus);
            sampson_residuals(&essential(&rm, &tm), m_a, m_b, indices, &mut minus);
            for i in 0..n {
                jac[(i, k)] = (plus[i] - minus[i]) / (2.0 * h);
            }
        }
        let jt = jac.transpose();
        let hess = &jt * &jac;
        let grad = &jt * nalgebra::DVector::from_column_slice(&res);
        let mut improved = false;
        while lambda < 1e10 {
            let mut damped = hess.clone();
            for k in 0..5 {
                damped[(k, k)] += lambda * hess[(k, k)].max(1e-12);
            }
            let Some(step) = damped.cholesky().map(|c| -c.solve(&grad)) else {
                lambda *= 10.0;
                continue;
            };
            let d = [step[0], step[1], step[2], step[3], step[4]];
            let (rn, tn) = essential_from(&r, &t, &d);
            sampson_residuals(&essential(&rn, &tn), m_a, m_b, indices, &mut plus);
            let c: f64 = plus.iter().map(|v| v * v).sum();
            if c < cost {
                let converged = cost - c <= 1e-10 * cost;
                (r, t, cost) = (rn, tn, c);
                std::mem::swap(&mut res, &mut plus);
                lambda = (lambda * 0.1).max(1e-12);
                improved = !converged;
                break;
            }
            lambda *= 10.0;
        }
        if !improved {
            break;
        }
    }
    Some(essential(&r, &t))
}

/// A triangulated correspondence.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Triangulated {
    /// The point in frame `a`.
    pub point_a: Vector3<f64>,
    /// Its depth in frame `a`.
    pub depth_a: f64,
    /// Its depth in frame `b`.
    pub depth_b: f64,
    /// The angle between the two viewing rays (radians): the parallax.
    pub parallax: f64,
}

/// Triangulates `m_a ↔ m_b` for the relative pose `b_from_a` by the midpoint method: the depths
/// `(d_a, d_b)` minimising `‖d_b·m̃_b − (R·d_a·m̃_a + t)‖²`, the point halfway between the two
/// closest ray points. `None` when the rays are (nearly) parallel.
pub fn triangulate(b_from_a: &Se3, m_a: &Vector2<f64>, m_b: &Vector2<f64>) -> Option<Triangulated> {
    let fa = b_from_a.rotation().act(&Vector3::new(m_a.x, m_a.y, 1.0));
    let fb = Vector3::new(m_b.x, m_b.y, 1.0);
    let t = b_from_a.translation();
    // Normal equations of [fa, −fb]·(d_a, d_b) = −t.
    let (aa, ab, bb) = (fa.dot(&fa), -fa.dot(&fb), fb.dot(&fb));
    let (ra, rb) = (-fa.dot(t), fb.dot(t));
    let det = aa * bb - ab * ab;
    let parallax = (fa.dot(&fb) / (fa.norm() * fb.norm()))
        .clamp(-1.0, 1.0)
        .acos();
    if det.is_nan() || det <= 1e-12 * aa * bb || !parallax.is_finite() {
        return None;
    }
    let da = (bb * ra - ab * rb) / det;
    let db = (aa * rb - ab * ra) / det;
    // Midpoint in frame b, then back to frame a.
    let mid_b = 0.5 * (fa * da + t + fb * db);
    let point_a = b_from_a.inverse().act(&mid_b);
    Some(Triangulated {
        point_a,
        depth_a: point_a.z,
        depth_b: mid_b.z,
        parallax,
    })
}

/// The candidate of [`decompose_essential`] that puts the most of the given correspondences in
/// front of both cameras (the cheirality check), with those correspondences' indices.
pub fn pose_from_essential(
    e: &Matrix3<f64>,
    m_a: &[Vector2<f64>],
    m_b: &[Vector2<f64>],
    indices: &[usize],
) -> Result<(Se3, Vec<usize>), TwoViewError> {
    let mut best: Option<(Se3, Vec<usize>)> = None;
    for cand in decompose_essential(e) {
        let in_front: Vec<usize> = indices
            .iter()
            .copied()
            .filter(|&i| {
                triangulate(&cand, &m_a[i], &m_b[i])
                    .is_some_and(|t| t.depth_a > 0.0 && t.depth_b > 0.0)
            })
            .collect();
        if best.as_ref().is_none_or(|b| in_front.len() > b.1.len()) {
            best = Some((cand, in_front));
        }
    }
    let (pose, in_front) = best.expect("four candidates");
    // At least half of the points must agree on one candidate.
    if in_front.len() < 8.max(indices.len() / 2) {
        return Err(TwoViewError::Cheirality {
            in_front: in_front.len(),
            total: indices.len(),
        });
    }
    Ok((pose, in_front))
}

/// The essential matrix as a RANSAC problem over normalised correspondences: minimal samples of
/// 8 by [`essential_eight_point`], inlier sets re-fitted by [`essential_sampson_refined`], error
/// the Sampson distance times `pixel_scale` (the focal length, so that the threshold is in
/// pixels).
#[derive(Clone, Copy, Debug)]
pub struct EssentialEstimator<'a> {
    /// Normalised points in view a.
    pub m_a: &'a [Vector2<f64>],
    /// Normalised points in view b.
    pub m_b: &'a [Vector2<f64>],
    /// Pixels per normalised unit (the focal length).
    pub pixel_scale: f64,
}

impl Estimator for EssentialEstimator<'_> {
    type Model = Matrix3<f64>;

    fn num_data(&self) -> usize {
        self.m_a.len().min(self.m_b.len())
    }

    fn sample_size(&self) -> usize {
        8
    }

    fn fit_minimal(&self, sample: &[usize], models: &mut Vec<Matrix3<f64>>) {
        let a: Vec<_> = sample.iter().map(|&i| self.m_a[i]).collect();
        let b: Vec<_> = sample.iter().map(|&i| self.m_b[i]).collect();
        if let Ok(e) = essential_eight_point(&a, &b) {
            models.push(e);
        }
    }

    /// Refines both `current` and the linear 8-point fit to the inliers with
    /// [`refine_essential`] and keeps the one with the smaller sum of squared Sampson distances
    /// over the inliers: a model from a minimal sample of noisy points can be far enough off
    /// that the local refinement from it stalls, while the linear fit to the whole inlier set
    /// starts near the optimum.
    fn fit_inliers(&self, inliers: &[usize], current: &Matrix3<f64>) -> Option<Matrix3<f64>> {
        let a: Vec<_> = inliers.iter().map(|&i| self.m_a[i]).collect();
        let b: Vec<_> = inliers.iter().map(|&i| self.m_b[i]).collect();
        let linear = essential_eight_point(&a, &b).ok();
        let cost = |e: &Matrix3<f64>| -> f64 {
            inliers
                .iter()
                .map(|&i| sampson_distance(e, &self.m_a[i], &self.m_b[i]).powi(2))
                .sum()
        };
        [Some(*current), linear]
            .into_iter()
            .flatten()
            .filter_map(|e| refine_essential(&e, self.m_a, self.m_b, inliers, 10))
            .map(|e| (cost(&e), e))
            .filter(|(c, _)| c.is_finite())
            .min_by(|x, y| x.0.total_cmp(&y.0))
            .map(|(_, e)| e)
    }

    fn error(&self, e: &Matrix3<f64>, i: usize) -> f64 {
        self.pixel_scale * sampson_distance(e, &self.m_a[i], &self.m_b[i])
    }
}

/// A relative pose from two views.
#[derive(Clone, Debug, PartialEq)]
pub struct RelativePose {
    /// `T_ba` with `|t| = 1` (the scale is not observable).
    pub b_from_a: Se3,
    /// The essential matrix.
    pub essential: Matrix3<f64>,
    /// Correspondences consistent with the epipolar geometry and in front of both cameras.
    pub inliers: Vec<usize>,
    /// The median parallax (radians) of the inliers' rays: small values mean a weak baseline.
    pub median_parallax: f64,
}

/// The relative pose of two calibrated views from correspondences with outliers: 8-point
/// RANSAC on the essential matrix (threshold in pixels through `pixel_scale`), then pose
/// recovery with the cheirality check on the RANSAC inliers (thesis §3.5).
pub fn relative_pose_ransac(
    m_a: &[Vector2<f64>],
    m_b: &[Vector2<f64>],
    pixel_scale: f64,
    config: &RansacConfig,
) -> Result<RelativePose, TwoViewError> {
    check_correspondences(m_a, m_b, 8)?;
    let est = EssentialEstimator {
        m_a,
        m_b,
        pixel_scale,
    };
    let r = ransac(&est, config)?;
    let (b_from_a, inliers) = pose_from_essential(&r.model, m_a, m_b, &r.inliers)?;
    let mut parallax: Vec<f64> = inliers
        .iter()
        .filter_map(|&i| triangulate(&b_from_a, &m_a[i], &m_b[i]).map(|t| t.parallax))
        .collect();
    parallax.sort_by(f64::total_cmp);
    let median_parallax = parallax.get(parallax.len() / 2).copied().unwrap_or(0.0);
    Ok(RelativePose {
        b_from_a,
        essential: r.model,
        inliers,
        median_parallax,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    fn scene(rng: &mut ChaCha8Rng, n: usize) -> Vec<Vector3<f64>> {
        (0..n)
            .map(|_| {
                Vector3::new(
                    rng.random_range(-2.0..2.0),
                    rng.random_range(-1.5..1.5),
                    rng.random_range(3.0..8.0),
                )
            })
            .collect()
    }

    fn proj(x: &Vector3<f64>) -> Vector2<f64> {
        Vector2::new(x.x / x.z, x.y / x.z)
    }

    fn relative(rng: &mut ChaCha8Rng) -> Se3 {
        let w = Vector3::new(
            rng.random_range(-0.1..0.1),
            rng.random_range(-0.1..0.1),
            rng.random_range(-0.1..0.1),
        );
        let t = Vector3::new(
            rng.random_range(-1.0..1.0),
            rng.random_range(-0.3..0.3),
            rng.random_range(-0.3..0.3),
        );
        Se3::new(So3::exp(&w), t)
    }

    fn same_direction(a: &Se3, b: &Se3) -> (f64, f64) {
        let rot = a.rotation().inverse().compose(b.rotation()).log().norm();
        let ta = a.translation().normalize();
        let tb = b.translation().normalize();
        (rot, (ta - tb).norm())
    }

    #[test]
    fn eight_point_satisfies_the_epipolar_constraint_and_recovers_the_pose() {
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        for _ in 0..20 {
            let t_ba = relative(&mut rng);
            let pts = scene(&mut rng, 30);
            let m_a: Vec<_> = pts.iter().map(proj).collect();
            let m_b: Vec<_> = pts.iter().map(|p| proj(&t_ba.act(p))).collect();
            let e = essential_eight_point(&m_a, &m_b).unwrap();
            for (a, b) in m_a.iter().zip(&m_b) {
                assert!(sampson_distance(&e, a, b) < 1e-9);
            }
            let all: Vec<usize> = (0..pts.len()).collect();
            let (pose, in_front) = pose_from_essential(&e, &m_a, &m_b, &all).unwrap();
            assert_eq!(in_front.len(), pts.len());
            let (rot, dir) = same_direction(&pose, &t_ba);
            assert!(rot < 1e-8 && dir < 1e-8, "{rot} {dir}");
            // Triangulation at the true scale recovers the points.
            for (i, p) in pts.iter().enumerate() {
                let tri = triangulate(&t_ba, &m_a[i], &m_b[i]).unwrap();
                assert!((tri.point_a - p).norm() < 1e-9);
            }
        }
    }

    #[test]
    fn eight_point_with_exactly_eight_points_and_degenerate_input() {
        let mut rng = ChaCha8Rng::seed_from_u64(2);
        let t_ba = relative(&mut rng);
        let pts = scene(&mut rng, 8);
        let m_a: Vec<_> = pts.iter().map(proj).collect();
        let m_b: Vec<_> = pts.iter().map(|p| proj(&t_ba.act(p))).collect();
        let e = essential_eight_point(&m_a, &m_b).unwrap();
        let (pose, _) = pose_from_essential(&e, &m_a, &m_b, &(0..8).collect::<Vec<_>>()).unwrap();
        let (rot, dir) = same_direction(&pose, &t_ba);
        assert!(rot < 1e-6 && dir < 1e-6);
        assert!(matches!(
            essential_eight_point(&m_a[..7], &m_b[..7]),
            Err(TwoViewError::TooFewPoints { count: 7, .. })
        ));
        let same = vec![Vector2::new(0.1, 0.2); 10];
        assert!(matches!(
            essential_eight_point(&same, &same),
            Err(TwoViewError::Degenerate(_))
        ));
        // Eight points with repeated correspondences: a rank-deficient system.
        let repeated: Vec<_> = (0..8).map(|i| m_a[i % 4]).collect();
        let repeated_b: Vec<_> = (0..8).map(|i| m_b[i % 4]).collect();
        assert!(essential_eight_point(&repeated, &repeated_b).is_err());
        let mut nan = m_a.clone();
        nan[3].x = f64::NAN;
        assert_eq!(
            essential_eight_point(&nan, &m_b),
            Err(TwoViewError::NotFinite { index: 3 })
        );
    }

    #[test]
    fn ransac_relative_pose_with_noise_and_outliers_is_seeded() {
        let f = 500.0;
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        for trial in 0..5 {
            let t_ba = relative(&mut rng);
            let pts = scene(&mut rng, 200);
            let noise = |rng: &mut ChaCha8Rng| {
                Vector2::new(rng.random_range(-0.5..0.5), rng.random_range(-0.5..0.5)) / f
            };
            let m_a: Vec<_> = pts.iter().map(|p| proj(p) + noise(&mut rng)).collect();
            let mut m_b: Vec<_> = pts
                .iter()
                .map(|p| proj(&t_ba.act(p)) + noise(&mut rng))
                .collect();
            // 30 % outliers.
            for m in m_b.iter_mut().step_by(3) {
                *m = Vector2::new(rng.random_range(-0.6..0.6), rng.random_range(-0.5..0.5));
            }
            let config = RansacConfig {
                threshold: 2.0,
                seed: trial,
                ..RansacConfig::default()
            };
            let r = relative_pose_ransac(&m_a, &m_b, f, &config).unwrap();
            let (rot, dir) = same_direction(&r.b_from_a, &t_ba);
            assert!(rot < 5e-3 && dir < 5e-2, "trial {trial}: {rot} {dir}");
            let good = (0..200).filter(|i| i % 3 != 0).collect::<Vec<_>>();
            let found_good = r.inliers.iter().filter(|i| *i % 3 != 0).count();
            assert!(found_good as f64 >= 0.95 * good.len() as f64);
            assert!(r.median_parallax > 0.01);
            let again = relative_pose_ransac(&m_a, &m_b, f, &config).unwrap();
            assert_eq!(r, again);
        }
    }

    #[test]
    fn parallel_rays_are_not_triangulated() {
        let t = Se3::from_translation(Vector3::new(1.0, 0.0, 0.0));
        assert!(triangulate(&t, &Vector2::new(0.0, 0.0), &Vector2::new(0.0, 0.0)).is_none());
        // Behind: depth negative is reported, not hidden.
        let tri = triangulate(&t, &Vector2::new(0.0, 0.0), &Vector2::new(-0.5, 0.0)).unwrap();
        assert!(tri.depth_a < 0.0);
    }
}
