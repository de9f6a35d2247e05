//! The courtyard: a 40 × 40 m square bounded by façades of 6–18 m (windows, doors, shop
//! fronts, balconies, downpipes), paved, with a lawn, a fountain, trees, benches and lamp posts;
//! beyond the low façades distant towers and a skyline under a cloudy sky.

use super::Builder;
use super::recipes::{self, NEUTRAL, tint};
use crate::render::procedural::{hash1, range};
use crate::render::scene::{Face, Scene, Sky};
use crate::render::texture::Layer;
use nalgebra::Vector3;

/// Half the side of the square (m): the façades stand at `x = ±20`, `y = ±20`.
pub const COURTYARD_HALF_SIZE: f64 = 20.0;
const LAYOUT: u64 = 0x636f_7572_7479_6172;

fn v(x: f64, y: f64, z: f64) -> Vector3<f64> {
    Vector3::new(x, y, z)
}

/// The courtyard world; textures seeded by `seed`. Texel 3 mm.
pub fn courtyard(seed: u64) -> Scene {
    let mut b = Builder::new("courtyard", 0.003, seed);
    let a = COURTYARD_HALF_SIZE;
    // Façades facing the square: (corner, normal, height).
    let facades = [
        (v(a, -a, 0.0), Vector3::y(), 15.0),
        (v(a, a, 0.0), -Vector3::x(), 9.0),
        (v(-a, a, 0.0), -Vector3::y(), 18.0),
        (v(-a, -a, 0.0), Vector3::x(), 6.0),
    ];
    for (k, &(corner, normal, height)) in facades.iter().enumerate() {
        let w = 2.0 * a;
        let kind = hash1(LAYOUT, k as u64);
        let colour = [
            tint(1.2, 1.0, 0.85),
            NEUTRAL,
            tint(1.0, 1.0, 1.1),
            tint(1.1, 1.05, 0.9),
        ][k];
        b.rect(corner, normal, w, height, colour, |s, w, h| {
            recipes::facade(s, w, h, kind)
        });
        let dir = Vector3::z().cross(&normal);
        // Balconies on the tall façades, downpipes, a cornice.
        if height > 10.0 {
            for j in 0..5u64 {
                let hb = hash1(kind, 10 + j);
                let s0 = range(hb, 2.0, w - 4.0);
                let z0 = range(hash1(hb, 1), 4.0, height - 4.0).floor();
                let p0 = corner + dir * s0 + Vector3::z() * z0;
                let p1 = p0 + dir * 2.5 + normal * 1.0 + Vector3::z() * 1.0;
                let (min, max) = (p0.inf(&p1), p0.sup(&p1));
                b.solid(min, max, NEUTRAL, |s, face, w, h| {
                    Some(match face {
                        Face::MaxZ | Face::MinZ => recipes::concrete(s),
                        _ => recipes::painted(s).with(Layer::Grid {
                            pitch_s: 0.12,
                            pitch_t: h,
                            joint: 0.03,
                            joint_value: 0.15,
                            cell_variation: 0.05,
                            row_offset: 0.0,
                            random_length: w < 0.0,
                        }),
                    })
                });
            }
        }
        for j in 0..3u64 {
            let s0 = range(hash1(kind, 30 + j), 1.0, w - 1.0);
            let p0 = corner + dir * s0;
            let p1 = p0 + dir * 0.12 + normal * 0.12 + Vector3::z() * height;
            b.solid(p0.inf(&p1), p0.sup(&p1), NEUTRAL, |s, _, _, _| {
                Some(recipes::painted(s))
            });
        }
        let p0 = corner + Vector3::z() * (height - 0.4);
        let p1 = corner + dir * w + normal * 0.3 + Vector3::z() * height;
        b.solid(p0.inf(&p1), p0.sup(&p1), NEUTRAL, |s, _, _, _| {
            Some(recipes::concrete(s))
        });
    }
    // Ground: cobbles, a path ring of tiles, a lawn with a fountain.
    b.rect(
        v(-a, -a, 0.0),
        Vector3::z(),
        2.0 * a,
        2.0 * a,
        NEUTRAL,
        |s, _, _| recipes::cobbles(s),
    );
    let (lawn, path) = (7.0, 2.0);
    for (x0, y0, w, h) in [
        (-lawn - path, -lawn - path, 2.0 * (lawn + path), path),
        (-lawn - path, lawn, 2.0 * (lawn + path), path),
        (-lawn - path, -lawn, path, 2.0 * lawn),
        (lawn, -lawn, path, 2.0 * lawn),
    ] {
        b.rect(
            v(x0, y0, 0.003),
            Vector3::z(),
            w,
            h,
            tint(1.1, 1.0, 0.9),
            |s, _, _| recipes::tiles(s, 0.4),
        );
    }
    b.rect(
        v(-lawn, -lawn, 0.005),
        Vector3::z(),
        2.0 * lawn,
        2.0 * lawn,
        tint(0.7, 1.25, 0.6),
        |s, _, _| recipes::grass(s),
    );
    b.solid(
        v(-1.5, -1.5, 0.0),
        v(1.5, 1.5, 0.5),
        NEUTRAL,
        |s, _, _, _| Some(recipes::concrete(s)),
    );
    b.solid(
        v(-0.3, -0.3, 0.5),
        v(0.3, 0.3, 2.0),
        NEUTRAL,
        |s, _, _, _| Some(recipes::concrete(s)),
    );
    b.solid(
        v(-0.7, -0.7, 2.0),
        v(0.7, 0.7, 2.2),
        NEUTRAL,
        |s, _, _, _| Some(recipes::concrete(s)),
    );
    // Trees between the path and the façades; benches and lamp posts on the tiled ring around
    // the lawn, at least 1.9 m from where the laps walk.
    for (x, y) in [
        (-15.0, -15.0),
        (15.0, -15.0),
        (15.0, 15.0),
        (-15.0, 15.0),
        (0.0, 15.5),
        (15.5, 0.0),
    ] {
        b.solid(
            v(x - 0.2, y - 0.2, 0.0),
            v(x + 0.2, y + 0.2, 2.6),
            tint(1.2, 1.0, 0.8),
            |s, _, _, _| Some(recipes::concrete(s)),
        );
        b.solid(
            v(x - 1.6, y - 1.6, 2.6),
            v(x + 1.6, y + 1.6, 5.4),
            tint(0.8, 1.2, 0.7),
            |s, _, _, _| Some(recipes::foliage(s)),
        );
    }
    for (x, y, along_x) in [
        (-4.0, -8.6, true),
        (4.0, 8.6, true),
        (-8.6, 3.0, false),
        (8.6, -3.0, false),
    ] {
        let (hx, hy) = if along_x { (0.9, 0.25) } else { (0.25, 0.9) };
        b.solid(
            v(x - hx, y - hy, 0.0),
            v(x + hx, y + hy, 0.45),
            tint(1.2, 1.0, 0.8),
            |s, _, _, _| Some(recipes::planks(s)),
        );
    }
    for (x, y) in [
        (-8.7, -8.7),
        (8.7, -8.7),
        (8.7, 8.7),
        (-8.7, 8.7),
        (0.0, -8.7),
        (0.0, 8.7),
    ] {
        b.solid(
            v(x - 0.06, y - 0.06, 0.0),
            v(x + 0.06, y + 0.06, 4.0),
            NEUTRAL,
            |s, _, _, _| Some(recipes::painted(s)),
        );
        b.solid(
            v(x - 0.2, y - 0.2, 4.0),
            v(x + 0.2, y + 0.2, 4.3),
            NEUTRAL,
            |s, _, _, _| Some(recipes::painted(s)),
        );
    }
    // Planters along the façades.
    for k in 0..8u64 {
        let h = hash1(LAYOUT, 100 + k);
        let s = range(h, -a + 3.0, a - 3.0);
        let (x, y) = match k % 4 {
            0 => (s, -a + 0.8),
            1 => (a - 0.8, s),
            2 => (s, a - 0.8),
            _ => (-a + 0.8, s),
        };
        b.solid(
            v(x - 0.6, y - 0.6, 0.0),
            v(x + 0.6, y + 0.6, 0.7),
            NEUTRAL,
            |s, face, _, _| {
                Some(if face == Face::MaxZ {
                    recipes::foliage(s)
                } else {
                    recipes::concrete(s)
                })
            },
        );
    }
    // Distant towers (50–300 m away).
    for (k, &(x, y, w, d, h)) in [
        (-120.0, 40.0, 30.0, 25.0, 60.0),
        (-90.0, -150.0, 40.0, 30.0, 45.0),
        (150.0, 120.0, 25.0, 25.0, 85.0),
        (60.0, -200.0, 35.0, 20.0, 50.0),
        (-220.0, -60.0, 50.0, 40.0, 70.0),
        (230.0, -30.0, 30.0, 30.0, 40.0),
        (-60.0, 210.0, 40.0, 30.0, 55.0),
        (-45.0, -60.0, 15.0, 15.0, 30.0),
    ]
    .iter()
    .enumerate()
    {
        let kind = hash1(LAYOUT, 200 + k as u64);
        b.solid(
            v(x - w / 2.0, y - d / 2.0, 0.0),
            v(x + w / 2.0, y + d / 2.0, h),
            NEUTRAL,
            |s, face, fw, fh| {
                Some(if face == Face::MaxZ {
                    recipes::concrete(s)
                } else {
                    recipes::facade(s, fw, fh, kind)
                })
            },
        );
    }
    b.scene.sky = Some(Sky {
        seed: b.seed(),
        horizon: 0.02,
        sky: (0.75, 0.95),
        ground: 0.3,
    });
    b.scene.lighting.ambient = 0.55;
    b.scene
        .lighting
        .directional
        .push((Vector3::new(0.45, -0.35, 0.82).normalize(), 0.6));
    b.scene
}
