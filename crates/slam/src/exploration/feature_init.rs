//! Feature initialisation by a set of independent inverse-depth Gauss-Newton filters (thesis
//! §3.4.4, eq. 3.35–3.37; §4.5.3 eq. 4.26).
//!
//! A new feature is first seen in an *anchor* frame `T_aw` (a keyframe). It is represented by
//! the anchored inverse-depth point `ψ = (ψ₁, ψ₂, ψ₃)`: normalised image coordinates
//! `(ψ₁, ψ₂)` in the anchor and the inverse depth `q = ψ₃`; its Euclidean position is
//! `y = T_aw⁻¹·Π(ψ)` with `Π(ψ) = (ψ₁/ψ₃, ψ₂/ψ₃, 1/ψ₃)` (thesis §B.3).
//!
//! Given the current camera pose `T_lw`, the features are independent (thesis eq. 3.35), so each
//! one is estimated by its own 3-dimensional information filter `⟨ψ̂, Λ_ψ⟩`. A new measurement
//! `z` of the feature in frame `T_lw` updates it by minimising (thesis eq. 3.36, 2.34)
//!
//! `χ²(ψ) = (ψ − ψ̂)ᵀ Λ_ψ (ψ − ψ̂) + (ẑ(T_lw·T_aw⁻¹·Π(ψ)) − z)ᵀ Λ_z (ẑ(T_lw·T_aw⁻¹·Π(ψ)) − z)`
//!
//! with Levenberg-Marquardt, then propagates the information (thesis eq. 3.37, 2.35)
//!
//! `Λ_ψ ← Λ_ψ + Jᵀ Λ_z J`, `J = ∂ẑ/∂ψ = ∂ẑ/∂x · R_la · ∂Π/∂ψ` (thesis eq. B.15, B.21)
//!
//! at the new estimate. The initial information is that of the anchor measurement,
//! `Λ_ψ⁽⁰⁾ = J₀ᵀ Λ_z J₀` with `J₀ = ∂ẑ(Π(ψ))/∂ψ`: for a monocular pinhole camera this is
//! exactly `diag(f²/σ², f²/σ², 0)` (thesis §3.4.4, eq. 4.26) — infinite uncertainty along the
//! depth, so no depth prior is imposed whatever the start value of `q`; for a stereo or RGB-D
//! camera (`N = 3`) it has full rank, the depth being measured directly (thesis eq. 3.9).
//!
//! A feature is *converged* and may be promoted to the map (to be jointly bundle adjusted) when
//! its inverse-depth standard deviation, from the marginal covariance `Λ_ψ⁻¹`, is a small
//! fraction of its inverse depth, `σ_q ≤ κ·q` — i.e. the depth is known to about `κ` relative
//! accuracy — after a minimum number of measurements.

use crate::factors::{Projector, inverse_depth_to_point, predict_inverse_depth};
use lie::{LieGroup, Se3};
use nalgebra::{Matrix3, SMatrix, SVector, Vector3};
use std::collections::BTreeMap;

/// Parameters of the feature-initialisation filters.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FeatureInitConfig {
    /// Measurement noise σ_z (measurement units, e.g. pixels): `Λ_z = I/σ_z²`.
    pub sigma: f64,
    /// Promotion threshold `κ`: a feature is converged when `σ_q ≤ κ·q`.
    pub max_relative_inverse_depth_std: f64,
    /// Promotion also needs at least this many measurements (the anchor's included).
    pub min_observations: usize,
    /// A measurement whose whitened residual `rᵀΛ_z r` after the update exceeds this is
    /// rejected as an outlier and leaves the filter unchanged. `None`: the 99.9 % quantile of
    /// χ² with `N` degrees of freedom ([`lsq::chi2_quantile`]).
    pub outlier_chi2: Option<f64>,
    /// Levenberg-Marquardt iterations per update at most.
    pub max_iterations: usize,
}

impl Default for FeatureInitConfig {
    /// σ_z = 1 px; promotion at 10 % relative inverse-depth (≈ depth) uncertainty after at
    /// least 3 measurements; 99.9 % outlier gate; 10 iterations.
    fn default() -> Self {
        FeatureInitConfig {
            sigma: 1.0,
            max_relative_inverse_depth_std: 0.1,
            min_observations: 3,
            outlier_chi2: None,
            max_iterations: 10,
        }
    }
}

