//! Camera trajectories as continuous functions of time, seeded: hand-held browsing of the room
//! with repeated revisits, a walk around the building's corridor loop, laps of the courtyard, a
//! drive through the town ([`drive`]).
//!
//! Every path gives `world_from_camera(t)` for any `t ≥ 0` (the camera frame: x right, y down,
//! z forward), so frames at any rate, and sub-frame poses for motion blur, come from the same
//! curve; a path never depends on how many frames are rendered.
//!
//! Motions are built from a smooth "intent" (waypoints of position and gaze target joined by
//! cubic Hermite segments with Catmull-Rom tangents, C¹) plus the small high-frequency motions
//! of a hand or a walking head (sums of sinusoids of seeded phase: shake, step bob, sway).

mod drive;

pub use drive::{TOWN_ROUTE, TownDrive};

use super::RenderError;
use super::procedural::{hash1, range, unit};
use super::worlds::{BUILDING_LOOP, COURTYARD_HALF_SIZE};
use crate::trajectory::pose_looking;
use lie::{LieGroup, Se3, So3};
use nalgebra::Vector3;
use std::f64::consts::{PI, TAU};

/// A camera trajectory.
pub trait CameraPath: Send + Sync {
    /// The camera pose at time `t` (seconds from the start), `world_from_camera`.
    fn world_from_camera(&self, t: f64) -> Se3;

    /// The natural length of the path in seconds (one pass of its loop or its browsing
    /// programme); paths continue beyond it.
    fn duration(&self) -> f64;
}

/// Cubic Hermite interpolation through `(times[i], values[i])` with Catmull-Rom tangents
/// `m_i = (p_{i+1} − p_{i−1})/(t_{i+1} − t_{i−1})` (one-sided at the ends); clamped outside.
#[derive(Debug, Clone, PartialEq)]
pub struct Spline {
    times: Vec<f64>,
    values: Vec<Vector3<f64>>,
}

impl Spline {
    /// A spline through the given knots (times strictly increasing, at least two).
    pub fn new(times: Vec<f64>, values: Vec<Vector3<f64>>) -> Self {
        assert!(times.len() >= 2 && times.len() == values.len());
        debug_assert!(times.windows(2).all(|w| w[1] > w[0]));
        Spline { times, values }
    }

    fn tangent(&self, i: usize) -> Vector3<f64> {
        let n = self.times.len();
        let (a, b) = (i.saturating_sub(1), (i + 1).min(n - 1));
        (self.values[b] - self.values[a]) / (self.times[b] - self.times[a])
    }

    /// The value at `t`.
    pub fn at(&self, t: f64) -> Vector3<f64> {
        let n = self.times.len();
        if t <= self.times[0] {
            return self.values[0];
        }
        if t >= self.times[n - 1] {
            return self.values[n - 1];
        }
        let i = self.times.partition_point(|&x| x <= t) - 1;
        let (t0, t1) = (self.times[i], self.times[i + 1]);
        let h = t1 - t0;
        let u = (t - t0) / h;
        let (u2, u3) = (u * u, u * u * u);
        let h00 = 2.0 * u3 - 3.0 * u2 + 1.0;
        let h10 = u3 - 2.0 * u2 + u;
        let h01 = -2.0 * u3 + 3.0 * u2;
        let h11 = u3 - u2;
        self.values[i] * h00
            + self.tangent(i) * (h10 * h)
            + self.values[i + 1] * h01
            + self.tangent(i + 1) * (h11 * h)
    }
}

/// A sum of three sinusoids per axis with seeded phases: `Σ_k a_k sin(2π f_k t + φ_k)`.
#[derive(Debug, Clone, PartialEq)]
struct Wobble {
    amplitude: [f64; 3],
    frequency: [f64; 3],
    phase: [[f64; 3]; 3],
}

