//! The BAL/Bundler camera as an optimisation variable and its observation factor ("Bundle
//! Adjustment in the Large", Agarwal et al. 2010).

use super::d_point_d_pose;
use geom::{BalCamera, CameraError};
use lie::{LieGroup, Se3};
use lsq::{Factor, Jacobians, Manifold, Values, Var, VarKey};
use nalgebra::{SMatrix, Vector2, Vector3};

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
    use crate::factors::test_support::{assert_jacobians, random_pose};
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

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
