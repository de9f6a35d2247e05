//! Sensor front-ends (thesis §6.3, §6.5.3): a frame from the reader becomes what tracking
//! needs — the grey image's pyramid, its FAST corners indexed by position, and depth: from the
//! depth camera (RGB-D as a virtual stereo camera), or from the stereo pair, measured at the
//! points the system asks for (sparse stereo, `vision::stereo::sparse`; the default) or read
//! from a block-matched disparity image (`stereo.matching: dense`).

use crate::config::{StereoMatching, SystemConfig};
use data::camera::SensorModel;
use data::sequence::{Frame, FrameImages, RgbPlanes};
use geom::{PinholeCamera, StereoCamera};
use lie::Se3;
use nalgebra::{Vector2, Vector3};
use vision::fast::{Corner, fast9_level};
use vision::image::{GrayImage, Image, ImageError};
use vision::pyramid::{Pyramid, half_sample};
use vision::stereo::{
    SparseParams, StereoMatcher, StereoParams, disparity_to_depth, point_block_disparity,
    point_disparity,
};

/// Why a frame could not be prepared.
#[derive(Debug, thiserror::Error)]
pub enum FrameError {
    /// An image operation failed (sizes, too small).
    #[error(transparent)]
    Image(#[from] ImageError),
    /// The frame does not fit the sensor (e.g. a mono frame for a stereo run).
    #[error("frame {index}: {what}")]
    Sensor {
        /// The frame.
        index: usize,
        /// What is wrong.
        what: String,
    },
}

/// FAST corners of an image, indexed by a grid for radius queries.
#[derive(Clone, Debug)]
pub struct CornerIndex {
    corners: Vec<Corner>,
    cell: f32,
    cols: usize,
    rows: usize,
    /// Start of each cell's corners in `order` (CSR layout: no allocation per cell).
    start: Vec<u32>,
    order: Vec<u32>,
}

impl CornerIndex {
    /// Indexes `corners` of a `width × height` image with square cells of `cell` pixels.
    pub fn new(corners: Vec<Corner>, width: usize, height: usize, cell: f32) -> Self {
        let cols = ((width as f32 / cell).ceil() as usize).max(1);
        let rows = ((height as f32 / cell).ceil() as usize).max(1);
        let cell_of = |c: &Corner| -> usize {
            let cu = ((c.u / cell) as usize).min(cols - 1);
            let cv = ((c.v / cell) as usize).min(rows - 1);
            cv * cols + cu
        };
        let mut count = vec![0u32; cols * rows + 1];
        for c in &corners {
            count[cell_of(c) + 1] += 1;
        }
        for i in 1..count.len() {
            count[i] += count[i - 1];
        }
        let mut fill = count.clone();
        let mut order = vec![0u32; corners.len()];
        for (i, c) in corners.iter().enumerate() {
            let k = cell_of(c);
            order[fill[k] as usize] = i as u32;
            fill[k] += 1;
        }
        CornerIndex {
            corners,
            cell,
            cols,
            rows,
            start: count,
            order,
        }
    }

    /// All corners.
    pub fn corners(&self) -> &[Corner] {
        &self.corners
    }

