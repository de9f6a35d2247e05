//! The homography between two views of a plane (or of any scene under a pure rotation): its
//! estimation by the normalised DLT, its errors, RANSAC over it, and its decomposition into the
//! candidate motions (Hartley & Zisserman 2004, ch. 4 and §13.1; Ma, Soatto, Košecká & Sastry
//! 2004, §5.3).
//!
//! Points are normalised image coordinates as in [`crate::two_view`], homogeneous
//! `m̃ = (m₁, m₂, 1)`. For the relative pose `T_ba = (R, t)` (`x_b = R·x_a + t`) and a plane
//! `nᵀ·x_a = d` (`|n| = 1`, `d > 0` its distance from camera a) every point of the plane obeys
//! `x_b = (R + t·nᵀ/d)·x_a`, so its images satisfy
//!
//! `λ·m̃_b = H·m̃_a`, `H = R + (t/d)·nᵀ` (H&Z eq. 13.2, the "Euclidean homography"),
//!
//! with `λ = z_b/z_a > 0`. A pure rotation gives `H = R` for every scene, which is why the
//! homography is also the right model when the baseline is too short for the epipolar geometry.

use crate::ransac::Estimator;
use crate::two_view::{TwoViewError, check_correspondences, hartley_normalisation, null_matrix};
use lie::{Se3, So3};
use nalgebra::{DMatrix, Matrix2, Matrix3, Rotation3, UnitQuaternion, Vector2, Vector3};

/// A homography with its inverse, `m̃_b ∝ H·m̃_a` and `m̃_a ∝ H⁻¹·m̃_b`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Homography {
    /// `H`, mapping view a to view b, scaled so that its middle singular value is 1 and signed so
    /// that `(H·m̃_a)₃ > 0` for most of the points it was fitted to (then `H = R + (t/d)·nᵀ`
    /// exactly, Ma et al. 2004 Lemma 5.18).
    pub b_from_a: Matrix3<f64>,
    /// `H⁻¹`, mapping view b to view a.
    pub a_from_b: Matrix3<f64>,
}

impl Homography {
    /// Normalises `h` (middle singular value 1, the sign making `(H·m̃_a)₃ > 0` for most of
    /// `m_a`), and inverts it. `None` if `h` is singular or not finite.
    pub fn new(h: &Matrix3<f64>, m_a: &[Vector2<f64>]) -> Option<Homography> {
        if !h.iter().all(|v| v.is_finite()) {
            return None;
        }
        let mut sv: Vec<f64> = h.singular_values().iter().copied().collect();
        sv.sort_by(f64::total_cmp);
        // Exactly or numerically singular: no inverse transfer.
        if sv[0] <= 1e-12 * sv[2] {
            return None;
        }
        let positive = m_a
            .iter()
            .filter(|m| (h * Vector3::new(m.x, m.y, 1.0)).z > 0.0)
            .count();
        let sign = if 2 * positive >= m_a.len() { 1.0 } else { -1.0 };
        let b_from_a = h * (sign / sv[1]);
        let a_from_b = b_from_a.try_inverse()?;
        Some(Homography { b_from_a, a_from_b })
    }

    /// `H·m̃_a` de-homogenised: where `m_a` maps to in view b (`None` at infinity).
    pub fn transfer(&self, m_a: &Vector2<f64>) -> Option<Vector2<f64>> {
        dehomogenise(&(self.b_from_a * Vector3::new(m_a.x, m_a.y, 1.0)))
    }

    /// `H⁻¹·m̃_b` de-homogenised: where `m_b` maps to in view a (`None` at infinity).
    pub fn transfer_back(&self, m_b: &Vector2<f64>) -> Option<Vector2<f64>> {
        dehomogenise(&(self.a_from_b * Vector3::new(m_b.x, m_b.y, 1.0)))
    }

    /// The squared transfer distances `(d(m_a, H⁻¹m_b)², d(m_b, H·m_a)²)` in normalised units,
    /// `∞` where a point maps to infinity.
    pub fn transfer_distances_sq(&self, m_a: &Vector2<f64>, m_b: &Vector2<f64>) -> (f64, f64) {
        let da = self
            .transfer_back(m_b)
            .map_or(f64::INFINITY, |p| (p - m_a).norm_squared());
        let db = self
            .transfer(m_a)
            .map_or(f64::INFINITY, |p| (p - m_b).norm_squared());
        (da, db)
    }

