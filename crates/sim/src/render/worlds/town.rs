//! The town: a grid of street blocks for a car to drive through. Streets 18 m between the
//! façades (two lanes, a parking strip on each side, raised pavements with kerbs), lined with
//! terraces of buildings of two to six storeys (storeys of windows, shop fronts and signs, cornices,
//! balconies), parked cars, street trees and lamp posts; zebra crossings at every junction and
//! a dashed centre line; the streets run out of town, under a skyline of distant towers.
//!
//! The street grid is fixed ([`TOWN_STREETS_X`], [`TOWN_STREETS_Y`]: the drive of
//! `paths::TownDrive` follows it); everything on it — the buildings' widths, heights and
//! façades, the cars and their colours, which streets have trees — is drawn from the seed, so
//! another seed is another town on the same streets.

use super::Builder;
use super::recipes::{self, NEUTRAL, tint};
use crate::render::procedural::{hash1, range, unit};
use crate::render::scene::{Face, Scene, Sky};
use crate::render::texture::{Layer, Material};
use nalgebra::Vector3;

/// Centrelines of the north–south streets (m, `x`).
pub const TOWN_STREETS_X: [f64; 4] = [0.0, 110.0, 220.0, 330.0];
/// Centrelines of the east–west streets (m, `y`).
pub const TOWN_STREETS_Y: [f64; 4] = [0.0, 80.0, 160.0, 240.0];
/// The driving lane's centre, right of a street's centreline (m): lanes of 3.5 m.
pub const TOWN_LANE_OFFSET: f64 = 1.75;
/// The kerb: the road (two lanes and the parking strips) is `±ROAD` about the centreline.
const ROAD: f64 = 5.5;
/// The parking strip's inner edge.
const PARKING: f64 = 3.5;
/// The façade line: pavements from the kerb to here.
const FACADE: f64 = 9.0;
/// The kerb's height (m).
const KERB: f64 = 0.12;
/// Depth of the buildings behind the façade line (m).
const DEPTH: f64 = 15.0;
/// The town's outer edge beyond the last streets (m): a row of buildings faces them.
const OUTSKIRTS: f64 = 60.0;

fn v(x: f64, y: f64, z: f64) -> Vector3<f64> {
    Vector3::new(x, y, z)
}

/// Dark asphalt: fine grain, a few patches and cracks.
fn asphalt(seed: u64) -> Material {
    recipes::concrete(seed).with(Layer::Scatter {
        cell: 2.0,
        density: 0.4,
        size: (0.2, 0.5),
        values: (0.15, 0.3),
        opacity: 0.35,
        shape: crate::render::texture::Shape::Mixed,
        angle: 0.3,
    })
}

/// A horizontal strip `[x0, x1] × [y0, y1]` at height `z`.
fn ground(
    b: &mut Builder,
    (x0, y0, x1, y1): (f64, f64, f64, f64),
    z: f64,
    colour: [f32; 3],
    recipe: impl FnOnce(u64, f64, f64) -> Material,
) {
    b.rect(v(x0, y0, z), Vector3::z(), x1 - x0, y1 - y0, colour, recipe);
}

/// One side of a block along a street: the façade line runs from `start` in direction `along`
/// (a unit horizontal axis) for `length` metres, the street on the side of `out` (unit, the
/// façade's outward normal).
#[derive(Clone, Copy)]
struct Side {
    start: Vector3<f64>,
    along: Vector3<f64>,
    out: Vector3<f64>,
    length: f64,
}

impl Side {
    /// The point `s` metres along the façade line and `d` metres out from it at height `z`.
    fn at(&self, s: f64, d: f64, z: f64) -> Vector3<f64> {
        self.start + self.along * s + self.out * d + Vector3::z() * z
    }
}

/// The axis-aligned box spanned by two corners.
fn boxed(
    b: &mut Builder,
    p: Vector3<f64>,
    q: Vector3<f64>,
    colour: [f32; 3],
    recipe: impl FnMut(u64, Face, f64, f64) -> Option<Material>,
) {
    b.solid(p.inf(&q), p.sup(&q), colour, recipe);
}

