//! Filter-SLAM (thesis Alg. 5, §4.5.2): the Gauss-Newton information filter of
//! [`super::filter`] run over keyframes with feature management as in BA-SLAM.
//!
//! Per keyframe `i`: if features left the field of view, the previous pose `T_{i−1}` becomes
//! an anchor, the lost points are marginalised and new ones anchored at `T_{i−1}` (stereo:
//! eq. 4.23–4.24; monocular: infinite depth uncertainty, eq. 4.26); otherwise `T_{i−1}` is
//! marginalised (eq. 4.25). Anchors no point uses any more are marginalised too. `T_i` is
//! predicted by motion-only BA (eq. 4.15) or from the Gaussian map prior (thesis Alg. 6), then
//! the joint update (eq. 4.18) and the information update (Alg. 4) follow.

use super::features::{FrameMeasurements, ImageArea, find, select_replacements, split_lost};
use super::filter::{Anchor, FilterError, GaussNewtonFilter, InverseDepthCamera, LmSettings};
use lie::Se3;
use nalgebra::SVector;
use slam::clock::CpuStopwatch;
use std::collections::HashSet;
use std::time::Duration;

/// How filter-SLAM predicts the new pose before the joint update (thesis §4.6.3).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum MotionEstimate {
    /// Motion-only BA against the map's mean (eq. 4.15), linear in the number of points.
    MotionOnlyBa,
    /// From the Gaussian map prior (thesis Alg. 6), cubic in the number of points; `exact`
    /// recomputes the innovation covariance at every step, otherwise it is computed once.
    MapPrior {
        /// Recompute `S` after every step (thesis Alg. 6 step 7).
        exact: bool,
    },
}

/// Settings of [`FilterSlam`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FilterSlamOptions {
    /// LM iterations of the joint update and of the pose prediction.
    pub iterations: usize,
    /// Pose prediction.
    pub motion: MotionEstimate,
    /// Image area for feature selection.
    pub area: ImageArea,
    /// Seed of feature selection (use the same as BA-SLAM's to select the same features).
    pub seed: u64,
}

/// Time spent in the parts of filter-SLAM (CPU time of the calling thread, [`slam::clock`]).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct FilterSlamCost {
    /// Marginalisation and feature replacement.
    pub marginalisation: Duration,
    /// Pose prediction.
    pub motion: Duration,
    /// Joint update and information update (the "joint filtering step" of thesis §4.6.5).
    pub update: Duration,
}

impl FilterSlamCost {
    /// The whole pipeline.
    pub fn total(&self) -> Duration {
        self.marginalisation + self.motion + self.update
    }

    /// The joint filtering steps (marginalisation, joint update, information update): what
    /// thesis §4.6.5 compares with the joint BA updates.
    pub fn joint(&self) -> Duration {
        self.marginalisation + self.update
    }
}

/// Filter-SLAM (module docs).
pub struct FilterSlam<C, const N: usize> {
    filter: GaussNewtonFilter<C, N>,
    options: FilterSlamOptions,
    tracked: Vec<usize>,
    used: HashSet<usize>,
    frame: usize,
    pose: Se3,
    /// Accumulated cost.
    pub cost: FilterSlamCost,
}

impl<C: InverseDepthCamera<N>, const N: usize> FilterSlam<C, N> {
    /// Starts from a filter whose points are the tracked features; `pose` is the estimate of
    /// the frame `frame` (either the filter's current pose or its fixed origin).
    pub fn new(filter: GaussNewtonFilter<C, N>, options: FilterSlamOptions, frame: usize) -> Self {
        let tracked = filter.point_ids();
        let pose = filter
            .current()
            .map(|c| c.1)
            .unwrap_or(*filter.origin_from_world());
        FilterSlam {
            used: tracked.iter().copied().collect(),
            tracked,
            filter,
            options,
            frame,
            pose,
            cost: FilterSlamCost::default(),
        }
    }

    /// The filter.
    pub fn filter(&self) -> &GaussNewtonFilter<C, N> {
        &self.filter
    }

    /// The latest pose estimate.
    pub fn current(&self) -> Se3 {
        self.pose
    }

    /// The tracked features.
    pub fn tracked(&self) -> &[usize] {
        &self.tracked
    }

    fn median_inverse_depth(&self, t: &Se3) -> f64 {
        super::features::median_inverse_depth(
            t,
            self.tracked
                .iter()
                .filter_map(|id| self.filter.point_world(*id)),
        )
    }