    /// The symmetric transfer error `d(m_a, H⁻¹m_b)² + d(m_b, H·m_a)²` (H&Z eq. 4.7), in squared
    /// normalised units.
    pub fn symmetric_transfer_error(&self, m_a: &Vector2<f64>, m_b: &Vector2<f64>) -> f64 {
        let (da, db) = self.transfer_distances_sq(m_a, m_b);
        da + db
    }

    /// The Sampson distance of `m_a ↔ m_b` to the homography (H&Z §4.2.6): the first-order
    /// distance in the joint image space `(m_a, m_b) ∈ ℝ⁴` to the 2-dimensional variety
    /// `m̃_b ∝ H·m̃_a`, `√(εᵀ(JJᵀ)⁻¹ε)` with `ε = (p₁ − m_b₁·p₃, p₂ − m_b₂·p₃)`, `p = H·m̃_a`,
    /// and `J = ∂ε/∂(m_a, m_b)` (2×4). Exact for an affine `H`; the distance that is
    /// comparable to the Sampson distance of the epipolar constraint
    /// ([`crate::two_view::sampson_distance`]), which [`crate::bootstrap`] needs to compare the
    /// two models.
    pub fn sampson_distance(&self, m_a: &Vector2<f64>, m_b: &Vector2<f64>) -> f64 {
        let h = &self.b_from_a;
        let p = h * Vector3::new(m_a.x, m_a.y, 1.0);
        let eps = Vector2::new(p.x - m_b.x * p.z, p.y - m_b.y * p.z);
        // Rows of J: ∂ε₁/∂(a₁, a₂, b₁, b₂) = (h₁₁ − b₁h₃₁, h₁₂ − b₁h₃₂, −p₃, 0), likewise ε₂.
        let j1 = [h[(0, 0)] - m_b.x * h[(2, 0)], h[(0, 1)] - m_b.x * h[(2, 1)]];
        let j2 = [h[(1, 0)] - m_b.y * h[(2, 0)], h[(1, 1)] - m_b.y * h[(2, 1)]];
        let p3sq = p.z * p.z;
        let jjt = Matrix2::new(
            j1[0] * j1[0] + j1[1] * j1[1] + p3sq,
            j1[0] * j2[0] + j1[1] * j2[1],
            j1[0] * j2[0] + j1[1] * j2[1],
            j2[0] * j2[0] + j2[1] * j2[1] + p3sq,
        );
        match jjt.try_inverse() {
            Some(inv) => eps.dot(&(inv * eps)).max(0.0).sqrt(),
            None if eps.norm_squared() == 0.0 => 0.0,
            None => f64::INFINITY,
        }
    }
}

fn dehomogenise(p: &Vector3<f64>) -> Option<Vector2<f64>> {
    (p.z.abs() > 1e-15 * (p.x.abs() + p.y.abs())).then(|| Vector2::new(p.x / p.z, p.y / p.z))
}

/// The homography of at least 4 correspondences `m_a[i] ↔ m_b[i]` by the normalised direct
/// linear transform (H&Z Algorithm 4.2): Hartley's normalisation `T_a`, `T_b` of each view,
/// the two rows `[0ᵀ, −x̂_aᵀ, v̂_b·x̂_aᵀ; x̂_aᵀ, 0ᵀ, −û_b·x̂_aᵀ]` per correspondence (H&Z
/// eq. 4.3), the least-squares null vector of the stacked system by SVD, and de-normalisation
/// `H = T_b⁻¹·Ĥ·T_a`. [`TwoViewError::Degenerate`] if the null space is not one-dimensional
/// (e.g. three of four points collinear) or `H` is singular.
pub fn homography_dlt(
    m_a: &[Vector2<f64>],
    m_b: &[Vector2<f64>],
) -> Result<Homography, TwoViewError> {
    check_correspondences(m_a, m_b, 4)?;
    let ta = hartley_normalisation(m_a).ok_or(TwoViewError::Degenerate("coincident points"))?;
    let tb = hartley_normalisation(m_b).ok_or(TwoViewError::Degenerate("coincident points"))?;
    // At least 9 rows so that the SVD returns the full right singular basis.
    let rows = (2 * m_a.len()).max(9);
    let mut a = DMatrix::<f64>::zeros(rows, 9);
    for (i, (pa, pb)) in m_a.iter().zip(m_b).enumerate() {
        let xa = ta * Vector3::new(pa.x, pa.y, 1.0);
        let xb = tb * Vector3::new(pb.x, pb.y, 1.0);
        for c in 0..3 {
            a[(2 * i, 3 + c)] = -xb.z * xa[c];
            a[(2 * i, 6 + c)] = xb.y * xa[c];
            a[(2 * i + 1, c)] = xb.z * xa[c];
            a[(2 * i + 1, 6 + c)] = -xb.x * xa[c];
        }
    }
    let h_hat = null_matrix(a, "the point transfers do not determine H")?;
    let tb_inv = tb
        .try_inverse()
        .ok_or(TwoViewError::Degenerate("coincident points"))?;
    Homography::new(&(tb_inv * h_hat * ta), m_a).ok_or(TwoViewError::Degenerate("singular H"))
}

