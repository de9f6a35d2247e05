//! Bundle-adjustment factors (thesis §3.3.1, ch. 4, app. B.4–B.5): reprojection errors of
//! Euclidean and anchored inverse-depth points, for monocular and stereo cameras, and the
//! BAL/Bundler camera with its intrinsics.
//!
//! Residuals are predicted minus measured, `r = ẑ(x) − z`; the cost is `½ρ(rᵀΛr)`. Poses are
//! `camera_from_world: Se3` updated by `exp(ε)·T` (thesis eq. 2.104).

use geom::{BalCamera, CameraError, CameraModel, StereoCamera};
use lie::{LieGroup, Se3, skew};
use lsq::{Factor, Jacobians, Manifold, Values, Var, VarKey};
use nalgebra::{Matrix3, SMatrix, SVector, Vector2, Vector3};

/// A measurement model from camera-frame points to `N` measurement coordinates with its
/// Jacobian (thesis eq. 3.4, 3.9, B.4, B.6): `(u, v)` for monocular cameras, `(u_l, v_l, u_r)`
/// for stereo and RGB-D (virtual stereo).
pub trait Projector<const N: usize>: Send + Sync + 'static {
    /// `(ẑ(x), ∂ẑ/∂x)`, or `None` when `x` is behind the camera (or otherwise not projectable).
    fn project(&self, x: &Vector3<f64>) -> Option<(SVector<f64, N>, SMatrix<f64, N, 3>)>;
}

impl<C: CameraModel + Send + Sync + 'static> Projector<2> for C {
    #[inline]
    fn project(&self, x: &Vector3<f64>) -> Option<(Vector2<f64>, SMatrix<f64, 2, 3>)> {
        self.project_with_jacobian(x).ok()
    }
}

impl Projector<3> for StereoCamera {
    #[inline]
    fn project(&self, x: &Vector3<f64>) -> Option<(Vector3<f64>, Matrix3<f64>)> {
        self.project_with_jacobian(x).ok()
    }
}

impl Projector<3> for geom::RgbdCamera {
    #[inline]
    fn project(&self, x: &Vector3<f64>) -> Option<(Vector3<f64>, Matrix3<f64>)> {
        self.project_with_jacobian(x).ok()
    }
}

/// `∂(exp(ε)·x)/∂ε = [I | −[x]×]` for a camera-frame point `x` (thesis eq. B.12).
#[inline]
pub(crate) fn d_point_d_pose(x: &Vector3<f64>) -> SMatrix<f64, 3, 6> {
    let mut j = SMatrix::<f64, 3, 6>::zeros();
    j.fixed_view_mut::<3, 3>(0, 0)
        .copy_from(&Matrix3::identity());
    j.fixed_view_mut::<3, 3>(0, 3).copy_from(&(-skew(x)));
    j
}

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

/// An anchored inverse-depth point observed in its own anchor frame: `r = ẑ(Π(ψ)) − z`,
/// unary in `ψ` (thesis §4.4.2: the anchor's observation does not involve any pose).
pub struct AnchorObservation<P, const N: usize> {
    /// `ψ = (u, v, q)` in the anchor frame.
    pub inverse_depth_point: Var<Vector3<f64>>,
    /// The measurement `z`.
    pub measurement: SVector<f64, N>,
    /// The measurement model.
    pub projector: P,
}

impl<P: Projector<N>, const N: usize> Factor for AnchorObservation<P, N> {
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
        let psi = values.get(self.inverse_depth_point);
        if psi.z.is_nan() || psi.z <= MIN_INVERSE_DEPTH {
            return false;
        }
        let x = inverse_depth_to_point(psi);
        let Some((z_hat, dz_dx)) = self.projector.project(&x) else {
            return false;
        };
        residual.copy_from_slice((z_hat - self.measurement).as_slice());
        if let Some(j) = jacobians {
            j.set(0, &(dz_dx * d_inverse_depth_to_point(psi)));
        }
        true
    }
}

/// A BAL/Bundler camera as one optimisation variable: its pose and its intrinsics
/// `(f, k₁, k₂)`, 9 degrees of freedom updated by `exp(ε)·T` and `+δ`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BalCameraState {
    /// `P = camera_from_world · X`.
    pub camera_from_world: Se3,
    /// `(f, k₁, k₂)`.
    pub intrinsics: BalCamera,
}