/// The face of a box that looks along `out`.
fn facing(out: &Vector3<f64>) -> Face {
    match (out.x.round() as i32, out.y.round() as i32) {
        (1, _) => Face::MaxX,
        (-1, _) => Face::MinX,
        (_, 1) => Face::MaxY,
        _ => Face::MinY,
    }
}

/// A terrace of buildings along `side` (the façade line), `layout` drawing their widths
/// (9–24 m), heights (two to six storeys of 3.4 m) and façades.
fn terrace(b: &mut Builder, side: &Side, layout: u64) {
    let mut s = 0.0;
    let mut k = 0u64;
    while side.length - s > 1.0 {
        let h = hash1(layout, k);
        let mut w = range(h, 9.0, 24.0);
        if side.length - s - w < 9.0 {
            w = side.length - s;
        }
        let height = (range(hash1(h, 1), 2.2, 7.0).floor() * 3.4).max(7.0);
        let kind = hash1(h, 2);
        let colour = [
            tint(1.2, 1.0, 0.85),
            NEUTRAL,
            tint(1.0, 1.0, 1.1),
            tint(1.1, 1.05, 0.9),
            tint(1.15, 0.95, 0.9),
        ][(hash1(h, 3) % 5) as usize];
        let front = facing(&side.out);
        let back = facing(&-side.out);
        let (p, q) = (side.at(s, 0.0, 0.0), side.at(s + w, -DEPTH, height));
        boxed(b, p, q, colour, |seed, face, fw, fh| {
            Some(if face == Face::MaxZ {
                recipes::concrete(seed)
            } else if face == back {
                return None;
            } else if face == front {
                recipes::facade(seed, fw, fh, kind)
            } else {
                recipes::facade(seed, fw, fh, kind ^ 1)
            })
        });
        // A cornice along the roof line, and balconies on some tall fronts.
        let (p, q) = (side.at(s, 0.0, height - 0.45), side.at(s + w, 0.35, height));
        boxed(b, p, q, NEUTRAL, |seed, _, _, _| {
            Some(recipes::concrete(seed))
        });
        if height > 12.0 && unit(hash1(h, 4)) < 0.5 {
            for j in 0..2u64 {
                let hb = hash1(h, 10 + j);
                let s0 = s + range(hb, 1.0, (w - 3.5).max(1.0));
                let z0 = (range(hash1(hb, 1), 4.0, height - 3.0) / 3.4).floor() * 3.4 + 0.1;
                let (p, q) = (side.at(s0, 0.0, z0), side.at(s0 + 2.5, 1.0, z0 + 1.0));
                boxed(b, p, q, NEUTRAL, |seed, face, fw, fh| {
                    Some(match face {
                        Face::MaxZ | Face::MinZ => recipes::concrete(seed),
                        _ => recipes::painted(seed).with(Layer::Grid {
                            pitch_s: 0.12,
                            pitch_t: fh,
                            joint: 0.03,
                            joint_value: 0.15,
                            cell_variation: 0.05,
                            row_offset: 0.0,
                            random_length: fw < 0.0,
                        }),
                    })
                });
            }
        }
        s += w;
        k += 1;
    }
}

/// A parked car with its nose towards `along`, its centre at `c` (on the ground): a dark
/// underbody, a painted body and a glazed cabin.
fn car(b: &mut Builder, c: Vector3<f64>, along: &Vector3<f64>, h: u64) {
    let across = Vector3::z().cross(along);
    let length = range(h, 3.8, 4.8);
    let paint = [
        tint(1.0, 1.0, 1.0),
        tint(1.4, 0.8, 0.8),
        tint(0.8, 0.9, 1.4),
        tint(1.0, 1.0, 0.9),
        tint(0.9, 1.2, 0.9),
    ][(hash1(h, 1) % 5) as usize];
    let bright = range(hash1(h, 2), 0.4, 1.6) as f32;
    let paint = paint.map(|x| x * bright);
    let part = |l: f64, w: f64, z0: f64, z1: f64, dl: f64| {
        let p = c + along * (dl - l / 2.0) - across * (w / 2.0) + Vector3::z() * z0;
        let q = c + along * (dl + l / 2.0) + across * (w / 2.0) + Vector3::z() * z1;
        (p, q)
    };
    let (p, q) = part(length - 0.4, 1.55, 0.0, 0.35, 0.0);
    boxed(b, p, q, NEUTRAL, |seed, _, _, _| {
        Some(Material::plain(0.08, seed))
    });
    let (p, q) = part(length, 1.8, 0.35, 1.0, 0.0);
    boxed(b, p, q, paint, |seed, _, _, _| Some(recipes::painted(seed)));
    let (p, q) = part(0.55 * length, 1.55, 1.0, 1.45, -0.1 * length);
    boxed(b, p, q, NEUTRAL, |seed, face, _, _| {
        Some(if face == Face::MaxZ {
            recipes::painted(seed)
        } else {
            // Glass: dark, with the street's reflections.
            Material::plain(0.12, seed).with(Layer::Noise {
                amplitude: 0.1,
                largest: 0.6,
                smallest: 0.02,
                gain: 0.6,
                stretch: (0.3, 1.0),
            })
        })
    });
}

