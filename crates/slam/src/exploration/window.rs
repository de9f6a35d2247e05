//! The keyframe BA's window (thesis §3.3.3, §5.4): which keyframes a new keyframe's BA
//! optimises (its job: `window_job.rs`; a loaded map held while localising), its answer written
//! back, and the removal of the measurements its optimum — or the double window's — does not
//! explain.

use super::window_job::{BaWindow, SolvedBa, WindowAnswer, WindowKind};
use super::{ExplorationError, LocalWindow, MonoExplorer, SolvedWindow, WindowJob, rigid_pose};
use crate::factors::point_to_inverse_depth;
use crate::map::{KeyframeId, PointId, SlamGraph};
use geom::CameraModel;
use lie::{LieGroup, Se3, Sim3};
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

    /// The window of new keyframe `k` as a job another thread can solve
    /// ([`WindowJob::solve`]): the double window, or the keyframe BA (§3.3.3) over the window's
    /// keyframes ([`Self::local_keyframes`]; localising, only the temporary ones) with what it
    /// needs of the explorer's configuration.
    pub(super) fn window_job(&self, graph: &SlamGraph<2>, k: KeyframeId) -> WindowJob {
        let kind = match self.double_window.clone().filter(|_| !self.localise) {
            Some(optimiser) => WindowKind::DoubleWindow(optimiser),
            None => {
                let mut local = self.local_keyframes(graph, k);
                // Localising, only the temporary keyframes and their points move: the loaded
                // map's keyframes that measure the window's points are held as its fixed
                // observers, and its points are held (`MonoExplorer::resume`).
                if self.localise {
                    local.retain(|w| self.temporary.contains(w));
                }
                WindowKind::Ba(BaWindow {
                    local,
                    temporary: self.localise.then(|| self.temporary.clone()),
                    sigma: self.config.sigma,
                    huber: self.config.huber,
                    fixed_observers: self.config.fixed_observers,
                    iterations: self.config.ba_iterations,
                    remove_outliers: self.config.remove_outliers,
                })
            }
        };
        WindowJob {
            keyframe: k,
            camera: self.camera,
            kind,
        }
    }

    /// Writes a solved window back into `graph` (the keyframes' poses, the filters' anchors,
    /// the points anchored in their possibly moved anchors; the measurements the optimum does
    /// not explain leave the map — after the double window, which wrote its optimum back
    /// itself, those its window's keyframes measure) and moves the frames' poses after the
    /// keyframe with it: the keyframe's new pose, or `None` if the window is stale — a keyframe
    /// of it moved since it was read (a loop corrected meanwhile): then nothing is written.
    /// Points changed or removed since keep their newer state.
    pub fn apply_window(
        &mut self,
        graph: &mut SlamGraph<2>,
        solved: SolvedWindow,
    ) -> Result<Option<Se3>, ExplorationError> {
        let k = solved.keyframe;
        let solved = match solved.answer {
            WindowAnswer::Ba(solved) => solved,
            WindowAnswer::DoubleWindow(optimiser, _) => {
                self.double_window = Some(optimiser);
                // What the optimum does not explain leaves the map, as after the BA.
                if self.config.remove_outliers {
                    let local = self.local_keyframes(graph, k);
                    self.remove_unexplained(graph, k, &local)?;
                }
                // The filters' anchors moved with their keyframes.
                let anchors: HashSet<usize> =
                    self.filters.iter().map(|(_, f)| f.anchor_frame).collect();
                for a in anchors {
                    if let Some(&ka) = self.keyframe_of_frame.get(&a) {
                        let t = rigid_pose(graph, ka);
                        self.filters.set_anchor_pose(a, t);
                    }
                }
                return Ok(Some(self.frames_moved(graph, k)));
            }
        };
        self.write_ba(graph, k, solved)
    }

    /// Writes the keyframe BA's optimum back (see [`Self::apply_window`]).
    fn write_ba(
        &mut self,
        graph: &mut SlamGraph<2>,
        k: KeyframeId,
        solved: SolvedBa,
    ) -> Result<Option<Se3>, ExplorationError> {
        let stale = solved.window.iter().any(|&w| {
            graph
                .keyframe(w)
                .is_none_or(|kf| kf.pose_version() > solved.version)
        });
        if stale {
            return Ok(None);
        }
        for (&w, t) in solved.local.iter().zip(&solved.poses) {
            graph
                .set_pose(w, Sim3::from_se3(t))
                .map_err(|e| ExplorationError::Optimisation(e.to_string()))?;
            self.filters
                .set_anchor_pose(self.map.keyframes[w.index()].frame, *t);
        }
        for (p, y) in &solved.points {
            let Some(point) = graph.point(*p).filter(|pt| pt.version() <= solved.version) else {
                continue;
            };
            let x = graph.pose(point.anchor()).expect("in the map").act(y);
            // A point the window pushed behind its anchor keeps its previous position.
            if let Some(psi) = point_to_inverse_depth(&x) {
                graph
                    .set_inverse_depth(*p, psi)
                    .map_err(|e| ExplorationError::Optimisation(e.to_string()))?;
            }
        }
        let outliers: Vec<(KeyframeId, PointId)> = solved
            .outliers
            .into_iter()
            .filter(|&(w, p)| {
                graph
                    .keyframe(w)
                    .is_some_and(|kf| kf.observations().contains_key(&p))
            })
            .collect();
        self.drop_measurements(graph, k, outliers)?;
        Ok(Some(self.frames_moved(graph, k)))
    }

    /// Keyframe `k`'s window moved it: the frame it was made from takes its new pose, and the
    /// frames tracked since move with it (`T_j·T_k⁻¹·T_k'`, `T_k` the pose tracking gave the
    /// keyframe). Returns the new pose.
    fn frames_moved(&mut self, graph: &SlamGraph<2>, k: KeyframeId) -> Se3 {
        let after = rigid_pose(graph, k);
        let frame = self.map.keyframes[k.index()].frame;
        let before = self
            .frame_poses
            .iter()
            .rev()
            .find(|(f, _)| *f == frame)
            .map_or(after, |(_, t)| *t);
        let moved = |t: &Se3| t.compose(&before.inverse()).compose(&after);
        for (f, t) in self.frame_poses.iter_mut().rev() {
            match (*f).cmp(&frame) {
                std::cmp::Ordering::Greater => *t = moved(t),
                std::cmp::Ordering::Equal => *t = after,
                std::cmp::Ordering::Less => break,
            }
        }
        if let super::State::Tracking {
            last_frame,
            last_pose,
            ..
        } = &mut self.state
        {
            *last_pose = if *last_frame == frame {
                after
            } else {
                moved(last_pose)
            };
        }
        after
    }
}
