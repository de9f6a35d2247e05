//! Guided search of map points in an image (thesis §3.4.2, §6.3, PTAM): each point's template
//! is warped from its anchor keyframe's image by the predicted relative pose (a fronto-parallel
//! patch at the point's depth), compared by zero-mean SSD with the FAST corners inside a
//! radius around the prediction, and the best match is refined to sub-pixel accuracy.

use crate::frame::CornerIndex;
use crate::keyframes::KeyframeImages;
use geom::PinholeCamera;
use lie::{LieGroup, Se3};
use nalgebra::{Matrix2, Vector2, Vector3};
use slam::map::{KeyframeId, PointId, SlamGraph};
use slam::pose_graph::rigid_from_similarity;
use vision::fast::Corner;
use vision::image::GrayImage;
use vision::patch::{Patch, affine_from_pose, nssd, refine_subpixel, template_with_gradient};

/// A point is searched only if its prediction lies this far inside the image (8 px: an 8×8
/// patch and its sub-pixel refinement stay inside).
pub(crate) const PATCH_MARGIN_PX: f64 = 8.0;

/// Cell of the corner index the search queries (16 px: about the wide search radius, so a
/// query reads a handful of cells).
pub(crate) const CORNER_CELL_PX: f32 = 16.0;

/// A match this close to a track's position is the corner the track follows (2 px: LK and the
/// sub-pixel refinement each localise a corner to a fraction of a pixel).
pub(crate) const SAME_CORNER_PX: f64 = 2.0;

/// A map point as the search needs it, copied out of the graph.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SearchPoint {
    /// The point.
    pub point: PointId,
    /// Its anchor keyframe.
    pub anchor: KeyframeId,
    /// Its measured pixel in the anchor.
    pub anchor_pixel: Vector2<f64>,
    /// Its depth in the anchor's frame.
    pub anchor_depth: f64,
    /// The anchor's pose (rigid part).
    pub anchor_from_world: Se3,
    /// The point in world coordinates.
    pub world: Vector3<f64>,
}

impl SearchPoint {
    /// Point `p` of the graph, if it exists and its anchor measures it.
    pub fn from_graph<const N: usize>(graph: &SlamGraph<N>, p: PointId) -> Option<Self> {
        let pt = graph.point(p)?;
        let anchor = pt.anchor();
        let z = graph.keyframe(anchor)?.observations().get(&p)?;
        // The anchor's rigid pose in world units, `(R, t/s)`: a monocular keyframe carries a
        // scale `s` after a Sim(3) loop correction, and its camera frame is then `s` times the
        // world's; the depth is taken in world units too, as the search's relative poses are.
        let anchor_from_world = rigid_from_similarity(&graph.pose(anchor).ok()?);
        let world = graph.point_world(p).ok()?;
        Some(SearchPoint {
            point: p,
            anchor,
            anchor_pixel: Vector2::new(z[0], z[1]),
            anchor_depth: anchor_from_world.act(&world).z,
            anchor_from_world,
            world,
        })
    }
}

/// Where a point should appear in an image with pose `camera_from_world`, if in front of the
/// camera and inside the image by `margin` pixels: `(pixel, depth)`.
pub fn predict(
    camera: &PinholeCamera,
    camera_from_world: &Se3,
    point: &SearchPoint,
    width: usize,
    height: usize,
    margin: f64,
) -> Option<(Vector2<f64>, f64)> {
    let x = camera_from_world.act(&point.world);
    if x.z <= 1e-6 {
        return None;
    }
    let u = Vector2::new(
        camera.fx * x.x / x.z + camera.cx,
        camera.fy * x.y / x.z + camera.cy,
    );
    let inside = u.x >= margin
        && u.y >= margin
        && u.x < width as f64 - margin
        && u.y < height as f64 - margin;
    inside.then_some((u, x.z))
}

