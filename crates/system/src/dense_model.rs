//! Dense model fusion (thesis §6.5.3): "the dense point clouds can be registered to the
//! optimised frames and used to construct a dense environment model cheaply".
//!
//! Each keyframe contributes its valid depth pixels, sampled on a stride
//! ([`KeyframeCloud::from_depth`]), back-projected into its camera frame (thesis eq. 3.5) and
//! coloured from its colour planes (or grey). A keyframe's samples are averaged per voxel of
//! its own camera frame already, so that what a keyframe keeps until the end of the run is
//! bounded by the surface it sees, not by its pixel count. Once the poses are final (after
//! the last optimisation and loop correction), [`DenseModel::add`] places every keyframe's
//! cloud in the world with its pose, `x_w = S_cw⁻¹·x_c` (the graph stores
//! `camera_from_world: Sim3`), and a voxel grid in the world averages position and colour per
//! voxel; voxels seen from fewer than `min_views` keyframes are discarded
//! ([`DenseModel::points`]): flying pixels at depth edges, multipath and noise outliers are
//! seen from one keyframe, a surface from several.
//!
//! Memory: the grid is a hash map of the occupied voxels only, so it grows with the mapped
//! surface area `A` as `A / voxel²` (≈ 50 bytes a voxel: a 100 m² room at 1.7 cm is ~17 MB),
//! whatever the number of keyframes.

use crate::frame::depth_off_edges;
use data::output::{MapPoint, PlyFormat, write_ply};
use data::sequence::RgbPlanes;
use geom::PinholeCamera;
use lie::{LieGroup, Sim3};
use nalgebra::{Vector2, Vector3};
use std::collections::HashMap;
use vision::image::GrayImage;

pub use crate::config::{DenseModelConfig, DenseModelError, KINECT_DEPTH_NOISE, TYPICAL_DEPTH};

/// Where a keyframe's colour comes from.
#[derive(Clone, Copy, Debug)]
pub enum Colour<'a> {
    /// Colour planes registered to the depth image.
    Rgb(&'a RgbPlanes),
    /// A grey image: grey points.
    Grey(&'a GrayImage),
    /// No colour.
    None,
}

impl Colour<'_> {
    fn at(&self, u: usize, v: usize) -> Option<[u8; 3]> {
        let inside = |i: &GrayImage| u < i.width() && v < i.height();
        match self {
            Colour::Rgb(p) if p.iter().all(inside) => {
                Some([p[0].get(u, v), p[1].get(u, v), p[2].get(u, v)])
            }
            Colour::Grey(g) if inside(g) => {
                let x = g.get(u, v);
                Some([x, x, x])
            }
            _ => None,
        }
    }
}

/// Sums of the samples in one voxel.
#[derive(Clone, Copy, Debug, Default)]
struct Accumulator {
    position: Vector3<f64>,
    colour: [u32; 3],
    coloured: u32,
    samples: u32,
}

impl Accumulator {
    fn add(&mut self, x: &Vector3<f64>, weight: u32, colour: Option<[u32; 3]>, coloured: u32) {
        self.position += x * weight as f64;
        self.samples += weight;
        if let Some(c) = colour {
            for (sum, x) in self.colour.iter_mut().zip(c) {
                *sum += x;
            }
            self.coloured += coloured;
        }
    }

    fn mean_colour(&self) -> Option<[u8; 3]> {
        (self.coloured > 0).then(|| {
            let n = self.coloured as f64;
            self.colour
                .map(|c| (c as f64 / n).round().clamp(0.0, 255.0) as u8)
        })
    }
}

fn voxel_of(x: &Vector3<f64>, voxel: f64) -> [i32; 3] {
    [
        (x.x / voxel).floor() as i32,
        (x.y / voxel).floor() as i32,
        (x.z / voxel).floor() as i32,
    ]
}

/// One keyframe's depth samples in its camera frame, averaged per camera-frame voxel: what the
/// live system keeps of a keyframe for the dense model until the poses are final.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct KeyframeCloud {
    /// Mean camera-frame positions (metres).
    pub points: Vec<Vector3<f32>>,
    /// Sum of the colours of the coloured samples of each point, and their count.
    pub colours: Vec<([u32; 3], u32)>,
    /// Samples averaged into each point.
    pub samples: Vec<u32>,
}

