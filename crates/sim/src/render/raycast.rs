//! The ray caster: the nearest quad along every pixel's ray, shaded from the texture tiles.
//!
//! Per view: every quad is moved into the camera frame, clipped to `z ≥ NEAR` and projected to
//! the normalised image plane; per [`TILE_PX`]² pixel tile the quads whose projection overlaps
//! the tile's ray bounds are kept (separating-axis test), sorted by a lower bound of their depth
//! over the tile, and those lying entirely behind a quad that covers the whole tile are dropped.
//!
//! A ray `z·d` with `d = (x, y, 1)` meets the plane `n·p = h` of a quad at depth
//! `z = h/(n·d)` (so the rendered depth *is* the exact ray–plane intersection, no depth buffer
//! quantisation), at texture coordinates `s = z·(a·d) − a·o`, `t = z·(b·d) − b·o`.
//!
//! Anti-aliasing: the centre ray of every pixel is cast first; pixels whose centre hit differs
//! from one of their eight neighbours' (silhouettes, quad borders) are supersampled with an
//! `S × S` grid of rays, and each quad met is shaded once, at the mean of its rays, weighted by
//! its share of them (multisampling: the coverage of the edge is exact to `1/S²`, the shading
//! is the surface's filtered texture); the texture itself is pre-filtered (trilinear mip-mapping with the
//! pixel's footprint on the surface, `|∂p/∂u|` and `|∂p/∂v|` from
//! `∂p/∂u = z·(∂d/∂u − d·(n·∂d/∂u)/(n·d))`), which is what supersampling would converge to
//! inside a surface, at one lookup per pixel.

use super::cache::TextureCache;
use super::camera::{RayTable, TILE_PX};
use super::procedural::fast_log2;
use super::scene::Scene;
use lie::Se3;
use nalgebra::Vector3;
use rayon::prelude::*;

/// Nearest depth rendered (m); the quads are clipped there.
pub const NEAR: f64 = 1e-3;
/// Hit index of rays that meet no quad (sky or background).
pub(crate) const NO_HIT: u32 = u32::MAX;
/// Tolerance on the texture-coordinate bounds (m), against cracks between quads that share an
/// edge.
const EDGE_EPS: f64 = 1e-9;

/// A quad in the camera frame.
#[derive(Debug, Clone, Copy)]
struct CamQuad {
    id: u32,
    n: [f64; 3],
    h: f64,
    a: [f64; 3],
    b: [f64; 3],
    oa: f64,
    ob: f64,
    w: f64,
    hgt: f64,
}

/// A quad in one tile's list: which, and the lower bound of its depth over the tile.
#[derive(Debug, Clone, Copy)]
struct Candidate {
    quad: u32,
    min_z: f64,
}

/// The nearest hit of a ray.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Hit {
    /// Index into the prepared quads (`NO_HIT` for none).
    pub quad: u32,
    pub z: f64,
    /// `1/(n·d)`.
    pub inv_nd: f64,
    pub s: f64,
    pub t: f64,
}

const MISS: Hit = Hit {
    quad: NO_HIT,
    z: f64::INFINITY,
    inv_nd: 0.0,
    s: 0.0,
    t: 0.0,
};

/// What a view renders per pixel.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Pixel {
    /// Radiance (colour channels, or the grey value in channel 0 for grey views).
    pub radiance: [f32; 3],
    /// Depth `z` of the pixel centre's hit (`0` where nothing is hit).
    pub depth: f32,
    /// Cosine between the centre ray and the surface normal (`0` where nothing is hit).
    pub cos_incidence: f32,
}

/// Options of one view.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ViewOptions {
    /// Supersampling grid `S` per axis at silhouettes (1: none).
    pub supersampling: usize,
    /// Colour radiance (else grey: radiance times the tint's luma, in channel 0).
    pub colour: bool,
    /// Fill [`Pixel::depth`] and [`Pixel::cos_incidence`] (else they stay 0).
    pub depth: bool,
}

struct Prepared {
    quads: Vec<CamQuad>,
    /// Per tile, the range of its candidates in `cands`.
    offsets: Vec<u32>,
    cands: Vec<Candidate>,
    /// Per tile: its only candidate when that one covers the whole tile (every ray of the
    /// tile meets it), else `NO_HIT`.
    sole: Vec<u32>,
    /// Rotation `world_from_camera` (for sky directions).
    r_wc: nalgebra::Matrix3<f64>,
}

