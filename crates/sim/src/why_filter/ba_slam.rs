//! Keyframe BA-SLAM (thesis Alg. 3, §4.5.1) on measured frames with known data association.
//!
//! Per keyframe `i`: features that left the field of view are replaced by new ones where the
//! feature density is low (quadtree, [`super::features`]); the pose `T_i` is tracked by
//! motion-only BA from `T_{i−1}` (eq. 4.15); the points are refined by structure-only BA
//! (eq. 4.16) and everything by full BA over `T_{1:i}` and all points with `T_0` fixed
//! (eq. 4.14; for a monocular camera the remaining scale gauge is left to the
//! Levenberg-Marquardt damping, §4.5.3). New stereo points are placed from their measurement in
//! keyframe `i−1`; new monocular points are triangulated between keyframes `i−1` and `i` by a
//! pluggable [`PointInitialiser`] (the thesis's independent inverse-depth filters, §3.4.4).

use super::features::{FrameMeasurements, ImageArea, find, select_replacements, split_lost};
use super::filter::InverseDepthCamera;
use super::motion::motion_only;
use lie::{LieGroup, Se3};
use nalgebra::{SVector, Vector2, Vector3};
use slam::ba::{BaMode, BundleAdjustment, Gauge, Observation};
use slam::clock::CpuStopwatch;
use slam::factors::{AnchoredObservation, InverseDepthObservation, inverse_depth_to_point};
use slam::tracking::TrackingError;
use std::collections::{HashMap, HashSet};
use std::time::Duration;

/// `lsq`'s default Levenberg-Marquardt limited to `iterations` linear solves.
fn solver_options(iterations: usize) -> lsq::SolverOptions {
    lsq::SolverOptions {
        max_iterations: iterations,
        ..Default::default()
    }
}

/// Triangulates a new monocular point between two keyframes (thesis §3.4.4).
pub trait PointInitialiser<C>: Sync {
    /// The world point of a feature measured `z_anchor` from `anchor_from_world` and
    /// `z_observer` from `observer_from_world` (poses known), starting at inverse depth
    /// `initial_inverse_depth` in the anchor frame; `None` if it cannot be placed (e.g.
    /// behind a camera).
    #[allow(clippy::too_many_arguments)]
    fn initialise(
        &self,
        camera: &C,
        sigma: f64,
        anchor_from_world: &Se3,
        z_anchor: &Vector2<f64>,
        observer_from_world: &Se3,
        z_observer: &Vector2<f64>,
        initial_inverse_depth: f64,
    ) -> Option<Vector3<f64>>;
}

/// The inverse-depth Gauss-Newton filter of thesis §3.4.4 for one point and one update: the
/// prior `ψ = ((u − p_u)/f, (v − p_v)/f, q)`, `Λ_ψ = diag(f²/σ², f²/σ², 0)` from the anchor
/// measurement, and eq. 3.36 minimised by `iterations` LM iterations for the observer's
/// measurement with both poses fixed (the anchor observation's cost is exactly the prior
/// term, since `ẑ(Π(ψ))` is linear in `ψ`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TwoViewInverseDepth {
    /// LM iterations.
    pub iterations: usize,
}

impl<C: InverseDepthCamera<2>> PointInitialiser<C> for TwoViewInverseDepth {
    fn initialise(
        &self,
        camera: &C,
        sigma: f64,
        anchor_from_world: &Se3,
        z_anchor: &Vector2<f64>,
        observer_from_world: &Se3,
        z_observer: &Vector2<f64>,
        initial_inverse_depth: f64,
    ) -> Option<Vector3<f64>> {
        let psi0 = camera.inverse_depth_from(z_anchor, initial_inverse_depth)?;
        let mut problem = lsq::Problem::new();
        let anchor = problem.add_variable(*anchor_from_world);
        let observer = problem.add_variable(*observer_from_world);
        let psi = problem.add_variable(psi0);
        problem.set_fixed(anchor.key(), true);
        problem.set_fixed(observer.key(), true);
        let info = lsq::Information::Isotropic(sigma);
        problem
            .add_factor(
                InverseDepthObservation {
                    observer_from_anchor: None,
                    inverse_depth_point: psi,
                    measurement: *z_anchor,
                    projector: camera.clone(),
                },
                info.clone(),
                None,
            )
            .ok()?;
        problem
            .add_factor(
                AnchoredObservation {
                    observer_from_world: observer,
                    anchor_from_world: anchor,
                    inverse_depth_point: psi,
                    measurement: *z_observer,
                    projector: camera.clone(),
                },
                info,
                None,
            )
            .ok()?;
        let summary = problem.optimise(&solver_options(self.iterations)).ok()?;
        if summary.invalid_factors > 0 {
            return None;
        }
        let psi = *problem.value(psi);
        (psi.z > slam::factors::MIN_INVERSE_DEPTH).then(|| {
            anchor_from_world
                .inverse()
                .act(&inverse_depth_to_point(&psi))
        })
    }
}

