//! Procedural materials: an albedo `ρ(s, t) ∈ [0, 1]` over a surface's texture coordinates
//! `(s, t)` (metres along the surface's two axes), built from layers — fractal noise, grids
//! (tiles, bricks, planks), scattered shapes (marks, labels, pictures), rows of glyph-like
//! blocks ("text"), book spines, window grids, a checkerboard — each seeded, so that no two
//! surfaces look alike even when they share a recipe.
//!
//! [`Material::albedo`] takes the texel size `τ` at which it is evaluated and band-limits every
//! layer to it (noise octaves below `2τ` dropped, edges box-filtered over `τ`, see
//! [`procedural`](super::procedural)): the mip level `l` of a texture holds exactly this
//! function evaluated with `τ = τ₀·2ˡ`.

use super::procedural::{
    fbm, hash1, hash2, interval_aa, range, rect_aa, smooth_step_aa, unit, value_noise,
};

/// Shapes drawn by [`Layer::Scatter`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Shape {
    /// Axis-aligned rectangles.
    Rect,
    /// Rectangles rotated by a random angle.
    RotatedRect,
    /// Discs.
    Disc,
    /// Rings (a disc with a hole).
    Ring,
    /// A random choice of the others, per shape.
    Mixed,
}

/// One layer of a [`Material`], applied on top of the layers before it.
#[derive(Debug, Clone, PartialEq)]
pub enum Layer {
    /// Adds `amplitude · fbm` with wavelengths from `largest` to `smallest`; `stretch` scales
    /// `(s, t)` first (e.g. `(0.1, 1)` for wood grain running along `s`).
    Noise {
        /// Amplitude (albedo units).
        amplitude: f64,
        /// Longest wavelength (m).
        largest: f64,
        /// Shortest wavelength (m).
        smallest: f64,
        /// Amplitude ratio between octaves.
        gain: f64,
        /// Scale applied to `(s, t)` before the noise.
        stretch: (f64, f64),
    },
    /// A grid of cells `(pitch_s × pitch_t)` separated by joints of width `joint` and albedo
    /// `joint_value`; every cell gets a random albedo offset in `±cell_variation`; rows are
    /// shifted by `row_offset · pitch_s` (0.5 for a running bond); `random_length` draws cell
    /// lengths along `s` per row (planks) in `[0.5, 1.5]·pitch_s`.
    Grid {
        /// Cell size along `s` (m).
        pitch_s: f64,
        /// Cell size along `t` (m).
        pitch_t: f64,
        /// Joint width (m).
        joint: f64,
        /// Joint albedo.
        joint_value: f64,
        /// Random albedo offset of each cell (±).
        cell_variation: f64,
        /// Row shift as a fraction of `pitch_s`.
        row_offset: f64,
        /// Random cell lengths along `s` (planks).
        random_length: bool,
    },
    /// At most one shape per cell of a `cell × cell` grid (present with probability
    /// `density`), contained in its cell, of size `size` (fractions of the cell, half-extent)
    /// and albedo in `values`, blended with `opacity`; the grid is rotated by `angle`.
    Scatter {
        /// Cell size (m).
        cell: f64,
        /// Probability that a cell holds a shape.
        density: f64,
        /// Half-extent range as fractions of the cell (≤ 0.5).
        size: (f64, f64),
        /// Albedo range of the shapes.
        values: (f64, f64),
        /// Blend factor.
        opacity: f64,
        /// Kind of shape.
        shape: Shape,
        /// Rotation of the grid (radians).
        angle: f64,
    },
    /// Rows of glyph-like blocks ("text") of height `row_height` inside the rectangle
    /// `[s0, s1] × [t0, t1]`, with albedo `ink`; rows run along `s`, one text line every
    /// `1.6 · row_height`; words of 2–9 glyphs.
    Text {
        /// Region `(s0, t0, s1, t1)` (m).
        region: (f64, f64, f64, f64),
        /// Glyph height (m).
        row_height: f64,
        /// Ink albedo.
        ink: f64,
    },
    /// Book spines standing on shelves: along `s`, spines of width 1.5–6 cm with random
    /// albedo, heights from `t = 0` up to 70–100 % of `height`, a label block on some; above a
    /// spine the albedo is `back` (the shelf's back wall).
    Books {
        /// Shelf height (m) (the region `0 ≤ t ≤ height`).
        height: f64,
        /// Albedo of the shelf back.
        back: f64,
    },
    /// A filled rectangle `[s0, s1] × [t0, t1]` of albedo `value`, blended with `opacity`.
    Panel {
        /// Region `(s0, t0, s1, t1)` (m).
        region: (f64, f64, f64, f64),
        /// Albedo.
        value: f64,
        /// Blend factor.
        opacity: f64,
    },
    /// A rectangle `region` split into `rows × columns` picture elements: a random-albedo
    /// background with a few large random shapes each (posters, photographs, paintings).
    Pictures {
        /// Region `(s0, t0, s1, t1)` (m).
        region: (f64, f64, f64, f64),
        /// Number of pictures along `s`.
        columns: usize,
        /// Number of pictures along `t`.
        rows: usize,
    },
    /// A grid of windows on a façade: `pitch_s × pitch_t` bays starting at `t0`, each a dark
    /// pane `pane_s × pane_t` with a light frame of width `frame`, a blind drawn to a random
    /// height, and a few bright reflections.
    Windows {
        /// Bay width (m).
        pitch_s: f64,
        /// Storey height (m).
        pitch_t: f64,
        /// Height of the first window's bottom (m).
        t0: f64,
        /// Height above which no windows are drawn (m).
        t1: f64,
        /// Pane width (m).
        pane_s: f64,
        /// Pane height (m).
        pane_t: f64,
        /// Frame width (m).
        frame: f64,
    },
    /// A checkerboard with squares of `square` metres, `columns × rows` squares, lower-left
    /// corner at `origin`, black `0.05` and white `0.95`, on whatever lies below it; its inner
    /// corners are at `origin + (i·square, j·square)` — the geometric test target. Box-filtered
    /// over two texels (see `checker`), so its edges and corners are reconstructed exactly.
    Checker {
        /// Lower-left corner `(s, t)` (m).
        origin: (f64, f64),
        /// Square size (m).
        square: f64,
        /// Number of squares along `s`.
        columns: usize,
        /// Number of squares along `t`.
        rows: usize,
    },
    /// Worley-like cobbles: a jittered grid of `cell` metres, each point's Voronoi cell a stone
    /// with random albedo offset (±`variation`) and dark joints of width `joint`.
    Cobbles {
        /// Cell size (m).
        cell: f64,
        /// Joint width (m).
        joint: f64,
        /// Albedo offset range (±).
        variation: f64,
    },
}

