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
    /// Its information (`None`: the identity, thesis eq. 5.16's usual choice).
    pub information: Option<EdgeInformation>,
}

/// A diagonal information of a pose-graph edge, `diag(λ_trans²·I₃, λ_rot²·I₃, λ_scale²)` in
/// the tangent order `(v, ω, σ)` (thesis eq. 6.2; the scale entry only in Sim(3)).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EdgeInformation {
    /// `λ_trans²` (1/map unit²).
    pub translation: f64,
    /// `λ_rot²` (1/rad²).
    pub rotation: f64,
    /// `λ_scale²` (of `σ = ln s`).
    pub scale: f64,
}

impl EdgeInformation {
    fn sim3(info: Option<&Self>) -> SMatrix<f64, 7, 7> {
        info.map_or_else(SMatrix::identity, |i| {
            SMatrix::from_diagonal(&nalgebra::SVector::<f64, 7>::from([
                i.translation,
                i.translation,
                i.translation,
                i.rotation,
                i.rotation,
                i.rotation,
                i.scale,
            ]))
        })
    }

    fn se3(info: Option<&Self>) -> SMatrix<f64, 6, 6> {
        info.map_or_else(SMatrix::identity, |i| {
            SMatrix::from_diagonal(&nalgebra::SVector::<f64, 6>::from([
                i.translation,
                i.translation,
                i.translation,
                i.rotation,
                i.rotation,
                i.rotation,
            ]))
        })
    }
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
/// loop constraints `S_ji = old_from_current⁻¹` (`i` old, `j` current). The information of
/// the consecutive constraint `k → k+1` is `chain[k]` (the identity if `chain` is empty), a
/// loop's its own.
pub fn sim3_pose_graph(
    keyframe_poses: &[Se3],
    loops: &[LoopEdge],
    chain: &[EdgeInformation],
) -> (Vec<Sim3>, Vec<Constraint<Sim3, 7>>) {
    let poses: Vec<Sim3> = keyframe_poses.iter().map(Sim3::from_se3).collect();
    let mut constraints: Vec<Constraint<Sim3, 7>> = keyframe_poses
        .windows(2)
        .enumerate()
        .map(|(k, w)| Constraint {
            i: k,
            j: k + 1,
            measured: Sim3::from_se3(&w[1].compose(&w[0].inverse())),
            information: EdgeInformation::sim3(chain.get(k)),
        })
        .collect();
    constraints.extend(loops.iter().map(|l| Constraint {
        i: l.old,
        j: l.current,
        measured: l.old_from_current.inverse(),
        information: EdgeInformation::sim3(l.information.as_ref()),
    }));
    (poses, constraints)
}

/// The SE(3) pose graph of the same chain: loop constraints reduced to the rigid part `(R, t)`
/// of `old_from_current⁻¹`, the informations without their scale entries.
pub fn se3_pose_graph(
    keyframe_poses: &[Se3],
    loops: &[LoopEdge],
    chain: &[EdgeInformation],
) -> Vec<Constraint<Se3, 6>> {
    let mut constraints: Vec<Constraint<Se3, 6>> = keyframe_poses
        .windows(2)
        .enumerate()
        .map(|(k, w)| Constraint {
            i: k,
            j: k + 1,
            measured: w[1].compose(&w[0].inverse()),
            information: EdgeInformation::se3(chain.get(k)),
        })
        .collect();
    constraints.extend(loops.iter().map(|l| Constraint {
        i: l.old,
        j: l.current,
        measured: l.old_from_current.inverse().rigid_part(),
        information: EdgeInformation::se3(l.information.as_ref()),
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
/// keyframe fixed (thesis eq. 5.16–5.17); `chain` the consecutive constraints' informations
/// (empty: the identity).
pub fn correct_pose_graph(
    keyframe_poses: &[Se3],
    loops: &[LoopEdge],
    chain: &[EdgeInformation],
    group: CorrectionGroup,
    jacobian: PoseGraphJacobian,
    options: &SolverOptions,
) -> Result<Correction, CorrectionError> {
    match group {
        CorrectionGroup::Sim3 => {
            let (poses, constraints) = sim3_pose_graph(keyframe_poses, loops, chain);
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
            let constraints = se3_pose_graph(keyframe_poses, loops, chain);
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
    correct_chain(graph, None, (loops, &[]), group, jacobian, options)
}

/// [`correct_graph`] for the keyframes of map `map` alone, in a graph that holds several
/// ([`SlamGraph::start_map`]): the chain is that map's keyframes in id order, `loops` give
/// positions in it, `chain` the informations of its consecutive constraints (empty: the
/// identity), and the other maps' keyframes stay as they are.
pub fn correct_map<const N: usize>(
    graph: &mut SlamGraph<N>,
    map: usize,
    (loops, chain): (&[LoopEdge], &[EdgeInformation]),
    group: CorrectionGroup,
    jacobian: PoseGraphJacobian,
    options: &SolverOptions,
) -> Result<Correction, CorrectionError> {
    correct_chain(graph, Some(map), (loops, chain), group, jacobian, options)
}

fn correct_chain<const N: usize>(
    graph: &mut SlamGraph<N>,
    map: Option<usize>,
    (loops, chain_information): (&[LoopEdge], &[EdgeInformation]),
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
    let correction =
        correct_pose_graph(&poses, loops, chain_information, group, jacobian, options)?;
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
            information: None,
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
            &[],
            CorrectionGroup::Sim3,
            PoseGraphJacobian::Analytic(lie::LogJacobian::Exact),
            &options,
        )
        .unwrap();
        let se = correct_pose_graph(
            &est,
            &loops,
            &[],
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

    /// The edges' informations decide where a loop's correction goes: a straight chain of 20
    /// keyframes a metre apart whose loop says the last one is 1 m further on; with the identity
    /// every consecutive edge stretches by about 1/19 m in SE(3) (in Sim(3) the scales take it),
    /// with one edge ten thousand times less informative than the others (keyframes that share
    /// few points) that edge takes nearly the whole metre — in SE(3) and in Sim(3).
    #[test]
    fn a_weak_edge_takes_the_loop_correction() {
        let n = 20;
        let pose = |x: f64| Se3::new(So3::identity(), Vector3::new(0.0, 0.0, -x));
        let est: Vec<Se3> = (0..n).map(|k| pose(k as f64)).collect();
        let truth_last = pose(n as f64);
        let loops = [LoopEdge {
            old: 0,
            current: n - 1,
            old_from_current: Sim3::from_se3(&est[0].compose(&truth_last.inverse())),
            information: Some(EdgeInformation {
                translation: 1e4,
                rotation: 1e4,
                scale: 1e4,
            }),
        }];
        let weak = 9;
        let chain: Vec<EdgeInformation> = (0..n - 1)
            .map(|k| {
                let w = if k == weak { 1e-4 } else { 1.0 };
                EdgeInformation {
                    translation: w,
                    rotation: w,
                    scale: w,
                }
            })
            .collect();
        let options = SolverOptions::default();
        let jacobian = PoseGraphJacobian::Analytic(lie::LogJacobian::Exact);
        let stretch = |c: &Correction, k: usize| {
            let p = &c.camera_from_world;
            (p[k + 1].inverse().translation() - p[k].inverse().translation()).norm() - 1.0
        };
        for group in [CorrectionGroup::Se3, CorrectionGroup::Sim3] {
            let identity =
                correct_pose_graph(&est, &loops, &[], group, jacobian, &options).unwrap();
            let weighted =
                correct_pose_graph(&est, &loops, &chain, group, jacobian, &options).unwrap();
            for k in 0..n - 1 {
                assert!(
                    group == CorrectionGroup::Sim3
                        || (stretch(&identity, k) - 1.0 / 19.0).abs() < 0.01,
                    "{group:?}, identity, edge {k}: {}",
                    stretch(&identity, k)
                );
                let stretched = stretch(&weighted, k);
                assert!(
                    if k == weak {
                        stretched > 0.9
                    } else {
                        stretched.abs() < 0.01
                    },
                    "{group:?}, weighted, edge {k}: {stretched}"
                );
            }
        }
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
            information: None,
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
