//! Metric loop closure in the SLAM graph (thesis §6.4.1, Figure 6.7(b)): the points of the
//! wider neighbourhood `N2` that tracking does not search (`N2 \ N1`) are looked for again in
//! the reference keyframe; when enough are found, well spread over the image and consistent
//! with one pose, the reference is joined to the old keyframes that see them.

use super::ClosureError;
use crate::factors::Projector;
use crate::map::{GraphError, KeyframeId, PointId, SlamGraph};
use crate::tracking::{MotionOnlyOptions, PoseProblem, tracking_candidates};
use lie::{LieGroup, Sim3};
use nalgebra::SVector;
use std::collections::{BTreeMap, BTreeSet};

/// The candidate points of a metric loop closure (thesis §6.4.1, Figure 6.7(b)): the set `A`
/// of points visible from `N2(ref)` (the first `n2_size` keyframes of the weighted BFS) but not
/// from `N1(ref)`.
pub fn loop_candidates<const N: usize>(
    graph: &SlamGraph<N>,
    reference: KeyframeId,
    n2_size: usize,
) -> BTreeSet<PointId> {
    let near = tracking_candidates(graph, reference);
    let wide = graph.points_visible_from(&graph.n2(reference, n2_size));
    wide.difference(&near).copied().collect()
}

/// Options of metric loop closure (thesis §6.4.1).
#[derive(Clone, Debug, PartialEq)]
pub struct MetricLoopParams {
    /// `Θ`: covisible points needed for an edge.
    pub theta: usize,
    /// Matches with `‖r‖²/σ²` above this after the robust pose fit are pruned (the thesis
    /// prunes at about one pixel; we use the χ² 95 % quantile of the measurement dimension).
    pub max_chi2: f64,
    /// Pixel noise σ.
    pub sigma: f64,
    /// Image width and height (for the spread test).
    pub image_size: (f64, f64),
}

/// A metric loop closure found by [`close_metric_loops`].
#[derive(Clone, Debug, PartialEq)]
pub struct MetricLoopClosure {
    /// The keyframe joined to the reference.
    pub keyframe: KeyframeId,
    /// Matches shared with the reference.
    pub shared: usize,
}

/// Metric loop closure (thesis §6.4.1): `matches` are points of the candidate set `A`
/// ([`loop_candidates`]) found again in the reference keyframe. They are explained by one pose
/// `T_loop` (robust motion-only BA from `T_ref`); matches it does not explain are pruned. For
/// each keyframe of `N2 \ N1` seeing at least `Θ` of the remaining points — with at least `Θ/2`
/// of them in each of the upper, lower, left and right halves of the reference image (the
/// spread-of-matches test) — an edge `E_ref,i` is added, marginalised with
/// `T_ref,i = T_loop·T_i⁻¹` (thesis eq. 6.8). The matches that survive the pruning become
/// observations of the reference keyframe (also when no edge is accepted).
///
/// In one go: [`MetricLoopProblem::from_graph`], [`MetricLoopProblem::solve`],
/// [`MetricLoopFit::apply`] (the phases a thread runs under a read lock, without a lock, and
/// under a write lock).
pub fn close_metric_loops<P: Projector<N> + Clone, const N: usize>(
    graph: &mut SlamGraph<N>,
    reference: KeyframeId,
    matches: &[(PointId, SVector<f64, N>)],
    projector: &P,
    params: &MetricLoopParams,
) -> Result<Vec<MetricLoopClosure>, ClosureError> {
    match MetricLoopProblem::from_graph(graph, reference, matches)? {
        Some(problem) => Ok(problem.solve(projector, params)?.apply(graph)?),
        None => Ok(Vec::new()),
    }
}

/// A metric loop closure copied out of the graph: the pose problem of the matches and, per
/// match, the old keyframes that observe its point.
#[derive(Clone, Debug)]
pub struct MetricLoopProblem<const N: usize> {
    reference: KeyframeId,
    matches: Vec<(PointId, SVector<f64, N>)>,
    observers: Vec<Vec<KeyframeId>>,
    /// The observers' poses when the problem was made: the edges measure the reference
    /// relative to them as they were then (the graph may move before the fit is written).
    poses: BTreeMap<KeyframeId, Sim3>,
    pose: PoseProblem<N>,
}