    /// The corners within `radius` of `(u, v)`, appended to `out` (cleared first).
    pub fn within(&self, u: f32, v: f32, radius: f32, out: &mut Vec<Corner>) {
        out.clear();
        let lo = |x: f32| ((x - radius) / self.cell).floor().max(0.0) as usize;
        let (c0, r0) = (lo(u), lo(v));
        let c1 = (((u + radius) / self.cell) as usize).min(self.cols - 1);
        let r1 = (((v + radius) / self.cell) as usize).min(self.rows - 1);
        let r2 = radius * radius;
        for r in r0..=r1 {
            for c in c0..=c1 {
                let k = r * self.cols + c;
                for &i in &self.order[self.start[k] as usize..self.start[k + 1] as usize] {
                    let p = self.corners[i as usize];
                    let (du, dv) = (p.u - u, p.v - v);
                    if du * du + dv * dv <= r2 {
                        out.push(p);
                    }
                }
            }
        }
    }
}

/// The depth at an image point (a keypoint, a sampled pixel) unless it lies on a depth edge:
/// the depth of the nearest pixel, accepted only if the valid depths of its
/// `(2·radius+1)²` neighbourhood all lie within `edge_ratio` (relative) of it. FAST corners often
/// sit on depth discontinuities, where the pixel's depth may belong to either side (and, with
/// colour and depth not registered exactly, to the wrong one); a relative spread of a few
/// percent over one pixel is what a surface shows even at grazing angles (at 3 m and 80° of
/// slant, 1 px spans 1 % of depth), while a discontinuity shows much more.
pub fn depth_off_edges(
    depth: &impl Fn(usize, usize) -> Option<f64>,
    u: f64,
    v: f64,
    radius: usize,
    edge_ratio: f64,
) -> Option<f64> {
    if !(u.is_finite() && v.is_finite()) || u < -0.5 || v < -0.5 {
        return None;
    }
    let (pu, pv) = ((u + 0.5) as usize, (v + 0.5) as usize);
    let d = depth(pu, pv).filter(|d| d.is_finite() && *d > 0.0)?;
    let r = radius as i64;
    for dv in -r..=r {
        for du in -r..=r {
            let (nu, nv) = (pu as i64 + du, pv as i64 + dv);
            if nu < 0 || nv < 0 || (du, dv) == (0, 0) {
                continue;
            }
            if let Some(n) = depth(nu as usize, nv as usize)
                && n.is_finite()
                && n > 0.0
                && (n - d).abs() > edge_ratio * d
            {
                return None;
            }
        }
    }
    Some(d)
}

/// Pixel `(x, y)` of a depth image in metres, `None` outside or where invalid.
pub fn pixel_depth(depth: &Image<f32>, x: usize, y: usize) -> Option<f64> {
    if x >= depth.width() || y >= depth.height() {
        return None;
    }
    let z = depth.get(x, y);
    (z.is_finite() && z > 0.0).then_some(z as f64)
}

/// The relative depth difference within a point's neighbourhood that still counts as one
/// smooth surface (see [`FrameData::depth_at`]): 3 %, three times the Kinect's noise at 2 m
/// (σ_z ≈ 1.5·10⁻³·z²) and the disparity error of a quarter pixel at 20 px of stereo
/// disparity, far below a depth step between objects.
pub const DEPTH_AGREEMENT: f32 = 0.03;

/// A frame prepared for tracking.
#[derive(Clone, Debug)]
pub struct FrameData {
    /// Position in the sequence.
    pub index: usize,
    /// Seconds.
    pub timestamp: f64,
    /// The grey (left / colour) image's pyramid.
    pub pyramid: Pyramid,
    /// FAST corners of level 0.
    pub corners: CornerIndex,
    /// Depth per pixel of level 0 in metres (`NaN` where unknown); `None` for frames without
    /// depth (an RGB-D frame whose depth image is missing). With sparse stereo
    /// ([`FrameData::sparse`]) a coarse block-matched map, for tracking's dense prior only:
    /// the points' depths are measured at the points.
    pub depth: Option<Image<f32>>,
    /// Colour planes, where the images have colour.
    pub colour: Option<RgbPlanes>,
    /// The right image of a stereo pair (level 0), where each point's disparity is measured
    /// ([`FrameData::stereo_measurement`]); `None` for RGB-D frames.
    pub right: Option<GrayImage>,
    /// Sparse stereo: each point's disparity searched along its row of the right image
    /// ([`point_block_disparity`]) instead of read from [`FrameData::depth`].
    pub sparse: Option<SparseStereo>,
    /// Ground truth `world_from_camera`, if the dataset has it.
    pub ground_truth: Option<Se3>,
}

impl FrameData {
    /// The grey image (level 0).
    pub fn gray(&self) -> &GrayImage {
        &self.pyramid.levels[0]
    }

