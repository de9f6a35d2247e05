//! Textured worlds made of planar rectangles ("quads"), with baked lighting and an optional sky.
//!
//! World frame: `x`, `y` horizontal, `z` up (metres). A [`Quad`] is the rectangle
//! `{o + s·a + t·b : 0 ≤ s ≤ w, 0 ≤ t ≤ h}` with orthonormal axes `a`, `b`; it is seen only
//! from its front side, the side of its normal `n = a × b` (closed worlds need no back faces,
//! and skipping them halves the candidates per ray).

use super::procedural::{fbm, smooth_step_aa};
use super::texture::Material;
use nalgebra::Vector3;

/// A textured planar rectangle.
#[derive(Debug, Clone, PartialEq)]
pub struct Quad {
    /// Corner at texture coordinates `(0, 0)`.
    pub origin: Vector3<f64>,
    /// Unit axis of the `s` texture coordinate.
    pub axis_s: Vector3<f64>,
    /// Unit axis of the `t` texture coordinate (orthogonal to `axis_s`).
    pub axis_t: Vector3<f64>,
    /// Extent along `axis_s` (m).
    pub width: f64,
    /// Extent along `axis_t` (m).
    pub height: f64,
    /// The surface's material.
    pub material: Material,
    /// Colour of the surface (multiplies the grey radiance per channel; luma ≈ 1).
    pub tint: [f32; 3],
}

impl Quad {
    /// The front normal `a × b`.
    pub fn normal(&self) -> Vector3<f64> {
        self.axis_s.cross(&self.axis_t)
    }

    /// The four corners in the order `(0,0), (w,0), (w,h), (0,h)`.
    pub fn corners(&self) -> [Vector3<f64>; 4] {
        let (a, b) = (self.axis_s * self.width, self.axis_t * self.height);
        [
            self.origin,
            self.origin + a,
            self.origin + a + b,
            self.origin + b,
        ]
    }

    /// The world point at texture coordinates `(s, t)`.
    pub fn point(&self, s: f64, t: f64) -> Vector3<f64> {
        self.origin + self.axis_s * s + self.axis_t * t
    }
}

/// A point light (`power / r²` falloff, Lambertian).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PointLight {
    /// Position (m).
    pub position: Vector3<f64>,
    /// Irradiance at 1 m on a surface facing the light.
    pub power: f64,
}

/// The static lighting, baked into the texture tiles: irradiance
/// `E(p, n) = ambient + Σ_d I_d max(0, n·l_d) + Σ_p P_p max(0, n·l_p)/r_p²`.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Lighting {
    /// Uniform ambient irradiance.
    pub ambient: f64,
    /// Directional lights: unit direction towards the light and irradiance.
    pub directional: Vec<(Vector3<f64>, f64)>,
    /// Point lights.
    pub points: Vec<PointLight>,
}

impl Lighting {
    /// Irradiance at `p` on a surface of normal `n`.
    pub fn irradiance(&self, p: &Vector3<f64>, n: &Vector3<f64>) -> f64 {
        let mut e = self.ambient;
        for (d, i) in &self.directional {
            e += i * n.dot(d).max(0.0);
        }
        for l in &self.points {
            let v = l.position - p;
            let r2 = v.norm_squared().max(1e-4);
            e += l.power * (n.dot(&v) / r2.sqrt()).max(0.0) / r2;
        }
        e
    }
}

/// The sky and the far background seen where no quad is hit: a distant skyline (hills, tree
/// line) below an elevation that varies with azimuth, and a sky with clouds above.
#[derive(Debug, Clone, PartialEq)]
pub struct Sky {
    /// Seed of the skyline and the clouds.
    pub seed: u64,
    /// Mean elevation of the skyline (radians).
    pub horizon: f64,
    /// Radiance of the sky at the zenith and at the horizon.
    pub sky: (f64, f64),
    /// Mean radiance of the far background below the skyline.
    pub ground: f64,
}

