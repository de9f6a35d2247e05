//! Dense photometric SE(3) alignment (thesis §6.3, eq. 6.7; Newcombe, Lovegrove & Davison
//! 2011): the pose prior of the stereo and RGB-D front-ends.
//!
//! Given a reference image `I_ref` with per-pixel depth (hence points `y_{u,v}` in the reference
//! camera frame, thesis eq. 6.6) and a current image `I_cur`, find `T = cur_from_ref` minimising
//!
//! `χ² = Σ_{u,v} ρ( (I_cur(ẑ_mono(T·y_{u,v})) − I_ref(u, v))² )`   (thesis eq. 6.7)
//!
//! with a Huber kernel `ρ`, by Gauss-Newton (iteratively re-weighted least squares) over a
//! pyramid, coarse to fine, with left-multiplicative updates `T ← exp(δ)·T` (thesis eq. 2.104).
//! The Jacobian of a residual is `∇I_cur · ∂ẑ_mono/∂x · [I | −[x]×]` with `x = T·y`
//! (thesis eq. B.4 and B.12).

use crate::image::{GrayImage, Image, ImageError};
use crate::interp::{Pixel, bilinear, bilinear_with_gradient};
use crate::pyramid::Pyramid;
use geom::{CameraModel, PinholeCamera};
use lie::{LieGroup, Se3};
use nalgebra::{Matrix6, Vector2, Vector3, Vector6};

/// Parameters of [`align`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DenseParams {
    /// Number of pyramid levels (coarsest first during the optimisation).
    pub levels: usize,
    /// Maximum Gauss-Newton iterations per level.
    pub max_iterations: usize,
    /// Huber threshold in units of the robust residual scale `σ̂ = 1.4826·median|r|`:
    /// `k = huber_scale·σ̂` (1.345 gives 95 % efficiency on Gaussian noise).
    pub huber_scale: f64,
    /// Pixels whose reference gradient magnitude is below this (intensity units per pixel)
    /// carry no information about the motion and are skipped.
    pub min_gradient: f32,
    /// Stop a level when the update `‖δ‖` is below this.
    pub min_update: f64,
    /// The finest level optimised (0: full resolution). A prior for a guided search needs no
    /// more than the level whose pixel is the search's tolerance.
    pub finest_level: usize,
}

impl Default for DenseParams {
    /// 4 levels, 30 iterations, Huber 1.345σ̂, gradient ≥ 2, ‖δ‖ < 1e-6.
    fn default() -> Self {
        Self {
            levels: 4,
            max_iterations: 30,
            huber_scale: 1.345,
            min_gradient: 2.0,
            min_update: 1e-6,
            finest_level: 0,
        }
    }
}

/// Result of [`align`].
#[derive(Debug, Clone, Copy)]
pub struct DenseResult {
    /// The estimated transformation from the reference camera frame to the current one.
    pub cur_from_ref: Se3,
    /// Final robust cost `Σρ(r²)/N` at the finest level optimised.
    pub final_cost: f64,
    /// Number of residuals used at the finest level in the last iteration.
    pub num_residuals: usize,
    /// Gauss-Newton iterations over all levels.
    pub iterations: usize,
}

