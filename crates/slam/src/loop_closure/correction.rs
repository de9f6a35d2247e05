//! Loop correction through the pose graph (thesis §5.3.2).
//!
//! Consecutive keyframes give relative constraints `T_ji = T_j·T_i⁻¹` and the loop gives
//! `S_ji = S⁻¹` (mapping the old camera into the current one). The pose graph (eq. 5.16) is
//! optimised either in SE(3) — the loop constraint's rigid part `(R, t)`, so scale drift cannot
//! be corrected — or in Sim(3), where every pose becomes a similarity with `s = 1` and only the
//! loop carries `s_loop ≠ 1` (eq. 5.17), with the exact or CBH Jacobians (§5.3.3).
//!
//! On the SLAM graph ([`correct_graph`]) the chain is its keyframes in id order. Afterwards
//! each point is re-anchored to a keyframe `a` that sees it, `y_cor = (S_a^cor)⁻¹·(T_a·y)`: in
//! the graph's anchored representation, `y = T_a⁻¹·Π(ψ)`, that is what writing the corrected
//! similarity into the anchor does, so the points follow their anchors. The map is then
//! refined by structure-only (and optionally full) BA on the rigid poses `(R, t/s)`
//! ([`crate::pose_graph::rigid_from_similarity`], [`refine_graph`]).

use crate::ba::{BaMode, BundleAdjustment, Gauge, Observation};
use crate::factors::point_to_inverse_depth;
use crate::map::{GraphError, KeyframeId, PointId, SlamGraph};
use crate::pose_graph::{
    Constraint, PoseGraphError, PoseGraphJacobian, PoseGraphProblem, rigid_from_similarity,
};
use geom::PinholeCamera;
use lie::{LieGroup, Se3, Sim3};
use lsq::{RobustKernel, SolverOptions};
use nalgebra::{SMatrix, Vector3};

/// A loop edge of the pose graph between the keyframes at positions `old` and `current` of a
/// keyframe chain (for a graph, [`correct_graph`]: positions in id order).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LoopEdge {
    /// The old keyframe.
    pub old: usize,
    /// The current keyframe.
    pub current: usize,
    /// `S` with `x_old = S·x_current` (see [`LoopConstraint`]).
    pub old_from_current: Sim3,
}

/// The group the pose graph is optimised in.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CorrectionGroup {
    /// Rigid SE(3): rotation and translation drift are corrected, scale drift is not.
    Se3,
    /// Sim(3): rotation, translation and scale drift (thesis eq. 5.17).
    Sim3,
}

/// The Sim(3) pose graph of a keyframe chain with loops (thesis §5.3.2): the keyframes as
/// similarities with `s = 1`, consecutive constraints `S_{k+1,k} = T_{k+1}·T_k⁻¹` (`s = 1`) and
/// loop constraints `S_ji = old_from_current⁻¹` (`i` old, `j` current), all with identity
/// information.
pub fn sim3_pose_graph(
    keyframe_poses: &[Se3],
    loops: &[LoopEdge],
) -> (Vec<Sim3>, Vec<Constraint<Sim3, 7>>) {
    let poses: Vec<Sim3> = keyframe_poses.iter().map(Sim3::from_se3).collect();
    let mut constraints: Vec<Constraint<Sim3, 7>> = keyframe_poses
        .windows(2)
        .enumerate()
        .map(|(k, w)| Constraint {
            i: k,
            j: k + 1,
            measured: Sim3::from_se3(&w[1].compose(&w[0].inverse())),
            information: SMatrix::identity(),
        })
        .collect();
    constraints.extend(loops.iter().map(|l| Constraint {
        i: l.old,
        j: l.current,
        measured: l.old_from_current.inverse(),
        information: SMatrix::identity(),
    }));
    (poses, constraints)
}