#[inline(always)]
fn dot(a: &[f64; 3], x: f64, y: f64) -> f64 {
    a[0] * x + a[1] * y + a[2]
}

/// Luma of a tint (Rec. 601 weights, as grey conversions of the readers use).
pub(crate) fn luma(t: &[f32; 3]) -> f32 {
    0.299 * t[0] + 0.587 * t[1] + 0.114 * t[2]
}

fn prepare(scene: &Scene, rays: &RayTable, camera_from_world: &Se3) -> Prepared {
    let r = camera_from_world.rotation().rotation_matrix();
    let tr = *camera_from_world.translation();
    let mut quads = Vec::new();
    let mut polys: Vec<(Vec<[f64; 2]>, f64)> = Vec::new();
    for (i, q) in scene.quads.iter().enumerate() {
        let o = r * q.origin + tr;
        let n = r * q.normal();
        let h = n.dot(&o);
        if h >= -1e-12 {
            continue; // the camera is behind (or in) the quad's plane
        }
        let corners = q.corners().map(|c| r * c + tr);
        let clipped = clip_near(&corners);
        if clipped.len() < 3 {
            continue;
        }
        let min_z = clipped.iter().map(|p| p.z).fold(f64::INFINITY, f64::min);
        let poly: Vec<[f64; 2]> = clipped.iter().map(|p| [p.x / p.z, p.y / p.z]).collect();
        let (a, b) = (r * q.axis_s, r * q.axis_t);
        quads.push(CamQuad {
            id: i as u32,
            n: [n.x, n.y, n.z],
            h,
            a: [a.x, a.y, a.z],
            b: [b.x, b.y, b.z],
            oa: a.dot(&o),
            ob: b.dot(&o),
            w: q.width,
            hgt: q.height,
        });
        polys.push((poly, min_z));
    }
    // Bin into tiles.
    let (tw, th) = rays.tiles;
    let mut offsets = Vec::with_capacity(tw * th + 1);
    let mut sole = Vec::with_capacity(tw * th);
    let mut cands = Vec::new();
    let mut tile: Vec<(Candidate, bool, f64)> = Vec::new();
    let bboxes: Vec<[f64; 4]> = polys
        .iter()
        .map(|(p, _)| {
            let mut b = [f64::INFINITY, f64::INFINITY, -f64::INFINITY, -f64::INFINITY];
            for v in p {
                b[0] = b[0].min(v[0]);
                b[1] = b[1].min(v[1]);
                b[2] = b[2].max(v[0]);
                b[3] = b[3].max(v[1]);
            }
            b
        })
        .collect();
    for tb in &rays.tile_bounds {
        offsets.push(cands.len() as u32);
        tile.clear();
        let rect = [
            [tb[0], tb[1]],
            [tb[2], tb[1]],
            [tb[2], tb[3]],
            [tb[0], tb[3]],
        ];
        for (k, ((poly, poly_min_z), bb)) in polys.iter().zip(&bboxes).enumerate() {
            if bb[2] < tb[0] || bb[0] > tb[2] || bb[3] < tb[1] || bb[1] > tb[3] {
                continue;
            }
            let Some(covers) = overlap(poly, &rect) else {
                continue;
            };
            let cq = &quads[k];
            let nd = rect.map(|c| dot(&cq.n, c[0], c[1]));
            let nd_min = nd.iter().copied().fold(f64::INFINITY, f64::min);
            let nd_max = nd.iter().copied().fold(-f64::INFINITY, f64::max);
            if nd_min >= 0.0 {
                continue; // no ray of the tile meets the front side
            }
            let min_z = (cq.h / nd_min).max(*poly_min_z);
            let max_z = if nd_max < 0.0 {
                cq.h / nd_max
            } else {
                f64::INFINITY
            };
            tile.push((
                Candidate {
                    quad: k as u32,
                    min_z,
                },
                covers,
                max_z,
            ));
        }
        // Occlusion: a quad covering the whole tile hides everything beyond its farthest point.
        let occluder = tile
            .iter()
            .filter(|c| c.1)
            .map(|c| c.2)
            .fold(f64::INFINITY, f64::min);
        tile.retain(|c| c.0.min_z <= occluder);
        tile.sort_by(|x, y| {
            x.0.min_z
                .total_cmp(&y.0.min_z)
                .then(x.0.quad.cmp(&y.0.quad))
        });
        sole.push(if tile.len() == 1 && tile[0].1 {
            tile[0].0.quad
        } else {
            NO_HIT
        });
        cands.extend(tile.iter().map(|c| c.0));
    }
    offsets.push(cands.len() as u32);
    Prepared {
        quads,
        offsets,
        cands,
        sole,
        r_wc: r.transpose(),
    }
}