/// Identifies a feature in a [`FeatureFilters`] set.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct FeatureId(pub usize);

/// One partially initialised feature: an anchored inverse-depth point with its information
/// matrix and the measurements it has taken in (thesis §3.4.4).
#[derive(Clone, Debug, PartialEq)]
pub struct InverseDepthFilter<const N: usize> {
    /// The caller's index of the anchor frame (keyframe).
    pub anchor_frame: usize,
    /// The anchor's `camera_from_world` `T_aw`.
    pub anchor_from_world: Se3,
    /// The estimate `ψ̂ = (ψ₁, ψ₂, q)` in the anchor frame.
    pub psi: Vector3<f64>,
    /// Its information matrix `Λ_ψ`.
    pub information: Matrix3<f64>,
    /// `(frame, z)` of every accepted measurement, the anchor's first.
    pub observations: Vec<(usize, SVector<f64, N>)>,
}

impl<const N: usize> InverseDepthFilter<N> {
    /// The filter of a feature measured at `measurement` in its anchor, with the starting
    /// estimate `psi` (which must reproject onto the measurement: `ψ₁, ψ₂` from the
    /// back-projected ray, and for a monocular camera any positive start value of `q`) and the
    /// information of that single measurement, `Λ_ψ⁽⁰⁾ = J₀ᵀΛ_zJ₀` (thesis §3.4.4, eq. 4.26).
    /// `None` if `psi` is not projectable.
    pub fn new<P: Projector<N>>(
        projector: &P,
        sigma: f64,
        anchor_frame: usize,
        anchor_from_world: Se3,
        measurement: SVector<f64, N>,
        psi: Vector3<f64>,
    ) -> Option<Self> {
        let (_, j0) = predict_inverse_depth(projector, Some(&Se3::identity()), &psi)?;
        let information = j0.transpose() * j0 / (sigma * sigma);
        Some(InverseDepthFilter {
            anchor_frame,
            anchor_from_world,
            psi,
            information,
            observations: vec![(anchor_frame, measurement)],
        })
    }

    /// The estimated point in world coordinates, `T_aw⁻¹·Π(ψ)`.
    pub fn point_world(&self) -> Vector3<f64> {
        self.anchor_from_world
            .inverse()
            .act(&inverse_depth_to_point(&self.psi))
    }

    /// The marginal covariance `Λ_ψ⁻¹`, or `None` while the depth is unobserved (`Λ_ψ`
    /// singular).
    pub fn covariance(&self) -> Option<Matrix3<f64>> {
        let c = self.information.cholesky()?;
        let cov = c.inverse();
        cov.iter().all(|v| v.is_finite()).then_some(cov)
    }

    /// The standard deviation of the inverse depth `σ_q = √(Λ_ψ⁻¹)₃₃`, or `None` while it is
    /// unobserved.
    pub fn inverse_depth_std(&self) -> Option<f64> {
        self.covariance().map(|c| c[(2, 2)].max(0.0).sqrt())
    }

    /// Whether the feature may be promoted to the map: `σ_q ≤ κ·q` after at least the
    /// configured number of measurements.
    pub fn is_converged(&self, config: &FeatureInitConfig) -> bool {
        self.observations.len() >= config.min_observations
            && self
                .inverse_depth_std()
                .is_some_and(|s| s <= config.max_relative_inverse_depth_std * self.psi.z)
    }

    /// The predicted measurement from `observer_from_world`, if projectable (for guided search
    /// of the feature in a new image).
    pub fn predict<P: Projector<N>>(
        &self,
        projector: &P,
        observer_from_world: &Se3,
    ) -> Option<SVector<f64, N>> {
        let t_la = observer_from_world.compose(&self.anchor_from_world.inverse());
        predict_inverse_depth(projector, Some(&t_la), &self.psi).map(|(z, _)| z)
    }

