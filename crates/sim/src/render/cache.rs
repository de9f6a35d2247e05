//! Mip-mapped texture tiles, generated on first use and evicted when unused ("virtual
//! texturing").
//!
//! Evaluating a layered procedural material costs 0.1–1 µs; a frame needs ~10⁶ texture samples
//! of 8 texels each. Texels are therefore evaluated once, into tiles of `32 × 32` texels (plus a
//! one-texel apron so that a bilinear lookup never straddles two tiles) per quad and mip level,
//! and looked up afterwards. Level `l` holds the material band-limited to texels of
//! `τ_l = τ₀·2ˡ` ([`Material::albedo`](super::texture::Material::albedo)) times the baked
//! irradiance. A tile's contents are a pure function of `(quad, level, tile)`: which thread
//! generates it, and whether it was evicted and regenerated, never changes an image.
//!
//! Slots are `OnceLock`s, so rendering threads share the cache without a lock; eviction runs
//! between frames with exclusive access.

use super::procedural::fast_log2;
use super::scene::{Lighting, Quad, Scene};
use std::sync::OnceLock;
use std::sync::atomic::{AtomicU32, AtomicUsize, Ordering};

/// Texels per tile side (without the apron).
pub const TILE: usize = 32;
const STRIDE: usize = TILE + 1;
/// Radiance of a stored texel is `value / TEXEL_SCALE` (u16 texels, radiance in `[0, 2)`).
const TEXEL_SCALE: f32 = 32768.0;
const TILE_BYTES: usize = STRIDE * STRIDE * 2;

struct Level {
    texel: f64,
    inv_texel: f64,
    /// Texels along `s` and `t`.
    n: (usize, usize),
    /// Tiles along `s` and in all.
    tiles_s: usize,
    count: usize,
    /// The level's slots, allocated on the level's first use (levels finer than a far quad
    /// ever needs cost nothing).
    slots: OnceLock<Slots>,
}

struct Slots {
    tiles: Box<[OnceLock<Box<[u16]>>]>,
    used: Box<[AtomicU32]>,
}

struct QuadLevels {
    levels: Vec<Level>,
    /// The scene's lighting with only the point lights that reach this quad's front.
    lighting: Lighting,
}

/// The tiles of every quad of a scene (see the module notes).
pub struct TextureCache {
    quads: Vec<QuadLevels>,
    bytes: AtomicUsize,
    frame: u32,
    budget: usize,
    generated: AtomicUsize,
    generation_ns: std::sync::atomic::AtomicU64,
}

impl std::fmt::Debug for TextureCache {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("TextureCache")
            .field("bytes", &self.bytes.load(Ordering::Relaxed))
            .field("budget", &self.budget)
            .field("frame", &self.frame)
            .finish()
    }
}

impl TextureCache {
    /// An empty cache for `scene`'s quads holding at most about `budget` bytes of tiles.
    pub fn new(scene: &Scene, budget: usize) -> Self {
        let quads = scene
            .quads
            .iter()
            .map(|q| {
                let mut levels = Vec::new();
                let mut texel = scene.texel;
                loop {
                    let n = (
                        ((q.width / texel).ceil() as usize).max(1),
                        ((q.height / texel).ceil() as usize).max(1),
                    );
                    let tiles = (n.0.div_ceil(TILE), n.1.div_ceil(TILE));
                    let count = tiles.0 * tiles.1;
                    levels.push(Level {
                        texel,
                        inv_texel: 1.0 / texel,
                        n,
                        tiles_s: tiles.0,
                        count,
                        slots: OnceLock::new(),
                    });
                    if n.0 <= TILE && n.1 <= TILE {
                        break;
                    }
                    texel *= 2.0;
                }
                QuadLevels {
                    levels,
                    lighting: quad_lighting(&scene.lighting, q),
                }
            })
            .collect();
        TextureCache {
            quads,
            bytes: AtomicUsize::new(0),
            frame: 1,
            budget,
            generated: AtomicUsize::new(0),
            generation_ns: std::sync::atomic::AtomicU64::new(0),
        }
    }

