//! The two-view bootstrap of monocular SLAM: the relative pose and a first structure from the
//! correspondences of two frames, choosing between a homography (a planar scene, or a motion too
//! close to a pure rotation for the epipolar geometry) and the essential matrix (a general scene)
//! (thesis §3.5, §4.3 "Structure and Motion Bootstrapping"; H&Z ch. 4, 9, 13).
//!
//! [`bootstrap_pose`]:
//!
//! 1. fits both models robustly with [`crate::ransac::ransac`]: the essential matrix by
//!    [`EssentialEstimator`] (gate `σ·√(χ²₁(p))` on the Sampson distance), then the homography
//!    by [`HomographyEstimator`] (gate `σ·√(2·χ²₂(p))` on the RMS transfer distance) with as
//!    many samples as the essential matrix's inlier ratio requires of a 4-point sample (a
//!    plane that could win explains as many points);
//! 2. selects the model by Torr's geometric robust information criterion (GRIC; Torr 1998,
//!    *Geometric motion segmentation and model selection*, Phil. Trans. R. Soc. A 356; Torr
//!    2002, IJCV 50(1) §7), a penalised log-likelihood:
//!
//!    `GRIC(M) = Σᵢ ρ(eᵢ²/σ²) + λ₁·d_M·n + λ₂·k_M`, `ρ(x) = min(x, λ₃·(r − d_M))`,
//!
//!    with `r = 4` the dimension of a datum `(m_a, m_b)`, `d_M` the dimension of the model's
//!    variety (`2` for a homography, `3` for the epipolar constraint), `k_M` its parameters (`8`
//!    for `H`, `5` for `E`), `λ₁ = ln r`, `λ₂ = ln(r·n)`, `λ₃ = 2` (Torr's values), and `eᵢ`
//!    the first-order geometric distance in the joint image space (the Sampson distances of
//!    [`Homography::sampson_distance`] and [`sampson_distance`]). The model with the lower
//!    GRIC wins: the essential matrix fits every scene at least as closely (it constrains one
//!    coordinate per datum, the homography two), and pays for it with `λ₁ = ln 4` per datum;
//!    on a plane or under a pure rotation the fits are equally good and the homography wins, in
//!    a scene with depth its residuals grow and the essential matrix wins. The sum runs over the
//!    data that at least one model explains (within its gate): a datum neither explains is
//!    evidence for neither, and counting it would charge the two models' different caps
//!    `λ₃·(r − d_M)` per outlier;
//! 3. decomposes the chosen model into its candidate motions ([`decompose_homography`]: four,
//!    [`decompose_essential`]: four), triangulates the model's inliers under each with
//!    [`triangulate`] and counts the *well triangulated* ones: in front of both cameras and
//!    re-projecting within `σ·√(χ²₂(p))` in both images (the cheirality check, H&Z §9.6.3,
//!    Result 9.19 and §13.1);
//! 4. refuses to decide when the data cannot support a decision, with a typed error a live
//!    system can show while it keeps tracking: [`TwoViewError::TooLittleParallax`] when the
//!    median angle between the inliers' rays is below the parallax needed for a relative depth
//!    error `ε` ([`BootstrapConfig::min_parallax`]), [`TwoViewError::Ambiguous`] when the
//!    runner-up candidate triangulates more than [`BootstrapConfig::ambiguity_ratio`] of the
//!    best one's points (the two-fold ambiguity of a plane), [`TwoViewError::Cheirality`] when
//!    the best triangulates too few.
//!
//! The translation is returned with unit length (the scale is not observable, thesis Fig. 3.2);
//! the points are in frame a in that unit.

use crate::homography::{Homography, HomographyEstimator, decompose_homography};
use crate::ransac::{Estimator, RansacConfig, RansacResult, ransac, required_iterations};
use crate::two_view::{
    EssentialEstimator, TwoViewError, check_correspondences, decompose_essential, sampson_distance,
    triangulate,
};
use lie::{LieGroup, Se3};
use nalgebra::{Matrix3, Vector2, Vector3};