/// A procedural material: a base albedo plus layers, with a seed.
#[derive(Debug, Clone, PartialEq)]
pub struct Material {
    /// The albedo before any layer.
    pub base: f64,
    /// The layers, applied in order.
    pub layers: Vec<Layer>,
    /// The seed (different per surface).
    pub seed: u64,
    /// Emitted radiance added after lighting (light panels, windows lit from outside).
    pub emission: f64,
}

impl Material {
    /// A material of constant albedo `base` with no layers.
    pub fn plain(base: f64, seed: u64) -> Self {
        Material {
            base,
            layers: Vec::new(),
            seed,
            emission: 0.0,
        }
    }

    /// Adds a layer (builder style).
    pub fn with(mut self, layer: Layer) -> Self {
        self.layers.push(layer);
        self
    }

    /// Sets the emitted radiance.
    pub fn emissive(mut self, emission: f64) -> Self {
        self.emission = emission;
        self
    }

    /// The albedo at `(s, t)` band-limited to texels of size `texel` (see the module notes),
    /// clamped to `[0, 1]`.
    pub fn albedo(&self, s: f64, t: f64, texel: f64) -> f64 {
        let mut v = self.base;
        for (i, layer) in self.layers.iter().enumerate() {
            let seed = hash1(self.seed, i as u64);
            v = apply(layer, v, s, t, texel, seed);
        }
        v.clamp(0.0, 1.0)
    }
}

#[inline]
fn blend(under: f64, over: f64, alpha: f64) -> f64 {
    under + alpha * (over - under)
}

