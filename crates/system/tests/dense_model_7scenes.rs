//! Dense model fusion on real 7-Scenes RGB-D frames with their ground-truth poses: the fused
//! cloud must lie on the surfaces that frames *not* fused measure.
//!
//! Keyframes every 40th frame (0, 40, …, 960) are fused; the frames halfway between them
//! (20, 60, …, 980) are held out. The fused cloud is rendered into every held-out frame with
//! the ground truth and a z-buffer (per 8×8-pixel cell the nearest point, so that points
//! hidden behind nearer surfaces do not count); where the winner lands on a valid depth pixel,
//! its distance to the measured surface along the ray, `|z_rendered − z_measured|`, is one
//! sample. The same is measured for the raw depth samples of the fused keyframes (every 8th
//! pixel, before voxel averaging and filtering) as the reference: the fusion should lie no
//! farther from held-out surfaces than the data it fused. The ground truth itself is
//! consistent to 6–15 mm between frames (PROVENANCE.md), a floor for both.

use data::paths;
use data::sequence::{FrameImages, OpenOptions, Sequence};
use geom::CameraModel;
use lie::{LieGroup, Se3, Sim3};
use nalgebra::{Vector2, Vector3};
use system::dense_model::{Colour, DenseModel, DenseModelConfig, KeyframeCloud};

fn median_and_p90(v: &mut [f64]) -> (f64, f64) {
    v.sort_by(f64::total_cmp);
    (v[v.len() / 2], v[v.len() * 9 / 10])
}

#[test]
fn fused_cloud_lies_on_held_out_depth_surfaces() {
    let Some(root) = paths::require("seven_scenes_redkitchen_1000") else {
        return;
    };
    let seq = Sequence::open(&root, &OpenOptions::default()).unwrap();
    let camera = *seq.info().camera.pinhole();
    let (width, height) = seq.info().size;
    let config = DenseModelConfig::default();
    let mut model = DenseModel::new(config.clone()).unwrap();
    let mut raw: Vec<Vector3<f64>> = Vec::new();
    let t0 = std::time::Instant::now();
    let mut cloud_points = 0;
    for index in (0..seq.len()).step_by(40) {
        let frame = seq.read(index).unwrap().unwrap();
        let FrameImages::Rgbd {
            image,
            colour,
            depth: Some(depth),
        } = &frame.images
        else {
            panic!("frame {index} has no depth");
        };
        let colour = colour.as_ref().map_or(Colour::Grey(image), Colour::Rgb);
        let cloud = KeyframeCloud::from_depth(
            |u, v| depth.metres_at(u, v),
            (width, height),
            colour,
            &camera,
            &config,
        );
        cloud_points += cloud.len();
        let world_from_camera = frame.world_from_camera.unwrap();
        model.add(&Sim3::from_se3(&world_from_camera.inverse()), &cloud);
        // The raw samples (every 8th pixel, enough for a reference distribution).
        for v in (0..height).step_by(8) {
            for u in (0..width).step_by(8) {
                if let Some(d) = depth.metres_at(u, v).filter(|&d| d <= config.max_depth())
                    && let Ok(x) = camera.unproject_depth(&Vector2::new(u as f64, v as f64), d)
                {
                    raw.push(world_from_camera.act(&x));
                }
            }
        }
    }
    let fusion_seconds = t0.elapsed().as_secs_f64();
    let points = model.points();
    let fused: Vec<Vector3<f64>> = points.iter().map(|p| p.position).collect();
    let coloured = points.iter().filter(|p| p.colour.is_some()).count();
    let mut fused_d = Vec::new();
    let mut raw_d = Vec::new();
    for index in (20..seq.len()).step_by(40) {
        let frame = seq.read(index).unwrap().unwrap();
        let FrameImages::Rgbd {
            depth: Some(depth), ..
        } = &frame.images
        else {
            panic!("frame {index} has no depth");
        };
        let camera_from_world: Se3 = frame.world_from_camera.unwrap().inverse();
        // The cloud rendered with a z-buffer of 8×8-pixel cells: per cell the nearest point,
        // compared with the measured depth at its own pixel.
        let cell = 8;
        let (cw, ch) = (width.div_ceil(cell), height.div_ceil(cell));
        let residuals = |cloud: &[Vector3<f64>], out: &mut Vec<f64>| {
            let mut zbuf: Vec<Option<(f64, usize, usize)>> = vec![None; cw * ch];
            for x in cloud {
                let xc = camera_from_world.act(x);
                let Ok(p) = camera.project(&xc) else { continue };
                let (u, v) = (p.x.round(), p.y.round());
                if u < 0.0 || v < 0.0 || u >= width as f64 || v >= height as f64 {
                    continue;
                }
                let (u, v) = (u as usize, v as usize);
                let z = &mut zbuf[(v / cell) * cw + u / cell];
                if z.is_none_or(|(zz, _, _)| xc.z < zz) {
                    *z = Some((xc.z, u, v));
                }
            }
            for (z, u, v) in zbuf.into_iter().flatten() {
                if let Some(d) = depth.metres_at(u, v) {
                    out.push((z - d).abs());
                }
            }
        };
        residuals(&fused, &mut fused_d);
        residuals(&raw, &mut raw_d);
    }
    let within = |v: &[f64], t: f64| v.iter().filter(|&&d| d <= t).count() as f64 / v.len() as f64;
    let (fused_median, fused_p90) = median_and_p90(&mut fused_d);
    let (raw_median, raw_p90) = median_and_p90(&mut raw_d);
    eprintln!(
        "fused {} keyframes ({} camera-frame voxels) into {} points ({} voxels before the \
         {}-view filter; {coloured} coloured), voxel {:.1} cm, in {:.2} s",
        model.views(),
        cloud_points,
        points.len(),
        model.voxel_count(),
        config.min_views,
        100.0 * config.voxel_size,
        fusion_seconds
    );
    eprintln!(
        "distance to held-out surfaces: fused median {:.1} mm, 90 % {:.1} mm, {:.1} % within \
         5 cm ({} samples); raw keyframe samples median {:.1} mm, 90 % {:.1} mm, {:.1} % within \
         5 cm",
        1000.0 * fused_median,
        1000.0 * fused_p90,
        100.0 * within(&fused_d, 0.05),
        fused_d.len(),
        1000.0 * raw_median,
        1000.0 * raw_p90,
        100.0 * within(&raw_d, 0.05)
    );
    // Most cells of the 25 held-out frames (25 × 80 × 60) see the model.
    assert!(fused_d.len() > 60_000, "{} samples", fused_d.len());
    // "Within a few cm": the median within 2 cm (the ground truth's own consistency is
    // 6–15 mm), and no farther than the raw data's.
    assert!(fused_median < 0.02, "median {fused_median} m");
    assert!(
        fused_median <= raw_median * 1.05,
        "{fused_median} vs raw {raw_median}"
    );
    assert_eq!(coloured, points.len());
}