/// Parameters of [`bootstrap_pose`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BootstrapConfig {
    /// Pixels per normalised unit (the focal length).
    pub pixel_scale: f64,
    /// Standard deviation `σ` of a corner's position in pixels (per coordinate).
    pub pixel_sigma: f64,
    /// The χ² quantile with one degree of freedom at the inlier confidence `p` (gate of the
    /// epipolar residual), e.g. `lsq::chi2_quantile(1, 0.95)`. `geom` sits below `lsq` in the
    /// crate layering, so the caller supplies it.
    pub chi2_one_dof: f64,
    /// The χ² quantile with two degrees of freedom at `p` (gate of the homography transfer and
    /// of the re-projections of triangulated points), e.g. `lsq::chi2_quantile(2, 0.95)`.
    pub chi2_two_dof: f64,
    /// Largest acceptable relative depth error `ε` of a typical (median-parallax) point; sets
    /// [`Self::min_parallax`].
    pub max_relative_depth_error: f64,
    /// Fewest well triangulated points for a bootstrap.
    pub min_triangulated: usize,
    /// `Some(floor)`: the parallax requirement ([`Self::min_parallax`]) uses the corner noise
    /// measured on the two frames instead of `pixel_sigma` — the robust estimate
    /// `σ̂ = √(median(e²) / median(χ²_d))` from the chosen model's inliers (`e` their Sampson
    /// distances in pixels, `d` = 1 for the epipolar constraint, 2 for a homography), clamped
    /// to `[floor, pixel_sigma]`. Tracks followed by sub-pixel optical flow over a few frames
    /// are often far better than the noise a system assumes for every frame (`pixel_sigma`
    /// covers motion blur), and the depth error a parallax gives depends on the noise the
    /// tracks have; the floor keeps the estimate from trusting a residual the fit absorbed.
    /// `None`: `pixel_sigma`.
    pub min_pixel_sigma: Option<f64>,
    /// A candidate motion is ambiguous when the runner-up triangulates more than this fraction
    /// of the best one's points.
    pub ambiguity_ratio: f64,
    /// Sampler settings of both RANSACs; the threshold is set per model from the gates above.
    pub ransac: RansacConfig,
}

impl BootstrapConfig {
    /// The defaults for a camera of focal length `pixel_scale` and corner noise `pixel_sigma`,
    /// with the χ² quantiles (one and two degrees of freedom) of the inlier confidence:
    ///
    /// - `max_relative_depth_error = 0.1`: a first map whose typical point depth is good to
    ///   10 %, about what inverse-depth features reach before they are promoted (thesis §3.4.4);
    /// - `min_triangulated = 50` (ORB-SLAM's bootstrap, Mur-Artal et al. 2015 §IV): fewer
    ///   points do not carry the tracking of the next frames;
    /// - `ambiguity_ratio = 0.75` (the same source): a runner-up within 25 % of the best is a
    ///   coin toss under noise;
    /// - RANSAC with `p = 0.999`, at most 2 000 samples (a 4-point sample at 50 % inliers needs
    ///   108, an 8-point one 1 765).
    pub fn new(
        pixel_scale: f64,
        pixel_sigma: f64,
        chi2_one_dof: f64,
        chi2_two_dof: f64,
    ) -> BootstrapConfig {
        BootstrapConfig {
            pixel_scale,
            pixel_sigma,
            chi2_one_dof,
            chi2_two_dof,
            max_relative_depth_error: 0.1,
            min_triangulated: 50,
            min_pixel_sigma: None,
            ambiguity_ratio: 0.75,
            ransac: RansacConfig {
                max_iterations: 2_000,
                ..RansacConfig::default()
            },
        }
    }

    /// The median parallax needed for a relative depth error `ε`: a ray's direction is known to
    /// `σ/f` in each view, the angle between two rays to `√2·σ/f`, and a point's depth
    /// `z ≈ b/θ` (baseline `b`, parallax `θ`) has relative error `δz/z = δθ/θ`, so
    /// `θ_min = √2·σ / (f·ε)` (radians).
    pub fn min_parallax(&self) -> f64 {
        self.min_parallax_for(self.pixel_sigma)
    }

    /// [`Self::min_parallax`] for corner noise `sigma` (pixels).
    pub fn min_parallax_for(&self, sigma: f64) -> f64 {
        std::f64::consts::SQRT_2 * sigma / (self.pixel_scale * self.max_relative_depth_error)
    }

    fn validate(&self) -> Result<(), TwoViewError> {
        let positive = |v: f64| v > 0.0 && v.is_finite();
        if !positive(self.pixel_scale) {
            return Err(TwoViewError::InvalidConfig("pixel_scale must be positive"));
        }
        if !positive(self.pixel_sigma) {
            return Err(TwoViewError::InvalidConfig("pixel_sigma must be positive"));
        }
        if !positive(self.chi2_one_dof) || !positive(self.chi2_two_dof) {
            return Err(TwoViewError::InvalidConfig("the χ² gates must be positive"));
        }
        if self
            .min_pixel_sigma
            .is_some_and(|s| !(positive(s) && s <= self.pixel_sigma))
        {
            return Err(TwoViewError::InvalidConfig(
                "min_pixel_sigma must be positive and at most pixel_sigma",
            ));
        }
        if !positive(self.max_relative_depth_error) {
            return Err(TwoViewError::InvalidConfig(
                "max_relative_depth_error must be positive",
            ));
        }
        if !(self.ambiguity_ratio > 0.0 && self.ambiguity_ratio <= 1.0) {
            return Err(TwoViewError::InvalidConfig(
                "ambiguity_ratio must lie in (0, 1]",
            ));
        }
        Ok(())
    }
}

