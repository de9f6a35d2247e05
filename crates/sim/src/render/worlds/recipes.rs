//! Material recipes shared by the worlds. Every recipe takes a seed, so two surfaces built from
//! the same recipe differ in every detail (the shapes, their values, the noise), and parameters
//! that a real surface would vary (colour, contrast, scale) are drawn from the seed too.

use crate::render::procedural::{hash1, range};
use crate::render::texture::{Layer, Material, Shape};

/// A colour normalised to luma 1 (Rec. 601), so that tints change colour, not brightness.
pub fn tint(r: f32, g: f32, b: f32) -> [f32; 3] {
    let l = 0.299 * r + 0.587 * g + 0.114 * b;
    [r / l, g / l, b / l]
}

/// Neutral grey.
pub const NEUTRAL: [f32; 3] = [1.0, 1.0, 1.0];

fn r(seed: u64, k: u64, lo: f64, hi: f64) -> f64 {
    range(hash1(seed, k), lo, hi)
}

fn noise(amplitude: f64, largest: f64, smallest: f64, gain: f64) -> Layer {
    Layer::Noise {
        amplitude,
        largest,
        smallest,
        gain,
        stretch: (1.0, 1.0),
    }
}

/// Painted plaster: weakly textured (low-contrast noise) with sparse small marks.
pub fn plaster(seed: u64) -> Material {
    Material::plain(r(seed, 0, 0.6, 0.8), seed)
        .with(noise(0.05, 0.8, 0.003, 0.55))
        .with(Layer::Scatter {
            cell: 0.25,
            density: 0.25,
            size: (0.02, 0.08),
            values: (0.2, 0.5),
            opacity: 0.6,
            shape: Shape::Disc,
            angle: r(seed, 1, 0.0, 1.5),
        })
}

/// Patterned wallpaper: motifs at two scales over a mottled ground.
pub fn wallpaper(seed: u64) -> Material {
    let cell = r(seed, 0, 0.08, 0.16);
    Material::plain(r(seed, 1, 0.5, 0.7), seed)
        .with(noise(0.08, 0.8, 0.003, 0.6))
        .with(Layer::Scatter {
            cell,
            density: r(seed, 2, 0.6, 0.9),
            size: (0.2, 0.45),
            values: (0.1, 0.9),
            opacity: 0.9,
            shape: Shape::Mixed,
            angle: r(seed, 3, 0.0, 1.5),
        })
        .with(Layer::Scatter {
            cell: cell * 0.3,
            density: 0.5,
            size: (0.15, 0.4),
            values: (0.0, 1.0),
            opacity: 0.7,
            shape: Shape::Rect,
            angle: r(seed, 4, 0.0, 1.5),
        })
}

/// Wooden floor boards along `s`.
pub fn planks(seed: u64) -> Material {
    Material::plain(r(seed, 0, 0.45, 0.6), seed)
        .with(Layer::Grid {
            pitch_s: r(seed, 1, 0.9, 1.5),
            pitch_t: r(seed, 2, 0.12, 0.2),
            joint: 0.004,
            joint_value: 0.12,
            cell_variation: 0.15,
            row_offset: 0.0,
            random_length: true,
        })
        .with(Layer::Noise {
            amplitude: 0.12,
            largest: 0.4,
            smallest: 0.002,
            gain: 0.7,
            stretch: (0.08, 1.0),
        })
        .with(Layer::Scatter {
            cell: 0.3,
            density: 0.4,
            size: (0.03, 0.1),
            values: (0.1, 0.3),
            opacity: 0.8,
            shape: Shape::Disc,
            angle: 0.0,
        })
}

