//! A new keyframe's BA as a job any thread can solve: what the explorer decided of it
//! ([`WindowJob`]), its problem read from the graph and solved there ([`WindowJob::solve`]),
//! the answer ([`SolvedWindow`]) for `MonoExplorer::apply_window`.

use super::error::ExplorationError;
use super::poses::rigid_pose;
use crate::ba::{BaMode, BundleAdjustment, Gauge, Observation};
use crate::dwo::{DoubleWindowOptimiser, DwoStats};
use crate::map::{GraphAccess, KeyframeId, PointId, SlamGraph};
use geom::{CameraModel, PinholeCamera};
use lie::{LieGroup, Se3};
use lsq::{RobustKernel, SolverOptions};
use nalgebra::Vector3;
use std::collections::{BTreeMap, HashSet};

/// The solver's options: `iterations` Levenberg-Marquardt iterations in one thread.
pub(super) fn solver(iterations: usize) -> SolverOptions {
    SolverOptions {
        max_iterations: iterations,
        threads: Some(1),
        ..SolverOptions::default()
    }
}

/// A new keyframe's window as [`MonoExplorer`] decides it: the keyframe BA (thesis §3.3.3) or
/// the double window (thesis §6.2). Its problem is read from the graph when it is solved
/// ([`WindowJob::solve`]), in whatever thread solves it.
#[derive(Clone, Debug)]
pub struct WindowJob {
    /// The new keyframe.
    pub(super) keyframe: KeyframeId,
    pub(super) camera: PinholeCamera,
    pub(super) kind: WindowKind,
}

/// Which optimisation a [`WindowJob`] is.
#[derive(Clone, Debug)]
pub(super) enum WindowKind {
    /// The keyframe BA.
    Ba(BaWindow),
    /// The double window: the explorer's optimiser (it carries its previous window), given back
    /// with the answer.
    DoubleWindow(DoubleWindowOptimiser),
}

/// The keyframe BA on Euclidean points: the window's keyframes are optimised with the points
/// they measure; up to `fixed_observers` other keyframes measuring those points join as fixed
/// poses, and with fewer than two of them the window's two oldest keyframes are fixed (they
/// anchor the window to the trajectory and fix the scale gauge). Points measured once in all
/// are held fixed, as are, localising, the loaded map's.
#[derive(Clone, Debug)]
pub(super) struct BaWindow {
    /// The keyframes optimised, oldest first.
    pub(super) local: Vec<KeyframeId>,
    /// Localising: the temporary keyframes (only they and their points move).
    pub(super) temporary: Option<Vec<KeyframeId>>,
    pub(super) sigma: f64,
    pub(super) huber: f64,
    pub(super) fixed_observers: usize,
    pub(super) iterations: usize,
    pub(super) remove_outliers: bool,
}

/// A solved [`WindowJob`], for [`MonoExplorer::apply_window`].
#[derive(Clone, Debug)]
pub struct SolvedWindow {
    pub(super) keyframe: KeyframeId,
    pub(super) answer: WindowAnswer,
    /// How long reading and solving took.
    pub time: std::time::Duration,
}

/// What a [`WindowJob`]'s optimisation gives back.
#[derive(Clone, Debug)]
pub(super) enum WindowAnswer {
    /// The keyframe BA's optimum, to be written back.
    Ba(SolvedBa),
    /// The double window's optimiser after the optimisation (it wrote the window back itself)
    /// and its statistics.
    DoubleWindow(DoubleWindowOptimiser, DwoStats),
}

/// The keyframe BA's optimum.
#[derive(Clone, Debug)]
pub(super) struct SolvedBa {
    /// The graph's version when the problem was read.
    pub(super) version: u64,
    /// The keyframes optimised, oldest first, and their optimised poses.
    pub(super) local: Vec<KeyframeId>,
    pub(super) poses: Vec<Se3>,
    /// Every keyframe of the problem (the optimised and the fixed).
    pub(super) window: Vec<KeyframeId>,
    /// The points optimised (not held), in the world frame.
    pub(super) points: Vec<(PointId, Vector3<f64>)>,
    /// The measurements the optimum does not explain (`remove_outliers`).
    pub(super) outliers: Vec<(KeyframeId, PointId)>,
}

