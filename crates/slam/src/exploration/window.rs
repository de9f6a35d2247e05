//! The keyframe BA's window (thesis §3.3.3, §5.4): which keyframes a new keyframe's BA
//! optimises, the BA itself (a loaded map held while localising) and the removal of the
//! measurements its optimum — or the double window's — does not explain.

use super::{ExplorationError, LocalWindow, MonoExplorer, rigid_pose, solver};
use crate::ba::{BaMode, BundleAdjustment, Gauge, Observation};
use crate::factors::point_to_inverse_depth;
use crate::map::{GraphAccess, KeyframeId, PointId, SlamGraph};
use geom::CameraModel;
use lie::{LieGroup, Se3, Sim3};
use lsq::RobustKernel;
use nalgebra::Vector3;
use std::collections::{BTreeMap, HashSet};

impl MonoExplorer {
    /// The keyframes the BA of new keyframe `k` optimises, oldest first
    /// ([`ExplorationConfig::local_window`]).
    pub(super) fn local_keyframes(&self, graph: &SlamGraph<2>, k: KeyframeId) -> Vec<KeyframeId> {
        let window = self.config.window.max(3);
        let n = self.map.keyframes.len();
        match self.config.local_window {
            LocalWindow::Sliding => (n.saturating_sub(window).max(self.map_start)..n)
                .map(KeyframeId::from_index)
                .collect(),
            LocalWindow::Covisible => {
                let mut shared: BTreeMap<KeyframeId, usize> = BTreeMap::new();
                for p in graph.keyframe(k).expect("in the map").observations().keys() {
                    for &o in graph.point(*p).expect("in the map").observers() {
                        if o != k {
                            *shared.entry(o).or_default() += 1;
                        }
                    }
                }
                let previous = KeyframeId::from_index(k.index().saturating_sub(1));
                let mut by_weight: Vec<(usize, KeyframeId)> = shared
                    .into_iter()
                    .filter(|&(o, _)| o != previous)
                    .map(|(o, c)| (c, o))
                    .collect();
                // Most shared points first, the newer keyframe on a tie.
                by_weight.sort_by(|a, b| b.cmp(a));
                let mut local: Vec<KeyframeId> = vec![k];
                if previous != k {
                    local.push(previous);
                }
                local.extend(
                    by_weight
                        .into_iter()
                        .map(|(_, o)| o)
                        .take(window.saturating_sub(local.len())),
                );
                local.sort();
                local
            }
        }
    }

    /// Removes the measurements `outliers` (keyframe, point) from the map; a point no longer
    /// measured by new keyframe `k` (or gone) is no longer tracked.
    pub(super) fn drop_measurements(
        &mut self,
        graph: &mut SlamGraph<2>,
        k: KeyframeId,
        outliers: Vec<(KeyframeId, PointId)>,
    ) -> Result<(), ExplorationError> {
        for (kf, p) in outliers {
            graph
                .remove_observation(kf, p)
                .map_err(|e| ExplorationError::Optimisation(e.to_string()))?;
            if kf == k || graph.point(p).is_none() {
                self.active.retain(|_, q| *q != p);
            }
        }
        Ok(())
    }

    /// Removes the measurements by `keyframes` that the map does not explain (beyond the
    /// χ²(2) 95 % gate at σ, the window BA's) of points that other keyframes measure too: the
    /// double window's outlier removal (`remove_outliers`), on the keyframes the BA would
    /// have optimised.
    pub(super) fn remove_unexplained(
        &mut self,
        graph: &mut SlamGraph<2>,
        k: KeyframeId,
        keyframes: &[KeyframeId],
    ) -> Result<(), ExplorationError> {
        let gate = lsq::chi2_quantile(2, 0.95) * self.config.sigma * self.config.sigma;
        let mut outliers: Vec<(KeyframeId, PointId)> = Vec::new();
        for &w in keyframes {
            let t = rigid_pose(graph, w);
            for (&p, z) in graph.keyframe(w).expect("in the map").observations() {
                if graph.point(p).is_none_or(|pt| pt.observers().len() < 2) {
                    continue;
                }
                let Ok(y) = graph.point_world(p) else {
                    continue;
                };
                let explained = CameraModel::project(&self.camera, &t.act(&y))
                    .is_ok_and(|u| (u - z).norm_squared() <= gate);
                if !explained {
                    outliers.push((w, p));
                }
            }
        }
        self.drop_measurements(graph, k, outliers)
    }