    /// One keyframe of thesis Alg. 5: `previous` and `frame` are the measurements of
    /// keyframes `i−1` and `i`. Returns the estimate of `T_i`. The same as [`Self::prepare`],
    /// [`Self::predict`] with the configured [`MotionEstimate`], then [`Self::update`].
    pub fn step(
        &mut self,
        previous: &FrameMeasurements<N>,
        frame: &FrameMeasurements<N>,
    ) -> Result<Se3, FilterError> {
        let obs = self.prepare(previous, frame)?;
        let start = CpuStopwatch::start();
        let predicted = self.predict(&obs, self.options.motion)?;
        self.cost.motion += start.elapsed();
        self.update(&obs, predicted)
    }

    /// The first part of a keyframe: marginalises the previous pose (or turns it into an
    /// anchor), marginalises the lost points, anchors replacements; returns the observations
    /// of the tracked features in `frame`, the input of [`Self::predict`] and
    /// [`Self::update`].
    pub fn prepare(
        &mut self,
        previous: &FrameMeasurements<N>,
        frame: &FrameMeasurements<N>,
    ) -> Result<Vec<(usize, SVector<f64, N>)>, FilterError> {
        let i = self.frame + 1;
        let t_prev = self.pose;
        let start = CpuStopwatch::start();
        let (kept, lost) = split_lost(&self.tracked, frame);
        if lost.is_empty() {
            if self.filter.current().is_some() {
                self.filter.marginalise_current()?;
            }
        } else {
            let anchor = if self.filter.current().is_some() {
                self.filter.current_to_anchor()?;
                Anchor::Frame(self.frame)
            } else {
                Anchor::Origin
            };
            self.filter.marginalise_points(&lost)?;
            let q0 = self.median_inverse_depth(&t_prev);
            let used = &self.used;
            let new = select_replacements(
                previous,
                frame,
                &kept,
                &|id| used.contains(&id),
                lost.len(),
                self.options.area,
                self.options.seed ^ (i as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15),
            );
            let mut tracked = kept;
            // Measured in the anchor frame (T_{i−1}, or the origin when T_{i−1} is it).
            let new: Vec<(usize, SVector<f64, N>)> = new
                .into_iter()
                .map(|id| {
                    (
                        id,
                        find(previous, id).expect("selected from the previous frame"),
                    )
                })
                .collect();
            self.used.extend(new.iter().map(|(id, _)| *id));
            if self.filter.add_points(&new, anchor, q0).is_ok() {
                tracked.extend(new.iter().map(|(id, _)| *id));
            } else {
                // One invalid measurement (e.g. a stereo disparity ≤ 0): add them one by one.
                for (id, z) in &new {
                    if self.filter.add_point(*id, z, anchor, q0).is_ok() {
                        tracked.push(*id);
                    }
                }
            }
            self.tracked = tracked;
            self.filter.marginalise_unused_anchors()?;
        }
        self.cost.marginalisation += start.elapsed();
        Ok(self
            .tracked
            .iter()
            .filter_map(|id| find(frame, *id).map(|z| (*id, z)))
            .collect())
    }

    /// Predicts the new pose from the map after [`Self::prepare`] (thesis §4.6.3), starting
    /// at the previous estimate; changes nothing, so several estimates can be compared on the
    /// same state (thesis Fig. 4.10). The map-prior estimate falls back to the previous pose
    /// if the map prior is singular (a fresh monocular map can be); a failed motion-only BA is
    /// an error.
    pub fn predict(
        &self,
        obs: &[(usize, SVector<f64, N>)],
        estimate: MotionEstimate,
    ) -> Result<Se3, FilterError> {
        let t_prev = self.pose;
        match estimate {
            MotionEstimate::MotionOnlyBa => {
                self.filter
                    .motion_only_ba(obs, &t_prev, self.options.iterations)
            }
            MotionEstimate::MapPrior { exact } => Ok(self
                .filter
                .motion_from_map_prior(obs, &t_prev, self.options.iterations, exact)
                .unwrap_or(t_prev)),
        }
    }

    /// The last part of a keyframe: the joint update (eq. 4.18) and the information update
    /// (Alg. 4) from the `predicted` pose. Returns the estimate of `T_i`.
    pub fn update(
        &mut self,
        obs: &[(usize, SVector<f64, N>)],
        predicted: Se3,
    ) -> Result<Se3, FilterError> {
        let i = self.frame + 1;
        let start = CpuStopwatch::start();
        self.filter.begin_frame(i, predicted)?;
        self.filter
            .update(obs, &LmSettings::with_iterations(self.options.iterations))?;
        self.cost.update += start.elapsed();
        self.frame = i;
        self.pose = self.filter.current().expect("just added").1;
        Ok(self.pose)
    }
}