    /// Number of mip levels of quad `q`.
    pub fn levels(&self, q: usize) -> usize {
        self.quads[q].levels.len()
    }

    /// Bytes held in tiles.
    pub fn bytes(&self) -> usize {
        self.bytes.load(Ordering::Relaxed)
    }

    /// Number of tiles generated so far (including regenerated ones).
    pub fn generated(&self) -> usize {
        self.generated.load(Ordering::Relaxed)
    }

    /// Total time spent generating tiles (seconds, summed over threads).
    pub fn generation_seconds(&self) -> f64 {
        self.generation_ns.load(Ordering::Relaxed) as f64 * 1e-9
    }

    /// Trilinear lookup of quad `q` at texture coordinates `(s, t)` for a footprint of
    /// `footprint` metres: level `λ = log₂(footprint/τ₀)`, bilinear on levels `⌊λ⌋` and
    /// `⌊λ⌋ + 1` blended by `λ − ⌊λ⌋` (clamped to the existing levels).
    #[inline]
    pub fn sample(&self, scene: &Scene, q: usize, s: f64, t: f64, footprint: f64) -> f32 {
        let r = footprint / scene.texel;
        self.sample_squared(scene, q, s, t, r * r)
    }

    /// [`sample`](Self::sample) with the squared footprint in level-0 texels,
    /// `(footprint/τ₀)²` (saves the square root).
    #[inline]
    pub fn sample_squared(&self, scene: &Scene, q: usize, s: f64, t: f64, footprint2: f64) -> f32 {
        let quad = &self.quads[q];
        let top = quad.levels.len() - 1;
        let lambda = 0.5 * fast_log2(footprint2.max(1e-300));
        if lambda <= 0.0 {
            return self.bilinear(scene, q, 0, s, t);
        }
        let l0 = lambda.floor() as usize;
        if l0 >= top {
            return self.bilinear(scene, q, top, s, t);
        }
        let f = (lambda - l0 as f64) as f32;
        let a = self.bilinear(scene, q, l0, s, t);
        let b = self.bilinear(scene, q, l0 + 1, s, t);
        a + f * (b - a)
    }

    /// Bilinear lookup on one level (texel centres at `(i + ½)·τ_l`, clamped to the quad's
    /// texels).
    #[inline]
    pub fn bilinear(&self, scene: &Scene, q: usize, level: usize, s: f64, t: f64) -> f32 {
        let lv = &self.quads[q].levels[level];
        let x = (s * lv.inv_texel - 0.5).clamp(0.0, (lv.n.0 - 1) as f64);
        let y = (t * lv.inv_texel - 0.5).clamp(0.0, (lv.n.1 - 1) as f64);
        let (xi, yi) = (x as usize, y as usize);
        let (fx, fy) = ((x - xi as f64) as f32, (y - yi as f64) as f32);
        let (tx, ty) = (xi / TILE, yi / TILE);
        let slot = ty * lv.tiles_s + tx;
        let tile = self.tile(scene, q, level, slot, tx, ty);
        let (lx, ly) = (xi - tx * TILE, yi - ty * TILE);
        let i = ly * STRIDE + lx;
        let (a, b, c, d) = (
            tile[i] as f32,
            tile[i + 1] as f32,
            tile[i + STRIDE] as f32,
            tile[i + STRIDE + 1] as f32,
        );
        let top = a + fx * (b - a);
        let bottom = c + fx * (d - c);
        (top + fy * (bottom - top)) * (1.0 / TEXEL_SCALE)
    }

    /// A sampler for one thread (see [`Sampler`]).
    pub fn sampler<'a>(&'a self, scene: &'a Scene) -> Sampler<'a> {
        Sampler {
            cache: self,
            scene,
            memo: [Memo::EMPTY; 2],
        }
    }