    /// The depth (metres) at pixel `(u, v)`, off depth edges. From a depth image: the nearest
    /// pixel's, if the valid depths of its 5×5 neighbourhood agree with it to
    /// [`DEPTH_AGREEMENT`] ([`depth_off_edges`]). Corners lie on object boundaries more often
    /// than not, where a depth image (or a disparity map's blocks) mixes the foreground with the
    /// background, and where a depth camera not registered to the colour camera puts the wrong
    /// surface's depth: a point gets its depth only where the surface around it is smooth.
    /// With sparse stereo: the block disparity searched at the nearest pixel, whose shifted
    /// blocks must agree with it (`vision::stereo::SparseParams::agreement`, the same 3 %, or
    /// a quarter pixel: the same test on the blocks themselves).
    pub fn depth_at(&self, u: f64, v: f64) -> Option<f64> {
        if let Some(sparse) = &self.sparse {
            return self.block_depth(sparse, u, v);
        }
        let d = self.depth.as_ref()?;
        depth_off_edges(
            &|x, y| pixel_depth(d, x, y),
            u,
            v,
            2,
            DEPTH_AGREEMENT as f64,
        )
    }

    /// The depth at a keypoint of place recognition (ORB): from a depth image, the nearest
    /// pixel's if its 3×3 neighbours agree to `edge_ratio`; with sparse stereo the block
    /// disparity with the same tolerance, its blocks shifted by one pixel (the 3×3
    /// neighbourhood's analogue).
    pub fn keypoint_depth(&self, u: f64, v: f64, edge_ratio: f64) -> Option<f64> {
        if let Some(sparse) = &self.sparse {
            let looser = SparseStereo {
                params: SparseParams {
                    shift: 1,
                    agreement: edge_ratio as f32,
                    ..sparse.params
                },
                ..*sparse
            };
            return self.block_depth(&looser, u, v);
        }
        let d = self.depth.as_ref()?;
        depth_off_edges(&|x, y| pixel_depth(d, x, y), u, v, 1, edge_ratio)
    }

    /// The depth of [`FrameData::block_disparity`].
    fn block_depth(&self, sparse: &SparseStereo, u: f64, v: f64) -> Option<f64> {
        let d = self.block_disparity(sparse, u, v)?;
        (d > 0.0).then(|| sparse.focal_baseline / d as f64)
    }

    /// The block disparity at the pixel nearest `(u, v)` (sparse stereo).
    fn block_disparity(&self, sparse: &SparseStereo, u: f64, v: f64) -> Option<f32> {
        let right = self.right.as_ref()?;
        if !(u.is_finite() && v.is_finite()) || u < -0.5 || v < -0.5 {
            return None;
        }
        let (x, y) = ((u + 0.5) as usize, (v + 0.5) as usize);
        point_block_disparity(self.gray(), right, x, y, &sparse.params)
    }