/// The model a bootstrap chose.
#[derive(Clone, Debug, PartialEq)]
pub enum TwoViewModel {
    /// A plane (or a rotation-dominated motion): `H = R + (t/d)·nᵀ`.
    Homography {
        /// The homography.
        homography: Homography,
        /// The plane's unit normal in frame a.
        normal_a: Vector3<f64>,
        /// The plane's distance from camera a in units of the baseline `|t|`.
        plane_distance: f64,
    },
    /// A general scene: `E = [t]×R`.
    Essential(Matrix3<f64>),
}

/// The outcome of [`bootstrap_pose`].
#[derive(Clone, Debug, PartialEq)]
pub struct TwoViewBootstrap {
    /// The chosen model.
    pub model: TwoViewModel,
    /// `T_ba` with `|t| = 1`.
    pub b_from_a: Se3,
    /// Per correspondence: an inlier of the chosen model.
    pub inliers: Vec<bool>,
    /// Per correspondence: the point in frame a (baseline units) where it is an inlier, in front
    /// of both cameras and re-projects within the gate.
    pub points: Vec<Option<Vector3<f64>>>,
    /// The median angle (radians) between the inliers' rays `R·m̃_a` and `m̃_b`.
    pub median_parallax: f64,
    /// The corner noise (pixels) the parallax requirement used: `pixel_sigma`, or the one
    /// measured on the inliers ([`BootstrapConfig::min_pixel_sigma`]).
    pub pixel_sigma: f64,
    /// The median parallax that was required (radians).
    pub required_parallax: f64,
    /// GRIC of the homography (`∞` when RANSAC found none).
    pub gric_homography: f64,
    /// GRIC of the essential matrix (`∞` when RANSAC found none).
    pub gric_essential: f64,
}

/// Torr's GRIC (module docs) of whitened squared residuals `x`, for a model of variety
/// dimension `dim` and `params` parameters, data of dimension 4.
fn gric(x: impl Iterator<Item = f64>, dim: usize, params: usize) -> f64 {
    const R: f64 = 4.0;
    let cap = 2.0 * (R - dim as f64);
    let (mut sum, mut n) = (0.0, 0usize);
    for v in x {
        sum += v.min(cap);
        n += 1;
    }
    let n_f = n as f64;
    sum + R.ln() * dim as f64 * n_f + (R * n_f).ln() * params as f64
}

/// The well triangulated inliers of one candidate motion and the inliers' ray angles.
struct Evaluation {
    good: Vec<(usize, Vector3<f64>)>,
    parallax: Vec<f64>,
}

fn evaluate(
    b_from_a: &Se3,
    m_a: &[Vector2<f64>],
    m_b: &[Vector2<f64>],
    inliers: &[usize],
    gate_sq: f64,
) -> Evaluation {
    let mut good = Vec::new();
    let mut parallax = Vec::with_capacity(inliers.len());
    let reprojects = |x: &Vector3<f64>, m: &Vector2<f64>| {
        (Vector2::new(x.x / x.z, x.y / x.z) - m).norm_squared() <= gate_sq
    };
    for &i in inliers {
        let ra = b_from_a
            .rotation()
            .act(&Vector3::new(m_a[i].x, m_a[i].y, 1.0));
        let rb = Vector3::new(m_b[i].x, m_b[i].y, 1.0);
        parallax.push(ra.angle(&rb));
        let Some(tri) = triangulate(b_from_a, &m_a[i], &m_b[i]) else {
            continue;
        };
        if tri.depth_a > 0.0 && tri.depth_b > 0.0 {
            let xb = b_from_a.act(&tri.point_a);
            if reprojects(&tri.point_a, &m_a[i]) && reprojects(&xb, &m_b[i]) {
                good.push((i, tri.point_a));
            }
        }
    }
    Evaluation { good, parallax }
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v.get(v.len() / 2).copied().unwrap_or(0.0)
}