/// The SE(3) pose graph of the same chain: loop constraints reduced to the rigid part `(R, t)`
/// of `old_from_current⁻¹`.
pub fn se3_pose_graph(keyframe_poses: &[Se3], loops: &[LoopEdge]) -> Vec<Constraint<Se3, 6>> {
    let mut constraints: Vec<Constraint<Se3, 6>> = keyframe_poses
        .windows(2)
        .enumerate()
        .map(|(k, w)| Constraint {
            i: k,
            j: k + 1,
            measured: w[1].compose(&w[0].inverse()),
            information: SMatrix::identity(),
        })
        .collect();
    constraints.extend(loops.iter().map(|l| Constraint {
        i: l.old,
        j: l.current,
        measured: l.old_from_current.inverse().rigid_part(),
        information: SMatrix::identity(),
    }));
    constraints
}

/// The outcome of [`correct_pose_graph`].
#[derive(Clone, Debug)]
pub struct Correction {
    /// The corrected keyframes as similarities (scale 1 for SE(3)).
    pub similarities: Vec<Sim3>,
    /// The corrected rigid poses `(R, t/s)`.
    pub camera_from_world: Vec<Se3>,
    /// The optimiser's summary.
    pub summary: lsq::Summary,
}

/// Optimises the pose graph of a keyframe chain with loop edges in SE(3) or Sim(3), the first
/// keyframe fixed (thesis eq. 5.16–5.17).
pub fn correct_pose_graph(
    keyframe_poses: &[Se3],
    loops: &[LoopEdge],
    group: CorrectionGroup,
    jacobian: PoseGraphJacobian,
    options: &SolverOptions,
) -> Result<Correction, CorrectionError> {
    match group {
        CorrectionGroup::Sim3 => {
            let (poses, constraints) = sim3_pose_graph(keyframe_poses, loops);
            let mut pg = PoseGraphProblem::with_jacobian(&poses, &constraints, &[0], jacobian)?;
            let summary = pg.problem.optimise(options)?;
            let similarities = pg.camera_from_world();
            Ok(Correction {
                camera_from_world: similarities.iter().map(rigid_from_similarity).collect(),
                similarities,
                summary,
            })
        }
        CorrectionGroup::Se3 => {
            let constraints = se3_pose_graph(keyframe_poses, loops);
            let mut pg =
                PoseGraphProblem::with_jacobian(keyframe_poses, &constraints, &[0], jacobian)?;
            let summary = pg.problem.optimise(options)?;
            let poses = pg.camera_from_world();
            Ok(Correction {
                similarities: poses.iter().map(Sim3::from_se3).collect(),
                camera_from_world: poses,
                summary,
            })
        }
    }
}

