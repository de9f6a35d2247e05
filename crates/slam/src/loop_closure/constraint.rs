//! The loop constraint of monocular loop closure (thesis §5.3.1).
//!
//! Given matched features between the current keyframe and an old one (from appearance; in
//! simulation, from the known data association), each feature gets a depth — its map point's
//! if it is one, otherwise by *k-nearest-neighbour regression* on the map points measured in
//! its keyframe ([`knn_depth`]: the scene is assumed smooth, Fig. 5.2) — and is back-projected
//! to a 3D point in its camera frame. The similarity `S` with `x_old ≈ S·x_current` is found by
//! the 3-point closed form of Arun / Umeyama (eq. 5.9–5.14) in a seeded RANSAC
//! ([`geom::ransac::Sim3Estimator`]), then refined robustly by a two-view bundle adjustment of
//! the similarity and the matched points with a Huber kernel, the maps' depths entering as
//! uncertain measurements ([`LoopViewMeasurement`]). Its scale `s_loop` is the scale drift
//! accumulated around the loop.

use crate::map::{KeyframeId, PointId, SlamGraph};
use crate::tracking::TrackId;
use geom::ransac::{RansacConfig, RansacError, Sim3Estimator, ransac};
use geom::{CameraModel, PinholeCamera};
use lie::{LieGroup, Sim3};
use lsq::{Factor, Information, Jacobians, RobustKernel, SolverOptions, Values, Var, VarKey};
use nalgebra::{Vector2, Vector3};

/// Depth at `query` (pixels) by k-nearest-neighbour regression on `samples` of
/// `(pixel, depth)` (thesis §5.3.1, Fig. 5.2): a local linear regression of the *inverse*
/// depth on the image coordinates over the `k` samples nearest in the image,
///
/// `q(u, v) ≈ q₀ + a·(u − u_q) + b·(v − v_q)`, weights `wᵢ = 1/(dᵢ + 1 px)`,
///
/// evaluated at the query, `d = 1/q₀`. The inverse depth of a plane is an affine function of
/// the pixel coordinates, so the regression is exact on locally planar surfaces (the smoothness
/// the thesis assumes); it falls back to the weighted mean of the inverse depths when the
/// neighbours are (nearly) collinear in the image, and the result is clamped to the
/// neighbours' range (no extrapolation beyond it). `None` when there are no samples within
/// `max_distance` pixels.
pub fn knn_depth(
    query: &Vector2<f64>,
    samples: &[(Vector2<f64>, f64)],
    k: usize,
    max_distance: f64,
) -> Option<f64> {
    let mut near: Vec<(f64, Vector2<f64>, f64)> = samples
        .iter()
        .filter(|(p, d)| d.is_finite() && *d > 0.0 && p.iter().all(|v| v.is_finite()))
        .map(|(p, d)| ((p - query).norm(), p - query, 1.0 / *d))
        .filter(|(dist, _, _)| *dist <= max_distance)
        .collect();
    if near.is_empty() || k == 0 {
        return None;
    }
    near.sort_by(|a, b| a.0.total_cmp(&b.0));
    near.truncate(k);
    let (q_min, q_max) = near.iter().fold((f64::INFINITY, 0.0_f64), |(lo, hi), n| {
        (lo.min(n.2), hi.max(n.2))
    });
    let (mut sw, mut swq) = (0.0, 0.0);
    let mut normal = nalgebra::Matrix3::<f64>::zeros();
    let mut rhs = Vector3::<f64>::zeros();
    for (dist, offset, q) in &near {
        let w = 1.0 / (dist + 1.0);
        sw += w;
        swq += w * q;
        let row = Vector3::new(1.0, offset.x, offset.y);
        normal += w * row * row.transpose();
        rhs += w * *q * row;
    }
    let mean = swq / sw;
    let q = if near.len() >= 3 {
        // Well-conditioned only if the neighbours span the image plane around the query.
        let eig = normal.symmetric_eigenvalues();
        let (lo, hi) = eig.iter().fold((f64::INFINITY, 0.0_f64), |(lo, hi), e| {
            (lo.min(*e), hi.max(*e))
        });
        if lo > 1e-6 * hi {
            normal
                .cholesky()
                .map(|c| c.solve(&rhs)[0])
                .filter(|q| q.is_finite())
                .unwrap_or(mean)
        } else {
            mean
        }
    } else {
        mean
    };
    Some(1.0 / q.clamp(q_min, q_max))
}

