//! Geometric verification of a loop hypothesis (thesis §6.4.2): ORB matches between the two
//! keyframes, 3D–3D correspondences from their depths, the rigid motion of thesis eq. 6.9 in a
//! 3-point RANSAC, and guided matching under the found motion; or, for monocular maps, the
//! 3-point similarity with regressed depths (thesis §5.3.1, `slam::loop_closure`).
//!
//! # The inlier test
//!
//! A correspondence `x_q ↔ x_o` (query and old camera frames) is an inlier of
//! `T = query_from_old` when its Mahalanobis distance
//!
//! `e² = Δᵀ (Σ_q + R Σ_o Rᵀ)⁻¹ Δ`, `Δ = x_q − T·x_o`,
//!
//! is below the χ²₃ quantile of [`PlaceRecognitionConfig::inlier_probability`]. Each point's
//! covariance follows the sensor: along the viewing ray the depth error
//! `σ_z = c·z²` (a structured-light or stereo sensor: `c` = [`depth_noise`]), across it the
//! keypoint's position error `σ_⊥ = σ_px·s·z/f` (pixel noise `σ_px` at the keypoint's pyramid
//! scale `s`):
//!
//! `Σ = σ_⊥²·I + (σ_z²·‖x‖²/z² − σ_⊥²)·r rᵀ`, `r = x/‖x‖`.
//!
//! A fixed metric threshold would accept far points too easily and reject near ones; this
//! gate scales with the depth as the sensor's errors do.
//!
//! [`depth_noise`]: PlaceRecognitionConfig::depth_noise

use super::features::KeyframeFeatures;
use super::types::{Alignment, LoopMatch, PlaceRecognitionConfig};
use geom::CameraModel;
use geom::align::align_se3;
use geom::pnp::PnpEstimator;
use geom::ransac::{Estimator, GiveUp, RansacConfig, ransac_or_give_up};
use lie::{LieGroup, Se3, Sim3};
use nalgebra::{Matrix3, Vector2, Vector3};
use slam::loop_closure::{LoopClosureConfig, LoopView, estimate_loop_constraint};
use vision::orb::{DMatch, hamming, match_descriptors};

/// The outcome of verifying one hypothesis.
#[derive(Clone, Debug, PartialEq)]
pub enum Verification {
    /// Enough inliers: the relative pose and the matches consistent with it.
    Accepted {
        /// `x_query = S·x_old` (scale 1 in SE(3)).
        query_from_old: Sim3,
        /// Inliers of the RANSAC on the appearance matches (compared with Θ).
        ransac_inliers: usize,
        /// Inliers after guided matching and the final fit.
        inliers: Vec<LoopMatch>,
    },
    /// Fewer descriptor matches with depth than Θ: RANSAC was not tried.
    TooFewMatches {
        /// Matches found (with depth in both keyframes, for SE(3)).
        matches: usize,
    },
    /// RANSAC found fewer than Θ inliers (or no model).
    TooFewInliers {
        /// Matches tried.
        matches: usize,
        /// Inliers of the best model.
        inliers: usize,
    },
}

/// The covariance of a camera-frame point (see the [module docs](self)).
pub fn point_covariance(
    x: &Vector3<f64>,
    level_scale: f64,
    focal: f64,
    config: &PlaceRecognitionConfig,
) -> Matrix3<f64> {
    let z = x.z.max(1e-6);
    let perp = config.pixel_sigma * level_scale * z / focal;
    let n = x.norm().max(1e-12);
    let ray = config.depth_noise * z * z * n / z;
    let r = x / n;
    Matrix3::identity() * (perp * perp) + r * r.transpose() * (ray * ray - perp * perp)
}

/// The Mahalanobis distance of `x_q ↔ x_o` under `query_from_old` (see the
/// [module docs](self)); `∞` if the covariance is singular.
pub fn mahalanobis(
    query_from_old: &Se3,
    (x_q, cov_q): (&Vector3<f64>, &Matrix3<f64>),
    (x_o, cov_o): (&Vector3<f64>, &Matrix3<f64>),
) -> f64 {
    let r = query_from_old.rotation().rotation_matrix();
    let delta = x_q - query_from_old.act(x_o);
    let cov = cov_q + r * cov_o * r.transpose();
    cov.cholesky()
        .map_or(f64::INFINITY, |c| delta.dot(&c.solve(&delta)).sqrt())
}