/// The angle (radians) between the rays from the anchor's and the current camera's centre to
/// the point (PTAM's visibility test: a template warped for a fronto-parallel plane predicts
/// the patch only for moderate changes of viewpoint).
pub fn view_angle(camera_from_world: &Se3, point: &SearchPoint) -> f64 {
    let centre = |t: &Se3| t.inverse().act(&Vector3::zeros());
    let a = point.world - centre(&point.anchor_from_world);
    let b = point.world - centre(camera_from_world);
    (a.dot(&b) / (a.norm() * b.norm())).clamp(-1.0, 1.0).acos()
}

/// A reusable scratch buffer for [`search`] (no allocation per point).
#[derive(Default)]
pub struct SearchScratch {
    corners: Vec<Corner>,
}

/// Searches `point` in `image` (pose `camera_from_world`, FAST corners `corners`) within
/// `radius` pixels of its prediction; the template comes from `anchor`'s image. The corner
/// whose patch correlates best with the template wins if the correlation is at least
/// `min_ncc`. Returns the sub-pixel match, or `None` (no corner in the radius, none correlating
/// enough, or the template leaves the anchor image).
#[allow(clippy::too_many_arguments)]
pub fn search(
    camera: &PinholeCamera,
    camera_from_world: &Se3,
    point: &SearchPoint,
    anchor: &KeyframeImages,
    image: &GrayImage,
    corners: &CornerIndex,
    radius: f64,
    min_ncc: f32,
    scratch: &mut SearchScratch,
) -> Option<Vector2<f64>> {
    let WarpedTemplate {
        predicted,
        warp,
        template,
    } = WarpedTemplate::new(camera, camera_from_world, point, anchor)?;
    let (ua, va) = (point.anchor_pixel.x as f32, point.anchor_pixel.y as f32);
    corners.within(
        predicted.x as f32,
        predicted.y as f32,
        radius as f32,
        &mut scratch.corners,
    );
    // NSSD = 2 − 2·NCC: the smallest wins. The prediction itself is a candidate too: FAST
    // fires on the same corner in only about half of the frames of a hand-held camera (blur,
    // noise), and sub-pixel alignment from the prediction finds the patch where the detector
    // did not.
    let max_nssd = 2.0 - 2.0 * min_ncc;
    let mut best: Option<(f32, f32, f32)> = None;
    let candidates = scratch
        .corners
        .iter()
        .map(|c| (c.u, c.v))
        .chain(std::iter::once((predicted.x as f32, predicted.y as f32)));
    for (u, v) in candidates {
        let Some(p) = Patch::extract(image, u, v) else {
            continue;
        };
        let s = nssd(&template, &p);
        if best.is_none_or(|b| s < b.2) {
            best = Some((u, v, s));
        }
    }
    let (u, v, _) = best?;
    let refined = template_with_gradient(&anchor.gray, ua, va, &warp)
        .and_then(|tg| refine_subpixel(&tg, image, [u, v], 10))
        .unwrap_or([u, v]);
    // The correlation where the match ends up decides.
    let p = Patch::extract(image, refined[0], refined[1])?;
    (nssd(&template, &p) <= max_nssd).then(|| Vector2::new(refined[0] as f64, refined[1] as f64))
}

/// A map point's template as a camera at `camera_from_world` sees it: its predicted pixel,
/// the affine warp from the anchor keyframe, and the anchor's patch warped by it.
struct WarpedTemplate {
    predicted: Vector2<f64>,
    warp: Matrix2<f64>,
    template: Patch,
}

impl WarpedTemplate {
    fn new(
        camera: &PinholeCamera,
        camera_from_world: &Se3,
        point: &SearchPoint,
        anchor: &KeyframeImages,
    ) -> Option<WarpedTemplate> {
        let cur_from_anchor = camera_from_world.compose(&point.anchor_from_world.inverse());
        let (predicted, warp) = affine_from_pose(
            camera,
            camera,
            &point.anchor_pixel,
            point.anchor_depth,
            &cur_from_anchor,
        )?;
        let (ua, va) = (point.anchor_pixel.x as f32, point.anchor_pixel.y as f32);
        let template = Patch::extract_warped(&anchor.gray, ua, va, &warp)?;
        Some(WarpedTemplate {
            predicted,
            warp,
            template,
        })
    }
}