    /// The stereo measurement `(u, v, u_r)` of pixel `u` with `camera`, where the frame has a
    /// depth there ([`FrameData::depth_at`]). For a stereo pair the disparity is then measured
    /// at the point itself ([`point_disparity`]: the left image's 8×8 patch around `u` aligned
    /// along the row of the right image, the block disparity as the start), the patch the
    /// tracker matches in the left image: both coordinates measure the same feature.
    ///
    /// Why not the block disparity itself: block matching sums a 9×9 block at the nearest
    /// pixel (the dense map: a 7×7 census over 9×9 blocks), and a corner lies on an object's
    /// boundary more often than not, where that support takes in the surface behind. `None`
    /// where the patch does not align within [`POINT_DISPARITY_MAX_STEP`] of the block's
    /// disparity (the two supports see different surfaces).
    pub fn stereo_measurement(
        &self,
        u: Vector2<f64>,
        camera: &StereoCamera,
    ) -> Option<Vector3<f64>> {
        let start = match &self.sparse {
            Some(sparse) => self.block_disparity(sparse, u.x, u.y)? as f64,
            None => camera.pinhole.fx * camera.baseline / self.depth_at(u.x, u.y)?,
        };
        let d = match &self.right {
            Some(right) => point_disparity(
                self.gray(),
                right,
                u.x as f32,
                u.y as f32,
                start as f32,
                POINT_DISPARITY_MAX_STEP,
            )? as f64,
            None => start,
        };
        Some(Vector3::new(u.x, u.y, u.x - d))
    }
}

/// Sparse stereo's parameters ([`FrameData::sparse`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SparseStereo {
    /// The search (`vision::stereo::sparse`).
    pub params: SparseParams,
    /// `f·b` (pixels · metres): depth = `f·b / disparity`.
    pub focal_baseline: f64,
}

/// Largest change of a point's disparity from the disparity map's (pixels): the block
/// matcher's own left-right tolerance.
pub const POINT_DISPARITY_MAX_STEP: f32 = 1.0;

/// The sensor of a live run: its camera (for RGB-D the virtual stereo camera, thesis §6.5.3)
/// and how it gets depth.
#[derive(Clone, Debug)]
pub struct SensorFrontEnd {
    camera: StereoCamera,
    kind: DepthSource,
    /// Block matching of the disparity image with its buffers kept from frame to frame: the
    /// points' depths with `stereo.matching: dense`, the dense prior's coarse map with sparse
    /// stereo.
    stereo: StereoMatcher,
    /// The pyramid level block matching runs at.
    stereo_level: usize,
    /// Its threads (horizontal bands).
    stereo_threads: usize,
    /// Sparse stereo (the points' disparities searched at the points), if chosen.
    sparse: Option<SparseStereo>,
    /// Full-resolution block matching for keyframes' depth images (the dense model) with sparse
    /// stereo; made when first needed.
    keyframe_matcher: Option<Box<StereoMatcher>>,
    /// Block matching's parameters at full resolution.
    full_params: StereoParams,
    fast_threshold: u8,
    levels: usize,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum DepthSource {
    BlockMatching,
    DepthImage,
}

impl SensorFrontEnd {
    /// The front-end of `sensor` (stereo or RGB-D; monocular runs are a later issue).
    pub fn new(sensor: &SensorModel, config: &SystemConfig) -> Result<Self, FrameError> {
        let (camera, kind) = match sensor {
            SensorModel::Stereo(s) => (*s, DepthSource::BlockMatching),
            SensorModel::Rgbd(r) => (r.stereo, DepthSource::DepthImage),
            SensorModel::Mono(_) => {
                return Err(FrameError::Sensor {
                    index: 0,
                    what: "a monocular camera: the live system runs stereo and RGB-D sensors"
                        .into(),
                });
            }
        };
        let full_params = StereoParams {
            max_disparity: config.stereo.max_disparity_for(camera.pinhole.fx),
            block_radius: config.stereo.block_radius,
            ..StereoParams::default()
        };
        let sparse = (kind == DepthSource::BlockMatching
            && config.stereo.matching == StereoMatching::Sparse)
            .then_some(SparseStereo {
                params: SparseParams {
                    max_disparity: full_params.max_disparity,
                    block_radius: config.stereo.block_radius,
                    ..SparseParams::default()
                },
                focal_baseline: camera.pinhole.fx * camera.baseline,
            });
        // With sparse stereo the disparity image is the dense prior's alone, which aligns
        // images from `tracker.dense_finest_level` up: matched at that level (KITTI at level 2:
        // 1/16 of the pixels over 1/4 of the disparities).
        let stereo_level = match sparse {
            Some(_) => config.tracker.dense_finest_level,
            None => config.stereo.level,
        };
        Ok(SensorFrontEnd {
            camera,
            kind,
            stereo_level,
            stereo_threads: config.stereo.threads(),
            stereo: StereoMatcher::new(StereoParams {
                // The same depth range at every level: the full-resolution disparities scaled.
                max_disparity: full_params.max_disparity.div_ceil(1 << stereo_level),
                ..full_params
            }),
            sparse,
            keyframe_matcher: None,
            full_params,
            fast_threshold: config.tracker.fast_threshold,
            levels: config.tracker.pyramid_levels,
        })
    }