/// The maximum-likelihood rigid motion under the noise model of the [module docs](self):
/// Gauss-Newton on `Σᵢ Δᵢᵀ Wᵢ Δᵢ`, `Δᵢ = x_q,i − T·x_o,i`, `Wᵢ = (Σ_q,i + R Σ_o,i Rᵀ)⁻¹`
/// (the weights re-evaluated at each iterate's rotation), from `start`, with the
/// left-multiplicative update `T ← exp(δ)·T` (thesis eq. 2.104) and `∂(exp(δ)·p)/∂δ = [I | −p̂]`
/// at `δ = 0`, `δ = (v, ω)`. Arun's closed form (eq. 6.9) weights every point alike, so the
/// far, noisy ones pull as hard as the near ones; this is the same fit weighted as the
/// inlier gate weighs. Returns `start` if the normal equations are singular.
pub fn refine_rigid(
    start: &Se3,
    target: &[(Vector3<f64>, Matrix3<f64>)],
    source: &[(Vector3<f64>, Matrix3<f64>)],
    iterations: usize,
) -> Se3 {
    let mut pose = *start;
    for _ in 0..iterations {
        let r = pose.rotation().rotation_matrix();
        let mut h = nalgebra::Matrix6::<f64>::zeros();
        let mut g = nalgebra::Vector6::<f64>::zeros();
        for ((x_q, cov_q), (x_o, cov_o)) in target.iter().zip(source) {
            let p = pose.act(x_o);
            let Some(w) = (cov_q + r * cov_o * r.transpose()).try_inverse() else {
                continue;
            };
            let mut a = nalgebra::Matrix3x6::<f64>::zeros();
            a.fixed_view_mut::<3, 3>(0, 0)
                .copy_from(&Matrix3::identity());
            a.fixed_view_mut::<3, 3>(0, 3).copy_from(&(-lie::skew(&p)));
            let aw = a.transpose() * w;
            h += aw * a;
            g += aw * (x_q - p);
        }
        let Some(delta) = h.cholesky().map(|c| c.solve(&g)) else {
            return pose;
        };
        pose = Se3::exp(&delta).compose(&pose);
        if delta.norm() < 1e-10 {
            break;
        }
    }
    pose
}

/// The rigid motion of thesis eq. 6.9 as a RANSAC problem: `target_i ≈ T·source_i`, minimal
/// samples of 3 by Arun's closed form (`geom::align::align_se3`), the re-fit to all inliers
/// by the same least squares, the error the Mahalanobis distance of the
/// [module docs](self).
pub struct RigidEstimator<'a> {
    /// Points in the target (query) frame.
    pub target: &'a [Vector3<f64>],
    /// Their covariances.
    pub target_cov: &'a [Matrix3<f64>],
    /// Points in the source (old) frame.
    pub source: &'a [Vector3<f64>],
    /// Their covariances.
    pub source_cov: &'a [Matrix3<f64>],
    /// Per correspondence, `tr Σ_q + tr Σ_o`: at least the largest eigenvalue of
    /// `Σ_q + R Σ_o Rᵀ` whatever `R` (a rotation keeps the eigenvalues; a covariance's largest
    /// is at most its trace), so `e² ≥ ‖Δ‖² / (tr Σ_q + tr Σ_o)`.
    spread: Vec<f64>,
}

impl<'a> RigidEstimator<'a> {
    /// The problem of the correspondences `target_i ≈ T·source_i` with their covariances
    /// (positive semi-definite, as `point_covariance`'s, for the bound of
    /// [`RigidEstimator::spread`]; it is computed here, from the covariances given).
    pub fn new(
        target: &'a [Vector3<f64>],
        target_cov: &'a [Matrix3<f64>],
        source: &'a [Vector3<f64>],
        source_cov: &'a [Matrix3<f64>],
    ) -> Self {
        let spread = target_cov
            .iter()
            .zip(source_cov)
            .map(|(q, o)| q.trace() + o.trace())
            .collect();
        RigidEstimator {
            target,
            target_cov,
            source,
            source_cov,
            spread,
        }
    }

    fn fit(&self, indices: &[usize]) -> Option<Se3> {
        let t: Vec<_> = indices.iter().map(|&i| self.target[i]).collect();
        let s: Vec<_> = indices.iter().map(|&i| self.source[i]).collect();
        align_se3(&t, &s).ok()
    }
}

impl Estimator for RigidEstimator<'_> {
    type Model = Se3;

    fn num_data(&self) -> usize {
        self.target.len().min(self.source.len())
    }

    fn sample_size(&self) -> usize {
        3
    }

    fn fit_minimal(&self, sample: &[usize], models: &mut Vec<Se3>) {
        models.extend(self.fit(sample));
    }

    fn fit_inliers(&self, inliers: &[usize], _current: &Se3) -> Option<Se3> {
        self.fit(inliers)
    }

    fn error(&self, model: &Se3, i: usize) -> f64 {
        mahalanobis(
            model,
            (&self.target[i], &self.target_cov[i]),
            (&self.source[i], &self.source_cov[i]),
        )
    }

    /// The bound of [`RigidEstimator::spread`] first: a correspondence whose Euclidean error
    /// alone puts it beyond the gate is an outlier without the covariance's Cholesky (most
    /// correspondences under a wrong model: a third of place recognition's time went to
    /// the Mahalanobis distance). The margin keeps rounding from deciding a datum the exact
    /// distance would decide otherwise.
    fn error_within(&self, model: &Se3, i: usize, threshold: f64) -> f64 {
        let delta = self.target[i] - model.act(&self.source[i]);
        if delta.norm_squared() > threshold * threshold * self.spread[i] * (1.0 + 1e-9) {
            return f64::INFINITY;
        }
        self.error(model, i)
    }
}

