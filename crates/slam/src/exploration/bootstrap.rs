//! The monocular map's start (thesis §3.4.4): the two-view bootstrap between the first frame
//! and a later one with parallax enough, its points and first keyframes.

use super::*;

impl MonoExplorer {
    /// Two-view bootstrap between the first frame and `frame`; `Err(reason)` to keep waiting.
    pub(super) fn bootstrap(
        &mut self,
        graph: &mut SlamGraph<2>,
        first: usize,
        first_measurements: &[(TrackId, Vector2<f64>)],
        frame: usize,
        measurements: &[(TrackId, Vector2<f64>)],
    ) -> Result<FrameOutcome, String> {
        let in_first: HashMap<TrackId, Vector2<f64>> = first_measurements.iter().copied().collect();
        let mut tracks = Vec::new();
        let (mut m_a, mut m_b) = (Vec::new(), Vec::new());
        let (mut z_a, mut z_b) = (Vec::new(), Vec::new());
        for (track, z) in measurements {
            if let Some(za) = in_first.get(track) {
                tracks.push(*track);
                z_a.push(*za);
                z_b.push(*z);
                m_a.push(self.camera.normalised_from_pixel(za));
                m_b.push(self.camera.normalised_from_pixel(z));
            }
        }
        // One two-view bootstrap for simulated and image tracks: `geom::bootstrap::bootstrap_pose`
        // chooses between the homography and the essential matrix (GRIC) and triangulates the
        // chosen model's inliers with the cheirality and re-projection checks; its parallax
        // gate is the one a relative depth error `bootstrap_depth_error` needs, and
        // `min_bootstrap_parallax` may ask for more.
        let mut bootstrap = BootstrapConfig::new(
            self.camera.fx,
            self.config.sigma,
            lsq::chi2_quantile(1, 0.95),
            lsq::chi2_quantile(2, 0.95),
        );
        bootstrap.max_relative_depth_error = self.config.bootstrap_depth_error;
        bootstrap.min_pixel_sigma = self
            .config
            .bootstrap_min_sigma
            .map(|floor| floor.min(self.config.sigma));
        bootstrap.min_triangulated = self.config.min_tracked.max(8);
        bootstrap.ransac = RansacConfig {
            seed: self.config.ransac.seed ^ self.config.seed,
            ..self.config.ransac
        };
        let rel = bootstrap_pose(&m_a, &m_b, &bootstrap).map_err(|e| e.to_string())?;
        let n_inliers = rel.inliers.iter().filter(|&&i| i).count();
        if (n_inliers as f64) < self.config.min_bootstrap_inlier_ratio * m_a.len() as f64 {
            return Err(format!(
                "only {n_inliers} of {} correspondences are inliers",
                m_a.len()
            ));
        }
        if rel.median_parallax < self.config.min_bootstrap_parallax {
            return Err(format!(
                "median parallax {:.2}° below {:.2}°",
                rel.median_parallax.to_degrees(),
                self.config.min_bootstrap_parallax.to_degrees()
            ));
        }
        // The well triangulated inliers with a usable parallax (a quarter of the median the
        // bootstrap needs).
        let min_ray_angle = 0.25
            * self
                .config
                .min_bootstrap_parallax
                .max(rel.required_parallax);
        let mut pts = Vec::new();
        for (i, p) in rel.points.iter().enumerate() {
            let Some(p) = p else { continue };
            let ray_a = rel.b_from_a.rotation().act(p);
            let ray_b = rel.b_from_a.act(p);
            if ray_a.angle(&ray_b) >= min_ray_angle {
                pts.push((i, *p));
            }
        }
        if pts.len() < self.config.min_tracked.max(8) {
            return Err(format!("only {} points triangulated", pts.len()));
        }
        // Two-view BA: first pose fixed, scale left to the damping (thesis §4.5.3).
        let poses = [Se3::identity(), rel.b_from_a];
        let points: Vec<Vector3<f64>> = pts.iter().map(|(_, p)| *p).collect();
        let mut obs = Vec::new();
        for (k, (i, _)) in pts.iter().enumerate() {
            obs.push(Observation {
                pose: 0,
                point: k,
                measurement: z_a[*i],
            });
            obs.push(Observation {
                pose: 1,
                point: k,
                measurement: z_b[*i],
            });
        }
        let mut ba = BundleAdjustment::new(
            &self.camera,
            &poses,
            &points,
            &obs,
            self.config.sigma,
            Some(RobustKernel::Huber(self.config.huber)),
            BaMode::Full,
            &Gauge::FixPoses(vec![0]),
        )
        .map_err(|e| e.to_string())?;
        ba.problem
            .optimise(&solver(20))
            .map_err(|e| e.to_string())?;
        let poses = ba.camera_from_world();
        let scale = poses[1].translation().norm();
        if !(scale.is_finite() && scale > 0.0) {
            return Err("degenerate baseline after bundle adjustment".into());
        }
        let second = Se3::new(*poses[1].rotation(), poses[1].translation() / scale);
        let points: Vec<Vector3<f64>> = ba.points_world().iter().map(|p| p / scale).collect();
        // Keyframes 0 and 1, map points anchored in keyframe 0.
        let k0 = self
            .map
            .add_keyframe(graph, first, Se3::identity(), first_measurements);
        let k1 = self.map.add_keyframe(graph, frame, second, measurements);
        self.keyframe_of_frame.insert(first, k0);
        self.keyframe_of_frame.insert(frame, k1);
        if self.double_window.is_some() {
            // The double window walks the covisibility edges; the points come below.
            graph
                .add_edge(k0, k1, Some(Sim3::from_se3(&second)))
                .map_err(|e| e.to_string())?;
        }
        for ((i, _), p) in pts.iter().zip(points) {
            let Some(point) = self.map.add_point(graph, tracks[*i], k0, &p, z_a[*i]) else {
                continue;
            };
            add_observation(graph, k1, point, z_b[*i]);
            self.active.insert(tracks[*i], point);
        }
        self.frame_poses.push((first, Se3::identity()));
        self.frame_poses.push((frame, second));
        let steps = (frame - first) as f64;
        let velocity = Se3::exp(&(second.log() / steps));
        let started = self.start_features(graph, k1, frame, measurements);
        self.state = State::Tracking {
            last_frame: frame,
            last_pose: second,
            velocity,
        };
        Ok(FrameOutcome {
            camera_from_world: Some(second),
            keyframe: Some(k1),
            keyframe_reason: None,
            tracked: self.active.len(),
            promoted: 0,
            started,
            filters: self.filters.len(),
            waiting: None,
            optimisation: None,
            window_time: None,
            window: None,
        })
    }
}