/// The `(pixel, depth)` samples of a keyframe: its measurements of map points with the points'
/// depths in its camera frame (those in front of it; empty for an unknown keyframe).
pub fn depth_samples(graph: &SlamGraph<2>, keyframe: KeyframeId) -> Vec<(Vector2<f64>, f64)> {
    graph.keyframe(keyframe).map_or_else(Vec::new, |kf| {
        kf.observations()
            .iter()
            .filter_map(|(&p, z)| Some((*z, graph.point_in_frame(p, keyframe).ok()?.z)))
            .filter(|(_, d)| *d > 0.0)
            .collect()
    })
}

/// A loop match seen in one of the two keyframes, for the robust refinement of the loop
/// similarity (thesis §5.3.1: "bundle adjustment using a robust kernel"). The match's point
/// `y` lives in the old camera frame; this keyframe sees it at `x = y` (the old keyframe) or
/// `x = S⁻¹·y` (the current keyframe, `S = old_from_current`). The residual stacks the
/// reprojection error and the depth measured by this keyframe's map,
///
/// `r = (ẑ(x) − z, x₃ − d)`,
///
/// to be weighted by `diag(1/σ², 1/σ², 1/(ρd)²)`: pixels are measured precisely, depths from a
/// map only to a relative accuracy `ρ` — which is why a rigid 3D–3D alignment alone does not
/// reproject well over a wide loop baseline. Binary in `(y, S)` for the current view, unary in
/// `y` for the old one.
#[derive(Clone, Copy, Debug)]
pub struct LoopViewMeasurement {
    /// The point in the old camera frame.
    pub point: Var<Vector3<f64>>,
    /// `S = old_from_current` for the current view, `None` for the old one.
    pub similarity: Option<Var<Sim3>>,
    /// The feature's pixel in this view.
    pub measurement: Vector2<f64>,
    /// Its depth in this view (from the map).
    pub depth: f64,
    /// The camera.
    pub camera: PinholeCamera,
}

impl Factor for LoopViewMeasurement {
    fn residual_dim(&self) -> usize {
        3
    }

    fn variables(&self) -> Vec<VarKey> {
        match self.similarity {
            Some(s) => vec![self.point.key(), s.key()],
            None => vec![self.point.key()],
        }
    }

    fn evaluate(
        &self,
        values: &Values,
        residual: &mut [f64],
        jacobians: Option<&mut Jacobians<'_>>,
    ) -> bool {
        let y = values.get(self.point);
        // x = S⁻¹·y; under S ← exp(ε)·S, x = S⁻¹·exp(−ε)·y: ∂x/∂ε = −(sR)⁻¹·[I | −[y]× | y].
        let (x, dx_dy, dx_ds) = match self.similarity {
            Some(sv) => {
                let inv = values.get(sv).inverse();
                let r = inv.d_act_d_point();
                (inv.act(y), r, Some(-(r * Sim3::identity().d_act_d_left(y))))
            }
            None => (*y, nalgebra::Matrix3::identity(), None),
        };
        let Ok((z, dz)) = self.camera.project_with_jacobian(&x) else {
            return false;
        };
        residual[0] = z.x - self.measurement.x;
        residual[1] = z.y - self.measurement.y;
        residual[2] = x.z - self.depth;
        if let Some(j) = jacobians {
            let mut dr_dx = nalgebra::Matrix3::<f64>::zeros();
            dr_dx.fixed_view_mut::<2, 3>(0, 0).copy_from(&dz);
            dr_dx[(2, 2)] = 1.0;
            if j.wants(0) {
                j.set(0, &(dr_dx * dx_dy));
            }
            if let Some(d) = dx_ds
                && j.wants(1)
            {
                j.set(1, &(dr_dx * d));
            }
        }
        true
    }
}