    /// The Gauss-Newton filter update with measurement `z` taken from `observer_from_world` in
    /// frame `frame` (thesis eq. 3.36–3.37): minimises `χ²(ψ)` by Levenberg-Marquardt from
    /// `ψ̂`, then adds `JᵀΛ_zJ` at the new estimate to `Λ_ψ`.
    pub fn update<P: Projector<N>>(
        &mut self,
        projector: &P,
        config: &FeatureInitConfig,
        frame: usize,
        observer_from_world: &Se3,
        z: &SVector<f64, N>,
    ) -> UpdateOutcome {
        if !z.iter().all(|v| v.is_finite()) {
            return UpdateOutcome::NotProjectable;
        }
        let t_la = observer_from_world.compose(&self.anchor_from_world.inverse());
        let w = 1.0 / (config.sigma * config.sigma);
        let prior = self.psi;
        let lambda_prior = self.information;
        let cost = |psi: &Vector3<f64>| -> Option<(f64, SVector<f64, N>, SMatrix<f64, N, 3>)> {
            let (zh, j) = predict_inverse_depth(projector, Some(&t_la), psi)?;
            let r = zh - z;
            let dp = psi - prior;
            Some((
                (dp.transpose() * lambda_prior * dp)[0] + w * r.norm_squared(),
                r,
                j,
            ))
        };
        let Some((mut chi2, mut r, mut j)) = cost(&self.psi) else {
            return UpdateOutcome::NotProjectable;
        };
        let mut psi = self.psi;
        let mut lambda = 1e-4;
        for _ in 0..config.max_iterations {
            let h = lambda_prior + j.transpose() * j * w;
            let g = lambda_prior * (psi - prior) + j.transpose() * r * w;
            let mut improved = false;
            // Marquardt damping on diag(H) (floored: the prior has a zero depth entry).
            while lambda < 1e12 {
                let mut damped = h;
                for k in 0..3 {
                    damped[(k, k)] += lambda * h[(k, k)].max(1e-9 * h.amax().max(1e-300));
                }
                let Some(step) = damped.cholesky().map(|c| -c.solve(&g)) else {
                    lambda *= 10.0;
                    continue;
                };
                let candidate = psi + step;
                match cost(&candidate) {
                    Some((c, rc, jc)) if c < chi2 => {
                        let converged = chi2 - c <= 1e-12 * chi2.max(1e-300)
                            || step.norm() <= 1e-12 * (1.0 + psi.norm());
                        psi = candidate;
                        chi2 = c;
                        r = rc;
                        j = jc;
                        lambda = (lambda * 0.1).max(1e-12);
                        improved = !converged;
                        break;
                    }
                    _ => lambda *= 10.0,
                }
            }
            if !improved {
                break;
            }
        }
        let gate = config
            .outlier_chi2
            .unwrap_or_else(|| lsq::chi2_quantile(N, 0.999));
        let measurement_chi2 = w * r.norm_squared();
        if measurement_chi2 > gate {
            return UpdateOutcome::Outlier {
                chi2: measurement_chi2,
            };
        }
        self.psi = psi;
        self.information = lambda_prior + j.transpose() * j * w;
        self.observations.push((frame, *z));
        UpdateOutcome::Updated {
            chi2: measurement_chi2,
        }
    }
}

/// What a filter update did.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum UpdateOutcome {
    /// The measurement was taken in; its whitened residual after the update is `chi2`.
    Updated {
        /// `rᵀΛ_z r` after the update.
        chi2: f64,
    },
    /// The measurement disagreed with the estimate beyond the outlier gate: not used.
    Outlier {
        /// `rᵀΛ_z r` at the best estimate including it.
        chi2: f64,
    },
    /// The feature cannot be projected into this frame (behind the camera) or the measurement
    /// is not finite: not used.
    NotProjectable,
    /// No feature with this id.
    Unknown,
}

/// Counts of what a [`FeatureFilters::update`] did.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct UpdateReport {
    /// Measurements taken in.
    pub updated: usize,
    /// Measurements rejected by the outlier gate.
    pub outliers: usize,
    /// Measurements of features that cannot be projected.
    pub not_projectable: usize,
    /// Measurements naming no feature.
    pub unknown: usize,
}