/// The RANSAC of a verification (`estimator` over the matches, inlier threshold `gate`, seeded
/// by the two keyframes' ids), accepted with at least Θ inliers; else the refusal to return.
///
/// A place that is not there costs RANSAC all its samples, and such places are most of the
/// verifications. So after [`early_refusal`]'s samples, a place whose best hypothesis explains
/// fewer than half of Θ is refused (`geom::ransac::ransac_or_give_up`). Any other search goes
/// on to its end, with the result it had before this check existed.
fn ransac_with_theta<E: Estimator>(
    estimator: &E,
    gate: f64,
    config: &PlaceRecognitionConfig,
    (query_id, old_id): (u32, u32),
) -> Result<geom::ransac::RansacResult<E::Model>, Verification> {
    let matches = estimator.num_data();
    let theta = config.min_inliers;
    let ransac_config = ransac_config(config, gate, hypothesis_seed(config, query_id, old_id));
    let give_up = GiveUp {
        after: early_refusal(config, matches, estimator.sample_size()),
        below: theta.div_ceil(2),
    };
    let Ok(result) = ransac_or_give_up(estimator, &ransac_config, give_up) else {
        return Err(Verification::TooFewInliers {
            matches,
            inliers: 0,
        });
    };
    if result.inliers.len() < theta {
        return Err(Verification::TooFewInliers {
            matches,
            inliers: result.inliers.len(),
        });
    }
    Ok(result)
}

/// A verification's RANSAC: inlier threshold `gate`, the configured confidence and sample
/// bound, at least 10 samples, `seed`.
fn ransac_config(config: &PlaceRecognitionConfig, gate: f64, seed: u64) -> RansacConfig {
    RansacConfig {
        threshold: gate,
        confidence: config.ransac_confidence,
        max_iterations: config.ransac_max_iterations,
        min_iterations: 10,
        seed,
    }
}

/// The samples after which a verification's RANSAC refuses a place whose best hypothesis
/// explains fewer than Θ/2 matches ([`ransac_with_theta`]): as many as it takes to draw an
/// all-inlier sample with probability `ransac_confidence` if Θ of the `matches` were inliers
/// (`geom::ransac::required_iterations` at the ratio Θ / matches), at most
/// `ransac_max_iterations`. The standard bound assumes that an all-inlier sample's hypothesis
/// explains all the inliers; with noisy points a minimal sample's hypothesis (refitted, LO-RANSAC)
/// explains fewer, so a place is given up only if no hypothesis explains half of Θ. A place at
/// Θ is then lost only if none of this many samples was all-inlier (probability at most 1 −
/// `ransac_confidence`) or the one that was explains under half its inliers. Requiring the
/// full Θ instead missed two loops with 20 and 21 inliers in twelve runs (7-Scenes RGB-D 500,
/// the rendered courtyard; bench/README, thirteenth session).
fn early_refusal(config: &PlaceRecognitionConfig, matches: usize, sample_size: usize) -> usize {
    let theta = config.min_inliers.max(sample_size);
    let ratio = theta as f64 / matches.max(1) as f64;
    geom::ransac::required_iterations(ratio, sample_size, config.ransac_confidence)
        .clamp(1, config.ransac_max_iterations)
}

/// The seed of one hypothesis's RANSAC: the configured seed mixed with the two keyframes'
/// ids, so that a verification gives the same result whatever was verified before it.
fn hypothesis_seed(config: &PlaceRecognitionConfig, query: u32, old: u32) -> u64 {
    config
        .seed
        .wrapping_add(((query as u64) << 32) | old as u64)
        .wrapping_mul(0x9e37_79b9_7f4a_7c15)
}

fn focal(f: &KeyframeFeatures) -> f64 {
    0.5 * (f.camera.fx + f.camera.fy)
}

/// Verifies the hypothesis that `query` sees the place of `old` (ids for the seed).
pub fn verify(
    (query_id, query): (u32, &KeyframeFeatures),
    (old_id, old): (u32, &KeyframeFeatures),
    config: &PlaceRecognitionConfig,
) -> Verification {
    match config.alignment {
        Alignment::Se3 => verify_rigid((query_id, query), (old_id, old), config),
        Alignment::Sim3 => verify_similarity((query_id, query), (old_id, old), config),
    }
}

/// Descriptor matches between the keypoints `qi` of the query and `oi` of the old keyframe
/// (ratio test and cross-check), as index pairs into the keyframes' keypoints.
fn match_subsets(
    query: &KeyframeFeatures,
    qi: &[usize],
    old: &KeyframeFeatures,
    oi: &[usize],
    config: &PlaceRecognitionConfig,
) -> Vec<DMatch> {
    let qd: Vec<_> = qi.iter().map(|&i| query.descriptors[i]).collect();
    let od: Vec<_> = oi.iter().map(|&i| old.descriptors[i]).collect();
    match_descriptors(&qd, &od, config.max_hamming, config.ratio, true)
        .into_iter()
        .map(|m| DMatch {
            query: qi[m.query],
            train: oi[m.train],
            distance: m.distance,
        })
        .collect()
}

fn loop_match(query: &KeyframeFeatures, old: &KeyframeFeatures, m: &DMatch) -> LoopMatch {
    let (q, o) = (&query.keypoints[m.query], &old.keypoints[m.train]);
    LoopMatch {
        query: m.query,
        old: m.train,
        query_pixel: Vector2::new(q.u as f64, q.v as f64),
        old_pixel: Vector2::new(o.u as f64, o.v as f64),
        distance: m.distance,
    }
}