/// What [`relocate`] made of a corner track's measurement of a map point.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Relocated {
    /// The point is here: where its template aligned, or the track's own measurement where the
    /// template is no model of the view (`max_scale`).
    At(Vector2<f64>),
    /// The alignment did not settle within its 2 px basin around the track (or the template
    /// has no gradient to align by, or the patch left the image): no evidence either way —
    /// a far view's template magnified into a smooth blob, motion blur, a corner that changed
    /// its look. Refusing these cuts a drive's tracks to a few frames (KITTI 04: a fifth of
    /// the checks); the caller may keep the measurement on probation, for the pose to judge
    /// (`mono.refuse_unaligned`, `slam::exploration::MonoExplorer::suspect`).
    Unaligned,
    /// Evidence that the track left its point: the template aligned farther than
    /// `max_shift` from it or does not correlate with the image there (or cannot be warped
    /// into this view at all).
    Refused,
}

/// Re-locates `point` near `at`, where a corner track measures it: its template, warped from
/// the anchor keyframe by the pose `camera_from_world` (a prediction is enough for the warp),
/// is aligned to `image` from `at` to sub-pixel accuracy ([`Relocated`]): the aligned position
/// if it moved at most `max_shift` pixels and correlates with the template at least `min_ncc`.
///
/// Optical flow follows a corner from frame to frame and drifts with every step; the template
/// is the point's appearance where it was first measured, so aligning to it measures the point
/// itself (the guided search of [`search`], started at the track instead of the prediction),
/// and a track that drifted off it or jumped to another corner is caught.
#[allow(clippy::too_many_arguments)]
pub fn relocate(
    camera: &PinholeCamera,
    camera_from_world: &Se3,
    point: &SearchPoint,
    anchor: &KeyframeImages,
    image: &GrayImage,
    at: Vector2<f64>,
    max_shift: f64,
    min_ncc: f32,
    max_scale: Option<f64>,
) -> Relocated {
    let Some(WarpedTemplate { warp, template, .. }) =
        WarpedTemplate::new(camera, camera_from_world, point, anchor)
    else {
        return Relocated::Refused;
    };
    let (ua, va) = (point.anchor_pixel.x as f32, point.anchor_pixel.y as f32);
    // A template is a model of its point at the anchor's scale (PTAM searches it on the
    // pyramid level nearest that scale): a view that sees the point at another level of
    // detail — nearer after driving towards it — stands as its track measured it.
    if let Some(limit) = max_scale {
        let scale = warp.determinant().abs().sqrt();
        if scale > limit || scale < 1.0 / limit {
            return Relocated::At(at);
        }
    }
    let Some(tg) = template_with_gradient(&anchor.gray, ua, va, &warp) else {
        return Relocated::Refused;
    };
    let Some(refined) = refine_subpixel(&tg, image, [at.x as f32, at.y as f32], 10) else {
        return Relocated::Unaligned;
    };
    let moved = Vector2::new(refined[0] as f64, refined[1] as f64);
    if (moved - at).norm() > max_shift {
        return Relocated::Refused;
    }
    match Patch::extract(image, refined[0], refined[1]) {
        Some(p) if nssd(&template, &p) <= 2.0 - 2.0 * min_ncc => Relocated::At(moved),
        _ => Relocated::Refused,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A smooth texture, shifted by `(dx, dy)` pixels (exact at any sub-pixel shift).
    fn texture(dx: f64, dy: f64, phase: f64) -> GrayImage {
        GrayImage::from_fn(160, 120, |u, v| {
            texture_at(u as f64 - dx, v as f64 - dy, phase)
        })
    }

    /// The texture's value at real coordinates `(x, y)`.
    fn texture_at(x: f64, y: f64, phase: f64) -> u8 {
        let i = 128.0
            + 40.0 * (0.31 * x + 0.17 * y + phase).sin()
            + 30.0 * (0.19 * x - 0.29 * y).sin()
            + 20.0 * (0.43 * x + 0.11 * y - phase).cos();
        i.round().clamp(0.0, 255.0) as u8
    }

    /// A track that drifted 0.9 px off its point is moved back onto it (the template from the
    /// anchor aligns to the image); a track in an image that does not show the point is
    /// refused, and so is one whose alignment would move it beyond `max_shift`; one the
    /// alignment cannot bring back within its basin is left to the pose (unaligned).
    #[test]
    fn relocate_moves_a_drifted_track_back_onto_its_point_and_refuses_a_wrong_one() {
        let camera = PinholeCamera::new(100.0, 100.0, 80.0, 60.0);
        let anchor_pixel = Vector2::new(70.0, 55.0);
        let depth = 2.0;
        let world = depth * Vector3::new((70.0 - 80.0) / 100.0, (55.0 - 60.0) / 100.0, 1.0);
        let point = SearchPoint {
            point: PointId::from_index(0),
            anchor: KeyframeId::from_index(0),
            anchor_pixel,
            anchor_depth: depth,
            anchor_from_world: Se3::identity(),
            world,
        };
        let anchor = KeyframeImages {
            frame_index: 0,
            timestamp: 0.0,
            gray: texture(0.0, 0.0, 0.0),
            depth: None,
            colour: None,
        };
        // The camera did not turn: the warp is the identity, the point moved with the image.
        let (dx, dy) = (2.4, -1.3);
        let image = texture(dx, dy, 0.0);
        let truth = anchor_pixel + Vector2::new(dx, dy);
        let pose = Se3::identity();
        let drifted = truth + Vector2::new(0.6, 0.7);
        let at = |image: &GrayImage, track: Vector2<f64>, max_shift: f64| {
            relocate(
                &camera, &pose, &point, &anchor, image, track, max_shift, 0.8, None,
            )
        };
        let Relocated::At(found) = at(&image, drifted, 3.0) else {
            panic!("not aligned");
        };
        assert!((found - truth).norm() < 0.05, "{found:?} vs {truth:?}");
        // Allowed to move 0.5 px only: refused.
        assert_eq!(at(&image, drifted, 0.5), Relocated::Refused);
        // Another pattern where the point was (a checkerboard of 2 px squares over it): the
        // alignment settles, and the correlation refuses it.
        let other = GrayImage::from_fn(160, 120, |u, v| {
            let c = if (u / 2 + v / 2) % 2 == 0 { 70 } else { -70 };
            (i32::from(image.get(u, v)) + c).clamp(0, 255) as u8
        });
        assert_eq!(at(&other, truth, 3.0), Relocated::Refused);
        // A track 2.5 px off: the alignment leaves its 2 px basin on the way — no evidence
        // either way, the pose judges the measurement (`MonoExplorer::suspect`).
        assert_eq!(
            at(&image, truth + Vector2::new(2.0, 1.5), 3.0),
            Relocated::Unaligned
        );
        // The camera moved halfway to the point: the point at (60, 50), seen twice as large.
        // The template, magnified from the anchor, aligns there (to 0.15 px: the magnified
        // template is a blurred model of the view); within √2 of scale only
        // (`mono.verify_within_scale`), the track's measurement stands unchecked.
        let nearer = Se3::from_translation(Vector3::new(0.0, 0.0, -0.5 * depth)).compose(&pose);
        let near_truth = Vector2::new(60.0, 50.0);
        let near_image = GrayImage::from_fn(160, 120, |u, v| {
            let (x, y) = (u as f64 - near_truth.x, v as f64 - near_truth.y);
            texture_at(anchor_pixel.x + 0.5 * x, anchor_pixel.y + 0.5 * y, 0.0)
        });
        let near_drifted = near_truth + Vector2::new(0.6, 0.7);
        let Relocated::At(aligned) = relocate(
            &camera,
            &nearer,
            &point,
            &anchor,
            &near_image,
            near_drifted,
            3.0,
            0.8,
            None,
        ) else {
            panic!("the magnified template not aligned");
        };
        assert!((aligned - near_truth).norm() < 0.25, "{aligned:?}");
        assert_eq!(
            relocate(
                &camera,
                &nearer,
                &point,
                &anchor,
                &near_image,
                near_drifted,
                3.0,
                0.8,
                Some(2f64.sqrt())
            ),
            Relocated::At(near_drifted)
        );
    }
}