/// Why a correction failed.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum CorrectionError {
    /// The pose graph could not be built.
    #[error(transparent)]
    PoseGraph(#[from] PoseGraphError),
    /// The optimisation failed.
    #[error(transparent)]
    Solve(#[from] lsq::SolveError),
    /// The bundle adjustment could not be built.
    #[error(transparent)]
    Ba(#[from] crate::ba::BaError),
    /// A graph operation failed.
    #[error(transparent)]
    Graph(#[from] GraphError),
    /// A loop refers to a position beyond the keyframe chain.
    #[error("a loop joins position {position} of a chain of {keyframes} keyframes")]
    LoopOutOfRange {
        /// The position.
        position: usize,
        /// Keyframes in the chain.
        keyframes: usize,
    },
}

/// The keyframes of `graph` in id order (the chain of thesis §5.3.2) with their rigid poses;
/// only those of map `map` if given.
fn chain<const N: usize>(graph: &SlamGraph<N>, map: Option<usize>) -> (Vec<KeyframeId>, Vec<Se3>) {
    graph
        .keyframes()
        .filter(|(_, kf)| map.is_none_or(|m| kf.map() == m))
        .map(|(k, kf)| (k, rigid_from_similarity(kf.camera_from_world())))
        .unzip()
}

/// Corrects the keyframes of `graph` through the pose graph of their chain — keyframes in id
/// order, `loops` giving positions in it — in `group`, the first keyframe fixed
/// ([`correct_pose_graph`] on the rigid poses), and writes the corrected poses back: a keyframe
/// `k` of scale `s_k` becomes `s_k·S_k`, so that its anchored points follow it (the
/// re-anchoring of the module docs). Returns the correction.
pub fn correct_graph<const N: usize>(
    graph: &mut SlamGraph<N>,
    loops: &[LoopEdge],
    group: CorrectionGroup,
    jacobian: PoseGraphJacobian,
    options: &SolverOptions,
) -> Result<Correction, CorrectionError> {
    correct_chain(graph, None, loops, group, jacobian, options)
}

/// [`correct_graph`] for the keyframes of map `map` alone, in a graph that holds several
/// ([`SlamGraph::start_map`]): the chain is that map's keyframes in id order, `loops` give
/// positions in it, and the other maps' keyframes stay as they are.
pub fn correct_map<const N: usize>(
    graph: &mut SlamGraph<N>,
    map: usize,
    loops: &[LoopEdge],
    group: CorrectionGroup,
    jacobian: PoseGraphJacobian,
    options: &SolverOptions,
) -> Result<Correction, CorrectionError> {
    correct_chain(graph, Some(map), loops, group, jacobian, options)
}

fn correct_chain<const N: usize>(
    graph: &mut SlamGraph<N>,
    map: Option<usize>,
    loops: &[LoopEdge],
    group: CorrectionGroup,
    jacobian: PoseGraphJacobian,
    options: &SolverOptions,
) -> Result<Correction, CorrectionError> {
    let (ids, poses) = chain(graph, map);
    if let Some(position) = loops
        .iter()
        .flat_map(|l| [l.old, l.current])
        .find(|&p| p >= ids.len())
    {
        return Err(CorrectionError::LoopOutOfRange {
            position,
            keyframes: ids.len(),
        });
    }
    let correction = correct_pose_graph(&poses, loops, group, jacobian, options)?;
    for (&k, s_cor) in ids.iter().zip(&correction.similarities) {
        let scale = graph.pose(k)?.scale();
        let pose = if scale == 1.0 {
            *s_cor
        } else {
            Sim3::new(lie::So3::identity(), Vector3::zeros(), scale)
                .expect("a keyframe's scale is positive")
                .compose(s_cor)
        };
        graph.set_pose(k, pose)?;
    }
    Ok(correction)
}

/// Refines the map of a monocular `graph` after a correction: structure-only BA on the rigid
/// poses `(R, t/s)` of its keyframes (poses fixed), then, if `full`, full BA with the first
/// two keyframes fixed (the monocular gauge, thesis §3.3.2), Huber at `huber`σ, on Euclidean
/// points; writes the rigid poses and the points (anchored again) back and returns the poses
/// in id order. A point the refinement pushes behind its anchor keeps its previous position.
#[allow(clippy::too_many_arguments)]
pub fn refine_graph(
    graph: &mut SlamGraph<2>,
    camera: &PinholeCamera,
    sigma: f64,
    huber: f64,
    full: bool,
    options: &SolverOptions,
) -> Result<Vec<Se3>, CorrectionError> {
    let (ids, poses) = chain(graph, None);
    let position: std::collections::BTreeMap<KeyframeId, usize> =
        ids.iter().enumerate().map(|(i, &k)| (k, i)).collect();
    let point_ids: Vec<PointId> = graph.points().map(|(p, _)| p).collect();
    let points_world: Vec<Vector3<f64>> = point_ids
        .iter()
        .map(|&p| graph.point_world(p))
        .collect::<Result<_, _>>()?;
    let mut observations = Vec::new();
    for (j, &p) in point_ids.iter().enumerate() {
        for &k in graph.point(p).expect("listed").observers() {
            observations.push(Observation {
                pose: position[&k],
                point: j,
                measurement: graph.keyframe(k).expect("observer").observations()[&p],
            });
        }
    }
    let mut ba = BundleAdjustment::new(
        camera,
        &poses,
        &points_world,
        &observations,
        sigma,
        Some(RobustKernel::Huber(huber)),
        BaMode::StructureOnly,
        &Gauge::FixPoses(vec![]),
    )?;
    ba.problem.optimise(options)?;
    let (mut poses, mut pts) = (ba.camera_from_world(), ba.points_world());
    if full {
        let mut ba = BundleAdjustment::new(
            camera,
            &poses,
            &pts,
            &observations,
            sigma,
            Some(RobustKernel::Huber(huber)),
            BaMode::Full,
            &Gauge::FixPoses(vec![0, 1]),
        )?;
        ba.problem.optimise(options)?;
        poses = ba.camera_from_world();
        pts = ba.points_world();
    }
    for (&k, t) in ids.iter().zip(&poses) {
        graph.set_pose(k, Sim3::from_se3(t))?;
    }
    for (&p, y) in point_ids.iter().zip(&pts) {
        let anchor = graph.point(p).expect("listed").anchor();
        if let Some(psi) = point_to_inverse_depth(&graph.pose(anchor)?.act(y)) {
            graph.set_inverse_depth(p, psi)?;
        }
    }
    Ok(poses)
}

#[cfg(test)]
mod tests {
    use super::*;
    use lie::So3;

    /// A chain whose scale drifts by 2 % per step around a circle, closed by the exact loop
    /// similarity: Sim(3) correction restores the shape, SE(3) cannot.
    #[test]
    fn sim3_correction_removes_scale_drift_that_se3_cannot() {
        let n = 60;
        let truth: Vec<Se3> = (0..n)
            .map(|k| {
                let a = std::f64::consts::TAU * k as f64 / n as f64;
                let c = Vector3::new(10.0 * a.cos(), 10.0 * a.sin(), 0.0);
                // Looking outwards, rotating about world z.
                let r = So3::rot_z(a);
                Se3::new(r.inverse(), -(r.inverse().act(&c)))
            })
            .collect();
        // Drifted estimate: relative motions with translation scaled by 0.98^k.
        let mut est = vec![truth[0]];
        for k in 1..n {
            let rel = truth[k].compose(&truth[k - 1].inverse());
            let scaled = Se3::new(*rel.rotation(), rel.translation() * 0.98f64.powi(k as i32));
            est.push(scaled.compose(&est[k - 1]));
        }
        // The loop: the current (last) camera in the old (first) one, scale from the drift.
        let s_loop = 0.98f64.powi(n as i32 - 1);
        let rigid = truth[0].compose(&truth[n - 1].inverse());
        let old_from_current =
            Sim3::new(*rigid.rotation(), *rigid.translation(), 1.0 / s_loop).unwrap();
        // Express the rigid part in the current (drifted) scale: x_old = S·x_cur, x_cur scaled by s_loop.
        let loops = [LoopEdge {
            old: 0,
            current: n - 1,
            old_from_current,
        }];
        let options = SolverOptions::default();
        let err = |poses: &[Se3]| -> f64 {
            // Scale-aligned centre error.
            let c_t: Vec<_> = truth
                .iter()
                .map(|t| t.inverse().translation().to_owned())
                .collect();
            let c_e: Vec<_> = poses
                .iter()
                .map(|t| t.inverse().translation().to_owned())
                .collect();
            let s = c_t.iter().zip(&c_e).map(|(a, b)| a.dot(b)).sum::<f64>()
                / c_e.iter().map(|b| b.norm_squared()).sum::<f64>();
            (c_t.iter()
                .zip(&c_e)
                .map(|(a, b)| (a - s * b).norm_squared())
                .sum::<f64>()
                / n as f64)
                .sqrt()
        };
        let sim = correct_pose_graph(
            &est,
            &loops,
            CorrectionGroup::Sim3,
            PoseGraphJacobian::Analytic(lie::LogJacobian::Exact),
            &options,
        )
        .unwrap();
        let se = correct_pose_graph(
            &est,
            &loops,
            CorrectionGroup::Se3,
            PoseGraphJacobian::Analytic(lie::LogJacobian::Exact),
            &options,
        )
        .unwrap();
        let (e0, e_sim, e_se) = (
            err(&est),
            err(&sim.camera_from_world),
            err(&se.camera_from_world),
        );
        assert!(
            e_sim < 0.2 * e_se,
            "before {e0}, Sim(3) {e_sim}, SE(3) {e_se}"
        );
        assert!(e_sim < 0.1 * e0);
    }

    /// On the graph the points follow their anchors: after the correction each point is where
    /// the thesis's re-anchoring puts it, `y_cor = (S_a^cor)⁻¹·(T_a·y)` with `T_a` rigid — also
    /// for a keyframe whose pose already had a scale.
    #[test]
    fn points_follow_their_anchors_through_a_graph_correction() {
        use nalgebra::Vector2;
        let mut g = SlamGraph::<2>::new();
        let mut rigid = Vec::new();
        for k in 0..12 {
            let a = 0.3 * k as f64;
            let t = Se3::new(So3::rot_y(a), Vector3::new(a.sin(), 0.0, 2.0 * a.cos()));
            // Keyframe 5 carries a scale from an earlier Sim(3) correction.
            let scale = if k == 5 { 1.3 } else { 1.0 };
            let pose = Sim3::new(*t.rotation(), t.translation() * scale, scale).unwrap();
            rigid.push(rigid_from_similarity(&pose));
            let kf = g.add_keyframe(pose);
            for i in 0..3 {
                let psi = Vector3::new(0.1 * i as f64, -0.05, 0.4 + 0.1 * i as f64);
                g.add_point(kf, psi, Vector2::zeros()).unwrap();
            }
        }
        let before: Vec<(PointId, KeyframeId, Vector3<f64>)> = g
            .points()
            .map(|(p, pt)| (p, pt.anchor(), g.point_world(p).unwrap()))
            .collect();
        let drifted = rigid[0].compose(&rigid[11].inverse());
        let loops = [LoopEdge {
            old: 0,
            current: 11,
            old_from_current: Sim3::new(*drifted.rotation(), *drifted.translation(), 0.9).unwrap(),
        }];
        let correction = correct_graph(
            &mut g,
            &loops,
            CorrectionGroup::Sim3,
            PoseGraphJacobian::Analytic(lie::LogJacobian::Exact),
            &SolverOptions::default(),
        )
        .unwrap();
        g.check_invariants().unwrap();
        let mut moved = 0.0f64;
        for (p, a, y) in before {
            let s_cor = correction.similarities[a.index()];
            let expect = s_cor.inverse().act(&rigid[a.index()].act(&y));
            let got = g.point_world(p).unwrap();
            assert!(
                (got - expect).norm() < 1e-9 * expect.norm(),
                "{p}: {got} vs {expect}"
            );
            moved = moved.max((got - y).norm());
        }
        assert!(moved > 0.05, "the correction should move points ({moved})");
        // Out-of-range loops are refused before anything changes.
        let bad = [LoopEdge {
            old: 0,
            current: 12,
            ..loops[0]
        }];
        let state = g.snapshot_state();
        assert!(matches!(
            correct_graph(
                &mut g,
                &bad,
                CorrectionGroup::Se3,
                PoseGraphJacobian::Analytic(lie::LogJacobian::Exact),
                &SolverOptions::default(),
            ),
            Err(CorrectionError::LoopOutOfRange { position: 12, .. })
        ));
        assert_eq!(g.snapshot_state(), state);
    }
}