fn verify_rigid(
    (query_id, query): (u32, &KeyframeFeatures),
    (old_id, old): (u32, &KeyframeFeatures),
    config: &PlaceRecognitionConfig,
) -> Verification {
    let with_depth = |f: &KeyframeFeatures| -> Vec<usize> {
        (0..f.points.len())
            .filter(|&i| f.points[i].is_some())
            .collect()
    };
    let matches = match_subsets(query, &with_depth(query), old, &with_depth(old), config);
    if matches.len() < config.min_inliers.max(3) {
        return Verification::TooFewMatches {
            matches: matches.len(),
        };
    }
    let cov = |f: &KeyframeFeatures, i: usize| {
        point_covariance(
            &f.points[i].expect("matched keypoints have points"),
            f.keypoints[i].scale as f64,
            focal(f),
            config,
        )
    };
    let target: Vec<_> = matches
        .iter()
        .map(|m| query.points[m.query].unwrap_or_default())
        .collect();
    let source: Vec<_> = matches
        .iter()
        .map(|m| old.points[m.train].unwrap_or_default())
        .collect();
    let target_cov: Vec<_> = matches.iter().map(|m| cov(query, m.query)).collect();
    let source_cov: Vec<_> = matches.iter().map(|m| cov(old, m.train)).collect();
    let gate = config.inlier_gate();
    let estimator = RigidEstimator::new(&target, &target_cov, &source, &source_cov);
    let result = match ransac_with_theta(&estimator, gate, config, (query_id, old_id)) {
        Ok(result) => result,
        Err(refused) => return refused,
    };
    let ransac_inliers = result.inliers.len();
    let mut pairs: Vec<DMatch> = result.inliers.iter().map(|&i| matches[i]).collect();
    let mut pose = result.model;
    // Guided matching (thesis §6.4.2, "guided matching"): the old keyframe's points projected
    // into the query under the found motion are searched for among the query's keypoints near
    // their prediction; then the motion is re-fitted to all consistent matches.
    for _ in 0..2 {
        pairs = guided_matches(query, old, &pose, pairs, config);
        let t: Vec<_> = pairs
            .iter()
            .map(|m| {
                (
                    query.points[m.query].unwrap_or_default(),
                    cov(query, m.query),
                )
            })
            .collect();
        let s: Vec<_> = pairs
            .iter()
            .map(|m| (old.points[m.train].unwrap_or_default(), cov(old, m.train)))
            .collect();
        {
            let refit = refine_rigid(&pose, &t, &s, 5);
            let consistent: Vec<DMatch> = pairs
                .iter()
                .copied()
                .filter(|m| {
                    let (q, o) = (m.query, m.train);
                    mahalanobis(
                        &refit,
                        (&query.points[q].unwrap_or_default(), &cov(query, q)),
                        (&old.points[o].unwrap_or_default(), &cov(old, o)),
                    ) <= gate
                })
                .collect();
            if consistent.len() >= config.min_inliers {
                pose = refit;
                pairs = consistent;
            }
        }
    }
    Verification::Accepted {
        query_from_old: Sim3::from_se3(&pose),
        ransac_inliers,
        inliers: pairs.iter().map(|m| loop_match(query, old, m)).collect(),
    }
}

/// `pairs` plus the matches guided matching finds under `pose` (see [`verify_rigid`]): for
/// each old keypoint with a point and no match yet, the unmatched query keypoint with a point
/// within [`PlaceRecognitionConfig::guided_radius`] × its pyramid scale of the prediction, on
/// a neighbouring pyramid level, nearest in Hamming distance (≤ `max_hamming`), kept if its 3D
/// point passes the inlier gate.
fn guided_matches(
    query: &KeyframeFeatures,
    old: &KeyframeFeatures,
    pose: &Se3,
    mut pairs: Vec<DMatch>,
    config: &PlaceRecognitionConfig,
) -> Vec<DMatch> {
    let mut query_used = vec![false; query.keypoints.len()];
    let mut old_used = vec![false; old.keypoints.len()];
    for m in &pairs {
        query_used[m.query] = true;
        old_used[m.train] = true;
    }
    let gate = config.inlier_gate();
    for (o, x_o) in old.points.iter().enumerate() {
        let Some(x_o) = x_o else { continue };
        if old_used[o] {
            continue;
        }
        let x_q = pose.act(x_o);
        let Ok(predicted) = query.camera.project(&x_q) else {
            continue;
        };
        let kp_o = &old.keypoints[o];
        let radius = config.guided_radius * kp_o.scale as f64;
        let mut best: Option<(u32, usize)> = None;
        for (q, kp_q) in query.keypoints.iter().enumerate() {
            if query_used[q] || query.points[q].is_none() || kp_q.level.abs_diff(kp_o.level) > 1 {
                continue;
            }
            let d2 = (kp_q.u as f64 - predicted.x).powi(2) + (kp_q.v as f64 - predicted.y).powi(2);
            if d2 > radius * radius {
                continue;
            }
            let h = hamming(&query.descriptors[q], &old.descriptors[o]);
            if h <= config.max_hamming && best.is_none_or(|b| h < b.0) {
                best = Some((h, q));
            }
        }
        if let Some((h, q)) = best {
            let cov_q = point_covariance(
                &query.points[q].unwrap_or_default(),
                query.keypoints[q].scale as f64,
                focal(query),
                config,
            );
            let cov_o = point_covariance(x_o, kp_o.scale as f64, focal(old), config);
            if mahalanobis(
                pose,
                (&query.points[q].unwrap_or_default(), &cov_q),
                (x_o, &cov_o),
            ) <= gate
            {
                query_used[q] = true;
                old_used[o] = true;
                pairs.push(DMatch {
                    query: q,
                    train: o,
                    distance: h,
                });
            }
        }
    }
    pairs
}

