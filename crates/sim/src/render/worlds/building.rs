//! The building: a ring corridor 3 m wide and 3 m high around an inner block, whose centre line
//! is a 61 × 45 m rectangle (212 m of path), with wall sections of different finishes, doors,
//! pillars, notice boards, posters, windows on the outer wall, benches, plants and ceiling
//! lights.

use super::Builder;
use super::recipes::{self, NEUTRAL, tint};
use crate::render::procedural::{hash1, range, unit};
use crate::render::scene::{Face, PointLight, Scene};
use crate::render::texture::Material;
use nalgebra::Vector3;

/// The corridor's centre line: the rectangle `[x0, y0, x1, y1]` (m) walked by the building
/// trajectory (perimeter 212 m).
pub const BUILDING_LOOP: [f64; 4] = [1.5, 1.5, 62.5, 46.5];
const OUTER: [f64; 4] = [0.0, 0.0, 64.0, 48.0];
const INNER: [f64; 4] = [3.0, 3.0, 61.0, 45.0];
const HEIGHT: f64 = 3.0;
/// The layout (section lengths, which features where) is fixed: only textures follow the seed.
const LAYOUT: u64 = 0x6275_696c_6469_6e67;

fn v(x: f64, y: f64, z: f64) -> Vector3<f64> {
    Vector3::new(x, y, z)
}

/// A wall material for section `k` of a run.
fn wall_material(seed: u64, kind: u64) -> Material {
    match kind % 5 {
        0 => recipes::plaster(seed),
        1 => recipes::wallpaper(seed),
        2 => recipes::tiles(seed, 0.2),
        3 => recipes::brick(seed),
        _ => recipes::concrete(seed),
    }
}

/// Lays one straight wall: from `corner` (its lower-left end seen from the corridor) along
/// `dir = z × normal` for `length` metres, in sections of 4–9 m, each with its own finish and
/// features; pillars between sections on outer walls.
fn wall_run(
    b: &mut Builder,
    corner: Vector3<f64>,
    normal: Vector3<f64>,
    length: f64,
    run: u64,
    outer: bool,
) {
    let dir = Vector3::z().cross(&normal);
    let eps = 0.004;
    let mut s = 0.0;
    let mut k = 0u64;
    while s < length - 1e-9 {
        let h = hash1(LAYOUT ^ run, k);
        let mut len = range(h, 4.0, 9.0);
        if length - (s + len) < 3.0 {
            len = length - s;
        }
        let c = corner + dir * s;
        let kind = hash1(h, 1);
        let colour = [
            tint(1.1, 1.0, 0.85),
            tint(0.9, 1.0, 1.1),
            NEUTRAL,
            tint(1.0, 1.05, 0.9),
        ][(kind % 4) as usize];
        b.rect(c, normal, len, HEIGHT, colour, |seed, _, _| {
            wall_material(seed, kind >> 3)
        });
        // Features along the section, at positions drawn from the layout hash.
        let mut x = 0.6;
        let mut f = 0u64;
        while x < len - 1.2 {
            let hf = hash1(h, 10 + f);
            let width = range(hf, 0.6, 1.6).min(len - 0.4 - x);
            let at = c + dir * x + normal * eps;
            match hf % 7 {
                0 | 1 => {
                    b.rect(at, normal, 0.95, 2.1, tint(1.2, 1.0, 0.8), recipes::door);
                    b.rect(
                        at - dir * 0.05 - normal * (eps * 0.5),
                        normal,
                        1.05,
                        2.16,
                        NEUTRAL,
                        |s, _, _| recipes::painted(s),
                    );
                    x += 0.95;
                }
                2 => {
                    b.rect(
                        at + Vector3::z() * 1.1,
                        normal,
                        width,
                        width * 0.7,
                        NEUTRAL,
                        recipes::pinboard,
                    );
                    x += width;
                }
                3 => {
                    let h2 = range(hash1(hf, 1), 0.6, 1.0);
                    b.rect(
                        at + Vector3::z() * 1.2,
                        normal,
                        width * 0.7,
                        h2,
                        NEUTRAL,
                        recipes::poster,
                    );
                    x += width * 0.7;
                }
                4 if outer => {
                    b.rect(
                        at + Vector3::z() * 0.9,
                        normal,
                        width,
                        1.4,
                        tint(0.9, 1.0, 1.15),
                        recipes::window_pane,
                    );
                    x += width;
                }
                5 => {
                    // A bench or a cabinet standing at the wall.
                    let depth = 0.45;
                    let (p0, p1) = (at, at + dir * width + normal * depth);
                    let (min, max) = (p0.inf(&p1), p0.sup(&p1));
                    let high = hash1(hf, 2).is_multiple_of(2);
                    let top = if high { 1.8 } else { 0.45 };
                    b.solid(
                        v(min.x, min.y, 0.0),
                        v(max.x, max.y, top),
                        tint(1.2, 1.0, 0.8),
                        |s, face, w, hh| {
                            Some(if high && face != Face::MaxZ {
                                recipes::door(s, w, hh)
                            } else {
                                recipes::planks(s)
                            })
                        },
                    );
                    x += width;
                }
                _ => {
                    // A plant in a pot, or an extinguisher.
                    let r = 0.2;
                    let p = at + dir * r + normal * r;
                    b.solid(
                        v(p.x - r, p.y - r, 0.0),
                        v(p.x + r, p.y + r, 0.5),
                        NEUTRAL,
                        |s, _, _, _| Some(recipes::painted(s)),
                    );
                    b.solid(
                        v(p.x - 0.3, p.y - 0.3, 0.5),
                        v(p.x + 0.3, p.y + 0.3, 1.3),
                        tint(0.8, 1.2, 0.7),
                        |s, _, _, _| Some(recipes::foliage(s)),
                    );
                    x += 0.6;
                }
            }
            x += range(hash1(hf, 3), 0.4, 1.5);
            f += 1;
        }
        s += len;
        k += 1;
        if outer && s < length - 1.0 {
            // A pillar at the section boundary.
            let p = corner + dir * s;
            let (p0, p1) = (p - dir * 0.18, p + dir * 0.18 + normal * 0.2);
            let (min, max) = (p0.inf(&p1), p0.sup(&p1));
            b.solid(
                v(min.x, min.y, 0.0),
                v(max.x, max.y, HEIGHT),
                NEUTRAL,
                |s, _, _, _| Some(recipes::concrete(s)),
            );
        }
    }
}