/// The set of independent inverse-depth filters of thesis §3.4.4 (eq. 3.35): features are
/// added in anchor (key)frames, updated by every new frame with known pose, and taken out once
/// converged, to be added to the map and bundle adjusted.
#[derive(Clone, Debug)]
pub struct FeatureFilters<P, const N: usize> {
    projector: P,
    config: FeatureInitConfig,
    filters: BTreeMap<FeatureId, InverseDepthFilter<N>>,
    next_id: usize,
}

impl<P: Projector<N>, const N: usize> FeatureFilters<P, N> {
    /// An empty set for the given measurement model.
    pub fn new(projector: P, config: FeatureInitConfig) -> Self {
        FeatureFilters {
            projector,
            config,
            filters: BTreeMap::new(),
            next_id: 0,
        }
    }

    /// The configuration.
    pub fn config(&self) -> &FeatureInitConfig {
        &self.config
    }

    /// The measurement model.
    pub fn projector(&self) -> &P {
        &self.projector
    }

    /// Starts a filter for a feature measured at `measurement` in anchor frame `anchor_frame`
    /// with pose `anchor_from_world`, starting from `psi` (see [`InverseDepthFilter::new`]).
    /// `None` if `psi` is not projectable.
    pub fn add(
        &mut self,
        anchor_frame: usize,
        anchor_from_world: Se3,
        measurement: SVector<f64, N>,
        psi: Vector3<f64>,
    ) -> Option<FeatureId> {
        let f = InverseDepthFilter::new(
            &self.projector,
            self.config.sigma,
            anchor_frame,
            anchor_from_world,
            measurement,
            psi,
        )?;
        let id = FeatureId(self.next_id);
        self.next_id += 1;
        self.filters.insert(id, f);
        Some(id)
    }

    /// Updates the filters measured in frame `frame` taken from `observer_from_world` with
    /// their measurements (thesis eq. 3.36–3.37); each filter independently (eq. 3.35).
    pub fn update(
        &mut self,
        frame: usize,
        observer_from_world: &Se3,
        measurements: &[(FeatureId, SVector<f64, N>)],
    ) -> UpdateReport {
        let mut report = UpdateReport::default();
        for (id, z) in measurements {
            let outcome = match self.filters.get_mut(id) {
                Some(f) => f.update(&self.projector, &self.config, frame, observer_from_world, z),
                None => UpdateOutcome::Unknown,
            };
            match outcome {
                UpdateOutcome::Updated { .. } => report.updated += 1,
                UpdateOutcome::Outlier { .. } => report.outliers += 1,
                UpdateOutcome::NotProjectable => report.not_projectable += 1,
                UpdateOutcome::Unknown => report.unknown += 1,
            }
        }
        report
    }

    /// Removes and returns the converged features (see [`InverseDepthFilter::is_converged`]),
    /// in id order: they are ready to be added to the map.
    pub fn take_converged(&mut self) -> Vec<(FeatureId, InverseDepthFilter<N>)> {
        let ids: Vec<FeatureId> = self
            .filters
            .iter()
            .filter(|(_, f)| f.is_converged(&self.config))
            .map(|(id, _)| *id)
            .collect();
        ids.into_iter()
            .filter_map(|id| self.filters.remove(&id).map(|f| (id, f)))
            .collect()
    }

    /// Removes a feature (e.g. lost by the tracker).
    pub fn remove(&mut self, id: FeatureId) -> Option<InverseDepthFilter<N>> {
        self.filters.remove(&id)
    }

    /// Keeps only the features for which `keep` is true.
    pub fn retain(&mut self, mut keep: impl FnMut(FeatureId, &InverseDepthFilter<N>) -> bool) {
        self.filters.retain(|id, f| keep(*id, f));
    }

    /// Sets the anchor pose of every feature anchored in `anchor_frame` (after the keyframe was
    /// moved by bundle adjustment; `ψ` is relative to the anchor and moves with it).
    pub fn set_anchor_pose(&mut self, anchor_frame: usize, anchor_from_world: Se3) {
        for f in self.filters.values_mut() {
            if f.anchor_frame == anchor_frame {
                f.anchor_from_world = anchor_from_world;
            }
        }
    }