/// Parameters of [`estimate_loop_constraint`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LoopClosureConfig {
    /// Neighbours of the depth regression.
    pub knn: usize,
    /// Farthest neighbour (pixels) used by the depth regression.
    pub knn_max_distance: f64,
    /// RANSAC settings; its threshold is *relative*: the 3D inlier distance is
    /// `threshold × median depth` of the old view's points.
    pub ransac: RansacConfig,
    /// Pixel noise σ of the refinement.
    pub sigma: f64,
    /// Relative depth uncertainty `ρ` of map points (known depths).
    pub map_depth_sigma: f64,
    /// Relative depth uncertainty of regressed depths.
    pub regressed_depth_sigma: f64,
    /// Huber width of the refinement, in standard deviations.
    pub huber: f64,
    /// A match is an inlier of the refined constraint when the whitened residual `rᵀΛr` of
    /// each view is below this (default: the 99.9 % quantile of χ² with 3 degrees of freedom).
    pub inlier_chi2: f64,
    /// Fewer inliers than this: no loop constraint.
    pub min_inliers: usize,
    /// Iterations of the robust refinement.
    pub refine_iterations: usize,
}

impl Default for LoopClosureConfig {
    /// 8 neighbours within 50 px; RANSAC at 10 % of the median depth; σ = 1 px, map depths to
    /// 5 %, regressed depths to 15 %, Huber at 2σ, the χ²₃ 99.9 % gate, at least 20 inliers.
    fn default() -> Self {
        LoopClosureConfig {
            knn: 8,
            knn_max_distance: 50.0,
            ransac: RansacConfig {
                threshold: 0.1,
                ..RansacConfig::default()
            },
            sigma: 1.0,
            map_depth_sigma: 0.05,
            regressed_depth_sigma: 0.15,
            huber: 2.0,
            inlier_chi2: lsq::chi2_quantile(3, 0.999),
            min_inliers: 20,
            refine_iterations: 20,
        }
    }
}

/// Why no loop constraint was found.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum LoopClosureError {
    /// The two match lists differ in length.
    #[error("{old} matched features in the old keyframe but {current} in the current one")]
    LengthMismatch {
        /// In the old view.
        old: usize,
        /// In the current view.
        current: usize,
    },
    /// RANSAC failed.
    #[error(transparent)]
    Ransac(#[from] RansacError),
    /// Too few matches survived.
    #[error("only {inliers} inliers (at least {required} required)")]
    TooFewInliers {
        /// Inliers found.
        inliers: usize,
        /// Required.
        required: usize,
    },
    /// The refinement failed.
    #[error("refinement failed: {0}")]
    Refinement(String),
}

/// A loop constraint between two keyframes.
#[derive(Clone, Debug, PartialEq)]
pub struct LoopConstraint {
    /// `S` with `x_old = S·x_current` (camera-frame points): the current camera expressed in
    /// the old one, with the relative scale `s_loop` (thesis §5.3.1).
    pub old_from_current: Sim3,
    /// Indices of the matches consistent with it.
    pub inliers: Vec<usize>,
    /// Matches for which both views had a depth.
    pub with_depth: usize,
}

/// One keyframe's side of a set of loop matches.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct LoopView {
    /// The matched features (pixels), in match order.
    pub pixels: Vec<Vector2<f64>>,
    /// Each feature's depth in this camera when it is known (the feature is a map point
    /// measured in this keyframe); `None`: by [`knn_depth`] regression on the samples.
    pub depths: Vec<Option<f64>>,
    /// `(pixel, depth)` samples of the keyframe's map points for the regression.
    pub samples: Vec<(Vector2<f64>, f64)>,
}