impl Manifold for BalCameraState {
    const DIM: usize = 9;
    const NAME: &'static str = "BAL camera";

    fn retract(&mut self, delta: &[f64]) {
        self.camera_from_world.retract(&delta[..6]);
        self.intrinsics.f += delta[6];
        self.intrinsics.k1 += delta[7];
        self.intrinsics.k2 += delta[8];
    }

    fn is_finite(&self) -> bool {
        LieGroup::is_finite(&self.camera_from_world)
            && self.intrinsics.f.is_finite()
            && self.intrinsics.k1.is_finite()
            && self.intrinsics.k2.is_finite()
    }
}

/// A BAL observation: `r = ẑ_BAL(T·X; f, k₁, k₂) − z` (pixels, origin at the image centre, `y`
/// up), binary in the camera state and the world point.
pub struct BalObservationFactor {
    /// The camera.
    pub camera: Var<BalCameraState>,
    /// The world point.
    pub point_world: Var<Vector3<f64>>,
    /// The measurement.
    pub measurement: Vector2<f64>,
}

impl BalObservationFactor {
    /// The residual at given values, or why it is undefined.
    pub fn residual_at(
        camera: &BalCameraState,
        point: &Vector3<f64>,
        z: &Vector2<f64>,
    ) -> Result<Vector2<f64>, CameraError> {
        camera
            .intrinsics
            .project(&camera.camera_from_world.act(point))
            .map(|p| p - z)
    }
}

impl Factor for BalObservationFactor {
    fn residual_dim(&self) -> usize {
        2
    }

    fn variables(&self) -> Vec<VarKey> {
        vec![self.camera.key(), self.point_world.key()]
    }