    /// The (virtual) stereo camera whose measurements `(u_l, v_l, u_r)` the map uses.
    pub fn camera(&self) -> &StereoCamera {
        &self.camera
    }

    /// `true` when depth comes from stereo block matching (else from a depth image).
    pub fn measures_disparity(&self) -> bool {
        self.kind == DepthSource::BlockMatching
    }

    /// The pinhole of the left / colour image.
    pub fn pinhole(&self) -> &PinholeCamera {
        &self.camera.pinhole
    }

    /// The depth of a stereo frame at level 0, block-matched at `stereo_level` (the left
    /// image's pyramid level, the right image half-sampled alike), each level-0 pixel taking the
    /// depth of the level pixel it lies in.
    fn stereo_depth(
        &mut self,
        left: &Pyramid,
        right: &GrayImage,
    ) -> Result<Image<f32>, FrameError> {
        let l = self.stereo_level.min(left.levels.len() - 1);
        let scale = 1usize << l;
        let focal = self.camera.pinhole.fx / scale as f64;
        if l == 0 {
            let disparity =
                self.stereo
                    .compute_in_bands(&left.levels[0], right, self.stereo_threads)?;
            return Ok(disparity_to_depth(&disparity, focal, self.camera.baseline));
        }
        let mut r = half_sample(right)?;
        for _ in 1..l {
            r = half_sample(&r)?;
        }
        let disparity = self
            .stereo
            .compute_in_bands(&left.levels[l], &r, self.stereo_threads)?;
        let coarse = disparity_to_depth(&disparity, focal, self.camera.baseline);
        let (w, h) = (left.levels[0].width(), left.levels[0].height());
        let (cw, ch) = (coarse.width(), coarse.height());
        let mut depth = Image::<f32>::new(w, h);
        for y in 0..h {
            let src = coarse.row((y / scale).min(ch - 1));
            for (x, d) in depth.row_mut(y).iter_mut().enumerate() {
                *d = src[(x / scale).min(cw - 1)];
            }
        }
        Ok(depth)
    }

    /// The full-resolution depth image of a keyframe, for the dense model: an RGB-D frame's
    /// depth image, the frame's own map with `stereo.matching: dense` at level 0, else
    /// block-matched now.
    pub fn keyframe_depth(&mut self, frame: &FrameData) -> Result<Option<Image<f32>>, FrameError> {
        let Some(right) = frame
            .right
            .as_ref()
            .filter(|_| self.sparse.is_some() || self.stereo_level > 0)
        else {
            // The depth camera's image, or the full-resolution disparity map's depth.
            return Ok(frame.depth.clone());
        };
        let matcher = self
            .keyframe_matcher
            .get_or_insert_with(|| Box::new(StereoMatcher::new(self.full_params)));
        let disparity = matcher.compute_in_bands(frame.gray(), right, self.stereo_threads)?;
        Ok(Some(disparity_to_depth(
            &disparity,
            self.camera.pinhole.fx,
            self.camera.baseline,
        )))
    }

