//! Reprojection errors of Euclidean points and of anchored inverse-depth points (thesis
//! §3.3.1, eq. 4.17, app. B.3–B.5), for any [`Projector`]: mono, stereo and RGB-D.

use super::{Projector, d_point_d_pose};
use lie::{LieGroup, Se3};
use lsq::{Factor, Jacobians, Manifold, Values, Var, VarKey};
use nalgebra::{Matrix3, SMatrix, SVector, Vector3};

/// A Euclidean world point observed from a pose: `r = ẑ(T_cw·y) − z` (thesis eq. 3.15, B.17,
/// B.18).
pub struct PointObservation<P, const N: usize> {
    /// The observing camera's `camera_from_world`.
    pub camera_from_world: Var<Se3>,
    /// The point in world coordinates.
    pub point_world: Var<Vector3<f64>>,
    /// The measurement `z`.
    pub measurement: SVector<f64, N>,
    /// The measurement model.
    pub projector: P,
}

impl<P: Projector<N>, const N: usize> Factor for PointObservation<P, N> {
    fn residual_dim(&self) -> usize {
        N
    }

    fn variables(&self) -> Vec<VarKey> {
        vec![self.camera_from_world.key(), self.point_world.key()]
    }

    fn evaluate(
        &self,
        values: &Values,
        residual: &mut [f64],
        jacobians: Option<&mut Jacobians<'_>>,
    ) -> bool {
        let t = values.get(self.camera_from_world);
        let x = t.act(values.get(self.point_world));
        let Some((z_hat, dz_dx)) = self.projector.project(&x) else {
            return false;
        };
        residual.copy_from_slice((z_hat - self.measurement).as_slice());
        if let Some(j) = jacobians {
            if j.wants(0) {
                j.set(0, &(dz_dx * d_point_d_pose(&x)));
            }
            if j.wants(1) {
                j.set(1, &(dz_dx * t.d_act_d_point()));
            }
        }
        true
    }
}

/// `Π(ψ) = (ψ₁/ψ₃, ψ₂/ψ₃, 1/ψ₃)`: an inverse-depth point `ψ = (u, v, q)` (normalised image
/// coordinates and inverse depth in its anchor frame) to the Euclidean point (thesis §B.3).
#[inline]
pub fn inverse_depth_to_point(psi: &Vector3<f64>) -> Vector3<f64> {
    Vector3::new(psi.x / psi.z, psi.y / psi.z, 1.0 / psi.z)
}

/// `∂Π(ψ)/∂ψ = (1/ψ₃)·[[1, 0, −y₁], [0, 1, −y₂], [0, 0, −y₃]]` with `y = Π(ψ)` (thesis eq. B.15).
#[inline]
pub fn d_inverse_depth_to_point(psi: &Vector3<f64>) -> Matrix3<f64> {
    let y = inverse_depth_to_point(psi);
    Matrix3::new(1.0, 0.0, -y.x, 0.0, 1.0, -y.y, 0.0, 0.0, -y.z) / psi.z
}

/// The smallest inverse depth accepted: `q ≤` this means the point is at or beyond infinity
/// (or behind the anchor), where `Π` is undefined.
pub const MIN_INVERSE_DEPTH: f64 = 1e-12;

/// `Π⁻¹(x) = (x₁/x₃, x₂/x₃, 1/x₃)`: the anchored inverse-depth point of a point `x` given in its
/// anchor frame (the inverse of [`inverse_depth_to_point`]); `None` if `x₃ ≤ 0` or not finite.
pub fn point_to_inverse_depth(x_anchor: &Vector3<f64>) -> Option<Vector3<f64>> {
    (x_anchor.iter().all(|v| v.is_finite()) && x_anchor.z > 0.0).then(|| {
        Vector3::new(
            x_anchor.x / x_anchor.z,
            x_anchor.y / x_anchor.z,
            1.0 / x_anchor.z,
        )
    })
}

/// An anchored inverse-depth point observed from another pose (thesis eq. 4.17, B.19–B.22):
/// `r = ẑ(T_lw·T_aw⁻¹·Π(ψ)) − z`, ternary in the observer `T_lw`, the anchor `T_aw` and `ψ`.
/// The poses are `Se3` by default, or any [`AnchoredPose`] (the fixed-scale Sim(3) poses of
/// double window optimisation).
pub struct AnchoredObservation<P, const N: usize, T = Se3> {
    /// The observer's `camera_from_world` (`T_lw`).
    pub observer_from_world: Var<T>,
    /// The anchor's `camera_from_world` (`T_aw`).
    pub anchor_from_world: Var<T>,
    /// `ψ = (u, v, q)` in the anchor frame.
    pub inverse_depth_point: Var<Vector3<f64>>,
    /// The measurement `z`.
    pub measurement: SVector<f64, N>,
    /// The measurement model.
    pub projector: P,
}