impl LoopView {
    /// The camera-frame point of feature `i` and its relative depth uncertainty: its known
    /// depth, else the regressed one.
    fn point(
        &self,
        camera: &PinholeCamera,
        i: usize,
        config: &LoopClosureConfig,
    ) -> Option<(Vector3<f64>, f64)> {
        let z = self.pixels[i];
        let (depth, rho) = match self.depths.get(i).copied().flatten() {
            Some(d) => (d, config.map_depth_sigma),
            None => (
                knn_depth(&z, &self.samples, config.knn, config.knn_max_distance)?,
                config.regressed_depth_sigma,
            ),
        };
        camera.unproject_depth(&z, depth).ok().map(|p| (p, rho))
    }
}

/// The loop constraint from matched features `old.pixels[i] ↔ current.pixels[i]` with their
/// depths (known or regressed, see [`LoopView`]; thesis §5.3.1 and the [module docs](self)).
pub fn estimate_loop_constraint(
    camera: &PinholeCamera,
    old: &LoopView,
    current: &LoopView,
    config: &LoopClosureConfig,
) -> Result<LoopConstraint, LoopClosureError> {
    let (z_old, z_current) = (&old.pixels, &current.pixels);
    if z_old.len() != z_current.len() {
        return Err(LoopClosureError::LengthMismatch {
            old: z_old.len(),
            current: z_current.len(),
        });
    }
    let mut idx = Vec::new();
    let (mut x_old, mut x_cur) = (Vec::new(), Vec::new());
    let (mut rho_old, mut rho_cur) = (Vec::new(), Vec::new());
    for i in 0..z_old.len() {
        if let (Some((po, ro)), Some((pc, rc))) = (
            old.point(camera, i, config),
            current.point(camera, i, config),
        ) {
            idx.push(i);
            x_old.push(po);
            x_cur.push(pc);
            rho_old.push(ro);
            rho_cur.push(rc);
        }
    }
    if idx.len() < config.min_inliers.max(3) {
        return Err(LoopClosureError::TooFewInliers {
            inliers: idx.len(),
            required: config.min_inliers.max(3),
        });
    }
    let mut depths: Vec<f64> = x_old.iter().map(|p| p.z).collect();
    depths.sort_by(f64::total_cmp);
    let median_depth = depths[depths.len() / 2];
    let ransac_config = RansacConfig {
        threshold: config.ransac.threshold * median_depth,
        ..config.ransac
    };
    let r = ransac(
        &Sim3Estimator {
            target: &x_old,
            source: &x_cur,
        },
        &ransac_config,
    )?;
    // Robust refinement: a two-view BA of the similarity and the matched points, with the
    // maps' depths as measurements (see `LoopViewMeasurement`); first over all matches, then
    // again over the inliers only (a Huber kernel bounds but does not remove the pull of
    // outliers).
    let matches = LoopMatches {
        camera,
        z_old,
        z_current,
        x_old: &x_old,
        x_cur: &x_cur,
        rho_old: &rho_old,
        rho_cur: &rho_cur,
        idx: &idx,
    };
    let all: Vec<usize> = (0..idx.len()).collect();
    let (s1, good) = matches.refine(r.model, &all, config)?;
    let (refined, good) = if good.len() >= config.min_inliers.max(3) {
        matches.refine(s1, &good, config)?
    } else {
        (s1, good)
    };
    let inliers: Vec<usize> = good.iter().map(|&k| idx[k]).collect();
    if inliers.len() < config.min_inliers {
        return Err(LoopClosureError::TooFewInliers {
            inliers: inliers.len(),
            required: config.min_inliers,
        });
    }
    Ok(LoopConstraint {
        old_from_current: refined,
        inliers,
        with_depth: idx.len(),
    })
}