    /// Prepares a frame: pyramid, FAST corners, depth (with sparse stereo the dense prior's
    /// coarse map only).
    pub fn prepare(&mut self, frame: Frame) -> Result<FrameData, FrameError> {
        let Frame {
            index,
            timestamp,
            images,
            world_from_camera,
        } = frame;
        let (gray, depth, colour, right) = match (images, self.kind) {
            (FrameImages::Stereo { left, right }, DepthSource::BlockMatching) => {
                (left, None, None, Some(right))
            }
            (
                FrameImages::Rgbd {
                    image,
                    colour,
                    depth,
                },
                DepthSource::DepthImage,
            ) => (image, depth.map(|d| d.to_metres()), colour, None),
            (other, _) => {
                return Err(FrameError::Sensor {
                    index,
                    what: format!(
                        "a {} frame for a {} sensor",
                        match other {
                            FrameImages::Mono { .. } => "mono",
                            FrameImages::Stereo { .. } => "stereo",
                            FrameImages::Rgbd { .. } => "RGB-D",
                        },
                        match self.kind {
                            DepthSource::BlockMatching => "stereo",
                            DepthSource::DepthImage => "RGB-D",
                        }
                    ),
                });
            }
        };
        let pyramid = Pyramid::new(&gray, self.levels, 16)?;
        let (w, h) = (gray.width(), gray.height());
        let depth = match &right {
            Some(right) => Some(self.stereo_depth(&pyramid, right)?),
            None => depth,
        };
        let corners = fast9_level(&pyramid.levels[0], self.fast_threshold, true, 0);
        Ok(FrameData {
            index,
            timestamp,
            corners: CornerIndex::new(corners, w, h, 16.0),
            pyramid,
            depth,
            colour,
            right,
            sparse: self.sparse,
            ground_truth: world_from_camera,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn depth_edges_are_rejected() {
        // (radius 1: the 3×3 neighbourhood)
        // A step from 1 m to 2 m between columns 9 and 10.
        let depth =
            |u: usize, v: usize| (u < 40 && v < 40).then_some(if u < 10 { 1.0 } else { 2.0 });
        assert_eq!(depth_off_edges(&depth, 5.0, 5.0, 1, 0.05), Some(1.0));
        assert_eq!(depth_off_edges(&depth, 20.2, 5.4, 1, 0.05), Some(2.0));
        assert_eq!(depth_off_edges(&depth, 9.0, 5.0, 1, 0.05), None);
        assert_eq!(depth_off_edges(&depth, 10.0, 5.0, 1, 0.05), None);
        // Invalid neighbours (outside) do not reject; an invalid centre does.
        assert_eq!(depth_off_edges(&depth, 39.0, 39.0, 1, 0.05), Some(2.0));
        assert_eq!(depth_off_edges(&depth, 45.0, 5.0, 1, 0.05), None);
        assert_eq!(depth_off_edges(&depth, f64::NAN, 5.0, 1, 0.05), None);
        // A slanted plane (1 % per pixel) passes.
        let slant = |u: usize, _v: usize| Some(2.0 * (1.0 + 0.01 * u as f64));
        assert!(depth_off_edges(&slant, 30.0, 3.0, 1, 0.05).is_some());
    }

    /// A rectified pair of a slanted textured plane, disparity `4 + 0.05·u` (6–11 px): the depth
    /// block-matched at level 0 and at level 1 (upsampled) both give each corner's depth, and
    /// every point's stereo measurement, refined on its own patch, gives its disparity to a
    /// small fraction of a pixel from either map; so does sparse stereo (its block disparities
    /// the start, the frame's depth image the dense prior's coarse map).
    #[test]
    fn stereo_depth_at_level_one_matches_level_zero() {
        use data::sequence::Frame;
        use geom::PinholeCamera;
        let (w, h) = (180usize, 120usize);
        let disparity = |u: f64| 4.0 + 0.05 * u;
        let texture = |x: f32, y: f32| {
            (128.0
                + 60.0 * (x * 0.31).sin() * (y * 0.23).cos()
                + 40.0 * ((x * 0.11 + y * 0.17).sin() > 0.2) as u8 as f32) as u8
        };
        let left = GrayImage::from_fn(w, h, |u, v| texture(u as f32, v as f32));
        // The left pixel u appears at u − d(u) on the right: u = (u_r + 4) / 0.95.
        let right = GrayImage::from_fn(w, h, |u, v| texture((u as f32 + 4.0) / 0.95, v as f32));
        let camera = StereoCamera::new(PinholeCamera::new(100.0, 100.0, 90.0, 60.0), 0.2);
        let frame = || Frame {
            index: 0,
            timestamp: 0.0,
            images: FrameImages::Stereo {
                left: left.clone(),
                right: right.clone(),
            },
            world_from_camera: None,
        };
        let mut measured = Vec::new();
        for (matching, level) in [
            (StereoMatching::Dense, 0),
            (StereoMatching::Dense, 1),
            (StereoMatching::Sparse, 0),
        ] {
            let mut config = SystemConfig::default();
            config.stereo.matching = matching;
            config.stereo.level = level;
            config.stereo.max_disparity = Some(32);
            let mut front = SensorFrontEnd::new(&SensorModel::Stereo(camera), &config).unwrap();
            let data = front.prepare(frame()).unwrap();
            let depth = data.depth.as_ref().unwrap();
            assert_eq!((depth.width(), depth.height()), (w, h));
            let (mut e_map, mut e_point) = (Vec::new(), Vec::new());
            for c in data.corners.corners().iter().filter(|c| {
                c.u > 40.0 && c.v > 20.0 && c.u < (w - 20) as f32 && c.v < (h - 20) as f32
            }) {
                let u = Vector2::new(c.u as f64, c.v as f64);
                let d_true = disparity(u.x);
                if let Some(z) = data.depth_at(u.x, u.y) {
                    e_map.push(100.0 * 0.2 / z - d_true);
                }
                if let Some(z) = data.stereo_measurement(u, &camera) {
                    e_point.push(z.x - z.z - d_true);
                }
            }
            let rms = |e: &[f64]| (e.iter().map(|x| x * x).sum::<f64>() / e.len() as f64).sqrt();
            let (map, point) = (rms(&e_map), rms(&e_point));
            println!(
                "{matching:?} level {level}: {} / {} corners with a block / point disparity, RMS error {map:.3} / {point:.3} px",
                e_map.len(),
                e_point.len()
            );
            assert!(e_point.len() >= 100, "level {level}: {}", e_point.len());
            assert!(
                point < 0.1,
                "level {level}: point disparities {point} px RMS"
            );
            measured.push((map, point));
        }
        // The coarser map is the coarser start (its pixel is two), the points are not.
        assert!(measured[1].0 > measured[0].0, "{measured:?}");
    }

    #[test]
    fn the_corner_index_finds_exactly_the_corners_in_a_radius() {
        let corners: Vec<Corner> = (0..400)
            .map(|i| Corner {
                u: (i * 37 % 640) as f32 + 0.5,
                v: (i * 53 % 480) as f32 + 0.25,
                score: 1.0,
                level: 0,
            })
            .collect();
        let index = CornerIndex::new(corners.clone(), 640, 480, 16.0);
        let mut out = Vec::new();
        for (u, v, r) in [
            (100.0, 100.0, 30.0),
            (0.0, 0.0, 50.0),
            (639.0, 479.0, 3.0),
            (320.0, 240.0, 200.0),
        ] {
            index.within(u, v, r, &mut out);
            let mut expect: Vec<(f32, f32)> = corners
                .iter()
                .filter(|c| (c.u - u).powi(2) + (c.v - v).powi(2) <= r * r)
                .map(|c| (c.u, c.v))
                .collect();
            let mut got: Vec<(f32, f32)> = out.iter().map(|c| (c.u, c.v)).collect();
            expect.sort_by(|a, b| a.partial_cmp(b).unwrap());
            got.sort_by(|a, b| a.partial_cmp(b).unwrap());
            assert_eq!(got, expect, "({u}, {v}) r {r}");
        }
    }
}