/// The candidate motions of a homography with unit translation, each with its model.
fn homography_candidates(h: RansacResult<Homography>) -> (Vec<usize>, Vec<(Se3, TwoViewModel)>) {
    let c = decompose_homography(&h.model)
        .into_iter()
        .map(|m| {
            let t = *m.b_from_a.translation();
            let norm = t.norm();
            let unit = if norm > 0.0 { t / norm } else { t };
            (
                Se3::new(*m.b_from_a.rotation(), unit),
                TwoViewModel::Homography {
                    homography: h.model,
                    normal_a: m.normal_a,
                    plane_distance: 1.0 / norm,
                },
            )
        })
        .collect();
    (h.inliers, c)
}

/// The monocular two-view bootstrap (see the [module docs](self)) of normalised
/// correspondences `m_a[i] ↔ m_b[i]` (at least 8).
pub fn bootstrap_pose(
    m_a: &[Vector2<f64>],
    m_b: &[Vector2<f64>],
    config: &BootstrapConfig,
) -> Result<TwoViewBootstrap, TwoViewError> {
    config.validate()?;
    check_correspondences(m_a, m_b, 8)?;
    let n = m_a.len();
    let (f, sigma) = (config.pixel_scale, config.pixel_sigma);
    let h_est = HomographyEstimator {
        m_a,
        m_b,
        pixel_scale: f,
    };
    let e_est = EssentialEstimator {
        m_a,
        m_b,
        pixel_scale: f,
    };
    let e_fit = ransac(
        &e_est,
        &RansacConfig {
            threshold: sigma * config.chi2_one_dof.sqrt(),
            ..config.ransac
        },
    );
    // The homography only has to be found when it explains about as many points as the
    // epipolar geometry (a plane explains the same points under both models): the samples
    // that find an all-inlier 4-sample at the essential matrix's inlier ratio with confidence
    // `p` suffice. Without an essential matrix (e.g. the 8-point algorithm degenerate on an
    // exact plane) the full budget is used.
    let h_iterations = e_fit.as_ref().map_or(config.ransac.max_iterations, |r| {
        required_iterations(
            r.inliers.len() as f64 / n as f64,
            h_est.sample_size(),
            config.ransac.confidence,
        )
    });
    let h_fit = ransac(
        &h_est,
        &RansacConfig {
            threshold: sigma * (2.0 * config.chi2_two_dof).sqrt(),
            max_iterations: h_iterations.clamp(1, config.ransac.max_iterations),
            ..config.ransac
        },
    );
    let (h_fit, e_fit) = match (h_fit, e_fit) {
        (Err(_), Err(e)) => return Err(e.into()),
        (h, e) => (h.ok(), e.ok()),
    };
    let mut explained = vec![false; n];
    for fit_inliers in [
        h_fit.as_ref().map(|r| &r.inliers),
        e_fit.as_ref().map(|r| &r.inliers),
    ]
    .into_iter()
    .flatten()
    {
        for &i in fit_inliers {
            explained[i] = true;
        }
    }
    // The corner noise the data show (`min_pixel_sigma`): from the residuals of the general
    // model, the epipolar constraint, which holds for any rigid scene (a homography's residuals
    // also hold its model error when the scene has depth), or the homography's when there is
    // no essential matrix. It whitens GRIC's residuals and sets the parallax requirement; the
    // RANSAC gates above stay at the assumed `σ`, the safe side for telling inliers.
    let pixel_sigma = match config.min_pixel_sigma {
        Some(floor) => {
            let squared: Vec<f64> = match (&e_fit, &h_fit) {
                (Some(e), _) => e
                    .inliers
                    .iter()
                    .map(|&i| {
                        (f * sampson_distance(&e.model, &m_a[i], &m_b[i])).powi(2) / CHI2_1_MEDIAN
                    })
                    .collect(),
                (None, Some(h)) => h
                    .inliers
                    .iter()
                    .map(|&i| {
                        (f * h.model.sampson_distance(&m_a[i], &m_b[i])).powi(2) / CHI2_2_MEDIAN
                    })
                    .collect(),
                (None, None) => Vec::new(),
            };
            median(squared).sqrt().clamp(floor, sigma)
        }
        None => sigma,
    };
    let whiten = f * f / (pixel_sigma * pixel_sigma);
    let explained_idx = || (0..n).filter(|&i| explained[i]);
    let gric_homography = h_fit.as_ref().map_or(f64::INFINITY, |r| {
        gric(
            explained_idx().map(|i| whiten * r.model.sampson_distance(&m_a[i], &m_b[i]).powi(2)),
            2,
            8,
        )
    });
    let gric_essential = e_fit.as_ref().map_or(f64::INFINITY, |r| {
        gric(
            explained_idx().map(|i| whiten * sampson_distance(&r.model, &m_a[i], &m_b[i]).powi(2)),
            3,
            5,
        )
    });
    let (inliers, candidates) = match (h_fit, e_fit) {
        (Some(h), None) => homography_candidates(h),
        (Some(h), Some(_)) if gric_homography <= gric_essential => homography_candidates(h),
        (_, Some(e)) => {
            let c = decompose_essential(&e.model)
                .into_iter()
                .map(|p| (p, TwoViewModel::Essential(e.model)))
                .collect();
            (e.inliers, c)
        }
        (None, None) => return Err(TwoViewError::Degenerate("neither model could be fitted")),
    };
    let gate_sq = config.chi2_two_dof * sigma * sigma / (f * f);
    let mut evaluations: Vec<(Evaluation, Se3, TwoViewModel)> = candidates
        .into_iter()
        .map(|(pose, model)| (evaluate(&pose, m_a, m_b, &inliers, gate_sq), pose, model))
        .collect();
    // Best first; ties keep the decomposition's order (deterministic).
    evaluations.sort_by_key(|e| std::cmp::Reverse(e.0.good.len()));
    let second = evaluations.get(1).map_or(0, |e| e.0.good.len());
    let (best, b_from_a, model) = evaluations.swap_remove(0);
    let median_parallax = median(best.parallax);
    let required = config.min_parallax_for(pixel_sigma);
    if median_parallax.is_nan() || median_parallax < required {
        return Err(TwoViewError::TooLittleParallax {
            median_parallax,
            required,
        });
    }
    let best_count = best.good.len();
    if second as f64 > config.ambiguity_ratio * best_count as f64 {
        return Err(TwoViewError::Ambiguous {
            best: best_count,
            second,
        });
    }
    if best_count < config.min_triangulated.max(inliers.len() / 2) {
        return Err(TwoViewError::Cheirality {
            in_front: best_count,
            total: inliers.len(),
        });
    }
    let mut inlier_mask = vec![false; n];
    for &i in &inliers {
        inlier_mask[i] = true;
    }
    let mut points = vec![None; n];
    for (i, p) in best.good {
        points[i] = Some(p);
    }
    Ok(TwoViewBootstrap {
        model,
        b_from_a,
        inliers: inlier_mask,
        points,
        median_parallax,
        pixel_sigma,
        required_parallax: required,
        gric_homography,
        gric_essential,
    })
}