/// A pose variable an [`AnchoredObservation`] can be linearised at: updated by rigid left
/// increments `exp(ε)·T`, `ε ∈ R⁶`, so that [`linearize_anchored`] gives its Jacobians.
pub trait AnchoredPose: Manifold {
    /// [`linearize_anchored`] at these poses.
    fn linearize_observation<P: Projector<N>, const N: usize>(
        projector: &P,
        observer_from_world: &Self,
        anchor_from_world: &Self,
        psi: &Vector3<f64>,
    ) -> Option<AnchoredLinearization<N>>;
}

impl AnchoredPose for Se3 {
    #[inline]
    fn linearize_observation<P: Projector<N>, const N: usize>(
        projector: &P,
        observer_from_world: &Se3,
        anchor_from_world: &Se3,
        psi: &Vector3<f64>,
    ) -> Option<AnchoredLinearization<N>> {
        linearize_anchored(projector, observer_from_world, anchor_from_world, psi)
    }
}

impl<P: Projector<N>, const N: usize, T: AnchoredPose> Factor for AnchoredObservation<P, N, T> {
    fn residual_dim(&self) -> usize {
        N
    }

    fn variables(&self) -> Vec<VarKey> {
        vec![
            self.observer_from_world.key(),
            self.anchor_from_world.key(),
            self.inverse_depth_point.key(),
        ]
    }

    fn evaluate(
        &self,
        values: &Values,
        residual: &mut [f64],
        jacobians: Option<&mut Jacobians<'_>>,
    ) -> bool {
        let Some(lin) = T::linearize_observation(
            &self.projector,
            values.get(self.observer_from_world),
            values.get(self.anchor_from_world),
            values.get(self.inverse_depth_point),
        ) else {
            return false;
        };
        residual.copy_from_slice((lin.predicted - self.measurement).as_slice());
        if let Some(j) = jacobians {
            if j.wants(0) {
                j.set(0, &lin.d_observer);
            }
            if j.wants(1) {
                j.set(1, &lin.d_anchor);
            }
            if j.wants(2) {
                j.set(2, &lin.d_inverse_depth);
            }
        }
        true
    }
}

/// The prediction `ẑ(T_lw·T_aw⁻¹·Π(ψ))` of an anchored inverse-depth point and its Jacobians
/// with respect to left perturbations `exp(ε)·T` of observer and anchor and to `ψ` (thesis
/// eq. 4.17, B.19–B.22; the blocks of thesis Alg. 4).
#[derive(Clone, Copy, Debug)]
pub struct AnchoredLinearization<const N: usize> {
    /// `ẑ`.
    pub predicted: SVector<f64, N>,
    /// `∂ẑ/∂ε` of the observer `exp(ε)·T_lw`.
    pub d_observer: SMatrix<f64, N, 6>,
    /// `∂ẑ/∂ε` of the anchor `exp(ε)·T_aw`.
    pub d_anchor: SMatrix<f64, N, 6>,
    /// `∂ẑ/∂ψ`.
    pub d_inverse_depth: SMatrix<f64, N, 3>,
}

/// Linearises an anchored inverse-depth observation (the maths of [`AnchoredObservation`]),
/// or `None` where it is undefined (inverse depth not positive, point behind the observer).
/// The poses are SE(3), or Sim(3) perturbed by a rigid `exp(ε)` (the fixed-scale poses of
/// double window optimisation, thesis §6.2.7): the Jacobians are the same expressions.
#[inline]
pub fn linearize_anchored<G, const D: usize, P: Projector<N>, const N: usize>(
    projector: &P,
    observer_from_world: &G,
    anchor_from_world: &G,
    psi: &Vector3<f64>,
) -> Option<AnchoredLinearization<N>>
where
    G: LieGroup<D, Point = Vector3<f64>, PointMatrix = Matrix3<f64>>,
{
    if psi.z.is_nan() || psi.z <= MIN_INVERSE_DEPTH {
        return None;
    }
    let t_la = observer_from_world.compose(&anchor_from_world.inverse());
    let y = inverse_depth_to_point(psi);
    let x = t_la.act(&y);
    let (predicted, dz_dx) = projector.project(&x)?;
    let r_la = t_la.d_act_d_point();
    Some(AnchoredLinearization {
        predicted,
        d_observer: dz_dx * d_point_d_pose(&x),
        // x = T_lw·(exp(ε)·T_aw)⁻¹·y = T_la·exp(−ε)·y (thesis eq. B.22).
        d_anchor: -(dz_dx * r_la) * d_point_d_pose(&y),
        d_inverse_depth: dz_dx * r_la * d_inverse_depth_to_point(psi),
    })
}