/// The 3D matches of [`estimate_loop_constraint`] (index `k` into the matches with depth in
/// both views; `idx[k]` is the match's index in the input).
struct LoopMatches<'a> {
    camera: &'a PinholeCamera,
    z_old: &'a [Vector2<f64>],
    z_current: &'a [Vector2<f64>],
    x_old: &'a [Vector3<f64>],
    x_cur: &'a [Vector3<f64>],
    rho_old: &'a [f64],
    rho_cur: &'a [f64],
    idx: &'a [usize],
}

impl LoopMatches<'_> {
    /// Two-view BA of `S` and the points of matches `subset`, from `s0`; returns `S` and the
    /// matches of `subset` whose whitened residual in both views passes the inlier gate.
    fn refine(
        &self,
        s0: Sim3,
        subset: &[usize],
        config: &LoopClosureConfig,
    ) -> Result<(Sim3, Vec<usize>), LoopClosureError> {
        let mut problem = lsq::Problem::new();
        let s = problem.add_variable(s0);
        let mut views = Vec::with_capacity(subset.len());
        let sigma2 = config.sigma * config.sigma;
        for &k in subset {
            let i = self.idx[k];
            // Start from the midpoint of the two maps' estimates (in the old frame).
            let y = problem.add_variable(0.5 * (self.x_old[k] + s0.act(&self.x_cur[k])));
            let f_old = LoopViewMeasurement {
                point: y,
                similarity: None,
                measurement: self.z_old[i],
                depth: self.x_old[k].z,
                camera: *self.camera,
            };
            let f_cur = LoopViewMeasurement {
                point: y,
                similarity: Some(s),
                measurement: self.z_current[i],
                depth: self.x_cur[k].z,
                camera: *self.camera,
            };
            let sd_old = self.rho_old[k] * self.x_old[k].z;
            let sd_cur = self.rho_cur[k] * self.x_cur[k].z;
            for (f, sd) in [(f_old, sd_old), (f_cur, sd_cur)] {
                problem
                    .add_factor(
                        f,
                        Information::Diagonal(vec![1.0 / sigma2, 1.0 / sigma2, 1.0 / (sd * sd)]),
                        Some(RobustKernel::Huber(config.huber)),
                    )
                    .map_err(|e| LoopClosureError::Refinement(e.to_string()))?;
            }
            views.push((k, f_old, sd_old, f_cur, sd_cur));
        }
        problem.set_eliminated::<Vector3<f64>>(true);
        problem
            .optimise(&SolverOptions {
                max_iterations: config.refine_iterations,
                threads: Some(1),
                ..SolverOptions::default()
            })
            .map_err(|e| LoopClosureError::Refinement(e.to_string()))?;
        let chi2 = |f: &LoopViewMeasurement, sd: f64| -> f64 {
            let mut r = [0.0; 3];
            if f.evaluate(problem.values(), &mut r, None) {
                (r[0] * r[0] + r[1] * r[1]) / sigma2 + (r[2] / sd).powi(2)
            } else {
                f64::INFINITY
            }
        };
        let good = views
            .iter()
            .filter(|(_, fo, so, fc, sc)| {
                chi2(fo, *so) <= config.inlier_chi2 && chi2(fc, *sc) <= config.inlier_chi2
            })
            .map(|(k, ..)| *k)
            .collect();
        Ok((*problem.value(s), good))
    }
}

