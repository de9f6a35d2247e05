//! The monocular bootstrap from images (issue 20, item 1; thesis §3.4): corners of the first
//! frame are tracked frame to frame by pyramidal LK (forward-backward checked) until the
//! two-view geometry between the first and the current frame has enough parallax, then
//! `geom::bootstrap::bootstrap_pose` chooses between the homography and the essential matrix
//! (Torr's GRIC), recovers the relative pose with a unit baseline and triangulates the inliers.
//! While it waits, the status says why (too few tracks, too little parallax, an ambiguous
//! plane); when the tracks thin out before that, it restarts from the current frame.
//!
//! This is the first stage of the monocular live system; the map it starts (two keyframes and
//! the triangulated points) is what the monocular tracker will take over. Where it goes next:
//! `slam::exploration::MonoExplorer` already bootstraps simulated tracks (essential matrix
//! only, `relative_pose_ransac`, then a two-view BA). The live monocular system must have one
//! bootstrap: `MonoExplorer`'s should take `geom::bootstrap::bootstrap_pose` (re-running the
//! scale-drift experiments that use it), and this module should shrink to the image side —
//! the LK tracks it feeds to `MonoExplorer` — rather than decide on its own.

use geom::PinholeCamera;
use geom::bootstrap::{BootstrapConfig, TwoViewBootstrap, TwoViewModel, bootstrap_pose};
use geom::two_view::TwoViewError;
use lie::Se3;
use nalgebra::{Vector2, Vector3};
use vision::image::GrayImage;
use vision::lk::{LkParams, track_forward_backward};
use vision::pyramid::Pyramid;
use vision::quadtree::select_corners;

/// Parameters of the bootstrap.
#[derive(Clone, Debug, PartialEq)]
pub struct BootstrapParams {
    /// Corners selected in the first frame (spread by the quadtree). 500: the two-view RANSAC
    /// wants a few hundred correspondences (ORB-SLAM initialises from 1000 ORB matches at
    /// 640×480; tracked corners are fewer but outlier-poorer).
    pub corners: usize,
    /// FAST threshold of the selection (the front-end's 20).
    pub fast_threshold: u8,
    /// Minimum quadtree cell, pixels (the front-end's 8).
    pub min_cell: f32,
    /// A track survives a frame only if LK back from it returns within this many pixels (1 px:
    /// a forward-backward error beyond the corner's own localisation error is a drift or an
    /// occlusion).
    pub max_forward_backward: f32,
    /// Restart from the current frame when fewer than this fraction of the first frame's
    /// corners are still tracked (0.3: the geometry of a third of the view no longer tells a
    /// plane from a general scene).
    pub min_tracked_fraction: f64,
    /// Standard deviation of a tracked corner's position, pixels (1 px: LK's error over several
    /// frames of chaining, measured ≤ 0.1 px per frame pair on rendered sequences).
    pub pixel_sigma: f64,
    /// Pyramid levels of the tracking (4, as the front-end).
    pub levels: usize,
}

impl Default for BootstrapParams {
    fn default() -> Self {
        BootstrapParams {
            corners: 500,
            fast_threshold: 20,
            min_cell: 8.0,
            max_forward_backward: 1.0,
            min_tracked_fraction: 0.3,
            pixel_sigma: 1.0,
            levels: 4,
        }
    }
}

/// The bootstrap's result: the first two keyframes and their points.
#[derive(Clone, Debug)]
pub struct Initialisation {
    /// Frame of the first keyframe (the camera frame of the points).
    pub first_frame: usize,
    /// Frame of the second keyframe.
    pub second_frame: usize,
    /// `T_second_first` with a unit baseline.
    pub second_from_first: Se3,
    /// "homography" or "essential".
    pub model: &'static str,
    /// The triangulated points: pixel in the first frame, pixel in the second, position in the
    /// first camera's frame (baseline units).
    pub points: Vec<(Vector2<f64>, Vector2<f64>, Vector3<f64>)>,
    /// Median parallax of the inliers, degrees.
    pub median_parallax_deg: f64,
}

/// What a frame did to the bootstrap.
#[derive(Clone, Debug)]
pub enum BootstrapStatus {
    /// Still initialising, with the reason.
    Initialising(String),
    /// Initialised at this frame.
    Initialised(Box<Initialisation>),
}

/// The bootstrap's state (see the module notes).
#[derive(Debug)]
pub struct Bootstrapper {
    camera: PinholeCamera,
    params: BootstrapParams,
    config: BootstrapConfig,
    /// First frame: its index and the selected corners.
    first: Option<(usize, Vec<[f32; 2]>)>,
    /// The previous frame's pyramid and where each first-frame corner is in it.
    previous: Option<(Pyramid, Vec<Option<[f32; 2]>>)>,
}

