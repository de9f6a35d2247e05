//! Monocular structure-and-motion bootstrapping (thesis §4.5.3) between three consecutive
//! frames `T_b0, T_b1, T_0`, with the Gauss-Newton filter instead of the 5-point algorithm:
//!
//! 1. `T_b0 = I` is the fixed origin; features seen in all three frames are selected
//!    (quadtree, thesis Alg. 2) and initialised with infinite depth uncertainty (eq. 4.26);
//! 2. the filter is run between `T_b0` and `T_b1` (6-DoF pose; the one scale gauge freedom is
//!    left to the Levenberg-Marquardt damping);
//! 3. the parallax of the estimate is checked;
//! 4. the state is scaled so that `|t_b1| = 1`, the information is propagated (Alg. 4) and the
//!    pose, reduced to 5 DoF (unit translation), marginalised out: the map information then
//!    has full rank and carries the scale prior;
//! 5. a standard monocular filter update between `T_b1` and `T_0` gives the initial map and
//!    `T_0`, ready for BA-SLAM or filter-SLAM.

use super::features::{FrameMeasurements, ImageArea, find, select_spread};
use super::filter::{Anchor, FilterError, GaussNewtonFilter, LmSettings};
use geom::PinholeCamera;
use lie::{LieGroup, Se3};
use nalgebra::Vector3;

/// Settings of [`bootstrap`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BootstrapOptions {
    /// Features to initialise.
    pub num_points: usize,
    /// LM iterations of the two filter updates.
    pub iterations: usize,
    /// Iterations of the pose estimate of `T_0` from the map prior (thesis Alg. 6).
    pub pose_iterations: usize,
    /// The median parallax angle (radians) of the points between `T_b0` and `T_b1` must reach
    /// this.
    pub min_parallax: f64,
    /// Image area for the selection.
    pub area: ImageArea,
    /// Seed of the selection.
    pub seed: u64,
}

/// Why bootstrapping failed.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum BootstrapError {
    /// Too few features are seen in all three frames.
    #[error("only {0} features are seen in all three bootstrap frames (need at least 6)")]
    TooFewFeatures(usize),
    /// The estimated motion between `T_b0` and `T_b1` has too little parallax.
    #[error("median parallax {got:.4} rad below the required {min:.4} rad")]
    InsufficientParallax {
        /// Measured median parallax.
        got: f64,
        /// Required.
        min: f64,
    },
    /// A filter operation failed.
    #[error(transparent)]
    Filter(#[from] FilterError),
}

/// The bootstrapped map.
#[derive(Clone, Debug)]
pub struct Bootstrap {
    /// The filter after the update with `T_0`: points anchored at the origin `T_b0 = I`, the
    /// current pose `T_0`, joint information over both.
    pub filter: GaussNewtonFilter<PinholeCamera, 2>,
    /// The estimated `T_b1` (unit translation).
    pub b1_from_world: Se3,
    /// The selected features, in filter order.
    pub features: Vec<usize>,
    /// The median parallax angle between `T_b0` and `T_b1` (radians).
    pub parallax: f64,
}

/// Runs the bootstrap of thesis §4.5.3 on the measurements of `T_b0`, `T_b1`, `T_0` (frame
/// numbers `0, 1, 2` inside the filter).
pub fn bootstrap(
    camera: PinholeCamera,
    sigma: f64,
    frames: [&FrameMeasurements<2>; 3],
    options: &BootstrapOptions,
) -> Result<Bootstrap, BootstrapError> {
    let [b0, b1, f0] = frames;
    let candidates: Vec<usize> = b0
        .iter()
        .map(|(id, _)| *id)
        .filter(|id| find(b1, *id).is_some() && find(f0, *id).is_some())
        .collect();
    if candidates.len() < 6 {
        return Err(BootstrapError::TooFewFeatures(candidates.len()));
    }
    let features = select_spread(
        b0,
        &candidates,
        &[],
        options.num_points,
        options.area,
        options.seed,
    );
    let mut filter = GaussNewtonFilter::new(camera, sigma, Se3::identity());
    for &id in &features {
        let z = find(b0, id).expect("selected from b0");
        filter.add_point(id, &z, Anchor::Origin, 1.0)?;
    }
    let settings = LmSettings::with_iterations(options.iterations);
    let obs = |frame: &FrameMeasurements<2>| -> Vec<_> {
        features
            .iter()
            .filter_map(|id| find(frame, *id).map(|z| (*id, z)))
            .collect()
    };
    let z_b1 = obs(b1);
    filter.begin_frame(1, Se3::identity())?;
    filter.optimise(&z_b1, &settings)?;
    let (_, t_b1) = filter.current().expect("current set");
    let parallax = median_parallax(&filter, &features, &t_b1);
    if parallax.is_nan() || parallax < options.min_parallax {
        return Err(BootstrapError::InsufficientParallax {
            got: parallax,
            min: options.min_parallax,
        });
    }
    filter
        .normalize_scale_to_current()
        .ok_or(BootstrapError::InsufficientParallax {
            got: 0.0,
            min: options.min_parallax,
        })?;
    let (_, b1_from_world) = filter.current().expect("current set");
    filter.propagate(&z_b1);
    filter.marginalise_current_unit_translation()?;
    let z_0 = obs(f0);
    let t0 = filter.motion_from_map_prior(&z_0, &b1_from_world, options.pose_iterations, false)?;
    filter.begin_frame(2, t0)?;
    filter.update(&z_0, &settings)?;
    Ok(Bootstrap {
        filter,
        b1_from_world,
        features,
        parallax,
    })
}

/// Median angle at the points between the rays to the origin `T_b0 = I` and to `t_b1`.
fn median_parallax(
    filter: &GaussNewtonFilter<PinholeCamera, 2>,
    features: &[usize],
    b1_from_world: &Se3,
) -> f64 {
    let c0 = Vector3::zeros();
    let c1 = b1_from_world.inverse().translation().to_owned();
    let mut angles: Vec<f64> = features
        .iter()
        .filter_map(|id| filter.point_world(*id))
        .map(|y| {
            let (a, b) = (c0 - y, c1 - y);
            a.angle(&b)
        })
        .filter(|a| a.is_finite())
        .collect();
    if angles.is_empty() {
        return 0.0;
    }
    angles.sort_by(f64::total_cmp);
    angles[angles.len() / 2]
}