/// A query without depth (a monocular frame to relocalise) against an old keyframe: 2D–3D
/// instead of 3D–3D. Descriptor matches from the query's keypoints to the old keypoints with
/// a point — measured (stereo, RGB-D) or, in a monocular map, its depth regressed from the
/// keyframe's map points as for a loop (`slam::loop_closure::knn_depth`, thesis §5.3.1) — then
/// the query camera's pose in the old camera frame by P3P RANSAC (`geom::pnp`) on the
/// re-projection error `‖proj(T·x_o) − m_q‖ / σ_q` (σ_q: [`PlaceRecognitionConfig::pixel_sigma`]
/// at the query keypoint's pyramid scale) gated at `√χ²₂(inlier_probability)`, re-fitted by
/// Gauss-Newton to the inliers. Accepted with at least Θ inliers; `query_from_old` is then
/// rigid (scale 1), in the old keyframe's camera units.
pub fn verify_absolute(
    (query_id, query): (u32, &KeyframeFeatures),
    (old_id, old): (u32, &KeyframeFeatures),
    config: &PlaceRecognitionConfig,
) -> Verification {
    let loop_config = LoopClosureConfig::default();
    let old_points: Vec<Option<Vector3<f64>>> = (0..old.keypoints.len())
        .map(|i| {
            old.points[i].or_else(|| {
                let kp = &old.keypoints[i];
                let z = Vector2::new(kp.u as f64, kp.v as f64);
                let d = slam::loop_closure::knn_depth(
                    &z,
                    &old.depth_samples,
                    loop_config.knn,
                    loop_config.knn_max_distance,
                )?;
                old.camera.unproject_depth(&z, d).ok()
            })
        })
        .collect();
    let with_point: Vec<usize> = (0..old_points.len())
        .filter(|&i| old_points[i].is_some())
        .collect();
    let all: Vec<usize> = (0..query.keypoints.len()).collect();
    let matches = match_subsets(query, &all, old, &with_point, config);
    if matches.len() < config.min_inliers.max(3) {
        return Verification::TooFewMatches {
            matches: matches.len(),
        };
    }
    let f = focal(query);
    let normalised: Vec<Vector2<f64>> = matches
        .iter()
        .map(|m| {
            let kp = &query.keypoints[m.query];
            query
                .camera
                .normalised_from_pixel(&Vector2::new(kp.u as f64, kp.v as f64))
        })
        .collect();
    let points: Vec<Vector3<f64>> = matches
        .iter()
        .map(|m| old_points[m.train].unwrap_or_default())
        .collect();
    let sigma: Vec<f64> = matches
        .iter()
        .map(|m| config.pixel_sigma * query.keypoints[m.query].scale as f64 / f)
        .collect();
    let estimator = PnpEstimator {
        normalised: &normalised,
        points: &points,
        sigma: &sigma,
    };
    let gate = lsq::chi2_quantile(2, config.inlier_probability).sqrt();
    let result = match ransac_with_theta(&estimator, gate, config, (query_id, old_id)) {
        Ok(result) => result,
        Err(refused) => return refused,
    };
    let ransac_inliers = result.inliers.len();
    let pose = estimator
        .refine(&result.model, &result.inliers, 10)
        .unwrap_or(result.model);
    let inliers: Vec<LoopMatch> = (0..matches.len())
        .filter(|&i| estimator.error(&pose, i) <= gate)
        .map(|i| loop_match(query, old, &matches[i]))
        .collect();
    if inliers.len() < config.min_inliers {
        return Verification::TooFewInliers {
            matches: matches.len(),
            inliers: inliers.len(),
        };
    }
    Verification::Accepted {
        query_from_old: Sim3::from_se3(&pose),
        ransac_inliers,
        inliers,
    }
}