/// Clips a convex polygon in the camera frame to `z ≥ NEAR` (Sutherland–Hodgman, one plane).
fn clip_near(poly: &[Vector3<f64>]) -> Vec<Vector3<f64>> {
    let mut out = Vec::with_capacity(poly.len() + 1);
    for i in 0..poly.len() {
        let (p, q) = (poly[i], poly[(i + 1) % poly.len()]);
        let (pin, qin) = (p.z >= NEAR, q.z >= NEAR);
        if pin {
            out.push(p);
        }
        if pin != qin {
            let t = (NEAR - p.z) / (q.z - p.z);
            let mut x = p + (q - p) * t;
            x.z = NEAR;
            out.push(x);
        }
    }
    out
}

/// Separating-axis test of a convex polygon against a rectangle (given as its four corners):
/// `None` if they are disjoint, else whether the polygon covers the whole rectangle.
fn overlap(poly: &[[f64; 2]], rect: &[[f64; 2]; 4]) -> Option<bool> {
    // Orientation of the polygon.
    let mut area = 0.0;
    for i in 0..poly.len() {
        let (p, q) = (poly[i], poly[(i + 1) % poly.len()]);
        area += p[0] * q[1] - q[0] * p[1];
    }
    let sign = if area >= 0.0 { 1.0 } else { -1.0 };
    let mut covers = true;
    for i in 0..poly.len() {
        let (p, q) = (poly[i], poly[(i + 1) % poly.len()]);
        let (ex, ey) = (q[0] - p[0], q[1] - p[1]);
        let mut inside = 0;
        for c in rect {
            let cross = sign * (ex * (c[1] - p[1]) - ey * (c[0] - p[0]));
            if cross >= 0.0 {
                inside += 1;
            }
        }
        if inside == 0 {
            return None;
        }
        if inside < 4 {
            covers = false;
        }
    }
    Some(covers)
}

impl Prepared {
    #[inline(always)]
    fn cast(&self, tile: usize, x: f64, y: f64) -> u32 {
        // Division-free: with n·d < 0 and h < 0 (the front side), z = h/(n·d) > 0 and every
        // test on z, s and t is multiplied through by n·d (flipping the inequalities); the
        // nearest hit so far is kept as the fraction (h_b, nd_b).
        let (a, b) = (self.offsets[tile] as usize, self.offsets[tile + 1] as usize);
        let (mut best, mut h_b, mut nd_b) = (NO_HIT, -1.0, -0.0);
        for c in &self.cands[a..b] {
            // Candidates are sorted by their lowest depth over the tile: stop once it is
            // beyond the nearest hit (c.min_z ≥ h_b/nd_b).
            if best != NO_HIT && c.min_z * nd_b <= h_b {
                break;
            }
            let q = &self.quads[c.quad as usize];
            let nd = dot(&q.n, x, y);
            if nd >= 0.0 {
                continue;
            }
            // z ≥ NEAR, and nearer than the best: h/nd < h_b/nd_b ⟺ h·nd_b < h_b·nd.
            if q.h > NEAR * nd || (best != NO_HIT && q.h * nd_b >= h_b * nd) {
                continue;
            }
            // s = h·(a·d)/nd − a·o ∈ [−ε, w + ε].
            let sa = q.h * dot(&q.a, x, y);
            if sa > nd * (q.oa - EDGE_EPS) || sa < nd * (q.oa + q.w + EDGE_EPS) {
                continue;
            }
            let tb = q.h * dot(&q.b, x, y);
            if tb > nd * (q.ob - EDGE_EPS) || tb < nd * (q.ob + q.hgt + EDGE_EPS) {
                continue;
            }
            best = c.quad;
            h_b = q.h;
            nd_b = nd;
        }
        best
    }