impl Wobble {
    fn new(seed: u64, amplitude: [f64; 3], frequency: [f64; 3]) -> Self {
        let mut phase = [[0.0; 3]; 3];
        for (i, p) in phase.iter_mut().enumerate() {
            for (k, x) in p.iter_mut().enumerate() {
                *x = TAU * unit(hash1(seed, (i * 3 + k) as u64));
            }
        }
        Wobble {
            amplitude,
            frequency,
            phase,
        }
    }

    fn at(&self, t: f64) -> Vector3<f64> {
        let mut v = Vector3::zeros();
        for axis in 0..3 {
            for k in 0..3 {
                v[axis] +=
                    self.amplitude[k] * (TAU * self.frequency[k] * t + self.phase[axis][k]).sin();
            }
        }
        v
    }
}

fn look(position: &Vector3<f64>, forward: &Vector3<f64>, roll: f64, shake: &Vector3<f64>) -> Se3 {
    let camera_from_world = pose_looking(position, forward, &Vector3::z());
    // Roll about the optical axis and a small shake rotation, in the camera frame.
    let r = So3::exp(&(Vector3::new(0.0, 0.0, roll) + shake));
    let world_from_camera = camera_from_world.inverse();
    world_from_camera.compose(&Se3::from_rotation(r))
}

/// Hand-held browsing of the room (30 Hz in the sequences): the camera moves around the table
/// between twelve viewpoints, each looking at something (the bookshelf, the sofa, the desk,
/// the door, the table top…), lap after lap around the room, alternating the direction of
/// successive laps and sometimes turning back to the previous view, so every view is revisited
/// many times from slightly different positions; about 0.4 m/s and 40°/s, with a hand's shake
/// (3 mm, 0.3°) and a slow roll (±4°). The gaze is interpolated in yaw and pitch (unwrapped), so
/// it turns the short way between views.
///
/// Every visit of a view moves its position by up to [`ROOM_POSITION_JITTER`] (±0.15 m across,
/// ±0.09 m in height) and its gaze target by up to [`ROOM_GAZE_JITTER`] (±0.25 m, ±0.15 m):
/// about one radius of the live system's keyframe coverage (parallax 0.1 of a ~1.8 m depth,
/// 10° of rotation), so each lap brings new views and a map keeps growing. With
/// [`RoomBrowse::with_revisit_jitter`] that variation is scaled: at 0.25 every visit returns
/// to nearly the same view, the browsing a map should saturate on (thesis §6.5.2: revisits
/// reuse keyframes).
#[derive(Debug, Clone, PartialEq)]
pub struct RoomBrowse {
    position: Spline,
    /// `(yaw, pitch, 0)` of the gaze.
    gaze: Spline,
    shake_t: Wobble,
    shake_r: Wobble,
    roll: Wobble,
    duration: f64,
}

/// The room's viewpoints: camera position and gaze target (m, room frame), in order around the
/// table.
pub const ROOM_VIEWS: [([f64; 3], [f64; 3]); 12] = [
    ([1.6, 2.5, 1.5], [0.3, 2.4, 1.1]),
    ([1.6, 1.5, 1.6], [0.2, 1.0, 1.3]),
    ([2.1, 1.2, 1.5], [2.0, 0.0, 1.1]),
    ([3.1, 1.25, 1.7], [3.0, 2.5, 0.8]),
    ([3.4, 1.7, 1.6], [3.7, 0.0, 1.3]),
    ([4.5, 1.4, 1.5], [6.0, 1.0, 1.3]),
    ([4.6, 2.5, 1.5], [6.0, 2.5, 1.1]),
    ([4.5, 3.6, 1.6], [6.0, 4.3, 1.2]),
    ([4.0, 3.9, 1.5], [5.1, 5.0, 1.2]),
    ([3.0, 3.7, 1.65], [2.6, 5.0, 1.1]),
    ([1.7, 3.8, 1.5], [0.6, 4.6, 0.9]),
    ([1.5, 3.1, 1.7], [3.0, 2.5, 0.8]),
];