/// The street furniture of `side`: its pavement and kerb (reaching `ends` metres beyond the
/// side at its start and its end, round the block's corners), parked cars in its parking
/// strip, street trees (on `trees` streets) and lamp posts on the pavement.
fn street_side(b: &mut Builder, side: &Side, ends: (f64, f64), layout: u64, trees: bool) {
    let pave = FACADE - ROAD;
    // The pavement from the façade to the kerb, raised; the kerb towards the road.
    let (p, q) = (
        side.at(-ends.0, 0.0, KERB),
        side.at(side.length + ends.1, pave, KERB),
    );
    let (lo, hi) = (p.inf(&q), p.sup(&q));
    ground(
        b,
        (lo.x, lo.y, hi.x, hi.y),
        KERB,
        tint(1.05, 1.0, 0.95),
        |s, _, _| recipes::tiles(s, 0.3),
    );
    let (p, q) = (
        side.at(-ends.0.max(pave), pave - 0.15, 0.0),
        side.at(side.length + ends.1.max(pave), pave, KERB),
    );
    boxed(b, p, q, NEUTRAL, |seed, face, _, _| {
        (face != Face::MaxZ).then(|| recipes::concrete(seed))
    });
    // Parked cars, 6 m slots, about a third of them taken, most facing the traffic's way.
    let slots = ((side.length - 12.0) / 6.0).floor().max(0.0) as u64;
    for k in 0..slots {
        let h = hash1(layout ^ 0xca75, k);
        if unit(h) < 0.35 {
            let c = side.at(9.0 + 6.0 * k as f64, FACADE - (ROAD + PARKING) / 2.0, 0.0);
            let nose = if unit(hash1(h, 9)) < 0.9 {
                side.along
            } else {
                -side.along
            };
            car(b, c, &nose, hash1(h, 5));
        }
    }
    // Trees every 12 m on the tree-lined streets; lamp posts every 30 m.
    if trees {
        let mut s = 8.0;
        while s < side.length - 6.0 {
            let h = hash1(layout ^ 0x7ee, s as u64);
            let c = side.at(s, pave - 1.2, 0.0);
            let (r, top) = (0.15, range(h, 2.6, 3.4));
            boxed(
                b,
                c - v(r, r, 0.0),
                c + v(r, r, top),
                tint(1.2, 1.0, 0.8),
                |seed, _, _, _| Some(recipes::concrete(seed)),
            );
            let r = range(hash1(h, 1), 1.2, 1.6);
            let crown = top + range(hash1(h, 2), 2.5, 4.0);
            boxed(
                b,
                c + v(-r, -r, top),
                c + v(r, r, crown),
                tint(0.8, 1.2, 0.7),
                |seed, _, _, _| Some(recipes::foliage(seed)),
            );
            s += 12.0;
        }
    }
    let mut s = 14.0;
    while s < side.length - 6.0 {
        let c = side.at(s, pave - 0.4, 0.0);
        boxed(
            b,
            c - v(0.07, 0.07, 0.0),
            c + v(0.07, 0.07, 6.0),
            NEUTRAL,
            |seed, _, _, _| Some(recipes::painted(seed)),
        );
        let arm = c + side.out * 1.2;
        boxed(
            b,
            c + v(-0.1, -0.1, 5.8),
            arm + v(0.1, 0.1, 6.0),
            NEUTRAL,
            |seed, _, _, _| Some(recipes::painted(seed)),
        );
        s += 30.0;
    }
}