impl KeyframeCloud {
    /// The samples of one keyframe: every `stride`-th pixel with a valid depth (`depth(u, v)` in
    /// metres) up to the maximum depth and off depth edges, back-projected through `camera`
    /// (`x = z·K⁻¹·(u, v, 1)ᵀ`, thesis eq. 3.5), coloured from `colour`, averaged per voxel.
    pub fn from_depth(
        depth: impl Fn(usize, usize) -> Option<f64>,
        (width, height): (usize, usize),
        colour: Colour<'_>,
        camera: &PinholeCamera,
        config: &DenseModelConfig,
    ) -> Self {
        let stride = config.stride_for(camera);
        let max_depth = config.max_depth();
        let mut cells: HashMap<[i32; 3], Accumulator> = HashMap::new();
        for v in (stride / 2..height).step_by(stride) {
            for u in (stride / 2..width).step_by(stride) {
                let Some(z) =
                    depth_off_edges(&depth, u as f64, v as f64, 1, config.depth_edge_ratio)
                else {
                    continue;
                };
                if z > max_depth {
                    continue;
                }
                let Ok(x) = camera.unproject_depth(&Vector2::new(u as f64, v as f64), z) else {
                    continue;
                };
                let c = colour.at(u, v).map(|c| c.map(u32::from));
                cells
                    .entry(voxel_of(&x, config.voxel_size))
                    .or_default()
                    .add(&x, 1, c, 1);
            }
        }
        // Sorted by cell so that the cloud (and the model built from it) does not depend on
        // the hash map's iteration order.
        let mut cells: Vec<_> = cells.into_iter().collect();
        cells.sort_unstable_by_key(|(k, _)| *k);
        let mut cloud = KeyframeCloud::default();
        for (_, a) in cells {
            cloud
                .points
                .push((a.position / a.samples as f64).map(|x| x as f32));
            cloud.colours.push((a.colour, a.coloured));
            cloud.samples.push(a.samples);
        }
        cloud
    }

    /// Number of (voxel-averaged) points.
    pub fn len(&self) -> usize {
        self.points.len()
    }

    /// `true` if the keyframe had no valid depth.
    pub fn is_empty(&self) -> bool {
        self.points.is_empty()
    }
}

#[derive(Clone, Copy, Debug, Default)]
struct Voxel {
    sums: Accumulator,
    views: u32,
    last_view: u32,
}

/// The fused model: a voxel grid in the world (see the [module docs](self)).
#[derive(Clone, Debug)]
pub struct DenseModel {
    config: DenseModelConfig,
    voxels: HashMap<[i32; 3], Voxel>,
    views: u32,
}

impl DenseModel {
    /// An empty model.
    pub fn new(config: DenseModelConfig) -> Result<Self, DenseModelError> {
        config.validate()?;
        Ok(DenseModel {
            config,
            voxels: HashMap::new(),
            views: 0,
        })
    }

    /// The configuration.
    pub fn config(&self) -> &DenseModelConfig {
        &self.config
    }

    /// Occupied voxels (before the `min_views` filter).
    pub fn voxel_count(&self) -> usize {
        self.voxels.len()
    }

    /// Keyframes added.
    pub fn views(&self) -> usize {
        self.views as usize
    }

    /// Adds one keyframe's cloud with its final pose `camera_from_world` (as the SLAM graph
    /// stores it): each point enters the voxel of `x_w = S⁻¹·x_c` with its sample count as
    /// weight; the keyframe counts once per voxel it reaches.
    pub fn add(&mut self, camera_from_world: &Sim3, cloud: &KeyframeCloud) {
        self.views += 1;
        let view = self.views;
        let world_from_camera = camera_from_world.inverse();
        for ((x, (colour, coloured)), &samples) in
            cloud.points.iter().zip(&cloud.colours).zip(&cloud.samples)
        {
            let xw = world_from_camera.act(&x.map(f64::from));
            let voxel = self
                .voxels
                .entry(voxel_of(&xw, self.config.voxel_size))
                .or_default();
            voxel.sums.add(&xw, samples, Some(*colour), *coloured);
            if voxel.last_view != view {
                voxel.last_view = view;
                voxel.views += 1;
            }
        }
    }

    /// The model: the mean position and colour of every voxel seen from at least `min_views`
    /// keyframes, ordered by voxel (deterministic).
    pub fn points(&self) -> Vec<MapPoint> {
        let mut kept: Vec<(&[i32; 3], &Voxel)> = self
            .voxels
            .iter()
            .filter(|(_, v)| v.views as usize >= self.config.min_views)
            .collect();
        kept.sort_unstable_by_key(|(k, _)| **k);
        kept.into_iter()
            .map(|(_, v)| MapPoint {
                position: v.sums.position / v.sums.samples as f64,
                colour: v.sums.mean_colour(),
            })
            .collect()
    }