    #[inline]
    fn tile(
        &self,
        scene: &Scene,
        q: usize,
        level: usize,
        slot: usize,
        tx: usize,
        ty: usize,
    ) -> &[u16] {
        let lv = &self.quads[q].levels[level];
        let slots = lv.slots.get_or_init(|| Slots {
            tiles: (0..lv.count).map(|_| OnceLock::new()).collect(),
            used: (0..lv.count).map(|_| AtomicU32::new(0)).collect(),
        });
        let used = &slots.used[slot];
        if used.load(Ordering::Relaxed) != self.frame {
            used.store(self.frame, Ordering::Relaxed);
        }
        slots.tiles[slot].get_or_init(|| {
            self.bytes.fetch_add(TILE_BYTES, Ordering::Relaxed);
            self.generated.fetch_add(1, Ordering::Relaxed);
            let start = std::time::Instant::now();
            let tile = generate(scene, &self.quads[q].lighting, q, lv.texel, tx, ty);
            self.generation_ns
                .fetch_add(start.elapsed().as_nanos() as u64, Ordering::Relaxed);
            tile
        })
    }

    /// Marks the end of a frame: tiles not used in this frame become candidates for eviction,
    /// oldest first, once the cache holds more than its budget (down to ¾ of it). Tiles used in
    /// the frame just finished are kept.
    pub fn end_frame(&mut self) {
        let frame = self.frame;
        self.frame = self.frame.wrapping_add(1).max(1);
        if *self.bytes.get_mut() <= self.budget {
            return;
        }
        let mut loaded: Vec<(u32, usize, usize, usize)> = Vec::new();
        for (q, ql) in self.quads.iter_mut().enumerate() {
            for (l, lv) in ql.levels.iter_mut().enumerate() {
                let Some(slots) = lv.slots.get_mut() else {
                    continue;
                };
                for (i, tile) in slots.tiles.iter_mut().enumerate() {
                    let used = *slots.used[i].get_mut();
                    if tile.get().is_some() && used != frame {
                        loaded.push((used, q, l, i));
                    }
                }
            }
        }
        loaded.sort_unstable();
        let target = self.budget / 4 * 3;
        for (_, q, l, i) in loaded {
            if *self.bytes.get_mut() <= target {
                break;
            }
            let slots = self.quads[q].levels[l]
                .slots
                .get_mut()
                .expect("listed above");
            if slots.tiles[i].take().is_some() {
                *self.bytes.get_mut() -= TILE_BYTES;
            }
        }
    }
}

/// The last tile a [`Sampler`] used on one level parity (trilinear lookups alternate between
/// an even and an odd level, and neighbouring pixels mostly fall into the same tiles).
#[derive(Clone, Copy)]
struct Memo<'a> {
    q: usize,
    level: usize,
    inv_texel: f64,
    max: (f64, f64),
    tiles_s: usize,
    tile_xy: (usize, usize),
    tile: &'a [u16],
}

impl Memo<'_> {
    const EMPTY: Memo<'static> = Memo {
        q: usize::MAX,
        level: usize::MAX,
        inv_texel: 0.0,
        max: (0.0, 0.0),
        tiles_s: 0,
        tile_xy: (usize::MAX, usize::MAX),
        tile: &[],
    };
}

/// Lookups of one thread: the same results as [`TextureCache::sample`], with the last tile of
/// each level parity remembered, which saves the slot lookups for most pixels.
pub struct Sampler<'a> {
    cache: &'a TextureCache,
    scene: &'a Scene,
    memo: [Memo<'a>; 2],
}

impl<'a> Sampler<'a> {
    /// [`TextureCache::sample_squared`].
    #[inline]
    pub fn sample_squared(&mut self, q: usize, s: f64, t: f64, footprint2: f64) -> f32 {
        self.sample_level(q, s, t, 0.5 * fast_log2(footprint2.max(1e-300)))
    }

    /// The trilinear lookup at the (fractional) level `lambda`.
    #[inline(always)]
    pub fn sample_level(&mut self, q: usize, s: f64, t: f64, lambda: f64) -> f32 {
        let top = self.cache.quads[q].levels.len() - 1;
        if lambda <= 0.0 {
            return self.bilinear(q, 0, s, t);
        }
        let l0 = lambda as usize;
        if l0 >= top {
            return self.bilinear(q, top, s, t);
        }
        let f = (lambda - l0 as f64) as f32;
        let a = self.bilinear(q, l0, s, t);
        let b = self.bilinear(q, l0 + 1, s, t);
        a + f * (b - a)
    }