    /// The intersection of the ray `(x, y, 1)` with prepared quad `q`'s plane (no bounds
    /// check), or a miss for `NO_HIT`.
    #[inline(always)]
    fn hit_on(&self, q: u32, x: f64, y: f64) -> Hit {
        if q == NO_HIT {
            return MISS;
        }
        let cq = &self.quads[q as usize];
        let inv_nd = 1.0 / dot(&cq.n, x, y);
        let z = cq.h * inv_nd;
        Hit {
            quad: q,
            z,
            inv_nd,
            s: z * dot(&cq.a, x, y) - cq.oa,
            t: z * dot(&cq.b, x, y) - cq.ob,
        }
    }

    /// Squared footprint (m²) on the hit's surface of a pixel with ray Jacobian `j`: the larger
    /// of `|∂p/∂u|²` and `|∂p/∂v|²` (see the module notes).
    #[inline(always)]
    fn footprint2(&self, hit: &Hit, x: f64, y: f64, j: &[f64; 4]) -> f64 {
        let q = &self.quads[hit.quad as usize];
        let inv_nd = hit.inv_nd;
        let len2 = |du0: f64, du1: f64| {
            let k = (q.n[0] * du0 + q.n[1] * du1) * inv_nd;
            let v = [du0 - x * k, du1 - y * k, -k];
            v[0] * v[0] + v[1] * v[1] + v[2] * v[2]
        };
        hit.z * hit.z * len2(j[0], j[2]).max(len2(j[1], j[3]))
    }
}

