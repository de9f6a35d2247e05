//! A drive through the town: a car-mounted forward camera (KITTI's: 1.65 m above the road,
//! level) on the right-hand lane of [`TOWN_ROUTE`], 1.74 km with two loops.
//!
//! The route starts eastwards on the southern street, drives the loop of the two south-western
//! blocks counter-clockwise and comes back onto its first street (loop one, closed in the
//! direction it was first driven); goes on east, north up the eastern street, west and then
//! south down the middle street it drove north on in the first loop — the other way, in the
//! other lane — and turns east onto the southern street again (loop two, closed where the drive
//! went east before). Every junction is a left turn on a curve of 11 m radius.
//!
//! Speed: 38–49 km/h on each straight (drawn from the seed), slowing with a comfortable
//! 1 m/s² to 25 km/h for each turn, as a driver in a town does (a 90° turn of 11 m taken at
//! 30 km/h would ask for 0.6 g). The car wanders in its lane by a few decimetres, and the body
//! pitches, rolls and bobs on its suspension by fractions of a degree and a centimetre.

use super::{CameraPath, Wobble, look};
use crate::render::procedural::{hash1, range};
use crate::render::worlds::TOWN_LANE_OFFSET;
use lie::Se3;
use nalgebra::{Vector2, Vector3};

/// The route: junctions of the street grid (centrelines, m) in driving order.
pub const TOWN_ROUTE: [[f64; 2]; 10] = [
    [20.0, 0.0],
    [220.0, 0.0],
    [220.0, 160.0],
    [0.0, 160.0],
    [0.0, 0.0],
    [330.0, 0.0],
    [330.0, 240.0],
    [220.0, 240.0],
    [220.0, 0.0],
    [300.0, 0.0],
];
/// Radius of the turns, on the lane's centre (m).
const TURN_RADIUS: f64 = 11.0;
/// Speed through the turns (m/s): 25 km/h.
const TURN_SPEED: f64 = 25.0 / 3.6;
/// Speeds on the straights (m/s): 38–49 km/h.
const STRAIGHT_SPEED: (f64, f64) = (10.5, 13.5);
/// Distance over which the car slows for a turn and speeds up after it (m): 1 m/s² from
/// 13.5 to 7 m/s takes 67 m, from 10.5 m/s 31 m; 45 m is between.
const RAMP: f64 = 45.0;
/// The camera's height above the road (m), KITTI's.
const CAMERA_HEIGHT: f64 = 1.65;
/// Step of the tabulated distance along the route over time (s).
const STEP: f64 = 0.01;

/// A piece of the lane's centre: a straight or a circular arc.
#[derive(Debug, Clone, PartialEq)]
enum Piece {
    Line {
        start: Vector2<f64>,
        dir: Vector2<f64>,
        length: f64,
        speed: f64,
    },
    Arc {
        centre: Vector2<f64>,
        radius: f64,
        start: f64,
        sweep: f64,
    },
}

impl Piece {
    fn length(&self) -> f64 {
        match self {
            Piece::Line { length, .. } => *length,
            Piece::Arc { radius, sweep, .. } => radius * sweep.abs(),
        }
    }

    /// Position and unit tangent `u` metres into the piece.
    fn at(&self, u: f64) -> (Vector2<f64>, Vector2<f64>) {
        match self {
            Piece::Line { start, dir, .. } => (start + dir * u, *dir),
            Piece::Arc {
                centre,
                radius,
                start,
                sweep,
            } => {
                let a = start + sweep.signum() * u / radius;
                let (s, c) = a.sin_cos();
                (
                    centre + Vector2::new(c, s) * *radius,
                    Vector2::new(-s, c) * sweep.signum(),
                )
            }
        }
    }

    /// The car's speed `u` metres into the piece.
    fn speed(&self, u: f64) -> f64 {
        match self {
            Piece::Arc { .. } => TURN_SPEED,
            Piece::Line { length, speed, .. } => {
                let x = (u.min(length - u) / RAMP).clamp(0.0, 1.0);
                TURN_SPEED + (speed - TURN_SPEED) * x * x * (3.0 - 2.0 * x)
            }
        }
    }
}

/// The drive of `seed` through the town (see the module notes).
#[derive(Debug, Clone, PartialEq)]
pub struct TownDrive {
    pieces: Vec<Piece>,
    /// Where each piece starts along the route (m).
    starts: Vec<f64>,
    /// Distance along the route every [`STEP`] seconds.
    distance: Vec<f64>,
    lane: Wobble,
    body: Wobble,
    bob: Wobble,
}

fn right_of(d: &Vector2<f64>) -> Vector2<f64> {
    Vector2::new(d.y, -d.x)
}