/// The predicted measurement of an anchored inverse-depth point and its Jacobian with respect
/// to `ψ`, by a camera whose pose relative to the anchor, `T_la = T_lw·T_aw⁻¹`, is known (thesis
/// eq. B.19–B.21): `ẑ = proj(T_la·Π(ψ))`, `∂ẑ/∂ψ = ∂ẑ/∂x · R_la · ∂Π/∂ψ`; in the anchor itself
/// (`None`), `ẑ = proj(Π(ψ))`. `None` when `ψ` is not finite or `ψ₃` not a positive inverse depth,
/// or the point is not projectable (behind the camera).
pub fn predict_inverse_depth<P: Projector<N>, const N: usize>(
    projector: &P,
    observer_from_anchor: Option<&Se3>,
    psi: &Vector3<f64>,
) -> Option<(SVector<f64, N>, SMatrix<f64, N, 3>)> {
    if !psi.iter().all(|v| v.is_finite()) || psi.z <= MIN_INVERSE_DEPTH {
        return None;
    }
    let y = inverse_depth_to_point(psi);
    match observer_from_anchor {
        None => {
            let (z, dz_dx) = projector.project(&y)?;
            Some((z, dz_dx * d_inverse_depth_to_point(psi)))
        }
        Some(t_la) => {
            let (z, dz_dx) = projector.project(&t_la.act(&y))?;
            Some((
                z,
                dz_dx * t_la.d_act_d_point() * d_inverse_depth_to_point(psi),
            ))
        }
    }
}

/// An anchored inverse-depth point measured by a camera whose pose relative to the anchor is
/// held constant: `r = ẑ(T_la·Π(ψ)) − z`, unary in `ψ` ([`predict_inverse_depth`]). In its own
/// anchor frame (`observer_from_anchor: None`) the observation involves no pose at all (thesis
/// §4.4.2: the anchor's observation in a window, the first term of a feature filter); with a
/// known `T_la` it is a measurement of a feature-initialisation filter (thesis eq. 3.36, second
/// term).
pub struct InverseDepthObservation<P, const N: usize> {
    /// `ψ = (u, v, q)` in the anchor frame.
    pub inverse_depth_point: Var<Vector3<f64>>,
    /// `T_la = T_lw·T_aw⁻¹`; `None` in the anchor frame itself.
    pub observer_from_anchor: Option<Se3>,
    /// The measurement `z`.
    pub measurement: SVector<f64, N>,
    /// The measurement model.
    pub projector: P,
}

impl<P: Projector<N>, const N: usize> Factor for InverseDepthObservation<P, N> {
    fn residual_dim(&self) -> usize {
        N
    }

    fn variables(&self) -> Vec<VarKey> {
        vec![self.inverse_depth_point.key()]
    }

