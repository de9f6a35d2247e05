//! Synthetic bundle-adjustment scenes: cameras on a circle looking at a point cloud, with
//! known ground truth and Gaussian pixel noise (the scaling benchmark of issue 4 and the BA
//! tests).

use data::bal::{BalCameraParameters, BalObservation, BalProblem};
use geom::{BalCamera, CameraModel, PinholeCamera};
use lie::{LieGroup, Se3, So3};
use nalgebra::{Vector2, Vector3, Vector6};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};
use slam::ba::Observation;

/// Parameters of [`circle_scene`].
#[derive(Clone, Debug)]
pub struct CircleSceneParams {
    /// Number of cameras, evenly spaced on the circle.
    pub cameras: usize,
    /// Number of points.
    pub points: usize,
    /// Radius of the camera circle (m).
    pub radius: f64,
    /// Points are uniform in a ball of this radius about the centre (m).
    pub cloud_radius: f64,
    /// Each point is observed by at most this many consecutive cameras that see it (a
    /// feature track); at least 2.
    pub max_track_length: usize,
    /// Standard deviation of the pixel noise.
    pub noise_sigma: f64,
    /// Seed of every random draw.
    pub seed: u64,
}

impl Default for CircleSceneParams {
    fn default() -> Self {
        CircleSceneParams {
            cameras: 50,
            points: 1000,
            radius: 10.0,
            cloud_radius: 3.0,
            max_track_length: 8,
            noise_sigma: 1.0,
            seed: 1,
        }
    }
}

/// A synthetic scene: ground truth and noisy monocular observations (pixels, 640×480).
#[derive(Clone, Debug)]
pub struct BaScene {
    /// The camera (f = 500, principal point at the image centre).
    pub camera: PinholeCamera,
    /// True `camera_from_world` of each camera.
    pub camera_from_world: Vec<Se3>,
    /// True world points.
    pub points_world: Vec<Vector3<f64>>,
    /// Noisy observations `z = ẑ(T·y) + 𝒩(0, σ²I)`.
    pub observations: Vec<Observation<2>>,
    /// The pixel noise σ.
    pub noise_sigma: f64,
}

/// Image size of the simulated camera.
pub const IMAGE_SIZE: (f64, f64) = (640.0, 480.0);

pub use crate::trajectory::look_at;

/// Generates the scene: cameras on a horizontal circle about the origin, each looking at the
/// origin; points uniform in a ball; each point observed by up to `max_track_length`
/// consecutive cameras among those in whose image it falls.
pub fn circle_scene(params: &CircleSceneParams) -> BaScene {
    let mut rng = ChaCha8Rng::seed_from_u64(params.seed);
    let camera = PinholeCamera::new(500.0, 500.0, IMAGE_SIZE.0 / 2.0, IMAGE_SIZE.1 / 2.0);
    let up = Vector3::new(0.0, 0.0, 1.0);
    let camera_from_world: Vec<Se3> = (0..params.cameras)
        .map(|k| {
            let a = 2.0 * std::f64::consts::PI * k as f64 / params.cameras as f64;
            let centre = Vector3::new(params.radius * a.cos(), params.radius * a.sin(), 0.0);
            look_at(&centre, &Vector3::zeros(), &up)
        })
        .collect();
    let noise = Normal::new(0.0, params.noise_sigma.max(0.0)).expect("σ ≥ 0");
    let mut points_world = Vec::with_capacity(params.points);
    let mut observations = Vec::new();
    let track = params.max_track_length.max(2);
    while points_world.len() < params.points {
        // Uniform in the ball by rejection.
        let p = Vector3::new(
            rng.random_range(-1.0..1.0),
            rng.random_range(-1.0..1.0),
            rng.random_range(-1.0..1.0),
        );
        if p.norm_squared() > 1.0 {
            continue;
        }
        let p = p * params.cloud_radius;
        let visible: Vec<(usize, Vector2<f64>)> = camera_from_world
            .iter()
            .enumerate()
            .filter_map(|(k, t)| {
                let uv = camera.project(&t.act(&p)).ok()?;
                (uv.x >= 0.0 && uv.x < IMAGE_SIZE.0 && uv.y >= 0.0 && uv.y < IMAGE_SIZE.1)
                    .then_some((k, uv))
            })
            .collect();
        if visible.len() < 2 {
            continue;
        }
        // A track: a run of consecutive visible cameras starting at a random one.
        let len = rng.random_range(2..=track.min(visible.len()));
        let start = rng.random_range(0..=visible.len() - len);
        let index = points_world.len();
        points_world.push(p);
        for &(k, uv) in &visible[start..start + len] {
            observations.push(Observation {
                pose: k,
                point: index,
                measurement: uv + Vector2::new(noise.sample(&mut rng), noise.sample(&mut rng)),
            });
        }
    }
    BaScene {
        camera,
        camera_from_world,
        points_world,
        observations,
        noise_sigma: params.noise_sigma,
    }
}

