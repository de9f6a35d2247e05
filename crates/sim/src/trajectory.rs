//! Camera trajectories: sequences of true `camera_from_world` poses (thesis §4.3.1, §4.6.1,
//! §5.4, §6.5.1). Cameras follow the thesis's convention: x right, y down, z forward.

use lie::{LieGroup, Se3, So3};
use nalgebra::{Matrix3, Vector3};
use std::f64::consts::{FRAC_PI_2, TAU};

/// The pose of a camera at `centre` with optical axis `forward` and image "up" as close as
/// possible to `up` (the camera's −y axis), as `camera_from_world`. `forward` and `up` must not
/// be parallel.
pub fn pose_looking(centre: &Vector3<f64>, forward: &Vector3<f64>, up: &Vector3<f64>) -> Se3 {
    let z = forward.normalize();
    let x = z.cross(up).normalize();
    let y = z.cross(&x);
    let world_from_camera = Matrix3::from_columns(&[x, y, z]);
    let r = So3::from_matrix(&world_from_camera.transpose()).expect("orthonormal by construction");
    Se3::new(r, -r.act(centre))
}

/// The camera at `centre` looking at `target` (see [`pose_looking`]).
pub fn look_at(centre: &Vector3<f64>, target: &Vector3<f64>, up: &Vector3<f64>) -> Se3 {
    pose_looking(centre, &(target - centre), up)
}

/// The world "up" of the planar scenes of chapter 4: cameras look along world `+z` at a scene
/// at depth `z > 0` with image-up `−y` (so at the identity pose camera and world frames agree).
const UP_CH4: Vector3<f64> = Vector3::new(0.0, -1.0, 0.0);

/// `n + 1` poses (`T_0 … T_n`) moving sideways along `+x` by `length`, looking along `+z`
/// (thesis §4.3.1, setting (i)–(ii) of §4.6.1). `T_0` is the identity.
pub fn sideways(length: f64, n: usize) -> Vec<Se3> {
    sideways_with_rotation(length, 0.0, n)
}

/// Sideways motion along `+x` by `length` while yawing (about the camera's `y` axis) by
/// `total_rotation` radians in total, linearly (thesis §4.6.1 setting (iii): 30°).
pub fn sideways_with_rotation(length: f64, total_rotation: f64, n: usize) -> Vec<Se3> {
    (0..=n)
        .map(|k| {
            let s = if n == 0 { 0.0 } else { k as f64 / n as f64 };
            let centre = Vector3::new(length * s, 0.0, 0.0);
            // Yaw about the (image) vertical axis: turning towards −x for positive angles.
            let forward = So3::rot_y(-total_rotation * s).act(&Vector3::z());
            pose_looking(&centre, &forward, &UP_CH4)
        })
        .collect()
}

/// A sharp forward turn (thesis §4.6.1 setting (iv)): moving forward along `+z` on an arc of
/// radius `radius` while the heading turns by `angle` (e.g. 90°), `n + 1` poses from the identity.
pub fn forward_turn(radius: f64, angle: f64, n: usize) -> Vec<Se3> {
    (0..=n)
        .map(|k| {
            let a = if n == 0 {
                0.0
            } else {
                angle * k as f64 / n as f64
            };
            // Arc in the x–z plane starting at the origin heading +z, turning towards +x.
            let centre = Vector3::new(radius * (1.0 - a.cos()), 0.0, radius * a.sin());
            let forward = Vector3::new(a.sin(), 0.0, a.cos());
            pose_looking(&centre, &forward, &Vector3::new(0.0, -1.0, 0.0))
        })
        .collect()
}

/// `n_per_loop · loops` poses on a horizontal circle of radius `radius` about the world `z`
/// axis (counter-clockwise seen from above), looking outwards (`outward = true`, thesis §5.4)
/// or inwards; `loops = 2` is the double loop of thesis §6.5.1.
pub fn circle(radius: f64, n_per_loop: usize, loops: usize, outward: bool) -> Vec<Se3> {
    coil(radius, n_per_loop, loops, 0.0, outward)
}

/// Poses on a circle about the world `z` axis rising by `rise_per_loop` per loop, looking
/// radially outwards or inwards with image-up along `+z`.
fn coil(
    radius: f64,
    n_per_loop: usize,
    loops: usize,
    rise_per_loop: f64,
    outward: bool,
) -> Vec<Se3> {
    let up = Vector3::z();
    (0..n_per_loop * loops)
        .map(|k| {
            let turns = k as f64 / n_per_loop as f64;
            let a = TAU * turns;
            let radial = Vector3::new(a.cos(), a.sin(), 0.0);
            let centre = radial * radius + up * (rise_per_loop * turns);
            pose_looking(&centre, &(if outward { radial } else { -radial }), &up)
        })
        .collect()
}

/// A planar coil (trochoid): the camera circles `loops` times on a circle of radius
/// `loop_radius` whose centre advances along world `+x` by `advance_per_loop` per loop, `n`
/// poses in all, looking outwards from the moving circle centre — loopy local motion combined
/// with exploration (thesis §6.5.1, the spiral).
pub fn spiral(n: usize, loop_radius: f64, loops: f64, advance_per_loop: f64) -> Vec<Se3> {
    let up = Vector3::z();
    (0..n)
        .map(|k| {
            let t = k as f64 / n.max(1) as f64;
            let a = TAU * loops * t;
            let hub = Vector3::new(advance_per_loop * loops * t, 0.0, 0.0);
            let radial = Vector3::new(a.cos(), a.sin(), 0.0);
            pose_looking(&(hub + radial * loop_radius), &radial, &up)
        })
        .collect()
}