/// The matches of two keyframes of `graph`: the tracks measured in both (perfect data
/// association, as a simulator gives, standing in for descriptor matching), in the order of
/// the old keyframe's `measurements` (`(track, z)` of every feature, map point or not), with
/// known depths for the map points each keyframe measures (`track_of` names a point's track)
/// and every map point it measures as a regression sample.
pub fn matched_views(
    graph: &SlamGraph<2>,
    (old, old_measurements): (KeyframeId, &[(TrackId, Vector2<f64>)]),
    (current, current_measurements): (KeyframeId, &[(TrackId, Vector2<f64>)]),
    track_of: &dyn Fn(PointId) -> TrackId,
) -> (LoopView, LoopView) {
    use std::collections::HashMap;
    let known = |k: KeyframeId| -> HashMap<TrackId, f64> {
        graph.keyframe(k).map_or_else(HashMap::new, |kf| {
            kf.observations()
                .keys()
                .filter_map(|&p| Some((track_of(p), graph.point_in_frame(p, k).ok()?.z)))
                .filter(|(_, d)| *d > 0.0)
                .collect()
        })
    };
    let (known_old, known_cur) = (known(old), known(current));
    let cur: HashMap<_, _> = current_measurements.iter().copied().collect();
    let mut views = (
        LoopView {
            samples: depth_samples(graph, old),
            ..LoopView::default()
        },
        LoopView {
            samples: depth_samples(graph, current),
            ..LoopView::default()
        },
    );
    for (t, z) in old_measurements {
        if let Some(zc) = cur.get(t) {
            views.0.pixels.push(*z);
            views.0.depths.push(known_old.get(t).copied());
            views.1.pixels.push(*zc);
            views.1.depths.push(known_cur.get(t).copied());
        }
    }
    views
}

#[cfg(test)]
mod tests {
    use super::*;
    use lie::{Se3, So3};
    use lsq::numeric::check_jacobians;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    fn camera() -> PinholeCamera {
        PinholeCamera::new(500.0, 500.0, 320.0, 240.0)
    }

    #[test]
    fn loop_view_measurement_jacobians() {
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        for _ in 0..20 {
            let s = Sim3::new(
                So3::exp(&Vector3::new(
                    rng.random_range(-0.2..0.2),
                    rng.random_range(-0.2..0.2),
                    rng.random_range(-0.2..0.2),
                )),
                Vector3::new(
                    rng.random_range(-0.3..0.3),
                    0.1,
                    rng.random_range(-0.3..0.3),
                ),
                rng.random_range(0.5..2.0),
            )
            .unwrap();
            let mut values = Values::new();
            let sv = values.add(s);
            let y = values.add(Vector3::new(
                rng.random_range(-1.0..1.0),
                rng.random_range(-1.0..1.0),
                rng.random_range(3.0..6.0),
            ));
            for similarity in [None, Some(sv)] {
                let f = LoopViewMeasurement {
                    point: y,
                    similarity,
                    measurement: Vector2::new(300.0, 200.0),
                    depth: 4.0,
                    camera: camera(),
                };
                let c = check_jacobians(&f, &values, 1e-5).unwrap();
                assert!(c.passes(1e-6), "{similarity:?}: {c:?}");
            }
        }
    }

    #[test]
    fn knn_depth_interpolates_a_plane_and_refuses_empty_neighbourhoods() {
        // A fronto-parallel plane at depth 4: any regression gives 4.
        let samples: Vec<_> = (0..50)
            .map(|i| {
                (
                    Vector2::new(10.0 * (i % 10) as f64, 10.0 * (i / 10) as f64),
                    4.0,
                )
            })
            .collect();
        assert_eq!(
            knn_depth(&Vector2::new(33.0, 17.0), &samples, 4, 50.0),
            Some(4.0)
        );
        assert_eq!(
            knn_depth(&Vector2::new(500.0, 500.0), &samples, 4, 50.0),
            None
        );
        assert_eq!(knn_depth(&Vector2::new(0.0, 0.0), &[], 4, 50.0), None);
        // A slanted plane: inverse depth affine in the pixel coordinates, recovered exactly.
        let plane = |p: &Vector2<f64>| 1.0 / (0.2 + 0.001 * p.x - 0.0005 * p.y);
        let slanted: Vec<_> = samples.iter().map(|(p, _)| (*p, plane(p))).collect();
        let q = Vector2::new(47.0, 23.0);
        let d = knn_depth(&q, &slanted, 8, 50.0).unwrap();
        assert!(
            (d - plane(&q)).abs() < 1e-9 * plane(&q),
            "{d} vs {}",
            plane(&q)
        );
        // Two neighbours (collinear): the weighted mean of the inverse depths.
        let two = [
            (Vector2::new(0.0, 0.0), 2.0),
            (Vector2::new(40.0, 0.0), 4.0),
        ];
        let d = knn_depth(&Vector2::new(0.0, 0.0), &two, 2, 50.0).unwrap();
        let q = (0.5 + 0.25 / 41.0) / (1.0 + 1.0 / 41.0);
        assert!((d - 1.0 / q).abs() < 1e-12);
    }