/// The median of χ² with one degree of freedom, `Φ⁻¹(0.75)²`.
const CHI2_1_MEDIAN: f64 = 0.454_936_423_119_572_8;
/// The median of χ² with two degrees of freedom, `2·ln 2`.
const CHI2_2_MEDIAN: f64 = std::f64::consts::LN_2 * 2.0;

#[cfg(test)]
mod tests {
    use super::*;
    use lie::So3;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;
    use rand_distr::{Distribution, Normal};

    const F: f64 = 500.0;
    const SIGMA: f64 = 0.5;
    /// Sideways motion (forward component at most 10 % of the sideways one): the plane's
    /// two-fold ambiguity is resolved by cheirality (see
    /// `plane_with_forward_motion_is_ambiguous_or_right_never_wrong` for the other case).
    const SIDEWAYS: (f64, f64) = (0.0, 0.1);

    fn config(seed: u64) -> BootstrapConfig {
        let mut c = BootstrapConfig::new(
            F,
            SIGMA,
            lsq::chi2_quantile(1, 0.95),
            lsq::chi2_quantile(2, 0.95),
        );
        c.ransac.seed = seed;
        c
    }

    fn proj(x: &Vector3<f64>) -> Vector2<f64> {
        Vector2::new(x.x / x.z, x.y / x.z)
    }

    /// Rotation angle and translation-direction angle between two poses (radians).
    fn pose_error(a: &Se3, b: &Se3) -> (f64, f64) {
        let rot = a.rotation().inverse().compose(b.rotation()).log().norm();
        (rot, a.translation().angle(b.translation()))
    }