/// The outcome of [`MetricLoopProblem::solve`]: what [`MetricLoopFit::apply`] writes.
#[derive(Clone, Debug, PartialEq)]
pub struct MetricLoopFit<const N: usize> {
    reference: KeyframeId,
    /// The accepted keyframes' poses when the problem was made.
    poses: BTreeMap<KeyframeId, Sim3>,
    /// `T_loop`, the pose of the reference that explains the matches.
    pub camera_from_world: Sim3,
    /// The matches it explains.
    pub inliers: Vec<(PointId, SVector<f64, N>)>,
    /// The old keyframes that pass the tests, with the matches they share.
    pub accepted: Vec<(KeyframeId, usize)>,
}

impl<const N: usize> MetricLoopProblem<N> {
    /// The problem of `matches` (points of `N2 \ N1` found again in `reference`), or `None`
    /// with fewer than six (a pose needs them).
    pub fn from_graph(
        graph: &SlamGraph<N>,
        reference: KeyframeId,
        matches: &[(PointId, SVector<f64, N>)],
    ) -> Result<Option<Self>, ClosureError> {
        if matches.len() < 6 {
            return Ok(None);
        }
        // T_loop is estimated in the reference's metric: the points are expressed in its frame.
        let t_ref = graph.pose(reference)?;
        let near: BTreeSet<KeyframeId> = graph.n1(reference).into_iter().collect();
        let observers: Vec<Vec<KeyframeId>> = matches
            .iter()
            .map(|(p, _)| {
                Ok(graph
                    .point(*p)
                    .ok_or(GraphError::UnknownPoint(*p))?
                    .observers()
                    .iter()
                    .copied()
                    .filter(|o| !near.contains(o))
                    .collect())
            })
            .collect::<Result<_, GraphError>>()?;
        let poses = observers
            .iter()
            .flatten()
            .filter_map(|&o| Some((o, graph.pose(o).ok()?)))
            .collect();
        Ok(Some(MetricLoopProblem {
            reference,
            matches: matches.to_vec(),
            observers,
            poses,
            pose: PoseProblem::from_graph(graph, reference, matches, &t_ref)?,
        }))
    }

    /// Fits `T_loop`, prunes the matches it does not explain and applies the tests (no graph
    /// access).
    pub fn solve<P: Projector<N> + Clone>(
        &self,
        projector: &P,
        params: &MetricLoopParams,
    ) -> Result<MetricLoopFit<N>, ClosureError> {
        let fit = self
            .pose
            .solve(projector, &MotionOnlyOptions::robust(params.sigma))?;
        let mut inliers = Vec::new();
        // Per keyframe: counts in the four image halves and in all.
        let mut counts: BTreeMap<KeyframeId, [usize; 5]> = BTreeMap::new();
        let (w, h) = params.image_size;
        for ((m, observers), &c) in self.matches.iter().zip(&self.observers).zip(&fit.chi2) {
            if c > params.max_chi2 {
                continue;
            }
            inliers.push(*m);
            let z = &m.1;
            for &o in observers {
                let c = counts.entry(o).or_default();
                c[0] += 1;
                c[if z[0] < w / 2.0 { 1 } else { 2 }] += 1;
                c[if z[1] < h / 2.0 { 3 } else { 4 }] += 1;
            }
        }
        let half = params.theta.div_ceil(2);
        let accepted: Vec<(KeyframeId, usize)> = counts
            .iter()
            .filter(|(_, c)| c[0] >= params.theta && c[1..].iter().all(|&n| n >= half))
            .map(|(&k, c)| (k, c[0]))
            .collect();
        Ok(MetricLoopFit {
            reference: self.reference,
            poses: accepted
                .iter()
                .filter_map(|(k, _)| Some((*k, *self.poses.get(k)?)))
                .collect(),
            camera_from_world: fit.camera_from_world,
            inliers,
            accepted,
        })
    }
}