/// Initial values for optimisation: the truth perturbed by Gaussian noise of the given size
/// (pose tangent `(v, ω)` with σ_t and σ_r, points with σ_p), seeded.
pub fn perturb(
    scene: &BaScene,
    sigma_t: f64,
    sigma_r: f64,
    sigma_p: f64,
    seed: u64,
) -> (Vec<Se3>, Vec<Vector3<f64>>) {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let n = |s: f64| Normal::new(0.0, s.max(0.0)).expect("σ ≥ 0");
    let (nt, nr, np) = (n(sigma_t), n(sigma_r), n(sigma_p));
    let poses = scene
        .camera_from_world
        .iter()
        .map(|t| {
            let d = Vector6::new(
                nt.sample(&mut rng),
                nt.sample(&mut rng),
                nt.sample(&mut rng),
                nr.sample(&mut rng),
                nr.sample(&mut rng),
                nr.sample(&mut rng),
            );
            Se3::exp(&d).compose(t)
        })
        .collect();
    let points = scene
        .points_world
        .iter()
        .map(|p| {
            p + Vector3::new(
                np.sample(&mut rng),
                np.sample(&mut rng),
                np.sample(&mut rng),
            )
        })
        .collect();
    (poses, points)
}

/// The rotation from our camera frame (z forward, y down) to the BAL camera frame (looks down
/// −z, y up): `diag(1, −1, −1)`.
fn bal_flip() -> So3 {
    So3::rot_x(std::f64::consts::PI)
}

/// The scene as a BAL problem with the given initial poses and points: BAL cameras with
/// `f = 500`, `k₁ = k₂ = 0`, measurements relative to the image centre with `y` up.
pub fn to_bal(
    scene: &BaScene,
    camera_from_world: &[Se3],
    points_world: &[Vector3<f64>],
) -> BalProblem {
    let flip = Se3::from_rotation(bal_flip());
    let (cx, cy) = (scene.camera.cx, scene.camera.cy);
    BalProblem {
        cameras: camera_from_world
            .iter()
            .map(|t| {
                let bal_from_world = flip.compose(t);
                BalCameraParameters {
                    camera_from_world: bal_from_world,
                    rotation_vector: bal_from_world.rotation().log(),
                    intrinsics: BalCamera::new(scene.camera.fx, 0.0, 0.0),
                }
            })
            .collect(),
        points_world: points_world.to_vec(),
        observations: scene
            .observations
            .iter()
            .map(|o| BalObservation {
                camera: o.pose,
                point: o.point,
                measurement: Vector2::new(o.measurement.x - cx, -(o.measurement.y - cy)),
            })
            .collect(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn scene_is_deterministic_and_consistent_with_its_bal_form() {
        let params = CircleSceneParams {
            points: 200,
            noise_sigma: 0.0,
            ..Default::default()
        };
        let a = circle_scene(&params);
        let b = circle_scene(&params);
        assert_eq!(a.observations, b.observations);
        assert_eq!(a.points_world.len(), 200);
        assert!(a.observations.len() >= 400);
        // Noise-free: every observation reprojects exactly, in both forms.
        let bal = to_bal(&a, &a.camera_from_world, &a.points_world);
        for (k, o) in a.observations.iter().enumerate() {
            let uv = a
                .camera
                .project(&a.camera_from_world[o.pose].act(&a.points_world[o.point]))
                .unwrap();
            assert!((uv - o.measurement).norm() < 1e-9);
            assert!(
                bal.residual(k).unwrap().norm() < 1e-9,
                "BAL residual {:?}",
                bal.residual(k)
            );
        }
    }

    #[test]
    fn look_at_points_the_optical_axis_at_the_target() {
        let t = look_at(
            &Vector3::new(10.0, 0.0, 0.0),
            &Vector3::zeros(),
            &Vector3::z(),
        );
        let x = t.act(&Vector3::zeros());
        assert!(x.x.abs() < 1e-12 && x.y.abs() < 1e-12 && (x.z - 10.0).abs() < 1e-12);
        // World up is image up (negative camera y).
        assert!(t.act(&Vector3::new(0.0, 0.0, 1.0)).y < 0.0);
    }
}