impl SolvedWindow {
    /// The new keyframe whose window this is.
    pub fn keyframe(&self) -> KeyframeId {
        self.keyframe
    }

    /// The double window's statistics (`None`: the keyframe BA).
    pub fn double_window_stats(&self) -> Option<DwoStats> {
        match &self.answer {
            WindowAnswer::DoubleWindow(_, stats) => Some(stats.clone()),
            WindowAnswer::Ba(_) => None,
        }
    }
}

impl WindowJob {
    /// The new keyframe.
    pub fn keyframe(&self) -> KeyframeId {
        self.keyframe
    }

    /// Reads the problem under a read lock of `graph`, solves it with no lock held, and
    /// finds the measurements the optimum does not explain ([`GraphAccess`]); the double
    /// window writes its optimum back itself, under a write lock
    /// ([`DoubleWindowOptimiser::optimise`]).
    pub fn solve(&self, mut graph: impl GraphAccess<2>) -> Result<SolvedWindow, ExplorationError> {
        let started = std::time::Instant::now();
        let answer = match &self.kind {
            WindowKind::DoubleWindow(optimiser) => {
                let mut optimiser = optimiser.clone();
                let stats = optimiser
                    .optimise(&mut graph, &self.camera)
                    .map_err(|e| ExplorationError::Optimisation(e.to_string()))?;
                WindowAnswer::DoubleWindow(optimiser, stats)
            }
            WindowKind::Ba(ba) => WindowAnswer::Ba(ba.solve(&self.camera, graph)?),
        };
        Ok(SolvedWindow {
            keyframe: self.keyframe,
            answer,
            time: started.elapsed(),
        })
    }
}

impl BaWindow {
    /// The keyframe BA read under a read lock of `graph` and solved with none.
    fn solve(
        &self,
        camera: &PinholeCamera,
        mut graph: impl GraphAccess<2>,
    ) -> Result<SolvedBa, ExplorationError> {
        let (
            WindowProblem {
                window,
                count,
                held,
                observations,
                mut ba,
            },
            version,
        ) = {
            let graph = graph.read();
            (self.problem(camera, &graph)?, graph.version())
        };
        ba.problem
            .optimise(&solver(self.iterations))
            .map_err(|e| ExplorationError::Optimisation(e.to_string()))?;
        let (all_poses, points) = (ba.camera_from_world(), ba.points_world());
        let mut outliers: Vec<(KeyframeId, PointId)> = Vec::new();
        if self.remove_outliers {
            let gate = lsq::chi2_quantile(2, 0.95) * self.sigma * self.sigma;
            let ids: Vec<PointId> = count.keys().copied().collect();
            for o in &observations {
                let p = ids[o.point];
                let moves = self
                    .temporary
                    .as_ref()
                    .is_none_or(|t| t.contains(&window[o.pose]));
                if count[&p] < 2 || !moves {
                    continue;
                }
                let x = all_poses[o.pose].act(&points[o.point]);
                let explained = CameraModel::project(camera, &x)
                    .is_ok_and(|z| (z - o.measurement).norm_squared() <= gate);
                if !explained {
                    outliers.push((window[o.pose], p));
                }
            }
        }
        let n = self.local.len();
        Ok(SolvedBa {
            version,
            local: self.local.clone(),
            poses: all_poses[..n].to_vec(),
            window,
            points: count
                .keys()
                .zip(points)
                .filter(|(p, _)| !held.contains(p))
                .map(|(&p, y)| (p, y))
                .collect(),
            outliers,
        })
    }
}

/// The keyframe BA's problem as [`BaWindow::problem`] reads it from the graph.
struct WindowProblem {
    /// The window's keyframes, then the fixed observers: the BA's poses.
    window: Vec<KeyframeId>,
    /// The window's points, with how many of its keyframes measure each.
    count: BTreeMap<PointId, usize>,
    /// Points held fixed and not written back (a loaded map's, while localising).
    held: HashSet<PointId>,
    /// The BA's observations, indexing `window` and `count`.
    observations: Vec<Observation<2>>,
    /// The problem, its points' fixings set.
    ba: BundleAdjustment,
}