/// Half-width (m) of a visit's variation of the camera position across (x, y); 0.6 of it in
/// height (a hand returns to a view within a step).
pub const ROOM_POSITION_JITTER: f64 = 0.15;

/// Half-width (m) of a visit's variation of the gaze target across (x, y); 0.6 of it in height
/// (a glance settles on the same object, not the same point of it).
pub const ROOM_GAZE_JITTER: f64 = 0.25;

impl RoomBrowse {
    /// The browsing path of `seed`, planned for `duration` seconds (it holds still beyond).
    pub fn new(seed: u64, duration: f64) -> Self {
        Self::plan(seed, duration, 1.0)
    }

    /// The browsing path of `seed` with each visit's variation of position and gaze target
    /// scaled by `revisit_jitter` (finite, ≥ 0): 1 is [`RoomBrowse::new`]'s path bit for bit, 0
    /// returns to exactly the same views ([`ROOM_VIEWS`]), 0.25 within a quarter of the default
    /// variation. The programme (order of the views, look-backs, pauses), the hand's shake and
    /// the roll are the same at any scale; only the time between views follows the distances.
    pub fn with_revisit_jitter(
        seed: u64,
        duration: f64,
        revisit_jitter: f64,
    ) -> Result<Self, RenderError> {
        if !(revisit_jitter.is_finite() && revisit_jitter >= 0.0) {
            return Err(RenderError::InvalidParameter {
                name: "revisit_jitter",
                reason: format!("must be finite and at least 0, got {revisit_jitter}"),
            });
        }
        Ok(Self::plan(seed, duration, revisit_jitter))
    }

    fn plan(seed: u64, duration: f64, revisit_jitter: f64) -> Self {
        let speed = 0.4;
        let turn_rate = 40f64.to_radians();
        let n = ROOM_VIEWS.len();
        let jitter = |h: u64, s: f64| {
            Vector3::new(
                range(hash1(h, 1), -s, s),
                range(hash1(h, 2), -s, s),
                range(hash1(h, 3), -0.6 * s, 0.6 * s),
            )
        };
        // A view: position and (yaw, pitch) of the gaze.
        let view = |i: usize, h: u64| {
            let (p, q) = ROOM_VIEWS[i];
            let p =
                Vector3::new(p[0], p[1], p[2]) + jitter(h, ROOM_POSITION_JITTER * revisit_jitter);
            let q = Vector3::new(q[0], q[1], q[2])
                + jitter(hash1(h, 9), ROOM_GAZE_JITTER * revisit_jitter);
            let d = q - p;
            (p, d.y.atan2(d.x), d.z.atan2(d.x.hypot(d.y)))
        };
        let (p0, yaw0, pitch0) = view(0, hash1(seed, 0));
        let mut times = vec![0.0];
        let mut positions = vec![p0];
        let mut gazes = vec![Vector3::new(yaw0, pitch0, 0.0)];
        // The programme: laps around the ring of views, alternating direction; after a view,
        // sometimes a look back at the previous one and a return.
        let mut order = Vec::new();
        let (mut i, mut dir, mut k) = (0usize, 1i64, 1u64);
        let mut t_est = 0.0;
        while t_est < duration + 30.0 {
            for _ in 0..n {
                let prev = i;
                i = (i as i64 + dir).rem_euclid(n as i64) as usize;
                order.push(i);
                if unit(hash1(seed, 1 << 20 | k)) < 0.15 {
                    order.push(prev);
                    order.push(i);
                }
                k += 1;
                t_est += 3.0;
            }
            dir = -dir;
        }
        let mut t = 0.0;
        for (k, &i) in order.iter().enumerate() {
            let h = hash1(seed, k as u64 + 1);
            let (p, yaw, pitch) = view(i, h);
            let (lp, lg) = (positions[positions.len() - 1], gazes[gazes.len() - 1]);
            // Unwrap the yaw to turn the short way.
            let yaw = lg.x + (yaw - lg.x + PI).rem_euclid(TAU) - PI;
            let angle = (yaw - lg.x).abs().max((pitch - lg.y).abs());
            let dt =
                ((p - lp).norm() / speed).max(angle / turn_rate) + range(hash1(h, 21), 0.2, 0.8);
            t += dt;
            times.push(t);
            positions.push(p);
            gazes.push(Vector3::new(yaw, pitch, 0.0));
            if t > duration + 5.0 {
                break;
            }
        }
        RoomBrowse {
            position: Spline::new(times.clone(), positions),
            gaze: Spline::new(times, gazes),
            shake_t: Wobble::new(
                hash1(seed, 1 << 40),
                [0.002, 0.0012, 0.0006],
                [0.7, 1.9, 4.3],
            ),
            shake_r: Wobble::new(
                hash1(seed, 2 << 40),
                [0.003, 0.0015, 0.0008],
                [0.5, 1.7, 3.9],
            ),
            roll: Wobble::new(hash1(seed, 3 << 40), [0.05, 0.02, 0.0], [0.05, 0.17, 1.0]),
            duration,
        }
    }
}