    /// The keyframe BA of new keyframe `k` (§3.3.3) on Euclidean points: the window's keyframes
    /// ([`Self::local_keyframes`]) and the points they measure are optimised; up to
    /// `fixed_observers` other keyframes measuring those points join as fixed poses, and
    /// with fewer than two of them the window's two oldest keyframes are fixed (they anchor
    /// the window to the trajectory and fix the scale gauge). Points measured once in all
    /// are held fixed. The points are written back anchored in their (possibly moved) anchor
    /// keyframes.
    ///
    /// The problem is copied out under a read lock of `graph`, solved with no lock held and
    /// written back under a write lock ([`GraphAccess`]).
    pub(super) fn window_ba(
        &mut self,
        graph: &mut impl GraphAccess<2>,
        k: KeyframeId,
    ) -> Result<(), ExplorationError> {
        let WindowProblem {
            local,
            window,
            count,
            held,
            observations,
            mut ba,
        } = self.window_problem(&graph.read(), k)?;
        ba.problem
            .optimise(&solver(self.config.ba_iterations))
            .map_err(|e| ExplorationError::Optimisation(e.to_string()))?;
        let mut graph = graph.write();
        let graph = &mut *graph;
        let (poses, points) = (ba.camera_from_world(), ba.points_world());
        for (&k, t) in local.iter().zip(&poses) {
            graph
                .set_pose(k, Sim3::from_se3(t))
                .map_err(|e| ExplorationError::Optimisation(e.to_string()))?;
            self.filters
                .set_anchor_pose(self.map.keyframes[k.index()].frame, *t);
        }
        // Measurements the optimum does not explain leave the map (after the points are
        // written back, below).
        let mut outliers: Vec<(KeyframeId, PointId)> = Vec::new();
        if self.config.remove_outliers {
            let gate = lsq::chi2_quantile(2, 0.95) * self.config.sigma * self.config.sigma;
            let ids: Vec<PointId> = count.keys().copied().collect();
            let all_poses = ba.camera_from_world();
            for o in &observations {
                let p = ids[o.point];
                if count[&p] < 2 || (self.localise && !self.temporary.contains(&window[o.pose])) {
                    continue;
                }
                let x = all_poses[o.pose].act(&points[o.point]);
                let explained = CameraModel::project(&self.camera, &x)
                    .is_ok_and(|z| (z - o.measurement).norm_squared() <= gate);
                if !explained {
                    outliers.push((window[o.pose], p));
                }
            }
        }
        for (&p, y) in count.keys().zip(&points) {
            if held.contains(&p) {
                continue;
            }
            let anchor = graph.point(p).expect("in the map").anchor();
            let x = graph.pose(anchor).expect("in the map").act(y);
            // A point the window pushed behind its anchor keeps its previous position.
            if let Some(psi) = point_to_inverse_depth(&x) {
                graph
                    .set_inverse_depth(p, psi)
                    .map_err(|e| ExplorationError::Optimisation(e.to_string()))?;
            }
        }
        self.drop_measurements(graph, k, outliers)
    }
}

/// The keyframe BA's problem as [`MonoExplorer::window_problem`] copies it out of the graph.
struct WindowProblem {
    /// The keyframes optimised, oldest first.
    local: Vec<KeyframeId>,
    /// `local`, then the fixed observers: the BA's poses.
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

impl MonoExplorer {
    /// Builds the keyframe BA of new keyframe `k` from `graph` (see [`MonoExplorer::window_ba`]).
    fn window_problem(
        &self,
        graph: &SlamGraph<2>,
        k: KeyframeId,
    ) -> Result<WindowProblem, ExplorationError> {
        let mut local = self.local_keyframes(graph, k);
        // Localising, only the temporary keyframes and their points move: the loaded map's
        // keyframes that measure the window's points are held as its fixed observers, and its
        // points are held (`MonoExplorer::resume`).
        if self.localise {
            local.retain(|w| self.temporary.contains(w));
        }
        let mut count: BTreeMap<PointId, usize> = BTreeMap::new();
        for &w in &local {
            for &p in graph.keyframe(w).expect("in the map").observations().keys() {
                *count.entry(p).or_default() += 1;
            }
        }
        let held: HashSet<PointId> = if self.localise {
            count
                .keys()
                .copied()
                .filter(|&p| {
                    graph
                        .point(p)
                        .is_some_and(|pt| !self.temporary.contains(&pt.anchor()))
                })
                .collect()
        } else {
            HashSet::new()
        };
        // Other observers of the window's points, those measuring most of them first.
        let mut fixed: Vec<KeyframeId> = Vec::new();
        if self.config.fixed_observers > 0 {
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
                    .take(self.config.fixed_observers)
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
            &self.camera,
            &poses,
            &points,
            &observations,
            self.config.sigma,
            Some(RobustKernel::Huber(self.config.huber)),
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
            local,
            window,
            count,
            held,
            observations,
            ba,
        })
    }
}