    fn evaluate(
        &self,
        values: &Values,
        residual: &mut [f64],
        jacobians: Option<&mut Jacobians<'_>>,
    ) -> bool {
        let cam = values.get(self.camera);
        let p = cam.camera_from_world.act(values.get(self.point_world));
        let Ok((z_hat, dz_dp, dz_dk)) = cam.intrinsics.project_with_jacobians(&p) else {
            return false;
        };
        residual.copy_from_slice((z_hat - self.measurement).as_slice());
        if let Some(j) = jacobians {
            if j.wants(0) {
                let mut jc = SMatrix::<f64, 2, 9>::zeros();
                jc.fixed_view_mut::<2, 6>(0, 0)
                    .copy_from(&(dz_dp * d_point_d_pose(&p)));
                jc.fixed_view_mut::<2, 3>(0, 6).copy_from(&dz_dk);
                j.set(0, &jc);
            }
            if j.wants(1) {
                j.set(1, &(dz_dp * cam.camera_from_world.d_act_d_point()));
            }
        }
        true
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use geom::{DistortedCamera, PinholeCamera, RadTan};
    use lsq::numeric::check_jacobians;
    use nalgebra::Vector6;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    fn random_pose(rng: &mut ChaCha8Rng) -> Se3 {
        Se3::exp(&Vector6::from_fn(|i, _| {
            if i < 3 {
                rng.random_range(-0.5..0.5)
            } else {
                rng.random_range(-0.3..0.3)
            }
        }))
    }

    /// A world point in front of `camera_from_world`, at depth 2–8.
    fn point_in_front(rng: &mut ChaCha8Rng, camera_from_world: &Se3) -> Vector3<f64> {
        let x = Vector3::new(
            rng.random_range(-1.0..1.0),
            rng.random_range(-1.0..1.0),
            rng.random_range(2.0..8.0),
        );
        camera_from_world.inverse().act(&x)
    }

    fn assert_jacobians(factor: &dyn Factor, values: &Values, what: &str) {
        let check = check_jacobians(factor, values, 1e-5)
            .unwrap_or_else(|| panic!("{what}: undefined at the test point"));
        assert!(check.passes(1e-6), "{what}: {check:?}");
    }

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
            let f = AnchorObservation {
                inverse_depth_point: p,
                measurement: Vector2::new(310.0, 250.0),
                projector: pinhole,
            };
            assert_jacobians(&f, &values, "anchor mono");
            let f = AnchorObservation {
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
            !AnchorObservation {
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

    #[test]
    fn bal_observation_jacobians() {
        let mut rng = ChaCha8Rng::seed_from_u64(4);
        for _ in 0..20 {
            let mut values = Values::new();
            let t = random_pose(&mut rng);
            // BAL cameras look down −z: flip the point to negative depth.
            let x = Vector3::new(
                rng.random_range(-1.0..1.0),
                rng.random_range(-1.0..1.0),
                -rng.random_range(2.0..8.0),
            );
            let y = t.inverse().act(&x);
            let cam = values.add(BalCameraState {
                camera_from_world: t,
                intrinsics: BalCamera::new(
                    500.0,
                    rng.random_range(-0.1..0.1),
                    rng.random_range(-0.01..0.01),
                ),
            });
            let p = values.add(y);
            let f = BalObservationFactor {
                camera: cam,
                point_world: p,
                measurement: Vector2::new(10.0, -20.0),
            };
            assert_jacobians(&f, &values, "BAL");
        }
    }
}

/// Which variables a bundle adjustment optimises (thesis eq. 4.14–4.16).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum BaMode {
    /// Poses and points (eq. 4.14).
    Full,
    /// Poses only, points held fixed (eq. 4.15): tracking against a known map.
    MotionOnly,
    /// Points only, poses held fixed (eq. 4.16): refining structure for known motion.
    StructureOnly,
}

/// How the gauge freedom of full BA is removed (thesis §3.3.2–3.3.3, §4.5.3).
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Gauge {
    /// Hold these poses fixed (e.g. the first one for stereo, the first two for monocular BA,
    /// which also fixes the scale).
    FixPoses(Vec<usize>),
    /// Fix nothing; Levenberg-Marquardt's damping regularises the null space (§6.2.3).
    Damping,
}

/// One observation of point `point` from pose `pose`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Observation<const N: usize> {
    /// Index of the observing pose.
    pub pose: usize,
    /// Index of the observed point.
    pub point: usize,
    /// The measurement.
    pub measurement: SVector<f64, N>,
}

impl<const N: usize> Observation<N> {
    /// The observations of one pose (index 0) seeing points `0, 1, …` in the order of
    /// `measurements` (the input of motion-only BA).
    pub fn of_one_pose(measurements: impl IntoIterator<Item = SVector<f64, N>>) -> Vec<Self> {
        measurements
            .into_iter()
            .enumerate()
            .map(|(point, measurement)| Observation {
                pose: 0,
                point,
                measurement,
            })
            .collect()
    }
}

/// Why a bundle adjustment could not be built.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum BaError {
    /// An observation refers to a missing pose or point.
    #[error("observation {observation} refers to {what} {index}, but there are only {count}")]
    OutOfRange {
        /// Index of the observation.
        observation: usize,
        /// "pose" or "point".
        what: &'static str,
        /// The index used.
        index: usize,
        /// How many exist.
        count: usize,
    },
    /// The least-squares problem refused a factor.
    #[error(transparent)]
    Problem(#[from] lsq::ProblemError),
}

/// A bundle-adjustment problem over `camera_from_world` poses and Euclidean world points,
/// ready to optimise; points are eliminated by the Schur complement unless they are fixed.
pub struct BundleAdjustment {
    /// The least-squares problem.
    pub problem: lsq::Problem,
    /// Pose variables in input order.
    pub poses: Vec<Var<Se3>>,
    /// Point variables in input order.
    pub points: Vec<Var<Vector3<f64>>>,
}

impl BundleAdjustment {
    /// Builds the problem: one [`PointObservation`] per observation, with information
    /// `I/σ²` (`sigma` in measurement units) and an optional robust kernel (in units of σ).
    #[allow(clippy::too_many_arguments)]
    pub fn new<P: Projector<N> + Clone, const N: usize>(
        projector: &P,
        camera_from_world: &[Se3],
        points_world: &[Vector3<f64>],
        observations: &[Observation<N>],
        sigma: f64,
        kernel: Option<lsq::RobustKernel>,
        mode: BaMode,
        gauge: &Gauge,
    ) -> Result<Self, BaError> {
        let mut problem = lsq::Problem::new();
        let poses: Vec<Var<Se3>> = camera_from_world
            .iter()
            .map(|t| problem.add_variable(*t))
            .collect();
        let points: Vec<Var<Vector3<f64>>> = points_world
            .iter()
            .map(|p| problem.add_variable(*p))
            .collect();
        for (k, o) in observations.iter().enumerate() {
            if o.pose >= poses.len() {
                return Err(BaError::OutOfRange {
                    observation: k,
                    what: "pose",
                    index: o.pose,
                    count: poses.len(),
                });
            }
            if o.point >= points.len() {
                return Err(BaError::OutOfRange {
                    observation: k,
                    what: "point",
                    index: o.point,
                    count: points.len(),
                });
            }
            problem.add_factor(
                PointObservation {
                    camera_from_world: poses[o.pose],
                    point_world: points[o.point],
                    measurement: o.measurement,
                    projector: projector.clone(),
                },
                lsq::Information::Isotropic(sigma),
                kernel,
            )?;
        }
        match mode {
            BaMode::MotionOnly => points.iter().for_each(|p| problem.set_fixed(p.key(), true)),
            BaMode::StructureOnly => poses.iter().for_each(|t| problem.set_fixed(t.key(), true)),
            BaMode::Full => {
                if let Gauge::FixPoses(fixed) = gauge {
                    for &i in fixed {
                        if let Some(t) = poses.get(i) {
                            problem.set_fixed(t.key(), true);
                        }
                    }
                }
            }
        }
        if mode != BaMode::MotionOnly && !points.is_empty() {
            problem.set_eliminated::<Vector3<f64>>(true);
        }
        Ok(BundleAdjustment {
            problem,
            poses,
            points,
        })
    }