fn apply(layer: &Layer, v: f64, s: f64, t: f64, texel: f64, seed: u64) -> f64 {
    match *layer {
        Layer::Noise {
            amplitude,
            largest,
            smallest,
            gain,
            stretch,
        } => {
            v + amplitude
                * fbm(
                    seed,
                    s * stretch.0,
                    t * stretch.1,
                    largest,
                    smallest,
                    gain,
                    texel * stretch.0.max(stretch.1),
                )
        }
        Layer::Grid {
            pitch_s,
            pitch_t,
            joint,
            joint_value,
            cell_variation,
            row_offset,
            random_length,
        } => grid(
            v,
            s,
            t,
            texel,
            seed,
            (pitch_s, pitch_t),
            joint,
            joint_value,
            cell_variation,
            row_offset,
            random_length,
        ),
        Layer::Scatter {
            cell,
            density,
            size,
            values,
            opacity,
            shape,
            angle,
        } => {
            let (c, sn) = (angle.cos(), angle.sin());
            let (x, y) = (c * s + sn * t, -sn * s + c * t);
            match scatter(seed, x, y, cell, density, size, values, shape, texel) {
                Some((cover, value)) => blend(v, value, opacity * cover),
                None => v,
            }
        }
        Layer::Text {
            region,
            row_height,
            ink,
        } => text(v, s, t, texel, seed, region, row_height, ink),
        Layer::Books { height, back } => books(v, s, t, texel, seed, height, back),
        Layer::Panel {
            region,
            value,
            opacity,
        } => {
            let c = rect_aa(s, t, region.0, region.1, region.2, region.3, texel);
            blend(v, value, opacity * c)
        }
        Layer::Pictures {
            region,
            columns,
            rows,
        } => pictures(v, s, t, texel, seed, region, columns, rows),
        Layer::Windows {
            pitch_s,
            pitch_t,
            t0,
            t1,
            pane_s,
            pane_t,
            frame,
        } => windows(
            v,
            s,
            t,
            texel,
            seed,
            (pitch_s, pitch_t),
            (t0, t1),
            (pane_s, pane_t),
            frame,
        ),
        Layer::Checker {
            origin,
            square,
            columns,
            rows,
        } => checker(v, s, t, texel, origin, square, columns, rows),
        Layer::Cobbles {
            cell,
            joint,
            variation,
        } => cobbles(v, s, t, texel, seed, cell, joint, variation),
    }
}

/// The shape of the scatter cell holding `(x, y)`, if any: its coverage of the texel and its
/// albedo.
#[allow(clippy::too_many_arguments)]
#[inline]
fn scatter(
    seed: u64,
    x: f64,
    y: f64,
    cell: f64,
    density: f64,
    size: (f64, f64),
    values: (f64, f64),
    shape: Shape,
    texel: f64,
) -> Option<(f64, f64)> {
    let (ci, cj) = ((x / cell).floor(), (y / cell).floor());
    let h = hash2(seed, ci as i64, cj as i64);
    if unit(h) >= density {
        return None;
    }
    // All the shape's parameters from one more hash, 10 bits each.
    let g = hash1(h, 1);
    let bits = |k: u32| ((g >> (10 * k)) & 1023) as f64 / 1023.0;
    let (ha, hb) = (
        (size.0 + (size.1 - size.0) * bits(0)) * cell,
        (size.0 + (size.1 - size.0) * bits(1)) * cell,
    );
    let kind = match shape {
        Shape::Mixed => match (g >> 60) % 4 {
            0 => Shape::Rect,
            1 => Shape::RotatedRect,
            2 => Shape::Disc,
            _ => Shape::Ring,
        },
        k => k,
    };
    let r_max = match kind {
        Shape::Rect => ha.max(hb),
        _ => (ha * ha + hb * hb).sqrt().min(0.5 * cell),
    };
    // Centre jittered so that the shape stays inside its cell.
    let free = (0.5 * cell - r_max).max(0.0);
    let cx = (ci + 0.5) * cell + free * (2.0 * bits(2) - 1.0);
    let cy = (cj + 0.5) * cell + free * (2.0 * bits(3) - 1.0);
    let (dx, dy) = (x - cx, y - cy);
    let cover = match kind {
        Shape::Rect => rect_aa(dx, dy, -ha, -hb, ha, hb, texel),
        Shape::RotatedRect => {
            let a = bits(4) * std::f64::consts::PI;
            let (ca, sa) = (a.cos(), a.sin());
            let (u, w) = (ca * dx + sa * dy, -sa * dx + ca * dy);
            let (ra, rb) = (ha.min(r_max * 0.7), hb.min(r_max * 0.7));
            rect_aa(u, w, -ra, -rb, ra, rb, texel)
        }
        Shape::Disc => smooth_step_aa(r_max - (dx * dx + dy * dy).sqrt(), texel),
        Shape::Ring | Shape::Mixed => {
            let d = (dx * dx + dy * dy).sqrt();
            smooth_step_aa(r_max - d, texel) * smooth_step_aa(d - 0.55 * r_max, texel)
        }
    };
    (cover > 0.0).then(|| (cover, values.0 + (values.1 - values.0) * bits(5)))
}