fn cross(a: &Vector2<f64>, b: &Vector2<f64>) -> f64 {
    a.x * b.y - a.y * b.x
}

impl TownDrive {
    /// The drive of `seed`: the route is fixed, the speeds, the wander in the lane and the
    /// body's motion are drawn from the seed.
    pub fn new(seed: u64) -> Self {
        let points: Vec<Vector2<f64>> = TOWN_ROUTE
            .iter()
            .map(|p| Vector2::new(p[0], p[1]))
            .collect();
        let dirs: Vec<Vector2<f64>> = points
            .windows(2)
            .map(|w| (w[1] - w[0]).normalize())
            .collect();
        // The lane: each leg moved right by the lane offset; corners where the legs meet.
        let lane = |i: usize| points[i] + right_of(&dirs[i]) * TOWN_LANE_OFFSET;
        let mut corners = vec![lane(0)];
        for i in 1..dirs.len() {
            let (a, d1) = (lane(i - 1), dirs[i - 1]);
            let (b, d2) = (lane(i), dirs[i]);
            let t = cross(&(b - a), &d2) / cross(&d1, &d2);
            corners.push(a + d1 * t);
        }
        let last = dirs.len() - 1;
        corners.push(points[last + 1] + right_of(&dirs[last]) * TOWN_LANE_OFFSET);
        // Straights between the turns' tangent points, arcs in the corners.
        let mut pieces = Vec::new();
        let mut from = corners[0];
        for i in 0..dirs.len() {
            let speed = range(
                hash1(seed, 100 + i as u64),
                STRAIGHT_SPEED.0,
                STRAIGHT_SPEED.1,
            );
            let (to, arc) = if i + 1 < dirs.len() {
                let (d1, d2) = (dirs[i], dirs[i + 1]);
                let turn = cross(&d1, &d2).atan2(d1.dot(&d2));
                let tangent = TURN_RADIUS * (turn.abs() / 2.0).tan();
                let a = corners[i + 1] - d1 * tangent;
                let left = Vector2::new(-d1.y, d1.x) * turn.signum();
                let centre = a + left * TURN_RADIUS;
                let start = (a - centre).y.atan2((a - centre).x);
                let arc = Piece::Arc {
                    centre,
                    radius: TURN_RADIUS,
                    start,
                    sweep: turn,
                };
                (a, Some((arc, corners[i + 1] + d2 * tangent)))
            } else {
                (corners[i + 1], None)
            };
            pieces.push(Piece::Line {
                start: from,
                dir: dirs[i],
                length: (to - from).norm(),
                speed,
            });
            if let Some((arc, next)) = arc {
                pieces.push(arc);
                from = next;
            }
        }
        let mut starts = Vec::with_capacity(pieces.len());
        let mut total = 0.0;
        for p in &pieces {
            starts.push(total);
            total += p.length();
        }
        let mut drive = TownDrive {
            pieces,
            starts,
            distance: Vec::new(),
            lane: Wobble::new(hash1(seed, 1), [0.12, 0.06, 0.01], [0.03, 0.11, 0.9]),
            body: Wobble::new(hash1(seed, 2), [0.0025, 0.0012, 0.0006], [0.6, 1.4, 3.3]),
            bob: Wobble::new(hash1(seed, 3), [0.006, 0.003, 0.0015], [1.2, 2.3, 4.1]),
        };
        // The distance over time: ds/dt = v(s), fourth-order Runge-Kutta.
        let mut s = 0.0;
        drive.distance.push(s);
        while s < total {
            let k1 = drive.speed(s);
            let k2 = drive.speed(s + 0.5 * STEP * k1);
            let k3 = drive.speed(s + 0.5 * STEP * k2);
            let k4 = drive.speed(s + STEP * k3);
            s += STEP * (k1 + 2.0 * k2 + 2.0 * k3 + k4) / 6.0;
            drive.distance.push(s);
        }
        drive
    }

    /// Length of the route (m).
    pub fn length(&self) -> f64 {
        self.starts.last().expect("pieces") + self.pieces.last().expect("pieces").length()
    }

    /// The piece at distance `s` along the route and how far into it.
    fn piece(&self, s: f64) -> (&Piece, f64) {
        let i = self.starts.partition_point(|&x| x <= s).saturating_sub(1);
        (&self.pieces[i], s - self.starts[i])
    }

    fn speed(&self, s: f64) -> f64 {
        let (p, u) = self.piece(s.clamp(0.0, self.length()));
        p.speed(u)
    }