    /// Views of `points` (frame a) with Gaussian pixel noise `sigma`, every third
    /// correspondence in view b replaced by a random point.
    fn views(
        rng: &mut ChaCha8Rng,
        b_from_a: &Se3,
        points: &[Vector3<f64>],
        sigma: f64,
        outliers: bool,
    ) -> (Vec<Vector2<f64>>, Vec<Vector2<f64>>) {
        let noise = Normal::new(0.0, sigma / F).unwrap();
        let jitter = |rng: &mut ChaCha8Rng| Vector2::new(noise.sample(rng), noise.sample(rng));
        let m_a: Vec<_> = points.iter().map(|p| proj(p) + jitter(rng)).collect();
        let mut m_b: Vec<_> = points
            .iter()
            .map(|p| proj(&b_from_a.act(p)) + jitter(rng))
            .collect();
        if outliers {
            for m in m_b.iter_mut().step_by(3) {
                *m = Vector2::new(rng.random_range(-0.6..0.6), rng.random_range(-0.5..0.5));
            }
        }
        (m_a, m_b)
    }

    /// Points on the plane `nᵀx = d` inside the view of camera a.
    fn plane(rng: &mut ChaCha8Rng, n: &Vector3<f64>, d: f64, count: usize) -> Vec<Vector3<f64>> {
        (0..count)
            .map(|_| {
                let ray = Vector3::new(
                    rng.random_range(-0.5..0.5),
                    rng.random_range(-0.4..0.4),
                    1.0,
                );
                ray * (d / n.dot(&ray))
            })
            .collect()
    }

    fn volume(rng: &mut ChaCha8Rng, count: usize) -> Vec<Vector3<f64>> {
        (0..count)
            .map(|_| {
                let z = rng.random_range(3.0..8.0);
                Vector3::new(
                    rng.random_range(-0.5..0.5) * z,
                    rng.random_range(-0.4..0.4) * z,
                    z,
                )
            })
            .collect()
    }

    /// A relative motion with rotation up to 0.1 rad per axis and a translation of length
    /// `baseline` mostly sideways, its component along the optical axis drawn from
    /// `forward.0..forward.1` (relative, random sign) before normalisation.
    fn motion(rng: &mut ChaCha8Rng, baseline: f64, forward: (f64, f64)) -> Se3 {
        let w = Vector3::new(
            rng.random_range(-0.1..0.1),
            rng.random_range(-0.1..0.1),
            rng.random_range(-0.1..0.1),
        );
        let t = Vector3::new(
            rng.random_range(0.5..1.0) * if rng.random_bool(0.5) { 1.0 } else { -1.0 },
            rng.random_range(-0.3..0.3),
            rng.random_range(forward.0..forward.1) * if rng.random_bool(0.5) { 1.0 } else { -1.0 },
        );
        Se3::new(So3::exp(&w), t.normalize() * baseline)
    }

    fn plane_normal(rng: &mut ChaCha8Rng) -> Vector3<f64> {
        Vector3::new(
            rng.random_range(-0.3..0.3),
            rng.random_range(-0.3..0.3),
            1.0,
        )
        .normalize()
    }

    /// Tracks far better than the assumed noise (σ = 0.1 px against `pixel_sigma` = 1 px) and
    /// a small baseline: with the assumed noise the parallax is too little (a 10 % depth error
    /// needs 1.6° at f = 500 px and σ = 1 px; a 4.5 cm baseline at 3–8 m gives about 0.5°);
    /// measured on the data, the noise is the true one, or the floor (0.25 px: 0.4° needed),
    /// and the bootstrap succeeds with the true motion. A floor above `pixel_sigma` is
    /// refused.
    #[test]
    fn measured_noise_sets_the_parallax_a_bootstrap_needs() {
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let b_from_a = motion(&mut rng, 0.045, SIDEWAYS);
        let pts = volume(&mut rng, 200);
        let (m_a, m_b) = views(&mut rng, &b_from_a, &pts, 0.1, false);
        let assumed = BootstrapConfig {
            pixel_sigma: 1.0,
            ..config(3)
        };
        match bootstrap_pose(&m_a, &m_b, &assumed) {
            Err(TwoViewError::TooLittleParallax {
                median_parallax,
                required,
            }) => assert!(median_parallax < required, "{median_parallax} {required}"),
            other => panic!("{other:?}"),
        }
        let measured = BootstrapConfig {
            min_pixel_sigma: Some(0.25),
            ..assumed
        };
        let r = bootstrap_pose(&m_a, &m_b, &measured).unwrap();
        assert_eq!(r.pixel_sigma, 0.25, "the floor: the data show 0.1 px");
        assert!((r.required_parallax - measured.min_parallax_for(0.25)).abs() < 1e-15);
        assert!(matches!(r.model, TwoViewModel::Essential(_)));
        let (rot, dir) = pose_error(&r.b_from_a, &b_from_a);
        assert!(rot < 0.002 && dir < 0.05, "{rot} {dir}");
        // Without a floor below it, the noise estimate is the data's.
        let free = BootstrapConfig {
            min_pixel_sigma: Some(0.01),
            ..assumed
        };
        let r = bootstrap_pose(&m_a, &m_b, &free).unwrap();
        assert!((0.07..0.13).contains(&r.pixel_sigma), "{}", r.pixel_sigma);
        let wrong = BootstrapConfig {
            min_pixel_sigma: Some(2.0),
            ..assumed
        };
        assert!(matches!(
            bootstrap_pose(&m_a, &m_b, &wrong),
            Err(TwoViewError::InvalidConfig(_))
        ));
    }