/// Why the bootstrap cannot start.
#[derive(Debug, thiserror::Error)]
pub enum BootstrapError {
    /// An image too small for the pyramid.
    #[error("bootstrap: {0}")]
    Image(#[from] vision::image::ImageError),
}

impl Bootstrapper {
    /// A bootstrap for `camera` (the gates are the χ² quantiles at 95 %).
    pub fn new(camera: PinholeCamera, params: BootstrapParams) -> Self {
        let config = BootstrapConfig::new(
            0.5 * (camera.fx + camera.fy),
            params.pixel_sigma,
            lsq::chi2_quantile(1, 0.95),
            lsq::chi2_quantile(2, 0.95),
        );
        Bootstrapper {
            camera,
            params,
            config,
            first: None,
            previous: None,
        }
    }

    /// Takes the next frame's grey image.
    pub fn push(
        &mut self,
        index: usize,
        image: &GrayImage,
    ) -> Result<BootstrapStatus, BootstrapError> {
        let pyramid = Pyramid::new(image, self.params.levels, 16)?;
        let Some((first_index, first_corners)) = &self.first else {
            return Ok(self.restart(index, image, pyramid));
        };
        let first_index = *first_index;
        let (prev_pyramid, prev_positions) = self.previous.take().expect("set with first");
        // Track the live tracks from the previous frame.
        let live: Vec<usize> = (0..prev_positions.len())
            .filter(|&i| prev_positions[i].is_some())
            .collect();
        let from: Vec<[f32; 2]> = live
            .iter()
            .map(|&i| prev_positions[i].expect("live"))
            .collect();
        let tracked = track_forward_backward(
            &prev_pyramid,
            &pyramid,
            &from,
            &LkParams {
                levels: self.params.levels,
                ..LkParams::default()
            },
            self.params.max_forward_backward,
        );
        let mut positions = vec![None; prev_positions.len()];
        for (&i, t) in live.iter().zip(&tracked) {
            positions[i] = *t;
        }
        let n_tracked = positions.iter().filter(|p| p.is_some()).count();
        if (n_tracked as f64) < self.params.min_tracked_fraction * first_corners.len() as f64 {
            let reason = format!(
                "only {n_tracked} of {} corners of frame {first_index} still tracked: restarted",
                first_corners.len()
            );
            self.restart(index, image, pyramid);
            return Ok(BootstrapStatus::Initialising(reason));
        }
        let normalise = |p: [f32; 2]| {
            Vector2::new(
                (p[0] as f64 - self.camera.cx) / self.camera.fx,
                (p[1] as f64 - self.camera.cy) / self.camera.fy,
            )
        };
        let pairs: Vec<(usize, [f32; 2])> = positions
            .iter()
            .enumerate()
            .filter_map(|(i, p)| p.map(|p| (i, p)))
            .collect();
        let m_a: Vec<Vector2<f64>> = pairs
            .iter()
            .map(|&(i, _)| normalise(first_corners[i]))
            .collect();
        let m_b: Vec<Vector2<f64>> = pairs.iter().map(|&(_, p)| normalise(p)).collect();
        let status = match bootstrap_pose(&m_a, &m_b, &self.config) {
            Ok(b) => {
                let init = self.initialisation(first_index, index, &b, &m_a, &m_b);
                BootstrapStatus::Initialised(Box::new(init))
            }
            Err(e) => BootstrapStatus::Initialising(match e {
                TwoViewError::TooLittleParallax {
                    median_parallax,
                    required,
                } => format!(
                    "too little parallax ({:.2}° of {:.2}°) over {n_tracked} tracks from frame {first_index}",
                    median_parallax.to_degrees(),
                    required.to_degrees()
                ),
                other => format!("{other} ({n_tracked} tracks from frame {first_index})"),
            }),
        };
        self.previous = Some((pyramid, positions));
        Ok(status)
    }

    fn restart(&mut self, index: usize, image: &GrayImage, pyramid: Pyramid) -> BootstrapStatus {
        let (_, selected) = select_corners(
            image,
            self.params.fast_threshold,
            self.params.corners,
            self.params.min_cell,
        );
        let corners: Vec<[f32; 2]> = selected.iter().map(|q| [q.u, q.v]).collect();
        let n = corners.len();
        self.previous = Some((pyramid, corners.iter().map(|&c| Some(c)).collect()));
        self.first = Some((index, corners));
        BootstrapStatus::Initialising(format!("{n} corners selected in frame {index}"))
    }

    fn initialisation(
        &self,
        first: usize,
        second: usize,
        b: &TwoViewBootstrap,
        m_a: &[Vector2<f64>],
        m_b: &[Vector2<f64>],
    ) -> Initialisation {
        let pixel = |m: &Vector2<f64>| {
            Vector2::new(
                m.x * self.camera.fx + self.camera.cx,
                m.y * self.camera.fy + self.camera.cy,
            )
        };
        Initialisation {
            first_frame: first,
            second_frame: second,
            second_from_first: b.b_from_a,
            model: match b.model {
                TwoViewModel::Homography { .. } => "homography",
                TwoViewModel::Essential(_) => "essential",
            },
            points: b
                .points
                .iter()
                .enumerate()
                .filter_map(|(i, p)| p.map(|p| (pixel(&m_a[i]), pixel(&m_b[i]), p)))
                .collect(),
            median_parallax_deg: b.median_parallax.to_degrees(),
        }
    }
}