impl BaWindow {
    /// Builds the BA from `graph` (see [`BaWindow`]).
    fn problem(
        &self,
        camera: &PinholeCamera,
        graph: &SlamGraph<2>,
    ) -> Result<WindowProblem, ExplorationError> {
        let local = &self.local;
        let mut count: BTreeMap<PointId, usize> = BTreeMap::new();
        for &w in local {
            for &p in graph.keyframe(w).expect("in the map").observations().keys() {
                *count.entry(p).or_default() += 1;
            }
        }
        let held: HashSet<PointId> = match &self.temporary {
            Some(temporary) => count
                .keys()
                .copied()
                .filter(|&p| {
                    graph
                        .point(p)
                        .is_some_and(|pt| !temporary.contains(&pt.anchor()))
                })
                .collect(),
            None => HashSet::new(),
        };
        // Other observers of the window's points, those measuring most of them first.
        let mut fixed: Vec<KeyframeId> = Vec::new();
        if self.fixed_observers > 0 {
            let in_local: HashSet<KeyframeId> = local.iter().copied().collect();
            let mut measuring: BTreeMap<KeyframeId, usize> = BTreeMap::new();
            for p in count.keys() {
                for &o in graph.point(*p).expect("in the map").observers() {
                    if !in_local.contains(&o) {
                        *measuring.entry(o).or_default() += 1;
                    }
                }
            }
            let mut by_count: Vec<(usize, KeyframeId)> =
                measuring.into_iter().map(|(o, c)| (c, o)).collect();
            by_count.sort_by(|a, b| b.cmp(a));
            fixed.extend(
                by_count
                    .into_iter()
                    .take(self.fixed_observers)
                    .map(|(_, o)| o),
            );
            fixed.sort();
            for &f in &fixed {
                for &p in graph.keyframe(f).expect("in the map").observations().keys() {
                    if let Some(c) = count.get_mut(&p) {
                        *c += 1;
                    }
                }
            }
        }
        // Window first (optimised), then the fixed observers; the gauge.
        let window: Vec<KeyframeId> = local.iter().chain(&fixed).copied().collect();
        let gauge: Vec<usize> = if fixed.len() >= 2 {
            (local.len()..window.len()).collect()
        } else {
            (0..2.min(local.len()))
                .chain(local.len()..window.len())
                .collect()
        };
        let poses: Vec<Se3> = window.iter().map(|&k| rigid_pose(graph, k)).collect();
        let index: BTreeMap<PointId, usize> =
            count.keys().enumerate().map(|(i, &p)| (p, i)).collect();
        let points: Vec<Vector3<f64>> = count
            .keys()
            .map(|&p| graph.point_world(p))
            .collect::<Result<_, _>>()
            .map_err(|e| ExplorationError::Optimisation(e.to_string()))?;
        let observations: Vec<Observation<2>> = window
            .iter()
            .enumerate()
            .flat_map(|(wi, &k)| {
                let obs = graph.keyframe(k).expect("in the map").observations();
                let index = &index;
                // A fixed observer's other points are not in the problem.
                obs.iter().filter_map(move |(p, z)| {
                    Some(Observation {
                        pose: wi,
                        point: *index.get(p)?,
                        measurement: *z,
                    })
                })
            })
            .collect();
        let mut ba = BundleAdjustment::new(
            camera,
            &poses,
            &points,
            &observations,
            self.sigma,
            Some(RobustKernel::Huber(self.huber)),
            BaMode::Full,
            &Gauge::FixPoses(gauge),
        )
        .map_err(|e| ExplorationError::Optimisation(e.to_string()))?;
        for (v, (&p, &c)) in ba.points.iter().zip(&count) {
            if c < 2 || held.contains(&p) {
                ba.problem.set_fixed(v.key(), true);
            }
        }
        Ok(WindowProblem {
            window,
            count,
            held,
            observations,
            ba,
        })
    }
}
