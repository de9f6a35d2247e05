//! Simulated sensors: visibility (image bounds, depth range) and Gaussian pixel noise with
//! perfect data association, for monocular and stereo cameras (thesis §3.2, §4.3.1, §4.6).

use geom::{CameraModel, PinholeCamera, StereoCamera};
use lie::{LieGroup, Se3};
use nalgebra::{SVector, Vector2, Vector3};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};
use slam::ba::Observation;
use slam::factors::Projector;

/// The kind of simulated camera.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum SensorKind {
    /// Rectified stereo.
    Stereo,
    /// Monocular.
    Mono,
}

impl SensorKind {
    /// Both, stereo first.
    pub const ALL: [SensorKind; 2] = [SensorKind::Stereo, SensorKind::Mono];

    /// Lower-case name.
    pub fn name(self) -> &'static str {
        match self {
            SensorKind::Stereo => "stereo",
            SensorKind::Mono => "mono",
        }
    }
}

/// A camera that sees a point when it projects inside the image and lies within a depth
/// range, and measures it with isotropic Gaussian noise of `sigma` pixels.
pub trait Sensor<const N: usize>: Sync {
    /// The noise-free measurement of `point_world` from `camera_from_world`, if visible.
    fn predict(
        &self,
        camera_from_world: &Se3,
        point_world: &Vector3<f64>,
    ) -> Option<SVector<f64, N>>;
    /// The pixel noise σ.
    fn sigma(&self) -> f64;
}

/// Image size and depth range shared by the sensors.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Visibility {
    /// Image width in pixels (`0 ≤ u < width`).
    pub width: f64,
    /// Image height in pixels (`0 ≤ v < height`).
    pub height: f64,
    /// Nearest visible depth (m).
    pub min_depth: f64,
    /// Farthest visible depth (m).
    pub max_depth: f64,
}

impl Visibility {
    /// A 640×480 image and depths in `[0.1, 100]` m.
    pub const VGA: Visibility = Visibility {
        width: 640.0,
        height: 480.0,
        min_depth: 0.1,
        max_depth: 100.0,
    };

    fn in_image(&self, uv: &Vector2<f64>) -> bool {
        uv.x >= 0.0 && uv.x < self.width && uv.y >= 0.0 && uv.y < self.height
    }

    fn in_range(&self, depth: f64) -> bool {
        depth >= self.min_depth && depth <= self.max_depth
    }
}

/// A monocular pinhole camera measuring `(u, v)`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MonoSensor {
    /// The camera.
    pub camera: PinholeCamera,
    /// Image bounds and depth range.
    pub visibility: Visibility,
    /// Pixel noise σ.
    pub sigma: f64,
}

impl MonoSensor {
    /// A 640×480 camera with focal length `f` and the principal point at the image centre.
    pub fn vga(f: f64, sigma: f64) -> Self {
        MonoSensor {
            camera: PinholeCamera::new(f, f, 320.0, 240.0),
            visibility: Visibility::VGA,
            sigma,
        }
    }
}

impl Sensor<2> for MonoSensor {
    fn predict(&self, camera_from_world: &Se3, point_world: &Vector3<f64>) -> Option<Vector2<f64>> {
        let x = camera_from_world.act(point_world);
        if !self.visibility.in_range(x.z) {
            return None;
        }
        let uv = CameraModel::project(&self.camera, &x).ok()?;
        self.visibility.in_image(&uv).then_some(uv)
    }

    fn sigma(&self) -> f64 {
        self.sigma
    }
}

/// A rectified stereo camera measuring `(u_l, v_l, u_r)`; a point is visible when it
/// projects inside both images.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StereoSensor {
    /// The camera.
    pub camera: StereoCamera,
    /// Image bounds and depth range.
    pub visibility: Visibility,
    /// Pixel noise σ.
    pub sigma: f64,
}

impl StereoSensor {
    /// A 640×480 stereo camera with focal length `f`, the principal point at the image centre
    /// and the given baseline (m).
    pub fn vga(f: f64, baseline: f64, sigma: f64) -> Self {
        StereoSensor {
            camera: StereoCamera::new(PinholeCamera::new(f, f, 320.0, 240.0), baseline),
            visibility: Visibility::VGA,
            sigma,
        }
    }