impl CameraPath for RoomBrowse {
    fn world_from_camera(&self, t: f64) -> Se3 {
        let p = self.position.at(t) + self.shake_t.at(t);
        let g = self.gaze.at(t);
        let forward = Vector3::new(g.y.cos() * g.x.cos(), g.y.cos() * g.x.sin(), g.y.sin());
        look(&p, &forward, self.roll.at(t).x, &self.shake_r.at(t))
    }

    fn duration(&self) -> f64 {
        self.duration
    }
}

/// A point on a rounded rectangle `[x0, y0, x1, y1]` with corner radius `r`, by arc length `s`
/// (counter-clockwise from the middle of the bottom side, heading `+x`); returns the point and
/// the unit tangent. Periodic in `s`.
fn rounded_rectangle(rect: [f64; 4], r: f64, s: f64) -> (Vector3<f64>, Vector3<f64>) {
    let [x0, y0, x1, y1] = rect;
    let (w, h) = (x1 - x0 - 2.0 * r, y1 - y0 - 2.0 * r);
    let arc = 0.5 * PI * r;
    let total = 2.0 * (w + h) + 4.0 * arc;
    let mut s = (s + 0.5 * w).rem_euclid(total);
    // Straights and arcs in order: bottom (+x), corner, right (+y), corner, top (−x), corner,
    // left (−y), corner.
    let sides = [
        (
            Vector3::new(x0 + r, y0, 0.0),
            Vector3::x(),
            w,
            Vector3::new(x1 - r, y0 + r, 0.0),
        ),
        (
            Vector3::new(x1, y0 + r, 0.0),
            Vector3::y(),
            h,
            Vector3::new(x1 - r, y1 - r, 0.0),
        ),
        (
            Vector3::new(x1 - r, y1, 0.0),
            -Vector3::x(),
            w,
            Vector3::new(x0 + r, y1 - r, 0.0),
        ),
        (
            Vector3::new(x0, y1 - r, 0.0),
            -Vector3::y(),
            h,
            Vector3::new(x0 + r, y0 + r, 0.0),
        ),
    ];
    for (k, (start, dir, len, centre)) in sides.iter().enumerate() {
        if s <= *len {
            return (start + dir * s, *dir);
        }
        s -= len;
        if s <= arc {
            // Arc about `centre` from angle a0 turning left.
            let a0 = -0.5 * PI + 0.5 * PI * k as f64;
            let a = a0 + s / r;
            let p = centre + Vector3::new(a.cos(), a.sin(), 0.0) * r;
            return (p, Vector3::new(-a.sin(), a.cos(), 0.0));
        }
        s -= arc;
    }
    (sides[0].0, Vector3::x())
}