/// Zebra crossings across the street along `dir` (unit) at the junction `c`, on both
/// approaches; the centre line's dashes from `c` along `dir` for `length` metres.
fn markings(b: &mut Builder, c: Vector3<f64>, dir: &Vector3<f64>, length: f64) {
    let across = Vector3::z().cross(dir);
    let white = tint(1.0, 1.0, 1.0);
    let paint = |b: &mut Builder, p: Vector3<f64>, q: Vector3<f64>| {
        let (lo, hi) = (p.inf(&q), p.sup(&q));
        ground(b, (lo.x, lo.y, hi.x, hi.y), 0.004, white, |s, _, _| {
            recipes::plaster(s).with(Layer::Noise {
                amplitude: 0.08,
                largest: 0.5,
                smallest: 0.01,
                gain: 0.6,
                stretch: (1.0, 1.0),
            })
        });
    };
    // Zebra stripes: 0.5 m wide every metre across the road, 3 m long, beyond the junction's
    // pavements.
    for end in [FACADE + 0.5, length - FACADE - 3.5] {
        let mut d = -ROAD + 0.5;
        while d + 0.5 < ROAD {
            let p = c + dir * end + across * d;
            paint(b, p, p + dir * 3.0 + across * 0.5);
            d += 1.0;
        }
    }
    // Dashes: 3 m every 9 m between the crossings.
    let mut s = FACADE + 7.0;
    while s + 3.0 < length - FACADE - 5.0 {
        let p = c + dir * s - across * 0.06;
        paint(b, p, p + dir * 3.0 + across * 0.12);
        s += 9.0;
    }
}