    /// Distance along the route at time `t` (beyond the end: on at the last speed).
    pub fn distance(&self, t: f64) -> f64 {
        let x = t.max(0.0) / STEP;
        let k = x.floor() as usize;
        if k + 1 >= self.distance.len() {
            let end = (self.distance.len() - 1) as f64 * STEP;
            let last = *self.distance.last().expect("tabulated");
            return last + self.speed(last) * (t - end);
        }
        let f = x - k as f64;
        self.distance[k] * (1.0 - f) + self.distance[k + 1] * f
    }

    /// The lane's centre and its unit direction at distance `s` (beyond the end: straight on).
    pub fn lane_at(&self, s: f64) -> (Vector2<f64>, Vector2<f64>) {
        let s = s.max(0.0);
        let (p, u) = self.piece(s);
        let (x, d) = p.at(u.min(p.length()));
        (x + d * (u - p.length()).max(0.0), d)
    }
}

impl CameraPath for TownDrive {
    fn world_from_camera(&self, t: f64) -> Se3 {
        let (c, d) = self.lane_at(self.distance(t));
        let right = right_of(&d);
        let lane = self.lane.at(t);
        let body = self.body.at(t);
        let p = c + right * lane.x;
        let position = Vector3::new(p.x, p.y, CAMERA_HEIGHT + self.bob.at(t).x);
        let forward = Vector3::new(d.x, d.y, 0.0);
        // Pitch about the camera's x axis, roll about its optical axis.
        look(&position, &forward, body.y, &Vector3::new(body.x, 0.0, 0.0))
    }

    fn duration(&self) -> f64 {
        (self.distance.len() - 1) as f64 * STEP
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::render::worlds::{TOWN_STREETS_X, TOWN_STREETS_Y};
    use lie::LieGroup;

    #[test]
    fn the_route_follows_the_streets_and_is_long_enough() {
        for p in TOWN_ROUTE {
            assert!(
                TOWN_STREETS_X.contains(&p[0]) || TOWN_STREETS_Y.contains(&p[1]),
                "{p:?}"
            );
        }
        let drive = TownDrive::new(1);
        assert!(drive.length() > 1700.0, "{}", drive.length());
        // Continuous and at car speeds: 25–49 km/h, yaw rate ≤ v/r.
        let rate = 10.0;
        let n = (drive.duration() * rate) as usize;
        let mut speeds = Vec::new();
        for k in 0..n {
            let (a, b) = (
                drive.world_from_camera(k as f64 / rate),
                drive.world_from_camera((k + 1) as f64 / rate),
            );
            let d = a.inverse().compose(&b);
            let v = d.translation().norm() * rate;
            assert!(v > 24.0 / 3.6 && v < 50.0 / 3.6, "frame {k}: {v} m/s");
            assert!(
                d.rotation().angle() * rate < 1.1 * TURN_SPEED / TURN_RADIUS,
                "frame {k}"
            );
            speeds.push(v);
        }
        // About 1.7 km in 150–200 s (1500–2000 frames at 10 Hz).
        assert!((1500..2000).contains(&n), "{n} frames");
    }

    #[test]
    fn the_drive_comes_back_to_its_streets_both_ways() {
        let drive = TownDrive::new(4);
        let rate = 10.0;
        let n = (drive.duration() * rate) as usize;
        let poses: Vec<Se3> = (0..n)
            .map(|k| drive.world_from_camera(k as f64 / rate))
            .collect();
        // For every frame, the nearest frame at least 60 s earlier: same way (within 40° of
        // heading) or the other way (within 40° of opposite).
        let (mut same, mut opposite) = (0, 0);
        for k in 600..n {
            let (ck, fk) = (
                poses[k].translation(),
                poses[k].rotation().act(&Vector3::z()),
            );
            let near = (0..k - 600)
                .filter(|&j| (poses[j].translation() - ck).norm() < 4.0)
                .map(|j| poses[j].rotation().act(&Vector3::z()).dot(&fk))
                .collect::<Vec<_>>();
            if near.iter().any(|&c| c > 0.77) {
                same += 1;
            } else if near.iter().any(|&c| c < -0.77) {
                opposite += 1;
            }
        }
        // Loop one's 220 m and loop two's 80 m back on a street the same way; 160 m the
        // other way (the lanes are 3.5 m apart).
        assert!(same > 200, "{same} frames revisit a place the same way");
        assert!(
            opposite > 100,
            "{opposite} frames revisit a place the other way"
        );
        // Different seeds: the same route at other speeds.
        let other = TownDrive::new(5);
        assert!((other.length() - drive.length()).abs() < 1e-9);
        assert!((other.duration() - drive.duration()).abs() > 0.1);
    }
}