    /// Exact views of a plane: the homography is chosen (the 8-point algorithm is degenerate on
    /// a plane, so no essential matrix is found), and the cheirality selection among its four
    /// motions returns the true one, with the plane's normal and distance and the points.
    #[test]
    fn exact_plane_selects_the_true_motion_among_the_homography_candidates() {
        let mut rng = ChaCha8Rng::seed_from_u64(21);
        for trial in 0..5 {
            let b_from_a = motion(&mut rng, 0.7, SIDEWAYS);
            let n = plane_normal(&mut rng);
            let d = 4.0;
            let pts = plane(&mut rng, &n, d, 100);
            let (m_a, m_b) = views(&mut rng, &b_from_a, &pts, 0.0, false);
            // Without noise a single point behind a camera refutes a candidate: the selection
            // is by the count alone (with noise the default ratio leaves a margin).
            let exact = BootstrapConfig {
                ambiguity_ratio: 1.0,
                ..config(trial)
            };
            let r = bootstrap_pose(&m_a, &m_b, &exact).unwrap();
            let TwoViewModel::Homography {
                normal_a,
                plane_distance,
                ..
            } = r.model
            else {
                panic!("trial {trial}: {:?}", r.model);
            };
            let (rot, dir) = pose_error(&r.b_from_a, &b_from_a);
            assert!(rot < 1e-9 && dir < 1e-9, "trial {trial}: {rot} {dir}");
            assert!((normal_a - n).norm() < 1e-9);
            assert!((plane_distance - d / 0.7).abs() < 1e-8, "{plane_distance}");
            assert!(r.inliers.iter().all(|&b| b));
            for (p, q) in r.points.iter().zip(&pts) {
                assert!((p.unwrap() * 0.7 - q).norm() < 1e-8);
            }
        }
    }

    fn noisy_trials(planar: bool) -> (f64, f64) {
        let mut rng = ChaCha8Rng::seed_from_u64(if planar { 22 } else { 23 });
        let (mut worst_rot, mut worst_dir) = (0.0_f64, 0.0_f64);
        for trial in 0..5 {
            let b_from_a = motion(&mut rng, 0.7, if planar { SIDEWAYS } else { (0.0, 0.3) });
            let pts = if planar {
                let n = plane_normal(&mut rng);
                plane(&mut rng, &n, 4.0, 200)
            } else {
                volume(&mut rng, 200)
            };
            let (m_a, m_b) = views(&mut rng, &b_from_a, &pts, SIGMA, true);
            let r = bootstrap_pose(&m_a, &m_b, &config(trial)).unwrap();
            // Seeded: the same input gives the same bootstrap.
            assert_eq!(r, bootstrap_pose(&m_a, &m_b, &config(trial)).unwrap());
            let homography = matches!(r.model, TwoViewModel::Homography { .. });
            assert_eq!(
                homography, planar,
                "trial {trial}: GRIC H {} E {}",
                r.gric_homography, r.gric_essential
            );
            let (rot, dir) = pose_error(&r.b_from_a, &b_from_a);
            worst_rot = worst_rot.max(rot);
            worst_dir = worst_dir.max(dir);
            // The outliers (every third) are rejected, most of the rest triangulated.
            let good = (0..200).filter(|&i| i % 3 != 0);
            // An outlier that happens to lie on its epipolar line (or near the homography's
            // transfer) cannot be told from an inlier; at a 1 px gate they are rare.
            let accepted = r.inliers.iter().step_by(3).filter(|&&b| b).count();
            assert!(accepted <= 5, "trial {trial}: {accepted} outliers accepted");
            let found = good.filter(|&i| r.points[i].is_some()).count();
            assert!(found >= 120, "trial {trial}: {found} of 133 triangulated");
        }
        eprintln!(
            "{}: worst rotation error {:.4}°, translation direction {:.4}°",
            if planar { "plane" } else { "volume" },
            worst_rot.to_degrees(),
            worst_dir.to_degrees()
        );
        (worst_rot.to_degrees(), worst_dir.to_degrees())
    }