    /// The feature with this id.
    pub fn get(&self, id: FeatureId) -> Option<&InverseDepthFilter<N>> {
        self.filters.get(&id)
    }

    /// All features in id order.
    pub fn iter(&self) -> impl Iterator<Item = (FeatureId, &InverseDepthFilter<N>)> {
        self.filters.iter().map(|(id, f)| (*id, f))
    }

    /// Number of features being initialised.
    pub fn len(&self) -> usize {
        self.filters.len()
    }

    /// Whether no feature is being initialised.
    pub fn is_empty(&self) -> bool {
        self.filters.is_empty()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::factors::{InverseDepthObservation, point_to_inverse_depth};
    use geom::{CameraModel, PinholeCamera, StereoCamera};
    use lsq::Values;
    use lsq::numeric::check_jacobians;
    use nalgebra::{Vector2, Vector6};
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;
    use rand_distr::{Distribution, Normal};

    fn camera() -> PinholeCamera {
        PinholeCamera::new(500.0, 500.0, 320.0, 240.0)
    }

    /// Camera `k` of a sideways motion along world `+x` (10 cm per frame), looking along `+z`.
    fn sideways(k: usize) -> Se3 {
        Se3::from_translation(Vector3::new(-0.1 * k as f64, 0.0, 0.0))
    }

    #[test]
    fn jacobians_match_numeric_mono_and_stereo() {
        let mut rng = ChaCha8Rng::seed_from_u64(11);
        let stereo = StereoCamera::new(camera(), 0.1);
        for _ in 0..30 {
            let t = Se3::exp(&Vector6::from_fn(|i, _| {
                if i < 3 {
                    rng.random_range(-0.3..0.3)
                } else {
                    rng.random_range(-0.1..0.1)
                }
            }));
            let psi = Vector3::new(
                rng.random_range(-0.4..0.4),
                rng.random_range(-0.3..0.3),
                1.0 / rng.random_range(1.5..20.0),
            );
            let mut values = Values::new();
            let v = values.add(psi);
            let mono = InverseDepthObservation {
                inverse_depth_point: v,
                observer_from_anchor: Some(t),
                measurement: Vector2::new(300.0, 200.0),
                projector: camera(),
            };
            let c = check_jacobians(&mono, &values, 1e-6).expect("projectable");
            assert!(c.passes(1e-6), "mono {c:?}");
            let st = InverseDepthObservation {
                inverse_depth_point: v,
                observer_from_anchor: Some(t),
                measurement: Vector3::new(300.0, 200.0, 280.0),
                projector: stereo,
            };
            let c = check_jacobians(&st, &values, 1e-6).expect("projectable");
            assert!(c.passes(1e-6), "stereo {c:?}");
        }
    }

    #[test]
    fn initial_information_is_the_thesis_diagonal_for_mono_and_full_rank_for_stereo() {
        let cam = camera();
        let sigma = 0.7;
        let z = Vector2::new(400.0, 100.0);
        let ray = cam.unproject(&z).unwrap();
        let f = InverseDepthFilter::new(
            &cam,
            sigma,
            0,
            Se3::identity(),
            z,
            Vector3::new(ray.x, ray.y, 0.3),
        )
        .unwrap();
        let expected = Matrix3::from_diagonal(&Vector3::new(
            500.0 * 500.0 / (sigma * sigma),
            500.0 * 500.0 / (sigma * sigma),
            0.0,
        ));
        assert!((f.information - expected).amax() < 1e-6 * expected.amax());
        assert!(f.covariance().is_none() && f.inverse_depth_std().is_none());
        // Stereo: depth is measured, Λ has full rank.
        let stereo = StereoCamera::new(cam, 0.12);
        let x = Vector3::new(0.3, -0.2, 4.0);
        let zs = Projector::<3>::project(&stereo, &x).unwrap().0;
        let fs = InverseDepthFilter::new(
            &stereo,
            sigma,
            0,
            Se3::identity(),
            zs,
            point_to_inverse_depth(&x).unwrap(),
        )
        .unwrap();
        let sq = fs.inverse_depth_std().expect("stereo observes depth");
        assert!(sq > 0.0 && sq < 0.25 * 0.25, "σ_q = {sq}");
    }

    /// A point seen from a sideways-moving camera: the filter, started far from the true depth,
    /// converges to it, its information grows, and it is promoted once converged.
    #[test]
    fn mono_filter_converges_to_the_true_depth_from_a_wrong_start() {
        let cam = camera();
        let config = FeatureInitConfig::default();
        for (true_depth, start_q) in [(3.0, 1.0), (8.0, 0.05), (20.0, 2.0)] {
            let y = Vector3::new(0.4, -0.3, true_depth);
            let z0 = CameraModel::project(&cam, &sideways(0).act(&y)).unwrap();
            let ray = cam.unproject(&z0).unwrap();
            let mut set = FeatureFilters::new(cam, config);
            let id = set
                .add(0, sideways(0), z0, Vector3::new(ray.x, ray.y, start_q))
                .unwrap();
            let mut last_q_std = f64::INFINITY;
            for k in 1..=20 {
                let z = CameraModel::project(&cam, &sideways(k).act(&y)).unwrap();
                let r = set.update(k, &sideways(k), &[(id, z)]);
                assert_eq!(r.updated, 1, "depth {true_depth}, frame {k}: {r:?}");
                let f = set.get(id).unwrap();
                let s = f.inverse_depth_std().unwrap();
                assert!(s < last_q_std, "information only grows");
                last_q_std = s;
            }
            let f = set.get(id).unwrap();
            assert!(
                (f.point_world() - y).norm() < 1e-6 * true_depth,
                "depth {true_depth}: {:?}",
                f.point_world()
            );
            let promoted = set.take_converged();
            assert_eq!(promoted.len(), 1, "depth {true_depth}");
            assert!(set.is_empty());
            assert_eq!(promoted[0].1.observations.len(), 21);
        }
    }

    /// With noisy measurements the filter is consistent: the normalised estimation error
    /// squared of the promoted features averages about 3 (the dimension of ψ) over many runs,
    /// and a feature is promoted only once its depth is known to the configured accuracy.
    #[test]
    fn noisy_filters_are_consistent_and_promotion_respects_the_threshold() {
        let cam = camera();
        let config = FeatureInitConfig {
            sigma: 1.0,
            ..FeatureInitConfig::default()
        };
        let noise = Normal::new(0.0, config.sigma).unwrap();
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let mut nees = Vec::new();
        let mut depth_errors = Vec::new();
        for _ in 0..300 {
            let y = Vector3::new(
                rng.random_range(-2.0..2.0),
                rng.random_range(-1.5..1.5),
                rng.random_range(3.0..10.0),
            );
            let noisy = |t: &Se3, rng: &mut ChaCha8Rng| {
                CameraModel::project(&cam, &t.act(&y)).unwrap()
                    + Vector2::new(noise.sample(rng), noise.sample(rng))
            };
            let z0 = noisy(&sideways(0), &mut rng);
            let ray = cam.unproject(&z0).unwrap();
            let mut set = FeatureFilters::new(cam, config);
            let id = set
                .add(0, sideways(0), z0, Vector3::new(ray.x, ray.y, 0.2))
                .unwrap();
            let mut promoted = None;
            for k in 1..=40 {
                let z = noisy(&sideways(k), &mut rng);
                set.update(k, &sideways(k), &[(id, z)]);
                if let Some((_, f)) = set.take_converged().pop() {
                    promoted = Some(f);
                    break;
                }
            }
            let f = promoted.expect("40 frames of 10 cm at ≤ 10 m depth converge");
            let truth = point_to_inverse_depth(&y).unwrap();
            let e = f.psi - truth;
            nees.push((e.transpose() * f.information * e)[0]);
            depth_errors.push(((1.0 / f.psi.z) - y.z).abs() / y.z);
        }
        let mean_nees = nees.iter().sum::<f64>() / nees.len() as f64;
        assert!(
            (1.5..=5.0).contains(&mean_nees),
            "mean NEES {mean_nees} (expected ≈ 3)"
        );
        // σ_q ≤ 0.1·q: relative depth errors mostly below 3·10 %.
        let within = depth_errors.iter().filter(|e| **e < 0.3).count();
        assert!(within as f64 >= 0.97 * depth_errors.len() as f64);
    }

    #[test]
    fn stereo_filter_refines_the_depth_and_converges_at_once_when_close() {
        let cam = camera();
        let stereo = StereoCamera::new(cam, 0.12);
        let config = FeatureInitConfig {
            min_observations: 2,
            ..FeatureInitConfig::default()
        };
        let y = Vector3::new(0.2, 0.1, 3.0);
        let z0 = Projector::<3>::project(&stereo, &y).unwrap().0 + Vector3::new(0.0, 0.0, 0.8);
        // Start from the (wrong) stereo depth of the perturbed measurement.
        let x0 = stereo.unproject(&z0).unwrap();
        let mut set = FeatureFilters::new(stereo, config);
        let id = set
            .add(0, Se3::identity(), z0, point_to_inverse_depth(&x0).unwrap())
            .unwrap();
        let before = (set.get(id).unwrap().point_world() - y).norm();
        let z1 = Projector::<3>::project(&stereo, &sideways(1).act(&y))
            .unwrap()
            .0;
        set.update(1, &sideways(1), &[(id, z1)]);
        let after = (set.get(id).unwrap().point_world() - y).norm();
        assert!(after < before, "{after} vs {before}");
        assert_eq!(set.take_converged().len(), 1);
    }

    #[test]
    fn outliers_unknown_ids_and_points_behind_are_rejected_without_changing_the_filter() {
        let cam = camera();
        let y = Vector3::new(0.1, 0.1, 5.0);
        let z0 = CameraModel::project(&cam, &y).unwrap();
        let ray = cam.unproject(&z0).unwrap();
        let mut set = FeatureFilters::new(cam, FeatureInitConfig::default());
        let id = set
            .add(0, Se3::identity(), z0, Vector3::new(ray.x, ray.y, 0.2))
            .unwrap();
        for k in 1..5 {
            let z = CameraModel::project(&cam, &sideways(k).act(&y)).unwrap();
            set.update(k, &sideways(k), &[(id, z)]);
        }
        let before = set.get(id).unwrap().clone();
        // 30 px off the epipolar line (vertical, the motion is horizontal).
        let z = CameraModel::project(&cam, &sideways(5).act(&y)).unwrap() + Vector2::new(0.0, 30.0);
        let r = set.update(5, &sideways(5), &[(id, z), (FeatureId(99), z)]);
        assert_eq!((r.outliers, r.unknown, r.updated), (1, 1, 0));
        assert_eq!(set.get(id).unwrap(), &before);
        // A camera that has turned around: the point is behind it.
        let behind = Se3::from_rotation(lie::So3::rot_y(std::f64::consts::PI));
        let r = set.update(6, &behind, &[(id, z)]);
        assert_eq!(r.not_projectable, 1);
        let r = set.update(7, &sideways(7), &[(id, Vector2::new(f64::NAN, 1.0))]);
        assert_eq!(r.not_projectable, 1);
        assert_eq!(set.get(id).unwrap(), &before);
    }

    #[test]
    fn moving_the_anchor_moves_the_feature_with_it() {
        let cam = camera();
        let mut set = FeatureFilters::new(cam, FeatureInitConfig::default());
        let z0 = Vector2::new(320.0, 240.0);
        let id = set
            .add(3, Se3::identity(), z0, Vector3::new(0.0, 0.0, 0.5))
            .unwrap();
        assert!((set.get(id).unwrap().point_world() - Vector3::new(0.0, 0.0, 2.0)).norm() < 1e-12);
        set.set_anchor_pose(3, Se3::from_translation(Vector3::new(-1.0, 0.0, 0.0)));
        assert!((set.get(id).unwrap().point_world() - Vector3::new(1.0, 0.0, 2.0)).norm() < 1e-12);
        set.set_anchor_pose(4, Se3::identity());
        assert!((set.get(id).unwrap().point_world() - Vector3::new(1.0, 0.0, 2.0)).norm() < 1e-12);
        assert!(point_to_inverse_depth(&Vector3::new(1.0, 1.0, -1.0)).is_none());
    }
}