    /// Writes [`points`](Self::points) as a binary PLY (`data::output::write_ply`).
    pub fn write_ply(&self, out: impl std::io::Write) -> std::io::Result<()> {
        write_ply(&self.points(), PlyFormat::Binary, out)
    }
}

/// The dense model of a run (thesis §6.5.3): every keyframe of `graph` whose images `store`
/// holds, its depth sampled ([`KeyframeCloud::from_depth`], in parallel) and placed with its
/// final pose, in keyframe order (the model does not depend on the thread count). Only the
/// keyframes of map `map` (the map written, `crate::live::RunResult::world_map`): another map's
/// place in the world is a guess.
pub fn fuse(
    graph: &slam::map::SlamGraph<3>,
    map: usize,
    store: &crate::keyframes::KeyframeStore,
    camera: &PinholeCamera,
    config: &DenseModelConfig,
) -> Result<DenseModel, DenseModelError> {
    use rayon::prelude::*;
    let mut model = DenseModel::new(config.clone())?;
    let keyframes: Vec<_> = graph
        .keyframes()
        .filter(|&(k, _)| graph.map_of(k) == Ok(map))
        .filter_map(|(k, kf)| {
            let images = store.get(k)?;
            images.depth.as_ref()?;
            Some((*kf.camera_from_world(), images.clone()))
        })
        .collect();
    let clouds: Vec<(Sim3, KeyframeCloud)> = keyframes
        .par_iter()
        .map(|(pose, images)| {
            let depth = images.depth.as_ref().expect("filtered above");
            let colour = match &images.colour {
                Some(planes) => Colour::Rgb(planes),
                None => Colour::Grey(&images.gray),
            };
            let cloud = KeyframeCloud::from_depth(
                |u, v| crate::frame::pixel_depth(depth, u, v),
                (depth.width(), depth.height()),
                colour,
                camera,
                config,
            );
            (*pose, cloud)
        })
        .collect();
    for (pose, cloud) in &clouds {
        model.add(pose, cloud);
    }
    Ok(model)
}

#[cfg(test)]
mod tests {
    use super::*;
    use lie::{Se3, So3};
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    fn camera() -> PinholeCamera {
        PinholeCamera::new(585.0, 585.0, 319.5, 239.5)
    }

    /// The depth image of the plane `z_w = plane` (plus, optionally, a box in front of it over
    /// a patch of the image) seen from `world_from_camera`, with seeded noise of σ metres.
    fn plane_depth(
        world_from_camera: &Se3,
        plane: f64,
        sigma: f64,
        seed: u64,
        blob: bool,
    ) -> Vec<Option<f64>> {
        let cam = camera();
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let r = world_from_camera.rotation().rotation_matrix();
        let c = world_from_camera.translation();
        let mut out = Vec::with_capacity(640 * 480);
        for v in 0..480 {
            for u in 0..640 {
                let m = cam.normalised_from_pixel(&Vector2::new(u as f64, v as f64));
                let ray = r * Vector3::new(m.x, m.y, 1.0);
                // c + z·ray on the plane: the camera-frame depth z.
                let z = (plane - c.z) / ray.z;
                let noise: f64 = rng.random_range(-1.0..1.0) * sigma * 3f64.sqrt();
                let in_blob = blob && (300..340).contains(&u) && (200..240).contains(&v);
                let z = if in_blob { 0.6 * z } else { z };
                out.push((z > 0.0 && z.is_finite()).then_some(z + noise));
            }
        }
        out
    }

    fn poses() -> Vec<Se3> {
        // Cameras 2–2.5 m above the plane z = 0 looking down (+z of the camera = −z of the
        // world), translated and tilted by up to ~20°.
        let down = So3::rot_x(std::f64::consts::PI);
        [
            (0.0, 0.0, 2.5, 0.0, 0.0),
            (0.4, 0.1, 2.3, 0.15, -0.1),
            (-0.3, 0.3, 2.4, -0.2, 0.1),
            (0.2, -0.4, 2.2, 0.1, 0.3),
        ]
        .into_iter()
        .map(|(x, y, z, a, b)| {
            Se3::new(
                So3::rot_y(a).compose(&So3::rot_x(b)).compose(&down),
                Vector3::new(x, y, z),
            )
        })
        .collect()
    }