/// Square floor or wall tiles with speckles.
pub fn tiles(seed: u64, size: f64) -> Material {
    Material::plain(r(seed, 0, 0.45, 0.7), seed)
        .with(Layer::Grid {
            pitch_s: size,
            pitch_t: size,
            joint: 0.006,
            joint_value: r(seed, 1, 0.2, 0.85),
            cell_variation: 0.12,
            row_offset: 0.0,
            random_length: false,
        })
        .with(Layer::Scatter {
            cell: 0.025,
            density: 0.5,
            size: (0.1, 0.35),
            values: (0.05, 0.95),
            opacity: 0.6,
            shape: Shape::Disc,
            angle: 0.3,
        })
        .with(noise(0.06, 0.8, 0.003, 0.5))
}

/// A patterned rug: large checked motifs, scattered ornaments, a border.
pub fn rug(seed: u64, w: f64, h: f64) -> Material {
    Material::plain(r(seed, 0, 0.3, 0.5), seed)
        .with(Layer::Grid {
            pitch_s: w / 6.0,
            pitch_t: h / 4.0,
            joint: 0.03,
            joint_value: 0.8,
            cell_variation: 0.25,
            row_offset: 0.5,
            random_length: false,
        })
        .with(Layer::Scatter {
            cell: 0.12,
            density: 0.8,
            size: (0.2, 0.45),
            values: (0.0, 1.0),
            opacity: 0.8,
            shape: Shape::Mixed,
            angle: 0.785,
        })
        .with(noise(0.1, 0.1, 0.002, 0.8))
        .with(Layer::Panel {
            region: (0.0, 0.0, w, 0.12),
            value: 0.15,
            opacity: 1.0,
        })
        .with(Layer::Panel {
            region: (0.0, h - 0.12, w, h),
            value: 0.15,
            opacity: 1.0,
        })
}

/// Suspended ceiling: a faint grid of panels, very weakly textured.
pub fn ceiling(seed: u64) -> Material {
    Material::plain(0.85, seed)
        .with(Layer::Grid {
            pitch_s: 0.6,
            pitch_t: 0.6,
            joint: 0.015,
            joint_value: 0.7,
            cell_variation: 0.015,
            row_offset: 0.0,
            random_length: false,
        })
        .with(noise(0.025, 0.5, 0.003, 0.6))
}

/// A light panel: bright, emissive, almost uniform (saturates the sensor).
pub fn light_panel(seed: u64) -> Material {
    Material::plain(0.95, seed)
        .with(noise(0.02, 0.3, 0.01, 0.5))
        .emissive(0.9)
}

/// Book spines on a shelf of height `height`.
pub fn books(seed: u64, height: f64) -> Material {
    Material::plain(0.1, seed)
        .with(Layer::Books { height, back: 0.08 })
        .with(noise(0.05, 0.2, 0.002, 0.6))
}

/// Cardboard with packing tape, a printed label and printed symbols, and a handwritten note.
pub fn cardboard(seed: u64, w: f64, h: f64) -> Material {
    let (lx, ly) = (r(seed, 0, 0.1, 0.5) * w, r(seed, 1, 0.1, 0.5) * h);
    let (lw, lh) = (r(seed, 2, 0.25, 0.45) * w, r(seed, 3, 0.2, 0.4) * h);
    Material::plain(r(seed, 4, 0.45, 0.6), seed)
        .with(Layer::Noise {
            amplitude: 0.1,
            largest: 0.3,
            smallest: 0.002,
            gain: 0.75,
            stretch: (1.0, 0.2),
        })
        .with(Layer::Panel {
            region: (0.0, 0.45 * h, w, 0.55 * h),
            value: 0.65,
            opacity: 0.8,
        })
        .with(Layer::Panel {
            region: (lx, ly, lx + lw, ly + lh),
            value: 0.92,
            opacity: 1.0,
        })
        .with(Layer::Text {
            region: (lx + 0.01, ly + 0.01, lx + lw - 0.01, ly + lh - 0.01),
            row_height: r(seed, 5, 0.008, 0.02),
            ink: 0.05,
        })
        .with(Layer::Text {
            region: (0.05 * w, 0.6 * h, 0.7 * w, 0.95 * h),
            row_height: r(seed, 6, 0.02, 0.04),
            ink: 0.15,
        })
        .with(Layer::Scatter {
            cell: 0.1,
            density: 0.5,
            size: (0.15, 0.4),
            values: (0.05, 0.2),
            opacity: 0.9,
            shape: Shape::Mixed,
            angle: 0.0,
        })
}