/// Renders one view of `scene` from `camera_from_world` (rows in parallel with rayon).
pub(crate) fn render_view(
    scene: &Scene,
    cache: &TextureCache,
    rays: &RayTable,
    camera_from_world: &Se3,
    opts: &ViewOptions,
) -> Vec<Pixel> {
    let prep = prepare(scene, rays, camera_from_world);
    let (w, h) = (rays.width, rays.height);
    let mut out = vec![Pixel::default(); w * h];
    let ss = opts.supersampling.max(1);
    let tint: Vec<[f32; 3]> = prep
        .quads
        .iter()
        .map(|q| {
            let t = scene.quads[q.id as usize].tint;
            if opts.colour { t } else { [luma(&t), 0.0, 0.0] }
        })
        .collect();
    let inv_texel2 = 1.0 / (scene.texel * scene.texel);
    // The mip level λ = log₂(footprint/τ₀) of a hit.
    let level = |hit: &Hit, x: f64, y: f64, j: &[f64; 4], spacing: f64| {
        let fp2 = prep.footprint2(hit, x, y, j) * (spacing * spacing * inv_texel2);
        0.5 * fast_log2(fp2.max(1e-300))
    };
    let shade = |sampler: &mut super::cache::Sampler,
                 hit: &Hit,
                 x: f64,
                 y: f64,
                 j: &[f64; 4],
                 spacing: f64|
     -> [f32; 3] {
        if hit.quad == NO_HIT {
            let Some(sky) = &scene.sky else {
                return [0.0; 3];
            };
            let d = prep.r_wc * Vector3::new(x, y, 1.0);
            let norm = d.norm();
            let footprint = spacing
                * (j[0] * j[0] + j[2] * j[2])
                    .sqrt()
                    .max((j[1] * j[1] + j[3] * j[3]).sqrt())
                / norm;
            let v = sky.radiance(&(d / norm), footprint) as f32;
            return if opts.colour {
                [v * 0.92, v * 0.98, v * 1.12]
            } else {
                [v, 0.0, 0.0]
            };
        }
        let lambda = level(hit, x, y, j, spacing);
        let q = &prep.quads[hit.quad as usize];
        let v = sampler.sample_level(q.id as usize, hit.s, hit.t, lambda);
        let t = &tint[hit.quad as usize];
        [v * t[0], v * t[1], v * t[2]]
    };
    out.par_chunks_mut(w * TILE_PX)
        .enumerate()
        .for_each(|(band, chunk)| {
            let r0 = band * TILE_PX;
            let r1 = (r0 + TILE_PX).min(h);
            let mut sampler = cache.sampler(scene);
            // Which quad the centre ray of each pixel of the band's rows (and one row above and
            // below) meets; the hits themselves are recomputed from the plane when shading,
            // which keeps this buffer small enough to stay in cache.
            let (h0, h1) = (r0.saturating_sub(1), (r1 + 1).min(h));
            let mut ids = vec![NO_HIT; (h1 - h0) * w];
            for v in h0..h1 {
                for u in 0..w {
                    let c = rays.centre[v * w + u];
                    let tile = (v / TILE_PX) * rays.tiles.0 + u / TILE_PX;
                    let sole = prep.sole[tile];
                    ids[(v - h0) * w + u] = if sole != NO_HIT {
                        sole
                    } else {
                        prep.cast(tile, c[0], c[1])
                    };
                }
            }
            // Shade tile by tile, so that the texture tiles a pixel tile needs stay in cache.
            for u0 in (0..w).step_by(TILE_PX) {
                let u1 = (u0 + TILE_PX).min(w);
                let tile = band * rays.tiles.0 + u0 / TILE_PX;
                let sole = prep.sole[tile];
                // The mip level λ of each quad of the tile is interpolated bilinearly from its
                // values at the tile's corners (λ is the logarithm of a smooth function of the
                // pixel; the interpolation error is far below the level blending's resolution)
                // unless the quad's plane is seen edge-on within the tile (a corner ray misses
                // its front, or λ changes by more than two levels across the tile), where it is
                // computed per pixel. In a tile covered by one quad only the border pixels can
                // be edges.
                let (ca, cb) = (prep.offsets[tile] as usize, prep.offsets[tile + 1] as usize);
                let mut corner_lambda = [(NO_HIT, [0.0f64; 4]); 16];
                let n_corner = (cb - ca).min(16);
                let corner_ray = |u: usize, v: usize, du: f64, dv: f64| {
                    let (c, j) = (rays.centre[v * w + u], &rays.jacobian[v * w + u]);
                    (
                        c[0] + j[0] * du + j[1] * dv,
                        c[1] + j[2] * du + j[3] * dv,
                        *j,
                    )
                };
                let corners = [
                    corner_ray(u0, r0, -0.5, -0.5),
                    corner_ray(u1 - 1, r0, 0.5, -0.5),
                    corner_ray(u0, r1 - 1, -0.5, 0.5),
                    corner_ray(u1 - 1, r1 - 1, 0.5, 0.5),
                ];
                for (slot, cand) in corner_lambda.iter_mut().zip(&prep.cands[ca..ca + n_corner]) {
                    let q = &prep.quads[cand.quad as usize];
                    if corners.iter().any(|(x, y, _)| dot(&q.n, *x, *y) >= 0.0) {
                        continue;
                    }
                    let l = corners
                        .map(|(x, y, j)| level(&prep.hit_on(cand.quad, x, y), x, y, &j, 1.0));
                    let (lo, hi) = l
                        .iter()
                        .fold((f64::INFINITY, -f64::INFINITY), |(a, b), &x| {
                            (a.min(x), b.max(x))
                        });
                    if hi - lo <= 2.0 {
                        *slot = (cand.quad, l);
                    }
                }
                let (inv_tw, inv_th) = (1.0 / (u1 - u0) as f64, 1.0 / (r1 - r0) as f64);
                let lambda_at = |id: u32, u: usize, v: usize| -> Option<f64> {
                    let l = corner_lambda[..n_corner].iter().find(|c| c.0 == id)?.1;
                    let a = ((u - u0) as f64 + 0.5) * inv_tw;
                    let b = ((v - r0) as f64 + 0.5) * inv_th;
                    Some(
                        (1.0 - b) * ((1.0 - a) * l[0] + a * l[1])
                            + b * ((1.0 - a) * l[2] + a * l[3]),
                    )
                };
                for v in r0..r1 {
                    for u in u0..u1 {
                        let idx = v * w + u;
                        let c = rays.centre[idx];
                        let j = &rays.jacobian[idx];
                        let id = ids[(v - h0) * w + u];
                        let hit = prep.hit_on(id, c[0], c[1]);
                        let interior =
                            sole != NO_HIT && u > u0 && u + 1 < u1 && v > r0 && v + 1 < r1;
                        // An edge pixel: a neighbour's centre meets another quad (neighbours
                        // outside the image are clamped to the pixel itself).
                        let (ul, ur) = (u.saturating_sub(1), (u + 1).min(w - 1));
                        let (ra, rb, rc) = (
                            (v.saturating_sub(1).max(h0) - h0) * w,
                            (v - h0) * w,
                            ((v + 1).min(h1 - 1) - h0) * w,
                        );
                        let edge = !interior
                            && (ids[ra + ul] != id
                                || ids[ra + u] != id
                                || ids[ra + ur] != id
                                || ids[rb + ul] != id
                                || ids[rb + ur] != id
                                || ids[rc + ul] != id
                                || ids[rc + u] != id
                                || ids[rc + ur] != id);
                        let radiance = if !edge || ss == 1 {
                            match (id != NO_HIT).then(|| lambda_at(id, u, v)).flatten() {
                                Some(lambda) => {
                                    let q = prep.quads[id as usize].id as usize;
                                    let value = sampler.sample_level(q, hit.s, hit.t, lambda);
                                    let t = &tint[id as usize];
                                    [value * t[0], value * t[1], value * t[2]]
                                }
                                None => shade(&mut sampler, &hit, c[0], c[1], j, 1.0),
                            }
                        } else {
                            // Coverage from S×S rays, shading once per quad met (at the mean of its
                            // rays, with the pixel's footprint) — multisampling.
                            let mut groups: [(u32, u32, f64, f64); 64] =
                                [(NO_HIT, 0, 0.0, 0.0); 64];
                            let mut n_groups = 0;
                            let inv = 1.0 / ss as f64;
                            for sj in 0..ss {
                                let dv = (sj as f64 + 0.5) * inv - 0.5;
                                for si in 0..ss {
                                    let du = (si as f64 + 0.5) * inv - 0.5;
                                    let x = c[0] + j[0] * du + j[1] * dv;
                                    let y = c[1] + j[2] * du + j[3] * dv;
                                    let q = prep.cast(tile, x, y);
                                    let g = match groups[..n_groups].iter().position(|g| g.0 == q) {
                                        Some(g) => g,
                                        None => {
                                            groups[n_groups].0 = q;
                                            n_groups += 1;
                                            n_groups - 1
                                        }
                                    };
                                    groups[g].1 += 1;
                                    groups[g].2 += x;
                                    groups[g].3 += y;
                                }
                            }
                            let mut acc = [0.0f32; 3];
                            for &(q, count, sx, sy) in &groups[..n_groups] {
                                let (x, y) = (sx / count as f64, sy / count as f64);
                                let sub = prep.hit_on(q, x, y);
                                let r = shade(&mut sampler, &sub, x, y, j, 1.0);
                                let k = count as f32;
                                acc[0] += k * r[0];
                                acc[1] += k * r[1];
                                acc[2] += k * r[2];
                            }
                            let k = (inv * inv) as f32;
                            [acc[0] * k, acc[1] * k, acc[2] * k]
                        };
                        let px = &mut chunk[(v - r0) * w + u];
                        px.radiance = radiance;
                        if opts.depth && hit.quad != NO_HIT {
                            px.depth = hit.z as f32;
                            let q = &prep.quads[hit.quad as usize];
                            let nd = dot(&q.n, c[0], c[1]);
                            px.cos_incidence =
                                (-nd / (c[0] * c[0] + c[1] * c[1] + 1.0).sqrt()) as f32;
                        }
                    }
                }
            }
        });
    out
}