/// The town; layout and textures seeded by `seed`. Texel 4 mm.
pub fn town(seed: u64) -> Scene {
    let mut b = Builder::new("town", 0.004, seed);
    let layout = hash1(seed, 0x746f776e);
    let xs = [
        TOWN_STREETS_X[0] - OUTSKIRTS,
        TOWN_STREETS_X[0],
        TOWN_STREETS_X[1],
        TOWN_STREETS_X[2],
        TOWN_STREETS_X[3],
        TOWN_STREETS_X[3] + OUTSKIRTS,
    ];
    let ys = [
        TOWN_STREETS_Y[0] - OUTSKIRTS,
        TOWN_STREETS_Y[0],
        TOWN_STREETS_Y[1],
        TOWN_STREETS_Y[2],
        TOWN_STREETS_Y[3],
        TOWN_STREETS_Y[3] + OUTSKIRTS,
    ];
    let street = |i: usize, n: usize| i > 0 && i < n - 1;
    // The ground: fields around the town, asphalt in it and along the roads out.
    ground(
        &mut b,
        (-1500.0, -1500.0, 1500.0, 1500.0),
        -0.02,
        tint(0.8, 1.1, 0.7),
        |s, _, _| recipes::grass(s),
    );
    ground(
        &mut b,
        (xs[0], ys[0], xs[5], ys[5]),
        0.0,
        NEUTRAL,
        |s, _, _| asphalt(s),
    );
    for &x in &TOWN_STREETS_X {
        for (y0, y1) in [(-1200.0, ys[0]), (ys[5], 1200.0)] {
            ground(
                &mut b,
                (x - ROAD, y0, x + ROAD, y1),
                0.0,
                NEUTRAL,
                |s, _, _| asphalt(s),
            );
        }
    }
    for &y in &TOWN_STREETS_Y {
        for (x0, x1) in [(-1200.0, xs[0]), (xs[5], 1200.0)] {
            ground(
                &mut b,
                (x0, y - ROAD, x1, y + ROAD),
                0.0,
                NEUTRAL,
                |s, _, _| asphalt(s),
            );
        }
    }
    // The blocks: a terrace and its pavement along every side that faces a street.
    let trees_x: Vec<bool> = (0..6).map(|i| unit(hash1(layout, 300 + i)) < 0.5).collect();
    let trees_y: Vec<bool> = (0..6).map(|i| unit(hash1(layout, 310 + i)) < 0.5).collect();
    for i in 0..5 {
        for j in 0..5 {
            let (x0, x1, y0, y1) = (xs[i], xs[i + 1], ys[j], ys[j + 1]);
            let (sw, se, ss, sn) = (
                street(i, 6),
                street(i + 1, 6),
                street(j, 6),
                street(j + 1, 6),
            );
            let inset = |s: bool| if s { FACADE } else { 0.0 };
            let (fx0, fx1, fy0, fy1) = (
                x0 + inset(sw),
                x1 - inset(se),
                y0 + inset(ss),
                y1 - inset(sn),
            );
            let block = hash1(layout, (i * 6 + j) as u64 + 1000);
            // South and north rows span the block; west and east rows fit between them.
            let (ry0, ry1) = (
                fy0 + if ss { DEPTH } else { 0.0 },
                fy1 - if sn { DEPTH } else { 0.0 },
            );
            let sides = [
                (
                    ss,
                    Side {
                        start: v(fx0, fy0, 0.0),
                        along: Vector3::x(),
                        out: -Vector3::y(),
                        length: fx1 - fx0,
                    },
                    trees_y[j],
                ),
                (
                    sn,
                    Side {
                        start: v(fx1, fy1, 0.0),
                        along: -Vector3::x(),
                        out: Vector3::y(),
                        length: fx1 - fx0,
                    },
                    trees_y[j + 1],
                ),
                (
                    sw,
                    Side {
                        start: v(fx0, ry1, 0.0),
                        along: -Vector3::y(),
                        out: -Vector3::x(),
                        length: ry1 - ry0,
                    },
                    trees_x[i],
                ),
                (
                    se,
                    Side {
                        start: v(fx1, ry0, 0.0),
                        along: Vector3::y(),
                        out: Vector3::x(),
                        length: ry1 - ry0,
                    },
                    trees_x[i + 1],
                ),
            ];
            for (k, (is_street, side, _)) in sides.iter().enumerate() {
                if !is_street || side.length < 5.0 {
                    continue;
                }
                terrace(&mut b, side, hash1(block, k as u64));
            }
            // Pavements: the west and east ones reach round the corners to the south and north
            // ones (one surface under every point, no two coplanar).
            let corner = DEPTH + FACADE - ROAD;
            let ends = [
                (0.0, 0.0),
                (0.0, 0.0),
                (if sn { corner } else { 0.0 }, if ss { corner } else { 0.0 }),
                (if ss { corner } else { 0.0 }, if sn { corner } else { 0.0 }),
            ];
            for (k, (is_street, side, trees)) in sides.iter().enumerate() {
                if *is_street && side.length >= 5.0 {
                    street_side(&mut b, side, ends[k], hash1(block, 10 + k as u64), *trees);
                }
            }
        }
    }
    // Crossings and centre lines on every stretch of street between junctions.
    for &x in &TOWN_STREETS_X {
        for w in TOWN_STREETS_Y.windows(2) {
            markings(&mut b, v(x, w[0], 0.0), &Vector3::y(), w[1] - w[0]);
        }
    }
    for &y in &TOWN_STREETS_Y {
        for w in TOWN_STREETS_X.windows(2) {
            markings(&mut b, v(w[0], y, 0.0), &Vector3::x(), w[1] - w[0]);
        }
    }
    // Distant towers, 500–900 m from the centre of town, all around.
    let centre = v(165.0, 120.0, 0.0);
    for k in 0..18u64 {
        let h = hash1(layout, 500 + k);
        let a = std::f64::consts::TAU * (k as f64 + range(h, -0.3, 0.3)) / 18.0;
        let r = range(hash1(h, 1), 500.0, 900.0);
        let (w, d, height) = (
            range(hash1(h, 2), 25.0, 60.0),
            range(hash1(h, 3), 20.0, 50.0),
            range(hash1(h, 4), 40.0, 130.0),
        );
        let c = centre + v(a.cos() * r, a.sin() * r, 0.0);
        let kind = hash1(h, 5);
        b.solid(
            c - v(w / 2.0, d / 2.0, 0.0),
            c + v(w / 2.0, d / 2.0, height),
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
        horizon: 0.015,
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