/// Errors of [`align`].
#[derive(Debug, thiserror::Error)]
pub enum DenseError {
    /// Image sizes are inconsistent or too small.
    #[error(transparent)]
    Image(#[from] ImageError),
    /// Too few pixels with valid depth and gradient to estimate a pose.
    #[error("too few usable pixels ({0}) for dense alignment")]
    TooFewPixels(usize),
}

struct LevelData {
    points: Vec<Vector3<f64>>,
    intensities: Vec<f32>,
}

/// Per-level reference points: each level-`l` pixel takes the inverse-depth mean of the valid
/// depths in its `2ˡ×2ˡ` block of level 0 (at least half valid), back-projected with the
/// level's camera (thesis eq. 6.6).
fn level_points(
    img: &GrayImage,
    depth: &Image<f32>,
    cam: &PinholeCamera,
    l: usize,
    min_gradient: f32,
) -> LevelData {
    let s = 1usize << l;
    let mut points = Vec::new();
    let mut intensities = Vec::new();
    for v in 1..img.height().saturating_sub(1) {
        for u in 1..img.width().saturating_sub(1) {
            let gx = 0.5 * (img.get(u + 1, v) as f32 - img.get(u - 1, v) as f32);
            let gy = 0.5 * (img.get(u, v + 1) as f32 - img.get(u, v - 1) as f32);
            if gx * gx + gy * gy < min_gradient * min_gradient {
                continue;
            }
            let (mut sum_inv, mut n) = (0.0f64, 0usize);
            for dv in 0..s {
                for du in 0..s {
                    let (x, y) = (u * s + du, v * s + dv);
                    if x < depth.width() && y < depth.height() {
                        let d = depth.get(x, y);
                        if d.is_finite() && d > 0.0 {
                            sum_inv += 1.0 / d as f64;
                            n += 1;
                        }
                    }
                }
            }
            if 2 * n < s * s || n == 0 {
                continue;
            }
            let z = n as f64 / sum_inv;
            if let Ok(p) = cam.unproject_depth(&Vector2::new(u as f64, v as f64), z) {
                points.push(p);
                intensities.push(img.get(u, v).to_f32());
            }
        }
    }
    LevelData {
        points,
        intensities,
    }
}

/// Aligns `current` to `reference` whose per-pixel depth (metres along the optical axis; `NaN`
/// or ≤ 0 where unknown) is `depth`, with intrinsics `camera` (of level 0), starting from
/// `initial_cur_from_ref`.
pub fn align(
    reference: &GrayImage,
    depth: &Image<f32>,
    current: &GrayImage,
    camera: &PinholeCamera,
    initial_cur_from_ref: &Se3,
    params: &DenseParams,
) -> Result<DenseResult, DenseError> {
    if reference.width() != current.width() || reference.height() != current.height() {
        return Err(ImageError::SizeMismatch(
            reference.width(),
            reference.height(),
            current.width(),
            current.height(),
        )
        .into());
    }
    if depth.width() != reference.width() || depth.height() != reference.height() {
        return Err(ImageError::SizeMismatch(
            reference.width(),
            reference.height(),
            depth.width(),
            depth.height(),
        )
        .into());
    }
    let pr = Pyramid::new(reference, params.levels.max(1), 16)?;
    let pc = Pyramid::new(current, params.levels.max(1), 16)?;
    align_pyramids(&pr, depth, &pc, camera, initial_cur_from_ref, params)
}

/// [`align`] on pyramids built already (the live tracker builds each frame's once): level 0 of
/// `reference` and `depth` have the same size, `camera` is level 0's.
pub fn align_pyramids(
    pr: &Pyramid,
    depth: &Image<f32>,
    pc: &Pyramid,
    camera: &PinholeCamera,
    initial_cur_from_ref: &Se3,
    params: &DenseParams,
) -> Result<DenseResult, DenseError> {
    let levels = pr.len().min(pc.len()).min(params.levels.max(1));
    if levels == 0 {
        return Err(DenseError::TooFewPixels(0));
    }
    let finest = params.finest_level.min(levels - 1);
    let mut t = *initial_cur_from_ref;
    let mut iterations = 0;
    let mut final_cost = f64::NAN;
    let mut num_residuals = 0;
    for l in (finest..levels).rev() {
        let cam = camera.scaled(0.5f64.powi(l as i32));
        let data = level_points(&pr.levels[l], depth, &cam, l, params.min_gradient);
        if data.points.len() < 6 {
            if l == finest {
                return Err(DenseError::TooFewPixels(data.points.len()));
            }
            continue;
        }
        let cur = pc.levels[l].to_f32();
        let mut last_cost = f64::INFINITY;
        for _ in 0..params.max_iterations {
            iterations += 1;
            // Residuals and their Jacobians at the current estimate.
            let mut res = Vec::with_capacity(data.points.len());
            let mut jac: Vec<Vector6<f64>> = Vec::with_capacity(data.points.len());
            for (y, &iref) in data.points.iter().zip(&data.intensities) {
                let x = t.act(y);
                let Ok((uv, dproj)) = cam.project_with_jacobian(&x) else {
                    continue;
                };
                let Some((ic, gu, gv)) = bilinear_with_gradient(&cur, uv.x as f32, uv.y as f32)
                else {
                    continue;
                };
                let grad = nalgebra::RowVector2::new(gu as f64, gv as f64);
                let j = grad * dproj * t.d_act_d_left(y);
                res.push((ic - iref) as f64);
                jac.push(j.transpose());
            }
            if res.len() < 6 {
                return Err(DenseError::TooFewPixels(res.len()));
            }
            let mut absr: Vec<f64> = res.iter().map(|r| r.abs()).collect();
            let mid = absr.len() / 2;
            let med = *absr.select_nth_unstable_by(mid, |a, b| a.total_cmp(b)).1;
            let k = (params.huber_scale * 1.4826 * med).max(1e-3);
            let mut h = Matrix6::<f64>::zeros();
            let mut g = Vector6::<f64>::zeros();
            let mut cost = 0.0;
            for (r, j) in res.iter().zip(&jac) {
                let a = r.abs();
                let (w, rho) = if a <= k {
                    (1.0, r * r)
                } else {
                    (k / a, 2.0 * k * a - k * k)
                };
                cost += rho;
                h += j * j.transpose() * w;
                g += j * (w * r);
            }
            cost /= res.len() as f64;
            final_cost = cost;
            num_residuals = res.len();
            if cost > last_cost * (1.0 + 1e-9) && l == finest {
                // Should not happen often with IRLS; stop rather than diverge.
                break;
            }
            last_cost = cost;
            let Some(delta) = h.cholesky().map(|c| -c.solve(&g)) else {
                break;
            };
            t = Se3::exp(&delta).compose(&t);
            if delta.norm() < params.min_update {
                break;
            }
        }
    }
    Ok(DenseResult {
        cur_from_ref: t,
        final_cost,
        num_residuals,
        iterations,
    })
}

/// The photometric residual image `I_cur(ẑ(T·y_{u,v})) − I_ref(u, v)` at level 0 (NaN where the
/// depth is unknown or the point leaves the current image), for inspection (thesis Fig. 6.6c).
pub fn residual_image(
    reference: &GrayImage,
    depth: &Image<f32>,
    current: &GrayImage,
    camera: &PinholeCamera,
    cur_from_ref: &Se3,
) -> Image<f32> {
    Image::from_fn(reference.width(), reference.height(), |u, v| {
        let d = depth.get_checked(u as i64, v as i64).unwrap_or(f32::NAN);
        if !(d.is_finite() && d > 0.0) {
            return f32::NAN;
        }
        let Ok(y) = camera.unproject_depth(&Vector2::new(u as f64, v as f64), d as f64) else {
            return f32::NAN;
        };
        let Ok(uv) = camera.project(&cur_from_ref.act(&y)) else {
            return f32::NAN;
        };
        match bilinear(current, uv.x as f32, uv.y as f32) {
            Some(i) => i - reference.get(u, v) as f32,
            None => f32::NAN,
        }
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Renders a textured fronto-parallel-ish scene (a slanted plane) seen from `cam_from_world`.
    fn render(
        cam: &PinholeCamera,
        cam_from_world: &Se3,
        w: usize,
        h: usize,
    ) -> (GrayImage, Image<f32>) {
        // Plane z = 3 + 0.2 x in world; texture by world (x, y).
        let world_from_cam = cam_from_world.inverse();
        let tex = |x: f64, y: f64| {
            128.0 + 50.0 * (x * 9.0).sin() * (y * 7.0).cos() + 40.0 * ((x + 2.0 * y) * 4.0).sin()
        };
        let mut img = GrayImage::new(w, h);
        let mut depth = Image::<f32>::filled(w, h, f32::NAN);
        for v in 0..h {
            for u in 0..w {
                let ray_c = cam
                    .unproject_depth(&Vector2::new(u as f64, v as f64), 1.0)
                    .unwrap();
                let o = world_from_cam.act(&Vector3::zeros());
                let dir = world_from_cam.act(&ray_c) - o;
                // Solve (o + s dir).z = 3 + 0.2 (o + s dir).x
                let s = (3.0 + 0.2 * o.x - o.z) / (dir.z - 0.2 * dir.x);
                let p = o + dir * s;
                img.set(u, v, tex(p.x, p.y).clamp(0.0, 255.0) as u8);
                depth.set(u, v, (cam_from_world.act(&p)).z as f32);
            }
        }
        (img, depth)
    }

    #[test]
    fn recovers_a_small_motion() {
        let cam = PinholeCamera::new(200.0, 200.0, 79.5, 59.5);
        let ref_from_world = Se3::identity();
        let cur_from_world = Se3::exp(&Vector6::new(0.03, -0.02, 0.04, 0.01, -0.015, 0.02));
        let (iref, dref) = render(&cam, &ref_from_world, 160, 120);
        let (icur, _) = render(&cam, &cur_from_world, 160, 120);
        let r = align(
            &iref,
            &dref,
            &icur,
            &cam,
            &Se3::identity(),
            &DenseParams {
                levels: 3,
                ..Default::default()
            },
        )
        .unwrap();
        let truth = cur_from_world.compose(&ref_from_world.inverse());
        let err = r.cur_from_ref.compose(&truth.inverse()).log();
        assert!(
            err.fixed_rows::<3>(0).norm() < 2e-3,
            "translation error {}",
            err.fixed_rows::<3>(0).norm()
        );
        assert!(
            err.fixed_rows::<3>(3).norm() < 2e-3,
            "rotation error {}",
            err.fixed_rows::<3>(3).norm()
        );
        let res = residual_image(&iref, &dref, &icur, &cam, &r.cur_from_ref);
        assert_eq!(res.width(), 160);
    }

    #[test]
    fn stopping_at_a_coarser_level_is_a_coarser_prior() {
        // The same motion, aligned down to level 1 only (the live tracker's prior) on prebuilt
        // pyramids: close to the truth, and the residual count is level 1's.
        let cam = PinholeCamera::new(200.0, 200.0, 79.5, 59.5);
        let cur_from_world = Se3::exp(&Vector6::new(0.03, -0.02, 0.04, 0.01, -0.015, 0.02));
        let (iref, dref) = render(&cam, &Se3::identity(), 160, 120);
        let (icur, _) = render(&cam, &cur_from_world, 160, 120);
        let params = DenseParams {
            levels: 3,
            finest_level: 1,
            ..Default::default()
        };
        let (pr, pc) = (
            Pyramid::new(&iref, 3, 16).unwrap(),
            Pyramid::new(&icur, 3, 16).unwrap(),
        );
        let coarse = align_pyramids(&pr, &dref, &pc, &cam, &Se3::identity(), &params).unwrap();
        let full = align(
            &iref,
            &dref,
            &icur,
            &cam,
            &Se3::identity(),
            &DenseParams {
                levels: 3,
                ..Default::default()
            },
        )
        .unwrap();
        let err = coarse.cur_from_ref.compose(&cur_from_world.inverse()).log();
        assert!(err.norm() < 1e-2, "level-1 prior error {}", err.norm());
        assert!(
            coarse.num_residuals < full.num_residuals / 2,
            "{} vs {}",
            coarse.num_residuals,
            full.num_residuals
        );
    }

    #[test]
    fn rejects_bad_input() {
        let cam = PinholeCamera::new(100.0, 100.0, 10.0, 10.0);
        let a = GrayImage::filled(20, 20, 5);
        let d = Image::<f32>::filled(20, 20, 1.0);
        // Flat image: no gradient, no usable pixel.
        assert!(align(&a, &d, &a, &cam, &Se3::identity(), &DenseParams::default()).is_err());
        let b = GrayImage::new(21, 20);
        assert!(align(&a, &d, &b, &cam, &Se3::identity(), &DenseParams::default()).is_err());
        let one = GrayImage::new(1, 1);
        let d1 = Image::<f32>::filled(1, 1, 1.0);
        assert!(
            align(
                &one,
                &d1,
                &one,
                &cam,
                &Se3::identity(),
                &DenseParams::default()
            )
            .is_err()
        );
    }
}
