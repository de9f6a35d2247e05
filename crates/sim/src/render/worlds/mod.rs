//! The worlds: a furnished room, a building with a corridor loop, a courtyard, a town; and a test
//! plane with a checkerboard for the geometric tests.
//!
//! Geometry is fixed per world (but for the town, whose buildings, cars and trees along its fixed
//! streets are drawn from the seed); every surface's texture is seeded from the world seed and a
//! running surface counter, so a different seed gives a differently textured world of the same
//! shape, and no two surfaces of one world are alike.

mod building;
mod courtyard;
pub mod recipes;
mod room;
mod town;

pub use building::{BUILDING_LOOP, building};
pub use courtyard::{COURTYARD_HALF_SIZE, courtyard};
pub use room::{ROOM_SIZE, room};
pub use town::{TOWN_LANE_OFFSET, TOWN_STREETS_X, TOWN_STREETS_Y, town};

use super::procedural::hash1;
use super::scene::{Face, Scene};
use super::texture::{Layer, Material};
use nalgebra::Vector3;

/// Builds a scene with a running seed per surface.
pub(crate) struct Builder {
    pub scene: Scene,
    seed: u64,
    counter: u64,
}

impl Builder {
    pub fn new(name: &str, texel: f64, seed: u64) -> Self {
        Builder {
            scene: Scene::new(name, texel),
            seed,
            counter: 0,
        }
    }

    /// A fresh seed for the next surface.
    pub fn seed(&mut self) -> u64 {
        self.counter += 1;
        hash1(self.seed, self.counter)
    }

    /// A rectangle (see [`Scene::add_rect`]) whose material is made from a fresh seed.
    pub fn rect(
        &mut self,
        corner: Vector3<f64>,
        normal: Vector3<f64>,
        w: f64,
        h: f64,
        tint: [f32; 3],
        recipe: impl FnOnce(u64, f64, f64) -> Material,
    ) {
        let m = recipe(self.seed(), w, h);
        self.scene.add_rect(corner, normal, w, h, m, tint);
    }

    /// A solid box whose faces get materials from `recipe(seed, face, w, h)` (fresh seed per
    /// face); `None` skips a face. Bottom faces on the ground (`min.z ≤ 0`) are skipped.
    pub fn solid(
        &mut self,
        min: Vector3<f64>,
        max: Vector3<f64>,
        tint: [f32; 3],
        mut recipe: impl FnMut(u64, Face, f64, f64) -> Option<Material>,
    ) {
        let size = max - min;
        let mut seeds = [0u64; 6];
        for s in &mut seeds {
            *s = self.seed();
        }
        self.scene.add_box(min, max, false, tint, |face| {
            if face == Face::MinZ && min.z <= 1e-9 {
                return None;
            }
            let (w, h) = match face {
                Face::MinX | Face::MaxX => (size.y, size.z),
                Face::MinY | Face::MaxY => (size.x, size.z),
                Face::MinZ => (size.y, size.x),
                Face::MaxZ => (size.x, size.y),
            };
            let i = Face::ALL.iter().position(|f| *f == face).expect("a face");
            recipe(seeds[i], face, w, h)
        });
    }
}

/// The geometric test world: a large textured plane `z = 0` facing `+z` (texel 0.5 mm) with a
/// checkerboard of `columns × rows` squares of `square` metres whose lower-left corner is at
/// the origin; its inner corners are at `(i·square, j·square, 0)` for `0 < i < columns`,
/// `0 < j < rows`.
pub fn checker_plane(seed: u64, square: f64, columns: usize, rows: usize) -> Scene {
    let mut b = Builder::new("checker", 0.0005, seed);
    b.scene.lighting.ambient = 1.0;
    let (w, h) = (square * columns as f64, square * rows as f64);
    b.rect(
        Vector3::new(-0.5 * w, -0.5 * h, 0.0),
        Vector3::z(),
        2.0 * w,
        2.0 * h,
        recipes::NEUTRAL,
        |seed, _, _| {
            recipes::concrete(seed).with(Layer::Checker {
                origin: (0.5 * w, 0.5 * h),
                square,
                columns,
                rows,
            })
        },
    );
    b.scene
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn worlds_have_the_advertised_size_and_unique_textures() {
        for scene in [room(1), building(1), courtyard(1), town(1)] {
            assert!(
                scene.quads.len() > 50,
                "{}: {}",
                scene.name,
                scene.quads.len()
            );
            let mut seeds: Vec<u64> = scene.quads.iter().map(|q| q.material.seed).collect();
            seeds.sort_unstable();
            seeds.dedup();
            assert_eq!(seeds.len(), scene.quads.len(), "{}", scene.name);
            for q in &scene.quads {
                assert!(q.width > 0.0 && q.height > 0.0, "{}: {q:?}", scene.name);
            }
        }
        // The room: about 6 × 5 × 3 m.
        assert_eq!(ROOM_SIZE, [6.0, 5.0, 3.0]);
        // The building's corridor loop is at least 200 m long.
        let l = &BUILDING_LOOP;
        assert!(2.0 * ((l[2] - l[0]) + (l[3] - l[1])) >= 200.0);
        assert_ne!(room(1), room(2));
    }
}