/// Monocular maps (thesis §6.4.2, "in the case of monocular SLAM"): all descriptor matches,
/// each keypoint's depth known (its point) or regressed from the keyframe's depth samples, and
/// the similarity from `slam::loop_closure::estimate_loop_constraint` (3-point Sim(3) RANSAC
/// and robust two-view refinement, thesis §5.3.1).
fn verify_similarity(
    (query_id, query): (u32, &KeyframeFeatures),
    (old_id, old): (u32, &KeyframeFeatures),
    config: &PlaceRecognitionConfig,
) -> Verification {
    let all = |f: &KeyframeFeatures| -> Vec<usize> { (0..f.keypoints.len()).collect() };
    let matches = match_subsets(query, &all(query), old, &all(old), config);
    if matches.len() < config.min_inliers.max(3) {
        return Verification::TooFewMatches {
            matches: matches.len(),
        };
    }
    let view = |f: &KeyframeFeatures, index: &dyn Fn(&DMatch) -> usize| LoopView {
        pixels: matches
            .iter()
            .map(|m| {
                let kp = &f.keypoints[index(m)];
                Vector2::new(kp.u as f64, kp.v as f64)
            })
            .collect(),
        depths: matches
            .iter()
            .map(|m| f.points[index(m)].map(|p| p.z))
            .collect(),
        samples: f.depth_samples.clone(),
    };
    let old_view = view(old, &|m| m.train);
    let query_view = view(query, &|m| m.query);
    let mut loop_config = LoopClosureConfig {
        min_inliers: config.min_inliers,
        ..LoopClosureConfig::default()
    };
    loop_config.ransac.seed = hypothesis_seed(config, query_id, old_id);
    loop_config.ransac.confidence = config.ransac_confidence;
    // Not refused early as a rigid verification is ([`early_refusal`]): the similarity is
    // accepted on the inliers of the two-view refinement after the RANSAC, not on the
    // RANSAC's own, so a RANSAC hypothesis with fewer than Θ inliers may still be accepted.
    loop_config.ransac.max_iterations = config.ransac_max_iterations;
    // The two keyframes share one camera model in the live system; the old one's is used.
    match estimate_loop_constraint(&old.camera, &old_view, &query_view, &loop_config) {
        Ok(c) => Verification::Accepted {
            query_from_old: c.old_from_current.inverse(),
            ransac_inliers: c.inliers.len(),
            inliers: c
                .inliers
                .iter()
                .map(|&i| loop_match(query, old, &matches[i]))
                .collect(),
        },
        Err(slam::loop_closure::LoopClosureError::TooFewInliers { inliers, .. }) => {
            Verification::TooFewInliers {
                matches: matches.len(),
                inliers,
            }
        }
        Err(_) => Verification::TooFewInliers {
            matches: matches.len(),
            inliers: 0,
        },
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use geom::ransac::ransac;
    use lie::So3;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// RANSAC with a known outlier ratio: 40 % inliers with Kinect-like noise among 60 %
    /// outliers; the rigid motion is recovered to the noise level and the inliers are
    /// exactly the true ones (up to outliers that happen to fall within the gate, counted).
    #[test]
    fn rigid_ransac_with_a_known_outlier_ratio() {
        let config = PlaceRecognitionConfig::default();
        let focal = 585.0;
        let mut rng = ChaCha8Rng::seed_from_u64(11);
        let truth = Se3::new(
            So3::exp(&Vector3::new(0.1, -0.4, 0.2)),
            Vector3::new(0.3, -0.1, 0.2),
        );
        for (trial, outlier_ratio) in [0.3, 0.5, 0.6, 0.8].into_iter().enumerate() {
            let n = 200;
            let mut source = Vec::new();
            let mut target = Vec::new();
            let mut is_inlier = Vec::new();
            for _ in 0..n {
                let x_o = Vector3::new(
                    rng.random_range(-1.5..1.5),
                    rng.random_range(-1.0..1.0),
                    rng.random_range(1.0..4.0),
                );
                let cov_o = point_covariance(&x_o, 1.0, focal, &config);
                let x_q = truth.act(&x_o);
                let cov_q = point_covariance(&x_q, 1.0, focal, &config);
                // Noise drawn from the model's covariances.
                let noisy = |x: &Vector3<f64>, c: &Matrix3<f64>, rng: &mut ChaCha8Rng| {
                    let l = c.cholesky().unwrap().l();
                    // Box–Muller standard normals.
                    let g = Vector3::from_fn(|_, _| {
                        let (u1, u2): (f64, f64) = (rng.random_range(1e-12..1.0), rng.random());
                        (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
                    });
                    x + l * g
                };
                let outlier = rng.random::<f64>() < outlier_ratio;
                let x_o_noisy = noisy(&x_o, &cov_o, &mut rng);
                let x_q_noisy = if outlier {
                    Vector3::new(
                        rng.random_range(-2.0..2.0),
                        rng.random_range(-1.5..1.5),
                        rng.random_range(0.8..4.5),
                    )
                } else {
                    noisy(&x_q, &cov_q, &mut rng)
                };
                source.push(x_o_noisy);
                target.push(x_q_noisy);
                is_inlier.push(!outlier);
            }
            let cov = |p: &Vector3<f64>| point_covariance(p, 1.0, focal, &config);
            let target_cov: Vec<_> = target.iter().map(cov).collect();
            let source_cov: Vec<_> = source.iter().map(cov).collect();
            let estimator = RigidEstimator::new(&target, &target_cov, &source, &source_cov);
            let r = ransac(
                &estimator,
                &ransac_config(&config, config.inlier_gate(), trial as u64),
            )
            .unwrap();
            let err = r.model.compose(&truth.inverse());
            let (dt, dr) = (err.translation().norm(), err.rotation().angle());
            assert!(dt < 0.01 && dr < 0.005, "trial {trial}: {dt} m, {dr} rad");
            let true_inliers = is_inlier.iter().filter(|&&b| b).count();
            let found_true = r.inliers.iter().filter(|&&i| is_inlier[i]).count();
            let found_false = r.inliers.len() - found_true;
            // The 99 % gate keeps ≥ 95 % of the true inliers (binomial margin) and admits only
            // the few outliers that land within a few centimetres of their prediction.
            assert!(
                found_true as f64 >= 0.95 * true_inliers as f64,
                "trial {trial}: {found_true}/{true_inliers}"
            );
            assert!(
                found_false <= 3,
                "trial {trial}: {found_false} outliers accepted"
            );
            // The iteration count follows the inlier ratio (p = 0.999, s = 3).
            let w = r.inliers.len() as f64 / n as f64;
            assert!(
                r.iterations <= geom::ransac::required_iterations(w, 3, 0.999).max(10) * 3,
                "trial {trial}: {} iterations at w = {w}",
                r.iterations
            );
        }
    }

    /// The verification's early refusal ([`early_refusal`]): a place with exactly Θ inliers
    /// among the matches is still found, and a place with Θ/4 would cost the unbounded search
    /// more samples than the bound after which it is refused.
    #[test]
    fn a_place_with_theta_inliers_is_found_and_a_hopeless_one_given_up() {
        let config = PlaceRecognitionConfig::default();
        let theta = config.min_inliers;
        assert_eq!(
            early_refusal(&config, 100, 3),
            geom::ransac::required_iterations(theta as f64 / 100.0, 3, config.ransac_confidence)
        );
        assert_eq!(
            early_refusal(&config, 10_000, 3),
            config.ransac_max_iterations
        );
        let focal = 585.0;
        let truth = Se3::new(
            So3::exp(&Vector3::new(0.2, 0.1, -0.3)),
            Vector3::new(-0.2, 0.1, 0.4),
        );
        let n = 70;
        let bound = early_refusal(&config, n, 3);
        assert!(bound < config.ransac_max_iterations / 4, "{bound}");
        let mut found = [0; 2];
        let trials = 100;
        for seed in 0..trials {
            let mut rng = ChaCha8Rng::seed_from_u64(seed);
            // Θ inliers, then Θ / 4.
            for (case, inliers) in [theta, theta / 4].into_iter().enumerate() {
                let (mut source, mut target) = (Vec::new(), Vec::new());
                for i in 0..n {
                    let x_o = Vector3::new(
                        rng.random_range(-1.5..1.5),
                        rng.random_range(-1.0..1.0),
                        rng.random_range(1.0..4.0),
                    );
                    source.push(x_o);
                    target.push(if i < inliers {
                        truth.act(&x_o)
                    } else {
                        Vector3::new(
                            rng.random_range(-2.0..2.0),
                            rng.random_range(-1.5..1.5),
                            rng.random_range(0.8..4.5),
                        )
                    });
                }
                let cov = |p: &Vector3<f64>| point_covariance(p, 1.0, focal, &config);
                let target_cov: Vec<_> = target.iter().map(cov).collect();
                let source_cov: Vec<_> = source.iter().map(cov).collect();
                let estimator = RigidEstimator::new(&target, &target_cov, &source, &source_cov);
                if ransac_with_theta(
                    &estimator,
                    config.inlier_gate(),
                    &config,
                    (seed as u32, 1000),
                )
                .is_ok()
                {
                    found[case] += 1;
                } else if case == 1 {
                    // Without the bound, a place that is not there costs more samples.
                    let unbounded = ransac(
                        &estimator,
                        &ransac_config(&config, config.inlier_gate(), seed),
                    )
                    .unwrap();
                    assert!(unbounded.iterations > bound, "{}", unbounded.iterations);
                }
            }
        }
        // Θ inliers: missed with probability ≤ 1 − 0.999 per trial (and by outliers that
        // pull the fit); Θ / 4: never accepted.
        assert!(found[0] >= trials - 2, "{found:?}");
        assert_eq!(found[1], 0, "{found:?}");
    }

    /// Heteroscedastic noise (σ ∝ z²): the weighted refinement is exact on exact data and
    /// beats Arun's unweighted fit on noisy data (over 20 trials, in mean rotation error).
    #[test]
    fn weighted_refinement_beats_the_unweighted_fit() {
        let config = PlaceRecognitionConfig::default();
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let truth = Se3::new(
            So3::exp(&Vector3::new(0.2, 0.3, -0.1)),
            Vector3::new(0.2, 0.0, -0.3),
        );
        let (mut arun_total, mut refined_total) = (0.0, 0.0);
        for trial in 0..20 {
            let mut target = Vec::new();
            let mut source = Vec::new();
            for _ in 0..80 {
                let x_o = Vector3::new(
                    rng.random_range(-2.0..2.0),
                    rng.random_range(-1.5..1.5),
                    rng.random_range(0.8..6.0),
                );
                let x_q = truth.act(&x_o);
                let (c_o, c_q) = (
                    point_covariance(&x_o, 1.0, 585.0, &config),
                    point_covariance(&x_q, 1.0, 585.0, &config),
                );
                let sample = |x: &Vector3<f64>, c: &Matrix3<f64>, rng: &mut ChaCha8Rng| {
                    let g = Vector3::from_fn(|_, _| {
                        let (u1, u2): (f64, f64) = (rng.random_range(1e-12..1.0), rng.random());
                        (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
                    });
                    if trial == 0 {
                        *x
                    } else {
                        x + c.cholesky().unwrap().l() * g
                    }
                };
                source.push((sample(&x_o, &c_o, &mut rng), c_o));
                target.push((sample(&x_q, &c_q, &mut rng), c_q));
            }
            let t: Vec<_> = target.iter().map(|p| p.0).collect();
            let s: Vec<_> = source.iter().map(|p| p.0).collect();
            let arun = align_se3(&t, &s).unwrap();
            let refined = refine_rigid(&arun, &target, &source, 10);
            let err = |p: &Se3| p.compose(&truth.inverse()).rotation().angle();
            if trial == 0 {
                assert!(err(&refined) < 1e-9 && err(&arun) < 1e-9);
                continue;
            }
            arun_total += err(&arun);
            refined_total += err(&refined);
        }
        assert!(
            refined_total < 0.8 * arun_total,
            "{refined_total} vs {arun_total}"
        );
    }

    #[test]
    fn the_gate_scales_with_depth() {
        let config = PlaceRecognitionConfig::default();
        let identity = Se3::default();
        let near = Vector3::new(0.0, 0.0, 1.0);
        let far = Vector3::new(0.0, 0.0, 4.0);
        let c = |x: &Vector3<f64>| point_covariance(x, 1.0, 585.0, &config);
        // A 2 cm depth error is far outside the gate at 1 m, well inside at 4 m.
        let dz = Vector3::new(0.0, 0.0, 0.02);
        let e_near = mahalanobis(&identity, (&(near + dz), &c(&near)), (&near, &c(&near)));
        let e_far = mahalanobis(&identity, (&(far + dz), &c(&far)), (&far, &c(&far)));
        assert!(
            e_near > config.inlier_gate() && e_far < config.inlier_gate(),
            "{e_near} {e_far}"
        );
        // Lateral errors are measured against the (smaller) lateral σ.
        let dx = Vector3::new(0.02, 0.0, 0.0);
        let e_lat = mahalanobis(&identity, (&(far + dx), &c(&far)), (&far, &c(&far)));
        assert!(e_lat > e_far, "{e_lat} {e_far}");
    }

    /// The bound in `RigidEstimator::error_within` decides every datum as the exact
    /// Mahalanobis distance does, and gives that distance for the inliers: random points at
    /// 0.5–8 m under random motions, errors from millimetres to metres, near and far pyramid
    /// levels.
    #[test]
    fn the_cheap_bound_decides_as_the_mahalanobis_distance() {
        use rand::{Rng, SeedableRng};
        let config = PlaceRecognitionConfig::default();
        let gate = config.inlier_gate();
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        let n = 400;
        let mut target = Vec::new();
        let mut source = Vec::new();
        let mut target_cov = Vec::new();
        let mut source_cov = Vec::new();
        let truth = Se3::exp(&nalgebra::Vector6::new(0.3, -0.1, 0.2, 0.1, -0.2, 0.05));
        for i in 0..n {
            let x_o = Vector3::new(
                rng.random_range(-2.0..2.0),
                rng.random_range(-1.5..1.5),
                rng.random_range(0.5..8.0),
            );
            let noise = 10f64.powf(rng.random_range(-3.0..0.3));
            let dir = Vector3::new(
                rng.random_range(-1.0..1.0),
                rng.random_range(-1.0..1.0),
                rng.random_range(-1.0..1.0),
            );
            let x_q = truth.act(&x_o) + dir * noise;
            let level = (1.2f64).powi((i % 8) as i32);
            source_cov.push(point_covariance(&x_o, level, 585.0, &config));
            target_cov.push(point_covariance(&x_q, level, 585.0, &config));
            source.push(x_o);
            target.push(x_q);
        }
        let estimator = RigidEstimator::new(&target, &target_cov, &source, &source_cov);
        let (mut inside, mut bounded) = (0, 0);
        for m in 0..20 {
            let model = if m == 0 {
                truth
            } else {
                let d = nalgebra::Vector6::from_fn(|_, _| rng.random_range(-0.05..0.05));
                Se3::exp(&d).compose(&truth)
            };
            for i in 0..n {
                let exact = estimator.error(&model, i);
                let within = estimator.error_within(&model, i, gate);
                assert_eq!(exact <= gate, within <= gate, "datum {i}: {exact} {within}");
                if exact <= gate {
                    assert_eq!(exact, within);
                    inside += 1;
                } else if within.is_infinite() {
                    bounded += 1;
                }
            }
        }
        // Both kinds occur, and the bound settles most outliers.
        assert!(inside > 100, "{inside}");
        assert!(
            bounded > (20 * n - inside) / 2,
            "{bounded} of {}",
            20 * n - inside
        );
    }
}