    /// A plane, 0.5 px noise, 30 % outliers: the homography is chosen and the pose is within
    /// 0.5° (rotation) and 2° (translation direction).
    #[test]
    fn noisy_plane_with_outliers_chooses_the_homography() {
        let (rot, dir) = noisy_trials(true);
        assert!(rot < 0.5 && dir < 2.0, "{rot}° {dir}°");
    }

    /// A scene with depth, 0.5 px noise, 30 % outliers: the essential matrix is chosen, same
    /// tolerances.
    #[test]
    fn noisy_volume_with_outliers_chooses_the_essential_matrix() {
        let (rot, dir) = noisy_trials(false);
        assert!(rot < 0.5 && dir < 2.0, "{rot}° {dir}°");
    }

    /// A 5 mm baseline at 3–8 m (parallax ≈ 0.06°, well below the 0.81° that a 10 % depth
    /// error needs at σ = 0.5 px, f = 500): the typed error, never a pose; whichever model
    /// is chosen. Also a pure rotation.
    #[test]
    fn too_little_parallax_is_a_typed_error() {
        let mut rng = ChaCha8Rng::seed_from_u64(24);
        for trial in 0..5 {
            let baseline = if trial == 4 { 0.0 } else { 0.005 };
            let b_from_a = motion(&mut rng, baseline, (0.0, 0.3));
            let pts = volume(&mut rng, 200);
            let (m_a, m_b) = views(&mut rng, &b_from_a, &pts, SIGMA, true);
            match bootstrap_pose(&m_a, &m_b, &config(trial)) {
                Err(TwoViewError::TooLittleParallax {
                    median_parallax,
                    required,
                }) => {
                    eprintln!(
                        "baseline {baseline}: median parallax {:.4}° < required {:.4}°",
                        median_parallax.to_degrees(),
                        required.to_degrees()
                    );
                    assert!(median_parallax < 0.25 * required, "{median_parallax}");
                    assert!((required - config(0).min_parallax()).abs() < 1e-15);
                }
                other => panic!("trial {trial}: {other:?}"),
            }
        }
    }

    /// A plane seen while the camera also moves along its optical axis (translation direction
    /// 20–45° off the image plane): often the two-fold ambiguity of the homography (H&Z §13.1),
    /// both motions put (nearly) all points in front of both cameras. Each trial is either the
    /// typed [`TwoViewError::Ambiguous`] or the true pose, never a wrong one.
    #[test]
    fn plane_with_forward_motion_is_ambiguous_or_right_never_wrong() {
        let mut rng = ChaCha8Rng::seed_from_u64(25);
        let (mut ambiguous, mut right) = (0, 0);
        for trial in 0..10 {
            let b_from_a = motion(&mut rng, 0.7, (0.35, 1.0));
            let n = plane_normal(&mut rng);
            let pts = plane(&mut rng, &n, 4.0, 200);
            let (m_a, m_b) = views(&mut rng, &b_from_a, &pts, SIGMA, true);
            match bootstrap_pose(&m_a, &m_b, &config(trial)) {
                Err(TwoViewError::Ambiguous { best, second }) => {
                    assert!(second <= best);
                    ambiguous += 1;
                }
                Ok(r) => {
                    let (rot, dir) = pose_error(&r.b_from_a, &b_from_a);
                    assert!(
                        rot.to_degrees() < 0.5 && dir.to_degrees() < 2.0,
                        "trial {trial}: a wrong pose {rot} {dir}"
                    );
                    right += 1;
                }
                Err(other) => panic!("trial {trial}: {other}"),
            }
        }
        eprintln!("forward motion over a plane: {ambiguous} ambiguous, {right} right of 10");
        assert!(ambiguous >= 1);
    }

    #[test]
    fn bad_input_and_configuration_are_errors() {
        let m = vec![Vector2::new(0.1, 0.2); 5];
        assert!(matches!(
            bootstrap_pose(&m, &m, &config(0)),
            Err(TwoViewError::TooFewPoints { count: 5, .. })
        ));
        let m = vec![Vector2::new(0.1, 0.2); 20];
        assert!(matches!(
            bootstrap_pose(&m, &m[..19], &config(0)),
            Err(TwoViewError::LengthMismatch { .. })
        ));
        let bad = BootstrapConfig {
            pixel_sigma: 0.0,
            ..config(0)
        };
        assert!(matches!(
            bootstrap_pose(&m, &m, &bad),
            Err(TwoViewError::InvalidConfig(_))
        ));
        // All points coincide: no model, an error, not a panic.
        assert!(bootstrap_pose(&m, &m, &config(0)).is_err());
    }
}
