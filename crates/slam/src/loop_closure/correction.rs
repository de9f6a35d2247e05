//! Loop correction through the pose graph (thesis §5.3.2).
//!
//! Consecutive keyframes give relative constraints `T_ji = T_j·T_i⁻¹` and the loop gives
//! `S_ji = S⁻¹` (mapping the old camera into the current one). The pose graph (eq. 5.16) is
//! optimised either in SE(3) — the loop constraint's rigid part `(R, t)`, so scale drift cannot
//! be corrected — or in Sim(3), where every pose becomes a similarity with `s = 1` and only the
//! loop carries `s_loop ≠ 1` (eq. 5.17), with the exact or CBH Jacobians (§5.3.3). Afterwards
//! each point is re-anchored to a keyframe `i` that sees it, `y_cor = (S_i^cor)⁻¹·(T_i·y)`
//! ([`correct_points`]), the similarities become rigid poses `(R, t/s)`
//! ([`crate::pose_graph::rigid_from_similarity`]), and the map is refined by structure-only (and
//! optionally full) BA ([`refine_map`]).

use crate::ba::{BaMode, BundleAdjustment, Gauge, Observation};
use crate::exploration::MapPoint;
use crate::pose_graph::{
    Constraint, PoseGraphError, PoseGraphJacobian, PoseGraphProblem, rigid_from_similarity,
};
use geom::PinholeCamera;
use lie::{LieGroup, Se3, Sim3};
use lsq::{RobustKernel, SolverOptions};
use nalgebra::{SMatrix, Vector3};

/// A loop edge of the pose graph between keyframes `old` and `current`.
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
}

/// Re-anchors points to their corrected keyframes (thesis §5.3.2):
/// `y_cor = (S_a^cor)⁻¹·(T_a·y)` with `a` the point's anchor keyframe, `T_a` its pose before
/// and `S_a^cor` after the correction.
pub fn correct_points(
    points: &[MapPoint],
    poses_before: &[Se3],
    corrected: &[Sim3],
) -> Vec<Vector3<f64>> {
    points
        .iter()
        .map(|p| {
            let a = p.anchor_keyframe;
            corrected[a]
                .inverse()
                .act(&poses_before[a].act(&p.point_world))
        })
        .collect()
}

/// Refines the map after a correction: structure-only BA (poses fixed), then, if `full`, full
/// BA with the first two keyframes fixed (the monocular gauge, thesis §3.3.2), Huber at
/// `huber`σ. Returns the refined poses and points.
#[allow(clippy::too_many_arguments)]
pub fn refine_map(
    camera: &PinholeCamera,
    camera_from_world: &[Se3],
    points_world: &[Vector3<f64>],
    points: &[MapPoint],
    sigma: f64,
    huber: f64,
    full: bool,
    options: &SolverOptions,
) -> Result<(Vec<Se3>, Vec<Vector3<f64>>), CorrectionError> {
    let observations: Vec<Observation<2>> = points
        .iter()
        .enumerate()
        .flat_map(|(j, p)| {
            p.observations.iter().map(move |(k, z)| Observation {
                pose: *k,
                point: j,
                measurement: *z,
            })
        })
        .collect();
    let mut ba = BundleAdjustment::new(
        camera,
        camera_from_world,
        points_world,
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
    Ok((poses, pts))
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
}