    /// The left camera alone.
    pub fn left(&self) -> MonoSensor {
        MonoSensor {
            camera: self.camera.pinhole,
            visibility: self.visibility,
            sigma: self.sigma,
        }
    }
}

impl Sensor<3> for StereoSensor {
    fn predict(&self, camera_from_world: &Se3, point_world: &Vector3<f64>) -> Option<Vector3<f64>> {
        let x = camera_from_world.act(point_world);
        if !self.visibility.in_range(x.z) {
            return None;
        }
        let z = Projector::<3>::project(&self.camera, &x)?.0;
        let (left, right) = (Vector2::new(z.x, z.y), Vector2::new(z.z, z.y));
        (self.visibility.in_image(&left) && self.visibility.in_image(&right)).then_some(z)
    }

    fn sigma(&self) -> f64 {
        self.sigma
    }
}

/// Noisy measurements of every visible point from every pose, in pose-major order: for pose
/// `i`, the points in index order. Perfect data association: each observation names its
/// point.
pub fn observe<S: Sensor<N>, const N: usize>(
    sensor: &S,
    camera_from_world: &[Se3],
    points_world: &[Vector3<f64>],
    rng: &mut ChaCha8Rng,
) -> Vec<Observation<N>> {
    let noise = Normal::new(0.0, sensor.sigma().max(0.0)).expect("σ ≥ 0");
    let mut out = Vec::new();
    for (i, t) in camera_from_world.iter().enumerate() {
        for (j, p) in points_world.iter().enumerate() {
            if let Some(z) = sensor.predict(t, p) {
                let noisy = z + SVector::<f64, N>::from_fn(|_, _| noise.sample(rng));
                out.push(Observation {
                    pose: i,
                    point: j,
                    measurement: noisy,
                });
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::trajectory::sideways;
    use crate::world::nested_plane_grid;
    use rand::SeedableRng;

    #[test]
    fn the_preliminary_experiment_scene_is_fully_visible_in_stereo() {
        // Thesis §4.3.1: stereo f = 500, baseline 0.1 m, plane at 3 m, 1 m sideways: the object
        // is fully observable from all frames.
        let sensor = StereoSensor::vga(500.0, 0.1, 0.5);
        let poses = sideways(1.0, 36);
        // Centred on the middle of the trajectory, so every frame sees all of it.
        let points: Vec<_> = nested_plane_grid(25, 17, 2.0, 1.4, 3.0)
            .iter()
            .map(|p| p + Vector3::new(0.5, 0.0, 0.0))
            .collect();
        let obs = observe(&sensor, &poses, &points, &mut ChaCha8Rng::seed_from_u64(1));
        assert_eq!(obs.len(), poses.len() * points.len());
    }

    #[test]
    fn invisible_points_are_not_observed_and_noise_is_seeded() {
        let sensor = MonoSensor::vga(500.0, 1.0);
        let t = Se3::identity();
        assert!(
            sensor.predict(&t, &Vector3::new(0.0, 0.0, -1.0)).is_none(),
            "behind"
        );
        assert!(
            sensor.predict(&t, &Vector3::new(10.0, 0.0, 1.0)).is_none(),
            "outside the image"
        );
        assert!(
            sensor
                .predict(&t, &Vector3::new(0.0, 0.0, 1000.0))
                .is_none(),
            "too far"
        );
        let pts = vec![Vector3::new(0.1, 0.1, 2.0)];
        let a = observe(&sensor, &[t], &pts, &mut ChaCha8Rng::seed_from_u64(3));
        let b = observe(&sensor, &[t], &pts, &mut ChaCha8Rng::seed_from_u64(3));
        assert_eq!(a, b);
        let stereo = StereoSensor::vga(500.0, 0.1, 0.0);
        // Visible in the left image but not in the right one.
        assert!(stereo.predict(&t, &Vector3::new(-0.6, 0.0, 1.0)).is_none());
        assert!(
            stereo
                .left()
                .predict(&t, &Vector3::new(-0.6, 0.0, 1.0))
                .is_some()
        );
    }
}