/// A framed poster or painting of `w × h` metres, with a caption.
pub fn poster(seed: u64, w: f64, h: f64) -> Material {
    Material::plain(0.15, seed)
        .with(Layer::Pictures {
            region: (0.02, 0.15 * h, w - 0.02, h - 0.02),
            columns: 1,
            rows: 1,
        })
        .with(Layer::Panel {
            region: (0.02, 0.02, w - 0.02, 0.14 * h),
            value: 0.9,
            opacity: 1.0,
        })
        .with(Layer::Text {
            region: (0.05, 0.03, w - 0.05, 0.13 * h),
            row_height: (0.012 * h).max(0.01),
            ink: 0.1,
        })
}

/// A pinboard: cork with paper notes and photographs.
pub fn pinboard(seed: u64, w: f64, h: f64) -> Material {
    Material::plain(0.45, seed)
        .with(noise(0.15, 0.05, 0.002, 0.8))
        .with(Layer::Scatter {
            cell: 0.14,
            density: 0.8,
            size: (0.25, 0.45),
            values: (0.75, 1.0),
            opacity: 1.0,
            shape: Shape::RotatedRect,
            angle: 0.0,
        })
        .with(Layer::Text {
            region: (0.0, 0.0, w, h),
            row_height: 0.01,
            ink: 0.15,
        })
        .with(Layer::Scatter {
            cell: 0.3,
            density: 0.5,
            size: (0.2, 0.4),
            values: (0.0, 0.9),
            opacity: 1.0,
            shape: Shape::Rect,
            angle: 0.1,
        })
}

/// A whiteboard: nearly uniform white with some marker writing in part of it (weak texture).
pub fn whiteboard(seed: u64, w: f64, h: f64) -> Material {
    Material::plain(0.93, seed)
        .with(noise(0.015, 0.5, 0.005, 0.5))
        .with(Layer::Text {
            region: (0.08 * w, 0.3 * h, 0.7 * w, 0.92 * h),
            row_height: 0.035,
            ink: 0.3,
        })
        .with(Layer::Scatter {
            cell: 0.2,
            density: 0.4,
            size: (0.2, 0.45),
            values: (0.2, 0.5),
            opacity: 0.8,
            shape: Shape::Ring,
            angle: 0.0,
        })
        .with(Layer::Panel {
            region: (0.0, 0.0, w, 0.03),
            value: 0.5,
            opacity: 1.0,
        })
}

/// A door with two inset panels, a handle and a name plate.
pub fn door(seed: u64, w: f64, h: f64) -> Material {
    let base = r(seed, 0, 0.3, 0.7);
    Material::plain(base, seed)
        .with(Layer::Noise {
            amplitude: 0.12,
            largest: 0.5,
            smallest: 0.002,
            gain: 0.75,
            stretch: (1.0, 0.1),
        })
        .with(Layer::Scatter {
            cell: 0.25,
            density: 0.3,
            size: (0.15, 0.4),
            values: (0.0, 1.0),
            opacity: 1.0,
            shape: Shape::Mixed,
            angle: 0.0,
        })
        .with(Layer::Panel {
            region: (0.1 * w, 0.08 * h, 0.9 * w, 0.47 * h),
            value: base * 0.55,
            opacity: 1.0,
        })
        .with(Layer::Panel {
            region: (0.13 * w, 0.1 * h, 0.87 * w, 0.45 * h),
            value: base * 0.85,
            opacity: 1.0,
        })
        .with(Layer::Panel {
            region: (0.1 * w, 0.5 * h, 0.9 * w, 0.92 * h),
            value: base * 0.55,
            opacity: 1.0,
        })
        .with(Layer::Panel {
            region: (0.13 * w, 0.52 * h, 0.87 * w, 0.9 * h),
            value: base * 0.85,
            opacity: 1.0,
        })
        .with(Layer::Panel {
            region: (0.82 * w, 0.47 * h, 0.92 * w, 0.5 * h),
            value: 0.9,
            opacity: 1.0,
        })
        .with(Layer::Panel {
            region: (0.3 * w, 0.72 * h, 0.7 * w, 0.8 * h),
            value: 0.92,
            opacity: 1.0,
        })
        .with(Layer::Text {
            region: (0.32 * w, 0.73 * h, 0.68 * w, 0.79 * h),
            row_height: 0.025,
            ink: 0.05,
        })
}