    /// Two views of a smooth surface, the current map at 0.6 times the old one's scale, with a
    /// quarter of the matches wrong: the constraint recovers the relative pose and the scale.
    #[test]
    fn loop_constraint_recovers_relative_pose_and_scale_with_outliers() {
        let cam = camera();
        let mut rng = ChaCha8Rng::seed_from_u64(4);
        // World: a gently curved surface z = 5 + 0.2 sin(x) in front of both cameras.
        let world: Vec<Vector3<f64>> = (0..600)
            .map(|_| {
                let x: f64 = rng.random_range(-3.0..3.0);
                let y: f64 = rng.random_range(-2.5..2.5);
                Vector3::new(x, y, 5.0 + 0.2 * x.sin())
            })
            .collect();
        let old_from_world = Se3::identity();
        let cur_from_world = Se3::new(So3::rot_y(0.1), Vector3::new(0.3, 0.05, -0.2));
        let scale_cur = 0.6; // the current map's scale relative to the old one
        let mut z_old = Vec::new();
        let mut z_cur = Vec::new();
        let mut depth_old = Vec::new();
        let mut depth_cur = Vec::new();
        for (k, y) in world.iter().enumerate() {
            let (xo, xc) = (old_from_world.act(y), cur_from_world.act(y));
            let (Ok(zo), Ok(zc)) = (
                CameraModel::project(&cam, &xo),
                CameraModel::project(&cam, &xc),
            ) else {
                continue;
            };
            if k % 3 == 0 {
                // Map points with depth (the current map scaled by 0.6).
                depth_old.push((zo, xo.z));
                depth_cur.push((zc, scale_cur * xc.z));
            } else {
                z_old.push(zo);
                z_cur.push(zc);
            }
        }
        // 25 % wrong matches.
        let n = z_cur.len();
        let correct = z_cur.clone();
        for i in (0..n).step_by(4) {
            z_cur[i] = correct[(i + n / 2 + 1) % n];
        }
        let view = |pixels: Vec<Vector2<f64>>, samples: Vec<(Vector2<f64>, f64)>| LoopView {
            depths: vec![None; pixels.len()],
            pixels,
            samples,
        };
        let c = estimate_loop_constraint(
            &cam,
            &view(z_old.clone(), depth_old),
            &view(z_cur.clone(), depth_cur),
            &LoopClosureConfig::default(),
        )
        .unwrap();
        // x_old = S·x_cur with x_cur in the current map's scale: s = 1/0.6.
        let s = c.old_from_current;
        assert!(
            (s.scale() * scale_cur - 1.0).abs() < 0.02,
            "scale {}",
            s.scale()
        );
        let truth_rigid = old_from_world.compose(&cur_from_world.inverse());
        let rot_err = s
            .rotation()
            .inverse()
            .compose(truth_rigid.rotation())
            .log()
            .norm();
        assert!(rot_err < 5e-3, "rotation error {rot_err}");
        let t_err = (s.translation() - truth_rigid.translation()).norm();
        assert!(t_err < 0.05, "translation error {t_err}");
        let wrong = (0..n).step_by(4).filter(|i| c.inliers.contains(i)).count();
        assert!(wrong <= 2, "{wrong} wrong matches accepted");
        assert!(c.inliers.len() as f64 > 0.6 * n as f64);
    }
}