#[allow(clippy::too_many_arguments)]
fn grid(
    v: f64,
    s: f64,
    t: f64,
    texel: f64,
    seed: u64,
    pitch: (f64, f64),
    joint: f64,
    joint_value: f64,
    cell_variation: f64,
    row_offset: f64,
    random_length: bool,
) -> f64 {
    let row = (t / pitch.1).floor();
    let ty = t - row * pitch.1;
    let shift = row_offset * pitch.0 * row
        + range(hash2(seed, row as i64, -7), 0.0, 1.0) * {
            if random_length { pitch.0 } else { 0.0 }
        };
    let x = s + shift;
    let (col, sx, len) = if random_length {
        // Cells of random length: boundaries at k·pitch plus a random offset in ±0.4·pitch.
        let k = (x / pitch.0).floor();
        let b =
            |k: f64| k * pitch.0 + range(hash2(seed, row as i64, k as i64), -0.4, 0.4) * pitch.0;
        let (b0, b1) = (b(k), b(k + 1.0));
        if x < b0 {
            let bm = b(k - 1.0);
            (k - 1.0, x - bm, b0 - bm)
        } else if x >= b1 {
            let b2 = b(k + 2.0);
            (k + 1.0, x - b1, b2 - b1)
        } else {
            (k, x - b0, b1 - b0)
        }
    } else {
        let k = (x / pitch.0).floor();
        (k, x - k * pitch.0, pitch.0)
    };
    let cell = v + range(
        hash2(seed, col as i64, row as i64),
        -cell_variation,
        cell_variation,
    );
    // Joints: half a joint width on each side of each cell boundary.
    let hj = 0.5 * joint;
    let inside = interval_aa(sx, hj, len - hj, texel) * interval_aa(ty, hj, pitch.1 - hj, texel);
    blend(joint_value, cell, inside)
}

#[allow(clippy::too_many_arguments)]
fn text(
    v: f64,
    s: f64,
    t: f64,
    texel: f64,
    seed: u64,
    region: (f64, f64, f64, f64),
    row_height: f64,
    ink: f64,
) -> f64 {
    let (s0, t0, s1, t1) = region;
    if s < s0 - texel || s > s1 + texel || t < t0 - texel || t > t1 + texel {
        return v;
    }
    // Glyphs thinner than a texel average out to a tint: below ~2 texels per glyph stroke
    // draw the line as a faint band instead (the band-limited limit of text).
    let pitch = 1.6 * row_height;
    let line = ((t1 - t) / pitch).floor();
    let ty = (t1 - t) - line * pitch; // distance below the line's top
    if line < 0.0 {
        return v;
    }
    let glyph_w = 0.6 * row_height;
    let hl = hash2(seed, line as i64, 11);
    // Lines end at a random fraction of the width (paragraph ends).
    let line_end = s0 + (s1 - s0) * range(hl, 0.45, 1.0);
    if texel > 0.35 * row_height {
        let band = interval_aa(ty, 0.0, row_height, texel) * interval_aa(s, s0, line_end, texel);
        return blend(v, ink, 0.45 * band);
    }
    let k = ((s - s0) / glyph_w).floor();
    let gx = (s - s0) - k * glyph_w;
    let hg = hash2(seed ^ hl, k as i64, line as i64);
    // A space every few glyphs (word breaks), decided per glyph position.
    if hg.is_multiple_of(6) || s > line_end {
        return v;
    }
    // A glyph: one of a few block shapes (full block, upper/lower half, left bar, two bars).
    let sw = 0.28 * glyph_w; // stroke width
    let gw = glyph_w * 0.8;
    let h = row_height;
    let cover = match (hg >> 8) % 5 {
        0 => rect_aa(gx, ty, 0.0, 0.0, gw, h, texel),
        1 => {
            rect_aa(gx, ty, 0.0, 0.0, gw, 0.5 * h, texel)
                + rect_aa(gx, ty, 0.0, 0.5 * h, sw, h, texel)
        }
        2 => rect_aa(gx, ty, 0.0, 0.0, sw, h, texel) + rect_aa(gx, ty, sw, 0.6 * h, gw, h, texel),
        3 => rect_aa(gx, ty, 0.0, 0.0, sw, h, texel) + rect_aa(gx, ty, gw - sw, 0.0, gw, h, texel),
        _ => {
            rect_aa(gx, ty, 0.0, 0.3 * h, gw, 0.7 * h, texel)
                + rect_aa(gx, ty, 0.0, 0.0, sw, h, texel)
        }
    }
    .min(1.0);
    blend(v, ink, cover)
}