/// Brickwork in running bond.
pub fn brick(seed: u64) -> Material {
    Material::plain(r(seed, 0, 0.35, 0.55), seed)
        .with(Layer::Grid {
            pitch_s: 0.25,
            pitch_t: 0.075,
            joint: 0.012,
            joint_value: r(seed, 1, 0.7, 0.9),
            cell_variation: 0.22,
            row_offset: 0.5,
            random_length: false,
        })
        .with(noise(0.1, 0.8, 0.003, 0.7))
        .with(Layer::Scatter {
            cell: 0.03,
            density: 0.35,
            size: (0.1, 0.35),
            values: (0.05, 0.3),
            opacity: 0.8,
            shape: Shape::Disc,
            angle: 0.4,
        })
}

/// Concrete: mottled, with pores and stains.
pub fn concrete(seed: u64) -> Material {
    Material::plain(r(seed, 0, 0.45, 0.65), seed)
        .with(noise(0.12, 0.8, 0.003, 0.6))
        .with(Layer::Scatter {
            cell: 0.04,
            density: 0.4,
            size: (0.05, 0.2),
            values: (0.15, 0.35),
            opacity: 0.8,
            shape: Shape::Disc,
            angle: 0.2,
        })
        .with(Layer::Scatter {
            cell: 1.5,
            density: 0.5,
            size: (0.2, 0.45),
            values: (0.2, 0.4),
            opacity: 0.25,
            shape: Shape::Disc,
            angle: 0.7,
        })
}

/// Cobblestone paving.
pub fn cobbles(seed: u64) -> Material {
    Material::plain(r(seed, 0, 0.4, 0.55), seed)
        .with(Layer::Cobbles {
            cell: r(seed, 1, 0.12, 0.2),
            joint: 0.012,
            variation: 0.15,
        })
        .with(noise(0.06, 0.8, 0.004, 0.6))
}

/// Grass: fine high-contrast noise and blades.
pub fn grass(seed: u64) -> Material {
    Material::plain(0.35, seed)
        .with(noise(0.3, 0.8, 0.003, 0.8))
        .with(Layer::Scatter {
            cell: 0.02,
            density: 0.6,
            size: (0.1, 0.4),
            values: (0.1, 0.7),
            opacity: 0.8,
            shape: Shape::RotatedRect,
            angle: 0.0,
        })
}

/// A computer screen: dark, with windows and text.
pub fn screen(seed: u64, w: f64, h: f64) -> Material {
    Material::plain(0.08, seed)
        .with(Layer::Pictures {
            region: (0.02, 0.02, w - 0.02, h - 0.02),
            columns: 2,
            rows: 2,
        })
        .with(Layer::Text {
            region: (0.03, 0.03, 0.5 * w, 0.45 * h),
            row_height: 0.006,
            ink: 0.95,
        })
        .emissive(0.15)
}

/// Painted metal or plastic: nearly uniform (weakly textured) with a little speckle, scratches
/// and stickers.
pub fn painted(seed: u64) -> Material {
    Material::plain(r(seed, 0, 0.3, 0.8), seed)
        .with(noise(0.03, 0.5, 0.003, 0.5))
        .with(Layer::Scatter {
            cell: 0.03,
            density: 0.3,
            size: (0.1, 0.3),
            values: (0.2, 0.7),
            opacity: 0.4,
            shape: Shape::Disc,
            angle: 0.5,
        })
        .with(Layer::Scatter {
            cell: 0.2,
            density: 0.4,
            size: (0.05, 0.3),
            values: (0.0, 1.0),
            opacity: 0.8,
            shape: Shape::Mixed,
            angle: 0.0,
        })
}

