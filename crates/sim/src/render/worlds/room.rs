//! The furnished room: about 6 × 5 × 3 m, with a bookshelf, a sofa, a desk by the window, a
//! table with boxes in the middle, cabinets, pictures, a door, a rug and ceiling lights.

use super::Builder;
use super::recipes::{self, NEUTRAL, tint};
use crate::render::scene::{Face, PointLight, Scene};
use crate::render::texture::{Layer, Material};
use nalgebra::Vector3;

/// Inner size of the room `(x, y, z)` in metres; the room spans `[0, x] × [0, y] × [0, z]`.
pub const ROOM_SIZE: [f64; 3] = [6.0, 5.0, 3.0];

fn v(x: f64, y: f64, z: f64) -> Vector3<f64> {
    Vector3::new(x, y, z)
}

/// The room world; textures seeded by `seed`. Texel 1.5 mm: a hand-held camera at 0.7 m sees
/// 1.3 mm per pixel.
pub fn room(seed: u64) -> Scene {
    let [sx, sy, sz] = ROOM_SIZE;
    let mut b = Builder::new("room", 0.0015, seed);
    let wood = tint(1.3, 0.95, 0.65);
    let warm = tint(1.1, 1.0, 0.85);
    let cool = tint(0.9, 1.0, 1.15);

    // Walls, floor, ceiling (facing inwards).
    let mut wall_seeds = [0u64; 6];
    for s in &mut wall_seeds {
        *s = b.seed();
    }
    b.scene
        .add_box(v(0.0, 0.0, 0.0), v(sx, sy, sz), true, warm, |face| {
            Some(match face {
                Face::MinX => recipes::wallpaper(wall_seeds[0]),
                Face::MaxX => recipes::brick(wall_seeds[1]),
                Face::MinY => recipes::wallpaper(wall_seeds[2]),
                Face::MaxY => recipes::wallpaper(wall_seeds[3]),
                Face::MinZ => recipes::planks(wall_seeds[4]),
                Face::MaxZ => recipes::ceiling(wall_seeds[5]),
            })
        });
    let eps = 0.004; // pictures and panels stand this far off their wall

    // West wall (x = 0): the bookshelf, a poster and a painting.
    let (y0, y1, top) = (1.2, 3.6, 2.1);
    let depth = 0.38;
    b.rect(
        v(eps, y0, 0.0),
        Vector3::x(),
        y1 - y0,
        top,
        wood,
        |s, _, _| recipes::painted(s),
    );
    for (ya, yb) in [(y0, y0 + 0.03), (y1 - 0.03, y1)] {
        b.solid(v(0.0, ya, 0.0), v(depth, yb, top), wood, |s, _, _, _| {
            Some(recipes::planks(s))
        });
    }
    b.solid(
        v(0.0, y0, top - 0.03),
        v(depth, y1, top),
        wood,
        |s, _, _, _| Some(recipes::planks(s)),
    );
    let boards = [0.0, 0.5, 0.9, 1.3, 1.7];
    for (k, &z) in boards.iter().enumerate() {
        let thick = if k == 0 { 0.08 } else { 0.025 };
        b.solid(
            v(0.0, y0 + 0.03, z),
            v(depth, y1 - 0.03, z + thick),
            wood,
            |s, f, _, _| (f != Face::MinX).then(|| recipes::planks(s)),
        );
        // Book blocks on the board: runs of books with gaps.
        let zb = z + thick;
        let room_above = boards.get(k + 1).map_or(top - 0.03, |&n| n) - zb;
        let mut y = y0 + 0.05;
        let mut i = 0u64;
        while y < y1 - 0.25 {
            let h = b.seed();
            let len = 0.25 + 0.5 * crate::render::procedural::unit(h);
            let yb = (y + len).min(y1 - 0.05);
            let bh = room_above * (0.75 + 0.2 * crate::render::procedural::unit(h >> 7));
            if (i + k as u64).is_multiple_of(4) {
                // A box of stuff instead of books.
                b.solid(
                    v(0.04, y, zb),
                    v(0.3, yb, zb + 0.6 * bh),
                    NEUTRAL,
                    |s, _, w, hh| Some(recipes::cardboard(s, w, hh)),
                );
            } else {
                b.solid(
                    v(0.02, y, zb),
                    v(0.32, yb, zb + bh),
                    NEUTRAL,
                    |s, f, _, hh| {
                        Some(match f {
                            Face::MaxX => recipes::books(s, hh),
                            _ => recipes::painted(s),
                        })
                    },
                );
            }
            y = yb + 0.04 + 0.1 * crate::render::procedural::unit(h >> 13);
            i += 1;
        }
    }
    b.rect(
        v(eps, 0.25, 1.2),
        Vector3::x(),
        0.75,
        0.95,
        NEUTRAL,
        recipes::poster,
    );
    b.rect(
        v(eps, 3.9, 1.1),
        Vector3::x(),
        0.85,
        0.65,
        NEUTRAL,
        recipes::poster,
    );
    b.rect(
        v(eps, 4.0, 2.0),
        Vector3::x(),
        0.6,
        0.5,
        NEUTRAL,
        recipes::poster,
    );

    // North wall (y = 5, facing −y): door, posters, a cabinet with things on it.
    let n = -Vector3::y();
    b.rect(v(5.6, sy - eps, 0.0), n, 0.95, 2.1, wood, recipes::door);
    b.rect(
        v(5.65, sy - eps * 0.5, 0.0),
        n,
        1.05,
        2.16,
        NEUTRAL,
        |s, _, _| recipes::painted(s),
    );
    b.rect(
        v(1.6, sy - eps, 1.25),
        n,
        1.0,
        0.8,
        NEUTRAL,
        recipes::poster,
    );
    b.rect(
        v(4.1, sy - eps, 1.05),
        n,
        0.7,
        1.0,
        NEUTRAL,
        recipes::poster,
    );
    b.rect(
        v(0.9, sy - eps, 2.15),
        n,
        0.5,
        0.5,
        NEUTRAL,
        recipes::poster,
    );
    b.solid(v(1.5, 4.45, 0.0), v(3.6, sy, 0.9), wood, |s, f, w, h| {
        Some(match f {
            Face::MinY => recipes::door(s, w, h),
            _ => recipes::planks(s),
        })
    });
    b.rect(
        v(1.9, 4.45 - eps, 0.25),
        n,
        0.55,
        0.5,
        NEUTRAL,
        recipes::poster,
    );
    b.rect(
        v(2.9, 4.45 - eps, 0.3),
        n,
        0.4,
        0.45,
        NEUTRAL,
        recipes::pinboard,
    );
    b.solid(
        v(1.7, 4.6, 0.9),
        v(2.2, 4.95, 1.25),
        NEUTRAL,
        |s, _, w, h| Some(recipes::cardboard(s, w, h)),
    );
    b.solid(v(2.5, 4.7, 0.9), v(2.75, 4.95, 1.5), cool, |s, _, _, _| {
        Some(recipes::painted(s))
    });
    b.solid(
        v(3.0, 4.55, 0.9),
        v(3.5, 4.9, 1.1),
        NEUTRAL,
        |s, f, _, h| {
            Some(match f {
                Face::MinY => recipes::books(s, h),
                _ => recipes::painted(s),
            })
        },
    );

    // East wall (x = 6, facing −x): window with radiator, desk with screen, pinboard,
    // whiteboard.
    let e = -Vector3::x();
    b.rect(
        v(sx - eps, 3.5, 1.0),
        e,
        2.0,
        1.3,
        cool,
        recipes::window_pane,
    );
    b.rect(
        v(sx - eps * 0.5, 3.55, 0.95),
        e,
        2.1,
        1.4,
        NEUTRAL,
        |s, _, _| recipes::painted(s),
    );
    b.solid(
        v(5.88, 1.7, 0.2),
        v(5.96, 3.3, 0.8),
        NEUTRAL,
        |s, _, _, _| {
            Some(Material::plain(0.85, s).with(Layer::Grid {
                pitch_s: 0.05,
                pitch_t: 0.6,
                joint: 0.012,
                joint_value: 0.45,
                cell_variation: 0.02,
                row_offset: 0.0,
                random_length: false,
            }))
        },
    );
    b.solid(v(5.2, 3.7, 0.72), v(sx, 4.9, 0.76), wood, |s, _, _, _| {
        Some(recipes::planks(s))
    });
    for (x, y) in [(5.22, 3.72), (5.22, 4.84), (5.94, 3.72), (5.94, 4.84)] {
        b.solid(
            v(x, y, 0.0),
            v(x + 0.04, y + 0.04, 0.72),
            NEUTRAL,
            |s, _, _, _| Some(recipes::painted(s)),
        );
    }
    b.solid(
        v(5.7, 3.95, 0.76),
        v(5.75, 4.65, 1.2),
        NEUTRAL,
        |s, f, w, h| {
            Some(match f {
                Face::MinX => recipes::screen(s, w, h),
                _ => recipes::painted(s),
            })
        },
    );
    b.solid(
        v(5.35, 4.0, 0.76),
        v(5.5, 4.55, 0.78),
        NEUTRAL,
        |s, _, w, h| {
            Some(Material::plain(0.2, s).with(Layer::Grid {
                pitch_s: w / 14.0,
                pitch_t: h.max(0.02) / 5.0,
                joint: 0.004,
                joint_value: 0.05,
                cell_variation: 0.1,
                row_offset: 0.0,
                random_length: false,
            }))
        },
    );
    b.solid(
        v(5.3, 4.6, 0.76),
        v(5.5, 4.85, 0.95),
        NEUTRAL,
        |s, _, w, h| Some(recipes::cardboard(s, w, h)),
    );
    b.rect(
        v(sx - eps, 4.9, 1.3),
        e,
        1.2,
        0.8,
        NEUTRAL,
        recipes::pinboard,
    );
    b.rect(
        v(sx - eps, 1.3, 0.9),
        e,
        1.1,
        1.1,
        NEUTRAL,
        recipes::whiteboard,
    );

    // South wall (y = 0, facing +y; seen from the room its s axis runs towards −x, so a
    // rectangle's corner is its end at the larger x): sofa with paintings above, a wardrobe with
    // a calendar and stickers, a shelf with books, posters.
    let s_ = Vector3::y();
    let fabric = tint(0.8, 0.9, 1.3);
    let upholstery = |s: u64, _: Face, _: f64, _: f64| Some(recipes::rug(s, 0.6, 0.6));
    b.solid(v(1.0, 0.0, 0.0), v(3.0, 0.9, 0.45), fabric, upholstery);
    b.solid(v(1.0, 0.0, 0.45), v(3.0, 0.22, 0.9), fabric, upholstery);
    b.solid(v(0.85, 0.0, 0.0), v(1.0, 0.9, 0.65), fabric, upholstery);
    b.solid(v(3.0, 0.0, 0.0), v(3.15, 0.9, 0.65), fabric, upholstery);
    b.rect(v(2.8, eps, 1.15), s_, 1.6, 0.9, NEUTRAL, recipes::poster);
    b.rect(v(0.8, eps, 1.45), s_, 0.5, 0.65, NEUTRAL, recipes::poster);
    b.rect(v(0.7, eps, 0.7), s_, 0.35, 0.45, NEUTRAL, recipes::poster);
    b.rect(v(3.75, eps, 1.3), s_, 0.5, 0.6, NEUTRAL, recipes::poster);
    b.rect(v(2.3, eps, 2.2), s_, 0.6, 0.45, NEUTRAL, recipes::pinboard);
    b.solid(v(1.1, 0.0, 2.15), v(2.0, 0.25, 2.18), wood, |s, _, _, _| {
        Some(recipes::planks(s))
    });
    b.solid(
        v(1.15, 0.02, 2.18),
        v(1.9, 0.22, 2.45),
        NEUTRAL,
        |s, f, _, h| {
            Some(match f {
                Face::MaxY => recipes::books(s, h),
                _ => recipes::painted(s),
            })
        },
    );
    b.solid(v(3.9, 0.0, 0.0), v(5.1, 0.6, 2.0), wood, |s, _, _, _| {
        Some(recipes::planks(s))
    });
    b.rect(
        v(4.95, 0.6 + eps, 1.0),
        s_,
        0.45,
        0.6,
        NEUTRAL,
        recipes::poster,
    );
    b.rect(
        v(4.4, 0.6 + eps, 1.25),
        s_,
        0.35,
        0.5,
        NEUTRAL,
        recipes::pinboard,
    );
    // The wardrobe's doors are covered in posters, drawings and a calendar.
    b.rect(
        v(4.95, 0.6 + eps, 0.15),
        s_,
        0.5,
        0.7,
        NEUTRAL,
        recipes::poster,
    );
    b.rect(
        v(4.35, 0.6 + eps, 0.2),
        s_,
        0.35,
        0.55,
        NEUTRAL,
        recipes::pinboard,
    );
    b.rect(
        v(4.4, 0.6 + eps, 1.8),
        s_,
        0.4,
        0.15,
        NEUTRAL,
        recipes::poster,
    );
    b.rect(
        v(4.05, 0.6 + eps, 0.85),
        s_,
        0.1,
        0.3,
        NEUTRAL,
        |s, _, _| recipes::painted(s),
    );
    b.solid(
        v(4.0, 0.1, 2.0),
        v(4.5, 0.5, 2.35),
        NEUTRAL,
        |s, _, w, h| Some(recipes::cardboard(s, w, h)),
    );
    b.solid(
        v(4.55, 0.1, 2.0),
        v(5.0, 0.45, 2.2),
        NEUTRAL,
        |s, _, w, h| Some(recipes::cardboard(s, w, h)),
    );
    b.rect(v(5.9, eps, 1.0), s_, 0.6, 1.2, NEUTRAL, recipes::poster);

    // The middle: a rug, a table with boxes, books and a laptop, two chairs.
    b.rect(
        v(1.7, 1.3, 0.003),
        Vector3::z(),
        2.6,
        2.4,
        tint(1.2, 0.85, 0.8),
        recipes::rug,
    );
    b.solid(v(2.4, 2.0, 0.72), v(3.6, 3.0, 0.76), wood, |s, _, _, _| {
        Some(recipes::planks(s))
    });
    for (x, y) in [(2.43, 2.03), (2.43, 2.93), (3.53, 2.03), (3.53, 2.93)] {
        b.solid(
            v(x, y, 0.0),
            v(x + 0.04, y + 0.04, 0.72),
            wood,
            |s, _, _, _| Some(recipes::painted(s)),
        );
    }
    b.solid(
        v(2.5, 2.1, 0.76),
        v(2.85, 2.4, 1.0),
        NEUTRAL,
        |s, _, w, h| Some(recipes::cardboard(s, w, h)),
    );
    b.solid(
        v(2.55, 2.6, 0.76),
        v(2.8, 2.9, 0.88),
        NEUTRAL,
        |s, _, w, h| Some(recipes::cardboard(s, w, h)),
    );
    b.solid(
        v(3.1, 2.55, 0.76),
        v(3.4, 2.9, 0.84),
        NEUTRAL,
        |s, f, _, h| {
            Some(match f {
                Face::MaxZ => recipes::poster(s, 0.3, 0.35),
                _ => recipes::books(s, h),
            })
        },
    );
    b.solid(
        v(3.0, 2.1, 0.76),
        v(3.35, 2.35, 0.78),
        NEUTRAL,
        |s, _, _, _| Some(recipes::painted(s)),
    );
    b.rect(
        v(3.02, 2.35, 0.78),
        -Vector3::y(),
        0.31,
        0.2,
        NEUTRAL,
        recipes::screen,
    );
    for (y, back) in [(1.45, 1.45), (3.25, 3.51)] {
        b.solid(
            v(2.8, y, 0.45),
            v(3.2, y + 0.3, 0.49),
            wood,
            |s, _, _, _| Some(recipes::planks(s)),
        );
        b.solid(
            v(2.8, back, 0.49),
            v(3.2, back + 0.04, 0.95),
            wood,
            |s, _, _, _| Some(recipes::planks(s)),
        );
        for (x, yy) in [(2.8, y), (3.16, y), (2.8, y + 0.26), (3.16, y + 0.26)] {
            b.solid(
                v(x, yy, 0.0),
                v(x + 0.04, yy + 0.04, 0.45),
                NEUTRAL,
                |s, _, _, _| Some(recipes::painted(s)),
            );
        }
    }
    // Boxes on the floor by the walls.
    b.solid(v(0.5, 4.2, 0.0), v(1.0, 4.7, 0.4), NEUTRAL, |s, _, w, h| {
        Some(recipes::cardboard(s, w, h))
    });
    b.solid(
        v(0.55, 4.25, 0.4),
        v(0.9, 4.6, 0.65),
        NEUTRAL,
        |s, _, w, h| Some(recipes::cardboard(s, w, h)),
    );
    b.solid(v(5.3, 0.4, 0.0), v(5.7, 0.8, 0.5), cool, |s, _, _, _| {
        Some(recipes::painted(s))
    });

    // Ceiling lights.
    for (x, y) in [(2.0, 2.2), (3.4, 2.2)] {
        b.rect(
            v(x, y, sz - 0.005),
            -Vector3::z(),
            0.6,
            0.6,
            NEUTRAL,
            |s, _, _| recipes::light_panel(s),
        );
    }
    b.scene.lighting.ambient = 0.5;
    for (x, y) in [(2.3, 2.5), (3.7, 2.5)] {
        b.scene.lighting.points.push(PointLight {
            position: v(x, y, 2.85),
            power: 1.4,
        });
    }
    b.scene
        .lighting
        .directional
        .push((Vector3::new(1.0, 0.0, 0.3).normalize(), 0.2));
    b.scene
}