/// Length of [`rounded_rectangle`]'s loop.
fn rounded_length(rect: [f64; 4], r: f64) -> f64 {
    2.0 * ((rect[2] - rect[0] - 2.0 * r) + (rect[3] - rect[1] - 2.0 * r)) + TAU * r
}

/// A walk (15 Hz in the sequences) once around the building's corridor loop (about 210 m at
/// 1.3 m/s, counter-clockwise, starting and ending mid-way along the south corridor), and on;
/// looking ahead along the corridor with glances left and right (±20°), a sway of ±0.2 m
/// across the corridor, and the head's bob at the step frequency (1.8 Hz, ±2 cm).
#[derive(Debug, Clone, PartialEq)]
pub struct BuildingWalk {
    seed: u64,
    speed: f64,
    sway: Wobble,
    glance: Wobble,
    bob_phase: f64,
}

const WALK_CORNER_RADIUS: f64 = 1.2;
const WALK_START: f64 = 12.0;

impl BuildingWalk {
    /// The walk of `seed`.
    pub fn new(seed: u64) -> Self {
        BuildingWalk {
            seed,
            speed: 1.3,
            sway: Wobble::new(hash1(seed, 1), [0.12, 0.05, 0.02], [0.03, 0.11, 0.9]),
            glance: Wobble::new(hash1(seed, 2), [0.22, 0.08, 0.02], [0.021, 0.07, 0.4]),
            bob_phase: TAU * unit(hash1(seed, 3)),
        }
    }

    /// Length of the loop (m).
    pub fn loop_length() -> f64 {
        rounded_length(BUILDING_LOOP, WALK_CORNER_RADIUS)
    }
}

impl CameraPath for BuildingWalk {
    fn world_from_camera(&self, t: f64) -> Se3 {
        let _ = self.seed;
        let s = WALK_START + self.speed * t;
        let (c, tangent) = rounded_rectangle(BUILDING_LOOP, WALK_CORNER_RADIUS, s);
        let left = Vector3::z().cross(&tangent);
        let sway = self.sway.at(t);
        let bob = 0.02 * (TAU * 1.8 * t + self.bob_phase).sin();
        let p = c + left * sway.x + Vector3::new(0.0, 0.0, 1.6 + bob);
        // Gaze: the corridor 3 m ahead, turned by the glance.
        let (ahead, _) = rounded_rectangle(BUILDING_LOOP, WALK_CORNER_RADIUS, s + 3.0);
        let mut forward = ahead + Vector3::new(0.0, 0.0, 1.45) - p;
        forward = So3::rot_z(self.glance.at(t).x).act(&forward);
        let shake = Vector3::new(0.01 * (TAU * 1.8 * t + self.bob_phase).cos(), 0.0, 0.0);
        look(&p, &forward, 0.02 * self.glance.at(t).y, &shake)
    }

    fn duration(&self) -> f64 {
        Self::loop_length() / self.speed
    }
}

/// Laps of the courtyard (20 Hz in the sequences) on a rounded square 9 m inside the façades
/// (about 81 m per lap at 1.4 m/s, counter-clockwise), each lap shifted across the path by up to
/// ±1 m and looking outwards towards the façades by 15–40°, varying from lap to lap, so that
/// every lap revisits the places of the others from other viewpoints.
#[derive(Debug, Clone, PartialEq)]
pub struct CourtyardLaps {
    speed: f64,
    offset: Wobble,
    yaw: Wobble,
    bob_phase: f64,
}

const LAP_RECT: [f64; 4] = [
    -COURTYARD_HALF_SIZE + 9.0,
    -COURTYARD_HALF_SIZE + 9.0,
    COURTYARD_HALF_SIZE - 9.0,
    COURTYARD_HALF_SIZE - 9.0,
];
const LAP_CORNER_RADIUS: f64 = 4.0;