    /// [`TextureCache::bilinear`].
    #[inline(always)]
    pub fn bilinear(&mut self, q: usize, level: usize, s: f64, t: f64) -> f32 {
        let m = &mut self.memo[level & 1];
        if m.q != q || m.level != level {
            let lv = &self.cache.quads[q].levels[level];
            *m = Memo {
                q,
                level,
                inv_texel: lv.inv_texel,
                max: ((lv.n.0 - 1) as f64, (lv.n.1 - 1) as f64),
                tiles_s: lv.tiles_s,
                tile_xy: (usize::MAX, usize::MAX),
                tile: &[],
            };
        }
        let x = (s * m.inv_texel - 0.5).clamp(0.0, m.max.0);
        let y = (t * m.inv_texel - 0.5).clamp(0.0, m.max.1);
        let (xi, yi) = (x as usize, y as usize);
        let (fx, fy) = ((x - xi as f64) as f32, (y - yi as f64) as f32);
        let (tx, ty) = (xi / TILE, yi / TILE);
        if m.tile_xy != (tx, ty) {
            m.tile = self
                .cache
                .tile(self.scene, q, level, ty * m.tiles_s + tx, tx, ty);
            m.tile_xy = (tx, ty);
        }
        let i = (yi - ty * TILE) * STRIDE + (xi - tx * TILE);
        // One bounds check for the four texels.
        let quad = &m.tile[i..i + STRIDE + 2];
        let (a, b, c, d) = (
            quad[0] as f32,
            quad[1] as f32,
            quad[STRIDE] as f32,
            quad[STRIDE + 1] as f32,
        );
        let top = a + fx * (b - a);
        let bottom = c + fx * (d - c);
        (top + fy * (bottom - top)) * (1.0 / TEXEL_SCALE)
    }
}

/// Irradiance below which a point light is left out of a quad's lighting (a quarter of a grey
/// level at the default gain).
const LIGHT_CUTOFF: f64 = 1e-3;

/// `lighting` with the point lights that cannot reach `quad` removed: those behind its plane,
/// and those whose irradiance at the quad's nearest point is below [`LIGHT_CUTOFF`].
fn quad_lighting(lighting: &Lighting, quad: &Quad) -> Lighting {
    let n = quad.normal();
    let points = lighting
        .points
        .iter()
        .filter(|l| {
            let d = l.position - quad.origin;
            if n.dot(&d) <= 0.0 {
                return false;
            }
            // Nearest point of the rectangle to the light.
            let s = d.dot(&quad.axis_s).clamp(0.0, quad.width);
            let t = d.dot(&quad.axis_t).clamp(0.0, quad.height);
            let r2 = (l.position - quad.point(s, t)).norm_squared().max(1e-4);
            l.power / r2 >= LIGHT_CUTOFF
        })
        .copied()
        .collect();
    Lighting {
        ambient: lighting.ambient,
        directional: lighting.directional.clone(),
        points,
    }
}

/// Spacing of the irradiance samples of a tile: irradiance varies slowly (on the scale of the
/// distance to the lights, ≥ 0.2 m in the worlds), so it is evaluated every 4 texels up to 2 cm
/// apart and interpolated bilinearly in between; exactly at every texel beyond that.
fn light_step(texel: f64) -> usize {
    if 4.0 * texel <= 0.02 {
        4
    } else if 2.0 * texel <= 0.02 {
        2
    } else {
        1
    }
}