    /// The current poses.
    pub fn camera_from_world(&self) -> Vec<Se3> {
        self.poses.iter().map(|v| *self.problem.value(*v)).collect()
    }

    /// The current points.
    pub fn points_world(&self) -> Vec<Vector3<f64>> {
        self.points
            .iter()
            .map(|v| *self.problem.value(*v))
            .collect()
    }
}

/// A BAL bundle adjustment: [`BalCameraState`] cameras and world points, points eliminated by
/// the Schur complement, nothing fixed (the gauge is left to the damping, as Ceres does on
/// these problems).
pub struct BalAdjustment {
    /// The least-squares problem.
    pub problem: lsq::Problem,
    /// Camera variables in input order.
    pub cameras: Vec<Var<BalCameraState>>,
    /// Point variables in input order.
    pub points: Vec<Var<Vector3<f64>>>,
    /// Observations whose point is behind its camera at the initial values: not added.
    pub rejected: Vec<usize>,
}

impl BalAdjustment {
    /// Builds the problem from cameras, points and `(camera, point, measurement)`
    /// observations; observations that cannot be projected at the initial values (point
    /// behind the camera, non-finite) are left out and listed in `rejected`.
    pub fn new(
        cameras: &[BalCameraState],
        points_world: &[Vector3<f64>],
        observations: &[(usize, usize, Vector2<f64>)],
        kernel: Option<lsq::RobustKernel>,
    ) -> Result<Self, BaError> {
        let mut problem = lsq::Problem::new();
        let cams: Vec<_> = cameras.iter().map(|c| problem.add_variable(*c)).collect();
        let points: Vec<_> = points_world
            .iter()
            .map(|p| problem.add_variable(*p))
            .collect();
        let mut rejected = Vec::new();
        for (k, &(c, p, z)) in observations.iter().enumerate() {
            if c >= cams.len() {
                return Err(BaError::OutOfRange {
                    observation: k,
                    what: "camera",
                    index: c,
                    count: cams.len(),
                });
            }
            if p >= points.len() {
                return Err(BaError::OutOfRange {
                    observation: k,
                    what: "point",
                    index: p,
                    count: points.len(),
                });
            }
            if BalObservationFactor::residual_at(&cameras[c], &points_world[p], &z).is_err()
                || !z.iter().all(|v| v.is_finite())
            {
                rejected.push(k);
                continue;
            }
            problem.add_factor(
                BalObservationFactor {
                    camera: cams[c],
                    point_world: points[p],
                    measurement: z,
                },
                lsq::Information::Identity,
                kernel,
            )?;
        }
        problem.set_eliminated::<Vector3<f64>>(true);
        Ok(BalAdjustment {
            problem,
            cameras: cams,
            points,
            rejected,
        })
    }
}
