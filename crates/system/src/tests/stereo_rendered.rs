//! The stereo front-end against exact depth: each corner's stereo measurement (`u_r` from the
//! block-matched map refined on the point's own patch, `FrameData::stereo_measurement`) on
//! rendered pairs — textures, sensor noise, motion blur, vignetting — compared with the
//! disparity the renderer's depth gives at the corner.
//!
//! This is what separates the stereo's own error from a dataset's calibration or ground truth:
//! a disparity bias of δ pixels scales the depths (and a stereo trajectory) by `d/(d − δ)`, so
//! the 0.3 % that both dwslam and ORB-SLAM3 are too long on the KITTI snippet (disparities
//! 12–22 px) would take a bias of about 0.05 px.

use crate::config::{StereoMatching, SystemConfig};
use crate::frame::SensorFrontEnd;
use lie::LieGroup;
use nalgebra::Vector2;
use sim::render::sensor::DEFAULT_STEREO_BASELINE;
use sim::render::{
    DEFAULT_REVISIT_JITTER, Renderer, SceneKind, SensorKind, SensorModel, Sequence, SequenceConfig,
    ViewOptions,
};

/// The errors (measured − true disparity, pixels) of the stereo measurements of the corners on
/// smooth surfaces of `frames` frames spread over `scene`, by `matching` (dense: block matching
/// at `level`); and how many such corners there were.
fn disparity_errors(
    scene: SceneKind,
    frames: usize,
    matching: StereoMatching,
    level: usize,
) -> (Vec<f64>, usize) {
    let sensor = SensorModel::new(
        SensorKind::Stereo {
            baseline: DEFAULT_STEREO_BASELINE,
        },
        640,
        480,
    );
    let mut sequence = Sequence::new(SequenceConfig {
        scene,
        sensor,
        seed: 1,
        path_seed: None,
        frames: None,
        revisit_jitter: DEFAULT_REVISIT_JITTER,
    })
    .unwrap();
    // A second renderer of the same world for the exact depth of the left camera's view.
    let mut truth = Renderer::new(sequence.renderer().scene().clone());
    let camera = sensor.sequence_camera().unwrap();
    let data::camera::SensorModel::Stereo(stereo) = camera else {
        unreachable!("a stereo sensor")
    };
    let fb = stereo.pinhole.fx * stereo.baseline;
    let mut config = SystemConfig::default();
    config.stereo.matching = matching;
    config.stereo.level = level;
    config.stereo.threads = Some(1);
    let mut front = SensorFrontEnd::new(&camera, &config).unwrap();
    let (w, h) = (sensor.camera.width, sensor.camera.height);
    let (mut errors, mut corners) = (Vec::new(), 0);
    let step = sequence.len() / frames;
    for k in (0..frames).map(|i| i * step + step / 2) {
        let frame = sequence.render_frame(k).unwrap();
        let pixels = truth
            .render(
                &sensor.camera,
                &frame.world_from_camera.inverse(),
                &ViewOptions {
                    supersampling: 1,
                    colour: false,
                    depth: true,
                },
            )
            .unwrap();
        let depth = |x: usize, y: usize| pixels[y * w + x].depth as f64;
        let data = front.prepare(frame.to_sequence_frame()).unwrap();
        for c in data.corners.corners() {
            let (x, y) = (c.u.round() as usize, c.v.round() as usize);
            if x < 3 || y < 3 || x + 3 >= w || y + 3 >= h {
                continue;
            }
            // Only where the surface is smooth (the 5×5 depths within 1 %), so that the true
            // disparity at the corner is well defined: the inverse depth interpolated there.
            let z0 = depth(x, y);
            let smooth = z0 > 0.0
                && (y - 2..=y + 2)
                    .all(|yy| (x - 2..=x + 2).all(|xx| (depth(xx, yy) - z0).abs() <= 0.01 * z0));
            if !smooth {
                continue;
            }
            corners += 1;
            let (x0, y0) = (c.u.floor() as usize, c.v.floor() as usize);
            let (ax, ay) = (c.u as f64 - x0 as f64, c.v as f64 - y0 as f64);
            let inv = |x, y| 1.0 / depth(x, y);
            let inverse_depth = (1.0 - ay) * ((1.0 - ax) * inv(x0, y0) + ax * inv(x0 + 1, y0))
                + ay * ((1.0 - ax) * inv(x0, y0 + 1) + ax * inv(x0 + 1, y0 + 1));
            let u = Vector2::new(c.u as f64, c.v as f64);
            if let Some(z) = data.stereo_measurement(u, &stereo) {
                errors.push((z.x - z.z) - fb * inverse_depth);
            }
        }
    }
    (errors, corners)
}

/// On the three rendered worlds (disparities of 4–60 px), with sparse stereo (the default, 12
/// frames each) and with the disparity map at block-matching level 0 and 1 (4 frames each):
/// most corners on smooth surfaces are measured (measured 89–92 % sparse, 85–91 % dense); the
/// disparities are unbiased to 0.005 px (measured sparse: at most 0.0020 px; 0.005 px is 0.025 %
/// of depth at 20 px of disparity), their median error is at most 0.05 px (measured sparse
/// 0.034–0.050 px) and errors over a pixel are rare (measured 0.01–0.06 %). The dense maps,
/// kept as an option, are held to 0.01 px of bias and 0.1 px of median.
#[test]
fn stereo_measurements_on_rendered_pairs_agree_with_the_exact_depth() {
    for scene in [SceneKind::Room, SceneKind::Courtyard, SceneKind::Building] {
        for (how, matching, level) in [
            ("sparse", StereoMatching::Sparse, 0),
            ("dense level 0", StereoMatching::Dense, 0),
            ("dense level 1", StereoMatching::Dense, 1),
        ] {
            let frames = if matching == StereoMatching::Sparse {
                12
            } else {
                4
            };
            let (errors, corners) = disparity_errors(scene, frames, matching, level);
            let mut abs: Vec<f64> = errors.iter().map(|e| e.abs()).collect();
            abs.sort_by(f64::total_cmp);
            let quantile = |p: f64| abs[((abs.len() - 1) as f64 * p) as usize];
            let inliers: Vec<f64> = errors.iter().copied().filter(|e| e.abs() <= 1.0).collect();
            let gross = errors.len() - inliers.len();
            let bias = inliers.iter().sum::<f64>() / inliers.len() as f64;
            let measured = errors.len() as f64 / corners as f64;
            println!(
                "{} {how}: {} of {corners} corners measured ({:.1} %), |error| median \
                 {:.3} px, 90 % {:.3} px, 99 % {:.3} px, {gross} over 1 px, mean {bias:+.4} px",
                scene.name(),
                errors.len(),
                100.0 * measured,
                quantile(0.5),
                quantile(0.9),
                quantile(0.99),
            );
            let what = format!("{} {how}", scene.name());
            assert!(corners >= 1000, "{what}: {corners} corners");
            assert!(
                measured >= 0.75,
                "{what}: {:.1} % measured",
                100.0 * measured
            );
            let (max_bias, max_median) = match matching {
                StereoMatching::Sparse => (0.005, 0.05),
                StereoMatching::Dense => (0.01, 0.1),
            };
            assert!(bias.abs() <= max_bias, "{what}: bias {bias} px");
            assert!(
                quantile(0.5) <= max_median,
                "{what}: median {} px",
                quantile(0.5)
            );
            assert!(quantile(0.9) < 0.3, "{what}: 90 % {} px", quantile(0.9));
            assert!(
                (gross as f64) < 0.005 * errors.len() as f64,
                "{what}: {gross} of {} over 1 px",
                errors.len()
            );
        }
    }
}