impl<const N: usize> MetricLoopFit<N> {
    /// Writes the closure: the inliers become observations of the reference (they are verified
    /// data association, consistent with one pose — also when no edge passes the tests, so that
    /// tracking continues on the old points instead of duplicating them, and local
    /// registration of the following keyframes joins the old keyframes once they share `Θ`
    /// points), and each accepted keyframe gets its edge, `T_loop·T_i⁻¹` with `T_i` as it was
    /// when the problem was made (`T_loop` was fitted against the graph then: another thread may
    /// have moved both since). Points and keyframes removed since the problem was made are
    /// skipped.
    pub fn apply(&self, graph: &mut SlamGraph<N>) -> Result<Vec<MetricLoopClosure>, GraphError> {
        graph.pose(self.reference)?;
        for (p, z) in &self.inliers {
            match graph.add_observation(self.reference, *p, *z) {
                Ok(()) | Err(GraphError::UnknownPoint(_)) => {}
                Err(e) => return Err(e),
            }
        }
        let mut out = Vec::new();
        for &(k, shared) in &self.accepted {
            let (Some(t_k), Ok(_)) = (self.poses.get(&k), graph.pose(k)) else {
                continue;
            };
            let t_ref_k = self.camera_from_world.compose(&t_k.inverse());
            graph.add_edge(k, self.reference, Some(t_ref_k))?;
            out.push(MetricLoopClosure {
                keyframe: k,
                shared,
            });
        }
        Ok(out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::factors::point_to_inverse_depth;
    use geom::{PinholeCamera, StereoCamera};
    use lie::{Se3, Sim3};
    use nalgebra::Vector3;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    const THETA: usize = 20;

    fn k(i: usize) -> KeyframeId {
        KeyframeId::from_index(i)
    }

    fn params() -> MetricLoopParams {
        MetricLoopParams {
            theta: THETA,
            max_chi2: lsq::chi2_quantile(3, 0.95),
            sigma: 1.0,
            image_size: (640.0, 480.0),
        }
    }

    fn camera() -> StereoCamera {
        // The simulator's stereo rig: f = 300, 640×480, baseline 5 cm.
        StereoCamera::new(PinholeCamera::new(300.0, 300.0, 320.0, 240.0), 0.05)
    }

    /// A revisit (thesis Figure 6.7): keyframes 0–4 look at wall A (points anchored in
    /// keyframe 0 at their true positions, observed by all five), keyframes 5–9 turn away and
    /// are joined only as a chain, and the reference keyframe 10 comes back to the place of
    /// keyframe 0 (pose off by `offset` m) joined only to keyframe 9. Returns the graph, the
    /// true pose of the reference and wall A.
    fn revisit(offset: f64) -> (SlamGraph<3>, Se3, Vec<(PointId, Vector3<f64>)>) {
        let cam = camera();
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        let mut g = SlamGraph::<3>::new();
        let truth: Vec<Se3> = (0..11)
            .map(|k| match k {
                0..=4 => Se3::from_translation(Vector3::new(-0.02 * k as f64, 0.0, 0.0)),
                5..=9 => Se3::exp(&SVector::<f64, 6>::new(
                    0.0,
                    0.0,
                    0.0,
                    0.0,
                    0.3 * k as f64,
                    0.0,
                )),
                _ => Se3::from_translation(Vector3::new(0.01, 0.0, 0.0)),
            })
            .collect();
        for t in &truth[..10] {
            g.add_keyframe(Sim3::from_se3(t));
        }
        // Wall A: 150 points 3 m in front of keyframe 0, all over its image.
        let mut wall = Vec::new();
        while wall.len() < 150 {
            let y = Vector3::new(
                rng.random_range(-2.5..2.5),
                rng.random_range(-1.8..1.8),
                rng.random_range(2.8..3.2),
            );
            let zs: Option<Vec<_>> = (0..5)
                .map(|k| Projector::<3>::project(&cam, &truth[k].act(&y)).map(|(z, _)| z))
                .collect();
            let Some(zs) = zs else { continue };
            let x0 = truth[0].act(&y);
            let p = g
                .add_point(k(0), point_to_inverse_depth(&x0).unwrap(), zs[0])
                .unwrap();
            for (i, z) in zs.iter().enumerate().skip(1) {
                g.add_observation(k(i), p, *z).unwrap();
            }
            wall.push((p, y));
        }
        for a in 0..5 {
            for b in a + 1..5 {
                g.add_edge(k(a), k(b), None).unwrap();
            }
        }
        for i in 5..10 {
            g.add_edge(k(i - 1), k(i), None).unwrap();
        }
        let t_ref = Se3::from_translation(Vector3::new(offset, 0.0, 0.0)).compose(&truth[10]);
        let r = g.add_keyframe(Sim3::from_se3(&t_ref));
        g.add_edge(k(9), r, None).unwrap();
        g.set_reference(r).unwrap();
        (g, truth[10], wall)
    }

    /// Noise-free measurements of `wall` in the true reference pose, restricted by `keep`.
    fn measure(
        truth: &Se3,
        wall: &[(PointId, Vector3<f64>)],
        keep: impl Fn(&Vector3<f64>) -> bool,
    ) -> Vec<(PointId, Vector3<f64>)> {
        let cam = camera();
        wall.iter()
            .filter_map(|(p, y)| {
                let (z, _) = Projector::<3>::project(&cam, &truth.act(y))?;
                keep(&z).then_some((*p, z))
            })
            .collect()
    }

    #[test]
    fn loop_candidates_are_the_points_of_n2_not_seen_from_n1() {
        let (g, _, wall) = revisit(0.02);
        assert!(
            loop_candidates(&g, k(10), 5).is_empty(),
            "N2 of 5 keyframes ends at 6"
        );
        let a = loop_candidates(&g, k(10), 20);
        assert_eq!(a.len(), wall.len());
        assert!(tracking_candidates(&g, k(10)).is_empty());
    }

    #[test]
    fn metric_loop_closure_fires_on_a_revisit_with_well_spread_matches() {
        let (mut g, truth, wall) = revisit(0.02);
        let matches = measure(&truth, &wall, |_| true);
        let closed = close_metric_loops(&mut g, k(10), &matches, &camera(), &params()).unwrap();
        let joined: Vec<KeyframeId> = closed.iter().map(|c| c.keyframe).collect();
        assert_eq!(joined, (0..5).map(k).collect::<Vec<_>>(), "{closed:?}");
        for i in (0..5).map(k) {
            // Marginalised with T_loop·T_k⁻¹, i.e. close to the truth, not to the 2 cm off
            // reference pose.
            let rel = g.edge(i, k(10)).unwrap().relative.unwrap();
            let expect = Sim3::from_se3(&truth).compose(&g.pose(i).unwrap().inverse());
            let err = rel.compose(&expect.inverse()).log();
            assert!(err.norm() < 1e-6, "{i}: {err:?}");
        }
        assert_eq!(
            g.keyframe(k(10)).unwrap().observations().len(),
            matches.len()
        );
    }

    #[test]
    fn metric_loop_closure_rejects_matches_in_one_image_half_but_keeps_them() {
        let (mut g, truth, wall) = revisit(0.02);
        let matches = measure(&truth, &wall, |z| z[0] < 320.0);
        assert!(matches.len() >= 2 * THETA, "{} matches", matches.len());
        let closed = close_metric_loops(&mut g, k(10), &matches, &camera(), &params()).unwrap();
        assert!(closed.is_empty(), "{closed:?}");
        assert!(g.edge(k(0), k(10)).is_none());
        // The verified matches are observations of the reference all the same.
        assert_eq!(
            g.keyframe(k(10)).unwrap().observations().len(),
            matches.len()
        );
    }

    #[test]
    fn metric_loop_closure_prunes_matches_a_common_pose_does_not_explain() {
        let (mut g, truth, wall) = revisit(0.02);
        let mut matches = measure(&truth, &wall, |_| true);
        // A quarter of the matches are wrong by 8 px (outside the χ² gate, inside the 10 px
        // guided search).
        for (i, (_, z)) in matches.iter_mut().enumerate() {
            if i % 4 == 0 {
                z[0] += 8.0;
                z[2] += 8.0;
            }
        }
        let closed = close_metric_loops(&mut g, k(10), &matches, &camera(), &params()).unwrap();
        assert_eq!(closed.len(), 5, "{closed:?}");
        let kept = g.keyframe(k(10)).unwrap().observations().len();
        assert_eq!(kept, matches.len() - matches.len().div_ceil(4));
    }
}