impl CourtyardLaps {
    /// The laps of `seed`.
    pub fn new(seed: u64) -> Self {
        let lap = Self::lap_length() / 1.4;
        CourtyardLaps {
            speed: 1.4,
            offset: Wobble::new(
                hash1(seed, 1),
                [0.6, 0.3, 0.02],
                [0.7 / lap, 2.3 / lap, 0.9],
            ),
            yaw: Wobble::new(
                hash1(seed, 2),
                [0.12, 0.06, 0.02],
                [0.9 / lap, 3.1 / lap, 0.3],
            ),
            bob_phase: TAU * unit(hash1(seed, 3)),
        }
    }

    /// Length of one lap (m).
    pub fn lap_length() -> f64 {
        rounded_length(LAP_RECT, LAP_CORNER_RADIUS)
    }
}

impl CameraPath for CourtyardLaps {
    fn world_from_camera(&self, t: f64) -> Se3 {
        let s = self.speed * t;
        let (c, tangent) = rounded_rectangle(LAP_RECT, LAP_CORNER_RADIUS, s);
        let right = tangent.cross(&Vector3::z());
        let off = self.offset.at(t);
        let bob = 0.02 * (TAU * 1.8 * t + self.bob_phase).sin();
        let p = c + right * off.x + Vector3::new(0.0, 0.0, 1.6 + bob);
        // Outwards (to the right of the walking direction) by 15–40°, slightly up.
        let yaw = -(27.5f64.to_radians() + self.yaw.at(t).x);
        let mut forward = So3::rot_z(yaw).act(&tangent);
        forward.z = 0.05;
        look(&p, &forward, 0.015 * self.yaw.at(t).y, &Vector3::zeros())
    }