/// A helix: `n_per_loop · loops` poses on a circle of radius `radius` about the world `z` axis
/// (counter-clockwise seen from above) that rises by `rise_per_loop` per loop, looking
/// outwards with image-up along `+z` — loopy local motion (every loop passes the places of the
/// previous one) combined with exploration along the axis (thesis §6.5.1, the spiral, when
/// the camera flies through a tunnel around the axis).
pub fn helix(radius: f64, n_per_loop: usize, loops: usize, rise_per_loop: f64) -> Vec<Se3> {
    coil(radius, n_per_loop, loops, rise_per_loop, true)
}

/// A flight over a sphere of radius `radius` at `altitude` above its surface, `n` poses on a
/// spherical spiral from near the south pole to near the north pole with `turns` revolutions,
/// the camera looking straight down (at the centre) with image-up along the direction of
/// flight (thesis §5.4, Figure 5.6). Neighbouring turns overlap, which gives loop closures.
pub fn sphere_flight(radius: f64, altitude: f64, n: usize, turns: f64) -> Vec<Se3> {
    let r = radius + altitude;
    let margin = 0.15;
    let position = |t: f64| {
        let polar = margin + (std::f64::consts::PI - 2.0 * margin) * t; // from the south-ish pole
        let azimuth = TAU * turns * t;
        let (sp, cp) = polar.sin_cos();
        Vector3::new(r * sp * azimuth.cos(), r * sp * azimuth.sin(), -r * cp)
    };
    (0..n)
        .map(|k| {
            let t = k as f64 / (n.max(2) - 1) as f64;
            let p = position(t);
            let dt = 1e-4;
            let ahead = position((t + dt).min(1.0)) - position((t - dt).max(0.0));
            let down = -p.normalize();
            // Image-up along the direction of flight projected onto the tangent plane.
            let heading = ahead - down * ahead.dot(&down);
            pose_looking(&p, &down, &heading)
        })
        .collect()
}

/// The yaw (radians) turned in a `forward_turn` of a quarter circle.
pub const QUARTER_TURN: f64 = FRAC_PI_2;

/// Camera centre of a `camera_from_world` pose: `−Rᵀt`.
pub fn centre(camera_from_world: &Se3) -> Vector3<f64> {
    camera_from_world.inverse().translation().to_owned()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn optical_axis(t: &Se3) -> Vector3<f64> {
        t.rotation().inverse().act(&Vector3::z())
    }

    #[test]
    fn sideways_starts_at_the_identity_and_moves_along_x() {
        let poses = sideways(1.0, 36);
        assert_eq!(poses.len(), 37);
        assert!((poses[0].matrix() - Se3::identity().matrix()).amax() < 1e-12);
        assert!((centre(&poses[36]) - Vector3::new(1.0, 0.0, 0.0)).norm() < 1e-12);
        assert!((optical_axis(&poses[36]) - Vector3::z()).norm() < 1e-12);
    }

    #[test]
    fn rotation_and_turn_reach_their_angles() {
        let poses = sideways_with_rotation(1.0, 30f64.to_radians(), 8);
        let a = optical_axis(&poses[8]);
        assert!((a.dot(&Vector3::z()).acos() - 30f64.to_radians()).abs() < 1e-9);
        let turn = forward_turn(1.0, QUARTER_TURN, 10);
        assert!((optical_axis(&turn[10]) - Vector3::x()).norm() < 1e-9);
        assert!((centre(&turn[10]) - Vector3::new(1.0, 0.0, 1.0)).norm() < 1e-9);
    }

    #[test]
    fn circle_looks_outwards_and_closes() {
        let poses = circle(10.0, 720, 1, true);
        for (k, t) in poses.iter().enumerate().step_by(90) {
            let c = centre(t);
            assert!((c.norm() - 10.0).abs() < 1e-9);
            assert!((optical_axis(t) - c / 10.0).norm() < 1e-9, "pose {k}");
            // Image up is world up.
            assert!((t.rotation().inverse().act(&-Vector3::y()) - Vector3::z()).norm() < 1e-9);
        }
        let twice = circle(10.0, 100, 2, false);
        assert_eq!(twice.len(), 200);
        assert!((twice[0].matrix() - twice[100].matrix()).amax() < 1e-9);
    }

    #[test]
    fn helix_rises_by_one_step_per_loop_and_looks_outwards() {
        let poses = helix(0.5, 50, 3, 1.5);
        assert_eq!(poses.len(), 150);
        for (k, t) in poses.iter().enumerate() {
            let c = centre(t);
            let horizontal = Vector3::new(c.x, c.y, 0.0);
            assert!((horizontal.norm() - 0.5).abs() < 1e-9);
            assert!((c.z - 1.5 * k as f64 / 50.0).abs() < 1e-9);
            assert!(
                (optical_axis(t) - horizontal / 0.5).norm() < 1e-9,
                "pose {k}"
            );
        }
        // One loop later: the same view, 1.5 m higher.
        let (a, b) = (centre(&poses[7]), centre(&poses[57]));
        assert!((b - a - Vector3::new(0.0, 0.0, 1.5)).norm() < 1e-9);
    }

    #[test]
    fn sphere_flight_looks_down_at_constant_altitude() {
        let poses = sphere_flight(10.0, 2.0, 500, 5.0);
        for t in &poses {
            let c = centre(t);
            assert!((c.norm() - 12.0).abs() < 1e-9);
            assert!((optical_axis(t) + c.normalize()).norm() < 1e-9);
        }
    }

    #[test]
    fn spiral_advances_while_looping() {
        let poses = spiral(500, 2.0, 5.0, 3.0);
        let first = centre(&poses[0]);
        let last = centre(&poses[499]);
        assert!(last.x - first.x > 10.0);
        for t in &poses {
            assert!(centre(t).z.abs() < 1e-12);
        }
    }
}