fn books(v: f64, s: f64, t: f64, texel: f64, seed: u64, height: f64, back: f64) -> f64 {
    if t > height + texel || t < -texel {
        return v;
    }
    // Spines: boundaries at a random walk along s, widths 1.5–6 cm; found by stepping cells of
    // 6 cm each holding one boundary.
    let cell = 0.06;
    let k = (s / cell).floor();
    let b = |k: f64| k * cell + range(hash1(seed, k as i64 as u64), 0.0, 0.6) * cell;
    let (b0, b1) = (b(k), b(k + 1.0));
    let (id, x0, x1) = if s < b0 {
        (k - 1.0, b(k - 1.0), b0)
    } else {
        (k, b0, b1)
    };
    let h = hash1(seed ^ 0x5bd1_e995, id as i64 as u64);
    let top = height * range(h, 0.7, 0.98);
    let spine = range(hash1(h, 1), 0.08, 0.9);
    let inside = interval_aa(s, x0 + 0.002, x1 - 0.002, texel) * smooth_step_aa(top - t, texel);
    let mut value = blend(back, spine, inside);
    // A label band on 60 % of the spines, with a darker or lighter print.
    if unit(hash1(h, 2)) < 0.6 {
        let l0 = top * range(hash1(h, 3), 0.45, 0.7);
        let l1 = l0 + top * range(hash1(h, 4), 0.08, 0.18);
        let label = range(hash1(h, 5), 0.0, 1.0);
        let c = inside * rect_aa(s, t, x0 + 0.006, l0, x1 - 0.006, l1, texel);
        value = blend(value, label, c);
    }
    value
}

#[allow(clippy::too_many_arguments)]
fn pictures(
    v: f64,
    s: f64,
    t: f64,
    texel: f64,
    seed: u64,
    region: (f64, f64, f64, f64),
    columns: usize,
    rows: usize,
) -> f64 {
    let (s0, t0, s1, t1) = region;
    if s < s0 - texel || s > s1 + texel || t < t0 - texel || t > t1 + texel {
        return v;
    }
    let (pw, ph) = ((s1 - s0) / columns as f64, (t1 - t0) / rows as f64);
    let (ci, cj) = (((s - s0) / pw).floor(), ((t - t0) / ph).floor());
    let h = hash2(seed, ci as i64, cj as i64);
    let (x, y) = (s - s0 - ci * pw, t - t0 - cj * ph);
    let margin = 0.06 * pw.min(ph);
    let frame = rect_aa(x, y, margin, margin, pw - margin, ph - margin, texel);
    let mut value = blend(v, range(hash1(h, 1), 0.1, 0.9), frame);
    for k in 0..6u64 {
        let hk = hash1(h, 10 + k);
        let cx = range(hash1(hk, 1), 0.15, 0.85) * pw;
        let cy = range(hash1(hk, 2), 0.15, 0.85) * ph;
        let r = range(hash1(hk, 3), 0.05, 0.3) * pw.min(ph);
        let val = range(hash1(hk, 4), 0.0, 1.0);
        let c = if hk.is_multiple_of(2) {
            smooth_step_aa(r - ((x - cx).powi(2) + (y - cy).powi(2)).sqrt(), texel)
        } else {
            rect_aa(x, y, cx - r, cy - 0.6 * r, cx + r, cy + 0.6 * r, texel)
        };
        value = blend(value, val, frame * c);
    }
    // Smaller shapes at two scales, and fine detail (photographs are busy).
    for (k, scale) in [(0u64, 0.12), (1, 0.04)] {
        let cell = scale * pw.min(ph);
        if let Some((c, val)) = scatter(
            hash1(h, 30 + k),
            x,
            y,
            cell,
            0.6,
            (0.15, 0.45),
            (0.0, 1.0),
            Shape::Mixed,
            texel,
        ) {
            value = blend(value, val, frame * c);
        }
    }
    let n = fbm(h, x, y, 0.1 * pw, 0.002, 0.6, texel);
    value + 0.15 * frame * n
}