/// Evaluates one tile: texel `(i, j)` of tile `(tx, ty)` is the material at
/// `((32·tx + i + ½)·τ, (32·ty + j + ½)·τ)` times the irradiance there (see [`light_step`]),
/// plus the emission.
fn generate(
    scene: &Scene,
    lighting: &Lighting,
    q: usize,
    texel: f64,
    tx: usize,
    ty: usize,
) -> Box<[u16]> {
    let quad = &scene.quads[q];
    let n = quad.normal();
    let step = light_step(texel);
    let nodes = (STRIDE - 1) / step + 1;
    let centre = |i: usize| (i as f64 + 0.5) * texel;
    let mut irradiance = vec![0.0f64; nodes * nodes];
    for j in 0..nodes {
        let t = centre(ty * TILE + j * step);
        for i in 0..nodes {
            let s = centre(tx * TILE + i * step);
            let p = quad.point(s.min(quad.width), t.min(quad.height));
            irradiance[j * nodes + i] = lighting.irradiance(&p, &n);
        }
    }
    let inv = 1.0 / step as f64;
    let mut out = vec![0u16; STRIDE * STRIDE].into_boxed_slice();
    for j in 0..STRIDE {
        let t = centre(ty * TILE + j);
        let (j0, fy) = ((j / step).min(nodes - 2), 0.0);
        let fy = fy + (j - j0 * step) as f64 * inv;
        for i in 0..STRIDE {
            let s = centre(tx * TILE + i);
            let albedo = quad.material.albedo(s, t, texel);
            let i0 = (i / step).min(nodes - 2);
            let fx = (i - i0 * step) as f64 * inv;
            let e = |a: usize, b: usize| irradiance[(j0 + b) * nodes + i0 + a];
            let top = e(0, 0) + fx * (e(1, 0) - e(0, 0));
            let bottom = e(0, 1) + fx * (e(1, 1) - e(0, 1));
            let radiance = albedo * (top + fy * (bottom - top)) + quad.material.emission;
            // Round half up without a libm call (the value is clamped to be ≥ 0 first).
            out[j * STRIDE + i] =
                ((radiance * TEXEL_SCALE as f64).clamp(0.0, 65535.0) + 0.5) as u16;
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::render::texture::{Layer, Material};
    use nalgebra::Vector3;

    fn scene() -> Scene {
        let mut s = Scene::new("t", 0.002);
        s.lighting.ambient = 1.0;
        s.add_rect(
            Vector3::zeros(),
            Vector3::z(),
            1.0,
            0.5,
            Material::plain(0.5, 3).with(Layer::Noise {
                amplitude: 0.3,
                largest: 0.2,
                smallest: 0.002,
                gain: 0.7,
                stretch: (1.0, 1.0),
            }),
            [1.0; 3],
        );
        s
    }

    #[test]
    fn lookups_reproduce_texels_and_survive_eviction() {
        let s = scene();
        let mut cache = TextureCache::new(&s, 0);
        // 1 m / 2 mm = 500 texels: levels of 500, 250, 125, 63 and 32 texels along s.
        assert_eq!(cache.levels(0), 5);
        let q = &s.quads[0];
        let (si, ti) = (100.5 * s.texel, 40.5 * s.texel);
        let direct = q.material.albedo(si, ti, s.texel) as f32;
        let a = cache.bilinear(&s, 0, 0, si, ti);
        assert!((a - direct).abs() < 1e-4, "{a} vs {direct}");
        let before = cache.bilinear(&s, 0, 2, 0.37, 0.21);
        cache.end_frame();
        cache.end_frame(); // budget 0: everything unused in the last frame goes
        assert_eq!(cache.bytes(), 0);
        assert_eq!(
            cache.bilinear(&s, 0, 2, 0.37, 0.21).to_bits(),
            before.to_bits()
        );
    }

    #[test]
    fn trilinear_blends_neighbouring_levels() {
        let s = scene();
        let cache = TextureCache::new(&s, usize::MAX);
        let (sv, tv) = (0.3, 0.2);
        let l1 = cache.bilinear(&s, 0, 1, sv, tv);
        let l2 = cache.bilinear(&s, 0, 2, sv, tv);
        let mid = cache.sample(&s, 0, sv, tv, s.texel * 2f64.powf(1.5));
        assert!((mid - 0.5 * (l1 + l2)).abs() < 2e-3 * (l1 - l2).abs() + 1e-6);
        assert_eq!(
            cache.sample(&s, 0, sv, tv, 1e-9),
            cache.bilinear(&s, 0, 0, sv, tv)
        );
        assert_eq!(
            cache.sample(&s, 0, sv, tv, 1e9),
            cache.bilinear(&s, 0, 4, sv, tv)
        );
    }
}
