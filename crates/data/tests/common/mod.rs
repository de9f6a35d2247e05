//! Helpers of the sequence tests: stereo correspondences by FAST corners and patches.
#![allow(dead_code)]

use geom::{CameraModel, StereoCamera};
use lie::{LieGroup, Se3};
use nalgebra::{Matrix2, Vector2, Vector3};
use vision::fast::{Corner, fast9};
use vision::image::GrayImage;
use vision::patch::{Patch, guided_search, refine_subpixel, template_with_gradient, zmssd};

/// FAST threshold for the test correspondences (grey levels; OpenCV's default 10 gives too many
/// weak corners on sensor noise, 20 keeps the distinct ones).
pub const FAST_THRESHOLD: u8 = 20;

/// Patches whose ZMSSD is below this (mean squared difference ≤ 20², over 64 pixels) count as
/// matching.
pub const MAX_ZMSSD: f32 = 64.0 * 400.0;

/// Corners at least 12 px from the border (8×8 patches plus refinement).
pub fn corners(img: &GrayImage) -> Vec<Corner> {
    fast9(img, FAST_THRESHOLD, true)
        .into_iter()
        .filter(|c| img.contains_with_margin(c.u as f64, c.v as f64, 12.0))
        .collect()
}

/// A left↔right correspondence: left corner, sub-pixel right position.
#[derive(Clone, Copy, Debug)]
pub struct StereoMatch {
    pub left: [f32; 2],
    pub right: [f32; 2],
}

/// For each left corner, the best right corner by ZMSSD within `rows` rows of it and
/// 0 < disparity ≤ `max_disparity` (not constrained to the same row: the test measures the row
/// offset), kept if clearly better than the second best (ratio 0.7) and mutually best; then
/// refined to sub-pixel in the right image (inverse-compositional alignment of the left patch).
pub fn stereo_matches(
    left: &GrayImage,
    right: &GrayImage,
    rows: f32,
    max_disparity: f32,
) -> Vec<StereoMatch> {
    let cl = corners(left);
    let cr = corners(right);
    let pl: Vec<Option<Patch>> = cl.iter().map(|c| Patch::extract(left, c.u, c.v)).collect();
    let pr: Vec<Option<Patch>> = cr.iter().map(|c| Patch::extract(right, c.u, c.v)).collect();
    let best = |a: &Corner, pa: &Patch, others: &[Corner], po: &[Option<Patch>], sign: f32| {
        let mut b = (f32::INFINITY, usize::MAX);
        let mut second = f32::INFINITY;
        for (j, (c, p)) in others.iter().zip(po).enumerate() {
            let d = sign * (a.u - c.u);
            if (a.v - c.v).abs() > rows || d <= 0.0 || d > max_disparity {
                continue;
            }
            let Some(p) = p else { continue };
            let s = zmssd(pa, p);
            if s < b.0 {
                second = b.0;
                b = (s, j);
            } else if s < second {
                second = s;
            }
        }
        (b.0 < MAX_ZMSSD && b.0 < 0.7 * second).then_some(b.1)
    };
    let mut out = Vec::new();
    for (i, c) in cl.iter().enumerate() {
        let Some(pa) = &pl[i] else { continue };
        let Some(j) = best(c, pa, &cr, &pr, 1.0) else {
            continue;
        };
        let Some(pb) = &pr[j] else { continue };
        if best(&cr[j], pb, &cl, &pl, -1.0) != Some(i) {
            continue;
        }
        let Some(tg) = template_with_gradient(left, c.u, c.v, &Matrix2::identity()) else {
            continue;
        };
        let Some(r) = refine_subpixel(&tg, right, [cr[j].u, cr[j].v], 20) else {
            continue;
        };
        out.push(StereoMatch {
            left: [c.u, c.v],
            right: r,
        });
    }
    out
}

/// Median of absolute values.
pub fn median_abs(v: &[f64]) -> f64 {
    let mut a: Vec<f64> = v.iter().map(|x| x.abs()).collect();
    a.sort_by(f64::total_cmp);
    let n = a.len();
    if n % 2 == 1 {
        a[n / 2]
    } else {
        0.5 * (a[n / 2 - 1] + a[n / 2])
    }
}

/// Reprojection check of ground truth on a rectified stereo sequence: points triangulated in
/// frame `a` (same-row matches) are moved by `camera_b_from_camera_a` and projected into frame
/// `b`, where the left patch of frame `a` is searched among FAST corners within 20 px of the
/// prediction. Returns the median distance between prediction and match, and the number of
/// matches.
pub fn reprojection_median(
    camera: &StereoCamera,
    left_a: &GrayImage,
    right_a: &GrayImage,
    left_b: &GrayImage,
    camera_b_from_camera_a: &Se3,
) -> (f64, usize) {
    let matches = stereo_matches(left_a, right_a, 1.0, 150.0);
    let corners_b = corners(left_b);
    let mut errors = Vec::new();
    for m in matches {
        let z = Vector3::new(m.left[0] as f64, m.left[1] as f64, m.right[0] as f64);
        if z.x - z.z < 2.0 {
            continue; // far points say nothing about translation
        }
        let Ok(x_a) = camera.unproject(&z) else {
            continue;
        };
        let x_b = camera_b_from_camera_a.act(&x_a);
        let Ok(p) = camera.pinhole.project(&x_b) else {
            continue;
        };
        let Some(template) = Patch::extract(left_a, m.left[0], m.left[1]) else {
            continue;
        };
        let pred = [p.x as f32, p.y as f32];
        if let Some(found) = guided_search(&template, left_b, &corners_b, pred, 20.0, MAX_ZMSSD) {
            errors.push((Vector2::new(found.u as f64, found.v as f64) - p).norm());
        }
    }
    (median_abs(&errors), errors.len())
}
