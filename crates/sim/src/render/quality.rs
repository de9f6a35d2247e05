//! How trackable rendered images are, measured as the front-end would see them: FAST corners at
//! the front-end's threshold, the spread of the quadtree selection, and pyramidal Lucas-Kanade
//! between consecutive frames against the ground-truth motion of the corners.

use super::camera::RenderCamera;
use super::raycast::reference_depth;
use super::scene::Scene;
use lie::{LieGroup, Se3};
use nalgebra::{Vector2, Vector3};
use vision::image::GrayImage;
use vision::lk::{LkParams, track};
use vision::pyramid::Pyramid;
use vision::quadtree::{QuadPoint, select_corners};

/// The FAST threshold of the front-end (`dwslam inspect features` and its tracking use 20 on
/// 8-bit images).
pub const FAST_THRESHOLD: u8 = 20;
/// Features the quadtree selects per frame (as `dwslam inspect track` does by default).
pub const SELECTED: usize = 300;
/// Minimum quadtree cell (pixels), as the front-end uses.
pub const MIN_CELL: f32 = 8.0;
/// Depth of the quadtree whose cells the coverage counts: `2ᵈ × 2ᵈ` cells (8 × 8 = 64 cells of
/// 80 × 60 pixels at 640 × 480, the level at which the equi-distributed traversal has handed out
/// one feature per non-empty cell after 64 picks).
pub const COVERAGE_DEPTH: u32 = 3;

/// The front-end's feature selection on `img`: FAST-9 corners (non-maximum suppressed) at
/// [`FAST_THRESHOLD`] on the full image, scored by Shi-Tomasi (3 × 3 window radius), spread by
/// the quadtree's equi-distributed traversal (thesis Alg. 2, cells ≥ [`MIN_CELL`]) to
/// [`SELECTED`] features. Returns the number of FAST corners and the selection.
pub fn select_features(img: &GrayImage) -> (usize, Vec<QuadPoint>) {
    select_corners(img, FAST_THRESHOLD, SELECTED, MIN_CELL)
}

/// Trackability of one frame pair.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PairQuality {
    /// FAST-9 corners (non-maximum suppressed) on the first frame at [`FAST_THRESHOLD`].
    pub corners: usize,
    /// Fraction of the quadtree's `2ᵈ × 2ᵈ` cells (`d =` [`COVERAGE_DEPTH`]) holding at least one
    /// of the [`SELECTED`] features.
    pub coverage: f64,
    /// Selected features that LK tracked into the second frame and whose ground truth is
    /// defined (the ray meets a surface in both views).
    pub tracked: usize,
    /// Median distance (pixels) between the LK result and the ground-truth position.
    pub lk_median_error: f64,
}

/// Measures FAST, the quadtree selection and LK on frames `a` → `b` rendered of `scene` by an
/// undistorted `camera` at `world_from_a`, `world_from_b`. The ground truth of a feature at
/// pixel `p` of `a`: the world point on `p`'s ray at the exact depth (brute-force ray cast,
/// independent of the renderer's binning), projected into `b`.
pub fn pair_quality(
    scene: &Scene,
    camera: &RenderCamera,
    world_from_a: &Se3,
    world_from_b: &Se3,
    a: &GrayImage,
    b: &GrayImage,
) -> PairQuality {
    let (corners, chosen) = select_features(a);
    let (w, h) = (a.width() as f32, a.height() as f32);
    let cells = 1usize << COVERAGE_DEPTH;
    let mut covered = vec![false; cells * cells];
    for q in &chosen {
        let (i, j) = (
            ((q.u / w * cells as f32) as usize).min(cells - 1),
            ((q.v / h * cells as f32) as usize).min(cells - 1),
        );
        covered[j * cells + i] = true;
    }
    let coverage = covered.iter().filter(|&&c| c).count() as f64 / (cells * cells) as f64;
    // LK with the front-end's defaults.
    let params = LkParams::default();
    let (pa, pb) = (
        Pyramid::new(a, params.levels, 8).expect("non-empty image"),
        Pyramid::new(b, params.levels, 8).expect("non-empty image"),
    );
    let starts: Vec<[f32; 2]> = chosen.iter().map(|q| [q.u, q.v]).collect();
    let tracks = track(&pa, &pb, &starts, None, &params);
    let a_from_world = world_from_a.inverse();
    let b_from_world = world_from_b.inverse();
    let mut errors = Vec::new();
    for (p, t) in starts.iter().zip(&tracks) {
        let Some(t) = t else { continue };
        let ray = camera
            .ray(p[0] as f64, p[1] as f64)
            .expect("an undistorted camera");
        let Some((z, _)) = reference_depth(scene, &a_from_world, ray.x, ray.y) else {
            continue;
        };
        let x_a = Vector3::new(ray.x * z, ray.y * z, z);
        let x_b = b_from_world.act(&world_from_a.act(&x_a));
        // The point must still be the visible surface in b (not occluded there).
        let Ok(truth) = camera.project(&x_b) else {
            continue;
        };
        let ray_b = x_b / x_b.z;
        if let Some((zb, _)) = reference_depth(scene, &b_from_world, ray_b.x, ray_b.y)
            && (zb - x_b.z).abs() > 1e-6 * x_b.z.max(1.0)
        {
            continue;
        }
        errors.push((Vector2::new(t[0] as f64, t[1] as f64) - truth).norm());
    }
    errors.sort_by(f64::total_cmp);
    let lk_median_error = if errors.is_empty() {
        f64::INFINITY
    } else {
        errors[errors.len() / 2]
    };
    PairQuality {
        corners,
        coverage,
        tracked: errors.len(),
        lk_median_error,
    }
}