/// The homography as a RANSAC problem over normalised correspondences: minimal samples of 4 by
/// [`homography_dlt`], inlier sets re-fitted by the same DLT, error the root mean square of the
/// two transfer distances in pixels, `pixel_scale·√(½(d(m_a, H⁻¹m_b)² + d(m_b, H·m_a)²))`.
/// With noise `σ` (pixels, per coordinate) in both views and `H` near a similarity of scale
/// `≈ 1` (small motion), each transfer residual has covariance `≈ 2σ²·I`, so the squared error
/// over `2σ²` is `≈ χ²₂`: a threshold `σ·√(2·χ²₂(p))` keeps a fraction `p` of the inliers.
#[derive(Clone, Copy, Debug)]
pub struct HomographyEstimator<'a> {
    /// Normalised points in view a.
    pub m_a: &'a [Vector2<f64>],
    /// Normalised points in view b.
    pub m_b: &'a [Vector2<f64>],
    /// Pixels per normalised unit (the focal length).
    pub pixel_scale: f64,
}

impl HomographyEstimator<'_> {
    fn fit(&self, indices: &[usize]) -> Option<Homography> {
        let a: Vec<_> = indices.iter().map(|&i| self.m_a[i]).collect();
        let b: Vec<_> = indices.iter().map(|&i| self.m_b[i]).collect();
        homography_dlt(&a, &b).ok()
    }
}

impl Estimator for HomographyEstimator<'_> {
    type Model = Homography;

    fn num_data(&self) -> usize {
        self.m_a.len().min(self.m_b.len())
    }

    fn sample_size(&self) -> usize {
        4
    }

    fn fit_minimal(&self, sample: &[usize], models: &mut Vec<Homography>) {
        models.extend(self.fit(sample));
    }

    fn fit_inliers(&self, inliers: &[usize], _current: &Homography) -> Option<Homography> {
        self.fit(inliers)
    }

    fn error(&self, h: &Homography, i: usize) -> f64 {
        self.pixel_scale * (0.5 * h.symmetric_transfer_error(&self.m_a[i], &self.m_b[i])).sqrt()
    }
}

/// One motion that explains a homography: `H = R + (t/d)·nᵀ`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HomographyMotion {
    /// `T_ba = (R, t/d)`: the translation in units of the plane's distance `d` from camera a.
    pub b_from_a: Se3,
    /// The plane's unit normal `n` in frame a (`nᵀ·x_a = d` on the plane).
    pub normal_a: Vector3<f64>,
}

/// The closest rotation to `m` in the Frobenius sense (`U·diag(1, 1, det(UVᵀ))·Vᵀ`).
fn closest_rotation(m: &Matrix3<f64>) -> So3 {
    let svd = m.svd(true, true);
    let (u, v_t) = (svd.u.expect("requested"), svd.v_t.expect("requested"));
    let mut d = Matrix3::identity();
    d[(2, 2)] = (u * v_t).determinant().signum();
    So3::from_unit_quaternion(UnitQuaternion::from_rotation_matrix(
        &Rotation3::from_matrix_unchecked(u * d * v_t),
    ))
}