impl Sky {
    /// Radiance in the world direction `d` (unit) for an angular footprint `footprint`
    /// (radians per pixel): band-limited like the textures.
    pub fn radiance(&self, d: &Vector3<f64>, footprint: f64) -> f64 {
        let elevation = d.z.clamp(-1.0, 1.0).asin();
        let azimuth = d.y.atan2(d.x);
        // Skyline: fBm in azimuth (wrapped by evaluating on the unit circle).
        let (cx, cy) = (azimuth.cos(), azimuth.sin());
        let skyline = self.horizon
            + 0.05
                * fbm(
                    self.seed,
                    3.0 * cx,
                    3.0 * cy,
                    1.0,
                    0.004,
                    0.55,
                    footprint * 3.0,
                );
        let below = smooth_step_aa(skyline - elevation, footprint);
        let hills = self.ground
            * (1.0
                + 0.35
                    * fbm(
                        self.seed ^ 0x77,
                        40.0 * azimuth,
                        40.0 * elevation,
                        2.0,
                        0.05,
                        0.6,
                        footprint * 40.0,
                    ));
        let up = elevation.max(0.0) / std::f64::consts::FRAC_PI_2;
        let mut sky = self.sky.1 + (self.sky.0 - self.sky.1) * up.sqrt();
        if d.z > 0.02 {
            // Clouds on a plane above the viewer: (x, y)/z.
            let (px, py) = (d.x / d.z, d.y / d.z);
            let scale = footprint / (d.z * d.z).max(1e-3);
            let c = fbm(self.seed ^ 0x99, px, py, 2.0, 0.01, 0.55, scale);
            sky += 0.12 * (c + 0.2).max(0.0);
        }
        sky + below * (hills - sky)
    }
}

/// A world to render: quads, lighting, optional sky, and the level-0 texel size.
#[derive(Debug, Clone, PartialEq)]
pub struct Scene {
    /// Name (`room`, `building`, `courtyard`, or a test scene's).
    pub name: String,
    /// The surfaces.
    pub quads: Vec<Quad>,
    /// Baked lighting.
    pub lighting: Lighting,
    /// Seen where no quad is hit (`None`: black; closed worlds never show it).
    pub sky: Option<Sky>,
    /// Texel size of mip level 0 (m): the finest detail the textures hold.
    pub texel: f64,
}

/// The six faces of an axis-aligned box, for [`Scene::add_box`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Face {
    /// The face at `x = min.x`.
    MinX,
    /// The face at `x = max.x`.
    MaxX,
    /// The face at `y = min.y`.
    MinY,
    /// The face at `y = max.y`.
    MaxY,
    /// The face at `z = min.z` (bottom).
    MinZ,
    /// The face at `z = max.z` (top).
    MaxZ,
}

impl Face {
    /// All six faces.
    pub const ALL: [Face; 6] = [
        Face::MinX,
        Face::MaxX,
        Face::MinY,
        Face::MaxY,
        Face::MinZ,
        Face::MaxZ,
    ];
}

impl Scene {
    /// An empty scene.
    pub fn new(name: &str, texel: f64) -> Self {
        Scene {
            name: name.to_string(),
            quads: Vec::new(),
            lighting: Lighting::default(),
            sky: None,
            texel,
        }
    }

    /// Adds a rectangle facing `normal` (unit, ±world axis or horizontal), with `t` along world
    /// up for vertical rectangles (`s` then runs to the right as seen from the front) and, for
    /// horizontal ones, `s` along `+x` (floors) or `+y` (ceilings). `corner` is the `(0, 0)`
    /// corner: the lower-left one seen from the front.
    pub fn add_rect(
        &mut self,
        corner: Vector3<f64>,
        normal: Vector3<f64>,
        width: f64,
        height: f64,
        material: Material,
        tint: [f32; 3],
    ) {
        let n = normal.normalize();
        let (axis_s, axis_t) = if n.z.abs() > 0.5 {
            if n.z > 0.0 {
                (Vector3::x(), Vector3::y())
            } else {
                (Vector3::y(), Vector3::x())
            }
        } else {
            let t = Vector3::z();
            (t.cross(&n).normalize(), t)
        };
        self.quads.push(Quad {
            origin: corner,
            axis_s,
            axis_t,
            width,
            height,
            material,
            tint,
        });
    }