#[allow(clippy::too_many_arguments)]
fn windows(
    v: f64,
    s: f64,
    t: f64,
    texel: f64,
    seed: u64,
    pitch: (f64, f64),
    band: (f64, f64),
    pane: (f64, f64),
    frame: f64,
) -> f64 {
    if t < band.0 - texel || t > band.1 + texel {
        return v;
    }
    let (ci, cj) = ((s / pitch.0).floor(), ((t - band.0) / pitch.1).floor());
    if cj < 0.0 || band.0 + cj * pitch.1 + pane.1 > band.1 {
        return v;
    }
    let h = hash2(seed, ci as i64, cj as i64);
    let (x, y) = (s - ci * pitch.0, t - band.0 - cj * pitch.1);
    let x0 = 0.5 * (pitch.0 - pane.0);
    let outer = rect_aa(x, y, x0, 0.0, x0 + pane.0, pane.1, texel);
    if outer <= 0.0 {
        return v;
    }
    let inner = rect_aa(
        x,
        y,
        x0 + frame,
        frame,
        x0 + pane.0 - frame,
        pane.1 - frame,
        texel,
    );
    // Mullion in the middle of wide windows.
    let mid = x0 + 0.5 * pane.0;
    let mullion = if pane.0 > 1.0 {
        interval_aa(x, mid - 0.5 * frame, mid + 0.5 * frame, texel)
    } else {
        0.0
    };
    let glass = range(hash1(h, 1), 0.05, 0.25);
    let blind_to = pane.1 * range(hash1(h, 2), 0.3, 1.0);
    let blind = range(hash1(h, 3), 0.5, 0.85);
    let mut pane_value = glass + 0.08 * fbm(h, x, y, 0.5, 0.02, 0.5, texel);
    if unit(hash1(h, 4)) < 0.6 {
        // A blind drawn down from the top, with slats.
        let b = smooth_step_aa(y - blind_to, texel);
        let slats = 0.06 * (interval_aa((y * 20.0).fract(), 0.0, 0.15, texel * 20.0));
        pane_value = blend(pane_value, blind - slats, b);
    }
    let framev = range(hash1(h, 5), 0.75, 0.95);
    let inside = blend(framev, pane_value, inner * (1.0 - mullion));
    // Sill below the window.
    let sill = rect_aa(x, y, x0 - 0.05, -0.08, x0 + pane.0 + 0.05, 0.0, texel);
    let out = blend(v, inside, outer);
    blend(out, 0.85, sill)
}

#[allow(clippy::too_many_arguments)]
fn checker(
    v: f64,
    s: f64,
    t: f64,
    texel: f64,
    origin: (f64, f64),
    square: f64,
    columns: usize,
    rows: usize,
) -> f64 {
    let (x, y) = ((s - origin.0) / square, (t - origin.1) / square);
    let (wc, hc) = (columns as f64, rows as f64);
    // Box filter of two texels: the filtered pattern is then bilinear in (s, t) within a texel
    // of every edge and corner, so the bilinear reconstruction from the texels is exact there
    // and edges and corners stay exactly where they are at every mip level (a one-texel box
    // would shift the reconstructed edge by up to 0.08 texel with the sub-texel phase).
    let w = 2.0 * texel / square;
    let inside = interval_aa(x, 0.0, wc, w) * interval_aa(y, 0.0, hc, w);
    if inside <= 0.0 {
        return v;
    }
    // The product of two box-filtered square waves: the area average of the pattern over an
    // axis-aligned box of side 2τ.
    let sq = |z: f64| {
        // Square wave ±1 with period 2, box-filtered over width w: the integral of the wave
        // is a triangle wave.
        let tri = |z: f64| {
            let m = z.rem_euclid(2.0);
            if m < 1.0 { m } else { 2.0 - m }
        };
        if w < 1e-12 {
            if z.rem_euclid(2.0) < 1.0 { 1.0 } else { -1.0 }
        } else {
            ((tri(z + 0.5 * w) - tri(z - 0.5 * w)) / w).clamp(-1.0, 1.0)
        }
    };
    let c = sq(x) * sq(y); // +1 on even squares (white), −1 on odd (black)
    let value = 0.5 + 0.45 * c;
    blend(v, value, inside)
}