/// Settings of [`BaSlam`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BaSlamOptions {
    /// LM iterations of each optimisation (motion-only, structure-only, full BA): 3 or 10 in
    /// thesis §4.6.1.
    pub iterations: usize,
    /// Image area for feature selection.
    pub area: ImageArea,
    /// Seed of feature selection.
    pub seed: u64,
}

/// Time spent in the parts of BA-SLAM (CPU time of the calling thread, [`slam::clock`]).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct BaSlamCost {
    /// Feature replacement and initialisation.
    pub initialisation: Duration,
    /// Motion-only BA.
    pub motion: Duration,
    /// Structure-only BA.
    pub structure: Duration,
    /// Full BA (the "joint BA update" of thesis §4.6.5).
    pub full: Duration,
}

impl BaSlamCost {
    /// The whole pipeline.
    pub fn total(&self) -> Duration {
        self.initialisation + self.motion + self.structure + self.full
    }
}

/// Keyframe BA-SLAM (module docs).
pub struct BaSlam<C, const N: usize> {
    camera: C,
    sigma: f64,
    options: BaSlamOptions,
    keyframes: Vec<Se3>,
    point_of: HashMap<usize, usize>,
    points: Vec<Vector3<f64>>,
    observations: Vec<Observation<N>>,
    tracked: Vec<usize>,
    used: HashSet<usize>,
    /// Monocular features chosen in the previous keyframe, awaiting triangulation.
    pending: Vec<(usize, SVector<f64, N>)>,
    /// Accumulated cost.
    pub cost: BaSlamCost,
}

impl<C: InverseDepthCamera<N>, const N: usize> BaSlam<C, N> {
    /// Starts from keyframe 0 at `t0` with known points (e.g. from stereo or the monocular
    /// bootstrap), all of which are tracked; their measurements in `frame0` become the first
    /// observations.
    pub fn with_map(
        camera: C,
        sigma: f64,
        options: BaSlamOptions,
        t0: Se3,
        points: &[(usize, Vector3<f64>)],
        frame0: &FrameMeasurements<N>,
    ) -> Self {
        let mut s = BaSlam {
            camera,
            sigma,
            options,
            keyframes: vec![t0],
            point_of: HashMap::new(),
            points: Vec::new(),
            observations: Vec::new(),
            tracked: Vec::new(),
            used: HashSet::new(),
            pending: Vec::new(),
            cost: BaSlamCost::default(),
        };
        for (id, y) in points {
            s.add_point(*id, *y);
            s.tracked.push(*id);
            if let Some(z) = find(frame0, *id) {
                s.observe(0, *id, z);
            }
        }
        s
    }

    fn add_point(&mut self, id: usize, y: Vector3<f64>) {
        self.point_of.insert(id, self.points.len());
        self.points.push(y);
        self.used.insert(id);
    }

    fn observe(&mut self, pose: usize, id: usize, z: SVector<f64, N>) {
        self.observations.push(Observation {
            pose,
            point: self.point_of[&id],
            measurement: z,
        });
    }

    /// The keyframe poses `T_0 … T_i`.
    pub fn keyframes(&self) -> &[Se3] {
        &self.keyframes
    }

    /// The latest pose.
    pub fn current(&self) -> Se3 {
        *self.keyframes.last().expect("at least T_0")
    }

    /// The tracked features.
    pub fn tracked(&self) -> &[usize] {
        &self.tracked
    }

    /// Number of points in the map.
    pub fn num_points(&self) -> usize {
        self.points.len()
    }