/// The exact depth `z` of the nearest quad along the ray through the normalised point `(x, y)`
/// of a camera at `camera_from_world`, by brute force over all quads (a reference for tests,
/// independent of the binning). `None` if no quad is hit.
pub fn reference_depth(
    scene: &Scene,
    camera_from_world: &Se3,
    x: f64,
    y: f64,
) -> Option<(f64, usize)> {
    let r = camera_from_world.rotation().rotation_matrix();
    let tr = *camera_from_world.translation();
    let d = Vector3::new(x, y, 1.0);
    let mut best: Option<(f64, usize)> = None;
    for (i, q) in scene.quads.iter().enumerate() {
        let o = r * q.origin + tr;
        let n = r * q.normal();
        let nd = n.dot(&d);
        let h = n.dot(&o);
        if h >= 0.0 || nd >= 0.0 {
            continue;
        }
        let z = h / nd;
        if z < NEAR {
            continue;
        }
        let p = d * z - o;
        let (s, t) = (p.dot(&(r * q.axis_s)), p.dot(&(r * q.axis_t)));
        if s < -EDGE_EPS || s > q.width + EDGE_EPS || t < -EDGE_EPS || t > q.height + EDGE_EPS {
            continue;
        }
        if best.is_none_or(|(bz, _)| z < bz) {
            best = Some((z, i));
        }
    }
    best
}