    fn duration(&self) -> f64 {
        Self::lap_length() / self.speed
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn speeds(path: &dyn CameraPath, rate: f64, n: usize) -> (f64, f64) {
        let mut max_v: f64 = 0.0;
        let mut max_w: f64 = 0.0;
        for k in 0..n {
            let (a, b) = (
                path.world_from_camera(k as f64 / rate),
                path.world_from_camera((k + 1) as f64 / rate),
            );
            let d = a.inverse().compose(&b);
            max_v = max_v.max(d.translation().norm() * rate);
            max_w = max_w.max(d.rotation().angle() * rate);
        }
        (max_v, max_w)
    }

    #[test]
    fn spline_interpolates_its_knots_smoothly() {
        let s = Spline::new(
            vec![0.0, 1.0, 3.0],
            vec![Vector3::zeros(), Vector3::x(), Vector3::new(1.0, 2.0, 0.0)],
        );
        assert_eq!(s.at(1.0), Vector3::x());
        assert_eq!(s.at(-1.0), Vector3::zeros());
        // C¹: equal one-sided derivatives at the inner knot.
        let h = 1e-6;
        let l = (s.at(1.0) - s.at(1.0 - h)) / h;
        let r = (s.at(1.0 + h) - s.at(1.0)) / h;
        assert!((l - r).norm() < 1e-4);
    }

    #[test]
    fn rounded_rectangle_is_continuous_and_closes() {
        let rect = [0.0, 0.0, 10.0, 6.0];
        let len = rounded_length(rect, 1.0);
        let n = 2000;
        for k in 0..n {
            let s = len * k as f64 / n as f64;
            let (a, ta) = rounded_rectangle(rect, 1.0, s);
            let (b, tb) = rounded_rectangle(rect, 1.0, s + len / n as f64);
            assert!((a - b).norm() < 1.01 * len / n as f64, "{s}");
            assert!((ta - tb).norm() < 1.5 * len / n as f64, "{s}");
        }
        let (a, _) = rounded_rectangle(rect, 1.0, 0.3);
        let (b, _) = rounded_rectangle(rect, 1.0, 0.3 + len);
        assert!((a - b).norm() < 1e-9);
    }

    #[test]
    fn paths_move_at_realistic_speeds() {
        let room = RoomBrowse::new(3, 100.0);
        let (v, w) = speeds(&room, 30.0, 3000);
        assert!(v < 1.0 && w < 2.0, "room {v} m/s {w} rad/s");
        let walk = BuildingWalk::new(3);
        let (v, w) = speeds(&walk, 15.0, 2000);
        assert!(v < 2.0 && v > 1.0 && w < 2.0, "walk {v} m/s {w} rad/s");
        assert!(BuildingWalk::loop_length() > 200.0);
        let laps = CourtyardLaps::new(3);
        let (v, w) = speeds(&laps, 20.0, 2000);
        assert!(v < 2.0 && v > 1.0 && w < 1.5, "laps {v} m/s {w} rad/s");
        // The walk comes back to its start after one loop.
        let d = walk.duration();
        let (a, b) = (walk.world_from_camera(0.0), walk.world_from_camera(d));
        assert!((a.translation() - b.translation()).norm() < 0.8);
    }

    #[test]
    fn room_browsing_stays_inside_and_revisits_views() {
        let room = RoomBrowse::new(5, 100.0);
        // Visits: entries into a 0.45 m ball around each viewpoint.
        let mut visits = [0usize; ROOM_VIEWS.len()];
        let mut inside = [false; ROOM_VIEWS.len()];
        for k in 0..3000 {
            let t = k as f64 / 30.0;
            let p = *room.world_from_camera(t).translation();
            assert!(
                p.x > 0.8 && p.x < 5.2 && p.y > 0.8 && p.y < 4.2 && p.z > 1.1 && p.z < 2.0,
                "{p:?} at {t}"
            );
            for (i, (v, _)) in ROOM_VIEWS.iter().enumerate() {
                let near = (p - Vector3::new(v[0], v[1], v[2])).norm() < 0.45;
                if near && !inside[i] {
                    visits[i] += 1;
                }
                inside[i] = near;
            }
        }
        assert!(visits.iter().all(|&c| c >= 2), "{visits:?}");
    }

    #[test]
    fn revisit_jitter_one_is_the_default_path() {
        // Poses of `RoomBrowse::new` as it was before the revisit jitter was scalable (commit
        // 6441e3e): seed, planned duration, frame at 30 Hz, translation, quaternion (i, j, k, w).
        let before: [(u64, f64, usize, [f64; 7]); 5] = [
            (
                1,
                200.0,
                0,
                [
                    1.698392327783656,
                    2.5584916805715245,
                    1.4135946651221998,
                    -0.514209961582275,
                    -0.6039425769817462,
                    0.46853262269285634,
                    0.3889969930356227,
                ],
            ),
            (
                1,
                200.0,
                1234,
                [
                    1.5321958127017352,
                    3.767707769510851,
                    1.505751438733751,
                    -0.8098139973851268,
                    -0.25859767179539506,
                    0.16028822502015275,
                    0.5016335502147078,
                ],
            ),
            (
                1,
                200.0,
                5999,
                [
                    3.7577599584337285,
                    3.923567949217996,
                    1.4348977674688799,
                    -0.6840946054190467,
                    0.26020695136924943,
                    -0.23343197391489587,
                    0.6401690611470343,
                ],
            ),
            (
                5,
                100.0,
                2999,
                [
                    2.7751619975933126,
                    1.1310484293246168,
                    1.6505078031345868,
                    -0.7866563148350644,
                    -0.3219873119919513,
                    0.23005134563123023,
                    0.4738906958567282,
                ],
            ),
            (
                3,
                400.0,
                11000,
                [
                    2.8639433049411047,
                    3.576665847618105,
                    1.5728108364959483,
                    -0.7792703158194604,
                    -0.18305374353918252,
                    0.1541540326889556,
                    0.5791939537535437,
                ],
            ),
        ];
        for (seed, duration, k, want) in before {
            let pose = RoomBrowse::with_revisit_jitter(seed, duration, 1.0)
                .unwrap()
                .world_from_camera(k as f64 / 30.0);
            let (t, q) = (pose.translation(), pose.rotation().unit_quaternion());
            let got = [t.x, t.y, t.z, q.i, q.j, q.k, q.w];
            // 1e-12: the same plan to rounding (a changed plan moves a view by millimetres).
            for (g, w) in got.iter().zip(&want) {
                assert!(
                    (g - w).abs() < 1e-12,
                    "seed {seed} frame {k}: {got:?} vs {want:?}"
                );
            }
        }
        // And `new` is the scale of 1 bit for bit, frame after frame.
        let (a, b) = (
            RoomBrowse::new(2, 150.0),
            RoomBrowse::with_revisit_jitter(2, 150.0, 1.0).unwrap(),
        );
        assert_eq!(a, b);
        for k in 0..4500 {
            let t = k as f64 / 30.0;
            assert_eq!(a.world_from_camera(t), b.world_from_camera(t), "frame {k}");
        }
        for bad in [-0.01, f64::NAN, f64::INFINITY] {
            assert!(
                RoomBrowse::with_revisit_jitter(2, 150.0, bad).is_err(),
                "{bad}"
            );
        }
    }

    #[test]
    fn smaller_revisit_jitter_keeps_the_views_within_the_scaled_bound() {
        for scale in [0.0, 0.25, 0.5] {
            let room = RoomBrowse::with_revisit_jitter(7, 300.0, scale).unwrap();
            let (dp, dq) = (ROOM_POSITION_JITTER * scale, ROOM_GAZE_JITTER * scale);
            let (mut max_dp, mut max_gaze) = (0f64, 0f64);
            let knots = room.position.values.iter().zip(&room.gaze.values);
            assert!(knots.len() > 60, "{} visits", knots.len());
            for (p, g) in knots {
                // The visited view: the nearest (views are ≥ 0.5 m apart, visits within 0.12 m).
                let (v, q) = ROOM_VIEWS
                    .iter()
                    .map(|(v, q)| (Vector3::from(*v), Vector3::from(*q)))
                    .min_by(|a, b| (a.0 - p).norm().total_cmp(&(b.0 - p).norm()))
                    .unwrap();
                let d = p - v;
                assert!(
                    d.x.abs() <= dp + 1e-12 && d.y.abs() <= dp + 1e-12,
                    "scale {scale}: {d:?}"
                );
                assert!(d.z.abs() <= 0.6 * dp + 1e-12, "scale {scale}: {d:?}");
                max_dp = max_dp.max(d.x.abs()).max(d.y.abs());
                // The gaze ray from the visit's position passes the view's target within the
                // target's variation (the ray goes through the varied target).
                let forward = Vector3::new(g.y.cos() * g.x.cos(), g.y.cos() * g.x.sin(), g.y.sin());
                let off = (q - p) - forward * (q - p).dot(&forward);
                let bound = dq * (2.0f64 + 0.36).sqrt();
                assert!(
                    off.norm() <= bound + 1e-9,
                    "scale {scale}: gaze {}",
                    off.norm()
                );
                max_gaze = max_gaze.max(off.norm());
            }
            // The visits still vary (the bound is used, not collapsed) unless the scale is 0.
            if scale > 0.0 {
                assert!(max_dp > 0.8 * dp, "scale {scale}: {max_dp} of {dp}");
                assert!(max_gaze > 0.3 * dq, "scale {scale}: {max_gaze} of {dq}");
            } else {
                assert!(max_dp == 0.0 && max_gaze < 1e-9, "{max_dp} {max_gaze}");
            }
            // The browsing stays a hand's: realistic speeds, inside the room.
            let (v, w) = speeds(&room, 30.0, 3000);
            assert!(v < 1.0 && w < 2.0, "scale {scale}: {v} m/s {w} rad/s");
        }
    }
}