/// The building world; textures seeded by `seed`. Texel 2 mm (a wall 1 m away is seen at
/// 1.9 mm per pixel).
pub fn building(seed: u64) -> Scene {
    let mut b = Builder::new("building", 0.002, seed);
    let [ox0, oy0, ox1, oy1] = OUTER;
    let [ix0, iy0, ix1, iy1] = INNER;
    // Outer walls facing inwards, inner block walls facing outwards.
    wall_run(&mut b, v(ox1, oy0, 0.0), Vector3::y(), ox1 - ox0, 1, true);
    wall_run(&mut b, v(ox1, oy1, 0.0), -Vector3::x(), oy1 - oy0, 2, true);
    wall_run(&mut b, v(ox0, oy1, 0.0), -Vector3::y(), ox1 - ox0, 3, true);
    wall_run(&mut b, v(ox0, oy0, 0.0), Vector3::x(), oy1 - oy0, 4, true);
    wall_run(&mut b, v(ix0, iy0, 0.0), -Vector3::y(), ix1 - ix0, 5, false);
    wall_run(&mut b, v(ix1, iy0, 0.0), Vector3::x(), iy1 - iy0, 6, false);
    wall_run(&mut b, v(ix1, iy1, 0.0), Vector3::y(), ix1 - ix0, 7, false);
    wall_run(&mut b, v(ix0, iy1, 0.0), -Vector3::x(), iy1 - iy0, 8, false);
    // Floors and ceilings of the four corridors (each its own finish).
    let strips = [
        (ox0, oy0, ox1, iy0),
        (ox0, iy1, ox1, oy1),
        (ox0, iy0, ix0, iy1),
        (ix1, iy0, ox1, iy1),
    ];
    for (k, &(x0, y0, x1, y1)) in strips.iter().enumerate() {
        let (w, h) = (x1 - x0, y1 - y0);
        b.rect(
            v(x0, y0, 0.0),
            Vector3::z(),
            w,
            h,
            [NEUTRAL, tint(1.2, 1.0, 0.8), tint(0.9, 1.0, 1.1), NEUTRAL][k],
            |s, _, _| match k {
                0 => recipes::tiles(s, 0.3),
                1 => recipes::planks(s),
                2 => recipes::concrete(s),
                _ => recipes::tiles(s, 0.45),
            },
        );
        // Ceiling (s along +y, t along +x for downward-facing rectangles).
        b.rect(
            v(x0, y0, HEIGHT),
            -Vector3::z(),
            h,
            w,
            NEUTRAL,
            |s, _, _| recipes::ceiling(s),
        );
    }
    // Ceiling lights every 4 m along the centre line, and matching point lights.
    let [cx0, cy0, cx1, cy1] = BUILDING_LOOP;
    let mut lights = Vec::new();
    let mut x = cx0 + 2.0;
    while x < cx1 - 1.0 {
        lights.push((x, cy0));
        lights.push((x, cy1));
        x += 4.0;
    }
    let mut y = cy0 + 4.0;
    while y < cy1 - 2.0 {
        lights.push((cx0, y));
        lights.push((cx1, y));
        y += 4.0;
    }
    for (k, &(x, y)) in lights.iter().enumerate() {
        let along_x = (y - cy0).abs() < 1e-9 || (y - cy1).abs() < 1e-9;
        let (w, h) = if along_x { (0.3, 1.2) } else { (1.2, 0.3) };
        b.rect(
            v(x - h / 2.0, y - w / 2.0, HEIGHT - 0.005),
            -Vector3::z(),
            w,
            h,
            NEUTRAL,
            |s, _, _| recipes::light_panel(s),
        );
        // Every other light lights the corridor (point lights cost at bake time only).
        if k % 2 == 0 {
            b.scene.lighting.points.push(PointLight {
                position: v(x, y, HEIGHT - 0.2),
                power: 1.2,
            });
        }
    }
    b.scene.lighting.ambient = 0.45;
    // Slight variation of the walls' brightness with the outside light through the windows.
    b.scene.lighting.directional.push((
        Vector3::new(0.3, 0.5, 0.4).normalize(),
        0.15 + 0.1 * unit(hash1(LAYOUT, 99)),
    ));
    b.scene
}