    /// Adds the faces of the axis-aligned box `[min, max]` for which `material` returns a
    /// material, facing outwards (`inward = false`, a solid object) or inwards (a room).
    pub fn add_box(
        &mut self,
        min: Vector3<f64>,
        max: Vector3<f64>,
        inward: bool,
        tint: [f32; 3],
        mut material: impl FnMut(Face) -> Option<Material>,
    ) {
        let size = max - min;
        for face in Face::ALL {
            let Some(m) = material(face) else { continue };
            // Outward normal, and the lower-left corner seen from outside.
            let (n, corner, w, h) = match face {
                Face::MinX => (
                    -Vector3::x(),
                    Vector3::new(min.x, max.y, min.z),
                    size.y,
                    size.z,
                ),
                Face::MaxX => (
                    Vector3::x(),
                    Vector3::new(max.x, min.y, min.z),
                    size.y,
                    size.z,
                ),
                Face::MinY => (
                    -Vector3::y(),
                    Vector3::new(min.x, min.y, min.z),
                    size.x,
                    size.z,
                ),
                Face::MaxY => (
                    Vector3::y(),
                    Vector3::new(max.x, max.y, min.z),
                    size.x,
                    size.z,
                ),
                Face::MinZ => (
                    -Vector3::z(),
                    Vector3::new(min.x, min.y, min.z),
                    size.y,
                    size.x,
                ),
                Face::MaxZ => (
                    Vector3::z(),
                    Vector3::new(min.x, min.y, max.z),
                    size.x,
                    size.y,
                ),
            };
            if !inward {
                self.add_rect(corner, n, w, h, m, tint);
                continue;
            }
            // Facing inwards: the lower-left corner seen from inside.
            let (n, corner) = match face {
                Face::MinX => (Vector3::x(), Vector3::new(min.x, min.y, min.z)),
                Face::MaxX => (-Vector3::x(), Vector3::new(max.x, max.y, min.z)),
                Face::MinY => (Vector3::y(), Vector3::new(max.x, min.y, min.z)),
                Face::MaxY => (-Vector3::y(), Vector3::new(min.x, max.y, min.z)),
                Face::MinZ => (Vector3::z(), Vector3::new(min.x, min.y, min.z)),
                Face::MaxZ => (-Vector3::z(), Vector3::new(min.x, min.y, max.z)),
            };
            let (w, h) = match face {
                Face::MinZ => (size.x, size.y),
                Face::MaxZ => (size.y, size.x),
                _ => (w, h),
            };
            self.add_rect(corner, n, w, h, m, tint);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn box_faces_cover_the_box_and_face_the_right_way() {
        for inward in [false, true] {
            let mut s = Scene::new("t", 0.01);
            let (min, max) = (Vector3::new(1.0, 2.0, 3.0), Vector3::new(2.0, 4.0, 7.0));
            s.add_box(min, max, inward, [1.0; 3], |_| {
                Some(Material::plain(0.5, 0))
            });
            assert_eq!(s.quads.len(), 6);
            let centre = (min + max) / 2.0;
            for q in &s.quads {
                let n = q.normal();
                assert!((n.norm() - 1.0).abs() < 1e-12);
                assert!(q.axis_s.dot(&q.axis_t).abs() < 1e-12);
                // All corners on the box surface.
                for c in q.corners() {
                    for k in 0..3 {
                        assert!(c[k] >= min[k] - 1e-12 && c[k] <= max[k] + 1e-12);
                    }
                }
                // The quad's centre lies on its plane, and the normal points away from
                // (outward) or towards (inward) the box centre.
                let qc = q.point(q.width / 2.0, q.height / 2.0);
                let out = n.dot(&(qc - centre));
                assert!(if inward { out < 0.0 } else { out > 0.0 }, "{q:?}");
                for k in 0..3 {
                    assert!(qc[k] >= min[k] - 1e-12 && qc[k] <= max[k] + 1e-12);
                }
            }
        }
    }
}
