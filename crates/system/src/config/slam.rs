//! The system's configuration translated into the parameters of `slam`'s stages and of place
//! recognition and the dense model — in this one place, so that a key of the config file means
//! one thing everywhere.

use super::{DenseModelConfig, SystemConfig};
use crate::place_recognition::{Alignment, PlaceRecognitionConfig};
use geom::StereoCamera;
use lsq::RobustKernel;
use slam::dwo::DwoParams;
use slam::exploration::{ExplorationConfig, KeyframeBaseline, LocalWindow};
use slam::loop_closure::DriftLimits;
use slam::mapping::MappingConfig;

impl SystemConfig {
    /// The keyframe pipeline's parameters (`slam::mapping`) for a depth camera `camera`.
    pub(crate) fn keyframe_pipeline(&self, camera: &StereoCamera) -> MappingConfig {
        MappingConfig {
            theta: self.mapping.theta,
            n2: self.mapping.n2,
            appearance_max_drift: DriftLimits {
                of_path: self.loops.max_drift_of_path,
                of_scene_depth: self.loops.max_drift_of_scene_depth,
            },
            ..MappingConfig::new(
                self.pixel_noise,
                (2.0 * camera.pinhole.cx + 1.0, 2.0 * camera.pinhole.cy + 1.0),
                3,
            )
        }
    }

    /// The double window's parameters (`slam::dwo`) for a camera of focal length `focal`
    /// pixels, with the `baseline` (metres) of a depth camera.
    pub(crate) fn double_window(&self, focal: f64, baseline: Option<f64>) -> DwoParams {
        let mut params = DwoParams::new(
            self.optimiser.inner,
            self.optimiser.outer,
            focal,
            self.pixel_noise,
        );
        if let Some(b) = baseline {
            params = params.with_baseline(b);
        }
        params.iterations = self.optimiser.iterations;
        params
    }

    /// The monocular exploration's parameters (`slam::exploration`) for a camera of focal
    /// length `focal` pixels and images of `width`×`height`.
    pub(crate) fn exploration(&self, focal: f64, width: usize, height: usize) -> ExplorationConfig {
        let m = &self.mono;
        let mut config = ExplorationConfig {
            sigma: self.pixel_noise,
            window: m.window,
            keyframe_distance: m.keyframe_distance,
            keyframe_baseline: if m.keyframe_parallax {
                KeyframeBaseline::Parallax
            } else {
                KeyframeBaseline::Distance
            },
            max_features: m.max_features,
            feature_spacing: m.feature_spacing,
            seed: m.seed,
            image_width: width as f64,
            image_height: height as f64,
            bootstrap_depth_error: m.bootstrap_depth_error,
            bootstrap_min_sigma: Some(m.bootstrap_min_sigma),
            // The depth error alone decides when the bootstrap has parallax enough.
            min_bootstrap_parallax: 0.0,
            max_bootstrap_frames: m.max_bootstrap_frames,
            double_window: None,
            theta: self.mapping.theta,
            // Map reuse: the keyframes sharing most points with the new one are optimised,
            // older observers of their points held fixed, and what the optimum does not explain
            // removed (see `MonoConfig::fixed_observers`).
            local_window: LocalWindow::Covisible,
            fixed_observers: m.fixed_observers,
            remove_outliers: true,
            feature_history: m.feature_history,
            // The stereo system's keyframe criterion of coverage, with the mono distance, and
            // its fraction of points found.
            keyframe_rotation: Some(self.keyframes.rotation_deg.to_radians()),
            keyframe_min_tracked_fraction: self.keyframes.min_found_fraction,
            ..ExplorationConfig::default()
        };
        config.feature_init.max_relative_inverse_depth_std = m.feature_depth_error;
        // The monocular double window measures what the keyframe BA does — corner tracks and
        // template matches, a few of them off their points — so with the BA's Huber kernel
        // (the stereo double window has none: its points' depths are checked measurements, and
        // Huber was worse there). Without it, on KITTI 04 3.34 → 1.66 m, the rendered room
        // 2.18 → 0.55 cm (bench/README, twenty-fourth session).
        config.double_window = m.double_window.then(|| DwoParams {
            kernel: Some(RobustKernel::Huber(config.huber)),
            ..self.double_window(focal, None)
        });
        config
    }

    /// Place recognition's parameters for a depth camera (`Some((camera, stereo))`, `stereo`:
    /// depth from block matching; its depth noise from the sensor) or a monocular one (`None`:
    /// a similarity verification of regressed depths, with the system's pixel noise).
    pub(crate) fn place_recognition_for(
        &self,
        depth: Option<(&StereoCamera, bool)>,
    ) -> PlaceRecognitionConfig {
        let place = self.loops.place_recognition.clone();
        match depth {
            Some((camera, stereo)) => PlaceRecognitionConfig {
                depth_noise: self.depth_noise_for(camera, stereo),
                ..place
            },
            None => PlaceRecognitionConfig {
                alignment: Alignment::Sim3,
                pixel_sigma: self.pixel_noise,
                ..place
            },
        }
    }

    /// The dense model's parameters for a depth camera `camera` (`stereo`: block matching),
    /// with its depth noise.
    pub fn dense_model_for(&self, camera: &StereoCamera, stereo: bool) -> DenseModelConfig {
        DenseModelConfig {
            depth_noise: self.depth_noise_for(camera, stereo),
            ..self.dense.clone()
        }
    }
}