    fn evaluate(
        &self,
        values: &Values,
        residual: &mut [f64],
        jacobians: Option<&mut Jacobians<'_>>,
    ) -> bool {
        let Some((z_hat, j)) = predict_inverse_depth(
            &self.projector,
            self.observer_from_anchor.as_ref(),
            values.get(self.inverse_depth_point),
        ) else {
            return false;
        };
        residual.copy_from_slice((z_hat - self.measurement).as_slice());
        if let Some(jac) = jacobians {
            jac.set(0, &j);
        }
        true
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::factors::test_support::{assert_jacobians, point_in_front, random_pose};
    use geom::{DistortedCamera, PinholeCamera, RadTan, StereoCamera};
    use nalgebra::{Vector2, Vector6};
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    #[test]
    fn point_observation_jacobians_mono_stereo_distorted() {
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        let pinhole = PinholeCamera::new(500.0, 510.0, 320.0, 240.0);
        let stereo = StereoCamera::new(pinhole, 0.1);
        let distorted = DistortedCamera::new(pinhole, RadTan::new(-0.28, 0.07, 2e-4, -1e-4));
        for _ in 0..20 {
            let mut values = Values::new();
            let t = random_pose(&mut rng);
            let y = point_in_front(&mut rng, &t);
            let (tv, yv) = (values.add(t), values.add(y));
            let f = PointObservation {
                camera_from_world: tv,
                point_world: yv,
                measurement: Vector2::new(300.0, 200.0),
                projector: pinhole,
            };
            assert_jacobians(&f, &values, "mono");
            let f = PointObservation {
                camera_from_world: tv,
                point_world: yv,
                measurement: Vector3::new(300.0, 200.0, 280.0),
                projector: stereo,
            };
            assert_jacobians(&f, &values, "stereo");
            let f = PointObservation {
                camera_from_world: tv,
                point_world: yv,
                measurement: Vector2::new(300.0, 200.0),
                projector: distorted,
            };
            assert_jacobians(&f, &values, "distorted");
        }
    }

    #[test]
    fn anchored_inverse_depth_jacobians_mono_and_stereo() {
        let mut rng = ChaCha8Rng::seed_from_u64(2);
        let pinhole = PinholeCamera::new(300.0, 300.0, 320.0, 240.0);
        let stereo = StereoCamera::new(pinhole, 0.05);
        for _ in 0..20 {
            let mut values = Values::new();
            let anchor = random_pose(&mut rng);
            let observer =
                Se3::exp(&Vector6::new(0.1, -0.05, 0.2, 0.02, -0.03, 0.01)).compose(&anchor);
            let depth: f64 = rng.random_range(2.0..6.0);
            let psi = Vector3::new(
                rng.random_range(-0.3..0.3),
                rng.random_range(-0.3..0.3),
                1.0 / depth,
            );
            let (o, a, p) = (values.add(observer), values.add(anchor), values.add(psi));
            let f = AnchoredObservation {
                observer_from_world: o,
                anchor_from_world: a,
                inverse_depth_point: p,
                measurement: Vector2::new(310.0, 250.0),
                projector: pinhole,
            };
            assert_jacobians(&f, &values, "anchored mono");
            let f = AnchoredObservation {
                observer_from_world: o,
                anchor_from_world: a,
                inverse_depth_point: p,
                measurement: Vector3::new(310.0, 250.0, 300.0),
                projector: stereo,
            };
            assert_jacobians(&f, &values, "anchored stereo");
            let f = InverseDepthObservation {
                observer_from_anchor: None,
                inverse_depth_point: p,
                measurement: Vector2::new(310.0, 250.0),
                projector: pinhole,
            };
            assert_jacobians(&f, &values, "anchor mono");
            let f = InverseDepthObservation {
                observer_from_anchor: None,
                inverse_depth_point: p,
                measurement: Vector3::new(310.0, 250.0, 300.0),
                projector: stereo,
            };
            assert_jacobians(&f, &values, "anchor stereo");
        }
    }

    #[test]
    fn anchored_and_euclidean_parametrisations_predict_the_same_measurement() {
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let pinhole = PinholeCamera::new(300.0, 300.0, 320.0, 240.0);
        let anchor = random_pose(&mut rng);
        let observer = random_pose(&mut rng);
        let psi = Vector3::new(0.1, -0.2, 0.25);
        let world = anchor.inverse().act(&inverse_depth_to_point(&psi));
        let mut values = Values::new();
        let (o, a, p, w) = (
            values.add(observer),
            values.add(anchor),
            values.add(psi),
            values.add(world),
        );
        let z = Vector2::new(0.0, 0.0);
        let mut r1 = [0.0; 2];
        let mut r2 = [0.0; 2];
        assert!(
            AnchoredObservation {
                observer_from_world: o,
                anchor_from_world: a,
                inverse_depth_point: p,
                measurement: z,
                projector: pinhole
            }
            .evaluate(&values, &mut r1, None)
        );
        assert!(
            PointObservation {
                camera_from_world: o,
                point_world: w,
                measurement: z,
                projector: pinhole
            }
            .evaluate(&values, &mut r2, None)
        );
        assert!((r1[0] - r2[0]).abs() < 1e-9 && (r1[1] - r2[1]).abs() < 1e-9);
    }

    #[test]
    fn points_behind_the_camera_or_at_infinity_are_rejected_not_projected() {
        let pinhole = PinholeCamera::new(300.0, 300.0, 320.0, 240.0);
        let mut values = Values::new();
        let t = values.add(Se3::identity());
        let behind = values.add(Vector3::new(0.0, 0.0, -2.0));
        let mut r = [0.0; 2];
        assert!(
            !PointObservation {
                camera_from_world: t,
                point_world: behind,
                measurement: Vector2::zeros(),
                projector: pinhole
            }
            .evaluate(&values, &mut r, None)
        );
        let at_infinity = values.add(Vector3::new(0.1, 0.1, 0.0));
        assert!(
            !InverseDepthObservation {
                observer_from_anchor: None,
                inverse_depth_point: at_infinity,
                measurement: Vector2::zeros(),
                projector: pinhole
            }
            .evaluate(&values, &mut r, None)
        );
        let nan = values.add(Vector3::new(f64::NAN, 0.0, 1.0));
        assert!(
            !PointObservation {
                camera_from_world: t,
                point_world: nan,
                measurement: Vector2::zeros(),
                projector: pinhole
            }
            .evaluate(&values, &mut r, None)
        );
    }
}