    /// The median inverse depth of the tracked map points seen from `t`.
    fn median_inverse_depth(&self, t: &Se3) -> f64 {
        super::features::median_inverse_depth(
            t,
            self.tracked
                .iter()
                .filter_map(|id| self.point_of.get(id))
                .map(|&k| self.points[k]),
        )
    }

    /// One keyframe of thesis Alg. 3: `previous` and `frame` are the measurements of keyframes
    /// `i−1` and `i`; monocular cameras need an `initialiser` for new points (without one,
    /// lost features are not replaced). Returns the estimate of `T_i`.
    pub fn step(
        &mut self,
        previous: &FrameMeasurements<N>,
        frame: &FrameMeasurements<N>,
        initialiser: Option<&dyn PointInitialiser<C>>,
    ) -> Result<Se3, TrackingError> {
        let i = self.keyframes.len();
        let t_prev = self.current();
        // 1. Replace features that left the field of view.
        let start = CpuStopwatch::start();
        let (kept, lost) = split_lost(&self.tracked, frame);
        let mut tracked = kept.clone();
        if !lost.is_empty() {
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
            for id in new {
                let z = find(previous, id).expect("selected from the previous frame");
                self.used.insert(id);
                if C::MEASURES_DEPTH {
                    let Some(psi) = self.camera.inverse_depth_from(&z, 1.0) else {
                        continue;
                    };
                    let y = t_prev.inverse().act(&inverse_depth_to_point(&psi));
                    self.add_point(id, y);
                    self.observe(i - 1, id, z);
                } else {
                    self.pending.push((id, z));
                }
                tracked.push(id);
            }
        }
        self.tracked = tracked;
        self.cost.initialisation += start.elapsed();

        // 2. Motion-only BA from T_{i−1}.
        let start = CpuStopwatch::start();
        let mut pts = Vec::new();
        let mut measurements = Vec::new();
        for id in &self.tracked {
            if let (Some(&k), Some(z)) = (self.point_of.get(id), find(frame, *id)) {
                measurements.push(z);
                pts.push(self.points[k]);
            }
        }
        let t_i = motion_only(
            &self.camera,
            &t_prev,
            &pts,
            &measurements,
            self.sigma,
            self.options.iterations,
        )?;
        self.keyframes.push(t_i);
        for id in self.tracked.clone() {
            if self.point_of.contains_key(&id)
                && let Some(z) = find(frame, id)
            {
                self.observe(i, id, z);
            }
        }
        self.cost.motion += start.elapsed();

        // Monocular: triangulate the features chosen in keyframe i−1 between i−1 and i.
        let start = CpuStopwatch::start();
        if !self.pending.is_empty() {
            let q0 = self.median_inverse_depth(&t_prev);
            for (id, z_prev) in std::mem::take(&mut self.pending) {
                let placed = find(frame, id).zip(initialiser).and_then(|(z, init)| {
                    let za = Vector2::new(z_prev[0], z_prev[1]);
                    let zo = Vector2::new(z[0], z[1]);
                    init.initialise(&self.camera, self.sigma, &t_prev, &za, &t_i, &zo, q0)
                        .map(|y| (y, z))
                });
                match placed {
                    Some((y, z)) => {
                        self.add_point(id, y);
                        self.observe(i - 1, id, z_prev);
                        self.observe(i, id, z);
                    }
                    None => self.tracked.retain(|t| *t != id),
                }
            }
        }
        self.cost.initialisation += start.elapsed();

        // 3. Structure-only BA, 4. full BA with T_0 fixed.
        let start = CpuStopwatch::start();
        self.adjust(BaMode::StructureOnly);
        self.cost.structure += start.elapsed();
        let start = CpuStopwatch::start();
        self.adjust(BaMode::Full);
        self.cost.full += start.elapsed();
        Ok(self.current())
    }

    fn adjust(&mut self, mode: BaMode) {
        let Ok(mut ba) = BundleAdjustment::new(
            &self.camera,
            &self.keyframes,
            &self.points,
            &self.observations,
            self.sigma,
            None,
            mode,
            &Gauge::FixPoses(vec![0]),
        ) else {
            return;
        };
        if ba
            .problem
            .optimise(&solver_options(self.options.iterations))
            .is_ok()
        {
            self.keyframes = ba.camera_from_world();
            self.points = ba.points_world();
        }
    }
}