    /// A plane seen from several tilted poses fuses into a single layer of voxels at the plane
    /// (here the plane is at the centre of a voxel layer, z = −0.5·voxel, so noise of ±3σ =
    /// ±3 mm stays within it), with points on the plane to the noise; a blob seen by one
    /// keyframe only is discarded by `min_views = 2` and kept with 1.
    #[test]
    fn a_plane_from_several_poses_is_one_layer_of_voxels() {
        let config = DenseModelConfig::default();
        let voxel = config.voxel_size;
        let plane = -0.5 * voxel;
        let mut model = DenseModel::new(config.clone()).unwrap();
        let mut single = DenseModel::new(DenseModelConfig {
            min_views: 1,
            ..config.clone()
        })
        .unwrap();
        for (k, pose) in poses().iter().enumerate() {
            let d = plane_depth(pose, plane, 0.001, k as u64, k == 1);
            let cloud = KeyframeCloud::from_depth(
                |u, v| {
                    if u < 640 && v < 480 {
                        d[v * 640 + u]
                    } else {
                        None
                    }
                },
                (640, 480),
                Colour::None,
                &camera(),
                &config,
            );
            assert!(!cloud.is_empty());
            let camera_from_world = Sim3::from_se3(&pose.inverse());
            model.add(&camera_from_world, &cloud);
            single.add(&camera_from_world, &cloud);
        }
        let points = model.points();
        assert!(points.len() > 1000, "{}", points.len());
        let layers: std::collections::BTreeSet<i32> = points
            .iter()
            .map(|p| (p.position.z / voxel).floor() as i32)
            .collect();
        assert_eq!(layers.len(), 1, "layers {layers:?}");
        let worst = points
            .iter()
            .map(|p| (p.position.z - plane).abs())
            .fold(0.0, f64::max);
        assert!(worst < 0.003, "{worst}");
        // The blob (at 60 % of the plane's depth) exists only in the single-view model.
        let off_plane = |m: &DenseModel| {
            m.points()
                .iter()
                .filter(|p| (p.position.z - plane).abs() > 0.1)
                .count()
        };
        assert_eq!(off_plane(&model), 0);
        assert!(off_plane(&single) > 10, "{}", off_plane(&single));
        // Bounded by the surface: the grid holds about area / voxel² voxels.
        assert!(model.voxel_count() < single.points().len() + 1);
        assert_eq!(model.views(), 4);
    }

    #[test]
    fn defaults_follow_the_noise_model_and_colours_average() {
        let c = DenseModelConfig::default();
        assert!((c.voxel_size - 0.0171).abs() < 1e-6);
        assert_eq!(c.stride_for(&camera()), 2);
        assert!((c.max_depth() - 3.464).abs() < 1e-3);
        assert!(
            DenseModelConfig {
                voxel_size: 0.0,
                ..c.clone()
            }
            .validate()
            .is_err()
        );
        assert!(
            DenseModelConfig {
                min_views: 0,
                ..c.clone()
            }
            .validate()
            .is_err()
        );
        let yaml: DenseModelConfig = serde_saphyr::from_str("voxel_size: 0.05\n").unwrap();
        assert_eq!((yaml.voxel_size, yaml.min_views), (0.05, 2));
        // Two views of one point with colours 100 and 200: the mean, 150.
        let planes = |x: u8| {
            [
                GrayImage::filled(8, 8, x),
                GrayImage::filled(8, 8, x),
                GrayImage::filled(8, 8, 0),
            ]
        };
        let (a, b) = (planes(100), planes(200));
        let config = DenseModelConfig {
            stride: Some(8),
            ..c
        };
        let mut m = DenseModel::new(config.clone()).unwrap();
        for p in [&a, &b] {
            let cloud = KeyframeCloud::from_depth(
                |u, v| (u < 8 && v < 8).then_some(1.0),
                (8, 8),
                Colour::Rgb(p),
                &camera(),
                &config,
            );
            assert_eq!(cloud.len(), 1);
            m.add(&Sim3::default(), &cloud);
        }
        let pts = m.points();
        assert_eq!(pts.len(), 1);
        assert_eq!(pts[0].colour, Some([150, 150, 0]));
        let mut ply = Vec::new();
        m.write_ply(&mut ply).unwrap();
        assert!(String::from_utf8_lossy(&ply).contains("element vertex 1"));
    }
}