#[allow(clippy::too_many_arguments)]
fn cobbles(
    v: f64,
    s: f64,
    t: f64,
    texel: f64,
    seed: u64,
    cell: f64,
    joint: f64,
    variation: f64,
) -> f64 {
    let (x, y) = (s / cell, t / cell);
    let (ix, iy) = (x.floor() as i64, y.floor() as i64);
    let mut d1 = f64::INFINITY;
    let mut d2 = f64::INFINITY;
    let mut best = 0u64;
    for dy in -1..=1 {
        for dx in -1..=1 {
            let h = hash2(seed, ix + dx, iy + dy);
            let px = (ix + dx) as f64 + 0.15 + 0.7 * unit(h);
            let py = (iy + dy) as f64 + 0.15 + 0.7 * unit(hash1(h, 1));
            let d = ((x - px).powi(2) + (y - py).powi(2)).sqrt();
            if d < d1 {
                d2 = d1;
                d1 = d;
                best = h;
            } else if d < d2 {
                d2 = d;
            }
        }
    }
    // Distance to the Voronoi edge ≈ (d2 − d1)/2 (in cells).
    let edge = 0.5 * (d2 - d1) * cell;
    let stone = v
        + range(hash1(best, 2), -variation, variation)
        + 0.5 * variation * value_noise(best, s / (0.3 * cell), t / (0.3 * cell));
    blend(0.5 * v, stone, smooth_step_aa(edge - 0.5 * joint, texel))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rich(seed: u64) -> Material {
        Material::plain(0.5, seed)
            .with(Layer::Noise {
                amplitude: 0.2,
                largest: 0.5,
                smallest: 0.002,
                gain: 0.6,
                stretch: (1.0, 1.0),
            })
            .with(Layer::Scatter {
                cell: 0.1,
                density: 0.7,
                size: (0.1, 0.4),
                values: (0.0, 1.0),
                opacity: 1.0,
                shape: Shape::Mixed,
                angle: 0.3,
            })
            .with(Layer::Text {
                region: (0.0, 0.0, 1.0, 1.0),
                row_height: 0.01,
                ink: 0.05,
            })
    }

    #[test]
    fn albedo_is_bounded_deterministic_and_unique_per_seed() {
        let (a, b) = (rich(1), rich(2));
        let mut diff = 0.0;
        for i in 0..2000 {
            let (s, t) = (unit(hash1(9, i)) * 2.0, unit(hash1(10, i)) * 2.0);
            let x = a.albedo(s, t, 0.001);
            assert!((0.0..=1.0).contains(&x));
            assert_eq!(x.to_bits(), a.albedo(s, t, 0.001).to_bits());
            diff += (x - b.albedo(s, t, 0.001)).abs();
        }
        assert!(diff / 2000.0 > 0.05, "mean |a − b| = {}", diff / 2000.0);
    }

    #[test]
    fn coarse_levels_average_the_fine_ones() {
        // The checker at a coarse texel τ equals the mean of the pattern over the 2τ box
        // around it (the property mip-mapping relies on).
        let m = Material::plain(0.5, 0).with(Layer::Checker {
            origin: (0.0, 0.0),
            square: 0.05,
            columns: 8,
            rows: 8,
        });
        let coarse = 0.016;
        for (s, t) in [(0.123, 0.077), (0.2, 0.2), (0.051, 0.149)] {
            let n = 64;
            let mut mean = 0.0;
            for j in 0..n {
                for i in 0..n {
                    let ds = ((i as f64 + 0.5) / n as f64 - 0.5) * 2.0 * coarse;
                    let dt = ((j as f64 + 0.5) / n as f64 - 0.5) * 2.0 * coarse;
                    mean += m.albedo(s + ds, t + dt, 1e-9);
                }
            }
            mean /= (n * n) as f64;
            let c = m.albedo(s, t, coarse);
            assert!((c - mean).abs() < 0.02, "({s}, {t}): {c} vs {mean}");
        }
    }
}