/// A glazed window seen from inside: the outside (a house front and trees against the sky,
/// bright), behind glazing bars.
pub fn window_pane(seed: u64, w: f64, h: f64) -> Material {
    Material::plain(0.75, seed)
        .with(Layer::Pictures {
            region: (0.0, 0.0, w, 0.6 * h),
            columns: 3,
            rows: 1,
        })
        .with(Layer::Windows {
            pitch_s: 0.25,
            pitch_t: 0.3,
            t0: 0.1,
            t1: 0.55 * h,
            pane_s: 0.12,
            pane_t: 0.15,
            frame: 0.015,
        })
        .with(Layer::Scatter {
            cell: 0.12,
            density: 0.7,
            size: (0.25, 0.45),
            values: (0.1, 0.45),
            opacity: 0.9,
            shape: Shape::Disc,
            angle: 0.3,
        })
        .with(noise(0.06, 0.8, 0.005, 0.6))
        .with(Layer::Grid {
            pitch_s: w / 2.0,
            pitch_t: h / 3.0,
            joint: 0.05,
            joint_value: 0.9,
            cell_variation: 0.0,
            row_offset: 0.0,
            random_length: false,
        })
        .emissive(0.35)
}

/// Leaves of a tree canopy: dense high-contrast blobs at several scales.
pub fn foliage(seed: u64) -> Material {
    Material::plain(0.3, seed)
        .with(noise(0.25, 0.8, 0.005, 0.7))
        .with(Layer::Scatter {
            cell: 0.12,
            density: 0.9,
            size: (0.2, 0.45),
            values: (0.05, 0.6),
            opacity: 0.9,
            shape: Shape::Disc,
            angle: 0.4,
        })
        .with(Layer::Scatter {
            cell: 0.04,
            density: 0.8,
            size: (0.2, 0.45),
            values: (0.1, 0.8),
            opacity: 0.8,
            shape: Shape::Disc,
            angle: 1.1,
        })
}

/// A façade of `w × h` metres: brick, pre-cast concrete panels or rendered plaster (by `kind`),
/// storeys of windows, shop fronts and doors on the ground floor and a sign above them.
pub fn facade(seed: u64, w: f64, h: f64, kind: u64) -> Material {
    // Brick; pre-cast concrete panels; or rendered (plaster) walls with rusticated joints.
    let panels = |m: Material, pitch: (f64, f64)| {
        m.with(Layer::Grid {
            pitch_s: pitch.0,
            pitch_t: pitch.1,
            joint: 0.025,
            joint_value: 0.2,
            cell_variation: 0.08,
            row_offset: 0.5,
            random_length: false,
        })
    };
    let base = match kind % 3 {
        0 => brick(seed),
        1 => panels(concrete(seed), (1.5, 0.75)),
        _ => panels(plaster(seed), (0.9, 0.45)),
    };
    let storey = range(hash1(seed, 50), 3.0, 3.6);
    let bay = range(hash1(seed, 51), 2.4, 3.6);
    base.with(Layer::Windows {
        pitch_s: bay,
        pitch_t: storey,
        t0: storey + 0.9,
        t1: h - 0.5,
        pane_s: bay * range(hash1(seed, 52), 0.4, 0.6),
        pane_t: storey * 0.5,
        frame: 0.07,
    })
    // Shop fronts and doors on the ground floor.
    .with(Layer::Windows {
        pitch_s: bay * 2.0,
        pitch_t: storey,
        t0: 0.4,
        t1: storey - 0.3,
        pane_s: bay * 1.3,
        pane_t: storey - 1.0,
        frame: 0.1,
    })
    .with(Layer::Text {
        region: (0.5, storey - 0.55, w * 0.4, storey - 0.25),
        row_height: 0.2,
        ink: 0.1,
    })
}