/// The motions `(R, t/d, n)` with `R + (t/d)·nᵀ = H` for a homography normalised as by
/// [`Homography::new`] (middle singular value 1, correct sign), by the SVD analysis of
/// Faugeras & Lustman (1988) in the closed form of Ma, Soatto, Košecká & Sastry (2004,
/// *An Invitation to 3-D Vision*, §5.3.3, Theorem 5.19): with `HᵀH = V·diag(σ₁², 1, σ₃²)·Vᵀ`,
/// `V ∈ SO(3)`, and
///
/// `u₁,₂ = (√(1 − σ₃²)·v₁ ± √(σ₁² − 1)·v₃) / √(σ₁² − σ₃²)`,
///
/// `U_k = [v₂, u_k, v₂ × u_k]`, `W_k = [H·v₂, H·u_k, H·v₂ × H·u_k]`, the solutions are
/// `R_k = W_k·U_kᵀ`, `n_k = v₂ × u_k`, `t_k/d = (H − R_k)·n_k`, and the same with `−n_k`, `−t_k`:
/// four in all. The two with a normal facing camera a (`nᵀ·m̃_a > 0` for the points) survive
/// the cheirality check of the first view; in general the second view's cheirality removes one
/// more (H&Z §13.1 note 5: a two-fold ambiguity can remain, e.g. for a far, fronto-parallel
/// plane). The rotations are projected onto SO(3) against rounding.
///
/// When `σ₁ ≈ σ₃` (no translation, `H = R`), the normal is undefined and the single motion
/// `(R, 0)` with `n = (0, 0, 1)` is returned.
pub fn decompose_homography(h: &Homography) -> Vec<HomographyMotion> {
    let hm = h.b_from_a;
    let svd = hm.svd(false, true);
    let v_t = svd.v_t.expect("requested");
    let mut order = [0usize, 1, 2];
    order.sort_by(|&a, &b| svd.singular_values[b].total_cmp(&svd.singular_values[a]));
    let s2 = svd.singular_values[order[1]];
    let sq = |k: usize| (svd.singular_values[order[k]] / s2).powi(2);
    let (s1, s3) = (sq(0), sq(2));
    let hm = hm / s2;
    let mut v = Matrix3::zeros();
    for (col, &k) in order.iter().enumerate() {
        v.set_column(col, &v_t.row(k).transpose());
    }
    if v.determinant() < 0.0 {
        v.column_mut(2).neg_mut();
    }
    let (v1, v2, v3): (Vector3<f64>, Vector3<f64>, Vector3<f64>) =
        (v.column(0).into(), v.column(1).into(), v.column(2).into());
    if s1 - s3 <= 1e-12 {
        return vec![HomographyMotion {
            b_from_a: Se3::new(closest_rotation(&hm), Vector3::zeros()),
            normal_a: Vector3::z(),
        }];
    }
    let scale = (s1 - s3).sqrt();
    let (a, b) = ((1.0 - s3).max(0.0).sqrt(), (s1 - 1.0).max(0.0).sqrt());
    let mut out = Vec::with_capacity(4);
    for u in [(v1 * a + v3 * b) / scale, (v1 * a - v3 * b) / scale] {
        let uk = Matrix3::from_columns(&[v2, u, v2.cross(&u)]);
        let (hv2, hu) = (hm * v2, hm * u);
        let wk = Matrix3::from_columns(&[hv2, hu, hv2.cross(&hu)]);
        let r = closest_rotation(&(wk * uk.transpose()));
        let n = v2.cross(&u);
        let t = (hm - r.rotation_matrix()) * n;
        for sign in [1.0, -1.0] {
            out.push(HomographyMotion {
                b_from_a: Se3::new(r, t * sign),
                normal_a: n * sign,
            });
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::ransac::{RansacConfig, ransac};
    use lie::LieGroup;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    fn proj(x: &Vector3<f64>) -> Vector2<f64> {
        Vector2::new(x.x / x.z, x.y / x.z)
    }

    /// Points on the plane `nᵀx = d` seen by camera a, and their images in both views.
    fn plane_views(
        rng: &mut ChaCha8Rng,
        b_from_a: &Se3,
        n: &Vector3<f64>,
        d: f64,
        count: usize,
    ) -> (Vec<Vector2<f64>>, Vec<Vector2<f64>>) {
        let mut ma = Vec::new();
        let mut mb = Vec::new();
        while ma.len() < count {
            let m = Vector2::new(rng.random_range(-0.5..0.5), rng.random_range(-0.4..0.4));
            let ray = Vector3::new(m.x, m.y, 1.0);
            let x = ray * (d / n.dot(&ray));
            let xb = b_from_a.act(&x);
            if x.z > 0.0 && xb.z > 0.0 {
                ma.push(m);
                mb.push(proj(&xb));
            }
        }
        (ma, mb)
    }

    fn truth() -> (Se3, Vector3<f64>, f64) {
        let b_from_a = Se3::new(
            So3::exp(&Vector3::new(0.05, -0.08, 0.03)),
            Vector3::new(0.6, -0.1, 0.15),
        );
        (b_from_a, Vector3::new(0.2, -0.1, 1.0).normalize(), 4.0)
    }

    #[test]
    fn homography_of_a_known_motion_and_plane_transfers_the_points_and_dlt_recovers_it() {
        let mut rng = ChaCha8Rng::seed_from_u64(11);
        let (b_from_a, n, d) = truth();
        let (ma, mb) = plane_views(&mut rng, &b_from_a, &n, d, 30);
        let h_true =
            b_from_a.rotation().rotation_matrix() + b_from_a.translation() * n.transpose() / d;
        let h = Homography::new(&h_true, &ma).unwrap();
        let mut worst: f64 = 0.0;
        for (a, b) in ma.iter().zip(&mb) {
            worst = worst.max((h.transfer(a).unwrap() - b).norm());
            worst = worst.max((h.transfer_back(b).unwrap() - a).norm());
            assert!(h.sampson_distance(a, b) < 1e-12);
        }
        assert!(worst < 1e-9, "transfer error {worst}");
        // The Euclidean homography already has middle singular value 1 and the right sign.
        assert!((h.b_from_a - h_true).amax() < 1e-12);
        // The DLT recovers it from the exact points, with 4 and with 30 of them.
        for k in [4, 30] {
            let dlt = homography_dlt(&ma[..k], &mb[..k]).unwrap();
            let err = (dlt.b_from_a - h_true).amax();
            assert!(err < 1e-9, "{k} points: |H − H_true| = {err}");
        }
        // Collinear points do not determine H.
        let line: Vec<_> = (0..6).map(|i| Vector2::new(0.1 * i as f64, 0.05)).collect();
        assert!(matches!(
            homography_dlt(&line, &line),
            Err(TwoViewError::Degenerate(_))
        ));
        assert!(matches!(
            homography_dlt(&ma[..3], &mb[..3]),
            Err(TwoViewError::TooFewPoints {
                count: 3,
                needed: 4
            })
        ));
    }

    /// `H = I`: the variety `m_b = m_a` is linear, the Sampson distance is exact: the distance
    /// of `(m, m + δ)` to it is `|δ|/√2`.
    #[test]
    fn sampson_distance_of_the_identity_is_the_geometric_distance() {
        let h = Homography::new(&Matrix3::identity(), &[]).unwrap();
        let a = Vector2::new(0.3, -0.2);
        let delta = Vector2::new(0.01, -0.02);
        let s = h.sampson_distance(&a, &(a + delta));
        assert!((s - delta.norm() / 2f64.sqrt()).abs() < 1e-15, "{s}");
        let e = h.symmetric_transfer_error(&a, &(a + delta));
        assert!((e - 2.0 * delta.norm_squared()).abs() < 1e-15);
    }

    /// The Sampson distance (analytic `J`) against the geometric distance in the joint image
    /// space, minimised numerically (Gauss-Newton over the corrected point `x̂_a`, numeric
    /// Jacobian): equal to first order for a general (projective) `H`.
    #[test]
    fn sampson_distance_matches_the_numerically_minimised_geometric_distance() {
        use crate::testutil::numeric_jacobian;
        use nalgebra::DVector;
        let (b_from_a, n, d) = truth();
        let mut h_true =
            b_from_a.rotation().rotation_matrix() + b_from_a.translation() * n.transpose() / d;
        h_true[(2, 0)] += 0.3;
        h_true[(2, 1)] -= 0.2;
        let h = Homography::new(&h_true, &[Vector2::zeros()]).unwrap();
        let mut rng = ChaCha8Rng::seed_from_u64(14);
        for _ in 0..20 {
            let a = Vector2::new(rng.random_range(-0.5..0.5), rng.random_range(-0.4..0.4));
            let delta = Vector2::new(rng.random_range(-1e-3..1e-3), rng.random_range(-1e-3..1e-3));
            let b = h.transfer(&a).unwrap() + delta;
            let res = |x: &DVector<f64>| {
                let p = h.transfer(&Vector2::new(x[0], x[1])).unwrap();
                DVector::from_vec(vec![a.x - x[0], a.y - x[1], b.x - p.x, b.y - p.y])
            };
            let mut x = DVector::from_column_slice(a.as_slice());
            for _ in 0..20 {
                let j = numeric_jacobian(res, &x, 1e-7);
                let step = (j.transpose() * &j)
                    .cholesky()
                    .unwrap()
                    .solve(&(j.transpose() * res(&x)));
                x -= step;
            }
            let geometric = res(&x).norm();
            let sampson = h.sampson_distance(&a, &b);
            assert!(
                (sampson - geometric).abs() <= 1e-2 * geometric,
                "Sampson {sampson} vs geometric {geometric}"
            );
        }
    }

    #[test]
    fn decomposition_contains_the_true_motion() {
        let mut rng = ChaCha8Rng::seed_from_u64(12);
        for trial in 0..20 {
            let b_from_a = Se3::new(
                So3::exp(&Vector3::new(
                    rng.random_range(-0.2..0.2),
                    rng.random_range(-0.2..0.2),
                    rng.random_range(-0.2..0.2),
                )),
                Vector3::new(
                    rng.random_range(-1.0..1.0),
                    rng.random_range(-0.5..0.5),
                    rng.random_range(-0.5..0.5),
                ),
            );
            let n = Vector3::new(
                rng.random_range(-0.4..0.4),
                rng.random_range(-0.4..0.4),
                1.0,
            )
            .normalize();
            let d = rng.random_range(2.0..6.0);
            let (ma, _) = plane_views(&mut rng, &b_from_a, &n, d, 10);
            let h_true =
                b_from_a.rotation().rotation_matrix() + b_from_a.translation() * n.transpose() / d;
            // An arbitrary scale and sign, as from the DLT.
            let h = Homography::new(&(h_true * -3.7), &ma).unwrap();
            let motions = decompose_homography(&h);
            assert_eq!(motions.len(), 4);
            for m in &motions {
                let rebuilt = m.b_from_a.rotation().rotation_matrix()
                    + m.b_from_a.translation() * m.normal_a.transpose();
                assert!((rebuilt - h.b_from_a).amax() < 1e-9, "trial {trial}");
            }
            let best = motions
                .iter()
                .map(|m| {
                    let rot = m
                        .b_from_a
                        .rotation()
                        .inverse()
                        .compose(b_from_a.rotation())
                        .log()
                        .norm();
                    let t = (m.b_from_a.translation() - b_from_a.translation() / d).norm();
                    rot + t + (m.normal_a - n).norm()
                })
                .fold(f64::INFINITY, f64::min);
            assert!(best < 1e-9, "trial {trial}: {best}");
        }
        // A pure rotation gives one motion with zero translation.
        let r = So3::exp(&Vector3::new(0.1, 0.2, -0.1));
        let h = Homography::new(&r.rotation_matrix(), &[]).unwrap();
        let motions = decompose_homography(&h);
        assert_eq!(motions.len(), 1);
        assert!(motions[0].b_from_a.translation().norm() < 1e-12);
        assert!(
            motions[0]
                .b_from_a
                .rotation()
                .inverse()
                .compose(&r)
                .log()
                .norm()
                < 1e-12
        );
    }

    #[test]
    fn ransac_homography_with_outliers() {
        let f = 500.0;
        let mut rng = ChaCha8Rng::seed_from_u64(13);
        let (b_from_a, n, d) = truth();
        let (ma, mut mb) = plane_views(&mut rng, &b_from_a, &n, d, 200);
        for m in mb.iter_mut().step_by(3) {
            *m = Vector2::new(rng.random_range(-0.6..0.6), rng.random_range(-0.5..0.5));
        }
        let est = HomographyEstimator {
            m_a: &ma,
            m_b: &mb,
            pixel_scale: f,
        };
        let r = ransac(
            &est,
            &RansacConfig {
                threshold: 1.0,
                ..RansacConfig::default()
            },
        )
        .unwrap();
        let expected: Vec<usize> = (0..200).filter(|i| i % 3 != 0).collect();
        assert_eq!(r.inliers, expected);
        let h_true =
            b_from_a.rotation().rotation_matrix() + b_from_a.translation() * n.transpose() / d;
        assert!((r.model.b_from_a - h_true).amax() < 1e-9);
    }
}
